//! `make bench`: conversion throughput and peak memory of the real binary, per model, and Draco's
//! geometry compression ratio and encode throughput (each model converted with and without Draco).
//!
//! Runs `target/release/bimtiles convert` on every GLB and IFC file in the data folder given (default
//! `../shared/data`) and on campuses composed by `make_campus.py` at paper scale, each in its own
//! process (so peak memory is that conversion's), and prints one row per model from its
//! `report.json`, then the tiler stage alone (read, partition, write: `--lod none --compression
//! none --no-dedup`; issue 2's throughput and peak memory against the input), then a dedup/instancing table (issue 5) from the same reports, then the first
//! view (issue 4): tiles, levels, bytes and triangles a 3D Tiles client selects to draw the whole
//! model framed at 1920x1080 with a screen-space error limit of 16 px
//! ([`bimtiles::inspect::first_view`]) against the full model (every leaf), and the same
//! for `--lod hlod`, `--lod-ratios 0.85,0.7,0.5` and `--lod none` on Mini_Project. Also writes
//! `target/bench/tiler.json`.
//!
//! Usage: cargo run --release --example bench_tiler -- [DATA_DIR] [--budgets 10000,40000]
//!        cargo run --release --example bench_tiler -- --first-view TILESET_DIR...  (the first-view
//!        table of tilesets already written)

#[path = "../tests/support/glb.rs"]
#[allow(dead_code)]
mod glb;
#[path = "../tests/support/height_field.rs"]
#[allow(dead_code)]
mod height_field;

use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Bytes of geometry in a tileset's tiles: the bufferViews holding Draco streams or vertex/index
/// accessors (not images, not property tables).
fn geometry_bytes(dir: &Path) -> u64 {
    let mut total = 0;
    for e in std::fs::read_dir(dir.join("tiles"))
        .into_iter()
        .flatten()
        .flatten()
    {
        let Ok(bytes) = std::fs::read(e.path()) else {
            continue;
        };
        let Ok(glb) = gltf::binary::Glb::from_slice(&bytes) else {
            continue;
        };
        let Ok(doc) = serde_json::from_slice::<Value>(&glb.json) else {
            continue;
        };
        let views = doc["bufferViews"].as_array().cloned().unwrap_or_default();
        let mut geometry = std::collections::BTreeSet::new();
        for a in doc["accessors"].as_array().into_iter().flatten() {
            if let Some(v) = a["bufferView"].as_u64() {
                geometry.insert(v);
            }
        }
        for m in doc["meshes"].as_array().into_iter().flatten() {
            for p in m["primitives"].as_array().into_iter().flatten() {
                let draco = p.pointer("/extensions/KHR_draco_mesh_compression/bufferView");
                if let Some(v) = draco.and_then(Value::as_u64) {
                    geometry.insert(v);
                }
            }
        }
        total += geometry
            .iter()
            .filter_map(|&v| views.get(v as usize)?["byteLength"].as_u64())
            .sum::<u64>();
    }
    total
}

