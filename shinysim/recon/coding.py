"""Decoding coded scans: from frames with several sources lit to highlights.

:func:`decode` turns a coded scan (:mod:`shinysim.theory.coding`; simulated by
:func:`shinysim.sim.coded.coded_stack`, or real frames taken with the same
display sequence) into highlights: binary and Gray codes pixel by pixel, with
a crosstalk tolerance (:class:`DecodeParams`) and collisions flagged, never
labelled; Hadamard and sequential codes by demultiplexing
(:func:`demultiplex`) and the ordinary detection; colour codes after
:func:`unmix`. numpy, scipy and scikit-image only. How each decoding works
and why the tolerances are safe: ``docs/coded-scanning.md``, sections
"Decoding", "Crosstalk" and "Colour multiplexing".
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import ndimage

from .._shared import check_choice, check_matrix, check_number, named_check, with_overrides
from ..errors import FrameError, OptionError
from ..io import Stack
from ..io.table import HighlightTable
from ..rig import Rig
from ..theory.coding import Code, check_code
from .detect import (
    DetectParams,
    auto_min_area,
    estimate_noise,
    hot_pixel_k,
    hot_pixel_mask,
    measure_highlights,
    noise_k,
    regions_of_pixels,
    replace_hot_pixels,
)
from .pipeline import Reconstruction, detect_stack

__all__ = [
    "DecodeParams",
    "Decoded",
    "decode",
    "default_crosstalk",
    "check_crosstalk",
    "check_colour_tolerance",
    "colour_tolerance_bound",
    "unmix",
    "demultiplex",
    "measure_snr_gain",
    "SNR_REGIONS",
]

#: Pixels :func:`measure_snr_gain` pools: every pixel of every source frame,
#: the pixels a source lights in its own frame, or the pixels it does not
#: light but another source does.
SNR_REGIONS = ("all", "lit", "unlit")

#: Rows of frames per block in :func:`demultiplex` (at most 2**22 float64 values).
_BLOCK = 1 << 22


@dataclass(frozen=True)
class DecodeParams:
    """Settings of :func:`decode`; every default follows from the frames' noise.

    Parameters
    ----------
    threshold : float
        I0 of the paper, in (0, 1]: a decoded pixel joins its source's
        highlight where its signal is at least this fraction of that
        source's brightest decoded pixel (0.5, as ``DetectParams``'
        relative threshold, so a coded and a sequential scan give the same
        centroids). Pixels below it are still decoded (``labels``). 0 keeps
        every decoded pixel.
    noise_sigma : float or None
        rms noise of a dark pixel in one frame, frame units. None: 0 for a
        simulated coded stack without a sensor (ideal radiance), else each
        frame's own, estimated from its pixel differences
        (:func:`~shinysim.recon.detect.estimate_noise`; highlights touch
        few pixel pairs, so it is the dark noise).
    shot_gain : float or None
        Photon-noise variance per unit of signal, frame units (a pixel of
        signal ``v`` has variance ``noise_sigma**2 + shot_gain * v``). None:
        the sensor's ``gain / (2**bits - 1)`` when the frames carry a sensor
        with shot noise, else 0. It keeps bright pixels, whose photon noise
        is far above the dark noise, from being read as uncertain.
    background : float, "median" or None
        Level of a dark pixel, subtracted from every frame. None: the
        sensor's black level (``dark_offset / (2**bits - 1)``) when the
        frames carry a sensor, else 0 (ideal radiance). ``"median"``: each
        frame's median (real frames of unknown black level; right only
        where highlights cover less than half of the frame).
    false_alarm : float
        Expected number of pixels in the whole image that noise alone makes
        look lit, collided or sure of a bit: every test is made at ``k``
        noise standard deviations, ``k`` the one-sided Gaussian quantile of
        ``false_alarm / (pixels * tests per pixel)``
        (:func:`~shinysim.recon.detect.noise_k`; 5.3 for 256 x 256 pixels
        and 8 bits at 0.01). > 0.
    min_area : int or None
        Regions with fewer pixels are dropped. None: 1/8 of the median
        region area (:func:`~shinysim.recon.detect.auto_min_area`, the
        rule of sequential detection).
    connectivity : {1, 2}
        4- or 8-connected regions.
    detect : DetectParams or None
        Detection of the demultiplexed stack (Hadamard, sequential).
    crosstalk : float or None
        Complementary binary and Gray codes: the crosstalk tolerance
        ``rho``, in ``[0, 1 / bits)``. A bit pair is a collision only where
        its weaker frame holds more than ``rho`` times the stronger one
        (beyond noise). If it holds at most that in every pair, the source
        on the stronger side of every bit (one source, as codewords differ)
        holds at least ``1 - B rho / (1 + rho)`` of the pixel's light and
        every other source at most ``rho / (1 + rho)`` of it (``B`` bits),
        so for ``rho < 1 / B`` the decoded source is the pixel's brightest;
        a larger value is refused. None: :func:`default_crosstalk`,
        ``0.8 / B`` (0.1 for 200 sources), which keeps a margin below that
        bound for noise and still accepts the 1-5 % of light a rough
        highlight's core gets from its neighbours' tails. 0: the strict
        rule, any light beyond noise in a frame and its complement is a
        collision. Unused by other codes.
    colour_tolerance : float or None
        Colour codes: the light a pixel may hold in a channel other than its
        brightest, as a fraction of the brightest channel's (beyond noise),
        without being a colour collision; in ``[0, bound)`` with ``bound``
        :func:`colour_tolerance_bound` (``1 - B rho / (1 + rho)`` for
        complementary binary and Gray inner codes, 1 for the others). Below
        it the decoded source is the pixel's brightest of all colours (see
        :func:`colour_tolerance_bound`). None: ``min(0.2, bound / 2)``.
        Unused by codes of one colour.
    threshold_mode : {"source", "scan"}
        Bit and colour codes: ``threshold`` is a fraction of each source's
        own brightest decoded pixel (``"source"``, as ``DetectParams``'
        ``"relative"``) or of the brightest decoded pixel of all sources
        (``"scan"``, as ``DetectParams``' ``"scan"``: an object that mirrors
        only some sources, whose other frames hold only glossy tails). The
        demultiplexed codes take theirs from ``detect``.
    max_area : int or None
        Bit and colour codes: a decoded region with more pixels is
        subdivided into ``ceil(area / max_area)`` parts along its principal
        axes, each its own highlight, as sequential detection does
        (``DetectParams.max_area``, paper Section IV: a streak across a
        solder joint gives points along it, not one). None: never. The
        demultiplexed codes take it from ``detect``.
    """

    threshold: float = 0.5
    noise_sigma: float | None = None
    shot_gain: float | None = None
    background: float | str | None = None
    false_alarm: float = 0.01
    min_area: int | None = None
    connectivity: int = 2
    detect: DetectParams | None = None
    crosstalk: float | None = None
    colour_tolerance: float | None = None
    threshold_mode: str = "source"
    max_area: int | None = None

    def __post_init__(self):
        named_check("threshold", check_number, self.threshold, lo=0, hi=1)
        if self.noise_sigma is not None:
            named_check("noise_sigma", check_number, self.noise_sigma, lo=0)
        if self.shot_gain is not None:
            named_check("shot_gain", check_number, self.shot_gain, lo=0)
        if isinstance(self.background, str):
            named_check("background", check_choice, self.background, ("median",))
        elif self.background is not None:
            named_check("background", check_number, self.background, lo=-1e30, hi=1e30)
        named_check("false_alarm", check_number, self.false_alarm, lo=0, lo_open=True)
        if self.min_area is not None:
            named_check("min_area", check_number, self.min_area, lo=1, integer=True)
        named_check("connectivity", check_choice, self.connectivity, (1, 2))
        if self.crosstalk is not None:  # below 1 / bits, checked against the code by decode
            named_check("crosstalk", check_number, self.crosstalk, lo=0, hi=1, hi_open=True)
        if self.colour_tolerance is not None:  # below its bound, checked against the code by decode
            named_check("colour_tolerance", check_number, self.colour_tolerance, lo=0, hi=1, hi_open=True)
        named_check("threshold_mode", check_choice, self.threshold_mode, ("source", "scan"))
        if self.max_area is not None:
            named_check("max_area", check_number, self.max_area, lo=1, integer=True)
        if self.detect is not None and not isinstance(self.detect, DetectParams):
            raise OptionError(f"must be DetectParams or None, got {type(self.detect).__name__}", field="detect")



def default_crosstalk(n_bits: int) -> float:
    """The default crosstalk tolerance for ``n_bits`` bit pairs: ``0.8 / n_bits``.

    Below ``1 / n_bits`` a decoded pixel's source is provably its brightest
    (``DecodeParams.crosstalk``); 0.8 of that bound leaves a margin for noise.
    """
    return 0.8 / max(1, int(n_bits))


def check_crosstalk(crosstalk: float | None, n_bits: int) -> float:
    """The crosstalk tolerance :func:`decode` uses for ``n_bits`` bit pairs.

    None gives :func:`default_crosstalk`; a number must lie in ``[0, 1 /
    n_bits)``, else :class:`~shinysim.errors.OptionError` (field
    ``crosstalk``) says why: at or above ``1 / n_bits`` a pixel's
    crosstalk can outweigh its brightest source in the decoded codeword.
    """
    b = max(1, int(n_bits))
    if crosstalk is None:
        return default_crosstalk(b)
    rho = named_check("crosstalk", check_number, crosstalk, lo=0)
    if rho >= 1.0 / b:
        raise OptionError(f"must be below 1 / {b} bits = {1.0 / b:.4g}, got {rho:g}: at or above it, light from "
                          "other sources can outweigh a pixel's brightest source and decode as the wrong one",
                          field="crosstalk")
    return rho


def colour_tolerance_bound(code: Code, crosstalk: float | None = None) -> float:
    """The colour tolerance below which a colour code's decoded source is provably the pixel's brightest.

    A complementary binary or Gray inner code with crosstalk tolerance
    ``rho`` (:func:`check_crosstalk`; None: its default) decodes, in the
    pixel's brightest channel, a source holding at least ``1 - B rho / (1 +
    rho)`` of that channel's light (``DecodeParams.crosstalk``); a source of
    another colour holds at most the other channel's light, at most ``tau``
    of the brightest channel's. So for ``tau < 1 - B rho / (1 + rho)`` the
    decoded source is the pixel's brightest source of any colour. Sequential
    and Hadamard inner codes demultiplex each source's light, so the decoder
    checks it directly (a pixel whose labelled source holds less light than
    another channel is left unlabelled, ``uncertain``): their bound is 1.
    Codes without complementary frames guarantee nothing within a channel;
    their bound is 1 too.
    """
    if code.name in ("binary", "gray") and code.complementary:
        b = max(1, code.n_bits)
        rho = check_crosstalk(crosstalk, b)
        return 1.0 - b * rho / (1.0 + rho)
    return 1.0


def check_colour_tolerance(tolerance: float | None, code: Code, crosstalk: float | None = None) -> float:
    """The colour tolerance :func:`decode` uses for ``code``.

    None gives ``min(0.2, bound / 2)`` (:func:`colour_tolerance_bound`): 0.2
    is four times the 5 % of light that the tails of a rough highlight's
    neighbours put into its core, and half the bound keeps a margin for
    noise. A number must lie in ``[0, bound)``, else
    :class:`~shinysim.errors.OptionError` (field ``colour_tolerance``).
    """
    bound = colour_tolerance_bound(code, crosstalk)
    if tolerance is None:
        return min(0.2, 0.5 * bound)
    tau = named_check("colour_tolerance", check_number, tolerance, lo=0)
    if tau >= bound:
        raise OptionError(f"must be below {bound:.4g} for this code and crosstalk tolerance, got {tau:g}: at or "
                          "above it, a source of another colour can outweigh the decoded one", field="colour_tolerance")
    return tau


def unmix(frames: Any, mixing: Any, *, background: Any = 0.0) -> np.ndarray:
    """Per-pixel colour unmixing: ``u = mixing^-1 (y - background)``, channel by channel.

    Parameters
    ----------
    frames : (n_frames, H, W, 3) array_like
        Camera channels R, G, B.
    mixing : (3, 3) array_like
        Column ``c``: the camera's (R, G, B) response to fiber colour ``c``
        (a calibration on a white target; ``CodedStack.mixing``).
    background : float or (n_frames, 3) array_like
        Dark level of each frame and channel, subtracted first.

    Returns
    -------
    (3, n_frames, H, W) float32
        The light of each fiber colour, unclipped (noise makes dark pixels
        negative as often as positive). Computed per frame in float64.
    """
    m = _check_mixing(mixing)
    arr = np.asarray(frames)
    if arr.ndim != 4 or arr.shape[-1] != 3:
        raise OptionError(f"must be (n_frames, H, W, 3), got shape {arr.shape}", field="frames")
    F = arr.shape[0]
    bg = np.broadcast_to(np.asarray(background, dtype=np.float64), (F, 3))
    minv = np.linalg.inv(m)
    out = np.empty((3, F) + arr.shape[1:3], np.float32)
    for f in range(F):
        u = (arr[f].astype(np.float64) - bg[f]) @ minv.T
        out[:, f] = np.moveaxis(u, -1, 0)
    return out


def _check_mixing(mixing):
    m = check_matrix("mixing", mixing, "a finite 3 x 3 matrix (column c: the camera's response to fiber colour c)")
    cond = np.linalg.cond(m)
    if not np.isfinite(cond) or cond > 1e6:
        raise OptionError(f"is singular or nearly so (condition number {cond:.3g}): the colours cannot be unmixed",
                          field="mixing")
    return m


@dataclass
class Decoded:
    """The highlights of a coded scan.

    Attributes
    ----------
    table : HighlightTable
        One row per highlight, each source's in turn: ``source``, ``row``,
        ``col`` (centroid, pixels), ``area`` (pixels), ``peak`` and ``sum``
        (signal above the background), ``saturated`` (a pixel of it clipped
        in some frame), ``blob`` (its rank among its source's highlights,
        from 1), ``part`` (1: decoding does not tell whole regions from
        parts), ``rel_peak`` (peak / the brightest highlight's, the table's
        ``reference``) and ``interreflection`` (False).
    labels : (H, W) int64
        The source decoded at each pixel, -1 for none. Per-pixel codes:
        every confidently decoded pixel (also those below ``threshold``).
        Demultiplexed codes: the brightest source where it is significant.
    collision : (H, W) bool
        Per-pixel codes: light from two sources that differ in some bit,
        beyond the crosstalk tolerance (or a hot pixel); never labelled. Demultiplexed codes: two sources
        significant at once, which demultiplexing separates (informational).
        Colour codes: also every colour collision (``channel == -1``).
    saturated : (H, W) bool
        At the clip level in at least one frame.
    counts : dict of str -> int
        ``lit``, ``decoded``, ``collisions``, ``uncertain`` (lit but a bit
        within noise), ``invalid`` (a codeword no source has),
        ``saturated`` pixels and ``highlights``. Colour codes also
        ``colour_collisions`` (pixels with light beyond the colour
        tolerance in a second channel; among ``collisions``).
    notes : list of str
    signal : (H, W) float32 or None
        Per-pixel codes: each pixel's light above the background.
    pairs : (H, W, 2) int64 or None
        Per-pixel complementary codes: at a pixel whose collision is in one
        bit only, the two sources whose codewords agree in every other bit
        (each -1 where no source has it); -1 elsewhere.
    stack : Stack or None
        Demultiplexed codes: the per-source stack (a per-frame pedestal
        added so that it is >= 0; ``provenance["pedestal"]``).
    reconstruction : Reconstruction or None
        Demultiplexed codes: detection's full result on ``stack``.
    noise : dict
        The levels used: ``background`` and ``noise_sigma`` per frame,
        ``shot_gain``, ``k``; ``crosstalk`` (the tolerance) for
        complementary binary and Gray codes. Colour codes: ``background``
        and ``noise_sigma`` per frame and camera channel, and
        ``colour_tolerance``, ``colour_k``, ``mixing``,
        ``unmixed_noise_sigma`` (per channel and frame) and ``shot_gain``
        per unmixed channel (``unmixed_shot_gain``).
    channel : (H, W) int64 or None
        Colour codes: the pixel's brightest unmixed channel (0, 1, 2), whose
        code decoded it; -1 at colour collisions. None for one colour.
    light : (H, W, 3) float32 or None
        Colour codes: each unmixed channel's light at each pixel (the
        light of the brightest source of that colour, or of all of them
        where several overlap), as the colour test compares it.
    """

    table: HighlightTable
    labels: np.ndarray
    collision: np.ndarray
    saturated: np.ndarray
    counts: dict[str, int]
    notes: list[str] = field(default_factory=list)
    signal: np.ndarray | None = None
    pairs: np.ndarray | None = None
    stack: Stack | None = None
    reconstruction: Reconstruction | None = None
    noise: dict[str, Any] = field(default_factory=dict)
    channel: np.ndarray | None = None
    light: np.ndarray | None = None

    def __len__(self):
        return len(self.table)


def _decoded_table(source, row, col, area, peak, sum, saturated):
    """The :class:`HighlightTable` of decoded highlights (ordered by source): ``blob`` each one's rank among
    its source's, ``part`` 1, ``rel_peak`` relative to the brightest, no inter-reflection flags."""
    n = len(source)
    start = np.flatnonzero(np.r_[True, source[1:] != source[:-1]]) if n else np.zeros(0, np.int64)
    blob = np.arange(n) - np.repeat(start, np.diff(np.r_[start, n])) + 1
    reference = max(float(np.max(peak)) if n else 1.0, 1e-30)
    return HighlightTable({"source": source, "row": row, "col": col, "area": area, "peak": peak, "sum": sum,
                           "blob": blob, "part": np.ones(n, np.int64), "rel_peak": peak / reference,
                           "saturated": saturated}, reference=reference)


