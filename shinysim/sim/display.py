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

For fringe deflectometry, :func:`trace_screen_hits` keeps where each of
those samples meets the screen instead, so that :func:`pattern_frames` gives
the frames of any pattern (a :class:`~shinysim.theory.phase.PhaseCode`'s)
from one trace, and :func:`render_fringe_frames` renders a code's frames,
through a sensor if asked, with the exact screen point each pixel sees
(:func:`screen_fraction_truth`).

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

__all__ = ["DisplayFrame", "FringeFrames", "MAX_SCREEN_HITS", "SOFAST_ALPHA", "ScreenHits", "mask_frames",
           "pattern_frames", "pattern_texture", "render_display_frame", "render_fringe_frames",
           "screen_fraction_truth", "sofast_facet", "sofast_like_setup", "trace_screen_hits"]

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


def _checked_render(setup, spp, seed, alpha, distribution, rows, cols, more=()):
    """The checks every renderer of a :class:`DisplaySetup` makes, and its window: ``(setup, (row0, col0))``,
    the setup's camera cropped to ``rows`` x ``cols``. ``more``: further ``(name, value, lo, hi)`` integers."""
    if not isinstance(setup, DisplaySetup):
        raise OptionError(f"must be a DisplaySetup, got {type(setup).__name__}", field="setup")
    if not setup.display.is_planar:
        raise OptionError("the display's dots are off its plane z = 0; the renderer's screen is flat (use "
                          "Display.flattened())", field="setup.display")
    if not callable(getattr(setup.facet, "triangle_mesh", None)):
        raise OptionError(f"must be a MirrorFacet (something with a triangle_mesh), got "
                          f"{type(setup.facet).__name__}", field="setup.facet")
    for name, value, lo, hi in (("spp", spp, 1, 4096), ("seed", seed, 0, 2**63 - 1), *more):
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
    return setup, (r0, c0)


def _traced_samples(setup, scene, spp, seed):
    """Per pass ``s`` of ``spp``: ``(si2, hit, weight, ray2)``, the camera rays of every pixel (jittered within
    it, stratified: :class:`_Strata`) meeting the facet, one sample of its BSDF each, and where the reflected
    ray ``ray2`` goes (``si2``; ``hit``: a facet point, a sample of non-zero pdf, and ``ray2`` meets a shape).
    Mitsuba values, facet frame, pixels in raster order."""
    import mitsuba as mi

    cam = setup.camera
    H, W = cam.shape
    rr, cc = (a.ravel().astype(float) for a in np.indices((H, W)))
    n = H * W
    rng = np.random.default_rng(seed)
    R = setup.facet_rotation
    ctx = mi.BSDFContext()
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
        ray2 = si.spawn_ray(si.to_world(bs.wo))
        si2 = scene.ray_intersect(ray2, active)
        hit = active & si2.is_valid() & (bs.pdf > 0)
        yield si2, hit, weight, ray2


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
    setup, (r0, c0) = _checked_render(setup, spp, seed, alpha, distribution, rows, cols,
                                      (("texels_per_dot", texels_per_dot, 8, 1000),))
    texel = 2.0 * setup.display.dot_radius_mm / texels_per_dot
    texture = pattern_texture(setup.display, texel)

    def bitmap(mi):
        return {"type": "bitmap", "bitmap": mi.Bitmap(texture[..., None]), "raw": True, "filter_type": "bilinear",
                "wrap_mode": "clamp"}

    scene, mesh, name = _display_scene(setup, variant, alpha, distribution, mesh_tolerance_mm, bitmap,
                                       "render_display_frame")
    import drjit as dr
    H, W = setup.camera.shape
    rr, cc = (a.ravel().astype(float) for a in np.indices((H, W)))
    acc = np.zeros(H * W)
    for si2, hit, weight, _ in _traced_samples(setup, scene, spp, seed):
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


def _display_scene(setup, variant, alpha, distribution, mesh_tolerance_mm, radiance, caller):
    """The Mitsuba scene of a display setup in the facet's frame: the facet's mesh with a rough-conductor BSDF and
    the lit screen, an area emitter of ``radiance(mi)``; also the mesh and the JIT variant used."""
    mesh = setup.facet.triangle_mesh(mesh_tolerance_mm)
    name, reason = choose_variant(variant)
    if not is_vectorized(name):
        raise ShinysimError(f"{caller} needs a JIT (llvm or cuda) Mitsuba variant; {reason}")
    import mitsuba as mi

    scene = load_scene({
        "type": "scene",
        "facet": mesh_object(mesh, bsdf=rough_conductor(float(alpha), distribution=distribution)),
        "screen": {"type": "rectangle", "to_world": _screen_to_world(setup).tolist(),
                   "emitter": {"type": "area", "radiance": radiance(mi)}},
    })
    return scene, mesh, name


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


# -- fringe frames: where each sample meets the screen, and any pattern shown there ----------------------------

#: The most pixel samples :func:`trace_screen_hits` keeps (24 bytes each: a window, or fewer samples, beyond it).
MAX_SCREEN_HITS = 2**26


@dataclass(frozen=True, eq=False)
class ScreenHits:
    """Where every sample of every pixel's reflected ray meets the lit screen (:func:`trace_screen_hits`).

    Attributes
    ----------
    fraction : (H, W, spp, 2) float64
        ``(fx, fy)`` screen fractions of the lit rectangle,
        ``((x - (cx - w/2)) / w, (y - (cy - h/2)) / h)`` of the screen-frame
        point ``(x, y)`` (``(w, h)`` the display's ``size_mm``, ``(cx, cy)``
        its ``centre_mm``); NaN where the sample reaches no lit screen.
    weight : (H, W, spp) float64
        The sample's BSDF weight (its value over its pdf); 0 where
        ``fraction`` is NaN. A pixel's frame of a screen showing radiance
        ``L(fx, fy)`` is the mean over its samples of ``weight * L``.
    setup : DisplaySetup
        The setup traced (a window's camera for a window).
    offset_rc : (row0, col0)
        The window's first pixel in the whole image.
    metadata : dict
        Variant, spp, seed, alpha, distribution, mesh cells and the mesh's
        error bound.
    """

    fraction: np.ndarray
    weight: np.ndarray
    setup: DisplaySetup
    offset_rc: tuple[int, int] = (0, 0)
    metadata: dict = field(default_factory=dict)

    @property
    def coverage(self) -> np.ndarray:
        """(H, W) float: the fraction of each pixel's samples that reach the lit screen."""
        return np.mean(~np.isnan(self.fraction[..., 0]), axis=-1)


def trace_screen_hits(setup: DisplaySetup, *, spp: int = 64, seed: int = 0, alpha: float = SOFAST_ALPHA,
                      rows: slice | None = None, cols: slice | None = None, distribution: str = "beckmann",
                      mesh_tolerance_mm: float = MESH_TOLERANCE_MM, variant: str | None = None) -> ScreenHits:
    """Trace the camera's rays into the mirror and record where each sample meets the lit screen.

    The rays, the facet mesh, the BSDF samples and their stratification
    are :func:`render_display_frame`'s (the same ``seed`` gives the same
    samples); instead of the dot bitmap's radiance, each sample keeps
    where its reflected ray crosses the lit rectangle, in screen fractions,
    and its weight. Any pattern the screen shows is then a mean over these
    samples (:func:`pattern_frames`): every frame of a code from one trace,
    with the same random numbers, and the pattern exact (no texture).

    The crossing is computed in float64 from the ray Mitsuba traced
    (its origin and direction); Mitsuba says whether that ray reaches the
    screen's lit side unblocked.

    Parameters
    ----------
    setup : DisplaySetup
        Its display must be planar, its facet a
        :class:`~shinysim.objects.mirror.MirrorFacet`.
    spp, seed, alpha, rows, cols, distribution, mesh_tolerance_mm, variant
        As in :func:`render_display_frame`. At most
        :data:`MAX_SCREEN_HITS` samples in all (``H W spp``).

    Returns
    -------
    ScreenHits

    Raises
    ------
    OptionError
        Bad options, a non-planar display, a facet that cannot be meshed,
        or more than :data:`MAX_SCREEN_HITS` samples.
    ShinysimError
        Without the renderer or a JIT (llvm or cuda) variant.
    """
    setup, offset = _checked_render(setup, spp, seed, alpha, distribution, rows, cols)
    H, W = setup.camera.shape
    if H * W * spp > MAX_SCREEN_HITS:
        raise OptionError(f"{H} x {W} pixels at {spp} samples are {H * W * spp} screen hits, more than "
                          f"{MAX_SCREEN_HITS}; trace a window (rows=, cols=) or fewer samples", field="spp")
    # the screen an emitter, as the frame's: a camera ray that meets it directly is no facet sample
    scene, mesh, name = _display_scene(setup, variant, alpha, distribution, mesh_tolerance_mm, lambda mi: 1.0,
                                       "trace_screen_hits")
    import drjit as dr
    R, t = setup.screen_to_facet
    w, h = setup.display.size_mm
    x0 = setup.display.centre_mm[0] - 0.5 * w
    y0 = setup.display.centre_mm[1] - 0.5 * h
    n = H * W
    fraction = np.full((n, spp, 2), np.nan)
    weight = np.zeros((n, spp))
    for s, (si2, hit, bsdf_weight, ray2) in enumerate(_traced_samples(setup, scene, spp, seed)):
        on_screen = hit & si2.shape.is_emitter()
        value = dr.select(on_screen, bsdf_weight[0], 0.0)
        dr.eval(on_screen, value, ray2.o, ray2.d)
        ok = np.array(on_screen, dtype=bool)
        o = (np.array(ray2.o, dtype=np.float64).T - t) @ R  # screen frame
        d = np.array(ray2.d, dtype=np.float64).T @ R
        with np.errstate(divide="ignore", invalid="ignore"):
            along = -o[:, 2] / d[:, 2]
            fx = (o[:, 0] + along * d[:, 0] - x0) / w
            fy = (o[:, 1] + along * d[:, 1] - y0) / h
            # the lit side (+z) met from the front, within the rectangle (Mitsuba's float32 test agrees but at
            # its edge)
            ok &= (d[:, 2] < 0) & (along > 0) & (fx >= 0) & (fx <= 1) & (fy >= 0) & (fy <= 1)
        fraction[ok, s, 0] = fx[ok]
        fraction[ok, s, 1] = fy[ok]
        weight[ok, s] = np.array(value, dtype=np.float64)[ok]
    fraction = fraction.reshape(H, W, spp, 2)
    weight = weight.reshape(H, W, spp)
    fraction.setflags(write=False)
    weight.setflags(write=False)
    metadata = {"variant": name, "spp": int(spp), "seed": int(seed), "alpha": float(alpha),
                "distribution": distribution, "mesh_cells": list(mesh.params["cells"]),
                "mesh_error_bound_mm": mesh.params["error_bound_mm"]}
    return ScreenHits(fraction, weight, setup, offset, metadata)


def _level(name, value):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(value) and value >= 0):
        raise OptionError(f"must be a finite radiance >= 0, got {value!r}", field=name)
    return float(value)


