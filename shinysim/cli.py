"""``shinysim`` command line.

::

    shinysim scan --out DIR [--alpha 0.02] [--camera perspective] [--sensor machine_vision_12bit] ...
    shinysim scan --out DIR --rig dome [--n-sources 200] --code gray|binary|hadamard|sequential ...
    shinysim reconstruct DIR                       (a scan folder)
    shinysim reconstruct --rig RIG.json --frames F0.png F1.png ... --out DIR
    shinysim reconstruct --diligent DIR --out OUT     (a DiLiGenT folder)
    shinysim score DIR [--sphere-radius MM]
    shinysim figures OUT [--quick] [--overwrite]
    shinysim stereo --out DIR [--scene sphere] [--rig dome] [--beta 15] [--n-sources 1000] ...
    shinysim exposure --out DIR [--quick]
    shinysim solder --out DIR [--n-train 16] [--n-test 16] [--resolution 256] [--spp 16] ...
    shinysim inspect --out DIR [--n-train 80] [--n-test 100] [--resolution 256] [--spp 4] [--cache F] ...
    shinysim calibrate camera --rig NOMINAL.json --plates placements.json --out CAMERA.json
    shinysim calibrate sources --rig CAMERA.json --spheres spheres.json --out CALIBRATED.json
    shinysim calibrate study --out DIR [--quick]
    shinysim dataset SPEC.json --out DIR [--workers N] [--scheduler ADDRESS] [--items 0:100] ...
    shinysim dataset item SPEC.json INDEX --out DIR          (one item alone, as the data set has it)
    shinysim dataset export --format diligent SRC --out DIR  (an item folder or a whole data set)
    shinysim deflect --sofast DIR --out OUT [--expected FILE | --no-expected] [--align centre|none]
    shinysim deflect --sofast DIR --ensemble E.json --facet F.json --known-dot X Y IX IY ... --out OUT
    shinysim deflect --twin --out OUT [--size small|full] [--spp 256] [--sofast DIR]
    shinysim deflect --sofast DIR --mode fringe --out OUT   (phase-shifted fringes)

Heavy modules (Mitsuba, matplotlib) are imported inside the commands that
need them, so ``reconstruct`` and ``score`` run without a renderer.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from .errors import OptionError, ShinysimError

__all__ = ["main", "run"]


def _version_text():
    """shinysim's version, Python's, and the renderer's (Mitsuba, Dr.Jit and the variant it would use)."""
    import platform
    from importlib import metadata

    from . import __version__

    lines = [f"shinysim {__version__} (Python {platform.python_version()})"]
    versions = []
    for dist in ("numpy", "scipy", "scikit-image", "mitsuba", "drjit", "h5py"):
        try:
            versions.append(f"{dist} {metadata.version(dist)}")
        except metadata.PackageNotFoundError:
            versions.append(f"{dist} not installed")
    lines.append(", ".join(versions))
    try:
        from .sim.variants import choose_variant

        name, reason = choose_variant()
        lines.append(f"renderer variant: {name} ({reason})")
    except Exception as exc:  # the reconstruction half runs without a renderer: say why there is none
        lines.append(f"renderer: not usable ({exc}); pip install 'shinysim[render]'")
    return "\n".join(lines)


def _detect_args(p):
    from .recon.detect import CENTROID_METHODS, SATURATED_POLICIES, THRESHOLD_MODES, DetectParams

    DEFAULT = DetectParams()
    g = p.add_argument_group("highlight detection (defaults: derived from the frames; see docs/bad-input.md)")
    g.add_argument("--threshold", type=float, default=None,
                   help=f"I0: fraction of each frame's peak (relative) or a level (absolute) [{DEFAULT.threshold:g}]")
    g.add_argument("--threshold-mode", choices=THRESHOLD_MODES, default=None, help=f"[{DEFAULT.threshold_mode}]")
    g.add_argument("--min-area", type=int, default=None,
                   help="smallest highlight, pixels [1/8 of the stack's median highlight area]")
    g.add_argument("--max-area", type=int, default=None,
                   help="subdivide highlights larger than this many pixels [never]")
    g.add_argument("--centroid", choices=CENTROID_METHODS, default=None, help=f"[{DEFAULT.centroid}]")
    g.add_argument("--saturation", type=float, default=None,
                   help="sensor clip level [1.0 for 8/16-bit frames, none for float frames]")
    g.add_argument("--saturated", choices=SATURATED_POLICIES, default=None,
                   help=f"highlights that reach the clip level: flag them, refuse the frame, or neither [{DEFAULT.saturated}]")
    g.add_argument("--false-alarm", type=float, default=None,
                   help=f"noise highlights tolerated per frame; sets the noise floor (0: off) [{DEFAULT.false_alarm:g}]")
    g.add_argument("--keep-hot-pixels", action="store_true", help="do not replace hot pixels")


_DETECT_OPTIONS = ("threshold", "threshold_mode", "min_area", "max_area", "centroid", "saturation", "saturated",
                   "false_alarm")


def _detect_params(args, base=None):
    """DetectParams from the options given (over ``base``, default the defaults), or None when none was."""
    import dataclasses

    from .recon import DetectParams

    given = {k: getattr(args, k) for k in _DETECT_OPTIONS if getattr(args, k) is not None}
    if args.keep_hot_pixels:
        given["hot_pixels"] = False
    if not given:
        return None
    return dataclasses.replace(base, **given) if base is not None else DetectParams(**given)


_BARS = []


class _Progress:
    """One tqdm bar over a job's stages, on stderr."""

    def __init__(self, quiet=False, desc="scan", unit="step"):
        self.quiet, self.desc, self.unit, self.bar = quiet, desc, unit, None

    def __call__(self, stage, done, total, message=None):
        if self.quiet:
            return
        if message is not None:
            print(message, file=sys.stderr)
            return
        from tqdm import tqdm

        if self.bar is None:
            self.bar = tqdm(total=total, desc=self.desc, unit=self.unit, file=sys.stderr)
            _BARS.append(self.bar)
        self.bar.set_postfix_str(stage)
        self.bar.update(done - self.bar.n)
        if done >= total:
            self.bar.close()
            if self.bar in _BARS:
                _BARS.remove(self.bar)


def _num(v, width, digits=3, scale=1, dash=None):
    """A table cell: ``v * scale`` fixed-point, ``width`` wide; "-" (``dash`` wide, default ``width``) for None."""
    return f"{v * scale:{width}.{digits}f}" if v is not None else f"{'-':>{dash or width}}"


def _print_models(score):
    print(f"{'model':<14}{'n':>5}{'mean°':>9}{'median°':>9}{'p95°':>9}{'max°':>9}{'%err':>8}{'centre µm':>11}")
    for m, s in score["models"].items():
        print(f"{m:<14}{s['n']:>5}" + "".join(_num(s.get(k), w) for k, w in (
            ("mean_deg", 9), ("median_deg", 9), ("p95_deg", 9), ("max_deg", 9), ("percent_mean", 8)))
              + _num(s.get("centre_error_mm"), 11, 2, 1000))
    print(f"best model: {score['best_model']}" if score["best_model"] is not None
          else "best model: none (no highlight was scored)")


def _warnings(command, n_saturated, notes):
    """On stderr: the saturated highlights, then the detection's notes."""
    if n_saturated:
        print(f"shinysim {command}: warning: {n_saturated} highlight(s) reach the sensor's clip level or lie in a "
              "frame whose peak does; their centres may be off (flagged 'saturated' in highlights.csv; lower the "
              "exposure, or pass --saturated refuse)", file=sys.stderr)
    for note in notes:
        print(f"shinysim {command}: note: {note}", file=sys.stderr)


