"""Array kernels of the fleet core: the scalar client core's arithmetic, element-wise over many entities.

Why a copy of the arithmetic and not a call: the fleet core (fleet.py) must decide exactly what each entity's
`Player` would, so every kernel repeats one scalar routine's IEEE-754 operations in the same order (numpy's
element-wise +, -, *, / and sqrt are correctly rounded, as Python's floats are; branches become `np.where` over
values computed for every element). The one exception is `hypot`: numpy's and Python's `math.hypot` differ in the
last bit for about 0.6 % of inputs, so distances go through `math.hypot` itself (`hypot_py`). The scalar
originals are named in each docstring; tests/entitynet/client/test_fleet.py checks the results bit for bit.
"""

from __future__ import annotations

import math
import os

import numpy as np

from entitynet.client.kinematics import A_EPS
from entitynet.client.limits import HORIZON
from entitynet.client.network import NetView
from entitynet.client.tracker import DOPPLER_ALONG_SHARE, DOPPLER_MOVING

try:  # the compiled kernels, where pip built them (setup.py; optional): entitynet/client/_fleet.pyx
    from entitynet.client import _fleet as COMPILED  # type: ignore[attr-defined]
except ImportError:  # the numpy references below
    COMPILED = None
_K = None  # the compiled kernels in use (`use_compiled`), or None: the numpy references


def use_compiled(flag: bool = True) -> bool:
    """Select the fleet's kernels for this process: the compiled ones (`_fleet.pyx`) when `flag` and they were
    built, else the numpy references. Returns whether the compiled ones are now in use."""
    global _K
    _K = COMPILED if flag and COMPILED is not None else None
    return _K is not None


def compiled_in_use() -> bool:
    """Whether the compiled kernels are in use (the bench reports it)."""
    return _K is not None


def compiled() -> object | None:
    """The compiled kernels' module when in use, else None (fleet_near.py asks before its search)."""
    return _K


