"""Expiry timers: a binary heap that is re-armed lazily, so that a deadline moving later costs a dict store.

Every PUBLISH moves its entity's deadline, nearly always later (the entity updated before its validity ran
out). Pushing a heap entry each time (as this module did) cost a tuple, a push and, to keep the heap bounded,
periodic compactions: about 1 µs of the PUBLISH path and a heap two to three times the number of entities.
Now each key has at most one live heap entry, at or before its deadline: a later deadline only updates the
key's deadline, and when the early entry comes up it is pushed again at the real deadline. Only a deadline
moving *earlier* pushes a new entry (the old one turns stale: its generation no longer matches), and the heap is
compacted if such stale entries ever dominate. What `pop_due` and `next_deadline` return is unchanged: the keys
whose real deadline has passed, by (deadline, key), and the earliest real deadline.
"""

from __future__ import annotations

import heapq


class ExpiryHeap:
    """Deadlines by key (entity expiries, handshake deadlines): re-arming later is one dict store, earlier is
    O(log n) without a search, and the earliest live deadline is what the shell sleeps until."""

    def __init__(self) -> None:
        self._heap: list[tuple[float, int, int]] = []  # (entry's deadline, key, generation), at most one live per key
        self._deadline: dict[int, float] = {}  # key -> its real deadline (the armed keys)
        self._queued: dict[int, int] = {}  # key -> generation of its live heap entry (which is at or before it)
        self._next_gen = 0

    def __len__(self) -> int:
        return len(self._deadline)

    @property
    def heap_size(self) -> int:
        """Entries in the heap, stale ones included (a metric of the lazy deletion's overhead)."""
        return len(self._heap)

    def set(self, key: int, deadline: float) -> None:
        """(Re)arm the timer of `key`."""
        old = self._deadline.get(key)
        self._deadline[key] = deadline
        if old is not None and key in self._queued and not deadline < old:
            return  # later (or the same): the key's entry comes up early and is pushed again then
        self._push(key, deadline)

    def cancel(self, key: int) -> None:
        """Disarm the timer of `key`: its heap entry, if any, turns stale (dropped when it comes up, and counted
        towards a compaction, so that keys cancelled with far deadlines do not hold the heap's memory)."""
        self._deadline.pop(key, None)
        self._queued.pop(key, None)

    def next_deadline(self) -> float | None:
        """The earliest live deadline, or None (stale and early entries on top are settled on the way)."""
        heap = self._heap
        while heap:
            when, key, gen = heap[0]
            if self._queued.get(key) == gen:
                real = self._deadline.get(key)
                if real == when:
                    return when
                heapq.heappop(heap)
                del self._queued[key]
                if real is not None:
                    self._push(key, real)
                    heap = self._heap  # a push may compact: the heap is then a new list
            else:
                heapq.heappop(heap)
        return None

    def pop_due(self, now: float) -> list[int]:
        """Keys whose deadline is <= now, earliest first; their timers are removed."""
        out = []
        heap = self._heap
        while heap and heap[0][0] <= now:
            when, key, gen = heapq.heappop(heap)
            if self._queued.get(key) != gen:
                continue  # stale: replaced by an earlier entry of the same key
            del self._queued[key]
            real = self._deadline.get(key)
            if real is None:
                continue  # cancelled
            if real == when:
                del self._deadline[key]
                out.append(key)
            else:
                self._push(key, real)  # moved later since this entry was pushed
                heap = self._heap  # a push may compact: the heap is then a new list
        return out

    def _push(self, key: int, deadline: float) -> None:
        self._next_gen += 1
        self._queued[key] = self._next_gen
        heapq.heappush(self._heap, (deadline, key, self._next_gen))
        if len(self._heap) > 2 * len(self._queued) + 1024:
            self._compact()

    def _compact(self) -> None:
        """Rebuild the heap from the live entries (stale ones dropped; a cancelled key's is dropped too)."""
        self._queued = {}
        heap = []
        for key, deadline in self._deadline.items():
            self._next_gen += 1
            self._queued[key] = self._next_gen
            heap.append((deadline, key, self._next_gen))
        heapq.heapify(heap)
        self._heap = heap
