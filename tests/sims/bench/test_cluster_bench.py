"""`entitynet bench cluster`: where its time goes. `--quick` starts every run's processes together before the
first measurement (one after another they were a third of its time) and the full run keeps starting each run
just before it; the load connects its clients concurrently. Process-free: the processes and the measured drive
are stand-ins that record the order of events (no timing is asserted)."""

from __future__ import annotations

import argparse
import types

import trio

from sims.bench import cluster_bench


class _Proc:
    pid = 0


class _FakeShards:
    def __init__(self, events: list, topology, regions, nats_urls, k, log_dir, extra=()):
        self.events, self.k, self.name = events, k, log_dir.name
        self.procs = [_Proc() for _ in range(k)]
        self.ports = list(range(k))

    def spawn(self):
        self.events.append(("spawn", self.name))
        return self

    def wait_ready(self, timeout: float = 30.0):
        self.events.append(("ready", self.name))
        return self

    def start(self, timeout: float = 30.0):
        self.events.append(("start", self.name))
        return self

    def stop(self):
        self.events.append(("stop", self.name))

    def kill(self, i: int):
        if i == 0:
            self.events.append(("stop", self.name))


class _FakeNats:
    def __init__(self, n, log_dir=None):
        self.nodes = [types.SimpleNamespace(proc=_Proc(), url="nats://x:1") for _ in range(n)]
        self.urls = "nats://x:1"

    def start(self):
        return self

    def stop(self):
        pass


def _run_bench(monkeypatch, tmp_path, quick: bool) -> list:
    import topology.artifact
    import topology.regions
    from sims.bench import switch_bench

    events: list = []
    topo = types.SimpleNamespace(n_cells=4, digest="d" * 64)
    regions = types.SimpleNamespace(report={"balance": 1.0}, save=lambda path: None)
    monkeypatch.setattr(topology.artifact, "load", lambda path: topo)
    monkeypatch.setattr(topology.regions, "build_regions", lambda *a, **k: regions)
    monkeypatch.setattr(topology.regions, "cell_adjacency", lambda t: [{1}, {0, 2}, {1, 3}, {2}])
    monkeypatch.setattr(switch_bench, "pvs_viewer_cells", lambda t, n, rng: [(0, 1)] * n)
    monkeypatch.setattr(cluster_bench, "LocalShards", lambda *a, **k: _FakeShards(events, *a, **k))
    monkeypatch.setattr(cluster_bench, "NatsCluster", _FakeNats)

    def drive(fn, topo, regions, shards, *rest):
        events.append(("drive", shards.name))
        return {"cross_shard_fraction": 0.1, "cpu_s_per_million_deliveries": 1.0, "handover_gap_ms": 1.0,
                "viewer_duplicates": 0, "entities_lost": 0}

    monkeypatch.setattr(cluster_bench, "trio", types.SimpleNamespace(run=drive))
    out = cluster_bench.run(argparse.Namespace(quick=quick, topology=str(tmp_path / "t.enttopo")), lambda m: None)
    assert set(out["results"]["by_shards"]) == {"single", "shards_1", "shards_2", "shards_4"}
    return events


def test_quick_starts_every_run_before_the_first_measurement(monkeypatch, tmp_path):
    events = _run_bench(monkeypatch, tmp_path, quick=True)
    first_drive = events.index(("drive", "single"))
    names = ["single", "shards_1", "shards_2", "shards_4"]
    assert {("spawn", n) for n in names} | {("ready", n) for n in names} <= set(events[:first_drive])
    for n in names:  # each run's processes stop right after its own measurement, not at the end
        assert events.index(("stop", n)) == events.index(("drive", n)) + 1


def test_the_full_run_still_starts_each_run_just_before_it(monkeypatch, tmp_path):
    events = _run_bench(monkeypatch, tmp_path, quick=False)
    assert [e for e in events if e[0] != "stop"] == [
        (what, n) for n in ["single", "shards_1", "shards_2", "shards_4"] for what in ("start", "drive")]


async def test_the_load_connects_its_clients_concurrently(monkeypatch):
    """Viewers connect together, then movers together (viewers first: the first updates have an audience)."""
    from sims.bench import cluster_load

    log: list[tuple[str, str]] = []
    in_flight = [0]
    most = [0]

    class FakeConn:
        def __init__(self, home, *a, **k):
            self.home = home

        async def run(self, task_status=trio.TASK_STATUS_IGNORED):
            in_flight[0] += 1
            most[0] = max(most[0], in_flight[0])
            await trio.sleep(0.01)  # a handshake
            in_flight[0] -= 1
            log.append(("connected", self.home))
            task_status.started()
            await trio.sleep_forever()

        async def set_subscription(self, cells):
            pass

        async def publish(self, *m):
            pass

    monkeypatch.setattr(cluster_load, "Connection", FakeConn)
    p = {"publish_interval_s": 1.0, "move_every_s": 2.0, "validity_ms": 5000, "failover_s": 2.0}
    import random

    load = cluster_load.Load("d", ["127.0.0.1:1", "127.0.0.1:2"], lambda c: "127.0.0.1:2", [[1], [0]], [0] * 10,
                             [(0,)] * 10, ["127.0.0.1:1"] * 10, p, random.Random(1))
    async with trio.open_nursery() as nursery:
        await load.start(nursery)
        nursery.cancel_scope.cancel()
    assert most[0] == 10  # ten at a time, not one after another
    assert [h[1] for _c, h in log] == [1] * 10 + [2] * 10  # every viewer connected before any mover


def test_cpu_by_process_is_each_processes_own_share_of_the_window():
    """The report's `cpu_by_process`: each role's CPU over the window in ms per second; a process that is gone
    at either end of the window is left out rather than counted as zero."""
    before = {10: (1.0, 0.5), 11: (2.0, 0.0), 12: (0.2, 0.1)}
    after = {10: (1.5, 0.6), 11: (2.1, 0.1)}  # 12 died during the window
    out = cluster_bench._per_process(["shard_0", "shard_1", "nats_0"], [10, 11, 12], before, after, 2.0)
    assert out == {"shard_0": {"cpu_ms_per_s": 300.0, "user_ms_per_s": 250.0, "system_ms_per_s": 50.0},
                   "shard_1": {"cpu_ms_per_s": 100.0, "user_ms_per_s": 50.0, "system_ms_per_s": 50.0}}