def hypot_py(dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """`math.hypot` element-wise (numpy's hypot is not always the same last bit)."""
    if _K is not None:
        return _K.hypot_rows(dx, dy)
    return np.fromiter(map(math.hypot, dx.tolist(), dy.tolist()), float, len(dx))


def bisect_right_ranges(a: np.ndarray, x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """`bisect.bisect_right(a, x[i], lo[i], hi[i])` for every i: the same halving steps, all rows at once."""
    lo = lo.copy()
    hi = hi.copy()
    while True:
        act = lo < hi
        if not act.any():
            return lo
        mid = (lo + hi) // 2
        left = x < a[np.where(act, mid, 0)]
        hi = np.where(act & left, mid, hi)
        lo = np.where(act & ~left, mid + 1, lo)


class Geometry:
    """The network's geometry as flat numpy arrays (the NetView's lists, converted once per view): vertices,
    per-vertex segment terms of `Placer._edge_segs`, and per-edge lengths and flags."""

    def __init__(self, net: NetView) -> None:
        self.edge_len = np.array(net.edge_len, dtype=float)
        self.geom_off = np.array(net.geom_off, dtype=np.int64)
        self.gx = np.array(net.gx, dtype=float)
        self.gy = np.array(net.gy, dtype=float)
        self.gcum = np.array(net.gcum, dtype=float)
        gx, gy, gcum = self.gx, self.gy, self.gcum
        # segment k runs from vertex k to k + 1 (the last vertex of an edge starts none: its terms are unused)
        self.sdx = np.append(gx[1:] - gx[:-1], 0.0)
        self.sdy = np.append(gy[1:] - gy[:-1], 0.0)
        self.sl2 = self.sdx * self.sdx + self.sdy * self.sdy
        self.slen = np.append(gcum[1:] - gcum[:-1], 0.0)
        self.nseg = self.geom_off[1:] - self.geom_off[:-1] - 1
        area = np.array(net.node_area, dtype=np.int64)
        ef, et = np.array(net.edge_from, dtype=np.int64), np.array(net.edge_to, dtype=np.int64)
        self.inner = (area[ef] < 0) & (area[et] < 0)  # neither end is an area node

    def project(self, x: np.ndarray, y: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, ...]:
        """`Placer.project_on(x[i], y[i], e[i])` for every i (edges with at least one segment): (offset,
        px, py, distance), the first least distance over each edge's segments winning (none finite: offset 0,
        foot (0, 0), distance inf, as `project_on`). The compiled kernel where in use, else `project_np`."""
        if _K is not None:
            return _K.project(self, x, y, e)
        return self.project_np(x, y, e)

    def project_np(self, x: np.ndarray, y: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, ...]:
        """`project` in numpy (the reference)."""
        counts = self.nseg[e]
        n = len(e)
        start = np.cumsum(counts) - counts
        rep = np.repeat(np.arange(n), counts)
        k = np.arange(int(counts.sum())) - start[rep] + self.geom_off[e][rep]
        ax, ay, dx, dy, l2 = self.gx[k], self.gy[k], self.sdx[k], self.sdy[k], self.sl2[k]
        xr, yr = x[rep], y[rep]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = ((xr - ax) * dx + (yr - ay) * dy) / l2
        u = np.where(l2 <= 0.0, 0.0, u)
        u = np.where(u < 0.0, 0.0, np.where(u > 1.0, 1.0, u))
        px, py = ax + u * dx, ay + u * dy
        d = hypot_py(xr - px, yr - py)
        d = np.where(d < math.inf, d, math.inf)  # (NaN: never the least, as `dd < best_d` in `project_on`)
        dmin = np.minimum.reduceat(d, start)
        hit = np.flatnonzero(d == dmin[rep])
        best = hit[np.searchsorted(rep[hit], np.arange(n))]
        found = dmin < math.inf
        return (np.where(found, self.gcum[k[best]] + u[best] * self.slen[k[best]], 0.0),
                np.where(found, px[best], 0.0), np.where(found, py[best], 0.0), d[best])

    def path_xy(self, s: np.ndarray, pe: np.ndarray, pd: np.ndarray, cum: np.ndarray,
                n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`Path.xy(s[i])` for rows of padded paths: edges `pe`, directions `pd`, cumulative lengths `cum`
        (+inf past the path's `n` edges, n >= 1). The compiled kernel where in use, else `path_xy_np`."""
        if _K is not None:
            return _K.path_xy(self, s, pe, pd, cum, n)
        return self.path_xy_np(s, pe, pd, cum, n)

    def path_xy_np(self, s: np.ndarray, pe: np.ndarray, pd: np.ndarray, cum: np.ndarray,
                   n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`path_xy` in numpy (the reference)."""
        rows = np.arange(len(s))
        k = (cum <= s[:, None]).sum(axis=1) - 1
        k = np.where(k < 0, 0, np.where(k >= n, n - 1, k))
        e = pe[rows, k]
        length = self.edge_len[e]
        d = s - cum[rows, k]
        d = np.where(d < 0.0, 0.0, np.where(d > length, length, d))
        off = np.where(pd[rows, k] > 0, d, length - d)
        lo, hi = self.geom_off[e], self.geom_off[e + 1]
        kk = bisect_right_ranges(self.gcum, off, lo, hi) - 1
        kk = np.where(kk < lo, lo, np.where(kk > hi - 2, hi - 2, kk))
        c0 = self.gcum[kk]
        seg = self.gcum[kk + 1] - c0
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(seg <= 0.0, 0.0, (off - c0) / seg)
        gx, gy = self.gx, self.gy
        x0, y0 = gx[kk], gy[kk]
        x = x0 + t * (gx[kk + 1] - x0)
        y = y0 + t * (gy[kk + 1] - y0)
        at_start = off <= 0.0
        at_end = off >= self.gcum[hi - 1]
        x = np.where(at_start, gx[lo], np.where(at_end, gx[hi - 1], x))
        y = np.where(at_start, gy[lo], np.where(at_end, gy[hi - 1], y))
        return x, y


def advance(v: np.ndarray, a: np.ndarray, vmax: np.ndarray, dt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`kinematics.advance(v, a, vmax, dt)` element-wise: (distance, speed)."""
    a = np.where((a > -A_EPS) & (a < A_EPS), 0.0, a)
    with np.errstate(all="ignore"):
        t_stop = v / -a
        h_dt = v * dt + 0.5 * a * dt * dt
        v_dt = v + a * dt
        neg_d = np.where(dt >= t_stop, v * t_stop + 0.5 * a * t_stop * t_stop, h_dt)
        neg_v = np.where(dt >= t_stop, 0.0, v_dt)
        t_cap = (vmax - v) / a
        pos_d = np.where(dt <= t_cap, h_dt, v * t_cap + 0.5 * a * t_cap * t_cap + vmax * (dt - t_cap))
        pos_v = np.where(dt <= t_cap, v_dt, vmax)
    neg = a < 0.0
    pos = (a > 0.0) & (v < vmax)
    dist = np.where(neg, neg_d, np.where(pos, pos_d, v * dt))
    speed = np.where(neg, neg_v, np.where(pos, pos_v, v))
    still = dt <= 0.0
    return np.where(still, 0.0, dist), np.where(still, v, speed)


def ghost_s_speed(t: np.ndarray, t0, s0, v, a, vmax, tb, sb, vb, b, stop_s) -> tuple[np.ndarray, ...]:
    """The path coordinate and speed of `NetworkModel.xy_speed_at(t)` before the mapping to (x, y):
    (s, speed, beyond the horizon)."""
    dt = t - t0
    beyond = dt > HORIZON
    dt = np.where(beyond, HORIZON, dt)
    ds, v1 = advance(v, a, vmax, dt)
    const = (dt > 0.0) & (a > -A_EPS) & (a < A_EPS)
    s1 = np.where(const, s0 + v * dt, s0 + ds)
    v1 = np.where(const, v, v1)
    with np.errstate(all="ignore"):
        ds3, v3 = advance(vb, -b, vb, dt - tb)
        s3 = sb + ds3
    s3 = np.where(stop_s < s3, stop_s, s3)  # min(sb + ds, stop_s)
    free = dt <= tb
    finite_b = np.isfinite(b)
    s = np.where(free, s1, np.where(finite_b, s3, sb))
    speed = np.where(free, v1, np.where(finite_b, v3, 0.0))
    return s, speed, beyond


def kf_update(z, t, r, s, v, a, p00, p01, p02, p11, p12, p22, kt, q, accel) -> tuple[np.ndarray, ...]:
    """`Kinematic1D.update(z, t, r)` element-wise for rows with t > kt (the caller checks): the new (s, v, a,
    p00, p01, p02, p11, p12, p22) and the innovation variance (where it is not > 0 the scalar skips the update:
    the caller leaves those rows to it)."""
    dt = t - kt
    h = 0.5 * dt * dt
    dt2 = dt * dt
    dt3 = dt2 * dt
    # accelerating filter
    sa = s + (v * dt + a * h)  # `s += v * dt + a * h`: the sum first
    va = v + a * dt
    r00 = p00 + dt * p01 + h * p02
    r01 = p01 + dt * p11 + h * p12
    r02 = p02 + dt * p12 + h * p22
    r11 = p11 + dt * p12
    r12 = p12 + dt * p22
    a00 = r00 + dt * r01 + h * r02 + q * dt3 * dt2 / 20.0
    a01 = r01 + dt * r02 + q * dt2 * dt2 / 8.0
    a02 = r02 + q * dt3 / 6.0
    a11 = r11 + dt * r12 + q * dt3 / 3.0
    a12 = r12 + q * dt2 / 2.0
    a22 = p22 + q * dt
    # constant-velocity filter
    sc = s + v * dt
    c00 = p00 + 2.0 * dt * p01 + dt * dt * p11 + q * dt * dt * dt / 3.0
    c01 = p01 + dt * p11 + q * dt * dt / 2.0
    c11 = p11 + q * dt
    s = np.where(accel, sa, sc)
    v = np.where(accel, va, v)
    p00 = np.where(accel, a00, c00)
    p01 = np.where(accel, a01, c01)
    p02 = np.where(accel, a02, p02)
    p11 = np.where(accel, a11, c11)
    p12 = np.where(accel, a12, p12)
    p22 = np.where(accel, a22, p22)
    y = z - s
    sden = p00 + r
    with np.errstate(all="ignore"):
        k0, k1, k2 = p00 / sden, p01 / sden, p02 / sden
    return (s + k0 * y, v + k1 * y, a + k2 * y, p00 - k0 * p00, p01 - k0 * p01, p02 - k0 * p02,
            p11 - k1 * p01, p12 - k1 * p02, p22 - k2 * p02, sden)


def fuse_rows(geo: Geometry, vel: np.ndarray, s: np.ndarray, pe: np.ndarray, pd: np.ndarray, cum: np.ndarray,
              n: np.ndarray, has_route: np.ndarray, accel: np.ndarray, *kf: np.ndarray) -> tuple[np.ndarray, ...]:
    """`NetworkTracker.fuse_velocity` then `Kinematic1D.update_speed` element-wise on an edge: rows with a
    velocity (`vel[:, 3]`, its (vx, vy, variance) in `vel[:, :3]`) at path coordinate `s` (the last fix's) fold
    in its component along the path (the chord from s - 1 to s + 1 m); a moving one mostly across the path, or
    against an a-priori route, is left out, as is a row whose chord or innovation variance is not > 0. `kf`:
    (s, v, a, p00, p01, p02, p11, p12, p22); returns them updated (the same operations, in the same order)."""
    fs, fv, fa, p00, p01, p02, p11, p12, p22 = kf
    length = cum[np.arange(len(s)), n]
    hx, hy = geo.path_xy(np.minimum(s + 1.0, length), pe, pd, cum, n)
    bx, by = geo.path_xy(np.maximum(s - 1.0, 0.0), pe, pd, cum, n)
    vx, vy, rv = (np.ascontiguousarray(vel[:, j]) for j in range(3))
    norm = hypot_py(hx - bx, hy - by)
    with np.errstate(all="ignore"):
        along = (vx * (hx - bx) + vy * (hy - by)) / norm
    speed = hypot_py(vx, vy)
    across = (speed >= DOPPLER_MOVING) & ((np.abs(along) < DOPPLER_ALONG_SHARE * speed) | (has_route & (along < 0.0)))
    sden = p11 + rv
    use = (vel[:, 3] > 0.0) & (norm > 0.0) & ~across & (sden > 0.0)
    if not use.any():
        return kf
    y = along - fv
    with np.errstate(all="ignore"):
        k0, k1, k2 = p01 / sden, p11 / sden, p12 / sden
    acc = use & (accel != 0)
    return (np.where(use, fs + k0 * y, fs), np.where(use, fv + k1 * y, fv), np.where(acc, fa + k2 * y, fa),
            np.where(use, p00 - k0 * p01, p00), np.where(use, p01 - k0 * p11, p01),
            np.where(acc, p02 - k0 * p12, p02), np.where(use, p11 - k1 * p11, p11),
            np.where(acc, p12 - k1 * p12, p12), np.where(acc, p22 - k2 * p12, p22))


def extend_rows(players, net, sl: np.ndarray, ext: np.ndarray, need: np.ndarray, pe: np.ndarray, pd: np.ndarray,
                pc: np.ndarray, pn: np.ndarray) -> np.ndarray:
    """`NetworkTracker._maintain_path`'s extension ahead for rows `ext` of the path arrays (changed in place):
    the edges `follow` gives (route or junction rule) appended with the cumulative lengths `Path.extended`
    computes (the same additions). Returns per row of `ext` whether nothing followed (a dead end)."""
    from entitynet.client.path import follow
    from entitynet.client.tracker import MAX_PATH_EDGES

    dead = np.zeros(len(ext), dtype=bool)
    edge_len = net.edge_len
    for i, r in enumerate(ext.tolist()):
        trk = players[int(sl[r])].tracker
        n = int(pn[r])
        last = (int(pe[r, n - 1]), int(pd[r, n - 1]))
        length = float(pc[r, n])
        ahead = follow(net, last, trk.etype.networks, float(need[r]) - length, trk.route.edges,
                       trk.route.index(last), max_edges=MAX_PATH_EDGES - n)
        if not ahead:
            dead[i] = True
            continue
        c = length
        for j, (e, d) in enumerate(ahead):
            c = c + edge_len[e]
            pe[r, n + j], pd[r, n + j], pc[r, n + j + 1] = e, d, c
        pn[r] = n + len(ahead)
    return dead


def interval_rows(ring: np.ndarray, n: np.ndarray, dt: np.ndarray, max_gap: np.ndarray, lost_after: np.ndarray,
                  reacquire: np.ndarray, vmax: np.ndarray, gap_intervals: float,
                  min_intervals: int) -> tuple[np.ndarray, ...]:
    """`UpdateRules.note_interval` (with `usual_interval`, `gap_limit`) and the Player's `reach` for every row:
    the interval ring (oldest first, the last n columns used) with dt appended where 0 < dt < lost_after,
    its count, the gap limit, the along-path reach (rows with fewer than `min_intervals`: max_gap and
    reacquire), and the usual interval itself (their median; 0.0 with fewer)."""
    k = ring.shape[1]
    rec = (dt > 0.0) & (dt < lost_after)
    ring = np.where(rec[:, None], np.concatenate([ring[:, 1:], dt[:, None]], axis=1), ring)
    n = np.where(rec, np.minimum(n + 1, k), n)
    v = np.sort(np.where(np.arange(k)[None, :] >= (k - n)[:, None], ring, np.inf), axis=1)
    rows = np.arange(len(n))
    lo, hi = np.maximum(n - 1, 0) // 2, n // 2
    med = (v[rows, lo] + v[rows, np.minimum(hi, k - 1)]) / 2.0
    some = n >= min_intervals
    gap = np.where(some, np.minimum(np.maximum(max_gap, gap_intervals * med), np.maximum(max_gap, 0.5 * lost_after)),
                   max_gap)
    reach = np.where(some, np.maximum(reacquire, vmax * med), reacquire)
    return ring, n, gap, reach, np.where(some, med, 0.0)



use_compiled(not os.environ.get("ENTITYNET_PURE_PYTHON"))
