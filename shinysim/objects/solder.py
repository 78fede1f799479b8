r"""Exact cross-section truth of procedural surface-mount solder joints.

:class:`JointParams`, the class ranges and :func:`sample_params` describe a
joint; :class:`JointProfile` gives its exact profile ``z(x)``, normals and
curvature (positive where convex) in the x-z plane of the sources, each
solder surface swept straight along y. Pure numpy (no trimesh, no mitsuba):
the reconstruction side imports it to compare recovered profiles with the
truth, and :mod:`shinysim.sim.solder` builds the meshes from the same
geometry. The frame, the cross-sections of each kind and the fillet's arc:
``docs/solder.md``, sections "Frame and units" and "Geometry".
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass

import numpy as np

from .._shared import check_choice
from ..conventions import normal_from_gradient
from ..errors import OptionError

__all__ = [
    "JOINT_KINDS",
    "LEAD_TYPES",
    "WETTED_KINDS",
    "FIELD_HALF_WIDTH",
    "BOARD_HALF_WIDTH",
    "BOARD_THICKNESS",
    "PAD_THICKNESS",
    "PAD_RIGHT_X",
    "LEAD_NOMINAL_X",
    "LEAD_TOP_Z",
    "SOLDER_SINK",
    "SOLDER_SIDE_INSET",
    "MIN_VISIBLE_LENGTH",
    "LEAD_SHAPES",
    "LeadShape",
    "COMMON_RANGES",
    "PARAM_RANGES",
    "NOMINAL_PARAMS",
    "JointParams",
    "sample_params",
    "ArcSurface",
    "LeadGeometry",
    "JointProfile",
]

# ---------------------------------------------------------------------------
# Fixed layout (millimetres)
# ---------------------------------------------------------------------------

#: Joint kinds (defect classes), checked strings.
JOINT_KINDS = ("good", "insufficient", "excess", "lifted", "bridge")
#: Lead types, checked strings.
LEAD_TYPES = ("gull-wing", "j-lead")
#: Kinds whose solder wets the lead (a fillet from pad to lead).
WETTED_KINDS = ("good", "insufficient", "excess", "bridge")

#: Half side of the rig's square camera field centred on the origin.
FIELD_HALF_WIDTH = 1.0
#: Half side of the square board slab (larger than the field).
BOARD_HALF_WIDTH = 1.2
#: Board slab thickness; the board occupies ``-BOARD_THICKNESS <= z <= 0``.
BOARD_THICKNESS = 0.2
#: Nominal copper pad thickness (the design value); a joint's pad top is at
#: ``z = pad_thickness`` (:class:`JointParams`, default this value).
PAD_THICKNESS = 0.035
#: Nominal x of the pad's +x end; the pad spans ``[PAD_RIGHT_X + pad_offset -
#: pad_length, PAD_RIGHT_X + pad_offset]``.
PAD_RIGHT_X = 0.75
#: x of the lead's bend centre when ``lead_offset = 0``.
LEAD_NOMINAL_X = 0.18
#: Height of the outer corner where the rising leg is cut off (the rest of the
#: lead and the component body lie outside the modelled volume).
LEAD_TOP_Z = 0.8
#: Solder bodies reach this far into the pad/board/lead below their visible
#: surface, so no crack can open between touching parts.
SOLDER_SINK = 0.005
#: The fillet is swept across the lead width less this inset on each side
#: (keeps solder side faces off the lead side faces).
SOLDER_SIDE_INSET = 0.002
#: Shortest part of the main solder surface, along x, that the lead may leave
#: visible from above for the parameters to count as a joint.
MIN_VISIBLE_LENGTH = 0.03


@dataclass(frozen=True)
class LeadShape:
    """Fixed shape of one lead type (millimetres, radians).

    Attributes
    ----------
    bend_outer_radius : float, mm
        Outer radius of the bend (gull-wing heel, J curl).
    leg_angle : float, radians
        Angle of the rising leg above the +x axis measured on the -x side
        (``pi/2``: vertical; less than that: the leg leans back over the fillet).
    arc_end : float, radians
        Angle of the outer normal where the bend ends: ``-pi/2`` (gull-wing,
        foot along +x) or ``0`` (J-lead, short return leg rising under the body).
    tail_length : float, mm
        Length of the straight piece after the bend (foot or return leg).
    """

    bend_outer_radius: float
    leg_angle: float
    arc_end: float
    tail_length: float


#: Shapes of the two lead types.
LEAD_SHAPES = {
    "gull-wing": LeadShape(
        bend_outer_radius=0.15, leg_angle=math.radians(85.0), arc_end=-math.pi / 2, tail_length=0.45
    ),
    "j-lead": LeadShape(
        bend_outer_radius=0.18, leg_angle=math.pi / 2, arc_end=0.0, tail_length=0.12
    ),
}

# ---------------------------------------------------------------------------
# Parameter ranges of the classes (used by sample_params, documented in
# docs/solder.md). Lengths in mm, angles in radians.
# ---------------------------------------------------------------------------

_D = math.radians

#: Ranges shared by every class: ``name -> (low, high)``; ``lead_type`` is
#: drawn uniformly from :data:`LEAD_TYPES`.
COMMON_RANGES = {
    "lead_offset": (-0.05, 0.05),
    "ripple_amplitude": (0.0, 0.001),
    "ripple_wavelength": (0.06, 0.15),
    "ripple_phase": (0.0, 2 * math.pi),
    "pad_length": (1.2, 1.5),
    "pad_width": (0.35, 0.45),
    "lead_width": (0.18, 0.24),
    "lead_thickness": (0.09, 0.11),
}

_GOOD = {
    "fillet_height": (0.12, 0.30),
    "contact_angle_pad": (_D(15.0), _D(35.0)),
    "lead_slope_angle": (_D(50.0), _D(80.0)),
    "lead_lift": (0.0, 0.02),
}

#: Class-specific ranges, ``kind -> {name: (low, high)}``, on top of
#: :data:`COMMON_RANGES`.
PARAM_RANGES = {
    "good": dict(_GOOD),
    "insufficient": {
        "fillet_height": (0.025, 0.07),
        "contact_angle_pad": (_D(4.0), _D(15.0)),
        "lead_slope_angle": (_D(20.0), _D(45.0)),
        "lead_lift": (0.0, 0.01),
    },
    "excess": {
        "fillet_height": (0.25, 0.40),
        "contact_angle_pad": (_D(60.0), _D(85.0)),
        "lead_slope_angle": (_D(-15.0), _D(30.0)),
        "lead_lift": (0.0, 0.02),
    },
    "lifted": {
        "fillet_height": (0.06, 0.16),
        "contact_angle_pad": (_D(45.0), _D(85.0)),
        "lead_lift": (0.05, 0.15),
        "ball_clearance": (0.02, 0.10),
    },
    "bridge": {
        **_GOOD,
        "bridge_height": (0.06, 0.14),
        "bridge_length": (0.30, 0.50),
        "neighbour_pitch": (0.60, 0.70),
    },
}

_COMMON_NOMINAL = {
    "lead_offset": 0.0,
    "ripple_amplitude": 0.0,
    "ripple_wavelength": 0.1,
    "ripple_phase": 0.0,
    "pad_length": 1.35,
    "pad_width": 0.40,
    "lead_width": 0.20,
    "lead_thickness": 0.10,
    "pad_thickness": PAD_THICKNESS,
    "pad_offset": 0.0,
}

_GOOD_NOMINAL = {**_COMMON_NOMINAL, "fillet_height": 0.20, "contact_angle_pad": _D(25.0),
                 "lead_slope_angle": _D(65.0), "lead_lift": 0.01}
#: Nominal (default) values per class: a field of :class:`JointParams` left as
#: ``None`` takes this value.
NOMINAL_PARAMS = {
    "good": _GOOD_NOMINAL,
    "insufficient": {**_COMMON_NOMINAL, "fillet_height": 0.045, "contact_angle_pad": _D(6.0),
                     "lead_slope_angle": _D(25.0), "lead_lift": 0.005},
    "excess": {**_COMMON_NOMINAL, "fillet_height": 0.32, "contact_angle_pad": _D(72.0),
               "lead_slope_angle": _D(10.0), "lead_lift": 0.01},
    "lifted": {**_COMMON_NOMINAL, "fillet_height": 0.11, "contact_angle_pad": _D(65.0),
               "lead_lift": 0.10, "ball_clearance": 0.05},
    "bridge": {**_GOOD_NOMINAL, "bridge_height": 0.10, "bridge_length": 0.40, "neighbour_pitch": 0.65},
}

# Which kinds use the class-specific fields (others must leave them None).
_FIELD_KINDS = {
    "lead_slope_angle": WETTED_KINDS,
    "ball_clearance": ("lifted",),
    "bridge_height": ("bridge",),
    "bridge_length": ("bridge",),
    "neighbour_pitch": ("bridge",),
}

# Physical validity bounds checked by JointParams (wider than the class ranges):
# name -> (low, high, low_inclusive, high_inclusive).
_BOUNDS = {
    "fillet_height": (0.0, 0.6, False, True),
    "contact_angle_pad": (0.0, _D(89.0), False, True),
    "lead_slope_angle": (_D(-89.0), _D(89.0), True, True),
    "lead_offset": (-0.2, 0.2, True, True),
    "lead_lift": (0.0, 0.3, True, True),
    "ripple_amplitude": (0.0, 0.01, True, True),
    "ripple_wavelength": (0.01, 1.0, True, True),
    "ripple_phase": (-math.inf, math.inf, False, False),
    "pad_length": (0.8, PAD_RIGHT_X + FIELD_HALF_WIDTH - 0.05, True, True),
    "pad_width": (0.1, 1.0, True, True),
    "lead_width": (0.05, 0.5, True, True),
    "lead_thickness": (0.03, 0.13, True, True),
    "ball_clearance": (0.0, 0.3, True, True),
    "bridge_height": (PAD_THICKNESS + 0.01, 0.4, True, True),
    "bridge_length": (0.05, 1.0, True, True),
    "neighbour_pitch": (0.2, 1.0, True, True),
    "pad_thickness": (0.01, 0.08, True, True),
    "pad_offset": (-0.2, 0.2, True, True),
}


def _check_real(name, value):
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise OptionError(f"{name} must be a real number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise OptionError(f"{name} must be finite, got {value!r}")
    return value


@dataclass(frozen=True)
class JointParams:
    """Parameters of one procedural solder joint (millimetres, radians).

    Every numeric field left as ``None`` takes the class's nominal value from
    :data:`NOMINAL_PARAMS`; class-specific fields must stay ``None`` for the
    classes that do not use them. Values are checked against physical bounds
    here (``ValueError`` naming the field); combinations that do not make a
    joint (e.g. a fillet foot off the pad) are rejected by
    :class:`JointProfile`.

    Attributes
    ----------
    kind : str
        One of :data:`JOINT_KINDS`.
    lead_type : str
        One of :data:`LEAD_TYPES`.
    fillet_height : float, mm
        Wetted kinds: height of the solder's contact line on the lead above the
        pad top (the IPC heel-fillet height). ``"lifted"``: apex height of the
        solder ball above the pad top.
    contact_angle_pad : float, radians
        Slope angle of the solder surface where it meets the pad (the contact
        angle on the horizontal pad); for ``"lifted"`` on both sides of the ball.
    lead_slope_angle : float or None, radians
        Wetted kinds only: elevation angle of the solder surface's tangent
        where it meets the lead, positive rising towards the lead (+x). The
        fillet is concave when it exceeds ``contact_angle_pad`` and convex when
        it is smaller.
    lead_offset : float, mm
        Shift of the lead along +x from its nominal place (bend centre at
        ``LEAD_NOMINAL_X``).
    lead_lift : float, mm
        Gap between the lead's lowest point and the pad top. Wetted kinds fill
        it with solder under the lead; ``"lifted"`` leaves it open.
    ripple_amplitude : float, mm
        Amplitude of the surface ripple on the fillet or ball.
    ripple_wavelength : float, mm
        Wavelength of the ripple along x.
    ripple_phase : float, radians
        Phase of the ripple at the fillet foot.
    pad_length : float, mm
        Pad extent along x; the pad spans ``[PAD_RIGHT_X + pad_offset - pad_length,
        PAD_RIGHT_X + pad_offset]``.
    pad_width : float, mm
        Pad extent along y, centred on ``y = 0``.
    lead_width : float, mm
        Lead extent along y, centred on ``y = 0``; the fillet is swept over it.
    lead_thickness : float, mm
        Lead sheet thickness.
    ball_clearance : float or None, mm
        ``"lifted"`` only: horizontal gap between the ball's +x edge and the
        lead's outermost (-x) point.
    bridge_height : float or None, mm
        ``"bridge"`` only: apex height of the bridging lump above the board top.
    bridge_length : float or None, mm
        ``"bridge"`` only: extent along x of the bridge's base, centred on the
        fillet's mid x.
    neighbour_pitch : float or None, mm
        ``"bridge"`` only: y of the neighbouring pad/lead/joint (lead pitch).
    pad_thickness : float, mm
        Copper thickness of the pad: the pad top, where the fillet starts, is
        at ``z = pad_thickness`` (nominal :data:`PAD_THICKNESS`; a real
        board's varies by about +-10 um).
    pad_offset : float, mm
        Shift of the pad along +x from its nominal place (pad etching and
        registration error; the lead moves independently by ``lead_offset``).
    """

    kind: str = "good"
    lead_type: str = "gull-wing"
    fillet_height: float | None = None
    contact_angle_pad: float | None = None
    lead_slope_angle: float | None = None
    lead_offset: float | None = None
    lead_lift: float | None = None
    ripple_amplitude: float | None = None
    ripple_wavelength: float | None = None
    ripple_phase: float | None = None
    pad_length: float | None = None
    pad_width: float | None = None
    lead_width: float | None = None
    lead_thickness: float | None = None
    ball_clearance: float | None = None
    bridge_height: float | None = None
    bridge_length: float | None = None
    neighbour_pitch: float | None = None
    pad_thickness: float | None = None
    pad_offset: float | None = None

    def __post_init__(self):
        check_choice("kind", self.kind, JOINT_KINDS)
        check_choice("lead_type", self.lead_type, LEAD_TYPES)
        nominal = NOMINAL_PARAMS[self.kind]
        for f in dataclasses.fields(self):
            name = f.name
            if name in ("kind", "lead_type"):
                continue
            value = getattr(self, name)
            users = _FIELD_KINDS.get(name)
            if users is not None and self.kind not in users:
                if value is not None:
                    raise OptionError(
                        f"{name} applies only to kind in {users}, not kind={self.kind!r}; "
                        f"leave it None"
                    )
                continue
            if value is None:
                value = nominal[name]
            value = _check_real(name, value)
            lo, hi, lo_inc, hi_inc = _BOUNDS[name]
            ok_lo = value >= lo if lo_inc else value > lo
            ok_hi = value <= hi if hi_inc else value < hi
            if not (ok_lo and ok_hi):
                lb = "[" if lo_inc else "("
                hb = "]" if hi_inc else ")"
                raise OptionError(f"{name} must lie in {lb}{lo:.6g}, {hi:.6g}{hb}, got {value!r}")
            object.__setattr__(self, name, value)
        if self.lead_width >= self.pad_width:
            raise OptionError(
                f"lead_width ({self.lead_width} mm) must be smaller than pad_width "
                f"({self.pad_width} mm)"
            )
        shape = LEAD_SHAPES[self.lead_type]
        if self.lead_thickness > shape.bend_outer_radius - 0.03:
            raise OptionError(
                f"lead_thickness must be at most {shape.bend_outer_radius - 0.03:.3f} mm for a "
                f"{self.lead_type} lead (bend outer radius {shape.bend_outer_radius} mm), "
                f"got {self.lead_thickness}"
            )
        if self.kind == "bridge":
            if self.neighbour_pitch < self.pad_width + 0.05:
                raise OptionError(
                    f"neighbour_pitch ({self.neighbour_pitch} mm) must exceed pad_width "
                    f"({self.pad_width} mm) by at least 0.05 mm"
                )
            if self.neighbour_pitch + self.pad_width / 2 > FIELD_HALF_WIDTH:
                raise OptionError(
                    f"neighbour_pitch ({self.neighbour_pitch} mm) puts the neighbouring pad "
                    f"outside the {2 * FIELD_HALF_WIDTH} mm field"
                )
            if self.bridge_height >= 0.9 * self.bridge_length / 2:
                raise OptionError(
                    f"bridge_height ({self.bridge_height} mm) must be below 0.45 * bridge_length "
                    f"({self.bridge_length} mm) so the bridge surface is a height function"
                )

    def to_dict(self):
        """Plain ``dict`` of every field (JSON-ready)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data):
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError``."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise OptionError(f"data has unknown JointParams fields {unknown}")
        return cls(**data)


