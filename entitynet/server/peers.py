"""Peer addresses of accepted streams, and the key failed logins are throttled by.

The key is the peer's IP address without the port (a new connection gets a new port), and for IPv6 its /64
network (one host usually holds a whole /64, so a per-address key would be free to rotate). TLS streams are
looked through to their TCP socket, so TLS clients are throttled by their own address, not all as one.
"""

from __future__ import annotations

import ipaddress


def peer_address(stream) -> tuple[str, int] | None:
    """(host, port) of a trio SocketStream, an SSLStream over one, or a trio_websocket connection."""
    remote = getattr(stream, "remote", None)  # trio_websocket.WebSocketConnection: an Endpoint
    if remote is not None and hasattr(remote, "address"):
        return str(remote.address), int(remote.port)
    if isinstance(remote, str):  # a WebSocket over a stream that is not a socket: "host:port" or "[v6]:port"
        host, sep, port = remote.rpartition(":")
        if sep and port.isdigit() and host:
            return host.strip("[]"), int(port)
        return None
    while not hasattr(stream, "socket") and hasattr(stream, "transport_stream"):
        stream = stream.transport_stream
    sock = getattr(stream, "socket", None)
    if sock is None:
        return None
    try:
        name = sock.getpeername()
    except OSError:
        return None
    if isinstance(name, tuple) and len(name) >= 2:
        return str(name[0]), int(name[1])
    return str(name), 0  # a Unix socket


def throttle_key(host: str | None) -> str:
    """The address itself for IPv4, the /64 for IPv6; "?" when unknown."""
    if not host:
        return "?"
    try:
        ip = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        return host
    if isinstance(ip, ipaddress.IPv6Address):
        if ip.ipv4_mapped is not None:
            return str(ip.ipv4_mapped)
        return str(ipaddress.ip_network(f"{ip}/64", strict=False))
    return str(ip)
