"""The fleet core's vectorised fix: `Player.feed` for many entities at once where it ends in the usual update.

Why a module of its own: the fix is the fleet core's one long computation (prediction, projection onto the path
or the neighbourhood search, the along-path filter, the path's trim and extension, `UpdateRules.decide` against
the ghost, then the commit of the rows that stayed in arrays); fleet.py keeps the slots, the tick's order and
the calls to the Players. `fast_fixes` reads and writes the `FleetCore`'s columns (its record's numpy views and
its derived columns) and leaves every row it cannot decide, with the reason, to the scalar path.
"""

from __future__ import annotations

import math

import numpy as np

from entitynet.client.fleet_kernels import extend_rows, fuse_rows, ghost_s_speed, hypot_py, interval_rows, kf_update
from entitynet.client.fleet_near import near_fixes, s_of_rows
from entitynet.client.rules import GAP_INTERVALS, MIN_INTERVALS
from entitynet.client.state import PATH_W, RECENT

W = PATH_W  # the widest path a row holds in arrays

# why a fix went to the scalar path: codes 1.. of the vectorised fix's tests (in their order), then of `_refresh`'s
# eligibility (`fast` false), then a fix the arrays never look at (not finite, or not after the last fix), then
# fixes of a step with fewer rows than the fleet core's `min_rows` (the arrays' fixed cost is not worth it)
SCALAR_WHY = ("no_segments", "near_area", "near_switch", "near_best_on", "near_reacquire",
              "near_consistency", "reacquire", "reach_jump", "filter",
              "reversal", "unplaced", "area", "unpublished", "baseline_model", "path_or_ring_wide", "other_net",
              "bad_fix", "not_vectorised", "few_rows")
WHY = {w: k + 1 for k, w in enumerate(SCALAR_WHY)}


