//! CityJSON input (issue 31) with the real binary on the real datasets of
//! ../shared/data/cityjson/: every CityObject with surface geometry is one element (counted here
//! from the JSON, independently of the reader); every triangle is written once; the triangles
//! cover each object's polygons (area of the highest LoD's polygons, holes subtracted, computed
//! here with Newell's formula, against the area of the tiles' triangles); semantic surfaces are
//! materials named by their type; gltf-validator and the 3D Tiles schemas pass.

mod common;
use common::*;
use glam::DVec3;
use serde_json::Value;
use std::path::{Path, PathBuf};

const DATASETS: &[&str] = &[
    "fzk-haus-lod2-textured/01-FZK-Haus-LoD2-Tex-no-Storey-CG30-V01_formatted.json",
    "denhaag-lod2/DenHaag_01.json",
    "3dbag-5907-subset/3dbag_v210908_fd2cee53_5907_subset.json",
    "delfshaven-lod2-textured/3-20-DELFSHAVEN.city.json",
    "zurich-lod2-subset/zurich_subset_lod2.json",
    "delft-lod1-mixed/delft.json",
    "seq-france-tile/tile_00000.city.jsonl",
    "railway-lod3-seq-textured/railway_appearance.city.jsonl",
];

fn dataset(rel: &str) -> Option<PathBuf> {
    let p = shared_data()?.join("cityjson").join(rel);
    if p.is_file() {
        return Some(p);
    }
    assert!(!tools_required(), "{} is missing", p.display());
    None
}

/// The documents of a file: one for CityJSON, the features of a CityJSONSeq (with the header's
/// transform).
fn documents(path: &Path) -> (Value, Vec<Value>) {
    let text = std::fs::read_to_string(path).unwrap();
    if path.extension().is_some_and(|e| e == "jsonl") {
        let mut lines = text.lines().filter(|l| !l.trim().is_empty());
        let header: Value = serde_json::from_str(lines.next().unwrap()).unwrap();
        let features = lines.map(|l| serde_json::from_str(l).unwrap()).collect();
        (header, features)
    } else {
        let doc: Value = serde_json::from_str(&text).unwrap();
        (doc.clone(), vec![doc])
    }
}

fn lod(g: &Value) -> f64 {
    match &g["lod"] {
        Value::String(s) => s.parse().unwrap(),
        v => v.as_f64().unwrap_or(0.0),
    }
}

/// Area of one polygon (rings of real-world points): outer ring minus holes, by Newell.
fn polygon_area(rings: &[Vec<DVec3>]) -> f64 {
    let ring_area = |r: &Vec<DVec3>| -> DVec3 {
        (0..r.len())
            .map(|k| r[k].cross(r[(k + 1) % r.len()]))
            .sum::<DVec3>()
            / 2.0
    };
    let outer = ring_area(&rings[0]);
    let n = outer.normalize_or_zero();
    let holes: f64 = rings[1..].iter().map(|r| ring_area(r).dot(n).abs()).sum();
    outer.length() - holes
}

