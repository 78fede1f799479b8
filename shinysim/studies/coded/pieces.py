"""Pieces for studies of coded scanning: one render scored under several codes, and the signal-to-noise gain."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...evaluate import decoding_errors, normal_differences, pair_highlights, pixel_owner, score_normals
from ...io import Stack
from ...recon import DetectParams, reconstruct
from ...recon.coding import decode
from ...recon.decode import table_normals
from ...rig import Rig
from ...theory.coding import Code, make_code

from .scene import ScanObject, coded_rig, scan_object

__all__ = ["snr_gain_measurement", "RenderedScan", "render_scan", "code_row", "phase_row"]


def _normal_errors(table, normals, truth) -> dict:
    """``n``, ``median_deg``, ``p95_deg``, ``max_deg`` and ``rms_deg`` of a table's normals against the truth."""
    s = score_normals(table["row"], table["col"], normals, truth)
    return {k: s[k] for k in ("n", "median_deg", "p95_deg", "max_deg", "rms_deg")}


def _vs_sequential(table, seq_table, radius_px, normals, seq_normals) -> dict:
    """:func:`normal_differences` of the decoded and the sequential normals of the highlights paired with one of
    the same source (:func:`pair_highlights` within ``radius_px``)."""
    p = pair_highlights(table, seq_table, radius_px=radius_px)["partner"]
    same = (p >= 0) & (np.asarray(table["source"]) == np.asarray(seq_table["source"])[np.where(p >= 0, p, 0)])
    return normal_differences(normals[same], seq_normals[p[same]])


def snr_gain_measurement(stack: Stack, sensor, *, fraction: float = 0.5, seed: int = 0) -> dict[str, Any]:
    """Hadamard's SNR gain over sequential scanning at equal exposure per frame, measured and in theory.

    Both scans use one sensor exposed so that the stack's brightest pixel
    fills ``fraction`` of the full well; the Hadamard scan has ``n =
    2**m - 1 >= N`` frames (the S-matrix order). The gain is measured by
    :func:`shinysim.recon.coding.measure_snr_gain` over every pixel of
    every demultiplexed source frame against the noiseless frames, and set
    against :func:`~shinysim.theory.coding.hadamard_snr_gain` (additive
    noise: ``(n + 1) / (2 sqrt n)``).

    Returns
    -------
    dict
        ``gain``, ``stderr``, ``theory``, ``relative_error``, ``n``,
        ``frames_sequential``, ``frames_hadamard``, sigmas.
    """
    from ...recon.coding import measure_snr_gain
    from ...sim.coded import coded_stack, expected_frames
    from ...theory.coding import hadamard_snr_gain

    sensor = sensor.exposed_for(float(stack.frames.max()), fraction)
    n = stack.n_sources
    seq = coded_stack(stack, make_code("sequential", n), sensor=sensor, exposure=None, seed=seed)
    had = coded_stack(stack, make_code("hadamard", n), sensor=sensor, exposure=None, seed=seed + 1)
    r = measure_snr_gain(seq, had, expected_frames(stack.frames, sensor))
    theory = hadamard_snr_gain(had.n_frames)
    return {**r, "theory": theory, "relative_error": r["gain"] / theory - 1, "n": had.n_frames,
            "frames_sequential": seq.n_frames, "frames_hadamard": had.n_frames}


@dataclass
class RenderedScan:
    """One render of an object under a rig, with its sequential scan.

    Attributes
    ----------
    rig : Rig
        Anchored at the object's datum.
    obj : ScanObject
    truth : Truth
    stack : Stack
        Ideal per-source frames.
    sequential : Reconstruction
        Detection of ``stack`` (the object's settings, ``ScanObject.detect_params``).
    normals : dict
        :func:`table_normals` of the sequential highlights.
    owner : (H, W) int64
        :func:`pixel_owner` of ``stack``.
    seconds : float
        Render time.
    """

    rig: Rig
    obj: ScanObject
    truth: Any
    stack: Stack
    sequential: Any
    normals: dict
    owner: np.ndarray
    seconds: float = 0.0
    extra: dict = field(default_factory=dict)

    def sequential_errors(self, model: str | None = None) -> dict:
        """Normal errors of the sequential scan against the truth (``error_stats``), best model by default."""
        return _normal_errors(self.sequential.table, self.normals["normals"][model or self.normals["best"]], self.truth)


