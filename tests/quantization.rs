//! `--compression quantized` (KHR_mesh_quantization, issue 7) against `--compression none` with
//! the real binary: the same tiles, triangles and vertices; every decoded vertex (read with our
//! test reader from the integer accessors, placed by the glTF node hierarchy and instance
//! transforms, as a client does) within 1 mm per axis of the float one; the extension required;
//! integer accessors where the frame and ranges allow; fewer geometry bytes; gltf-validator 0
//! errors. Runs on the bundled sample and every model of ../shared/data when it exists.

mod common;
use common::*;
use glam::DVec3;
use serde_json::Value;
use std::collections::HashMap;
use std::path::Path;

/// Largest per-axis distance from each vertex of `b` to the nearest vertex of `a`.
fn worst_axis_deviation(a: &[DVec3], b: &[DVec3]) -> f64 {
    const CELL_M: f64 = 0.01;
    let key = |p: DVec3| {
        (
            (p.x / CELL_M).floor() as i64,
            (p.y / CELL_M).floor() as i64,
            (p.z / CELL_M).floor() as i64,
        )
    };
    let mut grid: HashMap<(i64, i64, i64), Vec<DVec3>> = HashMap::new();
    for &p in a {
        grid.entry(key(p)).or_default().push(p);
    }
    let mut worst: f64 = 0.0;
    for &q in b {
        let (x, y, z) = key(q);
        let mut best = f64::INFINITY;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    for p in grid.get(&(x + dx, y + dy, z + dz)).into_iter().flatten() {
                        best = best.min((*p - q).abs().max_element());
                    }
                }
            }
        }
        worst = worst.max(best);
    }
    worst
}

/// Counts of (POSITION, NORMAL, TEXCOORD_0) accessors stored as integers, and of all.
fn integer_attributes(dir: &Path, uri: &str) -> ([usize; 3], [usize; 3]) {
    let json = glb_json(&std::fs::read(dir.join(uri)).unwrap());
    let required: Vec<&str> = json["extensionsRequired"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(Value::as_str)
        .collect();
    assert!(
        required.contains(&"KHR_mesh_quantization"),
        "{uri}: KHR_mesh_quantization required"
    );
    let (mut ints, mut all) = ([0; 3], [0; 3]);
    for m in json["meshes"].as_array().into_iter().flatten() {
        for p in m["primitives"].as_array().into_iter().flatten() {
            for (k, name) in ["POSITION", "NORMAL", "TEXCOORD_0"].iter().enumerate() {
                let Some(a) = p["attributes"][name].as_u64() else {
                    continue;
                };
                let acc = &json["accessors"][a as usize];
                all[k] += 1;
                if acc["componentType"] != 5126 {
                    assert_eq!(acc["normalized"], true, "{uri}: {name} normalized");
                    ints[k] += 1;
                }
            }
        }
    }
    (ints, all)
}

fn check_model(model: &Path) {
    let name = model.file_stem().unwrap().to_string_lossy().to_string();
    let d = tmpdir(&format!("quant-{name}"));
    let (plain, quant) = (d.join("none"), d.join("quantized"));
    let rp = convert(model, &plain, &["--compression", "none"]);
    let rq = convert(model, &quant, &["--compression", "quantized"]);
    assert_eq!(rp["output"]["tiles"], rq["output"]["tiles"]);
    assert!(
        rq["output"]["bytes"].as_u64() < rp["output"]["bytes"].as_u64(),
        "{name}: quantized output is smaller"
    );
    let (_, tp) = decode_tileset(&plain);
    let (_, tq) = decode_tileset(&quant);
    let (mut worst, mut ints, mut all) = (0.0f64, [0; 3], [0; 3]);
    for (a, b) in tp.iter().zip(&tq) {
        assert_eq!(a.uri, b.uri);
        assert_eq!(a.triangles, b.triangles, "{name}: {:?} triangles", a.uri);
        assert_eq!(a.positions.len(), b.positions.len());
        let Some(uri) = &b.uri else { continue };
        worst = worst.max(worst_axis_deviation(&a.positions, &b.positions));
        let (i, n) = integer_attributes(&quant, uri);
        for k in 0..3 {
            ints[k] += i[k];
            all[k] += n[k];
        }
    }
    eprintln!(
        "{name}: worst per-axis deviation {:.3} mm; integer POSITION {}/{}, NORMAL {}/{}, TEXCOORD_0 {}/{}; bytes {} vs {}",
        worst * 1e3,
        ints[0],
        all[0],
        ints[1],
        all[1],
        ints[2],
        all[2],
        rq["output"]["bytes"],
        rp["output"]["bytes"]
    );
    // 1 mm bound, plus f32 rounding of the node transform and of the float reference.
    assert!(
        worst <= 0.001 + 1e-5,
        "{name}: a vertex moved {worst} m on an axis"
    );
    assert_eq!(ints[1], all[1], "{name}: every normal is an i8");
    assert!(ints[0] > 0, "{name}: some positions are i16");
    gltf_validator(&quant);
}

#[test]
fn sample_quantized_tiles_stay_within_a_millimetre() {
    check_model(&sample());
}

#[test]
fn shared_models_quantized_tiles_stay_within_a_millimetre() {
    for model in shared_models() {
        check_model(&model);
    }
}
