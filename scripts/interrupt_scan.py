"""Interrupt ``shinysim scan`` at random moments and check what it leaves.

For each of ``--trials`` runs, a scan is started in a child process and sent
SIGINT (Ctrl-C) after a random delay drawn uniformly from zero to 1.1 times
the length of an uninterrupted scan measured first (so that some signals
arrive after the scan has finished). After each run the output folder must
be either absent or complete: every scan file present and readable by
shinysim's own readers (rig, stack, truth, highlights, score, PNG), no
hidden ``.NAME.partial-*`` folder left beside it, an interrupted run ending
with exit status 130 and one line on stderr without a traceback (a signal
in the first tenth of a second, while the Python interpreter itself starts
and before any shinysim code runs, gets Python's own handling; such trials
are counted apart). Then the
same scan is run again (with ``--overwrite`` when the folder is complete)
and must succeed.

    python scripts/interrupt_scan.py [--trials 20] [--seed 0] [--resolution 512] [--spp 64]

Prints one line per trial and a summary; exit status 1 if any trial failed.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from shinysim.studies.scan import SCAN_FILES


def scan_command(out, resolution, spp, overwrite=False):
    cmd = [sys.executable, "-m", "shinysim.cli", "scan", "--out", str(out), "--quiet",
           "--resolution", str(resolution), "--spp", str(spp)]
    return cmd + (["--overwrite"] if overwrite else [])


def check_complete(folder):
    """None if ``folder`` is a complete, readable scan folder, else what is wrong."""
    from PIL import Image

    from shinysim.io import load_stack, load_truth
    from shinysim.io.table import read_highlight_table

    missing = [n for n in SCAN_FILES if not (folder / n).is_file()]
    if missing:
        return f"incomplete: missing {', '.join(missing)}"
    try:
        stack = load_stack(folder / "stack.exr")
        load_truth(folder / "truth.exr", stack.camera)
        read_highlight_table(folder / "highlights.csv", n_sources=stack.n_sources, shape=stack.camera.shape)
        json.loads((folder / "score.json").read_text())
        with Image.open(folder / "scan.png") as im:
            im.load()
    except Exception as exc:  # any failure to read a finished file is a finding
        return f"unreadable: {type(exc).__name__}: {exc}"
    return None


def leftovers(folder):
    return sorted(p.name for p in folder.parent.glob(f".{folder.name}.partial-*"))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--resolution", type=int, default=512)
    p.add_argument("--spp", type=int, default=64)
    args = p.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    work = Path(tempfile.mkdtemp(prefix="interrupt-scan-"))
    try:
        t0 = time.perf_counter()
        subprocess.run(scan_command(work / "reference", args.resolution, args.spp), check=True,
                       capture_output=True)
        length = time.perf_counter() - t0
        print(f"an uninterrupted scan takes {length:.1f} s; signals at uniform random moments in "
              f"[0, {1.1 * length:.1f}] s")
        outcomes = {"absent": 0, "complete": 0}
        n_startup = 0
        failures = []
        for trial in range(args.trials):
            out = work / f"scan{trial:02d}"
            delay = float(rng.uniform(0, 1.1 * length))
            proc = subprocess.Popen(scan_command(out, args.resolution, args.spp), stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
            time.sleep(delay)
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=600)
            problems = []
            # a signal while the interpreter itself starts (site, runpy: before any shinysim
            # code runs) gets Python's own handling; it writes nothing either
            startup = "Traceback" in err and "shinysim" not in err.replace(str(out), "")
            if out.exists():
                state = "complete"
                wrong = check_complete(out)
                if wrong:
                    problems.append(wrong)
            else:
                state = "absent"
            if leftovers(out):
                problems.append(f"left {', '.join(leftovers(out))}")
            if "Traceback" in err and not startup:
                problems.append("traceback on stderr")
            if proc.returncode not in (0, 130) and not startup:
                problems.append(f"exit status {proc.returncode}")
            if proc.returncode == 130 and len([ln for ln in err.splitlines() if ln.strip()]) != 1:
                problems.append(f"{len(err.splitlines())} lines on stderr, expected one")
            rerun = subprocess.run(scan_command(out, args.resolution, args.spp, overwrite=out.exists()),
                                   capture_output=True, text=True)
            if rerun.returncode != 0:
                problems.append(f"rerun failed ({rerun.returncode}): {rerun.stderr.strip()[-200:]}")
            elif check_complete(out):
                problems.append(f"rerun left {check_complete(out)}")
            outcomes[state] += 1
            n_startup += startup
            status = "ok" if not problems else "FAIL: " + "; ".join(problems)
            if startup:
                status += " (during the interpreter's start-up)"
            print(f"trial {trial:2d}: SIGINT at {delay:5.2f} s -> exit {proc.returncode:4d}, folder {state:8s} "
                  f"rerun ok={rerun.returncode == 0}  {status}")
            if problems:
                failures.append(trial)
            shutil.rmtree(out, ignore_errors=True)
        print(f"{args.trials} trials: {outcomes['absent']} left no folder, {outcomes['complete']} a complete one, "
              f"{n_startup} hit the interpreter's start-up, {len(failures)} failed")
        return 1 if failures else 0
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
