"""One data-set item: its scene, its renders, its files (the worker's side).

A worker keeps the last scene it loaded (:data:`_CACHE`) and reuses it for the
next item of the same group: spheres move and resize, random shapes and user
meshes change their vertices, materials their parameters, all in place. So
that an item comes out the same whether its scene was reused or loaded for it
alone, every item goes through the same steps: take the group's scene (a
template loaded once), set the item's geometry and material on it, render.
Solder joints differ in topology from item to item and load a scene each.

The files of an item (``rig.json``, ``stack.exr``, ``truth.exr`` and, for
more cameras, ``stack.cameraK.exr`` and ``truth.cameraK.exr``, plus
``item.json``) are a scan folder (``docs/file-format.md``).
"""

from __future__ import annotations

import gc
import hashlib
import os
import shutil
import time
from pathlib import Path
from typing import Any

from .._shared import write_json
from .spec import build_rig, canonical_json

__all__ = ["ITEM_FORMAT", "item_path", "render_item", "write_item", "file_digests", "file_sha256", "reset_cache"]

ITEM_FORMAT = "shinysim-dataset-item/1"

#: Items per shard folder: keeps folders small on any file system.
SHARD_SIZE = 1000

#: The worker's loaded scene: {"key": str, "sim": Simulator, "threads": int}.
_CACHE: dict[str, Any] = {}


def item_path(index: int) -> str:
    """Relative folder of item ``index``: ``items/SSSSS/IIIIIIII`` (fixed widths: sorts right past any count)."""
    return f"items/{index // SHARD_SIZE:05d}/{index:08d}"


def reset_cache() -> None:
    """Drop the worker's loaded scene."""
    _CACHE.clear()
    gc.collect()


def _bsdf(material: dict) -> dict:
    from ..sim.materials import paper_material
    from ..sim.scene import rough_conductor

    kind = material["kind"]
    if kind == "conductor":
        return rough_conductor(material.get("alpha", 0.02), distribution=material.get("distribution", "ggx"))
    if kind == "hybrid":
        return paper_material(material["k"], material["sharpness"], distribution=material.get("distribution", "ggx"))
    return {"type": "diffuse", "reflectance": {"type": "uniform", "value": float(material.get("reflectance", 0.8))}}


def _mesh(item: dict, base_dir):
    obj = item["object"]
    if obj["kind"] == "mesh":
        from ..sim.meshes import load_user_mesh

        kw = {k: obj[k] for k in ("fit_mm", "center_mm") if k in obj}
        return load_user_mesh(Path(base_dir) / obj["path"], **kw)
    from ..objects import shapes

    return getattr(shapes, obj["kind"])(**obj["params"])


def scene_key(item: dict) -> str:
    """Items with equal keys share a loaded scene (only parameters change between them)."""
    obj, mat = item["object"], item["material"]
    key = {"group": item["group"], "rig": item["rig"], "render": item["render"], "object": obj["kind"],
           "material": mat["kind"], "distribution": mat.get("distribution")}
    if obj["kind"] == "solder":
        key["item"] = item["index"]  # a joint is its own scene
    if obj["kind"] == "mesh":
        key["path"] = obj["path"]
    # random shapes of a group share one topology (random_shape's fixed resolution): only vertices change
    return canonical_json(key)


