// deck.gl 9 Tile3DLayer in headless Chromium: one page per tileset (pages/deckgl.js).
import { join } from "node:path";
import { bundle, openPage, pixelStats, TOOLS } from "./common.mjs";

export const name = "deckgl";
export const page = { path: "/deckgl.js", build: () => bundle(join(TOOLS, "clients/pages/deckgl.js")) };

export async function run(context, server, s, { timeoutMs }) {
  const url = `${server.url}/deckgl.html?tileset=${encodeURIComponent(s.url + "/tileset.json")}&lib=${server.url}/lib`;
  const { page, log } = await openPage(context, url);
  const t0 = Date.now();
  // Done: the tileset is in and (nothing is loading, or a tile failed and no tile loaded or
  // failed since) for 1 s, with a frame drawn since the last tile came in (a tile's layer can fail
  // in the frame after its load: on a busy machine that frame came after the 1 s), or for 3 s
  // without one; the layer itself failing (deck's onError) ends the wait too.
  let quiet = 0;
  let last = "";
  let framesAtChange = 0;
  let timedOut = false;
  for (;;) {
    const st = await page.evaluate(() => window.client && { ...window.client.state, tileUris: undefined, busy: window.client.busy() });
    const progress = st ? `${st.loaded}/${st.errors.length}` : "";
    if (progress !== last) framesAtChange = st ? st.frames : 0;
    const layerFailed = st && (st.errors.some((e) => e.startsWith("deck:")) || log.pageErrors.length > 0);
    const settled = st && st.tilesetLoaded && (st.loaded > 0 || st.errors.length) && (!st.busy || st.errors.length) && progress === last;
    if (layerFailed || settled) quiet++;
    else quiet = 0;
    last = progress;
    const drawnSince = st && st.frames > framesAtChange;
    if (layerFailed ? quiet >= 4 : quiet >= (drawnSince ? 4 : 12)) break;
    if (Date.now() - t0 > timeoutMs) { timedOut = true; break; }
    await new Promise((r) => setTimeout(r, 250));
  }
  const state = await page.evaluate(() => window.client.state);
  const png = await page.screenshot();
  const px = await pixelStats(page, png, [0, 0, 0]);
  const copies = await page.evaluate(() => window.client.copies());
  const sample = await page.evaluate(() => window.client.sample());
  const info = await page.evaluate(() => window.client.tilesetInfo());
  await page.close();
  return {
    timedOut,
    ms: Date.now() - t0,
    loaded: state.loaded,
    errors: [...state.errors, ...log.pageErrors, ...log.consoleErrors, ...log.httpErrors],
    external: log.external,
    copies,
    sample,
    info,
    pixels: px,
    png,
  };
}
