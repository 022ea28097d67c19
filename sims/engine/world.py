"""The world: every entity's truth, stepped by an explicit clock (sans-IO: no wall time, no sockets).

`World.step(dt)` advances the clock by `dt` seconds: each entity looks ahead along its route (leaders in its
lane, bus stops, junctions it has not been granted), takes the IDM acceleration of the strongest constraint,
moves, and the deadlock timeouts run: blocked by another entity for `accept_after` seconds, it accepts the
collision for `accept_for` seconds (drives through); blocked for `delete_after` seconds in all, it is deleted.
Everything is counted in `counters` (avoided, accepted, deleted, spawned, arrived). Entities are visited in id
order and all randomness comes from the world's seeded generator, so a seed reproduces a run exactly.
"""

from __future__ import annotations

import random
from collections import Counter
from collections.abc import Iterable

import numpy as np

from entitynet.client import netview
from entitynet.client.network import DirEdge
from sims.engine.agents import Agent, AreaWalk, Stop
from sims.engine.behaviour import Obstacle, accel_for, lanes_overlap, lookahead, timetable_speed
from sims.engine.crossings import Crossings, Movement
from sims.engine.free_flow import FreeFlow
from sims.engine.idm_arrays import moves as idm_moves
from sims.engine.leaders import leaders
from sims.engine.params import TypeParams, params
from sims.engine.route_table import RouteTable
from sims.engine.routes import Route
from topology.raw import TRAM, VEHICLE

#: below this speed (m/s) an entity that wants to move counts as blocked
BLOCKED_V = 0.1
#: the junction zone: a movement is reserved from this many metres before the node to as many after it
JUNCTION_RADIUS = 8.0


