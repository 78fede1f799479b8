"""What miscalibration costs: a rig built off its design, calibrated, and scanned.

:func:`run_calibration_study` (``shinysim calibrate study``) draws a true rig
from the nominal SHINY rig (:data:`STUDY_TOLERANCES`), renders the hole plate
at :data:`PLATE_PLACEMENTS` and the calibration sphere at
:data:`SPHERE_CENTERS` with it, calibrates the camera and then the fibers
from those images and the nominal rig alone, reconstructs the default sphere
scan with the nominal, calibrated and true rigs, and tests the paper's Fig. 6
requirement in simulation. Everything is written to the output folder, so
``shinysim calibrate camera`` and ``sources`` can be rerun on the same files
by hand. The steps and the measured numbers: ``docs/calibration.md``,
sections "What miscalibration costs" and "The paper's Fig. 6 requirement".
"""

from __future__ import annotations

import os
from dataclasses import replace
from typing import Any

import numpy as np

from .._shared import (
    Progress,
    check_number,
    derive_seed,
    json_safe,
    output_folder,
    write_file,
    write_json,
)
from ..errors import OptionError
from ..rig import Rig, RigTolerances, perturb_rig

__all__ = [
    "STUDY_TOLERANCES",
    "PLATE_PLACEMENTS",
    "SPHERE_CENTERS",
    "CALIBRATION_SPHERE_ALPHA",
    "FIG6_DELTAS_RAD",
    "CALIBRATION_FILES",
    "QUICK_SETTINGS",
    "render_plates",
    "render_sphere_scans",
    "run_calibration_study",
    "summary_lines",
]

#: The issue's rig errors, plus a principal point and distortion for the
#: camera calibration to find (a real lens has both).
STUDY_TOLERANCES = RigTolerances(fiber_position_mm=0.5, fiber_radius_fraction=0.05, camera_rotation_deg=0.05,
                                 camera_translation_mm=0.05, focal_fraction=0.005, principal_point_px=2.0,
                                 distortion=(5e-4, -1e-4))

#: Hole-plate placements: (offset_mm, tilt_deg), for the study's plate, a 5 x 5
#: grid of the paper's 0.2032 mm holes 0.35 mm apart
#: (:func:`shinysim.objects.plate.dot_grid`). Three heights on known spacers
#: (z = -1, 0, +1 mm): at a 0.9 degree field only the parallax between heights
#: separates the camera's distance from its focal length and a sideways shift
#: from a rotation. The grid reaches towards the corners of the field, where
#: the distortion is largest (beyond the outermost holes it is only
#: extrapolated), yet stays in view of a camera rotated by 1 mrad (which moves
#: the image by 0.13 mm). The paper's seven-hole plate cannot: shifted far
#: enough to reach the corners, its holes leave the field of the rotated
#: camera (docs/calibration.md has the table of what each set gives).
PLATE_PLACEMENTS = (((0.0, 0.0, 0.0), (0.0, 0.0)), ((0.0, 0.0, 1.0), (0.0, 0.0)), ((0.0, 0.0, -1.0), (0.0, 0.0)))

#: ``quick``: 256 px and fewer samples (about a minute), which the options given still override.
QUICK_SETTINGS = {"resolution": 256, "spp": 8, "scan_spp": 16}

#: Calibration-sphere centres (mm): lateral shifts that keep every highlight in
#: the 2 mm field (of a camera rotated by 1 mrad too), heights of +-1 mm
#: (spacers) for the baseline along which a fiber's distance is measured,
#: and four diagonal positions half way up or down. Each position adds one
#: highlight per fiber; the direction error falls as one over the square
#: root of their number (docs/calibration.md: 7 positions gave 0.0085 to
#: 0.0102 degrees RMS over three seeds; these 11 give 0.0074 to 0.0083).
SPHERE_CENTERS = (
    (0.0, 0.0, 0.0),
    (0.25, 0.0, 0.0),
    (-0.25, 0.0, 0.0),
    (0.0, 0.25, 0.0),
    (0.0, -0.25, 0.0),
    (0.0, 0.0, 1.0),
    (0.0, 0.0, -1.0),
    (0.18, 0.18, 0.5),
    (-0.18, -0.18, 0.5),
    (0.18, -0.18, -0.5),
    (-0.18, 0.18, -0.5),
)

