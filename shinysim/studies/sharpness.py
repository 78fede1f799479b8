"""The specularity-sharpness study: highlight size, count, coverage and accuracy.

Paper Section III: "I0 ... implicitly defines the tradeoff between
orientation resolution and sampling density of the orientation space".
Pure functions that render small scenes, reconstruct them and return plain
dicts of numpy arrays; ``notebooks/specularity_sharpness.ipynb`` and the
tests use them:

* :func:`highlight_metrics` measures one stack at one detection setting;
* :func:`sharpness_sweep` sweeps roughness alpha and threshold I0;
* :func:`rig_sweep` sweeps fiber diameter or source spacing.

Units: millimetres and radians in arguments; sizes are reported in
micrometres (``_um``), angles in degrees (``_deg``).

Rendering needs the ``render`` extra with a JIT (llvm/cuda) Mitsuba variant.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..conventions import angle_between
from ..errors import OptionError
from ..io import Stack, Truth
from ..recon.detect import DetectParams
from ..recon.normals import PAPER_MODELS as NORMAL_MODELS
from ..rig import Rig, shiny_1988

__all__ = [
    "SWEEP_KINDS",
    "spacing_rig",
    "lobe_radius_deg",
    "highlight_metrics",
    "sharpness_sweep",
    "rig_sweep",
    "noise_sweep",
]

#: Rig parameters :func:`rig_sweep` can vary.
SWEEP_KINDS = ("fiber_diameter_mm", "spacing_deg")


def spacing_rig(spacing_deg, *, max_polar_deg=84.0, **kwargs):
    """The SHINY rig with sources ``spacing_deg`` apart over about +-84 degrees.

    ``n = 2 floor(max_polar / spacing - 1/2) + 1`` sources at the preset's
    half-step offset angles (:func:`shinysim.rig.shiny_1988_source_angles_deg`):
    21 for 8 degrees, as in the paper. Other keyword arguments go to
    :func:`shinysim.rig.shiny_1988`.
    """
    spacing_deg = float(spacing_deg)
    if not spacing_deg > 0:
        raise OptionError(f"spacing_deg must be > 0, got {spacing_deg!r}")
    n_half = int(np.floor(max_polar_deg / spacing_deg - 0.5 + 1e-9))
    return shiny_1988(spacing_deg=spacing_deg, n_sources=2 * max(n_half, 0) + 1, **kwargs)


def lobe_radius_deg(alpha, threshold, *, distribution="ggx"):
    """Angle between normal and half vector where a microfacet lobe falls to ``threshold``.

    The slope-space shape of the distribution (``docs/theory.md``, section 2):
    GGX ``(a^2 / (a^2 + tan^2 d))^2 = I0`` gives ``tan d = a sqrt(I0^(-1/2) - 1)``;
    Beckmann ``exp(-tan^2 d / a^2) = I0`` gives ``tan d = a sqrt(-ln I0)``. For a
    point source this is the angular radius, in orientation space, of the
    highlight that the threshold I0 keeps; a fiber of angular radius rho
    widens it by about rho / 2.

    Parameters
    ----------
    alpha, threshold : array_like
        Roughness and relative threshold in (0, 1].
    distribution : {"ggx", "beckmann"}

    Returns
    -------
    ndarray, degrees
    """
    a = np.asarray(alpha, dtype=float)
    t = np.asarray(threshold, dtype=float)
    if distribution == "ggx":
        s = np.sqrt(np.maximum(t ** -0.5 - 1.0, 0.0))
    elif distribution == "beckmann":
        s = np.sqrt(np.maximum(-np.log(t), 0.0))
    else:
        raise OptionError(f"distribution must be 'ggx' or 'beckmann', got {distribution!r}")
    return np.degrees(np.arctan(a * s))


def _in_plane_tilt_deg(n):
    """Tilt of normals in the x-z plane from +z, degrees, positive towards +x."""
    return np.degrees(np.arctan2(n[..., 0], n[..., 2]))


def _brightest_per_source(table, keep=None):
    """Row of each source's brightest highlight (largest ``sum``, the first of equals), in source order.

    Only the rows where ``keep`` is true count.
    """
    idx = np.arange(len(table["source"])) if keep is None else np.flatnonzero(keep)
    order = idx[np.lexsort((-table["sum"][idx], table["source"][idx]))]
    return order[np.unique(table["source"][order], return_index=True)[1]]


def _union_length(intervals):
    if not intervals:
        return 0.0
    iv = sorted(intervals)
    total, (lo, hi) = 0.0, iv[0]
    for a, b in iv[1:]:
        if a > hi:
            total += hi - lo
            lo, hi = a, b
        else:
            hi = max(hi, b)
    return total + hi - lo


def highlight_metrics(stack: Stack, truth: Truth, params: DetectParams, *,
                      models: tuple[str, ...] = NORMAL_MODELS) -> dict[str, Any]:
    """Size, count, coverage and accuracy of the highlights of one stack.

    Highlights are found as :func:`shinysim.recon.reconstruct` finds them
    (threshold I0 relative to each frame's peak, connected regions at least
    ``min_area`` pixels, intensity-weighted centroids). Only highlights whose
    centroid lies on the object are scored.

    Parameters
    ----------
    stack : shinysim.io.Stack
        A scan of a convex object (the calibration sphere) by a rig whose
        sources lie in the x-z plane.
    truth : shinysim.io.Truth
    params : DetectParams
    models : sequence of str

    Returns
    -------
    dict
        ``n_highlights`` (connected regions kept), ``n_sources_found``
        (sources with at least one), ``n_sources``; ``area_px`` (median area
        of each source's largest highlight), ``diameter_um`` (the diameter
        of a disc of that area on the reference plane);
        ``orientation_spread_deg``: RMS angle between the true normals of a
        highlight's pixels and the true normal at its centroid -- how much
        of the orientation space one highlight stands for (the paper's
        orientation resolution; smaller is sharper); ``coverage``: fraction
        of the in-plane tilt range of the array's peak normals (first to
        last, widened by a quarter of the source spacing on each side) that
        the union of the highlights' pixel normals covers -- the sampling
        density of the orientation space; and per model (dicts):
        ``median_error_deg``, ``p95_error_deg`` (recovered normal against
        the true normal at the centroid) and ``pixel_error_deg`` (RMS angle
        between each highlight's recovered normal and the true normals of
        all its pixels: the error if the normal is given to the whole
        highlight).
    """
    from ..evaluate import sample_truth
    from ..recon import reconstruct

    rig, cam = stack.rig, stack.camera
    rec = reconstruct(stack, params, models=models)
    t = rec.table
    tn_c, _, valid = sample_truth(truth, t["row"], t["col"])
    n_src = stack.n_sources
    # pixels of each highlight: its whole region, as detection measured it
    spread_sq, pix_err_sq = [], {m: [] for m in models}
    intervals = []
    for i in np.argsort(t["source"], kind="stable"):
        if not valid[i]:
            continue
        coords = rec.regions.coords(rec.region[i])
        inside = truth.mask[coords[:, 0], coords[:, 1]]
        npix = truth.normals[coords[inside, 0], coords[inside, 1]].astype(np.float64)
        if not len(npix):
            continue
        spread_sq.append(np.degrees(angle_between(npix, tn_c[i])) ** 2)
        for m in models:
            pix_err_sq[m].append(np.degrees(angle_between(npix, rec.normals[m][i])) ** 2)
        tilt = _in_plane_tilt_deg(npix)
        intervals.append((float(tilt.min()), float(tilt.max())))
    # coverage of the array's range of peak normals (in-plane tilt = half the source angle)
    angles = np.degrees(np.arctan2(rig.source_positions[:, 0], rig.source_positions[:, 2]))
    spacing = float(np.median(np.diff(np.sort(angles)))) if n_src > 1 else 0.0
    lo, hi = 0.5 * angles.min() - 0.25 * spacing, 0.5 * angles.max() + 0.25 * spacing
    clipped = [(max(a, lo), min(b, hi)) for a, b in intervals if b > lo and a < hi]
    coverage = _union_length(clipped) / (hi - lo) if hi > lo else float("nan")
    areas = t["area"][_brightest_per_source(t)].astype(float)
    area = float(np.median(areas)) if areas.size else float("nan")
    out = {
        "n_highlights": int(len(rec)),
        "n_sources_found": int(len(areas)),
        "n_sources": int(n_src),
        "area_px": area,
        "diameter_um": float(2e3 * np.sqrt(area / np.pi) * cam.pixel_pitch) if areas.size else float("nan"),
        "orientation_spread_deg": float(np.sqrt(np.mean(np.concatenate(spread_sq)))) if spread_sq else float("nan"),
        "coverage": float(coverage),
        "median_error_deg": {},
        "p95_error_deg": {},
        "pixel_error_deg": {},
    }
    for m in models:
        e = np.degrees(angle_between(rec.normals[m][valid], tn_c[valid]))
        e = e[np.isfinite(e)]
        out["median_error_deg"][m] = float(np.median(e)) if e.size else float("nan")
        out["p95_error_deg"][m] = float(np.percentile(e, 95)) if e.size else float("nan")
        sq = pix_err_sq[m]
        out["pixel_error_deg"][m] = float(np.sqrt(np.mean(np.concatenate(sq)))) if sq else float("nan")
    return out


def _stack_metrics(results, shape):
    """Collect a list of :func:`highlight_metrics` dicts into arrays of ``shape``."""
    out = {}
    for key, v in results[0].items():
        if isinstance(v, dict):
            out[key] = {m: np.array([r[key][m] for r in results]).reshape(shape) for m in v}
        else:
            out[key] = np.array([r[key] for r in results]).reshape(shape)
    return out


def _detect(threshold, min_area):
    return DetectParams(threshold=float(threshold), min_area=int(min_area))


def sharpness_sweep(alphas: Sequence[float], thresholds: Sequence[float], *, rig: Rig | None = None,
                    resolution: int = 128, spp: int = 16, seed: int = 0, min_area: int = 2, distribution: str = "ggx",
                    method: str | None = None, variant: str | None = None, keep_frames: bool = False,
                    progress: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """Highlight size, count and accuracy against roughness alpha and threshold I0.

    One scene (the calibration sphere under ``rig``), one truth render, one
    stack per alpha (roughness changed in place); every threshold is applied
    to the same stack.

    Parameters
    ----------
    alphas : (n_alpha,) array_like
        Rough-conductor roughness values.
    thresholds : (n_I0,) array_like
        Relative thresholds I0 in (0, 1].
    rig : Rig, optional
        Default ``shiny_1988(resolution=resolution)``.
    resolution, spp, seed : int
    min_area : int
        Smallest highlight kept, pixels (rejects single noisy pixels).
    distribution : {"ggx", "beckmann"}
    method : str, optional
        Stack renderer (default: the simulator's).
    variant : str, optional
    keep_frames : bool
        Also return the stacks' frames, ``(n_alpha, n_sources, H, W)``.
    progress : callable, optional
        ``progress(done, total)`` after each alpha.

    Returns
    -------
    dict
        ``alpha`` (n_alpha,), ``threshold`` (n_I0,), every key of
        :func:`highlight_metrics` as an (n_alpha, n_I0) array (or a dict of
        them per model), ``settings``; with ``keep_frames`` also ``frames``
        and ``truth_mask``.
    """
    from ..sim.render import Simulator
    from ..sim.objects import scene_objects

    alphas, thresholds = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (alphas, thresholds))
    rig = shiny_1988(resolution=resolution) if rig is None else rig
    sim = Simulator(rig, scene_objects("sphere", alpha=float(alphas[0]), distribution=distribution), variant=variant)
    truth = sim.render_truth()
    results, frames = [], []
    for i, a in enumerate(alphas):
        sim.set_alpha(float(a))
        stack = sim.render_stack(spp=spp, seed=seed, method=method)
        if keep_frames:
            frames.append(stack.frames)
        results += [highlight_metrics(stack, truth, _detect(t, min_area)) for t in thresholds]
        if progress:
            progress(i + 1, len(alphas))
    out = {"alpha": alphas, "threshold": thresholds, **_stack_metrics(results, (len(alphas), len(thresholds)))}
    out["settings"] = {"resolution": rig.camera.width, "spp": spp, "seed": seed, "min_area": min_area,
                       "distribution": distribution, "n_sources": rig.n_sources,
                       "pixel_pitch_mm": rig.camera.pixel_pitch}
    if keep_frames:
        out["frames"] = np.stack(frames)
        out["truth_mask"] = truth.mask
    return out


def rig_sweep(kind: str, values: Sequence[float], *, alpha: float = 0.02, thresholds: Sequence[float] = (0.5,),
              resolution: int = 128, spp: int = 16, seed: int = 0, min_area: int = 2, distribution: str = "ggx",
              method: str | None = None, variant: str | None = None,
              progress: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """Highlight size, count and accuracy against fiber diameter or source spacing.

    Parameters
    ----------
    kind : {"fiber_diameter_mm", "spacing_deg"}
        ``"fiber_diameter_mm"``: the SHINY rig with every fiber this wide;
        ``"spacing_deg"``: :func:`spacing_rig` (sources that far apart over
        about +-84 degrees).
    values : (n,) array_like
    alpha : float
        Sphere roughness.
    thresholds : (n_I0,) array_like
    resolution, spp, seed, min_area, distribution, method, variant, progress
        As in :func:`sharpness_sweep`.

    Returns
    -------
    dict
        ``kind``, ``values`` (n,), ``threshold`` (n_I0,), ``n_sources_rig``
        (n,), every key of :func:`highlight_metrics` as (n, n_I0) arrays,
        ``settings``.
    """
    from ..sim.render import Simulator
    from ..sim.objects import scene_objects

    if kind not in SWEEP_KINDS:
        raise OptionError(f"kind must be one of {SWEEP_KINDS}, got {kind!r}")
    values, thresholds = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (values, thresholds))
    results, n_sources = [], []
    for i, v in enumerate(values):
        if kind == "fiber_diameter_mm":
            if not v > 0:
                raise OptionError(f"fiber diameters must be > 0 mm, got {v!r}")
            rig = shiny_1988(resolution=resolution, fiber_diameter_mm=float(v))
        else:
            rig = spacing_rig(v, resolution=resolution)
        n_sources.append(rig.n_sources)
        sim = Simulator(rig, scene_objects("sphere", alpha=alpha, distribution=distribution), variant=variant)
        truth = sim.render_truth()
        stack = sim.render_stack(spp=spp, seed=seed, method=method)
        results += [highlight_metrics(stack, truth, _detect(t, min_area)) for t in thresholds]
        if progress:
            progress(i + 1, len(values))
    out = {"kind": kind, "values": values, "threshold": thresholds, "n_sources_rig": np.array(n_sources),
           **_stack_metrics(results, (len(values), len(thresholds)))}
    out["settings"] = {"alpha": alpha, "resolution": resolution, "spp": spp, "seed": seed, "min_area": min_area,
                       "distribution": distribution}
    return out


def noise_sweep(alphas: Sequence[float], thresholds: Sequence[float], *, sensor: str = "machine_vision_12bit",
                exposure: float = 0.8, seeds: Sequence[int] = (0, 1, 2, 3, 4), resolution: int = 128, spp: int = 16,
                min_area: int = 2, distribution: str = "ggx", variant: str | None = None,
                progress: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """Repeatability and accuracy of the normals under sensor noise, against alpha and I0.

    One ideal stack per alpha is digitised by ``sensor`` (exposed so that
    its brightest pixel fills ``exposure`` of the full well) with each noise
    seed, and detected at each threshold I0. For every source the normal of
    its largest highlight under the near-field model (anchored at the
    sphere's apex) is compared across the seeds.

    Returns
    -------
    dict
        ``alpha``, ``threshold``, and (n_alpha, n_I0) arrays:
        ``repeatability_deg`` (RMS over sources of the RMS angle between a
        source's normals and their mean over the seeds: the noise's share),
        ``median_error_deg`` (median over sources and seeds of the angle to
        the true normal at the centroid), ``found`` (fraction of source and
        seed pairs with a highlight), and ``settings``.
    """
    from ..evaluate import sample_truth
    from ..recon import reconstruct
    from ..sim.render import Simulator
    from ..sim.objects import scene_objects
    from ..sim.sensor import sensor_preset
    from .scan import sphere_scan_rig

    alphas, thresholds = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (alphas, thresholds))
    rig = sphere_scan_rig(resolution=resolution)
    camera = sensor_preset(sensor)
    sim = Simulator(rig, scene_objects("sphere", alpha=float(alphas[0]), distribution=distribution), variant=variant)
    truth = sim.render_truth()
    shape = (len(alphas), len(thresholds))
    rep, err, found = np.full(shape, np.nan), np.full(shape, np.nan), np.zeros(shape)
    n_src = rig.n_sources
    for i, a in enumerate(alphas):
        sim.set_alpha(float(a))
        ideal = sim.render_stack(spp=spp, seed=0)
        exposed = camera.exposed_for(float(ideal.frames.max()), fraction=exposure)
        stacks = [exposed.expose(ideal, seed=int(s)) for s in seeds]
        for j, t in enumerate(thresholds):
            normals = np.full((len(seeds), n_src, 3), np.nan)
            errors = []
            for si, stack in enumerate(stacks):
                rec = reconstruct(stack, _detect(t, min_area), models=("near-field",))
                tab = rec.table
                if not len(rec) or "near-field" not in rec.normals:
                    continue
                tn, _, valid = sample_truth(truth, tab["row"], tab["col"])
                for main in _brightest_per_source(tab, valid):
                    normals[si, tab["source"][main]] = rec.normals["near-field"][main]
                    errors.append(float(np.degrees(angle_between(rec.normals["near-field"][main], tn[main]))))
            ok = np.all(np.isfinite(normals), axis=2)
            found[i, j] = ok.mean()
            spreads = []
            for k in range(n_src):
                nk = normals[ok[:, k], k]
                if len(nk) >= 2:
                    mean = nk.mean(axis=0)
                    mean /= np.linalg.norm(mean)
                    spreads.append(np.mean(np.degrees(angle_between(nk, mean)) ** 2))
            rep[i, j] = float(np.sqrt(np.mean(spreads))) if spreads else np.nan
            err[i, j] = float(np.median(errors)) if errors else np.nan
        if progress:
            progress(i + 1, len(alphas))
    return {
        "alpha": alphas, "threshold": thresholds, "repeatability_deg": rep, "median_error_deg": err,
        "found": found,
        "settings": {"sensor": sensor, "exposure": exposure, "seeds": [int(s) for s in seeds],
                     "resolution": resolution, "spp": spp, "min_area": min_area, "distribution": distribution},
    }
