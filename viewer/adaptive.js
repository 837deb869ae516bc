// bimtiles viewer: the adaptive rendering strategy (paper IV.B). The paper encapsulates its
// rendering optimisations in strategy classes and picks one from the current scene's complexity;
// here a strategy is a set of CesiumJS tileset settings (SSE bounds, how much coarser the view
// gets while the camera moves, foveation, progressive resolution), picked from the scene's size
// (tiles in its tileset.json) and the device (navigator.hardwareConcurrency,
// navigator.deviceMemory, and whether WebGL is rasterised in software). Then a controller measures
// the frame rate and moves maximumScreenSpaceError within the strategy's bounds to hold the target
// frame rate.
//
//   BimtilesAdaptive.renderer(canvas)  the WebGL renderer's name (software or not)
//   BimtilesAdaptive.plan(params, navigator, fixedSse, renderer)  device figures + tileset options and
//                                      the drawing resolution, before load
//   BimtilesAdaptive.start(scene, tileset, plan, onState)  strategy from the tile tree; controller
//   BimtilesAdaptive.describe(state)  the status line
"use strict";

(function () {
  // navigator.deviceMemory is Chromium-only (and capped at 8): elsewhere assume a small device.
  const DEFAULT_DEVICE_MEMORY_GB = 2;
  const DEFAULT_TARGET_FPS = 30;
  // Cesium's own default SSE: the first view of every strategy starts from it.
  const START_SSE = 16;
  // Frame-rate window and hysteresis: the SSE moves by STEP when the measured rate leaves
  // [LOW, HIGH] x target, at most once per window (so one slow frame does not move it).
  const WINDOW_MS = 1000;
  const WINDOW_MIN_FRAMES = 4;
  const LOW = 0.85;
  const HIGH = 1.25;
  const STEP = 1.25;
  // Without a GPU every pixel is shaded on the CPU, so a frame costs what its pixels cost: such a
  // device draws at half the canvas's resolution, a quarter of the pixels. Renderers that name
  // themselves software rasterisers (Chromium's SwiftShader, Mesa's llvmpipe and softpipe, Windows'
  // Basic Render Driver).
  const SOFTWARE_RESOLUTION_SCALE = 0.5;
  const SOFTWARE_RENDERER = /swiftshader|llvmpipe|softpipe|software rasterizer|basic render/i;

  // The strategies (paper IV.B's strategy classes), finest first.
  const STRATEGIES = {
    // Small scenes, or medium ones on a strong device: detail first.
    detail: { sseMin: 4, sseStart: START_SSE, sseMax: 32, motionFactor: 1.5, progressive: 0 },
    // The middle ground.
    balanced: { sseMin: 8, sseStart: START_SSE, sseMax: 64, motionFactor: 2, progressive: 0 },
    // Large scenes on small devices: coarse levels, much coarser while moving, and the first
    // frames of a load drawn at half resolution (progressiveResolutionHeightFraction).
    economy: { sseMin: 16, sseStart: 24, sseMax: 128, motionFactor: 3, progressive: 0.5 },
  };
  const ORDER = ["detail", "balanced", "economy"];

  /** The name of the WebGL renderer drawing on `canvas` (the context the viewer created: asking
   * a canvas for its own context type returns that context), or "" when it is not told. */
  function renderer(canvas) {
    try {
      const gl = canvas.getContext("webgl2") || canvas.getContext("webgl");
      if (!gl) return "";
      const info = gl.getExtension("WEBGL_debug_renderer_info");
      return String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER) || "");
    } catch (e) {
      return "";
    }
  }

  /** The device: cores, memory (GB, with its source), a class (0 small, 1 mid, 2 strong), and
   * whether its WebGL is rasterised in software. */
  function device(nav, rendererName) {
    const cores = nav.hardwareConcurrency || 2;
    const reported = typeof nav.deviceMemory === "number" && nav.deviceMemory > 0;
    const memoryGb = reported ? nav.deviceMemory : DEFAULT_DEVICE_MEMORY_GB;
    const cls = memoryGb >= 8 && cores >= 8 ? 2 : memoryGb < 4 || cores <= 2 ? 0 : 1;
    const software = SOFTWARE_RENDERER.test(rendererName || "");
    return { cores, memoryGb, memoryReported: reported, class: cls, software };
  }

  /** The drawing resolution, as a share of the canvas's: `scale=N` in the URL (0.1 to 2), else
   * half on a software rasteriser, else full. */
  function resolutionScale(params, dev) {
    const forced = parseFloat(params.get("scale") || "");
    if (Number.isFinite(forced) && forced >= 0.1 && forced <= 2) return forced;
    return dev.software ? SOFTWARE_RESOLUTION_SCALE : 1;
  }

  /** Tile cache budget from the device memory: 64 MiB per GB, 64 MiB to 512 MiB (Cesium's
   * default); the overflow Cesium may use while the view needs more, half of it. */
  function cacheBudget(memoryGb) {
    const MiB = 1024 * 1024;
    const cacheBytes = Math.round(Math.min(512, Math.max(64, 64 * memoryGb)) * MiB);
    return { cacheBytes, maximumCacheOverflowBytes: Math.round(cacheBytes / 2) };
  }

  function plan(params, nav, fixedSse, rendererName) {
    const dev = device(nav, rendererName);
    const fps = parseFloat(params.get("fps") || "");
    const fixed = Number.isFinite(fixedSse) && fixedSse > 0;
    const forced = params.get("strategy");
    return {
      device: dev,
      resolutionScale: resolutionScale(params, dev),
      targetFps: Number.isFinite(fps) && fps > 0 ? fps : DEFAULT_TARGET_FPS,
      adaptive: !fixed && params.get("adaptive") !== "0",
      fixedSse: fixed ? fixedSse : null,
      forcedStrategy: STRATEGIES[forced] ? forced : null,
      tilesetOptions: {
        maximumScreenSpaceError: fixed ? fixedSse : START_SSE,
        ...cacheBudget(dev.memoryGb),
        // Cesium's own view-dependent relaxations: coarser tiles at the screen's edges and
        // towards the horizon, no requests for tiles the moving camera leaves.
        foveatedScreenSpaceError: true,
        dynamicScreenSpaceError: true,
        cullRequestsWhileMoving: true,
      },
    };
  }

  /** Tiles in the loaded tree (tileset.json, and external tilesets already read). */
  function countTiles(root) {
    let n = 0;
    const stack = [root];
    while (stack.length) {
      const t = stack.pop();
      n++;
      for (const c of t.children || []) stack.push(c);
    }
    return n;
  }

  /** Scene class from its tile count: 0 small (<= 16 tiles), 1 medium (<= 128), 2 large. */
  function sceneClass(tiles) {
    return tiles <= 16 ? 0 : tiles <= 128 ? 1 : 2;
  }

  /** The strategy for a scene class and a device class: one step coarser per class the scene is
   * above the device. */
  function choose(sceneCls, deviceCls) {
    return ORDER[Math.max(0, Math.min(2, sceneCls - deviceCls + 1))];
  }

  function start(scene, tileset, p, onState) {
    const tiles = countTiles(tileset.root);
    const sCls = sceneClass(tiles);
    const name = p.forcedStrategy || choose(sCls, p.device.class);
    const st = STRATEGIES[name];
    const state = {
      strategy: name,
      forced: !!p.forcedStrategy,
      sceneTiles: tiles,
      sceneClass: ["small", "medium", "large"][sCls],
      cores: p.device.cores,
      memoryGb: p.device.memoryGb,
      memoryReported: p.device.memoryReported,
      softwareRenderer: p.device.software,
      resolutionScale: p.resolutionScale,
      cacheBytes: tileset.cacheBytes,
      adaptive: p.adaptive,
      targetFps: p.targetFps,
      sseMin: p.adaptive ? st.sseMin : p.fixedSse || st.sseStart,
      sseMax: p.adaptive ? st.sseMax : p.fixedSse || st.sseStart,
      sse: p.fixedSse || st.sseStart, // the SSE when the camera is still
      sseApplied: p.fixedSse || st.sseStart, // what the tileset uses now (higher while moving)
      fps: null,
      moving: false,
      adjustments: 0,
    };
    tileset.progressiveResolutionHeightFraction = st.progressive;
    const apply = () => {
      const moving = state.adaptive && state.moving;
      state.sseApplied = moving ? Math.min(state.sseMax, state.sse * st.motionFactor) : state.sse;
      tileset.maximumScreenSpaceError = state.sseApplied;
    };
    apply();

    let windowStart = performance.now();
    let windowFrames = 0;
    const onFrame = () => {
      windowFrames++;
      const now = performance.now();
      const elapsed = now - windowStart;
      if (elapsed < WINDOW_MS || windowFrames < WINDOW_MIN_FRAMES) return;
      state.fps = +((1000 * windowFrames) / elapsed).toFixed(2);
      windowStart = now;
      windowFrames = 0;
      if (state.adaptive) {
        let sse = state.sse;
        if (state.fps < LOW * state.targetFps) sse = Math.min(state.sseMax, sse * STEP);
        else if (state.fps > HIGH * state.targetFps) sse = Math.max(state.sseMin, sse / STEP);
        if (sse !== state.sse) {
          state.sse = +sse.toFixed(3);
          state.adjustments++;
          apply();
        }
      }
      onState(state);
    };
    // Coarser while the camera moves (the first view as the user starts flying), back on stop.
    const onMoveStart = () => {
      state.moving = true;
      apply();
      onState(state);
    };
    const onMoveEnd = () => {
      state.moving = false;
      apply();
      onState(state);
    };
    const offs = [
      scene.postRender.addEventListener(onFrame),
      scene.camera.moveStart.addEventListener(onMoveStart),
      scene.camera.moveEnd.addEventListener(onMoveEnd),
    ];
    onState(state);
    return { state, destroy: () => offs.forEach((off) => off()) };
  }

  function describe(s) {
    const mem = `${s.memoryGb} GB${s.memoryReported ? "" : " (assumed)"}`;
    const sse = s.adaptive ? `SSE ${s.sseApplied.toFixed(1)} [${s.sseMin}-${s.sseMax}]` : `SSE ${s.sse} fixed`;
    const fps = s.fps === null ? "- fps" : `${s.fps.toFixed(1)} fps`;
    const gpu = s.softwareRenderer ? ", software WebGL" : "";
    const res = s.resolutionScale === 1 ? "" : ` · ${s.resolutionScale}x resolution`;
    return (
      `${s.strategy}${s.forced ? " (forced)" : ""}: ${s.sceneClass} scene (${s.sceneTiles} tile${s.sceneTiles === 1 ? "" : "s"}), ` +
      `${s.cores} cores, ${mem}${gpu} · ${sse}${s.moving ? " moving" : ""}${res} · ${fps} / ${s.targetFps} target`
    );
  }

  window.BimtilesAdaptive = { renderer, plan, start, describe, STRATEGIES };
})();
