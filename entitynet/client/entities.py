"""Entity types: the parameters an entity type uses (reference section 5.2), and nothing more.

Lengths are body parts from the front: 0 parts for pedestrians and cyclists (length 0), one for buses and
cars, two for trams (a two-part vehicle with an articulation; both parts follow the rails).
"""

from __future__ import annotations

from dataclasses import dataclass

from topology.networks import PEDESTRIAN, TRAM, VEHICLE


@dataclass(frozen=True, slots=True)
class EntityType:
    """What the client core needs to know of a kind of entity: its networks, body, speed caps and the
    filter and hysteresis settings, so one Player handles walkers, cars and trams alike."""
    code: int
    name: str
    networks: int
    parts: tuple[float, ...]
    vmax: float  # m/s, caps accelerating extrapolations
    amax: float  # m/s^2, bound on the published acceleration
    v_stop: float  # below this estimated speed a moving entity has stopped (emergent update)
    v_start: float  # above this a stopped entity has started (emergent update)
    jerk_q: float  # process noise of the along-path filter
    accel: bool  # whether the along-path filter (and the published model) carries acceleration
    brake: float = 1.0  # comfortable braking used to extrapolate a halt at a known stop (m/s^2)
    # extrapolation limits (docs/dead-reckoning.md, "Limits"): no extrapolation of this type is faster
    max_speed: float = 40.0  # m/s: receivers and the player cap any extrapolated speed here
    max_gap: float = 20.0  # s without a fix: the player stops extrapolating and publishes a standing model
    lost_after: float = 120.0  # s without a fix: the player unpublishes the entity

    @property
    def length(self) -> float:
        """Body length (the sum of the parts): the occupation covers [s - length, s] behind the front."""
        return sum(self.parts)


# max_speed sits above vmax (what a player publishes) by what a real one of the type may reach (a sprinting
# walker: 8 m/s; the bench's noisy walker filters pass 6 m/s, so a lower cap would change their figures); max_gap is
# longer for vehicles (tunnels, urban canyons) than for walkers; lost_after leaves a transit vehicle at a
# terminus longer on the map than a walker whose phone went quiet
PEDESTRIAN_T = EntityType(0, "pedestrian", PEDESTRIAN, (), 3.0, 1.0, 0.25, 0.7, 0.1, False,
                          max_speed=8.0, max_gap=15.0, lost_after=120.0)
CAR = EntityType(1, "car", VEHICLE, (4.5,), 25.0, 3.0, 0.8, 2.0, 1.0, True,
                 max_speed=40.0, max_gap=20.0, lost_after=120.0)
BUS = EntityType(2, "bus", VEHICLE, (12.0,), 20.0, 1.5, 0.8, 2.0, 0.3, True, 1.2,
                 max_speed=25.0, max_gap=30.0, lost_after=180.0)
TRAM_T = EntityType(3, "tram", TRAM, (13.8, 13.8), 14.0, 1.3, 0.8, 2.0, 0.3, True, 1.0,
                    max_speed=20.0, max_gap=30.0, lost_after=180.0)
CYCLIST = EntityType(4, "cyclist", PEDESTRIAN | VEHICLE, (), 10.0, 2.0, 0.6, 1.5, 0.8, True,
                     max_speed=15.0, max_gap=15.0, lost_after=120.0)

TYPES: dict[str, EntityType] = {t.name: t for t in (PEDESTRIAN_T, CAR, BUS, TRAM_T, CYCLIST)}
BY_CODE: dict[int, EntityType] = {t.code: t for t in TYPES.values()}


def entity_type(name_or_type: str | EntityType) -> EntityType:
    """Resolve a type name (as given on the command line or by a proxy) or pass a type through;
    an unknown name is a `ValueError` listing the known ones."""
    if isinstance(name_or_type, EntityType):
        return name_or_type
    try:
        return TYPES[name_or_type]
    except KeyError:
        raise ValueError(f"unknown entity type {name_or_type!r} (known: {', '.join(sorted(TYPES))})") from None
