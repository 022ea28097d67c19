"""Which of the server's compiled hot paths are in use, and the one notice when they are not.

Why: the compiled per-PUBLISH route and fan-out (`entitynet/switchboard/_fanout.pyx`), the compiled flush loop
(`entitynet/server/_flushloop.pyx`), the compiled read path (`entitynet/server/_hubpass.pyx`) and the compiled
frame decoder (`entitynet/protocol/_decode.pyx`) are
optional: pip builds them where a C compiler is found, and otherwise the pure-Python references run, slower but
with the same behaviour. An operator should learn that from the log, once per process (not once per server
started in it, nor per connection), with the reason.
"""

from __future__ import annotations

import logging
import os

from entitynet.protocol import codec
from entitynet.server import flushloop, hubpass, logs
from entitynet.switchboard import outbox

_said = False


def in_use() -> dict[str, bool]:
    """Per compiled path, whether it is the one running in this process."""
    return {"route_and_fanout": outbox.compiled_in_use(), "flush_loop": flushloop.compiled_in_use(),
            "frame_decoder": codec.compiled_decoder_in_use(), "read_path": hubpass.compiled_in_use()}


def say_if_pure() -> bool:
    """Log once per process that pure-Python paths are in use (and why), if any are; True if it logged now."""
    global _said
    pure = [name for name, on in in_use().items() if not on]
    if not pure or _said:
        return False
    _said = True
    built = (outbox.COMPILED is not None and flushloop.COMPILED is not None and codec._COMPILED is not None
             and hubpass.COMPILED is not None)
    why = ("ENTITYNET_PURE_PYTHON is set" if os.environ.get("ENTITYNET_PURE_PYTHON") and built
           else "not built (no Cython or C compiler when the package was installed)")
    logs.event("pure-Python paths in use, slower than the compiled ones", logging.WARNING,
               paths=",".join(pure), reason=why)
    return True
