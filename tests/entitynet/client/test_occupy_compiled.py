"""The compiled occupation (`entitynet/client/_occupy.pyx`, issue 22) against the pure `occupy`, its reference:
the same Occupation, field for field and bit for bit (-0.0 is not 0.0 here, NaN equals NaN), or the same error,
on synthetic maps with junctions, a hairpin, a chain of short edges, zero-length edges and areas; with and without
a route, a look-ahead, the tight mode, a dead end and a model's own travel times; and on hostile input (NaN,
infinities, -0.0, huge values, a malformed path). With ENTITYNET_PURE_PYTHON set the reference is used."""

import math
import os
import random
import struct
import subprocess
import sys
from pathlib import Path as FilePath

import pytest

from entitynet.client import netview, occupation
from entitynet.client.motion import network_model
from entitynet.client.path import Path, follow
from tests.entitynet.client_fixtures import ALL, area_square, chain, cross, hairpin, make_topology, parallel, tee

compiled = occupation._COMPILED
needs_compiled = pytest.mark.skipif(compiled is None, reason="the compiled occupation is not built here")


def _degenerate():
    """A street with a zero-length edge (B to B2 at one point), a bent edge with a repeated vertex, a branch."""
    nodes = {"A": (0.0, 0.0), "B": (40.0, 0.0), "B2": (40.0, 0.0), "C": (120.0, 0.0), "H": (60.0, -30.0),
             "D": (200.0, 0.0), "E": (120.0, 50.0)}
    edges = [("A", "B"), ("B", "B2"), ("B2", "C", ALL, [(80.0, 0.0), (80.0, 0.0), (100.0, 2.0)]), ("B2", "H"),
             ("C", "D"), ("C", "E")]
    return make_topology(nodes, edges, junction_radius=5.0, street_cell_max=15.0)


TOPOS = [_degenerate(), cross(arm=100.0, street_cell_max=15.0), tee(), hairpin(), chain(), parallel(gap=6.0),
         area_square()]


def _bits(occ):
    """An Occupation (or an error) as comparable values: floats by bit pattern, NaN as one value."""
    if isinstance(occ, BaseException):
        return type(occ).__name__
    return tuple("nan" if isinstance(v, float) and v != v else struct.pack("=d", v) if isinstance(v, float) else v
                 for v in (occ.cells, occ.validity, occ.front_period, occ.aft_period, occ.cover_start, occ.cover_end))


def _run(fn, *args, **kw):
    try:
        return fn(*args, **kw)
    except (ArithmeticError, ValueError, IndexError, TypeError) as exc:
        return exc


def _paths(net, rng):
    """Every directed edge alone, and paths on from each by the junction rule (up to 12 edges)."""
    out = []
    for e in range(net.n_edges):
        for d in (1, -1):
            out.append(Path(net, [(e, d)]))
            more = follow(net, (e, d), ALL, rng.uniform(10.0, 400.0), max_edges=12)
            if more:
                out.append(Path(net, [(e, d)] + more))
    return out


@needs_compiled
@pytest.mark.parametrize("topo", TOPOS)
def test_the_compiled_occupation_is_the_reference(topo):
    net = netview(topo)
    rng = random.Random(22)
    for path in _paths(net, rng):
        marks = list(path.cum) + [c + a for c, (e, d) in zip(path.cum, path.edges, strict=False)
                                  for a, _b, _c in net.pieces(e, d)]
        for _ in range(25):
            s = rng.choice(marks) if rng.random() < 0.4 else rng.uniform(-20.0, path.length + 20.0)
            v, a = rng.choice([0.0, 0.3, 1.4, 9.0, 15.0]), rng.choice([0.0, -1.2, 0.8, 1e-12])
            kw = dict(known_until=rng.choice([0.0, path.length, rng.uniform(0.0, path.length)]),
                      margin=rng.choice([0.0, 5.0, 12.5]), lookahead=rng.choice([0.0, 30.0, 80.0]),
                      tight=rng.choice([None, True, False]), max_validity=rng.choice([60.0, 30.0]),
                      dead_end_at_path_end=rng.random() < 0.3, branch_depth=rng.choice([40.0, 5.0, 0.0]))
            if rng.random() < 0.5:  # the published model's own travel times (a halt ahead, the horizon)
                stop = rng.choice([math.inf, s + rng.uniform(-5.0, 60.0)])
                kw["travel"] = network_model(0.0, path, s, v, a, 20.0, 1, (0.0,), stop, 1.3).time_to
            args = (path, s, rng.choice([0.0, 12.0, 45.0]), v, a, rng.choice([20.0, 1.0]), rng.choice([ALL, 1, 2]))
            want = _bits(_run(occupation.occupy_reference, *args, **kw))
            assert _bits(_run(compiled.occupy, *args, **kw)) == want, (args, kw)
    if any(net.is_choice((e, d), ALL) for e in range(net.n_edges) for d in (1, -1)):
        assert net.__dict__.get("_branch_cover")  # the trees at the next choice of way were compared too