#: Roughness of the calibration sphere: mirror-like (a polished bearing
#: ball), so its highlight is the fiber's image and the COG its centre.
CALIBRATION_SPHERE_ALPHA = 0.0005

#: Source angular errors of the Fig. 6 check, radians (the paper's bound is 0.1).
FIG6_DELTAS_RAD = (-0.1, -0.05, 0.05, 0.1)

#: Top-level names in the study's folder.
CALIBRATION_FILES = ("nominal_rig.json", "true_rig.json", "calibrated_rig.json", "plates", "spheres", "scan",
                     "calibration_report.json", "calibration.png")


def _placements(placements):
    from ..objects.plate import PlatePlacement

    return [p if isinstance(p, PlatePlacement) else PlatePlacement(offset=tuple(p[0]), tilt_deg=tuple(p[1]))
            for p in placements]


def _render_each(true_rig, scenes, render, what, seed, variant, progress):
    """``render(simulator, seed)`` of each scene with the true rig, reporting ``what + "s"`` to ``progress``."""
    from ..sim.render import Simulator

    out = []
    for i, objects in enumerate(scenes):
        out.append(render(Simulator(true_rig, objects, variant=variant), derive_seed(seed, what, i)))
        if progress:
            progress(f"{what}s", i + 1, len(scenes))
    return out


def render_plates(true_rig: Rig, plate, placements, *, spp: int = 16, seed: int = 0, variant: str | None = None,
                  progress: Progress | None = None) -> list[np.ndarray]:
    """Images of the backlit hole plate at each placement, as the true rig's camera sees it."""
    from ..sim.scene import plate_objects

    return _render_each(true_rig, [plate_objects(plate, p) for p in placements],
                        lambda sim, s: sim.render_emission(spp=spp, seed=s), "plate", seed, variant, progress)


def render_sphere_scans(true_rig: Rig, centers, *, radius: float, alpha: float, spp: int, seed: int = 0,
                        variant: str | None = None, progress: Progress | None = None):
    """Stacks of a sphere at each centre, rendered with the true rig (the stacks carry the true rig)."""
    from ..sim.objects import scene_objects

    scenes = [scene_objects("sphere", radius_mm=radius, center_mm=tuple(c), alpha=alpha) for c in centers]
    return _render_each(true_rig, scenes, lambda sim, s: sim.render_stack(spp=spp, seed=s), "sphere", seed, variant,
                        progress)


def _as_nominal(stack, nominal, perturbation):
    """The stack as a user has it: the rig it claims is the nominal one; how it was really made is provenance."""
    from ..io import Stack

    prov = dict(stack.provenance)
    prov["rendered_with"] = "true_rig.json (the nominal rig perturbed; see its metadata.perturbation)"
    prov["perturbation"] = perturbation
    return Stack(stack.frames, nominal, stack.camera_index, prov)


def _normal_scores(stack, truth, rigs, radius):
    """Normal errors of one stack reconstructed with each rig: {rig name: {model: stats}}."""
    from ..evaluate import score_reconstruction
    from ..io import Stack
    from ..recon import DetectParams, reconstruct

    out = {}
    for name, rig in rigs.items():
        recon = reconstruct(Stack(stack.frames, rig, stack.camera_index, stack.provenance), DetectParams())
        per_model = score_reconstruction(recon, truth, sphere_center=(0, 0, 0), sphere_radius=radius)
        out[name] = {m: {k: v for k, v in s.items() if k != "errors_deg"} for m, s in per_model.items()}
    return out


