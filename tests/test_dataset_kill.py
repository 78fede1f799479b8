"""``shinysim dataset`` killed with SIGKILL at random moments ends with the same bytes as an uninterrupted run.

The command runs as a separate process (as a user runs it); the test kills
the client (and with it its local cluster), or first one of its worker
processes, at moments drawn from a seeded generator (while the cluster starts,
or in the 0.3 s after the run records an item), restarts the same command each time, and finally lets it finish. The
folder must then equal, file for file and byte for byte, the folder of a run
that was never interrupted. The folder is checked after every kill too: every
manifest row names a complete item folder.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import skip_without_jit, skip_without_render

pytestmark = [pytest.mark.render, skip_without_render, skip_without_jit]

psutil = pytest.importorskip("psutil")
pytest.importorskip("dask.distributed")

SPEC = {
    "format": "shinysim-dataset/1", "name": "kill", "seed": 5,
    "defaults": {"render": {"resolution": 48, "spp": 4, "coverage": 2}},
    "groups": [
        {"name": "spheres", "count": 160, "object": {"kind": "sphere", "radius_mm": {"uniform": [0.5, 0.8]}},
         "material": {"kind": "conductor", "alpha": {"loguniform": [0.01, 0.05]}},
         "sensor": {"preset": "machine_vision_12bit", "exposure": 0.8}},
        {"name": "stereo", "count": 2, "rig": {"preset": "stereo", "beta_deg": 20}},
    ],
}


def command(spec, out):
    return [sys.executable, "-m", "shinysim.cli", "dataset", str(spec), "--out", str(out), "--workers", "2",
            "--quiet"]


def folder_bytes(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def kill_tree(proc, *, worker_first: bool, rng) -> str:
    """SIGKILL a worker process (then, a moment later, the client) or the client; wait until all are gone."""
    try:
        family = psutil.Process(proc.pid).children(recursive=True)
    except psutil.NoSuchProcess:
        family = []
    what = "client"
    workers = [p for p in family if "spawn_main" in " ".join(p.cmdline() or [])] if family else []
    if worker_first and workers:
        workers[int(rng.integers(len(workers)))].send_signal(signal.SIGKILL)
        what = "worker, then client"
        time.sleep(float(rng.uniform(0.05, 0.3)))
        try:
            family = psutil.Process(proc.pid).children(recursive=True)
        except psutil.NoSuchProcess:
            pass
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    # the local cluster's processes end when the client does; wait for that (never leave them running)
    gone, alive = psutil.wait_procs(family, timeout=20)
    for p in alive:
        p.kill()
    return what


def check_consistent(out: Path):
    """Every manifest row (but a torn last one) names a complete item folder; no other item folder is complete."""
    manifest = out / "manifest.jsonl"
    if not manifest.exists():
        return 0
    lines = manifest.read_bytes().split(b"\n")
    rows = [json.loads(line) for line in lines[:-1]]
    for row in rows:
        folder = out / row["path"]
        names = sorted(p.name for p in folder.iterdir())
        assert names == sorted(row["files"]), (row["index"], names)
        for name, meta in row["files"].items():
            assert (folder / name).stat().st_size == meta["bytes"], (row["index"], name)
    return len(rows)


def test_killed_and_restarted_ten_times_gives_the_same_bytes(tmp_path):
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps(SPEC))
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    # the uninterrupted run
    subprocess.run(command(spec, tmp_path / "whole"), check=True, env=env, capture_output=True, timeout=600)
    whole = folder_bytes(tmp_path / "whole")
    assert sum(1 for k in whole if k.endswith("stack.exr")) == 162

    rng = np.random.default_rng(20261130)
    out = tmp_path / "killed"
    log = []
    for round_ in range(10):
        proc = subprocess.Popen(command(spec, out), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        if round_ % 3 == 0:
            # a random moment while the cluster starts (workers starting, the renderer loading): at most until the
            # round's first item is recorded, which on an idle machine can come well within the 3 s (and a few
            # seconds of items would make the data set before the tenth kill)
            before = check_consistent(out)
            deadline = time.monotonic() + float(rng.uniform(0.3, 3.0))
            while time.monotonic() < deadline and check_consistent(out) == before and proc.poll() is None:
                time.sleep(0.05)
        else:
            # a random moment once items are being made
            before = check_consistent(out)
            deadline = time.monotonic() + 60
            while check_consistent(out) == before and proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(float(rng.uniform(0.0, 0.3)))
        if proc.poll() is not None:  # finished before the kill: nothing to kill this round
            log.append((round_, "finished", check_consistent(out)))
            continue
        what = kill_tree(proc, worker_first=round_ % 3 == 2, rng=rng)
        log.append((round_, what, check_consistent(out)))
    done_after_kills = [n for _, _, n in log]
    print("kills (round, what, items recorded):", log)
    # all ten kills fell before the end, most of them while items were being made
    assert all(what != "finished" for _, what, _ in log), log
    assert len(set(done_after_kills)) >= 5 and done_after_kills[-1] < 162, log
    subprocess.run(command(spec, out), check=True, env=env, capture_output=True, timeout=600)
    finished = folder_bytes(out)
    assert sorted(finished) == sorted(whole)
    different = [k for k in whole if finished[k] != whole[k]]
    assert not different, different
