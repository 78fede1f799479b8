"""DiLiGenT folders: export, read back, photometric stereo on them, real photographs, bad folders."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import png
import pytest
from conftest import requires_jit
from scipy.io import savemat

import shinysim.io.diligent as dl
from shinysim.io.diligent import (
    DILIGENT_FILES,
    DiligentError,
    camera_frame,
    export_diligent,
    export_scan_folder,
    read_diligent,
    world_frame,
)
from shinysim.evaluate import angular_error_deg
from shinysim.io import Stack, Truth, save_stack, save_truth
from shinysim.rig import Camera, Rig, distant_rig, dome, fibonacci_hemisphere

# -- helpers ----------------------------------------------------------------------------


def sphere_truth(camera, radius, center=(0.0, 0.0, 0.0)):
    """Exact normals, points and mask of a sphere at a camera's pixel centres, and sub-pixel coverage."""
    H, W = camera.shape

    def hits(rows, cols):
        o, d = camera.pixel_rays(rows, cols)
        oc = o - np.asarray(center)
        b = np.sum(oc * d, axis=-1)
        disc = b * b - (np.sum(oc * oc, axis=-1) - radius**2)
        hit = disc >= 0
        t = -b - np.sqrt(np.where(hit, disc, 0.0))
        return o + t[..., None] * d, hit

    rows, cols = np.mgrid[0:H, 0:W].astype(float)
    points, hit = hits(rows, cols)
    normals = (points - np.asarray(center)) / radius
    normals[~hit] = np.nan
    points[~hit] = np.nan
    offsets = (np.arange(4) + 0.5) / 4 - 0.5
    coverage = np.mean([hits(rows + a, cols + b)[1] for a in offsets for b in offsets], axis=0)
    return Truth(normals, points, hit, coverage=coverage)


def lambertian_stack(rig, truth, albedo=0.8):
    """Frames of a Lambertian object under the rig's (distant) sources, exact at pixel centres."""
    n = np.nan_to_num(truth.normals.astype(float))
    shade = np.clip(np.einsum("hwc,kc->khw", n, rig.source_positions), 0.0, None)
    return Stack(albedo * shade * truth.mask, rig, 0, {"generator": "test: analytic Lambertian sphere"})


def solve_ps(ds, *, flip_y=False, shadow=0.05):
    """Least-squares photometric stereo on a read-back folder: per pixel, the lights whose value is above
    ``shadow`` of the pixel's brightest, ``I = L (rho n)``, normalised. NaN outside the mask."""
    L = ds.light_directions * ([1.0, -1.0, 1.0] if flip_y else 1.0)
    frames = ds.stack.frames.reshape(len(L), -1).T.astype(float)
    out = np.full((frames.shape[0], 3), np.nan)
    for p in np.flatnonzero(ds.mask.ravel()):
        v = frames[p]
        keep = v > shadow * v.max()
        if keep.sum() >= 3:
            b = np.linalg.lstsq(L[keep], v[keep], rcond=None)[0]
            out[p] = b / np.linalg.norm(b)
    return out.reshape(ds.mask.shape + (3,))


def geometric_normals(shape, center_rc, radius_px):
    """A sphere's normals from pixel positions alone, DiLiGenT frame (x right, y UP, z to the viewer)."""
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    u = (cols - center_rc[1]) / radius_px
    v = -(rows - center_rc[0]) / radius_px
    with np.errstate(invalid="ignore"):
        w = np.sqrt(1.0 - u**2 - v**2)
    return np.stack([u, v, w], axis=-1)


def write_png(path, array, bitdepth):
    a = np.asarray(array)
    with open(path, "wb") as fh:
        png.Writer(a.shape[1], a.shape[0], greyscale=a.ndim == 2, bitdepth=bitdepth).write(fh, a.reshape(a.shape[0],
                                                                                                           -1))


def read_png(path):
    with open(path, "rb") as fh:
        w, h, rows, meta = png.Reader(file=fh).read()
        return np.vstack([np.asarray(r, np.uint16) for r in rows]), meta


def top_camera(resolution=40, field_width=2.0):
    return Camera("orthographic", resolution, resolution, [0, 0, 100.0], [0, 0, 0], [0, 1, 0], field_width)


# -- frames -----------------------------------------------------------------------------


