"""A camera sensor for simulated stacks: from rendered radiance to digital numbers.

:class:`Sensor` applies a camera's chain (shot noise, full well, read noise,
black level, ADC, optional PRNU, hot pixels and cos^4 vignetting) to an ideal
stack: :meth:`Sensor.expose` returns a new stack whose provenance records the
sensor and the seed, :meth:`Sensor.capture` works on a bare array, and
:data:`SENSOR_PRESETS` / :func:`sensor_preset` hold a 1980s TV camera and a
modern machine-vision one. Frame ``k`` draws its noise from
``np.random.default_rng([seed, k])``; the fixed pattern from ``pattern_seed``
alone. numpy only. The equations, determinism and presets:
``docs/sensor.md``.
"""

from __future__ import annotations

import copy
import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

from .._shared import check_attributes, check_choice, check_number, derive_seed, named_check
from ..errors import OptionError, check_fields, did_you_mean
from ..io import Stack

__all__ = [
    "CAMERA_CROSSTALK",
    "POISSON_LIMIT",
    "SENSOR_BITS",
    "SENSOR_PRESETS",
    "Sensor",
    "sensor_preset",
    "check_colour_matrix",
]

#: The bit depths a :class:`Sensor` digitises to.
SENSOR_BITS = (8, 10, 12, 16)

#: Mean electron count above which shot noise is drawn from the Gaussian
#: approximation of the Poisson law instead of the Poisson law itself.
POISSON_LIMIT = 1e6

#: Colour crosstalk of a colour machine-vision camera under narrow-band
#: red, green and blue fibers: row ``i`` is camera channel ``i``'s (R, G, B)
#: response to red, green and blue light, each colour's own channel
#: white-balanced to 1; typical of a Bayer-filter CMOS sensor (where the
#: numbers come from: ``docs/coded-scanning.md``, "The colour camera").
CAMERA_CROSSTALK = np.array([
    [1.00, 0.08, 0.03],
    [0.10, 1.00, 0.15],
    [0.02, 0.18, 1.00],
])
CAMERA_CROSSTALK.setflags(write=False)

