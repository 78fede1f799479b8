"""Camera models held against the paper's analytic error model (Figs. 5-6).

Pure functions that render small scenes, reconstruct them and return plain
dicts of numpy arrays, for ``shinysim figures`` and the tests (nothing here
plots or prints): :func:`facet_errors` renders the surface element of
Figs. 5-6 as a small mirror facet, :func:`raised_sphere_errors` the SHINY
calibration sphere raised off the reference plane, and both compare the
three camera models' normals with Eqs 11-14 and the exact mirror-sphere
solution. Millimetres and radians in, errors in degrees (``_deg``) and
percent (``_percent``), signed ``Theta_act - Theta_model`` as in Eqs 15-17.
Rendering needs the ``render`` extra with a JIT Mitsuba variant. The set-ups
and the results: ``docs/theory.md``, section 4 "Simulation against theory".
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..conventions import MM_PER_INCH, angle_between, elevation_from_x
from ..objects.facet import FACET_SIZE_MM, facet_normal
from ..recon.detect import DetectParams, detect_highlights
from ..recon.normals import PAPER_MODELS as NORMAL_MODELS
from ..recon.normals import highlight_normals
from ..rig import Camera, Rig, shiny_1988
from ..theory import sensitivity as sens
from ..theory.mirror import mirror_sphere_highlight
from .sharpness import _brightest_per_source

__all__ = [
    "FIBER_DIAMETER_MM",
    "FIG5_X_IN",
    "FIG5_DH_IN",
    "TOLERANCE_REL",
    "TOLERANCE_DEG",
    "paper_geometry_mm",
    "facet_rig",
    "facet_errors",
    "raised_sphere_errors",
    "within_tolerance",
    "fig05_comparison",
    "fig06_comparison",
]

#: SHINY fiber diameter, 0.040 in.
FIBER_DIAMETER_MM = 0.040 * MM_PER_INCH

#: Corners and centre of the paper's Fig. 5 range, inches.
FIG5_X_IN = (-0.03, -0.015, 0.0, 0.015, 0.03)
FIG5_DH_IN = (0.0, 0.05, 0.1, 0.15, 0.2)

#: The issue's agreement criterion: 10 % relative or 0.02 degrees, whichever
#: is larger.
TOLERANCE_REL = 0.10
TOLERANCE_DEG = 0.02


def _wrap_deg(d):
    """Angle differences wrapped to (-180, 180] degrees."""
    return (np.asarray(d, dtype=float) + 180.0) % 360.0 - 180.0


def _signed_deg(true_normals, model_normals):
    """``Theta_act - Theta_model`` in degrees (in the x-z plane, from +x)."""
    return _wrap_deg(np.degrees(elevation_from_x(true_normals) - elevation_from_x(model_normals)))


def within_tolerance(measured, reference, *, rel=TOLERANCE_REL, abs_deg=TOLERANCE_DEG):
    """The issue's criterion: ``|measured - reference| <= max(rel |reference|, abs_deg)``.

    Parameters
    ----------
    measured, reference : array_like, degrees

    Returns
    -------
    ndarray of bool
    """
    m = np.asarray(measured, dtype=float)
    r = np.asarray(reference, dtype=float)
    return np.abs(m - r) <= np.maximum(rel * np.abs(r), abs_deg)


# --------------------------------------------------------------------------
# Figs. 5-6: a mirror facet at (x, dh)
# --------------------------------------------------------------------------

def paper_geometry_mm(*, R_mm=None, elevation=None, f_mm=None):
    """Source and camera of the paper's Fig. 5, millimetres.

    Defaults: ``R = 1.7 in`` (the text) and the source elevation and focal
    height under which the printed Eqs 11-17 give the quoted 1.25, 0.85 and
    0.91 percent (:data:`shinysim.theory.sensitivity.PAPER_FIT`: 46.67
    degrees above the horizontal, ``f = 2.115 in``).

    Returns
    -------
    dict
        ``R_mm``, ``elevation`` (radians), ``a_mm``, ``b_mm`` (source
        horizontal position and height) and ``f_mm`` (focal-point height).
    """
    R_mm = sens.PAPER_R_IN * MM_PER_INCH if R_mm is None else float(R_mm)
    elevation = sens.PAPER_FIT.elevation if elevation is None else float(elevation)
    f_mm = sens.PAPER_FIT.f * MM_PER_INCH if f_mm is None else float(f_mm)
    a, b = sens.source_position(R_mm, elevation)
    return {"R_mm": R_mm, "elevation": elevation, "a_mm": float(a), "b_mm": float(b), "f_mm": f_mm}


def facet_rig(*, R_mm=None, elevation=None, f_mm=None, projection="perspective", resolution=256,
              field_width_mm=2.5, fiber_diameter_mm=FIBER_DIAMETER_MM):
    """A one-source rig in the frame of Eqs 11-14.

    The source (a sphere of diameter ``fiber_diameter_mm``) sits at
    ``(R cos e, 0, R sin e)``; the camera looks down -z from ``(0, 0, f)``
    (perspective: its centre of projection is the focal point of Eq 12;
    orthographic: ``f`` only places the image plane).

    Parameters
    ----------
    R_mm, elevation, f_mm
        As in :func:`paper_geometry_mm`.
    projection : {"perspective", "orthographic"}
    resolution : int
        Square image size, pixels.
    field_width_mm : float
        Imaged width on the reference plane; 2.5 mm holds a 0.2 mm facet
        anywhere in the Fig. 5 range (|x| <= 0.03 in, dh <= 0.2 in) at
        ``f = 2.115 in``.
    fiber_diameter_mm : float

    Returns
    -------
    Rig
    """
    g = paper_geometry_mm(R_mm=R_mm, elevation=elevation, f_mm=f_mm)
    cam = Camera(projection=projection, width=resolution, height=resolution, position=[0.0, 0.0, g["f_mm"]],
                 target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0], field_width=field_width_mm, name="top")
    return Rig(
        source_positions=np.array([[g["a_mm"], 0.0, g["b_mm"]]]),
        source_radii=np.array([0.5 * fiber_diameter_mm]),
        cameras=(cam,),
        name="fig05_facet",
        metadata={"preset": "fig05_facet", **g},
    )


def _correct_errors_deg(x, dh, a, b, f, *, convention="correct", **kwargs):
    """Correct Eqs 11-14 (or ``convention="printed"``), signed degrees ``Theta_act - Theta_model`` per model, and
    ``Theta_act``."""
    th = sens.theta_models(x, dh, a, b, f, convention=convention, **kwargs)
    err = {m: _wrap_deg(np.degrees(th["actual"] - th[m])) for m in NORMAL_MODELS}
    return err, th["actual"]


def _analytic(x, dh, a, b, f, projection, a_true=None, b_true=None):
    """Eqs 11-14 in the forms compared, signed degrees ``Theta_act - Theta_model``."""
    if projection == "orthographic":
        # vertical rays: the camera term is pi/2 and the camera sees x itself
        f_eff, image_x, f_printed = np.inf, "reference", 1e12 * (abs(a) + abs(b) + 1.0)  # atan(f/x), f -> inf
    else:
        f_eff, image_x, f_printed = f, "projected", f
    kw = {"a_true": a_true, "b_true": b_true}
    out = {}
    out["analytic"], act = _correct_errors_deg(x, dh, a, b, f_eff, image_x=image_x, **kw)
    out["analytic_reference"], _ = _correct_errors_deg(x, dh, a, b, f_eff, image_x="reference", **kw)
    out["printed"], _ = _correct_errors_deg(x, dh, a, b, f_printed, convention="printed", **kw)
    out["theta_act_deg"] = np.degrees(act)
    with np.errstate(divide="ignore", invalid="ignore"):
        out["analytic_percent"] = {m: 100.0 * np.radians(out["analytic"][m]) / act for m in NORMAL_MODELS}
    return out


def _exact_sphere_reference(points, normals, sources_true, model_rig, *, radius):
    """Model errors from the exact mirror-sphere solution (no rendering).

    A mirror sphere of ``radius`` tangent to each element (centre
    ``point - radius * normal``) has its highlight for that source at the
    element: :func:`~shinysim.theory.mirror.mirror_sphere_highlight` finds it
    by bisection, the camera projects it, and the reconstruction's models
    turn the exact image point into normals.
    """
    cam = model_rig.camera
    centers = points - radius * normals
    cam_pos = None if cam.projection == "orthographic" else cam.position
    p_ex = np.empty_like(points)
    n_ex = np.empty_like(points)
    for i in range(len(points)):
        p_ex[i], n_ex[i] = mirror_sphere_highlight(sources_true[i], center=centers[i], radius=radius,
                                                   camera_position=cam_pos, view_direction=-cam.forward)
    rows, cols = cam.project(p_ex)
    src = np.zeros(len(points), dtype=int)
    return {m: _signed_deg(n_ex, highlight_normals(rows, cols, src, model_rig, model=m)) for m in NORMAL_MODELS}


def facet_errors(x_mm: ArrayLike, dh_mm: ArrayLike, *, source_error: ArrayLike = 0.0, R_mm: float | None = None,
                 elevation: float | None = None, f_mm: float | None = None, projection: str = "perspective",
                 alpha: float = 0.002, facet_mm: float = FACET_SIZE_MM, fiber_diameter_mm: float = FIBER_DIAMETER_MM,
                 resolution: int = 256, spp: int = 16, seed: int = 0, field_width_mm: float = 2.5,
                 threshold: float = 0.5, method: str = "per-source", variant: str | None = None,
                 sphere_radius_mm: float | None = None,
                 progress: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """Camera-model errors of a rendered mirror facet, against Eqs 11-17.

    For each point, a square mirror facet (the registry's ``tilted_plane``,
    :func:`shinysim.sim.objects.scene_objects`) centred at ``(x, 0, dh)`` is turned so that it reflects the *true*
    source into the camera; one frame is rendered, the highlight's centroid
    detected and the three camera models recover a normal using the source
    position the models *believe* (the nominal one). Paper Fig. 5 is
    ``source_error = 0``; Fig. 6 moves the true source by ``source_error``
    in elevation (same distance).

    Parameters
    ----------
    x_mm, dh_mm : array_like, millimetres
        Element positions and heights, broadcast together to N points.
    source_error : array_like, radians
        True source elevation minus believed elevation (Fig. 6's delta),
        broadcast with the points.
    R_mm, elevation, f_mm
        Believed source distance, elevation and focal height
        (:func:`paper_geometry_mm`; default the paper fit).
    projection : {"perspective", "orthographic"}
        The camera. Orthographic compares with Eqs 11-14 at ``f -> inf``.
    alpha : float
        Rough-conductor roughness of the facet (near mirror).
    facet_mm : float
        Side of the facet.
    fiber_diameter_mm : float
    resolution, spp, seed : int
    field_width_mm : float
    threshold : float
        Absolute detection threshold I0 as a fraction of the source's
        radiance (1): a lit mirror facet shows the source's radiance, so 0.5
        keeps the facet's pixels whatever the brightest pixel of the frame.
    method : str
        Stack renderer (:meth:`shinysim.sim.render.Simulator.render_stack`);
        with one source ``"per-source"`` (Mitsuba's own ``direct``
        integrator) costs the same as the one-pass renderer.
    variant : str, optional
        Mitsuba variant.
    sphere_radius_mm : float, optional
        Radius of the tangent sphere of the exact reference (default the
        SHINY calibration sphere's, 1/32 in).
    progress : callable, optional
        ``progress(done, total)`` after each point.

    Returns
    -------
    dict
        Per point (N,) arrays: ``x_mm``, ``dh_mm``, ``source_error``,
        ``theta_act_deg``, ``row``, ``col`` (centroid), ``area_px``,
        ``centroid_offset_px`` (centroid minus projected facet centre,
        length); per model dicts of signed errors in degrees:
        ``measured_deg`` (rendered), ``analytic_deg`` (Eqs 11-14 correct,
        with the image position the camera reports: ``x f / (f - dh)`` for
        a perspective camera), ``analytic_reference_deg`` (correct, models
        told the true ``x``, the paper's reading), ``printed_deg`` (Eqs
        11-14 as printed), ``exact_deg`` (exact mirror sphere); also
        ``measured_angle_deg`` (3-D angle between recovered and true
        normal), ``measured_percent`` and ``analytic_percent``
        (``100 (Theta_act - Theta_model) / Theta_act``), and ``settings``.
    """
    from ..objects.sphere import SHINY_SPHERE_RADIUS_MM
    from ..sim.render import Simulator
    from ..sim.objects import scene_objects

    x, dh, delta = (np.ravel(v).astype(float) for v in np.broadcast_arrays(x_mm, dh_mm, source_error))
    n_pts = len(x)
    sphere_radius_mm = SHINY_SPHERE_RADIUS_MM if sphere_radius_mm is None else float(sphere_radius_mm)
    geom = paper_geometry_mm(R_mm=R_mm, elevation=elevation, f_mm=f_mm)
    kw = dict(R_mm=geom["R_mm"], f_mm=geom["f_mm"], projection=projection, resolution=resolution,
              field_width_mm=field_width_mm, fiber_diameter_mm=fiber_diameter_mm)
    model_rig = facet_rig(elevation=geom["elevation"], **kw)
    cam = model_rig.camera
    params = DetectParams(threshold=threshold, threshold_mode="absolute")
    points = np.stack([x, np.zeros_like(x), dh], axis=1)
    a_true, b_true = sens.source_position(geom["R_mm"], geom["elevation"] + delta)
    sources_true = np.stack([a_true, np.zeros_like(a_true), b_true], axis=1)
    true_n = facet_normal(points, sources_true, cam)

    rows, cols, areas = np.full(n_pts, np.nan), np.full(n_pts, np.nan), np.zeros(n_pts, int)
    measured, measured_angle, sims = {}, {}, {}
    for i in range(n_pts):
        if delta[i] not in sims:
            sims[delta[i]] = facet_rig(elevation=geom["elevation"] + delta[i], **kw)
        render_rig = sims[delta[i]]
        facet = scene_objects("tilted_plane", center_mm=points[i], normal=true_n[i], size_mm=facet_mm, part="object",
                              alpha=alpha)
        sim = Simulator(render_rig, facet, variant=variant)
        frame = sim.render_stack(spp=spp, seed=seed + i, method=method).frames[0]
        h = detect_highlights(frame, params)
        if len(h["row"]):
            j = int(np.argmax(h["sum"]))
            rows[i], cols[i], areas[i] = h["row"][j], h["col"][j], h["area"][j]
        if progress:
            progress(i + 1, n_pts)
    for m in NORMAL_MODELS:
        nm = highlight_normals(rows, cols, np.zeros(n_pts, int), model_rig, model=m)
        measured[m] = _signed_deg(true_n, nm)
        measured_angle[m] = np.degrees(angle_between(nm, true_n))
    er, ec = cam.project(points)
    ana = _analytic(x, dh, geom["a_mm"], geom["b_mm"], geom["f_mm"], projection, a_true=a_true, b_true=b_true)
    exact = _exact_sphere_reference(points, true_n, sources_true, model_rig, radius=sphere_radius_mm)
    theta_act = np.radians(ana["theta_act_deg"])
    with np.errstate(divide="ignore", invalid="ignore"):
        measured_pct = {m: 100.0 * np.radians(measured[m]) / theta_act for m in NORMAL_MODELS}
    return {
        "x_mm": x,
        "dh_mm": dh,
        "source_error": delta,
        "theta_act_deg": ana["theta_act_deg"],
        "row": rows,
        "col": cols,
        "area_px": areas,
        "centroid_offset_px": np.hypot(rows - er, cols - ec),
        "measured_deg": measured,
        "measured_angle_deg": measured_angle,
        "analytic_deg": ana["analytic"],
        "analytic_reference_deg": ana["analytic_reference"],
        "printed_deg": ana["printed"],
        "exact_deg": exact,
        "measured_percent": measured_pct,
        "analytic_percent": ana["analytic_percent"],
        "settings": {
            **geom, "projection": projection, "alpha": alpha, "facet_mm": facet_mm,
            "fiber_diameter_mm": fiber_diameter_mm, "resolution": resolution, "spp": spp, "seed": seed,
            "field_width_mm": field_width_mm, "pixel_pitch_mm": cam.pixel_pitch, "threshold": threshold,
            "threshold_mode": "absolute", "method": method, "sphere_radius_mm": sphere_radius_mm,
        },
    }


def fig05_comparison(*, quick=False, **kwargs):
    """:func:`facet_errors` over the paper's Fig. 5 range (source error 0).

    ``quick``: the four corners x = +-0.03 in, dh = 0.05 and 0.2 in at 192
    px and 8 spp (a few seconds); otherwise the 5 x 5 grid
    :data:`FIG5_X_IN` x :data:`FIG5_DH_IN` at 256 px and 16 spp. Keyword
    arguments go to :func:`facet_errors`.
    """
    if quick:
        xs, dhs = (-0.03, 0.03), (0.05, 0.2)
        kwargs = {"resolution": 192, "spp": 8, **kwargs}
    else:
        xs, dhs = FIG5_X_IN, FIG5_DH_IN
    X, DH = np.meshgrid(np.asarray(xs) * MM_PER_INCH, np.asarray(dhs) * MM_PER_INCH)
    return facet_errors(X.ravel(), DH.ravel(), **kwargs)


def fig06_comparison(*, quick=False, x_in=None, **kwargs):
    """:func:`facet_errors` over the paper's Fig. 6 range (source error delta).

    At ``x = 0.02 in`` (the fitted reading of the paper's example; default)
    for delta in {-0.1, 0, 0.1} rad and dh in {0, 0.1, 0.2} in (``quick``:
    delta = +-0.1 rad, dh = 0.05 and 0.2 in, 192 px, 8 spp).
    """
    x_in = sens.PAPER_FIT.x if x_in is None else float(x_in)
    if quick:
        deltas, dhs = (-0.1, 0.1), (0.05, 0.2)
        kwargs = {"resolution": 192, "spp": 8, **kwargs}
    else:
        deltas, dhs = (-0.1, 0.0, 0.1), (0.0, 0.1, 0.2)
    D, DH = np.meshgrid(np.asarray(deltas), np.asarray(dhs) * MM_PER_INCH)
    return facet_errors(x_in * MM_PER_INCH, DH.ravel(), source_error=D.ravel(), **kwargs)


# --------------------------------------------------------------------------
# The calibration sphere raised off the reference plane
# --------------------------------------------------------------------------

def raised_sphere_errors(dh_mm: ArrayLike, *, alpha: float = 0.001, projection: str = "perspective",
                         resolution: int = 512, spp: int = 16, seed: int = 0, threshold: float = 0.5,
                         radius_mm: float | None = None, method: str | None = None, variant: str | None = None,
                         progress: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """Camera-model errors on the SHINY sphere raised by ``dh`` (all 21 sources).

    Each source's highlight on the sphere (centre ``(0, 0, dh)``) is a surface
    element at a height ``dh + r cos t`` and a position ``x = r sin t`` that
    the exact mirror-sphere solution gives; Eqs 11-14 are evaluated there
    with that source's ``(a, b)`` and the camera's height as ``f``.

    Parameters
    ----------
    dh_mm : float or sequence of float, millimetres
        Heights of the sphere's centre above the reference plane; one render
        each.
    alpha : float
        Roughness (near mirror, so the centroid sits on the mirror point).
    projection : {"perspective", "orthographic"}
    resolution, spp, seed : int
    threshold : float
        Relative I0; the largest highlight of each source is kept.
    radius_mm : float, optional
        Sphere radius (default 1/32 in).
    method : str, optional
        Stack renderer (default: the simulator's).
    variant : str, optional
    progress : callable, optional
        ``progress(done, total)`` after each height.

    Returns
    -------
    dict
        Per highlight (M,) arrays: ``sphere_dh_mm``, ``source``,
        ``source_angle_deg``, ``x_mm`` and ``dh_mm`` (the exact highlight
        point), ``centroid_offset_px`` (centroid minus the projected exact
        point); per-model signed errors in degrees: ``measured_deg``
        (recovered normal against the rendered truth at the centroid, as
        ``shinysim scan`` scores it), ``measured_exact_normal_deg``
        (recovered normal against the exact normal at the exact point),
        ``analytic_deg`` (Eqs 11-14, correct, at the exact point) and
        ``exact_deg`` (the models applied to the exactly projected exact
        point); and ``settings``.
    """
    from ..evaluate import sample_truth
    from ..objects.sphere import SHINY_SPHERE_RADIUS_MM
    from ..recon import reconstruct
    from ..sim.render import Simulator
    from ..sim.objects import scene_objects

    radius_mm = SHINY_SPHERE_RADIUS_MM if radius_mm is None else float(radius_mm)
    heights = np.atleast_1d(np.asarray(dh_mm, dtype=float)).ravel()
    rig = shiny_1988(projection=projection, resolution=resolution)
    cam = rig.camera
    src_all = rig.source_positions
    f_eff = np.inf if projection == "orthographic" else cam.position[2]
    cols_out = {k: [] for k in ("sphere_dh_mm", "source", "source_angle_deg", "x_mm", "dh_mm", "centroid_offset_px")}
    errs = {k: {m: [] for m in NORMAL_MODELS} for k in
            ("measured_deg", "measured_exact_normal_deg", "analytic_deg", "exact_deg")}
    for n_done, h in enumerate(heights):
        center = np.array([0.0, 0.0, h])
        sim = Simulator(rig, scene_objects("sphere", center_mm=center, radius_mm=radius_mm, alpha=alpha),
                        variant=variant)
        truth = sim.render_truth()
        stack = sim.render_stack(spp=spp, seed=seed, method=method)
        rec = reconstruct(stack, DetectParams(threshold=threshold))
        t = rec.table
        keep = _brightest_per_source(t)
        src = t["source"][keep]
        p_ex, n_ex = mirror_sphere_highlight(src_all, center=center, radius=radius_mm,
                                             camera_position=None if projection == "orthographic" else cam.position)
        er, ec = cam.project(p_ex)
        tn, _, _ = sample_truth(truth, t["row"][keep], t["col"][keep])
        ana, _ = _correct_errors_deg(p_ex[:, 0], p_ex[:, 2], src_all[:, 0], src_all[:, 2], f_eff,
                                     image_x="reference" if projection == "orthographic" else "projected")
        for m in NORMAL_MODELS:
            nm = rec.normals[m][keep]
            errs["measured_deg"][m].append(_signed_deg(tn, nm))
            errs["measured_exact_normal_deg"][m].append(_signed_deg(n_ex[src], nm))
            errs["analytic_deg"][m].append(ana[m][src])
            ne = highlight_normals(er, ec, np.arange(rig.n_sources), rig, model=m)
            errs["exact_deg"][m].append(_signed_deg(n_ex, ne)[src])
        cols_out["sphere_dh_mm"].append(np.full(len(src), h))
        cols_out["source"].append(src)
        cols_out["source_angle_deg"].append(np.asarray(rig.metadata["source_angles_deg"])[src])
        cols_out["x_mm"].append(p_ex[src, 0])
        cols_out["dh_mm"].append(p_ex[src, 2])
        cols_out["centroid_offset_px"].append(np.hypot(t["row"][keep] - er[src], t["col"][keep] - ec[src]))
        if progress:
            progress(n_done + 1, len(heights))
    out = {k: np.concatenate(v) for k, v in cols_out.items()}
    for k, d in errs.items():
        out[k] = {m: np.concatenate(v) for m, v in d.items()}
    out["settings"] = {"alpha": alpha, "projection": projection, "resolution": resolution, "spp": spp,
                       "seed": seed, "threshold": threshold, "radius_mm": radius_mm,
                       "pixel_pitch_mm": cam.pixel_pitch, "f_mm": float(f_eff)}
    return out
