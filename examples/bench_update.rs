//! `make bench`: `convert --update` on a campus of about 100 buildings (a manifest over the shared
//! IFC and GLB models, each building its own file), against a full build: wall time, and files
//! and bytes written again, for an unchanged manifest, one building's file replaced by another
//! model, one building moved 50 m, one property value renamed in an IFC file, and one building
//! removed. Each update starts from the tileset the previous one left, and where its time went
//! (reading the models, dedup, the tiles) is printed after. Then the same campus built
//! and updated sharded (`plan --update --jobs 4`, each job's `build-job` one after another, `merge`):
//! the jobs an update runs, and the time of each step. Also writes `target/bench/update.json`.
//!
//! Usage: cargo run --release --example bench_update -- [DATA_DIR] [--buildings N]

use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// The models the campus cycles through (file names in the data folder), IFC and GLB mixed.
const MODELS: &[&str] = &[
    "AC20-FZK-Haus.glb",
    "duplex.glb",
    "IfcOpenHouse_IFC4.glb",
    "AC20-FZK-Haus.ifc",
    "ISSUE_021_Mini_Project.glb",
    "IfcOpenHouse_IFC4.ifc",
    "duplex.glb",
    "AC20-FZK-Haus.glb",
];
/// Distance between neighbouring buildings (metres).
const SPACING_M: f64 = 60.0;
/// The property value renamed (an IfcLabel of one element's property set in AC20-FZK-Haus.ifc).
const PROPERTY: (&str, &str) = ("IFCLABEL('Wendeltreppe')", "IFCLABEL('Spiral stair')");

