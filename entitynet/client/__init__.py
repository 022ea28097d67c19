"""The honest client library: sans-IO cores fed fixes and `now`, returning protocol messages to send.

Public API (see docs/dead-reckoning.md):
- `Player(topo, entity, etype, model=..., route=...)`: `.feed(x, y, t, accuracy)`, `.tick(now)`, `.leave()`;
  its parts: `NetworkTracker`, `Coverage`, `UpdateRules` (with an injectable `Estimate`), world-frame baselines
- `GhostStore(net)`: `.receive(update, now)`, `.set_visible(cells)`, `.positions(now)`
- `Subscriptions(cells_at)`: `.move_camera(x, y, z)`, `.follow(entity)`, `.query(now, ...)`
- `occupy(...)`, `time_to_travel(...)`, `encode(model)` / `decode(payload, net)`, `netview(topo)`
"""

from entitynet.client.entities import TYPES, EntityType, entity_type
from entitynet.client.ghosts import Ghost, GhostStore
from entitynet.client.kinematics import advance, time_to_travel
from entitynet.client.modes import ModelKind, Place
from entitynet.client.motion import AreaModel, NetworkModel, WorldModel
from entitynet.client.network import NetView, netview
from entitynet.client.occupation import Occupation, occupy, occupy_area
from entitynet.client.path import Path, follow
from entitynet.client.payload import PayloadError, decode, encode
from entitynet.client.player import MODELS, FixRejected, Player
from entitynet.client.rules import OWN_ESTIMATE, Estimate
from entitynet.client.subscriptions import LimitExceeded, Subscriptions

__all__ = [
    "TYPES", "EntityType", "entity_type", "Ghost", "GhostStore", "advance", "time_to_travel", "AreaModel",
    "NetworkModel", "WorldModel", "NetView", "netview", "Occupation", "occupy", "occupy_area", "Path", "follow",
    "PayloadError", "decode", "encode", "MODELS", "ModelKind", "Place", "Estimate", "OWN_ESTIMATE", "FixRejected",
    "Player", "LimitExceeded", "Subscriptions",
]