def _no_highlights(command):
    print(f"shinysim {command}: error: no highlight was found, so nothing was scored "
          "(see the detection options, or the frames)", file=sys.stderr)
    return 1


def _coded_scan(args):
    from .studies.coded import format_coded_table, run_coded_scan

    if args.object not in ("sphere",):
        raise SystemExit(f"shinysim scan: --object {args.object} is not offered with --rig/--code")
    score = run_coded_scan(
        args.out, rig=args.rig, n_sources=args.n_sources, code=args.code or "sequential",
        complementary=not args.no_complement, alpha=args.alpha, resolution=args.resolution, spp=args.spp,
        seed=args.seed, sensor=None if args.sensor == "ideal" else args.sensor, exposure=args.exposure,
        crosstalk=args.crosstalk, overwrite=args.overwrite, progress=_Progress(args.quiet), plot=not args.no_plot,
        colours=args.colours, rim_deg=args.rim_deg,
    )
    print(f"coded scan: rig={args.rig} sources={score['rig']['n_sources'] if 'rig' in score else args.n_sources} "
          f"code={args.code or 'sequential'}{' colours=3 (RGB fibers)' if args.colours == 3 else ''} "
          f"{args.resolution}x{args.resolution} spp={args.spp} seed={args.seed}")
    print(format_coded_table(score))
    print(f"wrote {args.out}/")
    return 0 if score["decoding"]["highlights"] else _no_highlights("scan")


def cmd_scan(args):
    from .studies.scan import run_scan

    if args.rig != "shiny" or args.code is not None or args.colours != 1 or args.rim_deg is not None:
        return _coded_scan(args)

    score = run_scan(
        args.out, alpha=args.alpha, projection=args.camera, resolution=args.resolution, spp=args.spp,
        seed=args.seed, variant=args.variant, method=args.method, detect=_detect_params(args),
        overwrite=args.overwrite, progress=_Progress(args.quiet), plot=not args.no_plot, sensor=args.sensor,
        exposure=args.exposure,
    )
    prov = score["provenance"]
    sensor = "" if score["sensor"] is None else f" sensor={args.sensor} exposure={args.exposure:g}"
    print(f"sphere scan: alpha={args.alpha} camera={args.camera} {args.resolution}x{args.resolution} "
          f"spp={args.spp} seed={args.seed} variant={prov['variant']}{sensor}")
    det = score["detection"]
    print(f"{score['n_highlights']} highlights from {21 - len(score['empty_sources'])} of 21 sources "
          f"(min area {det['min_area']} px, noise floor {det['noise_k']:.1f} sigma, {det['hot_pixels']} hot pixels)")
    _warnings("scan", det["n_saturated"], score["notes"])
    _print_models(score)
    print(f"wrote {args.out}/: rig.json stack.exr truth.exr highlights.csv score.json"
          + ("" if args.no_plot or score["best_model"] is None else " scan.png"))
    return 0 if score["best_model"] is not None else _no_highlights("scan")


def cmd_stereo(args):
    from .recon.stereo import StereoParams
    from .studies.stereo import STEREO_DETECT, run_stereo

    params = StereoParams(**({} if args.d0_um is None else {"d0_mm": 1e-3 * args.d0_um}),
                          max_normal_gap_deg=args.max_normal_gap, relax=not args.no_relax)
    score = run_stereo(
        args.out, scene=args.scene, rig=args.rig, beta_deg=args.beta, alpha=args.alpha,
        projection=args.camera, resolution=args.resolution, spp=args.spp, n_sources=args.n_sources, seed=args.seed,
        sensor=args.sensor, exposure=args.exposure, params=params, detect=_detect_params(args, STEREO_DETECT),
        variant=args.variant, overwrite=args.overwrite, progress=_Progress(args.quiet), plot=not args.no_plot,
    )
    rig = score["rig"]
    print(f"stereo: scene={args.scene} rig={args.rig} ({rig['n_sources']} sources) beta={args.beta:g} "
          f"alpha={args.alpha} {args.resolution}x{args.resolution} spp={args.spp} seed={args.seed}")
    print(f"highlights {score['n_highlights'][0]} + {score['n_highlights'][1]}, candidate pairs "
          f"{score['n_candidates']}, matches {score['n_matches']}"
          + (f" ({score['reason']})" if score["reason"] else ""))
    print(f"{'':24s} {'position um (px-eq)':>26s} {'normal deg':>22s}")
    print(f"{'':24s} {'median':>12s} {'p95':>13s} {'median':>10s} {'p95':>11s}")

    def row(name, p, n):
        print(f"{name:24s} {p['median']:7.1f} ({p['median_px']:5.2f}) {p['p95']:7.1f} ({p['p95_px']:5.2f}) "
              f"{n['median']:10.3f} {n['p95']:11.3f}")

    if score["n_matches"]:
        row("stereo", score["position_error_um"], score["normal_error_deg"])
    else:
        print(f"{'stereo':24s} no matches: {score['reason']}")
    for model, s in score.get("single_camera", {}).items():
        row(f"single: {model}", s["position_error_um"], s["normal_error_deg"])
    if score["n_matches"]:
        print(f"false-match rate {100 * score['false_match_rate']:.2f} % (farther than "
              f"{score['false_match_tolerance_px']:g} px-eq)")
    if score["recall"] is not None:
        det = ", ".join(f"{100 * r:.1f} %" for r in score["detection_recall"])
        print(f"recall {100 * score['recall']:.1f} % of {score['matchable_truth']} exact highlights of camera 0 "
              f"with an exact camera-1 highlight within {score['matchable_px']:g} px-eq; detected: {det} of "
              f"each camera's {' and '.join(map(str, score['n_visible_truth']))} exact visible highlights")
    else:
        print(f"recall against exact highlights: none ({score['recall_basis']})")
    print(f"recall of the detected highlights {100 * score['recall_detected']:.1f} % of {score['n_matchable']} "
          f"with a camera-1 element within {score['matchable_px']:g} px-eq")
    b = score["spacing_bound"]
    if math.isfinite(b["lattice_gap_px"]):
        print(f"spacing bound: with these sources a camera-0 highlight lies a median {b['lattice_gap_px']:.2f} px "
              f"from camera 1's nearest (the normal turns {b['normal_turn_deg_per_px']:.3g} deg per pixel): "
              f"{100 * b['expected_matchable']:.1f} % within one pixel (docs/stereo.md)")
    print(f"wrote {args.out}/: rig.json stack*.exr truth*.exr highlights*.csv matches.csv stereo_score.json"
          + ("" if args.no_plot else " stereo.png"))
    return 0 if score["n_matches"] else 1


def _reconstruct_diligent(args, detect):
    from .studies.scan import reconstruct_diligent

    if not args.out:
        raise OptionError("--diligent needs --out DIR")
    if args.folder or args.frames or args.rig:
        raise OptionError("give --diligent DIR alone (not with a scan folder, --frames or --rig)")
    data, recon, score = reconstruct_diligent(args.diligent, args.out, detect=detect, overwrite=args.overwrite)
    print(f"{args.diligent}: {data.stack.n_sources} images, {len(recon)} highlights; sources without one: "
          f"{recon.empty_sources or 'none'}")
    _warnings("reconstruct", recon.detection["n_saturated"], recon.notes)
    if score:
        for model, s in score["models"].items():
            if s["n"]:
                print(f"  {model:<12} n={s['n']:<4} median {s['median_deg']:.3f} deg  p95 {s['p95_deg']:.3f} deg"
                      "  (against Normal_gt)")
    print(f"wrote {Path(args.out) / 'highlights.csv'}" + (" and score.json" if score else ""))
    return 0