/// A change made to the campus before an update, and its name.
type Change = (&'static str, Box<dyn Fn(&mut Campus)>);

struct Campus {
    dir: PathBuf,
    models: Vec<Value>,
}

impl Campus {
    fn write(&self) -> PathBuf {
        let m = self.dir.join("campus.json");
        let text = json!({
            "origin": {"longitude_deg": 8.4116, "latitude_deg": 49.0124, "height_m": 115.0},
            "models": self.models,
        });
        std::fs::write(&m, serde_json::to_vec_pretty(&text).unwrap()).unwrap();
        m
    }
}

/// Copies `from` to `to` as a file of its own (writable, so it can be edited).
fn copy(from: &Path, to: &Path) {
    let _ = std::fs::remove_file(to);
    std::fs::copy(from, to).unwrap();
    let mut perms = std::fs::metadata(to).unwrap().permissions();
    #[allow(clippy::permissions_set_readonly_false)]
    perms.set_readonly(false);
    std::fs::set_permissions(to, perms).unwrap();
}

/// Runs `bimtiles convert --manifest` with `extra`; the wall time and the report.
fn convert(bin: &Path, manifest: &Path, out: &Path, extra: &[&str]) -> (f64, Value) {
    let seconds = run(bin, |c| {
        c.args(["convert", "--manifest"])
            .arg(manifest)
            .arg("--out")
            .arg(out)
            .arg("--quiet")
            .args(extra);
    });
    let report = serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    (seconds, report)
}

/// Files of the tileset in `dir` (all but report.json and the cache), and those under tiles/.
fn count_files(dir: &Path) -> (usize, usize) {
    let files = bimtiles::update::tileset_files(dir).unwrap();
    let tiles = files
        .iter()
        .filter(|f| f.path.starts_with("tiles/"))
        .count();
    (files.len(), tiles)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut data = PathBuf::from("../shared/data");
    let mut buildings = 100usize;
    let mut i = 0;
    while i < args.len() {
        match args[i].as_str() {
            "--buildings" => {
                buildings = args[i + 1].parse().expect("--buildings N");
                i += 1;
            }
            a => data = PathBuf::from(a),
        }
        i += 1;
    }
    // The buildings replaced, moved and removed, and an IFC building apart from them whose
    // property is renamed.
    let middle = buildings / 2;
    let changed = middle..=middle + 2;
    let ifc = (0..buildings)
        .find(|b| MODELS[b % MODELS.len()] == "AC20-FZK-Haus.ifc" && !changed.contains(b));
    let Some(ifc) = ifc.filter(|_| *changed.end() < buildings) else {
        eprintln!("bench_update: --buildings {buildings} is too few: the changes need at least 8");
        std::process::exit(2);
    };
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let bin = repo.join("target/release/bimtiles");
    let root = repo.join("target/bench/update");
    let _ = std::fs::remove_dir_all(&root);
    let dir = root.join("campus");
    std::fs::create_dir_all(&dir).unwrap();
    let side = (buildings as f64).sqrt().ceil() as usize;
    let mut campus = Campus {
        dir: dir.clone(),
        models: Vec::new(),
    };
    for b in 0..buildings {
        let model = MODELS[b % MODELS.len()];
        let ext = Path::new(model).extension().unwrap().to_str().unwrap();
        let file = format!("b{b:03}.{ext}");
        copy(&data.join(model), &dir.join(&file));
        campus.models.push(json!({
            "name": format!("b{b:03}"),
            "path": file,
            "east_m": (b % side) as f64 * SPACING_M,
            "north_m": (b / side) as f64 * SPACING_M,
        }));
    }
    let manifest = campus.write();
    let out = root.join("tiles");
    // The first build with --update (a full build that leaves the update cache).
    let (full_s, report) = convert(&bin, &manifest, &out, &["--update"]);
    let (files, tiles) = count_files(&out);
    println!(
        "Campus: {buildings} buildings ({} triangles read, {} files), {files} tileset files ({tiles} tiles), {} bytes; full build {full_s:.1} s\n",
        report["input"]["triangles"],
        report["input"]["files"].as_array().map_or(0, Vec::len),
        report["output"]["bytes"],
    );
    let cache_bytes = dir_bytes(&out.join(".bimtiles"));
    let tileset_bytes: u64 = bimtiles::update::tileset_files(&out)
        .unwrap()
        .iter()
        .map(|f| f.bytes)
        .sum();
    println!(
        "Update cache (`.bimtiles/`): {cache_bytes} bytes, {:.1} % of the tileset's files ({tileset_bytes} bytes)\n",
        100.0 * cache_bytes as f64 / tileset_bytes as f64
    );
    println!("| change | update (s) | of a full build | files written | of all files | tiles written | bytes written | reused | removed | HLOD tiles built / written again / taken (simplified again) | full build because |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let mut rows = Vec::new();
    let changes: [Change; 5] = [
        ("unchanged manifest", Box::new(|_| {})),
        (
            "one building's file replaced",
            Box::new(move |c: &mut Campus| {
                let file = c.models[middle]["path"].as_str().unwrap().to_string();
                let other = if file.ends_with(".glb") {
                    "duplex.glb"
                } else {
                    "duplex.ifc"
                };
                let current = MODELS[middle % MODELS.len()];
                let other = if current == other {
                    "AC20-FZK-Haus.glb"
                } else {
                    other
                };
                let ext = Path::new(other).extension().unwrap().to_str().unwrap();
                let new_file = format!("b{middle:03}-new.{ext}");
                copy(&data.join(other), &c.dir.join(&new_file));
                c.models[middle]["path"] = json!(new_file);
            }),
        ),
        (
            "one building moved 50 m",
            Box::new(move |c: &mut Campus| {
                let east = c.models[middle + 1]["east_m"].as_f64().unwrap();
                c.models[middle + 1]["east_m"] = json!(east + 50.0);
            }),
        ),
        (
            "one IFC property value renamed",
            Box::new(move |c: &mut Campus| {
                let f = c.dir.join(c.models[ifc]["path"].as_str().unwrap());
                let text = std::fs::read_to_string(&f).unwrap();
                assert!(text.contains(PROPERTY.0));
                std::fs::write(&f, text.replacen(PROPERTY.0, PROPERTY.1, 1)).unwrap();
            }),
        ),
        (
            "one building removed",
            Box::new(move |c: &mut Campus| {
                c.models.remove(middle + 2);
            }),
        ),
    ];
    for (name, change) in changes.iter() {
        change(&mut campus);
        let manifest = campus.write();
        let before = inodes(&out);
        let (seconds, report) = convert(&bin, &manifest, &out, &["--update"]);
        let u = &report["update"];
        let after = inodes(&out);
        // A tile written again has a new inode; a reused one kept its own.
        let tiles_written = after
            .iter()
            .filter(|(path, ino)| path.starts_with("tiles/") && before.get(*path) != Some(ino))
            .count();
        let written = u["files_written"].as_u64().unwrap_or(0) as usize;
        let row = json!({
            "change": name,
            "seconds": seconds,
            "of_full_build": seconds / full_s,
            "files_written": written,
            "files": after.len(),
            "tiles_written": tiles_written,
            "tiles": after.keys().filter(|p| p.starts_with("tiles/")).count(),
            "bytes_written": u["bytes_written"],
            "files_reused": u["files_reused"],
            "files_removed": u["files_removed"],
            "internal_tiles_built": u["internal_tiles_built"],
            "internal_tiles": u["internal_tiles"],
            "tiles_rewritten": u["tiles_rewritten"],
            "tiles_reused": u["tiles_reused"],
            "tiles_remade": u["tiles_remade"],
            "reason": u["full_build_reason"],
            "mode": u["mode"],
            "timings_s": report["timings_s"],
            "hlod_timings_s": report["hlod_timings_s"],
        });
        println!(
            "| {name} | {seconds:.2} | {:.1} % | {written} | {:.1} % | {} of {} | {} | {} | {} | {} of {} / {} / {} ({}) | {} |",
            100.0 * seconds / full_s,
            100.0 * written as f64 / after.len().max(1) as f64,
            row["tiles_written"],
            row["tiles"],
            row["bytes_written"],
            row["files_reused"],
            row["files_removed"],
            u["internal_tiles_built"],
            u["internal_tiles"],
            u["tiles_rewritten"],
            u["tiles_reused"],
            u["tiles_remade"],
            // Input files named from the campus folder.
            u["full_build_reason"]
                .as_str()
                .map_or("-".into(), |r| r.replace(&format!("{}/", campus.dir.display()), "")),
        );
        rows.push(row);
    }
    print_phases(&rows);
    let sharded = sharded_updates(&bin, &mut campus, &root.join("tiles-sharded"), middle);
    let json = json!({"buildings": buildings, "full_build_s": full_s, "files": files, "tiles": tiles, "updates": rows, "sharded": sharded});
    std::fs::write(
        repo.join("target/bench/update.json"),
        serde_json::to_vec_pretty(&json).unwrap(),
    )
    .unwrap();
}

/// Where each update's time went, from its report's `timings_s` and `hlod_timings_s`: reading
/// the models (every entry is read while any input changed), dedup, and the tiles (leaves keyed,
/// taken or written; HLOD tiles taken, written again or built, with the CPU seconds their
/// simplifications and measurements took on all threads).
fn print_phases(rows: &[Value]) {
    println!(
        "\nWhere each update's time goes (`timings_s` and `hlod_timings_s` of its report.json):\n"
    );
    println!("| change | in all (s) | reading the models (s) | dedup (s) | tiles (s) | simplifying (CPU s) | measuring (CPU s) | measurements |");
    println!("|---|---|---|---|---|---|---|---|");
    for row in rows {
        if row["mode"] == "unchanged" {
            // Nothing was built: report.json keeps the last build's timings.
            println!(
                "| {} | {:.2} | no model read | | | | | 0 |",
                row["change"].as_str().unwrap_or("?"),
                row["seconds"].as_f64().unwrap_or(0.0)
            );
            continue;
        }
        let t = &row["timings_s"];
        let h = &row["hlod_timings_s"];
        let s = |v: &Value| v.as_f64().unwrap_or(0.0);
        let measuring = s(&h["measure_full_to_coarse"])
            + s(&h["measure_faces"])
            + s(&h["measure_coarse_to_full"]);
        println!(
            "| {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {measuring:.2} | {} |",
            row["change"].as_str().unwrap_or("?"),
            s(&row["seconds"]),
            s(&t["ingest"]),
            s(&t["dedup"]),
            s(&t["encode_write"]),
            s(&h["simplify"]),
            h["measurements"].as_u64().unwrap_or(0),
        );
    }
}

/// Jobs of a sharded update.
const SHARDED_JOBS: usize = 4;

/// The campus as it is built sharded into `out`, then updated sharded after one building moved
/// 50 m and with nothing changed: a table row and a JSON record each.
fn sharded_updates(bin: &Path, campus: &mut Campus, out: &Path, moved: usize) -> Vec<Value> {
    println!("\nSharded (`plan --update --jobs {SHARDED_JOBS}`, the jobs one after another, `merge`), from a fresh output folder:\n");
    println!("| change | plan (s) | jobs run | jobs (s, each) | merge (s) | in all (s) | of the sharded full build | files written |");
    println!("|---|---|---|---|---|---|---|---|");
    let mut rows: Vec<Value> = Vec::new();
    let steps: [Change; 3] = [
        ("full build", Box::new(|_| {})),
        (
            "one building moved 50 m",
            Box::new(move |c: &mut Campus| {
                let east = c.models[moved]["east_m"].as_f64().unwrap();
                c.models[moved]["east_m"] = json!(east + 50.0);
            }),
        ),
        ("unchanged manifest", Box::new(|_| {})),
    ];
    for (name, change) in steps.iter() {
        change(campus);
        let manifest = campus.write();
        let jobs = SHARDED_JOBS.to_string();
        let plan_s = run(bin, |c| {
            c.arg("plan")
                .arg("--manifest")
                .arg(&manifest)
                .arg("--out")
                .arg(out)
                .args(["--update", "--jobs", &jobs, "--quiet"]);
        });
        let state = out.join(bimtiles::shard::UPDATE_DIR);
        let plan: Value =
            serde_json::from_slice(&std::fs::read(state.join("plan.json")).unwrap()).unwrap();
        let changed: Vec<u64> = plan["jobs"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|j| j["changed"] == true)
            .map(|j| j["job"].as_u64().unwrap())
            .collect();
        let job_s: Vec<f64> = changed
            .iter()
            .map(|k| {
                run(bin, |c| {
                    c.arg("build-job")
                        .arg(out)
                        .args(["--job", &k.to_string(), "--quiet"]);
                })
            })
            .collect();
        let merge_s = run(bin, |c| {
            c.arg("merge").arg(out).arg("--quiet");
        });
        let report: Value =
            serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
        let total_s = plan_s + job_s.iter().sum::<f64>() + merge_s;
        let full_s = rows
            .first()
            .map_or(total_s, |r| r["seconds"].as_f64().unwrap());
        let written = report["update"]["files_written"].as_u64().unwrap_or(0);
        println!(
            "| {name} | {plan_s:.2} | {} of {SHARDED_JOBS} | {} | {merge_s:.2} | {total_s:.2} | {:.1} % | {written} |",
            changed.len(),
            job_s.iter().map(|s| format!("{s:.2}")).collect::<Vec<_>>().join(" + "),
            100.0 * total_s / full_s,
        );
        rows.push(json!({
            "change": name,
            "plan_s": plan_s,
            "jobs_run": changed,
            "job_s": job_s,
            "merge_s": merge_s,
            "seconds": total_s,
            "of_full_build": total_s / full_s,
            "files_written": written,
        }));
    }
    rows
}

/// Runs the bimtiles command `args` sets; its wall time. Panics if it fails.
fn run(bin: &Path, args: impl FnOnce(&mut Command)) -> f64 {
    let mut c = Command::new(bin);
    args(&mut c);
    let t = Instant::now();
    let o = c.output().expect("run bimtiles");
    let seconds = t.elapsed().as_secs_f64();
    assert!(
        o.status.success(),
        "{c:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    seconds
}

/// The bytes of the files below `dir`.
fn dir_bytes(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| match e.file_type() {
            Ok(t) if t.is_dir() => dir_bytes(&e.path()),
            _ => e.metadata().map_or(0, |m| m.len()),
        })
        .sum()
}

/// The inode of each file of the tileset in `dir`, by path.
fn inodes(dir: &Path) -> std::collections::BTreeMap<String, u64> {
    use std::os::unix::fs::MetadataExt;
    bimtiles::update::tileset_files(dir)
        .unwrap()
        .into_iter()
        .map(|f| {
            let ino = std::fs::metadata(dir.join(&f.path)).unwrap().ino();
            (f.path, ino)
        })
        .collect()
}
