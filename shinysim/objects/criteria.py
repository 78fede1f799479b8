r"""Acceptance classes of solder joints decided by criteria on their geometry.

The classes of an inspection follow from measurable quantities of each joint,
in the manner of IPC-A-610 (section 8, surface-mount gull-wing and J leads),
not from the generators that made them. :func:`judge` measures a joint's
exact geometry (:class:`~shinysim.objects.solder.JointProfile`) and applies
:class:`AcceptanceCriteria`: the first criterion violated, in the order of
:data:`DEFECT_ORDER`, gives the class, ``"good"`` if none; each continuous
criterion also gives a signed margin (:attr:`Judgement.near_boundary`).
Pure numpy; the reconstruction side may import it. The criteria and what is
not modelled: ``docs/solder.md``, section "Inspection under nuisances".
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from .._shared import check_number
from ..errors import OptionError
from .solder import WETTED_KINDS, JointParams, JointProfile

__all__ = ["DEFECT_ORDER", "CLASSES", "AcceptanceCriteria", "Judgement", "measure_joint", "judge"]

#: Defect classes in the order their criteria are applied (the first one a
#: joint violates is its class).
DEFECT_ORDER = ("bridge", "lifted", "insufficient", "excess")
#: Every class :func:`judge` can give.
CLASSES = ("good",) + DEFECT_ORDER


@dataclass(frozen=True)
class AcceptanceCriteria:
    """Thresholds of the acceptance criteria (the table in ``docs/solder.md``, "Inspection under nuisances").

    Attributes
    ----------
    heel_fillet_fraction : float
        Minimum heel fillet height ``F >= G + heel_fillet_fraction * T``
        (0.5: IPC-A-610 class 2; 1.0: class 3).
    max_wetting_angle_deg : float
        Largest acceptable wetting angle at the lead and at the pad, degrees.
    near_fraction : float
        A joint within this relative distance of a boundary is "near" it.
    """

    heel_fillet_fraction: float = 0.5
    max_wetting_angle_deg: float = 90.0
    near_fraction: float = 0.1

    def __post_init__(self):
        check_number("heel_fillet_fraction", self.heel_fillet_fraction, lo=0.0, hi=5.0)
        check_number("max_wetting_angle_deg", self.max_wetting_angle_deg, lo=0.0, hi=180.0, lo_open=True)
        check_number("near_fraction", self.near_fraction, lo=0.0, hi=1.0)

    def to_dict(self):
        return asdict(self)


@dataclass(frozen=True)
class Judgement:
    """The class of one joint and why.

    Attributes
    ----------
    label : str
        One of :data:`CLASSES`.
    violated : tuple of str
        Every defect class whose criterion the joint violates, in
        :data:`DEFECT_ORDER`.
    margins : dict of str -> float
        ``"heel_fillet"``: ``(F - F_min) / F_min``; ``"wetting_angle"``:
        ``(max - angle) / max``; negative where violated. Only for joints
        whose solder wets the lead.
    near_boundary : bool
        Some margin lies within ``near_fraction`` of zero.
    measurements : dict of str -> float or bool
        See :func:`measure_joint`.
    """

    label: str
    violated: tuple
    margins: dict
    near_boundary: bool
    measurements: dict

    def to_dict(self):
        return {"label": self.label, "violated": list(self.violated), "margins": dict(self.margins),
                "near_boundary": self.near_boundary, "measurements": dict(self.measurements)}


def _profile(joint):
    if isinstance(joint, JointParams):
        return JointProfile(joint)
    if isinstance(joint, JointProfile):
        return joint
    prof = getattr(joint, "profile", None)  # a shinysim.sim.solder.Joint
    if isinstance(prof, JointProfile):
        return prof
    raise OptionError(f"joint must be a JointParams, JointProfile or Joint, got {type(joint).__name__}")


def measure_joint(joint):
    """The quantities the acceptance criteria look at, from the exact geometry.

    Parameters
    ----------
    joint : JointParams, JointProfile or shinysim.sim.solder.Joint

    Returns
    -------
    dict
        ``wets_lead`` (the solder meets the lead), ``bridged`` (solder joins
        the neighbour), ``heel_fillet_mm`` (``F``; 0 where the lead is not
        wetted), ``solder_under_lead_mm`` (``G``), ``lead_thickness_mm``
        (``T``), ``wetting_angle_lead_deg`` (through the solder, between
        its surface at the contact and the lead's leg: ``180 deg -
        leg_angle - lead_slope_angle``; the leg, not the bend's local
        tangent, so that a low fillet meeting the curved heel is judged by
        the contour an inspector sees), ``contact_angle_lead_local_deg``
        (against the local tangent of the lead where the solder meets it)
        and ``wetting_angle_pad_deg``; the lead angles are None where the
        lead is not wetted.
    """
    prof = _profile(joint)
    p = prof.params
    wets = p.kind in WETTED_KINDS
    return {
        "wets_lead": wets,
        "bridged": p.kind == "bridge",
        "heel_fillet_mm": float(p.fillet_height) if wets else 0.0,
        "solder_under_lead_mm": float(p.lead_lift),
        "lead_thickness_mm": float(p.lead_thickness),
        "wetting_angle_lead_deg": (180.0 - math.degrees(prof.lead.leg_angle + p.lead_slope_angle)) if wets else None,
        "contact_angle_lead_local_deg": math.degrees(prof.contact_angle_lead) if wets else None,
        "wetting_angle_pad_deg": math.degrees(p.contact_angle_pad),
    }


def judge(joint, criteria=None):
    """Class of a joint by the acceptance criteria.

    Parameters
    ----------
    joint : JointParams, JointProfile or shinysim.sim.solder.Joint
    criteria : AcceptanceCriteria, optional

    Returns
    -------
    Judgement
    """
    c = criteria if criteria is not None else AcceptanceCriteria()
    if not isinstance(c, AcceptanceCriteria):
        raise OptionError(f"criteria must be an AcceptanceCriteria, got {type(c).__name__}")
    m = measure_joint(joint)
    violated = []
    margins = {}
    if m["bridged"]:
        violated.append("bridge")
    if not m["wets_lead"]:
        violated.append("lifted")
    else:
        f_min = m["solder_under_lead_mm"] + c.heel_fillet_fraction * m["lead_thickness_mm"]
        margins["heel_fillet"] = (m["heel_fillet_mm"] - f_min) / f_min
        if margins["heel_fillet"] < 0:
            violated.append("insufficient")
        angle = max(m["wetting_angle_lead_deg"], m["wetting_angle_pad_deg"])
        margins["wetting_angle"] = (c.max_wetting_angle_deg - angle) / c.max_wetting_angle_deg
        if margins["wetting_angle"] < 0:
            violated.append("excess")
    violated = tuple(k for k in DEFECT_ORDER if k in violated)
    label = violated[0] if violated else "good"
    near = any(abs(v) <= c.near_fraction for v in margins.values())
    return Judgement(label, violated, margins, near, m)
