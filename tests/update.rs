//! `convert --update` (the book's "Updating a tileset"): every update of a campus equals a full
//! build of the new manifest, file for file and byte for byte; the files whose bytes did not
//! change stay the same files; an unchanged manifest reads no model; a missing or corrupt cache is
//! a full build with one line saying why; a killed update leaves the old tileset or the new one.
//! A sharded update (`plan`/`build-job`/`merge` with `--update`) runs only the jobs whose
//! subtrees changed and gives the same tileset and tile cache.

use crate::common::*;
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

const STATE: &str = bimtiles::update::STATE_FILE;
const TILE_CACHE: &str = ".bimtiles/tile-cache.bin";

/// A campus manifest in its own folder, its models copied in (so they can be edited).
struct Campus {
    dir: PathBuf,
    models: Vec<Value>,
}

impl Campus {
    fn new(name: &str) -> Campus {
        Campus {
            dir: tmpdir(name),
            models: Vec::new(),
        }
    }

    /// Adds `model` (copied in under `file`) placed at (east, north) metres.
    fn add(&mut self, name: &str, model: &Path, file: &str, east_m: f64, north_m: f64) {
        let to = self.dir.join(file);
        if !to.exists() {
            std::fs::copy(model, &to).unwrap();
            let mut perms = std::fs::metadata(&to).unwrap().permissions();
            #[allow(clippy::permissions_set_readonly_false)]
            perms.set_readonly(false);
            std::fs::set_permissions(&to, perms).unwrap();
        }
        self.models
            .push(json!({"name": name, "path": file, "east_m": east_m, "north_m": north_m}));
    }

    fn manifest(&self) -> PathBuf {
        let m = self.dir.join("campus.json");
        let text = json!({
            "origin": {"longitude_deg": 8.4116, "latitude_deg": 49.0124, "height_m": 115.0},
            "models": self.models,
        });
        std::fs::write(&m, text.to_string()).unwrap();
        m
    }

    /// The arguments of `convert --manifest` into `out` with `extra` options.
    fn args(&self, out: &Path, extra: &[&str]) -> Vec<String> {
        let m = self.manifest();
        let mut args: Vec<String> = ["convert", "--manifest"].map(String::from).to_vec();
        args.push(m.to_string_lossy().to_string());
        args.extend(["--out".to_string(), out.to_string_lossy().to_string()]);
        args.extend(["--max-tile-triangles", "4000"].map(String::from));
        args.extend(extra.iter().map(|a| a.to_string()));
        args
    }

    /// Runs `convert --manifest` into `out` with `extra` options.
    fn try_convert(&self, out: &Path, extra: &[&str]) -> std::process::Output {
        let args = self.args(out, extra);
        run(&args.iter().map(String::as_str).collect::<Vec<_>>())
    }

