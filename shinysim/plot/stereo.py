"""Figures 13, 14, 16, 17 and 18 of the paper: structured-highlight stereo, from the exact theory.

Each function returns ``(figure, caption)``: a :class:`matplotlib.figure.Figure`
built directly (no pyplot) and a caption saying what was computed. All data
come from :mod:`shinysim.theory.stereo` (analytic, no renderer); matplotlib
is imported inside the functions. Lines that carry the theory's numbers have
a ``gid`` (``"eq20"``, ``"locus_p"``, ...) so they can be found again.
"""

from __future__ import annotations

import numpy as np

from ..conventions import gradient_from_normal, normalize
from ..theory import stereo as st
from .caption import new_figure

__all__ = [
    "fig13_stereo_geometry",
    "fig14_z_theta",
    "fig16_candidates",
    "fig17_matching",
    "fig18_gradient_loci",
    "fig16_scene",
]

_C1, _C2 = "tab:blue", "tab:orange"


def fig13_stereo_geometry(*, R=10.0, alpha=np.deg2rad(35.0), x=2.0, z=1.0, a_values=None):
    """Fig 13: one source, an element off the origin and the parabolas of Eq 18 along its camera ray.

    Parameters
    ----------
    R : float, mm
        Source distance (small, so that source and element share the plot).
    alpha : float, radians
        Source angle from the vertical.
    x, z : float, mm
        The element the vertical orthographic camera sees at ``x``.
    a_values : array_like, mm, optional
        Parameters of the other family members drawn; default five values
        spanning heights along the ray.

    Returns
    -------
    fig, caption
    """
    fig, ax = new_figure((6.4, 6.0), 1, 1)
    xs, zs = R * np.sin(alpha), R * np.cos(alpha)
    a0 = float(st.parabola_parameter(x, z, xs, zs))
    if a_values is None:
        a_values = a0 * np.array([0.25, 0.5, 2.0, 4.0])
    a_all = np.sort(np.append(np.asarray(a_values, float), a0))
    t = np.linspace(0, np.pi, 181)
    ax.plot(R * np.cos(t), R * np.sin(t), color="0.75", lw=0.8, ls="--", label="source semicircle, radius R")
    xx = np.linspace(-R, R, 400)
    zmin = zs - a_all.max() - 1.0
    for k, a in enumerate(a_all):
        zp, _ = st.parabola_family(xx, xs, zs, a)
        zp = np.where(zp > R + 1, np.nan, zp)
        true = np.isclose(a, a0)
        ax.plot(xx, zp, color="k" if true else "0.55", lw=1.4 if true else 0.8, gid="eq18_true" if true else None,
                label="Eq 18 parabolas, focus at S" if k == 0 else None)
        ze, pe = st.parabola_family(x, xs, zs, a)
        th = -np.arctan(pe)
        tang = 0.9 * np.array([np.cos(th), -np.sin(th)])
        ax.plot([x - tang[0], x + tang[0]], [ze - tang[1], ze + tang[1]], color="tab:red" if true else "tab:purple",
                lw=3.0 if true else 2.0, solid_capstyle="butt", gid="element_true" if true else None)
        nrm = 1.2 * np.array([np.sin(th), np.cos(th)])
        ax.annotate("", (x + nrm[0], ze + nrm[1]), (x, ze),
                    arrowprops={"arrowstyle": "->", "color": "tab:red" if true else "tab:purple", "lw": 1.0})
        # the ray from the source that this element reflects straight up
        ax.plot([xs, x, x], [zs, ze, ze + 2.0], color="gold" if true else "none", lw=1.0, zorder=1)
    ax.axvline(x, color=_C1, lw=1.0, ls=":", label=f"camera ray x = {x:g} mm (camera above, orthographic)")
    ax.plot([xs], [zs], "*", color="gold", ms=16, mec="k", label="source S at R (sin α, cos α)")
    ax.plot([0, xs], [0, zs], color="0.6", lw=0.7)
    ax.annotate(f"α = {np.rad2deg(alpha):.0f}°", (0.5 * xs, 0.5 * zs), xytext=(-40, 4), textcoords="offset points",
                fontsize=8)
    ax.plot([], [], color="tab:purple", lw=2, label="other (z, Θ) on the same ray, Eq 20")
    ax.plot([], [], color="tab:red", lw=3, label=f"element at ({x:g}, {z:g}) mm")
    ax.set(xlim=(-R - 0.5, R + 0.5), ylim=(max(zmin, -R), R + 1.0), aspect="equal", xlabel="x [mm]",
           ylabel="z [mm]")
    ax.legend(fontsize=7, loc="lower left")
    ax.set_title("Fig. 13: one camera leaves (z, Θ) ambiguous along its ray", fontsize=10)
    cap = ("Fig. 13 (analytic). A point source S (star) at R = "
           f"{R:g} mm, α = {np.rad2deg(alpha):.0f}° from the vertical, and a vertical orthographic camera that sees "
           f"a highlight at x = {x:g} mm. Every member of the family of parabolas with focus at S (Eq 18, "
           f"(x − xs)² = 4a(z − zs + a), a = {', '.join(f'{a:.2f}' for a in a_all)} mm) reflects S straight up; "
           "where each crosses the camera ray it gives an element (short bar, slope p of Eq 19, arrow = normal) that "
           "makes the same highlight. The element at "
           f"({x:g}, {z:g}) mm (red, its light path in gold) is one of a continuum: a second camera is needed.")
    return fig, cap


