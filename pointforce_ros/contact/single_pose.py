"""Compiled (numba) kernels of the contact simulator's single-pose query (issue 21).

A planner's single query touches 50-300 candidate contacts: the numpy form of steps 1 and 3-5
of :meth:`~pointforce_ros.contact.simulator.ContactSimulator._run` spends most of its time in
the fixed cost of 80 numpy calls, not in arithmetic. These kernels do the same arithmetic in
loops compiled once per machine (``cache=True``: the first import compiles in a few seconds and
stores the code beside this file, or in numba's user cache where that is not writable; later
processes load it). The neighbour search of step 2 (:func:`three_nearest`) serves the batched
numpy path too, so that both break ties between equidistant surface points alike.

Each kernel is the numpy code's twin, in the same order of operations where the order decides
a result (the de-duplications keep the same candidate, in the same order); only sums of a few
terms may round differently (1e-16 relative). ``test/core/test_contact_single_pose.py`` checks
them against the batched numpy path, which shares none of their code past the neighbour
search.

Units: metres and newtons; every array is float64 or int64 and C-contiguous (the callers make
it so).
"""

import math
from typing import Tuple

import numba
from numba import boolean, float64, int64, types
import numpy as np

OK = 0
"""Status of :func:`solve_single`: solved."""

NOT_CONVERGED = 1
"""Status: the pivoting did not converge within ``max_iter`` rounds."""

SINGULAR = 2
"""Status: a free set's matrix was not positive definite even with a ridge."""

MAX_KEY_POINTS = 2_000_000
"""Largest surface the triple key ``(i * N + j) * N + k`` fits int64 for."""

_JIT = dict(cache=True, nogil=True, error_model='numpy')

_V = types.Array(float64, 1, 'C', readonly=True)
_M = types.Array(float64, 2, 'C', readonly=True)
_I = types.Array(int64, 1, 'C', readonly=True)
_IM = types.Array(int64, 2, 'C', readonly=True)
_B = types.Array(boolean, 1, 'C', readonly=True)
# explicit argument types, read-only C arrays (a writable one converts): compiled, or loaded
# from the cache, at import, once; a caller passing another layout is told so instead of
# paying a second compilation mid-request


@numba.njit((_M, _M, _V, _M, float64, _V, float64, _I, _M), **_JIT)
def prefilter(local, to_frame, offset, rot, floor, origin, cell, last, bound):
    """Step 1: the rigid samples that may penetrate, in the projection plane and in ``base``.

    Args:
        local: (R, 3) rigid samples in the mesh frame.
        to_frame: (3, 3) mesh frame -> ``(a, e1, e2)``.
        offset: (3,) the pose's position in ``(a, e1, e2)``.
        rot: (3, 3) mesh frame -> ``base`` rotation.
        floor: lowest per-cell height bound of the projection.
        origin, cell, last, bound: the projection grid (:class:`_Projection`).

    Returns:
        ``uv`` (K, 2) plane coordinates and ``posed`` (K, 3) rotated samples (``base`` less the
        pose's position) of the samples above their cell's bound, in sample order.

    """
    n = local.shape[0]
    uv = np.empty((n, 2))
    posed = np.empty((n, 3))
    k = 0
    lim = floor - offset[0]
    for r in range(n):
        x, y, z = local[r, 0], local[r, 1], local[r, 2]
        rise = x * to_frame[0, 0] + y * to_frame[1, 0] + z * to_frame[2, 0]
        if not rise > lim:
            continue
        u = x * to_frame[0, 1] + y * to_frame[1, 1] + z * to_frame[2, 1] + offset[1]
        v = x * to_frame[0, 2] + y * to_frame[1, 2] + z * to_frame[2, 2] + offset[2]
        ci = min(max(np.int64(math.floor((u - origin[0]) / cell)), 0), last[0])
        cj = min(max(np.int64(math.floor((v - origin[1]) / cell)), 0), last[1])
        if not rise + offset[0] > bound[ci, cj]:
            continue
        uv[k, 0] = u
        uv[k, 1] = v
        posed[k, 0] = x * rot[0, 0] + y * rot[0, 1] + z * rot[0, 2]
        posed[k, 1] = x * rot[1, 0] + y * rot[1, 1] + z * rot[1, 2]
        posed[k, 2] = x * rot[2, 0] + y * rot[2, 1] + z * rot[2, 2]
        k += 1
    return uv[:k], posed[:k]


