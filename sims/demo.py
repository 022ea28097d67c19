"""`entitynet demo`: a live city on loopback.

One shard server (in this process, real TCP), a few hundred honest clients (pedestrians and cars, each through
the client core) multiplexed over a few connections the way a proxy carries a fleet, and viewers whose cameras
move at street level and above the roofs, subscribing to the PVS of their view cell. A summary line is printed
every few seconds; the run stops after `duration` seconds or on Ctrl-C.
"""

from __future__ import annotations

import random
import signal
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np
import trio

from entitynet import protocol as P
from entitynet.client import FixRejected, GhostStore, Subscriptions, netview
from entitynet.connection import Connection
from entitynet.server.app import Server, serve
from entitynet.server.config import ServerConfig
from sims.mobility import Mover, Trajectory, random_start
from topology.raw import PEDESTRIAN

Say = Callable[[str], None]


@dataclass
class DemoConfig:
    """The demo's knobs (population, viewers, connections, duration) with defaults a laptop runs live."""
    entities: int = 300
    viewers: int = 24
    connections: int = 4
    car_share: float = 0.3
    bus_share: float = 0.0  # the CLI's demo adds a few buses and trams (random routes, as the others)
    tram_share: float = 0.0
    duration: float | None = None  # seconds; None = until Ctrl-C
    summary_every: float = 5.0
    fix_interval: float = 1.0
    roof_share: float = 0.25  # share of viewers flying above the roofs
    seed: int = 1
    host: str = "127.0.0.1"
    port: int = 0
    transit: str | None = None  # a GTFS feed: trams and buses through the replay producer and the SIRI proxy
    http_port: int | None = None  # serve the browser viewer here (0: any free port; None: none)


@dataclass
class Stats:
    """Totals the demo prints and returns, so a run (and its test) can check that traffic flowed."""
    published: int = 0
    deliveries: int = 0
    rejected_fixes: int = 0
    subscribe_msgs: int = 0


def distance_cells_at(topo, view_distance: float = 500.0) -> Callable[[float, float, float], np.ndarray]:
    """Fallback when the artifact has no PVS: every cell whose footprint centre is within the view distance."""
    b = topo.cell_footprints.bounds()
    centres = np.column_stack([(b[:, 0] + b[:, 2]) / 2, (b[:, 1] + b[:, 3]) / 2])

    def cells_at(x: float, y: float, z: float) -> np.ndarray:
        return np.flatnonzero(np.hypot(centres[:, 0] - x, centres[:, 1] - y) <= view_distance)

    return cells_at


def pvs_lookup(topo, say: Say) -> Callable[[float, float, float], np.ndarray]:
    """The viewers' `cells_at`: the artifact's PVS, or, without one, every cell within 500 m (said
    once, so the demo still runs on a map built without PVS)."""
    if "pvs" in topo.meta:
        from topology.pvs_index import PvsIndex

        return PvsIndex.from_topology(topo).cells_at
    say("the artifact has no PVS: viewers subscribe to every cell within 500 m instead")
    return distance_cells_at(topo)


class Viewer:
    """A camera that moves and subscribes to the PVS of its view cell; it keeps ghosts of what it receives."""

    def __init__(self, topo, net, index: int, high: bool, cells_at, rng: random.Random):
        self.index = index
        self.high = high
        self.z = rng.uniform(40.0, 90.0) if high else 1.7
        self.traj = Trajectory.starting_at(net, PEDESTRIAN, rng, random_start(net, PEDESTRIAN, rng))
        self.speed = 6.0 if high else 1.4
        self.subs = Subscriptions(cells_at)
        self.ghosts = GhostStore(net)
        self.conn: Connection | None = None
        self.deliveries = 0

    def on_message(self, msg: P.Message) -> None:
        """Feed deliveries to the ghost store; on WELCOME forget old ghosts (entity ids are per server
        session) and adopt the server's limits."""
        if isinstance(msg, P.Update | P.Leave):
            if isinstance(msg, P.Update):
                self.deliveries += 1
            self.ghosts.receive(msg, time.time())
        elif isinstance(msg, P.Welcome):
            self.ghosts.ghosts.clear()  # entity ids are per server session
            self.subs.apply_limits(msg.limits)  # the next move subscribes within them (max_subscriptions, ...)

    def move(self, dt: float) -> list[P.Subscribe]:
        """Walk or fly the camera by dt and return the SUBSCRIBE difference for its new PVS."""
        self.traj.advance(self.speed * dt)
        x, y = self.traj.position()
        msgs = self.subs.move_camera(x, y, self.z)
        self.ghosts.set_visible(self.subs.cells)
        return msgs


def _plural(kind: str) -> str:
    return kind + ("es" if kind.endswith("s") else "s")


def _entity_kind(rng: random.Random, config: DemoConfig) -> str:
    r = rng.random()
    for kind, share in (("car", config.car_share), ("bus", config.bus_share), ("tram", config.tram_share)):
        if r < share:
            return kind
        r -= share
    return "pedestrian"


