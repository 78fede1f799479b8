"""Reconstruction: stacks of per-source frames to highlights, normals and surfaces.

numpy + scikit-image only; importing this package never imports a renderer
(``tests/test_recon_isolation.py`` checks that).
"""

from .classify import CLASSIFIER_METHODS, JointClassifier, train_classifier
from .detect import (
    CENTROID_METHODS,
    THRESHOLD_MODES,
    DetectParams,
    FrameError,
    detect_highlights,
)
from .highlights import FLAG_RULES, HighlightParams, find_highlights, find_toe
from .joint import FEATURE_NAMES, JointAnalysis, JointAnalysisParams, analyse_joint
from .normals import NORMAL_MODELS, highlight_normals, surface_points
from .pipeline import (
    Reconstruction,
    read_highlight_table,
    reconstruct,
    sparse_normal_map,
)
from .profile import Profile, ProfileParams, profile_from_normals
from .surface import Surface, SurfaceParams, surface_from_normals

__all__ = [
    "CLASSIFIER_METHODS",
    "FEATURE_NAMES",
    "FLAG_RULES",
    "HighlightParams",
    "JointAnalysis",
    "JointAnalysisParams",
    "JointClassifier",
    "Profile",
    "ProfileParams",
    "Surface",
    "SurfaceParams",
    "analyse_joint",
    "find_highlights",
    "find_toe",
    "profile_from_normals",
    "surface_from_normals",
    "train_classifier",
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
