"""Cutting the session's messages into frames the server accepts: a replay after a reconnect or a REDIRECT can carry
thousands of PUBLISHes, and one frame over the server's `max_frame` would be refused whole, every time."""

from __future__ import annotations

from entitynet import protocol as P

REPLAY_CHUNK = 5000  # messages per replay frame at most, well inside the codec's 20,000 ...
FRAME_ROOM = 64  # ... and bytes kept free below the frame limit for the array header and length prefix


def batches(msgs: list[P.Message], max_frame: int) -> list[tuple[P.Message, ...]]:
    """Cut messages into frames of at most REPLAY_CHUNK messages and `max_frame` bytes: a fleet of entities with
    large payloads would otherwise exceed the server's frame limit and be refused whole on every reconnect."""
    room = max_frame - FRAME_ROOM
    out: list[tuple[P.Message, ...]] = []
    batch: list[P.Message] = []
    size = 0
    for m in msgs:
        n = size_bound(m)
        if batch and (size + n > room or len(batch) >= REPLAY_CHUNK):
            out.append(tuple(batch))
            batch, size = [], 0
        batch.append(m)
        size += n
    if batch:
        out.append(tuple(batch))
    return out


def size_bound(m: P.Message) -> int:
    """Encoded size of a message, or a bound above it for PUBLISH (the hot path: no encoding twice). A PUBLISH is
    a 6-array of type, four integers of at most 9 bytes each, a cell array (at most 9 bytes a cell plus its
    header) and a bin payload (at most 5 bytes of header)."""
    if type(m) is P.Publish:
        return 1 + 1 + 4 * 9 + 5 + 9 * len(m.cells) + 5 + len(m.payload)
    return len(P.encode_message(m))
