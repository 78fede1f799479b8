"""The coded scan's table and figure."""

from __future__ import annotations

import math
import sys

import numpy as np

from ...recon.coding import Decoded
from ...rig import Rig

from .scene import ScanObject

__all__ = ["format_coded_table", "print_coded_table", "coded_figure"]


def format_coded_table(score: dict) -> str:
    """A short text table of a coded scan's score, for a terminal."""
    d = score["decoding"]
    f = score["frames"]
    rows = [("frames", f"{f['used']} (sequential {f['sequential']}, {f['speed_up']:.1f}x fewer)"),
            ("highlights", f"{d['highlights']} decoded, {d['sequential_highlights']} sequential"),
            ("decoding errors", f"{d['errors']} of {d['paired']} paired ({_pct(d['error_rate'])})"),
            ("spurious, missed", f"{d['spurious']}, {d['missed']}"),
            ("pixel errors", f"{d['pixel_errors']} of {d['pixels_decoded']} decoded pixels"),
            ("collisions", f"{d['counts']['collisions']} px; saturated {d['counts']['saturated']} px")]
    best = score["best_model"]
    n = score["normals"].get(best, {})
    rows.append((f"normal error ({best})", f"median {_deg(n.get('median_deg'))}, p95 {_deg(n.get('p95_deg'))}"))
    cs = score["coded_vs_sequential"]
    rows.append(("coded - sequential", f"median {_deg(cs.get('median_deg'))}, max {_deg(cs.get('max_deg'))}"))
    if "surface" in score:
        c = score["surface"]["coverage"]
        a = score["surface"]["anchored"]
        rows.append(("coverage, visible", f"{_pct(c['visible'])}"))
        rows.append(("coverage, reachable", f"{_pct(c['reachable'])} (reachable: {_pct(c['reachable_of_visible'])} "
                                            "of the visible)"))
        rows.append(("height RMS, anchored", f"{_um(a['height_rms_mm'])} ({_num(a['height_rms_pct'])} % of "
                                             f"{_um(a['scale_mm'])})"))
        if "height_rms_linear_mm" in a:
            rows.append(("  plane facets", f"{_um(a['height_rms_linear_mm'])} ({_num(a['height_rms_linear_pct'])} %)"))
        for m, s in score["surface"]["integrators"].items():
            if m == "grid" or not isinstance(s, dict):
                continue
            rows.append((f"  {m}", f"{_um(s['height_rms_mm'])}, normals {_deg(s['normal_rms_deg'])} RMS"))
    width = max(len(r[0]) for r in rows)
    return "\n".join(f"{a.ljust(width)}  {b}" for a, b in rows)


def print_coded_table(score: dict, file=None) -> None:
    """Print :func:`format_coded_table` (to stdout by default)."""
    print(format_coded_table(score), file=file or sys.stdout)


def _formatter(spec, scale=1, unit=""):
    """A function showing ``scale * x`` as ``spec`` followed by ``unit``, and "-" for None or a non-finite float."""

    def show(x):
        return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{scale * x:{spec}}{unit}"

    return show


_num = _formatter(".2f")
_pct = _formatter(".2f", 100, " %")
_deg = _formatter(".3f", unit=" deg")
_um = _formatter(".2f", 1e3, " um")


def coded_figure(coded, dec: Decoded, truth, rig: Rig, score: dict, surface, obj: ScanObject):
    """Four panels: a coded frame, the decoded sources, the height map's error and the score table.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    rr, cc = np.nonzero(truth.mask)
    pad = 3
    r0, r1 = max(0, rr.min() - pad), min(truth.mask.shape[0], rr.max() + pad + 1)
    c0, c1 = max(0, cc.min() - pad), min(truth.mask.shape[1], cc.max() + pad + 1)
    crop = (slice(r0, r1), slice(c0, c1))
    ext = (c0 - 0.5, c1 - 0.5, r1 - 0.5, r0 - 0.5)
    fig, ax = plt.subplots(2, 2, figsize=(11, 10))
    ax = ax.ravel()
    f0 = coded.frames[0]
    if f0.ndim == 3:  # RGB: each channel from its 1st percentile to the frame's brightest value
        lo = np.percentile(f0, 1, axis=(0, 1))
        ax[0].imshow(np.clip((f0 - lo) / max(float(f0.max() - lo.min()), 1e-30), 0, 1)[crop], extent=ext)
    else:
        ax[0].imshow(f0[crop], cmap="gray", vmin=float(np.percentile(f0, 1)), vmax=float(f0.max()), extent=ext)
    ax[0].set_title(f"{coded.code.name} frame 1 of {coded.n_frames}: {coded.code.lit_per_frame[0]} sources lit")
    lab = np.where(dec.labels >= 0, dec.labels, np.nan)
    ax[1].imshow(np.where(truth.mask, 0.2, 0.0)[crop], cmap="gray", vmin=0, vmax=1, extent=ext)
    ax[1].imshow(np.where(dec.collision, 1.0, np.nan)[crop], cmap="Greys", vmin=0, vmax=1.5, extent=ext,
                 interpolation="nearest")
    ax[1].imshow(lab[crop], cmap="hsv", interpolation="nearest", extent=ext)
    t = dec.table
    ax[1].plot(t["col"], t["row"], "k+", ms=5)
    d = score["decoding"]
    ax[1].set_title(f"decoded sources (colour), collisions (grey), centroids (+)\n"
                    f"{d['highlights']} highlights, {d['errors']} decoding errors")
    if surface is not None:
        m = truth.mask
        pts = truth.positions[m].astype(float)
        z = surface.heights_at(pts[:, :2], interpolation="normals")
        err = np.full(m.shape, np.nan)
        err[m] = 1e3 * (z - pts[:, 2])
        lim = float(np.nanpercentile(np.abs(err), 99)) if np.isfinite(err).any() else 1.0
        im = ax[2].imshow(err[crop], cmap="RdBu_r", vmin=-lim, vmax=lim, extent=ext)
        fig.colorbar(im, ax=ax[2], label="height error, um", shrink=0.8)
        a = score.get("surface", {}).get("anchored", {})
        ax[2].set_title(f"sparse heights minus truth (anchored; normals\nbetween points): RMS "
                        f"{1e3 * (a.get('height_rms_mm') or np.nan):.2f} um over the covered pixels")
    for a_ in ax[:3]:
        a_.set_xlabel("col, px")
        a_.set_ylabel("row, px")
    ax[3].axis("off")
    ax[3].text(0.0, 1.0, format_coded_table(score), family="monospace", fontsize=8, va="top",
               transform=ax[3].transAxes)
    rim = rig.metadata.get("max_polar_deg") if rig.name == "dome" else None
    fig.suptitle(f"coded scan: {rig.name}, {rig.n_sources} sources"
                 + (f", rim {rim:g} deg from the axis" if rim is not None else "") + f", {obj.name}", fontsize=12)
    fig.tight_layout()
    return fig