@numba.njit((float64, float64, float64, float64), **_JIT)
def neighbour_weights(r0, r1, r2, r3):
    """Weights of a sample's 3 nearest points at in-plane distances ``r0 <= r1 <= r2``.

    ``w_k = (r3 - r_k) / sum``, ``r3`` the fourth-nearest distance (at most ``max_gap``): a
    point's weight vanishes where it leaves the three (``r2 = r3``), so the averages of step 2
    are continuous as a sample moves across the surface, where equal weights step each time
    the third and fourth nearest swap. Equal weights where all four are equally far.
    """
    w0, w1, w2 = max(r3 - r0, 0.0), max(r3 - r1, 0.0), max(r3 - r2, 0.0)
    total = w0 + w1 + w2
    if not total > 0.0:
        return 1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0
    return w0 / total, w1 / total, w2 / total


@numba.njit((_M, _V, float64, _I, _I, _I, _M, float64, boolean), **_JIT)
def three_nearest(uv, origin, cell, last, starts, members, facing, max_gap, smooth):
    """Step 2's neighbour search: the 3 nearest facing points of each ``uv`` within ``max_gap``.

    A KD-tree query for 3 neighbours plus a ``max_gap`` test on the third, as a fixed-radius
    search: the projection grid's cells are at least ``max_gap`` wide, so the 3 x 3 cells
    around a sample hold every point that can count. Equal distances go to the lower facing
    index (a KD-tree breaks such ties by its traversal).

    Args:
        uv: (K, 2) samples in the projection plane.
        origin, cell, last: the projection grid (padded; :class:`_Projection`).
        starts: (cells + 1,) CSR offsets of each cell (row-major over the grid) into
            ``members``.
        members: (F,) facing-point positions (rows of ``facing``) sorted by cell.
        facing: (F, 2) the facing points in the projection plane.
        smooth: weigh the three by :func:`neighbour_weights` (else 1/3 each).

    Returns:
        ``nn`` (J, 3) positions in ``facing``, nearest first, their weights ``w`` (J, 3) and
        ``rows`` (J,) the samples whose third-nearest point lies within ``max_gap``, in
        sample order.

    """
    n = uv.shape[0]
    ny = last[1] + 1
    nn = np.empty((n, 3), dtype=np.int64)
    w = np.empty((n, 3))
    rows = np.empty(n, dtype=np.int64)
    best = np.empty(4)
    pick = np.empty(4, dtype=np.int64)
    slots = 4 if smooth else 3
    j = 0
    for k in range(n):
        u, v = uv[k, 0], uv[k, 1]
        ci = min(max(np.int64(math.floor((u - origin[0]) / cell)), 0), last[0])
        cj = min(max(np.int64(math.floor((v - origin[1]) / cell)), 0), last[1])
        best[:] = np.inf
        pick[:] = -1
        tail = slots - 1
        for a in range(max(ci - 1, 0), min(ci + 1, last[0]) + 1):
            for b in range(max(cj - 1, 0), min(cj + 1, last[1]) + 1):
                key = a * ny + b
                for s in range(starts[key], starts[key + 1]):
                    m = members[s]
                    du = facing[m, 0] - u
                    dv = facing[m, 1] - v
                    d2 = du * du + dv * dv
                    if d2 > best[tail] or (d2 == best[tail] and m > pick[tail]):
                        continue
                    slot = tail
                    while slot > 0 and (d2 < best[slot - 1]
                                        or (d2 == best[slot - 1] and m < pick[slot - 1])):
                        best[slot] = best[slot - 1]
                        pick[slot] = pick[slot - 1]
                        slot -= 1
                    best[slot] = d2
                    pick[slot] = m
        if pick[2] >= 0 and math.sqrt(best[2]) <= max_gap:
            nn[j, 0], nn[j, 1], nn[j, 2] = pick[0], pick[1], pick[2]
            if smooth:
                w[j, 0], w[j, 1], w[j, 2] = neighbour_weights(
                    math.sqrt(best[0]), math.sqrt(best[1]), math.sqrt(best[2]),
                    min(math.sqrt(best[3]), max_gap))
            else:
                w[j, 0] = w[j, 1] = w[j, 2] = 1.0 / 3.0
            rows[j] = k
            j += 1
    return nn[:j], w[:j], rows[:j]


