"""Interrupted scans leave no folder or a complete one (scripts/interrupt_scan.py).

The default run sends Ctrl-C at two random moments to a small scan; the
slow run is the full check at twenty moments during the default scan.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
from conftest import requires_render

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "interrupt_scan.py"


def _script():
    spec = importlib.util.spec_from_file_location("interrupt_scan", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@requires_render
def test_interrupted_small_scans_leave_nothing_or_a_whole_folder(capsys):
    status = _script().main(["--trials", "2", "--seed", "1", "--resolution", "48", "--spp", "2"])
    out = capsys.readouterr().out
    assert status == 0, out
    assert "2 trials:" in out and "0 failed" in out


@pytest.mark.slow
@requires_render
def test_twenty_interrupts_of_the_default_scan(capsys):
    status = _script().main(["--trials", "20", "--seed", "0"])
    out = capsys.readouterr().out
    assert status == 0, out
    assert "20 trials:" in out and "0 failed" in out


def test_an_interruption_a_library_turns_into_another_error_is_still_one(monkeypatch, capsys):
    """trimesh catches a Ctrl-C that arrives during its import and fails later with a TypeError of its own:
    the command still reports the interruption (one line, status 130), not that error's traceback."""
    import signal

    from shinysim import cli

    def swallowing_import():
        caught = None
        try:
            signal.raise_signal(signal.SIGINT)  # through the handler the command has set
        except BaseException as exc:  # noqa: BLE001 -- what the library does
            caught = exc
        assert isinstance(caught, KeyboardInterrupt)
        raise TypeError("unsupported operand type(s) for |: 'ExceptionWrapper' and 'NoneType'")

    monkeypatch.setattr(cli, "build_parser", swallowing_import)
    assert cli.main(["scan", "--out", "x"]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "shinysim scan: interrupted; no partial output was left"
    # and with no signal the same TypeError is a bug, shown as one
    monkeypatch.setattr(cli, "build_parser", lambda: (_ for _ in ()).throw(TypeError("a bug")))
    with pytest.raises(TypeError, match="a bug"):
        cli.main(["scan", "--out", "x"])