def _fig6_check(nominal, *, radius, alpha, spp, seed, variant):
    """Fig. 6 in simulation: every fiber turned by delta in its plane; percent normal errors against the theory."""
    from ..evaluate import sample_truth
    from ..io import Stack
    from ..recon import DetectParams, reconstruct
    from ..sim.render import Simulator
    from ..sim.objects import scene_objects
    from ..theory.sensitivity import percent_errors

    cam = nominal.camera
    f = float(cam.position[2])
    rows_out = []
    for j, delta in enumerate(FIG6_DELTAS_RAD):
        pos = nominal.source_positions.copy()
        # turn each fiber about the y axis through the origin by delta, towards the zenith for delta > 0
        # (its elevation above the horizontal grows by delta on either side of the axis)
        side = np.sign(pos[:, 0])
        ang = -side * delta
        c, s = np.cos(ang), np.sin(ang)
        x, z = pos[:, 0].copy(), pos[:, 2].copy()
        pos[:, 0], pos[:, 2] = c * x + s * z, -s * x + c * z
        turned = replace(nominal, source_positions=pos, metadata=dict(nominal.metadata))
        sim = Simulator(turned, scene_objects("sphere", radius_mm=radius, alpha=alpha), variant=variant)
        truth = sim.render_truth()
        stack = sim.render_stack(spp=spp, seed=derive_seed(seed, "fig6", j))
        recon = reconstruct(Stack(stack.frames, nominal, 0, stack.provenance), DetectParams())
        t = recon.table
        n_model = recon.normals["perspective"]
        true_n, true_p, valid = sample_truth(truth, t["row"], t["col"])
        k = np.asarray(t["source"], int)
        # the paper's 2-D geometry, mirrored so that each source lies on +x: angles from the horizontal
        sx = np.sign(nominal.source_positions[k, 0])
        theta_sim = np.arctan2(n_model[:, 2], sx * n_model[:, 0])
        theta_act = np.arctan2(true_n[:, 2], sx * true_n[:, 0])
        simulated = 100.0 * (theta_act - theta_sim) / theta_act
        a, b = sx * nominal.source_positions[k, 0], nominal.source_positions[k, 2]
        a_t, b_t = sx * pos[k, 0], pos[k, 2]
        predicted = percent_errors(sx * true_p[:, 0], true_p[:, 2], a, b, f, image_x="projected",
                                   a_true=a_t, b_true=b_t)["perspective"]
        # only highlights near the scan plane compare with the 2-D theory
        ok = valid & (np.abs(true_p[:, 1]) < 0.02)
        rows_out.append({
            "delta_rad": delta,
            "n": int(ok.sum()),
            "simulated_percent": simulated[ok].tolist(),
            "predicted_percent": predicted[ok].tolist(),
            "max_abs_simulated_percent": float(np.max(np.abs(simulated[ok]))) if ok.any() else None,
            "max_abs_difference_percent": float(np.max(np.abs(simulated[ok] - predicted[ok]))) if ok.any() else None,
            "normal_error_deg_median": float(np.median(np.degrees(np.abs(theta_act - theta_sim)[ok])))
            if ok.any() else None,
        })
    return rows_out


