// Decodes every tile of a `terrain tiles` tileset with @loaders.gl/terrain's QuantizedMeshLoader
// (an independent decoder: it knows nothing of the encoder) and checks it against the DEM:
//
// - layer.json: quantized-mesh-1.0, TMS, both extensions, available ranges; every tile they
//   list exists and decodes;
// - edge indices: the loader hangs skirts from them; every skirt edge lies on one border of the
//   tile and each border is spanned exactly once, corner to corner;
// - every vertex's height against the DEM's bilinear height there, within the tile's bound plus
//   the slack named below;
// - every non-void DEM sample inside the tile is covered by a triangle, and the decoded mesh
//   there is within the tile's bound: bound_L = error_scale * 77067.34 m / 2^L, computed here
//   from Cesium's formula, not read from the tileset.
//
// Slack for quantization: heights are quantized to (max - min) / 32767 and positions to
// 1/32767 of the tile, which moves the surface by at most |gradient| times half a quantum
// diagonal. A vertex off the DEM's samples (on a tile border, where the builder clips a mesh
// edge) is bounded only through the four samples of the DEM cell it falls in: the DEM moves by
// at most the cell's relief between them and the vertex, and the mesh by at most the steepest
// triangle over the cell times the cell's diagonal, so both are added to its allowance.
//
// Usage: node check.mjs TILESET DEM.json ERROR_SCALE [BOUND_FACTOR]
// DEM.json: {width, height, origin: [lon, lat] of sample (0, 0), spacing: [dlon, dlat],
// heights: [row 0 south first], voids: [sample indices]}. BOUND_FACTOR (default 1) scales the
// bounds: the negative control passes 0.25 and must fail. Exit 0 and a JSON summary on stdout
// when everything holds; exit 1 with the first failures on stderr otherwise.

import fs from 'node:fs';
import path from 'node:path';
import zlib from 'node:zlib';
import { parse } from '@loaders.gl/core';
import { QuantizedMeshLoader } from '@loaders.gl/terrain';

const [dir, demPath, scaleArg, factorArg] = process.argv.slice(2);
if (!dir || !demPath || !scaleArg) {
  console.error('usage: node check.mjs TILESET DEM.json ERROR_SCALE [BOUND_FACTOR]');
  process.exit(2);
}
const errorScale = Number(scaleArg);
const factor = factorArg === undefined ? 1 : Number(factorArg);
const E0 = (6378137 * 2 * Math.PI * 0.25) / 130;
const Q = 32767;

const dem = JSON.parse(fs.readFileSync(demPath, 'utf8'));
const void_ = new Uint8Array(dem.width * dem.height);
for (const k of dem.voids) void_[k] = 1;
const H = (i, j) => dem.heights[j * dem.width + i];

const failures = [];
function fail(msg) {
  failures.push(msg);
  if (failures.length >= 20) finish();
}

function finish() {
  if (failures.length) {
    console.error(`${failures.length} failure(s):\n` + failures.join('\n'));
    process.exit(1);
  }
}

/** The DEM's bilinear height at lon/lat, and the relief of the cell; null off the DEM or at voids. */
function demAt(lon, lat) {
  const gx = (lon - dem.origin[0]) / dem.spacing[0];
  const gy = (lat - dem.origin[1]) / dem.spacing[1];
  const eps = 1e-7;
  if (gx < -eps || gy < -eps || gx > dem.width - 1 + eps || gy > dem.height - 1 + eps) return null;
  const i0 = Math.min(Math.max(Math.floor(gx), 0), dem.width - 2);
  const j0 = Math.min(Math.max(Math.floor(gy), 0), dem.height - 2);
  const fx = Math.min(Math.max(gx - i0, 0), 1);
  const fy = Math.min(Math.max(gy - j0, 0), 1);
  const c = [H(i0, j0), H(i0 + 1, j0), H(i0, j0 + 1), H(i0 + 1, j0 + 1)];
  const v = [[i0, j0], [i0 + 1, j0], [i0, j0 + 1], [i0 + 1, j0 + 1]];
  if (v.some(([i, j]) => void_[j * dem.width + i])) return null;
  const z = c[0] * (1 - fx) * (1 - fy) + c[1] * fx * (1 - fy) + c[2] * (1 - fx) * fy + c[3] * fx * fy;
  const onSample = (fx === 0 || fx === 1) && (fy === 0 || fy === 1);
  const cell = [dem.origin[0] + i0 * dem.spacing[0], dem.origin[1] + j0 * dem.spacing[1]];
  return { z, relief: Math.max(...c) - Math.min(...c), onSample, cell };
}

