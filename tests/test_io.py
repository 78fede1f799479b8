"""Stack and truth files: round trips, and every malformed input named."""

import json

import numpy as np
import pytest

from shinysim.io import (
    Stack,
    StackFormatError,
    Truth,
    load_stack,
    load_truth,
    save_stack,
    save_truth,
    source_channel,
)
from shinysim.io import load_rig
from shinysim.rig import Camera, Rig, RigError


def small_rig(n=3, h=24, w=32):
    cam = Camera("orthographic", w, h, [0, 0, 10], [0, 0, 0], [0, 1, 0], 2.0)
    pos = np.stack([np.linspace(-10, 10, n), np.zeros(n), np.full(n, 40.0)], axis=1)
    return Rig(pos, np.full(n, 0.5), (cam,))


def small_stack(rng, n=3):
    rig = small_rig(n)
    frames = rng.uniform(0, 1, (n, 24, 32)).astype(np.float32)
    return Stack(frames, rig, provenance={"seed": 7})


def test_roundtrip_float16_precision(tmp_path, np_rng):
    st = small_stack(np_rng)
    save_stack(st, tmp_path / "stack.exr")
    back = load_stack(tmp_path / "stack.exr")
    assert back.rig == st.rig
    assert back.provenance["seed"] == 7
    # float16 has an 11-bit significand: relative rounding error <= 2**-11 < 1e-3
    err = np.abs(back.frames - st.frames).max() / st.frames.max()
    assert err <= 2.0**-11
    assert json.loads((tmp_path / "rig.json").read_text())["provenance"]["seed"] == 7


def test_roundtrip_float32_exact(tmp_path, np_rng):
    st = small_stack(np_rng)
    save_stack(st, tmp_path / "stack.exr", dtype="float32")
    np.testing.assert_array_equal(load_stack(tmp_path / "stack.exr").frames, st.frames)


def test_never_overwrites(tmp_path, np_rng):
    st = small_stack(np_rng)
    save_stack(st, tmp_path / "stack.exr")
    before = (tmp_path / "stack.exr").read_bytes(), (tmp_path / "rig.json").read_bytes()
    with pytest.raises(FileExistsError, match="not overwriting"):
        save_stack(small_stack(np.random.default_rng(9)), tmp_path / "stack.exr")
    assert ((tmp_path / "stack.exr").read_bytes(), (tmp_path / "rig.json").read_bytes()) == before
    # no temporary files left behind
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.json", "stack.exr"]


