"""Mitsuba 3 scenes of a rig: sources, camera, object and materials.

A scene is a plain Python dict (``mi.load_dict``) built from a
:class:`~shinysim.rig.Rig` and a dict of named object shapes. The same scene
can be written as Mitsuba XML (:func:`scene_xml`) that the ``mitsuba``
command-line renderer loads; ``scenes/shiny_sphere.xml`` is made that way and
a test checks that it matches the dict.

Building the dicts needs no renderer; only :func:`load_scene` imports
Mitsuba. Millimetres throughout: the 0.8 mm sphere is far above the ray
tracer's self-intersection epsilon.
"""

from __future__ import annotations

import numpy as np

from ..objects.facet import Facet
from ..objects.sphere import SHINY_SPHERE_RADIUS_MM, Sphere
from ..errors import OptionError

__all__ = [
    "DISTRIBUTIONS",
    "rough_conductor",
    "sphere_object",
    "facet_object",
    "plate_objects",
    "camera_sensor",
    "source_shapes",
    "scene_dict",
    "scene_xml",
    "load_scene",
]

#: Microfacet distributions of Mitsuba's rough conductor.
DISTRIBUTIONS = ("ggx", "beckmann")


def rough_conductor(alpha, *, distribution="ggx", material="none", reflectance=None):
    """A Mitsuba ``roughconductor`` BSDF dict.

    Parameters
    ----------
    alpha : float
        Microfacet roughness (GGX/Beckmann alpha), > 0.
    distribution : {"ggx", "beckmann"}
    material : str
        Mitsuba conductor preset (e.g. "Cr", "Al"); "none" is an ideal
        mirror with reflectance 1 (the default, so highlight intensities
        are set by geometry alone).
    reflectance : float, optional
        Scales the reflected light (``specular_reflectance``).
    """
    if not (np.isfinite(alpha) and alpha > 0):
        raise OptionError(f"alpha must be > 0, got {alpha!r}")
    if distribution not in DISTRIBUTIONS:
        raise OptionError(f"distribution must be one of {DISTRIBUTIONS}, got {distribution!r}")
    d = {"type": "roughconductor", "alpha": float(alpha), "distribution": distribution, "material": material}
    if reflectance is not None:
        d["specular_reflectance"] = {"type": "uniform", "value": float(reflectance)}
    return d


def sphere_object(*, radius=SHINY_SPHERE_RADIUS_MM, center=(0.0, 0.0, 0.0), alpha=0.02, distribution="ggx",
                  material="none"):
    """A polished sphere (:class:`shinysim.objects.sphere.Sphere`) as ``{"object": shape dict}``.

    The defaults are the paper's calibration sphere.
    """
    sphere = Sphere(center, radius)
    return {
        "object": {
            "type": "sphere",
            "center": list(sphere.center),
            "radius": sphere.radius,
            "bsdf": rough_conductor(alpha, distribution=distribution, material=material),
        }
    }


def facet_object(center, normal, size, *, alpha=0.002, distribution="ggx", material="none"):
    """A small flat square mirror facet (:class:`shinysim.objects.facet.Facet`) as ``{"object": shape dict}``.

    A Mitsuba ``rectangle`` (local square [-1, 1]^2 in its x-y plane, normal
    +z) carried by :meth:`Facet.to_world <shinysim.objects.facet.Facet.to_world>`
    onto a square of side ``size`` centred at ``center`` with unit normal
    ``normal``, with a rough-conductor BSDF on its front (normal) side.

    Parameters
    ----------
    center : (3,) float, millimetres
    normal : (3,) float
        Facet normal (normalised here).
    size : float, millimetres
        Side of the square.
    alpha, distribution, material
        As in :func:`rough_conductor`.

    Returns
    -------
    dict
        ``{"object": {"type": "rectangle", "to_world": 4x4 list of lists, "bsdf": ...}}``;
        the matrix is plain data, so the dict needs no renderer to build.
    """
    facet = Facet(center, normal, size)
    return {
        "object": {
            "type": "rectangle",
            "to_world": facet.to_world().tolist(),
            "bsdf": rough_conductor(alpha, distribution=distribution, material=material),
        }
    }


