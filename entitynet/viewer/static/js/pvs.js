// Camera position -> view cell -> PVS, as topology/pvs_index.py `PvsIndex.cells_at` answers it: positions are
// clamped to the grid and a grid cell inside a building answers with the resolved view cell (geometry.json
// ships the resolved index). One view cell's list is fetched from the server when the camera first enters it.
// Without a PVS in the artifact: every cell whose footprint centre is within 500 m (as sims/demo.py does).

export class PvsLookup {
  constructor(geometry, fetchCells) {
    this.grid = geometry.pvs;
    this.fetchCells = fetchCells;
    this.cache = new Map();
    this.loading = new Set();
    this.onLoaded = () => {};
    if (!this.grid) {
      this.centres = geometry.cells.polygons.map((rings) => {
        const r = rings[0];
        let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
        for (let i = 0; i < r.length; i += 2) {
          x0 = Math.min(x0, r[i]); x1 = Math.max(x1, r[i]);
          y0 = Math.min(y0, r[i + 1]); y1 = Math.max(y1, r[i + 1]);
        }
        return [(x0 + x1) / 2, (y0 + y1) / 2];
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
      this.centres.forEach(([cx, cy], i) => { if (Math.hypot(cx - x, cy - y) <= 500.0) out.push(i); });
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
