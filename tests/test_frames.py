"""Camera frames read into stacks: every supported kind read exactly, every bad file refused by name.

Each kind is written here as a small synthetic image (a Gaussian spot on a
dark background) and read back; integer images must come back as their
values over the type's maximum, with the spot where it was. Alpha is never
intensity. Every bad input gives a :class:`~shinysim.errors.FrameError`
(or :class:`~shinysim.errors.OptionError` for a bad option) that names the
file, and nothing else escapes, whatever bytes a file holds.
"""

from __future__ import annotations

import math
import pickle
import struct
import zlib

import numpy as np
import pytest
import tifffile
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

import shinysim.io as stack_io
from shinysim.errors import FrameError, OptionError, ShinysimError, StackFormatError
from shinysim.io.frames import CHANNEL_REDUCTIONS, read_frame, stack_from_frames
from shinysim.rig import Camera, distant_rig

H, W = 24, 32
SPOT = (7, 20)  # row, column of the spot's peak
REC709 = np.array([0.2126, 0.7152, 0.0722])


def spot(peak=240, floor=5, dtype=np.uint8, sigma=3.0, at=SPOT):
    """A Gaussian spot on a dark background, rounded to ``dtype`` (float dtypes unrounded)."""
    r, c = np.mgrid[:H, :W]
    g = floor + peak * np.exp(-((r - at[0]) ** 2 + (c - at[1]) ** 2) / (2 * sigma**2))
    return g.astype(dtype) if np.issubdtype(dtype, np.floating) else np.round(g).astype(dtype)


def rgb_spot(dtype=np.uint8, top=240):
    """Three different channels, each with the spot at SPOT (green the brightest)."""
    return np.dstack([spot(top // 2, 3, dtype), spot(top, 5, dtype), spot(top // 3, 1, dtype)])


def ramp_alpha(dtype=np.uint8, top=255):
    """An alpha that varies across the image, brightest where the spot is not."""
    a = np.linspace(0, top, H * W).reshape(H, W)[::-1]
    return np.round(a).astype(dtype)


def assert_scaled(frame, ints, scale):
    """The frame is exactly ``ints / scale``: float32, in [0, 1], integers recovered."""
    assert frame.dtype == np.float32 and frame.shape == ints.shape
    assert np.array_equal(np.rint(frame.astype(np.float64) * scale).astype(np.int64), ints.astype(np.int64))
    assert np.abs(frame - ints / scale).max() < 1e-7
    assert 0.0 <= frame.min() and frame.max() <= 1.0


def assert_spot(frame, at=SPOT):
    assert np.unravel_index(np.argmax(frame), frame.shape) == at


def refuses(path, *words, channel="max"):
    """read_frame raises a FrameError starting with the file; the message holds every word."""
    with pytest.raises(FrameError) as err:
        read_frame(path, channel=channel)
    msg = str(err.value)
    assert msg.startswith(f"{path}: "), msg
    assert err.value.path == str(path) and err.value.field
    for w in words:
        assert w in msg, msg
    return err.value


def write_png(path, arr, colour_type, depth, *, width=None, height=None):
    """A minimal PNG (unfiltered rows), for what Pillow cannot write: 2/4-bit, 16-bit colour, zero size."""
    h, w = arr.shape[:2]
    width, height = (w if width is None else width), (h if height is None else height)
    if depth < 8:
        per = 8 // depth
        rows = []
        for r in arr.reshape(h, w):
            packed = bytearray()
            for i in range(0, w, per):
                byte = 0
                for j, v in enumerate(r[i:i + per]):
                    byte |= int(v) << (8 - depth * (j + 1))
                packed.append(byte)
            rows.append(bytes(packed))
    else:
        rows = [arr[r].astype(">u2" if depth == 16 else "u1").tobytes() for r in range(h)]
    raw = b"".join(b"\x00" + row for row in rows)

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour_type, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw))
                     + chunk(b"IEND", b""))
    return path


def pil_mode(path):
    with Image.open(path) as im:
        return im.mode


def camera(h=H, w=W):
    return Camera("orthographic", w, h, [0, 0, 1000.0], [0, 0, 0], [0, 1, 0], float(w))


