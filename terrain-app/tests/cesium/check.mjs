// Loads a `terrain tiles` tileset in CesiumJS (the npm `cesium` package, served locally) in
// headless Chromium (Debian's /usr/bin/chromium, driven by playwright-core), flies to the
// terrain, waits until every tile in view is loaded, takes a screenshot, and fails on any tile
// request error.
//
// Nothing leaves 127.0.0.1: a local static server serves the page, CesiumJS's build and the
// tileset; every other request is aborted (and counted); no Ion, no imagery (the globe is a
// single colour, lit, so the terrain's oct-encoded normals shade it).
//
// Usage: node check.mjs TILESET_DIR OUT.png [TIMEOUT_S]
// Exit 0 and a JSON summary on stdout when tiles loaded without error; exit 1 with the errors
// on stderr otherwise (a tile request answered >= 400 or failed, a terrain provider error, a
// page error, a request that tried to leave the machine, or no tile drawn in time).

import fs from 'node:fs';
import http from 'node:http';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const [tilesetArg, outArg, timeoutArg] = process.argv.slice(2);
if (!tilesetArg || !outArg) {
  console.error('usage: node check.mjs TILESET_DIR OUT.png [TIMEOUT_S]');
  process.exit(2);
}
const here = path.dirname(fileURLToPath(import.meta.url));
const tileset = path.resolve(tilesetArg);
const cesiumBuild = path.join(here, 'node_modules/cesium/Build/Cesium');
const timeoutMs = 1000 * Number(timeoutArg ?? 240);
const layer = JSON.parse(fs.readFileSync(path.join(tileset, 'layer.json'), 'utf8'));
const [west, south, east, north] = layer.bounds;

const page = `<!doctype html>
<html><head><meta charset="utf-8">
<script>window.CESIUM_BASE_URL = '/cesium/';</script>
<script src="/cesium/Cesium.js"></script>
<link href="/cesium/Widgets/widgets.css" rel="stylesheet">
<style>html, body, #view { width: 100%; height: 100%; margin: 0; overflow: hidden; }</style>
</head><body><div id="view"></div>
<script>
window.report = { errors: [], loaded: false };
(async () => {
  try {
    const viewer = new Cesium.Viewer('view', {
      baseLayer: false, baseLayerPicker: false, geocoder: false, timeline: false,
      animation: false, homeButton: false, sceneModePicker: false, navigationHelpButton: false,
      fullscreenButton: false, infoBox: false, selectionIndicator: false,
      skyBox: false, skyAtmosphere: false, requestRenderMode: false,
    });
    viewer.scene.globe.baseColor = Cesium.Color.fromCssColorString('#c8b48c');
    viewer.scene.globe.enableLighting = true;
    viewer.clock.currentTime = Cesium.JulianDate.fromIso8601('2024-06-21T18:00:00Z');
    viewer.clock.shouldAnimate = false;
    const provider = await Cesium.CesiumTerrainProvider.fromUrl('/tiles/', {
      requestVertexNormals: true, requestMetadata: true,
    });
    provider.errorEvent.addEventListener((e) => window.report.errors.push('terrain provider: ' + e.message));
    viewer.terrainProvider = provider;
    window.report.hasVertexNormals = provider.hasVertexNormals;
    window.report.hasMetadata = provider.hasMetadata;
    const r = Cesium.Rectangle.fromDegrees(${west}, ${south}, ${east}, ${north});
    const c = Cesium.Rectangle.center(r);
    // Look at the terrain's centre from the south, 30 degrees down, from its width away.
    const range = 1.0 * Math.max(r.width * 6378137 * Math.cos(c.latitude), r.height * 6378137);
    const target = Cesium.Cartesian3.fromRadians(c.longitude, c.latitude, 0);
    viewer.camera.lookAt(target, new Cesium.HeadingPitchRange(0, Cesium.Math.toRadians(-30), range));
    window.report.range = range;
    let calm = 0;
    viewer.scene.postRender.addEventListener(() => {
      calm = viewer.scene.globe.tilesLoaded ? calm + 1 : 0;
      if (calm >= 30) window.report.loaded = true;
    });
  } catch (e) {
    window.report.errors.push('page: ' + (e && e.stack ? e.stack : e));
  }
})();
</script></body></html>`;

