// What each client must do with each tileset: the one table of the client matrix.
//
// Every entry is a check on a client's measured result against the tileset's facts (facts.mjs,
// read from the files). A check marked `limitation` asserts a documented shortcoming of the
// pinned client version (tools/package.json): it passes while the shortcoming is still there
// and FAILS when a newer client no longer has it ("limitation gone"), so the table is updated
// then. Profiles: a set named `<profile>-<model>` was converted with that profile's options
// (Makefile: CLIENTS_PROFILE_*); other sets use the default options.
//
// SCHEMA_INLINE_IN_DECKGL_PROFILE: `--client deckgl` and `--client portable` write the schema
// into every tile, so deck.gl / loaders.gl must decode those sets' property tables (whatever the
// files say: a profile that stopped inlining fails here).
export const SCHEMA_INLINE_IN_DECKGL_PROFILE = true;

// Pixel shares (of the frame, and of the drawn pixels): a drawn model covers at least DRAWN;
// a coloured model has at least COLOURED of its pixels coloured, a grey one at most GREY.
const DRAWN = 0.01;
const COLOURED = 0.1;
const GREY = 0.02;

export const profileOf = (set) => (set.match(/^(three|deckgl|portable)-/) || [, "default"])[1];

/** The clients run on a set: a profile's sets in that client (and the Node loader), the others in all. */
export function clientsFor(set) {
  const p = profileOf(set);
  if (p === "three") return ["three"];
  if (p === "deckgl") return ["deckgl", "loadersgl"];
  return ["three", "deckgl", "loadersgl"];
}

const sumOver = (obj, f) => Object.values(obj).reduce((a, x) => a + f(x), 0);
/** Facts of the GLBs a client loaded, by uri ("data:" for the inlined root). */
const loadedGlbs = (facts, uris) => uris.map((u) => facts.byUri[u]).filter(Boolean);
// A model whose colour the viewer sees: vertex colours, coloured materials or textures.
const hasColour = (f) => f.vertexColours || f.colouredMaterials || f.textured;

/**
 * The checks of `client` on set `set` (name) with facts `f` and measured result `r`:
 * [{name, ok, limitation?, detail}].
 */
