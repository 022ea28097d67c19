"""The simulation against an in-process switchboard core: no sockets, deterministic for a seed.

Why: tests and the benchmark's error figures need the real forwarding (the `Switchboard` core with its
subscriptions, expiry and coalescing, and the protocol codec both ways) without the jitter of sockets and
scheduling, so that a run is reproducible and costs only CPU. The shell's part is mimicked as the server does:
frames encoded and decoded, one flush per tick, expiry when the core's deadline passes.
"""

from __future__ import annotations

from collections.abc import Iterator

from entitynet import protocol as P
from entitynet.switchboard import Switchboard, SwitchConfig
from sims.engine.message_cache import MessageCache
from sims.engine.sim import Sim


class LocalSwitch:
    """The switchboard core in this process, fed as the server feeds it: a `Hello` per connection, frames
    encoded and decoded both ways, one flush per tick, so tests and the benchmark see the real forwarding."""

    def __init__(self, sim: Sim):
        self.sim = sim
        topo = sim.topo
        now = sim.now
        self.sb = Switchboard(SwitchConfig(n_cells=int(topo.n_cells), digest=topo.digest, open_mode=True,
                                           seed=sim.config.seed), now)
        self.pubs = [self.sb.connect(now, "sim") for _ in range(sim.config.connections)]
        self.views = [self.sb.connect(now, "viewer") for _ in sim.viewers]
        self.viewer_of = {cid: i for i, cid in enumerate(self.views)}
        #: the viewers' frames decoded as the shell decodes them: one object per distinct message of a flush,
        #: shared by the viewers it reaches (so the ghost table takes it as one version)
        self.messages = MessageCache()
        self.updates_in = 0
        self.bytes_in = 0
        hello = P.Hello(P.PROTOCOL_VERSION, "sim", topo.digest)
        for cid in self.pubs + self.views:
            self._feed(cid, [hello], now)
        self.flush(now)

    def _feed(self, cid: int, msgs: list[P.Message], now: float) -> None:
        if not msgs:
            return
        data = P.encode_frame(msgs)
        self.bytes_in += len(data)
        dec = P.FrameDecoder()
        dec.receive_data(data)
        while (got := dec.next_messages()) is not None:
            self.sb.receive(cid, got, now)

    def exchange(self, pubs: list[list[P.Message]], subs: list[list[P.Subscribe]]) -> None:
        """One tick's traffic: viewers' SUBSCRIBEs first (so this tick's publishes reach them), then the
        publishers' messages, expiry when the core's deadline has passed, and the flush to the viewers."""
        now = self.sim.now
        for cid, msgs in zip(self.views, subs, strict=True):
            self._feed(cid, msgs, now)
        for cid, msgs in zip(self.pubs, pubs, strict=True):
            self.updates_in += sum(isinstance(m, P.Publish) for m in msgs)
            self._feed(cid, msgs, now)
        deadline = self.sb.next_deadline()
        if deadline is not None and deadline <= now:
            self.sb.expire(now)
        self.flush(now)

    def flush(self, now: float) -> None:
        """Drain every dirty outbox and hand each viewer's messages (with their encoded size, for the byte
        counts) to `Sim.deliver`; publishers' outboxes are drained and dropped."""
        self.messages.clear()
        for i, encoded in self.drained():
            msgs = self.messages.decode(P.payload_from_encoded(encoded))
            for enc, m in zip(encoded, msgs, strict=True):
                self.sim.deliver(i, m, len(enc))

    def drained(self) -> Iterator[tuple[int, list[bytes]]]:
        """Drain every dirty outbox, in connection order: (viewer, its encoded messages) for each viewer with
        news; publishers' outboxes are drained and dropped."""
        for cid in sorted(self.sb.take_dirty()):
            ob = self.sb.outbox(cid)
            if ob is None:
                continue
            encoded = ob.drain()
            i = self.viewer_of.get(cid)
            if i is not None and encoded:
                yield i, encoded

    def eid_to_agent(self) -> dict[int, int]:
        """The switchboard's opaque entity id -> the simulation's agent id, so truth can be compared with
        ghosts (only possible because the core runs in this process)."""
        return {eid: e.local for eid, e in self.sb.entities.items()}


def run_local(sim: Sim, seconds: float, progress=None) -> dict:
    """Run `sim` for `seconds` of simulated time against the in-process switchboard; the report."""
    sw = LocalSwitch(sim)
    sw.exchange(*sim.start())
    n = int(round(seconds * sim.config.tick_hz))
    for k in range(n):
        sw.exchange(*sim.step())
        sim.maybe_sample(sw.eid_to_agent())
        if progress is not None:
            progress(k + 1, n)
    rep = sim.report()
    rep["switch"] = {"updates_in": sw.updates_in, "bytes_in": sw.bytes_in,
                     "deliveries": sw.sb.stats["deliveries"], "leaves": sw.sb.stats["leaves"]}
    return rep
