// bimtiles viewer service worker: keeps tile contents in the Cache API so a repeat visit loads
// them without the network.
//
// - Tile contents (.glb .b3dm .i3dm .pnts .cmpt .subtree .bin, textures) are served cache-first.
// - Tileset JSON files go to the network first (the server answers 304 when unchanged). When a
//   JSON file's ETag changes, the tileset was re-converted: every cached entry under that JSON's
//   folder is dropped. Offline, the cached JSON is used.
// - The page, CesiumJS (/cesium/, long max-age) and anything cross-origin pass through untouched.
// - A page loaded with ?cache=0 asks this worker to pass its requests through (to measure a cold
//   load while the worker is installed).
"use strict";

const TILE_CACHE = "bimtiles-tiles-v1";
const JSON_CACHE = "bimtiles-json-v1";
const TILE_EXT = /\.(glb|b3dm|i3dm|pnts|cmpt|subtree|bin|ktx2|png|jpe?g|webp)$/i;

const stats = new Map(); // clientId -> {hits, misses, networkBytes, invalidations}
// This worker's own fetches are its Resource Timing entries: their transferSize is what really
// crossed the network (compressed body + headers; a few hundred bytes for a 304, 0 from the
// HTTP cache), which Content-Length cannot tell. Kept for the whole worker's life.
if (self.performance && self.performance.setResourceTimingBufferSize) self.performance.setResourceTimingBufferSize(1000000);
const bypass = new Set(); // clientIds that asked for no caching

function statsFor(id) {
  let s = stats.get(id || "");
  if (!s) {
    s = { hits: 0, misses: 0, networkBytes: 0, invalidations: 0 };
    stats.set(id || "", s);
  }
  return s;
}

self.addEventListener("install", () => self.skipWaiting());
self.addEventListener("activate", (event) => event.waitUntil(self.clients.claim()));

self.addEventListener("message", (event) => {
  const id = event.source && event.source.id;
  const msg = event.data || {};
  let reply = {};
  if (msg.type === "bypass") {
    bypass.add(id);
    reply = { ok: true };
  } else if (msg.type === "stats") {
    reply = Object.assign({}, statsFor(id));
    // All clients together (Resource Timing does not say which client a fetch was for).
    reply.workerTransferBytes = self.performance
      ? self.performance.getEntriesByType("resource").reduce((n, e) => n + (e.transferSize || 0), 0)
      : null;
  }
  if (event.ports && event.ports[0]) event.ports[0].postMessage(reply);
});

self.addEventListener("fetch", (event) => {
  const req = event.request;
  if (req.method !== "GET" || req.headers.has("range")) return;
  if (bypass.has(event.clientId)) return;
  const url = new URL(req.url);
  if (url.origin !== self.location.origin || url.pathname.startsWith("/cesium/")) return;
  if (/\.json$/i.test(url.pathname)) {
    event.respondWith(networkFirstJson(req, url, statsFor(event.clientId)));
  } else if (TILE_EXT.test(url.pathname)) {
    event.respondWith(cacheFirst(req, statsFor(event.clientId)));
  }
});

function lengthOf(resp) {
  const n = parseInt(resp.headers.get("content-length") || "0", 10);
  return Number.isFinite(n) ? n : 0;
}

async function cacheFirst(req, s) {
  const cache = await caches.open(TILE_CACHE);
  const hit = await cache.match(req);
  if (hit) {
    s.hits++;
    return hit;
  }
  s.misses++;
  const resp = await fetch(req);
  s.networkBytes += lengthOf(resp);
  if (resp.status === 200 && resp.type === "basic") {
    // Do not let a full quota break the page.
    cache.put(req, resp.clone()).catch(() => {});
  }
  return resp;
}

async function networkFirstJson(req, url, s) {
  const cache = await caches.open(JSON_CACHE);
  let resp;
  try {
    resp = await fetch(req);
  } catch (e) {
    const cached = await cache.match(req);
    if (cached) {
      s.hits++;
      return cached;
    }
    throw e;
  }
  s.misses++;
  s.networkBytes += lengthOf(resp);
  if (resp.status === 200 && resp.type === "basic") {
    const old = await cache.match(req);
    const tag = resp.headers.get("etag");
    const oldTag = old && old.headers.get("etag");
    if (old && tag !== oldTag) {
      s.invalidations++;
      await dropUnder(url.href.slice(0, url.href.lastIndexOf("/") + 1));
    }
    if (!old || tag !== oldTag) await cache.put(req, resp.clone()).catch(() => {});
  }
  return resp;
}

async function dropUnder(prefix) {
  for (const name of [TILE_CACHE, JSON_CACHE]) {
    const cache = await caches.open(name);
    for (const key of await cache.keys()) {
      if (key.url.startsWith(prefix)) await cache.delete(key);
    }
  }
}
