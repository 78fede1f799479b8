"""The simulator: Mitsuba 3 scenes of rigs and objects, rendered into stacks.

The only part of shinysim that imports mitsuba, drjit or trimesh (the
``render`` extra); they are loaded when first used, not when this package
is imported.

* :mod:`shinysim.sim.scene`: scene dicts and XML from a rig and objects;
* :mod:`shinysim.sim.render`: :class:`~shinysim.sim.render.Simulator`, the
  one-pass and per-source stack renderers and the pixel-centre truth;
* :mod:`shinysim.sim.variants`: which Mitsuba variant to use;
* :mod:`shinysim.sim.materials`: the paper's Eq 5 as a Mitsuba material;
* :mod:`shinysim.sim.solder`, :mod:`shinysim.sim.solder_scene`: solder-joint
  meshes and their scans (``solder`` imports trimesh, so it is not imported
  here).
"""

from .render import RENDER_METHODS, Simulator
from .scene import facet_object, scene_dict, sphere_object
from .variants import choose_variant

__all__ = [
    "RENDER_METHODS",
    "Simulator",
    "facet_object",
    "scene_dict",
    "sphere_object",
    "choose_variant",
    "scene",
    "render",
    "variants",
    "materials",
    "solder",
    "solder_scene",
]
