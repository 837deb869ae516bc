//! `--client` profiles: each one's tileset passes the 3D Tiles schemas and gltf-validator, holds
//! none of the packagings its client cannot load, and carries the same elements, triangles and
//! property values as the default (`cesium`) one, read back with the `gltf` crate and our own
//! decoding of the property tables. The bytes and requests each profile costs are printed.

use crate::common::*;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

const PROFILES: [&str; 4] = ["cesium", "three", "deckgl", "portable"];

/// Element id → (triangles drawn, property name → value as text) over every full-detail tile
/// (geometricError 0) of a tileset. Values equal to their property's `noData` are left out (a
/// table that shares schema.json writes them where another profile's inline schema leaves the
/// property out: the same "no value").
type Elements = BTreeMap<String, (usize, BTreeMap<String, String>)>;

/// The bytes of the buffer view `index` of a plain GLB.
fn view<'a>(doc: &Value, blob: &'a [u8], index: &Value) -> &'a [u8] {
    let v = &doc["bufferViews"][index.as_u64().unwrap() as usize];
    let off = v["byteOffset"].as_u64().unwrap_or(0) as usize;
    &blob[off..off + v["byteLength"].as_u64().unwrap() as usize]
}

/// Little-endian unsigned integer `i` of `size` bytes in `bytes`.
fn uint(bytes: &[u8], i: usize, size: usize) -> usize {
    bytes[i * size..(i + 1) * size]
        .iter()
        .rev()
        .fold(0, |a, &b| a << 8 | b as usize)
}

