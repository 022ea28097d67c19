"""The NATS client protocol (the documented text protocol of nats-server), sans-IO.

Why our own: nats-py is asyncio-only and the service is trio; the part of the protocol a switchboard needs is
small (INFO, CONNECT, PUB, SUB, UNSUB, MSG, PING, PONG, +OK, -ERR; no headers, no JetStream), and a codec
with no I/O is tested byte by byte and driven by a thin trio shell (entitynet.cluster.nats_client). See
docs/cluster.md for the measurement behind the choice.

Parsing follows the h11 shape: `receive_data(bytes)`, then `next_event()` until it returns None. Every control
line is bounded (`max_control_line`) and every MSG payload by the server's announced `max_payload` (plus a
margin): a broken or hostile peer raises `NatsProtocolError`, never an unbounded buffer or another exception.
Subjects are checked on the way out (no spaces, no empty tokens), so a bad cell or entity id cannot inject a
second command into the stream.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from typing import Any, NamedTuple

CRLF = b"\r\n"
MAX_CONTROL_LINE = 4096
DEFAULT_MAX_PAYLOAD = 1 << 20
_SUBJECT = re.compile(r"^[A-Za-z0-9_\-$]+(\.[A-Za-z0-9_\-$]+|\.\*|\.>)*$|^\*$")


class NatsProtocolError(Exception):
    """The server's bytes make no sense (or a subject we were asked to send is invalid)."""


@dataclass(frozen=True)
class Info:
    """The server's INFO (parsing it also adopts its `max_payload` as the limit on MSG payloads)."""

    info: dict[str, Any]


class Msg(NamedTuple):
    """A message on a subscription: `sid` says which handler gets it; `reply` is the inbox to answer, if any.
    A named tuple, not a frozen dataclass: one is made per message received, and a frozen dataclass's
    `__init__` (four `object.__setattr__` calls) cost about as much as parsing the MSG line."""

    subject: str
    sid: int
    reply: str | None
    payload: bytes


@dataclass(frozen=True)
class Ping:
    """The server checks we are alive: answer PONG."""

    pass


@dataclass(frozen=True)
class Pong:
    """The answer to our PING (a flush: everything sent before it has reached the server)."""

    pass


@dataclass(frozen=True)
class Ok:
    """+OK: sent only in verbose mode, which we do not ask for (CONNECT verbose=false)."""

    pass


@dataclass(frozen=True)
class Err:
    """-ERR from the server, with its text (the quotes stripped)."""

    text: str


Event = Info | Msg | Ping | Pong | Ok | Err


def check_subject(subject: str, wildcards: bool = False) -> str:
    """A subject we send: dot-separated tokens of letters, digits, `_ - $`; wildcards only where allowed."""
    if not subject or len(subject) > 256 or not _SUBJECT.match(subject):
        raise NatsProtocolError(f"invalid subject {subject!r}")
    if not wildcards and ("*" in subject or ">" in subject):
        raise NatsProtocolError(f"wildcards are not allowed in a published subject: {subject!r}")
    return subject


# ---- encoding (client -> server) -------------------------------------------------------------------------------
def connect(options: dict[str, Any]) -> bytes:
    """The CONNECT line: `options` as compact JSON (echo, auth token, name, ...)."""
    return b"CONNECT " + json.dumps(options, separators=(",", ":")).encode() + CRLF


def pub(subject: str, payload: bytes, reply: str | None = None) -> bytes:
    """PUB subject [reply] n + payload. Hot path: the subject is checked by the callers that build it."""
    head = f"PUB {subject} {reply} {len(payload)}\r\n" if reply else f"PUB {subject} {len(payload)}\r\n"
    return head.encode() + payload + CRLF


def sub(subject: str, sid: int, queue: str | None = None) -> bytes:
    """SUB subject [queue] sid; the subject (wildcards allowed) is checked, so no second command can be injected."""
    check_subject(subject, wildcards=True)
    return (f"SUB {subject} {queue} {sid}\r\n" if queue else f"SUB {subject} {sid}\r\n").encode()


def unsub(sid: int, max_msgs: int | None = None) -> bytes:
    """UNSUB sid [max_msgs]: with `max_msgs`, the server unsubscribes after that many more messages."""
    return (f"UNSUB {sid} {max_msgs}\r\n" if max_msgs else f"UNSUB {sid}\r\n").encode()


PING = b"PING\r\n"
PONG = b"PONG\r\n"


