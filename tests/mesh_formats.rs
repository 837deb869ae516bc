//! Wavefront OBJ (+MTL) and FBX input with the real binary on every file of ../shared/data/obj/
//! and ../shared/data/fbx/: each file is converted once and its tileset shared by the checks.
//! Elements are counted against the OBJ groups counted here from the text and the FBX mesh models
//! the data folder's own `stats.py` lists; the tiles' triangle area against Debian's `assimp`
//! (its own readers, the faces exported to PLY); ids and Revit element ids against the group and
//! model names; textured triangles against the MTL maps (of the OBJ itself, or of assimp's OBJ
//! export of an FBX); gltf-validator and the 3D Tiles schemas on every tileset. A manifest entry's
//! `unit` wins over `--unit`, and an OBJ read under a tiny `--memory-budget` (its groups spilled)
//! gives the same tiles.

use crate::common::*;
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, Mutex, OnceLock};

/// The shared files, with the metres one of their units stands for (from MANIFEST.md: the Revit
/// OBJ is in centimetres, its header says so; the others state no unit and are read as metres).
const OBJ_FILES: &[(&str, f64)] = &[
    (
        "obj/alphaville-centerpart-textured/AlphaVille_CenterPart.obj",
        1.0,
    ),
    ("obj/revit-wall-untextured/revit_wall_square.obj", 0.01),
    ("obj/squareblock-building-textured/SquareBlock.obj", 1.0),
];

/// The shared FBX files, with the metres one of their units stands for (`UnitScaleFactor`, in
/// centimetres, from MANIFEST.md: assimp leaves it unapplied).
const FBX_FILES: &[(&str, f64)] = &[
    (
        "fbx/blender-embedded-textures-binary/blender_293_embedded_textures_7400_binary.fbx",
        1.0,
    ),
    (
        "fbx/maya-material-chart-ascii/maya_material_chart_7700_ascii.fbx",
        0.01,
    ),
    (
        "fbx/revit-wall-binary/revit_wall_square_7700_binary.fbx",
        0.3048,
    ),
    ("fbx/triangleblock-textured-binary/TriangleBlock.FBX", 1.0),
];

/// A file converted once (`--lod none`: every tile is full detail; no compression, so the tiles
/// read back with the `gltf` crate).
struct Converted {
    dir: PathBuf,
    report: Value,
}

/// Each file's conversion, made by the first test that asks for it.
type Conversions = Mutex<HashMap<String, Arc<OnceLock<Arc<Converted>>>>>;

fn converted(rel: &str) -> Option<Arc<Converted>> {
    static DONE: OnceLock<Conversions> = OnceLock::new();
    let path = shared_file(rel)?;
    let cell = DONE
        .get_or_init(Default::default)
        .lock()
        .unwrap()
        .entry(rel.to_string())
        .or_default()
        .clone();
    Some(
        cell.get_or_init(|| {
            let name = Path::new(rel).file_stem().unwrap().to_string_lossy();
            let dir = tmpdir(&format!("mesh-formats-{name}")).join("tiles");
            let report = convert(
                &path,
                &dir,
                &["--lod", "none", "--compression", "none", "--no-instancing"],
            );
            Arc::new(Converted { dir, report })
        })
        .clone(),
    )
}

/// The FBX SDK's `FBXASCnnn` escapes undone (written here, apart from the reader's).
fn fbx_unescaped(name: &str) -> String {
    let mut out = String::new();
    let mut rest = name;
    while let Some(at) = rest.find("FBXASC") {
        out.push_str(&rest[..at]);
        let code: u8 = rest[at + 6..at + 9].parse().unwrap();
        out.push(code as char);
        rest = &rest[at + 9..];
    }
    out + rest
}

/// What the OBJ text says, counted here: per element (group, within its object; faces before
/// any group are one of their own) its name, and the faces drawn with a textured material.
struct ObjCounts {
    groups: BTreeSet<String>,
    ungrouped_faces: bool,
    textured_triangles: usize,
    texture_files: BTreeSet<PathBuf>,
}

