//! Edges (`EXT_mesh_primitive_edge_visibility`): every tile primitive carries them by default,
//! every compression writes the bits against the triangles a client decodes, instanced shapes
//! carry them once, and what they cost is measured (gzip, as served) on every shared BIM model.
//! The bitfield itself is checked by an independent decoder in tests/python/test_edges.py, on
//! the tilesets written here among others.

use crate::common::*;
use glam::{DMat4, DVec3};
use serde_json::Value;
use std::collections::HashMap;
use std::path::Path;

const EXT: &str = "EXT_mesh_primitive_edge_visibility";

/// The GLB of every content of a tileset (inlined root included), by URI.
fn contents(dir: &Path) -> Vec<(String, Vec<u8>)> {
    tileset_contents(dir)
}

/// (primitives, primitives with edges) over every mesh of a tileset's tiles; and whether every
/// GLB with edges declares the extension as used, never as required.
fn edge_coverage(dir: &Path) -> (usize, usize) {
    let (mut prims, mut with) = (0, 0);
    for (uri, glb) in contents(dir) {
        let doc = glb_json(&glb);
        let mut here = 0;
        for mesh in doc["meshes"].as_array().into_iter().flatten() {
            for p in mesh["primitives"].as_array().unwrap() {
                prims += 1;
                if p["extensions"].get(EXT).is_some() {
                    here += 1;
                }
            }
        }
        with += here;
        let listed = |key: &str| {
            doc[key]
                .as_array()
                .is_some_and(|a| a.iter().any(|e| e == EXT))
        };
        assert_eq!(listed("extensionsUsed"), here > 0, "{uri}: extensionsUsed");
        assert!(!listed("extensionsRequired"), "{uri}: edges are optional");
    }
    (prims, with)
}

/// Bytes of `data` gzipped at the default level, as a web server sends them.
fn gzip_len(data: &[u8]) -> u64 {
    use std::io::Write;
    let mut z = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    z.write_all(data).unwrap();
    z.finish().unwrap().len() as u64
}

/// What a client downloads gzipped: tileset.json (with the inlined root) and every tile file;
/// and the same for a first whole-model view (tileset.json and the tiles it selects).
fn served_gzip_bytes(dir: &Path) -> (u64, u64) {
    let tileset = gzip_len(&std::fs::read(dir.join("tileset.json")).unwrap());
    // Tile files only: an inlined root is served inside tileset.json.
    let mut by_uri: HashMap<String, u64> = HashMap::new();
    for (uri, glb) in contents(dir) {
        if dir.join(&uri).is_file() {
            by_uri.insert(uri, gzip_len(&glb));
        }
    }
    let view = bimtiles::inspect::first_view::first_view(dir, &Default::default()).unwrap();
    let first: u64 = view
        .selected
        .iter()
        .filter_map(|u| by_uri.get(u))
        .sum::<u64>();
    (tileset + by_uri.values().sum::<u64>(), tileset + first)
}

/// The shared BIM models: every IFC file and the GLB exports listed beside them.
fn bim_models() -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    if cfg!(feature = "ifc") {
        out.extend(shared_files(&["ifc"]).unwrap_or_default());
    }
    for name in [
        "AC20-FZK-Haus.glb",
        "duplex.glb",
        "ISSUE_021_Mini_Project.glb",
        "IfcOpenHouse_IFC4.glb",
    ] {
        out.extend(shared_file(name));
    }
    out
}

