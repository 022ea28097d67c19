"""One mobility model for the benchmarks and the simulation engine (which the demo runs).

Layers, each its own module:
- `kinds`: per entity type, the motion parameters (cruise speed and spread, acceleration, halts);
- `network`: where an entity starts and the edges it goes along (a growing `Trajectory`, a `random_walk`);
- `profiles`: speed profiles along a path (acceleration, stops, red signals, drift);
- `areas`: waypoint walks inside squares and parks;
- `gps`: noisy fixes of the truth (from the caller's generator, or per entity: `entity_gps`);
- `walkers`: cheap constant-speed publishers for switchboard load.
Everything draws from the caller's seeded generators, so a seed reproduces a run.
"""

from sims.mobility.areas import area_walk, point_in_ring
from sims.mobility.gps import GPS_SIGMA, entity_gps, gps
from sims.mobility.kinds import KINDS, Halts, Kind, kind
from sims.mobility.network import Trajectory, random_start, random_walk
from sims.mobility.profiles import Profile, profile_for, speed_profile, vehicle_halts
from sims.mobility.walkers import Walkers

__all__ = [
    "GPS_SIGMA", "KINDS", "Halts", "Kind", "Profile", "Trajectory", "Walkers", "area_walk", "entity_gps", "gps",
    "kind", "point_in_ring", "profile_for", "random_start", "random_walk", "speed_profile", "vehicle_halts",
]
