// The receiver's ghost store: entitynet/client/ghosts.py, ported.
// An entity whose cells become invisible is kept until its validity runs out (it reappears at once when the
// camera bobs back), dropped on expiry, on LEAVE, or replaced by a newer UPDATE; older seqs are ignored; a ghost
// lives at most HORIZON seconds whatever validity it claims. Bad payloads are counted, never thrown.

import { LIMITS } from "./motion.js";
import { decodePayload, PayloadError } from "./payload.js";

export class GhostStore {
  /** clockOffset: receiver time minus publisher time (seconds), from WELCOME and PONG. */
  constructor(net, clockOffset = 0.0) {
    this.net = net;
    this.clockOffset = clockOffset;
    this.ghosts = new Map();
    this.visibleCells = new Set();
    this.badPayloads = 0;
  }
  get size() {
    return this.ghosts.size;
  }
  /** An UPDATE {entity, seq, cells, validityMs, payload, identity} or a LEAVE {entity, leave: true}. */
  receive(msg, now) {
    if (msg.leave) {
      this.ghosts.delete(msg.entity);
      return;
    }
    const old = this.ghosts.get(msg.entity);
    if (old !== undefined && msg.seq <= old.seq) return;
    let model;
    try {
      model = decodePayload(msg.payload, this.net);
    } catch (exc) {
      if (!(exc instanceof PayloadError)) throw exc;
      this.badPayloads += 1;
      return;
    }
    const life = Math.min(msg.validityMs / 1000.0, LIMITS.horizon);
    this.ghosts.set(msg.entity, {
      entity: msg.entity, seq: msg.seq, cells: msg.cells, expires: now + life, model, identity: msg.identity ?? null,
    });
  }
  setVisible(cells) {
    this.visibleCells = new Set(cells);
  }
  expire(now) {
    const gone = [];
    for (const [e, g] of this.ghosts) if (now >= g.expires) gone.push(e);
    for (const e of gone) this.ghosts.delete(e);
    return gone;
  }
  isVisible(g) {
    for (const c of g.cells) if (this.visibleCells.has(c)) return true;
    return false;
  }
  /** The ghosts to draw now (expired ones dropped first) and the time their models are evaluated at. */
  visible(now, visibleOnly = true) {
    if (!Number.isFinite(now)) throw new Error(`now must be finite, got ${now}`);
    this.expire(now);
    const out = [];
    for (const g of this.ghosts.values()) if (!visibleOnly || this.isVisible(g)) out.push(g);
    return { ghosts: out, t: now - this.clockOffset };
  }
}
