"""Expiry timers: a binary heap with lazy deletion, compacted when stale entries dominate.

Every PUBLISH pushes a new deadline; an older entry of the same entity becomes stale (its generation no
longer matches) and is skipped when popped. Compaction keeps the heap within a constant factor of the
number of live timers, so memory stays bounded however often entities update.
"""

from __future__ import annotations

import heapq


class ExpiryHeap:
    """Deadlines by key (entity expiries, handshake deadlines): re-arming is O(log n) without a search, and
    the earliest live deadline is what the shell sleeps until."""

    def __init__(self) -> None:
        self._heap: list[tuple[float, int, int]] = []
        self._gen: dict[int, int] = {}  # key -> live generation
        self._deadline: dict[int, float] = {}
        self._next_gen = 0

    def __len__(self) -> int:
        return len(self._gen)

    @property
    def heap_size(self) -> int:
        """Entries in the heap, stale ones included (a metric of the lazy deletion's overhead)."""
        return len(self._heap)

    def set(self, key: int, deadline: float) -> None:
        """(Re)arm the timer of `key`."""
        self._next_gen += 1
        self._gen[key] = self._next_gen
        self._deadline[key] = deadline
        heapq.heappush(self._heap, (deadline, key, self._next_gen))
        if len(self._heap) > 2 * len(self._gen) + 1024:
            self._compact()

    def cancel(self, key: int) -> None:
        """Disarm the timer of `key` (its heap entry turns stale and is skipped later)."""
        self._gen.pop(key, None)
        self._deadline.pop(key, None)

    def next_deadline(self) -> float | None:
        """The earliest live deadline, or None (stale entries on top are dropped on the way)."""
        heap = self._heap
        while heap and self._gen.get(heap[0][1]) != heap[0][2]:
            heapq.heappop(heap)
        return heap[0][0] if heap else None

    def pop_due(self, now: float) -> list[int]:
        """Keys whose deadline is <= now, earliest first; their timers are removed."""
        out = []
        heap = self._heap
        while heap and heap[0][0] <= now:
            _, key, gen = heapq.heappop(heap)
            if self._gen.get(key) == gen:
                del self._gen[key]
                del self._deadline[key]
                out.append(key)
        return out

    def _compact(self) -> None:
        self._heap = [(self._deadline[k], k, g) for k, g in self._gen.items()]
        heapq.heapify(self._heap)