@numba.njit((_I, _I), **_JIT)
def _repeats(key, order):
    """Whether any two neighbours of ``key[order]`` (sorted) are equal."""
    for a in range(1, len(order)):
        if key[order[a]] == key[order[a - 1]]:
            return True
    return False


@numba.njit((_I, _V, _I), **_JIT)
def _deepest_first(key, e, order):
    """Keep the deepest entry (first of equal depths) per run of equal ``key[order]``."""
    keep = np.empty(len(order), dtype=np.int64)
    n = 0
    i = 0
    while i < len(order):
        j = i
        top = e[order[i]]
        pick = order[i]
        while j + 1 < len(order) and key[order[j + 1]] == key[order[i]]:
            j += 1
            if e[order[j]] > top:
                top = e[order[j]]
                pick = order[j]
        keep[n] = pick
        n += 1
        i = j + 1
    return keep[:n]


@numba.njit((_M, _V), **_JIT)
def _cholesky_solve(A, b):
    """Solve ``A x = b`` for symmetric positive definite ``A`` (m, m); ``ok`` False if not."""
    m = A.shape[0]
    L = np.zeros((m, m))
    for j in range(m):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return np.zeros(m), False
        L[j, j] = math.sqrt(s)
        for i in range(j + 1, m):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    y = np.empty(m)
    for i in range(m):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    x = np.empty(m)
    for i in range(m - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, m):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return x, True


@numba.njit((_M, _V, _B, int64, float64), **_JIT)
def bpp(G, d, free, max_iter, tol):
    """Block principal pivoting: :func:`~pointforce_ros.contact.lcp.bpp_dense` compiled.

    Returns ``(x, rounds, status)`` with ``status`` :data:`OK`, :data:`NOT_CONVERGED` or
    :data:`SINGULAR`.
    """
    m = len(d)
    F = free.copy()
    top = 0.0
    for i in range(m):
        top = max(top, abs(d[i]))
    eps = tol * max(top, 1e-300)
    best = m + 1
    chances = 3
    x = np.zeros(m)
    w = np.empty(m)
    bad = np.empty(m, dtype=np.int64)
    for it in range(1, max_iter + 1):
        x[:] = 0.0
        idx = np.flatnonzero(F)
        k = len(idx)
        if k:
            sub = np.empty((k, k))
            rhs = np.empty(k)
            for a in range(k):
                rhs[a] = d[idx[a]]
                for b in range(k):
                    sub[a, b] = G[idx[a], idx[b]]
            xf, ok = _cholesky_solve(sub, rhs)
            if not ok:
                scale = 1.0
                for a in range(k):
                    scale = max(scale, abs(sub[a, a]))
                for a in range(k):
                    sub[a, a] += 1e-9 * scale
                xf, ok = _cholesky_solve(sub, rhs)
                if not ok:
                    return np.maximum(x, 0.0), it, SINGULAR
            for a in range(k):
                x[idx[a]] = xf[a]
        nbad = 0
        for i in range(m):
            s = 0.0
            for j in range(m):
                s += G[i, j] * x[j]
            w[i] = s - d[i]
            if (F[i] and x[i] < -eps) or (not F[i] and w[i] < -eps):
                bad[nbad] = i
                nbad += 1
        if nbad == 0:
            return np.maximum(x, 0.0), it, OK
        if nbad < best:
            best = nbad
            chances = 3
            for a in range(nbad):
                F[bad[a]] = not F[bad[a]]
        elif chances > 0:
            chances -= 1
            for a in range(nbad):
                F[bad[a]] = not F[bad[a]]
        else:
            F[bad[nbad - 1]] = not F[bad[nbad - 1]]
    return np.maximum(x, 0.0), max_iter, NOT_CONVERGED


@numba.njit((_IM, _M, _M, _V, _M, float64, float64, boolean, _V, boolean, float64, float64,
             float64, int64, float64), **_JIT)