def test_camera_frame_is_the_world_for_a_top_camera_and_inverts():
    cam = top_camera()
    v = np.random.default_rng(0).normal(size=(20, 3))
    # the top camera (up +y, looking down -z): image right +x, image up +y, viewer +z, bit for bit
    assert np.array_equal(camera_frame(v, cam), v)
    # a camera turned so that image up is world +x: image right is then world -y
    turned = Camera("orthographic", 8, 8, [0, 0, 100.0], [0, 0, 0], [1, 0, 0], 2.0)
    np.testing.assert_allclose(camera_frame([[1, 0, 0], [0, -1, 0], [0, 0, 1]], turned), np.eye(3)[[1, 0, 2]],
                               atol=1e-15)
    np.testing.assert_allclose(world_frame(camera_frame(v, turned), turned), v, atol=1e-14)
    # a tilted perspective camera: the frame is orthonormal and right handed
    tilted = Camera("perspective", 8, 8, [30, -20, 100.0], [1, 2, 0], [0, 1, 0], 2.0)
    M = camera_frame(np.eye(3), tilted)
    np.testing.assert_allclose(M @ M.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(M) == pytest.approx(1.0)
    np.testing.assert_allclose(camera_frame(-tilted.forward, tilted), [0, 0, 1], atol=1e-14)


# -- 1. round trip without the renderer ----------------------------------------------------


def test_round_trip_of_an_analytic_lambertian_sphere(tmp_path):
    rig = dome(n_sources=24, radius_mm=None, resolution=48, projection="orthographic")
    truth = sphere_truth(rig.camera, 0.7)
    stack = lambertian_stack(rig, truth)
    summary = export_diligent(stack, tmp_path / "ball", truth=truth)
    names = [f"{k:03d}.png" for k in range(1, 25)]
    assert summary["n_images"] == 24 and summary["files"][:24] == names
    assert sorted(os.listdir(tmp_path / "ball")) == sorted(names + list(DILIGENT_FILES))
    assert (tmp_path / "ball" / "filenames.txt").read_text().split() == names

    ds = read_diligent(tmp_path / "ball")
    # directions are written to 8 decimals (|rounding| <= 5e-9 per component) and normalised again on
    # reading, which moves each component by at most another |v . e| <= 8.7e-9
    np.testing.assert_allclose(ds.light_directions, rig.source_positions, rtol=0, atol=1.5e-8)
    assert np.array_equal(ds.light_intensities, np.ones((24, 3)))  # distant sources: all equal
    assert ds.filenames == names
    assert np.array_equal(ds.mask, truth.mask)
    # the truth's float32 normals, in the (here identical) DiLiGenT frame, stored as float64: exact
    expected = np.where(truth.mask[..., None], truth.normals.astype(float), np.nan)
    assert np.array_equal(ds.normals, expected, equal_nan=True)
    assert np.array_equal(ds.truth.mask, truth.mask)
    assert np.array_equal(ds.truth.normals, truth.normals, equal_nan=True)
    # images: 16-bit codes of one global scale; back in stack units they are within half a code
    # (plus float32 rounding of values <= 0.8, ~5e-8)
    info = json.loads((tmp_path / "ball" / "shinysim.json").read_text())
    scale = info["scale"]
    assert scale == pytest.approx(summary["scale"]) == pytest.approx(65535 / stack.frames.max())
    back = ds.stack.frames.astype(float) * 65535 / scale
    assert np.abs(back - stack.frames).max() <= 0.5 / scale + 1e-7
    assert ds.stack.frames.max() == 1.0  # the peak maps to 65535
    # a rendered stack has no clip level; shinysim.json says so and the reader keeps it that way
    assert ds.stack.saturation is None and info["saturation"] is None
    assert info["frame"].startswith("DiLiGenT camera frame: x = image right, y = image up")
    # the reader's rig: the lights, distant, under an orthographic top camera
    assert ds.stack.rig.source_distant.all() and ds.stack.camera.projection == "orthographic"
    np.testing.assert_allclose(camera_frame(ds.light_directions, ds.stack.camera), ds.light_directions)
    # coverage.png: 16-bit grey, coverage * 65535
    cov, meta = read_png(tmp_path / "ball" / "coverage.png")
    assert meta["greyscale"] and meta["bitdepth"] == 16
    assert np.array_equal(cov, np.rint(truth.coverage * 65535).astype(np.uint16))
    # normal.txt: one pixel a row, rows top to bottom (what reshape(H, W, 3) reads), zeros outside
    txt = np.loadtxt(tmp_path / "ball" / "normal.txt").reshape(48, 48, 3)
    np.testing.assert_allclose(txt, np.nan_to_num(expected), rtol=0, atol=5e-9)


def test_near_sources_give_directions_and_irradiance_from_the_origin(tmp_path):
    rig = dome(n_sources=12, resolution=32, projection="orthographic")  # fibers 43.18 mm away
    truth = sphere_truth(rig.camera, 0.6)
    stack = Stack(np.random.default_rng(3).random((12, 32, 32)), rig)
    summary = export_diligent(stack, tmp_path / "near", truth=truth)
    origin = np.nanmean(truth.positions[truth.mask].astype(float), axis=0)  # default: mean surface point
    np.testing.assert_allclose(summary["origin_mm"], origin, atol=1e-12)
    ds = read_diligent(tmp_path / "near")
    to_src = rig.source_positions - origin
    dist = np.linalg.norm(to_src, axis=1)
    np.testing.assert_allclose(ds.light_directions, to_src / dist[:, None], atol=1.5e-8)  # see the round trip
    irr = np.pi * rig.source_radii**2 / dist**2  # sphere sources of equal radiance
    np.testing.assert_allclose(ds.light_intensities, np.repeat((irr / irr.max())[:, None], 3, 1), atol=5e-9)
    # a given origin: directions from it
    export_diligent(stack, tmp_path / "near2", truth=truth, origin_mm=[0.3, -0.2, 0.0])
    d2 = read_diligent(tmp_path / "near2").light_directions
    t2 = rig.source_positions - [0.3, -0.2, 0.0]
    np.testing.assert_allclose(d2, t2 / np.linalg.norm(t2, axis=1)[:, None], atol=1.5e-8)
    # without truth: the camera's target, no normals, mask = pixels lit in some image
    summary = export_diligent(stack, tmp_path / "bare")
    assert summary["origin_mm"] == [0.0, 0.0, 0.0]
    assert not (tmp_path / "bare" / "Normal_gt.mat").exists() and not (tmp_path / "bare" / "normal.txt").exists()
    bare = read_diligent(tmp_path / "bare")
    assert bare.normals is None and bare.truth is None
    assert np.array_equal(bare.mask, (np.rint(stack.frames * summary["scale"]) > 0).any(axis=0))


def test_export_of_a_scan_folder_picks_the_camera(tmp_path):
    cam0 = top_camera(24)
    cam1 = Camera("orthographic", 24, 24, [0, 0, 100.0], [0, 0, 0], [1, 0, 0], 2.0, name="turned")
    dirs = fibonacci_hemisphere(6)
    rig = Rig(dirs, np.zeros(6), (cam0, cam1), source_distant=np.ones(6, bool))
    scan = tmp_path / "scan"
    scan.mkdir()
    t1 = sphere_truth(cam1, 0.7)
    save_stack(lambertian_stack(rig, sphere_truth(cam0, 0.7)), scan / "stack.exr")
    s1 = Stack(lambertian_stack(rig, t1).frames, rig, 1)
    save_stack(s1, scan / "stack.camera1.exr", rig_path=scan / "rig1.json")
    save_truth(t1, scan / "truth.camera1.exr")
    export_scan_folder(scan, tmp_path / "c0")
    assert not (tmp_path / "c0" / "Normal_gt.mat").exists()  # camera 0 has no truth file
    export_scan_folder(scan, tmp_path / "c1", camera=1)
    ds = read_diligent(tmp_path / "c1")
    # camera 1's image up is world +x, its image right world -y: the DiLiGenT frame turns with it
    np.testing.assert_allclose(ds.light_directions, np.c_[-dirs[:, 1], dirs[:, 0], dirs[:, 2]], atol=1.5e-8)
    np.testing.assert_allclose(ds.normals, camera_frame(t1.normals, cam1), atol=1e-15)
    with pytest.raises(ValueError, match="camera must be in"):
        export_scan_folder(scan, tmp_path / "c2", camera=2)


# -- 2. conventions with the renderer -------------------------------------------------------

LAMBERTIAN_BALL = {"type": "sphere", "radius": 0.8, "center": [0.0, 0.0, 0.0],
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.8}}}


