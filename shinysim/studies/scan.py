"""A whole structured-highlight scan: render, reconstruct, score, write.

Used by ``shinysim scan``. The rendering half needs the ``render`` extra;
:func:`reconstruct_folder` and :func:`score_folder` need only numpy and
scikit-image.
"""

from __future__ import annotations

import os
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from .._shared import (
    Progress,
    check_choice,
    check_free,
    check_number,
    output_folder,
    stage_reporter,
    write_file,
    write_json,
)
from ..errors import OptionError
from ..io import load_rig, load_stack, load_truth, save_stack, save_truth
from ..io.frames import stack_from_frames
from ..recon import NORMAL_MODELS, DetectParams, Reconstruction, reconstruct
from ..io.table import read_highlight_table
from ..rig import CAMERA_PROJECTIONS, Anchor, Rig

__all__ = ["SCAN_FILES", "SCAN_LIMITS", "sphere_scan_rig", "check_scan_options", "run_scan", "reconstruct_folder",
           "reconstruct_frames", "reconstruct_diligent", "score_folder"]

#: Files a scan folder may hold; none of them is ever silently replaced.
SCAN_FILES = ("rig.json", "stack.exr", "truth.exr", "highlights.csv", "score.json", "scan.png")

#: Ranges of the scan's options, checked before any work, each with its reason.
SCAN_LIMITS = {
    # the rough-conductor alpha of Mitsuba: 0 is a perfect mirror, which a
    # sampled renderer cannot image with small sources; above 1 is not a
    # microfacet roughness
    "alpha": dict(lo=1e-4, hi=1.0),
    # 16 px puts the 1.59 mm sphere on ~13 px, the least that keeps its 21
    # highlights on separate pixels; 4096 px is a 1.4 GB float32 stack
    "resolution": dict(lo=16, hi=4096, integer=True),
    # samples per pixel: at least one; 65536 is hours per source
    "spp": dict(lo=1, hi=65536, integer=True),
    # the renderer's seed is an unsigned 32-bit integer
    "seed": dict(lo=0, hi=2**32 - 1, integer=True),
}


def sphere_scan_rig(*, projection: str = "perspective", resolution: int = 512) -> Rig:
    """The SHINY rig (:func:`~shinysim.rig.shiny_1988`) anchored at the calibration sphere's apex.

    The sphere sits centred on the reference plane under the camera's target,
    so its apex is a known surface point with a vertical normal: the
    near-field model's anchor.
    """
    from ..objects.sphere import SHINY_SPHERE_RADIUS_MM
    from ..rig import shiny_1988

    return shiny_1988(projection=projection, resolution=resolution).with_anchor(
        Anchor.at_point((0.0, 0.0, SHINY_SPHERE_RADIUS_MM), normal=(0.0, 0.0, 1.0)))


def check_scan_options(*, alpha, projection, resolution, spp, seed, method=None, distribution="ggx"):
    """Check a scan's options before any work; raise :class:`~shinysim.errors.OptionError` naming the first bad one."""
    for name, value in (("alpha", alpha), ("resolution", resolution), ("spp", spp), ("seed", seed)):
        check_number(name, value, **SCAN_LIMITS[name])
    check_choice("projection", projection, CAMERA_PROJECTIONS)
    check_choice("distribution", distribution, ("ggx", "beckmann"))
    if method is not None:
        check_choice("method", method, ("one-pass", "per-source"))


def _without_errors(stats):
    """A model's statistics without the per-highlight errors."""
    return {k: v for k, v in stats.items() if k != "errors_deg"}


def _summary(per_model, recon, extra):
    models = {m: _without_errors(s) for m, s in per_model.items()}
    scored = {m: s["median_deg"] for m, s in models.items() if s["n"] > 0 and np.isfinite(s["median_deg"])}
    return {
        "models": models,
        # None when no highlight was scored: there is no best model then
        "best_model": min(scored, key=scored.get) if scored else None,
        "n_highlights": len(recon),
        # highlights at the sensor's clip level (their centres are the clipped areas')
        "n_saturated": int(np.count_nonzero(recon.table["saturated"])),
        "empty_sources": recon.empty_sources,
        **extra,
    }