def cmd_reconstruct(args):
    from .rig import Anchor
    from .studies.scan import reconstruct_folder, reconstruct_frames

    detect = _detect_params(args)
    if args.anchor_point is None and args.anchor_normal is not None:
        raise OptionError("--anchor-normal needs --anchor-point")
    anchor = None if args.anchor_point is None else Anchor.at_point(args.anchor_point, normal=args.anchor_normal)
    if args.diligent:
        return _reconstruct_diligent(args, detect)
    if args.frames and not (args.rig and args.out):
        raise OptionError("--frames needs --rig RIG.json and --out DIR")
    if args.frames and args.folder:
        raise OptionError("give a scan folder or --frames, not both")
    if not (args.frames or args.folder):
        raise OptionError("give a scan folder, or --frames with --rig and --out")
    out = Path(args.out or args.folder)
    if args.frames:
        recon = reconstruct_frames(args.frames, args.rig, args.out, detect=detect, anchor=anchor, channel=args.channel,
                                   overwrite=args.overwrite)
    else:
        recon = reconstruct_folder(args.folder, out=out, rig=args.rig, detect=detect, anchor=anchor,
                                   overwrite=args.overwrite)
    det = recon.detection
    print(f"{len(recon)} highlights (min area {det['min_area']} px, noise floor {det['noise_k']:.1f} sigma, "
          f"{det['hot_pixels']} hot pixels); sources without one: {recon.empty_sources or 'none'}")
    _warnings("reconstruct", det["n_saturated"], recon.notes)
    print(f"wrote {out / 'highlights.csv'} (normals under models: {', '.join(recon.models)})")
    return 0


def cmd_score(args):
    from .studies.scan import score_folder

    score = score_folder(args.folder, detect=_detect_params(args), sphere_radius=args.sphere_radius,
                         overwrite=args.overwrite)
    print(f"highlights {score['highlights']}")
    _warnings("score", score["n_saturated"], score.get("notes", []))
    _print_models(score)
    print(f"wrote {Path(args.folder) / 'score.json'}")
    return 0 if score["best_model"] is not None else _no_highlights("score")


def cmd_exposure(args):
    from .studies.exposure import run_exposure

    result = run_exposure(args.out, quick=args.quick, overwrite=args.overwrite, variant=args.variant,
                          progress=_Progress(args.quiet, desc="exposure"))
    st = result["settings"]
    print(f"sphere scan (alpha={st['alpha']}, {st['resolution']} px, {st['spp']} spp) digitised by each sensor; "
          f"{len(st['seeds'])} noise seed(s) per exposure; errors in degrees, means over the seeds")
    print(f"{'sensor':<22}{'exposure':>9}{'centroid':>10}{'21 found':>9}{'clipped':>8}{'nf med':>8}{'nf p95':>8}"
          f"{'nf max':>8}{'fixed med':>10}")
    for r in result["rows"]:
        if "models" not in r:
            print(f"{r['preset']:<22}{r['exposure']:>9g}{r['centroid']:>10}   refused: {r['refusal']}")
            continue
        nf, fx = r["models"].get("near-field", {}), r["models"]["fixed"]
        print(f"{r['preset']:<22}{r['exposure']:>9g}{r['centroid']:>10}{r['exactly_21']:>6}/{r['runs'] - r['refused']:<2}"
              f"{r['mean_saturated']:>8.1f}{nf.get('median_deg', float('nan')):>8.3f}"
              f"{nf.get('p95_deg', float('nan')):>8.3f}{nf.get('max_deg', float('nan')):>8.3f}{fx['median_deg']:>10.3f}")
    print(f"wrote {Path(args.out) / 'exposure.json'}")
    return 0


def cmd_figures(args):
    from .studies.figures import make_figures

    captions = make_figures(args.out, quick=args.quick, overwrite=args.overwrite, progress=_Progress())
    for name in captions:
        print(f"wrote {Path(args.out) / name}")
    print(f"captions in {Path(args.out) / 'captions.json'} and {Path(args.out) / 'README.md'}")
    return 0


def cmd_solder(args):
    from .studies.solder import run_solder

    report = run_solder(
        args.out, n_train=args.n_train, n_test=args.n_test, kinds=tuple(args.kinds), resolution=args.resolution, spp=args.spp,
        seed=args.seed, interreflections=not args.direct_only, label=not args.no_labels, method=args.classifier,
        variant=args.variant, overwrite=args.overwrite, progress=_Progress(args.quiet, desc="solder"),
        plot=not args.no_plot, sensor=args.sensor, exposure=args.exposure,
    )
    print(f"solder joints: {args.n_train} training + {args.n_test} held-out per class, {args.resolution} px, "
          f"{args.spp} spp, inter-reflections {'off' if args.direct_only else 'on'}")
    print(f"{'class':<14}{'n':>4}{'RMS %H':>9}{'max %H':>9}{'max um':>9}{'cover':>7}{'normal°':>9}{'max°':>7}")
    for kind, c in report["classes"].items():
        rms, mx, ne = c["profile_height_rms_pct"], c["profile_height_max_error_pct"], c["normal_error_deg"]
        print(f"{kind:<14}{c['n_joints']:>4}{_num(rms['mean'], 9, 2)}{_num(mx['mean'], 9, 2)}"
              f"{_num(c['profile_height_max_error_mm']['max'], 9, 1, 1000)}{_num(c['coverage']['mean'], 7, 2, dash=9)}"
              f"{_num(ne['mean'], 9, 2)}{_num(ne['max'], 7, 2, dash=9)}")
    cm = report["confusion_matrix"]
    print(f"held-out accuracy {report['accuracy']:.3f} ({report['classification']['method']}); "
          "confusion matrix (rows true, columns predicted):")
    print(" " * 14 + "".join(f"{k[:8]:>9}" for k in cm["classes"]))
    for k, row in zip(cm["classes"], cm["counts"]):
        print(f"{k:<14}" + "".join(f"{v:>9}" for v in row))
    print(f"wrote {Path(args.out) / 'solder_report.json'}" + ("" if args.no_plot else
                                                               f" and {Path(args.out) / 'fig12_solder_profile.png'}"))
    return 0


def cmd_inspect(args):
    from .objects.criteria import AcceptanceCriteria
    from .studies.inspection import run_inspection, summary_lines

    criteria = AcceptanceCriteria(heel_fillet_fraction=args.heel_fillet_fraction,
                                  max_wetting_angle_deg=args.max_wetting_angle)
    report = run_inspection(
        args.out, n_train=args.n_train, n_test=args.n_test, resolution=args.resolution, spp=args.spp,
        seed=args.seed, method=args.classifier, criteria=criteria, variant=args.variant, overwrite=args.overwrite,
        cache=args.cache, progress=_Progress(args.quiet, desc="inspect"),
    )
    print("\n".join(summary_lines(report)))
    print(f"wrote {Path(args.out) / 'inspection_report.json'} and {Path(args.out) / 'robustness.csv'}")
    return 0


