// The viewer's drawing with three.js (chosen over deck.gl by measured frame time with 2,000 entities: 225 ms
// against 1,843 ms a frame on SwiftShader, docs/viewer.md). Local metric coordinates of the artifact: x east,
// y north, z up; no map tiles. Static city merged into a few meshes once; entities are one InstancedMesh
// (a box per body part, a tram's two parts meeting at its articulation) rewritten every frame.

import * as THREE from "three";
import { mergeGeometries } from "three/examples/jsm/utils/BufferGeometryUtils.js";

const PEDESTRIAN = 1, VEHICLE = 2, TRAM = 4; // topology/raw.py network bits

// The simulated types (entitynet/client/entities.py; no cyclists are simulated, so none is in the legend):
// colour, true width and height in metres. The colours are saturated and far from the map's (grey streets,
// brown tram tracks 0x966e50, dull green areas, beige buildings, the overlays' light blue and yellow).
export const TYPE_STYLE = {
  0: { name: "pedestrian", color: 0xff2bd6, width: 0.7, height: 1.8 }, // magenta
  1: { name: "car", color: 0x00e5ff, width: 1.9, height: 1.5 }, // cyan
  2: { name: "bus", color: 0x8cff1a, width: 2.55, height: 3.1 }, // lime
  3: { name: "tram", color: 0xff1a3c, width: 2.4, height: 3.4 }, // crimson
};
const OTHER = { name: "other", color: 0xffffff, width: 1.5, height: 1.5 };
// Far away a true-size entity is a pixel or two: each is scaled up (never down) so that its width covers at
// least this many pixels on screen, whatever its distance.
export const MIN_ENTITY_PX = 8;

/** How much to enlarge a body of `width` metres at `distance` metres so that it spans at least `minPx` pixels
 * with a camera of focal length `focalPx` (pixels): 1 near the camera, growing with the distance. */
export function markerScale(width, distance, focalPx, minPx = MIN_ENTITY_PX) {
  if (!(width > 0) || !(focalPx > 0) || !(distance > 0)) return 1;
  return Math.max(1, (minPx * distance) / (focalPx * width));
}

function vec2s(flat) {
  const out = [];
  for (let i = 0; i < flat.length; i += 2) out.push(new THREE.Vector2(flat[i], flat[i + 1]));
  return out;
}

function shapeOf(rings) {
  const s = new THREE.Shape(vec2s(rings[0]));
  for (const hole of rings.slice(1)) s.holes.push(new THREE.Path(vec2s(hole)));
  return s;
}

function flat(polygons, z) {
  const parts = polygons.map((rings) => new THREE.ShapeGeometry(shapeOf(rings)).translate(0, 0, z));
  return parts.length ? mergeGeometries(parts) : new THREE.BufferGeometry();
}

function streetRibbons(net) {
  const pos = [];
  const col = [];
  const c = new THREE.Color();
  for (let e = 0; e < net.n_edges; e++) {
    const n = net.edge_net[e];
    const w = n & VEHICLE ? 3.5 : n & TRAM ? 1.25 : 1.0;
    c.setHex(n & VEHICLE ? 0x5c606c : n & TRAM ? 0x966e50 : 0x96989f);
    const z = n & TRAM ? 0.07 : n & VEHICLE ? 0.05 : 0.06;
    for (let k = net.geom_off[e]; k + 1 < net.geom_off[e + 1]; k++) {
      const ax = net.gx[k], ay = net.gy[k], bx = net.gx[k + 1], by = net.gy[k + 1];
      const l = Math.hypot(bx - ax, by - ay) || 1;
      const px = ((ay - by) / l) * w, py = ((bx - ax) / l) * w;
      pos.push(ax + px, ay + py, z, ax - px, ay - py, z, bx - px, by - py, z,
        ax + px, ay + py, z, bx - px, by - py, z, bx + px, by + py, z);
      for (let i = 0; i < 6; i++) col.push(c.r, c.g, c.b);
    }
  }
  const g = new THREE.BufferGeometry();
  g.setAttribute("position", new THREE.Float32BufferAttribute(pos, 3));
  g.setAttribute("color", new THREE.Float32BufferAttribute(col, 3));
  return g;
}

function outlines(polygons, z) {
  const pos = [];
  for (const rings of polygons) {
    for (const r of rings) {
      for (let i = 0; i + 3 < r.length; i += 2) pos.push(r[i], r[i + 1], z, r[i + 2], r[i + 3], z);
    }
  }
  const g = new THREE.BufferGeometry();
  g.setAttribute("position", new THREE.Float32BufferAttribute(pos, 3));
  return g;
}

