"""Rendering per-source highlight stacks and ground truth with Mitsuba 3.

:class:`Simulator` loads a rig's scene once and renders from it repeatedly:
:meth:`Simulator.render_stack` (``method="one-pass"``: every source from one
wavefront of lanes on JIT variants, direct light or a bounded ``path``;
``"per-source"``: ``mi.render`` once per source, the reference),
:meth:`Simulator.render_stack_and_direct`, :meth:`Simulator.render_truth`
(pixel-centre normals, points and parts), :meth:`Simulator.render_emission`
and, in an RGB variant (``colour=True``), :meth:`Simulator.render_colour_stack`.
Pixels are box-filtered averages, pixel centres at integers. How the
methods sample, and what they guarantee: ``docs/rendering.md``.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence

import numpy as np

from .. import __version__
from .._shared import check_number, derive_seed
from ..errors import OptionError
from ..io import Stack, Truth
from ..rig import Rig
from .scene import load_scene, scene_dict
from .variants import active_variant, choose_variant, is_vectorized

__all__ = ["RENDER_METHODS", "Simulator"]

#: How :meth:`Simulator.render_stack` renders.
RENDER_METHODS = ("one-pass", "uniform", "per-source")
#: Least expected samples per (source, pixel) pair of the one-pass renderer for direct light: every pair keeps a
#: chance (the stack stays unbiased), at a weight of at most 64 per sample.
DIRECT_FLOOR = 1.0 / 64
#: The same for paths with inter-reflections: one sample per pair, so that no sample weighs more than one. A
#: floor-sampled pixel weighted 64 that draws a rare bright path (light off the solder into a caustic on the
#: pad) becomes a speck that relative thresholds and multi-highlight detection on joints are sensitive to; at
#: this floor the solder study's figures match per-source paths (docs/rendering.md).
PATH_FLOOR = 1.0


def _in_own_variant(method):
    """Run a Simulator method in the Simulator's Mitsuba variant, the active one put back afterwards."""

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        if self._mi.variant() == self.variant:
            return method(self, *args, **kwargs)
        with self._mi.variant_context(self.variant):
            return method(self, *args, **kwargs)

    return wrapper


def _power_heuristic(dr, pdf, other):
    """The MIS power heuristic (exponent 2) of a sample drawn with ``pdf`` against ``other``."""
    return dr.square(pdf) / (dr.square(pdf) + dr.square(other))


def _window_max(a, w, axis):
    """The maximum over every run of ``w`` consecutive entries along ``axis`` (the axis shrinks by ``w - 1``):
    windows of twice the span from two of the span (a few whole-array maxima, not ``w``)."""
    def cut(x, lo, hi):
        sl = [slice(None)] * x.ndim
        sl[axis] = slice(lo, x.shape[axis] - hi)
        return x[tuple(sl)]

    cur, span = a, 1
    while 2 * span <= w:
        cur = np.maximum(cut(cur, 0, span), cut(cur, span, 0))
        span *= 2
    if span < w:  # two windows of the span, w - span apart, cover w
        cur = np.maximum(cut(cur, 0, w - span), cut(cur, w - span, 0))
    return cur


