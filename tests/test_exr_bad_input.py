"""Stack and truth EXR files as a careless or hostile user writes them: one named test per class.

Every case gives either the right frames or a ``StackFormatError`` (a
``ValueError``) whose message starts with the file and names the field or
channel. Byte-level fuzzing is in ``tests/test_fuzz_readers.py``.
"""

from __future__ import annotations

import json

import numpy as np
import OpenEXR
import pytest
from test_io import small_rig  # the round-trip tests' 3-source, 24 x 32 rig

from shinysim.errors import OptionError, RigError, StackFormatError
from shinysim.io import (
    Stack,
    Truth,
    choose_stack_dtype,
    load_stack,
    load_truth,
    save_stack,
    save_truth,
    source_channel,
)

H, W = 24, 32


def spot_frames(n=3, where=((5, 6), (10, 20), (18, 9))):
    yy, xx = np.mgrid[0:H, 0:W]
    return np.stack([np.exp(-((yy - r) ** 2 + (xx - c) ** 2) / 4.0) for r, c in where[:n]]).astype(np.float32)


def write_exr(path, channels, **header):
    h = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    h.update(header)
    with OpenEXR.File(h, channels) as f:
        f.write(str(path))


def stack_channels(frames):
    # OpenEXR's Python binding reads the array's buffer: views must be made contiguous
    return {source_channel(k): np.ascontiguousarray(f) for k, f in enumerate(frames)}


def small_truth():
    """A hemisphere of radius 10 px seen from above: unit normals inside the mask."""
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    x, y = (xx - 16) / 10, (yy - 12) / 10
    mask = x**2 + y**2 < 1
    z = np.sqrt(np.clip(1 - x**2 - y**2, 0, 1))
    normals = np.where(mask[..., None], np.stack([x, -y, z], -1), np.nan)
    positions = np.where(mask[..., None], np.stack([x, -y, z], -1), np.nan)
    return Truth(normals, positions, mask)


@pytest.fixture
def folder(tmp_path):
    small_rig().save(tmp_path / "rig.json")
    return tmp_path


def test_data_window_offset_is_honoured(folder):
    """A stack stored with a data window shifted by (dx, dy) = (10, 5) inside a full display window."""
    frames = spot_frames()
    crop = frames[:, 5:20, 10:30]
    write_exr(folder / "stack.exr", stack_channels(crop), dataWindow=((10, 5), (29, 19)),
              displayWindow=((0, 0), (W - 1, H - 1)))
    back = load_stack(folder / "stack.exr")
    expected = np.zeros_like(frames)
    expected[:, 5:20, 10:30] = crop
    np.testing.assert_array_equal(back.frames, expected)


def test_display_window_not_at_origin_is_the_image(folder):
    """The image is the display window wherever it sits: (100, 50) is pixel (0, 0)."""
    frames = spot_frames()
    write_exr(folder / "stack.exr", stack_channels(frames), dataWindow=((100, 50), (100 + W - 1, 50 + H - 1)),
              displayWindow=((100, 50), (100 + W - 1, 50 + H - 1)))
    np.testing.assert_array_equal(load_stack(folder / "stack.exr").frames, frames)


def test_overscan_outside_the_display_window_is_dropped(folder):
    frames = spot_frames()
    big = np.pad(frames, ((0, 0), (2, 2), (3, 3)), constant_values=9.0)
    write_exr(folder / "stack.exr", stack_channels(big), dataWindow=((-3, -2), (W + 2, H + 1)),
              displayWindow=((0, 0), (W - 1, H - 1)))
    np.testing.assert_array_equal(load_stack(folder / "stack.exr").frames, frames)


def test_display_window_disagreeing_with_the_camera_is_refused(folder):
    write_exr(folder / "stack.exr", stack_channels(np.zeros((3, H, W + 1), np.float32)))
    with pytest.raises(StackFormatError, match=r"stack.exr: displayWindow: display window is 24x33 .* camera is 24x32"):
        load_stack(folder / "stack.exr")


def test_data_window_outside_the_display_window_is_refused(folder):
    write_exr(folder / "stack.exr", stack_channels(spot_frames()), dataWindow=((500, 500), (500 + W - 1, 500 + H - 1)),
              displayWindow=((0, 0), (W - 1, H - 1)))
    with pytest.raises(StackFormatError, match="stack.exr: dataWindow: .*outside the display window"):
        load_stack(folder / "stack.exr")


def test_missing_source_channel_is_named(folder):
    write_exr(folder / "stack.exr", {"S000": spot_frames()[0], "S002": spot_frames()[2]})
    with pytest.raises(StackFormatError, match="stack.exr: channels: missing channel.*S001"):
        load_stack(folder / "stack.exr")


