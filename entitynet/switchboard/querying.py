"""Queries and privacy of the switchboard core: QUERY by cells or identity, and PRIVACY (the buddy rule).

A mixin of `Switchboard` (entitynet.switchboard.core), split off to keep each module to one job. In a cluster
(entitynet.cluster) a QUERY by identity or by cells also asks the other shards: the core hands the local answer
to the cluster hook, which replies once the others have answered (or their time is up).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from entitynet import protocol as P
from entitynet.protocol import ErrorCode
from entitynet.switchboard.privacy import claim_refused, identity_shown

if TYPE_CHECKING:
    from entitynet.switchboard.core import ClientState, EntityState  # noqa: F401


class QueriesMixin:
    """QUERY and PRIVACY handling; uses the tables and helpers of `Switchboard`."""

    def _query(self, c: ClientState, m: P.Query, now: float) -> None:
        if not c.bucket.take(now):
            self.stats["queries_refused"] += 1
            rate = self.config.query_rate
            self._error(c, ErrorCode.QUERY_RATE, f"query {m.query_id} refused: over {rate}/s")
            return
        found: list[EntityState] = []
        if m.kind == P.QUERY_IDENTITY:
            for ocid in self.by_identity.get(m.arg, ()):
                owner = self.clients[ocid]
                if identity_shown(owner, c) is None:
                    continue  # the buddy rule: not in the audience, or the asker shows no identity itself
                for eid in owner.entities.values():
                    found.append(self.entities[eid])
        else:
            n = self.config.n_cells
            seen: set[int] = set()
            for cell in m.arg:
                if cell >= n:
                    self._error(c, ErrorCode.NO_SUCH_CELL, f"cell {cell} does not exist (this map has {n})")
                    return
                seen |= self.occupants.get(cell, set())
            found = [self.entities[eid] for eid in seen]
        # at most max_query_results, and at most what fits in one frame with room for its headers: the result
        # is one message (clients wait for one), so it is cut rather than split
        room = self.config.codec.max_frame - 64
        encoded: list[bytes] = []
        for e in found[: self.config.max_query_results]:
            enc = self._encoded_for(e, c)
            room -= len(enc)
            if room < 0:
                self.stats["query_results_cut"] += 1
                break
            encoded.append(enc)
        self.stats["queries"] += 1
        if m.kind == P.QUERY_IDENTITY and self.cluster is not None:
            self.cluster.query_identity(c, m, encoded, now)  # answers when the other shards have
            return
        if self.cluster is not None:  # by cells: the cells' occupants owned by other shards, too
            self.cluster.query_cells(c, m, [(e.eid, b) for e, b in zip(found, encoded, strict=False)], now)
            return
        self._reply(c, P.encode_query_result(m.query_id, encoded))

    def _privacy(self, c: ClientState, m: P.Privacy) -> None:
        refused = claim_refused(c.user_id, m.identity, self.config.open_mode)
        if refused:
            self._error(c, ErrorCode.NOT_OWNER, refused)
            return
        if c.identity is not None:
            s = self.by_identity.get(c.identity)
            if s is not None:
                s.discard(c.cid)
                if not s:
                    del self.by_identity[c.identity]
        c.identity = m.identity
        c.audience = None if m.audience is None else frozenset(m.audience)
        if m.identity is not None:
            self.by_identity.setdefault(m.identity, set()).add(c.cid)
        for eid in c.entities.values():
            self.entities[eid].enc_ident = None
