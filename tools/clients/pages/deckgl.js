// deck.gl 9 Tile3DLayer page (loaders.gl Tiles3DLoader inside), bundled by esbuild at test time.
// Loads ?tileset= with every loaders.gl library served from ?lib= (no worker, no CDN), frames it
// on the tileset's own centre once loaded, and exposes window.client for tools/clients/deckgl.mjs:
// state (tiles loaded, errors), copies() (model nodes each ScenegraphLayer draws, per tile) and
// sample() (metadata of a sampled feature of each loaded tile, read from the content the layer got).
import { Deck } from "@deck.gl/core";
import { Tile3DLayer } from "@deck.gl/geo-layers";
import { Tiles3DLoader } from "@loaders.gl/3d-tiles";
import { sampleGltf } from "./gltf_sample.js";

const q = new URLSearchParams(location.search);
const lib = q.get("lib");
const tilesetUrl = q.get("tileset");
const base = tilesetUrl.replace(/[^/]*$/, "");
const rel = (u) => (u.startsWith("data:") ? "data:" : u.startsWith(base) ? u.slice(base.length) : u);
const state = { tilesetLoaded: false, loaded: 0, errors: [], tileUris: [], frames: 0, tileset: null };
let tileset3d = null;

const layer = () =>
  new Tile3DLayer({
    id: "tiles",
    data: tilesetUrl,
    loader: Tiles3DLoader,
    loadOptions: {
      worker: false,
      // loaders.gl fetches its decoders from unpkg/gstatic by default: the same files from
      // tools/node_modules instead.
      modules: {
        "draco_wasm_wrapper.js": `${lib}/@loaders.gl/draco/dist/libs/draco_wasm_wrapper.js`,
        "draco_decoder.wasm": `${lib}/@loaders.gl/draco/dist/libs/draco_decoder.wasm`,
        "basis_transcoder.js": `${lib}/@loaders.gl/textures/dist/libs/basis_transcoder.js`,
        "basis_transcoder.wasm": `${lib}/@loaders.gl/textures/dist/libs/basis_transcoder.wasm`,
        "basis_encoder.js": `${lib}/@loaders.gl/textures/dist/libs/basis_encoder.js`,
        "basis_encoder.wasm": `${lib}/@loaders.gl/textures/dist/libs/basis_encoder.wasm`,
      },
      tileset: { maximumScreenSpaceError: Number(q.get("sse") || 1), throttleRequests: false },
    },
    onTilesetLoad: (ts) => {
      tileset3d = ts;
      state.tilesetLoaded = true;
      const [longitude, latitude, height] = ts.cartographicCenter;
      // Frame the root's bounding box: its radius over 35 % of the view (web mercator: 512 px
      // for the world's circumference at zoom 0).
      const b = ts.root.header.boundingVolume.box;
      const r = b ? Math.hypot(...b.slice(3)) : ts.root.header.boundingVolume.sphere[3];
      const mpp = (2 * r) / (0.7 * Math.min(innerWidth, innerHeight));
      const zoom = Math.log2((40075016 * Math.cos((latitude * Math.PI) / 180)) / (512 * mpp));
      state.view = { longitude, latitude, height, zoom, radius: r };
      deck.setProps({ initialViewState: { longitude, latitude, zoom, pitch: 50, bearing: 30, position: [0, 0, height] } });
    },
    onTileLoad: (tile) => {
      state.loaded++;
      state.tileUris.push(rel(tile.contentUrl || ""));
    },
    onTileError: (tile, message, url) => state.errors.push(`tile ${rel(url || tile?.contentUrl || "").slice(0, 80)}: ${String(message).slice(0, 300)}`),
  });

const deck = new Deck({
  parent: document.body,
  width: "100%",
  height: "100%",
  initialViewState: { longitude: 0, latitude: 0, zoom: 1 },
  controller: false,
  layers: [layer()],
  onError: (e) => state.errors.push(`deck: ${String(e?.message || e).slice(0, 300)}`),
  onAfterRender: () => state.frames++,
});

/** Model nodes (a luma.gl ModelNode: one draw of one primitive) under a scenegraph. */
const countModels = (node) => (node?.model ? 1 : 0) + (node?.children || []).reduce((a, c) => a + countModels(c), 0);

window.client = {
  state,
  busy: () => (tileset3d ? tileset3d.isLoaded() === false : true),
  tilesetInfo: () => tileset3d && { tiles: tileset3d.tiles.length, selected: tileset3d.selectedTiles.length },
  /** Per loaded tile: the model nodes its ScenegraphLayer drew. */
  copies() {
    const out = {};
    for (const l of deck.layerManager?.getLayers() || []) {
      if (l.constructor.layerName !== "ScenegraphLayer" || !l.props.tile) continue;
      out[rel(l.props.tile.contentUrl)] = { models: countModels(l.state.scenegraph), drawn: !!l.props.tile.tileDrawn };
    }
    return out;
  },
  /** Per loaded tile: sampleGltf of the content the layer loaded. */
  sample() {
    const out = {};
    for (const t of tileset3d?.tiles || []) if (t.content?.gltf) out[rel(t.contentUrl)] = sampleGltf(t.content.gltf);
    return out;
  },
};
