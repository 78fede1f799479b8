r"""Solder inspection under nuisance variation, with classes decided by criteria.

``shinysim inspect --out DIR`` runs :func:`run_inspection`: classes come from
:func:`shinysim.objects.criteria.judge` on each joint's exact geometry (wetted
joints drawn from one broad distribution, :data:`WETTED_RANGES`), nuisances
vary in every draw (:data:`NUISANCE_RANGES`), the reconstruction is not told
the pad height, and :func:`robustness_table` tests a classifier outside the
part of a nuisance's range it was trained on. Everything goes to
``DIR/inspection_report.json``, ``DIR/robustness.csv`` and
``DIR/timing.json``; the same seed gives byte-identical reports. Why, and
the measured numbers: ``docs/solder.md``, section "Inspection under
nuisances".
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
import os
import time
from pathlib import Path
from statistics import NormalDist
from typing import Any

import numpy as np

from .._shared import (
    Progress,
    check_choice,
    derive_seed,
    json_safe,
    output_folder,
    write_bytes,
    write_json,
)
from ..errors import OptionError
from ..evaluate import profile_stats
from ..objects.criteria import CLASSES, AcceptanceCriteria, judge
from ..objects.solder import (
    COMMON_RANGES,
    LEAD_SHAPES,
    LEAD_TYPES,
    PARAM_RANGES,
    JointParams,
)
from ..recon.classify import accuracy, confusion_report, feature_matrix, train_classifier
from ..recon.joint import FEATURE_NAMES, JointAnalysisParams
from ..recon.profile import ProfileParams
from .solder import _check_study_options, _meshed_joint, scan_and_analyse

__all__ = [
    "WETTED_RANGES",
    "NUISANCE_RANGES",
    "SENSORS",
    "DESIGN_FEATURES",
    "INSPECTION_FEATURES",
    "CRITERION_FEATURES",
    "QUADRATIC_OF",
    "L2_GRID",
    "inspection_features",
    "INSPECTION_ANALYSIS",
    "INSPECTION_FILES",
    "draw_inspection_joint",
    "wilson_interval",
    "robustness_table",
    "run_inspection",
    "summary_lines",
]

_D = math.radians

#: Shape ranges of the wetted joints (good, insufficient and excess by the
#: criteria): wide enough to cross the boundaries (mm, radians).
WETTED_RANGES = {
    "fillet_height": (0.03, 0.36),
    "contact_angle_pad": (_D(4.0), _D(40.0)),
    "lead_slope_angle": (_D(-20.0), _D(75.0)),
    "lead_lift": (0.0, 0.02),
}

#: The camera sensor presets drawn from (equally likely).
SENSORS = ("machine_vision_12bit", "tv_1980s_8bit")

#: Nuisance ranges, drawn uniformly for every joint (the sensor from :data:`SENSORS`).
NUISANCE_RANGES = {
    "solder_alpha": (0.02, 0.05),        # GGX roughness of the solder surface
    "fiber_diameter_mm": (0.762, 1.27),  # 0.030 - 0.050 in, about the paper's 0.040 in
    "exposure": (0.5, 1.5),              # brightest pixel / full well (above 1: clipped)
    "pad_thickness": (0.025, 0.045),     # design 0.035 mm +- 10 um, unknown to the reconstruction
    "lead_offset": (-0.05, 0.05),        # lead placement along x, mm
    "pad_offset": (-0.05, 0.05),         # pad position along x, mm
}

#: Reconstruction settings of the study. The profile joins measured points
#: up to 0.3 mm apart and anchors a segment up to 0.15 mm from the toe
#: (the paper-setting defaults: 0.1 and 0.06 mm): a gently curved fillet
#: (radius up to about 2 mm) lit by fibers 8 deg apart, whose normals step by
#: 4 deg, puts consecutive highlights R * 0.07 rad = 0.14 mm apart, twice that
#: where one of them is too dim to take.
INSPECTION_ANALYSIS = JointAnalysisParams(profile=ProfileParams(
    max_gap_mm=0.3, max_angle_deg=20.0, merge_mm=0.003, smooth_mm=0.004, anchor_gap_mm=0.15, end_fit_points=5))

#: Design-data features an inspection system knows per joint (from the part
#: library), appended to the image features.
DESIGN_FEATURES = ("j_lead",)
#: Features that set a measurement against the criteria, with the design
#: data: the slope of the profile's last and of its least steep measured
#: point against ``90 deg - leg angle`` (where the wetting angle on the
#: lead's leg would be 90 deg; the leg angle of each lead type comes from the
#: part library), and the height of the profile's end over its highest point
#: (a ball descends back to the pad; a fillet ends on the lead).
CRITERION_FEATURES = ("end_slope_margin_deg", "min_slope_margin_deg", "end_to_max_height")
#: Products of these image features (all pairs and squares) let the linear
#: classifier draw curved class boundaries (e.g. a low height matters more on
#: a steep profile).
QUADRATIC_OF = ("height_max_mm", "phi_last_deg", "phi_min_deg", "phi_first_deg", "curvature_per_mm", "n_points")
_PAIRS = tuple(itertools.combinations_with_replacement(QUADRATIC_OF, 2))
#: Classifier columns: the image features of :func:`~shinysim.recon.joint.joint_features`,
#: the design data, the criterion features and the products.
INSPECTION_FEATURES = (tuple(FEATURE_NAMES) + DESIGN_FEATURES + CRITERION_FEATURES
                       + tuple(f"{a}*{b}" for a, b in _PAIRS))
#: L2 penalties tried; the one with the best 5-fold cross-validated accuracy
#: on the training joints is used (ties: the larger).
L2_GRID = (0.01, 0.03, 0.1, 0.3)
#: Files :func:`run_inspection` writes.
INSPECTION_FILES = ("inspection_report.json", "robustness.csv", "timing.json")

SPLITS = ("train", "test")
_FAMILY = {"good": "good", "insufficient": "good", "excess": "good", "lifted": "lifted", "bridge": "bridge"}
_GEOMETRY_NUISANCES = ("pad_thickness", "lead_offset", "pad_offset")


def _family_ranges(family):
    if family == "good":
        return {**COMMON_RANGES, **WETTED_RANGES}
    if family == "bridge":
        bridge_only = {k: PARAM_RANGES["bridge"][k] for k in ("bridge_height", "bridge_length", "neighbour_pitch")}
        return {**COMMON_RANGES, **WETTED_RANGES, **bridge_only}
    return {**COMMON_RANGES, **PARAM_RANGES["lifted"]}


def draw_inspection_joint(label, rng, *, criteria=None, max_tries=20000):
    """Draw a joint that the criteria put in class ``label``, with its nuisances.

    Parameters
    ----------
    label : str
        One of :data:`~shinysim.objects.criteria.CLASSES`.
    rng : numpy.random.Generator
    criteria : AcceptanceCriteria, optional
    max_tries : int

    Returns
    -------
    params : JointParams
    nuisances : dict
        ``sensor`` and the values of :data:`NUISANCE_RANGES`.
    judgement : shinysim.objects.criteria.Judgement
    """
    check_choice("label", label, CLASSES)
    family = _FAMILY[label]
    ranges = _family_ranges(family)
    last = None
    for _ in range(max_tries):
        values = {name: float(rng.uniform(lo, hi)) for name, (lo, hi) in ranges.items()}
        lead_type = LEAD_TYPES[int(rng.integers(len(LEAD_TYPES)))]
        nuis = {name: float(rng.uniform(lo, hi)) for name, (lo, hi) in NUISANCE_RANGES.items()}
        nuis["sensor"] = SENSORS[int(rng.integers(len(SENSORS)))]
        values.update({k: nuis[k] for k in _GEOMETRY_NUISANCES})
        try:
            params = JointParams(kind=family, lead_type=lead_type, **values)
            verdict = judge(params, criteria)
        except ValueError as exc:  # not a joint (foot off the pad, solder into the lead, ...)
            last = exc
            continue
        if verdict.label == label:
            return params, nuis, verdict
    raise RuntimeError(f"no {label!r} joint in {max_tries} draws (last rejection: {last})")


def wilson_interval(k, n, confidence=0.95):
    """Wilson score interval of a proportion ``k / n``; ``(nan, nan)`` for ``n = 0``."""
    if n <= 0:
        return (float("nan"), float("nan"))
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return (max(0.0, c - h), min(1.0, c + h))


def _accuracy_entry(y_true, y_pred):
    y_true, y_pred = list(y_true), list(y_pred)
    k = sum(a == b for a, b in zip(y_true, y_pred))
    n = len(y_true)
    lo, hi = wilson_interval(k, n)
    return {"n": n, "correct": k, "accuracy": (k / n) if n else None,
            "ci95": [lo, hi] if n else None}


def inspection_features(records):
    """(N, F) classifier matrix of joint records, columns :data:`INSPECTION_FEATURES`.

    Parameters
    ----------
    records : list of dict
        Each with ``features`` (:func:`~shinysim.recon.joint.joint_features`)
        and ``lead_type`` (design data).
    """
    X = feature_matrix([r["features"] for r in records], FEATURE_NAMES)
    col = {name: X[:, k] for k, name in enumerate(FEATURE_NAMES)}
    j_lead = np.array([1.0 if r["lead_type"] == "j-lead" else 0.0 for r in records])
    level = np.array([90.0 - math.degrees(LEAD_SHAPES[r["lead_type"]].leg_angle) for r in records])
    hmax = col["height_max_mm"]
    end_to_max = np.divide(col["height_mm"], hmax, out=np.zeros(len(records)), where=hmax > 0)
    extra = [j_lead, col["phi_last_deg"] - level, col["phi_min_deg"] - level, end_to_max]
    extra += [col[a] * col[b] for a, b in _PAIRS]
    return np.column_stack([X] + extra) if len(records) else np.zeros((0, len(INSPECTION_FEATURES)))


def _choose_l2(X, y, method, seed=0, folds=5):
    """L2 penalty from :data:`L2_GRID` by k-fold cross-validation on the training joints only."""
    if method != "logistic" or len(y) < 2 * folds:
        return L2_GRID[-1], {}
    order = np.random.default_rng(seed).permutation(len(y))
    parts = np.array_split(order, folds)
    scores = {}
    for l2 in L2_GRID:
        correct = 0
        for part in parts:
            fit = np.setdiff1d(order, part)
            classes = [c for c in CLASSES if c in set(y[fit].tolist())]
            if len(classes) < 2:
                continue
            clf = train_classifier(X[fit], y[fit], method=method, classes=classes, l2=l2)
            correct += int(np.sum(clf.predict(X[part]) == y[part]))
        scores[l2] = correct / len(y)
    best = max(scores.values())
    return max(l2 for l2, v in scores.items() if v == best), scores


def _fit(train, method):
    """The classifier of the training records (L2 by cross-validation on them)."""
    X = inspection_features(train)
    y = np.array([r["label"] for r in train], dtype=object)
    l2, scores = _choose_l2(X, y, method)
    classes = [c for c in CLASSES if c in set(y.tolist())]
    clf = train_classifier(X, y, method=method, feature_names=INSPECTION_FEATURES, classes=classes, l2=l2)
    clf.l2, clf.cv_scores = l2, scores
    return clf


def _predict(clf, records):
    return clf.predict(inspection_features(records)) if records else np.zeros(0, dtype=object)


def _nuisance_parts(name):
    """The two parts of a nuisance's range: ``[(part name, test(record)), ...]``."""
    if name == "sensor":
        return [(s, (lambda r, s=s: r["nuisances"]["sensor"] == s)) for s in SENSORS]
    lo, hi = NUISANCE_RANGES[name]
    mid = 0.5 * (lo + hi)
    return [(f"[{lo:.4g}, {mid:.4g})", lambda r: r["nuisances"][name] < mid),
            (f"[{mid:.4g}, {hi:.4g}]", lambda r: r["nuisances"][name] >= mid)]


