"""The expiry heap (lazily re-armed: a later deadline is a dict store) against the obvious model: a dict of
deadlines, `pop_due` = the keys at or before `now` sorted by (deadline, key), `next_deadline` = the minimum.

Why: the switchboard's expiries (entities whose validity ran out, handshakes not done in time) and the order in
which their LEAVEs go out rest on it, and the lazy re-arming (early entries pushed again at the real deadline,
stale ones skipped, compaction) is easy to get subtly wrong; hypothesis draws deadlines on a coarse grid so that
ties, moves earlier and later, cancels, re-arms after a cancel and pops between them all happen.
"""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from entitynet.switchboard.timers import ExpiryHeap

key = st.integers(0, 6)
when = st.integers(0, 12).map(float)
op = st.one_of(
    st.tuples(st.just("set"), key, when),
    st.tuples(st.just("cancel"), key),
    st.tuples(st.just("pop"), when),
    st.tuples(st.just("next")),
)


def _model_pop(model: dict[int, float], now: float) -> list[int]:
    due = sorted((d, k) for k, d in model.items() if d <= now)
    for _, k in due:
        del model[k]
    return [k for _, k in due]


@settings(max_examples=400)
@given(st.lists(op, max_size=60))
def test_the_heap_behaves_like_a_dict_of_deadlines(ops):
    heap, model = ExpiryHeap(), {}
    for o in ops:
        if o[0] == "set":
            heap.set(o[1], o[2])
            model[o[1]] = o[2]
        elif o[0] == "cancel":
            heap.cancel(o[1])
            model.pop(o[1], None)
        elif o[0] == "pop":
            assert heap.pop_due(o[1]) == _model_pop(model, o[1])
        else:
            assert heap.next_deadline() == (min(model.values()) if model else None)
        assert len(heap) == len(model)
    assert heap.pop_due(1e9) == _model_pop(model, 1e9)
    assert heap.next_deadline() is None


def test_deadlines_moving_later_push_nothing_and_still_fire_at_the_last_one():
    """The common case (an entity updating before its validity runs out): one heap entry per key however often
    it is re-armed, and the key fires at its last deadline only."""
    heap = ExpiryHeap()
    for k in range(100):
        for step in range(50):
            heap.set(k, 10.0 + step + k * 0.001)
    assert heap.heap_size == 100
    assert heap.pop_due(58.0) == []  # the entries at 10.x came up early and were pushed again at 59.x
    assert heap.heap_size == 100
    assert heap.next_deadline() == 59.0
    assert heap.pop_due(59.05) == list(range(51))


def test_deadlines_moving_earlier_stay_bounded():
    """Each earlier deadline pushes an entry (the old one turns stale); compaction keeps the heap within a
    constant factor of the live keys, and the earliest deadline is the one that counts."""
    heap = ExpiryHeap()
    for i in range(20_000):
        heap.set(i % 3, 1e6 - i)
    assert heap.heap_size <= 2 * 3 + 1024 + 1
    assert heap.next_deadline() == 1e6 - 19_999
    assert heap.pop_due(1e6 - 19_997) == [1, 0, 2]  # keys 19,999 % 3, 19,998 % 3, 19,997 % 3


def test_a_compaction_inside_an_expiry_pass_loses_no_armed_key():
    """A re-push from `pop_due` or `next_deadline` may compact the heap (a new list): the pass must go on over
    the new heap. Before, it went on over the old list, where every entry had turned stale, and dropped them
    all: `next_deadline` said None (a server sleeping forever) while a key was still armed."""
    heap = ExpiryHeap()
    for k in range(1, 11):
        heap.set(k, 1.0)
    for i in range(1035):
        heap.set(0, 4000.0 - i)  # moved earlier each time: 1,035 entries, all but one stale
    heap.set(0, 5000.0)  # then later: no push
    assert heap.pop_due(1.0) == list(range(1, 11))
    assert heap.next_deadline() == 5000.0
    assert heap.pop_due(5000.0) == [0]
    assert heap.next_deadline() is None


def test_cancelled_keys_do_not_hold_the_heap():
    """Entities that come and go (an UNPUBLISH, a client's reconnect with new ids) cancel timers with far
    deadlines: their entries turn stale and count towards a compaction, so the heap stays within a constant
    factor of the armed keys instead of growing until the far deadlines come up."""
    heap = ExpiryHeap()
    for k in range(50_000):
        heap.set(k, 86_400.0 + k)
        heap.cancel(k)
    heap.set(-1, 10.0)
    assert len(heap) == 1
    assert heap.heap_size <= 2 * 1 + 1024 + 1
    assert heap.next_deadline() == 10.0
    assert heap.pop_due(1e9) == [-1]
