r"""Coded (multiplexed) source displays: which sources each frame lights.

A code is a 0/1 matrix (frames x sources); :func:`make_code` builds the
sequential, binary, Gray and Hadamard codes, optionally inside the three
channels of a colour camera (``colours=3``, :func:`colour_channels`,
:func:`encode_colour`, :func:`fiber_emission`). numpy only: the simulator
(:mod:`shinysim.sim.coded`) and the decoder (:mod:`shinysim.recon.coding`)
both use this module. How the codes are built: ``docs/coded-scanning.md``,
sections "The codes" and "Colour multiplexing".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._shared import check_choice, check_matrix, check_number, named_check
from ..errors import OptionError, check_fields, did_you_mean

__all__ = [
    "CODES",
    "CODE_FORMAT",
    "COLOURS",
    "CHANNEL_NAMES",
    "MAX_SOURCES",
    "SNR_NOISES",
    "SNR_PIXELS",
    "Code",
    "check_code",
    "make_code",
    "encode",
    "encode_colour",
    "fiber_emission",
    "colour_channels",
    "gray",
    "s_matrix",
    "s_matrix_inverse",
    "hadamard_order",
    "hadamard_snr_gain",
    "hilbert_index",
    "spatial_order",
]

#: The codes :func:`make_code` builds.
CODES = ("sequential", "binary", "gray", "hadamard")
#: ``format`` of :meth:`Code.to_dict`.
CODE_FORMAT = "shinysim-code/1"
#: Most sources a code is built for: a Hadamard code of 4095 frames (its
#: S-matrix alone is 16.8 million entries) and 13 bit pairs.
MAX_SOURCES = 4095
#: Colour counts :func:`make_code` builds codes for: one (every source the
#: same colour) or three (red, green and blue fibers, a colour camera).
COLOURS = (1, 3)
#: The channels of a colour code, in the order of ``Code.channels``' values.
CHANNEL_NAMES = ("R", "G", "B")
#: Noise models of :func:`hadamard_snr_gain`.
SNR_NOISES = ("additive", "shot")
#: Which estimate :func:`hadamard_snr_gain` speaks of.
SNR_PIXELS = ("all", "lit", "unlit")

#: Pixels (times sources) per block of :func:`encode`: a float64 block of
#: 2**22 values is 32 MB whatever the stack's size.
_BLOCK = 1 << 22


def gray(i: Any) -> np.ndarray:
    """Reflected binary Gray code of non-negative integers: ``i XOR (i >> 1)``."""
    i = np.asarray(i, dtype=np.int64)
    return i ^ (i >> 1)


def _bits_for(n_sources: int) -> int:
    """``ceil(log2(N + 1))``: bits of codewords ``1 .. N``."""
    return int(n_sources).bit_length()


def hadamard_order(n_sources: int) -> int:
    """Order ``n = 2**m - 1`` of the smallest S-matrix with at least ``n_sources`` columns (``m >= 1``)."""
    n_sources = _count(n_sources)
    return (1 << max(1, _bits_for(n_sources))) - 1


def _s_order(n):
    """``n`` as an int of the form ``2**m - 1``, or OptionError naming ``n``."""
    n = int(check_number("n", n, lo=1, integer=True))
    if (n + 1) & n:
        raise OptionError(f"an S-matrix has order 2**m - 1, got {n}", field="n")
    return n


def s_matrix(n: int) -> np.ndarray:
    """The S-matrix of order ``n = 2**m - 1``: (n, n) float64 of 0 and 1.

    From the Sylvester Hadamard matrix ``H`` of order ``n + 1``
    (``H_1 = [1]``, ``H_2k = [[H_k, H_k], [H_k, -H_k]]``): drop its first
    row and column and map ``+1 -> 0``, ``-1 -> 1``. Every row and column
    holds ``(n + 1) / 2`` ones; any two rows share ``(n + 1) / 4`` of them
    (for ``n >= 3``).
    """
    n = _s_order(n)
    h = np.ones((1, 1))
    while len(h) < n + 1:
        h = np.block([[h, h], [h, -h]])
    return (1.0 - h[1:, 1:]) / 2.0


def s_matrix_inverse(n: int) -> np.ndarray:
    """``S^-1 = 2 / (n + 1) (2 S^T - J)``, ``J`` all ones: (n, n) float64.

    Each entry is ``+-2 / (n + 1)``, so every demultiplexed value is a sum of
    all ``n`` frames with equal weights (the origin of the additive-noise
    gain of :func:`hadamard_snr_gain`).
    """
    s = s_matrix(n)
    return 2.0 / (n + 1) * (2.0 * s.T - 1.0)


def _count(n_sources):
    try:
        n = check_number("n_sources", n_sources, lo=1, integer=True)
    except OptionError as exc:
        raise OptionError(exc.problem, field="n_sources") from None
    if n > MAX_SOURCES:
        raise OptionError(f"is {n}; codes are built for at most {MAX_SOURCES} sources", field="n_sources")
    return n


def _integers(value, n_sources, field, what, each):
    """(n_sources,) int64 from a sequence of integral numbers, or OptionError naming ``field``.

    ``what`` names the values ("source indices"), ``each`` what the sequence must do for each source.
    """
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        raise OptionError(f"must be a sequence of {what}", field=field) from None
    if arr.ndim != 1 or len(arr) != n_sources:
        raise OptionError(f"must {each}, got shape {arr.shape}", field=field)
    if arr.dtype.kind not in "iu":
        if arr.dtype.kind != "f" or not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
            raise OptionError(f"must hold integer {what}", field=field)
    return arr.astype(np.int64)


def _check_name(name):
    if not isinstance(name, str) or name not in CODES:
        raise OptionError(f"unknown code {name!r}{did_you_mean(str(name), CODES)}; codes are {', '.join(CODES)}",
                          field="name")


def _check_flag(complementary):
    if not isinstance(complementary, (bool, np.bool_)):
        raise OptionError(f"must be True or False, got {complementary!r}", field="complementary")
    return bool(complementary)


def _check_order(order, n_sources):
    """A permutation of ``range(n_sources)`` as int64, or OptionError naming ``order``."""
    if order is None:
        return np.arange(n_sources, dtype=np.int64)
    arr = _integers(order, n_sources, "order", "source indices", f"list each of the {n_sources} sources once")
    if not np.array_equal(np.sort(arr), np.arange(n_sources)):
        missing = np.setdiff1d(np.arange(n_sources), arr)
        raise OptionError(f"is not a permutation of 0..{n_sources - 1} (missing {missing[:8].tolist()}"
                          f"{' ...' if len(missing) > 8 else ''})", field="order")
    return arr


def _check_channels(channels, n_sources):
    """(n_sources,) int64 of 0, 1, 2, or OptionError naming ``channels``."""
    arr = _integers(channels, n_sources, "channels", "channels 0, 1, 2 (R, G, B)",
                    f"give each of the {n_sources} sources a channel")
    bad = np.flatnonzero((arr < 0) | (arr > 2))
    if len(bad):
        raise OptionError(f"must be 0, 1 or 2 (R, G, B); source(s) {bad[:8].tolist()} have "
                          f"{arr[bad[:8]].tolist()}", field="channels")
    return arr


def _column_positions(matrix, full):
    """For each column of ``matrix``, the index of the equal column of ``full``; None if one has none."""
    keys = {full[:, j].astype(bool).tobytes(): j for j in range(full.shape[1])}
    pos = [keys.get(matrix[:, s].astype(bool).tobytes()) for s in range(matrix.shape[1])]
    if any(p is None for p in pos):
        return None
    return np.array(pos, np.int64)


@dataclass(frozen=True, eq=False)
class Code:
    """A source display code: which sources each frame lights.

    Build one with :func:`make_code`; the constructor checks that the fields
    agree (a code read from a file, or edited by hand, cannot mislabel).

    Parameters
    ----------
    name : {"sequential", "binary", "gray", "hadamard"}
    n_sources : int
        Sources of the rig, ``1 .. MAX_SOURCES``.
    matrix : (n_frames, n_sources) float64 of 0 and 1
        ``matrix[f, s] = 1``: source ``s`` is lit in frame ``f``. Every
        source is lit in at least one frame and no two sources are lit in
        the same frames (the columns are distinct), so every source can be
        told from every other.
    codewords : (n_sources,) int64 or None
        Binary and Gray codes: source ``s``'s codeword, bit ``b`` (0 the
        most significant of ``n_bits``) set where the source is lit in bit
        frame ``b``; never 0 (colour codes: unique within the source's
        channel). None for the others.
    complementary : bool
        Binary and Gray codes: each bit frame is followed by its complement
        (``2 * n_bits`` frames). False for the others.
    order : (n_sources,) int64
        The permutation used to hand out codewords (columns): source
        ``order[i]`` gets the ``i``-th (codeword ``i + 1`` or ``g(i + 1)``,
        S-matrix column ``i``). Colour codes: within each channel, its
        sources take the inner code's columns in the order in which they
        appear here.
    channels : (n_sources,) int64 or None
        Colour codes: source ``s``'s fiber colour and camera channel, 0, 1
        or 2 (:data:`CHANNEL_NAMES`: R, G, B). The matrix then says in which
        frames each source is lit *in its colour*; sources of different
        colours may share their frames, sources of one colour may not.
        None (the default) for a code of one colour.
    """

    name: str
    n_sources: int
    matrix: np.ndarray
    codewords: np.ndarray | None
    complementary: bool
    order: np.ndarray
    channels: np.ndarray | None = None

    def __post_init__(self):
        def put(attr, value):
            object.__setattr__(self, attr, value)

        _check_name(self.name)
        put("n_sources", _count(self.n_sources))
        n = self.n_sources
        put("complementary", _check_flag(self.complementary))
        if self.complementary and self.name not in ("binary", "gray"):
            raise OptionError(f"only binary and gray codes have complementary frames, not {self.name!r}",
                              field="complementary")
        put("order", _check_order(self.order, n))
        try:
            m = np.array(self.matrix, dtype=np.float64)
        except (TypeError, ValueError):
            raise OptionError("must be a numeric (n_frames, n_sources) array", field="matrix") from None
        if m.ndim != 2 or m.shape[1] != n or m.shape[0] < 1:
            raise OptionError(f"must be (n_frames, {n}) for {n} sources, got shape {m.shape}", field="matrix")
        if not np.all((m == 0) | (m == 1)):
            raise OptionError("entries must be 0 (source off) or 1 (source on)", field="matrix")
        dark = np.flatnonzero(m.sum(axis=0) == 0)
        if len(dark):
            raise OptionError(f"source(s) {dark[:8].tolist()} are lit in no frame", field="matrix")
        if self.channels is not None:
            put("channels", _check_channels(self.channels, n))
        packed = np.packbits(m.astype(bool), axis=0)
        if self.channels is None:
            if len(np.unique(packed, axis=1).T) != n:
                raise OptionError("two sources are lit in the same frames: they cannot be told apart",
                                  field="matrix")
        else:
            for c in range(3):
                idx = np.flatnonzero(self.channels == c)
                if len(np.unique(packed[:, idx], axis=1).T) != len(idx):
                    raise OptionError(f"two sources of channel {CHANNEL_NAMES[c]} are lit in the same frames: they "
                                      "cannot be told apart", field="matrix")
            if self.name in ("sequential", "hadamard"):
                full = self._inner_full(m.shape[0])
                if full is None or _column_positions(m, full) is None:
                    raise OptionError(f"a colour {self.name} code's columns must be columns of the "
                                      f"{'identity' if self.name == 'sequential' else 'S-matrix'} of its "
                                      f"{m.shape[0]} frames", field="matrix")
        m.setflags(write=False)
        put("matrix", m)
        if self.name in ("binary", "gray"):
            if self.codewords is None:
                raise OptionError(f"a {self.name} code needs codewords", field="codewords")
            cw = np.asarray(self.codewords)
            if cw.shape != (n,) or cw.dtype.kind not in "iu":
                raise OptionError(f"must be ({n},) integers, got {cw.shape} {cw.dtype}", field="codewords")
            cw = cw.astype(np.int64)
            bits = self.n_bits
            if np.any(cw < 1) or np.any(cw >= 1 << bits):
                raise OptionError(f"must lie in 1 .. {(1 << bits) - 1} (0 would light a source in no bit frame)",
                                  field="codewords")
            if not np.array_equal(self.bit_matrix(cw, bits, self.complementary), m):
                raise OptionError("do not match the matrix", field="codewords")
            cw.setflags(write=False)
            put("codewords", cw)
        elif self.codewords is not None:
            raise OptionError(f"a {self.name} code has no codewords", field="codewords")
        self.order.setflags(write=False)
        if self.channels is not None:
            self.channels.setflags(write=False)

    # -- shape -----------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        """Frames a scan takes with this code."""
        return int(self.matrix.shape[0])

    @property
    def n_bits(self) -> int:
        """Binary and Gray codes: bits per codeword, ``ceil(log2(N + 1))`` (colour codes: ``N`` the
        :attr:`n_inner` sources of the inner code); 0 for the others."""
        return _bits_for(self.n_inner) if self.name in ("binary", "gray") else 0

    @property
    def colours(self) -> int:
        """3 for a colour code (:attr:`channels`), else 1."""
        return 1 if self.channels is None else 3

    @property
    def n_inner(self) -> int:
        """Sources the inner code is built for: the most any channel holds (``n_sources`` without colour)."""
        if self.channels is None:
            return self.n_sources
        return int(np.bincount(self.channels, minlength=3).max())

    def channel_sources(self, channel: int) -> np.ndarray:
        """Colour codes: (k,) int64, the sources of ``channel`` (0, 1, 2) in the order of their inner columns.

        For a code of one colour, ``channel`` 0 holds every source (in source order).
        """
        channel = named_check("channel", check_number, channel, lo=0, hi=self.colours - 1, integer=True)
        if self.channels is None:
            return np.arange(self.n_sources, dtype=np.int64)
        return self.order[self.channels[self.order] == channel]

    def _inner_full(self, n_frames):
        """The square matrix whose columns a linear colour code's columns are: I or the S-matrix (None if none)."""
        if self.name == "sequential":
            return np.eye(n_frames)
        if (n_frames + 1) & n_frames:
            return None
        return s_matrix(n_frames)

    @property
    def lit_per_frame(self) -> np.ndarray:
        """(n_frames,) int: sources lit in each frame."""
        return self.matrix.sum(axis=1).astype(int)

    @staticmethod
    def bit_matrix(codewords, n_bits, complementary) -> np.ndarray:
        """The frames of codewords: bit frames (most significant first), each followed by its complement."""
        cw = np.asarray(codewords, dtype=np.int64)
        shifts = np.arange(n_bits - 1, -1, -1)
        bits = ((cw[None, :] >> shifts[:, None]) & 1).astype(np.float64)
        if not complementary:
            return bits
        out = np.empty((2 * n_bits, len(cw)))
        out[0::2] = bits
        out[1::2] = 1.0 - bits
        return out

    def source_of_codeword(self, channel: int | None = None) -> np.ndarray:
        """Binary and Gray: (2**n_bits,) int64, the source of each codeword, -1 for unused ones (0 among them).

        Colour codes have one table per channel: give ``channel`` (0, 1, 2);
        the table holds the sources of that channel only.
        """
        if self.codewords is None:
            raise OptionError(f"a {self.name} code has no codewords", field="code")
        table = np.full(1 << self.n_bits, -1, np.int64)
        if self.channels is None:
            if channel is not None:
                raise OptionError("a code of one colour has one codeword table; give no channel", field="channel")
            table[self.codewords] = np.arange(self.n_sources)
            return table
        if channel is None:
            raise OptionError("a colour code has a codeword table per channel; give channel 0, 1 or 2",
                              field="channel")
        idx = self.channel_sources(channel)
        table[self.codewords[idx]] = idx
        return table

    def demultiplexer(self) -> np.ndarray:
        """Sequential and Hadamard: (n_sources, n_frames) float64 ``D`` with ``D @ matrix = I``.

        Row ``order[i]`` is row ``i`` of ``S^-1`` (:func:`s_matrix_inverse`;
        the identity for the sequential code), so ``x = D y`` recovers each
        source's frame from the coded frames exactly where ``y = matrix x``.
        Binary and Gray codes have fewer frames than sources: no linear
        inverse (they are decoded pixel by pixel). Colour codes: row ``s``
        inverts source ``s``'s column within its channel, so ``x_s = D[s]
        y_c`` with ``y_c`` the frames' channel ``c = channels[s]``
        (``D[idx] @ matrix[:, idx] = I`` for the sources ``idx`` of one
        channel).
        """
        if self.name not in ("sequential", "hadamard"):
            raise OptionError(f"a {self.name} code is decoded per pixel, not demultiplexed", field="code")
        inverse = np.eye(self.n_frames) if self.name == "sequential" else s_matrix_inverse(self.n_frames)
        if self.channels is not None:
            # colour: row s inverts source s's column within its own channel, x_s = D[s] @ y[..., channel(s)]
            return inverse[_column_positions(self.matrix, self._inner_full(self.n_frames))]
        out = np.empty((self.n_sources, self.n_frames))
        out[self.order] = inverse[: self.n_sources]
        return out

    # -- JSON ---------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The code as plain JSON: what :func:`make_code` needs, plus ``n_frames`` as a check.

        The matrix follows from ``name``, ``n_sources``, ``complementary``
        and ``order`` (and, for a colour code, ``colours`` and
        ``channels``); :meth:`from_dict` rebuilds it and checks the frame
        count.
        """
        d = {"format": CODE_FORMAT, "name": self.name, "n_sources": self.n_sources,
             "complementary": self.complementary, "order": self.order.tolist(), "n_frames": self.n_frames}
        if self.channels is not None:  # a code of one colour keeps exactly the fields it always had
            d["colours"] = self.colours
            d["channels"] = self.channels.tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Code:
        """A code from :meth:`to_dict`'s output.

        Raises
        ------
        OptionError
            An unknown or missing field, a wrong ``format``, a bad value, or a
            frame count that the rebuilt code does not have.
        """
        check_fields(d, ("format", "name", "n_sources", "complementary", "order", "n_frames", "colours", "channels"),
                     required=("name", "n_sources"), error=OptionError, field="code", what="code")
        fmt = d.get("format", CODE_FORMAT)
        if fmt != CODE_FORMAT:
            raise OptionError(f"is {fmt!r}, expected {CODE_FORMAT!r}", field="format")
        code = make_code(d["name"], d["n_sources"], complementary=d.get("complementary", d["name"] in ("binary", "gray")),
                         order=d.get("order"), colours=d.get("colours", 1), channels=d.get("channels"))
        if "n_frames" in d and d["n_frames"] != code.n_frames:
            raise OptionError(f"is {d['n_frames']!r} but a {code.name} code of {code.n_sources} sources has "
                              f"{code.n_frames} frames", field="n_frames")
        return code

    def __eq__(self, other):
        if not isinstance(other, Code):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    def __hash__(self):
        return hash((self.name, self.n_sources, self.complementary, self.order.tobytes(),
                     None if self.channels is None else self.channels.tobytes()))


def make_code(name: str, n_sources: int, *, complementary: bool = True, order: Any = None, colours: int = 1,
              channels: Any = None) -> Code:
    """Build a source display code.

    Parameters
    ----------
    name : {"sequential", "binary", "gray", "hadamard"}
        See ``docs/coded-scanning.md``, "The codes".
    n_sources : int
        Sources of the rig, ``1 .. MAX_SOURCES``.
    complementary : bool
        Binary and Gray codes: follow each bit frame by its complement
        (``2 ceil(log2(N + 1))`` frames; the decoder then compares each bit
        with its complement instead of with a per-pixel threshold, and sees
        collisions). Ignored by the other codes.
    order : sequence of int, optional
        A permutation of the sources: source ``order[i]`` gets the ``i``-th
        codeword. Default: source order. :func:`spatial_order` gives one in
        which neighbouring sources get Gray codewords one bit apart.
    colours : {1, 3}
        3: a colour code (``docs/coded-scanning.md``, "Colour multiplexing"). The inner code ``name``
        runs over each channel's sources with the frames shared, so the
        scan takes the frames of a ``name`` code for the largest channel's
        sources (``ceil(N / 3)``).
    channels : sequence of int, optional
        Colour codes: each source's channel, 0, 1 or 2 (R, G, B). Default:
        source ``order[i]`` takes channel ``i mod 3``, so consecutive sources
        of ``order`` differ in colour; :func:`colour_channels` gives
        channels that keep neighbouring directions apart.

    Returns
    -------
    Code

    Raises
    ------
    OptionError
        An unknown code, a source count outside ``1 .. MAX_SOURCES``, an
        order that is not a permutation, a colour count other than 1 or 3,
        channels for a code of one colour or channels not in 0, 1, 2; each
        names its field.
    """
    _check_name(name)
    n = _count(n_sources)
    _check_flag(complementary)
    order = _check_order(order, n)
    if isinstance(colours, (bool, np.bool_)) or colours not in COLOURS:
        raise OptionError(f"must be 1 or 3 (red, green and blue fibers), got {colours!r}", field="colours")
    if int(colours) == 3:
        return _make_colour_code(name, n, bool(complementary), order, channels)
    if channels is not None:
        raise OptionError("are for colour codes only (colours=3)", field="channels")
    i = np.arange(1, n + 1, dtype=np.int64)  # codeword ranks, never 0
    if name == "sequential":
        cols, codewords, complementary = np.eye(n), None, False
    elif name == "hadamard":
        cols, codewords, complementary = s_matrix(hadamard_order(n))[:, :n], None, False
    else:
        ranked = i if name == "binary" else gray(i)
        cols = Code.bit_matrix(ranked, _bits_for(n), bool(complementary))
        codewords = np.empty(n, np.int64)
        codewords[order] = ranked
    matrix = np.empty_like(cols)
    matrix[:, order] = cols
    return Code(name, n, matrix, codewords, bool(complementary), order)


def _make_colour_code(name, n, complementary, order, channels):
    """A colour code: the inner code ``name`` for the largest channel, its columns handed out per channel."""
    if channels is None:
        channels = np.empty(n, np.int64)
        channels[order] = np.arange(n) % 3
    channels = _check_channels(channels, n)
    inner = make_code(name, int(np.bincount(channels, minlength=3).max()), complementary=complementary)
    matrix = np.empty((inner.n_frames, n))
    codewords = None if inner.codewords is None else np.empty(n, np.int64)
    for c in range(3):
        idx = order[channels[order] == c]  # in the order's order: inner columns 0, 1, ...
        matrix[:, idx] = inner.matrix[:, : len(idx)]
        if codewords is not None:
            codewords[idx] = inner.codewords[: len(idx)]
    return Code(name, n, matrix, codewords, inner.complementary, order, channels)


def fiber_emission(leak: float = 0.0) -> np.ndarray:
    """(3, 3) float64: column ``c`` the linear RGB light of a fiber of colour ``c`` (R, G, B), unit in its own.

    A fiber behind a colour filter (or an LED of one colour) emits its own
    colour, 1, and ``leak`` of it in each of the other two: ``E = I + leak
    (J - I)``. The per-source frames are rendered under white sources, so a
    fiber's light at a pixel is ``E[:, c] * rgb`` (channel by channel).

    Parameters
    ----------
    leak : float
        In ``[0, 1)``: the filter's transmission outside its band, relative
        to inside it.
    """
    leak = named_check("leak", check_number, leak, lo=0, hi=1, hi_open=True)
    return np.eye(3) + leak * (np.ones((3, 3)) - np.eye(3))


def encode_colour(frames: Any, code: Code, emission: Any = None) -> np.ndarray:
    """RGB coded frames from RGB per-source frames: each source's light in its fiber's colour, summed.

    ``coded[f, ..., j] = sum over the sources s lit in f of emission[j, channels[s]] * frames[s, ..., j]``:
    the light (linear RGB, before any camera) with the frame's sources lit
    together, each through its fiber's colour filter.

    Parameters
    ----------
    frames : (n_sources, H, W, 3) array_like
        Linear RGB per-source frames rendered under white sources, finite.
    code : Code
        A colour code (``colours=3``) for ``n_sources`` sources.
    emission : (3, 3) array_like, optional
        :func:`fiber_emission` (column ``c``: the RGB light of a fiber of
        colour ``c``); default the identity (pure colours).

    Returns
    -------
    (n_frames, H, W, 3) float32
        Each value is a float64 sum rounded once to float32.
    """
    check_code(code)
    if code.channels is None:
        raise OptionError(f"is a {code.name} code of one colour; RGB frames need a colour code "
                          "(make_code(..., colours=3))", field="code")
    e = (np.eye(3) if emission is None
         else check_matrix("emission", emission, "a 3 x 3 array of finite numbers >= 0", nonnegative=True))
    arr = _source_frames(frames, code, colour=True)
    return _lit_sums(arr, [code.matrix * e[j, code.channels][None, :] for j in range(3)])


def check_code(code: Any) -> Code:
    """``code`` if it is a :class:`Code`, else OptionError naming ``code``."""
    if not isinstance(code, Code):
        raise OptionError(f"must be a Code (make_code), got {type(code).__name__}", field="code")
    return code


def _source_frames(frames, code, *, colour):
    """Per-source frames, (n_sources, H, W) or with ``colour`` (n_sources, H, W, 3), checked against ``code``."""
    arr = np.asarray(frames)
    if arr.ndim != 3 + colour or (colour and arr.shape[-1] != 3):
        raise OptionError(f"must be (n_sources, H, W{', 3' if colour else ''}), got shape {arr.shape}",
                          field="frames")
    if arr.dtype.kind not in "fiu":
        raise OptionError(f"must hold numbers, got {arr.dtype}", field="frames")
    if len(arr) != code.n_sources:
        raise OptionError(f"holds {len(arr)} source frames but the {code.name} code is for {code.n_sources} "
                          "sources", field="frames")
    return arr


def _lit_sums(arr, weights):
    """``weights[j] @ arr[..., j]`` per pixel (one weight matrix: ``arr`` has no channel axis), float32.

    Blocks of rows are converted to float64 (at most :data:`_BLOCK` values each) and checked finite.
    """
    n, h, w = arr.shape[:3]
    n_frames = len(weights[0])
    out = np.empty((n_frames,) + arr.shape[1:], np.float32)
    rows = max(1, _BLOCK // max(1, n * w))
    for r0 in range(0, h, rows):
        for j, m in enumerate(weights):
            at = (slice(None), slice(r0, r0 + rows), slice(None)) + ((j,) if arr.ndim == 4 else ())
            block = arr[at].astype(np.float64).reshape(n, -1)
            if not np.all(np.isfinite(block)):
                raise OptionError(f"has NaN or inf pixels (rows {r0}..{min(h, r0 + rows) - 1})", field="frames")
            out[at] = (m @ block).reshape(n_frames, -1, w)
    return out


def encode(frames: Any, code: Code) -> np.ndarray:
    """Coded frames from per-source frames: ``coded[f] = sum of frames[s] over the sources lit in f``.

    Light adds, so this is exactly the ideal (noiseless, unclipped) frame a
    camera would see with those sources lit together; a sensor acts on it
    afterwards (:func:`shinysim.sim.coded.coded_stack`).

    Parameters
    ----------
    frames : (n_sources, H, W) array_like
        Linear per-source frames (radiance), finite.
    code : Code
        For ``n_sources`` sources.

    Returns
    -------
    (n_frames, H, W) float32
        Each value is the float64 sum of the lit sources' values, rounded
        once to float32 (exact where at most one lit source is nonzero).

    Notes
    -----
    Memory: the stack is read in blocks of rows, each converted to float64
    (at most ``2**22`` values, 32 MB) and multiplied by the 0/1 matrix; no
    float64 copy of the whole stack is made. The output is the only
    stack-sized allocation.
    """
    return _lit_sums(_source_frames(frames, check_code(code), colour=False), [code.matrix])


# -- signal to noise ----------------------------------------------------------------


def hadamard_snr_gain(n: int, noise: str = "additive", signal: Any = None, *, read_noise: float = 0.0,
                      pixels: str = "all") -> float | np.ndarray:
    r"""Signal-to-noise gain of S-matrix multiplexing over sequential scanning.

    Both scans use the same exposure per frame; the gain is the noise
    standard deviation of a sequentially measured source frame over that of
    the demultiplexed one (> 1: multiplexing helps).

    Parameters
    ----------
    n : int
        Order of the S-matrix, ``2**m - 1`` (sources = frames = ``n``).
    noise : {"additive", "shot"}
        ``"additive"``: signal-independent noise of the same variance in
        every frame (read noise, quantisation). ``"shot"``: photon noise
        (variance = mean electrons) plus ``read_noise``.
    signal : float or array_like, optional
        ``"shot"``: mean photo-electrons that the one source lighting the
        pixel delivers in a frame where it is lit (a sparse, shiny scene:
        one source per pixel). None: the shot-noise limit (``read_noise``
        negligible).
    read_noise : float
        ``"shot"``: electrons rms added to every frame.
    pixels : {"all", "lit", "unlit"}
        ``"shot"``: which demultiplexed value: ``"lit"``, the estimate of
        the source that lights the pixel (the highlight itself);
        ``"unlit"``, that of a source that does not (the noise a highlight
        leaves in the other sources' frames); ``"all"``, the root mean square
        over all ``n`` sources at the pixel (a whole frame's noise power).

    Returns
    -------
    float or ndarray

    Notes
    -----
    Additive noise gains ``(n + 1) / (2 sqrt n)`` (Harwit & Sloane 1979);
    under dominant shot noise the lit pixel gains ``sqrt((n + 1) / 2)`` and
    a whole frame loses, ``sqrt((n + 1) / (2 n))``. The derivations:
    ``docs/coded-scanning.md``, "Signal to noise of the Hadamard code".
    """
    n = _s_order(n)
    check_choice("noise", noise, SNR_NOISES)
    check_choice("pixels", pixels, SNR_PIXELS)
    if noise == "additive":
        return (n + 1) / (2.0 * math.sqrt(n))
    r2 = check_number("read_noise", read_noise, lo=0) ** 2
    if signal is None:
        x, r2 = 1.0, 0.0  # the limit: read noise negligible against the signal
    else:
        x = np.asarray(signal, dtype=float)
        if not np.all(np.isfinite(x)) or np.any(x < 0):
            raise OptionError("must be finite and >= 0 electrons", field="signal")
    multiplexed = 2.0 * x / (n + 1) + 4.0 * n * r2 / (n + 1) ** 2
    sequential = {"lit": x + r2, "unlit": r2 + 0.0 * x, "all": x / n + r2}[pixels]
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = np.sqrt(np.where(multiplexed > 0, sequential / np.where(multiplexed > 0, multiplexed, 1.0),
                                (n + 1) / (2.0 * math.sqrt(n))))
    return float(gain) if np.ndim(gain) == 0 else gain


# -- spatially aware codeword order -------------------------------------------------------


def hilbert_index(x: Any, y: Any, bits: int = 16) -> np.ndarray:
    """Position along a Hilbert curve of integer grid points ``0 <= x, y < 2**bits``.

    The curve visits every cell of the ``2**bits`` square grid once, each
    step to an edge neighbour, so points close along it are close on the
    grid (the converse fails across the curve's quadrant seams).
    """
    bits = int(check_number("bits", bits, lo=1, hi=30, integer=True))
    x = np.array(x, dtype=np.int64)
    y = np.array(y, dtype=np.int64)
    side = 1 << bits
    if np.any((x < 0) | (x >= side) | (y < 0) | (y >= side)):
        raise OptionError(f"grid coordinates must lie in 0 .. {side - 1}", field="x, y")
    d = np.zeros(np.broadcast(x, y).shape, np.int64)
    x, y = np.broadcast_arrays(x, y)
    x, y = x.copy(), y.copy()
    s = side // 2
    while s > 0:
        rx = (x & s) > 0
        ry = (y & s) > 0
        d += s * s * ((3 * rx.astype(np.int64)) ^ ry.astype(np.int64))
        flip = (~ry) & rx
        x = np.where(flip, side - 1 - x, x)
        y = np.where(flip, side - 1 - y, y)
        swap = ~ry
        x, y = np.where(swap, y, x), np.where(swap, x, y)
        s //= 2
    return d


def _directions(directions):
    """(N, 3) float directions and their lengths, checked (field ``directions``)."""
    d = np.asarray(directions, dtype=float)
    if d.ndim != 2 or d.shape[1] != 3 or len(d) < 1:
        raise OptionError(f"must be (N, 3) with N >= 1, got shape {d.shape}", field="directions")
    norm = np.linalg.norm(d, axis=1)
    if not np.all(np.isfinite(d)) or np.any(norm == 0):
        raise OptionError("must be finite, non-zero directions", field="directions")
    return d, norm


def spatial_order(directions: Any, *, bits: int = 16) -> np.ndarray:
    """A source order along a space-filling path over the dome, for spatially aware codes.

    ``make_code("gray", N, order=spatial_order(dirs))`` hands out Gray
    codewords along the path, so sources next to each other on the path get
    codewords one bit apart. Where the highlights of two such sources
    overlap on the image (a curved object's neighbouring normals), the
    collision damages one bit: the decoder
    (:func:`shinysim.recon.coding.decode`) sees light in both that bit frame
    and its complement, flags the pixels, and knows the pair (the two
    codewords that agree in every other bit); in that bit frame and its
    complement each source's light is seen alone.

    Parameters
    ----------
    directions : (N, 3) array_like
        Directions from the object towards the sources (need not be unit);
        the dome's axis is +z.
    bits : int
        Hilbert grid resolution (``2**bits`` cells a side): fine enough that
        no two sources share a cell.

    Returns
    -------
    (N,) int64
        A permutation of the sources: ``order[i]`` is the ``i``-th along the path.

    Notes
    -----
    Lambert's equal-area projection about +z, then the order along a
    Hilbert curve over a ``2**bits`` grid of the projected points. Design
    and limits: ``docs/coded-scanning.md``, "A spatially aware order".
    """
    d, norm = _directions(directions)
    u = d / norm[:, None]
    if np.any(u[:, 2] <= -1 + 1e-12):
        raise OptionError("a direction points straight down (-z): it has no place on the dome's map",
                          field="directions")
    k = np.sqrt(2.0 / (1.0 + u[:, 2]))
    p = u[:, :2] * k[:, None]
    lo = p.min(axis=0)
    span = float(np.max(p.max(axis=0) - lo))
    side = 1 << int(check_number("bits", bits, lo=1, hi=30, integer=True))
    if span == 0:
        return np.arange(len(d), dtype=np.int64)
    g = np.clip(np.floor((p - lo) / span * side), 0, side - 1).astype(np.int64)
    h = hilbert_index(g[:, 0], g[:, 1], bits)
    return np.lexsort((np.arange(len(d)), h)).astype(np.int64)


def colour_channels(directions: Any, *, order: Any = None, neighbours: int = 6) -> np.ndarray:
    """Fiber colours for a dome's sources such that neighbouring directions mostly differ in colour.

    ``make_code(name, N, colours=3, order=order, channels=colour_channels(dirs, order=order))``.

    Parameters
    ----------
    directions : (N, 3) array_like
        Directions from the object towards the sources.
    order : sequence of int, optional
        The order in which sources are coloured (default :func:`spatial_order`
        of the directions): each takes, of the channels not yet full
        (``ceil(N / 3)`` sources each, so the code's frame count is that of
        ``ceil(N / 3)`` sources), the one least used by its already
        coloured neighbours.
    neighbours : int
        How many nearest directions count as a source's neighbours (6: a
        source on an even dome has about six).

    Returns
    -------
    (N,) int64 of 0, 1, 2

    Notes
    -----
    Greedy colouring of the graph of each source's ``neighbours`` nearest
    directions, a neighbour weighted by the inverse of its angle (close
    ones matter most); a tie goes to the channel ``i mod 3`` of the
    source's place ``i`` in ``order``. A dome's neighbour graph is a
    triangulation, which three colours cannot colour without some equal
    neighbours in general. On the Fibonacci dome of 200 sources 4 % of the
    sources share the colour of their nearest neighbour (22 % for
    ``i mod 3`` along :func:`spatial_order`, 33 % at random).
    """
    d, norm = _directions(directions)
    n = len(d)
    order = spatial_order(d) if order is None else _check_order(order, n)
    k = int(named_check("neighbours", check_number, neighbours, lo=1, integer=True))
    k = min(k, n - 1)
    u = d / norm[:, None]
    cap = -(-n // 3)
    channels = np.full(n, -1, np.int64)
    used = np.zeros(3, np.int64)
    for i, s in enumerate(order):
        cost = np.zeros(3)
        if k > 0:
            ang = np.arccos(np.clip(u @ u[s], -1.0, 1.0))
            ang[s] = np.inf
            near = np.argpartition(ang, k - 1)[:k]
            for j in near:
                if channels[j] >= 0:
                    cost[channels[j]] += 1.0 / max(float(ang[j]), 1e-9)
        cost[used >= cap] = np.inf
        tie = (np.arange(3) - i) % 3  # channel i mod 3 first
        c = int(np.lexsort((tie, cost))[0])
        channels[s] = c
        used[c] += 1
    return channels
