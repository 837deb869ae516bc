#!/usr/bin/env node
// Browser benchmark: each model as a single-tile tileset (the original GLB as the one content)
// against bimtiles' tileset, in real CesiumJS (Debian Chromium, SwiftShader WebGL).
//
//   node tools/bench_browser.mjs [--runs 3] [--throttle 20:40] [--json out.json] MODEL.glb|.ifc|.gml|.obj|.fbx|.json...
//
// Options:
//   --runs N           measured loads per variant (default 3), interleaved A/B, B/A, ...
//   --bimtiles PATH    converter binary (default target/release/bimtiles)
//   --convert-args A   extra `bimtiles convert` arguments (default none)
//   --serve-cmd T      command serving a folder at port 0 and printing its URL; {dir} is replaced
//                      (default: `bimtiles serve {dir} --port 0` when the binary has it, else the
//                      scratch server /work/scratch/serve/target/release/serve_scratch)
//   --path-frames N    frames of the scripted far-to-near camera path (default 30; 0: no path)
//   --throttle M:L     network emulated by Chromium (CDP Network.emulateNetworkConditions): M Mbit/s
//                      down and up, L ms latency per request, e.g. 20:40. The page then runs without
//                      the service worker (?cache=0: the worker's own fetches are not throttled), so
//                      there are no warm loads
//   --stops R,R,...    fly-in stops in bounding radii (default 20,6,2.5,1.2,0.6; "none": no fly-in)
//   --runs-for M=N     runs for the model named M (file name without .glb), e.g. a slow big one;
//                      repeatable as a comma list: "A=1,B=2"
//   --raw-glb M=PATH   the raw variant of the model named M is the GLB at PATH (for a model that is
//                      no GLB, e.g. a CityJSON file: the same data as one GLB in the tileset's frame)
//   --no-warm          skip the repeat-visit (warm tile cache) loads
//   --width W --height H   viewport (default 960x540: software WebGL time grows with pixels)
//   --scale S          the page's drawing resolution (?scale=S); default the viewer's own choice:
//                      half the canvas on a software renderer such as SwiftShader, else full
//   --timeout S        per-load timeout (default 180)
//   --query Q          more of the viewer page's query string, e.g. bim=0 (the page without its
//                      BIM tools) or edges=0
//   --json FILE        write the result there too
//   --cpu-profile DIR  write a CPU profile (CDP Profiler, Chrome DevTools' .cpuprofile) of each
//                      measured cold load there, DIR/MODEL-VARIANT-runN.cpuprofile: from the
//                      tileset request to all tiles loaded. Sampling slows the page a little: use
//                      it to see where a load's time goes, not for the figures
//
// A model that is no GLB (IFC, CityGML, CityJSON, OBJ, FBX) has no raw GLB: its raw variant is
// bimtiles' own single-tile GLB of it (one octree cell: --max-tile-triangles and --max-tile-bytes
// at their largest, and the hidden development option --max-leaf-extent-m inf, which lifts the
// octree's leaf extent rule so that a model wider than a leaf, a district or a city tile, is one
// cell too; no coarse root above it, Draco whatever our default, images embedded, the GLB a file
// as a raw model is, not inlined in tileset.json). It is already in the tileset's frame (moved by
// the same anchor as ours). A given --raw-glb, like a GLB model, is in the model's own frame.
//
// Fly-in (each run, each variant, after the cold load): the tileset is loaded again at a new URL
// (nothing cached) with the camera at the first stop, then moved to each stop in turn (heading 0.6,
// pitch -0.45 about the bounding sphere's centre, at that many radii); at each stop, once all its
// tiles are loaded, the tile bytes and requests fetched since the load began (cumulative).
//
// Method (see shared/notes/browser.md): one browser (fresh profile) per model, the viewer page with
// its service-worker tile cache on; both variants are loaded once and discarded first (shader
// compiles, worker start-up), then each measured load replaces the tileset in the same page
// (bimtiles.loadTileset). Each run and variant is a pair of loads of the same URL:
//   cold  a new query string (?run=N), so neither the service worker's Cache API store nor the
//         HTTP cache has any of its files: every byte comes from the server (first visit);
//   warm  the same URL again: tile contents come from the Cache API (repeat visit), tileset JSON
//         is revalidated (304).
// Runs alternate the variant order (A/B, B/A...). After the cold load, a scripted camera path
// from far to near measures frame times and triangles drawn. Figures are medians over the runs.
// Stable ones: requests, bytes, tiles, triangles, tileset memory, JS heap after GC, Cesium CPU ms
// per frame. Wall-clock times drift with the machine's load (reported with the load average);
// FPS mostly measures SwiftShader's fill rate.

