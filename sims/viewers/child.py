"""A viewer process: forked before the run's event loop, it waits for the server's address, connects its
viewers, then follows the coordinator's ticks until stop (or until the coordinator's socket closes).

Why forked and before trio runs: the child starts with the map and schedule already loaded (copy-on-write), and
a fork taken inside a running trio loop could not start its own. It dies with its parent (PR_SET_PDEATHSIG) and
ignores SIGINT (a terminal's Ctrl-C reaches the whole process group: the coordinator stops the run and then its
viewer processes, in order, with no traceback from any child).
"""

from __future__ import annotations

import signal
import socket
import time

from sims.viewers import wire


def _read_frame(sock: socket.socket, reader: wire.FrameReader) -> dict | None:
    """The next frame from a blocking socket (None when it closes first)."""
    while True:
        got = reader.frames()
        if got:
            return got[0]
        data = sock.recv(65536)
        if not data:
            return None
        reader.feed(data)


def child_main(sock: socket.socket, topo, schedule, config, indices: list[int],
               inherited: list[socket.socket] = ()) -> None:
    """The process's body (see the module docstring): its share's figures go back in a `report` frame.
    `inherited`: the coordinator's socket ends the fork copied into this process, closed first (held here, the
    coordinator's close of its end would never reach this process, or a sibling, as an end of file)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for s in inherited:
        s.close()
    from entitynet.cluster.natsd import die_with_parent

    tie = die_with_parent()
    if tie is not None:
        tie()
    reader = wire.FrameReader()
    try:
        start = _read_frame(sock, reader)
    except (OSError, wire.WireError):
        return
    if start is None or start["t"] != "start":
        return
    import trio

    from sims.viewers.share import ViewerShare

    try:
        share = ViewerShare(topo, schedule, config, indices)
        share.prepare()  # before the coordinator's first tick, which waits for this process's `ready`
        trio.run(_run, sock, reader, share, (start["host"], start["port"]), start["token"])
    except Exception as exc:  # a nursery's task wraps its error in a group: judged by what is inside
        errors = list(_leaves(exc))
        gone = (OSError, wire.WireError, trio.BrokenResourceError, trio.ClosedResourceError)
        if all(isinstance(e, gone) for e in errors):
            return  # the coordinator is gone, or sent what is not a frame: nothing to report to
        import sys

        first = next(e for e in errors if not isinstance(e, gone))
        which = indices[0] if indices else "?"  # a share starts at its process's index (`share_of`)
        # one line, no traceback: the coordinator names this process as gone
        print(f"entitynet sim: viewer process {which}: {type(first).__name__}: {first}", file=sys.stderr)
        sys.exit(1)


def _leaves(exc: BaseException):
    """The errors inside `exc`, exception groups opened (trio's nurseries group their tasks' errors)."""
    if isinstance(exc, BaseExceptionGroup):
        for e in exc.exceptions:
            yield from _leaves(e)
    else:
        yield exc


async def _run(sock: socket.socket, reader: wire.FrameReader, share, address: tuple[str, int], token: str) -> None:
    import trio

    from sims.engine.viewer_fleet import ViewerFleet

    stream = trio.SocketStream(trio.socket.from_stdlib_socket(sock))
    fleet = ViewerFleet(share.viewers, lambda: share.now, share.learn)  # frames into the ghost table whole

    digest = share.sim.topo.digest
    async with trio.open_nursery() as nursery:
        conns = [fleet.connection(i, address, digest, token) for i in range(len(share.viewers))]
        for c in conns:
            await nursery.start(c.run)
        await stream.send_all(wire.encode("ready", viewers=len(conns)))
        while True:
            frames = reader.frames()
            if not frames:
                data = await stream.receive_some(65536)
                if not data:
                    break  # the coordinator is gone
                reader.feed(data)
                continue
            for f in frames:
                if f["t"] == "tick":
                    fleet.clear()
                    subs = share.tick(f["k"], f["pub"], f["unpub"], time.monotonic() - f["sent"])
                    for c, msgs in zip(conns, subs, strict=True):
                        for m in msgs:
                            await c.subscribe(m.added, m.removed)
                elif f["t"] == "stop":
                    share.finish()
                    for frame in wire.report_frames(share.report()):
                        await stream.send_all(frame)
                    nursery.cancel_scope.cancel()
                    return
        nursery.cancel_scope.cancel()
