"""Generate a data set on Dask: resumable, deterministic, one folder per item.

:func:`run_dataset` renders every item of a spec that the folder does not
hold yet, on a Dask ``LocalCluster`` sized to the machine or on an existing
scheduler, writing each item into a temporary folder renamed into place whole
and only then appending its row to ``manifest.jsonl``; a run killed at any
moment is finished by the next run of the same command, with the same bytes.
:func:`build_one` builds one item, :func:`read_manifest` reads the record.
The folder's layout and why a rerun is safe: ``docs/datasets.md``, sections
"What a data-set folder holds" and "How it stays deterministic and safe".
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable, Iterable
from itertools import islice
from pathlib import Path
from typing import Any

from .. import __version__
from .._shared import cores, stage_reporter, write_text
from ..errors import OptionError, SpecError
from ..io.document import read_document
from .items import SHARD_SIZE, file_sha256
from .spec import DatasetSpec, load_spec, resolve_item, spec_diff

__all__ = ["DATASET_FORMAT", "run_dataset", "build_one", "read_manifest", "prepare_folder", "default_workers"]

DATASET_FORMAT = "shinysim-dataset-folder/1"
MANIFEST = "manifest.jsonl"


def default_workers() -> tuple[int, int]:
    """(workers, renderer threads per worker) for this machine: one worker per core, one thread each.

    Items are independent, so processes scale better than threads inside one
    render (the renderer's thread pool idles while a worker writes files);
    ``workers * threads`` never exceeds the cores.
    """
    return cores(), 1


def _inputs(spec: DatasetSpec) -> dict:
    """Digests of the files the spec names (rig and mesh files): part of what the folder was made from."""
    out = {}
    for g in spec.groups:
        for section, key in (("rig", "path"), ("object", "path")):
            p = g[section].get(key)
            if p:
                out[p] = file_sha256(spec.base_dir / p)
    return out


def _fingerprint(spec: DatasetSpec, variant: str) -> dict:
    import drjit
    import mitsuba

    return {
        "format": DATASET_FORMAT,
        "spec": spec.document,
        "spec_sha256": spec.sha256,
        "n_items": spec.n_items,
        "inputs": _inputs(spec),
        "renderer": {"shinysim": __version__, "mitsuba": mitsuba.__version__, "drjit": drjit.__version__,
                     "variant": variant},
        "layout": {"items": "items/SSSSS/IIIIIIII (shard = index // %d, 5 and 8 digits)" % SHARD_SIZE,
                   "manifest": MANIFEST},
    }


def prepare_folder(out: Path, fingerprint: dict) -> None:
    """Create the folder, or check that an existing one was made from the same spec and renderer."""
    meta = out / "dataset.json"
    if out.exists() and not out.is_dir():
        raise OptionError(f"{out} exists and is not a folder")
    if meta.is_file():
        old = read_document(meta, error=SpecError, what="data-set record")
        if old.get("format") != DATASET_FORMAT:
            raise SpecError(f"format {old.get('format')!r} is not {DATASET_FORMAT!r}", path=meta, field="format")
        diffs = [d for key in ("spec", "inputs", "renderer") for d in spec_diff(old.get(key), fingerprint[key], key)]
        if diffs:
            shown = "; ".join(diffs[:8]) + (f"; and {len(diffs) - 8} more" if len(diffs) > 8 else "")
            raise SpecError(f"the folder was made from another spec or renderer: {shown} (use a new folder, or "
                            f"the spec and renderer it was made with)", path=meta)
        return
    if out.exists() and any(out.iterdir()):
        raise OptionError(f"{out} is not empty and holds no dataset.json: give a new or empty folder")
    out.mkdir(parents=True, exist_ok=True)
    write_text(meta, json.dumps(fingerprint, indent=2, sort_keys=True) + "\n")


def read_manifest(out: str | os.PathLike, *, repair: bool = False) -> dict[int, dict]:
    """The manifest's rows by item index (a later row for an index replaces an earlier one).

    A torn last row (a run killed while appending it) is ignored, and with
    ``repair`` the file is rewritten without it; any other unreadable row is
    an error naming the line.
    """
    path = Path(out) / MANIFEST
    rows: dict[int, dict] = {}
    if not path.exists():
        return rows
    *body, last = path.read_bytes().split(b"\n")
    torn = last != b""  # the file should end with a newline
    for n, line in enumerate(body, 1):
        try:
            row = json.loads(line)
            rows[int(row["index"])] = row
        except (ValueError, KeyError, TypeError):
            raise SpecError(f"line {n} is not a manifest row", path=path, field=f"line {n}") from None
    if torn and repair:
        _rewrite_manifest(path, rows)
    return rows


def _row_line(row: dict) -> str:
    return json.dumps(row, sort_keys=True, separators=(",", ":")) + "\n"


def _rewrite_manifest(path: Path, rows: dict[int, dict]) -> None:
    write_text(path, "".join(_row_line(rows[i]) for i in sorted(rows)), overwrite=True)


def _clean(out: Path, done: set[int]) -> int:
    """Remove temporary folders and item folders the manifest does not record; returns how many."""
    removed = 0
    for entry in (out / "items").glob("*/*"):  # every entry of every shard folder, hidden ones too
        name = entry.name
        if name.startswith(".tmp-") or not (name.isdigit() and int(name) in done):
            shutil.rmtree(entry, ignore_errors=True) if entry.is_dir() else entry.unlink(missing_ok=True)
            removed += 1
    return removed


class _Lock:
    """An exclusive lock on the folder (released by the kernel if the process dies)."""

    def __init__(self, out: Path):
        self.path = out / ".lock"

    def __enter__(self):
        import fcntl

        self.f = open(self.path, "a")
        try:
            fcntl.flock(self.f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self.f.close()
            raise OptionError(f"{self.path.parent} is being written by another run") from None
        return self

    def __exit__(self, *exc):
        self.f.close()


def run_dataset(spec: str | os.PathLike | DatasetSpec, out: str | os.PathLike, *, workers: int | None = None,
                threads: int | None = None, scheduler: str | None = None, retries: int = 2,
                items: Iterable[int] | None = None, variant: str | None = None,
                timings: str | os.PathLike | None = None,
                progress: Callable[..., None] | None = None) -> dict[str, Any]:
    """Generate (or finish) a data set.

    Parameters
    ----------
    spec : path-like or DatasetSpec
    out : path-like
        The data-set folder (created; an existing one must have been made
        from the same spec, and then only its missing items are rendered).
    workers : int, optional
        Local worker processes (default: one per core). Ignored with ``scheduler``.
    threads : int, optional
        Renderer threads per worker (default: cores // workers, at least 1;
        1 on an existing scheduler's workers).
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``) whose
        workers see ``out`` at the same path.
    retries : int
        Times a failed item is retried before it is recorded as failed.
    items : iterable of int, optional
        Only these item indices (default: all).
    variant : str, optional
        Mitsuba variant (default: the fastest here; every worker uses it).
    timings : path-like, optional
        Append one JSON line per finished item (seconds, worker memory) here.
    progress : callable, optional
        ``progress("item", done, total)`` after each item, and
        ``progress("info", 0, 0, message)`` for one-line messages (as the
        other long commands report).

    Returns
    -------
    dict
        ``{"n_items", "done", "failed", "rendered", "seconds", "items_per_hour"}``.

    Examples
    --------
    Two spheres under the paper's rig at 32 x 32 pixels, 4 samples per
    pixel, on one local worker:

    >>> import tempfile
    >>> from pathlib import Path
    >>> from shinysim.datasets.spec import SPEC_FORMAT, parse_spec
    >>> spec = parse_spec({"format": SPEC_FORMAT, "seed": 1,
    ...                    "groups": [{"count": 2, "render": {"resolution": 32, "spp": 4}}]})
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     summary = run_dataset(spec, Path(tmp) / "spheres", workers=1)
    ...     rows = read_manifest(Path(tmp) / "spheres")
    >>> summary["n_items"], summary["done"], summary["failed"], [row["status"] for row in rows.values()]
    (2, 2, [], ['done', 'done'])
    """
    from ..sim.variants import choose_variant

    if not isinstance(spec, DatasetSpec):
        spec = load_spec(spec)
    out = Path(out)
    if retries < 0 or retries > 100:
        raise OptionError(f"retries must lie in 0..100, got {retries}")
    variant, why = choose_variant(variant)
    if scheduler is None:
        workers = default_workers()[0] if workers is None else int(workers)
        if workers < 1:
            raise OptionError(f"workers must be >= 1, got {workers}")
    if threads is None:  # an existing cluster's workers' cores are theirs to know: one thread unless told
        threads = 1 if scheduler else max(1, cores() // workers)
    threads = int(threads)
    if threads < 1:
        raise OptionError(f"threads must be >= 1, got {threads}")
    wanted = range(spec.n_items) if items is None else sorted(set(int(i) for i in items))
    for i in wanted:
        spec.group_of(i)  # refuses indices outside the spec
    _, say = stage_reporter(progress, None)
    prepare_folder(out, _fingerprint(spec, variant))
    with _Lock(out):
        rows = read_manifest(out, repair=True)
        done = {i for i, r in rows.items() if r.get("status") == "done" and (out / r["path"]).is_dir()}
        removed = _clean(out, done)
        pending = [i for i in wanted if i not in done]
        say(f"{len(done)} of {spec.n_items} items already done; {len(pending)} to render"
            + (f"; removed {removed} unfinished item folder(s)" if removed else "") + f" ({why})")
        t0 = time.perf_counter()
        n_done = n_failed = 0
        if pending:
            n_done, n_failed = _render(spec, out, pending, workers=workers, threads=threads,
                                       scheduler=scheduler, retries=retries, variant=variant, timings=timings,
                                       progress=progress, total=len(wanted), already=len(wanted) - len(pending))
        rows = read_manifest(out)
        _rewrite_manifest(out / MANIFEST, rows)
        seconds = time.perf_counter() - t0
    return {
        "n_items": spec.n_items,
        "done": sum(1 for r in rows.values() if r.get("status") == "done"),
        "failed": sorted(i for i, r in rows.items() if r.get("status") == "failed"),
        "rendered": n_done,
        "seconds": seconds,
        "items_per_hour": 3600 * n_done / seconds if n_done and seconds > 0 else None,
    }


def _render(spec, out, pending, *, workers, threads, scheduler, retries, variant, timings, progress,
            total, already):
    import logging

    from concurrent.futures import CancelledError

    from dask.distributed import Client, LocalCluster, as_completed

    from .items import write_item

    _, say = stage_reporter(progress, None)
    cluster = None
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except OSError as exc:
            raise OptionError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    else:
        import dask

        # Dask's nanny sets MALLOC_TRIM_THRESHOLD_ in its workers, which makes glibc unmap freed memory at once;
        # under it the renderer's lane kernel has been seen to fault on a read of freed memory (docs/datasets.md,
        # "Known issue"), so the local workers keep glibc's default allocator
        environ = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
                   if k != "MALLOC_TRIM_THRESHOLD_"}
        # the scheduler's HTTP server (health and metrics routes, the dashboard if bokeh is installed) on a free
        # loopback port: with dashboard_address=None it would still take 8787, and warn where that is in use
        with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR)
        client = Client(cluster)
    manifest = open(out / MANIFEST, "a")
    timing_file = open(timings, "a") if timings else None
    n_done = n_failed = 0
    try:
        n_workers = max(1, len(client.scheduler_info().get("workers", {})) or (workers or 1))
        queue = iter(pending)
        items_of = {}

        def submit(i):
            item = resolve_item(spec, i)
            fut = client.submit(write_item, item, str(out.resolve()), base_dir=str(spec.base_dir.resolve()),
                                variant=variant, threads=threads, key=f"shinysim-item-{spec.sha256[:12]}-{i}",
                                retries=retries, pure=False)
            items_of[fut.key] = item
            return fut

        # a bounded window of submitted items: the client never holds thousands of futures
        window = [submit(i) for i in islice(queue, 4 * n_workers)]
        ac = as_completed(window)
        for fut in ac:
            item = items_of.pop(fut.key)
            try:
                # an item's result is a small dict (its files are written by the worker): a minute is ample
                result = fut.result(timeout=60) if fut.status == "finished" else None
            except (OSError, TimeoutError, CancelledError):  # the scheduler is gone (Dask cancels every future)
                result = None
            if result is None and fut.status != "error":
                raise OptionError(f"lost the Dask scheduler at {scheduler or 'the local cluster'} after "
                                  f"{already + n_done + n_failed} of {total} items; what is done is recorded: "
                                  "run the same command again to finish")
            row = {"index": item["index"], "seed": item["seed"], "group": item["group_name"], "item": item}
            if result is not None:
                row.update(status="done", path=result["path"], files=result["files"])
                n_done += 1
                if timing_file:
                    timing_file.write(json.dumps({"index": item["index"], "seconds": result["seconds"],
                                                  "rss_mb": result["rss_mb"], "worker_pid": result["pid"],
                                                  "time": time.time()}) + "\n")
                    timing_file.flush()
            else:
                exc = fut.exception()
                row.update(status="failed", error=f"{type(exc).__name__}: {exc}")
                n_failed += 1
                say(f"item {item['index']} failed after {retries} retries: {row['error']}")
            manifest.write(_row_line(row))
            manifest.flush()
            os.fsync(manifest.fileno())
            fut.release()
            if progress:
                progress("item", already + n_done + n_failed, total)
            nxt = next(queue, None)
            if nxt is not None:
                ac.add(submit(nxt))
    finally:
        manifest.close()
        if timing_file:
            timing_file.close()
        client.close()
        if cluster is not None:
            cluster.close()
    return n_done, n_failed


def build_one(spec: str | os.PathLike | DatasetSpec, index: int, out: str | os.PathLike, *,
              variant: str | None = None, overwrite: bool = False) -> list[str]:
    """Render item ``index`` of a spec alone, in this process, into ``out``: the same bytes as in the data set.

    Returns the names of the files written.
    """
    from .._shared import output_folder
    from ..sim.variants import choose_variant
    from .items import item_files, render_item, write_files
    from .spec import build_rig

    if not isinstance(spec, DatasetSpec):
        spec = load_spec(spec)
    item = resolve_item(spec, int(index))
    variant, _ = choose_variant(variant)
    n_cam = len(build_rig(item["rig"], item["render"]["resolution"], spec.base_dir).cameras)
    names = item_files(n_cam)
    with output_folder(out, names, overwrite=overwrite) as tmp:
        write_files(item, render_item(item, base_dir=spec.base_dir, variant=variant), tmp)
    return names
