// bimtiles viewer, BIM tools (paper section IV, the web BIM system): model tree, search, hide /
// isolate / x-ray, colour by property, section box and plan cut, measure, and the view's state in
// the URL. Loaded by viewer.js only after the first view is drawn (or when the tools are opened),
// so the first view is not slowed; it then fetches the element index (element-index.json, named by
// tileset.json's asset.extras.bimtiles.elementIndex; book: reference/element-index.md).
//
// Feature styling is per feature (Cesium3DTileFeature show / color), applied to every loaded tile
// and to each tile as it loads, keyed by the element id of the tiles' property tables.
//
// For tests, window.bimtilesBim exposes the state and actions (see the `api` object at the end).
"use strict";

(function () {
  const { viewer } = window.bimtiles;
  const status = window.bimtilesStatus;
  const ROW_PX = 22; // height of one tree row (virtualised list)
  const LEVELS = ["site", "building", "storey", "class"];
  const NONE_LABEL = { site: "(no site)", building: "(no building)", storey: "(no storey)", class: "(no class)" };
  const XRAY = new Cesium.Color(0.75, 0.8, 0.86, 0.12);
  const SELECTED = Cesium.Color.YELLOW.withAlpha(0.9);
  const PLAN_CUT_ABOVE_FLOOR_M = 1.2; // a floor plan's conventional cut height
  const SEARCH_RESULTS = 50;

  const state = {
    index: null, // decoded element index (decodeIndex)
    hidden: null, // Uint8Array per row: 1 = hidden
    hiddenPrefix: null, // prefix sums of hidden, for node check states
    hideKeys: [], // tree node keys hidden, in order (URL)
    isolateKey: null, // tree node key isolated (URL)
    isolated: null, // Uint8Array per row, or null
    isolateMode: "xray", // the rest: "xray" (faint) or "hide"
    xray: false, // everything faint
    colorBy: "", // property colouring the features, "" = none
    colors: new Map(), // value -> Cesium.Color
    legend: new Map(), // value -> count
    selectedId: null,
    section: null, // {kind: "box", min: [x,y,z], max: [x,y,z]} | {kind: "plan", z} (tileset frame, m)
    measure: null, // {mode, points: [Cartesian3], distanceM, heightM}
  };
  const rowOf = new Map(); // element id -> row
  let tileset = window.bimtiles.tileset;

  // --- the element index --------------------------------------------------------------------
  function decodeIndex(json) {
    if (json.format !== "bimtiles-element-index/2") throw new Error("unknown element index format " + json.format);
    const c = json.columns;
    const d = json.dictionaries;
    const n = json.count;
    const box = Float64Array.from(c.box_mm, (v) => v / 1000);
    const ix = { n, d, c, box, hay: new Array(n) };
    for (let i = 0; i < n; i++) {
      rowOf.set(c.id[i], i);
      ix.hay[i] = [c.id[i], c.name[i] || "", d.class[c.class[i]] || "", d.storey[c.storey[i]] || "", d.building[c.building[i]] || "", path(ix, i)]
        .join("\n")
        .toLowerCase();
    }
    return ix;
  }
  function path(ix, i) {
    const parent = ix.d.pathParent[ix.c.pathParent[i]];
    // A null leaf is the element's label (its name, else its id); "" under no parent is no path.
    const leaf = ix.c.pathLeaf[i] ?? (ix.c.name[i] || ix.c.id[i]);
    return parent !== null ? parent + "/" + leaf : leaf;
  }
  function value(i, level) {
    return state.index.d[level][state.index.c[level][i]];
  }
  function rowBox(i) {
    const b = state.index.box;
    return { min: [b[6 * i], b[6 * i + 1], b[6 * i + 2]], max: [b[6 * i] + b[6 * i + 3], b[6 * i + 1] + b[6 * i + 4], b[6 * i + 2] + b[6 * i + 5]] };
  }
  function rangeBox(start, end) {
    const min = [Infinity, Infinity, Infinity], max = [-Infinity, -Infinity, -Infinity];
    for (let i = start; i < end; i++) {
      const b = rowBox(i);
      for (let k = 0; k < 3; k++) {
        min[k] = Math.min(min[k], b.min[k]);
        max[k] = Math.max(max[k], b.max[k]);
      }
    }
    return { min, max };
  }

  // --- tree: site -> building -> storey -> class -> element ----------------------------------
  // Rows are sorted by site, building, storey, class codes: every node is one run [start, end).
  function buildTree(ix) {
    const root = { key: "", level: 0, start: 0, end: ix.n, children: [], expanded: true };
    const open = [root];
    for (let i = 0; i < ix.n; i++) {
      for (let l = 0; l < LEVELS.length; l++) {
        const parent = open[l];
        let node = open[l + 1];
        const code = ix.c[LEVELS[l]][i];
        if (!node || node.parentNode !== parent || node.code !== code) {
          node = { level: l + 1, what: LEVELS[l], code, start: i, end: i, children: [], expanded: l < 2 && ix.d.building.length <= 50, parentNode: parent };
          node.key = (parent.key ? parent.key + "/" : "") + code;
          node.label = ix.d[LEVELS[l]][code] ?? NONE_LABEL[LEVELS[l]];
          parent.children.push(node);
          open[l + 1] = node;
          open.length = l + 2;
        }
        node.end = i + 1;
      }
    }
    // Storeys by elevation (median of their elements' lowest points), lowest first.
    const walk = (n) => {
      if (n.what === "storey") n.elevationM = storeyElevation(ix, n.start, n.end);
      n.children.forEach(walk);
      if (n.children.length && n.children[0].what === "storey") n.children.sort((a, b) => a.elevationM - b.elevationM);
    };
    walk(root);
    return root;
  }
  function storeyElevation(ix, start, end) {
    const z = [];
    for (let i = start; i < end; i++) z.push(ix.box[6 * i + 2]);
    z.sort((a, b) => a - b);
    return z[z.length >> 1];
  }
  function nodeByKey(key) {
    if (key.startsWith("e:")) return null;
    let n = state.tree;
    for (const part of key.split("/").filter((p) => p !== "")) {
      n = n && n.children.find((c) => String(c.code) === part);
    }
    return n || null;
  }
  function keyRange(key) {
    if (key.startsWith("e:")) {
      const r = rowOf.get(key.slice(2));
      return r === undefined ? null : [r, r + 1];
    }
    const n = nodeByKey(key);
    return n ? [n.start, n.end] : null;
  }

  // Flattened visible rows: {node} or {row, parentNode}.
  function flatten() {
    const out = [];
    const walk = (n) => {
      for (const c of n.children) {
        out.push({ node: c });
        if (c.expanded) {
          if (c.what === "class") for (let i = c.start; i < c.end; i++) out.push({ row: i, level: 5, parentNode: c });
          else walk(c);
        }
      }
    };
    walk(state.tree);
    state.flat = out;
  }

  function hiddenCount(start, end) {
    return state.hiddenPrefix[end] - state.hiddenPrefix[start];
  }
  function visibilityChanged() {
    const h = state.hidden;
    const p = state.hiddenPrefix;
    for (let i = 0; i < h.length; i++) p[i + 1] = p[i] + h[i];
    applyAll();
    renderTree();
    saveUrl();
  }
  function setHidden(key, hide) {
    const r = keyRange(key);
    if (!r) return;
    state.hidden.fill(hide ? 1 : 0, r[0], r[1]);
    state.hideKeys = state.hideKeys.filter((k) => k !== key);
    state.hideKeys.push((hide ? "" : "+") + key);
    visibilityChanged();
  }
  function isolate(key, mode) {
    state.isolateKey = key;
    if (mode) state.isolateMode = mode;
    state.isolated = null;
    const r = key && keyRange(key);
    if (r) {
      state.isolated = new Uint8Array(state.index.n);
      state.isolated.fill(1, r[0], r[1]);
    } else state.isolateKey = null;
    applyAll();
    renderTree();
    saveUrl();
    document.getElementById("bimIsolateMode").value = state.isolateMode;
  }
  function showAll() {
    state.hidden.fill(0);
    state.hideKeys = [];
    state.isolateKey = null;
    state.isolated = null;
    visibilityChanged();
  }

  // --- styling features ----------------------------------------------------------------------
  function featureValue(f, id, prop) {
    const r = rowOf.get(id);
    if (r !== undefined && LEVELS.includes(prop)) return value(r, prop);
    const v = f.getProperty(prop);
    return v === undefined ? null : v;
  }
  function colorOf(v) {
    const k = v === null || v === undefined ? "(none)" : String(v);
    let c = state.colors.get(k);
    if (!c) {
      // Golden-angle hues: neighbours in the legend stay far apart.
      c = Cesium.Color.fromHsl(((state.colors.size * 137.508) % 360) / 360, 0.62, 0.55, 1);
      state.colors.set(k, c);
    }
    return c;
  }
  function styleFeature(f) {
    const id = f.getProperty("id");
    const r = rowOf.get(id);
    let show = true;
    let color = Cesium.Color.WHITE;
    if (state.colorBy) color = colorOf(featureValue(f, id, state.colorBy));
    if (r !== undefined && state.hidden && state.hidden[r]) show = false;
    if (r !== undefined && state.isolated && !state.isolated[r]) {
      if (state.isolateMode === "hide") show = false;
      else color = XRAY;
    } else if (state.xray) color = Cesium.Color.fromAlpha(color, 0.25);
    if (id !== undefined && id === state.selectedId) color = SELECTED;
    f.show = show;
    f.color = color;
  }
  function styleContent(content) {
    if (!content || !content.featuresLength) return;
    for (let i = 0; i < content.featuresLength; i++) styleFeature(content.getFeature(i));
    if (content.innerContents) content.innerContents.forEach(styleContent);
  }
  function loadedContents() {
    const out = [];
    const walk = (t) => {
      if (t.contentReady && t.content) out.push(t.content);
      t.children.forEach(walk);
    };
    if (tileset && tileset.root) walk(tileset.root);
    return out;
  }
  function applyAll() {
    loadedContents().forEach(styleContent);
    if (state.colorBy) updateLegend();
  }
  function onTileLoad(tile) {
    styleContent(tile.content);
    collectProperties(tile.content);
  }

  // --- colour by property ---------------------------------------------------------------------
  const propertyIds = new Set(["class", "storey", "building", "site", "material"]);
  function collectProperties(content) {
    if (!content || !content.featuresLength) return;
    const before = propertyIds.size;
    for (const p of content.getFeature(0).getPropertyIds()) if (p !== "id" && p !== "aliases" && p !== "name" && p !== "path") propertyIds.add(p);
    if (propertyIds.size !== before) fillColorSelect();
  }
  function fillColorSelect() {
    const sel = document.getElementById("bimColorBy");
    const cur = sel.value || state.colorBy;
    sel.textContent = "";
    for (const p of ["", ...propertyIds]) {
      const o = document.createElement("option");
      o.value = p;
      o.textContent = p || "(no colouring)";
      sel.appendChild(o);
    }
    sel.value = cur;
  }
  function colorBy(prop) {
    state.colorBy = prop || "";
    state.colors = new Map();
    if (state.colorBy && LEVELS.includes(state.colorBy) && state.index) {
      // Colours in the legend's (sorted) order, whatever order tiles load in.
      for (const v of legendValues()) colorOf(v[0] === "(none)" ? null : v[0]);
    }
    applyAll();
    updateLegend();
    document.getElementById("bimColorBy").value = state.colorBy;
    saveUrl();
  }
  function legendValues() {
    const counts = new Map();
    if (LEVELS.includes(state.colorBy) && state.index) {
      for (let i = 0; i < state.index.n; i++) {
        const v = value(i, state.colorBy) ?? "(none)";
        counts.set(v, (counts.get(v) || 0) + 1);
      }
    } else {
      const seen = new Set();
      for (const content of loadedContents()) {
        for (let i = 0; i < content.featuresLength; i++) {
          const f = content.getFeature(i);
          const id = f.getProperty("id");
          if (seen.has(id)) continue;
          seen.add(id);
          const v = featureValue(f, id, state.colorBy);
          const k = v === null ? "(none)" : String(v);
          counts.set(k, (counts.get(k) || 0) + 1);
        }
      }
    }
    return [...counts.entries()].sort((a, b) => String(a[0]).localeCompare(String(b[0])));
  }
  function updateLegend() {
    const el = document.getElementById("bimLegend");
    el.textContent = "";
    state.legend = new Map();
    if (!state.colorBy) return;
    for (const [v, n] of legendValues()) {
      state.legend.set(v, n);
      const li = document.createElement("li");
      const sw = document.createElement("span");
      sw.className = "swatch";
      sw.style.background = colorOf(v === "(none)" ? null : v).toCssColorString();
      li.append(sw, document.createTextNode(`${v} (${n})`));
      el.appendChild(li);
    }
  }

  // --- selection and flying -------------------------------------------------------------------
  function toWorld(p) {
    return Cesium.Matrix4.multiplyByPoint(tileset.root.computedTransform, new Cesium.Cartesian3(p[0], p[1], p[2]), new Cesium.Cartesian3());
  }
  function toLocal(world) {
    const inv = Cesium.Matrix4.inverse(tileset.root.computedTransform, new Cesium.Matrix4());
    const p = Cesium.Matrix4.multiplyByPoint(inv, world, new Cesium.Cartesian3());
    return [p.x, p.y, p.z];
  }
  function boxSphere(b) {
    const pts = [];
    for (let k = 0; k < 8; k++) pts.push(toWorld([k & 1 ? b.max[0] : b.min[0], k & 2 ? b.max[1] : b.min[1], k & 4 ? b.max[2] : b.min[2]]));
    return Cesium.BoundingSphere.fromPoints(pts);
  }
  function flyToBox(b) {
    const s = boxSphere(b);
    const duration = api.flyDurationS;
    return new Promise((resolve) =>
      viewer.camera.flyToBoundingSphere(s, {
        duration,
        offset: new Cesium.HeadingPitchRange(0.6, -0.45, Math.max(s.radius * 3.2, 2)),
        complete: resolve,
        cancel: resolve,
      }),
    );
  }
  function selectId(id, { fly = false, reveal = true } = {}) {
    state.selectedId = id;
    applyAll();
    const r = id === null ? undefined : rowOf.get(id);
    if (r !== undefined && reveal) revealRow(r);
    renderTree();
    saveUrl();
    if (r !== undefined) showIndexProps(r);
    return r !== undefined && fly ? flyToBox(rowBox(r)) : Promise.resolve();
  }
  function showIndexProps(r) {
    if (!window.bimtiles.showRows) return;
    const ix = state.index;
    const rows = [
      ["id", ix.c.id[r]], ["name", ix.c.name[r]], ["class", value(r, "class")], ["storey", value(r, "storey")],
      ["building", value(r, "building")], ["site", value(r, "site")], ["path", path(ix, r)],
    ];
    window.bimtiles.showRows("Element", rows.filter(([, v]) => v !== null && v !== ""));
  }
  // Called by viewer.js when an element is picked (instead of its own highlight).
  function pickedFeature(feature) {
    const id = feature instanceof Cesium.Cesium3DTileFeature ? feature.getProperty("id") : null;
    state.selectedId = id ?? null;
    applyAll();
    if (state.index && id !== null && rowOf.has(id)) revealRow(rowOf.get(id));
    renderTree();
    saveUrl();
  }
  function revealRow(r) {
    let n = state.tree;
    while (n && n.children.length) {
      n = n.children.find((c) => c.start <= r && r < c.end);
      if (n) n.expanded = true;
    }
    flatten();
    const k = state.flat.findIndex((e) => e.row === r);
    if (k >= 0) {
      state.focus = k;
      const tree = document.getElementById("bimTree");
      const top = k * ROW_PX;
      if (top < tree.scrollTop || top > tree.scrollTop + tree.clientHeight - ROW_PX) tree.scrollTop = Math.max(0, top - tree.clientHeight / 2);
    }
  }

  // --- the tree's DOM: a virtualised ARIA tree --------------------------------------------------
  function renderTree() {
    const tree = document.getElementById("bimTree");
    if (!state.tree || !tree) return;
    if (!state.flat) flatten();
    const inner = document.getElementById("bimTreeInner");
    inner.style.height = state.flat.length * ROW_PX + "px";
    const first = Math.max(0, Math.floor(tree.scrollTop / ROW_PX) - 5);
    const last = Math.min(state.flat.length, Math.ceil((tree.scrollTop + tree.clientHeight) / ROW_PX) + 5);
    inner.textContent = "";
    for (let k = first; k < last; k++) inner.appendChild(treeRow(state.flat[k], k));
    tree.setAttribute("aria-activedescendant", "bimRow" + (state.focus ?? 0));
  }
  function treeRow(e, k) {
    const div = document.createElement("div");
    div.id = "bimRow" + k;
    div.setAttribute("role", "treeitem");
    div.className = "treerow" + (k === state.focus ? " focus" : "");
    div.style.top = k * ROW_PX + "px";
    const level = e.node ? e.node.level : 5;
    div.setAttribute("aria-level", level);
    div.style.paddingLeft = (level - 1) * 12 + "px";
    const [start, end] = e.node ? [e.node.start, e.node.end] : [e.row, e.row + 1];
    const hidden = hiddenCount(start, end);
    div.setAttribute("aria-checked", hidden === 0 ? "true" : hidden === end - start ? "false" : "mixed");
    const twist = document.createElement("span");
    twist.className = "twist";
    const box = document.createElement("input");
    box.type = "checkbox";
    box.tabIndex = -1;
    box.checked = hidden === 0;
    box.indeterminate = hidden > 0 && hidden < end - start;
    box.setAttribute("aria-hidden", "true");
    const label = document.createElement("span");
    label.className = "label";
    const key = e.node ? e.node.key : "e:" + state.index.c.id[e.row];
    div.dataset.key = key;
    if (e.node) {
      div.setAttribute("aria-expanded", String(!!e.node.expanded));
      twist.textContent = e.node.expanded ? "▾" : "▸";
      label.textContent = `${e.node.label} (${end - start})`;
      div.setAttribute("aria-label", `${e.node.what} ${e.node.label}, ${end - start} elements`);
    } else {
      const id = state.index.c.id[e.row];
      label.textContent = state.index.c.name[e.row] || id;
      div.setAttribute("aria-label", `element ${state.index.c.name[e.row] || ""} ${id}`);
      div.setAttribute("aria-selected", String(id === state.selectedId));
      if (id === state.selectedId) div.classList.add("selected");
    }
    if (state.isolateKey === key) div.classList.add("isolated");
    const iso = button("◎", "Isolate: show only these", () => isolate(state.isolateKey === key ? null : key));
    div.append(twist, box, label, iso);
    if (e.node && e.node.what === "storey") div.append(button("✂", "Plan cut at this storey", () => planCut(e.node)));
    twist.onclick = (ev) => {
      ev.stopPropagation();
      if (e.node) toggleExpand(e.node);
    };
    box.onclick = (ev) => {
      ev.stopPropagation();
      setHidden(key, hidden === 0);
    };
    div.onclick = () => {
      state.focus = k;
      if (e.node) toggleExpand(e.node);
      else selectId(state.index.c.id[e.row], { fly: true, reveal: false });
    };
    return div;
  }
  function button(text, title, onclick) {
    const b = document.createElement("button");
    b.className = "rowbtn";
    b.textContent = text;
    b.title = title;
    b.setAttribute("aria-label", title);
    b.tabIndex = -1;
    b.onclick = (ev) => {
      ev.stopPropagation();
      onclick();
    };
    return b;
  }
  function toggleExpand(node, open) {
    node.expanded = open === undefined ? !node.expanded : open;
    flatten();
    renderTree();
  }
  function treeKey(ev) {
    if (!state.flat) return;
    const k = state.focus ?? 0;
    const e = state.flat[k];
    const move = (to) => {
      state.focus = Math.max(0, Math.min(state.flat.length - 1, to));
      revealFocus();
    };
    const keyOf = (e) => (e.node ? e.node.key : "e:" + state.index.c.id[e.row]);
    switch (ev.key) {
      case "ArrowDown": move(k + 1); break;
      case "ArrowUp": move(k - 1); break;
      case "Home": move(0); break;
      case "End": move(state.flat.length - 1); break;
      case "ArrowRight": if (e.node && !e.node.expanded) toggleExpand(e.node, true); else move(k + 1); break;
      case "ArrowLeft":
        if (e.node && e.node.expanded) toggleExpand(e.node, false);
        else {
          const parent = e.node ? e.node.parentNode : e.parentNode;
          const p = state.flat.findIndex((x) => x.node === parent);
          if (p >= 0) move(p);
        }
        break;
      case " ": {
        const [s, t] = e.node ? [e.node.start, e.node.end] : [e.row, e.row + 1];
        setHidden(keyOf(e), hiddenCount(s, t) === 0);
        break;
      }
      case "Enter": if (e.node) toggleExpand(e.node); else selectId(state.index.c.id[e.row], { fly: true, reveal: false }); break;
      case "i": isolate(state.isolateKey === keyOf(e) ? null : keyOf(e)); break;
      default: return;
    }
    ev.preventDefault();
  }
  function revealFocus() {
    const tree = document.getElementById("bimTree");
    const top = state.focus * ROW_PX;
    if (top < tree.scrollTop) tree.scrollTop = top;
    else if (top > tree.scrollTop + tree.clientHeight - ROW_PX) tree.scrollTop = top - tree.clientHeight + ROW_PX;
    renderTree();
  }

  // --- search ---------------------------------------------------------------------------------
  // Index fields (id / GlobalId, name, class, storey, building, path), then property values of the
  // elements in loaded tiles.
  function search(q) {
    const t0 = performance.now();
    q = q.trim().toLowerCase();
    const hits = [];
    let total = 0;
    if (q && state.index) {
      const hay = state.index.hay;
      for (let i = 0; i < hay.length; i++) {
        if (hay[i].includes(q)) {
          if (hits.length < SEARCH_RESULTS) hits.push({ row: i });
          total++;
        }
      }
      if (hits.length < SEARCH_RESULTS) {
        const seen = new Set(hits.map((h) => state.index.c.id[h.row]));
        for (const content of loadedContents()) {
          for (let f = 0; f < content.featuresLength && hits.length < SEARCH_RESULTS; f++) {
            const feature = content.getFeature(f);
            const id = feature.getProperty("id");
            if (seen.has(id) || !rowOf.has(id)) continue;
            for (const p of feature.getPropertyIds()) {
              const v = feature.getProperty(p);
              if (v !== undefined && v !== null && String(v).toLowerCase().includes(q)) {
                seen.add(id);
                hits.push({ row: rowOf.get(id), via: `${p}: ${v}` });
                total++;
                break;
              }
            }
          }
        }
      }
    }
    const ms = performance.now() - t0;
    state.lastSearch = { query: q, total, ms, ids: hits.map((h) => state.index.c.id[h.row]) };
    return hits;
  }
  function renderResults(hits) {
    const list = document.getElementById("bimResults");
    list.textContent = "";
    hits.forEach((h, k) => {
      const li = document.createElement("li");
      li.setAttribute("role", "option");
      li.id = "bimResult" + k;
      const id = state.index.c.id[h.row];
      li.textContent = `${state.index.c.name[h.row] || id} · ${value(h.row, "class") || ""} · ${value(h.row, "storey") || ""}` + (h.via ? ` · ${h.via}` : "");
      li.title = id;
      li.onclick = () => selectId(id, { fly: true });
      list.appendChild(li);
    });
    list.classList.toggle("hidden", hits.length === 0);
    const s = state.lastSearch;
    document.getElementById("bimSearchInfo").textContent = s && s.query ? `${s.total} found in ${s.ms.toFixed(0)} ms` : "";
  }

  // --- section box and plan cut ---------------------------------------------------------------
  let sectionOutline = null;
  const handles = [];
  function setSection(sec) {
    state.section = sec;
    const planes = [];
    if (sec && sec.kind === "box") {
      for (let k = 0; k < 3; k++) {
        const n = [0, 0, 0];
        n[k] = 1;
        planes.push(new Cesium.ClippingPlane(Cesium.Cartesian3.fromArray(n), -sec.min[k]));
        n[k] = -1;
        planes.push(new Cesium.ClippingPlane(Cesium.Cartesian3.fromArray(n), sec.max[k]));
      }
    } else if (sec && sec.kind === "plan") planes.push(new Cesium.ClippingPlane(new Cesium.Cartesian3(0, 0, -1), sec.z));
    // The tileset's clipping planes are in the root tile's frame: the tileset frame of the index.
    // One collection for the tileset's life, its planes replaced: a collection replaced while
    // tiles still hold its texture stops Cesium's rendering.
    if (!tileset.clippingPlanes)
      tileset.clippingPlanes = new Cesium.ClippingPlaneCollection({ unionClippingRegions: true, edgeWidth: 1.0, edgeColor: Cesium.Color.ORANGE, enabled: false });
    const clip = tileset.clippingPlanes;
    clip.removeAll();
    planes.forEach((p) => clip.add(p));
    clip.enabled = planes.length > 0;
    drawSectionBox();
    document.getElementById("bimSectionOff").disabled = !sec;
    saveUrl();
  }
  function sectionAroundSelection() {
    let b;
    const r = state.selectedId !== null ? rowOf.get(state.selectedId) : undefined;
    if (r !== undefined) b = rowBox(r);
    else if (state.isolateKey && keyRange(state.isolateKey)) b = rangeBox(...keyRange(state.isolateKey));
    else b = rangeBox(0, state.index.n);
    const pad = 0.25;
    setSection({ kind: "box", min: b.min.map((v) => v - pad), max: b.max.map((v) => v + pad) });
  }
  function planCut(storeyNode) {
    setSection({ kind: "plan", z: +(storeyNode.elevationM + PLAN_CUT_ABOVE_FLOOR_M).toFixed(3) });
  }
  function drawSectionBox() {
    if (sectionOutline) viewer.scene.primitives.remove(sectionOutline);
    sectionOutline = null;
    handles.splice(0).forEach((h) => viewer.entities.remove(h));
    const sec = state.section;
    if (!sec || sec.kind !== "box") return;
    const size = sec.max.map((v, k) => v - sec.min[k]);
    const centre = sec.max.map((v, k) => (v + sec.min[k]) / 2);
    const m = Cesium.Matrix4.multiply(tileset.root.computedTransform, Cesium.Matrix4.fromTranslation(Cesium.Cartesian3.fromArray(centre)), new Cesium.Matrix4());
    sectionOutline = viewer.scene.primitives.add(
      new Cesium.Primitive({
        geometryInstances: new Cesium.GeometryInstance({
          geometry: Cesium.BoxOutlineGeometry.fromDimensions({ dimensions: Cesium.Cartesian3.fromArray(size) }),
          modelMatrix: m,
          attributes: { color: Cesium.ColorGeometryInstanceAttribute.fromColor(Cesium.Color.ORANGE) },
        }),
        appearance: new Cesium.PerInstanceColorAppearance({ flat: true, translucent: false }),
        asynchronous: false,
      }),
    );
    // A handle at each face centre, dragged along its axis.
    for (let k = 0; k < 3; k++) {
      for (const side of ["min", "max"]) {
        const p = centre.slice();
        p[k] = sec[side][k];
        handles.push(
          viewer.entities.add({
            position: toWorld(p),
            point: { pixelSize: 12, color: Cesium.Color.ORANGE, outlineColor: Cesium.Color.BLACK, outlineWidth: 1, disableDepthTestDistance: Number.POSITIVE_INFINITY },
            properties: { face: { axis: k, side } },
          }),
        );
      }
    }
  }
  let drag = null;
  function onLeftDown(e) {
    if (!state.section || state.section.kind !== "box") return false;
    const picked = viewer.scene.pick(e.position);
    const face = picked && picked.id && picked.id.properties && picked.id.properties.face;
    if (!face) return false;
    const f = face.getValue();
    drag = { axis: f.axis, side: f.side, last: Cesium.Cartesian2.clone(e.position) };
    viewer.scene.screenSpaceCameraController.enableInputs = false;
    return true;
  }
  function onMouseMove(e) {
    if (!drag) return;
    const sec = state.section;
    const p = sec[drag.side].slice();
    const a = toWorld(p);
    p[drag.axis] += 1;
    const b = toWorld(p);
    const sa = Cesium.SceneTransforms.worldToWindowCoordinates(viewer.scene, a);
    const sb = Cesium.SceneTransforms.worldToWindowCoordinates(viewer.scene, b);
    if (!sa || !sb) return;
    const v = [sb.x - sa.x, sb.y - sa.y];
    const d = [e.endPosition.x - drag.last.x, e.endPosition.y - drag.last.y];
    const len2 = v[0] * v[0] + v[1] * v[1];
    if (len2 < 1e-6) return;
    const moveM = (d[0] * v[0] + d[1] * v[1]) / len2;
    drag.last = Cesium.Cartesian2.clone(e.endPosition);
    const next = { kind: "box", min: sec.min.slice(), max: sec.max.slice() };
    next[drag.side][drag.axis] += moveM;
    if (next.max[drag.axis] - next.min[drag.axis] < 0.05) return;
    setSection(next);
  }
  function onLeftUp() {
    if (!drag) return;
    drag = null;
    viewer.scene.screenSpaceCameraController.enableInputs = true;
  }

  // --- measure ----------------------------------------------------------------------------------
  const measureEntities = [];
  function startMeasure(mode) {
    measureEntities.splice(0).forEach((e) => viewer.entities.remove(e));
    state.measure = mode ? { mode, points: [], distanceM: null, heightM: null } : null;
    document.getElementById("bimMeasureOut").textContent = mode ? "pick two points on the model" : "";
    status.measure = null;
  }
  // The depth buffer places a picked point within centimetres (its precision at the camera's
  // distance); CesiumJS's ray cast on the drawn tiles' triangles (Cesium3DTileset.pick) places it
  // on a triangle. The ray cast also meets what is not drawn there: faces seen from behind,
  // hidden elements, what the section cuts away. So hits are stepped over, nearest first, until
  // one agrees with the depth buffer's point (the surface drawn there); if none does, the depth
  // buffer's point stands. Without depth picking, the first hit the section keeps is taken.
  const SNAP_AGREEMENT = 0.01; // of the distance from the camera
  const SNAP_STEPS = 64;
  function cutAway(local) {
    const sec = state.section;
    if (!sec) return false;
    if (sec.kind === "plan") return local[2] > sec.z;
    return local.some((v, k) => v < sec.min[k] || v > sec.max[k]);
  }
  function surfacePoint(position) {
    const scene = viewer.scene;
    const drawn = scene.pickPositionSupported ? scene.pickPosition(position) : undefined;
    if (scene.pickPositionSupported && !drawn) return undefined;
    const ray = viewer.camera.getPickRay(position);
    const tolerance = drawn && SNAP_AGREEMENT * Cesium.Cartesian3.distance(ray.origin, drawn);
    const beyond = drawn && Cesium.Cartesian3.distance(ray.origin, drawn) + tolerance;
    const start = Cesium.Cartesian3.clone(ray.origin);
    for (let k = 0; k < SNAP_STEPS; k++) {
      const hit = tileset.pick(ray, scene.frameState);
      if (!hit || (drawn && Cesium.Cartesian3.distance(start, hit) > beyond)) break;
      if (!cutAway(toLocal(hit)) && (!drawn || Cesium.Cartesian3.distance(hit, drawn) <= tolerance)) return hit;
      // On past this hit, by a millimetre.
      Cesium.Cartesian3.add(hit, Cesium.Cartesian3.multiplyByScalar(ray.direction, 0.001, new Cesium.Cartesian3()), ray.origin);
    }
    return drawn;
  }
  function measureClick(position) {
    const m = state.measure;
    if (!m) return false;
    const p = surfacePoint(position);
    if (!p) return true;
    if (m.points.length === 2) {
      m.points = [];
      measureEntities.splice(0).forEach((e) => viewer.entities.remove(e));
    }
    m.points.push(p);
    measureEntities.push(viewer.entities.add({ position: p, point: { pixelSize: 8, color: Cesium.Color.CYAN, disableDepthTestDistance: Number.POSITIVE_INFINITY } }));
    if (m.points.length === 2) {
      const [a, b] = m.points;
      const la = toLocal(a), lb = toLocal(b);
      m.distanceM = Cesium.Cartesian3.distance(a, b);
      m.heightM = Math.abs(lb[2] - la[2]);
      const shown = m.mode === "height" ? m.heightM : m.distanceM;
      const text = `${m.mode === "height" ? "height" : "distance"} ${shown.toFixed(3)} m`;
      measureEntities.push(
        viewer.entities.add({ polyline: { positions: [a, b], width: 2, material: Cesium.Color.CYAN, depthFailMaterial: Cesium.Color.CYAN } }),
        viewer.entities.add({
          position: Cesium.Cartesian3.midpoint(a, b, new Cesium.Cartesian3()),
          label: { text, font: "13px sans-serif", showBackground: true, disableDepthTestDistance: Number.POSITIVE_INFINITY },
        }),
      );
      document.getElementById("bimMeasureOut").textContent = text;
      status.measure = { mode: m.mode, distanceM: m.distanceM, heightM: m.heightM, text };
    }
    return true;
  }

  // --- the state in the URL (hash) --------------------------------------------------------------
  let restoring = false;
  function saveUrl() {
    if (restoring) return;
    const h = new URLSearchParams();
    if (state.selectedId !== null) h.set("sel", state.selectedId);
    if (state.hideKeys.length) h.set("hide", state.hideKeys.join(","));
    if (state.isolateKey) h.set("iso", state.isolateKey + (state.isolateMode === "hide" ? "!" : ""));
    if (state.xray) h.set("xray", "1");
    if (state.colorBy) h.set("color", state.colorBy);
    const s = state.section;
    if (s && s.kind === "box") h.set("sec", "box:" + [...s.min, ...s.max].map((v) => v.toFixed(3)).join(","));
    if (s && s.kind === "plan") h.set("sec", "plan:" + s.z.toFixed(3));
    const c = viewer.camera;
    const p = c.positionWC;
    h.set("cam", [p.x, p.y, p.z].map((v) => v.toFixed(3)).concat([c.heading, c.pitch, c.roll].map((v) => v.toFixed(5))).join(","));
    history.replaceState(null, "", "#" + h.toString());
  }
  function restoreUrl(hash) {
    const h = new URLSearchParams((hash || location.hash).replace(/^#/, ""));
    restoring = true;
    try {
      const cam = h.get("cam");
      if (cam) {
        const v = cam.split(",").map(Number);
        if (v.length === 6 && v.every(Number.isFinite))
          viewer.camera.setView({ destination: new Cesium.Cartesian3(v[0], v[1], v[2]), orientation: { heading: v[3], pitch: v[4], roll: v[5] } });
      }
      state.hidden.fill(0);
      state.hideKeys = [];
      for (const k of (h.get("hide") || "").split(",").filter(Boolean)) {
        const show = k.startsWith("+");
        const key = show ? k.slice(1) : k;
        const r = keyRange(key);
        if (r) state.hidden.fill(show ? 0 : 1, r[0], r[1]);
        state.hideKeys.push(k);
      }
      const iso = h.get("iso");
      state.xray = h.get("xray") === "1";
      document.getElementById("bimXray").checked = state.xray;
      isolate(iso ? iso.replace(/!$/, "") : null, iso && iso.endsWith("!") ? "hide" : "xray");
      colorBy(h.get("color") || "");
      const sec = h.get("sec");
      if (sec && sec.startsWith("box:")) {
        const v = sec.slice(4).split(",").map(Number);
        if (v.length === 6 && v.every(Number.isFinite)) setSection({ kind: "box", min: v.slice(0, 3), max: v.slice(3) });
      } else if (sec && sec.startsWith("plan:")) setSection({ kind: "plan", z: Number(sec.slice(5)) });
      else setSection(null);
      selectId(h.get("sel"), { reveal: true });
      visibilityChanged();
    } finally {
      restoring = false;
    }
  }

  // --- the panel --------------------------------------------------------------------------------
  function buildPanel() {
    const panel = document.getElementById("bim");
    panel.innerHTML = `
      <div class="title"><span>Model</span><span id="bimCount"></span></div>
      <input id="bimSearch" type="search" role="searchbox" aria-label="Search elements by name, GlobalId or property value" placeholder="search name, GlobalId, property…" autocomplete="off" aria-controls="bimResults">
      <div id="bimSearchInfo" aria-live="polite"></div>
      <ul id="bimResults" role="listbox" aria-label="Search results" class="hidden"></ul>
      <div id="bimTree" role="tree" aria-label="Model tree: site, building, storey, class, element" tabindex="0"><div id="bimTreeInner"></div></div>
      <div class="tools">
        <button id="bimShowAll" title="Show every element">Show all</button>
        <label title="How elements outside an isolation are drawn">rest <select id="bimIsolateMode" aria-label="Elements outside the isolation"><option value="xray">x-ray</option><option value="hide">hidden</option></select></label>
        <label><input type="checkbox" id="bimXray"> X-ray</label>
        <label title="Edges need a tileset with edges"><input type="checkbox" id="bimEdges" disabled> Edges</label>
      </div>
      <div class="tools">
        <label>Colour by <select id="bimColorBy" aria-label="Colour by property"></select></label>
        <button id="bimColorReset">Reset</button>
      </div>
      <ul id="bimLegend" aria-label="Legend"></ul>
      <div class="tools">
        <button id="bimSection" title="A section box around the selection (or the isolation, or the model); drag its handles">Section box</button>
        <button id="bimSectionOff" disabled>No section</button>
      </div>
      <div class="tools">
        <button id="bimMeasureDist">Measure distance</button>
        <button id="bimMeasureHeight">Height</button>
        <button id="bimMeasureOff">Stop</button>
      </div>
      <div id="bimMeasureOut" aria-live="polite"></div>`;
    const search = document.getElementById("bimSearch");
    search.addEventListener("input", () => renderResults(api.search(search.value)));
    search.addEventListener("keydown", (e) => {
      if (e.key === "Enter") document.querySelector("#bimResults li")?.click();
    });
    const tree = document.getElementById("bimTree");
    tree.addEventListener("scroll", () => requestAnimationFrame(renderTree));
    tree.addEventListener("keydown", treeKey);
    document.getElementById("bimShowAll").onclick = showAll;
    document.getElementById("bimIsolateMode").onchange = (e) => isolate(state.isolateKey, e.target.value);
    document.getElementById("bimXray").onchange = (e) => {
      state.xray = e.target.checked;
      applyAll();
      saveUrl();
    };
    // Edges: on when the tileset carries them (the viewer chose the first state from it and the URL).
    const edgesBox = document.getElementById("bimEdges");
    const ts = window.bimtiles.tileset;
    const carried = ts && ts.asset && ts.asset.extras && ts.asset.extras.bimtiles && ts.asset.extras.bimtiles.edges;
    edgesBox.disabled = !carried || !Cesium.EdgeDisplayMode;
    edgesBox.checked = !!ts && !!Cesium.EdgeDisplayMode && ts.edgeDisplayMode === Cesium.EdgeDisplayMode.SURFACES_AND_EDGES;
    edgesBox.parentElement.title = carried ? "Edges of the elements (EXT_mesh_primitive_edge_visibility)" : "Edges need a tileset with edges";
    edgesBox.onchange = (e) => {
      e.target.checked = window.bimtiles.setEdges(e.target.checked, true);
    };
    document.getElementById("bimColorBy").onchange = (e) => colorBy(e.target.value);
    document.getElementById("bimColorReset").onclick = () => colorBy("");
    document.getElementById("bimSection").onclick = sectionAroundSelection;
    document.getElementById("bimSectionOff").onclick = () => setSection(null);
    document.getElementById("bimMeasureDist").onclick = () => startMeasure("distance");
    document.getElementById("bimMeasureHeight").onclick = () => startMeasure("height");
    document.getElementById("bimMeasureOff").onclick = () => startMeasure(null);
    fillColorSelect();
  }

  async function loadIndex() {
    const extras = (tileset.asset && tileset.asset.extras && tileset.asset.extras.bimtiles) || {};
    const name = extras.elementIndex;
    if (!name) {
      document.getElementById("bimCount").textContent = "no element index";
      return false;
    }
    const t0 = performance.now();
    const url = new URL(name, status.tilesetUrl).href;
    const response = await fetch(url);
    if (!response.ok) throw new Error(`cannot load ${url}: HTTP ${response.status}`);
    useIndex(await response.json());
    status.elementIndex = { url, elements: state.index.n, loadMs: performance.now() - t0 };
    return true;
  }
  // Shows the tree of a decoded index (the tileset's, or any other: the speed test's campus).
  function useIndex(json) {
    rowOf.clear();
    state.index = decodeIndex(json);
    state.hidden = new Uint8Array(state.index.n);
    state.hiddenPrefix = new Uint32Array(state.index.n + 1);
    Object.assign(state, { hideKeys: [], isolateKey: null, isolated: null, selectedId: null, focus: 0 });
    state.tree = buildTree(state.index);
    flatten();
    document.getElementById("bimCount").textContent = `${state.index.n.toLocaleString("en")} elements`;
    document.getElementById("bimTree").scrollTop = 0;
    renderTree();
  }

  let saveTimer = null;
  async function start() {
    buildPanel();
    tileset.tileLoad.addEventListener(onTileLoad);
    loadedContents().forEach(collectProperties);
    await loadIndex();
    if (location.hash.length > 1 && state.index) restoreUrl();
    viewer.camera.moveEnd.addEventListener(() => {
      clearTimeout(saveTimer);
      saveTimer = setTimeout(saveUrl, 200);
    });
    const h = viewer.screenSpaceEventHandler;
    h.setInputAction(onLeftDown, Cesium.ScreenSpaceEventType.LEFT_DOWN);
    h.setInputAction(onLeftUp, Cesium.ScreenSpaceEventType.LEFT_UP);
    h.setInputAction(onMouseMove, Cesium.ScreenSpaceEventType.MOUSE_MOVE);
    api.ready = true;
  }

  const api = (window.bimtilesBim = {
    ready: false,
    flyDurationS: 1.0,
    state,
    rowOf,
    search,
    renderResults,
    useIndex,
    selectId,
    setHidden,
    isolate,
    showAll,
    colorBy,
    setSection,
    sectionAroundSelection,
    planCut: (key) => planCut(nodeByKey(key)),
    startMeasure,
    measureClick,
    surfacePoint,
    restoreUrl,
    saveUrl,
    nodeByKey,
    rowBox,
    toWorld,
    toLocal,
    pickedFeature,
    /** Tree nodes as {key, label, what, count, elevationM}, depth first. */
    nodes() {
      const out = [];
      const walk = (n) =>
        n.children.forEach((c) => (out.push({ key: c.key, label: c.label, what: c.what, start: c.start, end: c.end, count: c.end - c.start, elevationM: c.elevationM }), walk(c)));
      if (state.tree) walk(state.tree);
      return out;
    },
    /** Clicks go to the measure tool while it is on; true when it took the click. */
    onClick: (position) => (state.measure ? measureClick(position) : false),
    expandAll() {
      const walk = (n) => n.children.forEach((c) => ((c.expanded = true), walk(c)));
      walk(state.tree);
      flatten();
      renderTree();
    },
  });
  const fly = new URLSearchParams(location.search).get("fly");
  if (fly !== null && Number.isFinite(+fly)) api.flyDurationS = +fly;
  api.started = start().catch((e) => {
    console.warn("BIM tools failed:", e);
    api.error = String(e && e.message ? e.message : e);
  });
})();
