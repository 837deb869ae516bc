#!/usr/bin/env node
// Independent decoder for EXT_meshopt_compression tiles: copies a tileset folder and rewrites each
// GLB with its meshopt bufferViews decoded into plain ones (the extension and its fallback buffer
// gone), so readers without the extension (our test reader, gltf-validator's data checks) see the
// data a client draws. It uses meshoptimizer's *reference* JavaScript decoder (npm `meshoptimizer`,
// meshopt_decoder_reference.js: written from the extension's bitstream description, not the C++
// codec bimtiles encodes with).
//
// GLBs inlined in a tileset.json as data URIs (3D Tiles 1.1 allows them; bimtiles inlines the root
// tile's GLB by default): every `content.uri` / `contents[].uri` of the tile tree of each file named
// tileset.json that is a `data:model/gltf-binary;base64,` URI is decoded the same way and written back
// as such a data URI into the copied tileset.json (pretty-printed with two spaces when the original had
// line breaks). A data URI of another media type is copied as it is; one that is not base64 or does not
// decode is malformed. A tileset.json without GLB data URIs is copied byte for byte.
//
// Usage: node tools/decode_meshopt.mjs IN_DIR OUT_DIR
// Prints one JSON line: {"files": N, "decodedViews": N}; `files` counts the GLBs rewritten, files and
// inlined ones alike. Exit 1 on any malformed file.

import { promises as fs } from 'node:fs';
import path from 'node:path';
import { isBase64, parseDataUri, readGlb, tileContentRefs, writeGlb } from './glb.mjs';

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

const GLB_DATA_URI = 'data:model/gltf-binary;base64,';

/** The tileset.json text with its inlined GLBs decoded; returns [text, GLBs decoded, views decoded]. */
function decodeTileset(text, where) {
  let tileset;
  try {
    tileset = JSON.parse(text);
  } catch (e) {
    throw new Error(`${where}: ${e.message}`);
  }
  let files = 0;
  let views = 0;
  for (const { pointer, holder, key } of tileContentRefs(tileset)) {
    const d = parseDataUri(holder[key]);
    if (!d || d.mediaType.toLowerCase() !== 'model/gltf-binary') continue;
    if (!d.base64) throw new Error(`${where}#${pointer}: GLB data URI is not base64`);
    if (!isBase64(d.payload)) throw new Error(`${where}#${pointer}: data URI does not decode as base64`);
    let bytes;
    let n;
    try {
      [bytes, n] = decodeGlb(new Uint8Array(Buffer.from(d.payload, 'base64')));
    } catch (e) {
      throw new Error(`${where}#${pointer}: ${e.message}`);
    }
    holder[key] = GLB_DATA_URI + Buffer.from(bytes).toString('base64');
    files++;
    views += n;
  }
  if (files === 0) return [text, 0, 0];
  return [JSON.stringify(tileset, null, text.includes('\n') ? 2 : 0), files, views];
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
    } else if (entry.name === 'tileset.json') {
      const [text, files, views] = decodeTileset(await fs.readFile(s, 'utf8'), s);
      if (files) await fs.writeFile(d, text);
      else await fs.copyFile(s, d);
      stats.files += files;
      stats.decodedViews += views;
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
