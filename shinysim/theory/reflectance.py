"""The paper's reflectance model and reflectance maps, Eqs 5-8 and Figs 3-4.

Sanderson, Weiss & Nayar (1988), Section II. Frames, angles and gradient
space follow :mod:`shinysim.conventions`: view direction ``z = (0, 0, 1)``,
normal ``n ~ (-p, -q, 1)`` and the *same* mapping for source directions.

Eq 5 (the paper's exponent ``n`` is called ``sharpness`` here, because
``n`` is also the normal)::

    E = A k max(0, n.s) + (A/2)(1 - k) max(0, 2 (n.z)(n.s) - z.s) ** sharpness

The bracket is ``r.z`` with ``r = 2 (n.s) n - s`` the mirror image of the
source direction about the normal, so the specular term is a Phong lobe
around the mirror direction; it peaks (value 1) where ``n`` bisects ``s``
and ``z``.

Also here: the relation between ``sharpness`` and the microfacet roughness
``alpha`` of the GGX and Beckmann distributions used for rendering
(:func:`sharpness_from_alpha`, :func:`alpha_from_sharpness`; derivation in
``docs/theory.md``).

Pure numpy.
"""

from __future__ import annotations

import numpy as np

from .._shared import check_choice
from ..conventions import VIEW_UP, bisector, normal_from_gradient, normalize
from ..errors import OptionError

__all__ = [
    "COMBINE_METHODS",
    "CONVENTIONS",
    "DISTRIBUTIONS",
    "alpha_from_sharpness",
    "lobe_hwhm",
    "peak_angles",
    "peak_gradient",
    "peak_normal",
    "reflectance",
    "reflectance_map",
    "sharpness_from_alpha",
]

#: Valid ``convention`` strings.
CONVENTIONS = ("correct", "printed")

#: Valid ``combine`` strings of :func:`reflectance_map`.
COMBINE_METHODS = ("max", "sum")

#: Microfacet distributions and the constant ``c`` of their half-maximum
#: slope: the slope-space shape falls to one half at ``tan(delta)^2 = c alpha^2``.
#: GGX: ``(alpha^2 / (alpha^2 + tan^2))^2 = 1/2``; Beckmann:
#: ``exp(-tan^2 / alpha^2) = 1/2``.
DISTRIBUTIONS = {"ggx": np.sqrt(2.0) - 1.0, "beckmann": np.log(2.0)}


def reflectance(normal, source_dir, view_dir=VIEW_UP, *, k, sharpness, A=1.0):
    """Image brightness of a surface patch under one distant source, Eq 5.

    Parameters
    ----------
    normal : (..., 3) array_like
        Surface normals (normalised here).
    source_dir : (..., 3) array_like
        Directions from the patch towards the source (normalised here).
    view_dir : (..., 3) array_like
        Direction from the patch towards the camera, ``z`` of Eq 5 (default
        ``(0, 0, 1)``, the paper's orthographic camera).
    k : array_like, in [0, 1]
        Weight of the Lambertian component; ``1 - k`` weights the specular one.
    sharpness : array_like, >= 0
        Exponent of the specular lobe (the paper's ``n``).
    A : array_like
        Overall scale (illumination intensity times albedo).

    Returns
    -------
    (...) ndarray of float64
        Brightness, broadcast over the leading axes. NaN where an input is NaN.

    Raises
    ------
    ValueError
        If ``k`` is outside [0, 1] or ``sharpness`` is negative.

    Notes
    -----
    Both terms are clamped at zero: ``n.s < 0`` (source behind the patch)
    gives no Lambertian light, and a negative bracket (mirror direction
    below the horizon of ``z``) gives no specular light, which also keeps
    non-integer exponents real.
    """
    k = np.asarray(k, dtype=float)
    sharpness = np.asarray(sharpness, dtype=float)
    if np.any((k < 0) | (k > 1)):
        raise OptionError(f"k must lie in [0, 1]; got {k!r}")
    if np.any(sharpness < 0):
        raise OptionError(f"sharpness must be >= 0; got {sharpness!r}")
    n = normalize(normal)
    s = normalize(source_dir)
    z = normalize(view_dir)
    ns = np.sum(n * s, axis=-1)
    nz = np.sum(n * z, axis=-1)
    zs = np.sum(z * s, axis=-1)
    lambertian = np.maximum(ns, 0.0)
    bracket = np.maximum(2.0 * nz * ns - zs, 0.0)
    with np.errstate(invalid="ignore", over="ignore"):
        specular = bracket**sharpness
    return A * k * lambertian + 0.5 * A * (1.0 - k) * specular


def peak_normal(source_dir, view_dir=VIEW_UP):
    """Normal at the peak of Eq 5's specular lobe: ``n ~ s + z``.

    Eq 6, ``n.z = n.s``, is necessary but not sufficient: every normal on
    the great circle of directions equidistant from ``s`` and ``z`` satisfies
    it (including ones perpendicular to both, where the specular term is 0).
    The peak is the point of that circle in the plane of ``s`` and ``z``
    that bisects them, where the mirror direction ``r`` equals ``z``.

    Parameters
    ----------
    source_dir : (..., 3) array_like
        Directions towards the source.
    view_dir : (..., 3) array_like
        Direction towards the camera (default ``(0, 0, 1)``).

    Returns
    -------
    (..., 3) ndarray
        Unit normals; NaN where ``s = -z`` (no unique bisector).
    """
    return bisector(source_dir, view_dir)


