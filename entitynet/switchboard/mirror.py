"""Entities of other shards, mirrored into this switchboard's tables (entitynet.cluster feeds them).

A mixin of `Switchboard` (entitynet.switchboard.core). Why mirror into the same tables rather than forward
raw: a mirrored entity is then seen, followed, queried by cells, shown or hidden by the buddy rule, coalesced
in slow readers' outboxes and expired exactly like a local one, by the same code. Each remote owner (a
client session on another shard) has a stand-in `ClientState` (negative cid, `mirror` = its shard) carrying
its identity, audience and user id, so `identity_shown` applies unchanged. Mirrored entities keep their
owner's entity id (ids are random 53-bit numbers above the local-id range, so they do not collide in
practice; one that would is refused and counted), expire on their validity plus grace like any other, and are
never passed back to the cluster hook (no echo).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from entitynet import protocol as P
from entitynet.protocol import ErrorCode
from entitynet.switchboard.outbox import Outbox
from entitynet.switchboard.ratelimit import TokenBucket

if TYPE_CHECKING:
    from entitynet.switchboard.tables import ClientState


class MirrorMixin:
    """inject_state / inject_leave / drop_shard / redirect; uses the tables of `Switchboard`."""

    def _stand_in(self, shard: int, owner: int, user_id: str, identity: str | None,
                  audience: frozenset[str] | None) -> ClientState:
        from entitynet.switchboard.tables import ClientState

        key = (shard, owner)
        c = self.mirrors.get(key)
        if c is None:
            c = ClientState(-self._next_mirror_id(), owner, Outbox(0, 0),
                            TokenBucket(0.0, 0.0, 0.0), TokenBucket(0.0, 0.0, 0.0))
            c.mirror = shard
            c.ready = True
            self.mirrors[key] = c
        if c.identity != identity or c.audience != audience or c.user_id != user_id:
            c.identity, c.audience, c.user_id = identity, audience, user_id
            for eid in c.entities.values():
                self.entities[eid].enc_ident = None
        return c

    def _next_mirror_id(self) -> int:
        self._mirror_seq = getattr(self, "_mirror_seq", 0) + 1
        return self._mirror_seq

    def inject_state(self, shard: int, owner: int, eid: int, seq: int, cells: tuple[int, ...], validity_ms: int,
                     payload: bytes, now: float, user_id: str = "", identity: str | None = None,
                     audience: frozenset[str] | None = None) -> bool:
        """A state of another shard's entity (from NATS). False when refused: bad cells, an id taken by a local
        entity, or not newer than what is known (duplicates arrive once per cell subject)."""
        n = self.config.n_cells
        if not (P.LOCAL_ID_LIMIT <= eid < P.MAX_INT) or (cells and (min(cells) < 0 or max(cells) >= n)):
            self.stats["mirror_refused"] += 1
            return False
        c = self._stand_in(shard, owner, user_id, identity, audience)
        e = self.entities.get(eid)
        if e is not None and e.owner is not c:
            if e.owner.mirror is None:
                self.stats["mirror_refused"] += 1  # a local entity has this id: ours wins
                return False
            self._remove_entity(e)  # it moved to another owner (a re-publish after a failover): quietly
            e = None
        if e is None:
            from entitynet.switchboard.tables import EntityState

            e = EntityState(eid, c, eid)
            self.entities[eid] = e
            c.entities[eid] = eid
            self.stats["mirrors_created"] += 1
        elif seq <= e.seq:
            self.stats["mirror_stale"] += 1
            return False
        self.stats["mirror_updates"] += 1
        self._apply_state(c, e, seq, tuple(cells), validity_ms, payload, now)
        return True

    def inject_leave(self, eid: int) -> bool:
        """Another shard's entity left: remove its mirror (and its stand-in client once empty); a local entity
        with that id is never touched. False when there was no such mirror."""
        e = self.entities.get(eid)
        if e is None or e.owner.mirror is None:
            return False
        self._remove_entity(e)
        self._forget_stand_in(e.owner)
        return True

    def drop_shard(self, shard: int) -> int:
        """A shard is gone: its mirrored entities leave (their clients re-publish on a survivor)."""
        n = 0
        for key in [k for k in self.mirrors if k[0] == shard]:
            c = self.mirrors.pop(key)
            for eid in list(c.entities.values()):
                e = self.entities.get(eid)
                if e is not None and e.owner is c:
                    self._remove_entity(e)
                    n += 1
        return n

    def mirrored_in(self, cells) -> list:
        """Mirrored entities occupying any of `cells` (to drop those nobody here needs any more)."""
        out = {}
        for cell in cells:
            for eid in self.occupants.get(cell, ()):
                e = self.entities[eid]
                if e.owner.mirror is not None:
                    out[eid] = e
        return list(out.values())

    def _forget_stand_in(self, c: ClientState) -> None:
        if not c.entities and c.mirror is not None:
            self.mirrors.pop((c.mirror, c.session), None)

    def redirect(self, cid: int, shard: int, address: str, send: bool = True) -> None:
        """Tell a local client its home is another shard (protocol v1 REDIRECT: the whole connection moves).

        Its entities leave here at once and whatever it sends afterwards is ignored until it hangs up, so the
        LEAVE of its old id goes out before it can re-publish on the new shard: no viewer shows one entity
        twice. With `send=False` the REDIRECT itself waits for `send_redirect` (the cluster first makes sure
        NATS has the LEAVEs)."""
        c = self.clients.get(cid)
        if c is not None and not c.closing:
            for eid in list(c.entities.values()):
                self._remove_entity(self.entities[eid])
            c.closing = True
            self.stats["redirects"] += 1
            if send:
                self.send_redirect(cid, shard, address)

    def send_redirect(self, cid: int, shard: int, address: str) -> None:
        """Queue the REDIRECT control message to a client marked by `redirect(send=False)`, once NATS has its
        LEAVEs; a client already gone is ignored."""
        c = self.clients.get(cid)
        if c is not None:
            c.outbox.put_control(P.encode_message(P.Redirect(shard, address)))
            self._dirty.add(cid)
            self.replies_waiting = True

    def answer_query(self, cid: int, query_id: int, encoded: list[bytes]) -> None:
        """The deferred answer of a QUERY by identity, once the other shards have answered."""
        c = self.clients.get(cid)
        if c is not None and not c.closing:
            c.outbox.put_control(P.encode_query_result(query_id, encoded))
            self._dirty.add(cid)
            self.replies_waiting = True

    def follow_now(self, cid: int, eid: int) -> None:
        """Complete a FOLLOW the cluster resolved (the entity is mirrored now)."""
        c = self.clients.get(cid)
        if c is not None and not c.closing:
            self._follow(c, P.Follow(eid))

    def refuse_follow(self, cid: int, eid: int) -> None:
        """No shard owns the entity a client asked to FOLLOW."""
        c = self.clients.get(cid)
        if c is not None and not c.closing and eid not in self.entities:
            self._error(c, ErrorCode.NO_SUCH_ENTITY, f"no entity {eid}")
            self.replies_waiting = True
