"""The receiver's ghost store (reference section 4.4): entities received, extrapolated to `now`.

An entity whose cells become invisible is *kept* until its validity period runs out, so that it reappears at
once if its cells become visible again (the viewpoint bobbing above the roofs); it is dropped when the period
expires, on LEAVE, or when a newer UPDATE replaces it. Out-of-order updates (lower seq) are ignored. A ghost
lives at most `limits.HORIZON` seconds after its UPDATE whatever validity it claims, and its model never
extrapolates past the horizon nor faster than its type's cap (entitynet/client/limits.py).
Undecodable payloads are counted and skipped, never raised into the viewer.

The rules live in `entitynet.client.ghost_table.GhostTable`, which holds many viewers' ghosts in arrays (a
simulation's viewers share one); a `GhostStore` is one viewer's view of such a table (its own table of one
column unless it is given one), so the Python viewer and the simulation's viewers follow the same code.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from entitynet.client.ghost_table import GhostTable
from entitynet.client.motion import Model
from entitynet.client.network import NetView
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
    reappear at once when their cells become visible again: one column of a `GhostTable`."""

    def __init__(self, net: NetView | None, *, clock_offset: float = 0.0,
                 decoder: Callable[[bytes], Model] | None = None, table: GhostTable | None = None) -> None:
        """`clock_offset`: add to a payload's t0 to get receiver time (from PING/PONG); 0 on a shared clock.
        `decoder`: payload bytes -> model, raising PayloadError (default: `payload.decode` on `net`); many
        viewers in one process share one caching decoder, since the server fans one payload out to all of them
        and models are immutable (sims.engine.decode_cache). `table`: the table this viewer is a column of
        (shared by a process's viewers; its decoder then decodes, `decoder` must be None)."""
        if table is not None and decoder is not None:
            raise ValueError("a store on a shared table decodes with the table's decoder")
        self.table = table if table is not None else GhostTable(net, decoder)
        self.col = self.table.add_viewer(clock_offset)
        self.net = net

    @property
    def clock_offset(self) -> float:
        """Add to a payload's t0 to get this viewer's receiver time (its column's, in the table)."""
        return self.table.clock_offset[self.col]

    @clock_offset.setter
    def clock_offset(self, value: float) -> None:
        """A new estimate (PING / PONG)."""
        self.table.clock_offset[self.col] = value

    @property
    def bad_payloads(self) -> int:
        """Undecodable payloads this viewer received with a newer seq (counted, skipped)."""
        self.table.flush()
        return int(self.table.bad[self.col])

    @property
    def _decode(self) -> Callable[[bytes], Model]:
        return self.table.decoder

    @_decode.setter
    def _decode(self, f: Callable[[bytes], Model]) -> None:  # tests and benches swap the table's decoder
        self.table.decoder = f

    def _decode_payload(self, data: bytes) -> Model:
        return self.table.decode_payload(data)

    def __len__(self) -> int:
        return len(self.table.rows_of(self.col)[0])

    @property
    def ghosts(self) -> dict[int, Ghost]:
        """A snapshot of this viewer's ghosts by entity id (in the table's row order)."""
        t = self.table
        rows, vers = t.rows_of(self.col)
        out = {}
        for e, k in zip(t.entity(rows).tolist(), vers.tolist(), strict=True):
            m = t.vmsg[k]
            out[e] = Ghost(e, m.seq, tuple(m.cells), float(t.vexp[k]), t.model(k), m.identity)
        return out

    def receive(self, msg: Update | Leave, now: float) -> None:
        """Apply an UPDATE or LEAVE: older sequence numbers are ignored, undecodable payloads counted
        (`bad_payloads`) and skipped, and life is capped at the horizon whatever validity is claimed."""
        self.table.receive(self.col, (msg,), now)

    def clear(self) -> None:
        """Drop every ghost (a WELCOME after a reconnect: entity ids are per server session)."""
        self.table.clear(self.col)

    def set_visible(self, cells) -> None:
        """The cells the viewer currently sees (its PVS)."""
        self.table.set_visible(self.col, cells)

    def expire(self, now: float) -> list[int]:
        """Drop ghosts whose validity ran out; returns their ids."""
        return self.table.expire(self.col, now)

    def positions(self, now: float, visible_only: bool = True) -> dict[int, tuple[float, float]]:
        """Extrapolated (x, y) of the ghosts to draw now (expired ones are dropped first)."""
        if not math.isfinite(now):
            raise ValueError(f"now must be finite, got {now!r}")
        t = self.table
        t.expire(self.col, now)
        rows, vers = t.rows_of(self.col)
        if visible_only:
            keep = t.visible_versions(self.col, vers)
            rows, vers = rows[keep], vers[keep]
        at = now - self.clock_offset
        return {e: t.model(k).xy_at(at) for e, k in zip(t.entity(rows).tolist(), vers.tolist(), strict=True)}
