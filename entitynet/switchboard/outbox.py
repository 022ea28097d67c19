"""Per-client outbound queues with coalescing: the boundary between the switchboard core and the I/O shell.

Entity states (UPDATE or LEAVE, already encoded) are keyed by entity id: a newer state replaces an older one
still pending, so the queue of a client never holds more than one item per entity it can see, however slowly
it reads. Other messages (WELCOME, ERROR, PONG, QUERY_RESULT, REDIRECT) go to a short FIFO. Both are bounded;
a queue beyond its bounds (`over_bounds`) marks the client as a slow consumer, which the core turns into an
error and a close.

The core only puts (`put_state`, `put_control`, `put_last_word`, and `Outboxes.fan_out` for the same bytes to
many clients); the shell only takes (`take_states`, `drain`) and reads the flags. Neither touches the other's
side, so either can change its data structures without the other noticing.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from types import ModuleType, SimpleNamespace
from typing import Any


class Outbox:
    """One client's pending messages: coalesced entity states and a control FIFO, bounded."""

    __slots__ = ("_states", "_control", "max_states", "max_control", "_overflow", "_close_after")

    def __init__(self, max_states: int, max_control: int):
        self._states: dict[int, bytes] = {}
        self._control: list[bytes] = []
        self.max_states = max_states
        self.max_control = max_control
        self._overflow = False
        self._close_after = False

    def __len__(self) -> int:
        return len(self._states) + len(self._control)

    # ------------------------------------------------------------------------------------------ state (read)
    @property
    def close_after(self) -> bool:
        """The connection is to be closed once what is queued has been written (a fatal ERROR is queued)."""
        return self._close_after

    @property
    def has_control(self) -> bool:
        """Replies are waiting (WELCOME, PONG, ERROR ...): a shell writes them now, not at the next flush."""
        return bool(self._control)

    @property
    def n_states(self) -> int:
        """Entity states pending (at most one per entity)."""
        return len(self._states)

    @property
    def n_control(self) -> int:
        """Replies pending."""
        return len(self._control)

    @property
    def over_bounds(self) -> bool:
        """More is pending than the bounds allow: the client does not keep up (the core drops it)."""
        return self._overflow or len(self._states) > self.max_states or len(self._control) > self.max_control

    # ------------------------------------------------------------------------------------------ core side
    def put_state(self, entity: int, encoded: bytes) -> None:
        """Queue an entity's latest state, replacing one still pending. Not refused here: the count is judged
        by `over_bounds` when the core hands the client to the shell (one check per frame, not per state)."""
        self._states[entity] = encoded

    def put_control(self, encoded: bytes) -> None:
        """Queue a reply; beyond `max_control` the client is marked over its bounds instead."""
        if len(self._control) >= self.max_control:
            self._overflow = True
            return
        self._control.append(encoded)

    def put_last_word(self, encoded: bytes) -> None:
        """Queue a fatal ERROR beyond the bound (it must go out) and close once it is written."""
        self._control.append(encoded)
        self._close_after = True

    def discard_states(self) -> None:
        """Forget the pending states (shutdown: nobody needs them any more)."""
        self._states.clear()

    def discard(self) -> None:
        """Forget everything pending and the overflow mark (a slow consumer gets only its last word)."""
        self._states.clear()
        self._control.clear()
        self._overflow = False

    # ------------------------------------------------------------------------------------------ shell side
    def take_states_py(self, max_messages: int, sure_fit: int, max_body: int) -> tuple[int, bytes] | None:
        """The writer's short path: when only states are pending (no replies, no close, not over bounds), at
        most `max_messages` of them, and they fit `max_body` bytes (certain below `sure_fit` states), take them
        all as (count, joined bytes); else None and nothing is taken (use `drain`)."""
        states = self._states
        n = len(states)
        if 0 < n <= max_messages and not self._control and not self._close_after and not self._overflow:
            if n <= sure_fit or sum(map(len, states.values())) <= max_body:
                body = b"".join(states.values())
                states.clear()
                return n, body
        return None

    take_states = take_states_py  # the reference; `use_compiled` installs `_fanout.take_states` in its place

    def drain(self, max_messages: int | None = None, max_bytes: int | None = None) -> list[bytes]:
        """Take queued messages for one frame: control first, then entity states in first-queued order.

        At most `max_messages` messages totalling at most `max_bytes` bytes (at least one message, so a single
        oversized one cannot block the queue; the core keeps every message far below a frame). The returned
        list is always a new list: the control FIFO stays the outbox's own, so what was taken is never sent
        again (and never counted against `max_control`)."""
        control = self._control
        states = self._states
        self._control = []
        if max_messages is None and max_bytes is None:
            control.extend(states.values())
            states.clear()
            return control
        n_max = len(control) + len(states) if max_messages is None else max(1, max_messages)
        b_max = -1 if max_bytes is None else max_bytes
        if not control and len(states) <= n_max and (b_max < 0 or sum(map(len, states.values())) <= b_max):
            out = list(states.values())  # the common case: every pending state fits one frame
            states.clear()
            return out
        out = []
        size = 0
        for i, m in enumerate(control):
            if len(out) >= n_max or (out and b_max >= 0 and size + len(m) > b_max):
                self._control = control[i:]
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


