"""`occupancy.move`, the cell -> occupants table's one update rule (both PUBLISH paths use it)."""

from __future__ import annotations

from entitynet.switchboard.occupancy import move


def test_entering_leaving_and_staying():
    occ: dict[int, set[int]] = {}
    move(occ, 7, (), (1, 2))
    move(occ, 8, (), (2,))
    assert occ == {1: {7}, 2: {7, 8}}
    move(occ, 7, (1, 2), (2, 3))
    assert occ == {2: {7, 8}, 3: {7}}
    move(occ, 7, (2, 3), ())
    assert occ == {2: {8}}


def test_repeated_cells_are_left_once_without_raising():
    """The wire refuses repeated cells, other feeders of the core may not: a cell repeated in the old state is
    dropped once, and the rest of the state is still applied (it raised KeyError half-way before)."""
    occ: dict[int, set[int]] = {}
    move(occ, 1, (), (0, 1, 0, 1))
    assert occ == {0: {1}, 1: {1}}
    move(occ, 1, (0, 1, 0, 1), (5,))
    assert occ == {5: {1}}