async def run_demo(topo, artifact: Path, config: DemoConfig, say: Say = print,
                   task_status=trio.TASK_STATUS_IGNORED) -> Stats:
    """Run the live demo on loopback (server, honest clients, viewers, optional transit) until `duration` or
    Ctrl-C, printing summaries; returns the totals. `task_status.started(server)` once everything is connected."""
    rng = random.Random(config.seed)
    net = netview(topo)
    cells_at = pvs_lookup(topo, say)
    stats = Stats()
    async with trio.open_nursery() as nursery:
        server: Server = await nursery.start(
            serve, ServerConfig(host=config.host, port=config.port, topology=str(artifact), open_mode=True,
                                ws_port=None if config.http_port is None else 0, http_port=config.http_port)
        )
        address = (config.host, server.port)
        say(f"shard server listening on {config.host}:{server.port} (open mode: no tokens, local use only)")
        if server.http_port is not None:
            from entitynet.viewer.routes import BUILD_HINT, BUNDLE, STATIC

            say(f"open the 3D viewer: http://{config.host}:{server.http_port}/")
            if not (STATIC / BUNDLE).exists():
                say(BUILD_HINT)

        async with trio.open_nursery() as clients:
            movers = [
                Mover(topo, net, i + 1, _entity_kind(rng, config), rng) for i in range(config.entities)
            ]
            kinds = Counter(m.etype.name for m in movers)
            conns = [Connection(address, topo.digest, on_message=lambda m: None) for _ in range(config.connections)]
            for c in conns:
                await clients.start(c.run)
            n_high = round(config.viewers * config.roof_share)
            viewers = [Viewer(topo, net, i, i < n_high, cells_at, rng) for i in range(config.viewers)]
            for v in viewers:
                v.conn = Connection(address, topo.digest, on_message=v.on_message)
                await clients.start(v.conn.run)
            say(
                f"{len(movers)} entities ({', '.join(f'{n} {_plural(k)}' for k, n in sorted(kinds.items()))}) over "
                f"{len(conns)} connections; {len(viewers)} viewers ({n_high} above the roofs)"
            )

            if config.transit:
                run_transit = demo_part("transit")  # optional part, from the proxies package
                await clients.start(run_transit, topo, address, config.transit, say)

            task_status.started(server)
            stop = trio.Event()
            clients.start_soon(_stop_on_signal, stop)
            if config.duration is not None:
                clients.start_soon(_stop_after, stop, config.duration)
            start = time.time()
            last_summary = start
            window = Stats()
            next_tick = trio.current_time()
            while not stop.is_set():
                now = time.time()
                batches: list[list[P.Publish]] = [[] for _ in conns]
                for k, m in enumerate(movers):
                    m.step(config.fix_interval)
                    try:
                        msgs = m.fix(now) + m.tick(now)
                    except FixRejected:
                        stats.rejected_fixes += 1
                        continue
                    for msg in msgs:
                        if isinstance(msg, P.Publish):
                            batches[k % len(conns)].append(msg)
                        else:
                            await conns[k % len(conns)].unpublish(msg.entity)
                for c, batch in zip(conns, batches, strict=True):
                    if batch:
                        await c.publish(*batch)
                        window.published += len(batch)
                for v in viewers:
                    for sub in v.move(config.fix_interval):
                        await v.conn.subscribe(sub.added, sub.removed)
                        window.subscribe_msgs += 1
                if now - last_summary >= config.summary_every:
                    _summarise(say, now - start, now - last_summary, window, viewers, movers, server)
                    stats.published += window.published
                    stats.subscribe_msgs += window.subscribe_msgs
                    window = Stats()
                    for v in viewers:
                        stats.deliveries += v.deliveries
                        v.deliveries = 0
                    last_summary = now
                next_tick += config.fix_interval
                with trio.move_on_at(next_tick):
                    await stop.wait()
            stats.published += window.published
            stats.deliveries += sum(v.deliveries for v in viewers)
            say(
                f"stopping after {time.time() - start:.0f} s: {stats.published} updates published, "
                f"{stats.deliveries} deliveries to viewers"
            )
            clients.cancel_scope.cancel()  # clients first, so that none of them sees the server go away
        await server.stop()
        nursery.cancel_scope.cancel()
    return stats


def _summarise(say: Say, elapsed: float, dt: float, window: Stats, viewers: list[Viewer], movers, server) -> None:
    now = time.time()
    street = [len(v.ghosts.positions(now)) for v in viewers if not v.high]
    roof = [len(v.ghosts.positions(now)) for v in viewers if v.high]
    deliveries = sum(v.deliveries for v in viewers)
    subs = [len(v.subs.cells) for v in viewers]
    say(
        f"[{elapsed:5.0f}s] entities {len(movers)} | updates {window.published / dt:6.1f}/s | "
        f"deliveries {deliveries / dt:7.1f}/s | viewers see: street level {_mean(street):5.1f}, "
        f"above roofs {_mean(roof):5.1f} entities (subscribed to {_mean(subs):.0f} of "
        f"{server.sb.config.n_cells} cells)"
    )


def _mean(xs: list[float]) -> float:
    return float(np.mean(xs)) if xs else 0.0


async def _stop_after(stop: trio.Event, seconds: float) -> None:
    await trio.sleep(seconds)
    stop.set()


async def _stop_on_signal(stop: trio.Event) -> None:
    with trio.open_signal_receiver(signal.SIGINT, signal.SIGTERM) as signals:
        async for _ in signals:
            stop.set()
            return


#: entry-point group through which other packages add parts to the demo (`name = "module:function"`)
DEMO_PART_GROUP = "entitynet.demo_parts"


def demo_part(name: str) -> Callable:
    """The demo part `name` that another package registers (transit: proxies' replay producer and SIRI proxy),
    found by entry point so that sims never imports proxies (the layering's arrows run one way)."""
    for ep in entry_points(group=DEMO_PART_GROUP, name=name):
        return ep.load()
    raise LookupError(f"no demo part {name!r} installed (entry-point group {DEMO_PART_GROUP})")
