"""Structured-highlight stereo end to end (paper Section V): render two cameras, match, score.

Used by ``shinysim stereo``. :func:`run_stereo` renders each camera's stack
and truth of an object somewhere in a working volume (where the distant-source
approximation fails), finds the highlights in each stack, matches them across
the cameras (:mod:`shinysim.recon.stereo`), and scores the matches against
the truth beside the single-camera models on the same highlights, so the
table shows what the second camera buys.

The scene, rig and scoring are separate functions (:func:`stereo_scene`,
:func:`stereo_rig`, :func:`score_stereo`) so that notebooks and tests can
run the pieces. Rendering needs the ``render`` extra; scoring needs only
numpy and scipy.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import asdict
from typing import Any

import numpy as np

from .._shared import (
    Progress,
    check_choice,
    check_number,
    output_folder,
    stage_reporter,
    write_file,
    write_json,
)
from ..errors import OptionError, StereoError
from ..evaluate import NEAR_FIELD_ORACLE, sample_truth, score_stereo
from ..objects.registry import scanned_object
from ..recon import NORMAL_MODELS, DetectParams, reconstruct
from ..recon.normals import surface_points
from ..recon.stereo import StereoParams, match_stacks
from ..rig import CAMERA_PROJECTIONS, STEREO_FIELD_WIDTH_MM, Anchor, Rig, rig_preset
from ..rig import STEREO_RIGS as PRESET_OF

__all__ = [
    "STEREO_SCENES",
    "STEREO_PLACEMENT",
    "STEREO_RIGS",
    "STEREO_FILES",
    "STEREO_LIMITS",
    "stereo_object",
    "stereo_scene",
    "stereo_rig",
    "check_stereo_inputs",
    "score_stereo",
    "run_stereo",
]

#: Objects of the stereo study (:data:`~shinysim.objects.registry.STEREO_OBJECTS`): each lies off the origin
#: or above the reference plane.
STEREO_SCENES = {
    "sphere": "the SHINY calibration sphere (r = 0.79375 mm) 1.5 mm sideways and 0.8 mm up",
    "three_spheres": "three calibration spheres at different places and heights",
    "three_sizes": "spheres of r = 1.2, 0.5 and 0.8 mm at (-2.0, -2.2, 0.3), (0.3, 0.2, 1.0), (2.3, 2.4, -0.5) mm",
    "large_sphere": "a sphere of r = 5 mm whose top is 2 mm above the reference plane",
    "shallow_sphere": "a large shallow sphere (a 12 mm radius cap, 0.5 mm high): a machined part",
    "tilted_plane": "a flat mirror 5 mm square, tilted 10 degrees, 0.5 mm above the reference plane",
    "solder": "a good solder joint raised 0.5 mm off the reference plane (direct light)",
}

#: Source arrays of the stereo study.
STEREO_RIGS = {
    "dome": "a Fibonacci dome of n_sources at 43.18 mm, holes for the cameras (3-D stereo)",
    "semicircle": "fibers every 2.5 degrees in the x-z plane, so that 2 beta = 30 degrees is whole spacings",
    "shiny": "the paper's 21 fibers, 8 degrees apart, on the 43.18 mm semicircle",
    "crossing_arcs": "two crossing arcs of 21 fibers 8 degrees apart, in the x-z and y-z planes (41 sources)",
}

#: Files a stereo folder holds; none of them is ever silently replaced.
STEREO_FILES = ("rig.json", "stack.exr", "stack.camera1.exr", "truth.exr", "truth.camera1.exr",
                "highlights.csv", "highlights.camera1.csv", "matches.csv", "stereo_score.json", "stereo.png")

#: Ranges of the stereo options, checked before any work, each with its reason.
STEREO_LIMITS = {
    # the cameras are turned about y; beyond 45 degrees a camera looks at the
    # working volume from the side and the dome's rim stands in its view
    "beta_deg": dict(lo=0, hi=45, lo_open=True),
    # rough-conductor alpha: 0 is a perfect mirror (no sampled highlight from
    # small sources); above 1 is not a microfacet roughness
    "alpha": dict(lo=1e-4, hi=1.0),
    # 64 px puts the calibration sphere on ~17 px in the 6 mm field; 2048 px
    # makes two 1000-frame float stacks of 16 GB
    "resolution": dict(lo=64, hi=2048, integer=True),
    "spp": dict(lo=1, hi=65536, integer=True),
    # a dome of fewer than 20 sources has no stereo pairs on common elements;
    # above 4000 a 512 px stack is 4 GB per camera
    "n_sources": dict(lo=20, hi=4000, integer=True),
    "seed": dict(lo=0, hi=2**32 - 1, integer=True),
}

def check_stereo_inputs(*, scene, rig, beta_deg, alpha, resolution, spp, n_sources, seed):
    """Check the study's options before any work; an :class:`OptionError` names the option."""
    check_choice("scene", scene, tuple(STEREO_SCENES))
    check_choice("rig", rig, tuple(STEREO_RIGS))
    for name, value in (("beta_deg", beta_deg), ("alpha", alpha), ("resolution", resolution), ("spp", spp),
                        ("n_sources", n_sources), ("seed", seed)):
        check_number(name, value, **STEREO_LIMITS[name])