def _scan_bytes(rig, n_sources):
    """An upper bound on a scan folder's size: float32 stack and truth uncompressed, 4 MB for the rest."""
    H, W = rig.camera.shape
    return 4 * H * W * (n_sources + 8) + 4 * 2**20


def run_scan(out: str | os.PathLike, *, alpha: float = 0.02, projection: str = "perspective", resolution: int = 512,
             spp: int = 64, seed: int = 0, variant: str | None = None, method: str | None = None,
             detect: DetectParams | None = None, overwrite: bool = False, progress: Progress | None = None,
             plot: bool = True, distribution: str = "ggx", sensor: str | Any | None = None,
             exposure: float = 0.8) -> dict[str, Any]:
    """Scan the SHINY calibration sphere and score the recovered normals.

    Parameters
    ----------
    out : path-like
        Folder to write ``rig.json``, ``stack.exr``, ``truth.exr``,
        ``highlights.csv``, ``score.json`` and ``scan.png`` into (created;
        existing files are never replaced unless ``overwrite``).
    alpha : float
        Rough-conductor roughness of the sphere.
    projection : {"perspective", "orthographic"}
    resolution, spp, seed : int
    variant : str, optional
        Mitsuba variant (default: fastest available).
    method : {"one-pass", "per-source"}, optional
    detect : DetectParams, optional
    sensor : str or shinysim.sim.sensor.Sensor, optional
        Digitise the rendered frames with this camera sensor (a preset name
        of :data:`shinysim.sim.sensor.SENSOR_PRESETS`, or a Sensor); None or
        ``"ideal"`` keeps the float frames. The sensor's noise is drawn from
        ``seed``.
    exposure : float
        With a sensor: the fraction of its full well that the stack's
        brightest pixel fills (above 1 clips it).
    progress : callable, optional
        ``progress(stage, done, total)`` after each of the scan's stages
        (``stage`` names the one just finished), and
        ``progress("info", 0, 0, message)`` for one-line messages.

    Returns
    -------
    dict
        The content of ``score.json``.
    """
    from ..objects.sphere import SHINY_SPHERE_RADIUS_MM

    check_scan_options(alpha=alpha, projection=projection, resolution=resolution, spp=spp, seed=seed,
                       method=method, distribution=distribution)
    from ..sim.sensor import Sensor, sensor_preset

    if sensor is None or isinstance(sensor, str):
        sensor = sensor_preset(sensor or "ideal")
    elif not isinstance(sensor, Sensor):
        raise OptionError(f"sensor must be a preset name or a Sensor, got {type(sensor).__name__}")
    # exposure: a fraction of the full well; 1e3 would clip all but the darkest pixels
    exposure = check_number("exposure", exposure, lo=0, lo_open=True, hi=1e3)
    if detect is not None and not isinstance(detect, DetectParams):
        raise OptionError(f"detect must be DetectParams, got {type(detect).__name__}")
    from ..sim.variants import choose_variant

    choose_variant(variant)  # no renderer, or an unknown or unusable variant: refused before any work
    from ..sim.render import Simulator
    from ..sim.objects import scene_objects

    rig = sphere_scan_rig(projection=projection, resolution=resolution)
    names = SCAN_FILES if plot else SCAN_FILES[:-1]
    stages = ["scene", "truth", "render", "write stack", "reconstruct", "score", "figure"][: 7 if plot else 6]

    done, say = stage_reporter(progress, stages)

    with output_folder(out, names, overwrite=overwrite, needed_bytes=_scan_bytes(rig, rig.n_sources),
                       last="score.json") as tmp:
        sim = Simulator(rig, scene_objects("sphere", alpha=alpha, distribution=distribution), variant=variant)
        say(sim.variant_reason)
        done("scene")
        truth = sim.render_truth()
        done("truth")
        stack = sim.render_stack(spp=spp, seed=seed, method=method)
        say(f"rendered {stack.n_sources} frames in {sim.last_render_seconds:.2f} s")
        if sensor is not None:
            sensor = sensor.exposed_for(float(stack.frames.max()), fraction=exposure)
            stack = sensor.expose(stack, seed=seed)
            say(f"digitised by the {sensor.name} sensor, the brightest pixel at {exposure:g} of its full well")
        done("render")
        dtype, why = save_stack(stack, tmp / "stack.exr")
        say(f"stack.exr stored as {dtype} ({why})")
        save_truth(truth, tmp / "truth.exr")
        # reconstruct and score what was written, so that the folder's numbers are a
        # function of its files (the renderer's last float32 bits vary between runs;
        # the stored pixels do not), as `shinysim reconstruct` and `score` would find them
        stack = load_stack(tmp / "stack.exr")
        truth = load_truth(tmp / "truth.exr", stack.camera)
        done("write stack")
        detect = detect or DetectParams()
        recon = reconstruct(stack, detect)
        recon.write_table(tmp / "highlights.csv")
        done("reconstruct")
        from ..evaluate import score_reconstruction

        per_model = score_reconstruction(recon, truth, sphere_center=(0, 0, 0),
                                         sphere_radius=SHINY_SPHERE_RADIUS_MM)
        score = _summary(per_model, recon, {
            "highlights": "detected by the scan",
            "detect": asdict(recon.params),
            "detection": recon.detection,
            "near_field": recon.near_field,
            "notes": recon.notes,
            "object": "sphere",
            "sphere_radius_mm": SHINY_SPHERE_RADIUS_MM,
            "alpha": alpha,
            "distribution": distribution,
            "projection": projection,
            "resolution": resolution,
            "sensor": None if sensor is None else sensor.to_dict(),
            "exposure": None if sensor is None else exposure,
            "provenance": stack.provenance,
        })
        write_json(tmp / "score.json", score)
        done("score")
        if plot and score["best_model"] is not None:
            from ..plot.scan import scan_figure

            fig = scan_figure(stack, recon, truth, per_model[score["best_model"]], model=score["best_model"],
                              sphere_radius=SHINY_SPHERE_RADIUS_MM)
            write_file(tmp / "scan.png", lambda f: fig.savefig(f, dpi=110, format="png"))
            done("figure")
    return score


