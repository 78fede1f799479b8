r"""The solder-inspection study: generate joints, scan, reconstruct, score, classify.

``shinysim solder --out DIR`` runs :func:`run_solder`: joints of every class
drawn with :func:`sample_split_params` (training and test joints from
interleaved bands of :data:`SPLIT_PARAMS`), scanned with and without
inter-reflections (:func:`shinysim.sim.solder_scene.scan_joint`),
reconstructed from the images (:func:`shinysim.recon.joint.analyse_joint`),
scored against the exact profile and classified; everything goes to
``DIR/solder_report.json`` and ``DIR/fig12_solder_profile.png``, never
replacing files unless ``overwrite=True``. Rendering needs the ``render``
extra; :func:`summarise` is numpy only. The steps, the report's fields and
the measured numbers: ``docs/solder.md``, section "The study".
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._shared import (
    Progress,
    check_choice,
    check_number,
    derive_seed,
    json_safe,
    output_folder,
    write_bytes,
    write_json,
)
from ..errors import OptionError
from ..evaluate import profile_stats, score_profile
from ..objects.solder import (
    COMMON_RANGES,
    JOINT_KINDS,
    PARAM_RANGES,
    JointParams,
    draw_valid_params,
)
from ..plot.caption import captioned_png
from ..plot.solder import draw_profile
from ..recon.classify import CLASSIFIER_METHODS, accuracy, confusion_report, feature_matrix, train_classifier
from ..recon.joint import FEATURE_NAMES, JointAnalysisParams, analyse_joint

__all__ = [
    "SPLIT_PARAMS",
    "N_BANDS",
    "REPORT_FILES",
    "sample_split_params",
    "score_profile",
    "label_interreflections",
    "summarise",
    "run_solder",
    "scan_and_analyse",
        "fig12_solder_profile",
]

#: Parameters whose ranges are split into interleaved train/test bands.
SPLIT_PARAMS = ("fillet_height", "contact_angle_pad")
#: Bands per split parameter (train: even, test: odd).
N_BANDS = 6
#: Files :func:`run_solder` writes.
REPORT_FILES = ("solder_report.json", "fig12_solder_profile.png")
#: A highlight counts as an inter-reflection (ground truth) when the
#: direct-only render holds less than this fraction of its brightness.
INTERREFLECTION_DIRECT_FRACTION = 0.5

SPLITS = ("train", "test")


def _band_value(lo, hi, split, rng, n_bands):
    width = (hi - lo) / n_bands
    bands = [b for b in range(n_bands) if b % 2 == (0 if split == "train" else 1)]
    b = bands[int(rng.integers(len(bands)))]
    return float(lo + width * (b + rng.uniform()))


def sample_split_params(kind, rng, split, *, n_bands=N_BANDS, max_tries=2000):
    """A random joint of one class from the training or the held-out sub-ranges.

    Like :func:`shinysim.objects.solder.sample_params`, but each of
    :data:`SPLIT_PARAMS` is drawn from the even (``split="train"``) or odd
    (``"test"``) bands of its range cut into ``n_bands`` equal bands.

    Parameters
    ----------
    kind : str
    rng : numpy.random.Generator or int
    split : {"train", "test"}
    n_bands : int
        Even, >= 2.

    Returns
    -------
    JointParams
    """
    if kind not in JOINT_KINDS:
        raise OptionError(f"kind must be one of {JOINT_KINDS}, got {kind!r}")
    if split not in SPLITS:
        raise OptionError(f"split must be one of {SPLITS}, got {split!r}")
    if not (isinstance(n_bands, int) and n_bands >= 2 and n_bands % 2 == 0):
        raise OptionError(f"n_bands must be an even integer >= 2, got {n_bands!r}")
    if not isinstance(rng, np.random.Generator):
        rng = np.random.default_rng(rng)

    def draw(name, lo, hi):
        if name in SPLIT_PARAMS:
            return _band_value(lo, hi, split, rng, n_bands)
        return float(rng.uniform(lo, hi))

    return draw_valid_params(kind, rng, draw, max_tries=max_tries, what=f" for split {split!r}")


def split_band(kind, name, value, n_bands=N_BANDS):
    """Which band (0 .. n_bands-1) of ``PARAM_RANGES[kind][name]`` a value falls in."""
    lo, hi = {**COMMON_RANGES, **PARAM_RANGES[kind]}[name]
    return int(min(n_bands - 1, max(0, math.floor((value - lo) / (hi - lo) * n_bands))))


# ---------------------------------------------------------------------------
# scoring (numpy only)
# ---------------------------------------------------------------------------


def label_interreflections(analysis, path_frames, direct_frames, truth=None, smooth_px=None):
    """Ground-truth inter-reflection labels, and how the flag and the readings did.

    A highlight (or band point) is an inter-reflection when the direct-only
    render holds less than :data:`INTERREFLECTION_DIRECT_FRACTION` of the
    path render's smoothed brightness at its centroid pixel.

    Parameters
    ----------
    analysis : JointAnalysis
    path_frames, direct_frames : (n_sources, H, W) ndarray
        The same scan with and without inter-reflections.
    truth : shinysim.io.Truth, optional
        Splits the counts by the part hit (solder or other).

    Returns
    -------
    dict
        ``highlights``: over every highlight, the flag against the labels
        (``n``, ``n_interreflection``, ``flagged_interreflection`` (true
        positives), ``flagged_direct`` (false positives), ``missed``,
        ``recall``, ``precision``), also restricted to highlights on solder
        (``highlights_on_solder``); ``band_points``: the cross-section's
        points by label and reading (``direct_read_direct``,
        ``direct_read_bounce``, ``direct_left_out``,
        ``interreflection_read_direct`` (wrong: a bounce taken for a
        direct reflection), ``interreflection_read_bounce``,
        ``interreflection_left_out``).
    """
    from ..recon.highlights import smoothed_frames

    sp = analysis.params.highlight.smooth_px if smooth_px is None else smooth_px
    P = smoothed_frames(path_frames, sp)
    D = smoothed_frames(direct_frames, sp)

    def labels(src, row, col):
        r = np.clip(np.rint(row).astype(int), 0, P.shape[1] - 1)
        c = np.clip(np.rint(col).astype(int), 0, P.shape[2] - 1)
        return D[src, r, c] < INTERREFLECTION_DIRECT_FRACTION * P[src, r, c], r, c

    def flag_counts(lab, flag):
        tp = int(np.sum(lab & flag))
        fp = int(np.sum(~lab & flag))
        fn = int(np.sum(lab & ~flag))
        return {"n": int(lab.size), "n_interreflection": int(lab.sum()), "flagged": int(flag.sum()),
                "flagged_interreflection": tp, "flagged_direct": fp, "missed": fn,
                "recall": None if tp + fn == 0 else tp / (tp + fn),
                "precision": None if tp + fp == 0 else tp / (tp + fp)}

    t = analysis.table
    out = {}
    if len(t["row"]):
        lab, r, c = labels(t["source"], t["row"], t["col"])
        out["highlights"] = flag_counts(lab, t["interreflection"])
        if truth is not None:
            solder_ids = [i for i, nm in enumerate(truth.part_names) if nm in ("solder", "neighbour_solder", "bridge")]
            on = np.isin(truth.part[r, c], solder_ids)
            out["highlights_on_solder"] = flag_counts(lab[on], t["interreflection"][on])
    g = analysis.points
    if len(g["x"]):
        lab, _, _ = labels(g["source"], g["row"], g["col"])
        rd = g["reading"]
        out["band_points"] = {"n": int(len(rd)), "n_interreflection": int(lab.sum()), **{
            f"{label}_{reading}": int(np.sum(is_label & (rd == code)))
            for label, is_label in (("direct", ~lab), ("interreflection", lab))
            for reading, code in (("read_direct", 1), ("read_bounce", 2), ("left_out", 0))}}
    return out


def summarise(records):
    """Per-class summary of per-joint scores (the report's ``classes``)."""
    out = {}
    for kind in JOINT_KINDS:
        rs = [r for r in records if r["kind"] == kind]
        if not rs:
            continue
        sc = [r["score"] for r in rs]
        ne = [v for s in sc for v in s["normal_errors_deg"] if v is not None]
        ne_direct = []
        ne_mirror = []
        for r in rs:
            m = r["score"].get("mirror_points", [])
            for v, is_m in zip(r["score"]["normal_errors_deg"], m):
                if v is not None:
                    (ne_mirror if is_m else ne_direct).append(v)
        rms_pct = [s["height_rms_pct"] for s in sc if s["height_rms_pct"] is not None]

        def stats_of(key):
            return profile_stats([s.get(key) for s in sc])

        out[kind] = {
            "n_joints": len(rs),
            "n_anchored": int(sum(bool(s["anchored"]) and s["height_rms_pct"] is not None for s in sc)),
            "profile_height_rms_pct": profile_stats(rms_pct),
            "profile_height_rms_mm": stats_of("height_rms_mm"),
            "profile_height_max_error_mm": stats_of("height_max_mm"),
            "profile_height_max_error_pct": stats_of("height_max_pct"),
            "share_rms_within_2pct": None if not rms_pct else float(np.mean(np.asarray(rms_pct) <= 2.0)),
            "coverage": profile_stats([s["coverage"] for s in sc]),
            "normal_error_deg": profile_stats(ne, rms=True),
            "normal_error_direct_deg": profile_stats(ne_direct),
            "normal_error_mirror_deg": profile_stats(ne_mirror),
            "share_normals_under_2deg": None if not ne else float(np.mean(np.asarray(ne) < 2.0)),
            "surface_height_rms_pct": stats_of("surface_rms_pct"),
        }
    return out


# ---------------------------------------------------------------------------
# the study (renders)
# ---------------------------------------------------------------------------


def scan_and_analyse(joint: Any, *, resolution: int = 256, spp: int = 16, seed: int = 0,
                     interreflections: bool = True, label: bool = True,
                     analysis_params: JointAnalysisParams | None = None, variant: str | None = None,
                     keep: bool = False, sensor: Any = None, exposure: float = 0.8,
                     fiber_diameter_mm: float | None = None, solder_alpha: float | None = None) -> dict[str, Any]:
    """Scan, reconstruct and score one joint.

    Parameters
    ----------
    joint : shinysim.sim.solder.Joint or JointParams
        A joint, or parameters to make one from.
    fiber_diameter_mm : float, optional
        Diameter of the rig's fibers (default the paper's 0.040 in).
    solder_alpha : float, optional
        GGX roughness of the solder (default
        ``shinysim.sim.solder_scene.SOLDER_MATERIALS["solder"]["alpha"]``).
    sensor : str or shinysim.sim.sensor.Sensor, optional
        Digitise the joint's stack with this camera sensor (a preset name or
        a Sensor; None or "ideal": the float frames), exposed so that its
        brightest pixel fills ``exposure`` of the full well, with noise
        drawn from ``seed``. The inter-reflection labels still come from the
        ideal direct-only render.

    Returns
    -------
    dict
        A JSON-ready record: ``kind``, ``params``, ``features``, ``score``,
        ``interreflections`` (flag score, when ``label``), ``seconds``; with
        ``keep=True`` also the live objects under ``"_analysis"``,
        ``"_scan"`` (not JSON).
    """
    from ..sim.solder import make_joint
    from ..sim.solder_scene import scan_joint, solder_rig

    t0 = time.perf_counter()
    if isinstance(joint, JointParams):
        joint = make_joint(joint)
    params = joint.params
    rig = solder_rig(resolution, **({} if fiber_diameter_mm is None else {"fiber_diameter_mm": fiber_diameter_mm}))
    scan = scan_joint(joint, rig, spp=spp, seed=seed, interreflections=interreflections,
                      direct_reference=label and interreflections, variant=variant, solder_alpha=solder_alpha)
    stack = scan.stack
    if sensor is not None:
        from ..sim.sensor import Sensor, sensor_preset

        camera = sensor_preset(sensor) if isinstance(sensor, str) else sensor
        if camera is not None:
            if not isinstance(camera, Sensor):
                raise OptionError(f"sensor must be a preset name or a Sensor, got {type(sensor).__name__}")
            stack = camera.exposed_for(float(stack.frames.max()), fraction=exposure).expose(stack, seed=seed)
    t1 = time.perf_counter()
    analysis = analyse_joint(stack, analysis_params or JointAnalysisParams())
    t2 = time.perf_counter()
    score = score_profile(analysis, joint.profile)
    rec = {
        "kind": params.kind,
        "lead_type": params.lead_type,
        "params": params.to_dict(),
        "fillet_height_mm": float(joint.fillet_height),
        "render_seed": int(seed),
        "toe_x_mm": analysis.toe_x,
        "toe_error_mm": analysis.toe_x - joint.profile.fillet_x_range[0],
        "features": analysis.features,
        "score": score,
        "seconds": {"render": t1 - t0, "analysis": t2 - t1, **{f"render_{k}": v for k, v in scan.seconds.items()}},
    }
    if label and scan.direct is not None:
        rec["interreflections"] = label_interreflections(analysis, stack.frames, scan.direct.frames, scan.truth)
    if keep:
        rec["_analysis"] = analysis
        rec["_scan"] = scan
    return rec


def _aggregate_flags(records):
    out = {}
    for scope in ("highlights", "highlights_on_solder", "band_points"):
        tot = {}
        for r in records:
            sc = r.get("interreflections", {}).get(scope)
            if not sc:
                continue
            for k, v in sc.items():
                if k not in ("recall", "precision"):
                    tot[k] = tot.get(k, 0) + v
        if not tot:
            continue
        if "flagged_interreflection" in tot:
            tp, fn, fp = tot["flagged_interreflection"], tot["missed"], tot["flagged_direct"]
            tot["recall"] = None if tp + fn == 0 else tp / (tp + fn)
            tot["precision"] = None if tp + fp == 0 else tp / (tp + fp)
        out[scope] = tot
    return out


def _check_study_options(n_train, n_test, resolution, spp, seed, method, kinds=None):
    """The options the joint studies share, checked in this order; returns ``(n_train, n_test)`` as ints."""
    n_train = check_number("n_train", n_train, lo=1, hi=10000, integer=True)
    n_test = check_number("n_test", n_test, lo=1, hi=10000, integer=True)
    # as for a scan: at least 16 px, at most a 1.4 GB float32 stack per joint
    check_number("resolution", resolution, lo=16, hi=4096, integer=True)
    check_number("spp", spp, lo=1, hi=65536, integer=True)
    check_number("seed", seed, lo=0, hi=2**32 - 1, integer=True)
    if kinds is not None:
        if not kinds:
            raise OptionError("kinds must name at least one joint class")
        for k in kinds:
            check_choice("kind", k, JOINT_KINDS)
    check_choice("method", method, CLASSIFIER_METHODS)
    return n_train, n_test


def _meshed_joint(draw, what, rejected=None):
    """``(joint, draw())`` of the first of 50 draws (JointParams, or a tuple led by one) the mesher can build."""
    from ..sim.solder import make_joint

    for _ in range(50):
        drawn = draw()
        params = drawn[0] if isinstance(drawn, tuple) else drawn
        try:
            return make_joint(params), drawn
        except (RuntimeError, ValueError) as exc:  # a combination the mesher cannot build: draw again
            if rejected is not None:
                rejected.append({"params": params.to_dict(), "error": str(exc)})
    last = f"; last error: {rejected[-1]['error']}" if rejected else ""
    raise RuntimeError(f"no {what} joint could be meshed in 50 draws{last}")


def run_solder(out: str | os.PathLike, *, n_train: int = 16, n_test: int = 16, kinds: Sequence[str] = JOINT_KINDS,
               resolution: int = 256, spp: int = 16, seed: int = 0, interreflections: bool = True, label: bool = True,
               method: str = "logistic", variant: str | None = None, overwrite: bool = False,
               progress: Progress | None = None, plot: bool = True,
               analysis_params: JointAnalysisParams | None = None, sensor: str | None = None,
               exposure: float = 0.8) -> dict[str, Any]:
    """Generate joints over the classes, scan, reconstruct, score and classify.

    Parameters
    ----------
    out : path-like
        Folder for ``solder_report.json`` (and ``fig12_solder_profile.png``).
    n_train, n_test : int
        Joints per class for training and for the held-out test.
    kinds : sequence of str
        Classes (default all five).
    resolution, spp : int
        Camera size (pixels across the 2 mm field) and samples per pixel per source.
    seed : int
        Everything (joints, renders) follows from it.
    interreflections : bool
        Render with two bounces (path integrator); else direct light only.
    label : bool
        Also render direct-only stacks to score the inter-reflection flag.
    method : {"logistic", "nearest-centroid"}
    overwrite : bool
    progress : callable, optional
        ``progress(stage, done, total)``; ``progress("info", 0, 0, message)``.
    plot : bool
        Write ``fig12_solder_profile.png`` from the first good test joint.

    Returns
    -------
    dict
        The content of ``solder_report.json``.
    """
    n_train, n_test = _check_study_options(n_train, n_test, resolution, spp, seed, method, kinds)
    from ..sim.sensor import SENSOR_PRESETS

    check_choice("sensor", sensor or "ideal", tuple(SENSOR_PRESETS))
    check_number("exposure", exposure, lo=0, lo_open=True, hi=1e3)
    from ..sim.variants import choose_variant

    choose_variant(variant)  # an unknown or unusable variant is refused before any work
    names = REPORT_FILES if plot else REPORT_FILES[:1]
    with output_folder(out, names + ("timing.json",), overwrite=overwrite, last="solder_report.json") as tmp:
        return _run_solder_into(tmp, n_train=n_train, n_test=n_test, kinds=kinds, resolution=resolution, spp=spp,
                                seed=seed, interreflections=interreflections, label=label, method=method,
                                variant=variant, progress=progress, plot=plot, analysis_params=analysis_params,
                                sensor=sensor, exposure=exposure)


def _run_solder_into(out, *, n_train, n_test, kinds, resolution, spp, seed, interreflections, label, method,
                     variant, progress, plot, analysis_params, sensor=None, exposure=0.8):
    """The body of :func:`run_solder`, writing into the (new, empty) folder ``out``."""
    overwrite = False
    t_start = time.perf_counter()
    jobs = [(split, kind, i) for split, n in (("train", int(n_train)), ("test", int(n_test)))
            for kind in kinds for i in range(n)]
    streams = {(split, kind): np.random.default_rng([int(seed), SPLITS.index(split), JOINT_KINDS.index(kind)])
               for split in SPLITS for kind in kinds}
    records = []
    rejected = []
    fig_record = None
    for done, (split, kind, i) in enumerate(jobs, 1):
        joint, _ = _meshed_joint(lambda: sample_split_params(kind, streams[split, kind], split), kind, rejected)
        keep = plot and fig_record is None and split == "test" and kind == "good"
        rec = scan_and_analyse(joint, resolution=resolution, spp=spp, seed=derive_seed(seed, split, kind, i),
                               sensor=sensor, exposure=exposure,
                               interreflections=interreflections, label=label, analysis_params=analysis_params,
                               variant=variant, keep=keep)
        rec.update(split=split, index=i)
        if keep:
            fig_record = rec
        records.append(rec)
        if progress:
            progress("joints", done, len(jobs))
    # classification
    train = [r for r in records if r["split"] == "train"]
    test = [r for r in records if r["split"] == "test"]
    Xtr = feature_matrix([r["features"] for r in train], FEATURE_NAMES)
    ytr = [r["kind"] for r in train]
    Xte = feature_matrix([r["features"] for r in test], FEATURE_NAMES)
    yte = [r["kind"] for r in test]
    clf = train_classifier(Xtr, ytr, method=method, feature_names=FEATURE_NAMES, classes=list(kinds))
    pred_te = clf.predict(Xte)
    pred_tr = clf.predict(Xtr)
    for part, pred in ((test, pred_te), (train, pred_tr)):
        for r, p in zip(part, pred):
            r["predicted"] = str(p)
    acc = accuracy(yte, pred_te)
    classes = summarise(records)
    report = {
        "format": "shinysim-solder-report/1",
        "settings": {
            "n_train_per_class": int(n_train), "n_test_per_class": int(n_test), "kinds": list(kinds),
            "resolution": int(resolution), "spp": int(spp), "seed": int(seed),
            "interreflections": bool(interreflections), "labelled": bool(label),
            "sensor": sensor if sensor not in (None, "ideal") else None,
            "exposure": float(exposure) if sensor not in (None, "ideal") else None,
            "held_out": {"split_params": list(SPLIT_PARAMS), "n_bands": N_BANDS,
                         "rule": "training joints draw the split parameters from the even bands of their "
                                 "class ranges, test joints from the odd bands, with different random streams"},
            "analysis": json_safe(_params_dict(analysis_params or JointAnalysisParams())),
        },
        "classes": classes,
        "accuracy": acc,
        "confusion_matrix": confusion_report(yte, pred_te, kinds),
        "classification": {"method": method, "features": list(FEATURE_NAMES), "train_accuracy": accuracy(ytr, pred_tr),
                           "n_train": len(train), "n_test": len(test), "model": clf.to_dict()},
        "interreflections": _aggregate_flags(records),
        "rejected_draws": rejected,
        "joints": [{k: v for k, v in r.items() if not k.startswith("_") and k != "seconds"} for r in records],
    }
    # timings go to their own file: the same seed gives a byte-identical report
    timing = {"total_s": time.perf_counter() - t_start,
              "render_s_per_joint": float(np.mean([r["seconds"]["render"] for r in records])),
              "analysis_s_per_joint": float(np.mean([r["seconds"]["analysis"] for r in records])),
              "joints": [{"split": r.get("split"), "kind": r.get("kind"), **r["seconds"]} for r in records]}
    write_json(out / "timing.json", json_safe(timing))
    report = json_safe(report)
    if plot and fig_record is not None:
        fig, caption = _fig12_from_record(fig_record)
        write_bytes(out / "fig12_solder_profile.png", captioned_png(fig, caption), overwrite=overwrite)
        report["fig12_caption"] = caption
    write_json(out / "solder_report.json", report, overwrite=overwrite)
    return report


def _params_dict(p):
    from dataclasses import asdict, is_dataclass

    return asdict(p) if is_dataclass(p) else dict(p)


# ---------------------------------------------------------------------------
# Fig. 12
# ---------------------------------------------------------------------------


def _fig12_caption(analysis, score, params, resolution, spp):
    ne = score["normal_error"]
    rms = score.get("height_rms_pct")
    parts = [
        f"Fig. 12 (simulated): reconstructed profile of a good {params.lead_type} joint "
        f"(fillet height {score['fillet_height_mm']:.3f} mm, contact angle "
        f"{math.degrees(params.contact_angle_pad):.1f} deg) scanned by the 21-fiber rig with inter-reflections "
        f"({resolution} px over 2 mm, {spp} spp).",
        "Blue: normals of direct highlights of the y = 0 band; green: flagged highlights read as bounces off the "
        "pad (mirrored source); red: circular interpolation between neighbours close in distance and angle, "
        "anchored at the toe (triangle) on the pad top; shaded: assumed discontinuities.",
    ]
    if rms is not None:
        parts.append(f"Height RMS error {1000 * score['height_rms_mm']:.2f} um = {rms:.2f}% of the fillet height "
                     f"(max {1000 * score['height_max_mm']:.2f} um) over {100 * score['coverage']:.0f}% of the "
                     f"visible fillet; normal error at the {ne['n']} measured points mean {ne['mean']:.2f} deg, "
                     f"max {ne['max']:.2f} deg (paper: under 2 deg at about 0.001 in).")
    return " ".join(parts)


def _draw_fig12(ax, rec):
    """Draw a kept record's profile into ``ax``; return its caption."""
    scan = rec["_scan"]
    draw_profile(ax, rec["_analysis"], scan.joint.profile)
    return _fig12_caption(rec["_analysis"], rec["score"], JointParams.from_dict(rec["params"]),
                          scan.stack.camera.width, scan.stack.provenance.get("spp"))


def _fig12_from_record(rec):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 4.6))
    return fig, _draw_fig12(fig.add_subplot(1, 1, 1), rec)


