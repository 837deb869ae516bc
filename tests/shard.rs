//! Sharded builds (issue 12): `plan` / `build-job` (jobs in reverse order) / `merge` must give the
//! tileset `convert` gives, byte for byte: every tile, tileset.json, schema.json, the element
//! index, and report.json apart from timings, memory and the texture tallies of the merging
//! process. A job killed mid-write (simulated by its leftover temporary files) is not accepted by
//! `merge`, and rerunning only that job completes the build. A tiny `--memory-budget` (geometry
//! spilled to disk and read back) gives the same tileset too, for a campus of GLBs, for
//! CityJSON districts and for textured OBJ, FBX and CityGML models side by side.

use crate::common::*;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The sample placed four times by a manifest (2 × 2 grid, different headings).
fn sample_campus(dir: &Path) -> PathBuf {
    put_model_in(&sample(), dir);
    let models: Vec<Value> = (0..4)
        .map(|i| {
            serde_json::json!({"name": format!("b{i}"), "path": "sample_building.glb",
                "east_m": 45.0 * (i % 2) as f64, "north_m": 45.0 * (i / 2) as f64, "heading_deg": 20.0 * i as f64})
        })
        .collect();
    let m = dir.join("campus.json");
    std::fs::write(&m, serde_json::json!({ "models": models }).to_string()).unwrap();
    m
}

fn ok(args: &[&str]) {
    let o = run(args);
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Every file of a tileset folder but report.json and the sharding state, with its bytes.
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let rel = e
                .path()
                .strip_prefix(dir)
                .unwrap()
                .to_string_lossy()
                .to_string();
            if e.path().is_dir() {
                if rel != "jobs" {
                    stack.push(e.path());
                }
            } else if rel != "report.json" && rel != "plan.json" {
                out.insert(rel, std::fs::read(e.path()).unwrap());
            }
        }
    }
    out
}

/// report.json without what measures the run (timings, memory) or counts what the writing
/// process itself embedded (texture tallies).
fn report_content(dir: &Path) -> Value {
    let mut r: Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    let o = r.as_object_mut().unwrap();
    o.remove("timings_s");
    o.remove("hlod_timings_s");
    o.remove("peak_memory_bytes");
    o.remove("memory");
    if let Some(d) = o.get_mut("dedup").and_then(Value::as_object_mut) {
        d.remove("seconds");
    }
    if let Some(t) = o.get_mut("textures").and_then(Value::as_object_mut) {
        for k in [
            "written_per_level",
            "written_bytes",
            "pyramid_levels",
            "images",
        ] {
            t.remove(k);
        }
    }
    r
}

fn assert_identical(convert: &Path, sharded: &Path) {
    let (a, b) = (files(convert), files(sharded));
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "same files"
    );
    assert!(a.keys().filter(|k| k.starts_with("tiles/")).count() > 1);
    assert!(a.contains_key("element-index.json"), "the element index");
    for (name, bytes) in &a {
        assert!(
            bytes == &b[name],
            "{name} differs between {} and {}",
            convert.display(),
            sharded.display()
        );
    }
    assert_eq!(
        report_content(convert),
        report_content(sharded),
        "report.json content"
    );
}

/// `convert --manifest m --out out --quiet` with `extra` options.
fn convert_manifest(m: &str, out: &Path, extra: &[&str]) {
    let mut args = vec![
        "convert",
        "--manifest",
        m,
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ];
    args.extend_from_slice(extra);
    ok(&args);
}

/// plan / build-job (reverse order, or `order`) / merge into `dir`.
fn sharded(inputs: &[&str], dir: &Path, jobs: usize, extra: &[&str]) -> Value {
    let _ = std::fs::remove_dir_all(dir);
    let n = jobs.to_string();
    let mut args = vec!["plan"];
    args.extend_from_slice(inputs);
    args.extend_from_slice(&["--out", dir.to_str().unwrap(), "--jobs", &n, "--quiet"]);
    args.extend_from_slice(extra);
    ok(&args);
    for k in (0..jobs).rev() {
        ok(&[
            "build-job",
            dir.to_str().unwrap(),
            "--job",
            &k.to_string(),
            "--quiet",
        ]);
    }
    ok(&["merge", dir.to_str().unwrap(), "--quiet"]);
    serde_json::from_slice(&std::fs::read(dir.join("plan.json")).unwrap()).unwrap()
}