fn count_obj(path: &Path) -> ObjCounts {
    let text = std::fs::read_to_string(path).unwrap();
    let dir = path.parent().unwrap();
    let mut maps: HashMap<String, PathBuf> = HashMap::new();
    let mut counts = ObjCounts {
        groups: BTreeSet::new(),
        ungrouped_faces: false,
        textured_triangles: 0,
        texture_files: BTreeSet::new(),
    };
    let (mut group, mut material) = (None::<String>, None::<String>);
    for line in text.lines() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("mtllib") => {
                let lib =
                    std::fs::read_to_string(dir.join(words.collect::<Vec<_>>().join(" "))).unwrap();
                let mut current = String::new();
                for l in lib.lines().map(str::trim) {
                    if let Some(n) = l.strip_prefix("newmtl ") {
                        current = n.trim().to_string();
                    } else if let Some(f) = l.strip_prefix("map_Kd ") {
                        maps.insert(current.clone(), dir.join(f.trim()));
                    }
                }
            }
            Some("g") | Some("o") => {
                group = Some(fbx_unescaped(words.collect::<Vec<_>>().join(" ").as_str()))
            }
            Some("usemtl") => material = Some(words.collect::<Vec<_>>().join(" ")),
            Some("f") => {
                let corners = words.count();
                match &group {
                    Some(g) => counts.groups.insert(g.clone()),
                    None => {
                        counts.ungrouped_faces = true;
                        false
                    }
                };
                if let Some(file) = material.as_ref().and_then(|m| maps.get(m)) {
                    counts.textured_triangles += corners - 2;
                    counts.texture_files.insert(file.clone());
                }
            }
            _ => {}
        }
    }
    counts
}

/// The triangle area of a model as Debian's Open Asset Import Library reads it (`assimp export
/// -ptv` to ASCII PLY: every node's transform applied), in the file's units; `None` when assimp
/// is not installed (and tools are not required).
fn assimp_area(model: &Path) -> Option<f64> {
    if Command::new("assimp").arg("version").output().is_err() {
        assert!(
            !tools_required(),
            "assimp is not installed (apt install assimp-utils)"
        );
        eprintln!("SKIPPED assimp area check: assimp not installed");
        return None;
    }
    let out = tmpdir(&format!(
        "assimp-{}",
        model.file_name().unwrap().to_string_lossy()
    ))
    .join("model.ply");
    let o = Command::new("assimp")
        .arg("export")
        .arg(model)
        .arg(&out)
        .arg("-ptv")
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "assimp export {}: {o:?}",
        model.display()
    );
    let text = std::fs::read_to_string(&out).unwrap();
    let (header, body) = text.split_once("end_header\n").unwrap();
    let mut vertices = 0;
    let mut properties = Vec::new();
    let mut in_vertex = false;
    for l in header.lines() {
        let w: Vec<&str> = l.split_whitespace().collect();
        match w.as_slice() {
            ["element", "vertex", n] => {
                vertices = n.parse().unwrap();
                in_vertex = true;
            }
            ["element", ..] => in_vertex = false,
            ["property", _, name] if in_vertex => properties.push(name.to_string()),
            _ => {}
        }
    }
    let at = |name: &str| properties.iter().position(|p| p == name).unwrap();
    let (x, y, z) = (at("x"), at("y"), at("z"));
    let mut lines = body.lines();
    let points: Vec<glam::DVec3> = (0..vertices)
        .map(|_| {
            let v: Vec<f64> = lines
                .next()
                .unwrap()
                .split_whitespace()
                .map(|t| t.parse().unwrap())
                .collect();
            glam::DVec3::new(v[x], v[y], v[z])
        })
        .collect();
    let mut area = 0.0;
    for l in lines {
        let idx: Vec<usize> = l.split_whitespace().map(|t| t.parse().unwrap()).collect();
        let corners = &idx[1..=idx[0]];
        for k in 1..corners.len() - 1 {
            let (a, b, c) = (
                points[corners[0]],
                points[corners[k]],
                points[corners[k + 1]],
            );
            area += (b - a).cross(c - a).length() / 2.0;
        }
    }
    Some(area)
}

