"""Configuration and limits of one switchboard (one shard)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from entitynet.protocol import CodecLimits


@dataclass(frozen=True, slots=True)
class SwitchConfig:
    """Everything the core needs to know; no geometry, only the cell count and the topology digest.

    Plain data: how tokens become users is not configuration but a dependency, given to the `Switchboard` as
    its `authenticate` callable (the shell's token store); with `open_mode` every token is accepted (local use)
    and the token itself, or `anon-<session>`, is the user id. Failed logins are throttled per peer address
    (`auth_fail_*`, see ratelimit.FailureThrottle). A connection that has not sent HELLO within
    `handshake_timeout_s` of `connect` is closed with HANDSHAKE_REQUIRED (None: never).
    """

    n_cells: int
    digest: str
    open_mode: bool = False
    grace_s: float = 5.0  # an entity lives this long past its validity without an update
    max_subscriptions: int = 20_000  # cells per client
    max_follows: int = 64  # direct subscriptions per client
    max_entities_per_client: int = 20_000  # a proxy may carry many entities over one connection
    max_entities: int = 1_000_000
    query_rate: float = 2.0  # queries per second per client (token bucket) ...
    query_burst: float = 5.0  # ... with this burst
    max_query_results: int = 1000  # and at most what fits in one frame (codec.max_frame)
    # subscription churn (cells added + removed by SUBSCRIBE) per second per client (token bucket): what one
    # client can make the switch do, since every changed cell costs snapshots or LEAVEs of its entities ...
    churn_rate: float = 10_000.0
    churn_burst: float = 40_000.0  # ... with this burst (a first full subscription, or replacing it, passes)
    # replies (PONG, QUERY_RESULT, ERROR) one frame may ask for; the frame's further requests are refused with
    # one TOO_MANY_REQUESTS error (must stay below max_control, which bounds what waits for a slow reader)
    max_replies_per_frame: int = 500
    max_pending: int = 50_000  # coalesced entity states waiting for one client; beyond -> slow consumer
    max_control: int = 1000  # non-coalescible messages (errors, pongs, results) waiting for one client
    codec: CodecLimits = CodecLimits()
    auth_fail_free: int = 3  # failed logins per peer address before the back-off starts ...
    auth_fail_base_s: float = 1.0  # ... blocking it this long, doubling with every further failure ...
    auth_fail_cap_s: float = 60.0  # ... up to this
    handshake_timeout_s: float | None = 10.0  # a connection without HELLO this long is closed
    seed: int | None = None  # for the opaque entity ids; None = unpredictable

    def __post_init__(self) -> None:
        if self.n_cells < 0:
            raise ValueError("n_cells must be >= 0")
        if not (0 <= self.grace_s < math.inf and self.query_rate >= 0 and self.query_burst >= 1):
            raise ValueError("grace_s must be finite and >= 0, query_rate >= 0 and query_burst >= 1")
        if not (self.churn_rate >= 0 and self.churn_burst >= 1):
            raise ValueError("churn_rate must be >= 0 and churn_burst >= 1")
        if self.handshake_timeout_s is not None and not self.handshake_timeout_s > 0:
            raise ValueError("handshake_timeout_s must be > 0 (or None)")
        if not 1 <= self.max_replies_per_frame < self.max_control:
            raise ValueError("max_replies_per_frame must be >= 1 and below max_control")

    def wire_limits(self) -> dict[str, int]:
        """The limits a client is told in WELCOME."""
        return {
            "max_subscriptions": self.max_subscriptions,
            "max_follows": self.max_follows,
            "max_entities": self.max_entities_per_client,
            "query_rate_mhz": int(self.query_rate * 1000),
            "max_frame": self.codec.max_frame,
            "max_payload": self.codec.max_payload,
            "n_cells": self.n_cells,
            "grace_ms": int(self.grace_s * 1000),
            "max_query_results": self.max_query_results,
            "churn_rate": int(self.churn_rate),
            "churn_burst": int(self.churn_burst),
            "max_replies_per_frame": self.max_replies_per_frame,
        }
