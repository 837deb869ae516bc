#!/usr/bin/env node
// End-to-end browser test of the bimtiles viewer: Debian's Chromium (headless, SwiftShader WebGL)
// driven by playwright-core.
//
//   node tools/browser_test.mjs --url http://127.0.0.1:8080/ [--out shot.png]
//   node tools/browser_test.mjs --server-cmd "bimtiles serve out/sample --port 0" [--out shot.png]
//
// Options:
//   --url URL            viewer page to load
//   --server-cmd CMD     start a server with `bash -c CMD`; its URL is the first http://... it prints
//                        on stdout; it is stopped at the end
//   --out FILE           screenshot (PNG) of the loaded view
//   --query Q            extra page query, e.g. "msaa=1&sse=8" (default "msaa=1")
//   --second-load        reload the page (service-worker tile cache warm) and report that load too
//   --timeout S          seconds to wait for all tiles (default 120)
//   --width W --height H viewport (default 1280x720)
//   --require-pick       fail if clicking the centre of the view, or a point near it, picks
//                        nothing (a district's centre can fall on a street between buildings)
//   --require-texture S  fail unless at least the share S of neighbouring pixels on one face
//                        differ in colour (texturedShare): a textured model not drawn untextured
//   --min-drawn-pct P    the share of pixels the tileset must change (default 1; a wide, sparse
//                        scene framed whole covers less)
//   --check-adaptive     also check the adaptive strategy (checkAdaptive): SSE up for ?fps=1000,
//                        down for ?fps=0.1, within bounds; ?sse=N fixed
//   --json FILE          also write the summary there
//
// Checks: the page reaches "all tiles loaded" (browser.md's condition), no tile failed, no console
// error, no request to anything but the loopback host, the view is not blank (more than 1% of
// the pixels change when the tileset is hidden), the adaptive status line is shown. Prints a JSON summary; exits 1 on failure.
// On a failure it also prints the requests still open (how long, how far they got) and, with
// --server-cmd, the server's stderr (`bimtiles serve` logs each connection and request there
// when BIMTILES_SERVE_LOG=1).
// Without /usr/bin/chromium: prints SKIPPED and exits 0 only if BIMTILES_ALLOW_SKIP=1.

import { spawn } from "node:child_process";
import { existsSync, mkdtempSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";

const CHROMIUM = process.env.BIMTILES_CHROMIUM || "/usr/bin/chromium";
export const CHROME_ARGS = [
  "--no-sandbox",
  "--disable-background-networking",
  "--disable-component-update",
  "--disable-sync",
  "--no-first-run",
  "--enable-precise-memory-info",
  "--use-gl=angle",
  "--use-angle=swiftshader",
  "--enable-unsafe-swiftshader",
];

function parseArgs(argv) {
  const o = { query: "msaa=1", timeout: 120, width: 1280, height: 720, "min-drawn-pct": 1 };
  const flags = new Set(["second-load", "require-pick", "check-adaptive"]);
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    if (!a.startsWith("--")) throw new Error(`unexpected argument ${a}`);
    const k = a.slice(2);
    if (flags.has(k)) o[k] = true;
    else {
      if (i + 1 >= argv.length) throw new Error(`${a} needs a value`);
      o[k] = argv[++i];
    }
  }
  for (const k of ["timeout", "width", "height", "min-drawn-pct", "require-texture"]) if (k in o) o[k] = Number(o[k]);
  return o;
}

/** Starts `bash -c cmd` in its own process group; resolves with {proc, url, stderr()} (all it
 * wrote to stderr so far). */
