// Camera position -> view cell -> PVS, as topology/pvs_index.py `PvsIndex.cells_at` answers it: positions are
// clamped to the grid and a grid cell inside a building answers with the resolved view cell (geometry.json
// ships the resolved index). One view cell's list is fetched from the server when the camera first enters it.
// Without a PVS in the artifact: every cell any part of whose footprint lies within 500 m of the camera, as
// sims/engine/viewers.py `radius_cells_at` answers (the footprint distance the PVS's own range uses).

const RADIUS = 500.0;

/** Whether any part of footprint `f` ({rings, box}) lies within `r` of (x, y): the box decides most cells (wholly
 * within, or not even near); only a box straddling the circle is measured exactly (inside, or an edge near). */
export function withinRadius(f, x, y, r) {
  const [x0, y0, x1, y1] = f.box;
  const nx = Math.max(x0 - x, x - x1, 0), ny = Math.max(y0 - y, y - y1, 0);
  if (nx * nx + ny * ny > r * r) return false;
  const fx = Math.max(Math.abs(x - x0), Math.abs(x - x1)), fy = Math.max(Math.abs(y - y0), Math.abs(y - y1));
  if (fx * fx + fy * fy <= r * r) return true;
  let inside = false, d2 = Infinity;
  f.rings.forEach((ring, k) => {
    let crossings = false;
    for (let i = 0, n = ring.length, j = n - 2; i < n; j = i, i += 2) {
      const ax = ring[j], ay = ring[j + 1], bx = ring[i], by = ring[i + 1];
      if ((ay > y) !== (by > y) && x < ax + ((y - ay) * (bx - ax)) / (by - ay)) crossings = !crossings;
      const dx = bx - ax, dy = by - ay, len2 = dx * dx + dy * dy;
      const t = len2 > 0 ? Math.min(Math.max(((x - ax) * dx + (y - ay) * dy) / len2, 0), 1) : 0;
      const px = ax + t * dx - x, py = ay + t * dy - y;
      d2 = Math.min(d2, px * px + py * py);
    }
    if (k === 0) inside = crossings;
    else if (crossings) inside = false; // in a hole
  });
  return inside || d2 <= r * r;
}

export class PvsLookup {
  constructor(geometry, fetchCells) {
    this.grid = geometry.pvs;
    this.fetchCells = fetchCells;
    this.cache = new Map();
    this.loading = new Set();
    this.onLoaded = () => {};
    if (!this.grid) {
      this.footprints = geometry.cells.polygons.map((rings) => {
        const r = rings[0];
        let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
        for (let i = 0; i < r.length; i += 2) {
          x0 = Math.min(x0, r[i]); x1 = Math.max(x1, r[i]);
          y0 = Math.min(y0, r[i + 1]); y1 = Math.max(y1, r[i + 1]);
        }
        return { rings, box: [x0, y0, x1, y1] };
      });
    }
  }

  viewCell(x, y, z) {
    const g = this.grid;
    if (!g) return -1;
    const clamp = (v, hi) => Math.min(Math.max(v, 0), hi);
    const ix = clamp(Math.floor((x - g.x0) / g.size), g.nx - 1);
    const iy = clamp(Math.floor((y - g.y0) / g.size), g.ny - 1);
    const iz = clamp(Math.floor(z / g.size), g.nz - 1);
    return g.resolved[(iz * g.ny + iy) * g.nx + ix];
  }

  /** The cells visible from (x, y, z), or null while that view cell's list is on its way. */
  cellsAt(x, y, z) {
    if (!this.grid) {
      const out = [];
      this.footprints.forEach((f, i) => { if (withinRadius(f, x, y, RADIUS)) out.push(i); });
      return out;
    }
    const vc = this.viewCell(x, y, z);
    if (vc < 0) return [];
    const hit = this.cache.get(vc);
    if (hit !== undefined) return hit;
    if (!this.loading.has(vc)) {
      this.loading.add(vc);
      this.fetchCells(vc).then((cells) => {
        this.cache.set(vc, cells);
        this.loading.delete(vc);
        this.onLoaded(vc);
      }, () => this.loading.delete(vc));
    }
    return null;
  }
}
