"""One payload decoder shared by all the simulation's viewers.

Why: the server forwards one opaque payload to every viewer subscribed to the entity's cells, so with V viewers
the same bytes arrive up to V times; decoding them (msgpack, validation, a `Path` rebuilt edge by edge) was the
largest single cost of a real-time run (about a third of the tick at 2,000 entities and 200 viewers). Decoded
models are frozen and their paths are never changed in place, so one model can serve every viewer: the cache
maps payload bytes to the model (or to the error an undecodable payload raised, raised again for every viewer
that gets it, so each ghost store still counts it). Bounded: at most `max_entries` payloads (50,000 by
default: about 25 ticks of distinct payloads at 10,000 entities, tens of MB of models and paths), in two
generations of half as many each: when the newer is full the older goes, and a payload found in the older is
moved to the newer. Why not one table cleared when full: the clear dropped every live entity's model at once,
and the next tick decoded all of them again (about 8,000 decodes in one tick at 8,000 entities, a late tick
every 20 s or so); with generations only the payloads not seen for a generation are decoded again.
"""

from __future__ import annotations

from entitynet.client.motion import Model
from entitynet.client.network import NetView
from entitynet.client.payload import PayloadError, decode


class DecodeCache:
    """payload bytes -> decoded model (see the module docstring); `hits` and `misses` count the calls."""

    def __init__(self, net: NetView | None, max_entries: int = 50_000) -> None:
        if max_entries < 1:
            raise ValueError(f"max_entries must be >= 1, got {max_entries}")
        self.net = net
        self.max_entries = max_entries
        self._half = max(max_entries // 2, 1)
        self._two = 2 * self._half <= max_entries  # (room for an older generation: not at max_entries=1)
        self._models: dict[bytes, Model | str] = {}  # this generation
        self._older: dict[bytes, Model | str] = {}  # and the one before
        self.hits = 0
        self.misses = 0

    def __len__(self) -> int:
        return len(self._models) + len(self._older)

    def __call__(self, data: bytes) -> Model:
        """The model `data` encodes, decoded once per distinct payload; raises PayloadError like `decode`."""
        got = self._models.get(data)
        if got is None:
            got = self._older.get(data)
            if got is None:
                self.misses += 1
                try:
                    got = decode(data, self.net)
                except PayloadError as exc:
                    got = str(exc)
            else:
                self.hits += 1
            if len(self._models) >= self._half:  # a new generation: the older one's payloads go
                self._older, self._models = (self._models if self._two else {}), {}
            self._models[bytes(data)] = got
        else:
            self.hits += 1
        if isinstance(got, str):
            raise PayloadError(got)
        return got
