"""The array ghost table against the dict-of-objects store it replaced (kept here as the reference), on random
and hostile message streams, many viewers sharing one table and each message object."""

from __future__ import annotations

import math
import random

import msgpack
import numpy as np
import pytest

from entitynet.client import GhostStore, WorldModel, encode
from entitynet.client.ghost_table import GhostTable
from entitynet.client.limits import HORIZON
from entitynet.client.payload import PayloadError, decode
from entitynet.protocol import Leave, Update


class DictStore:
    """The store as it was before the table (a dict of ghosts per viewer): the reference."""

    def __init__(self) -> None:
        self.ghosts: dict[int, tuple] = {}  # entity -> (seq, cells, expires, model, identity)
        self.visible: set[int] = set()
        self.bad_payloads = 0

    def receive(self, msg, now: float) -> None:
        if isinstance(msg, Leave):
            self.ghosts.pop(msg.entity, None)
            return
        old = self.ghosts.get(msg.entity)
        if old is not None and msg.seq <= old[0]:
            return
        try:
            model = decode(msg.payload, None)
        except PayloadError:
            self.bad_payloads += 1
            return
        life = min(msg.validity_ms / 1000.0, HORIZON)
        self.ghosts[msg.entity] = (msg.seq, tuple(msg.cells), now + life, model, msg.identity)

    def expire(self, now: float) -> None:
        for e in [e for e, g in self.ghosts.items() if now >= g[2]]:
            del self.ghosts[e]

    def positions(self, now: float) -> dict:
        self.expire(now)
        return {e: g[3].xy_at(now) for e, g in self.ghosts.items() if not self.visible.isdisjoint(g[1])}


def _payload(rng: random.Random) -> bytes:
    r = rng.random()
    if r < 0.04:
        return msgpack.packb([1, 3, 0, 1, float("nan"), 0, 0, 0, 0, 0])  # a NaN where an integer belongs
    if r < 0.07:
        return b"\xc1garbage"
    x = rng.uniform(-500, 500)
    return encode(WorldModel(rng.uniform(0, 20), x, rng.uniform(-500, 500), rng.uniform(-9, 9), 0.0, 0.0, 0.0, 1))


def _stream(rng: random.Random, n: int):
    """(viewer, message, now) with out-of-order seqs, LEAVEs of unknown entities, validity 0, bad payloads."""
    seqs: dict[int, int] = {}
    now = 0.0
    shared = []
    for _ in range(n):
        now += rng.choice((0.0, 0.0, 0.1, 0.5, 3.0))
        e = rng.randrange(30)
        r = rng.random()
        if r < 0.1:
            msg = Leave(rng.randrange(40))  # some never seen
        elif r < 0.3 and shared:
            msg = rng.choice(shared)  # the same object again (fanned out), maybe out of order now
        else:
            seqs[e] = seqs.get(e, 0) + rng.choice((1, 1, 2, -1, 0))
            cells = tuple(rng.sample(range(-2, 12), rng.randrange(0, 4)))
            msg = Update(e, max(seqs[e], 0), cells, rng.choice((0, 500, 4000, 10**8)), _payload(rng),
                         rng.choice((None, "bob")))
            shared.append(msg)
        yield rng.randrange(5), msg, now


