r"""Structured-highlight stereo, exactly: paper Section V, Eqs 18-45.

The planar relations (one camera's locus of elements, the ray intersection,
the mirror test of Eqs 18-35), the three-dimensional ones (closest approach,
depths, gradient loci and the Eq 43 test of Eqs 36-45), and exact synthetic
highlights from mirror geometry for tests and figures. ``convention="correct"``
(default) evaluates the geometric form, ``convention="printed"`` the
equations as printed (``docs/paper-errata.md``). Pure numpy. The frames
(camera ``C'`` is the rig's ``"plus"`` camera) and the chain of equations:
``docs/theory.md``, section 5.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._shared import check_choice, check_number
from ..conventions import normal_from_gradient, normalize
from ..errors import OptionError
from .mirror import mirror_sphere_highlight

__all__ = [
    "CAMERAS",
    "CONVENTIONS",
    "MatchResult",
    "PlanarHighlights",
    "camera_axes",
    "camera_coordinates",
    "circle_highlights",
    "closest_approach",
    "curve_highlights",
    "delta_z",
    "gradient_height",
    "gradient_locus",
    "gradient_loci",
    "gradient_to_camera",
    "match_function",
    "observe_3d",
    "parabola_family",
    "parabola_parameter",
    "paraboloid_family",
    "place_source",
    "place_source_3d",
    "planar_mirror_residual",
    "planar_observation",
    "planar_scene",
    "ray_depths",
    "ray_intersection",
    "ray_midpoint",
    "reflectance_match",
    "z_camera",
    "z_of_p",
    "z_of_theta",
]

#: Valid ``convention`` strings.
CONVENTIONS = ("correct", "printed")

#: Valid ``camera`` strings: ``"'"`` (alias ``"plus"``) is ``C'`` at ``+beta``,
#: ``'"'`` (alias ``"minus"``) is ``C''`` at ``-beta``.
CAMERAS = ("'", '"', "plus", "minus")


# -- argument checks -------------------------------------------------------------------------------

def _beta(beta):
    """``beta`` checked: one number in (0, pi/2) radians."""
    return check_number("beta", beta, lo=0.0, hi=0.5 * np.pi, lo_open=True, hi_open=True)


def _positive(name, value):
    return check_number(name, value, lo=0.0, lo_open=True)


def _sign(camera):
    """+1 for ``C'``, -1 for ``C''``."""
    check_choice("camera", camera, CAMERAS)
    return 1.0 if camera in ("'", "plus") else -1.0


def _arrays(_vectors=False, **named):
    """The named values as float arrays broadcast together (with ``_vectors``, (..., 3) vectors), or
    OptionError naming the argument at fault."""
    arrs = {}
    for k, v in named.items():
        a = np.asarray(v, dtype=float)
        if _vectors and (a.ndim == 0 or a.shape[-1] != 3):
            raise OptionError(f"{k} must hold 3-vectors on its last axis, got shape {a.shape}")
        arrs[k] = a
    try:
        return np.broadcast_arrays(*arrs.values())
    except ValueError:
        shapes = ", ".join(f"{k} {a.shape}" for k, a in arrs.items())
        raise OptionError(f"shapes do not broadcast together: {shapes}") from None


def _vectors(**named):
    return _arrays(True, **named)


def _wrap(a):
    """Angle wrapped to (-pi, pi]."""
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def _bisect(f, lo, hi, f_lo, *, to_round_off=False):
    """Midpoint of ``[lo, hi]`` after 200 halvings that keep the sign change of ``f`` (``f_lo = f(lo)``)
    inside; with ``to_round_off``, fewer once every bracket is down to round-off."""
    for _ in range(200):
        m = 0.5 * (lo + hi)
        fm = f(m)
        same = np.sign(fm) == np.sign(f_lo)
        lo, f_lo = np.where(same, m, lo), np.where(same, fm, f_lo)
        hi = np.where(same, hi, m)
        if to_round_off and np.all(hi - lo <= 2.0 * np.finfo(float).eps * np.maximum(1.0, np.abs(lo))):
            break
    return 0.5 * (lo + hi)


# -- one camera, planar: Eqs 18-25 -----------------------------------------------------------------

def parabola_family(x, xs, zs, a):
    """The parabola of Eq 18 with focus at the source, and its slope, Eq 19.

    ``(x - xs)^2 = 4 a (z - zs + a)``: every element on it reflects light
    from the focus ``(xs, zs)`` parallel to the axis, straight up into a
    vertical orthographic camera. The elements seen at one image position
    ``x`` lie on different members (different ``a``) at different heights.

    Parameters
    ----------
    x : array_like, mm
        Horizontal position.
    xs, zs : array_like, mm
        Source (focus) position.
    a : array_like, mm
        Parameter of the family (> 0 for a parabola opening upwards, the
        members that reflect into a camera above): the vertex is at
        ``(xs, zs - a)``.

    Returns
    -------
    z : ndarray, mm
        Height of the parabola at ``x``.
    p : ndarray
        Its slope ``dz/dx = (x - xs) / 2a`` (Eq 19).
    """
    x, xs, zs, a = _arrays(x=x, xs=xs, zs=zs, a=a)
    with np.errstate(divide="ignore", invalid="ignore"):
        return zs - a + (x - xs) ** 2 / (4.0 * a), (x - xs) / (2.0 * a)


def parabola_parameter(x, z, xs, zs):
    """The ``a`` of the Eq 18 parabola with focus ``(xs, zs)`` through ``(x, z)``.

    ``a = (rho - (z - zs)) / 2`` with ``rho`` the distance from the focus:
    the positive root of Eq 18 for ``a``.
    """
    x, z, xs, zs = _arrays(x=x, z=z, xs=xs, zs=zs)
    return 0.5 * (np.hypot(x - xs, z - zs) - (z - zs))



