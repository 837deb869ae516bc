//! Helpers shared by the end-to-end tests, in one place:
//! * running the real binary ([`run`], [`convert`]) into scratch folders ([`tmpdir`]);
//! * the reference data: the bundled [`sample`], and the shared data folder ([`shared`],
//!   [`shared_data`], [`shared_file`], [`shared_files`], [`shared_models`]); missing under
//!   `BIMTILES_REQUIRE_TOOLS` (`make test`), it fails the test instead of skipping it;
//! * GLBs written and split by hand (`tests/support/glb.rs`: [`glb`], [`glb_chunks`],
//!   [`GlbBuilder`], [`one_mesh_glb`], [`triangle_glb`]) and a synthetic height field
//!   (`tests/support/height_field.rs`);
//! * glTF read back with tools that are not our writer (the `gltf` crate, [`read_accessor`]) and
//!   expanded to world space (`tests/support/world.rs`: [`world_nodes`], [`world_mesh`];
//!   [`drawn_meshes`] with GPU instances, [`decode_tileset`] for whole tilesets); tile contents
//!   read by their URI, a file or a data URI ([`content_bytes`], [`tileset_contents`]);
//! * checks by independent tools: gltf-validator, the official 3D Tiles JSON schemas
//!   ([`check_tileset`]), and the README's element-id rule ([`expected_element_ids`]).

use glam::{DMat4, DVec3};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

#[path = "../support/glb.rs"]
pub mod glb;
pub use glb::{
    bounds, f32_bytes, glb, glb_chunks, one_mesh_glb, png_claiming, png_image, textured_quad_glb,
    GlbBuilder,
};

#[path = "../support/height_field.rs"]
pub mod height_field;

#[path = "../support/world.rs"]
pub mod world;
pub use world::{scene_roots, world_mesh, world_nodes, WorldMesh};

/// The bimtiles binary built for the tests.
pub fn bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_bimtiles"))
}

/// The crate's folder.
pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The bundled sample model.
pub fn sample() -> PathBuf {
    repo().join("samples/sample_building.glb")
}

/// `path` when it is there (`found`), else `None` after saying so; a failure under
/// `BIMTILES_REQUIRE_TOOLS` (`make test`), which must not skip.
fn found_or_skipped(path: PathBuf, found: bool, what: &str) -> Option<PathBuf> {
    assert!(
        found || !tools_required(),
        "{}: {what} is missing (BIMTILES_REQUIRE_TOOLS is set)",
        path.display()
    );
    if !found {
        eprintln!("SKIPPED: {} not found ({what})", path.display());
    }
    found.then_some(path)
}

/// `../shared` beside the repo (or $BIMTILES_SHARED), if it exists (see [`found_or_skipped`]).
pub fn shared() -> Option<PathBuf> {
    let p = std::env::var_os("BIMTILES_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo().join("../shared"));
    let found = p.is_dir();
    found_or_skipped(p, found, "the shared data folder")
}

/// The models folder of the shared data (`data/`, with `MANIFEST.md`), if it exists.
pub fn shared_data() -> Option<PathBuf> {
    let d = shared()?.join("data");
    let found = d.is_dir();
    found_or_skipped(d, found, "the shared models folder")
}

/// One file of the shared data folder (`data/<name>`), if it exists.
pub fn shared_file(name: &str) -> Option<PathBuf> {
    let f = shared_data()?.join(name);
    let found = f.is_file();
    found_or_skipped(f, found, "a shared data file")
}

/// The files of the shared data folder with one of these extensions (any case), sorted; `None`
/// when the folder is missing (see [`shared_data`]).
pub fn shared_files(extensions: &[&str]) -> Option<Vec<PathBuf>> {
    let d = shared_data()?;
    let mut v: Vec<PathBuf> = std::fs::read_dir(&d)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .is_some_and(|e| extensions.iter().any(|x| e.eq_ignore_ascii_case(x)))
        })
        .collect();
    v.sort();
    Some(v)
}

/// The GLB models listed in the shared data's MANIFEST.md (empty, after saying so, without it).
/// Under `BIMTILES_REQUIRE_TOOLS` the manifest and every GLB it lists must be there.
pub fn shared_models() -> Vec<PathBuf> {
    let Some(manifest) = shared_file("MANIFEST.md") else {
        eprintln!("SKIPPED: only the bundled sample is tested");
        return Vec::new();
    };
    let data = manifest.parent().unwrap();
    let mut out: Vec<PathBuf> = Vec::new();
    for line in std::fs::read_to_string(&manifest).unwrap().lines() {
        let Some(name) = line.strip_prefix('|').and_then(|l| l.split('|').next()) else {
            continue;
        };
        let f = data.join(name.trim());
        if name.trim().ends_with(".glb") && !out.contains(&f) {
            let found = f.is_file();
            out.extend(found_or_skipped(f, found, "a model listed in MANIFEST.md"));
        }
    }
    out
}

