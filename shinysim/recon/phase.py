"""Phase-coded frames back into display positions, pixel by pixel, with what cannot be trusted flagged.

The decoder of :class:`~shinysim.theory.phase.PhaseCode` frames (fringe
deflectometry): each camera pixel's frames give, per period, a phase
(``atan2`` of the frames against the shifts' sines and cosines), a modulation
(the sinusoid's amplitude) and a residual (what a sinusoid does not explain);
the coarsest period, under one per screen, places the pixel on the screen,
and each finer one refines it to the multiple of its own period nearest the
coarser estimate (temporal unwrapping, as SOFAST does it).

A pixel is *not decoded silently* when:

* its modulation at any period is below ``min_modulation_sigma`` times the
  frames' noise (``low_modulation``): the pixel sees no fringes (off the
  mirror, the screen's edge, a dust speck);
* a finer period disagrees with the coarser estimate by more than
  ``max_unwrap_fraction`` of the finer period (``unwrap_inconsistent``): the
  multiple of the period chosen is in doubt, and a wrong one moves the point
  by a whole period (a jump, not noise).

:class:`DisplayResponse` first maps camera values back to the display's
values (SOFAST's measured table, ``image_calibration.h5``, or a gamma), so
that a display's non-linear response does not bend the sinusoids.

numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._shared import check_number, with_overrides
from ..errors import FrameError, OptionError
from ..theory.phase import PhaseCode, position_noise

__all__ = ["DisplayResponse", "PhaseDecoding", "PhaseParams", "decode_phase"]


@dataclass(frozen=True)
class DisplayResponse:
    """Camera values to display values: the inverse of a display's (and camera's) intensity response.

    Parameters
    ----------
    camera_values, display_values : (n,) float
        A measured response: the camera's value when the display shows each
        display value (SOFAST's ``ImageCalibration``), display values
        increasing. Camera values that do not increase are dropped (as
        SOFAST drops them); outside the table, the end values.
    """

    camera_values: np.ndarray
    display_values: np.ndarray

    def __post_init__(self):
        cv = np.asarray(self.camera_values, float).ravel()
        dv = np.asarray(self.display_values, float).ravel()
        if cv.shape != dv.shape or cv.size < 2:
            raise OptionError(f"a response needs two equal-length tables of at least 2 values, got {cv.size} "
                              f"camera and {dv.size} display values")
        if not (np.all(np.isfinite(cv)) and np.all(np.isfinite(dv))):
            raise OptionError("the response's tables hold NaN or inf")
        if np.any(np.diff(dv) <= 0):
            raise OptionError("the response's display values must increase")
        keep = np.concatenate([[True], np.diff(cv) > 0])
        if keep.sum() < 2:
            raise OptionError("the response's camera values do not increase: no response to invert")
        object.__setattr__(self, "camera_values", cv[keep])
        object.__setattr__(self, "display_values", dv[keep])

    @classmethod
    def from_gamma(cls, gamma: float, *, display_max: float = 1.0, camera_max: float = 1.0, n: int = 257):
        """A display whose light is ``camera_max (d / display_max) ** gamma`` for display value ``d``."""
        check_number("gamma", gamma, lo=0.1, hi=10)
        d = np.linspace(0.0, display_max, n)
        return cls(camera_max * (d / display_max) ** gamma, d)

    def __call__(self, values) -> np.ndarray:
        """Display values of camera ``values`` (any shape)."""
        return np.interp(np.asarray(values, float), self.camera_values, self.display_values)


@dataclass(frozen=True)
class PhaseParams:
    """Settings of :func:`decode_phase`.

    Parameters
    ----------
    min_modulation_sigma : float
        A pixel whose modulation at some period is below this many noise
        standard deviations is flagged ``low_modulation`` (its phase error
        would be ~1/this of a radian or worse).
    max_unwrap_fraction : float
        A pixel whose finer period lands farther than this fraction of that
        period from the coarser estimate is flagged ``unwrap_inconsistent``
        (correct unwrapping leaves it within the coarser estimate's noise, a
        small fraction; a wrong multiple is off by half a period or more).
    noise_sigma : float, optional
        The frames' pixel noise (after the response), if known; else
        estimated from neighbouring pixels' differences of what no sinusoid
        explains (:func:`decode_phase` notes).
    """

    min_modulation_sigma: float = 5.0
    max_unwrap_fraction: float = 0.25
    noise_sigma: float | None = None

    def __post_init__(self):
        check_number("min_modulation_sigma", self.min_modulation_sigma, lo=0)
        check_number("max_unwrap_fraction", self.max_unwrap_fraction, lo=0, lo_open=True, hi=0.5)
        if self.noise_sigma is not None:
            check_number("noise_sigma", self.noise_sigma, lo=0)


@dataclass(frozen=True)
class PhaseDecoding:
    """Decoded display positions (:func:`decode_phase`).

    Attributes
    ----------
    decoded : (H, W, 2) float
        ``(fx, fy)``: where each pixel of the region with any modulation
        sees the screen, in screen fractions (SOFAST's fractional screens),
        whatever its flags say; NaN elsewhere.
    fraction : (H, W, 2) float
        ``decoded`` where ``valid``, NaN elsewhere (a property).
    valid : (H, W) bool
        Inside the region asked for, modulated and consistently unwrapped.
    low_modulation, unwrap_inconsistent : (H, W) bool
        Why a pixel of the region is not valid.
    modulation : (H, W, 2) float
        The finest period's modulation in x and y (display values).
    noise_sigma : float
        The frames' noise used (given or estimated).
    position_sigma : (H, W, 2) float
        The noise law's standard deviation of each decoded position
        (:func:`~shinysim.theory.phase.position_noise`), screen fractions.
    unwrap_margin : (H, W, 2) float
        The largest disagreement between a period and the coarser estimate,
        as a fraction of that period.
    """

    decoded: np.ndarray
    valid: np.ndarray
    low_modulation: np.ndarray
    unwrap_inconsistent: np.ndarray
    modulation: np.ndarray
    noise_sigma: float
    position_sigma: np.ndarray
    unwrap_margin: np.ndarray

    @property
    def fraction(self) -> np.ndarray:
        return np.where(self.valid[..., None], self.decoded, np.nan)


def _axis(frames, periods, deltas):
    """Per period: phase, modulation and residual of each pixel's frames (N shifts per period)."""
    n = len(deltas)
    c, s = np.cos(deltas), np.sin(deltas)
    out = []
    for i, _ in enumerate(periods):
        block = frames[..., n * i:n * (i + 1)]
        re = block @ c
        im = block @ s
        mean = block.mean(axis=-1)
        phase = np.arctan2(im, re)
        amp = 2.0 / n * np.hypot(re, im)
        fit = mean[..., None] + amp[..., None] * np.cos(phase[..., None] - deltas)
        out.append((phase, amp, block - fit))
    return out


def _noise(frames, n_y, code, region):
    """The frames' noise, from neighbouring pixels' differences of what no sinusoid can explain.

    Per pixel and period, the frames are projected on a unit vector orthogonal to the sinusoid's three
    terms (the residual's first direction; with three shifts there is none, and the frames' mean is used,
    scaled by sqrt(N)). A display's imperfect response and the camera's blur leave harmonics in that
    projection, but they change smoothly across the image with the fringes' phase; the noise does not.
    So the noise is read from the differences between horizontal neighbours inside the region (median
    absolute deviation, over sqrt 2), at the coarsest period of each axis, where the harmonics' phase
    moves slowest. 0 where the region is too small to tell.
    """
    n = code.shifts
    d = code.deltas
    basis = np.column_stack([np.ones(n), np.cos(d), np.sin(d)])
    if n > 3:
        u = np.linalg.svd(basis, full_matrices=True)[0][:, 3]  # a unit vector orthogonal to the model
    else:
        u = np.ones(n) / np.sqrt(n)
    both = region[:, 1:] & region[:, :-1]
    if not both.any():
        return 0.0
    estimates = []
    for start in (0, n_y):  # the coarsest period of y, then of x
        e = frames[..., start:start + n] @ u
        diff = np.diff(e, axis=1)[both]
        estimates.append(1.4826 * float(np.median(np.abs(diff - np.median(diff)))) / np.sqrt(2.0))
    return float(np.sqrt(np.mean(np.square(estimates))))


def _unwrap(axis, periods):
    x = margin = None
    for (phase, _, _), p in zip(axis, periods):
        w = np.mod(phase, 2 * np.pi) / (2 * np.pi * p)
        if x is None:
            x = w
            margin = np.zeros_like(w)
            continue
        f = 1.0 / p
        new = w + f * np.round((x - w) / f)
        margin = np.maximum(margin, np.abs(new - x) / f)
        x = new
    return x, margin


def decode_phase(frames, code: PhaseCode | None = None, *, region=None, response: DisplayResponse | None = None,
                 params: PhaseParams | None = None, **kwargs) -> PhaseDecoding:
    """Each pixel's display position from phase-coded frames.

    Parameters
    ----------
    frames : (H, W, n_frames) array_like
        The camera frames in the code's order (:class:`PhaseCode`).
    code : PhaseCode, optional
        Default SOFAST's (4 periods, 4 shifts, y first).
    region : (H, W) bool, optional
        Pixels to decode (default all); the others are NaN and not valid.
    response : DisplayResponse, optional
        Applied to the frames first.
    params : PhaseParams, optional

    Returns
    -------
    PhaseDecoding
    """
    p = with_overrides(PhaseParams, params, kwargs)
    code = PhaseCode() if code is None else code
    f = np.asarray(frames)
    if f.ndim != 3 or f.shape[-1] != code.n_frames:
        raise FrameError(f"must be (H, W, {code.n_frames}) frames for a code of {code.n_frames}, got shape {f.shape}",
                         field="frames")
    if not np.issubdtype(f.dtype, np.number) or np.issubdtype(f.dtype, np.complexfloating):
        raise FrameError(f"must hold real numbers, got {f.dtype}", field="frames")
    f = f.astype(np.float64)
    if not np.all(np.isfinite(f)):
        raise FrameError("hold NaN or inf", field="frames")
    H, W = f.shape[:2]
    region = np.ones((H, W), bool) if region is None else np.asarray(region, bool)
    if region.shape != (H, W):
        raise FrameError(f"region shape {region.shape} differs from the frames' {(H, W)}", field="region")
    if response is not None:
        f = response(f)
    n_y = code.shifts * len(code.periods_y)
    ay = _axis(f[..., :n_y], code.periods_y, code.deltas)
    ax = _axis(f[..., n_y:], code.periods_x, code.deltas)
    if p.noise_sigma is not None:
        sigma = float(p.noise_sigma)
    else:
        sigma = _noise(f, n_y, code, region)
    cx, mx = _unwrap(ax, code.periods_x)
    cy, my = _unwrap(ay, code.periods_y)
    amp_min = np.min(np.stack([a for _, a, _ in ay + ax]), axis=0)
    low = region & (amp_min <= p.min_modulation_sigma * sigma) if sigma > 0 else region & (amp_min <= 0)
    inconsistent = region & ~low & (np.maximum(mx, my) > p.max_unwrap_fraction)
    valid = region & ~low & ~inconsistent
    decoded = np.stack([cx, 1.0 - cy], axis=-1)
    decoded[~(region & (amp_min > 0))] = np.nan
    mod = np.stack([ax[-1][1], ay[-1][1]], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        sig = np.stack([position_noise(sigma, mod[..., 0], code.periods_x[-1], code.shifts),
                        position_noise(sigma, mod[..., 1], code.periods_y[-1], code.shifts)], axis=-1)
    return PhaseDecoding(decoded=decoded, valid=valid, low_modulation=low, unwrap_inconsistent=inconsistent,
                         modulation=mod, noise_sigma=sigma, position_sigma=sig,
                         unwrap_margin=np.stack([mx, my], axis=-1))
