"""Subscriptions of the switchboard core: SUBSCRIBE diffs (with the churn budget), FOLLOW and UNFOLLOW.

A mixin of `Switchboard` (entitynet.switchboard.core), split off to keep each module to one job: what a
change of a client's cells or follows does to the tables, and which snapshots and LEAVEs it queues. Every
changed cell costs work proportional to its occupants, so the cells added + removed per second are bounded
per client by a token bucket (`churn_rate`, `churn_burst`): one client cannot make the switch busy for long.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from entitynet import protocol as P
from entitynet.protocol import ErrorCode

if TYPE_CHECKING:
    from entitynet.switchboard.tables import ClientState


class SubscriptionsMixin:
    """SUBSCRIBE / FOLLOW / UNFOLLOW handling; uses the tables and helpers of `Switchboard`."""

    def _subscribe(self, c: ClientState, m: P.Subscribe, now: float) -> None:
        n = self.config.n_cells
        for cell in (*m.added, *m.removed):
            if cell >= n:
                self._error(c, ErrorCode.NO_SUCH_CELL, f"cell {cell} does not exist (this map has {n})")
                return
        old = c.subs
        new = (old - set(m.removed)) | set(m.added)
        if len(new) > self.config.max_subscriptions:
            self._error(
                c, ErrorCode.LIMIT_SUBSCRIPTIONS,
                f"{len(new)} cells > limit {self.config.max_subscriptions}; subscription unchanged",
            )
            return
        removed = old - new
        added = new - old
        churn = len(removed) + len(added)
        if churn and not c.churn.take(now, churn):
            cfg = self.config
            self.stats["churn_refused"] += 1
            self._error(
                c, ErrorCode.LIMIT_CHURN,
                f"subscription change of {churn} cells refused: over the budget of {cfg.churn_rate:g} cells/s "
                f"(burst {cfg.churn_burst:g}); subscription unchanged",
            )
            return
        cid = c.cid
        subs = self.subscribers
        if removed or added:
            self._tick += 1
            tick = self._tick
            cell_tick = self._cell_tick
        for cell in removed:
            s = subs[cell]
            s.discard(cid)
            if not s:
                del subs[cell]
            cell_tick[cell] = tick
        for cell in added:
            s = subs.get(cell)
            if s is None:
                subs[cell] = self._viewer_set((cid,))
            else:
                s.add(cid)
            cell_tick[cell] = tick
        c.subs = new
        occ = self.occupants
        ents = self.entities
        if removed:
            cand: set[int] = set()
            for cell in removed:
                o = occ.get(cell)
                if o:
                    cand |= o
            gone = [
                eid for eid in cand
                if cid in ents[eid].viewers and cid not in ents[eid].followers
                and new.isdisjoint(ents[eid].cells)
            ]
            for eid in gone:
                ents[eid].viewers.discard(cid)
                self._leave(eid, {cid})
        if added:
            cand = set()
            for cell in added:
                o = occ.get(cell)
                if o:
                    cand |= o
            put = c.outbox.put_state
            n_snap = 0
            for eid in cand:
                e = ents[eid]
                if cid in e.viewers or e.owner is c:
                    continue
                e.viewers.add(cid)
                put(eid, self._encoded_for(e, c))
                n_snap += 1
            if n_snap:
                self._dirty.add(cid)
                self.stats["snapshots"] += n_snap
        if self.cluster is not None and (removed or added):
            self.cluster.on_subscribe(c, now)

    def _follow(self, c: ClientState, m: P.Follow) -> None:
        e = self.entities.get(m.entity)
        if e is None:
            if self.cluster is not None and self.cluster.follow_remote(c, m.entity):
                return  # another shard may own it: the cluster asks, and follows it here if it does
            self._error(c, ErrorCode.NO_SUCH_ENTITY, f"no entity {m.entity}")
            return
        if m.entity in c.follows:
            return
        if len(c.follows) >= self.config.max_follows:
            self._error(c, ErrorCode.LIMIT_FOLLOWS, f"at most {self.config.max_follows} direct subscriptions")
            return
        c.follows.add(m.entity)
        e.followers.add(c.cid)
        e.viewers_tick = -1
        if c.cid not in e.viewers and e.owner is not c:
            e.viewers.add(c.cid)
            c.outbox.put_state(e.eid, self._encoded_for(e, c))
            self._dirty.add(c.cid)

    def _unfollow(self, c: ClientState, m: P.Unfollow) -> None:
        if m.entity not in c.follows:
            self._error(c, ErrorCode.NO_SUCH_ENTITY, f"you do not follow {m.entity}")
            return
        c.follows.discard(m.entity)
        e = self.entities.get(m.entity)
        if e is None:
            return
        e.followers.discard(c.cid)
        e.viewers_tick = -1
        if c.cid in e.viewers and c.subs.isdisjoint(e.cells):
            e.viewers.discard(c.cid)
            self._leave(e.eid, {c.cid})
