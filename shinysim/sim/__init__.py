"""The simulator: Mitsuba 3 scenes of rigs and objects, rendered into stacks.

The only part of shinysim that imports mitsuba, drjit or trimesh (the
``render`` extra); they are loaded when first used, not when this package
is imported: this face imports each part when a name of it is first used.

* :mod:`shinysim.sim.scene`: scene dicts and XML from a rig and objects;
* :mod:`shinysim.sim.objects`: the Mitsuba shapes of a registered object (:mod:`shinysim.objects.registry`);
* :mod:`shinysim.sim.render`: :class:`~shinysim.sim.render.Simulator`, the
  one-pass and per-source stack renderers and the pixel-centre truth;
* :mod:`shinysim.sim.variants`: which Mitsuba variant to use;
* :mod:`shinysim.sim.coded`: coded frames from one render of every source;
* :mod:`shinysim.sim.display`: the display-deflectometry twin (a dot screen seen in a
  mirror facet, with exact truth);
* :mod:`shinysim.sim.sensor`: the camera sensor (noise, bits, colour crosstalk);
* :mod:`shinysim.sim.meshes`: random shapes and users' meshes in scenes;
* :mod:`shinysim.sim.materials`: the paper's Eq 5 as a Mitsuba material;
* :mod:`shinysim.sim.solder`, :mod:`shinysim.sim.solder_scene`: solder-joint
  meshes and their scans (``solder`` needs trimesh; its names are reached
  through the module).
"""

from .._shared import lazy_face

__all__ = lazy_face(__name__, (
    "coded", "display", "materials", "meshes", "objects", "render", "scene", "sensor", "solder", "solder_scene",
    "variants"), {
    "coded": ("CodedStack", "ColourStack", "coded_stack", "colour_mixing", "expected_frames"),
    "display": ("DisplayFrame", "FringeFrames", "MAX_SCREEN_HITS", "SOFAST_ALPHA", "ScreenHits", "mask_frames",
                "pattern_frames", "pattern_texture", "render_display_frame", "render_fringe_frames",
                "screen_fraction_truth", "sofast_facet", "sofast_like_setup", "trace_screen_hits"),
    "materials": ("blend_weight", "paper_material"),
    "meshes": ("MESH_FORMATS", "load_user_mesh", "mesh_object", "ply_bytes", "update_mesh"),
    "objects": ("scene_objects",),
    "render": ("RENDER_METHODS", "Simulator"),
    "scene": ("DISTRIBUTIONS", "rough_conductor", "sphere_object", "facet_object", "plate_objects",
              "camera_sensor", "source_shapes", "scene_dict", "scene_xml", "load_scene"),
    "sensor": ("CAMERA_CROSSTALK", "POISSON_LIMIT", "SENSOR_BITS", "SENSOR_PRESETS", "Sensor", "sensor_preset",
               "check_colour_matrix"),
    "solder_scene": ("SOLDER_MATERIALS", "solder_rig", "joint_objects", "JointScan", "joint_simulator",
                     "scan_joint"),
    "variants": ("VARIANT_PREFERENCE", "COLOUR_VARIANT_PREFERENCE", "choose_variant", "is_vectorized",
                 "is_colour_variant", "active_variant"),
})
