"""Scoring coded scans: decoded highlights against the sequential scan's, pixels against their owners, coverage."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..conventions import angle_between
from .stats import summary_stats

__all__ = ["pixel_owner", "pair_highlights", "decoding_errors", "reachable_mask", "coverage", "normal_differences",
           "source_directions", "part_mask", "score_heights", "empty_coverage"]


def pixel_owner(frames: np.ndarray) -> np.ndarray:
    """(H, W) int64: the source giving each pixel the most light in ideal per-source frames, -1 where none does."""
    f = np.asarray(frames)
    best = f.max(axis=0)
    return np.where(best > 0, f.argmax(axis=0), -1).astype(np.int64)


def _nearest(points, queries, exclude_self=False, block=2048):
    """Distance to, and index of, the nearest of ``points`` for each query (brute force in blocks)."""
    d_out = np.empty(len(queries))
    j_out = np.empty(len(queries), int)
    for a in range(0, len(queries), block):
        q = queries[a:a + block]
        d2 = np.sum((q[:, None, :] - points[None, :, :]) ** 2, axis=-1)
        if exclude_self:
            d2[np.arange(len(q)), a + np.arange(len(q))] = np.inf
        j = np.argmin(d2, axis=1)
        j_out[a:a + block] = j
        d_out[a:a + block] = np.sqrt(d2[np.arange(len(q)), j])
    return d_out, j_out


def pair_highlights(table: dict, reference: dict, *, radius_px: float | None = None) -> dict[str, Any]:
    """Pair each highlight of ``table`` with the nearest ``reference`` highlight within a radius.

    A table highlight left unpaired that is the merge of reference
    highlights of its own source (two or more, none paired otherwise,
    within 3 px of it, their centroid weighted by their ``sum`` within the
    radius of it) is paired with all of them: a region the reference
    detection split where a pixel fell just below its level (the
    decoded signal holds the crosstalk of other sources, which lifts such a
    pixel over it) is one highlight there, at the pieces' centroid.

    Parameters
    ----------
    table, reference : HighlightTable (or a dict of columns)
        A decoded scan's and the sequential scan's (``row``, ``col``,
        ``source``; ``sum`` weights a merge's pieces, equal weights without
        it).
    radius_px : float, optional
        Pairing radius, pixels. Default: half the smallest distance between
        two reference highlights (each table highlight is then near at most
        one of them), at most 3 px.

    Returns
    -------
    dict
        ``partner`` ((N,) int: reference row, the brightest piece for a
        merge, -1 unpaired), ``distance_px``, ``radius_px``, ``paired``,
        ``errors`` (paired with another source), ``spurious`` (unpaired
        table rows), ``missed`` (reference rows no table row is paired
        with), ``merged`` (reference rows paired through a merge),
        ``error_rate`` (errors / paired).
    """
    t_rc = np.stack([np.asarray(table["row"], float), np.asarray(table["col"], float)], 1)
    r_rc = np.stack([np.asarray(reference["row"], float), np.asarray(reference["col"], float)], 1)
    if radius_px is None:
        if len(r_rc) > 1:
            d, _ = _nearest(r_rc, r_rc, exclude_self=True)
            radius_px = float(min(3.0, 0.5 * d.min()))
        else:
            radius_px = 3.0
    partner = np.full(len(t_rc), -1)
    dist = np.full(len(t_rc), np.inf)
    if len(t_rc) and len(r_rc):
        d, j = _nearest(r_rc, t_rc)
        ok = d <= radius_px
        partner[ok] = j[ok]
        dist = d
    src_r = np.asarray(reference["source"])
    src_t = np.asarray(table["source"])
    found = np.zeros(len(r_rc), bool)
    found[partner[partner >= 0]] = True
    weight = np.asarray(reference.get("sum", np.ones(len(r_rc))), float)
    merged = 0
    for t in np.flatnonzero(partner < 0):
        g = np.flatnonzero(~found & (src_r == src_t[t]) & (np.linalg.norm(r_rc - t_rc[t], axis=1) <= 3.0))
        if len(g) < 2 or np.linalg.norm(weight[g] @ r_rc[g] / weight[g].sum() - t_rc[t]) > radius_px:
            continue
        partner[t] = g[np.argmax(weight[g])]
        dist[t] = np.linalg.norm(r_rc[partner[t]] - t_rc[t])
        found[g] = True
        merged += len(g)
    paired = partner >= 0
    errors = paired & (src_t != src_r[np.where(paired, partner, 0)]) if len(src_r) else paired
    n_pair = int(paired.sum())
    return {"partner": partner, "distance_px": dist, "radius_px": float(radius_px), "paired": n_pair,
            "errors": int(errors.sum()), "error_rows": np.flatnonzero(errors), "spurious": int((~paired).sum()),
            "missed": int((~found).sum()), "merged": merged,
            "error_rate": float(errors.sum() / n_pair) if n_pair else float("nan")}


def decoding_errors(dec, owner: np.ndarray, sequential: dict, *, radius_px: float | None = None) -> dict:
    """Decoding scores: highlights paired with the sequential scan's (:func:`pair_highlights`) and pixels against owners.

    Returns
    -------
    dict
        The pairing's counts (without per-row arrays), ``pixels_decoded``,
        ``pixel_errors`` (decoded as another source than the pixel's owner)
        and ``pixel_error_rate``, and the decoder's ``counts``.
    """
    pairs = pair_highlights(dec.table, sequential, radius_px=radius_px)
    lab = dec.labels
    decoded = lab >= 0
    wrong = decoded & (lab != owner)
    out = {k: v for k, v in pairs.items() if k not in ("partner", "distance_px", "error_rows")}
    out.update(highlights=len(dec.table["source"]), sequential_highlights=len(sequential["source"]),
               pixels_decoded=int(decoded.sum()), pixel_errors=int(wrong.sum()),
               pixel_error_rate=float(wrong.sum() / decoded.sum()) if decoded.any() else float("nan"),
               counts=dict(dec.counts))
    return out


def source_directions(rig) -> np.ndarray:
    """(n_sources, 3) unit directions of a rig's sources seen from the origin."""
    pos = rig.source_positions
    return pos / np.linalg.norm(pos, axis=1, keepdims=True)


def reachable_mask(truth, rig, parts=None) -> np.ndarray:
    """(H, W) bool: visible pixels whose normal a source of the rig's cap can light.

    A pixel is reachable when its view ray, mirrored at its true normal,
    leaves at a polar angle no larger than the rig's largest source polar
    angle (seen from the origin). For a sphere under an axial camera that
    is the disc of radius ``R sin(a / 2)``.
    """
    cam = rig.camera
    mask = part_mask(truth, parts)
    n = truth.normals.astype(float)
    v = cam.view_directions(truth.positions.astype(float))
    r = 2 * np.sum(n * v, axis=-1, keepdims=True) * n - v
    rim = float(np.max(np.arccos(np.clip(source_directions(rig)[:, 2], -1, 1))))
    with np.errstate(invalid="ignore"):
        return mask & (np.arccos(np.clip(r[..., 2], -1, 1)) <= rim)


def part_mask(truth, parts) -> np.ndarray:
    """(H, W) bool: the truth's object pixels on ``parts`` (every object pixel without parts)."""
    if not parts:
        return truth.mask.copy()
    ids = [i for i, name in enumerate(truth.part_names) if name in parts]
    return truth.mask & np.isin(truth.part, ids)


def coverage(truth, rig, surface, parts=None) -> dict[str, float]:
    """Share of the visible and of the reachable surface inside the highlights' triangles.

    Parameters
    ----------
    truth : Truth
    rig : Rig
    surface : SparseSurface
        From the highlights' surface points and normals.
    parts : sequence of str, optional
        Truth parts that make the surface (default: every object pixel).

    Returns
    -------
    dict
        ``visible`` and ``reachable`` (fractions), ``reachable_of_visible``
        (the share a perfect scan could reach), the pixel counts, and the
        rig's rim polar angle ``rim_deg`` with the sphere value
        ``sin^2(rim / 2)``.
    """
    vis = part_mask(truth, parts)
    reach = reachable_mask(truth, rig, parts)
    xy = truth.positions[..., :2].astype(float)
    inside = np.zeros(vis.shape, bool)
    z = surface.heights_at(xy[vis], relative=True)
    inside[vis] = np.isfinite(z)
    rim = float(np.degrees(np.max(np.arccos(np.clip(source_directions(rig)[:, 2], -1, 1)))))
    nv, nr = int(vis.sum()), int(reach.sum())
    return {"visible": float(inside.sum() / nv) if nv else float("nan"),
            "reachable": float((inside & reach).sum() / nr) if nr else float("nan"),
            "reachable_of_visible": float(nr / nv) if nv else float("nan"),
            "pixels_visible": nv, "pixels_reachable": nr, "pixels_covered": int(inside.sum()),
            "rim_deg": rim, "sphere_reachable_theory": float(math.sin(math.radians(rim / 2)) ** 2)}


def normal_differences(a, b) -> dict[str, Any]:
    """``n``, ``median_deg``, ``p95_deg``, ``max_deg`` of the angles between two sets of (N, 3) normals."""
    d = np.degrees(angle_between(np.asarray(a, float), np.asarray(b, float)))
    return summary_stats(d, ("n", "median", "p95", "max"), key="{}_deg")


def score_heights(surface, truth, parts, scale_mm: float) -> dict[str, Any]:
    """An anchored height map (a ``SparseSurface``) against the truth at every covered pixel of ``parts``.

    No offset is removed. ``height_rms_mm`` / ``_pct`` (of ``scale_mm``)
    and ``height_max_mm`` with the heights between the points interpolated
    with the points' normals (``heights_at(..., interpolation="normals")``,
    exact on quadratic surfaces); ``height_rms_linear_mm`` / ``_pct`` the
    same with plane facets; the surface's counts.
    """
    vis = part_mask(truth, parts)
    pts = truth.positions[vis].astype(float)
    z = surface.heights_at(pts[:, :2], interpolation="normals")
    e = z - pts[:, 2]
    e = e[np.isfinite(e)]
    lin = surface.heights_at(pts[:, :2]) - pts[:, 2]
    rms = summary_stats(lin, ("rms",))["rms"]
    out = {"height_rms_mm": summary_stats(e, ("rms",))["rms"],
           "height_max_mm": summary_stats(np.abs(e), ("max",))["max"],
           "interpolation": "normals",
           "height_rms_linear_mm": rms,
           "pixels": int(e.size), "scale_mm": float(scale_mm), "points": int(len(surface.xy)),
           "components": len(surface.components), "floating": len(surface.floating),
           "edges_dropped": int(surface.dropped.get("long_edges", 0))}
    out["height_rms_pct"] = 100.0 * out["height_rms_mm"] / scale_mm
    out["height_rms_linear_pct"] = 100.0 * out["height_rms_linear_mm"] / scale_mm
    return out


def empty_coverage(truth, rig, parts, why: str) -> dict[str, Any]:
    """:func:`coverage` of a scan with no surface (too few points): nothing covered, and ``why``."""
    vis, reach = part_mask(truth, parts), reachable_mask(truth, rig, parts)
    return {"visible": 0.0, "reachable": 0.0 if reach.any() else float("nan"),
            "reachable_of_visible": float(reach.sum() / max(vis.sum(), 1)),
            "pixels_visible": int(vis.sum()), "pixels_reachable": int(reach.sum()),
            "pixels_covered": 0, "note": why}