def test_frames_beyond_the_rig_are_named(folder):
    frames = np.concatenate([spot_frames(), spot_frames()[:1]])
    write_exr(folder / "stack.exr", stack_channels(frames))
    with pytest.raises(StackFormatError, match="S003 beyond the rig's 3 sources"):
        load_stack(folder / "stack.exr")


def test_rgb_layer_per_source_is_read_as_the_max_of_rgb(folder):
    frames = spot_frames()
    ch = {}
    for k, f in enumerate(frames):
        ch[f"{source_channel(k)}.R"] = 0.2 * f
        ch[f"{source_channel(k)}.G"] = f
        ch[f"{source_channel(k)}.B"] = 0.5 * f
        ch[f"{source_channel(k)}.A"] = np.ones_like(f)  # alpha is never intensity
    write_exr(folder / "stack.exr", ch)
    np.testing.assert_allclose(load_stack(folder / "stack.exr").frames, frames)


def test_layer_with_unusable_channels_is_named(folder):
    ch = {f"{source_channel(k)}.{c}": f for k, f in enumerate(spot_frames()) for c in ("U", "V")}
    write_exr(folder / "stack.exr", ch)
    with pytest.raises(StackFormatError, match="channel S000: layer S000 has channels U, V"):
        load_stack(folder / "stack.exr")


def test_half_pixels_and_uint_pixels_read_as_float(folder):
    frames = spot_frames()
    ch = {"S000": frames[0].astype(np.float16), "S001": frames[1], "S002": (frames[2] * 100).astype(np.uint32)}
    write_exr(folder / "stack.exr", ch)
    back = load_stack(folder / "stack.exr").frames
    np.testing.assert_allclose(back[0], frames[0], rtol=2**-11, atol=2**-24)
    np.testing.assert_array_equal(back[2], (frames[2] * 100).astype(np.uint32).astype(np.float32))


def test_negative_pixels_are_counted(folder):
    frames = spot_frames()
    frames[1, 3, 4] = -0.5
    frames[1, 3, 5] = -0.1
    write_exr(folder / "stack.exr", stack_channels(frames))
    with pytest.raises(StackFormatError, match=r"stack.exr: stack: 2 negative pixel\(s\) in frame\(s\) S001 \(2\)"):
        load_stack(folder / "stack.exr")


def test_nan_pixels_are_counted(folder):
    frames = spot_frames()
    frames[2, 0, :3] = np.nan
    write_exr(folder / "stack.exr", stack_channels(frames))
    with pytest.raises(StackFormatError, match=r"3 NaN or inf pixel\(s\) in frame\(s\) S002 \(3\)"):
        load_stack(folder / "stack.exr")


@pytest.mark.parametrize("key, value, message", [
    ("n_sources", "3", "n_sources: header attribute must be an integer"),
    ("n_sources", 4, "n_sources: header says 4 sources but the rig has 3"),
    ("camera_index", 2, "camera_index: is 2 but the rig has 1 camera"),
    ("camera_index", 0.5, "camera_index: header attribute must be an integer"),
    ("provenance", "{not json", "provenance: header attribute is not valid JSON"),
    ("provenance", "[1, 2]", "provenance: header attribute must hold a JSON dict"),
    ("saturation", -1.0, "saturation: must be a finite level > 0"),
    ("shinysim_format", "shinysim-truth/1", "shinysim_format: file format is 'shinysim-truth/1'"),
])
def test_malformed_header_attribute_is_named(folder, key, value, message):
    write_exr(folder / "stack.exr", stack_channels(spot_frames()), **{key: value})
    with pytest.raises(StackFormatError, match=f"stack.exr: {message}"):
        load_stack(folder / "stack.exr")


def test_a_directory_named_stack_exr_is_refused(folder):
    (folder / "stack.exr").mkdir()
    with pytest.raises(StackFormatError, match="stack.exr: not a file"):
        load_stack(folder / "stack.exr")


def test_a_misspelt_rig_key_beside_the_stack_is_named(folder):
    doc = json.loads((folder / "rig.json").read_text())
    doc["reference_z"] = doc.pop("reference_z_mm")
    (folder / "rig.json").write_text(json.dumps(doc))
    write_exr(folder / "stack.exr", stack_channels(spot_frames()))
    with pytest.raises(RigError, match="rig.json: rig: unknown field 'reference_z' \\(did you mean 'reference_z_mm'\\?\\)"):
        load_stack(folder / "stack.exr")


# -- float16 range --------------------------------------------------------------------


