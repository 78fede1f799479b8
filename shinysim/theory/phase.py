r"""Phase codes: the code family's member for a dense source array (a display).

The discrete codes of :mod:`shinysim.theory.coding` say which of tens to
thousands of sources each frame lights. A display is a continuum of sources,
and the code the field uses on it is the phase-shifted sinusoid: frame ``k``
of a period ``P`` (periods per screen) shows

.. math:: I_k(c) = \tfrac12 + \tfrac12 \cos(2\pi P c - \delta_k), \qquad \delta_k = 2\pi k / N

across the screen coordinate ``c`` (a fraction of the screen, 0 to 1), so
that every camera pixel can decode *which display point it sees* from ``N``
frames per period: the phase :math:`\varphi = \operatorname{atan2}(\sum_k I_k
\sin\delta_k, \sum_k I_k \cos\delta_k)` is :math:`2\pi P c` modulo
:math:`2\pi`. A first period below one per screen is unambiguous over the
whole screen; each finer period refines it (temporal unwrapping,
:func:`shinysim.recon.phase.decode_phase`).

:class:`PhaseCode` fixes the periods, the shifts and the frame order
(SOFAST's: the y periods first, ``N`` frames each, then the x ones) and the
coordinates: ``c_x`` is the screen's x fraction ``fx``; ``c_y = 1 - fy`` (the
y fringes run down the screen, SOFAST's convention). :func:`position_noise`
is the noise law a decoded position follows. numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._shared import check_number
from ..errors import OptionError

__all__ = ["PhaseCode", "SOFAST_PERIODS", "position_noise"]

#: SOFAST's periods per screen (OpenCSP's ``Fringes.from_num_periods``: 4^k, the first 0.1 less so that it
#: covers the screen once, without wrapping).
SOFAST_PERIODS = (0.9, 3.9, 15.9, 63.9)


def _periods(name, value):
    try:
        p = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise OptionError(f"{name} must be a sequence of periods per screen, got {value!r}") from None
    if not p:
        raise OptionError(f"{name} needs at least one period")
    if not all(math.isfinite(v) and v > 0 for v in p):
        raise OptionError(f"{name} must be finite and > 0 periods per screen, got {p}")
    if p[0] >= 1.0:
        raise OptionError(f"{name}[0] = {p[0]:g}: the first period must be under one per screen, or the "
                          "decoded position wraps across the screen")
    if any(b <= a for a, b in zip(p, p[1:])):
        raise OptionError(f"{name} must increase (coarse to fine), got {p}")
    return p


@dataclass(frozen=True)
class PhaseCode:
    """N-step phase shifting at several periods, in x and y.

    Parameters
    ----------
    periods_x, periods_y : sequence of float
        Periods per screen, coarse to fine; the first under 1 (it covers the
        screen without wrapping). Default SOFAST's :data:`SOFAST_PERIODS`.
    shifts : int
        Frames per period, N >= 3, shifted by 2 pi / N.

    Notes
    -----
    Frames are ordered as SOFAST records them: for each y period its N
    shifts, then the same for x (:attr:`n_frames` in all).
    """

    periods_x: tuple = SOFAST_PERIODS
    periods_y: tuple = SOFAST_PERIODS
    shifts: int = 4

    def __post_init__(self):
        object.__setattr__(self, "periods_x", _periods("periods_x", self.periods_x))
        object.__setattr__(self, "periods_y", _periods("periods_y", self.periods_y))
        check_number("shifts", self.shifts, lo=3, hi=64, integer=True)
        object.__setattr__(self, "shifts", int(self.shifts))

    @property
    def n_frames(self) -> int:
        return self.shifts * (len(self.periods_x) + len(self.periods_y))

    @property
    def deltas(self) -> np.ndarray:
        """(N,) the phase shifts, radians."""
        return 2.0 * np.pi * np.arange(self.shifts) / self.shifts

    def frame_table(self):
        """One ``(axis, period, shift index)`` per frame, in frame order."""
        return [(axis, p, k) for axis, periods in (("y", self.periods_y), ("x", self.periods_x))
                for p in periods for k in range(self.shifts)]

    def intensity(self, fx, fy) -> np.ndarray:
        """(n_frames, ...) the displayed intensity, 0 to 1, at screen fractions ``(fx, fy)`` (each ``(...)``).

        ``c_x = fx`` and ``c_y = 1 - fy`` are the coded coordinates
        (module notes).
        """
        fx = np.asarray(fx, float)
        fy = np.asarray(fy, float)
        out = []
        for axis, p, k in self.frame_table():
            c = fx if axis == "x" else 1.0 - fy
            out.append(0.5 + 0.5 * np.cos(2 * np.pi * p * c - self.deltas[k]))
        return np.stack(out)


def position_noise(noise_sigma, modulation, period: float, shifts: int = 4):
    """The standard deviation of a decoded position, in screen fractions (the noise law).

    A pixel's frames ``I_k = A + B cos(phi - delta_k) + n_k`` with white
    noise ``n_k`` of standard deviation ``sigma`` give a phase whose standard
    deviation is ``sigma sqrt(2 / N) / B`` (small noise), and a position
    ``phi / (2 pi P)`` at the finest period ``P``:

    .. math:: \\sigma_c = \\frac{\\sigma}{B}\\,\\sqrt{\\frac{2}{N}}\\,\\frac{1}{2\\pi P}

    Parameters
    ----------
    noise_sigma : float or array
        Standard deviation of a frame's pixel value.
    modulation : float or array
        ``B``, in the same units.
    period : float
        The finest period, per screen.
    shifts : int
        ``N``.
    """
    return np.asarray(noise_sigma, float) / np.asarray(modulation, float) * np.sqrt(2.0 / shifts) / (
        2 * np.pi * period)