def run_calibration_study(out: str | os.PathLike, *, resolution: int = 512, spp: int = 128, scan_spp: int = 64,
                          seed: int = 0, tolerances: RigTolerances = STUDY_TOLERANCES, plate=None,
                          placements=PLATE_PLACEMENTS, sphere_centers=SPHERE_CENTERS,
                          variant: str | None = None, fig6: bool = True, plot: bool = True,
                          overwrite: bool = False, progress: Progress | None = None) -> dict[str, Any]:
    """Perturb, render, calibrate, rescan and score (``docs/calibration.md``, "What miscalibration costs").

    Parameters
    ----------
    out : path-like
        Folder for the files of :data:`CALIBRATION_FILES` (never replaced
        unless ``overwrite``).
    resolution : int
        Camera size, pixels (square; the field stays 2 mm).
    spp, scan_spp : int
        Samples per pixel of the plate and sphere calibration images, and
        of the test scan. At 32 spp the render noise moves the sphere
        highlights' centres by 0.05 px RMS and the fiber directions come out
        0.014 degrees RMS; 128 spp halves both.
    seed : int
        Draws the true rig and every render's noise.
    tolerances : RigTolerances
    plate : HolePlate, optional
        Default :func:`shinysim.objects.plate.dot_grid` (5 x 5 holes).
    placements, sphere_centers
        Where the plate and the calibration sphere are put.
    fig6 : bool
        Also run the Fig. 6 check (four more scans).

    Returns
    -------
    dict
        The content of ``calibration_report.json``.
    """
    check_number("resolution", resolution, lo=64, hi=4096, integer=True)
    check_number("spp", spp, lo=1, hi=65536, integer=True)
    check_number("scan_spp", scan_spp, lo=1, hi=65536, integer=True)
    check_number("seed", seed, lo=0, hi=2**32 - 1, integer=True)
    if not isinstance(tolerances, RigTolerances):
        raise OptionError(f"tolerances must be RigTolerances, got {type(tolerances).__name__}")
    from ..calibrate.camera import calibrate_camera, find_holes, ray_errors
    from ..calibrate.sources import SpherePlacement, calibrate_sources, observe_sphere
    from ..io import save_frame, save_stack, save_truth
    from ..objects.plate import dot_grid
    from ..objects.sphere import SHINY_SPHERE_RADIUS_MM
    from ..sim.render import Simulator
    from ..sim.objects import scene_objects
    from ..sim.variants import choose_variant
    from .scan import sphere_scan_rig

    choose_variant(variant)
    plate = plate or dot_grid()
    placements = _placements(placements)
    radius = SHINY_SPHERE_RADIUS_MM
    nominal = sphere_scan_rig(resolution=resolution)
    true = perturb_rig(nominal, tolerances, seed=seed)
    perturbation = true.metadata["perturbation"]
    report: dict[str, Any] = {"settings": {
        "resolution": resolution, "spp": spp, "scan_spp": scan_spp, "seed": seed,
        "tolerances": tolerances.to_dict(), "plate": plate.to_dict(),
        "placements": [p.to_dict() for p in placements],
        "sphere_centers_mm": [list(c) for c in sphere_centers], "sphere_radius_mm": radius,
        "calibration_sphere_alpha": CALIBRATION_SPHERE_ALPHA}}

    say = progress or (lambda stage, done, total: None)
    with output_folder(out, CALIBRATION_FILES if plot else CALIBRATION_FILES[:-1], overwrite=overwrite,
                       last="calibration_report.json") as tmp:
        nominal.save(tmp / "nominal_rig.json")
        true.save(tmp / "true_rig.json")
        # -- the camera, from the hole plate -------------------------------------------------------
        images = render_plates(true, plate, placements, spp=spp, seed=seed, variant=variant, progress=progress)
        (tmp / "plates").mkdir()
        observations = []
        for i, (img, placement) in enumerate(zip(images, placements)):
            save_frame(img, tmp / "plates" / f"plate_{i:02d}.exr")
            pts = find_holes(img, plate, placement, nominal.camera, name=f"plates/plate_{i:02d}.exr")
            observations.append((plate, placement, pts))
        write_json(tmp / "plates" / "placements.json", {
            "plate": plate.to_dict(),
            "images": [{"file": f"plate_{i:02d}.exr", "placement": p.to_dict()} for i, p in enumerate(placements)]})
        cam_cal = calibrate_camera(observations, nominal.camera,
                                   estimate=("pose", "focal", "principal_point", "distortion"))
        H, W = true.camera.shape
        axes = (np.linspace(0, H - 1, 33), np.linspace(0, W - 1, 33))  # a 33 x 33 grid over the whole image
        report["camera"] = {
            "calibration": cam_cal.to_metadata(),
            "within_3_sigma": _camera_honesty(cam_cal, true.camera, nominal.camera),
            "ray_errors_calibrated": ray_errors(cam_cal.camera, true.camera, *axes),
            "ray_errors_nominal": ray_errors(nominal.camera, true.camera, *axes),
        }
        say("camera", 1, 1)
        # -- the fibers, from the mirror sphere ----------------------------------------------------------
        cam_rig = cam_cal.apply(nominal)
        stacks = render_sphere_scans(true, sphere_centers, radius=radius, alpha=CALIBRATION_SPHERE_ALPHA, spp=spp,
                                     seed=seed, variant=variant, progress=progress)
        (tmp / "spheres").mkdir()
        sphere_obs = []
        for i, (stack, c) in enumerate(zip(stacks, sphere_centers)):
            folder = tmp / "spheres" / f"sphere_{i:02d}"
            folder.mkdir()
            user = _as_nominal(stack, nominal, perturbation)
            save_stack(user, folder / "stack.exr")
            placement = SpherePlacement(center=tuple(float(v) for v in c), radius=radius)
            sphere_obs.append(observe_sphere(user.__class__(user.frames, cam_rig, 0, user.provenance), placement,
                                             name=f"spheres/sphere_{i:02d}"))
        write_json(tmp / "spheres" / "spheres.json", {
            "radius_mm": radius,
            "scans": [{"folder": f"sphere_{i:02d}", "center_mm": list(c)} for i, c in enumerate(sphere_centers)]})
        src_cal = calibrate_sources(sphere_obs, cam_cal.camera, nominal=cam_rig)
        calibrated = src_cal.apply(cam_rig)
        calibrated.save(tmp / "calibrated_rig.json")
        report["sources"] = _source_report(src_cal, nominal, true)
        say("sources", 1, 1)
        # -- what it buys: the sphere scan with each rig ------------------------------------------------
        sim = Simulator(true, scene_objects("sphere", alpha=0.02), variant=variant)
        truth = sim.render_truth()
        stack = sim.render_stack(spp=scan_spp, seed=derive_seed(seed, "scan"))
        (tmp / "scan").mkdir()
        save_stack(_as_nominal(stack, nominal, perturbation), tmp / "scan" / "stack.exr")
        save_truth(truth, tmp / "scan" / "truth.exr")
        report["normal_error_deg"] = _normal_scores(stack, truth, {"nominal": nominal, "calibrated": calibrated,
                                                                   "true": true}, radius)
        say("scan", 1, 1)
        if fig6:
            report["fig6"] = _fig6_check(nominal, radius=radius, alpha=0.02, spp=scan_spp, seed=seed,
                                         variant=variant)
            say("fig6", 1, 1)
        report["targets"] = _targets(report)
        write_json(tmp / "calibration_report.json", report)
        if plot:
            from ..plot.calibration import calibration_figure

            fig = calibration_figure(report)
            write_file(tmp / "calibration.png", lambda f: fig.savefig(f, dpi=110, format="png"))
    return json_safe(report)