def robustness_table(records, *, method="logistic"):
    """Train on one part of each nuisance's range, test on the other.

    Parameters
    ----------
    records : list of dict
        Joint records of :func:`run_inspection` (``split``, ``label``,
        ``lead_type``, ``features``, ``nuisances``).

    Returns
    -------
    list of dict
        One row per nuisance and direction: ``nuisance``, ``train_range``,
        ``test_range``, ``n_train``, ``in_range`` (accuracy on held-out
        joints in the training range) and ``shifted`` (on held-out joints in
        the other part), each with its 95 % Wilson interval; ``missing``
        lists classes absent from the training part (its classifier cannot
        predict them).
    """
    rows = []
    for name in ("sensor",) + tuple(NUISANCE_RANGES):
        parts = _nuisance_parts(name)
        for i, (a_name, a_in) in enumerate(parts):
            b_name, b_in = parts[1 - i]
            train = [r for r in records if r["split"] == "train" and a_in(r)]
            test_a = [r for r in records if r["split"] == "test" and a_in(r)]
            test_b = [r for r in records if r["split"] == "test" and b_in(r)]
            present = {r["label"] for r in train}
            row = {"nuisance": name, "train_range": a_name, "test_range": b_name, "n_train": len(train),
                   "missing": [c for c in CLASSES if c not in present]}
            if len(present) < 2:
                row.update(in_range=None, shifted=None)
            else:
                clf = _fit(train, method)
                pa, pb = _predict(clf, test_a), _predict(clf, test_b)
                row["in_range"] = _accuracy_entry([r["label"] for r in test_a], pa)
                row["shifted"] = _accuracy_entry([r["label"] for r in test_b], pb)
            rows.append(row)
    return rows