/// Whether tests must fail (not skip) when an external tool is missing: `make test` sets it.
pub fn tools_required() -> bool {
    std::env::var_os("BIMTILES_REQUIRE_TOOLS").is_some()
}

/// Runs the binary with `args`.
pub fn run(args: &[&str]) -> Output {
    Command::new(bin())
        .args(args)
        .output()
        .expect("run bimtiles")
}

/// Puts `model` into `dir` under its own name (a hard link, or a copy across file systems): a
/// manifest's entries must stay inside its folder, and a symlink leading out is refused.
pub fn put_model_in(model: &Path, dir: &Path) -> PathBuf {
    let to = dir.join(model.file_name().unwrap());
    let _ = std::fs::remove_file(&to);
    if std::fs::hard_link(model, &to).is_err() {
        std::fs::copy(model, &to).unwrap();
    }
    to
}

/// Copies the folder holding `model` (its side files: materials, textures, sub-folders) into
/// `dir/<name>`; returns the model's path there.
pub fn put_folder_in(model: &Path, dir: &Path, name: &str) -> PathBuf {
    fn copy_tree(from: &Path, to: &Path) {
        std::fs::create_dir_all(to).unwrap();
        for e in std::fs::read_dir(from).unwrap() {
            let p = e.unwrap().path();
            let target = to.join(p.file_name().unwrap());
            if p.is_dir() {
                copy_tree(&p, &target);
            } else {
                std::fs::copy(&p, &target).unwrap();
            }
        }
    }
    let folder = dir.join(name);
    copy_tree(model.parent().unwrap(), &folder);
    folder.join(model.file_name().unwrap())
}

