"""The Player's whole output pinned: every message, the inferred place and the update reasons of many walks.

Splitting the client core into parts (tracker, coverage, update rules, world-frame baselines) must not change
one decision. These walks (every model, three entity types, with and without an a-priori route and stops,
Doppler velocities, turns back, pauses, fix gaps long enough to halt and to lose the entity) are replayed and
digested; the digests were recorded on the single-class Player (main 5a35715) before the split, and recorded again
where a rule changed on purpose (issue 20: the look-ahead, the lateral reach, a stop where the model halts).
Run `python -m tests.entitynet.client.test_player_replay` to print them; player_replay_digests.json holds them.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path as FilePath

import numpy as np

from entitynet.client import MODELS, Player, netview
from entitynet.client.path import Path
from tests.entitynet.client_fixtures import area_square, chain, cross, hairpin, parallel
from topology.raw import PEDESTRIAN, VEHICLE

TOPOS = {"cross": cross(arm=100.0), "parallel": parallel(gap=12.0, length=300.0), "chain": chain(),
         "hairpin": hairpin(), "area": area_square()}


def _walk_path(net, rng: np.random.Generator, networks: int) -> Path:
    """A walk of up to 8 directed edges (U-turns only where there is no other way)."""
    edges = [e for e in range(net.n_edges) if net.edge_net[e] & networks]
    out = [(int(rng.choice(edges)), int(rng.choice([1, -1])))]
    for _ in range(int(rng.integers(0, 8))):
        nxt = net.choices(out[-1], networks)
        if not nxt:
            break
        out.append(nxt[int(rng.integers(0, len(nxt)))])
    return Path(net, out)


def replay(name: str, model: str, etype: str, with_route: bool, seed: int) -> str:
    """One walk's digest: the messages of every fix and tick, the inferred place, and the final stats."""
    topo = TOPOS[name]
    net = netview(topo)
    rng = np.random.default_rng(seed)
    networks = PEDESTRIAN if name == "area" or etype == "pedestrian" else VEHICLE
    path = _walk_path(net, rng, networks)
    route = path.edges if with_route else None
    stops = [(path.edges[-1][0], 0.5 * float(net.edge_len[path.edges[-1][0]]))] if with_route else ()
    p = Player(topo, 1, etype, model=model, route=route, stops=stops, accuracy=5.0, max_gap=6.0, lost_after=25.0,
               lookahead=150.0)  # the look-ahead the digests were recorded with (the default is 40 m since issue 11)
    h = hashlib.sha256()
    s, v = 0.0, float(rng.uniform(0.0, 10.0))
    doppler = bool(rng.random() < 0.5)
    t = 0.0
    for _ in range(120):
        t += 1.0
        u = rng.random()
        if u < 0.05:
            v = -v if rng.random() < 0.4 else float(rng.uniform(0.0, 10.0))
        elif u < 0.08:
            v = 0.0
        s = min(max(s + v, 0.0), path.length)
        if rng.random() < 0.03:  # a fix gap: ticks only, long enough to halt (6 s) or to lose (25 s) it
            for _k in range(int(rng.choice([4, 10, 30]))):
                out = p.tick(t)
                h.update(repr(("tick", t, out)).encode())
                t += 1.0
        x, y = path.xy(s)
        x, y = x + float(rng.normal(0.0, 4.0)), y + float(rng.normal(0.0, 4.0))
        if doppler:
            out = p.feed(x, y, t, speed=abs(v), heading=float(rng.uniform(0.0, 360.0)) if v else None,
                         speed_accuracy=0.7)
        else:
            out = p.feed(x, y, t)
        h.update(repr((t, out, p.inferred)).encode())
        out = p.tick(t + 0.5)
        h.update(repr(("tick", out)).encode())
    h.update(repr(sorted(p.stats.items())).encode())
    return h.hexdigest()[:16]


def all_digests() -> dict[str, str]:
    """Every walk's digest by a readable key, and one over them all."""
    out = {}
    for name in TOPOS:
        for model in MODELS:
            for etype in ("car", "pedestrian", "tram"):
                if name == "area" and etype != "pedestrian":
                    continue
                for with_route in (False, True):
                    for seed in range(3):
                        key = f"{name}/{model}/{etype}/{'route' if with_route else 'free'}/{seed}"
                        out[key] = replay(name, model, etype, with_route, seed)
    out["all"] = hashlib.sha256(repr(sorted(out.items())).encode()).hexdigest()[:16]
    return out


REFERENCE = FilePath(__file__).with_name("player_replay_digests.json")


def test_every_walk_gives_the_recorded_messages():
    want = json.loads(REFERENCE.read_text())
    got = all_digests()
    assert len(want) == len(got) > 300
    changed = sorted(k for k in want if got.get(k) != want[k])
    assert not changed, f"{len(changed)} walks changed, e.g. {changed[:5]}"


if __name__ == "__main__":
    for k, d in all_digests().items():
        print(k, d)
