"""Protocol v1 vocabulary: message type tags, numbered errors, id ranges and the message dataclasses. No I/O.

Why a module of its own: the cores (switchboard, client session) speak in these values and never need the
codec's msgpack details or the TCP framing; keeping the vocabulary apart lets each of them import only it.
A message is an immutable dataclass; its wire form (a msgpack array starting with its type tag) is written and
read by `entitynet.protocol.codec`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

PROTOCOL_VERSION = 1

# message type tags (first element of every message)
HELLO = 1
WELCOME = 2
ERROR = 3
PUBLISH = 4
UNPUBLISH = 5
SUBSCRIBE = 6
FOLLOW = 7
UNFOLLOW = 8
QUERY = 9
QUERY_RESULT = 10
UPDATE = 11
LEAVE = 12
REDIRECT = 13
PRIVACY = 14
PING = 15
PONG = 16
CAMERA = 17  # optional, v1: sent only to servers whose WELCOME limits announce "camera" (a cluster's shards)

#: QUERY kinds: by published identity (arg: str) or by cells (arg: tuple of cell ids)
QUERY_IDENTITY = "identity"
QUERY_CELLS = "cells"

MAX_INT = 2**53  # ids, sequence numbers and times fit in a float64 on any client
#: a publisher names its own entities with local ids below this; server-assigned (forwarded) ids are above it,
#: so a PUBLISH that names someone else's entity is recognisable and refused with NOT_OWNER
LOCAL_ID_LIMIT = 2**32
MAX_CELL = 2**31 - 1
MAX_VALIDITY_MS = 24 * 3600 * 1000


class ErrorCode(IntEnum):
    """Numbered errors. 1xx: malformed input (connection closed); 2xx: handshake refused (closed);
    3xx: a request refers to something that is not yours or does not exist (request dropped);
    4xx: a limit was exceeded (request dropped; 404 and 405 close); 5xx: server side.

    406 LIMIT_CHURN: a SUBSCRIBE over the client's budget of subscription churn (cells added + removed per
    second); 407 TOO_MANY_REQUESTS: the requests of one frame beyond what one frame may ask replies for."""

    MALFORMED = 100
    FRAME_TOO_LARGE = 101
    UNKNOWN_TYPE = 102
    BAD_FIELD = 103
    VERSION_MISMATCH = 200
    TOPOLOGY_MISMATCH = 201
    AUTH_FAILED = 202
    HANDSHAKE_REQUIRED = 203
    AUTH_THROTTLED = 204  # too many failed logins from this address: retry after the time in the text
    NOT_OWNER = 300
    NO_SUCH_CELL = 301
    NO_SUCH_ENTITY = 302
    LIMIT_SUBSCRIPTIONS = 400
    LIMIT_FOLLOWS = 401
    QUERY_RATE = 402
    LIMIT_ENTITIES = 403
    SLOW_CONSUMER = 404
    SERVER_FULL = 405
    LIMIT_CHURN = 406
    TOO_MANY_REQUESTS = 407
    SHUTTING_DOWN = 500
    INTERNAL = 501
    AUTH_UNAVAILABLE = 502  # the server cannot check tokens now (its store is locked or damaged): retry later


#: errors after which the server closes the connection
FATAL_ERRORS = frozenset(
    {
        ErrorCode.MALFORMED,
        ErrorCode.FRAME_TOO_LARGE,
        ErrorCode.UNKNOWN_TYPE,
        ErrorCode.BAD_FIELD,
        ErrorCode.VERSION_MISMATCH,
        ErrorCode.TOPOLOGY_MISMATCH,
        ErrorCode.AUTH_FAILED,
        ErrorCode.HANDSHAKE_REQUIRED,
        ErrorCode.AUTH_THROTTLED,
        ErrorCode.SLOW_CONSUMER,
        ErrorCode.SERVER_FULL,
        ErrorCode.SHUTTING_DOWN,
        ErrorCode.INTERNAL,
        ErrorCode.AUTH_UNAVAILABLE,
    }
)


class ProtocolError(Exception):
    """Bad bytes or a bad message. Carries the numbered error code to send back, so that a server can close
    the one offending connection with a precise ERROR and keep serving everyone else."""

    def __init__(self, code: ErrorCode, text: str):
        super().__init__(f"{int(code)} {code.name}: {text}")
        self.code = code
        self.text = text


@dataclass(frozen=True, slots=True)
class Hello:
    """Client -> server, first message: protocol version, auth token and the topology digest it was built on
    (a client on another map would misread every cell id)."""

    version: int
    token: str
    digest: str


@dataclass(frozen=True, slots=True)
class Welcome:
    """Server -> client: the handshake succeeded; the session id, the server clock (for offset estimates) and
    the limits the client must stay within (so it can plan instead of being refused)."""

    version: int
    session: int
    server_time_ms: int
    limits: Mapping[str, int] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Error:
    """Server -> client: a numbered error (ErrorCode); fatal ones are the last message before the close."""

    code: int
    text: str


@dataclass(frozen=True, slots=True)
class Publish:
    """Client -> server: an honest client's own state: which cells it occupies, for how long, and an opaque
    payload (its dead-reckoning model) that the server forwards without decoding."""

    entity: int
    seq: int
    cells: tuple[int, ...]
    validity_ms: int
    payload: bytes


@dataclass(frozen=True, slots=True)
class Unpublish:
    """Client -> server: the entity is gone (viewers get LEAVE now rather than at its expiry)."""

    entity: int


@dataclass(frozen=True, slots=True)
class Subscribe:
    """Client -> server: the difference of a viewer's cell subscriptions (the PVS changes little per move)."""

    added: tuple[int, ...] = ()
    removed: tuple[int, ...] = ()


