//! End-to-end: the real binary on the bundled sample and on every model of ../shared/data, checked
//! with independent readers (gltf crate, gltf-validator, the official 3D Tiles schemas).

use crate::common::*;
use glam::DVec3;

#[test]
fn sample_converts_to_a_valid_tileset() {
    let out = tmpdir("sample").join("tiles");
    let expect: serde_json::Value = serde_json::from_slice(
        &std::fs::read(repo().join("samples/sample_building.expect.json")).unwrap(),
    )
    .unwrap();
    // A small budget so that the sample makes a real tree.
    let report = convert(&sample(), &out, &["--max-tile-triangles", "2000"]);
    let tris = expect["triangles"].as_u64().unwrap() as usize;
    assert_eq!(
        report["input"]["triangles"].as_u64().unwrap() as usize,
        tris
    );
    assert_eq!(report["input"]["components"], expect["components"]);
    // HLOD: full detail in the leaves plus the simplified levels above.
    assert!(report["output"]["triangles"].as_u64().unwrap() as usize > tris);
    assert!(
        report["output"]["tiles"].as_u64().unwrap() > 4,
        "a tree, not one tile"
    );
    assert!(report["output"]["max_depth"].as_u64().unwrap() >= 1);
    for key in ["ingest", "partition", "encode_write", "total"] {
        assert!(report["timings_s"][key].as_f64().is_some(), "timing {key}");
    }
    assert!(report["peak_memory_bytes"].as_u64().unwrap() > 0);
    assert!(report["geometric_error_metric"]
        .as_str()
        .unwrap()
        .starts_with("measured"));
    let tiles = check_tileset(&out, tris);
    // Geometric error is meaningful: not one constant, and 0 exactly at the leaves.
    let mut errors: Vec<f64> = tiles.iter().map(|t| t.geometric_error).collect();
    errors.dedup();
    assert!(errors.len() > 1);
    if let Some((files, _, _)) = gltf_validator(&out) {
        assert_eq!(
            files as usize,
            tiles.iter().filter(|t| t.uri.is_some()).count()
        );
    }
}

#[test]
fn every_shared_model_converts_to_a_valid_tileset() {
    for model in shared_models() {
        let name = model.file_stem().unwrap().to_string_lossy().to_string();
        let out = tmpdir(&format!("shared-{name}")).join("tiles");
        let report = convert(&model, &out, &["--max-tile-triangles", "5000"]);
        let tris = report["input"]["triangles"].as_u64().unwrap() as usize;
        assert!(tris > 0, "{name}");
        let tiles = check_tileset(&out, tris);
        eprintln!("{name}: {tris} triangles, {} tiles", tiles.len());
        gltf_validator(&out);
        // The report counts the tiles the tileset gives content, HLOD tiles included.
        let ts: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("tileset.json")).unwrap()).unwrap();
        let mut with_content = 0;
        let mut stack = vec![&ts["root"]];
        while let Some(t) = stack.pop() {
            with_content += usize::from(t["content"]["uri"].is_string());
            stack.extend(t["children"].as_array().into_iter().flatten());
        }
        assert_eq!(
            report["output"]["tiles_with_content"].as_u64().unwrap() as usize,
            with_content,
            "{name}"
        );
    }
}

#[test]
fn schema_check_catches_a_broken_tileset() {
    let bad = serde_json::json!({"geometricError": 1.0, "root": {"boundingVolume": {"box": [0]}, "geometricError": "x"}});
    match tileset_schema_errors(&bad) {
        Some(errors) => assert!(errors.len() >= 2, "{errors:?}"),
        None => assert!(!tools_required(), "schemas missing"),
    }
}

