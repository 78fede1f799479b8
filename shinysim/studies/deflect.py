"""Display deflectometry from files: a SOFAST fixed-pattern measurement to slopes, a score and a figure.

``shinysim deflect --sofast DIR --out OUT`` runs :func:`run_sofast_fixed`:
the files of ``DIR`` (SOFAST's layout or one flat folder;
:func:`shinysim.io.sofast.read_sofast_folder`) are read, the facet is measured
from its one frame (:func:`shinysim.recon.deflect.measure_facet`), and, where
SOFAST's own result is there, the slopes are scored against it at matched dots
(:func:`shinysim.evaluate.deflect.compare_slopes`).

What it writes (``docs/deflectometry.md`` says more):

* ``slopes.csv``: ``x_m,y_m,z_m,slope_x,slope_y``, one row per identified dot:
  where its camera ray meets the fitted surface and the slopes dz/dx, dz/dy
  there, in the facet frame (metres, radians), under the alignment asked for
  (SOFAST's centre alignment by default);
* ``slopes.npz``: the same in millimetres with each dot's pixel, grid index,
  the pose and the fitted surface;
* ``score.json``: ``dots_found``, ``dots_identified`` (and the dots left out,
  by reason), ``focal_lengths_m`` [fx, fy], the pose, and ``vs_expected``
  (``matched``, ``rms_mrad``, ``p95_mrad``, ``max_mrad``, ``n_over_1mrad``,
  ``detilted``: the same after removing constant + linear terms) when an
  expected result is given;
* ``deflect.png``: the slope maps, SOFAST's, and their difference, captioned.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._shared import json_safe, output_folder, write_bytes, write_file, write_json, write_text
from ..errors import OptionError
from ..evaluate.deflect import compare_matched, compare_slopes, detilt, match_points
from ..recon.deflect import SlopeParams, measure_facet, rotation_vector
from ..recon.dots import DotParams

__all__ = ["DEFLECT_OUTPUTS", "DeflectResult", "FILE_ROLES", "FRINGE_MESH_TOLERANCE_MM", "FRINGE_OUTPUTS",
           "FRINGE_TWIN_OUTPUTS", "FacetResult", "FringeResult", "NOISE_TABLE_CODES", "SOFAST_RIG",
           "TWIN_DISPLAY_PIXELS", "TWIN_OUTPUTS", "fringe_noise_table", "measure_fringe_twin",
           "measure_sofast_fixed", "measure_sofast_fringe", "measure_twin", "reconstructed_setup",
           "render_fringe_twin", "render_twin", "run_fringe_twin", "run_render_facet", "run_sofast_fixed",
           "run_sofast_fringe", "run_twin", "screen_points_csv", "slopes_csv", "sofast_geometry", "twin_facet"]

#: The files ``run_sofast_fixed`` writes.
DEFLECT_OUTPUTS = ("slopes.csv", "slopes.npz", "score.json", "deflect.png")


@dataclass(frozen=True)
class FacetResult:
    """One facet of a reconstructed measurement.

    Attributes
    ----------
    measurement : FacetMeasurement
        Its dots, pose and slopes (in its own frame).
    rotation, position_mm :
        Where it sits in the measured optic's frame (an ensemble's; identity
        and zero for a single facet): ``x_optic = rotation @ x_facet + position_mm``.
    expected : FacetResult of shinysim.io.sofast or None
        SOFAST's own result for it, when given.
    pairs : ((n,) bool, (n,) int) or None
        Which of its dots matched a point of ``expected``, and which.
    """

    measurement: object
    rotation: np.ndarray
    position_mm: np.ndarray
    expected: object = None
    pairs: tuple | None = None


@dataclass(frozen=True)
class DeflectResult:
    """A fixed-pattern measurement reconstructed (:func:`measure_sofast_fixed`).

    Attributes
    ----------
    facets : tuple of FacetResult
        One for a single facet, one per facet of an ensemble.
    score : dict
        What ``score.json`` holds.
    ensemble : EnsembleMeasurement or None
    """

    facets: tuple
    score: dict
    ensemble: object = None

    @property
    def measurement(self):
        """The (first) facet's :class:`~shinysim.recon.deflect.FacetMeasurement`."""
        return self.facets[0].measurement

    @property
    def expected(self):
        return self.facets[0].expected

    @property
    def pairs(self):
        return self.facets[0].pairs


def _surface_params(calc, align, facet=0):
    """The slope solver's settings as the reference calculation ran it (its ``ParamsSurface``), or None.

    Comparing with a tool's result is a comparison at that tool's settings: its first focal lengths, the
    rays it fitted the surface to (``downsample``) and its robust fit.
    """
    if calc is None:
        return None
    key = f"optic_definition/facet_{facet:03d}/ParamsSurface/"
    prm = calc.params
    if prm.get(key + "surface_type", "parabolic") != "parabolic":
        raise OptionError(f"the reference fitted a {prm.get(key + 'surface_type')!r} surface; shinysim fits a "
                          "paraboloid")
    f0 = prm.get(key + "initial_focal_lengths_xy")
    return SlopeParams(align=align,
                       initial_focal_mm=(150e3, 150e3) if f0 is None else tuple(1e3 * float(v) for v in f0),
                       downsample=int(prm.get(key + "downsample", 1)),
                       robust=bool(prm.get(key + "robust_least_squares", False)))


def _focal_fit(points_mm, slopes):
    """Focal lengths (mm) of the paraboloid whose slopes best fit ``slopes`` (SOFAST's linear slope model)."""
    design = np.column_stack([np.ones(len(points_mm)), points_mm[:, 0], points_mm[:, 1]])
    sx = np.linalg.lstsq(design, slopes[:, 0], rcond=None)[0]
    sy = np.linalg.lstsq(design, slopes[:, 1], rcond=None)[0]
    with np.errstate(divide="ignore"):
        return np.array([1 / (2 * sx[1]), 1 / (2 * sy[2])])


#: The files a measurement needs, by role: what the role is called on the command line, and what it is.
FILE_ROLES = {
    "fixed_measurement": ("--measurement", "a fixed-pattern measurement (measurement_facet.h5)"),
    "dot_locations": ("--dots", "the dot locations (fixed_pattern_dot_locations.h5)"),
    "camera": ("--camera", "the camera (camera_sofast.h5)"),
    "spatial_orientation": ("--orientation", "the camera-screen orientation (spatial_orientation.h5)"),
    "facet_definition": ("--facet", "the facet definition (Facet_*.json)"),
    "ensemble_definition": ("--ensemble", "the facet-ensemble definition (Ensemble_*.json)"),
    "fixed_calculation": ("--expected", "SOFAST's calculation file (calculation_*.h5)"),
    "fringe_measurement": ("--measurement", "a fringe measurement (measurement_facet.h5 with fringe_images)"),
    "fringe_camera": ("--camera", "the fringe measurement's camera (camera_sofast_downsampled.h5)"),
    "image_calibration": ("--calibration", "the display's response (image_calibration.h5)"),
    "display_shape": ("--display", "the display's shape (display_*.h5)"),
    "fringe_calculation": ("--expected", "SOFAST's fringe calculation file (expected_data.h5)"),
}


def _resolve(folder, given):
    """The path of every role: given, else found in ``folder``, else in a ``common/`` beside it (OpenCSP's
    layout, for a folder such as ``sofast/fringe``); an ambiguous role that is needed is named."""
    from ..io import sofast

    found = sofast.read_sofast_folder(folder) if folder is not None else None
    beside = None
    if folder is not None and (Path(folder).parent / "common").is_dir() and Path(folder).name != "common":
        beside = sofast.read_sofast_folder(Path(folder).parent / "common")
    paths = {}
    for role in FILE_ROLES:
        if given.get(role) is not None:
            paths[role] = Path(given[role])
        else:
            paths[role] = next((getattr(f, role) for f in (found, beside)
                                if f is not None and getattr(f, role) is not None), None)
    ambiguous = {} if found is None else {r: v for r, v in found.ambiguous.items() if given.get(r) is None}
    return paths, ambiguous


