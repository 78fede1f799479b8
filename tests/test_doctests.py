"""The examples in the package's docstrings run, and print what they say.

Every module under ``shinysim/`` whose source holds ``>>>`` is one case; a
module with ``>>>`` in which :mod:`doctest` finds no example (a typo in the
prompt, an example in a comment) fails. Modules of the simulator, and those
whose examples render, are skipped without the renderer.
"""

from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import pytest
from conftest import HAS_RENDER

import shinysim

PACKAGE = Path(shinysim.__file__).parent
#: Modules outside ``shinysim.sim`` whose examples render.
RENDERS = {"shinysim.datasets.engine"}


def _module(path):
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = sorted(_module(p) for p in PACKAGE.rglob("*.py") if ">>>" in p.read_text())


def _case(name):
    renders = name.startswith("shinysim.sim.") or name in RENDERS
    marks = [pytest.mark.render, pytest.mark.skipif(not HAS_RENDER, reason="needs the render extra (mitsuba, drjit)")]
    return pytest.param(name, marks=marks if renders else (), id=name)


def test_the_examples_are_found():
    assert {"shinysim.recon.pipeline", "shinysim.recon.coding", "shinysim.evaluate.normals",
            "shinysim.sim.render", "shinysim.datasets.engine"} <= set(MODULES)


@pytest.mark.parametrize("name", [_case(m) for m in MODULES])
def test_docstring_examples(name):
    module = importlib.import_module(name)
    tests = [t for t in doctest.DocTestFinder().find(module, name) if t.examples]
    assert tests, f"{name} holds '>>>' but doctest finds no example in it"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in tests:
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples of {name} failed (output above)"
