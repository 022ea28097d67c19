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

    def drain(self, max_messages: int | None = None, max_bytes: int | None = None) -> list[bytes]:
        """Take queued messages for one frame: control first, then entity states in first-queued order.

        At most `max_messages` messages totalling at most `max_bytes` bytes (at least one message, so a single
        oversized one cannot block the queue; the core keeps every message far below a frame). The returned
        list is always a new list: the control FIFO stays the outbox's own, so what was taken is never sent
        again (and never counted against `max_control`)."""
        control = self.control
        states = self.states
        self.control = []
        if max_messages is None and max_bytes is None:
            control.extend(states.values())
            states.clear()  # in place: the core holds a reference to this dict
            return control
        n_max = len(control) + len(states) if max_messages is None else max(1, max_messages)
        b_max = -1 if max_bytes is None else max_bytes
        out: list[bytes] = []
        size = 0
        for i, m in enumerate(control):
            if len(out) >= n_max or (out and b_max >= 0 and size + len(m) > b_max):
                self.control = control[i:]
                return out
            out.append(m)
            size += len(m)
        taken: list[int] = []
        for k, m in states.items():
            if len(out) >= n_max or (out and b_max >= 0 and size + len(m) > b_max):
                break
            out.append(m)
            size += len(m)
            taken.append(k)
        if len(taken) == len(states):
            states.clear()
        else:
            for k in taken:
                del states[k]
        return out