const layer = JSON.parse(fs.readFileSync(path.join(dir, 'layer.json'), 'utf8'));
if (layer.format !== 'quantized-mesh-1.0') fail(`layer.json format ${layer.format}`);
if (layer.scheme !== 'tms') fail(`layer.json scheme ${layer.scheme}`);
for (const e of ['octvertexnormals', 'metadata']) {
  if (!layer.extensions?.includes(e)) fail(`layer.json lacks extension ${e}`);
}
const roots = layer.available?.[0];
if (roots?.length !== 1 || roots[0].startX !== 0 || roots[0].startY !== 0 || roots[0].endX !== 1 || roots[0].endY !== 0) {
  fail('layer.json: level 0 must be the two root tiles');
}

let tiles = 0;
let vertices = 0;
let samples = 0;
let worst = 0; // largest error / bound over the DEM samples

for (let level = 0; level < layer.available.length; level++) {
  const bound = ((errorScale * E0) / 2 ** level) * factor;
  const size = 180 / 2 ** level;
  for (const r of layer.available[level]) {
    for (let y = r.startY; y <= r.endY; y++) {
      for (let x = r.startX; x <= r.endX; x++) {
        const file = path.join(dir, String(level), String(x), `${y}.terrain`);
        if (!fs.existsSync(file)) {
          fail(`${level}/${x}/${y}: listed as available but missing`);
          continue;
        }
        let buf = fs.readFileSync(file);
        if (buf[0] === 0x1f && buf[1] === 0x8b) buf = zlib.gunzipSync(buf);
        const ab = buf.buffer.slice(buf.byteOffset, buf.byteOffset + buf.byteLength);
        await checkTile(level, x, y, ab, bound, size);
        tiles++;
      }
    }
  }
}