/// (objects with surface geometry, total polygon area of their highest LoD).
fn expected(path: &Path) -> (usize, f64) {
    let (header, docs) = documents(path);
    let scale = header["transform"]["scale"]
        .as_array()
        .map(|a| {
            DVec3::new(
                a[0].as_f64().unwrap(),
                a[1].as_f64().unwrap(),
                a[2].as_f64().unwrap(),
            )
        })
        .unwrap_or(DVec3::ONE);
    let translate = header["transform"]["translate"]
        .as_array()
        .map(|a| {
            DVec3::new(
                a[0].as_f64().unwrap(),
                a[1].as_f64().unwrap(),
                a[2].as_f64().unwrap(),
            )
        })
        .unwrap_or(DVec3::ZERO);
    let (mut count, mut area) = (0, 0.0);
    for doc in docs {
        let vertices: Vec<DVec3> = doc["vertices"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| {
                DVec3::new(
                    v[0].as_f64().unwrap(),
                    v[1].as_f64().unwrap(),
                    v[2].as_f64().unwrap(),
                ) * scale
                    + translate
            })
            .collect();
        for object in doc["CityObjects"].as_object().unwrap().values() {
            let surface_geometries: Vec<&Value> = object["geometry"]
                .as_array()
                .into_iter()
                .flatten()
                .filter(|g| {
                    [
                        "MultiSurface",
                        "CompositeSurface",
                        "Solid",
                        "MultiSolid",
                        "CompositeSolid",
                    ]
                    .contains(&g["type"].as_str().unwrap_or(""))
                })
                .collect();
            let best = surface_geometries
                .iter()
                .map(|g| lod(g))
                .fold(f64::NEG_INFINITY, f64::max);
            let mut object_area = 0.0;
            for g in surface_geometries.iter().filter(|g| lod(g) == best) {
                let depth = match g["type"].as_str().unwrap() {
                    "MultiSurface" | "CompositeSurface" => 0,
                    "Solid" => 1,
                    _ => 2,
                };
                let mut level: Vec<&Value> = vec![&g["boundaries"]];
                for _ in 0..depth {
                    level = level.iter().flat_map(|v| v.as_array().unwrap()).collect();
                }
                for surface in level.iter().flat_map(|v| v.as_array().unwrap()) {
                    let rings: Vec<Vec<DVec3>> = surface
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(|r| {
                            r.as_array()
                                .unwrap()
                                .iter()
                                .map(|i| vertices[i.as_u64().unwrap() as usize])
                                .collect()
                        })
                        .collect();
                    // Relative to the first point, for precision on projected coordinates.
                    let o = rings[0][0];
                    let rel: Vec<Vec<DVec3>> = rings
                        .iter()
                        .map(|r| r.iter().map(|p| *p - o).collect())
                        .collect();
                    object_area += polygon_area(&rel);
                }
            }
            if object_area > 0.0 {
                count += 1;
                area += object_area;
            }
        }
    }
    (count, area)
}

#[test]
fn every_cityjson_dataset_converts_with_its_objects_and_areas() {
    for rel in DATASETS {
        let Some(path) = dataset(rel) else {
            continue;
        };
        let name = rel.split('/').next().unwrap();
        let out = tmpdir(&format!("cityjson-{name}")).join("tiles");
        let report = convert(&path, &out, &["--lod", "none", "--no-dedup"]);
        let (objects, polygon_area_m2) = expected(&path);
        assert_eq!(
            report["input"]["components"].as_u64().unwrap() as usize,
            objects,
            "{name}: one element per CityObject with surface geometry"
        );
        let tris = report["input"]["triangles"].as_u64().unwrap() as usize;
        let tiles = check_tileset(&out, tris);
        let area: f64 = tiles.iter().map(|t| t.area).sum();
        let rel_diff = (area - polygon_area_m2).abs() / polygon_area_m2;
        eprintln!(
            "{name}: {objects} elements, {tris} triangles, area {area:.1} m² vs polygons {polygon_area_m2:.1} m² ({:.4} %)",
            rel_diff * 100.0
        );
        assert!(
            rel_diff < 2e-3,
            "{name}: triangles cover the polygons ({rel_diff})"
        );
        gltf_validator(&out);
    }
}

#[test]
fn semantic_surfaces_are_materials_named_by_their_type() {
    let Some(path) =
        dataset("fzk-haus-lod2-textured/01-FZK-Haus-LoD2-Tex-no-Storey-CG30-V01_formatted.json")
    else {
        return;
    };
    let out = tmpdir("cityjson-semantics").join("tiles");
    convert(&path, &out, &["--lod", "none", "--compression", "none"]);
    let (_, tiles) = decode_tileset(&out);
    let mut names = std::collections::BTreeSet::new();
    for uri in tiles.iter().filter_map(|t| t.uri.as_ref()) {
        let json = glb_json(&std::fs::read(out.join(uri)).unwrap());
        for m in json["materials"].as_array().into_iter().flatten() {
            names.insert(m["name"].as_str().unwrap_or("").to_string());
        }
    }
    for s in ["RoofSurface", "WallSurface", "GroundSurface"] {
        assert!(names.contains(s), "{s} in {names:?}");
    }
}

#[test]
fn a_broken_cityjson_gives_one_line_naming_the_file() {
    let dir = tmpdir("cityjson-bad");
    let bad = dir.join("bad.city.json");
    std::fs::write(
        &bad,
        r#"{"type":"CityJSON","version":"2.0","vertices":[[0,0,0]],"CityObjects":{"x":{"type":"Building","geometry":[{"type":"MultiSurface","lod":"1","boundaries":[[[0,1,9]]]}]}}}"#,
    )
    .unwrap();
    let o = run(&[
        "convert",
        bad.to_str().unwrap(),
        "--out",
        dir.join("out").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("bad.city.json") && err.contains("CityObject x") && err.lines().count() == 1,
        "{err}"
    );
}