def z_of_theta(theta, x, alpha, R, *, convention="correct"):
    """Height of an element seen at ``x`` as a function of its orientation, Eqs 20-22.

    ``z_hat = cos(alpha) + (x_hat - sin(alpha)) / tan(2 Theta)`` with
    ``z_hat = z / R`` (Eq 21). Vertical orthographic camera, source at
    ``R (sin alpha, cos alpha)``.

    Parameters
    ----------
    theta : array_like, radians
        Orientation of the element: normal ``(sin Theta, cos Theta)``.
    x : array_like, mm
        Observed (image) position of the highlight.
    alpha : array_like, radians
        Source angle from the vertical, positive towards +x.
    R : float, mm
        Source distance from the origin.
    convention : {"correct", "printed"}
        ``"correct"``: ``x_hat = x / R`` (ERRATA); the element at
        ``(x, z(Theta))`` with orientation ``Theta`` reflects the source
        exactly into the camera. ``"printed"``: Eq 22 as printed,
        ``x_hat = R cos(alpha)`` (no dependence on ``x``).

    Returns
    -------
    z : ndarray, mm
        Infinite at ``Theta = 0`` unless the source is straight above ``x``;
        ``R cos(alpha)`` at ``Theta = +-45`` degrees (light arriving
        horizontally).
    """
    check_choice("convention", convention, CONVENTIONS)
    R = _positive("R", R)
    theta, x, alpha = _arrays(theta=theta, x=x, alpha=alpha)
    xh = x / R if convention == "correct" else R * np.cos(alpha)
    with np.errstate(divide="ignore", invalid="ignore"):
        return R * (np.cos(alpha) + (xh - np.sin(alpha)) / np.tan(2.0 * theta))


def z_of_p(p, x, alpha, R, *, convention="correct"):
    """Height of an element seen at ``x`` as a function of its slope ``p``, Eq 23.

    Correct (ERRATA): ``z_hat = cos(alpha) + 1/2 (x_hat - sin(alpha)) (p - 1/p)``
    with ``p = dz/dx = -tan(Theta)`` as in Eq 19 and ``x_hat = x / R``: the
    same curve as :func:`z_of_theta`, since ``1 / tan(2 Theta) = (p - 1/p) / 2``.

    Parameters
    ----------
    p : array_like
        Slope ``dz/dx`` of the element (nonzero).
    x, alpha, R
        As in :func:`z_of_theta` (mm, radians, mm).
    convention : {"correct", "printed"}
        ``"printed"``: Eq 23 as printed, with the minus sign and Eq 22's
        ``x_hat = R cos(alpha)``. The printed sign alone mirrors the curve,
        ``p -> -p`` (it is right for ``p = -dz/dx``).

    Returns
    -------
    z : ndarray, mm
    """
    check_choice("convention", convention, CONVENTIONS)
    R = _positive("R", R)
    p, x, alpha = _arrays(p=p, x=x, alpha=alpha)
    with np.errstate(divide="ignore", invalid="ignore"):
        if convention == "correct":
            return R * (np.cos(alpha) + 0.5 * (x / R - np.sin(alpha)) * (p - 1.0 / p))
        return R * (np.cos(alpha) - 0.5 * (R * np.cos(alpha) - np.sin(alpha)) * (p - 1.0 / p))


def planar_mirror_residual(x, z, theta, alpha, R, *, view_angle=0.0):
    """How far an element misses the mirror condition, radians (signed).

    The element at ``(x, z)`` with normal ``(sin Theta, cos Theta)`` reflects
    the ray from the source ``R (sin alpha, cos alpha)``; the result is the
    angle from the reflected ray to the direction towards the camera,
    ``(sin view_angle, cos view_angle)``. Zero means the highlight is seen.

    Parameters
    ----------
    x, z : array_like, mm
    theta, alpha : array_like, radians
    R : float, mm
    view_angle : array_like, radians
        Direction of the (orthographic) camera from the vertical: 0 for the
        single camera of Eqs 18-23, ``+-beta`` for the stereo pair.

    Returns
    -------
    ndarray, radians, in (-pi, pi]
    """
    x, z, theta, alpha, view_angle = _arrays(x=x, z=z, theta=theta, alpha=alpha, view_angle=view_angle)
    to_source = np.arctan2(R * np.sin(alpha) - x, R * np.cos(alpha) - z)
    reflected = 2.0 * theta - to_source
    return _wrap(view_angle - reflected)


def z_camera(theta, x_cam, alpha, beta, R, *, camera="'", convention="correct"):
    """Height of an element in one stereo camera's frame, Eqs 24-25.

    ``z' = R [cos a' + (x'/R - sin a') / tan 2(Theta - beta)]`` with
    ``a' = alpha - beta`` (camera ``C'``), and ``beta -> -beta`` for
    ``C''`` (Eq 25). ``x_cam`` and the result are the element's coordinates
    in the camera's frame (Eqs 28-31).

    Parameters
    ----------
    theta : array_like, radians
        Orientation of the element in the world frame (from the vertical).
    x_cam : array_like, mm
        Observed highlight position ``x'`` (or ``x''``) in the camera frame.
    alpha : array_like, radians
        World angle of the source that made the highlight.
    beta : float, radians, in (0, pi/2)
        Half the angle between the cameras.
    R : float, mm
    camera : {"'", '"', "plus", "minus"}
    convention : {"correct", "printed"}
        ``"printed"``: Eqs 24-25 as printed, without the normalisation by
        ``R`` (``z' = cos a' + (x' - sin a') / tan 2(Theta - beta)`` in the
        units of ``x_cam``): right only for ``R = 1``.

    Returns
    -------
    ndarray, mm
    """
    check_choice("convention", convention, CONVENTIONS)
    s = _sign(camera)
    beta = _beta(beta)
    R = _positive("R", R)
    theta, x_cam, alpha = _arrays(theta=theta, x_cam=x_cam, alpha=alpha)
    a_c = alpha - s * beta
    Rn = R if convention == "correct" else 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        return Rn * np.cos(a_c) + (x_cam - Rn * np.sin(a_c)) / np.tan(2.0 * (theta - s * beta))


# -- two cameras, planar: Eqs 26-34 ----------------------------------------------------------------

def planar_observation(x, z, beta, *, camera="'"):
    """Where an orthographic stereo camera sees the point ``(x, z)``: ``(x_cam, z_cam)``, mm.

    ``x' = x cos beta - z sin beta``, ``z' = x sin beta + z cos beta``
    (Eq 29) for ``C'``; ``beta -> -beta`` for ``C''`` (Eq 31).
    """
    s = _sign(camera)
    beta = _beta(beta)
    x, z = _arrays(x=x, z=z)
    c, sn = np.cos(beta), s * np.sin(beta)
    return x * c - z * sn, x * sn + z * c


