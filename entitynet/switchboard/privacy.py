"""The buddy rule of the reference (section 4.7), in one place.

Everyone is anonymous by default and entity ids are opaque per session. A client may publish an identity
for an audience (everyone, or a set of user ids: its buddies). A viewer is shown that identity only if it
is in the audience *and* has published an identity itself: who does not show, does not see.
"""

from __future__ import annotations

from typing import Protocol


class Party(Protocol):
    user_id: str
    identity: str | None
    audience: frozenset[str] | None


def identity_shown(owner: Party, viewer: Party) -> str | None:
    """The identity of `owner`'s entities as `viewer` may see it (None = anonymous)."""
    if owner.identity is None or viewer.identity is None:
        return None
    if owner.audience is not None and viewer.user_id not in owner.audience and viewer is not owner:
        return None
    return owner.identity
