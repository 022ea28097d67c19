"""Outbox.drain: bounded by count and bytes, never aliasing the control FIFO (issue 9, items 1 and 2)."""

from __future__ import annotations

from entitynet.switchboard import Outbox


def _filled(n_states: int, n_control: int = 0, size: int = 10) -> Outbox:
    ob = Outbox(50_000, 1000)
    for i in range(n_control):
        ob.put_control(b"c%d" % i + b"." * (size - 2))
    for i in range(n_states):
        ob.put_state(i, b"s%d" % i + b"." * (size - 2))
    return ob


def test_drain_with_empty_control_returns_a_new_list_and_leaves_control_empty():
    ob = _filled(5)
    out = ob.drain(3)
    out.append(b"appended by the shell")  # the list is the caller's: it must not alias the control FIFO
    assert len(out) == 4 and not ob.has_control and ob.n_states == 2
    out2 = ob.drain(3)
    assert len(out2) == 2 and not ob.has_control and len(ob) == 0
    assert [m[:2] for m in out[:3] + out2] == [b"s0", b"s1", b"s2", b"s3", b"s4"]


def test_draining_many_batches_never_grows_control():
    """A viewer of more than max_batch entities: every batch leaves the control FIFO empty (no false overflow)."""
    ob = _filled(5000)
    got = 0
    while len(ob):
        out = ob.drain(700)
        got += len(out)
        assert not ob.has_control and not ob.over_bounds
    assert got == 5000


def test_drain_bounded_by_bytes_keeps_order_and_the_rest():
    ob = _filled(10, n_control=3, size=100)
    out = ob.drain(1000, max_bytes=450)
    assert [m[:2] for m in out] == [b"c0", b"c1", b"c2", b"s0"]
    assert ob.n_states == 9 and not ob.has_control
    out = ob.drain(1000, max_bytes=250)
    assert [m[:2] for m in out] == [b"s1", b"s2"]
    out = ob.drain(None, max_bytes=10_000)
    assert len(out) == 7 and len(ob) == 0


def test_drain_bounded_by_bytes_inside_control():
    ob = _filled(2, n_control=5, size=100)
    out = ob.drain(1000, max_bytes=250)
    assert len(out) == 2 and ob.n_control == 3 and ob.n_states == 2
    assert [m[:2] for m in ob.drain()] == [b"c2", b"c3", b"c4", b"s0", b"s1"]


def test_a_single_message_larger_than_the_byte_bound_still_goes():
    ob = Outbox(10, 10)
    ob.put_state(1, b"x" * 500)
    ob.put_state(2, b"y")
    assert ob.drain(10, max_bytes=100) == [b"x" * 500]
    assert ob.drain(10, max_bytes=100) == [b"y"]
