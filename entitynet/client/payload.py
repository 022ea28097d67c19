"""The published model as a compact msgpack payload (opaque to servers).

Quantised integers keep it small and make it exact: positions in centimetres, speeds in mm/s, accelerations
in mm/s^2, times in wire milliseconds, directed edges as signed ids (edge + 1) * dir. A player builds its
ghost by *decoding its own payload*, so it extrapolates exactly what every receiver extrapolates.

    network: [1, 1, t0_ms, etype, s0_cm, v_mms, a_mms2, vmax_mms, [part_cm...], [signed edge...],
              stop_cm (-1: none), brake_mms2]
    area:    [1, 2, t0_ms, etype, area, x_cm, y_cm, vx_mms, vy_mms]
    world:   [1, 3, t0_ms, etype, x_cm, y_cm, vx_mms, vy_mms, ax_mms2, ay_mms2]
"""

from __future__ import annotations

import math

import msgpack

from entitynet.client.limits import max_speed
from entitynet.client.motion import (
    KIND_AREA,
    KIND_NETWORK,
    KIND_WORLD,
    AreaModel,
    Model,
    NetworkModel,
    WorldModel,
    network_model,
)
from entitynet.client.network import NetView
from entitynet.client.optional_c import compiled
from entitynet.client.path import Path

VERSION = 1
# one packer for the module (as `msgpack.packb` makes per call; autoreset: each call returns its own bytes).
# The client core is single-threaded per process, like the switchboard's shared packer
_pack = msgpack.Packer(use_bin_type=True).pack


class PayloadError(ValueError):
    """A payload that is not a valid published model (wrong shape, version, or an edge not in the map)."""


def _q(x: float, scale: float) -> int:
    if not math.isfinite(x):
        raise PayloadError(f"cannot encode non-finite value {x!r}")
    return int(round(x * scale))


def encode_quantized(model: Model) -> tuple[bytes, Model]:
    """The payload and the model it decodes to, quantising once (the player's hot path).

    Equal to `(encode(quantized(model)), quantized(model))` (a test): the integers are computed once and
    both the payload and the model are made from them (re-quantising n / scale gives n back exactly)."""
    if isinstance(model, NetworkModel):
        return encode_network(model.t0, model.path, model.s0, model.v, model.a, model.vmax, model.etype,
                              model.parts, model.stop_s, model.brake)
    t0 = _q(model.t0, 1000.0)
    if isinstance(model, AreaModel):
        x, y, vx, vy = _q(model.x, 100.0), _q(model.y, 100.0), _q(model.vx, 1000.0), _q(model.vy, 1000.0)
        body = [VERSION, KIND_AREA, t0, model.etype, model.area, x, y, vx, vy]
        return msgpack.packb(body, use_bin_type=True), AreaModel(
            t0 / 1000.0, model.area, x / 100.0, y / 100.0, vx / 1000.0, vy / 1000.0, model.etype)
    if isinstance(model, WorldModel):
        x, y = _q(model.x, 100.0), _q(model.y, 100.0)
        vx, vy, ax, ay = _q(model.vx, 1000.0), _q(model.vy, 1000.0), _q(model.ax, 1000.0), _q(model.ay, 1000.0)
        body = [VERSION, KIND_WORLD, t0, model.etype, x, y, vx, vy, ax, ay]
        return msgpack.packb(body, use_bin_type=True), WorldModel(
            t0 / 1000.0, x / 100.0, y / 100.0, vx / 1000.0, vy / 1000.0, ax / 1000.0, ay / 1000.0, model.etype)
    raise PayloadError(f"unknown model {type(model).__name__}")


