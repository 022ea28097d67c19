// The library benchmark's deck.gl variant (bench.js; the viewer draws with three.js, city3d.js): the static city (buildings, streets, areas) built once, overlays that toggle
// (visibility cells, the camera's view cell and its PVS) and the entities rebuilt every frame.
// Local metric coordinates of the artifact (CARTESIAN; x east, y north, z up), no map tiles.

import { COORDINATE_SYSTEM } from "@deck.gl/core";
import { PathLayer, PolygonLayer, SolidPolygonLayer } from "@deck.gl/layers";

const CART = { coordinateSystem: COORDINATE_SYSTEM.CARTESIAN };
const PEDESTRIAN = 1, VEHICLE = 2, TRAM = 4; // topology/raw.py network bits

// the simulated types, in the viewer's colours (city3d.js)
export const TYPE_STYLE = {
  0: { name: "pedestrian", color: [255, 43, 214], width: 0.9, height: 1.8 },
  1: { name: "car", color: [0, 229, 255], width: 1.9, height: 1.5 },
  2: { name: "bus", color: [140, 255, 26], width: 2.55, height: 3.1 },
  3: { name: "tram", color: [255, 26, 60], width: 2.4, height: 3.4 },
};
const OTHER = { name: "other", color: [200, 200, 200], width: 1.5, height: 1.5 };

function ring(flat) {
  const out = [];
  for (let i = 0; i < flat.length; i += 2) out.push([flat[i], flat[i + 1]]);
  return out;
}

export function staticData(geometry) {
  const net = geometry.net;
  const streets = [];
  for (let e = 0; e < net.n_edges; e++) {
    const path = [];
    for (let k = net.geom_off[e]; k < net.geom_off[e + 1]; k++) path.push([net.gx[k], net.gy[k]]);
    streets.push({ path, net: net.edge_net[e] });
  }
  const buildings = geometry.buildings.polygons.map((rings, i) => ({
    polygon: rings.map(ring), height: geometry.buildings.height[i],
  }));
  const areas = geometry.areas.polygons.map((rings) => ({ polygon: rings.map(ring) }));
  const cells = geometry.cells.polygons.map((rings, i) => ({ polygon: rings.map(ring), id: i, kind: geometry.cells.kind[i] }));
  const [x0, y0, x1, y1] = geometry.extent;
  const pad = 400;
  const ground = [{ polygon: [[x0 - pad, y0 - pad], [x1 + pad, y0 - pad], [x1 + pad, y1 + pad], [x0 - pad, y1 + pad]] }];
  return { streets, buildings, areas, cells, ground };
}

function streetColor(n) {
  if (n & VEHICLE) return [92, 96, 108];
  if (n & TRAM) return [150, 110, 80];
  if (n & PEDESTRIAN) return [150, 152, 160];
  return [120, 120, 120];
}

function streetWidth(n) {
  return n & VEHICLE ? 7 : n & TRAM ? 2.5 : 2;
}

export function cityLayers(data) {
  return [
    new SolidPolygonLayer({ id: "ground", data: data.ground, ...CART, getPolygon: (d) => d.polygon,
      getFillColor: [52, 56, 64], material: false }),
    new SolidPolygonLayer({ id: "areas", data: data.areas, ...CART, getPolygon: (d) => d.polygon,
      getFillColor: [62, 92, 70], material: false }),
    new PathLayer({ id: "streets", data: data.streets, ...CART, getPath: (d) => d.path,
      getColor: (d) => streetColor(d.net), getWidth: (d) => streetWidth(d.net), widthUnits: "meters",
      // square caps and miter joints: rounded ones cost a software renderer (SwiftShader) several times more
      widthMinPixels: 1, capRounded: false, jointRounded: false, parameters: { depthCompare: "always" } }),
    new SolidPolygonLayer({ id: "buildings", data: data.buildings, ...CART, getPolygon: (d) => d.polygon,
      extruded: true, getElevation: (d) => d.height, getFillColor: [205, 200, 190], wireframe: false,
      material: { ambient: 0.35, diffuse: 0.6, shininess: 16, specularColor: [40, 40, 40] } }),
  ];
}