def _camera_honesty(cal, true_camera, nominal_camera):
    """Each estimated camera parameter's error in units of its sigma (the covariance's honesty)."""
    from ..calibrate.camera import camera_parameters

    truth = camera_parameters(true_camera, nominal_camera)
    z = {n: (cal.parameters[n] - truth[n]) / cal.sigma[n] for n in cal.names if cal.sigma[n] > 0}
    values = np.abs(np.array(list(z.values())))
    return {"z": z, "true": {n: truth[n] for n in cal.names}, "n": int(values.size),
            "fraction": float(np.mean(values <= 3)) if values.size else None}


def _source_report(cal, nominal, true):
    """Per-fiber errors of the calibrated and the nominal rig against the true one, with the uncertainties."""
    from ..evaluate import angular_error_deg

    ref = np.asarray(cal.reference_point, float)
    d_true = true.source_positions - ref  # directions from the working volume (normalised by the error's measure)
    err_cal = angular_error_deg(cal.directions, d_true)
    err_nom = angular_error_deg(nominal.source_positions - ref, d_true)
    solved = np.all(np.isfinite(cal.positions), axis=1)
    pos_err = np.linalg.norm(cal.positions - true.source_positions, axis=1)
    # honesty: each position coordinate's error in units of its sigma
    sig = np.sqrt(np.diagonal(cal.position_cov[solved], axis1=1, axis2=2))
    z = ((cal.positions[solved] - true.source_positions[solved]) / sig).ravel()
    return {
        "calibration": cal.to_metadata(),
        "per_source_nominal": err_nom.tolist(),
        "direction_error_deg": {"calibrated_rms": float(np.sqrt(np.mean(err_cal**2))),
                                "calibrated_max": float(err_cal.max()),
                                "nominal_rms": float(np.sqrt(np.mean(err_nom**2))),
                                "nominal_max": float(err_nom.max()),
                                "per_source_calibrated": err_cal.tolist(),
                                "per_source_sigma": np.asarray(cal.direction_sigma_deg).tolist()},
        "position_error_mm": {"median": float(np.median(pos_err[solved])) if solved.any() else None,
                              "max": float(pos_err[solved].max()) if solved.any() else None,
                              "per_source": pos_err.tolist()},
        "within_3_sigma": {"fraction": float(np.mean(np.abs(z) <= 3)) if z.size else None, "n": int(z.size),
                           "z_rms": float(np.sqrt(np.mean(z**2))) if z.size else None},
        "radius_mm": {"estimated": np.asarray(cal.radius_mm).tolist(), "true": true.source_radii.tolist(),
                      "sigma": np.asarray(cal.radius_sigma_mm).tolist()},
    }


