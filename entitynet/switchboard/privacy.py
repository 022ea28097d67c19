"""The buddy rule of the reference (section 4.7), in one place.

Everyone is anonymous by default and entity ids are opaque per session. A client may publish an identity
for an audience (nil = everyone, or a set of user ids: its buddies; an empty set = nobody).

Who sees whose identity (reciprocity: who does not show, does not see): a viewer is shown the identity of
an owner's entities only if
  1. the owner publishes an identity and the viewer is in the owner's audience, and
  2. the viewer publishes an identity too and the owner is in the viewer's audience.
So a client with an empty audience, or none, sees nobody's identity, and nobody sees its own; a client always
sees its own. Queries by identity follow the same rule. A change of privacy takes effect with the next
UPDATE a viewer receives (entities already on its screen keep what they showed until then).

Whose identity a client may claim: with auth tokens, only its own user id (or none), so that "alice" on a
buddy's screen really is the holder of alice's token; a claim of another name is refused with NOT_OWNER and
the previous privacy stays. In open mode (`serve --open`) the token is the user id and nothing is verified:
anyone may claim any identity.
"""

from __future__ import annotations

from typing import Protocol


class Party(Protocol):
    """What the privacy rules need of a client (the core's ClientState has it): a structural type, so that the
    rules can be tested without a switchboard."""

    user_id: str
    identity: str | None
    audience: frozenset[str] | None


def _admits(shower: Party, watcher: Party) -> bool:
    audience = shower.audience
    return audience is None or watcher.user_id in audience


def identity_shown(owner: Party, viewer: Party) -> str | None:
    """The identity of `owner`'s entities as `viewer` may see it (None = anonymous)."""
    if viewer is owner:
        return owner.identity
    if owner.identity is None or viewer.identity is None:
        return None
    if not _admits(owner, viewer) or not _admits(viewer, owner):
        return None
    return owner.identity


def claim_refused(user_id: str, identity: str | None, open_mode: bool) -> str | None:
    """Why a client authenticated as `user_id` may not publish `identity` (None: it may)."""
    if open_mode or identity is None or identity == user_id:
        return None
    return f"identity {identity!r} is not yours: publish your user id {user_id!r} or none"