# -- input ----------------------------------------------------------------------------


def _inputs(coded, code, rig, camera_index, saturation, sensor):
    """(frames, code, rig, camera_index, saturation, sensor) from a coded stack or from frames plus keywords."""
    if hasattr(coded, "frames") and hasattr(coded, "code"):
        if code is not None and code != coded.code:
            raise OptionError("differs from the coded stack's own code", field="code")
        frames, code = coded.frames, coded.code
        rig = getattr(coded, "rig", None) if rig is None else rig
        camera_index = getattr(coded, "camera_index", camera_index)
        saturation = getattr(coded, "saturation", None) if saturation is None else saturation
        sensor = getattr(coded, "sensor", None) if sensor is None else sensor
        # a simulated coded stack without a sensor is ideal radiance: noiseless
        ideal = getattr(coded, "sensor", 0) is None and getattr(coded, "saturation", 0) is None
    else:
        frames, ideal = coded, False
    check_code(code)
    try:
        frames = np.asarray(frames)
    except (TypeError, ValueError):
        raise FrameError("must be an array of numbers", field="frames") from None
    if code.channels is not None:
        if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype.kind not in "fiu":
            raise FrameError(f"a colour code's frames must be (n_frames, H, W, 3) numbers, got shape "
                             f"{frames.shape} {frames.dtype}", field="frames")
    elif frames.ndim != 3 or frames.dtype.kind not in "fiu":
        raise FrameError(f"must be (n_frames, H, W) numbers, got shape {frames.shape} {frames.dtype}",
                         field="frames")
    if frames.shape[0] != code.n_frames:
        raise OptionError(f"the {code.name} code of {code.n_sources} sources has {code.n_frames} frames but "
                          f"{frames.shape[0]} were given", field="frames")
    flat = frames.reshape(len(frames), -1)
    bad = ~np.isfinite(flat) if frames.dtype.kind == "f" else np.zeros(flat.shape, bool)
    if bad.any():
        which = np.flatnonzero(bad.any(axis=1))
        raise FrameError(f"{int(bad.sum())} NaN or inf pixel(s) in frame(s) {which[:8].tolist()}"
                         f"{' ...' if len(which) > 8 else ''}", field="frames")
    if rig is not None:
        if not isinstance(rig, Rig):
            raise OptionError(f"must be a shinysim Rig, got {type(rig).__name__}", field="rig")
        if rig.n_sources != code.n_sources:
            raise OptionError(f"has {rig.n_sources} sources but the {code.name} code is for {code.n_sources}",
                              field="rig")
    if saturation is not None:
        saturation = named_check("saturation", check_number, saturation, lo=0, lo_open=True)
    return frames, code, rig, int(camera_index), saturation, sensor, ideal