def _render_export_read(tmp_path, name, radius_mm):
    from shinysim.sim.render import Simulator

    rig = dome(n_sources=40, radius_mm=radius_mm, resolution=96, projection="orthographic")
    sim = Simulator(rig, {"object": LAMBERTIAN_BALL})
    # one-pass, 16 spp: distant sources sample exactly, the only noise is where in the pixel each sample
    # lands; the PS median is 0.28 deg at 1 spp, 0.05 at 16, 0.03 at 64 (measured), so 16 leaves 20x room
    stack = sim.render_stack(spp=16, seed=1)
    truth = sim.render_truth(coverage=4)
    export_diligent(stack, tmp_path / name, truth=truth)
    return read_diligent(tmp_path / name), stack, truth


def _wrong_frame(camera):
    """y along image DOWN: the mistake a y-flip bug makes."""
    return np.stack([camera.right, camera.down, -camera.forward])


@requires_jit
def test_photometric_stereo_on_a_rendered_lambertian_sphere(tmp_path, monkeypatch):
    ds, stack, truth = _render_export_read(tmp_path, "distant", None)
    inside = ds.mask
    err = angular_error_deg(solve_ps(ds), ds.normals)[inside]
    # distant dome, 16 spp: median 0.05 deg, p95 0.26 (measured), against the 1 deg asked for; the
    # silhouette pixels (partly covered: 2.4 % of the mask) err by degrees but do not move the median
    assert np.median(err) < 0.2
    # the check can fail: lights with y not flipped (image-down y) give normals 48 deg off (measured)
    assert np.median(angular_error_deg(solve_ps(ds, flip_y=True), ds.normals)[inside]) > 20
    # Normal_gt against the sphere's geometry from pixel positions alone (y UP): the exported frame
    # itself is right, not only consistent. Pixel-centre normals from float32 ray hits: 3e-4 deg at
    # most, rim included (measured)
    cam = ds.stack.camera
    center = ((cam.height - 1) / 2, (cam.width - 1) / 2)
    geo = geometric_normals(ds.mask.shape, center, 0.8 / (2.0 / 96))
    assert inside.sum() > 4000
    assert angular_error_deg(ds.normals, geo)[inside].max() < 0.01

    # a consistently wrong frame (y = image down for lights and normals alike) still passes the PS check
    # (a mirror image of lights and normals explains the same images) but fails the geometry by a lot
    monkeypatch.setattr(dl, "_frame_matrix", _wrong_frame)
    export_diligent(stack, tmp_path / "wrong", truth=truth)
    monkeypatch.undo()
    wrong = read_diligent(tmp_path / "wrong")
    assert np.median(angular_error_deg(solve_ps(wrong), wrong.normals)[inside]) < 0.2
    assert np.median(angular_error_deg(wrong.normals, geo)[inside]) > 20  # 48 deg (measured)