def stereo_rig(preset: str = "dome", *, beta_deg: float = 15.0, resolution: int = 512, n_sources: int = 1000,
               projection: str = "perspective") -> Rig:
    """The study's two-camera rig: a preset of :data:`STEREO_RIGS` with cameras at +-beta
    (:data:`shinysim.rig.STEREO_RIGS` names its :data:`~shinysim.rig.RIG_PRESETS` entry).

    Every preset images a :data:`~shinysim.rig.STEREO_FIELD_WIDTH_MM` field at 512 px by default
    (11.7 um pixels at the object).
    """
    check_choice("rig", preset, tuple(STEREO_RIGS))
    options = dict(beta_deg=beta_deg, resolution=resolution, field_width_mm=STEREO_FIELD_WIDTH_MM,
                   projection=projection)
    if preset == "dome":
        options["n_sources"] = n_sources
    return rig_preset(PRESET_OF[preset], **options)


#: Where the stereo study places each of its :data:`~shinysim.objects.registry.OBJECTS`.
STEREO_PLACEMENT = {"sphere": dict(center_mm=(1.5, 0.0, 0.8), part="sphere"), "solder": dict(lift_mm=0.5)}


def stereo_object(name: str):
    """The :class:`~shinysim.objects.registry.ScannedObject` of stereo scene ``name`` (:data:`STEREO_SCENES`),
    placed as :data:`STEREO_PLACEMENT` says: its exact surface and highlights score a scan of it."""
    check_choice("scene", name, tuple(STEREO_SCENES))
    return scanned_object(name, **STEREO_PLACEMENT.get(name, {}))


def stereo_scene(name: str, *, alpha: float = 0.02, folder: str | os.PathLike | None = None) -> tuple[dict, dict]:
    """Objects of a stereo scene (Mitsuba shape dicts, named by part) and a description.

    Parameters
    ----------
    name : str
        One of :data:`STEREO_SCENES`: a :func:`~shinysim.objects.registry.scanned_object` placed as
        :data:`STEREO_PLACEMENT` says.
    alpha : float
        Roughness of the polished objects (the solder joint keeps its
        materials).
    folder : path-like, optional
        Where a mesh scene (``solder``) writes its PLY files; they must stay
        there until the scene is loaded.

    Returns
    -------
    objects : dict of str -> dict
    description : dict
        JSON-ready: what the scene is, with its geometry.
    """
    from ..sim.objects import scene_objects

    obj = stereo_object(name)
    objects = scene_objects(obj, alpha=alpha, folder=folder)
    return objects, {"scene": name, "what": STEREO_SCENES[name], **obj.description(list(objects))}


# -- scoring -------------------------------------------------------------------------


