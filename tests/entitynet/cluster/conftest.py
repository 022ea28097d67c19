"""Real nats-server processes on loopback for the cluster tests (skipped where nats-server is not installed)."""

from __future__ import annotations

import pytest

from entitynet.cluster.natsd import NatsCluster, NatsServerMissing, nats_server_binary


@pytest.fixture
def nats_server():
    try:
        nats_server_binary()
    except NatsServerMissing as exc:
        pytest.skip(str(exc))
    with NatsCluster(1) as c:
        yield c


@pytest.fixture
def nats_cluster3():
    try:
        nats_server_binary()
    except NatsServerMissing as exc:
        pytest.skip(str(exc))
    with NatsCluster(3) as c:
        yield c
