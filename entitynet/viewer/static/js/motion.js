// Dead reckoning exactly as the Python client does it: entitynet/client/{kinematics,limits,path,motion}.py.
// Every receiver must extrapolate a published model the same way, so this is a line-by-line port (same
// branches, same formulas, same clamps); the golden vectors in tests/entitynet/viewer/js/ hold it to 1 mm.

export const INF = Infinity;
const A_EPS = 1e-9;

// ---- limits (entitynet/client/limits.py); the server's config.json carries the Python values -----------------
export const LIMITS = {
  horizon: 90.0,
  maxSpeedDefault: 40.0,
  maxSpeed: { 0: 8.0, 1: 40.0, 2: 25.0, 3: 20.0, 4: 15.0 },
};

/** Adopt the limits of geometry.json's `limits` (entitynet/viewer/geometry.py `extrapolation_limits`). */
export function configureLimits(limits) {
  LIMITS.horizon = limits.horizon;
  LIMITS.maxSpeedDefault = limits.max_speed_default;
  LIMITS.maxSpeed = {};
  for (const [code, v] of Object.entries(limits.max_speed)) LIMITS.maxSpeed[Number(code)] = v;
}

export function maxSpeed(etype) {
  const v = LIMITS.maxSpeed[etype];
  return v === undefined ? LIMITS.maxSpeedDefault : v;
}

export function horizonDt(dt) {
  if (dt <= 0.0) return 0.0;
  return dt < LIMITS.horizon ? dt : LIMITS.horizon;
}

export function cappedVelocity(vx, vy, cap) {
  const speed = Math.hypot(vx, vy);
  if (speed <= cap) return [vx, vy];
  const f = cap / speed;
  return [vx * f, vy * f];
}

export function worldState(vx, vy, ax, ay, cap, dt) {
  const a2 = ax * ax + ay * ay;
  const v2 = vx * vx + vy * vy;
  if (v2 > cap * cap) {
    [vx, vy] = cappedVelocity(vx, vy, cap);
    return [vx * dt, vy * dt, vx, vy];
  }
  if (a2 === 0.0) return [vx * dt, vy * dt, vx, vy];
  const va = vx * ax + vy * ay;
  const tCap = (-va + Math.sqrt(Math.max(va * va - a2 * (v2 - cap * cap), 0.0))) / a2;
  if (dt <= tCap) {
    const h = 0.5 * dt * dt;
    return [vx * dt + ax * h, vy * dt + ay * h, vx + ax * dt, vy + ay * dt];
  }
  const h = 0.5 * tCap * tCap;
  const wx = vx + ax * tCap;
  const wy = vy + ay * tCap;
  const rest = dt - tCap;
  return [vx * tCap + ax * h + wx * rest, vy * tCap + ay * h + wy * rest, wx, wy];
}

// ---- kinematics (entitynet/client/kinematics.py) -------------------------------------------------------------
function zeroSmall(a) {
  return -A_EPS < a && a < A_EPS ? 0.0 : a;
}

/** [distance, speed] after dt >= 0 s from speed v >= 0 with acceleration a, speed capped at vmax. */
export function advance(v, a, vmax, dt) {
  if (dt <= 0.0) return [0.0, v];
  a = zeroSmall(a);
  if (a < 0.0) {
    const tStop = v / -a;
    if (dt >= tStop) return [v * tStop + 0.5 * a * tStop * tStop, 0.0];
    return [v * dt + 0.5 * a * dt * dt, v + a * dt];
  }
  if (a > 0.0 && v < vmax) {
    const tCap = (vmax - v) / a;
    if (dt <= tCap) return [v * dt + 0.5 * a * dt * dt, v + a * dt];
    return [v * tCap + 0.5 * a * tCap * tCap + vmax * (dt - tCap), vmax];
  }
  return [v * dt, v];
}