def plate_objects(plate, placement, *, radiance=1.0, half_size_mm=4.0):
    """The paper's calibration plate as Mitsuba shapes: backlit holes in an opaque plate.

    Each hole is an emitting disk of the hole's diameter in the plate's top
    face (what a camera sees of a backlit through-hole); the plate is a
    black, non-reflecting square 1 um below that face, ``2 half_size_mm``
    across, so that nothing but the holes is lit.

    Parameters
    ----------
    plate : shinysim.objects.plate.HolePlate
    placement : shinysim.objects.plate.PlatePlacement
    radiance : float
        Radiance of each hole.
    """
    m = np.asarray(placement.matrix(), dtype=float)
    below = np.eye(4)
    below[2, 3] = -1e-3
    size = np.diag([half_size_mm, half_size_mm, 1.0, 1.0])
    out = {"plate": {"type": "rectangle", "to_world": (m @ below @ size).tolist(),
                     "bsdf": {"type": "diffuse", "reflectance": 0.0}}}
    r = 0.5 * plate.hole_diameter
    for i, (x, y) in enumerate(np.asarray(plate.holes_xy, dtype=float)):
        local = np.diag([r, r, 1.0, 1.0])
        local[:2, 3] = (x, y)
        out[f"hole_{i:03d}"] = {"type": "disk", "to_world": (m @ local).tolist(),
                                "bsdf": {"type": "diffuse", "reflectance": 0.0},
                                "emitter": {"type": "area", "radiance": float(radiance)}}
    return out


def _look_at_matrix(cam):
    """4x4 camera-to-world matrix equal to Mitsuba's ``look_at``."""
    d = cam.forward
    left = np.cross(cam.up, d)
    left /= np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, cam.position
    return m


def camera_sensor(cam, *, spp=64, seed=0, pixel_format="luminance"):
    """A Mitsuba sensor dict equal to a :class:`~shinysim.rig.Camera`.

    Mitsuba's image +x is the camera's ``-left`` = ``forward x up`` and its
    image +y is ``-up'``, the same as :mod:`shinysim.conventions`; the box
    reconstruction filter makes each pixel the average over its area.
    The sensor's ``to_world`` is kept as a plain 4x4 matrix (list of lists)
    so that this dict needs no renderer to build. Mitsuba's sensors have no
    lens distortion: the dict is that of the camera without it and with its
    principal point at the image centre (the one-pass and truth renderers
    trace the camera's own rays and model both).
    """
    m = _look_at_matrix(cam)
    film = {
        "type": "hdrfilm",
        "width": cam.width,
        "height": cam.height,
        "pixel_format": pixel_format,
        "component_format": "float32",
        "rfilter": {"type": "box"},
    }
    if cam.projection == "orthographic":
        half_w = 0.5 * cam.field_width
        half_h = half_w * cam.height / cam.width
        m = m @ np.diag([half_w, half_h, 1.0, 1.0])
        sensor = {"type": "orthographic", "near_clip": 1e-3, "far_clip": 1e5}
    else:
        sensor = {"type": "perspective", "fov": cam.fov_x_deg, "fov_axis": "x", "near_clip": 1e-2,
                  "far_clip": 1e5}
    sensor["to_world"] = m.tolist()
    sensor["film"] = film
    sensor["sampler"] = {"type": "independent", "sample_count": int(spp), "seed": int(seed)}
    return sensor


def source_shapes(rig, *, radiance=1.0, sources=None):
    """Emitter dicts ``{"source_000": ..., ...}`` for a rig's sources.

    A source with radius > 0 is a sphere with an area emitter (a fiber tip:
    a point light would give no highlight on a near-mirror); radius 0 gives a
    ``point`` emitter with intensity ``radiance``; a distant source gives a
    ``directional`` emitter with irradiance ``radiance``.

    Parameters
    ----------
    sources : iterable of int, optional
        Which sources to include (default all).
    """
    keys = range(rig.n_sources) if sources is None else sources
    out = {}
    for k in keys:
        pos = rig.source_positions[k]
        r = rig.source_radii[k]
        name = f"source_{k:03d}"
        if rig.source_distant[k]:
            out[name] = {"type": "directional", "direction": (-pos).tolist(), "irradiance": float(radiance)}
        elif r > 0:
            out[name] = {
                "type": "sphere",
                "center": pos.tolist(),
                "radius": float(r),
                "bsdf": {"type": "diffuse", "reflectance": 0.0},
                "emitter": {"type": "area", "radiance": float(radiance)},
            }
        else:
            out[name] = {"type": "point", "position": pos.tolist(), "intensity": float(radiance)}
    return out