def rig(n=3, h=H, w=W):
    dirs = np.array([[np.sin(t), 0.0, np.cos(t)] for t in np.linspace(-0.5, 0.5, n)])
    return distant_rig(dirs, camera(h, w))


# -- PNG ----------------------------------------------------------------------------


def test_png_8bit_grey(tmp_path):
    ints = spot()
    Image.fromarray(ints, "L").save(p := tmp_path / "g.png")
    frame, clip = read_frame(p)
    assert clip == 1.0
    assert_scaled(frame, ints, 255)
    assert_spot(frame)


def test_png_16bit_grey(tmp_path):
    ints = spot(60000, 100, np.uint16)
    Image.fromarray(ints).save(p := tmp_path / "g16.png")
    assert pil_mode(p) == "I;16"
    frame, clip = read_frame(p)
    assert clip == 1.0
    assert_scaled(frame, ints, 65535)
    assert_spot(frame)


@pytest.mark.parametrize("depth", [2, 4])
def test_png_2_and_4_bit_grey_scaled_to_full_range(tmp_path, depth):
    top = 2**depth - 1
    ints = np.round(spot(top, 0, np.float64, sigma=1.0)).astype(np.uint8)
    write_png(p := tmp_path / "low.png", ints, 0, depth)
    frame, clip = read_frame(p)
    assert clip == 1.0
    assert_scaled(frame, ints, top)
    assert frame[SPOT] == 1.0 and (frame == 1.0).sum() == 1


def test_png_1bit(tmp_path):
    ints = spot() > 100
    Image.fromarray(ints).save(p := tmp_path / "b.png")
    assert pil_mode(p) == "1"
    frame, clip = read_frame(p)
    assert clip == 1.0 and frame.dtype == np.float32
    assert np.array_equal(frame, ints.astype(np.float32))


@pytest.mark.parametrize("alpha", ["opaque", "varying"])
def test_png_grey_alpha_reads_grey_not_alpha(tmp_path, alpha):
    ints = spot()
    a = np.full_like(ints, 255) if alpha == "opaque" else ramp_alpha()
    Image.fromarray(np.dstack([ints, a]), "LA").save(p := tmp_path / "la.png")
    frame, clip = read_frame(p)
    # the old bug took max(grey, alpha): an opaque alpha made every pixel 1.0
    assert_scaled(frame, ints, 255)
    assert_spot(frame)
    assert frame.min() < 0.05


@pytest.mark.parametrize("channel", CHANNEL_REDUCTIONS)
def test_png_rgb_channel_reductions(tmp_path, channel):
    ints = rgb_spot()
    Image.fromarray(ints, "RGB").save(p := tmp_path / "rgb.png")
    frame, clip = read_frame(p, channel=channel)
    v = ints / 255.0
    want = {"max": v.max(-1), "mean": v.mean(-1), "luminance": v @ REC709}[channel]
    assert clip == 1.0 and frame.dtype == np.float32
    np.testing.assert_allclose(frame, want, atol=1e-6)
    assert_spot(frame)
    if channel == "max":
        assert_scaled(frame, ints.max(-1), 255)


@pytest.mark.parametrize("alpha", ["opaque", "varying"])
@pytest.mark.parametrize("channel", CHANNEL_REDUCTIONS)
def test_png_rgba_alpha_is_not_intensity(tmp_path, alpha, channel):
    ints = rgb_spot()
    a = np.full(ints.shape[:2], 255, np.uint8) if alpha == "opaque" else ramp_alpha()
    Image.fromarray(np.dstack([ints, a]), "RGBA").save(p := tmp_path / "rgba.png")
    frame, _ = read_frame(p, channel=channel)
    Image.fromarray(ints, "RGB").save(q := tmp_path / "rgb.png")
    same, _ = read_frame(q, channel=channel)
    assert np.array_equal(frame, same)
    assert_spot(frame)


def test_png_palette_expanded_through_the_palette(tmp_path):
    ints = spot()
    palette = np.zeros((256, 3), np.uint8)
    palette[:, 1] = np.arange(256)  # index i -> (0, i, 0): the index itself would look the same as grey
    palette[:, 0] = np.arange(256)[::-1] // 4
    img = Image.fromarray(ints, "P")
    img.putpalette(palette.ravel().tolist())
    img.save(p := tmp_path / "p.png")
    assert pil_mode(p) == "P"
    frame, clip = read_frame(p, channel="mean")
    want = palette[ints].astype(np.float64).mean(-1) / 255
    assert clip == 1.0
    np.testing.assert_allclose(frame, want, atol=1e-6)
    assert_spot(frame)


