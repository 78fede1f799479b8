"""Procedural surface-mount solder-joint meshes for the SHINY rig.

Each joint is a few watertight triangle meshes (``trimesh.Trimesh``) in the
world frame of :mod:`shinysim.conventions` (millimetres, +z up towards the
camera, board top at ``z = 0``), built from the exact cross-sections of
:mod:`shinysim.objects.solder` swept straight along y. See ``docs/solder.md``
for the geometry, the defect classes and their parameter ranges.

Tessellation: every curved profile (fillet or ball, bridge, lead bends) is
sampled so that, on each facet, the angle between the facet normal and the
exact surface normal is at most :data:`TESSELLATION_BOUND` (0.1 deg)
anywhere on the facet; facets are at most :data:`MAX_FACET_LENGTH` long along
the profile. Vertex normals on curved profiles are the exact ones; flat faces
carry their own normal, with a :data:`CREASE_EPS`-wide shading bevel at sharp
edges, so the meshes stay watertight (one vertex per position) yet shade as
intended. The two y-facing end caps of each swept part (vertical faces the
overhead camera never sees) reuse the profile's vertex normals.

Regenerate the example meshes with::

    python -m shinysim.sim.solder --out meshes --seed 0
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from .._shared import refuse_existing, write_bytes, write_json
from ..conventions import normalize
from ..errors import OptionError
from ..objects.solder import (
    BOARD_HALF_WIDTH,
    BOARD_THICKNESS,
    JOINT_KINDS,
    LEAD_TYPES,
    SOLDER_SINK,
    JointParams,
    JointProfile,
    sample_params,
)

__all__ = [
    "JOINT_KINDS",
    "LEAD_TYPES",
    "JointParams",
    "JointProfile",
    "TESSELLATION_BOUND",
    "MAX_FACET_LENGTH",
    "CREASE_EPS",
    "MATERIALS",
    "Joint",
    "make_joint",
    "save_joint",
    "load_joint",
    "sample_params",
    "sample_surface",
    "write_ply",
    "main",
]

#: Largest angle, radians, between a facet normal and the exact normal at any
#: point of that facet, on every curved profile.
TESSELLATION_BOUND = math.radians(0.1)
#: Longest facet along a curved profile, mm.
MAX_FACET_LENGTH = 0.005
#: Width of the shading bevel at sharp edges, mm.
CREASE_EPS = 0.001

# The sampler aims below the bound so that the dense check grid's own
# resolution cannot push a facet past it.
_SAMPLING_MARGIN = 0.75

#: Material of each part, as Mitsuba 3 BSDF plugin names (the renderer picks
#: the metal and roughness; see docs/solder.md).
MATERIALS = {
    "board": "diffuse",
    "pad": "conductor",
    "lead": "roughconductor",
    "solder": "roughconductor",
}


# ---------------------------------------------------------------------------
# Profile sampling and 2-D polygons
# ---------------------------------------------------------------------------


def sample_surface(surface, bound=TESSELLATION_BOUND, max_length=MAX_FACET_LENGTH):
    """Sample an :class:`~shinysim.objects.solder.ArcSurface` for meshing.

    Greedy walk over a dense grid: a facet ends before the tangent angle
    spread inside it exceeds ``0.75 * bound`` or its length exceeds
    ``max_length``. Since a chord's direction equals the tangent direction at
    some point inside it (mean value theorem), the facet normal then differs
    from the exact normal by at most the spread, below ``bound``.

    Parameters
    ----------
    surface : ArcSurface
    bound : float, radians
    max_length : float, mm

    Returns
    -------
    x : (K,) float, mm
        Strictly increasing, from ``surface.x_start`` to ``surface.x_end``.
    """
    if not bound > 0:
        raise OptionError(f"bound must be positive, got {bound!r}")
    if not max_length > 0:
        raise OptionError(f"max_length must be positive, got {max_length!r}")
    xd = surface.tangent_angle_grid(20001, 8001)
    zd = surface.z(xd)
    th = np.arctan(surface.slope(xd)).tolist()
    ds = np.hypot(np.diff(xd), np.diff(zd))
    s = np.concatenate([[0.0], np.cumsum(ds)]).tolist()
    limit = _SAMPLING_MARGIN * bound
    keep = [0]
    i0 = 0
    lo = hi = th[0]
    for j in range(1, len(th)):
        t = th[j]
        lo2 = lo if lo < t else t
        hi2 = hi if hi > t else t
        if hi2 - lo2 > limit or s[j] - s[i0] > max_length:
            k = j - 1 if j - 1 > i0 else j
            keep.append(k)
            i0 = k
            lo = hi = th[k]
            if k == j - 1:
                lo = min(lo, t)
                hi = max(hi, t)
        else:
            lo, hi = lo2, hi2
    if keep[-1] != len(th) - 1:
        keep.append(len(th) - 1)
    return xd[np.array(keep)]


def _signed_area(poly):
    x, z = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(z, -1) - np.roll(x, -1) * z))


def _averaged_normals(poly):
    """Outward (x, z) vertex normals of a CCW polygon: mean of edge normals."""
    d = np.roll(poly, -1, axis=0) - poly
    en = normalize(np.stack([d[:, 1], -d[:, 0]], axis=-1))
    return normalize(en + np.roll(en, 1, axis=0))


def _crease_rectangle(x0, x1, z0, z1, eps=CREASE_EPS):
    """CCW rectangle with a shading bevel at each corner.

    Each corner keeps the normal of the edge arriving at it, and a point
    ``eps`` further along the next edge carries that edge's normal.
    """
    corners = np.array([[x0, z0], [x1, z0], [x1, z1], [x0, z1]], dtype=float)
    edge_n = np.array([[0.0, -1.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])  # edge i: i -> i+1
    pts, nrm = [], []
    for i in range(4):
        d = normalize(corners[(i + 1) % 4] - corners[i])
        pts += [corners[i], corners[i] + eps * d]
        nrm += [edge_n[i - 1], edge_n[i]]
    return np.array(pts), np.array(nrm)


def _triangulate_monotone(poly):
    """Triangulate a CCW polygon monotone in lexicographic (x, z) order.

    Classic stack algorithm (de Berg et al., Computational Geometry, 3.3).

    Parameters
    ----------
    poly : (N, 2) float

    Returns
    -------
    (N - 2, 3) int
        CCW triangles (indices into ``poly``).
    """
    n = len(poly)
    order = np.lexsort((poly[:, 1], poly[:, 0]))
    left, right = int(order[0]), int(order[-1])
    upper = np.zeros(n, dtype=bool)
    i = right
    while i != left:
        upper[i] = True
        i = (i + 1) % n
    upper[right] = False  # end points belong to both chains; never compared
    pts = poly.tolist()

    def orient(a, b, c):
        (ax, az), (bx, bz), (cx, cz) = pts[a], pts[b], pts[c]
        return (bx - ax) * (cz - az) - (bz - az) * (cx - ax)

    u = order.tolist()
    stack = [u[0], u[1]]
    tris = []
    for j in range(2, n - 1):
        v = u[j]
        if upper[v] != upper[stack[-1]]:
            while len(stack) > 1:
                a = stack.pop()
                tris.append((v, a, stack[-1]))
            stack = [u[j - 1], v]
        else:
            last = stack.pop()
            while stack:
                o = orient(stack[-1], v, last)
                if (o > 0) if upper[v] else (o < 0):
                    tris.append((v, last, stack[-1]))
                    last = stack.pop()
                else:
                    break
            stack += [last, v]
    v = u[-1]
    while len(stack) > 1:
        a = stack.pop()
        tris.append((v, a, stack[-1]))
    tris = np.array(tris, dtype=np.int64)
    a, b, c = poly[tris[:, 0]], poly[tris[:, 1]], poly[tris[:, 2]]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    flip = cross < 0
    tris[flip] = tris[flip][:, ::-1]
    # Positive triangles whose areas add up to the polygon's cover it once.
    area = _signed_area(poly)
    if (len(tris) != n - 2 or np.any(cross == 0)
            or abs(0.5 * np.abs(cross).sum() - area) > 1e-9 * max(area, 1e-12)):
        raise RuntimeError("polygon is not x-monotone (internal error)")
    return tris


def _extrude(poly, normals, tris, y0, y1):
    """Sweep a CCW (x, z) polygon over ``y0 <= y <= y1`` into a watertight mesh.

    Parameters
    ----------
    poly : (N, 2) float, mm
    normals : (N, 2) float
        Outward unit (x, z) vertex normals of the side walls.
    tris : (T, 3) int
        CCW triangulation of ``poly`` (the two end caps).
    y0, y1 : float, mm

    Returns
    -------
    trimesh.Trimesh
    """
    if _signed_area(poly) <= 0:
        raise RuntimeError("polygon must be counter-clockwise (internal error)")
    n = len(poly)
    ring0 = np.column_stack([poly[:, 0], np.full(n, y0), poly[:, 1]])
    ring1 = np.column_stack([poly[:, 0], np.full(n, y1), poly[:, 1]])
    n3 = np.column_stack([normals[:, 0], np.zeros(n), normals[:, 1]])
    i = np.arange(n)
    j = (i + 1) % n
    walls = np.concatenate([np.stack([i, j + n, j], -1), np.stack([i, i + n, j + n], -1)])
    caps = np.concatenate([tris, tris[:, ::-1] + n])
    mesh = trimesh.Trimesh(
        vertices=np.vstack([ring0, ring1]),
        faces=np.concatenate([walls, caps]),
        vertex_normals=normalize(np.vstack([n3, n3])),
        process=False,
    )
    return mesh


def _column_polygon(top, top_normals, z_bottom):
    """Polygon under an x-increasing top chain down to a flat bottom.

    Returns the polygon (CCW), its vertex normals (exact on the top chain,
    averaged elsewhere) and its triangulation.
    """
    if np.any(np.diff(top[:, 0]) <= 0):
        raise RuntimeError("top chain must be strictly x-increasing (internal error)")
    bottom = np.array([[top[0, 0], z_bottom], [top[-1, 0], z_bottom]])
    poly = np.vstack([bottom, top[::-1]])
    normals = _averaged_normals(poly)
    normals[2:] = top_normals[::-1]
    return poly, normals, _triangulate_monotone(poly)


def _surface_chain(surface, bound, max_length):
    x = sample_surface(surface, bound, max_length)
    z = surface.z(x)
    p = surface.slope(x)
    nrm = normalize(np.stack([-p, np.ones_like(p)], axis=-1))
    return np.column_stack([x, z]), nrm


def _solder_path(lead, z_c):
    """Hidden top chain of the solder from the contact C into the lead.

    Follows the lead's outer face downwards from C at a depth growing
    linearly from 0 to half the lead thickness, so it stays inside the lead
    metal and is strictly x-increasing. Returns (K, 2) points without C.
    """
    a0 = lead.alpha0
    alpha_c = float(lead.outer_alpha(z_c))
    xb, zb = lead.leg_base
    centre = np.array([lead.x_centre, lead.z_centre])
    pts, nrm = [], []
    n_leg = np.array([math.cos(a0), math.sin(a0)])
    if z_c > zb:
        x_c = float(lead.outer_x(z_c))
        for f in np.linspace(0.0, 1.0, 9)[:-1]:
            pts.append(np.array([x_c, z_c]) * (1 - f) + np.array([xb, zb]) * f)
            nrm.append(n_leg)
        alpha_c = a0
    alpha_end = -math.pi / 2 if lead.lead_type == "gull-wing" else -math.pi / 3
    n_arc = max(2, int(math.ceil(abs(alpha_end - alpha_c) / math.radians(2.0))))
    for alpha in np.linspace(alpha_c, alpha_end, n_arc + 1):
        nv = np.array([math.cos(alpha), math.sin(alpha)])
        pts.append(centre + lead.outer_radius * nv)
        nrm.append(nv)
    if lead.lead_type == "gull-wing":
        x_end = lead.x_centre + lead.tail_length - 0.03
        for x in np.linspace(lead.x_centre, x_end, 9)[1:]:
            pts.append(np.array([x, lead.bottom_z]))
            nrm.append(np.array([0.0, -1.0]))
    pts, nrm = np.array(pts), np.array(nrm)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    depth = (lead.thickness / 2) * s / s[-1]
    path = pts - depth[:, None] * nrm
    return path[1:]


def _lead_mesh(lead, y0, y1, bound):
    c, n, t = lead.centerline(2 * _SAMPLING_MARGIN * bound, CREASE_EPS)
    k = len(c)
    half = lead.thickness / 2
    outer, inner = c + half * n, c - half * n
    n_outer, n_inner = n.copy(), -n
    for idx, cut in ((0, -t[0]), (k - 1, t[-1])):
        n_outer[idx] = cut
        n_inner[idx] = cut
    poly = np.vstack([outer, inner[::-1]])
    normals = np.vstack([n_outer, n_inner[::-1]])
    i = np.arange(k - 1)
    o0, o1 = i, i + 1
    in0, in1 = 2 * k - 1 - i, 2 * k - 2 - i
    tris = np.concatenate([np.stack([o0, o1, in1], -1), np.stack([o0, in1, in0], -1)])
    return _extrude(poly, normals, tris, y0, y1)


def _box_mesh(x0, x1, z0, z1, y0, y1):
    poly, normals = _crease_rectangle(x0, x1, z0, z1)
    return _extrude(poly, normals, _triangulate_monotone(poly), y0, y1)


# ---------------------------------------------------------------------------
# Joint
# ---------------------------------------------------------------------------


@dataclass
class Joint:
    """One procedural solder joint: meshes, materials and exact profile.

    Attributes
    ----------
    params : JointParams
    profile : JointProfile
        Exact cross-section truth (pure numpy).
    meshes : dict of str to trimesh.Trimesh
        ``"board"``, ``"pad"``, ``"lead"``, ``"solder"`` and, for
        ``kind="bridge"``, ``"neighbour_pad"``, ``"neighbour_lead"``,
        ``"neighbour_solder"`` (the same parts shifted by
        ``neighbour_pitch`` along +y) and ``"bridge"`` (the solder lump
        spanning the gap). World frame, millimetres.
    materials : dict of str to str
        Part name to Mitsuba 3 BSDF plugin name.
    fillet_points : (K, 2) float, mm
        (x, z) of the tessellated main solder surface at y = 0.
    """

    params: JointParams
    profile: JointProfile
    meshes: dict
    materials: dict
    fillet_points: np.ndarray

    #: The exact truth a joint answers for its :attr:`profile` (:class:`JointProfile`): ``kind``,
    #: ``fillet_height``, ``fillet_x_range``, ``visible_x_range``, ``profile_z``, ``profile_slope``,
    #: ``profile_normal``, ``profile_curvature``.
    PROFILE_TRUTH = ("kind", "fillet_height", "fillet_x_range", "visible_x_range", "profile_z", "profile_slope",
                     "profile_normal", "profile_curvature")

    def __getattr__(self, name):
        if name in Joint.PROFILE_TRUTH:
            return getattr(self.profile, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")


def make_joint(params, *, bound=TESSELLATION_BOUND, max_length=MAX_FACET_LENGTH):
    """Build the meshes of one joint.

    Parameters
    ----------
    params : JointParams
    bound : float, radians
        Facet-normal error bound on curved profiles (default 0.1 deg).
    max_length : float, mm
        Longest facet along a curved profile.

    Returns
    -------
    Joint
    """
    if not isinstance(params, JointParams):
        raise OptionError(f"params must be a JointParams, got {type(params).__name__}")
    if not (isinstance(bound, (int, float)) and 0 < bound <= math.radians(5.0)):
        raise OptionError(f"bound must lie in (0, 5 deg] (radians), got {bound!r}")
    if not (isinstance(max_length, (int, float)) and 0 < max_length <= 0.1):
        raise OptionError(f"max_length must lie in (0, 0.1] mm, got {max_length!r}")
    prof = JointProfile(params)
    lead = prof.lead
    meshes = {}
    b = BOARD_HALF_WIDTH
    meshes["board"] = _box_mesh(-b, b, -BOARD_THICKNESS, 0.0, -b, b)
    px0, px1 = prof.pad_x_range
    hw = params.pad_width / 2
    meshes["pad"] = _box_mesh(px0, px1, 0.0, prof.pad_top_z, -hw, hw)
    lw = params.lead_width / 2
    meshes["lead"] = _lead_mesh(lead, -lw, lw, bound)

    chain, chain_n = _surface_chain(prof.fillet, bound, max_length)
    if prof.contact_point is not None:
        path = _solder_path(lead, prof.contact_point[1])
        top = np.vstack([chain, path])
        top_n = np.vstack([chain_n, np.zeros_like(path)])
        poly, normals, tris = _column_polygon(top, top_n, prof.pad_top_z - SOLDER_SINK)
        hidden = slice(2, 2 + len(path))  # path vertices (reversed order) get averaged normals
        normals[hidden] = _averaged_normals(poly)[hidden]
    else:
        poly, normals, tris = _column_polygon(chain, chain_n, prof.pad_top_z - SOLDER_SINK)
    sw = prof.solder_half_width
    meshes["solder"] = _extrude(poly, normals, tris, -sw, sw)

    materials = {name: MATERIALS[name] for name in meshes}
    if params.kind == "bridge":
        shift = trimesh.transformations.translation_matrix([0.0, params.neighbour_pitch, 0.0])
        for name in ("pad", "lead", "solder"):
            m = meshes[name].copy()
            m.apply_transform(shift)
            m.vertex_normals = meshes[name].vertex_normals
            meshes[f"neighbour_{name}"] = m
            materials[f"neighbour_{name}"] = MATERIALS[name]
        bchain, bchain_n = _surface_chain(prof.bridge, bound, max_length)
        bpoly, bnormals, btris = _column_polygon(bchain, bchain_n, -SOLDER_SINK)
        meshes["bridge"] = _extrude(bpoly, bnormals, btris, *prof.bridge_y_range)
        materials["bridge"] = MATERIALS["solder"]
    return Joint(params=params, profile=prof, meshes=meshes, materials=materials, fillet_points=chain)


# ---------------------------------------------------------------------------
# Files
# ---------------------------------------------------------------------------


def write_ply(path, mesh, *, overwrite=False, comment=None):
    """Write a binary little-endian PLY with float32 positions and normals.

    Parameters
    ----------
    path : str or Path
    mesh : trimesh.Trimesh
        Its ``vertex_normals`` are written as ``nx, ny, nz``.
    overwrite : bool
        If False an existing file raises ``FileExistsError``.
    comment : str or None
        One header comment line.
    """
    path = Path(path)
    v = np.asarray(mesh.vertices, dtype=float)
    vn = np.asarray(mesh.vertex_normals, dtype=float)
    f = np.asarray(mesh.faces, dtype=np.int64)
    vert = np.empty(len(v), dtype=[(c, "<f4") for c in ("x", "y", "z", "nx", "ny", "nz")])
    for k, c in enumerate("xyz"):
        vert[c] = v[:, k]
        vert["n" + c] = vn[:, k]
    face = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"] = 3
    face["i"] = f
    lines = ["ply", "format binary_little_endian 1.0"]
    if comment:
        lines.append("comment " + " ".join(str(comment).split()))
    lines += [f"element vertex {len(v)}"]
    lines += [f"property float {c}" for c in ("x", "y", "z", "nx", "ny", "nz")]
    lines += [f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]
    data = ("\n".join(lines) + "\n").encode("ascii") + vert.tobytes() + face.tobytes()
    return write_bytes(path, data, overwrite=overwrite)


def save_joint(joint, folder, *, overwrite=False):
    """Write one PLY per part and ``joint.json`` into ``folder``.

    Parameters
    ----------
    joint : Joint
    folder : str or Path
        Created if missing.
    overwrite : bool
        If False (default) and any target file exists, nothing is written and
        ``FileExistsError`` is raised.

    Returns
    -------
    dict of str to Path
        Part name (and ``"json"``) to the file written.
    """
    if not isinstance(joint, Joint):
        raise OptionError(f"joint must be a Joint, got {type(joint).__name__}")
    folder = Path(folder)
    targets = {name: folder / f"{name}.ply" for name in joint.meshes}
    targets["json"] = folder / "joint.json"
    for p in targets.values():  # nothing is written if any target is there
        refuse_existing(p, overwrite)
    folder.mkdir(parents=True, exist_ok=True)
    parts = {}
    for name, mesh in joint.meshes.items():
        write_ply(
            targets[name], mesh, overwrite=overwrite,
            comment=f"shinysim solder joint kind={joint.kind} part={name} units=mm",
        )
        parts[name] = {
            "file": targets[name].name,
            "material": joint.materials[name],
            "n_vertices": int(len(mesh.vertices)),
            "n_faces": int(len(mesh.faces)),
        }
    doc = {
        "format": "shinysim-solder-joint",
        "version": 1,
        "kind": joint.kind,
        "units": {"length": "mm", "angle": "rad"},
        "params": joint.params.to_dict(),
        "derived": joint.profile.summary(),
        "parts": parts,
        "tessellation_bound_deg": math.degrees(TESSELLATION_BOUND),
    }
    write_json(targets["json"], doc, overwrite=overwrite)
    return targets


def load_joint(folder):
    """Rebuild a :class:`Joint` from the ``joint.json`` that :func:`save_joint` wrote."""
    from ..io.document import read_document

    doc = read_document(Path(folder) / "joint.json")
    return make_joint(JointParams.from_dict(doc["params"]))


def main(argv=None):
    """Command line: write one example joint per class.

    ``python -m shinysim.sim.solder --out meshes --seed 0`` writes
    ``meshes/<kind>/{board,pad,lead,solder,...}.ply`` and ``joint.json``.
    """
    parser = argparse.ArgumentParser(
        prog="python -m shinysim.sim.solder",
        description="Write one procedural solder joint per defect class (PLY + JSON).",
    )
    parser.add_argument("--out", default="meshes", help="output folder (default: meshes)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument("--kinds", nargs="+", default=list(JOINT_KINDS), choices=JOINT_KINDS)
    parser.add_argument("--overwrite", action="store_true", help="replace existing files")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    out = Path(args.out)
    for kind in args.kinds:
        params = sample_params(kind, rng)
        joint = make_joint(params)
        files = save_joint(joint, out / kind, overwrite=args.overwrite)
        size = sum(p.stat().st_size for p in files.values())
        print(f"{kind:13s} {params.lead_type:9s} fillet_height={joint.fillet_height:.3f} mm "
              f"-> {out / kind} ({size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
