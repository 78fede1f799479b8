"""Mitsuba scenes and scans of procedural solder joints.

:func:`joint_objects` turns a :class:`~shinysim.sim.solder.Joint` into named
Mitsuba shapes (one per mesh part, with the BSDFs of
:data:`SOLDER_MATERIALS`; the names become the truth's ``part_names``), and
:func:`scan_joint` renders them through the SHINY rig (:func:`solder_rig`),
with inter-reflections (Mitsuba's ``path`` integrator, ``max_depth=3``) or
direct light only, or both, to label the inter-reflected highlights. The
materials and why, and the inter-reflections: ``docs/solder.md``, section
"Scanning joints".
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import OptionError
from ..rig import shiny_1988
from .scene import rough_conductor

__all__ = [
    "SOLDER_MATERIALS",
    "solder_rig",
    "joint_objects",
    "JointScan",
    "joint_simulator",
    "scan_joint",
]

#: BSDF settings per part family (the table in ``docs/solder.md``, "Scanning joints").
SOLDER_MATERIALS = {
    "solder": {"alpha": 0.03, "reflectance": 0.7},
    "lead": {"alpha": 0.08, "reflectance": 0.6},
    "pad": {"alpha": 0.05, "material": "Cu"},
    "board": {"reflectance": 0.04},
}

def solder_rig(resolution=512, **kwargs):
    """The SHINY rig used for solder scans: :func:`shinysim.rig.shiny_1988`
    (21 fibers, perspective camera 5 in above the board, 2 mm field) at
    ``resolution`` pixels; keyword arguments pass through."""
    return shiny_1988(resolution=resolution, **kwargs)


def _family(part):
    if part in ("solder", "neighbour_solder", "bridge"):
        return "solder"
    if part.endswith("lead"):
        return "lead"
    if part.endswith("pad"):
        return "pad"
    if part == "board":
        return "board"
    raise OptionError(f"unknown solder-joint part {part!r}")


def _bsdf(family, solder_alpha):
    m = SOLDER_MATERIALS[family]
    if family == "board":
        return {"type": "diffuse", "reflectance": float(m["reflectance"])}
    if family == "pad":
        return rough_conductor(m["alpha"], material=m["material"])
    alpha = solder_alpha if family == "solder" else m["alpha"]
    return rough_conductor(alpha, reflectance=m["reflectance"])


def joint_objects(joint, folder, *, solder_alpha=None):
    """Mitsuba shape dicts of a joint's parts, from PLY files in ``folder``.

    Parameters
    ----------
    joint : shinysim.sim.solder.Joint
    folder : path-like
        Existing folder to write ``<part>.ply`` into (files there are
        replaced).
    solder_alpha : float, optional
        Roughness of the solder parts (default
        ``SOLDER_MATERIALS["solder"]["alpha"]``).

    Returns
    -------
    dict of str -> dict
        ``{part: {"type": "ply", "filename": ..., "bsdf": ...}}``, solder
        parts first.
    """
    from .solder import write_ply

    alpha = SOLDER_MATERIALS["solder"]["alpha"] if solder_alpha is None else float(solder_alpha)
    if not (np.isfinite(alpha) and alpha > 0):
        raise OptionError(f"solder_alpha must be > 0, got {solder_alpha!r}")
    folder = Path(folder)
    out = {}
    for name, mesh in joint.meshes.items():
        path = folder / f"{name}.ply"
        write_ply(path, mesh, overwrite=True)
        out[name] = {"type": "ply", "filename": str(path), "bsdf": _bsdf(_family(name), alpha),
                     "face_normals": False}
    return out


def joint_simulator(joint, rig=None, *, interreflections=True, solder_alpha=None, max_depth=3,
                    variant=None):
    """A :class:`~shinysim.sim.render.Simulator` of one joint.

    Parameters
    ----------
    joint : shinysim.sim.solder.Joint
    rig : Rig, optional
        Default :func:`solder_rig` at 512 px.
    interreflections : bool
        ``path`` integrator with ``max_depth`` (per-source rendering) when
        True; direct light only (one-pass rendering) when False.
    solder_alpha : float, optional
    max_depth : int
        Longest light path, in Mitsuba's counting (3 = two bounces).
    variant : str, optional
    """
    from .render import Simulator

    rig = rig or solder_rig()
    integrator = {"type": "path", "max_depth": int(max_depth)} if interreflections else {"type": "direct"}
    with tempfile.TemporaryDirectory(prefix="shinysim-joint-") as tmp:
        objects = joint_objects(joint, tmp, solder_alpha=solder_alpha)
        sim = Simulator(rig, objects, integrator=integrator, variant=variant)
    return sim


@dataclass
class JointScan:
    """A rendered scan of one joint.

    Attributes
    ----------
    joint : Joint
    stack : shinysim.io.Stack
        The frames the reconstruction sees (with inter-reflections when the
        scan was rendered with them).
    truth : shinysim.io.Truth
        Pixel-centre truth; ``truth.part_names`` names the parts.
    direct : shinysim.io.Stack or None
        The same scan with direct light only (for labelling
        inter-reflections), when rendered.
    seconds : dict
        Render times.
    """

    joint: object
    stack: object
    truth: object
    direct: object = None
    seconds: dict = field(default_factory=dict)

    @property
    def part_names(self):
        return list(self.truth.part_names)

    def part_mask(self, *names):
        """(H, W) bool: pixels whose centre ray hits one of the named parts."""
        ids = [self.truth.part_names.index(n) for n in names if n in self.truth.part_names]
        return np.isin(self.truth.part, ids)


def scan_joint(joint, rig=None, *, spp=32, seed=0, interreflections=True, direct_reference=False,
               solder_alpha=None, variant=None, progress=None):
    """Render a joint's highlight stack and truth through the rig.

    Parameters
    ----------
    joint : shinysim.sim.solder.Joint
    rig : Rig, optional
        Default :func:`solder_rig` (512 px).
    spp : int
        Samples per pixel per source.
    seed : int
    interreflections : bool
        Render with the ``path`` integrator (two bounces); else direct light
        only.
    direct_reference : bool
        Also make the direct-light stack (:attr:`JointScan.direct`), to
        label inter-reflection highlights. With inter-reflections on a JIT
        variant it is the first-bounce part of the same samples, from the
        same render (:meth:`~shinysim.sim.render.Simulator.render_stack_and_direct`);
        otherwise a second render from the same seed (its time in
        ``seconds["direct"]``).
    progress : callable, optional
        ``progress(done, total)`` per source.

    Returns
    -------
    JointScan
    """
    import time

    from .variants import is_vectorized

    rig = rig or solder_rig()
    sim = joint_simulator(joint, rig, interreflections=interreflections, solder_alpha=solder_alpha,
                          variant=variant)
    t0 = time.perf_counter()
    truth = sim.render_truth()
    t1 = time.perf_counter()
    direct = None
    if direct_reference and interreflections and is_vectorized(sim.variant):
        # one render: the direct-light stack is the first-bounce part of the same samples
        stack, direct = sim.render_stack_and_direct(spp=spp, seed=seed, progress=progress)
    else:
        stack = sim.render_stack(spp=spp, seed=seed, progress=progress)
    t2 = time.perf_counter()
    seconds = {"truth": t1 - t0, "stack": t2 - t1}
    if direct_reference and direct is None:
        if interreflections:
            dsim = joint_simulator(joint, rig, interreflections=False, solder_alpha=solder_alpha,
                                   variant=variant)
            direct = dsim.render_stack(spp=spp, seed=seed)
        else:
            direct = stack
        seconds["direct"] = time.perf_counter() - t2
    stack.provenance["joint"] = {"kind": joint.kind, "params": joint.params.to_dict()}
    stack.provenance["interreflections"] = bool(interreflections)
    return JointScan(joint, stack, truth, direct, seconds)