import { execFileSync } from "node:child_process";
import { copyFileSync, cpSync, existsSync, mkdirSync, mkdtempSync, readdirSync, readFileSync, rmSync, statSync, writeFileSync } from "node:fs";
import { loadavg, tmpdir } from "node:os";
import { basename, dirname, join, resolve } from "node:path";
import { fileURLToPath } from "node:url";
import { collect, launch, startServer, stopServer, waitLoaded, watch } from "./browser_test.mjs";
import { readGlb, writeGlb } from "./glb.mjs";

const REPO = resolve(dirname(fileURLToPath(import.meta.url)), "..");

function parseArgs(argv) {
  const o = { runs: 3, "path-frames": 30, width: 960, height: 540, timeout: 180, models: [], warm: true, stops: "20,6,2.5,1.2,0.6" };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    if (a === "--no-warm") o.warm = false;
    else if (a.startsWith("--")) o[a.slice(2)] = argv[++i];
    else o.models.push(a);
  }
  for (const k of ["runs", "path-frames", "width", "height", "timeout"]) o[k] = Number(o[k]);
  o.runsFor = {};
  for (const kv of (o["runs-for"] || "").split(",").filter(Boolean)) {
    const [k, v] = kv.split("=");
    o.runsFor[k] = Number(v);
  }
  o.rawGlb = {};
  for (const kv of (o["raw-glb"] || "").split(",").filter(Boolean)) {
    const [k, v] = kv.split("=");
    o.rawGlb[k] = v;
  }
  o.bimtiles = o.bimtiles || join(REPO, "target/release/bimtiles");
  if (o["cpu-profile"]) mkdirSync(o["cpu-profile"], { recursive: true });
  o.stopRadii = o.stops === "none" ? [] : o.stops.split(",").map(Number);
  if (o.stopRadii.some((r) => !(r > 0))) throw new Error(`--stops: radii must be positive numbers, got ${o.stops}`);
  if (o.throttle) {
    const [mbit, latencyMs] = o.throttle.split(":").map(Number);
    if (!(mbit > 0) || !(latencyMs >= 0)) throw new Error(`--throttle wants MBIT:MS, e.g. 20:40, got ${o.throttle}`);
    o.network = { mbit, latencyMs };
    o.warm = false;
  }
  return o;
}

function defaultServeCmd(bimtiles) {
  try {
    execFileSync(bimtiles, ["serve", "--help"], { stdio: "ignore" });
    return `${bimtiles} serve {dir} --port 0`;
  } catch {
    return "/work/scratch/serve/target/release/serve_scratch {dir} --port 0";
  }
}

/**
 * A tileset whose single tile is the original GLB, placed like bimtiles' tileset. `anchored`: the
 * GLB is bimtiles' own, already moved by the anchor.
 */
function rawTileset(ours, glbName, anchored) {
  const anchor = (!anchored && ours.asset.extras && ours.asset.extras.bimtiles && ours.asset.extras.bimtiles.anchor_m) || [0, 0, 0];
  const root = {
    boundingVolume: ours.root.boundingVolume,
    geometricError: 0,
    refine: "ADD",
    content: { uri: glbName },
  };
  if (ours.root.transform) root.transform = ours.root.transform;
  if (anchor.some((v) => v !== 0)) {
    // bimtiles moved the model by -anchor (glTF y-up frame); do the same for the raw GLB with a
    // child tile transform in the tileset's z-up frame: (x, y, z)_gltf -> (x, -z, y).
    const t = [-anchor[0], anchor[2], -anchor[1]];
    root.content = undefined;
    // An empty root with error 0 is never refined (its SSE is 0): the GLB below it would load
    // only once the camera is inside its box.
    root.geometricError = ours.geometricError;
    root.children = [
      {
        boundingVolume: ours.root.boundingVolume,
        geometricError: 0,
        transform: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, t[0], t[1], t[2], 1],
        content: { uri: glbName },
      },
    ];
  }
  return { asset: { version: "1.1" }, geometricError: ours.geometricError, root };
}

