// Runs one of the npm error-bounded meshers (delatin, @mapbox/martini) on a raw height grid
// for bench/mesh/compare.sh (through terrain-core's mesh_compare example), timing the build.
//
//   node js_meshers.mjs PEERS_DIR HEIGHTS.f32 WIDTH HEIGHT TOOL MAX_ERROR RUNS OUT.bin
//
// HEIGHTS.f32: WIDTH x HEIGHT little-endian f32 metres, row-major (the caller's row order;
// coordinates come back in the same frame). TOOL: delatin | martini. Prints one JSON line
// {"ms": [...], "cpu": [...]} with each run's build time, wall and CPU (process.cpuUsage:
// user + system, the garbage collector's threads included); writes the last run's mesh to OUT.bin as
// u32 vertex count, u32 triangle count, then u32 (x, y) per vertex, then u32 x 3 per triangle.
// Martini needs a square grid of 2^k + 1 samples; its time is createTile (the error pass)
// plus getMesh, the constructor (index tables for the grid size) excluded.
import { readFileSync, writeFileSync } from 'node:fs';
import { createRequire } from 'node:module';
import { join } from 'node:path';
import { pathToFileURL } from 'node:url';

const [peers, heightsPath, ws, hs, tool, errs, runss, out] = process.argv.slice(2);
if (!out) {
  console.error('usage: node js_meshers.mjs PEERS_DIR HEIGHTS.f32 WIDTH HEIGHT TOOL MAX_ERROR RUNS OUT.bin');
  process.exit(2);
}
const [width, height, maxError, runs] = [+ws, +hs, +errs, +runss];
const buf = readFileSync(heightsPath);
const heights = new Float32Array(buf.buffer, buf.byteOffset, buf.byteLength / 4);
if (heights.length !== width * height) {
  console.error(`${heightsPath}: ${heights.length} samples, expected ${width} x ${height}`);
  process.exit(2);
}

let build;
if (tool === 'delatin') {
  const { default: Delatin } = await import(pathToFileURL(join(peers, 'node_modules/delatin/index.js')).href);
  build = () => {
    const tin = new Delatin(heights, width, height);
    tin.run(maxError);
    return { coords: tin.coords, triangles: tin.triangles };
  };
} else if (tool === 'martini') {
  const require = createRequire(pathToFileURL(join(peers, 'package.json')).href);
  const Martini = require('@mapbox/martini');
  if (width !== height || ((width - 1) & (width - 2)) !== 0) {
    console.error(`martini needs a square grid of 2^k + 1 samples, got ${width} x ${height}`);
    process.exit(3);
  }
  const martini = new Martini(width);
  build = () => {
    const tile = martini.createTile(heights);
    const mesh = tile.getMesh(maxError);
    return { coords: mesh.vertices, triangles: mesh.triangles };
  };
} else {
  console.error(`unknown tool ${tool} (delatin | martini)`);
  process.exit(2);
}

const ms = [];
const cpu = [];
let mesh;
for (let r = 0; r < runs; r++) {
  const t = process.hrtime.bigint();
  const c = process.cpuUsage();
  mesh = build();
  const dc = process.cpuUsage(c);
  ms.push(Number(process.hrtime.bigint() - t) / 1e6);
  cpu.push((dc.user + dc.system) / 1e3);
}
const nv = mesh.coords.length / 2;
const nt = mesh.triangles.length / 3;
const o = new Uint32Array(2 + 2 * nv + 3 * nt);
o[0] = nv;
o[1] = nt;
o.set(mesh.coords, 2);
o.set(mesh.triangles, 2 + 2 * nv);
writeFileSync(out, o);
console.log(JSON.stringify({ ms, cpu }));
