"""`encode_network` compiled (`_payload.pyx`, issue 22) against the pure reference: the same payload bytes and
the same ghost (every field by bit pattern) on random publishes, on half-way values of every quantisation
(round half to even), -0.0, subnormals, huge values, and the same error type on NaN and infinities."""

import math
import random
import struct

import pytest

from entitynet.client import netview, payload
from entitynet.client.path import Path
from tests.entitynet.client_fixtures import cross

compiled = pytest.importorskip("entitynet.client._payload", reason="the compiled quantisation is not built here")


def _compiled(*fields):
    return compiled.encode_network(*fields, payload._pack, payload.network_model, payload.encode_network_reference,
                                   payload.VERSION, payload.KIND_NETWORK)


def _bits(v):
    if isinstance(v, float):
        return "nan" if v != v else struct.pack("=d", v)
    if isinstance(v, tuple):
        return tuple(_bits(x) for x in v)
    return v


def _outcome(fn, *fields):
    """(bytes, the ghost's fields by bit pattern and type) or the exception's type."""
    try:
        data, ghost = fn(*fields)
    except (ArithmeticError, ValueError) as exc:
        return type(exc).__name__
    names = ("t0", "s0", "v", "a", "vmax", "etype", "parts", "stop_s", "brake", "plan")
    return data, ghost.path.edges, [(_bits(getattr(ghost, n)), type(getattr(ghost, n))) for n in names]


def test_compiled_equals_the_reference():
    net = netview(cross(arm=100.0, street_cell_max=15.0))
    paths = [Path(net, [(e, d)]) for e in range(net.n_edges) for d in (1, -1)]
    rng = random.Random(8)
    halves = [0.0005, 0.0015, 0.0025, -0.0005, 0.005, 0.015, -0.015, 2.5e-3, 1e-3 * 0.5]
    hard = [0.0, -0.0, 5e-324, -1e-310, 1e15, -1e15, 1e300, 1.7976931348623157e308, math.inf, -math.inf,
            math.nan, -0.004, -0.0049]

    def val(normal):
        u = rng.random()
        if u < 0.2:
            return rng.choice(hard)
        if u < 0.4:
            return rng.choice(halves) + rng.randint(-5000, 5000) * rng.choice([0.001, 0.01])
        return normal

    for _ in range(20_000):
        parts = tuple(val(rng.uniform(0.0, 20.0)) for _ in range(rng.randint(0, 3)))
        stop = rng.choice([math.inf, val(rng.uniform(0.0, 300.0))])
        fields = (val(rng.uniform(0.0, 5000.0)), rng.choice(paths), val(rng.uniform(0.0, 100.0)),
                  val(rng.uniform(-1.0, 15.0)), val(rng.uniform(-3.0, 3.0)), val(rng.uniform(0.0, 20.0)),
                  rng.randint(0, 5), parts, stop, val(rng.uniform(0.5, 3.0)))
        assert _outcome(_compiled, *fields) == _outcome(payload.encode_network_reference, *fields), fields


def test_the_payload_module_uses_the_compiled_one_where_built():
    net = netview(cross(arm=100.0, street_cell_max=15.0))
    fields = (12.3455, Path(net, [(0, 1)]), -0.0, 3.0005, -0.0, 13.9, 1, (4.5, 7.25), math.inf, 1.5)
    assert _outcome(payload.encode_network, *fields) == _outcome(payload.encode_network_reference, *fields)
    ghost = payload.encode_network(*fields)[1]
    assert struct.pack("=d", ghost.s0) == struct.pack("=d", 0.0)  # int 0 / 100.0: +0.0, as the reference
    if payload._COMPILED is not None:
        assert payload.encode_network is not payload.encode_network_reference