export function checks(client, set, f, r) {
  const profile = profileOf(set);
  const out = [];
  const check = (name, ok, detail, limitation) => out.push({ name, ok: !!ok, detail, ...(limitation ? { limitation } : {}) });
  const schemaInline = (g) => g.schemaInline || (SCHEMA_INLINE_IN_DECKGL_PROFILE && (profile === "deckgl" || profile === "portable"));
  check("loads: the tileset's own files read (facts.mjs)", !f.unreadable.length, f.unreadable.slice(0, 3).join(" | "));
  check("loads: no request leaves loopback", Array.isArray(r.external) && !r.external.length, (r.external || ["not followed"]).slice(0, 3).join(" "));

  if (client === "three") {
    check("loads: every requested tile loads, none fails", !r.timedOut && r.loaded > 0 && !r.errors.length, `${r.loaded} tiles; ${r.errors.slice(0, 3).join(" | ")}`);
    check("drawn", r.pixels.drawn >= DRAWN, `drawn ${r.pixels.drawn.toFixed(3)}`);
    const row = r.pick.rows?.[0];
    check("metadata: the picked feature's property table row", r.pick.hit && row && Object.values(row).some((v) => typeof v === "string" && v), JSON.stringify(row || r.pick).slice(0, 200));
    // Every copy of every loaded tile: one Mesh per primitive, an InstancedMesh of N copies per
    // instanced primitive (three's GLTFLoader reads EXT_mesh_gpu_instancing).
    const uris = Object.keys(r.tiles);
    const want = sumOver(loadedGlbs(f, uris), (g) => g.primitiveCopies);
    const got = sumOver(r.tiles, (t) => t.copies);
    check("instances: every instanced copy is drawn", uris.every((u) => f.byUri[u]) && got === want, `${got} of ${want} copies in ${uris.length} tiles`);
    if (r.instancePick?.found)
      check(
        "metadata of instanced copies: two copies of an instanced mesh are told apart",
        r.instancePick.hitBoth && r.instancePick.result !== "distinct",
        JSON.stringify(r.instancePick).slice(0, 200),
        "no EXT_instance_features: picking an instanced copy gives no feature (MeshFeatures is not attached to InstancedMesh)",
      );
    const withUri = loadedGlbs(f, uris).filter((g) => g.schemaUri).length;
    if (withUri > 1)
      check(
        "metadata: schema.json fetched once",
        r.schemaFetches > 1,
        `${r.schemaFetches} requests for ${withUri} tiles with schemaUri`,
        "GLTFStructuralMetadataExtension fetches schemaUri again for each tile (no cache; only concurrent loads share a request)",
      );
    if (hasColour(f)) check("colours", r.pixels.coloured >= COLOURED, `coloured ${r.pixels.coloured.toFixed(3)}`);
    return out;
  }

  // deck.gl and loaders.gl: the same loader (Tiles3DLoader), so the same metadata checks.
  const metadataChecks = (sample) => {
    const uris = Object.keys(sample);
    const glbs = uris.map((u) => [u, f.byUri[u], sample[u]]).filter(([, g]) => g && g.propertyTables.length);
    const draco = glbs.filter(([, g]) => g.draco);
    const plain = glbs.filter(([, g]) => !g.draco);
    if (draco.length)
      check(
        "metadata (Draco): feature ids",
        draco.every(([, , s]) => s.idLost === s.tables && s.decoded === 0),
        `${draco.length} Draco tiles; ids lost in ${draco.filter(([, , s]) => s.idLost).length}`,
        "Draco-decoded _FEATURE_ID_n comes back as CUSTOM_ATTRIBUTE_n: feature ids lost",
      );
    const inline = plain.filter(([, g]) => schemaInline(g));
    const external = plain.filter(([, g]) => !schemaInline(g));
    if (inline.length)
      check("metadata: a sampled feature's row decodes (schema inline)", inline.every(([, , s]) => s.tables > 0 && s.decoded === s.tables), `${inline.filter(([, , s]) => s.decoded === s.tables).length} of ${inline.length} tiles; ${JSON.stringify(inline[0][2].row).slice(0, 120)}`);
    if (external.length)
      check(
        "metadata: property tables with schemaUri",
        external.every(([, , s]) => s.decoded === 0),
        `${external.filter(([, , s]) => s.decoded).length} of ${external.length} tiles decoded`,
        "schemaUri is never fetched: property tables not decoded where schema.json is external",
      );
  };

  if (client === "deckgl") {
    if (f.inlinedRoot) {
      // The root's content is a data: URI: the tile type is taken from the text after the last '.'.
      const why = "a root inlined as a data: URI breaks the whole layer (tile type read after the URI's last '.')";
      check("loads (root inlined as a data: URI)", r.errors.some((e) => /Failed to render layer of type/.test(e)), `${r.loaded} tiles; ${r.errors.slice(0, 2).join(" | ")}`, why);
      check("drawn (root inlined as a data: URI)", r.pixels.drawn < DRAWN, `drawn ${r.pixels.drawn.toFixed(3)}`, why);
      return out;
    }
    const dracoFail = (e) => f.draco && /assert failed: gltf/.test(e);
    check("loads: every requested tile loads, no failure but the documented ones", !r.timedOut && r.loaded > 0 && r.errors.every(dracoFail), `${r.loaded} tiles; ${r.errors.slice(0, 3).join(" | ")}`);
    if (f.draco)
      check(
        "loads (Draco)",
        r.errors.some(dracoFail),
        `${r.loaded} of ${f.contents} tiles`,
        "a Draco tile whose lost feature id attribute EXT_mesh_features then reads fails to parse (assert failed: gltf); the layer loads few tiles",
      );
    check("drawn", r.pixels.drawn >= DRAWN, `drawn ${r.pixels.drawn.toFixed(3)}`);
    metadataChecks(r.sample);
    const uris = Object.keys(r.copies);
    const glbs = loadedGlbs(f, uris);
    const got = sumOver(r.copies, (c) => c.models);
    const nodes = sumOver(glbs, (g) => g.primitiveNodes);
    const copies = sumOver(glbs, (g) => g.primitiveCopies);
    if (copies > nodes)
      check("instances: every instanced copy is drawn", got === nodes, `${got} draws, ${copies} copies in ${uris.length} tiles`, "EXT_mesh_gpu_instancing ignored: one copy per instanced shape");
    else check("instances: every copy is drawn", uris.every((u) => f.byUri[u]) && got === copies, `${got} of ${copies} in ${uris.length} tiles`);
    if (f.vertexColours && !f.textured)
      check("colours (COLOR_0)", r.pixels.coloured <= GREY, `coloured ${r.pixels.coloured.toFixed(3)}`, "the scenegraph shader ignores COLOR_0: vertex colours draw grey");
    else if (hasColour(f)) check("colours", r.pixels.coloured >= COLOURED, `coloured ${r.pixels.coloured.toFixed(3)}`);
    return out;
  }

  if (client === "loadersgl") {
    const dataErr = r.errors.filter((e) => /^data:: tile type not a model/.test(e));
    if (f.inlinedRoot)
      check("loads (root inlined as a data: URI)", dataErr.length === 1, dataErr.join(" | ") || "the data: root loaded", "a data: URI content gets the type of the text after its last '.': not a model");
    const dracoErr = r.errors.filter((e) => f.draco && /assert failed: gltf/.test(e));
    if (f.draco)
      check(
        "loads (Draco)",
        dracoErr.length > 0,
        `${dracoErr.length} Draco tiles fail`,
        "a Draco tile whose lost feature id attribute EXT_mesh_features then reads fails to parse (assert failed: gltf)",
      );
    const other = r.errors.filter((e) => !dataErr.includes(e) && !dracoErr.includes(e));
    check("loads: every other tile loads, none fails", r.loaded + dataErr.length + dracoErr.length === f.contents && !other.length, `${r.loaded} of ${f.contents}${dracoErr.length ? `, ${dracoErr.length} Draco tiles fail (assert failed: gltf)` : ""}; ${other.slice(0, 3).join(" | ")}`);
    metadataChecks(r.sample);
    const uris = Object.keys(r.sample);
    const glbs = loadedGlbs(f, uris);
    const want = sumOver(glbs, (g) => g.instances);
    const got = sumOver(r.sample, (s) => s.instances);
    if (want) check("instances: every EXT_mesh_gpu_instancing copy is decoded", got === want, `${got} of ${want}`);
    if (uris.length) check("colours: COLOR_0 and material colours kept", uris.every((u) => r.sample[u].vertexColours === f.byUri[u].vertexColours && r.sample[u].colouredMaterials === f.byUri[u].colouredMaterials), `${uris.length} tiles`);
    return out;
  }
  throw new Error(`unknown client ${client}`);
}
