"""`WorkerSim`: the simulation whose honest clients run in worker processes, the rest as in `Sim`.

Why a `Sim` subclass: every driver (the CLI's shell over real sockets, `run_local`, the benchmark) calls
`start()` / `step()` and gets the messages to send per connection; here those messages come from the workers,
so nothing downstream changes. Each tick the coordinator sends the tick to the workers first, then steps its
own copy of the world (the truth the measure compares viewers with) and moves the viewers while they work, and
only then collects their output: the workers' client work and the coordinator's own work overlap.

A worker that dies (its process ends, or it does not answer a tick within the timeout) is named in the report
with the tick and simulated time, how many entities it carried and where they went: its entities are
UNPUBLISHed (viewers drop their ghosts) and the survivors' fresh client cores publish them again from the next
tick (`restarted`); with no survivor they are `lost` and the run ends.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol

import numpy as np

from entitynet import protocol as P
from sims.engine.schedule import Schedule
from sims.engine.sim import Sim, SimConfig
from sims.workers.coordinator import CoordinatorCore
from sims.workers.run import config_to_wire, run_digests
from sims.workers.split import Assignment

#: the coordinator decodes a worker's whole tick at once: far wider bounds than a client's frame
_LIMITS = P.CodecLimits(max_frame=1 << 30, max_messages=10_000_000)

#: what every report says about the world and the split (docs/simulation.md, "Workers")
SPLIT_NOTE = ("entities split over workers by id (id mod N; a dead worker's entities go to the survivors); every "
              "worker steps the whole world from the seed, so car following, crossings and collisions are never "
              "split over a worker boundary (interactions_missed_across_workers is 0 by construction)")
SAME_NOTE = ("nothing for a run without a worker death: every worker steps the same truth from the seed, and an "
             "entity's GPS noise is a function of (seed, entity id, fix time) only, so the fixes, messages and "
             "report are those of the run in one process whatever N is; a worker's death UNPUBLISHes its "
             "entities and restarts their client cores (see deaths)")


class Link(Protocol):
    """A transport to the run's workers (forked processes over pipes, or NATS): bytes only."""

    def send(self, index: int, data: bytes) -> None:
        """Send a frame to worker `index` (a worker that is gone is reported by `gone`, not raised)."""

    def recv(self, timeout: float) -> list[bytes]:
        """The frames that arrived, waiting up to `timeout` s for the first."""

    def gone(self) -> list[tuple[int, str]]:
        """Workers whose process or connection ended since the last call, with why."""

    def close(self) -> None:
        """Stop everything this link started (no process left behind)."""


class Forwarder:
    """The coordinator's stand-in for `Fleet`: which connection carries each entity (as `Fleet.conn_of`), and
    the client counters summed over the workers; the clients themselves run in the workers."""

    def __init__(self, connections: int, shards: int = 1, shard_at: Callable[[float, float], int] | None = None):
        self.per_shard = connections
        self.connections = connections * shards
        self.shard_at = shard_at
        self.home: dict[int, int] = {}
        self.counters = {"fixes": 0, "rejected_fixes": 0, "published": 0, "unpublished": 0}

    def track(self, a) -> None:
        """A new entity: with shards, the connection to the shard where it starts (as `Fleet.add`)."""
        if self.shard_at is not None:
            x, y = a.xy()
            self.home[a.id] = self.shard_at(float(x), float(y)) * self.per_shard + a.id % self.per_shard

    def conn_of(self, entity: int) -> int:
        """The publisher connection of `entity` (the same rule as `Fleet.conn_of`)."""
        home = self.home.get(entity)
        return entity % self.connections if home is None else home