/** [t_brake, deceleration]: when to start braking at b to stop d metres ahead (kinematics.brake_plan). */
export function brakePlan(v, a, vmax, d, b) {
  a = zeroSmall(a);
  if (!(d > 0.0 && b > 0.0)) return d <= 0.0 && v > 0.0 ? [0.0, INF] : [INF, b];
  if (v * v >= 2.0 * b * d) return [0.0, v > 0.0 ? (v * v) / (2.0 * d) : b];
  let t0;
  if (a !== 0.0 && !(a > 0.0 && v >= vmax)) {
    const tEnd = a > 0.0 ? (vmax - v) / a : v / -a;
    const qa = a * (a + b);
    const qb = 2.0 * v * (a + b);
    const qc = v * v - 2.0 * b * d;
    const roots = [];
    const disc = qb * qb - 4.0 * qa * qc;
    if (disc >= 0.0) {
      const q = -0.5 * (qb + (qb < 0 || Object.is(qb, -0) ? -Math.sqrt(disc) : Math.sqrt(disc)));
      if (q !== 0.0) roots.push(qc / q);
      if (qa !== 0.0) roots.push(q / qa);
    }
    const ts = roots.filter((t) => t >= 0.0 && t <= tEnd);
    if (ts.length) return [Math.min(...ts), b];
    if (a < 0.0) return [INF, b];
    const sCap = v * tEnd + 0.5 * a * tEnd * tEnd;
    v = vmax;
    t0 = tEnd;
    d = d - sCap;
  } else {
    t0 = 0.0;
  }
  if (v <= 0.0) return [INF, b];
  return [t0 + Math.max((d - (v * v) / (2.0 * b)) / v, 0.0), b];
}

// ---- the network and paths (entitynet/client/network.py, path.py) --------------------------------------------
/** geometry.json's `net`: edge endpoints, lengths and polylines, exactly as the artifact stores them. */
export class NetView {
  constructor(net) {
    this.nEdges = net.n_edges;
    this.edgeFrom = net.edge_from;
    this.edgeTo = net.edge_to;
    this.edgeLen = net.edge_len;
    this.edgeNet = net.edge_net;
    this.geomOff = net.geom_off;
    this.gx = net.gx;
    this.gy = net.gy;
    this.gcum = net.gcum;
  }
  startNode([e, d]) {
    return d > 0 ? this.edgeFrom[e] : this.edgeTo[e];
  }
  endNode([e, d]) {
    return d > 0 ? this.edgeTo[e] : this.edgeFrom[e];
  }
}

/** Index of the last element <= x in the sorted slice a[lo:hi] plus one (Python's bisect_right). */
function bisectRight(a, x, lo = 0, hi = a.length) {
  while (lo < hi) {
    const mid = (lo + hi) >> 1;
    if (x < a[mid]) hi = mid;
    else lo = mid + 1;
  }
  return lo;
}

export class Path {
  /** Directed edges [[edge, dir], ...]; throws when an edge is not in the map or two do not meet. */
  constructor(net, edges) {
    if (!edges.length) throw new Error("a path needs at least one edge");
    this.net = net;
    this.edges = edges.map(([e, d]) => [e, d > 0 ? 1 : -1]);
    const cum = [0.0];
    for (const [e] of this.edges) {
      if (!(Number.isInteger(e) && e >= 0 && e < net.nEdges)) throw new Error(`edge ${e} is not in the topology`);
      cum.push(cum[cum.length - 1] + net.edgeLen[e]);
    }
    this.cum = cum;
    for (let i = 1; i < this.edges.length; i++) {
      if (net.endNode(this.edges[i - 1]) !== net.startNode(this.edges[i])) {
        throw new Error(`path edges ${this.edges[i - 1]} and ${this.edges[i]} do not meet at a node`);
      }
    }
  }
  get length() {
    return this.cum[this.cum.length - 1];
  }
  xy(s) {
    const cum = this.cum;
    let k = bisectRight(cum, s) - 1;
    if (k < 0) k = 0;
    else if (k >= this.edges.length) k = this.edges.length - 1;
    const [e, dir] = this.edges[k];
    const net = this.net;
    const length = net.edgeLen[e];
    let d = s - cum[k];
    d = d < 0.0 ? 0.0 : d > length ? length : d;
    const offset = dir > 0 ? d : length - d;
    const lo = net.geomOff[e];
    const hi = net.geomOff[e + 1];
    if (offset <= 0.0) return [net.gx[lo], net.gy[lo]];
    const gcum = net.gcum;
    if (offset >= gcum[hi - 1]) return [net.gx[hi - 1], net.gy[hi - 1]];
    let j;
    if (hi - lo === 2) j = lo;
    else j = Math.min(Math.max(bisectRight(gcum, offset, lo, hi) - 1, lo), hi - 2);
    const c0 = gcum[j];
    const seg = gcum[j + 1] - c0;
    const t = seg <= 0.0 ? 0.0 : (offset - c0) / seg;
    const x0 = net.gx[j];
    const y0 = net.gy[j];
    return [x0 + t * (net.gx[j + 1] - x0), y0 + t * (net.gy[j + 1] - y0)];
  }
}

