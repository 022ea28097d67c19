"""The three systems the switch benchmark drives, started as real server processes, and the core plan.

Why apart from the benchmark: starting, pinning and stopping a server is the same chore for entitynet, Redis and
NATS, and whether the run could pin decides how its figures may be read. With enough cores (`pin_plan`), each
server process is pinned to one core of its own (`taskset`; nats-server also gets GOMAXPROCS=1) and the load
generator keeps the other cores, so "capacity of one core" means the same for all three. On a machine with
fewer cores the servers and the load generator share them, the report says so, and the figures are capacity
of that shared machine, not of one core.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import time
import urllib.request
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from entitynet.child_process import entitynet_argv, last_lines
from sims.bench.switch_drivers import NatsDriver, OursDriver, RedisDriver

MIN_CORES_TO_PIN = 4  # one for the server, at least three for the publisher and the reader processes

SYSTEMS = ("entitynet", "redis", "nats")


def pin_plan(cores: list[int]) -> dict[str, Any]:
    """Which core the server gets and which the load generator keeps, given the usable cores: the last core
    for the server when there are `MIN_CORES_TO_PIN` or more, else no pinning (and why)."""
    if len(cores) >= MIN_CORES_TO_PIN:
        return {"pinned": True, "server_core": cores[-1], "loadgen_cores": cores[:-1],
                "note": f"each server pinned to core {cores[-1]} (nats-server with GOMAXPROCS=1); the load "
                        f"generator on cores {cores[0]}-{cores[-2]}"}
    return {"pinned": False, "server_core": None, "loadgen_cores": cores,
            "note": f"not pinned: {len(cores)} usable core(s), fewer than {MIN_CORES_TO_PIN} (one for the server "
                    "and the rest for the load generator); servers and load generator share the cores "
                    "(nats-server still runs with GOMAXPROCS=1)"}


def workload_params(cores: list[int], plan: dict[str, Any]) -> dict[str, Any]:
    """The load generator's settings that every run of the same workload shares (the ladder, `switch_repeat`):
    publisher connections, reader processes (more where the plan leaves cores to the load generator), the
    subscription radius of the no-PVS fallback, the server's flush bound and the seed."""
    return {"publisher_connections": 4,
            "reader_processes": 2 if len(cores) <= 4 else min(8, len(plan["loadgen_cores"]) - 1),
            "radius_m": 500.0, "flush_ms": 10.0, "seed": 7}


def pin_loadgen(plan: dict[str, Any]) -> Callable[[], None]:
    """Move this process (and the reader processes it forks later) onto the load generator's cores when the plan
    pins; returns what puts its affinity back."""
    if not plan["pinned"]:
        return lambda: None
    own = os.sched_getaffinity(0)
    os.sched_setaffinity(0, plan["loadgen_cores"])
    return lambda: os.sched_setaffinity(0, own)


def usable_cores() -> list[int]:
    """The cores this process may run on."""
    try:
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        return list(range(os.cpu_count() or 1))


def free_port() -> int:
    """A free TCP port on loopback."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_port(port: int, proc, timeout: float = 30.0, log: Path | None = None) -> None:
    """Until something listens on `port` (or the process exits: then a clear error, with the end of its `log`)."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"server exited with status {proc.returncode}"
                               + (f"; the end of {log}:\n{last_lines(log)}" if log is not None else ""))
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return
        except OSError:
            time.sleep(0.05)
    raise RuntimeError(f"nothing listening on port {port} after {timeout} s")


def scraper(port: int):
    """A function reading our server's Prometheus endpoint into {metric: value}. A 1 s timeout: the scrape runs
    in the publisher's loop, so a busy server that answers late must not stall the load it is measured with."""
    def scrape() -> dict[str, float]:
        text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=1).read().decode()
        out = {}
        for line in text.splitlines():
            if line and not line.startswith("#"):
                k, _, v = line.rpartition(" ")
                out[k] = float(v)
        return out

    return scrape


def find_exe(name: str, package: str, progress) -> tuple[str | None, str]:
    """The server binary on PATH (or /usr/bin, /usr/sbin), else an `apt-get install` attempt; and how."""
    for exe in (shutil.which(name), f"/usr/bin/{name}", f"/usr/sbin/{name}"):
        if exe and os.path.exists(exe):
            return exe, f"found {exe}"
    progress(f"{name} not found; trying apt-get install -y {package}")
    try:
        r = subprocess.run(["apt-get", "install", "-y", package], capture_output=True, text=True, timeout=300)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return None, f"{name} not found and apt-get failed: {exc}"
    exe = shutil.which(name) or (f"/usr/sbin/{name}" if os.path.exists(f"/usr/sbin/{name}") else None)
    if exe:
        return exe, f"installed {package} with apt-get"
    return None, f"{name} not found; apt-get exited {r.returncode}: {r.stderr.strip()[-300:]}"


def _version(cmd: list[str]) -> str:
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"


@contextmanager
def started(system: str, exe: str | None, topo_path: str, digest: str, p: dict, plan: dict, log_dir: Path,
            progress) -> Iterator[tuple[Any, subprocess.Popen, Any]]:
    """Start one system's server (pinned when `plan` says so) and yield (driver, process, scrape or None);
    stopped on exit (ours gracefully, so that a profile gets written; the others killed: no persistence)."""
    pin = ["taskset", "-c", str(plan["server_core"])] if plan["pinned"] and shutil.which("taskset") else []
    port = free_port()
    env = None
    if system == "entitynet":
        mport = free_port()
        prof = os.environ.get("ENTITYNET_BENCH_PROFILE")  # developer aid: profile the server process
        cmd = [*pin, *entitynet_argv("serve", "--topology", topo_path, "--port", str(port), "--metrics-port",
                                     str(mport), "--open", "--flush-ms", str(p["flush_ms"]),
                                     *p.get("server_args", ()),  # switch_repeat's variants
                                     python_options=("-m", "cProfile", "-o", prof) if prof else ())]
        driver: Any = OursDriver(port, digest)
        scrape = scraper(mport)
    elif system == "redis":
        cmd = [*pin, exe, "--port", str(port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no",
               "--client-output-buffer-limit", "pubsub 0 0 0", "--maxclients", "20000"]
        driver, scrape, prof = RedisDriver(port), None, None
        p.setdefault("redis_version", _version([exe, "--version"]))
    else:
        cmd = [*pin, exe, "-a", "127.0.0.1", "-p", str(port)]
        env = {**os.environ, "GOMAXPROCS": "1"}
        driver, scrape, prof = NatsDriver(port), None, None
        p.setdefault("nats_version", _version([exe, "--version"]))
    progress(f"starting {system}: " + " ".join(cmd))
    log = open(log_dir / f"{system}.log", "w")
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env,
                            cwd=str(Path(__file__).parents[2]))
    try:
        wait_port(port, proc, log=log_dir / f"{system}.log")
        yield driver, proc, scrape
    finally:
        if system == "entitynet":
            proc.send_signal(2)  # SIGINT: graceful shutdown (and a written profile)
            try:
                proc.wait(60 if prof else 10)
            except subprocess.TimeoutExpired:
                proc.kill()
        else:
            proc.kill()  # no graceful stop needed; it may be busy flushing backlogs
        proc.wait(10)
        log.close()
