"""Scheduled full garbage collections (entitynet/server/gcpolicy.py, `entitynet serve --gc-full-every`).

Why: Python runs a full collection whenever the long-lived heap has grown by a quarter; a loaded server's heap
has millions of references, so each one stopped the server for 0.15-0.2 s in the middle of the traffic
(measured at the switch bench's 10,000-entity step). With the policy the server's start-up state is frozen out
of collection, automatic full collections are off and the server runs them on a schedule, reporting each pause.
These tests check the collector's settings, that the scheduled pass really collects cyclic garbage, that the
process's collector is given back afterwards, and that the option refuses nonsense.
"""

from __future__ import annotations

import gc
import math
import weakref

import pytest
import trio

from entitynet.cli import build_parser
from entitynet.server.gcpolicy import NEVER, FullCollections
from tests.entitynet.server_helpers import running


class _Node:
    def __init__(self):
        self.me = self  # a reference cycle: only the cyclic collector frees it


@pytest.fixture
def collector_state():
    """Leave the process's collector as the test found it, whatever the test does."""
    saved = gc.get_threshold()
    yield
    gc.set_threshold(*saved)
    gc.unfreeze()


def test_start_freezes_start_up_state_and_turns_automatic_full_collections_off(collector_state):
    before = gc.get_threshold()
    policy = FullCollections(60.0)
    policy.start()
    assert gc.get_threshold() == (before[0], before[1], NEVER)  # young collections untouched
    assert gc.get_freeze_count() > 0
    policy.restore()
    assert gc.get_threshold() == before
    assert gc.get_freeze_count() == 0


def test_a_scheduled_pass_frees_cyclic_garbage_and_reports_its_pause(collector_state):
    seen: list[float] = []
    policy = FullCollections(60.0, seen.append)
    policy.start()
    gc.disable()  # no young collection may free it first: only the scheduled pass
    try:
        node = _Node()
        ref = weakref.ref(node)
        del node
        assert ref() is not None  # a cycle: reference counting alone does not free it
        pause = policy.collect()
    finally:
        gc.enable()
        policy.restore()
    assert ref() is None
    assert seen == [pause] and policy.pauses == [pause] and pause >= 0.0


@pytest.mark.parametrize("every", [0.0, -1.0, math.nan])
def test_an_interval_that_is_not_positive_is_refused(every):
    with pytest.raises(ValueError, match="interval"):
        FullCollections(every)


async def test_a_server_with_the_policy_collects_on_schedule_and_gives_the_collector_back(collector_state):
    before = gc.get_threshold()
    async with running(gc_full_every=0.05) as server:
        assert gc.get_threshold()[2] == NEVER
        with trio.fail_after(30):  # a full pass of a big test process may itself take a while
            while len(server.gc.pauses) < 2:
                await trio.sleep(0.02)
        hist = server.metrics.gc_pause.collect()[0].samples
        assert next(s.value for s in hist if s.name.endswith("_count")) >= len(server.gc.pauses)  # on /metrics
    assert gc.get_threshold() == before
    assert gc.get_freeze_count() == 0


async def test_a_server_without_the_policy_leaves_the_collector_alone(collector_state):
    before = gc.get_threshold()
    async with running() as server:
        assert server.gc is None
        assert gc.get_threshold() == before


def test_serve_takes_the_option_and_refuses_nonsense():
    parser = build_parser()
    assert parser.parse_args(["serve", "--topology", "x.enttopo"]).gc_full_every == 300.0
    for bad in ("-1", "nan", "1e-9"):  # refused while parsing (entitynet/commands/options.py)
        with pytest.raises(SystemExit):
            parser.parse_args(["serve", "--topology", "x.enttopo", f"--gc-full-every={bad}", "--open"])
