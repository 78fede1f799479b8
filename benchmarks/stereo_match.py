"""Benchmark: structured-highlight stereo matching against the number of highlights, and the O(N^2) baseline.

Synthetic, seeded, no renderer. The surface is a height field: a sum
of Gaussian bumps (0.5 per mm^2, widths 0.3-0.8 mm, heights up to
+-0.15 mm), over a square that grows with N so that the density of
highlights stays 100 per mm^2 per camera (10 x 10 mm at N = 1e4, 32 x 32 mm at
1e5): the work per highlight is then what a real scan of a larger part
gives, and the time shows the algorithm's growth, not a denser crowd on each
epipolar line. Each camera of a ``stereo_pair`` (perspective, beta = 15 deg,
127 mm away, field 1 mm wider than the surface, 512 pixels) sees N
highlights: 90 % of them are
elements seen by both cameras, each with its own source placed by reflection
(43.18 mm from the element along the mirror direction of each camera), the
camera-2 element a little beside the camera-1 one (up to 0.005 mm, as
discrete sources leave them); 10 % are elements seen by one camera only.
Centroids get 0.05 pixel of noise. The working volume is z in
[-0.4, 0.4] mm (the surface's range with a margin), D0 = 0.03 mm, normal gap 0.5 degree.

Timed, for each N in ``--sizes`` (highlights per camera): the median of
``--repeats`` runs of :func:`match_highlights` (candidate search, tests,
relaxation, uniqueness, reflectance matching, refinement; on ``--workers``
threads, by default one per core), the same on one thread (``1thr_s``), and, for the record, of
:func:`candidate_pairs` alone; peak traced memory (``tracemalloc``) of one
``match_highlights`` run; then the median time of each stage over the same
runs (``StereoMatches.seconds``: the index, the exact tests, support weights
and relaxation, uniqueness, reflectance matching). A least-squares slope of log(time) against log(N)
says how the time grows (O(N log N) shows a slope near 1.0-1.15). The naive
O(N^2) search (:func:`candidate_pairs_naive`, chunked so that memory stays
bounded) runs beside it on the sizes up to ``--naive-max``, with the ratio of
its time to the indexed search's and a check that both find the same pairs.

Usage::

    python benchmarks/stereo_match.py                       # 1e3, 1e4, 1e5
    python benchmarks/stereo_match.py --sizes 1000 3000 --repeats 3

The last line printed is ``n=<largest N> seconds=<x> slope=<y>``: the
median seconds of ``match_highlights`` at the largest N and the slope.
"""

from __future__ import annotations

import argparse
import math
import time
import tracemalloc

import numpy as np

#: Highlights per mm^2 of the surface, per camera (N = 1e4 on 10 x 10 mm; the field grows with N).
DENSITY = 100.0
#: Gaussian bumps per mm^2.
BUMPS_PER_MM2 = 0.5


def height_field(rng, half, bumps, amp=0.15):
    """Height z(x, y) and its gradient for a sum of Gaussian bumps, as a function of (m, 2) points."""
    c = rng.uniform(-half, half, (bumps, 2))
    s = rng.uniform(0.3, 0.8, bumps)
    a = rng.uniform(-amp, amp, bumps)

    def f(xy):
        dx = xy[:, None, :] - c[None]
        g = a * np.exp(-np.sum(dx**2, -1) / (2 * s**2))
        grad = np.sum((-dx / (s**2)[:, None]) * g[..., None], 1)
        n = np.column_stack([-grad, np.ones(len(xy))])
        return np.column_stack([xy, g.sum(1)]), n / np.linalg.norm(n, axis=1)[:, None]

    return f


def scene(n, seed=0, matched=0.9, beside_mm=0.005, noise_px=0.05):
    """Rig and the two cameras' HighlightRays for N highlights per camera (module docstring)."""
    from shinysim.recon.stereo import highlight_rays
    from shinysim.rig import Camera, Rig, stereo_pair

    rng = np.random.default_rng(seed)
    half = 0.5 * math.sqrt(n / DENSITY)  # the same density of highlights at every N
    cam = Camera("perspective", 512, 512, [0.0, 0.0, 127.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], 2 * half + 1.0)
    base = stereo_pair(Rig(np.array([[0.0, 0.0, 43.18]]), np.zeros(1), (cam,)), beta_deg=15.0)
    f = height_field(rng, half, max(2, round(BUMPS_PER_MM2 * (2 * half) ** 2)))
    m = int(round(matched * n))
    xy = rng.uniform(-half, half, (m, 2))
    E1, N1 = f(xy)
    E2, N2 = f(xy + rng.uniform(-beside_mm, beside_mm, (m, 2)))
    extra = [f(rng.uniform(-half, half, (n - m, 2))) for _ in range(2)]
    pts = [np.concatenate([E1, extra[0][0]]), np.concatenate([E2, extra[1][0]])]
    nrm = [np.concatenate([N1, extra[0][1]]), np.concatenate([N2, extra[1][1]])]
    sources = []
    for k, c in enumerate(base.cameras):
        v = c.view_directions(pts[k])
        sources.append(pts[k] + 43.18 * (2 * np.sum(nrm[k] * v, 1)[:, None] * nrm[k] - v))
    rig = Rig(np.concatenate(sources), np.zeros(2 * n), base.cameras)
    rays = []
    for k, c in enumerate(rig.cameras):
        rr, cc = c.project(pts[k])
        rays.append(highlight_rays(rr + rng.normal(0, noise_px, n), cc + rng.normal(0, noise_px, n),
                                   np.arange(n) + k * n, rig, k))
    return rig, rays[0], rays[1], m


