// The page as an honest viewer client, sans-IO (entitynet/protocol.py and entitynet/client/subscriptions.py):
// bytes in with `receive(bytes, now)`, bytes out from `hello()`, `moveCamera()`, `ping()`. The shell
// (viewer.js) moves them over one WebSocket: one binary message = one payload = a msgpack array of messages.

import { decode as unpack, encode as pack } from "@msgpack/msgpack";
import { GhostStore } from "./ghosts.js";

export const PROTOCOL_VERSION = 1;
export const T = { HELLO: 1, WELCOME: 2, ERROR: 3, SUBSCRIBE: 6, UPDATE: 11, LEAVE: 12, REDIRECT: 13, PING: 15, PONG: 16 };

export class ViewerSession {
  /** cellsAt(x, y, z) -> iterable of cell ids, or null while the PVS of that view cell is being fetched. */
  constructor(net, digest, token, cellsAt) {
    this.digest = digest;
    this.token = token;
    this.cellsAt = cellsAt;
    this.ghosts = new GhostStore(net);
    this.cells = new Set();
    this.ready = false;
    this.limits = {};
    this.error = null;
    this.stats = { updates: 0, leaves: 0, bytes: 0, subscribes: 0, messages: 0 };
    this.bestRtt = Infinity;
    this.pending = [];
  }

  hello() {
    return pack([[T.HELLO, PROTOCOL_VERSION, this.token, this.digest]]);
  }

  ping(nowMs) {
    return pack([[T.PING, Math.round(nowMs)]]);
  }

  /** The SUBSCRIBE difference for a camera at (x, y, z), or null when nothing changed (or not ready). */
  moveCamera(x, y, z) {
    if (!(Number.isFinite(x) && Number.isFinite(y) && Number.isFinite(z))) throw new Error("camera must be finite");
    const next = this.cellsAt(x, y, z);
    if (next === null || !this.ready) return null;
    return this.setCells(next);
  }

  setCells(next) {
    const want = new Set(next);
    const added = [...want].filter((c) => !this.cells.has(c)).sort((a, b) => a - b);
    const removed = [...this.cells].filter((c) => !want.has(c)).sort((a, b) => a - b);
    this.cells = want;
    this.ghosts.setVisible(want);
    if (!added.length && !removed.length) return null;
    this.stats.subscribes += 1;
    return pack([[T.SUBSCRIBE, added, removed]]);
  }

  /** One WebSocket message from the server; `now` in seconds of the page clock. */
  receive(bytes, now) {
    this.stats.bytes += bytes.byteLength;
    const msgs = unpack(bytes);
    if (!Array.isArray(msgs)) throw new Error("a payload must be an array of messages");
    for (const m of msgs) {
      this.stats.messages += 1;
      switch (m[0]) {
        case T.UPDATE:
          this.stats.updates += 1;
          this.ghosts.receive({ entity: m[1], seq: m[2], cells: m[3], validityMs: m[4], payload: m[5], identity: m[6] }, now);
          break;
        case T.LEAVE:
          this.stats.leaves += 1;
          this.ghosts.receive({ entity: m[1], leave: true }, now);
          break;
        case T.WELCOME:
          this.ready = true;
          this.session = m[2];
          this.limits = m[4] || {};
          this.ghosts.ghosts.clear(); // entity ids are per server session
          this.ghosts.clockOffset = now - m[3] / 1000.0; // refined by PONG
          this.cells = new Set();
          break;
        case T.PONG: {
          const rtt = now * 1000.0 - m[1];
          if (rtt >= 0 && rtt <= this.bestRtt) {
            // the best (shortest) round trip gives the best estimate of the server clock
            this.bestRtt = rtt;
            this.ghosts.clockOffset = now - (m[2] + rtt / 2) / 1000.0;
          }
          break;
        }
        case T.ERROR:
          this.error = { code: m[1], text: m[2] };
          break;
        default:
          break; // REDIRECT, QUERY_RESULT: a single shard's viewer does not use them
      }
    }
  }
}
