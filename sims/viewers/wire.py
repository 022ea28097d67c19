"""The frames between the coordinator and its viewer processes: msgpack maps behind a 4-byte length.

Why checked field by field: a frame that is not what its kind says (a bug, a process killed mid-write) must be
one clear error naming the field, never a KeyError deep in a tick. Kinds: `start` (coordinator -> process: the
server's address and token), `ready` (process -> coordinator, its connections are up), `tick` (k, the payloads
published and the entities unpublished in that tick), `stop`, and `report` (the process's tallies and viewer
counters).
"""

from __future__ import annotations

import struct
from typing import Any

import msgpack

MAX_FRAME = 256 * 1024 * 1024  # a report holds every error sample of its viewers: tens of MB at most
HEADER = struct.Struct(">I")

FIELDS: dict[str, dict[str, type | tuple[type, ...]]] = {
    "start": {"host": str, "port": int, "token": str},
    "ready": {"viewers": int},
    "tick": {"k": int, "pub": list, "unpub": list, "sent": float},
    "stop": {},
    "report": {"tallies": dict, "viewers": dict, "subscribe_msgs": int, "ticks": int, "cpu_s": float,
               "tick_delay_p99_ms": float},
}


class WireError(ValueError):
    """A frame that is not one of the kinds above, or a field of the wrong type."""


def encode(kind: str, **fields: Any) -> bytes:
    """One frame of `kind` with its fields, length first."""
    check({"t": kind, **fields})
    body = msgpack.packb({"t": kind, **fields}, use_bin_type=True)
    return HEADER.pack(len(body)) + body


def check(frame: Any) -> dict:
    """The frame if it is a map of a known kind with every field of the right type; else WireError."""
    if not isinstance(frame, dict):
        raise WireError(f"a frame is a map, got {type(frame).__name__}")
    kind = frame.get("t")
    want = FIELDS.get(kind) if isinstance(kind, str) else None
    if want is None:
        raise WireError(f"unknown frame kind {kind!r:.40}")
    for name, typ in want.items():
        v = frame.get(name)
        if not isinstance(v, typ) or (typ is int and isinstance(v, bool)):
            raise WireError(f"{kind} frame: field {name!r} must be {typ.__name__}, got {v!r:.40}")
    return frame


class FrameReader:
    """Bytes in, whole frames out (`feed` then `frames`); a length over `max_frame` or a body that is not
    msgpack is a WireError."""

    def __init__(self, max_frame: int = MAX_FRAME) -> None:
        self.max_frame = max_frame
        self._buf = bytearray()

    def feed(self, data: bytes) -> None:
        """Bytes that arrived."""
        self._buf += data

    def frames(self) -> list[dict]:
        """Every whole frame buffered so far, checked."""
        out = []
        buf = self._buf
        while len(buf) >= HEADER.size:
            (n,) = HEADER.unpack_from(buf)
            if n > self.max_frame:
                raise WireError(f"frame of {n} bytes, over the limit of {self.max_frame}")
            if len(buf) < HEADER.size + n:
                break
            body = bytes(buf[HEADER.size:HEADER.size + n])
            del buf[:HEADER.size + n]
            try:
                frame = msgpack.unpackb(body, raw=False, strict_map_key=False)
            except Exception as exc:  # msgpack's errors have no common base worth naming
                raise WireError(f"a frame that is not msgpack: {exc}") from None
            out.append(check(frame))
        return out
