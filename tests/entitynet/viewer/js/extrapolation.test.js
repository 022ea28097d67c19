// The page's payload decoding and extrapolation against golden vectors the Python client wrote
// (tests/entitynet/viewer/golden.py): the same payload bytes must give the same positions to 1 mm.
// Run by `npm test` (node's test runner), from .ci/run.

import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { test } from "node:test";

import { GhostStore } from "../../../../entitynet/viewer/static/js/ghosts.js";
import { configureLimits, LIMITS, NetView } from "../../../../entitynet/viewer/static/js/motion.js";
import { decodePayload, PayloadError } from "../../../../entitynet/viewer/static/js/payload.js";
import { PvsLookup } from "../../../../entitynet/viewer/static/js/pvs.js";

const golden = JSON.parse(readFileSync(new URL("./golden.json", import.meta.url), "utf8"));
const net = new NetView(golden.net);
const MM = 1e-3;

function bytes(b64) {
  return new Uint8Array(Buffer.from(b64, "base64"));
}

function near(actual, expected, what) {
  const d = Math.hypot(actual[0] - expected[0], actual[1] - expected[1]);
  assert.ok(d <= MM, `${what}: (${actual}) is ${(d * 1000).toFixed(3)} mm from (${expected})`);
}

test("the page's built-in limits are the Python client's", () => {
  const py = golden.limits;
  assert.equal(LIMITS.horizon, py.horizon);
  assert.equal(LIMITS.maxSpeedDefault, py.max_speed_default);
  for (const [code, v] of Object.entries(py.max_speed)) assert.equal(LIMITS.maxSpeed[Number(code)], v, `type ${code}`);
  configureLimits(py); // what the page does with geometry.json's limits
  assert.equal(LIMITS.horizon, py.horizon);
});

test("golden vectors cover every model kind", () => {
  const kinds = new Set(golden.cases.map((c) => decodePayload(bytes(c.payload), net).kind));
  assert.deepEqual([...kinds].sort(), [1, 2, 3]);
  assert.ok(golden.cases.length >= 12);
});

for (const c of golden.cases) {
  test(`extrapolation: ${c.name}`, () => {
    const model = decodePayload(bytes(c.payload), net);
    c.times.forEach((t, i) => {
      near(model.xyAt(t), c.xy[i], `${c.name} at t0${(t - model.t0 >= 0 ? "+" : "")}${(t - model.t0).toFixed(3)}`);
      if (c.parts) {
        const parts = model.partsXyAt(t);
        assert.equal(parts.length, c.parts[i].length);
        parts.forEach((p, k) => near(p, c.parts[i][k], `${c.name} part point ${k} at ${t}`));
      }
    });
  });
}

for (const b of golden.bad) {
  test(`refused like the Python decoder: ${b.name}`, () => {
    assert.throws(() => decodePayload(bytes(b.payload), net), PayloadError);
  });
}

test("ghost store: newer seq replaces, older is ignored, bad payloads are counted, validity expires", () => {
  const store = new GhostStore(net);
  const [a, b] = golden.cases;
  store.receive({ entity: 5, seq: 2, cells: [1], validityMs: 10_000, payload: bytes(a.payload) }, 100.0);
  store.receive({ entity: 5, seq: 1, cells: [2], validityMs: 10_000, payload: bytes(b.payload) }, 100.5);
  assert.deepEqual(store.ghosts.get(5).cells, [1]);
  store.receive({ entity: 6, seq: 1, cells: [2], validityMs: 500_000, payload: bytes(golden.bad[0].payload) }, 100.0);
  assert.equal(store.badPayloads, 1);
  store.receive({ entity: 7, seq: 1, cells: [3], validityMs: 500_000, payload: bytes(b.payload) }, 100.0);
  store.setVisible([3]);
  assert.deepEqual(store.visible(101.0).ghosts.map((g) => g.entity), [7]); // 5 kept while invisible
  assert.equal(store.size, 2);
  assert.deepEqual(store.visible(111.0, false).ghosts.map((g) => g.entity), [7]); // 5's validity ran out
  assert.equal(store.visible(100.0 + LIMITS.horizon).ghosts.length, 0); // no ghost outlives the horizon
  store.receive({ entity: 7, leave: true }, 0);
  assert.equal(store.size, 0);
});

test("camera -> view cell as topology/pvs.py PvsIndex.lookup_cell answers (clamps, holes, buried columns)", () => {
  const lookup = new PvsLookup({ pvs: golden.pvs.grid }, async () => []);
  assert.ok(golden.pvs.lookups.length > 100);
  for (const [x, y, z, want] of golden.pvs.lookups) assert.equal(lookup.viewCell(x, y, z), want, `at ${x}, ${y}, ${z}`);
});
