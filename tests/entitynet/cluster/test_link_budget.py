"""The cluster link's latency budget (entitynet/cluster/link.py `_poke`, `_coalesce`): the core's publications
wait up to the server's budget to share one NATS write, but an answer to another shard's request (a QUERY, a
FOLLOW, a snapshot: a client there waits on it) does not.

Why a stub core here: which publications may wait is the shell's decision; the NATS round trip itself is covered
by test_shards.py and test_query_cells.py. The budget is 60 s so that a loaded machine cannot decide the test.
"""

from __future__ import annotations

from types import SimpleNamespace

import trio

from entitynet.cluster.link import ClusterLink


class _Core:
    """What `_on_msg` and `_coalesce` use of ClusterCore: every message it hears makes it publish something."""

    def __init__(self, deadline: float = 1e9):
        self.redirects: list = []
        self.out: list = []
        self.deadline = deadline

    def next_deadline(self) -> float:
        return self.deadline

    def on_message(self, subject, reply, payload, now):
        self.out.append(((reply or "state"), payload, None))


def _link(deadline: float = 1e9) -> ClusterLink:
    server = SimpleNamespace(clock=lambda: 0.0, _note_news=lambda: None)
    link = ClusterLink(server, None)
    link.core = _Core(deadline)
    return link


async def test_an_answer_to_a_request_is_not_held_for_the_budget():
    link = _link()
    link._on_msg("ent.q", "_INBOX.7", b"query")
    with trio.fail_after(10):
        await link._coalesce(60.0)
    assert link.core.out


async def test_a_mirrored_state_still_waits_for_the_budget():
    link = _link()
    link._on_msg("ent.c.3", None, b"state")
    with trio.move_on_after(0.3) as waited:
        await link._coalesce(60.0)
    assert waited.cancelled_caught  # the budget holds it (for up to 60 s): it shares the next write


async def test_a_request_of_ours_is_not_held_for_the_budget():
    """Our own request (a viewer's snapshot, QUERY or FOLLOW waits for its answer) is sent at once too."""
    link = _link()
    link.core.out.append(("ent.snap", b"request", "_INBOX.me"))
    link._poke()
    with trio.fail_after(10):
        await link._coalesce(60.0)


async def test_the_budget_does_not_postpone_the_cores_deadline():
    """Heartbeats and failover decisions are the core's timers (`next_deadline`, 0.2 s away here): coalescing
    ends there, whatever the budget, so that a long budget cannot make the other shards think this one dead."""
    link = _link(deadline=0.2)
    link._on_msg("ent.c.3", None, b"state")
    with trio.fail_after(10):
        await link._coalesce(60.0)