def _targets(report):
    """The issue's targets, each with the measured value and whether it is met."""
    cam = report["camera"]["ray_errors_calibrated"]
    src = report["sources"]["direction_error_deg"]
    nerr = report["normal_error_deg"]
    model = "near-field" if "near-field" in nerr["true"] else "perspective"
    gap = nerr["calibrated"][model]["median_deg"] - nerr["true"][model]["median_deg"]
    cz, sz = report["camera"]["within_3_sigma"], report["sources"]["within_3_sigma"]
    n = cz["n"] + sz["n"]
    inside = (cz["fraction"] or 0) * cz["n"] + (sz["fraction"] or 0) * sz["n"]
    rows = {
        "fiber_direction_rms_deg": (src["calibrated_rms"], 0.01),
        "ray_position_max_um": (cam["position_max_um"], 1.0),
        "ray_angle_max_deg": (cam["angle_max_deg"], 0.02),
        f"normal_median_gap_to_true_rig_deg ({model})": (gap, 0.01),
    }
    out = {k: {"measured": v, "target": t, "met": bool(v <= t)} for k, (v, t) in rows.items()}
    frac = inside / n if n else float("nan")
    out["parameters_within_3_sigma"] = {"measured": frac, "target": 0.95, "met": bool(frac >= 0.95), "n": n}
    return out


def summary_lines(report: dict[str, Any]) -> list[str]:
    """A few lines for the terminal."""
    lines = []
    for name, row in report["targets"].items():
        sign = ">=" if name == "parameters_within_3_sigma" else "<="
        lines.append(f"{name}: {row['measured']:.4g} (target {sign} {row['target']:g}) "
                     f"{'met' if row['met'] else 'NOT met'}")
    for rig in ("nominal", "calibrated", "true"):
        per = report["normal_error_deg"][rig]
        lines.append(f"sphere scan with the {rig} rig: " + ", ".join(
            f"{m} median {s['median_deg']:.4f} deg" for m, s in per.items() if s.get("median_deg") is not None))
    return lines