@requires_jit
def test_near_dome_breaks_the_distant_light_assumption(tmp_path):
    """The same sphere under the SHINY-size near dome (fibers 43 mm away).

    Measured: PS median 1.24 deg (p95 2.0) against 0.05 deg for the distant dome. DiLiGenT gives one
    direction and one intensity per light, true at the origin only; across the 1.6 mm sphere the
    direction to a fiber 43 mm away turns by up to +-1.1 deg and its irradiance changes by +-3.7 %
    (1/d^2). The same least squares on exact near-field shading computed in numpy (no renderer) gives
    1.25 deg: the error is the geometry, not the renderer.
    """
    near, _, truth = _render_export_read(tmp_path, "near", 1.7 * 25.4)  # the dome preset's 1.7 in
    err_near = float(np.median(angular_error_deg(solve_ps(near), near.normals)[near.mask]))
    # the same near-field shading computed exactly (pixel centres, per-pixel directions and 1/d^2)
    rig = dome(n_sources=40, resolution=96, projection="orthographic")
    p = truth.positions[truth.mask].astype(float)
    n = truth.normals[truth.mask].astype(float)
    to_src = rig.source_positions[None] - p[:, None]
    dist = np.linalg.norm(to_src, axis=-1)
    shade = np.clip(np.sum(n[:, None] * to_src / dist[..., None], axis=-1), 0, None) / dist**2
    exact = near.stack.frames.copy()
    exact[:, truth.mask] = (shade / near.light_intensities[:, 0]).T
    analytic = dl.DiligentSet(Stack(exact, near.stack.rig), near.mask, near.normals, None, near.light_directions,
                              near.light_intensities)
    err_analytic = float(np.median(angular_error_deg(solve_ps(analytic), near.normals)[near.mask]))
    assert 0.8 < err_near < 2.0  # loose: the figure is reported, not pinned
    assert abs(err_near - err_analytic) < 0.2



@requires_jit
def test_shinysim_reconstruction_on_an_exported_glossy_sphere(tmp_path):
    """The highlight reconstruction finds the same normals on the read-back folder as on the stack."""
    from shinysim.evaluate import score_reconstruction
    from shinysim.recon import DetectParams, reconstruct
    from shinysim.sim.render import Simulator
    from shinysim.sim.scene import sphere_object

    rig = dome(n_sources=40, radius_mm=None, resolution=128, projection="orthographic")
    sim = Simulator(rig, sphere_object(radius=0.8, alpha=0.02))
    stack, truth = sim.render_stack(spp=16, seed=0), sim.render_truth()
    export_diligent(stack, tmp_path / "glossy", truth=truth)
    ds = read_diligent(tmp_path / "glossy")
    params = DetectParams(threshold=0.5)
    direct = reconstruct(stack, params, mask=truth.mask)
    via = reconstruct(ds.stack, params, mask=ds.mask)
    assert len(via) == len(direct) == 40
    # 16-bit codes move a highlight's centroid by 5e-6 px and its normal by 2e-7 deg (measured)
    assert angular_error_deg(via.normals["fixed"], direct.normals["fixed"]).max() < 1e-4
    s_via, s_direct = score_reconstruction(via, ds.truth)["fixed"], score_reconstruction(direct, truth)["fixed"]
    assert s_via["n_invalid"] == 0 and s_via["median_deg"] == pytest.approx(s_direct["median_deg"], abs=1e-4)
    assert s_via["median_deg"] < 0.3  # 0.15 deg (measured): alpha 0.02 highlights at 128 px

# -- 3. real photographs -----------------------------------------------------------------------