def fig14_z_theta(*, x_hat=0.2, alphas_deg=(-60.0, -30.0, 0.0, 30.0, 60.0), printed=True, limit=2.0):
    """Fig 14: normalised height ``z/R`` against orientation ``Theta`` (Eq 20) for several sources.

    Parameters
    ----------
    x_hat : float
        Observed position ``x / R``.
    alphas_deg : sequence of float, degrees
        Source angles.
    printed : bool
        Also draw Eq 20 with the printed Eq 22 (``x_hat = R cos alpha`` at
        ``R = 1``, so that the printed ``x_hat`` is ``cos alpha``), dashed.
    limit : float
        Vertical range ``+-limit``; the curves run to infinity at their poles.

    Returns
    -------
    fig, caption
    """
    fig, ax = new_figure((7.0, 5.0), 1, 1)
    theta = np.deg2rad(np.linspace(-89.5, 89.5, 1433))
    colours = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink"]
    for k, a_deg in enumerate(alphas_deg):
        a = np.deg2rad(a_deg)
        col = colours[k % len(colours)]
        z = st.z_of_theta(theta, x_hat, a, 1.0)
        phys = np.sign(np.sin(2 * theta)) == np.sign(np.sin(a) - x_hat)
        zc = np.where(phys & (np.abs(z) < 3 * limit), z, np.nan)
        ax.plot(np.rad2deg(theta), zc, color=col, lw=1.5, label=f"α = {a_deg:+.0f}°", gid=f"eq20_{k}")
        if printed:
            zp = st.z_of_theta(theta, x_hat, a, 1.0, convention="printed")
            zp = np.where(np.abs(zp) < 3 * limit, zp, np.nan)
            ax.plot(np.rad2deg(theta), zp, color=col, lw=0.8, ls="--", gid=f"eq20_printed_{k}")
    if printed:
        ax.plot([], [], color="0.3", lw=0.8, ls="--", label="printed Eq 22 (x̂ = R cos α)")
    ax.axhline(0, color="0.8", lw=0.6)
    ax.set(ylim=(-limit, limit), xlim=(-90, 90), xlabel="element orientation Θ from the vertical [deg]",
           ylabel="height ẑ = z / R")
    ax.legend(fontsize=8, ncol=2, loc="upper left")
    ax.set_title(f"Fig. 14: Eq 20, heights consistent with one highlight at x̂ = x/R = {x_hat:g}", fontsize=10)
    cap = ("Fig. 14 (analytic). Every (z, Θ) on a curve reflects the source at angle α into a vertical "
           f"orthographic camera at the observed x̂ = x/R = {x_hat:g}: Eq 20, ẑ = cos α + (x̂ − sin α)/tan 2Θ, with "
           "Eq 22 corrected to x̂ = x/R (solid; only the branch whose light comes from the source's side is drawn). "
           "Dashed: Eq 20 with Eq 22 as printed, x̂ = R cos α (here R = 1), which does not depend on the observed x. "
           "Each curve runs to ±∞ where 2Θ points along the camera axis and passes through ẑ = cos α at "
           "Θ = ±45°, where the light arrives horizontally.")
    return fig, cap