/**
 * bimtiles' own GLB of `model` as one tile (one octree cell): the raw file a model that is no GLB
 * (IFC, CityGML, CityJSON, OBJ, FBX) lacks. The metadata schema its properties refer to goes
 * inline into the GLB (EXT_structural_metadata `schema`) and its images are embedded, so the file
 * stands alone as a raw GLB does (two requests with its tileset JSON).
 */
function singleTileGlb(bimtiles, model, outDir) {
  const most = String(2 ** 32 - 1);
  execFileSync(bimtiles, ["convert", model, "--out", outDir, "--quiet", "--compression", "draco", "--max-tile-triangles", most, "--max-tile-bytes", most, "--max-leaf-extent-m", "inf", "--no-coarse-root", "--no-inline-root", "--embed-textures"], { stdio: "inherit" });
  const ts = JSON.parse(readFileSync(join(outDir, "tileset.json")));
  if (!ts.root.content || (ts.root.children && ts.root.children.length))
    throw new Error(`${model}: the single-tile conversion has more than one tile`);
  const glbPath = join(outDir, ts.root.content.uri);
  const { json: gltf, bin } = readGlb(readFileSync(glbPath));
  const metadata = gltf.extensions && gltf.extensions.EXT_structural_metadata;
  if (metadata && metadata.schemaUri) {
    metadata.schema = JSON.parse(readFileSync(join(dirname(glbPath), metadata.schemaUri)));
    delete metadata.schemaUri;
  }
  const standalone = join(outDir, "standalone.glb");
  writeFileSync(standalone, writeGlb(gltf, bin));
  return standalone;
}

function median(a) {
  const s = a.filter((x) => typeof x === "number" && Number.isFinite(x)).sort((x, y) => x - y);
  if (!s.length) return null;
  const m = s.length >> 1;
  return s.length % 2 ? s[m] : (s[m - 1] + s[m]) / 2;
}

function mean(a) {
  const s = a.filter((x) => typeof x === "number" && Number.isFinite(x));
  return s.length ? s.reduce((x, y) => x + y, 0) / s.length : null;
}

function pct(a, p) {
  const s = a.filter((x) => typeof x === "number" && Number.isFinite(x)).sort((x, y) => x - y);
  return s.length ? s[Math.min(s.length - 1, Math.floor((p / 100) * s.length))] : null;
}

/** Bytes of all files under a folder (what a full download of the tileset would be). */
function dirBytes(dir) {
  let n = 0;
  for (const e of readdirSync(dir, { withFileTypes: true }))
    n += e.isDirectory() ? dirBytes(join(dir, e.name)) : statSync(join(dir, e.name)).size;
  return n;
}

async function cameraPath(page, frames) {
  return page.evaluate(async (frames) => {
    const { viewer, tileset } = window.bimtiles;
    const scene = viewer.scene;
    const bs = tileset.boundingSphere;
    const samples = [];
    await new Promise((resolve) => {
      let i = 0;
      let start = 0;
      let last = performance.now();
      const offPre = scene.preUpdate.addEventListener(() => (start = performance.now()));
      const offPost = scene.postRender.addEventListener(() => {
        const now = performance.now();
        if (i > 0)
          samples.push({
            cpuMs: now - start,
            wallMs: now - last,
            triangles: tileset.statistics.numberOfTrianglesSelected,
            tiles: tileset.statistics.selected,
          });
        last = now;
        if (i >= frames) {
          offPre();
          offPost();
          resolve();
          return;
        }
        // Geometric zoom from 8x to 0.3x the bounding radius.
        const range = bs.radius * 8 * Math.pow(0.3 / 8, i / Math.max(1, frames - 1));
        scene.camera.lookAt(bs.center, new Cesium.HeadingPitchRange(0.6, -0.45, range));
        i++;
      });
    });
    return samples;
  }, frames);
}

/**
 * Cesium's own memory figures for the loaded tileset (GPU buffers and textures it tracks), and the
 * same total with property tables counted once per content. Cesium 1.13x adds a model's property
 * tables to its statistics once per runtime *primitive* (PrimitiveStatisticsPipelineStage
 * countBinaryMetadata), so a tile with 21 primitives reports its 30 KB table as 630 KB, while the
 * typed arrays exist once per model. `tilesetMemoryBytes` is the corrected total (what is really
 * held); Cesium's own figures stay in `cesium*` fields.
 */