def chrome_as_diligent(chrome_dir, out, *, flip_y=False):
    """The psmImages chrome sphere written in the DiLiGenT layout with plain numpy and pypng.

    8-bit RGB PNGs (PIL reads the bottom-left-origin TGAs with row 0 at the top), a grey 0/255 mask
    (the anti-aliased mask cut at half), lights.txt's rows as they are: SOURCE.md establishes that
    its frame is x image right, y image UP, z towards the camera, which is DiLiGenT's. Intensities 1.
    """
    from PIL import Image

    out.mkdir()
    names = []
    for k in range(12):
        with Image.open(chrome_dir / "chrome" / f"chrome.{k}.tga") as im:
            rgb = np.asarray(im.convert("RGB"))
        names.append(f"{k + 1:03d}.png")
        write_png(out / names[-1], rgb, 8)
    with Image.open(chrome_dir / "chrome" / "chrome.mask.tga") as im:
        mask = np.asarray(im.convert("L")) > 127
    write_png(out / "mask.png", np.where(mask, 255, 0).astype(np.uint8), 8)
    lights = np.loadtxt(chrome_dir / "lights.txt", skiprows=1)
    if flip_y:
        lights = lights * [1, -1, 1]
    (out / "light_directions.txt").write_text("".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in lights.tolist()) + "\n\n")
    (out / "light_intensities.txt").write_text("1 1 1\n" * 12)
    (out / "filenames.txt").write_text("\n".join(names) + "\n")
    return lights


def test_real_chrome_sphere_in_diligent_layout(chrome_dir, tmp_path):
    from shinysim.recon import DetectParams, reconstruct
    from shinysim.recon.sphere import sphere_from_mask

    lights = chrome_as_diligent(chrome_dir, tmp_path / "chrome")
    ds = read_diligent(tmp_path / "chrome")
    assert ds.stack.frames.shape == (12, 340, 512) and ds.stack.saturation == 1.0  # 8-bit, intensities 1
    np.testing.assert_allclose(ds.light_directions, lights / np.linalg.norm(lights, axis=1)[:, None], atol=1e-12)
    # the thresholds test_real_chrome.py uses on these photographs
    params = DetectParams(threshold=0.9, saturation=1.0, min_area=20)
    recon = reconstruct(ds.stack, params, mask=ds.mask)
    assert len(recon) == 12 and list(recon.table["source"]) == list(range(12))
    center, radius = sphere_from_mask(ds.mask)
    # SOURCE.md: centre (row 147.77, col 253.27), radius 119.49 px (the mask's area)
    assert center == pytest.approx([147.77, 253.27], abs=0.1) and radius == pytest.approx(119.49, abs=0.1)
    assert ds.mask[np.rint(recon.table["row"]).astype(int), np.rint(recon.table["col"]).astype(int)].all()
    # the sphere's normal at each highlight centroid from its image position alone: x right, y UP
    uv = np.c_[recon.table["col"] - center[1], -(recon.table["row"] - center[0])] / radius
    geo = np.c_[uv, np.sqrt(1 - (uv**2).sum(axis=1))]
    err = angular_error_deg(recon.normals["fixed"], geo)
    # the figures test_real_chrome.py establishes: lights.txt is itself only a few degrees accurate
    # (SOURCE.md: mean 1.57, max 4.32 deg)
    assert 1.0 < err.mean() < 2.0 and err.max() < 5.0
    # the world of the read set is the DiLiGenT frame: 'fixed' normals bisect +z and the light
    h = lights / np.linalg.norm(lights, axis=1)[:, None] + [0, 0, 1]
    np.testing.assert_allclose(recon.normals["fixed"], h / np.linalg.norm(h, axis=1)[:, None], atol=1e-9)

    # the test can fail: the same photographs with lights.txt read as y DOWN are off by ~21 deg (SOURCE.md)
    chrome_as_diligent(chrome_dir, tmp_path / "flipped", flip_y=True)
    flipped = reconstruct(read_diligent(tmp_path / "flipped").stack, params, mask=ds.mask)
    assert angular_error_deg(flipped.normals["fixed"], geo).mean() > 10


# -- 4. what the reader accepts, and bad folders ---------------------------------------------------

N_SMALL, H_SMALL, W_SMALL = 4, 5, 6


