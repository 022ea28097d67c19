"""Workers on other machines, joined over NATS: the coordinator's transport and the worker's shell.

Why NATS: the cluster already runs on it (entitynet.cluster, our trio client `NatsClient`), so a run across
machines needs no second message engine, and a worker needs only the NATS URL. Subjects:
- `entitynet.sim.hello`: an idle worker announces itself every second (worker id, host, pid);
- `entitynet.sim.worker.<id>`: what the coordinator sends one worker (assign, tick, stop);
- `entitynet.sim.run.<run>.up`: what the run's workers send the coordinator (ready, refuse, out, bye).

The coordinator's side (`NatsWorkers`) runs the trio client in a thread of its own and offers the blocking
`Link` of `WorkerSim` (`send`, `recv(timeout)`), so the same `WorkerSim` serves the CLI's trio shell and the
synchronous drivers; the queue between them is bounded (frames beyond it are dropped and counted: the tick
then times out and names the worker, never a silent gap). A worker that dies is seen when it misses a tick's
deadline (`--worker-timeout`); a coordinator that dies, when the worker hears nothing for the same time.
"""

from __future__ import annotations

import os
import queue
import secrets
import socket
import threading
import time
from collections.abc import Callable

import trio

from entitynet.cluster.nats_client import NatsClient, parse_servers
from sims.engine.collector import settle_after_start
from sims.workers import wire
from sims.workers.worker import SILENCE_MIN_S, WorkerCore

HELLO = "entitynet.sim.hello"
#: frames waiting for the coordinator's thread, at most (a tick's output is one frame per worker, or a few parts)
QUEUE_FRAMES = 1024
#: how often the coordinator tells its workers it is alive (s)
BEAT_S = 1.0


def worker_subject(worker: str) -> str:
    """Where the coordinator reaches one worker."""
    return f"entitynet.sim.worker.{worker}"


def up_subject(run: str) -> str:
    """Where a run's workers answer the coordinator."""
    return f"entitynet.sim.run.{run}.up"


def leaf_text(exc: BaseException) -> str:
    """What went wrong, in words: the first leaf of an exception group (trio's nurseries wrap errors; walked by
    the CLI's one walker, `entitynet.cli.leaves`), by its text or else its type's name ("TooSlowError" for a
    first flush that got no answer; a first connect that got none says so in its own text)."""
    from entitynet.cli import leaves

    exc = next(leaves(exc), exc)
    text = str(exc)
    return text if text else {"TooSlowError": "no answer within the connect timeout"}.get(type(exc).__name__,
                                                                                          type(exc).__name__)


def only(group: BaseException, types: tuple[type[BaseException], ...]) -> BaseException | None:
    """The first leaf of `group` when every leaf is one of `types` (else None): an error to report in one line."""
    from entitynet.cli import leaves

    found = list(leaves(group))
    return found[0] if found and all(isinstance(e, types) for e in found) else None


