"""The switchboard core's records: one per connection (`ClientState`) and one per published entity
(`EntityState`).

Apart from the core's logic so that the mixins (subscribing, outbound) and the privacy rules can name them
without importing the core. `__slots__` on purpose: the forwarding hot path reads these attributes millions of
times and a switch holds tens of thousands of them.
"""

from __future__ import annotations

from entitynet.switchboard.outbox import Outbox
from entitynet.switchboard.ratelimit import TokenBucket


class ClientState:
    """What the core knows of one connection: its session, user, privacy, subscriptions, follows, published
    entities, budgets and outbox."""

    __slots__ = (
        "cid", "session", "user_id", "identity", "audience", "ready", "closing", "subs", "follows",
        "entities", "bucket", "churn", "outbox", "replies", "refused", "peer", "token", "mirror",
        "camera",
    )

    def __init__(self, cid: int, session: int, outbox: Outbox, bucket: TokenBucket, churn: TokenBucket,
                 peer: str = ""):
        self.cid = cid
        self.session = session
        self.peer = peer  # the address failed logins are throttled by (access.admit)
        self.token: str | None = None  # kept to re-check it after a revocation (access.revalidate)
        self.user_id = f"anon-{session}"
        self.identity: str | None = None
        self.audience: frozenset[str] | None = None
        self.ready = False
        self.closing = False
        self.subs: set[int] = set()
        self.follows: set[int] = set()
        self.entities: dict[int, int] = {}  # local id -> server id
        self.bucket = bucket
        self.churn = churn  # subscription churn budget (cells added + removed)
        self.outbox = outbox
        self.replies = 0  # replies queued for the current frame ...
        self.refused = 0  # ... and requests refused because the frame asked for too many
        self.mirror: int | None = None  # a stand-in for an owner on another shard (its number), see mirror.py
        self.camera: tuple[float, float, float] | None = None  # the viewer's camera (CAMERA), when it says


class EntityState:
    """One published entity: owner, occupied cells, latest state (and its encodings, made once per publish),
    and the clients that currently know it (`viewers`, kept so that only changes cost set algebra)."""

    __slots__ = (
        "eid", "owner", "local", "seq", "cells", "validity_ms", "payload", "viewers", "followers",
        "enc_plain", "enc_ident", "viewers_tick", "targets",
    )

    def __init__(self, eid: int, owner: ClientState, local: int):
        self.eid = eid
        self.owner = owner
        self.local = local
        self.seq = -1
        self.cells: tuple[int, ...] = ()
        self.validity_ms = 0
        self.payload = b""
        self.viewers: set[int] = set()  # a `ViewerSet` once routed on the compiled path (`outbox.set_kinds`)
        self.followers: set[int] = set()
        self.enc_plain = b""
        self.enc_ident: bytes | None = None  # cached encoding with the owner's identity
        # `viewers` is the full union of subscribers and followers as of this subscription tick (-1: not)
        self.viewers_tick = -1
        # the viewers' outboxes as an `Outboxes.targets` handle for `viewers` as last computed (None until the
        # set is reused by a PUBLISH; dropped whenever the set is recomputed)
        self.targets: tuple | None = None
