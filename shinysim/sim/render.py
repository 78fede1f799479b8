"""Rendering per-source highlight stacks and ground truth with Mitsuba 3.

:class:`Simulator` loads a rig's scene once and renders from it repeatedly
(roughness and seed changes update the loaded scene in place):

* :meth:`Simulator.render_stack` with ``method="one-pass"`` traces one camera
  ray per sample and, at its hit point, samples *every* source (one
  light sample each, plus one BSDF sample credited to the source it hits,
  combined by multiple importance sampling with the power heuristic),
  writing one image per source. Unbiased direct illumination, the same
  estimator as Mitsuba's ``direct`` integrator restricted to one source.
  Needs a JIT (llvm/cuda) variant.
* ``method="per-source"`` renders each source separately with
  ``mi.render`` and Mitsuba's ``direct`` integrator, the other sources'
  radiance and sampling weight set to zero: the reference, and the path
  used on scalar variants.
* :meth:`Simulator.render_truth` casts one ray through each pixel *centre*
  (not the jittered samples of an ``aov`` integrator) and records the
  surface normal, the hit point and which part was hit.

Pixels are averages over their area (box filter), matching the detector's
continuous coordinates (pixel centres at integers).
"""

from __future__ import annotations

import hashlib
import time

import numpy as np

from .. import __version__
from ..io import Stack, Truth
from .scene import load_scene, scene_dict
from .variants import choose_variant, is_vectorized

__all__ = ["RENDER_METHODS", "Simulator"]

#: How :meth:`Simulator.render_stack` renders.
RENDER_METHODS = ("one-pass", "per-source")


