// What a tileset holds, read from its files (not from any client): the ground truth each client's
// result is compared with. One walk over tileset.json (external tileset.json contents followed)
// and every GLB it references (files or data URIs).

import { readFileSync } from "node:fs";
import { dirname, join } from "node:path";
import { parseDataUri, readGlb, tileContentRefs } from "../glb.mjs";

const GREY_TOL = 0.04; // |r-g|, |g-b| below this: a grey (or white/black) colour

/** Whether an RGB(A) colour in 0..1 is visibly coloured (not a shade of grey). */
export const isColoured = (c) => Math.max(Math.abs(c[0] - c[1]), Math.abs(c[1] - c[2]), Math.abs(c[0] - c[2])) > GREY_TOL;

function glbFacts(bytes) {
  const { json } = readGlb(bytes);
  const used = json.extensionsUsed || [];
  const meta = json.extensions?.EXT_structural_metadata;
  const f = {
    extensions: used,
    schemaUri: meta?.schemaUri ?? null,
    schemaInline: !!meta?.schema,
    propertyTables: (meta?.propertyTables || []).map((t) => ({ class: t.class, count: t.count, properties: Object.keys(t.properties || {}) })),
    // Nodes drawn: a node with a mesh is one copy, or N copies with EXT_mesh_gpu_instancing.
    meshNodes: 0,
    instancedNodes: 0,
    instances: 0, // copies drawn by instanced nodes
    copies: 0, // every copy of every mesh node (plain nodes count 1)
    primitiveNodes: 0, // draws without instancing: one per primitive of each mesh node
    primitiveCopies: 0, // draws with every instanced copy: primitives x copies
    vertexColours: false, // a primitive with COLOR_0
    colouredMaterials: false, // a material whose base colour factor is not grey
    textures: (json.textures || []).length,
    featureIdAttributes: false, // EXT_mesh_features with an attribute
    draco: used.includes("KHR_draco_mesh_compression"),
    meshopt: used.includes("EXT_meshopt_compression"),
    ktx2: used.includes("KHR_texture_basisu"),
  };
  for (const n of json.nodes || []) {
    if (n.mesh === undefined) continue;
    f.meshNodes++;
    const inst = n.extensions?.EXT_mesh_gpu_instancing;
    const prims = json.meshes[n.mesh].primitives.length;
    f.primitiveNodes += prims;
    if (inst) {
      f.primitiveCopies += prims * json.accessors[Object.values(inst.attributes)[0]].count;
      const acc = json.accessors[Object.values(inst.attributes)[0]];
      f.instancedNodes++;
      f.instances += acc.count;
      f.copies += acc.count;
    } else {
      f.copies++;
      f.primitiveCopies += prims;
    }
  }
  for (const m of json.meshes || [])
    for (const p of m.primitives || []) {
      if (p.attributes?.COLOR_0 !== undefined) f.vertexColours = true;
      const fids = p.extensions?.EXT_mesh_features?.featureIds || [];
      if (fids.some((x) => x.attribute !== undefined)) f.featureIdAttributes = true;
    }
  for (const m of json.materials || []) {
    const c = m.pbrMetallicRoughness?.baseColorFactor;
    if (c && isColoured(c)) f.colouredMaterials = true;
  }
  return f;
}

/** Facts of the tileset in `dir` (tileset.json there). */
export function tilesetFacts(dir) {
  const out = {
    dir,
    contents: 0,
    glbs: [],
    inlinedRoot: false,
    dataUris: 0,
    unreadable: [], // contents that could not be read: the set fails every client
  };
  const walk = (file) => {
    const ts = JSON.parse(readFileSync(file, "utf8"));
    for (const ref of tileContentRefs(ts)) {
      const uri = ref.holder[ref.key];
      const d = parseDataUri(uri);
      const path = d ? null : join(dirname(file), decodeURI(uri.split("?")[0]));
      if (path && path.endsWith(".json")) {
        walk(path); // an external tileset: its own contents are counted
        continue;
      }
      out.contents++;
      if (d) {
        out.dataUris++;
        if (ref.pointer === "/root/content/uri") out.inlinedRoot = true;
      }
      try {
        const bytes = d ? Buffer.from(decodeURIComponent(d.payload), d.base64 ? "base64" : "utf8") : readFileSync(path);
        const g = glbFacts(new Uint8Array(bytes.buffer, bytes.byteOffset, bytes.byteLength));
        g.uri = d ? "data:" : uri;
        out.glbs.push(g);
      } catch (e) {
        out.unreadable.push(`${uri.slice(0, 60)}: ${e.message}`);
      }
    }
  };
  walk(join(dir, "tileset.json"));
  out.byUri = Object.fromEntries(out.glbs.map((g) => [g.uri, g]));
  const sum = (k) => out.glbs.reduce((a, g) => a + g[k], 0);
  const any = (k) => out.glbs.some((g) => g[k]);
  Object.assign(out, {
    meshNodes: sum("meshNodes"),
    instancedNodes: sum("instancedNodes"),
    instances: sum("instances"),
    copies: sum("copies"),
    features: out.glbs.reduce((a, g) => a + g.propertyTables.reduce((b, t) => b + t.count, 0), 0),
    externalSchema: out.glbs.some((g) => g.schemaUri),
    allSchemaInline: out.glbs.every((g) => g.schemaInline || !g.propertyTables.length),
    vertexColours: any("vertexColours"),
    colouredMaterials: any("colouredMaterials"),
    textured: any("textures"),
    featureIdAttributes: any("featureIdAttributes"),
    draco: any("draco"),
    meshopt: any("meshopt"),
    ktx2: any("ktx2"),
  });
  out.schemaUris = [...new Set(out.glbs.map((g) => g.schemaUri).filter(Boolean))];
  return out;
}

/** A one-line summary (no per-GLB list). */
export function summary(f) {
  const { glbs, byUri, ...rest } = f;
  return rest;
}

if (process.argv[1] && import.meta.url.endsWith(process.argv[1].split("/").pop())) {
  for (const d of process.argv.slice(2)) console.log(JSON.stringify(summary(tilesetFacts(d))));
}
