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
from ..evaluate.deflect import compare_slopes, match_points
from ..recon.deflect import SlopeParams, measure_facet, rotation_vector
from ..recon.dots import DotParams

__all__ = ["DEFLECT_OUTPUTS", "DeflectResult", "measure_sofast_fixed", "run_sofast_fixed", "slopes_csv"]

#: The files ``run_sofast_fixed`` writes.
DEFLECT_OUTPUTS = ("slopes.csv", "slopes.npz", "score.json", "deflect.png")


@dataclass(frozen=True)
class DeflectResult:
    """A fixed-pattern measurement reconstructed (:func:`measure_sofast_fixed`).

    Attributes
    ----------
    measurement : FacetMeasurement
    score : dict
        What ``score.json`` holds.
    expected : FacetResult or None
        SOFAST's own result, when given.
    pairs : ((n,) bool, (n,) int) or None
        Which of the solution's dots matched a point of ``expected``, and which.
    """

    measurement: object
    score: dict
    expected: object = None
    pairs: tuple | None = None


def _focal_fit(points_mm, slopes):
    """Focal lengths (mm) of the paraboloid whose slopes best fit ``slopes`` (SOFAST's linear slope model)."""
    design = np.column_stack([np.ones(len(points_mm)), points_mm[:, 0], points_mm[:, 1]])
    sx = np.linalg.lstsq(design, slopes[:, 0], rcond=None)[0]
    sy = np.linalg.lstsq(design, slopes[:, 1], rcond=None)[0]
    with np.errstate(divide="ignore"):
        return np.array([1 / (2 * sx[1]), 1 / (2 * sy[2])])


def measure_sofast_fixed(folder, *, expected=None, align: str = "centre", dot_params: DotParams | None = None,
                         slope_params: SlopeParams | None = None) -> DeflectResult:
    """Slopes of the facet of a SOFAST fixed-pattern measurement, scored against SOFAST's result if present.

    Parameters
    ----------
    folder : path
        SOFAST's files (:func:`~shinysim.io.sofast.read_sofast_folder`): a
        fixed-pattern measurement, its dot locations, the camera, the
        camera-screen orientation and the facet definition are needed.
    expected : path, False or None
        SOFAST's calculation file to score against; None: the folder's, if
        it has one; False: none.
    align : {"centre", "none"}
        See :data:`shinysim.recon.deflect.ALIGNMENTS`.

    Returns
    -------
    DeflectResult
    """
    from ..io import sofast
    from ..rig.opencv import camera_from_opencv

    t0 = time.perf_counter()
    files = sofast.read_sofast_folder(folder)
    needed = {"fixed_measurement": "a fixed-pattern measurement (measurement_facet.h5)",
              "dot_locations": "the dot locations (fixed_pattern_dot_locations.h5)",
              "camera": "the camera (camera_sofast.h5)",
              "spatial_orientation": "the camera-screen orientation (spatial_orientation.h5)",
              "facet_definition": "the facet definition (Facet_*.json)"}
    missing = [what for role, what in needed.items() if getattr(files, role) is None]
    if missing:
        raise OptionError(f"{folder}: no {', no '.join(missing)}")
    meas = sofast.read_fixed_measurement(files.fixed_measurement)
    dots = sofast.read_dot_locations(files.dot_locations)
    cam_file = sofast.read_camera(files.camera)
    orient = sofast.read_spatial_orientation(files.spatial_orientation)
    facet = sofast.read_facet_definition(files.facet_definition)
    height, width = meas.image.shape
    if tuple(cam_file.image_size) != (width, height):
        raise OptionError(f"{files.camera}: the camera's image is {cam_file.image_size[0]} x {cam_file.image_size[1]} "
                          f"but the measurement's is {width} x {height}")
    camera = camera_from_opencv(cam_file.matrix, cam_file.distortion, cam_file.image_size, name=cam_file.name)

    def dot_position(ix, iy):
        return orient.screen_to_camera(dots.position_mm(ix, iy))

    screen_origin = orient.screen_to_camera(np.zeros(3))
    sp = slope_params if slope_params is not None else SlopeParams(align=align)
    m = measure_facet(meas.image, camera, dot_position=dot_position, screen_origin_mm=screen_origin,
                      origin_rc=(meas.origin_px[1], meas.origin_px[0]), distance_mm=meas.dist_optic_screen_mm,
                      corners_mm=facet.corners_mm, centroid_mm=facet.centroid_mm,
                      measure_point_mm=meas.measure_point_mm, dot_params=dot_params, slope_params=sp)
    sol = m.solution
    turn = np.degrees(np.linalg.norm(rotation_vector(sol.alignment)))
    score = {
        "measurement": {"name": meas.name, "date": meas.date, "image": [width, height],
                        "dist_optic_screen_m": meas.dist_optic_screen_mm / 1e3},
        **m.counts,
        "focal_lengths_m": (sol.focal_lengths_mm / 1e3).tolist(),
        "alignment": sp.align,
        "pose": {"corners_rc": None if m.corners_rc is None else m.corners_rc.tolist(),
                 "corner_reprojection_rms_px": m.pose_rms_px,
                 "side_rms_px": None if m.side_rms_px is None else m.side_rms_px.tolist(),
                 "facet_origin_camera_m": (m.translation_mm / 1e3).tolist(),
                 "rvec_facet_to_camera": rotation_vector(m.rotation).tolist(),
                 "alignment_turn_mrad": float(np.radians(turn) * 1e3)},
        "dot_pitch_px": m.index.pitch_px,
        "files": {k: None if v is None else str(v) for k, v in vars(files).items() if k != "root"},
    }
    ref = pairs = None
    source = files.fixed_calculation if expected is None else (None if expected is False else expected)
    if source is not None:
        calc = sofast.read_calculation(source)
        if len(calc.facets) != 1:
            raise OptionError(f"{source}: holds {len(calc.facets)} facets; a single-facet measurement needs one")
        ref = calc.facets[0]
        vs = compare_slopes(sol.points_mm, sol.slopes, ref.surface_points_mm, ref.slopes)
        vs["expected_points"] = len(ref.slopes)
        vs["expected_focal_lengths_m"] = (_focal_fit(ref.surface_points_mm, ref.slopes) / 1e3).tolist()
        vs["focal_length_ratio"] = (sol.focal_lengths_mm / _focal_fit(ref.surface_points_mm, ref.slopes)).tolist()
        vs["file"] = str(source)
        hit, nearest, _ = match_points(sol.points_mm, ref.surface_points_mm, vs["match_mm"])
        pairs = (hit, nearest)
        score["vs_expected"] = vs
    score["seconds"] = time.perf_counter() - t0
    return DeflectResult(measurement=m, score=json_safe(score), expected=ref, pairs=pairs)