def render_scan(obj: str = "sphere", *, rig: str | None = None, n_sources: int = 200, alpha: float = 0.02,
                resolution: int = 256, spp: int = 16, seed: int = 0, folder=None,
                detect: DetectParams | None = None, rim_deg: float | None = None) -> RenderedScan:
    """Render an object under a coded-scan rig once and reconstruct its sequential scan.

    ``rig`` defaults to the object's own (``ScanObject.rig``: the dome, the rotating semicircle for the
    joint); ``detect`` to the object's own settings (``ScanObject.detect_params``)."""
    from ...sim.render import Simulator

    the_obj = scan_object(obj, alpha=alpha, folder=folder)
    the_rig = coded_rig(rig or the_obj.rig, n_sources=n_sources, resolution=resolution, anchor=the_obj.anchor,
                        rim_deg=rim_deg)
    sim = Simulator(the_rig, the_obj.objects)
    truth = sim.render_truth()
    stack = sim.render_stack(spp=spp, seed=seed)
    seq = reconstruct(stack, detect or the_obj.detect_params(the_rig.camera))
    return RenderedScan(the_rig, the_obj, truth, stack, seq, table_normals(seq.table, the_rig, the_rig.anchor),
                        pixel_owner(stack.frames), sim.last_render_seconds)


def code_row(scan: RenderedScan, code: Code, *, sensor=None, exposure: float | None = 0.8, seed: int = 0,
             crosstalk: float | None = None) -> dict[str, Any]:
    """Code, decode and score one scan setting: one row of a study table.

    Parameters
    ----------
    scan : RenderedScan
    code : Code
    sensor : Sensor, optional
    exposure : float or None
        As :func:`~shinysim.sim.coded.coded_stack` (None: the sensor's own exposure per frame).
    seed : int
    crosstalk : float, optional
        The decoder's crosstalk tolerance (``DecodeParams.crosstalk``;
        default ``0.8 / bits``).

    Returns
    -------
    dict
        ``code``, ``frames``, ``highlights``, ``paired``, ``errors``,
        ``error_rate``, ``missed``, ``spurious``, ``pixel_errors``,
        ``collisions``, ``saturated``, ``median_deg`` / ``p95_deg`` (best
        model against the truth), ``vs_sequential_deg`` (median over paired
        highlights), ``peak_electrons`` (the brightest coded pixel's mean
        signal, the sensor's exposure times the radiance).
    """
    from ...sim.coded import coded_stack

    coded = coded_stack(scan.stack, code, sensor=sensor, exposure=exposure if sensor is not None else None,
                        seed=seed)
    dec = decode(coded, crosstalk=crosstalk)
    errs = decoding_errors(dec, scan.owner, scan.sequential.table)
    row = {"code": code.name + ("" if code.complementary or code.name not in ("binary", "gray") else " (no compl.)"),
           "frames": code.n_frames, "highlights": errs["highlights"], "paired": errs["paired"],
           "errors": errs["errors"], "error_rate": errs["error_rate"], "missed": errs["missed"],
           "spurious": errs["spurious"], "pixel_errors": errs["pixel_errors"],
           "collisions": errs["counts"]["collisions"], "saturated": errs["counts"]["saturated"]}
    if coded.sensor is not None:
        from ...theory.coding import encode

        peak = float(encode(scan.stack.frames, code).max())
        row["peak_electrons"] = peak * coded.sensor.exposure
    if len(dec.table["source"]) >= 3:
        n = table_normals(dec.table, scan.rig, scan.rig.anchor)
        best = n["best"]
        s = score_normals(dec.table["row"], dec.table["col"], n["normals"][best], scan.truth)
        row.update(median_deg=s["median_deg"], p95_deg=s["p95_deg"])
        row["vs_sequential_deg"] = _vs_sequential(dec.table, scan.sequential.table, errs["radius_px"],
                                                  n["normals"][best], scan.normals["normals"][best])["median_deg"]
    return row


