"""``shinysim figures``: the paper's figures as captioned PNG files."""

import json

import numpy as np
import pytest
from conftest import assert_default_modes, requires_jit

from shinysim.cli import main
from shinysim.studies.figures import FIGURE_FILES

PNGS = [n for n in FIGURE_FILES if n.endswith(".png")]


@pytest.fixture(scope="module")
def quick_figures(tmp_path_factory):
    out = tmp_path_factory.mktemp("figures")
    rc = main(["figures", str(out), "--quick"])
    assert rc == 0
    return out


def test_figure_files_are_named_by_figure_number():
    numbers = {n.split("_")[0] for n in PNGS}
    assert numbers == {"fig03", "fig04", "fig05", "fig06", "fig09b", "fig10", "fig12", "fig13", "fig14", "fig16", "fig17",
                       "fig18"}


@pytest.mark.render
@requires_jit
def test_quick_figures_are_written_with_captions(quick_figures, capsys):
    import matplotlib.image as mpimg

    out = quick_figures
    for name in PNGS:
        img = mpimg.imread(out / name)
        assert img.ndim == 3 and min(img.shape[:2]) > 300, name
        # not a blank canvas
        assert np.ptp(img[..., :3]) > 0.5, name
    captions = json.loads((out / "captions.json").read_text())["figures"]
    assert list(captions) == PNGS
    for name, cap in captions.items():
        assert len(cap) > 80, name
    # each says what was computed
    assert "analytic" in captions["fig03_reflectance_map.png"]
    assert "rendered mirror facets" in captions["fig05_sensitivity.png"]
    assert "simulation" in captions["fig09b_highlights.png"] and "simulation" in captions["fig10_side_view.png"]
    assert "within 10 % or 0.02°" in captions["fig05_sensitivity.png"]
    readme = (out / "README.md").read_text()
    assert all(f"![{n}]({n})" in readme for n in PNGS)
    assert sorted(p.name for p in out.iterdir()) == sorted(FIGURE_FILES)
    assert_default_modes(out)


@pytest.mark.render
@requires_jit
def test_figures_never_overwrite(quick_figures, capsys):
    out = quick_figures
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    rc = main(["figures", str(out), "--quick"])
    assert rc == 1
    err = capsys.readouterr().err
    assert "already holds" in err and "--overwrite" in err and "fig03_reflectance_map.png" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_figures_refuse_before_rendering(tmp_path, capsys):
    (tmp_path / "fig10_side_view.png").write_bytes(b"mine")
    assert main(["figures", str(tmp_path)]) == 1
    assert "fig10_side_view.png" in capsys.readouterr().err
    assert [p.name for p in tmp_path.iterdir()] == ["fig10_side_view.png"]
    assert (tmp_path / "fig10_side_view.png").read_bytes() == b"mine"
