"""The accepted matches (:class:`StereoMatches`) and their CSV form.

See ``docs/stereo-matching.md`` for every definition.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...io.matches import write_matches
from ._base import STEREO_COLUMNS

__all__ = ["StereoMatches"]


@dataclass
class StereoMatches:
    """Accepted stereo matches, one row each (:func:`match_highlights`).

    Attributes
    ----------
    point : (M, 3) float, millimetres
        The match's surface point, world frame: the midpoint of its two
        elements placed by the umbilic refinement where ``refined``, else
        ``crossing``.
    normal : (M, 3) float
        Unit normal there: the mean of the two elements' normals where
        ``refined``, else ``n*``, the common normal of reflectance matching
        (``docs/stereo-matching.md``).
    crossing : (M, 3) float, millimetres
        ``P*``: midpoint of the rays' closest approach (Eq 40), the paper's
        point.
    refined : (M,) bool
        The umbilic refinement placed the elements (``docs/stereo-matching.md``).
    radius_mm : (M,) float
        Its local radius of curvature ``rho`` (signed: positive where the
        surface is convex towards the cameras); NaN where not refined.
    row1, col1, row2, col2 : (M,) float
        The two highlights' centroids, pixels.
    source1, source2 : (M,) int
        Their sources.
    index1, index2 : (M,) int
        Their positions in the two :class:`HighlightRays`.
    d_mm : (M,) float
        Closest-approach distance ``D`` (Eq 40), millimetres.
    normal_gap_deg : (M,) float
        ``angle(n1(P1*), n2(P2*))``, degrees.
    e1_mm, e2_mm : (M,) float
        ``E'``, ``E''`` of Eqs 33-34 in vector form: signed distance along
        each ray, from ``P_k*`` towards the camera, to where the ray's normal
        is nearest ``n*``.
    delta_z_mm : (M,) float
        ``e1 - e2`` (Eq 43's Delta z); zero where ``E1 = E2`` has a root on
        the arc from ``n1`` to ``n2``.
    confidence : (M,) float in [0, 1]
        ``a0 * margin``: the likelihood of the residuals times the margin
        over the best competitor (``docs/stereo-matching.md``).
    support : (M,) float
        Relaxation support (weighted count of consistent neighbours; 0
        without relaxation).
    n_examined : int
        Pairs that got the exact tests (``N1 * N2`` for the naive search).
    n_rejected_distance, n_rejected_depth, n_rejected_normal : int
        Examined pairs dropped by each test, in that order (``D >= D0`` or
        behind a camera; outside the depth range; normal gap too large).
    n_candidates : int
        Pairs that passed them.
    n_rejected_delta_z, n_rejected_e : int
        Candidates dropped by the optional Eq 43 / Eq 33-34 limits.
    n_rejected_uniqueness : int
        Candidates that lost to a competitor (relaxation and uniqueness).
    relax_iterations : int
    d0_mm, max_normal_gap_deg, neighbourhood_mm : float
        The limits used (after defaults were resolved).
    normal_turn_deg_per_px : float
        The median turn of the surface normal per pixel seen between
        neighbouring highlights of both cameras (``phi``, degrees).
    lattice_gap_px : float
        With this source array, the median distance (pixels) from a camera-1
        highlight to camera 2's nearest one on a surface turning
        ``phi`` per pixel (:func:`shinysim.recon.stereo.lattice_gaps`): the
        spacing bound on what can be matched.
    expected_matchable : float
        The share of camera-1 highlights with a camera-2 highlight within one
        pixel by that bound.
    reason : str
        Why there are no matches (empty when there are some).
    seconds : dict
        Wall-clock seconds of each stage: ``candidates`` (the index),
        ``tests`` (the exact tests), ``relaxation`` (support weights and
        the relaxation), ``uniqueness`` and ``reflectance`` (reflectance
        matching of the accepted pairs); stages not reached are absent.
    """

    point: np.ndarray
    normal: np.ndarray
    row1: np.ndarray
    col1: np.ndarray
    row2: np.ndarray
    col2: np.ndarray
    source1: np.ndarray
    source2: np.ndarray
    index1: np.ndarray
    index2: np.ndarray
    d_mm: np.ndarray
    normal_gap_deg: np.ndarray
    e1_mm: np.ndarray
    e2_mm: np.ndarray
    delta_z_mm: np.ndarray
    confidence: np.ndarray
    support: np.ndarray
    crossing: np.ndarray | None = None
    refined: np.ndarray | None = None
    radius_mm: np.ndarray | None = None
    n_examined: int = 0
    n_rejected_distance: int = 0
    n_rejected_depth: int = 0
    n_rejected_normal: int = 0
    n_candidates: int = 0
    n_rejected_delta_z: int = 0
    n_rejected_e: int = 0
    n_rejected_uniqueness: int = 0
    relax_iterations: int = 0
    d0_mm: float = float("nan")
    max_normal_gap_deg: float = float("nan")
    neighbourhood_mm: float = float("nan")
    normal_turn_deg_per_px: float = float("nan")
    lattice_gap_px: float = float("nan")
    expected_matchable: float = float("nan")
    reason: str = ""
    counts: dict = field(default_factory=dict, repr=False)
    seconds: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        m = self.point.shape[0]
        if self.crossing is None:
            self.crossing = self.point.copy()
        if self.refined is None:
            self.refined = np.zeros(m, bool)
        if self.radius_mm is None:
            self.radius_mm = np.full(m, np.nan)

    def __len__(self) -> int:
        return int(self.point.shape[0])

    @staticmethod
    def columns() -> tuple[str, ...]:
        """Column names of :meth:`as_dict` and :meth:`to_csv` (:data:`STEREO_COLUMNS`)."""
        return STEREO_COLUMNS

    def as_dict(self) -> dict[str, np.ndarray]:
        """One (M,) array per column of :meth:`columns`: the components of ``point``, ``normal`` and
        ``crossing``, and the attribute of that name."""
        parts = {name: vec[:, k] for names, vec in ((("x_mm", "y_mm", "z_mm"), self.point),
                                                     (("nx", "ny", "nz"), self.normal),
                                                     (("cx_mm", "cy_mm", "cz_mm"), self.crossing))
                 for k, name in enumerate(names)}
        return {c: parts[c] if c in parts else getattr(self, c) for c in STEREO_COLUMNS}

    def to_csv(self, path, *, overwrite: bool = False):
        """Write the matches as ``matches.csv`` (:func:`shinysim.io.matches.write_matches`): a header of
        :meth:`columns`, one row per match.

        Floats are written with ``repr`` (they read back exactly), integers as
        integers. Refuses to replace an existing file unless ``overwrite``.

        Returns
        -------
        Path
        """
        return write_matches(path, self.as_dict(), overwrite=overwrite)