def single_camera_estimates(recons, stacks, oracle_points=None) -> dict:
    """Normals and surface points of each single-camera model for both cameras' highlights.

    The paper's three models place each highlight on the reference plane.
    The near-field model needs one known height (:mod:`shinysim.recon.nearfield`):
    a single camera in a working volume knows none, so ``near-field`` is
    anchored where the highlight nearest the image centre would be if the
    object sat on the reference plane; with ``oracle_points`` (one true
    surface point per camera) :data:`NEAR_FIELD_ORACLE` is also computed,
    as the bound a single camera reaches when told the height.
    """
    from ..recon.nearfield import NEAR_FIELD, near_field_normals

    out: dict[str, list] = {}
    for k, (rec, stack) in enumerate(zip(recons, stacks)):
        t = rec.table
        for model in (m for m in NORMAL_MODELS if m != NEAR_FIELD):
            pts = surface_points(t["row"], t["col"], stack.rig, model=model, camera_index=stack.camera_index)
            out.setdefault(model, []).append((rec.normals[model], pts))
        if len(t["row"]) < 3:
            continue
        cam = stack.camera
        h, w = cam.shape
        i = int(np.argmin(np.hypot(t["row"] - (h - 1) / 2, t["col"] - (w - 1) / 2)))
        anchors = {NEAR_FIELD: cam.backproject_to_plane(t["row"][i], t["col"][i], stack.rig.reference_z)}
        if oracle_points is not None and oracle_points[k] is not None:
            anchors[NEAR_FIELD_ORACLE] = oracle_points[k]
        for name, point in anchors.items():
            nf = near_field_normals(t["row"], t["col"], t["source"], stack.rig, Anchor.at_point(point),
                                    camera_index=stack.camera_index)
            out.setdefault(name, []).append((nf.normals, nf.points))
    return {m: v for m, v in out.items() if len(v) == len(recons)}


# -- the whole run ---------------------------------------------------------------------

def _stereo_bytes(rig):
    cam = rig.cameras[0]
    # sparse highlight frames compress well; budget a quarter of float16 per frame
    return int(2 * rig.n_sources * cam.width * cam.height * 2 * 0.25 + 4 * 2 * cam.width * cam.height * 28)