def _clipped(frames, saturation):
    """Where a frame is at the clip level ``saturation`` (None: nowhere), over all frames."""
    sat = np.zeros(frames.shape[1:], bool)
    if saturation is not None:
        for f in frames:
            sat |= f >= saturation
    return sat


def _levels(frames, params, sensor, ideal=False):
    """Per-frame background and dark noise, and the shot-noise factor (frame units)."""
    n = len(frames)
    if params.background == "median":
        bg = np.array([float(np.median(f)) for f in frames])
    elif params.background is not None:
        bg = np.full(n, float(params.background))
    elif sensor is not None:
        bg = np.full(n, sensor.dark_offset / sensor.full_scale)
    else:
        bg = np.zeros(n)
    if params.noise_sigma is not None:
        sig = np.full(n, float(params.noise_sigma))
    elif ideal:
        sig = np.zeros(n)
    else:
        sig = np.array([estimate_noise(f) for f in frames])
    if params.shot_gain is not None:
        shot = float(params.shot_gain)
    elif sensor is not None and getattr(sensor, "shot_noise", False):
        shot = sensor.gain / sensor.full_scale
    else:
        shot = 0.0
    return bg, sig, shot


# -- decoding -----------------------------------------------------------------------


def decode(coded: Any, params: DecodeParams | None = None, *, code: Code | None = None, rig: Rig | None = None,
           camera_index: int = 0, saturation: float | None = None, sensor: Any = None, mixing: Any = None,
           **kwargs) -> Decoded:
    """Highlights of a coded scan.

    Parameters
    ----------
    coded : CodedStack or (n_frames, H, W) array_like
        A :class:`shinysim.sim.coded.CodedStack` (or anything with its
        ``frames``, ``code``, ``rig``, ``camera_index``, ``saturation`` and
        ``sensor``), or the coded frames themselves with ``code`` (and
        ``rig`` for demultiplexed codes) given.
    params : DecodeParams, optional
        Keyword arguments override single fields.
    code : Code, optional
    rig : Rig, optional
        Needed to demultiplex (the per-source stack belongs to a rig).
    camera_index : int
    saturation : float, optional
        The frames' clip level (a coded stack's own by default).
    sensor : Sensor, optional
        Its black level and photon-noise gain set the defaults of
        ``background`` and ``shot_gain``.
    mixing : (3, 3) array_like, optional
        Colour codes: the calibrated mixing matrix, column ``c`` the
        camera's (R, G, B) response to fiber colour ``c``
        (:func:`shinysim.sim.coded.colour_mixing`); a coded stack's own
        ``mixing`` by default. Needed for colour frames given as an array.

    Returns
    -------
    Decoded

    Raises
    ------
    OptionError
        A code whose frame count differs from the frames', a rig with
        another source count, bad parameters (a crosstalk tolerance at or
        above ``1 / bits`` among them); each names its field.
    FrameError
        NaN or inf pixels (naming the frames), frames not (n, H, W).

    Notes
    -----
    The per-pixel tests of each kind of code, and the colour test:
    ``docs/coded-scanning.md``, "Decoding", "The decoder's tests".

    Examples
    --------
    The spots of :func:`shinysim.recon.pipeline.reconstruct`'s example
    (each source's exact highlight on the paper's mirror sphere), lit by a
    complementary Gray code: 10 frames for 21 sources, every highlight
    decoded back to its source, within a third of a pixel of the exact
    point (the regions are cut at the threshold):

    >>> import numpy as np
    >>> from shinysim.rig import shiny_1988
    >>> from shinysim.theory.coding import encode, make_code
    >>> from shinysim.theory.mirror import mirror_sphere_highlight
    >>> rig = shiny_1988(resolution=128)
    >>> point, _ = mirror_sphere_highlight(rig.source_positions, radius=0.79375,
    ...                                    camera_position=rig.camera.position)
    >>> row, col = rig.camera.project(point)
    >>> r, c = np.mgrid[:128, :128]
    >>> frames = np.exp(-((r - row[:, None, None]) ** 2 + (c - col[:, None, None]) ** 2) / 2)
    >>> code = make_code("gray", rig.n_sources)
    >>> coded = encode(frames, code)
    >>> found = decode(coded, code=code, rig=rig)
    >>> t = found.table
    >>> len(coded), found.counts["highlights"], sorted(t["source"].tolist()) == list(range(21))
    (10, 21, True)
    >>> round(float(np.hypot(t["row"] - row[t["source"]], t["col"] - col[t["source"]]).max()), 1)
    0.3
    """
    params = with_overrides(DecodeParams, params, kwargs)
    frames, code, rig, camera_index, saturation, sensor, ideal = _inputs(coded, code, rig, camera_index,
                                                                         saturation, sensor)
    if code.channels is not None:
        if mixing is None:
            mixing = getattr(coded, "mixing", None)
        if mixing is None:
            raise OptionError("a colour code's frames need the calibrated mixing matrix (column c: the camera's "
                              "response to fiber colour c; shinysim.sim.coded.colour_mixing)", field="mixing")
        return _decode_colour(frames, code, params, _check_mixing(mixing), saturation, sensor, ideal, rig,
                              camera_index)
    if mixing is not None:
        raise OptionError("is for colour codes only", field="mixing")
    bits = code.name in ("binary", "gray")
    rho = check_crosstalk(params.crosstalk, code.n_bits) if bits and code.complementary else None
    bg, sig, shot = _levels(frames, params, sensor, ideal)
    sat = _clipped(frames, saturation)
    if bits:
        return _decode_bits(frames, code, params, bg, sig, shot, sat, rho)
    if rig is None:
        raise OptionError(f"a {code.name} code is demultiplexed into a stack, which needs the rig", field="rig")
    x = demultiplex(frames, code, background=bg)
    return _detect_sources(x, frames.shape[1:], code, params, bg, sig, shot, sat, rig, camera_index)