#[test]
fn sample_campus_sharded_is_byte_identical_to_convert() {
    let dir = tmpdir("shard-sample");
    let m = sample_campus(&dir);
    let m = m.to_str().unwrap();
    for (name, extra) in [
        ("hlod", vec!["--max-tile-triangles", "3000"]),
        ("add", vec!["--max-tile-triangles", "3000", "--lod", "none"]),
    ] {
        let conv = dir.join(format!("convert-{name}"));
        convert_manifest(m, &conv, &extra);
        for jobs in [1, 4] {
            let out = dir.join(format!("shard-{name}-{jobs}"));
            let plan = sharded(&["--manifest", m], &out, jobs, &extra);
            if jobs == 4 {
                // The split opens top levels and gives every job work: merge builds tiles too.
                assert!(!plan["top"].as_array().unwrap().is_empty(), "{plan}");
                for j in plan["jobs"].as_array().unwrap() {
                    assert!(j["tiles"].as_u64().unwrap() > 0, "{plan}");
                }
            }
            assert_identical(&conv, &out);
        }
    }
}

#[test]
fn killed_job_is_refused_and_a_rerun_completes() {
    let dir = tmpdir("shard-killed");
    let m = sample_campus(&dir);
    let m = m.to_str().unwrap();
    let extra = ["--max-tile-triangles", "3000"];
    let conv = dir.join("convert");
    ok(&[
        "convert",
        "--manifest",
        m,
        "--out",
        conv.to_str().unwrap(),
        "--quiet",
        extra[0],
        extra[1],
    ]);
    let out = dir.join("shard");
    let d = out.to_str().unwrap();
    ok(&[
        "plan",
        "--manifest",
        m,
        "--out",
        d,
        "--jobs",
        "3",
        "--quiet",
        extra[0],
        extra[1],
    ]);
    for k in ["2", "0"] {
        ok(&["build-job", d, "--job", k, "--quiet"]);
    }
    // Job 1 killed mid-write: half-written tile and result under temporary names only.
    std::fs::write(out.join("tiles/.r1.glb.tmp-4242"), b"glTF half").unwrap();
    std::fs::write(out.join("jobs/.job-1.bin.tmp-4242"), b"BIMTJOB1 half").unwrap();
    let o = run(&["merge", d, "--quiet"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("jobs 1)") && err.trim().lines().count() == 1,
        "{err}"
    );
    assert!(
        !out.join("tileset.json").exists(),
        "no tileset from an incomplete build"
    );
    // A damaged result under the final name is refused too.
    let good = std::fs::read(out.join("jobs/job-0.bin")).unwrap();
    std::fs::write(out.join("jobs/job-1.bin"), &good[..good.len() / 2]).unwrap();
    let o = run(&["merge", d, "--quiet"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("job-1.bin") && err.contains("truncated"),
        "{err}"
    );
    std::fs::write(out.join("jobs/job-1.bin"), &good).unwrap();
    let o = run(&["merge", d, "--quiet"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("another plan or job"),
        "{err}"
    );
    // Rerunning only job 1 completes the build; the leftovers are gone.
    ok(&["build-job", d, "--job", "1", "--quiet"]);
    ok(&["merge", d, "--quiet"]);
    assert!(
        !out.join("tiles/.r1.glb.tmp-4242").exists()
            && !out.join("jobs/.job-1.bin.tmp-4242").exists()
    );
    assert_identical(&conv, &out);
}

#[test]
fn real_campus_sharded_is_byte_identical() {
    // Without the shared data, the sample campus is tested instead.
    let (Some(make_campus), Some(fzk)) = (
        shared_file("make_campus.py"),
        shared_file("AC20-FZK-Haus.glb"),
    ) else {
        return;
    };
    let dir = tmpdir("shard-campus");
    let campus = dir.join("campus.glb");
    let o = std::process::Command::new("python3")
        .arg(make_campus)
        .arg(&campus)
        .args(["--copies", "3", "--bake", "--inputs"])
        .arg(fzk)
        .output()
        .expect("python3");
    assert!(
        o.status.success(),
        "make_campus.py: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let c = campus.to_str().unwrap();
    let extra = ["--max-tile-triangles", "8000"];
    let conv = dir.join("convert");
    ok(&[
        "convert",
        c,
        "--out",
        conv.to_str().unwrap(),
        "--quiet",
        extra[0],
        extra[1],
    ]);
    let out = dir.join("shard-4");
    sharded(&[c], &out, 4, &extra);
    assert_identical(&conv, &out);

    let tiny = dir.join("convert-tiny-budget");
    ok(&[
        "convert",
        c,
        "--out",
        tiny.to_str().unwrap(),
        "--quiet",
        extra[0],
        extra[1],
        "--memory-budget",
        "64K",
    ]);
    let (spilled, resident) = spilled_bytes(&tiny);
    assert!(
        spilled > 20 * resident,
        "{spilled} bytes spilled, {resident} kept"
    );
    // The elements' metadata records spilled too (past 4 KiB, a 256 KiB chunk at a time).
    let r: Value =
        serde_json::from_slice(&std::fs::read(tiny.join("report.json")).unwrap()).unwrap();
    let m = &r["memory"]["metadata"];
    assert!(m["spilled_bytes"].as_u64().unwrap() > 0, "{m}");
    assert_identical(&conv, &tiny);
}

/// Bytes of geometry report.json says were spilled to disk, and kept in memory.
fn spilled_bytes(dir: &Path) -> (u64, u64) {
    let r: Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    let g = &r["memory"]["geometry"];
    let n = |k: &str| {
        g[k].as_u64()
            .unwrap_or_else(|| panic!("no {k} in {}/report.json", dir.display()))
    };
    (n("spilled_bytes"), n("resident_bytes"))
}

#[test]
fn tiny_memory_budget_gives_the_same_tileset() {
    let dir = tmpdir("memory-budget");
    let m = sample_campus(&dir);
    let m = m.to_str().unwrap();
    let extra = ["--max-tile-triangles", "3000"];
    let run_convert = |name: &str, budget: &str| {
        let out = dir.join(name);
        let _ = std::fs::remove_dir_all(&out);
        ok(&[
            "convert",
            "--manifest",
            m,
            "--out",
            out.to_str().unwrap(),
            "--quiet",
            extra[0],
            extra[1],
            "--memory-budget",
            budget,
        ]);
        out
    };
    let full = run_convert("in-memory", "none");
    let default = run_convert("default-budget", "4G");
    assert_eq!(spilled_bytes(&default).0, 0, "the sample fits in 4 GB");
    // 64 KiB: a 16 KiB resident limit and a 4 KiB cache, so nearly every mesh is on disk and read
    // back each time it is used.
    let tiny = run_convert("tiny-budget", "64K");
    let (spilled, resident) = spilled_bytes(&tiny);
    assert!(
        spilled > 20 * resident,
        "{spilled} bytes spilled, {resident} kept"
    );
    assert_identical(&full, &default);
    assert_identical(&full, &tiny);

    // A sharded build under the same budget: every job and the merge spill too.
    let out = dir.join("shard-tiny");
    let mut args = extra.to_vec();
    args.extend_from_slice(&["--memory-budget", "64K"]);
    sharded(&["--manifest", m], &out, 2, &args);
    let (spilled, resident) = spilled_bytes(&out);
    assert!(
        spilled > 20 * resident,
        "{spilled} bytes spilled, {resident} kept"
    );
    assert_identical(&full, &out);
}

#[test]
fn bad_memory_options_are_refused_clearly() {
    let dir = tmpdir("memory-options");
    for (args, expect) in [
        (vec!["--memory-budget", "12Q"], "unknown unit"),
        (vec!["--memory-budget", "0"], "not a size"),
        (
            vec!["--spill-dir", "/nonexistent/spill"],
            "/nonexistent/spill",
        ),
    ] {
        let out = dir.join("out");
        let mut a = vec!["convert", "--out", out.to_str().unwrap(), "--quiet"];
        a.extend_from_slice(&args);
        let o = run(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && err.contains(expect),
            "{args:?}: {err}"
        );
        assert!(!out.exists(), "{args:?} left {}", out.display());
    }
}

/// CityJSON goes through campus manifests, sharded builds and the memory budget as any input does
/// (issue 31): two real Dutch datasets, each placed by its CRS, in one manifest; `convert`,
/// three jobs, and a tiny budget give the same tileset.
#[test]
fn cityjson_manifest_sharded_and_spilled_is_byte_identical() {
    let Some(data) = shared_data() else {
        return;
    };
    let dir = tmpdir("shard-cityjson");
    let models: Vec<Value> = [
        (
            "bag",
            "3dbag-5907-subset/3dbag_v210908_fd2cee53_5907_subset.json",
        ),
        ("denhaag", "denhaag-lod2/DenHaag_01.json"),
    ]
    .iter()
    .map(|(name, rel)| {
        let placed = put_model_in(&data.join("cityjson").join(rel), &dir);
        let file = placed.file_name().unwrap().to_str().unwrap();
        serde_json::json!({"name": name, "path": file, "crs": "EPSG:28992"})
    })
    .collect();
    let m = dir.join("district.json");
    std::fs::write(&m, serde_json::json!({ "models": models }).to_string()).unwrap();
    let m = m.to_str().unwrap();
    let extra = ["--max-tile-triangles", "8000"];

    let conv = dir.join("convert");
    convert_manifest(m, &conv, &extra);
    let report: Value =
        serde_json::from_slice(&std::fs::read(conv.join("report.json")).unwrap()).unwrap();
    assert_eq!(
        report["input"]["files"].as_array().unwrap().len(),
        2,
        "{}",
        report["input"]
    );
    assert!(
        report["input"]["components"].as_u64().unwrap() > 100,
        "{}",
        report["input"]
    );

    let out = dir.join("shard");
    sharded(&["--manifest", m], &out, 3, &extra);
    assert_identical(&conv, &out);

    let tiny = dir.join("tiny-budget");
    convert_manifest(m, &tiny, &[extra[0], extra[1], "--memory-budget", "64K"]);
    let (spilled, resident) = spilled_bytes(&tiny);
    assert!(
        spilled > 20 * resident,
        "{spilled} bytes spilled, {resident} kept"
    );
    assert_identical(&conv, &tiny);
}

/// Textured OBJ, FBX and CityGML models, each read by its own reader with its side files, go
/// through a manifest, sharded builds and the memory budget as a GLB campus does.
#[test]
fn textured_obj_fbx_and_citygml_sharded_and_spilled_are_byte_identical() {
    let (Some(obj), Some(fbx), Some(gml)) = (
        shared_file("obj/squareblock-building-textured/SquareBlock.obj"),
        shared_file("fbx/triangleblock-textured-binary/TriangleBlock.FBX"),
        shared_file("citygml/citygml4j-lod3-building-textured/lod3_building_v2.gml"),
    ) else {
        return;
    };
    let dir = tmpdir("shard-mesh-formats");
    let models: Vec<Value> = [("block", &obj), ("triangle", &fbx), ("gml", &gml)]
        .iter()
        .enumerate()
        .map(|(i, (name, model))| {
            let placed = put_folder_in(model, &dir, name);
            let file = placed.file_name().unwrap().to_string_lossy();
            serde_json::json!({"name": name, "path": format!("{name}/{file}"),
                "east_m": 80.0 * i as f64, "heading_deg": 15.0 * i as f64})
        })
        .collect();
    let m = dir.join("district.json");
    std::fs::write(&m, serde_json::json!({ "models": models }).to_string()).unwrap();
    let m = m.to_str().unwrap();
    let extra = ["--max-tile-triangles", "2000"];

    let conv = dir.join("convert");
    convert_manifest(m, &conv, &extra);
    let report = report_content(&conv);
    assert_eq!(report["input"]["files"].as_array().unwrap().len(), 3);
    // The three readers' textures: the block's facades, the FBX's and the CityGML appearances.
    assert!(
        report["textures"]["images_bound"].as_u64().unwrap_or(0) >= 3,
        "{}",
        report["textures"]
    );

    let out = dir.join("shard");
    sharded(&["--manifest", m], &out, 3, &extra);
    assert_identical(&conv, &out);

    let tiny = dir.join("tiny-budget");
    convert_manifest(m, &tiny, &[extra[0], extra[1], "--memory-budget", "64K"]);
    let (spilled, _) = spilled_bytes(&tiny);
    assert!(spilled > 0, "nothing spilled");
    assert_identical(&conv, &tiny);
}