@pytest.fixture
def small(tmp_path):
    """A valid hand-written 4-image DiLiGenT folder, 5 x 6 pixels, 16-bit RGB."""
    folder = tmp_path / "obj"
    folder.mkdir()
    rng = np.random.default_rng(7)
    images = rng.integers(0, 65536, size=(N_SMALL, H_SMALL, W_SMALL, 3), dtype=np.uint16)
    names = [f"{k + 1:03d}.png" for k in range(N_SMALL)]
    for name, img in zip(names, images):
        write_png(folder / name, img, 16)
    (folder / "filenames.txt").write_text("\n".join(names) + "\n")
    dirs = np.array([[0.1, 0.2, 0.97], [-0.3, 0.1, 0.95], [0.2, -0.4, 0.9], [0.0, 0.0, 1.0]])
    (folder / "light_directions.txt").write_text("".join(" ".join(map(str, d)) + "\n" for d in dirs))
    (folder / "light_intensities.txt").write_text("1.0 2.0 4.0\n" * N_SMALL)
    mask = np.zeros((H_SMALL, W_SMALL), bool)
    mask[1:4, 1:5] = True
    write_png(folder / "mask.png", np.where(mask, 255, 0).astype(np.uint8), 8)
    normals = np.zeros((H_SMALL, W_SMALL, 3))
    normals[mask] = [0.0, 0.6, 0.8]
    savemat(folder / "Normal_gt.mat", {"Normal_gt": normals})
    return {"folder": folder, "images": images, "dirs": dirs, "mask": mask, "normals": normals, "names": names}


def test_small_folder_reads_as_the_readers_read_it(small):
    ds = read_diligent(small["folder"])
    # each channel / 65535 / its intensity (R 1, G 2, B 4), then the mean over R, G, B
    expected = np.mean(small["images"] / 65535.0 / [1.0, 2.0, 4.0], axis=-1)
    np.testing.assert_allclose(ds.stack.frames, expected, rtol=1e-7)
    np.testing.assert_allclose(ds.light_directions, small["dirs"] / np.linalg.norm(small["dirs"], axis=1)[:, None])
    assert np.array_equal(ds.mask, small["mask"])
    assert np.array_equal(np.nan_to_num(ds.normals), small["normals"])
    assert np.isnan(ds.normals[~small["mask"]]).all()
    assert ds.stack.saturation == pytest.approx(np.mean([1.0, 0.5, 0.25]))  # a saturated pixel: 1/I averaged
    assert ds.truth.positions.shape == (H_SMALL, W_SMALL, 3) and np.isnan(ds.truth.positions).all()


def test_reader_accepts_what_users_bring(small):
    folder = small["folder"]
    # 8-bit grey images, no filenames.txt (numbered images in number order), no intensities, CRLF and
    # blank lines in the light file, commas, a 1-bit mask, normals only in normal.txt
    grey = (small["images"][..., 0] >> 8).astype(np.uint8)
    for name, img in zip(small["names"], grey):
        write_png(folder / name, img, 8)
    (folder / "filenames.txt").unlink()
    (folder / "light_intensities.txt").unlink()
    (folder / "Normal_gt.mat").unlink()
    rows = [",".join(map(str, d)) for d in small["dirs"]]
    (folder / "light_directions.txt").write_bytes(("\r\n".join(rows[:2]) + "\r\n\r\n" + "\n".join(rows[2:])
                                                   + "\n\n\n").encode())
    with open(folder / "mask.png", "wb") as fh:
        png.Writer(W_SMALL, H_SMALL, greyscale=True, bitdepth=1).write(fh, small["mask"].astype(np.uint8))
    np.savetxt(folder / "normal.txt", small["normals"].reshape(-1, 3))
    ds = read_diligent(folder)
    np.testing.assert_allclose(ds.stack.frames, grey / 255.0, rtol=1e-7)
    assert np.array_equal(ds.light_intensities, np.ones((N_SMALL, 3)))
    assert ds.filenames == small["names"]
    assert np.array_equal(ds.mask, small["mask"])
    assert np.array_equal(np.nan_to_num(ds.normals), small["normals"])
    assert ds.stack.saturation == 1.0
    # no mask.png: every pixel; RGBA images: alpha is not intensity
    (folder / "mask.png").unlink()
    rgba = np.concatenate([small["images"], np.full((N_SMALL, H_SMALL, W_SMALL, 1), 7, np.uint16)], axis=-1)
    for name, img in zip(small["names"], rgba):
        with open(folder / name, "wb") as fh:
            png.Writer(W_SMALL, H_SMALL, greyscale=False, alpha=True, bitdepth=16).write(fh, img.reshape(H_SMALL, -1))
    ds = read_diligent(folder)
    assert ds.mask.all()
    np.testing.assert_allclose(ds.stack.frames, small["images"].mean(axis=-1) / 65535.0, rtol=1e-6)


def refused(folder, name, field, match=None):
    """read_diligent raises DiligentError naming the file ``name`` and the field; the message for a user."""
    with pytest.raises(DiligentError) as info:
        read_diligent(folder)
    exc = info.value
    assert exc.path is not None and os.path.basename(exc.path) == name, str(exc)
    assert exc.field == field, str(exc)
    assert f"{name}: {field + ': ' if field else ''}" in str(exc)
    if match:
        assert match in str(exc), str(exc)
    return str(exc)


def set_row(path, k, text):
    lines = path.read_text().splitlines()
    lines[k - 1] = text
    path.write_text("\n".join(lines) + "\n")