async function checkTile(level, x, y, ab, bound, size) {
  const name = `${level}/${x}/${y}`;
  const west = -180 + x * size;
  const south = -90 + y * size;
  const opts = { worker: false, 'quantized-mesh': { bounds: [0, 0, 1, 1] } };
  let mesh, skirted;
  try {
    mesh = await parse(ab.slice(0), QuantizedMeshLoader, opts);
    skirted = await parse(ab.slice(0), QuantizedMeshLoader, {
      worker: false,
      'quantized-mesh': { bounds: [0, 0, 1, 1], skirtHeight: 1 },
    });
  } catch (e) {
    fail(`${name}: the loader failed: ${e}`);
    return;
  }
  const pos = mesh.attributes.POSITION.value;
  const idx = mesh.indices.value;
  const n = pos.length / 3;
  vertices += n;
  if (n < 3 || idx.length < 3 || idx.length % 3) return fail(`${name}: ${n} vertices, ${idx.length} indices`);
  for (const k of idx) if (k >= n) return fail(`${name}: index ${k} >= ${n} vertices`);
  let zmin = Infinity;
  let zmax = -Infinity;
  for (let k = 0; k < n; k++) {
    zmin = Math.min(zmin, pos[3 * k + 2]);
    zmax = Math.max(zmax, pos[3 * k + 2]);
  }
  const hq = (zmax - zmin) / Q;
  const lonOf = (u) => west + u * size;
  const latOf = (v) => south + v * size;

  // Edge indices, through the skirts the loader hung from them: 2 vertices per border edge.
  const spos = skirted.attributes.POSITION.value;
  const extra = spos.length / 3 - n;
  if (extra <= 0 || extra % 2) return fail(`${name}: ${extra} skirt vertices`);
  const span = { w: 0, e: 0, s: 0, n: 0 };
  for (let k = n; k < n + extra; k += 2) {
    const a = [spos[3 * k], spos[3 * k + 1]];
    const b = [spos[3 * k + 3], spos[3 * k + 4]];
    const len = Math.hypot(a[0] - b[0], a[1] - b[1]);
    if (a[0] === 0 && b[0] === 0) span.w += len;
    else if (a[0] === 1 && b[0] === 1) span.e += len;
    else if (a[1] === 0 && b[1] === 0) span.s += len;
    else if (a[1] === 1 && b[1] === 1) span.n += len;
    else fail(`${name}: a skirt edge (${a}) - (${b}) is on no border: edge indices off the border`);
  }
  for (const [side, l] of Object.entries(span)) {
    if (Math.abs(l - 1) > 1e-6) fail(`${name}: the ${side} border's edge vertices span ${l} of it, not 1`);
  }

  // Triangles in degrees and metres; the steepest gradient gives the quantization slack.
  const T = [];
  let steepest = 0;
  for (let t = 0; t < idx.length; t += 3) {
    const p = [idx[t], idx[t + 1], idx[t + 2]].map((k) => [lonOf(pos[3 * k]), latOf(pos[3 * k + 1]), pos[3 * k + 2]]);
    const d = (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[1][1] - p[0][1]) * (p[2][0] - p[0][0]);
    if (d === 0) continue;
    // Plane z = z0 + gx (lon - lon0) + gy (lat - lat0); gradient in metres per degree.
    const gx = ((p[1][2] - p[0][2]) * (p[2][1] - p[0][1]) - (p[2][2] - p[0][2]) * (p[1][1] - p[0][1])) / d;
    const gy = ((p[2][2] - p[0][2]) * (p[1][0] - p[0][0]) - (p[1][2] - p[0][2]) * (p[2][0] - p[0][0])) / d;
    const g = Math.hypot(gx, gy);
    steepest = Math.max(steepest, g);
    const lo = [Math.min(p[0][0], p[1][0], p[2][0]), Math.min(p[0][1], p[1][1], p[2][1])];
    const hi = [Math.max(p[0][0], p[1][0], p[2][0]), Math.max(p[0][1], p[1][1], p[2][1])];
    T.push({ p, d, g, lo, hi });
  }
  // The steepest triangle over a DEM cell: a vertex off the DEM's samples (a border vertex the
  // builder clipped onto a mesh edge) is bounded only through the cell's corner samples, each
  // within the bound of the mesh where it lies, and the mesh between the vertex and a corner
  // changes by at most this gradient times the cell's diagonal.
  const cellDiagonal = Math.hypot(dem.spacing[0], dem.spacing[1]);
  const steepestOver = ([lon0, lat0]) => {
    let g = 0;
    for (const t of T) {
      const apart =
        t.hi[0] < lon0 || t.lo[0] > lon0 + dem.spacing[0] || t.hi[1] < lat0 || t.lo[1] > lat0 + dem.spacing[1];
      if (!apart) g = Math.max(g, t.g);
    }
    return g;
  };
  const slack = hq + steepest * (Math.SQRT1_2 * size) / Q;

  // Every vertex against the DEM.
  for (let k = 0; k < n; k++) {
    const at = demAt(lonOf(pos[3 * k]), latOf(pos[3 * k + 1]));
    if (!at) continue;
    const err = Math.abs(pos[3 * k + 2] - at.z);
    const between = at.onSample ? 0 : at.relief + steepestOver(at.cell) * cellDiagonal;
    if (err > bound + slack + between + 1e-3) {
      fail(`${name}: vertex ${k} is ${err.toFixed(3)} m off the DEM (bound ${bound.toFixed(3)} m)`);
    }
  }

  // Every non-void DEM sample inside the tile: covered, and within the bound.
  const gx0 = Math.max(0, Math.ceil((west - dem.origin[0]) / dem.spacing[0] - 1e-9));
  const gx1 = Math.min(dem.width - 1, Math.floor((west + size - dem.origin[0]) / dem.spacing[0] + 1e-9));
  const gy0 = Math.max(0, Math.ceil((south - dem.origin[1]) / dem.spacing[1] - 1e-9));
  const gy1 = Math.min(dem.height - 1, Math.floor((south + size - dem.origin[1]) / dem.spacing[1] + 1e-9));
  if (gx0 > gx1 || gy0 > gy1) return;
  const w = gx1 - gx0 + 1;
  const got = new Float64Array(w * (gy1 - gy0 + 1)).fill(NaN);
  for (const { p, d } of T) {
    const lo = [Math.min(p[0][0], p[1][0], p[2][0]), Math.min(p[0][1], p[1][1], p[2][1])];
    const hi = [Math.max(p[0][0], p[1][0], p[2][0]), Math.max(p[0][1], p[1][1], p[2][1])];
    const i0 = Math.max(gx0, Math.ceil((lo[0] - dem.origin[0]) / dem.spacing[0] - 1e-6));
    const i1 = Math.min(gx1, Math.floor((hi[0] - dem.origin[0]) / dem.spacing[0] + 1e-6));
    const j0 = Math.max(gy0, Math.ceil((lo[1] - dem.origin[1]) / dem.spacing[1] - 1e-6));
    const j1 = Math.min(gy1, Math.floor((hi[1] - dem.origin[1]) / dem.spacing[1] + 1e-6));
    for (let j = j0; j <= j1; j++) {
      for (let i = i0; i <= i1; i++) {
        const sx = dem.origin[0] + i * dem.spacing[0];
        const sy = dem.origin[1] + j * dem.spacing[1];
        const w1 = ((sx - p[0][0]) * (p[2][1] - p[0][1]) - (sy - p[0][1]) * (p[2][0] - p[0][0])) / d;
        const w2 = ((p[1][0] - p[0][0]) * (sy - p[0][1]) - (p[1][1] - p[0][1]) * (sx - p[0][0])) / d;
        const w0 = 1 - w1 - w2;
        const e = -1e-4; // samples on an edge, within the positions' quantization, count
        if (w0 < e || w1 < e || w2 < e) continue;
        const z = w0 * p[0][2] + w1 * p[1][2] + w2 * p[2][2];
        const slot = (j - gy0) * w + (i - gx0);
        const err = Math.abs(z - H(i, j));
        if (!(got[slot] >= err)) got[slot] = Number.isNaN(got[slot]) ? err : Math.max(got[slot], err);
      }
    }
  }
  for (let j = gy0; j <= gy1; j++) {
    for (let i = gx0; i <= gx1; i++) {
      if (void_[j * dem.width + i]) continue;
      const err = got[(j - gy0) * w + (i - gx0)];
      if (Number.isNaN(err)) {
        fail(`${name}: DEM sample (${i}, ${j}) is covered by no triangle`);
        continue;
      }
      samples++;
      worst = Math.max(worst, err / bound);
      if (err > bound + slack + 1e-3) {
        fail(`${name}: DEM sample (${i}, ${j}) is ${err.toFixed(3)} m off, bound ${bound.toFixed(3)} m (+${slack.toFixed(3)} m quantization)`);
      }
    }
  }
}

finish();
if (tiles === 0) {
  console.error('no tile checked');
  process.exit(1);
}
console.log(JSON.stringify({ tiles, vertices, samples, worstErrorOverBound: worst }));