def _gamma(value):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(value) and 0.1 <= value <= 10):
        raise OptionError(f"must be a display gamma from 0.1 to 10, got {value!r}", field="gamma")
    return float(value)


def pattern_frames(hits: ScreenHits, pattern, *, on_radiance: float = 1.0, off_radiance: float = 0.0,
                   gamma: float = 1.0) -> np.ndarray:
    """The frames the camera sees while the screen shows a pattern: exact Monte-Carlo means over the samples.

    Frame ``k`` of pixel ``(r, c)`` is the mean over its samples ``s`` of
    ``weight * (off + (on - off) * v_k ** gamma)``, ``v_k`` the pattern's
    displayed value, 0 to 1, where sample ``s`` meets the screen (a sample
    that meets none adds 0). The pattern is evaluated where each sample
    lands: no texture, no discretisation; all frames share the samples.

    Parameters
    ----------
    hits : ScreenHits
    pattern : callable
        ``pattern(fx, fy) -> (n, ...)``: the ``n`` frames' displayed values
        at screen fractions ``fx``, ``fy`` (arrays of one shape ``(...)``),
        e.g. :meth:`shinysim.theory.phase.PhaseCode.intensity`. Values must
        be finite and within [0, 1].
    on_radiance, off_radiance : float
        The screen's radiance at displayed value 1 and 0, >= 0.
    gamma : float
        The display's response ``v ** gamma`` (1: linear), 0.1 to 10.

    Returns
    -------
    (H, W, n) float64
        Linear radiance.

    Raises
    ------
    OptionError
        Not a ScreenHits, a pattern that is not callable or gives values of
        the wrong shape or outside [0, 1], bad levels or gamma.

    Examples
    --------
    A pattern of one frame at 0.5 shows half of :func:`mask_frames`'s light frame:

    >>> hits = ScreenHits(np.full((1, 1, 2, 2), 0.5), np.ones((1, 1, 2)), None)
    >>> pattern_frames(hits, lambda fx, fy: np.full((1,) + fx.shape, 0.5))[..., 0].tolist()
    [[0.5]]
    """
    if not isinstance(hits, ScreenHits):
        raise OptionError(f"must be a ScreenHits (trace_screen_hits), got {type(hits).__name__}", field="hits")
    if not callable(pattern):
        raise OptionError(f"must be a callable pattern(fx, fy) -> (n, ...), got {type(pattern).__name__}",
                          field="pattern")
    on = _level("on_radiance", on_radiance)
    off = _level("off_radiance", off_radiance)
    gamma = _gamma(gamma)
    frac = np.asarray(hits.fraction, dtype=np.float64)
    weight = np.asarray(hits.weight, dtype=np.float64)
    if frac.ndim != 4 or frac.shape[-1] != 2 or weight.shape != frac.shape[:-1]:
        raise OptionError(f"hits must hold (H, W, spp, 2) fractions and (H, W, spp) weights, got {frac.shape} and "
                          f"{weight.shape}", field="hits")
    H, W, spp, _ = frac.shape
    hit = ~np.isnan(frac[..., 0]) & ~np.isnan(frac[..., 1])
    fx = np.where(hit, frac[..., 0], 0.5)  # the pattern sees finite places only; a miss weighs 0
    fy = np.where(hit, frac[..., 1], 0.5)
    w = np.where(hit, weight, 0.0)
    acc = None
    step = max(1, 2**18 // max(1, H * W))  # samples per call: the pattern's values stay ~n * 2 MiB
    for s0 in range(0, spp, step):
        s1 = min(spp, s0 + step)
        v = pattern(fx[:, :, s0:s1], fy[:, :, s0:s1])
        try:
            v = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise OptionError("must return an array of numbers", field="pattern") from None
        if v.ndim != 4 or v.shape[1:] != (H, W, s1 - s0):
            raise OptionError(f"must return (n, ...) values for fractions of shape {(H, W, s1 - s0)}, got shape "
                              f"{v.shape}", field="pattern")
        if acc is None:
            acc = np.zeros((v.shape[0], H, W))
        elif v.shape[0] != acc.shape[0]:
            raise OptionError(f"returned {v.shape[0]} frames after {acc.shape[0]}", field="pattern")
        used = v[:, hit[:, :, s0:s1]]
        if not np.all(np.isfinite(used)) or np.any(used < 0) or np.any(used > 1):
            raise OptionError("must give displayed values within [0, 1] (finite)", field="pattern")
        if gamma != 1.0:
            v = v**gamma
        acc += np.sum(w[None, :, :, s0:s1] * (off + (on - off) * v), axis=-1)
    return np.moveaxis(acc / spp, 0, -1)


def mask_frames(hits: ScreenHits, *, on_radiance: float = 1.0, off_radiance: float = 0.0
                ) -> tuple[np.ndarray, np.ndarray]:
    """The frames of the screen all off and all on (a fringe measurement's mask images).

    Parameters
    ----------
    hits : ScreenHits
    on_radiance, off_radiance : float
        The screen's radiance at displayed value 1 and 0, >= 0.

    Returns
    -------
    dark, light : (H, W) float64
        ``off`` and ``on`` times each pixel's mean sample weight: what
        :func:`pattern_frames` gives for a pattern of 0 and of 1 (any gamma).
    """
    if not isinstance(hits, ScreenHits):
        raise OptionError(f"must be a ScreenHits (trace_screen_hits), got {type(hits).__name__}", field="hits")
    on = _level("on_radiance", on_radiance)
    off = _level("off_radiance", off_radiance)
    mean = np.mean(np.where(np.isnan(hits.fraction[..., 0]), 0.0, hits.weight), axis=-1)
    return off * mean, on * mean


def screen_fraction_truth(setup: DisplaySetup, row, col) -> tuple[np.ndarray, np.ndarray]:
    """Where the rays through pixel positions see the lit screen after a perfect reflection in the exact facet.

    Each ray meets the exact facet (:meth:`~shinysim.rig.display.DisplaySetup.trace_pixels`),
    reflects about the exact normal there and crosses the screen's plane;
    the crossing is given in screen fractions (:class:`ScreenHits`).

    Parameters
    ----------
    setup : DisplaySetup
    row, col : array_like
        Continuous pixel positions (centres at integers), one shape ``(...)``.

    Returns
    -------
    fraction : (..., 2) float64
        ``(fx, fy)``; NaN off the facet, or where the reflected ray meets
        no lit screen from its front.
    points_mm : (..., 3) float64, millimetres
        The facet point, facet frame; NaN off the facet.
    """
    if not isinstance(setup, DisplaySetup):
        raise OptionError(f"must be a DisplaySetup, got {type(setup).__name__}", field="setup")
    points, hit = setup.trace_pixels(row, col)
    _, d = setup.camera.pixel_rays(row, col)
    d = d @ setup.facet_rotation
    with np.errstate(invalid="ignore", divide="ignore"):
        n = setup.facet.normal(points[..., 0], points[..., 1])
        r = d - 2.0 * np.sum(d * n, axis=-1, keepdims=True) * n
        R, t = setup.screen_to_facet
        o = (points - t) @ R
        v = r @ R
        along = -o[..., 2] / v[..., 2]
        w, h = setup.display.size_mm
        fx = (o[..., 0] + along * v[..., 0] - (setup.display.centre_mm[0] - 0.5 * w)) / w
        fy = (o[..., 1] + along * v[..., 1] - (setup.display.centre_mm[1] - 0.5 * h)) / h
        ok = hit & (v[..., 2] < 0) & (along > 0) & (fx >= 0) & (fx <= 1) & (fy >= 0) & (fy <= 1)
    fraction = np.where(ok[..., None], np.stack([fx, fy], axis=-1), np.nan)
    return fraction, points


@dataclass(frozen=True, eq=False)
class FringeFrames:
    """A phase code's frames of a display seen in a mirror, with the mask frames and the exact truth
    (:func:`render_fringe_frames`).

    Attributes
    ----------
    frames : (H, W, n_frames) float
        In the code's frame order: linear radiance (float64), or the
        sensor's frames (float32 digital numbers over ``2**bits - 1``,
        :meth:`~shinysim.sim.sensor.Sensor.capture`).
    dark, light : (H, W) float
        The screen all off and all on, likewise.
    coverage : (H, W) float
        The fraction of each pixel's samples that reach the lit screen
        (below 1 at the facet's edge: a pixel that sees it only in part).
    truth_fraction : (H, W, 2) float64
        ``(fx, fy)`` where each pixel centre's ray sees the screen after a
        perfect reflection in the exact facet (:func:`screen_fraction_truth`);
        NaN off the facet or off the lit screen.
    truth_points_mm : (H, W, 3) float64, millimetres
        The facet point each pixel centre sees, facet frame; NaN off it.
    truth_slopes : (H, W, 2) float64
        The facet's exact slopes there.
    setup : DisplaySetup
        The setup rendered (a window's camera for a window).
    offset_rc : (row0, col0)
        The window's first pixel in the whole image.
    metadata : dict
        The trace's (:class:`ScreenHits`), the code, gamma, the display's
        levels and the sensor (its fields with the exposure used, and its
        seed; None for radiance).
    """

    frames: np.ndarray
    dark: np.ndarray
    light: np.ndarray
    coverage: np.ndarray
    truth_fraction: np.ndarray
    truth_points_mm: np.ndarray
    truth_slopes: np.ndarray
    setup: DisplaySetup
    offset_rc: tuple[int, int] = (0, 0)
    metadata: dict = field(default_factory=dict)


def render_fringe_frames(setup: DisplaySetup, code, *, spp: int = 64, seed: int = 0, alpha: float = SOFAST_ALPHA,
                         rows: slice | None = None, cols: slice | None = None, gamma: float = 1.0, sensor=None,
                         exposure: float = 0.8, sensor_seed: int = 0, distribution: str = "beckmann",
                         mesh_tolerance_mm: float = MESH_TOLERANCE_MM, variant: str | None = None) -> FringeFrames:
    """Render every frame of a phase code shown on the display and seen in the mirror, with the exact truth.

    One trace (:func:`trace_screen_hits`) gives all frames
    (:func:`pattern_frames` of ``code.intensity``, the display's
    ``on_radiance`` and ``off_radiance`` at displayed values 1 and 0, its
    response ``v ** gamma``) and the mask frames (:func:`mask_frames`).
    With a sensor, all of them are captured at one exposure, the light
    frame's brightest pixel at ``exposure`` of the full well
    (:meth:`~shinysim.sim.sensor.Sensor.exposed_for`), each frame with its
    own noise (frame ``k`` of the code's, then the dark and the light
    frame, from ``default_rng([sensor_seed, k])``). A window is captured
    as that part of the whole image: its vignetting and gain pattern (PRNU)
    are the whole image's there; its hot pixels are drawn for the window.

    Parameters
    ----------
    setup : DisplaySetup
    code : shinysim.theory.phase.PhaseCode
    spp, seed, alpha, rows, cols, distribution, mesh_tolerance_mm, variant
        As in :func:`trace_screen_hits`.
    gamma : float
        The display's response, 0.1 to 10 (1: linear).
    sensor : Sensor or str, optional
        A :class:`~shinysim.sim.sensor.Sensor` or a preset's name
        (:data:`~shinysim.sim.sensor.SENSOR_PRESETS`; ``"ideal"`` or None:
        radiance).
    exposure : float
        The light frame's brightest pixel as a fraction of the full well,
        in (0, 100].
    sensor_seed : int
        The sensor's noise seed, >= 0.

    Returns
    -------
    FringeFrames

    Raises
    ------
    OptionError
        Bad options (as :func:`trace_screen_hits`; a code that is not a
        PhaseCode; an unknown sensor), or a window that sees no lit screen
        to expose a sensor for.
    ShinysimError
        Without the renderer or a JIT (llvm or cuda) variant.
    """
    from ..theory.phase import PhaseCode
    from .sensor import Sensor, sensor_preset

    if not isinstance(setup, DisplaySetup):
        raise OptionError(f"must be a DisplaySetup, got {type(setup).__name__}", field="setup")
    on, off = setup.display.on_radiance, setup.display.off_radiance
    if not isinstance(code, PhaseCode):
        raise OptionError(f"must be a PhaseCode, got {type(code).__name__}", field="code")
    gamma = _gamma(gamma)
    if isinstance(sensor, str):
        sensor = sensor_preset(sensor)
    elif sensor is not None and not isinstance(sensor, Sensor):
        raise OptionError(f"must be a Sensor, a preset's name or None, got {type(sensor).__name__}", field="sensor")
    if sensor is not None:
        if isinstance(sensor_seed, (bool, np.bool_)) or not isinstance(sensor_seed, (int, np.integer)) \
                or sensor_seed < 0:
            raise OptionError(f"must be an integer >= 0, got {sensor_seed!r}", field="sensor_seed")
        if isinstance(exposure, (bool, np.bool_)) or not isinstance(exposure, (int, float, np.integer, np.floating)) \
                or not (math.isfinite(exposure) and 0 < exposure <= 100):
            raise OptionError(f"must be a fraction of the full well in (0, 100], got {exposure!r}", field="exposure")
    hits = trace_screen_hits(setup, spp=spp, seed=seed, alpha=alpha, rows=rows, cols=cols,
                             distribution=distribution, mesh_tolerance_mm=mesh_tolerance_mm, variant=variant)
    frames = pattern_frames(hits, code.intensity, on_radiance=on, off_radiance=off, gamma=gamma)
    dark, light = mask_frames(hits, on_radiance=on, off_radiance=off)
    sensor_meta = None
    if sensor is not None:
        if not light.max() > 0:
            raise OptionError("the window sees no lit screen in the mirror: no light to expose the sensor for",
                              field="sensor")
        exposed = sensor.exposed_for(float(light.max()), exposure)
        stack = np.concatenate([np.moveaxis(frames, -1, 0), dark[None], light[None]])
        capturing = exposed
        if hits.setup.camera.shape != setup.camera.shape:
            # a window sees the whole image's vignetting and gain pattern there, not its own about its centre
            (r0, c0), (H, W) = hits.offset_rc, hits.setup.camera.shape
            full = setup.camera.shape
            stack = stack * (exposed.vignette(full) * exposed.prnu_map(full))[r0:r0 + H, c0:c0 + W]
            capturing = replace(exposed, vignetting=0.0, prnu=0.0)
        captured = capturing.capture(stack, seed=int(sensor_seed))
        frames = np.moveaxis(captured[:-2], 0, -1)
        dark, light = captured[-2], captured[-1]
        sensor_meta = {**exposed.to_dict(), "seed": int(sensor_seed), "exposure_fraction": float(exposure)}
    setup = hits.setup
    H, W = setup.camera.shape
    rr, cc = np.indices((H, W)).astype(float)
    truth, points = screen_fraction_truth(setup, rr, cc)
    slopes = setup.facet.slopes(points[..., 0], points[..., 1])
    coverage = hits.coverage
    frames = np.ascontiguousarray(frames)
    for a in (frames, dark, light, coverage, truth, points, slopes):
        a.setflags(write=False)
    metadata = {**hits.metadata, "code": {"periods_x": list(code.periods_x), "periods_y": list(code.periods_y),
                                          "shifts": code.shifts},
                "gamma": gamma, "on_radiance": on, "off_radiance": off, "sensor": sensor_meta}
    return FringeFrames(frames, dark, light, coverage, truth, points, slopes, setup, hits.offset_rc, metadata)