def peak_gradient(ps, qs, *, convention="correct"):
    """Gradient of the specular-peak normal for a source at gradient (ps, qs), Eqs 7-8.

    Parameters
    ----------
    ps, qs : array_like
        Source direction in gradient space, ``s ~ (-ps, -qs, 1)`` (the same
        mapping as for normals; a front-hemisphere source).
    convention : {"correct", "printed"}
        ``"correct"``: ``p = ps / (1 + sqrt(1 + ps^2 + qs^2))`` (same for
        ``q``), algebraically identical to Eqs 7-8 but free of the 0/0 on
        the camera axis and of the cancellation in ``sqrt(1 + r^2) - 1``.
        ``"printed"``: Eqs 7-8 evaluated literally,
        ``p = ps (sqrt(1 + ps^2 + qs^2) - 1) / (ps^2 + qs^2)``; NaN at
        ``ps = qs = 0``.

    Returns
    -------
    p, q : ndarray

    Notes
    -----
    With the same gradient mapping for source and normal, the printed
    Eqs 7-8 agree with :func:`peak_normal` (checked in the tests): there is
    no sign error in them. The sign of ``(p, q)`` flips only if the source is
    mapped as ``s ~ (ps, qs, 1)`` while the normal keeps ``(-p, -q, 1)``. For
    a source at polar angle ``theta`` and azimuth ``phi``,
    ``p = -tan(theta/2) cos(phi)``, ``q = -tan(theta/2) sin(phi)``.
    """
    check_choice("convention", convention, CONVENTIONS)
    ps, qs = np.broadcast_arrays(np.asarray(ps, dtype=float), np.asarray(qs, dtype=float))
    r2 = ps**2 + qs**2
    if convention == "correct":
        scale = 1.0 / (1.0 + np.sqrt(1.0 + r2))
    else:
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = (np.sqrt(1.0 + r2) - 1.0) / r2
    return ps * scale, qs * scale


def peak_angles(theta_s, phi_s, *, convention="correct"):
    """Polar angles of the specular-peak normal for a source at (theta_s, phi_s).

    Parameters
    ----------
    theta_s : array_like, radians
        Source polar angle from +z.
    phi_s : array_like, radians
        Source azimuth from +x towards +y.
    convention : {"correct", "printed"}
        ``"correct"``: ``(theta_s / 2, phi_s)``, Eq 10 and :func:`peak_normal`.
        ``"printed"``: ``(theta_s, phi_s / 2)``, as the sentence before Eq 7
        says (the halving is on the wrong angle).

    Returns
    -------
    theta, phi : ndarray, radians
    """
    check_choice("convention", convention, CONVENTIONS)
    theta_s, phi_s = np.broadcast_arrays(np.asarray(theta_s, dtype=float), np.asarray(phi_s, dtype=float))
    if convention == "correct":
        return 0.5 * theta_s, phi_s.copy()
    return theta_s.copy(), 0.5 * phi_s


def reflectance_map(
    sources,
    *,
    k,
    sharpness,
    p_range=(-1.0, 1.0),
    q_range=(-1.0, 1.0),
    shape=(201, 201),
    combine="max",
    view_dir=VIEW_UP,
    A=1.0,
):
    """Reflectance map ``R(p, q)`` of Eq 5 for one or several distant sources.

    Fig 3 is the map of one source; Fig 4 the map of a whole source array.

    Parameters
    ----------
    sources : (3,) or (n_sources, 3) array_like
        Directions towards the sources (normalised here). A source given in
        gradient space is ``normal_from_gradient(ps, qs)``.
    k, sharpness, A
        As in :func:`reflectance`.
    p_range, q_range : (2,) tuple of float
        Extent of the grid along p (columns) and q (rows), end points included.
    shape : (2,) tuple of int
        ``(n_q, n_p)``: number of rows (q samples) and columns (p samples).
    combine : {"max", "sum"}
        How the sources' maps are combined: ``"max"`` shows every peak at its
        own height (the sources are scanned one at a time); ``"sum"`` is the
        map with all sources on at once.
    view_dir : (3,) array_like
        Direction towards the camera (default ``(0, 0, 1)``).

    Returns
    -------
    E : (n_q, n_p) ndarray
        Brightness; row ``i`` has ``q = q[i, 0]``, column ``j`` has
        ``p = p[0, j]``.
    p, q : (n_q, n_p) ndarray
        Gradient grids.

    Raises
    ------
    ValueError
        For a bad ``combine``, ``shape`` or ``sources`` shape.
    """
    check_choice("combine", combine, COMBINE_METHODS)
    src = np.asarray(sources, dtype=float)
    if src.ndim == 1:
        src = src[None, :]
    if src.ndim != 2 or src.shape[-1] != 3:
        raise OptionError(f"sources must have shape (3,) or (n_sources, 3); got {np.shape(sources)}")
    shape = tuple(int(v) for v in shape)
    if len(shape) != 2 or min(shape) < 1:
        raise OptionError(f"shape must be (n_q, n_p) with positive sizes; got {shape!r}")
    p1 = np.linspace(p_range[0], p_range[1], shape[1])
    q1 = np.linspace(q_range[0], q_range[1], shape[0])
    p, q = np.meshgrid(p1, q1, indexing="xy")
    normals = normal_from_gradient(p, q)
    E = None
    for s in src:
        e = reflectance(normals, s, view_dir, k=k, sharpness=sharpness, A=A)
        if E is None:
            E = e
        elif combine == "max":
            E = np.fmax(E, e)
        else:
            E = E + e
    return E, p, q


