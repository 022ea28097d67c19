"""How entitynet starts another entitynet process (shards, benchmark servers) and reports one that died.

Why one home: every launcher used `python -m entitynet`, which puts the current folder first on `sys.path`; a
user who starts a cluster from a folder holding another `entitynet/` (an old checkout, a copy of the package)
got children that imported that one and died, with an error that only named a log. `entitynet_argv` runs the
child with `-P` (Python 3.11+: no unsafe path entry), so it imports the package this interpreter has installed,
and `last_lines` puts the child's own last words into the error when it dies at start.
"""

from __future__ import annotations

import sys
from collections import deque
from pathlib import Path


def entitynet_argv(*args: str, python_options: tuple[str, ...] = ()) -> list[str]:
    """The argv of `entitynet ARGS` in this interpreter and environment, immune to the working folder.

    `python_options` go before the module (e.g. `("-m", "cProfile", "-o", FILE)` to profile the child)."""
    return [sys.executable, "-P", *python_options, "-m", "entitynet", *args]


def last_lines(log: Path, n: int = 8, max_chars: int = 2000) -> str:
    """The last `n` non-blank lines of a child's log (at most `max_chars`, its end kept), or a note that there
    are none: what an error about a child that died should show the user instead of only the log's path."""
    try:
        with open(log, errors="replace") as f:
            tail = deque((line.rstrip() for line in f if line.strip()), maxlen=n)
    except OSError as exc:
        return f"(its log {log} cannot be read: {exc.strerror or exc})"
    if not tail:
        return "(its log is empty)"
    return "\n".join(tail)[-max_chars:]