def median_seconds(fn, repeats, stages=None):
    """Median wall seconds of ``fn()`` over ``repeats`` runs after a warm-up; with ``stages`` (a dict), also
    the median of each entry of the results' ``seconds`` (per-stage times of :func:`match_highlights`)."""
    fn()  # warm-up
    times, per_stage = [], {}
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = fn()
        times.append(time.perf_counter() - t0)
        for name, sec in getattr(res, "seconds", {}).items():
            per_stage.setdefault(name, []).append(sec)
    if stages is not None:
        stages.update({name: float(np.median(v)) for name, v in per_stage.items()})
    return float(np.median(times))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 100000],
                        help="highlights per camera (default 1000 10000 100000)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per size (median)")
    parser.add_argument("--naive-max", type=int, default=10000, help="largest N for the O(N^2) baseline")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=None,
                        help="threads of match_highlights (default: one per core); 1thr_s is always 1 thread")
    args = parser.parse_args(argv)

    from shinysim.recon.stereo import (
        StereoParams,
        candidate_pairs,
        candidate_pairs_naive,
        match_highlights,
    )

    params = StereoParams(d0_mm=0.03, max_normal_gap_deg=0.5, depth_range_mm=(-0.4, 0.4), workers=args.workers)
    single = StereoParams(d0_mm=0.03, max_normal_gap_deg=0.5, depth_range_mm=(-0.4, 0.4), workers=1)
    sizes, seconds, breakdown = [], [], []
    print(f"threads: {params.threads}")
    print(f"{'N':>8} {'match_s':>9} {'1thr_s':>9} {'cand_s':>9} {'peak_MB':>8} {'cands':>9} {'matches':>8}"
          f" {'right':>7} {'naive_s':>9} {'ratio':>8} {'same':>5}")
    for n in sorted(args.sizes):
        rig, r1, r2, m = scene(n, args.seed)
        stages = {}
        t_match = median_seconds(lambda: match_highlights(r1, r2, rig, params), args.repeats, stages)
        t_one = median_seconds(lambda: match_highlights(r1, r2, rig, single), args.repeats)
        breakdown.append((n, stages))
        t_cand = median_seconds(lambda: candidate_pairs(r1, r2, rig, params), args.repeats)
        tracemalloc.start()
        res = match_highlights(r1, r2, rig, params)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        right = int(np.count_nonzero((res.index1 == res.index2) & (res.index1 < m)))
        naive_s, ratio, same = float("nan"), float("nan"), "-"
        if n <= args.naive_max:
            t0 = time.perf_counter()
            ni, nj = candidate_pairs_naive(r1, r2, rig, params)
            naive_s = time.perf_counter() - t0
            ii, jj = candidate_pairs(r1, r2, rig, params)
            ratio = naive_s / t_cand
            same = "yes" if np.array_equal(ni, ii) and np.array_equal(nj, jj) else "NO"
        print(f"{n:>8} {t_match:>9.4f} {t_one:>9.4f} {t_cand:>9.4f} {peak:>8.1f} {res.n_candidates:>9} {len(res):>8} "
              f"{right / m:>7.3f} {naive_s:>9.3f} {ratio:>8.1f} {same:>5}", flush=True)
        sizes.append(n)
        seconds.append(t_match)
    # per stage (medians of the same timed runs): index, exact tests, support weights and relaxation,
    # uniqueness and confidence, reflectance matching of the accepted pairs, the umbilic refinement
    names = ("candidates", "tests", "relaxation", "uniqueness", "reflectance", "refinement")
    print(f"{'N':>8} " + " ".join(f"{name:>11}" for name in names) + f" {'sum_s':>8}")
    for n, stages in breakdown:
        print(f"{n:>8} " + " ".join(f"{stages.get(name, float('nan')):>11.4f}" for name in names)
              + f" {sum(stages.values()):>8.4f}")
    slope = float(np.polyfit(np.log(sizes), np.log(seconds), 1)[0]) if len(sizes) > 1 else float("nan")
    print(f"n={sizes[-1]} seconds={seconds[-1]:.4f} slope={slope:.3f}")


if __name__ == "__main__":
    main()