def ray_intersection(x0p, x0pp, beta, *, convention="correct"):
    """Where the rays of two highlights meet, Eqs 26-27.

    Parameters
    ----------
    x0p, x0pp : array_like, mm
        Highlight positions ``x0'`` in ``C'`` and ``x0''`` in ``C''`` (image
        coordinates of :func:`planar_observation`).
    beta : float, radians, in (0, pi/2)
    convention : {"correct", "printed"}
        ``"correct"`` (ERRATA): ``x* = (x0' + x0'') / (2 cos beta)``,
        ``z* = (x0'' - x0') / (2 sin beta)``. ``"printed"``: Eq 27 with
        ``(x0' - x0'')``, which puts the candidate at ``-z*`` (Eq 26 read as
        ``/(2 cos beta)``, which is right).

    Returns
    -------
    x_star, z_star : ndarray, mm
    """
    check_choice("convention", convention, CONVENTIONS)
    beta = _beta(beta)
    x0p, x0pp = _arrays(x0p=x0p, x0pp=x0pp)
    x = (x0p + x0pp) / (2.0 * np.cos(beta))
    dz = (x0pp - x0p) if convention == "correct" else (x0p - x0pp)
    return x, dz / (2.0 * np.sin(beta))


def camera_coordinates(x0p, x0pp, x_star, z_star, beta):
    """A candidate point in both camera frames, Eqs 28-31.

    Parameters
    ----------
    x0p, x0pp : array_like, mm
        The observed highlight positions (Eqs 28, 30: ``x'* = x0'``,
        ``x''* = x0''``).
    x_star, z_star : array_like, mm
        The candidate point (:func:`ray_intersection`).
    beta : float, radians

    Returns
    -------
    xp, zp, xpp, zpp : ndarray, mm
        ``x'*``, ``z'* = x* sin beta + z* cos beta`` (Eq 29), ``x''*`` and
        ``z''* = -x* sin beta + z* cos beta`` (Eq 31).
    """
    beta = _beta(beta)
    x0p, x0pp, x_star, z_star = _arrays(x0p=x0p, x0pp=x0pp, x_star=x_star, z_star=z_star)
    c, s = np.cos(beta), np.sin(beta)
    return x0p, x_star * s + z_star * c, x0pp, -x_star * s + z_star * c


def _match_terms(x_p, alpha_p, x_pp, alpha_pp, beta, R, convention):
    """Candidate and the coefficients of ``E'(T) = B' + A' cot 2(T - beta)`` and ``E''``."""
    xs, zs = ray_intersection(x_p, x_pp, beta, convention=convention)
    _, zp, _, zpp = camera_coordinates(x_p, x_pp, xs, zs, beta)
    Rn = R if convention == "correct" else 1.0
    a1, a2 = alpha_p - beta, alpha_pp + beta
    A1, B1 = x_p - Rn * np.sin(a1), Rn * np.cos(a1) - zp
    A2, B2 = x_pp - Rn * np.sin(a2), Rn * np.cos(a2) - zpp
    return xs, zs, zp, zpp, A1, B1, A2, B2


def match_function(theta, x_p, alpha_p, x_pp, alpha_pp, beta, R, *, convention="correct"):
    """Both sides of Eq 32 at ``theta``: ``E'(Theta)`` and ``E''(Theta)``, mm.

    ``E'(Theta) = z'(Theta - beta) - z'*`` and ``E''(Theta) = z''(Theta + beta)
    - z''*`` (Eqs 33-34 at any ``Theta``), with ``z'``, ``z''`` from
    :func:`z_camera` and ``z'*``, ``z''*`` the candidate's camera
    coordinates (Eqs 26-31). These are the two curves of Fig 17; a true
    match has them cross on the axis.

    Parameters
    ----------
    theta : array_like, radians
    x_p, alpha_p : array_like, mm and radians
        Highlight ``x0'`` in ``C'`` and the world angle of its source.
    x_pp, alpha_pp : array_like, mm and radians
        Highlight ``x0''`` in ``C''`` and its source.
    beta : float, radians; R : float, mm
    convention : {"correct", "printed"}
        Printed Eq 27 and Eqs 24-25 as printed.

    Returns
    -------
    e1, e2 : ndarray, mm
    """
    check_choice("convention", convention, CONVENTIONS)
    beta = _beta(beta)
    R = _positive("R", R)
    theta, x_p, alpha_p, x_pp, alpha_pp = _arrays(theta=theta, x_p=x_p, alpha_p=alpha_p, x_pp=x_pp,
                                                   alpha_pp=alpha_pp)
    _, _, _, _, A1, B1, A2, B2 = _match_terms(x_p, alpha_p, x_pp, alpha_pp, beta, R, convention)
    with np.errstate(divide="ignore", invalid="ignore"):
        return B1 + A1 / np.tan(2.0 * (theta - beta)), B2 + A2 / np.tan(2.0 * (theta + beta))


@dataclass(frozen=True)
class MatchResult:
    """Outcome of :func:`reflectance_match`, one entry per candidate pair.

    Attributes
    ----------
    theta : ndarray, radians
        ``Theta*``, the root of Eq 32 (NaN where none was found).
    x, z : ndarray, mm
        The candidate point ``(x*, z*)`` (Eqs 26-27).
    zp, zpp : ndarray, mm
        ``z'*`` and ``z''*`` (Eqs 29, 31).
    e1, e2 : ndarray, mm
        ``E'(Theta*)``, ``E''(Theta*)`` (Eqs 33-34).
    accepted : ndarray of bool
        ``|E'| < tol_mm`` and ``|E''| < tol_mm`` at a converged root.
    iterations : ndarray of int
        Newton-Raphson iterations taken (the bracketing fallback adds none).
    converged : ndarray of bool
        A root of Eq 32 was found, by Newton-Raphson or by the fallback.
    theta_p, theta_pp : ndarray, radians
        The orientations that make ``E' = 0`` alone and ``E'' = 0`` alone
        (the bisectors of source and camera at the candidate); a true
        match has them equal.
    """

    theta: np.ndarray
    x: np.ndarray
    z: np.ndarray
    zp: np.ndarray
    zpp: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    accepted: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    theta_p: np.ndarray
    theta_pp: np.ndarray


def _interval(A, beta):
    """Orientations for which a camera at ``beta`` sees the source on the right side.

    The direction to the source makes ``2 (Theta - beta)`` with the camera
    axis, on the side where the source is: ``(0, pi/2)`` of ``Theta - beta``
    if ``A = x' - R sin a' < 0`` (source towards +x'), ``(-pi/2, 0)``
    otherwise. ``E'`` runs monotonically between -inf and +inf across it
    (increasing for ``A < 0``, decreasing for ``A > 0``).
    """
    lo = np.where(A < 0, beta, beta - 0.5 * np.pi)
    return lo, lo + 0.5 * np.pi