def fig16_scene(*, beta=np.deg2rad(20.0), R=43.18, circles=((-3.0, 0.0, 2.5), (3.5, 1.0, 2.0)),
                theta_deg=(-24.0, -4.0, 12.0), tol_mm=1e-6):
    """The synthetic planar scene of Figs 16-17: two mirror circles, placed sources, both cameras' highlights.

    Sources are placed (:func:`shinysim.theory.stereo.place_source`) so that
    each camera sees the elements at ``theta_deg`` on each circle; every
    source then lights the whole scene and each camera records all its
    visible highlights (:func:`shinysim.theory.stereo.planar_scene`).

    Returns
    -------
    dict
        ``"h1"``, ``"h2"`` (:class:`~shinysim.theory.stereo.PlanarHighlights`
        of ``C'`` and ``C''``), ``"match"`` (the
        :class:`~shinysim.theory.stereo.MatchResult` of every pair), ``"true"``
        (pairs made by one surface point), ``"alphas"``, and the parameters.
    """
    t = np.deg2rad(np.asarray(theta_deg, float))
    # the sources that light the chosen elements, for each circle and camera
    alphas = np.unique(np.concatenate([st.place_source(xc + r * np.sin(t), zc + r * np.cos(t), t, beta, R,
                                                       camera=cam) for xc, zc, r in circles for cam in ("'", '"')]))
    h1, h2 = (st.planar_scene(circles, alphas, R, beta, camera=c) for c in ("'", '"'))
    m = st.reflectance_match(h1.x_cam[:, None], h1.alpha[:, None], h2.x_cam[None, :], h2.alpha[None, :], beta, R,
                             tol_mm=tol_mm)
    true = np.hypot(h1.x[:, None] - h2.x[None, :], h1.z[:, None] - h2.z[None, :]) < 1e-9
    return {"h1": h1, "h2": h2, "match": m, "true": true, "alphas": alphas, "beta": beta, "R": R,
            "circles": np.asarray(circles, float), "tol_mm": tol_mm}