def fig12_solder_profile(out_path_or_ax, *, quick=False, seed=0, params=None, record=None, overwrite=False,
                         progress=None):
    """The paper's Fig. 12 from simulation: a good joint's reconstructed profile.

    Draws the reconstructed cross-section ``z(x)`` (with its gaps and the
    measured normals) over the exact one, for a good joint scanned with
    inter-reflections.

    Parameters
    ----------
    out_path_or_ax : path-like or matplotlib Axes
        A PNG path (written with the caption under the plot) or an Axes to
        draw into.
    quick : bool
        256 px and 16 spp (seconds) instead of 512 px and 32 spp (a minute or two).
    seed : int
        Draws the good joint (``sample_params("good", seed)``) and seeds the render.
    params : JointParams, optional
        A specific joint instead of a random good one.
    record : dict, optional
        A kept record of :func:`scan_and_analyse` (``keep=True``) to draw
        instead of scanning.
    overwrite : bool
        Replace an existing PNG (else ``FileExistsError``).
    progress : callable, optional
        ``progress("info", 0, 0, message)``.

    Returns
    -------
    caption : str
    """
    from ..objects.solder import sample_params

    if record is None:
        params = params or sample_params("good", np.random.default_rng(seed))
        res, spp = (256, 16) if quick else (512, 32)
        if progress:
            progress("info", 0, 0, f"Fig. 12: scanning a good joint at {res} px, {spp} spp")
        record = scan_and_analyse(params, resolution=res, spp=spp, seed=derive_seed(seed, "fig12"), label=False, keep=True)
    if hasattr(out_path_or_ax, "plot"):
        return _draw_fig12(out_path_or_ax, record)
    fig, caption = _fig12_from_record(record)
    path = Path(out_path_or_ax)
    write_bytes(path, captioned_png(fig, caption), overwrite=overwrite)
    return caption
