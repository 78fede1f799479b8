"""Benchmark: one-pass stack rendering against the best per-source baseline.

Both renderers make the same 21-frame stack: of the SHINY sphere scan
(``--scene sphere``, direct light), or of a solder joint with
inter-reflections (``--scene solder``: a good joint drawn from seed 0, the
``path`` integrator with ``max_depth`` 3 as the solder studies render it).
The baseline renders each source with ``mi.render`` and Mitsuba's ``direct``
(or ``path``) integrator, the other sources' radiance *and* sampling weight
set to zero (its best form: every light sample goes to the lit source). Noise is the
relative RMSE over the *highlight pixels* (reference >= 10 % of its frame's
peak) against a high-spp per-source reference; the speed ratio is taken at
equal noise, ``(t_base * rmse_base^2) / (t_one * rmse_one^2)`` (variance
falls as 1/spp, so that is the ratio of the times each needs for the same
noise).

Each renderer runs in its own process, so its peak memory (max RSS) is its
own; times are medians of repeated renders after a warm-up render, whose
extra time is reported as the JIT compile time.

Usage::

    python benchmarks/render_stack.py                       # 512^2, alpha 0.02, 64 spp
    python benchmarks/render_stack.py --alpha 0.2 --ref-spp 1024
    python benchmarks/render_stack.py --quick               # 256^2, fewer repeats
    python benchmarks/render_stack.py --scene solder        # 256^2, 16 spp, reference 512 spp
    python benchmarks/render_stack.py --scene solder --floor 0.015625   # paths at the direct-light floor
    python benchmarks/render_stack.py --variant cuda_ad_mono   # on a GPU

The last line printed is ``ratio=<baseline/one-pass> seconds_per_stack=<one-pass>``.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def make_simulator(args):
    """The benchmark's scene, loaded once."""
    from shinysim.rig import shiny_1988

    if args.scene == "solder":
        from shinysim.objects.solder import sample_params
        from shinysim.sim.solder import make_joint
        from shinysim.sim.solder_scene import joint_simulator

        joint = make_joint(sample_params("good", np.random.default_rng(0)))
        return joint_simulator(joint, shiny_1988(resolution=args.resolution, projection=args.camera),
                               max_depth=3, variant=args.variant)
    from shinysim.sim.render import Simulator
    from shinysim.sim.scene import sphere_object

    return Simulator(shiny_1988(resolution=args.resolution, projection=args.camera),
                     sphere_object(alpha=args.alpha), variant=args.variant)


def worker(args):
    t0 = time.perf_counter()
    sim = make_simulator(args)
    load = time.perf_counter() - t0
    times = []
    frames = None
    for rep in range(args.repeats + 1):
        t0 = time.perf_counter()
        floor = args.floor if args.worker == "one-pass" else None
        stack = sim.render_stack(spp=args.spp, seed=args.seed + rep, method=args.worker, floor=floor)
        times.append(time.perf_counter() - t0)
        frames = stack.frames
    warm = float(np.median(times[1:])) if len(times) > 1 else times[0]
    info = {
        "method": args.worker,
        "variant": sim.variant,
        "load_seconds": load,
        "first_seconds": times[0],
        "seconds_per_stack": warm,
        "jit_compile_seconds": max(0.0, times[0] - warm),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "lanes": getattr(sim, "last_lane_count", None),
    }
    np.save(args.out + ".npy", frames)
    Path(args.out + ".json").write_text(json.dumps(info))


def run_worker(method, spp, repeats, args, tmp):
    out = str(Path(tmp) / f"{method}-{spp}")
    cmd = [sys.executable, __file__, "--worker", method, "--spp", str(spp), "--repeats", str(repeats),
           "--scene", args.scene, "--alpha", str(args.alpha), "--resolution", str(args.resolution), "--camera", args.camera,
           "--seed", str(args.seed), "--out", out]
    if args.variant:
        cmd += ["--variant", args.variant]
    if args.floor is not None:
        cmd += ["--floor", str(args.floor)]
    if subprocess.run(cmd).returncode != 0:
        sys.exit(f"render_stack: the {method} renderer at {spp} spp failed (its error is above)")
    return np.load(out + ".npy"), json.loads(Path(out + ".json").read_text())


