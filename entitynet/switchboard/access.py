"""Who may join and who may stay: the HELLO checks in order, and re-checking tokens after a revocation.

HELLO is checked in this order: protocol version (public anyway); the peer's failed-login back-off; the token;
and only then the topology digest. A client that has not authenticated therefore learns nothing about the map
the server holds, not even whether its own digest is right. In open mode every token is accepted and names the
user, so the digest is checked right after the version.

Tokens are checked once at HELLO; `revalidate` checks the open connections again. The shell calls it when the
token store changed (entitynet.auth.TokenStore.data_version), so `entitynet users remove NAME` in another
process closes NAME's connections within the shell's re-check interval.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection
from typing import TYPE_CHECKING

from entitynet import protocol as P
from entitynet.protocol import ErrorCode
from entitynet.switchboard.config import SwitchConfig
from entitynet.switchboard.ratelimit import FailureThrottle

if TYPE_CHECKING:
    from entitynet.switchboard.core import Switchboard


class StoreUnavailable(Exception):
    """Raised by the shell's token resolver when it cannot answer (its store is locked or damaged): the HELLO
    is refused with AUTH_UNAVAILABLE, which clients retry, and it is not counted as a failed login."""


def throttle_for(cfg: SwitchConfig) -> FailureThrottle:
    """The failed-login back-off of a switchboard, from its configuration."""
    return FailureThrottle(cfg.auth_fail_free, cfg.auth_fail_base_s, cfg.auth_fail_cap_s)


def admit(cfg: SwitchConfig, throttle: FailureThrottle, m: P.Hello, peer: str, session: int, now: float,
          authenticate: Callable[[str], str | None] | None = None) -> tuple[str | None, P.ProtocolError | None]:
    """(user id, None) for a HELLO that may join, else (None, the error to close with). `authenticate` is the
    shell's resolver (token -> user id or None); it is asked only after the back-off let the peer try."""
    if m.version != P.PROTOCOL_VERSION:
        return None, P.ProtocolError(
            ErrorCode.VERSION_MISMATCH, f"server speaks protocol v{P.PROTOCOL_VERSION}, not v{m.version}")
    if cfg.open_mode:
        user: str | None = m.token or f"anon-{session}"
    else:
        wait = throttle.retry_after(peer, now)
        if wait > 0.0:
            return None, P.ProtocolError(
                ErrorCode.AUTH_THROTTLED,
                f"too many failed logins from your address; retry in {math.ceil(wait)} s")
        try:
            user = authenticate(m.token) if authenticate and m.token else None
        except StoreUnavailable:
            return None, P.ProtocolError(ErrorCode.AUTH_UNAVAILABLE,
                                         "the server cannot check tokens right now; try again later")
        if user is None:
            block = throttle.failed(peer, now)
            later = f"; your address may try again in {math.ceil(block)} s" if block > 0.0 else ""
            return None, P.ProtocolError(ErrorCode.AUTH_FAILED, "unknown or missing auth token" + later)
    if m.digest != cfg.digest:
        return None, P.ProtocolError(
            ErrorCode.TOPOLOGY_MISMATCH,
            f"topology digest mismatch: server has {cfg.digest[:16]}, client has {m.digest[:16]}")
    return user, None


def asks_token(cfg: SwitchConfig, throttle: FailureThrottle, m: P.Hello, peer: str, now: float) -> bool:
    """Whether `admit` would ask the resolver about this HELLO's token, so that a shell whose store answers
    slowly looks it up beforehand (off its event loop) only when it will be needed: not for a blocked peer,
    an empty token, a wrong protocol version or in open mode."""
    return (m.version == P.PROTOCOL_VERSION and not cfg.open_mode and bool(m.token)
            and throttle.retry_after(peer, now) <= 0.0)


def tokens_in_use(sb: Switchboard) -> set[str]:
    """The distinct tokens of the authenticated connections: what a re-check after a revocation looks up."""
    return {c.token for c in sb.clients.values() if c.token is not None and c.ready and not c.closing}


def revalidate(sb: Switchboard, authenticate: Callable[[str], str | None], only: Collection[str] | None = None,
               ) -> list[int]:
    """Close (AUTH_FAILED, "revoked") every authenticated connection whose token no longer names its user;
    returns their ids. One store lookup per distinct token; with `only`, just the connections of those tokens
    (the shell looked them up beforehand, off its loop). Errors of `authenticate` (a locked or vanished store)
    propagate and close nobody: the shell retries later."""
    users: dict[str, str | None] = {}
    closed: list[int] = []
    for c in list(sb.clients.values()):
        token = c.token
        if token is None or not c.ready or c.closing or (only is not None and token not in only):
            continue
        if token not in users:
            users[token] = authenticate(token)
        if users[token] != c.user_id:
            sb.protocol_error(c.cid, P.ProtocolError(ErrorCode.AUTH_FAILED, "auth token revoked; disconnecting"))
            closed.append(c.cid)
    return closed
