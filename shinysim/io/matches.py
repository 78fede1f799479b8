"""``matches.csv``: a stereo scan's matched highlights, one row per match (``docs/file-format.md``).

:data:`MATCH_COLUMNS` are its columns in order; :func:`write_matches`
writes them from a mapping of equal-length columns (what
:meth:`shinysim.recon.stereo.StereoMatches.to_csv` hands over).
"""

from __future__ import annotations

import csv
import io as _io
import os
from pathlib import Path

from .._shared import write_text

__all__ = ["MATCH_COLUMNS", "MATCH_INT_COLUMNS", "write_matches"]

#: The columns of ``matches.csv``, in order (``docs/file-format.md`` gives each one's meaning and unit).
MATCH_COLUMNS = ("x_mm", "y_mm", "z_mm", "nx", "ny", "nz", "row1", "col1", "row2", "col2", "source1", "source2",
                 "index1", "index2", "d_mm", "normal_gap_deg", "e1_mm", "e2_mm", "delta_z_mm", "confidence",
                 "refined", "radius_mm", "cx_mm", "cy_mm", "cz_mm")
#: The columns written as integers; every other one is a float written with ``repr`` (it reads back exactly).
MATCH_INT_COLUMNS = ("source1", "source2", "index1", "index2", "refined")


def write_matches(path: str | os.PathLike, columns, *, overwrite: bool = False) -> Path:
    """Write ``matches.csv`` from ``columns`` (a mapping of each :data:`MATCH_COLUMNS` name to a 1-D array).

    Refuses to replace an existing file unless ``overwrite``; writes through a temporary file.
    """
    buf = _io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(MATCH_COLUMNS)
    data = [columns[c].tolist() for c in MATCH_COLUMNS]
    for row in zip(*data):
        writer.writerow([str(int(v)) if c in MATCH_INT_COLUMNS else repr(float(v)) for c, v in zip(MATCH_COLUMNS, row)])
    return write_text(path, buf.getvalue(), overwrite=overwrite)
