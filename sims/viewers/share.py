"""A viewer process's share of a run, sans-IO: its viewers, the run's truth stepped from the seed, their measure.

Why its own truth: the measure compares each viewer's ghosts with where the entities truly are, and sending the
truth (every entity's position and cells, every sample) from the coordinator would cost it what the process is
meant to take off it; the world is deterministic for a seed, so the process steps its own copy, as every worker
does (`sims.workers.run`). Its viewers are the run's viewers with the same indices, cameras and walks as in one
process (the whole list is built from the same generator, then cut to the share), so only where they are
measured changes. Ghost ids are the server's: the payloads the coordinator's publishers sent (in each tick
frame) name them (`sims.engine.payload_ids`).
"""

from __future__ import annotations

import time
from collections import namedtuple
from collections.abc import Iterable

import numpy as np

from entitynet import protocol as P
from sims.engine.payload_ids import PayloadIds
from sims.engine.schedule import Schedule
from sims.engine.sim import Sim, SimConfig
from sims.engine.viewers import viewer_counts

Sent = namedtuple("Sent", "entity payload")  # what `PayloadIds.published` reads of a PUBLISH
UNKNOWN_TICKS = 20  # how long an UPDATE whose payload is not known yet waits for its tick frame


def share_of(viewers: int, processes: int, index: int) -> list[int]:
    """The viewer indices process `index` of `processes` holds: every `processes`-th, so street and roof
    viewers (the first `roof_share` of the list are roof viewers) spread evenly."""
    if not 0 <= index < processes:
        raise ValueError(f"viewer process {index} of {processes}")
    return list(range(index, viewers, processes))


class ViewerShare:
    """Viewers `indices` of the run `config` and the run's truth (see the module docstring)."""

    def __init__(self, topo, schedule: Schedule | None, config: SimConfig, indices: Iterable[int]):
        self.sim = Sim(topo, config, schedule if config.transit else None)
        keep = set(indices)
        self.viewers = self.sim.viewers = [v for v in self.sim.viewers if v.index in keep]
        self.ids = PayloadIds()
        #: UPDATEs whose payload was not known yet (server id -> (payload, tick)): the tick frame naming it and
        #: the server's UPDATE race to this process (and a process behind real time reads its frames late), so
        #: these are tried again at each tick frame, for up to `UNKNOWN_TICKS` ticks (bounded: one per id)
        self._unknown: dict[int, tuple[bytes, int]] = {}
        self.k = -1
        self._first: list[list[P.Subscribe]] | None = None  # the first subscriptions, from `prepare`
        self._prepared = False
        self.subscribe_msgs = 0
        self.delays: list[float] = []  # seconds from the coordinator's send of each tick to its use here

    @property
    def now(self) -> float:
        """The truth's clock (service-day seconds), the viewers' receiver time."""
        return self.sim.now

    def tick(self, k: int, published: list, unpublished: list, delay: float = 0.0) -> list[list[P.Subscribe]]:
        """Tick `k` (0: the start): sample the viewers when due (before the truth moves: the deliveries of
        tick k - 1's messages have had the tick's wait to arrive, as in one process), learn the payloads the
        coordinator's publishers send in this tick, step the truth and move the cameras; the SUBSCRIBE
        differences each viewer sends. `delay`: seconds between the coordinator's send and this call (kept
        for the report: a process behind real time measures its viewers less well)."""
        if k != self.k + 1:
            raise ValueError(f"tick {k} after tick {self.k}: ticks come in order")
        sim = self.sim
        self.delays.append(delay)
        if k > 0:
            sim.maybe_sample(self.ids.local_of)
        self.ids.published(Sent(int(e), bytes(p)) for e, p in published)
        if self._unknown:
            local_of = self.ids.local_of
            for eid, (payload, since) in list(self._unknown.items()):
                self.ids.learn(eid, payload)
                if eid in local_of or k - since > UNKNOWN_TICKS:
                    del self._unknown[eid]
        for e in unpublished:
            self.ids.forget(int(e))
        if k == 0:
            self.prepare()
            subs, self._first = self._first or [], None
            self.subscribe_msgs += sum(len(x) for x in subs)
            self.k = 0
            return subs
        else:
            sim.source.step(sim.dt)
            sim.ticks += 1
            dt = sim.dt
        sim.world.take_removed()  # no fleet here takes them: the queue would only grow
        subs = [v.move(dt) for v in self.viewers]
        self.subscribe_msgs += sum(len(s) for s in subs)
        self.k = k
        return subs

    def prepare(self) -> None:
        """The start's work ahead of the first tick: the first population and the cameras' first
        subscriptions (deterministic from the seed, so they need nothing from the coordinator). Why ahead: it
        is most of a second of CPU at 1,000 entities and 100 viewers, and done at tick 0 it left the process
        that long behind the run for its first ticks (joins not yet received, counted as missed)."""
        if not self._prepared:
            self._prepared = True
            self.sim.source.start()
            self.sim.world.take_removed()
            self._first = [v.move(0.0) for v in self.viewers]

    def finish(self) -> None:
        """The last sample, at the end of the run (as the shell takes it before it stops)."""
        self.sim.maybe_sample(self.ids.local_of)

    def learn(self, m: P.Update) -> None:
        """An UPDATE arrived: map its server id if its payload is one of ours (or once its tick frame is in)."""
        ids = self.ids
        if m.entity not in ids.local_of:
            ids.learn(m.entity, m.payload)
            if m.entity not in ids.local_of:
                self._unknown[m.entity] = (m.payload, self.k)

    def report(self) -> dict:
        """What the coordinator merges: the raw tallies per viewer group and the viewers' counters."""
        v = self.viewers
        tallies = {g: {"errors": list(t.errors), "visible": t.visible, "missed": t.missed, "shown": t.shown,
                       "stale": t.stale, "viewer_samples": t.viewer_samples}
                   for g, t in self.sim.measure.tallies.items()}
        return {"tallies": tallies, "subscribe_msgs": self.subscribe_msgs, "ticks": self.sim.ticks,
                "cpu_s": float(time.process_time()),
                "tick_delay_p99_ms": float(np.percentile(self.delays, 99) * 1000) if self.delays else 0.0,
                "viewers": viewer_counts(v)}