# ---- parsing (server -> client) --------------------------------------------------------------------------------
class Parser:
    """Bytes from the server in, events out."""

    def __init__(self, max_payload: int = DEFAULT_MAX_PAYLOAD, max_control_line: int = MAX_CONTROL_LINE):
        self._buf = bytearray()
        self._pos = 0
        self.max_payload = max_payload
        self.max_control_line = max_control_line
        self._pending: tuple[str, int, str | None, int] | None = None  # a MSG head waiting for its payload

    def receive_data(self, data: bytes) -> None:
        """Append bytes from the socket; consumed bytes are compacted away only once they are most of a large
        buffer, so parsing stays linear without copying on every call."""
        if self._pos > 65536 and self._pos * 2 > len(self._buf):
            del self._buf[: self._pos]
            self._pos = 0
        self._buf += data

    @property
    def buffered(self) -> int:
        """Bytes received but not yet parsed into events."""
        return len(self._buf) - self._pos

    def next_event(self) -> Event | None:
        """The next complete event, or None until more bytes arrive; raises `NatsProtocolError` on anything
        malformed or over the limits, never buffers without bound."""
        buf = self._buf
        pos = self._pos
        if self._pending is None and buf.startswith(b"MSG ", pos):
            # the hot path (every state from another shard): head and payload in one step when both are here
            i = buf.find(CRLF, pos, pos + self.max_control_line + 2)
            if i > 0:
                parts = buf[pos + 4 : i].split()
                if len(parts) == 3 and parts[1].isdigit() and parts[2].isdigit():  # no reply inbox
                    subject, sid, reply, n = parts[0].decode("ascii", "replace"), int(parts[1]), None, int(parts[2])
                    if n > self.max_payload + 1024:
                        raise NatsProtocolError(f"MSG of {n} bytes beyond max_payload {self.max_payload}")
                else:
                    subject, sid, reply, n = self._msg_head(bytes(buf[pos + 4 : i]))
                start = i + 2
                end = start + n
                if len(buf) < end + 2:
                    self._pending, self._pos = (subject, sid, reply, n), start
                    return None
                if buf[end] != 13 or buf[end + 1] != 10:
                    raise NatsProtocolError("MSG payload not followed by CRLF")
                self._pos = end + 2
                return Msg(subject, sid, reply, bytes(buf[start:end]))
        if self._pending is not None:
            subject, sid, reply, n = self._pending
            end = self._pos + n
            if len(buf) < end + 2:
                return None
            if buf[end : end + 2] != CRLF:
                raise NatsProtocolError("MSG payload not followed by CRLF")
            payload = bytes(buf[self._pos : end])
            self._pos = end + 2
            self._pending = None
            return Msg(subject, sid, reply, payload)
        i = buf.find(CRLF, self._pos)
        if i < 0:
            if len(buf) - self._pos > self.max_control_line:
                raise NatsProtocolError(f"control line longer than {self.max_control_line} bytes")
            return None
        if i - self._pos > self.max_control_line:
            raise NatsProtocolError(f"control line longer than {self.max_control_line} bytes")
        line = bytes(buf[self._pos : i])
        self._pos = i + 2
        op, _, rest = line.partition(b" ")
        op = op.upper()
        if op == b"MSG":
            self._pending = self._msg_head(rest)
            return self.next_event()
        if op == b"PING":
            return Ping()
        if op == b"PONG":
            return Pong()
        if op == b"+OK":
            return Ok()
        if op == b"-ERR":
            return Err(rest.decode("utf-8", "replace").strip().strip("'"))
        if op == b"INFO":
            try:
                info = json.loads(rest)
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                raise NatsProtocolError(f"bad INFO: {exc}") from None
            if not isinstance(info, dict):
                raise NatsProtocolError("INFO is not a JSON object")
            mp = info.get("max_payload")
            if isinstance(mp, int) and mp > 0:
                self.max_payload = mp
            return Info(info)
        raise NatsProtocolError(f"unknown operation {op[:20]!r}")

    def _msg_head(self, rest: bytes) -> tuple[str, int, str | None, int]:
        parts = rest.split()
        try:
            if len(parts) == 3:
                subject, sid, reply, n = parts[0], int(parts[1]), None, int(parts[2])
            elif len(parts) == 4:
                subject, sid, reply, n = parts[0], int(parts[1]), parts[2].decode(), int(parts[3])
            else:
                raise ValueError(f"{len(parts)} fields")
        except (ValueError, UnicodeDecodeError) as exc:
            raise NatsProtocolError(f"bad MSG line: {exc}") from None
        if not 0 <= n <= self.max_payload + 1024:
            raise NatsProtocolError(f"MSG of {n} bytes beyond max_payload {self.max_payload}")
        return subject.decode("ascii", "replace"), sid, reply, n
