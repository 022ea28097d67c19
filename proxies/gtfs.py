"""GTFS reading and matching moved to `topology.gtfs` (the arrows run topology <- entitynet <- proxies, and
the benchmarks in `sims` need it too); this name stays as a thin re-export for the transit proxies, which
read their schedules through `proxies.gtfs`."""

from topology.gtfs import *  # noqa: F403
from topology.gtfs import STOP_SHAPE, Feed, GtfsError, MatchedShape, match_shapes, read_feed, trip_stops

__all__ = ["STOP_SHAPE", "Feed", "GtfsError", "MatchedShape", "match_shapes", "read_feed", "trip_stops"]
