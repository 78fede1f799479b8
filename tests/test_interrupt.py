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