/// Each property table row of every tile: its `id`, and its numeric columns by name.
fn element_rows(dir: &Path) -> Vec<(String, BTreeMap<String, f64>)> {
    let (_, tiles) = decode_tileset(dir);
    let mut rows = Vec::new();
    for uri in tiles.iter().filter_map(|t| t.uri.as_ref()) {
        let bytes = read_content(dir, uri);
        let g = gltf::Gltf::from_slice_without_validation(&bytes).unwrap();
        let blob = g.blob.as_deref().unwrap();
        let doc = glb_json(&bytes);
        let view = |i: &Value| -> &[u8] {
            let v = &doc["bufferViews"][i.as_u64().unwrap() as usize];
            let o = v["byteOffset"].as_u64().unwrap_or(0) as usize;
            &blob[o..o + v["byteLength"].as_u64().unwrap() as usize]
        };
        let schema = tile_schema(dir, uri);
        let tables = doc["extensions"]["EXT_structural_metadata"]["propertyTables"]
            .as_array()
            .cloned()
            .unwrap_or_default();
        for table in tables {
            let count = table["count"].as_u64().unwrap() as usize;
            let class = &schema["classes"][table["class"].as_str().unwrap()]["properties"];
            let id = &table["properties"]["id"];
            let size = match id["stringOffsetType"].as_str().unwrap_or("UINT32") {
                "UINT8" => 1,
                "UINT16" => 2,
                _ => 4,
            };
            let values = view(&id["values"]);
            let offsets: Vec<usize> = view(&id["stringOffsets"])
                .chunks_exact(size)
                .map(|c| c.iter().rev().fold(0usize, |a, &b| a << 8 | b as usize))
                .collect();
            for r in 0..count {
                let key = String::from_utf8(values[offsets[r]..offsets[r + 1]].to_vec()).unwrap();
                let mut numbers = BTreeMap::new();
                for (name, p) in table["properties"].as_object().unwrap() {
                    if class[name]["componentType"] == "FLOAT64" {
                        let v = view(&p["values"]);
                        let b: [u8; 8] = v[r * 8..r * 8 + 8].try_into().unwrap();
                        numbers.insert(name.clone(), f64::from_le_bytes(b));
                    }
                }
                rows.push((key, numbers));
            }
        }
    }
    rows
}

/// The tiles' area against assimp's (in the file's units, `metres_per_unit`), within 0.1 %.
fn check_area(rel: &str, done: &Converted, model: &Path, metres_per_unit: f64) {
    let triangles = done.report["input"]["triangles"].as_u64().unwrap() as usize;
    let tiles = check_tileset(&done.dir, triangles);
    let area_m2: f64 = tiles.iter().map(|t| t.area).sum();
    if let Some(a) = assimp_area(model) {
        let expected_m2 = a * metres_per_unit * metres_per_unit;
        let rel_diff = (area_m2 - expected_m2).abs() / expected_m2;
        eprintln!(
            "{rel}: {triangles} triangles, {area_m2:.4} m² vs assimp {expected_m2:.4} m² ({:.5} %)",
            rel_diff * 100.0
        );
        assert!(
            rel_diff < 1e-3,
            "{rel}: area {area_m2} vs assimp {expected_m2}"
        );
    }
}

/// Every row whose id ends in a Revit element id (`… [320878]`) carries it as a number, and no
/// other row has one.
fn check_revit_ids(rel: &str, rows: &[(String, BTreeMap<String, f64>)]) {
    for (key, numbers) in rows {
        let written = key
            .strip_suffix(']')
            .and_then(|k| k.rsplit_once('['))
            .and_then(|(_, d)| d.parse::<f64>().ok());
        assert_eq!(
            numbers.get("revit_element_id").copied(),
            written,
            "{rel}: {key}"
        );
    }
}

