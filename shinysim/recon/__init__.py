"""Reconstruction: stacks of per-source frames to highlights, normals and surfaces.

numpy + scikit-image only; importing this package never imports a renderer
(``tests/test_layering.py`` and ``tests/test_recon_isolation.py`` check that).

* :mod:`~shinysim.recon.detect`: one frame: threshold, connected regions,
  centre of gravity, subdivision;
* :mod:`~shinysim.recon.pipeline`: the one stack -> highlights path
  (:func:`detect_stack`) and :func:`reconstruct` (normals under each model);
* :mod:`~shinysim.recon.normals`: the paper's three camera models;
* :mod:`~shinysim.recon.highlights`: multi-highlight frames of complex
  objects (solder defaults, pad toe, mirrored-source normals);
* :mod:`~shinysim.recon.profile`: the paper's profile procedure;
  :mod:`~shinysim.recon.surface`: surfaces from all sparse normals;
  :mod:`~shinysim.recon.integrate`: heights on the sparse points' triangulation, and grid
  integrators (Poisson, Frankot-Chellappa, robust) to compare;
* :mod:`~shinysim.recon.joint`, :mod:`~shinysim.recon.classify`: solder-joint
  analysis and defect classification;
* :func:`read_frame`, :func:`stack_from_frames` (from :mod:`shinysim.io.frames`): your own camera frames as a stack;
  :mod:`~shinysim.recon.sphere`: a sphere seen in an image (real photographs);
* :mod:`~shinysim.recon.stereo`: structured-highlight stereo, matching two
  cameras' highlights (paper Section V), from two stacks by :func:`match_stacks`;
* :mod:`~shinysim.recon.decode`: decode settings that follow a sequential
  detection, and the normals of a highlight table under every model.
"""

from .classify import CLASSIFIER_METHODS, JointClassifier, train_classifier
from .coding import Decoded, DecodeParams, decode, demultiplex, measure_snr_gain
from .detect import (
    CENTROID_METHODS,
    FLAG_RULES,
    THRESHOLD_MODES,
    DetectParams,
    FrameError,
    detect_highlights,
)
from ..io.frames import CHANNEL_REDUCTIONS, read_frame, stack_from_frames
from .highlights import HighlightParams, find_highlights, find_toe
from .integrate import (
    RISE_RULES,
    GridSurface,
    IntegrateParams,
    SparseSurface,
    compare_integrators,
    grid_gradients,
    integrate_frankot_chellappa,
    integrate_poisson,
    integrate_robust,
    integrate_triangulated,
)
from .joint import FEATURE_NAMES, JointAnalysis, JointAnalysisParams, analyse_joint
from .nearfield import NEAR_FIELD, NearField, near_field_normals
from .normals import NORMAL_MODELS, PAPER_MODELS, highlight_normals, surface_points
from .pipeline import (
    Reconstruction,
    detect_stack,
    read_highlight_table,
    reconstruct,
    sparse_normal_map,
)
from .profile import Profile, ProfileParams, profile_from_normals
from .sphere import lights_from_highlights, sphere_from_mask, sphere_normals
from .stereo import (
    HighlightRays,
    StereoMatches,
    StereoParams,
    candidate_pairs,
    candidate_pairs_naive,
    highlight_rays,
    match_highlights,
    match_stacks,
)
from .surface import Surface, SurfaceParams, surface_from_normals

__all__ = [
    # detection and normals
    "CENTROID_METHODS",
    "THRESHOLD_MODES",
    "FLAG_RULES",
    "NORMAL_MODELS",
    "PAPER_MODELS",
    "NEAR_FIELD",
    "NearField",
    "near_field_normals",
    "DetectParams",
    "FrameError",
    "Reconstruction",
    "detect_highlights",
    "detect_stack",
    "reconstruct",
    "highlight_normals",
    "surface_points",
    "sparse_normal_map",
    "read_highlight_table",
    # your own frames, spheres in images
    "CHANNEL_REDUCTIONS",
    "read_frame",
    "stack_from_frames",
    "sphere_from_mask",
    "sphere_normals",
    "lights_from_highlights",
    # complex objects: highlights, profiles, surfaces, joints
    "HighlightParams",
    "find_highlights",
    "find_toe",
    "Profile",
    "ProfileParams",
    "profile_from_normals",
    "Surface",
    "SurfaceParams",
    "surface_from_normals",
    "IntegrateParams",
    "SparseSurface",
    "GridSurface",
    "RISE_RULES",
    "integrate_triangulated",
    "grid_gradients",
    "integrate_poisson",
    "integrate_frankot_chellappa",
    "integrate_robust",
    "compare_integrators",
    "FEATURE_NAMES",
    "JointAnalysis",
    "JointAnalysisParams",
    "analyse_joint",
    "CLASSIFIER_METHODS",
    "JointClassifier",
    "train_classifier",
    # coded scans
    "DecodeParams",
    "Decoded",
    "decode",
    "demultiplex",
    "measure_snr_gain",
    # structured-highlight stereo
    "HighlightRays",
    "StereoParams",
    "StereoMatches",
    "highlight_rays",
    "candidate_pairs",
    "candidate_pairs_naive",
    "match_highlights",
    "match_stacks",
]
