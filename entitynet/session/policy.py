"""Reconnect policy and shard addresses: which errors end a session, how long to wait before trying again.

Kept apart from the session so that the rules a user may need to know (docs/switch.md) sit in one small place.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from entitynet import protocol as P

#: errors after which reconnecting cannot help: the same HELLO would be refused again
REFUSALS = frozenset({P.ErrorCode.VERSION_MISMATCH, P.ErrorCode.TOPOLOGY_MISMATCH, P.ErrorCode.AUTH_FAILED})

#: a shard address: a (host, port) TCP pair, or a ws:// / wss:// URL
Address = tuple[str, int] | str

_RETRY_IN = re.compile(r"retry in (\d+(?:\.\d+)?) s")


@dataclass(frozen=True)
class ReconnectPolicy:
    """Exponential backoff between `first` and `cap` seconds, reset by every successful handshake.

    Why doubling with a cap: a server that is restarting is retried quickly, one that is down is not hammered;
    many clients dropped at once spread out as their failures accumulate. `retry=False` makes every loss final.
    """

    first: float = 0.1
    cap: float = 5.0
    retry: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.first) and math.isfinite(self.cap)) or self.first < 0 or self.cap < self.first:
            raise ValueError(f"backoff must be finite with 0 <= first <= cap, got ({self.first}, {self.cap})")

    def delay(self, failures: int) -> float:
        """Seconds to wait after `failures` (>= 1) consecutive failed or lost attempts."""
        if failures <= 1:
            return self.first
        return min(self.cap, self.first * 2.0 ** min(failures - 1, 60))

    @staticmethod
    def is_final(code: int) -> bool:
        """True for an ERROR that no reconnect can cure (version, topology digest, token)."""
        return code in REFUSALS

    @staticmethod
    def throttled_for(error: P.Error) -> float:
        """The wait an AUTH_THROTTLED refusal asks for ("retry in N s"), 0 for any other error: retrying sooner
        would only be refused again and lengthen the block."""
        if error.code != P.ErrorCode.AUTH_THROTTLED:
            return 0.0
        m = _RETRY_IN.search(error.text)
        return float(m.group(1)) if m else 0.0


def parse_address(text: str) -> Address:
    """A REDIRECT's address as the shell dials it: "ws://..." / "wss://..." as is, "host:port" or "[v6]:port"
    as a (host, port) pair. Raises ValueError for anything else, so a bad redirect moves nothing."""
    if text.startswith(("ws://", "wss://")):
        if len(text) <= len("wss://"):
            raise ValueError(f"bad shard URL {text!r}")
        return text
    host, sep, port = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536 or any(c in host for c in "/ "):
        raise ValueError(f"bad shard address {text!r} (want host:port or a ws:// URL)")
    return host, int(port)
