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
Bounded: cleared when it holds `max_entries` messages, and by its owner each tick (`clear`). The messages the
codec decoded are also kept across the clears, in two generations of at most `keep` messages and `keep_clears`
clears each (the older one goes when the newer is full or old), so that a message seen in an earlier tick is
looked up, not decoded again: same bytes, the same immutable message. One unpacker serves every frame (built
again after a frame it refused): building one per frame was a third of the walk's cost. Where the walk is
compiled (sims/engine/_frame_walk.pyx) it runs instead of the Python walk, which stays as the reference.
`on_new(msg)` is told of each message new since the last clear (the viewer fleet maps an external server's ids
from the payloads once per distinct message and tick, not once per delivery).
"""

from __future__ import annotations

import os
from collections.abc import Callable

import msgpack

from entitynet import protocol as P

# the walk in C (sims/engine/_frame_walk.pyx, built by pip where a C compiler is found): the same messages as the
# Python walk below, the reference, which runs without it or with ENTITYNET_PURE_PYTHON=1
try:
    from sims.engine import _frame_walk as _COMPILED  # type: ignore[attr-defined]
except ImportError:
    _COMPILED = None


# decoded messages kept across the per-tick clears, per generation: a viewer that subscribes to new cells gets
# the stored UPDATEs of the entities there, published ticks ago (measured at 8,000 entities and 800 viewers:
# 5,000-11,600 messages a tick not seen since the last clear, against about 1,200 new; each a codec decode; kept
# 32,768 a generation: 1,170 decoded a tick, 16,384: 1,437, 8,192: 4,593), about 600 bytes a message kept
KEEP = 32_768
KEEP_CLEARS = 60  # clears a generation lasts (30 s at the simulator's 2 ticks a second)


class Frame(list):
    """A frame's messages, as a list, with `nbytes`: the encoded size of them all (the payload less its array
    header), so that a viewer's byte count takes a frame in one addition."""

    __slots__ = ("nbytes",)


class MessageCache:
    """Frame payload -> messages, each distinct message's bytes decoded once (see the module docstring);
    `size(msg)` is the encoded size of a message it returned (the viewers' byte counts without re-encoding)."""

    def __init__(self, limits: P.CodecLimits = P.DEFAULT_LIMITS, max_entries: int = 100_000,
                 on_new: Callable[[P.Message], None] | None = None, keep: int = KEEP,
                 keep_clears: int = KEEP_CLEARS) -> None:
        """`keep`: how many decoded messages a generation of the kept table holds across `clear`s, and
        `keep_clears`: how many clears it lasts (two generations: at most 2 * keep messages, none older than
        2 * keep_clears clears; keep=0: none kept, every message after a clear decoded again)."""
        if max_entries < 1:
            raise ValueError(f"max_entries must be >= 1, got {max_entries}")
        if keep < 0 or keep_clears < 1:
            raise ValueError(f"keep must be >= 0 and keep_clears >= 1, got {keep} and {keep_clears}")
        self.limits = limits
        self.max_entries = max_entries
        self.keep, self.keep_clears = keep, keep_clears
        self._clears = 0
        self._messages: dict[bytes, P.Message] = {}
        self._sizes: dict[int, tuple[P.Message, int]] = {}  # id(message) -> (the message, its encoded size)
        self._kept: dict[bytes, P.Message] = {}  # decoded messages kept across clears: this generation
        self._kept_old: dict[bytes, P.Message] = {}  # and the one before
        self.hits = 0
        self.misses = 0  # messages not seen since the last clear
        self.decoded = 0  # of those, the ones the codec decoded (not kept from before the clear)
        self._one = P.array_header(1)
        self.on_new = on_new
        self._up = self._unpacker()
        self._walk = None if _COMPILED is None or os.environ.get("ENTITYNET_PURE_PYTHON") else _COMPILED.walk

    def _unpacker(self) -> msgpack.Unpacker:
        return msgpack.Unpacker(max_buffer_size=max(self.limits.max_frame, 1))

    def __len__(self) -> int:
        return len(self._messages)

    def clear(self) -> None:
        """Forget every message (the shell calls it each tick: a message is shared within a tick's fan-out); the
        kept table starts a new generation every `keep_clears` clears."""
        self._messages.clear()
        self._sizes.clear()
        self._clears += 1
        if self._clears % self.keep_clears == 0:
            self._new_generation()

    def _new_generation(self) -> None:
        self._kept_old, self._kept = self._kept, {}

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
        if self._walk is not None:  # (the same walk in C: where each message ends, by the format's type bytes)
            got = self._walk(payload, self, lim.max_messages, out)
            if got is None:
                return P.decode_payload(payload, lim)  # not one array of whole messages, or a message refused
            self.misses += got[0]
            self.hits += len(out) - got[0]
            out.nbytes = len(payload) - got[1]
            return out
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
        """A message not seen since the last clear: the one kept from before it, or decoded alone by the codec
        and kept (None: refused); remembered for this tick and told to `on_new` either way."""
        m = self._kept.get(piece)
        if m is None:
            m = self._kept_old.get(piece)
            if m is None:
                try:
                    (m,) = P.decode_payload(self._one + piece, self.limits)
                except P.ProtocolError:
                    return None
                self.decoded += 1
            if self.keep:
                if len(self._kept) >= self.keep:  # a new generation: the oldest messages go
                    self._new_generation()
                self._kept[piece] = m
        if len(self._messages) >= self.max_entries:
            self.clear()
        self._messages[piece] = m
        self._sizes[id(m)] = (m, size)
        if self.on_new is not None:
            self.on_new(m)
        return m
