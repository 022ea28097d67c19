"""Eclipse SUMO as a mobility source (issue 26): a traffic engineer's scenario drives the honest clients.

- `source`: `SumoSource`, a SUMO scenario stepped in process through libsumo as `Sim`'s mobility source
  (`sims.engine.source`); each vehicle and person an entity of the matching type;
- `truth`: the SUMO entities' truth as the fleet and the measure read it (positions in our local coordinates,
  true cells by placement on our network, positions off our network counted);
- `scenario`: a scenario from the bundled map (netconvert in the artifact's projection, random trips, the
  public transport lines of the map at the bundled GTFS feed's frequencies), cached;
- `commands`: `entitynet sumo scenario`;
- `compare`: SUMO's step time per vehicle-second against our world's on the same network (`bench sim`).

Everything SUMO is optional (the `[sumo]` extra: eclipse-sumo and libsumo); `missing()` says why it cannot run.
"""

from __future__ import annotations


class SumoError(Exception):
    """A SUMO scenario that cannot be used here (not installed, unreadable, off the map): a clear message."""


def missing() -> str | None:
    """Why SUMO cannot run here (the extra is not installed), or None when libsumo and the SUMO tools import."""
    try:
        import libsumo  # noqa: F401
        import sumo  # noqa: F401
    except ImportError as exc:
        return (f"SUMO is not installed ({exc.name or exc}): pip install 'entitynet[sumo]' "
                "(eclipse-sumo and libsumo)")
    return None


def sumo_home() -> str:
    """SUMO_HOME of the installed eclipse-sumo wheel (binaries in bin/, tools in tools/, type maps in data/)."""
    err = missing()
    if err:
        raise SumoError(err)
    import sumo

    return sumo.SUMO_HOME
