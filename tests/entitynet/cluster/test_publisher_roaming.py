"""Publishers roam with a hysteresis (entitynet.cluster.roaming): served on by the shard they are on while they
stay within a band of its regions (in cell hops) and for at most `publisher_linger_s`, seen meanwhile by the
region owner's viewers as mirrors; REDIRECTed once beyond the band or the time. Sans-IO, over the in-memory bus.

Cells 0..49 are region 0, 50..99 region 1, adjacent in a line: with the default margin of 2 cells, shard 0 serves
its publishers in cells 0..50, shard 1 in 49..99."""

from __future__ import annotations

import math

import pytest

from entitynet import protocol as P
from entitynet.cluster.core import ClusterCore
from entitynet.cluster.roaming import region_bands
from tests.entitynet.switchboard_helpers import join, make, of, pub, recv

from .shard_helpers import N_CELLS, two_regions
from .test_core import Bus

LINE = [[c for c in (i - 1, i + 1) if 0 <= c < N_CELLS] for i in range(N_CELLS)]


class Seen:
    """What one viewer shows: server id -> cells, with a check that it never shows the publisher twice."""

    def __init__(self, sb, cid):
        self.sb, self.cid = sb, cid
        self.visible: dict[int, tuple[int, ...]] = {}
        self.updates: list[int] = []  # the seq numbers it received

    def read(self) -> None:
        for m in recv(self.sb, self.cid):
            if isinstance(m, P.Update):
                self.visible[m.entity] = m.cells
                self.updates.append(m.seq)
            elif isinstance(m, P.Leave):
                self.visible.pop(m.entity, None)
        assert len(self.visible) <= 1, f"one publisher shown twice: {self.visible}"


def watch(bus: Bus, i: int, cells: tuple[int, ...]) -> Seen:
    """A viewer on shard i subscribed to `cells` at t=0.5 (NATS interest and snapshot settled)."""
    sb = bus.sbs[i]
    cid = join(sb)
    sb.receive(cid, [P.Subscribe(cells, ())], 0.5)
    bus.run(0.5)
    return Seen(sb, cid)


def banded_bus(**kw) -> Bus:
    kw.setdefault("cell_adjacency", LINE)
    b = Bus(2, **kw)
    b.run(0.0)
    b.run(0.5)  # heartbeats heard: addresses known
    return b


def step(bus: Bus, cid: int, seq: int, cell: int, now: float, sb_index: int = 0) -> list[P.Message]:
    sb = bus.sbs[sb_index]
    sb.receive(cid, [pub(1, seq, (cell,))], now)
    bus.run(now)
    return recv(sb, cid)


def start(bus: Bus, i: int, cell: int, now: float) -> int:
    """A publisher joins shard i at `now` with its first state in `cell`; near a border that PUBLISH is held
    until the neighbour's next heartbeat (it might still be serving it: `admit`), so run the bus to then."""
    sb = bus.sbs[i]
    cid = join(sb, now=now)
    sb.receive(cid, [pub(1, 1, (cell,))], now)
    bus.run(now)
    bus.run(now + 0.5)
    assert sb.clients[cid].entities, "first PUBLISH not admitted within a heartbeat"
    recv(sb, cid)
    return cid


def test_a_publisher_dithering_on_the_border_is_not_redirected_and_every_viewer_sees_each_state():
    bus = banded_bus()
    a, b = bus.sbs
    viewers = [watch(bus, 1, (49, 50)), watch(bus, 0, (49, 50))]  # both sides of the border, from both shards
    p = start(bus, 0, 49, 0.5)
    for v in viewers:
        v.read()  # (unread, an UPDATE would be coalesced with the next one of the same entity)
    t, seq = 1.5, 1
    for cell in [49, 50] * 8:  # 16 crossings in 16 s, well within the linger
        seq += 1
        assert not of(step(bus, p, seq, cell, t), P.Redirect)
        for v in viewers:
            v.read()
            assert list(v.visible.values()) == [(cell,)]  # every state, in region 0 or 1, at both viewers
        t += 1.0
    assert viewers[0].updates == viewers[1].updates == list(range(1, seq + 1))
    assert bus.cores[0].stats["redirects"] == 0 and bus.cores[0].stats["publishers_in_band"] == 8
    assert b.counts()["entities"] == 1 and a.counts()["entities"] == 1  # b: the mirror


