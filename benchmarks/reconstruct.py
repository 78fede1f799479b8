"""Benchmark: reconstruct() on a rendered-like sphere stack against plain scikit-image and memory bandwidth.

The stack is synthetic (numpy, seeded; no renderer), drawn to look like the
default rendered sphere scan (``shiny_1988`` rig, alpha 0.02, 64 spp, 512 x
512), whose statistics were measured on one render: per frame one compact
highlight (peak about 0.08-0.10, about 20-25 pixels above half of it) on the
row through the sphere's centre; around it a tail that is fully lit out to
about 20 pixels (0.3 % of the peak at 15 pixels), thinning out to a few
percent of pixels lit at 30-60 pixels; about 1000-2000 scattered single
"firefly" pixels over the sphere at 1e-5 to 1e-3 of the peak; every other
pixel exactly 0, so that 1.5-2.5 % of a frame's pixels are nonzero. No hot
pixels, no clipping (a float render has no clip level).

Timed in the same process, medians of repeated runs after a warm-up run, back
to back (as a repeated call finds its data in the caches), in five passes
over all of them so that a drift in the machine's load hits them alike (the
minimum is printed too: what an unloaded machine would show):

* ``reconstruct(stack)``, default detection and the default
  normal models;
* ``skimage``: a plain scikit-image pipeline that does the least any
  detection must: threshold each frame at the level the detection used,
  ``skimage.measure.label`` and ``regionprops`` with the weighted centroid
  of every region (no noise estimate, no hot pixels, no checks); its
  centroids of the regions detection keeps must be detection's to 1e-9 px
  (the same sums in another order);
* ``memcpy``: ``np.copyto`` of the stack into a preallocated array;
* ``read``: one read pass, ``stack.frames.max()``;
* for the record, parts of it: ``detect_stack(stack)`` (detection
  without the normals) and the same with ``noise_sigma`` given (no noise
  estimate: it depends on every nonzero pixel, whose differences are
  sorted).

Peak extra memory of detection is measured with ``tracemalloc`` (numpy's
allocations are traced) against the stack's size; its scaling by time
per pixel on a 96 x 512 x 512 stack (96 sources) and a 21 x 2048 x 2048
stack (the same scene at 4x the resolution), against the 21 x 512 x 512 case.

Usage::

    python benchmarks/reconstruct.py            # 30 repeats, scaling with 9
    python benchmarks/reconstruct.py --quick    # 10 repeats, scaling with 3

The last line printed is ``median_ms=<x> ratio_vs_skimage=<y> ratio_vs_memcpy=<z>``:
``reconstruct``'s median, the skimage baseline's median over it, and it
over the memcpy's.
"""

from __future__ import annotations

import argparse
import os
import time
import tracemalloc

import numpy as np


def rendered_like_stack(n_sources=21, resolution=512, seed=0, fireflies_per_frame=1400):
    """(n, R, R) float32 frames like a rendered sphere scan (see the module docstring), in ``resolution`` pixels."""
    rng = np.random.default_rng(seed)
    R = resolution
    scale = R / 512
    frames = np.zeros((n_sources, R, R), np.float32)
    centre, sphere_px = R / 2, 203 * scale  # the 1/16 in sphere in a 2 mm field
    angles = np.radians(np.linspace(-84, 76, n_sources))
    half = int(64 * scale)
    wr, wc = np.indices((2 * half + 1, 2 * half + 1), dtype=float)
    for k in range(n_sources):
        # the mirror ball's highlight: where the normal bisects camera and source
        r0 = centre + rng.uniform(-1, 1) * scale
        c0 = centre + sphere_px * np.sin(angles[k] / 2) + rng.uniform(-0.5, 0.5)
        peak = rng.uniform(0.08, 0.10)
        top, left = int(round(r0)) - half, int(round(c0)) - half
        d = np.hypot(wr + top - r0, wc + left - c0) / scale
        f = peak * (0.8 * np.exp(-d**2 / (2 * 1.8**2)) + 0.35 / (1 + (d / 3) ** 3))
        shape = 4.0 + 400.0 * f / peak  # Monte Carlo noise: about 5 % in the core, 50 % in the tail
        f *= rng.gamma(shape, 1.0 / shape)
        lit = rng.random(f.shape) < np.where(d < 20, 1.0, np.where(d < 30, 0.8, np.where(d < 60, 0.13, 0.0)))
        frames[k, top:top + 2 * half + 1, left:left + 2 * half + 1] = np.where(lit, f, 0.0)
        # fireflies over the sphere
        m = int(fireflies_per_frame * scale**2)
        rad, phi = sphere_px * np.sqrt(rng.random(m)), rng.uniform(0, 2 * np.pi, m)
        rows = np.clip((centre + rad * np.sin(phi)).astype(int), 0, R - 1)
        cols = np.clip((centre + rad * np.cos(phi)).astype(int), 0, R - 1)
        frames[k, rows, cols] = np.maximum(frames[k, rows, cols], peak * 10 ** rng.uniform(-5, -3, m))
    return frames


def blocked_ms(fns, repeats, passes=5):
    """Median milliseconds of each function: in each pass, each one runs a warm-up and then its share of
    ``repeats`` back to back (its data warm in the caches, as a repeated call finds it); the passes go round
    all the functions in turn, so that a drift in the machine's load hits them alike."""
    times = {name: [] for name in fns}
    for p in range(passes):
        share = repeats // passes + (p < repeats % passes)
        for name, fn in fns.items():
            fn()
            for _ in range(share):
                t0 = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t0)
    return {name: (1e3 * float(np.median(t)), 1e3 * float(np.min(t))) for name, t in times.items()}


