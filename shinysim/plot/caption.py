"""The figure every drawing starts from, and figures with their caption drawn under them, as PNG bytes.

matplotlib is imported inside the functions.
"""

from __future__ import annotations

import textwrap
from io import BytesIO

import numpy as np

__all__ = ["captioned_png", "new_figure"]


def new_figure(figsize, *grid, **kwargs):
    """A :class:`matplotlib.figure.Figure` of ``figsize`` inches, constrained layout, no pyplot.

    With ``grid`` (rows, columns) it returns ``(fig, fig.subplots(*grid, **kwargs))``.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    return (fig, fig.subplots(*grid, **kwargs)) if grid else fig


def captioned_png(fig, text, *, dpi=110, fontsize=8.0):
    """PNG bytes of ``fig`` with ``text`` (wrapped) written under it.

    The figure is laid out and rasterised as it is, then placed pixel for
    pixel on a taller canvas whose bottom strip holds the caption, so the
    plot's own layout is never disturbed.
    """
    import matplotlib.image as mpimg
    from matplotlib.figure import Figure

    buf = BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    buf.seek(0)
    img = mpimg.imread(buf, format="png")
    h_px, w_px = img.shape[:2]
    w_in = w_px / dpi
    chars = max(40, int(w_in * 72 / (0.52 * fontsize)))
    lines = []
    for para in text.split("\n"):
        lines.extend(textwrap.wrap(para, chars) or [""])
    cap_px = int(np.ceil((len(lines) * fontsize * 1.35 + 12) / 72 * dpi))
    H = h_px + cap_px
    canvas = Figure(figsize=(w_in, H / dpi), dpi=dpi)
    ax = canvas.add_axes((0.0, cap_px / H, 1.0, h_px / H))
    ax.imshow(img, interpolation="none", aspect="auto")
    ax.set_axis_off()
    canvas.text(0.012, 6 / 72 * dpi / H, "\n".join(lines), ha="left", va="bottom", fontsize=fontsize,
                linespacing=1.35)
    out = BytesIO()
    canvas.savefig(out, format="png", dpi=dpi)
    return out.getvalue()
