"""entitynet: dynamic entities on mobile 3D city maps (honest clients, switchboard servers)."""

__version__ = "0.1.0"
