"""The cluster link's latency budget (entitynet/cluster/link.py `_poke`, `_wait_until`, `_serve_core`): the core's
publications wait up to the server's budget to share one NATS write, but an answer to another shard's request (a
QUERY, a FOLLOW, a snapshot: a client there waits on it) does not; and the loop wakes once per write, not once
for the poke and again for the budget.

Why a stub core here: which publications may wait, and how often the loop runs, is the shell's decision; the
NATS round trip itself is covered by test_shards.py and test_query_cells.py. The budget is 60 s in the first
tests so that a loaded machine cannot decide them; the loop's tests run on trio's autojump clock (virtual time).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import trio
import trio.testing

from entitynet.cluster.link import ClusterLink


class _Core:
    """What `_on_msg`, `_poke` and the loop use of ClusterCore: every message it hears makes it publish
    something; `tick` counts its calls and may queue a publication of its own (as a heartbeat does)."""

    def __init__(self, deadline: float = 1e9):
        self.redirects: list = []
        self.out: list = []
        self.deadline = deadline
        self.ticks: list[float] = []
        self.wake = lambda: None
        self.publish_on_tick = False

    def next_deadline(self) -> float:
        return self.deadline

    def on_message(self, subject, reply, payload, now):
        self.out.append(((reply or "state"), payload, None))

    def tick(self, now):
        self.ticks.append(now)
        if now >= self.deadline:  # as the real core's heartbeat: the next one a period later
            self.deadline = now + 10.0
        if self.publish_on_tick:
            self.out.append(("hb", b"beat", None))
            self.wake()


def _link(deadline: float = 1e9, budget: float = 60.0) -> ClusterLink:
    server = SimpleNamespace(clock=trio.current_time, _note_news=lambda: None,
                             config=SimpleNamespace(latency_budget=budget))
    link = ClusterLink(server, None)
    link.core = _Core(deadline)
    link.core.wake = link._poke
    return link


async def test_an_answer_to_a_request_is_not_held_for_the_budget():
    link = _link()
    link._on_msg("ent.q", "_INBOX.7", b"query")
    assert link.core.out and link._wait_until() <= trio.current_time()


async def test_a_mirrored_state_still_waits_for_the_budget():
    link = _link()
    t = trio.current_time()
    link._on_msg("ent.c.3", None, b"state")
    assert link._due == pytest.approx(t + 60.0, abs=1.0)  # it shares the write a budget after the first poke
    link._poke()  # later pokes do not postpone it
    assert link._due == pytest.approx(t + 60.0, abs=1.0)


async def test_a_request_of_ours_is_not_held_for_the_budget():
    """Our own request (a viewer's snapshot, QUERY or FOLLOW waits for its answer) is sent at once too."""
    link = _link()
    link._poke()
    link.core.out.append(("ent.snap", b"request", "_INBOX.me"))
    link._poke()
    assert link._wait_until() <= trio.current_time()


async def test_the_budget_does_not_postpone_the_cores_deadline():
    """Heartbeats and failover decisions are the core's timers (`next_deadline`, 0.2 s away here): the wait ends
    there, whatever the budget, so that a long budget cannot make the other shards think this one dead."""
    link = _link(deadline=trio.current_time() + 0.2)
    link._on_msg("ent.c.3", None, b"state")
    assert link._wait_until() <= trio.current_time() + 0.2 + 1e-9


async def _run_loop(link: ClusterLink, pumps: list, body) -> None:
    link._pump = lambda: (pumps.append(trio.current_time()), link.core.out.clear())
    async with trio.open_nursery() as n:
        n.start_soon(link._serve_core)
        await body()
        n.cancel_scope.cancel()


async def test_pokes_within_a_budget_cost_one_pass_of_the_loop(autojump_clock: trio.testing.MockClock):
    link = _link(budget=0.02)
    pumps: list[float] = []

    async def body():
        t0 = trio.current_time()
        for dt in (0.0, 0.005, 0.01, 0.015):
            await trio.sleep_until(t0 + dt)
            link.core.out.append(("state", b"x", None))
            link._poke()
        await trio.sleep_until(t0 + 0.5)
        assert pumps == [pytest.approx(t0 + 0.02)]  # one pass, a budget after the first poke
        assert len(link.core.ticks) == 1 and link._due == math.inf
        link.core.out.append(("snap", b"req", "_INBOX.me"))  # a request of ours: at once
        link._poke()
        await trio.sleep(0.001)
        assert pumps[1:] == [pytest.approx(t0 + 0.5)]

    await _run_loop(link, pumps, body)


async def test_what_the_tick_queues_goes_out_in_the_same_pass(autojump_clock: trio.testing.MockClock):
    """A heartbeat is queued by the tick itself: the pump right after it hands it over, and the loop then sleeps
    to the next deadline instead of waking again for the heartbeat's own poke and its budget."""
    link = _link(budget=0.02)
    link.core.publish_on_tick = True
    pumps: list[float] = []
    t0 = trio.current_time()
    link.core.deadline = t0 + 0.25

    async def body():
        await trio.sleep_until(t0 + 0.3)
        assert len(link.core.ticks) == 1 and pumps == [pytest.approx(t0 + 0.25)]
        assert link._due == math.inf  # nothing left due: the heartbeat's poke was served by that pass
        await trio.sleep_until(t0 + 5.0)
        assert len(link.core.ticks) == 1  # and no pass since, until the next deadline (t0 + 10.25)

    await _run_loop(link, pumps, body)


async def test_a_poke_with_the_budget_off_is_pumped_at_once(autojump_clock: trio.testing.MockClock):
    link = _link(budget=0.0)
    pumps: list[float] = []

    async def body():
        t0 = trio.current_time()
        link.core.out.append(("state", b"x", None))
        link._poke()
        await trio.sleep(0.001)
        assert pumps == [pytest.approx(t0)]

    await _run_loop(link, pumps, body)
