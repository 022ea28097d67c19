"""Which worker carries which entity's honest client: by entity id, and a dead worker's entities handed on.

Why by id and not by region: every worker steps the whole world (see `sims.workers`), so a split by region
would keep no interaction more correct than a split by id, while entities crossing a region border would have
to move their client core between workers (an UNPUBLISH and a fresh PUBLISH each time). By id, an entity keeps
its worker for life and the load is even whatever the map.

The rule must give the same answer on the coordinator and on every worker without talking, so it is a pure
function of the entity ids and the ordered deaths: a new entity goes to `id mod N` if that worker is alive, or
else to `alive[id mod len(alive)]`; when a worker dies, each of its live entities goes to
`alive[id mod len(alive)]` (the others keep theirs). Every side applies a death at the same point of the run
(after the tick in which the coordinator declared it), so the tables stay equal.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable


class Assignment:
    """Entity -> worker for the live entities (the same table on every side of a run)."""

    def __init__(self, workers: int):
        if workers < 1:
            raise ValueError(f"at least one worker, got {workers}")
        self.workers = workers
        self.dead: list[int] = []  # in the order they died
        self.owner: dict[int, int] = {}

    @property
    def alive(self) -> list[int]:
        """The workers still running, in index order."""
        return [w for w in range(self.workers) if w not in self.dead]

    def place(self, entity: int) -> int | None:
        """The worker a new entity goes to (None: every worker is dead)."""
        home = entity % self.workers
        if home not in self.dead:
            return home
        alive = self.alive
        return alive[entity % len(alive)] if alive else None

    def add(self, entity: int) -> int | None:
        """Place a new entity and remember it; its worker (None when no worker is left: it is lost)."""
        w = self.place(entity)
        if w is not None:
            self.owner[entity] = w
        return w

    def kill(self, worker: int, live: Collection[int]) -> dict[int, int | None]:
        """Worker `worker` died: its entities still in `live` go to the survivors (entity -> new worker, or
        None when none is left); entries of entities no longer live are dropped on the way."""
        if not 0 <= worker < self.workers:
            raise ValueError(f"no worker {worker} of {self.workers}")
        if worker in self.dead:
            return {}
        self.dead.append(worker)
        self.owner = {e: w for e, w in self.owner.items() if e in live}
        alive = self.alive
        moved: dict[int, int | None] = {}
        for e in sorted(e for e, w in self.owner.items() if w == worker):
            new = alive[e % len(alive)] if alive else None
            moved[e] = new
            if new is None:
                del self.owner[e]
            else:
                self.owner[e] = new
        return moved

    def forget(self, entities: Iterable[int]) -> None:
        """Entities that left the world."""
        for e in entities:
            self.owner.pop(e, None)

    def counts(self, live: Collection[int] | None = None) -> list[int]:
        """Live entities per worker (all remembered ones, or only those in `live`)."""
        out = [0] * self.workers
        for e, w in self.owner.items():
            if live is None or e in live:
                out[w] += 1
        return out
