// The page's shell: fetch config and geometry, open the WebSocket, draw every frame, move the camera.
// All protocol logic is in session.js (sans-IO), all extrapolation in motion.js; this file only wires them
// to the browser. `window.entitynet` exposes read-outs (and a camera setter) for the headless-browser test.

import { City3D, TYPE_STYLE } from "./city3d.js";
import { configureLimits, NetView } from "./motion.js";
import { PvsLookup } from "./pvs.js";
import { ViewerSession } from "./session.js";

const PING_EVERY_MS = 5000;
const STREET_Z = 1.7;
const ROOF_Z = 90;
const $ = (id) => document.getElementById(id);
const nowS = () => (performance.timeOrigin + performance.now()) / 1000.0;

async function getJson(url) {
  const r = await fetch(url, { cache: "no-store" });
  if (!r.ok) throw new Error(`${url}: ${r.status} ${await r.text()}`);
  return r.json();
}

function tokenFrom(config) {
  if (config.auth === "open") return "viewer";
  const fromUrl = new URLSearchParams(location.hash.slice(1)).get("token");
  if (fromUrl) {
    localStorage.setItem("entitynet-token", fromUrl);
    return fromUrl;
  }
  return localStorage.getItem("entitynet-token") || prompt("entitynet token (entitynet users add NAME)") || "";
}

function status(text, bad = false) {
  const el = $("status");
  el.textContent = text;
  el.className = bad ? "bad" : "";
}