def test_a_publisher_moving_deep_into_another_region_is_redirected_at_once_and_shown_once():
    bus = banded_bus()
    b = bus.sbs[1]
    viewer = watch(bus, 1, (50, 51))
    p = start(bus, 0, 49, 0.5)  # (a first PUBLISH outside the regions would be REDIRECTed before it is served)
    assert not of(step(bus, p, 2, 50, 1.5), P.Redirect)  # one cell over: served by a, b's viewer sees the mirror
    viewer.read()
    assert viewer.updates == [2]
    red = of(step(bus, p, 3, 51, 2.0), P.Redirect)  # two cells over: beyond the band
    assert [(r.shard, r.address) for r in red] == [(1, "h:1")]
    viewer.read()
    assert viewer.visible == {}  # the old id left before the client can re-publish on b
    q = join(b, now=2.1)
    assert not of(step(bus, q, 4, 51, 2.1, sb_index=1), P.Redirect)
    viewer.read()
    assert list(viewer.visible.values()) == [(51,)]


def test_a_publisher_parked_in_the_band_is_redirected_after_the_linger():
    bus = banded_bus(publisher_linger_s=5.0)
    p = start(bus, 0, 49, 0.5)
    t = 2.0
    for seq in range(2, 7):  # out since t=2.0, at 50 (one cell over) until the linger has passed
        assert not of(step(bus, p, seq, 50, t), P.Redirect)
        t += 1.0
    assert t == 7.0
    assert [r.shard for r in of(step(bus, p, 7, 50, t), P.Redirect)] == [1]  # 5 s out: moved on


def test_coming_back_resets_the_linger():
    bus = banded_bus(publisher_linger_s=3.0)
    p = start(bus, 0, 49, 0.5)
    seq = 1
    for t in range(2, 13):  # two seconds out, one back in, again and again: never out for 3 s
        seq += 1
        assert not of(step(bus, p, seq, 49 if t % 3 == 0 else 50, float(t)), P.Redirect)


def test_without_an_adjacency_a_publisher_is_redirected_as_soon_as_it_is_out():
    bus = Bus(2)
    bus.run(0.0)
    bus.run(0.5)
    p = join(bus.sbs[0], now=0.5)
    step(bus, p, 1, 49, 0.9)  # admitted at once: without bands no neighbour can be serving it
    assert [r.shard for r in of(step(bus, p, 2, 50, 1.0), P.Redirect)] == [1]


def test_a_shard_dying_while_serving_a_neighbours_entity():
    bus = banded_bus()
    b = bus.sbs[1]
    viewer = watch(bus, 1, (50,))
    p = start(bus, 0, 49, 0.5)
    step(bus, p, 2, 50, 1.5)  # in region 1, served by shard 0
    viewer.read()
    assert len(viewer.visible) == 1
    bus.down = {0}
    bus.run(2.5)
    viewer.read()
    assert len(viewer.visible) == 1  # not declared dead yet: its mirror stays until then
    bus.run(3.6)  # shard 0 silent for dead_after_s (2 s): its mirror leaves at once
    viewer.read()
    assert viewer.visible == {}
    q = join(b, now=3.7)  # its client fails over to shard 1, the region's owner, and is served there
    assert not of(step(bus, q, 3, 50, 3.7, sb_index=1), P.Redirect)
    viewer.read()
    assert list(viewer.visible.values()) == [(50,)]


def test_ownership_moves_the_band():
    """Once shard 1 is dead shard 0 owns region 1: a publisher there is at home, however deep."""
    bus = banded_bus()
    a = bus.sbs[0]
    bus.down = {1}
    bus.run(3.1)
    p = join(a, now=3.2)
    step(bus, p, 1, 49, 3.2)
    assert not of(step(bus, p, 2, 90, 3.3), P.Redirect)
    assert bus.cores[0].out_since == {}


