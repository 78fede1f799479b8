"""A display's dots in one frame: detection and identification by their place in the grid.

A display that shows a grid of dots is an array of point sources lit all at
once (fixed-pattern deflectometry): its reflection in a mirror is one frame
of structured highlights, each told apart not by the frame it is lit in (the
paper's sequential scan) but by its place in the grid.

* :func:`dot_signal`: the frame against its local background (dark dots on a
  bright reflected screen, or bright dots on a dark one), so that every dot
  is a non-negative bump on zero;
* :func:`optic_mask`: the bright region the mirror reflects the screen in;
* :func:`detect_dots`: the dots, found and measured by the one detection
  engine (:func:`shinysim.recon.detect.detect_highlights`, each region cut at
  a fraction of its own peak, background-subtracted weighted centroids), with
  their distance to the mask's edge (a dot cut by the mirror's edge has a
  biased centroid and is flagged ``cut``);
* :func:`index_dots`: each dot's grid index, by a walk over the lattice from
  a dot of known index. A dot is placed only when exactly one detected dot
  lies near the position its placed neighbours predict, and a placed dot that
  disagrees with the local lattice of its neighbours is taken out again: a
  wrong index (about one screen pitch of slope, ~2 mrad on a heliostat
  facet) is never assigned silently; dots that cannot be placed are counted.

numpy + SciPy + scikit-image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .._shared import check_choice, check_number, with_overrides
from ..errors import FrameError, OptionError
from ..io.table import HighlightTable
from .detect import DetectParams, detect_highlights

__all__ = ["DOT_POLARITIES", "DotIndex", "DotParams", "detect_dots", "dot_signal", "index_dots", "optic_mask"]

#: What a dot is against the screen around it.
DOT_POLARITIES = ("dark", "bright")

_STEPS = ((1, 0), (-1, 0), (0, 1), (0, -1))


@dataclass(frozen=True)
class DotParams:
    """Settings of dot detection and identification.

    Parameters
    ----------
    polarity : {"dark", "bright"}
        Dark dots on a bright screen (SOFAST's fixed pattern) or bright dots
        on a dark one.
    background_px : int
        Side of the window of the local background estimate (a grey closing
        for dark dots, an opening for bright ones, then a median of the same
        size): wider than a dot, narrower than the dot pitch in the image.
    threshold : float
        Each dot is measured over its pixels at or above this fraction of
        its own peak (the detection engine's ``"highlight"`` mode): low, so
        that the weighted centroid sees the whole blurred dot.
    edge_margin_px : float
        A dot whose centre is nearer the mask's edge than its radius
        (``sqrt(area / pi)``) plus this margin is cut by the mirror's edge:
        flagged ``cut``, used to walk the lattice but not as a measurement.
    search : float
        A dot is looked for within this fraction of the local pitch of the
        position its placed neighbours predict.
    unique : float
        ... and placed only if no other dot lies within this fraction of
        the pitch of that position (else it is ambiguous, and left out).
    max_gap : int
        Steps tried along a lattice direction past missing dots (1: none
        skipped).
    check : float
        A placed dot farther than this fraction of the pitch from where the
        lattice of its placed neighbours within two steps puts it (a
        quadratic map of the index) is taken out again (``inconsistent``): a
        wrong index is a whole pitch off, the waviness of a real mirror's
        reflected grid under 0.2 of one.
    """

    polarity: str = "dark"
    background_px: int = 9
    threshold: float = 0.1
    edge_margin_px: float = 1.0
    search: float = 0.3
    unique: float = 0.6
    max_gap: int = 2
    check: float = 0.35

    def __post_init__(self):
        check_choice("polarity", self.polarity, DOT_POLARITIES)
        check_number("background_px", self.background_px, lo=3, hi=255, integer=True)
        check_number("threshold", self.threshold, lo=0, lo_open=True, hi=1)
        check_number("edge_margin_px", self.edge_margin_px, lo=0, hi=100)
        check_number("search", self.search, lo=0, lo_open=True, hi=0.5)
        check_number("unique", self.unique, lo=self.search, hi=1)
        check_number("max_gap", self.max_gap, lo=1, hi=5, integer=True)
        check_number("check", self.check, lo=0, lo_open=True, hi=0.5)


def _image(image, name):
    a = np.asarray(image)
    if a.ndim != 2 or a.size == 0:
        raise FrameError(f"must be one 2-D image, got shape {a.shape}", field=name)
    if not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating):
        raise FrameError(f"must hold real numbers, got {a.dtype}", field=name)
    a = a.astype(np.float64)
    if not np.all(np.isfinite(a)):
        raise FrameError("holds NaN or inf", field=name)
    return a


def dot_signal(image, params: DotParams | None = None, **kwargs) -> tuple[np.ndarray, np.ndarray]:
    """The frame as non-negative dots on zero, and the background they were taken from.

    Parameters
    ----------
    image : (H, W) array_like
        One frame (any real dtype; linear intensity).
    params : DotParams, optional
        ``polarity`` and ``background_px`` are used; keywords override.

    Returns
    -------
    signal : (H, W) float64
        ``background - image`` for dark dots, ``image - background`` for
        bright ones, clipped at 0.
    background : (H, W) float64
        The local background: a grey closing (dark dots) or opening
        (bright) of side ``background_px``, which removes every feature
        narrower than the window, then a median of the same side.
    """
    p = with_overrides(DotParams, params, kwargs)
    a = _image(image, "image")
    size = (p.background_px, p.background_px)
    if p.polarity == "dark":
        bg = ndimage.grey_closing(a, size=size)
    else:
        bg = ndimage.grey_opening(a, size=size)
    bg = ndimage.median_filter(bg, size=size)
    sig = bg - a if p.polarity == "dark" else a - bg
    return np.clip(sig, 0.0, None), bg


def optic_mask(background, *, min_fraction: float = 0.05) -> np.ndarray:
    """The mirror's region: where it reflects the lit screen.

    Parameters
    ----------
    background : (H, W) array_like
        The local background of :func:`dot_signal` (for dark dots: the
        screen's brightness with the dots closed over).
    min_fraction : float
        Bright connected regions smaller than this fraction of the largest
        are dropped (glints, the screen seen directly).

    Returns
    -------
    (H, W) bool
        Above Otsu's threshold of ``background``, in regions of at least
        ``min_fraction`` of the largest, holes filled (several facets of an
        ensemble stay separate regions).
    """
    from skimage.filters import threshold_otsu

    bg = _image(background, "background")
    if float(bg.max()) <= float(bg.min()):
        raise FrameError("is flat: no bright mirror region to find", field="background")
    bright = bg > threshold_otsu(bg)
    labels, n = ndimage.label(bright)
    sizes = np.bincount(labels.ravel(), minlength=n + 1)[1:]
    keep = np.flatnonzero(sizes >= min_fraction * sizes.max()) + 1
    return ndimage.binary_fill_holes(np.isin(labels, keep))


def detect_dots(image, params: DotParams | None = None, *, mask=None, name: str = "image",
                **kwargs) -> HighlightTable:
    """The dots of one frame, measured by the one detection engine.

    Parameters
    ----------
    image : (H, W) array_like
    params : DotParams, optional
    mask : (H, W) bool, optional
        The mirror's region (default: :func:`optic_mask` of the frame's
        background).
    name : str
        Used in error messages.

    Returns
    -------
    HighlightTable
        One row per dot: ``row``, ``col`` (background-subtracted,
        intensity-weighted centroid), ``area``, ``peak`` (depth below the
        background for dark dots), ..., ``cut`` (the dot touches the frame's
        border or is cut by the mask's edge), and ``edge_px`` (distance of the
        centroid to the mask's edge, pixels).
    """
    p = with_overrides(DotParams, params, kwargs)
    signal, background = dot_signal(image, p)
    if mask is None:
        mask = optic_mask(background)
    mask = np.asarray(mask, bool)
    if mask.shape != signal.shape:
        raise FrameError(f"mask shape {mask.shape} differs from the image's {signal.shape}", field="mask")
    table = detect_highlights(signal, DetectParams(threshold_mode="highlight", threshold=p.threshold,
                                                   hot_pixels=False, min_area=2,
                                                   noise_sigma=_screen_noise(image, mask, signal)),
                              mask=mask, name=name, specks=False)
    edt = ndimage.distance_transform_edt(mask)
    edge = ndimage.map_coordinates(edt, [table["row"], table["col"]], order=1, mode="constant")
    radius = np.sqrt(table["area"] / np.pi)
    table["edge_px"] = edge
    table["cut"] = table["cut"] | (edge < radius + p.edge_margin_px)
    return table


def _screen_noise(image, mask, signal):
    """The frame's pixel noise on the lit mirror, from horizontal differences of neighbours inside ``mask``.

    Measured on the frame, not on the signal (clipped at zero, mostly zero): the median absolute deviation
    of the differences, first of all pairs, then again of the pairs where neither pixel is in a dot (signal
    within 3 of those deviations of zero), so that the dots' edges do not inflate it.
    """
    a = np.asarray(image, np.float64)
    both = mask[:, 1:] & mask[:, :-1]
    d = np.diff(a, axis=1)
    sigma = 0.0
    for _ in range(2):
        sel = d[both]
        if sel.size == 0:
            return 0.0
        sigma = float(1.4826 / np.sqrt(2.0) * np.median(np.abs(sel - np.median(sel))))
        quiet = signal <= 3.0 * sigma
        both = both & quiet[:, 1:] & quiet[:, :-1]
    return sigma


@dataclass(frozen=True)
class DotIndex:
    """Grid indices of detected dots (:func:`index_dots`).

    Attributes
    ----------
    index : (n, 2) int64
        (x index, y index) of each dot; meaningful where ``identified``.
    identified : (n,) bool
    pitch_px : float
        Median distance between neighbouring dots in the image.
    n_ambiguous : int
        Predicted positions with more than one dot near them (left out).
    n_inconsistent : int
        Dots placed by the walk and taken out again by the lattice check.
    n_unreached : int
        Detected dots the walk never reached (outside the region, across a
        seam, beyond a gap of more than ``max_gap``).
    """

    index: np.ndarray
    identified: np.ndarray
    pitch_px: float
    n_ambiguous: int
    n_inconsistent: int
    n_unreached: int

    @property
    def n_identified(self) -> int:
        return int(self.identified.sum())


def _first_steps(pts, tree, i0, pitch, axes):
    """The lattice steps of x and y at the origin dot, from its neighbours within 1.5 pitches.

    A direction whose neighbour is missing takes the opposite neighbour's step reversed, and with both
    missing the other axis' step turned a quarter (the lattice is locally near-square).
    """
    dist, near = tree.query(pts[i0], k=min(9, len(pts)))
    vec = pts[near[1:]] - pts[i0]
    vec = vec[dist[1:] < 1.5 * pitch]
    steps = []
    for axis in axes:
        axis = axis / np.linalg.norm(axis)
        cos = vec @ axis / np.linalg.norm(vec, axis=1) if len(vec) else np.zeros(0)
        if np.any(cos > 0.8):
            steps.append(vec[np.argmax(cos)])
        elif np.any(cos < -0.8):
            steps.append(-vec[np.argmin(cos)])
        else:
            steps.append(None)
    ex, ey = steps
    if ex is None and ey is None:
        raise OptionError(f"the origin dot has no neighbour within 1.5 pitches ({1.5 * pitch:.1f} px) along the "
                          "index axes: is the origin right?")
    quarter = np.array([[0.0, -1.0], [1.0, 0.0]])  # (row, col): turns +col onto +row for the default axes
    sign = np.sign(np.linalg.det(np.asarray(axes, float)[:, ::-1])) or 1.0
    if ex is None:
        ex = sign * (quarter @ ey)
    if ey is None:
        ey = -sign * (quarter @ ex)
    return ex, ey


def index_dots(rows, cols, origin, origin_index=(0, 0), *, axes=((0.0, 1.0), (1.0, 0.0)), region=None,
               params: DotParams | None = None, **kwargs) -> DotIndex:
    """Each dot's grid index, by a lattice walk from a dot of known index.

    Parameters
    ----------
    rows, cols : (n,) array_like
        Dot centroids, pixels.
    origin : (row, col)
        Image position of the dot whose index is ``origin_index`` (the
        nearest detected dot is taken, within ``search`` of a pitch... or a
        whole pitch at most).
    origin_index : (ix, iy)
    axes : ((drow, dcol), (drow, dcol))
        Image directions in which the x and the y index grow (roughly):
        default +x with columns, +y with rows (SOFAST's fixed pattern seen
        in a facet).
    region : (H, W) bool, optional
        Only dots inside are placed (one facet of an ensemble).
    params : DotParams, optional
        ``search``, ``unique``, ``max_gap`` and ``check`` are used.

    Returns
    -------
    DotIndex

    Raises
    ------
    OptionError
        Fewer than 5 dots, or no dot near ``origin``.
    """
    p = with_overrides(DotParams, params, kwargs)
    pts = np.column_stack([np.asarray(rows, float), np.asarray(cols, float)])
    n = len(pts)
    if n < 5 or not np.all(np.isfinite(pts)):
        raise OptionError(f"index_dots needs at least 5 finite dot positions, got {n}")
    inside = np.ones(n, bool)
    if region is not None:
        region = np.asarray(region, bool)
        r = np.clip(np.round(pts[:, 0]).astype(int), 0, region.shape[0] - 1)
        c = np.clip(np.round(pts[:, 1]).astype(int), 0, region.shape[1] - 1)
        inside = region[r, c]
    tree = cKDTree(pts)
    pitch = float(np.median(tree.query(pts, k=2)[0][:, 1]))
    d0, i0 = tree.query(np.asarray(origin, float))
    if d0 > pitch or not inside[i0]:
        raise OptionError(f"no dot within a pitch ({pitch:.1f} px) of the origin {tuple(origin)} "
                          f"(nearest {d0:.1f} px away{'' if inside[i0] else ', outside the region'})")
    ex, ey = _first_steps(pts, tree, int(i0), pitch, np.asarray(axes, float))

    at: dict[tuple[int, int], int] = {}
    owner = np.full(n, False)
    index = np.zeros((n, 2), np.int64)

    def place(ij, k):
        at[ij] = k
        owner[k] = True
        index[k] = ij

    def step_vector(ij, dv):
        # the lattice step along dv where ij is, from placed pairs around it
        found = []
        for da, db in ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)):
            a = (ij[0] + da, ij[1] + db)
            if a not in at:
                continue
            for sign in (1, -1):
                b = (a[0] + sign * dv[0], a[1] + sign * dv[1])
                if b in at:
                    found.append(sign * (pts[at[b]] - pts[at[a]]))
        return np.mean(found, axis=0) if found else ex * dv[0] + ey * dv[1]

    place(tuple(int(v) for v in origin_index), int(i0))
    frontier = [tuple(int(v) for v in origin_index)]
    ambiguous = 0
    while frontier:
        grown = []
        for ij in frontier:
            base = pts[at[ij]]
            for dv in _STEPS:
                for step in range(1, p.max_gap + 1):
                    q = (ij[0] + step * dv[0], ij[1] + step * dv[1])
                    if q in at:
                        break
                    v = step_vector(ij, dv)
                    length = float(np.linalg.norm(v))
                    dist, cand = tree.query(base + step * v, k=2)
                    if dist[0] > p.search * length:
                        continue  # missing here: look one step farther
                    k = int(cand[0])
                    if dist[1] < p.unique * length or owner[k] or not inside[k]:
                        ambiguous += int(dist[1] < p.unique * length)
                        break
                    place(q, k)
                    grown.append(q)
                    break
        frontier = grown

    # the lattice check: every placed dot against the smooth lattice of its placed neighbours within two
    # steps (a quadratic map of the index, which follows the waviness a real mirror's slope errors give the
    # reflected grid, up to ~0.2 pitch on a heliostat facet; an affine one where fewer neighbours are placed)
    placed = np.flatnonzero(owner)
    inconsistent = np.zeros(n, bool)
    for k in placed:
        i, j = index[k]
        nb = [at[(i + a, j + b)] for a in range(-2, 3) for b in range(-2, 3)
              if (a or b) and (i + a, j + b) in at]
        rel = index[nb].astype(float) - (i, j)
        terms = [np.ones(len(nb)), rel[:, 0], rel[:, 1], rel[:, 0] ** 2, rel[:, 0] * rel[:, 1], rel[:, 1] ** 2]
        design = np.column_stack(terms)
        if len(nb) < 8 or np.linalg.matrix_rank(design) < 6:
            design = design[:, :3]
        if len(nb) < 4 or np.linalg.matrix_rank(design) < design.shape[1]:
            inconsistent[k] = True  # too isolated to be checked: left out, not trusted
            continue
        coef = np.linalg.lstsq(design, pts[nb], rcond=None)[0]
        if np.linalg.norm(coef[0] - pts[k]) > p.check * pitch:
            inconsistent[k] = True
    identified = owner & ~inconsistent
    return DotIndex(index=index, identified=identified, pitch_px=pitch, n_ambiguous=int(ambiguous),
                    n_inconsistent=int(inconsistent.sum()), n_unreached=int((~owner & inside).sum()))
