"""The trio shell of `entitynet sim`: real sockets, real time (or faster), pause and resume, a live summary.

It only moves bytes and keeps time: the simulation is the sans-IO `sims.engine.sim.Sim`. Each tick of
`1 / tick_hz` simulated seconds is due `1 / (tick_hz * speed)` wall seconds after the previous one; the shell
records how late each tick starts (tick lateness) and how many ticks it ran behind. Publishers and viewers
are `entitynet.connection.Connection`s: when the server goes away they reconnect through the client session
while the simulation keeps stepping, and the shell reports the gap (seconds with a connection down).
Pause: SIGUSR1, or `p` + Enter on a terminal; the simulated clock stops while paused.

The in-process server runs on the simulation's clock (`clock()`: the last tick's time, advanced with the wall
clock times the speed until the next tick): the honest clients stamp their models with that clock, and the
browser viewer (served with `http_port`, the way `entitynet demo` serves it) takes its clock offset from the
server's WELCOME and PONG, so its ghosts move in the publishers' time. Other parts of a run (the demo's transit
proxy) are started with the server's address through `parts`; `task_status.started(server)` once all connected.
"""

from __future__ import annotations

import gc
import math
import signal
import sys
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trio

from entitynet import protocol as P
from entitynet.connection import Connection
from sims.engine.collector import settle_after_start, unsettle
from sims.engine.payload_ids import PayloadIds
from sims.engine.sim import Sim
from sims.engine.viewer_fleet import ViewerFleet

Say = Callable[[str], None]


@dataclass
class ShellConfig:
    """How the shell runs a simulation: duration and speed, where the server is (or one in this process),
    summary interval and the warm-up ticks left out of the lateness figures."""

    duration: float | None = None  # simulated seconds; None = until Ctrl-C
    speed: float = 1.0
    summary_every: float = 5.0  # wall seconds
    server: tuple[str, int] | None = None  # None = start one in this process
    token: str = ""
    artifact: Path | None = None
    host: str = "127.0.0.1"  # of the in-process server
    port: int = 0  # of the in-process server (0: any free port)
    keys: bool = True  # read `p` from a terminal
    warmup_ticks: int = 0  # ticks left out of the lateness figures (the start's burst of first publishes)
    cluster: Any = None  # a sims.cluster_run.ClusterRun: connect to its shards by where entities and cameras are
    http_port: int | None = None  # the in-process server also serves the browser viewer here (0: any free port)
    #: started with the server's address once the clients are connected (`await nursery.start(part, address)`)
    parts: tuple[Callable[..., Awaitable[object]], ...] = ()
    behind_warn_every: float = 30.0  # wall seconds between two warnings that the run is behind real time
    #: a sims.viewers.procs.ViewerProcesses: the viewers live there (the sim then holds none), with their own
    #: connections to the server and their own measure, gathered into the report at the end
    viewer_processes: Any = None
    #: after the start, freeze what it built and raise the collector's first generation
    #: (sims.engine.collector: 0.85x of a tick's CPU in the bench's cost split); only a process's owner sets it
    settle_gc: bool = False