@needs_compiled
def test_the_compiled_occupation_is_the_reference_on_hard_inputs():
    """NaN, infinities, -0.0, subnormals and huge values in every numeric argument, and malformed paths: the
    same Occupation bit for bit, or the same refusal (a clear ValueError for a non-finite position or motion)."""
    hard = [0.0, -0.0, 5e-324, 1e-300, 1e16, -1e16, 1e308, -1e308, math.inf, -math.inf, math.nan]
    rng = random.Random(5)
    net = netview(_degenerate())
    paths = _paths(net, rng)

    def pick(normal):
        return rng.choice(hard) if rng.random() < 0.3 else normal

    for _ in range(4000):
        path = rng.choice(paths)
        args = (path, pick(rng.uniform(-5.0, path.length + 5.0)), pick(10.0), pick(5.0), pick(-1.0), pick(15.0),
                ALL)
        kw = dict(known_until=pick(0.0), margin=pick(5.0), lookahead=pick(30.0), tight=rng.choice([None, True]),
                  max_validity=pick(60.0), min_validity=pick(0.5), branch_depth=pick(40.0),
                  dead_end_at_path_end=rng.random() < 0.3)
        want = _bits(_run(occupation.occupy_reference, *args, **kw))
        assert _bits(_run(compiled.occupy, *args, **kw)) == want, (args, kw)
    for bad in (math.nan, math.inf, -math.inf):
        for i in (1, 3, 4):
            args = [paths[0], 1.0, 0.0, 1.0, 0.0, 10.0, ALL]
            args[i] = bad
            with pytest.raises(ValueError, match="finite"):
                compiled.occupy(*args)
    # a path that is no path (no edges, an edge not in the map, a cumulative list of the wrong length): an error
    bogus = [Path(net, [], _cum=[]), Path(net, [(net.n_edges + 3, 1)], _cum=[0.0, 10.0]),
             Path(net, [(0, 1)], _cum=[0.0])]
    for p in bogus:
        with pytest.raises((ValueError, IndexError)):
            compiled.occupy(p, 1.0, 0.0, 1.0, 0.0, 10.0, ALL, lookahead=30.0)


@needs_compiled
def test_the_compiled_occupation_shares_the_branch_memo():
    """A tree found by one is a hit for the other: the memo is the pure function's, kept on the view."""
    net = netview(cross(arm=100.0, street_cell_max=15.0))
    path = Path(net, [(0, 1)])
    net.__dict__.pop("_branch_cover", None)
    s = path.length - 10.0  # 10 m before the crossing: the tree of the three ways on
    first = compiled.occupy(path, s, 0.0, 5.0, 0.0, 10.0, ALL, lookahead=30.0)
    assert net.__dict__["_branch_cover"], "the compiled occupation stored its tree in the view's memo"
    net.__dict__["_branch_cover"] = {key: (list(los), list(rest)) for key, (los, rest) in
                                     net.__dict__["_branch_cover"].items()}
    again = occupation.occupy_reference(path, s, 0.0, 5.0, 0.0, 10.0, ALL, lookahead=30.0)
    assert _bits(first) == _bits(again)


def test_pure_python_forces_the_reference():
    """ENTITYNET_PURE_PYTHON=1 selects the pure occupation (the pinned replay digests on the pure path run in
    test_state's child, with every compiled client module hidden)."""
    code = ("from entitynet.client import coverage, occupation\n"
            "assert occupation._COMPILED is None and occupation.occupy is occupation.occupy_reference\n"
            "assert coverage.occupy is occupation.occupy_reference\n"
            "assert coverage._COMPILED is coverage._network_occupation is None\nprint('reference ok')\n")
    env = dict(os.environ, ENTITYNET_PURE_PYTHON="1")
    done = subprocess.run([sys.executable, "-c", code], cwd=FilePath(__file__).parents[3], capture_output=True,
                          text=True, timeout=300, env=env)
    assert done.returncode == 0 and done.stdout.strip() == "reference ok", done.stderr[-3000:]


@needs_compiled
@pytest.mark.parametrize("topo", TOPOS)
def test_the_compiled_branch_search_is_the_reference(topo):
    """`_span` (the branch tree and the interval of depths it answers) compiled against the pure search: every
    directed edge, network mask and budget, at depths on and between the tree's cell boundaries and at NaN,
    infinities, -0.0 and negative depths; compared by bit pattern."""
    net = netview(topo)
    rng = random.Random(7)
    hard = [0.0, -0.0, -5.0, 5e-324, 1e308, math.inf, -math.inf, math.nan]
    for e in range(net.n_edges):
        for d in (1, -1):
            for networks in (ALL, 1, 2):
                for budget in ((48, 64), (2, 64), (48, 2), (0, 0)):
                    for depth in hard + [rng.uniform(0.0, 150.0) for _ in range(12)] + [10.0, 20.0, 30.0, 40.0]:
                        want = occupation._span(net, (e, d), depth, networks, *budget)
                        got = compiled.span(net, (e, d), depth, networks, *budget)
                        assert _bits_span(got) == _bits_span(want), ((e, d), depth, networks, budget)


def _bits_span(out):
    cells, shortest, lo, hi = out
    return cells, [struct.pack("=d", v) if v == v else "nan" for v in (shortest, lo, hi)]