def scene_dict(rig, objects, *, camera_index=0, spp=64, seed=0, radiance=1.0, sources=None,
               integrator=None):
    """The whole scene as a dict for ``mi.load_dict`` (after :func:`to_mitsuba`).

    Parameters
    ----------
    rig : Rig
    objects : dict of str -> shape dict
        Named object shapes (e.g. :func:`sphere_object`).
    camera_index : int
    spp, seed : int
        Sensor sampler settings (used by ``mi.render``).
    radiance : float
        Emitted radiance of every source.
    sources : iterable of int, optional
        Sources to include (default all; the XML scene has all of them on,
        the picture of a whole scan at once).
    integrator : dict, optional
        Default: ``direct`` (one bounce, all a convex mirror object needs).
    """
    d = {"type": "scene"}
    d["integrator"] = integrator or {"type": "direct"}
    d["sensor"] = camera_sensor(rig.cameras[camera_index], spp=spp, seed=seed)
    for name, shape in objects.items():
        if name.startswith("source_") or name in ("integrator", "sensor", "type"):
            raise OptionError(f"object name {name!r} is reserved")
        d[name] = shape
    d.update(source_shapes(rig, radiance=radiance, sources=sources))
    return d


def to_mitsuba(d):
    """Turn plain matrices (``to_world`` lists) into Mitsuba transforms."""
    import mitsuba as mi

    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out[k] = to_mitsuba(v)
        elif k == "to_world" and isinstance(v, list):
            out[k] = mi.ScalarTransform4f(np.asarray(v, dtype=float))
        else:
            out[k] = v
    return out


def load_scene(d):
    """``mi.load_dict`` of a scene dict from :func:`scene_dict`.

    Loaded with ``optimize=False``: Mitsuba (3.7+) otherwise merges equivalent
    BSDFs and then the meshes that share one into a single shape, so parts
    with equal materials (a bridge's two solder bodies, say) would lose their
    ids and the truth's part map would be wrong.
    """
    import mitsuba as mi

    return mi.load_dict(to_mitsuba(d), optimize=False)


# -- XML ------------------------------------------------------------------------

def _fmt(x):
    return repr(float(x))


def _xml_value(name, value, indent, params):
    pad = " " * indent
    if name in params:
        return f'{pad}<float name="{name}" value="${params[name]}"/>\n'
    if isinstance(value, bool):
        return f'{pad}<boolean name="{name}" value="{str(value).lower()}"/>\n'
    if isinstance(value, int):
        return f'{pad}<integer name="{name}" value="{value}"/>\n'
    if isinstance(value, float):
        return f'{pad}<float name="{name}" value="{_fmt(value)}"/>\n'
    if isinstance(value, str):
        return f'{pad}<string name="{name}" value="{value}"/>\n'
    if name == "to_world":
        flat = " ".join(_fmt(x) for row in value for x in row)
        return f'{pad}<transform name="to_world">\n{pad}    <matrix value="{flat}"/>\n{pad}</transform>\n'
    if isinstance(value, (list, tuple)) and len(value) == 3:
        tag = "vector" if name == "direction" else "point"
        return f'{pad}<{tag} name="{name}" x="{_fmt(value[0])}" y="{_fmt(value[1])}" z="{_fmt(value[2])}"/>\n'
    raise TypeError(f"cannot write {name}={value!r} as Mitsuba XML")


_TAGS = {
    "sensor": "sensor", "film": "film", "sampler": "sampler", "rfilter": "rfilter", "integrator": "integrator",
    "bsdf": "bsdf", "emitter": "emitter", "specular_reflectance": "spectrum",
}


