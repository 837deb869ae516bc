#!/usr/bin/env node
// Independent glTF check for bimtiles output, using the Khronos glTF-Validator (npm `gltf-validator`).
//
// Usage: node tools/validate_gltf.mjs [--max-messages N] [--concurrency N] [--root DIR] <file-or-dir>...
//
// Validates every .glb / .gltf given (directories are searched recursively, in sorted order) in one Node
// process and prints ONE JSON object to stdout:
//   {"validator": "<version>", "files": N, "errors": N, "warnings": N, "infos": N, "hints": N,
//    "results": [{"file", "errors", "warnings", "infos", "hints", "messages": [...]}]}
// `messages` holds the first few errors/warnings (code, severity, message, pointer or offset).
// Infos (e.g. UNSUPPORTED_EXTENSION for EXT_mesh_features, EXT_structural_metadata, EXT_mesh_gpu_instancing,
// EXT_instance_features, KHR_draco_mesh_compression) and hints never make the run fail.
// Exit code: 0 = no errors, 1 = at least one error (or a file that could not be read/parsed), 2 = usage.
//
// Contents inlined in a tileset (3D Tiles 1.1 content URIs may be RFC 2397 data URIs; bimtiles inlines the
// root tile's GLB by default): when an input is a folder that directly holds a tileset.json, every
// data-URI content of its tile tree (`content.uri` and `contents[].uri` of every tile) is decoded from
// base64 and validated as one more file, labelled `<folder>/tileset.json#<JSON pointer to the uri>`
// (e.g. `out/tileset.json#/root/content/uri`); it counts in files/errors/warnings like a file. Only such
// inputs: a tileset.json found deeper while searching a folder, or beside an input (DIR/tiles given
// for DIR), is not read. Media type model/gltf-binary is validated as GLB, model/gltf+json as glTF; a
// data URI that is not base64, does not decode, or has another media type is an error result for its
// label, and so is a tileset.json that cannot be read or parsed. An inlined glTF's own relative uris
// resolve against the tileset folder.
//
// External resources (buffers/images by uri) are read relative to the glTF's folder; a uri that escapes that
// folder (.., absolute paths, other schemes) is refused and reported as an error by the validator. With
// --root DIR, relative uris may reach anything inside DIR instead (a tileset folder: tiles in tiles/ share
// images in textures/ as ../textures/<name>).

import { promises as fs } from 'node:fs';
import path from 'node:path';
import { createRequire } from 'node:module';
import { isBase64, parseDataUri, tileContentRefs } from './glb.mjs';

const require = createRequire(import.meta.url);
const validator = require('gltf-validator');

const SEVERITY = ['error', 'warning', 'info', 'hint'];

function usage(msg) {
  if (msg) process.stderr.write(`validate_gltf: ${msg}\n`);
  process.stderr.write('usage: node tools/validate_gltf.mjs [--max-messages N] [--concurrency N] [--root DIR] <file-or-dir>...\n');
  process.exit(2);
}

function parseArgs(argv) {
  const opts = { maxMessages: 5, concurrency: 4, root: null, inputs: [] };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    if (a === '--max-messages' || a === '--concurrency') {
      const v = Number.parseInt(argv[++i], 10);
      if (!Number.isFinite(v) || v < (a === '--concurrency' ? 1 : 0)) usage(`bad value for ${a}`);
      if (a === '--max-messages') opts.maxMessages = v; else opts.concurrency = v;
    } else if (a === '--root') {
      if (argv[i + 1] === undefined) usage('--root needs a folder');
      opts.root = path.resolve(argv[++i]);
    } else if (a === '-h' || a === '--help') {
      usage();
    } else if (a.startsWith('--')) {
      usage(`unknown option ${a}`);
    } else {
      opts.inputs.push(a);
    }
  }
  if (opts.inputs.length === 0) usage('no input given');
  return opts;
}

const isGltf = (p) => /\.(glb|gltf)$/i.test(p);

async function collect(input, out, top = true) {
  let st;
  try {
    st = await fs.stat(input);
  } catch (e) {
    out.push({ path: input, missing: String(e.message || e) });
    return;
  }
  if (st.isDirectory()) {
    const entries = (await fs.readdir(input, { withFileTypes: true }))
      .map((d) => d.name)
      .sort();
    for (const name of entries) {
      const p = path.join(input, name);
      let s;
      try { s = await fs.stat(p); } catch { continue; }
      if (s.isDirectory()) await collect(p, out, false);
      else if (isGltf(name)) out.push({ path: p });
    }
    if (top && entries.includes('tileset.json')) await collectDataUris(path.join(input, 'tileset.json'), out);
  } else {
    out.push({ path: input });
  }
}

const FORMATS = { 'model/gltf-binary': 'glb', 'model/gltf+json': 'gltf' };

