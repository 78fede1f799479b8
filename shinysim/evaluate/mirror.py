"""Exact highlights of a scanned object in a rig: where each source's mirror point lies, seen by each camera.

The truth that highlight detection and stereo matching are scored against,
computed from the object's analytic parts (spheres and square facets), never
from what a detector found: for every source and every part, the point whose
normal bisects the directions to the source and to the camera
(:func:`shinysim.theory.mirror.mirror_sphere_highlight` on a sphere, the
mirror image of the camera on a facet), its pixel, and whether the camera
sees it (in the image, neither the view nor the light path blocked by another
part). numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..conventions import normalize
from ..errors import OptionError
from ..objects.facet import Facet
from ..theory.mirror import mirror_sphere_highlight

__all__ = ["ANALYTIC_SHAPES", "ExactHighlights", "exact_highlights", "is_analytic", "nearest_on_object"]

#: Part shapes whose mirror points are computed exactly.
ANALYTIC_SHAPES = ("sphere", "facet")

#: A distant source stands this far away along its direction (mm): the normal it gives on a
#: part of radius r then differs from the limit by about r / 1e9 rad.
_FAR_MM = 1e9


@dataclass(frozen=True, eq=False)
class ExactHighlights:
    """Exact mirror highlights of one camera: one row per (source, part) that has a mirror point.

    Attributes
    ----------
    camera : int
        Index of the camera in the rig.
    source : (M,) int
    part : (M,) object
        Part name.
    point, normal : (M, 3) float
        The mirror point (mm) and the unit normal there.
    row, col : (M,) float
        Its continuous pixel coordinates.
    visible : (M,) bool
        Inside the image (pixel-centre range) and neither the view ray nor the light path blocked by
        another part.
    """

    camera: int
    source: np.ndarray
    part: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    row: np.ndarray
    col: np.ndarray
    visible: np.ndarray

    def __len__(self) -> int:
        return int(len(self.source))


def is_analytic(obj) -> bool:
    """Whether every part of a :class:`~shinysim.objects.registry.ScannedObject` is a sphere or a facet."""
    return bool(obj.parts) and all(p.shape in ANALYTIC_SHAPES for p in obj.parts.values())


def _facet_frame(part):
    m = Facet(part.center_mm, part.normal, part.size_mm).to_world()
    half = 0.5 * part.size_mm
    return np.asarray(part.center_mm, float), m[:3, 2], m[:3, 0] / half, m[:3, 1] / half, half


def _facet_mirror(part, S, distant, camera):
    """Mirror points on a facet: the point whose reflection of the camera's ray reaches each source."""
    c, n, u, v, half = _facet_frame(part)
    if camera.projection == "perspective":
        C = camera.position
        Cm = C - 2.0 * np.dot(C - c, n) * n  # the camera's mirror image
        # near source: on the line from S to the mirrored camera; distant: the ray from Cm along -dir
        d = np.where(distant[:, None], -S, Cm - S)
        base = np.where(distant[:, None], Cm, S)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.dot(c - base, n) / (d @ n)
        P = base + t[:, None] * d
        cam_side = np.dot(C - c, n) > 0
    else:
        w = -camera.forward                                 # towards the camera
        r = 2.0 * np.dot(w, n) * n - w                      # towards the source, after reflection
        with np.errstate(divide="ignore", invalid="ignore"):
            s = ((S - c) @ n) / np.dot(r, n)
        P = S - s[:, None] * r
        cam_side = np.dot(w, n) > 0
        # a distant source in exactly the mirror direction lights the whole facet: its centre stands for it
        P = np.where(distant[:, None], c, P)
        ok_far = np.abs(normalize(S) @ r - 1.0) < 1e-12
        P[distant & ~ok_far] = np.nan
    rel = P - c
    inside = (np.abs(rel @ u) <= half) & (np.abs(rel @ v) <= half)
    lit = np.where(distant, S @ n > 0, (S - c) @ n > 0)
    ok = inside & lit & cam_side & np.all(np.isfinite(P), axis=1)
    return P, np.broadcast_to(n, P.shape).copy(), ok


def _blocked(P, D, far, parts, own):
    """Whether the segment ``P + t D``, ``0 < t < far`` (``far`` inf: a ray) meets any part but ``own``."""
    hit = np.zeros(len(P), bool)
    eps = 1e-9
    for name, part in parts.items():
        sel = own != name
        if not sel.any():
            continue
        if part.shape == "sphere":
            c, r = np.asarray(part.center_mm, float), float(part.radius_mm)
            m = P - c
            b = np.einsum("ij,ij->i", m, D)
            q = np.einsum("ij,ij->i", m, m) - r * r
            disc = b * b - q
            with np.errstate(invalid="ignore"):
                root = np.sqrt(disc)
            t0, t1 = -b - root, -b + root
            meets = (disc > 0) & (t1 > eps) & (t0 < far)
        else:
            c, n, u, v, half = _facet_frame(part)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((c - P) @ n) / (D @ n)
            Q = P + t[:, None] * D
            meets = (t > eps) & (t < far) & (np.abs((Q - c) @ u) <= half) & (np.abs((Q - c) @ v) <= half)
        hit |= sel & meets
    return hit