#[test]
fn every_obj_converts_with_its_groups_area_and_ids() {
    for &(rel, metres_per_unit) in OBJ_FILES {
        let Some(done) = converted(rel) else {
            continue;
        };
        let path = shared_file(rel).unwrap();
        let counts = count_obj(&path);
        let elements = counts.groups.len() + usize::from(counts.ungrouped_faces);
        let components = done.report["input"]["components"].as_u64().unwrap() as usize;
        assert_eq!(components, elements, "{rel}: one element per group");
        check_area(rel, &done, &path, metres_per_unit);
        let rows = element_rows(&done.dir);
        let ids: BTreeSet<String> = rows.iter().map(|(k, _)| k.clone()).collect();
        assert_eq!(ids, counts.groups, "{rel}: the ids are the group names");
        check_revit_ids(rel, &rows);
        gltf_validator(&done.dir);
    }
}

/// What the data folder's `stats.py` (its own binary and ASCII FBX parser) says of a file: the
/// number of mesh models and the names of all models.
fn fbx_stats(model: &Path) -> (usize, BTreeSet<String>) {
    let stats = model.parent().unwrap().parent().unwrap().join("stats.py");
    let o = Command::new("python3")
        .arg(&stats)
        .arg(model)
        .output()
        .unwrap();
    assert!(o.status.success(), "{o:?}");
    let text = String::from_utf8(o.stdout).unwrap();
    let meshes = text
        .split("'Model:Mesh': ")
        .nth(1)
        .and_then(|t| t.split(|c: char| !c.is_ascii_digit()).next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0);
    let list = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("models ("))
        .and_then(|l| l.split_once("): ['"))
        .map(|(_, l)| l.trim_end_matches("']").to_string())
        .unwrap_or_default();
    (meshes, list.split("', '").map(str::to_string).collect())
}

#[test]
fn every_fbx_converts_with_its_mesh_nodes_area_and_ids() {
    for &(rel, metres_per_unit) in FBX_FILES {
        let Some(done) = converted(rel) else {
            continue;
        };
        let path = shared_file(rel).unwrap();
        let (mesh_models, model_names) = fbx_stats(&path);
        let components = done.report["input"]["components"].as_u64().unwrap() as usize;
        assert_eq!(components, mesh_models, "{rel}: one element per mesh node");
        check_area(rel, &done, &path, metres_per_unit);
        let rows = element_rows(&done.dir);
        let ids: BTreeSet<String> = rows.iter().map(|(k, _)| k.clone()).collect();
        assert_eq!(ids.len(), mesh_models, "{rel}: {ids:?}");
        assert!(
            ids.is_subset(&model_names),
            "{rel}: {ids:?} are model names"
        );
        check_revit_ids(rel, &rows);
        gltf_validator(&done.dir);
    }
}

/// Triangles drawn with a base-colour texture in the tiles.
fn textured_triangles(dir: &Path) -> usize {
    let (_, tiles) = decode_tileset(dir);
    let mut count = 0;
    for uri in tiles.iter().filter_map(|t| t.uri.as_ref()) {
        for t in read_textured(dir, uri) {
            assert!(t.dims.0 > 0 && t.dims.1 > 0);
            assert_eq!(t.uvs.len(), t.positions.len());
            for uv in &t.uvs {
                assert!(uv.iter().all(|c| c.is_finite()), "UV {uv:?}");
            }
            count += t.indices.len() / 3;
        }
    }
    count
}

#[test]
fn obj_textures_reach_the_tiles_with_their_uvs() {
    for &(rel, _) in OBJ_FILES {
        let Some(done) = converted(rel) else {
            continue;
        };
        let counts = count_obj(&shared_file(rel).unwrap());
        let textured = textured_triangles(&done.dir);
        assert_eq!(
            textured, counts.textured_triangles,
            "{rel}: every face of a textured material is drawn textured"
        );
        for f in &counts.texture_files {
            assert!(f.is_file(), "{}", f.display());
        }
        eprintln!(
            "{rel}: {textured} textured triangles from {} images",
            counts.texture_files.len()
        );
    }
}

