"""The switchboard core: sans-IO tables and forwarding (no sockets, no clock, no geometry).

Fed decoded protocol messages and an explicit `now`; produces encoded messages in per-client outboxes
that an I/O shell (entitynet.server) writes out.
"""

from entitynet.switchboard.config import SwitchConfig
from entitynet.switchboard.core import Switchboard
from entitynet.switchboard.outbox import Outbox

__all__ = ["Outbox", "SwitchConfig", "Switchboard"]
