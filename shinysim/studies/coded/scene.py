"""What a coded scan scans and with which rig: the objects (sphere, machined part, solder joint) with their datum and
exact heights, and the rig presets it offers."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..._shared import check_number, named_check
from ...errors import OptionError, did_you_mean
from ...objects.registry import CODED_OBJECTS, scanned_object
from ...recon import DetectParams
from ...recon.decode import decode_settings
from ...rig import DOME_RIM_DEG, SCAN_RIGS, Anchor, Rig, rig_preset
from ...theory.coding import MAX_SOURCES


__all__ = ["CODED_RIGS", "CODED_OBJECTS", "STEP_DETECT", "SOLDER_DETECT", "SOLDER_SUBDIVIDE_MM2", "ScanObject", "check_rim", "coded_rig", "scan_object"]

#: Rigs of a coded scan: a Fibonacci dome, stacked rings, the SHINY
#: semicircle turned to several azimuths, the SHINY semicircle itself.
CODED_RIGS = tuple(SCAN_RIGS)


#: Objects (:data:`~shinysim.objects.registry.CODED_OBJECTS`): the calibration sphere, a machined part with a
#: step, a solder joint.


#: Detection of the part's sequential scan: half of the scan's brightest pixel, not of each frame's. Its
#: normals tilt at most ~20 degrees towards +x and +-y (34 towards -x on the flank), so of a 200-source
#: dome (normals to 40 degrees) about half the sources have no mirror point on it; their frames hold
#: only glossy tails and render noise, which a threshold relative to the frame's own peak turns into
#: dozens of false highlights per frame, each with the wrong normal.
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
    if rig == "shiny" and n > 22:
        raise OptionError(f"is {n}, but the SHINY semicircle holds at most 22 fibers 8 degrees apart "
                          "above the horizon", field="n_sources")
    options = {"dome": dict(n_sources=n, max_polar_deg=rim), "rings": dict(n_sources=n, max_polar_deg=rim),
               "rotating": dict(positions=max(1, round(n / 21))), "shiny": dict(n_sources=n)}[rig]
    try:
        out = rig_preset(SCAN_RIGS[rig], resolution=resolution, **options)
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
    datum, datum_normal, height, scale_mm, parts, sphere
        Its exact truth, as the registry's
        :class:`~shinysim.objects.registry.ScannedObject` gives it (``parts``:
        its ``truth_parts``, the truth parts of the surface measured).
    detect : DetectParams
        Detection settings of its sequential scan. The sphere mirrors every
        source of a dome somewhere, so each frame holds a highlight and the
        default threshold, half of each frame's own peak, finds it. The part
        and the joint mirror only some sources and are thresholded at half of
        the scan's brightest pixel (:data:`STEP_DETECT`, :data:`SOLDER_DETECT`),
        so that a frame whose source they cannot mirror stays empty.
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
    from ...sim.objects import scene_objects

    obj = scanned_object(name)
    if name == "solder" and folder is None:
        import tempfile

        folder = tempfile.mkdtemp(prefix="shinysim-coded-")
    settings = {"step": dict(detect=STEP_DETECT),
                "solder": dict(detect=SOLDER_DETECT, subdivide_mm2=SOLDER_SUBDIVIDE_MM2, rig="rotating")}
    return ScanObject(name, scene_objects(obj, alpha=alpha, folder=folder), obj.datum, obj.datum_normal, obj.height,
                      obj.scale_mm, obj.truth_parts, obj.sphere, **settings.get(name, {}))
