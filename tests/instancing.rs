//! Dedup and instancing end to end (issue 5): the real binary converts a model, and the tiles are
//! read back with the `gltf` crate and our own accessor reader (no writer code): every
//! `EXT_mesh_gpu_instancing` instance is expanded to world geometry and, feature by feature (ids
//! from the tiles' property tables), compared triangle by triangle with the input components, read
//! independently from the input GLB. Every input element must be drawn exactly once, under its own
//! id, or be listed once as an alias of an element drawn with the same geometry.

use crate::common::*;
use glam::DVec3;
use serde_json::Value;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// Dedup's tolerance (1 mm) plus f32 rounding of tile-relative positions.
const TOL_M: f64 = 0.0011;

type Tri = [DVec3; 3];

/// Input components by element id, as world triangles (scene frame, z-up), read with the gltf
/// crate.
fn input_components(path: &Path) -> BTreeMap<String, Vec<Tri>> {
    let bytes = std::fs::read(path).unwrap();
    let g = gltf::Gltf::from_slice_without_validation(&bytes).expect("input reads");
    let (doc, blob) = (&g.document, g.blob.as_deref().expect("a GLB input"));
    let ids = expected_element_ids(doc);
    let mut out: BTreeMap<String, Vec<Tri>> = BTreeMap::new();
    for (node, world) in world_nodes(scene_roots(doc), Y_UP_TO_Z_UP) {
        let Some(mesh) = node.mesh() else { continue };
        let key = ids[&node.index()].clone();
        let tris = out.entry(key.clone()).or_default();
        assert!(tris.is_empty(), "{key}: element ids are unique");
        let flip = glam::DMat3::from_mat4(world).determinant() < 0.0;
        for p in mesh.primitives() {
            let r = p.reader(|_| Some(blob));
            let pos: Vec<DVec3> = r
                .read_positions()
                .unwrap()
                .map(|v| world.transform_point3(DVec3::from_array(v.map(f64::from))))
                .collect();
            let idx: Vec<u32> = match r.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..pos.len() as u32).collect(),
            };
            for t in idx.chunks_exact(3) {
                let [a, b, c] = [0, 1, 2].map(|k| pos[t[k] as usize]);
                tris.push(if flip { [a, c, b] } else { [a, b, c] });
            }
        }
    }
    out
}

/// The strings of a STRING column of a property table (UINT32 offsets unless said otherwise).
fn string_column(doc: &Value, blob: &[u8], prop: &Value, count: usize) -> Vec<String> {
    let view = |i: &Value| {
        let v = &doc["bufferViews"][i.as_u64().unwrap() as usize];
        let o = v["byteOffset"].as_u64().unwrap_or(0) as usize;
        &blob[o..o + v["byteLength"].as_u64().unwrap() as usize]
    };
    let values = view(&prop["values"]);
    let offsets = view(&prop["stringOffsets"]);
    let size = match prop["stringOffsetType"].as_str().unwrap_or("UINT32") {
        "UINT8" => 1,
        "UINT16" => 2,
        "UINT32" => 4,
        t => panic!("offset type {t}"),
    };
    let at = |i: usize| {
        let b = &offsets[i * size..(i + 1) * size];
        b.iter().rev().fold(0usize, |a, &x| a * 256 + x as usize)
    };
    (0..count)
        .map(|i| String::from_utf8(values[at(i)..at(i + 1)].to_vec()).unwrap())
        .collect()
}

/// What the tileset draws, per element id (world triangles, scene frame), the aliases it lists
/// (alias id → kept id), and how many instances and instanced nodes it has.
struct Drawn {
    by_id: BTreeMap<String, Vec<Tri>>,
    aliases: BTreeMap<String, String>,
    instances: usize,
}