    /// [`Campus::try_convert`], which must succeed.
    fn convert(&self, out: &Path, extra: &[&str]) -> std::process::Output {
        let o = self.try_convert(out, extra);
        assert!(
            o.status.success(),
            "convert failed: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        o
    }
}

/// Every file of the tileset in `dir` (all but report.json and the update cache), by path.
fn tileset_files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(dir: &Path, prefix: &str, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let e = e.unwrap();
            let name = e.file_name().to_string_lossy().to_string();
            if prefix.is_empty() && (name == "report.json" || name == ".bimtiles") {
                continue;
            }
            let rel = format!("{prefix}{name}");
            if e.file_type().unwrap().is_dir() {
                walk(&e.path(), &format!("{rel}/"), out);
            } else {
                out.insert(rel, std::fs::read(e.path()).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, "", &mut out);
    out
}

/// Inode and modification time of each file of the tileset in `dir`.
fn identities(dir: &Path) -> BTreeMap<String, (u64, i64, i64)> {
    tileset_files(dir)
        .into_keys()
        .map(|f| {
            let m = std::fs::metadata(dir.join(&f)).unwrap();
            (f, (m.ino(), m.mtime(), m.mtime_nsec()))
        })
        .collect()
}

fn report(dir: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap()
}

/// Updates `out` to the campus as it is now and checks the result against a full build of it
/// (`full`): the same files with the same bytes; the files whose bytes did not change are the
/// same files as before; the report's counts are those files. Returns the update's report.
fn update_and_compare(campus: &Campus, out: &Path, full: &Path, extra: &[&str]) -> Value {
    let before = tileset_files(out);
    let ids_before = identities(out);
    let mut args = vec!["--update", "--quiet"];
    args.extend_from_slice(extra);
    campus.convert(out, &args);
    let _ = std::fs::remove_dir_all(full);
    // A full build with the same options: `--update` into a folder of its own.
    let mut full_args = vec!["--update", "--quiet"];
    full_args.extend_from_slice(extra);
    campus.convert(full, &full_args);
    let after = tileset_files(out);
    let expected = tileset_files(full);
    assert_eq!(
        after.keys().collect::<Vec<_>>(),
        expected.keys().collect::<Vec<_>>(),
        "the update has the full build's files"
    );
    for (name, bytes) in &expected {
        assert!(
            after[name] == *bytes,
            "{name} differs from the full build's"
        );
    }
    let ids_after = identities(out);
    let u = report(out)["update"].clone();
    let mut reused = 0;
    for (name, bytes) in &after {
        if before.get(name) == Some(bytes) {
            reused += 1;
            assert_eq!(ids_after[name], ids_before[name], "{name} kept as it was");
        }
    }
    let removed = before.keys().filter(|k| !after.contains_key(*k)).count();
    assert_eq!(u["files_reused"], reused, "{u}");
    assert_eq!(u["files_written"], after.len() - reused, "{u}");
    assert_eq!(u["files_removed"], removed, "{u}");
    assert_eq!(u["mode"], "rebuilt", "{u}");
    assert_tile_counts(out, &u);
    let cache_bytes: u64 = [STATE, TILE_CACHE]
        .iter()
        .map(|f| std::fs::metadata(out.join(f)).unwrap().len())
        .sum();
    let tileset_bytes: usize = after.values().map(Vec::len).sum();
    assert!(
        cache_bytes as f64 <= 0.1 * tileset_bytes as f64,
        "the cache ({cache_bytes} bytes) is at most 10 % of the tileset ({tileset_bytes})"
    );
    u
}

/// The update's tile counts agree with each other and with the tile cache written.
fn assert_tile_counts(out: &Path, u: &Value) {
    let n = |k: &str| u[k].as_u64().unwrap_or_else(|| panic!("{k} in {u}"));
    assert_eq!(
        n("internal_tiles_built") + n("tiles_reused") + n("tiles_rewritten"),
        n("internal_tiles"),
        "{u}"
    );
    assert!(n("tiles_remade") <= n("internal_tiles"), "{u}");
    assert!(n("tiles_built") >= n("internal_tiles_built"), "{u}");
    let cache = std::fs::metadata(out.join(TILE_CACHE)).unwrap().len();
    assert_eq!(n("tile_cache_bytes"), cache, "{u}");
}

/// An update that took some HLOD tiles from the tile cache: it built fewer than the tileset has.
/// Returns how many of them had their hand-over made again from its recipe.
fn assert_some_tiles_reused(u: &Value) -> u64 {
    let n = |k: &str| u[k].as_u64().unwrap();
    assert!(n("tiles_reused") > 0, "{u}");
    assert!(n("internal_tiles_built") < n("internal_tiles"), "{u}");
    assert!(n("tile_bytes_reused") > 0, "{u}");
    // Unchanged leaves are taken whole too, not encoded again.
    assert!(n("leaves_reused") > 0 && n("leaf_bytes_reused") > 0, "{u}");
    n("tiles_remade")
}

/// Replace a model, move one, remove one, rename one element's property: each update equals a
/// full build of the new manifest; an unchanged manifest builds nothing and touches no file.
#[test]
fn every_update_equals_a_full_build_of_the_new_manifest() {
    let (Some(fzk_glb), Some(duplex), Some(fzk_ifc)) = (
        shared_file("AC20-FZK-Haus.glb"),
        shared_file("duplex.glb"),
        shared_file("AC20-FZK-Haus.ifc"),
    ) else {
        return;
    };
    // Untextured models: tiles with textures are not taken from the tile cache.
    let mut campus = Campus::new("update-campus");
    campus.add("a", &duplex, "a.glb", 0.0, 0.0);
    campus.add("b", &duplex, "b.glb", 120.0, 0.0);
    campus.add("c", &duplex, "a.glb", 0.0, 120.0);
    campus.add("d", &fzk_ifc, "d.ifc", 120.0, 120.0);
    let out = campus.dir.join("out");
    let full = campus.dir.join("full");
    campus.convert(&out, &["--update", "--quiet"]);

    // Unchanged: nothing built, no file touched, one line says so.
    let ids = identities(&out);
    let o = campus.convert(&out, &["--update"]);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("up to date, nothing built"), "{said}");
    assert_eq!(identities(&out), ids);
    let u = &report(&out)["update"];
    assert_eq!(u["mode"], "unchanged", "{u}");
    assert_eq!(
        (u["files_written"].as_u64(), u["files_reused"].as_u64()),
        (Some(0), Some(ids.len() as u64))
    );

    // A new model under the same file name, with the old file's modification time: the content
    // hash sees it.
    let b = campus.dir.join("b.glb");
    let mtime = std::fs::metadata(&b).unwrap().modified().unwrap();
    std::fs::copy(&fzk_glb, &b).unwrap();
    std::fs::File::options()
        .write(true)
        .open(&b)
        .unwrap()
        .set_modified(mtime)
        .unwrap();
    let u = update_and_compare(&campus, &out, &full, &[]);
    assert!(
        u["changed_inputs"][0].as_str().unwrap().ends_with("b.glb"),
        "{u}"
    );
    // Tiles whose hand-over a built parent needed, not kept in the cache: made again.
    let mut remade = assert_some_tiles_reused(&u);

    // One building moved 50 m.
    campus.models[2]["east_m"] = json!(50.0);
    let u = update_and_compare(&campus, &out, &full, &[]);
    assert!(u["files_reused"].as_u64().unwrap() > 0, "{u}");
    remade += assert_some_tiles_reused(&u);

    // One element's property value renamed in the IFC file.
    let d = campus.dir.join("d.ifc");
    let text = std::fs::read_to_string(&d).unwrap();
    let old = "IFCLABEL('Wendeltreppe')";
    assert!(text.contains(old), "the IFC file has the property");
    std::fs::write(&d, text.replacen(old, "IFCLABEL('Spiral stair')", 1)).unwrap();
    let u = update_and_compare(&campus, &out, &full, &[]);
    assert!(u["files_reused"].as_u64().unwrap() > 0, "{u}");
    // Its geometry is the same: the HLOD tiles above it are written again with the new property
    // table in their files, none is simplified, none has its content made again.
    assert_eq!(assert_some_tiles_reused(&u), 0, "{u}");
    assert_eq!(u["internal_tiles_built"], 0, "{u}");
    assert!(u["tiles_rewritten"].as_u64().unwrap() > 0, "{u}");
    // The leaf that draws it is written again (its property table changed), not taken.
    assert!(
        u["tiles_built"].as_u64().unwrap() > u["tiles_rewritten"].as_u64().unwrap(),
        "{u}"
    );

    // Renamed back, with every live HLOD tile's file altered since it was written: no table is
    // replaced in a file that is not as written; their content is made again and encoded.
    for tile in report(&out)["tiles"].as_array().unwrap() {
        if let (Some(uri), Some(_)) = (
            tile["content"].as_str(),
            tile.get("simplified_from_triangles"),
        ) {
            let mut f = std::fs::OpenOptions::new()
                .append(true)
                .open(out.join(uri))
                .unwrap();
            std::io::Write::write_all(&mut f, b"    ").unwrap();
        }
    }
    std::fs::write(&d, text).unwrap();
    let u = update_and_compare(&campus, &out, &full, &[]);
    assert_eq!(u["internal_tiles_built"], 0, "{u}");
    assert_eq!(u["tiles_reused"], 0, "{u}");
    remade += u["tiles_remade"].as_u64().unwrap();

    // One building removed, the old files kept for clients that hold the old tileset.json; the
    // next update, without --keep-stale, removes them.
    let before = tileset_files(&out);
    campus.models.remove(1);
    campus.convert(&out, &["--update", "--quiet", "--keep-stale"]);
    let _ = std::fs::remove_dir_all(&full);
    campus.convert(&full, &["--update", "--quiet"]);
    let (kept, expected) = (tileset_files(&out), tileset_files(&full));
    let stale: Vec<&String> = before
        .keys()
        .filter(|k| !expected.contains_key(*k))
        .collect();
    assert!(!stale.is_empty(), "removing a building removes some tile");
    assert_eq!(report(&out)["update"]["files_kept_stale"], stale.len());
    remade += assert_some_tiles_reused(&report(&out)["update"]);
    assert!(remade > 0, "some hand-over made again from its recipe");
    for (name, bytes) in &kept {
        assert!(
            expected.get(name).or(before.get(name)) == Some(bytes),
            "{name}: the new build's file, or a stale one as it was"
        );
    }
    assert_eq!(kept.len(), expected.len() + stale.len());
    campus.convert(&out, &["--update", "--quiet"]);
    assert_eq!(tileset_files(&out), expected, "stale files removed");
    let u = &report(&out)["update"];
    assert_eq!(
        (u["mode"].as_str(), u["files_removed"].as_u64()),
        (Some("unchanged"), Some(stale.len() as u64))
    );
}

/// The reason an update must give, what spoils the cache before it, and the update's options.
type Spoiled<'a> = (&'a str, &'a dyn Fn(), &'a [&'a str]);

/// A missing, corrupt or foreign cache, changed options, or no tileset yet: a full build, one
/// line saying why (stderr and report.json), and the result a full build gives.
#[test]
fn a_missing_or_corrupt_cache_is_a_full_build_with_one_line_note() {
    let mut campus = Campus::new("update-fallbacks");
    campus.add("a", &sample(), "a.glb", 0.0, 0.0);
    campus.add("b", &sample(), "a.glb", 80.0, 0.0);
    let out = campus.dir.join("out");
    let full = campus.dir.join("full");
    let o = campus.convert(&out, &["--update"]);
    let note = |o: &std::process::Output| {
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        let notes: Vec<&str> = err
            .lines()
            .filter(|l| l.starts_with("note: update:"))
            .collect();
        assert_eq!(notes.len(), 1, "{err}");
        notes[0].to_string()
    };
    assert!(note(&o).ends_with("full build: no tileset at the output yet"));
    let plain = campus.dir.join("plain");
    campus.convert(&plain, &["--quiet"]);
    assert!(
        !plain.join(".bimtiles").exists(),
        "a plain build leaves no cache"
    );
    campus.convert(&full, &["--update", "--quiet"]);
    let expected = tileset_files(&full);
    let cases: [Spoiled; 4] = [
        (
            "no update cache",
            &|| std::fs::remove_file(out.join(STATE)).unwrap(),
            &[],
        ),
        (
            "the update cache is corrupt",
            &|| std::fs::write(out.join(STATE), b"{\"format\": 1, \"tool").unwrap(),
            &[],
        ),
        (
            "the update cache has format 99",
            &|| {
                let mut s: Value =
                    serde_json::from_slice(&std::fs::read(out.join(STATE)).unwrap()).unwrap();
                s["format"] = json!(99);
                std::fs::write(out.join(STATE), s.to_string()).unwrap();
            },
            &[],
        ),
        ("the options changed", &|| {}, &["--compression", "draco"]),
    ];
    for (reason, spoil, extra) in cases {
        spoil();
        let mut args = vec!["--update"];
        args.extend_from_slice(extra);
        let line = note(&campus.convert(&out, &args));
        assert!(line.contains(reason), "{line}");
        let r = report(&out);
        assert!(r["update"]["full_build_reason"]
            .as_str()
            .unwrap()
            .contains(reason));
        if extra.is_empty() {
            assert_eq!(tileset_files(&out), expected);
        }
        assert!(out.join(STATE).is_file(), "the cache is written again");
    }
    // The bundled sample (no input given) is updated too.
    let sample_out = campus.dir.join("sample");
    for mode in ["rebuilt", "unchanged"] {
        let o = run(&[
            "convert",
            "--out",
            sample_out.to_str().unwrap(),
            "--update",
            "--quiet",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert_eq!(report(&sample_out)["update"]["mode"], mode);
    }
    // A foreign folder is never taken for a tileset to update.
    let mine = campus.dir.join("mine");
    std::fs::create_dir_all(&mine).unwrap();
    std::fs::write(mine.join("notes.txt"), "user data").unwrap();
    let o = campus.try_convert(&mine, &["--update"]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(
        std::fs::read_to_string(mine.join("notes.txt")).unwrap(),
        "user data"
    );
}

/// The start of the tile cache in `out` (its format's mark) cut short, and the mark of the format
/// before it.
fn cut_and_older_cache(out: &Path) -> (Vec<u8>, Vec<u8>) {
    let mark = std::fs::read(out.join(TILE_CACHE)).unwrap()[..8].to_vec();
    let mut older = mark.clone();
    older[7] -= 1;
    (
        [&mark[..], b" cut"].concat(),
        [&older[..], b" old"].concat(),
    )
}

/// A spoiled tile cache (the update state intact): every tile built, one line saying why, the
/// full build's result; the next update takes tiles from the cache written again.
#[test]
fn a_spoiled_tile_cache_is_a_full_build_with_one_line_note() {
    let Some(duplex) = shared_file("duplex.glb") else {
        return;
    };
    let mut campus = Campus::new("update-tile-cache");
    campus.add("a", &duplex, "a.glb", 0.0, 0.0);
    campus.add("b", &duplex, "a.glb", 120.0, 0.0);
    let out = campus.dir.join("out");
    let full = campus.dir.join("full");
    campus.convert(&out, &["--update", "--quiet"]);
    let note = |o: &std::process::Output| {
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        let notes: Vec<&str> = err
            .lines()
            .filter(|l| l.starts_with("note: update:"))
            .collect();
        assert_eq!(notes.len(), 1, "{err}");
        notes[0].to_string()
    };
    // A spoiled tile cache, with an input changed: every tile built, one line saying why, and
    // the full build's result.
    let (cut, old) = cut_and_older_cache(&out);
    for (spoil, reason) in [
        (cut.as_slice(), "the tile cache is corrupt"),
        (b"not a cache".as_slice(), "the tile cache is corrupt"),
        (old.as_slice(), "the tile cache is of another format"),
    ] {
        campus.models[1]["east_m"] = json!(campus.models[1]["east_m"].as_f64().unwrap() + 10.0);
        std::fs::write(out.join(TILE_CACHE), spoil).unwrap();
        let line = note(&campus.convert(&out, &["--update"]));
        assert!(line.contains("full build: 1 input file changed"), "{line}");
        assert!(line.contains(reason), "{line}");
        let u = &report(&out)["update"];
        assert_eq!(u["tiles_reused"], 0, "{u}");
        assert!(u["tile_cache_note"].as_str().unwrap().contains(reason));
        let _ = std::fs::remove_dir_all(&full);
        campus.convert(&full, &["--update", "--quiet"]);
        assert_eq!(tileset_files(&out), tileset_files(&full));
        // The cache is written again, and the next update takes tiles from it.
        campus.models[1]["east_m"] = json!(campus.models[1]["east_m"].as_f64().unwrap() + 10.0);
        let line = note(&campus.convert(&out, &["--update"]));
        assert!(
            line.contains("HLOD tiles reused from the tile cache"),
            "{line}"
        );
        let _ = std::fs::remove_dir_all(&full);
        campus.convert(&full, &["--update", "--quiet"]);
        assert_eq!(tileset_files(&out), tileset_files(&full));
    }
}

/// An update killed (SIGKILL) at spread-out moments leaves the old tileset or the new one, never
/// a mix; the next update finishes the job and removes the killed run's folder.
#[test]
fn killed_updates_leave_the_old_or_the_new_tileset() {
    let Some(fzk) = shared_file("AC20-FZK-Haus.glb") else {
        return;
    };
    let mut campus = Campus::new("update-killed");
    campus.add("a", &sample(), "a.glb", 0.0, 0.0);
    campus.add("b", &fzk, "b.glb", 100.0, 0.0);
    campus.add("c", &sample(), "a.glb", 0.0, 100.0);
    let pristine = campus.dir.join("pristine");
    campus.convert(&pristine, &["--update", "--quiet"]);
    let old = tileset_files(&pristine);
    campus.models[1]["east_m"] = json!(150.0);
    let full = campus.dir.join("full");
    let t = Instant::now();
    campus.convert(&full, &["--update", "--quiet"]);
    let build = t.elapsed();
    let new = tileset_files(&full);
    assert_ne!(old, new);
    let out = campus.dir.join("out");
    // Moments spread over a build's time, in a fixed pseudo-random order.
    let mut x: u32 = 2_463_534_242;
    let mut outcomes = BTreeMap::new();
    for round in 0..8 {
        let _ = std::fs::remove_dir_all(&out);
        let cp = Command::new("cp")
            .arg("-a")
            .arg(&pristine)
            .arg(&out)
            .status()
            .unwrap();
        assert!(cp.success());
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        let delay = build.mul_f64(f64::from(x % 1000) / 1000.0 * 1.2);
        let mut child = Command::new(bin())
            .args(campus.args(&out, &["--update", "--quiet"]))
            .spawn()
            .unwrap();
        std::thread::sleep(delay);
        let _ = child.kill();
        child.wait().unwrap();
        let now = tileset_files(&out);
        let which = if now == old {
            "old"
        } else if now == new {
            "new"
        } else {
            panic!("round {round}: killed after {delay:?}, the output is neither tileset")
        };
        *outcomes.entry(which).or_insert(0) += 1;
    }
    eprintln!("killed updates left: {outcomes:?}");
    campus.convert(&out, &["--update", "--quiet"]);
    assert_eq!(tileset_files(&out), new);
    let leftovers: Vec<String> = std::fs::read_dir(&campus.dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .filter(|n| n.starts_with(".out."))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    assert!(build > Duration::ZERO);
}

/// The box (tileset frame, metres) of the elements of building `name` in the tileset in `dir`,
/// from its element index; `None` if it has none.
fn building_box(dir: &Path, name: &str) -> Option<[f64; 6]> {
    let index: Value =
        serde_json::from_slice(&std::fs::read(dir.join("element-index.json")).unwrap()).unwrap();
    let ids = index["columns"]["id"].as_array().unwrap();
    let boxes = index["columns"]["box_mm"].as_array().unwrap();
    assert_eq!(
        boxes.len(),
        6 * ids.len(),
        "six millimetre figures an element"
    );
    let prefix = format!("{name}/");
    let mut b = [f64::MAX, f64::MAX, f64::MAX, f64::MIN, f64::MIN, f64::MIN];
    let mut any = false;
    for (i, id) in ids.iter().enumerate() {
        if !id.as_str().unwrap().starts_with(&prefix) {
            continue;
        }
        let mm: Vec<f64> = (0..6)
            .map(|k| boxes[6 * i + k].as_f64().unwrap() / 1000.0)
            .collect();
        for k in 0..3 {
            b[k] = b[k].min(mm[k]);
            b[k + 3] = b[k + 3].max(mm[k + 3]);
        }
        any = true;
    }
    any.then_some(b)
}

/// The content files of the tiles of `tileset` (tileset.json's bytes) whose bounding box meets
/// one of `boxes` (tileset frame, 1 cm of slack), and of their ancestors: what a change inside
/// those boxes may rewrite, worked out from the tree alone.
fn tiles_meeting(tileset: &[u8], boxes: &[[f64; 6]]) -> std::collections::BTreeSet<String> {
    fn visit(
        tile: &Value,
        boxes: &[[f64; 6]],
        ancestors: &mut Vec<String>,
        out: &mut std::collections::BTreeSet<String>,
    ) {
        let uri = tile["content"]["uri"].as_str().map(String::from);
        let b = tile["boundingVolume"]["box"].as_array().unwrap();
        let f = |i: usize| b[i].as_f64().unwrap();
        // Boxes in the tileset frame are axis-aligned: half-axes along x, y, z.
        let (centre, half) = ([f(0), f(1), f(2)], [f(3), f(7), f(11)]);
        let meets = boxes.iter().any(|c| {
            (0..3).all(|k| {
                centre[k] - half[k].abs() <= c[k + 3] + 0.01
                    && c[k] - 0.01 <= centre[k] + half[k].abs()
            })
        });
        if meets {
            out.extend(ancestors.iter().cloned());
            out.extend(uri.clone());
        }
        ancestors.extend(uri.clone());
        for c in tile["children"].as_array().into_iter().flatten() {
            visit(c, boxes, ancestors, out);
        }
        if uri.is_some() {
            ancestors.pop();
        }
    }
    let tileset: Value = serde_json::from_slice(tileset).unwrap();
    let mut out = std::collections::BTreeSet::new();
    visit(&tileset["root"], boxes, &mut Vec::new(), &mut out);
    out
}

/// The tileset's own files every build writes again when any content changes: the tree, the
/// schema and the element index.
const TILESET_WIDE_FILES: [&str; 3] = ["tileset.json", "schema.json", "element-index.json"];

/// A campus of buildings `b0`..`b8` on a 3 × 3 grid 60 m apart, building `bK` drawing the
/// `K % 3`-th of three shared models, in the order of `cells` (the Ks); `None` without the shared
/// data. Untextured models: a texture shared by several tiles is written once, as its own file,
/// so a building's textures would reach every tile that shares them.
fn grid_campus(name: &str, cells: &[usize]) -> Option<Campus> {
    let models = [
        ("AC20-FZK-Haus.glb", "fzk.glb"),
        ("duplex.glb", "duplex.glb"),
        ("IfcOpenHouse_IFC4.glb", "house.glb"),
    ];
    let mut campus = Campus::new(name);
    for &b in cells {
        let (shared, file) = models[b % 3];
        let (east, north) = ((b % 3) as f64 * 60.0, (b / 3) as f64 * 60.0);
        campus.add(&format!("b{b}"), &shared_file(shared)?, file, east, north);
    }
    Some(campus)
}

/// A building removed at the campus's edge (which moves the campus's bounds): the files the update writes
/// with new bytes are the tiles whose boxes meet the building's old or new box and their
/// ancestors (and the tileset-wide files), all but a few; and the update equals a full build.
#[test]
fn a_removal_rewrites_only_the_tiles_it_touches() {
    let Some(mut campus) = grid_campus("update-local", &[0, 1, 2, 3, 4, 5, 6, 7, 8]) else {
        return;
    };
    let out = campus.dir.join("out");
    let full = campus.dir.join("full");
    campus.convert(&out, &["--update", "--quiet"]);
    type Change<'a> = (&'a str, &'a dyn Fn(&mut Campus));
    let changes: [Change; 1] = [("b8", &|c| {
        c.models.remove(8);
    })];
    for (building, change) in changes {
        let before = tileset_files(&out);
        let old_box = building_box(&out, building);
        change(&mut campus);
        update_and_compare(&campus, &out, &full, &[]);
        let after = tileset_files(&out);
        let boxes: Vec<[f64; 6]> = old_box
            .into_iter()
            .chain(building_box(&out, building))
            .collect();
        assert!(!boxes.is_empty(), "{building} has elements");
        let mut may_change = tiles_meeting(&after["tileset.json"], &boxes);
        may_change.extend(tiles_meeting(&before["tileset.json"], &boxes));
        may_change.extend(TILESET_WIDE_FILES.map(String::from));
        let rewritten: Vec<&String> = after
            .iter()
            .filter(|(name, bytes)| before.get(*name) != Some(bytes))
            .map(|(name, _)| name)
            .collect();
        let outside: Vec<&&String> = rewritten
            .iter()
            .filter(|n| !may_change.contains(n.as_str()))
            .collect();
        // A few may lie beyond: an ancestor that held some of the building and cut what stays in
        // it to the budget cuts other meshes once it is gone, and their parts go to other cells.
        assert!(
            outside.len() * 50 <= after.len(),
            "{building}: {} of {} files rewritten away from the change: {outside:?}",
            outside.len(),
            rewritten.len()
        );
        assert!(
            after.len() - rewritten.len() > after.len() / 2,
            "{building}: most files kept ({} of {} rewritten)",
            rewritten.len(),
            after.len()
        );
    }
}

/// The share of the HLOD tiles an update took from the tile cache.
fn share_reused(u: &Value) -> f64 {
    let n = |k: &str| u[k].as_u64().unwrap() as f64;
    n("tiles_reused") / n("internal_tiles")
}

/// The first entry of a manifest replaced or removed renumbers every element, mesh and material
/// after it, and leaves their tiles as they were: most HLOD tiles are taken from the tile cache,
/// and the update equals a full build. Entries swapped (their ids in another order) equal a full
/// build too.
#[test]
fn a_changed_first_entry_keeps_the_tiles_of_the_others() {
    // The first entry stands in the middle of the campus, so that changing it leaves the
    // campus's bounds (and so the octree's cells) as they are.
    let Some(mut campus) = grid_campus("update-first-entry", &[4, 0, 1, 2, 3, 5, 6, 7, 8]) else {
        return;
    };
    let out = campus.dir.join("out");
    let full = campus.dir.join("full");
    campus.convert(&out, &["--update", "--quiet"]);

    // The first entry's model replaced by another (with another number of elements): its cells
    // change, and their ancestors, a good share of this small campus's tiles.
    campus.models[0]["path"] = json!("house.glb");
    let u = update_and_compare(&campus, &out, &full, &[]);
    assert!(share_reused(&u) > 0.3, "the other tiles reused: {u}");

    // The first entry removed.
    campus.models.remove(0);
    let u = update_and_compare(&campus, &out, &full, &[]);
    assert!(share_reused(&u) > 0.65, "most HLOD tiles reused: {u}");

    // The first two entries swapped: their ids change order, and only the tiles that merge both
    // are built again.
    campus.models.swap(0, 1);
    let u = update_and_compare(&campus, &out, &full, &[]);
    assert!(share_reused(&u) > 0.65, "most HLOD tiles reused: {u}");
}

/// The stderr lines of `o` that are update notes.
fn update_notes(o: &std::process::Output) -> Vec<String> {
    String::from_utf8_lossy(&o.stderr)
        .lines()
        .filter(|l| l.starts_with("note: update:"))
        .map(String::from)
        .collect()
}

/// A sharded update of `out` to the campus as it is now (`plan --update` with `jobs` jobs, every
/// job's `build-job`, then `merge`): the plan (plan.json) and the update notes of plan and merge.
/// A job the plan marks unchanged succeeds and leaves no result file.
fn sharded_update(campus: &Campus, out: &Path, jobs: usize) -> (Value, Vec<String>) {
    let n = jobs.to_string();
    let mut args = campus.args(out, &["--update", "--jobs", &n]);
    args[0] = "plan".into();
    let ok = |o: std::process::Output, what: &str| {
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{what}: {err}");
        o
    };
    let planned = ok(
        run(&args.iter().map(String::as_str).collect::<Vec<_>>()),
        "plan",
    );
    let build = out.join(bimtiles::shard::UPDATE_DIR);
    let plan: Value =
        serde_json::from_slice(&std::fs::read(build.join("plan.json")).unwrap()).unwrap();
    let d = out.to_str().unwrap();
    for job in plan["jobs"].as_array().unwrap() {
        let k = job["job"].to_string();
        ok(run(&["build-job", d, "--job", &k, "--quiet"]), "build-job");
        let result = build.join(format!("jobs/job-{k}.bin"));
        assert_eq!(result.is_file(), job["changed"] == true, "job {k}: {job}");
    }
    let merged = ok(run(&["merge", d]), "merge");
    assert!(
        !build.exists(),
        "the build folder goes with the old tileset"
    );
    let mut notes = update_notes(&planned);
    notes.extend(update_notes(&merged));
    (plan, notes)
}

/// How many of the plan's jobs are marked changed, and how many not.
fn jobs_changed(plan: &Value) -> (usize, usize) {
    let jobs = plan["jobs"].as_array().unwrap();
    let changed = jobs.iter().filter(|j| j["changed"] == true).count();
    (changed, jobs.len() - changed)
}

/// A sharded update (`plan`/`build-job`/`merge` with `--update`) runs only the jobs whose
/// subtrees changed and gives what `convert` and `convert --update` give: every tileset file,
/// byte for byte, and the same tile cache; an unchanged campus runs no job and touches no file;
/// `convert --update` carries on from it.
#[test]
fn a_sharded_update_runs_only_changed_jobs_and_equals_a_full_build() {
    let (Some(fzk), Some(duplex), Some(house)) = (
        shared_file("AC20-FZK-Haus.glb"),
        shared_file("duplex.glb"),
        shared_file("IfcOpenHouse_IFC4.glb"),
    ) else {
        return;
    };
    let mut campus = Campus::new("update-sharded");
    campus.add("a", &duplex, "a.glb", 0.0, 0.0);
    campus.add("b", &fzk, "b.glb", 120.0, 0.0);
    campus.add("c", &house, "c.glb", 0.0, 120.0);
    campus.add("d", &duplex, "a.glb", 120.0, 120.0);
    campus.add("e", &house, "c.glb", 240.0, 0.0);
    campus.add("f", &duplex, "a.glb", 240.0, 120.0);
    let out = campus.dir.join("out");
    let full = campus.dir.join("full");
    // The first build: every job runs.
    let (plan, notes) = sharded_update(&campus, &out, 4);
    assert_eq!(jobs_changed(&plan), (4, 0), "{plan}");
    assert!(
        notes[0].ends_with("full build: no tileset at the output yet"),
        "{notes:?}"
    );
    campus.convert(&full, &["--update", "--quiet"]);
    assert_eq!(tileset_files(&out), tileset_files(&full));

    // One building's model replaced.
    let single = campus.dir.join("single");
    let copied = Command::new("cp").arg("-a").arg(&out).arg(&single).status();
    assert!(copied.unwrap().success());
    let before = identities(&out);
    std::fs::copy(&house, campus.dir.join("b.glb")).unwrap();
    let (plan, notes) = sharded_update(&campus, &out, 4);
    let (changed, unchanged) = jobs_changed(&plan);
    assert!(changed > 0 && unchanged > 0, "{plan}");
    assert_eq!(
        notes.len(),
        2,
        "one note from plan, one from merge: {notes:?}"
    );
    assert!(
        notes[0].contains(&format!("{changed} of 4 jobs to run")),
        "{notes:?}"
    );
    let _ = std::fs::remove_dir_all(&full);
    campus.convert(&full, &["--update", "--quiet"]);
    let (after, expected) = (tileset_files(&out), tileset_files(&full));
    assert_eq!(
        after.keys().collect::<Vec<_>>(),
        expected.keys().collect::<Vec<_>>()
    );
    for (name, bytes) in &expected {
        assert!(
            after[name] == *bytes,
            "{name} differs from the full build's"
        );
    }
    let u = report(&out)["update"].clone();
    assert_some_tiles_reused(&u);
    assert_tile_counts(&out, &u);
    // Every input the state records was hashed, and is counted.
    let state: Value = serde_json::from_slice(&std::fs::read(out.join(STATE)).unwrap()).unwrap();
    let inputs = state["inputs"].as_array().unwrap();
    let bytes: u64 = inputs.iter().map(|i| i["bytes"].as_u64().unwrap()).sum();
    assert!(!inputs.is_empty() && bytes > 0, "{state}");
    assert_eq!(u["inputs_hashed"], inputs.len(), "{u}");
    assert_eq!(u["input_bytes_hashed"], bytes, "{u}");
    let ids = identities(&out);
    let kept = ids
        .iter()
        .filter(|(f, id)| before.get(*f) == Some(id))
        .count();
    assert_eq!(u["files_reused"], kept, "{u}");
    // `convert --update` of the same change: the same tileset and the same tile cache.
    campus.convert(&single, &["--update", "--quiet"]);
    assert_eq!(tileset_files(&single), after);
    let cache = |dir: &Path| std::fs::read(dir.join(TILE_CACHE)).unwrap();
    assert!(
        cache(&single) == cache(&out),
        "the tile cache of convert --update"
    );

    // Nothing changed: no job runs, no file is touched; a killed plan's folder is removed.
    let killed_plan = out.join(".bimtiles/shard.tmp-99999999");
    std::fs::create_dir_all(killed_plan.join("jobs")).unwrap();
    let (plan, _) = sharded_update(&campus, &out, 4);
    assert!(!killed_plan.exists());
    assert_eq!(jobs_changed(&plan), (0, 4), "{plan}");
    assert_eq!(identities(&out), ids);
    assert_eq!(report(&out)["update"]["mode"], "unchanged");
    // The state the sharded update left is the one `convert --update` reads.
    let o = campus.convert(&out, &["--update"]);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("up to date, nothing built"), "{said}");
}

/// A sharded update over a spoiled tile cache: every job with HLOD tiles runs, one line from plan
/// and one from merge say why, and the result is the full build's.
#[test]
fn a_sharded_update_with_a_corrupt_cache_is_a_full_build_with_one_line_note() {
    let Some(duplex) = shared_file("duplex.glb") else {
        return;
    };
    let mut campus = Campus::new("update-sharded-spoiled");
    campus.add("a", &duplex, "a.glb", 0.0, 0.0);
    campus.add("b", &duplex, "a.glb", 120.0, 0.0);
    let out = campus.dir.join("out");
    let full = campus.dir.join("full");
    campus.convert(&out, &["--update", "--quiet"]);
    campus.models[1]["east_m"] = json!(130.0);
    std::fs::write(out.join(TILE_CACHE), cut_and_older_cache(&out).0).unwrap();
    let (plan, notes) = sharded_update(&campus, &out, 3);
    for job in plan["jobs"].as_array().unwrap() {
        // A job of leaves alone has no work: the plan built them.
        let roots = job["roots"].as_array().unwrap().len();
        let hlod = job["tiles"].as_u64().unwrap() > roots as u64;
        assert_eq!(
            job["changed"], hlod,
            "every job with HLOD tiles runs: {plan}"
        );
    }
    assert_eq!(notes.len(), 2, "{notes:?}");
    for note in &notes {
        assert!(note.contains("full build: 1 input file changed"), "{note}");
        assert!(note.contains("the tile cache is corrupt"), "{note}");
    }
    assert_eq!(report(&out)["update"]["tiles_reused"], 0);
    campus.convert(&full, &["--update", "--quiet"]);
    assert_eq!(tileset_files(&out), tileset_files(&full));
}