def test_png_16bit_colour_is_read_at_16_bits(tmp_path):
    # every 16-bit code, exactly: the values are the codes over 65535 (in float32), not 8 bits' worth
    ints = rgb_spot(np.uint16, 60000)
    ints[0, 0] = (1, 257, 511)  # codes whose low byte is all there is, or differs from their high byte
    write_png(p := tmp_path / "rgb48.png", ints, 2, 16)
    frame, clip = read_frame(p, channel="max")
    assert clip == 1.0
    np.testing.assert_array_equal(frame, ints.max(-1).astype(np.float32) / np.float32(65535))
    assert_spot(frame)
    write_png(q := tmp_path / "la32.png", np.dstack([ints[..., 0], ints[..., 1]]), 4, 16)
    frame, _ = read_frame(q)  # grey+alpha: the grey, never the alpha
    np.testing.assert_array_equal(frame, ints[..., 0].astype(np.float32) / np.float32(65535))


# -- TIFF ---------------------------------------------------------------------------


@pytest.mark.parametrize("dtype, scale", [(np.uint8, 255), (np.uint16, 65535)])
def test_tiff_integer_grey(tmp_path, dtype, scale):
    ints = spot(int(scale * 0.9), 3, dtype)
    tifffile.imwrite(p := tmp_path / "g.tif", ints, photometric="minisblack")
    frame, clip = read_frame(p)
    assert clip == 1.0
    assert_scaled(frame, ints, scale)
    assert_spot(frame)


@pytest.mark.parametrize("dtype, scale", [(np.uint8, 255), (np.uint16, 65535)])
@pytest.mark.parametrize("alpha", [False, True])
def test_tiff_integer_rgb_and_rgba(tmp_path, dtype, scale, alpha):
    ints = rgb_spot(dtype, int(scale * 0.9))
    data = np.dstack([ints, np.full(ints.shape[:2], scale, dtype)]) if alpha else ints
    extra = {"extrasamples": ["unassalpha"]} if alpha else {}
    tifffile.imwrite(p := tmp_path / "c.tif", data, photometric="rgb", **extra)
    frame, clip = read_frame(p)
    assert clip == 1.0
    assert_scaled(frame, ints.max(-1), scale)
    assert_spot(frame)


@pytest.mark.parametrize("alpha", ["opaque", "varying"])
def test_tiff_16bit_grey_alpha(tmp_path, alpha):
    ints = spot(60000, 50, np.uint16)
    a = np.full_like(ints, 65535) if alpha == "opaque" else ramp_alpha(np.uint16, 65535)
    tifffile.imwrite(p := tmp_path / "la.tif", np.dstack([ints, a]), photometric="minisblack",
                     extrasamples=["unassalpha"])
    frame, _ = read_frame(p)
    assert_scaled(frame, ints, 65535)
    assert_spot(frame)


def test_tiff_planar_rgb(tmp_path):
    ints = rgb_spot(np.uint16, 50000)
    tifffile.imwrite(p := tmp_path / "planar.tif", np.moveaxis(ints, -1, 0), photometric="rgb",
                     planarconfig="separate")
    frame, _ = read_frame(p, channel="luminance")
    np.testing.assert_allclose(frame, (ints / 65535) @ REC709, atol=1e-6)
    assert_spot(frame)


@pytest.mark.parametrize("colour", [False, True])
def test_tiff_float32(tmp_path, colour):
    data = np.dstack([spot(3.5, 0.01, np.float32)] * 3) * [0.5, 1.0, 0.25] if colour else spot(3.5, 0.01, np.float32)
    data = data.astype(np.float32)
    tifffile.imwrite(p := tmp_path / "f.tif", data, photometric="rgb" if colour else "minisblack")
    frame, clip = read_frame(p)
    assert clip == math.inf and frame.dtype == np.float32
    np.testing.assert_array_equal(frame, data.max(-1) if colour else data)
    assert frame.max() > 1.0  # linear, not clipped or rescaled
    assert_spot(frame)


