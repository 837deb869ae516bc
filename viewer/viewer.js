// bimtiles viewer: CesiumJS, offline (no ion token, no imagery, ellipsoid terrain).
//
// URL parameters:
//   tileset=URL   tileset to load (default /tileset/tileset.json)
//   cache=0       do not use the service-worker tile cache for this load; cache=clear empties it first
//   msaa=N        MSAA samples (default 4; 1 is much faster under software WebGL)
//   sse=N         fixed maximumScreenSpaceError, adaptation off (default: adaptive, see below)
//   fps=N         target frame rate of the adaptive strategy (default 30)
//   adaptive=0    no adaptation: the strategy's starting SSE stays (same as a fixed sse)
//   strategy=NAME force a strategy (detail, balanced, economy) instead of choosing one
//   debug=1       show tile bounding volumes
//   dracoWorkers=N  Draco decoding workers (default max(4, cores - 1); 0 = Cesium's cores - 1)
//   sky=1         sky and ground atmosphere (off by default: costly under software rendering)
//   bim=0         no BIM tools (bim.js); fly=S  their camera flights' seconds (default 1)
//
// BIM tools (bim.js: model tree, search, isolate, colour by property, section, measure, the view in
// the URL's hash) are loaded once the first view is drawn (all its tiles loaded), or at once when
// their button is pressed, so the first view does not wait for them or for the element index.
//
// Adaptive rendering (paper IV.B, strategy pattern): adaptive.js picks a strategy from the scene's
// size (tiles in tileset.json) and the device (cores, navigator.deviceMemory), sets the tile cache
// budget from the device memory, raises the SSE while the camera moves (and uses Cesium's own
// foveated / dynamic SSE), and moves the SSE within the strategy's bounds to hold the target
// frame rate. The status line (#adaptive) shows strategy, SSE and frame rate.
//
// For tests, window.bimtilesStatus holds the figures below (times in ms since navigation start),
// and window.bimtiles exposes {viewer, tileset, pickAt(x, y), swStats(), describe(pick)}.
"use strict";