export class City3D {
  constructor(container, geometry, { pixelRatio = 1, antialias = false } = {}) {
    this.geometry = geometry;
    this.renderer = new THREE.WebGLRenderer({ antialias });
    this.renderer.setPixelRatio(pixelRatio);
    this.renderer.setSize(container.clientWidth, container.clientHeight);
    container.appendChild(this.renderer.domElement);
    const scene = (this.scene = new THREE.Scene());
    scene.background = new THREE.Color(0x1c1f26);
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    sun.position.set(-0.4, -0.6, 1.0);
    scene.add(new THREE.AmbientLight(0xffffff, 1.1), sun);
    this.camera = new THREE.PerspectiveCamera(60, container.clientWidth / container.clientHeight, 0.3, 6000);
    this.camera.up.set(0, 0, 1);

    const [x0, y0, x1, y1] = geometry.extent;
    const ground = new THREE.PlaneGeometry(x1 - x0 + 800, y1 - y0 + 800).translate((x0 + x1) / 2, (y0 + y1) / 2, -0.02);
    scene.add(new THREE.Mesh(ground, new THREE.MeshBasicMaterial({ color: 0x343840 })));
    scene.add(new THREE.Mesh(flat(geometry.areas.polygons, 0.0), new THREE.MeshBasicMaterial({ color: 0x3e5c46 })));
    scene.add(new THREE.Mesh(streetRibbons(geometry.net), new THREE.MeshBasicMaterial({ vertexColors: true })));
    const b = geometry.buildings;
    const blocks = b.polygons.map((rings, i) => new THREE.ExtrudeGeometry(shapeOf(rings), { depth: b.height[i], bevelEnabled: false }));
    if (blocks.length) {
      scene.add(new THREE.Mesh(mergeGeometries(blocks), new THREE.MeshLambertMaterial({ color: 0xcdc8be })));
    }
    // overlays
    this.cellLines = new THREE.LineSegments(outlines(geometry.cells.polygons, 0.3),
      new THREE.LineBasicMaterial({ color: 0x78c8ff, transparent: true, opacity: 0.6 }));
    this.cellLines.visible = false;
    scene.add(this.cellLines);
    this.pvsMesh = new THREE.Mesh(new THREE.BufferGeometry(), new THREE.MeshBasicMaterial({
      color: 0xffe63c, transparent: true, opacity: 0.35, depthTest: false }));
    this.pvsMesh.visible = false;
    this.pvsCells = null;
    scene.add(this.pvsMesh);
    this.viewBox = new THREE.LineSegments(new THREE.EdgesGeometry(new THREE.BoxGeometry(1, 1, 1)),
      new THREE.LineBasicMaterial({ color: 0xffffff }));
    this.viewBox.visible = false;
    scene.add(this.viewBox);
    // entities
    this.capacity = 0;
    this.bodies = null;
    this.joints = null;
    this.picked = [];
    this._m = new THREE.Matrix4();
    this._q = new THREE.Quaternion();
    this._v = new THREE.Vector3();
    this._s = new THREE.Vector3();
    this._c = new THREE.Color();
    this._z = new THREE.Vector3(0, 0, 1);
    this.raycaster = new THREE.Raycaster();
  }

  resize(width, height) {
    this.renderer.setSize(width, height);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
  }

  /** position [x, y, z], bearing (degrees from north, clockwise), pitch (degrees below the horizon). */
  setCamera(position, bearing, pitch) {
    const b = (bearing * Math.PI) / 180, p = (pitch * Math.PI) / 180;
    this.camera.position.set(...position);
    this.camera.lookAt(position[0] + Math.sin(b) * Math.cos(p), position[1] + Math.cos(b) * Math.cos(p),
      position[2] - Math.sin(p));
  }

  setOverlays(show, cells, box) {
    this.cellLines.visible = show.cells;
    this.pvsMesh.visible = show.pvs;
    if (show.pvs && cells !== this.pvsCells) {
      this.pvsCells = cells;
      const polys = [...cells].map((c) => this.geometry.cells.polygons[c]).filter(Boolean);
      this.pvsMesh.geometry.dispose();
      this.pvsMesh.geometry = flat(polys, 0.4);
    }
    this.viewBox.visible = show.viewCell && box !== null;
    if (this.viewBox.visible) {
      const [bx0, by0, bz0, bx1, by1, bz1] = box;
      this.viewBox.position.set((bx0 + bx1) / 2, (by0 + by1) / 2, (bz0 + bz1) / 2);
      this.viewBox.scale.set(bx1 - bx0, by1 - by0, bz1 - bz0);
    }
  }