async function tilesetMemory(page) {
  return page.evaluate(() => {
    const t = window.bimtiles.tileset;
    const s = t.statistics;
    let tablesOnce = 0;
    let batchTextures = 0;
    const seen = new Set();
    const visit = (tile) => {
      const c = tile.content;
      const model = c && c._model;
      if (model && !seen.has(model) && tile.contentReady) {
        seen.add(model);
        const md = model.structuralMetadata;
        if (md) tablesOnce += md.propertyTablesByteLength;
        batchTextures += model.statistics.batchTexturesByteLength;
      }
      for (const ch of tile.children) visit(ch);
    };
    visit(t.root);
    const batchTableBytes = tablesOnce + batchTextures;
    return {
      tilesetMemoryBytes: t.totalMemoryUsageInBytes - s.batchTableByteLength + batchTableBytes,
      geometryBytes: s.geometryByteLength,
      textureBytes: s.texturesByteLength,
      batchTableBytes,
      cesiumTilesetMemoryBytes: t.totalMemoryUsageInBytes,
      cesiumBatchTableBytes: s.batchTableByteLength,
    };
  });
}

/** Chromium's network emulation on `page` (its requests: the page runs without the worker). */
async function throttle(page, network) {
  const cdp = await page.context().newCDPSession(page);
  await cdp.send("Network.enable");
  const bytesPerS = (network.mbit * 1e6) / 8;
  await cdp.send("Network.emulateNetworkConditions", {
    offline: false,
    latency: network.latencyMs,
    downloadThroughput: bytesPerS,
    uploadThroughput: bytesPerS,
  });
  return cdp;
}

/**
 * The fly-in: `url` loaded with nothing refined (the framed view draws what the root has), the
 * camera moved to the first stop, then to each stop in turn; at each, once all its tiles are
 * loaded, what was fetched since the load began (cumulative) and the time since it began.
 */
async function flyIn(page, url, opts) {
  const ok = await page.evaluate((u) => window.bimtiles.loadTileset(u, { maximumScreenSpaceError: 1e9 }), url);
  if (!ok) throw new Error(`cannot load ${url}`);
  const stops = [];
  for (const radii of opts.stopRadii) {
    await page.evaluate((radii) => {
      const { viewer, tileset } = window.bimtiles;
      tileset.maximumScreenSpaceError = 16;
      const bs = tileset.boundingSphere;
      viewer.scene.camera.lookAt(bs.center, new Cesium.HeadingPitchRange(0.6, -0.45, radii * bs.radius));
    }, radii);
    // Some frames at the new camera before the check (browser.md's condition).
    await page.waitForTimeout(200);
    const w = await waitLoaded(page, opts.timeout * 1000);
    if (!w.ok) throw new Error(`${url}: fly-in stop at ${radii} radii: ${w.reason}`);
    const s = await collect(page);
    stops.push({
      radii,
      tileBytes: s.tileBytes,
      tileRequests: s.tileRequests,
      trianglesSelected: s.trianglesSelected,
      sinceLoadMs: await page.evaluate(() => performance.now() - window.bimtilesStatus.tilesetRequestedMs),
    });
  }
  await homeView(page, url, opts);
  return stops;
}

/** Service-worker counters for this page (cumulative: callers take differences). */
async function swCounters(page) {
  const s = await page.evaluate(() => (window.bimtiles.swStats ? window.bimtiles.swStats() : null));
  return s || { hits: 0, misses: 0, networkBytes: 0, invalidations: 0, workerTransferBytes: null };
}

/**
 * One load of `url` in the page; with `path`, then the far-to-near camera path. With `profilePath`,
 * a CPU profile of the load (request to all tiles loaded) is written there.
 */
