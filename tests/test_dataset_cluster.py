"""``shinysim dataset --scheduler``: a separately started Dask scheduler and workers give the local cluster's bytes.

The scheduler and two single-threaded worker processes are started as
separate programs (``dask scheduler``, ``dask worker``) on the loopback
interface, as on a cluster; the scheduler is killed with SIGKILL part-way
through a run, everything is started again and the same command finishes
the data set. The result must equal a local-cluster run file for file.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import skip_without_jit, skip_without_render

pytestmark = [pytest.mark.render, skip_without_render, skip_without_jit]

pytest.importorskip("dask.distributed")
psutil = pytest.importorskip("psutil")

SPEC = {
    "format": "shinysim-dataset/1", "name": "cluster", "seed": 11,
    "defaults": {"render": {"resolution": 48, "spp": 4, "coverage": 2}},
    "groups": [
        {"name": "spheres", "count": 40, "object": {"kind": "sphere", "radius_mm": {"uniform": [0.5, 0.8]}},
         "material": {"kind": "conductor", "alpha": {"loguniform": [0.01, 0.05]}}},
        {"name": "blob", "count": 2, "object": {"kind": "blob", "size_mm": 0.6}},
    ],
}
DASK = [sys.executable, "-m", "dask"]


def folder_bytes(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


class Cluster:
    """A scheduler and two worker processes, started as separate programs."""

    def __init__(self, tmp: Path, env):
        self.file = tmp / f"scheduler-{time.monotonic_ns()}.json"
        self.env = env
        # no fixed port: the HTTP server too (without --dashboard-address it takes 8787 even with --no-dashboard)
        self.scheduler = subprocess.Popen(DASK + ["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                                  "--dashboard-address", "127.0.0.1:0", "--scheduler-file",
                                                  str(self.file)],
                                          env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 60
        while not self.file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(0.2)
        self.address = json.loads(self.file.read_text())["address"]
        # glibc's default allocator in the workers, as docs/datasets.md tells users ("Known issue")
        worker_env = dict(env, DASK_DISTRIBUTED__NANNY__PRE_SPAWN_ENVIRON="{}")
        self.workers = subprocess.Popen(DASK + ["worker", self.address, "--nworkers", "2", "--nthreads", "1",
                                                "--no-dashboard"], env=worker_env, stdout=subprocess.DEVNULL,
                                        stderr=subprocess.DEVNULL)
        from dask.distributed import Client

        with Client(self.address, timeout="30s") as c:
            c.wait_for_workers(2, timeout=60)

    def processes(self):
        out = []
        for p in (self.scheduler, self.workers):
            try:
                out += [psutil.Process(p.pid)] + psutil.Process(p.pid).children(recursive=True)
            except psutil.NoSuchProcess:
                pass
        return out

    def stop(self):
        procs = self.processes()
        for p in procs:
            try:
                p.send_signal(signal.SIGKILL)
            except psutil.NoSuchProcess:
                pass
        psutil.wait_procs(procs, timeout=20)
        for p in (self.scheduler, self.workers):
            p.wait(timeout=20)  # reaped, so the Popen objects know


def command(spec, out, *extra):
    return [sys.executable, "-m", "shinysim.cli", "dataset", str(spec), "--out", str(out), "--quiet", *extra]


def test_separate_scheduler_and_workers_give_the_local_bytes_even_after_the_scheduler_is_killed(tmp_path):
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps(SPEC))
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    subprocess.run(command(spec, tmp_path / "local"), check=True, env=env, capture_output=True, timeout=600)

    cluster = Cluster(tmp_path, env)
    try:
        run = subprocess.Popen(command(spec, tmp_path / "remote", "--scheduler", cluster.address), env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        manifest = tmp_path / "remote" / "manifest.jsonl"
        deadline = time.monotonic() + 120
        while (not manifest.exists() or manifest.read_text().count("\n") < 5) and time.monotonic() < deadline:
            time.sleep(0.05)
        cluster.scheduler.send_signal(signal.SIGKILL)  # part-way: the run loses its scheduler
        _, err = run.communicate(timeout=120)
        recorded = manifest.read_text().count("\n")
        assert run.returncode != 0, "the run cannot finish without its scheduler"
        # Dask logs its reconnection attempts; the run's own last word is one line saying what happened
        last = err.decode().strip().splitlines()[-1]
        assert last.startswith("shinysim dataset: error: lost the Dask scheduler at tcp://127.0.0.1:"), last
        assert "run the same command again to finish" in last, last
        assert 5 <= recorded < 42, recorded
    finally:
        cluster.stop()
    cluster = Cluster(tmp_path, env)
    try:
        subprocess.run(command(spec, tmp_path / "remote", "--scheduler", cluster.address), check=True, env=env,
                       capture_output=True, timeout=600)
    finally:
        cluster.stop()
    local, remote = folder_bytes(tmp_path / "local"), folder_bytes(tmp_path / "remote")
    assert sorted(local) == sorted(remote)
    assert [k for k in local if local[k] != remote[k]] == []
