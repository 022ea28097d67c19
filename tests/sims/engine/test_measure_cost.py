"""The real-time loop's viewer-side savings change no figure (issue 11, more entities in real time): the shared
payload decoder, the measure's per-sample extrapolation memo, and the measured share of viewers."""

from __future__ import annotations

import msgpack
import pytest

from entitynet import protocol as P
from entitynet.client.payload import PayloadError, decode
from sims.engine.decode_cache import DecodeCache
from sims.engine.local import run_local
from sims.engine.sim import Sim, SimConfig
from tests.sims.engine.test_routes import grid


def small(**kw) -> SimConfig:
    base = dict(entities=16, viewers=6, connections=2, tick_hz=2.0, subscribe="radius", radius=400.0,
                transit=False, start=0.0, seed=5)
    base.update(kw)
    return SimConfig(**base)


def _own_decoders(sim: Sim) -> None:
    """Each viewer a ghost store of its own (a table of one column) decoding its own payloads, as before the
    savings: no shared table, decoder or extrapolation."""
    from entitynet.client import GhostStore

    for v in sim.viewers:
        v.ghosts = GhostStore(sim.world.net)


def test_the_shared_decoder_and_the_memo_give_the_same_report():
    fast = Sim(grid(), small())
    rep = run_local(fast, 30.0)
    slow = Sim(grid(), small())
    _own_decoders(slow)
    want = run_local(slow, 30.0)
    assert rep["truth_vs_viewer"]["all"]["visible_entity_samples"] > 50
    assert rep == want
    # one payload reached several viewers and was decoded once (one version of the message in the ghost table)
    calls = fast.decode_cache.hits + fast.decode_cache.misses
    assert sum(v.deliveries for v in fast.viewers) > calls >= fast.decode_cache.misses == len(fast.decode_cache) > 0


def test_the_cache_returns_what_decode_returns_and_refuses_bad_payloads_every_time():
    sim = Sim(grid(), small())
    from sims.engine.local import LocalSwitch

    sw = LocalSwitch(sim)
    got: list[bytes] = []
    real = sim.deliver
    sim.deliver = lambda i, m, size=0: (got.append(m.payload) if isinstance(m, P.Update) else None, real(i, m, size))
    sw.exchange(*sim.start())
    for _ in range(6):
        sw.exchange(*sim.step())
    assert got
    cache = DecodeCache(sim.world.net)
    for data in got:
        assert cache(data) == decode(data, sim.world.net)
        assert cache(data) is cache(data)  # shared, not copied
    bad = msgpack.packb([99, 1])
    for _ in range(2):
        with pytest.raises(PayloadError):
            cache(bad)
    v = sim.viewers[0]
    v.ghosts._decode = cache
    before = v.ghosts.bad_payloads
    for seq in (1, 2):
        v.ghosts.receive(P.Update(424242, seq, (0,), 5000, bad), sim.now)
    assert v.ghosts.bad_payloads == before + 2 and 424242 not in v.ghosts.ghosts


def test_the_cache_is_bounded():
    sim = Sim(grid(), small())
    cache = DecodeCache(sim.world.net, max_entries=2)
    for k in range(5):
        with pytest.raises(PayloadError):
            cache(msgpack.packb([99, k]))
        assert len(cache) <= 2
    one = DecodeCache(sim.world.net, max_entries=1)
    for k in range(3):
        with pytest.raises(PayloadError):
            one(msgpack.packb([99, k]))
        assert len(one) == 1
    with pytest.raises(ValueError):
        DecodeCache(None, max_entries=0)


def test_the_cache_keeps_two_generations_so_a_full_table_is_not_decoded_again_at_once():
    sim = Sim(grid(), small())
    cache = DecodeCache(sim.world.net, max_entries=4)
    pay = [msgpack.packb([99, k]) for k in range(5)]

    def ask(k: int) -> None:
        with pytest.raises(PayloadError):
            cache(pay[k])

    for k in (0, 1, 2):  # the third starts a generation: 0 and 1 are the older one
        ask(k)
    assert cache.misses == 3 and len(cache) == 3
    ask(0)  # found in the older generation (not decoded again) and moved to the newer
    assert cache.misses == 3 and cache.hits == 1
    ask(3)  # another generation: 2 and 0 the older, 1 gone
    ask(0)
    assert cache.misses == 4
    ask(1)
    assert cache.misses == 5 and len(cache) <= 4


