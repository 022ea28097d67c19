"""The shard server: a thin trio shell (TCP, WebSocket, TLS, metrics) around the switchboard core."""

from entitynet.server.app import ConfigError, Server, serve, serve_until_signal
from entitynet.server.config import ServerConfig

__all__ = ["ConfigError", "Server", "ServerConfig", "serve", "serve_until_signal"]