def cmd_calibrate(args):
    import statistics

    if args.what == "study":
        return _calibrate_study(args)
    if args.what == "camera":
        from .calibrate.from_files import camera_from_files

        estimate = tuple(e.replace("-", "_") for e in args.estimate) if args.estimate else None
        _, cal, n_images, estimate = camera_from_files(args.rig, args.plates, args.out, camera_index=args.camera_index,
                                                       estimate=estimate, pixel_sigma=args.pixel_sigma,
                                                       overwrite=args.overwrite)
        print(f"camera from {n_images} plate image(s), {cal.n_points} holes: estimated {', '.join(estimate)}; "
              f"reprojection RMS {cal.rms_px:.4f} px, max {cal.max_px:.4f} px")
        for name in cal.names:
            print(f"  {name:<22}{cal.parameters[name]:>16.8g}  +- {cal.sigma[name]:.3g}")
    else:
        from .calibrate.from_files import sources_from_files

        _, cal, n_scans = sources_from_files(args.rig, args.spheres, args.out, pixel_sigma=args.pixel_sigma,
                                             require_positions=args.require_positions, overwrite=args.overwrite)
        kinds = [str(k) for k in cal.solved]
        sigmas = [float(v) for v in cal.direction_sigma_deg if math.isfinite(v)]
        print(f"sources from {n_scans} sphere position(s): {kinds.count('position')} of {len(kinds)} placed in "
              f"3-D, {kinds.count('direction')} by direction only; pixel sigma {cal.pixel_sigma:.4f} px "
              f"({cal.pixel_sigma_source})")
        if sigmas:
            print(f"  direction 1-sigma: median {statistics.median(sigmas):.5f} deg, max {max(sigmas):.5f} deg")
    print(f"wrote {args.out}")
    return 0


def _calibrate_study(args):
    from .studies.calibration import QUICK_SETTINGS, run_calibration_study, summary_lines

    settings = {**(QUICK_SETTINGS if args.quick else {}),
                **{k: getattr(args, k) for k in ("resolution", "spp", "seed") if getattr(args, k) is not None}}
    report = run_calibration_study(args.out, variant=args.variant, overwrite=args.overwrite,
                                   progress=_Progress(args.quiet, desc="calibrate"), **settings)
    print("\n".join(summary_lines(report)))
    print(f"wrote {Path(args.out) / 'calibration_report.json'} and {Path(args.out) / 'calibration.png'}")
    return 0


def _parse_items(text):
    """``--items``: "0:100", "5", "3,7,9" or a mix ("0:10,42")."""
    try:
        out = [i for part in text.split(",")
               for i in (range(*map(int, part.split(":"))) if part.count(":") == 1 else [int(part)])]
    except ValueError:
        raise OptionError(f"--items {text!r}: give indices and ranges like 0:100,150,200:210") from None
    if any(i < 0 for i in out):
        raise OptionError(f"--items {text!r}: indices are >= 0")
    return out


def _deflect_mode(args):
    """``fixed`` or ``fringe``: as asked, else the kind of ``--measurement``, else what the folder holds."""
    if args.mode != "auto":
        return args.mode
    from .io import sofast

    if args.measurement:
        return sofast.measurement_kind(args.measurement)
    if args.sofast is None:
        raise OptionError("give --sofast DIR or --measurement FILE")
    found = sofast.read_sofast_folder(args.sofast)
    if found.fixed_measurement is not None or "fixed_measurement" in found.ambiguous:
        return "fixed"
    if found.fringe_measurement is not None or "fringe_measurement" in found.ambiguous:
        return "fringe"
    raise OptionError(f"{args.sofast}: holds no fixed-pattern or fringe measurement (measurement_*.h5)")


def _print_fringe(s):
    print(f"pixels: {s['pixels_region']} on the facet ({s['pixels_partial']} more see it only in part), "
          f"{s['pixels_valid']} decoded ({s['pixels_low_modulation']} below the noise, "
          f"{s['pixels_unwrap_inconsistent']} unwrapped inconsistently); frames' noise {s['noise_sigma']:.2f}")
    fx, fy = s["focal_lengths_m"]
    print(f"focal lengths {fx:.2f} m, {fy:.2f} m ({s['alignment']}-aligned; surface fit: {s['surface_fit']['from']})")
    sv = s.get("screen_vs_expected")
    if sv is not None:
        print(f"decoded screen positions at SOFAST's {sv['matched']} pixels: {sv['rms_screen_widths']:.2e} screen "
              f"widths RMS, {sv['unwrap_errors']} unwrapping errors ({sv['flagged_by_us']} of its pixels flagged here)")
    vs = s.get("vs_expected")
    if vs is not None:
        print(f"slopes at the {vs['matched']} pixels both decoded (of SOFAST's {vs['expected_pixels']}):")
        print(f"{'slope difference':<26}{'rms':>8}{'p95':>8}{'max':>8}{'>1 mrad':>9}")
        for label, d in (("as aligned (mrad)", vs), ("detilted (mrad)", vs["detilted"])):
            print(f"{label:<26}{d['rms_mrad']:8.3f}{d['p95_mrad']:8.3f}{d['max_mrad']:8.3f}{d['n_over_1mrad']:9d}")