/// Every column of a property table, decoded by the types its schema declares, as text per
/// row; `None` where the row holds the property's `noData`.
fn table_rows(
    doc: &Value,
    blob: &[u8],
    table: &Value,
    schema: &Value,
) -> Vec<BTreeMap<String, String>> {
    let rows = table["count"].as_u64().unwrap() as usize;
    let class = &schema["classes"][table["class"].as_str().unwrap()]["properties"];
    let mut out = vec![BTreeMap::new(); rows];
    for (name, prop) in table["properties"].as_object().unwrap() {
        let def = &class[name];
        let no_data = &def["noData"];
        let values = view(doc, blob, &prop["values"]);
        for (r, row) in out.iter_mut().enumerate() {
            let v: Value = match def["type"].as_str().unwrap() {
                "STRING" => {
                    let size = match prop["stringOffsetType"].as_str().unwrap_or("UINT32") {
                        "UINT8" => 1,
                        "UINT16" => 2,
                        _ => 4,
                    };
                    let offsets = view(doc, blob, &prop["stringOffsets"]);
                    let s = &values[uint(offsets, r, size)..uint(offsets, r + 1, size)];
                    Value::from(String::from_utf8(s.to_vec()).unwrap())
                }
                "ENUM" => {
                    let e = &schema["enums"][def["enumType"].as_str().unwrap()];
                    let size = match e["valueType"].as_str().unwrap_or("UINT16") {
                        "UINT8" => 1,
                        "UINT16" => 2,
                        other => panic!("enum valueType {other}"),
                    };
                    let code = uint(values, r, size) as u64;
                    e["values"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .find(|v| v["value"].as_u64() == Some(code))
                        .map(|v| v["name"].clone())
                        .unwrap_or_else(|| panic!("{name}: code {code} not in its enum"))
                }
                "SCALAR" => {
                    assert_eq!(def["componentType"], "FLOAT64", "{name}");
                    let x = f64::from_le_bytes(values[r * 8..r * 8 + 8].try_into().unwrap());
                    Value::from(x)
                }
                other => panic!("{name}: type {other}"),
            };
            if v != *no_data {
                row.insert(name.clone(), v.to_string());
            }
        }
    }
    out
}

/// What [`Elements`] says of the tileset in `dir`.
fn elements_of(dir: &Path) -> Elements {
    let (_, tiles) = decode_tileset(dir);
    let mut out = Elements::new();
    for t in tiles.iter().filter(|t| t.geometric_error == 0.0) {
        let Some(uri) = &t.uri else { continue };
        let bytes = read_content(dir, uri);
        let (doc, blob) = glb_chunks(&bytes);
        let g = gltf::Gltf::from_slice_without_validation(&bytes).unwrap();
        let schema = tile_schema(dir, uri);
        let tables: Vec<Vec<BTreeMap<String, String>>> = doc["extensions"]
            ["EXT_structural_metadata"]["propertyTables"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| table_rows(&doc, &blob, t, &schema))
            .collect();
        for (mesh, placement) in drawn_meshes(&g, &doc, &blob) {
            for p in mesh.primitives() {
                let (pos, idx) = primitive_geometry(&g, &blob, &p);
                let prim = &doc["meshes"][mesh.index()]["primitives"][p.index()];
                let ext = &prim["extensions"]["EXT_mesh_features"]["featureIds"][0];
                // An instanced mesh takes its ids from the node (`EXT_instance_features`), into
                // the tile's one table.
                let table = match ext["propertyTable"].as_u64() {
                    Some(t) => &tables[t as usize],
                    None => {
                        assert!(placement.instance_feature.is_some() && tables.len() == 1);
                        &tables[0]
                    }
                };
                let features: Vec<usize> = match placement.instance_feature {
                    Some(f) => vec![f as usize; pos.len()],
                    None => {
                        let acc = prim["attributes"]["_FEATURE_ID_0"].as_u64().unwrap();
                        read_accessor(&doc, &blob, acc as usize)
                            .into_iter()
                            .map(|v| v[0] as usize)
                            .collect()
                    }
                };
                for tri in idx.chunks_exact(3) {
                    let row = &table[features[tri[0] as usize]];
                    let e = out
                        .entry(row["id"].clone())
                        .or_insert_with(|| (0, row.clone()));
                    assert_eq!(&e.1, row, "{uri}: one element, two rows");
                    e.0 += 1;
                }
            }
        }
    }
    out
}

/// Bytes of every file a client may fetch (tileset.json, tiles, schema.json, textures), their
/// gzip size, and how many files that is.
fn transfer(dir: &Path) -> (u64, u64, usize) {
    use std::io::Write;
    let mut files = vec![dir.join("tileset.json")];
    let mut stack: Vec<PathBuf> = ["tiles", "textures"].iter().map(|d| dir.join(d)).collect();
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            match e.path().is_dir() {
                true => stack.push(e.path()),
                false => files.push(e.path()),
            }
        }
    }
    if dir.join("schema.json").is_file() {
        files.push(dir.join("schema.json"));
    }
    let (mut bytes, mut gz) = (0, 0);
    for f in &files {
        let b = std::fs::read(f).unwrap();
        let mut z = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::new(6));
        z.write_all(&b).unwrap();
        bytes += b.len() as u64;
        gz += z.finish().unwrap().len() as u64;
    }
    (bytes, gz, files.len())
}