# --------------------------------------------------------------------------
# Sharpness (Eq 5) <-> microfacet roughness alpha (GGX, Beckmann)
# --------------------------------------------------------------------------

def _slope_constant(distribution):
    check_choice("distribution", distribution, tuple(DISTRIBUTIONS))
    return DISTRIBUTIONS[distribution]


def sharpness_from_alpha(alpha, distribution="ggx"):
    """Eq 5 exponent whose lobe has the same half-width as a microfacet lobe.

    Matches the half-width at half-maximum, in the angle ``delta`` between
    the normal and the half vector, of Eq 5's specular term
    ``cos(2 delta)^sharpness`` and of the distribution's slope-space shape
    (``D(delta) cos^4(delta) / D(0)``). Closed form::

        sharpness = ln 2 / (2 artanh(c alpha^2)),
        c = sqrt(2) - 1 (GGX) or ln 2 (Beckmann).

    For small ``alpha``: ``sharpness ~ 1 / (2 alpha^2)`` (Beckmann) and
    ``~ 0.8367 / alpha^2`` (GGX).

    Parameters
    ----------
    alpha : array_like, > 0
        Microfacet roughness (Mitsuba's ``alpha``).
    distribution : {"ggx", "beckmann"}

    Returns
    -------
    ndarray
        Sharpness; ``inf`` at ``alpha = 0`` (a mirror) and NaN for
        ``alpha < 0`` or ``alpha >= 1 / sqrt(c)`` (1.554 for GGX, 1.201 for
        Beckmann), where the microfacet lobe is wider than any Eq 5 lobe
        (whose half-width cannot exceed 45 degrees).

    Notes
    -----
    Only the core of the lobe is matched. GGX has long tails (falling like
    ``tan(delta)^-4``, not exponentially), so far from the peak it is much
    brighter than the matched Eq 5 lobe; Beckmann's Gaussian-in-slope tail
    is close. See ``docs/theory.md``.
    """
    c = _slope_constant(distribution)
    alpha = np.asarray(alpha, dtype=float)
    t2 = c * alpha**2
    with np.errstate(divide="ignore", invalid="ignore"):
        n = np.log(2.0) / (2.0 * np.arctanh(t2))
    return np.where((alpha >= 0) & (t2 < 1), n, np.nan)


def alpha_from_sharpness(sharpness, distribution="ggx"):
    """Inverse of :func:`sharpness_from_alpha`.

    ``alpha = sqrt(tanh(ln 2 / (2 sharpness)) / c)``.

    Parameters
    ----------
    sharpness : array_like, > 0
        Eq 5 exponent.
    distribution : {"ggx", "beckmann"}

    Returns
    -------
    ndarray
        Roughness alpha; 0 at ``sharpness = inf``, NaN for ``sharpness <= 0``.
    """
    c = _slope_constant(distribution)
    n = np.asarray(sharpness, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        alpha = np.sqrt(np.tanh(np.log(2.0) / (2.0 * n)) / c)
    return np.where(n > 0, alpha, np.nan)


def lobe_hwhm(*, sharpness=None, alpha=None, distribution="ggx"):
    """Half-width at half-maximum of a lobe, in the angle normal-to-half-vector.

    Give exactly one of ``sharpness`` (Eq 5 lobe ``cos(2 delta)^sharpness``:
    ``delta = arccos(2^(-1/sharpness)) / 2``) or ``alpha`` (microfacet
    slope-space shape: ``delta = atan(alpha sqrt(c))``).

    Parameters
    ----------
    sharpness : array_like, optional
    alpha : array_like, optional
    distribution : {"ggx", "beckmann"}
        Used with ``alpha``.

    Returns
    -------
    ndarray, radians
    """
    if (sharpness is None) == (alpha is None):
        raise OptionError("give exactly one of sharpness or alpha")
    if sharpness is not None:
        n = np.asarray(sharpness, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            return 0.5 * np.arccos(2.0 ** (-1.0 / n))
    c = _slope_constant(distribution)
    return np.arctan(np.asarray(alpha, dtype=float) * np.sqrt(c))