def cmd_deflect(args):
    from .studies.deflect import run_render_facet, run_sofast_fixed, run_twin

    fringe_twin = args.twin and args.mode == "fringe"
    if not fringe_twin and (args.sensor is not None or args.gamma != 1.0):
        raise OptionError("--sensor and --gamma are for the fringe twin (--twin --mode fringe)")
    if fringe_twin and args.size != "small":
        raise OptionError("the fringe twin renders the small facet only (--size small)")
    if not args.twin and args.size != "small":
        raise OptionError("--size is for the twin (--twin)")
    if fringe_twin:
        from .studies.deflect import run_fringe_twin

        score = run_fringe_twin(args.out, folder=args.sofast, spp=args.spp or 256, seed=args.seed,
                                sensor=args.sensor, gamma=args.gamma, overwrite=args.overwrite)
        print(f"fringe twin: small facet, {score['geometry']} geometry, {score['image'][0]} x {score['image'][1]} px, "
              f"{score['spp']} spp, sensor {score['sensor'] or 'ideal'}, display gamma {score['gamma']:g}")
        print(f"{'pose':<14}{'decoded':>9}{'unwrap err':>12}{'pos rms px (x, y)':>20}{'slope rms':>11}"
              f"{'detilted':>10}  (display px; mrad, against the exact truth)")
        for label, d in (("true", score["given_pose"]), ("from corners", score["from_corners"])):
            dec, sl = d["decoding"], d["slopes"]
            pos = "{:.3f}, {:.3f}".format(*dec["rms_display_px"])
            print(f"{label:<14}{dec['valid']:>9}{dec['unwrap_errors']:>12}{pos:>20}{sl['rms_mrad']:>11.4f}"
                  f"{sl['detilted']['rms_mrad']:>10.4f}")
        for r in score.get("noise_table", []):
            m, law = r["measured_display_px"], r["law_display_px"]
            print(f"  {r['shifts']} shifts x {r['periods']}: {r['frames']} frames, sensor noise {m[0]:.4f}, "
                  f"{m[1]:.4f} px (law {law[0]:.4f}, {law[1]:.4f}), {r['unwrap_errors']} unwrap errors")
        print(f"wrote {args.out}/")
        return 0
    if args.twin:
        score = run_twin(args.out, folder=args.sofast, size=args.size, spp=args.spp, seed=args.seed,
                         overwrite=args.overwrite, plot=not args.no_plot)
        print(f"twin: {score['size']} facet, {score['geometry']} geometry, {score['image'][1]} x {score['image'][0]} "
              f"px, {score['spp']} spp ({score['render_seconds']:.1f} s)")
        print(f"{'pose':<14}{'identified':>11}{'wrong':>7}{'centroid px':>13}{'slope rms':>11}{'max':>8}"
              f"{'detilted rms':>14}{'max':>8}  (mrad, against the exact slopes)")
        for label, d in (("true", score["given_pose"]), ("from corners", score["from_corners"])):
            sl, dt = d["slopes"], d["slopes"]["detilted"]
            print(f"{label:<14}{d['identification']['identified']:>11}{d['identification']['wrong']:>7}"
                  f"{d['centroid_px']['rms']:>13.3f}{sl['rms_mrad']:>11.4f}{sl['max_mrad']:>8.4f}"
                  f"{dt['rms_mrad']:>14.4f}{dt['max_mrad']:>8.4f}")
        print(f"wrote {args.out}/")
        return 0
    if args.expected is not None and args.no_expected:
        raise OptionError("give --expected FILE or --no-expected, not both")
    mode = _deflect_mode(args)
    expected = False if args.no_expected else args.expected
    if mode == "fringe":
        if args.render_facet or args.ensemble or args.known_dot or args.dots:
            raise OptionError("--render-facet, --ensemble, --known-dot and --dots are for fixed-pattern (dot) "
                              "measurements; this is a fringe one")
        files = {"fringe_measurement": args.measurement, "fringe_camera": args.camera,
                 "image_calibration": args.calibration, "display_shape": args.display,
                 "spatial_orientation": args.orientation, "facet_definition": args.facet}
        from .studies.deflect import run_sofast_fringe

        result = run_sofast_fringe(args.sofast, args.out, files=files, expected=expected, align=args.align,
                                   overwrite=args.overwrite, plot=not args.no_plot)
        _print_fringe(result.score)
        print(f"wrote {args.out}/")
        return 0
    if args.calibration or args.display:
        raise OptionError("--calibration and --display are for fringe measurements; this is a fixed-pattern one")
    if args.sofast is None and not all((args.measurement, args.dots, args.camera, args.orientation, args.facet)):
        raise OptionError("give --sofast DIR, or every one of --measurement, --dots, --camera, --orientation, --facet")
    files = {"fixed_measurement": args.measurement, "dot_locations": args.dots, "camera": args.camera,
             "spatial_orientation": args.orientation, "facet_definition": args.facet,
             "ensemble_definition": args.ensemble}
    if args.render_facet:
        if args.no_plot or args.sofast is None:
            raise OptionError("--render-facet draws real_vs_render.png: it needs --sofast DIR and the plot")
        from ._shared import refuse_existing

        refuse_existing(Path(args.out) / "real_vs_render.png", args.overwrite)
    result = run_sofast_fixed(args.sofast, args.out, files=files, expected=expected, known_dots=args.known_dot,
                              align=args.align, overwrite=args.overwrite, plot=not args.no_plot)
    if args.render_facet:
        png = run_render_facet(result, args.sofast, Path(args.out) / "real_vs_render.png", spp=args.spp or 16,
                               seed=args.seed, overwrite=args.overwrite)
        print(f"wrote {png}")
    s = result.score
    print(f"dots: {s['dots_detected']} detected, {s['dots_cut']} cut by an edge, {s['dots_found']} found, "
          f"{s['dots_identified']} identified ({s['ambiguous']} ambiguous, {s['inconsistent']} inconsistent, "
          f"{s['left_out']} left out)")
    facets = s.get("facets") or [dict(s, alignment_turn_mrad=s["pose"]["alignment_turn_mrad"])]
    for k, f in enumerate(facets):
        fx, fy = f["focal_lengths_m"]
        who = "" if len(facets) == 1 else f"facet {k}: {f['dots_identified']} dots, "
        point = f", pointing {f['pointing_mrad'][0]:+.2f}, {f['pointing_mrad'][1]:+.2f} mrad" if "pointing_mrad" in f \
            else ""
        print(f"{who}focal lengths {fx:.2f} m, {fy:.2f} m ({s['alignment']}-aligned; the pose from the corners was "
              f"turned {f['alignment_turn_mrad']:.1f} mrad{point})")
    vs = s.get("vs_expected")
    if vs is not None:
        focal = ""
        if "expected_focal_lengths_m" in vs:
            focal = ", focal lengths {:.2f} m, {:.2f} m".format(*vs["expected_focal_lengths_m"])
        print(f"against {Path(vs['file']).name} ({vs['expected_points']} points{focal}): {vs['matched']} dots matched")
        print(f"{'slope difference':<26}{'rms':>8}{'p95':>8}{'max':>8}{'>1 mrad':>9}")
        for label, d in (("as aligned (mrad)", vs), ("detilted (mrad)", vs["detilted"])):
            print(f"{label:<26}{d['rms_mrad']:8.3f}{d['p95_mrad']:8.3f}{d['max_mrad']:8.3f}{d['n_over_1mrad']:9d}")
    print(f"wrote {args.out}/")
    return 0


def cmd_dataset(args):
    from .datasets.engine import run_dataset

    summary = run_dataset(args.spec, args.out, workers=args.workers, threads=args.threads,
                          scheduler=args.scheduler, retries=args.retries,
                          items=None if args.items is None else _parse_items(args.items), variant=args.variant,
                          timings=args.timings, progress=_Progress(args.quiet, desc="dataset", unit="item"))
    rate = summary["items_per_hour"]
    print(f"dataset {args.out}: {summary['done']} of {summary['n_items']} items done, {summary['rendered']} rendered "
          f"now in {summary['seconds']:.1f} s" + (f" ({rate:.0f} items/h)" if rate else ""))
    if summary["failed"]:
        shown = ", ".join(map(str, summary["failed"][:20])) + (" ..." if len(summary["failed"]) > 20 else "")
        print(f"shinysim dataset: {len(summary['failed'])} item(s) failed (errors in manifest.jsonl): {shown}; "
              "rerun the same command to retry them", file=sys.stderr)
        return 1
    return 0


def cmd_dataset_item(args):
    from .datasets.engine import build_one

    rel = build_one(args.spec, args.index, args.out, variant=args.variant, overwrite=args.overwrite)
    print(f"item {args.index} of {args.spec}: wrote {args.out}/ ({', '.join(rel)})")
    return 0


def cmd_dataset_export(args):
    from .datasets.export import export_diligent_folders

    written = export_diligent_folders(args.source, args.out, camera=args.camera, overwrite=args.overwrite)
    print(f"exported {len(written)} DiLiGenT folder(s) to {args.out}/")
    return 0


#: Options that several commands share: keywords of ``add_argument``, whose help a command may replace.
_SHARED = {
    "out": dict(required=True, help="output folder (existing files are never replaced)"),
    "alpha": dict(type=float, default=0.02, help="rough-conductor roughness [0.02]"),
    "variant": dict(default=None, help="Mitsuba variant [fastest available]"),
    "overwrite": dict(action="store_true", help=None),
    "no_plot": dict(action="store_true"),
    "quiet": dict(action="store_true", help="no progress bar"),
}
_REPLACE = "replace files already in --out"


def _shared(p, **helps):
    """Add the shared options named, in this order; a help other than True replaces the usual one."""
    for name, help in helps.items():
        kw = _SHARED[name] if help is True else {**_SHARED[name], "help": help}
        p.add_argument("--" + name.replace("_", "-"), **kw)


def _image(p, resolution, spp, size="image size, pixels", samples="samples per pixel", shown=None, seed=0,
           seed_help=None):
    """``--resolution``, ``--spp`` and ``--seed``; ``shown``: the defaults the help names, when not these."""
    r, s = shown or (resolution, spp)
    p.add_argument("--resolution", type=int, default=resolution, help=f"{size} [{r}]")
    p.add_argument("--spp", type=int, default=spp, help=f"{samples} [{s}]")
    p.add_argument("--seed", type=int, default=seed, help=seed_help)


def _sensor(p, frames, ideal="ideal", pixel="the brightest pixel"):
    from .sim.sensor import SENSOR_PRESETS

    p.add_argument("--sensor", choices=tuple(SENSOR_PRESETS), default="ideal",
                   help=f"camera sensor that digitises {frames} (docs/sensor.md) [{ideal}]")
    p.add_argument("--exposure", type=float, default=0.8,
                   help=f"with a sensor: fraction of its full well at {pixel} [0.8]")