export function startServer(cmd, timeoutMs = 60000) {
  return new Promise((resolve, reject) => {
    const proc = spawn("bash", ["-c", cmd], { detached: true, stdio: ["ignore", "pipe", "pipe"] });
    let out = "";
    let err = "";
    const stderr = () => err;
    const timer = setTimeout(() => {
      stopServer(proc);
      reject(new Error(`server printed no URL within ${timeoutMs / 1000} s\nstdout: ${out}\nstderr: ${err}`));
    }, timeoutMs);
    proc.stdout.on("data", (d) => {
      out += d;
      const m = out.match(/https?:\/\/[^\s"')]+/);
      if (m) {
        clearTimeout(timer);
        resolve({ proc, url: m[0], stderr });
      }
    });
    proc.stderr.on("data", (d) => (err += d));
    proc.on("exit", (code) => {
      clearTimeout(timer);
      reject(new Error(`server exited (${code}) before printing a URL\nstdout: ${out}\nstderr: ${err}`));
    });
  });
}

export function stopServer(proc) {
  if (!proc || proc.exitCode !== null) return;
  try {
    process.kill(-proc.pid, "SIGTERM"); // the group we created (detached), nothing else
  } catch {
    /* already gone */
  }
}

export async function launch(playwright, width, height) {
  const userDataDir = mkdtempSync(join(tmpdir(), "bimtiles-chromium-"));
  const context = await playwright.chromium.launchPersistentContext(userDataDir, {
    executablePath: CHROMIUM,
    headless: true,
    args: CHROME_ARGS,
    viewport: { width, height },
  });
  return { context, userDataDir };
}

const LOCAL_HOSTS = new Set(["127.0.0.1", "localhost", "[::1]"]);
export function isLocal(url) {
  if (/^(data|blob|about|chrome|devtools):/.test(url)) return true;
  try {
    return LOCAL_HOSTS.has(new URL(url).hostname) || new URL(url).hostname === "::1";
  } catch {
    return false;
  }
}

/** Watches a context: external requests, failed responses, console errors. */
export function watch(context) {
  const w = { external: [], httpErrors: [], consoleErrors: [], requests: 0 };
  context.on("request", (r) => {
    w.requests++;
    if (!isLocal(r.url())) w.external.push(r.url());
  });
  context.on("response", (r) => {
    if (r.status() >= 400) w.httpErrors.push(`${r.status()} ${r.url()}`);
  });
  context.on("requestfailed", (r) => {
    const f = r.failure();
    // Cesium cancels requests for tiles that left the view: not an error.
    if (f && !/ERR_ABORTED/.test(f.errorText)) w.httpErrors.push(`${f.errorText} ${r.url()}`);
  });
  const onPage = (page) => {
    page.on("console", (m) => {
      if (m.type() === "error") w.consoleErrors.push(m.text().slice(0, 500));
    });
    page.on("pageerror", (e) => w.consoleErrors.push("pageerror: " + String(e.message || e).slice(0, 500)));
  };
  context.pages().forEach(onPage);
  context.on("page", onPage);
  return w;
}

/**
 * Follows every request of the context (page and service worker) to say, at a timeout, which
 * ones are still open and how far each got. Playwright's events give issued / headers received /
 * finished; the page's CDP Network events add whether the network stack really sent it (a request
 * queued for a socket, e.g. behind Chromium's 6 connections per host, is not), the connection it
 * went on and the body bytes received. Requests a service worker answers are followed by
 * Playwright only (CDP here sees the page's side).
 */
export async function trackRequests(context, page) {
  const t0 = Date.now();
  const open = new Map(); // Playwright Request -> entry
  const byUrl = new Map(); // url -> entries still open, for matching CDP events
  context.on("request", (r) => {
    if (!/^https?:/.test(r.url())) return; // blob: and data: never touch the server
    const sw = typeof r.serviceWorker === "function" && r.serviceWorker() ? "service worker" : "page";
    const e = { url: r.url(), method: r.method(), from: sw, startMs: Date.now() - t0, state: "issued" };
    open.set(r, e);
    if (!byUrl.has(e.url)) byUrl.set(e.url, []);
    byUrl.get(e.url).push(e);
  });
  const close = (r) => {
    const e = open.get(r);
    if (!e) return;
    open.delete(r);
    const l = byUrl.get(e.url) || [];
    l.splice(l.indexOf(e), 1);
  };
  context.on("response", (r) => {
    const e = open.get(r.request());
    if (e) Object.assign(e, { state: "headers received", status: r.status(), headersMs: Date.now() - t0 });
  });
  context.on("requestfinished", close);
  context.on("requestfailed", close);

  const net = new Map(); // CDP requestId -> {url, sent, connectionId, remotePort, bytes, fromServiceWorker}
  try {
    const cdp = await context.newCDPSession(page);
    await cdp.send("Network.enable");
    cdp.on("Network.requestWillBeSent", (ev) => net.set(ev.requestId, { url: ev.request.url, sent: false, bytes: 0 }));
    // Fired when the network stack puts the request on a connection (not for a queued one).
    cdp.on("Network.requestWillBeSentExtraInfo", (ev) => {
      const n = net.get(ev.requestId);
      if (n) n.sent = true;
    });
    cdp.on("Network.responseReceived", (ev) => {
      const n = net.get(ev.requestId);
      if (n)
        Object.assign(n, {
          connectionId: ev.response.connectionId,
          remotePort: ev.response.remotePort,
          fromServiceWorker: ev.response.fromServiceWorker,
        });
    });
    cdp.on("Network.dataReceived", (ev) => {
      const n = net.get(ev.requestId);
      if (n) n.bytes += ev.dataLength;
    });
    const done = (ev) => net.delete(ev.requestId);
    cdp.on("Network.loadingFinished", done);
    cdp.on("Network.loadingFailed", done);
  } catch (e) {
    /* no CDP: Playwright's view only */
  }

  return {
    /** The requests still open, oldest first. */
    pending() {
      const now = Date.now() - t0;
      const nets = [...net.values()];
      return [...open.values()]
        .sort((a, b) => a.startMs - b.startMs)
        .map((e) => {
          const n = e.from === "page" ? nets.find((x) => x.url === e.url) : null;
          const p = { ...e, pendingMs: now - e.startMs };
          if (n)
            Object.assign(p, {
              sentOnNetwork: n.sent,
              connectionId: n.connectionId,
              remotePort: n.remotePort,
              fromServiceWorker: n.fromServiceWorker,
              bodyBytes: n.bytes,
            });
          return p;
        });
    },
  };
}

/** One line per open request, for the log. */
function describePending(list) {
  return list
    .map((p) => {
      const bits = [`${(p.pendingMs / 1000).toFixed(1)} s`, p.from, p.state];
      if (p.status) bits.push(`status ${p.status}`);
      if (p.sentOnNetwork !== undefined)
        bits.push(p.sentOnNetwork ? "sent on a connection" : "not on a connection (queued for a socket, or with the service worker)");
      if (p.connectionId) bits.push(`connection ${p.connectionId}`);
      if (p.bodyBytes) bits.push(`${p.bodyBytes} body bytes`);
      return `  ${p.method} ${p.url}  (${bits.join(", ")}; issued at ${(p.startMs / 1000).toFixed(1)} s)`;
    })
    .join("\n");
}

/** Waits until the viewer reports all tiles loaded (or an error / timeout). */
export async function waitLoaded(page, timeoutMs) {
  const start = Date.now();
  for (;;) {
    const s = await page.evaluate(() => {
      const s = window.bimtilesStatus;
      return s ? { ready: s.ready, all: s.allTilesLoaded, error: s.error, failures: s.tileFailures.length } : null;
    });
    if (s && s.error) return { ok: false, reason: "viewer error: " + s.error };
    if (s && s.ready && s.all) return { ok: true, waitedMs: Date.now() - start };
    if (Date.now() - start > timeoutMs) return { ok: false, reason: `not all tiles loaded after ${timeoutMs / 1000} s` };
    await page.waitForTimeout(100);
  }
}

function median(a) {
  if (!a.length) return null;
  const s = [...a].sort((x, y) => x - y);
  const m = s.length >> 1;
  return s.length % 2 ? s[m] : (s[m - 1] + s[m]) / 2;
}
function pct(a, p) {
  if (!a.length) return null;
  const s = [...a].sort((x, y) => x - y);
  return s[Math.min(s.length - 1, Math.floor((p / 100) * s.length))];
}

/** The status figures, with JS heap measured after a forced GC. */
export async function collect(page) {
  const cdp = await page.context().newCDPSession(page);
  await cdp.send("HeapProfiler.collectGarbage").catch(() => {});
  await cdp.detach().catch(() => {});
  const s = await page.evaluate(async () => {
    const s = JSON.parse(JSON.stringify(window.bimtilesStatus));
    s.jsHeapBytesAfterGc = performance.memory ? performance.memory.usedJSHeapSize : null;
    s.serviceWorkerStats = window.bimtiles && window.bimtiles.swStats ? await window.bimtiles.swStats() : null;
    return s;
  });
  const frames = s.cpuFrameMs || [];
  delete s.cpuFrameMs;
  delete s._hudLoaded;
  s.cpuFrameMsMedian = median(frames);
  s.cpuFrameMsP95 = pct(frames, 95);
  for (const k of ["tilesetRequestedMs", "tilesetReadyMs", "firstFrameWithContentMs", "allTilesLoadedMs"])
    if (typeof s[k] === "number") s[k] = Math.round(s[k]);
  return s;
}

/** A screenshot of the canvas alone (panels hidden). */
export async function canvasShot(page) {
  await page.evaluate(() => document.querySelectorAll(".panel").forEach((e) => (e.style.visibility = "hidden")));
  await frames(page, 3);
  const png = await page.screenshot();
  await page.evaluate(() => document.querySelectorAll(".panel").forEach((e) => (e.style.visibility = "")));
  return png;
}

/** Runs `analyse(images, arg)` in the page on PNG screenshots decoded there (RGBA arrays), and
 * returns its (small) result: the pixels never cross the wire. */
export async function pixels(page, pngs, analyse, arg = null) {
  return page.evaluate(
    async ([list, source, arg]) => {
      const images = [];
      for (const b64 of list) {
        const blob = await (await fetch("data:image/png;base64," + b64)).blob();
        const bmp = await createImageBitmap(blob);
        const c = new OffscreenCanvas(bmp.width, bmp.height);
        const ctx = c.getContext("2d");
        ctx.drawImage(bmp, 0, 0);
        images.push(ctx.getImageData(0, 0, bmp.width, bmp.height).data);
      }
      const differs = (a, b, i) => Math.abs(a[i] - b[i]) + Math.abs(a[i + 1] - b[i + 1]) + Math.abs(a[i + 2] - b[i + 2]) > 24;
      return new Function("images", "arg", "differs", `return (${source})(images, arg, differs);`)(images, arg, differs);
    },
    [pngs.map((p) => p.toString("base64")), analyse.toString(), arg],
  );
}

/** Share of pixels (0..1) that differ between two PNG screenshots, decoded by the page itself. */
export async function changedShare(page, pngA, pngB) {
  return pixels(page, [pngA, pngB], ([a, b], _, differs) => {
    let changed = 0;
    for (let i = 0; i < a.length; i += 4) if (differs(a, b, i)) changed++;
    return changed / (a.length / 4);
  });
}

/** Waits for `n` rendered frames. */
export async function frames(page, n) {
  await page.evaluate(
    (n) =>
      new Promise((resolve) => {
        const scene = window.bimtiles.viewer.scene;
        let k = 0;
        const off = scene.postRender.addEventListener(() => {
          if (++k >= n) {
            off();
            resolve();
          }
        });
      }),
    n,
  );
}

/** Screenshot with and without the tileset (overlays hidden): share of changed pixels. */
export async function notBlank(page) {
  const shown = await canvasShot(page);
  await page.evaluate(() => (window.bimtiles.tileset.show = false));
  const hidden = await canvasShot(page);
  await page.evaluate(() => (window.bimtiles.tileset.show = true));
  await frames(page, 3);
  return changedShare(page, shown, hidden);
}

/** How textured the drawn model looks. The frame is drawn again with every surface's colour set
 * to white: two neighbouring pixels alike there lie on one face under the same light, so where
 * they differ in the real frame, the surface's own colour changes within the face: a texture. A
 * flat material changes only at element borders. Returns the share of such neighbour pairs (of
 * the model's pixels, right and down neighbours) whose colours differ. */
export async function texturedShare(page) {
  const shown = await canvasShot(page);
  await page.evaluate(() => {
    window.bimtiles.tileset.customShader = new Cesium.CustomShader({
      fragmentShaderText: "void fragmentMain(FragmentInput fsInput, inout czm_modelMaterial material) { material.diffuse = vec3(1.0); }",
    });
  });
  await frames(page, 10);
  const white = await canvasShot(page);
  await page.evaluate(() => (window.bimtiles.tileset.show = false));
  const background = await canvasShot(page);
  await page.evaluate(() => {
    window.bimtiles.tileset.show = true;
    window.bimtiles.tileset.customShader = undefined;
  });
  await frames(page, 10);
  return pixels(page, [shown, white, background], ([s, w, b], width, differs) => {
    const alike = (a, i, j, tol) => Math.abs(a[i] - a[j]) + Math.abs(a[i + 1] - a[j + 1]) + Math.abs(a[i + 2] - a[j + 2]) <= tol;
    let pairs = 0, textured = 0;
    for (let i = 0; i < s.length; i += 4) {
      if (!differs(w, b, i)) continue;
      for (const j of [i + 4, i + 4 * width]) {
        if (j >= s.length || !differs(w, b, j) || !alike(w, i, j, 3)) continue;
        pairs++;
        if (!alike(s, i, j, 12)) textured++;
      }
    }
    return { pairs, share: pairs ? +(textured / pairs).toFixed(4) : 0 };
  }, await page.evaluate(() => window.bimtiles.viewer.canvas.width));
}

/** The adaptive strategy's state (viewer/adaptive.js) and the status line's text. */
export async function adaptiveState(page) {
  return page.evaluate(() => ({
    ...(window.bimtilesStatus.adaptive || {}),
    line: document.getElementById("adaptive").textContent,
    tilesetSse: window.bimtiles.tileset ? window.bimtiles.tileset.maximumScreenSpaceError : null,
  }));
}

/** Polls the adaptive state until `done(state)` or `timeoutMs`; returns the last state. */
async function waitAdaptive(page, done, timeoutMs) {
  const start = Date.now();
  for (;;) {
    const s = await adaptiveState(page);
    if (done(s) || Date.now() - start > timeoutMs) return s;
    await page.waitForTimeout(250);
  }
}

/**
 * In SwiftShader frames are slow (a few fps): a target of 1000 fps must drive the SSE up to the
 * strategy's maximum, a target of 0.1 fps down to its minimum, and it must stay within the bounds;
 * a software rasteriser draws at half resolution unless ?scale=1; ?sse=N fixes the SSE. Returns the
 * failures.
 */
export async function checkAdaptive(context, url, timeoutMs = 90000) {
  const failures = [];
  const page = await context.newPage();
  const inBounds = (s) => s.sse >= s.sseMin && s.sse <= s.sseMax && s.tilesetSse >= s.sseMin && s.tilesetSse <= s.sseMax;
  try {
    for (const [fps, bound, dir] of [[1000, "sseMax", "up"], [0.1, "sseMin", "down"]]) {
      await page.goto(withQuery(url, `msaa=1&fps=${fps}`), { waitUntil: "load" });
      const s = await waitAdaptive(page, (s) => s.sse !== undefined && s.sse === s[bound], timeoutMs);
      if (s.targetFps !== fps) failures.push(`?fps=${fps}: target ${s.targetFps}`);
      if (!s.adaptive || s.sse !== s[bound]) failures.push(`?fps=${fps}: SSE did not go ${dir} to ${s[bound]}: ${s.line}`);
      await page.waitForTimeout(2500); // two more windows: it stays at the bound
      const after = await adaptiveState(page);
      if (after.sse !== s[bound] || !inBounds(after)) failures.push(`?fps=${fps}: SSE left its bounds: ${after.line}`);
      if (!/SSE/.test(after.line) || !/fps/.test(after.line)) failures.push(`status line lacks SSE / fps: ${after.line}`);
    }
    // The drawing resolution: half on a software rasteriser (SwiftShader here), full with ?scale=1;
    // the renderer asked here through a canvas of the test's own.
    for (const [query, forced] of [["msaa=1", null], ["msaa=1&scale=1", 1]]) {
      await page.goto(withQuery(url, query), { waitUntil: "load" });
      const s = await waitAdaptive(page, (s) => s.resolutionScale !== undefined, timeoutMs);
      const r = await page.evaluate(() => {
        const gl = document.createElement("canvas").getContext("webgl2");
        const info = gl && gl.getExtension("WEBGL_debug_renderer_info");
        const name = gl ? String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER)) : "";
        const { viewer } = window.bimtiles;
        return { name, bufferPx: viewer.scene.drawingBufferWidth, canvasPx: viewer.canvas.clientWidth };
      });
      const software = /swiftshader|llvmpipe|softpipe/i.test(r.name);
      const scale = forced ?? (software ? 0.5 : 1);
      if (s.resolutionScale !== scale || Math.abs(r.bufferPx - scale * r.canvasPx) > 2)
        failures.push(`?${query} on "${r.name}": drawn at ${r.bufferPx} px of ${r.canvasPx} (scale ${s.resolutionScale}), not ${scale}x`);
      if (software !== s.softwareRenderer || (software && !/software WebGL/.test(s.line)))
        failures.push(`renderer "${r.name}": software ${software}, but the strategy says ${s.softwareRenderer}: ${s.line}`);
    }
    await page.goto(withQuery(url, "msaa=1&fps=1000&sse=12"), { waitUntil: "load" });
    const s = await waitAdaptive(page, (s) => s.fps !== null && s.fps !== undefined, timeoutMs);
    await page.waitForTimeout(2500);
    const f = await adaptiveState(page);
    if (f.adaptive || f.sse !== 12 || f.tilesetSse !== 12 || s.fps === undefined)
      failures.push(`?sse=12 is not a fixed SSE: ${f.line} (tileset SSE ${f.tilesetSse})`);
  } catch (e) {
    failures.push("adaptive check: " + String(e && e.message ? e.message : e));
  } finally {
    await page.close().catch(() => {});
  }
  return failures;
}