@dataclass(frozen=True)
class Sensor:
    """A camera sensor: exposure, noise, full well, black level and quantisation.

    Parameters
    ----------
    name : str
        Free label (the preset's name for a preset).
    bits : {8, 10, 12, 16}
        ADC depth; codes run from 0 to ``2**bits - 1``.
    exposure : float
        Photo-electrons per pixel per unit of rendered radiance (quantum
        efficiency, photon flux and exposure time folded into one number).
        :meth:`exposed_for` picks one from the brightest radiance.
    full_well : float
        Electrons at which a pixel saturates; it reads the top code.
    read_noise : float
        Electrons rms, Gaussian, added after the full-well clip.
    dark_offset : float
        Black level in DN, added before quantisation; in ``[0, 2**bits - 1)``.
    shot_noise : bool
        Poisson photon noise.
    prnu : float
        rms relative per-pixel gain variation (fixed pattern), in ``[0, 1]``.
    hot_pixel_fraction : float
        Fraction of pixels that are hot (fixed pattern), in ``[0, 1]``.
    hot_pixel_level : float
        A hot pixel's extra signal, as a fraction of full scale, in ``[0, 1]``.
    vignetting : float
        Relative irradiance loss at the image corners (cos^4 falloff;
        0 = none), in ``[0, 1)``.
    pattern_seed : int
        Seeds the fixed pattern (PRNU, hot pixels): a property of the
        camera, not of the frame.

    Every field is checked; a bad one raises
    :class:`~shinysim.errors.OptionError` naming it (also as ``.field``).
    """

    name: str = "custom"
    bits: int = 12
    exposure: float = 1e5
    full_well: float = 10_000.0
    read_noise: float = 2.5
    dark_offset: float = 0.0
    shot_noise: bool = True
    prnu: float = 0.0
    hot_pixel_fraction: float = 0.0
    hot_pixel_level: float = 0.5
    vignetting: float = 0.0
    pattern_seed: int = 0

    def __post_init__(self):
        if not isinstance(self.name, str):
            raise OptionError(f"name must be a string, got {self.name!r}", field="name")
        if isinstance(self.bits, (bool, np.bool_)):
            raise OptionError(f"bits must be one of {', '.join(map(str, SENSOR_BITS))}; got {self.bits!r}",
                              field="bits")
        object.__setattr__(self, "bits", int(named_check("bits", check_choice, self.bits, SENSOR_BITS)))
        check_attributes(self, {"exposure": dict(lo=0, lo_open=True, hi=1e30),
                                "full_well": dict(lo=0, lo_open=True, hi=1e9), "read_noise": dict(lo=0, hi=1e9)},
                         named=True)
        check_attributes(self, {"dark_offset": dict(lo=0, hi=self.full_scale, hi_open=True)}, named=True)
        if not isinstance(self.shot_noise, (bool, np.bool_)):
            raise OptionError(f"shot_noise must be True or False, got {self.shot_noise!r}", field="shot_noise")
        object.__setattr__(self, "shot_noise", bool(self.shot_noise))
        check_attributes(self, {"prnu": dict(lo=0, hi=1), "hot_pixel_fraction": dict(lo=0, hi=1),
                                "hot_pixel_level": dict(lo=0, hi=1), "vignetting": dict(lo=0, hi=1, hi_open=True),
                                "pattern_seed": dict(lo=0, integer=True)}, named=True)

    # -- derived numbers -----------------------------------------------------------
    @property
    def full_scale(self) -> int:
        """The top code, ``2**bits - 1``."""
        return 2 ** self.bits - 1

    @property
    def gain(self) -> float:
        """DN per electron: ``(2**bits - 1 - dark_offset) / full_well`` (a full well reads the top code)."""
        return (self.full_scale - self.dark_offset) / self.full_well

    def with_exposure(self, exposure: float) -> Sensor:
        """This sensor with another exposure (electrons per unit radiance)."""
        return replace(self, exposure=exposure)

    def exposed_for(self, peak_radiance: Any, fraction: float = 0.8) -> Sensor:
        """This sensor exposed so the brightest radiance fills ``fraction`` of the full well.

        Parameters
        ----------
        peak_radiance : float or array_like
            The brightest rendered radiance (of an array, its maximum), > 0.
        fraction : float
            Mean electrons at that radiance, as a fraction of ``full_well``,
            before vignetting and PRNU; in (0, 100] (above 1 over-exposes).

        Returns
        -------
        Sensor
            With ``exposure = fraction * full_well / peak_radiance``.
        """
        if isinstance(peak_radiance, (np.ndarray, list, tuple)):
            arr = np.asarray(peak_radiance, dtype=float)
            if arr.size == 0 or not np.all(np.isfinite(arr)):
                raise OptionError("must be a non-empty array of finite radiances", field="peak_radiance")
            peak_radiance = float(arr.max())
        peak = named_check("peak_radiance", check_number, peak_radiance, lo=0, lo_open=True)
        fraction = named_check("fraction", check_number, fraction, lo=0, lo_open=True, hi=100)
        return self.with_exposure(fraction * self.full_well / peak)

    def noise_sigma(self, signal_dn: Any) -> float | np.ndarray:
        """Expected temporal noise (DN rms) of a pixel at a mean signal above the black level.

        ``sqrt(gain**2 * (signal_dn / gain + read_noise**2) + 1/12)``, the shot
        term only with ``shot_noise``; 1/12 DN^2 is the quantisation noise (a
        good approximation once the other noise exceeds about 0.5 DN). Fixed
        pattern (PRNU, hot pixels) and clipping are left out. Divide by
        :attr:`full_scale` for frame units.

        Parameters
        ----------
        signal_dn : float or array_like
            Mean signal in DN above ``dark_offset``, >= 0.
        """
        s = np.asarray(signal_dn, dtype=float)
        if not np.all(np.isfinite(s)) or np.any(s < 0):
            raise OptionError(f"must be finite and >= 0 DN, got {signal_dn!r}", field="signal_dn")
        electrons = s / self.gain if self.shot_noise else 0.0 * s
        sigma = np.sqrt(self.gain**2 * (electrons + self.read_noise**2) + 1.0 / 12.0)
        return float(sigma) if sigma.ndim == 0 else sigma

    # -- fixed pattern -------------------------------------------------------------------
    def vignette(self, shape: tuple[int, int]) -> np.ndarray:
        """(H, W) relative irradiance ``v``: 1 at the image centre, ``1 - vignetting`` at the corners."""
        h, w = _shape(shape)
        cy, cx = 0.5 * (h - 1), 0.5 * (w - 1)
        rc2 = cy**2 + cx**2
        if self.vignetting == 0 or rc2 == 0:
            return np.ones((h, w))
        y = (np.arange(h) - cy)[:, None]
        x = (np.arange(w) - cx)[None, :]
        t2 = 1.0 / math.sqrt(1.0 - self.vignetting) - 1.0  # tan^2 of the corner's field angle
        return 1.0 / (1.0 + (y**2 + x**2) / rc2 * t2) ** 2

    def prnu_map(self, shape: tuple[int, int]) -> np.ndarray:
        """(H, W) per-pixel gain ``max(0, 1 + prnu * z)``, from ``pattern_seed`` only."""
        h, w = _shape(shape)
        if self.prnu == 0:
            return np.ones((h, w))
        rng = np.random.default_rng(derive_seed("sensor pattern", "prnu", self.pattern_seed))
        return np.maximum(0.0, 1.0 + self.prnu * rng.standard_normal((h, w)))

    def hot_pixels(self, shape: tuple[int, int]) -> np.ndarray:
        """(H, W) bool, the hot pixels, from ``pattern_seed`` only."""
        h, w = _shape(shape)
        if self.hot_pixel_fraction == 0:
            return np.zeros((h, w), bool)
        rng = np.random.default_rng(derive_seed("sensor pattern", "hot pixels", self.pattern_seed))
        return rng.random((h, w)) < self.hot_pixel_fraction

    # -- capture -------------------------------------------------------------------------
    def capture(self, radiance: Any, *, seed: int | None = None,
                rng: np.random.Generator | None = None) -> np.ndarray:
        """Digitise ideal radiance: frames in [0, 1], multiples of ``1 / (2**bits - 1)``.

        Parameters
        ----------
        radiance : (n, H, W) or (H, W) array_like
            Rendered radiance, finite and >= 0.
        seed : int, optional
            Frame ``k`` draws its noise from ``np.random.default_rng([seed, k])``.
        rng : numpy.random.Generator, optional
            Instead of ``seed``: one generator for all frames, in order (then
            frame ``k`` depends on the frames before it). Give one of the two.

        Returns
        -------
        ndarray, float32, the shape of ``radiance``
            ``DN / (2**bits - 1)``.
        """
        if (seed is None) == (rng is None):
            raise OptionError("give either seed or rng", field="seed")
        if seed is not None:
            seed = named_check("seed", check_number, seed, lo=0, integer=True)
        elif not isinstance(rng, np.random.Generator):
            raise OptionError(f"must be a numpy Generator, got {type(rng).__name__}", field="rng")
        arr = _radiance(radiance, lambda a: a.ndim in (2, 3), "(n, H, W) or (H, W)")
        stack = arr if arr.ndim == 3 else arr[None]
        out = self._capture_frames(stack, lambda k: rng if rng is not None else np.random.default_rng([seed, k]))
        return out if arr.ndim == 3 else out[0]

    def capture_colour(self, radiance: Any, *, seed: int) -> np.ndarray:
        """Digitise ideal colour frames, each camera channel as :meth:`capture` does one frame.

        A colour camera's three channels are three sets of photosites (a
        Bayer mosaic's, or a prism camera's three chips) with this sensor's
        full well, noise and ADC each; each channel has its own fixed pattern
        (PRNU and hot pixels drawn from ``pattern_seed`` and the channel)
        and its own noise.

        Parameters
        ----------
        radiance : (n, H, W, 3) array_like
            Per camera channel, what :meth:`capture` takes: the light each
            channel's photosites see (colour crosstalk applied already), finite
            and >= 0.
        seed : int
            Frame ``k``, channel ``c`` draws its noise from
            ``np.random.default_rng([seed, k, c])``.

        Returns
        -------
        (n, H, W, 3) float32
            ``DN / (2**bits - 1)``.
        """
        seed = named_check("seed", check_number, seed, lo=0, integer=True)
        arr = _radiance(radiance, lambda a: a.ndim == 4 and a.shape[-1] == 3, "(n, H, W, 3)")
        out = np.empty(arr.shape, np.float32)
        for c in range(3):
            chan = self if c == 0 else replace(self, pattern_seed=derive_seed("colour channel", c, self.pattern_seed))
            out[..., c] = chan._capture_frames(arr[..., c], lambda k: np.random.default_rng([seed, k, c]))
        return out

    def _capture_frames(self, stack, frame_rng):
        """(n, H, W) float32 captures of the (n, H, W) radiance ``stack``, frame ``k`` with ``frame_rng(k)``."""
        shape = stack.shape[1:]
        response = self.exposure * self.vignette(shape) * self.prnu_map(shape)
        hot = self.hot_pixels(shape)
        out = np.empty(stack.shape, np.float32)
        for k in range(len(stack)):
            out[k] = self._capture_frame(stack[k] * response, hot, frame_rng(k))
        return out

    def _capture_frame(self, mean, hot, rng):
        fw = self.full_well
        # beyond this a pixel saturates whatever the noise (50 sigma): keeps the samplers finite
        mean = np.minimum(mean, fw + 50.0 * math.sqrt(fw) + 1000.0)
        if self.shot_noise:
            electrons = np.empty_like(mean)
            small = mean <= POISSON_LIMIT
            electrons[small] = rng.poisson(mean[small])
            big = ~small
            if big.any():
                electrons[big] = np.rint(mean[big] + np.sqrt(mean[big]) * rng.standard_normal(int(big.sum())))
        else:
            electrons = mean
        full = electrons >= fw
        electrons = np.minimum(electrons, fw)
        if self.read_noise > 0:
            electrons = electrons + self.read_noise * rng.standard_normal(mean.shape)
        dn = electrons * self.gain + self.dark_offset
        if hot.any():
            dn = dn + hot * (self.hot_pixel_level * self.full_scale)
        dn = np.clip(np.rint(dn), 0, self.full_scale)
        dn[full] = self.full_scale  # a full well reads the top code, read noise or not
        return (dn / self.full_scale).astype(np.float32)

    def expose(self, stack: Stack, *, seed: int) -> Stack:
        """Capture an ideal stack with this sensor: a new stack, the ideal one untouched.

        The new stack's frames are :meth:`capture` of the ideal frames, its
        ``saturation`` is 1.0 (the top code) and its provenance is the ideal
        one plus ``"sensor"`` (:meth:`to_dict`) and ``"sensor_seed"``.

        Raises
        ------
        OptionError
            For a stack that is not ideal: one with a clip level (read from
            image files, or captured already) or a sensor in its provenance.
        """
        if not isinstance(stack, Stack):
            raise OptionError(f"must be a shinysim Stack, got {type(stack).__name__}", field="stack")
        if "sensor" in stack.provenance or stack.saturation is not None:
            raise OptionError("is digitised already (it has a clip level or a sensor in its provenance); "
                              "expose the ideal float stack", field="stack")
        seed = named_check("seed", check_number, seed, lo=0, integer=True)
        frames = self.capture(stack.frames, seed=seed)
        provenance = {**copy.deepcopy(stack.provenance), "sensor": self.to_dict(), "sensor_seed": seed}
        return Stack(frames, stack.rig, stack.camera_index, provenance, saturation=1.0)

    # -- JSON --------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The sensor as plain JSON values, every field."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Sensor:
        """A sensor from :meth:`to_dict`'s output; missing fields take their defaults.

        Raises
        ------
        OptionError
            For an unknown field (with a did-you-mean) or a bad value.
        """
        check_fields(d, [f.name for f in fields(cls)], error=OptionError, field="sensor", what="sensor")
        return cls(**d)


