"""Local nats-server processes: one node or a routed cluster on loopback, for `entitynet cluster up` and tests.

Why a module of its own: the demo, the tests and the benchmark all need the same thing (free ports, the
routes between nodes, waiting until every node answers, killing them all at the end) and none of it belongs
in the cluster's logic. Production runs nats-server under its own service manager (docs/deploy.md).
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from entitynet.child_process import last_lines


def die_with_parent() -> Callable[[], None] | None:
    """A `preexec_fn` for a child that must not outlive this process (Linux: PR_SET_PDEATHSIG = SIGKILL), or None
    where that is not available. Why: a local cluster started for a demo or a simulation must leave no orphan
    nats-server or switchboard behind, even when its parent is SIGKILLed and cannot clean up. The libc call is
    looked up here, in the parent, so the child between fork and exec only calls it. The signal fires when the
    *thread* that started the child exits, so only children started from the main thread may use it."""
    import ctypes
    import signal
    import sys

    if not sys.platform.startswith("linux"):
        return None
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None

    def preexec() -> None:
        prctl(1, signal.SIGKILL, 0, 0, 0)  # 1 = PR_SET_PDEATHSIG

    return preexec


class NatsServerMissing(RuntimeError):
    """nats-server is not installed (Debian: apt-get install nats-server)."""


def nats_server_binary() -> str:
    """Path of nats-server (PATH, then Debian's /usr/sbin); `NatsServerMissing` says how to install it."""
    path = shutil.which("nats-server") or (
        "/usr/sbin/nats-server" if Path("/usr/sbin/nats-server").exists() else None)
    if path is None:
        raise NatsServerMissing("nats-server not found: install it (Debian: apt-get install nats-server)")
    return path


def free_port(host: str = "127.0.0.1") -> int:
    """A port the OS says is free now (bound and released; a race is possible but rare on loopback)."""
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _answers(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=0.2) as s:
            s.settimeout(0.5)
            return s.recv(4).startswith(b"INFO")
    except OSError:
        return False


@dataclass
class NatsNode:
    """One nats-server process: its client port and, in a routed cluster, its route port."""

    port: int
    cluster_port: int | None
    proc: subprocess.Popen | None = None
    host: str = "127.0.0.1"

    @property
    def url(self) -> str:
        """The URL clients connect to."""
        return f"nats://{self.host}:{self.port}"

    def kill(self) -> None:
        """SIGKILL the node if it still runs (tests of a NATS node's failure need it abrupt)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)


@dataclass
class NatsCluster:
    """`n` nats-server nodes on loopback, routed to each other when n > 1."""

    n: int = 1
    token: str | None = None
    host: str = "127.0.0.1"
    log_dir: Path | None = None
    tie_to_parent: bool = False  # children die with this process and miss a terminal's Ctrl-C (main thread only)
    nodes: list[NatsNode] = field(default_factory=list)

    @property
    def urls(self) -> str:
        """Comma-separated client URLs of every node, the form `--cluster` takes."""
        return ",".join(node.url for node in self.nodes)

    def start(self, timeout: float = 10.0) -> NatsCluster:
        """Spawn the nodes (routed to each other when n > 1) and wait until each answers with INFO; a node
        that exits or misses `timeout` stops them all and raises RuntimeError."""
        binary = nats_server_binary()
        self.nodes = [NatsNode(free_port(self.host), free_port(self.host) if self.n > 1 else None, host=self.host)
                      for _ in range(self.n)]
        for i, node in enumerate(self.nodes):
            args = [binary, "-a", self.host, "-p", str(node.port), "-n", f"entitynet-{i}"]
            if self.token:
                args += ["--auth", self.token]
            if node.cluster_port is not None:
                routes = ",".join(f"nats://{self.host}:{o.cluster_port}" for o in self.nodes if o is not node)
                args += ["--cluster", f"nats://{self.host}:{node.cluster_port}", "--routes", routes,
                         "--cluster_name", "entitynet"]
            out = subprocess.DEVNULL
            if self.log_dir is not None:
                out = open(Path(self.log_dir) / f"nats-{i}.log", "ab")  # noqa: SIM115 (the child owns it)
            node.proc = subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                         preexec_fn=die_with_parent() if self.tie_to_parent else None,
                                         start_new_session=self.tie_to_parent)
        deadline = time.monotonic() + timeout
        for node in self.nodes:
            while not _answers(node.host, node.port):
                if node.proc.poll() is not None:
                    self.stop()
                    log = Path(self.log_dir) / f"nats-{self.nodes.index(node)}.log" if self.log_dir else None
                    raise RuntimeError(f"nats-server on port {node.port} exited with {node.proc.returncode}"
                                       + (f"; the end of {log}:\n{last_lines(log)}" if log else ""))
                if time.monotonic() > deadline:
                    self.stop()
                    raise RuntimeError(f"nats-server on port {node.port} did not start within {timeout} s")
                time.sleep(0.02)
        if self.n > 1:
            time.sleep(0.3)  # routes form within a few hundred ms of the last node starting
        return self

    def stop(self) -> None:
        """Kill every node."""
        for node in self.nodes:
            node.kill()

    def __enter__(self) -> NatsCluster:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
