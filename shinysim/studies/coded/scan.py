"""The coded scan: options, code, surfaces and scores, the run that writes a folder, and decoding a given folder."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..._shared import (
    Progress,
    check_number,
    json_safe,
    named_check,
    output_folder,
    write_file,
    write_json,
)
from ...errors import OptionError
from ...evaluate import (
    coverage,
    decoding_errors,
    empty_coverage,
    part_mask,
    pixel_owner,
    sample_truth,
    score_heights,
    source_directions,
)
from ...io import Stack, load_stack, load_truth, save_stack, save_truth
from ...io.coded import DETECT_FIELDS, read_coded_scan, write_coded_scan
from ...recon import DetectParams, reconstruct
from ...recon.coding import Decoded, check_crosstalk, decode
from ...recon.decode import decode_settings, table_normals
from ...recon.integrate import (
    compare_integrators,
    integrate_triangulated,
)
from ...rig import Rig
from ...theory.coding import (
    CODES,
    COLOURS,
    MAX_SOURCES,
    Code,
    colour_channels,
    make_code,
    spatial_order,
)
from ..scan import SCAN_LIMITS
from .pieces import _normal_errors, _vs_sequential
from .report import coded_figure
from .scene import CODED_OBJECTS, CODED_RIGS, ScanObject, _choice, coded_rig, scan_object

__all__ = ["CODED_FILES", "check_coded_options", "study_code", "surface_scores", "score_coded", "run_coded_scan",
           "decode_folder"]


#: Files a coded scan folder holds; none is ever silently replaced.
CODED_FILES = ("rig.json", "stack.exr", "coded.npz", "code.json", "truth.exr", "highlights.csv", "score.json",
               "surface.npz", "coded.png")


# -- options ----------------------------------------------------------------------------------


def check_coded_options(*, rig="dome", n_sources=200, code="binary", complementary=True, object="sphere",
                        alpha=0.02, resolution=512, spp=16, seed=0, sensor=None, exposure=0.8, crosstalk=None,
                        colours=1, rim_deg=None):
    """Check a coded scan's options before any work.

    Returns
    -------
    (Rig, Code, Sensor or None)
        The rig (without its anchor), the code and the sensor the options describe.

    Raises
    ------
    OptionError
        Naming the first bad option: an unknown rig, object or code, a
        source count the rig or the code cannot hold (more sources lit at
        once than a code of that kind tells apart), bad numbers, an unknown
        sensor, a crosstalk tolerance at or above ``1 / bits``, a colour
        count other than 1 or 3.
    """
    from ...sim.sensor import Sensor, sensor_preset

    _choice("rig", rig, CODED_RIGS)
    _choice("object", object, CODED_OBJECTS)
    _choice("code", code, CODES)
    if isinstance(n_sources, (bool, np.bool_)) or not isinstance(n_sources, (int, np.integer)):
        raise OptionError(f"must be an integer, got {n_sources!r}", field="n_sources")
    if n_sources < 1:
        raise OptionError(f"must be >= 1, got {n_sources}", field="n_sources")
    if n_sources > MAX_SOURCES:
        raise OptionError(f"is {n_sources}: more sources than a {code} code tells apart (at most {MAX_SOURCES})",
                          field="n_sources")
    if not isinstance(complementary, (bool, np.bool_)):
        raise OptionError(f"must be True or False, got {complementary!r}", field="complementary")
    for name, value in (("alpha", alpha), ("resolution", resolution), ("spp", spp), ("seed", seed)):
        named_check(name, check_number, value, **SCAN_LIMITS[name])
    named_check("exposure", check_number, exposure, lo=0, lo_open=True, hi=100)
    if sensor is None or isinstance(sensor, str):
        sensor = sensor_preset(sensor or "ideal")
    elif not isinstance(sensor, Sensor):
        raise OptionError(f"must be a preset name or a Sensor, got {type(sensor).__name__}", field="sensor")
    if isinstance(colours, (bool, np.bool_)) or colours not in COLOURS:
        raise OptionError(f"must be 1 (one colour) or 3 (red, green and blue fibers), got {colours!r}",
                          field="colours")
    the_rig = coded_rig(rig, n_sources=int(n_sources), resolution=int(resolution), rim_deg=rim_deg)
    the_code = study_code(code, the_rig, complementary=complementary, colours=int(colours))
    if crosstalk is not None:
        check_crosstalk(crosstalk, the_code.n_bits)
    return the_rig, the_code, sensor


def study_code(name: str, rig: Rig, *, complementary: bool = True, colours: int = 1) -> Code:
    """The study's code of kind ``name`` for ``rig``'s sources.

    Gray codewords, and with ``colours=3`` every code's columns and fiber
    colours, go along :func:`~shinysim.theory.coding.spatial_order` of the
    source directions (neighbouring sources one bit apart, and in different
    colours: :func:`~shinysim.theory.coding.colour_channels`).
    """
    _choice("code", name, CODES)
    dirs = source_directions(rig)
    comp = bool(complementary) and name in ("binary", "gray")
    if colours == 3:
        order = spatial_order(dirs)
        return make_code(name, rig.n_sources, complementary=comp, order=order, colours=3,
                         channels=colour_channels(dirs, order=order))
    return make_code(name, rig.n_sources, complementary=comp, order=spatial_order(dirs) if name == "gray" else None)


# -- normals and surfaces -------------------------------------------------------------------


def _truth_height_fn(truth, parts, camera):
    """``height(x, y)`` of the rendered truth: the point (x, y) at the surface's height projected into the
    image, the truth's heights interpolated bilinearly there, twice (perspective moves the pixel with the
    height); NaN off the measured parts."""
    m = part_mask(truth, parts)
    z_img = np.where(m, truth.positions[..., 2].astype(float), np.nan)
    H, W = m.shape
    z_start = float(np.nanmedian(z_img))

    def height(x, y):
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        z = np.full(x.shape, z_start)
        for _ in range(3):
            r, c = camera.project(np.stack([x, y, z], axis=-1))
            r0 = np.clip(np.floor(r), 0, H - 2).astype(int)
            c0 = np.clip(np.floor(c), 0, W - 2).astype(int)
            fr, fc = np.clip(r - r0, 0, 1), np.clip(c - c0, 0, 1)
            z_new = ((1 - fr) * (1 - fc) * z_img[r0, c0] + (1 - fr) * fc * z_img[r0, c0 + 1]
                     + fr * (1 - fc) * z_img[r0 + 1, c0] + fr * fc * z_img[r0 + 1, c0 + 1])
            z = np.where(np.isfinite(z_new), z_new, z)
        return np.where(np.isfinite(z_new), z, np.nan)

    return height


def surface_scores(xy, normals, truth, obj: ScanObject, rig: Rig | None = None, *, grid_step_mm=None,
                   methods=("sparse-arc", "poisson", "frankot-chellappa", "robust")) -> dict[str, Any]:
    """Height maps from sparse normals, scored against the truth.

    Two scores:

    * ``anchored``: :func:`~shinysim.recon.integrate.integrate_triangulated`
      tied to the object's datum (a known point), its heights compared
      with the truth at every covered pixel, *without* removing an offset
      (``height_rms_mm``, ``height_rms_pct`` of ``obj.scale_mm``), the
      heights between the points interpolated with the points' normals
      (``SparseSurface.heights_at(..., interpolation="normals")``, exact on
      quadratic surfaces); ``height_rms_linear_mm`` / ``_pct``: the same with
      plane facets.
    * ``integrators``: :func:`~shinysim.recon.integrate.compare_integrators`
      on the same normals (the sparse integrator and the grid integrators
      on one grid, each result's mean offset removed), height RMS and the
      normal RMS of each height map against the truth.

    Returns
    -------
    dict
        ``anchored``, ``integrators``, ``surface`` (the anchored
        :class:`SparseSurface`), ``coverage`` (with ``rig``).
    """
    xy = np.asarray(xy, float)
    normals = np.asarray(normals, float)
    ok = np.all(np.isfinite(xy), 1) & np.all(np.isfinite(normals), 1)
    xy, normals = xy[ok], normals[ok]
    if len(xy) < 3:
        nan = float("nan")
        why = f"{len(xy)} highlight(s) with normals on the surface: too few to triangulate"
        out = {"anchored": {"height_rms_mm": nan, "height_rms_pct": nan, "height_max_mm": nan, "pixels": 0,
                            "scale_mm": float(obj.scale_mm), "points": int(len(xy)), "note": why},
               "integrators": {"error": why}, "surface": None}
        if rig is not None:
            out["coverage"] = empty_coverage(truth, rig, obj.parts, why)
        return out
    surf = integrate_triangulated(xy, normals, anchors=np.asarray(obj.datum, float)[None])
    height = obj.height if obj.height is not None else _truth_height_fn(truth, obj.parts, (rig or coded_rig()).camera)
    anchored = score_heights(surf, truth, obj.parts, obj.scale_mm)
    try:
        integ = compare_integrators(xy, normals, height, grid_step_mm=grid_step_mm, scale_mm=obj.scale_mm,
                                    methods=methods)
    except OptionError as exc:
        integ = {"error": str(exc)}
    out = {"anchored": anchored, "integrators": integ, "surface": surf}
    if rig is not None:
        out["coverage"] = coverage(truth, rig, surf, obj.parts)
    return out


# -- the scan ---------------------------------------------------------------------------------


def score_coded(dec: Decoded, seq_recon, code: Code, rig: Rig, truth, owner, obj: ScanObject, *,
                seq_normals=None) -> dict[str, Any]:
    """Score a decoded scan against the sequential one and the truth (the ``score.json`` content, less run facts).

    Returns
    -------
    dict
        ``decoding`` (:func:`decoding_errors`), ``frames`` (used, and
        sequential), ``normals`` (per model, against the truth: median, p95,
        max), ``best_model``, ``coded_vs_sequential`` (angle between the
        coded and the sequential normal of each paired highlight, best
        model), ``surface`` (anchored height map, integrators, coverage).
    """
    seq_table = seq_recon.table
    seq_n = seq_normals if seq_normals is not None else table_normals(seq_table, rig, rig.anchor)
    dec_n = table_normals(dec.table, rig, rig.anchor)
    best = dec_n["best"]
    errs = decoding_errors(dec, owner, seq_table)
    per_model = {m: _normal_errors(dec.table, n, truth) for m, n in dec_n["normals"].items()}
    diff = _vs_sequential(dec.table, seq_table, errs["radius_px"], dec_n["normals"][best], seq_n["normals"][best])
    # the surface from the decoded highlights on the measured parts
    _, _, on = sample_truth(truth, dec.table["row"], dec.table["col"])
    part_ok = np.ones(len(on), bool)
    if obj.parts and len(on):
        ids = [i for i, nm in enumerate(truth.part_names) if nm in obj.parts]
        r = np.clip(np.rint(dec.table["row"]).astype(int), 0, truth.mask.shape[0] - 1)
        c = np.clip(np.rint(dec.table["col"]).astype(int), 0, truth.mask.shape[1] - 1)
        part_ok = np.isin(truth.part[r, c], ids)
    surf = surface_scores(dec_n["points"][part_ok, :2], dec_n["normals"][best][part_ok], truth, obj, rig)
    return {"decoding": errs, "frames": {"used": code.n_frames, "sequential": rig.n_sources,
                                         "speed_up": rig.n_sources / code.n_frames},
            "normals": per_model, "best_model": best, "coded_vs_sequential": {"model": best, **diff},
            "surface": {"anchored": surf["anchored"], "integrators": surf["integrators"],
                        "coverage": surf["coverage"]},
            "_surface": surf["surface"], "_normals": dec_n}


def _coded_bytes(rig, n_frames, colours=1):
    H, W = rig.camera.shape
    return 4 * H * W * (rig.n_sources + colours * n_frames + 12) + 8 * 2**20


def run_coded_scan(out: str | os.PathLike, *, rig: str = "dome", n_sources: int = 200, code: str = "binary",
                   complementary: bool = True, object: str = "sphere", alpha: float = 0.02, resolution: int = 512,
                   spp: int = 16, seed: int = 0, sensor: Any = None, exposure: float = 0.8,
                   crosstalk: float | None = None, surface: bool = True, overwrite: bool = False,
                   progress: Progress | None = None, plot: bool = True, colours: int = 1,
                   rim_deg: float | None = None) -> dict[str, Any]:
    """Render a dome scan once, code it, decode it and score normals, decoding and surface.

    Parameters
    ----------
    out : path-like
        Folder for :data:`CODED_FILES` (``surface.npz`` only with
        ``surface``, ``coded.png`` only with ``plot``); existing files are
        never replaced unless ``overwrite``.
    rig : {"dome", "rings", "rotating", "shiny"}
        See :func:`coded_rig`. The solder joint needs sources in its profile
        plane: ``"rotating"`` (``ScanObject.rig``); under the dome one source
        mirrors on it.
    n_sources : int
    code : {"sequential", "binary", "gray", "hadamard"}
        Gray codewords go along :func:`~shinysim.theory.coding.spatial_order`.
    complementary : bool
        Binary and Gray: each bit frame followed by its complement.
    object : {"sphere", "step", "solder"}
        See :func:`scan_object`.
    alpha : float
        Roughness of the sphere or part.
    resolution, spp, seed : int
        Image size (pixels), samples per pixel, seed of the render and the sensor.
    sensor : str, Sensor or None
        The coded frames' sensor (a preset name; None or ``"ideal"``: float frames).
    exposure : float
        With a sensor: the fraction of the full well the brightest *coded*
        pixel fills.
    crosstalk : float, optional
        The decoder's crosstalk tolerance (``DecodeParams.crosstalk``;
        default ``0.8 / bits``).
    surface : bool
        Also integrate the decoded normals and write ``surface.npz``.
    progress : callable, optional
        ``progress(stage, done, total)`` after each stage and
        ``progress("info", 0, 0, message)``.
    plot : bool
    colours : {1, 3}
        3: red, green and blue fibers and a colour camera (colour
        multiplexing, ``docs/coded-scanning.md``): the scene renders in
        colour, ``coded.npz`` holds RGB frames, and ``stack.exr`` holds
        each source's frame in its own fiber's colour channel (the
        sequential reference).
    rim_deg : float, optional
        The dome's or the rings' rim (:func:`coded_rig`); beyond 90 degrees
        the array reaches below the object.

    Returns
    -------
    dict
        The content of ``score.json``: ``decoding`` (pairing with the
        sequential scan: paired, errors, error_rate, spurious, missed,
        radius_px; pixel errors; the decoder's counts, collisions and
        saturated pixels among them), ``frames`` (used vs sequential),
        ``normals`` per model against the truth, ``best_model``,
        ``coded_vs_sequential``, ``surface`` (``anchored`` height RMS,
        ``integrators``, ``coverage`` of the visible and the reachable
        surface), ``sequential`` (the sequential scan's normal errors), the
        options, ``seconds`` per stage.

    Raises
    ------
    OptionError
        Bad options, before any work (:func:`check_coded_options`).
    """
    the_rig, the_code, the_sensor = check_coded_options(
        rig=rig, n_sources=n_sources, code=code, complementary=complementary, object=object, alpha=alpha,
        resolution=resolution, spp=spp, seed=seed, sensor=sensor, exposure=exposure, crosstalk=crosstalk,
        colours=colours, rim_deg=rim_deg)
    from ...sim.coded import coded_stack
    from ...sim.render import Simulator
    from ...sim.variants import choose_variant

    choose_variant(None)
    names = [n for n in CODED_FILES if (surface or n != "surface.npz") and (plot or n != "coded.png")]
    stages = ["scene", "render", "sequential", "code", "decode", "score", "write"] + (["figure"] if plot else [])
    seconds = {}
    clock = [time.perf_counter()]

    def done(stage):
        now = time.perf_counter()
        seconds[stage] = round(now - clock[0], 3)
        clock[0] = now
        if progress:
            progress(stage, stages.index(stage) + 1, len(stages))

    with output_folder(out, names, overwrite=overwrite,
                       needed_bytes=_coded_bytes(the_rig, the_code.n_frames, the_code.colours),
                       last="score.json") as tmp:
        obj = scan_object(object, alpha=alpha, folder=tmp)
        the_rig = the_rig.with_anchor(obj.anchor)
        sim = Simulator(the_rig, obj.objects, colour=the_code.colours == 3)
        done("scene")
        truth = sim.render_truth()
        if the_code.colours == 3:
            rgb = sim.render_colour_stack(spp=spp, seed=seed)
            # the sequential reference: each source seen in its own fiber's colour
            own = rgb.frames[np.arange(rgb.n_sources), ..., the_code.channels]
            stack = Stack(np.ascontiguousarray(own), rgb.rig, rgb.camera_index,
                          {**rgb.provenance, "channel": "each source's fiber colour"})
        else:
            rgb = None
            stack = sim.render_stack(spp=spp, seed=seed)
        done("render")
        save_stack(stack, tmp / "stack.exr")
        save_truth(truth, tmp / "truth.exr")
        stack = load_stack(tmp / "stack.exr")  # score what the folder holds
        truth = load_truth(tmp / "truth.exr", stack.camera)
        seq = reconstruct(stack, obj.detect_params(the_rig.camera))
        seq_n = table_normals(seq.table, the_rig, the_rig.anchor)
        seq_scores = {m: _normal_errors(seq.table, n, truth) for m, n in seq_n["normals"].items()}
        done("sequential")
        coded = coded_stack(stack if rgb is None else rgb, the_code, sensor=the_sensor,
                            exposure=exposure if the_sensor else None, seed=seed)
        del rgb
        done("code")
        dec = decode(coded, crosstalk=crosstalk, **obj.decode_settings(the_rig.camera))
        done("decode")
        owner = pixel_owner(stack.frames)
        score = score_coded(dec, seq, the_code, the_rig, truth, owner, obj, seq_normals=seq_n)
        surf = score.pop("_surface")
        dec_n = score.pop("_normals")
        if not surface:
            score.pop("surface")
        done("score")
        score.update({
            "sequential": {"highlights": len(seq), "normals": seq_scores, "best_model": seq_n["best"],
                           "detect": {k: getattr(obj.detect_params(the_rig.camera), k) for k in DETECT_FIELDS}},
            "pairing": "each decoded highlight is paired with the sequential highlight (same render, one source "
                       "per frame, ideal frames) nearest to its centroid within radius_px, half the smallest "
                       "distance between two sequential highlights (at most 3 px); a paired highlight with "
                       "another source is an error; unpaired decoded ones are spurious, unpaired sequential "
                       "ones missed. Pixel errors: decoded source differs from the source giving the pixel "
                       "the most light",
            "coverage_note": "a mirror under a dome whose rim is at polar angle a, seen from the axis, shows "
                             "normals up to a/2 only; 'reachable' is the part of the visible surface a perfect "
                             "scan could cover (sin^2(a/2) of a sphere's disc)",
            "code": the_code.to_dict() | {"order": "see code.json"},
            "decode_notes": dec.notes, "noise": {k: v for k, v in dec.noise.items() if k in ("k", "crosstalk")},
            "rig": {"preset": rig, "n_sources": the_rig.n_sources, "metadata": the_rig.metadata},
            "object": object, "alpha": alpha, "resolution": resolution, "spp": spp, "seed": seed,
            "colours": the_code.colours,
            "colour": coded.provenance.get("colour"),
            "sensor": None if coded.sensor is None else coded.sensor.to_dict(),
            "exposure": exposure if the_sensor else None, "render_seconds": sim.last_render_seconds,
        })
        write_coded_scan(tmp, coded, score["sequential"]["detect"])
        dec.table.write_csv(tmp / "highlights.csv", dec_n["normals"])
        if surface and surf is None:
            np.savez_compressed(tmp / "surface.npz", x=np.zeros(0), y=np.zeros(0), z=np.zeros((0, 0)))
        elif surface:
            x0, y0 = surf.xy.min(0)
            x1, y1 = surf.xy.max(0)
            step = 2.0 * the_rig.camera.pixel_pitch
            gx = np.arange(x0, x1 + 0.5 * step, step)
            gy = np.arange(y0, y1 + 0.5 * step, step)
            np.savez_compressed(tmp / "surface.npz", x=gx, y=gy, z=surf.height_map(gx, gy, interpolation="normals"),
                                points_xy=surf.xy,
                                points_z=surf.z, normals=surf.normals, triangles=surf.triangles)
        done("write")
        score["seconds"] = dict(seconds)
        write_json(tmp / "score.json", score)
        if plot:
            fig = coded_figure(coded, dec, truth, the_rig, score, surf, obj)
            write_file(tmp / "coded.png", lambda f: fig.savefig(f, dpi=100, format="png"))
            import matplotlib.pyplot as plt

            plt.close(fig)
            done("figure")
    score["seconds"] = dict(seconds)
    return json_safe(score)


# -- a given folder ---------------------------------------------------------------------------


def decode_folder(folder: str | os.PathLike, *, code: Code | str | None = None, crosstalk: float | None = None
                  ) -> Decoded:
    """Decode the coded frames of a coded scan folder (``coded.npz``, ``code.json``, ``stack.exr``'s rig).

    Parameters
    ----------
    folder : path-like
    code : Code or str, optional
        The code the frames were taken with (default: the folder's
        ``code.json``); a name builds it for the rig's sources.
    crosstalk : float, optional
        The decoder's crosstalk tolerance (``DecodeParams.crosstalk``;
        default ``0.8 / bits``).

    The decoder detects and subdivides as the scan's sequential detection
    did, and takes the sensor's black level and shot noise as the scan did:
    ``code.json``'s ``decode`` settings (:func:`shinysim.io.coded.read_coded_scan`;
    a folder written before them: ``score.json``'s ``sequential.detect`` and
    the sensor of ``coded.npz``; the defaults without either).

    Raises
    ------
    OptionError
        A code whose frame count or source count does not match the
        folder's frames or stack (field ``code``); ``decode.detect`` that is
        not a detection's settings.
    """
    make = (lambda rig, colours: study_code(code, rig, colours=colours)) if isinstance(code, str) else None
    coded, settings = read_coded_scan(folder, code=None if make else code, make_code=make)
    det = settings.pop("detect", None)
    try:
        if det is not None:
            settings.update(decode_settings(DetectParams(**det)))
    except (ValueError, TypeError) as exc:
        raise OptionError(f"decode.detect: not the settings of a detection ({exc})",
                          field=str(Path(folder) / "code.json")) from None
    return decode(coded, crosstalk=crosstalk, **settings)
