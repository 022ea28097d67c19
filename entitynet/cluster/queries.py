"""QUERY by identity and by cells across the cluster (a mixin of `ClusterCore`): ask every live shard, answer
the asker once all have answered or `query_wait_s` has passed (then with what arrived: partial, counted as
`queries_partial`; protocol v1's QUERY_RESULT has no field to say so, and old clients check its arity).

Why every shard for cells too: an entity is owned by the shard it is published to, wherever it is (a proxy's
fleet is not redirected), so the owners of a cell's occupants are not only the shard whose region holds the
cell; each shard answers with the occupants it owns (never its mirrors), and the owner's answer replaces the
asking shard's mirror of the same entity, so every entity is in the result once.

Why the asker's user, identity and audience travel with the question: the buddy rule (switchboard/privacy.py)
needs both parties, and only the owner's shard knows the owner's; each shard answers with exactly what the rule
lets the asker see, as encoded UPDATEs under the owners' ids (the ids the asker's shard mirrors them under).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import msgpack

from entitynet import protocol as P

QUERY_REQ, QUERY_REP = 7, 8

_packb = msgpack.Packer(use_bin_type=True).pack


@dataclass
class _Asker:
    """The party a remote query asks for (the buddy rule needs its user, identity and audience)."""

    user_id: str
    identity: str | None
    audience: frozenset[str] | None


@dataclass
class _Query:
    cid: int
    query_id: int
    encoded: list[bytes]
    waiting: set[int]
    deadline: float
    by_eid: dict[int, bytes] | None = None  # QUERY by cells: entity -> its UPDATE, the owner's answer winning


class ClusterQueriesMixin:
    """Uses `sb`, `shard`, `prefix`, `inbox`, `queries`, `_pub` and `live_shards` of `ClusterCore`."""

    def query_identity(self, c: Any, m: P.Query, encoded: list[bytes], now: float) -> None:
        """QUERY by identity: the local answer waits for the other live shards' (or `query_wait_s`)."""
        self._ask(c, m, list(encoded), None, m.arg, now)

    def query_cells(self, c: Any, m: P.Query, found: list[tuple[int, bytes]], now: float) -> None:
        """QUERY by cells: the local answer (own and mirrored entities, as (id, UPDATE) pairs) waits for the
        other live shards' answers with the occupants they own (or `query_wait_s`)."""
        self._ask(c, m, [b for _eid, b in found], dict(found), sorted(set(m.arg)), now)

    def _ask(self, c: Any, m: P.Query, encoded: list[bytes], by_eid: dict[int, bytes] | None, arg: Any,
             now: float) -> None:
        waiting = set(self.live_shards(now)) - {self.shard}
        if not waiting:
            self.sb.answer_query(c.cid, m.query_id, encoded)
            return
        key = next(self._qkeys)
        self.queries[key] = _Query(c.cid, m.query_id, encoded, waiting, now + self.query_wait_s, by_eid)
        aud = None if c.audience is None else sorted(c.audience)
        self._pub(f"{self.prefix}.q", _packb([QUERY_REQ, self.shard, key, arg, c.user_id, c.identity, aud]),
                  self.inbox)

    def _answer_query(self, m: list, reply: str) -> None:
        key, arg, user, ident, aud = int(m[2]), m[3], str(m[4]), m[5], m[6]
        asker = _Asker(user, None if ident is None else str(ident), None if aud is None else frozenset(aud))
        from entitynet.switchboard.privacy import identity_shown

        sb = self.sb
        found: list[bytes] = []
        if isinstance(arg, list):  # by cells: the occupants this shard owns, shown as the privacy rule allows
            n = sb.config.n_cells
            mine = {eid for cell in arg if 0 <= int(cell) < n for eid in sb.occupants.get(int(cell), ())
                    if sb.entities[eid].owner.mirror is None}
            found = [sb._encoded_for(sb.entities[eid], asker) for eid in sorted(mine)]
            self._pub(reply, _packb([QUERY_REP, self.shard, key, found[: sb.config.max_query_results]]))
            return
        for ocid in sb.by_identity.get(str(arg), ()):
            owner = sb.clients.get(ocid)
            if owner is None or identity_shown(owner, asker) is None:
                continue
            for eid in owner.entities.values():
                found.append(sb._encoded_for(sb.entities[eid], asker))
        self._pub(reply, _packb([QUERY_REP, self.shard, key, found[: sb.config.max_query_results]]))

    def _query_reply(self, shard: int, key: int, encoded: list) -> None:
        q = self.queries.get(key)
        if q is None:
            return
        if q.by_eid is None:
            q.encoded.extend(bytes(b) for b in encoded)
        else:
            for b in encoded:
                b = bytes(b)
                q.by_eid[int(msgpack.unpackb(b)[1])] = b  # the owner's state replaces our mirror's
        q.waiting.discard(shard)
        if not q.waiting:
            self._finish_query(key)

    def _finish_query(self, key: int) -> None:
        q = self.queries.pop(key)
        if q.waiting:
            self.stats["queries_partial"] += 1  # some live shard did not answer in time: what arrived goes out
        room = self.sb.config.codec.max_frame - 64
        out: list[bytes] = []
        encoded = q.encoded if q.by_eid is None else list(q.by_eid.values())
        for b in encoded[: self.sb.config.max_query_results]:
            room -= len(b)
            if room < 0:
                break
            out.append(b)
        self.sb.answer_query(q.cid, q.query_id, out)
