"""Protocol v1: message types, strict codec and framing. No I/O.

Wire format (DESIGN.md): over TCP a frame is a 4-byte big-endian length followed by a msgpack payload; over
WebSocket one binary message is one payload. A payload is a msgpack array of messages; a message is an array
whose first element is its integer type. Payloads of PUBLISH/UPDATE are opaque bytes the server never decodes.

The decoder is strict on purpose: every field has a type, a range and a size bound, and *any* byte
string makes it either return valid messages or raise `ProtocolError` (never another exception), so a server
can close one bad connection with a numbered error and keep serving everyone else.

Encoding is split into `encode_message` (one message -> bytes) and `payload_from_encoded` (already encoded
messages -> one payload) so that a switch can encode a forwarded UPDATE once and copy the bytes into the
batches of every subscriber.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import msgpack

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

#: QUERY kinds: by published identity (arg: str) or by cells (arg: tuple of cell ids)
QUERY_IDENTITY = "identity"
QUERY_CELLS = "cells"

MAX_INT = 2**53  # ids, sequence numbers and times fit in a float64 on any client
#: a publisher names its own entities with local ids below this; server-assigned (forwarded) ids are above it,
#: so a PUBLISH that names someone else's entity is recognisable and refused with NOT_OWNER
LOCAL_ID_LIMIT = 2**32
MAX_CELL = 2**31 - 1
MAX_VALIDITY_MS = 24 * 3600 * 1000
LENGTH_PREFIX = struct.Struct(">I")


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
    }
)


class ProtocolError(Exception):
    """Bad bytes or a bad message. Carries the numbered error code to send back."""

    def __init__(self, code: ErrorCode, text: str):
        super().__init__(f"{int(code)} {code.name}: {text}")
        self.code = code
        self.text = text


@dataclass(frozen=True, slots=True)
class CodecLimits:
    """Size and count bounds enforced by the decoder (the server may tighten them)."""

    max_frame: int = 1 << 20
    max_messages: int = 20_000
    max_payload: int = 2048
    max_publish_cells: int = 64
    max_subscribe_cells: int = 65_536
    max_str: int = 256
    max_audience: int = 1024
    max_query_results: int = 10_000


DEFAULT_LIMITS = CodecLimits()


# ----------------------------------------------------------------------------------------------- messages
@dataclass(frozen=True, slots=True)
class Hello:
    version: int
    token: str
    digest: str


@dataclass(frozen=True, slots=True)
class Welcome:
    version: int
    session: int
    server_time_ms: int
    limits: Mapping[str, int] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Error:
    code: int
    text: str


@dataclass(frozen=True, slots=True)
class Publish:
    entity: int
    seq: int
    cells: tuple[int, ...]
    validity_ms: int
    payload: bytes


@dataclass(frozen=True, slots=True)
class Unpublish:
    entity: int


@dataclass(frozen=True, slots=True)
class Subscribe:
    added: tuple[int, ...] = ()
    removed: tuple[int, ...] = ()


@dataclass(frozen=True, slots=True)
class Follow:
    entity: int


@dataclass(frozen=True, slots=True)
class Unfollow:
    entity: int


@dataclass(frozen=True, slots=True)
class Query:
    query_id: int
    kind: str
    arg: Any  # str for QUERY_IDENTITY, tuple[int, ...] for QUERY_CELLS


@dataclass(frozen=True, slots=True)
class Update:
    entity: int
    seq: int
    cells: tuple[int, ...]
    validity_ms: int
    payload: bytes
    identity: str | None = None


@dataclass(frozen=True, slots=True)
class QueryResult:
    query_id: int
    entities: tuple[Update, ...]


@dataclass(frozen=True, slots=True)
class Leave:
    entity: int


@dataclass(frozen=True, slots=True)
class Redirect:
    shard: int
    address: str


@dataclass(frozen=True, slots=True)
class Privacy:
    identity: str | None
    audience: tuple[str, ...] | None = None


@dataclass(frozen=True, slots=True)
class Ping:
    client_ms: int


@dataclass(frozen=True, slots=True)
class Pong:
    client_ms: int
    server_ms: int


Message = (
    Hello | Welcome | Error | Publish | Unpublish | Subscribe | Follow | Unfollow | Query | QueryResult
    | Update | Leave | Redirect | Privacy | Ping | Pong
)


# ----------------------------------------------------------------------------------------------- encoding
def _to_list(msg: Message) -> list:
    t = type(msg)
    if t is Update:
        return [UPDATE, msg.entity, msg.seq, list(msg.cells), msg.validity_ms, msg.payload, msg.identity]
    if t is Publish:
        return [PUBLISH, msg.entity, msg.seq, list(msg.cells), msg.validity_ms, msg.payload]
    if t is Leave:
        return [LEAVE, msg.entity]
    if t is Subscribe:
        return [SUBSCRIBE, list(msg.added), list(msg.removed)]
    if t is Hello:
        return [HELLO, msg.version, msg.token, msg.digest]
    if t is Welcome:
        return [WELCOME, msg.version, msg.session, msg.server_time_ms, dict(msg.limits)]
    if t is Error:
        return [ERROR, int(msg.code), msg.text]
    if t is Unpublish:
        return [UNPUBLISH, msg.entity]
    if t is Follow:
        return [FOLLOW, msg.entity]
    if t is Unfollow:
        return [UNFOLLOW, msg.entity]
    if t is Query:
        arg = list(msg.arg) if msg.kind == QUERY_CELLS else msg.arg
        return [QUERY, msg.query_id, msg.kind, arg]
    if t is QueryResult:
        return [QUERY_RESULT, msg.query_id, [_to_list(u) for u in msg.entities]]
    if t is Redirect:
        return [REDIRECT, msg.shard, msg.address]
    if t is Privacy:
        return [PRIVACY, msg.identity, None if msg.audience is None else list(msg.audience)]
    if t is Ping:
        return [PING, msg.client_ms]
    if t is Pong:
        return [PONG, msg.client_ms, msg.server_ms]
    raise TypeError(f"not a protocol message: {msg!r}")


def encode_message(msg: Message) -> bytes:
    """One message as msgpack bytes (an element of a payload array)."""
    return msgpack.packb(_to_list(msg), use_bin_type=True)


def _array_header(n: int) -> bytes:
    if n < 16:
        return bytes((0x90 | n,))
    if n < 0x10000:
        return b"\xdc" + n.to_bytes(2, "big")
    return b"\xdd" + n.to_bytes(4, "big")


def payload_from_encoded(encoded: Sequence[bytes]) -> bytes:
    """Join already encoded messages into one payload (msgpack array) without re-encoding them."""
    return _array_header(len(encoded)) + b"".join(encoded)


def array_header(n: int) -> bytes:
    """The msgpack array header of a payload of `n` messages (a writer may send it apart from the body)."""
    return _array_header(n)


def encode_query_result(query_id: int, encoded_updates: Sequence[bytes]) -> bytes:
    """A QUERY_RESULT from already encoded UPDATE messages (the switch bounds the result by their sizes)."""
    return (
        b"\x93" + msgpack.packb(QUERY_RESULT) + msgpack.packb(query_id) + _array_header(len(encoded_updates))
        + b"".join(encoded_updates)
    )


def frame_head(payload_size: int) -> bytes:
    """The 4-byte length prefix of a TCP frame whose payload has `payload_size` bytes."""
    return LENGTH_PREFIX.pack(payload_size)


_HEAD_FIX = struct.Struct(">IB")  # length prefix + fixarray header
_HEAD_16 = struct.Struct(">IBH")  # length prefix + array16 header


def frame_prefix(n_messages: int, body_size: int) -> bytes:
    """Length prefix and array header of a TCP frame of `n_messages` already encoded messages totalling
    `body_size` bytes, in one call (the writer sends it with the joined messages, without concatenating)."""
    if n_messages < 16:
        return _HEAD_FIX.pack(body_size + 1, 0x90 | n_messages)
    if n_messages < 0x10000:
        return _HEAD_16.pack(body_size + 3, 0xDC, n_messages)
    return LENGTH_PREFIX.pack(body_size + 5) + _array_header(n_messages)


def encode_payload(msgs: Iterable[Message]) -> bytes:
    """Messages -> one payload (a WebSocket message body, or the body of a TCP frame)."""
    return payload_from_encoded([encode_message(m) for m in msgs])


def frame(payload: bytes) -> bytes:
    """A payload with its 4-byte big-endian length prefix (TCP framing)."""
    return LENGTH_PREFIX.pack(len(payload)) + payload


def encode_frame(msgs: Iterable[Message]) -> bytes:
    return frame(encode_payload(msgs))


# ----------------------------------------------------------------------------------------------- decoding
def _bad(text: str) -> ProtocolError:
    return ProtocolError(ErrorCode.BAD_FIELD, text)


def _int(v: Any, name: str, hi: int = MAX_INT) -> int:
    if type(v) is not int or v < 0 or v > hi:
        raise _bad(f"{name} must be an integer in [0, {hi}]")
    return v


def _str(v: Any, name: str, lim: CodecLimits) -> str:
    if type(v) is not str or len(v) > lim.max_str:
        raise _bad(f"{name} must be a string of at most {lim.max_str} characters")
    return v


def _opt_str(v: Any, name: str, lim: CodecLimits) -> str | None:
    return None if v is None else _str(v, name, lim)


def _cells(v: Any, name: str, max_n: int) -> tuple[int, ...]:
    if type(v) is not tuple or len(v) > max_n:
        raise _bad(f"{name} must be an array of at most {max_n} cell ids")
    for c in v:
        if type(c) is not int or c < 0 or c > MAX_CELL:
            raise _bad(f"{name}: cell ids are integers in [0, {MAX_CELL}]")
    return v


def _bytes(v: Any, name: str, lim: CodecLimits) -> bytes:
    if type(v) is not bytes or len(v) > lim.max_payload:
        raise _bad(f"{name} must be binary of at most {lim.max_payload} bytes")
    return v


def _arity(m: tuple, n: int, name: str) -> None:
    if len(m) != n:
        raise _bad(f"{name} takes {n - 1} fields, got {len(m) - 1}")


def _update(m: Any, lim: CodecLimits) -> Update:
    if type(m) is not tuple or not m or m[0] != UPDATE:
        raise _bad("query result entries must be UPDATE messages")
    _arity(m, 7, "UPDATE")
    return Update(
        _int(m[1], "entity"),
        _int(m[2], "seq"),
        _cells(m[3], "cells", lim.max_publish_cells),
        _int(m[4], "validity_ms", MAX_VALIDITY_MS),
        _bytes(m[5], "payload", lim),
        _opt_str(m[6], "identity", lim),
    )


def _decode_one(m: Any, lim: CodecLimits) -> Message:
    if type(m) is not tuple or not m:
        raise ProtocolError(ErrorCode.MALFORMED, "a message must be a non-empty array")
    t = m[0]
    if type(t) is not int:
        raise ProtocolError(ErrorCode.MALFORMED, "a message must start with its integer type")
    if t == PUBLISH:
        _arity(m, 6, "PUBLISH")
        cells = _cells(m[3], "cells", lim.max_publish_cells)
        if len(set(cells)) != len(cells):
            raise _bad("PUBLISH cells must be distinct")
        return Publish(
            _int(m[1], "entity"), _int(m[2], "seq"), cells, _int(m[4], "validity_ms", MAX_VALIDITY_MS),
            _bytes(m[5], "payload", lim),
        )
    if t == UPDATE:
        return _update(m, lim)
    if t == SUBSCRIBE:
        _arity(m, 3, "SUBSCRIBE")
        return Subscribe(
            _cells(m[1], "added", lim.max_subscribe_cells), _cells(m[2], "removed", lim.max_subscribe_cells)
        )
    if t == LEAVE:
        _arity(m, 2, "LEAVE")
        return Leave(_int(m[1], "entity"))
    if t == UNPUBLISH:
        _arity(m, 2, "UNPUBLISH")
        return Unpublish(_int(m[1], "entity"))
    if t == FOLLOW:
        _arity(m, 2, "FOLLOW")
        return Follow(_int(m[1], "entity"))
    if t == UNFOLLOW:
        _arity(m, 2, "UNFOLLOW")
        return Unfollow(_int(m[1], "entity"))
    if t == PING:
        _arity(m, 2, "PING")
        return Ping(_int(m[1], "client_ms"))
    if t == PONG:
        _arity(m, 3, "PONG")
        return Pong(_int(m[1], "client_ms"), _int(m[2], "server_ms"))
    if t == HELLO:
        _arity(m, 4, "HELLO")
        return Hello(_int(m[1], "version", 0xFFFF), _str(m[2], "token", lim), _str(m[3], "digest", lim))
    if t == WELCOME:
        _arity(m, 5, "WELCOME")
        limits = m[4]
        if type(limits) is not dict or len(limits) > 64:
            raise _bad("WELCOME limits must be a map of at most 64 entries")
        out = {_str(k, "limit name", lim): _int(v, "limit value") for k, v in limits.items()}
        return Welcome(
            _int(m[1], "version", 0xFFFF), _int(m[2], "session"), _int(m[3], "server_time_ms"), out
        )
    if t == ERROR:
        _arity(m, 3, "ERROR")
        return Error(_int(m[1], "code", 999), _str(m[2], "text", lim))
    if t == QUERY:
        _arity(m, 4, "QUERY")
        kind = m[2]
        if kind == QUERY_IDENTITY:
            arg: Any = _str(m[3], "identity", lim)
        elif kind == QUERY_CELLS:
            arg = _cells(m[3], "cells", lim.max_subscribe_cells)
        else:
            raise _bad(f"QUERY kind must be {QUERY_IDENTITY!r} or {QUERY_CELLS!r}")
        return Query(_int(m[1], "query_id"), kind, arg)
    if t == QUERY_RESULT:
        _arity(m, 3, "QUERY_RESULT")
        ents = m[2]
        if type(ents) is not tuple or len(ents) > lim.max_query_results:
            raise _bad("QUERY_RESULT entities must be an array")
        return QueryResult(_int(m[1], "query_id"), tuple(_update(u, lim) for u in ents))
    if t == REDIRECT:
        _arity(m, 3, "REDIRECT")
        return Redirect(_int(m[1], "shard"), _str(m[2], "address", lim))
    if t == PRIVACY:
        _arity(m, 3, "PRIVACY")
        aud = m[2]
        if aud is not None:
            if type(aud) is not tuple or len(aud) > lim.max_audience:
                raise _bad(f"PRIVACY audience must be nil or an array of at most {lim.max_audience} user ids")
            aud = tuple(_str(a, "audience member", lim) for a in aud)
        return Privacy(_opt_str(m[1], "identity", lim), aud)
    raise ProtocolError(ErrorCode.UNKNOWN_TYPE, f"unknown message type {t}")


def _no_ext(code: int, data: bytes) -> Any:
    raise ProtocolError(ErrorCode.MALFORMED, "msgpack extension types are not allowed")


def decode_payload(data: bytes, limits: CodecLimits = DEFAULT_LIMITS) -> list[Message]:
    """One payload -> its messages. Raises only ProtocolError."""
    if len(data) > limits.max_frame:
        raise ProtocolError(ErrorCode.FRAME_TOO_LARGE, f"payload of {len(data)} bytes > {limits.max_frame}")
    try:
        obj = msgpack.unpackb(
            data, use_list=False, raw=False, strict_map_key=True, ext_hook=_no_ext, timestamp=0,
            max_array_len=max(limits.max_messages, limits.max_subscribe_cells, limits.max_query_results),
        )
    except ProtocolError:
        raise
    except Exception as exc:  # msgpack raises ValueError, ExtraData, UnicodeDecodeError, StackError, ...
        raise ProtocolError(ErrorCode.MALFORMED, f"not a msgpack payload ({type(exc).__name__})") from None
    if type(obj) is not tuple:
        raise ProtocolError(ErrorCode.MALFORMED, "a payload must be an array of messages")
    if len(obj) > limits.max_messages:
        raise ProtocolError(ErrorCode.FRAME_TOO_LARGE, f"more than {limits.max_messages} messages")
    try:
        return [_decode_one(m, limits) for m in obj]
    except ProtocolError:
        raise
    except Exception as exc:  # defensive: e.g. unhashable map keys inside a message
        raise ProtocolError(ErrorCode.MALFORMED, f"malformed message ({type(exc).__name__})") from None


class FrameDecoder:
    """Sans-IO TCP deframer: feed bytes with `receive_data`, take payloads with `next_payload`.

    The length prefix is checked as soon as its 4 bytes arrive, so a 4 GB announcement is refused
    without buffering anything; the buffer never holds more than one maximal frame plus one read.
    """

    def __init__(self, limits: CodecLimits = DEFAULT_LIMITS):
        self.limits = limits
        self._buf = bytearray()
        self._need: int | None = None

    @property
    def buffered(self) -> int:
        return len(self._buf)

    @property
    def mid_frame(self) -> bool:
        """True when part of a frame has arrived but not all of it."""
        return bool(self._buf)

    def receive_data(self, data: bytes) -> None:
        self._buf += data

    def next_payload(self) -> bytes | None:
        buf = self._buf
        if self._need is None:
            if len(buf) < 4:
                return None
            (n,) = LENGTH_PREFIX.unpack_from(buf)
            if n > self.limits.max_frame:
                raise ProtocolError(
                    ErrorCode.FRAME_TOO_LARGE, f"frame of {n} bytes > {self.limits.max_frame}"
                )
            if n == 0:
                raise ProtocolError(ErrorCode.MALFORMED, "empty frame")
            self._need = n
        n = self._need
        if len(buf) < 4 + n:
            return None
        payload = bytes(buf[4 : 4 + n])
        del buf[: 4 + n]
        self._need = None
        return payload

    def next_messages(self) -> list[Message] | None:
        """The next complete frame's messages, or None when more bytes are needed."""
        payload = self.next_payload()
        return None if payload is None else decode_payload(payload, self.limits)


def now_ms(seconds: float) -> int:
    """Seconds (float) -> integer milliseconds for the wire; rejects NaN, inf and negative times."""
    if not math.isfinite(seconds) or seconds < 0:
        raise ValueError(f"time must be finite and non-negative, got {seconds!r}")
    return int(round(seconds * 1000.0))
