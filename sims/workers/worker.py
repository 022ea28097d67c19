"""The worker's side of the protocol as a sans-IO state machine: frames in, frames out, `now` given.

Why sans-IO: the same core serves a forked local worker (pipes) and a worker on another machine (NATS); the
shells only move bytes and call `receive` and `expire`. A worker is idle (announcing itself), then in one run:
an assign builds its share (`build`: the shell's way to get the map and schedule), each tick steps it, a stop
ends it. A run whose coordinator goes quiet for longer than the assign's `timeout` is given up (`expire`), so a
worker never waits forever for a coordinator that died.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from entitynet import protocol as P
from sims.workers import wire
from sims.workers.run import RefusedRun, WorkerShare

#: an out frame's protocol frame is cut into parts of at most this many bytes (NATS' default max_payload is 1 MiB)
PART_BYTES = 512 << 10

#: a worker gives a run up after the coordinator's timeout of silence, but never sooner than this (s): its
#: transport says "alive" every second (`sims.workers.nats_link`)
SILENCE_MIN_S = 5.0

Build = Callable[[dict, dict, int, int], WorkerShare]


class WorkerCore:
    """One worker: `receive(frame, now)` returns the frames to send back; `expire(now)` gives up a silent run."""

    def __init__(self, worker: str, host: str, pid: int, build: Build, silence_min: float = SILENCE_MIN_S):
        self.worker, self.host, self.pid = worker, host, pid
        self.build = build
        self.silence_min = silence_min  # `sim worker --coordinator-silence`: never give a run up sooner
        self.run: str | None = None
        self.index = -1
        self.share: WorkerShare | None = None
        self.timeout = 10.0
        self.reply = ""  # where the coordinator listens (NATS subject; "" over a pipe)
        self.answer_to = ""  # where the answers to the last frame received go (an assign's own `reply`)
        self.heard = 0.0
        self.runs_done = 0
        self.ended: str | None = None  # why the last run ended (stop's why, "coordinator silent ...")
        self.bad_frames = 0
        self.ignored = 0  # frames of another run, or ticks out of order

    @property
    def idle(self) -> bool:
        """No run under way (a NATS worker then announces itself)."""
        return self.run is None

    def hello(self) -> bytes:
        """The idle worker's announcement."""
        return wire.encode("hello", worker=self.worker, host=self.host, pid=self.pid)

    def receive(self, data: bytes, now: float) -> list[bytes]:
        """Handle one frame from the coordinator; the frames to send back (to `reply`)."""
        try:
            f = wire.decode(data)
        except wire.WireError:
            self.bad_frames += 1
            return []
        kind = f["kind"]
        if kind == "assign":  # answered where that coordinator listens, even a refusal while busy elsewhere
            self.answer_to = f["reply"]
            return self._assign(f, now)
        self.answer_to = self.reply
        if f.get("run") != self.run or self.share is None:
            self.ignored += 1
            return []
        self.heard = now
        if kind == "tick":
            return self._tick(f)
        if kind == "stop":
            return self._end(f["why"])
        if kind == "alive":
            return []
        self.ignored += 1
        return []

    def expire(self, now: float) -> bool:
        """Give the run up when the coordinator has been silent for longer than its timeout (True then)."""
        limit = max(self.timeout, self.silence_min)
        if self.run is not None and now - self.heard > limit:
            self._end(f"the coordinator was silent for over {limit:g} s")
            return True
        return False

    def _assign(self, f: dict[str, Any], now: float) -> list[bytes]:
        if self.run is not None:
            return [wire.encode("refuse", run=f["run"], index=f["index"], why=f"busy in run {self.run}")]
        try:
            share = self.build(f["config"], f["digests"], f["index"], f["n"])
        except RefusedRun as exc:
            return [wire.encode("refuse", run=f["run"], index=f["index"], why=str(exc))]
        except Exception as exc:  # noqa: BLE001 (an assign from the network must not end the worker daemon)
            why = f"cannot build the run: {type(exc).__name__}: {exc}"[:500]
            return [wire.encode("refuse", run=f["run"], index=f["index"], why=why)]
        self.run, self.index, self.share = f["run"], f["index"], share
        self.timeout, self.reply, self.heard = float(f["timeout"]), f["reply"], now
        self.ended = None
        return [wire.encode("ready", run=self.run, index=self.index, worker=self.worker, host=self.host,
                            pid=self.pid)]

    def _tick(self, f: dict[str, Any]) -> list[bytes]:
        share = self.share
        if f["k"] != share.k + 1 or any(w >= share.n for w in f["dead"]):
            self.ignored += 1
            return []
        t0 = time.perf_counter()
        msgs = share.tick(f["k"], list(f["dead"]))
        frame = P.encode_payload(msgs) if msgs else b""
        step_s = time.perf_counter() - t0
        parts = [frame[i:i + PART_BYTES] for i in range(0, len(frame), PART_BYTES)] or [b""]
        counters, owned = share.counters(), share.owned()
        return [wire.encode("out", run=self.run, index=self.index, k=f["k"], part=i, last=i == len(parts) - 1,
                            frame=part, counters=counters, step_s=step_s, owned=owned)
                for i, part in enumerate(parts)]

    def _end(self, why: str) -> list[bytes]:
        out = [wire.encode("bye", run=self.run, index=self.index, counters=self.share.counters())]
        self.run, self.share, self.index = None, None, -1
        self.runs_done += 1
        self.ended = why
        return out
