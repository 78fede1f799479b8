"""The reconstruction half never imports a renderer."""

import subprocess
import sys


def test_recon_does_not_import_mitsuba_or_drjit():
    code = (
        "import sys\n"
        "import shinysim, shinysim.recon, shinysim.io, shinysim.rig, shinysim.evaluate, shinysim.scan\n"
        "import shinysim.recon.frames, shinysim.recon.sphere, shinysim.theory.mirror, shinysim.cli\n"
        "import shinysim.recon.highlights, shinysim.recon.profile, shinysim.recon.joint, shinysim.recon.classify\n"
        "import shinysim.solder_profiles, shinysim.solder_study\n"
        "from shinysim.recon import reconstruct\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('mitsuba', 'drjit', 'trimesh'))\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"renderer modules imported: {out.stdout.strip()}"


def test_check_would_catch_an_import():
    """The probe above can fail: importing the simulator does pull mitsuba in."""
    import importlib.util

    if importlib.util.find_spec("mitsuba") is None:
        return
    code = "import sys, shinysim.sim.variants as v; v.choose_variant(); print('mitsuba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "True"
