"""The switchboard core: master tables and forwarding, sans-IO.

Tables: entities (owner, occupied cells, validity deadline, latest payload, viewers), cell -> subscribers,
cell -> occupants, direct followers, per-client subscriptions/limits/outbox. The shell feeds decoded messages
with `receive(cid, msgs, now)`, runs `expire(now)` at `next_deadline()`, and writes what `take_dirty()` names.

Each entity keeps the set of clients that currently know it (`viewers`). A PUBLISH computes the new set
(the union of the subscribers of its cells and its followers, minus the owner): the members get the
UPDATE once however many of those cells they hold, and those that dropped out get LEAVE. Set algebra runs
in C, and is skipped when neither the entity's cells nor their subscribers nor its followers changed since
the set was computed (per-cell subscription ticks): the common case of an entity updating in place. An
UPDATE is encoded once per publish (twice when an identity is shown to part of the audience) and the same
bytes are queued for every viewer. Nothing here assumes a single shard: cell ids are plain ints
and a neighbouring shard would be just another client subscribing with the same messages.
"""

from __future__ import annotations

import random
from collections import Counter
from collections.abc import Callable

from entitynet import protocol as P
from entitynet.protocol import ErrorCode
from entitynet.switchboard import access, occupancy
from entitynet.switchboard import outbox as outbox_module
from entitynet.switchboard.config import SwitchConfig
from entitynet.switchboard.mirror import MirrorMixin
from entitynet.switchboard.outbound import OutboundMixin
from entitynet.switchboard.outbox import Outbox
from entitynet.switchboard.privacy import identity_shown
from entitynet.switchboard.querying import QueriesMixin
from entitynet.switchboard.ratelimit import TokenBucket
from entitynet.switchboard.subscribing import SubscriptionsMixin
from entitynet.switchboard.tables import ClientState, EntityState
from entitynet.switchboard.timers import ExpiryHeap

_encode_update = P.encode_update  # the one UPDATE layout (entitynet.protocol.codec), bound for the hot path
_encode_leave = P.encode_leave


