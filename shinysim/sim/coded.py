"""Coded scans from rendered per-source stacks: several sources per frame, then the sensor.

Light adds: the ideal frame taken with a set of sources lit is exactly the
sum of those sources' single-source frames, so a coded scan needs no new
render: :func:`coded_stack` sums a rendered stack's frames by the code
(:func:`shinysim.theory.coding.encode`) and hands each coded frame to a
:class:`~shinysim.sim.sensor.Sensor`, which adds its noise, clips and
quantises *the coded frame* (a coded frame's pixel is one exposure, not a
sum of noisy exposures). :func:`shinysim.recon.coding.decode` turns the
result back into highlights.

Two comparisons a study of coded scanning needs, and how to make each:

* *Equal frame exposure*: every frame of every scan gets the same exposure
  (electrons per unit radiance), as a camera run at a fixed shutter time
  would. Pass one :class:`Sensor` with its exposure set
  (``sensor.exposed_for(...)``) and ``exposure=None`` to every scan.
  This is the comparison of :func:`~shinysim.theory.coding.hadamard_snr_gain`,
  and the fair one for speed: a binary scan of 200 sources takes 16 such
  frames instead of 200.
* *Equal total exposure*: the scans collect light for the same total time.
  A scan of ``F`` frames against a sequential one of ``N`` then gets
  ``N / F`` times the frame exposure (``sensor.with_exposure(e * N / F)``),
  which helps a binary scan's noise but saturates the highlights unless
  the sequential scan was exposed well below the full well.

With ``exposure`` a fraction (the default 0.8), each scan is exposed so that
its own brightest coded pixel fills that fraction of the full well (the
rule of :func:`~shinysim.sim.sensor.Sensor.exposed_for`): on a shiny object,
whose highlights rarely overlap, that is nearly the sequential scan's
exposure, but a pixel lit by several sources at once is brighter, and the
rule then lowers every frame's exposure.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._shared import check_number
from ..errors import OptionError
from ..io import Stack
from ..rig import Rig
from ..theory.coding import Code, encode
from .sensor import Sensor

__all__ = ["CodedStack", "coded_stack", "expected_frames"]


@dataclass
class CodedStack:
    """The frames of a coded scan of one camera.

    Attributes
    ----------
    frames : (n_frames, H, W) float32
        With a sensor: digital numbers over the top code, in [0, 1] (the
        black level ``dark_offset / (2**bits - 1)`` included). Without:
        ideal radiance (the code's sums of the rendered frames).
    code : Code
    rig : Rig
    camera_index : int
    saturation : float or None
        The clip level (1.0 with a sensor), None for ideal radiance.
    sensor : Sensor or None
        The sensor, with the exposure it was used at.
    provenance : dict
        The stack's provenance plus the code (``"code"``) and, with a
        sensor, ``"sensor"`` and ``"sensor_seed"``.
    """

    frames: np.ndarray
    code: Code
    rig: Rig
    camera_index: int = 0
    saturation: float | None = None
    sensor: Sensor | None = None
    provenance: dict[str, Any] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def n_sources(self) -> int:
        return self.code.n_sources


def coded_stack(stack: Stack, code: Code, *, sensor: Sensor | None = None, exposure: float | None = 0.8,
                seed: int = 0) -> CodedStack:
    """A coded scan of a rendered (ideal) stack: the code's frame sums, then the sensor.

    Parameters
    ----------
    stack : Stack
        Ideal per-source frames (rendered radiance, no clip level).
    code : Code
        For ``stack.n_sources`` sources (:func:`~shinysim.theory.coding.make_code`).
    sensor : Sensor, optional
        Without one the coded frames are ideal radiance.
    exposure : float or None
        With a sensor: the fraction of the full well that the brightest
        *coded* pixel fills (``Sensor.exposed_for``), in (0, 100]; None
        keeps the sensor's own exposure (equal-frame-exposure comparisons;
        see the module notes).
    seed : int
        Coded frame ``f`` draws its noise from ``default_rng([seed, f])``.

    Returns
    -------
    CodedStack

    Raises
    ------
    OptionError
        A code for another number of sources (naming both counts), a
        digitised stack, an all-dark stack with a fractional exposure.
    """
    if not isinstance(stack, Stack):
        raise OptionError(f"must be a shinysim Stack, got {type(stack).__name__}", field="stack")
    if not isinstance(code, Code):
        raise OptionError(f"must be a Code (make_code), got {type(code).__name__}", field="code")
    if code.n_sources != stack.n_sources:
        raise OptionError(f"is a {code.name} code for {code.n_sources} sources but the stack has "
                          f"{stack.n_sources} sources", field="code")
    if stack.saturation is not None or "sensor" in stack.provenance:
        raise OptionError("is digitised already (it has a clip level or a sensor in its provenance); "
                          "code the ideal float stack", field="stack")
    if sensor is not None and not isinstance(sensor, Sensor):
        raise OptionError(f"must be a Sensor or None, got {type(sensor).__name__}", field="sensor")
    seed = check_number("seed", seed, lo=0, integer=True)
    coded = encode(stack.frames, code)
    provenance = {**copy.deepcopy(stack.provenance), "code": code.to_dict()}
    if sensor is None:
        return CodedStack(coded, code, stack.rig, stack.camera_index, None, None, provenance)
    if exposure is not None:
        exposure = check_number("exposure", exposure, lo=0, lo_open=True, hi=100)
        peak = float(coded.max()) if coded.size else 0.0
        if not peak > 0:
            raise OptionError("every coded frame is dark: nothing to expose for (give exposure=None)",
                              field="exposure")
        sensor = sensor.exposed_for(peak, exposure)
    frames = sensor.capture(coded, seed=seed)
    provenance.update(sensor=sensor.to_dict(), sensor_seed=seed)
    return CodedStack(frames, code, stack.rig, stack.camera_index, 1.0, sensor, provenance)


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
