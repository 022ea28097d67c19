"""Roaming with hysteresis (mixins of `ClusterCore`): viewers by their camera, publishers by a border band.

Viewers: a viewer whose client says where its camera is (CAMERA) is REDIRECTed to the shard whose region holds
the camera, not by where its subscribed cells lie.

Why the camera and not the cells: from near a border a PVS reaches deep into both regions, so a vote of cells
flips with every step along the border; the camera's position is one point with one region
(`RegionMap.region_at`, the view-grid column's). Why a margin: a camera walking along a border would still
cross it back and forth, so a shard hands a viewer on only once its camera is `camera_margin_m` deep into
another shard's area (the region at the camera and at that distance in the four axis directions all belong to
one other shard). Coming back costs the same margin the other way: a band twice the margin wide around every
border in which no viewer is moved, so a camera on a border is redirected once, not back and forth.

Publishers: a REDIRECT costs a connection, a handshake and a re-publish (and a LEAVE and a new id at every viewer),
and an entity random-walking near a border crossed it back and forth (400 REDIRECTs in a full `bench cluster` at
4 shards). So a connection whose entities have all left this shard's regions is served on here while any of
their cells lies within `publisher_margin_cells - 1` cell hops (the cell adjacency graph) of a region this shard
owns, and for at most `publisher_linger_s` after they left: the bound on how far and how long a neighbour may
serve an entity. Nothing is lost meanwhile: a shard publishes its entities' states to the subjects of their
cells wherever those lie (as for a proxy's fleet), and the region's owner subscribes to the cells its viewers
watch, so they see the entity as a mirror; snapshots, QUERY by cells and FOLLOW ask every shard for what it
owns. Without the adjacency (a map given without its topology) a publisher is redirected as soon as it is out.
"""

from __future__ import annotations

import operator
from collections.abc import Sequence
from typing import Any

import numpy as np

PUBLISHER_MARGIN_CELLS = 2  # redirected once no cell of its entities is ours or next to ours
PUBLISHER_LINGER_S = 30.0  # ... or once they have been out of our regions this long, wherever they are
CAMERA_MARGIN_M = 24.0  # a view-grid column or so: deep enough that GPS-like jitter on a border cannot bounce


class CameraRoamingMixin:
    """Uses `sb`, `regions`, `shard`, `redirect_viewers`, `redirected`, `camera_retry`, `_owners` and `_redirect`
    of `ClusterCore`."""

    camera_margin_m: float = CAMERA_MARGIN_M

    def on_camera(self, c: Any, now: float) -> None:
        """A viewer's camera moved (`c.camera`): REDIRECT it when the camera is well inside another shard's
        area. Connections that publish entities roam by their entities instead. A viewer whose camera lies in
        another shard's own region and stays here (that shard quiet, not yet heard, or dead with its region
        failed over to us) is judged again each heartbeat (`_retry_cameras`): a camera at rest sends no
        further CAMERA, so it would otherwise stay on the wrong shard for good once that shard is back."""
        self._now_hint = now
        retry = self.camera_retry
        if not self.redirect_viewers or c.entities or c.cid in self.redirected or c.camera is None:
            retry.discard(c.cid)
            return
        x, y = c.camera[0], c.camera[1]
        target = self.camera_shard(x, y, now)
        if target is not None and target != self.shard:
            self._redirect(c, target)
        home = self.regions.region_at(x, y)  # (a region's own shard has its number)
        if home is not None and home != self.shard and c.cid not in self.redirected:
            retry.add(c.cid)
        else:
            retry.discard(c.cid)

    def _retry_cameras(self, now: float) -> None:
        """From `tick`, once a heartbeat: judge again the cameras kept here in another shard's region (a
        connection that is gone drops out)."""
        retry = self.camera_retry
        if not retry:
            return
        clients = self.sb.clients
        for cid in list(retry):
            c = clients.get(cid)
            if c is None:
                retry.discard(cid)
            else:
                self.on_camera(c, now)

    def camera_shard(self, x: float, y: float, now: float) -> int | None:
        """The shard a camera at local (x, y) belongs to, with the margin: this shard unless the camera and the
        four points `camera_margin_m` away from it all lie in regions of one other shard; None without a view grid."""
        r = self.regions.region_at(x, y)
        if r is None:
            return None
        owners = self._owners(now)
        target = owners[r]
        if target == self.shard:
            return self.shard
        m = self.camera_margin_m
        for dx, dy in ((m, 0.0), (-m, 0.0), (0.0, m), (0.0, -m)):
            rr = self.regions.region_at(x + dx, y + dy)
            if rr is None or owners[rr] != target:
                return self.shard  # within the margin of a border: stay
        return target