class Simulator:
    """A rig's scene, loaded once, rendered many times.

    Parameters
    ----------
    rig : shinysim.rig.Rig
    objects : dict of str -> Mitsuba shape dict
        Named object shapes, e.g. :func:`shinysim.sim.scene.sphere_object`.
    camera_index : int
    variant : str, optional
        Force a Mitsuba variant (default: fastest available, see
        :func:`shinysim.sim.variants.choose_variant`).
    radiance : float
        Emitted radiance of each source.
    integrator : dict, optional
        Mitsuba integrator for the per-source renderer (default ``direct``,
        one bounce: exact for a convex mirror). For inter-reflections (e.g.
        solder joints) pass ``{"type": "path", "max_depth": 3}``; the
        one-pass renderer traces it too (a finite ``max_depth``), in grey.
    colour : bool
        Render in colour: an RGB variant (``variant``, if given, must be
        one), :meth:`render_colour_stack` for linear-RGB stacks. The
        process's active Mitsuba variant is left as it was (if none was
        active, the one a mono Simulator picks is activated).
    """

    def __init__(self, rig: Rig, objects: dict[str, dict], *, camera_index: int = 0, variant: str | None = None,
                 radiance: float = 1.0, integrator: dict | None = None, colour: bool = False) -> None:
        if not isinstance(colour, (bool, np.bool_)):
            raise OptionError(f"colour must be True or False, got {colour!r}")
        self.colour = bool(colour)
        previous = active_variant()
        try:
            self._init(rig, objects, camera_index, variant, radiance, integrator)
        finally:  # a colour Simulator puts the active variant back (none was active: the one a mono one picks)
            if self.colour and previous is None and active_variant() is not None:
                choose_variant()
            elif self.colour and active_variant() != previous:
                import mitsuba as mi

                mi.set_variant(previous)

    def _init(self, rig, objects, camera_index, variant, radiance, integrator):
        self.variant, self.variant_reason = choose_variant(variant, colour=self.colour)
        import drjit as dr
        import mitsuba as mi

        self._mi, self._dr = mi, dr
        self.rig = rig
        self.camera_index = camera_index
        self._scene_camera = camera_index  # the camera of the loaded scene's Mitsuba sensor
        self.objects = objects
        self.radiance = float(radiance)
        self.integrator = integrator or {"type": "direct"}
        self.scene_description = scene_dict(rig, objects, camera_index=camera_index, radiance=radiance,
                                            integrator=self.integrator)
        if self.colour:  # the per-source renderer's film keeps R, G and B
            self.scene_description["sensor"]["film"]["pixel_format"] = "rgb"
        self.scene = load_scene(self.scene_description)
        self.params = mi.traverse(self.scene)
        # plain copies: parameter arrays are updated in place by Mitsuba
        self._params_initial = {
            k: (type(self.params[k]), np.array(self.params[k]).ravel().tolist())
            for k in self.params.keys()
            if k.startswith("source_") and k.endswith(("radiance.value", "sampling_weight", "intensity.value"))
        }
        # source index of each emitter, from its Mitsuba id ("source_007")
        self._emitters = [None] * rig.n_sources
        for em in self.scene.emitters():
            shape = em.get_shape()
            name = shape.id() if shape is not None else em.id()
            if name.startswith("source_"):
                self._emitters[int(name.split("_")[1])] = em
        if any(e is None for e in self._emitters):
            raise RuntimeError("could not match every rig source to a Mitsuba emitter")
        self.part_names = ["background"] + list(objects)
        self.alpha = {name: shape.get("bsdf", {}).get("alpha") for name, shape in objects.items()}

    # -- scene updates -----------------------------------------------------------
    def use_camera(self, index: int) -> None:
        """Render from another of the rig's cameras, without reloading the scene.

        The one-pass renderer and the truth trace the camera's rays
        themselves, so they follow at once; the per-source renderer uses the
        Mitsuba sensor the scene was loaded with and refuses another camera.
        """
        n = len(self.rig.cameras)
        if not 0 <= int(index) < n:
            raise OptionError(f"camera index must lie in 0..{n - 1} (the rig has {n} camera(s)), got {index}")
        if int(index) != self.camera_index:
            self.camera_index = int(index)
            self.geometry_changed()

    def geometry_changed(self) -> None:
        """Forget what was cached of the scene's geometry (pixel-centre hits, sample-allocation terms).

        Call after moving or reshaping objects in place (``self.params``), as
        :meth:`use_camera` does; roughness changes (:meth:`set_alpha`) need
        no call.
        """
        self._geom = None
        self._alloc = None

    @_in_own_variant
    def set_alpha(self, alpha: float, parts: Sequence[str] | None = None) -> None:
        """Change the roughness of the object parts in place (no reload).

        Parameters
        ----------
        alpha : float
        parts : iterable of str, optional
            Object names to change (default: every rough-conductor part).
        """
        if not (np.isfinite(alpha) and alpha > 0):
            raise OptionError(f"alpha must be > 0, got {alpha!r}")
        names = parts or [n for n in self.objects if f"{n}.bsdf.alpha.value" in self.params]
        for name in names:
            key = f"{name}.bsdf.alpha.value"
            if key not in self.params:
                raise KeyError(f"object {name!r} has no rough-conductor alpha")
            self.params[key] = float(alpha)
            self.alpha[name] = float(alpha)
        self.params.update()

    def _only_source(self, k):
        """Switch every source but ``k`` off (radiance and sampling weight)."""
        for key, (kind, value) in self._params_initial.items():
            on = k is None or key.split(".")[0] == f"source_{k:03d}"
            new = value if on else [0.0] * len(value)
            self.params[key] = kind(new[0]) if kind in (float, int) else kind(new)
        self.params.update()

    # -- rays ------------------------------------------------------------------------
    def _camera_rays(self, pixel, jitter):
        mi, dr = self._mi, self._dr
        cam = self.rig.cameras[self.camera_index]
        W = cam.width
        row = mi.Float(pixel // W)
        col = mi.Float(pixel % W)
        if jitter is not None:
            col += jitter.x - 0.5
            row += jitter.y - 0.5
        pr, pc = (float(x) for x in cam.principal_point_px)
        half = 0.5 * W
        u = (col - pc) / half
        v = (row - pr) / (half * cam.aspect)
        k1, k2, p1, p2, k3 = cam.distortion
        if p1 != 0.0 or p2 != 0.0:
            # undistort: Newton in two dimensions on the map's Jacobian, as Camera.undistort (a fixed count)
            ud, vd = u, v
            for _ in range(8):
                r2 = u * u + v * v
                g = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
                dg = 2.0 * (k1 + 2.0 * k2 * r2 + 3.0 * k3 * r2 * r2)
                uv = u * v
                ru = u * g + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u * u) - ud
                rv = v * g + p1 * (r2 + 2.0 * v * v) + 2.0 * p2 * uv - vd
                a11 = g + dg * u * u + 2.0 * p1 * v + 6.0 * p2 * u
                a12 = dg * uv + 2.0 * p1 * u + 2.0 * p2 * v
                a22 = g + dg * v * v + 6.0 * p1 * v + 2.0 * p2 * u
                det = a11 * a22 - a12 * a12
                u, v = u - (a22 * ru - a12 * rv) / det, v - (a11 * rv - a12 * ru) / det
        elif k1 != 0.0 or k2 != 0.0 or k3 != 0.0:
            # undistort: Newton on the radius, as Camera.undistort (a fixed count: float32 converges in a few)
            rd = dr.sqrt(u * u + v * v)
            r = mi.Float(rd)
            for _ in range(6):
                r2 = r * r
                if k3 != 0.0:
                    r = r - ((r * (1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2) - rd)
                             / (1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2 + 7.0 * k3 * r2 * r2 * r2))
                else:
                    r = r - (r * (1.0 + k1 * r2 + k2 * r2 * r2) - rd) / (1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2)
            scale = dr.select(rd > 0, r / dr.maximum(rd, 1e-30), 1.0)
            u, v = u * scale, v * scale
        du = u * (0.5 * cam.field_width)
        dv = v * (0.5 * cam.field_width)
        right = mi.ScalarVector3f(cam.right)
        down = mi.ScalarVector3f(cam.down)
        fwd = mi.ScalarVector3f(cam.forward)
        pos = mi.ScalarPoint3f(cam.position)
        if cam.projection == "orthographic":
            o = mi.Point3f(pos) + right * du + down * dv
            d = mi.Vector3f(fwd)
        else:
            o = mi.Point3f(pos)
            d = dr.normalize(fwd * cam.distance + right * du + down * dv)
        return mi.Ray3f(o, d)

    def _jittered_rays(self, pixel, seed):
        """An independent sampler seeded with ``seed`` for the lanes ``pixel``, and their camera rays, jittered
        within each pixel by its first 2D sample."""
        sampler = self._mi.load_dict({"type": "independent"})
        sampler.seed(seed, self._dr.width(pixel))
        return sampler, self._camera_rays(pixel, sampler.next_2d())

    # -- truth -----------------------------------------------------------------------
    @_in_own_variant
    def render_truth(self, *, coverage: int = 0) -> Truth:
        """Normals, positions, mask and part ids at pixel centres.

        Parameters
        ----------
        coverage : int
            With ``n > 0``, also the fraction of each pixel that images the
            object, from an ``n x n`` grid of sub-pixel rays (``Truth.coverage``;
            needs a JIT variant). The normals stay those at pixel centres:
            never averaged over a pixel.

        Returns
        -------
        shinysim.io.Truth
        """
        truth = self._render_truth() if is_vectorized(self.variant) else self._render_truth_scalar()
        if coverage:
            truth.coverage = self._render_coverage(int(coverage))
            truth.metadata["coverage_grid"] = int(coverage)
        return truth

    def _render_coverage(self, n):
        mi, dr = self._mi, self._dr
        self._require_vectorized("coverage")
        if n < 1 or n > 16:
            raise OptionError(f"coverage grid must be 1..16 rays a side, got {n}")
        cam = self.rig.cameras[self.camera_index]
        H, W = cam.shape
        hits = np.zeros(H * W, np.float64)
        lookup = self._object_shape_lookup()
        pixel = dr.arange(mi.UInt32, H * W)
        for j in range(n):
            for i in range(n):
                jitter = mi.Point2f((i + 0.5) / n, (j + 0.5) / n)
                hits += self._parts_hit(self.scene.ray_intersect(self._camera_rays(pixel, jitter)), lookup) > 0
        return (hits / (n * n)).reshape(H, W).astype(np.float32)

    def _object_shape_lookup(self):
        """Part index (0 = none) of every shape, indexed by the shape's drjit id."""
        mi, dr = self._mi, self._dr
        ids = np.array(dr.reinterpret_array(mi.UInt32, self.scene.shapes_dr()))
        lookup = np.zeros(int(ids.max()) + 1, dtype=np.uint32)
        for sid, shape in zip(ids, self.scene.shapes()):
            name = shape.id()
            lookup[sid] = self.part_names.index(name) if name in self.part_names else 0
        return lookup

    def _parts_hit(self, si, lookup):
        """The part index (0 = none) each ray of ``si`` hit, as a numpy array."""
        mi, dr = self._mi, self._dr
        part = dr.gather(mi.UInt32, mi.UInt32(lookup), dr.reinterpret_array(mi.UInt32, si.shape), si.is_valid())
        return np.array(dr.select(si.is_valid(), part, 0))

    def _render_truth(self) -> Truth:
        mi, dr = self._mi, self._dr
        cam = self.rig.cameras[self.camera_index]
        H, W = cam.shape
        pixel = dr.arange(mi.UInt32, H * W)
        si = self.scene.ray_intersect(self._camera_rays(pixel, None))
        part = self._parts_hit(si, self._object_shape_lookup()).reshape(H, W).astype(np.int32)
        n = np.stack([np.array(c) for c in si.sh_frame.n], axis=-1).reshape(H, W, 3)
        p = np.stack([np.array(c) for c in si.p], axis=-1).reshape(H, W, 3)
        mask = part > 0
        n[~mask] = np.nan
        p[~mask] = np.nan
        return Truth(n, p, mask, part, list(self.part_names), {"variant": self.variant})

    def _render_truth_scalar(self):
        """render_truth for scalar variants: one Python call per pixel ray (slow)."""
        mi = self._mi
        cam = self.rig.cameras[self.camera_index]
        H, W = cam.shape
        rows, cols = np.indices((H, W))
        origins, dirs = cam.pixel_rays(rows.ravel(), cols.ravel())
        n = np.full((H * W, 3), np.nan)
        p = np.full((H * W, 3), np.nan)
        part = np.zeros(H * W, np.int32)
        for i in range(H * W):
            si = self.scene.ray_intersect(mi.Ray3f(mi.Point3f(origins[i]), mi.Vector3f(dirs[i])))
            if not si.is_valid():
                continue
            name = si.shape.id()
            if name not in self.part_names:
                continue
            part[i] = self.part_names.index(name)
            n[i] = np.array(si.sh_frame.n, dtype=float)
            p[i] = np.array(si.p, dtype=float)
        part = part.reshape(H, W)
        return Truth(n.reshape(H, W, 3), p.reshape(H, W, 3), part > 0, part, list(self.part_names),
                     {"variant": self.variant})

    @_in_own_variant
    def render_emission(self, spp: int = 16, seed: int = 0) -> np.ndarray:
        """What the camera sees of the emitters alone, e.g. a backlit hole plate.

        Jittered rays of the camera's own model (principal point and
        distortion included), ``spp`` per pixel, box filter; each ray scores
        the radiance of the emitter it hits first (nothing is reflected).

        Returns
        -------
        (H, W) float32 ndarray
        """
        mi, dr = self._mi, self._dr
        self._require_vectorized("render_emission")
        spp = int(spp)
        if spp < 1:
            raise OptionError(f"spp must be >= 1, got {spp}")
        cam = self.rig.cameras[self.camera_index]
        H, W = cam.shape
        pixel = dr.arange(mi.UInt32, H * W)
        acc = dr.zeros(mi.Float, H * W)
        for s in range(spp):
            si = self.scene.ray_intersect(self._jittered_rays(pixel, derive_seed(seed, "emission", s))[1])
            em = si.emitter(self.scene, si.is_valid())
            acc += dr.select(si.is_valid(), em.eval(si, si.is_valid())[0], 0.0)
        return (np.array(acc) / spp).reshape(H, W).astype(np.float32)

    def _require_vectorized(self, what):
        if not is_vectorized(self.variant):
            raise RuntimeError(
                f"{what} needs a JIT (llvm or cuda) Mitsuba variant; running {self.variant}. "
                "Install an LLVM that drjit accepts (Debian: libllvm19)."
            )

    # -- stacks ----------------------------------------------------------------------
    @_in_own_variant
    def render_stack(self, spp: int = 64, seed: int = 0, *, method: str | None = None,
                     progress: Callable[[int, int], None] | None = None, direct_only: bool = False,
                     floor: float | None = None) -> Stack:
        """Render one frame per source.

        Parameters
        ----------
        spp : int
            Samples per pixel (per source, for every method).
        seed : int
            Same seed, same stack.
        method : {"one-pass", "uniform", "per-source"}, optional
            Default: one-pass on JIT variants for direct light (and with
            ``direct_only``) and for the ``path`` integrator with a finite
            ``max_depth`` (grey stacks); per-source on scalar variants, for
            other integrators and for colour paths.
            "uniform" is the one-pass sampler with ``spp`` samples for every
            (source, pixel) pair: no allocation, a reference for it.
        progress : callable, optional
            Called as ``progress(done, total)`` after each batch or source.
        direct_only : bool
            Direct light only, whatever the integrator (one-pass: the same
            loaded scene and cached geometry; e.g. the direct reference of a
            scan rendered with inter-reflections).
        floor : float, optional
            One-pass: the least expected samples per (source, pixel) pair
            (:data:`DIRECT_FLOOR` for direct light, :data:`PATH_FLOOR` for
            paths with inter-reflections by default). > 0.

        Returns
        -------
        shinysim.io.Stack
            In a colour Simulator: the mean of R, G and B of
            :meth:`render_colour_stack`.

        Examples
        --------
        The paper's calibration sphere under its 21 sources, at 32 x 32
        pixels and 4 samples per pixel, and its highlights found again:

        >>> from shinysim.recon import reconstruct
        >>> from shinysim.rig import shiny_1988
        >>> from shinysim.sim.scene import sphere_object
        >>> stack = Simulator(shiny_1988(resolution=32), sphere_object()).render_stack(spp=4)
        >>> stack.frames.shape, len(reconstruct(stack).table["row"])
        ((21, 32, 32), 21)
        """
        if self.colour:
            return self.render_colour_stack(spp, seed, method=method, progress=progress,
                                            direct_only=direct_only, floor=floor).grey()
        frames, provenance = self._render(spp, seed, method, progress, direct_only, False, floor)
        return Stack(frames, self.rig, self.camera_index, provenance)

    @_in_own_variant
    def render_stack_and_direct(self, spp: int = 64, seed: int = 0, *,
                                progress: Callable[[int, int], None] | None = None,
                                floor: float | None = None) -> tuple[Stack, Stack]:
        """The stack with inter-reflections and its direct-light part, from the same samples.

        With the ``path`` integrator (a finite ``max_depth`` above 2) on a JIT
        variant, one one-pass render: each lane's contributions up to its
        first bounce (the source seen directly, the light sample at the first
        hit, a first bounce that lands on the source) are summed into the
        second stack as well, which is therefore an unbiased direct-light
        render (the ``direct`` integrator's estimator) made of parts of the
        first stack's samples: pixel by pixel it never exceeds the first,
        and their difference is the inter-reflected light alone. Otherwise
        two renders from ``seed``: :meth:`render_stack` and its direct-light
        counterpart (``direct_only=True`` on a JIT variant; the same stack
        for the ``direct`` integrator).

        Returns
        -------
        (stack, direct) : (shinysim.io.Stack, shinysim.io.Stack)
            ``direct.provenance["direct_only"]`` is True; from one render,
            ``direct.provenance["split_from"]`` is ``"path"``.

        Raises
        ------
        ValueError
            In a colour Simulator; or a scalar variant with an integrator
            other than ``direct`` (render the direct stack with a second,
            direct-light Simulator).
        """
        if self.colour:
            raise OptionError("render_stack_and_direct renders grey stacks; this Simulator is a colour one")
        kind = self.integrator.get("type")
        if not is_vectorized(self.variant) and kind != "direct":
            raise OptionError(f"render_stack_and_direct on the scalar variant {self.variant} needs the direct "
                             f"integrator; for {kind!r}, render the direct stack with a direct-light Simulator")
        if not (is_vectorized(self.variant) and kind == "path" and int(self.integrator.get("max_depth", -1)) > 2):
            stack = self.render_stack(spp, seed, progress=progress, floor=floor)
            return stack, (stack if kind == "direct" else self.render_stack(spp, seed, direct_only=True))
        (frames, direct_frames), provenance = self._render(spp, seed, None, progress, False, False, floor,
                                                          split=True)
        direct_provenance = {**provenance, "direct_only": True, "split_from": "path"}
        return (Stack(frames, self.rig, self.camera_index, provenance),
                Stack(direct_frames, self.rig, self.camera_index, direct_provenance))

    @_in_own_variant
    def render_colour_stack(self, spp: int = 64, seed: int = 0, *, method: str | None = None,
                            progress: Callable[[int, int], None] | None = None, direct_only: bool = False,
                            floor: float | None = None):
        """Render one linear-RGB frame per source, every source white: a colour Simulator only.

        The parameters are :meth:`render_stack`'s. The one-pass and uniform
        renderers trace direct light in colour (the three channels from the
        same samples, so a grey material gives three equal channels, each
        the mono render of the same seed); with inter-reflections (the
        ``path`` integrator) the per-source renderer is used.

        Returns
        -------
        shinysim.sim.coded.ColourStack
            Frames (n_sources, H, W, 3) float32.

        Raises
        ------
        ValueError
            In a Simulator made without ``colour=True``, or the one-pass
            renderer asked for paths with inter-reflections.
        """
        from .coded import ColourStack

        if not self.colour:
            raise OptionError(f"colour stacks need a colour Simulator (Simulator(..., colour=True), an RGB variant); "
                             f"this one runs {self.variant}")
        frames, provenance = self._render(spp, seed, method, progress, direct_only, True, floor)
        return ColourStack(frames, self.rig, self.camera_index, provenance)

    def _render(self, spp, seed, method, progress, direct_only, colour, floor=None, split=False):
        """The frames of :meth:`render_stack` (colour: of :meth:`render_colour_stack`) and their provenance."""
        kind = "direct" if direct_only else self.integrator.get("type")
        self._depth_override = 2 if direct_only else None
        if method is None:
            if direct_only and not is_vectorized(self.variant):
                raise OptionError("direct_only needs the one-pass renderer (a JIT variant)")
            # paths: one-pass where it can trace them (a finite depth; grey, as colour paths render per source)
            finite_path = kind == "path" and int(self.integrator.get("max_depth", -1)) >= 0 and not colour
            method = "one-pass" if is_vectorized(self.variant) and (kind == "direct" or finite_path) else "per-source"
        if floor is not None:
            floor = check_number("floor", floor, lo=0, lo_open=True)
        if method not in RENDER_METHODS:
            raise OptionError(f"method must be one of {RENDER_METHODS}, got {method!r}")
        if method == "per-source" and direct_only and self.integrator.get("type") != "direct":
            raise OptionError("direct_only renders with the one-pass renderer; the per-source renderer uses the "
                             "simulator's own integrator")
        if method != "per-source" and kind not in ("direct", "path"):
            raise OptionError(f"the {method} renderer traces direct light or paths; use method='per-source' "
                             f"for the {kind!r} integrator")
        spp = int(spp)
        if spp < 1:
            raise OptionError(f"spp must be >= 1, got {spp}")
        if colour and method != "per-source" and self._max_depth() > 2:
            raise OptionError(f"the {method} renderer traces direct light in colour; render paths with "
                             "inter-reflections in colour with method='per-source'")
        t0 = time.perf_counter()
        if method in ("one-pass", "uniform"):
            self._require_vectorized(f"the {method} renderer")
            if method == "one-pass":
                paths = self._max_depth() > 2
                if floor is None:
                    floor = PATH_FLOOR if paths else DIRECT_FLOOR
                m = self.sample_allocation(spp, floor=floor)
                if paths:  # inter-reflections light more than the direct estimate says
                    m = np.maximum(m, self._pilot_allocation(spp, seed, floor=floor))
            else:
                cam = self.rig.cameras[self.camera_index]
                m = np.full((self.rig.n_sources,) + cam.shape, float(spp))
            frames = self._render_lanes(m, seed, progress, colour=colour, split=split)
        else:
            frames = self._render_per_source(spp, seed, progress, colour=colour)
        seconds = time.perf_counter() - t0
        provenance = {
            "generator": f"shinysim {__version__}",
            "mitsuba": self._mi.__version__,
            "drjit": self._dr.__version__,
            "variant": self.variant,
            "method": method,
            **({"floor": float(floor)} if method == "one-pass" else {}),
            **({"direct_only": True} if direct_only else {}),
            "spp": spp,
            "seed": int(seed),
            "alpha": self.alpha,
            "radiance": self.radiance,
            **({"colour": "linear RGB, white sources"} if colour else {}),
        }
        # the time goes to the caller's log, not into the stack: the same seed
        # gives byte-identical files
        self.last_render_seconds = seconds
        return frames, provenance

    def _render_per_source(self, spp, seed, progress, colour=False):
        mi = self._mi
        cam = self.rig.cameras[self.camera_index]
        if self.camera_index != self._scene_camera:
            raise OptionError(f"the per-source renderer images the camera the scene was loaded with "
                             f"({self._scene_camera}); load a Simulator with camera_index={self.camera_index}, "
                             f"or render camera {self.camera_index} with the one-pass renderer")
        if not cam.is_ideal:
            raise OptionError(f"camera {cam.name!r} has a principal point off centre or lens distortion, which "
                             "Mitsuba's own sensors (used by the per-source renderer) do not model; render "
                             "it with the one-pass renderer (direct lighting), which traces the camera's rays")
        frames = np.zeros((self.rig.n_sources,) + cam.shape + ((3,) if colour else ()), np.float32)
        try:
            for k in range(self.rig.n_sources):
                self._only_source(k)
                img = np.array(mi.render(self.scene, spp=spp, seed=derive_seed(seed, k)))
                if colour:
                    frames[k] = img[..., :3]
                else:
                    frames[k] = img.mean(axis=-1) if img.ndim == 3 else img
                if progress:
                    progress(k + 1, self.rig.n_sources)
        finally:
            self._only_source(None)
        return frames

    # -- one-pass rendering ------------------------------------------------------
    def _geometry(self):
        """Pixel-centre hits, cached: position, normal, part and view direction."""
        if getattr(self, "_geom", None) is not None:
            return self._geom
        t = self.render_truth()
        cam = self.rig.cameras[self.camera_index]
        view = cam.view_directions(np.nan_to_num(t.positions.astype(float)))
        self._geom = {"truth": t, "view": view}
        return self._geom

    def _material_table(self):
        """Per part: (kind, alpha) for the sample allocation; 0 is background."""
        table = [("none", 0.0)]
        for name in self.part_names[1:]:
            bsdf = self.objects[name].get("bsdf", {})
            kind = {"roughconductor": "lobe", "diffuse": "diffuse"}.get(bsdf.get("type"), "unknown")
            table.append((kind, float(self.alpha.get(name) or bsdf.get("alpha", 0.1)) if kind == "lobe" else 0.0))
        return table

    def _allocation_terms(self):
        """Roughness-independent terms of :meth:`sample_allocation`, cached.

        Over the pixels whose centre ray hits the object (index ``pix``):
        per source the angle to the half vector ``theta_h``, the lobe and
        diffuse prefactors (zero where the source is below the surface) and
        the source's angular radius; per pixel the spread of normals across
        it and its part.
        """
        if getattr(self, "_alloc", None) is not None:
            return self._alloc
        geo = self._geometry()
        t = geo["truth"]
        rig = self.rig
        H, W = t.mask.shape
        hit = t.mask
        n_img = np.nan_to_num(t.normals.astype(float))
        # spread of normals across each pixel: the largest angle to a 4-neighbour's
        # normal; towards a neighbour off the object, the angle from the normal to
        # the silhouette (normals there run from n to perpendicular to the view)
        view_cos = np.clip(np.sum(n_img * geo["view"], axis=-1), -1.0, 1.0)
        to_rim = np.maximum(0.0, 0.5 * np.pi - np.arccos(view_cos))
        spread = np.zeros((H, W))
        padded_hit = np.pad(hit, 1)
        padded_n = np.pad(n_img, ((1, 1), (1, 1), (0, 0)))
        for dr_, dc_ in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            nb_hit = padded_hit[1 + dr_:H + 1 + dr_, 1 + dc_:W + 1 + dc_]
            nb_n = padded_n[1 + dr_:H + 1 + dr_, 1 + dc_:W + 1 + dc_]
            ang = np.arccos(np.clip(np.sum(n_img * nb_n, axis=-1), -1, 1))
            spread = np.maximum(spread, np.where(nb_hit, ang, to_rim))
        spread = np.where(hit, spread, 0.0)
        pix = np.flatnonzero(hit)
        n = n_img.reshape(-1, 3)[pix]
        p = np.nan_to_num(t.positions.astype(float)).reshape(-1, 3)[pix]
        v = geo["view"].reshape(-1, 3)[pix]
        cos_o = np.clip(np.sum(n * v, axis=-1), 1e-3, 1.0)
        k_n = rig.n_sources
        theta_h = np.empty((k_n, pix.size), np.float32)
        lobe = np.empty((k_n, pix.size), np.float32)
        diffuse = np.empty((k_n, pix.size), np.float32)
        half_rho = np.empty((k_n, pix.size), np.float32)
        # per-component arrays: reductions over a trailing axis of 3 are slow in numpy
        nx, ny, nz = (np.ascontiguousarray(n[:, i]) for i in range(3))
        px, py, pz = (np.ascontiguousarray(p[:, i]) for i in range(3))
        vx, vy, vz = (np.ascontiguousarray(v[:, i]) for i in range(3))
        for k in range(k_n):
            if rig.source_distant[k]:
                sx, sy, sz = (np.full(pix.size, c) for c in rig.source_positions[k])
                omega, rho = np.ones(pix.size), np.zeros(pix.size)
            else:
                dx, dy, dz = (rig.source_positions[k][0] - px, rig.source_positions[k][1] - py,
                              rig.source_positions[k][2] - pz)
                dist = np.sqrt(dx * dx + dy * dy + dz * dz)
                sx, sy, sz = dx / dist, dy / dist, dz / dist
                r = rig.source_radii[k]
                rho = np.arcsin(np.clip(r / dist, 0, 1)) if r > 0 else np.zeros_like(dist)
                omega = np.pi * rho**2 if r > 0 else 1.0 / dist**2
            hx, hy, hz = sx + vx, sy + vy, sz + vz
            hn = np.sqrt(hx * hx + hy * hy + hz * hz)
            cos_i = nx * sx + ny * sy + nz * sz
            above = cos_i > 0
            theta_h[k] = np.arccos(np.clip((nx * hx + ny * hy + nz * hz) / hn, 0.0, 1.0))
            lobe[k] = np.where(above, omega / (4 * cos_o), 0.0)
            diffuse[k] = np.where(above, omega * cos_i / np.pi, 0.0)
            half_rho[k] = 0.5 * rho
        # pixels whose centre misses but which the object partly covers: they take
        # the largest allocation of their hit 8-neighbours (else a lit edge would
        # be sampled at the floor rate and come out as fireflies)
        index = np.full(H * W, -1, np.int64)
        index[pix] = np.arange(pix.size)
        index = np.pad(index.reshape(H, W), 1, constant_values=-1)
        shifts = [(dr_, dc_) for dr_ in (-1, 0, 1) for dc_ in (-1, 0, 1) if (dr_, dc_) != (0, 0)]
        nb = np.stack([index[1 + dr_:H + 1 + dr_, 1 + dc_:W + 1 + dc_] for dr_, dc_ in shifts], axis=-1)
        rim = np.flatnonzero(~hit.reshape(-1) & (nb.reshape(H * W, 8) >= 0).any(axis=1))
        self._alloc = {
            "pix": pix, "shape": (H, W), "theta_h": theta_h, "lobe": lobe, "diffuse": diffuse,
            "half_rho": half_rho, "spread": spread.reshape(-1)[pix].astype(np.float32),
            "part": t.part.reshape(-1)[pix],
            "rim": rim, "rim_nb": nb.reshape(H * W, 8)[rim],
        }
        return self._alloc

    @_in_own_variant
    def sample_allocation(self, spp, *, full_fraction=0.1, floor=DIRECT_FLOOR, widen=1.25):
        """Expected samples per (source, pixel) for the one-pass renderer.

        An upper estimate of each pixel's value under each source,
        ``V = L * Omega * f * cos_i``, evaluates the microfacet lobe (GGX, its
        alpha times ``widen``) at the smallest angle between any normal in the
        pixel and any half vector towards the source,
        ``theta' = max(0, theta_h - spread - rho / 2)`` (``theta_h`` at the
        pixel centre and the source centre, ``spread`` the angle over which
        normals vary across the pixel, ``rho`` the source's angular radius);
        diffuse parts use ``f = 1/pi``. A pair gets
        ``spp * min(1, V / (full_fraction * peak))`` samples in expectation,
        at least ``floor`` (every pixel keeps a non-zero chance, which keeps
        the estimate unbiased everywhere), and the full ``spp`` on materials
        it cannot model. On silhouette pixels the spread runs from the
        normal at the pixel centre to the silhouette, where normals are
        perpendicular to the view; pixels whose centre misses the object but
        which touch it take the largest allocation of their neighbours.

        Returns
        -------
        (n_sources, H, W) float32
        """
        a = self._allocation_terms()
        mats = self._material_table()
        kind = np.array([m[0] for m in mats])[a["part"]]
        alpha = np.array([m[1] for m in mats], np.float32)[a["part"]]
        # smallest angle between a normal in the pixel and a half vector towards
        # some point of the source: an upper bound of the lobe over the pixel
        theta = np.maximum(0.0, a["theta_h"] - a["spread"] - a["half_rho"])
        a2 = np.maximum(np.float32(widen**2) * alpha**2, np.float32(1e-8))
        c2 = np.cos(theta) ** 2
        D = a2 / (np.float32(np.pi) * (a2 * c2 + (1 - c2)) ** 2)
        value = np.where(kind == "lobe", a["lobe"] * D, a["diffuse"])
        peak = value.max(axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            m = np.where(peak > 0, spp * np.minimum(1.0, value / (full_fraction * peak)), 0.0)
        m[:, kind == "unknown"] = spp
        H, W = a["shape"]
        out = np.full((self.rig.n_sources, H * W), floor, np.float32)
        m = np.maximum(m, floor)
        out[:, a["pix"]] = m
        if a["rim"].size:
            nb = a["rim_nb"]
            out[:, a["rim"]] = np.where(nb >= 0, m[:, np.maximum(nb, 0)], floor).max(axis=-1)
        return out.reshape(-1, H, W)

    def _sample_lanes(self, pixel, source, seed, colour=False):
        """Trace one sample per lane: a jittered camera ray, then direct light
        from the lane's source (one light sample + one BSDF sample, MIS).

        Returns the per-lane value (drjit Float; with ``colour`` the RGB
        spectrum, the same samples for the three channels); the caller
        applies the lane weights.
        """
        mi, dr = self._mi, self._dr
        sampler, ray = self._jittered_rays(pixel, seed)
        si = self.scene.ray_intersect(ray)
        active = si.is_valid() & ~si.shape.is_emitter()
        bsdf = si.bsdf(ray)
        ctx = mi.BSDFContext()
        emitter = dr.gather(mi.EmitterPtr, self._emitters_dr, source, active)
        pick = (lambda x: x) if colour else (lambda x: x[0])  # the spectrum, or its one channel
        ok, w_em, f, mis = self._light_sample(si, bsdf, ctx, emitter, sampler, active)
        value = dr.select(ok, pick(w_em) * pick(f) * mis, 0.0)
        # BSDF sample, counted only when it reaches the lane's source
        bs, w_bsdf = bsdf.sample(ctx, si, sampler.next_1d(), sampler.next_2d(), active)
        si2 = self.scene.ray_intersect(si.spawn_ray(si.to_world(bs.wo)), active)
        em2 = si2.emitter(self.scene, active)
        hit = active & (dr.reinterpret_array(mi.UInt32, em2) == dr.reinterpret_array(mi.UInt32, emitter))
        le = em2.eval(si2, hit)
        pdf_e = em2.pdf_direction(si, mi.DirectionSample3f(self.scene, si2, si), hit)
        mis_b = dr.select(bs.pdf > 0, _power_heuristic(dr, bs.pdf, pdf_e), 0.0)
        value += dr.select(hit, pick(w_bsdf) * pick(le) * mis_b, 0.0)
        return value

    def _light_sample(self, si, bsdf, ctx, emitter, sampler, active):
        """One light sample from ``emitter`` at ``si``, MIS with the BSDF's pdf: ``(ok, w_em, f, mis)``, the
        unoccluded lanes, the emitter's sample weight, the BSDF value towards it and the MIS weight."""
        dr = self._dr
        ds, w_em = emitter.sample_direction(si, sampler.next_2d(), active)
        ok = active & (ds.pdf > 0)
        ok &= ~self.scene.ray_test(si.spawn_ray_to(ds.p), ok)
        f, pdf_b = bsdf.eval_pdf(ctx, si, si.to_local(ds.d), ok)
        return ok, w_em, f, dr.select(ds.delta, 1.0, _power_heuristic(dr, ds.pdf, pdf_b))

    def _max_depth(self):
        """Longest light path in Mitsuba's counting: 2 for direct light, the path integrator's ``max_depth``."""
        if getattr(self, "_depth_override", None) is not None:
            return self._depth_override
        if self.integrator.get("type") != "path":
            return 2
        depth = int(self.integrator.get("max_depth", -1))
        if depth < 0:
            raise OptionError("the one-pass renderer needs a finite max_depth for the path integrator")
        return depth

    def _sample_lanes_path(self, pixel, source, seed, max_depth, split=False):
        """One path per lane, lit by the lane's source only: Mitsuba's ``path`` integrator restricted to one
        emitter, as the per-source renderer runs it with the other sources switched off.

        At each vertex up to ``max_depth - 1``: next-event estimation towards the lane's source (one light
        sample, MIS with the BSDF's pdf); the BSDF sample continues the path, and a later vertex that lands on
        the lane's source adds its radiance with the matching MIS weight (no weight for a directly seen
        source). Every other source is geometry that emits nothing, as in the per-source render.

        With ``split``: ``(value, direct)``, ``direct`` the lane's value up to its first bounce (the source seen
        directly, the light sample at the first hit, a first bounce that lands on the source): the ``direct``
        integrator's estimate, a partial sum of ``value``'s nonnegative terms, so never above it.
        """
        mi, dr = self._mi, self._dr
        sampler, ray = self._jittered_rays(pixel, seed)
        emitter = dr.gather(mi.EmitterPtr, self._emitters_dr, source)
        emitter_id = dr.reinterpret_array(mi.UInt32, emitter)
        ctx = mi.BSDFContext()
        beta = mi.Float(1.0)
        value = mi.Float(0.0)
        active = mi.Bool(True)
        prev_si = prev_pdf = prev_delta = None
        for depth in range(max_depth):
            si = self.scene.ray_intersect(ray, active)
            em = si.emitter(self.scene, active)
            hit = active & (dr.reinterpret_array(mi.UInt32, em) == emitter_id)
            le = em.eval(si, hit)[0]
            if depth == 0:
                mis = mi.Float(1.0)
            else:
                pdf_e = em.pdf_direction(prev_si, mi.DirectionSample3f(self.scene, si, prev_si), hit)
                mis = dr.select(prev_delta, 1.0, _power_heuristic(dr, prev_pdf, pdf_e))
            value += dr.select(hit, beta * le * mis, 0.0)
            if split and depth == 1:
                direct = mi.Float(value)  # its own variable: the in-place sums below leave it as it is
            active &= si.is_valid()
            if depth + 1 >= max_depth:
                break
            bsdf = si.bsdf(ray)
            # next-event estimate towards the lane's source
            ok, w_em, f, mis_e = self._light_sample(si, bsdf, ctx, emitter, sampler, active)
            value += dr.select(ok, beta * w_em[0] * f[0] * mis_e, 0.0)
            # continue along a BSDF sample
            bs, w_b = bsdf.sample(ctx, si, sampler.next_1d(), sampler.next_2d(), active)
            beta = dr.select(active, beta * w_b[0], 0.0)
            active &= (bs.pdf > 0) & (beta > 0)
            prev_si, prev_pdf = si, bs.pdf
            prev_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            ray = si.spawn_ray(si.to_world(bs.wo))
        if split:
            dr.eval(value, direct)  # one kernel for both
            return value, direct
        return value

    def _pilot_allocation(self, spp, seed, *, step=2, full_fraction=0.1, floor=DIRECT_FLOOR, grow=3):
        """Expected samples from a cheap pilot render, for paths with inter-reflections.

        The direct-light allocation of :meth:`sample_allocation` does not know where light arrives after
        two bounces. A pilot of one sample on every ``step``-th pixel in each direction, for every source,
        finds it; its values, spread over ``step`` x ``step`` blocks and grown by ``grow`` pixels (a maximum
        filter), give each pair ``spp * min(1, V / (full_fraction * peak))`` samples, at least ``floor``.
        The pilot has its own random numbers and only decides where samples go: the render stays unbiased.
        """
        n_src = self.rig.n_sources
        H, W = self.rig.cameras[self.camera_index].shape
        m = np.zeros((n_src, H, W), np.float32)
        m[:, ::step, ::step] = 1.0
        pilot = self._render_lanes(m, derive_seed(seed, "pilot"), None)
        small = pilot[:, ::step, ::step]
        full = np.repeat(np.repeat(small, step, axis=1), step, axis=2)[:, :H, :W]
        # a 3 x 3 maximum filter applied ``grow`` times (zeros beyond the frame, below every value): the same
        # as one (2 grow + 1)-square maximum, taken along rows, then columns
        w = 2 * grow + 1
        grown = _window_max(np.pad(full, ((0, 0), (grow, grow), (0, 0))), w, 1)
        grown = _window_max(np.pad(grown, ((0, 0), (0, 0), (grow, grow))), w, 2)
        peak = grown.max(axis=(1, 2), keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(peak > 0, spp * np.minimum(1.0, grown / (full_fraction * peak)), 0.0)
        return np.maximum(out, floor).astype(np.float32)

    def _render_lanes(self, m, seed, progress, chunk=1 << 22, colour=False, split=False):
        """Render from expected sample counts ``m`` (n_sources, H, W).

        Each (source, pixel) pair gets ``floor(m + u)`` samples, u uniform,
        each weighted ``1 / m``: an unbiased estimate of the pixel whenever
        ``m > 0``. With ``colour``: (n_sources, H, W, 3), the three channels
        from the same lanes (direct light only). With ``split`` (paths):
        ``(frames, direct)``, the second the sums of the lanes' direct parts
        (:meth:`_sample_lanes_path`), with the same weights.
        """
        mi, dr = self._mi, self._dr
        n_src, H, W = m.shape
        HW = H * W
        if getattr(self, "_emitters_dr", None) is None:
            order = [list(self.scene.emitters()).index(e) for e in self._emitters]
            self._emitters_dr = dr.gather(mi.EmitterPtr, self.scene.emitters_dr(), mi.UInt32(order))
        rng = np.random.default_rng(derive_seed(seed, "allocation"))
        flat = m.reshape(-1)
        counts = np.floor(flat + rng.random(flat.size, dtype=np.float32)).astype(np.int32)
        pairs = np.flatnonzero(counts)
        reps = counts[pairs]
        lane_pair = np.repeat(pairs.astype(np.uint32), reps)
        lane_weight = np.repeat((1.0 / flat[pairs]).astype(np.float32), reps)
        # sums in numpy, lane by lane in a fixed order: a parallel scatter-add would add a pixel's samples in
        # whatever order the threads reach them, and the stack's last bits would vary from run to run
        acc = np.zeros((n_src * HW, 3) if colour else n_src * HW, np.float64)
        acc_direct = np.zeros(n_src * HW, np.float64) if split else None
        n_lanes = lane_pair.size
        chunks = max(1, -(-n_lanes // chunk))
        for c in range(chunks):
            sl = slice(c * chunk, min(n_lanes, (c + 1) * chunk))
            pair = mi.UInt32(lane_pair[sl])
            if self._max_depth() > 2 and not colour:
                value = self._sample_lanes_path(pair % HW, pair // HW, derive_seed(seed, c), self._max_depth(),
                                                split=split)
                value, direct = value if split else (value, None)
            else:
                value = self._sample_lanes(pair % HW, pair // HW, derive_seed(seed, c), colour=colour)
            # the lane weights are applied here, in numpy (in float64, as the sums); colour: (3, lanes) -> (lanes, 3)
            value = np.asarray(value, np.float64).T * (lane_weight[sl][:, None] if colour else lane_weight[sl])
            group_pair = lane_pair[sl]
            starts = np.flatnonzero(np.r_[True, group_pair[1:] != group_pair[:-1]])  # lanes are grouped by pair
            acc[group_pair[starts]] += np.add.reduceat(value, starts)
            if split:
                acc_direct[group_pair[starts]] += np.add.reduceat(np.asarray(direct, np.float64) * lane_weight[sl],
                                                                  starts)
            if progress:
                progress(c + 1, chunks)
        self.last_lane_count = int(n_lanes)
        if colour:
            return acc.reshape(n_src, H, W, 3).astype(np.float32)
        frames = acc.reshape(n_src, H, W).astype(np.float32)
        if split:
            return frames, acc_direct.reshape(n_src, H, W).astype(np.float32)
        return frames