#[test]
fn output_is_byte_identical_whatever_the_thread_count() {
    let d = tmpdir("determinism");
    let a = d.join("a");
    let b = d.join("b");
    convert(
        &sample(),
        &a,
        &["--max-tile-triangles", "1500", "--threads", "1"],
    );
    convert(
        &sample(),
        &b,
        &["--max-tile-triangles", "1500", "--threads", "2"],
    );
    // Every file under the output (tiles, shared textures, schema), by relative path.
    fn files(root: &std::path::Path) -> Vec<std::path::PathBuf> {
        let mut out = Vec::new();
        let mut stack = vec![root.to_path_buf()];
        while let Some(dir) = stack.pop() {
            for e in std::fs::read_dir(&dir).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    stack.push(p);
                } else {
                    out.push(p.strip_prefix(root).unwrap().to_path_buf());
                }
            }
        }
        out.sort();
        out
    }
    let (fa, fb) = (files(&a), files(&b));
    assert_eq!(fa, fb);
    assert!(fa.iter().filter(|f| f.starts_with("tiles")).count() > 3);
    for f in &fa {
        if f.as_os_str() == "report.json" {
            continue; // holds timings
        }
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
            "{f:?}"
        );
    }
}

/// WGS84 → ECEF, written again here so the test does not trust the code it checks.
fn ecef(lon: f64, lat: f64, h: f64) -> DVec3 {
    let a = 6378137.0;
    let f = 1.0 / 298.257223563;
    let e2 = f * (2.0 - f);
    let (lo, la) = (lon.to_radians(), lat.to_radians());
    let n = a / (1.0 - e2 * la.sin() * la.sin()).sqrt();
    DVec3::new(
        (n + h) * la.cos() * lo.cos(),
        (n + h) * la.cos() * lo.sin(),
        (n * (1.0 - e2) + h) * la.sin(),
    )
}

