"""The NATS driver against a real nats-server on loopback: subscriptions are in place when the reader says so,
and every PUB reaches the viewers of its subject, found by the readers' pattern.

Why: the ladder's third system is only comparable if the driver speaks NATS correctly (the PONG after the SUBs
means they are in place; a two-cell update is two PUBs, delivered twice to a viewer of both, counted once).
Skips when nats-server is not installed (`.ci/run` installs it).
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import time

import pytest

from sims.bench.switch_drivers import PAD, PAYLOAD, NatsDriver
from sims.bench.switch_readers import Scanner
from sims.bench.switch_systems import free_port, wait_port

NATS = shutil.which("nats-server") or ("/usr/sbin/nats-server" if os.path.exists("/usr/sbin/nats-server") else None)


def _read_until(sock: socket.socket, done, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not done():
        left = deadline - time.monotonic()
        assert left > 0, "timed out"
        sock.settimeout(left)
        data = sock.recv(65536)
        assert data, "connection closed"
        yield data


@pytest.mark.skipif(NATS is None, reason="nats-server not installed")
def test_nats_driver_delivers_every_pub_to_the_subjects_viewers():
    port = free_port()
    proc = subprocess.Popen([NATS, "-a", "127.0.0.1", "-p", str(port)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, env={**os.environ, "GOMAXPROCS": "1"})
    try:
        wait_port(port, proc)
        drv = NatsDriver(port)
        viewer = socket.create_connection(("127.0.0.1", port), timeout=5)
        hello, ready = drv.viewer_hello((3, 7))
        viewer.sendall(hello)
        state = {"ready": False}
        for data in _read_until(viewer, lambda: state["ready"]):
            state["ready"] = ready.feed(data)
        pub = socket.create_connection(("127.0.0.1", port), timeout=5)
        pub.sendall(drv.publisher_hello())
        now = time.time()
        # entity 1 in cell 3, entity 2 in cells 3 and 7 (the viewer holds both), entity 4 in cell 9 (not held)
        pub.sendall(drv.publish_bytes([(1, 1, (3,), 5000), (2, 1, (3, 7), 5000), (4, 1, (9,), 5000)], now)
                    + b"PING\r\n")
        scan = Scanner(drv.pattern)
        heads: list[bytes] = []
        for data in _read_until(viewer, lambda: len(heads) >= 3):
            heads.extend(scan.feed(data))
        got = sorted(PAYLOAD.unpack(h)[1:] for h in heads)
        assert got == [(1, 1), (2, 1), (2, 1)]  # twice for the two-cell entity (the tally counts it once)
        assert all(PAYLOAD.unpack(h)[0] == now for h in heads)
        assert len(PAYLOAD.pack(now, 1, 1) + PAD) == 48
        pub.close()
        viewer.close()
    finally:
        proc.kill()
        proc.wait(10)
