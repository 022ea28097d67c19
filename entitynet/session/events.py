"""What the client session asks its I/O shell to do. Plain frozen records, so a test can compare them.

Every network attempt gets its own integer `link` token from the session (in `Connect`); the shell quotes it
back in every event of that attempt, so a late event of an attempt the session already gave up is ignored.
"""

from __future__ import annotations

from dataclasses import dataclass

from entitynet import protocol as P
from entitynet.session.policy import Address


@dataclass(frozen=True, slots=True)
class Connect:
    """Open a connection to `address` for attempt `link`, then report `connection_made(link, now)`."""

    link: int
    address: Address


@dataclass(frozen=True, slots=True)
class Send:
    """Write these messages as one frame on attempt `link` (skip it if that attempt is gone)."""

    link: int
    msgs: tuple[P.Message, ...]


@dataclass(frozen=True, slots=True)
class Drop:
    """Close attempt `link` (bad input, handshake timeout, or nothing left to carry), then report the loss."""

    link: int
    reason: str


@dataclass(frozen=True, slots=True)
class Deliver:
    """Hand this message to the application (UPDATE, LEAVE, ERROR, REDIRECT, and the home WELCOME)."""

    msg: P.Message


@dataclass(frozen=True, slots=True)
class Answer:
    """The answer to pending query `query_id`: a QUERY_RESULT, or the ERROR that refused it."""

    query_id: int
    msg: P.QueryResult | P.Error


@dataclass(frozen=True, slots=True)
class Notice:
    """Something worth a log line that changes nothing for the application (a loss, a bad redirect)."""

    text: str


@dataclass(frozen=True, slots=True)
class Stop:
    """The session is over: refused for good (`error` set), or a loss while reconnecting is off (`error` None)."""

    error: P.Error | None


Action = Connect | Send | Drop | Deliver | Answer | Notice | Stop
