"""Full-field heights from sparse normals (shinysim.recon.integrate): exact cases first.

Measured numbers the assertions rest on are quoted in the comments (fixed
seeds, so they are reproducible); every tolerance says why it is what it is.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import griddata

from shinysim.conventions import normal_from_gradient
from shinysim.errors import OptionError
from shinysim.recon.integrate import (
    INTEGRATE_METHODS,
    RISE_RULES,
    IntegrateParams,
    compare_integrators,
    edge_rise,
    grid_gradients,
    integrate_frankot_chellappa,
    integrate_poisson,
    integrate_robust,
    integrate,
    integrate_triangulated,
)

# round-off of a least-squares solve over a few hundred points with heights of order 1 mm:
# the normal equations' condition number is about 1e4 here, times 1e-16 => 1e-12; 1e-10 leaves room
EXACT_MM = 1e-10
R_SPHERE = 0.8  # mm, the SHINY calibration sphere


def exact_normals(f, xy, h=1e-6):
    """Normals of the height function ``f`` by central differences (error ~h**2 f''' ~1e-12)."""
    x, y = xy[:, 0], xy[:, 1]
    p = (f(x + h, y) - f(x - h, y)) / (2 * h)
    q = (f(x, y + h) - f(x, y - h)) / (2 * h)
    return normal_from_gradient(p, q)


def analytic(grad, xy):
    p, q = grad(xy[:, 0], xy[:, 1])
    return normal_from_gradient(p, q)


def sphere_cap(n_points, seed=0, max_deg=70.0, radius=R_SPHERE):
    """Points on a sphere cap, uniform in normal direction (as a dome of sources lights it)."""
    rng = np.random.default_rng(seed)
    ct = rng.uniform(np.cos(np.radians(max_deg)), 1.0, n_points)
    ph = rng.uniform(0, 2 * np.pi, n_points)
    st = np.sqrt(1 - ct**2)
    n = np.column_stack([st * np.cos(ph), st * np.sin(ph), ct])
    return radius * n[:, :2], n, radius * ct


def rms(e):
    e = np.asarray(e, float)
    return float(np.sqrt(np.mean(e**2)))


# ----------------------------------------------------------------------------------------------
# exact cases


@pytest.mark.parametrize("rule", RISE_RULES)
def test_plane_is_exact_with_both_rules(rule):
    rng = np.random.default_rng(1)
    xy = rng.uniform(-1, 1, (300, 2))
    zt = 0.3 * xy[:, 0] - 0.2 * xy[:, 1] + 1.0
    n = analytic(lambda x, y: (0.3 + 0 * x, -0.2 + 0 * y), xy)
    s = integrate_triangulated(xy, n, anchors=[xy[0, 0], xy[0, 1], zt[0]], rule=rule)
    assert np.max(np.abs(s.z - zt)) < EXACT_MM
    assert s.residual_rms_mm < EXACT_MM
    assert len(s.components) == 1 and s.components[0].anchored_by == "point"


def test_quadratic_is_exact_with_the_trapezoid_rule_only():
    # the trapezoid rule on an edge is exact when the gradient is linear along the edge, i.e. for
    # every quadratic surface (here a tilted, sheared paraboloid with a saddle term)
    rng = np.random.default_rng(1)
    xy = rng.uniform(-1, 1, (300, 2))

    def f(x, y):
        return 0.5 * x**2 + 0.3 * x * y - 0.2 * y**2 + 0.1 * x

    n = analytic(lambda x, y: (x + 0.3 * y + 0.1, 0.3 * x - 0.4 * y), xy)
    zt = f(*xy.T)
    anchor = [xy[0, 0], xy[0, 1], zt[0]]
    trap = integrate_triangulated(xy, n, anchors=anchor, rule="trapezoid")
    assert np.max(np.abs(trap.z - zt)) < EXACT_MM
    # the arc rule is only second-order here (measured max 3.8e-3 mm over slopes up to 1.5)
    arc = integrate_triangulated(xy, n, anchors=anchor, rule="arc")
    assert 1e-4 < np.max(np.abs(arc.z - zt)) < 1e-2
    # the iterative solver reaches the same answer (lsqr stops at ~1e-11 here: its own tolerance)
    lsq = integrate_triangulated(xy, n, anchors=anchor, rule="trapezoid", solver="lsqr")
    assert np.max(np.abs(lsq.z - zt)) < 1e-8


def test_sphere_cap_arc_exact_trapezoid_second_order():
    xy, n, zt = sphere_cap(200)
    mean = float(zt.mean())
    arc = integrate_triangulated(xy, n, anchors=mean)
    trap = integrate_triangulated(xy, n, anchors=mean, rule="trapezoid")
    assert arc.params.rule == "arc"  # the default
    # the circular arc is exact on a sphere along any edge: round-off only (measured 1e-15 mm)
    assert rms(arc.z - zt) < EXACT_MM
    # the trapezoid rule: measured 6.6 um RMS = 0.82 % of the radius with 200 points (spec: <= 1 %)
    e_trap = rms(trap.z - zt)
    assert e_trap <= 0.01 * R_SPHERE
    assert e_trap > 1e3 * EXACT_MM
    assert not arc.floating and arc.components[0].anchored_by == "mean"
    assert arc.dropped["long_edges"] == 0  # the cap's outline is convex: nothing to drop

    # the trapezoid error falls as spacing**2 ~ 1 / N (measured 6.6, 1.4, 0.40 um for 200, 800, 3200:
    # exponent -1.01); the band [-1.25, -0.8] allows for other random point sets
    errs = [e_trap]
    for k in (800, 3200):
        xy, n, zt = sphere_cap(k)
        errs.append(rms(integrate_triangulated(xy, n, anchors=float(zt.mean()), rule="trapezoid").z - zt))
    slope = np.polyfit(np.log([200, 800, 3200]), np.log(errs), 1)[0]
    assert -1.25 < slope < -0.8


def test_edge_rise_rules_agree_on_planes_and_differ_on_curves():
    d = np.array([[0.1, 0.05]])
    n = normal_from_gradient([0.4], [-0.3])
    for rule in RISE_RULES:
        assert edge_rise(n, n, d, rule)[0] == pytest.approx(0.4 * 0.1 - 0.3 * 0.05, abs=1e-15)
    # along x on a unit circle from 0 to 60 degrees: the arc gives the exact rise
    a0, a1 = 0.0, np.radians(60)
    n0 = [[np.sin(a0), 0, np.cos(a0)]]
    n1 = [[np.sin(a1), 0, np.cos(a1)]]
    dx = np.array([[np.sin(a1) - np.sin(a0), 0.0]])
    true_rise = np.cos(a1) - np.cos(a0)
    assert edge_rise(n0, n1, dx, "arc")[0] == pytest.approx(true_rise, abs=1e-15)
    assert abs(edge_rise(n0, n1, dx, "trapezoid")[0] - true_rise) > 0.1


# ----------------------------------------------------------------------------------------------
# steps


H_STEP, W_FLANK = 0.8, 1.0  # mm: a shoulder 0.8 mm high over a 1 mm wide raised-cosine flank


def plateau_step(x, y):
    t = np.clip(x / W_FLANK, -0.5, 0.5)
    return H_STEP / 2 * (1 + np.sin(np.pi * t)) + 0.03 * y**2 - 0.02 * x


def plateau_step_grad(x, y):
    t = x / W_FLANK
    p = np.where(np.abs(t) < 0.5, H_STEP / 2 * np.pi / W_FLANK * np.cos(np.pi * t), 0.0) - 0.02
    return p, 0.06 * y


def lit_step(n_points=900, seed=3, max_tilt_deg=40.0):
    """Irregular highlights on the step, only where a dome reaching 80 degrees lights the normal."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([-1.5, -1.0], [1.5, 1.0], (n_points, 2))
    n = analytic(plateau_step_grad, xy)
    lit = np.degrees(np.arccos(n[:, 2])) <= max_tilt_deg
    return xy[lit], n[lit]


def test_step_with_unlit_flank_splits_into_anchored_components():
    # the flank's middle (tilt > 40 degrees, |x| < 0.27 mm) has no highlights: a gap of 0.53 mm,
    # about 6 local spacings (median 0.084 mm) of these 747 points, so the max-edge rule
    # (3 spacings) cuts it
    xy, n = lit_step()
    zt = plateau_step(*xy.T)
    left = np.array([-1.2, 0.0, plateau_step(-1.2, 0.0)])
    right = np.array([1.2, 0.0, plateau_step(1.2, 0.0)])
    s = integrate_triangulated(xy, n, anchors=np.array([left, right]))
    assert len(s.components) == 2
    assert s.dropped["long_edges"] > 0
    sides = {np.sign(np.mean(s.xy[c.points, 0])) for c in s.components}
    assert sides == {-1.0, 1.0}
    assert all(c.anchored_by == "point" for c in s.components)
    # each side recovered: measured 1.0 um RMS, 5.8 um max (the arc's second-order error on the
    # curved parts of the flank, and the anchors placed off the points); 5 um RMS is 0.6 % of the step
    e = s.z - zt
    assert rms(e) < 0.005
    # one anchor only: the other side floats (NaN, never a silent 0), its shape still known
    one = integrate_triangulated(xy, n, anchors=left[None])
    floating = one.floating
    assert len(floating) == 1
    assert np.all(np.isnan(one.z[floating[0].points]))
    assert np.all(np.isfinite(one.z_relative))
    assert np.isnan(one.heights_at([[1.0, 0.0]])[0]) and np.isfinite(one.heights_at([[-1.0, 0.0]])[0])
    # without the cut, edges across the gap predict 0.84 mm per mm where the flank is steeper:
    # the step comes out too low, measured 0.10 mm RMS relative error (the grid integrators on the
    # same normals do no better: Poisson 89 um, robust 87 um, Frankot-Chellappa 0.24 mm)
    joined = integrate_triangulated(xy, n, max_edge_factor=100.0)
    assert len(joined.components) == 1 and joined.floating
    assert rms(joined.z_relative - (zt - zt.mean())) > 0.05


H_SHOULDER = 0.3  # mm


def shoulder(x, y):
    """A shoulder that runs out: for y >= 0 a plateau 0.3 mm up (x > 0.4) meets the floor through a
    ramp (0 < x < 0.4) and is flush with it for x < 0; a vertical wall along y = 0 between them."""
    t = np.clip(x / 0.4, 0, 1)
    return np.where(y >= 0, H_SHOULDER * 0.5 * (1 - np.cos(np.pi * t)), 0.0) + 0.05 * x


def shoulder_grad(x, y):
    t = x / 0.4
    ramp = np.where((t > 0) & (t < 1), H_SHOULDER * 0.5 * np.pi / 0.4 * np.sin(np.pi * np.clip(t, 0, 1)), 0.0)
    return np.where(y >= 0, ramp, 0.0) + 0.05, 0.0 * x


def test_robust_integrator_keeps_the_wall_poisson_smears_it():
    # The wall (vertical: no highlights on it) is invisible in the slopes, but the two levels also
    # meet through the ramp, so the slopes do fix the plateau's height: integrating around the wall
    # is right, across it wrong. Poisson averages both paths; the reweighted integrator drops the
    # edges across the wall (their residuals are large), keeping the plateau where the ramp puts it.
    step = 0.025
    gx = np.arange(-1 + step / 2, 1, step)
    X, Y = np.meshgrid(gx, gx)
    T = shoulder(X, Y)

    def err(z, mask):
        e = (z - T)[mask]
        return rms(e - e.mean())  # zero-mean results: compare shapes

    # slopes sampled exactly at the nodes: Poisson 72 um RMS, robust 0.22 um (measured)
    P, Q = shoulder_grad(X, Y)
    full = np.ones_like(P, bool)
    e_poisson = err(integrate_poisson(P, Q, full, step_mm=step).z, full)
    e_robust = err(integrate_robust(P, Q, full, step_mm=step).z, full)
    assert e_poisson > 0.05
    assert e_robust < 0.02 * e_poisson
    # the same from 900 irregular highlights through grid_gradients: Poisson 72 um, robust 10 um
    # (the interpolated band across the wall is a few triangles wide; Frankot-Chellappa 0.11 mm);
    # asserted: at least 3x better
    rng = np.random.default_rng(0)
    xy = rng.uniform(-1, 1, (900, 2))
    P, Q = grid_gradients(xy, analytic(shoulder_grad, xy), gx, gx)
    mask = np.isfinite(P)
    poisson = integrate_poisson(P, Q, mask, step_mm=step)
    robust = integrate_robust(P, Q, mask, step_mm=step)
    e_poisson, e_robust = err(poisson.z, mask), err(robust.z, mask)
    assert e_robust < e_poisson / 3
    wx, wy = robust.weights
    # the y edges across the wall (between the rows at y = -step/2 and +step/2) where it stands
    # (x > 0.4) lost their weight; those far from the wall and the ramp kept it
    wall_row = int(np.argmin(np.abs(gx + step / 2)))
    assert np.nanmedian(wy[wall_row, gx > 0.45]) < 0.1
    far = np.abs(gx[:-1] + step / 2) > 0.3
    assert np.nanmedian(wy[far][:, (gx < -0.1) | (gx > 0.5)]) > 0.9


# ----------------------------------------------------------------------------------------------
# noise


def test_noise_grows_linearly_with_normal_noise():
    # 0.1 degree of normal noise on the sphere cap (where the arc rule is exact, so the error is the
    # noise's alone). The solve is linear in the rises and each rise linear (to first order) in
    # small tilts, so the height error is proportional to the noise: 4x the noise, 4x the error.
    # Its size: a random walk over the graph, RMS ~ sigma * spacing * sqrt(ln(D / spacing)):
    # measured 0.19 um = 0.68 x that estimate; the band [0.2, 3] allows for the random graph.
    xy, n, zt = sphere_cap(200)
    rng = np.random.default_rng(5)
    axis = rng.normal(size=(len(n), 3))
    axis -= np.sum(axis * n, axis=1, keepdims=True) * n  # tangent directions
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    mag = rng.normal(size=(len(n), 1))

    def noisy(sigma_deg):
        a = np.radians(sigma_deg) * mag
        return np.cos(a) * n + np.sin(a) * axis

    e1 = rms(integrate_triangulated(xy, noisy(0.1), anchors=float(zt.mean())).z - zt)
    e4 = rms(integrate_triangulated(xy, noisy(0.4), anchors=float(zt.mean())).z - zt)
    assert e4 / e1 == pytest.approx(4.0, rel=0.02)  # measured 3.998: 2 % leaves room for 2nd-order terms
    spacing = np.sqrt(np.pi * (R_SPHERE * np.sin(np.radians(70))) ** 2 / len(xy))
    D = 2 * R_SPHERE * np.sin(np.radians(70))
    estimate = np.radians(0.1) * spacing * np.sqrt(np.log(D / spacing))
    assert 0.2 * estimate < e1 < 3 * estimate
    assert e1 < 0.001 * R_SPHERE  # well under 1 um for 0.1 degree


# ----------------------------------------------------------------------------------------------
# grid integrators


def gaussian_bump(x, y):
    return 0.2 * np.exp(-(x**2 + y**2) / (2 * 0.25**2))


def gaussian_grad(x, y):
    z = gaussian_bump(x, y)
    return -x / 0.25**2 * z, -y / 0.25**2 * z


def test_frankot_chellappa_and_poisson_on_a_bump_inside_the_grid():
    step = 0.02
    g = np.arange(-2.0, 2.0, step)  # the bump is 3e-15 mm at the border: periodic-free
    X, Y = np.meshgrid(g, g)
    T = gaussian_bump(X, Y) - gaussian_bump(X, Y).mean()
    P, Q = gaussian_grad(X, Y)
    fc = integrate_frankot_chellappa(P, Q, step_mm=step)
    # spectral: the bump is band-limited far below the grid's Nyquist (measured 1e-15 mm max)
    assert np.max(np.abs(fc.z - T)) < 1e-12
    # Poisson (trapezoid rule on the grid edges): second order, error ~ h**3 z''' / 12 per edge,
    # summed over the bump (measured 1.6e-4 mm max = 0.08 % of the 0.2 mm bump; halving the step
    # quarters it); asserted under 0.25 % of the bump
    po = integrate_poisson(P, Q, step_mm=step)
    e_po = np.max(np.abs(po.z - T))
    assert e_po < 5e-4
    g2 = np.arange(-2.0, 2.0, step / 2)
    X2, Y2 = np.meshgrid(g2, g2)
    T2 = gaussian_bump(X2, Y2) - gaussian_bump(X2, Y2).mean()
    e_po2 = np.max(np.abs(integrate_poisson(*gaussian_grad(X2, Y2), step_mm=step / 2).z - T2))
    assert e_po / e_po2 == pytest.approx(4.0, rel=0.1)
    # robust on a smooth field keeps every weight and matches Poisson (same fit, no outliers)
    ro = integrate_robust(P, Q, step_mm=step)
    assert np.max(np.abs(ro.z - po.z)) < 1e-6
    assert min(np.nanmin(w) for w in ro.weights) > 0.99


def test_frankot_chellappa_periodic_limitation_and_reflect_padding():
    # a tilted plane: its opposite borders do not match, so the periodic FFT spreads a sawtooth error;
    # the mirror extension joins them continuously (errors left only at the kinks of the mirrored
    # plane: measured 93 um RMS periodic, 0.18 um reflected)
    step = 0.02
    g = np.arange(0, 1 + 1e-9, step)
    X, Y = np.meshgrid(g, g)
    T = 0.3 * X - 0.1 * Y
    T = T - T.mean()
    P, Q = np.full_like(X, 0.3), np.full_like(X, -0.1)
    e_per = rms(integrate_frankot_chellappa(P, Q, step_mm=step).z - T)
    e_ref = rms(integrate_frankot_chellappa(P, Q, step_mm=step, pad="reflect").z - T)
    assert e_per > 0.05
    assert e_ref < e_per / 100  # 500x measured
    # Poisson with Neumann conditions is exact on a plane
    assert rms(integrate_poisson(P, Q, step_mm=step).z - T) < EXACT_MM


def test_masks_and_fill():
    step = 0.02
    g = np.arange(-1, 1 + 1e-9, step)
    X, Y = np.meshgrid(g, g)
    P, Q = gaussian_grad(X, Y)
    mask = X**2 + Y**2 < 0.8**2
    T = gaussian_bump(X, Y)
    for fill in ("zero", "poisson"):
        fc = integrate_frankot_chellappa(P, Q, mask=mask, step_mm=step, fill=fill)
        assert np.all(np.isnan(fc.z[~mask])) and np.all(np.isfinite(fc.z[mask]))
        e = (fc.z - T)[mask]
        # a round bump in a round mask: the height along the mask's edge is constant, so either fill
        # is integrable up to the mask's staircase outline (measured 1.0e-5 and 1.1e-5 mm RMS, 0.005 %
        # of the bump)
        assert rms(e - e.mean()) < 5e-5
    po = integrate_poisson(P, Q, mask, step_mm=step)
    assert np.nanmean(po.z) == pytest.approx(0.0, abs=1e-12)  # zero mean when not anchored
    anchored = integrate_poisson(P, Q, mask, step_mm=step, anchors=[[50, 50, 1.0]])
    assert anchored.z[50, 50] == pytest.approx(1.0, abs=1e-9)
    # two pieces of a mask: each zero-mean
    two = (np.abs(X) > 0.3) & (np.abs(Y) < 0.8)
    res = integrate_poisson(P, Q, two, step_mm=step)
    assert res.components == 2
    for side in (X < 0, X > 0):
        assert np.nanmean(res.z[side & two]) == pytest.approx(0.0, abs=1e-12)


def test_grid_gradients_are_griddata_linear():
    rng = np.random.default_rng(2)
    xy = rng.uniform(-1, 1, (150, 2))
    n = exact_normals(gaussian_bump, xy)
    gx = np.linspace(-1.2, 1.2, 41)
    P, Q = grid_gradients(xy, n, gx, gx)
    X, Y = np.meshgrid(gx, gx)
    ref = griddata(xy, -n[:, 0] / n[:, 2], (X, Y), method="linear")
    assert np.array_equal(np.isnan(P), np.isnan(ref))
    assert np.nanmax(np.abs(P - ref)) < 1e-12
    assert np.isnan(P[0, 0])  # outside the convex hull
    # drop_gaps: NaN in the triangles the sparse integrator drops
    xy2, n2 = lit_step()
    g2 = np.linspace(-1.4, 1.4, 57)
    P2, _ = grid_gradients(xy2, n2, g2, g2, drop_gaps=IntegrateParams())
    assert np.all(np.isnan(P2[:, np.abs(g2) < 0.2]))


# ----------------------------------------------------------------------------------------------
# the sparse surface's interpolation and the comparison function


def test_heights_at_and_height_map():
    xy, n, zt = sphere_cap(200)
    s = integrate_triangulated(xy, n, anchors=float(zt.mean()))
    assert np.allclose(s.heights_at(s.xy), s.z, atol=1e-12)  # at the vertices: the vertex heights
    gx = np.linspace(-0.8, 0.8, 33)
    hm = s.height_map(gx, gx)
    assert hm.shape == (33, 33)
    assert np.isnan(hm[0, 0])  # outside the cap's hull
    X, Y = np.meshgrid(gx, gx)
    inside = np.isfinite(hm)
    truth = np.sqrt(R_SPHERE**2 - X[inside] ** 2 - Y[inside] ** 2)
    # linear interpolation between exact vertices: chord sag ~ L**2 / (8 R) times the slope terms,
    # worst in the triangles along the steep rim (measured 49 um max, 11 um RMS on this grid)
    assert np.max(np.abs(hm[inside] - truth)) < 0.06
    assert rms(hm[inside] - truth) < 0.015
    assert s.point_residual_mm.shape == (len(s.xy),) and np.all(s.point_residual_mm < EXACT_MM)


def test_interpolation_with_normals_is_exact_on_quadratics():
    """Each vertex carried half way along its tangent plane: linear interpolation errs by
    +sum b_i d_i^T H d_i / 2 on a quadratic of Hessian H and the tangent planes' average by the same
    negated, so the blend is exact to rounding, at any triangle size."""
    rng = np.random.default_rng(3)
    xy = rng.uniform(-1, 1, (150, 2))
    a, b, c = 0.3, -0.2, 0.5

    def z(x, y):
        return a * x * x + b * x * y + c * y * y + 0.1 * x - 0.05 * y

    n = normal_from_gradient(2 * a * xy[:, 0] + b * xy[:, 1] + 0.1, b * xy[:, 0] + 2 * c * xy[:, 1] - 0.05)
    s = integrate_triangulated(xy, n, anchors=0.0)
    s.z[:] = z(*xy.T)  # exact vertex heights, to isolate the interpolation from the integration
    q = rng.uniform(-0.6, 0.6, (2000, 2))
    exact = z(*q.T)
    quad = s.heights_at(q, interpolation="normals")
    lin = s.heights_at(q)
    assert np.all(np.isfinite(quad))
    assert np.max(np.abs(quad - exact)) < 1e-12
    assert np.max(np.abs(lin - exact)) > 1e-3  # plane facets sag: the comparison can fail
    # the vertex heights are kept (NaN alike where a vertex lies only in triangles with a dropped edge)
    np.testing.assert_allclose(s.heights_at(s.xy, interpolation="normals"), s.heights_at(s.xy), atol=1e-12)
    assert s.height_map([0.0, 0.1], [0.2], interpolation="normals") == pytest.approx(
        z(np.array([[0.0, 0.1]]), np.array([[0.2, 0.2]])), abs=1e-12)
    with pytest.raises(OptionError, match="interpolation"):
        s.heights_at(q, interpolation="cubic")


def test_interpolation_with_normals_on_the_sphere_cap():
    # the same cap as above, heights integrated: normals between the points remove the chord sag
    # (a sphere is quadratic to second order at each triangle), leaving the integration's own error
    xy, n, zt = sphere_cap(200)
    s = integrate_triangulated(xy, n, anchors=float(zt.mean()))
    gx = np.linspace(-0.8, 0.8, 33)
    X, Y = np.meshgrid(gx, gx)
    lin = s.height_map(gx, gx)
    quad = s.height_map(gx, gx, interpolation="normals")
    inside = np.isfinite(lin)
    assert np.array_equal(inside, np.isfinite(quad))
    truth = np.sqrt(R_SPHERE**2 - X[inside] ** 2 - Y[inside] ** 2)
    assert rms(quad[inside] - truth) < 0.25 * rms(lin[inside] - truth)


def test_compare_integrators_refuses_points_along_a_line():
    # highlights on one streak (a solder joint's, not subdivided) span a grid one node wide: refused by
    # name, not a numpy error from the slopes
    t = np.linspace(0.0, 1.0, 12)
    xy = np.column_stack([t, 1e-4 * np.sin(7 * t)])
    n = np.tile([0.0, 0.0, 1.0], (12, 1))
    with pytest.raises(OptionError, match="3 x 3") as e:
        compare_integrators(xy, n, lambda x, y: np.zeros_like(x))
    assert e.value.field == "grid_step_mm"


def test_compare_integrators_on_the_sphere_cap():
    xy, n, _ = sphere_cap(200)

    def truth(x, y):
        return np.sqrt(np.maximum(R_SPHERE**2 - x**2 - y**2, 0.0))

    out = compare_integrators(xy, n, truth, scale_mm=R_SPHERE, grid_step_mm=0.02)
    methods = ("sparse-arc", "sparse-trapezoid", "poisson", "frankot-chellappa", "robust")
    assert set(methods) <= set(out)
    for m in methods:
        assert np.isfinite(out[m]["height_rms_mm"]) and np.isfinite(out[m]["normal_rms_deg"])
        assert out[m]["height_rms_pct"] == pytest.approx(100 * out[m]["height_rms_mm"] / R_SPHERE)
    # exact at the points; on the grid the piecewise-linear chord sag is what is left (measured on
    # 4186 nodes: sparse-arc 7.9 um = 0.99 % of R, sparse-trapezoid 12.3, Poisson 7.8, Frankot-
    # Chellappa 9.1, robust 8.4 um; normals 4.6 deg for the flat triangles against 1.7 for Poisson)
    assert out["sparse-arc"]["height_rms_at_points_mm"] < EXACT_MM
    assert out["sparse-trapezoid"]["height_rms_at_points_mm"] > 1e-3
    assert out["sparse-arc"]["height_rms_pct"] <= 1.0
    assert out["sparse-arc"]["height_rms_mm"] < out["sparse-trapezoid"]["height_rms_mm"]
    assert out["sparse-arc"]["height_rms_mm"] <= 1.1 * min(out[m]["height_rms_mm"] for m in methods)


# ----------------------------------------------------------------------------------------------
# bad input


def test_bad_input():
    xy, n, _ = sphere_cap(50)
    with pytest.raises(OptionError, match="at least 3") as exc:
        integrate_triangulated(xy[:2], n[:2])
    assert exc.value.field == "xy"
    line = np.column_stack([np.linspace(0, 1, 10), 2 * np.linspace(0, 1, 10)])
    with pytest.raises(OptionError, match="collinear") as exc:
        integrate_triangulated(line, np.tile([0, 0, 1.0], (10, 1)))
    assert exc.value.field == "xy"
    with pytest.raises(OptionError) as exc:
        integrate_triangulated(xy, n[:-1])
    assert exc.value.field == "normals"
    with pytest.raises(OptionError, match="rule"):
        integrate_triangulated(xy, n, rule="simpson")
    with pytest.raises(OptionError, match="max_edge_factor"):
        IntegrateParams(max_edge_factor=0)

    bad = n.copy()
    bad[3] = np.nan
    bad[7] = [0.1, 0.0, -0.9]  # points down: no gradient
    bad[9] = [1.0, 0.0, 0.0]  # horizontal: nz = 0, no gradient either
    s = integrate_triangulated(xy, bad, anchors=0.0)
    assert s.dropped["nonfinite"] == 1 and s.dropped["downward"] == 2
    assert len(s.xy) == len(xy) - 3 and 3 not in s.index and 7 not in s.index
    with pytest.raises(OptionError, match="row 3") as exc:
        integrate_triangulated(xy, bad, invalid="raise")
    assert exc.value.field == "normals"
    down = bad.copy()
    down[3] = [0, 0, 1.0]
    with pytest.raises(OptionError, match="points down") as exc:
        integrate_triangulated(xy, down, invalid="raise")
    assert exc.value.field == "normals"
    # all but two dropped: too few left
    few = np.full_like(n, np.nan)
    few[:2] = n[:2]
    with pytest.raises(OptionError, match="at least 3"):
        integrate_triangulated(xy, few)
    w = np.ones(len(xy))
    w[0] = 0
    assert integrate_triangulated(xy, n, weights=w, anchors=0.0).dropped["zero_weight"] == 1
    with pytest.raises(OptionError) as exc:
        integrate_triangulated(xy, n, weights=-w)
    assert exc.value.field == "weights"
    with pytest.raises(OptionError, match="anchor 0") as exc:
        integrate_triangulated(xy, n, anchors=[[50.0, 50.0, 0.0]])
    assert exc.value.field == "anchors"
    with pytest.raises(OptionError) as exc:
        integrate_triangulated(xy, n, anchors=[[0.0, 0.0]])
    assert exc.value.field == "anchors"
    with pytest.raises(OptionError) as exc:
        integrate_poisson(np.zeros((4, 4)), np.zeros((4, 5)), step_mm=0.1)
    with pytest.raises(OptionError) as exc:
        integrate_poisson(np.zeros((4, 4)), np.zeros((4, 4)), step_mm=-1)
    assert exc.value.field == "step_mm"


def test_duplicate_points_are_tied_not_lost():
    xy, n, zt = sphere_cap(100)
    xy2 = np.vstack([xy, xy[:3]])
    n2 = np.vstack([n, n[:3]])
    s = integrate_triangulated(xy2, n2, anchors=float(zt.mean()))
    assert len(s.components) == 1
    assert np.allclose(s.z[-3:], s.z[:3], atol=EXACT_MM)


# ----------------------------------------------------------------------------------------------
# the family: one entry point, each method on a case with an exact answer


def paraboloid(x, y):
    return 0.5 * x**2 + 0.3 * x * y - 0.2 * y**2 + 0.1 * x


def paraboloid_normals(x, y):
    return normal_from_gradient(x + 0.3 * y + 0.1, 0.3 * x - 0.4 * y)


def grid_case(h=0.05):
    gx = np.arange(-0.5, 0.5 + h / 2, h)
    gy = np.arange(-0.4, 0.4 + h / 2, h)
    return np.meshgrid(gx, gy)


def test_integrate_knows_every_method():
    assert set(INTEGRATE_METHODS) == {"triangulated", "poisson", "frankot-chellappa", "robust", "profile",
                                      "thin-plate"}


def test_integrate_triangulated_on_a_paraboloid_and_a_sphere():
    rng = np.random.default_rng(1)
    xy = rng.uniform(-1, 1, (300, 2))
    zt = paraboloid(*xy.T)
    # the trapezoid rule is exact on quadratics: round-off of the solve only
    s = integrate(xy, paraboloid_normals(*xy.T), method="triangulated", anchors=[[*xy[0], zt[0]]], rule="trapezoid")
    assert np.max(np.abs(s.z - zt)) < EXACT_MM
    xy, n, zt = sphere_cap(200)
    s = integrate(xy, n, anchors=float(zt.mean()))  # the default method, the arc rule: exact on a sphere
    assert np.max(np.abs(s.z - zt)) < EXACT_MM


@pytest.mark.parametrize("method", ["poisson", "robust"])
def test_grid_least_squares_methods_are_exact_on_a_paraboloid(method):
    # on a grid the trapezoid rise of an edge is exact wherever the gradient is linear along it, so the
    # least-squares heights of a quadratic are exact up to the solve's round-off; the robust weights
    # stay 1 (zero curl, zero residual)
    X, Y = grid_case()
    zt = paraboloid(X, Y)
    g = integrate(0.05, paraboloid_normals(X, Y), method=method, anchors=[[0, 0, zt[0, 0]]])
    assert np.max(np.abs(g.z - zt)) < EXACT_MM
    mask = X**2 + Y**2 < 0.3**2  # a disc of the grid: NaN outside, exact inside
    n = paraboloid_normals(X, Y)
    n[~mask] = np.nan
    g = integrate(0.05, n, method=method)
    assert np.array_equal(np.isfinite(g.z), mask)
    assert np.max(np.abs(g.z[mask] - (zt[mask] - zt[mask].mean()))) < EXACT_MM


def test_frankot_chellappa_is_exact_on_a_periodic_surface():
    # one full period of a cosine along x and a sine along y: the FFT's basis, so the projection is
    # exact up to the transform's round-off (zero mean, as is the truth over whole periods)
    H, W, h = 16, 20, 0.05
    X, Y = np.meshgrid(h * np.arange(W), h * np.arange(H))
    kx, ky = 2 * np.pi / (W * h), 2 * np.pi / (H * h)
    zt = 0.02 * np.cos(kx * X) + 0.01 * np.sin(ky * Y)
    n = normal_from_gradient(-0.02 * kx * np.sin(kx * X), 0.01 * ky * np.cos(ky * Y))
    g = integrate(h, n, method="frankot-chellappa")
    assert np.max(np.abs(g.z - zt)) < EXACT_MM


def test_profile_method_is_the_papers_rule_exact_on_a_circle():
    x = -0.3 + 0.6 * np.sort(np.random.default_rng(3).permutation(31)[:20]) / 30  # uneven, none merged
    zt = np.sqrt(0.5**2 - x**2)
    pr = integrate(x, normal_from_gradient(-x / zt, 0 * x), method="profile", max_gap_mm=0.1, anchor=(x[0], zt[0]))
    assert pr.n_segments == 1
    assert np.max(np.abs(pr.points["z"] - zt)) < EXACT_MM  # the circular arc is exact on a circle


def test_thin_plate_method_is_exact_on_a_plane():
    rng = np.random.default_rng(2)
    xy = rng.uniform([0, -0.1], [0.2, 0.1], (60, 2))
    n = normal_from_gradient(np.full(60, 0.4), np.full(60, -0.2))
    s = integrate(xy, n, method="thin-plate", anchors=[[0.0, 0.0, 0.05]], bounds=(0, 0.2, -0.1, 0.1), step_mm=0.01)
    X, Y = np.meshgrid(s.x, s.y)
    # a plane meets every equation (zero thin-plate energy); what moves it is the ridge that makes the
    # normal equations definite, 1e-12 of their mean diagonal on every node, pulling the heights
    # (up to 0.11 mm) towards 0 against the softest mode of this system (1.25e-5 of the mean diagonal):
    # 0.11 * 1e-12 / 1.25e-5 = 8.8e-9 mm (measured 8.4e-9); twice that for solver round-off
    assert np.max(np.abs(s.z - (0.4 * X - 0.2 * Y + 0.05))) < 2e-8


def test_integrate_refuses_an_unknown_method_and_misshapen_input():
    xy, n, _ = sphere_cap(50)
    with pytest.raises(OptionError, match="method must be one of 'triangulated', 'poisson', 'frankot-chellappa', "
                                          "'robust', 'profile', 'thin-plate'; got 'simpson'"):
        integrate(xy, n, method="simpson")
    with pytest.raises(OptionError, match=r"\(H, W, 3\) normals") as exc:
        integrate(0.1, n, method="poisson")
    assert exc.value.field == "normals"
    with pytest.raises(OptionError, match=r"\(N, 2\) points") as exc:
        integrate(xy[:, 0], n, method="thin-plate")
    assert exc.value.field == "points_or_grid"
