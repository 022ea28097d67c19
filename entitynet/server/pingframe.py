"""Recognise a read that is exactly one frame holding one PING, from its bytes, before the frame decoder.

Why: a lock step's barrier (`bench e2e`) sends every client one PING per tick, and most of what the server then
spends per PING in Python was the general path: the deframer's buffer, msgpack, the per-message checks and the
`Ping` built on the way. A PING frame as our clients write it is 8 to 16 bytes of fixed shape: the 4-byte length,
`0x91 0x92 0x0f` (an array of one message, an array of two, type 15) and client_ms as a msgpack unsigned int.
`lone_ping_ms` reads exactly that shape and nothing else: any other encoding, a second frame in the same read,
or a value the codec refuses returns None and goes the reference way (`FrameDecoder` and `decode_payload`),
which stays the one judge of what is valid; tests compare the two on arbitrary bytes.
"""

from __future__ import annotations

from entitynet.protocol import MAX_INT

_HEAD = b"\x91\x92\x0f"  # array(1) [ array(2) [ 15 = PING, ...
_WIDTH = {0xCC: 1, 0xCD: 2, 0xCE: 4, 0xCF: 8}  # msgpack uint 8/16/32/64


def lone_ping_ms(data: bytes) -> int | None:
    """client_ms when `data` is one whole frame holding one PING in the canonical encoding, else None."""
    n = len(data)
    if n < 8 or n > 16 or data[4:7] != _HEAD or int.from_bytes(data[:4], "big") != n - 4:
        return None
    tag = data[7]
    if tag < 0x80:  # positive fixint
        return tag if n == 8 else None
    width = _WIDTH.get(tag)
    if width is None or n != 8 + width:
        return None
    ms = int.from_bytes(data[8:], "big")
    return ms if ms <= MAX_INT else None
