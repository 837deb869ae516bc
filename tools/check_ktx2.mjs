#!/usr/bin/env node
// Independent check of the KTX2 textures in a bimtiles tileset: npm `ktx-parse` reads each KTX2
// container, and the Basis Universal transcoder CesiumJS ships (ThirdParty/basis_transcoder.wasm,
// the one the browser uses) decodes every mip level to RGBA.
//
//   node tools/check_ktx2.mjs <tileset dir>
//
// Finds the .ktx2 files under the folder and the images with mimeType image/ktx2 embedded in its
// .glb files. Prints one JSON object: {"files": [{name, width, height, levels, codec, srgb,
// meanRgb}], "errors": [...]}, where meanRgb is level 0's mean colour (0-255) as decoded.
// Exit code 1 when a file fails to parse or decode, or when none was found.

import { createRequire } from "node:module";
import { readFileSync, readdirSync, statSync } from "node:fs";
import path from "node:path";
import { readGlb } from "./glb.mjs";
import { fileURLToPath } from "node:url";
import { read as readKtx2, KHR_DF_MODEL_ETC1S, KHR_DF_MODEL_UASTC, KHR_DF_TRANSFER_SRGB } from "ktx-parse";

const here = path.dirname(fileURLToPath(import.meta.url));
const cesium = path.join(here, "node_modules/cesium");
const require = createRequire(import.meta.url);
const BASIS = require(path.join(cesium, "Source/ThirdParty/Workers/basis_transcoder.js"));
const RGBA32 = 13; // basist::transcoder_texture_format::cTFRGBA32

function walk(dir, out = []) {
  for (const name of readdirSync(dir).sort()) {
    const p = path.join(dir, name);
    if (statSync(p).isDirectory()) walk(p, out);
    else out.push(p);
  }
  return out;
}

/** The KTX2 images embedded in a GLB: [{name, bytes}]. */
function embedded(file) {
  const { json, bin } = readGlb(readFileSync(file));
  const out = [];
  (json && json.images ? json.images : []).forEach((im, i) => {
    if (im.mimeType !== "image/ktx2" || im.bufferView === undefined) return;
    const v = json.bufferViews[im.bufferView];
    out.push({ name: `${file}#image${i}`, bytes: bin.subarray(v.byteOffset || 0, (v.byteOffset || 0) + v.byteLength) });
  });
  return out;
}

function check(basis, name, bytes) {
  const container = readKtx2(new Uint8Array(bytes));
  const dfd = container.dataFormatDescriptor[0];
  const codec = { [KHR_DF_MODEL_ETC1S]: "etc1s", [KHR_DF_MODEL_UASTC]: "uastc" }[dfd.colorModel];
  if (container.vkFormat !== 0 || !codec) throw new Error(`not Basis Universal (vkFormat ${container.vkFormat}, colour model ${dfd.colorModel})`);
  const { pixelWidth: w, pixelHeight: h } = container;
  if (w % 4 || h % 4) throw new Error(`${w}x${h}: KHR_texture_basisu needs multiples of 4`);
  const file = new basis.KTX2File(new Uint8Array(bytes));
  try {
    if (!file.isValid() || !file.startTranscoding()) throw new Error("the Basis transcoder refuses it");
    if (file.getWidth() !== w || file.getHeight() !== h || file.getLevels() !== container.levels.length)
      throw new Error("the transcoder and ktx-parse disagree on the size or the levels");
    let meanRgb = null;
    for (let level = 0; level < file.getLevels(); level++) {
      const size = file.getImageTranscodedSizeInBytes(level, 0, 0, RGBA32);
      const px = new Uint8Array(size);
      if (!file.transcodeImage(px, level, 0, 0, RGBA32, 0, -1, -1)) throw new Error(`level ${level} does not decode`);
      const [lw, lh] = [Math.max(1, w >> level), Math.max(1, h >> level)];
      if (size !== lw * lh * 4) throw new Error(`level ${level}: ${size} bytes for ${lw}x${lh}`);
      if (level === 0) {
        const sum = [0, 0, 0];
        for (let i = 0; i < px.length; i += 4) for (let c = 0; c < 3; c++) sum[c] += px[i + c];
        meanRgb = sum.map((s) => +(s / (lw * lh)).toFixed(2));
      }
    }
    return { name, width: w, height: h, levels: container.levels.length, codec, srgb: dfd.transferFunction === KHR_DF_TRANSFER_SRGB, meanRgb };
  } finally {
    file.close();
    file.delete();
  }
}

async function main() {
  const dir = process.argv[2];
  if (!dir) {
    console.error("usage: node tools/check_ktx2.mjs <tileset dir>");
    process.exit(2);
  }
  const basis = await BASIS({ wasmBinary: readFileSync(path.join(cesium, "Build/Cesium/ThirdParty/basis_transcoder.wasm")) });
  basis.initializeBasis();
  const images = [];
  for (const f of walk(dir)) {
    if (/\.ktx2$/i.test(f)) images.push({ name: f, bytes: readFileSync(f) });
    else if (/\.glb$/i.test(f)) images.push(...embedded(f));
  }
  const files = [];
  const errors = [];
  for (const im of images) {
    try {
      files.push(check(basis, path.relative(dir, im.name), im.bytes));
    } catch (e) {
      errors.push(`${path.relative(dir, im.name)}: ${e.message}`);
    }
  }
  if (!images.length) errors.push(`no KTX2 image under ${dir}`);
  console.log(JSON.stringify({ files, errors }));
  process.exit(errors.length ? 1 : 0);
}

main();