def fig16_candidates(scene=None):
    """Fig 16: highlight rays of both cameras, every ray intersection (candidate), the true matches.

    Parameters
    ----------
    scene : dict, optional
        From :func:`fig16_scene` (default: its defaults).

    Returns
    -------
    fig, caption
    """
    s = fig16_scene() if scene is None else scene
    h1, h2, m, true, beta = s["h1"], s["h2"], s["match"], s["true"], s["beta"]
    fig, ax = new_figure((7.6, 6.4), 1, 1)
    circles = s["circles"]
    lo_x = (circles[:, 0] - circles[:, 2]).min() - 2.5
    hi_x = (circles[:, 0] + circles[:, 2]).max() + 2.5
    lo_z = (circles[:, 1] - circles[:, 2]).min() - 1.0
    hi_z = (circles[:, 1] + circles[:, 2]).max() + 4.0
    t = np.linspace(0, 2 * np.pi, 241)
    for k, (xc, zc, r) in enumerate(circles):
        ax.fill(xc + r * np.sin(t), zc + r * np.cos(t), color="0.88", ec="0.4", lw=1.0,
                label="mirror circles" if k == 0 else None)
    L = 30.0
    for h, cam, col, name in ((h1, "'", _C1, "C′ (+β)"), (h2, '"', _C2, "C″ (−β)")):
        ez = st.camera_axes(beta, camera=cam)[2][[0, 2]]
        for i in range(len(h.x)):
            ax.plot([h.x[i] - L * ez[0], h.x[i] + L * ez[0]], [h.z[i] - L * ez[1], h.z[i] + L * ez[1]], color=col,
                    lw=0.6, alpha=0.7, label=f"highlight rays of {name}" if i == 0 else None)
        ax.plot(h.x, h.z, ".", color=col, ms=5)
    cand = np.isfinite(m.x) & (m.x > lo_x) & (m.x < hi_x) & (m.z > lo_z) & (m.z < hi_z)
    ax.plot(m.x[cand & ~m.accepted], m.z[cand & ~m.accepted], "o", ms=3.0, color="0.35", gid="candidates",
            label=f"candidates, Eqs 26-27 ({int((~m.accepted).sum())} rejected by Eqs 32-34)")
    ax.plot(m.x[true], m.z[true], "o", ms=10, mfc="none", mec="tab:red", mew=1.6, gid="true",
            label=f"true matches ({int(true.sum())})")
    ax.plot(m.x[m.accepted], m.z[m.accepted], "x", ms=7, color="k", mew=1.4, gid="accepted",
            label=f"accepted, |E′|, |E″| < {s['tol_mm']:g} mm ({int(m.accepted.sum())})")
    ax.set(xlim=(lo_x, hi_x), ylim=(lo_z, hi_z), aspect="equal", xlabel="x [mm]", ylabel="z [mm]")
    ax.legend(fontsize=7, loc="upper left", framealpha=0.9)
    ax.set_title(f"Fig. 16: candidate points of two cameras at ±{np.rad2deg(beta):.0f}°", fontsize=10)
    n1, n2 = len(h1.x), len(h2.x)
    cap = (f"Fig. 16 (analytic). Two orthographic cameras at ±{np.rad2deg(beta):.0f}° from the vertical look at "
           f"two mirror circles; {len(s['alphas'])} point sources on a semicircle of radius {s['R']:g} mm, placed so "
           "that each camera sees chosen elements, light the scene one at a time. Exact highlights (mirror law "
           f"solved by bisection, occlusion by the other circle checked): {n1} in C′ (blue rays), {n2} in C″ "
           f"(orange rays). Each pair of rays meets at a candidate point (Eqs 26-27, corrected z*): {n1 * n2} "
           f"candidates, {int(cand.sum())} inside the plot (grey). Red rings: the {int(true.sum())} pairs made by "
           "one surface point; black crosses: pairs accepted by reflectance matching (Eq 32 solved by "
           f"Newton-Raphson, |E′|, |E″| < {s['tol_mm']:g} mm). Accepted and true coincide.")
    return fig, cap


