"""The cell -> occupants table's one update rule, shared by the Python PUBLISH path (`Switchboard._apply_state`)
and the compiled one (`_fanout.publish_run`), so that both make the same set operations in the same order (a
set's iteration order, and so the order of a SUBSCRIBE's snapshot, depends on it). It imports nothing: the
compiled module loads it without a cycle."""

from __future__ import annotations


def move(occ: dict[int, set[int]], eid: int, old: tuple[int, ...], new: tuple[int, ...]) -> None:
    """Entity `eid` left the cells of `old` that are not in `new` and entered those of `new` not in `old`
    (a cell left empty is dropped from the table). A cell repeated in `old` is left once: the wire's decoder
    refuses repeated cells, but the core is also fed by other code (the cluster's mirror, tests), and a second
    leave of a cell already dropped must not raise half-way through a state (a KeyError here left the entity's
    cells and the table disagreeing)."""
    for cell in old:
        if cell not in new:
            s = occ.get(cell)
            if s is None:
                continue
            s.discard(eid)
            if not s:
                del occ[cell]
    for cell in new:
        if cell not in old:
            s = occ.get(cell)
            if s is None:
                occ[cell] = {eid}
            else:
                s.add(eid)