function withQuery(url, q) {
  if (!q) return url;
  return url + (url.includes("?") ? "&" : "?") + q;
}

async function main() {
  let opts;
  try {
    opts = parseArgs(process.argv.slice(2));
  } catch (e) {
    console.error(`error: ${e.message}`);
    process.exit(2);
  }
  if (!opts.url && !opts["server-cmd"]) {
    console.error("error: give --url URL or --server-cmd CMD");
    process.exit(2);
  }
  if (!existsSync(CHROMIUM)) {
    const allow = process.env.BIMTILES_ALLOW_SKIP === "1";
    console.log(`SKIPPED: browser test needs ${CHROMIUM} (apt-get install chromium)${allow ? "" : "; set BIMTILES_ALLOW_SKIP=1 to allow skipping"}`);
    process.exit(allow ? 0 : 1);
  }
  let playwright;
  try {
    playwright = await import("playwright-core");
  } catch (e) {
    console.error("error: playwright-core is not installed (cd tools && npm ci)");
    process.exit(1);
  }

  const failures = [];
  const summary = { ok: false, url: null, failures };
  let server = null;
  let browser = null;
  try {
    if (opts["server-cmd"]) {
      server = await startServer(opts["server-cmd"]);
      summary.url = server.url;
    } else summary.url = opts.url;

    browser = await launch(playwright, opts.width, opts.height);
    const w = watch(browser.context);
    const page = browser.context.pages()[0] || (await browser.context.newPage());
    const tracker = await trackRequests(browser.context, page);
    const url = withQuery(summary.url, opts.query);
    const t = Date.now();
    await page.goto(url, { waitUntil: "load" });
    const wait = await waitLoaded(page, opts.timeout * 1000);
    summary.load = await collect(page);
    summary.load.wallMs = Date.now() - t;
    if (!wait.ok) {
      failures.push(wait.reason);
      summary.pendingRequests = tracker.pending();
      console.error(`${summary.pendingRequests.length} request(s) still open at the failure:\n${describePending(summary.pendingRequests)}`);
    }

    if (summary.load.ready) {
      const share = await notBlank(page);
      summary.changedPixelsPct = +(share * 100).toFixed(2);
      if (share * 100 <= opts["min-drawn-pct"])
        failures.push(`view looks blank: only ${summary.changedPixelsPct}% of pixels show the tileset`);
      if (opts.out) {
        await page.screenshot({ path: opts.out });
        summary.screenshot = opts.out;
      }
      // The centre first, then rings around it (up to a tenth of the view's height away): the
      // first point that picks an element, and where it is.
      const [cx, cy] = [Math.round(opts.width / 2), Math.round(opts.height / 2)];
      const reach = Math.round(opts.height / 10);
      const points = [[0, 0]];
      for (let r = Math.round(reach / 4); r <= reach; r += Math.round(reach / 4))
        for (let k = 0; k < 8; k++) {
          const a = (k * Math.PI) / 4;
          points.push([Math.round(r * Math.cos(a)), Math.round(r * Math.sin(a))]);
        }
      for (const [dx, dy] of points) {
        summary.pick = await page.evaluate(([x, y]) => window.bimtiles.pickAt(x, y), [cx + dx, cy + dy]);
        if (summary.pick) {
          summary.pickOffsetPx = [dx, dy];
          break;
        }
      }
      if (opts["require-pick"] && !summary.pick)
        failures.push(`clicking the centre of the view, or within ${reach} px of it, picked nothing`);
      summary.textured = await texturedShare(page);
      if (opts["require-texture"] && !(summary.textured.share >= opts["require-texture"]))
        failures.push(`the model looks untextured: ${summary.textured.share} of ${summary.textured.pairs} neighbouring pixel pairs on one face differ in colour, below ${opts["require-texture"]}`);
      summary.adaptive = await adaptiveState(page);
      if (!summary.adaptive.strategy || !summary.adaptive.line) failures.push("no adaptive strategy status line");
    }
    if (opts["check-adaptive"] && wait.ok) failures.push(...(await checkAdaptive(browser.context, summary.url)));

    if (opts["second-load"] && wait.ok) {
      const t2 = Date.now();
      await page.reload({ waitUntil: "load" });
      const wait2 = await waitLoaded(page, opts.timeout * 1000);
      summary.secondLoad = await collect(page);
      summary.secondLoad.wallMs = Date.now() - t2;
      if (!wait2.ok) {
        failures.push("second load: " + wait2.reason);
        summary.pendingRequests = tracker.pending();
        console.error(`${summary.pendingRequests.length} request(s) still open at the failure:\n${describePending(summary.pendingRequests)}`);
      }
    }

    const loads = [summary.load, summary.secondLoad].filter(Boolean);
    for (const l of loads) {
      for (const f of l.tileFailures || []) failures.push(`tile failed: ${f.url}: ${f.message}`);
      for (const e of l.consoleErrors || []) if (!w.consoleErrors.includes(e)) w.consoleErrors.push(e);
    }
    summary.browserRequests = w.requests;
    summary.externalRequests = w.external;
    summary.httpErrors = w.httpErrors;
    summary.consoleErrors = w.consoleErrors;
    if (w.external.length) failures.push(`${w.external.length} request(s) to other hosts, first: ${w.external[0]}`);
    if (w.httpErrors.length) failures.push(`${w.httpErrors.length} failed request(s), first: ${w.httpErrors[0]}`);
    if (w.consoleErrors.length) failures.push(`${w.consoleErrors.length} console error(s), first: ${w.consoleErrors[0]}`);
  } catch (e) {
    failures.push(String(e && e.stack ? e.stack : e));
  } finally {
    if (browser) {
      await browser.context.close().catch(() => {});
      rmSync(browser.userDataDir, { recursive: true, force: true });
    }
    stopServer(server && server.proc);
  }
  summary.ok = failures.length === 0;
  if (!summary.ok && server && server.stderr().trim()) {
    // The end of the server's log: with BIMTILES_SERVE_LOG=1, every connection and request.
    const lines = server.stderr().trimEnd().split("\n");
    console.error(`server stderr (last ${Math.min(lines.length, 400)} of ${lines.length} lines):\n` + lines.slice(-400).join("\n"));
  }
  const text = JSON.stringify(summary, null, 2);
  console.log(text);
  if (opts.json) writeFileSync(opts.json, text + "\n");
  console.log(summary.ok ? "browser test: PASSED" : `browser test: FAILED (${failures.length}): ${failures[0]}`);
  process.exit(summary.ok ? 0 : 1);
}

if (import.meta.url === `file://${process.argv[1]}`) main();