def solve_single(nbr, w, posed, pos, table, c, decay, penetration_law, thickness, flat,
                 reference, floor_share, warm_start, max_iter, tol):
    """Solve steps 2 (after the search), 3 and 4 of one pose: candidates, dedupes, LCP.

    Args:
        nbr: (K, 3) int64 surface indices of each sample's three nearest points (within
            ``max_gap``).
        w: (K, 3) their weights (each row sums to one; :func:`three_nearest`).
        posed: (K, 3) their rotated samples, ``base`` less ``pos``.
        pos: (3,) the pose's position, ``base``.
        table: (N, 8) per surface point: normal, ``n . x``, onset, position.
        c, decay: shape-function constant and tail length (``inf``: no tail), metres.
        penetration_law: decay lengths grow with each contact's penetration
            (``decay * max(e, floor_share * reference) / reference``); False: one ``decay``.
        thickness: (N,) per surface point the layer proxy of the ``'layer'`` law: with
            ``penetration_law``, every length of the pose is also multiplied by the median
            over its candidates of their three neighbours' weighted mean proxy; empty: not.
        flat: the flat-topped near field ``(1 + r / c) exp(-r / c)`` instead of the paper's
            ``c / (c + r)`` (:data:`~pointforce_ros.contact.lcp.NEARS`).
        warm_start: the first free set: penetration >= ``warm_start`` x the deepest.
        max_iter, tol: the pivoting's limits (as :func:`bpp`).

    Returns:
        ``(keep, p, q, nq, d, e, G, x, u, residual, status)``: the kept candidates' rows of
        ``nbr`` (M,), their positions ``p`` (M, 3), equilibrium points ``q`` (M, 3), unit
        normals ``nq`` (M, 3), nominal displacements ``d`` and penetrations ``e`` (M,), the
        shape matrix ``G`` (M, M), the actual displacements ``x``, ``u = G x``, the LCP
        residual and the pivoting's status. No candidate: M = 0.
    """
    K = nbr.shape[0]
    N = table.shape[0]
    sums = np.empty((K, 8))
    d_all = np.empty(K)
    e_all = np.empty(K)
    p_all = np.empty((K, 3))
    positive = np.empty(K, dtype=np.int64)
    npos = 0
    for k in range(K):
        i0, i1, i2 = nbr[k, 0], nbr[k, 1], nbr[k, 2]
        w0, w1, w2 = w[k, 0], w[k, 1], w[k, 2]
        for j in range(8):
            sums[k, j] = w0 * table[i0, j] + w1 * table[i1, j] + w2 * table[i2, j]
        for j in range(3):
            p_all[k, j] = posed[k, j] + pos[j]
        dot = p_all[k, 0] * sums[k, 0] + p_all[k, 1] * sums[k, 1] + p_all[k, 2] * sums[k, 2]
        d_all[k] = sums[k, 3] - dot
        e_all[k] = d_all[k] - sums[k, 4]
        if e_all[k] > 0.0:
            positive[npos] = k
            npos += 1
    idx = positive[:npos]
    # front-most sample per surface location (key: first neighbour), sorted by key when any
    # key repeats (as the numpy path's stable sort)
    if npos > 1:
        key = np.empty(npos, dtype=np.int64)
        for a in range(npos):
            key[a] = nbr[idx[a], 0]
        order = np.argsort(key, kind='mergesort')
        if _repeats(key, order):
            depth = np.empty(npos)
            for a in range(npos):
                depth[a] = e_all[idx[a]]
            idx = idx[_deepest_first(key, depth, order)]
    # then per neighbour triple, lexicographic order when any triple repeats
    n = len(idx)
    if n > 1:
        tri = np.empty(n, dtype=np.int64)
        depth = np.empty(n)
        for a in range(n):
            i0, i1, i2 = nbr[idx[a], 0], nbr[idx[a], 1], nbr[idx[a], 2]
            lo, hi = min(i0, i1), max(i0, i1)
            low, high = min(lo, i2), max(hi, i2)
            mid = max(lo, min(hi, i2))
            tri[a] = (low * N + mid) * N + high
            depth[a] = e_all[idx[a]]
        by_depth = np.argsort(-depth, kind='mergesort')
        order = by_depth[np.argsort(tri[by_depth], kind='mergesort')]
        if _repeats(tri, order):
            keep = np.empty(n, dtype=np.int64)
            m = 0
            for a in range(n):
                if a == 0 or tri[order[a]] != tri[order[a - 1]]:
                    keep[m] = idx[order[a]]
                    m += 1
            idx = keep[:m]
    M = len(idx)
    p = np.empty((M, 3))
    q = np.empty((M, 3))
    nq = np.empty((M, 3))
    d = np.empty(M)
    e = np.empty(M)
    top = -np.inf
    for a in range(M):
        k = idx[a]
        norm = math.sqrt(sums[k, 0] ** 2 + sums[k, 1] ** 2 + sums[k, 2] ** 2)
        for j in range(3):
            p[a, j] = p_all[k, j]
            q[a, j] = sums[k, 5 + j]
            nq[a, j] = sums[k, j] / norm
        d[a] = d_all[k]
        e[a] = e_all[k]
        top = max(top, e[a])
    # 4. the shape matrix and the LCP
    G = np.empty((M, M))
    lengths = np.empty(M)
    varying = penetration_law and math.isfinite(decay)
    if varying:
        scale = 1.0
        if len(thickness) > 0 and M > 0:
            proxy = np.empty(M)
            for a in range(M):
                k = idx[a]
                proxy[a] = (w[k, 0] * thickness[nbr[k, 0]] + w[k, 1] * thickness[nbr[k, 1]]
                            + w[k, 2] * thickness[nbr[k, 2]])
            scale = np.median(proxy)
        for a in range(M):
            lengths[a] = scale * decay * max(e[a], floor_share * reference) / reference
    for i in range(M):
        G[i, i] = 1.0           # g(0) = 1 under both laws
        for j in range(i + 1, M):   # symmetric: each pair once
            dx = q[i, 0] - q[j, 0]
            dy = q[i, 1] - q[j, 1]
            dz = q[i, 2] - q[j, 2]
            r = math.sqrt(dx * dx + dy * dy + dz * dz)
            g = (1.0 + r / c) * math.exp(-r / c) if flat else c / (c + r)
            if varying:
                s2 = 0.5 * (lengths[i] * lengths[i] + lengths[j] * lengths[j])
                g *= (lengths[i] * lengths[j] / s2) ** 1.5
                g *= math.exp(-r / math.sqrt(s2))
            elif math.isfinite(decay):
                g *= math.exp(r * (-1.0 / decay))
            G[i, j] = g
            G[j, i] = g
    free = np.empty(M, dtype=np.bool_)
    for a in range(M):
        free[a] = e[a] >= warm_start * top
    x, _, status = bpp(G, e, free, max_iter, tol)
    u = np.empty(M)
    residual = 0.0
    for i in range(M):
        s = 0.0
        for j in range(M):
            s += G[i, j] * x[j]
        u[i] = s
        residual = max(residual, abs(min(x[i], s - e[i])))
    return idx, p, q, nq, d, e, G, x, u, residual, status