def run_stereo(out: str | os.PathLike, *, scene: str = "sphere", rig: str = "dome", beta_deg: float = 15.0,
               alpha: float = 0.02, projection: str = "perspective", resolution: int = 512, spp: int = 16, n_sources: int = 1000, seed: int = 0,
               sensor: str | None = None, exposure: float = 0.8, params=None,
               detect: DetectParams | None = None, variant: str | None = None, overwrite: bool = False,
               progress: Progress | None = None, plot: bool = True) -> dict[str, Any]:
    """Render a stereo scan, match its highlights, score them: ``shinysim stereo``.

    Parameters
    ----------
    out : path-like
        Folder for :data:`STEREO_FILES` (created; nothing is replaced unless
        ``overwrite``).
    scene : str
        One of :data:`STEREO_SCENES`.
    rig : str
        One of :data:`STEREO_RIGS`.
    beta_deg : float
        Each camera's angle from the vertical.
    projection : {"perspective", "orthographic"}
        Both cameras'.
    alpha, resolution, spp, n_sources, seed
        Roughness, image size, samples per pixel, dome sources, seed.
    sensor : str, optional
        A sensor preset (:data:`shinysim.sim.sensor.SENSOR_PRESETS`) that
        digitises both stacks, exposed so that the brighter stack's
        brightest pixel fills ``exposure`` of its full well.
    params : StereoParams, optional
        Matching settings.
    progress : callable, optional
        ``progress(stage, done, total)`` after each stage and
        ``progress("info", 0, 0, message)``.

    Returns
    -------
    dict
        The content of ``stereo_score.json``.
    """
    check_stereo_inputs(scene=scene, rig=rig, beta_deg=beta_deg, alpha=alpha, resolution=resolution, spp=spp,
                        n_sources=n_sources, seed=seed)
    exposure = check_number("exposure", exposure, lo=0, lo_open=True, hi=1e3)
    if params is not None and not isinstance(params, StereoParams):
        raise OptionError(f"params must be StereoParams, got {type(params).__name__}")
    from ..sim.sensor import sensor_preset
    from ..sim.variants import choose_variant

    sensor_obj = sensor_preset(sensor or "ideal")
    choose_variant(variant)
    from ..io import load_stack, load_truth, save_stack, save_truth
    check_choice("projection", projection, CAMERA_PROJECTIONS)
    the_rig = stereo_rig(rig, beta_deg=beta_deg, resolution=resolution, n_sources=n_sources, projection=projection)
    names = STEREO_FILES if plot else STEREO_FILES[:-1]
    stages = ["scene", "render camera 0", "render camera 1", "write", "detect", "match", "score", "figure"]
    stages = stages if plot else stages[:-1]

    done, say = stage_reporter(progress, stages)

    with output_folder(out, names, overwrite=overwrite, needed_bytes=_stereo_bytes(the_rig),
                       last="stereo_score.json") as tmp, tempfile.TemporaryDirectory(prefix="shinysim-") as meshes:
        objects, desc = stereo_scene(scene, alpha=alpha, folder=meshes)
        stacks, truths = render_stereo(the_rig, objects, spp=spp, seed=seed, sensor=sensor_obj, exposure=exposure,
                                       variant=variant, progress=progress, stages=stages)
        the_rig.save(tmp / "rig.json")
        for k in range(2):
            suffix = "" if k == 0 else f".camera{k}"
            save_stack(stacks[k], tmp / f"stack{suffix}.exr", rig_path=tmp / "rig.json", overwrite=True)
            save_truth(truths[k], tmp / f"truth{suffix}.exr")
            # analyse what was written, so that the folder's numbers are a function of its files
            stacks[k] = load_stack(tmp / f"stack{suffix}.exr")
            truths[k] = load_truth(tmp / f"truth{suffix}.exr", stacks[k].camera)
        done("write")
        result = analyse_stereo(stacks, truths, params=params, detect=detect, progress=progress, stages=stages,
                                obj=stereo_object(scene))
        recons, matches, score = result["recons"], result["matches"], result["score"]
        for k, rec in enumerate(recons):
            rec.write_table(tmp / ("highlights.csv" if k == 0 else f"highlights.camera{k}.csv"))
        matches.to_csv(tmp / "matches.csv")
        say(f"{len(matches)} matches of {matches.n_candidates} candidate pairs"
            + (f" ({matches.reason})" if matches.reason else ""))
        score.update({
            "scene": desc, "rig": {"preset": rig, "n_sources": the_rig.n_sources, "beta_deg": beta_deg,
                                   "projection": projection,
                                   "metadata": the_rig.metadata},
            "alpha": alpha, "resolution": resolution, "spp": spp, "seed": seed,
            "sensor": None if sensor_obj is None else sensor_obj.to_dict(), "exposure": exposure,
            "provenance": stacks[0].provenance,
        })
        write_json(tmp / "stereo_score.json", score)
        if plot:
            from ..plot.stereo_scan import stereo_matches_figure

            best = score.get("best_single_camera")
            points = result["single"][best][0][1] if best else None
            fig = stereo_matches_figure(stacks, matches, truths, score, single_points=points)
            write_file(tmp / "stereo.png", lambda f: fig.savefig(f, dpi=100, format="png"))
            done("figure")
    return score