def test_gone_publishers_are_forgotten():
    bus = banded_bus()
    a = bus.sbs[0]
    p = start(bus, 0, 49, 0.5)
    step(bus, p, 2, 50, 1.5)
    assert p in bus.cores[0].out_since
    a.disconnect(p, 1.6)
    bus.run(2.1)  # the next heartbeat's tick
    assert bus.cores[0].out_since == {}


@pytest.mark.parametrize("adjacency, margin, linger, match", [
    (LINE[:-1], 2, 30.0, "99 cells"),
    ([*LINE[:-1], [100]], 2, 30.0, "outside the map"),
    ([*LINE[:-1], [-1]], 2, 30.0, "outside the map"),
    ([*LINE[:-1], None], 2, 30.0, "not a list"),
    ([*LINE[:-1], ["x"]], 2, 30.0, "not a list"),
    ([*LINE[:-1], [98.0]], 2, 30.0, "not a list"),
    ([*LINE[:-1], [math.inf]], 2, 30.0, "not a list"),
    (7, 2, 30.0, "one per cell"),
    (LINE, 0, 30.0, "margin"),
    (LINE, True, 30.0, "margin"),
    (LINE, 2.5, 30.0, "margin"),
    (LINE, 2, -1.0, "linger"),
    (LINE, 2, math.nan, "linger"),
    (LINE, 2, math.inf, "linger"),
    (LINE, 2, "5", "linger"),
])
def test_a_bad_band_configuration_is_refused_at_start(adjacency, margin, linger, match):
    with pytest.raises(ValueError, match=match):
        ClusterCore(make(), two_regions(2), 0, "h:0", now=0.0, inbox="_INBOX.0", cell_adjacency=adjacency,
                    publisher_margin_cells=margin, publisher_linger_s=linger)


def test_region_bands_walk_the_adjacency():
    bands = region_bands([0, 0, 1, 1, 1], [[1], [0, 2], [1, 3], [2, 4], [3]], 3)
    assert bands.tolist() == [[True, True, True, True, False], [True, True, True, True, True]]
    assert region_bands([0, 1], [[1], [0]], 1).tolist() == [[True, False], [False, True]]
    assert region_bands([0, 1, 1], [[1], [0, 2], [1]], 10**9).tolist() == [[True] * 3, [True] * 3]
    assert region_bands([0, 0], [[1], [0]], 2, regions=3).tolist() == [[True, True], [False, False], [False, False]]


def test_a_region_without_cells_has_an_empty_band():
    """A map whose last region got no cells (regions.shards beyond the largest region in use): no IndexError."""
    regions = two_regions(2)
    regions.cell_region[:] = 0  # region 1 owns nothing
    core = ClusterCore(make(), regions, 1, "h:1", now=0.0, inbox="_INBOX.1", cell_adjacency=LINE)
    assert core._near_cells(core._owners(0.0)) == [False] * N_CELLS
    assert not core._in_band_of_unsure_shard((10,), [0, 1], 0.0, 0.0)


def test_a_client_failing_over_from_a_neighbour_that_served_it_is_held_until_that_neighbour_is_decided():
    """Shard 1 serves a publisher in cell 49 (region 0, in its band) and dies; the client fails over to shard 0,
    whose region holds it. Admitted at once it would be shown beside shard 1's copy until shard 1 is declared
    dead, so its first PUBLISH waits for that (and is then served without a new PUBLISH)."""
    bus = banded_bus()
    a = bus.sbs[0]
    viewer = watch(bus, 0, (49,))
    p = start(bus, 1, 50, 0.5)
    assert not of(step(bus, p, 2, 49, 1.5, sb_index=1), P.Redirect)  # one cell into region 0: served by b
    viewer.read()
    assert list(viewer.visible.values()) == [(49,)]
    bus.down = {1}
    q = join(a, now=1.7)  # b not heard since (quiet from 2.5 on), not yet dead
    a.receive(q, [pub(1, 3, (49,))], 1.7)
    bus.run(1.7)
    bus.run(2.7)
    viewer.read()
    assert a.counts()["entities"] == 1 and bus.cores[0].stats["admissions_deferred"] >= 1  # only b's copy
    bus.run(3.6)  # b declared dead: its copy leaves, the held PUBLISH is served here
    viewer.read()
    assert list(viewer.visible.values()) == [(49,)] and viewer.updates[-1] == 3
    assert not of(recv(a, q), P.Redirect)


