//! The integration tests: one crate, one binary. Each module runs the real `bimtiles` binary (or
//! the library's public API) on the bundled sample and the real files of `../shared/data`, and
//! checks what comes out with readers and tools that share no code with our writers.
//!
//! Shared helpers live in `common` (running the binary, the shared data, decoding tiles back,
//! gltf-validator and the 3D Tiles schemas); hand-built inputs in `support/`.

#[allow(dead_code, unused_imports)]
mod common;

// What every conversion promises.
/// Bad input: one clear error line naming the file, no panic, no output left behind.
mod bad_input;
/// The command line: help with examples, the version's commit, completions, man pages, and
/// summaries that end with a newline.
mod cli;
/// `--client` profiles: each loads in its client, with the same elements, triangles and properties.
mod clients;
/// The fuzz corpora replayed on stable: every input returns, none panics.
mod fuzz_corpus;
/// The user's folders are never lost or clobbered: locks, `--force`, killed runs.
mod output_safety;
/// `convert --update` and sharded updates: every update equals a full build; a sharded update
/// runs only the jobs whose subtrees changed; killed updates leave the old or the new tileset; a
/// missing or corrupt cache is a full build with one line saying why.
mod update;
/// Every shared model converts to a tileset that gltf-validator and the 3D Tiles schemas accept.
mod valid_tilesets;

// Input formats.
/// CityGML files (2.0, 3.0, ADEs): valid tilesets, gml:ids and ADE attributes, textures, LoD choice.
mod citygml;
/// CityJSON datasets: every city object an element, every triangle once, placed on Earth.
mod cityjson;
/// glTF compressed by third-party tools (Draco, meshopt) reads as the plain files do.
mod compressed_gltf;
/// Real georeferenced IFC exports land where their georeferencing says.
#[cfg(feature = "ifc")]
mod georef_ifc;
/// The IFC reader against IfcOpenShell's exports of the same files.
#[cfg(feature = "ifc")]
mod ifc_crosscheck;
/// Campus manifests: models placed on Earth, one tileset, element identity kept.
mod manifest;
/// Wavefront OBJ (+MTL) and FBX: groups and mesh nodes as elements, their area, ids and textures.
mod mesh_formats;

// The pipeline's stages, checked from the outside.
/// Repeated shapes and exact duplicates found on real models.
mod dedup;
/// Edges (EXT_mesh_primitive_edge_visibility) in every tile, against the decoded triangles, and
/// what they cost.
mod edges;
/// Fewer sequential requests before the first frame: embedded files, schema placement.
mod first_view_requests;
/// HLOD and LOD chains: every declared geometricError honest and tight.
mod hlod;
/// GPU instancing expanded back to the same world geometry and features.
mod instancing;
/// Large meshes cut across tiles by whole triangles.
mod mesh_splitting;
/// Quantized and meshopt tiles give the same geometry as plain ones.
mod quantization;
/// Sharded builds give `convert`'s tileset byte for byte.
mod shard;
/// `bimtiles simplify` on every model.
mod simplify_cli;
/// The simplifier's quality against meshoptimizer and the paper's Table IV.
mod simplify_quality;
/// Texture pyramids, crops and atlases read back level by level.
mod textures;
