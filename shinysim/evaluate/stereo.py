"""Scoring structured-highlight stereo: matches and single-camera estimates against both cameras' truth."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..conventions import normalize
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


def score_stereo(matches, tables, truths, rig, *, single=None, false_tolerance_px: float = 5.0,
                 matchable_px: float = 1.0) -> dict[str, Any]:
    """Score stereo matches (and single-camera normals) against the truth of both cameras.

    Parameters
    ----------
    matches : StereoMatches
    tables : (HighlightTable, HighlightTable) (or dicts of columns)
        Each camera's highlights (``row``, ``col``, ``source`` are used), in
        the order the matches index them.
    truths : (Truth, Truth)
    rig : Rig
    single : dict, optional
        ``{model: [(normals, points) of camera 0, (normals, points) of camera 1]}``:
        single-camera estimates of each highlight, scored the same way.
    false_tolerance_px : float
        A match farther than this (pixel-equivalents) from the true surface
        is false.
    matchable_px : float
        A camera-0 highlight is *matchable* when a camera-1 highlight's true
        element lies within this many pixel-equivalents of its own
        (:func:`shinysim.evaluate.matchable_highlights`).

    Returns
    -------
    dict
        ``position_error_um`` and ``normal_error_deg`` (``median``, ``p95``,
        ``max``) of the accepted matches, ``false_match_rate``, ``recall``,
        counts, and ``single_camera`` per model.

    Notes
    -----
    Position error: distance from a match's point to the true surface (the
    tangent plane of the nearest pixel-centre truth sample of either
    camera). Normal error: angle to the true normal there. A single-camera
    model's position is where it places the highlight (on the reference
    plane, or on the near-field surface) and its normal error is against
    the true normal at the highlight's own centroid.
    """
    pixel_mm = float(np.mean([c.pixel_pitch for c in rig.cameras[:2]]))
    surface = TruthSurface(truths, spacing_mm=pixel_mm)
    dist, foot_normal, _ = surface.nearest(matches.point)
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
        "n_matchable": int(ok.sum()),
        "n_matchable_matched": int((good & ok).sum()),
        "recall": float((good & ok).sum() / ok.sum()) if ok.any() else float("nan"),
        "matchable_fraction": float(ok.mean()) if len(ok) else float("nan"),
        "reason": matches.reason,
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
                dists.append(surface.nearest(points)[0])
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
