// Entity markers keep a minimum size on screen: true size near the camera, enlarged with the distance so that
// the width always spans MIN_ENTITY_PX pixels; and the legend lists only the simulated types.
import { test } from "node:test";
import assert from "node:assert/strict";
import { MIN_ENTITY_PX, markerScale, TYPE_STYLE } from "../../../../entitynet/viewer/static/js/city3d.js";

const FOCAL = 693; // 800 px tall canvas, 60 degree field of view

test("near the camera an entity keeps its true size; far away its width spans the minimum", () => {
  assert.equal(markerScale(0.7, 10, FOCAL), 1);
  for (const d of [200, 412, 1500]) {
    const k = markerScale(0.7, d, FOCAL);
    assert.ok(k > 1);
    assert.ok(Math.abs((0.7 * k * FOCAL) / d - MIN_ENTITY_PX) < 1e-9); // on-screen width in pixels
  }
  assert.ok(markerScale(0.7, 1000, FOCAL) > markerScale(0.7, 500, FOCAL));
});

test("zero, negative or NaN inputs leave the size alone", () => {
  for (const [w, d, f] of [[0, 100, FOCAL], [0.7, 0, FOCAL], [0.7, -5, FOCAL], [0.7, NaN, FOCAL], [0.7, 100, 0], [NaN, 100, FOCAL]]) {
    assert.equal(markerScale(w, d, f), 1);
  }
});

// hue in degrees and saturation (HSV) of 0xRRGGBB
function hueSat(c) {
  const r = ((c >> 16) & 255) / 255, g = ((c >> 8) & 255) / 255, b = (c & 255) / 255;
  const max = Math.max(r, g, b), d = max - Math.min(r, g, b);
  if (d === 0) return [0, 0];
  const h = max === r ? ((g - b) / d) % 6 : max === g ? (b - r) / d + 2 : (r - g) / d + 4;
  return [(h * 60 + 360) % 360, d / max];
}
const hueGap = (a, b) => Math.min(Math.abs(a - b), 360 - Math.abs(a - b));

test("the legend has the simulated types only, saturated and in hues apart from the map's and each other's", () => {
  assert.deepEqual(Object.values(TYPE_STYLE).map((s) => s.name), ["pedestrian", "car", "bus", "tram"]);
  // the map (city3d.js): streets and footways grey, tram tracks brown, areas green, buildings beige, ground
  const map = [0x5c606c, 0x96989f, 0x966e50, 0x3e5c46, 0xcdc8be, 0x343840, 0x1c1f26];
  const tinted = map.filter((m) => hueSat(m)[1] >= 0.2); // brown, green, the bluish background; greys have no hue
  const styles = Object.values(TYPE_STYLE);
  for (const s of styles) {
    const [h, sat] = hueSat(s.color);
    assert.ok(sat >= 0.8, `${s.name} not saturated`);
    for (const m of tinted) assert.ok(hueGap(h, hueSat(m)[0]) >= 30, `${s.name} near the map's 0x${m.toString(16)}`);
    for (const o of styles) {
      if (o !== s) assert.ok(hueGap(h, hueSat(o.color)[0]) >= 30, `${s.name} near ${o.name}`);
    }
  }
});
