r"""Highlights of complex shiny objects: several per source, subdivided, flagged.

:func:`find_highlights` finds every highlight of a solder-joint stack
(thresholded against one scan-wide reference level, large regions subdivided
as the paper does, inter-reflections flagged by :data:`FLAG_RULES` and kept
in the table) with its normal on a known plane; these are options of
:func:`shinysim.recon.pipeline.detect_stack`, with the solder defaults in
:class:`HighlightParams`. :func:`find_toe` finds where a fillet meets the pad.
numpy + scikit-image only. Why each step, and the measured brightness of
direct and bounced highlights: ``docs/solder.md``, section "Highlights".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._shared import with_overrides
from ..conventions import bisector, normalize
from ..errors import OptionError
from .detect import FLAG_RULES, DetectParams, smoothed_frames
from .normals import NORMAL_MODELS, highlight_normals
from .pipeline import detect_stack

__all__ = [
    "FLAG_RULES",
    "HighlightParams",
    "find_highlights",
    "select_band",
    "find_toe",
    "normals_at_points",
    "blob_area",
]


@dataclass(frozen=True)
class HighlightParams:
    """Settings of :func:`find_highlights`.

    Parameters
    ----------
    threshold : float
        Detection level as a fraction of the scan's reference level, in (0, 1].
    smooth_px : float
        Standard deviation of the Gaussian applied to every frame before
        thresholding, pixels (0: none).
    min_area : int
        Smaller regions are dropped (noise).
    max_area : int or None
        Regions with more pixels are subdivided (paper Section IV).
    flag_rule : {"dim", "none"}
        Inter-reflection rule (:data:`FLAG_RULES`).
    dim_fraction : float
        ``"dim"``: highlights whose peak is below this fraction of the
        reference level are flagged.
    model : {"perspective", "orthographic", "fixed"}
        Camera model for the normals.
    """

    threshold: float = 0.15
    smooth_px: float = 0.7
    min_area: int = 2
    max_area: int | None = 12
    flag_rule: str = "dim"
    dim_fraction: float = 0.5
    model: str = "perspective"

    def __post_init__(self):
        if self.model not in NORMAL_MODELS:
            raise OptionError(f"model must be one of {NORMAL_MODELS}, got {self.model!r}")
        self.detect_params()  # checks every detection field

    def detect_params(self):
        """These settings as :class:`~shinysim.recon.detect.DetectParams` of the one pipeline."""
        return DetectParams(threshold=self.threshold, threshold_mode="scan", smooth_px=self.smooth_px,
                            min_area=self.min_area, max_area=self.max_area, flag_rule=self.flag_rule,
                            dim_fraction=self.dim_fraction)


def find_highlights(stack, params=None, *, plane_z=None, mask=None, **kwargs):
    """Every highlight of every frame, with normals and inter-reflection flags.

    Parameters
    ----------
    stack : shinysim.io.Stack
    params : HighlightParams, optional
        Keyword arguments override single fields.
    plane_z : float, optional
        Height of the plane the surface points are assumed on, mm (default
        the rig's reference plane). For solder joints: the pad top.
    mask : (H, W) bool, optional
        Region to search.

    Returns
    -------
    HighlightTable
        Detection's table (``rel_peak``: peak / its ``reference`` level;
        ``interreflection``: the flag) with ``x``, ``y``, ``z_plane`` (the
        assumed surface point, mm) and ``normal`` ((N, 3), unit).
    """
    params = with_overrides(HighlightParams, params, kwargs)
    out = detect_stack(stack, params.detect_params(), mask=mask).table
    n = len(out)
    z = stack.rig.reference_z if plane_z is None else float(plane_z)
    pts = stack.camera.backproject_to_plane(out["row"], out["col"], z).reshape(-1, 3)
    out["x"], out["y"] = pts[:, 0], pts[:, 1]
    out["z_plane"] = np.full(n, z)
    out["normal"] = highlight_normals(out["row"], out["col"], out["source"], stack.rig, model=params.model,
                                      camera_index=stack.camera_index, plane_z=z).reshape(-1, 3)
    return out


def blob_area(table):
    """(N,) int: pixel area of the whole connected region each highlight came from.

    Subdivided regions give several highlights; this is their parent's area.
    """
    key = table["source"].astype(np.int64) * (1 << 32) + table["blob"].astype(np.int64)
    _, inv = np.unique(key, return_inverse=True)
    return np.bincount(inv, weights=table["area"]).astype(int)[inv]


def select_band(table, y_center=0.0, half_width=0.02, *, keep_flagged=False):
    """Indices of the highlights of one cross-section band ``|y - y_center| <= half_width``.

    Parameters
    ----------
    table : HighlightTable
        From :func:`find_highlights`.
    y_center, half_width : float, mm
    keep_flagged : bool
        Keep highlights flagged as inter-reflections (default: leave them out).

    Returns
    -------
    (K,) int ndarray
    """
    if not (np.isfinite(half_width) and half_width > 0):
        raise OptionError(f"half_width must be > 0 mm, got {half_width!r}")
    sel = np.abs(table["y"] - y_center) <= half_width
    if not keep_flagged:
        sel &= ~table["interreflection"]
    return np.flatnonzero(sel)


def find_toe(stack, *, x_before=None, y_center=0.0, half_width=0.02, plane_z=None, smooth_px=0.7, sources=None,
             level=0.5, min_run_mm=0.01):
    """Where a fillet meets the pad, from the frames in which the pad is lit.

    In the frames of the sources nearest the camera axis a flat shiny pad
    reflects light into the camera, while solder sloping by more than a few
    degrees stays dark. Along the cross-section band the lit runs are found
    (brightness at least a quarter of the band's peak, at least
    ``min_run_mm`` long); with the lead towards +x (the layout of
    ``docs/solder.md``) the exposed pad in front of the joint is the last
    run that ends before the first fillet point ``x_before`` (or, without
    it, the first run from the -x side). The toe is that run's +x end: where
    the brightness falls through ``level`` times the run's median brightness
    (linear interpolation between pixels). Each frame gives an edge and the
    one furthest towards +x is taken: a pad strip darkened near the fillet in
    one frame (a partial shadow, light the fillet takes away) only moves
    that frame's edge back towards -x. Each frame's median (the dark level
    of a real camera: most of the field is the dull board) is subtracted
    first.

    Parameters
    ----------
    stack : shinysim.io.Stack
    x_before : float, optional, mm
        x of the fillet point nearest the pad (e.g. the first direct
        highlight of the band).
    y_center, half_width : float, mm
        The cross-section band.
    plane_z : float, optional
        Height of the pad top, mm (to map pixels to x).
    smooth_px : float
        Gaussian smoothing of the frames, pixels.
    sources : sequence of int, optional
        Frames to use (default: the two sources nearest the camera axis).
    level : float
        Fraction of the pad brightness that marks the edge.
    min_run_mm : float
        Shortest lit run that counts as pad.

    Returns
    -------
    x_toe : float, mm
        NaN when no lit pad run is found.
    """
    rig, cam = stack.rig, stack.camera
    z = rig.reference_z if plane_z is None else float(plane_z)
    if not (0 < level < 1):
        raise OptionError(f"level must be in (0, 1), got {level!r}")
    if sources is None:
        to_src = rig.source_directions(np.array([0.0, 0.0, z]))
        axis_angle = np.arccos(np.clip(to_src @ (-cam.forward), -1, 1))
        sources = np.argsort(axis_angle)[:2]
    frames = smoothed_frames(stack.frames[list(sources)], smooth_px)
    # a camera's dark level (offset, stray light) would make every pixel "lit":
    # subtract each frame's median first (most of the field is the dull board)
    frames = frames - np.median(frames.reshape(len(frames), -1), axis=1)[:, None, None]
    H, W = cam.shape
    rows = np.arange(H)
    ys = cam.backproject_to_plane(rows, np.full(H, 0.5 * (W - 1)), z)[:, 1]
    band = np.abs(ys - y_center) <= half_width
    if not band.any():
        return float("nan")
    xs = cam.backproject_to_plane(np.full(W, float(np.mean(rows[band]))), np.arange(W), z)[:, 0]
    order = np.argsort(xs)  # walk along +x whatever the image orientation
    xs = xs[order]
    step = np.abs(np.median(np.diff(xs)))
    min_px = max(2, int(np.ceil(min_run_mm / step)))
    # the first fillet highlight may lie within a pixel or two of the toe (a shallow
    # foot lit by the same near-axis sources): edges up to two pixels past it count
    before = None if x_before is None else x_before + 2 * step
    toes = [_pad_edge(f[band].mean(axis=0)[order], xs, level, min_px, before) for f in frames]
    toes = [t for t in toes if np.isfinite(t)]
    return max(toes) if toes else float("nan")


def _pad_edge(profile, xs, level, min_px, x_before):
    """+x end of the pad's lit run along one frame's band profile (see find_toe)."""
    peak = profile.max()
    if peak <= 0:
        return float("nan")
    lit = np.concatenate([[False], profile >= 0.25 * peak, [False]])
    starts, stops = np.flatnonzero(lit[1:] & ~lit[:-1]), np.flatnonzero(lit[:-1] & ~lit[1:])  # runs [i, j)
    edges = []
    for i, j in zip(starts, stops):
        if j - i < min_px:
            continue
        thr = level * float(np.median(profile[i:j]))
        below = np.flatnonzero(profile[j:] < thr)  # the brightness falls through thr between k and k + 1
        if len(below):
            k = j + int(below[0]) - 1
            t = (profile[k] - thr) / (profile[k] - profile[k + 1])
            edges.append(float(xs[k] + t * (xs[k + 1] - xs[k])))
        if x_before is None:
            break
    if x_before is not None:
        edges = [e for e in edges if e < x_before]
        return max(edges) if edges else float("nan")
    return edges[0] if edges else float("nan")


def normals_at_points(points, sources, stack, *, mirror_z=None):
    """Mirror-law normals at known surface points, optionally via a plane mirror.

    Parameters
    ----------
    points : (N, 3) array_like, mm
        Surface points (e.g. pixel rays met at reconstructed heights).
    sources : (N,) int array_like
    stack : shinysim.io.Stack
        For its rig and camera.
    mirror_z : float, optional
        Height of a horizontal plane mirror (a shiny pad). The light then
        reaches the point from the source's mirror image ``(x, y, 2 z_m - z)``
        below the plane: the normal of a *second-bounce* highlight
        (surface -> pad -> source).

    Returns
    -------
    (N, 3) ndarray
        Unit normals bisecting the directions to the (mirrored) source and to
        the viewer (the perspective camera model).
    """
    rig, cam = stack.rig, stack.camera
    points = np.asarray(points, float).reshape(-1, 3)
    sources = np.asarray(sources, int).reshape(-1)
    pos = rig.source_positions[sources].copy()
    distant = rig.source_distant[sources]
    if mirror_z is not None:
        pos[:, 2] = np.where(distant, -pos[:, 2], 2.0 * mirror_z - pos[:, 2])
    to_src = np.where(distant[:, None], normalize(pos), normalize(pos - points))
    return bisector(to_src, cam.view_directions(points))