def sample_params(kind, rng, *, max_tries=500):
    """Draw a random joint of one class from its documented ranges.

    Each varied parameter is drawn uniformly from ``COMMON_RANGES`` and
    ``PARAM_RANGES[kind]``, the lead type uniformly from :data:`LEAD_TYPES`;
    draws whose combination does not make a valid joint (fillet foot off the
    pad, solder cutting into the lead, ...) are redrawn.

    Parameters
    ----------
    kind : str
        One of :data:`JOINT_KINDS`.
    rng : numpy.random.Generator or int
        Random generator, or a seed for ``numpy.random.default_rng``.
    max_tries : int
        Redraws before giving up with ``RuntimeError``.

    Returns
    -------
    JointParams
    """
    check_choice("kind", kind, JOINT_KINDS)
    if isinstance(rng, numbers.Integral) and not isinstance(rng, bool):
        rng = np.random.default_rng(int(rng))
    if not isinstance(rng, np.random.Generator):
        raise OptionError(f"rng must be a numpy.random.Generator or an int seed, got {rng!r}")
    return draw_valid_params(kind, rng, lambda name, lo, hi: float(rng.uniform(lo, hi)), max_tries=max_tries)


def draw_valid_params(kind, rng, draw, *, max_tries=500, what=""):
    """Draw parameters of a class until they make a valid joint.

    Parameters
    ----------
    kind : str
    rng : numpy.random.Generator
        Draws the lead type.
    draw : callable
        ``draw(name, lo, hi) -> float`` for each ranged parameter, in the
        order of the class's ranges.
    max_tries : int
        Redraws before giving up with ``RuntimeError``.
    what : str
        Extra words for the error message (e.g. the split).
    """
    ranges = {**COMMON_RANGES, **PARAM_RANGES[kind]}
    last_error = None
    for _ in range(max_tries):
        values = {name: draw(name, lo, hi) for name, (lo, hi) in ranges.items()}
        lead_type = LEAD_TYPES[int(rng.integers(len(LEAD_TYPES)))]
        try:
            params = JointParams(kind=kind, lead_type=lead_type, **values)
            JointProfile(params)
        except ValueError as exc:
            last_error = exc
            continue
        return params
    raise RuntimeError(
        f"no valid {kind!r} joint{what} in {max_tries} draws; last rejection: {last_error}"
    )


