"""Reconstruction: stacks of per-source frames to highlights, normals and surfaces.

numpy + scikit-image only; importing this package never imports a renderer
(``tests/test_recon_isolation.py`` checks that).
"""

from .detect import CENTROID_METHODS, THRESHOLD_MODES, DetectParams, FrameError, detect_highlights
from .normals import NORMAL_MODELS, highlight_normals, surface_points
from .pipeline import Reconstruction, read_highlight_table, reconstruct, sparse_normal_map

__all__ = [
    "CENTROID_METHODS",
    "THRESHOLD_MODES",
    "NORMAL_MODELS",
    "DetectParams",
    "FrameError",
    "Reconstruction",
    "detect_highlights",
    "highlight_normals",
    "read_highlight_table",
    "reconstruct",
    "sparse_normal_map",
    "surface_points",
]