/// An empty scratch folder `target/test-out/<name>`.
pub fn tmpdir(name: &str) -> PathBuf {
    let d = repo().join("target/test-out").join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Converts `input` into `out` with extra args; panics with the tool's stderr on failure.
pub fn convert(input: &Path, out: &Path, extra: &[&str]) -> Value {
    let mut args = vec![
        "convert",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ];
    args.extend_from_slice(extra);
    let o = run(&args);
    assert!(
        o.status.success(),
        "convert {} failed: {}",
        input.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap()
}

/// The position grid (metres per axis) of each simplified tile's content, by URI, from a
/// conversion's report: simplified tiles may quantize on a share of their error, coarser than
/// full detail's 1 mm.
pub fn position_grids_m(report: &Value) -> std::collections::HashMap<String, f64> {
    report["tiles"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|t| {
            Some((
                t["content"].as_str()?.to_string(),
                t["max_position_error_m"].as_f64()?,
            ))
        })
        .collect()
}

/// Runs the Khronos glTF validator (npm) over a folder; returns (files, errors, warnings), or None
/// when Node or the package is not installed (and tools are not required). Tiles may reach shared
/// files anywhere in their tileset (`../textures/`): the tileset folder (`dir`, or its parent for
/// a `tiles` folder) is the root their URIs may reach.
pub fn gltf_validator(dir: &Path) -> Option<(u64, u64, u64)> {
    let script = repo().join("tools/validate_gltf.mjs");
    let installed = repo().join("tools/node_modules/gltf-validator").is_dir();
    if !installed {
        assert!(
            !tools_required(),
            "gltf-validator is not installed (run `make test`)"
        );
        eprintln!("SKIPPED gltf-validator: tools/node_modules missing (run `make test`)");
        return None;
    }
    let root = match dir.join("tileset.json").is_file() {
        true => dir,
        false => dir.parent().unwrap_or(dir),
    };
    let o = Command::new("node")
        .arg(script)
        .arg("--root")
        .arg(root)
        .arg(dir)
        .output()
        .expect("run node");
    let v: Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| {
        panic!(
            "validator output: {e}: {}",
            String::from_utf8_lossy(&o.stderr)
        )
    });
    if v["errors"].as_u64() != Some(0) {
        panic!(
            "gltf-validator errors: {}",
            serde_json::to_string_pretty(&v["results"]).unwrap()
        );
    }
    Some((
        v["files"].as_u64().unwrap(),
        v["errors"].as_u64().unwrap(),
        v["warnings"].as_u64().unwrap(),
    ))
}

/// The tileset folder `dir` with its `EXT_meshopt_compression` tiles decoded into plain GLBs by
/// meshoptimizer's reference JavaScript decoder (tools/decode_meshopt.mjs), in `out`; the number
/// of views decoded, or None when Node's packages are not installed (and tools are not required).
pub fn decode_meshopt(dir: &Path, out: &Path) -> Option<u64> {
    if !repo().join("tools/node_modules/meshoptimizer").is_dir() {
        assert!(
            !tools_required(),
            "meshoptimizer (npm) is not installed (run `make test`)"
        );
        eprintln!("SKIPPED meshopt decoding: tools/node_modules missing (run `make test`)");
        return None;
    }
    let _ = std::fs::remove_dir_all(out);
    let o = Command::new("node")
        .arg(repo().join("tools/decode_meshopt.mjs"))
        .arg(dir)
        .arg(out)
        .output()
        .expect("run node");
    assert!(
        o.status.success(),
        "decode_meshopt: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    v["decodedViews"].as_u64()
}

struct SchemaFiles(PathBuf);

impl jsonschema::Retrieve for SchemaFiles {
    fn retrieve(
        &self,
        uri: &jsonschema::Uri<String>,
    ) -> Result<Value, Box<dyn std::error::Error + Send + Sync>> {
        let path = PathBuf::from(uri.path().as_str());
        // Only files inside the schema folder.
        if !path.starts_with(&self.0) {
            return Err(format!("schema ref outside the schema folder: {uri}").into());
        }
        Ok(serde_json::from_slice(&std::fs::read(&path)?)?)
    }
}

/// Validates tileset.json against the official 3D Tiles 1.1 schemas in ../shared; returns the
/// error messages, or None when the schemas are not there.
pub fn tileset_schema_errors(tileset: &Value) -> Option<Vec<String>> {
    let dir = shared()?.join("specs/3d-tiles/specification/schema");
    if !dir.is_dir() {
        return None;
    }
    let dir = dir.canonicalize().unwrap();
    let main = dir.join("tileset.schema.json");
    let schema: Value = serde_json::from_slice(&std::fs::read(&main).unwrap()).unwrap();
    let validator = jsonschema::options()
        .with_draft(jsonschema::Draft::Draft202012)
        .with_base_uri(format!("file://{}", main.display()))
        .with_retriever(SchemaFiles(dir))
        .build(&schema)
        .expect("3D Tiles schema compiles");
    Some(
        validator
            .iter_errors(tileset)
            .map(|e| format!("{} at {}", e, e.instance_path()))
            .collect(),
    )
}

/// A tile read back: its box (centre, half-axes) in the tileset's root frame, and its content.
pub struct DecodedTile {
    /// The content URI in tileset.json: a file's path, or the data URI of an inlined root.
    pub uri: Option<String>,
    /// The content's name in report.json ([`content_name`]): the file name, also for the inlined
    /// root.
    pub name: Option<String>,
    pub box_min: DVec3,
    pub box_max: DVec3,
    pub geometric_error: f64,
    pub depth: u32,
    pub parent: Option<usize>,
    /// Content vertex positions in the root frame (z-up), and triangles.
    pub positions: Vec<DVec3>,
    /// Triangle corners, indices into `positions`.
    pub indices: Vec<u32>,
    pub triangles: usize,
    pub area: f64,
}

/// glTF y-up → 3D Tiles z-up, as the 3D Tiles spec asks clients to apply to glTF content.
pub const Y_UP_TO_Z_UP: DMat4 = DMat4::from_cols_array(&[
    1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
]);

/// Reads every tile of a tileset back with the `gltf` crate (no code of ours).
pub fn decode_tileset(dir: &Path) -> (Value, Vec<DecodedTile>) {
    let ts: Value =
        serde_json::from_slice(&std::fs::read(dir.join("tileset.json")).unwrap()).unwrap();
    let mut out = Vec::new();
    let mut stack = vec![(&ts["root"], 0u32, None::<usize>)];
    while let Some((t, depth, parent)) = stack.pop() {
        assert!(
            t.get("transform").is_none() || depth == 0,
            "only the root has a transform"
        );
        let b: Vec<f64> = t["boundingVolume"]["box"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        let c = DVec3::new(b[0], b[1], b[2]);
        let h = DVec3::new(
            DVec3::new(b[3], b[4], b[5]).abs().element_sum(),
            DVec3::new(b[6], b[7], b[8]).abs().element_sum(),
            DVec3::new(b[9], b[10], b[11]).abs().element_sum(),
        );
        let uri = t
            .pointer("/content/uri")
            .and_then(Value::as_str)
            .map(str::to_string);
        let (mut positions, mut indices, mut triangles, mut area) =
            (Vec::new(), Vec::new(), 0, 0.0);
        if let Some(u) = &uri {
            let bytes = read_content(dir, u);
            let g = gltf::Gltf::from_slice_without_validation(&bytes).unwrap();
            let blob = g.blob.as_deref().unwrap();
            for (mesh, placement) in drawn_meshes(&g, &glb_json(&bytes), blob) {
                let m = Y_UP_TO_Z_UP * placement.matrix;
                for p in mesh.primitives() {
                    let base = positions.len();
                    let (pos, idx) = primitive_geometry(&g, blob, &p);
                    positions.extend(pos.iter().map(|v| {
                        m.transform_point3(DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64))
                    }));
                    for t in idx.chunks_exact(3) {
                        let v = |i: u32| positions[base + i as usize];
                        area += (v(t[1]) - v(t[0])).cross(v(t[2]) - v(t[0])).length() * 0.5;
                    }
                    triangles += idx.len() / 3;
                    indices.extend(idx.iter().map(|&i| base as u32 + i));
                }
            }
        }
        let me = out.len();
        out.push(DecodedTile {
            name: uri.as_deref().map(|u| content_name(dir, u)),
            uri,
            box_min: c - h,
            box_max: c + h,
            geometric_error: t["geometricError"].as_f64().unwrap(),
            depth,
            parent,
            positions,
            indices,
            triangles,
            area,
        });
        if let Some(ch) = t.get("children").and_then(Value::as_array) {
            for c in ch.iter().rev() {
                stack.push((c, depth + 1, Some(me)));
            }
        }
    }
    (ts, out)
}

/// The metadata schema the tile `tile_uri` (a file in the tileset folder `dir`, or a data URI)
/// uses: inline in its `EXT_structural_metadata`, or the file its `schemaUri` names.
pub fn tile_schema(dir: &Path, tile_uri: &str) -> Value {
    let json = glb_json(&content_bytes(dir, tile_uri));
    let ext = &json["extensions"]["EXT_structural_metadata"];
    match ext["schemaUri"].as_str() {
        Some(uri) => {
            let file = dir.join(tile_uri).parent().unwrap().join(uri);
            serde_json::from_slice(&std::fs::read(&file).unwrap()).unwrap()
        }
        None => ext["schema"].clone(),
    }
}

/// The JSON chunk of a GLB, as plain JSON (extensions included).
pub fn glb_json(bytes: &[u8]) -> Value {
    glb_chunks(bytes).0
}

/// Where a mesh is drawn: the node's world matrix (times the instance transform for
/// `EXT_mesh_gpu_instancing`, glTF y-up), and the instance's `_FEATURE_ID_0` if it has one.
pub struct Placement {
    pub matrix: DMat4,
    pub instance_feature: Option<u32>,
}

/// Every (mesh, placement) of the default scene: the node hierarchy walked from the roots, each
/// instance of an instanced node separately (read here from the accessors, not by our writer).
pub fn drawn_meshes<'a>(
    g: &'a gltf::Gltf,
    doc: &Value,
    blob: &[u8],
) -> Vec<(gltf::Mesh<'a>, Placement)> {
    let mut out = Vec::new();
    for (node, world) in world_nodes(scene_roots(&g.document), DMat4::IDENTITY) {
        if let Some(mesh) = node.mesh() {
            match doc["nodes"][node.index()]
                .pointer("/extensions/EXT_mesh_gpu_instancing/attributes")
            {
                Some(attrs) => {
                    let read = |name: &str| {
                        attrs
                            .get(name)
                            .map(|a| read_accessor(doc, blob, a.as_u64().unwrap() as usize))
                    };
                    let t = read("TRANSLATION");
                    let r = read("ROTATION");
                    let sc = read("SCALE");
                    let f = read("_FEATURE_ID_0");
                    let count = [&t, &r, &sc, &f]
                        .iter()
                        .filter_map(|x| x.as_ref())
                        .map(|x| x.len())
                        .max()
                        .unwrap_or(0);
                    for i in 0..count {
                        let tr = t
                            .as_ref()
                            .map_or(DVec3::ZERO, |v| DVec3::new(v[i][0], v[i][1], v[i][2]));
                        let rot = r.as_ref().map_or(glam::DQuat::IDENTITY, |v| {
                            glam::DQuat::from_xyzw(v[i][0], v[i][1], v[i][2], v[i][3])
                        });
                        let scale = sc
                            .as_ref()
                            .map_or(DVec3::ONE, |v| DVec3::new(v[i][0], v[i][1], v[i][2]));
                        out.push((
                            mesh.clone(),
                            Placement {
                                matrix: world
                                    * DMat4::from_scale_rotation_translation(scale, rot, tr),
                                instance_feature: f.as_ref().map(|v| v[i][0] as u32),
                            },
                        ));
                    }
                }
                None => out.push((
                    mesh,
                    Placement {
                        matrix: world,
                        instance_feature: None,
                    },
                )),
            }
        }
    }
    out
}

/// The values of a plain (non-Draco) accessor as f64 rows (FLOAT, and unsigned/normalized integer
/// types), honouring byteOffset and byteStride.
pub fn read_accessor(doc: &Value, blob: &[u8], index: usize) -> Vec<Vec<f64>> {
    let a = &doc["accessors"][index];
    let v =
        &doc["bufferViews"][a["bufferView"].as_u64().expect("accessor has a bufferView") as usize];
    let n = match a["type"].as_str().unwrap() {
        "SCALAR" => 1,
        "VEC2" => 2,
        "VEC3" => 3,
        "VEC4" => 4,
        t => panic!("accessor type {t}"),
    };
    let ct = a["componentType"].as_u64().unwrap();
    let size = match ct {
        5126 | 5125 => 4,
        5123 | 5122 => 2,
        _ => 1,
    };
    let normalized = a["normalized"].as_bool().unwrap_or(false);
    let stride = v["byteStride"].as_u64().map_or(n * size, |s| s as usize);
    let base = v["byteOffset"].as_u64().unwrap_or(0) as usize
        + a["byteOffset"].as_u64().unwrap_or(0) as usize;
    (0..a["count"].as_u64().unwrap() as usize)
        .map(|i| {
            (0..n)
                .map(|k| {
                    let o = base + i * stride + k * size;
                    let b = &blob[o..o + size];
                    let x = match ct {
                        5126 => f32::from_le_bytes(b.try_into().unwrap()) as f64,
                        5125 => u32::from_le_bytes(b.try_into().unwrap()) as f64,
                        5123 => u16::from_le_bytes(b.try_into().unwrap()) as f64,
                        5122 => i16::from_le_bytes(b.try_into().unwrap()) as f64,
                        5121 => b[0] as f64,
                        _ => b[0] as i8 as f64,
                    };
                    match (normalized, ct) {
                        (true, 5123) => x / 65535.0,
                        (true, 5122) => (x / 32767.0).max(-1.0),
                        (true, 5121) => x / 255.0,
                        (true, 5120) => (x / 127.0).max(-1.0),
                        _ => x,
                    }
                })
                .collect()
        })
        .collect()
}

/// A tile's GLB as plain glTF: with `EXT_meshopt_compression`, every compressed view decoded (by
/// the crate's reader) into the BIN chunk and the extension and its fallback buffer gone, so the
/// readers here see the data a client draws. Other GLBs are returned as they are.
pub fn plain_glb(bytes: Vec<u8>) -> Vec<u8> {
    let (mut json, mut bin) = glb_chunks(&bytes);
    let used = json["extensionsUsed"].to_string();
    if !used.contains("EXT_meshopt_compression") {
        return bytes;
    }
    let source = bin.clone();
    for v in json["bufferViews"].as_array_mut().unwrap() {
        let Some(ext) = v.pointer("/extensions/EXT_meshopt_compression") else {
            continue;
        };
        let view: bimtiles::ingest::MeshoptView = serde_json::from_value(ext.clone()).unwrap();
        assert_eq!(view.buffer, 0, "meshopt streams are in the BIN chunk");
        let decoded =
            bimtiles::ingest::decode_meshopt_view(&view, &source).expect("meshopt view decodes");
        assert_eq!(decoded.len() as u64, v["byteLength"].as_u64().unwrap());
        bin.resize(bin.len().next_multiple_of(4), 0);
        v["buffer"] = json!(0);
        v["byteOffset"] = json!(bin.len());
        v.as_object_mut().unwrap().remove("extensions");
        bin.extend_from_slice(&decoded);
    }
    json["buffers"] = json!([{"byteLength": bin.len()}]);
    for key in ["extensionsUsed", "extensionsRequired"] {
        if let Some(list) = json[key].as_array_mut() {
            list.retain(|e| e != "EXT_meshopt_compression");
        }
    }
    bimtiles::glb_container::glb_container(&serde_json::to_vec(&json).unwrap(), &bin)
}

/// The GLB at `path`, as [`plain_glb`] makes it.
pub fn read_tile(path: &Path) -> Vec<u8> {
    plain_glb(std::fs::read(path).unwrap())
}

/// The bytes of the content `uri` of the tileset in `dir`: the file it names, or for a data URI
/// (3D Tiles 1.1 allows them; bimtiles inlines a small root so) its payload, decoded with the
/// `base64` crate rather than our own reader.
pub fn content_bytes(dir: &Path, uri: &str) -> Vec<u8> {
    use base64::Engine;
    match uri.strip_prefix("data:") {
        Some(rest) => {
            let (media, payload) = rest.split_once(',').expect("a data URI has a comma");
            assert!(
                media.ends_with(";base64"),
                "{}: data URI not base64",
                dir.display()
            );
            base64::engine::general_purpose::STANDARD
                .decode(payload)
                .unwrap_or_else(|e| panic!("{}: data URI: {e}", dir.display()))
        }
        None => std::fs::read(dir.join(uri))
            .unwrap_or_else(|e| panic!("{}: {e}", dir.join(uri).display())),
    }
}

/// [`content_bytes`] as [`plain_glb`] makes them.
pub fn read_content(dir: &Path, uri: &str) -> Vec<u8> {
    plain_glb(content_bytes(dir, uri))
}

/// The name report.json gives the content `uri` of the tileset in `dir`: the URI itself, or for
/// the root inlined as a data URI, the file name its record keeps (`inlined_in_tileset`).
pub fn content_name(dir: &Path, uri: &str) -> String {
    if !uri.starts_with("data:") {
        return uri.to_string();
    }
    let report: Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    let root = &report["tiles"][0];
    assert_eq!(root["inlined_in_tileset"], true, "{}", dir.display());
    root["content"].as_str().unwrap().to_string()
}

/// The content URI tileset.json gives the tile report.json names `name` (the inverse of
/// [`content_name`]): the name itself, or the root's data URI when it was inlined.
pub fn content_uri(dir: &Path, name: &str) -> String {
    let read = |file: &str| -> Value {
        serde_json::from_slice(&std::fs::read(dir.join(file)).unwrap()).unwrap()
    };
    let root = &read("report.json")["tiles"][0];
    if root["inlined_in_tileset"] == true && root["content"] == name {
        return read("tileset.json")["root"]["content"]["uri"]
            .as_str()
            .unwrap()
            .to_string();
    }
    name.to_string()
}

/// Every content of the tileset in `dir`, in tree order: (its name in report.json, its bytes).
pub fn tileset_contents(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let ts: Value =
        serde_json::from_slice(&std::fs::read(dir.join("tileset.json")).unwrap()).unwrap();
    let mut out = Vec::new();
    let mut stack = vec![&ts["root"]];
    while let Some(t) = stack.pop() {
        let uris = t.pointer("/content/uri").into_iter().chain(
            t["contents"]
                .as_array()
                .into_iter()
                .flatten()
                .map(|c| &c["uri"]),
        );
        for uri in uris.filter_map(Value::as_str) {
            out.push((content_name(dir, uri), content_bytes(dir, uri)));
        }
        if let Some(children) = t["children"].as_array() {
            stack.extend(children.iter().rev());
        }
    }
    out
}

/// Positions and triangle indices of a primitive, decoding Draco when it is compressed.
pub fn primitive_geometry(
    g: &gltf::Gltf,
    blob: &[u8],
    p: &gltf::Primitive,
) -> (Vec<[f32; 3]>, Vec<u32>) {
    if let Some(ext) = p.extension_value("KHR_draco_mesh_compression") {
        let view = g
            .document
            .views()
            .nth(ext["bufferView"].as_u64().unwrap() as usize)
            .unwrap();
        let bytes = &blob[view.offset()..view.offset() + view.length()];
        let d = bimtiles::encode::draco::decode_mesh(bytes).expect("Draco stream decodes");
        let id = ext["attributes"]["POSITION"].as_u64().unwrap() as u32;
        let pos = d.attribute(id).unwrap().values.as_f32().unwrap().to_vec();
        // The accessors must describe the decoded data.
        let acc = p.get(&gltf::Semantic::Positions).unwrap();
        assert_eq!(
            acc.count() * 3,
            pos.len(),
            "POSITION count is the decoded count"
        );
        assert_eq!(
            p.indices().unwrap().count(),
            d.indices.len(),
            "index count is the decoded count"
        );
        return (
            pos.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
            d.indices,
        );
    }
    let r = p.reader(|_| Some(blob));
    let indices = r.read_indices().unwrap().into_u32().collect();
    let acc = p.get(&gltf::Semantic::Positions).unwrap();
    if acc.data_type() == gltf::accessor::DataType::F32 {
        return (r.read_positions().unwrap().collect(), indices);
    }
    // KHR_mesh_quantization: integer positions (normalized or not), the node transform
    // dequantizes them.
    let doc = serde_json::to_value(g.document.clone().into_json()).unwrap();
    let pos = read_accessor(&doc, blob, acc.index())
        .into_iter()
        .map(|v| [v[0] as f32, v[1] as f32, v[2] as f32])
        .collect();
    (pos, indices)
}

/// Checks the structural promises of a written tileset; returns the decoded tiles.
pub fn check_tileset(dir: &Path, input_triangles: usize) -> Vec<DecodedTile> {
    let (ts, tiles) = decode_tileset(dir);
    // Exact duplicates removed by dedup are not drawn: what must be drawn is what dedup kept.
    let input_triangles = match std::fs::read(dir.join("report.json"))
        .ok()
        .and_then(|b| serde_json::from_slice::<Value>(&b).ok())
        .filter(|r| r["dedup"].is_object())
    {
        Some(r) => {
            assert_eq!(
                r["dedup"]["triangles_before"].as_u64(),
                Some(input_triangles as u64),
                "dedup saw the whole input"
            );
            r["dedup"]["triangles_after"].as_u64().unwrap() as usize
        }
        None => input_triangles,
    };
    assert_eq!(ts["asset"]["version"], "1.1");
    if let Some(errors) = tileset_schema_errors(&ts) {
        assert!(
            errors.is_empty(),
            "{}: schema errors: {errors:#?}",
            dir.display()
        );
    } else {
        assert!(
            !tools_required() || shared().is_none(),
            "3D Tiles schemas missing"
        );
        eprintln!("SKIPPED schema check: ../shared/specs not found");
    }
    let mut has_child = vec![false; tiles.len()];
    for t in &tiles {
        if let Some(p) = t.parent {
            has_child[p] = true;
        }
    }
    // Additive refinement: every input triangle in exactly one tile; replacement (HLOD): in
    // exactly one leaf, and every internal tile has (simplified) content; discrete LOD chains
    // (`--lod-ratios`) only leave the octree's internal tiles above the chains empty.
    let chains = std::fs::read(dir.join("report.json"))
        .ok()
        .and_then(|b| serde_json::from_slice::<Value>(&b).ok())
        .is_some_and(|r| r["options"]["lod"] == "ratios");
    let replace = ts["root"]["refine"] == "REPLACE";
    let total: usize = tiles
        .iter()
        .enumerate()
        .filter(|&(i, _)| !replace || !has_child[i])
        .map(|(_, t)| t.triangles)
        .sum();
    assert_eq!(
        total,
        input_triangles,
        "{}: every input triangle is written once (in a leaf, with HLOD)",
        dir.display()
    );
    if replace {
        for (i, t) in tiles.iter().enumerate() {
            assert!(
                t.triangles > 0 || (chains && has_child[i]),
                "{}: HLOD tile {i} without content",
                dir.display()
            );
            if !has_child[i] {
                assert_eq!(t.geometric_error, 0.0, "leaves are full detail");
            }
            if let Some(p) = t.parent {
                assert!(
                    t.geometric_error < tiles[p].geometric_error,
                    "{}: geometric error decreases strictly downwards",
                    dir.display()
                );
            }
        }
    }
    let top = ts["geometricError"].as_f64().unwrap();
    assert!(top > 0.0);
    for (i, t) in tiles.iter().enumerate() {
        // Content inside its box (f32 rounding allowance of 0.1 mm).
        for p in &t.positions {
            assert!(
                p.cmpge(t.box_min - DVec3::splat(1e-4)).all()
                    && p.cmple(t.box_max + DVec3::splat(1e-4)).all(),
                "{}: {:?} vertex {p} outside its box {}..{}",
                dir.display(),
                t.uri,
                t.box_min,
                t.box_max
            );
        }
        match t.parent {
            Some(pi) => {
                let p = &tiles[pi];
                assert!(
                    t.box_min.cmpge(p.box_min - DVec3::splat(1e-9)).all()
                        && t.box_max.cmple(p.box_max + DVec3::splat(1e-9)).all(),
                    "child box inside parent"
                );
                assert!(
                    t.geometric_error <= p.geometric_error,
                    "geometric error does not grow downwards"
                );
            }
            None => assert!(t.geometric_error <= top),
        }
        // Tight: the box is the content's box (plus a hair) for tiles with content and no children.
        if !t.positions.is_empty() && !has_child[i] {
            let mut lo = DVec3::splat(f64::INFINITY);
            let mut hi = DVec3::splat(f64::NEG_INFINITY);
            for p in &t.positions {
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
            let slack = ((t.box_max - t.box_min) - (hi - lo)).max_element();
            assert!(
                slack < 0.01 + (hi - lo).max_element() * 1e-4,
                "leaf box is tight (slack {slack} m)"
            );
        }
    }
    tiles
}

/// A one-triangle GLB with vertices given in glTF (y-up) coordinates and an optional node translation.
pub fn triangle_glb(verts: [[f32; 3]; 3], translation: Option<[f64; 3]>) -> Vec<u8> {
    let mut node = serde_json::json!({"mesh": 0});
    if let Some(t) = translation {
        node["translation"] = serde_json::json!(t);
    }
    one_mesh_glb(&verts, None, serde_json::json!([node]), &[0])
}

/// Each reachable mesh node's element id (node index → id), derived from the glTF alone by the
/// rule the README gives under "Element ids" (not by the product's code):
/// 1. a node path segment is the node's name (`node<i>` unnamed); among siblings, in glTF order,
///    the n-th repeat of a name is `name#n`;
/// 2. a GlobalId (extras `guid`/`GlobalId`/`globalId`/`ifc_guid`, or a node name of GlobalId form)
///    is the id when no other element of the file has it; else the path is;
/// 3. an id still taken by an earlier element (depth-first reading order) gets the smallest free
///    `#k`.
pub fn expected_element_ids(doc: &gltf::Document) -> std::collections::HashMap<usize, String> {
    use std::collections::{HashMap, HashSet};
    let roots: Vec<usize> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(s) => s.nodes().map(|n| n.index()).collect(),
        None => {
            let children: HashSet<usize> = doc
                .nodes()
                .flat_map(|n| n.children().map(|c| c.index()))
                .collect();
            (0..doc.nodes().count())
                .filter(|i| !children.contains(i))
                .collect()
        }
    };
    let nodes: Vec<gltf::Node> = doc.nodes().collect();
    let mut parent: HashMap<usize, usize> = HashMap::new();
    let mut segment: Vec<String> = nodes
        .iter()
        .map(|n| {
            n.name()
                .map_or_else(|| format!("node{}", n.index()), str::to_string)
        })
        .collect();
    let mut groups: Vec<Vec<usize>> = vec![roots.clone()];
    for n in &nodes {
        let kids: Vec<usize> = n.children().map(|c| c.index()).collect();
        for &k in &kids {
            parent.insert(k, n.index());
        }
        groups.push(kids);
    }
    for g in &groups {
        let mut seen: HashMap<String, usize> = HashMap::new();
        for &i in g {
            if nodes[i].name().is_none() {
                continue;
            }
            let count = seen.entry(segment[i].clone()).or_default();
            if *count > 0 {
                segment[i] = format!("{}#{count}", segment[i]);
            }
            *count += 1;
        }
    }
    let path = |mut i: usize| {
        let mut parts = vec![segment[i].clone()];
        while let Some(&p) = parent.get(&i) {
            parts.push(segment[p].clone());
            i = p;
        }
        parts.reverse();
        parts.join("/")
    };
    let is_guid = |s: &str| {
        s.len() == 22
            && s.starts_with(['0', '1', '2', '3'])
            && s.bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'$')
    };
    let guid_of = |n: &gltf::Node| -> Option<String> {
        let extras: Option<Value> = n
            .extras()
            .as_ref()
            .and_then(|x| serde_json::from_str(x.get()).ok());
        let from_extras = ["guid", "GlobalId", "globalId", "ifc_guid"]
            .iter()
            .find_map(|k| extras.as_ref()?.get(*k)?.as_str().map(str::to_string));
        from_extras.or_else(|| n.name().filter(|s| is_guid(s)).map(str::to_string))
    };
    // Depth-first reading order, roots and children in glTF order.
    let mut order = Vec::new();
    let mut stack: Vec<usize> = roots.iter().rev().copied().collect();
    while let Some(i) = stack.pop() {
        if nodes[i].mesh().is_some() {
            order.push(i);
        }
        stack.extend(
            nodes[i]
                .children()
                .map(|c| c.index())
                .collect::<Vec<_>>()
                .iter()
                .rev(),
        );
    }
    let mut guid_uses: HashMap<String, usize> = HashMap::new();
    for &i in &order {
        if let Some(g) = guid_of(&nodes[i]) {
            *guid_uses.entry(g).or_default() += 1;
        }
    }
    let first: Vec<String> = order
        .iter()
        .map(|&i| match guid_of(&nodes[i]) {
            Some(g) if guid_uses[&g] == 1 => g,
            _ => path(i),
        })
        .collect();
    let mut taken: HashSet<String> = first.iter().cloned().collect();
    let mut held: HashSet<String> = HashSet::new();
    let mut out = HashMap::new();
    for (&i, id) in order.iter().zip(first) {
        let id = if held.insert(id.clone()) {
            id
        } else {
            let free = (1..)
                .map(|k| format!("{id}#{k}"))
                .find(|c| !taken.contains(c))
                .unwrap();
            taken.insert(free.clone());
            held.insert(free.clone());
            free
        };
        out.insert(i, id);
    }
    out
}

