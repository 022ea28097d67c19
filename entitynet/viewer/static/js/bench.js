// The library benchmark behind the viewer's choice of deck.gl: the same city (the artifact's buildings and
// streets) and the same N moving entities, extrapolated every frame with the viewer's own models
// (motion.js), drawn by deck.gl (the viewer's scene.js layers) or by three.js (merged meshes and one
// InstancedMesh), at the same camera. `/static/bench.html#lib=deck&n=2000`; `window.bench` reports frames.
// Run by `python -m sims.viewer_bench --libraries`.

import { NetView, NetworkModel, Path } from "./motion.js";

const params = new URLSearchParams(location.hash.slice(1));
const LIB = params.get("lib") || "deck";
const N = Number(params.get("n") || 2000);
const frames = [];
window.bench = { lib: LIB, n: N, frames, ready: false };

function rng(seed) {
  let s = seed >>> 0;
  return () => ((s = (s * 1664525 + 1013904223) >>> 0) / 4294967296);
}

/** N network models on random connected paths: 70 % walkers, 25 % cars, 5 % trams (two parts). */
function entities(geometry) {
  const net = new NetView(geometry.net);
  const out = [];
  const byNode = new Map();
  for (let e = 0; e < net.nEdges; e++) {
    for (const n of [net.edgeFrom[e], net.edgeTo[e]]) (byNode.get(n) || byNode.set(n, []).get(n)).push(e);
  }
  const r = rng(7);
  const t0 = performance.now() / 1000;
  while (out.length < N) {
    const edges = [[Math.floor(r() * net.nEdges), r() < 0.5 ? 1 : -1]];
    for (let k = 0; k < 12; k++) {
      const end = net.endNode(edges[edges.length - 1]);
      const next = (byNode.get(end) || []).filter((e) => e !== edges[edges.length - 1][0]);
      if (!next.length) break;
      const e = next[Math.floor(r() * next.length)];
      edges.push([e, net.edgeFrom[e] === end ? 1 : -1]);
    }
    const u = r();
    const [etype, v, parts] = u < 0.7 ? [0, 1.4, []] : u < 0.95 ? [1, 9, [4.5]] : [3, 7, [13.8, 13.8]];
    const path = new Path(net, edges);
    out.push({ entity: out.length, model: new NetworkModel(t0, path, r() * 5, v, 0, v, etype, parts) });
  }
  return out;
}

function camera(geometry) {
  const [x0, y0, x1, y1] = geometry.extent;
  return { position: [(x0 + x1) / 2, (y0 + y1) / 2 - 380, 160], pitch: 42, bearing: 0 };
}

async function runDeck(geometry, ghosts) {
  const { Deck, FirstPersonView } = await import("@deck.gl/core");
  const { cityLayers, entityLayers, staticData } = await import("./scene.js");
  const city = cityLayers(staticData(geometry));
  const deck = new Deck({ parent: document.getElementById("map"), useDevicePixels: false,
    deviceProps: { webgl: { antialias: false } },
    views: new FirstPersonView({ fovy: 60, near: 0.3, far: 6000 }), viewState: camera(geometry), layers: city });
  let frame = 0;
  return () => {
    frame += 1;
    deck.setProps({ layers: [...city, ...entityLayers(ghosts, performance.now() / 1000, frame)] });
  };
}

