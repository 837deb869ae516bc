// loaders.gl 4.5 in Node, as a user of @loaders.gl/3d-tiles would: Tiles3DLoader reads
// tileset.json over HTTP (the loopback server), then every tile's content the normalized tile
// tree lists (type "scenegraph"), parsed with the same loader (meshopt, Draco through the draco3d
// npm module, no worker, no CDN). Images are not decoded (no canvas in Node: gltf.loadImages
// off); the textures are drawn by the deck.gl check.
import { load } from "@loaders.gl/core";
import { Tiles3DLoader } from "@loaders.gl/3d-tiles";
import draco3d from "draco3d";
import { sampleGltf } from "./pages/gltf_sample.js";
import { isLocal } from "../browser_test.mjs";

export const name = "loadersgl";
export const page = null; // Node only

const OPTIONS = { worker: false, modules: { draco3d }, gltf: { loadImages: false } };

// Every fetch loaders.gl makes goes through here: a URL off loopback is recorded and refused.
const external = [];
const realFetch = globalThis.fetch;
globalThis.fetch = (input, init) => {
  const url = String(input?.url ?? input);
  if (!isLocal(url)) {
    external.push(url);
    return Promise.reject(new Error(`refused: ${url} is not on loopback`));
  }
  return realFetch(input, init);
};

export async function run(_context, _server, s) {
  const t0 = Date.now();
  external.length = 0;
  const base = s.url + "/";
  const rel = (u) => (u.startsWith("data:") ? "data:" : u.startsWith(base) ? u.slice(base.length) : u);
  const errors = [];
  const sample = {};
  const types = {};
  let loaded = 0;
  let ts;
  try {
    ts = await load(`${s.url}/tileset.json`, Tiles3DLoader, OPTIONS);
  } catch (e) {
    return { ms: Date.now() - t0, loaded, errors: [`tileset.json: ${e.message}`], sample, types, external: [...external] };
  }
  const tiles = [];
  const walk = (t) => {
    if (t.contentUrl) tiles.push(t);
    (t.children || []).forEach(walk);
  };
  walk(ts.root);
  for (const t of tiles) {
    const uri = rel(t.contentUrl);
    // The type the loader gives the tile (from the text after the content URI's last '.').
    types[uri] = t.type === "scenegraph" ? "scenegraph" : `not a model: "${String(t.type).slice(0, 24)}…"`;
    if (t.type !== "scenegraph") {
      errors.push(`${uri.slice(0, 40)}: tile type ${types[uri]}`);
      continue;
    }
    try {
      const c = await load(t.contentUrl, Tiles3DLoader, { ...OPTIONS, "3d-tiles": { isTileset: false } });
      sample[uri] = sampleGltf(c.gltf);
      loaded++;
    } catch (e) {
      errors.push(`${uri}: ${String(e.message).slice(0, 300)}`);
    }
  }
  return { ms: Date.now() - t0, loaded, tiles: tiles.length, errors, sample, types, external: [...external] };
}