def reflectance_match(x_p, alpha_p, x_pp, alpha_pp, beta, R, *, tol_mm, convention="correct", max_iter=60,
                      n_bracket=256):
    """Reflectance matching of candidate pairs, Eqs 26-34.

    For each pair of highlights (``x0'`` in ``C'`` lit by the source at
    ``alpha_p``, ``x0''`` in ``C''`` lit by ``alpha_pp``) the rays are
    intersected (Eqs 26-27), the candidate put into both camera frames
    (Eqs 28-31), Eq 32 ``E'(Theta) = E''(Theta)`` solved for ``Theta*`` and
    the pair accepted when ``|E'(Theta*)|`` and ``|E''(Theta*)|`` (Eqs 33-34)
    are below ``tol_mm``.

    Parameters
    ----------
    x_p, alpha_p, x_pp, alpha_pp : array_like
        Highlight positions (mm, camera frames) and world source angles
        (radians), broadcast together: pass ``x_p[:, None]`` and
        ``x_pp[None, :]`` to test every pair.
    beta : float, radians, in (0, pi/2)
    R : float, mm
    tol_mm : float, mm, > 0
        Acceptance threshold on ``|E'|`` and ``|E''|``.
    convention : {"correct", "printed"}
        ``"printed"``: Eq 27 and Eqs 24-25 as printed.
    max_iter : int
        Newton-Raphson iterations before the fallback.
    n_bracket : int
        Samples of the fallback's search for a sign change.

    Returns
    -------
    MatchResult

    Notes
    -----
    Only orientations that see the source from the camera's side of the
    element are physical: ``Theta`` lies in an open interval of width
    ``pi/2`` for each camera (:func:`_interval`), whose ends are poles of
    ``E'`` (or ``E''``); Eq 32 is solved on their intersection, where it has
    no pole. ``E'`` and ``E''`` are each monotonic across their intervals,
    between -inf and +inf: where they run in opposite directions Eq 32 has
    exactly one root; where they run the same way ``E' - E''`` tends to the
    same infinity at both ends of the common interval and has an even
    number of roots (Fig 17's two curves cross twice or not at all).
    Newton-Raphson on ``E' - E''`` with the analytic derivative starts from
    the mean of the two single-camera solutions ``theta_p``, ``theta_pp``
    (closed form), which for a true pair is the root itself; a step that
    would leave the interval is halved towards its end. Pairs that have not
    converged after ``max_iter`` steps are bracketed on ``n_bracket``
    samples and bisected to round-off, starting from the sign change nearest
    the start; with no sign change the pair is ``converged = False``,
    ``theta = NaN`` and rejected.
    """
    check_choice("convention", convention, CONVENTIONS)
    beta = _beta(beta)
    R = _positive("R", R)
    tol_mm = _positive("tol_mm", tol_mm)
    max_iter = check_number("max_iter", max_iter, lo=0, integer=True)
    n_bracket = check_number("n_bracket", n_bracket, lo=4, integer=True)
    x_p, alpha_p, x_pp, alpha_pp = _arrays(x_p=x_p, alpha_p=alpha_p, x_pp=x_pp, alpha_pp=alpha_pp)
    xs, zs, zp, zpp, A1, B1, A2, B2 = _match_terms(x_p, alpha_p, x_pp, alpha_pp, beta, R, convention)
    lo1, hi1 = _interval(A1, beta)
    lo2, hi2 = _interval(A2, -beta)
    lo, hi = np.maximum(lo1, lo2), np.minimum(hi1, hi2)
    th1 = beta + 0.5 * np.arctan2(-A1, B1)
    th2 = -beta + 0.5 * np.arctan2(-A2, B2)
    # a source on its own camera's ray (A = 0) allows only the orientation along that ray, Theta = +-beta,
    # the end of the interval, where E' - E'' has its pole: solved directly
    Rn = R if convention == "correct" else 1.0
    scale = 1e-12 * (Rn + np.abs(x_p) + np.abs(x_pp))
    deg1, deg2 = np.abs(A1) <= scale, np.abs(A2) <= scale
    feasible = (hi > lo) | deg1 | deg2

    def f_df(t):
        u1, u2 = 2.0 * (t - beta), 2.0 * (t + beta)
        s1, s2 = np.sin(u1), np.sin(u2)
        f = (B1 + A1 * np.cos(u1) / s1) - (B2 + A2 * np.cos(u2) / s2)
        df = -2.0 * A1 / s1**2 + 2.0 * A2 / s2**2
        return f, df

    with np.errstate(divide="ignore", invalid="ignore"):
        t = 0.5 * (th1 + th2)
        t = np.where((t > lo) & (t < hi), t, 0.5 * (lo + hi))
        its = np.zeros(t.shape, dtype=int)
        done = ~feasible | ~np.isfinite(t) | deg1 | deg2
        conv = np.zeros(t.shape, dtype=bool)
        f, df = f_df(t)
        conv |= feasible & (f == 0)
        done |= conv
        for _ in range(max_iter):
            if done.all():
                break
            step = f / df
            new = t - step
            new = np.where(new <= lo, 0.5 * (t + lo), new)
            new = np.where(new >= hi, 0.5 * (t + hi), new)
            ok = np.isfinite(new)
            active = ~done & ok
            small = np.abs(new - t) <= 4.0 * np.finfo(float).eps * np.maximum(1.0, np.abs(t))
            t = np.where(active, new, t)
            its = its + active
            f, df = f_df(t)
            newly = active & (small | (f == 0))
            conv |= newly
            done |= newly | ~ok
        # bracketing fallback for feasible pairs Newton-Raphson left unconverged
        todo = feasible & ~conv & ~deg1 & ~deg2
        if todo.any():
            idx = np.nonzero(todo)
            lo_t, hi_t, t0 = lo[idx], hi[idx], 0.5 * (th1[idx] + th2[idx])
            frac = (np.arange(n_bracket) + 0.5) / n_bracket
            grid = lo_t[:, None] + (hi_t - lo_t)[:, None] * frac[None, :]
            a1, b1, a2, b2 = (np.broadcast_to(v, todo.shape)[idx][:, None] for v in (A1, B1, A2, B2))

            def gap(tt):  # E' - E'' at tt, a row per pair
                return (b1 + a1 / np.tan(2.0 * (tt - beta))) - (b2 + a2 / np.tan(2.0 * (tt + beta)))

            g = gap(grid)
            change = np.sign(g[:, :-1]) * np.sign(g[:, 1:]) < 0
            has = change.any(axis=1)
            mid = 0.5 * (grid[:, :-1] + grid[:, 1:])
            dist = np.where(change, np.abs(mid - t0[:, None]), np.inf)
            k = np.argmin(dist, axis=1)
            rows = np.arange(len(k))
            a, b = grid[rows, k], grid[rows, np.minimum(k + 1, n_bracket - 1)]
            root = _bisect(lambda m: gap(m[:, None])[:, 0], a, b, g[rows, k], to_round_off=True)
            t[idx] = np.where(has, root, np.nan)
            conv[idx] = has
        t = np.where(deg1, th1, np.where(deg2, th2, t))
        conv = np.where(deg1 | deg2, True, conv)
        its = np.where(deg1 | deg2, 0, its)
        theta = np.where(conv, t, np.nan)
        e1 = np.where(deg1, 0.0, B1 + A1 / np.tan(2.0 * (theta - beta)))
        e2 = np.where(deg2, 0.0, B2 + A2 / np.tan(2.0 * (theta + beta)))
        if (deg1 & deg2).any():  # both rays through their sources: consistent only if both orientations agree
            both = deg1 & deg2
            e1 = np.where(both, 0.5 * Rn * np.abs(th1 - th2), e1)
            e2 = np.where(both, 0.5 * Rn * np.abs(th1 - th2), e2)
    accepted = conv & (np.abs(e1) < tol_mm) & (np.abs(e2) < tol_mm)
    return MatchResult(theta=theta, x=xs, z=zs, zp=zp, zpp=zpp, e1=e1, e2=e2, accepted=accepted,
                       iterations=its, converged=conv, theta_p=np.where(feasible, th1, np.nan),
                       theta_pp=np.where(feasible, th2, np.nan))


