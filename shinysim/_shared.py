"""What every part of shinysim shares: file writing, choice checks, JSON, seeds.

One home for the small helpers that the drivers, readers and writers would
otherwise each grow a copy of. It imports nothing of the package, so every
module may use it (the layering is written in ``tests/test_layering.py``).

* :func:`write_file` (and :func:`write_text`, :func:`write_bytes`,
  :func:`write_json`): the one atomic, no-clobber writer behind every file
  the package writes: text, JSON, CSV, EXR, PNG, PLY;
* :func:`refuse_existing` and :func:`check_free`: refuse, before any work,
  to replace a file or to write into a folder that already holds a run's files;
* :func:`check_choice`: a string option checked against its valid choices;
* :func:`with_overrides`: a settings dataclass with single fields overridden;
* :func:`json_safe`: numpy scalars and arrays to plain JSON (NaN -> null);
* :func:`derive_seed`: a reproducible 31-bit seed from any tuple of parts;
* :func:`lazy_face`: a package ``__init__`` that imports its parts when first used;
* the tolerances that several tests and studies share, each with its reason.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import importlib
import math
import os
import secrets
import shutil
import signal
import sys
import threading
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from .errors import OptionError

__all__ = [
    "write_file",
    "write_bytes",
    "write_text",
    "write_json",
    "refuse_existing",
    "check_free",
    "check_space",
    "output_folder",
    "signals_held",
    "check_choice",
    "check_number",
    "with_overrides",
    "json_safe",
    "derive_seed",
    "lazy_face",
    "Progress",
    "EXACT_TOL",
    "EXACT_MM_TOL",
    "EXACT_DEG_TOL",
    "ORACLE_CENTROID_PX",
]


# -- files --------------------------------------------------------------------------


def _exists_message(path: Path) -> str:
    return f"{path} exists; not overwriting it (pass overwrite=True to replace it)"


def _temporary_beside(path: Path) -> Path:
    """Create an empty, unique temporary file beside ``path`` and return its name.

    Created with mode 0666 filtered by the process umask, as ``open`` would
    create the file itself (0644 under the usual umask 022), so the finished
    file has the permissions the user expects.
    """
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return tmp
    raise FileExistsError(f"no free temporary name beside {path}")  # pragma: no cover


def _claim(tmp: Path, path: Path, overwrite: bool) -> None:
    """Move a finished temporary file into place; never clobber unless asked."""
    if overwrite:
        os.replace(tmp, path)
        return
    try:
        os.link(tmp, path)  # atomic, and fails if ``path`` appeared meanwhile
    except FileExistsError:
        raise FileExistsError(_exists_message(path)) from None
    except OSError:
        # file systems without hard links: check, then rename
        if path.exists():
            raise FileExistsError(_exists_message(path)) from None
        os.replace(tmp, path)
        return
    os.unlink(tmp)


def write_file(path: str | os.PathLike, write: Callable[[str], None], *, overwrite: bool = False) -> Path:
    """Write a file atomically: ``write(tmp)`` fills a temporary file beside it.

    The temporary file is moved into place only when ``write`` returns, so a
    reader never sees a half-written file, and it is removed whatever goes
    wrong (an exception, Ctrl-C). An existing ``path`` is never replaced
    unless ``overwrite``; the check is made before ``write`` runs and again,
    atomically, when the file is moved into place.

    Parameters
    ----------
    path : path-like
        The file to write; its folder must exist.
    write : callable
        ``write(tmp_path: str)`` writes the whole content to ``tmp_path`` (an
        empty file that already exists), e.g. an EXR writer or ``savefig``.
    overwrite : bool

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    FileExistsError
        ``path`` exists and ``overwrite`` is False.
    """
    path = Path(path)
    refuse_existing(path, overwrite)
    tmp = _temporary_beside(path)
    try:
        write(str(tmp))
        _claim(tmp, path, overwrite)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def write_bytes(path: str | os.PathLike, data: bytes, *, overwrite: bool = False) -> Path:
    """Write bytes atomically without clobbering (:func:`write_file`)."""
    return write_file(path, lambda tmp: Path(tmp).write_bytes(data), overwrite=overwrite)


def write_text(path: str | os.PathLike, text: str, *, overwrite: bool = False) -> Path:
    """Write UTF-8 text atomically without clobbering (:func:`write_file`)."""
    return write_bytes(path, text.encode("utf-8"), overwrite=overwrite)


def write_json(path: str | os.PathLike, obj: Any, *, overwrite: bool = False, ensure_ascii: bool = True) -> Path:
    """Write ``json_safe(obj)`` as JSON indented by 2, with a final newline (:func:`write_file`)."""
    import json

    text = json.dumps(json_safe(obj), indent=2, ensure_ascii=ensure_ascii) + "\n"
    return write_text(path, text, overwrite=overwrite)


def refuse_existing(path: str | os.PathLike, overwrite: bool) -> None:
    """Raise ``FileExistsError`` if ``path`` exists (or is a link) and ``overwrite`` is False."""
    path = Path(path)
    if not overwrite and (path.exists() or path.is_symlink()):
        raise FileExistsError(_exists_message(path))


def check_free(folder: str | os.PathLike, names: Iterable[str], overwrite: bool) -> None:
    """Refuse to write a run's files into ``folder`` if any of them is there.

    Called before any work is done, so that a long render never ends in a
    refusal.

    Raises
    ------
    FileExistsError
        Naming the files already present (unless ``overwrite``).
    """
    if overwrite:
        return
    folder = Path(folder)
    clash = [n for n in names if os.path.lexists(folder / n)]  # a dangling link counts
    if clash:
        raise FileExistsError(f"{folder} already holds {', '.join(clash)}; choose another folder or pass --overwrite")


def check_space(folder: str | os.PathLike, needed_bytes: int, what: str = "the output") -> None:
    """Refuse, before any work, to write ``needed_bytes`` where there is less room.

    ``folder`` is the output folder or, when it does not exist yet, its
    nearest existing parent.
    """
    where = Path(folder)
    while not where.exists() and where != where.parent:
        where = where.parent
    free = shutil.disk_usage(where).free
    if free < needed_bytes:
        raise OSError(errno.ENOSPC, f"{what} needs about {needed_bytes / 2**20:.0f} MiB but {where} has "
                      f"{free / 2**20:.0f} MiB free", str(folder))


@contextlib.contextmanager
def signals_held():
    """Hold SIGINT and SIGTERM until the block ends, then deliver them.

    For the few steps that an interruption would corrupt rather than stop:
    moving a finished output folder into place, and importing a C extension
    (Mitsuba's variant set-up), which a KeyboardInterrupt can leave half
    initialised. While the block runs, the signals' Python handlers only
    record them (also one that arrived just before the block, which Python
    handles at its next check); after it, the original handlers run for each
    recorded signal. Outside the main thread (where Python runs no signal
    handlers) the block runs as it is.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    wanted = (signal.SIGINT, signal.SIGTERM)
    previous = {sig: signal.signal(sig, lambda signum, frame: caught.append(signum)) for sig in wanted}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for sig in dict.fromkeys(caught):
            signal.raise_signal(sig)


@contextlib.contextmanager
def output_folder(target: str | os.PathLike, names: Iterable[str] = (), *, overwrite: bool = False,
                  needed_bytes: int = 0, last: str | None = None):
    """A transactional output folder: write into a temporary folder, move into place when done.

    Checks, before the block runs (so before any long work): that ``target``
    is a folder or does not exist yet, that none of ``names`` is there
    (unless ``overwrite``; a link counts), that its location is writable
    (the temporary folder is created there) and has ``needed_bytes`` free.
    The block writes into the yielded temporary folder, a hidden
    ``.NAME.partial-XXXX`` beside ``target`` on the same file system. When
    the block completes, its files move into place with SIGINT/SIGTERM held:
    a new ``target`` is one atomic rename; into an existing folder, the
    files move one by one, ``last`` (the run's summary) last. When the block
    raises (an error, Ctrl-C, SIGTERM turned into ``SystemExit``), the
    temporary folder is removed: an interrupted or failed run leaves the
    previous state, never a folder that looks finished. (A run killed with
    SIGKILL leaves only the hidden ``.partial`` folder.)

    Yields
    ------
    pathlib.Path
        The temporary folder to write into.
    """
    target = Path(target)
    if target.is_symlink() and not target.exists():
        raise FileExistsError(f"{target} is a link to a missing folder; give a real folder")
    if target.exists() and not target.is_dir():
        raise FileExistsError(f"{target} exists and is not a folder")
    real = target.resolve() if target.exists() else target.absolute()
    check_free(target, names, overwrite)
    parent = real.parent
    created = []  # parent folders this run makes, removed again if it fails
    missing = parent
    while not missing.exists() and missing != missing.parent:
        created.append(missing)
        missing = missing.parent
    tmp = None
    try:
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OSError(exc.errno, f"cannot create the folder {parent}: {exc.strerror}") from None
        if target.exists() and not os.access(real, os.W_OK | os.X_OK):
            raise PermissionError(errno.EACCES, f"cannot write into {target}: permission denied")
        check_space(parent, needed_bytes, f"writing {target}")
        tmp = _temporary_folder_beside(real, target)
        yield tmp
        with signals_held():
            _commit(tmp, real, overwrite, last)
        created = []
    finally:
        if tmp is not None and tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        for folder in created:  # innermost first; only if still empty
            with contextlib.suppress(OSError):
                folder.rmdir()


def _temporary_folder_beside(real: Path, target: Path) -> Path:
    """Create an empty, unique hidden folder ``.NAME.partial-XXXX`` beside ``real``.

    Made with mode 0777 filtered by the process umask, as :func:`_temporary_beside`
    makes its files, so the finished folder has the permissions the user expects.
    """
    for _ in range(100):
        tmp = real.with_name(f".{real.name}.partial-{secrets.token_hex(4)}")
        try:
            os.mkdir(tmp, 0o777)
        except FileExistsError:
            continue
        except OSError as exc:
            raise OSError(exc.errno, f"cannot write beside {target}: {exc.strerror}") from None
        return tmp
    raise FileExistsError(f"no free temporary folder name beside {target}")  # pragma: no cover


def _commit(tmp: Path, target: Path, overwrite: bool, last: str | None) -> None:
    """Move a finished temporary folder's content to ``target`` (see :func:`output_folder`)."""
    if not os.path.lexists(target):
        os.rename(tmp, target)
        return
    entries = sorted(p.name for p in tmp.iterdir())
    if last in entries:
        entries.remove(last)
        entries.append(last)
    for name in entries:
        src, dst = tmp / name, target / name
        if os.path.lexists(dst):
            if not overwrite:
                raise FileExistsError(_exists_message(dst))
            if dst.is_dir() and not dst.is_symlink():
                old = tmp / f".old-{name}"
                os.rename(dst, old)
            else:
                os.unlink(dst)
        os.rename(src, dst)


# -- values ---------------------------------------------------------------------------


def check_choice(name: str, value: Any, choices: Sequence) -> Any:
    """Return ``value`` if it is one of ``choices``, else raise :class:`~shinysim.errors.OptionError`.

    The message names the parameter and lists the valid choices, e.g.
    ``centroid must be one of 'weighted', 'plain'; got 'median'``.
    """
    try:
        ok = not isinstance(value, (np.ndarray, list, dict, set)) and value in choices
    except TypeError:  # unhashable or incomparable
        ok = False
    if not ok:
        raise OptionError(f"{name} must be one of {', '.join(map(repr, choices))}; got {value!r}")
    return value


def _bound(value):
    """A range bound as a user reads it: integers in full (4294967295), others with %g."""
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


def check_number(name: str, value: Any, *, lo: float | None = None, hi: float | None = None,
                 lo_open: bool = False, hi_open: bool = False, integer: bool = False) -> Any:
    """Return ``value`` if it is a finite number in range, else raise :class:`~shinysim.errors.OptionError`.

    Parameters
    ----------
    name : str
        The option, as the user knows it (``"resolution"``, ``"--alpha"``).
    value : any
        Booleans, strings, None, NaN and infinities are refused.
    lo, hi : float, optional
        Bounds, closed unless ``lo_open`` / ``hi_open``.
    integer : bool
        Require an integer (an ``int`` or an integral numpy integer).

    Returns
    -------
    int or float
        ``value`` as a Python ``int`` (``integer=True``) or ``float``.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        kind = "an integer" if integer else "a number"
        raise OptionError(f"{name} must be {kind}, got {value!r}")
    if integer and not isinstance(value, (int, np.integer)):
        if not (math.isfinite(value) and float(value).is_integer()):
            raise OptionError(f"{name} must be an integer, got {value!r}")
    if not math.isfinite(value):
        raise OptionError(f"{name} must be finite, got {value!r}")
    value = int(value) if integer else float(value)
    below = lo is not None and (value <= lo if lo_open else value < lo)
    above = hi is not None and (value >= hi if hi_open else value > hi)
    if below or above:
        if lo is not None and hi is not None:
            where = f"in {'(' if lo_open else '['}{_bound(lo)}, {_bound(hi)}{')' if hi_open else ']'}"
        elif lo is not None:
            where = f"{'>' if lo_open else '>='} {_bound(lo)}"
        else:
            where = f"{'<' if hi_open else '<='} {_bound(hi)}"
        raise OptionError(f"{name} must be {where}, got {value!r}")
    return value


def check_attributes(obj: Any, rules: dict, *, named: bool = False) -> None:
    """Check attributes of ``obj`` (a dataclass, frozen or not) with :func:`check_number`, each by its
    ``rules[name]`` (:func:`check_number`'s keywords, plus ``optional=True``: None stays None), and store the
    checked values. ``named``: an error also carries ``field=name`` (as :func:`named_check`'s)."""
    for name, rule in rules.items():
        rule = dict(rule)
        value = getattr(obj, name)
        if value is None and rule.pop("optional", False):
            continue
        rule.pop("optional", None)
        object.__setattr__(obj, name, named_check(name, check_number, value, **rule) if named
                           else check_number(name, value, **rule))


def check_matrix(field: str, value: Any, rule: str, *, nonnegative: bool = False) -> np.ndarray:
    """``value`` as a finite 3 x 3 float64 matrix (all ``>= 0`` if ``nonnegative``), else an
    :class:`~shinysim.errors.OptionError` with ``field``, saying it ``must be {rule}``."""
    try:
        m = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise OptionError("must be a 3 x 3 array of numbers", field=field) from None
    if m.shape != (3, 3) or not np.all(np.isfinite(m)) or (nonnegative and np.any(m < 0)):
        raise OptionError(f"must be {rule}, got shape {m.shape}", field=field)
    return m


def named_check(name: str, check: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """Run ``check(name, *args, **kwargs)`` (e.g. :func:`check_number`); its OptionError also carries ``field=name``."""
    try:
        return check(name, *args, **kwargs)
    except OptionError as exc:
        exc.field = name
        raise


def with_overrides(cls: type, params: Any, overrides: dict) -> Any:
    """Settings object of type ``cls``: ``params`` (default ``cls()``) with
    single fields replaced by ``overrides``, validated again.

    The settings classes are frozen dataclasses that check themselves in
    ``__post_init__``; public functions take ``params=None, **overrides``.
    """
    if params is None:
        return cls(**overrides)
    return replace(params, **overrides) if overrides else params


def json_safe(obj: Any) -> Any:
    """``obj`` with numpy scalars and arrays made plain JSON values.

    Dict keys become strings, tuples and arrays lists, non-finite floats
    ``None`` (JSON has no NaN).
    """
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return None if not math.isfinite(float(obj)) else float(obj)
    return obj


#: A driver's progress callback: ``progress(stage, done, total)`` after each
#: step, and ``progress("info", 0, 0, message)`` for one-line messages.
Progress = Callable[..., None]


def stage_reporter(progress: Progress | None, stages: Sequence[str] | None):
    """``done(stage)`` and ``say(message)`` that report to a :data:`Progress` callback (or do nothing).

    ``done(stage)`` calls ``progress(stage, k, len(stages))`` with ``k`` the
    stage's place in ``stages`` counted from 1 (a stage not listed is not
    reported); ``say(message)`` calls ``progress("info", 0, 0, message)``.
    """
    def done(stage):
        if progress and stages and stage in stages:
            progress(stage, stages.index(stage) + 1, len(stages))

    def say(message):
        if progress:
            progress("info", 0, 0, message)

    return done, say


def derive_seed(*parts: Any) -> int:
    """A 31-bit seed determined by ``parts`` (their ``repr``), the same on every machine.

    Used to give every frame, joint or item of a run its own random stream
    from the run's one seed, e.g. ``derive_seed(seed, "train", "good", 3)``.
    """
    h = hashlib.sha256(repr(parts).encode()).digest()
    return int.from_bytes(h[:4], "little") & 0x7FFFFFFF


def lazy_face(package: str, submodules: Iterable[str] = (), names: dict[str, Iterable[str]] | None = None) -> list:
    """Make ``package`` a face that imports its parts when first used; return its ``__all__``.

    As scikit-image's ``lazy_loader.attach``: ``submodules`` are the
    package's modules, ``names`` maps a module to the public names the face
    gives from it. The package gets a module ``__getattr__`` and ``__dir__``;
    nothing is imported until a name is looked up. In its ``__init__``::

        __all__ = lazy_face(__name__, ["render"], {"render": ["Simulator"]})
    """
    module = sys.modules[package]
    submodules = list(submodules)
    owner = {name: part for part, listed in (names or {}).items() for name in listed}
    public = list(dict.fromkeys([*submodules, *owner]))

    def __getattr__(name):
        if name in owner:
            value = getattr(importlib.import_module(f"{package}.{owner[name]}"), name)
            setattr(module, name, value)  # found directly from now on
            return value
        if name in submodules:
            return importlib.import_module(f"{package}.{name}")
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    module.__getattr__ = __getattr__
    module.__dir__ = lambda: sorted({*public, *vars(module)})
    module.__face__ = {part: tuple(listed) for part, listed in (names or {}).items()}
    return public


# -- tolerances ------------------------------------------------------------------------
#
# One home for the tolerances that several tests and studies share. Each says
# where it comes from; a check that needs a looser bound states its own reason.

#: Closed-form float64 geometry: unit vectors, angles in radians and positions
#: of order 1-100 mm computed along different routes (about 1e4 ulps of 1).
EXACT_TOL = 1e-12

#: Exact profiles and surfaces rebuilt numerically from exact normals (circular
#: arcs, sparse least-squares solves to round-off), mm.
EXACT_MM_TOL = 1e-9

#: Two independent exact solutions of the same angle (the iterative mirror-sphere
#: reflection point against closed-form Eqs 11-14), degrees.
EXACT_DEG_TOL = 1e-7

#: Highlight centroid against the exact mirror point on a near-mirror sphere,
#: pixels: the 1.016 mm fiber images to about 2.4 px at the scan's 3.9 um
#: pixels and its centroid sits up to about 0.1 px off the mirror point
#: (measured); 0.25 px leaves room for sampling noise at 16 spp.
ORACLE_CENTROID_PX = 0.25


# -- threads ------------------------------------------------------------------------------------

_POOLS: dict = {}
_POOLS_LOCK = threading.Lock()


def cores() -> int:
    """The cores this process may run on (its CPU affinity where the platform tells it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on every platform
        return max(1, os.cpu_count() or 1)


def thread_map(fn: Callable, items: Sequence, workers: int) -> list:
    """``[fn(item) for item in items]`` on up to ``workers`` threads of a shared pool.

    numpy and scipy let go of the interpreter lock in their loops, so array
    work on separate items runs side by side. The results come in the
    items' order; ``workers <= 1`` or a single item runs in the caller's
    thread.
    """
    if workers <= 1 or len(items) <= 1:
        return [fn(item) for item in items]
    with _POOLS_LOCK:
        pool = _POOLS.get(workers)
        if pool is None:
            pool = _POOLS[workers] = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="shinysim")
    return list(pool.map(fn, items))
