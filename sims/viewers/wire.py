"""The frames between the coordinator and its viewer processes: msgpack maps behind a 4-byte length.

Why checked field by field: a frame that is not what its kind says (a bug, a process killed mid-write) must be
one clear error naming the field, never a KeyError deep in a tick. Kinds: `start` (coordinator -> process: the
server's address and token), `ready` (process -> coordinator, its connections are up), `tick` (k, the payloads
published and the entities unpublished in that tick), `stop`, and `report` (the process's tallies and viewer
counters), followed by its `errors` frames (its tallies' error samples, packed float64, `report_frames`).
"""

from __future__ import annotations

import struct
from typing import Any

import msgpack
import numpy as np

MAX_FRAME = 256 * 1024 * 1024  # the largest frame read (a tick frame, or a report less its error samples)
#: error samples per `errors` frame (8 bytes each): a report's error samples grow with the run's length (a run
#: goes on until Ctrl-C by default), so they follow the report in frames of their own, each well under MAX_FRAME
ERROR_CHUNK = 1 << 20
HEADER = struct.Struct(">I")

FIELDS: dict[str, dict[str, type | tuple[type, ...]]] = {
    "start": {"host": str, "port": int, "token": str},
    "ready": {"viewers": int},
    "tick": {"k": int, "pub": list, "unpub": list, "sent": float},
    "stop": {},
    "report": {"tallies": dict, "viewers": dict, "subscribe_msgs": int, "ticks": int, "cpu_s": float,
               "tick_delay_p99_ms": float, "error_frames": int},
    "errors": {"group": str, "values": bytes},
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


def report_frames(report: dict) -> list[bytes]:
    """A process's report as frames: the report with its tallies' error lists emptied (and `error_frames`, how
    many follow), then those errors, `ERROR_CHUNK` at most per `errors` frame (little-endian float64)."""
    tallies, chunks = {}, []
    for group, t in report["tallies"].items():
        errors = np.asarray(t["errors"], dtype="<f8")
        tallies[group] = {**t, "errors": []}
        for at in range(0, len(errors), ERROR_CHUNK):
            chunks.append(encode("errors", group=str(group), values=errors[at:at + ERROR_CHUNK].tobytes()))
    return [encode("report", **{**report, "tallies": tallies, "error_frames": len(chunks)}), *chunks]


def add_errors(report: dict, frame: dict) -> None:
    """An `errors` frame's samples back into the report's tallies; WireError for a group the report has not or
    bytes that are not float64s."""
    tally = report["tallies"].get(frame["group"])
    values = frame["values"]
    if not isinstance(tally, dict) or not isinstance(tally.get("errors"), list) or len(values) % 8:
        raise WireError(f"errors frame for group {frame['group']!r:.40} that the report does not hold, "
                        f"or {len(values)} bytes")
    tally["errors"].extend(np.frombuffer(values, dtype="<f8").tolist())


class FrameReader:
    """Bytes in, whole frames out (`feed` then `frames`); a length over `max_frame` or a body that is not
    msgpack is a WireError."""

    def __init__(self, max_frame: int | None = None) -> None:
        self.max_frame = MAX_FRAME if max_frame is None else max_frame
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
