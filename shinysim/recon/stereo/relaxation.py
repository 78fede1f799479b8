"""Ambiguity: support between candidates on one smooth surface, Marr-Poggio style relaxation and uniqueness (Eq 35).

See ``docs/stereo-matching.md`` for every definition.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from ..._shared import thread_map
from ._base import _PAIR_PIECE, _STEP, _dot_c, _per_piece, _pieces

__all__ = []


def _group_max(key, values, n):
    """The largest of ``values`` in each group ``0 .. n-1`` of ``key`` (-inf where a group is empty)."""
    best = np.full(n, -np.inf)
    np.maximum.at(best, key, values)
    return best


def _competitor_max(values, i, j, n1, n2):
    """For each candidate: the largest value among the candidates sharing its i or its j (itself included),
    and the largest among those other than itself."""
    idx = np.arange(len(values))

    def per_group(key, n):
        best = _group_max(key, values, n)
        # one holder of each group's best (the last), then the best of the rest of the group
        holder = np.full(n, -1)
        top = values >= best[key]
        np.maximum.at(holder, key[top], idx[top])
        rest = idx != holder[key]
        second = _group_max(key[rest], values[rest], n)
        return best[key], np.where(rest, best[key], second[key])

    best_i, other_i = per_group(i, n1)
    best_j, other_j = per_group(j, n2)
    return np.maximum(best_i, best_j), np.maximum(other_i, other_j)


def _spatial_order(P):
    """A permutation that puts nearby points near each other in memory: strips a few point spacings
    wide across the two widest axes, sorted along each strip (the sparse products of the relaxation
    then read their neighbours from cache)."""
    k = len(P)
    lo, hi = P.min(axis=0), P.max(axis=0)
    ext = hi - lo
    a0, a1 = np.argsort(-ext)[:2]
    cell = 8.0 * math.sqrt(max(ext[a0] * ext[a1], 1e-300) / max(k, 1))
    if not (np.isfinite(cell) and cell > 0):
        return np.arange(k)
    strip = np.floor((P[:, a1] - lo[a1]) / cell)
    # one sort key: the strip, then the place along it (any order serves; results do not depend on it)
    return np.argsort(strip * (2.0 * ext[a0] + 1.0) + (P[:, a0] - lo[a0]))


#: Points whose nearest-neighbour distances :func:`_median_nn` takes the median of, at most.
_NN_SAMPLE = 16384


def _median_nn(tree, P):
    """Median distance from each point to its nearest other point (0 with fewer than two points).

    Beyond :data:`_NN_SAMPLE` points, the median over every ``s``-th point (``s`` the smallest stride
    that keeps the sample within it; each still searched against all the points): a sample of 16384
    puts the median within about 1 % of the whole set's (its standard error is about 1.25 sigma / sqrt(n)
    with sigma, the spread of the distances, below their median), and the support radius it sets is a
    rule of thumb (:class:`StereoParams`), not a measurement.

    The nearest neighbours are searched within a bound first (a few times the median spacing that the
    points' spread suggests, then four times wider): once more than half of the points have theirs
    within it, the middle of the sorted distances is known exactly, and the others (marked infinite)
    cannot change it; a full search otherwise."""
    k = len(P)
    if k < 2:
        return 0.0
    ext = np.sort(P.max(axis=0) - P.min(axis=0))[::-1]
    guess = math.sqrt(max(ext[0] * ext[1], 1e-300) / k)
    if k > _NN_SAMPLE:
        P = P[::-(-k // _NN_SAMPLE)]
        k = len(P)
    for bound in (guess, 4.0 * guess, None):
        if bound is None or not (np.isfinite(bound) and bound > 0):
            dist, _ = tree.query(P, k=2)
            nn = dist[:, 1][np.isfinite(dist[:, 1])]
            return float(np.median(nn)) if nn.size else 0.0
        dist, _ = tree.query(P, k=2, distance_upper_bound=bound)
        if np.count_nonzero(np.isfinite(dist[:, 1])) >= k // 2 + 1:
            return float(np.median(dist[:, 1]))


def _support_matrix(P, N, i, j, radius, rise_tol, gap0, tree=None, cols=None, workers=1):
    """Sparse symmetric weights between candidates that fit one smooth surface (``docs/stereo-matching.md``).

    ``cols`` (optional): a label per candidate (a permutation); each row's entries are then stored in
    increasing ``cols`` (the order in which the products sum), the column indices staying those of ``P``."""
    k = len(P)
    if k < 2 or radius <= 0:
        return sparse.csr_matrix((k, k))
    tree = cKDTree(P) if tree is None else tree
    pairs = tree.query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return sparse.csr_matrix((k, k))
    cols = np.arange(k) if cols is None else cols
    index = np.int32 if k < 2**31 - 1 else np.int64
    lab = cols.astype(index)
    Pc = [np.ascontiguousarray(P[:, c]) for c in range(3)]
    Nc = [np.ascontiguousarray(N[:, c]) for c in range(3)]
    m = len(pairs)
    gap = np.broadcast_to(np.asarray(gap0, float), (k,))  # each candidate's normal limit

    def piece(sl):
        # component by component (the same operations as on (K, 3) rows, so the same bits)
        a, b = pairs[sl, 0], pairs[sl, 1]
        distinct = (i[a] != i[b]) & (j[a] != j[b])
        a, b = a[distinct], b[distinct]
        dP = [v[b] - v[a] for v in Pc]
        h = [0.5 * (v[a] + v[b]) for v in Nc]
        rise = np.abs(_dot_c(dP, h))
        tol = rise_tol + np.sqrt(_dot_c(dP, dP)) * np.sin(0.5 * (gap[a] + gap[b]))
        wgt = np.exp(-0.5 * (rise / tol) ** 2)
        return (np.concatenate([a, b]).astype(index), np.concatenate([lab[b], lab[a]]),
                np.concatenate([wgt, wgt]))

    # in pieces (small temporaries, on threads); the pieces' order does not matter: each row is sorted below
    parts = thread_map(piece, [slice(a, a + _PAIR_PIECE) for a in range(0, m, _PAIR_PIECE)], workers)
    rows, labels, data = (np.concatenate(v) for v in zip(*parts))
    # canonical CSR: each row's entries sorted by label
    W = sparse.coo_matrix((data, (rows, labels)), shape=(k, k)).tocsr()
    W.sort_indices()
    inv = np.empty(k, index)
    inv[cols] = np.arange(k, dtype=index)
    return sparse.csr_matrix((W.data, inv[W.indices], W.indptr), shape=(k, k))


def _relax(a0, gvec, W, i, j, n1, n2, gap0, iterations, tol, workers=1):
    """Relaxation to a fixed point (``docs/stereo-matching.md``); returns the final x, activations, support, steps.

    A candidate without competitors keeps activation 1 exactly (``x / x``) as long as its ``x`` is
    positive and finite, which holds when no candidate has 700 neighbours or more (``x >= a0 exp(-bias)``
    with ``a0 >= exp(-2)`` and ``bias <= 1 + support``): the steps then update only the candidates with
    competitors, and every candidate gets its final ``x`` and support at the end."""
    act = np.ones_like(a0)
    steps = 0
    k = len(a0)
    g = [np.ascontiguousarray(gvec[:, c]) for c in range(3)]
    rows = np.arange(k)
    if k and int(np.max(np.diff(W.indptr))) < 700:
        ni = np.bincount(i, minlength=n1)
        nj = np.bincount(j, minlength=n2)
        rows = np.flatnonzero((ni[i] > 1) | (nj[j] > 1))
    Wr = W if len(rows) == k else W[rows]

    gap0 = np.broadcast_to(np.asarray(gap0, float), (k,))  # each candidate's normal limit

    def excite(act, M, own_g, own_a0, own_gap):
        support = M @ act
        one = 1.0 + support
        # the neighbourhood's mean normal gap: zero-mean scatter on a real surface, a smooth bias on a ghost
        gb = [(own_g[c] + M @ (act * g[c])) / one for c in range(3)]
        with np.errstate(divide="ignore", invalid="ignore"):
            bias = np.where(own_gap > 0, one * _dot_c(gb, gb) / own_gap**2, 0.0)
        return own_a0 * np.exp(-bias) * one, support

    ir, jr, g_r, a0_r, gap_r = i[rows], j[rows], [v[rows] for v in g], a0[rows], gap0[rows]
    nr = len(rows)
    # the rows in blocks, one per thread (a row's sums are the same whichever block holds it)
    blocks = {sl.start: Wr[sl] for sl in _pieces(nr, workers)}

    def step_all(act):
        return _per_piece(lambda sl: excite(act, blocks[sl.start], [v[sl] for v in g_r], a0_r[sl], gap_r[sl]), nr,
                          workers)[0]

    def step_some(act, sub):
        return _per_piece(lambda sl: excite(act, Wr[sub[sl]], [v[sub[sl]] for v in g_r], a0_r[sub[sl]],
                                            gap_r[sub[sl]]), len(sub), workers)[0]

    def group_best(x):
        # the largest x among each row's competitors (the rows sharing its i or its j), itself included
        return np.maximum(_group_max(ir, x, n1)[ir], _group_max(jr, x, n2)[jr])

    local = np.full(k, -1, np.int64)
    local[rows] = np.arange(nr)
    x_r = np.zeros(nr)
    last_pull = np.zeros(nr)  # each row's last pull towards its target (the damping's memory)
    sub = None  # None: every row; else the rows (local indices) that this step updates
    if nr:
        # the start: every activation at its first target, x over the largest x of its competitors
        x = step_all(act)
        act[rows] = x / group_best(x)
    for steps in range(1, iterations + 1):
        if sub is None:
            x = step_all(act)
            x_r[:] = x
        else:
            x = step_some(act, sub)
            x_r[sub] = x
        best = group_best(x_r)
        idx = rows if sub is None else rows[sub]
        # damped: a candidate's activation moves _STEP of the way to its new value, half way where its pull
        # turned since its last update (rivals taking turns: the half step keeps them from oscillating)
        old = act[idx]
        pull = x / (best if sub is None else best[sub]) - old
        at = slice(None) if sub is None else sub
        new = old + np.where(pull * last_pull[at] < 0, 0.5, _STEP) * pull
        last_pull[at] = pull
        moved = np.abs(new - old)
        act[idx] = new
        change = float(np.max(moved)) if len(moved) else 0.0
        if sub is None:
            if change <= tol:
                break
            if np.count_nonzero(moved > tol) * 8 > nr:
                continue
        elif change <= tol:
            # the rows left out moved by at most tol / 4 when last updated: a step over every
            # row says whether this is the fixed point
            sub = None
            continue
        # the next step updates only the rows still moving, their competitors and their support neighbours
        # (the rows whose inputs moved); a full step ends the run, so the stopping rule is the plain one
        warm = np.flatnonzero(moved > tol / 4)
        hot = np.flatnonzero(moved > tol)
        if sub is not None:
            warm, hot = sub[warm], sub[hot]
        near = local[Wr[hot].indices]
        touched = np.isin(ir, ir[hot]) | np.isin(jr, jr[hot])
        touched[near[near >= 0]] = True
        touched[warm] = True
        sub = np.flatnonzero(touched)
    x, support = _per_piece(lambda sl: excite(act, W[sl], [v[sl] for v in g], a0[sl], gap0[sl]), k, workers)
    return x, act, support, steps


def _greedy_fast(score, i, j, n1, n2):
    """Greedy uniqueness: repeatedly accept every candidate that is the best of its i and of its j."""
    alive = np.ones(len(score), bool)
    take = np.zeros(len(score), bool)
    key = score.astype(float)
    # ties broken by (i, j) so that the result does not depend on the candidates' order
    rank = np.empty(len(key), np.int64)
    rank[np.lexsort((j, i, -key))] = np.arange(len(key))
    prio = -rank.astype(float)  # larger is better, all distinct
    while np.any(alive):
        idx = np.flatnonzero(alive)
        best_i, best_j = _group_max(i[idx], prio[idx], n1), _group_max(j[idx], prio[idx], n2)
        win = idx[(prio[idx] >= best_i[i[idx]]) & (prio[idx] >= best_j[j[idx]])]
        take[win] = True
        alive[idx] = ~(np.isin(i[idx], i[win]) | np.isin(j[idx], j[win]))
    return take