def _shape(shape) -> tuple[int, int]:
    try:
        h, w = (int(n) for n in shape)
    except (TypeError, ValueError):
        raise OptionError(f"must be (H, W), got {shape!r}", field="shape") from None
    if h < 1 or w < 1:
        raise OptionError(f"must be at least 1 x 1 pixels, got {shape!r}", field="shape")
    return h, w


#: Named sensors. ``"ideal"`` is no sensor: the rendered float image. The
#: exposures put radiance 1 (a source of radiance 1 seen in a perfect
#: mirror) at 80% of the full well; :meth:`Sensor.exposed_for` sets another.
#: What each preset stands for, and where its numbers come from:
#: ``docs/sensor.md``, "Presets".
SENSOR_PRESETS: dict[str, Sensor | None] = {
    "ideal": None,
    # a 1980s CCD (or tube) TV camera at video rate, an 8-bit frame grabber
    "tv_1980s_8bit": Sensor(
        name="tv_1980s_8bit", bits=8, exposure=0.8 * 50_000.0, full_well=50_000.0, read_noise=100.0,
        dark_offset=8.0, prnu=0.02, hot_pixel_fraction=1e-4, hot_pixel_level=0.5, vignetting=0.25,
    ),
    # a modern global-shutter CMOS machine-vision camera (Sony Pregius class, e.g. IMX250)
    "machine_vision_12bit": Sensor(
        name="machine_vision_12bit", bits=12, exposure=0.8 * 10_500.0, full_well=10_500.0, read_noise=2.5,
        dark_offset=40.0, prnu=0.005, hot_pixel_fraction=1e-5, hot_pixel_level=0.5, vignetting=0.05,
    ),
}