class NatsWorkers:
    """The coordinator's NATS transport: connect (a clear error naming the URL when it cannot), `choose` the
    workers that announced themselves, then the `Link` calls for `WorkerSim`."""

    def __init__(self, url: str, token: str | None = None, connect_timeout: float = 1.0,
                 say: Callable[[str], None] | None = None):
        self.servers = parse_servers(url)  # ValueError on a bad URL, before any thread starts
        self.url = url
        self.say = say or (lambda _m: None)
        self.run = secrets.token_hex(6)
        self.reply = up_subject(self.run)
        self.inq: queue.Queue[bytes] = queue.Queue(QUEUE_FRAMES)
        self.dropped = 0
        self.hellos: dict[str, tuple[str, int]] = {}
        self.workers: list[str] = []
        self._token: trio.lowlevel.TrioToken | None = None
        self._closing: trio.Event | None = None
        self._nc: NatsClient | None = None
        self._error: BaseException | None = None
        self._up = threading.Event()
        self._thread = threading.Thread(target=trio.run, args=(self._main, token, connect_timeout),
                                        name="entitynet-sim-nats", daemon=True)
        self._thread.start()
        if not self._up.wait(connect_timeout * max(2, len(self.servers)) + 5.0) or self._error is not None:
            why = leaf_text(self._error) if self._error is not None else "no answer"
            self.close()
            raise RuntimeError(f"cannot reach NATS at {url}: {why}")

    async def _main(self, token: str | None, connect_timeout: float) -> None:
        try:
            async with NatsClient(self.url, name="entitynet-sim-coordinator", token=token,
                                  connect_timeout=connect_timeout, on_disconnect=self._lost,
                                  on_reconnect=self._back) as nc:
                self._nc, self._token, self._closing = nc, trio.lowlevel.current_trio_token(), trio.Event()
                nc.subscribe(HELLO, self._on_hello)
                nc.subscribe(self.reply, self._on_up)
                await nc.flush()
                self._up.set()
                async with trio.open_nursery() as beats:
                    beats.start_soon(self._beat, nc)
                    await self._closing.wait()
                    beats.cancel_scope.cancel()
                with trio.move_on_after(1.0):  # what is queued (the stop frames) reaches the server first
                    try:
                        await nc.flush(1.0)
                    except (trio.TooSlowError, trio.BrokenResourceError):
                        pass
        except BaseException as exc:  # noqa: BLE001 (reported to the caller's thread, which raises it)
            self._error = exc
            self._up.set()

    def _lost(self, why: str) -> None:
        """Said at once: otherwise the only sign is every worker declared dead for a tick it did not answer."""
        self.say(f"lost NATS at {self.url} ({why}); reconnecting (workers that miss a tick meanwhile are "
                 "declared dead)")

    def _back(self) -> None:
        self.say(f"NATS at {self.url} is back")

    async def _beat(self, nc: NatsClient) -> None:
        """Tell the chosen workers every second that the coordinator is alive (see `wire`: "alive")."""
        frame = wire.encode("alive", run=self.run)
        while True:
            for w in list(self.workers):
                nc.publish(worker_subject(w), frame)
            await trio.sleep(BEAT_S)

    def _on_hello(self, _subject: str, _reply: str | None, payload: bytes) -> None:
        try:
            f = wire.decode(payload)
        except wire.WireError:
            return
        # bounded: at most MAX_WORKERS names (a run takes no more), and none once the workers are chosen
        if (f["kind"] == "hello" and not self.workers and f["worker"] not in self.hellos
                and len(self.hellos) < wire.MAX_WORKERS):
            self.hellos[f["worker"]] = (f["host"], f["pid"])

    def _on_up(self, _subject: str, _reply: str | None, payload: bytes) -> None:
        try:
            self.inq.put_nowait(payload)
        except queue.Full:
            self.dropped += 1

    def choose(self, want: int | None, join_timeout: float, settle: float = 2.0,
               clock: Callable[[], float] = time.monotonic) -> list[str]:
        """Wait (at most `join_timeout` s) for `want` idle workers, or with `want` None for the first and then
        `settle` s more for others; the chosen worker ids (index order). RuntimeError when too few joined."""
        t0 = clock()
        first_at = None
        while True:
            heard = list(self.hellos)
            if heard and first_at is None:
                first_at = clock()
            if want is not None and len(heard) >= want:
                break
            if want is None and first_at is not None and clock() - first_at >= settle:
                break
            if clock() - t0 > join_timeout:
                need = want or 1
                raise RuntimeError(f"only {len(heard)} of {need} worker(s) joined over NATS at {self.url} within "
                                   f"{join_timeout:g} s: start `entitynet sim worker --nats {self.url}` on each "
                                   "machine (or wait longer with --join-timeout)")
            time.sleep(0.05)
        self.workers = sorted(heard)[: want or min(len(heard), wire.MAX_WORKERS)]
        return self.workers

    # ---- Link --------------------------------------------------------------------------------------------------
    def send(self, index: int, data: bytes) -> None:
        """Publish a frame to worker `index` (queued in the NATS thread; never blocks)."""
        if self._token is None:
            return
        try:
            self._token.run_sync_soon(self._nc.publish, worker_subject(self.workers[index]), data)
        except trio.RunFinishedError:
            pass

    def recv(self, timeout: float) -> list[bytes]:
        """Frames from the run's workers, waiting up to `timeout` s for the first."""
        try:
            out = [self.inq.get(timeout=timeout)]
        except queue.Empty:
            return []
        while True:
            try:
                out.append(self.inq.get_nowait())
            except queue.Empty:
                return out

    def gone(self) -> list[tuple[int, str]]:
        """NATS does not tell when a worker's process ends: a dead worker misses a tick's deadline instead."""
        return []

    def close(self) -> None:
        """Flush what is queued (the stop frames), close the client and end its thread."""
        if self._token is not None and self._closing is not None:
            try:
                self._token.run_sync_soon(self._closing.set)
            except trio.RunFinishedError:
                pass
        self._thread.join(3.0)


