"""The simulation's entities spread over worker processes, on this machine or on others joined over NATS.

Why this split (docs/simulation.md, "Workers"): most of a large run's time goes to the honest clients (every
entity's GPS fix through its client core), and that work is independent per entity. So every worker steps the
*whole* world from the run's seed (the truth is the same on every worker and in the coordinator; no car
following or crossing is ever split over a boundary, so none is missed) and runs the client cores of its share
of the entities only (`split`: by entity id). The coordinator keeps the clock, the seed, the viewers, the truth
measure and the report, and forwards what the workers' clients publish.

- `split`: which worker carries which entity, and where a dead worker's entities go (the same rule everywhere);
- `wire`: the frames between coordinator and workers (msgpack, checked on the way in);
- `coordinator`, `worker`: the two sides of the protocol as sans-IO state machines;
- `run`: a worker's share of a run (the world replica and its `Fleet`);
- `sim`: `WorkerSim`, the `Sim` whose honest clients live in workers;
- `local`, `nats_link`: the transports (forked processes over pipes; NATS), thin shells;
- `commands`: `entitynet sim --workers N / --nats URL` and `entitynet sim worker`.
"""
