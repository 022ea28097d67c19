"""Ownership and failover (a mixin of `ClusterCore`): heartbeats, which shards are alive, who owns which region,
and first PUBLISHes held while their region's owner is dying.

Why these rules: a region belongs to its own shard while that shard lives, else to `live[region % len(live)]`
(live sorted), which every survivor computes alike from the same heartbeats. A shard silent for `dead_after_s`
is dead; the first survivor to decide says so in its heartbeat, and every other survivor that has not heard the
shard for `quiet_s` either believes it at once. Since NATS delivers one publisher's messages in order, a
survivor's word that a shard is dead reaches every other survivor before the STATEs of the dead shard's former
clients that this survivor publishes next: each survivor drops the dead shard's copies before the new ones
arrive, and no viewer shows an entity twice. A client that fails over early (before the owner is decided) is
not refused: its first PUBLISH is held and judged again the moment the owner is decided.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import msgpack

from entitynet import protocol as P

log = logging.getLogger("entitynet.cluster")

HEARTBEAT = 5
# "send your heartbeat now": a shard holding a first PUBLISH for want of a peer's heartbeat since the client came
# asks for it, so a live peer (the old shard of a client it REDIRECTed, a neighbour of a client that starts near a
# border) releases the hold within a NATS round trip instead of up to `heartbeat_s`; a dead one does not answer
HEARTBEAT_ASK = 10
# a heartbeat's subscription, follow, timer and mirror counts (each walks every client or mirror) are taken at
# most this often; the heartbeats in between (4 a second at `--dead-after 1`) repeat them. Clients and
# entities are counted afresh every time (a `len`)
TABLE_COUNTS_EVERY_S = 1.0

_packb = msgpack.Packer(use_bin_type=True).pack


@dataclass
class Peer:
    """What this shard knows of another from its heartbeats; `alive` turns False after `dead_after_s` of
    silence, which hands its regions to the survivors."""

    shard: int
    address: str = ""
    last_seen: float = 0.0
    alive: bool = True
    counts: dict = field(default_factory=dict)


class ClusterFailoverMixin:
    """Liveness, ownership, heartbeats and held first PUBLISHes; uses `ClusterCore`'s tables and `_pub`."""

    def live_shards(self, now: float) -> list[int]:
        """Shards counted alive now, sorted (the failover rule indexes into it); a shard not heard from yet is
        presumed alive for `dead_after_s` after start, so a cluster starting together does not reassign regions."""
        live = {self.shard}
        for s in range(self.regions.shards):
            p = self.peers.get(s)
            if p is not None and p.alive:
                live.add(s)
            elif p is None and now - self.started < self.dead_after_s:
                live.add(s)  # not heard from yet: presumed alive while we start
        return sorted(live)

    def owner_of(self, region: int, live: list[int]) -> int:
        """The failover rule: a region's own shard while it lives, else `live[region % len(live)]`."""
        return region if region in live else live[region % len(live)]

    def _owners(self, now: float) -> list[int]:
        live = self.live_shards(now)
        key = frozenset(live)
        if self._owners_cache is None or self._owners_cache[0] != key:
            self._owners_cache = (key, [self.owner_of(r, live) for r in range(self.regions.shards)])
        return self._owners_cache[1]

    def owned_regions(self, now: float) -> list[int]:
        """The regions this shard serves now: its own, plus those of dead shards that the failover rule gives it."""
        return [r for r, s in enumerate(self._owners(now)) if s == self.shard]

    def address_of(self, shard: int) -> str | None:
        """Where to REDIRECT a client for `shard`; None when that shard is dead or has not told us its address."""
        if shard == self.shard:
            return self.address
        p = self.peers.get(shard)
        return p.address if p is not None and p.alive and p.address else None

    def _quiet(self, shard: int, now: float) -> bool:
        """A live peer not heard from for `quiet_s`: perhaps dying, so not a place to send clients to."""
        p = self.peers.get(shard)
        return p is not None and p.alive and now - p.last_seen > self.quiet_s

    def _heard_since(self, shard: int, since: float) -> bool:
        """Whether `shard` sent a heartbeat after `since` (True for ourselves, and for a shard not heard from
        at all yet: a cluster starting together presumes its peers alive)."""
        p = self.peers.get(shard)
        return shard == self.shard or p is None or p.last_seen > since

    def admit(self, c: Any, cells: tuple[int, ...], now: float, msg: Any = None) -> bool:
        """A new entity of connection `c` (the switchboard asks before it is published here): False when it is
        held or REDIRECTed instead. Held while another shard that may still serve the connection cannot be
        told alive (`_unsure_of`); a connection's first entity wholly in other shards' regions is REDIRECTed
        before it is published here, so no viewer sees it under an id that is about to vanish."""
        self._now_hint = now
        if not cells or c.cid in self.redirected:
            return True
        if not c.entities and c.cid not in self.held:
            self.first_publish_at.setdefault(c.cid, now)
        owners = self._owners(now)
        if self._unsure_of(c, cells, owners, now):
            return self._hold(c, msg, now)
        if c.entities or any(owners[self.region_of[cell]] == self.shard for cell in cells):
            return True
        target = owners[self.region_of[cells[0]]]
        if self.address_of(target) is None:
            return True  # nowhere to send it: serve it here
        if self._quiet(target, now) or not self._heard_since(target, self.first_publish_at.get(c.cid, now)):
            # its owner has not been heard since this client came (a client failing over arrives after its shard
            # died) or has gone quiet (dying?): sending the client there could cost it a failover, serving it
            # here might show it twice beside the dying owner's copy. Hold this PUBLISH and judge it again the
            # moment the owner is heard or decided (`_retry_held`): a NATS round trip for a client that merely
            # started on the wrong shard (`_hold` asks for the heartbeat), no round trip to a dead shard for one
            # failing over
            return self._hold(c, msg, now)
        self._redirect(c, target)
        return False

    def _unsure_of(self, c: Any, cells: tuple[int, ...], owners: list[int], now: float) -> bool:
        """Whether another shard may still be serving this connection (roaming.py's band, judged over all its
        cells: a shard serves every entity of a connection while one of them is in its band). If so, and it
        has entities admitted here since it came, those are taken back into the hold too: they might be shown
        beside that shard's copies (a client failing over re-publishes its entities one by one). A fleet (more
        than `max_redirect_entities`) is judged as before: it never roamed by the band, so the band says nothing
        about where its old shard served it, and taking back hundreds of entities would only churn ids."""
        if len(c.entities) > self.max_redirect_entities:
            return False
        since = self.first_publish_at.get(c.cid, -float("inf"))
        every = self._connection_cells(c, cells)
        if not self._in_band_of_unsure_shard(every, owners, now, since):
            return False
        if c.entities and self._in_band_of_unsure_shard(every, owners, now, since, quiet=False):
            self._take_back(c, now)
        return True

    def _take_back(self, c: Any, now: float) -> None:
        """Hold the last states of the connection's admitted entities and remove them here (LEAVE to viewers),
        as the client's UNPUBLISH would; they are judged again with its other held PUBLISHes."""
        held = self.held.setdefault(c.cid, {})
        for local, eid in list(c.entities.items()):
            e = self.sb.entities[eid]
            held[local] = (P.Publish(local, e.seq, e.cells, e.validity_ms, e.payload), self.sent_at.get(eid, now))
            self.stats["admissions_taken_back"] += 1
        self.sb.receive(c.cid, [P.Unpublish(local) for local in list(c.entities)], now)

    def _hold(self, c: Any, msg: Any, now: float) -> bool:
        """Hold a first PUBLISH until `_retry_held` judges it again (False: not admitted now)."""
        self.stats["admissions_deferred"] += 1
        if msg is not None:
            self.held.setdefault(c.cid, {})[msg.entity] = (msg, now)
        if self._asked_at < self.first_publish_at.get(c.cid, now):
            self._asked_at = now  # one ask answers every connection that came before it
            self._pub(f"{self.prefix}.hb", _packb([HEARTBEAT_ASK, self.shard]))
            self.stats["heartbeats_asked"] += 1
        return False

    def _heartbeat_asked(self, shard: int, now: float) -> None:
        """Another shard holds a client for want of our heartbeat: send it at the next `tick` (asks that come
        before it share it)."""
        if shard != self.shard:
            self._next_hb = min(self._next_hb, now)
            self.wake()

    def _retry_held(self, now: float) -> None:
        """Judge the held first PUBLISHes again (their validity shortened by the wait; those run out are
        dropped): held on as a whole while the connection is still unsure, else received again, one
        connection at a time, to be admitted here, REDIRECTed to the region's new owner, or held again."""
        if not self.held:
            return
        clients = self.sb.clients
        for cid in list(self.held):
            msgs = self.held.pop(cid)
            c = clients.get(cid)
            if c is None or c.closing:
                continue
            live = {k: (m, at) for k, (m, at) in msgs.items() if m.validity_ms - round((now - at) * 1000) > 0}
            if not live:
                continue
            cells = tuple(cell for m, _at in live.values() for cell in m.cells)
            if self._unsure_of(c, cells, self._owners(now), now):
                self.held.setdefault(cid, {}).update(live)
                continue
            self.sb.receive(cid, [P.Publish(m.entity, m.seq, m.cells, m.validity_ms - round((now - at) * 1000),
                                            m.payload) for m, at in live.values()], now)

    def _forget_first_publishes(self) -> None:
        """Drop the first-PUBLISH times every live peer has been heard since (they decide nothing any more) and
        those of connections that are gone (called with every heartbeat)."""
        heard = [p.last_seen for p in self.peers.values() if p.alive]
        oldest = min(heard, default=float("inf"))
        clients, held = self.sb.clients, self.held
        for cid in [x for x, t in self.first_publish_at.items() if x not in clients or (t < oldest and x not in held)]:
            del self.first_publish_at[cid]

    def _heartbeat(self, shard: int, m: list, now: float) -> None:
        if not 0 <= shard < self.regions.shards:
            self.stats["bad_messages"] += 1
            return
        if str(m[3]) != self.map_digest:
            self.stats["peer_map_mismatch"] += 1  # another cluster map: not one of ours
            return
        p = self.peers.get(shard)
        if p is None:
            p = self.peers[shard] = Peer(shard)
        if not p.alive:
            log.info("shard %d is back", shard)
        p.address, p.last_seen, p.alive = str(m[2]), now, True
        p.counts = dict(m[4]) if isinstance(m[4], dict) else {}
        # another survivor declared these shards dead: believe it for any that is quiet here too, at once. Its
        # STATEs of their former clients follow this heartbeat on NATS, so the dead shard's copies leave our
        # viewers first and no viewer shows an entity twice (deciding on our own clock alone let survivors
        # disagree by up to a heartbeat, the source of duplicates during a failover)
        for d in m[5] if len(m) > 5 and isinstance(m[5], list) else ():
            q = self.peers.get(int(d))
            if q is not None and q.alive and int(d) != self.shard and self._quiet(int(d), now):
                self._declare_dead(q, now, by=shard)
        if self.held:
            self.wake()  # an owner heard or decided: the held PUBLISHes are judged at the next tick

    def _heartbeat_out(self, now: float) -> None:
        """Our heartbeat: address, map digest, counts, and the shards we hold dead (so every survivor drops a
        dead shard's copies before anyone publishes its clients' new ones: see `_heartbeat`)."""
        self._next_hb = now + self.heartbeat_s
        sb = self.sb
        if now >= self._tables_at + TABLE_COUNTS_EVERY_S:  # the figures that walk every client or mirror
            self._tables_at = now
            self._table_counts = sb.counts()
            self._table_counts["mirrored"] = sum(len(c.entities) for c in sb.mirrors.values())
        counts = dict(self._table_counts)
        counts["clients"], counts["entities"] = len(sb.clients), len(sb.entities)
        counts["owned_regions"] = len(self.owned_regions(now))
        counts["updates_in"] = self.sb.stats["updates_in"]
        counts["deliveries"] = self.sb.stats["deliveries"]
        counts["held"] = len(self.held)
        counts.update(self.extra_counts())
        dead = sorted(p.shard for p in self.peers.values() if not p.alive)
        self._pub(f"{self.prefix}.hb", _packb([HEARTBEAT, self.shard, self.address, self.map_digest, counts,
                                               dead]))

    def _declare_dead(self, p: Peer, now: float, by: int | None = None) -> None:
        """`p` is dead: its mirrors leave (LEAVE to our viewers), its regions pass on, and our heartbeat says so
        at once, ahead of anything we publish for its former clients (NATS keeps one publisher's order)."""
        p.alive = False
        n = self.sb.drop_shard(p.shard)
        self._set_interest(p.shard, set())
        self.stats["peers_lost"] += 1
        log.warning("shard %d is gone%s: dropped its %d mirrored entities", p.shard,
                    "" if by is None else f" (shard {by} says)", n)
        self._heartbeat_out(now)
        self.wake()