# ---------------------------------------------------------------------------
# Exact profile pieces
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ArcSurface:
    """Swept solder surface ``z(x)``: circular arc plus tapered ripple.

    The arc starts at ``(x_start, z_start)`` with slope angle ``theta_start``
    and passes through ``(x_end, z_end)``. Both end slope angles must lie in
    ``(-pi/2, pi/2)`` so the arc is a height function. The ripple is
    ``amplitude * sin^2(pi s) * sin(2 pi (x - x_start) / wavelength + phase)``
    with ``s = (x - x_start) / (x_end - x_start)``.

    Attributes
    ----------
    x_start, z_start, x_end, z_end : float, mm
    theta_start : float, radians
    amplitude, wavelength : float, mm
    phase : float, radians
    """

    x_start: float
    z_start: float
    theta_start: float
    x_end: float
    z_end: float
    amplitude: float = 0.0
    wavelength: float = 1.0
    phase: float = 0.0

    def __post_init__(self):
        dx = self.x_end - self.x_start
        dz = self.z_end - self.z_start
        if not dx > 0:
            raise OptionError("x_end must exceed x_start")
        chord = math.hypot(dx, dz)
        phi = math.atan2(dz, dx)
        k = 2.0 * math.sin(phi - self.theta_start) / chord  # signed, CCW positive
        object.__setattr__(self, "_k", k)
        object.__setattr__(self, "theta_end", 2.0 * phi - self.theta_start)
        if abs(k) > 1e-9:
            r = 1.0 / abs(k)
            xc = self.x_start - math.sin(self.theta_start) / k
            zc = self.z_start + math.cos(self.theta_start) / k
            object.__setattr__(self, "_arc", (xc, zc, r, 1.0 if k > 0 else -1.0))
        else:
            object.__setattr__(self, "_arc", None)

    @property
    def x_range(self):
        """``(x_start, x_end)``, mm."""
        return (self.x_start, self.x_end)

    @property
    def curvature_smooth(self):
        """Signed curvature of the arc, 1/mm; positive: convex (bulging)."""
        return -self._k

    def _smooth(self, x):
        if self._arc is None:
            m = (self.z_end - self.z_start) / (self.x_end - self.x_start)
            return self.z_start + m * (x - self.x_start), np.full_like(x, m), np.zeros_like(x)
        xc, zc, r, sign = self._arc
        u = x - xc
        root = np.sqrt(np.maximum(r * r - u * u, 1e-300))
        z = zc - sign * root
        dz = sign * u / root
        d2z = sign * r * r / root**3
        return z, dz, d2z

    def _ripple(self, x):
        a = self.amplitude
        if a == 0.0:
            zero = np.zeros_like(x)
            return zero, zero, zero
        length = self.x_end - self.x_start
        s = (x - self.x_start) / length
        w = 2.0 * math.pi / self.wavelength
        arg = w * (x - self.x_start) + self.phase
        taper = np.sin(np.pi * s) ** 2
        dtaper = (np.pi / length) * np.sin(2.0 * np.pi * s)
        d2taper = (2.0 * np.pi**2 / length**2) * np.cos(2.0 * np.pi * s)
        sn, cs = np.sin(arg), np.cos(arg)
        r = a * taper * sn
        dr = a * (dtaper * sn + taper * w * cs)
        d2r = a * (d2taper * sn + 2.0 * dtaper * w * cs - taper * w * w * sn)
        return r, dr, d2r

    def _eval(self, x, ripple):
        x = np.asarray(x, dtype=float)
        inside = (x >= self.x_start) & (x <= self.x_end)
        xc = np.clip(x, self.x_start, self.x_end)
        z, dz, d2z = self._smooth(xc)
        if ripple:
            r, dr, d2r = self._ripple(xc)
            z, dz, d2z = z + r, dz + dr, d2z + d2r
        nan = np.nan
        return np.where(inside, z, nan), np.where(inside, dz, nan), np.where(inside, d2z, nan)

    def z(self, x, ripple=True):
        """Height, mm, of (...) x in mm; NaN outside ``x_range``."""
        return self._eval(x, ripple)[0]

    def slope(self, x, ripple=True):
        """``dz/dx`` at (...) x; NaN outside ``x_range``."""
        return self._eval(x, ripple)[1]

    def curvature(self, x, ripple=True):
        """Signed curvature, 1/mm, positive where convex (bulging up)."""
        _, dz, d2z = self._eval(x, ripple)
        return -d2z / (1.0 + dz * dz) ** 1.5

    def tangent_angle_grid(self, n_x=20001, n_theta=4001):
        """Dense, strictly increasing x grid fine in both x and arc angle.

        Used to sample and to check tessellations: returns (K,) float x, mm.
        """
        xs = [np.linspace(self.x_start, self.x_end, n_x)]
        if self._arc is not None:
            xc, _, r, sign = self._arc
            th = np.linspace(self.theta_start, self.theta_end, n_theta)
            xs.append(xc + sign * r * np.sin(th))
        x = np.unique(np.clip(np.concatenate(xs), self.x_start, self.x_end))
        return x


