"""Rig presets: the paper's SHINY semicircle, domes, stereo pairs, and one registry of them by name.

:data:`RIG_PRESETS` maps each preset's name to its builder (keyword
arguments only); :func:`rig_preset` builds one by name with its options
checked. The studies, the data sets and the command line pick their rigs
from it (:data:`SCAN_RIGS`, :data:`STEREO_RIGS`: the names they offer).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from .._shared import check_choice
from ..conventions import MM_PER_INCH
from ..errors import OptionError
from .core import Camera, Rig
from .visibility import drop_sources_in_view

__all__ = [
    "DOME_LAYOUTS",
    "DOME_RIM_DEG",
    "RIG_PRESETS",
    "SCAN_RIGS",
    "STEREO_FIELD_WIDTH_MM",
    "STEREO_RIGS",
    "distant_rig",
    "dome",
    "fibonacci_hemisphere",
    "ring_layout",
    "rings_dome",
    "rig_preset",
    "rotating_semicircle",
    "shiny_1988",
    "shiny_1988_source_angles_deg",
    "shiny_stereo",
    "stereo_crossing_arcs",
    "stereo_dome",
    "stereo_pair",
    "stereo_semicircle",
]


def shiny_1988_source_angles_deg(n_sources=21, spacing_deg=8.0):
    """Signed polar angles (degrees) of the preset's fibers, in the x-z plane.

    ``-84, -76, ..., -4, +4, ..., +76`` for the default 21 fibers: evenly
    spaced, symmetric about the axis except for the last fiber, and never
    on the camera axis (where a fiber would block the view of the object).
    """
    first = -spacing_deg * (n_sources // 2) - 0.5 * spacing_deg
    if n_sources % 2 == 0:
        first = -spacing_deg * (n_sources / 2 - 0.5)
    return first + spacing_deg * np.arange(n_sources)


def shiny_1988(
    *,
    projection: str = "perspective",
    resolution: int = 512,
    field_width_mm: float = 2.0,
    camera_height_mm: float = 5.0 * MM_PER_INCH,
    radius_mm: float = 1.7 * MM_PER_INCH,
    fiber_diameter_mm: float = 0.040 * MM_PER_INCH,
    n_sources: int = 21,
    spacing_deg: float = 8.0,
) -> Rig:
    """The SHINY prototype of the paper (Section IV, Fig. 7).

    21 optical fibers 0.040 in (1.016 mm) across on a semicircle of radius
    1.7 in (43.18 mm) in the x-z plane, 8 degrees apart at signed polar
    angles -84 ... +76 degrees (the paper does not give the span; see
    :func:`shiny_1988_source_angles_deg`), and one camera looking down -z at
    the object on the reference plane z = 0.

    Parameters
    ----------
    projection : {"perspective", "orthographic"}
    resolution : int
        Square image size (the paper's camera is 512 x 512).
    field_width_mm : float
        Width of the imaged field at the object; 2.0 mm frames the 1/16 in
        calibration sphere (1.59 mm) with a margin.
    camera_height_mm : float
        Height of the centre of projection above the reference plane (the
        paper gives none; 5 in is a plausible macro working distance).
    """
    angles = np.radians(shiny_1988_source_angles_deg(n_sources, spacing_deg))
    positions = radius_mm * np.stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)], axis=1)
    return Rig(
        source_positions=positions,
        source_radii=np.full(n_sources, 0.5 * fiber_diameter_mm),
        cameras=(_top_camera(projection, resolution, field_width_mm, camera_height_mm),),
        name="shiny_1988",
        metadata={
            "preset": "shiny_1988",
            "source_angles_deg": shiny_1988_source_angles_deg(n_sources, spacing_deg).tolist(),
            "array_radius_mm": radius_mm,
        },
    )


def distant_rig(directions: ArrayLike, camera: Camera, *, name: str = "distant") -> Rig:
    """A rig whose sources are known only by direction (at infinity).

    Parameters
    ----------
    directions : (n_sources, 3) array_like
        Direction towards each light, in the world frame.
    camera : Camera
    """
    directions = np.asarray(directions, dtype=float)
    return Rig(
        source_positions=directions,
        source_radii=np.zeros(len(directions)),
        cameras=(camera,),
        source_distant=np.ones(len(directions), bool),
        name=name,
    )


#: Source layouts of :func:`dome`.
DOME_LAYOUTS = ("fibonacci", "rings")


def fibonacci_hemisphere(n: int, *, max_polar_deg: float = 80.0) -> np.ndarray:
    """``n`` unit directions spread evenly over a spherical cap about +z.

    Beyond 90 degrees the cap reaches below the horizon: the paper's
    "spherical array" (Fig. 1), which a free-standing object needs for
    normals tilted more than 45 degrees from an axial camera.

    The golden-angle (Fibonacci) spiral: equal solid angle per point, polar
    angles from ``acos(1 - (i + 1/2)(1 - cos max) / n)``, azimuths ``i`` times
    the golden angle. No point lies on the axis (the first is at
    ``acos(1 - (1 - cos max) / (2 n))``, 2.3 degrees for 500 points over 80
    degrees), so a dome leaves the camera's view free.

    Parameters
    ----------
    n : int, >= 1
    max_polar_deg : float, in (0, 180)
        Polar angle of the cap's rim.

    Returns
    -------
    (n, 3) ndarray
    """
    n = int(n)
    if n < 1:
        raise OptionError(f"n must be >= 1, got {n}")
    if not 0 < max_polar_deg < 180:
        raise OptionError(f"max_polar_deg must lie in (0, 180), got {max_polar_deg}")
    i = np.arange(n) + 0.5
    z = 1.0 - i * (1.0 - np.cos(np.radians(max_polar_deg))) / n
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _ring_directions(rings) -> np.ndarray:
    dirs = []
    for k, ring in enumerate(rings):
        if len(ring) != 2:
            raise OptionError(f"rings[{k}] must be (polar_deg, count), got {ring!r}")
        polar, count = float(ring[0]), int(ring[1])
        if not 0 <= polar < 180 or count < 1:
            raise OptionError(f"rings[{k}]: polar angle must lie in [0, 180) degrees and count be >= 1, got {ring!r}")
        phi = 2 * np.pi * (np.arange(count) + 0.5 * (k % 2)) / count
        t = np.radians(polar)
        dirs.append(np.stack([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.full(count, np.cos(t))], axis=1))
    return np.concatenate(dirs)


def _top_camera(projection, resolution, field_width_mm, camera_height_mm):
    return Camera(projection=projection, width=resolution, height=resolution, position=[0.0, 0.0, camera_height_mm],
                  target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0], field_width=field_width_mm, name="top")


def dome(
    *,
    n_sources: int = 200,
    layout: str = "fibonacci",
    rings: Sequence[tuple[float, int]] | None = None,
    max_polar_deg: float = 80.0,
    radius_mm: float | None = 1.7 * MM_PER_INCH,
    fiber_diameter_mm: float = 0.040 * MM_PER_INCH,
    projection: str = "perspective",
    resolution: int = 512,
    field_width_mm: float = 2.0,
    camera_height_mm: float = 5.0 * MM_PER_INCH,
) -> Rig:
    """A dome of sources about the object: the paper's "spherical array" (Fig. 1).

    With the rim at or below 90 degrees it is a hemispherical dome above the
    object. An axial camera sees a mirror normal only where it bisects the
    view and a source, so a rim at polar angle ``a`` reaches normals up to
    ``a / 2``: ``sin^2(a / 2)`` of a sphere's image (41 % at 80 degrees). A
    rim beyond 90 degrees carries the array below the horizon, as Fig. 1's
    sphere does, for free-standing objects; 90 % of a sphere's image needs
    ``a >= 2 asin(sqrt 0.9) = 143.1`` degrees.

    Parameters
    ----------
    n_sources : int
        Number of sources of the ``fibonacci`` layout (ignored for ``rings``).
    layout : {"fibonacci", "rings"}
        ``fibonacci``: :func:`fibonacci_hemisphere`, even over the cap.
        ``rings``: stacked rings, like the tiered ring lights of solder
        inspection; ``rings`` gives ``(polar_deg, count)`` per ring.
    max_polar_deg : float, in (0, 180)
        Rim of the fibonacci cap, from the camera axis (beyond 90: below the
        horizon).
    radius_mm : float or None
        Distance of the fiber tips from the object (the SHINY array's 1.7 in
        by default); None makes every source distant (a direction only).
    fiber_diameter_mm : float
        Diameter of each near source (the SHINY fibers' 0.040 in).
    projection, resolution, field_width_mm, camera_height_mm
        The camera, as in :func:`shiny_1988`.
    """
    if layout not in DOME_LAYOUTS:
        raise OptionError(f"layout must be one of {DOME_LAYOUTS}, got {layout!r}")
    if layout == "rings":
        if not rings:
            raise OptionError("the rings layout needs rings=[(polar_deg, count), ...]")
        dirs = _ring_directions(rings)
    else:
        dirs = fibonacci_hemisphere(n_sources, max_polar_deg=max_polar_deg)
    camera = _top_camera(projection, resolution, field_width_mm, camera_height_mm)
    distant = radius_mm is None
    if not distant:
        if not radius_mm > 0:
            raise OptionError(f"radius_mm must be > 0 or None, got {radius_mm}")
        # a fiber tip inside the camera's view of the object's field would
        # hide it from above, or shine into the image from below (the view
        # cone reaches the field at the target and widens beyond it)
        half = 0.5 * field_width_mm
        lateral = radius_mm * np.hypot(dirs[:, 0], dirs[:, 1])
        height = radius_mm * dirs[:, 2]
        cone = half * (np.ones_like(height) if projection == "orthographic"
                       else np.clip(1.0 - height / camera_height_mm, 0.0, None))
        blocking = lateral - 0.5 * fiber_diameter_mm < cone
        if np.any(blocking):
            k = int(np.flatnonzero(blocking)[0])
            polar = np.degrees(np.arccos(np.clip(dirs[k, 2], -1, 1)))
            if height[k] < 0:
                raise OptionError(f"source {k} (polar {polar:.2f} deg) lies in the camera's view cone below the "
                                 f"object and would shine into the image; use a smaller max_polar_deg")
            raise OptionError(f"source {k} (polar {polar:.2f} deg) lies "
                             f"in the camera's view of the object; use fewer sources or a ring layout off the axis")
    meta = {"preset": "dome", "layout": layout, "n_sources": int(len(dirs)), "max_polar_deg": float(max_polar_deg),
            "array_radius_mm": None if distant else float(radius_mm)}
    if layout == "rings":
        meta["rings"] = [[float(a), int(c)] for a, c in rings]
    return Rig(
        source_positions=dirs if distant else radius_mm * dirs,
        source_radii=np.zeros(len(dirs)) if distant else np.full(len(dirs), 0.5 * fiber_diameter_mm),
        cameras=(camera,),
        source_distant=np.full(len(dirs), distant),
        name="dome",
        metadata=meta,
    )


def stereo_pair(base: Rig | None = None, *, beta_deg: float = 15.0) -> Rig:
    """Two cameras at +beta and -beta from the vertical in the x-z plane, sharing ``base``'s sources.

    The paper's structured-highlight stereo (Section V, Fig. 15): each
    camera keeps the base camera's distance to its target, field width,
    resolution and projection, and is turned about the y axis (camera 0 at
    +beta towards +x, camera 1 at -beta).

    Parameters
    ----------
    base : Rig, optional
        Sources and camera to start from (default :func:`shiny_1988`).
    beta_deg : float, in (0, 80]
    """
    base = shiny_1988() if base is None else base
    return Rig(source_positions=base.source_positions, source_radii=base.source_radii,
               cameras=_pair_cameras(base.camera, beta_deg), source_distant=base.source_distant,
               reference_z=base.reference_z, name=f"{base.name}_stereo",
               metadata={**base.metadata, "stereo_beta_deg": float(beta_deg)}, anchor=base.anchor)


def _pair_cameras(cam, beta_deg):
    """The cameras of :func:`stereo_pair`: ``cam`` turned about the y axis through its target to +-beta."""
    if not 0 < beta_deg <= 80:
        raise OptionError(f"beta_deg must lie in (0, 80], got {beta_deg}")
    target = np.asarray(cam.target, float)
    dist = float(np.linalg.norm(np.asarray(cam.position, float) - target))
    cams = []
    for sign, name in ((1, "plus"), (-1, "minus")):
        b = np.radians(sign * beta_deg)
        pos = target + dist * np.array([np.sin(b), 0.0, np.cos(b)])
        cams.append(Camera(projection=cam.projection, width=cam.width, height=cam.height, position=pos.tolist(),
                           target=target.tolist(), up=[0.0, 1.0, 0.0], field_width=cam.field_width, name=name))
    return tuple(cams)


def _stereo_rig(dirs, name, meta, *, beta_deg, radius_mm, fiber_diameter_mm, projection, resolution, field_width_mm,
                camera_height_mm):
    """The stereo rig of source directions ``dirs``: the two cameras, the sources out of their views."""
    cams = _pair_cameras(_top_camera(projection, resolution, field_width_mm, camera_height_mm), beta_deg)
    if not radius_mm > 0:
        raise OptionError(f"radius_mm must be > 0, got {radius_mm}")
    pos, radii, hidden = drop_sources_in_view(radius_mm * dirs, 0.5 * fiber_diameter_mm, cams)
    meta = {**meta, "n_sources": int((~hidden).sum()), "sources_removed_for_cameras": int(hidden.sum()),
            "array_radius_mm": float(radius_mm), "stereo_beta_deg": float(beta_deg)}
    return Rig(source_positions=pos, source_radii=radii, cameras=cams, name=name, metadata=meta)


def stereo_dome(
    *,
    n_sources: int = 1000,
    beta_deg: float = 15.0,
    max_polar_deg: float = 80.0,
    radius_mm: float = 1.7 * MM_PER_INCH,
    fiber_diameter_mm: float = 0.040 * MM_PER_INCH,
    projection: str = "perspective",
    resolution: int = 512,
    field_width_mm: float = 6.0,
    camera_height_mm: float = 5.0 * MM_PER_INCH,
) -> Rig:
    """Structured-highlight stereo in three dimensions: a Fibonacci dome and two cameras at +-beta.

    The sources of :func:`fibonacci_hemisphere` at ``radius_mm`` (the SHINY
    array's distance) and the cameras of :func:`stereo_pair` (turned about
    the y axis, camera 0 "plus" towards +x). The dome has holes where the
    cameras look through it: sources that would stand in either camera's
    view of the field (:func:`sources_in_view`) are left out, and
    ``metadata["sources_removed_for_cameras"]`` counts them.

    Why dense: a mirror element reflects a source into one camera only, so a
    stereo match pairs *different* sources whose highlights, one per camera,
    fall on nearly the same surface element. On a dome the two cameras'
    highlight elements form two unrelated lattices of spacing about
    ``r * s / 2`` on a sphere of radius ``r`` (``s`` the angular source
    spacing, ``sqrt(2 pi (1 - cos max_polar) / n)``: 4.1 degrees for 1000
    sources over 80 degrees), and their nearest pairs lie closer than a pixel
    only for a share of highlights that grows with ``n``; see
    ``docs/stereo.md``.

    Parameters
    ----------
    n_sources : int
        Sources of the Fibonacci layout before the camera holes.
    beta_deg : float, in (0, 80]
    field_width_mm : float
        A working volume several millimetres wide (the stereo case: objects
        anywhere in it, not only at the origin).
    Other parameters as in :func:`dome`.
    """
    dirs = fibonacci_hemisphere(n_sources, max_polar_deg=max_polar_deg)
    return _stereo_rig(dirs, "stereo_dome", {"preset": "stereo_dome", "layout": "fibonacci",
                                             "max_polar_deg": float(max_polar_deg)},
                       beta_deg=beta_deg, radius_mm=radius_mm, fiber_diameter_mm=fiber_diameter_mm,
                       projection=projection, resolution=resolution, field_width_mm=field_width_mm,
                       camera_height_mm=camera_height_mm)


def stereo_semicircle(
    *,
    spacing_deg: float = 2.5,
    max_polar_deg: float = 80.0,
    beta_deg: float = 15.0,
    radius_mm: float = 1.7 * MM_PER_INCH,
    fiber_diameter_mm: float = 0.040 * MM_PER_INCH,
    projection: str = "perspective",
    resolution: int = 512,
    field_width_mm: float = 6.0,
    camera_height_mm: float = 5.0 * MM_PER_INCH,
) -> Rig:
    """Planar structured-highlight stereo (paper Fig. 15): one semicircle of fibers and two cameras in its plane.

    Fibers every ``spacing_deg`` in the x-z plane (signed polar angles
    ``+-spacing/2, +-3 spacing/2, ...`` up to ``max_polar_deg``), cameras at
    ``+-beta_deg`` as in :func:`stereo_pair`, fibers in a camera's view left
    out. For an element in the source plane, camera 0 sees it under the
    source at polar angle ``2 theta - beta`` and camera 1 under ``2 theta +
    beta`` (theta the element's normal), so the two cameras' highlights fall
    on common elements when ``2 beta`` is a whole number of spacings: the
    default 2.5 degrees divides the default 30.
    """
    if not 0 < spacing_deg <= 45:
        raise OptionError(f"spacing_deg must lie in (0, 45], got {spacing_deg}")
    half = np.arange(0.5 * spacing_deg, max_polar_deg + 1e-9, spacing_deg)
    angles = np.radians(np.concatenate([-half[::-1], half]))
    dirs = np.stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)], axis=1)
    return _stereo_rig(dirs, "stereo_semicircle", {"preset": "stereo_semicircle", "spacing_deg": float(spacing_deg),
                                                   "max_polar_deg": float(max_polar_deg)},
                       beta_deg=beta_deg, radius_mm=radius_mm, fiber_diameter_mm=fiber_diameter_mm,
                       projection=projection, resolution=resolution, field_width_mm=field_width_mm,
                       camera_height_mm=camera_height_mm)


def stereo_crossing_arcs(
    *,
    n_fibers: int = 21,
    spacing_deg: float = 8.0,
    beta_deg: float = 15.0,
    radius_mm: float = 1.7 * MM_PER_INCH,
    fiber_diameter_mm: float = 0.040 * MM_PER_INCH,
    projection: str = "perspective",
    resolution: int = 512,
    field_width_mm: float = 6.0,
    camera_height_mm: float = 5.0 * MM_PER_INCH,
) -> Rig:
    """Two crossing arcs of fibers, one in the x-z plane and one in the y-z plane, and two cameras at +-beta.

    Each arc holds ``n_fibers`` (odd) fibers ``spacing_deg`` apart, symmetric about the zenith, which the
    arcs share: ``2 n_fibers - 1`` sources (41 for the defaults, polar angles up to 80 degrees). The
    cameras are :func:`stereo_pair`'s; fibers in a camera's view are left out. The y-z arc lights
    elements tilted across the cameras' plane, which a single semicircle in their plane never mirrors
    into them.
    """
    n_fibers = int(n_fibers)
    if n_fibers < 1 or n_fibers % 2 == 0:
        raise OptionError(f"n_fibers must be a positive odd number (the arcs share their middle fiber), "
                          f"got {n_fibers}")
    half = (n_fibers - 1) // 2
    if not 0 < spacing_deg * half < 90:
        raise OptionError(f"{n_fibers} fibers {spacing_deg} degrees apart must stay above the horizon (< 90)")
    polar = np.radians(spacing_deg * np.arange(-half, half + 1))
    xz = np.stack([np.sin(polar), np.zeros_like(polar), np.cos(polar)], axis=1)
    yz = np.stack([np.zeros_like(polar), np.sin(polar), np.cos(polar)], axis=1)
    dirs = np.concatenate([xz, np.delete(yz, half, axis=0)])
    return _stereo_rig(dirs, "stereo_crossing_arcs", {"preset": "stereo_crossing_arcs", "n_fibers": n_fibers,
                                                      "spacing_deg": float(spacing_deg)},
                       beta_deg=beta_deg, radius_mm=radius_mm, fiber_diameter_mm=fiber_diameter_mm,
                       projection=projection, resolution=resolution, field_width_mm=field_width_mm,
                       camera_height_mm=camera_height_mm)


def rotating_semicircle(
    *,
    positions: int = 10,
    n_fibers: int = 21,
    spacing_deg: float = 8.0,
    radius_mm: float = 1.7 * MM_PER_INCH,
    fiber_diameter_mm: float = 0.040 * MM_PER_INCH,
    projection: str = "perspective",
    resolution: int = 512,
    field_width_mm: float = 2.0,
    camera_height_mm: float = 5.0 * MM_PER_INCH,
) -> Rig:
    """The SHINY semicircle of fibers turned about the vertical axis to ``positions`` azimuths.

    The fibers of :func:`shiny_1988` (signed polar angles
    :func:`shiny_1988_source_angles_deg`, in the x-z plane at azimuth 0)
    turned about +z by ``180 k / positions`` degrees, ``k = 0 .. positions -
    1``: each (position, fiber) pair is one source, ``positions * n_fibers``
    in all, in that order (position-major). Half a turn suffices, as the
    semicircle spans both sides of the axis; a turn of 180 degrees would map
    the fiber at ``+a`` onto the one at ``-a``. Fibers that would stand in
    the camera's view of its field (:func:`sources_in_view`) are left out,
    and ``metadata["sources_removed_for_camera"]`` counts them (none for the
    defaults: the innermost fibers are 4 degrees off the axis).

    Parameters
    ----------
    positions : int, >= 1
        Azimuths of the semicircle.
    n_fibers, spacing_deg, radius_mm, fiber_diameter_mm
        The semicircle, as in :func:`shiny_1988` (all fibers within 90
        degrees of the axis).
    projection, resolution, field_width_mm, camera_height_mm
        The camera, as in :func:`shiny_1988`.
    """
    positions = int(positions)
    if positions < 1:
        raise OptionError(f"positions must be >= 1, got {positions}")
    if not radius_mm > 0:
        raise OptionError(f"radius_mm must be > 0, got {radius_mm}")
    angles_deg = shiny_1988_source_angles_deg(int(n_fibers), spacing_deg)
    if np.any(np.abs(angles_deg) >= 90):
        raise OptionError(f"{n_fibers} fibers {spacing_deg} degrees apart reach {np.abs(angles_deg).max():g} "
                         "degrees from the axis; they must stay above the horizon (< 90)")
    polar = np.radians(angles_deg)
    azimuths = np.pi * np.arange(positions) / positions
    x = np.sin(polar)[None, :] * np.cos(azimuths)[:, None]
    y = np.sin(polar)[None, :] * np.sin(azimuths)[:, None]
    z = np.broadcast_to(np.cos(polar)[None, :], x.shape)
    dirs = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    camera = _top_camera(projection, resolution, field_width_mm, camera_height_mm)
    pos, radii, hidden = drop_sources_in_view(radius_mm * dirs, 0.5 * fiber_diameter_mm, (camera,), what="fiber")
    meta = {"preset": "rotating_semicircle", "positions": positions, "n_fibers": int(n_fibers),
            "spacing_deg": float(spacing_deg), "azimuths_deg": np.degrees(azimuths).tolist(),
            "source_angles_deg": angles_deg.tolist(), "array_radius_mm": float(radius_mm),
            "n_sources": int((~hidden).sum()), "sources_removed_for_camera": int(hidden.sum())}
    return Rig(source_positions=pos, source_radii=radii, cameras=(camera,), name="rotating_semicircle", metadata=meta)


#: Rim of the dome and ring rigs, degrees from the camera axis, unless a scan says otherwise.
DOME_RIM_DEG = 80.0


def ring_layout(n_sources: int, max_polar_deg: float = DOME_RIM_DEG) -> list[tuple[float, int]]:
    """``(polar_deg, count)`` rings totalling ``n_sources``: ring polar angles evenly spaced, counts by circumference."""
    n_rings = max(1, int(round(math.sqrt(n_sources / math.pi))))
    polar = (np.arange(n_rings) + 1.0) * max_polar_deg / n_rings
    w = np.sin(np.radians(polar))
    counts = np.maximum(1, np.floor(n_sources * w / w.sum())).astype(int)
    counts[-1] += n_sources - counts.sum()
    if counts[-1] < 1:
        raise OptionError(f"{n_sources} sources are too few for {n_rings} rings", field="n_sources")
    return [(float(a), int(c)) for a, c in zip(polar, counts)]


def rings_dome(*, n_sources: int = 200, max_polar_deg: float = DOME_RIM_DEG, **kwargs) -> Rig:
    """A dome of stacked rings (:func:`dome` with ``layout="rings"``), ``n_sources`` in about ``sqrt(n / pi)`` rings
    up to ``max_polar_deg`` (:func:`ring_layout`); other keyword arguments as :func:`dome`'s."""
    return dome(layout="rings", rings=ring_layout(n_sources, max_polar_deg), **kwargs)


#: Working field of the two-camera presets' use in the stereo study: several millimetres, so that
#: objects sit anywhere in it.
STEREO_FIELD_WIDTH_MM = 6.0


def shiny_stereo(*, beta_deg: float = 15.0, projection: str = "perspective", resolution: int = 512,
                 field_width_mm: float = STEREO_FIELD_WIDTH_MM) -> Rig:
    """The paper's 21 fibers (:func:`shiny_1988`) seen by two cameras at +-beta (:func:`stereo_pair`).

    A fiber in a camera's view of the field would hide the object: it is
    left out, as the dome's holes are, and
    ``metadata["sources_removed_for_cameras"]`` lists the fibers taken out.
    """
    base = shiny_1988(projection=projection, resolution=resolution, field_width_mm=field_width_mm)
    rig = stereo_pair(base, beta_deg=beta_deg)
    pos, radii, hidden = drop_sources_in_view(rig.source_positions, rig.source_radii, rig.cameras, what="fiber")
    meta = {**rig.metadata, "sources_removed_for_cameras": np.flatnonzero(hidden).tolist(),
            "source_angles_deg": [a for a, h in zip(rig.metadata["source_angles_deg"], hidden) if not h]}
    return Rig(source_positions=pos, source_radii=radii, cameras=rig.cameras, name=rig.name, metadata=meta)


def _shiny_pair(*, beta_deg: float = 15.0, **kwargs) -> Rig:
    """:func:`stereo_pair` of :func:`shiny_1988` (built with ``kwargs``), every fiber kept."""
    return stereo_pair(shiny_1988(**kwargs), beta_deg=beta_deg)


#: Every rig preset by name: ``RIG_PRESETS[name](**options)`` builds it.
RIG_PRESETS: dict[str, Callable[..., Rig]] = {
    "shiny_1988": shiny_1988,
    "dome": dome,
    "rings": rings_dome,
    "rotating_semicircle": rotating_semicircle,
    "stereo_pair": _shiny_pair,
    "stereo_shiny": shiny_stereo,
    "stereo_dome": stereo_dome,
    "stereo_semicircle": stereo_semicircle,
    "stereo_crossing_arcs": stereo_crossing_arcs,
}

#: The single-camera arrays a scan offers (``shinysim scan --rig``): name -> preset.
SCAN_RIGS = {"dome": "dome", "rings": "rings", "rotating": "rotating_semicircle", "shiny": "shiny_1988"}

#: The two-camera arrays of the stereo study (``shinysim stereo --rig``): name -> preset.
STEREO_RIGS = {"dome": "stereo_dome", "semicircle": "stereo_semicircle", "shiny": "stereo_shiny",
               "crossing_arcs": "stereo_crossing_arcs"}


def rig_preset(name: str, **options) -> Rig:
    """The rig preset ``name`` of :data:`RIG_PRESETS`, built with ``options``.

    >>> rig_preset("shiny_1988", resolution=64).n_sources
    21

    Raises
    ------
    OptionError
        (field ``rig``) an unknown name, with a did-you-mean.
    """
    check_choice("rig", name, tuple(RIG_PRESETS))
    return RIG_PRESETS[name](**options)
