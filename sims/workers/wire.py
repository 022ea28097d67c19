"""The frames between a run's coordinator and its workers: msgpack maps, checked on the way in.

Why checked field by field: a worker may run on another machine, another version, or be something else on the
same NATS subject; a frame that does not have the fields of its kind, of their types, is a `WireError` (the
receiver counts it and carries on), never a KeyError deep inside a tick. Frames are bounded (`MAX_FRAME`).

Kinds (coordinator -> worker: assign, tick, stop, alive; worker -> coordinator: hello, ready, refuse, out, bye):
- hello: a NATS worker announces itself while idle (worker id, host, pid);
- assign: join run `run` as worker `index` of `n`, with the run's `config` and the `digests` its topology and
  schedule must have; `reply`: the subject to answer on (NATS), `timeout`: how long a worker waits for a tick
  before it gives the run up;
- ready / refuse: the worker built its share of the run, or cannot (why);
- tick: step to tick `k` (0: the start), with the workers declared dead so far, in the order they died;
- out: what the worker's honest clients sent in tick `k` (`frame`: a protocol payload of PUBLISH / UNPUBLISH),
  in `part`s when large (`last` marks the final one), its cumulative client counters, the seconds its step
  took and how many entities it carries;
- bye: the worker's final counters (after stop); stop: the run ends (why);
- alive: the coordinator is still there (sent over NATS every second, by its transport's own thread, so that
  a pause or a long wait for another worker does not look like a dead coordinator).
"""

from __future__ import annotations

import math
from typing import Any

import msgpack

#: the largest frame either side accepts (a tick's messages of a large share, before splitting for NATS)
MAX_FRAME = 64 << 20
#: the most workers a run may have (an assign's `n`): every side keeps per-worker tables of that size
MAX_WORKERS = 1024

_STR, _INT, _FLOAT, _BOOL, _BYTES, _DICT, _LIST = str, int, (int, float), bool, bytes, dict, list

FIELDS: dict[str, dict[str, Any]] = {
    "hello": {"worker": _STR, "host": _STR, "pid": _INT},
    "assign": {"run": _STR, "index": _INT, "n": _INT, "config": _DICT, "digests": _DICT, "timeout": _FLOAT,
               "reply": _STR},
    "ready": {"run": _STR, "index": _INT, "worker": _STR, "host": _STR, "pid": _INT},
    "refuse": {"run": _STR, "index": _INT, "why": _STR},
    "tick": {"run": _STR, "k": _INT, "dead": _LIST},
    "out": {"run": _STR, "index": _INT, "k": _INT, "part": _INT, "last": _BOOL, "frame": _BYTES,
            "counters": _DICT, "step_s": _FLOAT, "owned": _INT},
    "bye": {"run": _STR, "index": _INT, "counters": _DICT},
    "stop": {"run": _STR, "why": _STR},
    "alive": {"run": _STR},
}


class WireError(ValueError):
    """A frame that is not a frame of this protocol (malformed, unknown kind, missing or mistyped field)."""


def encode(kind: str, **fields: Any) -> bytes:
    """One frame; the fields are checked as the receiver will check them (a sender bug fails here, loudly)."""
    frame = {"kind": kind, **fields}
    _check(frame)
    return msgpack.packb(frame, use_bin_type=True)


def decode(data: bytes) -> dict[str, Any]:
    """The frame in `data` (a dict with its kind under "kind"), or `WireError` saying what is wrong."""
    if len(data) > MAX_FRAME:
        raise WireError(f"frame of {len(data)} bytes is over the {MAX_FRAME} limit")
    try:
        frame = msgpack.unpackb(data, raw=False, strict_map_key=True, max_bin_len=MAX_FRAME)
    except Exception as exc:  # msgpack raises several types (ExtraData, FormatError, ValueError, ...)
        raise WireError(f"not a msgpack frame: {exc}") from None
    _check(frame)
    return frame


def _check(frame: Any) -> None:
    if not isinstance(frame, dict):
        raise WireError(f"a frame is a map, got {type(frame).__name__}")
    kind = frame.get("kind")
    spec = FIELDS.get(kind) if isinstance(kind, str) else None
    if spec is None:
        raise WireError(f"unknown frame kind {kind!r:.40}")
    for name, typ in spec.items():
        value = frame.get(name)
        if not isinstance(value, typ) or (typ is _INT and isinstance(value, bool)):
            raise WireError(f"{kind} frame: field {name!r} missing or not {_type_name(typ)}")
    if kind == "tick" and (frame["k"] < 0 or not all(isinstance(w, int) and w >= 0 for w in frame["dead"])):
        raise WireError("tick frame: negative tick or bad dead worker list")
    if kind in ("assign", "ready", "refuse", "out", "bye") and frame["index"] < 0:
        raise WireError(f"{kind} frame: negative worker index")
    if kind == "out" and not (math.isfinite(frame["step_s"]) and frame["step_s"] >= 0 and frame["owned"] >= 0):
        raise WireError("out frame: step time not a finite number of seconds, or a negative entity count")
    if kind == "assign" and not math.isfinite(frame["timeout"]) or kind == "assign" and frame["timeout"] <= 0:
        raise WireError("assign frame: the timeout must be a positive number of seconds")
    if kind == "assign" and not 0 <= frame["index"] < frame["n"] <= MAX_WORKERS:
        raise WireError(f"assign frame: worker {frame['index']} of {frame['n']} (at most {MAX_WORKERS} workers)")
    if kind in ("out", "bye") and not all(isinstance(k, str) and isinstance(v, int) and not isinstance(v, bool)
                                          for k, v in frame["counters"].items()):
        raise WireError(f"{kind} frame: counters must map names to integers")


def _type_name(typ: Any) -> str:
    if isinstance(typ, tuple):
        return "a number"
    return {str: "a string", int: "an integer", bool: "a boolean", bytes: "bytes", dict: "a map",
            list: "a list"}[typ]
