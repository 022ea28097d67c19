"""The compiled switchboard's id sets (`_fanout.ViewerSet`: subscribers and viewers; `_fanout.CidMarks`: the dirty
marks; entitynet/switchboard/_viewsets.pxi) behave like the Python sets they replace, and the core forwards the
same messages with them as the reference does, with client ids spread over many 64-bit words and reused slots.

Why: these sets are the core's only home of who subscribes to a cell, who knows an entity and who has news, on
the compiled path; a set that lost or invented a member would send a LEAVE too many or an UPDATE too few. The
reference (`set`, ENTITYNET_PURE_PYTHON=1) is the oracle: hypothesis draws operations, hostile values included
(negative, huge, not ints), and compares every observable after each one.
"""

from __future__ import annotations

import pickle

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from entitynet import protocol as P
from entitynet.switchboard import outbox
from tests.entitynet.switchboard_helpers import make, on_both_paths

_fanout = pytest.importorskip("entitynet.switchboard._fanout", reason="the compiled switchboard was not built")
ViewerSet, CidMarks = _fanout.ViewerSet, _fanout.CidMarks

# ids around word boundaries, far apart, and at the bounds; then values a client id never is
good_id = st.one_of(st.integers(0, 200), st.sampled_from([63, 64, 127, 128, 4095, 4096, (1 << 28) - 1]))
bad_id = st.one_of(st.integers(max_value=-1), st.integers(min_value=1 << 40), st.just(1 << 70),
                   st.sampled_from([None, "7", 1.0, float("nan"), b"\x01"]))
op = st.one_of(
    st.tuples(st.just("add"), good_id), st.tuples(st.just("add"), good_id), st.tuples(st.just("add"), bad_id),
    st.tuples(st.just("discard"), st.one_of(good_id, bad_id)),
    st.tuples(st.just("in"), st.one_of(good_id, bad_id)),
    st.tuples(st.just("update"), st.lists(good_id, max_size=20)),
    st.tuples(st.just("ior"), st.lists(good_id, max_size=20), st.booleans()),
    st.tuples(st.just("take")),
)


def _observe(s) -> tuple:
    return len(s), bool(s), sorted(s)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(op, max_size=60), st.sampled_from(["viewers", "marks"]))
def test_the_compiled_sets_behave_like_python_sets(ops, kind):
    ref: set = set()
    got = ViewerSet() if kind == "viewers" else CidMarks()
    for o in ops:
        name = o[0]
        if name == "add":
            try:
                got.add(o[1])
                ok = True
            except ValueError:
                ok = False
            assert ok == (type(o[1]) is int and 0 <= o[1] < (1 << 28))  # (none drawn in [2**28, 2**40))
            if ok:
                ref.add(o[1])
        elif name == "discard":
            got.discard(o[1])
            if type(o[1]) is int:
                ref.discard(o[1])
        elif name == "in":
            assert (o[1] in got) == (type(o[1]) is int and o[1] in ref)
        elif name == "update":
            if kind == "viewers":
                got.update(o[1])
                ref.update(o[1])
        elif name == "take":
            if kind == "marks":  # the flush's `take_dirty`: ascending ids, the marks emptied in place
                assert got.take() == sorted(ref)
                ref.clear()
        else:
            other = ViewerSet(o[1]) if o[2] else set(o[1])
            if kind == "marks":
                got |= other
                ref |= set(o[1])
        assert _observe(got) == _observe(ref)
        assert got == ref
    if kind == "viewers":
        assert got - {min(ref, default=0)} == ref - {min(ref, default=0)}
        assert pickle.loads(pickle.dumps(got)) == ref
        assert ViewerSet(iter(got)) == got
        with pytest.raises(TypeError):
            hash(got)


def test_iterating_a_set_while_changing_it_sees_a_snapshot():
    s = ViewerSet(range(0, 300, 7))
    for v in s:
        s.discard(v)
        s.add(v + 1000)
    assert sorted(s) == [v + 1000 for v in range(0, 300, 7)]
    m = CidMarks([1, 65, 700])
    for v in m:
        m.discard(v)
    assert len(m) == 0 and not m and list(m) == []


def test_marks_discarded_without_a_take_leave_nothing_behind():
    """A reader answering PINGs itself marks and discards (`written_out`) with no flush and no `take_dirty` in
    between: the list of touched words grew by one entry per reply without bound (a reviewer's finding)."""
    m = CidMarks()
    for i in range(10_000):
        m.add(i % 3)
        m.discard(i % 3)
    assert m.nt == 0 and len(m) == 0 and m.take() == []
    m.add(5)
    m.add(700)
    m.discard(5)
    assert m.nt == 2 and list(m) == [700]  # while a mark stands its word is kept, and the emptied one with it
    assert m.take() == [700] and m.nt == 0