(function () {
  const status = (window.bimtilesStatus = {
    ready: false, // viewer created, tileset loaded and framed
    error: null, // fatal error message (tileset could not load...)
    allTilesLoaded: false, // current view fully loaded (see updateFrame)
    tilesLoaded: 0, // tile contents loaded (tileLoad events)
    tileFailures: [], // {url, message}
    consoleErrors: [], // console.error / uncaught errors / render errors
    requests: 0, // all resources fetched by the page (Resource Timing)
    bytes: 0, // their encoded body bytes (what went over the wire, or from cache)
    transferBytes: 0, // bytes actually transferred (0 when served from a cache)
    tileRequests: 0, // of which tileset files (JSON + contents)
    tileBytes: 0,
    trianglesSelected: 0,
    featuresSelected: 0,
    tilesSelected: 0,
    tilesWithContent: 0,
    tilesTotal: 0,
    pendingRequests: 0,
    tilesProcessing: 0,
    tilesetMemoryBytes: 0,
    jsHeapBytes: null,
    tilesetUrl: null,
    tilesetRequestedMs: null,
    tilesetReadyMs: null,
    firstFrameWithContentMs: null,
    allTilesLoadedMs: null,
    frames: 0,
    cpuFrameMs: [], // Cesium CPU time per frame (preUpdate -> postRender), last 600 frames
    cache: { serviceWorker: false, reason: null },
    adaptive: null, // the adaptive strategy's state (adaptive.js): strategy, sse, fps, bounds...
    selected: null, // properties shown for the last picked element
    indexRequests: 0, // the element index (bim.js), not counted as tile requests
    indexBytes: 0,
  });

  // --- console errors, uncaught errors -----------------------------------------------------
  const origError = console.error.bind(console);
  console.error = function (...args) {
    status.consoleErrors.push(args.map(String).join(" ").slice(0, 500));
    origError(...args);
  };
  window.addEventListener("error", (e) => status.consoleErrors.push("uncaught: " + (e.message || e)));
  window.addEventListener("unhandledrejection", (e) =>
    status.consoleErrors.push("unhandled rejection: " + ((e.reason && e.reason.message) || e.reason)),
  );

  // --- requests and bytes (Resource Timing) ------------------------------------------------
  if (performance.setResourceTimingBufferSize) performance.setResourceTimingBufferSize(100000);
  const countEntry = (e) => {
    status.requests++;
    status.bytes += e.encodedBodySize || 0;
    status.transferBytes += e.transferSize || 0;
    if (/\/element-index\.json(\?|$)/.test(e.name)) {
      status.indexRequests++;
      status.indexBytes += e.encodedBodySize || 0;
    } else if (status.tilesetUrl && e.name.startsWith(tilesetBase())) {
      status.tileRequests++;
      status.tileBytes += e.encodedBodySize || 0;
    }
  };
  try {
    new PerformanceObserver((list) => list.getEntries().forEach(countEntry)).observe({
      type: "resource",
      buffered: true,
    });
  } catch (e) {
    /* very old browser: figures stay 0 */
  }
  function tilesetBase() {
    return status.tilesetUrl.slice(0, status.tilesetUrl.lastIndexOf("/") + 1);
  }

  const params = new URLSearchParams(location.search);
  const tilesetUrl = new URL(params.get("tileset") || "/tileset/tileset.json", location.href).href;
  status.tilesetUrl = tilesetUrl;

  function showError(msg) {
    const el = document.getElementById("error");
    el.textContent = msg;
    el.classList.remove("hidden");
  }

  // --- service-worker tile cache -----------------------------------------------------------
  function swMessage(msg, timeoutMs = 2000) {
    const ctl = navigator.serviceWorker && navigator.serviceWorker.controller;
    if (!ctl) return Promise.resolve(null);
    return new Promise((resolve) => {
      const ch = new MessageChannel();
      const timer = setTimeout(() => resolve(null), timeoutMs);
      ch.port1.onmessage = (e) => {
        clearTimeout(timer);
        resolve(e.data);
      };
      ctl.postMessage(msg, [ch.port2]);
    });
  }

  async function setupCache() {
    if (!("serviceWorker" in navigator)) return { serviceWorker: false, reason: "unsupported" };
    const mode = params.get("cache");
    if (mode === "0") {
      await swMessage({ type: "bypass" });
      return { serviceWorker: false, reason: "disabled by ?cache=0" };
    }
    try {
      if (mode === "clear" && window.caches) {
        for (const k of await caches.keys()) if (k.startsWith("bimtiles-")) await caches.delete(k);
      }
      await navigator.serviceWorker.register("sw.js");
      if (!navigator.serviceWorker.controller) {
        // First visit: the worker claims this page once active.
        await Promise.race([
          new Promise((r) => navigator.serviceWorker.addEventListener("controllerchange", r, { once: true })),
          new Promise((r) => setTimeout(r, 3000)),
        ]);
      }
      const on = !!navigator.serviceWorker.controller;
      return { serviceWorker: on, reason: on ? null : "worker did not take control in time" };
    } catch (e) {
      return { serviceWorker: false, reason: String(e && e.message ? e.message : e) };
    }
  }

  // --- picking -------------------------------------------------------------------------------
  const glbCache = new Map(); // url -> Promise<{json, bin}>

  function parseGlb(buf) {
    const dv = new DataView(buf);
    if (dv.getUint32(0, true) !== 0x46546c67) throw new Error("not a GLB");
    let off = 12;
    let json = null;
    let bin = null;
    while (off + 8 <= buf.byteLength) {
      const len = dv.getUint32(off, true);
      const type = dv.getUint32(off + 4, true);
      if (type === 0x4e4f534a) json = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, off + 8, len)));
      else if (type === 0x004e4942) bin = new Uint8Array(buf, off + 8, len);
      off += 8 + len;
    }
    return { json, bin };
  }

  function loadGlb(url) {
    if (!glbCache.has(url)) {
      if (glbCache.size > 16) glbCache.delete(glbCache.keys().next().value);
      glbCache.set(
        url,
        fetch(url)
          .then((r) => r.arrayBuffer())
          .then(parseGlb),
      );
    }
    return glbCache.get(url);
  }

  const COMPONENTS = { SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4 };
  function readAccessor(gltf, bin, index) {
    const a = gltf.accessors[index];
    if (!a || a.bufferView === undefined || a.sparse) throw new Error("unsupported accessor");
    const bv = gltf.bufferViews[a.bufferView];
    if ((bv.buffer || 0) !== 0) throw new Error("external buffer");
    const n = COMPONENTS[a.type];
    const size = { 5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4 }[a.componentType];
    const stride = bv.byteStride || n * size;
    const dv = new DataView(bin.buffer, bin.byteOffset + (bv.byteOffset || 0) + (a.byteOffset || 0));
    const get = {
      5120: (o) => dv.getInt8(o),
      5121: (o) => dv.getUint8(o),
      5122: (o) => dv.getInt16(o, true),
      5123: (o) => dv.getUint16(o, true),
      5125: (o) => dv.getUint32(o, true),
      5126: (o) => dv.getFloat32(o, true),
    }[a.componentType];
    const out = new Float64Array(a.count * n);
    for (let i = 0; i < a.count; i++)
      for (let c = 0; c < n; c++) out[i * n + c] = get(i * stride + c * size);
    return out;
  }

  // Squared distance from p to triangle abc (Ericson, Real-Time Collision Detection 5.1.5).
  function distTri2(p, a, b, c) {
    const sub = (u, v) => [u[0] - v[0], u[1] - v[1], u[2] - v[2]];
    const dot = (u, v) => u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    const ab = sub(b, a), ac = sub(c, a), ap = sub(p, a);
    const d1 = dot(ab, ap), d2 = dot(ac, ap);
    let q;
    if (d1 <= 0 && d2 <= 0) q = a;
    else {
      const bp = sub(p, b), d3 = dot(ab, bp), d4 = dot(ac, bp);
      const cp = sub(p, c), d5 = dot(ab, cp), d6 = dot(ac, cp);
      const vc = d1 * d4 - d3 * d2, vb = d5 * d2 - d1 * d6, va = d3 * d6 - d5 * d4;
      if (d3 >= 0 && d4 <= d3) q = b;
      else if (vc <= 0 && d1 >= 0 && d3 <= 0) { const v = d1 / (d1 - d3); q = [a[0] + v * ab[0], a[1] + v * ab[1], a[2] + v * ab[2]]; }
      else if (d6 >= 0 && d5 <= d6) q = c;
      else if (vb <= 0 && d2 >= 0 && d6 <= 0) { const w = d2 / (d2 - d6); q = [a[0] + w * ac[0], a[1] + w * ac[1], a[2] + w * ac[2]]; }
      else if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) {
        const w = (d4 - d3) / (d4 - d3 + (d5 - d6));
        q = [b[0] + w * (c[0] - b[0]), b[1] + w * (c[1] - b[1]), b[2] + w * (c[2] - b[2])];
      } else {
        const den = 1 / (va + vb + vc), v = vb * den, w = vc * den;
        q = [a[0] + ab[0] * v + ac[0] * w, a[1] + ab[1] * v + ac[1] * w, a[2] + ab[2] * v + ac[2] * w];
      }
    }
    const d = sub(p, q);
    return dot(d, d);
  }

  // Feature ID of the picked point when Cesium has no property table to pick features with:
  // read the tile's GLB (from the cache), find the primitive's triangle nearest to the picked
  // position and read its _FEATURE_ID_n.
  async function featureIdFromGeometry(picked, worldPos) {
    const detail = picked.detail;
    if (!detail || !detail.model || !detail.node || !detail.primitive || !worldPos) return null;
    const url = picked.content && picked.content.url;
    const { json, bin } = await loadGlb(url);
    const nodeIndex = detail.node.node.index;
    const mesh = json.meshes[json.nodes[nodeIndex].mesh];
    const primIndex = detail.node.runtimePrimitives.indexOf(detail.primitive);
    const prim = mesh.primitives[primIndex];
    if (!prim) return null;
    if (prim.extensions && prim.extensions.KHR_draco_mesh_compression)
      return { note: "geometry is Draco-compressed: feature ID needs a property table" };
    const fx = prim.extensions && prim.extensions.EXT_mesh_features;
    const fid = fx && fx.featureIds && fx.featureIds[0];
    if (!fid) return { note: "no EXT_mesh_features on this primitive" };
    if (fid.texture) return { note: "feature ID texture (not read here)" };
    const m = Cesium.Matrix4.multiply(
      detail.model.sceneGraph.computedModelMatrix,
      detail.node.computedTransform,
      new Cesium.Matrix4(),
    );
    const local = Cesium.Matrix4.multiplyByPoint(Cesium.Matrix4.inverse(m, new Cesium.Matrix4()), worldPos, new Cesium.Cartesian3());
    const pos = readAccessor(json, bin, prim.attributes.POSITION);
    const idx = prim.indices !== undefined ? readAccessor(json, bin, prim.indices) : null;
    const ids = fid.attribute !== undefined ? readAccessor(json, bin, prim.attributes["_FEATURE_ID_" + fid.attribute]) : null;
    const p = [local.x, local.y, local.z];
    const triCount = idx ? idx.length / 3 : pos.length / 9;
    let best = Infinity;
    let bestVertex = -1;
    const v = (i) => [pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]];
    for (let t = 0; t < triCount; t++) {
      const i0 = idx ? idx[3 * t] : 3 * t, i1 = idx ? idx[3 * t + 1] : 3 * t + 1, i2 = idx ? idx[3 * t + 2] : 3 * t + 2;
      const d = distTri2(p, v(i0), v(i1), v(i2));
      if (d < best) {
        best = d;
        bestVertex = i0;
      }
    }
    if (bestVertex < 0) return null;
    const featureId = ids ? ids[bestVertex] : bestVertex; // implicit IDs: the vertex index
    if (fid.nullFeatureId !== undefined && featureId === fid.nullFeatureId) return { featureId: null, note: "null feature ID" };
    return { featureId, distanceM: Math.sqrt(best), featureCount: fid.featureCount };
  }

  async function describe(picked, windowPos) {
    const rows = [];
    if (picked instanceof Cesium.Cesium3DTileFeature) {
      rows.push(["feature ID", picked.featureId]);
      for (const id of picked.getPropertyIds()) {
        let v = picked.getProperty(id);
        if (v !== null && typeof v === "object") v = JSON.stringify(v);
        rows.push([id, v]);
      }
      const tileUrl = picked.content && picked.content.url;
      // A root inlined in tileset.json (bimtiles convert, by default for a small root) has the whole GLB as its URL.
      rows.push(["tile", tileUrl && tileUrl.startsWith("data:") ? "tileset.json (inlined)" : tileUrl]);
      return { kind: "feature", rows };
    }
    if (picked && picked.content) {
      let worldPos = null;
      if (windowPos && viewer.scene.pickPositionSupported) worldPos = viewer.scene.pickPosition(windowPos);
      let info = null;
      try {
        info = await featureIdFromGeometry(picked, worldPos);
      } catch (e) {
        info = { note: "feature ID unavailable: " + e.message };
      }
      if (info && info.featureId !== undefined) rows.push(["feature ID", info.featureId]);
      if (picked.instanceId !== undefined) rows.push(["instance", picked.instanceId]);
      if (info && info.note) rows.push(["note", info.note]);
      rows.push(["tile", picked.content.url]);
      if (picked.detail && picked.detail.node && picked.detail.node.node.name)
        rows.push(["node", picked.detail.node.node.name]);
      rows.push(["properties", "none in this tile (no EXT_structural_metadata)"]);
      return { kind: "tile", rows };
    }
    return null;
  }

  let highlighted = null;
  function highlight(feature) {
    if (window.bimtilesBim && window.bimtilesBim.ready) return window.bimtilesBim.pickedFeature(feature);
    if (highlighted) {
      try {
        highlighted.feature.color = highlighted.color;
      } catch (e) {
        /* tile unloaded */
      }
      highlighted = null;
    }
    if (feature instanceof Cesium.Cesium3DTileFeature) {
      highlighted = { feature, color: Cesium.Color.clone(feature.color) };
      feature.color = Cesium.Color.YELLOW.withAlpha(0.8);
    }
  }

  // The properties panel with given rows (bim.js shows an element of the index there).
  function showRows(title, rows) {
    showProps({ kind: "feature", rows });
    document.getElementById("propsTitle").textContent = title;
  }

  function showProps(desc) {
    const panel = document.getElementById("props");
    const table = document.getElementById("propsTable");
    table.textContent = "";
    if (!desc) {
      panel.classList.add("hidden");
      return;
    }
    for (const [k, v] of desc.rows) {
      const tr = table.insertRow();
      tr.insertCell().textContent = k;
      tr.insertCell().textContent = v === undefined ? "" : String(v);
    }
    document.getElementById("propsTitle").textContent = desc.kind === "feature" ? "Element" : "Tile content";
    panel.classList.remove("hidden");
  }

  async function pickAt(x, y) {
    const pos = new Cesium.Cartesian2(x, y);
    const picked = viewer.scene.pick(pos);
    highlight(picked);
    const desc = await describe(picked, pos);
    status.selected = desc ? Object.fromEntries(desc.rows) : null;
    showProps(desc);
    return status.selected;
  }

  // --- viewer --------------------------------------------------------------------------------
  let viewer = null;
  let tileset = null;
  let adaptive = null; // BimtilesAdaptive controller of the current tileset
  let rendererName = ""; // the WebGL renderer's name (software or not, for the strategy)

  async function main() {
    status.cache = await setupCache();
    // Cesium decodes Draco primitives in max(cores - 1, 1) workers and schedules new decodes
    // only once per frame: on 2 cores a tile of N Draco primitives needs N frames.
    // Measured (ISSUE_021 model, 20 tiles of ~6 Draco primitives, 2 cores, SwiftShader): all tiles
    // loaded after 131 frames / 67 s with Cesium's default, 47 frames / 23 s with 4 workers.
    // Default here 4 (at least); dracoWorkers=0 keeps Cesium's own default.
    const dw = params.get("dracoWorkers");
    const dracoWorkers = dw === null ? Math.max(4, (navigator.hardwareConcurrency || 2) - 1) : parseInt(dw, 10);
    if (dracoWorkers > 0 && Cesium.DracoLoader) Cesium.DracoLoader._maxDecodingConcurrency = dracoWorkers;

    const msaa = parseInt(params.get("msaa") || "4", 10);
    viewer = new Cesium.Viewer("cesiumContainer", {
      baseLayer: false,
      terrainProvider: new Cesium.EllipsoidTerrainProvider(),
      geocoder: false,
      baseLayerPicker: false,
      timeline: false,
      animation: false,
      sceneModePicker: false,
      infoBox: false,
      selectionIndicator: false,
      navigationHelpButton: false,
      fullscreenButton: false,
      homeButton: true,
      skyBox: false,
      msaaSamples: Number.isFinite(msaa) ? msaa : 4,
    });
    const scene = viewer.scene;
    // A light from the camera, as BIM viewers light a model: the sun of the current time of day
    // left a model dark where it stands at night, and its look changed with the clock.
    const headlight = new Cesium.DirectionalLight({ direction: Cesium.Cartesian3.clone(scene.camera.directionWC) });
    scene.light = headlight;
    scene.preRender.addEventListener(() => { Cesium.Cartesian3.clone(scene.camera.directionWC, headlight.direction); });
    rendererName = BimtilesAdaptive.renderer(viewer.canvas);
    scene.globe.baseColor = Cesium.Color.fromCssColorString("#5a6068");
    scene.backgroundColor = Cesium.Color.fromCssColorString("#1b1e23");
    scene.globe.depthTestAgainstTerrain = true;
    // The sky and ground atmosphere cost more than the model itself under software WebGL
    // (measured ~0.5 s per 1280x720 frame with SwiftShader on 2 loaded cores): off unless ?sky=1.
    const sky = params.get("sky") === "1";
    scene.skyAtmosphere.show = sky;
    scene.globe.showGroundAtmosphere = sky;
    scene.renderError.addEventListener((s, e) => status.consoleErrors.push("render error: " + (e && e.message ? e.message : e)));
    window.bimtiles = { viewer, tileset: null, pickAt, describe, loadTileset, showRows, loadBimTools, setEdges, swStats: () => swMessage({ type: "stats" }) };

    installFrameHooks(scene);

    viewer.homeButton.viewModel.command.beforeExecute.addEventListener((e) => {
      e.cancel = true;
      if (tileset) viewer.zoomTo(tileset, HOME_OFFSET);
    });
    viewer.screenSpaceEventHandler.setInputAction((click) => {
      if (window.bimtilesBim && window.bimtilesBim.onClick(click.position)) return;
      pickAt(click.position.x, click.position.y).catch((e) => console.warn("pick failed", e));
    }, Cesium.ScreenSpaceEventType.LEFT_CLICK);
    document.getElementById("bimToggle").onclick = () => {
      loadBimTools();
      document.body.classList.toggle("bim-toggled");
    };
    document.getElementById("propsClose").onclick = () => {
      highlight(null);
      showProps(null);
    };
    await loadTileset(tilesetUrl);
  }

  const HOME_OFFSET = new Cesium.HeadingPitchRange(0.6, -0.45, 0);

  // The BIM tools, loaded once (see the header).
  let bimTools = null;
  function loadBimTools() {
    if (bimTools || params.get("bim") === "0" || !tileset) return bimTools;
    bimTools = new Promise((resolve, reject) => {
      const el = document.createElement("script");
      el.src = "bim.js";
      el.onload = resolve;
      el.onerror = () => reject(new Error("cannot load bim.js"));
      document.body.appendChild(el);
    });
    document.getElementById("bim").classList.remove("hidden");
    return bimTools;
  }

  // Edges (EXT_mesh_primitive_edge_visibility, drawn through the tileset's edgeDisplayMode): what
  // the tileset carries is in asset.extras.bimtiles.edges ({written, shown}: shown at first for
  // plain-coloured models, not for photo-textured scenes). ?edges=0|1 overrides it, and a toggle
  // writes it back into the URL so a shared link keeps it.
  function tilesetEdges(ts) {
    const e = ts && ts.asset && ts.asset.extras && ts.asset.extras.bimtiles && ts.asset.extras.bimtiles.edges;
    return e && e.written ? e : null;
  }
  function setEdges(on, remember) {
    if (!tileset || !Cesium.EdgeDisplayMode) return false;
    const shown = !!on && !!tilesetEdges(tileset);
    tileset.edgeDisplayMode = shown ? Cesium.EdgeDisplayMode.SURFACES_AND_EDGES : Cesium.EdgeDisplayMode.SURFACES_ONLY;
    status.edges = { written: tilesetEdges(tileset) ? tilesetEdges(tileset).written : null, shown };
    if (remember) {
      const u = new URL(location.href);
      u.searchParams.set("edges", shown ? "1" : "0");
      history.replaceState(null, "", u.pathname + u.search + u.hash);
    }
    return shown;
  }

  // Loads (or replaces) the tileset and frames it; resets the per-load figures. Used by the page
  // itself and by the benchmark (to compare tilesets in one warmed-up page).
  async function loadTileset(url, options = {}) {
    if (adaptive) adaptive.destroy(); // it drives the tileset about to go
    adaptive = null;
    if (tileset) {
      highlight(null);
      showProps(null);
      viewer.scene.primitives.remove(tileset); // destroys it
      tileset = null;
      window.bimtiles.tileset = null;
    }
    url = new URL(url, location.href).href;
    Object.assign(status, {
      ready: false, error: null, allTilesLoaded: false, tilesLoaded: 0, tileFailures: [],
      tileRequests: 0, tileBytes: 0, tilesetUrl: url, tilesetReadyMs: null,
      firstFrameWithContentMs: null, allTilesLoadedMs: null, selected: null,
    });
    status.tilesetRequestedMs = performance.now();
    let ts;
    const fixedSse = options.maximumScreenSpaceError || parseFloat(params.get("sse") || "NaN");
    const plan = BimtilesAdaptive.plan(params, navigator, fixedSse, rendererName);
    viewer.resolutionScale = plan.resolutionScale;
    // Cesium shows its canvas pixelated (crisp at full resolution); scaled up, smooth reads better.
    if (plan.resolutionScale < 1) viewer.canvas.style.imageRendering = "auto";
    try {
      ts = await Cesium.Cesium3DTileset.fromUrl(url, {
        ...plan.tilesetOptions,
        debugShowBoundingVolume: params.get("debug") === "1",
      });
    } catch (e) {
      status.error = "cannot load " + url + ": " + (e && e.message ? e.message : e);
      showError(status.error);
      document.getElementById("progressText").textContent = "failed";
      return false;
    }
    status.tilesetReadyMs = performance.now();
    ts.tileLoad.addEventListener(() => status.tilesLoaded++);
    ts.tileFailed.addEventListener((err) => {
      status.tileFailures.push({ url: String(err.url), message: String(err.message) });
      // Cesium logs tileFailed to the console only when nobody listens: keep it visible.
      console.warn("tile failed:", err.url, err.message);
    });
    tileset = ts;
    window.bimtiles.tileset = ts;
    const askedEdges = params.get("edges");
    const edges = tilesetEdges(ts);
    setEdges(askedEdges === null ? !!(edges && edges.shown) : askedEdges === "1", false);
    adaptive = BimtilesAdaptive.start(viewer.scene, ts, plan, (state) => {
      status.adaptive = state;
      document.getElementById("adaptive").textContent = BimtilesAdaptive.describe(state);
    });
    viewer.scene.primitives.add(ts);
    await viewer.zoomTo(ts, HOME_OFFSET);
    // A shared link's camera (bim.js writes it in the hash) is the first view.
    const cam = new URLSearchParams(location.hash.slice(1)).get("cam");
    const v = cam ? cam.split(",").map(Number) : [];
    if (v.length === 6 && v.every(Number.isFinite))
      viewer.camera.setView({ destination: new Cesium.Cartesian3(v[0], v[1], v[2]), orientation: { heading: v[3], pitch: v[4], roll: v[5] } });
    status.ready = true;
    return true;
  }

  // --- per-frame figures -----------------------------------------------------------------------
  function installFrameHooks(scene) {
    let frameStart = 0;
    let lastView = null;
    let stillFrames = 0;
    let hudFrame = 0;
    scene.preUpdate.addEventListener(() => (frameStart = performance.now()));
    scene.postRender.addEventListener(() => {
      const now = performance.now();
      status.frames++;
      status.cpuFrameMs.push(+(now - frameStart).toFixed(3));
      if (status.cpuFrameMs.length > 600) status.cpuFrameMs.shift();
      const cam = scene.camera;
      const view = [cam.positionWC.x, cam.positionWC.y, cam.positionWC.z, cam.directionWC.x, cam.directionWC.y, cam.directionWC.z];
      const moved = !lastView || view.some((v, i) => Math.abs(v - lastView[i]) > 1e-6 * Math.max(1, Math.abs(v)));
      lastView = view;
      stillFrames = moved ? 0 : stillFrames + 1;
      if (!tileset) return;
      const s = tileset.statistics;
      status.trianglesSelected = s.numberOfTrianglesSelected;
      status.featuresSelected = s.numberOfFeaturesSelected;
      status.tilesSelected = s.selected;
      status.tilesWithContent = s.numberOfTilesWithContentReady;
      status.tilesTotal = s.numberOfTilesTotal;
      status.pendingRequests = s.numberOfPendingRequests;
      status.tilesProcessing = s.numberOfTilesProcessing;
      status.tilesetMemoryBytes = tileset.totalMemoryUsageInBytes;
      if (performance.memory) status.jsHeapBytes = performance.memory.usedJSHeapSize;
      if (status.firstFrameWithContentMs === null && s.numberOfTrianglesSelected > 0) status.firstFrameWithContentMs = now;
      const loaded = status.ready && tileset.tilesLoaded && s.numberOfPendingRequests === 0 && s.numberOfTilesProcessing === 0 && stillFrames >= 3;
      status.allTilesLoaded = loaded;
      if (loaded && status.allTilesLoadedMs === null) {
        status.allTilesLoadedMs = now;
        setTimeout(loadBimTools, 0);
      }
      if (hudFrame++ % 10 === 0 || loaded !== status._hudLoaded) {
        status._hudLoaded = loaded;
        updateHud(s, loaded);
      }
    });
  }

  function updateHud(s, loaded) {
    const busy = s.numberOfPendingRequests + s.numberOfTilesProcessing;
    const done = s.numberOfTilesWithContentReady;
    const pct = loaded ? 100 : Math.round((100 * done) / Math.max(1, done + busy));
    document.getElementById("progressFill").style.width = pct + "%";
    document.getElementById("progressText").textContent = loaded
      ? `all tiles loaded (${(status.allTilesLoadedMs / 1000).toFixed(2)} s)`
      : `loading: ${s.numberOfPendingRequests} requests pending, ${s.numberOfTilesProcessing} tiles processing`;
    const mb = (b) => (b / 1048576).toFixed(1) + " MB";
    document.getElementById("statsText").textContent =
      `tiles loaded    ${status.tilesLoaded} (in memory ${done}/${s.numberOfTilesTotal})\n` +
      `tiles drawn     ${s.selected}\n` +
      `triangles drawn ${s.numberOfTrianglesSelected.toLocaleString("en")}\n` +
      `tile memory     ${mb(tileset.totalMemoryUsageInBytes)}\n` +
      `tile data       ${mb(status.tileBytes)} in ${status.tileRequests} requests` +
      (status.cache.serviceWorker ? "\ntile cache      on" : "") +
      (status.tileFailures.length ? `\nFAILED tiles    ${status.tileFailures.length}` : "");
  }

  main().catch((e) => {
    status.error = String(e && e.stack ? e.stack : e);
    console.error("viewer failed:", e);
    showError(status.error);
  });
})();
