"""Triangle meshes in Mitsuba scenes: random shapes and users' meshes, loaded once, reshaped in place.

* :func:`mesh_object`: a :class:`~shinysim.objects.shapes.TriangleMesh` as
  a shape dict for :class:`~shinysim.sim.render.Simulator`'s objects (a
  Mitsuba ``ply`` shape with the mesh's own vertex normals);
* :func:`update_mesh`: give a loaded scene's mesh new vertices, normals and
  faces of the same counts, without reloading the scene;
* :func:`load_user_mesh`: a PLY or OBJ file as a ``TriangleMesh``, scaled
  and placed in the world frame.

Both ways into a scene go through Mitsuba's PLY reader, which re-normalises
the vertex normals in single precision. So :func:`update_mesh` leaves the
scene holding exactly the arrays a fresh load of the same mesh would hold,
and a stack rendered after an update is identical to one from a fresh load
with the same seed. (Writing the float32 arrays into the scene directly
would differ from a fresh load in the last bit of some normals; the sample
allocation can then round a sample count the other way, and the stack's
noise would change.)

PLY files for Mitsuba are written to ``folder`` when given, else to a
temporary folder of this process that is removed when the interpreter
exits; a mesh's file is named by its content, so loading the same mesh again
writes nothing. Mitsuba and trimesh are imported when first used.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from .._shared import check_choice, check_number, write_bytes
from ..errors import OptionError, ShinysimError
from ..objects.shapes import TriangleMesh

__all__ = ["MESH_FORMATS", "load_user_mesh", "mesh_object", "ply_bytes", "update_mesh"]

#: File types :func:`load_user_mesh` reads.
MESH_FORMATS = (".ply", ".obj")

_TEMP = None  # (pid, folder) of this process's temporary PLY folder


def _temp_folder() -> Path:
    """This process's temporary folder for PLY files (a forked child makes its own)."""
    global _TEMP
    if _TEMP is None or _TEMP[0] != os.getpid() or not _TEMP[1].is_dir():
        folder = Path(tempfile.mkdtemp(prefix="shinysim-meshes-"))
        atexit.register(shutil.rmtree, folder, True)
        _TEMP = (os.getpid(), folder)
    return _TEMP[1]