def _need(paths, ambiguous, roles, folder):
    missing = []
    for role in roles:
        if paths[role] is not None:
            continue
        option, what = FILE_ROLES[role]
        if role in ambiguous:
            raise OptionError(f"{folder}: {len(ambiguous[role])} files could be {what}: "
                              f"{', '.join(p.name for p in ambiguous[role])}; name one with {option}")
        missing.append(f"{what} (or {option})")
    if missing:
        raise OptionError(f"{folder or 'no --sofast folder'}: no {', no '.join(missing)}")


def measure_sofast_fixed(folder=None, *, files: dict | None = None, expected=None, known_dots=None,
                         align: str = "centre", dot_params: DotParams | None = None,
                         slope_params: SlopeParams | None = None) -> DeflectResult:
    """Slopes of the facet (or facets) of a SOFAST fixed-pattern measurement, scored against SOFAST's result.

    Parameters
    ----------
    folder : path, optional
        SOFAST's files (:func:`~shinysim.io.sofast.read_sofast_folder`).
    files : dict, optional
        Paths by role (the keys of :data:`FILE_ROLES`), over what the folder
        holds: a measurement, its dot locations, the camera, the camera-screen
        orientation and the facet definition are needed; an ensemble
        definition for an ensemble.
    expected : path, False or None
        SOFAST's calculation file to score against; None: the folder's, if
        it has one; False: none.
    known_dots : sequence of (x_px, y_px, ix, iy), optional
        For each facet, the image position (x = column, y = row, SOFAST's
        order) of one of its dots and that dot's grid index. Default for a
        single facet: the measurement's ``origin`` and index (0, 0). More than
        one makes the measurement an ensemble's (an ensemble definition is
        then needed, with as many facets).
    align : {"centre", "none"}
        See :data:`shinysim.recon.deflect.ALIGNMENTS`.

    Returns
    -------
    DeflectResult
    """
    from ..io import sofast
    from ..recon.deflect import measure_ensemble
    from ..rig.opencv import camera_from_opencv

    t0 = time.perf_counter()
    given = dict(files or {})
    if expected not in (None, False):
        given["fixed_calculation"] = expected
    paths, ambiguous = _resolve(folder, given)
    ensemble_mode = known_dots is not None and len(known_dots) > 1 or given.get("ensemble_definition") is not None
    roles = ["fixed_measurement", "dot_locations", "camera", "spatial_orientation", "facet_definition"]
    _need(paths, ambiguous, roles + (["ensemble_definition"] if ensemble_mode else []), folder)
    meas = sofast.read_fixed_measurement(paths["fixed_measurement"])
    dots = sofast.read_dot_locations(paths["dot_locations"])
    cam_file = sofast.read_camera(paths["camera"])
    orient = sofast.read_spatial_orientation(paths["spatial_orientation"])
    facet = sofast.read_facet_definition(paths["facet_definition"])
    height, width = meas.image.shape
    if tuple(cam_file.image_size) != (width, height):
        raise OptionError(f"{paths['camera']}: the camera's image is {cam_file.image_size[0]} x "
                          f"{cam_file.image_size[1]} but the measurement's is {width} x {height}")
    if len(facet.corners_mm) != 4:
        raise OptionError(f"{paths['facet_definition']}: the facet has {len(facet.corners_mm)} corners; "
                          "shinysim poses four-cornered facets")
    camera = camera_from_opencv(cam_file.matrix, cam_file.distortion, cam_file.image_size, name=cam_file.name)

    def dot_position(ix, iy):
        return orient.screen_to_camera(dots.position_mm(ix, iy))

    screen_origin = orient.screen_to_camera(np.zeros(3))
    source = paths["fixed_calculation"] if expected is not False else None
    calc = sofast.read_calculation(source) if source is not None else None
    if calc is not None and getattr(calc, "kind", "fixed") == "fringe":
        raise OptionError(f"{source}: is SOFAST's result of a fringe measurement; this is a fixed-pattern one "
                          "(give its own calculation file, or --no-expected)")
    # compared with SOFAST's result, at SOFAST's own surface-fit settings (its ParamsSurface)
    sp = slope_params if slope_params is not None else (_surface_params(calc, align) or SlopeParams(align=align))
    if known_dots is None:
        known = [((float(meas.origin_px[1]), float(meas.origin_px[0])), (0, 0))]
    else:
        known = [((float(y), float(x)), (int(ix), int(iy))) for x, y, ix, iy in known_dots]
    ens = None
    if ensemble_mode:
        ensemble = sofast.read_ensemble_definition(paths["ensemble_definition"])
        n = len(ensemble.facet_positions_mm)
        if len(known) != n:
            raise OptionError(f"{paths['ensemble_definition']}: the ensemble has {n} facets; give one known dot "
                              f"for each (--known-dot X Y IX IY, {n} times), got {len(known)}")
        from ..recon.deflect import rotation_matrix

        rotations = np.array([rotation_matrix(r) for r in ensemble.facet_rotations])
        ens = measure_ensemble(meas.image, camera, dot_position=dot_position, screen_origin_mm=screen_origin,
                               distance_mm=meas.dist_optic_screen_mm, corners_mm=[facet.corners_mm] * n,
                               centroids_mm=[facet.centroid_mm] * n, facet_positions_mm=ensemble.facet_positions_mm,
                               facet_rotations=rotations, origins=known, ensemble_centroid_mm=ensemble.centroid_mm,
                               measure_point_mm=meas.measure_point_mm, dot_params=dot_params, slope_params=sp)
        placed = list(zip(ens.facets, rotations, ensemble.facet_positions_mm))
    else:
        if len(known) != 1:
            raise OptionError(f"a single facet takes one known dot, got {len(known)}")
        m = measure_facet(meas.image, camera, dot_position=dot_position, screen_origin_mm=screen_origin,
                          origin_rc=known[0][0], origin_index=known[0][1], distance_mm=meas.dist_optic_screen_mm,
                          corners_mm=facet.corners_mm, centroid_mm=facet.centroid_mm,
                          measure_point_mm=meas.measure_point_mm, dot_params=dot_params, slope_params=sp)
        placed = [(m, np.eye(3), np.zeros(3))]
    refs = [None] * len(placed)
    if calc is not None:
        if len(calc.facets) != len(placed):
            raise OptionError(f"{source}: holds {len(calc.facets)} facets; the measurement has {len(placed)}")
        refs = list(calc.facets)
    facets, per_facet = [], []
    for k, ((m, rot, pos), ref) in enumerate(zip(placed, refs)):
        sol = m.solution
        entry = {**m.counts, "focal_lengths_m": (sol.focal_lengths_mm / 1e3).tolist(),
                 "corners_rc": None if m.corners_rc is None else m.corners_rc.tolist(),
                 "side_rms_px": None if m.side_rms_px is None else m.side_rms_px.tolist(),
                 "alignment_turn_mrad": float(np.linalg.norm(rotation_vector(sol.alignment)) * 1e3)}
        pairs = None
        if ref is not None:
            vs = compare_slopes(sol.points_mm, sol.slopes, ref.surface_points_mm, ref.slopes)
            vs["expected_points"] = len(ref.slopes)
            ref_focal = _focal_fit(ref.surface_points_mm, ref.slopes)
            vs["expected_focal_lengths_m"] = (ref_focal / 1e3).tolist()
            vs["focal_length_ratio"] = (sol.focal_lengths_mm / ref_focal).tolist()
            hit, nearest, _ = match_points(sol.points_mm, ref.surface_points_mm, vs["match_mm"])
            pairs = (hit, nearest)
            entry["vs_expected"] = vs
        if ens is not None:
            entry["pointing_mrad"] = ens.pointing_mrad[k].tolist()
        facets.append(FacetResult(measurement=m, rotation=np.asarray(rot), position_mm=np.asarray(pos),
                                  expected=ref, pairs=pairs))
        per_facet.append(entry)
    first = placed[0][0]
    R, t, rms = ((ens.rotation, ens.translation_mm, ens.pose_rms_px) if ens is not None
                 else (first.rotation, first.translation_mm, first.pose_rms_px))
    count_keys = ("dots_detected", "dots_cut", "dots_found")
    score = {
        "measurement": {"name": meas.name, "date": meas.date, "image": [width, height],
                        "dist_optic_screen_m": meas.dist_optic_screen_mm / 1e3},
        "optic": "ensemble" if ens is not None else "facet",
        # the frame's dots (counted once) and those identified on the facets
        **{k: per_facet[0][k] for k in count_keys},
        **{k: int(sum(e[k] for e in per_facet)) for k in ("dots_identified", "ambiguous", "inconsistent",
                                                            "left_out")},
        "unreached": per_facet[0]["unreached"] if ens is None else None,
        "focal_lengths_m": per_facet[0]["focal_lengths_m"] if ens is None else
        np.mean([e["focal_lengths_m"] for e in per_facet], axis=0).tolist(),
        "alignment": sp.align,
        "surface_fit": {"initial_focal_m": [f / 1e3 for f in sp.initial_focal_mm], "downsample": sp.downsample,
                        "robust": sp.robust, "from": "given" if slope_params is not None else
                        "the reference's settings" if calc is not None else "defaults"},
        "pose": {"corner_reprojection_rms_px": rms, "optic_origin_camera_m": (t / 1e3).tolist(),
                 "rvec_optic_to_camera": rotation_vector(R).tolist(),
                 **({"corners_rc": per_facet[0]["corners_rc"], "side_rms_px": per_facet[0]["side_rms_px"],
                     "alignment_turn_mrad": per_facet[0]["alignment_turn_mrad"]} if ens is None else {})},
        "dot_pitch_px": first.index.pitch_px,
        "facet_corners_mm": np.asarray(facet.corners_mm).tolist(),
        "files": {k: None if v is None else str(v) for k, v in paths.items()},
    }
    if ens is not None:
        score["facets"] = per_facet
    if source is not None:
        if ens is None:
            vs = per_facet[0]["vs_expected"]
        else:  # the facets' matched differences pooled
            diffs, pts = [], []
            for f in facets:
                hit, j = f.pairs
                sol = f.measurement.solution
                diffs.append(sol.slopes[hit] - f.expected.slopes[j[hit]])
                pts.append(sol.points_mm[hit])
            from ..evaluate.deflect import slope_stats

            d = np.concatenate(diffs)
            vs = {"matched": int(len(d)), **slope_stats(d),
                  "detilted": slope_stats(np.concatenate([detilt(p, q) for p, q in zip(pts, diffs)])),
                  "expected_points": int(sum(len(f.expected.slopes) for f in facets))}
        vs = {**vs, "file": str(source)}
        score["vs_expected"] = vs
    score["seconds"] = time.perf_counter() - t0
    return DeflectResult(facets=tuple(facets), score=json_safe(score), ensemble=ens)