def test_light_file_rows(small):
    f = small["folder"]
    ld = f / "light_directions.txt"
    set_row(ld, 3, "0.1 0.2")
    refused(f, "light_directions.txt", "row 3", "not 3 numbers")
    set_row(ld, 3, "0.1 0.2 zero")
    refused(f, "light_directions.txt", "row 3", "not 3 numbers")
    set_row(ld, 3, "0 0 0")
    refused(f, "light_directions.txt", "row 3", "zero vector")
    set_row(ld, 3, "0.1 nan 0.9")
    refused(f, "light_directions.txt", "row 3", "not finite")
    set_row(ld, 3, "0.1 inf 0.9")
    refused(f, "light_directions.txt", "row 3", "not finite")
    set_row(ld, 3, "0.1 0.2 0.9")
    li = f / "light_intensities.txt"
    set_row(li, 2, "1 -0.5 1")
    refused(f, "light_intensities.txt", "row 2", "negative intensity")
    set_row(li, 2, "1 0 1")
    refused(f, "light_intensities.txt", "row 2", "zero intensity")
    li.write_text("\n\n")
    refused(f, "light_intensities.txt", "rows", "holds no rows")
    li.unlink()
    ld.unlink()
    refused(f, "light_directions.txt", None, "no such file")


def test_counts_must_agree(small):
    f = small["folder"]
    lines = (f / "light_directions.txt").read_text().splitlines()
    (f / "light_directions.txt").write_text("\n".join(lines[:3]) + "\n")
    refused(f, "light_directions.txt", "rows", "has 3 rows but there are 4 images (filenames.txt)")
    (f / "light_directions.txt").write_text("\n".join(lines) + "\n")
    (f / "light_intensities.txt").write_text("1 1 1\n" * 5)
    refused(f, "light_intensities.txt", "rows", "has 5 rows but there are 4 images")
    (f / "light_intensities.txt").write_text("1 1 1\n" * 4)
    (f / "filenames.txt").write_text("001.png\n002.png\n003.png\n")
    refused(f, "light_directions.txt", "rows", "has 4 rows but there are 3 images")
    # without filenames.txt the numbered images are counted
    (f / "filenames.txt").unlink()
    (f / "004.png").unlink()
    refused(f, "light_directions.txt", "rows", "but there are 3 images (numbered images (no filenames.txt))")


