"""The server's token store, read off the event loop, and its watch for revocations.

Tokens are checked at HELLO. The store is a SQLite file that other processes write (`entitynet users`), so a
read can wait for their lock (SQLite's busy timeout) or fail on a damaged page. Neither may hold the event loop
(every other client waits) or end the server: each read runs in a worker thread (one at a time: one SQLite
handle) under a deadline (`ServerConfig.auth_timeout`), and a read that fails or times out refuses that login
with 502 AUTH_UNAVAILABLE (clients retry it) and logs why, at most one line a second.

The core asks its resolver synchronously (entitynet.switchboard.access.admit), so the shell looks the token of
a HELLO up first (`lookup`) and hands the answer over for that one feed (`answering`).

So that `entitynet users remove NAME` (another process) also ends NAME's open connections, the shell calls
`poll()` every `ServerConfig.auth_recheck` seconds: one `PRAGMA data_version`, and only when the store changed,
one lookup per distinct token of the open connections, all in the worker thread
(entitynet.switchboard.access.revalidate). A store that cannot be read then is tried again next time;
connections are never closed because of it.
"""

from __future__ import annotations

import contextlib
import logging
import sqlite3
from collections.abc import Iterator

import trio

from entitynet.server import logs
from entitynet.server.accept import Throttled
from entitynet.server.config import ConfigError, ServerConfig
from entitynet.switchboard import Switchboard
from entitynet.switchboard.access import StoreUnavailable, revalidate, tokens_in_use

#: what a lookup answered: the user id, None (unknown token) or why the store could not answer
Answer = str | None | StoreUnavailable


class TokenWatch:
    """The token store of a server that is not in open mode, its reads off the loop, and its change counter."""

    def __init__(self, config: ServerConfig):
        from entitynet.auth import TokenStore, default_db_path

        path = config.users_db or default_db_path()
        self.timeout = config.auth_timeout
        try:
            # SQLite's own wait for a lock ends within the deadline, so an abandoned read does not linger
            self.store = TokenStore(path, timeout=self.timeout / 2)
            damage = self.store.damage()
            self._version = self.store.data_version()
        except (OSError, sqlite3.Error) as exc:
            raise ConfigError(f"cannot open token store {path}: {exc}") from exc
        if damage is not None:
            self.store.close()
            raise ConfigError(f"token store {path} is damaged ({damage}); restore it from a backup, or move it "
                              "away and add the users again with `entitynet users add`")
        self._reads = trio.CapacityLimiter(1)  # one SQLite handle: one read at a time
        self._answer: tuple[str, Answer] | None = None
        self._unavailable = Throttled("token store unavailable: login refused")
        self._poll_failed = Throttled("token store unreadable; re-check postponed")

    async def _read(self, fn, *args):
        """`fn(*args)` in the worker thread within the deadline; a timeout is a StoreUnavailable."""
        with trio.move_on_after(self.timeout):
            return await trio.to_thread.run_sync(fn, *args, limiter=self._reads, abandon_on_cancel=True)
        raise StoreUnavailable(f"no answer within {self.timeout:g} s")

    async def lookup(self, token: str) -> Answer:
        """The user of `token` (None: unknown), or a StoreUnavailable saying why the store did not answer."""
        try:
            return await self._read(self.store.authenticate, token)
        except (sqlite3.Error, StoreUnavailable) as exc:
            self._unavailable(error=str(exc), store=str(self.store.path))
            return exc if isinstance(exc, StoreUnavailable) else StoreUnavailable(str(exc))

    @contextlib.contextmanager
    def answering(self, token: str, answer: Answer) -> Iterator[None]:
        """While the core handles one frame (synchronously), `authenticate(token)` gives this answer."""
        self._answer = (token, answer)
        try:
            yield
        finally:
            self._answer = None

    def authenticate(self, token: str) -> str | None:
        """The core's resolver: the answer `lookup` found for this HELLO. A token that was not looked up is
        refused as unavailable rather than read here, on the loop."""
        if self._answer is None or self._answer[0] != token:
            raise StoreUnavailable("token not looked up")
        answer = self._answer[1]
        if isinstance(answer, StoreUnavailable):
            raise answer
        return answer

    def _changes(self, tokens: set[str]) -> tuple[int, dict[str, str | None]] | None:
        """(In the worker thread.) None when the store has not changed; else its version and the users now
        named by `tokens`."""
        version = self.store.data_version()
        if version == self._version:
            return None
        return version, {t: self.store.authenticate(t) for t in tokens}

    async def poll(self, sb: Switchboard) -> list[int]:
        """Close (in the core) the connections whose token was revoked since the last poll; their ids."""
        try:
            found = await self._read(self._changes, tokens_in_use(sb))
        except (sqlite3.Error, StoreUnavailable) as exc:
            self._poll_failed(error=str(exc))
            return []
        if found is None:
            return []
        version, users = found
        closed = revalidate(sb, users.__getitem__, only=users)  # connections made meanwhile were just checked
        self._version = version
        for cid in closed:
            logs.event("token revoked: connection closed", logging.WARNING, cid=cid, user=sb.user_of(cid) or "?")
        return closed