def test_truncated_exr(tmp_path, np_rng):
    save_stack(small_stack(np_rng), tmp_path / "stack.exr")
    data = (tmp_path / "stack.exr").read_bytes()
    for cut in (100, len(data) // 2, len(data) - 10):
        (tmp_path / "stack.exr").write_bytes(data[:cut])
        with pytest.raises(StackFormatError, match="corrupt or truncated"):
            load_stack(tmp_path / "stack.exr")


def test_not_an_exr(tmp_path, np_rng):
    save_stack(small_stack(np_rng), tmp_path / "stack.exr")
    (tmp_path / "stack.exr").write_text("hello")
    with pytest.raises(StackFormatError, match="not a readable OpenEXR"):
        load_stack(tmp_path / "stack.exr")
    with pytest.raises(StackFormatError, match="no such file"):
        load_stack(tmp_path / "missing.exr")


def test_missing_channel(tmp_path, np_rng):
    import OpenEXR

    st = small_stack(np_rng)
    save_stack(st, tmp_path / "stack.exr")
    channels = {source_channel(k): st.frames[k] for k in (0, 2)}
    (tmp_path / "stack.exr").unlink()
    with OpenEXR.File({"type": OpenEXR.scanlineimage}, channels) as f:
        f.write(str(tmp_path / "stack.exr"))
    with pytest.raises(StackFormatError, match="missing channel.*S001"):
        load_stack(tmp_path / "stack.exr")


def test_source_count_disagrees_with_rig(tmp_path, np_rng):
    save_stack(small_stack(np_rng, n=3), tmp_path / "stack.exr")
    small_rig(4).save(tmp_path / "rig4.json")
    with pytest.raises(StackFormatError, match="missing channel.*S003"):
        load_stack(tmp_path / "stack.exr", tmp_path / "rig4.json")
    small_rig(2).save(tmp_path / "rig2.json")
    with pytest.raises(StackFormatError, match="beyond the rig's 2 sources"):
        load_stack(tmp_path / "stack.exr", tmp_path / "rig2.json")


def test_size_disagrees_with_rig(tmp_path, np_rng):
    save_stack(small_stack(np_rng), tmp_path / "stack.exr")
    rig = load_rig(tmp_path / "rig.json")
    cam = rig.camera
    wrong = Camera(cam.projection, 33, 24, cam.position, cam.target, cam.up, cam.field_width)
    with pytest.raises(StackFormatError, match="display window is 24x32 .* but the camera is 24x33"):
        load_stack(tmp_path / "stack.exr", rig.with_camera(wrong))


def test_nan_frames_rejected(np_rng):
    rig = small_rig()
    frames = np_rng.uniform(0, 1, (3, 24, 32)).astype(np.float32)
    frames[1, 3, 4] = np.nan
    frames[2, 0, 0] = np.inf
    with pytest.raises(StackFormatError, match=r"2 NaN or inf pixel\(s\) in frame\(s\) S001 \(1\), S002 \(1\)"):
        Stack(frames, rig)


def test_nan_frames_in_file(tmp_path, np_rng):
    import OpenEXR

    st = small_stack(np_rng)
    save_stack(st, tmp_path / "stack.exr")
    frames = st.frames.copy()
    frames[0, 0, 0] = np.nan
    (tmp_path / "stack.exr").unlink()
    with OpenEXR.File({"type": OpenEXR.scanlineimage}, {source_channel(k): frames[k] for k in range(3)}) as f:
        f.write(str(tmp_path / "stack.exr"))
    with pytest.raises(StackFormatError, match=r"stack.exr: .*NaN or inf pixel\(s\) in frame\(s\) S000"):
        load_stack(tmp_path / "stack.exr")


def test_bad_rig_file_next_to_stack(tmp_path, np_rng):
    save_stack(small_stack(np_rng), tmp_path / "stack.exr")
    (tmp_path / "rig.json").write_text('{"sources": []')
    with pytest.raises(RigError, match="rig.json: .*not valid JSON"):
        load_stack(tmp_path / "stack.exr")
    (tmp_path / "rig.json").write_text('{"cameras": []}')
    with pytest.raises(RigError, match="rig.json: rig: missing required field.*sources"):
        load_stack(tmp_path / "stack.exr")
    (tmp_path / "rig.json").unlink()
    with pytest.raises(RigError, match="rig.json: no such file"):
        load_stack(tmp_path / "stack.exr")


def test_truth_roundtrip_and_errors(tmp_path, np_rng):
    mask = np.zeros((24, 32), bool)
    mask[5:10, 6:12] = True
    n = np.full((24, 32, 3), np.nan, np.float32)
    n[mask] = [0, 0, 1]
    p = np.full((24, 32, 3), np.nan, np.float32)
    p[mask] = np_rng.uniform(size=(mask.sum(), 3))
    t = Truth(n, p, mask)
    save_truth(t, tmp_path / "truth.exr")
    back = load_truth(tmp_path / "truth.exr", small_rig().camera)
    np.testing.assert_array_equal(back.mask, mask)
    np.testing.assert_array_equal(back.normals[mask], n[mask])
    np.testing.assert_array_equal(back.positions[mask], p[mask])
    with pytest.raises(FileExistsError):
        save_truth(t, tmp_path / "truth.exr")
    cam = Camera("orthographic", 10, 10, [0, 0, 10], [0, 0, 0], [0, 1, 0], 2.0)
    with pytest.raises(StackFormatError, match="display window is 24x32 .* but the camera is 10x10"):
        load_truth(tmp_path / "truth.exr", cam)
    with pytest.raises(StackFormatError, match="truth normals must have shape"):
        Truth(n[:, :5], p, mask)


def test_truth_missing_channel(tmp_path):
    import OpenEXR

    z = np.zeros((4, 4), np.float32)
    with OpenEXR.File({"type": OpenEXR.scanlineimage}, {"normal.X": z, "normal.Y": z}) as f:
        f.write(str(tmp_path / "truth.exr"))
    with pytest.raises(StackFormatError, match="missing truth channel.*normal.Z"):
        load_truth(tmp_path / "truth.exr")


def test_stack_shape_errors():
    rig = small_rig()
    with pytest.raises(StackFormatError, match="3 frames but the rig has|has 2 frames but the rig has 3"):
        Stack(np.zeros((2, 24, 32)), rig)
    with pytest.raises(StackFormatError, match=r"must be \(n_sources, H, W\)"):
        Stack(np.zeros((24, 32)), rig)


def test_truth_coverage_round_trips_and_is_checked(tmp_path):
    from shinysim.io import StackFormatError, Truth, load_truth, save_truth

    mask = np.zeros((4, 5), bool)
    mask[1:3, 1:4] = True
    normals = np.where(mask[..., None], np.array([0, 0, 1.0], np.float32), np.nan)
    cov = mask.astype(np.float32)
    cov[0, 1] = 0.25  # a silhouette pixel whose centre misses the object
    t = Truth(normals, normals, mask, coverage=cov)
    save_truth(t, tmp_path / "t.exr")
    back = load_truth(tmp_path / "t.exr")
    np.testing.assert_array_equal(back.coverage, cov)
    assert load_truth_without_coverage(tmp_path, normals, mask).coverage is None
    with pytest.raises(StackFormatError, match="coverage"):
        Truth(normals, normals, mask, coverage=cov * 2)


def load_truth_without_coverage(tmp_path, normals, mask):
    from shinysim.io import Truth, load_truth, save_truth

    save_truth(Truth(normals, normals, mask), tmp_path / "plain.exr")
    return load_truth(tmp_path / "plain.exr")