async def serve_worker(url: str, build, say: Callable[[str], None], *, once: bool = False,
                       token: str | None = None, connect_timeout: float = 1.0, settle: bool = True,
                       silence_min: float = SILENCE_MIN_S) -> int:
    """`entitynet sim worker`: announce this worker on NATS, take part in runs (`build` makes the share of a
    run from its assign frame), until Ctrl-C / SIGTERM, or after one run with `once`; the number of runs.
    `settle`: the process is the worker's own, so once its first run has started, what it holds is frozen out
    of garbage collection (`sims.engine.collector`). `silence_min`: a run whose coordinator is silent for this
    long (or its worker timeout, if longer) is given up."""
    import signal

    worker = f"{socket.gethostname()}-{os.getpid()}-{secrets.token_hex(3)}".replace(".", "_")
    core = WorkerCore(worker, socket.gethostname(), os.getpid(), build, silence_min)
    send, received = trio.open_memory_channel[bytes](256)
    dropped = 0

    def on_frame(_subject: str, _reply: str | None, payload: bytes) -> None:
        nonlocal dropped
        try:
            send.send_nowait(payload)
        except trio.WouldBlock:
            dropped += 1

    def lost(why: str) -> None:  # the client reconnects by itself; the worker's operator hears of it
        say(f"worker {worker}: lost NATS at {url} ({why}); reconnecting")

    def back() -> None:
        say(f"worker {worker}: NATS at {url} is back")

    async with NatsClient(url, name="entitynet-sim-worker", token=token, connect_timeout=connect_timeout,
                          on_disconnect=lost, on_reconnect=back) as nc:
        nc.subscribe(worker_subject(worker), on_frame)
        await nc.flush()
        async with trio.open_nursery() as nursery:

            async def announce() -> None:
                while True:
                    if core.idle:
                        nc.publish(HELLO, core.hello())
                    await trio.sleep(1.0)

            async def on_signal(task_status=trio.TASK_STATUS_IGNORED) -> None:
                with trio.open_signal_receiver(signal.SIGINT, signal.SIGTERM) as signals:
                    task_status.started()
                    async for _sig in signals:
                        say(f"worker {worker} stopped")
                        nursery.cancel_scope.cancel()
                        return

            await nursery.start(on_signal)  # Ctrl-C from here on is a clean stop, never a KeyboardInterrupt
            say(f"worker {worker} waiting for a run on {url}")
            nursery.start_soon(announce)
            while True:
                data = None
                with trio.move_on_after(1.0):
                    data = await received.receive()
                now = time.monotonic()
                was_idle = core.idle
                if data is not None:
                    for frame in core.receive(data, now):
                        if core.answer_to:
                            nc.publish(core.answer_to, frame)
                    if was_idle and not core.idle:
                        say(f"worker {worker} joined run {core.run} as worker {core.index}")
                    if settle and core.share is not None and core.share.k >= 0:  # its start done: freeze it
                        settle_after_start()
                        settle = False
                core.expire(now)
                if not was_idle and core.idle and core.ended is not None:
                    say(f"worker {worker}: run ended ({core.ended})")
                if once and core.runs_done:
                    with trio.move_on_after(2.0):
                        await nc.flush(2.0)
                    nursery.cancel_scope.cancel()
                    break
    return core.runs_done