@pytest.mark.parametrize("seed", range(12))
def test_the_table_follows_the_dict_store_on_random_hostile_streams(seed):
    rng = random.Random(seed)
    table = GhostTable(None)
    if seed % 2:
        table._compact_at = 8  # compact often: versions dropped and rows reused on the way
    stores = [GhostStore(None, table=table) for _ in range(5)]
    refs = [DictStore() for _ in range(5)]
    for step, (v, msg, now) in enumerate(_stream(rng, 1500)):
        stores[v].receive(msg, now)
        refs[v].receive(msg, now)
        if rng.random() < 0.02:  # a reconnect: WELCOME clears the viewer's ghosts
            stores[v].clear()
            refs[v].ghosts.clear()
        if rng.random() < 0.05:
            cells = set(rng.sample(range(-3, 14), rng.randrange(0, 6)))
            stores[v].set_visible(cells)
            refs[v].visible = cells
        if step % 37 == 0:
            w = rng.randrange(5)
            assert stores[w].positions(now) == refs[w].positions(now)
        if step % 53 == 0:
            w = rng.randrange(5)
            stores[w].expire(now)
            refs[w].expire(now)
        if step % 41 == 0:  # the measure's one pass: what expires at `now` dropped, the rest read
            w = rng.randrange(5)
            rows, vers = table.live_rows(stores[w].col, now)
            refs[w].expire(now)
            ents = table.entity(rows).tolist()
            assert sorted(ents) == sorted(refs[w].ghosts)
            assert table.vseq[vers].tolist() == [refs[w].ghosts[e][0] for e in ents]
            assert rows.tolist() == table.rows_of(stores[w].col)[0].tolist()  # nothing left to expire
    for s, r in zip(stores, refs, strict=True):
        assert s.bad_payloads == r.bad_payloads
        got = {e: (g.seq, g.cells, g.expires, g.model, g.identity) for e, g in s.ghosts.items()}
        assert got == r.ghosts
    assert sum(r.bad_payloads for r in refs) > 0 and any(r.ghosts for r in refs)


def test_one_message_to_many_viewers_is_one_version_decoded_once():
    calls = []

    def dec(data):
        calls.append(data)
        return decode(data, None)

    table = GhostTable(None, dec)
    stores = [GhostStore(None, table=table) for _ in range(50)]
    m = Update(7, 3, (1, 2), 5000, encode(WorldModel(0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 1)))
    for s in stores:
        s.receive(m, 1.0)
    assert len(calls) == 1 and len(table.vmsg) == 1
    assert all(s.ghosts[7].seq == 3 for s in stores)


def test_a_frame_that_names_an_entity_twice_applies_in_order():
    gs = GhostStore(None)
    p = encode(WorldModel(0.0, 5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1))
    gs.table.receive(gs.col, [Update(1, 1, (1,), 5000, p), Leave(1), Update(1, 1, (1,), 5000, p),
                              Update(1, 2, (2,), 5000, p), Update(1, 1, (3,), 5000, p)], 0.0)
    assert gs.ghosts[1].seq == 2 and gs.ghosts[1].cells == (2,)


def test_bad_input_is_refused_whole_and_loses_nothing():
    gs = GhostStore(None)
    p = encode(WorldModel(0.0, 5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1))
    gs.receive(Update(1, 1, (1,), 5000, p), 0.0)
    for bad in ([Update(2, 1, (1,), 5000, p), Update(3, 2**70, (1,), 5000, p)],
                [Update(2, 1, (1,), 5000, p), "PING"],
                [Update(2**64, 1, (1,), 5000, p)]):
        with pytest.raises((ValueError, TypeError)):
            gs.table.receive(gs.col, bad, 0.0)
    with pytest.raises(ValueError):
        gs.receive(Update(4, 1, ("x",), 5000, p), 0.0)
    assert set(gs.ghosts) == {1}
    with pytest.raises(ValueError):
        gs.positions(math.nan)


def test_the_table_stays_bounded_under_churn():
    table = GhostTable(None)
    gs = GhostStore(None, table=table)
    p = encode(WorldModel(0.0, 5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1))
    for k in range(20_000):
        gs.receive(Update(k, 1, (1,), 1000, p), float(k))
        gs.receive(Leave(k - 3), float(k))
    assert len(gs) == 3
    assert len(table.vmsg) <= 8192 and table.held.shape[0] <= 8192
    assert np.all(table.held[:table._n_rows, 0][table.held[:table._n_rows, 0] >= 0] < len(table.vmsg))


def test_visible_cells_far_apart_need_no_mask_of_their_span():
    gs = GhostStore(None)
    p = encode(WorldModel(0.0, 5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1))
    gs.receive(Update(1, 1, (2**62,), 5000, p), 0.0)
    gs.receive(Update(2, 1, (-(2**62), 3), 5000, p), 0.0)
    gs.receive(Update(3, 1, (4,), 5000, p), 0.0)
    gs.set_visible({-(2**62), 2**62})  # a mask over that span would not fit in memory
    assert set(gs.positions(1.0)) == {1, 2}
    gs.set_visible({3, 4})
    assert set(gs.positions(1.0)) == {2, 3}