def encode_network(t0: float, path: Path, s0: float, v: float, a: float, vmax: float, etype: int,
                   parts: tuple[float, ...], stop_s: float, brake: float) -> tuple[bytes, NetworkModel]:
    """`encode_quantized` of the NetworkModel with these fields, without building the unquantised model
    (whose braking plan would be computed only to be thrown away). The quantisation is `_q` written out
    for finite values (the usual case); anything else takes `_encode_network_checked`, which raises."""
    v = max(v, 0.0)
    # one test for all: a NaN or an infinity makes the sum non-finite (a finite sum too large to represent
    # only sends finite values the long way, which encodes them the same)
    if not math.isfinite(t0 + s0 + v + a + vmax + brake + sum(parts)):
        return _encode_network_checked(t0, path, s0, v, a, vmax, etype, parts, stop_s, brake)
    # round(x) of a float is already the int that int(round(x)) gives
    t0i = round(t0 * 1000.0)
    s0i = round(s0 * 100.0)
    vi = round(v * 1000.0)
    ai = round(a * 1000.0)
    vmaxi = round(vmax * 1000.0)
    partsi = [round(p * 100.0) for p in parts]
    stop_finite = math.isfinite(stop_s)
    stopi = round(stop_s * 100.0) if stop_finite else -1
    brakei = round(brake * 1000.0)
    body = [VERSION, KIND_NETWORK, t0i, etype, s0i, vi, ai, vmaxi, partsi, [(e + 1) * d for e, d in path.edges],
            stopi, brakei]
    ghost = network_model(t0i / 1000.0, path, s0i / 100.0, vi / 1000.0, ai / 1000.0, vmaxi / 1000.0, etype,
                          tuple([p / 100.0 for p in partsi]), stopi / 100.0 if stop_finite else math.inf,
                          brakei / 1000.0)
    return _pack(body), ghost


def _encode_network_checked(t0: float, path: Path, s0: float, v: float, a: float, vmax: float, etype: int,
                            parts: tuple[float, ...], stop_s: float, brake: float) -> tuple[bytes, NetworkModel]:
    """`encode_network` as first written: every value through `_q` (the reference; raises on non-finite)."""
    t0i = _q(t0, 1000.0)
    s0i = _q(s0, 100.0)
    vi = _q(max(v, 0.0), 1000.0)
    ai = _q(a, 1000.0)
    vmaxi = _q(vmax, 1000.0)
    partsi = [_q(p, 100.0) for p in parts]
    stopi = _q(stop_s, 100.0) if math.isfinite(stop_s) else -1
    brakei = _q(brake, 1000.0)
    body = [VERSION, KIND_NETWORK, t0i, etype, s0i, vi, ai, vmaxi, partsi, [(e + 1) * d for e, d in path.edges],
            stopi, brakei]
    ghost = NetworkModel(t0i / 1000.0, path, s0i / 100.0, vi / 1000.0, ai / 1000.0, vmaxi / 1000.0, etype,
                         tuple(p / 100.0 for p in partsi), stopi / 100.0 if math.isfinite(stop_s) else math.inf,
                         brakei / 1000.0)
    return msgpack.packb(body, use_bin_type=True), ghost


encode_network_reference = encode_network  # the pure function (tests hold the compiled one equal to it)
_COMPILED = compiled("_payload")  # the quantisation compiled
if _COMPILED is not None:
    _encode_network_c = _COMPILED.encode_network

    def encode_network(t0: float, path: Path, s0: float, v: float, a: float, vmax: float, etype: int,
                       parts: tuple[float, ...], stop_s: float, brake: float) -> tuple[bytes, NetworkModel]:
        """`encode_network_reference`, compiled (_payload.pyx): the same bytes and ghost."""
        return _encode_network_c(t0, path, s0, v, a, vmax, etype, parts, stop_s, brake, _pack, network_model,
                                 encode_network_reference, VERSION, KIND_NETWORK)


def encode(model: Model) -> bytes:
    """The model as the quantised msgpack payload of the wire format above; the player decodes its own
    payload so that its ghost equals every receiver's."""
    t0 = _q(model.t0, 1000.0)
    if isinstance(model, NetworkModel):
        edges = [(e + 1) * d for e, d in model.path.edges]
        body = [VERSION, KIND_NETWORK, t0, model.etype, _q(model.s0, 100.0), _q(max(model.v, 0.0), 1000.0),
                _q(model.a, 1000.0), _q(model.vmax, 1000.0), [_q(p, 100.0) for p in model.parts], edges,
                _q(model.stop_s, 100.0) if math.isfinite(model.stop_s) else -1, _q(model.brake, 1000.0)]
    elif isinstance(model, AreaModel):
        body = [VERSION, KIND_AREA, t0, model.etype, model.area, _q(model.x, 100.0), _q(model.y, 100.0),
                _q(model.vx, 1000.0), _q(model.vy, 1000.0)]
    elif isinstance(model, WorldModel):
        body = [VERSION, KIND_WORLD, t0, model.etype, _q(model.x, 100.0), _q(model.y, 100.0),
                _q(model.vx, 1000.0), _q(model.vy, 1000.0), _q(model.ax, 1000.0), _q(model.ay, 1000.0)]
    else:
        raise PayloadError(f"unknown model {type(model).__name__}")
    return msgpack.packb(body, use_bin_type=True)