def _decode_bits(frames, code, params, bg, sig, shot, sat, rho):
    """Per-pixel decoding of a binary or Gray code; ``rho`` the crosstalk tolerance (complementary codes)."""
    _, H, W = frames.shape
    B = code.n_bits
    k = noise_k(H * W * B, params.false_alarm)
    px = _bit_pixels(frames, B, code.complementary, code.source_of_codeword(), bg, sig, shot, rho, k)
    table = _regions(px["labels"], px["signal"], sat, code.n_sources, params)
    notes = list(px["notes"])
    if sat.any():
        notes.append(f"{int(sat.sum())} pixel(s) at the clip level in some frame: their signal (and so the "
                     "centroids of highlights that hold them) is too low")
    if rho:
        notes.append(f"crosstalk tolerance {rho:.3g}: a bit pair is a collision only where its weaker frame holds "
                     f"more than {rho:.3g} of the stronger (beyond noise)")
    counts = {"lit": int(px["lit"].sum()), "decoded": int(px["decoded"].sum()),
              "collisions": int(px["collision"].sum()), "uncertain": int(px["uncertain"].sum()),
              "invalid": int(px["invalid"].sum()), "saturated": int(sat.sum()), "highlights": len(table)}
    noise = {"background": bg.tolist(), "noise_sigma": sig.tolist(), "shot_gain": shot, "k": k}
    if rho is not None:
        noise["crosstalk"] = rho
    return Decoded(table, px["labels"], px["collision"], sat, counts, notes, px["signal"].astype(np.float32),
                   px["pairs"], None, None, noise)


