"""Property test: after any sequence of operations every client's view (built only from what it received)
equals what the tables say it should see: the latest state of every entity sharing a cell or followed."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from entitynet import protocol as P
from tests.entitynet.switchboard_helpers import join, make, recv

N_CELLS = 6
N_CLIENTS = 4
cells = st.lists(st.integers(0, N_CELLS - 1), min_size=1, max_size=3, unique=True).map(tuple)
ops = st.lists(
    st.one_of(
        st.tuples(st.just("pub"), st.integers(0, N_CLIENTS - 1), st.integers(0, 2), cells,
                  st.integers(0, 3000)),
        st.tuples(st.just("sub"), st.integers(0, N_CLIENTS - 1), cells, cells),
        st.tuples(st.just("follow"), st.integers(0, N_CLIENTS - 1), st.integers(0, 20)),
        st.tuples(st.just("unfollow"), st.integers(0, N_CLIENTS - 1), st.integers(0, 20)),
        st.tuples(st.just("unpub"), st.integers(0, N_CLIENTS - 1), st.integers(0, 2)),
        st.tuples(st.just("tick"), st.floats(0, 3)),
        st.tuples(st.just("read"), st.integers(0, N_CLIENTS - 1)),
    ),
    max_size=40,
)


@settings(max_examples=300, deadline=None)
@given(ops)
def test_views_match_tables(ops):
    sb = make(n_cells=N_CELLS, grace_s=1.0)
    now = 0.0
    cids = [join(sb) for _ in range(N_CLIENTS)]
    views: dict[int, dict[int, P.Update]] = {c: {} for c in cids}
    seqs: dict[tuple[int, int], int] = {}

    def read(c):
        for m in recv(sb, c):
            if isinstance(m, P.Update):
                views[c][m.entity] = m
            elif isinstance(m, P.Leave):
                views[c].pop(m.entity, None)

    for op in ops:
        kind = op[0]
        if kind == "pub":
            _, ci, local, cs, val = op
            seqs[(ci, local)] = seqs.get((ci, local), 0) + 1
            sb.receive(cids[ci], [P.Publish(local, seqs[(ci, local)], cs, val, b"%d" % seqs[(ci, local)])], now)
        elif kind == "sub":
            sb.receive(cids[op[1]], [P.Subscribe(op[2], op[3])], now)
        elif kind in ("follow", "unfollow"):
            ents = sorted(sb.entities)
            if ents:
                eid = ents[op[2] % len(ents)]
                sb.receive(cids[op[1]], [(P.Follow if kind == "follow" else P.Unfollow)(eid)], now)
        elif kind == "unpub":
            sb.receive(cids[op[1]], [P.Unpublish(op[2])], now)
        elif kind == "tick":
            now += op[1]
            sb.expire(now)
        else:
            read(cids[op[1]])
    for c in cids:
        read(c)
    for c in cids:
        st_c = sb.clients[c]
        expect = {
            eid: e for eid, e in sb.entities.items()
            if e.owner is not st_c and (not st_c.subs.isdisjoint(e.cells) or c in e.followers)
        }
        assert set(views[c]) == set(expect)
        for eid, e in expect.items():
            u = views[c][eid]
            assert (u.seq, u.cells, u.payload) == (e.seq, e.cells, e.payload)
    # occupancy table consistent with entities
    occ = {}
    for eid, e in sb.entities.items():
        for cell in e.cells:
            occ.setdefault(cell, set()).add(eid)
    assert occ == sb.occupants
