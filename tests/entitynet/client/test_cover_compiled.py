"""The network model's compiled publish cover (`entitynet/client/_cover.pyx`, issue 22) against the pure
`Coverage.occupation`, its reference: the same Occupation, field for field and bit for bit (-0.0 is not 0.0 here,
NaN equals NaN), or the same error, for every publish of walkers, cyclists, cars and buses (with and without a
route and stops) walked over synthetic maps with parallel ways, junctions, a hairpin, short edges and an area;
and on ghosts with hostile fields (NaN, infinities, -0.0, huge and negative values, a one-edge path), with the
usual, a zero, a held and an oversized lateral cover."""

import math
import random
import struct

import pytest

from entitynet.client import coverage
from entitynet.client.modes import EDGE
from entitynet.client.motion import network_model
from entitynet.client.path import Path, follow
from entitynet.client.player import Player
from tests.entitynet.client_fixtures import ALL, area_square, chain, cross, hairpin, parallel, tee

compiled = coverage._COMPILED
needs_compiled = pytest.mark.skipif(compiled is None, reason="the compiled cover is not built here")


def _bits(occ):
    """An Occupation (or an error) as comparable values: floats by bit pattern, NaN as one value."""
    if isinstance(occ, BaseException):
        return type(occ).__name__
    if occ is None:
        return None
    return tuple("nan" if isinstance(v, float) and v != v else struct.pack("=d", v) if isinstance(v, float) else v
                 for v in (occ.cells, occ.validity, occ.front_period, occ.aft_period, occ.cover_start, occ.cover_end))


def _both(cov, t, ghost, trk, est, lateral=None):
    """(reference, compiled) of one `Coverage.occupation` call, each an Occupation or the error it raised."""
    out = []
    saved = coverage._network_occupation
    for fn in (None, saved):
        coverage._network_occupation = fn
        try:
            out.append(cov.occupation(t, ghost, trk, est, lateral))
        except (ArithmeticError, ValueError, IndexError, TypeError) as exc:
            out.append(exc)
        finally:
            coverage._network_occupation = saved
    return out


def _walk(topo, etype, rng, route=False, **kw):
    """A Player fed a noisy walk along a path by the junction rule from a random edge (`route`: that path is its
    a-priori route, with a stop on it); yields the Player after each fix."""
    net = Player(topo, 1, etype).net
    e = rng.randrange(net.n_edges)
    path = Path(net, [(e, 1)] + follow(net, (e, 1), ALL, 400.0, max_edges=20))
    if route:
        kw.update(route=path.edges, stops=[(path.edges[-1][0], 5.0)])
    p = Player(topo, 1, etype, **kw)
    speed = {"pedestrian": 1.4, "cyclist": 5.0}.get(etype, 11.0)
    t, s = 0.0, rng.uniform(0.0, path.length / 3)
    for _ in range(40):
        v = speed * rng.choice([1.0, 1.0, 0.0, 0.5])
        s = min(s + v, path.length)
        x, y = path.xy(s)
        out = p.feed(x + rng.gauss(0.0, 2.0), y + rng.gauss(0.0, 2.0), t)
        out += p.tick(t + 0.5)
        yield p
        t += 1.0


TOPOS = [cross(arm=100.0, street_cell_max=15.0), tee(), hairpin(), chain(), parallel(gap=6.0), area_square()]


@needs_compiled
@pytest.mark.parametrize("topo", TOPOS)
def test_every_publish_cover_is_the_references(topo):
    rng = random.Random(22)
    seen = 0
    for etype, kw in (("pedestrian", {}), ("cyclist", {}), ("car", {}), ("car", {"lateral": 30.0}),
                      ("bus", {"route": True}), ("tram", {"route": True, "lookahead": 60.0})):
        for _ in range(3):
            for p in _walk(topo, etype, rng, **kw):
                trk, ghost = p.tracker, p.ghost
                if ghost is None or trk.place is not EDGE or p.world is not None:
                    continue
                for lateral in (None, 0.0, 17.5):
                    ref, out = _both(p.coverage, 3.0, ghost, trk, p.estimate_xy, lateral)
                    assert _bits(out) == _bits(ref)
                    seen += 1
    assert seen > 50


def _placed_player(topo, etype):
    """A Player on a way (placed and published by its first fix)."""
    p = Player(topo, 1, etype)
    net = p.net
    for e in range(net.n_edges):
        x, y = Path(net, [(e, 1)]).xy(net.edge_len[e] / 2)
        p = Player(topo, 1, etype)
        p.feed(x, y, 0.0)
        if p.tracker.place is EDGE:
            return p
    raise AssertionError("no edge to place on")


HOSTILE = [0.0, -0.0, 1e-300, -1e-300, 1.0, -3.5, 1e9, -1e9, 1e300, math.inf, -math.inf, math.nan]


@needs_compiled
@pytest.mark.parametrize("etype", ["pedestrian", "car"])
def test_the_compiled_cover_is_the_reference_on_hostile_ghosts(etype):
    topo = parallel(gap=6.0)
    p = _placed_player(topo, etype)
    trk, net = p.tracker, p.net
    rng = random.Random(7)
    one = Path(net, [(0, 1)])
    paths = [one, Path(net, [(0, -1)]), trk.path]
    n = 0
    for path in paths:
        for s0 in HOSTILE + [path.length, path.cum[-1] / 2]:
            for v, a in ((0.0, 0.0), (-0.0, -0.0), (rng.choice(HOSTILE), rng.choice(HOSTILE)), (1.4, -0.7)):
                try:
                    ghost = network_model(0.0, path, s0, v, a, 15.0, p.etype.code, p.etype.parts,
                                          rng.choice([math.inf, 50.0]), 1.0)
                except (ArithmeticError, ValueError):
                    continue
                for lateral in (None, 0.0, -1.0, 2.0, 40.0, math.nan):
                    ref, out = _both(p.coverage, 1.0, ghost, trk, p.estimate_xy, lateral)
                    assert _bits(out) == _bits(ref), (s0, v, a, lateral)
                    n += 1
    assert n > 200


@needs_compiled
def test_the_compiled_constants_are_the_coverages():
    c = compiled.constants()
    assert c == {"MAX_PUBLISH_CELLS": coverage.MAX_PUBLISH_CELLS, "LATERAL_AHEAD_TIME": coverage.LATERAL_AHEAD_TIME,
                 "LATERAL_AHEAD_MIN": coverage.LATERAL_AHEAD_MIN}