  _ensure(n) {
    if (this.bodies && n <= this.capacity) return;
    const cap = Math.max(256, 2 ** Math.ceil(Math.log2(n)));
    for (const mesh of [this.bodies, this.joints]) {
      if (mesh) { this.scene.remove(mesh); mesh.dispose(); }
    }
    const box = new THREE.BoxGeometry(1, 1, 1).translate(0, 0, 0.5);
    this.bodies = new THREE.InstancedMesh(box, new THREE.MeshLambertMaterial(), cap);
    this.joints = new THREE.InstancedMesh(box, new THREE.MeshBasicMaterial({ color: 0xffffff }), cap);
    for (const mesh of [this.bodies, this.joints]) {
      mesh.frustumCulled = false;
      mesh.count = 0;
      this.scene.add(mesh);
    }
    this.capacity = cap;
  }

  /** The camera's focal length in CSS pixels (the vertical field of view over the canvas height). */
  focalPx() {
    const h = this.renderer.domElement.clientHeight || this.renderer.getSize(this._size || (this._size = new THREE.Vector2())).y;
    return h / 2 / Math.tan((this.camera.fov * Math.PI) / 360);
  }

  /** Draw the ghosts at time t (their models extrapolated: motion.js), each at least MIN_ENTITY_PX wide. */
  setEntities(ghosts, t) {
    let n = 0;
    for (const g of ghosts) n += Math.max(1, g.model.parts.length);
    this._ensure(n);
    const { _m: m, _q: q, _v: v, _s: s, _c: c, _z: z } = this;
    const eye = this.camera.position;
    const focal = this.focalPx();
    let i = 0, j = 0;
    this.picked.length = 0;
    for (const g of ghosts) {
      const style = TYPE_STYLE[g.model.etype] || OTHER;
      c.setHex(style.color);
      const pts = g.model.partsXyAt(t);
      const [cx, cy] = pts.length < 2 ? pts[0] : pts[(pts.length - 1) >> 1];
      const k0 = markerScale(style.width, Math.hypot(cx - eye.x, cy - eye.y, eye.z), focal);
      const w = style.width * k0, h = style.height * k0;
      if (pts.length < 2) {
        m.compose(v.set(pts[0][0], pts[0][1], 0), q.identity(), s.set(w, w, h));
        this.bodies.setMatrixAt(i, m);
        this.bodies.setColorAt(i, c);
        this.picked[i++] = g;
        continue;
      }
      for (let k = 0; k + 1 < pts.length; k++) {
        const [ax, ay] = pts[k], [bx, by] = pts[k + 1];
        q.setFromAxisAngle(z, Math.atan2(ay - by, ax - bx));
        m.compose(v.set((ax + bx) / 2, (ay + by) / 2, 0), q, s.set(Math.max(Math.hypot(ax - bx, ay - by), w), w, h));
        this.bodies.setMatrixAt(i, m);
        this.bodies.setColorAt(i, c);
        this.picked[i++] = g;
        if (k > 0) {
          m.compose(v.set(ax, ay, h), q, s.set(1.0 * k0, w * 0.8, 0.35 * k0));
          this.joints.setMatrixAt(j++, m);
        }
      }
    }
    this.bodies.count = i;
    this.joints.count = j;
    this.bodies.instanceMatrix.needsUpdate = true;
    if (this.bodies.instanceColor) this.bodies.instanceColor.needsUpdate = true;
    this.joints.instanceMatrix.needsUpdate = true;
  }

  /** The ghost under a canvas pixel, or null (for the tooltip). */
  pick(x, y) {
    if (!this.bodies || !this.bodies.count) return null;
    const el = this.renderer.domElement;
    this.raycaster.setFromCamera(new THREE.Vector2((x / el.clientWidth) * 2 - 1, -(y / el.clientHeight) * 2 + 1), this.camera);
    const hit = this.raycaster.intersectObject(this.bodies, false)[0];
    return hit && hit.instanceId !== undefined ? this.picked[hit.instanceId] : null;
  }

  /** Show or hide the entities (the legibility test renders the same instant with and without them). */
  setEntitiesVisible(on) {
    for (const mesh of [this.bodies, this.joints]) if (mesh) mesh.visible = on;
  }

  /** Where a local point [x, y, z] lands on the canvas: [px, py] in CSS pixels, or null behind the camera. */
  project(x, y, z) {
    const p = this._v.set(x, y, z).project(this.camera);
    if (p.z < -1 || p.z > 1) return null;
    const el = this.renderer.domElement;
    return [((p.x + 1) / 2) * el.clientWidth, ((1 - p.y) / 2) * el.clientHeight];
  }

  render() {
    this.renderer.render(this.scene, this.camera);
  }
}
