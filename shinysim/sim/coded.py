"""Coded scans from rendered per-source stacks: several sources per frame, then the sensor.

Light adds, so a coded scan needs no new render: :func:`coded_stack` sums a
rendered stack's frames (grey, or RGB from a :class:`ColourStack`) by the
code and hands each coded frame to a :class:`~shinysim.sim.sensor.Sensor`;
the result is a :class:`CodedStack`, which
:func:`shinysim.recon.coding.decode` turns back into highlights.
:func:`colour_mixing` is the colour camera's ``crosstalk @ emission``.
How to compare codes at equal frame or total exposure, and the colour
camera: ``docs/coded-scanning.md``, sections "Exposure" and "Colour
multiplexing".
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._shared import check_number
from ..errors import OptionError
from ..io import Stack, check_frames
from ..io.coded import CodedStack
from ..rig import Rig
from ..theory.coding import Code, encode, encode_colour, fiber_emission
from .sensor import CAMERA_CROSSTALK, Sensor, check_colour_matrix

__all__ = ["CodedStack", "ColourStack", "coded_stack", "colour_mixing", "expected_frames"]


@dataclass
class ColourStack:
    """Per-source frames in linear RGB, one camera: what a colour code is applied to.

    Parameters
    ----------
    frames : (n_sources, H, W, 3) float32
        Linear RGB radiance, one frame per source in source order, each
        source white (equal R, G, B emission): the fibers' colours are
        applied by :func:`coded_stack`. Finite and >= 0.
    rig : Rig
    camera_index : int
    provenance : dict
    """

    frames: np.ndarray
    rig: Rig
    camera_index: int = 0
    provenance: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        self.frames = np.asarray(self.frames, dtype=np.float32)
        if self.frames.ndim != 4 or self.frames.shape[-1] != 3:
            raise OptionError(f"must be (n_sources, H, W, 3), got shape {self.frames.shape}", field="frames")
        for c in range(3):
            check_frames(self.frames[..., c], self.rig, self.camera_index, what="frames")

    camera = Stack.camera
    n_sources = Stack.n_sources

    def channel(self, c: int) -> Stack:
        """Channel ``c`` (0, 1, 2: R, G, B) as a grey :class:`~shinysim.io.Stack`."""
        c = check_number("c", c, lo=0, hi=2, integer=True)
        return Stack(np.ascontiguousarray(self.frames[..., c]), self.rig, self.camera_index,
                     {**copy.deepcopy(self.provenance), "channel": "RGB"[c]})

    def grey(self) -> Stack:
        """The mean of R, G and B as a grey :class:`~shinysim.io.Stack` (float64 mean, rounded once)."""
        return Stack(self.frames.astype(np.float64).mean(axis=-1).astype(np.float32), self.rig, self.camera_index,
                     {**copy.deepcopy(self.provenance), "channel": "mean of RGB"})


def colour_mixing(crosstalk: Any = None, leak: float = 0.0) -> np.ndarray:
    """(3, 3) float64 ``crosstalk @ fiber_emission(leak)``: column ``c`` the camera's (R, G, B) response to fiber ``c``.

    What a calibration measures (each fiber colour lit alone on a white,
    grey or diffuse target) and what :func:`shinysim.recon.coding.decode`
    unmixes by. ``crosstalk`` defaults to :data:`~shinysim.sim.sensor.CAMERA_CROSSTALK`.
    """
    x = CAMERA_CROSSTALK if crosstalk is None else check_colour_matrix(crosstalk, "crosstalk")
    return np.asarray(x, np.float64) @ fiber_emission(leak)


def coded_stack(stack: Stack | ColourStack, code: Code, *, sensor: Sensor | None = None,
                exposure: float | None = 0.8, seed: int = 0, crosstalk: Any = None, leak: float | None = None
                ) -> CodedStack:
    """A coded scan of a rendered (ideal) stack: the code's frame sums, then the sensor.

    Parameters
    ----------
    stack : Stack or ColourStack
        Ideal per-source frames (rendered radiance, no clip level); a
        :class:`ColourStack` for a colour code.
    code : Code
        For ``stack.n_sources`` sources (:func:`~shinysim.theory.coding.make_code`);
        a colour code (``colours=3``) exactly when ``stack`` is a ColourStack.
    sensor : Sensor, optional
        Without one the coded frames are ideal radiance.
    exposure : float or None
        With a sensor: the fraction of the full well that the brightest
        *coded* pixel fills (``Sensor.exposed_for``), in (0, 100]; None
        keeps the sensor's own exposure (equal-frame-exposure comparisons;
        ``docs/coded-scanning.md``, "Exposure").
    seed : int
        Coded frame ``f`` draws its noise from ``default_rng([seed, f])``
        (colour: channel ``c`` of it from ``default_rng([seed, f, c])``).
    crosstalk : (3, 3) array_like, optional
        Colour scans: the camera's colour crosstalk, row ``i`` camera
        channel ``i``'s response to red, green and blue light (default
        :data:`~shinysim.sim.sensor.CAMERA_CROSSTALK`; the identity for
        none). Applied with or without a sensor: it is the camera's.
    leak : float, optional
        Colour scans: each fiber's light in the other two colours, relative
        to its own (:func:`~shinysim.theory.coding.fiber_emission`), in
        ``[0, 1)``; default 0.

    Returns
    -------
    CodedStack

    Raises
    ------
    OptionError
        A code for another number of sources (naming both counts), a
        digitised stack, an all-dark stack with a fractional exposure, a
        colour code with a grey stack or the other way round, crosstalk or
        leak for a grey stack, a singular crosstalk matrix.
    """
    colour = isinstance(stack, ColourStack)
    if not colour and not isinstance(stack, Stack):
        raise OptionError(f"must be a shinysim Stack or ColourStack, got {type(stack).__name__}", field="stack")
    if not isinstance(code, Code):
        raise OptionError(f"must be a Code (make_code), got {type(code).__name__}", field="code")
    if colour and code.channels is None:
        raise OptionError(f"is a {code.name} code of one colour; a ColourStack needs a colour code "
                          "(make_code(..., colours=3))", field="code")
    if not colour and code.channels is not None:
        raise OptionError("is a colour code; it needs RGB per-source frames (a ColourStack, "
                          "Simulator(..., colour=True).render_colour_stack)", field="code")
    for name, value in (("crosstalk", crosstalk), ("leak", leak)):
        if value is not None and not colour:
            raise OptionError("is for colour scans (a ColourStack and a colour code) only", field=name)
    if code.n_sources != stack.n_sources:
        raise OptionError(f"is a {code.name} code for {code.n_sources} sources but the stack has "
                          f"{stack.n_sources} sources", field="code")
    if colour and "sensor" in stack.provenance:
        raise OptionError("is digitised already (it has a sensor in its provenance); code the ideal float stack",
                          field="stack")
    if not colour and (stack.saturation is not None or "sensor" in stack.provenance):
        raise OptionError("is digitised already (it has a clip level or a sensor in its provenance); "
                          "code the ideal float stack", field="stack")
    if sensor is not None and not isinstance(sensor, Sensor):
        raise OptionError(f"must be a Sensor or None, got {type(sensor).__name__}", field="sensor")
    seed = check_number("seed", seed, lo=0, integer=True)
    if colour:
        return _coded_colour(stack, code, sensor, exposure, seed, crosstalk, leak)
    coded = encode(stack.frames, code)
    provenance = {**copy.deepcopy(stack.provenance), "code": code.to_dict()}
    return _through_sensor(coded, stack, code, sensor, exposure, seed, provenance)


def _coded_colour(stack, code, sensor, exposure, seed, crosstalk, leak):
    """:func:`coded_stack` of a ColourStack, checked: fiber colours, the code's sums, camera crosstalk, sensor."""
    x = np.asarray(CAMERA_CROSSTALK if crosstalk is None else check_colour_matrix(crosstalk, "crosstalk"), np.float64)
    leak = 0.0 if leak is None else leak
    emission = fiber_emission(leak)
    light = encode_colour(stack.frames, code, emission)
    coded = np.empty_like(light)
    for f in range(len(light)):  # each camera channel's response to the light's three colours
        coded[f] = (light[f].astype(np.float64) @ x.T).astype(np.float32)
    mixing = x @ emission
    provenance = {**copy.deepcopy(stack.provenance), "code": code.to_dict(),
                  "colour": {"crosstalk": x.tolist(), "leak": float(leak), "emission": emission.tolist(),
                             "mixing": mixing.tolist()}}
    return _through_sensor(coded, stack, code, sensor, exposure, seed, provenance, mixing)


