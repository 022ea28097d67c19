// The published model from an UPDATE's opaque payload: entitynet/client/payload.py `decode`, ported.
// Quantised integers on the wire (cm, mm/s, mm/s^2, ms); the same validation and the same per-type speed cap
// (a publisher's speed beyond its type's cap is not believed).

import { decode as unpack } from "@msgpack/msgpack";
import { AreaModel, INF, KIND_AREA, KIND_NETWORK, KIND_WORLD, NetworkModel, Path, WorldModel, maxSpeed } from "./motion.js";

export const VERSION = 1;

export class PayloadError extends Error {}

function ints(xs, n) {
  if (!Array.isArray(xs) || (n !== undefined && xs.length !== n)) throw new PayloadError("malformed payload");
  for (const x of xs) {
    if (typeof x !== "number" || !Number.isInteger(x)) throw new PayloadError("malformed payload: expected integers");
  }
  return xs;
}

/** The model in payload bytes (Uint8Array). Network models need the NetView (`net`). */
export function decodePayload(bytes, net) {
  let body;
  try {
    body = unpack(bytes);
  } catch (exc) {
    throw new PayloadError(`not a msgpack payload (${exc.name})`);
  }
  if (!Array.isArray(body) || body.length < 4 || body[0] !== VERSION) {
    throw new PayloadError("unknown payload version or shape");
  }
  const kind = body[1];
  if (kind === KIND_NETWORK) {
    if (body.length !== 12) throw new PayloadError("malformed network payload");
    let [t0, etype, s0, v, a, vmax] = ints(body.slice(2, 8), 6);
    const [stop, brake] = ints(body.slice(10, 12), 2);
    const parts = ints(body[8]);
    const signed = ints(body[9]);
    if (!net) throw new PayloadError("a network payload needs the topology");
    if (!signed.length || v < 0 || vmax < 0 || brake <= 0 || stop < -1 || parts.some((p) => p < 0)) {
      throw new PayloadError("malformed network payload values");
    }
    const cap = Math.round(maxSpeed(etype) * 1000.0);
    v = Math.min(v, cap);
    vmax = Math.min(vmax, cap);
    let path;
    try {
      path = new Path(net, signed.filter((x) => x !== 0).map((x) => [Math.abs(x) - 1, x > 0 ? 1 : -1]));
    } catch (exc) {
      throw new PayloadError(exc.message);
    }
    return new NetworkModel(t0 / 1000.0, path, s0 / 100.0, v / 1000.0, a / 1000.0, vmax / 1000.0, etype,
      parts.map((p) => p / 100.0), stop >= 0 ? stop / 100.0 : INF, brake / 1000.0);
  }
  if (kind === KIND_AREA) {
    const [t0, etype, area, x, y, vx, vy] = ints(body.slice(2), 7);
    return new AreaModel(t0 / 1000.0, area, x / 100.0, y / 100.0, vx / 1000.0, vy / 1000.0, etype);
  }
  if (kind === KIND_WORLD) {
    const [t0, etype, x, y, vx, vy, ax, ay] = ints(body.slice(2), 8);
    return new WorldModel(t0 / 1000.0, x / 100.0, y / 100.0, vx / 1000.0, vy / 1000.0, ax / 1000.0, ay / 1000.0, etype);
  }
  throw new PayloadError(`unknown model kind ${kind}`);
}