export function overlayLayers(data, show, pvsCells, viewBox) {
  const layers = [];
  if (show.cells) {
    layers.push(new PolygonLayer({ id: "cells", data: data.cells, ...CART, getPolygon: (d) => d.polygon,
      filled: false, stroked: true, getLineColor: [120, 200, 255, 140], lineWidthUnits: "pixels", getLineWidth: 1 }));
  }
  if (show.pvs && pvsCells) {
    layers.push(new SolidPolygonLayer({ id: "pvs", data: pvsCells.map((c) => data.cells[c]).filter(Boolean), ...CART,
      getPolygon: (d) => d.polygon, getFillColor: [255, 230, 60, 70], parameters: { depthCompare: "always" },
      updateTriggers: { getPolygon: pvsCells.length } }));
  }
  if (show.viewCell && viewBox) {
    const [x0, y0, z0, x1, y1, z1] = viewBox;
    layers.push(new PolygonLayer({ id: "view-cell", data: [{ polygon: [[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0]] }],
      ...CART, getPolygon: (d) => d.polygon, extruded: true, wireframe: true, filled: false,
      getElevation: z1 - z0, getLineColor: [255, 255, 255], lineWidthUnits: "pixels", getLineWidth: 2 }));
  }
  return layers;
}

/** Oriented box footprint of a body part from point a (front) to point b (aft), width w. */
function box(a, b, w) {
  let dx = a[0] - b[0], dy = a[1] - b[1];
  const n = Math.hypot(dx, dy);
  if (n < 1e-6) { dx = 1; dy = 0; } else { dx /= n; dy /= n; }
  const px = -dy * w / 2, py = dx * w / 2;
  const first = [a[0] - px, a[1] - py];
  return [first, [a[0] + px, a[1] + py], [b[0] + px, b[1] + py], [b[0] - px, b[1] - py], first]; // closed, CCW
}

/** Entities at time t: pedestrians as dots, vehicles as extruded boxes (a tram's two parts meet at its joint). */
export function entityLayers(ghosts, t, frame) {
  const walkers = [];
  const bodies = [];
  const joints = [];
  for (const g of ghosts) {
    const m = g.model;
    const style = TYPE_STYLE[m.etype] || OTHER;
    const pts = m.partsXyAt(t);
    if (pts.length < 2) {
      // a walker: a square post (ScatterplotLayer draws nothing in a non-geospatial FirstPersonView, deck.gl 9.4)
      const [x, y] = pts[0];
      const r = style.width;
      walkers.push({ polygon: [[x - r, y - r], [x + r, y - r], [x + r, y + r], [x - r, y + r], [x - r, y - r]],
        h: style.height, c: style.color, g });
      continue;
    }
    for (let k = 0; k + 1 < pts.length; k++) {
      bodies.push({ polygon: box(pts[k], pts[k + 1], style.width), h: style.height, c: style.color, g });
    }
    for (let k = 1; k + 1 < pts.length; k++) {
      const [x, y] = pts[k];
      joints.push({ polygon: [[x - 0.6, y - 0.6], [x + 0.6, y - 0.6], [x + 0.6, y + 0.6], [x - 0.6, y + 0.6], [x - 0.6, y - 0.6]],
        h: style.height + 0.4 });
    }
  }
  return [
    new SolidPolygonLayer({ id: "vehicles", data: bodies, ...CART, getPolygon: (d) => d.polygon, extruded: true,
      getElevation: (d) => d.h, getFillColor: (d) => d.c, pickable: true,
      updateTriggers: { getPolygon: frame, getElevation: frame, getFillColor: frame } }),
    new SolidPolygonLayer({ id: "walkers", data: walkers, ...CART, getPolygon: (d) => d.polygon, extruded: true,
      getElevation: (d) => d.h, getFillColor: (d) => d.c, pickable: true,
      updateTriggers: { getPolygon: frame } }),
    new SolidPolygonLayer({ id: "joints", data: joints, ...CART, getPolygon: (d) => d.polygon, extruded: true,
      getElevation: (d) => d.h, getFillColor: [255, 255, 255], updateTriggers: { getPolygon: frame } }),
  ];
}