def test_a_measure_share_takes_the_viewers_in_turn():
    sim = Sim(grid(), small(viewers=8, measure_share=0.25))
    seen = [[v.index for v in sim.measured_viewers()] for _ in range(4)]
    assert seen == [[0, 1], [2, 3], [4, 5], [6, 7]]
    assert [v.index for v in sim.measured_viewers()] == [0, 1]
    odd = Sim(grid(), small(viewers=5, measure_share=0.5))
    assert [[v.index for v in odd.measured_viewers()] for _ in range(2)] == [[0, 1, 2], [3, 4, 0]]
    full = Sim(grid(), small(viewers=8))
    assert full.measured_viewers() == full.viewers


def test_a_measure_share_samples_that_share_of_viewer_time():
    full_sim = Sim(grid(), small(viewers=8))
    full = run_local(full_sim, 20.0)
    part_sim = Sim(grid(), small(viewers=8, measure_share=0.25))
    part = run_local(part_sim, 20.0)
    samples = sum(t.viewer_samples for t in full_sim.measure.tallies.values()) // 8
    assert samples >= 15
    assert sum(t.viewer_samples for t in part_sim.measure.tallies.values()) == 2 * samples
    # the traffic is untouched: the share only thins the measure
    assert part["viewers"] == full["viewers"] and part["clients"] == full["clients"]
    assert part["truth_vs_viewer"]["all"]["visible_entity_samples"] > 0


@pytest.mark.parametrize("share", [0.0, -0.1, 1.5])
def test_a_bad_measure_share_is_refused(share):
    with pytest.raises(ValueError, match="measure share"):
        small(measure_share=share)


def _pvs_like(size: float = 60.0):
    """A lookup that, like the PVS index, answers every camera in one square with the same cached array."""
    import numpy as np

    topo = grid()
    b = topo.cell_footprints.bounds()
    cx, cy = (b[:, 0] + b[:, 2]) / 2.0, (b[:, 1] + b[:, 3]) / 2.0
    cache: dict = {}

    def cells_at(x: float, y: float, z: float):
        key = (int(x // size), int(y // size))
        if key not in cache:
            cache[key] = np.flatnonzero(np.hypot(cx - x, cy - y) < 250.0)
        return cache[key]

    return topo, cells_at


def test_a_camera_in_the_same_view_cell_skips_its_lookup_and_nothing_changes():
    topo, cells_at = _pvs_like()
    fast = Sim(topo, small(), cells_at=cells_at)
    rep = run_local(fast, 30.0)
    topo2, cached = _pvs_like()
    slow = Sim(topo2, small(), cells_at=lambda x, y, z: cached(x, y, z).copy())  # a new array every time
    want = run_local(slow, 30.0)
    assert rep == want
    assert sum(v.lookups_skipped for v in fast.viewers) > 30
    assert sum(v.lookups_skipped for v in slow.viewers) == 0
    assert rep["truth_vs_viewer"]["all"]["visible_entity_samples"] > 50


def test_a_welcome_makes_the_next_move_resubscribe_under_its_limits():
    topo, cells_at = _pvs_like()
    sim = Sim(topo, small(viewers=1), cells_at=cells_at)
    v = sim.viewers[0]
    v.move(0.0)
    assert len(v.subs.cells) > 3
    assert v.move(0.0) == []  # same place: skipped
    w = P.Welcome(P.PROTOCOL_VERSION, 1, 0, {"max_subscriptions": 3})
    v.receive(w, sim.now)
    msgs = v.move(0.0)
    assert len(v.subs.cells) == 3 and msgs and msgs[0].removed
