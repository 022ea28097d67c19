"""The cluster core, sans-IO: what one switchboard says to and hears from the others over NATS.

Why NATS subjects per cell: a switchboard publishes every UPDATE and LEAVE of its own entities to the subjects
of the cells they occupy (and left), and subscribes only to the cells its own viewers subscribe to, so NATS's
interest routing carries exactly what crosses a region border (DESIGN.md, "Shards"); nothing is echoed back
(CONNECT echo=false, and mirrored entities are never re-published).

Subjects (prefix `en.<cluster-map digest[:12]>`, so shards of different maps never mix):
  `P.c.<cell>`   STATE / LEAVE of the entities in that cell
  `P.e.<eid>`    STATE / LEAVE of one entity that another shard FOLLOWs (published while asked for)
  `P.snap`       snapshot request (cells) -> every owner answers the reply inbox with its occupants' states
  `P.f`          follow request (an entity id) -> its owner answers with its state and publishes `P.e.<eid>`
  `P.q`          query by identity -> every shard answers with what the asker may see (the buddy rule)
  `P.hb`         heartbeats: shard, address, map digest, counts; and asks for one now (HEARTBEAT_ASK, failover.py)
  `P.i`          interest: the cells a shard subscribes to (changes at once, the whole set every 2 s)
Messages are msgpack arrays (kind first). A shard publishes a cell's states only while another shard has
announced interest in that cell: interior cells, which no other shard's viewers can see, cost nothing on NATS.
Mirrored entities live in the switchboard's own tables (entitynet.switchboard.mirror): seen, followed, queried,
expired like local ones.

Ownership and failover: shard k owns region k while it is alive; a region whose shard is dead (no heartbeat for
`dead_after_s`) passes to the live shards by one deterministic rule, `live[region % len(live)]` (live sorted),
which every survivor computes alike from the same heartbeats. A dead shard's mirrored entities are dropped at
once; its clients reconnect to another shard they know and re-publish.

Roaming: a client whose entities have all left this shard's regions, and the band around them or for a while, is
sent REDIRECT (owner shard, address) once (roaming.py: the hysteresis); a client with no entities (a viewer) whose
subscribed cells lie mostly in another shard's regions likewise.
The shell (entitynet.cluster.link) moves bytes: `on_message` in, `take_out()` publications and
`interest_changes()` SUB/UNSUB out, `tick(now)` at `next_deadline()`.
"""

from __future__ import annotations

import itertools
import logging
from collections import Counter, deque
from typing import Any

import msgpack

from entitynet import protocol as P
from entitynet.cluster.defaults import DEAD_AFTER_S
from entitynet.cluster.failover import HEARTBEAT, HEARTBEAT_ASK, ClusterFailoverMixin, Peer
from entitynet.cluster.queries import QUERY_REP, QUERY_REQ, ClusterQueriesMixin
from entitynet.cluster.roaming import (
    PUBLISHER_LINGER_S,
    PUBLISHER_MARGIN_CELLS,
    CameraRoamingMixin,
    PublisherRoamingMixin,
)

log = logging.getLogger("entitynet.cluster")

STATE, LEAVE, SNAP_REQ, SNAP_REP, FOLLOW_REQ = 1, 2, 3, 4, 6  # (5: HEARTBEAT, in failover.py)
INTEREST = 9  # (7 and 8: QUERY_REQ and QUERY_REP, in queries.py; 10: HEARTBEAT_ASK, in failover.py)
RESEND_LEAVES_S = 3.0  # LEAVEs published again after a NATS reconnect if they went out this recently
MAX_REDIRECT_ENTITIES = 8  # a connection carrying more (a proxy's fleet) is not redirected: mirrors carry it

_packb = msgpack.Packer(use_bin_type=True).pack


def _unpack(data: bytes) -> Any:
    return msgpack.unpackb(data, raw=False, strict_map_key=False, use_list=True)


