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
   extended (`extend_rows`), and `UpdateRules.decide` (fleet_kernels.py; the fix itself: fleet_fix.py).
   Where `decide` publishes, the row is committed and the Player builds the publish (`_publish`; a stop asks
   `_halts_here` first). Every other fix (first placement, an area, a switch to another way, a reversal,
   re-acquisition) goes to the Player (`feed` then `tick`, as `sims.engine.clients.Fleet` calls them).

One home: the entities' state is the fleet's client-state `Record` (entitynet/client/state.py). `add` moves a
Player's row there (`Player.move_to`); the vectorised fix reads and writes the record's columns through numpy
views, the Player's parts read and write the same row through their properties, so nothing is copied back and
forth. What the fleet core keeps besides is derived from the row (after a scalar call, and for the deadline
also at the vectorised fix's commit), never state: per slot the earliest time a tick can speak (`deadline`),
whether the next fix may take the arrays (`fast`, or `slow`: why not), and the columns of the published ghost
and of the entity's options (immutable values, read again when the ghost or the Player changes: `_refresh`).
`player(slot)` hands the Player out. A fix may come with the receiver's Doppler velocity (`speed`, `heading`:
a proxy's vehicles report one); the arrays fold it in as `NetworkTracker.fuse_velocity` does (fleet_fix.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from entitynet.client.fixes import FixRejected, velocity
from entitynet.client.fleet_fix import SCALAR_WHY, WHY, fast_fixes
from entitynet.client.fleet_kernels import Geometry, compiled
from entitynet.client.fleet_near import NearTables, by_placement_index
from entitynet.client.modes import EDGE
from entitynet.client.motion import NetworkModel
from entitynet.client.player import Player
from entitynet.client.rules import FIX_INTERVALS_KEPT, OWN_ESTIMATE
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
# the scalar fixes whose tracker asks the placement index (`Placer.first`): primed in one batch per step
PRIMED_WHY = ("unplaced", "near_consistency", "near_reacquire", "reacquire", "area")
_PRIMED_CODES = np.array([WHY[w] for w in PRIMED_WHY], dtype=np.int64)
_AREA_CODE = WHY["area"]
PRIME_MIN = 8  # fewer in a batch cost more than the single calls (measured: 22 us a point at 8, 100 at 1)
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


def ghost_row_py(gm, ge, gd, gc, gn, s: int, nums: tuple, path) -> None:
    """A new ghost read into slot s's derived columns: its numbers (the `_GHOST` columns) into gm, its path's
    edges, directions and cumulative lengths (+inf past them) into ge, gd, gc and their count into gn. The
    reference that `_fleet.GhostCols.write` is tested against."""
    gm[s] = nums
    n = gn[s] = len(path.edges)
    ge[s, :n] = [de[0] for de in path.edges]
    gd[s, :n] = [de[1] for de in path.edges]
    gc[s, : n + 1] = path.cum
    gc[s, n + 1:] = math.inf


class FleetCore:
    """Players in slots (a removed player's slot goes to a later add; `order` keeps the order of the adds),
    stepped together."""

    def __init__(self, capacity: int = 64, *, vectorised: bool = True, min_rows: int = 0,
                 prime_min: int = PRIME_MIN) -> None:
        """`vectorised=False`: every fix and every tick through the entity's `Player`, one by one (the
        per-entity baseline `bench sim` measures the arrays against, and what a fleet of one does).
        `min_rows`: a step with fewer fixes the arrays could take gives them to the Players (`few_rows`: the
        vectorised fix has a fixed cost of a few hundred numpy calls; a small fleet's caller sets it); the
        timers stay in arrays. `prime_min`: the fewest fixes of one map and network mask whose placements are
        computed in one batch (`_prime_places`)."""
        if prime_min < 1:
            raise ValueError(f"prime_min must be at least 1, got {prime_min}")
        self.vectorised = vectorised
        self.min_rows = int(min_rows)
        self.prime_min = int(prime_min)
        self.players: list[Player | None] = []
        self.geo: Geometry | None = None
        self._near = NearTables()
        self.net = None
        self.last_now = -math.inf
        self.counters = {"vector_fixes": 0, "vector_near": 0, "vector_best_on": 0, "vector_hysteresis": 0,
                         "vector_trims": 0, "vector_extends": 0, "vector_publishes": 0, "vector_velocity": 0,
                         "scalar_fixes": 0, "scalar_ticks": 0, "primed_places": 0}
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
        self._ghost_cols = None  # `_fleet.GhostCols` over the ghost columns, taken again after they grew
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
             idle: Sequence[int] = (), *, speed: np.ndarray | None = None, heading: np.ndarray | None = None,
             speed_accuracy: float = 0.5) -> tuple[list[tuple[int, list[Publish | Unpublish]]], int]:
        """Time `now` for every live slot: the slots in `due` take the fix (x[i], y[i]) (`feed` then `tick`),
        the others `tick` (except those in `idle`). `speed[i]`, `heading[i]`: the fix's Doppler velocity as
        `Player.feed` takes it (NaN: not reported, `feed`'s None). Returns ([(slot, messages)] in the order the
        slots' players were added, `order`), rejected fixes)."""
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
        why = np.full(len(due), WHY["not_vectorised"], dtype=np.int64)
        spd = hdg = None
        if speed is not None:
            spd = [None if v != v else v for v in np.asarray(speed, dtype=float).tolist()]
            hdg = [None if v != v else v for v in np.asarray(heading, dtype=float).tolist()] if heading is not None \
                else [None] * len(spd)
        if len(due) and math.isfinite(acc) and acc > 0.0 and self.vectorised:
            fast = self.fast[due] & self.alive[due]
            good = np.isfinite(x) & np.isfinite(y) & (now > self.last_t[due])
            vel = None
            if spd is not None:  # (the velocity as `feed` makes it, per fix: one `velocity` call each)
                vel = np.zeros((len(due), 4))
                for k, v in enumerate(spd):
                    if v is not None:
                        try:
                            vel[k, :3] = velocity(v, hdg[k], speed_accuracy)
                            vel[k, 3] = 1.0
                        except FixRejected:
                            good[k] = False  # (the scalar `feed` rejects it)
            why = np.where(fast, WHY["bad_fix"], self.slow[due])
            rows = np.flatnonzero(fast & good)
            if len(rows) < self.min_rows:
                why[rows] = WHY["few_rows"]
                rows = rows[:0]
            if len(rows):
                why[rows], pub[rows] = fast_fixes(self, due[rows], x[rows], y[rows], now, acc * acc,
                                                  None if vel is None else vel[rows])
                done[rows] = why[rows] == 0
        self.counters["vector_fixes"] += int(done.sum())
        if self.vectorised and len(due):
            self._prime_places(due, x, y, why, done)
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
            fresh = False  # (`_then_tick` derived the slot's columns after its last call)
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
                    msgs, fresh = self._then_tick(s, p, [p._publish(now, why_pub)], now), self.vectorised
            elif k < 0:
                self.counters["scalar_ticks"] += 1
                msgs = p.tick(now)
                if not msgs:
                    continue  # nothing changed: the deadline stays (it fires again until the exact test does)
            else:
                self.counters["scalar_fixes"] += 1
                try:
                    if spd is None:
                        msgs = p.feed(float(x[k]), float(y[k]), now, acc)
                    else:
                        msgs = p.feed(float(x[k]), float(y[k]), now, acc, speed=spd[k], heading=hdg[k],
                                      speed_accuracy=speed_accuracy)
                    msgs, fresh = self._then_tick(s, p, msgs, now), self.vectorised
                except FixRejected:
                    rejected += 1
                    msgs = []
            if self.vectorised and not fresh:  # (one by one, every live slot ticks: nothing is derived)
                self._refresh(s)
            if msgs:
                out.append((s, msgs))
        return out, rejected

    def _prime_places(self, due: np.ndarray, x: np.ndarray, y: np.ndarray, why: np.ndarray,
                      done: np.ndarray) -> None:
        """Prime the placement index (`PlacementIndex.prime`) with the fixes of this step that go to the Players
        for a reason that asks it (`PRIMED_WHY`: a first fix, a re-placement, a fix leaving its area), one batch per
        map and network mask of at least `prime_min` fixes: their `place` calls are then lookups of answers computed
        in one vectorised pass, the same answers (issue 23: the first fixes of a large run's start were a
        third of its first two ticks)."""
        ask = np.flatnonzero(~done & np.isin(why, _PRIMED_CODES))
        if len(ask) < self.prime_min:
            return
        asking = []
        players = self.players
        for k in ask.tolist():
            p = players[int(due[k])]
            trk = None if p is None else p.tracker
            if trk is not None:
                if why[k] == _AREA_CODE and trk.area >= 0 and trk.placer.inside_area(trk.area, float(x[k]),
                                                                                            float(y[k])):
                    continue  # (a fix inside its area: `track` asks no placement)
                asking.append((k, trk))
        primed: set[int] = set()  # (the indexes primed this step: each keeps its step's batches together)
        for placer, rows in by_placement_index(asking):
            if len(rows) >= self.prime_min:
                w = np.array(rows, dtype=np.int64)
                index = placer.topo.placement_index()
                self.counters["primed_places"] += index.prime(np.column_stack([x[w], y[w]]), placer.networks,
                                                              keep=id(index) in primed)
                primed.add(id(index))

    def _then_tick(self, s: int, p: Player, msgs: list[Publish | Unpublish], now: float) -> list[Publish | Unpublish]:
        """`msgs + p.tick(now)` after a fix or a publish of slot `s`: the tick is asked only where the slot's
        deadline, derived again first (`_refresh`), has come; before it `tick` provably returns nothing and
        changes nothing (the timers' rule, the module docstring), and a tick right after a publish seldom has
        anything to say (issue 22: a few microseconds a publish)."""
        if not self.vectorised:
            return msgs + p.tick(now)
        self._refresh(s)
        if self.deadline[s] <= now:
            msgs = msgs + p.tick(now)
            self._refresh(s)
        return msgs

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
        self.slow[s] = 0 if ok else WHY[slow]
        self.fast[s] = ok
        if not ok:
            return
        if self._ghosts[s] is not ghost:  # a new ghost comes only with a publish (and with it its validity)
            self._ghosts[s] = ghost
            tb, sb, vb, b = ghost.plan
            nums = (p.rules.validity(p.occupation), ghost.t0, ghost.s0, ghost.v, ghost.a, ghost.vmax, tb, sb, vb, b,
                    ghost.stop_s)
            path = ghost.path
            k = compiled()
            if k is not None:  # (the same values, written in one call through the columns taken once)
                cols = self._ghost_cols
                if cols is None:
                    cols = self._ghost_cols = k.GhostCols(self.gm, self.ge, self.gd, self.gc, self.gn)
                cols.write(s, nums, path)
            else:
                ghost_row_py(self.gm, self.ge, self.gd, self.gc, self.gn, s, nums, path)
        if not self.consts[s]:
            rules, placer, et = p.rules, trk.placer, trk.etype
            self.cm[s] = [placer.switch_margin if trk.switch_margin is None else trk.switch_margin,
                          placer.reacquire, et.v_start, et.v_stop, trk.body + trk.margin + 50.0, trk.lookahead,
                          trk.margin, rules.threshold, rules.heartbeat, rules.max_gap, rules.lost_after, trk.body,
                          et.vmax, placer.switch_count if trk.switch_count is None else trk.switch_count]
            self.has_route[s], self.confirm[s] = trk.has_route, rules.confirm
            self.ncls[s] = self._near.class_of(placer.networks, len(self.geo.edge_len))
            self.consts[s] = True
