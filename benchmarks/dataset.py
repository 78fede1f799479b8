"""Data-set throughput: scenes per hour on the default local Dask cluster, worker scaling, memory per worker.

    python benchmarks/dataset.py [--items 60] [--solder-items 8] [--memory-items 1000] [--variant V]

Sphere scenes as the issue states them: 512 x 512, the 21-fiber rig, 64 spp,
truth with a 4 x 4 coverage grid, a 12-bit sensor, random radius, position,
alpha and exposure; each run writes a fresh data-set folder in a temporary
place. Rates count the whole command (cluster start included); the steady
rate (first to last item) is printed beside. Runs, in one process, one after
another (never two at once on the same cores):

1. the default cluster (one worker per core, one renderer thread each);
2. one worker with one thread, and one worker with all the cores' threads;
3. solder joints (256 px, 16 spp, paths of depth 3, one scene per joint);
4. memory: ``--memory-items`` small sphere items (128 px) on the default
   cluster, each worker's resident memory at its 100th and its last item.

The last line reads ``scenes_per_hour=<x> speedup_2_workers=<y>`` (2 workers
of one thread against 1 worker of one thread).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from shinysim.datasets.engine import default_workers, run_dataset
from shinysim.datasets.spec import parse_spec


def sphere_spec(n, resolution=512, spp=64):
    return {
        "format": "shinysim-dataset/1", "name": "benchmark spheres", "seed": 0,
        "groups": [{
            "name": "spheres", "count": n,
            "render": {"resolution": resolution, "spp": spp, "coverage": 4},
            "object": {"kind": "sphere", "radius_mm": {"uniform": [0.6, 0.8]},
                       "center_mm": [{"uniform": [-0.15, 0.15]}, {"uniform": [-0.15, 0.15]}, 0]},
            "material": {"kind": "conductor", "alpha": {"loguniform": [0.005, 0.05]}},
            "sensor": {"preset": "machine_vision_12bit", "exposure": {"uniform": [0.5, 1.0]}},
        }],
    }


def solder_spec(n):
    return {
        "format": "shinysim-dataset/1", "name": "benchmark solder", "seed": 0,
        "groups": [{"name": "joints", "count": n, "render": {"resolution": 256, "spp": 16, "coverage": 0,
                                                              "max_depth": 3},
                    "object": {"kind": "solder",
                               "class": {"choice": ["good", "insufficient", "excess", "lifted", "bridge"]}}}],
    }


def run(doc, *, workers=None, threads=None, variant=None, timings=False):
    with tempfile.TemporaryDirectory(prefix="shinysim-bench-") as tmp:
        tfile = Path(tmp) / "timings.jsonl" if timings else None
        t0 = time.perf_counter()
        summary = run_dataset(parse_spec(doc), Path(tmp) / "ds", workers=workers, threads=threads, variant=variant,
                              timings=tfile, progress=_log)
        wall = time.perf_counter() - t0
        rows = [json.loads(line) for line in tfile.read_text().splitlines()] if tfile else []
    if summary["failed"]:
        print(f"  {len(summary['failed'])} item(s) failed: {summary['failed']}")
    return summary["n_items"], wall, rows


def _log(stage, done, total, message=None):
    if message and "failed" in message:
        print(f"  {message}", flush=True)


def steady(rows):
    t = sorted(r["time"] for r in rows)
    return 3600 * (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else float("nan")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--items", type=int, default=60, help="sphere scenes per run [60]")
    p.add_argument("--solder-items", type=int, default=8)
    p.add_argument("--memory-items", type=int, default=1000)
    p.add_argument("--variant", default=None)
    a = p.parse_args()
    if a.variant:  # one line, before any cluster starts, where the variant cannot run here
        from shinysim.errors import ShinysimError
        from shinysim.sim.variants import choose_variant

        try:
            choose_variant(a.variant)
        except ShinysimError as e:
            sys.exit(f"dataset: {e}")
    w, th = default_workers()
    cores = w * th
    print(f"cores={cores} default cluster: {w} worker(s) x {th} renderer thread(s)")

    n, wall, rows = run(sphere_spec(a.items), variant=a.variant, timings=True)
    default_rate = 3600 * n / wall
    print(f"spheres 512^2 64spp, default cluster: {n} in {wall:.1f} s = {default_rate:.0f} scenes/h "
          f"(steady {steady(rows):.0f}/h)")
    n1, wall1, rows1 = run(sphere_spec(a.items), workers=1, threads=1, variant=a.variant, timings=True)
    rate1 = 3600 * n1 / wall1
    print(f"spheres, 1 worker x 1 thread: {rate1:.0f} scenes/h (steady {steady(rows1):.0f}/h)")
    n2, wall2, rows2 = run(sphere_spec(a.items), workers=2, threads=1, variant=a.variant, timings=True)
    rate2 = 3600 * n2 / wall2
    print(f"spheres, 2 workers x 1 thread: {rate2:.0f} scenes/h (steady {steady(rows2):.0f}/h)")
    if cores > 1:
        n3, wall3, rows3 = run(sphere_spec(a.items), workers=1, threads=cores, variant=a.variant, timings=True)
        print(f"spheres, 1 worker x {cores} threads: {3600 * n3 / wall3:.0f} scenes/h (steady {steady(rows3):.0f}/h)")
    if a.solder_items:
        ns, walls, rowss = run(solder_spec(a.solder_items), variant=a.variant, timings=True)
        print(f"solder 256^2 16spp depth 3, default cluster: {ns} in {walls:.1f} s = {3600 * ns / walls:.0f} "
              f"scenes/h (steady {steady(rowss):.0f}/h)")
    if a.memory_items:
        nm, wallm, rowsm = run(sphere_spec(a.memory_items, resolution=128, spp=16), variant=a.variant, timings=True)
        by_worker = {}
        for r in sorted(rowsm, key=lambda r: r["time"]):
            by_worker.setdefault(r["worker_pid"], []).append(r["rss_mb"])
        for pid, rss in by_worker.items():
            at = min(99, len(rss) - 1)
            print(f"memory, worker {pid}: {len(rss)} items, resident {rss[at]:.0f} MiB at its item {at + 1}, "
                  f"{rss[-1]:.0f} MiB at its last, peak {max(rss[at:]):.0f} MiB "
                  f"(growth {100 * (max(rss[at:]) / rss[at] - 1):+.1f} %)")
        print(f"memory run: {nm} items in {wallm:.0f} s")
    print(f"scenes_per_hour={default_rate:.0f} speedup_2_workers={rate2 / rate1:.2f}")


if __name__ == "__main__":
    main()