fn content_points_ecef(dir: &std::path::Path) -> Vec<DVec3> {
    let (ts, tiles) = decode_tileset(dir);
    let m: Vec<f64> = ts["root"]["transform"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let root = glam::DMat4::from_cols_slice(&m);
    tiles
        .iter()
        .flat_map(|t| t.positions.iter().map(|p| root.transform_point3(*p)))
        .collect()
}

#[test]
fn a_known_point_lands_at_the_right_ecef_coordinate() {
    let d = tmpdir("georef");
    // glTF y-up: (5, 10, -3) is 5 m east, 10 m up, 3 m north of the model origin.
    let input = d.join("tri.glb");
    std::fs::write(
        &input,
        triangle_glb([[0.0, 0.0, 0.0], [5.0, 10.0, -3.0], [1.0, 0.0, 0.0]], None),
    )
    .unwrap();
    let out = d.join("out");
    // Uncompressed: this checks placement, not quantization.
    convert(
        &input,
        &out,
        &[
            "--origin",
            "-122.4194,37.7749,12.5",
            "--compression",
            "none",
        ],
    );
    let pts = content_points_ecef(&out);
    let (lon, lat, h) = (-122.4194f64, 37.7749f64, 12.5);
    // Expected: ENU offsets (e, n, u) = (5, 3, 10) from the origin, built from first principles.
    let (lo, la) = (lon.to_radians(), lat.to_radians());
    let east = DVec3::new(-lo.sin(), lo.cos(), 0.0);
    let north = DVec3::new(-la.sin() * lo.cos(), -la.sin() * lo.sin(), la.cos());
    let up = DVec3::new(la.cos() * lo.cos(), la.cos() * lo.sin(), la.sin());
    let expected = ecef(lon, lat, h) + east * 5.0 + north * 3.0 + up * 10.0;
    let best = pts
        .iter()
        .map(|p| (*p - expected).length())
        .fold(f64::MAX, f64::min);
    assert!(best < 1e-3, "known point is {best} m off (must be < 1 mm)");
    // And the model origin sits exactly at the origin given.
    let o = pts
        .iter()
        .map(|p| (*p - ecef(lon, lat, h)).length())
        .fold(f64::MAX, f64::min);
    assert!(o < 1e-3, "origin is {o} m off");
}

#[test]
fn projected_coordinates_keep_millimetres() {
    let d = tmpdir("projected");
    // A model 5.4 million metres north (a UTM northing): node translation in f64, triangle of 1 mm edges.
    let input = d.join("far.glb");
    std::fs::write(
        &input,
        triangle_glb(
            [[0.0, 0.0, 0.0], [0.001, 0.0, 0.0], [0.0, 0.0, -0.001]],
            Some([512_345.678, 40.0, -5_412_345.123]),
        ),
    )
    .unwrap();
    let out = d.join("out");
    let report = convert(&input, &out, &["--compression", "none"]);
    let rule = &report["georeference"]["anchor_rule"];
    assert_eq!(rule["rule"], "footprint-centre", "{rule}");
    assert!(rule["distance_m"].as_f64().unwrap() > 10_000.0, "{rule}");
    let anchor: Vec<f64> = report["georeference"]["anchor_m"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert!((anchor[0] - 512_345.678).abs() < 0.01 && (anchor[1] - 5_412_345.123).abs() < 0.01);
    let (_, tiles) = decode_tileset(&out);
    let p: Vec<DVec3> = tiles.iter().flat_map(|t| t.positions.clone()).collect();
    assert_eq!(p.len(), 3);
    // The 1 mm edges survive (f32 at 5.4e6 m would round them to 0.5 m steps).
    let e1 = (p[1] - p[0]).length();
    let e2 = (p[2] - p[0]).length();
    assert!(
        (e1 - 0.001).abs() < 1e-5 && (e2 - 0.001).abs() < 1e-5,
        "edges {e1} {e2}"
    );
}

#[test]
fn draco_tiles_stay_within_a_millimetre_of_the_uncompressed_ones() {
    let d = tmpdir("draco-vs-none");
    let (a, b) = (d.join("draco"), d.join("none"));
    // The same shapes instanced in both (the default threshold depends on the compression).
    let same = [
        "--max-tile-triangles",
        "2000",
        "--min-instanced-triangles-saved",
        "300",
    ];
    let ra = convert(&sample(), &a, &same);
    let rb = convert(
        &sample(),
        &b,
        &[&same[..], &["--compression", "none"]].concat(),
    );
    assert_eq!(ra["output"]["tiles"], rb["output"]["tiles"]);
    let (_, ta) = decode_tileset(&a);
    let (_, tb) = decode_tileset(&b);
    // Full detail: 1 mm per axis. Simplified tiles may use a coarser grid, reported per tile.
    let grid_m = position_grids_m(&ra);
    let (mut worst, mut n, mut coarse) = (0.0f64, 0usize, 0usize);
    for (x, y) in ta.iter().zip(&tb) {
        assert_eq!(x.name, y.name);
        let allowed_m = match x.name.as_ref().and_then(|u| grid_m.get(u)) {
            Some(&g) => {
                coarse += 1;
                g
            }
            None => 0.001,
        };
        let mut tile_worst = 0.0f64;
        if allowed_m == 0.001 {
            assert_eq!(
                x.triangles, y.triangles,
                "Draco keeps every full-detail triangle"
            );
        } else {
            // A simplified tile drops the triangles its coarse grid would flatten (they draw
            // nothing), a few at most.
            assert!(
                x.triangles <= y.triangles && x.triangles * 10 >= y.triangles * 9,
                "{:?}: {} triangles with Draco, {} without",
                x.name,
                x.triangles,
                y.triangles
            );
        }
        // Every decoded vertex is near an original one (grid cells of at least 1 cm, larger than
        // the allowed distance, searched with their neighbours).
        let size = 0.01f64.max(2.0 * allowed_m);
        let mut grid: std::collections::HashMap<(i64, i64, i64), Vec<DVec3>> = Default::default();
        let cell = |p: DVec3| {
            (
                (p.x / size).floor() as i64,
                (p.y / size).floor() as i64,
                (p.z / size).floor() as i64,
            )
        };
        for p in &y.positions {
            grid.entry(cell(*p)).or_default().push(*p);
        }
        for p in &x.positions {
            let c = cell(*p);
            let mut best = f64::MAX;
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        for q in grid
                            .get(&(c.0 + dx, c.1 + dy, c.2 + dz))
                            .into_iter()
                            .flatten()
                        {
                            best = best.min((*p - *q).length());
                        }
                    }
                }
            }
            tile_worst = tile_worst.max(best);
            n += 1;
        }
        // Per axis at most: sqrt(3) times that in 3D.
        assert!(
            tile_worst <= allowed_m * 3f64.sqrt() + 1e-6,
            "{:?}: worst quantization error {tile_worst} m, allowed {allowed_m} m per axis",
            x.name
        );
        if allowed_m == 0.001 {
            worst = worst.max(tile_worst);
        }
    }
    assert!(n > 1000);
    assert!(coarse > 0, "the sample has simplified tiles");
    assert!(worst > 0.0, "some full-detail vertex moved (quantized)");
    let (sa, sb) = (
        ra["output"]["bytes"].as_f64().unwrap(),
        rb["output"]["bytes"].as_f64().unwrap(),
    );
    assert!(sa < sb * 0.5, "Draco output {sa} B vs uncompressed {sb} B");
}

