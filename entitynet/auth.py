"""Auth tokens mapped to user ids, in SQLite.

Only a SHA-256 of each token is stored, so a leaked database does not leak usable tokens. Tokens are
random (secrets.token_urlsafe); a user may hold several. Lookups are one indexed SELECT; the server still
runs them in a worker thread with a deadline (entitynet.server.tokens), since another process may hold the
file locked and a damaged file raises: neither may hold or end the server.

The file holds who may connect, so it is private to its owner: a new store is created 0600 (and the folder
0700 when we create it); an existing store that others can read is reported with a warning, not changed.
A server watches `data_version()` to notice `entitynet users remove` from another process and re-check the
tokens of its open connections (entitynet.switchboard.access.revalidate).
"""

from __future__ import annotations

import hashlib
import logging
import os
import re
import secrets
import sqlite3
import time
from pathlib import Path

log = logging.getLogger("entitynet.auth")

USER_RE = re.compile(r"^[A-Za-z0-9_.@-]{1,64}$")


def default_db_path() -> Path:
    """$ENTITYNET_USERS_DB, else $XDG_DATA_HOME/entitynet/users.sqlite (~/.local/share by default)."""
    env = os.environ.get("ENTITYNET_USERS_DB")
    if env:
        return Path(env)
    base = Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share")
    return base / "entitynet" / "users.sqlite"


def _hash(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def _create_private(path: Path) -> None:
    """Create the store's folder (0700) and an empty file (0600) if they are missing, before SQLite opens it:
    SQLite would create the file with the umask (usually world-readable), and its journal files copy the
    database's mode, so getting the mode right at creation covers them too."""
    parent = path.parent
    if not parent.exists():
        parent.parent.mkdir(parents=True, exist_ok=True)
        parent.mkdir(mode=0o700, exist_ok=True)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        mode = path.stat().st_mode
        if mode & 0o077:
            log.warning("token store %s is readable by others (mode %o); chmod 600 it", path, mode & 0o777)
        return
    os.close(fd)


class TokenStore:
    """Who may connect: token hashes -> user ids in one SQLite file, shared by `entitynet users` and
    the server (which polls `data_version` to see revocations made from another process)."""

    def __init__(self, path: str | os.PathLike, timeout: float = 5.0):
        """Open (creating if missing) the store; `timeout` is how long one statement waits for a lock another
        process holds before it fails with "database is locked"."""
        self.path = Path(path)
        _create_private(self.path)
        self._db = sqlite3.connect(str(self.path), timeout=timeout, check_same_thread=False)
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS tokens (hash TEXT PRIMARY KEY, user TEXT NOT NULL, created REAL NOT NULL)"
        )
        self._db.execute("CREATE INDEX IF NOT EXISTS tokens_user ON tokens(user)")
        self._db.commit()

    def damage(self) -> str | None:
        """What SQLite's quick check finds wrong with the file (None: nothing). A page of the data can be damaged
        while the header still opens; a server checks at start rather than fail every login later."""
        try:
            rows = [str(r[0]) for r in self._db.execute("PRAGMA quick_check(5)")]
        except sqlite3.DatabaseError as exc:
            return str(exc)
        return None if rows == ["ok"] else "; ".join(r.replace("\n", " ") for r in rows)

    def data_version(self) -> int:
        """SQLite's change counter: differs from the last value when another connection (another process, e.g.
        `entitynet users remove`) committed a change since. One cheap PRAGMA, fine to poll every second."""
        return int(self._db.execute("PRAGMA data_version").fetchone()[0])

    def close(self) -> None:
        """Release the SQLite handle; public so that an embedding program or a test can close a store it
        opened before the file is removed or reopened."""
        self._db.close()

    def add_user(self, user: str) -> str:
        """Create a new token for `user` (a user may have several) and return it; it is not stored in clear."""
        if not USER_RE.match(user):
            raise ValueError("user ids are 1-64 characters of letters, digits, _ . @ -")
        token = secrets.token_urlsafe(24)
        with self._db:
            self._db.execute("INSERT INTO tokens VALUES (?, ?, ?)", (_hash(token), user, time.time()))
        return token

    def authenticate(self, token: str) -> str | None:
        """The user id of `token`, or None. Empty or over-long tokens (> 256 characters) are refused
        without hashing or a query, so junk costs nothing."""
        if not token or len(token) > 256:
            return None
        row = self._db.execute("SELECT user FROM tokens WHERE hash = ?", (_hash(token),)).fetchone()
        return row[0] if row else None

    def users(self) -> list[tuple[str, int]]:
        """(user, number of tokens), sorted by user."""
        return list(self._db.execute("SELECT user, COUNT(*) FROM tokens GROUP BY user ORDER BY user"))

    def remove_user(self, user: str) -> int:
        """Revoke all tokens of `user`; returns how many."""
        with self._db:
            return self._db.execute("DELETE FROM tokens WHERE user = ?", (user,)).rowcount
