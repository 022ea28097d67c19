"""Motion models and payloads: every receiver extrapolates the published model the same way."""

import pytest

from entitynet.client import AreaModel, NetworkModel, Path, PayloadError, WorldModel, decode, encode, netview
from entitynet.client.path import follow
from tests.entitynet.client_fixtures import cross, tee
from topology.raw import VEHICLE


def test_network_model_follows_its_path_through_the_junction_and_clamps_at_the_end():
    net = netview(cross(arm=100.0))
    path = Path(net, [(0, 1), (3, 1)])  # west -> centre, then north
    m = NetworkModel(10.0, path, 90.0, 10.0, 0.0, 14.0, 3, (13.8, 13.8))
    assert m.xy_at(10.0) == pytest.approx((-10.0, 0.0))
    assert m.xy_at(12.0) == pytest.approx((0.0, 10.0))  # turned north at the node
    assert m.xy_at(1000.0) == pytest.approx((0.0, 100.0))  # clamps at the end of the path
    assert m.xy_at(5.0) == pytest.approx((-10.0, 0.0))  # never extrapolates backwards
    front, joint, aft = m.parts_xy_at(12.0)
    assert front == pytest.approx((0.0, 10.0)) and joint == pytest.approx((-3.8, 0.0))
    assert aft == pytest.approx((-17.6, 0.0))


def test_junction_rule_is_the_straightest_continuation_and_deterministic():
    net = netview(tee())
    assert net.next_edge((0, 1), VEHICLE) == (1, 1)  # west -> east goes straight on
    assert net.next_edge((1, -1), VEHICLE) == (0, -1)
    # from the stem (south, travelling north) left and right are equally straight: the lowest edge id wins
    assert net.next_edge((2, -1), VEHICLE) == (0, -1)
    assert follow(net, (0, 1), VEHICLE, 500.0) == [(1, 1)]  # then a dead end


def test_route_overrides_the_junction_rule():
    net = netview(tee())
    route = [(0, 1), (2, 1)]
    assert follow(net, (0, 1), VEHICLE, 500.0, route, 0) == [(2, 1)]


@pytest.mark.parametrize("model", [
    WorldModel(12.345, 100.01, -200.02, 1.234, -0.5, 0.01, 0.02, 1),
    AreaModel(3.0, 0, 1.25, -2.5, 0.7, 0.1, 0),
])
def test_payload_roundtrip_extrapolates_identically(model):
    net = netview(cross())
    back = decode(encode(model), net)
    again = decode(encode(back), net)
    assert again == back  # quantisation is idempotent: a player's ghost equals every receiver's ghost
    for t in (model.t0, model.t0 + 1.0, model.t0 + 30.0):
        assert back.xy_at(t) == pytest.approx(model.xy_at(t), abs=0.02 + 0.002 * (t - model.t0) ** 2)


def test_network_payload_roundtrip_and_size():
    net = netview(cross())
    m = NetworkModel(100.0, Path(net, [(0, 1), (1, 1)]), 55.55, 9.876, -0.5, 14.0, 3, (13.8, 13.8))
    data = encode(m)
    assert len(data) < 64
    back = decode(data, net)
    assert back.path.edges == m.path.edges and back.parts == (13.8, 13.8)
    assert decode(encode(back), net) == back
    for t in (100.0, 103.0, 150.0):
        assert back.xy_at(t) == pytest.approx(m.xy_at(t), abs=0.05)


@pytest.mark.parametrize("data", [b"", b"\xc1", b"\x93\x01\x01\x00", encode(WorldModel(0, 0, 0, 0, 0, 0, 0, 1))[:-1]])
def test_bad_payloads_are_rejected_cleanly(data):
    with pytest.raises(PayloadError):
        decode(data, netview(cross()))


def test_network_payload_with_unknown_edge_is_rejected():
    import msgpack

    data = msgpack.packb([1, 1, 0, 3, 0, 0, 0, 0, [], [99], -1, 1000])
    with pytest.raises(PayloadError):
        decode(data, netview(cross()))


def test_quantized_equals_the_decoded_payload():
    from entitynet.client.payload import quantized

    net = netview(cross())
    models = [
        NetworkModel(100.0004, Path(net, [(0, 1), (1, 1)]), 55.555, 9.8765, -0.5004, 14.0, 3, (13.8, 13.8),
                     150.004, 1.2),
        NetworkModel(1.5, Path(net, [(2, 1)]), 0.0, 0.0, 0.0, 3.0, 0, ()),
        WorldModel(12.3456, 100.011, -200.026, 1.2344, -0.5, 0.0105, 0.02, 1),
        AreaModel(3.0007, 0, 1.254, -2.5, 0.7003, 0.1, 0),
    ]
    for m in models:
        assert quantized(m) == decode(encode(m), net)
        assert encode(quantized(m)) == encode(m)  # quantising is idempotent: the payload of the ghost