def slopes_csv(points_mm, slopes) -> str:
    """The ``slopes.csv`` text: ``x_m,y_m,z_m,slope_x,slope_y``, one row per point (metres, radians)."""
    rows = ["x_m,y_m,z_m,slope_x,slope_y"]
    for (x, y, z), (sx, sy) in zip(np.asarray(points_mm) / 1e3, np.asarray(slopes)):
        rows.append(f"{x:.9g},{y:.9g},{z:.9g},{sx:.9g},{sy:.9g}")
    return "\n".join(rows) + "\n"


def screen_points_csv(rows, cols, fraction) -> str:
    """The ``screen_points.csv`` text: ``row,col,screen_x,screen_y``, each decoded pixel's screen fractions."""
    lines = ["row,col,screen_x,screen_y"] + [f"{r},{c},{x:.10g},{y:.10g}" for r, c, (x, y) in zip(rows, cols, fraction)]
    return "\n".join(lines) + "\n"


def run_sofast_fixed(folder, out, *, files: dict | None = None, expected=None, known_dots=None,
                     align: str = "centre", overwrite: bool = False, plot: bool = True,
                     dot_params: DotParams | None = None) -> DeflectResult:
    """:func:`measure_sofast_fixed`, written to ``out`` (:data:`DEFLECT_OUTPUTS`; nothing outside it).

    An ensemble's facets are written one after another (``slopes.csv``'s
    rows facet by facet, each in its own facet frame; ``slopes.npz``'s
    ``facet`` says which row is whose).
    """
    import importlib.util

    names = [n for n in DEFLECT_OUTPUTS if plot or n != "deflect.png"]
    if plot and importlib.util.find_spec("matplotlib") is None:
        raise OptionError("deflect.png needs matplotlib (pip install 'shinysim[plot]'), or pass --no-plot")
    with output_folder(out, names, overwrite=overwrite, last="score.json") as tmp:
        tmp = Path(tmp)
        result = measure_sofast_fixed(folder, files=files, expected=expected, known_dots=known_dots, align=align,
                                      dot_params=dot_params)
        sols = [f.measurement.solution for f in result.facets]
        points = np.concatenate([s_.points_mm for s_ in sols])
        slopes = np.concatenate([s_.slopes for s_ in sols])
        write_text(tmp / "slopes.csv", slopes_csv(points, slopes))
        arrays = {"points_mm": points, "slopes": slopes,
                  "facet": np.concatenate([np.full(len(s_.slopes), k) for k, s_ in enumerate(sols)])}
        for key in ("row", "col"):
            arrays[key] = np.concatenate([f.measurement.dots[key][f.measurement.used] for f in result.facets])
        arrays["index"] = np.concatenate([f.measurement.index.index[f.measurement.used] for f in result.facets])
        for key, get in (("coefs", lambda f: f.measurement.solution.coefs),
                         ("focal_lengths_mm", lambda f: f.measurement.solution.focal_lengths_mm),
                         ("rotation", lambda f: f.measurement.rotation),
                         ("translation_mm", lambda f: f.measurement.translation_mm),
                         ("alignment", lambda f: f.measurement.solution.alignment),
                         ("camera_mm", lambda f: f.measurement.solution.camera_mm)):
            stacked = np.stack([get(f) for f in result.facets])
            arrays[key] = stacked[0] if len(result.facets) == 1 else stacked

        def npz(f):
            with open(f, "wb") as fh:  # a file object: np.savez given a name adds ".npz" to it
                np.savez(fh, **arrays)

        write_file(tmp / "slopes.npz", npz)
        if plot:
            from ..plot.deflect import deflect_figure

            write_bytes(tmp / "deflect.png", deflect_figure(result))
        write_json(tmp / "score.json", result.score)
    return result


# -- the simulated twin ------------------------------------------------------------------------------------------

#: SOFAST's fixed-pattern rig as OpenCSP's files give it (``../shared/data/sofast``), for the twin where the files
#: are absent: the camera (OpenCV's matrix entries, distortion, image size), the camera-screen orientation
#: (``r_cam_screen``, ``v_cam_screen_cam`` in mm) and an 85 x 85 grid of dots at the measured table's mean pitch.
SOFAST_RIG = {
    "matrix": ((5492.06431, 0.0, 812.5), (0.0, 5486.27060, 617.5), (0.0, 0.0, 1.0)),
    "distortion": (-0.144160743, 1.60974438, 2.50349816e-05, -1.89904226e-03, 0.0),
    "image_size": (1626, 1236),
    "r_cam_screen": (-0.03629624, 0.35523602, -0.01208407),
    "v_cam_screen_cam_mm": (4451.83834, 57.10465, 368.3293),
    "n_dots": 85,
    "pitch_mm": 40.0,
}