# -- three dimensions: Eqs 36-45 -------------------------------------------------------------------

def camera_axes(beta, *, camera="'"):
    """Rows ``e_x, e_y, e_z`` of a stereo camera turned by ``+-beta`` about ``y``.

    ``e_x = (cos g, 0, -sin g)``, ``e_y = (0, 1, 0)``, ``e_z = (sin g, 0,
    cos g)`` with ``g = +beta`` for ``C'`` and ``-beta`` for ``C''``:
    right-handed, ``e_z`` towards the camera, ``e_x`` the image ``+col``
    direction of :func:`shinysim.rig.stereo_pair`'s cameras.

    Returns
    -------
    (3, 3) ndarray
        A world vector ``w`` has camera coordinates ``axes @ w``.
    """
    g = _sign(camera) * _beta(beta)
    return np.array([[np.cos(g), 0.0, -np.sin(g)], [0.0, 1.0, 0.0], [np.sin(g), 0.0, np.cos(g)]])


def paraboloid_family(x, y, a):
    """The paraboloid of Eqs 36-37 and its gradient.

    ``z' = r'^2 / 4a - a``, ``r' = sqrt(x'^2 + y'^2)``, in a frame with its
    origin at the source (the focus) and ``z'`` along the camera axis,
    towards the camera: every element on it reflects the source parallel to
    the axis.

    Parameters
    ----------
    x, y : array_like, mm
        Element coordinates relative to the source, camera axes.
    a : array_like, mm, > 0

    Returns
    -------
    z, p, q : ndarray
        Height (mm) and gradient ``(x/2a, y/2a)``.
    """
    x, y, a = _arrays(x=x, y=y, a=a)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (x * x + y * y) / (4.0 * a) - a, x / (2.0 * a), y / (2.0 * a)


def gradient_height(x, y, p, q):
    """Height of an element relative to the source from its gradient, Eq 38.

    ``z' = x'p'/2 + y'q'/2 - r' / (2 sqrt(p'^2 + q'^2))``, all in one
    camera's axes with the origin at the source; valid on the locus
    ``q'/p' = y'/x'`` (Eq 39) with ``p'`` of the sign of ``x'`` (the member
    ``a = r' / (2 sqrt(p'^2 + q'^2)) > 0`` of Eq 36).

    Parameters
    ----------
    x, y : array_like, mm
    p, q : array_like
        Gradient in the camera's frame (:func:`gradient_to_camera`).

    Returns
    -------
    ndarray, mm
    """
    x, y, p, q = _arrays(x=x, y=y, p=p, q=q)
    with np.errstate(divide="ignore", invalid="ignore"):
        return 0.5 * (x * p + y * q) - np.hypot(x, y) / (2.0 * np.hypot(p, q))


def gradient_to_camera(p, q, beta, *, camera="'", convention="correct"):
    """A world gradient ``(p, q)`` written in a stereo camera's frame.

    Parameters
    ----------
    p, q : array_like
    beta : float, radians
    camera : {"'", '"', "plus", "minus"}
    convention : {"correct", "printed"}
        ``"correct"``: the normal ``(-p, -q, 1)`` rotated into the camera's
        axes. ``"printed"``: the translation that Eqs 44-45 imply,
        ``(p + tan g, q)`` with ``g = +-beta`` (exact at ``beta = 0`` only).

    Returns
    -------
    p_cam, q_cam : ndarray
    """
    check_choice("convention", convention, CONVENTIONS)
    axes = camera_axes(beta, camera=camera)
    p, q = _arrays(p=p, q=q)
    if convention == "printed":
        return p + np.tan(_sign(camera) * beta), q.copy()
    n = normal_from_gradient(p, q) @ axes.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return -n[..., 0] / n[..., 2], -n[..., 1] / n[..., 2]


def gradient_locus(p, x, y, beta, *, camera="'", convention="correct"):
    """The line of world gradients one camera's highlight allows, Eq 44 (or 45): ``q(p)``.

    Parameters
    ----------
    p : array_like
        World ``p`` values at which to evaluate the line.
    x, y : array_like, mm
        The element relative to the camera's source, in the camera's axes
        (``x'``, ``y'`` of Eq 39).
    beta : float, radians
    camera : {"'", '"', "plus", "minus"}
    convention : {"correct", "printed"}
        ``"correct"`` (ERRATA): ``q = (y/x) cos(g) (p + tan g)``;
        ``"printed"``: ``q = (y/x)(p + tan g)``; ``g = +beta`` for ``C'``,
        ``-beta`` for ``C''``. Both pass through the gradient ``(-tan g, 0)``
        of the camera axis.

    Returns
    -------
    q : ndarray
    """
    check_choice("convention", convention, CONVENTIONS)
    g = _sign(camera) * _beta(beta)
    p, x, y = _arrays(p=p, x=x, y=y)
    with np.errstate(divide="ignore", invalid="ignore"):
        k = y / x * (np.cos(g) if convention == "correct" else 1.0)
    return k * (p + np.tan(g))