def fig17_matching(scene=None, *, false_pair=None):
    """Fig 17: ``E'(Theta) = z'(Theta - beta) - z'*`` and ``E''(Theta)`` for a true and a false pair.

    Parameters
    ----------
    scene : dict, optional
        From :func:`fig16_scene`.
    false_pair : (int, int), optional
        Indices (into ``h1``, ``h2``) of the false pair shown; default the
        false pair with a root of Eq 32 whose candidate lies nearest the
        first true match.

    Returns
    -------
    fig, caption
    """
    s = fig16_scene() if scene is None else scene
    h1, h2, m, true, beta, R = s["h1"], s["h2"], s["match"], s["true"], s["beta"], s["R"]
    ti, tj = np.argwhere(true)[len(np.argwhere(true)) // 2]
    if false_pair is None:
        ok = m.converged & ~true
        d = np.where(ok, np.hypot(m.x - m.x[ti, tj], m.z - m.z[ti, tj]), np.inf)
        false_pair = np.unravel_index(np.argmin(d), d.shape)
    fi, fj = false_pair
    fig, axes = new_figure((11.0, 4.6), 1, 2)
    for ax, (i, j), kind in ((axes[0], (ti, tj), "true pair"), (axes[1], (fi, fj), "false pair")):
        args = (h1.x_cam[i], h1.alpha[i], h2.x_cam[j], h2.alpha[j], beta, R)
        th_star = m.theta[i, j]
        span = np.deg2rad(25.0)
        centre = th_star if np.isfinite(th_star) else 0.5 * (m.theta_p[i, j] + m.theta_pp[i, j])
        theta = np.linspace(centre - span, centre + span, 801)
        e1, e2 = st.match_function(theta, *args)
        scale = 3.0 * max(1.0, abs(m.e1[i, j]) if np.isfinite(m.e1[i, j]) else 1.0)
        e1, e2 = (np.where(np.abs(e) < 4 * scale, e, np.nan) for e in (e1, e2))
        ax.plot(np.rad2deg(theta), e1, color=_C1, lw=1.5, label="E′(Θ) = z′(Θ − β) − z′*  (Eq 33)", gid="e1")
        ax.plot(np.rad2deg(theta), e2, color=_C2, lw=1.5, label="E″(Θ) = z″(Θ + β) − z″*  (Eq 34)", gid="e2")
        ax.axhline(0, color="0.5", lw=0.7)
        if np.isfinite(th_star):
            ax.plot([np.rad2deg(th_star)], [m.e1[i, j]], "ko", ms=6, mfc="none", mew=1.4, gid="root",
                    label=f"Θ* = {np.rad2deg(th_star):.3f}°, E′ = E″ = {m.e1[i, j]:.3g} mm")
        ax.set(ylim=(-scale, scale), xlabel="orientation Θ [deg]", ylabel="height error [mm]")
        verdict = "accepted" if m.accepted[i, j] else "rejected"
        ax.set_title(f"{kind}: candidate ({m.x[i, j]:.2f}, {m.z[i, j]:.2f}) mm, {verdict}", fontsize=9)
        ax.legend(fontsize=7, loc="lower right")
    fig.suptitle(f"Fig. 17: reflectance matching, β = {np.rad2deg(beta):.0f}°", fontsize=10)
    cap = ("Fig. 17 (analytic). The matching test of two candidates from the scene of Fig. 16: the height errors "
           "E′(Θ) = z′(Θ − β) − z′* and E″(Θ) = z″(Θ + β) − z″* (Eqs 24-25 in each camera's frame, minus the "
           "candidate's height from Eqs 29, 31) against the orientation Θ. Eq 32 asks where the curves cross "
           "(Newton-Raphson, circle). Left: a true pair, the curves cross on the axis, E′ = E″ = "
           f"{abs(m.e1[ti, tj]):.1e} mm (round-off), Θ* = {np.rad2deg(m.theta[ti, tj]):.4f}° against the element's "
           f"{np.rad2deg(h1.theta[ti]):.4f}°. Right: a false pair, the curves cross "
           f"{abs(m.e1[fi, fj]):.3g} mm off the axis and the candidate is rejected.")
    return fig, cap


def fig18_gradient_loci(*, beta=np.deg2rad(30.0), R=43.18, normal=(-0.25, 0.35, 1.0), point=(0.8, 0.6, -0.4),
                        printed=True, extent=1.2):
    """Fig 18: the two cameras' gradient loci of a true 3-D pair and their crossing ``(p*, q*)``.

    Parameters
    ----------
    beta : float, radians
        Cameras at ``+-beta`` about the ``y`` axis, orthographic.
    R : float, mm
        Sources are placed on the sphere of radius ``R``
        (:func:`shinysim.theory.stereo.place_source_3d`) so that each camera
        sees the element.
    normal, point : (3,) array_like
        The element's normal and position (mm).
    printed : bool
        Also draw the printed loci (slope ``y/x``), dashed.
    extent : float
        Half-width of the gradient-space window around the true gradient.

    Returns
    -------
    fig, caption
    """
    P = np.asarray(point, float)
    n = normalize(np.asarray(normal, float))
    # the element relative to each camera's source, in that camera's axes
    rel1, rel2 = ((P - st.place_source_3d(P, n, beta, R, camera=c)) @ st.camera_axes(beta, camera=c).T
                  for c in ("'", '"'))
    pt, qt = (float(v) for v in gradient_from_normal(n))
    ps, qs = st.gradient_loci(rel1[0], rel1[1], rel2[0], rel2[1], beta)
    fig, ax = new_figure((6.6, 6.0), 1, 1)
    tb = np.tan(beta)
    p = np.linspace(min(pt, -tb) - extent, max(pt, tb) + extent, 401)
    for rel, cam, col, name, gid in ((rel1, "'", _C1, "C′", "locus_p"), (rel2, '"', _C2, "C″", "locus_pp")):
        q = st.gradient_locus(p, rel[0], rel[1], beta, camera=cam)
        ax.plot(p, q, color=col, lw=1.6, gid=gid, label=f"{name} locus (Eq {44 if cam == chr(39) else 45}, corrected)")
        if printed:
            qp = st.gradient_locus(p, rel[0], rel[1], beta, camera=cam, convention="printed")
            ax.plot(p, qp, color=col, lw=1.0, ls="--", gid=gid + "_printed", label=f"{name} locus as printed")
    ax.plot([-tb, tb], [0, 0], "s", color="0.3", ms=6, label="camera-axis gradients (∓tan β, 0)")
    ax.plot([pt], [qt], "o", ms=11, mfc="none", mec="tab:red", mew=1.8, label=f"true gradient ({pt:.3f}, {qt:.3f})")
    ax.plot([ps], [qs], "k+", ms=12, mew=1.8, gid="crossing", label=f"(p*, q*) = ({float(ps):.3f}, {float(qs):.3f})")
    txt = ""
    if printed:
        pp, qp = st.gradient_loci(rel1[0], rel1[1], rel2[0], rel2[1], beta, convention="printed")
        ax.plot([pp], [qp], "kx", ms=8, mew=1.2, label=f"printed crossing ({float(pp):.3f}, {float(qp):.3f})")
        txt = (f" Dashed: the printed Eqs 44-45 (slope y′/x′, a translation of gradient space); they cross at the "
               f"right p* but at q* = q / cos β = {float(qp):.3f}.")
    ax.axhline(0, color="0.85", lw=0.6)
    ax.axvline(0, color="0.85", lw=0.6)
    ax.set(xlim=(p[0], p[-1]), ylim=(qt - extent - 0.3, qt + extent + 0.3), aspect="equal",
           xlabel="p = dz/dx", ylabel="q = dz/dy")
    ax.legend(fontsize=7, loc="lower left", framealpha=0.9)
    ax.set_title(f"Fig. 18: gradient-space loci of a stereo pair, β = {np.rad2deg(beta):.0f}°", fontsize=10)
    cap = ("Fig. 18 (analytic). An element at "
           f"({', '.join(f'{v:g}' for v in P)}) mm with gradient ({pt:.3f}, {qt:.3f}) seen by two orthographic "
           f"cameras at ±{np.rad2deg(beta):.0f}° about the y axis, each with a source placed on the sphere of radius "
           f"{R:g} mm. Each highlight allows a line of gradients (Eq 39 in its camera's frame, q′/p′ = y′/x′): in the "
           "world gradient space it is the line through the camera-axis gradient (∓tan β, 0) with slope "
           "(y′/x′) cos β (corrected Eqs 44-45, solid). The lines cross at the element's gradient "
           f"(p*, q*) = ({float(ps):.3f}, {float(qs):.3f}).{txt}")
    return fig, cap
