"""Normal error against exposure for real camera sensors (the sphere scan, digitised).

The calibration sphere is rendered once (ideal float frames and truth);
each sensor preset then digitises that stack at a series of exposures (the
fraction of its full well that the brightest pixel fills), with several
noise seeds, and the default detection and all four normal models are
scored against the truth. Below the right exposure, shot and read noise and
quantisation move the centroids; above it, the highlights clip.

Used by ``shinysim exposure``; needs the ``render`` extra.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from .._shared import Progress, check_number, output_folder, write_json

__all__ = ["EXPOSURE_PRESETS", "EXPOSURES", "exposure_sweep", "run_exposure"]

#: The sensors of the sweep.
EXPOSURE_PRESETS = ("machine_vision_12bit", "tv_1980s_8bit")
#: Fractions of the full well at the brightest pixel (above 1: clipped).
EXPOSURES = (0.02, 0.05, 0.1, 0.2, 0.4, 0.8, 1.0, 2.0, 5.0)
_STATS = ("median_deg", "p95_deg", "max_deg")


def exposure_sweep(*, presets: tuple[str, ...] = EXPOSURE_PRESETS, exposures: tuple[float, ...] = EXPOSURES,
                   seeds: tuple[int, ...] = (0, 1, 2), centroids: tuple[str, ...] = ("weighted", "plain"),
                   alpha: float = 0.02, resolution: int = 512, spp: int = 64, variant: str | None = None,
                   progress: Progress | None = None) -> dict[str, Any]:
    """Score the default sphere scan digitised by each preset at each exposure.

    Each digitised stack is detected with each centroid method: ``"plain"``
    (the paper's centre of gravity of the thresholded pixels) and
    ``"weighted"`` (weighted by the background-subtracted intensity, the
    default).

    Returns
    -------
    dict
        ``settings``, and ``rows``: one per preset, exposure and centroid method, with, over
        the seeds, the mean number of highlights and of sources found, the
        number of runs that found exactly the 21 highlights, the mean number
        of saturated highlights, and per normal model the mean of the
        median, p95 and max errors (degrees) and their largest values.
    """
    from ..errors import ShinysimError
    from ..evaluate import score_reconstruction
    from ..recon import DetectParams, reconstruct
    from ..sim.render import Simulator
    from ..sim.objects import scene_objects
    from ..sim.sensor import sensor_preset
    from .scan import sphere_scan_rig

    for e in exposures:
        check_number("exposure", e, lo=0, lo_open=True, hi=1e3)
    presets = tuple(presets)
    sensors = {name: sensor_preset(name) for name in presets}
    rig = sphere_scan_rig(resolution=resolution)
    sim = Simulator(rig, scene_objects("sphere", alpha=alpha), variant=variant)
    truth = sim.render_truth()
    ideal = sim.render_stack(spp=spp, seed=0)
    peak = float(ideal.frames.max())
    total = len(presets) * len(exposures) * len(seeds)
    done = 0
    runs = {}
    for name in presets:
        for e in exposures:
            for seed in seeds:
                stack = sensors[name].exposed_for(peak, fraction=e).expose(ideal, seed=seed)
                for method in centroids:
                    try:
                        recon = reconstruct(stack, DetectParams(centroid=method))
                    except ShinysimError as exc:  # e.g. a frame over-exposed beyond use: refused, and said
                        runs.setdefault((name, e, method), []).append({"refused": str(exc)})
                        continue
                    per_model = score_reconstruction(recon, truth)
                    runs.setdefault((name, e, method), []).append({
                        "n": len(recon),
                        "sources": len(set(recon.table["source"].tolist())),
                        "saturated": recon.detection["n_saturated"],
                        "models": {m: {k: s[k] for k in _STATS} for m, s in per_model.items()},
                    })
                done += 1
                if progress:
                    progress(f"{name} {e:g}", done, total)
    rows = []
    for (name, e, method), rs in runs.items():
        ok = [r for r in rs if "refused" not in r]
        row = {"preset": name, "exposure": e, "centroid": method, "runs": len(rs), "refused": len(rs) - len(ok),
               "refusal": next((r["refused"] for r in rs if "refused" in r), None)}
        if ok:
            row.update({
                "mean_highlights": float(np.mean([r["n"] for r in ok])),
                "mean_sources": float(np.mean([r["sources"] for r in ok])),
                "exactly_21": int(sum(r["n"] == 21 and r["sources"] == 21 for r in ok)),
                "mean_saturated": float(np.mean([r["saturated"] for r in ok])),
                "models": {m: {
                    **{k: float(np.mean([r["models"][m][k] for r in ok])) for k in _STATS},
                    "worst_median_deg": float(np.max([r["models"][m]["median_deg"] for r in ok])),
                } for m in ok[0]["models"]},
            })
        rows.append(row)
    return {
        "settings": {"presets": list(presets), "exposures": list(exposures), "seeds": list(seeds),
                     "centroids": list(centroids), "alpha": alpha, "ideal_peak_radiance": peak,
                     "resolution": resolution, "spp": spp, "sensors": {n: sensors[n].to_dict() for n in presets}},
        "rows": rows,
    }


def run_exposure(out: str | os.PathLike, *, quick: bool = False, overwrite: bool = False,
                 variant: str | None = None, progress: Progress | None = None) -> dict[str, Any]:
    """Run :func:`exposure_sweep` and write ``exposure.json`` into ``out``.

    ``quick``: a 256 px, 16 spp scan, one seed, five exposures (about half a
    minute) instead of 512 px, 64 spp, three seeds, nine exposures.
    """
    from ..sim.variants import choose_variant

    choose_variant(variant)
    kwargs = dict(resolution=256, spp=16, seeds=(0,), exposures=(0.05, 0.2, 0.8, 1.0, 5.0)) if quick else {}
    with output_folder(out, ["exposure.json"], overwrite=overwrite) as tmp:
        result = exposure_sweep(variant=variant, progress=progress, **kwargs)
        write_json(Path(tmp) / "exposure.json", result)
    return result
