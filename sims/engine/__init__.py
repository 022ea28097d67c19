"""The simulation engine (reference sections 5.2-5.3): a sans-IO world stepped with an explicit clock.

- `params`: per-type parameters (length, speeds, lateral offset, collision threshold, deadlock timeouts);
- `routes`: routes along directed edges, OD trips by shortest paths;
- `agents`, `behaviour`: an entity's truth and the car-following model (IDM) with its obstacles;
- `crossings`: first come, first served at junctions on bounding boxes;
- `world`: stepping, deadlock timeouts and counters;
- `spawn`, `schedule`: random OD spawns and GTFS-scheduled transit;
- `clients`, `viewers`, `measure`, `harness`: honest clients, PVS viewers, truth against what viewers see.
"""

#: the tick rates (Hz) a simulation takes: one home for `SimConfig`'s check and `entitynet sim --tick-hz`'s range
#: (here, so that building the CLI's parser loads nothing of the engine)
TICK_HZ_RANGE = (0.1, 100.0)