class Outboxes:
    """The outboxes of all clients, by client id: lets the core queue the same bytes for many clients in one
    call (a PUBLISH reaches every viewer of its cells) at the cost of a dict store per client, which is what
    the forwarding hot path can afford."""

    __slots__ = ("_boxes", "_states", "max_states", "max_control")

    def __init__(self, max_states: int, max_control: int):
        self._boxes: dict[int, Outbox] = {}
        self._states: dict[int, dict[int, bytes]] = {}  # client id -> its outbox's states (the fan-out path)
        self.max_states = max_states
        self.max_control = max_control

    def open(self, cid: int) -> Outbox:
        """A new client's outbox."""
        ob = Outbox(self.max_states, self.max_control)
        self._boxes[cid] = ob
        self._states[cid] = ob._states
        return ob

    def close(self, cid: int) -> None:
        """The client is gone: nothing more is queued for it (its Outbox object stays valid for the shell)."""
        self._boxes.pop(cid, None)
        self._states.pop(cid, None)

    def targets(self, cids: Iterable[int]) -> tuple[dict[int, bytes], ...]:
        """An opaque handle on the outboxes of `cids` (all open) for `fan_out_to`. The core keeps one per entity
        with its viewer set and hands it back on every PUBLISH that reuses the set: the client-id lookup is paid
        once per viewer-set change instead of once per delivery (the per-delivery work is then one dict store,
        about half the cost). A handle is valid while its clients are open: the core recomputes viewer sets
        (and handles) after any subscription change, follow change, disconnect or shutdown."""
        return tuple(map(self._states.__getitem__, cids))  # the lookups in C, once

    @staticmethod
    def fan_out_to(targets: tuple[dict[int, bytes], ...], entity: int, encoded: bytes) -> None:
        """`put_state(entity, encoded)` on every outbox of a `targets` handle (replaced by `use_compiled`)."""
        fan_out_to_py(targets, entity, encoded)

    def fan_out(self, cids: Iterable[int], entity: int, encoded: bytes) -> None:
        """`put_state(entity, encoded)` on the outbox of every client in `cids` (all open)."""
        _impl.fan_out(self._states, cids, entity, encoded)

    def fan_out_open(self, cids: Iterable[int], entity: int, encoded: bytes) -> None:
        """As `fan_out`, skipping clients that are gone (LEAVEs to sets that may name closed clients)."""
        _impl.fan_out_open(self._states, cids, entity, encoded)


# ---------------------------------------------------------------------------------------------- fan-out loops
# The per-delivery loops, in Python (the reference) and, where pip built it, compiled (`_fanout.pyx`, the same
# three functions in C). `use_compiled` picks one for the process; ENTITYNET_PURE_PYTHON=1 forces the reference.
def fan_out_py(states: dict[int, dict[int, bytes]], cids: Iterable[int], entity: int, encoded: bytes) -> None:
    """`states[v][entity] = encoded` for every v in `cids` (all present)."""
    for v in cids:
        states[v][entity] = encoded


def fan_out_open_py(states: dict[int, dict[int, bytes]], cids: Iterable[int], entity: int, encoded: bytes) -> None:
    """As `fan_out_py`, skipping client ids not in `states`."""
    for v in cids:
        st = states.get(v)
        if st is not None:
            st[entity] = encoded


def fan_out_to_py(targets: tuple[dict[int, bytes], ...], entity: int, encoded: bytes) -> None:
    """`st[entity] = encoded` for every dict of `targets`."""
    for st in targets:
        st[entity] = encoded


PURE: Any = SimpleNamespace(fan_out=fan_out_py, fan_out_open=fan_out_open_py, fan_out_to=fan_out_to_py)
COMPILED: ModuleType | None
try:
    from entitynet.switchboard import _fanout as COMPILED  # type: ignore[attr-defined, no-redef]
except ImportError:  # not built (no compiler at install time): the reference path
    COMPILED = None
_impl: Any = PURE
_route: Any = None
_publish_run: Any = None


def use_compiled(flag: bool = True) -> bool:
    """Select the fan-out loops for this process: the compiled ones when `flag` and they were built, else the
    pure-Python reference. Returns whether the compiled ones are now in use."""
    global _impl, _route, _publish_run
    _impl = COMPILED if flag and COMPILED is not None else PURE
    _route = getattr(_impl, "route", None)
    _publish_run = getattr(_impl, "publish_run", None)
    Outbox.take_states = getattr(_impl, "take_states", Outbox.take_states_py)  # type: ignore[method-assign]
    Outboxes.fan_out_to = staticmethod(_impl.fan_out_to)  # type: ignore[method-assign]
    return _impl is COMPILED


def compiled_route() -> Any:
    """The compiled `Switchboard._route` (`_fanout.route`) when the compiled loops are in use, else None (the
    core then routes in Python)."""
    return _route


def compiled_publish_run() -> Any:
    """The compiled run of PUBLISHes (`_fanout.publish_run`: `_publish`, `_apply_state` and the route in one C
    loop) when the compiled loops are in use, else None (the core then publishes in Python)."""
    return _publish_run


def compiled_in_use() -> bool:
    """Whether the compiled fan-out loops are in use (the server logs it, the bench reports it)."""
    return COMPILED is not None and _impl is COMPILED


use_compiled(not os.environ.get("ENTITYNET_PURE_PYTHON"))