def _load(item, base_dir, variant):
    """Load the item's scene (the template its group's items share)."""
    from ..sim.render import Simulator

    render = item["render"]
    rig = build_rig(item["rig"], render["resolution"], base_dir)
    kind = item["object"]["kind"]
    if kind == "solder":
        from ..objects.solder import JointParams
        from ..sim.solder import make_joint
        from ..sim.solder_scene import joint_simulator

        joint = make_joint(JointParams.from_dict(item["object"]["params"]))
        depth = render.get("max_depth") or 3
        return joint_simulator(joint, rig, interreflections=depth > 2, max_depth=depth,
                               solder_alpha=item["material"].get("alpha"), variant=variant)
    integrator = {"type": "path", "max_depth": int(render["max_depth"])} if render.get("max_depth") else None
    if kind == "sphere":
        shape = {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": 1.0, "bsdf": _bsdf(item["material"])}
    else:
        from ..sim.meshes import mesh_object

        shape = mesh_object(_mesh(item, base_dir), bsdf=_bsdf(item["material"]))
    return Simulator(rig, {"object": shape}, variant=variant, integrator=integrator)


def _apply(sim, item, base_dir):
    """Set the item's geometry and material on the loaded scene."""
    import mitsuba as mi

    obj = item["object"]
    kind = obj["kind"]
    if kind == "sphere":
        from ..objects.sphere import SHINY_SPHERE_RADIUS_MM

        center = [float(x) for x in obj.get("center_mm", [0.0, 0.0, 0.0])]
        radius = float(obj.get("radius_mm", SHINY_SPHERE_RADIUS_MM))
        sim.params["object.to_world"] = mi.ScalarTransform4f().translate(center).scale(radius)
        sim.geometry_changed()
    elif kind != "solder":
        from ..sim.meshes import update_mesh

        update_mesh(sim, "object", _mesh(item, base_dir))  # forgets the cached geometry itself
    if kind != "solder":  # a joint's materials were set when its scene was loaded
        # material: the item's values, as plain numbers, into the loaded BSDF's parameters
        for key, value in _bsdf_numbers(_bsdf(item["material"]), "object.bsdf"):
            if key in sim.params:
                sim.params[key] = value
    sim.params.update()  # one update for geometry and material together
    if item["material"]["kind"] == "conductor":
        sim.alpha["object"] = float(item["material"].get("alpha", 0.02))


def _bsdf_numbers(d: dict, prefix: str):
    """(Mitsuba parameter key, float) for every number of a BSDF dict: ``alpha`` -> ``PREFIX.alpha.value``."""
    for k, v in d.items():
        if isinstance(v, bool) or k == "type":
            continue
        if isinstance(v, (int, float)):
            yield f"{prefix}.{k}.value", float(v)
        elif isinstance(v, dict):
            if v.get("type") in ("uniform", "rgb") and isinstance(v.get("value"), (int, float)):
                yield f"{prefix}.{k}.value", float(v["value"])
            else:
                yield from _bsdf_numbers(v, f"{prefix}.{k}")


def _set_threads(threads):
    if threads and _CACHE.get("threads") != threads:
        import drjit as dr

        dr.set_thread_count(int(threads))
        _CACHE["threads"] = threads


def render_item(item: dict, *, base_dir: str | os.PathLike = ".", variant: str | None = None,
                threads: int | None = None) -> dict:
    """Render one item: ``{"stacks": [Stack per camera], "truths": [Truth per camera], "seconds": {...}}``."""
    from ..sim.sensor import sensor_preset

    _set_threads(threads)
    t0 = time.perf_counter()
    key = scene_key(item)
    if _CACHE.get("key") != key:
        _CACHE.pop("sim", None)
        _CACHE["key"] = None
        gc.collect()
        _CACHE["sim"] = _load(item, base_dir, variant)
        _CACHE["key"] = key
    sim = _CACHE["sim"]
    _apply(sim, item, base_dir)
    t1 = time.perf_counter()
    render = item["render"]
    stacks, truths = [], []
    for cam in range(len(sim.rig.cameras)):
        sim.use_camera(cam)
        truths.append(sim.render_truth(coverage=render.get("coverage", 0)))
        method = render.get("method")
        if method is None and sim.integrator.get("type") == "path" and cam > 0:
            method = "one-pass"  # the per-source renderer images the scene's own camera only
        stack = sim.render_stack(spp=render["spp"], seed=item["seed"], method=method)
        sensor = sensor_preset(item["sensor"]["preset"])
        if sensor is not None:
            peak = float(stack.frames.max())
            if peak > 0:
                sensor = sensor.exposed_for(peak, fraction=item["sensor"]["exposure"])
            stack = sensor.expose(stack, seed=item["seed"] + cam)
        stack.provenance["dataset_item"] = {"index": item["index"], "group": item["group_name"]}
        stacks.append(stack)
    sim.use_camera(0)
    return {"stacks": stacks, "truths": truths,
            "seconds": {"scene": t1 - t0, "render": time.perf_counter() - t1}}


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes, hex."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def file_digests(folder: str | os.PathLike) -> dict:
    """{name: {"bytes": n, "sha256": hex}} of every file in a folder (sorted by name)."""
    return {p.name: {"bytes": p.stat().st_size, "sha256": file_sha256(p)}
            for p in sorted(Path(folder).iterdir()) if p.is_file()}


def item_files(n_cameras: int) -> list[str]:
    """The names of an item's files."""
    names = ["rig.json", "stack.exr", "truth.exr", "item.json"]
    for cam in range(1, n_cameras):
        names += [f"stack.camera{cam}.exr", f"truth.camera{cam}.exr"]
    return names


def write_files(item: dict, rendered: dict, folder: Path) -> None:
    """Write a rendered item's files into ``folder``."""
    from ..io import save_stack, save_truth

    for cam, (stack, truth) in enumerate(zip(rendered["stacks"], rendered["truths"])):
        suffix = "" if cam == 0 else f".camera{cam}"
        save_stack(stack, folder / f"stack{suffix}.exr", rig_path=folder / "rig.json", overwrite=cam > 0)
        save_truth(truth, folder / f"truth{suffix}.exr")
    keep = ("generator", "mitsuba", "drjit", "variant", "method")
    write_json(folder / "item.json", {"format": ITEM_FORMAT, **item, "provenance": {
        k: v for k, v in rendered["stacks"][0].provenance.items() if k in keep}})


def write_item(item: dict, root: str | os.PathLike, *, base_dir: str | os.PathLike = ".",
               variant: str | None = None, threads: int | None = None) -> dict:
    """Render item ``item`` and put its folder in place under ``root``, atomically.

    The files are written into a hidden temporary folder beside the target
    and renamed into place when complete: a reader (or a rerun after a kill)
    sees the whole item or none of it. An item folder already there (from a
    run killed before it recorded the item) is replaced by the new one, which
    has the same bytes.

    Returns
    -------
    dict
        ``{"index", "path", "files": {name: {"bytes", "sha256"}}, "seconds", "rss_mb"}``.
    """
    root = Path(root)
    rel = item_path(item["index"])
    final = root / rel
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = final.parent / f".tmp-{item['index']:08d}-{os.getpid()}-{time.monotonic_ns()}"
    tmp.mkdir()
    try:
        out = render_item(item, base_dir=base_dir, variant=variant, threads=threads)
        t0 = time.perf_counter()
        write_files(item, out, tmp)
        digests = file_digests(tmp)
        if final.exists():
            shutil.rmtree(final)
        os.rename(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    seconds = dict(out["seconds"], write=time.perf_counter() - t0)
    return {"index": item["index"], "path": rel, "files": digests, "seconds": seconds, "rss_mb": _rss_mb(),
            "pid": os.getpid()}


def _rss_mb() -> float:
    """This process's resident memory now, MiB (Linux; NaN elsewhere)."""
    try:
        with open("/proc/self/statm") as f:
            pages = int(f.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return float("nan")