class ClusterCore(ClusterQueriesMixin, ClusterFailoverMixin, CameraRoamingMixin, PublisherRoamingMixin):
    """Cluster logic of one shard; installs itself as the switchboard's `cluster` hook (queries by identity
    across shards in `queries.py`; liveness, ownership and failover in `failover.py`; roaming with its
    hysteresis in `roaming.py`: `cell_adjacency` (cell -> neighbour cells) gives publishers their border band)."""

    max_redirect_entities = MAX_REDIRECT_ENTITIES

    def __init__(self, sb: Any, regions: Any, shard: int, address: str, *, now: float, inbox: str,
                 heartbeat_s: float = 0.5, dead_after_s: float = DEAD_AFTER_S, follow_ttl_s: float = 6.0,
                 query_wait_s: float = 0.5, follow_wait_s: float = 1.0, redirect_viewers: bool = True,
                 wake: Any = None, cell_adjacency: Any = None, publisher_margin_cells: int = PUBLISHER_MARGIN_CELLS,
                 publisher_linger_s: float = PUBLISHER_LINGER_S):
        if not 0 <= shard < regions.shards:
            raise ValueError(f"shard {shard} is not one of the map's {regions.shards} regions")
        self.sb = sb
        sb.cluster = self
        self.regions = regions
        self.region_of = regions.cell_region.tolist()
        self.shard = shard
        self.address = address
        self.map_digest = regions.digest  # (a property that hashes the map: taken once, compared per heartbeat)
        self.prefix = f"en.{self.map_digest[:12]}"
        self._tables_at = -float("inf")  # when the heartbeat's table counts were last taken (failover.py)
        self._table_counts: dict[str, int] = {}
        self.inbox = inbox
        self.heartbeat_s, self.dead_after_s = heartbeat_s, dead_after_s
        self.follow_ttl_s, self.query_wait_s, self.follow_wait_s = follow_ttl_s, query_wait_s, follow_wait_s
        self.wake = wake or (lambda: None)
        self.redirect_viewers = redirect_viewers
        self.extra_counts: Any = dict  # the shell's own figures for the heartbeat (NATS messages in and out)
        self.started = now
        self.out: list[tuple[str, bytes, str | None]] = []
        self.peers: dict[int, Peer] = {}
        self.nats_cells: set[int] = set()
        self.nats_entities: set[int] = set()
        self.sent_at: dict[int, float] = {}  # local entity -> when its state last went out (snapshot validity)
        self.remote_followed: dict[int, float] = {}  # local entity -> until when another shard follows it
        self.pending_follows: dict[int, dict[int, float]] = {}  # remote entity -> {cid: give up at}
        self.following: set[int] = set()  # remote entities some local client follows through `P.e.<eid>`
        self.queries: dict = {}  # key -> queries._Query
        self.redirected: set[int] = set()
        self.camera_retry: set[int] = set()  # viewers whose camera REDIRECT waits for its target (roaming.py)
        self.redirects: list[tuple[int, int, str]] = []  # REDIRECTs waiting for NATS to have our LEAVEs
        self.recent_leaves: deque[tuple[float, int, tuple[int, ...]]] = deque()  # (when, entity, its cells)
        self.interest: dict[int, set[int]] = {}  # other shard -> the cells it subscribes to
        self.wanted: Counter[int] = Counter()  # cell -> how many other shards want it
        self._next_interest = now
        self.stats: Counter[str] = Counter()
        self._qkeys = itertools.count(1)
        self._next_hb = now
        self._next_follow_refresh = now
        self._owners_cache: tuple[frozenset[int], list[int]] | None = None
        # a peer unheard for this long is "quiet": dying, not yet dead. No REDIRECT goes to it, a first PUBLISH
        # for its regions is held (not refused), and another shard's word that it is dead is believed
        self.quiet_s = min(2 * heartbeat_s, dead_after_s / 2)
        # first PUBLISHes held while their region's owner is quiet: cid -> local id -> (message, when it came);
        # judged again as soon as the owner is decided (declared dead, or heard again)
        self.held: dict[int, dict[int, tuple[Any, float]]] = {}
        # cid -> when a connection's first PUBLISH came, while some peer has not been heard since (failover.py)
        self.first_publish_at: dict[int, float] = {}
        self._asked_at = -float("inf")  # when we last asked the peers for a heartbeat now (failover.py)
        self.init_publisher_roaming(cell_adjacency, publisher_margin_cells, publisher_linger_s)

    # ------------------------------------------------------------------------------------------ switchboard hooks
    def _pub(self, subject: str, payload: bytes, reply: str | None = None) -> None:
        """Queue a publication; wake the shell on the first since it last took them, and on every request (one
        with a `reply` subject: the shell sends those at once instead of after its latency budget)."""
        first = not self.out
        self.out.append((subject, payload, reply))
        if first or reply is not None:
            self.wake()

    def _state_of(self, e: Any, now: float) -> list:
        o = e.owner
        left = e.validity_ms
        at = self.sent_at.get(e.eid)
        if at is not None:
            left = max(0, e.validity_ms - int((now - at) * 1000))
        aud = None if o.audience is None else sorted(o.audience)
        return [self.shard, o.session, e.eid, e.seq, list(e.cells), left, e.payload, o.identity, aud, o.user_id]

    def on_state(self, c: Any, e: Any, old: tuple[int, ...], now: float) -> None:
        """A local entity's new state: to its cells' subjects (and the cells it left), maybe a REDIRECT."""
        self._now_hint = now
        self.sent_at[e.eid] = now
        p = self.prefix
        wanted = self.wanted
        # the subjects first, the message only if one exists: a state of a cell no other shard watches (a
        # region's interior, which in a city is most of it; every state of a lone shard) costs no encoding
        subjects = [f"{p}.c.{cell}" for cell in e.cells if cell in wanted]
        for cell in old:
            if cell not in e.cells and cell in wanted:
                subjects.append(f"{p}.c.{cell}")
        until = self.remote_followed.get(e.eid)
        if until is not None:
            if until >= now:
                subjects.append(f"{p}.e.{e.eid}")
            else:
                del self.remote_followed[e.eid]
        if subjects:
            aud = None if c.audience is None else sorted(c.audience)
            msg = _packb([STATE, self.shard, c.session, e.eid, e.seq, list(e.cells), e.validity_ms, e.payload,
                          c.identity, aud, c.user_id])  # once per state, whatever the number of subjects
            for subject in subjects:
                self._pub(subject, msg)
            self.stats["states_encoded"] += 1
        self.stats["states_out"] += 1
        if c.cid not in self.redirected:
            self._roam_publisher(c, e, now)

    def on_leave(self, e: Any) -> None:
        """A local entity left: its LEAVE goes to the cells other shards want, and to its `P.e.<eid>` if followed.
        Recent LEAVEs are kept for `RESEND_LEAVES_S`: a NATS node that dies takes what was written to it."""
        self.sent_at.pop(e.eid, None)
        msg = _packb([LEAVE, self.shard, e.eid])
        now = self._now_hint
        recent = self.recent_leaves
        while recent and recent[0][0] < now - RESEND_LEAVES_S:
            recent.popleft()
        recent.append((now, e.eid, tuple(e.cells)))
        for cell in e.cells:
            if self.wanted[cell]:
                self._pub(f"{self.prefix}.c.{cell}", msg)
        if self.remote_followed.pop(e.eid, None) is not None:
            self._pub(f"{self.prefix}.e.{e.eid}", msg)
        self.stats["leaves_out"] += 1

    def on_subscribe(self, c: Any, now: float) -> None:
        """A local client's cells changed: NATS interest may change (the shell asks), maybe a viewer REDIRECT."""
        self._now_hint = now
        self.wake()
        if not self.redirect_viewers or c.entities or c.cid in self.redirected or not c.subs or c.camera:
            return  # (a viewer that says where its camera is roams by the camera: roaming.py)
        owners = self._owners(now)
        by_shard: Counter[int] = Counter(owners[self.region_of[cell]] for cell in c.subs)
        best, n_best = by_shard.most_common(1)[0]
        if best != self.shard and n_best > 1.5 * by_shard.get(self.shard, 0):
            self._redirect(c, best)

    _now_hint = 0.0  # the latest `now` the core saw (hooks without a `now` use it)

    def _redirect(self, c: Any, shard: int) -> None:
        """The client's entities leave now; the REDIRECT itself waits in `redirects` until the shell has
        handed those LEAVEs to NATS and NATS has confirmed them (`release_redirects`): only then can the client
        re-publish elsewhere, so the new shard's first UPDATE never overtakes our LEAVE."""
        address = self.address_of(shard)
        if address is None or shard == self.shard or self._quiet(shard, self._now_hint):
            return  # not to a shard that is gone or going quiet: the client would only fail over again
        self.redirected.add(c.cid)
        self.sb.redirect(c.cid, shard, address, send=False)
        self.redirects.append((c.cid, shard, address))
        self.stats["redirects"] += 1
        self.wake()

    def release_redirects(self) -> int:
        """Send the REDIRECTs held back until now (the shell calls this once NATS has our LEAVEs)."""
        held, self.redirects = self.redirects, []
        for cid, shard, address in held:
            self.sb.send_redirect(cid, shard, address)
        return len(held)

    def follow_remote(self, c: Any, eid: int) -> bool:
        """FOLLOW of an entity not known here: ask its owner (whoever it is) for it; the follow completes when
        the answer arrives, or NO_SUCH_ENTITY after `follow_wait_s`."""
        if not P.LOCAL_ID_LIMIT <= eid < P.MAX_INT:
            return False
        now = self._now_hint
        self.pending_follows.setdefault(eid, {})[c.cid] = now + self.follow_wait_s
        self.following.add(eid)
        self._pub(f"{self.prefix}.f", _packb([FOLLOW_REQ, self.shard, eid]), self.inbox)
        self.stats["follow_requests"] += 1
        return True

    # ------------------------------------------------------------------------------------------ NATS interest
    def interest_changes(self) -> tuple[list[str], list[str]]:
        """Subjects to SUB and UNSUB now: the cells local clients subscribe to, and followed remote entities.
        New cells also get a snapshot request; mirrored entities nobody here needs any more are dropped."""
        want = set(self.sb.subscribers)
        add_cells = want - self.nats_cells
        del_cells = self.nats_cells - want
        self.nats_cells = want
        p = self.prefix
        subs = [f"{p}.c.{c}" for c in sorted(add_cells)]
        unsubs = [f"{p}.c.{c}" for c in sorted(del_cells)]
        if add_cells or del_cells:  # before the snapshot request: owners publish these cells from now on
            self._pub(f"{p}.i", _packb([INTEREST, self.shard, sorted(add_cells), sorted(del_cells), False]))
        if add_cells:
            cells = sorted(add_cells)
            for i in range(0, len(cells), 2000):
                self._pub(f"{p}.snap", _packb([SNAP_REQ, self.shard, cells[i : i + 2000]]), self.inbox)
        if del_cells:
            for e in self.sb.mirrored_in(del_cells):
                if not e.followers and want.isdisjoint(e.cells):
                    self.sb.inject_leave(e.eid)  # no viewers here: nothing is sent
        ents = set(self.following)
        subs += [f"{p}.e.{x}" for x in sorted(ents - self.nats_entities)]
        unsubs += [f"{p}.e.{x}" for x in sorted(self.nats_entities - ents)]
        self.nats_entities = ents
        return subs, unsubs

    def resync(self) -> None:
        """After a NATS reconnect: the LEAVEs of the last `RESEND_LEAVES_S` go out again (those written to the
        node that died never reached anyone, and a mirror left behind would show its entity twice once it
        re-appears elsewhere under a new id: a LEAVE twice is harmless), and every subscribed cell needs a fresh
        snapshot (states may have been missed)."""
        for _t, eid, cells_left in self.recent_leaves:
            if eid not in self.sb.entities:
                msg = _packb([LEAVE, self.shard, eid])
                for cell in cells_left:
                    if self.wanted[cell]:
                        self._pub(f"{self.prefix}.c.{cell}", msg)
                self.stats["leaves_resent"] += 1
        cells = sorted(self.nats_cells)
        for i in range(0, len(cells), 2000):
            self._pub(f"{self.prefix}.snap", _packb([SNAP_REQ, self.shard, cells[i : i + 2000]]), self.inbox)

    # ------------------------------------------------------------------------------------------ messages in
    def on_message(self, subject: str, reply: str | None, data: bytes, now: float) -> None:
        """One NATS message in; unreadable or malformed ones are counted as `bad_messages` and dropped, never
        raised, since a peer's bad bytes must not stop this shard."""
        self._now_hint = now
        try:
            m = _unpack(data)
            kind, shard = int(m[0]), int(m[1])
        except Exception:  # a message we cannot read is dropped and counted, never fatal
            self.stats["bad_messages"] += 1
            return
        if shard == self.shard:
            return  # our own (NATS does not echo, but another link of the same shard might)
        try:
            if kind == STATE:
                self._inject(m[1:], now)
            elif kind == LEAVE:
                self.sb.inject_leave(int(m[2]))
            elif kind == SNAP_REQ and reply:
                self._answer_snapshot(m[2], reply, now)
            elif kind == SNAP_REP:
                for st in m[2]:
                    self._inject(st, now)
                self._complete_follows(now)
            elif kind == HEARTBEAT:
                self._heartbeat(shard, m, now)
            elif kind == HEARTBEAT_ASK:
                self._heartbeat_asked(shard, now)
            elif kind == FOLLOW_REQ and reply:
                self._answer_follow(int(m[2]), reply, now)
            elif kind == QUERY_REQ and reply:
                self._answer_query(m, reply)
            elif kind == QUERY_REP:
                self._query_reply(shard, int(m[2]), m[3])
            elif kind == INTEREST:
                self._interest(shard, m[2], m[3], bool(m[4]))
            else:
                self.stats["bad_messages"] += 1
        except (TypeError, ValueError, IndexError, KeyError):
            self.stats["bad_messages"] += 1

    def _inject(self, st: list, now: float) -> None:
        shard, owner, eid, seq, cells, vms, payload, ident, aud, user = st[:10]
        shard = int(shard)
        if shard == self.shard:
            return
        eid = int(eid)
        cells = tuple(map(int, cells))  # (map: the per-message cost of a generator is not negligible here)
        ok = self.sb.inject_state(shard, int(owner), eid, int(seq), cells, int(vms), bytes(payload), now, str(user),
                                  None if ident is None else str(ident),
                                  None if aud is None else frozenset(map(str, aud)))
        self.stats["states_in" if ok else "states_dropped"] += 1
        if ok:
            self._forget_if_out_of_view(eid, cells)

    def _forget_if_out_of_view(self, eid: int, cells: tuple[int, ...]) -> None:
        """A mirror that moved into cells nobody here watches (and nobody here follows) is dropped now: its owner
        publishes its later states and its LEAVE only to those cells, which we do not subscribe to, so kept it
        would linger unseen until its validity and grace ran out, and a viewer subscribing to its cell meanwhile
        (a client failing over onto this shard) would be shown a ghost beside the entity's real copy."""
        if eid in self.following or eid in self.pending_follows:
            return
        subs = self.sb.subscribers
        for c in cells:
            if c in subs:
                return
        e = self.sb.entities.get(eid)
        if e is not None and not e.followers and e.owner.mirror is not None:
            self.sb.inject_leave(eid)  # its viewers here had their LEAVE when it left their cells
            self.stats["mirrors_out_of_view"] += 1

    def _answer_snapshot(self, cells: list, reply: str, now: float) -> None:
        sb = self.sb
        seen: dict[int, Any] = {}
        for cell in cells:
            for eid in sb.occupants.get(int(cell), ()):
                e = sb.entities[eid]
                if e.owner.mirror is None:
                    seen[eid] = e
        if seen:
            states = [self._state_of(e, now) for e in seen.values()]
            for i in range(0, len(states), 500):
                self._pub(reply, _packb([SNAP_REP, self.shard, states[i : i + 500]]))
            self.stats["snapshot_states_out"] += len(states)

    def _answer_follow(self, eid: int, reply: str, now: float) -> None:
        e = self.sb.entities.get(eid)
        if e is None or e.owner.mirror is not None:
            return  # not ours: its owner answers
        self.remote_followed[eid] = now + self.follow_ttl_s
        self._pub(reply, _packb([SNAP_REP, self.shard, [self._state_of(e, now)]]))

    def _complete_follows(self, now: float) -> None:
        for eid in [x for x in self.pending_follows if x in self.sb.entities]:
            for cid in self.pending_follows.pop(eid):
                self.sb.follow_now(cid, eid)

    def _interest(self, shard: int, added: list, removed: list, whole: bool) -> None:
        """Another shard's cells: a change, or (`whole`) its full set replacing what we knew."""
        if not 0 <= shard < self.regions.shards:
            raise ValueError("no such shard")
        n = self.sb.config.n_cells
        mine = self.interest.setdefault(shard, set())
        new = set(mine) if not whole else set()
        new |= {int(c) for c in added if 0 <= int(c) < n}
        new -= {int(c) for c in removed}
        self._set_interest(shard, new)

    def _set_interest(self, shard: int, new: set[int]) -> None:
        old = self.interest.get(shard, set())
        wanted = self.wanted
        for c in old - new:
            wanted[c] -= 1
            if wanted[c] <= 0:
                del wanted[c]
        for c in new - old:
            wanted[c] += 1
        if new:
            self.interest[shard] = new
        else:
            self.interest.pop(shard, None)

    # ------------------------------------------------------------------------------------------ time
    def tick(self, now: float) -> None:
        """Heartbeats, dead peers, follow interest, queries and follows that ran out of time."""
        self._now_hint = now
        for p in self.peers.values():
            if p.alive and now - p.last_seen >= self.dead_after_s:
                self._declare_dead(p, now)
        if now >= self._next_hb:
            self._heartbeat_out(now)
            self._forget_gone_publishers()
            self._forget_first_publishes()
            self._retry_cameras(now)
        self._retry_held(now)
        self._roam_lingering(now)
        if now >= self._next_interest:  # the whole set now and then: a shard that started late learns it
            self._next_interest = now + 2.0
            self._pub(f"{self.prefix}.i", _packb([INTEREST, self.shard, sorted(self.nats_cells), [], True]))
        for key in [k for k, q in self.queries.items() if q.deadline <= now]:
            self._finish_query(key)
        for eid in list(self.pending_follows):
            waiting = self.pending_follows[eid]
            for cid in [c for c, t in waiting.items() if t <= now]:
                del waiting[cid]
                self.sb.refuse_follow(cid, eid)
            if not waiting:
                del self.pending_follows[eid]
        if now >= self._next_follow_refresh:
            self._next_follow_refresh = now + self.follow_ttl_s / 3
            keep = set(self.pending_follows)
            for eid in self.following:
                e = self.sb.entities.get(eid)
                if e is not None and e.followers and e.owner.mirror is not None:
                    keep.add(eid)
                    self._pub(f"{self.prefix}.f", _packb([FOLLOW_REQ, self.shard, eid]), self.inbox)
            if keep != self.following:
                self.following = keep
                self.wake()

    def next_deadline(self) -> float:
        """When `tick` must next run: the next heartbeat, interest or follow refresh, query or follow timeout, or
        the moment a silent peer is due to be declared dead (not the next heartbeat after it: every survivor
        then decides within a moment of the others)."""
        t = min(self._next_hb, self._next_follow_refresh, self._next_interest, self._linger_deadline())
        for p in self.peers.values():
            if p.alive:
                t = min(t, p.last_seen + self.dead_after_s)
        for q in self.queries.values():
            t = min(t, q.deadline)
        for waiting in self.pending_follows.values():
            t = min(t, *waiting.values())
        return t

    def take_out(self) -> list[tuple[str, bytes, str | None]]:
        """The publications queued since the last call, for the shell to hand to NATS (the core does no I/O)."""
        out, self.out = self.out, []
        return out
