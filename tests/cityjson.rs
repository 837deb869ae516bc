//! CityJSON input (issue 31) with the real binary on the real datasets of
//! ../shared/data/cityjson/: every CityObject with surface geometry is one element (counted here
//! from the JSON, independently of the reader); every triangle is written once; the triangles
//! cover each object's polygons (area of the highest LoD's polygons, holes subtracted, computed
//! here with Newell's formula, against the area of the tiles' triangles); semantic surfaces are
//! materials named by their type; gltf-validator and the 3D Tiles schemas pass; `--cityjson-lod`
//! reads one LoD (and names the LoDs present when asked for one no object has); appearance
//! textures reach the tiles with their images and UVs.

use crate::common::*;
use glam::DVec3;
use serde_json::Value;
use std::collections::BTreeMap;
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

/// (objects with surface geometry, total polygon area of their highest LoD, or of LoD `at_lod`).
fn expected(path: &Path, at_lod: Option<f64>) -> (usize, f64) {
    let (header, docs) = documents(path);
    let transform = |key: &str, absent: DVec3| {
        header["transform"][key].as_array().map_or(absent, |a| {
            DVec3::from_array([0, 1, 2].map(|i| a[i].as_f64().unwrap()))
        })
    };
    let (scale, translate) = (
        transform("scale", DVec3::ONE),
        transform("translate", DVec3::ZERO),
    );
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
            let best = at_lod.unwrap_or_else(|| {
                surface_geometries
                    .iter()
                    .map(|g| lod(g))
                    .fold(f64::NEG_INFINITY, f64::max)
            });
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
        let (objects, polygon_area_m2) = expected(&path, None);
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
        let json = glb_json(&content_bytes(&out, uri));
        for m in json["materials"].as_array().into_iter().flatten() {
            names.insert(m["name"].as_str().unwrap_or("").to_string());
        }
    }
    // Textured surfaces are named by their type and image ("WallSurface textures/FZK-Haus-Front.png").
    for s in ["RoofSurface", "WallSurface", "GroundSurface"] {
        assert!(
            names.iter().any(|n| n.split(' ').next() == Some(s)),
            "{s} in {names:?}"
        );
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

#[test]
fn cityjson_lod_reads_one_lod_and_an_unknown_one_names_those_present() {
    let Some(path) = dataset("3dbag-5907-subset/3dbag_v210908_fd2cee53_5907_subset.json") else {
        return;
    };
    let dir = tmpdir("cityjson-lod");
    let out = dir.join("lod12");
    let report = convert(&path, &out, &["--lod", "none", "--cityjson-lod", "1.2"]);
    let (objects, polygon_area_m2) = expected(&path, Some(1.2));
    let (all_objects, _) = expected(&path, None);
    assert!(objects < all_objects, "the Buildings have LoD 0 only");
    assert_eq!(
        report["input"]["components"].as_u64().unwrap() as usize,
        objects
    );
    let tiles = check_tileset(
        &out,
        report["input"]["triangles"].as_u64().unwrap() as usize,
    );
    let area: f64 = tiles.iter().map(|t| t.area).sum();
    assert!(
        (area - polygon_area_m2).abs() / polygon_area_m2 < 2e-3,
        "LoD 1.2 area {area} vs {polygon_area_m2}"
    );
    let warnings = report["warnings"].as_array().unwrap();
    assert!(
        warnings
            .iter()
            .any(|w| w.as_str().unwrap().contains("none at LoD 1.2")),
        "{warnings:?}"
    );

    let missing = dir.join("lod3");
    let o = run(&[
        "convert",
        path.to_str().unwrap(),
        "--out",
        missing.to_str().unwrap(),
        "--cityjson-lod",
        "3",
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("3dbag_v210908") && err.contains("LoD 3") && err.contains("0, 1.2, 1.3, 2.2"),
        "{err}"
    );
    assert!(!missing.exists(), "nothing written");
}

/// An image's size and decoded RGBA8 pixels: what a client draws (a tile may carry an input PNG
/// without the colour-space chunks glTF clients ignore).
fn pixels(bytes: &[u8]) -> Vec<u8> {
    let img = image::load_from_memory(bytes).unwrap().to_rgba8();
    let mut out = [img.width(), img.height()].map(u32::to_le_bytes).concat();
    out.extend_from_slice(img.as_raw());
    out
}

/// Per input image (its bytes), the UVs (glTF convention: v from the top) the file's surfaces
/// give it, read here from the JSON: `appearance.textures`, `vertices-texture`, and each
/// geometry's ring texture values `[texture, uv…]`. Images are keyed by their [`pixels`].
fn input_texture_uvs(path: &Path) -> BTreeMap<Vec<u8>, Vec<[f64; 2]>> {
    fn rings<'v>(v: &'v Value, out: &mut Vec<&'v Vec<Value>>) {
        if let Some(a) = v.as_array() {
            match a.first() {
                Some(Value::Array(_)) => a.iter().for_each(|x| rings(x, out)),
                Some(_) => out.push(a),
                None => {}
            }
        }
    }
    let (header, docs) = documents(path);
    let mut out: BTreeMap<Vec<u8>, Vec<[f64; 2]>> = BTreeMap::new();
    for doc in &docs {
        let appearance = if doc["appearance"].is_object() {
            &doc["appearance"]
        } else {
            &header["appearance"]
        };
        let uvs = appearance["vertices-texture"].as_array();
        let images: Vec<Option<Vec<u8>>> = appearance["textures"]
            .as_array()
            .into_iter()
            .flatten()
            .map(|t| std::fs::read(path.parent().unwrap().join(t["image"].as_str().unwrap())).ok())
            .map(|b| b.map(|b| pixels(&b)))
            .collect();
        for object in doc["CityObjects"].as_object().unwrap().values() {
            for g in object["geometry"].as_array().into_iter().flatten() {
                let Some(themes) = g["texture"].as_object() else {
                    continue;
                };
                for theme in themes.values() {
                    let mut found = Vec::new();
                    rings(&theme["values"], &mut found);
                    for ring in found {
                        let Some(t) = ring[0].as_u64() else { continue };
                        let Some(Some(image)) = images.get(t as usize) else {
                            continue;
                        };
                        let entry = out.entry(image.clone()).or_default();
                        for i in &ring[1..] {
                            let uv = &uvs.unwrap()[i.as_u64().unwrap() as usize];
                            entry.push([uv[0].as_f64().unwrap(), 1.0 - uv[1].as_f64().unwrap()]);
                        }
                    }
                }
            }
        }
    }
    out
}

#[test]
fn cityjson_textures_reach_the_tiles_with_their_images_and_uvs() {
    for rel in [
        "fzk-haus-lod2-textured/01-FZK-Haus-LoD2-Tex-no-Storey-CG30-V01_formatted.json",
        "railway-lod3-seq-textured/railway_appearance.city.jsonl",
    ] {
        let Some(path) = dataset(rel) else {
            continue;
        };
        let name = rel.split('/').next().unwrap();
        let expected_uvs = input_texture_uvs(&path);
        assert!(
            !expected_uvs.is_empty(),
            "{name}: textured surfaces in the input"
        );
        // Plain tiles, no atlas or crop: each textured primitive shows an input image, at UVs
        // the input gives that image.
        let plain = tmpdir(&format!("cityjson-tex-{name}")).join("plain");
        let options = [
            "--lod",
            "none",
            "--compression",
            "none",
            "--texture-atlas",
            "off",
            "--texture-crop",
            "off",
        ];
        convert(&path, &plain, &options);
        let (_, tiles) = decode_tileset(&plain);
        let mut images_seen = std::collections::BTreeSet::new();
        let mut textured_triangles = 0;
        for uri in tiles.iter().filter_map(|t| t.uri.as_ref()) {
            for t in read_textured(&plain, uri) {
                let allowed = expected_uvs
                    .get(&pixels(&t.image))
                    .unwrap_or_else(|| panic!("{name}: a tile image that is no input image"));
                for uv in &t.uvs {
                    let nearest = allowed
                        .iter()
                        .map(|a| (a[0] - uv[0] as f64).hypot(a[1] - uv[1] as f64))
                        .fold(f64::INFINITY, f64::min);
                    assert!(
                        nearest < 1e-5,
                        "{name}: UV {uv:?} is no input UV of its image"
                    );
                }
                textured_triangles += t.indices.len() / 3;
                images_seen.insert(pixels(&t.image));
            }
        }
        assert_eq!(
            images_seen.len(),
            expected_uvs.len(),
            "{name}: every image used by a surface is drawn"
        );
        assert!(textured_triangles > 0);
        // The whole pipeline (HLOD, texture levels, atlas, Draco): textured tiles whose images decode.
        let full = tmpdir(&format!("cityjson-tex-{name}")).join("full");
        let report = convert(&path, &full, &[]);
        assert_eq!(
            report["textures"]["images_bound"].as_u64(),
            Some(expected_uvs.len() as u64),
            "{name}"
        );
        let (_, tiles) = decode_tileset(&full);
        let mut textured_tiles = 0;
        for uri in tiles.iter().filter_map(|t| t.uri.as_ref()) {
            let bytes = read_content(&full, uri);
            let g = gltf::Gltf::from_slice_without_validation(&bytes).unwrap();
            let blob = g.blob.as_deref().unwrap_or(&[]);
            let textured = g
                .document
                .materials()
                .any(|m| m.pbr_metallic_roughness().base_color_texture().is_some());
            textured_tiles += usize::from(textured);
            for image in g.document.images() {
                let data = image_bytes(&full, uri, blob, &image);
                let decoded = image::load_from_memory(&data)
                    .unwrap_or_else(|e| panic!("{name}: {uri}: image does not decode: {e}"));
                assert!(decoded.width() > 0 && decoded.height() > 0);
            }
        }
        assert!(textured_tiles > 0, "{name}: textured tiles");
        gltf_validator(&full);
    }
}

#[test]
fn missing_texture_images_are_one_report_warning() {
    let Some(path) = dataset("delfshaven-lod2-textured/3-20-DELFSHAVEN.city.json") else {
        return;
    };
    let out = tmpdir("cityjson-missing-images").join("tiles");
    let report = convert(&path, &out, &["--lod", "none"]);
    let present = input_texture_uvs(&path).len();
    assert_eq!(
        report["textures"]["images_bound"].as_u64(),
        Some(present as u64)
    );
    let warnings: Vec<&str> = report["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_str)
        .filter(|w| w.contains("texture images are missing"))
        .collect();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(
        warnings[0].contains("3-20-DELFSHAVEN.city.json"),
        "{}",
        warnings[0]
    );
}