def _bit_pixels(frames, B, complementary, source_of, bg, sig, shot, rho, k):
    """The per-pixel part of :func:`_decode_bits`: each pixel's codeword, tests and source.

    ``source_of`` maps codewords to sources (-1 for none); ``k`` is the
    noise multiplier. Returns a dict of (H, W) arrays (``labels``,
    ``signal``, ``lit``, ``collision``, ``uncertain``, ``invalid``,
    ``decoded``, ``pairs`` (H, W, 2) or None) and ``notes``.
    """
    _, H, W = frames.shape
    word = np.zeros((H, W), np.int64)
    weak = np.zeros((H, W), bool)
    collided = np.zeros((H, W), np.int64)
    first = np.full((H, W), -1, np.int64)
    notes = []
    if complementary:
        total = np.zeros((H, W))
        major = np.zeros((H, W))
        dark_var = 0.0
        for b in range(B):
            a = frames[2 * b].astype(np.float64) - bg[2 * b]
            c = frames[2 * b + 1].astype(np.float64) - bg[2 * b + 1]
            word = (word << 1) | (a > c)
            total += a + c
            va, vc = sig[2 * b] ** 2, sig[2 * b + 1] ** 2
            dark_var += va + vc
            spread = k * np.sqrt(va + vc + shot * (np.maximum(a, 0) + np.maximum(c, 0)))
            weak |= ~(np.abs(a - c) > spread)
            if rho == 0:  # strict: light beyond noise in both frames
                both = (a > k * np.sqrt(va)) & (c > k * np.sqrt(vc))
            else:  # the weaker frame's light, less its noise, beyond rho of the stronger frame's
                hi, lo = np.maximum(a, c), np.minimum(a, c)
                v_lo = np.where(a > c, vc, va)
                both = lo - k * np.sqrt(v_lo + shot * np.maximum(lo, 0)) > rho * np.maximum(hi, 0)
                major += np.maximum(hi, 0)
            first[both & (first < 0)] = b
            collided += both
        lit = total / B > k * np.sqrt(dark_var) / B
        signal = total / B if rho == 0 else major / B
    else:
        peak = np.full((H, W), -np.inf)
        for b in range(B):
            np.maximum(peak, frames[b].astype(np.float64) - bg[b], out=peak)
        s_max = float(np.max(sig))
        lit = peak > 2 * k * s_max
        on_sum = np.zeros((H, W))
        n_on = np.zeros((H, W), np.int64)
        for b in range(B):
            a = frames[b].astype(np.float64) - bg[b]
            on = a > 0.5 * peak
            word = (word << 1) | on
            on_sum += np.where(on, a, 0.0)
            n_on += on
            near_full = a >= peak - k * np.sqrt(2 * sig[b] ** 2 + shot * 2 * np.maximum(peak, 0))
            dark = a <= k * sig[b]
            middle = ~(near_full | dark)
            first[middle & (first < 0)] = b
            collided += middle
        signal = np.where(n_on > 0, on_sum / np.maximum(n_on, 1), 0.0)
        notes.append("no complementary frames: bits judged against half of each pixel's brightest frame; "
                     "collisions of sources with disjoint codewords can go unseen")
    collision = lit & (collided > 0)
    src = source_of[np.clip(word, 0, len(source_of) - 1)]
    uncertain = lit & ~collision & weak
    invalid = lit & ~collision & ~weak & (src < 0)
    decoded = lit & ~collision & ~weak & (src >= 0)
    labels = np.where(decoded, src, -1)
    pairs = None
    if complementary:
        pairs = np.full((H, W, 2), -1, np.int64)
        one = collision & (collided == 1)
        if one.any():
            bit = np.left_shift(1, B - 1 - first[one])
            pairs[one, 0] = source_of[word[one] | bit]
            pairs[one, 1] = source_of[word[one] & ~bit]
    return {"labels": labels, "signal": signal, "lit": lit, "collision": collision, "uncertain": uncertain,
            "invalid": invalid, "decoded": decoded, "pairs": pairs, "notes": notes}


