"""A shard says when its NATS connection is lost and when it is restored: one line for each transition (not
one per failed reconnect attempt), at levels `entitynet serve` shows by default, with a real nats-server
process that is stopped and started again on the same port."""

from __future__ import annotations

import logging
import subprocess

import trio

from entitynet.cluster.natsd import NatsCluster, _answers, nats_server_binary
from tests.entitynet.cluster.shard_helpers import shards, two_regions


def _lines(caplog, text: str) -> list[logging.LogRecord]:
    return [r for r in caplog.records if text in r.getMessage()]


async def _until(pred, timeout: float = 10.0) -> None:
    with trio.fail_after(timeout):
        while not pred():
            await trio.sleep(0.05)


async def test_a_shard_logs_losing_and_regaining_nats(caplog, nats_server: NatsCluster):
    caplog.set_level(logging.DEBUG, logger="entitynet")
    node = nats_server.nodes[0]
    async with shards(nats_server.urls, two_regions(1)) as [server]:
        node.kill()
        await _until(lambda: _lines(caplog, "lost its NATS connection"))
        await trio.sleep(0.5)  # several reconnect attempts fail meanwhile (one every 0.1 s)
        node.proc = subprocess.Popen([nats_server_binary(), "-a", node.host, "-p", str(node.port)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        await _until(lambda: _answers(node.host, node.port))
        await _until(lambda: _lines(caplog, "NATS connection restored"))
        assert server.cluster.nc.connected
    [lost] = _lines(caplog, "lost its NATS connection")
    [back] = _lines(caplog, "NATS connection restored")
    assert lost.levelno == logging.WARNING and back.levelno == logging.INFO  # `serve` shows both
    for record in (lost, back):
        assert "shard 0" in record.getMessage() and f"{node.host}:{node.port}" in record.getMessage()
    assert "after" in back.getMessage()  # how long the shard was cut off
    assert lost.created < back.created
