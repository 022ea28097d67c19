"""The coordinator's side of the protocol as a sans-IO state machine: which workers answered which tick.

Why sans-IO: the waiting rules (every live worker answers each tick; one that does not within `timeout`, or
whose transport says it is gone, is declared dead, named, and the run goes on without it) are the part that
must not hang, and here they are tested with a fake clock. The shell (`sims.workers.sim`) sends the frames this
core makes, feeds it what arrives, and asks `waiting()` / `expire(now)` until the tick is complete.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sims.workers import wire


@dataclass
class Slot:
    """What the coordinator knows of one worker of the run."""

    index: int
    worker: str = ""
    host: str = ""
    pid: int = 0
    ready: bool = False
    refused: str | None = None
    dead: str | None = None  # why it was declared dead
    done_k: int = -1  # the last tick whose output is complete
    parts: list[bytes] = field(default_factory=list)
    counters: dict = field(default_factory=dict)
    owned: int = 0
    step_s: list[float] = field(default_factory=list)
    bye: bool = False


class CoordinatorCore:
    """Run `run` over `n` workers: frames out (`assign_frames`, `tick`, `stop`), frames in (`receive`)."""

    def __init__(self, run: str, n: int, config: dict, digests: dict, timeout: float, reply: str = ""):
        if n < 1:
            raise ValueError(f"at least one worker, got {n}")
        if not timeout > 0:
            raise ValueError(f"the worker timeout must be > 0 s, got {timeout}")
        self.run, self.n = run, n
        self.config, self.digests, self.timeout, self.reply = config, digests, timeout, reply
        self.slots = [Slot(i) for i in range(n)]
        self.k = -1
        self.deadline = 0.0
        self.deaths: list[int] = []  # in the order declared
        self.outs: dict[int, bytes] = {}  # this tick's complete outputs, by worker
        self.bad_frames = 0
        self.stray = 0  # frames of another run, of a dead worker, or of another tick

    def assign_frame(self, index: int) -> bytes:
        """The assign frame for worker `index`."""
        return wire.encode("assign", run=self.run, index=index, n=self.n, config=self.config,
                           digests=self.digests, timeout=self.timeout, reply=self.reply)

    def all_ready(self) -> bool:
        """Every worker has built its share."""
        return all(s.ready for s in self.slots)

    def refusals(self) -> list[str]:
        """Why workers refused the run ("worker i (name): why")."""
        return [f"worker {s.index} ({s.worker or '?'}): {s.refused}" for s in self.slots if s.refused]

    @property
    def alive(self) -> list[int]:
        """Workers not declared dead."""
        return [s.index for s in self.slots if s.dead is None]

    def tick(self, k: int, now: float) -> bytes:
        """Start tick `k`: the frame to send to every live worker (it carries the deaths so far)."""
        if k != self.k + 1:
            raise ValueError(f"tick {k} after tick {self.k}")
        self.k, self.deadline, self.outs = k, now + self.timeout, {}
        return wire.encode("tick", run=self.run, k=k, dead=list(self.deaths))

    def stop(self, why: str) -> bytes:
        """The frame that ends the run for every worker."""
        return wire.encode("stop", run=self.run, why=why)

    def waiting(self) -> list[int]:
        """Live workers whose output for the current tick is not complete yet."""
        return [s.index for s in self.slots if s.dead is None and s.done_k < self.k]

    def receive(self, data: bytes, now: float) -> None:
        """One frame from a worker (malformed and stray frames are counted and dropped)."""
        try:
            f = wire.decode(data)
        except wire.WireError:
            self.bad_frames += 1
            return
        if f["kind"] == "hello":
            return  # an idle worker announcing itself: the transport's business
        if f.get("run") != self.run or not 0 <= f.get("index", -1) < self.n:
            self.stray += 1
            return
        s = self.slots[f["index"]]
        if s.dead is not None:
            self.stray += 1
            return
        kind = f["kind"]
        if kind == "ready":
            s.ready, s.worker, s.host, s.pid = True, f["worker"], f["host"], f["pid"]
        elif kind == "refuse":
            s.refused = f["why"]
        elif kind == "bye":
            s.counters, s.bye = f["counters"], True
        elif kind == "out":
            self._out(s, f)
        else:
            self.stray += 1

    def _out(self, s: Slot, f: dict) -> None:
        if f["k"] != self.k or s.done_k >= self.k or f["part"] != len(s.parts):
            self.stray += 1
            return
        s.parts.append(f["frame"])
        if sum(map(len, s.parts)) > wire.MAX_FRAME:  # parts without end: bounded like one frame, then dropped
            s.parts = []
            self.bad_frames += 1
            return
        if f["last"]:
            self.outs[s.index] = b"".join(s.parts)
            s.parts = []
            s.done_k = self.k
            s.counters, s.owned = f["counters"], f["owned"]
            s.step_s.append(float(f["step_s"]))

    def lost(self, index: int, why: str) -> bool:
        """The transport says worker `index` is gone; True when this declares it dead (it was alive)."""
        s = self.slots[index]
        if s.dead is not None:
            return False
        s.dead, s.parts = why, []
        self.deaths.append(index)
        return True

    def expire(self, now: float) -> list[int]:
        """Declare dead the live workers that have not answered the current tick by its deadline."""
        if now < self.deadline:
            return []
        late = self.waiting()
        for i in late:
            self.lost(i, f"no answer to tick {self.k} within {self.timeout:g} s")
        return late