# ---- the vectorised fix --------------------------------------------------------------------------------
def fast_fixes(core, sl: np.ndarray, x: np.ndarray, y: np.ndarray, t: float, r: float,
               vel: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """`Player.feed` at `t` for slots `sl` where the fix ends in the usual update (fleet.py's docstring):
    `vel` (or None): per row (vx, vy, variance, 1 where the fix has a Doppler velocity, else 0) as `velocity`
    makes it, folded in after the path's upkeep as `NetworkTracker.fuse_velocity` does (`fuse_rows`).
    commits those rows and returns per row 0 (done here) or the `SCALAR_WHY` code (1..) of the first test
    that leaves it to the scalar path, and per row done here the publish `decide` asks for: 0 none, else
    j with `fleet.PUBLISH_WHY[abs(j) - 1]` (j < 0: a reposition), or 10 + j for a stop unless the ghost halts
    there by itself (`_halts_here`, asked per entity after the commit; then j as before)."""
    geo = core.geo
    pn, pe, pd, pc = core.pn[sl], core.pe[sl], core.pd[sl], core.pc[sl]
    rows = np.arange(len(sl))
    ks, kv, ka, kt = core.ks[sl], core.kv[sl], core.ka[sl], core.kt[sl]
    iv, iv_n, gap_lim, reach, interval = interval_rows(
        core.iv[sl], core.iv_n[sl], t - core.last_t[sl], core.max_gap[sl], core.lost_after[sl], core.reacq[sl],
        core.vmax[sl], GAP_INTERVALS, MIN_INTERVALS)
    dt = np.where(t > kt, t - kt, 0.0)
    s_pred = ks + kv * dt + 0.5 * ka * dt * dt
    k = (pc <= s_pred[:, None]).sum(axis=1) - 1
    k = np.where(k < 0, 0, np.where(k >= pn, pn - 1, k))
    e = pe[rows, k]
    ok = geo.nseg[e] > 0
    why = np.where(ok, 0, WHY["no_segments"])

    def fail(cond: np.ndarray, reason: str) -> None:  # rows still ok that fail `cond` leave for `reason`
        why[ok & ~cond] = WHY[reason]
    off = px = py = dist = np.zeros(len(sl))
    if ok.any():
        off, px, py, dist = (np.zeros(len(sl)) for _ in range(4))
        w = np.flatnonzero(ok)
        off[w], px[w], py[w], dist[w] = geo.project(x[w], y[w], e[w])
    elen = geo.edge_len[e]
    swm, reacq = core.swm[sl], core.reacq[sl]
    written_out = (dist <= swm) & (off > 0.0) & (off < elen) & geo.inner[e]  # `track`'s test for `_track_on`
    gen = ok & ~written_out  # the neighbourhood search (`Placer.near`)
    fail(~gen, "near_area")  # (rows of the near search: their reason is set below)
    ok &= written_out
    fail(dist <= reacq, "reacquire")
    ok &= dist <= reacq
    # `_s_of`'s first case: the edge does not recur within three edges either side (else `_s_of` in full)
    j = k[:, None] + np.arange(-3, 4)[None, :]
    inside = (j >= 0) & (j < pn[:, None])
    same = (pe[rows[:, None], np.clip(j, 0, W - 1)] == e[:, None]) & inside
    s_meas = pc[rows, k] + np.where(pd[rows, k] > 0, off, elen - off)
    again = np.flatnonzero(ok & (same.sum(axis=1) != 1))
    if len(again):
        s_meas[again] = s_of_rows(pe[again], pd[again], pc[again], pn[again], geo.edge_len, e[again],
                                  off[again], s_pred[again], k[again])
    pend_e, pend_n = np.full(len(sl), -1, dtype=np.int64), np.zeros(len(sl), dtype=np.int64)
    retried = np.zeros(len(sl), dtype=bool)
    if gen.any():
        g = np.flatnonzero(gen)
        gwhy, ge_, goff, gpx, gpy, gd, gs, pend_e[g], pend_n[g], retried[g] = near_fixes(
            core, sl[g], x[g], y[g], s_pred[g], pe[g], pd[g], pc[g], pn[g], k[g], r, WHY)
        ok[g] = gwhy == 0
        why[g] = gwhy
        e, off, px, py, dist, s_meas = e.copy(), off.copy(), px.copy(), py.copy(), dist.copy(), s_meas.copy()
        e[g], off[g], px[g], py[g], dist[g], s_meas[g] = ge_, goff, gpx, gpy, gd, gs
    fail(~(np.abs(s_meas - s_pred) > reach), "reach_jump")
    ok &= ~(np.abs(s_meas - s_pred) > reach)
    near_rows = gen
    dist_ema = 0.7 * core.dist_ema[sl] + 0.3 * dist
    kup = kt < t
    *new, sden = kf_update(s_meas, t, r, ks, kv, ka, core.p00[sl], core.p01[sl], core.p02[sl], core.p11[sl],
                    core.p12[sl], core.p22[sl], kt, core.kq[sl], core.kacc[sl])
    ns, nv, na, n00, n01, n02, n11, n12, n22 = new
    fail(kup & (sden > 0.0) & np.isfinite(ns), "filter")
    ok &= kup & (sden > 0.0) & np.isfinite(ns)
    vpeak_set = (nv > core.vpeak[sl]) | (t - core.vpeak_t[sl] > 120.0)
    has_route = core.has_route[sl]
    backwards = (nv < -core.v_start[sl]) & (nv + np.sqrt(np.maximum(n11, 0.0)) < 0.0)
    rev = np.where(has_route | ~backwards, 0, core.rev[sl] + 1)
    fail(rev < 3, "reversal")
    ok &= rev < 3
    # the recent fixes: path coordinates (tracker) and projected points (rules)
    rs = np.concatenate([core.rs[sl][:, 1:], s_meas[:, None]], axis=1)
    # `_maintain_path`: the edges behind the body and margin are trimmed here (`Path.trimmed`, `kf.shift`,
    # `recent_s` shifted: the same subtractions); a path to extend ahead is extended below, row by row
    keep = ns - core.behind[sl]
    trim = (pn + 1 > 2) & (keep > pc[:, 1])
    if trim.any():  # (the trimmed rows only: shifting every row's 49 columns costs more than the rest)
        tr = np.flatnonzero(trim)
        kk = (pc[tr] <= keep[tr, None]).sum(axis=1) - 1
        kk = np.where(kk < 0, 0, np.where(kk >= pn[tr], pn[tr] - 1, kk))
        c0 = pc[tr, kk]
        real = (kk > 0) & (c0 > 0.0)  # (`trimmed` gives shift 0.0 otherwise: nothing changes)
        trim[tr] = real
        tr, kk, c0 = tr[real], kk[real], c0[real]
        jj = np.minimum(np.arange(W)[None, :] + kk[:, None], W - 1)
        jc = np.arange(W + 1)[None, :] + kk[:, None]
        ns, rs = ns.copy(), rs.copy()  # (pe, pd, pc, pn are this call's own: `core.pe[sl]` copies the rows)
        pe[tr], pd[tr] = pe[tr[:, None], jj], pd[tr[:, None], jj]
        pc[tr] = np.where(jc <= pn[tr, None], pc[tr[:, None], np.minimum(jc, W)] - c0[:, None], np.inf)
        pn[tr] = pn[tr] - kk
        ns[tr] = ns[tr] - c0
        rs[tr] = rs[tr] - c0[:, None]
    vpos = np.where(nv > 0.0, nv, 0.0)
    last = pe[rows, pn - 1], pd[rows, pn - 1]
    need = ns + core.la[sl] + core.mg[sl] + 80.0 + 15.0 * vpos
    extend = (pc[rows, pn] < need) & (pn < W) & ~((last[0] == core.dead_e[sl]) & (last[1] == core.dead_d[sl]))
    dead = np.zeros(len(sl), dtype=bool)
    ext = np.flatnonzero(extend & ok)
    if len(ext):  # `_maintain_path`'s extension ahead, row by row (rows that stay in arrays otherwise)
        dead[ext] = extend_rows(core.players, core.net, sl, ext, need, pe, pd, pc, pn)
        trim[ext] = True  # (the path changed: committed like a trimmed one)
        core.counters["vector_extends"] += len(ext)
    else:
        ok &= ~extend
    nv_track = nv  # (`track` sets the peak speed before the velocity is folded in)
    if vel is not None and vel[:, 3].any():
        new = list(fuse_rows(geo, vel, rs[:, -1], pe, pd, pc, pn, has_route, core.kacc[sl], ns, *new[1:]))
        ns, nv = new[0], new[1]
    rx = np.concatenate([core.rx[sl][:, 1:], px[:, None]], axis=1)
    ry = np.concatenate([core.ry[sl][:, 1:], py[:, None]], axis=1)
    rr_n = np.minimum(core.rr_n[sl] + 1, RECENT)
    # `UpdateRules.decide` against the ghost
    gs, gv, _beyond = ghost_s_speed(np.full(len(sl), t), core.g_t0[sl], core.g_s0[sl], core.g_v[sl],
                                    core.g_a[sl], core.g_vmax[sl], core.g_tb[sl], core.g_sb[sl], core.g_vb[sl],
                                    core.g_b[sl], core.g_stop[sl])
    gv = np.where(_beyond, 0.0, gv)
    gn = core.gn[sl]
    gc = core.gc[sl]
    glen = gc[rows, gn]
    gx, gy = geo.path_xy(np.where(glen < gs, glen, gs), core.ge[sl], core.gd[sl], gc, gn)
    v_stop = core.v_stop[sl]
    thr = core.thr[sl]
    stop = (gv > v_stop) & (nv < v_stop)
    standing = gv <= v_stop
    moved = np.zeros(len(sl), dtype=bool)
    for m_n, limit in ((5, thr), (2, 1.6 * thr)):
        m = np.minimum(rr_n, m_n)
        mx = np.zeros(len(sl))
        my = np.zeros(len(sl))
        for c in range(RECENT - m_n, RECENT):
            use = c >= RECENT - m
            mx = np.where(use, mx + rx[:, c], mx)
            my = np.where(use, my + ry[:, c], my)
        moved |= hypot_py(mx / m - gx, my / m - gy) > limit
    ex, ey = geo.path_xy(ns, pe, pd, pc, pn)
    drift = hypot_py(gx - ex, gy - ey)
    over = np.where(drift > thr, core.over[sl] + 1, 0)
    drifted = (over >= core.confirm[sl]) | (drift > 1.5 * thr)
    pub_t = core.pub_t[sl]
    due = (t >= pub_t + core.validity[sl]) | (t - pub_t >= core.heartbeat[sl])
    expiry = t >= pub_t + core.validity[sl]
    due = expiry | (t - pub_t >= core.heartbeat[sl])
    # `decide`'s reason where it publishes: standing and moved: start, else drift (a reposition where the
    # filter stands too); moving and drifted: drift; else expiry or heartbeat where due; else none (0)
    pub = np.where(expiry, 3, np.where(due, 4, 0))
    pub = np.where(~standing & drifted, 2, pub)
    nv_start = nv > core.v_start[sl]
    pub = np.where(standing & moved, np.where(nv_start, 1, np.where(nv <= v_stop, -2, 2)), pub)
    pub = np.where(stop, 10 + pub, pub)  # "stop" unless `_halts_here` (per entity, after the commit): pub
    # commit the rows that stay in arrays
    core.counters["vector_near"] += int((ok & near_rows).sum())
    core.counters["vector_best_on"] += int((ok & retried).sum())
    core.counters["vector_hysteresis"] += int((ok & (pend_e != -1)).sum())  # (an area not entered yet too)
    if vel is not None:
        core.counters["vector_velocity"] += int((ok & (vel[:, 3] > 0.0)).sum())
    w = np.flatnonzero(ok)
    c = sl[w]
    core.last_t[c] = t
    core.iv[c], core.iv_n[c], core.gap_lim[c], core.reach[c] = iv[w], iv_n[w], gap_lim[w], reach[w]
    core.interval[c] = interval[w]
    core.mx[c], core.my[c] = x[w], y[w]
    # what `feed` and the usual `track` reset: no fix gap, on the network; the hysteresis candidate (near)
    core.off_since[c], core.halted[c], core.pend_e[c], core.pend_n[c] = math.nan, 0, pend_e[w], pend_n[w]
    core.lf_kind[c] = 1
    core.lf_e[c], core.lf_off[c], core.lf_x[c], core.lf_y[c], core.lf_d[c] = e[w], off[w], px[w], py[w], dist[w]
    core.dist_ema[c] = dist_ema[w]
    for f, v in zip(("ks", "kv", "ka", "p00", "p01", "p02", "p11", "p12", "p22"), [ns, *new[1:]], strict=True):
        getattr(core, f)[c] = v[w]
    dw = w[dead[w]]
    if len(dw):  # nothing follows the path's last edge: `dead_end`, not asked again
        core.dead_e[sl[dw]], core.dead_d[sl[dw]] = pe[dw, pn[dw] - 1], pd[dw, pn[dw] - 1]
    tw = w[trim[w]]
    if len(tw):
        core.counters["vector_trims"] += len(tw)
        ct = sl[tw]
        core.pe[ct], core.pd[ct], core.pc[ct], core.pn[ct] = pe[tw], pd[tw], pc[tw], pn[tw]
        paths = core.rec.paths
        for slot in ct.tolist():
            paths[slot] = None  # the row's path changed: its `Path` is built again when asked
    core.kt[c] = t
    vs = w[vpeak_set[w]]
    core.vpeak[sl[vs]] = nv_track[vs]
    core.vpeak_t[sl[vs]] = t
    core.rev[c] = rev[w]
    core.rs[c] = rs[w]
    core.rs_n[c] = np.minimum(core.rs_n[c] + 1, RECENT)
    core.rx[c], core.ry[c], core.rr_n[c] = rx[w], ry[w], rr_n[w]
    core.over[c] = np.where(standing[w], core.over[c], over[w])
    d = np.minimum(np.minimum(pub_t[w] + core.validity[c], pub_t[w] + core.heartbeat[c]),
                   np.minimum(t + core.lost_after[c], t + gap_lim[w]))
    core.deadline[c] = d - (1e-6 + np.abs(d) * 1e-12)
    return np.where(ok, 0, why), np.where(ok, pub, 0)

