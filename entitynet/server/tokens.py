"""The server's token store and its watch for revocations.

Tokens are checked at HELLO. So that `entitynet users remove NAME` (another process) also ends NAME's open
connections, the shell calls `TokenWatch.poll()` every `ServerConfig.auth_recheck` seconds: one
`PRAGMA data_version`, and only when the store changed, one lookup per distinct token of the open connections
(entitynet.switchboard.access.revalidate). A store that cannot be read at that moment (locked by a writer,
removed) is tried again next time; connections are never closed because of it.
"""

from __future__ import annotations

import logging
import sqlite3

from entitynet.server import logs
from entitynet.server.config import ConfigError, ServerConfig
from entitynet.switchboard import Switchboard
from entitynet.switchboard.access import revalidate


class TokenWatch:
    """The token store of a server that is not in open mode, and its change counter."""

    def __init__(self, config: ServerConfig):
        from entitynet.auth import TokenStore, default_db_path

        path = config.users_db or default_db_path()
        try:
            self.store = TokenStore(path)
            self._version = self.store.data_version()
        except (OSError, sqlite3.Error) as exc:
            raise ConfigError(f"cannot open token store {path}: {exc}") from exc
        self.authenticate = self.store.authenticate

    def poll(self, sb: Switchboard) -> list[int]:
        """Close (in the core) the connections whose token was revoked since the last poll; their ids."""
        try:
            version = self.store.data_version()
            if version == self._version:
                return []
            closed = revalidate(sb, self.authenticate)
        except sqlite3.Error as exc:
            logs.event("token store unreadable; re-check postponed", logging.WARNING, error=str(exc))
            return []
        self._version = version
        for cid in closed:
            logs.event("token revoked: connection closed", logging.WARNING, cid=cid, user=sb.user_of(cid) or "?")
        return closed