# -------------------------------------------------------------------------------------- the core with many words
N_CELLS = 5
client = st.integers(0, 11)
cells = st.lists(st.integers(0, N_CELLS - 1), max_size=3, unique=True).map(tuple)
step = st.one_of(
    st.tuples(st.just("pub"), client, st.integers(0, 1), cells),
    st.tuples(st.just("pub"), client, st.integers(0, 1), cells),
    st.tuples(st.just("sub"), client, cells, cells),
    st.tuples(st.just("drop"), client),  # disconnect; the client comes back under a new id (its slot reused)
    st.tuples(st.just("unpub"), client, st.integers(0, 1)),
    st.tuples(st.just("follow"), client, st.integers(0, 30)),
)


def _play(steps: list[tuple], compiled: bool) -> list:
    """Twelve clients whose ids lie in different 64-bit words (filler connections come and go between them, so
    ids jump by 50-150 and outbox slots are reused); what each received after every step, and the tables."""
    outbox.use_compiled(compiled)
    sb = make(n_cells=N_CELLS)
    seq = [0]

    def hello() -> int:
        for _ in range(50 + 10 * (len(sb.clients) % 11)):
            sb.disconnect(sb.connect(0.0), 0.0)  # ids skipped (their slots freed and reused)
        cid = sb.connect(0.0)
        sb.receive(cid, [P.Hello(P.PROTOCOL_VERSION, "u", sb.config.digest)], 0.0)
        return cid

    cids = [hello() for _ in range(12)]
    log: list = []
    for s in steps:
        k = s[1]
        c = cids[k]
        if s[0] == "pub":
            seq[0] += 1
            sb.receive(c, [P.Publish(s[2], seq[0], s[3], 10_000, b"p")], 0.0)
        elif s[0] == "sub":
            sb.receive(c, [P.Subscribe(s[2], s[3])], 0.0)
        elif s[0] == "drop":
            sb.disconnect(c, 0.0)
            cids[k] = hello()
        elif s[0] == "unpub":
            sb.receive(c, [P.Unpublish(s[2])], 0.0)
        else:
            eids = sorted(sb.entities)
            if eids:
                sb.receive(c, [P.Follow(eids[s[2] % len(eids)])], 0.0)
        dirty = sorted(sb.take_dirty())
        got = []
        for i, cid in enumerate(cids):
            ob = sb.outbox(cid)
            got.append((i, ob.drain() if ob is not None and len(ob) else []))
        log.append((dirty, [(i, d) for i, d in got if d],
                    sorted((e.local, e.owner.cid, sorted(e.viewers)) for e in sb.entities.values()),
                    sorted((cell, sorted(s)) for cell, s in sb.subscribers.items()), dict(sb.stats)))
    return [cids, log]


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(step, max_size=40))
def test_both_paths_agree_with_ids_over_many_words(steps):
    compiled, pure = on_both_paths(_play, steps)
    assert compiled == pure


def test_the_compiled_switchboard_uses_the_compiled_sets():
    was = outbox.compiled_in_use()
    try:
        outbox.use_compiled(True)
        sb = make(n_cells=N_CELLS)
        assert type(sb._dirty) is CidMarks and type(sb.take_dirty()) is list and type(sb._dirty) is CidMarks
        outbox.use_compiled(False)
        assert type(make(n_cells=N_CELLS)._dirty) is set
    finally:
        outbox.use_compiled(was)


def _two_slow_consumers(_steps, compiled: bool) -> tuple:
    """Two viewers over their outbox bound in one flush, whose ids (1 and 9) a Python set of 8 slots keeps in the
    order 9, 1 (the reviewer's case): dropping one first changes what the other's entities leave."""
    outbox.use_compiled(compiled)
    sb = make(n_cells=10, max_pending=2)

    def hello() -> int:
        c = sb.connect(0.0)
        sb.receive(c, [P.Hello(P.PROTOCOL_VERSION, "", "d")], 0.0)
        return c

    a = hello()
    for _ in range(7):
        sb.disconnect(sb.connect(0.0), 0.0)
    b, pub = hello(), hello()
    sb.take_dirty()
    for c in (a, b, pub):
        sb.outbox(c).drain()
    sb.receive(a, [P.Subscribe((0,), ())], 0.0)
    sb.receive(b, [P.Subscribe((1,), ())], 0.0)
    sb.receive(b, [P.Ping(1), P.Publish(0, 1, (0,), 10_000, b"b")], 0.0)  # b has news before a
    sb.receive(pub, [P.Publish(i, 1, (0, 1), 10_000, b"p") for i in range(3)], 0.0)  # both over the bound
    sb.take_dirty()
    return (a, b), sb.stats["leaves"], sb.stats["slow_consumers"], sb.outbox(pub).drain()


def test_slow_consumers_are_dropped_in_the_same_order_on_both_paths():
    compiled, pure = on_both_paths(_two_slow_consumers, None)
    assert compiled[0] == (1, 9) and compiled[2] == 2
    assert compiled == pure
