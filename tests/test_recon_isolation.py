"""The reconstruction half never imports a renderer, checked at run time.

``tests/test_layering.py`` reads every import statement; this imports every
module outside ``shinysim.sim`` in a fresh interpreter and looks at what was
loaded.
"""

import pkgutil
import subprocess
import sys

import pytest

import shinysim


def test_nothing_outside_sim_imports_a_renderer_or_matplotlib():
    mods = sorted(m.name for m in pkgutil.walk_packages(shinysim.__path__, "shinysim.")
                  if not m.name.startswith("shinysim.sim"))
    assert {"shinysim.recon.pipeline", "shinysim.studies.scan", "shinysim.cli", "shinysim.plot.scan"} <= set(mods)
    code = (
        "import importlib, sys\n"
        f"for m in {mods!r}:\n"
        "    importlib.import_module(m)\n"
        "from shinysim.recon import reconstruct\n"
        "print(','.join(sorted(m for m in sys.modules\n"
        "                      if m.split('.')[0] in ('mitsuba', 'drjit', 'trimesh', 'matplotlib'))))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"imported without being used: {out.stdout.strip()}"


def test_check_would_catch_an_import():
    """The probe above can fail: importing the simulator does pull mitsuba in."""
    pytest.importorskip("mitsuba")
    code = "import sys, shinysim.sim.variants as v; v.choose_variant(); print('mitsuba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "True"