fn drawn(dir: &Path, anchor: DVec3) -> Drawn {
    let (_, tiles) = decode_tileset(dir);
    let mut d = Drawn {
        by_id: BTreeMap::new(),
        aliases: BTreeMap::new(),
        instances: 0,
    };
    for uri in tiles.iter().filter_map(|t| t.uri.as_ref()) {
        let bytes = read_content(dir, uri);
        let g = gltf::Gltf::from_slice_without_validation(&bytes).unwrap();
        let blob = g.blob.as_deref().unwrap();
        let doc = glb_json(&bytes);
        let table = &doc["extensions"]["EXT_structural_metadata"]["propertyTables"][0];
        let count = table["count"].as_u64().unwrap() as usize;
        let ids = string_column(&doc, blob, &table["properties"]["id"], count);
        if let Some(a) = table["properties"].get("aliases") {
            for (kept, list) in ids.iter().zip(string_column(&doc, blob, a, count)) {
                // No aliases: the empty string (noData); else a JSON array of ids.
                let ids: Vec<String> = match list.as_str() {
                    "" => Vec::new(),
                    l => serde_json::from_str(l).expect("aliases: a JSON array"),
                };
                for alias in &ids {
                    let old = d.aliases.insert(alias.to_string(), kept.clone());
                    assert!(
                        old.is_none() || old.as_ref() == Some(kept),
                        "{alias} listed as an alias of two elements"
                    );
                }
            }
        }
        for (mesh, placement) in drawn_meshes(&g, &doc, blob) {
            let m = Y_UP_TO_Z_UP * placement.matrix;
            if placement.instance_feature.is_some() {
                d.instances += 1;
            }
            for p in mesh.primitives() {
                assert!(
                    p.extension_value("KHR_draco_mesh_compression").is_none(),
                    "this test reads plain tiles"
                );
                let (pos, idx) = primitive_geometry(&g, blob, &p);
                let fids: Vec<u32> = match placement.instance_feature {
                    Some(f) => vec![f; pos.len()],
                    None => {
                        let a = doc["meshes"][mesh.index()]["primitives"][p.index()]["attributes"]
                            ["_FEATURE_ID_0"]
                            .as_u64()
                            .expect("plain primitives carry feature IDs");
                        read_accessor(&doc, blob, a as usize)
                            .iter()
                            .map(|v| v[0] as u32)
                            .collect()
                    }
                };
                let world: Vec<DVec3> = pos
                    .iter()
                    .map(|v| m.transform_point3(DVec3::from_array(v.map(f64::from))) + anchor)
                    .collect();
                for t in idx.chunks_exact(3) {
                    let f = fids[t[0] as usize];
                    assert!(
                        t.iter().all(|&i| fids[i as usize] == f),
                        "one feature per triangle"
                    );
                    d.by_id
                        .entry(ids[f as usize].clone())
                        .or_default()
                        .push([0, 1, 2].map(|k| world[t[k] as usize]));
                }
            }
        }
    }
    d
}

/// Whether two triangle sets are the same within `TOL_M` (same count; every triangle of `a`
/// matched by a distinct triangle of `b` with the same corners in the same winding).
fn same_triangles(a: &[Tri], b: &[Tri]) -> Result<(), String> {
    if a.len() != b.len() {
        return Err(format!("{} triangles vs {}", a.len(), b.len()));
    }
    let cell = |p: DVec3| (p / 0.01).floor().as_i64vec3().to_array();
    let centroid = |t: &Tri| (t[0] + t[1] + t[2]) / 3.0;
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, t) in b.iter().enumerate() {
        grid.entry(cell(centroid(t))).or_default().push(i);
    }
    let mut used = vec![false; b.len()];
    for t in a {
        let c = cell(centroid(t));
        // The closest unused candidate (tiny triangles of one element can lie within the
        // tolerance of each other: the first one in range may belong to another).
        let mut found: Option<(usize, f64)> = None;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    for &j in grid
                        .get(&[c[0] + dx, c[1] + dy, c[2] + dz])
                        .into_iter()
                        .flatten()
                    {
                        let u = &b[j];
                        let dist = (0..3)
                            .map(|r| {
                                (0..3)
                                    .map(|k| t[k].distance(u[(k + r) % 3]))
                                    .fold(0.0, f64::max)
                            })
                            .fold(f64::INFINITY, f64::min);
                        if !used[j] && dist <= TOL_M && found.is_none_or(|(_, d)| dist < d) {
                            found = Some((j, dist));
                        }
                    }
                }
            }
        }
        let found = found.map(|(j, _)| j);
        match found {
            Some(j) => used[j] = true,
            None => {
                let nearest = b
                    .iter()
                    .map(|u| (0..3).map(|k| t[k].distance(u[k])).fold(0.0, f64::max))
                    .fold(f64::INFINITY, f64::min);
                return Err(format!(
                    "no match for triangle {t:?} (nearest differs by {nearest:.6} m at some corner)"
                ));
            }
        }
    }
    Ok(())
}

/// Converts `model` with instancing forced on every repeated shape, and checks identity and
/// geometry of every element; returns (elements, instances, aliases).
fn check_model(model: &Path, name: &str) -> (usize, usize, usize) {
    let out = tmpdir(&format!("instancing-{name}")).join("tiles");
    let report = convert(
        model,
        &out,
        &[
            "--compression",
            "none",
            "--lod",
            "none",
            "--max-tile-triangles",
            "4000",
            "--min-instanced-triangles-saved",
            "0",
        ],
    );
    let anchor = DVec3::from_array(
        serde_json::from_value::<[f64; 3]>(report["georeference"]["anchor_m"].clone()).unwrap(),
    );
    let input = input_components(model);
    let d = drawn(&out, anchor);
    assert_eq!(
        report["output"]["instances"].as_u64().unwrap() as usize,
        d.instances,
        "{name}: the report counts the instances the tiles hold"
    );
    for (key, tris) in &input {
        let drawn_as = match (d.by_id.get(key), d.aliases.get(key)) {
            (Some(t), None) => t,
            (None, Some(kept)) => d.by_id.get(kept).unwrap_or_else(|| {
                panic!("{name}: {key} is an alias of {kept}, which is not drawn")
            }),
            (Some(_), Some(_)) => panic!("{name}: {key} is drawn and also an alias"),
            (None, None) => panic!("{name}: input element {key} is neither drawn nor an alias"),
        };
        if let Err(e) = same_triangles(tris, drawn_as) {
            panic!("{name}: element {key} differs from the input: {e}");
        }
    }
    for id in d.by_id.keys() {
        assert!(
            input.contains_key(id),
            "{name}: drawn id {id} is not an input element"
        );
    }
    tileset_checks(&out, &report);
    (input.len(), d.instances, d.aliases.len())
}

