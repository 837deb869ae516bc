#!/usr/bin/env node
// Frame rate and Cesium CPU time per frame with and without the viewer's adaptive strategy
// (viewer/adaptive.js, paper IV.B), in real CesiumJS (headless Chromium, SwiftShader).
//
//   node tools/bench_adaptive.mjs --server-cmd "bimtiles serve DIR --port 0" [--runs 2]
//        [--seconds 10] [--fps 30] [--json FILE]
//
// Variants, interleaved per run: "adaptive" (the default page, target --fps) and "fixed" (?sse=16:
// Cesium's default SSE, adaptation off). Each loads the page, waits for all tiles of the framed view
// (or --timeout s), then measures --seconds still and --seconds orbiting the model (the same
// angular speed in both variants, so the same path): frames per second, median and p95 Cesium CPU
// ms per frame (scene.preUpdate -> postRender), triangles drawn, the SSE in use, tile requests.
// In SwiftShader the frame time mostly measures fill rate: compare the variants, not the figures
// with a GPU's.

import { launch, startServer, stopServer, waitLoaded, collect } from "./browser_test.mjs";
import { writeFileSync, rmSync } from "node:fs";

function parseArgs(argv) {
  const o = { runs: 2, seconds: 10, fps: 30, timeout: 240, width: 1280, height: 720 };
  for (let i = 0; i < argv.length; i += 2) {
    if (!argv[i].startsWith("--") || argv[i + 1] === undefined) throw new Error(`bad argument ${argv[i]}`);
    o[argv[i].slice(2)] = argv[i + 1];
  }
  for (const k of ["runs", "seconds", "fps", "timeout", "width", "height"]) o[k] = Number(o[k]);
  if (!o["server-cmd"]) throw new Error("give --server-cmd CMD");
  return o;
}

/** Runs `seconds` of frames in the page, orbiting the model when `orbit`; per-frame figures. */
function phase(page, seconds, orbit) {
  return page.evaluate(
    ([seconds, orbit]) =>
      new Promise((resolve) => {
        const { viewer, tileset } = window.bimtiles;
        const scene = viewer.scene;
        const cam = scene.camera;
        const status = window.bimtilesStatus;
        if (orbit) cam.lookAtTransform(Cesium.Transforms.eastNorthUpToFixedFrame(tileset.boundingSphere.center));
        const RAD_PER_S = (2 * Math.PI) / 20; // a full turn in 20 s
        const t0 = performance.now();
        let last = t0;
        const frames = [];
        const requests0 = status.tileRequests;
        const off = scene.postRender.addEventListener(() => {
          const now = performance.now();
          frames.push({
            cpuMs: status.cpuFrameMs[status.cpuFrameMs.length - 1],
            triangles: tileset.statistics.numberOfTrianglesSelected,
            sse: tileset.maximumScreenSpaceError,
          });
          if (orbit) cam.rotateRight(RAD_PER_S * ((now - last) / 1000));
          last = now;
          if (now - t0 >= seconds * 1000) {
            off();
            if (orbit) cam.lookAtTransform(Cesium.Matrix4.IDENTITY);
            const cpu = frames.map((f) => f.cpuMs).sort((a, b) => a - b);
            const mean = (k) => frames.reduce((s, f) => s + f[k], 0) / frames.length;
            resolve({
              fps: +((1000 * frames.length) / (now - t0)).toFixed(2),
              cpuMsMedian: cpu[cpu.length >> 1],
              cpuMsP95: cpu[Math.min(cpu.length - 1, Math.floor(0.95 * cpu.length))],
              trianglesMean: Math.round(mean("triangles")),
              sseMean: +mean("sse").toFixed(1),
              tileRequests: status.tileRequests - requests0,
              tilesetMemoryBytes: tileset.totalMemoryUsageInBytes,
            });
          }
        });
      }),
    [seconds, orbit],
  );
}

async function main() {
  const o = parseArgs(process.argv.slice(2));
  const playwright = await import("playwright-core");
  const server = await startServer(o["server-cmd"]);
  const browser = await launch(playwright, o.width, o.height);
  const results = [];
  try {
    const page = browser.context.pages()[0] || (await browser.context.newPage());
    const variants = { adaptive: `msaa=1&fps=${o.fps}`, fixed: "msaa=1&sse=16" };
    // One load first: shader compiles and worker start-up are paid once, not by the first variant.
    await page.goto(`${server.url}?${variants.fixed}`, { waitUntil: "load" });
    await waitLoaded(page, o.timeout * 1000);
    for (let run = 0; run < o.runs; run++) {
      for (const [name, q] of Object.entries(variants)) {
        await page.goto(`${server.url}?${q}&run=${run}`, { waitUntil: "load" });
        const wait = await waitLoaded(page, o.timeout * 1000);
        const load = await collect(page);
        const still = await phase(page, o.seconds, false);
        const orbit = await phase(page, o.seconds, true);
        const r = {
          variant: name,
          run,
          loaded: wait.ok,
          loadMs: load.allTilesLoadedMs === null ? null : load.allTilesLoadedMs - load.tilesetRequestedMs,
          strategy: load.adaptive && load.adaptive.line,
          still,
          orbit,
        };
        results.push(r);
        console.log(JSON.stringify(r));
      }
    }
  } finally {
    await browser.context.close().catch(() => {});
    rmSync(browser.userDataDir, { recursive: true, force: true });
    stopServer(server.proc);
  }
  const summary = {};
  for (const name of ["adaptive", "fixed"]) {
    const rs = results.filter((r) => r.variant === name);
    const med = (f) => {
      const v = rs.map(f).sort((a, b) => a - b);
      return v[v.length >> 1];
    };
    summary[name] = {
      stillFps: med((r) => r.still.fps),
      stillCpuMs: med((r) => r.still.cpuMsMedian),
      stillTriangles: med((r) => r.still.trianglesMean),
      orbitFps: med((r) => r.orbit.fps),
      orbitCpuMs: med((r) => r.orbit.cpuMsMedian),
      orbitCpuMsP95: med((r) => r.orbit.cpuMsP95),
      orbitTriangles: med((r) => r.orbit.trianglesMean),
      orbitSse: med((r) => r.orbit.sseMean),
      tilesetMemoryBytes: med((r) => r.orbit.tilesetMemoryBytes),
    };
  }
  console.log(JSON.stringify({ summary }, null, 2));
  if (o.json) writeFileSync(o.json, JSON.stringify({ options: o, results, summary }, null, 2) + "\n");
}

main().catch((e) => {
  console.error(e);
  process.exit(1);
});