def skimage_baseline(frames, levels):
    """Threshold at the given levels, label and regionprops' weighted centroids, frame by frame."""
    from skimage import measure

    out = []
    for frame, level in zip(frames, levels):
        labels = measure.label(frame >= level, connectivity=2)
        out.append([(region.area, region.centroid_weighted)
                    for region in measure.regionprops(labels, intensity_image=frame)])
    return out


def levels_used(rec, frames, params):
    """Each frame's absolute threshold in the detection (relative level raised to the noise floor)."""
    k = rec.detection["noise_k"]
    out = []
    for j, f in enumerate(frames):
        level = params.threshold * float(f.max())
        out.append(max(level, rec.detection["background"][j] + k * rec.detection["noise_sigma"][j]))
    return out


def same(rec, baseline):
    """Detection's highlights are the baseline's regions of at least the minimum area, centroids to 1e-9 px.

    (No background is subtracted in a rendered frame, whose median is 0, and
    no region is subdivided: the weighted centroids are the same sums.)
    """
    t = rec.table
    for k, regions in enumerate(baseline):
        mine = np.flatnonzero(t["source"] == k)
        theirs = [(a, c) for a, c in regions if a >= rec.detection["min_area"]]
        if len(mine) != len(theirs):
            return False
        for i, (a, c) in zip(mine, theirs):
            if t["area"][i] != a or not np.allclose([t["row"][i], t["col"][i]], c, rtol=0, atol=1e-9):
                return False
    return True


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats")
    parser.add_argument("--repeats", type=int, default=None, help="repeats of each timing (default 30, quick 10)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-scaling", action="store_true", help="skip the 96 x 512^2 and 21 x 2048^2 stacks")
    args = parser.parse_args(argv)
    repeats = args.repeats or (10 if args.quick else 30)
    scale_repeats = 3 if args.quick else 9

    from shinysim.io import Stack
    from shinysim.recon import DetectParams, detect_stack, reconstruct
    from shinysim.rig import shiny_1988

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    frames = rendered_like_stack(seed=args.seed)
    stack = Stack(frames, shiny_1988())
    params = DetectParams()
    nonzero = np.count_nonzero(frames) / frames.size
    print(f"stack: {frames.shape[0]} x {frames.shape[1]} x {frames.shape[2]} float32 "
          f"({frames.nbytes / 2**20:.1f} MiB), {100 * nonzero:.2f} % of pixels nonzero; load average {load:.2f}")

    fast = reconstruct(stack)
    levels = levels_used(fast, frames, params)
    identical = same(fast, skimage_baseline(frames, levels))
    print(f"highlights: {len(fast)} in {frames.shape[0]} frames; == scikit-image's regions: "
          f"{'yes' if identical else 'NO'}")
    dst = np.empty_like(frames)

    sigma = float(np.median(fast.detection["noise_sigma"]))
    timed = blocked_ms({
        "fast": lambda: reconstruct(stack),
        "skimage": lambda: skimage_baseline(frames, levels),
        "memcpy": lambda: np.copyto(dst, frames),
        "read": lambda: frames.max(),
        "detect": lambda: detect_stack(stack),
        "given": lambda: detect_stack(stack, noise_sigma=sigma),
    }, repeats)
    t_fast, t_sk, t_copy = (timed[k][0] for k in ("fast", "skimage", "memcpy"))
    rows = [
        ("reconstruct(stack)", timed["fast"], repeats),
        ("skimage: threshold + label + regionprops", timed["skimage"], repeats),
        ("memcpy: np.copyto", timed["memcpy"], repeats),
        ("read pass: stack.max()", timed["read"], repeats),
        ("  of it: detect_stack(stack) (no normals)", timed["detect"], repeats),
        ("  of it: detect_stack, noise_sigma given", timed["given"], repeats),
    ]

    tracemalloc.start()
    detect_stack(stack)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()

    print()
    print(f"{'what':52s} {'median ms':>10s} {'min ms':>8s} {'repeats':>8s} {'x recon':>8s}")
    for what, (ms, least), rep in rows:
        print(f"{what:52s} {ms:10.2f} {least:8.2f} {rep:8d} {ms / t_fast:8.2f}")
    print()
    print(f"peak extra memory of detect_stack: {peak / 2**20:6.1f} MiB = {peak / frames.nbytes:.2f} x the stack")

    if not args.no_scaling:
        per_pixel = t_fast / frames.size
        print()
        print(f"{'scaling (reconstruct)':52s} {'median ms':>10s} {'ns/pixel':>8s} {'x 21x512':>8s}")
        print(f"{'21 x 512 x 512':52s} {t_fast:10.2f} {1e6 * per_pixel:8.3f} {1.0:8.2f}")
        for n, res in ((96, 512), (21, 2048)):
            big = rendered_like_stack(n, res, seed=args.seed + 1)
            rig = shiny_1988(n_sources=n, spacing_deg=160 / (n - 1), resolution=res)
            big_stack = Stack(big, rig)
            ms = blocked_ms({"fast": lambda: reconstruct(big_stack)}, scale_repeats, passes=1)["fast"][0]
            print(f"{f'{n} x {res} x {res}':52s} {ms:10.2f} {1e6 * ms / big.size:8.3f} "
                  f"{ms / big.size / per_pixel:8.2f}")
            del big, big_stack

    print()
    print(f"median_ms={t_fast:.2f} ratio_vs_skimage={t_sk / t_fast:.2f} ratio_vs_memcpy={t_fast / t_copy:.2f}")
    return 0 if identical else 1


if __name__ == "__main__":
    raise SystemExit(main())