def test_images_missing_unreadable_or_of_different_sizes(small):
    f = small["folder"]
    (f / "filenames.txt").write_text("001.png\n002.png\n003.png\nlight_004.png\n")
    refused(f, "light_004.png", "image", "no such file (image 4 of 4, listed by filenames.txt)")
    (f / "filenames.txt").write_text("001.png\n002.png\n003.png\n../004.png\n")
    refused(f, "filenames.txt", "line 4", "is not a file of the folder")
    (f / "filenames.txt").write_text("\n".join(small["names"]) + "\n")
    write_png(f / "003.png", np.zeros((H_SMALL + 1, W_SMALL, 3), np.uint16), 16)
    refused(f, "003.png", "size", "is 6x6 (H x W) but 001.png is 5x6")
    (f / "003.png").write_bytes(b"not a png at all")
    refused(f, "003.png", "image", "not a readable PNG image")
    good = (f / "002.png").read_bytes()
    (f / "003.png").write_bytes(good[: len(good) // 2])  # truncated in the data stream
    refused(f, "003.png", "image", "not a readable PNG image")
    (f / "003.png").write_bytes(good)
    (f / "003.png").unlink()
    (f / "003.png").mkdir()
    refused(f, "003.png", "image", "is a folder")
    shutil.rmtree(f / "003.png")
    (f / "003.png").write_bytes(good)
    write_png(f / "mask.png", np.zeros((H_SMALL, W_SMALL + 2), np.uint8), 8)
    refused(f, "mask.png", "size", "is 5x8 (H x W) but the images are 5x6")
    (f / "mask.png").write_bytes(b"\x89PNG garbage")
    refused(f, "mask.png", "mask", "not a readable PNG image")
    # no filenames.txt and no numbered images
    for p in f.glob("*.png"):
        p.unlink()
    (f / "filenames.txt").unlink()
    refused(f, "obj", None, "has no filenames.txt and no numbered images")


def test_normal_files(small):
    f = small["folder"]
    savemat(f / "Normal_gt.mat", {"normals": small["normals"]})
    refused(f, "Normal_gt.mat", "Normal_gt", "has no variable Normal_gt (found normals)")
    savemat(f / "Normal_gt.mat", {"Normal_gt": small["normals"][:, :4]})
    refused(f, "Normal_gt.mat", "Normal_gt", "has shape (5, 4, 3); the images need (5, 6, 3)")
    savemat(f / "Normal_gt.mat", {"Normal_gt": np.full((H_SMALL, W_SMALL, 3), np.inf)})
    refused(f, "Normal_gt.mat", "Normal_gt", "infinite")
    (f / "Normal_gt.mat").write_bytes(b"MATLAB 5.0 MAT-file, but then nothing")
    refused(f, "Normal_gt.mat", None, "not a readable MATLAB file")
    (f / "Normal_gt.mat").unlink()
    np.savetxt(f / "normal.txt", small["normals"].reshape(-1, 3)[:-1])
    refused(f, "normal.txt", "rows", "has 29 rows; the 5x6 images need 30")
    rows = ["0 0 1"] * 30
    rows[11] = "0 0"
    (f / "normal.txt").write_text("\n".join(rows) + "\n")
    refused(f, "normal.txt", "row 12", "not 3 numbers")


def test_not_a_folder_and_bad_options(tmp_path, small):
    refused(tmp_path / "nowhere", "nowhere", None, "no such folder")
    (tmp_path / "file").write_text("x")
    refused(tmp_path / "file", "file", None, "is not a folder")
    with pytest.raises(ValueError, match="pixel_pitch_mm must be > 0"):
        read_diligent(small["folder"], pixel_pitch_mm=0)
    (small["folder"] / "light_directions.txt").write_bytes(b"\xff\xfe\x00garbage")
    refused(small["folder"], "light_directions.txt", None, "is not UTF-8 text")


# -- 5. writing: never clobber, never half a folder --------------------------------------------------


def small_export():
    rig = distant_rig(fibonacci_hemisphere(5), top_camera(16))
    truth = sphere_truth(rig.camera, 0.8)
    return lambertian_stack(rig, truth), truth


def listing(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())} if folder.exists() else None


def test_export_never_overwrites_unless_asked(tmp_path):
    stack, truth = small_export()
    out = tmp_path / "obj"
    export_diligent(stack, out, truth=truth)
    before = listing(out)
    brighter = Stack(stack.frames * 0.5 + (stack.frames > 0) * 0.1, stack.rig)
    with pytest.raises(FileExistsError, match="already holds 001.png"):
        export_diligent(brighter, out, truth=truth)
    assert listing(out) == before
    export_diligent(brighter, out, truth=truth, overwrite=True)
    assert listing(out)["001.png"] != before["001.png"]
    # an export that would leave files of the earlier one behind (normals it does not write, more images)
    # is refused even with overwrite: the folder would contradict itself
    with pytest.raises(FileExistsError, match="Normal_gt.mat, coverage.png, normal.txt from an earlier export"):
        export_diligent(stack, out, overwrite=True)
    fewer = Stack(stack.frames[:3], distant_rig(fibonacci_hemisphere(5)[:3], stack.camera))
    with pytest.raises(FileExistsError, match="004.png, 005.png"):
        export_diligent(fewer, out, truth=truth, overwrite=True)
    # unrelated files in the folder are left alone
    other = tmp_path / "mixed"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    export_diligent(stack, other, truth=truth)
    assert (other / "notes.txt").read_text() == "mine" and (other / "005.png").exists()


def test_interrupted_export_leaves_nothing(tmp_path, monkeypatch):
    stack, truth = small_export()
    written = []
    real = dl._write_png

    def interrupted(path, array, *, bitdepth):
        if len(written) == 3:
            raise KeyboardInterrupt
        written.append(path.name)
        real(path, array, bitdepth=bitdepth)

    monkeypatch.setattr(dl, "_write_png", interrupted)
    with pytest.raises(KeyboardInterrupt):
        export_diligent(stack, tmp_path / "new" / "obj", truth=truth)
    assert written == ["001.png", "002.png", "003.png"]
    assert os.listdir(tmp_path) == []  # no folder, no hidden partial folder, not even the parent it made
    # into an existing export with overwrite: the earlier files stay as they were
    monkeypatch.undo()
    export_diligent(stack, tmp_path / "obj", truth=truth)
    before = listing(tmp_path / "obj")
    written.clear()
    monkeypatch.setattr(dl, "_write_png", interrupted)
    with pytest.raises(KeyboardInterrupt):
        export_diligent(Stack(stack.frames * 0.5, stack.rig), tmp_path / "obj", truth=truth, overwrite=True)
    assert listing(tmp_path / "obj") == before
    assert os.listdir(tmp_path) == ["obj"]


def test_export_refuses_bad_arguments(tmp_path):
    stack, truth = small_export()
    with pytest.raises(ValueError, match="stack must be a shinysim.io.Stack"):
        export_diligent(stack.frames, tmp_path / "a")
    with pytest.raises(ValueError, match="truth is 8x8"):
        export_diligent(stack, tmp_path / "a", truth=sphere_truth(top_camera(8), 0.5))
    with pytest.raises(ValueError, match="origin_mm must be 3 finite numbers"):
        export_diligent(stack, tmp_path / "a", origin_mm=[0, np.nan, 0])
    assert not (tmp_path / "a").exists()