class Shell:
    """The trio shell around a `Sim`: keeps the tick schedule, moves its messages over real connections, and
    measures tick lateness and server outages (see the module docstring)."""

    def __init__(self, sim: Sim, config: ShellConfig, say: Say = print):
        if not config.speed > 0 or not math.isfinite(config.speed):
            raise ValueError(f"speed must be a positive number, got {config.speed}")
        if config.http_port is not None and config.server is not None:
            raise ValueError("the browser viewer is served by the in-process server: an external server serves "
                             "its own (entitynet serve --ws-port P --http-port Q)")
        if config.viewer_processes is not None and (sim.viewers or config.cluster is not None):
            raise ValueError("with viewer processes the simulation holds no viewers of its own, and a cluster's "
                             "viewers follow their cameras between shards, which viewer processes do not")
        self.sim = sim
        self.config = config
        self.say = say
        self.paused = False
        self.lateness: list[float] = []
        self.behind = 0
        self._win_late: list[float] = []  # this summary window's tick lateness (s) and ticks behind
        self._win_behind = 0
        self._warned_at = -math.inf  # wall time of the last "behind real time" warning
        self.gap_s = 0.0
        self.outages = 0
        self.server = None
        self.subscribe_msgs = 0
        self._cameras: dict[int, tuple[float, float]] = {}  # viewer -> where its camera was last sent
        self._window = {"published": 0, "deliveries": 0, "t": 0.0}
        self.published = 0
        self.publishers: list[Connection] = []
        self._part_states: list[Any] = []  # what each part's task_status.started gave (see `counts`)
        self._tick_wall: float | None = None  # monotonic time of the last tick (the clock runs on from it)
        self._frozen = sim.now  # the clock while paused
        self.ids = PayloadIds()  # an external server's entity ids -> ours (truth against viewers)
        #: the viewers' connections: frames into the shared ghost table whole, one frame decoder for all
        self.viewer_fleet = ViewerFleet(sim.viewers, lambda: self.sim.now, self._learn)
        self.server_info: dict = {}  # more about where the server ran (a child process: its pid), for the report
        self._deaths_said = 0  # viewer processes' deaths already said on the live output

    def clock(self) -> float:
        """The simulation's time now, between ticks too (the in-process server's clock, see the module
        docstring): the last tick's time plus the wall time since, times the speed, at most one tick on. Wall
        time from `time.monotonic`, not trio's clock: parts call it from worker threads too (the proxy's polls)."""
        sim = self.sim
        if self.paused:
            return self._frozen
        if self._tick_wall is None:
            return sim.now
        return sim.now + min(max(time.monotonic() - self._tick_wall, 0.0) * self.config.speed, sim.dt)

    # ---- the run ---------------------------------------------------------------------------------------------
    async def run(self, task_status=trio.TASK_STATUS_IGNORED) -> dict:
        """Start the in-process server when none is given, connect the publishers and viewers, start the parts,
        run the tick loop until the duration or a signal, and return the report. `task_status.started(server)`
        (None for an external one) once everything is connected."""
        cfg = self.config
        async with trio.open_nursery() as nursery:
            address = cfg.server
            if address is None and cfg.cluster is None:
                from entitynet.server.app import serve
                from entitynet.server.config import ServerConfig

                self.server = await nursery.start(serve, ServerConfig(
                    host=cfg.host, port=cfg.port, topology=str(cfg.artifact), open_mode=True, clock=self.clock,
                    ws_port=None if cfg.http_port is None else 0, http_port=cfg.http_port))
                address = (cfg.host, self.server.port)
                self.say(f"shard server listening on {cfg.host}:{self.server.port} (in this process, open mode)")
                if self.server.http_port is not None:
                    from entitynet.viewer.routes import BUILD_HINT, BUNDLE, STATIC

                    self.say(f"open the 3D viewer: http://{cfg.host}:{self.server.http_port}/")
                    if not (STATIC / BUNDLE).exists():
                        self.say(BUILD_HINT)
            digest = self.sim.topo.digest
            async with trio.open_nursery() as clients:
                if cfg.cluster is not None:
                    pubs, views = self._cluster_connections(cfg.cluster, digest)
                else:
                    pubs = [Connection(address, digest, cfg.token, on_message=lambda m: None)
                            for _ in range(self.sim.config.connections)]
                    views = [self.viewer_fleet.connection(i, address, digest, cfg.token)
                             for i in range(len(self.sim.viewers))]
                self.publishers = pubs
                for c in pubs + views:
                    await clients.start(c.run)
                if cfg.viewer_processes is not None:
                    await cfg.viewer_processes.connect(address, cfg.token)
                    self._say_viewer_deaths()
                for part in cfg.parts:
                    self._part_states.append(await clients.start(part, address))
                task_status.started(self.server)
                stop = trio.Event()
                clients.start_soon(self._signals, stop)
                if cfg.keys and sys.stdin is not None and sys.stdin.isatty():
                    clients.start_soon(self._keys)
                await self._loop(pubs, views, stop)
                if cfg.viewer_processes is not None:
                    await cfg.viewer_processes.finish()
                    self._say_viewer_deaths()
                self.say(self.final_line())
                clients.cancel_scope.cancel()  # clients first, so that none of them sees the server go away
            if self.server is not None:
                await self.server.stop()
            nursery.cancel_scope.cancel()
        return self.report()

    def _cluster_connections(self, cl: Any, digest: str) -> tuple[list[Connection], list[Connection]]:
        """Publishers: the fleet's connections to each shard (an entity rides one to the shard it started in);
        viewers: to the shard whose region holds the camera. Every connection knows every shard (failover)."""
        fleet, cfg, alts = self.sim.fleet, self.config, tuple(cl.addresses)
        pubs = [Connection(cl.addresses[j // fleet.per_shard], digest, cfg.token, on_message=lambda m: None,
                           alternates=alts) for j in range(fleet.connections)]
        views = [self.viewer_fleet.connection(i, cl.address_at(*v.traj.position()), digest, cfg.token,
                                              alternates=alts) for i, v in enumerate(self.sim.viewers)]
        return pubs, views

    def _learn(self, m: P.Update) -> None:
        """An UPDATE arrived: map an external server's entity id back to ours from its payload."""
        if m.entity not in self.ids.local_of:
            self.ids.learn(m.entity, m.payload)

    async def _loop(self, pubs: list[Connection], views: list[Connection], stop: trio.Event) -> None:
        sim, cfg = self.sim, self.config
        vp = cfg.viewer_processes
        first = sim.start()
        if vp is not None:
            await vp.tick(0, first[0])
        await self._send(pubs, views, *first)
        gc_before = gc.get_threshold()
        if cfg.settle_gc:
            settle_after_start()
        try:
            await self._ticks(pubs, views, stop)
        finally:
            if cfg.settle_gc:
                unsettle(gc_before)

    async def _ticks(self, pubs: list[Connection], views: list[Connection], stop: trio.Event) -> None:
        sim, cfg = self.sim, self.config
        period = sim.dt / cfg.speed
        vp = cfg.viewer_processes
        self._tick_wall = time.monotonic()
        wall0 = last_summary = trio.current_time()
        due = wall0 + period
        while not stop.is_set():
            if getattr(sim, "ended_early", None):  # sims.workers: every worker is gone, the report says so
                self.say(f"[{sim.ticks * sim.dt:6.0f}s] stopping: {sim.ended_early}")
                break
            with trio.move_on_at(due):
                await stop.wait()
            if stop.is_set():
                break
            t = trio.current_time()
            if self.paused:
                due = t + period
                continue
            if cfg.duration is not None and sim.ticks * sim.dt >= cfg.duration - 1e-9:
                self.sample_before_step(pubs)  # the last tick's sample, its deliveries arrived as every other's
                break
            late = t - due
            if sim.ticks >= cfg.warmup_ticks:
                self.lateness.append(late)
                self._win_late.append(late)
                if late > period:
                    self.behind += 1
                    self._win_behind += 1
                    if t - self._warned_at >= cfg.behind_warn_every:
                        self._warned_at = t
                        self.say(self.behind_warning(late))
            down = sum(1 for c in pubs + views if not c.session.connected)
            if down:
                self.gap_s += sim.dt
                if not getattr(self, "_was_down", False):
                    self.outages += 1
                    self.say(f"[{sim.ticks * sim.dt:6.0f}s] server unreachable: {down} connection(s) down, "
                             "stepping on and reconnecting")
            self._was_down = bool(down)
            self.viewer_fleet.clear()
            # the truth measure samples here, before the world steps: the truth is still the last tick's and the
            # deliveries of that tick's messages have had the tick's wait to arrive (`sample_before_step`)
            self.sample_before_step(pubs)
            out = sim.step()
            self._tick_wall = time.monotonic()
            if vp is not None:  # before the publishes: a viewer process learns a payload before its UPDATEs
                await vp.tick(sim.ticks, out[0])
                self._say_viewer_deaths()
            await self._send(pubs, views, *out)
            due += period
            if t - due > 10 * period:  # hopelessly behind: do not try to catch up in a burst
                due = t + period
            if t - last_summary >= cfg.summary_every:
                self.say(self.summary_line(t - last_summary))
                last_summary = t

    def sample_before_step(self, pubs: list[Connection]) -> bool:
        """Sample truth against viewers when due, at the start of a tick before the world steps. Why here and not
        right after the tick's sends: a server in another process (the child, `--server`, a cluster) has not
        delivered the tick's updates by then, so a newly visible entity's first UPDATE counted as missed (missed
        visibility 0.6-0.95 % with a child against 0.1-0.3 % in-process, docs/simulation.md). Before the next
        step the world still holds the sampled tick's truth, the viewers the subscriptions sent with it, and the
        deliveries have had the wait for the tick's due time (the tick period in real time) to arrive."""
        return self.sim.maybe_sample(self._eid_map(pubs))

    async def _send(self, pubs, views, out_pubs, out_subs) -> None:
        for c, msgs in zip(pubs, out_pubs, strict=True):
            ps = [m for m in msgs if isinstance(m, P.Publish)]
            if ps and self.server is None:
                self.ids.published(ps)
            if ps:
                await c.publish(*ps)
                self._window["published"] += len(ps)
                self.published += len(ps)
            for m in msgs:
                if isinstance(m, P.Unpublish):
                    self.ids.forget(m.entity)
                    await c.unpublish(m.entity)
        for i, (c, msgs) in enumerate(zip(views, out_subs, strict=True)):
            if self.config.cluster is not None:  # shards hand viewers on by their camera (CAMERA)
                v = self.sim.viewers[i]
                x, y = v.traj.position()
                last = self._cameras.get(i)
                if last is None or math.hypot(x - last[0], y - last[1]) >= 5.0:
                    self._cameras[i] = (x, y)
                    await c.camera(float(x), float(y), v.z)
            for m in msgs:
                await c.subscribe(m.added, m.removed)
                self.subscribe_msgs += 1

    def _say_viewer_deaths(self) -> None:
        """Name each viewer process declared dead since the last call, once, on the live output."""
        vp = self.config.viewer_processes
        for d in vp.deaths[self._deaths_said:]:
            self.say(f"[{self.sim.ticks * self.sim.dt:6.0f}s] viewer process {d['index']} (pid {d['pid']}) is "
                     f"gone: {d['why']}; its {d['viewers']} viewers are not measured, the run goes on")
        self._deaths_said = len(vp.deaths)

    def _eid_map(self, pubs: list[Connection]) -> dict[int, int] | None:
        """Server entity id -> simulated entity, for the entities our publishers own (the demo's transit proxy
        publishes others into the same server, with local ids of its own). An external server's ids (a child
        process, `--server`, a cluster) are learnt from the payloads (`PayloadIds`)."""
        if self.server is None:
            return self.ids.local_of
        ours = {c.welcome.session for c in pubs if c.welcome is not None}
        return {eid: e.local for eid, e in self.server.sb.entities.items() if e.owner.session in ours}

    async def _signals(self, stop: trio.Event) -> None:
        with trio.open_signal_receiver(signal.SIGINT, signal.SIGTERM, signal.SIGUSR1) as signals:
            async for sig in signals:
                if sig == signal.SIGUSR1:
                    self._toggle()
                else:
                    stop.set()
                    return

    async def _keys(self) -> None:
        while True:
            line = await trio.to_thread.run_sync(sys.stdin.readline, abandon_on_cancel=True)
            if not line:
                return
            if line.strip().lower() == "p":
                self._toggle()

    def _toggle(self) -> None:
        at = self.clock()  # the clock stands still while paused, and runs on from there (never backwards)
        self.paused = not self.paused
        self._frozen = at
        if self._tick_wall is not None:
            self._tick_wall = time.monotonic() - (at - self.sim.now) / self.config.speed
        line = f"[{self.sim.ticks * self.sim.dt:6.0f}s] {'paused' if self.paused else 'resumed'}"
        if self.paused and (self.config.server is not None or self.config.cluster is not None):
            # a server in another process (the child of a large run, --server, a cluster) keeps the wall clock
            # and expires validity periods while the simulation stands still; after a long pause an entity is
            # missing from the viewers until its client publishes again (the measure counts it as missed)
            line += (": the server in its own process keeps the wall clock, so entities expire there while "
                     "paused and reappear as they publish again (--server-process no pauses the server too)")
        self.say(line)

    # ---- output ----------------------------------------------------------------------------------------------
    def part_counts(self) -> list[dict]:
        """The counts of the parts whose started value has a `counts()` (the demo's transit proxy: its trams and
        buses by mode and the stops they served). Why: the parts publish into the same server as the simulation,
        so the viewers see their entities; a summary of only the simulation's truth showed no tram or bus."""
        out = []
        for state in self._part_states:
            counts = getattr(state, "counts", None)
            pc = counts() if callable(counts) else None
            # a part of another kind may have a counts() of another shape: only {"entities": {kind: n}, ...}
            if isinstance(pc, dict) and isinstance(pc.get("entities", {}), dict):
                out.append(pc)
        return out

    def counts(self) -> dict:
        """The simulation's counts with the parts' entities and stops served added in."""
        c = self.sim.counts()
        entities = dict(c["entities"])
        for pc in self.part_counts():
            for kind, n in pc.get("entities", {}).items():
                entities[kind] = entities.get(kind, 0) + int(n)
            c["stops_served"] += int(pc.get("stops_served", 0))
        c["entities"] = dict(sorted(entities.items()))
        return c

    def behind_warning(self, late: float) -> str:
        """The warning that the run does not keep real time, and what to do about it (said once, then every
        `behind_warn_every` wall seconds while it lasts)."""
        sim = self.sim
        return (f"[{sim.ticks * sim.dt:6.0f}s] warning: behind real time (this tick {1000 * late:.0f} ms late, "
                f"{self.behind} ticks behind so far): the figures still hold for simulated time, but the load "
                "is not what the options asked for; try fewer viewers (--viewers) or fewer of them measured "
                "(--measured-viewers), fewer entities, a smaller --measure-share or a slower --speed")

    def _lateness_text(self) -> str:
        """This window's tick lateness for the summary line (and the window restarts)."""
        late, behind = self._win_late, self._win_behind
        self._win_late, self._win_behind = [], 0
        if not late:
            return "late n/a"
        text = f"late p99 {1000 * float(np.percentile(late, 99)):.0f} ms"
        return text + (f", {behind} of {len(late)} ticks behind" if behind else "")

    def summary_line(self, wall_dt: float) -> str:
        """The live one-line summary: rates over the last `wall_dt` wall seconds (the window restarts here),
        collisions, viewer error and a progress bar when running faster than real time."""
        sim = self.sim
        c = self.counts()
        deliveries = sum(v.deliveries for v in sim.viewers)
        d_del = deliveries - self._window["deliveries"]
        d_pub = self._window["published"]
        self._window = {"published": 0, "deliveries": deliveries, "t": 0.0}
        ents = ", ".join(f"{n} {k}" for k, n in c["entities"].items())
        tv = sim.measure.summary()["all"]
        err = f"{tv['error_p95_m']:.1f} m p95" if tv["error_p95_m"] is not None else "n/a"
        col = c["collisions"]
        vp = self.config.viewer_processes  # its viewers' figures come at the end: none on the live line
        line = (f"[{sim.ticks * sim.dt:6.0f}s] entities {sum(c['entities'].values())} ({ents}) | "
                f"updates {d_pub / wall_dt:6.1f}/s | "
                + ("" if vp is not None else f"deliveries {d_del / wall_dt:7.1f}/s | ")
                + f"collisions avoided {col['avoided']} accepted {col['accepted']} deleted {col['deleted']}"
                + ("" if vp is not None else
                   f" | viewer error {err}, missed {100 * tv['missed_visibility']:.1f}%")
                + f" | {self._lateness_text()}")
        if self.config.cluster is not None:
            line += " | " + self.config.cluster.summary()
        if vp is not None:
            line += f" | viewers in {len(vp.live())} of {vp.n} processes (their figures at the end)"
        if self.config.duration and self.config.speed > 1.0:
            frac = min(1.0, sim.ticks * sim.dt / self.config.duration)
            line += f" [{'#' * int(20 * frac):<20}] {100 * frac:3.0f}%"
        return line

    def final_line(self) -> str:
        """What the run did, in one line (before the JSON report)."""
        sim = self.sim
        return (f"[{sim.ticks * sim.dt:6.0f}s] stopped after {sim.ticks * sim.dt:.0f} simulated s: "
                f"{self.published} updates published, {self._deliveries()} deliveries to "
                f"viewers, {self.counts()['stops_served']} bus and tram stops served")

    def _deliveries(self) -> int:
        """UPDATEs delivered to the viewers so far: this process's, or at the end those the viewer processes
        reported."""
        vp = self.config.viewer_processes
        if vp is not None:
            return vp.deliveries()
        return sum(v.deliveries for v in self.sim.viewers)

    def report(self) -> dict:
        """The simulation's report plus the shell's own figures: tick lateness, ticks behind, server gaps and
        where the server ran."""
        rep = self.sim.report()
        if self.config.viewer_processes is not None:
            rep = self.config.viewer_processes.merge(rep)
        parts = self.part_counts()
        if parts:  # every entity the viewers saw, the parts' too; each part's own figures beside
            c = self.counts()
            rep["entities"], rep["stops_served"], rep["parts"] = c["entities"], c["stops_served"], parts
        lat = np.array(self.lateness) if self.lateness else np.zeros(1)
        rep["realtime"] = {
            "speed": self.config.speed, "ticks": self.sim.ticks,
            "tick_lateness_p50_ms": float(np.percentile(lat, 50) * 1000),
            "tick_lateness_p99_ms": float(np.percentile(lat, 99) * 1000),
            "ticks_behind": self.behind,
        }
        rep["server"] = {"in_process": self.server is not None, **self.server_info, "gap_s": self.gap_s,
                         "outages": self.outages}
        rep["viewer_errors"] = self.viewer_fleet.error_report()  # per viewer: attempts ended by an error
        if self.config.cluster is not None:
            cl = self.config.cluster
            rep["cluster"] = {"shards": cl.per_shard(), "nats": cl.nats_urls,
                              "viewer_redirects": self.viewer_fleet.redirects}
        if self.server is None and isinstance(rep.get("truth_vs_viewer"), dict):
            rep["truth_vs_viewer"]["ids"] = ("an external server's entity ids, mapped to the simulation's by the "
                                             "payload each entity last published")
        return rep
