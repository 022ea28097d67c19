"""Real nats-server processes on loopback for the cluster tests (skipped where nats-server is not installed)."""

from __future__ import annotations

import pytest

from entitynet.cluster.natsd import NatsCluster, NatsServerMissing, nats_server_binary


def _cluster(n: int, token: str | None = None):
    """`n` real nats-server nodes on loopback (wanting `token` when given), stopped after the test; a clean skip
    without the binary."""
    try:
        nats_server_binary()
    except NatsServerMissing as exc:
        pytest.skip(str(exc))
    with NatsCluster(n, token=token) as c:
        yield c


@pytest.fixture
def nats_server():
    """One nats-server node."""
    yield from _cluster(1)


@pytest.fixture
def nats_server_with_token():
    """One nats-server node that wants the token `s3cret`."""
    yield from _cluster(1, token="s3cret")


@pytest.fixture
def nats_cluster3():
    """A three-node NATS cluster (its routes carry interest between the nodes)."""
    yield from _cluster(3)