def sofast_geometry(folder=None):
    """The camera, screen pose and dots of SOFAST's rig: from its files when ``folder`` holds them, else
    :data:`SOFAST_RIG`.

    Returns
    -------
    camera : Camera
        In its own frame.
    screen_rotation : (3, 3), screen_origin_mm : (3,)
        ``x_cam = screen_origin_mm + screen_rotation @ p_screen``.
    dots_mm : (ny, nx, 3), x_index : (nx,), y_index : (ny,)
    source : str
        ``"files"`` or ``"built-in"``.
    """
    from ..recon.deflect import rotation_matrix
    from ..rig.opencv import camera_from_opencv

    files = None
    if folder is not None:
        from ..io import sofast

        found = sofast.read_sofast_folder(folder)
        if all(getattr(found, r) is not None for r in ("camera", "spatial_orientation", "dot_locations")):
            files = found
    if files is not None:
        cam = sofast.read_camera(files.camera)
        orient = sofast.read_spatial_orientation(files.spatial_orientation)
        dots = sofast.read_dot_locations(files.dot_locations)
        camera = camera_from_opencv(cam.matrix, cam.distortion, cam.image_size, name=cam.name)
        rot = rotation_matrix(orient.r_cam_screen).T
        return camera, rot, np.asarray(orient.v_cam_screen_cam_mm, float), dots.xyz_mm, dots.x_index, \
            dots.y_index, "files"
    r = SOFAST_RIG
    camera = camera_from_opencv(np.array(r["matrix"]), r["distortion"], r["image_size"], name="SOFAST-like camera")
    n = r["n_dots"]
    idx = np.arange(n) - n // 2
    gx, gy = np.meshgrid(idx * r["pitch_mm"], idx * r["pitch_mm"])
    dots = np.stack([gx, gy, np.zeros_like(gx)], axis=-1)
    return camera, rotation_matrix(r["r_cam_screen"]).T, np.array(r["v_cam_screen_cam_mm"]), dots, idx, idx, \
        "built-in"


def twin_facet(size: str = "small"):
    """The twin's mirror: ``"full"`` the 1.212 m NSTTF facet of :func:`~shinysim.sim.display.sofast_facet`;
    ``"small"`` a 240 mm square cut of the same paraboloid with a shorter ripple (0.02 mm, period 150 mm: 0.84
    mrad of slope), small enough to render in seconds."""
    from ..objects.mirror import MirrorFacet

    if size == "full":
        from ..sim.display import sofast_facet

        return sofast_facet()
    if size != "small":
        raise OptionError(f"twin size must be 'small' or 'full', got {size!r}")
    return MirrorFacet(120.0, 120.0, focal_mm=(-136e3, -146e3), ripple_mm=0.02, ripple_period_mm=150.0,
                       ripple_angle_rad=0.5)


def _twin_setup(folder, size, margin_px):
    """SOFAST's rig (:func:`sofast_geometry`) with :func:`twin_facet`, and the window (rows, cols slices) that
    holds the facet's image with ``margin_px`` around it; also where the geometry came from."""
    from ..sim.display import sofast_like_setup

    camera, rot, origin, dots, xi, yi, source = sofast_geometry(folder)
    setup = sofast_like_setup(camera, rot, origin, dots, xi, yi, facet=twin_facet(size))
    r, c = camera.project(setup.facet_to_camera(setup.facet.corners_mm()))
    rows = slice(max(0, int(np.floor(r.min())) - margin_px), min(camera.height, int(np.ceil(r.max())) + margin_px + 1))
    cols = slice(max(0, int(np.floor(c.min())) - margin_px), min(camera.width, int(np.ceil(c.max())) + margin_px + 1))
    return setup, rows, cols, source


def render_twin(*, folder=None, size: str = "small", spp: int = 64, seed: int = 0, margin_px: int = 12,
                variant: str | None = None):
    """The twin's frame: SOFAST's rig (:func:`sofast_geometry`) with :func:`twin_facet`, rendered over the
    window that holds the facet's image and ``margin_px`` around it (Mitsuba;
    :func:`shinysim.sim.display.render_display_frame`)."""
    from ..sim.display import render_display_frame

    setup, rows, cols, source = _twin_setup(folder, size, margin_px)
    frame = render_display_frame(setup, spp=spp, seed=seed, rows=rows, cols=cols, variant=variant)
    return frame, source


def measure_twin(frame, *, pose: str = "given", dot_params: DotParams | None = None) -> dict:
    """The twin's frame reconstructed and scored against its exact truth.

    Parameters
    ----------
    frame : DisplayFrame
    pose : {"given", "corners"}
        ``"given"``: the facet's true pose, no alignment (the slopes are
        then absolute); ``"corners"``: the pose from the facet's corners and
        SOFAST's centre alignment, as for a real measurement (the slopes are
        then compared with constant + linear terms removed).

    Returns
    -------
    dict
        ``identification`` (``identified``, ``correct``: the dot at its
        assigned index's exact reflected position, within half a pitch;
        ``wrong``; ``visible``: complete dots whose exact reflection is in the
        image), ``centroid_px`` (distance of each identified dot to its exact
        reflected position: RMS, max), ``slopes`` (against the exact slopes
        at the reconstructed points: ``rms_mrad`` ... and ``detilted``),
        ``focal_lengths_m`` (fitted, and the true facet's), and
        ``_measurement`` (the :class:`~shinysim.recon.deflect.FacetMeasurement`; not JSON).
    """
    from ..evaluate.deflect import detilt as _detilt
    from ..evaluate.deflect import slope_stats

    check = ("given", "corners")
    if pose not in check:
        raise OptionError(f"pose must be one of {check}, got {pose!r}")
    setup = frame.setup
    facet = setup.facet
    disp = setup.display
    xi, yi = np.asarray(disp.x_index), np.asarray(disp.y_index)

    s0 = np.asarray(setup.screen_origin_mm, float)
    centre_cam = setup.facet_to_camera(np.zeros(3))
    distance = float(np.linalg.norm(centre_cam - s0))
    kwargs = dict(dot_position=setup.dot_position, screen_origin_mm=s0, origin_rc=frame.origin_rc, distance_mm=distance,
                  dot_params=dot_params)
    if pose == "given":
        m = measure_facet(frame.image, setup.camera, pose=(setup.facet_rotation, setup.facet_origin_mm),
                          slope_params=SlopeParams(align="none"), **kwargs)
    else:
        m = measure_facet(frame.image, setup.camera, corners_mm=facet.corners_mm(),
                          slope_params=SlopeParams(align="centre"), **kwargs)
    sol = m.solution
    ref = frame.reflected
    idx = m.index.index[m.used]
    a = idx[:, 1] - yi[0]
    b = idx[:, 0] - xi[0]
    exact = np.column_stack([ref.row[a, b], ref.col[a, b]])
    seen = np.column_stack([m.dots["row"][m.used], m.dots["col"][m.used]])
    off = np.linalg.norm(seen - exact, axis=1)
    correct = np.isfinite(off) & (off < 0.5 * m.index.pitch_px)
    truth = facet.slopes(sol.points_mm[:, 0], sol.points_mm[:, 1])
    diff = sol.slopes - truth
    good = ~(m.dots["cut"])
    visible = int(np.sum(ref.visible))
    return {
        "pose": pose,
        "identification": {"identified": int(m.used.sum()), "correct": int(correct.sum()),
                           "wrong": int((~correct).sum()), "visible_reflections": visible,
                           "dots_found": int(good.sum()), "ambiguous": m.index.n_ambiguous,
                           "inconsistent": m.index.n_inconsistent},
        "centroid_px": {"rms": float(np.sqrt(np.mean(off[correct] ** 2))) if correct.any() else None,
                        "max": float(off[correct].max()) if correct.any() else None},
        "slopes": {**slope_stats(diff), "detilted": slope_stats(_detilt(sol.points_mm, diff))},
        "focal_lengths_m": (sol.focal_lengths_mm / 1e3).tolist(),
        "true_focal_lengths_m": [float(f) / 1e3 for f in facet.focal_mm],
        "alignment_turn_mrad": float(np.linalg.norm(rotation_vector(sol.alignment)) * 1e3),
        "_measurement": m,
    }


