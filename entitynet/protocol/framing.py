"""Protocol v1 TCP framing: a 4-byte big-endian length prefix before each payload. No I/O.

Why apart from the codec: WebSocket carries one payload per message and needs no framing, and the server's
writer builds frame heads around already encoded bodies (writev) without touching the codec.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable

from entitynet.protocol.codec import DEFAULT_LIMITS, CodecLimits, array_header, decode_payload, encode_payload
from entitynet.protocol.messages import ErrorCode, Message, ProtocolError

LENGTH_PREFIX = struct.Struct(">I")


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
    return LENGTH_PREFIX.pack(body_size + 5) + array_header(n_messages)


def frame(payload: bytes) -> bytes:
    """A payload with its 4-byte big-endian length prefix (TCP framing)."""
    return LENGTH_PREFIX.pack(len(payload)) + payload


def encode_frame(msgs: Iterable[Message]) -> bytes:
    """Messages -> one complete TCP frame (what a client writes for one batch)."""
    return frame(encode_payload(msgs))


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
        """Bytes received but not yet taken as payloads (for the log line of a client that vanished)."""
        return len(self._buf)

    @property
    def mid_frame(self) -> bool:
        """True when part of a frame has arrived but not all of it."""
        return bool(self._buf)

    def receive_data(self, data: bytes) -> None:
        """Bytes as they came off the socket, any split."""
        self._buf += data

    def next_payload(self) -> bytes | None:
        """The next complete frame's payload, or None when more bytes are needed; raises ProtocolError on a
        length prefix over `max_frame` or of zero."""
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
