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
* :mod:`~shinysim.recon.coding`: coded (multiplexed) frames back into
  per-source highlights (:func:`decode`);
* :mod:`~shinysim.recon.dots`, :mod:`~shinysim.recon.deflect`: a display's
  dots in one frame (found, indexed by a lattice walk) and a large mirror's
  pose and slopes from them (display deflectometry);
* :mod:`~shinysim.recon.decode`: decode settings that follow a sequential
  detection, and the normals of a highlight table under every model;
* :mod:`shinysim.io.table`: the highlight table (:class:`HighlightTable`) and its CSV form.

Every module's public names are here too, except the height integrator
:func:`shinysim.recon.integrate.integrate`, which would hide its module
(``shinysim.recon.integrate``), and the module ``decode``, whose name is
the decoder :func:`shinysim.recon.coding.decode`.
"""

from __future__ import annotations

import sys

# the modules first, so that the names below (``decode``: coding's function) win over them
from ..io.frames import CHANNEL_REDUCTIONS, read_frame, stack_from_frames
from . import (classify, coding, decode, deflect, detect, dots, highlights, integrate, joint, nearfield, normals,
               pipeline, profile, sphere, stereo, surface)
from .classify import *  # noqa: F403
from .coding import *  # noqa: F403
from .decode import *  # noqa: F403
from .deflect import *  # noqa: F403
from .detect import *  # noqa: F403
from .dots import *  # noqa: F403
from .highlights import *  # noqa: F403
from .integrate import (INTEGRATE_METHODS, RISE_RULES, Component, GridSurface, IntegrateParams, SparseSurface,
                        compare_integrators, edge_rise, grid_gradients, integrate_frankot_chellappa,
                        integrate_poisson, integrate_robust, integrate_triangulated, solve_heights)
from .joint import *  # noqa: F403
from .nearfield import *  # noqa: F403
from .normals import *  # noqa: F403
from .pipeline import *  # noqa: F403
from .profile import *  # noqa: F403
from .sphere import *  # noqa: F403
from .stereo import *  # noqa: F403
from .surface import *  # noqa: F403

_PARTS = ("classify", "coding", "decode", "deflect", "detect", "dots", "highlights", "integrate", "joint", "nearfield",
          "normals", "pipeline", "profile", "sphere", "stereo", "surface")
__all__ = list(dict.fromkeys([
    *_PARTS,
    *(n for part in _PARTS for n in sys.modules[f"{__name__}.{part}"].__all__ if (part, n) != ("integrate", "integrate")),
    "CHANNEL_REDUCTIONS", "read_frame", "stack_from_frames",
]))
