// Shared by the client checks: one loopback static server for everything a page needs (the page,
// its esbuild bundle, decoder files from tools/node_modules, and every tileset under /sets/<i>/),
// one headless Chromium (flags of tools/browser_test.mjs), and the pixel helpers.

import { createServer } from "node:http";
import { createReadStream, existsSync, rmSync, statSync } from "node:fs";
import { extname, join, normalize, resolve, sep } from "node:path";
import { fileURLToPath } from "node:url";
import { CHROME_ARGS, isLocal } from "../browser_test.mjs";

export const TOOLS = resolve(fileURLToPath(import.meta.url), "../..");
export const NODE_MODULES = join(TOOLS, "node_modules");

const TYPES = {
  ".html": "text/html; charset=utf-8",
  ".js": "text/javascript",
  ".mjs": "text/javascript",
  ".json": "application/json",
  ".wasm": "application/wasm",
  ".glb": "model/gltf-binary",
  ".png": "image/png",
  ".jpg": "image/jpeg",
  ".jpeg": "image/jpeg",
  ".webp": "image/webp",
  ".ktx2": "image/ktx2",
};

/**
 * Starts a server on 127.0.0.1 (port chosen by the OS). `mounts` maps a URL prefix ("/sets/0/")
 * to a directory; `pages` maps a path ("/three.html") to a string or Buffer. Counts requests per
 * path (for "schema.json is fetched once per tile"). Resolves with {url, close, requests}.
 */
export function startStaticServer(mounts, pages = {}) {
  const requests = new Map();
  const server = createServer((req, res) => {
    const path = decodeURIComponent(new URL(req.url, "http://x").pathname);
    requests.set(path, (requests.get(path) || 0) + 1);
    const send = (code, body, type = "text/plain") => {
      res.writeHead(code, { "content-type": type, "access-control-allow-origin": "*", "cache-control": "no-store" });
      res.end(body);
    };
    if (path === "/favicon.ico") return send(204, "");
    if (pages[path] !== undefined) return send(200, pages[path], TYPES[extname(path)] || "text/plain");
    for (const [prefix, d] of Object.entries(mounts)) {
      if (!path.startsWith(prefix)) continue;
      const dir = resolve(d);
      const file = normalize(join(dir, path.slice(prefix.length)));
      if (!file.startsWith(dir + sep)) return send(403, "outside");
      if (!existsSync(file) || !statSync(file).isFile()) return send(404, "not found");
      res.writeHead(200, {
        "content-type": TYPES[extname(file).toLowerCase()] || "application/octet-stream",
        "content-length": statSync(file).size,
        "access-control-allow-origin": "*",
        "cache-control": "no-store",
      });
      return createReadStream(file).pipe(res);
    }
    send(404, "not found");
  });
  return new Promise((ok) =>
    server.listen(0, "127.0.0.1", () => {
      const url = `http://127.0.0.1:${server.address().port}`;
      ok({ url, requests, close: () => new Promise((r) => server.close(r)) });
    }),
  );
}

/** Bundles `entry` (an ES module using npm packages from tools/node_modules) for the browser. */
export async function bundle(entry) {
  const esbuild = await import("esbuild");
  const r = await esbuild.build({
    entryPoints: [entry],
    bundle: true,
    format: "esm",
    platform: "browser",
    write: false,
    minify: false,
    logLevel: "silent",
    nodePaths: [NODE_MODULES],
    absWorkingDir: TOOLS,
    define: { "process.env.NODE_ENV": '"production"' },
  });
  return Buffer.from(r.outputFiles[0].contents);
}

/** One headless Chromium for a whole matrix: {context, close}. */
export async function launchBrowser(width, height) {
  const playwright = await import("playwright-core");
  const { mkdtempSync } = await import("node:fs");
  const { tmpdir } = await import("node:os");
  const userDataDir = mkdtempSync(join(tmpdir(), "bimtiles-clients-"));
  const context = await playwright.chromium.launchPersistentContext(userDataDir, {
    executablePath: process.env.BIMTILES_CHROMIUM || "/usr/bin/chromium",
    headless: true,
    args: CHROME_ARGS,
    viewport: { width, height },
  });
  // Nothing leaves loopback: such a request is aborted (and reported by openPage as external).
  await context.route((url) => !isLocal(url.toString()), (route) => route.abort());
  return {
    context,
    close: async () => {
      await context.close();
      rmSync(userDataDir, { recursive: true, force: true });
    },
  };
}

/**
 * Opens `url` in a new page of `context` and follows it: console errors, page errors, failed
 * and non-loopback requests. Returns {page, log}.
 */
export async function openPage(context, url) {
  const page = await context.newPage();
  const log = { consoleErrors: [], pageErrors: [], external: [], httpErrors: [], console: [] };
  page.on("console", (m) => {
    const t = m.text().slice(0, 400);
    if (m.type() === "error") log.consoleErrors.push(t);
    else if (log.console.length < 50) log.console.push(t);
  });
  page.on("pageerror", (e) => log.pageErrors.push(String(e.message || e).slice(0, 400)));
  page.on("request", (r) => {
    if (!isLocal(r.url())) log.external.push(r.url());
  });
  page.on("requestfailed", (r) => {
    const f = r.failure();
    if (f && !/ERR_ABORTED/.test(f.errorText)) log.httpErrors.push(`${f.errorText} ${r.url()}`);
  });
  page.on("response", (r) => {
    if (r.status() >= 400) log.httpErrors.push(`${r.status()} ${r.url()}`);
  });
  await page.goto(url);
  return { page, log };
}

/** The HTML shell of a client page: a full-window canvas and the bundle as a module. */
export const pageHtml = (bundlePath) =>
  `<!doctype html><html><head><meta charset="utf-8"><style>html,body{margin:0;height:100%;overflow:hidden;background:#000}` +
  `canvas{display:block}</style></head><body><script type="module" src="${bundlePath}"></script></body></html>`;

/**
 * Pixel statistics of a PNG screenshot, decoded by the page: `drawn` the share of pixels that
 * differ from the background `bg` ([r,g,b]), `coloured` the share of drawn pixels whose colour
 * is not a shade of grey (max - min channel > 40 of 255).
 */
export async function pixelStats(page, png, bg) {
  return page.evaluate(
    async ([b64, bg]) => {
      const blob = await (await fetch("data:image/png;base64," + b64)).blob();
      const bmp = await createImageBitmap(blob);
      const c = new OffscreenCanvas(bmp.width, bmp.height);
      const ctx = c.getContext("2d");
      ctx.drawImage(bmp, 0, 0);
      const d = ctx.getImageData(0, 0, bmp.width, bmp.height).data;
      let drawn = 0;
      let coloured = 0;
      for (let i = 0; i < d.length; i += 4) {
        const r = d[i], g = d[i + 1], b = d[i + 2];
        if (Math.abs(r - bg[0]) + Math.abs(g - bg[1]) + Math.abs(b - bg[2]) <= 24) continue;
        drawn++;
        if (Math.max(r, g, b) - Math.min(r, g, b) > 40) coloured++;
      }
      return { drawn: drawn / (d.length / 4), coloured: drawn ? coloured / drawn : 0 };
    },
    [png.toString("base64"), bg],
  );
}

/** Polls `fn` in the page every 250 ms until it returns a truthy value or `ms` pass. */
export async function waitFor(page, fn, ms, arg) {
  const t0 = Date.now();
  for (;;) {
    const v = await page.evaluate(fn, arg);
    if (v) return v;
    if (Date.now() - t0 > ms) return null;
    await new Promise((r) => setTimeout(r, 250));
  }
}
