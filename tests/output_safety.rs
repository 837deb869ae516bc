//! The output is never lost or clobbered (README, "Safety"): one run at a time per output, `--force`
//! replaces only after the new build is complete, a failed run leaves nothing it created, and the
//! temporary folders of killed runs are removed by the next run.

use crate::common::*;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    v.sort();
    v
}

/// A second conversion to an output that a running conversion is writing fails at once, with one
/// line; the first completes.
#[test]
fn two_runs_to_one_output() {
    let Some(airport) = shared_file("phnl_honolulu_airport.glb") else {
        return;
    };
    let dir = tmpdir("safety-concurrent");
    let out = dir.join("out");
    let first = Command::new(bin())
        .args(["convert", airport.to_str().unwrap(), "--out"])
        .arg(&out)
        .arg("--quiet")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let lock = dir.join(".out.lock");
    let t = Instant::now();
    while !lock.exists() {
        assert!(t.elapsed() < Duration::from_secs(30), "no lock taken");
        std::thread::sleep(Duration::from_millis(5));
    }
    let second = run(&[
        "convert",
        sample().to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&second.stderr);
    assert_eq!(second.status.code(), Some(1), "{err}");
    assert!(
        err.contains("another bimtiles run is writing this output"),
        "{err}"
    );
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    let first = first.wait_with_output().unwrap();
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert!(report["input"]["files"][0]
        .as_str()
        .unwrap()
        .ends_with("phnl_honolulu_airport.glb"));
    assert_eq!(names(&dir), vec!["out"], "no lock or temporary folder left");
}

/// `plan --force` and `convert --force` check their input before they replace anything: with an
/// unreadable input, the old build folder and tileset are left as they were.
#[test]
fn force_with_a_bad_input_keeps_the_old_output() {
    let dir = tmpdir("safety-force");
    let bad = dir.join("bad.glb");
    std::fs::write(&bad, b"not a model").unwrap();
    let plan = dir.join("plan");
    let sample = sample();
    let ok = run(&[
        "plan",
        sample.to_str().unwrap(),
        "--out",
        plan.to_str().unwrap(),
        "--jobs",
        "2",
    ]);
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    let before = std::fs::read(plan.join("plan.json")).unwrap();
    let o = run(&[
        "plan",
        bad.to_str().unwrap(),
        "--out",
        plan.to_str().unwrap(),
        "--jobs",
        "2",
        "--force",
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("bad.glb"));
    assert_eq!(std::fs::read(plan.join("plan.json")).unwrap(), before);
    assert!(plan.join("jobs").is_dir());

    let out = dir.join("tileset");
    convert(&sample, &out, &[]);
    let tileset = std::fs::read(out.join("tileset.json")).unwrap();
    let o = run(&[
        "convert",
        bad.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--force",
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(std::fs::read(out.join("tileset.json")).unwrap(), tileset);
    assert_eq!(names(&dir), vec!["bad.glb", "plan", "tileset"]);
}

/// A failed run removes the parent folders it created; a killed run's temporary folder is removed
/// by the next run to the same output.
#[test]
fn failed_and_killed_runs_leave_nothing_behind() {
    let dir = tmpdir("safety-leftovers");
    let bad = dir.join("bad.glb");
    std::fs::write(&bad, b"glTF").unwrap();
    let deep = dir.join("new/nested/out");
    let o = run(&[
        "convert",
        bad.to_str().unwrap(),
        "--out",
        deep.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(names(&dir), vec!["bad.glb"], "created parents removed");

    // A run killed mid-build leaves `.out.tmp-PID`: its process is gone, so the next run removes it.
    let mut child = Command::new("true").spawn().unwrap();
    let dead = child.id();
    child.wait().unwrap();
    let killed = dir.join(format!(".out.tmp-{dead}"));
    std::fs::create_dir_all(killed.join("tiles")).unwrap();
    std::fs::write(killed.join("tiles/r.glb"), b"half").unwrap();
    convert(&sample(), &dir.join("out"), &[]);
    assert_eq!(names(&dir), vec!["bad.glb", "out"]);
}

/// A panic, on any thread, ends as one `error:` line naming the input and exit code 1; the
/// details come with `RUST_BACKTRACE`.
#[test]
fn a_panic_is_one_error_line() {
    let dir = tmpdir("safety-panic");
    let input = sample();
    let out = dir.join("out");
    let run_with = |backtrace: &str| {
        Command::new(bin())
            .args([
                "convert",
                input.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ])
            .env("BIMTILES_TEST_PANIC", "1")
            .env("RUST_BACKTRACE", backtrace)
            .output()
            .unwrap()
    };
    let o = run_with("0");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.starts_with("error: "), "{err}");
    assert!(err.contains("sample_building.glb: internal error"), "{err}");
    assert!(err.contains("BIMTILES_TEST_PANIC is set"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(!out.exists());
    let o = run_with("1");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        err.contains("panicked") && err.contains("stack backtrace"),
        "{err}"
    );
}