def test_tiff_1bit_and_min_is_white(tmp_path):
    mask = spot() > 100
    tifffile.imwrite(p := tmp_path / "b.tif", mask, photometric="minisblack")
    frame, clip = read_frame(p)
    assert clip == 1.0 and np.array_equal(frame, mask.astype(np.float32))
    ints = spot()
    tifffile.imwrite(q := tmp_path / "w.tif", 255 - ints, photometric="miniswhite")
    frame, _ = read_frame(q)
    assert_scaled(frame, ints, 255)  # min-is-white stores the complement
    assert_spot(frame)


# -- TGA, JPEG, BMP -----------------------------------------------------------------


@pytest.mark.parametrize("mode", ["L", "RGB", "RGBA"])
@pytest.mark.parametrize("rle", [False, True])
def test_tga(tmp_path, mode, rle):
    ints = rgb_spot()
    data = {"L": ints[..., 1], "RGB": ints, "RGBA": np.dstack([ints, ramp_alpha()])}[mode]
    Image.fromarray(data, mode).save(p := tmp_path / "f.tga", compression="tga_rle" if rle else None)
    frame, clip = read_frame(p)
    assert clip == 1.0
    assert_scaled(frame, ints[..., 1] if mode == "L" else ints.max(-1), 255)
    assert_spot(frame)


@pytest.mark.parametrize("mode", ["L", "RGB"])
def test_jpeg(tmp_path, mode):
    ints = rgb_spot() if mode == "RGB" else spot()
    Image.fromarray(ints, mode).save(p := tmp_path / "f.jpg", quality=95)
    frame, clip = read_frame(p, channel="mean")
    assert clip == 1.0 and frame.shape == (H, W)
    want = ints / 255.0 if mode == "L" else (ints / 255.0).mean(-1)
    assert np.abs(frame - want).max() < 0.05  # lossy
    assert_spot(frame)


def test_jpeg_cmyk_refused(tmp_path):
    Image.new("CMYK", (W, H), (10, 20, 30, 0)).save(p := tmp_path / "cmyk.jpg")
    refuses(p, "4 components")


def test_bmp_rgb(tmp_path):
    ints = rgb_spot()
    Image.fromarray(ints, "RGB").save(p := tmp_path / "f.bmp")
    frame, clip = read_frame(p)
    assert clip == 1.0
    assert_scaled(frame, ints.max(-1), 255)
    assert_spot(frame)


def test_kind_is_decided_by_content_and_a_misleading_name_refused(tmp_path):
    ints = spot()
    Image.fromarray(ints, "L").save(p := tmp_path / "frame.dat", format="PNG")
    assert_scaled(read_frame(p)[0], ints, 255)  # a neutral name: the content decides
    Image.fromarray(ints, "L").save(q := tmp_path / "really_png.tif", format="PNG")
    refuses(q, "holds PNG data but is named .tif")
    tifffile.imwrite(r := tmp_path / "really_tiff.png", ints)
    refuses(r, "holds TIFF data but is named .png")


# -- EXR ----------------------------------------------------------------------------

needs_exr_reader = pytest.mark.skipif(
    not hasattr(stack_io, "read_exr_channels"), reason="shinysim.io.read_exr_channels not available"
)


def write_exr(path, channels):
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in channels.items()}) as f:
        f.write(str(path))
    return path


@needs_exr_reader
@pytest.mark.parametrize("name", ["Y", "Z", "intensity"])
def test_exr_single_channel_any_name(tmp_path, name):
    data = spot(7.0, 0.02, np.float32)
    frame, clip = read_frame(write_exr(tmp_path / "y.exr", {name: data}))
    assert clip == math.inf
    np.testing.assert_array_equal(frame, data)
    assert_spot(frame)


