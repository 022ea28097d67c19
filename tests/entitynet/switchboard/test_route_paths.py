"""The compiled per-PUBLISH route (`_fanout.route`) and the pure-Python one (`Switchboard._route_py`) send the
same messages to every client, whatever the clients do.

Why: the compiled route is an optimisation of the core's hottest method, never a second behaviour. Hypothesis
draws sequences of publishes (moving between cells, staying, stale), subscription changes, follows, identities,
unpublishes, disconnects and expiries, including a client that views the cells it publishes in; each sequence
runs once on each path, and after every step each client's drained messages, and every entity's viewer set,
must be the same.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from entitynet import protocol as P
from entitynet.switchboard import outbox
from tests.entitynet.switchboard_helpers import make, on_both_paths

N_CLIENTS = 5
N_CELLS = 6

cells = st.lists(st.integers(0, N_CELLS - 1), min_size=0, max_size=3, unique=True).map(tuple)
client = st.integers(0, N_CLIENTS - 1)
step = st.one_of(
    st.tuples(st.just("pub"), client, st.integers(0, 2), st.integers(0, 3), cells),
    st.tuples(st.just("sub"), client, cells, cells),
    st.tuples(st.just("follow"), client, st.integers(0, 20)),
    st.tuples(st.just("unfollow"), client, st.integers(0, 20)),
    st.tuples(st.just("privacy"), client, st.sampled_from([None, "a", "b"])),
    st.tuples(st.just("unpub"), client, st.integers(0, 2)),
    st.tuples(st.just("drop"), client),
    st.tuples(st.just("time"), st.floats(0.0, 3.0)),
)
# with states held between steps: a client's frame taken (at most n messages), a client closed by a fatal error
# with its states still queued behind its last word
held_step = st.one_of(
    step, step, step, step, step, step,  # (one_of draws its branches about evenly: mostly the usual steps)
    st.tuples(st.just("flush"), client, st.integers(1, 4)),
    st.tuples(st.just("fatal"), client),
)


def _run(steps: list[tuple], compiled: bool, hold: bool = False) -> list:
    """Play `steps` on a fresh switchboard on one path; what every client received after each step (with
    `hold`, only what the "flush" steps took, and everything at the end: states coalesce across steps)."""
    outbox.use_compiled(compiled)
    sb = make(n_cells=N_CELLS, grace_s=0.5)
    now = 0.0
    cids = []
    seqs: dict[tuple[int, int], int] = {}

    def hello(k: int) -> int:
        cid = sb.connect(now)
        sb.receive(cid, [P.Hello(P.PROTOCOL_VERSION, f"u{k}", sb.config.digest)], now)
        return cid

    cids = [hello(k) for k in range(N_CLIENTS)]
    log: list = []
    held: list = []  # outboxes of clients closed by a fatal error (their states wait behind the last word)
    for s in steps:
        kind = s[0]
        if kind == "time":
            now += s[1]
            sb.expire(now)
        else:
            k = s[1]
            cid = cids[k]
            if kind == "pub":
                _, _, local, back, cs = s
                seq = seqs.get((k, local), 0) + 1 - back  # back > 0: a stale or repeated seq, dropped
                seqs[(k, local)] = max(seq, seqs.get((k, local), 0))
                sb.receive(cid, [P.Publish(local, max(seq, 0), cs, 1000, b"p%d" % seq)], now)
            elif kind == "sub":
                sb.receive(cid, [P.Subscribe(s[2], s[3])], now)
            elif kind in ("follow", "unfollow"):
                eids = sorted(sb.entities)
                eid = eids[s[2] % len(eids)] if eids else P.LOCAL_ID_LIMIT + s[2]
                sb.receive(cid, [(P.Follow if kind == "follow" else P.Unfollow)(eid)], now)
            elif kind == "privacy":
                sb.receive(cid, [P.Privacy(s[2], None)], now)
            elif kind == "unpub":
                sb.receive(cid, [P.Unpublish(s[2])], now)
            elif kind == "drop":
                sb.disconnect(cid, now)
                cids[k] = hello(k)
            elif kind == "flush":
                ob = sb.outbox(cid)
                log.append(ob.drain(s[2]) if ob is not None else None)
            elif kind == "fatal":
                sb.protocol_error(cid, P.ProtocolError(P.ErrorCode.MALFORMED, "bad bytes"))
                held.append(sb.outbox(cid))
        if hold:
            log.append((sorted((e.local, e.owner.cid, sorted(e.viewers)) for e in sb.entities.values()),
                        dict(sb.stats)))
            continue
        sb.take_dirty()
        got = []
        for cid in cids:
            ob = sb.outbox(cid)
            got.append(ob.drain() if ob is not None else None)
        viewers = sorted((e.local, e.owner.cid, sorted(e.viewers)) for e in sb.entities.values())
        log.append((got, viewers, dict(sb.stats)))
    if hold:
        log.append([ob.drain() for ob in held + [sb.outbox(cid) for cid in cids] if ob is not None])
    return log


@pytest.mark.skipif(outbox.COMPILED is None or not hasattr(outbox.COMPILED, "route"),
                    reason="the compiled route was not built")
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(step, min_size=1, max_size=40))
def test_both_routes_send_the_same_messages(steps):
    fast, pure = on_both_paths(_run, steps)
    assert fast == pure


@pytest.mark.skipif(outbox.COMPILED is None or not hasattr(outbox.COMPILED, "route"),
                    reason="the compiled route was not built")
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(held_step, min_size=1, max_size=40))
def test_both_paths_send_the_same_messages_when_states_wait(steps):
    """States held across publishes, subscription changes, LEAVEs, expiries and closes (the compiled outboxes
    share an entity's bytes among its viewers: each must still get the bytes it was last given)."""
    fast, pure = on_both_paths(lambda s, compiled: _run(s, compiled, hold=True), steps)
    assert fast == pure


@pytest.mark.skipif(outbox.COMPILED is None or not hasattr(outbox.COMPILED, "route"),
                    reason="the compiled route was not built")
def test_the_compiled_route_is_used_and_exercised():
    """Not vacuous: the fixed sequence moves entities between watched cells (UPDATEs and LEAVEs on both
    paths), and the compiled path really runs `route` for new entities and `publish_run` (which routes in C
    without a Python call) for the updates of known ones (both counted through wrappers)."""
    steps = [("sub", 0, (0, 1), ()), ("sub", 1, (1, 2), ()), ("sub", 3, (3,), ()), ("pub", 2, 0, 0, (0,)),
             ("pub", 2, 0, 0, (1, 2)), ("pub", 2, 0, 0, (1, 2)), ("pub", 2, 0, 0, (3,)), ("pub", 3, 1, 0, (3,)),
             ("sub", 0, (3,), (0, 1)), ("pub", 2, 0, 0, (3,)), ("time", 2.0)]
    calls, runs = [], []
    real, real_run = outbox.COMPILED.route, outbox.COMPILED.publish_run
    was = outbox.compiled_in_use()

    def counting(*a):
        calls.append(1)
        return real(*a)

    def counting_run(sb, c, msgs, i, *a):
        j = real_run(sb, c, msgs, i, *a)
        runs.append(j - i)
        return j

    outbox.COMPILED.route, outbox.COMPILED.publish_run = counting, counting_run
    try:
        fast = _run(steps, True)
    finally:
        outbox.COMPILED.route, outbox.COMPILED.publish_run = real, real_run
        outbox.use_compiled(was)
    assert fast == _run(steps, False)
    outbox.use_compiled(was)
    sent = [m for got, _v, _s in fast for msgs in got if msgs for m in msgs]
    kinds = [P.decode_payload(P.payload_from_encoded([m]))[0] for m in sent]
    assert sum(isinstance(m, P.Update) for m in kinds) >= 6 and any(isinstance(m, P.Leave) for m in kinds)
    assert len(calls) >= 2 and sum(runs) >= 4  # two new entities routed by `route`, four updates by the run


@pytest.mark.skipif(outbox.COMPILED is None or not hasattr(outbox.COMPILED, "route"),
                    reason="the compiled route was not built")
def test_the_compiled_route_keeps_viewer_sets_out_of_the_collector():
    """A viewer set holds only client ids (no cycle possible): the compiled route untracks it, so young
    collections do not walk every moving entity's set (they made 15-30 ms pauses at the standard load). The set
    still works as a set (the subscription code adds and discards in it)."""
    import gc

    was = outbox.compiled_in_use()
    try:
        outbox.use_compiled(True)
        sb = make(n_cells=N_CELLS)
        viewer, owner = sb.connect(0.0), sb.connect(0.0)
        for cid in (viewer, owner):
            sb.receive(cid, [P.Hello(P.PROTOCOL_VERSION, "u", sb.config.digest)], 0.0)
        sb.receive(viewer, [P.Subscribe((1, 2), ())], 0.0)
        sb.receive(owner, [P.Publish(7, 1, (1,), 1000, b"x")], 0.0)
        (e,) = sb.entities.values()
        assert e.viewers == {viewer} and not gc.is_tracked(e.viewers)
        sb.receive(owner, [P.Publish(7, 2, (2,), 1000, b"y")], 0.0)  # moved: a new set, untracked too
        assert e.viewers == {viewer} and not gc.is_tracked(e.viewers)
        sb.receive(viewer, [P.Subscribe((), (1, 2))], 0.0)
        assert e.viewers == set()
    finally:
        outbox.use_compiled(was)


def _held_scenario(_steps, compiled: bool) -> list:
    """States that wait across publishes: a viewer closed by a fatal error, an entity unpublished, a viewer
    unsubscribing between two partial frames, one entity published fifty times; every frame decoded."""
    outbox.use_compiled(compiled)
    sb = make(n_cells=N_CELLS)

    def hello() -> int:
        cid = sb.connect(0.0)
        sb.receive(cid, [P.Hello(P.PROTOCOL_VERSION, "", sb.config.digest)], 0.0)
        sb.outbox(cid).drain()
        return cid

    owner, closed, partial, steady = hello(), hello(), hello(), hello()
    for v in (closed, partial, steady):
        sb.receive(v, [P.Subscribe((0, 1, 2), ())], 0.0)
    frames = []

    def take(cid: int, n: int | None = None) -> None:
        frames.append(P.decode_payload(P.payload_from_encoded(sb.outbox(cid).drain(n))))

    for local in (1, 2, 3):
        sb.receive(owner, [P.Publish(local, 1, (local - 1,), 10_000, b"first")], 0.0)
    box = sb.outbox(closed)
    sb.protocol_error(closed, P.ProtocolError(P.ErrorCode.MALFORMED, "bad bytes"))  # its states wait
    take(partial, 2)
    sb.receive(partial, [P.Subscribe((), (0,))], 0.0)  # entity 1 left its view: a LEAVE replaces the UPDATE
    for seq in range(2, 52):
        sb.receive(owner, [P.Publish(1, seq, (0,), 10_000, b"s%d" % seq),
                           P.Publish(2, seq, (1,), 10_000, b"s%d" % seq)], 0.0)
    sb.receive(owner, [P.Unpublish(3)], 0.0)  # gone with its state pending
    take(partial)
    take(steady)
    frames.append(P.decode_payload(P.payload_from_encoded(box.drain())))
    return frames


def test_states_that_wait_are_the_same_on_both_paths():
    fast, pure = on_both_paths(_held_scenario, None)
    assert fast == pure
    closed = pure[-1]
    assert type(closed[0]) is P.Error and [m.payload for m in closed[1:]] == [b"first"] * 3  # what it was given
    kinds = [[(type(m).__name__, getattr(m, "payload", None)) for m in frame] for frame in pure[1:3]]
    # the partial viewer: 3's UPDATE replaced by its LEAVE in its place, 1's LEAVE, 2's UPDATEs coalesced
    assert kinds[0] == [("Leave", None), ("Leave", None), ("Update", b"s51")]
    assert kinds[1] == [("Update", b"s51"), ("Update", b"s51"), ("Leave", None)]  # the steady viewer