@numba.njit((_M, _M, _V, _M, float64, _V, float64, _I, _M, _I, _I, _M, _I, float64, boolean,
             _V, _M, float64, float64, boolean, _V, boolean, float64, float64, float64, int64,
             float64), **_JIT)
def single_query(local, to_frame, offset, rot, floor, origin, cell, last, bound, starts, members,
                 facing, facing_index, max_gap, smooth, pos, table, c, decay, penetration_law,
                 thickness, flat, reference, floor_share, warm_start, max_iter, tol):
    """Solve steps 1-4 of one pose in one call.

    :func:`prefilter`, :func:`three_nearest`, then :func:`solve_single`, with their arguments;
    ``facing_index`` (F,) maps rows of ``facing`` to surface indices.

    Returns:
        ``nbr`` (K, 3) surface indices of every candidate and their weights ``w`` (K, 3),
        followed by what :func:`solve_single` returns (``keep`` indexes both).

    """
    uv, posed = prefilter(local, to_frame, offset, rot, floor, origin, cell, last, bound)
    nn, w, rows = three_nearest(uv, origin, cell, last, starts, members, facing, max_gap,
                                smooth)
    nbr = np.empty(nn.shape, dtype=np.int64)
    near = np.empty((len(rows), 3))
    for k in range(len(rows)):
        for j in range(3):
            nbr[k, j] = facing_index[nn[k, j]]
            near[k, j] = posed[rows[k], j]
    out = solve_single(nbr, w, near, pos, table, c, decay, penetration_law, thickness, flat,
                       reference, floor_share, warm_start, max_iter, tol)
    return (nbr, w) + out