def test_a_first_publish_near_a_live_neighbour_waits_at_most_a_heartbeat_and_one_deep_inside_none():
    bus = banded_bus()
    a = bus.sbs[0]
    p = join(a, now=0.6)
    a.receive(p, [pub(1, 1, (49,))], 0.6)
    assert a.counts()["entities"] == 0  # b was last heard at 0.5: it might be serving this client
    bus.run(1.0)  # b's heartbeat: alive, so not serving it
    assert a.counts()["entities"] == 1
    q = join(a, now=1.1)
    a.receive(q, [pub(1, 1, (10,))], 1.1)
    assert a.counts()["entities"] == 2


def _shown(sb, cid, visible: dict[int, tuple[int, ...]]) -> list[tuple[int, ...]]:
    """Apply a viewer's messages to `visible` (server id -> cells) and return the cells shown, sorted."""
    for m in recv(sb, cid):
        if isinstance(m, P.Update):
            visible[m.entity] = m.cells
        elif isinstance(m, P.Leave):
            visible.pop(m.entity, None)
    return sorted(visible.values())


@pytest.mark.parametrize("order", [(2, 1), (1, 2)])
def test_a_multi_entity_connection_failing_over_from_a_neighbour_is_never_shown_twice(order):
    """Shard 1 serves a connection with one entity in its band (49) and one deep in region 0 (10): a shard
    serves every entity of a connection while one is in its band. It dies; the client fails over to shard 0
    and re-publishes both, in either order. Neither may be shown beside shard 1's copies until shard 1 is
    declared dead: the hold judges the connection's cells, and an entity admitted before its sibling showed
    the connection to be unsure is taken back."""
    bus = banded_bus()
    a, b = bus.sbs
    viewer = watch(bus, 0, (10, 49))
    visible: dict[int, tuple[int, ...]] = {}
    p = join(b, now=0.5)
    b.receive(p, [pub(1, 1, (50,)), pub(2, 1, (60,))], 0.5)
    bus.run(0.5)
    bus.run(1.0)
    b.receive(p, [pub(1, 2, (49,)), pub(2, 2, (10,))], 1.5)
    bus.run(1.5)
    assert _shown(a, viewer.cid, visible) == [(10,), (49,)]  # b's two, as mirrors on a
    bus.down = {1}
    q = join(a, now=1.7)
    cells = {1: (49,), 2: (10,)}
    a.receive(q, [pub(local, 3, cells[local]) for local in order], 1.7)
    for t in (1.7, 2.2, 2.7, 3.2, 3.6, 4.0):
        bus.run(t)
        assert _shown(a, viewer.cid, visible) == [(10,), (49,)], t  # two entities, two ids, never four
    assert len(a.clients[q].entities) == 2 and a.counts()["entities"] == 2  # served on a once b is dead
    assert not of(recv(a, q), P.Redirect)


def test_a_silent_entity_parked_in_the_band_is_redirected_when_the_linger_ends():
    """An entity with a long validity that then sends only PINGs: its linger ends from `tick`, not at a
    PUBLISH that may not come for hours."""
    bus = banded_bus(publisher_linger_s=5.0)
    a = bus.sbs[0]
    p = start(bus, 0, 49, 0.5)
    a.receive(p, [pub(1, 2, (50,), validity_ms=3_600_000)], 1.5)  # one cell over, out since 1.5
    bus.run(1.5)
    assert bus.cores[0].next_deadline() <= 6.5
    t = 1.5
    while t < 6.0:  # up to 6.0: 4.5 s out
        t += 0.5
        a.receive(p, [P.Ping(0)], t)
        bus.run(t)
        assert not of(recv(a, p), P.Redirect), t
    bus.run(6.5)
    assert [r.shard for r in of(recv(a, p), P.Redirect)] == [1]
    assert bus.cores[0].out_since == {} and a.counts()["entities"] == 0


