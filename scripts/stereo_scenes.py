"""Structured-highlight stereo on a grid of scenes, arrays and cameras, scored against exact highlights.

Renders (once; a folder already there is reused) every combination of

* scenes: ``sphere`` (r = 0.79375 mm at (1.5, 0, 0.8) mm), ``three_sizes``
  (r = 1.2, 0.5, 0.8 mm at (-2.0, -2.2, 0.3), (0.3, 0.2, 1.0), (2.3, 2.4, -0.5) mm)
  and ``large_sphere`` (r = 5 mm, its top 2 mm above the reference plane);
* source arrays: ``shiny`` (the paper's 21 fibers on the x-z semicircle),
  ``crossing_arcs`` (two 21-fiber arcs, x-z and y-z, 41 sources) and ``dome``
  (1000 sources);
* cameras at +-beta about the vertical in the x-z plane, beta 15 and 30 degrees,
  perspective and orthographic;

with ``shinysim stereo``'s defaults otherwise (512 px over a 6 mm field, 16
spp, alpha 0.02), then analyses every folder with the current code
(:func:`shinysim.studies.stereo.analyse_stereo`: detection, matching and the
score against the exact highlights and surface) and writes ``table.md`` and
``table.json`` into the output folder: per configuration the exact visible
and matchable highlights, detection recall, recall, false-match rate,
position and normal error of the matches, the best single-camera model's
normal error on the same highlights, and, for the sparse arrays, the
spacing bound on what can be matched (``docs/stereo.md``).

    python scripts/stereo_scenes.py --out DIR [--scenes ...] [--rigs ...] [--betas 15 30]
        [--cameras perspective orthographic] [--resolution 512] [--spp 16] [--analyse-only]

The full grid renders 36 stereo scans (about an hour on two cores, most of
it the dome on the large sphere).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from shinysim.io import load_stack, load_truth
from shinysim.studies.stereo import analyse_stereo, run_stereo, stereo_object

SCENES = ("sphere", "three_sizes", "large_sphere")
RIGS = ("shiny", "crossing_arcs", "dome")


def folder_name(scene, rig, beta, camera):
    return f"{scene}-{rig}-b{beta:g}-{camera}"


def analyse(folder, scene):
    stacks = [load_stack(folder / "stack.exr"), load_stack(folder / "stack.camera1.exr")]
    truths = [load_truth(folder / "truth.exr", stacks[0].camera), load_truth(folder / "truth.camera1.exr",
                                                                              stacks[1].camera)]
    return analyse_stereo(stacks, truths, obj=stereo_object(scene))["score"]


def row_of(name, score):
    best = score.get("best_single_camera")
    single = score["single_camera"][best]["on_matched_highlights"]["normal_error_deg"]["median"] if best else None
    n = score["n_matches"]
    return {
        "config": name,
        "visible": score.get("n_visible_truth"),
        "matchable": score.get("matchable_truth"),
        "detection_recall": score.get("detection_recall"),
        "recall": score.get("recall"),
        "matches": n,
        "false_rate": score["false_match_rate"] if n else None,
        "position_px": score["position_error_um"]["median_px"] if n else None,
        "normal_deg": score["normal_error_deg"]["median"] if n else None,
        "single_best": best,
        "single_normal_deg": single,
        "lattice_gap_px": score["spacing_bound"]["lattice_gap_px"],
        "expected_matchable": score["spacing_bound"]["expected_matchable"],
        "measured_matchable": score["spacing_bound"]["measured_matchable"],
        "reason": score.get("reason"),
    }


def _fmt(v, pct=False, digits=3):
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    if isinstance(v, list):
        return "/".join(_fmt(x, pct, digits) for x in v)
    if pct:
        return f"{100 * v:.1f} %"
    return f"{v:.{digits}g}" if isinstance(v, float) else str(v)


def write_table(out, rows):
    (out / "table.json").write_text(json.dumps(rows, indent=1, default=float) + "\n")
    head = ("| configuration | visible | matchable | bound: gap px, share within 1 px (measured) | detected | "
            "recall | matches | false | position px | normal deg | best single-camera normal deg |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|\n")
    lines = [f"| {r['config']} | {_fmt(r['visible'])} | {_fmt(r['matchable'])} | "
             f"{_fmt(r['lattice_gap_px'])}, {_fmt(r['expected_matchable'], pct=True)} "
             f"({_fmt(r['measured_matchable'], pct=True)}) | "
             f"{_fmt(r['detection_recall'], pct=True)} | {_fmt(r['recall'], pct=True)} | {r['matches']} | "
             f"{_fmt(r['false_rate'], pct=True)} | {_fmt(r['position_px'])} | {_fmt(r['normal_deg'])} | "
             f"{_fmt(r['single_normal_deg'])} ({r['single_best'] or '-'}) |" for r in rows]
    (out / "table.md").write_text(head + "\n".join(lines) + "\n")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES)
    ap.add_argument("--rigs", nargs="+", default=list(RIGS), choices=RIGS)
    ap.add_argument("--betas", nargs="+", type=float, default=[15.0, 30.0])
    ap.add_argument("--cameras", nargs="+", default=["perspective", "orthographic"],
                    choices=("perspective", "orthographic"))
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--analyse-only", action="store_true", help="score the folders there, render nothing")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for scene in args.scenes:
        for rig in args.rigs:
            for beta in args.betas:
                for camera in args.cameras:
                    name = folder_name(scene, rig, beta, camera)
                    folder = args.out / name
                    if not (folder / "stereo_score.json").exists():
                        if args.analyse_only:
                            continue
                        run_stereo(folder, scene=scene, rig=rig, beta_deg=beta, projection=camera,
                                   resolution=args.resolution, spp=args.spp, plot=False)
                    row = row_of(name, analyse(folder, scene))
                    rows.append(row)
                    print(" ".join(f"{k}={_fmt(v)}" for k, v in row.items()), flush=True)
    write_table(args.out, rows)
    print(f"wrote {args.out / 'table.md'} and {args.out / 'table.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
