//! Compressed glTF input (issue 31), with the real binary: the shared GLBs compressed by real
//! third-party tools (gltf-pipeline: `KHR_draco_mesh_compression`; gltfpack: `EXT_meshopt_compression`
//! with `KHR_mesh_quantization` and `KHR_texture_transform`) convert to the same elements (ids and
//! count) as the uncompressed files, each element with the same triangle count and, within the
//! codec's quantization, the same bounding box. Tiles are written uncompressed, with `--lod none`,
//! so each element's triangles are read back exactly; gltf-validator checks the tiles.

use crate::common::*;
use glam::DVec3;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Per element id: (triangles, box min, box max) in the tileset's root frame.
type Elements = BTreeMap<String, (usize, DVec3, DVec3)>;

/// A tool of tools/node_modules/.bin, or None (a failure under `BIMTILES_REQUIRE_TOOLS`).
fn npm_tool(name: &str) -> Option<PathBuf> {
    let path = repo().join("tools/node_modules/.bin").join(name);
    if path.exists() {
        return Some(path);
    }
    assert!(
        !tools_required(),
        "{name} is not installed (run `make test`)"
    );
    eprintln!("SKIPPED: {name} missing (run `make test`)");
    None
}

/// Runs a compressor; panics with its output when it fails.
fn compress(tool: &Path, args: &[&str]) {
    let o = Command::new(tool)
        .args(args)
        .output()
        .expect("run compressor");
    assert!(
        o.status.success(),
        "{} {args:?}: {}{}",
        tool.display(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The string column `name` of a property table, one entry per row.
fn string_column(doc: &Value, blob: &[u8], table: &Value, name: &str) -> Vec<String> {
    let prop = &table["properties"][name];
    let view = |key: &str| -> &[u8] {
        let v = &doc["bufferViews"][prop[key].as_u64().unwrap() as usize];
        let off = v["byteOffset"].as_u64().unwrap_or(0) as usize;
        &blob[off..off + v["byteLength"].as_u64().unwrap() as usize]
    };
    let values = view("values");
    let offsets = view("stringOffsets");
    let size = match prop["stringOffsetType"].as_str().unwrap_or("UINT32") {
        "UINT8" => 1,
        "UINT16" => 2,
        _ => 4,
    };
    let offset = |i: usize| -> usize {
        offsets[i * size..(i + 1) * size]
            .iter()
            .rev()
            .fold(0usize, |a, &b| a << 8 | b as usize)
    };
    let rows = table["count"].as_u64().unwrap() as usize;
    (0..rows)
        .map(|r| String::from_utf8(values[offset(r)..offset(r + 1)].to_vec()).unwrap())
        .collect()
}

/// Every element's triangles and box, read back from an uncompressed `--lod none` tileset with
/// the `gltf` crate (feature ids mapped to the property table's `id` column).
fn elements_of(dir: &Path) -> Elements {
    let (_, tiles) = decode_tileset(dir);
    let mut out = Elements::new();
    for uri in tiles.iter().filter_map(|t| t.uri.as_ref()) {
        let bytes = read_content(dir, uri);
        let (doc, blob) = glb_chunks(&bytes);
        let g = gltf::Gltf::from_slice_without_validation(&bytes).unwrap();
        let tables = &doc["extensions"]["EXT_structural_metadata"]["propertyTables"];
        let ids: Vec<Vec<String>> = tables
            .as_array()
            .unwrap()
            .iter()
            .map(|t| string_column(&doc, &blob, t, "id"))
            .collect();
        for (mesh, placement) in drawn_meshes(&g, &doc, &blob) {
            let m = Y_UP_TO_Z_UP * placement.matrix;
            for p in mesh.primitives() {
                let (pos, idx) = primitive_geometry(&g, &blob, &p);
                let ext = &doc["meshes"][mesh.index()]["primitives"][p.index()]["extensions"]
                    ["EXT_mesh_features"]["featureIds"][0];
                let table = ext["propertyTable"].as_u64().unwrap() as usize;
                let features: Vec<usize> = match (placement.instance_feature, ext.get("attribute"))
                {
                    (Some(f), _) => vec![f as usize; pos.len()],
                    (None, Some(_)) => {
                        let acc = doc["meshes"][mesh.index()]["primitives"][p.index()]["attributes"]
                            ["_FEATURE_ID_0"]
                            .as_u64()
                            .unwrap() as usize;
                        read_accessor(&doc, &blob, acc)
                            .into_iter()
                            .map(|v| v[0] as usize)
                            .collect()
                    }
                    (None, None) => vec![0; pos.len()],
                };
                for t in idx.chunks_exact(3) {
                    let id = ids[table][features[t[0] as usize]].clone();
                    let e = out.entry(id).or_insert((
                        0,
                        DVec3::splat(f64::INFINITY),
                        DVec3::splat(f64::NEG_INFINITY),
                    ));
                    e.0 += 1;
                    for &i in t {
                        let v = pos[i as usize];
                        let w =
                            m.transform_point3(DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64));
                        e.1 = e.1.min(w);
                        e.2 = e.2.max(w);
                    }
                }
            }
        }
    }
    out
}

fn convert_plain(input: &Path, name: &str) -> (Value, PathBuf) {
    let out = tmpdir(name).join("tiles");
    let report = convert(
        input,
        &out,
        &[
            "--lod",
            "none",
            "--compression",
            "none",
            "--no-dedup",
            "--no-instancing",
        ],
    );
    (report, out)
}

/// Converts `original` and its compressed copy and compares them element by element; `tolerance_m`
/// is the codec's quantization bound on a box corner for this model.
fn compare(original: &Path, compressed: &Path, label: &str, tolerance_m: f64) {
    let (ref_report, ref_dir) = convert_plain(original, &format!("compressed-{label}-ref"));
    let (report, dir) = convert_plain(compressed, &format!("compressed-{label}"));
    assert_eq!(
        report["input"]["components"], ref_report["input"]["components"],
        "{label}: element count"
    );
    assert_eq!(
        report["input"]["triangles"], ref_report["input"]["triangles"],
        "{label}: triangle count"
    );
    let (want, mut got) = (elements_of(&ref_dir), elements_of(&dir));
    // Unnamed nodes are known by their index path (`node0`), and a compressor renumbers nodes:
    // a model of unnamed nodes only (LoD3_Railway) is compared element by element in order.
    let unnamed = |e: &Elements| e.keys().all(|k| k.starts_with("node"));
    if unnamed(&want) && unnamed(&got) && want.len() == got.len() {
        got = want.keys().cloned().zip(got.into_values()).collect();
    }
    assert_eq!(
        want.keys().collect::<Vec<_>>(),
        got.keys().collect::<Vec<_>>(),
        "{label}: the same element ids"
    );
    let mut worst: f64 = 0.0;
    for (id, (tris, lo, hi)) in &want {
        let (g_tris, g_lo, g_hi) = &got[id];
        assert_eq!(tris, g_tris, "{label}: {id} triangles");
        let d = (*lo - *g_lo).abs().max((*hi - *g_hi).abs()).max_element();
        worst = worst.max(d);
        assert!(
            d <= tolerance_m,
            "{label}: {id} box moved by {d} m (> {tolerance_m})"
        );
    }
    eprintln!(
        "{label}: {} elements, {} triangles, worst box corner {:.2} mm",
        want.len(),
        ref_report["input"]["triangles"],
        worst * 1000.0
    );
    gltf_validator(&dir);
}

/// The model's largest extent, from the reference conversion's root box.
fn extent_m(model: &Path, label: &str) -> f64 {
    let (_, dir) = convert_plain(model, &format!("compressed-{label}-extent"));
    let (_, tiles) = decode_tileset(&dir);
    (tiles[0].box_max - tiles[0].box_min).max_element()
}

#[test]
fn draco_compressed_shared_models_give_the_same_elements() {
    let Some(tool) = npm_tool("gltf-pipeline") else {
        return;
    };
    for name in ["AC20-FZK-Haus", "duplex", "LoD3_Railway"] {
        let Some(model) = shared_file(&format!("{name}.glb")) else {
            continue;
        };
        let dir = tmpdir(&format!("compressed-src-draco-{name}"));
        let out = dir.join(format!("{name}.draco.glb"));
        // gltf-pipeline's defaults: 11-bit positions over each mesh's extent.
        compress(
            &tool,
            &[
                "-i",
                model.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
                "-d",
            ],
        );
        let extent = extent_m(&model, &format!("draco-{name}"));
        compare(&model, &out, &format!("draco-{name}"), extent / 2047.0);
    }
}

#[test]
fn meshopt_quantized_shared_models_give_the_same_elements() {
    let Some(tool) = npm_tool("gltfpack") else {
        return;
    };
    for name in ["AC20-FZK-Haus", "duplex", "LoD3_Railway"] {
        let Some(model) = shared_file(&format!("{name}.glb")) else {
            continue;
        };
        let dir = tmpdir(&format!("compressed-src-meshopt-{name}"));
        let out = dir.join(format!("{name}.meshopt.glb"));
        // -cc: meshopt with filters; quantized attributes (KHR_mesh_quantization) and UVs
        // dequantized by KHR_texture_transform; -kn/-km/-ke keep every named node (the
        // elements), material and extras.
        compress(
            &tool,
            &[
                "-i",
                model.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
                "-cc",
                "-kn",
                "-km",
                "-ke",
            ],
        );
        let json = glb_json(&std::fs::read(&out).unwrap());
        let used: Vec<&str> = json["extensionsUsed"]
            .as_array()
            .unwrap()
            .iter()
            .filter_map(Value::as_str)
            .collect();
        assert!(used.contains(&"EXT_meshopt_compression"), "{used:?}");
        assert!(used.contains(&"KHR_mesh_quantization"), "{used:?}");
        // gltfpack's default 14-bit positions over the model's extent.
        let extent = extent_m(&model, &format!("meshopt-{name}"));
        compare(&model, &out, &format!("meshopt-{name}"), extent / 16383.0);
    }
}

#[test]
fn an_unknown_required_extension_is_named_and_an_unknown_used_one_is_ignored() {
    let base = triangle_glb([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], None);
    let (mut json, bin) = glb_chunks(&base);
    let dir = tmpdir("compressed-unknown-ext");
    json["extensionsUsed"] = serde_json::json!(["EXT_made_up"]);
    let used = dir.join("used.glb");
    std::fs::write(&used, glb(&serde_json::to_vec(&json).unwrap(), &bin)).unwrap();
    convert(&used, &dir.join("used"), &[]);
    json["extensionsRequired"] = serde_json::json!(["EXT_made_up"]);
    let required = dir.join("required.glb");
    std::fs::write(&required, glb(&serde_json::to_vec(&json).unwrap(), &bin)).unwrap();
    let o = run(&[
        "convert",
        required.to_str().unwrap(),
        "--out",
        dir.join("required").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("required.glb") && err.contains("EXT_made_up") && err.lines().count() == 1,
        "{err}"
    );
}