// ---- models (entitynet/client/motion.py) ---------------------------------------------------------------------
export const KIND_NETWORK = 1;
export const KIND_AREA = 2;
export const KIND_WORLD = 3;

export class NetworkModel {
  constructor(t0, path, s0, v, a, vmax, etype, parts, stopS = INF, brake = 1.0) {
    Object.assign(this, { t0, path, s0, v, a, vmax, etype, parts, stopS, brake });
    this.kind = KIND_NETWORK;
    this.plan = [INF, 0.0, 0.0, 0.0];
    if (Number.isFinite(stopS)) {
      const [tb, b] = brakePlan(v, a, vmax, stopS - s0, brake);
      if (Number.isFinite(tb)) {
        const [ds, vb] = advance(v, a, vmax, tb);
        this.plan = [tb, s0 + ds, vb, b];
      }
    }
  }
  state(dt) {
    if (dt > LIMITS.horizon) return [this.state(LIMITS.horizon)[0], 0.0];
    const [tb, sb, vb, b] = this.plan;
    if (dt <= tb) {
      const [ds, v] = advance(this.v, this.a, this.vmax, dt);
      return [this.s0 + ds, v];
    }
    if (!Number.isFinite(b)) return [sb, 0.0];
    const [ds, v] = advance(vb, -b, vb, dt - tb);
    return [Math.min(sb + ds, this.stopS), v];
  }
  sAt(t) {
    return Math.min(this.state(t - this.t0)[0], this.path.length);
  }
  xyAt(t) {
    return this.path.xy(this.sAt(t));
  }
  /** Front, articulation(s) and aft points along the path (a two-part tram bends at its articulation). */
  partsXyAt(t) {
    let s = this.sAt(t);
    const pts = [this.path.xy(s)];
    for (const p of this.parts) {
      s -= p;
      pts.push(this.path.xy(Math.max(s, 0.0)));
    }
    return pts;
  }
}

export class AreaModel {
  constructor(t0, area, x, y, vx, vy, etype) {
    Object.assign(this, { t0, area, x, y, vx, vy, etype });
    this.kind = KIND_AREA;
    this.parts = [];
  }
  xyAt(t) {
    const dt = horizonDt(t - this.t0);
    const [vx, vy] = cappedVelocity(this.vx, this.vy, maxSpeed(this.etype));
    return [this.x + vx * dt, this.y + vy * dt];
  }
  partsXyAt(t) {
    return [this.xyAt(t)];
  }
}

export class WorldModel {
  constructor(t0, x, y, vx, vy, ax, ay, etype) {
    Object.assign(this, { t0, x, y, vx, vy, ax, ay, etype });
    this.kind = KIND_WORLD;
    this.parts = [];
  }
  xyAt(t) {
    const dt = horizonDt(t - this.t0);
    const { vx, vy, ax, ay } = this;
    const cap = maxSpeed(this.etype);
    const cap2 = cap * cap;
    const wx = vx + ax * dt;
    const wy = vy + ay * dt;
    if (vx * vx + vy * vy <= cap2 && wx * wx + wy * wy <= cap2) {
      const h = 0.5 * dt * dt;
      return [this.x + vx * dt + ax * h, this.y + vy * dt + ay * h];
    }
    const [dx, dy] = worldState(vx, vy, ax, ay, Math.sqrt(cap2), dt);
    return [this.x + dx, this.y + dy];
  }
  partsXyAt(t) {
    return [this.xyAt(t)];
  }
}