/// One textured primitive of a tile, read back.
pub struct Textured {
    pub image: Vec<u8>,
    pub dims: (u32, u32),
    pub positions: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    pub indices: Vec<u32>,
}

/// The encoded images a GLB input embeds, as a set.
pub fn input_images(model: &Path) -> std::collections::BTreeSet<Vec<u8>> {
    let g = gltf::Gltf::from_slice_without_validation(&std::fs::read(model).unwrap()).unwrap();
    let blob = g.blob.as_deref().unwrap();
    g.images()
        .filter_map(|im| match im.source() {
            gltf::image::Source::View { view, .. } => {
                Some(blob[view.offset()..view.offset() + view.length()].to_vec())
            }
            _ => None,
        })
        .collect()
}

/// An image of the tile `tile_uri` of the tileset in `dir`: embedded in the GLB (`blob`) or a
/// shared file relative to the tile (an inlined root names no file).
pub fn image_bytes(dir: &Path, tile_uri: &str, blob: &[u8], image: &gltf::Image) -> Vec<u8> {
    match image.source() {
        gltf::image::Source::View { view, .. } => {
            blob[view.offset()..view.offset() + view.length()].to_vec()
        }
        gltf::image::Source::Uri { uri, .. } => {
            assert!(uri.starts_with("../textures/"), "{uri}");
            assert!(
                !tile_uri.starts_with("data:"),
                "an inlined tile names {uri}"
            );
            let tile = dir.join(tile_uri);
            std::fs::read(tile.parent().unwrap().join(uri)).unwrap()
        }
    }
}

/// Textured primitives of the tile `uri` of the tileset in `dir`, written without Draco
/// (`--compression none`).
pub fn read_textured(dir: &Path, uri: &str) -> Vec<Textured> {
    let bytes = read_content(dir, uri);
    let g = gltf::Gltf::from_slice_without_validation(&bytes).unwrap();
    let blob = g.blob.as_deref().unwrap();
    let mut out = Vec::new();
    for mesh in g.document.meshes() {
        for p in mesh.primitives() {
            let Some(info) = p.material().pbr_metallic_roughness().base_color_texture() else {
                continue;
            };
            let image = image_bytes(dir, uri, blob, &info.texture().source());
            let dims = image::ImageReader::new(std::io::Cursor::new(&image))
                .with_guessed_format()
                .unwrap()
                .into_dimensions()
                .unwrap();
            let r = p.reader(|_| Some(blob));
            out.push(Textured {
                image,
                dims,
                positions: r.read_positions().unwrap().collect(),
                uvs: r.read_tex_coords(0).unwrap().into_f32().collect(),
                indices: r.read_indices().unwrap().into_u32().collect(),
            });
        }
    }
    out
}
