"""Phase codes on the dome's discrete sources beside the binary and Gray codes: frames, decoding errors, normals.

    python scripts/phase_dome.py [--n-sources 200] [--resolution 256] [--spp 16]

One render of the sphere under the dome (``shinysim.studies.coded.pieces.render_scan``), then every code
under the ideal sensor and the two presets: the binary and Gray codes decoded by ``shinysim.recon.coding``,
the phase codes by ``phase_row`` (the dome as the display, each fiber dimmed to the code's value at its
direction). Prints a markdown table; ``docs/coded-scanning.md`` quotes it.
"""

from __future__ import annotations

import argparse
import time

from shinysim.sim.sensor import sensor_preset
from shinysim.studies.coded.pieces import code_row, phase_row, render_scan
from shinysim.theory.coding import make_code
from shinysim.theory.phase import PhaseCode

PHASE_CODES = (PhaseCode((0.9,), (0.9,), 3), PhaseCode((0.9,), (0.9,), 4), PhaseCode((0.9, 3.9), (0.9, 3.9), 3),
               PhaseCode((0.9, 3.9), (0.9, 3.9), 4))
SENSORS = (None, "machine_vision_12bit", "tv_1980s_8bit")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-sources", type=int, default=200)
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--spp", type=int, default=16)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    scan = render_scan("sphere", n_sources=args.n_sources, resolution=args.resolution, spp=args.spp)
    print(f"sphere under a {args.n_sources}-source dome, {args.resolution} px, {args.spp} spp "
          f"({time.perf_counter() - t0:.1f} s); sequential scan: {len(scan.sequential.table['source'])} highlights")
    print("| code | frames | sensor | highlights | errors | flagged | missed | spurious | normals median / p95 (deg) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for sensor in SENSORS:
        s = sensor_preset(sensor) if sensor else None
        rows = [code_row(scan, make_code(name, args.n_sources), sensor=s) for name in ("binary", "gray")]
        rows += [phase_row(scan, code, sensor=s) for code in PHASE_CODES]
        for r in rows:
            print(f"| {r['code']} | {r['frames']} | {sensor or 'ideal'} | {r['highlights']} | {r['errors']} | "
                  f"{r.get('flagged', '-')} | {r['missed']} | {r['spurious']} | "
                  f"{r.get('median_deg', float('nan')):.3f} / {r.get('p95_deg', float('nan')):.3f} |")


if __name__ == "__main__":
    main()
