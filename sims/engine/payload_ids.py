"""A server's opaque entity ids mapped back to the simulation's, from the payloads (truth against viewers).

Why: the switchboard gives each entity an opaque id per session (entitynet/switchboard/privacy.py) and tells
the publisher nothing of it; in-process the shell reads the switchboard's table, but a server in another
process (the sim's child server, `--server`, a cluster) keeps it to itself. Every UPDATE a viewer gets carries
the payload (the dead-reckoning model) its publisher sent unchanged, so the latest payloads our publishers sent
name the entity: the first UPDATE of an unknown id whose payload is one of them maps that id. An UPDATE that
arrives after its entity published twice more is not mapped (its next one is); two entities with the same
payload (same place, velocity and time to the millisecond) would share the first one's mapping.

Bounded: two payloads per live entity, and the ids learnt for it, all dropped when the entity is unpublished.
"""

from __future__ import annotations

from collections.abc import Iterable

from entitynet import protocol as P


class PayloadIds:
    """Server entity id -> simulated entity (`local_of`), learnt from the payloads our publishers sent."""

    def __init__(self) -> None:
        self.local_of: dict[int, int] = {}  # server entity id -> the simulation's entity id
        self._owner: dict[bytes, int] = {}  # a payload sent lately -> its entity
        self._sent: dict[int, tuple[bytes, ...]] = {}  # entity -> its last two payloads (newest last)
        self._ids: dict[int, list[int]] = {}  # entity -> the server ids learnt for it

    def published(self, msgs: Iterable[P.Publish]) -> None:
        """Our publishers sent these PUBLISHes: their payloads now name their entities."""
        owner, sent = self._owner, self._sent
        for m in msgs:
            last = sent.get(m.entity, ())
            if len(last) == 2 and owner.get(last[0]) == m.entity:
                del owner[last[0]]  # the older of the two goes
            sent[m.entity] = (last[-1], m.payload) if last else (m.payload,)
            owner[m.payload] = m.entity

    def learn(self, eid: int, payload: bytes) -> None:
        """An UPDATE of server id `eid` arrived with `payload`: map the id if the payload is one of ours."""
        local = self._owner.get(payload)
        if local is not None and eid not in self.local_of:
            self.local_of[eid] = local
            self._ids.setdefault(local, []).append(eid)

    def forget(self, entity: int) -> None:
        """The entity was unpublished: its payloads and ids go (the server drops it too)."""
        for payload in self._sent.pop(entity, ()):
            if self._owner.get(payload) == entity:
                del self._owner[payload]
        for eid in self._ids.pop(entity, ()):
            self.local_of.pop(eid, None)
