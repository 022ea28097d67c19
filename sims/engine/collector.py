"""The garbage collector's policy for a simulation process (the coordinator's `Sim`, a worker's share).

Why: a large run holds millions of long-lived objects from its start (the map, the routes, every entity, its
client core, the viewers' stores), and Python's cyclic collector walks them again in each full collection, which
it starts whenever the long-lived heap has grown by a quarter; the step allocates many short-lived objects
(tuples, obstacles, messages), so young collections come every few hundred allocations and promote survivors.
Freezing what the start built moves it out of every later collection (it is never garbage: the run holds it to
the end); a larger first-generation threshold lets each tick's short-lived objects die before a collection
looks at them. Cyclic garbage is still collected (young and full collections keep running). The thresholds are
the process's, so only a process's owner calls this: the `entitynet sim` command and the worker processes,
never a library caller.
"""

from __future__ import annotations

import gc

#: the first generation's threshold for a simulation process (Python's default is 700 allocations)
SIM_GEN0 = 50_000


def settle_after_start(gen0: int | None = SIM_GEN0) -> int:
    """Collect once, freeze what survives and, with `gen0`, raise the first generation's threshold to it.
    Returns the number of objects frozen. Call it once the run is built (its start done)."""
    if gen0 is not None and not 1 <= gen0 <= 10_000_000:
        raise ValueError(f"the first generation's threshold must be 1 to 10,000,000, not {gen0!r}")
    gc.collect()
    gc.freeze()
    if gen0 is not None:
        _t0, t1, t2 = gc.get_threshold()
        gc.set_threshold(gen0, t1, t2)
    return gc.get_freeze_count()


def unsettle(threshold: tuple[int, int, int]) -> None:
    """Undo `settle_after_start`: unfreeze and put back `threshold` (what `gc.get_threshold()` gave before).
    Why: a caller that runs a simulation inside a longer-lived process (a test session, a notebook) gets its
    collector back as it was once the run ends."""
    gc.unfreeze()
    gc.set_threshold(*threshold)