def gradient_loci(x1, y1, x2, y2, beta, *, convention="correct"):
    """Where the two gradient loci cross: ``(p*, q*)``, Eqs 44-45.

    Parameters
    ----------
    x1, y1 : array_like, mm
        The candidate element relative to the source of the ``C'``
        highlight, in ``C'``'s axes.
    x2, y2 : array_like, mm
        The same relative to the source of the ``C''`` highlight, in
        ``C''``'s axes.
    beta : float, radians, in (0, pi/2)
    convention : {"correct", "printed"}
        ``"correct"``: each locus passes through its camera-axis gradient
        ``(-+tan beta, 0)`` with slope ``(y/x) cos beta``. ``"printed"``:
        slope ``y/x``, as if the change of frame translated gradient space.

    Returns
    -------
    p, q : ndarray
        World gradient; NaN where the loci are parallel (both ``y = 0``: an
        element in the plane of the cameras, where only Eq 32 decides).
    """
    check_choice("convention", convention, CONVENTIONS)
    beta = _beta(beta)
    x1, y1, x2, y2 = _arrays(x1=x1, y1=y1, x2=x2, y2=y2)
    c = np.cos(beta) if convention == "correct" else 1.0
    t = np.tan(beta)
    with np.errstate(divide="ignore", invalid="ignore"):
        m1, m2 = y1 / x1 * c, y2 / x2 * c
        # q = m1 (p + t) = m2 (p - t)
        p = -t * (m1 + m2) / (m1 - m2)
        q = m1 * (p + t)
        bad = ~np.isfinite(p) | ~np.isfinite(q) | (m1 == m2)
    return np.where(bad, np.nan, p), np.where(bad, np.nan, q)


