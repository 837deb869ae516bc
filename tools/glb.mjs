// The GLB container (glTF 2.0 §4.4): its JSON and BIN chunks, read and written, for the tools
// here (decode_meshopt.mjs, check_ktx2.mjs, bench_browser.mjs); and GLBs inlined in a tileset.json
// (data URIs, the walk over a tile tree's content uris) for decode_meshopt.mjs and validate_gltf.mjs.

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

/** Whether `s` is strict base64 (RFC 4648 alphabet, padded): Buffer.from alone skips characters it does not know. */
export const isBase64 = (s) => s.length % 4 === 0 && /^[A-Za-z0-9+/]*={0,2}$/.test(s)
  && Buffer.from(s, "base64").toString("base64") === s;

/**
 * The parts of an RFC 2397 data URI: {mediaType, base64, payload}, or null when `uri` does not start
 * with `data:`. mediaType is as written (compare it lowercased; "" when none); base64 is true when the
 * URI has a comma and its last parameter is `base64`; payload is the text after the first comma
 * (not decoded), null when there is no comma.
 */
export function parseDataUri(uri) {
  if (!uri.startsWith("data:")) return null;
  const comma = uri.indexOf(",");
  const params = uri.slice(5, comma < 0 ? uri.length : comma).split(";");
  return {
    mediaType: params[0],
    base64: comma >= 0 && params.length >= 2 && params[params.length - 1].toLowerCase() === "base64",
    payload: comma < 0 ? null : uri.slice(comma + 1),
  };
}

/**
 * Every content URI of a 3D Tiles tileset's tile tree (`content.uri`, 1.0's `content.url`, and
 * `contents[].uri`; string ones only), depth first: [{pointer, holder, key}] with holder[key] the uri
 * (read it, or assign it to rewrite the uri in place) and pointer its JSON pointer, e.g.
 * `/root/children/0/content/uri`.
 */
export function tileContentRefs(tileset) {
  const out = [];
  const walk = (tile, ptr) => {
    if (!tile || typeof tile !== "object") return;
    const c = tile.content;
    if (c && typeof c === "object") {
      const key = "uri" in c ? "uri" : "url";
      if (typeof c[key] === "string") out.push({ pointer: `${ptr}/content/${key}`, holder: c, key });
    }
    (Array.isArray(tile.contents) ? tile.contents : []).forEach((x, i) => {
      if (x && typeof x === "object" && typeof x.uri === "string") {
        out.push({ pointer: `${ptr}/contents/${i}/uri`, holder: x, key: "uri" });
      }
    });
    (Array.isArray(tile.children) ? tile.children : []).forEach((ch, i) => walk(ch, `${ptr}/children/${i}`));
  };
  walk(tileset && tileset.root, "/root");
  return out;
}