def exact_highlights(obj, rig, camera_index: int = 0) -> ExactHighlights:
    """Every source's exact mirror highlight on every analytic part of ``obj``, seen by one camera.

    Parameters
    ----------
    obj : ScannedObject
        Its parts must all be spheres or facets (:func:`is_analytic`).
    rig : Rig
    camera_index : int

    Returns
    -------
    ExactHighlights

    Raises
    ------
    OptionError
        An object with a mesh or joint part (no exact mirror points), a camera index out of range.

    On the paper's rig every fiber lies in the x-z plane, so the sphere at the origin mirrors all 21 of
    them onto the image's middle row:

    >>> from shinysim.objects.registry import scanned_object
    >>> from shinysim.rig import shiny_1988
    >>> ex = exact_highlights(scanned_object("sphere"), shiny_1988(resolution=64))
    >>> len(ex), int(ex.visible.sum()), bool(np.allclose(ex.row, 31.5))
    (21, 21, True)
    """
    if not is_analytic(obj):
        shapes = sorted({p.shape for p in obj.parts.values()} - set(ANALYTIC_SHAPES))
        raise OptionError(f"{obj.name!r} has {', '.join(shapes) or 'no'} parts: exact mirror points are known "
                          f"for {' and '.join(ANALYTIC_SHAPES)} parts only")
    if not 0 <= int(camera_index) < len(rig.cameras):
        raise OptionError(f"camera_index {camera_index} is out of range 0..{len(rig.cameras) - 1}")
    cam = rig.cameras[int(camera_index)]
    distant = np.asarray(rig.source_distant, bool)
    S = np.asarray(rig.source_positions, float)
    n_src = len(S)
    rows = []
    for name, part in obj.parts.items():
        if part.shape == "sphere":
            c = np.asarray(part.center_mm, float)
            Sn = np.where(distant[:, None], c + _FAR_MM * normalize(S), S)
            view = (dict(camera_position=cam.position) if cam.projection == "perspective"
                    else dict(view_direction=-cam.forward))
            P, n = mirror_sphere_highlight(Sn, center=c, radius=float(part.radius_mm), **view)
            # a source inside the sphere or behind it (from the camera) has no mirror point
            lit = np.einsum("ij,ij->i", normalize(Sn - P), n) > 0
            ok = lit & np.all(np.isfinite(P), axis=1)
        else:
            P, n, ok = _facet_mirror(part, S, distant, cam)
        rows.append((np.arange(n_src)[ok], np.full(int(ok.sum()), name, dtype=object), P[ok], n[ok]))
    source = np.concatenate([r[0] for r in rows]).astype(np.int64)
    part_of = np.concatenate([r[1] for r in rows])
    P = np.concatenate([r[2] for r in rows]).reshape(-1, 3)
    n = np.concatenate([r[3] for r in rows]).reshape(-1, 3)
    row, col = cam.project(P) if len(P) else (np.zeros(0), np.zeros(0))
    h, w = cam.shape
    inside = np.isfinite(row) & np.isfinite(col) & (row >= 0) & (row <= h - 1) & (col >= 0) & (col <= w - 1)
    if cam.projection == "perspective":
        to_cam = cam.position - P
        cam_far = np.linalg.norm(to_cam, axis=1)
        cam_dir = to_cam / np.where(cam_far > 0, cam_far, 1.0)[:, None]
    else:
        cam_dir, cam_far = np.broadcast_to(-cam.forward, P.shape), np.full(len(P), np.inf)
    Ss = S[source]
    to_src = np.where(distant[source][:, None], normalize(Ss), Ss - P)
    src_far = np.where(distant[source], np.inf, np.linalg.norm(to_src, axis=1))
    src_dir = normalize(to_src)
    visible = inside & ~_blocked(P, cam_dir, cam_far, obj.parts, part_of) \
        & ~_blocked(P, src_dir, src_far, obj.parts, part_of)
    return ExactHighlights(int(camera_index), source, part_of, P, n, np.asarray(row, float),
                           np.asarray(col, float), visible)


def nearest_on_object(obj, points, parts):
    """Each point's nearest point on a named analytic part of ``obj``, its distance and the exact normal.

    On a sphere the foot is the radial projection; on a facet the nearest point of its square.

    Parameters
    ----------
    obj : ScannedObject
    points : (N, 3) array_like, millimetres
    parts : (N,) sequence of str or None
        The part of each point (None: no foot).

    Returns
    -------
    distance : (N,) ndarray, millimetres (NaN where no foot)
    normal, foot : (N, 3) ndarray
    """
    p = np.asarray(points, float).reshape(-1, 3)
    parts = np.asarray(parts, dtype=object).reshape(-1)
    dist = np.full(len(p), np.nan)
    normal = np.full((len(p), 3), np.nan)
    foot = np.full((len(p), 3), np.nan)
    for name, prt in obj.parts.items():
        sel = np.flatnonzero(parts == name)
        if not len(sel) or prt.shape not in ANALYTIC_SHAPES:
            continue
        q = p[sel]
        if prt.shape == "sphere":
            c = np.asarray(prt.center_mm, float)
            rad = np.linalg.norm(q - c, axis=1)
            n = (q - c) / np.where(rad > 0, rad, np.nan)[:, None]
            f = c + float(prt.radius_mm) * n
        else:
            c, n0, u, v, half = _facet_frame(prt)
            rel = q - c
            f = c + np.clip(rel @ u, -half, half)[:, None] * u + np.clip(rel @ v, -half, half)[:, None] * v
            n = np.broadcast_to(n0, q.shape)
        dist[sel], normal[sel], foot[sel] = np.linalg.norm(q - f, axis=1), n, f
    return dist, normal, foot