def _radiance(radiance, shape_ok, shape_text):
    """``radiance`` as float64, else OptionError: not numbers, not of the ``shape_ok`` shape (``shape_text``),
    a NaN or inf pixel or a negative one."""
    try:
        arr = np.asarray(radiance, dtype=np.float64)
    except (TypeError, ValueError):
        raise OptionError("must be an array of numbers", field="radiance") from None
    if not shape_ok(arr):
        raise OptionError(f"must be {shape_text}, got shape {arr.shape}", field="radiance")
    bad = ~np.isfinite(arr)
    if bad.any():
        raise OptionError(f"{int(bad.sum())} NaN or inf pixel(s); radiance must be finite", field="radiance")
    if (arr < 0).any():
        raise OptionError(f"{int((arr < 0).sum())} negative pixel(s); radiance must be >= 0", field="radiance")
    return arr


def check_colour_matrix(matrix: Any, field: str = "crosstalk") -> np.ndarray:
    """A 3 x 3 colour matrix as float64: finite, >= 0 and invertible, else OptionError naming ``field``.

    What the camera's colour crosstalk (:data:`CAMERA_CROSSTALK`) and the
    decoder's unmixing matrix must be: a singular one would make two
    colours indistinguishable.
    """
    try:
        m = np.array(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise OptionError("must be a 3 x 3 array of numbers", field=field) from None
    if m.shape != (3, 3):
        raise OptionError(f"must be 3 x 3 (rows: camera channels R, G, B; columns: red, green, blue light), "
                          f"got shape {m.shape}", field=field)
    if not np.all(np.isfinite(m)) or np.any(m < 0):
        raise OptionError("must hold finite responses >= 0", field=field)
    cond = np.linalg.cond(m)
    if not np.isfinite(cond) or cond > 1e6:
        raise OptionError(f"is singular or nearly so (condition number {cond:.3g}): its colours cannot be "
                          "told apart", field=field)
    return m


def sensor_preset(name: str) -> Sensor | None:
    """The preset sensor called ``name`` (None for ``"ideal"``: no sensor).

    Raises
    ------
    OptionError
        For an unknown name, listing the presets.
    """
    if not isinstance(name, str) or name not in SENSOR_PRESETS:
        raise OptionError(f"unknown sensor {name!r}{did_you_mean(str(name), SENSOR_PRESETS)}; presets are "
                          f"{', '.join(SENSOR_PRESETS)}", field="sensor")
    return SENSOR_PRESETS[name]
