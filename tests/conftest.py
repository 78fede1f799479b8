"""Shared fixtures and helpers: renderer availability, the real-photograph folder, a seeded RNG, exact shapes."""

from __future__ import annotations

import importlib.util
import math
import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
#: Real photographs live beside the repository, never inside it.
SHARED_DATA = Path(os.environ.get("SHINYSIM_SHARED_DATA", REPO.parent / "shared" / "data"))

HAS_RENDER = all(importlib.util.find_spec(m) is not None for m in ("mitsuba", "drjit"))


def _jit_variant_available():
    if not HAS_RENDER:
        return False
    import drjit as dr

    return dr.has_backend(dr.JitBackend.LLVM) or dr.has_backend(dr.JitBackend.CUDA)


HAS_JIT = _jit_variant_available()

skip_without_render = pytest.mark.skipif(not HAS_RENDER, reason="needs the render extra (mitsuba, drjit)")
skip_without_jit = pytest.mark.skipif(
    not HAS_JIT, reason="needs a JIT Mitsuba variant (llvm: Debian's libllvm19, or cuda)"
)


def _marked(*marks):
    def apply(test):
        for mark in marks:
            test = mark(test)
        return test

    return apply


#: A test that renders: marked ``render`` (``-m "not render"`` leaves it out)
#: and skipped without the renderer, or without a JIT variant.
requires_render = _marked(pytest.mark.render, skip_without_render)
requires_jit = _marked(pytest.mark.render, skip_without_jit)


@pytest.fixture(scope="session", autouse=True)
def default_umask():
    """Run the tests under the usual umask 022, whatever the shell had."""
    old = os.umask(0o022)
    yield
    os.umask(old)


def assert_default_modes(*paths):
    """Every file given (or inside a folder given) has mode 0644: what any tool creates under umask 022."""
    files = [f for p in map(Path, paths) for f in (sorted(p.iterdir()) if p.is_dir() else [p])]
    assert files, "no files to check"
    modes = {f.name: oct(f.stat().st_mode & 0o777) for f in files}
    assert set(modes.values()) == {"0o644"}, modes


@pytest.fixture
def np_rng():
    return np.random.default_rng(1234)


@pytest.fixture
def chrome_dir():
    d = SHARED_DATA / "psm_chrome"
    if not (d / "lights.txt").is_file():
        pytest.skip(f"real photographs not available ({d} absent)")
    return d


def circle(xc, zc, R, sign=-1):
    """z(x), dz/dx of a circle: sign=-1 the lower arc (concave up, a meniscus), +1 the upper (a dome)."""

    def z(x):
        return zc + sign * np.sqrt(R**2 - (x - xc) ** 2)

    def p(x):
        return -sign * (x - xc) / np.sqrt(R**2 - (x - xc) ** 2)

    return z, p


def draw_disks(image, camera, world, diameter, amplitude=1.0, supersample=8):
    """Add disks of ``diameter`` mm at the world points' images: each pixel gets the fraction of its
    ``supersample`` x ``supersample`` sub-pixel centres inside the disk. Returns the projected centres."""
    rows, cols = camera.project(world)
    depth = (world - camera.position) @ camera.forward
    radii = 0.5 * diameter / (camera.pixel_pitch * depth / camera.distance)
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    for r, c, radius in zip(rows, cols, radii):
        r0, c0 = max(int(r - radius) - 2, 0), max(int(c - radius) - 2, 0)
        r1, c1 = min(int(r + radius) + 3, camera.height), min(int(c + radius) + 3, camera.width)
        pr, pc = np.mgrid[r0:r1, c0:c1]
        sr = pr[..., None, None] + offsets[:, None]
        sc = pc[..., None, None] + offsets[None, :]
        image[r0:r1, c0:c1] += amplitude * (((sr - r) ** 2 + (sc - c) ** 2) <= radius**2).mean(axis=(-2, -1))
    return np.column_stack([rows, cols])


def gaussian_blobs(rows, cols, amp, size, sigma=1.2, support=3.5):
    """(n, size, size) float32: a Gaussian blob per source, exactly 0 beyond ``support`` px."""
    frames = np.zeros((len(rows), size, size), np.float32)
    r = math.ceil(support)
    for k, (rc, cc) in enumerate(zip(rows, cols)):
        r0, c0 = int(round(rc)), int(round(cc))
        yy, xx = np.mgrid[r0 - r:r0 + r + 1, c0 - r:c0 + r + 1]
        d2 = (yy - rc) ** 2 + (xx - cc) ** 2
        frames[k, yy, xx] = np.where(d2 <= support**2, amp[k] * np.exp(-d2 / (2 * sigma**2)), 0.0)
    return frames