def reconstruct_folder(folder: str | os.PathLike, *, out: str | os.PathLike | None = None,
                       rig: Rig | str | os.PathLike | None = None, detect: DetectParams | None = None,
                       models: tuple[str, ...] = NORMAL_MODELS, anchor: Anchor | None = None,
                       overwrite: bool = False) -> Reconstruction:
    """Reconstruct a scan folder's stack (no renderer needed).

    Writes ``highlights.csv`` into ``out`` (default: the folder itself) and
    returns the :class:`~shinysim.recon.Reconstruction`. Without
    ``detect``, the default detection (derived from the frames); without
    ``anchor``, the rig's (for the near-field model).
    """
    folder = Path(folder)
    out = folder if out is None else Path(out)
    check_free(out, ["highlights.csv"], overwrite)
    stack = load_stack(folder / "stack.exr", rig)
    with output_folder(out, ["highlights.csv"], overwrite=overwrite) as tmp:
        recon = reconstruct(stack, detect or DetectParams(), models=models, anchor=anchor)
        recon.write_table(tmp / "highlights.csv")
    return recon


def reconstruct_frames(frames, rig: Rig | str | os.PathLike, out: str | os.PathLike, *,
                       detect: DetectParams | None = None, anchor: Anchor | None = None, channel: str = "max",
                       overwrite: bool = False) -> Reconstruction:
    """Reconstruct camera frames (one image file per source, in source order) taken with ``rig``.

    ``rig`` is a :class:`~shinysim.rig.Rig` or the path of its JSON file;
    ``channel`` turns colour frames into intensity
    (:func:`~shinysim.io.frames.stack_from_frames`). Writes
    ``highlights.csv`` into ``out`` (checked before any file is read) and
    returns the :class:`~shinysim.recon.Reconstruction`.
    """
    with output_folder(out, ["highlights.csv"], overwrite=overwrite) as tmp:
        rig = rig if isinstance(rig, Rig) else load_rig(rig)
        stack = stack_from_frames(frames, rig, channel=channel)
        recon = reconstruct(stack, detect or DetectParams(), anchor=anchor)
        recon.write_table(tmp / "highlights.csv")
    return recon


