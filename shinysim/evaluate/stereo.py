"""Scoring structured-highlight stereo: matches and single-camera estimates against both cameras' truth."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..conventions import normalize
from .mirror import exact_highlights, is_analytic, nearest_on_object
from .normals import angular_error_deg, sample_truth
from .stats import distance_stats, summary_stats
from .surface import TruthSurface, matchable_highlights

__all__ = ["NEAR_FIELD_ORACLE", "score_stereo"]


def _stats3(values):
    return summary_stats(values, ("median", "p95", "max", "n"))


def _position_block(dist_mm, pixel_mm):
    s = distance_stats(dist_mm, pixel_mm)
    return {"median": s["median"], "p95": s["p95"], "max": s["max"], "n": s["n"],
            "median_px": s["median_px"], "p95_px": s["p95_px"], "max_px": s["max_px"]}


def _detected_of(exact, table, found_px):
    """Per exact highlight, the index of the nearest detected highlight of its source within ``found_px``
    pixels (-1 where none)."""
    rows, cols = np.asarray(table["row"], float), np.asarray(table["col"], float)
    src = np.asarray(table["source"], np.int64)
    order = np.argsort(src, kind="stable")
    lo = np.searchsorted(src[order], exact.source, "left")
    hi = np.searchsorted(src[order], exact.source, "right")
    out = np.full(len(exact), -1, np.int64)
    for k in np.flatnonzero(hi > lo):
        cand = order[lo[k]:hi[k]]
        d = np.hypot(rows[cand] - exact.row[k], cols[cand] - exact.col[k])
        m = int(np.argmin(d))
        if d[m] <= found_px:
            out[k] = cand[m]
    return out


def _truth_recall(obj, rig, tables, good, pixel_mm, matchable_px, found_px):
    """Recall against the exact highlights of an analytic object (``docs/stereo.md``, "Scoring")."""
    exact = [exact_highlights(obj, rig, k) for k in (0, 1)]
    det = [_detected_of(e, t, found_px) for e, t in zip(exact, tables)]
    vis = [e.visible for e in exact]
    ok, _, _ = matchable_highlights(exact[0].point[vis[0]], exact[0].part[vis[0]], exact[1].point[vis[1]],
                                    exact[1].part[vis[1]], eps_mm=matchable_px * pixel_mm)
    d0 = det[0][vis[0]]
    found = (d0 >= 0) & good[np.where(d0 >= 0, d0, 0)]
    n_ok = int(ok.sum())
    return {
        "recall": float((found & ok).sum() / n_ok) if n_ok else float("nan"),
        "matchable_truth": n_ok,
        "n_matchable_truth_matched": int((found & ok).sum()),
        "n_visible_truth": [int(v.sum()) for v in vis],
        "detection_recall": [float((d[v] >= 0).mean()) if v.any() else float("nan") for d, v in zip(det, vis)],
        "found_px": found_px,
    }


def score_stereo(matches, tables, truths, rig, *, single=None, obj=None, false_tolerance_px: float = 5.0,
                 matchable_px: float = 1.0, found_px: float = 2.0) -> dict[str, Any]:
    """Score stereo matches (and single-camera normals) against the truth of both cameras.

    Parameters
    ----------
    matches : StereoMatches
    tables : (HighlightTable, HighlightTable) (or dicts of columns)
        Each camera's highlights (``row``, ``col``, ``source`` are used), in
        the order the matches index them.
    truths : (Truth, Truth)
    rig : Rig
    obj : ScannedObject, optional
        The object scanned. Where it is made of spheres and facets
        (:func:`~shinysim.evaluate.mirror.is_analytic`), positions and
        normals are scored against its exact surface and ``recall`` against
        its exact highlights; otherwise against the pixel-centre truth, and
        ``recall`` is None (only ``recall_detected`` is known).
    single : dict, optional
        ``{model: [(normals, points) of camera 0, (normals, points) of camera 1]}``:
        single-camera estimates of each highlight, scored the same way.
    false_tolerance_px : float
        A match farther than this (pixel-equivalents) from the true surface
        is false.
    matchable_px : float
        An exact camera-0 highlight is *matchable* when an exact camera-1
        highlight on the same part lies within this many pixel-equivalents
        of it (:func:`shinysim.evaluate.matchable_highlights`); for
        ``recall_detected`` the same test on the detected highlights' true
        elements.
    found_px : float
        An exact highlight is *detected* when a highlight of its source lies
        within this many pixels of it, and *found* when that highlight is in
        a match that is not false.

    Returns
    -------
    dict
        ``position_error_um`` and ``normal_error_deg`` (``median``, ``p95``,
        ``max``) of the accepted matches, ``false_match_rate``, ``recall``
        (of the exact matchable highlights, ``matchable_truth`` of them),
        ``recall_detected`` (of the detected ones), ``detection_recall``
        per camera, counts, and ``single_camera`` per model.

    Notes
    -----
    Position error: distance from a match's point to the true surface (the
    exact one, or the tangent plane of the nearest pixel-centre truth sample
    of either camera). Normal error: angle to the true normal at the foot
    (exact, or interpolated in the truth image). A single-camera
    model's position is where it places the highlight (on the reference
    plane, or on the near-field surface) and its normal error is against
    the true normal at the highlight's own centroid.
    """
    pixel_mm = float(np.mean([c.pixel_pitch for c in rig.cameras[:2]]))
    analytic = obj is not None and is_analytic(obj)
    surface = TruthSurface(truths, spacing_mm=pixel_mm, cameras=rig.cameras[:2])

    def nearest(points):
        # the visible surface from the truth samples; on an analytic part, the exact foot and normal where
        # that foot lies on the visible element (within two samples of the nearest sample)
        dist, normal, part, sample = surface.nearest(points, with_sample=True)
        if analytic:
            d_a, n_a, f_a = nearest_on_object(obj, points, part)
            use = np.linalg.norm(f_a - sample, axis=1) <= 2.0 * pixel_mm
            dist, normal = np.where(use, d_a, dist), np.where(use[:, None], n_a, normal)
        return dist, normal, part

    dist, foot_normal, _ = nearest(matches.point)
    n_err = angular_error_deg(matches.normal, foot_normal) if len(matches) else np.zeros(0)
    false = dist > false_tolerance_px * pixel_mm
    elements = []
    for table, truth in zip(tables, truths):
        _, p, valid = sample_truth(truth, table["row"], table["col"])
        parts = np.array([truth.part_names[i] for i in _parts_at(truth, table["row"], table["col"])], dtype=object)
        parts[~valid] = None
        elements.append((p, parts))
    ok, partner, gap = matchable_highlights(*elements[0], *elements[1], eps_mm=matchable_px * pixel_mm)
    good = np.zeros(len(ok), bool)  # camera-0 highlights in a match that is not false
    good[np.asarray(matches.index1, int)[~false]] = True
    truth_recall = (_truth_recall(obj, rig, tables, good, pixel_mm, matchable_px, found_px) if analytic
                    else {"recall": None, "matchable_truth": None,
                          "recall_basis": "no exact highlights: the object has mesh parts"})
    n_match = int(len(matches))
    out: dict[str, Any] = {
        "pixel_equivalent_um": 1e3 * pixel_mm,
        "n_highlights": [int(len(t["row"])) for t in tables],
        "n_matches": n_match,
        "n_candidates": int(matches.n_candidates),
        "position_error_um": _position_block(dist, pixel_mm),
        "normal_error_deg": _stats3(n_err),
        "false_match_tolerance_px": false_tolerance_px,
        "n_false": int(false.sum()),
        "false_match_rate": float(false.mean()) if n_match else float("nan"),
        "matchable_px": matchable_px,
        **truth_recall,
        "n_matchable": int(ok.sum()),
        "n_matchable_matched": int((good & ok).sum()),
        "recall_detected": float((good & ok).sum() / ok.sum()) if ok.any() else float("nan"),
        "matchable_fraction": float(ok.mean()) if len(ok) else float("nan"),
        "reason": matches.reason,
        "spacing_bound": {
            "normal_turn_deg_per_px": matches.normal_turn_deg_per_px,
            "lattice_gap_px": matches.lattice_gap_px,
            "expected_matchable": matches.expected_matchable,
            "measured_matchable": (truth_recall["matchable_truth"] / truth_recall["n_visible_truth"][0]
                                   if truth_recall.get("matchable_truth") is not None
                                   and truth_recall["n_visible_truth"][0] else None),
        },
    }
    if n_match:
        true_n = normalize(sample_truth(truths[0], matches.row1, matches.col1)[0]
                           + sample_truth(truths[1], matches.row2, matches.col2)[0])
        out["normal_error_at_centroids_deg"] = _stats3(angular_error_deg(matches.normal, true_n))
    if single:
        out["single_camera"] = {}
        matched0 = np.asarray(matches.index1, int) if n_match else np.zeros(0, int)

        def errors(normal_err, dist):
            return {"normal_error_deg": _stats3(normal_err),
                    "position_error_um": _position_block(dist, pixel_mm)}

        for model, per_cam in single.items():
            errs, dists = [], []
            for k, (normals, points) in enumerate(per_cam):
                tn, _, valid = sample_truth(truths[k], tables[k]["row"], tables[k]["col"])
                e = angular_error_deg(normals, tn)
                e[~valid] = np.nan
                errs.append(e)
                dists.append(nearest(points)[0])
            # on the highlights of camera 0 that stereo matched
            out["single_camera"][model] = {
                **errors(np.concatenate(errs), np.concatenate(dists)),
                "on_matched_highlights": errors(errs[0][matched0], dists[0][matched0])}
        rivals = {m: v for m, v in out["single_camera"].items() if m != NEAR_FIELD_ORACLE}
        if rivals and n_match:
            best = min(rivals, key=lambda m: rivals[m]["on_matched_highlights"]["normal_error_deg"]["median"])
            b = rivals[best]["on_matched_highlights"]
            out["best_single_camera"] = best
            # what the second camera buys, on the highlights stereo matched: the best single-camera
            # model's median error over the stereo median (> 1: stereo is better by that factor)
            out["stereo_gain"] = {
                "normal_error_median_ratio": b["normal_error_deg"]["median"] / out["normal_error_deg"]["median"],
                "position_error_median_ratio": (b["position_error_um"]["median"]
                                                / out["position_error_um"]["median"]),
            }
    return out


def _parts_at(truth, rows, cols):
    r = np.clip(np.rint(np.asarray(rows, float)).astype(int), 0, truth.part.shape[0] - 1)
    c = np.clip(np.rint(np.asarray(cols, float)).astype(int), 0, truth.part.shape[1] - 1)
    return truth.part[r, c]


#: The single-camera near-field model given the true height of one highlight: a bound, not a rival.
NEAR_FIELD_ORACLE = "near-field (true anchor)"
