"""What decoding and the normals of a decoded table share with a sequential scan: settings, normals of a table."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..io.table import HighlightTable
from ..rig import Anchor, Rig
from .detect import DetectParams
from .nearfield import NEAR_FIELD, near_field_normals
from .normals import NORMAL_MODELS, highlight_normals, surface_points

__all__ = ["decode_settings", "table_normals"]


def decode_settings(det: DetectParams) -> dict:
    """:func:`~shinysim.recon.coding.decode` settings that follow a sequential detection's ``det``."""
    return {"detect": det, "max_area": det.max_area,
            "threshold_mode": "scan" if det.threshold_mode == "scan" else "source"}


def table_normals(table: HighlightTable, rig: Rig, anchor: Anchor | None = None) -> dict[str, Any]:
    """Normals of a highlight table: the near-field model (with an anchor) and the paper's models.

    Returns
    -------
    dict
        ``normals`` (model -> (N, 3)), ``points`` ((N, 3) mm: the
        near-field surface points, or the perspective model's points on the
        reference plane without an anchor), ``best`` (the near-field model
        with an anchor, else ``"perspective"``), ``converged``.
    """
    rows, cols, src = table["row"], table["col"], table["source"]
    out = {"normals": {}, "points": None, "best": "perspective", "converged": None}
    for m in NORMAL_MODELS:
        if m == NEAR_FIELD:
            continue
        out["normals"][m] = highlight_normals(rows, cols, src, rig, model=m).reshape(-1, 3)
    if anchor is not None and len(rows) >= 2:
        nf = near_field_normals(rows, cols, src, rig, anchor)
        out["normals"][NEAR_FIELD] = nf.normals
        out["points"] = nf.points
        out["best"] = NEAR_FIELD
        out["converged"] = bool(nf.converged)
    else:
        out["points"] = np.asarray(surface_points(rows, cols, rig, model="perspective")).reshape(-1, 3)
    return out
