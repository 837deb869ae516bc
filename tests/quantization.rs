//! `--compression quantized` (KHR_mesh_quantization, issue 7) and `--compression meshopt` (the
//! same attributes as EXT_meshopt_compression streams, issue 28) against `--compression none`
//! with the real binary: the same tiles; full detail with the same triangles and vertices, every
//! decoded vertex (read with our test reader from the integer accessors, placed by the glTF node
//! hierarchy and instance transforms, as a client does; meshopt streams first decoded by
//! meshoptimizer's reference JavaScript decoder) within 1 mm per axis of the float one, and
//! simplified tiles within their own coarser grid; the extensions required; integer accessors
//! where the frame and ranges allow; fewer bytes; gltf-validator 0 errors on the tiles and on
//! their decoded data. Runs on the bundled sample and every model of ../shared/data.

use crate::common::*;
use glam::DVec3;
use serde_json::Value;
use std::collections::HashMap;
use std::path::Path;

/// Largest per-axis distance from each vertex of `b` to the nearest vertex of `a`, when it is at
/// most `within_m` (infinite otherwise).
fn worst_axis_deviation(a: &[DVec3], b: &[DVec3], within_m: f64) -> f64 {
    // Cells larger than the distance sought, searched with their neighbours.
    let cell_m = 0.01f64.max(within_m);
    let key = |p: DVec3| {
        (
            (p.x / cell_m).floor() as i64,
            (p.y / cell_m).floor() as i64,
            (p.z / cell_m).floor() as i64,
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

/// Counts of (POSITION, NORMAL, TEXCOORD_0) accessors stored as integers, and of all, in the
/// tile `uri` (named `tile` in messages).
fn integer_attributes(dir: &Path, uri: &str, tile: &str) -> ([usize; 3], [usize; 3]) {
    let json = glb_json(&content_bytes(dir, uri));
    let required: Vec<&str> = json["extensionsRequired"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(Value::as_str)
        .collect();
    assert!(
        required.contains(&"KHR_mesh_quantization"),
        "{tile}: KHR_mesh_quantization required"
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
                    assert_eq!(acc["normalized"], true, "{tile}: {name} normalized");
                    ints[k] += 1;
                }
            }
        }
    }
    (ints, all)
}

/// Every tile with geometry requires EXT_meshopt_compression, and its fallback buffer has no data.
fn assert_meshopt_required(dir: &Path) {
    let contents = tileset_contents(dir);
    assert!(!contents.is_empty());
    for (uri, bytes) in contents {
        let json = glb_json(&bytes);
        if json["meshes"].as_array().is_none_or(|m| m.is_empty()) {
            continue;
        }
        let required = json["extensionsRequired"].to_string();
        assert!(
            required.contains("EXT_meshopt_compression"),
            "{uri}: {required}"
        );
        let fallback = &json["buffers"][1];
        assert_eq!(
            fallback["extensions"]["EXT_meshopt_compression"]["fallback"],
            true
        );
        assert!(
            fallback.get("uri").is_none(),
            "{uri}: the fallback has no data"
        );
    }
}

/// `model` converted with `compression` ("quantized" or "meshopt") against `--compression none`.
fn check_model(model: &Path, compression: &str) {
    let name = model.file_stem().unwrap().to_string_lossy().to_string();
    let d = tmpdir(&format!("{compression}-{name}"));
    let (plain, quant) = (d.join("none"), d.join(compression));
    // The same tiles on both sides, so vertices compare one to one: no coarse root (whether a
    // one-tile model gets one depends on its bytes, so on the compression), and with meshopt the
    // tiles of `none` (materials apart, repeated shapes instanced from 100 saved triangles).
    let rp = convert(
        model,
        &plain,
        &["--compression", "none", "--no-coarse-root"],
    );
    let same_tiles = [
        "--keep-materials",
        "--min-instanced-triangles-saved",
        "100",
        "--no-coarse-root",
    ];
    let rq = convert(
        model,
        &quant,
        &[&["--compression", compression][..], &same_tiles].concat(),
    );
    assert_eq!(rp["output"]["tiles"], rq["output"]["tiles"]);
    assert!(
        rq["output"]["bytes"].as_u64() < rp["output"]["bytes"].as_u64(),
        "{name}: {compression} output is smaller"
    );
    if compression == "meshopt" {
        assert_meshopt_required(&quant);
        gltf_validator(&quant);
        let decoded = d.join("meshopt-decoded");
        let Some(views) = decode_meshopt(&quant, &decoded) else {
            return;
        };
        assert!(views > 0, "{name}: meshopt streams decoded");
        return check_against_plain(&name, &plain, &decoded, &rp, &rq);
    }
    check_against_plain(&name, &plain, &quant, &rp, &rq)
}

/// The quantized tileset `quant` (plain GLBs) against the float one, `plain`. Full-detail tiles
/// hold the same triangles, each vertex within 1 mm per axis. A simplified tile quantizes on its
/// own grid (a share of its error, reported per tile), whose flattened triangles it drops, and
/// so do its ancestors' simplifications: it is compared, within its grid, when it kept as many
/// triangles as the float one; its honesty against full detail is `tests/hlod.rs`'s.
fn check_against_plain(name: &str, plain: &Path, quant: &Path, rp: &Value, rq: &Value) {
    let (_, tp) = decode_tileset(plain);
    let (_, tq) = decode_tileset(quant);
    let grids_m = position_grids_m(rq);
    let (mut worst, mut ints, mut all) = (0.0f64, [0; 3], [0; 3]);
    let (mut coarse, mut coarse_compared) = (0, 0);
    for (a, b) in tp.iter().zip(&tq) {
        assert_eq!(a.name, b.name);
        let (Some(uri), Some(tile)) = (&b.uri, &b.name) else {
            continue;
        };
        let grid_m = grids_m.get(tile).copied();
        if grid_m.is_some_and(|g| g > 0.001 + 1e-9) {
            coarse += 1;
        }
        match grid_m {
            None => {
                assert_eq!(a.triangles, b.triangles, "{name}: {tile} triangles");
                assert_eq!(a.positions.len(), b.positions.len());
                worst = worst.max(worst_axis_deviation(&a.positions, &b.positions, 0.001));
            }
            Some(g) if a.triangles == b.triangles => {
                let d = worst_axis_deviation(&a.positions, &b.positions, g);
                // f32 rounding of the positions relative to the tile's centre and of the node
                // transform, as the test reads them (simplified tiles can be kilometres wide).
                let f32_m = 3e-7 * (b.box_max - b.box_min).length();
                assert!(
                    d <= g * (1.0 + 1e-6) + 1e-5 + f32_m,
                    "{name}: {tile} a vertex moved {d} m on an axis, its grid allows {g} m"
                );
                coarse_compared += 1;
            }
            Some(_) => assert!(
                b.triangles > 0 && b.triangles <= a.triangles,
                "{name}: {tile} keeps {} of {} triangles",
                b.triangles,
                a.triangles
            ),
        }
        let (i, n) = integer_attributes(quant, uri, tile);
        for k in 0..3 {
            ints[k] += i[k];
            all[k] += n[k];
        }
    }
    eprintln!(
        "{name}: worst per-axis deviation {:.3} mm; {coarse} tiles on a coarser grid, \
         {coarse_compared} compared; integer POSITION {}/{}, NORMAL {}/{}, TEXCOORD_0 {}/{}; \
         bytes {} vs {}",
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
    gltf_validator(quant);
}

#[test]
fn sample_quantized_tiles_stay_within_a_millimetre() {
    check_model(&sample(), "quantized");
}

#[test]
fn shared_models_quantized_tiles_stay_within_a_millimetre() {
    for model in shared_models() {
        check_model(&model, "quantized");
    }
}

#[test]
fn sample_meshopt_tiles_decode_within_a_millimetre() {
    check_model(&sample(), "meshopt");
}

#[test]
fn shared_models_meshopt_tiles_decode_within_a_millimetre() {
    for model in shared_models() {
        check_model(&model, "meshopt");
    }
}