def _joints(p, n_train, n_test):
    p.add_argument("--n-train", type=int, default=n_train, help=f"training joints per class [{n_train}]")
    p.add_argument("--n-test", type=int, default=n_test, help=f"held-out test joints per class [{n_test}]")


def _calibrated_rig(p, noise):
    p.add_argument("--pixel-sigma", type=float, default=None,
                   help=f"{noise} noise, px, for the uncertainties [from the residuals]")
    _shared(p, out="the calibrated rig JSON to write", overwrite=True)


def _defaults(fn):
    """The keyword defaults of a library entry point, which its command's options share."""
    import inspect

    return {k: p.default for k, p in inspect.signature(fn).parameters.items() if p.default is not p.empty}


def build_parser():
    # choices and defaults come from the library's own tuples, dataclasses and signatures
    from .calibrate.camera import ESTIMATE_GROUPS
    from .datasets.engine import run_dataset
    from .objects.criteria import AcceptanceCriteria
    from .io.frames import CHANNEL_REDUCTIONS
    from .objects.registry import STEREO_OBJECTS
    from .objects.solder import JOINT_KINDS
    from .recon.classify import CLASSIFIER_METHODS
    from .rig import SCAN_RIGS, STEREO_RIGS
    from .rig.core import CAMERA_PROJECTIONS
    from .studies.coded import run_coded_scan
    from .studies.inspection import run_inspection
    from .studies.scan import run_scan
    from .studies.solder import run_solder
    from .studies.stereo import run_stereo
    from .theory.coding import CODES

    p = argparse.ArgumentParser(prog="shinysim", description="Structured-highlight inspection: simulate, reconstruct, score.")
    p.add_argument("--version", action="store_true",
                   help="print shinysim's version and its libraries' (Mitsuba, Dr.Jit, the variant) and exit")
    sub = p.add_subparsers(dest="command")

    d = _defaults(run_scan)
    s = sub.add_parser("scan", help="render a sphere scan, reconstruct it and score the normals")
    _shared(s, out=True)
    s.add_argument("--object", choices=("sphere",), default="sphere", help="object to scan [sphere]")
    s.add_argument("--rig", choices=sorted(SCAN_RIGS, key=lambda r: r != "shiny"), default="shiny",
                   help="source array: the paper's 21 fibers, a Fibonacci dome, stacked rings, or the semicircle "
                        "turned about the axis (docs/coded-scanning.md) [shiny]")
    n_sources = _defaults(run_coded_scan)["n_sources"]
    s.add_argument("--n-sources", type=int, default=n_sources, help=f"sources of a dome or ring rig [{n_sources}]")
    s.add_argument("--rim-deg", type=float, default=None,
                   help="polar angle of a dome's or ring rig's rim from the camera axis, deg; beyond 90 the array "
                        "reaches below the object, the paper's spherical array (docs/coded-scanning.md) [80]")
    s.add_argument("--code", choices=CODES, default=None,
                   help="light several sources per frame and decode them (docs/coded-scanning.md) [one per frame]")
    s.add_argument("--no-complement", action="store_true",
                   help="binary/gray codes without their complementary frames (half the frames, weaker decoding)")
    s.add_argument("--crosstalk", type=float, default=None,
                   help="largest share of a bit's light from other sources still decoded [0.8 / bits]")
    s.add_argument("--colours", type=int, choices=(1, 3), default=1,
                   help="3: red, green and blue fibers and a colour camera, the code run per colour (colour "
                        "multiplexing, docs/coded-scanning.md) [1]")
    _shared(s, alpha=True)
    s.add_argument("--camera", choices=sorted(CAMERA_PROJECTIONS, key=lambda c: c != d["projection"]),
                   default=d["projection"], help=f"camera projection [{d['projection']}]")
    _image(s, d["resolution"], d["spp"], seed=d["seed"])
    _shared(s, variant=True)
    s.add_argument("--method", choices=("one-pass", "per-source"), default=None, help="stack renderer")
    _sensor(s, "the frames", ideal="ideal: float frames")
    _shared(s, overwrite=_REPLACE, no_plot="skip scan.png", quiet=True)
    _detect_args(s)
    s.set_defaults(func=cmd_scan)

    d = _defaults(run_stereo)
    st = sub.add_parser("stereo", help="structured-highlight stereo (paper Section V): render two cameras, "
                                       "match their highlights, score them beside the single-camera models")
    _shared(st, out=True)
    st.add_argument("--scene", choices=STEREO_OBJECTS,
                    default=d["scene"], help=f"object in the working volume (docs/stereo.md) [{d['scene']}]")
    st.add_argument("--rig", choices=tuple(STEREO_RIGS), default=d["rig"],
                    help="source array: a Fibonacci dome, a dense semicircle, the paper's 21 fibers, or two "
                         f"crossing 21-fiber arcs [{d['rig']}]")
    st.add_argument("--beta", type=float, default=d["beta_deg"],
                    help=f"each camera's angle from the vertical, deg [{d['beta_deg']:g}]")
    st.add_argument("--n-sources", type=int, default=d["n_sources"],
                    help=f"dome sources before the camera holes [{d['n_sources']}]")
    st.add_argument("--camera", choices=sorted(CAMERA_PROJECTIONS, key=lambda c: c != d["projection"]),
                    default=d["projection"], help=f"both cameras' projection [{d['projection']}]")
    _shared(st, alpha=True)
    _image(st, d["resolution"], d["spp"], seed=d["seed"])
    _sensor(st, "both stacks")
    st.add_argument("--d0-um", type=float, default=None,
                    help="closest-approach limit D0 of a candidate pair, micrometres [derived from the pixel size]")
    st.add_argument("--max-normal-gap", type=float, default=None,
                    help="largest angle between the two cameras' normals at a match, deg, the same for every pair "
                         "[derived per pair from the highlights' footprints, docs/stereo-matching.md]")
    st.add_argument("--no-relax", action="store_true", help="skip the smoothness (relaxation) step")
    _shared(st, variant=True, overwrite=_REPLACE, no_plot="skip stereo.png", quiet=True)
    _detect_args(st)
    st.set_defaults(func=cmd_stereo)

    r = sub.add_parser("reconstruct", help="highlights and normals from a stack or from image frames")
    r.add_argument("folder", nargs="?", help="scan folder with stack.exr and rig.json")
    r.add_argument("--rig", help="rig JSON (default: rig.json in the folder)")
    r.add_argument("--frames", nargs="+", help="one image per source, in source order")
    r.add_argument("--channel", choices=CHANNEL_REDUCTIONS, default=CHANNEL_REDUCTIONS[0])
    r.add_argument("--diligent", metavar="DIR", default=None,
                   help="a DiLiGenT folder (images, light_directions.txt, ...; docs/diligent.md): distant lights, "
                        "an orthographic view; scored against Normal_gt.mat when present (needs --out)")
    r.add_argument("--anchor-point", type=float, nargs=3, metavar=("X", "Y", "Z"), default=None,
                   help="a known surface point (mm) for the near-field model [the rig's anchor]")
    r.add_argument("--anchor-normal", type=float, nargs=3, metavar=("NX", "NY", "NZ"), default=None,
                   help="the known normal at --anchor-point [unknown]")
    r.add_argument("--out", help="output folder [the scan folder]")
    _shared(r, overwrite=True)
    _detect_args(r)
    r.set_defaults(func=cmd_reconstruct)

    c = sub.add_parser("score", help="score a scan folder's normals against its truth.exr")
    c.add_argument("folder")
    c.add_argument("--sphere-radius", type=float, default=None,
                   help="object is a sphere of this radius (mm) at the origin: also run the Fig. 10 centre test")
    _shared(c, overwrite=True)
    _detect_args(c)
    c.set_defaults(func=cmd_score)

    e = sub.add_parser("exposure", help="normal error against exposure for the 8-bit TV and 12-bit camera presets")
    _shared(e, out="output folder for exposure.json")
    e.add_argument("--quick", action="store_true", help="256 px, one seed, five exposures (about half a minute)")
    _shared(e, variant=True, overwrite=True, quiet=True)
    e.set_defaults(func=cmd_exposure)

    g = sub.add_parser("figures", help="regenerate the paper's figures (3-6, 9b, 10, 12-14, 16-18) as captioned PNGs")
    g.add_argument("out", help="output folder (existing files are never replaced)")
    g.add_argument("--quick", action="store_true",
                   help="small renders (about 10 s) instead of full ones (under a minute)")
    _shared(g, overwrite="replace files already in OUT")
    g.set_defaults(func=cmd_figures)

    joints = dict(size="image size over the 2 mm field, pixels", samples="samples per pixel per source")
    d = _defaults(run_solder)
    sj = sub.add_parser("solder", help="solder joints: generate, scan, reconstruct profiles, classify defects")
    _shared(sj, out=True)
    _joints(sj, d["n_train"], d["n_test"])
    sj.add_argument("--kinds", nargs="+", default=list(d["kinds"]), choices=JOINT_KINDS, help="classes [all five]")
    _image(sj, d["resolution"], d["spp"], seed=d["seed"], **joints)
    sj.add_argument("--classifier", choices=CLASSIFIER_METHODS, default=d["method"])
    sj.add_argument("--direct-only", action="store_true", help="render without inter-reflections (faster)")
    sj.add_argument("--no-labels", action="store_true",
                    help="skip the direct-only renders that label inter-reflection highlights")
    _shared(sj, variant=True)
    _sensor(sj, "each joint's frames", pixel="each joint's brightest pixel")
    _shared(sj, no_plot="skip fig12_solder_profile.png", overwrite=_REPLACE, quiet=True)
    sj.set_defaults(func=cmd_solder)

    d, criteria = _defaults(run_inspection), AcceptanceCriteria()
    ip = sub.add_parser("inspect", help="solder inspection: classes by acceptance criteria, nuisances in every draw, "
                                         "robustness table")
    _shared(ip, out=True)
    _joints(ip, d["n_train"], d["n_test"])
    _image(ip, d["resolution"], d["spp"], seed=d["seed"], **joints)
    ip.add_argument("--classifier", choices=CLASSIFIER_METHODS, default=d["method"])
    ip.add_argument("--heel-fillet-fraction", type=float, default=criteria.heel_fillet_fraction,
                    help=f"insufficient when the heel fillet F < G + this * T [{criteria.heel_fillet_fraction:g}: "
                         "IPC class 2; 1.0: class 3]")
    ip.add_argument("--max-wetting-angle", type=float, default=criteria.max_wetting_angle_deg,
                    help="excess when the wetting angle at the lead or pad exceeds this, degrees "
                         f"[{criteria.max_wetting_angle_deg:g}]")
    ip.add_argument("--cache", default=None,
                    help="JSON-lines file of finished joints: resume an interrupted run, rerun without rendering")
    _shared(ip, variant=True, overwrite=_REPLACE, quiet=True)
    ip.set_defaults(func=cmd_inspect)

    cal = sub.add_parser("calibrate", help="calibrate a rig: the camera from hole-plate images, the sources from "
                                           "mirror-sphere scans; or the study of what miscalibration costs")
    what = cal.add_subparsers(dest="what", required=True)
    cc = what.add_parser("camera", help="camera pose, focal length, principal point and distortion from images of "
                                        "the backlit hole plate (docs/calibration.md)")
    cc.add_argument("--rig", required=True, help="the nominal rig JSON (its camera is the starting point)")
    cc.add_argument("--plates", required=True, help="placements.json: the plate, its images and their placements")
    cc.add_argument("--estimate", nargs="+", choices=tuple(g.replace("_", "-") for g in ESTIMATE_GROUPS), default=None,
                    help="parameter groups [one image: pose; several: all four]")
    cc.add_argument("--camera-index", type=int, default=0, help="which camera of the rig [0]")
    _calibrated_rig(cc, "hole-centre")
    cs = what.add_parser("sources", help="each fiber's position (or direction) from scans of a mirror-like sphere "
                                         "at known positions (docs/calibration.md)")
    cs.add_argument("--rig", required=True, help="the rig JSON: its camera (calibrated) and nominal sources")
    cs.add_argument("--spheres", required=True, help="spheres.json: the sphere's radius, scans and centres")
    cs.add_argument("--require-positions", action="store_true",
                    help="refuse unless every fiber is placed in 3-D (needs two or more sphere positions)")
    _calibrated_rig(cs, "highlight-centre")
    st = what.add_parser("study", help="perturb the rig, render plate and sphere images, calibrate, and score the "
                                       "sphere scan with the nominal, calibrated and true rig")
    _shared(st, out=True)
    st.add_argument("--quick", action="store_true", help="256 px and fewer samples (about a minute)")
    _image(st, None, None, samples="samples per pixel of the calibration images", shown=(512, 32), seed=None,
           seed_help="draws the true rig and the noise [0]")
    _shared(st, variant=True, overwrite=True, quiet=True)
    for q in (cc, cs, st):
        q.set_defaults(func=cmd_calibrate)

    df = sub.add_parser("deflect", help="display deflectometry: a SOFAST fixed-pattern measurement (one frame of a "
                        "screen's dots reflected in a mirror facet) to slopes, scored against SOFAST's own result")
    df.add_argument("--sofast", metavar="DIR", default=None,
                    help="SOFAST's files: common/, fixed/ (and fringe/) as OpenCSP lays them out, or one flat folder; "
                         "the file options below name files the folder does not hold, or holds more than one of")
    df.add_argument("--mode", choices=("auto", "fixed", "fringe"), default="auto",
                    help="the measurement's kind: fixed (one frame of dots) or fringe (phase-shifted sinusoids) "
                         "[auto: --measurement's kind, else the folder's fixed-pattern one, else its fringe one]")
    for opt, what in (("--measurement", "the measurement (.h5), fixed or fringe"),
                      ("--dots", "the dot locations (.h5)"),
                      ("--camera", "the camera (.h5)"), ("--orientation", "the camera-screen orientation (.h5)"),
                      ("--facet", "the facet definition (OpenCSP's JSON)"),
                      ("--ensemble", "a facet-ensemble definition (OpenCSP's JSON): the measurement is an ensemble's"),
                      ("--calibration", "a fringe measurement's display response (image_calibration.h5)"),
                      ("--display", "a fringe measurement's display shape (display_*.h5)")):
        df.add_argument(opt, metavar="FILE", default=None, help=f"{what} [found in --sofast]")
    df.add_argument("--known-dot", type=float, nargs=4, action="append", metavar=("X", "Y", "IX", "IY"),
                    help="image x (column), y (row) of a dot and its grid index, once per facet (an ensemble needs "
                         "one for each) [the measurement's origin, index 0 0]")
    df.add_argument("--expected", metavar="FILE", default=None,
                    help="SOFAST's calculation file to score against [the folder's: expected_calculation_facet.h5, "
                         "or expected_data.h5 for fringes]")
    df.add_argument("--no-expected", action="store_true", help="score against nothing")
    from .recon.deflect import ALIGNMENTS

    df.add_argument("--align", choices=ALIGNMENTS, default=ALIGNMENTS[0],
                    help="centre: turn the fitted normal at the facet's centre onto its design normal (SOFAST's); "
                         "none: keep the pose from the corners [centre]")
    df.add_argument("--twin", action="store_true",
                    help="render the simulated twin of SOFAST's rig (a facet of known shape; its geometry from "
                         "--sofast when given, else built in), reconstruct it and score it against the exact truth")
    df.add_argument("--size", choices=("small", "full"), default="small",
                    help="--twin: a 240 mm cut of the facet (seconds) or the whole 1.212 m facet [small]")
    df.add_argument("--spp", type=int, default=None,
                    help="samples per pixel of a render [--twin: 256 small, 64 full; --render-facet: 16]")
    df.add_argument("--seed", type=int, default=0, help="render seed [0]")
    from .sim.sensor import SENSOR_PRESETS

    df.add_argument("--sensor", choices=tuple(k for k in SENSOR_PRESETS if k != "ideal"), default=None,
                    help="--twin --mode fringe: digitise the frames with this camera preset and add the noise "
                         "table [ideal: radiance]")
    df.add_argument("--gamma", type=float, default=1.0,
                    help="--twin --mode fringe: the display's response exponent, undone by the decoder [1]")
    df.add_argument("--render-facet", action="store_true",
                    help="also render the reconstructed facet in the real rig: real_vs_render.png (needs the "
                         "render extra)")
    _shared(df, out=True, overwrite=_REPLACE, no_plot="skip the figures")
    df.set_defaults(func=cmd_deflect)

    ds = sub.add_parser("dataset", help="render a synthetic data set from a JSON spec on Dask (resumable); "
                                        "also 'dataset item' and 'dataset export' (see docs/datasets.md)")
    ds.add_argument("spec", help="the data-set spec (JSON, docs/datasets.md)")
    _shared(ds, out="data-set folder: created, or finished if it holds part of this spec's items")
    ds.add_argument("--workers", type=int, default=None, help="local worker processes [one per core]")
    ds.add_argument("--threads", type=int, default=None, help="renderer threads per worker [cores / workers]")
    ds.add_argument("--scheduler", default=None, help="address of a running Dask scheduler (tcp://HOST:8786) "
                                                      "whose workers see --out at the same path")
    ds.add_argument("--items", default=None, help="only these items, e.g. 0:100,250 [all]")
    retries = _defaults(run_dataset)["retries"]
    ds.add_argument("--retries", type=int, default=retries,
                    help=f"retries of a failing item before it is recorded as failed [{retries}]")
    ds.add_argument("--timings", default=None, help="append per-item timings and worker memory (JSON lines) "
                                                    "to this file (kept out of the data-set folder)")
    _shared(ds, variant=True, quiet=True)
    ds.set_defaults(func=cmd_dataset)
    # 'dataset item' and 'dataset export' (main() routes them here): kept out of the command list, where
    # the dataset command's help names them
    di = sub.add_parser("dataset-item", prog="shinysim dataset item",
                        description="one item of a spec alone: the same bytes as in the data set")
    di.add_argument("spec")
    di.add_argument("index", type=int)
    _shared(di, out="folder for the item's files", variant=None, overwrite=True)
    di.set_defaults(func=cmd_dataset_item)
    de = sub.add_parser("dataset-export", prog="shinysim dataset export",
                        description="an item (scan) folder, or every item of a data set, as DiLiGenT folders")
    de.add_argument("source", help="an item (scan) folder or a data-set folder")
    de.add_argument("--format", choices=("diligent",), required=True)
    _shared(de, out=None)
    de.add_argument("--camera", type=int, default=0, help="camera of a multi-camera item [0]")
    _shared(de, overwrite=True)
    de.set_defaults(func=cmd_dataset_export)
    sub.metavar = "{" + ",".join(name for name in sub.choices if not name.startswith("dataset-")) + "}"
    return p