#[test]
fn fbx_textures_reach_the_tiles_with_their_uvs() {
    for &(rel, _) in FBX_FILES {
        let Some(done) = converted(rel) else {
            continue;
        };
        let path = shared_file(rel).unwrap();
        if Command::new("assimp").arg("version").output().is_err() {
            assert!(!tools_required(), "assimp is not installed");
            continue;
        }
        // assimp's OBJ export: its materials with their diffuse maps, its faces per material.
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        let obj = tmpdir(&format!("assimp-obj-{name}")).join("model.obj");
        let o = Command::new("assimp")
            .arg("export")
            .arg(&path)
            .arg(&obj)
            .arg("-ptv")
            .output()
            .unwrap();
        assert!(o.status.success(), "{o:?}");
        let by_assimp = count_obj(&obj).textured_triangles;
        let textured = textured_triangles(&done.dir);
        eprintln!("{rel}: {textured} textured triangles (assimp: {by_assimp})");
        // assimp reads no Maya Standard Surface maps: the material chart (one quad per model,
        // each named by what its material shows) has its base-colour textures on the quads
        // named `…DiffuseTexture…` (Lambert/Phong, which assimp reads) and `…BaseTexture…`.
        let (_, models) = fbx_stats(&path);
        let expected = match models.iter().any(|m| m.starts_with("Standard_")) {
            true => {
                2 * models
                    .iter()
                    .filter(|m| m.contains("DiffuseTexture") || m.contains("BaseTexture"))
                    .count()
            }
            false => by_assimp,
        };
        assert!(textured >= by_assimp, "{rel}");
        assert_eq!(textured, expected, "{rel}");
    }
}

#[test]
fn manifest_entries_place_obj_and_fbx_with_their_own_unit() {
    let (Some(obj), Some(fbx)) = (
        shared_file(OBJ_FILES[2].0),
        shared_file("fbx/revit-wall-binary/revit_wall_square_7700_binary.fbx"),
    ) else {
        return;
    };
    let dir = tmpdir("mesh-formats-manifest");
    put_folder_in(&obj, &dir, "block");
    put_folder_in(&fbx, &dir, "wall");
    let obj_name = obj.file_name().unwrap().to_string_lossy();
    let fbx_name = fbx.file_name().unwrap().to_string_lossy();
    let manifest = dir.join("campus.json");
    std::fs::write(
        &manifest,
        serde_json::json!({"models": [
            {"path": format!("block/{obj_name}"), "unit": "cm", "up": "y"},
            {"path": format!("wall/{fbx_name}"), "east_m": 200.0},
        ]})
        .to_string(),
    )
    .unwrap();
    let out = dir.join("tiles");
    let o = run(&[
        "convert",
        "--manifest",
        manifest.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
        "--lod",
        "none",
        "--unit",
        "mm",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let triangles = report["input"]["triangles"].as_u64().unwrap() as usize;
    let area_m2: f64 = check_tileset(&out, triangles).iter().map(|t| t.area).sum();
    // The entry's centimetres win over --unit mm; the FBX keeps its own feet.
    let (Some(block), Some(wall)) = (assimp_area(&obj), assimp_area(&fbx)) else {
        return;
    };
    let expected_m2 = block * 1e-4 + wall * 0.3048 * 0.3048;
    assert!(
        (area_m2 - expected_m2).abs() / expected_m2 < 1e-3,
        "{area_m2} vs {expected_m2}"
    );
}

/// Every file of a tileset folder but the report, by relative path.
fn tileset_files(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else if p.file_name().is_some_and(|n| n != "report.json") {
                out.insert(
                    p.strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

#[test]
fn an_obj_read_under_a_tiny_memory_budget_gives_the_same_tiles() {
    let rel = OBJ_FILES[0].0;
    let Some(done) = converted(rel) else {
        return;
    };
    let out = tmpdir("mesh-formats-budget").join("tiles");
    let options = [
        "--lod",
        "none",
        "--compression",
        "none",
        "--no-instancing",
        "--memory-budget",
        "64K",
    ];
    let report = convert(&shared_file(rel).unwrap(), &out, &options);
    assert!(
        report["memory"]["geometry"]["spilled_bytes"]
            .as_u64()
            .unwrap_or(0)
            > 0,
        "the groups went to disk: {}",
        report["memory"]
    );
    let (a, b) = (tileset_files(&done.dir), tileset_files(&out));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (name, bytes) in &a {
        assert!(bytes == &b[name], "{rel}: {} differs", name.display());
    }
}