@dataclass(frozen=True)
class LeadGeometry:
    """Cross-section of the lead in the x-z plane (mm, radians).

    The lead is a sheet of ``thickness`` bent along a centre line: a straight
    leg rising at ``leg_angle`` (cut at ``top_z``), an arc of outer radius
    ``outer_radius`` about ``(x_centre, z_centre)`` whose outer normal turns
    from ``alpha0 = -pi/2 - leg_angle`` to ``arc_end``, then a straight tail.
    The *outer* face (normal ``(cos alpha, sin alpha)`` on the arc) faces the
    fillet.
    """

    lead_type: str
    x_centre: float
    z_centre: float
    outer_radius: float
    thickness: float
    width: float
    leg_angle: float
    arc_end: float
    tail_length: float
    top_z: float

    @property
    def alpha0(self):
        """Outer-normal angle where the leg joins the bend, radians."""
        return -math.pi / 2 - self.leg_angle

    @property
    def bottom_z(self):
        """Lowest z of the lead, mm."""
        return self.z_centre - self.outer_radius

    @property
    def leg_base(self):
        """(x, z) of the outer face where the leg joins the bend, mm."""
        a0 = self.alpha0
        return (
            self.x_centre + self.outer_radius * math.cos(a0),
            self.z_centre + self.outer_radius * math.sin(a0),
        )

    def outer_alpha(self, z):
        """Outer-normal angle of the fillet-side outer face at height z.

        (...) float, radians; NaN below the lead, ``alpha0`` on the leg.
        """
        z = np.asarray(z, dtype=float)
        s = np.clip((z - self.z_centre) / self.outer_radius, -1.0, 1.0)
        alpha = -math.pi - np.arcsin(s)
        alpha = np.where(z > self.leg_base[1], self.alpha0, alpha)
        return np.where(z < self.bottom_z, np.nan, alpha)

    def outer_x(self, z):
        """x of the fillet-side outer face at height z (mm); NaN below the lead."""
        z = np.asarray(z, dtype=float)
        a = self.leg_angle
        xb, zb = self.leg_base
        leg = xb - (z - zb) * math.cos(a) / math.sin(a)
        alpha = self.outer_alpha(z)
        bend = self.x_centre + self.outer_radius * np.cos(alpha)
        return np.where(z > zb, leg, bend)

    def outer_normal(self, z):
        """(..., 2) outward unit normal (x, z) of the outer face at height z."""
        alpha = self.outer_alpha(z)
        return np.stack([np.cos(alpha), np.sin(alpha)], axis=-1)

    @property
    def min_x(self):
        """Smallest x of the lead (its outer face at the cut), mm."""
        return float(self.outer_x(self.top_z))

    @property
    def max_x(self):
        """Largest x of the lead, mm."""
        if self.lead_type == "gull-wing":
            return self.x_centre + self.tail_length
        return self.x_centre + self.outer_radius

    def centerline(self, max_angle_step, end_eps):
        """Centre line samples from the leg's cut end to the tail's end.

        Parameters
        ----------
        max_angle_step : float, radians
            Largest turn between consecutive samples on the bend.
        end_eps : float, mm
            Distance of the extra sample next to each cut end (where the
            crease between side faces and cut face is shaded).

        Returns
        -------
        points : (K, 2) float, mm
            (x, z) of the centre line.
        normals : (K, 2) float
            Unit outer normals (towards the fillet side).
        tangents : (K, 2) float
            Unit tangents along the direction of travel.
        """
        a = self.leg_angle
        a0, a1 = self.alpha0, self.arc_end
        rc = self.outer_radius - self.thickness / 2
        n_in_leg = np.array([math.sin(a), math.cos(a)])
        d_leg = np.array([math.cos(a), -math.sin(a)])
        xb, zb = self.leg_base
        leg_len_outer = (self.top_z - zb) / math.sin(a)
        outer_top = np.array([xb, zb]) - leg_len_outer * d_leg
        c_top = outer_top + (self.thickness / 2) * n_in_leg
        centre = np.array([self.x_centre, self.z_centre])
        c_bend0 = centre + rc * np.array([math.cos(a0), math.sin(a0)])
        leg_len = float(np.dot(c_bend0 - c_top, d_leg))
        n_steps = max(2, int(math.ceil(abs(a1 - a0) / max_angle_step)))
        alphas = np.linspace(a0, a1, n_steps + 1)
        if leg_len <= 2 * end_eps:
            raise OptionError("lead leg too short for its cut (lead_lift/fillet too high)")
        arc_n = np.stack([np.cos(alphas), np.sin(alphas)], axis=-1)
        arc_p = centre + rc * arc_n
        arc_t = np.stack([-np.sin(alphas), np.cos(alphas)], axis=-1)
        n_leg = np.array([math.cos(a0), math.sin(a0)])
        # the leg's cut end and a point end_eps along, the bend, and the tail's two points (end_eps before its end)
        tail = arc_p[-1] + np.array([[self.tail_length - end_eps], [self.tail_length]]) * arc_t[-1]
        points = np.vstack([c_top, c_top + end_eps * d_leg, arc_p, tail])
        normals = np.vstack([n_leg, n_leg, arc_n, arc_n[-1], arc_n[-1]])
        return points, normals, np.vstack([d_leg, d_leg, arc_t, arc_t[-1], arc_t[-1]])