async function measure(page, url, opts, path = true, profilePath = null) {
  const sw0 = await swCounters(page);
  let profiler = null;
  if (profilePath) {
    profiler = await page.context().newCDPSession(page);
    await profiler.send("Profiler.enable");
    await profiler.send("Profiler.setSamplingInterval", { interval: 200 });
    await profiler.send("Profiler.start");
  }
  // The browser keeps only 250 Resource Timing entries: a fly-in before this load can fill them.
  await page.evaluate(() => performance.clearResourceTimings());
  const ok = await page.evaluate((u) => window.bimtiles.loadTileset(u), url);
  if (!ok) throw new Error(`cannot load ${url}`);
  const w = await waitLoaded(page, opts.timeout * 1000);
  if (!w.ok) throw new Error(`${url}: ${w.reason}`);
  if (profiler) {
    const { profile } = await profiler.send("Profiler.stop");
    writeFileSync(profilePath, JSON.stringify(profile));
    await profiler.detach();
  }
  const s = await collect(page);
  const sw1 = await swCounters(page);
  // Each file fetched for this load (Resource Timing): when its request started and its last
  // byte arrived, from the tileset request on; what is left of allTilesLoadedMs is the client's.
  const fetches = await page.evaluate((t0) =>
    performance
      .getEntriesByType("resource")
      .filter((e) => e.startTime >= t0)
      .map((e) => ({ file: new URL(e.name).pathname.split("/").pop(), startMs: e.startTime - t0, responseEndMs: e.responseEnd - t0 })),
    s.tilesetRequestedMs);
  const r = {
    tilesetJsonMs: s.tilesetReadyMs - s.tilesetRequestedMs,
    firstFrameWithContentMs: s.firstFrameWithContentMs - s.tilesetRequestedMs,
    allTilesLoadedMs: s.allTilesLoadedMs - s.tilesetRequestedMs,
    tileRequests: s.tileRequests,
    tileBytes: s.tileBytes,
    // What the service worker fetched over the network (Resource Timing transferSize: compressed
    // bodies + headers; the only page in this browser is ours, so the worker's total is this load's),
    // and how many tile files it served from its Cache API store.
    // (null when the browser restarted the idle worker in between: its counters started again)
    networkBytes:
      sw1.workerTransferBytes === null || sw1.workerTransferBytes < sw0.workerTransferBytes
        ? null
        : sw1.workerTransferBytes - sw0.workerTransferBytes,
    swFetchedBodyBytes: sw1.networkBytes - sw0.networkBytes,
    cacheHits: sw1.hits - sw0.hits,
    cacheMisses: sw1.misses - sw0.misses,
    tilesLoaded: s.tilesLoaded,
    trianglesSelected: s.trianglesSelected,
    jsHeapBytesAfterGc: s.jsHeapBytesAfterGc,
    ...(await tilesetMemory(page)),
    tileFailures: s.tileFailures.length,
    fetches,
  };
  if (path && opts["path-frames"] > 0) {
    const frames = await cameraPath(page, opts["path-frames"]);
    const wall = frames.map((p) => p.wallMs);
    const cpu = frames.map((p) => p.cpuMs);
    r.pathMeanFps = 1000 / mean(wall);
    r.pathWallFrameMsMean = mean(wall);
    r.pathWallFrameMsP95 = pct(wall, 95);
    r.pathCpuFrameMsMean = mean(cpu);
    r.pathCpuFrameMsP95 = pct(cpu, 95);
    r.pathTrianglesMedian = median(frames.map((p) => p.triangles));
    r.pathTrianglesMax = Math.max(...frames.map((p) => p.triangles));
    // At the near end of the path: wait for its tiles, then what was drawn and downloaded in all.
    const w2 = await waitLoaded(page, opts.timeout * 1000);
    const s2 = await collect(page);
    r.nearAllLoaded = w2.ok ? 1 : 0;
    r.nearTrianglesSelected = s2.trianglesSelected;
    r.totalTileBytes = s2.tileBytes;
    r.totalTileRequests = s2.tileRequests;
    r.nearTilesetMemoryBytes = (await tilesetMemory(page)).tilesetMemoryBytes;
    r.nearJsHeapBytesAfterGc = s2.jsHeapBytesAfterGc;
  }
  await homeView(page, url, opts);
  return r;
}

/** Back to the home view and its tiles, so that every measured load starts from the same camera
 * (a load started at the near end first selects, and requests, the near view's tiles). */
async function homeView(page, url, opts) {
  await page.evaluate(async () => {
    const { viewer, tileset } = window.bimtiles;
    viewer.scene.camera.lookAtTransform(Cesium.Matrix4.IDENTITY);
    await viewer.zoomTo(tileset, new Cesium.HeadingPitchRange(0.6, -0.45, 0));
  });
  const w = await waitLoaded(page, opts.timeout * 1000);
  if (!w.ok) throw new Error(`${url}: back at the home view: ${w.reason}`);
}