def _robustness_csv(rows):
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["nuisance", "train_range", "test_range", "n_train", "n_in_range", "in_range_accuracy",
                "in_range_ci_low", "in_range_ci_high", "n_shifted", "shifted_accuracy", "shifted_ci_low",
                "shifted_ci_high"])

    def cells(e):
        if not e or not e["n"]:
            return [0 if e is None else e["n"], "", "", ""]
        return [e["n"], f"{e['accuracy']:.4f}", f"{e['ci95'][0]:.4f}", f"{e['ci95'][1]:.4f}"]

    for r in rows:
        w.writerow([r["nuisance"], r["train_range"], r["test_range"], r["n_train"], *cells(r["in_range"]),
                    *cells(r["shifted"])])
    return buf.getvalue().encode()


def run_inspection(out: str | os.PathLike, *, n_train: int = 80, n_test: int = 100, resolution: int = 256,
                   spp: int = 4, seed: int = 0, method: str = "logistic", criteria: AcceptanceCriteria | None = None,
                   variant: str | None = None, overwrite: bool = False, cache: str | os.PathLike | None = None,
                   progress: Progress | None = None) -> dict[str, Any]:
    """Draw joints by class under nuisances, scan, reconstruct, classify, score.

    Parameters
    ----------
    out : path-like
        Folder for :data:`INSPECTION_FILES` (made whole or not at all).
    n_train, n_test : int
        Joints per class (by the criteria) for training and for the held-out
        test; the two come from different random streams.
    resolution, spp : int
        Camera size over the 2 mm field and samples per pixel per source
        (inter-reflections are always rendered: two bounces).
    seed : int
    method : {"logistic", "nearest-centroid"}
    criteria : AcceptanceCriteria, optional
    variant : str, optional
    overwrite : bool
    cache : path-like, optional
        A JSON-lines file of finished joints: each joint's record is
        appended when it is done, and a joint already there (same seed,
        split, class, index, size and spp) is read instead of rendered, so
        an interrupted run resumes and a changed classifier reruns without
        rendering.
    progress : callable, optional
        ``progress("joints", done, total)``.

    Returns
    -------
    dict
        The content of ``inspection_report.json``.
    """
    n_train, n_test = _check_study_options(n_train, n_test, resolution, spp, seed, method)
    criteria = criteria if criteria is not None else AcceptanceCriteria()
    if not isinstance(criteria, AcceptanceCriteria):
        raise OptionError(f"criteria must be an AcceptanceCriteria, got {type(criteria).__name__}")
    if cache is not None:
        cache = Path(cache)
        if cache.exists() and not cache.is_file():
            raise OptionError("not a regular file (the cache is a JSON-lines file)", path=cache, field="cache")
        if not cache.parent.is_dir():
            raise OptionError("its folder does not exist", path=cache, field="cache")
    from ..sim.variants import choose_variant

    choose_variant(variant)
    with output_folder(out, INSPECTION_FILES, overwrite=overwrite, last="inspection_report.json") as tmp:
        return _run_into(tmp, n_train=n_train, n_test=n_test, resolution=resolution, spp=spp, seed=seed,
                         method=method, criteria=criteria, variant=variant, progress=progress,
                         cache=cache)