async function runThree(geometry, ghosts) {
  const THREE = await import("three");
  const { mergeGeometries } = await import("three/examples/jsm/utils/BufferGeometryUtils.js");
  const renderer = new THREE.WebGLRenderer({ antialias: false });
  renderer.setSize(innerWidth, innerHeight);
  document.body.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0x1c1f26);
  scene.add(new THREE.AmbientLight(0xffffff, 1.2), new THREE.DirectionalLight(0xffffff, 1.5));
  const shape = (flat) => {
    const pts = [];
    for (let i = 0; i < flat.length; i += 2) pts.push(new THREE.Vector2(flat[i], flat[i + 1]));
    return pts;
  };
  const parts = geometry.buildings.polygons.map((rings, i) => {
    const s = new THREE.Shape(shape(rings[0]));
    for (const hole of rings.slice(1)) s.holes.push(new THREE.Path(shape(hole)));
    return new THREE.ExtrudeGeometry(s, { depth: geometry.buildings.height[i], bevelEnabled: false });
  });
  scene.add(new THREE.Mesh(mergeGeometries(parts), new THREE.MeshLambertMaterial({ color: 0xcdc8be })));
  const net = geometry.net;
  const pos = [];
  for (let e = 0; e < net.n_edges; e++) {
    const w = net.edge_net[e] & 2 ? 3.5 : 1;
    for (let k = net.geom_off[e]; k + 1 < net.geom_off[e + 1]; k++) {
      const ax = net.gx[k], ay = net.gy[k], bx = net.gx[k + 1], by = net.gy[k + 1];
      const l = Math.hypot(bx - ax, by - ay) || 1;
      const px = ((ay - by) / l) * w, py = ((bx - ax) / l) * w;
      pos.push(ax + px, ay + py, 0.05, ax - px, ay - py, 0.05, bx - px, by - py, 0.05,
        ax + px, ay + py, 0.05, bx - px, by - py, 0.05, bx + px, by + py, 0.05);
    }
  }
  const streets = new THREE.BufferGeometry();
  streets.setAttribute("position", new THREE.Float32BufferAttribute(pos, 3));
  scene.add(new THREE.Mesh(streets, new THREE.MeshBasicMaterial({ color: 0x5c606c, side: THREE.DoubleSide })));
  const count = ghosts.reduce((n, g) => n + Math.max(1, g.model.parts.length), 0);
  const boxes = new THREE.InstancedMesh(new THREE.BoxGeometry(1, 1, 1).translate(0, 0, 0.5),
    new THREE.MeshLambertMaterial(), count);
  const colors = { 0: new THREE.Color(0xff2bd6), 1: new THREE.Color(0x00e5ff), 3: new THREE.Color(0xff1a3c) }; // city3d.js TYPE_STYLE
  scene.add(boxes);
  const cam = new THREE.PerspectiveCamera(60, innerWidth / innerHeight, 0.3, 6000);
  const c = camera(geometry);
  cam.up.set(0, 0, 1);
  cam.position.set(...c.position);
  const p = (c.pitch * Math.PI) / 180;
  cam.lookAt(c.position[0], c.position[1] + Math.cos(p), c.position[2] - Math.sin(p));
  const m = new THREE.Matrix4(), q = new THREE.Quaternion(), z = new THREE.Vector3(0, 0, 1);
  const v = new THREE.Vector3(), s = new THREE.Vector3();
  return () => {
    const t = performance.now() / 1000;
    let i = 0;
    for (const g of ghosts) {
      const pts = g.model.partsXyAt(t);
      const color = colors[g.model.etype];
      if (pts.length < 2) {
        m.compose(v.set(pts[0][0], pts[0][1], 0), q.identity(), s.set(1.8, 1.8, 1.8));
        boxes.setMatrixAt(i, m);
        boxes.setColorAt(i++, color);
        continue;
      }
      for (let k = 0; k + 1 < pts.length; k++) {
        const [ax, ay] = pts[k], [bx, by] = pts[k + 1];
        q.setFromAxisAngle(z, Math.atan2(ay - by, ax - bx));
        m.compose(v.set((ax + bx) / 2, (ay + by) / 2, 0), q, s.set(Math.hypot(ax - bx, ay - by) || 0.1, 2.2, 3));
        boxes.setMatrixAt(i, m);
        boxes.setColorAt(i++, color);
      }
    }
    boxes.instanceMatrix.needsUpdate = true;
    if (boxes.instanceColor) boxes.instanceColor.needsUpdate = true;
    renderer.render(scene, cam);
  };
}

async function main() {
  const geometry = await (await fetch("/viewer/geometry.json")).json();
  const ghosts = entities(geometry);
  const draw = LIB === "three" ? await runThree(geometry, ghosts) : await runDeck(geometry, ghosts);
  let last = null;
  const tick = () => {
    const now = performance.now();
    if (last !== null) frames.push(now - last);
    last = now;
    draw();
    requestAnimationFrame(tick);
  };
  window.bench.ready = true;
  requestAnimationFrame(tick);
}

main().catch((err) => { window.bench.error = String(err); console.error(err); });
