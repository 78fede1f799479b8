"""Export data-set items (or any scan folder) as DiLiGenT folders (``shinysim dataset export``)."""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import OptionError

__all__ = ["export_diligent_folders"]


def export_diligent_folders(source: str | os.PathLike, out: str | os.PathLike, *, camera: int = 0,
                            overwrite: bool = False) -> list[Path]:
    """Write DiLiGenT folders from a scan (item) folder, or from every finished item of a data set.

    A data-set folder (one with ``dataset.json``) gives ``OUT/IIIIIIII/`` per
    finished item (the item's index, 8 digits), in index order; an item or
    scan folder gives ``OUT`` itself. Each folder is written whole or not at
    all (:func:`shinysim.io.diligent.export_scan_folder`).
    """
    from ..io.diligent import export_scan_folder
    from .engine import read_manifest

    source, out = Path(source), Path(out)
    if not source.is_dir():
        raise OptionError(f"{source} is not a folder (give an item folder or a data-set folder)")
    if (source / "dataset.json").is_file():
        rows = read_manifest(source)
        done = [rows[i] for i in sorted(rows) if rows[i].get("status") == "done"]
        if not done:
            raise OptionError(f"{source} holds no finished item to export")
        written = []
        for row in done:
            target = out / f"{row['index']:08d}"
            export_scan_folder(source / row["path"], target, camera=camera, overwrite=overwrite)
            written.append(target)
        return written
    if not (source / "stack.exr").is_file():
        raise OptionError(f"{source} holds neither dataset.json nor stack.exr: not a data set or a scan folder")
    export_scan_folder(source, out, camera=camera, overwrite=overwrite)
    return [out]


