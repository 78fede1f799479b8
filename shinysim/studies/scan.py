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

from .._shared import Progress, check_free, write_file, write_json
from ..io import load_stack, load_truth, save_stack, save_truth
from ..recon import NORMAL_MODELS, DetectParams, Reconstruction, reconstruct
from ..rig import Rig

__all__ = ["SCAN_FILES", "run_scan", "reconstruct_folder", "score_folder", "write_score"]

#: Files a scan folder may hold; none of them is ever silently replaced.
SCAN_FILES = ("rig.json", "stack.exr", "truth.exr", "highlights.csv", "score.json", "scan.png")


def write_score(path: str | os.PathLike, score: dict[str, Any], *, overwrite: bool = False) -> Path:
    """Write a score dict as JSON (NaN becomes null)."""
    return write_json(path, score, overwrite=overwrite)


def _summary(per_model, recon, extra):
    models = {}
    for m, s in per_model.items():
        models[m] = {k: v for k, v in s.items() if k != "errors_deg"}
    best = min(models, key=lambda m: (np.inf if not np.isfinite(models[m]["median_deg"]) else models[m]["median_deg"]))
    return {
        "models": models,
        "best_model": best,
        "n_highlights": len(recon),
        "empty_sources": recon.empty_sources,
        "detect": asdict(recon.params),
        **extra,
    }


def run_scan(out: str | os.PathLike, *, alpha: float = 0.02, projection: str = "perspective", resolution: int = 512,
             spp: int = 64, seed: int = 0, variant: str | None = None, method: str | None = None,
             detect: DetectParams | None = None, overwrite: bool = False, progress: Progress | None = None,
             plot: bool = True, distribution: str = "ggx") -> dict[str, Any]:
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
    from ..rig import shiny_1988
    from ..sim.render import Simulator
    from ..sim.scene import sphere_object

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    check_free(out, SCAN_FILES, overwrite)
    stages = ["scene", "truth", "render", "write stack", "reconstruct", "score", "figure"][: 7 if plot else 6]

    def done(stage):
        if progress:
            progress(stage, stages.index(stage) + 1, len(stages))

    rig = shiny_1988(projection=projection, resolution=resolution)
    sim = Simulator(rig, sphere_object(alpha=alpha, distribution=distribution), variant=variant)
    if progress:
        progress("info", 0, 0, sim.variant_reason)
    done("scene")
    truth = sim.render_truth()
    done("truth")
    stack = sim.render_stack(spp=spp, seed=seed, method=method)
    done("render")
    save_stack(stack, out / "stack.exr", overwrite=overwrite)
    save_truth(truth, out / "truth.exr", overwrite=overwrite)
    done("write stack")
    detect = detect or DetectParams()
    recon = reconstruct(stack, detect)
    recon.write_table(out / "highlights.csv", overwrite=overwrite)
    done("reconstruct")
    from ..evaluate import score_reconstruction

    per_model = score_reconstruction(recon, truth, sphere_center=(0, 0, 0), sphere_radius=SHINY_SPHERE_RADIUS_MM)
    score = _summary(per_model, recon, {
        "object": "sphere",
        "sphere_radius_mm": SHINY_SPHERE_RADIUS_MM,
        "alpha": alpha,
        "distribution": distribution,
        "projection": projection,
        "resolution": resolution,
        "provenance": stack.provenance,
    })
    write_score(out / "score.json", score, overwrite=overwrite)
    done("score")
    if plot:
        from ..plot.scan import scan_figure

        fig = scan_figure(stack, recon, truth, per_model[score["best_model"]], model=score["best_model"],
                          sphere_radius=SHINY_SPHERE_RADIUS_MM)
        write_file(out / "scan.png", lambda tmp: fig.savefig(tmp, dpi=110, format="png"), overwrite=overwrite)
        done("figure")
    return score


def reconstruct_folder(folder: str | os.PathLike, *, out: str | os.PathLike | None = None,
                       rig: Rig | str | os.PathLike | None = None, detect: DetectParams | None = None,
                       models: tuple[str, ...] = NORMAL_MODELS, overwrite: bool = False) -> Reconstruction:
    """Reconstruct a scan folder's stack (no renderer needed).

    Writes ``highlights.csv`` into ``out`` (default: the folder itself) and
    returns the :class:`~shinysim.recon.Reconstruction`.
    """
    folder = Path(folder)
    out = folder if out is None else Path(out)
    out.mkdir(parents=True, exist_ok=True)
    check_free(out, ["highlights.csv"], overwrite)
    stack = load_stack(folder / "stack.exr", rig)
    recon = reconstruct(stack, detect or DetectParams(), models=models)
    recon.write_table(out / "highlights.csv", overwrite=overwrite)
    return recon


def score_folder(folder: str | os.PathLike, *, detect: DetectParams | None = None, sphere_radius: float | None = None,
                 sphere_center: tuple[float, float, float] = (0.0, 0.0, 0.0), out: str | os.PathLike | None = None,
                 overwrite: bool = False) -> dict[str, Any]:
    """Score a scan folder's stack against its truth; writes ``score.json``."""
    from ..evaluate import score_reconstruction

    folder = Path(folder)
    out = folder if out is None else Path(out)
    check_free(out, ["score.json"], overwrite)
    stack = load_stack(folder / "stack.exr")
    truth = load_truth(folder / "truth.exr", stack.camera)
    recon = reconstruct(stack, detect or DetectParams())
    kwargs = {}
    if sphere_radius is not None:
        kwargs = {"sphere_center": sphere_center, "sphere_radius": sphere_radius}
    per_model = score_reconstruction(recon, truth, **kwargs)
    score = _summary(per_model, recon, {"provenance": stack.provenance})
    write_score(out / "score.json", score, overwrite=overwrite)
    return score