@needs_exr_reader
@pytest.mark.parametrize("prefix", ["", "rgba."])
@pytest.mark.parametrize("alpha", [None, "opaque", "varying"])
@pytest.mark.parametrize("channel", CHANNEL_REDUCTIONS)
def test_exr_rgb_and_rgba(tmp_path, prefix, alpha, channel):
    rgb = (rgb_spot(np.float32, 6) + 0.01).astype(np.float32)
    chans = {f"{prefix}{c}": rgb[..., i] for i, c in enumerate("RGB")}
    if alpha:
        chans[f"{prefix}A"] = np.ones((H, W), np.float32) if alpha == "opaque" else ramp_alpha(np.float32, 1)
    frame, _ = read_frame(write_exr(tmp_path / "c.exr", chans), channel=channel)
    want = {"max": rgb.max(-1), "mean": rgb.mean(-1), "luminance": rgb @ REC709}[channel]
    np.testing.assert_allclose(frame, want, rtol=1e-6)
    assert_spot(frame)


@needs_exr_reader
@pytest.mark.parametrize("prefix", ["", "beauty."])
def test_exr_grey_alpha(tmp_path, prefix):
    data = spot(2.0, 0.0, np.float32)
    p = write_exr(tmp_path / "ya.exr", {f"{prefix}Y": data, f"{prefix}A": np.ones((H, W), np.float32)})
    frame, _ = read_frame(p)
    np.testing.assert_array_equal(frame, data)


@needs_exr_reader
@pytest.mark.parametrize("names", [["S000", "S001"], ["foo", "bar"], ["R", "G"], ["a.R", "a.G", "a.B", "b.Y"],
                                   ["A"]])
def test_exr_channels_not_one_layer_refused(tmp_path, names):
    p = write_exr(tmp_path / "multi.exr", {n: np.ones((H, W), np.float32) for n in names})
    err = refuses(p, "not one grey or colour layer", *names)
    assert err.field == "channels"


@needs_exr_reader
def test_exr_nan_and_negative_refused(tmp_path):
    data = spot(2.0, 0.0, np.float32)
    data[0, :3] = np.nan
    data[1, 0] = np.inf
    refuses(write_exr(tmp_path / "nan.exr", {"Y": data}), "4 pixel(s) are NaN or inf")
    data = spot(2.0, 0.0, np.float32)
    data[5, 5:7] = [-0.5, -0.25]
    refuses(write_exr(tmp_path / "neg.exr", {"Y": data}), "2 pixel(s) are negative", "-0.5")


