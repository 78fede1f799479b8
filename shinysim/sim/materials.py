"""Mitsuba material dicts that approximate the paper's reflectance model (Eq 5).

Builds plain Python dicts (no mitsuba import): pass them to
``mitsuba.load_dict`` or put them in a scene dict as a shape's ``"bsdf"``.
"""

from __future__ import annotations

import numpy as np

from ..errors import OptionError
from ..theory.reflectance import alpha_from_sharpness

__all__ = ["blend_weight", "paper_material"]


def blend_weight(k, sharpness, *, distribution="ggx", diffuse_reflectance=1.0):
    """``blendbsdf`` weight that gives Eq 5's ratio of specular to diffuse light.

    Mitsuba's ``blendbsdf`` returns ``(1 - w) f_diffuse + w f_conductor``.
    Per unit source irradiance, a patch seen along ``z`` then has radiance::

        L = (1 - w) rho/pi (n.s) + w F G D(delta) / (4 n.z),

    and Eq 5 is ``A k (n.s) + (A/2)(1 - k) cos(2 delta)^sharpness``. With
    ``D(0) = 1 / (pi alpha^2)`` (GGX and Beckmann), ``F = 1`` (Mitsuba's
    ``material="none"``), ``G = 1`` and ``n.z = 1`` at the peak, equal
    ratios of peak specular to diffuse slope need::

        w / (1 - w) = 2 alpha^2 rho (1 - k) / k,

    and then ``A = (1 - w) rho / (pi k)`` times the source irradiance
    (``A = w / (2 pi alpha^2 (1 - k))`` when ``k = 0``).

    Parameters
    ----------
    k : array_like, in [0, 1]
        Eq 5 Lambertian weight.
    sharpness : array_like, > 0
        Eq 5 exponent; ``alpha = alpha_from_sharpness(sharpness, distribution)``.
    distribution : {"ggx", "beckmann"}
    diffuse_reflectance : float, in (0, 1]
        Albedo ``rho`` of the ``diffuse`` component.

    Returns
    -------
    ndarray, in [0, 1]

    Notes
    -----
    Approximate: the peak height is matched at the peak only, where
    ``n.z = cos(theta_s / 2)`` is really below 1 (the microfacet peak is
    ``1 / cos(theta_s / 2)`` brighter, 35 percent at ``theta_s = 84`` deg),
    Smith ``G`` is slightly below 1, and the lobe shapes agree only up to
    their half-width (see :func:`shinysim.theory.reflectance.sharpness_from_alpha`).
    """
    k = np.asarray(k, dtype=float)
    if np.any((k < 0) | (k > 1)):
        raise OptionError(f"k must lie in [0, 1]; got {k!r}")
    if not 0 < diffuse_reflectance <= 1:
        raise OptionError(f"diffuse_reflectance must lie in (0, 1]; got {diffuse_reflectance!r}")
    alpha = alpha_from_sharpness(sharpness, distribution)
    spec = 2.0 * alpha**2 * diffuse_reflectance * (1.0 - k)
    with np.errstate(divide="ignore", invalid="ignore"):
        return spec / (k + spec)


def paper_material(k, sharpness, *, distribution="ggx", diffuse_reflectance=1.0):
    """Mitsuba ``blendbsdf`` dict of ``diffuse`` and ``roughconductor`` for Eq 5.

    Parameters
    ----------
    k : float, in [0, 1]
        Eq 5 Lambertian weight.
    sharpness : float, > 0
        Eq 5 exponent.
    distribution : {"ggx", "beckmann"}
        Microfacet distribution of the conductor.
    diffuse_reflectance : float, in (0, 1]

    Returns
    -------
    dict
        ``{"type": "blendbsdf", "weight": w, "bsdf_0": diffuse,
        "bsdf_1": roughconductor}``; ``bsdf_0`` is taken at weight 0 (Mitsuba
        orders the children by name). The conductor is a 100 percent
        reflector (``material="none"``) with
        ``alpha = alpha_from_sharpness(sharpness, distribution)``, and ``w``
        is :func:`blend_weight`.

    Raises
    ------
    ValueError
        If ``sharpness`` maps to no valid alpha, or ``k`` or
        ``diffuse_reflectance`` is out of range.
    """
    alpha = float(alpha_from_sharpness(sharpness, distribution))
    if not np.isfinite(alpha) or alpha <= 0:
        raise OptionError(f"sharpness must be finite and > 0; got {sharpness!r}")
    w = float(blend_weight(k, sharpness, distribution=distribution, diffuse_reflectance=diffuse_reflectance))
    return {
        "type": "blendbsdf",
        "weight": w,
        "bsdf_0": {"type": "diffuse", "reflectance": float(diffuse_reflectance)},
        "bsdf_1": {"type": "roughconductor", "distribution": distribution, "alpha": alpha, "material": "none"},
    }
