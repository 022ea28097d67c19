"""Per-type simulation parameters (reference section 5.2): what the engine needs to move and separate entities.

Why a second table next to `sims.mobility.kinds`: a kind says how an entity moves on its own (cruise, speed
spread, acceleration, halts); the engine adds what it needs to move entities *among each other*: body length
(from the client core's entity type, so the published body and the simulated one agree), the car-following
model's headway and gap, the lateral offset (walkway spread or virtual lane), the collision threshold and the
deadlock timeouts. Cruise, acceleration and braking come from the kind, so the demo, the benchmarks and the
engine move a tram the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sims.mobility.kinds import kind


@dataclass(frozen=True)
class TypeParams:
    """Everything the engine needs about one entity type.

    `length` 0 means point-like (pedestrians, cyclists): such entities take no part in collision avoidance.
    `lateral` is the offset to the right of the direction of travel (a virtual lane, 3 m for vehicles);
    `lateral_spread` randomises it per entity (pedestrians spread across the walkway). `gap` is the collision
    distance threshold (the car-following model's minimum gap, and the padding of the bounding boxes);
    `headway` the IDM time headway. `accept_after`: seconds blocked by another entity before a collision is
    accepted temporarily (for `accept_for` seconds); `delete_after`: seconds blocked in all before the entity is
    deleted.
    """

    name: str
    parts: tuple[float, ...]
    vmax: float
    accel: float
    decel: float
    lateral: float
    lateral_spread: float
    gap: float
    headway: float
    width: float
    accept_after: float
    accept_for: float
    delete_after: float

    #: body length: the sum of the parts (a two-part tram is both parts end to end); computed once (the world's
    #: step reads it several times per entity and tick)
    length: float = field(init=False, repr=False, compare=False)
    #: whether this type takes part in collision avoidance (bodies with a length do)
    avoids: bool = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "length", float(sum(self.parts)))
        object.__setattr__(self, "avoids", self.length > 0.0)


def _from_kind(name: str, *, lateral: float, lateral_spread: float = 0.0, gap: float = 2.0, headway: float = 1.5,
               width: float = 2.5, accept_after: float = 30.0, accept_for: float = 15.0,
               delete_after: float = 120.0, accel: float | None = None, decel: float | None = None) -> TypeParams:
    k = kind(name)
    et = k.etype
    return TypeParams(
        name=name, parts=tuple(float(p) for p in et.parts),
        vmax=min(k.cruise * (1.0 + k.spread), et.vmax),
        accel=float(accel if accel is not None else k.accel), decel=float(decel if decel is not None else k.decel),
        lateral=lateral, lateral_spread=lateral_spread, gap=gap, headway=headway, width=width,
        accept_after=accept_after, accept_for=accept_for, delete_after=delete_after,
    )


#: the engine's types; cars take the IDM textbook acceleration and comfortable braking (their kind is moved by
#: drift, not profiles, so it has none of its own)
PARAMS: dict[str, TypeParams] = {
    "pedestrian": _from_kind("pedestrian", lateral=0.0, lateral_spread=2.5, gap=0.0, headway=0.5, width=0.6),
    "car": _from_kind("car", lateral=3.0, accel=1.5, decel=2.5),
    "bus": _from_kind("bus", lateral=3.0, gap=2.5),
    "tram": _from_kind("tram", lateral=0.0, gap=3.0, headway=2.0, accept_after=45.0, delete_after=180.0),
}


def params(name: str) -> TypeParams:
    """The parameters of an entity type; a clear error naming the known types otherwise."""
    try:
        return PARAMS[name]
    except KeyError:
        raise ValueError(f"the simulation has no entity type {name!r} (known: {', '.join(sorted(PARAMS))})") \
            from None
