// The GLB container (glTF 2.0 §4.4): its JSON and BIN chunks, read and written, for the tools
// here (decode_meshopt.mjs, check_ktx2.mjs, bench_browser.mjs).

const MAGIC = 0x46546c67; // "glTF"
const JSON_CHUNK = 0x4e4f534a;
const BIN_CHUNK = 0x004e4942;
const pad4 = (n) => (n + 3) & ~3;

/** The chunks of a GLB (Uint8Array or Buffer): {json, bin}; bin is empty when there is none. */
export function readGlb(bytes) {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (bytes.length < 20 || dv.getUint32(0, true) !== MAGIC) throw new Error("not a GLB");
  let json = null;
  let bin = new Uint8Array(0);
  for (let off = 12; off + 8 <= bytes.length; ) {
    const len = dv.getUint32(off, true);
    const type = dv.getUint32(off + 4, true);
    const data = bytes.subarray(off + 8, off + 8 + len);
    if (type === JSON_CHUNK) json = JSON.parse(new TextDecoder().decode(data));
    else if (type === BIN_CHUNK) bin = data;
    off += 8 + len;
  }
  if (!json) throw new Error("a GLB without a JSON chunk");
  return { json, bin };
}

/** A GLB of `json` (an object) and `bin` (bytes; no BIN chunk when empty). */
export function writeGlb(json, bin) {
  const jsonBytes = new TextEncoder().encode(JSON.stringify(json));
  const jl = pad4(jsonBytes.length);
  const bl = bin.length ? 8 + pad4(bin.length) : 0;
  const out = new Uint8Array(20 + jl + bl);
  const dv = new DataView(out.buffer);
  dv.setUint32(0, MAGIC, true);
  dv.setUint32(4, 2, true);
  dv.setUint32(8, out.length, true);
  dv.setUint32(12, jl, true);
  dv.setUint32(16, JSON_CHUNK, true);
  out.set(jsonBytes, 20);
  out.fill(0x20, 20 + jsonBytes.length, 20 + jl);
  if (bin.length) {
    dv.setUint32(20 + jl, pad4(bin.length), true);
    dv.setUint32(24 + jl, BIN_CHUNK, true);
    out.set(bin, 28 + jl);
  }
  return out;
}
