"""The transit proxy's core (sans-IO): tracker answers in, honest-client messages out.

`ingest` takes the calls of one poll (SIRI MonitoredStopVisits or GTFS-rt StopTimeUpdates, as `siri_xml.Call`),
keeps only traced vehicles on the map's routes (the rest is counted as discarded), and updates each vehicle's
`EtaMotion`. `fixes` takes GTFS-rt VehiclePositions: the position goes to the vehicle's client core as a phone's
fix would. `tick(now)` moves every vehicle, feeds its position to its `entitynet.client.Player` (its route as the
a-priori path, its stops as known halts) every `fix_interval` seconds and returns what the players publish;
vehicles whose data is older than `stale_after`, or that reached the end of their route on the map, leave.

One client core for the fleet: every vehicle's Player is a row of one `entitynet.client.fleet.FleetCore` (added
when the vehicle is placed, removed when it leaves), and `tick` steps them together: the motion's fixes with
their Doppler velocity, and the timers, over arrays; a Player is called only where something happens, as the
simulator's fleet does. `core="player"` turns the arrays off (one `feed` or `tick` per vehicle, the per-entity
path the tests compare with: the same messages, payload bytes included). A GTFS-rt position (`fix`) has its own
time, so it goes to its vehicle's Player directly.

Clocks: the producer's times are mapped to ours by the offset `received - ResponseTimestamp` with the smallest
value seen lately (the answer with the least latency tells the offset best, as NTP does), so a service that
answers several seconds late does not shift every ETA by its latency.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from entitynet.client import FixRejected, Path, Player, netview
from entitynet.client.entities import entity_type
from entitynet.client.fleet import FleetCore
from entitynet.client.motion import NetworkModel
from entitynet.protocol import Publish, Unpublish
from proxies.eta_motion import EtaMotion, Limits
from proxies.routes import RouteBook, TransitRoute
from proxies.siri_xml import Call

# fewer motion fixes in a tick than this go to the vehicles' Players, not the arrays (`FleetCore.min_rows`):
# the vectorised fix costs a few ms a call whatever its rows, a Player's fix about 80 us (docs/transit.md)
MIN_ROWS = 32


@dataclass
class Counters:
    """What the proxy did with its input, so that discarded data (untraced, off the map) is visible in
    the metrics and the benchmark rather than silently lost."""
    calls: int = 0
    used: int = 0
    untraced: int = 0
    off_map: int = 0
    polls: int = 0
    fixes: int = 0
    publishes: int = 0
    fixes_rejected: int = 0  # fixes the client core refused (NaN, a position off the map's frame): counted, not fed
    retired_stale: int = 0
    retired_done: int = 0
    stops_served_retired: int = 0  # stops served by vehicles that have left (`Fleet.stops_served` adds the rest)
    vehicles_seen: set[str] = field(default_factory=set)

    @property
    def discarded_fraction(self) -> float:
        """Share of the received calls that were not used (0 before any call)."""
        return 1.0 - self.used / self.calls if self.calls else 0.0


@dataclass
class Vehicle:
    """One proxied vehicle: its trip and route, the ETA motion that moves it and the Player that
    publishes it as an honest client would (a row of the fleet's client core, at `slot`: read it here, change
    it through `FleetCore.player(slot)`)."""
    ref: str
    trip: str
    route: TransitRoute
    entity: int
    motion: EtaMotion
    player: Player
    index_of: dict[int, int]  # trip stop index -> route stop index
    last_data: float
    slot: int  # its row in the fleet's client core
    last_fix: float = -math.inf
    still_s: float | None = None  # path coordinate of the last fix fed while standing at a stop, else None
    next_check: float = -math.inf  # a fix found needless is not looked at again before this time
    positions: bool = False  # a position feed gives its fixes (the ETA motion only fills gaps)


class Fleet:
    """The proxy core (sans-IO): tracker answers in, PUBLISH/UNPUBLISH out, one Player per vehicle in one
    fleet core (see the module docstring for the clock mapping, the core and when vehicles leave)."""

    def __init__(self, topo, book: RouteBook, *, fix_interval: float = 2.0, stale_after: float = 300.0,
                 granularity: float = 60.0, threshold: float = 8.0, accuracy: float = 3.0,
                 first_entity: int = 1, entry_horizon: float = 20.0, quiet_drift: float = 2.0,
                 quiet_refresh: float = 6.0, core: str = "fleet", min_rows: int = MIN_ROWS) -> None:
        if core not in ("fleet", "player"):
            raise ValueError(f"core must be 'fleet' or 'player', got {core!r}")
        self.core = FleetCore(vectorised=core == "fleet", min_rows=min_rows)
        self.topo = topo
        self.net = netview(topo)
        self.book = book
        self.fix_interval = fix_interval
        self.stale_after = stale_after
        self.granularity = granularity
        self.threshold = threshold
        self.accuracy = accuracy
        self.entry_horizon = entry_horizon
        self.position_gap = 60.0  # s without a position before the ETA motion feeds the fixes again
        self.standing_refresh = 10.0  # s between fixes of a vehicle standing at a stop once its ghost stands
        self.quiet_refresh = quiet_refresh  # s between fixes of a vehicle moving as its ghost does
        self.quiet_drift = quiet_drift  # m from its ghost within which a moving vehicle is "as its ghost"
        self.vehicles: dict[str, Vehicle] = {}
        self.counters = Counters()
        self._next_entity = first_entity
        self._paths: dict[int, Path] = {}
        self._poly: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._route_index: dict[int, dict[int, int]] = {}
        self._route_stops: dict[int, dict[str, list[int]]] = {}
        self._offsets: deque[float] = deque(maxlen=20)
        self.pending: list[Publish | Unpublish] = []

    # ---- clocks -----------------------------------------------------------------------------------------
    def clock_offset(self, response_time: float, received: float) -> float:
        """local - producer, from this answer and the recent ones (smallest wins)."""
        if math.isfinite(response_time) and math.isfinite(received):
            self._offsets.append(received - response_time)
        return min(self._offsets) if self._offsets else 0.0

    # ---- routes ---------------------------------------------------------------------------------------------
    def path_of(self, route: TransitRoute) -> Path:
        """The Path of a route, built once per route object (trips of one shape share it)."""
        p = self._paths.get(id(route))
        if p is None:
            p = self._paths[id(route)] = Path(self.net, route.edges)
        return p

    def _project(self, route: TransitRoute, x: float, y: float, s_near: float) -> float | None:
        """Path coordinate of a reported location near the route (within 50 m), preferring the nearest to
        `s_near` where the route passes twice."""
        got = self._poly.get(id(route))
        if got is None:
            pts = []
            for e, d in route.edges:
                p = self.topo.edge_polyline(e)
                pts.append(p if d > 0 else p[::-1])
            xy = np.concatenate(pts)
            cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
            got = self._poly[id(route)] = (xy, cum)
        xy, cum = got
        a, b = xy[:-1], xy[1:]
        ab = b - a
        ll = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
        p = np.array([x, y])
        t = np.clip(np.einsum("ij,ij->i", p - a, ab) / ll, 0.0, 1.0)
        d = np.hypot(*(a + t[:, None] * ab - p).T)
        s = cum[:-1] + t * (cum[1:] - cum[:-1])
        ok = d <= 50.0
        if not ok.any():
            return None
        cost = np.where(ok, d + 0.05 * np.abs(s - s_near), np.inf)
        return float(s[int(np.argmin(cost))])

    def _new_motion(self, route: TransitRoute) -> EtaMotion:
        """The ETA motion of a vehicle on `route` (cheap: placed before the costlier Player exists)."""
        et = entity_type("tram" if route.mode == "tram" else "bus")
        return EtaMotion([st.s for st in route.stops], [(st.sched_arr, st.sched_dep) for st in route.stops],
                         Limits(vmax=min(et.vmax, 14.0 if route.mode == "tram" else 15.0), accel=et.amax * 0.8,
                                brake=et.brake), granularity=self.granularity)

    def _new_vehicle(self, ref: str, trip: str, route: TransitRoute, motion: EtaMotion) -> Vehicle:
        """A vehicle with its honest client core. Built only once its motion is placed on the map: a Player
        (its path, its stops located) costs more than reading a poll, and a vehicle still off the map is asked
        about at every poll until it enters."""
        et = entity_type("tram" if route.mode == "tram" else "bus")
        path = self.path_of(route)
        stops = [path.locate(min(st.s, path.length)) for st in route.stops]
        player = Player(self.topo, self._next_entity, et, route=route.edges, stops=stops,
                        accuracy=self.accuracy, threshold=self.threshold)
        self._next_entity += 1
        return Vehicle(ref, trip, route, player.entity, motion, player, self._index_of(route), 0.0,
                       self.core.add(player))

    def _index_of(self, route: TransitRoute) -> dict[int, int]:
        """Trip stop index -> route stop index, once per route object (shared: read only)."""
        got = self._route_index.get(id(route))
        if got is None:
            got = self._route_index[id(route)] = {st.index: i for i, st in enumerate(route.stops)}
        return got

    def _stop_index(self, route: TransitRoute) -> dict[str, list[int]]:
        """Stop id -> route stop indices (several where the route passes a stop twice), once per route."""
        got = self._route_stops.get(id(route))
        if got is None:
            got = {}
            for i, st in enumerate(route.stops):
                got.setdefault(st.stop_id, []).append(i)
            self._route_stops[id(route)] = got
        return got

    # ---- input ---------------------------------------------------------------------------------------------
    def ingest(self, calls: list[Call], response_time: float, received: float, *,
               to_local=None) -> None:
        """One poll's calls. `to_local(lon, lat) -> (x, y)` maps VehicleLocation when given."""
        c = self.counters
        c.polls += 1
        c.calls += len(calls)
        off = self.clock_offset(response_time, received)
        by_vehicle: dict[str, list[Call]] = {}
        for call in calls:
            if not call.vehicle or not call.monitored:
                c.untraced += 1
                continue
            by_vehicle.setdefault(call.vehicle, []).append(call)
        for ref, vcalls in by_vehicle.items():
            found = self.book.route_of(vcalls[0].journey)
            if found is None:
                c.off_map += len(vcalls)
                continue
            trip, route = found
            veh = self.vehicles.get(ref)
            if veh is not None and veh.trip != trip:
                self.pending.extend(self._retire(ref))  # the vehicle started its next trip: a new route
                veh = None
            index_of = self._index_of(route)
            stop_index = self._stop_index(route)
            etas, etds, aimed = {}, {}, {}
            at_stop = None
            loc = None
            for call in vcalls:
                # the stop id says which stop; the order (SIRI Order / VisitNumber, GTFS-rt stop_sequence: not
                # always the trip's index + 1 in real feeds) only where the route passes a stop twice
                cand = stop_index.get(call.stop_id, ())
                i = cand[0] if len(cand) == 1 else None
                if i is None and call.order:
                    i = index_of.get(call.order - 1)
                    if cand and i not in cand:
                        i = cand[0]
                if i is None or call.expected_arrival is None:
                    continue
                etas[i] = call.expected_arrival + off
                if call.expected_departure is not None:
                    etds[i] = call.expected_departure + off
                if call.aimed_arrival is not None:
                    aimed[i] = call.aimed_arrival + off
                if call.at_stop:
                    at_stop = i if at_stop is None else min(at_stop, i)
                if call.lon is not None and to_local is not None:
                    loc = (call.lon, call.lat)
            if not etas:
                c.off_map += len(vcalls)
                continue
            c.used += 1
            c.vehicles_seen.add(ref)
            nxt = min(etas)
            if veh is None:
                motion = self._new_motion(route)
                if not self._place(motion, route, nxt, etas[nxt], at_stop, received, loc, to_local):
                    continue  # not on the map yet
                veh = self.vehicles[ref] = self._new_vehicle(ref, trip, route, motion)
            loc_s = None
            if loc is not None:
                x, y = to_local(*loc)
                loc_s = self._project(route, x, y, veh.motion.s)
            veh.motion.observe(received, etas, etds, at_stop, aimed, loc_s)
            veh.last_data = received

    def _place(self, m: EtaMotion, route: TransitRoute, nxt: int, eta: float, at_stop: int | None, now: float,
               loc, to_local) -> bool:
        if loc is not None:
            x, y = to_local(*loc)
            s = self._project(route, x, y, route.stops[nxt].s)
            if s is not None:
                m.place(min(s, route.stops[nxt].s), now, nxt)
                return True
        if at_stop is not None or nxt == 0 and eta - now <= 0.0:
            m.place(route.stops[nxt].s, now, nxt)
            m.standing = True
            return True
        s_next = route.stops[nxt].s
        left = max(eta - now, 0.0)
        if nxt > 0:
            prev = route.stops[nxt - 1]
            run = max(route.stops[nxt].sched_arr - prev.sched_dep, 1.0)
            frac = min(max(1.0 - left / run, 0.0), 1.0)
            s = prev.s + frac * (s_next - prev.s)
        else:
            # entering the map: where it is before its first stop here is a guess (the schedule's speed from its
            # previous stop, off the map), so it appears only `entry_horizon` seconds before that stop
            if left > self.entry_horizon:
                return False
            s = max(s_next - left * route.stops[nxt].approach_speed, 0.0)
        m.place(s, now, nxt)
        return True

    def ingest_positions(self, positions, offset: float, to_local) -> None:
        """GTFS-rt VehiclePositions (`gtfsrt.Position`, producer times + `offset` = local): each position is a
        fix for the vehicle's client core, as a phone's would be; a vehicle seen first is placed where the
        position projects onto its route. The ETA motion is moved up to the position, so that it carries on
        from there should the positions stop."""
        c = self.counters
        c.polls += 1
        for pos in positions:
            c.calls += 1
            if not pos.vehicle or not pos.trip_id:
                c.untraced += 1
                continue
            found = self.book.route_of(pos.trip_id)
            if found is None:
                c.off_map += 1
                continue
            trip, route = found
            x, y = to_local(pos.lon, pos.lat)
            veh = self.vehicles.get(pos.vehicle)
            if veh is not None and veh.trip != trip:
                self.pending.extend(self._retire(pos.vehicle))
                veh = None
            s = self._project(route, x, y, veh.motion.s if veh is not None else 0.0)
            if s is None:
                c.off_map += 1
                continue
            t = pos.t + offset
            if veh is None:
                motion = self._new_motion(route)
                nxt = next((i for i, st in enumerate(route.stops) if st.s > s + 1.0), len(route.stops) - 1)
                motion.place(s, t, nxt)
                veh = self.vehicles[pos.vehicle] = self._new_vehicle(pos.vehicle, trip, route, motion)
            c.used += 1
            c.vehicles_seen.add(pos.vehicle)
            veh.motion.observe(t, {}, location_s=s)
            veh.positions = True
            self.fix(pos.vehicle, x, y, t, pos.speed, pos.bearing)

    def fix(self, ref: str, x: float, y: float, t: float, speed: float | None = None,
            heading: float | None = None) -> None:
        """A vehicle position (local metres): fed to the vehicle's client core as it is, when newer."""
        veh = self.vehicles.get(ref)
        if veh is None or t <= veh.last_fix:
            return
        try:
            self.pending.extend(self.core.player(veh.slot).feed(x, y, t, self.accuracy, speed=speed, heading=heading))
        except FixRejected:
            self.counters.fixes_rejected += 1
            return
        veh.last_fix = t
        veh.still_s = None
        veh.last_data = max(veh.last_data, t)
        self.counters.fixes += 1

    # ---- time ----------------------------------------------------------------------------------------------
    def position(self, veh: Vehicle, now: float) -> tuple[float, float, float, float]:
        """(x, y, speed, heading) of the vehicle's motion at `now`; the heading from the chord to 2 m ahead
        (behind at the route's end), two path look-ups per fix."""
        s, v = veh.motion.advance(now)
        path = self.path_of(veh.route)
        x, y = path.xy(s)
        if s + 2.0 <= path.length:
            x1, y1 = path.xy(s + 2.0)
            heading = math.degrees(math.atan2(x1 - x, y1 - y)) % 360.0
        else:
            x0, y0 = path.xy(max(s - 2.0, 0.0))
            heading = math.degrees(math.atan2(x - x0, y - y0)) % 360.0
        return x, y, v, heading

    def _idle(self, veh: Vehicle, now: float) -> bool:
        """True when a fix now would tell the client core nothing new, so only the player's clock runs
        (validity, heartbeat): the vehicle stands at a stop where the last fix already had it and its ghost
        stands too (a third of a transit vehicle's time), or it moves within `quiet_drift` metres of its
        published ghost (cruising as published), in both cases with a fix under `standing_refresh` or
        `quiet_refresh` seconds old (far below the type's `max_gap`). The fix that shows it stopping, starting or
        drifting is fed at the next tick."""
        m = veh.motion
        g = veh.player.ghost
        age = now - veh.last_fix
        if not isinstance(g, NetworkModel) or not veh.player.published:
            return False
        still = veh.still_s
        if still is not None:
            if age >= self.standing_refresh:
                return False
            m.advance(now)
            return m.standing and m.s == still and g.v == 0.0 and g.a == 0.0
        if age >= self.quiet_refresh or self.quiet_drift <= 0.0:
            return False
        s, _v = m.advance(now)
        if m.standing:
            return False
        x, y = self.path_of(veh.route).xy(s)
        gx, gy = g.xy_at(now)
        return (x - gx) ** 2 + (y - gy) ** 2 < self.quiet_drift ** 2

    def tick(self, now: float, *, motion_fixes: bool = True) -> list[Publish | Unpublish]:
        """Move every vehicle to `now`; returns what to send (the vehicles' messages in the order they came, as
        the core steps them). `motion_fixes=False` when a GTFS-rt position feed provides the fixes (the motion
        then only fills the gaps between positions). A wall clock stepping back holds the time still."""
        now = max(now, self.core.last_now)
        out = self.pending
        self.pending = []
        order = self.core.order
        left: list[tuple[int, list[Unpublish]]] = []  # (order, messages) of the vehicles leaving now
        due: list[int] = []
        fixes: list[tuple[float, float, float, float]] = []
        for ref in list(self.vehicles):
            veh = self.vehicles[ref]
            if now - veh.last_data > self.stale_after or veh.motion.finished:
                if veh.motion.finished:
                    self.counters.retired_done += 1
                else:
                    self.counters.retired_stale += 1
                left.append((int(order[veh.slot]), self._retire(ref)))
                continue
            gap = self.fix_interval if not veh.positions else max(self.fix_interval, self.position_gap)
            if motion_fixes and now - veh.last_fix >= gap and now >= veh.next_check:
                if self._idle(veh, now):
                    veh.next_check = now + gap  # the same cadence as the fixes it stands for (its timers run)
                    continue
                due.append(veh.slot)
                fixes.append(self.position(veh, now))
                veh.last_fix = now
                veh.still_s = veh.motion.s if veh.motion.standing else None
        self.counters.fixes += len(due)
        f = np.array(fixes, dtype=float).reshape(len(fixes), 4)
        stepped, rejected = self.core.step(now, due, f[:, 0], f[:, 1], self.accuracy, speed=f[:, 2],
                                            heading=f[:, 3], speed_accuracy=0.3)
        self.counters.fixes_rejected += rejected
        msgs = [(int(order[slot]), m) for slot, m in stepped]
        if left:  # (a vehicle leaving has no row any more: its messages go where its row's were)
            msgs = sorted(msgs + left, key=lambda om: om[0])
        for _o, m in msgs:
            out.extend(m)
        self.counters.publishes += sum(1 for m in out if isinstance(m, Publish))
        return out

    def _retire(self, ref: str) -> list[Unpublish]:
        veh = self.vehicles.pop(ref, None)
        if veh is None:
            return []
        self.counters.stops_served_retired += veh.motion.stops_served
        return self.core.remove(veh.slot)

    def stops_served(self) -> int:
        """Stops the fleet's vehicles came to stand at, those that have left included (the demo's summary
        counts them with the simulation's own buses and trams)."""
        return self.counters.stops_served_retired + sum(v.motion.stops_served for v in self.vehicles.values())

    def by_mode(self) -> dict[str, int]:
        """Vehicles on the map by mode ("tram", "bus"), as the simulation counts its entities by type."""
        out: dict[str, int] = {}
        for veh in self.vehicles.values():
            out[veh.route.mode] = out.get(veh.route.mode, 0) + 1
        return out

    def ghost_xy(self, ref: str, now: float) -> tuple[float, float] | None:
        """Where a viewer sees the vehicle now (its published model extrapolated), or None."""
        veh = self.vehicles.get(ref)
        if veh is None or veh.player.ghost is None or not veh.player.published:
            return None
        return veh.player.ghost.xy_at(now)
