#!/usr/bin/env node
// The client compatibility matrix: the same tilesets in 3DTilesRendererJS (three.js)
// and deck.gl's Tile3DLayer in one headless Chromium (one page per set), and in loaders.gl in
// Node. Prints one JSON line per (client, set) and exits 1 when any check of
// expectations.mjs fails (a documented limitation that no longer holds included).
//
//   node tools/clients/run.mjs [--json FILE] [--clients three,deckgl,loadersgl] [--timeout S] NAME=DIR ...
//
// NAME is the set's name (`three-…`, `deckgl-…`, `portable-…` for a profile's variant, see
// expectations.mjs), DIR the folder of its tileset.json. Everything is served from one loopback
// server (tilesets, pages, esbuild bundles, decoders from tools/node_modules).
import { writeFileSync } from "node:fs";
import { launchBrowser, NODE_MODULES, pageHtml, startStaticServer } from "./common.mjs";
import { tilesetFacts } from "./facts.mjs";
import { checks, clientsFor, profileOf } from "./expectations.mjs";
import * as three from "./three.mjs";
import * as deckgl from "./deckgl.mjs";
import * as loadersgl from "./loadersgl.mjs";

const CLIENTS = { three, deckgl, loadersgl };
const args = process.argv.slice(2);
const opt = { json: null, clients: Object.keys(CLIENTS), timeout: 90, shots: null };
const sets = [];
for (let i = 0; i < args.length; i++) {
  const a = args[i];
  if (a === "--json") opt.json = args[++i];
  else if (a === "--clients") opt.clients = args[++i].split(",");
  else if (a === "--timeout") opt.timeout = Number(args[++i]);
  else if (a === "--shots") opt.shots = args[++i];
  else if (/^[^=]+=/.test(a)) sets.push({ name: a.split("=")[0], dir: a.slice(a.indexOf("=") + 1) });
  else throw new Error(`unexpected argument ${a}`);
}
if (!sets.length) throw new Error("no NAME=DIR set given");

const t0 = Date.now();
const mounts = { "/lib/": NODE_MODULES };
sets.forEach((s, i) => {
  s.mount = `/sets/${i}/`;
  mounts[s.mount] = s.dir;
  s.facts = tilesetFacts(s.dir);
});
const pages = {};
const browserClients = opt.clients.filter((c) => CLIENTS[c].page);
for (const c of browserClients) {
  pages[`/${c}.html`] = pageHtml(CLIENTS[c].page.path);
  pages[CLIENTS[c].page.path] = await CLIENTS[c].page.build();
}
const server = await startStaticServer(mounts, pages);
sets.forEach((s) => (s.url = server.url + s.mount.replace(/\/$/, "")));
const browser = browserClients.length ? await launchBrowser(800, 600) : null;

const results = [];
let failed = 0;
try {
  for (const s of sets)
    for (const c of clientsFor(s.name).filter((c) => opt.clients.includes(c))) {
      let r;
      try {
        r = await CLIENTS[c].run(browser?.context, server, s, { timeoutMs: opt.timeout * 1000 });
      } catch (e) {
        r = { crashed: String(e.stack || e).slice(0, 600) };
      }
      const list = r.crashed ? [{ name: "the check ran", ok: false, detail: r.crashed }] : checks(c, s.name, s.facts, r);
      if (opt.shots && r.png) writeFileSync(`${opt.shots}/${c}-${s.name}.png`, r.png);
      const bad = list.filter((x) => !x.ok);
      failed += bad.length;
      // One status per column of the matrix: the worst of its checks (by the check name's first word).
      const status = (x) => (x.ok ? (x.limitation ? "limited" : "ok") : x.limitation ? "LIMITATION GONE" : "FAIL");
      const rank = ["ok", "limited", "LIMITATION GONE", "FAIL"];
      const column = (c) => {
        const l = list.filter((x) => x.name.split(/[: ]/)[0] === c).map(status);
        return l.length ? l.reduce((a, b) => (rank.indexOf(b) > rank.indexOf(a) ? b : a)) : "n/a";
      };
      const line = {
        client: c,
        set: s.name,
        profile: profileOf(s.name),
        ok: !bad.length,
        loads: column("loads"),
        drawn: column("drawn"),
        metadata: column("metadata"),
        instances: column("instances"),
        colours: column("colours"),
        ms: r.ms,
        loaded: r.loaded,
        errors: (r.errors || []).length,
        drawnShare: r.pixels ? +r.pixels.drawn.toFixed(3) : null,
        colouredShare: r.pixels ? +r.pixels.coloured.toFixed(3) : null,
        checks: Object.fromEntries(list.map((x) => [x.name, `${x.ok ? (x.limitation ? "limitation holds" : "ok") : x.limitation ? "LIMITATION GONE (update tools/clients/expectations.mjs)" : "FAIL"}: ${x.detail}`])),
        limitations: list.filter((x) => x.limitation).map((x) => x.limitation),
      };
      results.push(line);
      console.log(JSON.stringify(line));
    }
} finally {
  await browser?.close();
  await server.close();
}
const summary = { runs: results.length, failedChecks: failed, seconds: Math.round((Date.now() - t0) / 1000) };
console.log(JSON.stringify({ summary }));
if (opt.json) writeFileSync(opt.json, JSON.stringify({ summary, results }, null, 1));
process.exit(failed ? 1 : 0);