def _rigid_fit(a, b):
    """The rotation R and shift t with ``b = a R^T + t`` best in least squares (Kabsch)."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    R = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return R, cb - R @ ca


def reconstructed_setup(result, folder):
    """The twin of a real measurement's reconstruction: SOFAST's rig with the fitted paraboloid where it was found.

    The facet's pose is the rigid map between the dots' surface points in the (aligned) facet frame and the same
    points in the camera frame (along each dot's camera ray, at its distance from the camera); the facet is
    the fitted paraboloid's focal lengths (its small cross term ``c4`` is left out), the size of the
    facet definition's corners. One facet only.
    """
    from ..objects.mirror import MirrorFacet
    from ..recon.deflect import camera_rays
    from ..sim.display import sofast_like_setup

    if len(result.facets) != 1:
        raise OptionError("a render of the reconstruction is offered for a single facet")
    m = result.measurement
    sol = m.solution
    camera, rot, origin, dots, xi, yi, _ = sofast_geometry(folder)
    rays = camera_rays(camera, m.dots["row"][m.used], m.dots["col"][m.used])
    dist = np.linalg.norm(sol.points_mm - sol.camera_mm, axis=1)
    R, t = _rigid_fit(sol.points_mm, rays * dist[:, None])
    corners = np.asarray(result.score["facet_corners_mm"], float)
    hx, hy = float(np.abs(corners[:, 0]).max()), float(np.abs(corners[:, 1]).max())
    facet = MirrorFacet(hx, hy, focal_mm=tuple(float(f) for f in sol.focal_lengths_mm))
    setup = sofast_like_setup(camera, rot, origin, dots, xi, yi, facet=facet)
    from dataclasses import replace

    return replace(setup, facet_rotation=R, facet_origin_mm=t)


#: The files ``run_twin`` writes.
TWIN_OUTPUTS = ("twin_score.json", "slopes.csv", "twin.png")


def run_twin(out, *, folder=None, size: str = "small", spp: int | None = None, seed: int = 0,
             overwrite: bool = False, plot: bool = True, variant: str | None = None) -> dict:
    """Render the twin (:func:`render_twin`), reconstruct it with the true pose and from its corners, score
    both against the exact truth (:func:`measure_twin`), and write :data:`TWIN_OUTPUTS` to ``out``.

    ``spp`` defaults to 256 for the small twin and 64 for the full facet (which renders 1626 x 1236 pixels).
    ``slopes.csv`` holds the reconstruction from the corners (as for a real measurement).
    """
    import importlib.util

    from .._shared import check_number

    spp = (256 if size == "small" else 64) if spp is None else spp
    check_number("spp", spp, lo=1, hi=4096, integer=True)
    twin_facet(size)  # the size is checked before the folder is made
    names = [n for n in TWIN_OUTPUTS if plot or n != "twin.png"]
    if plot and importlib.util.find_spec("matplotlib") is None:
        raise OptionError("twin.png needs matplotlib (pip install 'shinysim[plot]'), or pass --no-plot")
    with output_folder(out, names, overwrite=overwrite, last="twin_score.json") as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        frame, source = render_twin(folder=folder, size=size, spp=spp, seed=seed, variant=variant)
        t1 = time.perf_counter()
        given = measure_twin(frame, pose="given")
        corners = measure_twin(frame, pose="corners")
        score = {"size": size, "spp": spp, "seed": seed, "geometry": source, "window_rc": list(frame.offset_rc),
                 "image": list(frame.image.shape), "facet": {
                     "half_sides_mm": [frame.setup.facet.half_width_mm, frame.setup.facet.half_height_mm],
                     "focal_mm": list(frame.setup.facet.focal_mm), "ripple_mm": frame.setup.facet.ripple_mm,
                     "ripple_period_mm": frame.setup.facet.ripple_period_mm},
                 "given_pose": given, "from_corners": corners,
                 "render_seconds": t1 - t0, "seconds": time.perf_counter() - t0}
        m = corners.pop("_measurement")
        given.pop("_measurement")
        write_text(tmp / "slopes.csv", slopes_csv(m.solution.points_mm, m.solution.slopes))
        if plot:
            from ..plot.deflect import twin_figure

            write_bytes(tmp / "twin.png", twin_figure(frame, m, score))
        write_json(tmp / "twin_score.json", json_safe(score))
    return score


def run_render_facet(result, folder, out_png, *, spp: int = 16, seed: int = 0, variant: str | None = None,
                     overwrite: bool = False) -> Path:
    """``real_vs_render.png``: the real frame beside a render of its reconstruction (:func:`reconstructed_setup`)."""
    from ..io import sofast
    from ..plot.deflect import real_vs_render_figure
    from ..sim.display import render_display_frame

    setup = reconstructed_setup(result, folder)
    frame = render_display_frame(setup, spp=spp, seed=seed, variant=variant)
    real = sofast.read_fixed_measurement(sofast.read_sofast_folder(folder).fixed_measurement).image
    f = setup.facet
    caption = (f"Left: the real frame (SOFAST's fixed-pattern measurement). Right: the same rig rendered with the "
               f"facet shinysim reconstructed from it: a paraboloid of focal lengths {f.focal_mm[0] / 1e3:.2f} m, "
               f"{f.focal_mm[1] / 1e3:.2f} m at the fitted pose (the rigid map of the dots' surface points into the "
               f"camera frame), a rough mirror of alpha {frame.metadata.get('alpha', 0):.1e}, {spp} samples per "
               "pixel. Below: 80 x 80 px around dot (0, 0). The rendered dots fall where the real ones are; what "
               "the paraboloid leaves out (the facet's waviness, its edge hardware, the screen's surround and the "
               "camera's vignetting) is what differs.")
    return write_bytes(out_png, real_vs_render_figure(real, frame.image, frame.origin_rc, caption), overwrite=overwrite)


# -- fringe deflectometry ----------------------------------------------------------------------------------------

#: The files ``run_sofast_fringe`` writes.
FRINGE_OUTPUTS = ("slopes.csv", "slopes.npz", "screen_points.csv", "score.json", "deflect.png")


@dataclass(frozen=True)
class FringeResult:
    """A SOFAST fringe measurement reconstructed (:func:`measure_sofast_fringe`).

    Attributes
    ----------
    measurement : PixelMeasurement
    score : dict
    expected : FacetResult of shinysim.io.sofast or None
    expected_pixels : ((m,) int, (m,) int) or None
        SOFAST's pixels (rows, cols), in the order of ``expected``'s slopes.
    """

    measurement: object
    score: dict
    expected: object = None
    expected_pixels: tuple | None = None


def measure_sofast_fringe(folder=None, *, files: dict | None = None, expected=None, align: str = "centre",
                          slope_params: SlopeParams | None = None, phase_params=None) -> FringeResult:
    """Slopes of the facet of a SOFAST fringe measurement, scored against SOFAST's result if present.

    Parameters
    ----------
    folder : path, optional
        SOFAST's files (:func:`~shinysim.io.sofast.read_sofast_folder`; a
        ``common/`` beside the folder is looked in too).
    files : dict, optional
        Paths by role (:data:`FILE_ROLES`): the fringe measurement, its
        camera, the display's response and shape, the camera-screen
        orientation and the facet definition; the last four may come from
        SOFAST's calculation file, which holds what it used.
    expected : path, False or None
        SOFAST's fringe calculation file (None: the folder's; False: none).
    align : {"centre", "none"}

    Returns
    -------
    FringeResult
    """
    from ..io import sofast
    from ..recon.deflect import measure_pixels
    from ..recon.phase import DisplayResponse, decode_phase
    from ..rig.opencv import camera_from_opencv
    from ..theory.phase import PhaseCode

    t0 = time.perf_counter()
    given = dict(files or {})
    if expected not in (None, False):
        given["fringe_calculation"] = expected
    paths, ambiguous = _resolve(folder, given)
    _need(paths, ambiguous, ["fringe_measurement"], folder)
    calc_path = paths["fringe_calculation"] if expected is not False else None
    notes = []

    def from_calculation(role, reader, what):
        if paths[role] is not None:
            return reader(paths[role])
        source = paths["fringe_calculation"]
        if source is None:
            _need(paths, ambiguous, [role], folder)
        notes.append(f"{what} from {Path(source).name} (the inputs SOFAST's calculation used)")
        return reader(source)

    meas = sofast.read_fringe_measurement(paths["fringe_measurement"])
    height, width = meas.fringe_images.shape[:2]
    cam_file = None
    for role in ("fringe_camera", "camera"):
        if paths[role] is not None:
            c = sofast.read_camera(paths[role])
            if tuple(c.image_size) == (width, height):
                cam_file = c
                break
    if cam_file is None:
        cam_file = from_calculation("fringe_camera", sofast.read_camera, "the camera")
    if tuple(cam_file.image_size) != (width, height):
        raise OptionError(f"no camera of the fringe images' size {width} x {height} (give --camera)")
    orient = from_calculation("spatial_orientation", sofast.read_spatial_orientation, "the camera-screen orientation")
    display = from_calculation("display_shape", sofast.read_display_shape, "the display's shape")
    facet = (sofast.read_facet_definition(paths["facet_definition"]) if paths["facet_definition"] is not None else
             None)
    if facet is None:
        if paths["fringe_calculation"] is None:
            _need(paths, ambiguous, ["facet_definition"], folder)
        facet = sofast.read_facet_definition(paths["fringe_calculation"],
                                             prefix="DataSofastInput/optic_definition/facet_000/")
        notes.append(f"the facet definition from {Path(paths['fringe_calculation']).name}")
    response = None
    if paths["image_calibration"] is not None:
        cal = sofast.read_image_calibration(paths["image_calibration"])
        response = DisplayResponse(cal.camera_values, cal.display_values)
    else:
        notes.append("no display response (image_calibration.h5): the camera values are taken as linear")
    camera = camera_from_opencv(cam_file.matrix, cam_file.distortion, cam_file.image_size, name=cam_file.name)
    code = PhaseCode(meas.periods_x, meas.periods_y)
    dec = decode_phase(meas.fringe_images, code, response=response, params=phase_params)
    lin = response if response is not None else (lambda v: np.asarray(v, float))
    edge = lin(meas.mask_images[..., 1].astype(float)) - lin(meas.mask_images[..., 0].astype(float))

    def screen_position(frac):
        return orient.screen_to_camera(display.fraction_to_screen_mm(frac))

    calc = sofast.read_calculation(calc_path) if calc_path is not None else None
    if calc is not None and getattr(calc, "kind", "fringe") == "fixed":
        raise OptionError(f"{calc_path}: is SOFAST's result of a fixed-pattern measurement; this is a fringe one "
                          "(give its own calculation file, or --no-expected)")
    sp = slope_params if slope_params is not None else (_surface_params(calc, align) or SlopeParams(align=align))
    pm = measure_pixels(dec, edge, camera, screen_position=screen_position,
                        screen_origin_mm=orient.screen_to_camera(np.zeros(3)),
                        distance_mm=meas.dist_optic_screen_mm, corners_mm=facet.corners_mm,
                        centroid_mm=facet.centroid_mm, measure_point_mm=meas.measure_point_mm, slope_params=sp)
    sol = pm.solution
    score = {
        "measurement": {"name": meas.name, "date": meas.date, "image": [width, height], "frames": code.n_frames,
                        "periods_x": list(code.periods_x), "periods_y": list(code.periods_y),
                        "dist_optic_screen_m": meas.dist_optic_screen_mm / 1e3},
        "optic": "facet", "mode": "fringe",
        **pm.counts,
        "noise_sigma": dec.noise_sigma,
        "focal_lengths_m": (sol.focal_lengths_mm / 1e3).tolist(),
        "alignment": sp.align,
        "pose": {"corners_rc": None if pm.corners_rc is None else pm.corners_rc.tolist(),
                 "corner_reprojection_rms_px": pm.pose_rms_px,
                 "side_rms_px": None if pm.side_rms_px is None else pm.side_rms_px.tolist(),
                 "optic_origin_camera_m": (pm.translation_mm / 1e3).tolist(),
                 "rvec_optic_to_camera": rotation_vector(pm.rotation).tolist(),
                 "alignment_turn_mrad": float(np.linalg.norm(rotation_vector(sol.alignment)) * 1e3)},
        "files": {k: None if v is None else str(v) for k, v in paths.items()},
        "notes": notes,
    }
    score["surface_fit"] = {"initial_focal_m": [f / 1e3 for f in sp.initial_focal_mm], "downsample": sp.downsample,
                            "robust": sp.robust, "from": "the reference's settings" if (
                                slope_params is None and calc is not None) else "given" if slope_params else
                            "defaults"}
    ref = ref_pixels = None
    if calc is not None:
        if len(calc.facets) != 1:
            raise OptionError(f"{calc_path}: holds {len(calc.facets)} facets; a single-facet measurement needs one")
        ref = calc.facets[0]
        mask = ref.extras.get("mask_processed")
        if mask is None or np.asarray(mask).shape != (height, width) or int(np.sum(mask)) != len(ref.slopes):
            raise OptionError(f"{calc_path}: its mask_processed does not give one pixel per slope of the "
                              f"{width} x {height} image; the pixels cannot be paired")
        rr, cc = np.nonzero(np.asarray(mask, bool))
        ref_pixels = (rr, cc)
        where = np.full((height, width), -1, np.int64)
        where[rr, cc] = np.arange(len(rr))
        k = where[pm.rows, pm.cols]
        both = k >= 0
        vs = compare_matched(sol.points_mm[both], sol.slopes[both], ref.slopes[k[both]])
        vs.update({"expected_pixels": len(ref.slopes), "only_ours": int((~both).sum()),
                   "only_expected": int(len(rr) - both.sum()), "file": str(calc_path),
                   "expected_focal_lengths_m": (_focal_fit(ref.surface_points_mm, ref.slopes) / 1e3).tolist()})
        score["vs_expected"] = vs
        frac_ref = ref.extras.get("v_screen_points_fractional_screens")
        if frac_ref is not None:
            # SOFAST's positions at its pixels, against ours at the same pixels decoded whatever our flags say
            diff = dec.decoded[rr, cc] - np.asarray(frac_ref, float)
            # an unwrapping error moves a position by a multiple of a period: more than half the finest one is one
            half = 0.5 / max(code.periods_x[-1], code.periods_y[-1])
            jumps = np.any(np.abs(diff) > half, axis=1)
            flagged = ~dec.valid[rr, cc]
            finite = np.all(np.isfinite(diff), axis=1)
            keep = finite & ~jumps
            score["screen_vs_expected"] = {
                "matched": int(finite.sum()),
                "rms_screen_widths": float(np.sqrt(np.mean(diff[keep] ** 2))) if keep.any() else None,
                "max_screen_widths": float(np.abs(diff[keep]).max()) if keep.any() else None,
                "unwrap_errors": int(jumps.sum()),
                "flagged_by_us": int(flagged.sum()),
                "unwrap_errors_unflagged": int((jumps & ~flagged).sum())}
    score["seconds"] = time.perf_counter() - t0
    return FringeResult(measurement=pm, score=json_safe(score), expected=ref, expected_pixels=ref_pixels)


def run_sofast_fringe(folder, out, *, files: dict | None = None, expected=None, align: str = "centre",
                      overwrite: bool = False, plot: bool = True) -> FringeResult:
    """:func:`measure_sofast_fringe`, written to ``out`` (:data:`FRINGE_OUTPUTS`)."""
    import importlib.util

    names = [n for n in FRINGE_OUTPUTS if plot or n != "deflect.png"]
    if plot and importlib.util.find_spec("matplotlib") is None:
        raise OptionError("deflect.png needs matplotlib (pip install 'shinysim[plot]'), or pass --no-plot")
    with output_folder(out, names, overwrite=overwrite, last="score.json") as tmp:
        tmp = Path(tmp)
        result = measure_sofast_fringe(folder, files=files, expected=expected, align=align)
        pm = result.measurement
        sol = pm.solution
        write_text(tmp / "slopes.csv", slopes_csv(sol.points_mm, sol.slopes))
        write_text(tmp / "screen_points.csv", screen_points_csv(pm.rows, pm.cols, pm.fraction))
        arrays = {"points_mm": sol.points_mm, "slopes": sol.slopes, "row": pm.rows, "col": pm.cols,
                  "fraction": pm.fraction, "coefs": sol.coefs, "focal_lengths_mm": sol.focal_lengths_mm,
                  "rotation": pm.rotation, "translation_mm": pm.translation_mm, "alignment": sol.alignment,
                  "camera_mm": sol.camera_mm}

        def npz(f):
            with open(f, "wb") as fh:
                np.savez(fh, **arrays)

        write_file(tmp / "slopes.npz", npz)
        if plot:
            from ..plot.deflect import fringe_figure

            write_bytes(tmp / "deflect.png", fringe_figure(result))
        write_json(tmp / "score.json", result.score)
    return result


#: Display pixels across the twin's lit screen (x, y): the unit of the fringe twin's decoding error. A 1920 x
#: 1080 display spread over the lit rectangle.
TWIN_DISPLAY_PIXELS = (1920, 1080)


#: The fringe twin's facet mesh tolerance, mm (:func:`render_fringe_twin`).
FRINGE_MESH_TOLERANCE_MM = 1e-5


def render_fringe_twin(*, folder=None, size: str = "small", code=None, spp: int = 64, seed: int = 0,
                       sensor=None, exposure: float = 0.8, gamma: float = 1.0, alpha: float | None = None,
                       mesh_tolerance_mm: float | None = None, margin_px: int = 12, batches: int = 1,
                       variant: str | None = None):
    """The fringe twin's frames: SOFAST's rig (:func:`sofast_geometry`) with :func:`twin_facet`, the display showing
    every frame of a phase code (default SOFAST's, :class:`~shinysim.theory.phase.PhaseCode`), rendered over the
    facet's window (:func:`shinysim.sim.display.render_fringe_frames`) through ``sensor`` (a preset name or a
    Sensor; None: radiance) with a display of response ``gamma``. ``batches`` > 1 (ideal sensor only) averages
    that many traces of ``spp`` samples (seeds ``seed``, ``seed + 1``, ...): ``batches * spp`` samples per pixel
    without holding them all at once."""
    from ..sim.display import render_fringe_frames
    from ..sim.sensor import Sensor, sensor_preset
    from ..theory.phase import PhaseCode

    setup, rows, cols, source = _twin_setup(folder, size, margin_px)
    if isinstance(sensor, str):
        sensor = sensor_preset(sensor)
    if sensor is not None and not isinstance(sensor, Sensor):
        raise OptionError(f"sensor must be a preset name or a Sensor, got {sensor!r}")
    from dataclasses import replace

    from .._shared import check_number
    from ..sim.display import SOFAST_ALPHA

    check_number("batches", batches, lo=1, hi=4096, integer=True)
    if batches > 1 and sensor is not None:
        raise OptionError("batches > 1 averages radiance frames: give no sensor")
    # the facet's mesh within 1e-5 mm of the surface: its interpolated normals then move the reflected points by
    # under 0.002 display px (at the default 1e-4 mm, 0.014 px RMS in a ripple-shaped pattern)
    kw = dict(rows=rows, cols=cols, gamma=gamma, sensor=sensor, exposure=exposure, variant=variant,
              alpha=SOFAST_ALPHA if alpha is None else alpha,
              mesh_tolerance_mm=FRINGE_MESH_TOLERANCE_MM if mesh_tolerance_mm is None else mesh_tolerance_mm)
    frames = render_fringe_frames(setup, code or PhaseCode(), spp=spp, seed=seed, **kw)
    if batches > 1:
        acc = [np.array(frames.frames, float), np.array(frames.dark, float), np.array(frames.light, float),
               np.array(frames.coverage, float)]
        for b in range(1, batches):
            more = render_fringe_frames(setup, code or PhaseCode(), spp=spp, seed=seed + b, **kw)
            for a, m in zip(acc, (more.frames, more.dark, more.light, more.coverage)):
                a += m
        frames = replace(frames, frames=acc[0] / batches, dark=acc[1] / batches, light=acc[2] / batches,
                         coverage=acc[3] / batches,
                         metadata={**frames.metadata, "spp": spp * batches, "batches": batches})
    return frames, source


def measure_fringe_twin(frames, code=None, *, pose: str = "given", response=None, gamma: float | None = None) -> dict:
    """The fringe twin decoded and reconstructed, scored against its exact truth.

    Parameters
    ----------
    frames : FringeFrames
    code : PhaseCode, optional
        The code rendered (default SOFAST's).
    pose : {"given", "corners"}
        As :func:`measure_twin`.
    response : DisplayResponse, optional
        Undoes the display's response; default: with ``gamma`` given,
        :meth:`~shinysim.recon.phase.DisplayResponse.from_gamma`, scaled to the light frame's range.
    gamma : float, optional

    Returns
    -------
    dict
        ``decoding`` (``valid``, ``low_modulation``, ``unwrap_inconsistent``,
        ``rms_display_px`` [x, y] against the exact screen point of each
        valid pixel's centre, ``max_display_px``, ``unwrap_errors``: valid
        pixels off by more than half the finest period, ``noise_law_display_px``:
        the median of :func:`~shinysim.theory.phase.position_noise` over the
        valid pixels), ``slopes`` (against the exact slopes at the
        reconstructed points, and detilted), ``focal_lengths_m``.
    """
    from ..evaluate.deflect import detilt as _detilt
    from ..evaluate.deflect import slope_stats
    from ..recon.deflect import measure_pixels
    from ..recon.phase import DisplayResponse, decode_phase
    from ..theory.phase import PhaseCode

    if pose not in ("given", "corners"):
        raise OptionError(f"pose must be 'given' or 'corners', got {pose!r}")
    code = code or PhaseCode()
    setup = frames.setup
    if response is None and gamma is not None:
        response = DisplayResponse.from_gamma(gamma, display_max=1.0, camera_max=float(np.max(frames.light)))
    dec = decode_phase(frames.frames, code, response=response)
    lin = response if response is not None else (lambda v: np.asarray(v, float))
    edge = lin(frames.light) - lin(frames.dark)
    w, h = setup.display.size_mm
    cx, cy = setup.display.centre_mm

    def screen_position(frac):
        frac = np.asarray(frac, float)
        pts = np.column_stack([cx - 0.5 * w + frac[:, 0] * w, cy - 0.5 * h + frac[:, 1] * h, np.zeros(len(frac))])
        return setup.screen_to_camera(pts)

    s0 = np.asarray(setup.screen_origin_mm, float)
    distance = float(np.linalg.norm(setup.facet_to_camera(np.zeros(3)) - s0))
    kw = dict(screen_position=screen_position, screen_origin_mm=s0, distance_mm=distance)
    if pose == "given":
        pm = measure_pixels(dec, edge, setup.camera, pose=(setup.facet_rotation, setup.facet_origin_mm),
                            slope_params=SlopeParams(align="none"), **kw)
    else:
        pm = measure_pixels(dec, edge, setup.camera, corners_mm=setup.facet.corners_mm(),
                            slope_params=SlopeParams(align="centre"), **kw)
    truth = frames.truth_fraction[pm.rows, pm.cols]
    err = (pm.fraction - truth) * np.array(TWIN_DISPLAY_PIXELS)
    finite = np.all(np.isfinite(err), axis=1)
    half = 0.5 / np.array([code.periods_x[-1], code.periods_y[-1]]) * np.array(TWIN_DISPLAY_PIXELS)
    jumps = finite & np.any(np.abs(err) > half, axis=1)
    good = finite & ~jumps
    law = dec.position_sigma[pm.rows, pm.cols] * np.array(TWIN_DISPLAY_PIXELS)
    sol = pm.solution
    diff = sol.slopes - setup.facet.slopes(sol.points_mm[:, 0], sol.points_mm[:, 1])
    return {
        "pose": pose,
        "decoding": {"pixels_region": int(pm.mask.sum()), "valid": int(len(pm.rows)),
                     "low_modulation": int((dec.low_modulation & pm.mask).sum()),
                     "unwrap_inconsistent": int((dec.unwrap_inconsistent & pm.mask).sum()),
                     "compared": int(good.sum()), "unwrap_errors": int(jumps.sum()),
                     "rms_display_px": np.sqrt(np.mean(err[good] ** 2, axis=0)).tolist() if good.any() else None,
                     "max_display_px": np.abs(err[good]).max(axis=0).tolist() if good.any() else None,
                     "noise_law_display_px": np.median(law[good], axis=0).tolist() if good.any() else None,
                     "noise_sigma": dec.noise_sigma},
        "slopes": {**slope_stats(diff), "detilted": slope_stats(_detilt(sol.points_mm, diff))},
        "focal_lengths_m": (sol.focal_lengths_mm / 1e3).tolist(),
        "alignment_turn_mrad": float(np.linalg.norm(rotation_vector(sol.alignment)) * 1e3),
        "_measurement": pm,
    }


#: Codes of the fringe noise table: shifts and periods per screen (x and y alike).
NOISE_TABLE_CODES = ((3, (0.9, 3.9, 15.9, 63.9)), (4, (0.9, 3.9, 15.9, 63.9)), (6, (0.9, 3.9, 15.9, 63.9)),
                     (8, (0.9, 3.9, 15.9, 63.9)), (4, (0.9, 7.9, 63.9)), (4, (0.9, 3.9, 15.9)), (4, (0.9, 3.9)))


def fringe_noise_table(*, folder=None, sensor="tv_1980s_8bit", spp: int = 64, seed: int = 0, exposure: float = 0.8,
                       codes=NOISE_TABLE_CODES, variant: str | None = None) -> list[dict]:
    """The decoded position's noise against frames and periods, under a sensor, beside the noise law.

    One trace of the small fringe twin (:func:`shinysim.sim.display.trace_screen_hits`) gives every code's
    noise-free frames from the same samples (:func:`~shinysim.sim.display.pattern_frames`), so the render's own
    sampling noise is the same on both sides and cancels: each code is decoded from the sensor's frames and from
    the noise-free ones, and the difference is the sensor's doing. The law is
    :func:`~shinysim.theory.phase.position_noise` with the frames' noise measured from two captures of the same
    frames (their difference over sqrt 2) and the median finest-period modulation of the region. The sensor's
    fixed pattern (vignetting, pixel gains) is left out: it does not move a phase.

    Returns
    -------
    list of dict
        One per code: ``shifts``, ``periods``, ``frames``, ``pixels``, ``measured_display_px`` [x, y] (RMS),
        ``law_display_px`` [x, y], ``ratio`` [x, y], ``unwrap_errors`` (against the noise-free decoding), and
        the sensor's ``noise_sigma`` and the ``modulation``.
    """
    from dataclasses import replace

    from ..recon.phase import decode_phase
    from ..sim.display import mask_frames, pattern_frames, trace_screen_hits
    from ..sim.sensor import sensor_preset
    from ..theory.phase import PhaseCode, position_noise

    setup, rows, cols, _ = _twin_setup(folder, "small", 12)
    hits = trace_screen_hits(setup, spp=spp, seed=seed, rows=rows, cols=cols, variant=variant)
    on, off = setup.display.on_radiance, setup.display.off_radiance
    dark, light = mask_frames(hits, on_radiance=on, off_radiance=off)
    sens = sensor_preset(sensor) if isinstance(sensor, str) else sensor
    exposed = replace(sens.exposed_for(float(light.max()), exposure), vignetting=0.0, prnu=0.0)
    region = hits.coverage >= 0.999  # pixels that see the lit screen whole
    table = []
    for k, (shifts, periods) in enumerate(codes):
        code = PhaseCode(periods, periods, shifts)
        clean = pattern_frames(hits, code.intensity, on_radiance=on, off_radiance=off)
        a = np.asarray(exposed.capture(np.moveaxis(clean, -1, 0), seed=2 * k + 1), float)
        b = np.asarray(exposed.capture(np.moveaxis(clean, -1, 0), seed=2 * k + 2), float)
        noisy = np.moveaxis(a, 0, -1)
        d_clean = decode_phase(clean, code, region=region, noise_sigma=0.0)  # the phase is the radiance's
        d_noisy = decode_phase(noisy, code, region=region)
        both = d_clean.valid & d_noisy.valid
        err = (d_noisy.fraction - d_clean.fraction)[both] * np.array(TWIN_DISPLAY_PIXELS)
        half = 0.5 / periods[-1] * np.array(TWIN_DISPLAY_PIXELS)
        jumps = np.any(np.abs(err) > half, axis=1)
        sigma = float(np.sqrt(np.mean((a - b)[:, region] ** 2) / 2.0))
        mod = float(np.median(d_noisy.modulation[both]))  # the sensor's units, as sigma
        law = position_noise(sigma, mod, periods[-1], shifts) * np.array(TWIN_DISPLAY_PIXELS)
        measured = np.sqrt(np.mean(err[~jumps] ** 2, axis=0))
        table.append({"shifts": shifts, "periods": list(periods), "frames": code.n_frames, "pixels": int(both.sum()),
                      "measured_display_px": measured.tolist(), "law_display_px": law.tolist(),
                      "ratio": (measured / law).tolist(), "unwrap_errors": int(jumps.sum()),
                      "flagged": int((d_noisy.low_modulation | d_noisy.unwrap_inconsistent)[region].sum()),
                      "noise_sigma": sigma, "decoder_noise_sigma": d_noisy.noise_sigma, "modulation": mod})
    return table


#: The files ``run_fringe_twin`` writes.
FRINGE_TWIN_OUTPUTS = ("twin_score.json", "slopes.csv", "screen_points.csv")


def run_fringe_twin(out, *, folder=None, spp: int = 256, seed: int = 0, sensor: str | None = None,
                    gamma: float = 1.0, overwrite: bool = False, variant: str | None = None) -> dict:
    """The small fringe twin rendered (:func:`render_fringe_twin`), decoded and reconstructed with the true pose and
    from its corners, scored against its exact truth (:func:`measure_fringe_twin`), and, under a ``sensor``, the
    noise table (:func:`fringe_noise_table`); written to ``out`` (:data:`FRINGE_TWIN_OUTPUTS`)."""
    from .._shared import check_number

    check_number("spp", spp, lo=1, hi=4096, integer=True)
    with output_folder(out, list(FRINGE_TWIN_OUTPUTS), overwrite=overwrite, last="twin_score.json") as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        frames, source = render_fringe_twin(folder=folder, spp=spp, seed=seed, sensor=sensor, gamma=gamma,
                                            variant=variant)
        response_gamma = gamma if gamma != 1.0 else None
        given = measure_fringe_twin(frames, pose="given", gamma=response_gamma)
        corners = measure_fringe_twin(frames, pose="corners", gamma=response_gamma)
        score = {"mode": "fringe", "geometry": source, "spp": spp, "seed": seed, "sensor": sensor, "gamma": gamma,
                 "image": list(frames.frames.shape[:2]), "display_pixels": list(TWIN_DISPLAY_PIXELS),
                 "given_pose": given, "from_corners": corners}
        pm = corners.pop("_measurement")
        given.pop("_measurement")
        if sensor is not None:
            score["noise_table"] = fringe_noise_table(folder=folder, sensor=sensor, seed=seed, variant=variant)
        score["seconds"] = time.perf_counter() - t0
        write_text(tmp / "slopes.csv", slopes_csv(pm.solution.points_mm, pm.solution.slopes))
        write_text(tmp / "screen_points.csv", screen_points_csv(pm.rows, pm.cols, pm.fraction))
        write_json(tmp / "twin_score.json", json_safe(score))
    return score