fn tileset_checks(out: &Path, report: &Value) {
    check_tileset(out, report["input"]["triangles"].as_u64().unwrap() as usize);
    if let Some((_, errors, _)) = gltf_validator(out) {
        assert_eq!(errors, 0, "gltf-validator errors in {}", out.display());
    }
}

#[test]
fn sample_instances_expand_to_the_input_elements() {
    let (elements, instances, aliases) = check_model(&sample(), "sample");
    let expect: Value = serde_json::from_slice(
        &std::fs::read(repo().join("samples/sample_building.expect.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(elements, expect["components"].as_u64().unwrap() as usize);
    assert_eq!(
        aliases,
        expect["exact_duplicates"].as_u64().unwrap() as usize
    );
    // The baked copies and glTF-level reuse are drawn as instances, not as copies.
    assert!(
        instances >= expect["gltf_instances"].as_u64().unwrap() as usize,
        "{instances} instances"
    );
}

#[test]
fn shared_models_instances_expand_to_the_input_elements() {
    for model in shared_models() {
        let name = model.file_stem().unwrap().to_string_lossy().to_string();
        let (elements, instances, aliases) = check_model(&model, &name);
        eprintln!("{name}: {elements} elements, {instances} instances, {aliases} aliases");
    }
}

#[test]
fn no_instancing_writes_plain_geometry_and_default_output_is_valid() {
    // Without instancing: no extension, same drawn triangles.
    let out = tmpdir("instancing-off").join("tiles");
    let report = convert(&sample(), &out, &["--no-instancing"]);
    assert_eq!(report["output"]["instances"], 0);
    for f in std::fs::read_dir(out.join("tiles")).unwrap() {
        let bytes = std::fs::read(f.unwrap().path()).unwrap();
        let doc = glb_json(&bytes);
        assert!(!doc["extensionsUsed"]
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e == "EXT_mesh_gpu_instancing"));
    }
    tileset_checks(&out, &report);
    // Default settings (Draco, HLOD) with instances: the structure holds and the instanced
    // leaves decode to the same number of drawn triangles.
    let out = tmpdir("instancing-default").join("tiles");
    let report = convert(&sample(), &out, &["--max-tile-triangles", "4000"]);
    assert!(report["output"]["instances"].as_u64().unwrap() > 0);
    tileset_checks(&out, &report);
}

#[test]
fn removed_duplicates_stay_queryable_as_aliases() {
    let out = tmpdir("instancing-aliases").join("tiles");
    convert(&sample(), &out, &["--max-tile-triangles", "4000"]);
    let expect: Value = serde_json::from_slice(
        &std::fs::read(repo().join("samples/sample_building.expect.json")).unwrap(),
    )
    .unwrap();
    let feature = |id: &str| -> Value {
        let o = run(&["inspect", out.to_str().unwrap(), "--feature", id, "--json"]);
        assert!(
            o.status.success(),
            "inspect --feature {id}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        serde_json::from_slice(&o.stdout).unwrap()
    };
    for pair in expect["exact_duplicate_pairs"].as_array().unwrap() {
        let ids = [
            pair["kept"].as_str().unwrap(),
            pair["duplicate"].as_str().unwrap(),
        ];
        let [a, b] = ids.map(feature);
        // One of the two is drawn; the other is found through it, as its alias.
        let alias_of = |f: &Value| f["properties"]["Alias of"].as_str().map(str::to_string);
        match (alias_of(&a), alias_of(&b)) {
            (None, Some(kept)) => assert_eq!(kept, ids[0]),
            (Some(kept), None) => assert_eq!(kept, ids[1]),
            other => panic!("{ids:?}: expected exactly one alias, got {other:?}"),
        }
        assert_eq!(
            a["tiles"], b["tiles"],
            "the alias is drawn where its element is"
        );
    }
}

/// A GLB whose nodes repeat names the ways exporters do: same-named siblings (the airport's
/// `world/object/object`), a literal `object#1` beside them, an unnamed node, same-named parents,
/// a repeated and a unique GlobalId, a repeated root, and an exact copy whose id holds a space
/// (an alias).
fn repeated_names_glb() -> Vec<u8> {
    let verts: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let at = |name: Option<&str>, x: f64, guid: Option<&str>| {
        let mut n = serde_json::json!({"mesh": 0, "translation": [x, 0.0, 0.0]});
        if let Some(name) = name {
            n["name"] = name.into();
        }
        if let Some(g) = guid {
            n["extras"] = serde_json::json!({"guid": g});
        }
        n
    };
    let repeated_guid = Some("2O2Fr$t4X7Zf8NOew3FLOH");
    let nodes = serde_json::json!([
        {"name": "site", "children": [1, 2, 3, 4, 5, 6, 7, 8, 11, 12, 15]},
        at(Some("object"), 0.0, None),
        at(Some("object"), 10.0, None),
        at(Some("object#1"), 20.0, None),
        at(None, 30.0, None),
        at(Some("object"), 40.0, None),
        {"name": "world", "children": [9]},
        {"name": "world", "children": [10]},
        at(Some("wall"), 50.0, repeated_guid),
        at(Some("object"), 60.0, None),
        at(Some("object"), 70.0, None),
        at(Some("wall"), 80.0, repeated_guid),
        at(Some("door"), 90.0, Some("1CBNfY0004DZ4oDpWmD3am")),
        {"name": "site", "children": [14]},
        at(Some("object"), 100.0, None),
        at(Some("object copy"), 0.0, None),
    ]);
    one_mesh_glb(&verts, None, nodes, &[0, 13])
}

#[test]
fn repeated_sibling_names_give_unique_ids_that_inspect_finds() {
    let dir = tmpdir("ids-repeated-names");
    let model = dir.join("repeated-names.glb");
    std::fs::write(&model, repeated_names_glb()).unwrap();
    let g = gltf::Gltf::from_slice(&std::fs::read(&model).unwrap()).unwrap();
    let expected = expected_element_ids(&g.document);
    // The rule, spelled out for this file (README "Element ids").
    let mut ids: Vec<&str> = expected.values().map(String::as_str).collect();
    ids.sort_unstable();
    assert_eq!(
        ids,
        [
            "1CBNfY0004DZ4oDpWmD3am",
            "site#1/object",
            "site/node4",
            "site/object",
            "site/object copy",
            "site/object#1",
            "site/object#1#1",
            "site/object#2",
            "site/wall",
            "site/wall#1",
            "site/world#1/object",
            "site/world/object",
        ]
    );
    // Every element is drawn (or aliased) once under its id, with its own geometry.
    let (elements, _, aliases) = check_model(&model, "ids-repeated-names");
    assert_eq!((elements, aliases), (12, 1));
    let out = repo().join("target/test-out/instancing-ids-repeated-names/tiles");
    let report: Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    // Renamed: each id that is not the plain GlobalId or the path without numbers.
    assert_eq!(report["input"]["renamed_ids"], 7);
    for id in &ids {
        let o = run(&["inspect", out.to_str().unwrap(), "--feature", id, "--json"]);
        assert!(
            o.status.success(),
            "inspect --feature {id}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let f: Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(f["id"], *id);
        assert!(!f["tiles"].as_array().unwrap().is_empty(), "{id} is drawn");
    }
    // The exact copy is an alias; its id holds a space and still reads back whole.
    let o = run(&[
        "inspect",
        out.to_str().unwrap(),
        "--feature",
        "site/object copy",
        "--json",
    ]);
    let f: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(f["properties"]["Alias of"], "site/object");
    // A path that is no element's id is not found.
    let o = run(&[
        "inspect",
        out.to_str().unwrap(),
        "--feature",
        "site/object#9",
    ]);
    assert!(!o.status.success());
}

#[test]
fn airport_ids_are_unique_and_inspect_finds_the_numbered_ones() {
    let Some(model) = shared_file("phnl_honolulu_airport.glb") else {
        return;
    };
    let g = gltf::Gltf::open(&model).unwrap();
    let expected = expected_element_ids(&g.document);
    let out = tmpdir("ids-airport").join("tiles");
    let report = convert(&model, &out, &["--compression", "none", "--lod", "none"]);
    let numbered: Vec<&String> = expected.values().filter(|id| id.contains('#')).collect();
    assert!(numbered.len() > 100, "{} numbered ids", numbered.len());
    assert_eq!(
        report["input"]["renamed_ids"].as_u64().unwrap() as usize,
        numbered.len()
    );
    for id in numbered.iter().step_by(7) {
        let o = run(&["inspect", out.to_str().unwrap(), "--feature", id, "--json"]);
        assert!(o.status.success(), "inspect --feature {id}");
        let f: Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(f["id"], id.as_str());
    }
}
