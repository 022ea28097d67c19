"""K switchboard processes (`entitynet serve --cluster`) on loopback, for `entitynet cluster up` and the benchmark.

Why processes: a shard is a process in production, and what the cluster costs (CPU per delivery across shards
and NATS nodes) is only honest when each shard has its own interpreter.
"""

from __future__ import annotations

import socket
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

from entitynet.child_process import entitynet_argv, last_lines
from entitynet.cluster.natsd import die_with_parent, free_port


@dataclass
class LocalShards:
    """K `entitynet serve` processes on free loopback ports, one per shard (or one plain server when `regions`
    is None); each logs to `log_dir/shard-<i>.log`."""

    topology: Path
    regions: Path | None  # None: one plain switchboard, no cluster (the single-server baseline)
    nats_urls: str | None
    k: int
    log_dir: Path
    extra: list[str] = field(default_factory=list)  # more `serve` options (e.g. --dead-after 1)
    tie_to_parent: bool = False  # shards die with this process (start from the main thread only)
    ports: list[int] = field(default_factory=list)
    procs: list[subprocess.Popen] = field(default_factory=list)

    def start(self, timeout: float = 30.0) -> LocalShards:
        """Spawn every shard and wait until each accepts TCP connections; a shard that exits or misses
        `timeout` stops them all, so a failed start leaves no processes behind."""
        self.spawn()
        return self.wait_ready(timeout)

    def spawn(self) -> LocalShards:
        """Spawn every shard without waiting for it (`wait_ready` waits): several clusters can start at once."""
        self.ports = [free_port() for _ in range(self.k)]
        for i, port in enumerate(self.ports):
            cmd = entitynet_argv("serve", "--open", "--topology", str(self.topology), "--port", str(port),
                                 *self.extra)
            if self.regions is not None:
                cmd += ["--cluster", self.nats_urls, "--shard", str(i), "--regions", str(self.regions)]
            log = open(Path(self.log_dir) / f"shard-{i}.log", "ab")  # noqa: SIM115 (the child owns it)
            self.procs.append(subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                               preexec_fn=die_with_parent() if self.tie_to_parent else None,
                                               start_new_session=self.tie_to_parent))
        return self

    def wait_ready(self, timeout: float = 30.0) -> LocalShards:
        """Until every spawned shard accepts TCP connections; one that exits or misses `timeout` stops them all."""
        deadline = time.monotonic() + timeout
        for i, port in enumerate(self.ports):
            while True:
                try:
                    socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                    break
                except OSError:
                    code = self.procs[i].poll()
                    if code is not None or time.monotonic() > deadline:
                        self.stop()
                        log = Path(self.log_dir) / f"shard-{i}.log"
                        how = f"exited with {code}" if code is not None else f"did not listen within {timeout:g} s"
                        raise RuntimeError(f"shard {i} did not start ({how}); the end of {log}:\n"
                                           + last_lines(log)) from None
                    time.sleep(0.05)
        return self

    @property
    def addresses(self) -> list[str]:
        """`host:port` of every shard, in shard order (what clients and REDIRECTs use)."""
        return [f"127.0.0.1:{p}" for p in self.ports]

    def kill(self, i: int) -> None:
        """SIGKILL shard `i` (no goodbye on NATS): the failover test and benchmark need an abrupt death."""
        if self.procs[i].poll() is None:
            self.procs[i].kill()
            self.procs[i].wait(5)

    def stop(self) -> None:
        """SIGTERM every shard for a clean exit, SIGKILL whichever has not exited within 5 s."""
        import signal

        for pr in self.procs:
            if pr.poll() is None:
                pr.send_signal(signal.SIGTERM)
        for pr in self.procs:
            try:
                pr.wait(5)
            except subprocess.TimeoutExpired:
                pr.kill()
                pr.wait(5)