def _read_cache(path):
    """Records of a cache file by key; a torn last line (an interrupted write) is ignored."""
    out = {}
    if path is None or not path.exists():
        return out
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(rec, dict) and isinstance(rec.get("cache_key"), str):
                out[rec["cache_key"]] = rec
    return out


def _profile_points(analysis):
    """The measured points of a joint's profile, for features computed later."""
    pts = analysis.profile.points
    anchored = analysis.profile.anchored
    seg = np.asarray(pts["segment"], int)
    return {"x": np.round(pts["x"], 7).tolist(), "z": np.round(pts["z"], 7).tolist(),
            "phi": np.round(pts["phi"], 7).tolist(), "segment": seg.tolist(),
            "anchored": [bool(anchored[k]) if 0 <= k < len(anchored) else False for k in seg],
            "toe_x": None if not np.isfinite(analysis.toe_x) else float(analysis.toe_x)}


def _run_into(out, *, n_train, n_test, resolution, spp, seed, method, criteria, variant, progress, cache=None):

    t_start = time.perf_counter()
    jobs = [(split, label, i) for split, n in (("train", n_train), ("test", n_test))
            for label in CLASSES for i in range(n)]
    streams = {(split, label): np.random.default_rng([int(seed), 7, SPLITS.index(split), CLASSES.index(label)])
               for split in SPLITS for label in CLASSES}
    records, seconds = [], []
    analysis_params = INSPECTION_ANALYSIS  # the design pad thickness, not the joint's
    cached = _read_cache(cache)
    if cache is not None and cache.exists() and cache.stat().st_size:
        with open(cache, "rb+") as fh:  # a torn last line (an interrupted write) is closed, not continued
            fh.seek(-1, os.SEEK_END)
            if fh.read(1) != b"\n":
                fh.write(b"\n")
    for done, (split, label, i) in enumerate(jobs, 1):
        rng = streams[split, label]
        key = f"{seed}/{split}/{label}/{i}/{resolution}/{spp}/{json.dumps(criteria.to_dict(), sort_keys=True)}"
        joint, (params, nuis, verdict) = _meshed_joint(lambda: draw_inspection_joint(label, rng, criteria=criteria),
                                                       label)
        if key in cached and cached[key].get("params") == json_safe(params.to_dict()):
            rec = cached[key]
            seconds.append(rec["seconds"])
        else:
            rec = scan_and_analyse(joint, resolution=resolution, spp=spp,
                                   seed=derive_seed(seed, "inspect", split, label, i), interreflections=True,
                                   label=False, analysis_params=analysis_params, variant=variant,
                                   sensor=nuis["sensor"], exposure=nuis["exposure"], keep=True,
                                   fiber_diameter_mm=nuis["fiber_diameter_mm"], solder_alpha=nuis["solder_alpha"])
            rec["profile_points"] = _profile_points(rec.pop("_analysis"))
            rec.pop("_scan")
            rec.update(split=split, index=i, label=label, generator=params.kind, nuisances=nuis,
                       judgement=verdict.to_dict(), cache_key=key)
            rec = json_safe(rec)
            seconds.append(rec["seconds"])
            if cache is not None:
                with open(cache, "a", encoding="utf-8") as fh:
                    fh.write(json.dumps(rec) + "\n")
        rec = {k: v for k, v in rec.items() if k not in ("seconds", "cache_key")}
        records.append(rec)
        if progress:
            progress("joints", done, len(jobs))
    train = [r for r in records if r["split"] == "train"]
    test = [r for r in records if r["split"] == "test"]
    clf = _fit(train, method)
    pred, pred_train = _predict(clf, test), _predict(clf, train)
    for part, predicted in ((test, pred), (train, pred_train)):
        for r, p in zip(part, predicted):
            r["predicted"] = str(p)
    y = [r["label"] for r in test]
    good_true = [v == "good" for v in y]
    good_pred = [str(v) == "good" for v in pred]
    n_good, n_bad = sum(good_true), len(y) - sum(good_true)
    false_calls = sum(t and not q for t, q in zip(good_true, good_pred))
    escapes = sum(q and not t for t, q in zip(good_true, good_pred))
    accept_reject = {**_accuracy_entry(good_true, good_pred),
                     "false_calls": false_calls, "false_call_rate": false_calls / n_good if n_good else None,
                     "escapes": escapes, "escape_rate": escapes / n_bad if n_bad else None}
    near = [r for r in test if r["judgement"]["near_boundary"]]
    per_class = {c: _accuracy_entry([c] * sum(r["label"] == c for r in test),
                                    [r["predicted"] for r in test if r["label"] == c]) for c in CLASSES}
    good = [r for r in test if r["label"] == "good"]
    rms = [r["score"]["height_rms_pct"] for r in good]
    heights = {
        "good_test_joints": len(good),
        "measured": sum(v is not None for v in rms),
        "height_above_pad_rms_pct": profile_stats(rms),
        "share_within_2pct": (float(np.mean([v <= 2.0 for v in rms if v is not None]))
                              if any(v is not None for v in rms) else None),
        "absolute_height_rms_pct": profile_stats([r["score"].get("absolute_height_rms_pct") for r in good]),
        "coverage": profile_stats([r["score"]["coverage"] for r in good]),
        "pad_top_z_assumed_mm": analysis_params.pad_top_z,
    }
    rows = robustness_table(records, method=method)
    report = {
        "format": "shinysim-inspection-report/1",
        "settings": {
            "n_train_per_class": n_train, "n_test_per_class": n_test, "classes": list(CLASSES),
            "resolution": resolution, "spp": spp, "seed": seed, "interreflections": True, "method": method,
            "criteria": criteria.to_dict(), "wetted_ranges": WETTED_RANGES,
            "nuisance_ranges": {**NUISANCE_RANGES, "sensor": list(SENSORS)},
            "features": list(INSPECTION_FEATURES),
        },
        "accuracy": _accuracy_entry(y, pred),
        "train_accuracy": accuracy([r["label"] for r in train], pred_train),
        "accept_reject": accept_reject,
        "per_class": per_class,
        "near_boundary": {"n_test": len(near), "share_of_test": len(near) / len(test) if test else None,
                          **{k: v for k, v in _accuracy_entry([r["label"] for r in near],
                                                               [r["predicted"] for r in near]).items()}},
        "confusion_matrix": confusion_report(y, pred, CLASSES),
        "good_joint_heights": heights,
        "robustness": rows,
        "model": {**clf.to_dict(), "l2": clf.l2,
                  "cross_validated_accuracy": {str(k): v for k, v in clf.cv_scores.items()}},
        "joints": records,
    }
    report = json_safe(report)
    timing = {"total_s": time.perf_counter() - t_start,
              "render_s_per_joint": float(np.mean([s["render"] for s in seconds])),
              "analysis_s_per_joint": float(np.mean([s["analysis"] for s in seconds]))}
    write_json(out / "timing.json", json_safe(timing))
    write_bytes(out / "robustness.csv", _robustness_csv(rows))
    write_json(out / "inspection_report.json", report)
    return report


