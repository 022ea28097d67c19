"""The receiver's ghost store (reference section 4.4): entities received, extrapolated to `now`.

An entity whose cells become invisible is *kept* until its validity period runs out, so that it reappears at
once if its cells become visible again (the viewpoint bobbing above the roofs); it is dropped when the period
expires, on LEAVE, or when a newer UPDATE replaces it. Out-of-order updates (lower seq) are ignored. A ghost
lives at most `limits.HORIZON` seconds after its UPDATE whatever validity it claims, and its model never
extrapolates past the horizon nor faster than its type's cap (entitynet/client/limits.py).
Undecodable payloads are counted and skipped, never raised into the viewer.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from entitynet.client.limits import HORIZON
from entitynet.client.motion import Model
from entitynet.client.network import NetView
from entitynet.client.payload import PayloadError, decode
from entitynet.protocol import Leave, Update


@dataclass(slots=True)
class Ghost:
    """A received entity as a viewer holds it: the decoded model to extrapolate, its cells (for
    visibility) and when it expires in receiver time."""
    entity: int
    seq: int
    cells: tuple[int, ...]
    expires: float  # receiver time (seconds)
    model: Model
    identity: str | None


class GhostStore:
    """A viewer's received entities, kept while invisible until their validity ends so that they
    reappear at once when their cells become visible again."""

    def __init__(self, net: NetView | None, *, clock_offset: float = 0.0,
                 decoder: Callable[[bytes], Model] | None = None) -> None:
        """`clock_offset`: add to a payload's t0 to get receiver time (from PING/PONG); 0 on a shared clock.
        `decoder`: payload bytes -> model, raising PayloadError (default: `payload.decode` on `net`); many
        viewers in one process share one caching decoder, since the server fans one payload out to all of them
        and models are immutable (sims.engine.decode_cache)."""
        self.net = net
        self._decode: Callable[[bytes], Model] = decoder if decoder is not None else self._decode_payload
        self.clock_offset = clock_offset
        self.ghosts: dict[int, Ghost] = {}
        self.visible_cells: set[int] = set()
        self.bad_payloads = 0

    def __len__(self) -> int:
        return len(self.ghosts)

    def receive(self, msg: Update | Leave, now: float) -> None:
        """Apply an UPDATE or LEAVE: older sequence numbers are ignored, undecodable payloads counted
        (`bad_payloads`) and skipped, and life is capped at the horizon whatever validity is claimed."""
        if isinstance(msg, Leave):
            self.ghosts.pop(msg.entity, None)
            return
        old = self.ghosts.get(msg.entity)
        if old is not None and msg.seq <= old.seq:
            return
        try:
            model = self._decode(msg.payload)
        except PayloadError:
            self.bad_payloads += 1
            return
        life = min(msg.validity_ms / 1000.0, HORIZON)
        self.ghosts[msg.entity] = Ghost(msg.entity, msg.seq, tuple(msg.cells), now + life, model, msg.identity)

    def _decode_payload(self, data: bytes) -> Model:
        return decode(data, self.net)

    def set_visible(self, cells) -> None:
        """The cells the viewer currently sees (its PVS)."""
        self.visible_cells = set(cells)

    def expire(self, now: float) -> list[int]:
        """Drop ghosts whose validity ran out; returns their ids."""
        gone = [e for e, g in self.ghosts.items() if now >= g.expires]
        for e in gone:
            del self.ghosts[e]
        return gone

    def is_visible(self, g: Ghost) -> bool:
        """Whether any of the ghost's cells is in the viewer's current PVS (only those are drawn)."""
        return not self.visible_cells.isdisjoint(g.cells)

    def positions(self, now: float, visible_only: bool = True) -> dict[int, tuple[float, float]]:
        """Extrapolated (x, y) of the ghosts to draw now (expired ones are dropped first)."""
        if not math.isfinite(now):
            raise ValueError(f"now must be finite, got {now!r}")
        self.expire(now)
        t = now - self.clock_offset
        return {e: g.model.xy_at(t) for e, g in self.ghosts.items() if not visible_only or self.is_visible(g)}
