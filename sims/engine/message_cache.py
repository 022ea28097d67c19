"""One frame decoder shared by all the simulation's viewer connections: each distinct message decoded once.

Why: the server encodes an UPDATE once and writes the same bytes into the frame of every viewer subscribed to
the entity's cells, so with V viewers one message arrives up to V times (about 26 times at 1,600 entities and
160 viewers), and the codec's per-message checks and dataclass (`entitynet.protocol.codec._decode_one`) were
the largest single part of the viewers' side of a real-time tick. Here msgpack's C unpacker only finds where
each message of a frame starts and ends (`Unpacker.skip` and `tell`, no Python objects built), and the message's
bytes are looked up in a table of the messages already decoded; a new one is decoded by the codec itself (the
one reader of the wire format), alone in a one-message payload, so the same checks apply to it. Messages are
frozen dataclasses: one object serves every viewer, and its payload bytes are then one object too, so the
ghost stores' payload cache (`decode_cache.DecodeCache`) hashes it once.

Equivalence: `decode(payload)` returns what `protocol.decode_payload(payload, limits)` returns (equal messages,
in order) and raises what it raises: a frame the fast walk does not accept whole (over `max_frame`, not one
array, more than `max_messages`, trailing bytes, anything msgpack refuses) or that holds a bad message is
handed whole to the codec, which gives the answer or the error (tests/sims/engine/test_message_cache.py).
Bounded: cleared when it holds `max_entries` messages, and by its owner each tick (`clear`). One unpacker serves
every frame (built again after a frame it refused): building one per frame was a third of the walk's cost.
`on_new(msg)` is told of each message decoded anew (the viewer fleet maps an external server's ids from the
payloads once per distinct message, not once per delivery).
"""

from __future__ import annotations

from collections.abc import Callable

import msgpack

from entitynet import protocol as P


class Frame(list):
    """A frame's messages, as a list, with `nbytes`: the encoded size of them all (the payload less its array
    header), so that a viewer's byte count takes a frame in one addition."""

    __slots__ = ("nbytes",)


class MessageCache:
    """Frame payload -> messages, each distinct message's bytes decoded once (see the module docstring);
    `size(msg)` is the encoded size of a message it returned (the viewers' byte counts without re-encoding)."""

    def __init__(self, limits: P.CodecLimits = P.DEFAULT_LIMITS, max_entries: int = 100_000,
                 on_new: Callable[[P.Message], None] | None = None) -> None:
        if max_entries < 1:
            raise ValueError(f"max_entries must be >= 1, got {max_entries}")
        self.limits = limits
        self.max_entries = max_entries
        self._messages: dict[bytes, P.Message] = {}
        self._sizes: dict[int, tuple[P.Message, int]] = {}  # id(message) -> (the message, its encoded size)
        self.hits = 0
        self.misses = 0
        self._one = P.array_header(1)
        self.on_new = on_new
        self._up = self._unpacker()

    def _unpacker(self) -> msgpack.Unpacker:
        return msgpack.Unpacker(max_buffer_size=max(self.limits.max_frame, 1))

    def __len__(self) -> int:
        return len(self._messages)

    def clear(self) -> None:
        """Forget every message (the shell calls it each tick: a message is shared within a tick's fan-out)."""
        self._messages.clear()
        self._sizes.clear()

    def size(self, msg: P.Message) -> int | None:
        """The encoded size of `msg` if this cache returned that very object since the last clear, else None."""
        got = self._sizes.get(id(msg))
        return got[1] if got is not None and got[0] is msg else None

    def decode(self, payload: bytes) -> list[P.Message]:
        """The messages of one frame payload, as `protocol.decode_payload(payload, limits)` gives them (and
        its ProtocolError for a bad frame); a `Frame` with their encoded size where the fast walk took it."""
        lim = self.limits
        if len(payload) > lim.max_frame:
            return P.decode_payload(payload, lim)  # raises FRAME_TOO_LARGE
        out = Frame()
        get = self._messages.get
        misses = 0
        try:  # one pass: where each message ends (msgpack's C unpacker, no objects built), then its bytes looked up
            up = self._up
            base = up.tell()
            up.feed(payload)
            n = up.read_array_header()
            if n > lim.max_messages:
                self._up = self._unpacker()
                return P.decode_payload(payload, lim)  # raises
            skip, tell = up.skip, up.tell
            at = first = tell() - base
            for _ in range(n):
                skip()
                end = tell() - base
                piece = payload[at:end]
                m = get(piece)
                if m is None:
                    m = self._decode_new(piece, end - at)
                    if m is None:
                        self._up = self._unpacker()
                        # the frame is bad; the codec unpacks it whole before it checks any message, so a later
                        # message msgpack refuses decides the error over this one's: the codec gives it
                        return P.decode_payload(payload, lim)
                    misses += 1
                out.append(m)
                at = end
        except Exception:  # not one array of whole msgpack objects: the codec says what is wrong
            self._up = self._unpacker()
            return P.decode_payload(payload, lim)
        if at != len(payload):
            self._up = self._unpacker()
            return P.decode_payload(payload, lim)  # trailing bytes
        self.misses += misses
        self.hits += n - misses
        out.nbytes = at - first
        return out

    def _decode_new(self, piece: bytes, size: int) -> P.Message | None:
        """A message not seen since the last clear, decoded alone by the codec and remembered (None: refused)."""
        try:
            (m,) = P.decode_payload(self._one + piece, self.limits)
        except P.ProtocolError:
            return None
        if len(self._messages) >= self.max_entries:
            self.clear()
        self._messages[piece] = m
        self._sizes[id(m)] = (m, size)
        if self.on_new is not None:
            self.on_new(m)
        return m