def _decode_colour(frames, code, params, mixing, saturation, sensor, ideal, rig, camera_index):
    """Colour codes: unmix, give each pixel its brightest channel, flag colour collisions, decode each channel."""
    F, H, W, _ = frames.shape
    bits = code.name in ("binary", "gray")
    rho = check_crosstalk(params.crosstalk, code.n_bits) if bits and code.complementary else None
    tau = check_colour_tolerance(params.colour_tolerance, code, params.crosstalk)
    if not bits and rig is None:
        raise OptionError(f"a {code.name} code is demultiplexed into a stack, which needs the rig", field="rig")
    # backgrounds and dark noise of the raw camera channels, per frame
    flat = [frames[f, ..., c] for f in range(F) for c in range(3)]
    bg, sig, shot = _levels(flat, params, sensor, ideal)
    bg, sig = bg.reshape(F, 3), sig.reshape(F, 3)
    minv = np.linalg.inv(mixing)
    u = unmix(frames, mixing, background=bg)  # (3, F, H, W)
    w2 = minv**2
    sig_u = np.sqrt(sig**2 @ w2.T).T  # (3, F): dark noise of each unmixed channel and frame
    # photon noise of a channel's own light: Var u_i = shot sum_j minv_ij^2 (mixing u)_j, with u in channel i only
    shot_u = shot * np.einsum("ij,ji->i", w2, mixing)
    sat_raw = _clipped(frames, saturation)
    sat = sat_raw.any(axis=-1)
    # each channel's light and its variance, from all frames
    per_source = code.matrix.sum(axis=0)
    share = float(per_source[0]) if np.all(per_source == per_source[0]) else None
    light = np.zeros((3, H, W)) if share is not None else np.full((3, H, W), -np.inf)
    var = np.zeros((3, H, W))
    for f in range(F):
        v = sig_u[:, f, None, None] ** 2
        if shot > 0:
            raw_pos = np.maximum(frames[f].astype(np.float64) - bg[f], 0.0)  # (H, W, 3)
            v = v + shot * np.moveaxis(raw_pos @ w2.T, -1, 0)
        if share is not None:
            light += u[:, f]
            var += v
        else:
            np.maximum(light, u[:, f], out=light)
            np.maximum(var, v, out=var)
    if share is not None:
        light /= share
        var /= share**2
    k_c = noise_k(H * W * 2, params.false_alarm)
    dom = np.argmax(light, axis=0)
    l_dom = np.take_along_axis(light, dom[None], 0)[0]
    colour_coll = np.zeros((H, W), bool)
    for i in range(3):
        colour_coll |= (dom != i) & (light[i] - k_c * np.sqrt(var[i]) > tau * np.maximum(l_dom, 0.0))
    # where a camera channel clips the unmixing is wrong: trust the pixel only if its channel is one that clips
    clip_doubt = sat & ~np.take_along_axis(sat_raw, dom[..., None], -1)[..., 0]
    colour_coll |= clip_doubt
    owner = np.where(colour_coll, -1, dom)
    notes = []
    noise = {"background": bg.tolist(), "noise_sigma": sig.tolist(), "shot_gain": shot,
             "colour_tolerance": tau, "colour_k": k_c, "mixing": mixing.tolist(),
             "unmixed_noise_sigma": sig_u.tolist(), "unmixed_shot_gain": shot_u.tolist()}
    if bits:
        B = code.n_bits
        k = noise_k(H * W * B * 3, params.false_alarm)
        for i in range(3):  # each channel keeps only the pixels it owns
            u[i][:, owner != i] = 0.0
        zero = np.zeros(F)
        px = [_bit_pixels(u[i], B, code.complementary, code.source_of_codeword(i), zero, sig_u[i], shot_u[i], rho, k)
              for i in range(3)]
        labels = np.full((H, W), -1, np.int64)
        signal = np.zeros((H, W))
        pairs = None if px[0]["pairs"] is None else np.full((H, W, 2), -1, np.int64)
        collision = colour_coll.copy()
        counts = {key: 0 for key in ("lit", "decoded", "uncertain", "invalid")}
        for i, p in enumerate(px):
            mine = owner == i
            labels = np.where(mine & (p["labels"] >= 0), p["labels"], labels)
            signal += np.where(mine, p["signal"], 0.0)
            collision |= mine & p["collision"]
            if pairs is not None:
                pairs[mine & p["collision"]] = p["pairs"][mine & p["collision"]]
            for key in counts:
                counts[key] += int((mine & p[key]).sum())
        notes.extend(px[0]["notes"])
        table = _regions(labels, signal, sat, code.n_sources, params)
        counts.update(collisions=int(collision.sum()), colour_collisions=int(colour_coll.sum()),
                      saturated=int(sat.sum()), highlights=len(table))
        noise["k"] = k
        if rho is not None:
            noise["crosstalk"] = rho
        dec = Decoded(table, labels, collision, sat, counts, notes, signal.astype(np.float32), pairs, None, None,
                      noise)
    else:
        # each source's frame from its own channel; the noise is measured before the pixels other channels own
        # are set to 0 (a frame mostly of zeros would understate it)
        D = code.demultiplexer()
        dparams = params.detect if params.detect is not None else DetectParams()
        x = np.empty((code.n_sources, H, W), np.float32)
        x_sigma = 0.0
        n_hot = 0
        for i in range(3):
            idx = np.flatnonzero(code.channels == i)
            if len(idx):
                sub = (D[idx] @ u[i].reshape(F, -1).astype(np.float64)).reshape(len(idx), H, W).astype(np.float32)
                sigmas = [dparams.noise_sigma if dparams.noise_sigma is not None else estimate_noise(f) for f in sub]
                x_sigma = max([x_sigma] + sigmas)
                if dparams.hot_pixels:
                    # a hot pixel of one camera channel is in every frame of that colour only: a third of the
                    # sources, too few for detection's test (half the frames), so it is found per channel
                    hot = hot_pixel_mask(sub, sigmas, hot_pixel_k(H * W, dparams.false_alarm))
                    n_hot += int(hot.sum())
                    sub = replace_hot_pixels(sub, hot)
                sub[:, owner != i] = 0.0
                x[idx] = sub
        # detection then runs on frames whose hot pixels are gone (its own test would see the zeros of the
        # pixels other channels own as spikes); its noise is the frames' before the zeros, the largest of them
        dparams = replace(dparams, hot_pixels=False)
        if dparams.noise_sigma is None and not ideal:
            dparams = replace(dparams, noise_sigma=x_sigma)
        params = replace(params, detect=dparams)
        dec = _detect_sources(x, (H, W), code, params, bg, sig, shot, sat, rig, camera_index)
        # a label is the brightest source of the pixel's channel; where another channel holds more light than
        # that source, a source of another colour may be brighter: left unlabelled
        lab = dec.labels
        has = lab >= 0
        own = np.zeros((H, W))
        own[has] = x[lab[has], np.nonzero(has)[0], np.nonzero(has)[1]] - np.asarray(
            dec.stack.provenance["pedestal"])[lab[has]]
        other = np.max(np.where(np.arange(3)[:, None, None] == dom[None], -np.inf, light), axis=0)
        unsure = has & ~colour_coll & (own < other)
        lab[colour_coll | unsure] = -1
        dec.collision |= colour_coll
        dec.counts.update(lit=int((lab >= 0).sum()), decoded=int((lab >= 0).sum()), uncertain=int(unsure.sum()),
                          collisions=int(dec.collision.sum()), colour_collisions=int(colour_coll.sum()))
        dec.noise.update(noise)
        notes = dec.notes
        if n_hot:
            notes.append(f"{n_hot} hot pixel(s) of single colour channels replaced by their 3 x 3 median")
    if colour_coll.any():
        notes.append(f"{int(colour_coll.sum())} pixel(s) with light beyond the colour tolerance {tau:.3g} in a second "
                     "channel (overlapping highlights of different colours, or a tinted surface the calibration does "
                     f"not know{', or clipping' if clip_doubt.any() else ''}): flagged, not labelled")
    if bits and sat.any():
        notes.append(f"{int(sat.sum())} pixel(s) at the clip level in some frame and channel: their signal (and so "
                     "the centroids of highlights that hold them) is too low")
    dec.channel = owner
    dec.light = np.moveaxis(light, 0, -1).astype(np.float32)
    return dec