function medians(runs) {
  const out = {};
  if (!runs.length) return out;
  for (const k of Object.keys(runs[0]))
    if (typeof runs[0][k] === "number") out[k] = median(runs.map((r) => r[k]));
  // Fly-in stops: medians per stop.
  if (Array.isArray(runs[0].flyIn))
    out.flyIn = runs[0].flyIn.map((stop, i) => {
      const m = { radii: stop.radii };
      for (const k of Object.keys(stop)) if (k !== "radii") m[k] = median(runs.map((r) => r.flyIn[i] && r.flyIn[i][k]));
      return m;
    });
  return out;
}

async function main() {
  const opts = parseArgs(process.argv.slice(2));
  if (!opts.models.length) {
    console.error("usage: node tools/bench_browser.mjs [--runs N] [--json FILE] MODEL.glb...");
    process.exit(2);
  }
  if (!existsSync("/usr/bin/chromium")) {
    console.log("SKIPPED: bench needs /usr/bin/chromium");
    process.exit(process.env.BIMTILES_ALLOW_SKIP === "1" ? 0 : 1);
  }
  const playwright = await import("playwright-core");
  const serveCmd = opts["serve-cmd"] || defaultServeCmd(opts.bimtiles);
  const chromiumVersion = execFileSync("/usr/bin/chromium", ["--version"]).toString().trim();
  const cesiumVersion = JSON.parse(readFileSync(join(REPO, "tools/node_modules/cesium/package.json"))).version;
  const result = {
    date: new Date().toISOString(),
    chromium: chromiumVersion,
    cesium: cesiumVersion,
    viewport: `${opts.width}x${opts.height}`,
    runs: opts.runs,
    pathFrames: opts["path-frames"],
    network: opts.network || null,
    flyInStopsRadii: opts.stopRadii,
    bimtiles: { path: opts.bimtiles, modified: statSync(opts.bimtiles).mtime.toISOString() },
    loadAverageAtStart: loadavg().map((x) => +x.toFixed(2)),
    models: {},
  };
  // Interrupted: stop this model's server and browser and quit (Playwright's own SIGTERM handler
  // only closes the browser, and the loop would go on with the next model).
  let current = {};
  for (const sig of ["SIGINT", "SIGTERM"])
    process.on(sig, () => {
      stopServer(current.server && current.server.proc);
      if (current.browser) rmSync(current.browser.userDataDir, { recursive: true, force: true });
      if (current.dir) rmSync(current.dir, { recursive: true, force: true });
      process.exit(130);
    });
  for (const model of opts.models) {
    const name = basename(model).replace(/\.(glb|city\.jsonl|city\.json|json)$/i, "");
    const dir = mkdtempSync(join(tmpdir(), "bimtiles-bench-"));
    let server = null;
    let browser = null;
    let throttled = null; // the CDP session holding the network emulation
    current = { dir };
    const runs = opts.runsFor[name] || opts.runs;
    const entry = { model, runs: runs, loads: { ours: { cold: [], warm: [] }, raw: { cold: [], warm: [] } } };
    result.models[name] = entry;
    try {
      const oursDir = join(dir, "ours");
      const extra = opts["convert-args"] ? opts["convert-args"].split(/\s+/).filter(Boolean) : [];
      const t = Date.now();
      execFileSync(opts.bimtiles, ["convert", model, "--out", oursDir, "--quiet", ...extra], { stdio: "inherit" });
      entry.convertMs = Date.now() - t;
      // The raw variant: a given GLB, else the model itself when it is a GLB, else our own one-tile GLB.
      const rawIsOurs = !opts.rawGlb[name] && !/\.glb$/i.test(model);
      const rawModel = opts.rawGlb[name] || (rawIsOurs ? singleTileGlb(opts.bimtiles, model, join(dir, "single")) : model);
      const ours = JSON.parse(readFileSync(join(oursDir, "tileset.json")));
      cpSync(join(oursDir, "tileset.json"), join(dir, "tileset.json")); // the server wants one at its root
      const rawDir = join(dir, "raw");
      mkdirSync(rawDir);
      copyFileSync(rawModel, join(rawDir, "model.glb"));
      writeFileSync(join(rawDir, "tileset.json"), JSON.stringify(rawTileset(ours, "model.glb", rawIsOurs), null, 1));
      // Everything a client could download: the whole tileset folder against the GLB.
      entry.diskBytes = { ours: dirBytes(oursDir), raw: statSync(rawModel).size };

      server = current.server = await startServer(serveCmd.replace("{dir}", dir));
      const base = new URL(server.url);
      browser = current.browser = await launch(playwright, opts.width, opts.height);
      const w = watch(browser.context);
      const page = browser.context.pages()[0] || (await browser.context.newPage());
      const variants = {
        ours: new URL("/tileset/ours/tileset.json", base).href,
        raw: new URL("/tileset/raw/tileset.json", base).href,
      };
      // Service worker on (no cache=0): the first page load installs it and it takes control.
      // sse=16 fixes the SSE (the viewer's adaptive strategy off), so both variants are drawn alike.
      // Throttled: no worker at all (a fresh profile and ?cache=0 never register it), and the
      // emulated network on from the first page load.
      if (opts.network) throttled = await throttle(page, opts.network);
      const cacheQuery = opts.network ? "&cache=0" : "";
      const scaleQuery = opts.scale ? `&scale=${opts.scale}` : "";
      const moreQuery = opts.query ? `&${opts.query}` : "";
      await page.goto(new URL(`/?msaa=1&sse=16${cacheQuery}${scaleQuery}${moreQuery}&tileset=${encodeURIComponent(variants.ours + "?warm=0")}`, base).href);
      const w0 = await waitLoaded(page, opts.timeout * 1000);
      if (!w0.ok) throw new Error(`warm-up: ${w0.reason}`);
      entry.serviceWorker = await page.evaluate(() => window.bimtilesStatus.cache);
      // The drawing resolution the page chose (or was given): figures at 0.5 and 1 differ.
      entry.resolutionScale = await page.evaluate(() => window.bimtilesStatus.adaptive.resolutionScale);
      if (opts.warm && !entry.serviceWorker.serviceWorker)
        throw new Error(`service worker not in control (${entry.serviceWorker.reason}): warm loads would not be repeat visits`);
      await measure(page, variants.raw + "?warm=1", opts); // warm-up of the other variant
      for (let run = 0; run < runs; run++) {
        const order = run % 2 === 0 ? ["ours", "raw"] : ["raw", "ours"];
        for (const v of order) {
          const url = `${variants[v]}?run=${run}`;
          const profilePath = opts["cpu-profile"] ? join(opts["cpu-profile"], `${name}-${v}-run${run}.cpuprofile`) : null;
          const cold = await measure(page, url, opts, true, profilePath);
          if (opts.stopRadii.length) cold.flyIn = await flyIn(page, `${variants[v]}?fly=${run}`, opts);
          entry.loads[v].cold.push(cold);
          let line = `${name} run ${run} ${v}: cold all tiles ${Math.round(cold.allTilesLoadedMs)} ms, ${cold.tileBytes} B`;
          if (cold.flyIn) line += `; fly-in ${cold.flyIn.map((f) => `${f.radii}r ${f.tileBytes} B`).join(", ")}`;
          if (opts.warm) {
            const warm = await measure(page, url, opts, false);
            entry.loads[v].warm.push(warm);
            line += `; warm ${Math.round(warm.allTilesLoadedMs)} ms, ${warm.networkBytes} B from the server, ${warm.cacheHits} cache hits`;
          }
          process.stderr.write(line + "\n");
        }
      }
      entry.median = {};
      for (const v of ["ours", "raw"]) entry.median[v] = { cold: medians(entry.loads[v].cold), warm: medians(entry.loads[v].warm) };
      entry.externalRequests = w.external.length;
      entry.consoleErrors = w.consoleErrors;
    } catch (e) {
      entry.error = String(e && e.message ? e.message : e);
    } finally {
      if (throttled) await throttled.detach().catch(() => {});
      if (browser) {
        await browser.context.close().catch(() => {});
        rmSync(browser.userDataDir, { recursive: true, force: true });
      }
      stopServer(server && server.proc);
      rmSync(dir, { recursive: true, force: true });
    }
  }
  result.loadAverageAtEnd = loadavg().map((x) => +x.toFixed(2));
  const text = JSON.stringify(result, null, 2);
  console.log(text);
  if (opts.json) writeFileSync(opts.json, text + "\n");
  const failed = Object.values(result.models).some((m) => m.error);
  process.exit(failed ? 1 : 0);
}

main();