/// The structural promises of one profile's tileset.
fn check_profile(dir: &Path, profile: &str, report: &Value) {
    assert_eq!(report["options"]["client"], profile);
    let ts: Value = serde_json::from_slice(&std::fs::read(dir.join("tileset.json")).unwrap())
        .expect("tileset.json");
    if let Some(errors) = tileset_schema_errors(&ts) {
        assert!(errors.is_empty(), "{profile}: {errors:?}");
    }
    gltf_validator(dir);
    let (_, tiles) = decode_tileset(dir);
    let uris: Vec<&String> = tiles.iter().filter_map(|t| t.uri.as_ref()).collect();
    assert!(!uris.is_empty());
    let all_in_one = matches!(profile, "deckgl" | "portable");
    let no_instancing = profile != "cesium";
    assert_eq!(
        report["options"]["schema_in_every_tile"], all_in_one,
        "{profile}"
    );
    if all_in_one {
        assert!(!dir.join("schema.json").exists(), "{profile}: schema.json");
    }
    for uri in uris {
        if all_in_one {
            assert!(!uri.starts_with("data:"), "{profile}: root inlined");
        }
        let json = glb_json(&content_bytes(dir, uri));
        let used = json["extensionsUsed"].to_string();
        if no_instancing {
            assert!(
                !used.contains("EXT_mesh_gpu_instancing"),
                "{profile}: {uri} instanced"
            );
        }
        if all_in_one {
            assert!(!used.contains("KHR_draco_mesh_compression"), "{profile}");
            let ext = &json["extensions"]["EXT_structural_metadata"];
            assert!(
                ext.get("schemaUri").is_none() && ext["schema"].is_object(),
                "{profile}: {uri} has no inline schema"
            );
            // Materials kept: no vertex colours standing for them.
            for m in json["meshes"].as_array().unwrap() {
                for p in m["primitives"].as_array().unwrap() {
                    assert!(
                        p["attributes"].get("COLOR_0").is_none(),
                        "{profile}: {uri}: COLOR_0"
                    );
                }
            }
        }
    }
}

/// Every profile on models that exercise what the profiles change: GPU instancing and a shared
/// schema.json (the Mini_Project steel roof), a root inlined in tileset.json (the duplex).
#[test]
fn every_profile_packages_the_same_elements_for_its_client() {
    for name in ["ISSUE_021_Mini_Project.glb", "duplex.glb"] {
        let Some(model) = shared_file(name) else {
            return;
        };
        let mut cesium: Option<(Elements, (u64, u64, usize))> = None;
        for profile in PROFILES {
            let out = tmpdir(&format!("clients-{name}-{profile}")).join("tiles");
            let report = convert(&model, &out, &["--client", profile]);
            check_profile(&out, profile, &report);
            let elements = elements_of(&out);
            let cost = transfer(&out);
            assert!(!elements.is_empty(), "{name} {profile}: no elements");
            match &cesium {
                None => cesium = Some((elements, cost)),
                Some((base, base_cost)) => {
                    assert_eq!(
                        elements.keys().collect::<Vec<_>>(),
                        base.keys().collect::<Vec<_>>(),
                        "{name} {profile}: element ids"
                    );
                    for (id, (tris, props)) in &elements {
                        assert_eq!(&base[id].0, tris, "{name} {profile}: {id} triangles");
                        assert_eq!(&base[id].1, props, "{name} {profile}: {id} properties");
                    }
                    eprintln!(
                        "{name} --client {profile}: {} bytes ({:+}), gzip {} ({:+}), {} files ({:+}) against cesium",
                        cost.0,
                        cost.0 as i64 - base_cost.0 as i64,
                        cost.1,
                        cost.1 as i64 - base_cost.1 as i64,
                        cost.2,
                        cost.2 as i64 - base_cost.2 as i64
                    );
                }
            }
        }
    }
}

/// Draco with a profile whose client loses its feature ids is refused in one line naming the
/// option; the same with cesium or three converts.
#[test]
fn draco_with_deckgl_is_refused_in_one_line() {
    let dir = tmpdir("clients-draco");
    for profile in ["deckgl", "portable"] {
        let o = run(&[
            "convert",
            sample().to_str().unwrap(),
            "--out",
            dir.join(profile).to_str().unwrap(),
            "--client",
            profile,
            "--compression",
            "draco",
            "--quiet",
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{profile}");
        assert!(
            err.contains("--client") && err.contains("draco") && err.trim().lines().count() == 1,
            "{profile}: {err}"
        );
        assert!(!dir.join(profile).join("tileset.json").exists());
    }
    let out = dir.join("three");
    let report = convert(
        &sample(),
        &out,
        &["--client", "three", "--compression", "draco"],
    );
    assert_eq!(report["options"]["compression"], "draco");
    assert_eq!(report["options"]["instancing"], false);
}