def _regions(labels, signal, sat, n_sources, params):
    """One highlight per connected region of same-source pixels at or above ``threshold`` of the source's peak
    (``threshold_mode="scan"``: of the brightest source's)."""
    H, W = labels.shape
    decoded = labels >= 0
    peak = np.zeros(n_sources)
    np.maximum.at(peak, labels[decoded], signal[decoded])
    if params.threshold_mode == "scan":
        peak[:] = peak.max(initial=0.0)
    keep = decoded & (signal >= params.threshold * peak[np.where(decoded, labels, 0)]) & (signal > 0)
    # regions of equal source: each source's pixels as a frame of their own, labelled and measured by detection
    flat = np.flatnonzero(keep)
    regions = regions_of_pixels(labels.reshape(-1)[flat], flat, (n_sources, H, W), params.connectivity)
    found = measure_highlights(regions, regions.values(signal), DetectParams(max_area=params.max_area),
                               level=0.0, raw=regions.values(sat).astype(float), saturation=1.0)
    min_area = int(params.min_area) if params.min_area is not None else auto_min_area(regions.area)
    # each source's whole regions first, then the parts of its subdivided ones
    order = np.lexsort((found["part"] > 0, found["source"]))
    order = order[found["region_area"][order] >= min_area]
    return _decoded_table(*(found[k][order] for k in ("source", "row", "col", "area", "peak", "sum", "saturated")))


