"""Full-size solder-inspection study: the numbers behind docs/solder.md ("Inspection under nuisances").

Runs :func:`shinysim.studies.inspection.run_inspection` with 80 training and
100 held-out joints per class (900 joints, about 45 minutes on two CPU cores
with the LLVM variant), prints the summary and the robustness table, and checks
the targets: held-out accuracy >= 0.95 and good-joint height RMS (above the pad
top, the pad thickness unknown to the reconstruction) <= 2 % of the fillet
height. The exit status is 1 when a target is missed.

Usage::

    python benchmarks/solder_inspection.py --out inspect-full [--cache inspect-full.jsonl]

With ``--cache`` every finished joint is kept in a JSON-lines file, so an
interrupted run resumes and a rerun (e.g. after changing the classifier)
renders nothing. The CI runs the same code at small size
(``tests/test_inspection_run.py``).
"""

from __future__ import annotations

import argparse
import sys
import time

from shinysim.studies.inspection import run_inspection, summary_lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--cache", default=None)
    ap.add_argument("--n-train", type=int, default=80)
    ap.add_argument("--n-test", type=int, default=100)
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    done = [0]

    def progress(stage, k, n, *rest):
        if k - done[0] >= 25 or k == n:
            done[0] = k
            print(f"{k}/{n} joints, {time.perf_counter() - t0:.0f} s", flush=True)

    rep = run_inspection(args.out, n_train=args.n_train, n_test=args.n_test, resolution=args.resolution,
                         spp=args.spp, seed=args.seed, overwrite=args.overwrite, cache=args.cache,
                         progress=progress)
    print("\n".join(summary_lines(rep)))
    acc = rep["accuracy"]
    h = rep["good_joint_heights"]["height_above_pad_rms_pct"]
    ok_acc = acc["accuracy"] is not None and acc["accuracy"] >= 0.95
    ok_h = h["median"] is not None and h["median"] <= 2.0
    print(f"target accuracy >= 0.95: {'met' if ok_acc else 'MISSED'} ({acc['accuracy']:.3f}, "
          f"95% CI {acc['ci95'][0]:.3f}-{acc['ci95'][1]:.3f})")
    share = rep["good_joint_heights"]["share_within_2pct"]
    print(f"target good-joint height RMS <= 2 %: {'met' if ok_h else 'MISSED'} (median {h['median']:.2f} %, "
          f"{100 * share:.0f} % of the {h['n']} measured good joints within 2 %)")
    return 0 if ok_acc and ok_h else 1


if __name__ == "__main__":
    sys.exit(main())
