"""Where the compiled paths are missing (no C compiler at install time) or switched off, the server runs the
pure-Python ones and says so once per process, with the reason; where they are in use it says nothing."""

from __future__ import annotations

import logging
import subprocess
import sys
import textwrap

from entitynet.server import compiled
from entitynet.switchboard import outbox


def test_the_notice_comes_once_and_only_for_pure_paths(caplog, monkeypatch):
    caplog.set_level(logging.INFO, logger="entitynet.server")
    monkeypatch.setattr(compiled, "_said", False)
    was = outbox.compiled_in_use()
    try:
        outbox.use_compiled(False)
        assert compiled.in_use()["route_and_fanout"] is False
        assert compiled.say_if_pure() is True
        assert compiled.say_if_pure() is False  # once per process
        notices = [r for r in caplog.records if "pure-Python paths in use" in r.getMessage()]
        assert len(notices) == 1 and notices[0].levelno == logging.WARNING
        assert "route_and_fanout" in notices[0].getMessage() and "reason=" in notices[0].getMessage()
    finally:
        outbox.use_compiled(was)
    monkeypatch.setattr(compiled, "_said", False)
    caplog.clear()
    if all(compiled.in_use().values()):  # built and in use (the usual install): nothing to say
        assert compiled.say_if_pure() is False
        assert "pure-Python" not in caplog.text


# A fresh interpreter in which the compiled modules cannot be imported, as after an install without a compiler:
# two servers started one after the other log the notice once, and forward as usual.
_NO_COMPILER = textwrap.dedent("""
    import logging, sys
    sys.modules["entitynet.switchboard._fanout"] = None  # import fails: as if never built
    sys.modules["entitynet.server._flushloop"] = None
    sys.modules["entitynet.protocol._decode"] = None
    import trio
    from entitynet.server.app import serve
    from entitynet.server.config import ServerConfig
    from entitynet.switchboard import outbox
    from entitynet.server import flushloop
    logging.basicConfig(level=logging.INFO, stream=sys.stdout, format="%(message)s")
    assert outbox.COMPILED is None and flushloop.COMPILED is None

    async def main():
        for _ in range(2):
            async with trio.open_nursery() as nursery:
                server = await nursery.start(serve, ServerConfig(port=0, digest="d", n_cells=10, open_mode=True,
                                                                 raise_nofile=False))
                await server.stop()
                nursery.cancel_scope.cancel()

    trio.run(main)
""")


def test_without_the_compiled_modules_the_server_runs_and_says_so_once():
    out = subprocess.run([sys.executable, "-c", _NO_COMPILER], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.count("pure-Python paths in use") == 1, out.stdout
    assert "not built" in out.stdout and "route_and_fanout,flush_loop,frame_decoder" in out.stdout
    assert out.stdout.count("listening") == 2 and "Traceback" not in out.stdout + out.stderr
