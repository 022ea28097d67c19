"""What the cross-shard path costs per state, counted (never timed): encodings of a local state, and that the
bytes another shard receives are the same whichever way they were made.

Why counted: the cluster's CPU per delivery is the issue-13 target; a state of a cell no other shard watches (a
region's interior; every state of a lone shard) must cost no msgpack encoding, and a state published to several
subjects is encoded once."""

from __future__ import annotations

import msgpack

from entitynet import protocol as P
from entitynet.cluster import core as cluster_core
from entitynet.cluster.core import STATE
from tests.entitynet.switchboard_helpers import join, pub

from .test_core import Bus


class _CountingPacker:
    """Wraps the core's msgpack packer and counts STATE messages encoded."""

    def __init__(self, pack):
        self.pack = pack
        self.states = 0

    def __call__(self, obj):
        if isinstance(obj, list) and obj and obj[0] == STATE:
            self.states += 1
        return self.pack(obj)


def test_a_state_no_other_shard_watches_is_not_encoded(monkeypatch):
    bus = Bus()
    bus.run(0.0)
    a, _b = bus.sbs
    counter = _CountingPacker(cluster_core._packb)
    monkeypatch.setattr(cluster_core, "_packb", counter)
    p = join(a)
    for seq in range(1, 6):
        a.receive(p, [pub(1, seq, (10,))], 0.1 * seq)
    bus.run(0.6)
    assert counter.states == 0  # nobody else watches cell 10 (main encoded all 5)
    assert bus.cores[0].out == [] and bus.cell_msgs == 0


def test_a_state_for_several_subjects_is_encoded_once_and_received_as_sent(monkeypatch):
    bus = Bus()
    bus.run(0.0)
    a, b = bus.sbs
    v = join(b)
    b.receive(v, [P.Subscribe((10, 11, 12), ())], 0.05)
    bus.run(0.05)
    counter = _CountingPacker(cluster_core._packb)
    monkeypatch.setattr(cluster_core, "_packb", counter)
    p = join(a)
    a.receive(p, [pub(1, 1, (10, 11), payload=b"\x00opaque\xff")], 0.1)
    sent = list(bus.cores[0].out)
    bus.run(0.1)
    assert counter.states == 1
    a.receive(p, [pub(1, 2, (12,), payload=b"\x01two")], 0.2)  # left 10 and 11 (watched): three subjects
    moved = list(bus.cores[0].out)
    bus.run(0.2)
    assert counter.states == 2
    prefix = bus.cores[0].prefix
    assert [s for s, _d, _r in sent] == [f"{prefix}.c.10", f"{prefix}.c.11"]
    assert [s for s, _d, _r in moved] == [f"{prefix}.c.12", f"{prefix}.c.10", f"{prefix}.c.11"]
    assert len({d for _s, d, _r in moved}) == 1  # the same bytes on every subject
    m = msgpack.unpackb(moved[0][1], raw=False)
    e = next(iter(a.entities.values()))
    c = a.clients[p]
    assert m == [STATE, 0, c.session, e.eid, 2, [12], 10_000, b"\x01two", c.identity, None, c.user_id]
    got = b.entities[e.eid]  # the payload reaches the other shard's tables byte for byte
    assert got.payload == b"\x01two" and got.cells == (12,) and got.seq == 2


def test_a_heartbeat_walks_the_tables_at_most_once_a_second(monkeypatch):
    """Heartbeats go out 4 times a second at `--dead-after 1`; the counts that walk every client (subscriptions,
    follows) and every mirror are taken once a second and repeated in between, while clients and entities are
    counted afresh in each heartbeat."""
    bus = Bus()
    bus.run(0.0)
    core, sb = bus.cores[0], bus.sbs[0]
    walks = []
    real = sb.counts
    monkeypatch.setattr(sb, "counts", lambda: (walks.append(1), real())[1])
    beats = []
    pack = msgpack.Packer(use_bin_type=True).pack
    monkeypatch.setattr("entitynet.cluster.failover._packb", lambda m: (beats.append(m), pack(m))[1])
    t = 10.0
    core._heartbeat_out(t)
    v = join(sb)
    sb.receive(v, [P.Subscribe((10, 11), ())], t)
    p = join(sb)
    sb.receive(p, [pub(1, 1, (10,))], t)
    core._heartbeat_out(t + 0.25)
    core._heartbeat_out(t + 0.5)
    assert len(walks) == 1  # (at t) the table walk is not repeated within the second
    first, later = beats[0][4], beats[-1][4]
    assert first["subscriptions"] == later["subscriptions"] == 0  # repeated, up to a second old
    assert (first["clients"], first["entities"]) == (0, 0) and (later["clients"], later["entities"]) == (2, 1)
    core._heartbeat_out(t + 1.0)
    assert len(walks) == 2 and beats[-1][4]["subscriptions"] == 2  # a second on: walked again
    assert beats[-1][3] == core.regions.digest  # the map digest taken once at start is the map's
