"""Viewers roam by their camera (a mixin of `ClusterCore`): a viewer whose client says where its camera is
(CAMERA) is REDIRECTed to the shard whose region holds the camera, not by where its subscribed cells lie.

Why the camera and not the cells: from near a border a PVS reaches deep into both regions, so a vote of cells
flips with every step along the border; the camera's position is one point with one region
(`RegionMap.region_at`, the view-grid column's). Why a margin: a camera walking along a border would still
cross it back and forth, so a shard hands a viewer on only once its camera is `camera_margin_m` deep into
another shard's area (the region at the camera and at that distance in the four axis directions all belong to
one other shard). Coming back costs the same margin the other way: a band twice the margin wide around every
border in which no viewer is moved, so a camera on a border is redirected once, not back and forth.
"""

from __future__ import annotations

from typing import Any

CAMERA_MARGIN_M = 24.0  # a view-grid column or so: deep enough that GPS-like jitter on a border cannot bounce


class CameraRoamingMixin:
    """Uses `regions`, `shard`, `redirect_viewers`, `redirected`, `_owners` and `_redirect` of `ClusterCore`."""

    camera_margin_m: float = CAMERA_MARGIN_M

    def on_camera(self, c: Any, now: float) -> None:
        """A viewer's camera moved (`c.camera`): REDIRECT it when the camera is well inside another shard's
        area. Connections that publish entities roam by their entities instead."""
        self._now_hint = now
        if not self.redirect_viewers or c.entities or c.cid in self.redirected or c.camera is None:
            return
        target = self.camera_shard(c.camera[0], c.camera[1], now)
        if target is not None and target != self.shard:
            self._redirect(c, target)

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
