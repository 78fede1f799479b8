"""The calibration study's figure: what each rig costs, fiber by fiber and normal by normal.

matplotlib is imported inside the function.
"""

from __future__ import annotations

import numpy as np

from .caption import new_figure

__all__ = ["calibration_figure"]


def calibration_figure(report):
    """Three panels from a ``calibration_report.json`` dict.

    (a) each fiber's direction error from the working volume, nominal and
    calibrated rig, with the calibration's 1-sigma; (b) the sphere scan's
    normal errors (median and p95) reconstructed with the nominal, calibrated
    and true rig; (c) the Fig. 6 check: simulated against predicted
    percentage errors for fibers turned by delta.

    Returns
    -------
    matplotlib.figure.Figure
    """
    n_panels = 3 if report.get("fig6") else 2
    fig, axes = new_figure((4.4 * n_panels, 3.8), 1, n_panels)
    src = report["sources"]
    d = src["direction_error_deg"]
    err = np.asarray(d["per_source_calibrated"], float)
    sig = np.asarray(d["per_source_sigma"], float)
    nominal = np.asarray(src["per_source_nominal"], float) if "per_source_nominal" in src else None
    k = np.arange(len(err))
    ax = axes[0]
    if nominal is not None:
        ax.semilogy(k, nominal, "o", color="0.6", ms=4, label="nominal rig")
    ax.errorbar(k, err, yerr=sig, fmt="o", color="C0", ms=4, capsize=2, label="calibrated (1$\\sigma$)")
    ax.axhline(0.01, color="C3", lw=1, ls="--", label="0.01$^\\circ$ target (RMS)")
    ax.set_yscale("log")
    ax.set_xlabel("fiber")
    ax.set_ylabel("direction error from the working volume (deg)")
    ax.set_title(f"(a) fibers: RMS {d['calibrated_rms']:.4f}$^\\circ$ (nominal {d['nominal_rms']:.2f}$^\\circ$)",
                 fontsize=9)
    ax.legend(fontsize=7)
    ax = axes[1]
    rigs = ("nominal", "calibrated", "true")
    models = [m for m in ("perspective", "near-field") if m in report["normal_error_deg"]["true"]]
    width = 0.8 / len(models)
    for j, m in enumerate(models):
        med = [report["normal_error_deg"][r][m]["median_deg"] for r in rigs]
        p95 = [report["normal_error_deg"][r][m]["p95_deg"] for r in rigs]
        x = np.arange(len(rigs)) + (j - 0.5 * (len(models) - 1)) * width
        ax.bar(x, med, width, color=f"C{j + 1}", label=f"{m} median")
        ax.plot(x, p95, "_", color="k", ms=14, mew=2, label="p95" if j == 0 else None)
    ax.set_xticks(np.arange(len(rigs)), [f"{r} rig" for r in rigs])
    ax.set_yscale("log")
    ax.set_ylabel("sphere-scan normal error (deg)")
    ax.set_title("(b) the default sphere scan, reconstructed with each rig", fontsize=9)
    ax.legend(fontsize=7)
    if n_panels == 3:
        ax = axes[2]
        lim = 0.0
        for j, row in enumerate(report["fig6"]):
            p = np.asarray(row["predicted_percent"], float)
            s = np.asarray(row["simulated_percent"], float)
            if p.size:
                ax.plot(p, s, "o", ms=4, color=f"C{j}", label=f"$\\delta$ = {row['delta_rad']:+.2f} rad")
                lim = max(lim, np.abs(p).max(), np.abs(s).max())
        lim = 1.1 * lim or 1.0
        ax.plot([-lim, lim], [-lim, lim], color="0.5", lw=1)
        ax.set_xlabel("predicted (theory, Fig. 6), %")
        ax.set_ylabel("simulated (rendered scan), %")
        ax.set_title("(c) Fig. 6: fibers turned by $\\delta$", fontsize=9)
        ax.legend(fontsize=7)
    return fig