@needs_exr_reader
def test_exr_corrupt_refused(tmp_path):
    good = write_exr(tmp_path / "good.exr", {"Y": spot(2.0, 0.0, np.float32)}).read_bytes()
    (p := tmp_path / "cut.exr").write_bytes(good[: len(good) // 2])
    with pytest.raises(FrameError) as err:
        read_frame(p)
    assert str(err.value).startswith(str(p))


# -- bad files ----------------------------------------------------------------------


def test_missing_file(tmp_path):
    refuses(tmp_path / "nope.png", "no such file")


def test_directory(tmp_path):
    refuses(tmp_path, "is a directory")


def test_empty_file(tmp_path):
    (p := tmp_path / "empty.png").write_bytes(b"")
    refuses(p, "empty file (0 bytes)")


def test_truncated_png(tmp_path):
    Image.fromarray(spot(), "L").save(good := tmp_path / "good.png")
    data = good.read_bytes()
    for n in (12, 30, len(data) // 2, len(data) - 13):
        (p := tmp_path / f"cut{n}.png").write_bytes(data[:n])
        refuses(p)


def test_corrupt_png_data(tmp_path):
    Image.fromarray(spot(), "L").save(good := tmp_path / "good.png")
    data = bytearray(good.read_bytes())
    data[60:70] = bytes(10)  # inside the compressed pixels: the CRC and zlib no longer agree
    (p := tmp_path / "bad.png").write_bytes(bytes(data))
    refuses(p, "cannot decode the PNG image")


def test_text_file_is_not_an_image(tmp_path):
    (p := tmp_path / "notes.txt").write_text("source 1: left\nsource 2: right\n")
    refuses(p, "not an image in a supported format")
    (q := tmp_path / "notes.png").write_text("not really a png\n")
    refuses(q, "not an image in a supported format")
    (r := tmp_path / "notes.tga").write_text("not really a tga either, but named like one\n")
    refuses(r, "TGA")


def test_unsupported_layout_five_samples(tmp_path):
    data = np.dstack([spot()] * 5)
    tifffile.imwrite(p := tmp_path / "five.tif", data, photometric="minisblack", planarconfig="contig")
    refuses(p, "5 samples per pixel")
    tifffile.imwrite(q := tmp_path / "rgb2.tif", data, photometric="rgb", extrasamples=["unspecified"] * 2)
    refuses(q, "5 samples per pixel")


@pytest.mark.parametrize("pages", [2, 3, 4, 7])
def test_multipage_tiff_names_the_page_count(tmp_path, pages):
    # three or four grey pages must not pass for one RGB(A) image
    tifffile.imwrite(p := tmp_path / "stack.tif", np.stack([spot()] * pages), photometric="minisblack")
    err = refuses(p, f"{pages} pages")
    assert err.field == "pages"


def test_unsupported_tiff_kinds(tmp_path):
    tifffile.imwrite(p := tmp_path / "signed.tif", spot().astype(np.int16))
    refuses(p, "signed integer")
    tifffile.imwrite(q := tmp_path / "pal.tif", spot(), photometric="palette",
                     colormap=np.tile(np.arange(256, dtype=np.uint16) * 257, (3, 1)))
    refuses(q, "palette")


def test_float_nan_and_inf_pixels_counted(tmp_path):
    data = spot(2.0, 0.0, np.float32)
    data[0, 0] = np.nan
    data[3, 4:6] = np.inf
    tifffile.imwrite(p := tmp_path / "nan.tif", data)
    err = refuses(p, "3 pixel(s) are NaN or inf")
    assert err.field == "pixels"


def test_float_negative_pixels_counted_with_most_negative(tmp_path):
    data = spot(2.0, 0.0, np.float32)
    data[2, 2:5] = [-0.125, -3.5, -1e-4]
    tifffile.imwrite(p := tmp_path / "neg.tif", data)
    refuses(p, "3 pixel(s) are negative", "most negative -3.5")


def test_float_problems_in_alpha_do_not_count(tmp_path):
    rgb = rgb_spot(np.float32, 4)
    alpha = np.full((H, W), np.nan, np.float32)
    tifffile.imwrite(p := tmp_path / "a.tif", np.dstack([rgb, alpha]), photometric="rgb",
                     extrasamples=["unassalpha"])
    frame, _ = read_frame(p)
    np.testing.assert_array_equal(frame, rgb.max(-1))


def test_zero_width_or_height(tmp_path):
    write_png(p := tmp_path / "flat.png", np.zeros((1, 4), np.uint8), 0, 8, height=0)
    refuses(p, "zero width or height")
    write_png(q := tmp_path / "thin.png", np.zeros((4, 1), np.uint8), 0, 8, width=0)
    refuses(q, "zero width or height")


def test_unknown_channel_option(tmp_path):
    Image.fromarray(spot(), "L").save(p := tmp_path / "g.png")
    for bad in ("median", "MAX", None, ["max"]):
        with pytest.raises(OptionError, match="channel must be one of 'max', 'mean', 'luminance'"):
            read_frame(p, channel=bad)


def test_errors_pickle_and_are_value_errors(tmp_path):
    err = refuses(tmp_path / "nope.png", "no such file")
    assert isinstance(err, ValueError) and isinstance(err, ShinysimError)
    again = pickle.loads(pickle.dumps(err))
    assert str(again) == str(err) and again.path == err.path


# -- stacks -------------------------------------------------------------------------


def grey_pngs(tmp_path, n=3, size=(H, W), dtype=np.uint8, alpha=False):
    paths = []
    for k in range(n):
        at = (SPOT[0], SPOT[1] - 4 * k)
        ints = spot(200 if dtype == np.uint8 else 50000, 5, dtype, at=at)[: size[0], : size[1]]
        if alpha:
            Image.fromarray(np.dstack([ints, np.full_like(ints, 255)]), "LA").save(p := tmp_path / f"f{k}.png")
        else:
            Image.fromarray(ints).save(p := tmp_path / f"f{k}.png")
        paths.append(p)
    return paths


def test_stack_from_integer_frames(tmp_path):
    paths = grey_pngs(tmp_path, alpha=True)
    stack = stack_from_frames(paths, rig(), provenance={"operator": "test"})
    assert stack.frames.shape == (3, H, W) and stack.saturation == 1.0
    for k in range(3):
        assert_spot(stack.frames[k], (SPOT[0], SPOT[1] - 4 * k))
    prov = stack.provenance
    assert prov["frames"] == ["f0.png", "f1.png", "f2.png"]
    assert prov["channel"] == "max" and prov["clip"] == 1.0 and prov["operator"] == "test"
    assert prov["kinds"] == ["8-bit grey+alpha PNG"] * 3
    assert prov["alpha_dropped"] == [True] * 3


def test_stack_from_float_frames_has_no_clip_level(tmp_path):
    paths = []
    for k in range(2):
        tifffile.imwrite(p := tmp_path / f"f{k}.tif", spot(3.0, 0.0, np.float32))
        paths.append(p)
    stack = stack_from_frames(paths, rig(2))
    assert stack.saturation is None and stack.provenance["clip"] is None
    assert stack.provenance["kinds"] == ["float32 grey TIFF"] * 2
    assert stack.provenance["alpha_dropped"] == [False, False]


def test_stack_wrong_number_of_files(tmp_path):
    paths = grey_pngs(tmp_path, n=2)
    with pytest.raises(FrameError, match="2 frame files given but the rig has 3 sources") as err:
        stack_from_frames(paths, rig(3))
    assert isinstance(err.value, StackFormatError)  # the frames disagree with their rig


def test_stack_frame_size_differs_from_camera(tmp_path):
    paths = grey_pngs(tmp_path, size=(20, 30))
    with pytest.raises(FrameError) as err:
        stack_from_frames(paths, rig())
    msg = str(err.value)
    assert msg.startswith(f"{paths[0]}: size: ") and "20x30" in msg and f"is {H}x{W}" in msg
    assert isinstance(err.value, StackFormatError)


def test_stack_frames_of_mixed_sizes(tmp_path):
    paths = grey_pngs(tmp_path)
    Image.fromarray(spot()[:20]).save(paths[1])
    Image.fromarray(spot()[:18]).save(paths[2])
    with pytest.raises(FrameError) as err:
        stack_from_frames(paths, rig())
    msg = str(err.value)
    assert msg.startswith(f"{paths[1]}: size: frames differ in size"), msg
    assert f"20x{W}" in msg and f"f0.png is {H}x{W}" in msg


def test_stack_mixed_integer_and_float_frames(tmp_path):
    paths = grey_pngs(tmp_path, n=2)
    tifffile.imwrite(p := tmp_path / "f.tif", spot(0.8, 0.0, np.float32))
    with pytest.raises(FrameError) as err:
        stack_from_frames([paths[0], p, paths[1]], rig())
    msg = str(err.value)
    assert msg.startswith(f"{p}: kind: frames mix integer and float images")
    assert "f0.png is 8-bit grey PNG" in msg and "f.tif is float32 grey TIFF" in msg


def test_stack_mixed_8_and_16_bit_is_one_scale(tmp_path):
    (tmp_path / "deep").mkdir()
    paths = grey_pngs(tmp_path, n=2) + grey_pngs(tmp_path / "deep", n=1, dtype=np.uint16)
    stack = stack_from_frames(paths, rig())
    assert stack.saturation == 1.0
    assert stack.provenance["kinds"] == ["8-bit grey PNG", "8-bit grey PNG", "16-bit grey PNG"]


def test_stack_bad_options(tmp_path):
    paths = grey_pngs(tmp_path)
    with pytest.raises(OptionError, match="channel"):
        stack_from_frames(paths, rig(), channel="brightest")
    with pytest.raises(OptionError, match="camera_index"):
        stack_from_frames(paths, rig(), camera_index=1)
    with pytest.raises(OptionError, match="list of frame files"):
        stack_from_frames(str(paths[0]), rig())


def test_stack_bad_frame_names_the_file(tmp_path):
    paths = grey_pngs(tmp_path)
    paths[2].write_text("oops")
    with pytest.raises(FrameError) as err:
        stack_from_frames(paths, rig())
    assert str(err.value).startswith(str(paths[2]))



def test_tiff_whose_directory_chain_loops_is_refused(tmp_path):
    """A TIFF whose last IFD names itself as the next: tifffile would walk it forever, growing."""
    tifffile.imwrite(p := tmp_path / "loop.tif", spot())
    data = bytearray(p.read_bytes())
    first = struct.unpack("<I", data[4:8])[0]
    n_tags = struct.unpack("<H", data[first:first + 2])[0]
    data[first + 2 + 12 * n_tags:first + 6 + 12 * n_tags] = struct.pack("<I", first)
    p.write_bytes(bytes(data))
    with pytest.raises(FrameError) as err:
        read_frame(p)
    assert str(err.value).startswith(f"{p}: pages: TIFF's chain of image directories runs past")


@pytest.mark.parametrize("fmt", ["PNG", "TIFF"])
def test_frame_declaring_too_many_pixels_is_refused_before_decoding(tmp_path, fmt):
    """A header bit flip can declare 2^30 pixels in a file of a few bytes: refused from the header alone."""
    from shinysim.io.frames import MAX_FRAME_PIXELS

    side = 32768  # 2^30 pixels > MAX_FRAME_PIXELS
    assert side * side > MAX_FRAME_PIXELS
    if fmt == "PNG":
        p = tmp_path / "big.png"
        ihdr = struct.pack(">IIBBBBB", side, side, 8, 0, 0, 0, 0)
        chunk = lambda tag, d: (struct.pack(">I", len(d)) + tag + d  # noqa: E731
                                + struct.pack(">I", zlib.crc32(tag + d) & 0xFFFFFFFF))
        p.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64))
                      + chunk(b"IEND", b""))
    else:
        tifffile.imwrite(p := tmp_path / "big.tif", spot())
        data = bytearray(p.read_bytes())
        first = struct.unpack("<I", data[4:8])[0]
        for i in range(struct.unpack("<H", data[first:first + 2])[0]):
            at = first + 2 + 12 * i
            tag, typ = struct.unpack("<HH", data[at:at + 4])
            if tag in (256, 257):  # ImageWidth, ImageLength
                data[at + 8:at + 12] = struct.pack("<H", side) + b"\0\0" if typ == 3 else struct.pack("<I", side)
        p.write_bytes(bytes(data))
    with pytest.raises(FrameError) as err:
        read_frame(p)
    assert str(err.value).startswith(f"{p}: size: image declares {side}x{side} pixels"), str(err.value)