def region_bands(cell_region: Sequence[int], adjacency: Sequence[Sequence[int]], margin: int,
                 regions: int | None = None) -> np.ndarray:
    """(regions, cells) bool: the cells within `margin - 1` hops of each region (the region itself included), by
    a breadth-first walk of the cell adjacency; `regions` rows (the map's count, which a region without cells may
    exceed). Raises ValueError on an adjacency that does not fit the map (another length, a neighbour that is
    not a cell), so a bad table is refused at start, never half used."""
    n = len(cell_region)
    if isinstance(margin, bool) or not isinstance(margin, int) or margin < 1:
        raise ValueError(f"publisher margin must be a whole number of cells >= 1, got {margin!r}")
    try:
        size = len(adjacency)
    except TypeError:
        raise ValueError("cell adjacency must be a list of neighbour lists, one per cell") from None
    if size != n:
        raise ValueError(f"cell adjacency has {size} cells, the cluster map {n}")
    nbrs: list[list[int]] = []
    for c, row in enumerate(adjacency):
        try:
            cells = [operator.index(x) for x in row]  # whole numbers only: 2.5 is no cell
        except TypeError:
            raise ValueError(f"cell adjacency of cell {c} is not a list of cells") from None
        if any(not 0 <= x < n for x in cells):
            raise ValueError(f"cell adjacency of cell {c} names a cell outside the map")
        nbrs.append(cells)
    k = int(max(cell_region, default=-1)) + 1 if regions is None else regions
    bands = np.zeros((k, n), dtype=bool)
    for r in range(k):
        band = bands[r]
        frontier = [c for c in range(n) if cell_region[c] == r]
        band[frontier] = True
        for _ in range(margin - 1):
            if not frontier:
                break  # (a huge margin: the walk ends where the graph does)
            nxt = [x for c in frontier for x in nbrs[c] if not band[x]]
            band[nxt] = True
            frontier = nxt
    return bands


