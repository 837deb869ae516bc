#!/usr/bin/env node
// Independent decoder for EXT_meshopt_compression tiles: copies a tileset folder and rewrites each
// GLB with its meshopt bufferViews decoded into plain ones (the extension and its fallback buffer
// gone), so readers without the extension (our test reader, gltf-validator's data checks) see the
// data a client draws. It uses meshoptimizer's *reference* JavaScript decoder (npm `meshoptimizer`,
// meshopt_decoder_reference.js: written from the extension's bitstream description, not the C++
// codec bimtiles encodes with).
//
// Usage: node tools/decode_meshopt.mjs IN_DIR OUT_DIR
// Prints one JSON line: {"files": N, "decodedViews": N}. Exit 1 on any malformed file.

import { promises as fs } from 'node:fs';
import path from 'node:path';
import { readGlb, writeGlb } from './glb.mjs';

// The package does not export the reference decoder: loaded by its path (tools/package.json pins
// meshoptimizer).
const { MeshoptDecoder } = await import(
  new URL('./node_modules/meshoptimizer/meshopt_decoder_reference.js', import.meta.url).href
);

const EXT = 'EXT_meshopt_compression';
const pad4 = (n) => (n + 3) & ~3;

/** The GLB with every meshopt view decoded; returns [bytes, decoded view count]. */
function decodeGlb(bytes) {
  const { json, bin } = readGlb(bytes);
  const views = json.bufferViews || [];
  const parts = [bin];
  let length = bin.length;
  let decoded = 0;
  for (const v of views) {
    const e = v.extensions && v.extensions[EXT];
    if (!e) continue;
    if ((e.buffer ?? 0) !== 0) throw new Error('meshopt source outside the BIN chunk');
    const source = bin.subarray(e.byteOffset ?? 0, (e.byteOffset ?? 0) + e.byteLength);
    const target = new Uint8Array(e.count * e.byteStride);
    MeshoptDecoder.decodeGltfBuffer(target, e.count, e.byteStride, source, e.mode, e.filter);
    const at = pad4(length);
    parts.push(new Uint8Array(at - length), target);
    length = at + target.length;
    v.buffer = 0;
    v.byteOffset = at;
    v.byteLength = target.length;
    delete v.extensions[EXT];
    if (Object.keys(v.extensions).length === 0) delete v.extensions;
    decoded++;
  }
  const out = new Uint8Array(length);
  let at = 0;
  for (const p of parts) {
    out.set(p, at);
    at += p.length;
  }
  // Only buffer 0 (the BIN chunk) stays: every view that named the fallback is decoded.
  if (views.some((v) => v.buffer !== 0)) throw new Error('a view names a buffer other than 0');
  json.buffers = [{ byteLength: out.length }];
  for (const key of ['extensionsUsed', 'extensionsRequired']) {
    if (!json[key]) continue;
    json[key] = json[key].filter((x) => x !== EXT);
    if (json[key].length === 0) delete json[key];
  }
  return [writeGlb(json, out), decoded];
}

async function copyTree(src, dst, stats) {
  await fs.mkdir(dst, { recursive: true });
  for (const entry of await fs.readdir(src, { withFileTypes: true })) {
    const s = path.join(src, entry.name);
    const d = path.join(dst, entry.name);
    if (entry.isDirectory()) await copyTree(s, d, stats);
    else if (entry.name.endsWith('.glb')) {
      const [bytes, n] = decodeGlb(new Uint8Array(await fs.readFile(s)));
      await fs.writeFile(d, bytes);
      stats.files++;
      stats.decodedViews += n;
    } else await fs.copyFile(s, d);
  }
}

const [inDir, outDir] = process.argv.slice(2);
if (!inDir || !outDir) {
  process.stderr.write('usage: node tools/decode_meshopt.mjs IN_DIR OUT_DIR\n');
  process.exit(2);
}
await MeshoptDecoder.ready;
const stats = { files: 0, decodedViews: 0 };
try {
  await copyTree(inDir, outDir, stats);
} catch (e) {
  process.stderr.write(`decode_meshopt: ${e.message}\n`);
  process.exit(1);
}
process.stdout.write(JSON.stringify(stats) + '\n');
