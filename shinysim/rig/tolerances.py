"""Tolerances of a built rig, and a *true* rig drawn from a nominal one within them."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from .._shared import check_attributes, derive_seed
from ..conventions import normalize
from ..errors import RigError, check_fields
from .core import Camera, Rig, _floats_or_empty

__all__ = ["RigTolerances", "perturb_rig"]


@dataclass(frozen=True)
class RigTolerances:
    """How far a built rig may be from its design: what :func:`perturb_rig` draws.

    Random quantities are drawn from the seed; magnitudes marked *exact* are
    applied at exactly that size in a random direction, so that a study can
    say "a rotation of 0.05 degrees" rather than "of about".

    Parameters
    ----------
    fiber_position_mm : float
        Standard deviation of each fiber's position error, per axis (mm).
    fiber_radius_fraction : float
        Standard deviation of each fiber's relative radius error.
    camera_rotation_deg : float
        Exact angle of the camera's rotation about its centre of projection,
        about a random axis (degrees).
    camera_translation_mm : float
        Exact length of the camera's translation, in a random direction (mm).
    focal_fraction : float
        Exact relative change of the focal length: the field width becomes
        ``field_width / (1 + focal_fraction)`` (a longer focal length
        magnifies).
    principal_point_px : float
        Exact distance of the principal point from its nominal place, in a
        random direction (pixels).
    distortion : (k1, k2)
        Radial distortion added to the nominal camera's (exact); its
        tangential terms, ``k3`` and aspect are kept.
    """

    fiber_position_mm: float = 0.0
    fiber_radius_fraction: float = 0.0
    camera_rotation_deg: float = 0.0
    camera_translation_mm: float = 0.0
    focal_fraction: float = 0.0
    principal_point_px: float = 0.0
    distortion: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        check_attributes(self, {"fiber_position_mm": dict(lo=0.0), "fiber_radius_fraction": dict(lo=0.0),
                                "camera_rotation_deg": dict(lo=0.0), "camera_translation_mm": dict(lo=0.0),
                                "principal_point_px": dict(lo=0.0), "focal_fraction": dict(lo=-0.5, hi=0.5)})
        k = _floats_or_empty(self.distortion)
        if k.shape != (2,) or not np.all(np.isfinite(k)):
            raise RigError(f"must be 2 finite numbers (k1, k2), got {self.distortion!r}", field="distortion")
        object.__setattr__(self, "distortion", (float(k[0]), float(k[1])))

    def to_dict(self) -> dict:
        return {**asdict(self), "distortion": list(self.distortion)}

    @classmethod
    def from_dict(cls, d: dict) -> RigTolerances:
        check_fields(d, cls().to_dict(), error=RigError, field="tolerances")
        return cls(**d)


def _rotation(axis, angle):
    """Rotation matrix about a unit ``axis`` by ``angle`` radians (Rodrigues)."""
    a = normalize(np.asarray(axis, float))
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _random_unit(rng, n=3):
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


def perturb_rig(nominal: Rig, tolerances: RigTolerances, seed: int = 0) -> Rig:
    """A *true* rig: the nominal one as it might have been built.

    Every draw comes from ``seed`` (per source and per camera, so adding a
    source does not change the others' errors). The result's
    ``metadata["perturbation"]`` records the seed, the tolerances and every
    applied error, so a scan rendered with it says how it differs from the
    rig a reconstruction is given.

    Parameters
    ----------
    nominal : Rig
    tolerances : RigTolerances
    seed : int

    Returns
    -------
    Rig
        Same sources (distant ones keep their direction), cameras moved,
        rotated, refocused, with principal point and distortion as drawn.
    """
    if not isinstance(tolerances, RigTolerances):
        raise RigError(f"must be RigTolerances, got {type(tolerances).__name__}", field="tolerances")
    tol = tolerances
    pos = nominal.source_positions.copy()
    radii = nominal.source_radii.copy()
    offsets = np.zeros_like(pos)
    for i in range(nominal.n_sources):
        rng = np.random.default_rng(derive_seed(seed, "source", i))
        d, f = rng.normal(size=3), rng.normal()
        if not nominal.source_distant[i]:
            offsets[i] = tol.fiber_position_mm * d
            radii[i] = radii[i] * max(0.0, 1.0 + tol.fiber_radius_fraction * f)
    pos = pos + offsets
    cams, applied_cams = [], []
    for j, cam in enumerate(nominal.cameras):
        rng = np.random.default_rng(derive_seed(seed, "camera", j))
        axis, direction, pp_dir = _random_unit(rng), _random_unit(rng), _random_unit(rng, 2)
        R = _rotation(axis, math.radians(tol.camera_rotation_deg))
        shift = tol.camera_translation_mm * direction
        position = cam.position + shift
        target = position + R @ (cam.target - cam.position)
        pp = cam.principal_point_px + tol.principal_point_px * pp_dir
        k = (cam.distortion[0] + tol.distortion[0], cam.distortion[1] + tol.distortion[1], *cam.distortion[2:])
        cams.append(Camera(cam.projection, cam.width, cam.height, position, target, R @ cam.up,
                           cam.field_width / (1.0 + tol.focal_fraction), cam.name,
                           principal_point=tuple(pp), distortion=k, aspect=cam.aspect))
        applied_cams.append({"rotation_axis": axis.tolist(), "rotation_deg": tol.camera_rotation_deg,
                             "translation_mm": shift.tolist(), "focal_fraction": tol.focal_fraction,
                             "principal_point_shift_px": (tol.principal_point_px * pp_dir).tolist(),
                             "distortion_added": list(tol.distortion)})
    metadata = dict(nominal.metadata)
    metadata["perturbation"] = {
        "seed": int(seed),
        "nominal": nominal.name,
        "tolerances": tol.to_dict(),
        "source_offsets_mm": offsets.tolist(),
        "source_radius_scale": np.divide(radii, nominal.source_radii, out=np.ones_like(radii),
                                         where=nominal.source_radii > 0).tolist(),
        "cameras": applied_cams,
    }
    return Rig(pos, radii, tuple(cams), nominal.source_distant, nominal.reference_z, f"{nominal.name} (as built)",
               metadata, nominal.anchor)