def _seed(*parts):
    h = hashlib.sha256(repr(parts).encode()).digest()
    return int.from_bytes(h[:4], "little") & 0x7FFFFFFF


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
    """

    def __init__(self, rig, objects, *, camera_index=0, variant=None, radiance=1.0):
        self.variant, self.variant_reason = choose_variant(variant)
        import drjit as dr
        import mitsuba as mi

        self._mi, self._dr = mi, dr
        self.rig = rig
        self.camera_index = camera_index
        self.objects = objects
        self.radiance = float(radiance)
        self.scene_description = scene_dict(rig, objects, camera_index=camera_index, radiance=radiance)
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
    def set_alpha(self, alpha, parts=None):
        """Change the roughness of the object parts in place (no reload).

        Parameters
        ----------
        alpha : float
        parts : iterable of str, optional
            Object names to change (default: every rough-conductor part).
        """
        if not (np.isfinite(alpha) and alpha > 0):
            raise ValueError(f"alpha must be > 0, got {alpha!r}")
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
        W, H = cam.width, cam.height
        row = mi.Float(pixel // W)
        col = mi.Float(pixel % W)
        if jitter is not None:
            col += jitter.x - 0.5
            row += jitter.y - 0.5
        du = (col - 0.5 * (W - 1)) * cam.pixel_pitch
        dv = (row - 0.5 * (H - 1)) * cam.pixel_pitch
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

    # -- truth -----------------------------------------------------------------------
    def render_truth(self):
        """Normals, positions, mask and part ids at pixel centres.

        Returns
        -------
        shinysim.io.Truth
        """
        mi, dr = self._mi, self._dr
        self._require_vectorized("render_truth")
        cam = self.rig.cameras[self.camera_index]
        H, W = cam.shape
        pixel = dr.arange(mi.UInt32, H * W)
        si = self.scene.ray_intersect(self._camera_rays(pixel, None))
        shape_ids = dr.reinterpret_array(mi.UInt32, self.scene.shapes_dr())
        ids = np.array(shape_ids)
        lookup = np.zeros(int(ids.max()) + 1, dtype=np.uint32)
        for sid, shape in zip(ids, self.scene.shapes()):
            name = shape.id()
            lookup[sid] = self.part_names.index(name) if name in self.part_names else 0
        hit_id = dr.reinterpret_array(mi.UInt32, si.shape)
        part = dr.gather(mi.UInt32, mi.UInt32(lookup), hit_id, si.is_valid())
        part = np.array(dr.select(si.is_valid(), part, 0)).reshape(H, W).astype(np.int32)
        n = np.stack([np.array(c) for c in si.sh_frame.n], axis=-1).reshape(H, W, 3)
        p = np.stack([np.array(c) for c in si.p], axis=-1).reshape(H, W, 3)
        mask = part > 0
        n[~mask] = np.nan
        p[~mask] = np.nan
        return Truth(n, p, mask, part, list(self.part_names), {"variant": self.variant})

    def _require_vectorized(self, what):
        if not is_vectorized(self.variant):
            raise RuntimeError(
                f"{what} needs a JIT (llvm or cuda) Mitsuba variant; running {self.variant}. "
                "Install an LLVM that drjit accepts (Debian: libllvm19)."
            )

    # -- stacks ----------------------------------------------------------------------
    def render_stack(self, spp=64, seed=0, *, method=None, batch_spp=None, progress=None):
        """Render one frame per source.

        Parameters
        ----------
        spp : int
            Samples per pixel (per source, for every method).
        seed : int
            Same seed, same stack.
        method : {"one-pass", "per-source"}, optional
            Default: one-pass on JIT variants, per-source on scalar ones.
        batch_spp : int, optional
            Samples per pixel traced per batch (memory bound); default keeps
            about 4 M rays in flight.
        progress : callable, optional
            Called as ``progress(done, total)`` after each batch or source.

        Returns
        -------
        shinysim.io.Stack
        """
        if method is None:
            method = "one-pass" if is_vectorized(self.variant) else "per-source"
        if method not in RENDER_METHODS:
            raise ValueError(f"method must be one of {RENDER_METHODS}, got {method!r}")
        spp = int(spp)
        if spp < 1:
            raise ValueError(f"spp must be >= 1, got {spp}")
        t0 = time.perf_counter()
        if method == "one-pass":
            self._require_vectorized("the one-pass renderer")
            frames = self._render_one_pass(spp, seed, batch_spp, progress)
        else:
            frames = self._render_per_source(spp, seed, progress)
        seconds = time.perf_counter() - t0
        provenance = {
            "generator": f"shinysim {__version__}",
            "mitsuba": self._mi.__version__,
            "drjit": self._dr.__version__,
            "variant": self.variant,
            "method": method,
            "spp": spp,
            "seed": int(seed),
            "alpha": self.alpha,
            "radiance": self.radiance,
            "render_seconds": round(seconds, 3),
        }
        return Stack(frames, self.rig, self.camera_index, provenance)

    def _render_per_source(self, spp, seed, progress):
        mi = self._mi
        cam = self.rig.cameras[self.camera_index]
        frames = np.zeros((self.rig.n_sources,) + cam.shape, np.float32)
        try:
            for k in range(self.rig.n_sources):
                self._only_source(k)
                img = np.array(mi.render(self.scene, spp=spp, seed=_seed(seed, k)))
                frames[k] = img.mean(axis=-1) if img.ndim == 3 else img
                if progress:
                    progress(k + 1, self.rig.n_sources)
        finally:
            self._only_source(None)
        return frames

    def _render_one_pass(self, spp, seed, batch_spp, progress):
        mi, dr = self._mi, self._dr
        cam = self.rig.cameras[self.camera_index]
        H, W = cam.shape
        HW = H * W
        n_src = self.rig.n_sources
        if batch_spp is None:
            batch_spp = max(1, min(spp, (4 << 20) // HW))
        batches = [min(batch_spp, spp - s) for s in range(0, spp, batch_spp)]
        # emitter registry id -> source index, for BSDF samples that hit a source
        em_ids = np.array(dr.reinterpret_array(mi.UInt32, self.scene.emitters_dr()))
        lookup = np.zeros(int(em_ids.max()) + 1, dtype=np.uint32)
        for eid, em in zip(em_ids, self.scene.emitters()):
            lookup[eid] = self._emitters.index(em)
        lookup = mi.UInt32(lookup)
        ctx = mi.BSDFContext()
        acc = np.zeros((n_src, HW))
        for b, n_b in enumerate(batches):
            N = HW * n_b
            sampler = mi.load_dict({"type": "independent"})
            sampler.seed(_seed(seed, b), N)
            pixel = dr.arange(mi.UInt32, N) // n_b
            ray = self._camera_rays(pixel, sampler.next_2d())
            si = self.scene.ray_intersect(ray)
            active = si.is_valid() & ~si.shape.is_emitter()
            bsdf = si.bsdf(ray)
            dr.eval(si, active)
            # BSDF sample, credited to the source it reaches
            bs, w_bsdf = bsdf.sample(ctx, si, sampler.next_1d(), sampler.next_2d(), active)
            ray2 = si.spawn_ray(si.to_world(bs.wo))
            si2 = self.scene.ray_intersect(ray2, active)
            em2 = si2.emitter(self.scene, active)
            hit = active & (em2 != None)  # noqa: E711 (drjit pointer comparison)
            le = em2.eval(si2, hit)
            ds2 = mi.DirectionSample3f(self.scene, si2, si)
            pdf_e = em2.pdf_direction(si, ds2, hit)
            mis = dr.select(bs.pdf > 0, dr.square(bs.pdf) / (dr.square(bs.pdf) + dr.square(pdf_e)), 0.0)
            val = w_bsdf[0] * le[0] * mis
            src = dr.gather(mi.UInt32, lookup, dr.reinterpret_array(mi.UInt32, em2), hit)
            buf = dr.zeros(mi.Float, n_src * HW)
            dr.scatter_reduce(dr.ReduceOp.Add, buf, val, src * HW + pixel, hit)
            acc += np.array(buf).reshape(n_src, HW)
            # one light sample per source
            for k, em in enumerate(self._emitters):
                ds, w_em = em.sample_direction(si, sampler.next_2d(), active)
                ok = active & (ds.pdf > 0)
                ok &= ~self.scene.ray_test(si.spawn_ray_to(ds.p), ok)
                f, pdf_b = bsdf.eval_pdf(ctx, si, si.to_local(ds.d), ok)
                mis = dr.select(ds.delta, 1.0, dr.square(ds.pdf) / (dr.square(ds.pdf) + dr.square(pdf_b)))
                val = dr.select(ok, w_em[0] * f[0] * mis, 0.0)
                acc[k] += np.array(dr.block_sum(val, n_b), dtype=np.float64)
            if progress:
                progress(b + 1, len(batches))
        return (acc / spp).reshape(n_src, H, W).astype(np.float32)
