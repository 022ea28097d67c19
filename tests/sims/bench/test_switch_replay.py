"""The switch workload replayed through the core gives the same deliveries, frames and LEAVEs as before.

The pinned digest was recorded on the code before the mobility model was unified (issue 10 item 6): a change
to the movers' RNG draws, the core's forwarding or the frame grouping changes it. A deliberate behaviour change
must update the pin and say why in its commit.
"""

from __future__ import annotations

from sims.bench.switch_replay import replay

SMALL = {"entities": 300, "viewers": 40, "seconds": 6.0}
PINNED = {
    "digest": "e0c7a81e5846722917c7556c313a42dc6c7742c585dad27d0022f7349623ab3f",
    "updates_in": 885,
    "deliveries": 14435,
    "leaves": 97,
    "frames": 6874,
}


def test_replay_digest_is_pinned(helsinki, fanout_path):
    res = replay(helsinki, **SMALL)
    got = {k: getattr(res, k) for k in PINNED}
    assert got == PINNED


def test_replay_is_deterministic_and_sensitive_to_the_workload(helsinki):
    a = replay(helsinki, entities=120, viewers=20, seconds=3.0)
    b = replay(helsinki, entities=120, viewers=20, seconds=3.0)
    assert a == b  # the timing (core_s) differs from run to run and is left out of the comparison
    assert a.deliveries > 0 and a.leaves > 0 and a.frames > 0
    assert a.core_s > 0 and a.core_us_per_delivery == a.core_s * 1e6 / a.deliveries
    other = replay(helsinki, entities=120, viewers=20, seconds=3.0, seed=8)
    assert other.digest != a.digest


def test_the_socket_path_delivers_exactly_the_pinned_frames(helsinki, flush_path):
    """Flushed through the server's flush loop (pure and compiled) onto loopback TCP, the peers receive the very
    frames the pin describes: one per client with news per flush, every message's bytes and order intact."""
    res = replay(helsinki, **SMALL, sockets=True)
    got = {k: getattr(res, k) for k in PINNED}
    assert got == PINNED
    assert res.flush_s > 0 and res.flush_us_per_frame == res.flush_s * 1e6 / res.frames


def test_held_small_frames_deliver_the_same_states_in_fewer_frames(helsinki, flush_path):
    """`hold_below` (the server's `--flush-min-frame`): every state still arrives (the same deliveries and
    LEAVEs as the pin), in fewer frames, and the states that waited a flush are counted; both loops alike."""
    res = replay(helsinki, **SMALL, sockets=True, hold_below=3)
    assert (res.deliveries, res.leaves) == (PINNED["deliveries"], PINNED["leaves"])
    assert res.frames < PINNED["frames"] and 0 < res.held_states < res.deliveries
    assert res.digest != PINNED["digest"]  # frames moved to later flushes
