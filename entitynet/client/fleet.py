"""The fleet core: many entities' client cores stepped together, the usual fix and the timers over arrays.

Why: a simulation or a proxy runs thousands of honest clients, and per entity and tick a `Player` costs tens of
microseconds of Python even when it decides nothing. The fleet core runs the same decisions for all of them at
once and calls an entity's own `Player` only where something happens:

1. **Timers.** Per entity the earliest time at which `Player.tick` could return anything (the publish's
   validity or heartbeat running out, `max_gap` and `lost_after` after the last fix) is kept in `deadline`,
   made earlier by 1e-6 s plus 1e-12 of its size, more than the rounding of the scalar tests (`now - last_t >=
   lost_after` and the like are a subtraction and a compare: one rounding). Before its deadline an entity's
   `tick` provably returns nothing and changes nothing, so only entities whose deadline has come call it.
2. **The steady-state fix.** An entity placed on an edge, with a network ghost, whose fix ends in `track`'s
   usual update is decided in arrays: `NetworkTracker._track_on` (within the switch margin of the current edge,
   away from its ends, no area at either end) or, beyond it, `track`'s general branch (fleet_near.py:
   `Placer.near`, an area of the neighbourhood not entered yet, `_best_on`, the hysteresis, `_s_of`, the
   consistency query asked per fix); then the along-path filter, the recent fixes, the path trimmed and
   extended (`extend_rows`), and `UpdateRules.decide` (fleet_kernels.py). Where `decide` publishes, the row is
   committed and the Player builds the publish (`_publish`; a stop asks `_halts_here` first). Every other fix
   (first placement, an area, a switch to another way, a reversal, re-acquisition) goes to the Player (`feed`
   then `tick`, as `sims.engine.clients.Fleet` calls them).

One home: the entities' state is the fleet's client-state `Record` (entitynet/client/state.py). `add` moves a
Player's row there (`Player.move_to`); the vectorised fix reads and writes the record's columns through numpy
views, the Player's parts read and write the same row through their properties, so nothing is copied back and
forth. What the fleet core keeps besides is derived, never written by a fix: per slot the earliest time a tick
can speak (`deadline`), whether the next fix may take the arrays (`fast`, or `slow`: why not), and the columns of
the published ghost and of the entity's options (immutable values, read again when the ghost or the Player
changes: `_refresh`). `player(slot)` hands the Player out. Doppler velocities are not taken (the fleet feeds
positions).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from entitynet.client.fixes import FixRejected
from entitynet.client.fleet_kernels import Geometry, extend_rows, ghost_s_speed, hypot_py, interval_rows, kf_update
from entitynet.client.fleet_near import NearTables, near_fixes, s_of_rows
from entitynet.client.modes import EDGE
from entitynet.client.motion import NetworkModel
from entitynet.client.player import Player
from entitynet.client.rules import FIX_INTERVALS_KEPT, GAP_INTERVALS, MIN_INTERVALS, OWN_ESTIMATE
from entitynet.client.state import PATH_W, RECENT, Record
from entitynet.client.tracker import MAX_PATH_EDGES
from entitynet.protocol import Publish, Unpublish

W = PATH_W  # the widest path a row holds in arrays
assert MAX_PATH_EDGES == W and FIX_INTERVALS_KEPT == RECENT
# derived columns of the fleet (not state): the published ghost's numbers (a new ghost comes only with a
# publish) and the entity's options, read by `_refresh`
_GHOST = ("validity", "g_t0", "g_s0", "g_v", "g_a", "g_vmax", "g_tb", "g_sb", "g_vb", "g_b", "g_stop")
_CONST = ("swm", "reacq", "v_start", "v_stop", "behind", "la", "mg", "thr", "heartbeat", "max_gap", "lost_after",
          "body", "vmax", "swc")
# the derived columns' blocks: (name, initial value, dtype, shape of a row)
_DERIVED = (("deadline", math.inf, float, ()), ("alive", False, bool, ()), ("fast", False, bool, ()),
            ("consts", False, bool, ()), ("has_route", False, bool, ()), ("slow", 0, np.int64, ()),
            ("order", 0, np.int64, ()), ("confirm", 1, np.int64, ()), ("gm", 0.0, float, (len(_GHOST),)),
            ("cm", 0.0, float, (len(_CONST),)), ("ge", 0, np.int64, (W,)), ("gd", 1, np.int64, (W,)),
            ("gc", math.inf, float, (W + 1,)), ("gn", 0, np.int64, ()), ("ncls", 0, np.int64, ()))
# why a fix went to the scalar path: codes 1.. of the vectorised fix's tests (in their order), then of `_load`'s
# eligibility (`fast` false), then a fix the arrays never look at (not finite, or not after the last fix)
SCALAR_WHY = ("no_segments", "near_area", "near_switch", "near_best_on", "near_reacquire",
              "near_consistency", "reacquire", "reach_jump", "filter",
              "reversal", "unplaced", "area", "unpublished", "baseline_model", "path_or_ring_wide", "other_net",
              "bad_fix", "not_vectorised")
_WHY = {w: k + 1 for k, w in enumerate(SCALAR_WHY)}
# the reasons of a publish the arrays decide (`UpdateRules.decide`'s; a "stop" asks `_halts_here` per entity)
PUBLISH_WHY = ("start", "drift", "expiry", "heartbeat")


def _deadline(p: Player) -> float:
    """The time before which `p.tick` returns nothing (see the module docstring), or inf."""
    if not p.published or p.ghost is None:
        return math.inf
    r = p.rules
    d = min(p.pub_t + r.validity(p.occupation), p.pub_t + r.heartbeat)
    if p.last_t is not None:
        d = min(d, p.last_t + r.lost_after)
        if not r.halted:
            d = min(d, p.last_t + r.gap_limit)
    return d - (1e-6 + abs(d) * 1e-12)


class FleetCore:
    """Players in slots (a removed player's slot goes to a later add; `order` keeps the order of the adds),
    stepped together."""

    def __init__(self, capacity: int = 64, *, vectorised: bool = True) -> None:
        """`vectorised=False`: every fix and every tick through the entity's `Player`, one by one (the
        per-entity baseline `bench sim` measures the arrays against, and what a fleet of one does)."""
        self.vectorised = vectorised
        self.players: list[Player | None] = []
        self.geo: Geometry | None = None
        self._near = NearTables()
        self.net = None
        self.last_now = -math.inf
        self.counters = {"vector_fixes": 0, "vector_near": 0, "vector_best_on": 0, "vector_hysteresis": 0,
                         "vector_trims": 0, "vector_extends": 0, "vector_publishes": 0, "scalar_fixes": 0,
                         "scalar_ticks": 0}
        # why each scalar fix was scalar (the first reason that held, in `SCALAR_WHY`'s order of tests)
        self.scalar_why: dict[str, int] = dict.fromkeys(SCALAR_WHY, 0)
        self.rec = Record(max(int(capacity), 1), fleet=True)
        self._free: list[int] = []  # slots of removed players, for the next adds
        self._handed: set[int] = set()  # slots whose Player was handed out: `_refresh` before the next step
        self._added = 0
        self._cap = 0
        self._grow()

    def _grow(self) -> None:
        """Views of the record's columns (again after it grew) and the derived columns, as wide."""
        cap, old = self.rec.cap, self._cap
        for name, arr in self.rec.view().items():
            setattr(self, name, arr)
        for name, fill, dtype, shape in _DERIVED:  # (new blocks holding the old rows)
            b = np.full((cap, *shape), fill, dtype=dtype)
            if old:
                b[:old] = getattr(self, name)
            setattr(self, name, b)
        for j, f in enumerate(_GHOST):
            setattr(self, f, self.gm[:, j])
        for j, f in enumerate(_CONST):
            setattr(self, f, self.cm[:, j])
        self._ghosts: list = [None] * cap if old == 0 else self._ghosts + [None] * (cap - old)
        self._cap = cap

    # ---- slots ---------------------------------------------------------------------------------------------
    def add(self, player: Player) -> int:
        """Take a player (its state as it is); returns its slot: a removed one's if any (the rows stay as many
        as the most entities held at once), else a new one. `order[slot]` counts the adds: a tick's messages
        come in that order, whichever slots the entities hold. A Player in a fleet core already is refused."""
        if player._st.fleet:  # (a second slot would step one Player twice, one of them on a row nobody reads)
            raise ValueError(f"player {player.entity} is in a fleet core already: `remove` it there first")
        slot = player.move_to(self.rec, self._free.pop() if self._free else None)
        if self.rec.cap != self._cap:
            self._grow()
        if slot == len(self.players):
            self.players.append(player)
        else:
            self.players[slot] = player
        self.order[slot] = self._added
        self._added += 1
        self.alive[slot] = True
        self.consts[slot] = False
        self._ghosts[slot] = None
        self._refresh(slot)
        return slot

    def remove(self, slot: int) -> list[Unpublish]:
        """Drop a slot's player: `Player.leave()`'s messages. Its row moves out to a record of its own (the
        Player stays whole for whoever holds it); a later `add` may take the slot."""
        p = self.player(slot)
        self.players[slot] = None
        self.alive[slot] = self.fast[slot] = False
        self.deadline[slot] = math.inf
        p.move_to(Record(1))
        self.rec.paths[slot] = None
        self._free.append(slot)
        return p.leave()

    def player(self, slot: int) -> Player:
        """The slot's `Player` (its state is the record's row: nothing to write back). The caller may change
        it (its options, a fix fed directly): the next `step` reads its ghost, options and deadline again first."""
        p = self.players[slot]
        if p is None:
            raise KeyError(f"slot {slot} holds no player")
        self.consts[slot] = False
        self._ghosts[slot] = None
        self._handed.add(slot)
        return p

    # ---- one tick ------------------------------------------------------------------------------------------
    def step(self, now: float, due: Sequence[int] | np.ndarray, x: np.ndarray, y: np.ndarray, accuracy: float,
             idle: Sequence[int] = ()) -> tuple[list[tuple[int, list[Publish | Unpublish]]], int]:
        """Time `now` for every live slot: the slots in `due` take the fix (x[i], y[i]) (`feed` then `tick`),
        the others `tick` (except those in `idle`). Returns ([(slot, messages)] in the order the slots' players
        were added, `order`), rejected fixes)."""
        if not math.isfinite(now):
            raise ValueError(f"now must be finite, got {now!r}")
        if now < self.last_now:
            raise ValueError(f"now {now!r} is before the last step at {self.last_now!r}")
        self.last_now = now
        for s in self._handed:  # (before any decision reads the derived columns)
            if self.players[s] is not None:
                self._refresh(s)
        self._handed.clear()
        n = len(self.players)
        due = np.asarray(due, dtype=np.int64)
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        done = np.zeros(len(due), dtype=bool)
        pub = np.zeros(len(due), dtype=np.int64)
        acc = float(accuracy)
        why = np.full(len(due), _WHY["not_vectorised"], dtype=np.int64)
        if len(due) and math.isfinite(acc) and acc > 0.0 and self.vectorised:
            fast = self.fast[due] & self.alive[due]
            good = np.isfinite(x) & np.isfinite(y) & (now > self.last_t[due])
            why = np.where(fast, _WHY["bad_fix"], self.slow[due])
            rows = np.flatnonzero(fast & good)
            if len(rows):
                why[rows], pub[rows] = self._fast_fixes(due[rows], x[rows], y[rows], now, acc * acc)
                done[rows] = why[rows] == 0
        self.counters["vector_fixes"] += int(done.sum())
        for code, count in enumerate(np.bincount(why[~done], minlength=len(SCALAR_WHY) + 1).tolist()):
            if code and count:
                self.scalar_why[SCALAR_WHY[code - 1]] += count
        # per slot: k >= 0 the scalar fix due[k], -1 a timer's tick, -2 `feed`'s publish after a fix decided and
        # committed in arrays (its reason `pubs[slot]`: j of `pub`)
        work: dict[int, int] = {int(s): k if not done[k] else -2
                                for k, s in enumerate(due.tolist()) if not done[k] or pub[k]}
        pubs = {int(due[k]): int(pub[k]) for k in np.flatnonzero(pub).tolist()}
        timers = self.alive[:n] & (self.deadline[:n] <= now) if self.vectorised else self.alive[:n].copy()
        timers[due[due < n]] = False
        for s in idle:
            timers[s] = False
        for s in np.flatnonzero(timers).tolist():
            work.setdefault(s, -1)
        out: list[tuple[int, list[Publish | Unpublish]]] = []
        rejected = 0
        order = self.order
        for s in sorted(work, key=order.__getitem__):
            k = work[s]
            p = self.players[s]
            if p is None:
                continue
            if k < -1:  # `feed`'s publish, after the fix done in arrays
                j = pubs[s]
                why_pub = PUBLISH_WHY[abs(j) - 1] if 0 < abs(j) < 10 else None
                if j >= 10:  # a stop, unless the ghost halts here by itself (then `decide` goes on: j - 10)
                    halts = p.rules._halts_here(p.ghost, p.estimate, p, now)
                    why_pub = PUBLISH_WHY[j - 11] if halts and j > 10 else None if halts else "stop"
                elif j < 0:
                    p.rules.reposition = True  # (`decide`: still standing, just somewhere else)
                if why_pub is None:
                    msgs = p.tick(now)
                else:
                    self.counters["vector_publishes"] += 1
                    msgs = [p._publish(now, why_pub)] + p.tick(now)
            elif k < 0:
                self.counters["scalar_ticks"] += 1
                msgs = p.tick(now)
                if not msgs:
                    continue  # nothing changed: the deadline stays (it fires again until the exact test does)
            else:
                self.counters["scalar_fixes"] += 1
                try:
                    msgs = p.feed(float(x[k]), float(y[k]), now, acc) + p.tick(now)
                except FixRejected:
                    rejected += 1
                    msgs = []
            if self.vectorised:  # (one by one, every live slot ticks: nothing is derived)
                self._refresh(s)
            if msgs:
                out.append((s, msgs))
        return out, rejected

    # ---- the vectorised fix --------------------------------------------------------------------------------
    def _fast_fixes(self, sl: np.ndarray, x: np.ndarray, y: np.ndarray, t: float,
                    r: float) -> tuple[np.ndarray, np.ndarray]:
        """`Player.feed` at `t` for slots `sl` where the fix ends in the usual update (module docstring):
        commits those rows and returns per row 0 (done here) or the `SCALAR_WHY` code (1..) of the first test
        that leaves it to the scalar path, and per row done here the publish `decide` asks for: 0 none, else
        j with `PUBLISH_WHY[abs(j) - 1]` (j < 0: a reposition), or 10 + j for a stop unless the ghost halts
        there by itself (`_halts_here`, asked per entity after the commit; then j as before)."""
        geo = self.geo
        pn, pe, pd, pc = self.pn[sl], self.pe[sl], self.pd[sl], self.pc[sl]
        rows = np.arange(len(sl))
        ks, kv, ka, kt = self.ks[sl], self.kv[sl], self.ka[sl], self.kt[sl]
        iv, iv_n, gap_lim, reach, interval = interval_rows(
            self.iv[sl], self.iv_n[sl], t - self.last_t[sl], self.max_gap[sl], self.lost_after[sl], self.reacq[sl],
            self.vmax[sl], GAP_INTERVALS, MIN_INTERVALS)
        dt = np.where(t > kt, t - kt, 0.0)
        s_pred = ks + kv * dt + 0.5 * ka * dt * dt
        k = (pc <= s_pred[:, None]).sum(axis=1) - 1
        k = np.where(k < 0, 0, np.where(k >= pn, pn - 1, k))
        e = pe[rows, k]
        ok = geo.nseg[e] > 0
        why = np.where(ok, 0, _WHY["no_segments"])

        def fail(cond: np.ndarray, reason: str) -> None:  # rows still ok that fail `cond` leave for `reason`
            why[ok & ~cond] = _WHY[reason]
        off = px = py = dist = np.zeros(len(sl))
        if ok.any():
            off, px, py, dist = (np.zeros(len(sl)) for _ in range(4))
            w = np.flatnonzero(ok)
            off[w], px[w], py[w], dist[w] = geo.project(x[w], y[w], e[w])
        elen = geo.edge_len[e]
        swm, reacq = self.swm[sl], self.reacq[sl]
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
                self, sl[g], x[g], y[g], s_pred[g], pe[g], pd[g], pc[g], pn[g], k[g], r, _WHY)
            ok[g] = gwhy == 0
            why[g] = gwhy
            e, off, px, py, dist, s_meas = e.copy(), off.copy(), px.copy(), py.copy(), dist.copy(), s_meas.copy()
            e[g], off[g], px[g], py[g], dist[g], s_meas[g] = ge_, goff, gpx, gpy, gd, gs
        fail(~(np.abs(s_meas - s_pred) > reach), "reach_jump")
        ok &= ~(np.abs(s_meas - s_pred) > reach)
        near_rows = gen
        dist_ema = 0.7 * self.dist_ema[sl] + 0.3 * dist
        kup = kt < t
        *new, sden = kf_update(s_meas, t, r, ks, kv, ka, self.p00[sl], self.p01[sl], self.p02[sl], self.p11[sl],
                        self.p12[sl], self.p22[sl], kt, self.kq[sl], self.kacc[sl])
        ns, nv, na, n00, n01, n02, n11, n12, n22 = new
        fail(kup & (sden > 0.0) & np.isfinite(ns), "filter")
        ok &= kup & (sden > 0.0) & np.isfinite(ns)
        vpeak_set = (nv > self.vpeak[sl]) | (t - self.vpeak_t[sl] > 120.0)
        has_route = self.has_route[sl]
        backwards = (nv < -self.v_start[sl]) & (nv + np.sqrt(np.maximum(n11, 0.0)) < 0.0)
        rev = np.where(has_route | ~backwards, 0, self.rev[sl] + 1)
        fail(rev < 3, "reversal")
        ok &= rev < 3
        # the recent fixes: path coordinates (tracker) and projected points (rules)
        rs = np.concatenate([self.rs[sl][:, 1:], s_meas[:, None]], axis=1)
        # `_maintain_path`: the edges behind the body and margin are trimmed here (`Path.trimmed`, `kf.shift`,
        # `recent_s` shifted: the same subtractions); a path to extend ahead is extended below, row by row
        keep = ns - self.behind[sl]
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
            pe, pd, pc, pn, ns, rs = pe.copy(), pd.copy(), pc.copy(), pn.copy(), ns.copy(), rs.copy()
            pe[tr], pd[tr] = pe[tr[:, None], jj], pd[tr[:, None], jj]
            pc[tr] = np.where(jc <= pn[tr, None], pc[tr[:, None], np.minimum(jc, W)] - c0[:, None], np.inf)
            pn[tr] = pn[tr] - kk
            ns[tr] = ns[tr] - c0
            rs[tr] = rs[tr] - c0[:, None]
        vpos = np.where(nv > 0.0, nv, 0.0)
        last = pe[rows, pn - 1], pd[rows, pn - 1]
        need = ns + self.la[sl] + self.mg[sl] + 80.0 + 15.0 * vpos
        extend = (pc[rows, pn] < need) & (pn < W) & ~((last[0] == self.dead_e[sl]) & (last[1] == self.dead_d[sl]))
        dead = np.zeros(len(sl), dtype=bool)
        ext = np.flatnonzero(extend & ok)
        if len(ext):  # `_maintain_path`'s extension ahead, row by row (rows that stay in arrays otherwise)
            pe, pd, pc, pn = pe.copy(), pd.copy(), pc.copy(), pn.copy()
            dead[ext] = extend_rows(self.players, self.net, sl, ext, need, pe, pd, pc, pn)
            trim[ext] = True  # (the path changed: committed like a trimmed one)
            self.counters["vector_extends"] += len(ext)
        else:
            ok &= ~extend
        rx = np.concatenate([self.rx[sl][:, 1:], px[:, None]], axis=1)
        ry = np.concatenate([self.ry[sl][:, 1:], py[:, None]], axis=1)
        rr_n = np.minimum(self.rr_n[sl] + 1, RECENT)
        # `UpdateRules.decide` against the ghost
        gs, gv, _beyond = ghost_s_speed(np.full(len(sl), t), self.g_t0[sl], self.g_s0[sl], self.g_v[sl],
                                        self.g_a[sl], self.g_vmax[sl], self.g_tb[sl], self.g_sb[sl], self.g_vb[sl],
                                        self.g_b[sl], self.g_stop[sl])
        gv = np.where(_beyond, 0.0, gv)
        gn = self.gn[sl]
        glen = self.gc[sl][rows, gn]
        gx, gy = geo.path_xy(np.where(glen < gs, glen, gs), self.ge[sl], self.gd[sl], self.gc[sl], gn)
        v_stop = self.v_stop[sl]
        thr = self.thr[sl]
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
        over = np.where(drift > thr, self.over[sl] + 1, 0)
        drifted = (over >= self.confirm[sl]) | (drift > 1.5 * thr)
        pub_t = self.pub_t[sl]
        due = (t >= pub_t + self.validity[sl]) | (t - pub_t >= self.heartbeat[sl])
        expiry = t >= pub_t + self.validity[sl]
        due = expiry | (t - pub_t >= self.heartbeat[sl])
        # `decide`'s reason where it publishes: standing and moved: start, else drift (a reposition where the
        # filter stands too); moving and drifted: drift; else expiry or heartbeat where due; else none (0)
        pub = np.where(expiry, 3, np.where(due, 4, 0))
        pub = np.where(~standing & drifted, 2, pub)
        nv_start = nv > self.v_start[sl]
        pub = np.where(standing & moved, np.where(nv_start, 1, np.where(nv <= v_stop, -2, 2)), pub)
        pub = np.where(stop, 10 + pub, pub)  # "stop" unless `_halts_here` (per entity, after the commit): pub
        # commit the rows that stay in arrays
        self.counters["vector_near"] += int((ok & near_rows).sum())
        self.counters["vector_best_on"] += int((ok & retried).sum())
        self.counters["vector_hysteresis"] += int((ok & (pend_e != -1)).sum())  # (an area not entered yet too)
        w = np.flatnonzero(ok)
        c = sl[w]
        self.last_t[c] = t
        self.iv[c], self.iv_n[c], self.gap_lim[c], self.reach[c] = iv[w], iv_n[w], gap_lim[w], reach[w]
        self.interval[c] = interval[w]
        self.mx[c], self.my[c] = x[w], y[w]
        # what `feed` and the usual `track` reset: no fix gap, on the network; the hysteresis candidate (near)
        self.off_since[c], self.halted[c], self.pend_e[c], self.pend_n[c] = math.nan, 0, pend_e[w], pend_n[w]
        self.lf_kind[c] = 1
        self.lf_e[c], self.lf_off[c], self.lf_x[c], self.lf_y[c], self.lf_d[c] = e[w], off[w], px[w], py[w], dist[w]
        self.dist_ema[c] = dist_ema[w]
        for f, v in zip(("ks", "kv", "ka", "p00", "p01", "p02", "p11", "p12", "p22"), [ns, *new[1:]], strict=True):
            getattr(self, f)[c] = v[w]
        dw = w[dead[w]]
        if len(dw):  # nothing follows the path's last edge: `dead_end`, not asked again
            self.dead_e[sl[dw]], self.dead_d[sl[dw]] = pe[dw, pn[dw] - 1], pd[dw, pn[dw] - 1]
        tw = w[trim[w]]
        if len(tw):
            self.counters["vector_trims"] += len(tw)
            ct = sl[tw]
            self.pe[ct], self.pd[ct], self.pc[ct], self.pn[ct] = pe[tw], pd[tw], pc[tw], pn[tw]
            paths = self.rec.paths
            for slot in ct.tolist():
                paths[slot] = None  # the row's path changed: its `Path` is built again when asked
        self.kt[c] = t
        vs = w[vpeak_set[w]]
        self.vpeak[sl[vs]] = nv[vs]
        self.vpeak_t[sl[vs]] = t
        self.rev[c] = rev[w]
        self.rs[c] = rs[w]
        self.rs_n[c] = np.minimum(self.rs_n[c] + 1, RECENT)
        self.rx[c], self.ry[c], self.rr_n[c] = rx[w], ry[w], rr_n[w]
        self.over[c] = np.where(standing[w], self.over[c], over[w])
        d = np.minimum(np.minimum(pub_t[w] + self.validity[c], pub_t[w] + self.heartbeat[c]),
                       np.minimum(t + self.lost_after[c], t + gap_lim[w]))
        self.deadline[c] = d - (1e-6 + np.abs(d) * 1e-12)
        return np.where(ok, 0, why), np.where(ok, pub, 0)

    # ---- what the arrays derive from a Player -------------------------------------------------------------
    def _refresh(self, s: int) -> None:
        """After a scalar call (or `add`): the slot's deadline, whether its next fix may take the arrays, and
        the derived columns of a new ghost (and of the options, once per hand-out). Its state is not read:
        the row is the state."""
        p = self.players[s]
        self.deadline[s] = _deadline(p)
        trk = p.tracker
        ghost = p.ghost
        if not self.vectorised:
            self.fast[s] = False
            return
        if trk is None or trk.place is None or p.last_t is None:
            slow = "unplaced"
        elif trk.place is not EDGE:
            slow = "area"
        elif not p.published or ghost is None:
            slow = "unpublished"
        elif (p.world is not None or not isinstance(ghost, NetworkModel) or p.estimate is not OWN_ESTIMATE
              or p.rules.periodic or not trk.written_out or trk.kf is None):
            slow = "baseline_model"
        elif not self.rec.path_to_arrays(s) or len(ghost.path.edges) > W or self.rr_n[s] == 0:
            slow = "path_or_ring_wide"
        else:
            if self.net is None:
                self.net, self.geo = p.net, Geometry(p.net)
            slow = None if p.net is self.net and ghost.path.net is self.net else "other_net"
        ok = slow is None
        self.slow[s] = 0 if ok else _WHY[slow]
        self.fast[s] = ok
        if not ok:
            return
        if self._ghosts[s] is not ghost:  # a new ghost comes only with a publish (and with it its validity)
            self._ghosts[s] = ghost
            tb, sb, vb, b = ghost.plan
            self.gm[s] = [p.rules.validity(p.occupation), ghost.t0, ghost.s0, ghost.v, ghost.a, ghost.vmax, tb, sb,
                          vb, b, ghost.stop_s]
            path = ghost.path
            n = self.gn[s] = len(path.edges)
            self.ge[s, :n] = [de[0] for de in path.edges]
            self.gd[s, :n] = [de[1] for de in path.edges]
            self.gc[s, : n + 1] = path.cum
            self.gc[s, n + 1:] = math.inf
        if not self.consts[s]:
            rules, placer, et = p.rules, trk.placer, trk.etype
            self.cm[s] = [placer.switch_margin if trk.switch_margin is None else trk.switch_margin,
                          placer.reacquire, et.v_start, et.v_stop, trk.body + trk.margin + 50.0, trk.lookahead,
                          trk.margin, rules.threshold, rules.heartbeat, rules.max_gap, rules.lost_after, trk.body,
                          et.vmax, placer.switch_count if trk.switch_count is None else trk.switch_count]
            self.has_route[s], self.confirm[s] = trk.has_route, rules.confirm
            self.ncls[s] = self._near.class_of(placer.networks, len(self.geo.edge_len))
            self.consts[s] = True
