"""The client session: protocol v1's client side as a sans-IO core (no trio, no sockets, no geometry).

Kept out of `entitynet.client` so that the trio connection, proxies and viewers can use it without loading the
honest-client core (numpy, topology). `entitynet.connection.Connection` is its trio shell.
"""

from entitynet.session.clock import ClockEstimate
from entitynet.session.events import Action, Answer, Connect, Deliver, Drop, Notice, Send, Stop
from entitynet.session.policy import REFUSALS, Address, ReconnectPolicy, parse_address
from entitynet.session.session import ClientSession

__all__ = [
    "ClockEstimate", "Action", "Answer", "Connect", "Deliver", "Drop", "Notice", "Send", "Stop", "REFUSALS",
    "Address", "ReconnectPolicy", "parse_address", "ClientSession",
]
