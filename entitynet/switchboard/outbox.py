"""Per-client outbound queues with coalescing: the boundary between the switchboard core and the I/O shell.

Entity states (UPDATE or LEAVE, already encoded) are keyed by entity id: a newer state replaces an older one
still pending, so the queue of a client never holds more than one item per entity it can see, however slowly
it reads. Other messages (WELCOME, ERROR, PONG, QUERY_RESULT, REDIRECT) go to a short FIFO. Both are bounded;
a queue beyond its bounds (`over_bounds`) marks the client as a slow consumer, which the core turns into an
error and a close.

The core only puts (`put_state`, `put_control`, `put_last_word`, and `Outboxes.fan_out` for the same bytes to
many clients); the shell only takes (`take_states`, `drain`) and reads the flags. Neither touches the other's
side, so either can change its data structures without the other noticing. Two implementations: these classes
(dicts; the reference and the fallback) and, where pip built it, `_outbox.pyx` (the states in C arrays, the
same API and behaviour); `new_outboxes` picks one per switchboard.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from types import ModuleType
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

    take_states = take_states_py

    def holds_few(self, k: int) -> bool:
        """Whether only states are pending (no replies, no close, not over bounds) and fewer than `k` of them:
        a frame the flush may hold for one more flush (`flushloop.flush_short`'s `hold_below`), since a frame
        costs a `writev` whatever it carries and a reply or a close must never wait."""
        return 0 < len(self._states) < k and not self._control and not self._close_after and not self._overflow

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
    call (a PUBLISH reaches every viewer of its cells) at the cost of a dict store per client. The reference of
    the compiled `_outbox.OutboxTable` (same methods)."""

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

    def forget(self, eid: int) -> None:
        """The entity is gone (its LEAVEs are queued): nothing to do for dicts (the compiled table frees its slot)."""

    def targets(self, cids: Iterable[int]) -> tuple[dict[int, bytes], ...]:
        """An opaque handle on the outboxes of `cids` (all open) for `fan_out_to`. The core keeps one per entity
        with its viewer set and hands it back on every PUBLISH that reuses the set: the client-id lookup is paid
        once per viewer-set change instead of once per delivery (the per-delivery work is then one dict store,
        about half the cost). A handle is valid while its clients are open: the core recomputes viewer sets
        (and handles) after any subscription change, follow change, disconnect or shutdown."""
        return tuple(map(self._states.__getitem__, cids))  # the lookups in C, once

    @staticmethod
    def fan_out_to(targets: tuple[dict[int, bytes], ...], entity: int, encoded: bytes) -> None:
        """`put_state(entity, encoded)` on every outbox of a `targets` handle."""
        for st in targets:
            st[entity] = encoded

    def fan_out(self, cids: Iterable[int], entity: int, encoded: bytes) -> None:
        """`put_state(entity, encoded)` on the outbox of every client in `cids` (all open)."""
        states = self._states
        for v in cids:
            states[v][entity] = encoded

    def fan_out_open(self, cids: Iterable[int], entity: int, encoded: bytes) -> None:
        """As `fan_out`, skipping clients that are gone (LEAVEs to sets that may name closed clients)."""
        states = self._states
        for v in cids:
            st = states.get(v)
            if st is not None:
                st[entity] = encoded


# ---------------------------------------------------------------------------------------------- the paths
# The compiled outboxes (`_outbox.pyx`) and the compiled route and PUBLISH run over them (`_fanout.pyx`), where
# pip built both; `use_compiled` picks them or these classes for the switchboards made afterwards
# (ENTITYNET_PURE_PYTHON=1 forces the reference).
COMPILED: ModuleType | None
TABLE: Any = None
try:
    from entitynet.switchboard import _fanout as COMPILED  # type: ignore[attr-defined, no-redef]
    from entitynet.switchboard._outbox import OutboxTable as TABLE  # type: ignore[import-not-found, no-redef]
except ImportError:  # not built (no compiler at install time): the reference path
    COMPILED = TABLE = None
_in_use = False


def use_compiled(flag: bool = True) -> bool:
    """Select the outboxes, route and PUBLISH run for switchboards made from now on: the compiled ones when
    `flag` and they were built, else the pure-Python reference. Returns whether the compiled ones are in use."""
    global _in_use
    _in_use = bool(flag) and COMPILED is not None
    return _in_use


def new_outboxes(max_states: int, max_control: int) -> Any:
    """A switchboard's outboxes: the compiled table when in use, else `Outboxes`."""
    return TABLE(max_states, max_control) if _in_use else Outboxes(max_states, max_control)


def compiled_route(outboxes: Any) -> Any:
    """The compiled `Switchboard._route` (`_fanout.route`) for a switchboard whose outboxes are the compiled
    table while the compiled paths are in use, else None (the core then routes in Python)."""
    return COMPILED.route if _in_use and type(outboxes) is TABLE else None  # type: ignore[union-attr]


def compiled_publish_run(outboxes: Any) -> Any:
    """The compiled run of PUBLISHes (`_fanout.publish_run`: `_publish`, `_apply_state` and the route in one C
    loop) under the same conditions as `compiled_route`, else None (the core then publishes in Python)."""
    return COMPILED.publish_run if _in_use and type(outboxes) is TABLE else None  # type: ignore[union-attr]


def set_kinds(outboxes: Any) -> tuple[Any, Any]:
    """The kinds of a switchboard's id sets, (viewer and subscriber sets, dirty marks): the compiled route's
    `_fanout.ViewerSet` and `_fanout.CidMarks` under the same conditions as `compiled_route`, else `set` twice.
    One kind per switchboard, chosen with its outboxes, so that every set the route reads is one it can walk."""
    if _in_use and type(outboxes) is TABLE:
        return COMPILED.ViewerSet, COMPILED.CidMarks  # type: ignore[union-attr]
    return set, set


def compiled_in_use() -> bool:
    """Whether the compiled outboxes and loops are in use (the server logs it, the bench reports it)."""
    return _in_use


use_compiled(not os.environ.get("ENTITYNET_PURE_PYTHON"))