def render_stereo(rig: Rig, objects: dict, *, spp: int = 16, seed: int = 0, sensor=None, exposure: float = 0.8,
                  variant: str | None = None, progress: Progress | None = None, stages=None):
    """Each camera's stack and truth of one scene, from one loaded scene.

    Parameters
    ----------
    rig : Rig
        Two cameras (or more; the first two are rendered).
    objects : dict
        Mitsuba shape dicts by part name (:func:`stereo_scene`).
    sensor : shinysim.sim.sensor.Sensor, optional
        Digitises both stacks, exposed so that the brighter stack's brightest
        pixel fills ``exposure`` of its full well (one exposure for both
        cameras, as one rig would have); noise from ``seed`` and ``seed + 1``.

    Returns
    -------
    stacks, truths : list of Stack, list of Truth
    """
    from ..sim.render import Simulator

    if len(rig.cameras) < 2:
        raise StereoError("the rig has one camera; stereo needs two", field="rig.cameras")
    done, say = stage_reporter(progress, stages)
    sim = Simulator(rig, objects, variant=variant)
    say(sim.variant_reason)
    done("scene")
    stacks, truths = [], []
    for k in range(2):
        sim.use_camera(k)
        truths.append(sim.render_truth())
        stacks.append(sim.render_stack(spp=spp, seed=seed + k))
        say(f"camera {k}: {stacks[-1].n_sources} frames in {sim.last_render_seconds:.2f} s")
        done(f"render camera {k}")
    if sensor is not None:
        peak = max(float(s.frames.max()) for s in stacks)
        exposed = sensor.exposed_for(peak, fraction=exposure)
        stacks = [exposed.expose(s, seed=seed + k) for k, s in enumerate(stacks)]
        say(f"digitised by the {exposed.name} sensor")
    return stacks, truths


#: Highlight detection of the stereo study: regions found at the frames' noise (or the render's: one
#: sample's share of the brightest pixel), each measured over its pixels at half its own peak. A frame
#: may hold a bright highlight on a large element and a dim one on a small element; a level relative to
#: the frame's or the scan's peak would lose the dim one.
STEREO_DETECT = DetectParams(threshold_mode="highlight", threshold=0.5)


def analyse_stereo(stacks, truths=None, *, params=None, detect: DetectParams | None = None, oracle: bool = True,
                   obj=None, progress: Progress | None = None, stages=None) -> dict[str, Any]:
    """Detect, match and (with truths) score a stereo scan.

    ``obj``, the :class:`~shinysim.objects.registry.ScannedObject` scanned (or a :data:`STEREO_SCENES`
    name, :func:`stereo_object`), gives the exact surface and highlights the score uses where it is made
    of spheres and facets (:func:`score_stereo`); without it recall is not computed.

    Returns
    -------
    dict
        ``recons`` (each camera's :class:`~shinysim.recon.Reconstruction`
        with the paper's models), ``matches``
        (:class:`~shinysim.recon.stereo.StereoMatches`), and with
        ``truths`` also ``single`` (:func:`single_camera_estimates`) and
        ``score`` (:func:`score_stereo` plus the settings used).
    """
    done, _ = stage_reporter(progress, stages)
    detect = detect or STEREO_DETECT
    obj = stereo_object(obj) if isinstance(obj, str) else obj
    recons = [reconstruct(s, detect, models=tuple(m for m in NORMAL_MODELS if m != "near-field")) for s in stacks]
    done("detect")
    matches = match_stacks(stacks[0], stacks[1], tables=[r.table for r in recons], params=params)
    done("match")
    out: dict[str, Any] = {"recons": recons, "matches": matches}
    if truths is None:
        return out
    anchors = [_anchor_point(rec, truth) for rec, truth in zip(recons, truths)] if oracle else None
    out["single"] = single_camera_estimates(recons, stacks, anchors)
    score = score_stereo(matches, [r.table for r in recons], truths, stacks[0].rig, single=out["single"], obj=obj)
    score.update({
        "detect": asdict(detect),
        "match_params": {"d0_mm": matches.d0_mm, "max_normal_gap_deg": matches.max_normal_gap_deg,
                         "neighbourhood_mm": matches.neighbourhood_mm,
                         "relax": True if params is None else bool(params.relax)},
        "near_field_anchor": ("near-field: the highlight nearest the image centre placed on the reference "
                              "plane; near-field (true anchor): its true surface point, a bound"),
    })
    out["score"] = score
    done("score")
    return out


def _anchor_point(rec, truth):
    t = rec.table
    if not len(t["row"]):
        return None
    h, w = truth.mask.shape
    order = np.argsort(np.hypot(t["row"] - (h - 1) / 2, t["col"] - (w - 1) / 2))
    for i in order:
        _, p, valid = sample_truth(truth, t["row"][i:i + 1], t["col"][i:i + 1])
        if valid[0]:
            return p[0]
    return None
