"""The entity -> worker rule: by id, the same on every side, a dead worker's entities handed to survivors."""

from __future__ import annotations

import pytest

from sims.workers.split import Assignment


def test_new_entities_go_by_id_and_around_dead_workers():
    a = Assignment(3)
    assert [a.add(e) for e in range(6)] == [0, 1, 2, 0, 1, 2]
    moved = a.kill(1, live=set(range(6)))
    assert moved == {1: [0, 2][1 % 2], 4: [0, 2][4 % 2]}
    assert a.alive == [0, 2] and a.counts() == [3, 0, 3]
    assert a.add(7) == [0, 2][7 % 2]  # home 1 is dead
    assert a.add(9) == 0  # home 0 is alive


def test_two_sides_that_see_the_same_events_keep_the_same_table():
    sides = [Assignment(4), Assignment(4)]
    for s in sides:
        for e in range(40):
            s.add(e)
        s.forget(range(0, 40, 7))
        s.kill(2, live=set(range(40)) - set(range(0, 40, 7)))
        for e in range(40, 50):
            s.add(e)
        s.kill(0, live=set(range(1, 50)))
    assert sides[0].owner == sides[1].owner
    assert 0 not in sides[0].owner.values() and 2 not in sides[0].owner.values()


def test_entities_no_longer_live_are_dropped_and_the_last_death_loses_everyone():
    a = Assignment(2)
    for e in range(4):
        a.add(e)
    assert a.kill(0, live={1, 2, 3}) == {2: 1}  # entity 0 left the world: not handed on
    assert a.kill(1, live={1, 2, 3}) == {1: None, 2: None, 3: None}
    assert a.owner == {} and a.add(5) is None
    assert a.kill(1, live=set()) == {}  # a second report of the same death changes nothing


def test_bad_worker_counts_and_indices():
    with pytest.raises(ValueError):
        Assignment(0)
    with pytest.raises(ValueError):
        Assignment(2).kill(2, live=set())