fn convert(
    bin: &Path,
    input: &Path,
    out: &Path,
    budget: usize,
    compression: &str,
    extra: &[&str],
) -> Option<Value> {
    let st = Command::new(bin)
        .args([
            "convert",
            input.to_str()?,
            "--out",
            out.to_str()?,
            "--force",
            "--quiet",
        ])
        .args([
            "--max-tile-triangles",
            &budget.to_string(),
            "--compression",
            compression,
        ])
        .args(extra)
        .status()
        .ok()?;
    if !st.success() {
        eprintln!("conversion of {} failed", input.display());
        return None;
    }
    serde_json::from_slice(&std::fs::read(out.join("report.json")).ok()?).ok()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().is_some_and(|a| a == "--first-view") {
        first_view_header();
        for dir in &args[1..] {
            first_view_row(dir, &first_view(Path::new(dir)));
        }
        return;
    }
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let data = args
        .iter()
        .find(|a| !a.starts_with("--"))
        .map(PathBuf::from)
        .unwrap_or_else(|| repo.join("../shared/data"));
    let budgets: Vec<usize> = args
        .iter()
        .position(|a| a == "--budgets")
        .and_then(|i| args.get(i + 1))
        .map(|s| s.split(',').filter_map(|x| x.parse().ok()).collect())
        .unwrap_or_else(|| vec![bimtiles::partition::OctreeOptions::default().max_tile_triangles]);
    let bin = repo.join("target/release/bimtiles");
    let work = repo.join("target/bench");
    std::fs::create_dir_all(&work).unwrap();

    let mut inputs: Vec<PathBuf> = vec![repo.join("samples/sample_building.glb")];
    if data.is_dir() {
        let mut glbs: Vec<PathBuf> = std::fs::read_dir(&data)
            .unwrap()
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "glb" || e == "ifc"))
            .collect();
        glbs.sort();
        inputs.extend(glbs);
        // Paper-scale inputs: real components, synthetic layout (see MANIFEST.md).
        let script = data.join("make_campus.py");
        // Jittered copies are near-twins dedup cannot share (every part stored); exact copies
        // become instances at full detail, while HLOD tiles stay plain geometry.
        for (name, copies, jitter_m) in [
            ("campus-1.9M", 8, "0.002"),
            ("campus-1.9M-exact", 8, "0"),
            ("campus-8.2M", 34, "0.002"),
        ] {
            let out = work.join(format!("{name}.glb"));
            if !out.exists() {
                let ok = Command::new("python3")
                    .arg(&script)
                    .arg(&out)
                    .args(["--copies", &copies.to_string(), "--inputs"])
                    .arg(data.join("ISSUE_021_Mini_Project.glb"))
                    .args(["--bake", "--jitter-m", jitter_m])
                    .status()
                    .is_ok_and(|s| s.success());
                if !ok {
                    eprintln!("make_campus.py failed for {name}");
                    continue;
                }
            }
            inputs.push(out);
        }
    } else {
        eprintln!(
            "{} not found: benchmarking the bundled sample only",
            data.display()
        );
    }
    // One huge surface: a mesh far over the tile budget, cut across tiles.
    let surface = work.join("surface-1M.glb");
    if !surface.exists() {
        std::fs::write(&surface, height_field::height_field_glb(708, 2000.0)).unwrap();
    }
    inputs.push(surface);

    println!(
        "{:<26} {:>6} {:>9} {:>6} {:>5} {:>8} {:>7} {:>7} {:>8} {:>7} {:>7} {:>9} {:>11}",
        "model",
        "budget",
        "triangles",
        "tiles",
        "depth",
        "out MB",
        "secs",
        "Mtri/s",
        "peak MB",
        "peak/in",
        "draco %",
        "draco s",
        "draco Mtri/s"
    );
    let mut rows = Vec::new();
    for input in &inputs {
        for &budget in &budgets {
            // IFC files share their stem with the GLB exports of the same model.
            let name = match input.extension().is_some_and(|e| e == "ifc") {
                true => input.file_name().unwrap().to_string_lossy().to_string(),
                false => input.file_stem().unwrap().to_string_lossy().to_string(),
            };
            let out = work.join(format!("out-{name}-{budget}"));
            let Some(r) = convert(&bin, input, &out, budget, "draco", &[]) else {
                continue;
            };
            let draco_geometry = geometry_bytes(&out);
            let plain = work.join(format!("out-{name}-{budget}-none"));
            let plain_report = convert(&bin, input, &plain, budget, "none", &[]);
            let plain_geometry = geometry_bytes(&plain);
            let _ = std::fs::remove_dir_all(&plain);
            // The tiler stage alone (issue 2): read, octree partition and plain GLB write; no
            // dedup (its own stage, in the dedup table below), no LOD, no compression.
            let tiler_dir = work.join(format!("out-{name}-{budget}-tiler"));
            let tiler_args = ["--lod", "none", "--no-dedup"];
            let tiler = convert(&bin, input, &tiler_dir, budget, "none", &tiler_args);
            let _ = std::fs::remove_dir_all(&tiler_dir);
            let encode_plain_s = plain_report
                .as_ref()
                .and_then(|p| p["timings_s"]["encode_write"].as_f64())
                .unwrap_or(0.0);
            let tris = r["input"]["triangles"].as_f64().unwrap_or(0.0);
            let secs = r["timings_s"]["total"].as_f64().unwrap_or(0.0);
            let in_bytes = r["input"]["bytes"].as_f64().unwrap_or(1.0);
            let peak = r["peak_memory_bytes"].as_f64().unwrap_or(0.0);
            let row = json!({
                "model": name, "budget": budget, "input_bytes": in_bytes, "triangles": tris,
                "tiles": r["output"]["tiles"], "max_depth": r["output"]["max_depth"],
                "output_bytes": r["output"]["bytes"], "seconds": secs, "timings_s": r["timings_s"],
                "mtri_per_s": tris / secs.max(1e-9) / 1e6, "peak_memory_bytes": peak,
                "peak_over_input": peak / in_bytes,
                "geometry_bytes_draco": draco_geometry, "geometry_bytes_uncompressed": plain_geometry,
                "draco_geometry_ratio": draco_geometry as f64 / plain_geometry.max(1) as f64,
                "encode_write_s_uncompressed": encode_plain_s,
                "dedup": r["dedup"], "instances": r["output"]["instances"],
                "instanced_shapes": r["output"]["instanced_shapes"],
                "stored_triangles": r["output"]["stored_triangles"],
                "output_triangles": r["output"]["triangles"],
                "first_view": first_view(&out),
                "tiler_stage": tiler.as_ref().map(|t| json!({
                    "seconds": t["timings_s"]["total"], "timings_s": t["timings_s"],
                    "peak_memory_bytes": t["peak_memory_bytes"],
                })),
            });
            // Draco's own cost: encode+write with Draco minus without.
            let draco_s =
                (r["timings_s"]["encode_write"].as_f64().unwrap_or(0.0) - encode_plain_s).max(1e-6);
            println!(
                "{:<26} {:>6} {:>9} {:>6} {:>5} {:>8.2} {:>7.3} {:>7.2} {:>8.1} {:>7.2} {:>7.1} {:>9.3} {:>11.2}",
                name,
                budget,
                tris,
                r["output"]["tiles"],
                r["output"]["max_depth"],
                r["output"]["bytes"].as_f64().unwrap_or(0.0) / 1e6,
                secs,
                tris / secs.max(1e-9) / 1e6,
                peak / 1e6,
                peak / in_bytes,
                draco_geometry as f64 / plain_geometry.max(1) as f64 * 100.0,
                draco_s,
                tris / draco_s / 1e6
            );
            let _ = std::fs::remove_dir_all(&out);
            rows.push(row);
        }
    }
    // The tiler stage (issue 2's targets: at least 3M input triangles/s end to end, peak memory
    // under 3x the input).
    println!("\ntiler stage alone (--lod none --compression none --no-dedup):");
    println!(
        "{:<26} {:>6} {:>9} {:>7} {:>7} {:>8} {:>8} {:>7}",
        "model", "budget", "triangles", "secs", "Mtri/s", "in MB", "peak MB", "peak/in"
    );
    for r in &rows {
        let t = &r["tiler_stage"];
        let f = |v: &Value| v.as_f64().unwrap_or(0.0);
        if !t.is_object() {
            continue;
        }
        println!(
            "{:<26} {:>6} {:>9} {:>7.3} {:>7.2} {:>8.2} {:>8.1} {:>7.2}",
            r["model"].as_str().unwrap_or(""),
            f(&r["budget"]),
            f(&r["triangles"]),
            f(&t["seconds"]),
            f(&r["triangles"]) / f(&t["seconds"]).max(1e-9) / 1e6,
            f(&r["input_bytes"]) / 1e6,
            f(&t["peak_memory_bytes"]) / 1e6,
            f(&t["peak_memory_bytes"]) / f(&r["input_bytes"]).max(1.0)
        );
    }
    // Dedup (paper III.A): what it found, what it saves, what it costs, per conversion above.
    println!(
        "\n{:<26} {:>6} {:>10} {:>7} {:>9} {:>8} {:>9} {:>12} {:>8} {:>7} {:>9} {:>10}",
        "model",
        "budget",
        "components",
        "shapes",
        "congruent",
        "removed",
        "instances",
        "stored/drawn",
        "scene MB",
        "saved %",
        "dedup s",
        "% of total"
    );
    for r in &rows {
        let d = &r["dedup"];
        if !d.is_object() {
            continue;
        }
        let f = |v: &Value| v.as_f64().unwrap_or(0.0);
        println!(
            "{:<26} {:>6} {:>10} {:>7} {:>9} {:>8} {:>9} {:>12.3} {:>8.2} {:>7.1} {:>9.3} {:>10.1}",
            r["model"].as_str().unwrap_or(""),
            f(&r["budget"]),
            f(&d["components"]),
            f(&d["unique_shapes"]),
            f(&d["congruent_rewritten"]),
            f(&d["redundant_removed"]),
            f(&r["instances"]),
            f(&r["stored_triangles"]) / f(&r["output_triangles"]).max(1.0),
            f(&d["bytes_before"]) / 1e6,
            (1.0 - f(&d["bytes_after"]) / f(&d["bytes_before"]).max(1.0)) * 100.0,
            f(&d["seconds"]),
            f(&d["seconds"]) / f(&r["seconds"]).max(1e-9) * 100.0
        );
    }
    // First view (issue 4): what a client loads to draw the whole model framed on screen.
    println!(
        "\nfirst view at 1920x1080, SSE 16 px, whole model framed (default options), against all leaves:"
    );
    first_view_header();
    for r in &rows {
        first_view_row(r["model"].as_str().unwrap_or(""), &r["first_view"]);
    }
    // The LOD modes side by side on Mini_Project.
    let mut modes = Vec::new();
    if let Some(mini) = inputs.iter().find(|p| {
        p.file_name()
            .is_some_and(|n| n == "ISSUE_021_Mini_Project.glb")
    }) {
        println!(
            "\nfirst view of Mini_Project per LOD mode (budget {}):",
            budgets[0]
        );
        first_view_header();
        for (mode, extra) in [
            ("hlod", vec!["--lod", "hlod"]),
            ("ratios 0.85,0.7,0.5", vec!["--lod-ratios", "0.85,0.7,0.5"]),
            ("none", vec!["--lod", "none"]),
        ] {
            let out = work.join("out-mini-lod");
            if convert(&bin, mini, &out, budgets[0], "draco", &extra).is_some() {
                let v = first_view(&out);
                first_view_row(mode, &v);
                modes.push(json!({"mode": mode, "first_view": v}));
            }
            let _ = std::fs::remove_dir_all(&out);
        }
    }
    let rows = json!({"conversions": rows, "mini_project_lod_modes": modes});
    std::fs::write(
        work.join("tiler.json"),
        serde_json::to_vec_pretty(&rows).unwrap(),
    )
    .unwrap();
    println!("written {}", work.join("tiler.json").display());
}