class World:
    """The simulation's truth. `add` spawns, `step` moves, `agents` is every live entity by id."""

    def __init__(self, topo, seed: int = 1, *, start: float = 0.0, vectorised: bool = True):
        """`vectorised`: the free walkers (pedestrians without stops) step over arrays (`FreeFlow`), the leaders
        are found and the others' moves computed for all at once (`leaders`, `idm_arrays`), the same truth bit
        for bit; False steps every entity in the scalar loop (the baseline the tests compare with)."""
        self.topo = topo
        self.net = netview(topo)
        self.rng = random.Random(seed)
        self.now = start
        self.agents: dict[int, Agent] = {}
        self.crossings = Crossings()
        self.counters: Counter = Counter()
        self.removed: list[tuple[int, str]] = []  # (id, why) since the last `take_removed`
        self.stop_lateness: list[float] = []  # s after the timetable's arrival, per stop served on a timetable
        self._next_id = 1
        self.free: FreeFlow | None = FreeFlow() if vectorised else None
        self._scalar: set[int] = set()  # the entities the scalar step visits (all, without `free`)
        self.routes = RouteTable(self.net.edge_len)  # every live entity's route as arrays (`positions`)
        self._avoiders: dict[int, Agent] = {}  # the entities with a body length, in id order (the leaders')
        net = self.net
        self._junction = [sum(1 for e in net.node_edges[n] if net.edge_net[e] & (VEHICLE | TRAM)) >= 3
                          for n in range(len(net.node_edges))]

    # ---- spawning ---------------------------------------------------------------------------------------------
    def add(self, kind: str | TypeParams, edges: list[DirEdge], *, s: float = 0.0, v: float | None = None,
            v0: float | None = None, lateral: float | None = None, stops: Iterable[Stop] = (),
            label: str = "", area_walk: float = 0.0, timetable: float | None = None) -> Agent:
        """Spawn an entity on a connected route of directed edges, its front `s` metres along it. With
        `area_walk` > 0 and a route ending at an area node, the entity then walks inside the area for about that
        many seconds (random waypoints) before it leaves the simulation. `timetable`: the service-day time the
        stops' `arrive` count from (a scheduled vehicle drives to reach each stop on time)."""
        p = kind if isinstance(kind, TypeParams) else params(kind)
        route = Route(self.net, edges)
        if not 0.0 <= s <= route.length:
            raise ValueError(f"start {s} m is not on the route (0 to {route.length:.1f} m)")
        rng = self.rng
        if v0 is None:
            v0 = p.vmax * rng.uniform(0.75, 1.0)
        if lateral is None:
            lateral = p.lateral + (rng.uniform(-p.lateral_spread, p.lateral_spread) if p.lateral_spread else 0.0)
        a = Agent(self._next_id, p, route, s, v0 if v is None else v, v0, lateral, self.now,
                  stops=sorted(stops, key=lambda st: st.s), label=label, t0=timetable, v_free=v0)
        while a.next_stop < len(a.stops) and a.stops[a.next_stop].s < s - 1.0:
            a.next_stop += 1
        if p.avoids:
            a.crossings = [(sn, n, k) for sn, n, k in route.nodes() if self._junction[n] and sn > s - a.length]
        end = self.net.end_node(route.edges[-1])
        area = self.net.node_area[end]
        if area_walk > 0.0 and area >= 0:
            from sims.mobility.areas import area_walk as walk

            t, xy = walk(np.asarray(self.topo.area_polygons.exterior(area)), rng, area_walk, speed=a.v0, dt=0.5)
            # from where the route meets the area (its boundary) straight to the walk's first waypoint
            ex, ey = route.xy(route.length)
            steps = max(int(np.hypot(xy[0, 0] - ex, xy[0, 1] - ey) / max(a.v0 * 0.5, 0.1)), 1)
            k = np.arange(steps)[:, None] / steps
            lead = np.array([ex, ey]) + k * (xy[0] - np.array([ex, ey]))
            t = np.concatenate([np.arange(steps) * 0.5, t + steps * 0.5])
            xy = np.concatenate([lead, xy])
            a.area = AreaWalk(t, xy, self.net.area_cell[area])
        a._clock = self.now
        self._next_id += 1
        self.agents[a.id] = a
        self.routes.add(a)
        if p.avoids:
            self._avoiders[a.id] = a
        if self.free is not None and FreeFlow.takes(a):
            self.free.add(a)
        else:
            self._scalar.add(a.id)
        self.counters["spawned"] += 1
        self.counters[f"spawned:{p.name}"] += 1
        return a

    def stall(self, agent: int, seconds: float) -> None:
        """A breakdown: the entity stands still for `seconds` (what it blocks, it blocks)."""
        self.agents[agent].stalled_until = self.now + seconds
        self._to_scalar(agent)

    def _to_scalar(self, agent: int) -> None:
        """An entity that leaves the free walkers' columns (stalled, at its route's end) for the scalar step."""
        if self.free is not None and agent in self.free:
            self.free.drop(agent)
            self._scalar.add(agent)

    def remove(self, agent: int, why: str) -> None:
        """Take an entity out (arrived, deleted), freeing its junction reservations so waiting vehicles are not
        blocked by a ghost holder; counted under `why` and queued for `take_removed`."""
        a = self.agents.pop(agent, None)
        if a is None:
            return
        self._scalar.discard(agent)
        self.routes.forget(a)
        self._avoiders.pop(agent, None)
        if self.free is not None:
            self.free.drop(agent)
        self.crossings.forget(agent, [n for _s, n, _k in a.crossings] + list(a.held))
        self.removed.append((agent, why))
        self.counters[why] += 1

    def take_removed(self) -> list[tuple[int, str]]:
        """The (id, why) removed since the last call, once: the fleet sends their UNPUBLISH from this."""
        out, self.removed = self.removed, []
        return out

    # ---- stepping ---------------------------------------------------------------------------------------------
    def step(self, dt: float) -> None:
        """Advance the truth by `dt` seconds (dt > 0)."""
        if not dt > 0.0:
            raise ValueError(f"a step must move time forward, got dt={dt!r}")
        now = self.now + dt
        moves: list[tuple[Agent, float, float, Obstacle | None]] = []
        if self.free is None:  # the scalar step: the body index, then each entity's decision in id order
            index = self._body_index()
            for aid in sorted(self._scalar):
                a = self.agents[aid]
                moves.append(self._decide(a, index, now, dt))
        else:
            moves = self._decide_all(now, dt)
        ended = self.free.step(dt, now) if self.free is not None else []
        if ended:  # free walkers at their route's end: their `_after_move` in id order among the others'
            for a in ended:
                self._to_scalar(a.id)
            moves.extend((a, a.s, a.v, None) for a in ended)
            moves.sort(key=lambda m: m[0].id)
        for a, new_s, new_v, limit in moves:
            a.distance += max(new_s - a.s, 0.0)  # 0.0 for a free walker (moved already)
            a.s, a.v = new_s, new_v
            a._clock = now
            self._after_move(a, limit, now)
        self.now = now
        self.routes.compact(self.agents.values())

    def _decide_all(self, now: float, dt: float) -> list[tuple[Agent, float, float, Obstacle | None]]:
        """`_decide` for every entity of the scalar step, in id order, with the leaders found for all vehicles
        at once (`leaders`): first each one's state up to its obstacles (`_prepare`: the same for all, none
        reads another's), then the leaders over arrays, then each one's junction request in id order (as
        before: a grant changes the next asker's answer), then every move at once (`idm_arrays.moves`: what
        `_finish` computes) and the stops served, in id order."""
        prepared = []
        movers: list[Agent] = []
        ahead: list[float] = []
        sight: dict[int, float] = {}  # each vehicle's a.s + lookahead(a), computed once for both uses
        for aid in sorted(self._scalar):
            a = self.agents[aid]
            prep = self._prepare(a, now)
            prepared.append((a, prep))
            if prep is not None and a.params.avoids:
                sight[aid] = far = a.s + lookahead(a)
                if a.accept_until <= now:
                    movers.append(a)
                    ahead.append(far)
        bodies = [b for b in self._avoiders.values()]
        found = dict(zip([m.id for m in movers], leaders(self.routes, bodies, movers, ahead), strict=True))
        out: list = []
        going: list[Agent] = []
        their: list[list[Obstacle]] = []
        slots: list[int] = []
        for a, obstacles in prepared:
            if obstacles is None:
                out.append((a, a.s, 0.0, None))
                continue
            if a.params.avoids:
                self._add_crossing(a, obstacles, found.get(a.id), now, sight[a.id])
            slots.append(len(out))
            out.append(None)
            going.append(a)
            their.append(obstacles)
        new_s, new_v, limits = idm_moves(going, their, dt)
        for k, a, si, vi, limit in zip(slots, going, new_s, new_v, limits, strict=True):
            if limit is not None and limit.kind == "stop":
                si, vi = self._serve_stop(a, si, vi, now)
            out[k] = (a, si, vi, limit)
        return out

    def _decide(self, a: Agent, index, now: float, dt: float) -> tuple[Agent, float, float, Obstacle | None]:
        obstacles = self._prepare(a, now)
        if obstacles is None:
            return a, a.s, 0.0, None
        leader = None
        if a.params.avoids and a.accept_until <= now:
            leader = self._leader(a, index, a.s + lookahead(a))
        return self._finish(a, obstacles, leader, now, dt)

    def _prepare(self, a: Agent, now: float) -> list[Obstacle] | None:
        """The entity's state before its obstacles (None: it stands this step: in its area walk, stalled,
        dwelling), its desired speed for now, and the stop ahead as its first obstacle."""
        if a.in_area_since is not None:  # walking inside its area: the walk's samples are the truth
            return None
        if a.stalled_until > now:
            a.cause = "stall"
            return None
        if a.dwell_until is not None:
            if now < a.dwell_until:
                return None
            a.dwell_until = None
            a.next_stop += 1
        obstacles: list[Obstacle] = []
        a.v0 = a.v_free
        if a.next_stop < len(a.stops):
            st = a.stops[a.next_stop]
            if a.t0 is not None and st.arrive is not None:  # reach the stop at the timetable's time
                p = a.params
                a.v0 = timetable_speed(st.s - a.s, a.t0 + st.arrive - self.now, a.v, p.accel, p.decel, p.vmax)
            # a stop is no leader: no time headway to it (with one, vehicles braked early and crept up to it)
            obstacles.append(Obstacle(st.s + 1.0, 0.0, "stop", a.next_stop, s0=1.0, headway=0.0))
        return obstacles

    def _finish(self, a: Agent, obstacles: list[Obstacle], leader: Obstacle | None, now: float,
                dt: float) -> tuple[Agent, float, float, Obstacle | None]:
        """The entity's decision given its leader (None: none, or it accepts collisions now): the crossing
        ahead, the strongest IDM constraint, the move, a stop served."""
        if a.params.avoids:
            self._add_crossing(a, obstacles, leader, now, a.s + lookahead(a))
        acc, limit = accel_for(a, obstacles)
        new_v = max(0.0, a.v + acc * dt)
        if acc < 0 and a.v > 0 and new_v == 0.0:
            ds = a.v * a.v / (-2.0 * acc)
        else:
            ds = 0.5 * (a.v + new_v) * dt
        new_s = a.s + max(ds, 0.0)
        if limit is not None and limit.kind != "stop":  # never into the obstacle
            hard = max(limit.at - 0.3, a.s)
            if new_s > hard:
                new_s, new_v = hard, 0.0
        if limit is not None and limit.kind == "stop":
            new_s, new_v = self._serve_stop(a, new_s, new_v, now)
        return a, new_s, new_v, limit

    def _add_crossing(self, a: Agent, obstacles: list[Obstacle], leader: Obstacle | None, now: float,
                      ahead: float) -> None:
        """Append the leader and the first junction ahead (before `ahead`, the agent's sight) not granted yet
        (asked for now: in id order)."""
        if leader is not None:
            obstacles.append(leader)
        # only the first of a lane asks for a junction: one queued behind a leader would hold it for nothing
        ob = self._crossing(a, ahead if leader is None else min(ahead, leader.at), now)
        if ob is not None:
            obstacles.append(ob)

    def _serve_stop(self, a: Agent, new_s: float, new_v: float, now: float) -> tuple[float, float]:
        """Limited by its stop: close to it and slow, it halts there and dwells (the stop counted served)."""
        st = a.stops[a.next_stop]
        if not (st.s - new_s < 1.5 and new_v < 2.0):
            return new_s, new_v
        a.dwell_until = now + st.dwell
        self.counters["stops_served"] += 1
        if a.t0 is not None and st.arrive is not None:
            self.stop_lateness.append(now - (a.t0 + st.arrive))
        return max(a.s, st.s), 0.0

    def _after_move(self, a: Agent, limit: Obstacle | None, now: float) -> None:
        if a.in_area_since is not None:
            if now - a.in_area_since >= a.area.duration:
                self.remove(a.id, "arrived")
            return
        if a.s >= a.route.length - 1e-6:
            if a.area is not None:
                a.in_area_since = now
                self.counters["area_walks"] += 1
                return
            self.remove(a.id, "arrived")
            return
        for sn, n, _k in list(a.crossings):  # leave junctions the whole body has passed
            if a.s - a.length > sn + JUNCTION_RADIUS:
                self.crossings.release(n, a.id)
                a.held.discard(n)
                a.crossings.remove((sn, n, _k))
            else:
                break
        yielding = limit is not None and limit.kind in ("leader", "crossing")
        episode = (limit.kind, limit.who) if yielding else ("", None)
        if yielding and episode != a._episode:
            self.counters["avoided"] += 1
        a._episode = episode
        a.cause = limit.kind if limit is not None else ""
        a.blocker = limit.who if yielding else None
        if not (yielding and a.v < BLOCKED_V):
            a.blocked_since = None
            return
        if a.blocked_since is None:
            a.blocked_since = now
        waited = now - a.blocked_since
        p = a.params
        if waited >= p.delete_after:
            self.remove(a.id, "deleted")
            return
        if limit.kind == "leader" and waited >= p.accept_after and a.accept_until <= now:
            other = self.agents.get(limit.who) if limit.who is not None else None
            if other is None or other.accept_until <= now:  # one side of a deadlock accepting is enough
                a.accept_until = now + p.accept_for
                self.counters["accepted"] += 1

    # ---- what is ahead ----------------------------------------------------------------------------------------
    def _body_index(self) -> dict[int, list[tuple[float, float, Agent, int]]]:
        """edge -> (lo offset, hi offset, agent, direction) of every body with a length on it."""
        index: dict[int, list[tuple[float, float, Agent, int]]] = {}
        for a in self.agents.values():
            if not a.params.avoids:
                continue
            r = a.route
            back = max(a.s - a.length, 0.0)
            k0, k1 = r.index(back), r.index(a.s)
            for k in range(k0, k1 + 1):
                e, d = r.edges[k]
                lo, hi = max(back - r.cum[k], 0.0), min(a.s - r.cum[k], self.net.edge_len[e])
                if d < 0:
                    lo, hi = self.net.edge_len[e] - hi, self.net.edge_len[e] - lo
                index.setdefault(e, []).append((lo, hi, a, d))
        return index

    def _leader(self, a: Agent, index, ahead: float) -> Obstacle | None:
        """The nearest body ahead of the front in the agent's lane (same way: follow it; oncoming: stop)."""
        r = a.route
        best: Obstacle | None = None
        k = r.index(a.s)
        behind = a.s - 0.01
        while k < len(r.edges) and r.cum[k] < ahead:
            e, d = r.edges[k]
            L = self.net.edge_len[e]
            base = r.cum[k]
            for lo, hi, b, db in index.get(e, ()):
                if b is a:
                    continue
                near = base + (lo if d > 0 else L - hi)
                # behind the front, overlapping it already, beyond sight or no nearer than the best: the cheap
                # tests first, the lanes' sideways overlap only for a candidate (the same leader either way)
                if near < behind or near > ahead or (best is not None and near >= best.at):
                    continue
                if lanes_overlap(a, d, b, db):
                    best = Obstacle(near, b.v if db == d else -b.v, "leader", b.id)
            if best is not None:
                return best
            k += 1
        return best

    def _crossing(self, a: Agent, ahead: float, now: float) -> Obstacle | None:
        """The first junction ahead that the agent has not been granted, as a stop line (None if all clear)."""
        for sn, n, k in a.crossings:
            if n in a.held:
                continue
            line = sn - JUNCTION_RADIUS
            if line > ahead:  # beyond sight, or behind this lane's leader
                return None
            move = a.movements.get(k)  # the same every time it asks (its route and lane do not change)
            if move is None:
                move = a.movements[k] = self._movement(a, sn, k)
            if self.crossings.request(n, a.id, move, now):
                a.held.add(n)
                continue
            return Obstacle(max(line, a.s), 0.0, "crossing", n, s0=0.5)
        return None

    def _movement(self, a: Agent, sn: float, k: int) -> Movement:
        r = a.route
        pts = [r.xy(min(max(sn + t, 0.0), r.length), a.lateral) for t in range(-8, 9, 2)]
        w = 0.5 * a.params.width
        xs, ys = [p[0] for p in pts], [p[1] for p in pts]
        return Movement(r.edges[k - 1], r.edges[k], (min(xs) - w, min(ys) - w, max(xs) + w, max(ys) + w))

    # ---- summaries --------------------------------------------------------------------------------------------
    def by_type(self) -> Counter:
        """Live entities counted by type name (for summaries and reports)."""
        return Counter(a.name for a in self.agents.values())
