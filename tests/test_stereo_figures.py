"""Figs. 13, 14, 16, 17, 18 (structured-highlight stereo): built from the theory, saved, registered."""

from __future__ import annotations

import json

import numpy as np
import pytest

from shinysim.plot import stereo as ps
from shinysim.studies import figures as figmod
from shinysim.theory import stereo as st

STEREO_PNGS = ("fig13_stereo_geometry.png", "fig14_z_theta.png", "fig16_candidates.png", "fig17_matching.png",
               "fig18_gradient_loci.png")


@pytest.fixture(scope="module")
def scene():
    return ps.fig16_scene()


def _line(fig, gid):
    found = [ln for ax in fig.axes for ln in ax.get_lines() if ln.get_gid() == gid]
    assert found, f"no line {gid!r}"
    return found[0]


def _saved(fig, tmp_path, name):
    import matplotlib.image as mpimg

    path = tmp_path / name
    fig.savefig(path, dpi=60)
    img = mpimg.imread(path)
    assert img.ndim == 3 and min(img.shape[:2]) > 200
    assert np.ptp(img[..., :3]) > 0.5  # not a blank canvas
    return img


def test_fig13_parabola_through_the_element(tmp_path):
    fig, cap = ps.fig13_stereo_geometry(R=10.0, alpha=np.deg2rad(35.0), x=2.0, z=1.0)
    xx, zz = _line(fig, "eq18_true").get_data()
    xs, zs = 10 * np.sin(np.deg2rad(35.0)), 10 * np.cos(np.deg2rad(35.0))
    a = st.parabola_parameter(2.0, 1.0, xs, zs)
    ok = np.isfinite(zz)
    assert np.allclose(zz[ok], st.parabola_family(xx[ok], xs, zs, a)[0])
    assert "Eq 18" in cap and len(cap) > 200
    _saved(fig, tmp_path, "fig13.png")


def test_fig14_draws_eq20_correct_and_printed(tmp_path):
    fig, cap = ps.fig14_z_theta(x_hat=0.2, alphas_deg=(-30.0, 30.0))
    th, z = _line(fig, "eq20_1").get_data()
    ok = np.isfinite(z)
    assert ok.sum() > 200
    assert np.allclose(z[ok], st.z_of_theta(np.deg2rad(th[ok]), 0.2, np.deg2rad(30.0), 1.0))
    thp, zp = _line(fig, "eq20_printed_1").get_data()
    okp = np.isfinite(zp)
    assert np.allclose(zp[okp], st.z_of_theta(np.deg2rad(thp[okp]), 0.2, np.deg2rad(30.0), 1.0,
                                              convention="printed"))
    assert "x̂ = x/R" in cap
    _saved(fig, tmp_path, "fig14.png")


def test_fig16_marks_the_true_matches_and_they_are_accepted(scene, tmp_path):
    fig, cap = ps.fig16_candidates(scene)
    m, true = scene["match"], scene["true"]
    assert true.sum() >= 6 and np.array_equal(m.accepted, true)
    tx, tz = _line(fig, "true").get_data()
    assert np.allclose(tx, scene["h1"].x[np.nonzero(true)[0]], atol=1e-9)
    assert np.allclose(tz, scene["h1"].z[np.nonzero(true)[0]], atol=1e-9)
    cx, _ = _line(fig, "candidates").get_data()
    assert len(cx) > 50
    assert "Accepted and true coincide" in cap
    _saved(fig, tmp_path, "fig16.png")


def test_fig17_curves_are_eqs_33_34(scene, tmp_path):
    fig, cap = ps.fig17_matching(scene)
    true_ax, false_ax = fig.axes[:2]
    h1, h2, m = scene["h1"], scene["h2"], scene["match"]
    for ax, accepted in ((true_ax, True), (false_ax, False)):
        (rx,), (ry,) = [v for v in [ln for ln in ax.get_lines() if ln.get_gid() == "root"][0].get_data()]
        i, j = np.argwhere((np.rad2deg(m.theta) == rx) & (m.e1 == ry))[0]  # the values plotted
        assert bool(m.accepted[i, j]) is accepted
        th, e1 = [ln for ln in ax.get_lines() if ln.get_gid() == "e1"][0].get_data()
        ok = np.isfinite(e1)
        ref, _ = st.match_function(np.deg2rad(th[ok]), h1.x_cam[i], h1.alpha[i], h2.x_cam[j], h2.alpha[j],
                                   scene["beta"], scene["R"])
        assert np.allclose(e1[ok], ref)
    assert abs(ry) > 1e-3  # the false pair's curves cross off the axis
    assert "false pair" in cap
    _saved(fig, tmp_path, "fig17.png")


def test_fig18_loci_cross_at_the_true_gradient(tmp_path):
    normal = np.array([-0.25, 0.35, 1.0])
    fig, cap = ps.fig18_gradient_loci(beta=np.deg2rad(30.0), normal=normal)
    (px,), (qy,) = _line(fig, "crossing").get_data()
    assert px == pytest.approx(0.25, abs=1e-12) and qy == pytest.approx(-0.35, abs=1e-12)
    p, q = _line(fig, "locus_p").get_data()
    assert np.allclose(np.polyfit(p, q, 1)[1] / np.polyfit(p, q, 1)[0], np.tan(np.deg2rad(30.0)))  # through (-tan b, 0)
    pp, qp = _line(fig, "locus_p_printed").get_data()
    assert np.polyfit(pp, qp, 1)[0] == pytest.approx(np.polyfit(p, q, 1)[0] / np.cos(np.deg2rad(30.0)))
    assert "(p*, q*)" in cap
    _saved(fig, tmp_path, "fig18.png")


def test_figures_command_writes_the_stereo_figures(tmp_path, monkeypatch):
    """The figures command with its rendered figures stubbed out: the analytic stereo figures are
    written and captioned (the rendered ones are covered by tests/test_figures.py)."""
    from matplotlib.figure import Figure

    def stub(*_, **__):
        fig = Figure(figsize=(4, 3))
        fig.add_subplot().plot([0, 1], [0, 1])
        return fig, "stub caption " * 10, None

    for name in ("_fig03", "_fig04", "_fig05_printed", "_fig06_printed"):
        monkeypatch.setattr(figmod, name, lambda: stub()[:2])
    for name in ("_fig05", "_fig06"):
        monkeypatch.setattr(figmod, name, stub)
    monkeypatch.setattr(figmod, "_scan", lambda quick, progress: None)
    for name in ("_fig09b", "_fig10"):
        monkeypatch.setattr(figmod, name, lambda scan: stub()[:2])
    monkeypatch.setattr(figmod, "_fig12", lambda quick: stub()[:2])
    captions = figmod.make_figures(tmp_path, quick=True)
    assert set(STEREO_PNGS) <= set(figmod.FIGURE_FILES)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(figmod.FIGURE_FILES)
    stored = json.loads((tmp_path / "captions.json").read_text())["figures"]
    for name in STEREO_PNGS:
        assert (tmp_path / name).stat().st_size > 20_000, name
        assert "analytic" in captions[name] and stored[name] == captions[name]