def _xml_object(tag, d, indent, name=None, params=None, obj_id=None):
    pad = " " * indent
    attrs = f' type="{d["type"]}"'
    if obj_id:
        attrs += f' id="{obj_id}"'
    if name and tag not in ("sensor", "integrator", "shape", "emitter", "bsdf", "film", "sampler", "rfilter"):
        attrs += f' name="{name}"'
    out = f"{pad}<{tag}{attrs}>\n"
    for key, value in d.items():
        if key == "type":
            continue
        if isinstance(value, dict):
            out += _xml_object(_TAGS.get(key, "spectrum"), value, indent + 4, name=key, params=params)
        else:
            out += _xml_value(key, value, indent + 4, params or {})
    return out + f"{pad}</{tag}>\n"


def scene_xml(d, *, defaults=None, comment=None):
    """Mitsuba 3 XML text of a scene dict from :func:`scene_dict`.

    Parameters
    ----------
    defaults : dict, optional
        ``{name: value}`` for ``<default>`` parameters, e.g.
        ``{"alpha": 0.02, "spp": 64}``: every float field called ``alpha``
        becomes ``$alpha`` and the sampler's ``sample_count`` ``$spp``, so
        ``mitsuba -D alpha=0.05 -D spp=16 scene.xml`` overrides them.
    comment : str, optional
        Text for an XML comment at the top.
    """
    defaults = dict(defaults or {})
    params = {k: k for k in defaults if k != "spp"}
    lines = '<scene version="3.0.0">\n'
    if comment:
        lines += "    <!--\n" + "".join(f"    {c}\n" for c in comment.strip().splitlines()) + "    -->\n"
    for k, v in defaults.items():
        lines += f'    <default name="{k}" value="{v}"/>\n'
    for key, value in d.items():
        if key == "type":
            continue
        if key == "integrator":
            lines += _xml_object("integrator", value, 4)
        elif key == "sensor":
            sensor = dict(value)
            if "spp" in defaults:
                sensor["sampler"] = dict(sensor["sampler"])
                sensor["sampler"]["sample_count"] = "$spp"
            lines += _xml_object("sensor", sensor, 4, obj_id="sensor").replace(
                '<string name="sample_count" value="$spp"/>', '<integer name="sample_count" value="$spp"/>'
            )
        elif value["type"] in ("point", "directional"):
            lines += _xml_object("emitter", value, 4, obj_id=key)
        else:
            lines += _xml_object("shape", value, 4, obj_id=key, params=params)
    return lines + "</scene>\n"


def shiny_sphere_xml(*, alpha=0.02, spp=64, projection="perspective", resolution=512):
    """XML of the default sphere scan with every fiber lit (``scenes/shiny_sphere.xml``)."""
    from ..rig import shiny_1988

    rig = shiny_1988(projection=projection, resolution=resolution)
    d = scene_dict(rig, sphere_object(alpha=alpha), spp=spp)
    comment = (
        "shinysim: the SHINY rig (Sanderson, Weiss & Nayar 1988) with the 1/16 in calibration sphere.\n"
        "Millimetres. 21 fibers (spheres of radius 0.508 mm with area emitters) on a semicircle of\n"
        "radius 43.18 mm in the x-z plane, all lit at once (the whole scan in one picture); the\n"
        "Python builder shinysim.sim.scene.scene_dict(..., sources=[k]) lights one at a time.\n"
        "Camera looks down -z. Regenerate with: python -m shinysim.sim.scene scenes/shiny_sphere.xml\n"
        "Render with: mitsuba -m llvm_ad_mono -D alpha=0.05 -D spp=16 shiny_sphere.xml"
    )
    return scene_xml(d, defaults={"alpha": alpha, "spp": spp}, comment=comment)


if __name__ == "__main__":  # pragma: no cover
    import sys
    from pathlib import Path

    from .._shared import write_text

    target = Path(sys.argv[1] if len(sys.argv) > 1 else "scenes/shiny_sphere.xml")
    write_text(target, shiny_sphere_xml(), overwrite="--overwrite" in sys.argv)
    print(f"wrote {target}")