class PublisherRoamingMixin:
    """Uses `sb`, `shard`, `region_of`, `held`, `heartbeat_s`, `max_redirect_entities`, `redirected`, `_owners`,
    `_quiet`, `_heard_since`, `_redirect` and `stats` of `ClusterCore`;
    `init_publisher_roaming` is called from its constructor."""

    def init_publisher_roaming(self, adjacency: Sequence[Sequence[int]] | None, margin: int, linger_s: float) -> None:
        """The bands (None without an adjacency) and the time bound; bad values raise ValueError."""
        if not (isinstance(linger_s, int | float) and linger_s >= 0 and linger_s != float("inf")):
            raise ValueError(f"publisher linger must be a finite number of seconds >= 0, got {linger_s!r}")
        self.publisher_linger_s = float(linger_s)
        self._bands = None if adjacency is None else region_bands(self.region_of, adjacency, margin,
                                                                       self.regions.shards)
        self._near: tuple[tuple[int, ...], list[bool]] | None = None  # (owners, cell -> within our band)
        self.out_since: dict[int, float] = {}  # cid -> since when all its entities are out of our regions
        self._next_linger = float("inf")  # when `_roam_lingering` next has a linger to end

    def _near_cells(self, owners: list[int]) -> list[bool] | None:
        """Cell -> within the band of a region this shard owns now (recomputed when ownership changes)."""
        if self._bands is None:
            return None
        key = tuple(owners)
        if self._near is None or self._near[0] != key:
            mine = [r for r, s in enumerate(owners) if s == self.shard]
            near = self._bands[mine].any(axis=0) if mine else np.zeros(self._bands.shape[1], dtype=bool)
            self._near = (key, near.tolist())
        return self._near[1]

    def _in_band_of_unsure_shard(self, cells: Sequence[int], owners: list[int], now: float, since: float,
                                 quiet: bool = True) -> bool:
        """Whether another shard may still be serving an entity in `cells` from within its band while we cannot
        tell it is alive: not heard since the client came (a client failing over arrives before its shard is
        quiet) or, unless `quiet` is False, quiet (dying?). Admitted, it would be shown beside the copy that
        shard still publishes, so it is held (`admit`) until that shard is heard (asked for its heartbeat at
        once: a NATS round trip) or declared dead; also a client its old shard REDIRECTed, which a shard cannot
        tell from a client failing over (both are new connections whose old shard was last heard before they
        came)."""
        bands = self._bands
        if bands is None:
            return False
        for r, s in enumerate(owners):
            if (s != self.shard and ((quiet and self._quiet(s, now)) or not self._heard_since(s, since))
                    and any(bands[r, cell] for cell in cells)):
                return True
        return False

    def _connection_cells(self, c: Any, cells: Sequence[int]) -> list[int]:
        """`cells` and those of every entity of the connection, admitted or held: a shard serves all of a
        connection's entities while any one of them is in its band, so the others may be anywhere."""
        entities = self.sb.entities
        out = list(cells)
        for eid in c.entities.values():
            e = entities.get(eid)
            if e is not None:
                out.extend(e.cells)
        for m, _at in self.held.get(c.cid, {}).values():
            out.extend(m.cells)
        return out

    def _roam_publisher(self, c: Any, e: Any, now: float) -> None:
        """After a local entity's new state: REDIRECT its connection when all its entities are out of our
        regions and beyond the band (or out for `publisher_linger_s`). A fleet (> `max_redirect_entities`)
        stays where it is."""
        if not e.cells or len(c.entities) > self.max_redirect_entities:
            return
        owners = self._owners(now)
        region_of = self.region_of
        me = self.shard
        entities = self.sb.entities
        cells = [cell for eid in c.entities.values() if (x := entities.get(eid)) is not None for cell in x.cells]
        if any(owners[region_of[cell]] == me for cell in cells):
            self.out_since.pop(c.cid, None)  # something of this connection is still ours
            return
        since = self.out_since.get(c.cid)
        if since is None:
            since = self.out_since[c.cid] = now
            self._next_linger = min(self._next_linger, now + self.publisher_linger_s)
        near = self._near_cells(owners)
        if near is not None and now - since < self.publisher_linger_s and any(near[cell] for cell in cells):
            self.stats["publishers_in_band"] += 1  # served on here: a state of an entity just over the border
            return
        self._redirect(c, owners[region_of[e.cells[0]]])
        if c.cid in self.redirected:
            del self.out_since[c.cid]

    def _roam_lingering(self, now: float) -> None:
        """From `tick`: end the lingers that ran out (a parked entity may send nothing but PINGs for as long as
        its validity lasts, so its next PUBLISH cannot be waited for): its connection is judged as after a
        new state, REDIRECTed unless something of it came back into our regions. A REDIRECT that cannot go
        now (its target quiet) is tried again a heartbeat later."""
        if now < self._next_linger:
            return
        clients, entities, linger = self.sb.clients, self.sb.entities, self.publisher_linger_s
        for cid, since in list(self.out_since.items()):
            if now - since < linger:
                continue
            c = clients.get(cid)
            e = None if c is None else next((x for eid in c.entities.values()
                                             if (x := entities.get(eid)) is not None and x.cells), None)
            if e is None or cid in self.redirected or len(c.entities) > self.max_redirect_entities:
                del self.out_since[cid]  # gone, moved on, or no longer one to redirect
                continue
            self._roam_publisher(c, e, now)
        due = [t + linger for t in self.out_since.values()]
        self._next_linger = min((t if t > now else now + self.heartbeat_s for t in due), default=float("inf"))

    def _linger_deadline(self) -> float:
        """When `tick` must next run for `_roam_lingering`."""
        return self._next_linger

    def _forget_gone_publishers(self) -> None:
        """Drop the out-of-region times of connections that are gone (called now and then from `tick`)."""
        clients = self.sb.clients
        for cid in [x for x in self.out_since if x not in clients]:
            del self.out_since[cid]
