"""Bad input on the command line: one named error line, never a traceback, never partial output.

Every case calls ``shinysim.cli.main`` in-process and checks the exit status
(1 for bad input, 2 for argparse usage errors), that stderr holds exactly one
``shinysim CMD: error:`` line naming the option, file or field at fault, and,
for commands that write, that nothing was written: the folder the test works
in is listed (names, link targets, sizes, contents and modification times)
before and after, so a created folder, a replaced file or a hidden
``.NAME.partial-*`` folder left behind all fail the test.

Option errors must be refused before any rendering: those tests block the
renderer (``mitsuba`` and ``drjit`` cannot be imported) and make any attempt
to render fail the test. Only the module's one real scan renders.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import stat
import sys

import numpy as np
import pytest
from conftest import HAS_RENDER, requires_render, skip_without_render

from shinysim.cli import main
from shinysim.io import Stack, Truth, save_stack, save_truth
from shinysim.rig import Camera, Rig

# -- helpers ---------------------------------------------------------------------------


def run_cli(capsys, *argv):
    """``main(argv)`` as the interpreter would run it: (exit status, stdout, stderr)."""
    try:
        status = main([os.fspath(a) for a in argv])
    except SystemExit as exc:
        status = exc.code
        if isinstance(status, str):  # the interpreter prints the message and exits with 1
            print(status, file=sys.stderr)
            status = 1
    out, err = capsys.readouterr()
    return status, out, err


def assert_refused(result, command, *names, status=1):
    """One error line for ``command`` that matches every regex in ``names``; no traceback."""
    code, _, err = result
    assert "Traceback" not in err, err
    assert code == status, f"exit status {code!r}, expected {status}; stderr:\n{err}"
    lines = [line for line in err.splitlines() if line.strip()]
    if status == 1:
        assert len(lines) == 1, f"expected one line on stderr, got:\n{err}"
    else:  # argparse: usage lines, then the one error line
        assert [line for line in lines if "error:" in line] == lines[-1:], err
    line = lines[-1]
    assert line.startswith(f"shinysim {command}: error: "), line
    for name in names:
        assert re.search(name, line), f"{name!r} not named in: {line}"
    return line


def snapshot(root):
    """Every path under ``root``: type, link target, or size, mtime and content hash."""
    entries = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            path = os.path.join(folder, name)
            st = os.lstat(path)
            rel = os.path.relpath(path, root)
            if stat.S_ISLNK(st.st_mode):
                entries[rel] = ("link", os.readlink(path))
            elif stat.S_ISDIR(st.st_mode):
                entries[rel] = ("dir",)
            else:
                with open(path, "rb") as fh:
                    digest = hashlib.sha256(fh.read()).hexdigest()
                entries[rel] = ("file", st.st_size, st.st_mtime_ns, digest)
    return entries


def assert_unchanged(root, before):
    after = snapshot(root)
    partial = [p for p in after if ".partial-" in p]
    assert not partial, f"partial output left behind: {partial}"
    assert after == before, {"added": sorted(set(after) - set(before)), "removed": sorted(set(before) - set(after)),
                             "changed": sorted(p for p in set(after) & set(before) if after[p] != before[p])}


@pytest.fixture
def no_render(monkeypatch):
    """Any attempt to render (a scan's Simulator, a solder run's work) fails the test."""
    import shinysim.sim.render
    import shinysim.studies.inspection
    import shinysim.studies.solder

    class Forbidden:
        def __init__(self, *args, **kwargs):
            raise AssertionError("rendering started: the bad input should have been refused before any work")

    def forbidden(*args, **kwargs):
        raise AssertionError("solder work started: the bad input should have been refused before any work")

    monkeypatch.setattr(shinysim.sim.render, "Simulator", Forbidden)
    monkeypatch.setattr(shinysim.studies.solder, "_run_solder_into", forbidden)
    monkeypatch.setattr(shinysim.studies.inspection, "_run_into", forbidden)


@pytest.fixture
def without_renderer(monkeypatch, no_render):
    """As on a machine without the render extra: ``import mitsuba`` and ``import drjit`` fail."""
    monkeypatch.setitem(sys.modules, "mitsuba", None)
    monkeypatch.setitem(sys.modules, "drjit", None)


# -- a small scan folder, without a renderer ------------------------------------------------

H, W = 24, 32
SPOTS = [(8, 6), (12, 16), (16, 26)]


def small_rig(width=W, height=H):
    cam = Camera("orthographic", width, height, [0, 0, 10], [0, 0, 0], [0, 1, 0], 2.0)
    pos = np.stack([np.linspace(-10, 10, 3), np.zeros(3), np.full(3, 40.0)], axis=1)
    return Rig(pos, np.full(3, 0.5), (cam,))


def spot_frames(height=H, width=W):
    rows, cols = np.indices((height, width))
    return np.stack([np.exp(-((rows - r) ** 2 + (cols - c) ** 2) / 2.0) for r, c in SPOTS]).astype(np.float32)


@pytest.fixture(scope="module")
def folder_template(tmp_path_factory):
    """stack.exr, rig.json, truth.exr and highlights.csv of a 3-source flat scan (no score.json)."""
    from shinysim.studies.scan import reconstruct_folder

    folder = tmp_path_factory.mktemp("template") / "scan"
    folder.mkdir()
    save_stack(Stack(spot_frames(), small_rig()), folder / "stack.exr")
    rows, cols = np.indices((H, W))
    normals = np.zeros((H, W, 3), np.float32)
    normals[..., 2] = 1
    positions = np.stack([cols, rows, np.zeros((H, W))], axis=-1).astype(np.float32)
    save_truth(Truth(normals, positions, np.ones((H, W), bool)), folder / "truth.exr")
    assert len(reconstruct_folder(folder)) == 3
    return folder


@pytest.fixture
def scan_dir(folder_template, tmp_path):
    """A fresh copy of the template in ``tmp_path / "scan"``."""
    return shutil.copytree(folder_template, tmp_path / "scan")


@pytest.fixture(scope="module")
def rendered_scan(tmp_path_factory):
    """One real tiny scan for the module (needs the renderer)."""
    if not HAS_RENDER:
        pytest.skip("needs the render extra")
    from shinysim.studies.scan import run_scan

    folder = tmp_path_factory.mktemp("rendered") / "scan"
    run_scan(folder, resolution=32, spp=2, plot=False)
    return folder


# -- scan: options, refused before any rendering ----------------------------------------------

SCAN_BAD_OPTIONS = {
    "resolution-1": (["--resolution", "1"], r"resolution"),
    "resolution-0": (["--resolution", "0"], r"resolution"),
    "resolution-negative": (["--resolution", "-5"], r"resolution"),
    "resolution-100000": (["--resolution", "100000"], r"resolution"),
    "spp-0": (["--spp", "0"], r"spp"),
    "spp-100000": (["--spp", "100000"], r"spp"),
    "alpha-0": (["--alpha", "0"], r"alpha"),
    "alpha-negative": (["--alpha", "-0.1"], r"alpha"),
    "alpha-nan": (["--alpha", "nan"], r"alpha"),
    "alpha-inf": (["--alpha", "inf"], r"alpha"),
    "alpha-2": (["--alpha", "2"], r"alpha"),
    "seed-negative": (["--seed", "-1"], r"seed"),
    "seed-beyond-32-bits": (["--seed", str(2**32)], r"seed"),
    "threshold-0": (["--threshold", "0"], r"threshold"),
    "threshold-1.5": (["--threshold", "1.5"], r"threshold"),
    "threshold-nan": (["--threshold", "nan"], r"threshold"),
    "threshold-absolute-negative": (["--threshold-mode", "absolute", "--threshold", "-1"], r"threshold"),
    "min-area-0": (["--min-area", "0"], r"min[_-]area"),
    "max-area-below-min-area": (["--min-area", "10", "--max-area", "5"], r"max[_-]area"),
    "saturation-0": (["--saturation", "0"], r"saturation"),
    "saturation-nan": (["--saturation", "nan"], r"saturation"),
    "false-alarm-negative": (["--false-alarm", "-1"], r"false[_-]alarm"),
}


@pytest.mark.parametrize("bad", SCAN_BAD_OPTIONS.values(), ids=SCAN_BAD_OPTIONS.keys())
def test_scan_bad_option(bad, tmp_path, capsys, without_renderer):
    args, name = bad
    before = snapshot(tmp_path)
    result = run_cli(capsys, "scan", "--out", tmp_path / "out", "--resolution", "32", "--spp", "2", "--quiet",
                     "--no-plot", *args)
    assert_refused(result, "scan", name)
    assert not (tmp_path / "out").exists()
    assert_unchanged(tmp_path, before)


SCAN_USAGE_ERRORS = {
    "resolution-not-integer": (["--resolution", "32.5"], r"--resolution"),
    "resolution-word": (["--resolution", "big"], r"--resolution"),
    "spp-word": (["--spp", "many"], r"--spp"),
    "alpha-word": (["--alpha", "rough"], r"--alpha"),
    "camera-unknown": (["--camera", "fisheye"], r"--camera"),
    "object-unknown": (["--object", "cube"], r"--object"),
    "method-unknown": (["--method", "fast"], r"--method"),
    "threshold-mode-unknown": (["--threshold-mode", "median"], r"--threshold-mode"),
}


@pytest.mark.parametrize("bad", SCAN_USAGE_ERRORS.values(), ids=SCAN_USAGE_ERRORS.keys())
def test_scan_usage_error(bad, tmp_path, capsys, without_renderer):
    args, name = bad
    before = snapshot(tmp_path)
    result = run_cli(capsys, "scan", "--out", tmp_path / "out", "--quiet", *args)
    assert_refused(result, "scan", name, status=2)
    assert_unchanged(tmp_path, before)


def test_scan_without_out(tmp_path, capsys, without_renderer):
    assert_refused(run_cli(capsys, "scan", "--quiet"), "scan", r"--out", status=2)


@skip_without_render
def test_scan_unknown_variant(tmp_path, capsys, no_render):
    before = snapshot(tmp_path)
    result = run_cli(capsys, "scan", "--out", tmp_path / "out", "--resolution", "32", "--spp", "2", "--quiet",
                     "--variant", "nonsense")
    assert_refused(result, "scan", r"variant", r"nonsense")
    assert_unchanged(tmp_path, before)


def test_scan_without_renderer(tmp_path, capsys, without_renderer):
    """A machine without the render extra: a named error, not an ImportError traceback."""
    before = snapshot(tmp_path)
    result = run_cli(capsys, "scan", "--out", tmp_path / "out", "--resolution", "32", "--spp", "2", "--quiet")
    assert_refused(result, "scan", r"(?i)mitsuba|render")
    assert_unchanged(tmp_path, before)


# -- scan: the output location, checked before rendering --------------------------------------


def scan_into(capsys, out, *more):
    return run_cli(capsys, "scan", "--out", out, "--resolution", "32", "--spp", "2", "--quiet", *more)


def test_scan_out_is_a_file(tmp_path, capsys, no_render):
    (tmp_path / "out").write_text("not a folder\n")
    before = snapshot(tmp_path)
    assert_refused(scan_into(capsys, tmp_path / "out"), "scan", r"out", r"not a folder")
    assert_unchanged(tmp_path, before)


def test_scan_out_is_a_dangling_link(tmp_path, capsys, no_render):
    (tmp_path / "out").symlink_to(tmp_path / "elsewhere")
    before = snapshot(tmp_path)
    assert_refused(scan_into(capsys, tmp_path / "out"), "scan", r"out", r"link")
    assert not (tmp_path / "elsewhere").exists()
    assert_unchanged(tmp_path, before)


@requires_render
def test_scan_out_already_holds_a_scan(rendered_scan, tmp_path, capsys, no_render):
    out = shutil.copytree(rendered_scan, tmp_path / "out")
    truth_mtime = (out / "truth.exr").stat().st_mtime_ns
    before = snapshot(tmp_path)
    line = assert_refused(scan_into(capsys, out), "scan", r"out", r"already holds", r"--overwrite")
    assert "truth.exr" in line and "stack.exr" in line
    assert (out / "truth.exr").stat().st_mtime_ns == truth_mtime
    assert_unchanged(tmp_path, before)


@pytest.mark.parametrize("name", ["scan.png", "score.json"])
def test_scan_out_holds_a_dangling_link(name, tmp_path, capsys, no_render):
    """A link planted in the output folder is never written through, even where it points nowhere yet."""
    out = tmp_path / "out"
    out.mkdir()
    outside = tmp_path / "outside"
    outside.mkdir()
    (out / name).symlink_to(outside / name)
    before = snapshot(tmp_path)
    assert_refused(scan_into(capsys, out), "scan", re.escape(name), r"already holds")
    assert not (outside / name).exists()
    assert_unchanged(tmp_path, before)


def test_scan_out_holds_a_link_to_a_file_outside(tmp_path, capsys, no_render):
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "precious.csv"
    victim.write_text("keep me\n")
    (out / "highlights.csv").symlink_to(victim)
    before = snapshot(tmp_path)
    assert_refused(scan_into(capsys, out), "scan", r"highlights\.csv", r"already holds")
    assert victim.read_text() == "keep me\n"
    assert_unchanged(tmp_path, before)


def test_scan_out_cannot_be_created(tmp_path, capsys, no_render):
    """A parent folder that cannot be written (read-only; as root, which ignores permissions, a file)."""
    if os.geteuid() == 0:
        (tmp_path / "parent").write_text("a file, not a folder\n")
    else:
        (tmp_path / "parent").mkdir()
        os.chmod(tmp_path / "parent", 0o555)
    before = snapshot(tmp_path)
    try:
        assert_refused(scan_into(capsys, tmp_path / "parent" / "out"), "scan", r"parent")
    finally:
        if (tmp_path / "parent").is_dir():
            os.chmod(tmp_path / "parent", 0o755)
    assert_unchanged(tmp_path, before)


def test_scan_out_parent_is_a_file(tmp_path, capsys, no_render):
    (tmp_path / "notes.txt").write_text("a file\n")
    before = snapshot(tmp_path)
    assert_refused(scan_into(capsys, tmp_path / "notes.txt" / "deeper" / "out"), "scan", r"notes\.txt")
    assert_unchanged(tmp_path, before)


# -- reconstruct: a scan folder ----------------------------------------------------------------


def test_reconstruct_missing_folder(tmp_path, capsys):
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "reconstruct", tmp_path / "nope"), "reconstruct", r"nope")
    assert_unchanged(tmp_path, before)


def test_reconstruct_missing_nested_folder(tmp_path, capsys):
    """No parent folders are created for a scan folder that is not there."""
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "reconstruct", tmp_path / "missing" / "scan"), "reconstruct", r"missing")
    assert_unchanged(tmp_path, before)


def test_reconstruct_folder_without_stack(scan_dir, tmp_path, capsys):
    (scan_dir / "stack.exr").unlink()
    (scan_dir / "highlights.csv").unlink()
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "reconstruct", scan_dir), "reconstruct", r"stack\.exr", r"no such file")
    assert_unchanged(tmp_path, before)


def test_reconstruct_stack_is_text(scan_dir, tmp_path, capsys):
    (scan_dir / "stack.exr").write_text("this is not an EXR file\n")
    (scan_dir / "highlights.csv").unlink()
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "reconstruct", scan_dir), "reconstruct", r"stack\.exr", r"OpenEXR")
    assert_unchanged(tmp_path, before)


def test_reconstruct_stack_truncated(scan_dir, tmp_path, capsys):
    data = (scan_dir / "stack.exr").read_bytes()
    (scan_dir / "stack.exr").write_bytes(data[: len(data) // 2])
    (scan_dir / "highlights.csv").unlink()
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "reconstruct", scan_dir), "reconstruct", r"stack\.exr", r"truncated")
    assert_unchanged(tmp_path, before)


def test_reconstruct_stack_disagrees_with_rig(scan_dir, tmp_path, capsys):
    small_rig(width=W + 1).save(tmp_path / "wide.json")
    before = snapshot(tmp_path)
    result = run_cli(capsys, "reconstruct", scan_dir, "--rig", tmp_path / "wide.json", "--out", tmp_path / "o")
    assert_refused(result, "reconstruct", r"stack\.exr", rf"{W + 1}")
    assert_unchanged(tmp_path, before)


def test_reconstruct_rig_missing(scan_dir, tmp_path, capsys):
    (scan_dir / "rig.json").unlink()
    (scan_dir / "highlights.csv").unlink()
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "reconstruct", scan_dir), "reconstruct", r"rig\.json", r"no such file")
    assert_unchanged(tmp_path, before)


def _rig_doc(scan_dir):
    return json.loads((scan_dir / "rig.json").read_text())


BAD_RIGS = {
    "invalid-json": (lambda doc: json.dumps(doc)[:-5].encode(), [r"not valid JSON"]),
    "unknown-key": (lambda doc: json.dumps({("reference_z" if k == "reference_z_mm" else k): v
                                            for k, v in doc.items()}).encode(),
                    [r"reference_z", r"did you mean 'reference_z_mm'"]),
    "not-utf8": (lambda doc: b"\xff\xfe" + json.dumps(doc).encode("utf-16-le"), [r"UTF-8"]),
    "null-width": (lambda doc: json.dumps({**doc, "cameras": [{**doc["cameras"][0], "width": None}]}).encode(),
                   [r"cameras\[0\]\.width"]),
    "string-number": (lambda doc: json.dumps({**doc, "cameras": [{**doc["cameras"][0], "field_width_mm": "2.0"}]})
                      .encode(), [r"cameras\[0\]\.field_width_mm"]),
    "negative-radius": (lambda doc: json.dumps({**doc, "sources": [{**doc["sources"][0], "radius_mm": -1}]
                                                + doc["sources"][1:]}).encode(), [r"sources\[0\]\.radius_mm"]),
}


@pytest.mark.parametrize("bad", BAD_RIGS.values(), ids=BAD_RIGS.keys())
def test_reconstruct_bad_rig(bad, scan_dir, tmp_path, capsys):
    make, names = bad
    (scan_dir / "rig.json").write_bytes(make(_rig_doc(scan_dir)))
    (scan_dir / "highlights.csv").unlink()
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "reconstruct", scan_dir), "reconstruct", r"rig\.json", *names)
    assert_unchanged(tmp_path, before)


def test_reconstruct_out_already_holds_highlights(scan_dir, tmp_path, capsys):
    before = snapshot(tmp_path)
    result = run_cli(capsys, "reconstruct", scan_dir)
    assert_refused(result, "reconstruct", r"highlights\.csv", r"already holds", r"--overwrite")
    assert_unchanged(tmp_path, before)


def test_reconstruct_out_holds_a_dangling_link(scan_dir, tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "highlights.csv").symlink_to(tmp_path / "outside.csv")
    before = snapshot(tmp_path)
    result = run_cli(capsys, "reconstruct", scan_dir, "--out", out)
    assert_refused(result, "reconstruct", r"highlights\.csv", r"already holds")
    assert not (tmp_path / "outside.csv").exists()
    assert_unchanged(tmp_path, before)


def test_reconstruct_out_is_a_file(scan_dir, tmp_path, capsys):
    (tmp_path / "o").write_text("a file\n")
    before = snapshot(tmp_path)
    result = run_cli(capsys, "reconstruct", scan_dir, "--out", tmp_path / "o")
    assert_refused(result, "reconstruct", r"o exists and is not a folder")
    assert_unchanged(tmp_path, before)


@pytest.mark.parametrize("bad", [(["--threshold", "0"], r"threshold"), (["--min-area", "-3"], r"min[_-]area")],
                         ids=["threshold-0", "min-area-negative"])
def test_reconstruct_bad_detection_option(bad, scan_dir, tmp_path, capsys):
    args, name = bad
    before = snapshot(tmp_path)
    result = run_cli(capsys, "reconstruct", scan_dir, "--out", tmp_path / "o", *args)
    assert_refused(result, "reconstruct", name)
    assert_unchanged(tmp_path, before)


def test_reconstruct_nothing_to_read(capsys):
    assert_refused(run_cli(capsys, "reconstruct"), "reconstruct", r"scan folder", r"--frames")


def test_reconstruct_unknown_channel(scan_dir, capsys):
    assert_refused(run_cli(capsys, "reconstruct", scan_dir, "--channel", "green"), "reconstruct", r"--channel",
                   status=2)


# -- reconstruct: image frames -----------------------------------------------------------------


def write_png(path, grey, alpha=None):
    from PIL import Image

    grey = np.asarray(grey, np.uint8)
    if alpha is None:
        Image.fromarray(grey, "L").save(path)
    else:
        Image.fromarray(np.stack([grey, np.asarray(alpha, np.uint8)], axis=-1), "LA").save(path)


@pytest.fixture
def frames_dir(tmp_path):
    """rig.json and three 8-bit grey PNG frames f0..f2, one spot each."""
    folder = tmp_path / "frames"
    folder.mkdir()
    small_rig().save(folder / "rig.json")
    for k, frame in enumerate(spot_frames()):
        write_png(folder / f"f{k}.png", np.round(255 * frame))
    return folder


def frames_args(folder, *names, out):
    names = names or ("f0.png", "f1.png", "f2.png")
    return ["reconstruct", "--rig", folder / "rig.json", "--frames", *[folder / n for n in names], "--out", out]


def test_frames_without_rig(frames_dir, tmp_path, capsys):
    before = snapshot(tmp_path)
    args = frames_args(frames_dir, out=tmp_path / "o")
    del args[1:3]
    assert_refused(run_cli(capsys, *args), "reconstruct", r"--rig")
    assert_unchanged(tmp_path, before)


def test_frames_without_out(frames_dir, tmp_path, capsys):
    before = snapshot(tmp_path)
    args = frames_args(frames_dir, out=tmp_path / "o")[:-2]
    assert_refused(run_cli(capsys, *args), "reconstruct", r"--out")
    assert_unchanged(tmp_path, before)


def test_frames_and_folder(frames_dir, scan_dir, tmp_path, capsys):
    before = snapshot(tmp_path)
    args = frames_args(frames_dir, out=tmp_path / "o")
    assert_refused(run_cli(capsys, *args[:1], scan_dir, *args[1:]), "reconstruct", r"--frames")
    assert_unchanged(tmp_path, before)


def test_frames_rig_missing(frames_dir, tmp_path, capsys):
    (frames_dir / "rig.json").unlink()
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, *frames_args(frames_dir, out=tmp_path / "o")), "reconstruct", r"rig\.json",
                   r"no such file")
    assert_unchanged(tmp_path, before)


def test_frames_wrong_count(frames_dir, tmp_path, capsys):
    before = snapshot(tmp_path)
    result = run_cli(capsys, *frames_args(frames_dir, "f0.png", "f1.png", out=tmp_path / "o"))
    assert_refused(result, "reconstruct", r"frames", r"2 frame files", r"3 sources")
    assert_unchanged(tmp_path, before)


def test_frames_missing_file(frames_dir, tmp_path, capsys):
    before = snapshot(tmp_path)
    result = run_cli(capsys, *frames_args(frames_dir, "f0.png", "f1.png", "f9.png", out=tmp_path / "o"))
    assert_refused(result, "reconstruct", r"f9\.png", r"no such file")
    assert_unchanged(tmp_path, before)


def test_frames_text_file(frames_dir, tmp_path, capsys):
    (frames_dir / "f1.png").write_text("not a picture\n")
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, *frames_args(frames_dir, out=tmp_path / "o")), "reconstruct", r"f1\.png")
    assert_unchanged(tmp_path, before)


def test_frames_wrong_size(frames_dir, tmp_path, capsys):
    for k, frame in enumerate(spot_frames(H + 2, W + 4)):
        (frames_dir / f"f{k}.png").unlink()
        write_png(frames_dir / f"f{k}.png", np.round(255 * frame))
    before = snapshot(tmp_path)
    result = run_cli(capsys, *frames_args(frames_dir, out=tmp_path / "o"))
    assert_refused(result, "reconstruct", r"f0\.png", r"size", rf"{H}x{W}")
    assert_unchanged(tmp_path, before)


def test_frames_of_mixed_sizes(frames_dir, tmp_path, capsys):
    (frames_dir / "f2.png").unlink()
    write_png(frames_dir / "f2.png", np.zeros((H, W + 1)))
    before = snapshot(tmp_path)
    result = run_cli(capsys, *frames_args(frames_dir, out=tmp_path / "o"))
    assert_refused(result, "reconstruct", r"f2\.png", r"size")
    assert_unchanged(tmp_path, before)


def test_frames_out_holds_highlights(frames_dir, tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "highlights.csv").write_text("mine\n")
    before = snapshot(tmp_path)
    result = run_cli(capsys, *frames_args(frames_dir, out=out))
    assert_refused(result, "reconstruct", r"highlights\.csv", r"already holds")
    assert_unchanged(tmp_path, before)


def test_frames_grey_alpha_png(tmp_path, capsys):
    """Grey+alpha PNGs: the alpha channel is not light; one highlight per frame, at its spot."""
    from shinysim.io.table import read_highlight_table

    folder = tmp_path / "frames"
    folder.mkdir()
    small_rig().save(folder / "rig.json")
    opaque = np.full((H, W), 255)
    for k, frame in enumerate(spot_frames()):
        write_png(folder / f"f{k}.png", np.round(255 * frame), alpha=opaque)
    code, out, err = run_cli(capsys, *frames_args(folder, out=tmp_path / "o"))
    assert "Traceback" not in err
    assert code == 0, err
    table, normals = read_highlight_table(tmp_path / "o" / "highlights.csv", n_sources=3, shape=(H, W))
    assert table["source"].tolist() == [0, 1, 2]
    np.testing.assert_allclose(np.c_[table["row"], table["col"]], SPOTS, atol=0.05)
    assert table["area"].max() < 20  # a spot, not the whole opaque image
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["highlights.csv"]


# -- score ------------------------------------------------------------------------------------------


def test_score_missing_truth(scan_dir, tmp_path, capsys):
    (scan_dir / "truth.exr").unlink()
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "score", scan_dir), "score", r"truth\.exr", r"no such file")
    assert_unchanged(tmp_path, before)


def test_score_truth_is_text(scan_dir, tmp_path, capsys):
    (scan_dir / "truth.exr").write_text("no truth here\n")
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "score", scan_dir), "score", r"truth\.exr", r"OpenEXR")
    assert_unchanged(tmp_path, before)


def test_score_truth_of_wrong_size(scan_dir, tmp_path, capsys):
    (scan_dir / "truth.exr").unlink()
    n = np.zeros((H, W + 2, 3), np.float32)
    n[..., 2] = 1
    save_truth(Truth(n, np.zeros_like(n), np.ones((H, W + 2), bool)), scan_dir / "truth.exr")
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "score", scan_dir), "score", r"truth\.exr", rf"{W + 2}")
    assert_unchanged(tmp_path, before)


def test_score_missing_folder(tmp_path, capsys):
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "score", tmp_path / "nope"), "score", r"nope")
    assert_unchanged(tmp_path, before)


@pytest.mark.parametrize("radius", ["0", "-1", "nan", "inf"])
def test_score_bad_sphere_radius(radius, scan_dir, tmp_path, capsys):
    before = snapshot(tmp_path)
    result = run_cli(capsys, "score", scan_dir, "--sphere-radius", radius)
    assert_refused(result, "score", r"sphere radius|sphere-radius")
    assert_unchanged(tmp_path, before)


def test_score_sphere_radius_not_a_number(scan_dir, capsys):
    assert_refused(run_cli(capsys, "score", scan_dir, "--sphere-radius", "big"), "score", r"--sphere-radius",
                   status=2)


def _edit_table(scan_dir, line, column, value):
    path = scan_dir / "highlights.csv"
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[line - 1].split(",")
    cells[header.index(column)] = value
    lines[line - 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def test_score_table_bad_cell(scan_dir, tmp_path, capsys):
    _edit_table(scan_dir, 3, "row", "abc")
    before = snapshot(tmp_path)
    line = assert_refused(run_cli(capsys, "score", scan_dir), "score", r"highlights\.csv", r"line 3", r"row")
    assert "abc" in line
    assert_unchanged(tmp_path, before)


def test_score_table_source_beyond_rig(scan_dir, tmp_path, capsys):
    _edit_table(scan_dir, 2, "source", "7")
    before = snapshot(tmp_path)
    line = assert_refused(run_cli(capsys, "score", scan_dir), "score", r"highlights\.csv", r"line 2", r"source")
    assert "7" in line
    assert_unchanged(tmp_path, before)


def test_score_table_pixel_outside_image(scan_dir, tmp_path, capsys):
    _edit_table(scan_dir, 2, "col", "500.0")
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "score", scan_dir), "score", r"highlights\.csv", r"line 2", r"col")
    assert_unchanged(tmp_path, before)


def test_score_already_written(scan_dir, tmp_path, capsys):
    (scan_dir / "score.json").write_text("{}\n")
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "score", scan_dir), "score", r"score\.json", r"already holds", r"--overwrite")
    assert_unchanged(tmp_path, before)


def test_score_bad_detection_option(scan_dir, tmp_path, capsys):
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "score", scan_dir, "--false-alarm", "-1"), "score", r"false[_-]alarm")
    assert_unchanged(tmp_path, before)


# -- figures and solder ---------------------------------------------------------------------------------


def test_figures_out_is_a_file(tmp_path, capsys):
    (tmp_path / "figs").write_text("a file\n")
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "figures", tmp_path / "figs", "--quick"), "figures", r"figs",
                   r"not a folder")
    assert_unchanged(tmp_path, before)


def test_figures_out_is_a_dangling_link(tmp_path, capsys):
    (tmp_path / "figs").symlink_to(tmp_path / "elsewhere")
    before = snapshot(tmp_path)
    assert_refused(run_cli(capsys, "figures", tmp_path / "figs", "--quick"), "figures", r"figs", r"link")
    assert_unchanged(tmp_path, before)


SOLDER_BAD_OPTIONS = {
    "n-train-0": (["--n-train", "0"], r"n[_-]train"),
    "n-test-negative": (["--n-test", "-2"], r"n[_-]test"),
    "resolution-1": (["--resolution", "1"], r"resolution"),
    "spp-0": (["--spp", "0"], r"spp"),
    "seed-negative": (["--seed", "-1"], r"seed"),
}


INSPECT_BAD_OPTIONS = {
    **SOLDER_BAD_OPTIONS,
    "heel-fraction-nan": (["--heel-fillet-fraction", "nan"], r"heel_fillet_fraction"),
    "wetting-angle-0": (["--max-wetting-angle", "0"], r"max_wetting_angle"),
}
STUDY_BAD_OPTIONS = {**{f"solder-{k}": ("solder", *v) for k, v in SOLDER_BAD_OPTIONS.items()},
                     **{f"inspect-{k}": ("inspect", *v) for k, v in INSPECT_BAD_OPTIONS.items()}}


@pytest.mark.parametrize("bad", STUDY_BAD_OPTIONS.values(), ids=STUDY_BAD_OPTIONS.keys())
def test_study_bad_option(bad, tmp_path, capsys, without_renderer):
    command, args, name = bad
    before = snapshot(tmp_path)
    result = run_cli(capsys, command, "--out", tmp_path / "out", "--n-train", "1", "--n-test", "1",
                     "--resolution", "32", "--spp", "2", "--quiet", *args)
    assert_refused(result, command, name)
    assert_unchanged(tmp_path, before)


@pytest.mark.parametrize("where", ["folder", "no-parent"])
def test_inspect_bad_cache(where, tmp_path, capsys, without_renderer):
    cache = tmp_path / "cache.jsonl"
    if where == "folder":
        cache.mkdir()
    else:
        cache = tmp_path / "missing" / "cache.jsonl"
    before = snapshot(tmp_path)
    result = run_cli(capsys, "inspect", "--out", tmp_path / "out", "--n-train", "1", "--n-test", "1", "--quiet",
                     "--cache", cache)
    assert_refused(result, "inspect", r"cache", r"not a regular file|folder does not exist")
    assert_unchanged(tmp_path, before)


def test_solder_unknown_kind(tmp_path, capsys, without_renderer):
    before = snapshot(tmp_path)
    result = run_cli(capsys, "solder", "--out", tmp_path / "out", "--kinds", "good", "cracked")
    assert_refused(result, "solder", r"--kinds", status=2)
    assert_unchanged(tmp_path, before)


def test_solder_out_is_a_file(tmp_path, capsys, no_render):
    (tmp_path / "out").write_text("a file\n")
    before = snapshot(tmp_path)
    result = run_cli(capsys, "solder", "--out", tmp_path / "out", "--n-train", "1", "--n-test", "1", "--quiet")
    assert_refused(result, "solder", r"out", r"not a folder")
    assert_unchanged(tmp_path, before)


@skip_without_render
def test_solder_unknown_variant(tmp_path, capsys, no_render):
    """An unknown Mitsuba variant is refused before any joint is made."""
    before = snapshot(tmp_path)
    result = run_cli(capsys, "solder", "--out", tmp_path / "out", "--n-train", "1", "--n-test", "1",
                     "--resolution", "32", "--spp", "2", "--quiet", "--variant", "nonsense")
    assert_refused(result, "solder", r"variant", r"nonsense")
    assert_unchanged(tmp_path, before)
