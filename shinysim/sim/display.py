"""The simulated twin of a display-deflectometry rig: a dot screen seen in a mirror facet, with exact truth.

:func:`sofast_like_setup` places a facet as SOFAST's fixed-pattern
measurement has it (the camera, screen and dots given, the facet at the real
facet's place facing the bisector); :func:`render_display_frame` renders
the frame the camera sees, with Mitsuba 3 tracing the rays (the screen a
``rectangle`` whose ``area`` emitter shows the dot pattern as a bitmap, the
facet a triangle mesh of its exact surface with a rough-conductor BSDF) and
numpy making them (the package's own camera model, jittered within each
pixel: the lens distortion is the :class:`~shinysim.rig.Camera`'s). The
frame comes with its exact truth: the facet point and slopes each pixel
centre sees, and where every dot centre's reflection images
(:meth:`~shinysim.rig.display.DisplaySetup.reflected_dots`).

The scene is built in the facet's frame (the mirror near the origin, where
float32 is finest), in millimetres. Mitsuba is imported when a frame is
rendered.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import OptionError, ShinysimError
from ..objects.mirror import MESH_TOLERANCE_MM, MirrorFacet
from ..rig import Camera
from ..rig.display import (SOFAST_DOT_RADIUS_MM, SOFAST_FACET_CENTRE_MM, Display, DisplaySetup, ReflectedDots,
                           crop_camera, facet_pose)
from .meshes import mesh_object
from .scene import DISTRIBUTIONS, load_scene, rough_conductor
from .variants import choose_variant, is_vectorized

__all__ = ["DisplayFrame", "SOFAST_ALPHA", "pattern_texture", "render_display_frame", "sofast_facet",
           "sofast_like_setup"]

#: The roughness that blurs the twin's dots as the real frame's are blurred. A real dot is 54 % as deep as the
#: background around it and its darkness has a second moment of 1.79 px per axis; a 3.67 px disc blurred by a
#: Gaussian of 1.5 px gives both. A Beckmann surface of roughness alpha tilts the reflected ray by sqrt(2) alpha
#: (rms per axis), which at the screen 10.0 m away and 3.68 mm per pixel is 1.5 px for alpha = 3.9e-4.
SOFAST_ALPHA = 4e-4


def sofast_facet() -> MirrorFacet:
    """The twin's NSTTF facet: 1.212 m square, SOFAST's fitted focal lengths, and a known ripple.

    Returns
    -------
    MirrorFacet
        Half sides 606 mm; focal lengths (-136, -146) m as SOFAST reports
        them (the surface falls away from the camera); a ripple of 0.02 mm,
        period 400 mm, at 0.5 rad (0.3 mrad of slope: what a measurement of
        the twin should find beyond the paraboloid).
    """
    return MirrorFacet(606.0, 606.0, focal_mm=(-136e3, -146e3), ripple_mm=0.02, ripple_period_mm=400.0,
                       ripple_angle_rad=0.5)


def sofast_like_setup(camera: Camera, screen_rotation, screen_origin_mm, dots_mm, x_index, y_index, *,
                      facet: MirrorFacet | None = None, facet_centre_mm=SOFAST_FACET_CENTRE_MM,
                      dot_radius_mm: float = SOFAST_DOT_RADIUS_MM, polarity: str = "dark",
                      on_radiance: float = 1.0, off_radiance: float = 0.0) -> DisplaySetup:
    """A display-deflectometry rig placed as SOFAST's fixed-pattern measurement is.

    Parameters
    ----------
    camera : Camera
        In its own frame (``camera_from_opencv`` without a pose).
    screen_rotation : (3, 3) array_like
    screen_origin_mm : (3,) array_like, millimetres
        ``x_cam = screen_origin_mm + screen_rotation @ p_screen``: SOFAST's
        ``R(r_cam_screen)^-1`` and ``v_cam_screen_cam`` in mm.
    dots_mm : (ny, nx, 3) array_like, millimetres
        Dot centres in the screen frame (SOFAST's ``xyz_dot_loc`` in mm;
        NaN: a dot whose place is unknown, not shown). The twin's screen is
        the flat plane z = 0: each dot is put there at its (x, y) (the
        measured ones are off it by up to 4 mm).
    x_index, y_index : (nx,), (ny,) int
    facet : MirrorFacet, optional
        Default :func:`sofast_facet`.
    facet_centre_mm : (3,) array_like, millimetres
        Where the facet's centre is in the camera frame (default the real
        facet's, :data:`~shinysim.rig.display.SOFAST_FACET_CENTRE_MM`). The facet faces the
        bisector of the directions from there to the camera and to the
        screen's origin, its +x as near the camera's +x as that allows
        (:func:`shinysim.rig.display.facet_pose`).
    dot_radius_mm, polarity, on_radiance, off_radiance
        As in :class:`~shinysim.rig.display.Display`; the default radius
        is :data:`~shinysim.rig.display.SOFAST_DOT_RADIUS_MM`.

    Returns
    -------
    DisplaySetup
    """
    if not isinstance(camera, Camera):
        raise OptionError(f"must be a Camera, got {type(camera).__name__}", field="camera")
    display = Display(dots_mm, x_index, y_index, dot_radius_mm=dot_radius_mm, polarity=polarity,
                      on_radiance=on_radiance, off_radiance=off_radiance).flattened()
    facet = sofast_facet() if facet is None else facet
    rotation, origin = facet_pose(camera.position, screen_origin_mm, facet_centre_mm, camera.right)
    return DisplaySetup(display, camera, screen_rotation, screen_origin_mm, facet, rotation, origin)


def pattern_texture(display: Display, texel_mm: float) -> np.ndarray:
    """The display's lit rectangle as an image: row ``j``, column ``i`` at screen
    ``(x0 + (i + 1/2) w / W, y0 + (j + 1/2) h / H)`` (``x0, y0`` its lower-left corner).

    Each texel holds the dot pattern's mean over it: a dot's coverage ramps
    linearly across one texel at its edge (``clip((R - d) / texel + 1/2, 0, 1)``
    of the distance ``d`` to the centre), which keeps each dot's centroid on
    its centre.

    Parameters
    ----------
    display : Display
    texel_mm : float, millimetres
        The largest texel side; the rectangle is divided into whole texels.

    Returns
    -------
    (H, W) float32
    """
    w, h = display.size_mm
    W = max(1, math.ceil(w / texel_mm))
    H = max(1, math.ceil(h / texel_mm))
    if W * H > 2**26:
        raise OptionError(f"a {W} x {H} texture of the display is more than 2**26 texels; give a coarser texel",
                          field="texel_mm")
    tx, ty = w / W, h / H
    ramp = max(tx, ty)
    x0 = display.centre_mm[0] - 0.5 * w
    y0 = display.centre_mm[1] - 0.5 * h
    R = display.dot_radius_mm
    centres = display.dots_mm[display.shown][:, :2]
    k = math.ceil((R + ramp) / min(tx, ty)) + 1
    off = np.arange(-k, k + 1)
    ci = np.floor((centres[:, 0] - x0) / tx).astype(np.int64)
    cj = np.floor((centres[:, 1] - y0) / ty).astype(np.int64)
    ii = ci[:, None, None] + off[None, None, :]
    jj = cj[:, None, None] + off[None, :, None]
    ii, jj = np.broadcast_arrays(ii, jj)
    d = np.hypot(x0 + (ii + 0.5) * tx - centres[:, 0, None, None], y0 + (jj + 0.5) * ty - centres[:, 1, None, None])
    cover = np.clip((R - d) / ramp + 0.5, 0.0, 1.0)
    keep = (cover > 0) & (ii >= 0) & (ii < W) & (jj >= 0) & (jj < H)
    coverage = np.zeros((H, W))
    np.maximum.at(coverage, (jj[keep], ii[keep]), cover[keep])  # dots do not overlap: no texel holds two
    on, off_level = display.on_radiance, display.off_radiance
    if display.polarity == "dark":
        tex = on - (on - off_level) * coverage
    else:
        tex = off_level + (on - off_level) * coverage
    return tex.astype(np.float32)


@dataclass(frozen=True, eq=False)
class DisplayFrame:
    """One rendered frame of a display seen in a mirror, with its exact truth (:func:`render_display_frame`).

    Attributes
    ----------
    image : (H, W) float32
        Linear radiance (the screen's levels times the mirror's reflectance
        of 1); 0 where a pixel sees no reflected screen.
    truth_points_mm : (H, W, 3) float, millimetres
        Where each pixel centre's ray meets the exact facet, facet frame;
        NaN off the facet.
    truth_slopes : (H, W, 2) float
        The facet's exact slopes there.
    origin_rc : (row, col)
        The exact image position of dot index (0, 0)'s reflection (NaN if
        it is not reflected or the display has no such dot).
    reflected : ReflectedDots
        Every dot's (:meth:`~shinysim.rig.display.DisplaySetup.reflected_dots`).
    setup : DisplaySetup
        The setup rendered: for a window, its camera is the window's
        (:func:`~shinysim.rig.display.crop_camera`), and every position
        above is in the window's pixels.
    offset_rc : (row0, col0)
        The window's first pixel in the whole image ((0, 0) for all of it).
    metadata : dict
        How it was made: variant, spp, seed, alpha, distribution, texel,
        mesh cells and the mesh's error bound.
    """

    image: np.ndarray
    truth_points_mm: np.ndarray
    truth_slopes: np.ndarray
    origin_rc: tuple[float, float]
    reflected: ReflectedDots
    setup: DisplaySetup
    offset_rc: tuple[int, int] = (0, 0)
    metadata: dict = field(default_factory=dict)


class _Strata:
    """Stratified random numbers for ``spp`` samples of ``n`` pixels: the pixel jitter and the BSDF's 2D sample
    each from a ``k1 x k2`` grid of strata (``k1 k2 = spp``, ``k1`` the largest divisor up to ``sqrt(spp)``), every
    stratum once per pixel (sample ``s`` takes stratum ``(order[s] + shift) mod spp``, a random order per pair
    and a random shift per pixel and pair), at a uniform place inside it. Each number is uniform on [0, 1): the
    frame is unbiased; a dot's edge, sampled evenly, is less noisy than with independent samples."""

    def __init__(self, rng, n, spp):
        self.rng, self.n, self.spp = rng, n, spp
        self.k1 = max(k for k in range(1, math.isqrt(spp) + 1) if spp % k == 0)
        self.k2 = spp // self.k1
        self.order = [rng.permutation(spp), rng.permutation(spp)]
        self.shift = rng.integers(0, spp, size=(2, n))

    def sample(self, s):
        """(5, n): jitter (x, y), the BSDF's 1D sample, its 2D sample (x, y)."""
        u = self.rng.random((5, self.n))
        for pair, (ix, iy) in enumerate(((0, 1), (3, 4))):
            cell = (self.order[pair][s] + self.shift[pair]) % self.spp
            u[ix] = (cell % self.k2 + u[ix]) / self.k2
            u[iy] = (cell // self.k2 + u[iy]) / self.k1
        return u


def _window(name, value, n):
    if value is None:
        return 0, n
    if not isinstance(value, slice) or value.step not in (None, 1):
        raise OptionError(f"must be a slice with step 1 (or None for all), got {value!r}", field=name)
    start, stop, _ = value.indices(n)
    if stop <= start:
        raise OptionError(f"{value!r} selects no {name[:-1]} of the {n}", field=name)
    return start, stop


def render_display_frame(setup: DisplaySetup, *, spp: int = 16, seed: int = 0, alpha: float = SOFAST_ALPHA,
                         rows: slice | None = None, cols: slice | None = None, distribution: str = "beckmann",
                         texels_per_dot: int = 10, mesh_tolerance_mm: float = MESH_TOLERANCE_MM,
                         variant: str | None = None) -> DisplayFrame:
    """Render the frame the camera sees of the display in the mirror, with its exact truth.

    Each of ``spp`` passes traces one ray per pixel, jittered uniformly
    within the pixel (a seeded numpy generator; box filter), through the
    camera's own model (:meth:`~shinysim.rig.Camera.pixel_rays`, lens
    distortion included). Where it meets the facet, one sample of its BSDF
    (Mitsuba's ``bsdf.sample``, the random numbers numpy's too) gives the
    reflected ray; if that meets the screen, the pixel gains the sample's
    weight times the screen's radiance there (``emitter.eval``). A ray that
    sees the screen directly, or nothing, adds nothing.

    Parameters
    ----------
    setup : DisplaySetup
        Its display must be planar (:meth:`Display.flattened`), its facet a
        :class:`~shinysim.objects.mirror.MirrorFacet`.
    spp : int
        Samples per pixel, 1 to 4096.
    seed : int
        The numpy generator's seed (the same frame for the same seed).
    alpha : float
        The facet's microfacet roughness, > 0 (default :data:`SOFAST_ALPHA`,
        which blurs the dots as much as the real frame's are).
    rows, cols : slice, optional
        Render only this window of the image (all of it by default).
    distribution : {"beckmann", "ggx"}
        The microfacet distribution (Beckmann's is Gaussian in slope: the
        blur of a polished mirror).
    texels_per_dot : int
        Texels across a dot's diameter in the screen's bitmap, >= 8.
    mesh_tolerance_mm : float
        The facet mesh's bound on its distance from the exact surface
        (:meth:`~shinysim.objects.mirror.MirrorFacet.triangle_mesh`).
    variant : str, optional
        A JIT Mitsuba variant (default the fastest, :func:`~shinysim.sim.variants.choose_variant`).

    Returns
    -------
    DisplayFrame

    Raises
    ------
    OptionError
        Bad options, a non-planar display or a facet that cannot be meshed.
    ShinysimError
        Without the renderer or a JIT (llvm or cuda) variant.
    """
    if not isinstance(setup, DisplaySetup):
        raise OptionError(f"must be a DisplaySetup, got {type(setup).__name__}", field="setup")
    if not setup.display.is_planar:
        raise OptionError("the display's dots are off its plane z = 0; the renderer's screen is flat (use "
                          "Display.flattened())", field="setup.display")
    if not callable(getattr(setup.facet, "triangle_mesh", None)):
        raise OptionError(f"must be a MirrorFacet (something with a triangle_mesh), got "
                          f"{type(setup.facet).__name__}", field="setup.facet")
    for name, value, lo, hi in (("spp", spp, 1, 4096), ("seed", seed, 0, 2**63 - 1),
                                ("texels_per_dot", texels_per_dot, 8, 1000)):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
            raise OptionError(f"must be an integer from {lo} to {hi}, got {value!r}", field=name)
    if isinstance(alpha, (bool, np.bool_)) or not isinstance(alpha, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(alpha) and alpha > 0):
        raise OptionError(f"must be a finite roughness > 0, got {alpha!r}", field="alpha")
    if distribution not in DISTRIBUTIONS:
        raise OptionError(f"must be one of {', '.join(map(repr, DISTRIBUTIONS))}, got {distribution!r}",
                          field="distribution")
    H0, W0 = setup.camera.shape
    r0, r1 = _window("rows", rows, H0)
    c0, c1 = _window("cols", cols, W0)
    if (r0, r1, c0, c1) != (0, H0, 0, W0):
        setup = replace(setup, camera=crop_camera(setup.camera, r0, c0, r1 - r0, c1 - c0))
    mesh = setup.facet.triangle_mesh(mesh_tolerance_mm)
    texel = 2.0 * setup.display.dot_radius_mm / texels_per_dot
    texture = pattern_texture(setup.display, texel)

    name, reason = choose_variant(variant)
    if not is_vectorized(name):
        raise ShinysimError(f"render_display_frame needs a JIT (llvm or cuda) Mitsuba variant; {reason}")
    import drjit as dr
    import mitsuba as mi

    scene = load_scene({
        "type": "scene",
        "facet": mesh_object(mesh, bsdf=rough_conductor(float(alpha), distribution=distribution)),
        "screen": {"type": "rectangle", "to_world": _screen_to_world(setup).tolist(),
                   "emitter": {"type": "area", "radiance": {
                       "type": "bitmap", "bitmap": mi.Bitmap(texture[..., None]), "raw": True,
                       "filter_type": "bilinear", "wrap_mode": "clamp"}}},
    })
    cam = setup.camera
    H, W = cam.shape
    rr, cc = (a.ravel().astype(float) for a in np.indices((H, W)))
    n = H * W
    rng = np.random.default_rng(seed)
    R = setup.facet_rotation
    ctx = mi.BSDFContext()
    acc = np.zeros(n)
    strata = _Strata(rng, n, spp)
    for s in range(spp):
        u = strata.sample(s)
        o, d = cam.pixel_rays(rr + u[0] - 0.5, cc + u[1] - 0.5)
        o = setup.camera_to_facet(o)
        d = d @ R
        ray = mi.Ray3f(mi.Point3f(*(o.T.astype(np.float32))), mi.Vector3f(*(d.T.astype(np.float32))))
        si = scene.ray_intersect(ray)
        active = si.is_valid() & ~si.shape.is_emitter()
        bsdf = si.bsdf(ray)
        bs, weight = bsdf.sample(ctx, si, mi.Float(u[2].astype(np.float32)),
                                 mi.Point2f(u[3].astype(np.float32), u[4].astype(np.float32)), active)
        si2 = scene.ray_intersect(si.spawn_ray(si.to_world(bs.wo)), active)
        hit = active & si2.is_valid() & (bs.pdf > 0)
        emitter = si2.emitter(scene, hit)
        value = dr.select(hit, weight[0] * emitter.eval(si2, hit)[0], 0.0)
        acc += np.array(value, dtype=np.float64)
    image = (acc / spp).reshape(H, W).astype(np.float32)

    points, hit = setup.trace_pixels(rr.reshape(H, W), cc.reshape(H, W))
    slopes = setup.facet.slopes(points[..., 0], points[..., 1])
    reflected = setup.reflected_dots()
    has_origin = np.any(setup.display.x_index == 0) and np.any(setup.display.y_index == 0)
    origin = reflected.at(0, 0) if has_origin else (math.nan, math.nan)
    cells = mesh.params["cells"]
    metadata = {"variant": name, "spp": int(spp), "seed": int(seed), "alpha": float(alpha),
                "distribution": distribution, "texel_mm": texel, "texture_shape": list(texture.shape),
                "mesh_cells": list(cells), "mesh_error_bound_mm": mesh.params["error_bound_mm"]}
    for a in (image, points, slopes):
        a.setflags(write=False)
    return DisplayFrame(image, points, slopes, origin, reflected, setup, (r0, c0), metadata)


def _screen_to_world(setup: DisplaySetup) -> np.ndarray:
    """(4, 4) the Mitsuba ``rectangle`` (local [-1, 1]^2, emitting towards local +z) onto the lit screen, in the
    facet frame; local (u, v) is screen ``(cx + u w / 2, cy + v h / 2)``, the texture's column and row order.

    The screen emits from its +z side, which must face the facet."""
    R, t = setup.screen_to_facet
    w, h = setup.display.size_mm
    cx, cy = setup.display.centre_mm
    centre = R @ np.array([cx, cy, 0.0]) + t
    if not float(R[:, 2] @ -centre) > 0:
        raise OptionError("the screen's +z side (the side it shows its dots on) faces away from the facet",
                          field="setup.screen_rotation")
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = 0.5 * w * R[:, 0], 0.5 * h * R[:, 1], R[:, 2], centre
    return m