def demultiplex(frames: Any, code: Code, *, background: Any = 0.0) -> np.ndarray:
    """Per-source frames from coded frames: ``x = D (y - background)`` per pixel.

    Parameters
    ----------
    frames : (n_frames, H, W) array_like
    code : Code
        Sequential or Hadamard (:meth:`~shinysim.theory.coding.Code.demultiplexer`).
    background : float or (n_frames,) array_like
        Dark level of each frame, subtracted first (a constant left in
        would come back as ``2 / (n + 1)`` of itself in every source frame).

    Returns
    -------
    (n_sources, H, W) float32
        Unclipped: noise makes dark pixels negative as often as positive.

    Notes
    -----
    Computed in blocks of rows in float64 (at most ``2**22`` values per
    block); no float64 copy of the stack is made.
    """
    d = check_code(code).demultiplexer()
    arr = np.asarray(frames)
    if arr.ndim != 3 or arr.shape[0] != code.n_frames:
        raise OptionError(f"the {code.name} code has {code.n_frames} frames; got shape {arr.shape}", field="frames")
    bg = np.broadcast_to(np.asarray(background, dtype=np.float64), (code.n_frames,))
    F, H, W = arr.shape
    out = np.empty((code.n_sources, H, W), np.float32)
    rows = max(1, _BLOCK // max(1, max(F, code.n_sources) * W))
    for r0 in range(0, H, rows):
        block = arr[:, r0:r0 + rows, :].astype(np.float64).reshape(F, -1) - bg[:, None]
        out[:, r0:r0 + rows, :] = (d @ block).reshape(code.n_sources, -1, W)
    return out


def _detect_sources(x, shape, code, params, bg, sig, shot, sat, rig, camera_index):
    """Detection of demultiplexed per-source frames ``x`` (float32, changed in place): sequential and Hadamard codes."""
    pedestal = np.zeros(code.n_sources)
    for i in range(code.n_sources):  # a pedestal per frame keeps it >= 0 without clipping its noise
        m = float(x[i].min())
        if m < 0:
            x[i] -= np.float32(m)  # rounding is monotonic: x - min >= 0 exactly
            pedestal[i] = -np.float32(m)
    provenance = {"demultiplexed": code.to_dict(), "pedestal": pedestal.tolist(), "background": bg.tolist()}
    stack = Stack(x, rig, camera_index, provenance, saturation=None)
    dparams = params.detect if params.detect is not None else DetectParams()
    if params.min_area is not None and dparams.min_area is None:
        dparams = replace(dparams, min_area=int(params.min_area))
    recon = detect_stack(stack, dparams)
    t = recon.table
    # a highlight is saturated where a clipped pixel lies within its equivalent radius of its centroid
    saturated = np.zeros(len(t["row"]), bool)
    if sat.any() and len(t["row"]):
        dist = ndimage.distance_transform_edt(~sat)
        r = np.clip(np.rint(t["row"]).astype(int), 0, sat.shape[0] - 1)
        c = np.clip(np.rint(t["col"]).astype(int), 0, sat.shape[1] - 1)
        saturated = dist[r, c] <= np.sqrt(t["area"] / np.pi) + 1.0
    table = _decoded_table(t["source"], t["row"], t["col"], t["area"], t["peak"], t["sum"], saturated)
    # per pixel: the brightest source where it stands out of its frame's noise
    k = recon.detection["noise_k"]
    level = np.array([k * s for s in recon.detection["noise_sigma"]]) + pedestal
    best = np.full(shape, -np.inf, np.float32)
    labels = np.full(shape, -1, np.int64)
    n_sig = np.zeros(shape, np.int64)
    for i in range(code.n_sources):
        above = x[i] > level[i]
        if not above.any():
            continue
        n_sig += above
        better = above & (x[i] - np.float32(pedestal[i]) > best)
        best[better] = x[i][better] - np.float32(pedestal[i])
        labels[better] = i
    collision = n_sig > 1
    notes = list(recon.notes)
    if sat.any():
        notes.append(f"{int(sat.sum())} pixel(s) at the clip level in some frame: demultiplexing spreads the "
                     "error to every source's frame there")
    counts = {"lit": int((labels >= 0).sum()), "decoded": int((labels >= 0).sum()),
              "collisions": int(collision.sum()), "uncertain": 0, "invalid": 0, "saturated": int(sat.sum()),
              "highlights": len(t["row"])}
    noise = {"background": bg.tolist(), "noise_sigma": sig.tolist(), "shot_gain": shot, "k": k,
             "demultiplexed_noise_sigma": recon.detection["noise_sigma"]}
    return Decoded(table, labels, collision, sat, counts, notes, None, None, stack, recon, noise)


# -- signal to noise -------------------------------------------------------------------


def measure_snr_gain(sequential: Any, multiplexed: Any, ideal: Any, *, region: str = "all") -> dict[str, Any]:
    """Measured noise gain of a multiplexed scan over a sequential one of the same scene.

    Both scans are demultiplexed (:func:`demultiplex`, each frame's
    background removed as :func:`decode` removes it) and compared with the
    noiseless per-source frames; the gain is the rms error of the
    sequential scan's source frames over that of the multiplexed one's
    (> 1: multiplexing helps), to set against
    :func:`~shinysim.theory.coding.hadamard_snr_gain`.

    Parameters
    ----------
    sequential, multiplexed : CodedStack
        Scans of one scene (sequential and Hadamard codes for the same
        sources), normally with the same sensor exposure per frame.
    ideal : (n_sources, H, W) array_like
        Noiseless per-source frames above the black level, in the scans'
        units (:func:`shinysim.sim.coded.expected_frames`).
    region : {"all", "lit", "unlit"}
        Pixels pooled: every pixel of every source frame; those where the
        source's own ideal frame is > 0 (its highlights); or those where it
        is 0 but another source's is > 0 (the noise a highlight leaves in
        the other sources' frames). Pixels at the clip level in any frame
        of either scan are left out.

    Returns
    -------
    dict
        ``gain``; ``sigma_sequential`` and ``sigma_multiplexed`` (rms
        errors); ``bias_sequential`` and ``bias_multiplexed`` (mean errors);
        ``n_samples``; ``stderr`` of the gain, ``gain * sqrt(1 / n)``: each
        rms of ``n`` independent Gaussian errors has relative standard
        error ``1 / sqrt(2 n)`` (a multiplexed pixel's source errors are
        nearly independent: their correlation is ``-1 / n`` for an S-matrix).
    """
    check_choice("region", region, SNR_REGIONS)
    ideal = np.asarray(ideal, dtype=np.float32)
    errors, clipped = [], None
    for coded, name in ((sequential, "sequential"), (multiplexed, "multiplexed")):
        frames, code, _, _, saturation, sensor, _ = _inputs(coded, None, None, 0, None, None)
        if code.n_sources != ideal.shape[0] or frames.shape[1:] != ideal.shape[1:]:
            raise OptionError(f"has {code.n_sources} sources of {frames.shape[1:]} pixels but ideal is "
                              f"{ideal.shape}", field=name)
        bg, _, _ = _levels(frames, DecodeParams(noise_sigma=0.0), sensor)
        errors.append(demultiplex(frames, code, background=bg) - ideal)
        if saturation is not None:
            s = (frames >= saturation).any(axis=0)
            clipped = s if clipped is None else clipped | s
    use = np.ones(ideal.shape, bool)
    if region == "lit":
        use = ideal > 0
    elif region == "unlit":
        use = (ideal == 0) & (ideal > 0).any(axis=0)[None]
    if clipped is not None:
        use &= ~clipped[None]
    n = int(use.sum())
    if n == 0:
        raise OptionError(f"no pixel of region {region!r} to measure", field="region")
    rms = [float(np.sqrt(np.mean(np.square(e[use], dtype=np.float64)))) for e in errors]
    bias = [float(np.mean(e[use], dtype=np.float64)) for e in errors]
    gain = rms[0] / rms[1] if rms[1] > 0 else np.inf
    return {"gain": gain, "sigma_sequential": rms[0], "sigma_multiplexed": rms[1], "bias_sequential": bias[0],
            "bias_multiplexed": bias[1], "n_samples": n, "stderr": gain * np.sqrt(1.0 / n), "region": region}
