"""The end-to-end benchmark's brokers as real processes: mosquitto here; Redis and our server through the switch
benchmark's harness (`sims.bench.switch_systems.started`, one home for starting peers).

Why mosquitto gets its own starter: it reads its listener from a config file, not flags, so the bench writes a
minimal one (loopback listener on a free port, anonymous clients, no persistence, nothing logged but errors)
into the run's log folder. Stopped with SIGTERM, killed if it does not go.
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from sims.bench.switch_systems import _version, free_port, wait_port


def mosquitto_config(port: int) -> str:
    """A mosquitto 2 config for one loopback listener (QoS 0 clients, no persistence, no queue limits that
    would drop a subscriber's QoS 0 messages)."""
    return "\n".join([
        f"listener {port} 127.0.0.1",
        "allow_anonymous true",
        "persistence false",
        "max_queued_messages 0",
        "max_inflight_messages 0",
        "log_dest stderr",
        "log_type error",
        "",
    ])


@contextmanager
def mosquitto(exe: str, log_dir: Path, progress) -> Iterator[tuple[subprocess.Popen, int, str]]:
    """Start mosquitto on a free loopback port; yield (process, port, version); stopped on exit."""
    port = free_port()
    conf = log_dir / "mosquitto.conf"
    conf.write_text(mosquitto_config(port))
    version = _version([exe, "-h"]).splitlines()[0] if exe else "unknown"
    progress(f"starting mosquitto: {exe} -c {conf} (port {port})")
    log = open(log_dir / "mosquitto.log", "w")
    proc = subprocess.Popen([exe, "-c", str(conf)], stdout=log, stderr=subprocess.STDOUT)
    try:
        wait_port(port, proc)
        yield proc, port, version
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
        log.close()
