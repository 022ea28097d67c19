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

import msgpack

from entitynet import protocol as P

log = logging.getLogger("entitynet.cluster")

HEARTBEAT = 5
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

    def _retry_held(self, now: float) -> None:
        """Judge the held first PUBLISHes again (their validity shortened by the wait): admitted here, REDIRECTed
        to the region's new owner, or held on while it is still undecided."""
        if not self.held:
            return
        held, self.held = self.held, {}
        for cid, msgs in held.items():
            c = self.sb.clients.get(cid)
            if c is None or c.closing:
                self.hold_since.pop(cid, None)
                continue
            for m, at in msgs.values():
                left = m.validity_ms - round((now - at) * 1000)
                if left > 0:
                    self.sb.receive(cid, [P.Publish(m.entity, m.seq, m.cells, left, m.payload)], now)

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