def summary_lines(report):
    """Short text summary of a report (the CLI prints it)."""
    a = report["accuracy"]
    s = report["settings"]
    lines = [f"solder inspection: {s['n_train_per_class']} training + {s['n_test_per_class']} held-out joints "
             f"per class, {s['resolution']} px, {s['spp']} spp, nuisances on",
             f"held-out accuracy {a['accuracy']:.3f} (95% CI {a['ci95'][0]:.3f}-{a['ci95'][1]:.3f}, "
             f"n = {a['n']}; logistic L2 {report['model'].get('l2')} by cross-validation on the training joints)"]
    ar = report["accept_reject"]
    lines.append(f"accept/reject (good or a defect): {ar['accuracy']:.3f} (95% CI {ar['ci95'][0]:.3f}-"
                 f"{ar['ci95'][1]:.3f}); good joints rejected: {ar['false_calls']}, defects passed: {ar['escapes']}")
    nb = report["near_boundary"]
    if nb["n"]:
        lines.append(f"joints within 10% of a boundary: {nb['n']} ({100 * nb['share_of_test']:.0f}% of the test), "
                     f"accuracy {nb['accuracy']:.3f}")
    for c, e in report["per_class"].items():
        if e["n"]:
            lines.append(f"  {c:<13} recall {e['accuracy']:.3f}  (n = {e['n']})")
    h = report["good_joint_heights"]["height_above_pad_rms_pct"]
    if h["n"]:
        lines.append(f"good joints, height above the pad: RMS median {h['median']:.2f}%, p95 {h['p95']:.2f}%, "
                     f"max {h['max']:.2f}% of the fillet height ({h['n']} joints)")
    lines.append("robustness (train on one part of a nuisance's range, test on the other):")
    for r in report["robustness"]:
        ia, sh = r["in_range"], r["shifted"]
        if ia is None or not ia["n"] or not sh["n"]:
            continue
        lines.append(f"  {r['nuisance']:<18} train {r['train_range']:<22} in-range {ia['accuracy']:.3f}  "
                     f"shifted to {r['test_range']:<22} {sh['accuracy']:.3f}")
    return lines

