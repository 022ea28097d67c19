"""One system of the end-to-end benchmark: the seeded world stepped in lock step, its traffic through one
transport, every viewer's ghosts measured against the truth.

Why one runner for every system: the world (same seed, entities, schedule), the cameras (the simulation's own
viewers: same walks and flights) and the measure (`sims.engine.measure.Measure`, against the cells of each
camera's PVS for every system, so "missed" and "stale" mean the same everywhere) are the simulation's; only
what crosses the wire differs:
- entitynet systems: the simulation's honest clients (`Fleet`: dead reckoning, or the periodic ablation) and
  viewers subscribing by PVS or a radius, as in `entitynet sim`, against a separate `entitynet serve` process.
- periodic systems (MQTT, Redis): every entity publishes a GPS fix (the same noise model) once a second,
  staggered by id as the fleet's fixes are, as compact HFP-like JSON (`payload`); each viewer shows the last
  position it received (HFP consumers do; no extrapolation) and drops a vehicle not heard of for
  `validity_s`. For the drawing rule a ghost claims the cells its entity occupied at the fix (known to the
  load generator, not sent).
Ticks are paced at `speed` x real time (our server expires entities on its own wall clock), then each tick:
subscription changes (acknowledged), the publishes, the transport's barrier, a sample each simulated second.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from entitynet import protocol as P
from entitynet.client.entities import entity_type
from entitynet.client.motion import WorldModel
from sims.bench import hfp_geohash as gh
from sims.engine.measure import Measure
from sims.engine.sim import Sim, SimConfig
from sims.engine.viewers import pvs_cells_at
from sims.mobility.gps import gps
from topology.projection import LocalProjection


@dataclass(frozen=True)
class System:
    """One system of the comparison: its transport ("entitynet", "mqtt", "redis"), how viewers subscribe
    ("pvs", "radius" for ours; "disc" or "pvs-boxes" for the grid systems), our clients' model and their
    drift threshold (None: the client core's default, the GPS accuracy)."""

    name: str
    transport: str
    subscribe: str
    client_model: str = "network"
    threshold: float | None = None


@dataclass(frozen=True)
class RunParams:
    """The workload every system runs (see the suite for the values and why)."""

    entities: int = 400
    viewers: int = 30
    seconds: float = 60.0
    tick_hz: float = 2.0
    seed: int = 7
    radius_m: float = 500.0
    speed: float = 1.0
    validity_s: float = 3.0  # a periodic viewer drops a vehicle not heard of for this long
    publishers: int = 4
    measure_after: float = 5.0
    timeout_s: float = 10.0
    transit: bool = True  # the schedule's trams and buses (given a schedule)


class PeriodicFeed:
    """The 1 Hz publishers of the grid systems: GPS fixes of the truth as HFP-like JSON, topic tail by box."""

    def __init__(self, sim: Sim, proj: LocalProjection, seed: int):
        self.sim, self.proj = sim, proj
        self.rng = np.random.default_rng(seed)
        self.due: dict[int, float] = {}
        self.prev: dict[int, tuple[float, float]] = {}
        self.cells_at_fix: dict[int, tuple[int, ...]] = {}
        self.modes: dict[int, str] = {}
        self.decoder: PeriodicDecoder | None = None  # the viewers' decoder, its cache cleared every tick

    def step(self, now: float) -> list[tuple[int, gh.Box, bytes]]:
        """The fixes due now: (entity, box, payload). New entities are phased by id as `Fleet` phases them."""
        world = self.sim.world
        for aid, _why in world.take_removed():
            self.due.pop(aid, None)
            self.prev.pop(aid, None)
        due, xy, v = [], [], []
        dt = self.sim.dt
        for aid, a in world.agents.items():
            x, y = a.xy()
            if aid not in self.due:
                self.due[aid] = now + (aid * 0.618033988749895) % 1.0
                self.modes[aid] = a.params.name
            if self.due[aid] <= now:
                px, py = self.prev.get(aid, (x, y))
                due.append(a)
                xy.append((x, y))
                v.append(((x - px) / dt, (y - py) / dt))
                self.due[aid] += max(1.0, math.floor(now - self.due[aid]) + 1.0)
            self.prev[aid] = (x, y)
        if not due:
            return []
        fixes = gps(np.array(xy), self.rng, self.sim.config.gps_sigma)
        ll = self.proj.to_wgs84(fixes)
        out = []
        for a, (lon, lat), (vx, vy) in zip(due, ll.tolist(), v, strict=True):
            self.cells_at_fix[a.id] = a.cells()
            spd = math.hypot(vx, vy)
            hdg = round(math.degrees(math.atan2(vx, vy)) % 360.0) if spd > 0.1 else 0
            payload = json.dumps({"VP": {"veh": a.id, "tsi": round(now, 3), "lat": round(lat, 7),
                                         "long": round(lon, 7), "spd": round(spd, 2), "hdg": hdg}},
                                 separators=(",", ":")).encode()
            out.append((a.id, gh.box_of(lat, lon), payload))
        return out


class PeriodicDecoder:
    """Payload -> (entity, model of the last position), once per distinct payload per tick (every viewer of a
    vehicle gets the same bytes); ValueError for a payload that is not a valid position report."""

    def __init__(self, proj: LocalProjection):
        self.proj = proj
        self.cache: dict[bytes, tuple[int, int, WorldModel]] = {}
        self.code = entity_type("car").code  # the cap does not bind: the model stands still

    def decode(self, payload: bytes) -> tuple[int, int, WorldModel]:
        """(entity, seq, model); ValueError (cached too) when malformed."""
        got = self.cache.get(payload)
        if got is None:
            try:
                vp = json.loads(payload)["VP"]
                veh, t, lat, lon = int(vp["veh"]), float(vp["tsi"]), float(vp["lat"]), float(vp["long"])
                if not all(map(math.isfinite, (t, lat, lon))):
                    raise ValueError("not finite")
                x, y = self.proj.to_local(np.array([lon]), np.array([lat]))[0].tolist()
                got = (veh, int(round(t * 1000)), WorldModel(t, x, y, 0.0, 0.0, 0.0, 0.0, self.code))
            except (ValueError, KeyError, TypeError) as exc:
                got = ValueError(f"malformed position report: {exc}")  # type: ignore[assignment]
            self.cache[payload] = got
        if isinstance(got, ValueError):
            raise got
        return got


class Tally:
    """What one viewer received: messages, wire bytes, malformed payloads."""

    __slots__ = ("messages", "bytes", "bad")

    def __init__(self) -> None:
        self.messages = self.bytes = self.bad = 0


def topic_of(box: gh.Box, mode: str, veh: int) -> str:
    """The HFP-like topic of a position report (trimmed: mode, vehicle, then the geohash levels)."""
    return f"/hfp/v2/journey/ongoing/vp/{mode}/{veh}/{gh.topic_tail(box)}"


def filter_of(box: gh.Box) -> str:
    """The MQTT topic filter of every report inside `box`."""
    return f"/hfp/v2/journey/ongoing/vp/+/+/{gh.topic_tail(box)}/#"


def channel_of(box: gh.Box) -> str:
    """The Redis channel of a grid box."""
    return f"g:{gh.topic_tail(box)}"


class _Seen:
    """A viewer as the measure sees it: its group, the cells of its camera's PVS (what the camera can see, the
    same yardstick for every system) and its ghosts."""

    __slots__ = ("high", "subs", "ghosts")

    def __init__(self, high: bool, cells, ghosts) -> None:
        self.high, self.subs, self.ghosts = high, SimpleNamespace(cells=cells), ghosts


def run_system(topo, schedule, system: System, p: RunParams, connect, cell_boxes=None, progress=None,
               server_cpu=None, seen_at=None) -> dict:
    """Run one system for `p.seconds` simulated seconds; its figures. `connect(on_message)` opens the
    transport (MQTT/Redis: `on_message(viewer, topic, payload, size)`; ours: `on_message(viewer, msg, size)`);
    `cell_boxes`: the boxes of each cell (the "pvs-boxes" subscription); `server_cpu()`: the broker's CPU
    seconds so far, read when the ticks start and end (its start-up and our connecting are left out);
    `seen_at(x, y, z)`: the cells a camera can see, the measure's yardstick (default: the PVS; a map without
    one, as in the tests, gives a distance cut here)."""
    ours = system.transport == "entitynet"
    cfg = SimConfig(entities=p.entities, viewers=p.viewers, connections=p.publishers, tick_hz=p.tick_hz,
                    seed=p.seed, subscribe="radius" if system.subscribe == "radius" else "pvs",
                    radius=p.radius_m, client_model=system.client_model, threshold=system.threshold,
                    measure_after=p.measure_after,
                    transit=p.transit and schedule is not None)
    sim = Sim(topo, cfg, schedule)
    pvs_at = seen_at or pvs_cells_at(topo)
    if pvs_at is None:
        raise ValueError("the end-to-end benchmark needs a topology with a PVS")
    proj = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"]))
    tallies = [Tally() for _ in sim.viewers]
    eid_to_agent: dict[int, int] = {}
    owner: dict[bytes, int] = {}  # ours: the latest payload of each entity -> entity (maps server ids back)
    latest: dict[int, bytes] = {}
    decoder = PeriodicDecoder(proj)
    now_box = [sim.now]

    def on_ours(i: int, m: P.Message, size: int) -> None:
        t = tallies[i]
        t.messages += 1
        t.bytes += size
        if isinstance(m, P.Update) and m.entity not in eid_to_agent:
            aid = owner.get(m.payload)
            if aid is not None:
                eid_to_agent[m.entity] = aid
        sim.viewers[i].receive(m, now_box[0], 0)

    def on_grid(i: int, topic: str, payload: bytes, size: int) -> None:
        t = tallies[i]
        t.messages += 1
        t.bytes += size
        try:
            veh, seq, model = decoder.decode(payload)
        except ValueError:
            t.bad += 1
            return
        cells = feed.cells_at_fix.get(veh, ())
        sim.viewers[i].ghosts.receive(P.Update(veh, seq, cells, int(p.validity_s * 1000), payload), now_box[0])

    feed = None if ours else PeriodicFeed(sim, proj, p.seed + 101)
    if feed is not None:
        feed.decoder = decoder
    if not ours:
        for v in sim.viewers:  # the ghost store takes the model decoded once (`on_grid` decodes first)
            v.ghosts._decode = lambda payload: decoder.decode(payload)[2]
    transport = connect(on_ours if ours else on_grid)
    try:
        return _loop(sim, system, p, transport, feed, tallies, eid_to_agent, owner, latest, pvs_at, proj,
                     cell_boxes, now_box, progress, server_cpu or (lambda: 0.0))
    finally:
        transport.close()


def _grid_keys(system: System, v, proj: LocalProjection, radius: float, cell_boxes, memo: dict) -> set[gh.Box]:
    if system.subscribe == "disc":
        x, y = v.traj.position()
        lon, lat = proj.to_wgs84(np.array([[x, y]]))[0].tolist()
        return gh.disc_cover(lat, lon, radius)
    cells = v._last_cells  # the PVS array of the camera's view cell (cached by the index: same object)
    got = memo.get(id(cells))
    if got is None or got[0] is not cells:
        boxes: set[gh.Box] = set()
        for c in np.asarray(cells).tolist():
            boxes |= cell_boxes[c]
        got = memo[id(cells)] = (cells, gh.merge(boxes))
    return got[1]


def _loop(sim, system, p, transport, feed, tallies, eid_to_agent, owner, latest, pvs_at, proj, cell_boxes,
          now_box, progress, server_cpu) -> dict:
    ours = feed is None
    viewers = sim.viewers
    measure = Measure()
    keys: list[set] = [set() for _ in viewers]
    memo: dict = {}
    name_of = filter_of if system.transport == "mqtt" else channel_of
    n_ticks = int(round(p.seconds * p.tick_hz))
    if ours:
        for v, w in zip(viewers, transport.welcomes[len(transport.pubs):], strict=True):
            v.receive(w, sim.now)
        pubs, subs = sim.start()
    else:
        sim.population.start()
        pubs, subs = None, [v.move(0.0) for v in viewers]
    next_sample = sim.now + p.measure_after
    late, behind, period = [], 0, sim.dt / p.speed
    cpu0, wall0, srv0 = time.process_time(), time.monotonic(), server_cpu()
    due = wall0
    for k in range(n_ticks + 1):
        if k:
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            late.append(max(0.0, -wait))
            behind += -wait > period
            if ours:
                pubs, subs = sim.step()
            else:
                sim.world.step(sim.dt)
                sim.ticks += 1
                sim.population.step()
                subs = [v.move(sim.dt) for v in viewers]
        due += period
        now_box[0] = sim.now
        if ours:
            for i, msgs in enumerate(subs):
                transport.subscribe(i, msgs)
        else:
            for i, v in enumerate(viewers):
                want = _grid_keys(system, v, proj, p.radius_m, cell_boxes, memo)
                if want != keys[i]:
                    transport.subscribe(i, [name_of(b) for b in want - keys[i]],
                                        [name_of(b) for b in keys[i] - want])
                    keys[i] = want
        transport.settle()
        if ours:
            for conn, msgs in enumerate(pubs):
                for m in msgs:
                    if isinstance(m, P.Publish):
                        old = latest.get(m.entity)
                        if old is not None:
                            owner.pop(old, None)
                        latest[m.entity] = m.payload
                        owner[m.payload] = m.entity
                transport.publish(conn, msgs)
        else:
            feed.decoder.cache.clear()  # a tick's reports are all delivered within the tick (the barrier)
            for aid, box, payload in feed.step(sim.now):
                conn = aid % p.publishers
                if system.transport == "mqtt":
                    transport.publish(conn, topic_of(box, feed.modes[aid], aid), payload)
                else:
                    transport.publish(conn, channel_of(box), payload)
        transport.sync(k)
        if sim.now + 1e-9 >= next_sample:
            next_sample += 1.0
            seen = []
            for v in viewers:
                x, y = v.traj.position()
                seen.append(_Seen(v.high, pvs_at(x, y, v.z), v.ghosts))
            measure.sample(sim.now, sim.world, seen, eid_to_agent if ours else _identity(sim))
        if progress is not None and k and k % int(10 * p.tick_hz) == 0:
            progress(f"  {system.name}: {k / p.tick_hz:.0f} of {p.seconds:g} simulated s")
    cpu, wall, srv = time.process_time() - cpu0, time.monotonic() - wall0, server_cpu() - srv0
    viewer_s = len(viewers) * p.seconds
    delivered = sum(t.messages for t in tallies)
    lat = np.array(late) if late else np.zeros(1)
    tv = measure.summary()
    return {
        "system": system.name, "transport": system.transport, "subscribe": system.subscribe,
        "client_model": system.client_model if ours else "periodic 1 Hz (HFP-like JSON, last position shown)",
        "threshold_m": system.threshold,
        "messages_per_viewer_s": sum(t.messages for t in tallies) / viewer_s,
        "bytes_per_viewer_s": sum(t.bytes for t in tallies) / viewer_s,
        "malformed_payloads": sum(t.bad for t in tallies),
        "subscriptions_mean": float(np.mean([len(k) for k in keys])) if not ours else float(
            np.mean([len(v.subs.cells) for v in viewers])),
        "error_mean_m": tv["all"]["error_mean_m"], "error_p95_m": tv["all"]["error_p95_m"],
        "error_max_m": tv["all"]["error_max_m"], "missed_visibility": tv["all"]["missed_visibility"],
        "stale_ghost_fraction": tv["all"]["stale_ghost_fraction"], "truth_vs_viewer": tv,
        "entities_on_map": len(sim.world.agents),
        "server_cpu_s": srv, "server_cpu_ms_per_viewer_s": 1000.0 * srv / viewer_s,
        "server_cpu_us_per_delivered": 1e6 * srv / delivered if delivered else None,
        "loadgen_cpu_s": cpu, "wall_s": wall, "viewer_seconds": viewer_s,
        # the broker's CPU against the load generator's for the same (seeded, lock-stepped) work in the same run,
        # both on the same CPU: the machine's speed of the moment divides out (docs/e2e.md, "Stability")
        "server_cpu_per_loadgen_cpu": srv / cpu if cpu > 0 else None,
        "loadgen_cpu_share": cpu / wall if wall > 0 else None,
        "tick_lateness_p50_ms": float(np.percentile(lat, 50) * 1000),
        "tick_lateness_p99_ms": float(np.percentile(lat, 99) * 1000), "ticks_behind": int(behind),
    }


def _identity(sim: Sim) -> dict[int, int]:
    return {aid: aid for aid in sim.world.agents}
