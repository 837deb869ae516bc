// What a loaders.gl-parsed glTF (postProcessGLTF output: tile.content.gltf) gives its user, shared
// by the loaders.gl check in Node (loadersgl.mjs) and the deck.gl page (deckgl.js, the same loader
// inside Tile3DLayer). Plain ES module, no imports.

/**
 * {tables, decoded, idLost, row, instances, instanceNodes, vertexColours, colouredMaterials}:
 * tables: primitives with an EXT_mesh_features attribute feature id bound to a property table;
 * decoded: of those, how many give a row whose properties all decoded (a sampled feature: the
 * feature id of the primitive's first vertex); idLost: how many lost their `_FEATURE_ID_n`
 * attribute (renamed by the decoder); row: the first decoded row; instances: copies the
 * EXT_mesh_gpu_instancing nodes carry (decoded TRANSLATION accessors); vertexColours: a
 * primitive kept COLOR_0; colouredMaterials: a material with a non-grey base colour.
 */
export function sampleGltf(gltf) {
  const out = { tables: 0, decoded: 0, idLost: 0, row: null, instances: 0, instanceNodes: 0, vertexColours: false, colouredMaterials: false, primitiveNodes: 0 };
  const meta = gltf.extensions?.EXT_structural_metadata;
  for (const mesh of gltf.meshes || [])
    for (const p of mesh.primitives || []) {
      if (p.attributes?.COLOR_0) out.vertexColours = true;
      for (const f of p.extensions?.EXT_mesh_features?.featureIds || []) {
        if (f.attribute === undefined || f.propertyTable === undefined) continue;
        out.tables++;
        if (!p.attributes?.[`_FEATURE_ID_${f.attribute}`]) {
          out.idLost++;
          continue;
        }
        const table = meta?.propertyTables?.[f.propertyTable];
        const fid = f.data?.[0];
        if (!table || fid === undefined) continue;
        const row = {};
        let ok = true;
        for (const [k, prop] of Object.entries(table.properties || {})) {
          const v = prop.data?.[fid];
          if (v === undefined || v === null) ok = false;
          row[k] = v;
        }
        if (ok && Object.values(row).some((v) => typeof v === "string" && v.length)) {
          out.decoded++;
          out.row ??= row;
        }
      }
    }
  for (const n of gltf.nodes || []) {
    const inst = n.extensions?.EXT_mesh_gpu_instancing;
    if (!inst) continue;
    out.instanceNodes++;
    const acc = inst.attributes?.TRANSLATION;
    const a = typeof acc === "object" ? acc : gltf.accessors?.[acc];
    if (a?.value) out.instances += a.value.length / 3;
  }
  for (const m of gltf.materials || []) {
    const c = m.pbrMetallicRoughness?.baseColorFactor;
    if (c && Math.max(Math.abs(c[0] - c[1]), Math.abs(c[1] - c[2]), Math.abs(c[0] - c[2])) > 0.04) out.colouredMaterials = true;
  }
  return out;
}