class WorkerSim(Sim):
    """`Sim` with its honest clients in workers reached through `link` (see the module docstring)."""

    def __init__(self, topo, config: SimConfig, schedule: Schedule | None, link: Link, workers: int, *,
                 transport: str, timeout: float = 10.0, start_timeout: float = 60.0, run_id: str = "run",
                 reply: str = "", shards: int = 1, shard_at: Callable[[float, float], int] | None = None,
                 clock: Callable[[], float] = time.monotonic, say: Callable[[str], None] | None = None):
        super().__init__(topo, config, schedule, shards=shards, shard_at=shard_at)
        self.fleet = Forwarder(config.connections, shards, shard_at)
        self.link, self.transport, self.clock = link, transport, clock
        self.say = say or (lambda _m: None)
        self.core = CoordinatorCore(run_id, workers, config_to_wire(config), run_digests(topo, schedule), timeout,
                                    reply)
        self.assignment = Assignment(workers)
        self.start_timeout = start_timeout
        self.deaths: list[dict] = []
        self.published_ids: set[int] = set()
        self.wait_s: list[float] = []  # per tick: how long the coordinator waited for the workers' output
        self.ended_early: str | None = None

    # ---- the run ------------------------------------------------------------------------------------------
    def join(self) -> None:
        """Assign every worker its share and wait (bounded) until all have built it; RuntimeError naming the
        workers that refused or did not answer. Called by `start` if not before (the CLI calls it before its
        event loop, so that a refusal is one usage error); a second call does nothing."""
        core = self.core
        if core.all_ready():
            return
        for i in range(core.n):
            self.link.send(i, core.assign_frame(i))
        deadline = self.clock() + self.start_timeout
        while not core.all_ready():
            for data in self.link.recv(0.1):
                core.receive(data, self.clock())
            gone = self.link.gone()
            if core.refusals() or gone or self.clock() > deadline:
                missing = [s.index for s in core.slots if not s.ready]
                why = "; ".join(core.refusals() + [f"worker {i}: {w}" for i, w in gone])
                self.close(why or "start failed")
                raise RuntimeError(why or f"worker(s) {missing} did not build their share of the run within "
                                          f"{self.start_timeout:g} s")

    def start(self) -> tuple[list[list[P.Message]], list[list[P.Subscribe]]]:
        """Join the workers, then tick 0 (the first population) as `Sim.start`."""
        self.join()
        self._send_tick()
        for a in self.source.start():
            self._track(a)
        subs = [v.move(0.0) for v in self.viewers]
        return self._collect(), subs

    def step(self) -> tuple[list[list[P.Message]], list[list[P.Subscribe]]]:
        """One tick: the workers step while this process steps its truth and moves the cameras."""
        if self.ended_early is not None:  # every worker is gone: nothing moves (drivers stop on `ended_early`)
            return [[] for _ in range(self.fleet.connections)], [[] for _ in self.viewers]
        self._send_tick()
        new = self.source.step(self.dt)
        self.ticks += 1
        for a in new:
            self._track(a)
        subs = [v.move(self.dt) for v in self.viewers]
        return self._collect(), subs

    def _track(self, a) -> None:
        self.fleet.track(a)
        self.assignment.add(a.id)

    def _send_tick(self) -> None:
        frame = self.core.tick(self.core.k + 1, self.clock())
        for i in self.core.alive:
            self.link.send(i, frame)

    def _collect(self) -> list[list[P.Message]]:
        """Wait for every live worker's output of this tick (declaring dead whoever does not answer in time),
        then route each message to its connection."""
        core, t0 = self.core, self.clock()
        while core.waiting():
            for data in self.link.recv(0.05):
                core.receive(data, self.clock())
            for i, why in self.link.gone():
                core.lost(i, why)
            core.expire(self.clock())
        self.wait_s.append(self.clock() - t0)
        out: list[list[P.Message]] = [[] for _ in range(self.fleet.connections)]
        for i in sorted(core.outs):
            try:
                msgs = P.decode_payload(core.outs[i], _LIMITS) if core.outs[i] else []
            except P.ProtocolError:
                core.bad_frames += 1  # a worker's garbled output: its tick is lost, counted, the run goes on
                continue
            for m in msgs:
                if type(m) is not P.Publish and type(m) is not P.Unpublish:
                    core.bad_frames += 1  # a worker's clients only publish and unpublish
                    continue
                entity = m.entity
                out[self.fleet.conn_of(entity)].append(m)
                if type(m) is P.Publish:
                    self.published_ids.add(entity)
                else:
                    self.published_ids.discard(entity)
        self._sum_counters()
        removed = [aid for aid, _why in self.world.take_removed()]
        for aid in removed:
            if aid in self.published_ids:  # its worker died in this tick before sending the UNPUBLISH: send it
                out[self.fleet.conn_of(aid)].append(P.Unpublish(aid))
                self.published_ids.discard(aid)
            self.fleet.home.pop(aid, None)
        self.assignment.forget(removed)
        for d in core.deaths[len(self.assignment.dead):]:
            self._declare(d, out)
        return out

    def _declare(self, d: int, out: list[list[P.Message]]) -> None:
        """Worker `d` is dead: hand its entities on (the same rule as the workers apply at the next tick) and
        UNPUBLISH the ones it had published, so that viewers do not keep ghosts of stale clients."""
        # a worker declared dead for its silence may still run (slow, cut off): it is told the run is over for it
        self.link.send(d, self.core.stop(f"declared dead: {self.core.slots[d].dead}"))
        moved = self.assignment.kill(d, self.world.agents)
        for e in moved:
            if e in self.published_ids:
                out[self.fleet.conn_of(e)].append(P.Unpublish(e))
                self.published_ids.discard(e)
        s = self.core.slots[d]
        restarted = sum(w is not None for w in moved.values())
        self.deaths.append({"worker": d, "name": s.worker, "host": s.host, "pid": s.pid, "why": s.dead,
                            "tick": self.core.k, "sim_time_s": self.ticks * self.dt, "entities": len(moved),
                            "restarted": restarted, "lost": len(moved) - restarted,
                            "restarted_on": sorted({w for w in moved.values() if w is not None})})
        d_rep = self.deaths[-1]
        where = (f"restarted on worker(s) {', '.join(map(str, d_rep['restarted_on']))}" if restarted
                 else "lost (no worker left)" if d_rep["lost"] else "none to hand on")
        self.say(f"[{d_rep['sim_time_s']:6.0f}s] worker {d} ({s.worker or '?'} on {s.host or '?'}, pid {s.pid}) lost "
                 f"at tick {d_rep['tick']}: {s.dead}; its {len(moved)} entities {where}")
        if not self.core.alive:
            self.ended_early = f"every worker is gone (the last, worker {d}, at tick {self.core.k})"

    def _sum_counters(self) -> None:
        total = dict.fromkeys(self.fleet.counters, 0)
        for s in self.core.slots:
            for k in total:
                total[k] += int(s.counters.get(k, 0))
        self.fleet.counters = total

    def close(self, why: str = "the run ended") -> None:
        """Tell the workers the run is over (each answers with its final counters), then stop the link."""
        frame = self.core.stop(why)
        for i in self.core.alive:
            self.link.send(i, frame)
        deadline = self.clock() + min(2.0, self.core.timeout)
        while any(not self.core.slots[i].bye for i in self.core.alive if self.core.slots[i].ready) \
                and self.clock() < deadline:
            for data in self.link.recv(0.05):
                self.core.receive(data, self.clock())
            for i, gone_why in self.link.gone():
                self.core.lost(i, gone_why)
        self._sum_counters()
        self.link.close()

    # ---- the report -----------------------------------------------------------------------------------------
    def report(self) -> dict:
        """`Sim.report` plus the workers' section: who ran what, how long each step took, every loss."""
        rep = super().report()
        live = self.world.agents
        per = []
        for s in self.core.slots:
            steps = np.array(s.step_s) if s.step_s else np.zeros(1)
            per.append({"worker": s.index, "name": s.worker, "host": s.host, "pid": s.pid,
                        "alive": s.dead is None, "entities": s.owned if s.dead is None else 0,
                        "ticks": len(s.step_s), "step_p50_ms": float(np.percentile(steps, 50) * 1000),
                        "step_p99_ms": float(np.percentile(steps, 99) * 1000), "clients": dict(s.counters)})
        wait = np.array(self.wait_s) if self.wait_s else np.zeros(1)
        rep["workers"] = {
            "n": self.core.n, "transport": self.transport, "split": SPLIT_NOTE, "differs": SAME_NOTE,
            "interactions_missed_across_workers": 0,
            "entities_now": self.assignment.counts(live), "per_worker": per, "deaths": self.deaths,
            "entities_lost": sum(d["lost"] for d in self.deaths),
            "entities_restarted": sum(d["restarted"] for d in self.deaths),
            "coordinator_wait_p50_ms": float(np.percentile(wait, 50) * 1000),
            "coordinator_wait_p99_ms": float(np.percentile(wait, 99) * 1000),
            "bad_frames": self.core.bad_frames, "stray_frames": self.core.stray,
            # frames the transport dropped with its queue full (NATS: `QUEUE_FRAMES`); a tick that lost one timed out
            "frames_dropped": int(getattr(self.link, "dropped", 0)),
            "ended_early": self.ended_early,
        }
        return rep