def _lead_geometry(params):
    shape = LEAD_SHAPES[params.lead_type]
    bottom = params.pad_thickness + params.lead_lift
    return LeadGeometry(
        lead_type=params.lead_type,
        x_centre=LEAD_NOMINAL_X + params.lead_offset,
        z_centre=bottom + shape.bend_outer_radius,
        outer_radius=shape.bend_outer_radius,
        thickness=params.lead_thickness,
        width=params.lead_width,
        leg_angle=shape.leg_angle,
        arc_end=shape.arc_end,
        tail_length=shape.tail_length,
        top_z=LEAD_TOP_Z,
    )


class JointProfile:
    """Exact cross-section truth of one joint (pure numpy).

    Builds and checks the geometry of ``params``; raises ``ValueError`` naming
    the parameters to change when they do not make a joint.

    Parameters
    ----------
    params : JointParams

    Attributes
    ----------
    params : JointParams
    lead : LeadGeometry
        Main lead at ``y = 0`` (the bridge's neighbour is the same, shifted by
        ``neighbour_pitch`` in y).
    fillet : ArcSurface
        Main free solder surface: the fillet (wetted kinds) or the ball
        (``"lifted"``), swept over ``|y| <= solder_half_width``.
    bridge : ArcSurface or None
        Bridge lump cross-section (``"bridge"`` only), swept over
        ``bridge_y_range``.
    solder_half_width : float, mm
    bridge_y_range : (2,) tuple of float or None, mm
    pad_x_range : (2,) tuple of float, mm
    pad_top_z : float, mm
        Height of the pad top (``params.pad_thickness``).
    contact_point : (2,) tuple of float or None, mm
        ``(x_C, z_C)`` where the fillet meets the lead (wetted kinds).
    contact_angle_lead : float or None, radians
        Angle between lead and solder surface at C, measured through the solder.
    """

    def __init__(self, params):
        if not isinstance(params, JointParams):
            raise OptionError(f"params must be a JointParams, got {type(params).__name__}")
        self.params = p = params
        self.lead = lead = _lead_geometry(p)
        pad_right = PAD_RIGHT_X + p.pad_offset
        self.pad_x_range = (pad_right - p.pad_length, pad_right)
        self.pad_top_z = zp = p.pad_thickness
        self.solder_half_width = p.lead_width / 2 - SOLDER_SIDE_INSET
        pad_x0 = self.pad_x_range[0]
        if lead.max_x > pad_right - 0.02:
            raise OptionError(
                f"lead_offset ({p.lead_offset} mm) puts the lead end at x = {lead.max_x:.3f} mm, "
                f"past the pad end (x = {pad_right - 0.02:.3f} mm allowed)"
            )
        ripple = dict(amplitude=p.ripple_amplitude, wavelength=p.ripple_wavelength, phase=p.ripple_phase)
        self.bridge = None
        self.bridge_y_range = None
        self.contact_point = None
        self.contact_angle_lead = None
        if p.kind == "lifted":
            theta = p.contact_angle_pad
            radius = p.fillet_height / (1.0 - math.cos(theta))
            half = radius * math.sin(theta)
            x_r = lead.min_x - p.ball_clearance
            x_l = x_r - 2 * half
            if x_l < pad_x0 + 0.01:
                raise OptionError(
                    f"solder ball (fillet_height {p.fillet_height} mm, contact_angle_pad "
                    f"{math.degrees(theta):.1f} deg, base {2 * half:.3f} mm) runs off the pad at "
                    f"x = {x_l:.3f} mm: lower fillet_height or ball_clearance, raise "
                    f"contact_angle_pad, or lengthen pad_length"
                )
            self.fillet = ArcSurface(x_l, zp, theta, x_r, zp, **ripple)
        else:
            z_c = zp + p.fillet_height
            if z_c < lead.bottom_z + 0.005:
                raise OptionError(
                    f"fillet_height ({p.fillet_height} mm) must exceed lead_lift "
                    f"({p.lead_lift} mm) by at least 0.005 mm so the solder reaches the lead"
                )
            if z_c > lead.top_z - 0.1:
                raise OptionError(f"fillet_height ({p.fillet_height} mm) reaches too close to the lead cut")
            x_c = float(lead.outer_x(z_c))
            theta_a, theta_c = p.contact_angle_pad, p.lead_slope_angle
            phi = (theta_a + theta_c) / 2
            if phi < math.radians(3.0):
                raise OptionError(
                    "contact_angle_pad + lead_slope_angle must be at least 6 deg (the fillet "
                    f"must rise from pad to lead), got {math.degrees(2 * phi):.2f} deg"
                )
            x_a = x_c - p.fillet_height / math.tan(phi)
            if x_a < pad_x0 + 0.01:
                raise OptionError(
                    f"fillet foot at x = {x_a:.3f} mm lies off the pad (pad starts at "
                    f"x = {pad_x0:.3f} mm): lower fillet_height, raise contact_angle_pad or "
                    f"lead_slope_angle, or lengthen pad_length"
                )
            self.fillet = ArcSurface(x_a, zp, theta_a, x_c, z_c, **ripple)
            n_lead = lead.outer_normal(z_c)
            t_down = np.array([-n_lead[1], n_lead[0]])
            back = -np.array([math.cos(theta_c), math.sin(theta_c)])
            psi = math.atan2(back[0] * t_down[1] - back[1] * t_down[0], float(back @ t_down))
            if not 0.0 < psi < math.pi:
                raise OptionError(
                    f"lead_slope_angle ({math.degrees(theta_c):.1f} deg) makes the solder cut into "
                    f"the lead at the contact (contact angle {math.degrees(psi):.1f} deg)"
                )
            self.contact_point = (x_c, z_c)
            self.contact_angle_lead = psi
        xg = self.fillet.tangent_angle_grid(4001, 1001)
        zg = self.fillet.z(xg)
        if self.contact_point is not None:
            inside = (xg < self.contact_point[0] - 1e-6) & (zg >= lead.bottom_z)  # below C, beside the lead
            if np.any(xg[inside] > lead.outer_x(zg[inside]) - 1e-7):
                raise OptionError(
                    f"the fillet cuts into the lead: raise lead_slope_angle "
                    f"({math.degrees(p.lead_slope_angle):.1f} deg) or lower fillet_height"
                )
        if self.visible_x_range[1] - self.fillet.x_start < MIN_VISIBLE_LENGTH:
            raise OptionError(
                f"the lead hides all but {self.visible_x_range[1] - self.fillet.x_start:.3f} mm "
                f"of the solder surface (at least {MIN_VISIBLE_LENGTH} mm must show): lower "
                "contact_angle_pad or lead_slope_angle, or raise fillet_height"
            )
        if np.any(zg < zp - 1e-9):
            raise OptionError(
                f"ripple_amplitude ({p.ripple_amplitude} mm) pushes the solder surface below "
                "the pad top; lower it"
            )
        self._apex_z = float(np.max(zg))
        if self.fillet.x_start < -FIELD_HALF_WIDTH or self.fillet.x_end > FIELD_HALF_WIDTH:
            raise OptionError("the fillet leaves the camera field; shorten pad_length")
        if p.kind == "bridge":
            x_mid = 0.5 * (self.fillet.x_start + self.fillet.x_end)
            half = p.bridge_length / 2
            if x_mid - half < -FIELD_HALF_WIDTH or x_mid + half > FIELD_HALF_WIDTH:
                raise OptionError(f"bridge_length ({p.bridge_length} mm) leaves the camera field")
            theta_b = 2.0 * math.atan(p.bridge_height / half)
            self.bridge = ArcSurface(x_mid - half, 0.0, theta_b, x_mid + half, 0.0)
            overlap = 0.02
            self.bridge_y_range = (
                self.solder_half_width - overlap,
                p.neighbour_pitch - self.solder_half_width + overlap,
            )

    # -- derived scalars --------------------------------------------------

    @property
    def kind(self):
        """Joint class, one of :data:`JOINT_KINDS`."""
        return self.params.kind

    @property
    def fillet_x_range(self):
        """``(x_start, x_end)`` of the main solder surface at y = 0, mm."""
        return self.fillet.x_range

    @property
    def fillet_height(self):
        """Apex height of the main solder surface above the pad top, mm.

        Equals ``params.fillet_height`` for concave fillets and balls; larger
        for excess fillets that crest before reaching the lead.
        """
        return self._apex_z - self.pad_top_z

    @property
    def visible_x_range(self):
        """x-range at y = 0 where the main solder surface is the top-most one.

        ``(x_start, x_stop)`` in mm: the lead overhangs (and hides from a
        camera looking down -z) the part of the fillet beyond ``lead.min_x``.
        """
        x0 = self.fillet.x_start
        return (x0, max(x0, min(self.fillet.x_end, self.lead.min_x)))

    # -- exact profile ----------------------------------------------------

    def _surfaces(self):
        w = self.solder_half_width
        out = [(self.fillet, -w, w)]
        if self.bridge is not None:
            pitch = self.params.neighbour_pitch
            out.append((self.fillet, pitch - w, pitch + w))
            out.append((self.bridge, *self.bridge_y_range))
        return out

    def _top(self, x, y, ripple):
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        zs, dzs, d2zs = [], [], []
        for surf, y0, y1 in self._surfaces():
            z, dz, d2z = surf._eval(x, ripple)
            iny = (y >= y0) & (y <= y1)
            zs.append(np.where(iny, z, np.nan))
            dzs.append(dz)
            d2zs.append(d2z)
        zs = np.stack(zs)
        filled = np.where(np.isnan(zs), -np.inf, zs)
        idx = np.argmax(filled, axis=0)[None]
        z = np.take_along_axis(zs, idx, 0)[0]
        dz = np.take_along_axis(np.stack(dzs), idx, 0)[0]
        d2z = np.take_along_axis(np.stack(d2zs), idx, 0)[0]
        nan = np.isnan(z)
        return z, np.where(nan, np.nan, dz), np.where(nan, np.nan, d2z)

    def profile_z(self, x, y=0.0, *, ripple=True):
        """Height of the top-most solder surface, mm.

        Parameters
        ----------
        x, y : array_like, mm
            Broadcast together.
        ripple : bool
            ``False`` gives the smooth meniscus without the ripple.

        Returns
        -------
        ndarray of float, mm
            NaN where there is no solder surface at (x, y).
        """
        return self._top(x, y, ripple)[0]

    def profile_slope(self, x, y=0.0, *, ripple=True):
        """Slope ``p = dz/dx`` of the solder surface (``q = dz/dy = 0``); NaN off it."""
        return self._top(x, y, ripple)[1]

    def profile_normal(self, x, y=0.0, *, ripple=True):
        """(..., 3) unit outward normal ``(-p, 0, 1)/sqrt(1 + p^2)``; NaN off the solder."""
        p = self.profile_slope(x, y, ripple=ripple)
        return normal_from_gradient(p, np.zeros_like(p))

    def profile_curvature(self, x, y=0.0, *, ripple=True):
        """Signed curvature in the x-z plane, 1/mm, positive where convex."""
        _, dz, d2z = self._top(x, y, ripple)
        return -d2z / (1.0 + dz * dz) ** 1.5

    def summary(self):
        """JSON-ready dict of derived quantities (mm, radians and degrees)."""
        out = {
            "fillet_x_range": list(self.fillet_x_range),
            "visible_x_range": list(self.visible_x_range),
            "fillet_height": self.fillet_height,
            "pad_x_range": list(self.pad_x_range),
            "pad_top_z": self.pad_top_z,
            "solder_y_range": [-self.solder_half_width, self.solder_half_width],
            "lead_bottom_z": self.lead.bottom_z,
            "lead_min_x": self.lead.min_x,
            "smooth_curvature": self.fillet.curvature_smooth,
            "contact_angle_pad_deg": math.degrees(self.params.contact_angle_pad),
        }
        if self.contact_point is not None:
            out["contact_point"] = list(self.contact_point)
            out["contact_angle_lead"] = self.contact_angle_lead
            out["contact_angle_lead_deg"] = math.degrees(self.contact_angle_lead)
            out["lead_slope_angle_deg"] = math.degrees(self.params.lead_slope_angle)
        if self.bridge is not None:
            out["bridge_x_range"] = list(self.bridge.x_range)
            out["bridge_y_range"] = list(self.bridge_y_range)
        return out
