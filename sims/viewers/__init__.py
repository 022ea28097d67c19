"""Viewers in their own processes (`entitynet sim --viewer-processes K`, issue 23 item 1).

Each viewer process holds a share of the run's viewers with their own server connections, steps the run's
truth itself from the seed (as every worker does, `sims.workers.run`), and measures its viewers against it;
the coordinator sends it each tick (with the payloads its publishers sent, which name the server's entity ids)
and gathers the measures for the report. `wire`: the frames; `share`: a process's viewers and truth (sans-IO);
`child`: the forked process; `procs`: the coordinator's side.
"""
