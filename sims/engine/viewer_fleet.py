"""The simulation's viewer connections as one fleet: frames read from each viewer's socket go to the shared
ghost table whole, not message by message.

Why: with the server fanning each UPDATE out to every viewer of its cells, the viewers' side of a large run was
about 14-15 us of CPU per delivery over sockets, most of it per message: the session's action per message, the
callback chain, a `Ghost` object per viewer per message (docs/simulation.md, "The coordinator's part"). Here a
frame's payload is split by msgpack's C unpacker and its messages looked up in the shared decoder
(`message_cache.MessageCache`: each distinct message decoded once, by the codec), and a frame of only UPDATEs
and LEAVEs on an open link, the usual frame, goes whole to the viewer's column of the ghost table
(`entitynet.client.ghost_table`, the ghost rules' one home) with no per-message call in between
(`Connection(on_frame=...)`: the session says when that is exactly what it would do, `delivers_whole`).

How the bytes arrive: by default all the viewers' TCP sockets are read by one task
(`sims.engine.viewer_reader.ViewerReader`: one epoll set, each ready socket read once per pass, a read's run of
whole frames handed on as one), each viewer keeping its own sans-IO `ClientSession`, so the handshake (HELLO /
WELCOME, digest check), the SUBSCRIBE differences, the PING / PONG clock offset, reconnects with backoff and the
replay of the subscription, REDIRECT and ERROR go through the session as for any client; only the UPDATE /
LEAVE frames of an open link skip the per-message actions. `one_reader=False` (and a ws:// address) gives each
viewer an `entitynet.connection.Connection` of its own instead: the reference path, the same session. What a
simulated viewer skips that the browser-less Python viewer does: nothing of the rules (the same table), but the
simulated viewers share one clock with the publishers, so their ghosts use clock offset 0, not the PONG
estimate. An external server's ids are learnt once per distinct UPDATE (the decoder's `on_new`).
Sans-IO apart from building the connections; `now()` is the simulation's receiver time.
"""

from __future__ import annotations

import select
from collections.abc import Callable

from entitynet import protocol as P
from entitynet.connection import Connection
from sims.engine.message_cache import MessageCache
from sims.engine.viewer_reader import ReaderViewer, ViewerReader
from sims.engine.viewers import SimViewer


class ViewerFleet:
    """Many viewers' connections and what arrives on them (see the module docstring). `learn(update)` is told
    of every UPDATE that arrives (an external server's ids mapped back to the truth), None for none."""

    def __init__(self, viewers: list[SimViewer], now: Callable[[], float],
                 learn: Callable[[P.Update], None] | None = None, one_reader: bool | None = None) -> None:
        """`one_reader`: the viewers' TCP sockets read by one task (`viewer_reader.ViewerReader`, the default
        where the system has epoll: Linux); False: a `Connection` and its tasks per viewer (the reference)."""
        if one_reader is None:
            one_reader = hasattr(select, "epoll")
        self.viewers = viewers
        self.now = now
        self.learn = learn
        # one frame decoder for all the connections, cleared each tick; it maps the ids of each distinct UPDATE
        self.messages = MessageCache(on_new=None if learn is None else self._learn_new)
        self._sizes: dict[P.Message, int] = {}
        self.redirects = 0  # REDIRECTs the viewers followed (a cluster)
        self.frames_whole = 0  # frames handed to the ghost table whole (the rest went message by message)
        self.reader = ViewerReader(self.messages.decode, self.on_frame, self.on_message) if one_reader else None

    def _learn_new(self, m: P.Message) -> None:
        if type(m) is P.Update:
            self.learn(m)

    def clear(self) -> None:
        """Forget the tick's decoded messages (a message is shared within a tick's fan-out)."""
        self.messages.clear()
        self._sizes.clear()

    def error_report(self) -> dict:
        """The viewers' connection errors (`ViewerReader.error_report`) for the run's report; with a
        `Connection` per viewer (`one_reader=False`) they are not gathered, and the report says so."""
        if self.reader is None:
            return {"errors": None, "why": "a Connection per viewer: errors not gathered (only the one reader's)"}
        return self.reader.error_report()

    def size(self, m: P.Update | P.Leave) -> int:
        """The encoded size of a message that arrived: its bytes' length in the frame when the shared decoder
        returned it, else encoded once per tick (equal messages encode alike)."""
        size = self.messages.size(m)
        if size is None:
            size = self._sizes.get(m)
            if size is None:
                size = self._sizes[m] = len(P.encode_message(m))
        return size

    def connection(self, i: int, address, digest: str, token: str, **kw) -> Connection | ReaderViewer:
        """Viewer `i`'s connection, its frames decoded by the shared decoder and handed to this fleet: a handle of
        the one reader (viewers connected in index order), or a `Connection` of its own (the reference path, and
        any ws:// address)."""
        if self.reader is not None and not isinstance(address, str):
            if i != len(self.reader.viewers):
                raise ValueError(f"the one reader's viewers connect in order: {len(self.reader.viewers)} next, "
                                 f"not {i}")
            return self.reader.viewer(address, digest, token, **kw)
        return Connection(address, digest, token, on_message=self.on_message(i), on_frame=self.on_frame(i),
                          decode=self.messages.decode, **kw)

    def on_frame(self, i: int) -> Callable[[list[P.Message]], None]:
        """Viewer `i`'s whole frames of UPDATEs and LEAVEs: counted, learnt, and into the ghost table."""
        viewer, size, learn = self.viewers[i], self.size, self.learn

        def on_frame(msgs: list[P.Message]) -> None:
            self.frames_whole += 1
            nbytes = getattr(msgs, "nbytes", None)  # the shared decoder's `Frame`: its size at once
            if learn is not None and nbytes is None:  # not the decoder's walk: its messages not learnt yet
                for m in msgs:
                    if type(m) is P.Update:
                        learn(m)
            # the codec decoded them and the session found them all UPDATEs and LEAVEs: `decoded`
            viewer.receive_frame(msgs, self.now(), sum(map(size, msgs)) if nbytes is None else nbytes, True)

        return on_frame

    def on_message(self, i: int) -> Callable[[P.Message], None]:
        """Viewer `i`'s messages one by one (WELCOME, REDIRECT, ERROR, and a frame that was not all UPDATEs and
        LEAVEs on an open link): as `SimViewer.receive` takes them."""
        viewer, learn = self.viewers[i], self.learn

        def on_message(m: P.Message) -> None:
            if isinstance(m, P.Redirect):
                self.redirects += 1
            elif type(m) is P.Update and learn is not None:
                learn(m)
            viewer.receive(m, self.now(), self.size(m) if isinstance(m, P.Update | P.Leave) else 0)

        return on_message
