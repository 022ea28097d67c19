"""The client side of protocol v1 as a sans-IO state machine (the h11 shape): events and `now` in, actions out.

Why a plain class: everything a client must remember and decide (the latest PUBLISH of every entity, the cell
subscription, follows, privacy, the clock offset, when to reconnect, which errors are final, where a REDIRECT
sends what) can then be driven by tests and simulations deterministically, without sockets or trio; the trio
`entitynet.connection.Connection` only moves frames and sleeps until `next_deadline(now)`.

Links: the session talks to one *home* shard (the viewer's subscriptions, follows, queries, new entities) and,
after a REDIRECT that names entities, to further shards for those. Each network attempt has a token (`link`);
the shell reports `connection_made`, `receive` and `connection_lost` with it. Server-assigned entity ids are per
session: every home WELCOME is delivered, and the application must then forget the entities it knew.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from entitynet import protocol as P
from entitynet.session.batching import batches as _batches
from entitynet.session.clock import ClockEstimate
from entitynet.session.events import Action, Answer, Connect, Deliver, Drop, Notice, Send, Stop
from entitynet.session.policy import Address, ReconnectPolicy, parse_address

#: messages only a client sends: a server sending one is broken, and the link is dropped
_CLIENT_ONLY = (P.Hello, P.Publish, P.Unpublish, P.Subscribe, P.Follow, P.Unfollow, P.Query, P.Privacy, P.Ping,
                P.Camera)
#: errors that refuse the oldest pending query (the server answers queries in order)
_QUERY_REFUSALS = (P.ErrorCode.QUERY_RATE, P.ErrorCode.NO_SUCH_CELL)
MAX_PINGS = 16  # unanswered pings remembered


@dataclass
class _Sent:
    msg: P.Publish
    at: float  # local time when published, to shorten the validity when replaying


@dataclass
class _Link:
    address: Address
    phase: str = "waiting"  # waiting -> dialing -> handshake -> open -> waiting ...
    token: int | None = None  # the current attempt
    dropping: bool = False  # a Drop was asked: ignore the attempt's input until it is reported lost
    failures: int = 0  # consecutive attempts that ended without or after a WELCOME, reset by a WELCOME
    retry_at: float = 0.0
    failing_since: float = 0.0  # when the current run of failures began
    handshake_deadline: float = math.inf
    next_ping: float = math.inf
    throttle: float = 0.0  # extra wait an AUTH_THROTTLED refusal asked for
    pings: dict[int, float] = field(default_factory=dict)  # PING client_ms -> local send time
    max_frame: int = P.DEFAULT_LIMITS.max_frame  # ours, or the server's from WELCOME when smaller
    camera: bool = False  # the server's WELCOME announced CAMERA (a shard): older servers refuse the type


class ClientSession:
    """Replay memory, subscriptions, follows, privacy, clock offset, reconnect policy and REDIRECTs, no I/O.

    Every method taking `now` (seconds, local clock) returns the list of actions (`entitynet.session.events`)
    for the shell to carry out in order. Time that goes backwards is not an error: deadlines and remembered
    send times are moved back with it and the clock samples are forgotten (they measured the old clock).
    """

    def __init__(self, address: Address, digest: str, token: str = "", *,
                 policy: ReconnectPolicy | None = None, ping_interval: float = 5.0,
                 handshake_timeout: float = 10.0, alternates: tuple[Address, ...] = (), failover_s: float = 3.0,
                 failover_attempts: int = 2):
        for name, v in (("ping_interval", ping_interval), ("handshake_timeout", handshake_timeout)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number of seconds, got {v!r}")
        self.home: Address = address
        # other shards of the cluster (given, or learned from REDIRECTs): once a shard has failed
        # `failover_attempts` attempts in a row (the lost link and one redial: a SIGKILLed shard refuses at once),
        # or every attempt for `failover_s` (a shard that does not answer at all), what it carried moves to the
        # next of these at once. A survivor holds a first PUBLISH for a dying shard's region until that shard is
        # declared dead, then serves it or REDIRECTs it to the region's new owner (entitynet.cluster.failover),
        # so moving early costs no duplicate and no second wait
        self.alternates: list[Address] = [a for a in alternates if a != address]
        self.failover_s = float(failover_s)
        if failover_attempts < 0:
            raise ValueError(f"failover_attempts must be >= 0 (0: by time only), got {failover_attempts!r}")
        self.failover_attempts = int(failover_attempts)
        self._failover_turn = 0
        self.digest = digest
        self.token = token
        self.policy = policy or ReconnectPolicy()
        self.ping_interval = ping_interval
        self.handshake_timeout = handshake_timeout
        self.clock = ClockEstimate()
        self.welcome: P.Welcome | None = None
        self.connects = 0  # WELCOMEs received, on any link
        self.finished = False
        self._links: dict[Address, _Link] = {}
        self._by_token: dict[int, _Link] = {}
        self._tokens = 0
        self._published: dict[int, _Sent] = {}
        self._where: dict[int, Address] = {}  # entity -> the shard that carries it
        self._subs: set[int] = set()
        self._follows: set[int] = set()
        self._privacy: P.Privacy | None = None
        self._camera: P.Camera | None = None
        self._queries: dict[int, None] = {}  # pending query ids, oldest first
        self._next_query = 1
        self._last_now: float | None = None

    # ------------------------------------------------------------------------------------------ state
    @property
    def connected(self) -> bool:
        """True while the home link has completed its handshake (publishes and subscriptions go out now)."""
        link = self._links.get(self.home)
        return link is not None and link.phase == "open" and not link.dropping

    @property
    def subscriptions(self) -> frozenset[int]:
        """The cells we are subscribed to (as the home shard will know them after the next replay)."""
        return frozenset(self._subs)

    @property
    def published(self) -> dict[int, P.Publish]:
        """The latest PUBLISH of every entity we carry, as replayed after a reconnect."""
        return {e: s.msg for e, s in self._published.items()}

    def where(self, entity: int) -> Address | None:
        """The shard address that carries `entity`, or None when it is not published."""
        return self._where.get(entity) if entity in self._published else None

    def server_time(self, now: float) -> float:
        """The server clock at local time `now`, as well as we know it (`now` itself until a PONG arrives)."""
        return now + (self.clock.offset or 0.0)

    # ------------------------------------------------------------------------------------------ events from the shell
    def start(self, now: float) -> list[Action]:
        """Begin: dial the home shard."""
        self._now(now)
        if self.finished or self.home in self._links:
            return []
        link = self._links[self.home] = _Link(self.home)
        return [self._dial(link, now)]

    def connection_made(self, link: int, now: float) -> list[Action]:
        """The attempt's stream is open: say HELLO and wait for WELCOME until the handshake deadline."""
        now = self._now(now)
        lk = self._live(link)
        if lk is None or lk.phase != "dialing":
            return []
        lk.phase = "handshake"
        return [Send(link, (P.Hello(P.PROTOCOL_VERSION, self.token, self.digest),))]

    def receive(self, link: int, msgs: list[P.Message], now: float) -> list[Action]:
        """One decoded frame from attempt `link`. A protocol violation drops that link (and it is retried);
        a final refusal ends the session; everything else is delivered or answered."""
        now = self._now(now)
        lk = self._live(link)
        out: list[Action] = []
        if lk is None:
            return out
        for m in msgs:
            if self.finished or lk.dropping:
                break
            if lk.phase != "open":
                self._handshake(lk, m, now, out)
            else:
                self._message(lk, m, now, out)
        return out

    def delivers_whole(self, link: int, msgs: list[P.Message], now: float) -> bool:
        """Whether `receive(link, msgs, now)` would do nothing but Deliver each message in order (an open link
        not being dropped, every message an UPDATE or LEAVE), so that a shell may hand the frame on whole
        (a simulation's viewer fleet: sims.engine.viewer_fleet). Takes `now` as `receive` does."""
        self._now(now)
        lk = self._live(link)
        if lk is None or lk.phase != "open" or lk.dropping:
            return False
        for m in msgs:
            t = type(m)
            if t is not P.Update and t is not P.Leave:
                return False
        return True

    def connection_lost(self, link: int, now: float, error: str | None = None) -> list[Action]:
        """Attempt `link` ended (by the peer, the network, or a Drop): schedule the next attempt, or stop."""
        now = self._now(now)
        lk = self._by_token.pop(link, None)
        if lk is None or lk.token != link:
            return []
        lk.token, lk.phase, lk.dropping = None, "waiting", False
        lk.handshake_deadline = lk.next_ping = math.inf
        lk.pings.clear()
        if self.finished or self._links.get(lk.address) is not lk:
            return []
        out: list[Action] = [Notice(f"connection to {lk.address} lost: {error or 'closed'}")]
        if not self.policy.retry:
            self.finished = True
            out.append(Stop(None))
            return out
        lk.failures += 1
        lk.retry_at = now + max(self.policy.delay(lk.failures), lk.throttle)
        throttled, lk.throttle = lk.throttle > 0, 0.0
        if lk.failures == 1:
            lk.failing_since = now
        if self.alternates and not throttled and (now - lk.failing_since >= self.failover_s
                                                  or 0 < self.failover_attempts <= lk.failures):
            self._fail_over(lk, now, out)
        return out

    def _fail_over(self, lk: _Link, now: float, out: list[Action]) -> None:
        """The shard at `lk` keeps failing: move what it carries to the next alternate shard (round robin)."""
        cands = [a for a in self.alternates if a != lk.address]
        if not cands:
            return
        target = cands[self._failover_turn % len(cands)]
        self._failover_turn += 1
        out.append(Notice(f"{lk.address} keeps failing: moving to {target}"))
        self._move(lk, target, None, now, out)

    def next_deadline(self, now: float) -> float | None:
        """The earliest local time at which `timers` has something to do (None: nothing until an event)."""
        now = self._now(now)
        best = math.inf
        for lk in self._links.values():
            if lk.phase == "waiting":
                best = min(best, lk.retry_at)
            elif lk.phase in ("dialing", "handshake") and not lk.dropping:
                best = min(best, lk.handshake_deadline)
            elif lk.phase == "open" and lk.address == self.home:
                best = min(best, lk.next_ping)
        return None if self.finished or best == math.inf else best

    def timers(self, now: float) -> list[Action]:
        """Whatever is due at `now`: handshake timeouts, reconnect attempts, the home link's PING."""
        now = self._now(now)
        out: list[Action] = []
        if self.finished:
            return out
        for lk in list(self._links.values()):
            if lk.phase == "waiting" and now >= lk.retry_at:
                out.append(self._dial(lk, now))
            elif lk.phase in ("dialing", "handshake") and not lk.dropping and now >= lk.handshake_deadline:
                lk.dropping = True
                out.append(Drop(lk.token, f"no WELCOME within {self.handshake_timeout:g} s"))
            elif lk.phase == "open" and lk.address == self.home and now >= lk.next_ping:
                out.extend(self._ping(lk, now))
        return out

    # ------------------------------------------------------------------------------------------ application calls
    def publish(self, msgs: tuple[P.Publish, ...] | list[P.Publish], now: float) -> list[Action]:
        """Remember each entity's latest state and send it to the shard that carries it (if connected)."""
        now = self._now(now)
        per_link: dict[Address, list[P.Message]] = {}
        for m in msgs:
            self._published[m.entity] = _Sent(m, now)
            addr = self._where.setdefault(m.entity, self.home)
            per_link.setdefault(addr, []).append(m)
        return [a for addr, ms in per_link.items() for a in self._send_to(addr, ms)]

    def unpublish(self, entity: int) -> list[Action]:
        """Forget an entity and tell its shard; a shard left carrying nothing is disconnected."""
        self._published.pop(entity, None)
        addr = self._where.pop(entity, self.home)
        return self._send_to(addr, [P.Unpublish(entity)]) + self._prune()

    def subscribe(self, added=(), removed=()) -> list[Action]:
        """Add and remove cells (removal first, as the server applies it); sends the diff as given."""
        added, removed = tuple(sorted(set(added))), tuple(sorted(set(removed)))
        self._subs.difference_update(removed)
        self._subs.update(added)
        return self._send_to(self.home, [P.Subscribe(added, removed)])

    def set_camera(self, x: float, y: float, z: float = 0.0) -> list[Action]:
        """The viewer's camera: kept (re-sent first after a reconnect or REDIRECT), sent where WELCOME said `camera`."""
        for v in (x, y, z):
            if not (math.isfinite(v) and abs(v) <= P.MAX_COORD):
                raise ValueError(f"camera coordinates must be finite metres, got {(x, y, z)!r}")
        self._camera = P.Camera(float(x), float(y), float(z))
        lk = self._links.get(self.home)
        return self._send_to(self.home, [self._camera]) if lk is not None and lk.camera else []

    def set_subscription(self, cells) -> list[Action]:
        """Subscribe to exactly these cells, sending only the difference (nothing when there is none)."""
        want = set(cells)
        added, removed = want - self._subs, self._subs - want
        return self.subscribe(added, removed) if added or removed else []

    def follow(self, entity: int) -> list[Action]:
        """Follow an entity (server id) regardless of cells."""
        self._follows.add(entity)
        return self._send_to(self.home, [P.Follow(entity)])

    def unfollow(self, entity: int) -> list[Action]:
        """Stop following an entity."""
        self._follows.discard(entity)
        return self._send_to(self.home, [P.Unfollow(entity)])

    def set_privacy(self, identity: str | None, audience=None) -> list[Action]:
        """Set our identity and audience on every shard we publish to (it binds to the connection there)."""
        self._privacy = P.Privacy(identity, None if audience is None else tuple(audience))
        return [a for addr in list(self._links) for a in self._send_to(addr, [self._privacy])]

    def query(self, kind: str, arg: Any) -> tuple[int, list[Action]]:
        """Ask the home shard; the answer comes back as `Answer(query_id, ...)`. Returns (query_id, actions)."""
        qid = self._next_query
        self._next_query += 1
        self._queries[qid] = None
        return qid, self._send_to(self.home, [P.Query(qid, kind, tuple(arg) if kind == P.QUERY_CELLS else arg)])

    def forget_query(self, query_id: int) -> None:
        """The asker gave up (timeout): a late answer is then ignored, and a refusal maps to an older query."""
        self._queries.pop(query_id, None)

    def ping(self, now: float) -> list[Action]:
        """PING the home shard now (the session also pings every `ping_interval` by itself)."""
        now = self._now(now)
        lk = self._links.get(self.home)
        return self._ping(lk, now) if lk is not None and lk.phase == "open" else []

    # ------------------------------------------------------------------------------------------ inside
    def _now(self, now: float) -> float:
        """Reject non-finite times; when time went backwards, move every remembered time back with it."""
        if not isinstance(now, (int, float)) or not math.isfinite(now):
            raise ValueError(f"now must be a finite number of seconds, got {now!r}")
        last = self._last_now
        if last is not None and now < last:
            back = last - now
            for lk in self._links.values():
                lk.retry_at -= back
                lk.handshake_deadline -= back
                lk.next_ping -= back
                lk.pings.clear()  # their round trips would span the step
            for s in self._published.values():
                s.at -= back
            self.clock.clear()  # the offset to the server changed by the step
        self._last_now = now
        return now

    def _live(self, token: int) -> _Link | None:
        lk = self._by_token.get(token)
        return lk if lk is not None and lk.token == token and not self.finished else None

    def _dial(self, lk: _Link, now: float) -> Connect:
        self._tokens += 1
        lk.token, lk.phase, lk.dropping = self._tokens, "dialing", False
        lk.handshake_deadline = now + self.handshake_timeout
        self._by_token[lk.token] = lk
        return Connect(lk.token, lk.address)

    def _send_to(self, addr: Address, msgs: list[P.Message]) -> list[Action]:
        lk = self._links.get(addr)
        if lk is None or lk.phase != "open" or lk.dropping or not msgs:
            return []  # remembered; the replay after the (re)connect carries it
        return [Send(lk.token, batch) for batch in _batches(msgs, lk.max_frame)]

    def _handshake(self, lk: _Link, m: P.Message, now: float, out: list[Action]) -> None:
        if type(m) is P.Welcome:
            lk.phase, lk.failures, lk.handshake_deadline = "open", 0, math.inf
            announced = m.limits.get("max_frame")
            if isinstance(announced, int) and announced > 0:
                lk.max_frame = min(P.DEFAULT_LIMITS.max_frame, announced)
            lk.camera = m.limits.get("camera") == 1
            self.connects += 1
            out.extend(self._replay(lk, now))
            if lk.address == self.home:
                self.welcome = m
                out.append(Deliver(m))
                out.extend(self._ping(lk, now))
            return
        lk.dropping = True
        if type(m) is P.Error and self.policy.is_final(m.code):
            self.finished = True
            out.append(Stop(m))
        elif type(m) is P.Error:
            lk.throttle = self.policy.throttled_for(m)
            out.append(Drop(lk.token, f"refused: {m.code} {m.text}"))
        else:
            out.append(Drop(lk.token, f"expected WELCOME, got {m!r:.80}"))

    def _message(self, lk: _Link, m: P.Message, now: float, out: list[Action]) -> None:
        t = type(m)
        if t is P.Update or t is P.Leave:
            out.append(Deliver(m))
        elif t is P.Pong:
            sent = lk.pings.pop(m.client_ms, None)
            if sent is not None and lk.address == self.home:
                self.clock.add(sent, now, m.server_ms / 1000.0)
        elif t is P.QueryResult:
            if m.query_id in self._queries:
                del self._queries[m.query_id]
                out.append(Answer(m.query_id, m))
        elif t is P.Error:
            if self.policy.is_final(m.code):
                self.finished = True
                out.append(Stop(m))
                return
            if m.code in _QUERY_REFUSALS and self._queries:
                qid = next(iter(self._queries))
                del self._queries[qid]
                out.append(Answer(qid, m))
            out.append(Deliver(m))
        elif isinstance(m, P.Redirect):
            self._redirect(lk, m, now, out)
            out.append(Deliver(m))
        else:
            what = "a second WELCOME" if t is P.Welcome else f"a client-only message {m!r:.60}"
            lk.dropping = True
            out.append(Drop(lk.token, f"server sent {what}"))

    def _redirect(self, lk: _Link, m: P.Redirect, now: float, out: list[Action]) -> None:
        """Move the named entities (a REDIRECT listing them) or everything this link carries, the viewer
        included when it is home, to the shard at `m.address`; re-send there what now belongs there."""
        try:
            target = parse_address(m.address)
        except ValueError as exc:
            out.append(Notice(f"ignored REDIRECT: {exc}"))
            return
        if target == lk.address:
            return
        if target not in self.alternates:
            self.alternates.append(target)
        if lk.address not in self.alternates:
            self.alternates.append(lk.address)
        self._move(lk, target, getattr(m, "entities", None), now, out)

    def _move(self, lk: _Link, target: Address, named, now: float, out: list[Action]) -> None:
        """Move `named` entities (None: everything `lk` carries, the viewer included when it is home) to
        `target`, dialling it if needed; links left with nothing to carry are dropped."""
        here = [e for e, a in self._where.items() if a == lk.address and e in self._published]
        moving = here if named is None else [e for e in here if e in set(named)]
        viewer = named is None and lk.address == self.home
        for e in moving:
            self._where[e] = target
        if named is not None and moving:
            out.extend(self._send_to(lk.address, [P.Unpublish(e) for e in moving]))
        if viewer:
            self.home = target
            self.clock.clear()  # another server, another clock
        dest = self._links.get(target)
        if dest is None:
            dest = self._links[target] = _Link(target)
            out.append(self._dial(dest, now))
        elif dest.phase == "open" and not dest.dropping:
            msgs = self._viewer_state(dest) if viewer else []
            msgs += self._entity_states(moving, now)
            out.extend(Send(dest.token, batch) for batch in _batches(msgs, dest.max_frame))
        out.extend(self._prune())

    def _prune(self) -> list[Action]:
        """Disconnect every link that is neither home nor carrying an entity."""
        used = {self._where[e] for e in self._published if e in self._where} | {self.home}
        out: list[Action] = []
        for addr in [a for a in self._links if a not in used]:
            lk = self._links.pop(addr)
            if lk.token is not None:
                out.append(Drop(lk.token, "nothing left to carry on this shard"))
        return out

    def _viewer_state(self, lk: _Link) -> list[P.Message]:
        msgs: list[P.Message] = [self._camera] if self._camera is not None and lk.camera else []
        if self._subs:
            msgs.append(P.Subscribe(tuple(sorted(self._subs)), ()))
        msgs.extend(P.Follow(e) for e in sorted(self._follows))
        return msgs

    def _entity_states(self, entities, now: float) -> list[P.Message]:
        msgs: list[P.Message] = []
        for e in entities:
            s = self._published[e]
            m = s.msg
            left = max(0, m.validity_ms - int(max(0.0, now - s.at) * 1000))
            msgs.append(P.Publish(m.entity, m.seq, m.cells, left, m.payload))
        return msgs

    def _replay(self, lk: _Link, now: float) -> list[Action]:
        """After a WELCOME: privacy, then (home only) subscription and follows, then the latest state of
        every entity this link carries, with its validity shortened by the time since it was published."""
        msgs: list[P.Message] = [self._privacy] if self._privacy is not None else []
        if lk.address == self.home:
            msgs += self._viewer_state(lk)
        mine = [e for e in self._published if self._where.get(e) == lk.address]
        msgs += self._entity_states(mine, now)
        return [Send(lk.token, batch) for batch in _batches(msgs, lk.max_frame)]

    def _ping(self, lk: _Link, now: float) -> list[Action]:
        lk.next_ping = now + self.ping_interval
        if now < 0:
            return []  # the wire carries non-negative milliseconds only
        ms = P.now_ms(now)
        lk.pings[ms] = now
        while len(lk.pings) > MAX_PINGS:
            lk.pings.pop(next(iter(lk.pings)))
        return [Send(lk.token, (P.Ping(ms),))]