#[test]
fn every_shared_ifc_converts_with_semantics_and_georeference() {
    let Some(ifcs) = shared_files(&["ifc"]) else {
        return;
    };
    assert!(!ifcs.is_empty());
    for ifc in ifcs {
        let name = ifc.file_stem().unwrap().to_string_lossy().to_string();
        let out = tmpdir(&format!("ifc-{name}")).join("tiles");
        let report = convert(&ifc, &out, &["--max-tile-triangles", "20000"]);
        let tris = report["input"]["triangles"].as_u64().unwrap() as usize;
        assert!(
            report["input"]["components"].as_u64().unwrap() > 0,
            "{name}"
        );
        assert_eq!(report["input"]["skipped_elements"], 0, "{name}");
        check_tileset(&out, tris);
        gltf_validator(&out);
        // The IFC classes reach the tiles' schema.
        let root = content_uri(&out, report["tiles"][0]["content"].as_str().unwrap());
        let schema = tile_schema(&out, &root);
        let classes: Vec<&str> = schema["enums"]["ifcClass"]["values"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v["name"].as_str().unwrap())
            .collect();
        assert!(
            classes.iter().any(|c| c.starts_with("Ifc")),
            "{name}: {classes:?}"
        );
        eprintln!(
            "{name}: {tris} triangles, origin from {}",
            report["georeference"]["origin_source"]
        );
    }
    // FZK-Haus carries its site reference: it is placed there, not at the default.
    let r: serde_json::Value = serde_json::from_slice(
        &std::fs::read(repo().join("target/test-out/ifc-AC20-FZK-Haus/tiles/report.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(r["georeference"]["origin_source"], "input-site");
    assert!(
        (r["georeference"]["origin"]["latitude_deg"]
            .as_f64()
            .unwrap()
            - 49.100435)
            .abs()
            < 1e-6
    );
}

#[test]
fn inspect_finds_an_element_by_its_global_id() {
    let out = tmpdir("inspect-feature").join("tiles");
    convert(&sample(), &out, &["--max-tile-triangles", "2000"]);
    // A window of the sample, by the GlobalId its generator wrote.
    let o = run(&[
        "inspect",
        out.to_str().unwrap(),
        "--feature",
        "2V3RCMqZPE5ad58ZlBLt5Y",
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let f: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(f["properties"]["Id"], "2V3RCMqZPE5ad58ZlBLt5Y");
    assert_eq!(f["properties"]["IFC class"], "IfcWindow");
    assert!(f["properties"]["Storey"].as_str().is_some());
    assert!(!f["tiles"].as_array().unwrap().is_empty());
    let o = run(&[
        "inspect",
        out.to_str().unwrap(),
        "--feature",
        "no-such-element",
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no element with id"));
}

#[test]
fn lod_none_writes_every_triangle_once_with_additive_refinement() {
    let out = tmpdir("sample-lod-none").join("tiles");
    let report = convert(
        &sample(),
        &out,
        &["--max-tile-triangles", "2000", "--lod", "none"],
    );
    let tris = report["input"]["triangles"].as_u64().unwrap() as usize;
    // Drawn: the input less the exact duplicates dedup removed.
    assert_eq!(
        report["output"]["triangles"].as_u64().unwrap() as usize,
        report["dedup"]["triangles_after"].as_u64().unwrap() as usize
    );
    assert!(report["geometric_error_metric"]
        .as_str()
        .unwrap()
        .starts_with("size-bound"));
    check_tileset(&out, tris);
    let ts: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("tileset.json")).unwrap()).unwrap();
    assert_eq!(ts["root"]["refine"], "ADD");
}