def test_float16_auto_keeps_a_tiny_stack_exact_in_float32(tmp_path):
    """A peak of 6e-10 is below float16's smallest subnormal: float16 would store zeros."""
    st = Stack(spot_frames() * 6e-10, small_rig())
    dtype, why = save_stack(st, tmp_path / "stack.exr")
    assert dtype == "float32" and "smallest normal" in why
    np.testing.assert_array_equal(load_stack(tmp_path / "stack.exr").frames, st.frames)


def test_float16_auto_keeps_a_bright_stack_in_float32(tmp_path):
    st = Stack(spot_frames() * 7.0e4, small_rig())  # above float16's largest value, 65504
    dtype, why = save_stack(st, tmp_path / "stack.exr")
    assert dtype == "float32" and "65504" in why
    np.testing.assert_array_equal(load_stack(tmp_path / "stack.exr").frames, st.frames)


def test_float16_holds_up_to_65504(tmp_path):
    st = Stack(spot_frames() * 65000.0, small_rig())
    assert save_stack(st, tmp_path / "stack.exr")[0] == "float16"
    back = load_stack(tmp_path / "stack.exr").frames
    assert np.all(np.isfinite(back))
    # float16 rounding: relative error <= 2**-11 of the value, 2**-24 absolute near 0
    np.testing.assert_allclose(back, st.frames, rtol=2**-11, atol=2**-24 * 65000)


def test_explicit_float16_that_cannot_hold_the_stack_is_refused(tmp_path):
    st = Stack(spot_frames() * 1e5, small_rig())
    with pytest.raises(OptionError, match="dtype 'float16' cannot hold this stack: peak 1e\\+05"):
        save_stack(st, tmp_path / "stack.exr", dtype="float16")
    assert not any(tmp_path.iterdir())


def test_choose_stack_dtype_at_the_boundaries():
    # the smallest peak float16 keeps: 1e-3 of it must be a normal half (2**-14)
    edge = 2.0**-14 / 1e-3
    assert choose_stack_dtype(np.array([edge]))[0] == "float16"
    assert choose_stack_dtype(np.array([edge * 0.99]))[0] == "float32"
    assert choose_stack_dtype(np.array([65504.0]))[0] == "float16"
    assert choose_stack_dtype(np.array([65504.5]))[0] == "float32"
    assert choose_stack_dtype(np.zeros(3))[0] == "float16"


# -- truth ----------------------------------------------------------------------------


def test_truth_round_trip_against_its_camera(tmp_path):
    t = small_truth()
    save_truth(t, tmp_path / "truth.exr")
    back = load_truth(tmp_path / "truth.exr", small_rig().camera)
    np.testing.assert_array_equal(back.mask, t.mask)
    np.testing.assert_array_equal(back.normals[t.mask], t.normals[t.mask])


def test_truth_normals_that_are_not_unit_are_named(tmp_path):
    t = small_truth()
    t.normals[t.mask] *= 2.0
    save_truth(t, tmp_path / "truth.exr")
    with pytest.raises(StackFormatError, match="truth.exr: normal: .* are not unit vectors"):
        load_truth(tmp_path / "truth.exr")


def test_truth_part_names_that_are_not_json_are_named(tmp_path):
    t = small_truth()
    save_truth(t, tmp_path / "truth.exr")
    header_channels = {c: np.zeros((H, W), np.float32) for c in
                       ("normal.X", "normal.Y", "position.X", "position.Y", "position.Z", "mask")}
    header_channels["normal.Z"] = np.ones((H, W), np.float32)
    write_exr(tmp_path / "bad.exr", header_channels, part_names="not json")
    with pytest.raises(StackFormatError, match="bad.exr: part_names: header attribute is not valid JSON"):
        load_truth(tmp_path / "bad.exr")


def test_truth_missing_channels_are_named(tmp_path):
    write_exr(tmp_path / "truth.exr", {"mask": np.zeros((H, W), np.float32)})
    with pytest.raises(StackFormatError, match="truth.exr: channels: missing truth channel.*normal.X"):
        load_truth(tmp_path / "truth.exr")


@pytest.mark.parametrize("bits, dtype", [(8, "float16"), (10, "float16"), (12, "float32"), (16, "float32")])
def test_sensor_codes_survive_the_stack_file(tmp_path, bits, dtype):
    """A digitised stack keeps every code: float16 only where its 11 bits keep neighbouring codes apart."""
    top = 2**bits - 1
    codes = np.random.default_rng(bits).integers(0, top + 1, (3, H, W))
    codes[0, 0, :2] = (top - 1, top)  # the closest codes, at full scale
    st = Stack((codes / top).astype(np.float32), small_rig(), saturation=1.0)
    assert save_stack(st, tmp_path / "stack.exr")[0] == dtype
    back = load_stack(tmp_path / "stack.exr")
    np.testing.assert_array_equal(np.rint(back.frames * top), codes)
    assert back.saturation == 1.0
