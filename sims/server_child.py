"""The shard server of `entitynet sim` in a child process (`entitynet serve`), and when a run gets one.

Why: with the server in the simulation's process, one interpreter steps the world, thousands of honest clients,
the viewers and the truth measure *and* serves every PUBLISH and fan-out; a large run falls behind real time
on the server's share of that one core (issue 23). A child `entitynet serve` takes the server to its own
process (the second core), the way a real deployment runs it. Small runs stay in one process: they keep real
time either way and start faster.

The child is started with the project's one launcher (`entitynet.cluster.local.LocalShards`, one plain shard:
`python -P -m entitynet serve --open` on a free loopback port, tied to this process with PDEATHSIG), waited for
until it listens, and stopped on every way out (terminate, kill after 5 s). A child that dies mid-run ends the
run with `ServerChildDied`, whose message names its exit code and the last lines of its log.

The child's clock is the wall clock, not the simulation's: at `--speed` below 1 it would expire entities
before their simulated validity ran out, so `auto` keeps such runs in-process and `yes` refuses them. For the
same reason a pause (SIGUSR1, `p`) does not stop the child's expiry; the shell's pause line says so.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import trio

from entitynet.child_process import last_lines
from entitynet.cluster.local import LocalShards

#: `auto` starts the server in a child process from this many entities ... (`entitynet bench sim`: in-process
#: the ladder keeps real time up to 800-1,600 entities with a tenth as many viewers; docs/simulation.md)
PROCESS_MIN_ENTITIES = 1000
#: ... or this many viewers (their fan-out is the server's largest cost)
PROCESS_MIN_VIEWERS = 100
MODES = ("auto", "yes", "no")


class ServerChildDied(RuntimeError):
    """The child server exited while the run still needed it (the message is one line for the user)."""


def wants_server_process(mode: str, entities: int, viewers: int, speed: float = 1.0,
                         external: bool = False) -> tuple[bool, str]:
    """Whether the run starts its server in a child process, and why (said in the start-up lines and the
    report). `external`: the run has its own server or cluster (`--server`, `--shards`), so no child; a
    ValueError where `mode` asks for something that cannot be (a child besides an external server, a child at
    `speed` < 1: see the module docstring)."""
    if mode not in MODES:
        raise ValueError(f"server process mode must be one of {', '.join(MODES)}, got {mode!r}")
    if external:
        if mode == "yes":
            raise ValueError("--server-process yes starts its own server: not with --server or --shards")
        return False, "an external server or cluster"
    if mode == "no":
        return False, "asked for (--server-process no)"
    if speed < 1.0:
        if mode == "yes":
            raise ValueError("--server-process yes runs the server on the wall clock, which at --speed below 1 "
                             "would expire entities early: use --server-process no")
        return False, f"--speed {speed:g} below 1 (a child server keeps wall-clock time)"
    if mode == "yes":
        return True, "asked for (--server-process yes)"
    if entities >= PROCESS_MIN_ENTITIES or viewers >= PROCESS_MIN_VIEWERS:
        return True, (f"a large run ({entities} entities, {viewers} viewers; auto from {PROCESS_MIN_ENTITIES} "
                      f"entities or {PROCESS_MIN_VIEWERS} viewers)")
    return False, (f"a small run ({entities} entities, {viewers} viewers; auto from {PROCESS_MIN_ENTITIES} "
                   f"entities or {PROCESS_MIN_VIEWERS} viewers)")


class ServerChild:
    """One `entitynet serve --open` child on a free loopback port for the length of a run (a context manager:
    started on enter, stopped on every exit). Start it from the main thread: it dies with this process."""

    def __init__(self, artifact: Path, timeout: float = 30.0, serve_options: tuple[str, ...] = ()):
        self.artifact = Path(artifact)
        self.timeout = timeout
        self.log_dir = Path(tempfile.mkdtemp(prefix="entitynet-sim-server-"))
        self._shards = LocalShards(topology=self.artifact, regions=None, nats_urls=None, k=1, log_dir=self.log_dir,
                                   extra=list(serve_options), tie_to_parent=True)
        self.failed = False

    def __enter__(self) -> ServerChild:
        try:
            self._shards.start(self.timeout)
        except RuntimeError as exc:
            self.failed = True
            raise ServerChildDied(f"the sim's server process did not start: {exc}") from None
        except BaseException:  # Ctrl-C while it starts: nothing left behind
            self.stop()
            raise
        return self

    def __exit__(self, *exc_info) -> None:
        self.stop()

    @property
    def address(self) -> tuple[str, int]:
        """Where the publishers and viewers connect."""
        return "127.0.0.1", self._shards.ports[0]

    @property
    def pid(self) -> int:
        """The child's process id (in the report, and for whoever wants to watch it)."""
        return self._shards.procs[0].pid

    @property
    def log(self) -> Path:
        """The child's log (kept after a failure, removed after a clean run)."""
        return self.log_dir / "shard-0.log"

    def exit_code(self) -> int | None:
        """The child's exit status once it has exited; None while it runs."""
        return self._shards.procs[0].poll()

    def cpu_seconds(self) -> float | None:
        """CPU time (user + system) the child has used so far; None once it is gone. Why: what the server costs
        beside the simulation's own process, the figure that says what moving it out can gain."""
        import psutil

        try:
            t = psutil.Process(self.pid).cpu_times()
        except psutil.Error:
            return None
        return t.user + t.system

    def death_message(self, code: int) -> str:
        """One line for the user: the child's exit status and its last log lines (joined with ' | ')."""
        import signal

        tail = " | ".join(last_lines(self.log, n=4, max_chars=600).splitlines())
        try:
            how = f"was killed by {signal.Signals(-code).name}" if code < 0 else f"exited with {code}"
        except ValueError:
            how = f"exited with {code}"
        return f"the sim's server process (pid {self.pid}) {how} mid-run; the end of {self.log}: {tail}"

    def stop(self) -> None:
        """Terminate the child (kill after 5 s) and remove its log folder unless something failed."""
        if self._shards.procs:
            self._shards.stop()
        if not self.failed:
            shutil.rmtree(self.log_dir, ignore_errors=True)

    def report(self, why: str) -> dict:
        """What the report says about where the server ran."""
        return {"in_process": False, "process": True, "pid": self.pid, "why": why}

    async def run_shell(self, shell) -> dict:
        """`shell.run()` against this child, watched: a child that exits mid-run cancels the run and raises
        `ServerChildDied` (the shell's connections would otherwise reconnect to nothing until the duration)."""
        died: list[int] = []

        async def watch(scope: trio.CancelScope) -> None:
            while (code := self.exit_code()) is None:
                await trio.sleep(0.2)
            died.append(code)
            scope.cancel()

        report = None
        async with trio.open_nursery() as nursery:
            nursery.start_soon(watch, nursery.cancel_scope)
            report = await shell.run()
            nursery.cancel_scope.cancel()
        if died and report is None:
            self.failed = True
            raise ServerChildDied(self.death_message(died[0]))
        return report