#[test]
fn every_bim_model_carries_edges_and_reports_what_they_cost() {
    let mut rows = Vec::new();
    for model in bim_models() {
        let name = model
            .file_name()
            .unwrap()
            .to_string_lossy()
            .replace('.', "-");
        let with = tmpdir(&format!("edges-{name}")).join("tiles");
        let without = tmpdir(&format!("edges-none-{name}")).join("tiles");
        let r = convert(&model, &with, &["--edges", "all"]);
        let r0 = convert(&model, &without, &[]);
        // Every primitive of every tile (simplified ones too) has edges; none with `none`.
        let (prims, edged) = edge_coverage(&with);
        assert!(
            prims > 0 && edged == prims,
            "{name}: {edged} of {prims} primitives have edges"
        );
        assert_eq!(edge_coverage(&without).1, 0, "{name}: no edges by default");
        // report.json: the figures per tile add up to the output's; none without edges.
        let sum = |r: &Value, key: &str| -> u64 {
            r["tiles"]
                .as_array()
                .unwrap()
                .iter()
                .map(|t| t[key].as_u64().unwrap())
                .sum()
        };
        for key in ["edge_bytes", "edge_gzip_bytes"] {
            assert_eq!(
                r["output"][key].as_u64().unwrap(),
                sum(&r, key),
                "{name} {key}"
            );
            assert_eq!(
                r0["output"][key].as_u64().unwrap(),
                0,
                "{name} {key} without edges"
            );
        }
        let reported = r["output"]["edge_gzip_bytes"].as_u64().unwrap();
        assert!(reported > 0, "{name}: edges cost bytes");
        // The first view's share: some edges, at most all of them; none without edges.
        let first_view = r["output"]["first_view_edge_gzip_bytes"].as_u64().unwrap();
        assert!(
            first_view > 0 && first_view <= reported,
            "{name}: first view {first_view} of {reported} edge gzip bytes"
        );
        assert_eq!(
            r0["output"]["first_view_edge_gzip_bytes"].as_u64().unwrap(),
            0,
            "{name}: first view without edges"
        );
        // What serving adds: the same tiles with and without edges, gzipped (the tree can differ
        // where a tile's size decides, e.g. whether the root is inlined).
        let (all, first) = served_gzip_bytes(&with);
        let (all0, first0) = served_gzip_bytes(&without);
        eprintln!("{name}: report.json says {reported} gzip bytes of edges");
        rows.push((name, all0, all, first0, first));
    }
    eprintln!("model | all tiles gzip (no edges -> edges) | first view gzip (no edges -> edges)");
    for (name, all0, all, first0, first) in &rows {
        let pct = |a: u64, b: u64| 100.0 * (b as f64 - a as f64) / a as f64;
        eprintln!(
            "{name} | {all0} -> {all} ({:+.1} %) | {first0} -> {first} ({:+.1} %)",
            pct(*all0, *all),
            pct(*first0, *first)
        );
    }
}

/// Hard edges (values 2 and 3) of the full-detail tiles as segments in the tileset's frame (z-up,
/// metres), each instance of an instanced mesh apart. Meshopt tiles are decoded by
/// meshoptimizer's reference decoder first; Draco's by the Draco library.
fn hard_segments(dir: &Path) -> Vec<[DVec3; 2]> {
    let plain = dir.with_extension("plain");
    let read_dir = match decode_meshopt(dir, &plain) {
        Some(n) if n > 0 => plain,
        _ => dir.to_path_buf(),
    };
    let ts: Value =
        serde_json::from_slice(&std::fs::read(read_dir.join("tileset.json")).unwrap()).unwrap();
    let mut out = Vec::new();
    let mut stack = vec![&ts["root"]];
    while let Some(t) = stack.pop() {
        stack.extend(t["children"].as_array().into_iter().flatten());
        let Some(uri) = t.pointer("/content/uri").and_then(Value::as_str) else {
            continue;
        };
        if t["geometricError"].as_f64().unwrap() > 0.0 {
            continue;
        }
        let bytes = read_content(&read_dir, uri);
        let g = gltf::Gltf::from_slice_without_validation(&bytes).unwrap();
        let doc = glb_json(&bytes);
        let blob = g.blob.as_deref().unwrap();
        for (mesh, placement) in drawn_meshes(&g, &doc, blob) {
            let m: DMat4 = Y_UP_TO_Z_UP * placement.matrix;
            for p in mesh.primitives() {
                let json = &doc["meshes"][mesh.index()]["primitives"][p.index()];
                let vis = json["extensions"][EXT]["visibility"]
                    .as_u64()
                    .expect("every primitive has edges") as usize;
                let bits: Vec<u8> = read_accessor(&doc, blob, vis)
                    .iter()
                    .map(|v| v[0] as u8)
                    .collect();
                let (pos, idx) = primitive_geometry(&g, blob, &p);
                let at = |i: u32| {
                    let v = pos[i as usize];
                    m.transform_point3(DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64))
                };
                for (k, pair) in idx
                    .chunks_exact(3)
                    .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
                    .enumerate()
                {
                    if (bits[k / 4] >> ((k % 4) * 2)) & 2 != 0 {
                        out.push([at(pair.0), at(pair.1)]);
                    }
                }
            }
        }
    }
    out
}

/// The share of segments of `a` that `b` has too (either way round, endpoints within `tol_m`).
fn share_found(a: &[[DVec3; 2]], b: &[[DVec3; 2]], tol_m: f64) -> f64 {
    let cell = |p: DVec3| (p / (4.0 * tol_m)).floor().as_i64vec3().to_array();
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, s) in b.iter().enumerate() {
        grid.entry(cell((s[0] + s[1]) / 2.0)).or_default().push(i);
    }
    let found = a
        .iter()
        .filter(|s| {
            let c = cell((s[0] + s[1]) / 2.0);
            (-1..=1).any(|dx| {
                (-1..=1).any(|dy| {
                    (-1..=1).any(|dz| {
                        grid.get(&[c[0] + dx, c[1] + dy, c[2] + dz])
                            .into_iter()
                            .flatten()
                            .any(|&j| {
                                let t = &b[j];
                                let close = |p: DVec3, q: DVec3| p.distance(q) <= tol_m;
                                (close(s[0], t[0]) && close(s[1], t[1]))
                                    || (close(s[0], t[1]) && close(s[1], t[0]))
                            })
                    })
                })
            })
        })
        .count();
    found as f64 / a.len().max(1) as f64
}