def reconstruct_diligent(folder: str | os.PathLike, out: str | os.PathLike, *, detect: DetectParams | None = None,
                         overwrite: bool = False) -> tuple[Any, Reconstruction, dict[str, Any] | None]:
    """Reconstruct a DiLiGenT folder (distant lights, orthographic view) and score it against its ``Normal_gt``.

    Writes ``highlights.csv`` and, where the folder has ground truth,
    ``score.json`` (per normal model the statistics of
    :func:`~shinysim.evaluate.score_normals`, without the per-highlight
    errors) into ``out``. Returns the folder's data
    (:func:`~shinysim.io.diligent.read_diligent`), the reconstruction and the
    score (None without ground truth or highlights).
    """
    from ..evaluate import score_normals
    from ..io.diligent import read_diligent

    data = read_diligent(folder)
    names = ["highlights.csv"] + (["score.json"] if data.truth is not None else [])
    with output_folder(out, names, overwrite=overwrite) as tmp:
        recon = reconstruct(data.stack, detect or DetectParams())
        recon.write_table(tmp / "highlights.csv")
        score = None
        if data.truth is not None and len(recon):
            score = {"source": str(folder), "models": {
                m: _without_errors(score_normals(recon.table["row"], recon.table["col"], n, data.truth))
                for m, n in recon.normals.items()}}
            write_json(tmp / "score.json", score)
    return data, recon, score


def score_folder(folder: str | os.PathLike, *, detect: DetectParams | None = None, sphere_radius: float | None = None,
                 sphere_center: tuple[float, float, float] = (0.0, 0.0, 0.0), out: str | os.PathLike | None = None,
                 overwrite: bool = False) -> dict[str, Any]:
    """Score a scan folder's highlights against its truth; writes ``score.json``.

    The highlights scored are those of the folder's ``highlights.csv`` (what
    ``shinysim reconstruct`` or ``scan`` wrote), checked against the stack's
    rig and image size. With ``detect`` given, or without a
    ``highlights.csv``, the stack is detected again instead, and
    ``score.json`` says so (its ``highlights`` field) with the parameters
    used (``detect``).
    """
    from ..evaluate import score_reconstruction

    if sphere_radius is not None:
        sphere_radius = check_number("sphere radius", sphere_radius, lo=0, lo_open=True)
    folder = Path(folder)
    out = folder if out is None else Path(out)
    check_free(out, ["score.json"], overwrite)
    stack = load_stack(folder / "stack.exr")
    truth = load_truth(folder / "truth.exr", stack.camera)
    table_path = folder / "highlights.csv"
    if detect is None and os.path.lexists(table_path):
        table, normals = read_highlight_table(table_path, n_sources=stack.n_sources, shape=stack.camera.shape,
                                              models=NORMAL_MODELS)
        found = set(table["source"].tolist())
        recon = Reconstruction(table, normals, stack.camera.shape,
                               [k for k in range(stack.n_sources) if k not in found], None)
        how = {"highlights": f"read from {table_path.name}"}
    else:
        why = "detection options were given" if detect is not None else f"there is no {table_path.name}"
        detect = detect or DetectParams()
        recon = reconstruct(stack, detect)
        how = {"highlights": f"detected again ({why})", "detect": asdict(detect), "detection": recon.detection,
               "near_field": recon.near_field, "notes": recon.notes}
    kwargs = {"sphere_center": sphere_center, "sphere_radius": sphere_radius} if sphere_radius is not None else {}
    per_model = score_reconstruction(recon, truth, **kwargs)
    score = _summary(per_model, recon, {**how, "provenance": stack.provenance})
    write_json(out / "score.json", score, overwrite=overwrite)
    return score
