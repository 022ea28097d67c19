"""Protocol v1 codec: messages <-> msgpack payloads, strict and bounded. No I/O, no framing.

A payload is a msgpack array of messages; a message is an array whose first element is its integer type.
Payloads of PUBLISH/UPDATE are opaque bytes the server never decodes.

The decoder is strict on purpose: every field has a type, a range and a size bound, and *any* byte
string makes it either return valid messages or raise `ProtocolError` (never another exception), so a server
can close one bad connection with a numbered error and keep serving everyone else.

Encoding is split into `encode_message` (one message -> bytes) and `payload_from_encoded` (already encoded
messages -> one payload) so that a switch can encode a forwarded UPDATE once and copy the bytes into the
batches of every subscriber. The UPDATE and LEAVE layouts are written once, in `encode_update` and
`encode_leave`: the switchboard core calls them on its hot path and `encode_message` calls them for the
dataclasses, so the bytes a switch forwards and the bytes the protocol defines cannot drift apart.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import msgpack

from entitynet.protocol.messages import (
    CAMERA,
    ERROR,
    FOLLOW,
    HELLO,
    LEAVE,
    MAX_CELL,
    MAX_COORD,
    MAX_INT,
    MAX_VALIDITY_MS,
    PING,
    PONG,
    PRIVACY,
    PUBLISH,
    QUERY,
    QUERY_CELLS,
    QUERY_IDENTITY,
    QUERY_RESULT,
    REDIRECT,
    SUBSCRIBE,
    UNFOLLOW,
    UNPUBLISH,
    UPDATE,
    WELCOME,
    Camera,
    Error,
    ErrorCode,
    Follow,
    Hello,
    Leave,
    Message,
    Ping,
    Pong,
    Privacy,
    ProtocolError,
    Publish,
    Query,
    QueryResult,
    Redirect,
    Subscribe,
    Unfollow,
    Unpublish,
    Update,
    Welcome,
)


@dataclass(frozen=True, slots=True)
class CodecLimits:
    """Size and count bounds enforced by the decoder (the server may tighten them): bounded input is what
    lets one process serve thousands of clients without one of them exhausting its memory."""

    max_frame: int = 1 << 20
    max_messages: int = 20_000
    max_payload: int = 2048
    max_publish_cells: int = 64
    max_subscribe_cells: int = 65_536
    max_str: int = 256
    max_audience: int = 1024
    max_query_results: int = 10_000


DEFAULT_LIMITS = CodecLimits()


# ----------------------------------------------------------------------------------------------- encoding
# One packer for the process: a bound Packer.pack is markedly cheaper than msgpack.packb on the switch's hot
# path (one UPDATE per PUBLISH). Packing plain ints, bytes, strings and lists runs in C under the GIL without
# calling back into Python, so a call is never interleaved with another thread's.
_packb = msgpack.Packer(use_bin_type=True).pack


def encode_update(entity: int, seq: int, cells: Sequence[int], validity_ms: int, payload: bytes,
                  identity: str | None = None) -> bytes:
    """The one UPDATE layout: `[UPDATE, entity, seq, cells, validity_ms, payload, identity]`.

    The switchboard core encodes every forwarded state with this (once per publish, the same bytes copied to
    every viewer), and `encode_message(Update(...))` calls it too: one definition of the forwarded bytes."""
    return _packb([UPDATE, entity, seq, cells, validity_ms, payload, identity])


def encode_leave(entity: int) -> bytes:
    """The one LEAVE layout: `[LEAVE, entity]` (the core queues it for every viewer that lost the entity)."""
    return _packb([LEAVE, entity])


def _to_list(msg: Message) -> list:
    t = type(msg)
    if t is Publish:
        return [PUBLISH, msg.entity, msg.seq, list(msg.cells), msg.validity_ms, msg.payload]
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
    if t is Redirect:
        return [REDIRECT, msg.shard, msg.address]
    if t is Camera:
        return [CAMERA, float(msg.x), float(msg.y), float(msg.z)]
    if t is Privacy:
        return [PRIVACY, msg.identity, None if msg.audience is None else list(msg.audience)]
    if t is Ping:
        return [PING, msg.client_ms]
    if t is Pong:
        return [PONG, msg.client_ms, msg.server_ms]
    raise TypeError(f"not a protocol message: {msg!r}")


def encode_message(msg: Message) -> bytes:
    """One message as msgpack bytes (an element of a payload array)."""
    t = type(msg)
    if t is Update:
        return encode_update(msg.entity, msg.seq, msg.cells, msg.validity_ms, msg.payload, msg.identity)
    if t is Leave:
        return encode_leave(msg.entity)
    if t is QueryResult:
        return encode_query_result(msg.query_id, [encode_message(u) for u in msg.entities])
    return msgpack.packb(_to_list(msg), use_bin_type=True)


def array_header(n: int) -> bytes:
    """The msgpack array header of a payload of `n` messages (a writer may send it apart from the body)."""
    if n < 16:
        return bytes((0x90 | n,))
    if n < 0x10000:
        return b"\xdc" + n.to_bytes(2, "big")
    return b"\xdd" + n.to_bytes(4, "big")


def payload_from_encoded(encoded: Sequence[bytes]) -> bytes:
    """Join already encoded messages into one payload (msgpack array) without re-encoding them."""
    return array_header(len(encoded)) + b"".join(encoded)


def encode_query_result(query_id: int, encoded_updates: Sequence[bytes]) -> bytes:
    """A QUERY_RESULT from already encoded UPDATE messages (the switch bounds the result by their sizes)."""
    return (
        b"\x93" + msgpack.packb(QUERY_RESULT) + msgpack.packb(query_id) + array_header(len(encoded_updates))
        + b"".join(encoded_updates)
    )


def encode_payload(msgs: Iterable[Message]) -> bytes:
    """Messages -> one payload (a WebSocket message body, or the body of a TCP frame)."""
    return payload_from_encoded([encode_message(m) for m in msgs])


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


def _coord(v: Any, name: str) -> float:
    if type(v) not in (int, float) or not math.isfinite(v) or abs(v) > MAX_COORD:
        raise _bad(f"{name} must be a finite number of metres within {MAX_COORD:g} of the origin")
    return float(v)


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
    if t == CAMERA:
        _arity(m, 4, "CAMERA")
        return Camera(_coord(m[1], "camera x"), _coord(m[2], "camera y"), _coord(m[3], "camera z"))
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
        if _decode_messages is not None:
            return _decode_messages(obj, limits, limits.max_publish_cells, limits.max_payload,
                                    limits.max_subscribe_cells, _decode_one)
        return [_decode_one(m, limits) for m in obj]
    except ProtocolError:
        raise
    except Exception as exc:  # defensive: e.g. unhashable map keys inside a message
        raise ProtocolError(ErrorCode.MALFORMED, f"malformed message ({type(exc).__name__})") from None


# ------------------------------------------------------------------------------------- the compiled message loop
# `_decode.decode_messages` (entitynet/protocol/_decode.pyx, built by pip where a C compiler is found) is the
# loop above with PUBLISHes and SUBSCRIBEs checked and built in C; anything it does not accept goes to
# `_decode_one`, so both paths return equal messages and raise the same errors (tests/entitynet/protocol/
# test_decode_compiled.py). ENTITYNET_PURE_PYTHON=1 forces the Python loop, as for the switchboard's loops.
try:
    from entitynet.protocol import _decode as _COMPILED  # type: ignore[attr-defined]
except ImportError:  # not built: the Python loop, the reference
    _COMPILED = None
_decode_messages: Any = None


def use_compiled_decoder(flag: bool = True) -> bool:
    """Select `decode_payload`'s message loop for this process: the compiled one when `flag` and it was built,
    else the Python reference. Returns whether the compiled one is now in use."""
    global _decode_messages
    if flag and _COMPILED is not None:
        _COMPILED.bind(Publish, PUBLISH, Subscribe, SUBSCRIBE, MAX_INT, MAX_CELL, MAX_VALIDITY_MS)
        _decode_messages = _COMPILED.decode_messages
    else:
        _decode_messages = None
    return _decode_messages is not None


def compiled_decoder_in_use() -> bool:
    """Whether `decode_payload` runs the compiled message loop in this process (the server's start-up notice)."""
    return _decode_messages is not None


use_compiled_decoder(not os.environ.get("ENTITYNET_PURE_PYTHON"))
