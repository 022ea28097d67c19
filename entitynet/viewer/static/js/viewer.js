// The page's shell: fetch config and geometry, open the WebSocket, draw every frame, move the camera.
// All protocol logic is in session.js (sans-IO), all extrapolation in motion.js; this file only wires them
// to the browser. `window.entitynet` exposes read-outs (and a camera setter) for the headless-browser test.

import { Deck, FirstPersonView } from "@deck.gl/core";
import { configureLimits, NetView } from "./motion.js";
import { PvsLookup } from "./pvs.js";
import { cityLayers, entityLayers, overlayLayers, staticData, TYPE_STYLE } from "./scene.js";
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
  const data = staticData(geometry);
  const hide = (new URLSearchParams(location.hash.slice(1)).get("hide") || "").split(",");
  const city = cityLayers(data).filter((layer) => !hide.includes(layer.id)); // `#hide=streets,ground`
  const show = { cells: false, pvs: false, viewCell: false };
  const [x0, y0, x1, y1] = geometry.extent;
  let viewState = {
    position: [(x0 + x1) / 2, (y0 + y1) / 2 - 380, 160], bearing: 0, pitch: 42, maxPitch: 89, minPitch: -89,
    maxBounds: [[x0 - 400, y0 - 400, 0.5], [x1 + 400, y1 + 400, 600]],
  };
  const probe = { tickMs: 0, firstEntityMs: null, frames: [], lastFrame: null, subscribesSent: 0, started: opened };

  let ws = null;
  const deck = new Deck({
    parent: $("map"),
    views: new FirstPersonView({ id: "camera", fovy: 60, near: 0.3, far: 6000, controller: { keyboard: { moveSpeed: 8 } } }),
    viewState,
    onViewStateChange: ({ viewState: v }) => { viewState = v; deck.setProps({ viewState }); },
    layers: city,
    getTooltip: ({ object }) => tooltip(object),
    // `#scale=0.5` renders at half resolution: a software renderer's frame time falls with the pixel count
    useDevicePixels: Number(new URLSearchParams(location.hash.slice(1)).get("scale")) || false,
    // multisampling quadruples the fragment work of a software renderer (SwiftShader); `#aa=1` turns it on
    deviceProps: { webgl: { antialias: new URLSearchParams(location.hash.slice(1)).get("aa") === "1" } },
    // connect once the city is drawn: its first build keeps the page busy for seconds on a slow machine,
    // and a socket opened before would miss the server's handshake timeout
    onAfterRender: () => { if (ws === null) connect(); },
  });

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
    deck.setProps({ layers: [...city, ...overlayLayers(data, show, [...session.cells], viewBox(geometry, x, y, z)),
      ...entityLayers(ghosts, t, frame)] });
    probe.tickMs = performance.now() - t0; // this frame's JavaScript: extrapolation and layer props
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

  // ---- controls ----
  function setCamera(x, y, z, pitch = viewState.pitch, bearing = viewState.bearing) {
    viewState = { ...viewState, position: [x, y, z], pitch, bearing };
    deck.setProps({ viewState });
    resubscribe();
  }
  $("street").onclick = () => setCamera(viewState.position[0], viewState.position[1], STREET_Z, 3);
  $("roofs").onclick = () => setCamera(viewState.position[0], viewState.position[1], ROOF_Z, 32);
  for (const key of Object.keys(show)) {
    $(`show-${key}`).onchange = (ev) => { show[key] = ev.target.checked; };
  }
  window.addEventListener("keydown", (ev) => {
    const [x, y, z] = viewState.position;
    if (ev.key === "PageUp" || ev.key === "e") setCamera(x, y, Math.min(z + 5, 600));
    if (ev.key === "PageDown" || ev.key === "q") setCamera(x, y, Math.max(z - 5, 0.5));
  });
  $("legend").innerHTML = Object.values(TYPE_STYLE)
    .map((s) => `<span><i style="background:rgb(${s.color})"></i>${s.name}</span>`).join("");
  status("connecting");

  window.entitynet = {
    ready: () => session.ready,
    stats: () => ({ ...session.stats, held: session.ghosts.size, visible: visibleCount, cells: session.cells.size,
      badPayloads: session.ghosts.badPayloads, error: session.error, firstEntityMs: probe.firstEntityMs,
      subscribesSent: probe.subscribesSent, frame, tickMs: probe.tickMs, deck: { ...deck.metrics } }),
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

function tooltip(object) {
  const g = object && object.g;
  if (!g) return null;
  const style = TYPE_STYLE[g.model.etype];
  // identities come only as the server's privacy rule allows (reciprocal, audience): otherwise null
  return `${style ? style.name : "type " + g.model.etype} #${g.entity}` + (g.identity ? `\n${g.identity}` : "");
}

main().catch((err) => {
  status(`error: ${err.message}`, true);
  console.error(err);
  window.entitynet = { error: String(err) };
});