class Switchboard(SubscriptionsMixin, OutboundMixin, QueriesMixin, MirrorMixin):
    """The master tables and forwarding (subscriptions in `subscribing.py`, replies and bounds in `outbound.py`,
    queries and privacy in `querying.py`, other shards' entities in `mirror.py`).

    Sans-IO: fed connections, decoded messages and `now`; what to send waits in per-client outboxes
    (`outbox(cid)`, named by `take_dirty()`); what is due (entity expiries, handshake deadlines) happens in
    `expire(now)`, which the shell calls at `next_deadline()`. `authenticate(token) -> user id | None` is the
    shell's token resolver (no store is queried here); None refuses every token unless `config.open_mode`.
    """

    def __init__(self, config: SwitchConfig, now: float = 0.0,
                 authenticate: Callable[[str], str | None] | None = None):
        self.config = config
        self.authenticate = authenticate
        self.clients: dict[int, ClientState] = {}
        self.entities: dict[int, EntityState] = {}
        self.subscribers: dict[int, set[int]] = {}  # cell -> client ids
        self.occupants: dict[int, set[int]] = {}  # cell -> entity ids
        self.by_identity: dict[str, set[int]] = {}  # published identity -> client ids
        self.timers = ExpiryHeap()  # entity id -> validity deadline
        self.hello_timers = ExpiryHeap()  # client id -> handshake deadline
        self.outboxes = outbox_module.new_outboxes(config.max_pending, config.max_control)  # C arrays or dicts
        # the kinds of the id sets (subscribers, viewers; dirty marks): C word arrays with the compiled outboxes
        self._viewer_set, marks = outbox_module.set_kinds(self.outboxes)
        self._dirty: set[int] = marks()
        # a reply was queued outside its client's own frame (a cluster's QUERY answer, FOLLOW refusal, REDIRECT):
        # the reader will not write it, and the shell's flusher must not hold it for its latency budget
        self.replies_waiting = False
        # Subscription ticks: a viewer set computed at tick T stays exact while none of the entity's cells has
        # changed subscribers since (and its followers have not changed), so most PUBLISHes reuse it.
        self._tick = 0
        self._cell_tick: dict[int, int] = {}  # cell -> tick of its last subscriber change
        self._cell_targets: dict[int, tuple[int, tuple]] = {}  # cell -> (tick made, its subscribers' handle)
        self._valid_from = 0  # viewer sets computed before this tick are void (shutdown)
        self._next_cid = 1
        self._rng = random.Random(config.seed)
        self.auth_throttle = access.throttle_for(config)
        self._shut = False
        # the counters the shell reads per frame start at zero: a missing key costs a Python-level __missing__
        self.stats: Counter[str] = Counter(updates_in=0, deliveries=0, leaves=0, slow_consumers=0)
        self.errors: Counter[int] = Counter()
        self._start = now
        # the cluster hook (entitynet.cluster.core.ClusterCore) when sharded: told of every state and LEAVE of a
        # local entity and every subscription change, asked about follows of unknown and queries by identity
        self.cluster = None
        self.mirrors: dict[tuple[int, int], ClientState] = {}  # (shard, owner session) -> stand-in owner

    # ------------------------------------------------------------------------------------------ connections
    def connect(self, now: float, peer: str = "") -> int:
        """A new connection; `peer` keys the failed-login back-off (the shell passes the client's address)."""
        cid = self._next_cid
        self._next_cid += 1
        session = self._rng.randrange(1, P.MAX_INT)
        ob = self.outboxes.open(cid)
        cfg = self.config
        c = ClientState(cid, session, ob, TokenBucket(cfg.query_rate, cfg.query_burst, now),
                        TokenBucket(cfg.churn_rate, cfg.churn_burst, now), peer)
        self.clients[cid] = c
        if cfg.handshake_timeout_s is not None:
            self.hello_timers.set(cid, now + cfg.handshake_timeout_s)
        self.stats["connections"] += 1
        return cid

    def disconnect(self, cid: int, now: float) -> None:
        """The connection is gone: its entities leave at once (a reconnecting client re-publishes)."""
        c = self.clients.pop(cid, None)
        if c is None:
            return
        self.hello_timers.cancel(cid)
        if self._shut:
            self.outboxes.close(cid)
            return
        self._detach(c)
        self.outboxes.close(cid)
        self._dirty.discard(cid)

    def outbox(self, cid: int) -> Outbox | None:
        """The outbox of a connected client (the shell drains it through its API), or None once it is gone."""
        c = self.clients.get(cid)
        return c.outbox if c else None

    def asks_token(self, cid: int, m: P.Hello, now: float) -> bool:
        """Whether a HELLO from this connection, fed now, would be checked with the resolver (access.asks_token)."""
        c = self.clients.get(cid)
        return c is not None and not c.ready and access.asks_token(self.config, self.auth_throttle, m, c.peer, now)

    def user_of(self, cid: int) -> str | None:
        """The user a connected client authenticated as (for the shell's logs), or None."""
        c = self.clients.get(cid)
        return c.user_id if c else None

    def protocol_error(self, cid: int, err: P.ProtocolError) -> None:
        """The shell could not decode this client's bytes."""
        c = self.clients.get(cid)
        if c is not None:
            self._error(c, err.code, err.text)

    def shutdown(self) -> None:
        """Tell every client SHUTTING_DOWN and stop forwarding. Tables are left as they are (not detached
        client by client, which costs time proportional to all subscriptions): the switchboard is done."""
        enc = P.encode_message(P.Error(int(ErrorCode.SHUTTING_DOWN), "server shutting down"))
        for c in self.clients.values():
            c.outbox.discard_states()
            c.outbox.put_last_word(enc)
            c.closing = True
            self._dirty.add(c.cid)
        self.errors[int(ErrorCode.SHUTTING_DOWN)] += len(self.clients)
        self.subscribers.clear()
        self._tick += 1
        self._valid_from = self._tick
        self.by_identity.clear()
        self._shut = True

    # ------------------------------------------------------------------------------------------ messages in
    def receive(self, cid: int, msgs: list[P.Message], now: float, frame_end: bool = True) -> None:
        """Handle messages of one client. A shell may feed one frame in several slices (serving other clients
        in between); `frame_end=False` on all but the last, since the reply bound counts per frame."""
        c = self.clients.get(cid)
        if c is None:
            return
        cap = self.config.max_replies_per_frame
        # the compiled PUBLISH run (`_fanout.publish_run`) takes the common PUBLISHes in one C loop and leaves
        # the rest (refusals, new entities, stale seqs, followers, identities) to `_publish` below
        run = outbox_module.compiled_publish_run(self.outboxes) if self.cluster is None else None
        i, n = 0, len(msgs)
        while i < n:
            if c.closing:
                return
            m = msgs[i]
            t = type(m)
            if t is P.Publish and run is not None and c.ready:
                j = run(self, c, msgs, i, P.Publish, now)
                if j != i:
                    i = j
                    continue
            i += 1
            if (t is P.Ping or t is P.Query) and c.replies >= cap and c.ready:
                c.refused += 1  # not answered, not executed: the frame asked for too many replies
                continue
            if not c.ready:
                if t is P.Hello:
                    self._hello(c, m, now)
                else:
                    self._error(c, ErrorCode.HANDSHAKE_REQUIRED, "the first message must be HELLO")
                continue
            if t is P.Publish:
                self._publish(c, m, now)
            elif t is P.Subscribe:
                self._subscribe(c, m, now)
            elif t is P.Ping:
                self._reply_msg(c, P.Pong(m.client_ms, P.now_ms(max(now, 0.0))))
            elif t is P.Unpublish:
                self._unpublish(c, m)
            elif t is P.Follow:
                self._follow(c, m)
            elif t is P.Unfollow:
                self._unfollow(c, m)
            elif t is P.Query:
                self._query(c, m, now)
            elif t is P.Privacy:
                self._privacy(c, m)
            elif t is P.Camera:  # kept for the cluster's viewer roaming; one server has nothing to do with it
                c.camera = (m.x, m.y, m.z)
                if self.cluster is not None:
                    self.cluster.on_camera(c, now)
            elif t is P.Hello:
                self._error(c, ErrorCode.BAD_FIELD, "HELLO sent twice")
            else:
                self._error(c, ErrorCode.UNKNOWN_TYPE, f"{t.__name__} is a server-to-client message")
        if frame_end:
            self._end_frame(c)

    # ------------------------------------------------------------------------------------------ handshake
    def _hello(self, c: ClientState, m: P.Hello, now: float) -> None:
        cfg = self.config
        user, err = access.admit(cfg, self.auth_throttle, m, c.peer, c.session, now, self.authenticate)
        if user is None:
            self._error(c, err.code, err.text)
            return
        c.user_id = user
        if not cfg.open_mode:
            c.token = m.token
        c.ready = True
        self.hello_timers.cancel(c.cid)
        limits = cfg.wire_limits()
        if self.cluster is not None:
            limits["camera"] = 1  # a shard roams viewers by their camera: clients may send CAMERA
        self._reply_msg(c, P.Welcome(P.PROTOCOL_VERSION, c.session, P.now_ms(max(now, 0.0)), limits))

    # ------------------------------------------------------------------------------------------ publishing
    def _publish(self, c: ClientState, m: P.Publish, now: float) -> None:
        cfg = self.config
        local = m.entity
        if local >= P.LOCAL_ID_LIMIT:
            self._error(c, ErrorCode.NOT_OWNER, f"entity {local} is not one of yours (local ids are < 2**32)")
            return
        n = cfg.n_cells
        for cell in m.cells:
            if cell >= n:
                self._error(c, ErrorCode.NO_SUCH_CELL, f"cell {cell} does not exist (this map has {n})")
                return
        eid = c.entities.get(local)
        if eid is None:
            if self.cluster is not None and not self.cluster.admit(c, m.cells, now, m):
                return  # sharded: the entity belongs elsewhere; REDIRECTed before anyone here sees it
            if len(c.entities) >= cfg.max_entities_per_client or len(self.entities) >= cfg.max_entities:
                self._error(c, ErrorCode.LIMIT_ENTITIES, f"at most {cfg.max_entities_per_client} entities")
                return
            eid = self._new_eid()
            e = EntityState(eid, c, local)
            self.entities[eid] = e
            c.entities[local] = eid
            self.stats["entities_created"] += 1
        else:
            e = self.entities[eid]
            if m.seq <= e.seq:
                self.stats["stale"] += 1  # out of order or duplicate: the newer state already went out
                return
        self.stats["updates_in"] += 1
        self._apply_state(c, e, m.seq, m.cells, m.validity_ms, m.payload, now)

    def _apply_state(self, c: ClientState, e: EntityState, seq: int, new: tuple[int, ...], validity_ms: int,
                     payload: bytes, now: float) -> None:
        """A new state of entity `e` (local or mirrored): tables, expiry, delivery, LEAVEs, the cluster hook."""
        cfg = self.config
        eid = e.eid
        old = e.cells
        if old != new:
            occupancy.move(self.occupants, eid, old, new)
            e.cells = new
        e.seq = seq
        e.validity_ms = validity_ms
        e.payload = payload
        e.enc_plain = _encode_update(eid, seq, new, validity_ms, payload)
        e.enc_ident = None
        self.timers.set(eid, now + validity_ms / 1000.0 + cfg.grace_s)
        self._route(c, e, old, new)
        if self.cluster is not None and c.mirror is None:
            self.cluster.on_state(c, e, old, now)  # after delivery: it may REDIRECT the owner (LEAVEs follow)

    def _route(self, c: ClientState, e: EntityState, old: tuple[int, ...], new: tuple[int, ...]) -> None:
        """Deliver the new state to the entity's viewers, LEAVE to those who no longer see it: in C
        (`_fanout.route`) where it was built and the entity has no followers and shows no identity (nearly every
        PUBLISH), else `_route_py`, the reference; both leave the same tables and outboxes behind. (Cells that are
        not tuples come only from code feeding the core directly, never from the decoder: the reference takes them.)"""
        fast = outbox_module.compiled_route(self.outboxes)
        if fast is not None and not e.followers and e.owner.identity is None and type(new) is tuple \
                and type(old) is tuple:
            fast(self, c, e, old, new)
        else:
            self._route_py(c, e, old, new)

    def _route_py(self, c: ClientState, e: EntityState, old: tuple[int, ...], new: tuple[int, ...]) -> None:
        """`_route` in Python: the reference of the compiled route, and the path for followers and identities."""
        eid = e.eid
        t = e.viewers_tick
        if t >= self._valid_from and (old is new or old == new):
            cell_tick = self._cell_tick
            for cell in new:
                if cell_tick.get(cell, 0) > t:
                    break
            else:  # nobody (un)subscribed to these cells or (un)followed it: the viewers are the same
                viewers = e.viewers
                if e.targets is None and viewers:  # the set's second use: resolve its outboxes once
                    e.targets = self.outboxes.targets(viewers)
                self._deliver(e, viewers, e.targets)
                return
        viewers: set[int] = set()
        subs = self.subscribers
        for cell in new:
            s = subs.get(cell)
            if s:
                viewers.update(s)
        if e.followers:
            viewers |= e.followers
        if c.cid in viewers or e.followers or e.owner.identity is not None:
            viewers.discard(c.cid)
            self._deliver(e, viewers, None)
        elif viewers:  # exactly the cells' subscribers: store through the cells' handles
            self._deliver_to_cells(e, viewers, new)
        gone = e.viewers - viewers
        if gone:
            self._leave(eid, gone)
        e.viewers = viewers if self._viewer_set is set else self._viewer_set(viewers)
        e.targets = None  # resolved when the set is reused (many entities change cells at every publish)
        e.viewers_tick = self._tick

    def _deliver(self, e: EntityState, viewers: set[int], targets: tuple | None) -> None:
        """Queue the entity's new state for `viewers`: through `targets` (an `Outboxes.targets` handle made with
        this set) when there is one, else by client id."""
        if not viewers:
            return
        eid = e.eid
        if e.owner.identity is not None:
            clients = self.clients
            for v in viewers:
                c = clients[v]
                c.outbox.put_state(eid, self._encoded_for(e, c))
        elif targets is not None:
            self.outboxes.fan_out_to(targets, eid, e.enc_plain)
        else:
            self.outboxes.fan_out(viewers, eid, e.enc_plain)
        self._dirty |= viewers
        self.stats["deliveries"] += len(viewers)

    def _deliver_to_cells(self, e: EntityState, viewers: set[int], cells: tuple[int, ...]) -> None:
        """`_deliver` for a viewer set that is exactly the union of `cells`' subscribers (no followers, not the
        owner, no identity shown): the stores go through one `Outboxes.targets` handle per cell, kept until the
        cell's subscribers change (per-cell ticks), instead of a client-id lookup per delivery. A viewer in two
        of the cells gets the same bytes stored twice under the same key: the same outbox afterwards (a dict
        keeps a key's first position), so frames are unchanged."""
        eid, enc = e.eid, e.enc_plain
        handles, tick, cell_tick, subs = self._cell_targets, self._tick, self._cell_tick, self.subscribers
        fan_out_to = self.outboxes.fan_out_to
        for cell in cells:
            h = handles.get(cell)
            if h is None or h[0] < cell_tick.get(cell, 0) or h[0] < self._valid_from:
                s = subs.get(cell)
                if not s:
                    continue
                h = handles[cell] = (tick, self.outboxes.targets(s))
            fan_out_to(h[1], eid, enc)
        self._dirty |= viewers
        self.stats["deliveries"] += len(viewers)

    def _encoded_for(self, e: EntityState, viewer: ClientState) -> bytes:
        ident = identity_shown(e.owner, viewer)
        if ident is None:
            return e.enc_plain
        if e.enc_ident is None:
            e.enc_ident = _encode_update(e.eid, e.seq, e.cells, e.validity_ms, e.payload, ident)
        return e.enc_ident

    def _leave(self, eid: int, clients: set[int]) -> None:
        self.outboxes.fan_out_open(clients, eid, _encode_leave(eid))
        self._dirty |= clients
        self.stats["leaves"] += len(clients)

    def _new_eid(self) -> int:
        while True:
            eid = self._rng.randrange(P.LOCAL_ID_LIMIT, P.MAX_INT)
            if eid not in self.entities:
                return eid

    def _unpublish(self, c: ClientState, m: P.Unpublish) -> None:
        if m.entity >= P.LOCAL_ID_LIMIT:
            self._error(c, ErrorCode.NOT_OWNER, f"entity {m.entity} is not one of yours")
            return
        eid = c.entities.get(m.entity)
        if eid is None:
            self._error(c, ErrorCode.NO_SUCH_ENTITY, f"you publish no entity {m.entity}")
            return
        self._remove_entity(self.entities[eid])

    def _remove_entity(self, e: EntityState) -> None:
        eid = e.eid
        del self.entities[eid]
        if self.cluster is not None and e.owner.mirror is None:
            self.cluster.on_leave(e)
        e.owner.entities.pop(e.local, None)
        self.timers.cancel(eid)
        occ = self.occupants
        for cell in e.cells:
            s = occ.get(cell)
            if s is not None:
                s.discard(eid)
                if not s:
                    del occ[cell]
        for f in e.followers:
            fc = self.clients.get(f)
            if fc is not None:
                fc.follows.discard(eid)
        if e.viewers:
            self._leave(eid, e.viewers)
        self.outboxes.forget(eid)
        e.viewers = self._viewer_set()
        e.targets = None

    def expire(self, now: float) -> int:
        """Do what is due at `now`: remove entities whose validity (plus grace) ran out without an update
        (returns how many), and close connections that sent no HELLO within `handshake_timeout_s`."""
        for cid in self.hello_timers.pop_due(now):
            c = self.clients.get(cid)
            if c is not None and not c.ready and not c.closing:
                self._error(c, ErrorCode.HANDSHAKE_REQUIRED,
                            f"no HELLO within {self.config.handshake_timeout_s:g} s")
        n = 0
        for eid in self.timers.pop_due(now):
            e = self.entities.get(eid)
            if e is not None:
                self._remove_entity(e)
                n += 1
        self.stats["expired"] += n
        return n

    def next_deadline(self) -> float | None:
        """When `expire` next has something to do (the earliest entity expiry or handshake deadline), in the
        clock of the `now`s fed; None when nothing is pending. The shell sleeps until then instead of polling."""
        a, b = self.timers.next_deadline(), self.hello_timers.next_deadline()
        if a is None:
            return b
        return a if b is None or a <= b else b

    # ------------------------------------------------------------------------------------------ helpers
    def _detach(self, c: ClientState) -> None:
        """Remove a client's entities, subscriptions and follows from the tables (it keeps its outbox)."""
        for eid in list(c.entities.values()):
            self._remove_entity(self.entities[eid])
        cid = c.cid
        self._tick += 1
        cell_tick = self._cell_tick
        for cell in c.subs:
            s = self.subscribers.get(cell)
            if s is not None:
                s.discard(cid)
                if not s:
                    del self.subscribers[cell]
            cell_tick[cell] = self._tick
            self._cell_targets.pop(cell, None)  # its handle names this client's outbox: let it go now
        for cell in c.subs:
            for eid in self.occupants.get(cell, ()):
                self.entities[eid].viewers.discard(cid)
        c.subs = set()
        for eid in c.follows:
            e = self.entities.get(eid)
            if e is not None:
                e.followers.discard(cid)
                e.viewers.discard(cid)
                e.viewers_tick = -1
        c.follows = set()
        if c.identity is not None:
            s = self.by_identity.get(c.identity)
            if s is not None:
                s.discard(cid)
                if not s:
                    del self.by_identity[c.identity]
        c.ready = c.ready and not c.closing

    # ------------------------------------------------------------------------------------------ introspection
    def counts(self) -> dict[str, int]:
        """Table sizes for the metrics."""
        return {
            "clients": len(self.clients),
            "entities": len(self.entities),
            "subscriptions": sum(len(c.subs) for c in self.clients.values()),
            "follows": sum(len(c.follows) for c in self.clients.values()),
            "timers": self.timers.heap_size,
        }