// One entry per data-URI content of `tilesetPath` (decoded bytes, or an error to report for its label).
async function collectDataUris(tilesetPath, out) {
  let tileset;
  try {
    tileset = JSON.parse(await fs.readFile(tilesetPath, 'utf8'));
  } catch (e) {
    out.push({ path: tilesetPath, bad: { code: 'TILESET_UNREADABLE', message: String(e.message || e) } });
    return;
  }
  for (const { pointer, holder, key } of tileContentRefs(tileset)) {
    const uri = holder[key];
    const d = parseDataUri(uri);
    if (!d) continue;
    const label = `${tilesetPath}#${pointer}`;
    const base = path.dirname(tilesetPath);
    const format = FORMATS[d.mediaType.toLowerCase()];
    let bad = null;
    if (!d.base64) {
      bad = { code: 'DATA_URI_NOT_BASE64', message: `data URI is not base64: ${uri.slice(0, 60)}` };
    } else if (!isBase64(d.payload)) {
      bad = { code: 'DATA_URI_BAD_BASE64', message: 'data URI payload does not decode as base64' };
    } else if (!format) {
      bad = { code: 'DATA_URI_MEDIA_TYPE', message: `data URI media type ${d.mediaType || '(none)'} is not glTF` };
    }
    if (bad) out.push({ path: label, bad });
    else {
      out.push({ path: label, uri: `${path.basename(tilesetPath)}#${pointer}`, format, base,
        bytes: new Uint8Array(Buffer.from(d.payload, 'base64')) });
    }
  }
}

// Reads `uri` relative to the folder of the glTF; refuses anything that escapes `root` (default: that folder).
function resourceLoader(base, root) {
  base = path.resolve(base);
  const limit = root ?? base;
  return async (uri) => {
    let rel;
    try {
      rel = decodeURIComponent(uri);
    } catch {
      throw new Error(`bad uri ${uri}`);
    }
    if (/^[a-zA-Z][a-zA-Z0-9+.-]*:/.test(rel) || path.isAbsolute(rel)) {
      throw new Error(`refused external resource ${uri}: not a relative path`);
    }
    const full = path.resolve(base, rel);
    const back = path.relative(limit, full);
    if (back === '' || back.startsWith('..') || path.isAbsolute(back)) {
      throw new Error(`refused external resource ${uri}: escapes ${limit}`);
    }
    return new Uint8Array(await fs.readFile(full));
  };
}

async function validateOne(file, maxMessages, root) {
  if (file.missing) {
    return { file: file.path, errors: 1, warnings: 0, infos: 0, hints: 0,
      messages: [{ code: 'FILE_NOT_FOUND', severity: 'error', message: file.missing }] };
  }
  if (file.bad) {
    return { file: file.path, errors: 1, warnings: 0, infos: 0, hints: 0,
      messages: [{ code: file.bad.code, severity: 'error', message: file.bad.message }] };
  }
  let bytes = file.bytes;
  if (!bytes) {
    try {
      bytes = new Uint8Array(await fs.readFile(file.path));
    } catch (e) {
      return { file: file.path, errors: 1, warnings: 0, infos: 0, hints: 0,
        messages: [{ code: 'IO_ERROR', severity: 'error', message: String(e.message || e) }] };
    }
  }
  let report;
  try {
    report = await validator.validateBytes(bytes, {
      uri: file.uri ?? path.basename(file.path),
      format: file.format ?? (/\.glb$/i.test(file.path) ? 'glb' : 'gltf'),
      maxIssues: 0,
      writeTimestamp: false,
      externalResourceFunction: resourceLoader(file.base ?? path.dirname(file.path), root),
    });
  } catch (e) {
    return { file: file.path, errors: 1, warnings: 0, infos: 0, hints: 0,
      messages: [{ code: 'VALIDATOR_REJECTED', severity: 'error', message: String(e && e.message ? e.message : e) }] };
  }
  const iss = report.issues || {};
  const messages = (iss.messages || [])
    .filter((m) => m.severity <= 1)
    .slice(0, maxMessages)
    .map((m) => {
      const o = { code: m.code, severity: SEVERITY[m.severity] ?? String(m.severity), message: m.message };
      if (m.pointer !== undefined) o.pointer = m.pointer;
      if (m.offset !== undefined) o.offset = m.offset;
      return o;
    });
  const r = {
    file: file.path,
    errors: iss.numErrors || 0,
    warnings: iss.numWarnings || 0,
    infos: iss.numInfos || 0,
    hints: iss.numHints || 0,
    messages,
  };
  if (iss.truncated) r.truncated = true;
  return r;
}

async function main() {
  const opts = parseArgs(process.argv.slice(2));
  const files = [];
  for (const input of opts.inputs) await collect(input, files);

  const results = new Array(files.length);
  let next = 0;
  async function worker() {
    while (next < files.length) {
      const i = next++;
      results[i] = await validateOne(files[i], opts.maxMessages, opts.root);
    }
  }
  await Promise.all(Array.from({ length: Math.min(opts.concurrency, Math.max(files.length, 1)) }, worker));

  const sum = (k) => results.reduce((a, r) => a + r[k], 0);
  const out = {
    validator: validator.version(),
    files: results.length,
    errors: sum('errors'),
    warnings: sum('warnings'),
    infos: sum('infos'),
    hints: sum('hints'),
    results,
  };
  process.stdout.write(JSON.stringify(out, null, 1) + '\n');
  process.exitCode = out.errors > 0 ? 1 : 0;
}

main().catch((e) => {
  process.stderr.write(`validate_gltf: ${e && e.stack ? e.stack : e}\n`);
  process.exit(1);
});
