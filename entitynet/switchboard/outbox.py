"""Per-client outbound queue with coalescing.

Entity states (UPDATE or LEAVE, already encoded) are keyed by entity id: a newer state replaces an older one
still pending, so the queue of a client never holds more than one item per entity it can see, however slowly
it reads. Other messages (WELCOME, ERROR, PONG, QUERY_RESULT, REDIRECT) go to a short FIFO. Both are bounded;
overflow marks the client as a slow consumer, which the core turns into an error and a close.
"""

from __future__ import annotations


class Outbox:
    __slots__ = ("states", "control", "max_states", "max_control", "overflow", "close_after")

    def __init__(self, max_states: int, max_control: int):
        self.states: dict[int, bytes] = {}
        self.control: list[bytes] = []
        self.max_states = max_states
        self.max_control = max_control
        self.overflow = False
        self.close_after = False  # close the connection once what is queued has been written

    def __len__(self) -> int:
        return len(self.states) + len(self.control)

    def put_state(self, entity: int, encoded: bytes) -> None:
        states = self.states
        if len(states) >= self.max_states and entity not in states:
            self.overflow = True
            return
        states[entity] = encoded

    def put_control(self, encoded: bytes) -> None:
        if len(self.control) >= self.max_control:
            self.overflow = True
            return
        self.control.append(encoded)

    def drain(self, max_messages: int | None = None) -> list[bytes]:
        """Take queued messages (control first, then entity states in first-queued order)."""
        out = self.control
        states = self.states
        if out:
            self.control = []
        if max_messages is None or len(out) + len(states) <= max_messages:
            if out:
                out.extend(states.values())
            else:
                out = list(states.values())
            states.clear()  # in place: the core holds a reference to this dict
            return out
        room = max(0, max_messages - len(out))
        keys = list(self.states)[:room]
        for k in keys:
            out.append(self.states.pop(k))
        return out