const types = {
  '.js': 'text/javascript', '.css': 'text/css', '.json': 'application/json', '.png': 'image/png',
  '.jpg': 'image/jpeg', '.svg': 'image/svg+xml', '.wasm': 'application/wasm', '.html': 'text/html',
  '.terrain': 'application/vnd.quantized-mesh', '.xml': 'application/xml', '.glb': 'model/gltf-binary',
};
const tileRequests = { ok: 0, failed: [] };
let deepest = -1;
const server = http.createServer((req, res) => {
  const url = new URL(req.url, 'http://127.0.0.1');
  const send = (code, body, headers = {}) => { res.writeHead(code, headers); res.end(body); };
  if (url.pathname === '/') return send(200, page, { 'Content-Type': 'text/html' });
  let root, rel;
  if (url.pathname.startsWith('/cesium/')) [root, rel] = [cesiumBuild, url.pathname.slice(8)];
  else if (url.pathname.startsWith('/tiles/')) [root, rel] = [tileset, url.pathname.slice(7)];
  else return send(404, 'not found');
  const file = path.join(root, decodeURIComponent(rel));
  if (!file.startsWith(root) || !fs.existsSync(file) || !fs.statSync(file).isFile()) {
    if (root === tileset) tileRequests.failed.push(`${url.pathname}: 404`);
    return send(404, 'not found');
  }
  const body = fs.readFileSync(file);
  const headers = { 'Content-Type': types[path.extname(file)] ?? 'application/octet-stream' };
  if (file.endsWith('.terrain')) {
    // gzip tiles (`terrain tiles --gzip`) are served as the format asks.
    if (body[0] === 0x1f && body[1] === 0x8b) headers['Content-Encoding'] = 'gzip';
    tileRequests.ok++;
    deepest = Math.max(deepest, Number(rel.split('/')[0]));
  }
  send(200, body, headers);
});
await new Promise((ok) => server.listen(0, '127.0.0.1', ok));
const base = `http://127.0.0.1:${server.address().port}`;

const errors = [];
const consoleErrors = [];
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM ?? '/usr/bin/chromium',
  headless: true,
  args: [
    '--no-sandbox', '--disable-background-networking', '--disable-component-update',
    '--disable-sync', '--no-first-run', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
    '--ignore-gpu-blocklist', '--disable-quic',
  ],
});
let summary;
try {
  const ctx = await browser.newContext({ viewport: { width: 1024, height: 640 } });
  const tab = await ctx.newPage();
  await tab.route('**/*', (route) => {
    const u = route.request().url();
    if (u.startsWith(base + '/') || u.startsWith('data:') || u.startsWith('blob:')) return route.continue();
    errors.push(`a request tried to leave the machine: ${u}`);
    return route.abort();
  });
  tab.on('console', (m) => {
    if (m.type() === 'error') consoleErrors.push(m.text());
  });
  tab.on('pageerror', (e) => errors.push(`page error: ${e.message}`));
  tab.on('requestfailed', (r) => {
    if (r.url().includes('/tiles/')) errors.push(`tile request failed: ${r.url()} ${r.failure()?.errorText}`);
  });
  tab.on('response', (r) => {
    if (r.url().includes('/tiles/') && r.status() >= 400) errors.push(`tile request ${r.url()}: HTTP ${r.status()}`);
  });
  await tab.goto(base + '/');
  const webgl = await tab.evaluate(() => {
    const gl = document.createElement('canvas').getContext('webgl2') || document.createElement('canvas').getContext('webgl');
    if (!gl) return null;
    const dbg = gl.getExtension('WEBGL_debug_renderer_info');
    return dbg ? gl.getParameter(dbg.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
  });
  if (!webgl) errors.push('WebGL is not available in this Chromium');
  const t0 = Date.now();
  let report;
  for (;;) {
    report = await tab.evaluate(() => window.report);
    if (report.loaded || report.errors.length || errors.length || tileRequests.failed.length) break;
    if (Date.now() - t0 > timeoutMs) break;
    await new Promise((ok) => setTimeout(ok, 250));
  }
  errors.push(...report.errors);
  if (!report.loaded) errors.push(`tiles not loaded after ${timeoutMs / 1000} s`);
  if (report.hasVertexNormals !== true) errors.push('the provider did not take the vertex normals');
  if (report.hasMetadata !== true) errors.push('the provider did not take the metadata extension');
  // Console errors about tiles (CesiumJS logs failed terrain requests there).
  for (const m of consoleErrors) {
    if (/tile|terrain|quantized|\/tiles\//i.test(m)) errors.push(`console: ${m}`);
  }
  if (tileRequests.ok === 0) errors.push('no tile was requested');
  errors.push(...tileRequests.failed.map((f) => `tile request ${f}`));
  await tab.screenshot({ path: outArg });
  summary = {
    webgl, loadedInSeconds: (Date.now() - t0) / 1000, tilesServed: tileRequests.ok,
    deepestLevel: deepest, consoleErrors: consoleErrors.length, screenshot: outArg,
  };
} finally {
  await browser.close();
  server.close();
}
if (errors.length) {
  console.error(`${errors.length} error(s):\n` + errors.slice(0, 30).join('\n'));
  console.log(JSON.stringify(summary));
  process.exit(1);
}
console.log(JSON.stringify(summary));
