"""Highlight detection against blobs with known centres."""

import numpy as np
import pytest

from shinysim.recon import DetectParams, FrameError, detect_highlights


def gaussian(shape, center, sigma, amp=1.0):
    r, c = np.indices(shape, dtype=float)
    return amp * np.exp(-((r - center[0]) ** 2 + (c - center[1]) ** 2) / (2 * sigma**2))


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint8, np.uint16])
def test_gaussian_centroid(dtype):
    # a symmetric blob: its weighted centroid is its centre, up to the
    # quantisation of integer dtypes and the threshold's cut (symmetric too)
    center = (20.3, 31.7)
    img = gaussian((48, 64), center, 2.0)
    if np.issubdtype(dtype, np.integer):
        img = img * np.iinfo(dtype).max
    img = img.astype(dtype)
    h = detect_highlights(img, threshold=0.05)
    assert len(h["row"]) == 1
    # the 5% cut of a sigma=2 Gaussian removes a nearly symmetric rim: < 0.05 px
    assert h["row"][0] == pytest.approx(center[0], abs=0.05)
    assert h["col"][0] == pytest.approx(center[1], abs=0.05)
    assert h["peak"][0] == pytest.approx(img.max())


def test_plain_centroid_of_a_square():
    img = np.zeros((20, 20))
    img[4:8, 10:16] = np.linspace(1, 2, 6)  # intensity ramp along col
    plain = detect_highlights(img, threshold=0.1, centroid="plain")
    weighted = detect_highlights(img, threshold=0.1)
    assert (plain["row"][0], plain["col"][0]) == pytest.approx((5.5, 12.5))
    assert weighted["col"][0] > 12.5  # pulled towards the bright side
    assert plain["area"][0] == 24


def test_threshold_modes_and_min_area():
    img = gaussian((40, 40), (10, 10), 1.5) + gaussian((40, 40), (30, 28), 1.5, 0.3)
    rel = detect_highlights(img, threshold=0.5)
    assert len(rel["row"]) == 1  # the faint blob is below half the frame peak
    absolute = detect_highlights(img, threshold=0.1, threshold_mode="absolute")
    assert len(absolute["row"]) == 2
    big_only = detect_highlights(img, threshold=0.1, threshold_mode="absolute", min_area=25)
    assert len(big_only["row"]) == 1


def test_subdivision_of_large_blob():
    img = np.zeros((30, 60))
    img[10:14, 5:55] = 1.0  # a 4 x 50 streak
    whole = detect_highlights(img, threshold=0.5)
    parts = detect_highlights(img, threshold=0.5, max_area=50)
    assert len(whole["row"]) == 1
    assert len(parts["row"]) == 4  # ceil(200 / 50)
    assert parts["area"].sum() == 200
    assert set(parts["blob"]) == {1} and sorted(parts["part"]) == [1, 2, 3, 4]
    # equal parts along the streak: centroids at cols 11, 23.5, 36, 48.5 (+-0.5 for the cut)
    np.testing.assert_allclose(np.sort(parts["col"]), [11.0, 23.5, 36.0, 48.5], atol=0.6)


def test_empty_frame_gives_no_highlights():
    h = detect_highlights(np.zeros((10, 10)))
    assert all(len(v) == 0 for v in h.values())


def test_bad_frames():
    with pytest.raises(FrameError, match="NaN or inf"):
        detect_highlights(np.full((5, 5), np.nan))
    with pytest.raises(FrameError, match="must be 2-D"):
        detect_highlights(np.zeros((2, 5, 5)))
    sat = np.ones((10, 10))
    with pytest.raises(FrameError, match="frame is over-exposed"):
        detect_highlights(sat, saturation=1.0, name="S004")
    ok = np.zeros((10, 10))
    ok[2, 2] = 1.0  # one clipped pixel is a highlight, not a saturated frame
    assert len(detect_highlights(ok, saturation=1.0)["row"]) == 1


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"threshold_mode": "otsu"}, "threshold_mode must be one of"),
        ({"centroid": "median"}, "centroid must be one of"),
        ({"threshold": 0}, r"threshold must be in \(0, 1\]"),
        ({"threshold": 2.0}, "relative threshold"),
        ({"min_area": 0}, "min_area"),
        ({"max_area": 0}, "max_area"),
    ],
)
def test_invalid_params(kwargs, message):
    with pytest.raises(ValueError, match=message):
        DetectParams(**kwargs)


# -- the engine (find_regions / Regions) on known answers ------------------------------------------