class _Terminated(BaseException):
    """SIGTERM, raised like Ctrl-C so that transactional outputs are cleaned up."""


def _interruption(exc):
    """The KeyboardInterrupt or SIGTERM behind ``exc`` (itself, its cause or context), or None."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, (KeyboardInterrupt, _Terminated)):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def _on_sigterm(signum, frame):
    _SIGNALLED.append(_Terminated())
    raise _Terminated()


def _on_sigint(signum, frame):
    _SIGNALLED.append(KeyboardInterrupt())
    raise KeyboardInterrupt


#: The interruptions received during the command: a library may catch one and raise something else
#: (trimesh turns a Ctrl-C during its import into a TypeError), and the run is still an interrupted one.
_SIGNALLED: list = []


def main(argv=None):
    """Run one command; bad input gives one line on stderr and exit status 1 (2 for usage),
    Ctrl-C one line and 130, SIGTERM one line and 143; an interrupted run leaves no partial output."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) >= 2 and argv[0] == "dataset" and argv[1] in ("item", "export"):
        argv = [f"dataset-{argv[1]}"] + argv[2:]  # the dataset command's two other forms
    import signal
    import threading

    # SIGTERM is turned into a clean interruption; signal handlers can only be set in the main thread
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _on_sigterm) if in_main else None
    previous_int = signal.signal(signal.SIGINT, _on_sigint) if in_main else None
    _SIGNALLED.clear()
    # who speaks in the one-line messages: the command, named from argv until the parser has read it
    who = " ".join(["shinysim", *(a.replace("-", " ") for a in argv[:1] if not a.startswith("-"))])
    try:
        parser = build_parser()  # its choices import the library (numpy, SciPy): Ctrl-C may come here
        args = parser.parse_args(argv)
        if args.version:
            print(_version_text())
            return 0
        if not args.command:
            parser.print_help()
            return 2
        who = f"shinysim {args.command.replace('-', ' ')}"
        return args.func(args)
    except Exception as exc:
        # Ctrl-C or SIGTERM behind it (Mitsuba's variant import raises a SystemError caused by the
        # KeyboardInterrupt), or received while it was raised (a library turned the interruption into it)
        cause = _interruption(exc) or (_SIGNALLED[0] if _SIGNALLED else None)
        if cause is not None:
            return _interrupted(who, cause)
        if not isinstance(exc, (ShinysimError, OSError)):
            raise
        # bad input; an unwritable, full or occupied output location
        text = str(exc)
        if isinstance(exc, OSError) and exc.strerror:  # "[Errno 28] ..." -> the words, with the file
            where = f"{exc.filename}: " if exc.filename and str(exc.filename) not in exc.strerror else ""
            text = f"{where}{exc.strerror}"
        print(f"{who}: error: {text}", file=sys.stderr)
        return 1
    except (KeyboardInterrupt, _Terminated) as exc:
        return _interrupted(who, exc)
    finally:
        if in_main:
            signal.signal(signal.SIGTERM, previous)
            signal.signal(signal.SIGINT, previous_int)


def _interrupted(who, cause):
    """The one line and the status of an interrupted run (its outputs are cleaned up already)."""
    for bar in _BARS:
        bar.close()
    end = "interrupted" if isinstance(cause, KeyboardInterrupt) else "terminated"
    print(f"{who}: {end}; no partial output was left", file=sys.stderr)
    return 130 if isinstance(cause, KeyboardInterrupt) else 143


def run():
    """The ``shinysim`` console command: :func:`main`, and its exit status.

    After Ctrl-C or SIGTERM (status 130 or 143; the run's outputs are
    already cleaned up) the process ends at once: the renderer's teardown
    could otherwise meet the interruption again and end the process by the
    signal instead of with the status. After a finished run, a late Ctrl-C
    during the teardown is ignored.
    """
    status = main()
    if status in (130, 143):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    # the run is over and its outputs are in place: a Ctrl-C during the interpreter's
    # teardown has nothing left to stop
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    sys.exit(status)


if __name__ == "__main__":
    run()