@dataclass(frozen=True, slots=True)
class Follow:
    """Client -> server: a direct subscription to one entity wherever it is."""

    entity: int


@dataclass(frozen=True, slots=True)
class Unfollow:
    """Client -> server: ends a direct subscription."""

    entity: int


@dataclass(frozen=True, slots=True)
class Query:
    """Client -> server: a one-off question, answered by one QUERY_RESULT with the same id."""

    query_id: int
    kind: str
    arg: Any  # str for QUERY_IDENTITY, tuple[int, ...] for QUERY_CELLS


@dataclass(frozen=True, slots=True)
class Update:
    """Server -> client: a forwarded state under the server's opaque entity id (the owner's identity only
    where the privacy rules show it to this viewer)."""

    entity: int
    seq: int
    cells: tuple[int, ...]
    validity_ms: int
    payload: bytes
    identity: str | None = None


@dataclass(frozen=True, slots=True)
class QueryResult:
    """Server -> client: the entities a QUERY found, as UPDATEs (cut to fit one frame)."""

    query_id: int
    entities: tuple[Update, ...]


@dataclass(frozen=True, slots=True)
class Leave:
    """Server -> client: the entity is no longer visible to this client (moved away, gone or expired)."""

    entity: int


@dataclass(frozen=True, slots=True)
class Redirect:
    """Server -> client: the shard at `address` owns what the client asked for."""

    shard: int
    address: str


@dataclass(frozen=True, slots=True)
class Privacy:
    """Client -> server: the identity this client's entities show, and to whom (None: everyone who shows
    one)."""

    identity: str | None
    audience: tuple[str, ...] | None = None


@dataclass(frozen=True, slots=True)
class Camera:
    """Client -> server (optional in v1): where the viewer's camera is, in the artifact's local metres, so a
    sharded server can hand the viewer to the shard whose region holds the camera (cells seen from a border
    lie on both sides; the camera does not). Sent only to a server whose WELCOME limits carry `camera`: an
    older server would refuse the unknown type."""

    x: float
    y: float
    z: float = 0.0


@dataclass(frozen=True, slots=True)
class Ping:
    """Client -> server: a clock probe (the client's send time, echoed back)."""

    client_ms: int


@dataclass(frozen=True, slots=True)
class Pong:
    """Server -> client: the echoed probe and the server's time, for the client's clock-offset estimate."""

    client_ms: int
    server_ms: int


Message = (
    Hello | Welcome | Error | Publish | Unpublish | Subscribe | Follow | Unfollow | Query | QueryResult
    | Update | Leave | Redirect | Privacy | Ping | Pong | Camera
)

MAX_COORD = 1.0e7  # metres from the artifact's local origin: anything beyond is not on a city map


def now_ms(seconds: float) -> int:
    """Seconds (float) -> integer milliseconds for the wire; rejects NaN, inf and negative times (inside
    everything is float seconds, on the wire integer milliseconds)."""
    if not math.isfinite(seconds) or seconds < 0:
        raise ValueError(f"time must be finite and non-negative, got {seconds!r}")
    return int(round(seconds * 1000.0))
