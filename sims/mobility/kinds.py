"""Entity kinds: the motion parameters of each entity type, in one table.

Why one table: the demo, the benchmarks and the coming simulation engine must agree on how fast a tram
accelerates or how long a bus dwells, or their figures describe different cities. A kind names the client
core's entity type (its networks and body come from there, so they cannot disagree) and adds only what
moving it needs; a parameter a kind's motion does not use is left out (None), not invented.
"""

from __future__ import annotations

from dataclasses import dataclass

from entitynet.client import EntityType, entity_type


@dataclass(frozen=True)
class Halts:
    """Where a scheduled vehicle stops: always at its stops (`dwell` seconds, uniform in the range), and at a
    signal when it is red (probability `p_red`, waiting `red` seconds). Only transit kinds have halts."""

    dwell: tuple[float, float]
    p_red: float
    red: tuple[float, float]


@dataclass(frozen=True)
class Kind:
    """Motion parameters of one entity type.

    `cruise` (m/s) is the typical free speed; `spread` the per-entity spread a mover draws its own cruise
    from (uniform in cruise x [1 - spread, 1 + spread]); `vary` how much the target speed of a speed profile
    drifts along the way; `accel` and `decel` (m/s^2) bound a speed profile's changes (None: this kind is
    not moved by profiles yet); `halts` the stops and signals of scheduled vehicles.
    """

    name: str
    cruise: float
    spread: float
    vary: float = 0.15
    accel: float | None = None
    decel: float | None = None
    halts: Halts | None = None

    @property
    def etype(self) -> EntityType:
        """The client core's entity type of this kind (networks, body parts, filter settings)."""
        return entity_type(self.name)

    @property
    def networks(self) -> int:
        """The networks (bit mask) this kind moves on."""
        return self.etype.networks

    @property
    def length(self) -> float:
        """Body length in metres (all parts end to end; 0 for a point-like pedestrian)."""
        return float(sum(self.etype.parts))


_TRANSIT_DWELL = (12.0, 30.0)
_TRANSIT_RED = (5.0, 35.0)

#: The kinds the simulations know. Pedestrian and car spreads are the demo's; the transit kinds' profiles
#: (cruise, accel, decel, halts) are those of the dr benchmark's GTFS vehicles.
KINDS: dict[str, Kind] = {
    "pedestrian": Kind("pedestrian", cruise=1.35, spread=0.25, vary=0.2, accel=0.6, decel=0.8),
    "car": Kind("car", cruise=9.0, spread=0.35),
    "bus": Kind("bus", cruise=10.5, spread=0.3, accel=1.2, decel=1.5,
                halts=Halts(_TRANSIT_DWELL, p_red=0.35, red=_TRANSIT_RED)),
    "tram": Kind("tram", cruise=9.0, spread=0.3, accel=1.0, decel=1.2,
                 halts=Halts(_TRANSIT_DWELL, p_red=0.25, red=_TRANSIT_RED)),
}


def kind(name: str) -> Kind:
    """The kind of an entity type name; a clear error for an unknown one (the known ones are listed)."""
    try:
        return KINDS[name]
    except KeyError:
        raise ValueError(f"no motion parameters for entity type {name!r} (known: {', '.join(sorted(KINDS))})") \
            from None