async function main() {
  const opened = performance.now();
  const [config, geometry] = await Promise.all([getJson("/viewer/config.json"), getJson("/viewer/geometry.json")]);
  configureLimits(geometry.limits);
  const net = new NetView(geometry.net);
  const pvs = new PvsLookup(geometry, (vc) => getJson(`/viewer/pvs/${vc}.json`));
  const session = new ViewerSession(net, config.digest, tokenFrom(config), (x, y, z) => pvs.cellsAt(x, y, z));
  const hash = new URLSearchParams(location.hash.slice(1));
  const city = new City3D($("map"), geometry, { pixelRatio: Number(hash.get("scale")) || 1, antialias: hash.get("aa") === "1" });
  const show = { cells: false, pvs: false, viewCell: false };
  const [x0, y0, x1, y1] = geometry.extent;
  // bearing: degrees clockwise from north; pitch: degrees below the horizon
  let viewState = { position: [(x0 + x1) / 2, (y0 + y1) / 2 - 380, 160], bearing: 0, pitch: 42 };
  const bounds = [[x0 - 400, y0 - 400, 0.5], [x1 + 400, y1 + 400, 600]];
  const probe = { tickMs: 0, firstEntityMs: null, frames: [], lastFrame: null, subscribesSent: 0, started: opened };
  let ws = null;

  // ---- the WebSocket shell ----
  function send(bytes) {
    if (bytes && ws && ws.readyState === WebSocket.OPEN) ws.send(bytes);
  }
  function resubscribe() {
    const [x, y, z] = viewState.position;
    const diff = session.moveCamera(x, y, z);
    if (diff) {
      probe.subscribesSent += 1;
      send(diff);
    }
  }
  pvs.onLoaded = resubscribe;
  function connect() {
    const scheme = config.tls ? "wss" : "ws";
    ws = new WebSocket(`${scheme}://${location.hostname}:${config.ws_port}/`);
    ws.binaryType = "arraybuffer";
    session.error = null;
    ws.onopen = () => { status("connected"); ws.send(session.hello()); ws.send(session.ping(nowS() * 1000)); };
    ws.onmessage = (ev) => {
      session.receive(new Uint8Array(ev.data), nowS());
      if (session.error) status(`server: ${session.error.code} ${session.error.text}`, true);
      if (session.ready && !session.subscribedOnce) {
        session.subscribedOnce = true;
        resubscribe();
      }
      if (probe.firstEntityMs === null && session.ghosts.size > 0) probe.firstEntityMs = performance.now() - opened;
    };
    ws.onclose = () => {
      status(session.error ? `closed: ${session.error.text}` : "disconnected; retrying in 2 s", true);
      session.ready = false;
      session.subscribedOnce = false;
      session.cells = new Set();
      // a refused handshake (version, topology, token) will not pass by retrying; anything else may
      if (!session.error || ![200, 201, 202].includes(session.error.code)) setTimeout(connect, 2000);
    };
  }
  setInterval(() => send(session.ping(nowS() * 1000)), PING_EVERY_MS);

  // ---- per frame: extrapolate, draw, read out ----
  let frame = 0;
  const rate = { t: performance.now(), updates: 0, bytes: 0, ups: 0, bps: 0 };
  let visibleCount = 0;
  function tick() {
    const t0 = performance.now();
    if (probe.lastFrame !== null) {
      probe.frames.push(t0 - probe.lastFrame);
      if (probe.frames.length > 600) probe.frames.shift();
    }
    probe.lastFrame = t0;
    frame += 1;
    resubscribe();
    const { ghosts, t } = session.ghosts.visible(nowS());
    visibleCount = ghosts.length;
    const [x, y, z] = viewState.position;
    const vc = pvs.viewCell(x, y, z);
    city.setCamera(viewState.position, viewState.bearing, viewState.pitch);
    city.setOverlays(show, session.cells, viewBox(geometry, x, y, z));
    city.setEntities(ghosts, t);
    probe.tickMs = performance.now() - t0; // this frame's JavaScript: extrapolation and instance matrices
    city.render();
    if (ws === null) connect(); // after the city's first frame: its first build keeps a slow page busy for seconds
    if (t0 - rate.t >= 1000) {
      rate.ups = ((session.stats.updates - rate.updates) * 1000) / (t0 - rate.t);
      rate.bps = ((session.stats.bytes - rate.bytes) * 1000) / (t0 - rate.t);
      Object.assign(rate, { t: t0, updates: session.stats.updates, bytes: session.stats.bytes });
      $("overlay").textContent =
        `entities seen ${visibleCount} (held ${session.ghosts.size}) | updates ${rate.ups.toFixed(1)}/s | ` +
        `${(rate.bps / 1024).toFixed(1)} KiB/s | cells ${session.cells.size} | view cell ${vc} | ` +
        `camera ${x.toFixed(0)}, ${y.toFixed(0)}, ${z.toFixed(1)} m`;
    }
    requestAnimationFrame(tick);
  }
  requestAnimationFrame(tick);

  // ---- controls: a free first-person camera ----
  function setCamera(x, y, z, pitch = viewState.pitch, bearing = viewState.bearing) {
    const clamp = (v, i) => Math.min(Math.max(v, bounds[0][i]), bounds[1][i]);
    viewState = { position: [clamp(x, 0), clamp(y, 1), clamp(z, 2)], pitch: Math.min(Math.max(pitch, -89), 89),
      bearing: ((bearing % 360) + 360) % 360 };
    resubscribe();
  }
  function move(forward, right, up) {
    const b = (viewState.bearing * Math.PI) / 180;
    const step = Math.max(2, viewState.position[2] / 10); // faster high up
    const [x, y, z] = viewState.position;
    setCamera(x + step * (forward * Math.sin(b) + right * Math.cos(b)), y + step * (forward * Math.cos(b) - right * Math.sin(b)),
      z + up * Math.max(1, step / 2));
  }
  const keys = { ArrowUp: [1, 0, 0], w: [1, 0, 0], ArrowDown: [-1, 0, 0], s: [-1, 0, 0], ArrowLeft: [0, -1, 0],
    a: [0, -1, 0], ArrowRight: [0, 1, 0], d: [0, 1, 0], e: [0, 0, 1], PageUp: [0, 0, 1], q: [0, 0, -1], PageDown: [0, 0, -1] };
  window.addEventListener("keydown", (ev) => {
    const k = keys[ev.key];
    if (k && !(ev.target instanceof HTMLInputElement)) { move(...k); ev.preventDefault(); }
  });
  const canvas = city.renderer.domElement;
  let drag = null;
  canvas.addEventListener("pointerdown", (ev) => { drag = [ev.clientX, ev.clientY]; canvas.setPointerCapture(ev.pointerId); });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("pointermove", (ev) => {
    if (drag) {
      const [px, py] = drag;
      drag = [ev.clientX, ev.clientY];
      const [x, y, z] = viewState.position;
      setCamera(x, y, z, viewState.pitch + (ev.clientY - py) * 0.2, viewState.bearing + (ev.clientX - px) * 0.2);
      return;
    }
    const g = city.pick(ev.offsetX, ev.offsetY);
    const tip = $("tooltip");
    tip.style.display = g ? "block" : "none";
    if (g) {
      tip.textContent = tooltip(g);
      tip.style.left = `${ev.clientX + 12}px`;
      tip.style.top = `${ev.clientY + 12}px`;
    }
  });
  canvas.addEventListener("wheel", (ev) => { move(ev.deltaY < 0 ? 1 : -1, 0, 0); ev.preventDefault(); }, { passive: false });
  window.addEventListener("resize", () => city.resize($("map").clientWidth, $("map").clientHeight));
  $("street").onclick = () => setCamera(viewState.position[0], viewState.position[1], STREET_Z, 3);
  $("roofs").onclick = () => setCamera(viewState.position[0], viewState.position[1], ROOF_Z, 32);
  for (const key of Object.keys(show)) {
    $(`show-${key}`).onchange = (ev) => { show[key] = ev.target.checked; };
  }
  $("legend").innerHTML = Object.values(TYPE_STYLE)
    .map((s) => `<span><i style="background:#${s.color.toString(16).padStart(6, "0")}"></i>${s.name}</span>`).join("");
  status("connecting");

  window.entitynet = {
    ready: () => session.ready,
    stats: () => ({ ...session.stats, held: session.ghosts.size, visible: visibleCount, cells: session.cells.size,
      badPayloads: session.ghosts.badPayloads, error: session.error, firstEntityMs: probe.firstEntityMs,
      subscribesSent: probe.subscribesSent, frame, tickMs: probe.tickMs }),
    entityIds: () => [...session.ghosts.ghosts.keys()].sort((a, b) => a - b),
    byType: () => {
      const out = {};
      for (const g of session.ghosts.ghosts.values()) out[g.model.etype] = (out[g.model.etype] || 0) + 1;
      return out;
    },
    positions: (n = 5) => {
      const { ghosts, t } = session.ghosts.visible(nowS());
      return ghosts.slice(0, n).map((g) => ({ entity: g.entity, etype: g.model.etype, t, t0: g.model.t0,
        points: g.model.partsXyAt(t) }));
    },
    subscribedCells: () => [...session.cells].sort((a, b) => a - b),
    frameTimes: () => probe.frames.slice(),
    camera: () => viewState.position.slice(),
    viewCell: (x, y, z) => pvs.viewCell(x, y, z),
    setCamera,
    show: (key, on) => { show[key] = on; },
    // for the legibility test: one instant drawn with and without the entities (PNG data URLs, CSS pixels at
    // scale 1) and where each visible ghost's middle lands on the canvas (null: behind the camera)
    entityFrames: () => {
      const { ghosts, t } = session.ghosts.visible(nowS());
      city.setEntities(ghosts, t);
      city.render();
      const withEntities = canvas.toDataURL("image/png");
      city.setEntitiesVisible(false);
      city.render();
      const without = canvas.toDataURL("image/png");
      city.setEntitiesVisible(true);
      const entities = ghosts.map((g) => {
        const pts = g.model.partsXyAt(t);
        const [px, py] = pts[(pts.length - 1) >> 1];
        return { entity: g.entity, etype: g.model.etype, screen: city.project(px, py, 1.0) };
      });
      return { withEntities, without, entities };
    },
  };
}

function viewBox(geometry, x, y, z) {
  const g = geometry.pvs;
  if (!g) return null;
  const ix = Math.min(Math.max(Math.floor((x - g.x0) / g.size), 0), g.nx - 1);
  const iy = Math.min(Math.max(Math.floor((y - g.y0) / g.size), 0), g.ny - 1);
  const iz = Math.min(Math.max(Math.floor(z / g.size), 0), g.nz - 1);
  const bx = g.x0 + ix * g.size, by = g.y0 + iy * g.size, bz = iz * g.size;
  return [bx, by, bz, bx + g.size, by + g.size, Math.min(bz + g.size, g.max_height)];
}

function tooltip(g) {
  const style = TYPE_STYLE[g.model.etype];
  // identities come only as the server's privacy rule allows (reciprocal, audience): otherwise null
  return `${style ? style.name : "type " + g.model.etype} #${g.entity}` + (g.identity ? ` ${g.identity}` : "");
}

main().catch((err) => {
  status(`error: ${err.message}`, true);
  console.error(err);
  window.entitynet = { error: String(err) };
});
