"""The network model's compiled publish fields (`entitynet/client/_fields.pyx`, issue 22) against the pure
`Player._network_fields`, its reference: the same fields bit for bit (the path by its edges and cumulative
lengths; -0.0 is not 0.0 here, NaN equals NaN), or the same error, after every fix of walkers, cyclists, cars, buses
and trams (with a route and a stop) over synthetic maps, from the filter and from the ghost (moving on, and
standing at a gap's time); and with an injected estimate's hostile speeds and accelerations (NaN, infinities,
-0.0, huge, negative, ints)."""

import math
import random
import struct

import pytest

from entitynet.client import player as player_module
from entitynet.client.modes import EDGE
from entitynet.client.player import Player
from entitynet.client.rules import OwnEstimate
from tests.entitynet.client.test_cover_compiled import HOSTILE, TOPOS, _walk

compiled = player_module._FIELDS
needs_compiled = pytest.mark.skipif(compiled is None, reason="the compiled fields are not built here")
REFERENCE = Player._network_fields


def _val(x):
    if isinstance(x, float):
        return "nan" if x != x else struct.pack("=d", x)
    if hasattr(x, "cum"):  # a Path
        return tuple(x.edges), tuple(_val(c) for c in x.cum)
    if isinstance(x, tuple):
        return tuple(_val(v) for v in x)
    return x


def _both(p, t, from_ghost, stop_at):
    out = []
    for fn in (lambda: REFERENCE(p, t, from_ghost, stop_at),
               lambda: compiled.network_fields(p, t, from_ghost, stop_at, REFERENCE)):
        try:
            out.append(_val(fn()))
        except (ArithmeticError, ValueError, IndexError, TypeError) as exc:
            out.append(type(exc).__name__)
    return out


@needs_compiled
@pytest.mark.parametrize("topo", TOPOS)
def test_the_compiled_fields_are_the_references(topo):
    rng = random.Random(23)
    seen = 0
    for etype, kw in (("pedestrian", {}), ("cyclist", {}), ("car", {}), ("bus", {"route": True}),
                      ("tram", {"route": True})):
        for _ in range(3):
            for p in _walk(topo, etype, rng, **kw):
                if p.tracker.place is not EDGE or p.ghost is None:
                    continue
                t = p.last_t
                for from_ghost, stop_at in ((False, None), (True, None), (True, t + 0.5)):
                    ref, out = _both(p, t + 1.0, from_ghost, stop_at)
                    assert out == ref
                    seen += 1
    assert seen > 100


class _Injected(OwnEstimate):
    """An estimate whose (v, a) the test sets."""

    motion_va = (0.0, 0.0)

    def motion(self, player, t):
        return self.motion_va


@needs_compiled
@pytest.mark.parametrize("etype", ["pedestrian", "car", "bus"])
def test_the_compiled_fields_are_the_reference_on_hostile_motion(etype):
    est = _Injected()
    rng = random.Random(5)
    p = Player(TOPOS[4], 1, etype, estimate=est)
    path = None
    n = 0
    for k in range(12):  # placed and tracked along the first way
        if path is None and p.tracker.path is not None:
            path = p.tracker.path
        x, y = (10.0 + 1.2 * k, 0.0) if path is None else path.xy(10.0 + 1.2 * k)
        p.feed(x, y, float(k))
        if p.tracker.place is not EDGE:
            continue
        for v in HOSTILE + [3, 0, -2]:
            for a in (0.0, -0.0, rng.choice(HOSTILE), 1, math.nan):
                est.motion_va = (v, a)
                for reposition in (False, True):
                    p.rules.reposition = reposition
                    ref, out = _both(p, k + 0.5, False, None)
                    assert out == ref, (v, a, reposition)
                    n += 1
        p.rules.reposition = False
    assert n > 500