def ply_bytes(mesh: TriangleMesh) -> bytes:
    """A binary little-endian PLY of the mesh: float32 positions and normals, int32 triangles."""
    v = np.asarray(mesh.vertices, dtype="<f4")
    n = np.asarray(mesh.normals, dtype="<f4")
    vert = np.empty(len(v), dtype=[(c, "<f4") for c in ("x", "y", "z", "nx", "ny", "nz")])
    for k, c in enumerate("xyz"):
        vert[c] = v[:, k]
        vert["n" + c] = n[:, k]
    face = np.empty(len(mesh.faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"] = 3
    face["i"] = mesh.faces
    header = ["ply", "format binary_little_endian 1.0", f"comment shinysim {mesh.name}",
              f"element vertex {len(v)}"]
    header += [f"property float {c}" for c in ("x", "y", "z", "nx", "ny", "nz")]
    header += [f"element face {len(face)}", "property list uchar int vertex_indices", "end_header"]
    return ("\n".join(header) + "\n").encode("ascii") + vert.tobytes() + face.tobytes()


def _check_mesh(mesh):
    if not isinstance(mesh, TriangleMesh):
        raise TypeError(f"mesh must be a shinysim.objects.shapes.TriangleMesh, got {type(mesh).__name__}")


def mesh_object(mesh: TriangleMesh, *, bsdf: dict, folder=None) -> dict:
    """A triangle mesh as a shape dict for a :class:`~shinysim.sim.render.Simulator`'s objects.

    Parameters
    ----------
    mesh : shinysim.objects.shapes.TriangleMesh
    bsdf : dict
        A Mitsuba BSDF dict, e.g. :func:`shinysim.sim.scene.rough_conductor`.
    folder : path-like, optional
        Existing folder for the mesh's PLY file (default: a temporary folder
        removed when the interpreter exits). The file is named by a hash of
        its content.

    Returns
    -------
    dict
        ``{"type": "ply", "filename": ..., "bsdf": bsdf}``: Mitsuba shades
        with the mesh's vertex normals, interpolated across each face. Use it
        as a value of the objects dict, e.g.
        ``Simulator(rig, {"object": mesh_object(m, bsdf=rough_conductor(0.02))})``;
        the dict (plain data) also goes into :func:`shinysim.sim.scene.scene_xml`.
    """
    _check_mesh(mesh)
    if not isinstance(bsdf, dict) or "type" not in bsdf:
        raise TypeError(f"bsdf must be a Mitsuba BSDF dict with a 'type', got {bsdf!r}")
    data = ply_bytes(mesh)
    target = Path(folder) if folder is not None else _temp_folder()
    if not target.is_dir():
        raise FileNotFoundError(f"{target}: no such folder for the mesh's PLY file")
    path = target / f"{mesh.name}-{hashlib.sha256(data).hexdigest()[:20]}.ply"
    if not path.is_file():
        write_bytes(path, data, overwrite=True)  # atomic; a concurrent writer writes the same bytes
    return {"type": "ply", "filename": str(path), "bsdf": bsdf}


def _mitsuba_arrays(mesh, variant):
    """The mesh's position, normal and face buffers as Mitsuba's PLY reader makes them in ``variant``."""
    import mitsuba as mi

    if mi.variant() != variant:
        mi.set_variant(variant)
    fd, tmp = tempfile.mkstemp(suffix=".ply", dir=_temp_folder())
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(ply_bytes(mesh))
        params = mi.traverse(mi.load_dict({"type": "ply", "filename": tmp}))
        return {k: params[k] for k in ("vertex_positions", "vertex_normals", "faces")}
    finally:
        os.unlink(tmp)


def update_mesh(sim, name: str, mesh: TriangleMesh) -> None:
    """Give the loaded scene's mesh ``name`` the vertices, normals and faces of ``mesh``, in place.

    The new mesh must have the loaded one's vertex and face counts (random
    shapes of one family and resolution always do:
    :func:`shinysim.objects.shapes.shape_topology_key`); its faces are
    written too. The scene's acceleration structure is rebuilt and the
    simulator's cached geometry forgotten (``sim.geometry_changed()``), so
    truths and stacks rendered afterwards equal those of a freshly loaded
    simulator with ``mesh``, bit for bit. ``sim.objects`` and
    ``sim.scene_description`` still describe the mesh first loaded.

    Parameters
    ----------
    sim : shinysim.sim.render.Simulator
    name : str
        The object's name in the simulator's objects dict.
    mesh : shinysim.objects.shapes.TriangleMesh

    Raises
    ------
    shinysim.errors.OptionError
        (a ``ValueError``) ``name`` is no mesh with vertex normals in the
        scene, or ``mesh`` has other vertex or face counts.
    """
    _check_mesh(mesh)
    params = sim.params
    keys = {k: f"{name}.{k}" for k in ("vertex_positions", "vertex_normals", "faces")}
    missing = [key for key in keys.values() if key not in params]
    if missing:
        raise OptionError(f"the scene has no mesh {name!r} (no parameter {missing[0]!r}); objects: "
                          f"{', '.join(sim.part_names[1:])}")
    n_vertices = len(params[keys["vertex_positions"]]) // 3
    n_faces = len(params[keys["faces"]]) // 3
    if len(params[keys["vertex_normals"]]) != 3 * n_vertices:
        raise OptionError(f"mesh {name!r} of the scene has no vertex normals; load it with mesh_object")
    if (mesh.n_vertices, mesh.n_faces) != (n_vertices, n_faces):
        raise OptionError(f"mesh {name!r} of the scene has {n_vertices} vertices and {n_faces} faces, the new "
                          f"{mesh.name} mesh {mesh.n_vertices} and {mesh.n_faces}: a different topology cannot "
                          "be updated in place; load a new Simulator")
    for k, value in _mitsuba_arrays(mesh, sim.variant).items():
        params[keys[k]] = value
    params.update()
    sim.geometry_changed()


# -- users' meshes -------------------------------------------------------------------

def _fail(path, message, field=None):
    raise ShinysimError(message, path=path, field=field)


def load_user_mesh(path, *, scale_to_mm=1.0, center_mm=(0.0, 0.0, 0.0), fit_mm=None,
                   anchor="bottom") -> TriangleMesh:
    """A user's PLY or OBJ triangle mesh, scaled and placed in the world frame (millimetres).

    Parameters
    ----------
    path : path-like
        A ``.ply`` or ``.obj`` file, read with trimesh (``process=False``:
        vertices and faces as they are in the file, quads and polygons
        split into triangles). A file of several objects, groups or
        materials is one mesh, their concatenation.
    scale_to_mm : float
        Millimetres per file unit (25.4 for inches, 1000 for metres).
    center_mm : (3,) float or None
        Where the mesh goes: its bounding box's centre in x and y, and in z
        its bottom (``anchor="bottom"``: the object rests on the reference
        plane z = 0 by default) or its centre (``anchor="center"``). None
        keeps the file's coordinates (scaled).
    fit_mm : float, optional
        Scale instead so that the bounding box's largest side is ``fit_mm``
        (``scale_to_mm`` is then ignored).
    anchor : {"bottom", "center"}

    Returns
    -------
    TriangleMesh
        ``name`` ``"mesh"``, ``params`` the arguments of this call (the path
        as given, made a string), so ``load_user_mesh(**mesh.params)``
        reads it again. The normals are the mesh's own, not analytic: the
        file's vertex normals when it has one for every vertex, else
        trimesh's (the mean of the adjacent faces' normals, weighted by
        their angles at the vertex). Vertices that no face uses are
        dropped. A closed mesh whose faces wind inwards (negative volume)
        is turned outwards, and each vertex normal is put on the side its
        faces wind to (that of the area-weighted sum of their normals).

    Raises
    ------
    shinysim.errors.ShinysimError
        Naming the file: missing, unreadable or of an unsupported type, no
        faces, face indices out of range, non-finite vertices or normals,
        zero area, or normals that cannot be computed (vertices only on
        zero-area faces).
    """
    scale_to_mm = check_number("scale_to_mm", scale_to_mm, lo=0.0, lo_open=True)
    if fit_mm is not None:
        fit_mm = check_number("fit_mm", fit_mm, lo=0.0, lo_open=True)
    check_choice("anchor", anchor, ("bottom", "center"))
    if center_mm is not None:
        c = np.asarray(center_mm, dtype=float) if not isinstance(center_mm, str) else np.zeros(0)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise OptionError(f"center_mm must be 3 finite numbers or None, got {center_mm!r}")
    p = Path(path)
    if not p.is_file():
        _fail(p, "no such mesh file" if not p.exists() else "not a file")
    if p.suffix.lower() not in MESH_FORMATS:
        _fail(p, f"unsupported mesh type {p.suffix or '(no extension)'!r}; shinysim reads "
                 f"{', '.join(MESH_FORMATS)}")
    import trimesh

    try:
        tm = trimesh.load(str(p), process=False)
        if isinstance(tm, trimesh.Scene):  # several parts (an OBJ with several materials): one mesh
            parts = [g for g in tm.dump() if isinstance(g, trimesh.Trimesh)]
            tm = parts[0] if len(parts) == 1 else trimesh.util.concatenate(parts) if parts else tm
    except Exception as exc:  # noqa: BLE001 - trimesh raises many kinds on bad files
        _fail(p, f"cannot read it as a {p.suffix.lower()[1:].upper()} mesh ({type(exc).__name__}: {exc})")
    if not isinstance(tm, trimesh.Trimesh):
        _fail(p, f"holds no triangle mesh (read as {type(tm).__name__})")
    try:
        vertices = np.asarray(tm.vertices, dtype=np.float64)
        faces = np.asarray(tm.faces, dtype=np.int64)
    except Exception as exc:  # noqa: BLE001
        _fail(p, f"cannot read the mesh ({type(exc).__name__}: {exc})")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        _fail(p, "has no faces (a point cloud or an empty mesh)", "faces")
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) < 3:
        _fail(p, f"has {len(vertices)} vertices; a mesh needs at least 3", "vertices")
    if faces.min() < 0 or faces.max() >= len(vertices):
        _fail(p, f"face indices run outside the {len(vertices)} vertices", "faces")
    if not np.all(np.isfinite(vertices)):
        bad = int(np.sum(~np.all(np.isfinite(vertices), axis=1)))
        _fail(p, f"{bad} of {len(vertices)} vertices not finite (NaN or infinite)", "vertices")
    try:
        normals = np.asarray(tm.vertex_normals, dtype=np.float64)
    except Exception as exc:  # noqa: BLE001
        _fail(p, f"cannot compute vertex normals ({type(exc).__name__}: {exc})", "normals")
    if normals.shape != vertices.shape:
        _fail(p, f"has {len(normals)} vertex normals for {len(vertices)} vertices", "normals")
    # drop the vertices no face uses
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    remap = np.cumsum(used) - 1
    vertices, normals, faces = vertices[used], normals[used], remap[faces]
    v = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    if not np.sum(area) > 0:
        _fail(p, "has zero area (every face is degenerate)", "faces")
    length = np.linalg.norm(normals, axis=1)
    bad = ~(np.isfinite(length) & (length > 1e-12))
    if np.any(bad):
        _fail(p, f"{int(bad.sum())} of {len(normals)} vertex normals zero or not finite (vertices only on "
                 "zero-area faces, or bad normals in the file)", "normals")
    normals = normals / length[:, None]
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    extent = float(np.max(hi - lo))
    if fit_mm is not None:
        if not extent > 0:
            _fail(p, "has a bounding box of zero size; cannot fit it", "vertices")
        scale = fit_mm / extent
    else:
        scale = scale_to_mm
    vertices = vertices * scale
    if center_mm is not None:
        lo, hi = lo * scale, hi * scale
        ref = 0.5 * (lo + hi)
        if anchor == "bottom":
            ref[2] = lo[2]
        vertices = vertices + (np.asarray(center_mm, dtype=float) - ref)
    v = vertices[faces]
    if bool(tm.is_watertight) and np.sum(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2]))) < 0:
        faces = faces[:, ::-1]  # closed but wound inwards (negative volume)
        v = vertices[faces]
    # each vertex normal on the side its faces wind to (the area-weighted sum of their normals)
    face_n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    side = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(side, faces[:, k], face_n)
    normals = np.where(np.sum(normals * side, axis=1, keepdims=True) < 0, -normals, normals)
    return TriangleMesh(vertices, faces.astype(np.int32), normals, "mesh", {
        "path": os.fspath(path), "scale_to_mm": scale_to_mm,
        "center_mm": None if center_mm is None else [float(x) for x in center_mm],
        "fit_mm": fit_mm, "anchor": anchor,
    })