def slopes_csv(points_mm, slopes) -> str:
    """The ``slopes.csv`` text: ``x_m,y_m,z_m,slope_x,slope_y``, one row per point (metres, radians)."""
    rows = ["x_m,y_m,z_m,slope_x,slope_y"]
    for (x, y, z), (sx, sy) in zip(np.asarray(points_mm) / 1e3, np.asarray(slopes)):
        rows.append(f"{x:.9g},{y:.9g},{z:.9g},{sx:.9g},{sy:.9g}")
    return "\n".join(rows) + "\n"


def run_sofast_fixed(folder, out, *, expected=None, align: str = "centre", overwrite: bool = False,
                     plot: bool = True, dot_params: DotParams | None = None) -> DeflectResult:
    """:func:`measure_sofast_fixed`, written to ``out`` (:data:`DEFLECT_OUTPUTS`; nothing outside it)."""
    names = [n for n in DEFLECT_OUTPUTS if plot or n != "deflect.png"]
    if plot:
        from ..plot import deflect as _check_plot  # noqa: F401 - the plot extra, before any work
    with output_folder(out, names, overwrite=overwrite, last="score.json") as tmp:
        tmp = Path(tmp)
        result = measure_sofast_fixed(folder, expected=expected, align=align, dot_params=dot_params)
        m = result.measurement
        sol = m.solution
        write_text(tmp / "slopes.csv", slopes_csv(sol.points_mm, sol.slopes))
        dots = m.dots
        used = m.used

        def npz(f):
            with open(f, "wb") as fh:  # a file object: np.savez given a name adds ".npz" to it
                np.savez(fh, points_mm=sol.points_mm, slopes=sol.slopes, row=dots["row"][used],
                         col=dots["col"][used], index=m.index.index[used], coefs=sol.coefs,
                         focal_lengths_mm=sol.focal_lengths_mm, rotation=m.rotation, translation_mm=m.translation_mm,
                         alignment=sol.alignment, camera_mm=sol.camera_mm)

        write_file(tmp / "slopes.npz", npz)
        if plot:
            from ..plot.deflect import deflect_figure

            write_bytes(tmp / "deflect.png", deflect_figure(result))
        write_json(tmp / "score.json", result.score)
    return result