def closest_approach(v1, u1, v2, u2, *, convention="correct"):
    """Distance between two viewing rays, Eq 40.

    Parameters
    ----------
    v1, u1 : (..., 3) array_like
        A point of the first ray (the observed point in the image plane, mm)
        and its direction (any length).
    v2, u2 : (..., 3) array_like
        The same for the second ray.
    convention : {"correct", "printed"}
        ``"correct"`` (ERRATA): ``D = |(v' - v'') . (u' x u'')| / |u' x u''|``,
        and ``|(v' - v'') x u'| / |u'|`` for parallel rays. ``"printed"``:
        Eq 40 as printed, with no absolute value (its non-bold denominator
        read as ``|u' x u''|``): a signed distance, negative for half of all
        skew pairs, so ``D < D0`` accepts them; infinite or NaN for parallel
        rays.

    Returns
    -------
    D : ndarray, mm
    """
    check_choice("convention", convention, CONVENTIONS)
    v1, u1, v2, u2 = _vectors(v1=v1, u1=u1, v2=v2, u2=u2)
    w = v1 - v2
    cr = np.cross(u1, u2)
    n = np.linalg.norm(cr, axis=-1)
    num = np.sum(w * cr, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        if convention == "printed":
            return num / n
        u1n = normalize(u1)
        par = np.linalg.norm(np.cross(w, u1n), axis=-1)
        return np.where(n > 1e-12 * np.linalg.norm(u1, axis=-1) * np.linalg.norm(u2, axis=-1),
                        np.abs(num) / n, par)


def ray_depths(v1, u1, v2, u2, *, convention="correct"):
    """Depths along two rays of their points of closest approach, Eqs 41-42.

    The closest points are ``v' + z' u'`` and ``v'' + z'' u''`` with unit
    ``u``; for an orthographic camera whose ``v`` lies in the image plane
    through the origin and whose ``u`` points towards the camera, ``z'`` is
    the height in the camera frame.

    Parameters
    ----------
    v1, u1, v2, u2 : (..., 3) array_like
        Ray points (mm) and directions (normalised here).
    convention : {"correct", "printed"}
        ``"correct"`` (ERRATA), with ``c = u' . u''``:
        ``z' = [(v'' - v') . u' - c (v'' - v') . u''] / (1 - c^2)`` and
        ``z'' = [(v' - v'') . u'' - c (v' - v'') . u'] / (1 - c^2)``.
        ``"printed"``: ``z' = (v'' - v') . u'``, ``z'' = (v' - v'') . u''``,
        exact only for perpendicular rays (``c = 0``, ``beta = 45`` degrees).

    Returns
    -------
    z1, z2 : ndarray, mm
        NaN for parallel rays (correct form).
    """
    check_choice("convention", convention, CONVENTIONS)
    v1, u1, v2, u2 = _vectors(v1=v1, u1=u1, v2=v2, u2=u2)
    u1, u2 = normalize(u1), normalize(u2)
    w = v2 - v1
    a1, a2 = np.sum(w * u1, axis=-1), np.sum(w * u2, axis=-1)
    if convention == "printed":
        return a1, -a2
    c = np.sum(u1 * u2, axis=-1)
    den = 1.0 - c * c
    with np.errstate(divide="ignore", invalid="ignore"):
        ok = den > 0
        den = np.where(ok, den, np.nan)
        return (a1 - c * a2) / den, (c * a1 - a2) / den


def ray_midpoint(v1, u1, v2, u2, *, convention="correct"):
    """The candidate point: halfway between the rays' closest points (Eqs 41-42), mm, (..., 3)."""
    z1, z2 = ray_depths(v1, u1, v2, u2, convention=convention)
    v1, u1, v2, u2 = _vectors(v1=v1, u1=u1, v2=v2, u2=u2)
    return 0.5 * (v1 + z1[..., None] * normalize(u1) + v2 + z2[..., None] * normalize(u2))


def delta_z(p, q, point, source1, source2, beta, *, convention="correct"):
    """The reflectance-match test of a 3-D candidate, Eq 43.

    ``Delta z = [z'(p*, q*) - z'] - [z''(p*, q*) - z'']``: for each camera,
    the height relative to its source that Eq 38 gives for the gradient
    ``(p*, q*)`` minus the height of the candidate point from the ray
    intersection, both in that camera's axes.

    Parameters
    ----------
    p, q : array_like
        World gradient ``(p*, q*)`` (:func:`gradient_loci`).
    point : (..., 3) array_like, mm
        The candidate point (:func:`ray_midpoint`).
    source1, source2 : (..., 3) array_like, mm
        The sources of the ``C'`` and ``C''`` highlights.
    beta : float, radians
    convention : {"correct", "printed"}
        How ``(p*, q*)`` is taken into each camera's frame
        (:func:`gradient_to_camera`).

    Returns
    -------
    ndarray, mm
        Zero (to round-off) for a true pair with the correct ``(p*, q*)``.
    """
    check_choice("convention", convention, CONVENTIONS)
    point, source1, source2 = _vectors(point=point, source1=source1, source2=source2)
    p, q = _arrays(p=p, q=q)
    out = []
    for cam, src in (("'", source1), ('"', source2)):
        rel = (point - src) @ camera_axes(beta, camera=cam).T
        pc, qc = gradient_to_camera(p, q, beta, camera=cam, convention=convention)
        out.append(gradient_height(rel[..., 0], rel[..., 1], pc, qc) - rel[..., 2])
    return out[0] - out[1]


# -- exact synthetic highlights --------------------------------------------------------------------

def observe_3d(point, beta, *, camera="'", distance=None):
    """The viewing ray of a point in one stereo camera: ``(v, u, depth)``.

    Parameters
    ----------
    point : (..., 3) array_like, mm
    beta : float, radians
    camera : {"'", '"', "plus", "minus"}
    distance : float, mm, optional
        Pinhole camera with its centre at ``distance * e_z`` (looking at the
        origin). Without it the camera is orthographic.

    Returns
    -------
    v : (..., 3) ndarray, mm
        Orthographic: the point's image in the plane through the origin
        normal to the axis; pinhole: the centre of projection.
    u : (..., 3) ndarray
        Unit ray direction, with ``point = v + depth * u``: the axis
        ``e_z`` (towards the camera) for orthographic, from the centre
        into the scene for pinhole.
    depth : (...) ndarray, mm
    """
    (point,) = _vectors(point=point)
    ez = camera_axes(beta, camera=camera)[2]
    if distance is None:
        depth = point @ ez
        return point - depth[..., None] * ez, np.broadcast_to(ez, point.shape).copy(), depth
    distance = _positive("distance", distance)
    c = np.broadcast_to(distance * ez, point.shape).copy()
    d = point - c
    depth = np.linalg.norm(d, axis=-1)
    return c, d / depth[..., None], depth


def place_source_3d(point, normal, beta, R, *, camera="'", distance=None):
    """The source on the sphere of radius ``R`` about the origin that a camera sees reflected at ``point``.

    The ray towards the camera reflected about ``normal`` leaves ``point``
    towards the source; the source is where it meets the sphere.

    Parameters
    ----------
    point, normal : (..., 3) array_like
        Surface element (mm) and its normal (normalised here).
    beta : float, radians
    R : float, mm
        Source sphere radius (the point must lie inside it).
    camera, distance
        As in :func:`observe_3d`.

    Returns
    -------
    (..., 3) ndarray, mm
        NaN where the reflected ray points away from the element's front
        (the camera sees the back) or misses the sphere.
    """
    point, normal = _vectors(point=point, normal=normal)
    R = _positive("R", R)
    n = normalize(normal)
    ez = camera_axes(_beta(beta), camera=camera)[2]
    # unit direction from the point towards the camera (orthographic, or the pinhole at distance)
    d = (np.broadcast_to(ez, point.shape).astype(float) if distance is None
         else normalize(distance * ez - point))
    nd = np.sum(n * d, axis=-1, keepdims=True)
    r = 2.0 * nd * n - d
    pr = np.sum(point * r, axis=-1, keepdims=True)
    disc = pr * pr - np.sum(point * point, axis=-1, keepdims=True) + R * R
    with np.errstate(invalid="ignore"):
        s = -pr + np.sqrt(disc)
    out = point + s * r
    bad = (nd <= 0) | ~(s > 0)
    return np.where(bad, np.nan, out)


def place_source(x, z, theta, beta, R, *, camera="'"):
    """World angle of the source on the semicircle that ``C'`` (or ``C''``) sees at an element.

    Parameters
    ----------
    x, z : array_like, mm
        The element, inside the source circle.
    theta : array_like, radians
        Its orientation (normal ``(sin Theta, cos Theta)``).
    beta : float, radians
    R : float, mm
    camera : {"'", '"', "plus", "minus"}

    Returns
    -------
    alpha : ndarray, radians
        Signed from the vertical; the source is at ``R (sin alpha, cos
        alpha)``. NaN if the camera sees the element's back.
    """
    x, z, theta = _arrays(x=x, z=z, theta=theta)
    pt = np.stack([x, np.zeros_like(x), z], axis=-1)
    n = np.stack([np.sin(theta), np.zeros_like(x), np.cos(theta)], axis=-1)
    s = place_source_3d(pt, n, beta, R, camera=camera)
    return np.arctan2(s[..., 0], s[..., 2])


@dataclass(frozen=True)
class PlanarHighlights:
    """Exact highlights seen by one planar camera, one entry per highlight.

    Attributes
    ----------
    x_cam : ndarray, mm
        Image position in the camera frame (:func:`planar_observation`).
    alpha : ndarray, radians
        World angle of the source that made it.
    source : ndarray of int
        Index of that source.
    x, z, theta : ndarray, mm, mm, radians
        The reflecting element and its orientation.
    part : ndarray of int
        Which curve (or circle) it lies on.
    """

    x_cam: np.ndarray
    alpha: np.ndarray
    source: np.ndarray
    x: np.ndarray
    z: np.ndarray
    theta: np.ndarray
    part: np.ndarray


def circle_highlights(alpha, R, xc, zc, r, beta, *, camera="'"):
    """Exact highlight of each source on a mirror circle, seen by one orthographic stereo camera.

    Solves the mirror condition on the circle by bisection
    (:func:`shinysim.theory.mirror.mirror_sphere_highlight` in the plane
    ``y = 0``): exact to float64 round-off.

    Parameters
    ----------
    alpha : array_like, radians
        Source angles, sources at ``R (sin alpha, cos alpha)``.
    R : float, mm
    xc, zc, r : float, mm
        Circle centre and radius.
    beta : float, radians
    camera : {"'", '"', "plus", "minus"}

    Returns
    -------
    x, z, theta, x_cam : ndarray
        Element (mm), its orientation (radians) and its image position (mm).
    """
    R = _positive("R", R)
    r = _positive("r", r)
    (alpha,) = _arrays(alpha=alpha)
    src = np.stack([R * np.sin(alpha), np.zeros_like(alpha), R * np.cos(alpha)], axis=-1)
    view = camera_axes(beta, camera=camera)[2]
    pt, n = mirror_sphere_highlight(src, center=(float(xc), 0.0, float(zc)), radius=r, view_direction=view)
    x, z = pt[..., 0], pt[..., 2]
    theta = np.arctan2(n[..., 0], n[..., 2])
    return x, z, theta, planar_observation(x, z, beta, camera=camera)[0]


def curve_highlights(curve, t, alpha, R, beta, *, camera="'"):
    """Exact highlights of sources on a smooth planar mirror curve, one camera.

    Parameters
    ----------
    curve : callable
        ``curve(t) -> (x, z, theta)``: points (mm) and outward normal angles
        (radians from the vertical) of the curve at parameters ``t``
        (array in, arrays of the same shape out).
    t : (n,) array_like
        Increasing samples of the parameter, fine enough that two highlights
        of one source never fall between neighbours.
    alpha : (m,) array_like, radians
        Source angles.
    R : float, mm
    beta : float, radians
    camera : {"'", '"', "plus", "minus"}

    Returns
    -------
    t_root, alpha_idx : ndarray
        Curve parameter of each highlight and the index of its source.
    x, z, theta, x_cam : ndarray
        As in :func:`circle_highlights`.

    Notes
    -----
    The residual is :func:`planar_mirror_residual`; its sign changes
    between samples are refined by bisection to round-off and kept when the
    residual there is within 1e-9 rad of zero (a change across the wrap at
    +-pi is not a root) and the element faces the camera and the source.
    """
    R = _positive("R", R)
    beta = _beta(beta)
    s = _sign(camera)
    t = np.asarray(t, dtype=float)
    (alpha,) = _arrays(alpha=np.atleast_1d(alpha))
    if t.ndim != 1 or t.size < 2:
        raise OptionError(f"t must be a 1-D array of at least 2 samples, got shape {t.shape}")

    def resid(tt, a):
        x, z, th = curve(tt)
        return planar_mirror_residual(x, z, th, a, R, view_angle=s * beta)

    out_t, out_a = [], []
    for i, a in enumerate(alpha):
        h = resid(t, a)
        ch = np.nonzero(np.sign(h[:-1]) * np.sign(h[1:]) <= 0)[0]
        if ch.size == 0:
            continue
        root = _bisect(lambda m: resid(m, a), t[ch], t[ch + 1], h[ch])
        keep = np.abs(resid(root, a)) < 1e-9
        out_t.append(root[keep])
        out_a.append(np.full(int(keep.sum()), i))
    tr = np.concatenate(out_t) if out_t else np.zeros(0)
    ai = np.concatenate(out_a) if out_a else np.zeros(0, dtype=int)
    x, z, th = (np.asarray(v, dtype=float) for v in curve(tr))
    a = alpha[ai]
    # the element must face the camera and the source
    face_cam = np.cos(th - s * beta) > 0
    face_src = np.sin(th) * (R * np.sin(a) - x) + np.cos(th) * (R * np.cos(a) - z) > 0
    k = face_cam & face_src
    xc = planar_observation(x[k], z[k], beta, camera=camera)[0]
    return tr[k], ai[k], x[k], z[k], th[k], xc


def _segment_hits_circle(p0, d, length, centre, radius):
    """Whether the segments ``p0 + s d`` (0 < s < length, unit d) pass through the circle's inside."""
    w = p0 - centre
    b = np.sum(w * d, axis=-1)
    c = np.sum(w * w, axis=-1) - radius * radius
    disc = b * b - c
    with np.errstate(invalid="ignore"):
        sq = np.sqrt(disc)
    s1, s2 = -b - sq, -b + sq
    tol = 1e-9 * max(1.0, radius)
    return (disc > 0) & (s2 > tol) & (s1 < length - tol) & (s2 - s1 > tol)


def planar_scene(circles, alpha, R, beta, *, camera="'"):
    """Every highlight one orthographic stereo camera sees on a set of mirror circles.

    For each source and circle the exact highlight (:func:`circle_highlights`)
    is kept if neither the ray to the camera nor the ray to the source
    passes through another circle.

    Parameters
    ----------
    circles : sequence of (xc, zc, r)
        Circle centres and radii, mm.
    alpha : (m,) array_like, radians
        Source angles on the semicircle of radius ``R``.
    R : float, mm
    beta : float, radians
    camera : {"'", '"', "plus", "minus"}

    Returns
    -------
    PlanarHighlights
    """
    circles = np.asarray(circles, dtype=float)
    if circles.ndim != 2 or circles.shape[1] != 3:
        raise OptionError(f"circles must be a sequence of (xc, zc, r), got shape {circles.shape}")
    beta = _beta(beta)
    R = _positive("R", R)
    alpha = np.atleast_1d(np.asarray(alpha, dtype=float))
    view = camera_axes(beta, camera=camera)[2][[0, 2]]
    rows = []
    for k, (xc, zc, r) in enumerate(circles):
        x, z, th, xcam = circle_highlights(alpha, R, xc, zc, r, beta, camera=camera)
        p = np.stack([x, z], axis=-1)
        src = np.stack([R * np.sin(alpha), R * np.cos(alpha)], axis=-1)
        to_s = src - p
        ls = np.linalg.norm(to_s, axis=-1)
        ok = np.ones(x.shape, dtype=bool)
        for j, (xo, zo, ro) in enumerate(circles):
            if j == k:
                continue
            ctr = np.array([xo, zo])
            ok &= ~_segment_hits_circle(p, np.broadcast_to(view, p.shape), np.inf, ctr, ro)
            ok &= ~_segment_hits_circle(p, to_s / ls[:, None], ls, ctr, ro)
        idx = np.nonzero(ok)[0]
        rows.append((xcam[idx], alpha[idx], idx, x[idx], z[idx], th[idx], np.full(idx.size, k)))
    cols = [np.concatenate([r_[i] for r_ in rows]) for i in range(7)]
    return PlanarHighlights(x_cam=cols[0], alpha=cols[1], source=cols[2].astype(int), x=cols[3], z=cols[4],
                            theta=cols[5], part=cols[6].astype(int))

