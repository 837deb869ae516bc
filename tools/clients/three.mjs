// 3DTilesRendererJS 0.5 on three.js in headless Chromium: one page per tileset (pages/three.js).
import { join } from "node:path";
import { bundle, openPage, pixelStats, TOOLS } from "./common.mjs";

export const name = "three";
export const page = { path: "/three.js", build: () => bundle(join(TOOLS, "clients/pages/three.js")) };

/** Loads set `s` ({url, facts}) and measures it. */
export async function run(context, server, s, { timeoutMs }) {
  const url = `${server.url}/three.html?tileset=${encodeURIComponent(s.url + "/tileset.json")}&lib=${server.url}/lib`;
  const schemaPath = s.mount + "schema.json";
  const schemaBefore = server.requests.get(schemaPath) || 0;
  const { page, log } = await openPage(context, url);
  const t0 = Date.now();
  // Done: framed, content loaded, nothing queued, downloading or parsing for 1 s.
  let quiet = 0;
  let timedOut = false;
  for (;;) {
    const st = await page.evaluate(() => window.client && { framed: window.client.state.framed, models: window.client.state.models, busy: window.client.busy(), errors: window.client.state.errors.length });
    // (A tileset.json that fails to load leaves nothing to frame: done too.)
    if (st && (st.framed || st.errors > 0) && (st.models > 0 || st.errors > 0) && st.busy === 0) quiet++;
    else quiet = 0;
    if (quiet >= 4) break;
    if (Date.now() - t0 > timeoutMs) { timedOut = true; break; }
    await new Promise((r) => setTimeout(r, 250));
  }
  const state = await page.evaluate(() => window.client.state);
  const png = await page.screenshot();
  const px = await pixelStats(page, png, [0, 0, 0]);
  const pick = await page.evaluate(() => window.client.pick());
  const instancePick = s.facts.instancedNodes ? await page.evaluate(() => window.client.instancePick()) : null;
  await page.close();
  return {
    timedOut,
    ms: Date.now() - t0,
    loaded: state.models,
    errors: [...state.errors, ...log.pageErrors, ...log.consoleErrors, ...log.httpErrors],
    external: log.external,
    tiles: state.tiles,
    pixels: px,
    pick,
    instancePick,
    schemaFetches: (server.requests.get(schemaPath) || 0) - schemaBefore,
    png,
  };
}