@numba.njit((_V, _M, _V, int64, float64), **_JIT)
def _interpolate(depths, forces, slopes, i, d):
    """One ``y(x_i, d)`` of a baked table: :meth:`BakedResponse.force` for one entry."""
    n = len(depths)
    if d > depths[n - 1]:
        return forces[i, n - 1] + slopes[i] * (d - depths[n - 1])
    k = np.searchsorted(depths, d, side='right') - 1
    k = min(max(k, 0), n - 2)
    lo, hi = depths[k], depths[k + 1]
    w = min(max((d - lo) / (hi - lo), 0.0), 1.0)
    f0 = forces[i, k]
    return f0 + w * (forces[i, k + 1] - f0)


@numba.njit((_IM, _M, _V, _V, _M, _M, _V, _V, _M, _V), **_JIT)
def baked_wrench(nbr, w, d, x, nq, p, centre, depths, forces, slopes):
    """Step 5 with a baked response: per-contact forces ``f`` (M,) and the wrench (6,).

    ``f_i = sum over the 3 neighbours, weighted by w_i, of y(d_i) - y(d_i - x_i)`` for
    ``x_i > 0`` (else 0);
    force ``sum f_i nq_i`` and torque ``sum (p_i - centre) x f_i nq_i``.
    """
    M = len(d)
    f = np.zeros(M)
    wrench = np.zeros(6)
    for a in range(M):
        if not x[a] > 0.0:
            continue
        s = 0.0
        for j in range(3):
            i = nbr[a, j]
            s += w[a, j] * (_interpolate(depths, forces, slopes, i, d[a])
                            - _interpolate(depths, forces, slopes, i, d[a] - x[a]))
        f[a] = s
    for a in range(M):
        fx, fy, fz = f[a] * nq[a, 0], f[a] * nq[a, 1], f[a] * nq[a, 2]
        ax, ay, az = p[a, 0] - centre[0], p[a, 1] - centre[1], p[a, 2] - centre[2]
        wrench[0] += fx
        wrench[1] += fy
        wrench[2] += fz
        wrench[3] += ay * fz - az * fy
        wrench[4] += az * fx - ax * fz
        wrench[5] += ax * fy - ay * fx
    return f, wrench


def cell_members(uv: np.ndarray, origin: np.ndarray, cell: float,
                 last: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """CSR of points ``uv`` (F, 2) over a grid: ``(starts, members)`` for :func:`three_nearest`.

    ``starts`` (cells + 1,) int64 offsets into ``members`` (F,), the point rows sorted by their
    row-major cell (clipped to the grid as the kernels clip).
    """
    cij = np.floor((uv - origin) / cell).astype(np.int64)
    cij = np.minimum(np.maximum(cij, 0), last)
    key = cij[:, 0] * (int(last[1]) + 1) + cij[:, 1]
    members = np.argsort(key, kind='stable').astype(np.int64)
    cells = (int(last[0]) + 1) * (int(last[1]) + 1)
    starts = np.searchsorted(key[members], np.arange(cells + 1)).astype(np.int64)
    return starts, members


def baked_tables(response) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return a baked response's ``(depths, forces, slopes)`` as contiguous float64 arrays."""
    return (np.ascontiguousarray(response.depths, dtype=np.float64),
            np.ascontiguousarray(response.forces, dtype=np.float64),
            np.ascontiguousarray(response.slopes, dtype=np.float64))


__all__ = ['MAX_KEY_POINTS', 'NOT_CONVERGED', 'OK', 'SINGULAR', 'baked_tables', 'baked_wrench',
           'bpp', 'cell_members', 'neighbour_weights', 'prefilter', 'single_query',
           'solve_single', 'three_nearest']
