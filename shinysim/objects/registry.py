"""One registry of what is scanned: each object's parts and its exact truth.

:data:`OBJECTS` maps a name to a builder of a :class:`ScannedObject`: its
parts (:class:`Part`: a sphere, a square mirror facet, a mesh, a solder
joint), a known surface point with its normal (the datum), the exact height
``z(x, y)`` where one is known, and the size its errors are reported
against. :func:`scanned_object` builds one by name, with placement options
(``center_mm``, ``lift_mm``, ``part``). :func:`shinysim.sim.objects.scene_objects`
turns one into Mitsuba shapes; the studies, the data sets and the CLI take
their object names from here. numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from .._shared import check_choice
from .shapes import SHAPE_FAMILIES
from .solder import JointParams, JointProfile
from .sphere import SHINY_SPHERE_RADIUS_MM
from .step import STEP_PART, step_gradient, step_height, step_mesh

__all__ = ["PART_SHAPES", "Part", "ScannedObject", "OBJECTS", "OBJECT_NAMES", "STEREO_OBJECTS", "CODED_OBJECTS",
           "DATASET_OBJECT_KINDS",
           "scanned_object", "sphere_height"]

#: What a part can be.
PART_SHAPES = ("sphere", "facet", "mesh", "joint")


@dataclass(frozen=True)
class Part:
    """One shape of a scanned object.

    ``shape`` is one of :data:`PART_SHAPES`: a ``sphere`` (``center_mm``,
    ``radius_mm``), a square mirror ``facet`` (``center_mm``, unit
    ``normal``, side ``size_mm``), a ``mesh`` (``mesh()`` builds its
    :class:`~shinysim.objects.shapes.TriangleMesh`) or a solder ``joint``
    (:class:`~shinysim.objects.solder.JointParams` ``joint``, its own
    materials and part names), raised by ``lift_mm``.
    """

    shape: str
    center_mm: tuple = (0.0, 0.0, 0.0)
    radius_mm: float = SHINY_SPHERE_RADIUS_MM
    normal: tuple = (0.0, 0.0, 1.0)
    size_mm: float = 0.0
    mesh: Callable[[], Any] | None = None
    joint: JointParams | None = None
    lift_mm: float = 0.0


@dataclass(frozen=True)
class ScannedObject:
    """An object to scan and its exact truth.

    Attributes
    ----------
    name : str
        Its :data:`OBJECTS` name.
    parts : dict of str -> Part
        Named parts (a joint part stands for all the joint's meshes).
    datum, datum_normal : (3,) float or None
        A known surface point (mm) and its unit normal: the near-field
        model's anchor and the height map's.
    height : callable or None
        ``height(x, y) -> z`` (mm), the exact surface where known.
    scale_mm : float or None
        The size height errors are reported against.
    truth_parts : tuple of str
        Truth parts that belong to the surface measured.
    sphere : ((3,) centre, radius) or None
        The sphere, for an object that is one.
    profile : JointProfile or None
        A joint's exact cross-section profile.
    """

    name: str
    parts: dict
    datum: np.ndarray | None = None
    datum_normal: np.ndarray | None = None
    height: Callable | None = None
    scale_mm: float | None = None
    truth_parts: tuple = ("object",)
    sphere: tuple | None = None
    profile: Any = field(default=None, repr=False)

    def description(self, part_names=None) -> dict:
        """JSON-ready geometry: ``spheres`` (name -> centre, radius), ``plane`` (one facet) or ``joint``
        (its kind, lift and ``part_names``, the rendered shapes' names)."""
        spheres = {k: p for k, p in self.parts.items() if p.shape == "sphere"}
        if spheres:
            return {"spheres": {k: {"center_mm": list(p.center_mm), "radius_mm": p.radius_mm}
                                for k, p in spheres.items()}}
        out: dict[str, Any] = {}
        for p in self.parts.values():
            if p.shape == "facet":
                out["plane"] = {"center_mm": list(p.center_mm), "normal": list(p.normal), "size_mm": p.size_mm}
            elif p.shape == "joint":
                out["joint"] = {"kind": p.joint.kind, "lift_mm": p.lift_mm, "parts": list(part_names or ())}
        return out


def sphere_height(center_mm, radius_mm):
    """``z(x, y)`` of a sphere's upper half (its rim's height outside it)."""
    cx, cy, cz = center_mm
    r2 = radius_mm * radius_mm

    def height(x, y):
        z = np.sqrt(np.clip(r2 - (np.asarray(x) - cx) ** 2 - (np.asarray(y) - cy) ** 2, 0, None))
        return z + cz if cz else z

    return height


def _sphere(*, center_mm=(0.0, 0.0, 0.0), radius_mm=SHINY_SPHERE_RADIUS_MM, part="object"):
    c = tuple(center_mm)
    return ScannedObject("sphere", {part: Part("sphere", c, radius_mm)},
                         np.array([c[0], c[1], c[2] + radius_mm]), np.array([0.0, 0.0, 1.0]),
                         sphere_height(c, radius_mm), radius_mm, (part,), (c, radius_mm))


def _three_spheres():
    centres = {"sphere_a": (-1.4, 0.9, 0.2), "sphere_b": (0.3, -0.8, 1.0), "sphere_c": (1.5, 0.7, 0.5)}
    return ScannedObject("three_spheres", {k: Part("sphere", c) for k, c in centres.items()},
                         scale_mm=SHINY_SPHERE_RADIUS_MM, truth_parts=tuple(centres))


def _three_sizes():
    spheres = {"sphere_a": ((-2.0, -2.2, 0.3), 1.2), "sphere_b": ((0.3, 0.2, 1.0), 0.5),
               "sphere_c": ((2.3, 2.4, -0.5), 0.8)}
    return ScannedObject("three_sizes", {k: Part("sphere", c, r) for k, (c, r) in spheres.items()},
                         scale_mm=0.8, truth_parts=tuple(spheres))


def _large_sphere():
    big = _sphere(center_mm=(0.0, 0.0, -3.0), radius_mm=5.0, part="sphere")
    return replace(big, name="large_sphere")


def _shallow_sphere():
    cap = _sphere(center_mm=(0.3, 0.0, 0.5 - 12.0), radius_mm=12.0, part="cap")
    return replace(cap, name="shallow_sphere", scale_mm=0.5)


def _facet(*, center_mm=(0.3, 0.0, 0.5), tilt_deg=10.0, size_mm=5.0, normal=None, part="plane"):
    if normal is None:
        t = np.radians(tilt_deg)
        normal = np.array([np.sin(t), 0.0, np.cos(t)])
    n = np.asarray(normal, dtype=float)
    c = tuple(float(v) for v in center_mm)
    nx, ny, nz = n / np.linalg.norm(n)

    def height(x, y):
        return c[2] - (nx * (np.asarray(x) - c[0]) + ny * (np.asarray(y) - c[1])) / nz

    return ScannedObject("tilted_plane", {part: Part("facet", c, normal=tuple(n.tolist()), size_mm=size_mm)},
                         np.array(c, dtype=float), np.array([nx, ny, nz]), height, size_mm, (part,))


def _step():
    x0 = 0.45
    p, q = step_gradient(np.array(x0), np.array(0.0))
    nrm = np.array([-float(p), -float(q), 1.0])
    return ScannedObject("step", {"object": Part("mesh", mesh=step_mesh)},
                         np.array([x0, 0.0, float(step_height(x0, 0.0))]), nrm / np.linalg.norm(nrm),
                         step_height, STEP_PART["step_mm"], ("object",))


def _solder(*, kind="good", lift_mm=0.0):
    params = JointParams(kind=kind)
    prof = JointProfile(params)
    lo, hi = prof.visible_x_range
    xm = 0.5 * (lo + hi)
    nrm = np.asarray(prof.profile_normal(xm, 0.0, ripple=False), float).reshape(3)
    datum = np.array([xm, 0.0, float(prof.profile_z(xm, 0.0, ripple=False)) + lift_mm])
    return ScannedObject("solder", {"joint": Part("joint", joint=params, lift_mm=lift_mm)}, datum, nrm, None,
                         float(prof.fillet_height), ("solder",), profile=prof)


#: Every scanned object by name: a builder taking its placement options.
OBJECTS: dict[str, Callable[..., ScannedObject]] = {
    "sphere": _sphere,                  # the SHINY calibration sphere (r = 0.79375 mm), datum its apex
    "three_spheres": _three_spheres,    # three calibration spheres at different places and heights
    "three_sizes": _three_sizes,        # spheres of r = 1.2, 0.5 and 0.8 mm at different places and heights
    "large_sphere": _large_sphere,      # a 5 mm radius sphere whose top is 2 mm above the reference plane
    "shallow_sphere": _shallow_sphere,  # a 12 mm radius cap 0.5 mm high: a machined part
    "tilted_plane": _facet,             # a square flat mirror (5 mm, tilted 10 degrees, 0.5 mm up by default)
    "step": _step,                      # the machined part of STEP_PART, datum on its upper plateau at x = 0.45 mm
    "solder": _solder,                  # a procedural solder joint (nominal good), datum mid-fillet
}
OBJECT_NAMES = tuple(OBJECTS)
#: What each study scans: the stereo study (each object off the origin or above the reference plane, as
#: its placements say) and the coded scans.
STEREO_OBJECTS = ("sphere", "three_spheres", "three_sizes", "large_sphere", "shallow_sphere", "tilted_plane",
                  "solder")
CODED_OBJECTS = ("sphere", "step", "solder")

#: Object kinds of a data set's spec: the calibration sphere, a drawn solder joint, the random shape
#: families of :mod:`~shinysim.objects.shapes` and a user's mesh file.
DATASET_OBJECT_KINDS = ("sphere", "solder", *SHAPE_FAMILIES, "mesh")


def scanned_object(name: str, **options) -> ScannedObject:
    """The :data:`OBJECTS` entry ``name`` built with its placement ``options``.

    Raises
    ------
    OptionError
        An unknown name.
    """
    check_choice("object", name, OBJECT_NAMES)
    return OBJECTS[name](**options)