# -- fuzzing: nothing but FrameError, whatever the bytes ------------------------------


def _good_bytes():
    import io

    out = {}
    for fmt, mode, data in [("PNG", "L", spot()), ("TGA", "RGB", rgb_spot()), ("TIFF", "RGB", rgb_spot())]:
        buf = io.BytesIO()
        Image.fromarray(data, mode).save(buf, format=fmt)
        out[fmt] = buf.getvalue()
    return out


GOOD = _good_bytes()
SUFFIX = {"PNG": ".png", "TGA": ".tga", "TIFF": ".tif"}


@st.composite
def hostile(draw):
    fmt = draw(st.sampled_from(sorted(GOOD)))
    how = draw(st.sampled_from(["random", "flip", "truncate", "splice"]))
    good = bytearray(GOOD[fmt])
    if how == "random":
        data = draw(st.binary(min_size=1, max_size=400))
        if draw(st.booleans()):  # keep the signature so the decoder is reached
            data = bytes(good[:8]) + data
    elif how == "flip":
        for _ in range(draw(st.integers(1, 8))):
            i = draw(st.integers(0, len(good) - 1))
            good[i] ^= 1 << draw(st.integers(0, 7))
        data = bytes(good)
    elif how == "truncate":
        data = bytes(good[: draw(st.integers(1, len(good) - 1))])
    else:
        i = draw(st.integers(0, len(good) - 1))
        data = bytes(good[:i]) + draw(st.binary(min_size=1, max_size=64)) + bytes(good[i:])
    return SUFFIX[fmt], data


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=hostile())
def test_hostile_bytes_give_frame_error_or_a_frame(tmp_path, case):
    suffix, data = case
    p = tmp_path / f"hostile{suffix}"
    p.write_bytes(data)
    try:
        frame, clip = read_frame(p)
    except FrameError as exc:
        assert str(exc).startswith(str(p))
    else:
        assert frame.dtype == np.float32 and frame.ndim == 2 and frame.size
        assert clip == 1.0 or clip == math.inf
        assert np.isfinite(frame).all() and frame.min() >= 0
