"""In-process shard servers joined over a real nats-server, for the multi-shard tests."""

from __future__ import annotations

import contextlib

import numpy as np
import trio

from entitynet.cluster.link import ClusterConfig
from tests.entitynet.server_helpers import DIGEST, config
from topology.regions import RegionMap

N_CELLS = 100


def two_regions(k: int = 2) -> RegionMap:
    """Cells 0..49 are region 0, 50..99 region 1 (k=2); k equal bands otherwise."""
    region = (np.arange(N_CELLS) * k // N_CELLS).astype(np.int32)
    borders = [np.zeros(0, np.int32) for _ in range(k)]
    return RegionMap(DIGEST, k, region, None, None, borders, {})


def shards(nats_urls: str, regions: RegionMap, n: int | None = None, redirect_viewers: bool = False, **kw):
    """Start `n` shard servers (shard i owns region i); yields the list of servers. Viewers stay where they
    connect unless `redirect_viewers` (most tests watch one region from the other's shard)."""
    n = regions.shards if n is None else n
    return shards_on([nats_urls] * n, regions, redirect_viewers, **kw)


@contextlib.asynccontextmanager
async def shards_on(urls: list[str], regions: RegionMap, redirect_viewers: bool = False,
                    cluster_kw: dict | None = None, **kw):
    """Shard i connects to NATS at urls[i]; `cluster_kw` goes to every shard's ClusterConfig."""
    kw.setdefault("switch", {"grace_s": 0.2})
    async with trio.open_nursery() as nursery:
        servers = []
        for i, nats_urls in enumerate(urls):
            cc = ClusterConfig(nats_urls, i, regions, heartbeat_s=0.1, dead_after_s=0.6,
                               redirect_viewers=redirect_viewers, **(cluster_kw or {}))
            servers.append(await nursery.start(_serve_scoped, config(n_cells=N_CELLS, cluster=cc, **kw)))
        await wait_peers(servers)
        try:
            yield servers
        finally:
            nursery.cancel_scope.cancel()


async def _serve_scoped(cfg, task_status=trio.TASK_STATUS_IGNORED):
    """A server in its own cancel scope (kill it with `server.kill_scope.cancel()`: no goodbye, like SIGKILL)."""
    from entitynet.server.app import Server

    server = Server(cfg)
    with trio.CancelScope() as scope:
        server.kill_scope = scope
        await server.run(task_status=task_status)


async def wait_peers(servers, timeout: float = 5.0) -> None:
    """Until every shard has heard every other's heartbeat (addresses known for REDIRECTs)."""
    want = len(servers) - 1
    with trio.fail_after(timeout):
        while any(sum(p.alive for p in s.cluster.core.peers.values()) < want for s in servers):
            await trio.sleep(0.02)


async def until(pred, timeout: float = 5.0) -> None:
    with trio.fail_after(timeout):
        while not pred():
            await trio.sleep(0.01)


def town_artifact(tmp_path_factory, name: str, blocks: int, build_config=None):
    """A small grid town's artifact (`blocks` x `blocks`, 100 m blocks) for tests that start shard processes,
    which need nats-server: the test is skipped, with the reason, where it is not installed."""
    import pytest

    from entitynet.cluster.natsd import NatsServerMissing, nats_server_binary
    from tests.topology.mapfixtures import collection, grid
    from topology.artifact import save
    from topology.build import build
    from topology.geojson_reader import geojson_to_raw

    try:
        nats_server_binary()
    except NatsServerMissing as exc:
        pytest.skip(str(exc))
    path = tmp_path_factory.mktemp(name) / "town.enttopo"
    raw = geojson_to_raw(collection(*grid(blocks, blocks)))
    save(build(raw) if build_config is None else build(raw, build_config), path)
    return path