def _through_sensor(coded, stack, code, sensor, exposure, seed, provenance, mixing=None):
    """The CodedStack of ideal coded frames: as they are without a sensor; else exposed (``exposure`` a
    fraction of the full well at the brightest coded pixel, None: the sensor's own) and captured, RGB
    frames (``mixing`` given) channel by channel."""
    if sensor is None:
        return CodedStack(coded, code, stack.rig, stack.camera_index, None, None, provenance, mixing)
    if exposure is not None:
        exposure = check_number("exposure", exposure, lo=0, lo_open=True, hi=100)
        peak = float(coded.max()) if coded.size else 0.0
        if not peak > 0:
            raise OptionError("every coded frame is dark: nothing to expose for (give exposure=None)",
                              field="exposure")
        sensor = sensor.exposed_for(peak, exposure)
    capture = sensor.capture if mixing is None else sensor.capture_colour
    frames = capture(coded, seed=seed)
    provenance.update(sensor=sensor.to_dict(), sensor_seed=seed)
    return CodedStack(frames, code, stack.rig, stack.camera_index, 1.0, sensor, provenance, mixing)


def expected_frames(radiance: Any, sensor: Sensor | None) -> np.ndarray:
    """Noiseless, unclipped frames above the black level, in a sensor's frame units.

    ``radiance * exposure * vignette * prnu * gain / (2**bits - 1)``: what a
    sensor's frames hold on average above ``dark_offset`` where nothing
    clips (the reference a noise measurement subtracts). Without a sensor,
    the radiance as float32.

    Parameters
    ----------
    radiance : (n, H, W) or (H, W) array_like
    sensor : Sensor or None
    """
    arr = np.asarray(radiance, dtype=np.float64)
    if sensor is None:
        return arr.astype(np.float32)
    shape = arr.shape[-2:]
    scale = sensor.exposure * sensor.vignette(shape) * sensor.prnu_map(shape) * sensor.gain / sensor.full_scale
    return (arr * scale).astype(np.float32)