def test_discs_at_known_sub_pixel_centres():
    """Digital discs centred between pixels (x.5) and on them are symmetric: their plain centroid is the centre
    exactly (to float64 rounding of sums of a few hundred integers: 1e-12 px), their area the pixel count."""
    from shinysim.recon.detect import find_regions

    rows, cols = np.indices((80, 90))
    centres = [(20.5, 30.5), (50.0, 20.0), (60.5, 70.0)]
    above = np.zeros((80, 90), bool)
    for (r, c), radius in zip(centres, (6.3, 4.0, 9.1)):
        above |= np.hypot(rows - r, cols - c) <= radius
    regions = find_regions(above)
    assert len(regions) == 3
    # labels in raster order of each region's first pixel
    order = np.argsort([r - radius for (r, _), radius in zip(centres, (6.3, 4.0, 9.1))])
    np.testing.assert_allclose(regions.centroid(), np.array(centres)[order], rtol=0, atol=1e-12)
    assert regions.area.sum() == above.sum()
    np.testing.assert_array_equal(regions.label, [1, 2, 3])
    np.testing.assert_array_equal(regions.label_image() > 0, above)


def test_gaussians_at_known_sub_pixel_centres_in_a_stack():
    """Gaussians at sub-pixel centres, one per frame of a stack labelled at once: each weighted centroid is its
    centre to 0.01 px (the threshold's cut of the sampled Gaussian is nearly symmetric), frames never joined."""
    from shinysim.recon.detect import find_regions

    rng = np.random.default_rng(3)
    centres = rng.uniform(12, 36, (5, 2))
    frames = np.stack([gaussian((48, 48), c, 1.7) for c in centres])
    frames[2] += gaussian((48, 48), centres[2], 1.7)  # same place in two frames: still two regions
    regions = find_regions(frames >= 1e-4)
    assert len(regions) == 5
    np.testing.assert_array_equal(regions.frame, np.arange(5))
    cog = regions.centroid(regions.values(frames))
    np.testing.assert_allclose(cog, centres, rtol=0, atol=0.01)
    np.testing.assert_allclose(regions.max(regions.values(frames)), frames.max(axis=(1, 2)), rtol=0, atol=0)
    np.testing.assert_allclose(regions.sum(regions.values(frames)), [f[f >= 1e-4].sum() for f in frames],
                               rtol=1e-12)


def test_regions_match_skimage_regionprops():
    """Labels, areas, bounding boxes and centroids of random blobs are skimage's (centroids to 1e-9 px)."""
    from skimage import measure

    from shinysim.recon.detect import find_regions

    rng = np.random.default_rng(5)
    for connectivity in (1, 2):
        img = rng.random((40, 50))
        above = img > 0.7
        regions = find_regions(above, connectivity)
        labels = measure.label(above, connectivity=connectivity)
        props = measure.regionprops(labels, intensity_image=img)
        np.testing.assert_array_equal(regions.label_image(), labels)
        assert [p.area for p in props] == regions.area.tolist()
        np.testing.assert_array_equal(regions.bbox(), [p.bbox for p in props])
        np.testing.assert_allclose(regions.centroid(regions.values(img)), [p.centroid_weighted for p in props],
                                   rtol=0, atol=1e-9)


def test_highlight_threshold_keeps_a_dim_highlight_beside_a_bright_one():
    """Two Gaussian highlights in one frame, the second at a fifth of the first's peak (a small element beside a
    large one): a level relative to the frame's peak (0.5) loses the dim one; ``"highlight"`` cuts each at half
    its own peak, so both are found, each where the frame-relative threshold puts it when it is alone in its
    frame (the same pixels and weights: equal to rounding)."""
    rows, cols = np.indices((64, 64))

    def spot(centre, peak):
        return peak * np.exp(-((rows - centre[0]) ** 2 + (cols - centre[1]) ** 2) / (2 * 1.5**2))

    bright, dim = spot((20.3, 18.6), 1.0), spot((41.7, 44.2), 0.2)
    frame = bright + dim
    assert len(detect_highlights(frame, threshold=0.5)) == 1
    found = detect_highlights(frame, threshold=0.5, threshold_mode="highlight")
    assert len(found) == 2
    alone = [detect_highlights(f, threshold=0.5) for f in (bright, dim)]
    order = np.argsort(found["row"])
    for k, one in zip(order, alone):
        assert len(one) == 1
        # each spot's tail adds under 1e-60 of its peak at the other's pixels
        np.testing.assert_allclose([found["row"][k], found["col"][k]], [one["row"][0], one["col"][0]],
                                   rtol=0, atol=1e-9)
    assert not found["cut"].any()


def test_a_highlight_cut_by_the_border_is_flagged():
    """A highlight whose region reaches the frame's edge is ``cut`` (its centroid is not its centre); one wholly
    inside is not."""
    rows, cols = np.indices((40, 40))
    frame = sum(np.exp(-((rows - r) ** 2 + (cols - c) ** 2) / (2 * 1.5**2)) for r, c in ((0.5, 20.0), (25.0, 25.0)))
    found = detect_highlights(frame, threshold=0.5, threshold_mode="highlight")
    assert len(found) == 2
    np.testing.assert_array_equal(found["cut"][np.argsort(found["row"])], [True, False])