def phase_row(scan: RenderedScan, code, *, sensor=None, exposure: float | None = 0.8, seed: int = 0,
              window: int = 1) -> dict[str, Any]:
    """A phase code on the dome's discrete sources: code, decode and score one setting (a row of the table).

    The dome is the display: each source's direction ``(x, y, z)`` is the
    screen point ``(fx, fy) = ((x + 1) / 2, (y + 1) / 2)``, and frame ``k`` of
    the :class:`~shinysim.theory.phase.PhaseCode` lights every source at the
    code's value there (gray levels: a dimmed fiber). Highlights are found
    with the one detection engine on the frames' mean (every source at half
    its brightness); each highlight's frames (summed over a ``2 window + 1``
    square about its centroid's pixel) are decoded
    (:func:`~shinysim.recon.phase.decode_phase`) to a screen point, and the
    highlight is the source nearest it. A highlight whose decoding is
    flagged is left unlabelled; the rest are scored as :func:`code_row`
    scores a binary code.

    Returns
    -------
    dict
        As :func:`code_row` (``code`` is ``"phase N x P"``), plus
        ``flagged`` (highlights left unlabelled) and ``source_spacing`` (the
        sources' nearest spacing in screen fractions: what the decoding must
        resolve).
    """
    from ...io.table import HighlightTable
    from ...recon.detect import detect_highlights
    from ...recon.phase import decode_phase
    from ...theory.phase import PhaseCode

    if not isinstance(code, PhaseCode):
        raise TypeError(f"phase_row takes a PhaseCode, got {type(code).__name__}")
    dirs = scan.rig.source_positions / np.linalg.norm(scan.rig.source_positions, axis=1, keepdims=True)
    frac = 0.5 * (dirs[:, :2] + 1.0)
    weights = code.intensity(frac[:, 0], frac[:, 1])  # (n_frames, n_sources)
    stack = np.asarray(scan.stack.frames, np.float64)
    coded = np.tensordot(weights, stack, axes=(1, 0))  # (n_frames, H, W)
    if sensor is not None:
        peak = float(coded.max())
        s = sensor.exposed_for(peak, exposure) if exposure is not None else sensor
        coded = np.asarray(s.capture(coded.astype(np.float32), seed=seed), np.float64)
    mean = coded.mean(axis=0)
    params = scan.obj.detect_params(scan.rig.camera)
    table = detect_highlights(mean, params)
    H, W = mean.shape
    r = np.clip(np.round(table["row"]).astype(int), 0, H - 1)
    c = np.clip(np.round(table["col"]).astype(int), 0, W - 1)
    sums = np.zeros((len(r), code.n_frames))
    for dr in range(-window, window + 1):
        for dc in range(-window, window + 1):
            rr = np.clip(r + dr, 0, H - 1)
            cc = np.clip(c + dc, 0, W - 1)
            sums += coded[:, rr, cc].T
    dec = decode_phase(sums[:, None, :], code)
    got = dec.fraction[:, 0, :]
    ok = dec.valid[:, 0]
    d2 = np.sum((got[:, None, :] - frac[None, :, :]) ** 2, axis=-1)
    label = np.where(ok, np.argmin(np.where(np.isfinite(d2), d2, np.inf), axis=1), -1)
    keep = label >= 0
    out_table = HighlightTable({k: (np.asarray(v)[keep] if np.ndim(v) else v) for k, v in table.items()})
    out_table["source"] = label[keep].astype(np.int64)
    pairs = pair_highlights(out_table, scan.sequential.table)
    spacing = np.sqrt(np.min(np.sum((frac[:, None] - frac[None]) ** 2, -1) + np.eye(len(frac)) * 9, axis=1))
    row = {"code": f"phase {code.shifts} x {len(code.periods_x)}", "frames": code.n_frames,
           "highlights": int(keep.sum()), "flagged": int((~ok).sum()), "paired": pairs["paired"],
           "errors": pairs["errors"], "error_rate": pairs["error_rate"], "missed": pairs["missed"],
           "spurious": pairs["spurious"], "source_spacing": float(np.min(spacing))}
    if keep.sum() >= 3:
        n = table_normals(out_table, scan.rig, scan.rig.anchor)
        best = n["best"]
        sc = score_normals(out_table["row"], out_table["col"], n["normals"][best], scan.truth)
        row.update(median_deg=sc["median_deg"], p95_deg=sc["p95_deg"])
    return row
