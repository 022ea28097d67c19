// The viewer's no-PVS fallback: a cell is subscribed when any part of its footprint lies within the radius
// (as sims/engine/viewers.py radius_cells_at), not only when its centre does.
import { test } from "node:test";
import assert from "node:assert/strict";
import { withinRadius } from "../../../../entitynet/viewer/static/js/pvs.js";

const square = (x0, y0, x1, y1) => [x0, y0, x1, y0, x1, y1, x0, y1, x0, y0];
const footprint = (rings) => {
  const r = rings[0];
  const xs = r.filter((_, i) => i % 2 === 0), ys = r.filter((_, i) => i % 2 === 1);
  return { rings, box: [Math.min(...xs), Math.min(...ys), Math.max(...xs), Math.max(...ys)] };
};

test("a long cell reaching into the disc counts though its centre lies outside", () => {
  const street = footprint([square(490, -5, 1490, 5)]); // centre 990 m away, near end 490 m
  assert.equal(withinRadius(street, 0, 0, 500), true);
  assert.equal(withinRadius(street, -20, 0, 500), false); // 510 m from its near end
});

test("a camera inside a footprint is within any radius; inside its hole only by the hole's edge", () => {
  const ring = footprint([square(-100, -100, 100, 100), square(-50, -50, 50, 50)]);
  assert.equal(withinRadius(ring, 80, 0, 1), true);
  assert.equal(withinRadius(ring, 0, 0, 10), false); // 50 m from the hole's edge
  assert.equal(withinRadius(ring, 0, 0, 60), true);
});

test("a box corner near the circle is measured exactly, not by the box", () => {
  const diamond = footprint([[600, 0, 700, 100, 600, 200, 500, 100, 600, 0]]); // box corner (500, 0) at 500 m
  assert.equal(withinRadius(diamond, 0, 0, 500), false); // nearest point, the vertex (500, 100), is 510 m away
  assert.equal(withinRadius(diamond, 0, 0, 560), true);
});
