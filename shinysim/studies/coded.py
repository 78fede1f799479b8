r"""Coded dome scans: render once, light several sources per frame, decode, and make surfaces.

The scan of :mod:`shinysim.studies.scan` lights one of 21 fibers per frame.
This study lights a dome of hundreds of sources (:func:`shinysim.rig.dome`,
stacked rings, a rotating semicircle) with a *code*
(:mod:`shinysim.theory.coding`): binary and Gray codes tell 200 sources
apart in 16 frames, Hadamard multiplexing trades frames for signal to
noise. One render gives every source's frame; light adds, so the coded
frames are sums of them (:func:`shinysim.sim.coded.coded_stack`) taken
through a sensor. Decoding (:func:`shinysim.recon.coding.decode`) turns
them back into highlights, whose normals
(:mod:`shinysim.recon.nearfield`, anchored at a known point) are integrated
into a height map (:mod:`shinysim.recon.integrate`).

What is scored (``score.json`` of :func:`run_coded_scan`):

*Decoding.* Every highlight of the coded scan is paired with the highlight
of the sequential scan (the same render, one source per frame, ideal
sensor) whose centroid is nearest, if it lies within the *pairing radius*:
half the smallest distance between two sequential highlights (so no
decoded highlight can be near two of them), at most 3 px. A paired
highlight whose decoded source differs from the sequential highlight's is
a *decoding error*; an unpaired decoded highlight is *spurious*, an
unpaired sequential one *missed*. Per pixel, the decoded source is also
compared with the pixel's *owner*, the source that gives it the most light
in the ideal per-source frames.

*Crosstalk*. A rough mirror's highlight has tails (GGX falls off as the
inverse fourth power of the half-angle tangent): on the rendered sphere at
``alpha = 0.02`` a highlight's core holds 1-5 % of light from the other
199 sources, so in some bit frame *and* its complement there is light,
which a strict decoder (``crosstalk=0``) calls a collision at any noise
level, leaving almost nothing decoded. The scan is decoded with
:func:`~shinysim.recon.coding.decode`'s crosstalk tolerance
(``DecodeParams.crosstalk``, default ``0.8 / bits``, 0.1 for 200
sources): a pixel is decoded when, in every bit pair, the weaker frame
holds at most that fraction of the stronger (beyond noise), which for any
tolerance below ``1 / bits`` makes the decoded source the pixel's owner.
Light of two comparable sources is still a collision, flagged and never
labelled.

*Coverage.* With the camera on the axis, a mirror normal bisects the view
and the source direction, so a dome whose rim is at polar angle ``a``
lights normals up to ``a / 2`` only: on a sphere, the disc of radius ``R
sin(a / 2)`` of the image's disc of radius ``R``, a share ``sin^2(a / 2)``
(41 % for an 80 degree dome). Coverage is reported both ways: of the whole
visible surface and of the part the dome can reach (pixels whose view ray,
mirrored at the true normal, leaves within the rim's polar angle). A pixel
is covered when it lies inside the triangles of the highlights' surface
(:func:`~shinysim.recon.integrate.integrate_triangulated`, long edges
across gaps cut).

The rendering half needs the ``render`` extra; matplotlib is imported only
inside the plotting function.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._shared import (
    Progress,
    check_number,
    json_safe,
    named_check,
    output_folder,
    write_file,
    write_json,
)
from ..conventions import angle_between
from ..errors import OptionError, did_you_mean
from ..evaluate import error_stats, sample_truth, score_normals
from ..io import Stack, load_stack, load_truth, save_stack, save_truth
from ..recon import DetectParams, reconstruct
from ..recon.coding import Decoded, check_crosstalk, decode
from ..recon.integrate import (
    compare_integrators,
    integrate_triangulated,
)
from ..recon.nearfield import NEAR_FIELD, near_field_normals
from ..recon.normals import highlight_normals
from ..rig import Anchor, Rig, dome, rotating_semicircle, shiny_1988
from ..theory.coding import (
    CODES,
    COLOURS,
    MAX_SOURCES,
    Code,
    colour_channels,
    make_code,
    spatial_order,
)
from .scan import SCAN_LIMITS

__all__ = [
    "CODED_FILES",
    "CODED_OBJECTS",
    "CODED_RIGS",
    "STEP_PART",
    "STEP_DETECT",
    "SOLDER_DETECT",
    "SOLDER_SUBDIVIDE_MM2",
    "ScanObject",
    "check_coded_options",
    "coded_rig",
    "scan_object",
    "pixel_owner",
    "pair_highlights",
    "decoding_errors",
    "table_normals",
    "reachable_mask",
    "coverage",
    "surface_scores",
    "score_coded",
    "run_coded_scan",
    "decode_folder",
    "format_coded_table",
    "print_coded_table",
    "coded_figure",
    "snr_gain_measurement",
    "RenderedScan",
    "render_scan",
    "code_row",
]

#: Rigs of a coded scan: a Fibonacci dome, stacked rings, the SHINY
#: semicircle turned to several azimuths, the SHINY semicircle itself.
CODED_RIGS = ("dome", "rings", "rotating", "shiny")
#: Objects: the calibration sphere, a machined part with a step, a solder joint.
CODED_OBJECTS = ("sphere", "step", "solder")
#: Files a coded scan folder holds; none is ever silently replaced.
CODED_FILES = ("rig.json", "stack.exr", "coded.npz", "code.json", "truth.exr", "highlights.csv", "score.json",
               "surface.npz", "coded.png")

#: The machined part: ``z = z0 - (x^2 + y^2) / (2 crown) + step (1 + tanh(x / flank)) / 2``, mm. Two
#: crowned plateaus (a flat plateau has one normal and so mirrors at most one source of a dome;
#: a slight crown, radius 2.5 mm, shows it the dome) joined along x = 0 by a smooth flank 0.2 mm
#: high whose steepest slope, ``step / (2 flank)``, is 34 degrees: inside the 40 degrees an 80
#: degree dome reaches, so the flank is measured, not a gap.
STEP_PART = {"size_mm": 1.8, "z0_mm": 0.4, "crown_mm": 2.5, "step_mm": 0.2, "flank_mm": 0.15, "vertices": 241}
#: Detection of the part's sequential scan: half of the scan's brightest pixel, not of each frame's. Its
#: normals tilt at most ~20 degrees towards +x and +-y (34 towards -x on the flank), so of a 200-source
#: dome (normals to 40 degrees) about half the sources have no mirror point on it; their frames hold
#: only glossy tails and render noise, which a threshold relative to the frame's own peak turns into
#: false highlights (see :class:`ScanObject`).
STEP_DETECT = DetectParams(threshold=0.5, threshold_mode="scan")
#: Detection of the solder joint's sequential scan: half of the scan's brightest pixel, as the part's. The
#: joint is swept along y, so its normals lie in the x-z plane and only sources in that plane have a
#: mirror point on it (five fibers of the rotating semicircle, one of the 200-source dome, two of the rings); every
#: other frame holds glossy tails at most, which a frame-relative threshold takes for highlights.
SOLDER_DETECT = DetectParams(threshold=0.5, threshold_mode="scan")
#: Area (mm^2, at the object) above which a joint's highlight is subdivided (paper Section IV: "When the
#: size of a blob is relatively large, it is subdivided into smaller blobs"): the joint analysis' 12 px at
#: 128 px per mm (:class:`~shinysim.recon.highlights.HighlightParams`, ``analyse_joint``). A mirror
#: highlight on the joint is a streak across the whole fillet width in y (0.2 mm: the half vector turns by
#: about 0.1 degree out to its edges, less than the 0.34 degree a fiber's own size allows), one centroid
#: per streak would put every point on one line, and a surface needs them spread.
SOLDER_SUBDIVIDE_MM2 = 12 / 128**2



def _choice(name, value, choices):
    if not isinstance(value, str) or value not in choices:
        raise OptionError(f"unknown {name} {value!r}{did_you_mean(str(value), choices)}; {name}s are "
                          f"{', '.join(choices)}", field=name)
    return value


# -- rigs and objects -----------------------------------------------------------------------


def _rings_for(n_sources, max_polar_deg=80.0):
    """``(polar_deg, count)`` rings totalling ``n_sources``: ring polar angles evenly spaced, counts by circumference."""
    n_rings = max(1, int(round(math.sqrt(n_sources / math.pi))))
    polar = (np.arange(n_rings) + 1.0) * max_polar_deg / n_rings
    w = np.sin(np.radians(polar))
    counts = np.maximum(1, np.floor(n_sources * w / w.sum())).astype(int)
    counts[-1] += n_sources - counts.sum()
    if counts[-1] < 1:
        raise OptionError(f"{n_sources} sources are too few for {n_rings} rings", field="n_sources")
    return [(float(a), int(c)) for a, c in zip(polar, counts)]


#: Rim of the dome and ring rigs, degrees from the camera axis, unless a scan says otherwise.
DOME_RIM_DEG = 80.0


def check_rim(rig: str, rim_deg: float | None) -> float | None:
    """The dome's rim polar angle for ``rig`` (None for the semicircle rigs), checked.

    Raises
    ------
    OptionError
        (field ``rim_deg``) a rim outside (0, 180) degrees, or one given
        for a rig without a dome.
    """
    if rig not in ("dome", "rings"):
        if rim_deg is not None:
            raise OptionError(f"is {rim_deg!r}, but only the dome and rings rigs have a rim; the {rig} rig's "
                              "sources are fixed", field="rim_deg")
        return None
    if rim_deg is None:
        return DOME_RIM_DEG
    # beyond 180 degrees the cap would close on the camera axis below the object
    return named_check("rim_deg", check_number, rim_deg, lo=0, lo_open=True, hi=180, hi_open=True)


def coded_rig(rig: str = "dome", *, n_sources: int = 200, resolution: int = 512, anchor: Anchor | None = None,
              rim_deg: float | None = None) -> Rig:
    """The rig of a coded scan.

    Parameters
    ----------
    rig : {"dome", "rings", "rotating", "shiny"}
        ``dome``: :func:`~shinysim.rig.dome`, ``n_sources`` on a Fibonacci
        cap to ``rim_deg``. ``rings``: the same cap as stacked rings (about
        ``sqrt(n / pi)`` rings up to ``rim_deg``, counts in proportion to
        each ring's circumference). ``rotating``:
        :func:`~shinysim.rig.rotating_semicircle`, the 21 SHINY fibers at
        ``round(n_sources / 21)`` azimuths. ``shiny``:
        :func:`~shinysim.rig.shiny_1988` with ``n_sources`` fibers (at most 22).
    n_sources : int
    resolution : int
        Square image size, pixels.
    anchor : Anchor, optional
        The near-field model's known point.
    rim_deg : float, optional
        Polar angle of the dome's or the rings' rim from the camera axis
        (:data:`DOME_RIM_DEG` by default). Beyond 90 degrees the array
        reaches below the object, the paper's spherical array (Fig. 1): a
        mirror sphere under an axial camera shows normals up to
        ``rim_deg / 2``, ``sin^2(rim_deg / 2)`` of its image.

    Raises
    ------
    OptionError
        An unknown rig, a source count the rig cannot hold (field
        ``n_sources``), a bad rim (field ``rim_deg``).
    """
    _choice("rig", rig, CODED_RIGS)
    n = named_check("n_sources", check_number, n_sources, lo=1, hi=MAX_SOURCES, integer=True)
    rim = check_rim(rig, rim_deg)
    try:
        if rig == "dome":
            out = dome(n_sources=n, resolution=resolution, max_polar_deg=rim)
        elif rig == "rings":
            out = dome(layout="rings", rings=_rings_for(n, rim), resolution=resolution)
        elif rig == "rotating":
            out = rotating_semicircle(positions=max(1, round(n / 21)), resolution=resolution)
        else:
            if n > 22:
                raise OptionError(f"is {n}, but the SHINY semicircle holds at most 22 fibers 8 degrees apart "
                                  "above the horizon", field="n_sources")
            out = shiny_1988(n_sources=n, resolution=resolution)
    except ValueError as exc:  # the preset's own limits (a source in the camera's view)
        raise OptionError(str(exc).replace("max_polar_deg", "rim"),
                          field="rim_deg" if "below the object" in str(exc) else "n_sources") from None
    return out.with_anchor(anchor) if anchor is not None else out


@dataclass
class ScanObject:
    """An object to scan and what is known of it.

    Attributes
    ----------
    name : str
    objects : dict
        Mitsuba shape dicts for :class:`~shinysim.sim.render.Simulator`.
    datum : (3,) float, mm
        A known surface point (the sphere's apex, a point of the part's
        upper plateau, the fillet's middle): the near-field model's anchor
        and the height map's.
    datum_normal : (3,) float
        Its known unit normal.
    height : callable or None
        ``height(x, y) -> z`` (mm), the exact surface where known (None: the
        rendered truth is interpolated).
    scale_mm : float
        The size height errors are reported against (the sphere's radius,
        the step's height, the fillet's height).
    parts : tuple of str
        Truth parts that belong to the surface measured (highlights
        elsewhere are left out of the surface).
    sphere : (centre, radius) or None
    detect : DetectParams
        Detection settings of its sequential scan. The sphere mirrors every
        source of a dome somewhere, so each frame holds a highlight and the
        default threshold, half of each frame's own peak, finds it. The
        part's normals reach only some of the dome's directions: about half
        of its frames hold no mirror point, only glossy tails and sampling
        noise, and half of *their* peak turns that into dozens of false
        "highlights" per frame, each with the wrong normal. The part is
        therefore thresholded at half of the scan's brightest pixel
        (``threshold_mode="scan"``): a frame whose source the part cannot
        mirror stays empty. The solder joint likewise (:data:`SOLDER_DETECT`).
    subdivide_mm2 : float or None
        Highlights larger than this area at the object are subdivided
        (``DetectParams.max_area`` of :meth:`detect_params`; None: never).
        The joint's mirror highlights are streaks across its width
        (:data:`SOLDER_SUBDIVIDE_MM2`).
    rig : str
        The :func:`coded_rig` the object is scanned with by default
        (:func:`render_scan`): the dome for the sphere and the part; the
        rotating semicircle for the joint, whose normals lie in the x-z plane
        and need sources in that plane (the semicircle's first azimuth).
    """

    name: str
    objects: dict
    datum: np.ndarray
    datum_normal: np.ndarray
    height: Any
    scale_mm: float
    parts: tuple = ("object",)
    sphere: tuple | None = None
    detect: DetectParams = field(default_factory=DetectParams)
    subdivide_mm2: float | None = None
    rig: str = "dome"

    @property
    def anchor(self) -> Anchor:
        return Anchor.at_point(tuple(self.datum), normal=tuple(self.datum_normal))

    def detect_params(self, camera) -> DetectParams:
        """:attr:`detect` for ``camera``: ``max_area`` from :attr:`subdivide_mm2` and its pixel pitch."""
        if self.subdivide_mm2 is None:
            return self.detect
        from dataclasses import replace

        return replace(self.detect, max_area=max(1, round(self.subdivide_mm2 / camera.pixel_pitch ** 2)))

    def decode_settings(self, camera) -> dict:
        """The object's settings for :func:`~shinysim.recon.coding.decode`: the demultiplexed codes detect
        as its sequential scan does (:meth:`detect_params`); bit and colour codes threshold against the
        same peak (each source's own, or the scan's brightest for ``threshold_mode="scan"``) and
        subdivide large regions as it does (``max_area``)."""
        return decode_settings(self.detect_params(camera))


def decode_settings(det: DetectParams) -> dict:
    """:func:`~shinysim.recon.coding.decode` settings that follow a sequential detection's ``det``."""
    return {"detect": det, "max_area": det.max_area,
            "threshold_mode": "scan" if det.threshold_mode == "scan" else "source"}


def step_height(x, y, part=STEP_PART):
    """Height of the machined part (:data:`STEP_PART`), mm."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    return (part["z0_mm"] - (x * x + y * y) / (2 * part["crown_mm"])
            + 0.5 * part["step_mm"] * (1 + np.tanh(x / part["flank_mm"])))


def _step_gradient(x, y, part=STEP_PART):
    sech2 = 1.0 / np.cosh(x / part["flank_mm"]) ** 2
    return (-x / part["crown_mm"] + 0.5 * part["step_mm"] * sech2 / part["flank_mm"], -y / part["crown_mm"])


def step_mesh(part=STEP_PART):
    """The machined part as a :class:`~shinysim.objects.shapes.TriangleMesh` with analytic normals."""
    from ..objects.shapes import TriangleMesh

    n = int(part["vertices"])
    t = part["size_mm"] * (np.arange(n) / (n - 1) - 0.5)
    yy, xx = np.meshgrid(t, t, indexing="ij")
    x, y = xx.ravel(), yy.ravel()
    p, q = _step_gradient(x, y, part)
    normals = np.stack([-p, -q, np.ones_like(p)], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    v00 = (i * n + j).ravel()
    faces = np.concatenate([np.stack([v00, v00 + 1, v00 + n + 1], 1), np.stack([v00, v00 + n + 1, v00 + n], 1)])
    return TriangleMesh(np.stack([x, y, step_height(x, y, part)], 1), faces.astype(np.int32), normals, "mesh",
                        {"step_part": dict(part)})


def scan_object(name: str = "sphere", *, alpha: float = 0.02, folder: str | os.PathLike | None = None) -> ScanObject:
    """The object of a coded scan, with its datum and exact height where known.

    Parameters
    ----------
    name : {"sphere", "step", "solder"}
        ``sphere``: the SHINY calibration sphere (radius 0.794 mm, centre
        on the reference plane), datum its apex. ``step``: the machined part
        of :data:`STEP_PART`, datum on its upper plateau at ``x = 0.45`` mm.
        ``solder``: the nominal good joint
        (:func:`~shinysim.sim.solder.make_joint`), direct light only, datum
        on the fillet at the middle of its visible range; scanned with the
        rotating semicircle (its normals lie in the x-z plane), detected with
        :data:`SOLDER_DETECT`, streaks subdivided (:data:`SOLDER_SUBDIVIDE_MM2`).
    alpha : float
        Roughness of the sphere and the part (the joint keeps its materials).
    folder : path-like, optional
        Where mesh files go (default: a temporary folder).
    """
    _choice("object", name, CODED_OBJECTS)
    if name == "sphere":
        from ..objects.sphere import SHINY_SPHERE_RADIUS_MM as R
        from ..sim.scene import sphere_object

        def height(x, y):
            return np.sqrt(np.clip(R * R - np.asarray(x) ** 2 - np.asarray(y) ** 2, 0, None))

        return ScanObject("sphere", sphere_object(alpha=alpha), np.array([0.0, 0.0, R]), np.array([0.0, 0.0, 1.0]),
                          height, R, ("object",), ((0.0, 0.0, 0.0), R))
    if name == "step":
        from ..sim.meshes import mesh_object
        from ..sim.scene import rough_conductor

        x0 = 0.45
        p, q = _step_gradient(np.array(x0), np.array(0.0))
        nrm = np.array([-float(p), -float(q), 1.0])
        return ScanObject("step", {"object": mesh_object(step_mesh(), bsdf=rough_conductor(alpha), folder=folder)},
                          np.array([x0, 0.0, float(step_height(x0, 0.0))]), nrm / np.linalg.norm(nrm),
                          step_height, STEP_PART["step_mm"], ("object",), detect=STEP_DETECT)
    import tempfile

    from ..objects.solder import JointParams
    from ..sim.solder import make_joint
    from ..sim.solder_scene import joint_objects

    joint = make_joint(JointParams(kind="good"))
    target = folder if folder is not None else tempfile.mkdtemp(prefix="shinysim-coded-")
    objects = joint_objects(joint, target)
    lo, hi = joint.visible_x_range
    xm = 0.5 * (lo + hi)
    nrm = np.asarray(joint.profile_normal(xm, 0.0, ripple=False), float).reshape(3)
    datum = np.array([xm, 0.0, float(joint.profile_z(xm, 0.0, ripple=False))])
    return ScanObject("solder", objects, datum, nrm, None, float(joint.fillet_height), ("solder",),
                      detect=SOLDER_DETECT, subdivide_mm2=SOLDER_SUBDIVIDE_MM2, rig="rotating")


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
    from ..sim.sensor import Sensor, sensor_preset

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
    dirs = _directions(rig)
    comp = bool(complementary) and name in ("binary", "gray")
    if colours == 3:
        order = spatial_order(dirs)
        return make_code(name, rig.n_sources, complementary=comp, order=order, colours=3,
                         channels=colour_channels(dirs, order=order))
    return make_code(name, rig.n_sources, complementary=comp, order=spatial_order(dirs) if name == "gray" else None)


def _directions(rig):
    pos = rig.source_positions
    return pos / np.linalg.norm(pos, axis=1, keepdims=True)


# -- decoding ---------------------------------------------------------------------------------


def pixel_owner(frames: np.ndarray) -> np.ndarray:
    """(H, W) int64: the source giving each pixel the most light in ideal per-source frames, -1 where none does."""
    f = np.asarray(frames)
    best = f.max(axis=0)
    return np.where(best > 0, f.argmax(axis=0), -1).astype(np.int64)


def _nearest(points, queries, exclude_self=False, block=2048):
    """Distance to, and index of, the nearest of ``points`` for each query (brute force in blocks)."""
    d_out = np.empty(len(queries))
    j_out = np.empty(len(queries), int)
    for a in range(0, len(queries), block):
        q = queries[a:a + block]
        d2 = np.sum((q[:, None, :] - points[None, :, :]) ** 2, axis=-1)
        if exclude_self:
            d2[np.arange(len(q)), a + np.arange(len(q))] = np.inf
        j = np.argmin(d2, axis=1)
        j_out[a:a + block] = j
        d_out[a:a + block] = np.sqrt(d2[np.arange(len(q)), j])
    return d_out, j_out


def pair_highlights(table: dict, reference: dict, *, radius_px: float | None = None) -> dict[str, Any]:
    """Pair each highlight of ``table`` with the nearest ``reference`` highlight within a radius.

    A table highlight left unpaired that is the merge of reference
    highlights of its own source (two or more, none paired otherwise,
    within 3 px of it, their centroid weighted by their ``sum`` within the
    radius of it) is paired with all of them: a region the reference
    detection split where a pixel fell just below its level (the
    decoded signal holds the crosstalk of other sources, which lifts such a
    pixel over it) is one highlight there, at the pieces' centroid.

    Parameters
    ----------
    table, reference : dict of (N,) arrays
        Highlight tables (``row``, ``col``, ``source``; ``sum`` weights a
        merge's pieces, equal weights without it): a decoded scan's and the
        sequential scan's.
    radius_px : float, optional
        Pairing radius, pixels. Default: half the smallest distance between
        two reference highlights (each table highlight is then near at most
        one of them), at most 3 px.

    Returns
    -------
    dict
        ``partner`` ((N,) int: reference row, the brightest piece for a
        merge, -1 unpaired), ``distance_px``, ``radius_px``, ``paired``,
        ``errors`` (paired with another source), ``spurious`` (unpaired
        table rows), ``missed`` (reference rows no table row is paired
        with), ``merged`` (reference rows paired through a merge),
        ``error_rate`` (errors / paired).
    """
    t_rc = np.stack([np.asarray(table["row"], float), np.asarray(table["col"], float)], 1)
    r_rc = np.stack([np.asarray(reference["row"], float), np.asarray(reference["col"], float)], 1)
    if radius_px is None:
        if len(r_rc) > 1:
            d, _ = _nearest(r_rc, r_rc, exclude_self=True)
            radius_px = float(min(3.0, 0.5 * d.min()))
        else:
            radius_px = 3.0
    partner = np.full(len(t_rc), -1)
    dist = np.full(len(t_rc), np.inf)
    if len(t_rc) and len(r_rc):
        d, j = _nearest(r_rc, t_rc)
        ok = d <= radius_px
        partner[ok] = j[ok]
        dist = d
    src_r = np.asarray(reference["source"])
    src_t = np.asarray(table["source"])
    found = np.zeros(len(r_rc), bool)
    found[partner[partner >= 0]] = True
    weight = np.asarray(reference.get("sum", np.ones(len(r_rc))), float)
    merged = 0
    for t in np.flatnonzero(partner < 0):
        g = np.flatnonzero(~found & (src_r == src_t[t]) & (np.linalg.norm(r_rc - t_rc[t], axis=1) <= 3.0))
        if len(g) < 2 or np.linalg.norm(weight[g] @ r_rc[g] / weight[g].sum() - t_rc[t]) > radius_px:
            continue
        partner[t] = g[np.argmax(weight[g])]
        dist[t] = np.linalg.norm(r_rc[partner[t]] - t_rc[t])
        found[g] = True
        merged += len(g)
    paired = partner >= 0
    errors = paired & (src_t != src_r[np.where(paired, partner, 0)]) if len(src_r) else paired
    n_pair = int(paired.sum())
    return {"partner": partner, "distance_px": dist, "radius_px": float(radius_px), "paired": n_pair,
            "errors": int(errors.sum()), "error_rows": np.flatnonzero(errors), "spurious": int((~paired).sum()),
            "missed": int((~found).sum()), "merged": merged,
            "error_rate": float(errors.sum() / n_pair) if n_pair else float("nan")}


def decoding_errors(dec: Decoded, owner: np.ndarray, sequential: dict, *, radius_px: float | None = None) -> dict:
    """Decoding scores: highlights paired with the sequential scan's (:func:`pair_highlights`) and pixels against owners.

    Returns
    -------
    dict
        The pairing's counts (without per-row arrays), ``pixels_decoded``,
        ``pixel_errors`` (decoded as another source than the pixel's owner)
        and ``pixel_error_rate``, and the decoder's ``counts``.
    """
    pairs = pair_highlights(dec.table, sequential, radius_px=radius_px)
    lab = dec.labels
    decoded = lab >= 0
    wrong = decoded & (lab != owner)
    out = {k: v for k, v in pairs.items() if k not in ("partner", "distance_px", "error_rows")}
    out.update(highlights=len(dec.table["source"]), sequential_highlights=len(sequential["source"]),
               pixels_decoded=int(decoded.sum()), pixel_errors=int(wrong.sum()),
               pixel_error_rate=float(wrong.sum() / decoded.sum()) if decoded.any() else float("nan"),
               counts=dict(dec.counts))
    return out


# -- normals and surfaces -------------------------------------------------------------------


def table_normals(table: dict, rig: Rig, anchor: Anchor | None = None) -> dict[str, Any]:
    """Normals of a highlight table: the near-field model (with an anchor) and the paper's models.

    Returns
    -------
    dict
        ``normals`` (model -> (N, 3)), ``points`` ((N, 3) mm: the
        near-field surface points, or the perspective model's points on the
        reference plane without an anchor), ``best`` (the near-field model
        with an anchor, else ``"perspective"``), ``converged``.
    """
    from ..recon.normals import NORMAL_MODELS, surface_points

    rows, cols, src = table["row"], table["col"], table["source"]
    out = {"normals": {}, "points": None, "best": "perspective", "converged": None}
    for m in NORMAL_MODELS:
        if m == NEAR_FIELD:
            continue
        out["normals"][m] = highlight_normals(rows, cols, src, rig, model=m).reshape(-1, 3)
    if anchor is not None and len(rows) >= 2:
        nf = near_field_normals(rows, cols, src, rig, anchor)
        out["normals"][NEAR_FIELD] = nf.normals
        out["points"] = nf.points
        out["best"] = NEAR_FIELD
        out["converged"] = bool(nf.converged)
    else:
        out["points"] = np.asarray(surface_points(rows, cols, rig, model="perspective")).reshape(-1, 3)
    return out


def reachable_mask(truth, rig: Rig, parts=None) -> np.ndarray:
    """(H, W) bool: visible pixels whose normal a source of the rig's cap can light.

    A pixel is reachable when its view ray, mirrored at its true normal,
    leaves at a polar angle no larger than the rig's largest source polar
    angle (seen from the origin). For a sphere under an axial camera that
    is the disc of radius ``R sin(a / 2)``.
    """
    cam = rig.camera
    mask = _part_mask(truth, parts)
    n = truth.normals.astype(float)
    v = cam.view_directions(truth.positions.astype(float))
    r = 2 * np.sum(n * v, axis=-1, keepdims=True) * n - v
    rim = float(np.max(np.arccos(np.clip(_directions(rig)[:, 2], -1, 1))))
    with np.errstate(invalid="ignore"):
        return mask & (np.arccos(np.clip(r[..., 2], -1, 1)) <= rim)


def _part_mask(truth, parts):
    if not parts:
        return truth.mask.copy()
    ids = [i for i, name in enumerate(truth.part_names) if name in parts]
    return truth.mask & np.isin(truth.part, ids)


def coverage(truth, rig: Rig, surface, parts=None) -> dict[str, float]:
    """Share of the visible and of the reachable surface inside the highlights' triangles.

    Parameters
    ----------
    truth : Truth
    rig : Rig
    surface : SparseSurface
        From the highlights' surface points and normals.
    parts : sequence of str, optional
        Truth parts that make the surface (default: every object pixel).

    Returns
    -------
    dict
        ``visible`` and ``reachable`` (fractions), ``reachable_of_visible``
        (the share a perfect scan could reach), the pixel counts, and the
        rig's rim polar angle ``rim_deg`` with the sphere value
        ``sin^2(rim / 2)``.
    """
    vis = _part_mask(truth, parts)
    reach = reachable_mask(truth, rig, parts)
    xy = truth.positions[..., :2].astype(float)
    inside = np.zeros(vis.shape, bool)
    z = surface.heights_at(xy[vis], relative=True)
    inside[vis] = np.isfinite(z)
    rim = float(np.degrees(np.max(np.arccos(np.clip(_directions(rig)[:, 2], -1, 1)))))
    nv, nr = int(vis.sum()), int(reach.sum())
    return {"visible": float(inside.sum() / nv) if nv else float("nan"),
            "reachable": float((inside & reach).sum() / nr) if nr else float("nan"),
            "reachable_of_visible": float(nr / nv) if nv else float("nan"),
            "pixels_visible": nv, "pixels_reachable": nr, "pixels_covered": int(inside.sum()),
            "rim_deg": rim, "sphere_reachable_theory": float(math.sin(math.radians(rim / 2)) ** 2)}


def _truth_height_fn(truth, parts, camera):
    """``height(x, y)`` of the rendered truth: the point (x, y) at the surface's height projected into the
    image, the truth's heights interpolated bilinearly there, twice (perspective moves the pixel with the
    height); NaN off the measured parts."""
    m = _part_mask(truth, parts)
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
            vis, reach = _part_mask(truth, obj.parts), reachable_mask(truth, rig, obj.parts)
            out["coverage"] = {"visible": 0.0, "reachable": 0.0 if reach.any() else nan,
                               "reachable_of_visible": float(reach.sum() / max(vis.sum(), 1)),
                               "pixels_visible": int(vis.sum()), "pixels_reachable": int(reach.sum()),
                               "pixels_covered": 0, "note": why}
        return out
    surf = integrate_triangulated(xy, normals, anchors=np.asarray(obj.datum, float)[None])
    height = obj.height if obj.height is not None else _truth_height_fn(truth, obj.parts, (rig or coded_rig()).camera)
    vis = _part_mask(truth, obj.parts)
    pts = truth.positions[vis].astype(float)
    z = surf.heights_at(pts[:, :2], interpolation="normals")
    e = z - pts[:, 2]
    e = e[np.isfinite(e)]
    lin = surf.heights_at(pts[:, :2]) - pts[:, 2]
    lin = lin[np.isfinite(lin)]
    anchored = {"height_rms_mm": float(np.sqrt(np.mean(e**2))) if e.size else float("nan"),
                "height_max_mm": float(np.max(np.abs(e))) if e.size else float("nan"),
                "interpolation": "normals",
                "height_rms_linear_mm": float(np.sqrt(np.mean(lin**2))) if lin.size else float("nan"),
                "pixels": int(e.size), "scale_mm": float(obj.scale_mm), "points": int(len(surf.xy)),
                "components": len(surf.components), "floating": len(surf.floating),
                "edges_dropped": int(surf.dropped.get("long_edges", 0))}
    anchored["height_rms_pct"] = 100.0 * anchored["height_rms_mm"] / obj.scale_mm
    anchored["height_rms_linear_pct"] = 100.0 * anchored["height_rms_linear_mm"] / obj.scale_mm
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


def _normal_diff(a, b):
    d = np.degrees(angle_between(np.asarray(a, float), np.asarray(b, float)))
    s = error_stats(d)
    return {k: s[k] for k in ("n", "median_deg", "p95_deg", "max_deg")}


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
    pairs = pair_highlights(dec.table, seq_table, radius_px=errs["radius_px"])
    per_model = {}
    for m, n in dec_n["normals"].items():
        s = score_normals(dec.table["row"], dec.table["col"], n, truth)
        per_model[m] = {k: s[k] for k in ("n", "median_deg", "p95_deg", "max_deg", "rms_deg")}
    p = pairs["partner"]
    same = (p >= 0)
    same &= np.asarray(dec.table["source"]) == np.asarray(seq_table["source"])[np.where(same, p, 0)]
    diff = _normal_diff(dec_n["normals"][best][same], seq_n["normals"][best][p[same]])
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
    from ..sim.coded import coded_stack
    from ..sim.render import Simulator
    from ..sim.variants import choose_variant

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
        seq_scores = {}
        for m, n in seq_n["normals"].items():
            s = score_normals(seq.table["row"], seq.table["col"], n, truth)
            seq_scores[m] = {k: s[k] for k in ("n", "median_deg", "p95_deg", "max_deg", "rms_deg")}
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
                           "detect": {"threshold": obj.detect.threshold,
                                      "threshold_mode": obj.detect.threshold_mode,
                                      "smooth_px": obj.detect.smooth_px,
                                      "max_area": obj.detect_params(the_rig.camera).max_area}},
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
        _write_coded(tmp, coded)
        write_json(tmp / "code.json", the_code.to_dict())
        _write_table(tmp / "highlights.csv", dec.table, dec_n)
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



def _write_coded(path_folder, coded):
    def write(f):
        with open(f, "wb") as fh:
            np.savez_compressed(fh, frames=coded.frames, saturation=np.nan if coded.saturation is None
                                else coded.saturation, provenance=json.dumps(json_safe(coded.provenance)))

    write_file(path_folder / "coded.npz", write)


def _write_table(path, table, normals):
    """The decoded highlights as CSV: one row per highlight and model (the columns of ``highlights.csv``)."""
    from ..recon.table import write_highlight_table

    t = dict(table)
    n = len(t["source"])
    src = np.asarray(t["source"], int)
    blob = np.ones(n, int)  # 1-based rank of each region among its source's
    for i in range(1, n):
        blob[i] = blob[i - 1] + 1 if src[i] == src[i - 1] else 1
    t.setdefault("blob", blob)
    t.setdefault("part", np.ones(n, int))
    t.setdefault("rel_peak", t["peak"] / max(float(np.max(t["peak"])) if n else 1.0, 1e-30))
    t.setdefault("interreflection", np.zeros(n, bool))
    write_highlight_table(path, t, normals["normals"])


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
    did (``score.json``'s ``sequential.detect``; the defaults without it).

    Raises
    ------
    OptionError
        A code whose frame count or source count does not match the
        folder's frames or stack (field ``code``); a ``score.json`` whose
        ``sequential.detect`` is not a detection's settings.
    """
    from ..sim.coded import CodedStack
    from ..sim.sensor import Sensor

    folder = Path(folder)
    stack = load_stack(folder / "stack.exr")
    with np.load(folder / "coded.npz") as z:
        frames = z["frames"]
        sat = float(z["saturation"])
        prov = json.loads(str(z["provenance"]))
    colours = 3 if frames.ndim == 4 else 1
    if code is None:
        code = Code.from_dict(json.loads((folder / "code.json").read_text()))
    elif isinstance(code, str):
        code = study_code(code, stack.rig, colours=colours)
    if code.colours != colours:
        raise OptionError(f"is a code of {code.colours} colour(s) but {folder / 'coded.npz'} holds "
                          f"{'RGB' if colours == 3 else 'grey'} frames", field="code")
    if code.n_sources != stack.n_sources:
        raise OptionError(f"is a {code.name} code for {code.n_sources} sources but the stack has "
                          f"{stack.n_sources}", field="code")
    if code.n_frames != len(frames):
        raise OptionError(f"a {code.name} code of {code.n_sources} sources has {code.n_frames} frames but "
                          f"{folder / 'coded.npz'} holds {len(frames)}", field="code")
    sensor = Sensor(**prov["sensor"]) if "sensor" in prov else None
    mixing = np.array(prov["colour"]["mixing"], float) if colours == 3 and "colour" in prov else None
    if colours == 3 and mixing is None:
        raise OptionError("holds RGB frames but no mixing matrix in its provenance ('colour': {'mixing': ...})",
                          field=str(folder / "coded.npz"))
    coded = CodedStack(frames, code, stack.rig, stack.camera_index, None if math.isnan(sat) else sat, sensor, prov,
                       mixing)
    # the object's detection, as the scan used it (score.json; the defaults without one)
    settings = {}
    score_path = folder / "score.json"
    if score_path.exists():
        try:
            det = json.loads(score_path.read_text()).get("sequential", {}).get("detect")
            if det is not None:
                settings = decode_settings(DetectParams(**det))
        except (ValueError, TypeError, AttributeError) as exc:
            raise OptionError(f"sequential.detect: not the settings of a detection ({exc})",
                              field=str(score_path)) from None
    return decode(coded, crosstalk=crosstalk, **settings)


# -- reporting -------------------------------------------------------------------------------


def format_coded_table(score: dict) -> str:
    """A short text table of a coded scan's score, for a terminal."""
    d = score["decoding"]
    f = score["frames"]
    rows = [("frames", f"{f['used']} (sequential {f['sequential']}, {f['speed_up']:.1f}x fewer)"),
            ("highlights", f"{d['highlights']} decoded, {d['sequential_highlights']} sequential"),
            ("decoding errors", f"{d['errors']} of {d['paired']} paired ({_pct(d['error_rate'])})"),
            ("spurious, missed", f"{d['spurious']}, {d['missed']}"),
            ("pixel errors", f"{d['pixel_errors']} of {d['pixels_decoded']} decoded pixels"),
            ("collisions", f"{d['counts']['collisions']} px; saturated {d['counts']['saturated']} px")]
    best = score["best_model"]
    n = score["normals"].get(best, {})
    rows.append((f"normal error ({best})", f"median {_deg(n.get('median_deg'))}, p95 {_deg(n.get('p95_deg'))}"))
    cs = score["coded_vs_sequential"]
    rows.append(("coded - sequential", f"median {_deg(cs.get('median_deg'))}, max {_deg(cs.get('max_deg'))}"))
    if "surface" in score:
        c = score["surface"]["coverage"]
        a = score["surface"]["anchored"]
        rows.append(("coverage, visible", f"{_pct(c['visible'])}"))
        rows.append(("coverage, reachable", f"{_pct(c['reachable'])} (reachable: {_pct(c['reachable_of_visible'])} "
                                            "of the visible)"))
        rows.append(("height RMS, anchored", f"{_um(a['height_rms_mm'])} ({_num(a['height_rms_pct'])} % of "
                                             f"{_um(a['scale_mm'])})"))
        if "height_rms_linear_mm" in a:
            rows.append(("  plane facets", f"{_um(a['height_rms_linear_mm'])} ({_num(a['height_rms_linear_pct'])} %)"))
        for m, s in score["surface"]["integrators"].items():
            if m == "grid" or not isinstance(s, dict):
                continue
            rows.append((f"  {m}", f"{_um(s['height_rms_mm'])}, normals {_deg(s['normal_rms_deg'])} RMS"))
    width = max(len(r[0]) for r in rows)
    return "\n".join(f"{a.ljust(width)}  {b}" for a, b in rows)


def print_coded_table(score: dict, file=None) -> None:
    """Print :func:`format_coded_table` (to stdout by default)."""
    print(format_coded_table(score), file=file or sys.stdout)


def _num(x):
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.2f}"


def _pct(x):
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{100 * x:.2f} %"


def _deg(x):
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.3f} deg"


def _um(x):
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{1e3 * x:.2f} um"


def coded_figure(coded, dec: Decoded, truth, rig: Rig, score: dict, surface, obj: ScanObject):
    """Four panels: a coded frame, the decoded sources, the height map's error and the score table.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    rr, cc = np.nonzero(truth.mask)
    pad = 3
    r0, r1 = max(0, rr.min() - pad), min(truth.mask.shape[0], rr.max() + pad + 1)
    c0, c1 = max(0, cc.min() - pad), min(truth.mask.shape[1], cc.max() + pad + 1)
    crop = (slice(r0, r1), slice(c0, c1))
    ext = (c0 - 0.5, c1 - 0.5, r1 - 0.5, r0 - 0.5)
    fig, ax = plt.subplots(2, 2, figsize=(11, 10))
    ax = ax.ravel()
    f0 = coded.frames[0]
    if f0.ndim == 3:  # RGB: each channel from its 1st percentile to the frame's brightest value
        lo = np.percentile(f0, 1, axis=(0, 1))
        ax[0].imshow(np.clip((f0 - lo) / max(float(f0.max() - lo.min()), 1e-30), 0, 1)[crop], extent=ext)
    else:
        ax[0].imshow(f0[crop], cmap="gray", vmin=float(np.percentile(f0, 1)), vmax=float(f0.max()), extent=ext)
    ax[0].set_title(f"{coded.code.name} frame 1 of {coded.n_frames}: {coded.code.lit_per_frame[0]} sources lit")
    lab = np.where(dec.labels >= 0, dec.labels, np.nan)
    ax[1].imshow(np.where(truth.mask, 0.2, 0.0)[crop], cmap="gray", vmin=0, vmax=1, extent=ext)
    ax[1].imshow(np.where(dec.collision, 1.0, np.nan)[crop], cmap="Greys", vmin=0, vmax=1.5, extent=ext,
                 interpolation="nearest")
    ax[1].imshow(lab[crop], cmap="hsv", interpolation="nearest", extent=ext)
    t = dec.table
    ax[1].plot(t["col"], t["row"], "k+", ms=5)
    d = score["decoding"]
    ax[1].set_title(f"decoded sources (colour), collisions (grey), centroids (+)\n"
                    f"{d['highlights']} highlights, {d['errors']} decoding errors")
    if surface is not None:
        m = truth.mask
        pts = truth.positions[m].astype(float)
        z = surface.heights_at(pts[:, :2], interpolation="normals")
        err = np.full(m.shape, np.nan)
        err[m] = 1e3 * (z - pts[:, 2])
        lim = float(np.nanpercentile(np.abs(err), 99)) if np.isfinite(err).any() else 1.0
        im = ax[2].imshow(err[crop], cmap="RdBu_r", vmin=-lim, vmax=lim, extent=ext)
        fig.colorbar(im, ax=ax[2], label="height error, um", shrink=0.8)
        a = score.get("surface", {}).get("anchored", {})
        ax[2].set_title(f"sparse heights minus truth (anchored; normals\nbetween points): RMS "
                        f"{1e3 * (a.get('height_rms_mm') or np.nan):.2f} um over the covered pixels")
    for a_ in ax[:3]:
        a_.set_xlabel("col, px")
        a_.set_ylabel("row, px")
    ax[3].axis("off")
    ax[3].text(0.0, 1.0, format_coded_table(score), family="monospace", fontsize=8, va="top",
               transform=ax[3].transAxes)
    rim = rig.metadata.get("max_polar_deg") if rig.name == "dome" else None
    fig.suptitle(f"coded scan: {rig.name}, {rig.n_sources} sources"
                 + (f", rim {rim:g} deg from the axis" if rim is not None else "") + f", {obj.name}", fontsize=12)
    fig.tight_layout()
    return fig


# -- signal to noise --------------------------------------------------------------------------


def snr_gain_measurement(stack: Stack, sensor, *, fraction: float = 0.5, seed: int = 0) -> dict[str, Any]:
    """Hadamard's SNR gain over sequential scanning at equal exposure per frame, measured and in theory.

    Both scans use one sensor exposed so that the stack's brightest pixel
    fills ``fraction`` of the full well; the Hadamard scan has ``n =
    2**m - 1 >= N`` frames (the S-matrix order). The gain is measured by
    :func:`shinysim.recon.coding.measure_snr_gain` over every pixel of
    every demultiplexed source frame against the noiseless frames, and set
    against :func:`~shinysim.theory.coding.hadamard_snr_gain` (additive
    noise: ``(n + 1) / (2 sqrt n)``).

    Returns
    -------
    dict
        ``gain``, ``stderr``, ``theory``, ``relative_error``, ``n``,
        ``frames_sequential``, ``frames_hadamard``, sigmas.
    """
    from ..recon.coding import measure_snr_gain
    from ..sim.coded import coded_stack, expected_frames
    from ..theory.coding import hadamard_snr_gain

    sensor = sensor.exposed_for(float(stack.frames.max()), fraction)
    n = stack.n_sources
    seq = coded_stack(stack, make_code("sequential", n), sensor=sensor, exposure=None, seed=seed)
    had = coded_stack(stack, make_code("hadamard", n), sensor=sensor, exposure=None, seed=seed + 1)
    r = measure_snr_gain(seq, had, expected_frames(stack.frames, sensor))
    theory = hadamard_snr_gain(had.n_frames)
    return {**r, "theory": theory, "relative_error": r["gain"] / theory - 1, "n": had.n_frames,
            "frames_sequential": seq.n_frames, "frames_hadamard": had.n_frames}


# -- pieces for studies ------------------------------------------------------------------------


@dataclass
class RenderedScan:
    """One render of an object under a rig, with its sequential scan.

    Attributes
    ----------
    rig : Rig
        Anchored at the object's datum.
    obj : ScanObject
    truth : Truth
    stack : Stack
        Ideal per-source frames.
    sequential : Reconstruction
        Detection of ``stack`` (the object's settings, ``ScanObject.detect_params``).
    normals : dict
        :func:`table_normals` of the sequential highlights.
    owner : (H, W) int64
        :func:`pixel_owner` of ``stack``.
    seconds : float
        Render time.
    """

    rig: Rig
    obj: ScanObject
    truth: Any
    stack: Stack
    sequential: Any
    normals: dict
    owner: np.ndarray
    seconds: float = 0.0
    extra: dict = field(default_factory=dict)

    def sequential_errors(self, model: str | None = None) -> dict:
        """Normal errors of the sequential scan against the truth (``error_stats``), best model by default."""
        m = model or self.normals["best"]
        t = self.sequential.table
        s = score_normals(t["row"], t["col"], self.normals["normals"][m], self.truth)
        return {k: s[k] for k in ("n", "median_deg", "p95_deg", "max_deg", "rms_deg")}


def render_scan(obj: str = "sphere", *, rig: str | None = None, n_sources: int = 200, alpha: float = 0.02,
                resolution: int = 256, spp: int = 16, seed: int = 0, folder=None,
                detect: DetectParams | None = None, rim_deg: float | None = None) -> RenderedScan:
    """Render an object under a coded-scan rig once and reconstruct its sequential scan.

    ``rig`` defaults to the object's own (``ScanObject.rig``: the dome, the rotating semicircle for the
    joint); ``detect`` to the object's own settings (``ScanObject.detect_params``)."""
    from ..sim.render import Simulator

    the_obj = scan_object(obj, alpha=alpha, folder=folder)
    the_rig = coded_rig(rig or the_obj.rig, n_sources=n_sources, resolution=resolution, anchor=the_obj.anchor,
                        rim_deg=rim_deg)
    sim = Simulator(the_rig, the_obj.objects)
    truth = sim.render_truth()
    stack = sim.render_stack(spp=spp, seed=seed)
    seq = reconstruct(stack, detect or the_obj.detect_params(the_rig.camera))
    return RenderedScan(the_rig, the_obj, truth, stack, seq, table_normals(seq.table, the_rig, the_rig.anchor),
                        pixel_owner(stack.frames), sim.last_render_seconds)


def code_row(scan: RenderedScan, code: Code, *, sensor=None, exposure: float | None = 0.8, seed: int = 0,
             crosstalk: float | None = None) -> dict[str, Any]:
    """Code, decode and score one scan setting: one row of a study table.

    Parameters
    ----------
    scan : RenderedScan
    code : Code
    sensor : Sensor, optional
    exposure : float or None
        As :func:`~shinysim.sim.coded.coded_stack` (None: the sensor's own exposure per frame).
    seed : int
    crosstalk : float, optional
        The decoder's crosstalk tolerance (``DecodeParams.crosstalk``;
        default ``0.8 / bits``).

    Returns
    -------
    dict
        ``code``, ``frames``, ``highlights``, ``paired``, ``errors``,
        ``error_rate``, ``missed``, ``spurious``, ``pixel_errors``,
        ``collisions``, ``saturated``, ``median_deg`` / ``p95_deg`` (best
        model against the truth), ``vs_sequential_deg`` (median over paired
        highlights), ``peak_electrons`` (the brightest coded pixel's mean
        signal, the sensor's exposure times the radiance).
    """
    from ..sim.coded import coded_stack

    coded = coded_stack(scan.stack, code, sensor=sensor, exposure=exposure if sensor is not None else None,
                        seed=seed)
    dec = decode(coded, crosstalk=crosstalk)
    errs = decoding_errors(dec, scan.owner, scan.sequential.table)
    row = {"code": code.name + ("" if code.complementary or code.name not in ("binary", "gray") else " (no compl.)"),
           "frames": code.n_frames, "highlights": errs["highlights"], "paired": errs["paired"],
           "errors": errs["errors"], "error_rate": errs["error_rate"], "missed": errs["missed"],
           "spurious": errs["spurious"], "pixel_errors": errs["pixel_errors"],
           "collisions": errs["counts"]["collisions"], "saturated": errs["counts"]["saturated"]}
    if coded.sensor is not None:
        from ..theory.coding import encode

        peak = float(encode(scan.stack.frames, code).max())
        row["peak_electrons"] = peak * coded.sensor.exposure
    if len(dec.table["source"]) >= 3:
        n = table_normals(dec.table, scan.rig, scan.rig.anchor)
        best = n["best"]
        s = score_normals(dec.table["row"], dec.table["col"], n["normals"][best], scan.truth)
        row.update(median_deg=s["median_deg"], p95_deg=s["p95_deg"])
        pairs = pair_highlights(dec.table, scan.sequential.table, radius_px=errs["radius_px"])
        p = pairs["partner"]
        same = (p >= 0) & (np.asarray(dec.table["source"]) == np.asarray(scan.sequential.table["source"])[
            np.where(p >= 0, p, 0)])
        row["vs_sequential_deg"] = _normal_diff(n["normals"][best][same], scan.normals["normals"][best][p[same]])[
            "median_deg"]
    return row
