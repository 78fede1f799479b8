"""Mitsuba shapes of a scanned object of the registry (:mod:`shinysim.objects.registry`)."""

from __future__ import annotations

import numpy as np

from ..errors import OptionError
from ..objects.registry import ScannedObject, scanned_object
from .meshes import mesh_object
from .scene import facet_object, rough_conductor, sphere_object
from .solder import make_joint
from .solder_scene import joint_objects

__all__ = ["scene_objects"]


def scene_objects(obj: ScannedObject | str, *, alpha: float = 0.02, distribution: str = "ggx", folder=None,
                  **options) -> dict:
    """Named Mitsuba shape dicts of ``obj`` (a :class:`ScannedObject`, or a registry name built with ``options``).

    Spheres, facets and meshes are rough conductors of roughness ``alpha``; a
    joint keeps its own materials and names its shapes by part. ``folder``
    holds mesh files (a mesh part's default: a temporary folder; a joint
    needs one).
    """
    if isinstance(obj, str):
        obj = scanned_object(obj, **options)
    out = {}
    for name, part in obj.parts.items():
        if part.shape == "sphere":
            out[name] = sphere_object(radius=part.radius_mm, center=part.center_mm, alpha=alpha,
                                      distribution=distribution)["object"]
        elif part.shape == "facet":
            out[name] = facet_object(part.center_mm, np.array(part.normal), part.size_mm, alpha=alpha,
                                     distribution=distribution)["object"]
        elif part.shape == "mesh":
            out[name] = mesh_object(part.mesh(), bsdf=rough_conductor(alpha, distribution=distribution), folder=folder)
        else:
            if folder is None:
                raise OptionError(f"the {obj.name} scene needs a folder for its mesh files", field="folder")
            shapes = joint_objects(make_joint(part.joint), folder)
            if part.lift_mm:  # as on a board that is not at the reference height
                lift = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, float(part.lift_mm)],
                        [0.0, 0.0, 0.0, 1.0]]
                for shape in shapes.values():
                    shape["to_world"] = lift
            out.update(shapes)
    return out