/// The first view and the full model of the tileset in `dir` (see the module docs), as JSON.
fn first_view(dir: &Path) -> Value {
    use bimtiles::inspect::first_view as view;
    match (
        view::first_view(dir, &bimtiles::tileset::view::ViewOptions::default()),
        view::full_view(dir),
    ) {
        (Ok(first), Ok(full)) => json!({
            "first": first, "full": full,
            "bytes_share": first.glb_bytes as f64 / full.glb_bytes.max(1) as f64,
            "triangles_share": first.triangles as f64 / full.triangles.max(1) as f64,
        }),
        (a, b) => {
            eprintln!("first view of {} failed: {a:?} {b:?}", dir.display());
            Value::Null
        }
    }
}

fn first_view_header() {
    println!(
        "{:<26} {:>6} {:>6} {:>10} {:>11} {:>7} {:>10} {:>11} {:>7}",
        "model",
        "tiles",
        "levels",
        "first MB",
        "first tris",
        "full t.",
        "full MB",
        "full tris",
        "bytes %"
    );
}

fn first_view_row(name: &str, v: &Value) {
    let f = |p: &str| v.pointer(p).and_then(Value::as_f64).unwrap_or(0.0);
    println!(
        "{:<26} {:>6} {:>6} {:>10.3} {:>11} {:>7} {:>10.3} {:>11} {:>7.1}",
        name,
        f("/first/tiles"),
        f("/first/levels"),
        f("/first/glb_bytes") / 1e6,
        f("/first/triangles"),
        f("/full/tiles"),
        f("/full/glb_bytes") / 1e6,
        f("/full/triangles"),
        f("/bytes_share") * 100.0
    );
}