def test_a_linger_that_cannot_redirect_now_is_tried_again_a_heartbeat_later_not_in_a_busy_loop():
    bus = banded_bus(publisher_linger_s=1.0)
    core = bus.cores[0]
    p = start(bus, 0, 49, 0.5)
    step(bus, p, 2, 50, 1.5)
    bus.down = {1}  # shard 1 goes quiet: no REDIRECT goes to it
    bus.run(2.6)
    assert p in core.out_since and core.stats["redirects"] == 0
    assert core.next_deadline() > 2.6  # not due again at once


def test_a_held_first_publish_that_runs_out_is_forgotten_with_its_connection():
    """A first PUBLISH held near a border whose validity runs out before it is judged again is dropped, and
    nothing of its connection is kept: not while it lives on (once every peer was heard), not after it left."""
    bus = banded_bus()
    a = bus.sbs[0]
    core = bus.cores[0]
    p = join(a, now=0.6)
    a.receive(p, [pub(1, 1, (49,), validity_ms=300)], 0.6)
    assert core.held and p in core.first_publish_at
    bus.run(1.0)  # b heard: the PUBLISH would be admitted, but it ran out at 0.9
    assert a.counts()["entities"] == 0 and core.held == {}
    bus.run(1.5)
    assert core.first_publish_at == {}
    q = join(a, now=1.6)
    a.receive(q, [pub(1, 1, (49,), validity_ms=300)], 1.6)
    assert q in core.first_publish_at
    a.disconnect(q, 1.7)
    bus.run(2.0)
    assert core.held == {} and core.first_publish_at == {}


def test_a_fleet_is_judged_as_before_not_taken_back():
    """A connection with more than `max_redirect_entities` entities never roamed by the band: a new entity of it
    near an unsure neighbour is admitted as before, and nothing of it is taken back."""
    bus = banded_bus()
    a = bus.sbs[0]
    core = bus.cores[0]
    p = join(a, now=0.6)
    a.receive(p, [pub(i, 1, (10 + i,)) for i in range(core.max_redirect_entities + 1)], 0.6)
    assert len(a.clients[p].entities) == core.max_redirect_entities + 1  # deep in region 0: admitted at once
    a.receive(p, [pub(99, 1, (49,))], 0.7)  # b not heard since: a smaller connection would be held
    assert len(a.clients[p].entities) == core.max_redirect_entities + 2 and core.stats["admissions_taken_back"] == 0


def test_a_client_redirected_after_the_linger_is_served_at_its_new_shard_within_a_round_trip():
    """REDIRECTed after the linger, the client is still within its old shard's band: its new shard holds its
    first PUBLISH (it cannot tell it from a client failing over) but asks the old shard for a heartbeat at once,
    so it is served as soon as that answer comes, not at the old shard's next scheduled heartbeat."""
    bus = banded_bus(publisher_linger_s=2.0)
    b = bus.sbs[1]
    p = start(bus, 0, 49, 0.5)
    step(bus, p, 2, 50, 1.2)  # one cell over: lingering
    for t in (1.7, 2.2, 2.7, 3.2):
        bus.run(t)
    assert [r.shard for r in of(recv(bus.sbs[0], p), P.Redirect)] == [1]  # the linger ended at 3.2
    q = join(b, now=3.4)  # a's last heartbeat was at 3.2, before the client came
    b.receive(q, [pub(1, 3, (50,))], 3.4)
    assert b.counts()["entities"] == 0  # held: a could be a shard that died serving it
    bus.run(3.41)  # a answers b's ask: a NATS round trip (here 10 ms) later, not at its next heartbeat (3.7)
    assert b.counts()["entities"] == 1 and bus.cores[1].stats["heartbeats_asked"] == 1
