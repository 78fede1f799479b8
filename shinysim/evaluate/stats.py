"""The one statistics helper of the scores: counts, means, medians, percentiles, maxima over finite values."""

from __future__ import annotations

import numpy as np

__all__ = ["STATISTICS", "summary_stats", "error_stats", "distance_stats"]

#: What :func:`summary_stats` can report (besides ``n``, the count), each over the finite values.
STATISTICS = {
    "mean": np.mean,
    "median": np.median,
    "p95": lambda v: np.percentile(v, 95),
    "max": np.max,
    "rms": lambda v: np.sqrt(np.mean(v**2)),
}


def summary_stats(values, stats=("n", "mean", "median", "p95", "max", "rms"), *, key="{}", empty=float("nan")):
    """Statistics of the finite entries of ``values`` (None and NaN count as missing).

    Parameters
    ----------
    values : array_like
    stats : sequence of str
        ``"n"`` (the count of finite values) and names of
        :data:`STATISTICS`, in the order the result lists them.
    key : str
        Format of each statistic's key (``"{}_deg"`` gives ``median_deg``);
        ``n`` is always ``"n"``.
    empty
        Each statistic's value when no entry is finite.

    >>> summary_stats([1.0, 3.0, float("nan")], ("n", "mean", "max"), key="{}_deg")
    {'n': 2, 'mean_deg': 2.0, 'max_deg': 3.0}
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return {"n" if s == "n" else key.format(s): int(v.size) if s == "n" else
            (float(STATISTICS[s](v)) if v.size else empty) for s in stats}


def error_stats(errors_deg):
    """Summary statistics of angular errors over the finite entries.

    Returns
    -------
    dict
        ``n``, ``mean_deg``, ``median_deg``, ``p95_deg``, ``max_deg``, ``rms_deg``
        (NaN statistics when ``n == 0``).
    """
    return summary_stats(errors_deg, key="{}_deg")


def distance_stats(distances_mm, pixel_mm):
    """Median, 95th percentile and maximum of point distances, in micrometres and pixel-equivalents.

    Returns
    -------
    dict
        ``n``, ``median``, ``p95``, ``max`` (micrometres) and ``median_px``,
        ``p95_px``, ``max_px`` (in units of ``pixel_mm``, the camera's pixel
        pitch at its target).
    """
    s = summary_stats(distances_mm, ("n", "median", "p95", "max"))
    out = {"n": s.pop("n")}
    for name, v in s.items():
        out[name] = 1e3 * v
        out[f"{name}_px"] = v / pixel_mm
    return out