def centroid_shift(x, ref, mask):
    """Per frame: distance (px) between the weighted centroids of ``x`` and ``ref`` over the highlight pixels."""
    rows, cols = np.indices(ref.shape[1:])
    out = []
    for k in range(ref.shape[0]):
        m = mask[k]
        c = [np.array([np.sum(f[k][m] * rows[m]), np.sum(f[k][m] * cols[m])]) / np.sum(f[k][m]) for f in (x, ref)]
        out.append(float(np.hypot(*(c[0] - c[1]))))
    return np.array(out)


def rel_rmse(x, ref, mask):
    return float(np.sqrt(np.mean((x[mask] - ref[mask]) ** 2)) / np.mean(ref[mask]))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", choices=("sphere", "solder"), default="sphere")
    p.add_argument("--alpha", type=float, default=0.02, help="the sphere's roughness")
    p.add_argument("--resolution", type=int, default=None, help="[sphere 512, solder 256]")
    p.add_argument("--camera", default="perspective")
    p.add_argument("--spp", type=int, default=None, help="spp of both renderers [sphere 64, solder 16]")
    p.add_argument("--ref-spp", type=int, default=None,
                   help="spp of the per-source reference [sphere 1024, solder 512]")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--variant", default=None)
    p.add_argument("--floor", type=float, default=None,
                   help="one-pass: least expected samples per (source, pixel) [the renderer's: 1/64 for direct "
                        "light, 1 for paths]")
    p.add_argument("--quick", action="store_true", help="256^2, ref 256 spp, 1 repeat")
    p.add_argument("--worker", help=argparse.SUPPRESS)
    p.add_argument("--out", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.worker:
        return worker(args)
    if args.variant:  # one line, before any render, where the variant cannot run here
        from shinysim.errors import ShinysimError
        from shinysim.sim.variants import choose_variant

        try:
            choose_variant(args.variant)
        except ShinysimError as e:
            sys.exit(f"render_stack: {e}")
    solder = args.scene == "solder"
    args.resolution = args.resolution or (256 if solder else 512)
    args.spp = args.spp or (16 if solder else 64)
    args.ref_spp = args.ref_spp or (512 if solder else 1024)
    if args.quick:
        args.resolution, args.ref_spp, args.repeats = (128 if solder else 256), 256, 1

    with tempfile.TemporaryDirectory() as tmp:
        what = "solder joint, path max_depth 3" if solder else f"sphere alpha={args.alpha}"
        print(f"render_stack: {what}, {args.resolution}^2, 21 sources, camera={args.camera}, "
              f"spp={args.spp}, reference {args.ref_spp} spp per-source"
              + ("" if args.floor is None else f", one-pass floor {args.floor:g}"), flush=True)
        ref, ref_info = run_worker("per-source", args.ref_spp, 0, args, tmp)
        base, base_info = run_worker("per-source", args.spp, args.repeats, args, tmp)
        one, one_info = run_worker("one-pass", args.spp, args.repeats, args, tmp)
    mask = ref >= 0.1 * ref.max(axis=(1, 2), keepdims=True)
    e_base = rel_rmse(base, ref, mask)
    e_one = rel_rmse(one, ref, mask)
    sums = one.sum(axis=(1, 2)) / ref.sum(axis=(1, 2))
    t_base, t_one = base_info["seconds_per_stack"], one_info["seconds_per_stack"]
    ratio_time = t_base / t_one
    ratio = (t_base * e_base**2) / (t_one * e_one**2)
    print(f"variant {one_info['variant']}; highlight pixels: {int(mask.sum())} over 21 frames")
    print(f"{'renderer':<12}{'s/stack':>9}{'JIT s':>8}{'peak MB':>9}{'rel RMSE':>10}{'lanes':>11}")
    for name, info, err in (("per-source", base_info, e_base), ("one-pass", one_info, e_one)):
        lanes = f"{info['lanes']:>11d}" if info["lanes"] else f"{'-':>11}"
        print(f"{name:<12}{info['seconds_per_stack']:>9.3f}{info['jit_compile_seconds']:>8.2f}"
              f"{info['peak_rss_mb']:>9.0f}{err:>10.4f}{lanes}")
    print(f"one-pass frame sums / reference: min {sums.min():.4f} max {sums.max():.4f}")
    shift = centroid_shift(one, ref, mask)
    print(f"one-pass highlight centroids (reference's highlight pixels) off the reference's: "
          f"median {np.median(shift):.3f} px, max {shift.max():.3f} px")
    print(f"time ratio at equal spp {ratio_time:.1f}; noise ratio (one-pass/per-source) {e_one / e_base:.3f}")
    print(f"ratio={ratio:.1f} seconds_per_stack={t_one:.3f}")


if __name__ == "__main__":
    main()