def quantized(model: Model) -> Model:
    """Exactly what `decode(encode(model))` returns, without the msgpack round trip or path re-validation:
    the player's ghost on the hot path (the equality is a test)."""
    def q(x: float, scale: float) -> float:
        return _q(x, scale) / scale

    t0 = _q(model.t0, 1000.0) / 1000.0
    if isinstance(model, NetworkModel):
        return NetworkModel(t0, model.path, q(model.s0, 100.0), q(max(model.v, 0.0), 1000.0), q(model.a, 1000.0),
                            q(model.vmax, 1000.0), model.etype, tuple(q(p, 100.0) for p in model.parts),
                            q(model.stop_s, 100.0) if math.isfinite(model.stop_s) else math.inf,
                            q(model.brake, 1000.0))
    if isinstance(model, AreaModel):
        return AreaModel(t0, model.area, q(model.x, 100.0), q(model.y, 100.0), q(model.vx, 1000.0),
                         q(model.vy, 1000.0), model.etype)
    if isinstance(model, WorldModel):
        return WorldModel(t0, q(model.x, 100.0), q(model.y, 100.0), q(model.vx, 1000.0), q(model.vy, 1000.0),
                          q(model.ax, 1000.0), q(model.ay, 1000.0), model.etype)
    raise PayloadError(f"unknown model {type(model).__name__}")


def _ints(xs, n: int | None = None) -> list[int]:
    if not isinstance(xs, list) or (n is not None and len(xs) != n):
        raise PayloadError("malformed payload")
    for x in xs:
        if not isinstance(x, int) or isinstance(x, bool):
            raise PayloadError("malformed payload: expected integers")
    return xs


def decode(data: bytes, net: NetView | None) -> Model:
    """The model in a payload. Network models need the topology (`net`); world models do not."""
    try:
        body = msgpack.unpackb(data, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types
        raise PayloadError(f"not a msgpack payload ({exc.__class__.__name__})") from None
    if not isinstance(body, list) or len(body) < 4 or body[0] != VERSION:
        raise PayloadError("unknown payload version or shape")
    kind = body[1]
    if kind == KIND_NETWORK:
        if len(body) != 12:
            raise PayloadError("malformed network payload")
        t0, etype, s0, v, a, vmax = _ints(body[2:8], 6)
        stop, brake = _ints(body[10:12], 2)
        parts = _ints(body[8])
        signed = _ints(body[9])
        if net is None:
            raise PayloadError("a network payload needs the topology")
        if not signed or v < 0 or vmax < 0 or brake <= 0 or stop < -1 or any(p < 0 for p in parts):
            raise PayloadError("malformed network payload values")
        cap = round(max_speed(etype) * 1000.0)  # a publisher's speed beyond its type's cap is not believed
        v, vmax = min(v, cap), min(vmax, cap)
        try:
            path = Path(net, [(abs(x) - 1, 1 if x > 0 else -1) for x in signed if x != 0])
        except ValueError as exc:
            raise PayloadError(str(exc)) from None
        return NetworkModel(t0 / 1000.0, path, s0 / 100.0, v / 1000.0, a / 1000.0, vmax / 1000.0, etype,
                            tuple(p / 100.0 for p in parts), stop / 100.0 if stop >= 0 else math.inf,
                            brake / 1000.0)
    if kind == KIND_AREA:
        t0, etype, area, x, y, vx, vy = _ints(body[2:], 7)
        return AreaModel(t0 / 1000.0, area, x / 100.0, y / 100.0, vx / 1000.0, vy / 1000.0, etype)
    if kind == KIND_WORLD:
        t0, etype, x, y, vx, vy, ax, ay = _ints(body[2:], 8)
        return WorldModel(t0 / 1000.0, x / 100.0, y / 100.0, vx / 1000.0, vy / 1000.0, ax / 1000.0,
                          ay / 1000.0, etype)
    raise PayloadError(f"unknown model kind {kind!r}")