#[test]
fn every_compression_draws_the_same_hard_edges() {
    // The meshopt index codec rotates triangles and Draco reorders them: bits written against the
    // encoder's input order would land on other edges once decoded.
    let Some(model) = shared_file("IfcOpenHouse_IFC4.glb") else {
        return;
    };
    let mut by = Vec::new();
    for c in ["none", "quantized", "meshopt", "draco"] {
        let dir = tmpdir(&format!("edges-compression-{c}")).join("tiles");
        convert(&model, &dir, &["--compression", c, "--edges", "hard"]);
        let segments = hard_segments(&dir);
        assert!(!segments.is_empty(), "{c}: hard edges");
        by.push((c, segments));
    }
    let plain = &by[0].1;
    for (c, s) in &by[1..] {
        // Within the 1 mm position bound (both ends), and a little for the float frame.
        let (there, back) = (share_found(plain, s, 0.003), share_found(s, plain, 0.003));
        eprintln!("{c}: {there:.4} of the plain tiles' hard edges found, {back:.4} back");
        assert!(there >= 0.99 && back >= 0.99, "{c}: {there} / {back}");
    }
}

#[test]
fn instanced_shapes_carry_their_edges_once() {
    let Some(model) = shared_file("duplex.glb") else {
        return;
    };
    let dir = tmpdir("edges-instancing").join("tiles");
    let r = convert(
        &model,
        &dir,
        &[
            "--edges",
            "all",
            "--min-instanced-triangles-saved",
            "0",
            "--max-tile-triangles",
            "100000",
        ],
    );
    assert!(r["output"]["instanced_shapes"].as_u64().unwrap() > 0);
    let mut shapes = 0;
    for (uri, glb) in contents(&dir) {
        let doc = glb_json(&glb);
        let nodes = doc["nodes"].as_array().unwrap();
        for (i, mesh) in doc["meshes"].as_array().into_iter().flatten().enumerate() {
            let users: Vec<&Value> = nodes.iter().filter(|n| n["mesh"] == i).collect();
            let instanced = users
                .iter()
                .any(|n| n.pointer("/extensions/EXT_mesh_gpu_instancing").is_some());
            if !instanced {
                continue;
            }
            shapes += 1;
            // One mesh, one node drawing it per instance: the edges are in the file once.
            assert_eq!(users.len(), 1, "{uri}: mesh {i} is drawn by one node");
            for p in mesh["primitives"].as_array().unwrap() {
                assert!(p["extensions"].get(EXT).is_some(), "{uri}: mesh {i} edges");
            }
        }
    }
    assert!(shapes > 0, "no instanced shape written");
}

#[test]
fn a_tileset_whose_elements_are_cut_between_tiles() {
    // tests/python/test_edges.py checks on it that a cut across a face draws no line: a house with a
    // tile budget small enough that the octree cuts its large elements (slabs, walls, roof).
    let Some(model) = shared_file("AC20-FZK-Haus.ifc") else {
        return;
    };
    let dir = tmpdir("edges-cut-fzk").join("tiles");
    let r = convert(
        &model,
        &dir,
        &["--edges", "all", "--max-tile-triangles", "1000"],
    );
    assert!(r["output"]["edge_bytes"].as_u64().unwrap() > 0);
    let cut = r["tiles"].as_array().unwrap().len();
    assert!(cut > 8, "{cut} tiles: the budget did not split the model");
}

#[test]
fn finder_tilesets_for_the_independent_check() {
    // tests/python/test_edges.py compares the hard edges of these full-detail tiles with its own
    // finder on the input: per element and material as the input has them (no dedup, no
    // instancing, materials apart) and at the input's float positions.
    for name in [
        "AC20-FZK-Haus",
        "duplex",
        "ISSUE_021_Mini_Project",
        "IfcOpenHouse_IFC4",
    ] {
        let Some(model) = shared_file(&format!("{name}.glb")) else {
            continue;
        };
        let dir = tmpdir(&format!("edges-finder-{name}")).join("tiles");
        let r = convert(
            &model,
            &dir,
            &[
                "--edges",
                "all",
                "--no-dedup",
                "--no-instancing",
                "--keep-materials",
                "--compression",
                "none",
            ],
        );
        assert!(r["output"]["edge_bytes"].as_u64().unwrap() > 0, "{name}");
    }
}
