//! `make bench-scale`: issue 12's measurements. How conversion time and peak memory grow with the
//! input, from 1M to 100M triangles, and how much a sharded build gains on a local Ray cluster.
//!
//! 1. Campuses are composed by `../shared/data/make_campus.py OUT --copies C --inputs
//!    ISSUE_021_Mini_Project.glb --bake [--jitter-m 0.002]` (the project venv's Python, numpy), one
//!    per size and variant: `exact` copies (dedup can make them instances) and `jitter` (2 mm noise,
//!    no two copies congruent, every triangle stored). Sizes are whole copies of Mini_Project
//!    (241,016 triangles): 1M = 4, 32M = 133, 100M = 415 copies, and `8M` is the issue's 8.2M
//!    campus (34 copies). They are cached in
//!    `target/bench/scale/` (100M is about 2.5 GB a variant), and the campuses `make bench` made
//!    (`target/bench/campus-1.9M.glb`, `-1.9M-exact`, `-8.2M`: the same commands) are reused.
//! 2. Each is converted by `target/release/bimtiles convert IN --out DIR --force --quiet` (default
//!    options: HLOD, Draco), in its own process: wall seconds, peak memory (the larger of
//!    report.json's `peak_memory_bytes` and the child's max RSS from GNU `time`, when installed),
//!    output bytes and tiles, stage timings. A failed conversion is recorded with its log and the
//!    bench goes on.
//! 3. The growth exponents of time and memory against triangles (least squares on log-log) per
//!    variant, and a log-log chart of both.
//! 4. Sharding: `bimtiles plan` into 4 jobs, the jobs run one after another with one thread each,
//!    then the same plan run by `tools/ray_driver.py --threads 1` on a local Ray cluster of two
//!    one-CPU nodes (inside `unshare -n`, loopback only, as tests/python/test_ray_shard.py does):
//!    the ratio of the job phases (the driver's, from submitting the tasks to the last result,
//!    over the sum of the sequential jobs), and both merged tilesets compared byte for byte. A
//!    private PID namespace too, where permitted: every Ray process ends with the run, and
//!    `ray stop` sees no other cluster on the machine.
//!
//! Writes OUT (default `target/bench/scale`)/{scale.json, scale.md, scale.png} (MB = 10^6 bytes,
//! GB = 10^9), the issue's targets marked PASS/FAIL, and prints the markdown; exits non-zero,
//! after writing them, when a conversion or the sharded build failed.
//!
//! Usage: cargo run --release --features charts --example bench_scale -- [--sizes 1M,8M,32M,100M]
//!        [--variants exact,jitter] [--skip-ray] [--ray-size 8M] [--ray-variant jitter]
//!        [--ray-jobs 4] [--keep] [--out DIR] [--campus-dir DIR] [--shared DIR] [--python PATH]
//!        [--memory-budget-gb 4]
//! Sizes take K/M suffixes and fractions (`0.5M`). `--keep` keeps the tilesets and build folders.
//! The shared folder is `--shared`, else $BIMTILES_SHARED, else `../shared`. Text in the chart
//! needs a TrueType font: $BIMTILES_FONT or the usual DejaVu / Liberation paths.

#[path = "common/chart_font.rs"]
mod chart_font;
use chart_font::{load_font, FONT};
use plotters::coord::Shift;
use plotters::prelude::*;
use serde_json::{json, Map, Value};
use std::ffi::OsString;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

type Res<T> = Result<T, Box<dyn std::error::Error>>;

const MINI: &str = "ISSUE_021_Mini_Project.glb";
/// Mini_Project's triangles (MANIFEST.md), used only if the GLB cannot be read for its own count.
const MINI_TRIANGLES: u64 = 241_016;
/// The issue's 8.2M campus: `--copies 34`.
const ISSUE_COPIES_8M: usize = 34;
const JITTER_M: &str = "0.002";
const GB: f64 = 1e9;
const MB: f64 = 1e6;
/// The issues' targets (scale, then conversion speed at city scale).
const TARGET_8M_SECONDS: f64 = 25.0;
const TARGET_8M_PEAK_GB: f64 = 1.0;
/// The 100M jittered campus under a memory budget of at most this much (`--memory-budget-gb 2`).
const TARGET_100M_SECONDS: f64 = 250.0;
const TARGET_100M_PEAK_GB: f64 = 2.0;
const TARGET_EXPONENT: f64 = 1.15;
const TARGET_RAY_RATIO: f64 = 0.6;
const GNU_TIME: &str = "/usr/bin/time";
/// A Ray run that takes longer than this is stopped (a cluster that never comes up must not hang
/// the bench).
const RAY_TIMEOUT: Duration = Duration::from_secs(3 * 3600);

const EXACT_COLOR: RGBColor = RGBColor(50, 110, 180);
const JITTER_COLOR: RGBColor = RGBColor(200, 90, 70);

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Variant {
    Exact,
    Jitter,
}

impl Variant {
    fn name(self) -> &'static str {
        match self {
            Variant::Exact => "exact",
            Variant::Jitter => "jitter",
        }
    }
    fn describe(self) -> &'static str {
        match self {
            Variant::Exact => "exact copies (dedup helps)",
            Variant::Jitter => "jitter 2 mm (dedup cannot help)",
        }
    }
    fn parse(s: &str) -> Result<Self, String> {
        match s.trim() {
            "exact" => Ok(Variant::Exact),
            "jitter" => Ok(Variant::Jitter),
            o => Err(format!("unknown variant {o:?} (exact, jitter)")),
        }
    }
    fn campus_args(self) -> Vec<&'static str> {
        match self {
            Variant::Exact => vec![],
            Variant::Jitter => vec!["--jitter-m", JITTER_M],
        }
    }
    fn color(self) -> RGBColor {
        match self {
            Variant::Exact => EXACT_COLOR,
            Variant::Jitter => JITTER_COLOR,
        }
    }
}

/// A requested size: its spelling and triangles.
#[derive(Clone, Debug)]
struct Size {
    label: String,
    triangles: f64,
}

fn parse_size(s: &str) -> Result<Size, String> {
    let t = s.trim();
    let (num, mult) = match t.char_indices().last() {
        Some((i, 'M' | 'm')) => (&t[..i], 1e6),
        Some((i, 'K' | 'k')) => (&t[..i], 1e3),
        _ => (t, 1.0),
    };
    match num.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(Size {
            label: t.to_string(),
            triangles: v * mult,
        }),
        _ => Err(format!(
            "bad size {s:?} (a positive number of triangles, with K or M: 0.5M, 8M, 100M)"
        )),
    }
}

/// Whole copies of Mini_Project for a size; 8M (7.9-8.3M) is the issue's 34-copy campus.
fn copies_for(triangles: f64, per_copy: u64) -> usize {
    if (7.9e6..=8.3e6).contains(&triangles) {
        return ISSUE_COPIES_8M;
    }
    ((triangles / per_copy.max(1) as f64).round() as usize).max(1)
}

struct Opts {
    sizes: Vec<Size>,
    variants: Vec<Variant>,
    skip_ray: bool,
    ray_size: Size,
    ray_variant: Variant,
    ray_jobs: usize,
    keep: bool,
    out: PathBuf,
    campus_dir: PathBuf,
    shared: PathBuf,
    python: PathBuf,
    memory_budget_gb: f64,
}

const USAGE: &str = "usage: cargo run --release --features charts --example bench_scale -- [--sizes 1M,8M,32M,100M] \
[--variants exact,jitter] [--skip-ray] [--ray-size 8M] [--ray-variant jitter] [--ray-jobs 4] [--keep] \
[--out DIR] [--campus-dir DIR] [--shared DIR] [--python PATH] [--memory-budget-gb 4]";

fn parse_args(repo: &Path) -> Result<Opts, String> {
    let mut o = Opts {
        sizes: ["1M", "8M", "32M", "100M"]
            .iter()
            .map(|s| parse_size(s).unwrap())
            .collect(),
        variants: vec![Variant::Exact, Variant::Jitter],
        skip_ray: false,
        ray_size: parse_size("8M").unwrap(),
        ray_variant: Variant::Jitter,
        ray_jobs: 4,
        keep: false,
        out: repo.join("target/bench/scale"),
        // Not under --out: a trial run elsewhere must not compose 7 GB of campuses again.
        campus_dir: repo.join("target/bench/scale"),
        shared: std::env::var_os("BIMTILES_SHARED")
            .map(PathBuf::from)
            .unwrap_or_else(|| repo.join("../shared")),
        python: repo.join(".venv/bin/python"),
        memory_budget_gb: 4.0,
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().ok_or_else(|| format!("{a} needs a value"));
        match a.as_str() {
            "--sizes" => {
                o.sizes = value()?
                    .split(',')
                    .map(parse_size)
                    .collect::<Result<_, _>>()?
            }
            "--variants" => {
                o.variants = value()?
                    .split(',')
                    .map(Variant::parse)
                    .collect::<Result<_, _>>()?
            }
            "--skip-ray" => o.skip_ray = true,
            "--ray-size" => o.ray_size = parse_size(&value()?)?,
            "--ray-variant" => o.ray_variant = Variant::parse(&value()?)?,
            "--ray-jobs" => {
                o.ray_jobs = value()?
                    .parse()
                    .ok()
                    .filter(|&n| n >= 1)
                    .ok_or("--ray-jobs takes a positive integer")?
            }
            "--keep" => o.keep = true,
            "--out" => o.out = PathBuf::from(value()?),
            "--campus-dir" => o.campus_dir = PathBuf::from(value()?),
            "--shared" => o.shared = PathBuf::from(value()?),
            "--python" => o.python = PathBuf::from(value()?),
            "--memory-budget-gb" => {
                o.memory_budget_gb = value()?
                    .parse()
                    .ok()
                    .filter(|v: &f64| *v > 0.0)
                    .ok_or("--memory-budget-gb takes a positive number")?
            }
            "-h" | "--help" => {
                println!("{USAGE}");
                std::process::exit(0);
            }
            other => return Err(format!("unknown argument {other:?}\n{USAGE}")),
        }
    }
    if o.sizes.is_empty() || o.variants.is_empty() {
        return Err("--sizes and --variants need at least one value".into());
    }
    Ok(o)
}

/// Absolute, so that the commands recorded and the children's paths do not depend on the cwd.
fn absolute(p: &Path) -> PathBuf {
    std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf())
}

fn main() {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut opts = match parse_args(&repo) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("bench_scale: {e}");
            std::process::exit(2);
        }
    };
    for p in [
        &mut opts.out,
        &mut opts.campus_dir,
        &mut opts.shared,
        &mut opts.python,
    ] {
        *p = absolute(p);
    }
    // Without `..` in the recorded commands (not the venv's python: its symlink is the venv).
    if let Ok(p) = std::fs::canonicalize(&opts.shared) {
        opts.shared = p;
    }
    if let Err(e) = run(&repo, &opts) {
        eprintln!("bench_scale: {e}");
        std::process::exit(1);
    }
}

/// Where things are, checked once.
struct Ctx<'a> {
    opts: &'a Opts,
    repo: PathBuf,
    bin: PathBuf,
    script: PathBuf,
    mini: PathBuf,
    per_copy: u64,
    copy_bytes: u64,
    gnu_time: bool,
}

fn run(repo: &Path, opts: &Opts) -> Res<()> {
    let data = opts.shared.join("data");
    let script = data.join("make_campus.py");
    let mini = data.join(MINI);
    let bin = repo.join("target/release/bimtiles");
    for (path, what) in [
        (
            &script,
            "make_campus.py (the shared data folder; set --shared or BIMTILES_SHARED)",
        ),
        (
            &mini,
            "the Mini_Project model (the shared data folder; set --shared or BIMTILES_SHARED)",
        ),
        (
            &bin,
            "the bimtiles binary (run `make build` or `cargo build --release`)",
        ),
        (
            &opts.python,
            "the project venv's Python with numpy (run `make deps-python`, or give --python)",
        ),
    ] {
        if !path.is_file() {
            return Err(format!("{} not found: {what}", path.display()).into());
        }
    }
    std::fs::create_dir_all(&opts.out).map_err(|e| format!("{}: {e}", opts.out.display()))?;
    std::fs::create_dir_all(&opts.campus_dir)
        .map_err(|e| format!("{}: {e}", opts.campus_dir.display()))?;
    // What one copy adds to a campus: the model's triangles as our reader counts them.
    let per_copy = match bimtiles::ingest::read_input(&mini) {
        Ok(scene) => scene.triangle_count() as u64,
        Err(e) => {
            eprintln!("{e}: taking {MINI_TRIANGLES} triangles per copy");
            MINI_TRIANGLES
        }
    };
    let mini_bytes = std::fs::metadata(&mini)?.len();
    let ctx = Ctx {
        opts,
        repo: repo.to_path_buf(),
        bin,
        script,
        mini,
        per_copy,
        // A baked copy is the model's positions and indices again (campus-8.2M: 5.99 MB a copy
        // for Mini_Project's 5.96 MB).
        copy_bytes: mini_bytes + mini_bytes / 50,
        gnu_time: Path::new(GNU_TIME).is_file(),
    };
    if !ctx.gnu_time {
        eprintln!(
            "note: {GNU_TIME} not found (Debian package `time`): peak memory is report.json's only"
        );
    }

    // The points, smallest first, so that a short disk or a crash at 100M leaves the rest measured.
    let mut points: Vec<(String, usize, Variant)> = Vec::new();
    let mut sizes = opts.sizes.clone();
    sizes.sort_by(|a, b| a.triangles.total_cmp(&b.triangles));
    for s in &sizes {
        let copies = copies_for(s.triangles, per_copy);
        for &v in &opts.variants {
            if !points.iter().any(|p| p.1 == copies && p.2 == v) {
                points.push((s.label.clone(), copies, v));
            }
        }
    }
    let ray_copies = copies_for(opts.ray_size.triangles, per_copy);
    let load_start = loadavg();
    check_disk(
        &ctx,
        &points,
        (!opts.skip_ray).then_some((ray_copies, opts.ray_variant)),
    )?;

    let mut rows = Vec::new();
    for (label, copies, variant) in &points {
        eprintln!(
            "== {label} ({copies} cop{}, ~{:.2}M triangles), {}",
            if *copies == 1 { "y" } else { "ies" },
            (*copies as u64 * per_copy) as f64 / 1e6,
            variant.name()
        );
        let mut row = match campus(&ctx, *copies, *variant) {
            Ok((path, gen)) => {
                let mut r = convert_point(&ctx, &path, *copies, *variant);
                r["campus"] = gen;
                r
            }
            Err(e) => {
                eprintln!("   campus failed: {e}");
                json!({"ok": false, "error": format!("make_campus.py failed: {e}")})
            }
        };
        row["size"] = json!(label);
        row["copies"] = json!(copies);
        row["variant"] = json!(variant.name());
        if row["ok"].as_bool() == Some(true) {
            eprintln!(
                "   {:.1} s, peak {:.0} MB, {:.1} MB out, {} tiles",
                f(&row["wall_s"]),
                f(&row["peak_memory_bytes"]) / MB,
                f(&row["output_bytes"]) / MB,
                row["tiles"]
            );
        }
        rows.push(row);
        // What is measured so far, in case a long run is stopped (the 100M points take hours).
        let doc = document(&ctx, &rows, json!({"pending": true}), load_start);
        let _ = std::fs::write(
            opts.out.join("scale.json"),
            serde_json::to_vec_pretty(&doc).unwrap_or_default(),
        );
        let _ = std::fs::write(
            opts.out.join("scale.md"),
            markdown(&ctx, &doc, Some("the run is not finished")),
        );
    }

    let ray = if opts.skip_ray {
        json!({"skipped": "--skip-ray"})
    } else {
        eprintln!(
            "== sharding: {} ({ray_copies} cop{}), {}, {} jobs, one thread each",
            opts.ray_size.label,
            if ray_copies == 1 { "y" } else { "ies" },
            opts.ray_variant.name(),
            opts.ray_jobs
        );
        match campus(&ctx, ray_copies, opts.ray_variant) {
            Ok((path, gen)) => {
                let mut r = ray_bench(&ctx, &path);
                r["campus"] = gen;
                r["size"] = json!(opts.ray_size.label);
                r["copies"] = json!(ray_copies);
                r["variant"] = json!(opts.ray_variant.name());
                r
            }
            Err(e) => json!({"error": format!("make_campus.py failed: {e}")}),
        }
    };
    if let Some(e) = ray["error"].as_str() {
        eprintln!("   sharding bench failed: {e}");
    } else if let Some(s) = ray["skipped"].as_str() {
        eprintln!("   sharding bench skipped: {s}");
    }

    let doc = document(&ctx, &rows, ray, load_start);
    let json_path = opts.out.join("scale.json");
    std::fs::write(&json_path, serde_json::to_vec_pretty(&doc)?)
        .map_err(|e| format!("{}: {e}", json_path.display()))?;
    let png = opts.out.join("scale.png");
    let chart_note = match draw_chart(&png, &doc, &opts.variants) {
        Ok(()) => None,
        Err(e) => {
            eprintln!("chart not drawn: {e}");
            Some(e.to_string())
        }
    };
    let md = markdown(&ctx, &doc, chart_note.as_deref());
    std::fs::write(opts.out.join("scale.md"), &md)?;
    println!("{md}");
    println!(
        "written {}, {}{}",
        json_path.display(),
        opts.out.join("scale.md").display(),
        if chart_note.is_none() {
            format!(", {}", png.display())
        } else {
            String::new()
        }
    );
    // As `make bench-browser`: everything measured is written, then a failure fails the run.
    let failed = doc["points"]
        .as_array()
        .into_iter()
        .flatten()
        .filter(|p| p["ok"].as_bool() != Some(true))
        .count();
    if failed > 0 || doc["ray"]["error"].is_string() {
        return Err(format!(
            "{failed} conversion(s) failed{}; see {}",
            if doc["ray"]["error"].is_string() {
                ", the sharding bench failed"
            } else {
                ""
            },
            opts.out.join("scale.md").display()
        )
        .into());
    }
    Ok(())
}

/// Everything measured, with the fits, as scale.json holds it.
fn document(ctx: &Ctx, rows: &[Value], ray: Value, load_start: Option<f64>) -> Value {
    let mut fits = Map::new();
    for &v in &ctx.opts.variants {
        let pts = |key: &str| -> Vec<(f64, f64)> {
            ok_rows(rows, v)
                .map(|r| (f(&r["triangles"]), f(&r[key])))
                .collect()
        };
        let time = pts("wall_s");
        fits.insert(
            v.name().into(),
            json!({"time": fit_loglog(&time).map(Fit::to_json),
                   "memory": fit_loglog(&pts("peak_memory_bytes")).map(Fit::to_json),
                   "points": time.len(),
                   "triangles_min": time.iter().map(|p| p.0).reduce(f64::min),
                   "triangles_max": time.iter().map(|p| p.0).reduce(f64::max)}),
        );
    }
    let mut machine = machine(ctx);
    machine["loadavg_start"] = json!(load_start);
    json!({
        "machine": machine,
        "per_copy_triangles": ctx.per_copy,
        "campus_command": format!(
            "{} {} OUT.glb --copies C --inputs {} --bake [--jitter-m {JITTER_M}]",
            ctx.opts.python.display(), ctx.script.display(), ctx.mini.display()),
        "convert_command": format!("{} convert IN --out DIR --force --quiet", ctx.bin.display()),
        "memory_budget_gb": ctx.opts.memory_budget_gb,
        "points": rows,
        "fits": fits,
        "ray": ray,
    })
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

fn ok_rows(rows: &[Value], v: Variant) -> impl Iterator<Item = &Value> {
    rows.iter()
        .filter(move |r| r["ok"].as_bool() == Some(true) && r["variant"] == v.name())
}

/// A cached GLB is whole when its header's length is the file's (a killed make_campus.py writes
/// to a temporary name, but an old partial file must not be taken either).
fn glb_complete(path: &Path) -> bool {
    use std::io::Read;
    let mut head = [0u8; 12];
    let Ok(mut file) = std::fs::File::open(path) else {
        return false;
    };
    if file.read_exact(&mut head).is_err() || &head[..4] != b"glTF" {
        return false;
    }
    let len = u32::from_le_bytes([head[8], head[9], head[10], head[11]]) as u64;
    file.metadata().is_ok_and(|m| m.len() == len)
}

fn campus_path(ctx: &Ctx, copies: usize, v: Variant) -> PathBuf {
    ctx.opts
        .campus_dir
        .join(format!("campus-{copies}x-{}.glb", v.name()))
}

/// Campuses `make bench` (examples/bench_tiler.rs) already made with the same command and seed.
fn reusable(ctx: &Ctx, copies: usize, v: Variant) -> Option<PathBuf> {
    let name = match (copies, v) {
        (8, Variant::Jitter) => "campus-1.9M.glb",
        (8, Variant::Exact) => "campus-1.9M-exact.glb",
        (34, Variant::Jitter) => "campus-8.2M.glb",
        _ => return None,
    };
    let p = ctx.repo.join("target/bench").join(name);
    glb_complete(&p).then_some(p)
}

/// The campus of `copies` copies: cached, reused from `make bench`, or made now.
fn campus(ctx: &Ctx, copies: usize, v: Variant) -> Result<(PathBuf, Value), String> {
    let path = campus_path(ctx, copies, v);
    if glb_complete(&path) {
        return Ok((path.clone(), json!({"path": path, "made": false})));
    }
    if let Some(p) = reusable(ctx, copies, v) {
        return Ok((
            p.clone(),
            json!({"path": p, "made": false, "reused_from_make_bench": true}),
        ));
    }
    let tmp = path.with_extension("glb.tmp");
    let mut cmd = Command::new(&ctx.opts.python);
    cmd.arg(&ctx.script)
        .arg(&tmp)
        .args(["--copies", &copies.to_string(), "--inputs"])
        .arg(&ctx.mini)
        .arg("--bake")
        .args(v.campus_args());
    let shown = show_command(&cmd);
    eprintln!("   composing {}", path.display());
    let t = Instant::now();
    let out = cmd
        .stdin(Stdio::null())
        .output()
        .map_err(|e| format!("cannot run {}: {e}", ctx.opts.python.display()))?;
    let secs = t.elapsed().as_secs_f64();
    if !out.status.success() || !glb_complete(&tmp) {
        let _ = std::fs::remove_file(&tmp);
        return Err(format!(
            "{shown}: {}\n{}",
            out.status,
            tail(&String::from_utf8_lossy(&out.stderr), 20)
        )
        .trim_end()
        .to_string());
    }
    std::fs::rename(&tmp, &path).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok((
        path.clone(),
        json!({"path": path, "made": true, "seconds": secs, "command": shown,
               "stdout": String::from_utf8_lossy(&out.stdout).trim()}),
    ))
}

/// Free bytes on the filesystem holding `dir` (POSIX `df`; std has no statvfs).
fn free_bytes(dir: &Path) -> Option<u64> {
    let out = Command::new("df").arg("-Pk").arg(dir).output().ok()?;
    let text = String::from_utf8_lossy(&out.stdout);
    let kb: u64 = text
        .lines()
        .nth(1)?
        .split_whitespace()
        .nth(3)?
        .parse()
        .ok()?;
    Some(kb * 1024)
}

/// Refuses to start when the campuses still to make, plus room for the largest conversion's
/// output and spill, do not fit on the disk.
fn check_disk(
    ctx: &Ctx,
    points: &[(String, usize, Variant)],
    ray: Option<(usize, Variant)>,
) -> Res<()> {
    let mut needed: Vec<(usize, Variant)> = points.iter().map(|p| (p.1, p.2)).collect();
    needed.extend(ray);
    needed.sort_by_key(|p| (p.0, p.1.name()));
    needed.dedup();
    let missing: Vec<&(usize, Variant)> = needed
        .iter()
        .filter(|(c, v)| {
            !glb_complete(&campus_path(ctx, *c, *v)) && reusable(ctx, *c, *v).is_none()
        })
        .collect();
    let new_inputs: u64 = missing
        .iter()
        .map(|(c, _)| *c as u64 * ctx.copy_bytes)
        .sum();
    let largest = needed.iter().map(|p| p.0).max().unwrap_or(0) as u64 * ctx.copy_bytes;
    // Output (about a fifth of the input with Draco) and an on-disk spill store (up to the input),
    // and for the sharded build two build folders at once.
    let headroom = largest * 3 / 2 + GB as u64;
    let want = new_inputs + headroom;
    let Some(free) = free_bytes(&ctx.opts.campus_dir) else {
        eprintln!(
            "note: cannot tell the free disk space; about {:.1} GB is needed",
            want as f64 / GB
        );
        return Ok(());
    };
    eprintln!(
        "disk: {:.1} GB free; {} campus(es) to compose ({:.1} GB) + {:.1} GB working room",
        free as f64 / GB,
        missing.len(),
        new_inputs as f64 / GB,
        headroom as f64 / GB
    );
    if free < want {
        return Err(format!(
            "not enough free disk space on the filesystem of {}: {:.1} GB free, about {:.1} GB needed \
             ({:.1} GB of campuses to compose: {}; {:.1} GB for the largest conversion's output and spill). \
             Free some space or leave out the largest sizes (--sizes).",
            ctx.opts.campus_dir.display(),
            free as f64 / GB,
            want as f64 / GB,
            new_inputs as f64 / GB,
            missing
                .iter()
                .map(|(c, v)| format!("{c}x {}", v.name()))
                .collect::<Vec<_>>()
                .join(", "),
            headroom as f64 / GB
        )
        .into());
    }
    Ok(())
}

fn show_command(cmd: &Command) -> String {
    std::iter::once(cmd.get_program())
        .chain(cmd.get_args())
        .map(|a| a.to_string_lossy().into_owned())
        .collect::<Vec<_>>()
        .join(" ")
}

/// The last `n` lines of a log (progress bars redraw with `\r`: only their last state is kept).
fn tail(s: &str, n: usize) -> String {
    let lines: Vec<&str> = s
        .lines()
        .map(|l| l.rsplit('\r').next().unwrap_or(l))
        .filter(|l| !l.trim().is_empty())
        .collect();
    lines[lines.len().saturating_sub(n)..].join("\n")
}

/// One measured child process.
struct Measured {
    ok: bool,
    status: String,
    wall_s: f64,
    /// The child's max RSS (GNU time), when known.
    max_rss_bytes: Option<u64>,
    log: String,
}

/// Runs `program args` with stdout and stderr into `log_path` (a file, not a pipe, so a chatty child
/// cannot block), timed, under GNU time when installed for the child's own max RSS.
fn measure(ctx: &Ctx, program: &Path, args: &[OsString], log_path: &Path) -> (String, Measured) {
    let rss_path = log_path.with_extension("rss");
    let _ = std::fs::remove_file(&rss_path);
    let mut cmd = if ctx.gnu_time {
        let mut c = Command::new(GNU_TIME);
        c.args(["-f", "%M", "-o"]).arg(&rss_path).arg(program);
        c
    } else {
        Command::new(program)
    };
    cmd.args(args).stdin(Stdio::null());
    let mut shown = program.display().to_string();
    for a in args {
        shown.push(' ');
        shown.push_str(&a.to_string_lossy());
    }
    let spawned = std::fs::File::create(log_path).and_then(|log| {
        cmd.stdout(log.try_clone()?).stderr(log);
        let t = Instant::now();
        let st = cmd.status()?;
        Ok((st, t.elapsed().as_secs_f64()))
    });
    let log = std::fs::read_to_string(log_path).unwrap_or_default();
    let m = match spawned {
        Ok((st, wall_s)) => Measured {
            ok: st.success(),
            status: st.to_string(),
            wall_s,
            // GNU time's file ends with the figure ("Command exited with non-zero status" first).
            max_rss_bytes: std::fs::read_to_string(&rss_path).ok().and_then(|s| {
                s.lines()
                    .rev()
                    .find_map(|l| l.trim().parse::<u64>().ok())
                    .map(|kb| kb * 1024)
            }),
            log,
        },
        Err(e) => Measured {
            ok: false,
            status: format!("cannot run: {e}"),
            wall_s: 0.0,
            max_rss_bytes: None,
            log,
        },
    };
    let _ = std::fs::remove_file(&rss_path);
    (shown, m)
}

fn os(args: &[&dyn AsRef<std::ffi::OsStr>]) -> Vec<OsString> {
    args.iter().map(|a| a.as_ref().to_os_string()).collect()
}

/// Bytes and files under a folder, and the GLBs among them.
fn dir_stats(dir: &Path) -> (u64, u64, u64) {
    let (mut bytes, mut files, mut glbs) = (0, 0, 0);
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let Ok(meta) = e.metadata() else { continue };
            if meta.is_dir() {
                stack.push(e.path());
            } else {
                bytes += meta.len();
                files += 1;
                glbs += e.path().extension().is_some_and(|x| x == "glb") as u64;
            }
        }
    }
    (bytes, files, glbs)
}

fn read_report(dir: &Path) -> Result<Value, String> {
    let p = dir.join("report.json");
    let bytes = std::fs::read(&p).map_err(|e| format!("{}: {e}", p.display()))?;
    serde_json::from_slice(&bytes).map_err(|e| format!("{}: {e}", p.display()))
}

/// One conversion, measured.
fn convert_point(ctx: &Ctx, input: &Path, copies: usize, v: Variant) -> Value {
    let out = ctx.opts.out.join(format!("tiles-{copies}x-{}", v.name()));
    let _ = std::fs::remove_dir_all(&out);
    let log = ctx
        .opts
        .out
        .join(format!("convert-{copies}x-{}.log", v.name()));
    let args = os(&[&"convert", &input, &"--out", &out, &"--force", &"--quiet"]);
    let (shown, m) = measure(ctx, &ctx.bin, &args, &log);
    let input_bytes = std::fs::metadata(input).map(|m| m.len()).unwrap_or(0);
    let mut row = json!({
        "input": input, "input_bytes": input_bytes, "command": shown, "ok": m.ok,
        "status": m.status, "wall_s": m.wall_s, "max_rss_bytes": m.max_rss_bytes,
        "log": log,
    });
    if !m.ok {
        eprintln!("   convert failed ({}):\n{}", m.status, tail(&m.log, 20));
        row["error"] = json!(format!("convert {}: {}", m.status, tail(&m.log, 20)));
        if !ctx.opts.keep {
            let _ = std::fs::remove_dir_all(&out);
        }
        return row;
    }
    let report = match read_report(&out) {
        Ok(r) => r,
        Err(e) => {
            row["ok"] = json!(false);
            row["error"] = json!(e);
            return row;
        }
    };
    let (bytes, files, glbs) = dir_stats(&out);
    let tris = report["input"]["triangles"]
        .as_u64()
        .or_else(|| report["dedup"]["triangles_before"].as_u64())
        .unwrap_or(copies as u64 * ctx.per_copy);
    let rep_peak = report["peak_memory_bytes"].as_u64();
    let peak = rep_peak.max(m.max_rss_bytes);
    let d = &report["dedup"];
    let extra = json!({
        "triangles": tris,
        "report_total_s": report["timings_s"]["total"],
        "timings_s": report["timings_s"],
        "peak_memory_bytes_report": rep_peak,
        "peak_memory_bytes": peak,
        "output_bytes": bytes,
        "output_files": files,
        "tile_files": glbs,
        "tiles": report["output"]["tiles"],
        "tiles_with_content": report["output"]["tiles_with_content"],
        "max_depth": report["output"]["max_depth"],
        "output_triangles": report["output"]["triangles"],
        "stored_triangles": report["output"]["stored_triangles"],
        "instances": report["output"]["instances"],
        "s_per_mtri": m.wall_s / (tris as f64 / 1e6),
        "dedup": {
            "unique_shapes": d["unique_shapes"], "congruent_rewritten": d["congruent_rewritten"],
            "redundant_removed": d["redundant_removed"], "triangles_stored_after": d["triangles_stored_after"],
            "seconds": d["seconds"],
        },
        "options": report["options"],
    });
    for (k, val) in extra.as_object().unwrap() {
        row[k] = val.clone();
    }
    if !ctx.opts.keep {
        let _ = std::fs::remove_dir_all(&out);
    }
    row
}

/// `y = a x^k` by least squares on `ln y = ln a + k ln x`.
#[derive(Clone, Copy)]
struct Fit {
    k: f64,
    ln_a: f64,
    r2: f64,
    n: usize,
}

impl Fit {
    fn to_json(self) -> Value {
        json!({"exponent": self.k, "ln_coefficient": self.ln_a, "r2": self.r2, "points": self.n})
    }
    fn from_json(v: &Value) -> Option<Fit> {
        Some(Fit {
            k: v["exponent"].as_f64()?,
            ln_a: v["ln_coefficient"].as_f64()?,
            r2: v["r2"].as_f64().unwrap_or(f64::NAN),
            n: v["points"].as_u64().unwrap_or(0) as usize,
        })
    }
    fn at(&self, x: f64) -> f64 {
        (self.ln_a + self.k * x.ln()).exp()
    }
}

fn fit_loglog(pts: &[(f64, f64)]) -> Option<Fit> {
    let pts: Vec<(f64, f64)> = pts
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    let n = pts.len() as f64;
    if pts.len() < 2 {
        return None;
    }
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let syy: f64 = pts.iter().map(|p| (p.1 - my).powi(2)).sum();
    if sxx < 1e-12 {
        return None; // one size only: no slope
    }
    let k = sxy / sxx;
    let r2 = if syy > 0.0 {
        sxy * sxy / (sxx * syy)
    } else {
        1.0
    };
    Some(Fit {
        k,
        ln_a: my - k * mx,
        r2,
        n: pts.len(),
    })
}

/// Is `unshare -n` (a private network namespace, loopback only) permitted, and with a private PID
/// namespace too? The PID namespace ends every Ray process with the run and keeps `ray stop` from
/// seeing anyone else's cluster.
fn unshare_mode() -> Option<Vec<&'static str>> {
    let ok = |args: &[&str]| {
        Command::new("unshare")
            .args(args)
            .arg("true")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    };
    let with_pid = ["-n", "-p", "-f", "--mount-proc", "--kill-child"];
    if ok(&with_pid) {
        return Some(with_pid.to_vec());
    }
    ok(&["-n"]).then(|| vec!["-n"])
}

/// Every file of a tileset folder but those that are allowed to differ between builds.
fn tileset_files(dir: &Path) -> Vec<String> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
                continue;
            }
            let rel = p
                .strip_prefix(dir)
                .unwrap_or(&p)
                .to_string_lossy()
                .replace('\\', "/");
            if rel != "report.json" && rel != "plan.json" && !rel.starts_with("jobs/") {
                out.push(rel);
            }
        }
    }
    out.sort();
    out
}

/// Differences between two tilesets (file names, then bytes), at most a few named.
fn compare_tilesets(a: &Path, b: &Path) -> (usize, Vec<String>) {
    let (fa, fb) = (tileset_files(a), tileset_files(b));
    let mut diffs = Vec::new();
    for name in fa.iter().filter(|n| !fb.contains(n)) {
        diffs.push(format!("only in the sequential build: {name}"));
    }
    for name in fb.iter().filter(|n| !fa.contains(n)) {
        diffs.push(format!("only in the Ray build: {name}"));
    }
    for name in fa.iter().filter(|n| fb.contains(n)) {
        let (x, y) = (std::fs::read(a.join(name)), std::fs::read(b.join(name)));
        if x.is_err() || y.is_err() || x.ok() != y.ok() {
            diffs.push(format!("differs: {name}"));
        }
    }
    (fa.len(), diffs)
}

/// The last "jobs [...] N/N   T s" of the driver's progress bar: the job phase as the driver saw it
/// (from submitting the tasks to the last result, without `ray.init` and the merge).
fn driver_job_phase(log: &str) -> Option<f64> {
    log.split(['\r', '\n'])
        .rfind(|l| l.contains("jobs ["))?
        .trim()
        .strip_suffix(" s")?
        .split_whitespace()
        .last()?
        .parse()
        .ok()
}

/// The sharded build: sequential jobs (one thread each) against the Ray driver on two one-CPU nodes.
fn ray_bench(ctx: &Ctx, input: &Path) -> Value {
    match ray_bench_inner(ctx, input) {
        Ok(v) => v,
        Err(e) => json!({"error": e}),
    }
}

fn ray_bench_inner(ctx: &Ctx, input: &Path) -> Result<Value, String> {
    let venv_bin = ctx.opts.python.parent().unwrap_or(Path::new("."));
    let ray_cli = venv_bin.join("ray");
    let driver = ctx.repo.join("tools/ray_driver.py");
    for (p, what) in [
        (
            &ray_cli,
            "Ray's CLI in the project venv (PyPI `ray`: `make deps-python`)",
        ),
        (&driver, "the Ray driver"),
    ] {
        if !p.is_file() {
            return Err(format!("{} not found: {what}", p.display()));
        }
    }
    let Some(unshare) = unshare_mode() else {
        return Ok(
            json!({"skipped": "`unshare -n` is not permitted here: a Ray cluster cannot be \
                         kept on loopback, so the sharding bench is skipped"}),
        );
    };
    let jobs = ctx.opts.ray_jobs.to_string();
    let seq = ctx.opts.out.join("shard-sequential");
    let ray = ctx.opts.out.join("shard-ray");
    let log = |name: &str| ctx.opts.out.join(format!("shard-{name}.log"));
    let plan = |dir: &Path, name: &str| -> Result<Measured, String> {
        let _ = std::fs::remove_dir_all(dir);
        let args = os(&[
            &"plan", &input, &"--out", &dir, &"--jobs", &jobs, &"--quiet",
        ]);
        let (shown, m) = measure(ctx, &ctx.bin, &args, &log(name));
        if !m.ok {
            return Err(format!("{shown}: {}\n{}", m.status, tail(&m.log, 20)));
        }
        Ok(m)
    };
    let cleanup = || {
        if !ctx.opts.keep {
            let _ = std::fs::remove_dir_all(&seq);
            let _ = std::fs::remove_dir_all(&ray);
        }
    };

    // (a) the jobs one after another.
    let plan_a = plan(&seq, "plan-sequential")?;
    let plan_json = read_json(&seq.join("plan.json"))?;
    let job_tris: Vec<Value> = plan_json["jobs"]
        .as_array()
        .map(|j| j.iter().map(|j| j["triangles"].clone()).collect())
        .unwrap_or_default();
    let n_jobs = plan_json["jobs"]
        .as_array()
        .map_or(ctx.opts.ray_jobs, |j| j.len());
    let mut seq_jobs = Vec::new();
    let mut seq_total = 0.0;
    for k in 0..n_jobs {
        let args = os(&[
            &"build-job",
            &seq,
            &"--job",
            &k.to_string(),
            &"--threads",
            &"1",
            &"--quiet",
        ]);
        let (shown, m) = measure(ctx, &ctx.bin, &args, &log(&format!("job-{k}")));
        if !m.ok {
            cleanup();
            return Err(format!("{shown}: {}\n{}", m.status, tail(&m.log, 20)));
        }
        eprintln!("   sequential job {k}: {:.1} s", m.wall_s);
        seq_total += m.wall_s;
        seq_jobs.push(json!({"job": k, "wall_s": m.wall_s, "max_rss_bytes": m.max_rss_bytes}));
    }
    let (shown, merge_a) = measure(
        ctx,
        &ctx.bin,
        &os(&[&"merge", &seq, &"--quiet"]),
        &log("merge-sequential"),
    );
    if !merge_a.ok {
        cleanup();
        return Err(format!(
            "{shown}: {}\n{}",
            merge_a.status,
            tail(&merge_a.log, 20)
        ));
    }

    // (b) the same plan on Ray: a head and a second node, one CPU each, loopback only.
    plan(&ray, "plan-ray")?;
    let tmp = std::env::temp_dir().join(format!("bimtiles-bench-ray-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).map_err(|e| format!("{}: {e}", tmp.display()))?;
    let q = |p: &Path| format!("'{}'", p.display().to_string().replace('\'', r"'\''"));
    // Ray keeps its sockets and logs in --temp-dir (our own, removed after), not in /tmp/ray.
    let script = format!(
        r#"set -e
ip link set lo up
export RAY_USAGE_STATS_ENABLED=0
trap '{ray} stop --force >/dev/null 2>&1 || true' EXIT
echo "BENCH_T0 $(date +%s.%N)"
{ray} start --head --port=6399 --num-cpus=1 --include-dashboard=false --node-ip-address=127.0.0.1 --temp-dir={tmp} >/dev/null
{ray} start --address=127.0.0.1:6399 --num-cpus=1 --node-ip-address=127.0.0.1 --temp-dir={tmp} >/dev/null
echo "BENCH_T1 $(date +%s.%N)"
{py} {driver} {build} --bimtiles {bin} --threads 1
echo "BENCH_T2 $(date +%s.%N)"
"#,
        ray = q(&ray_cli),
        tmp = q(&tmp),
        py = q(&ctx.opts.python),
        driver = q(&driver),
        build = q(&ray),
        bin = q(&ctx.bin),
    );
    let ray_log = log("ray");
    let status = std::fs::File::create(&ray_log).and_then(|f| {
        let path = format!(
            "{}:{}",
            venv_bin.display(),
            std::env::var("PATH").unwrap_or_default()
        );
        let mut child = Command::new("unshare")
            .args(&unshare)
            .args(["bash", "-c", &script])
            .env("PATH", path)
            .stdin(Stdio::null())
            .stdout(f.try_clone()?)
            .stderr(f)
            .spawn()?;
        let t = Instant::now();
        loop {
            if let Some(st) = child.try_wait()? {
                return Ok(Some(st));
            }
            if t.elapsed() > RAY_TIMEOUT {
                // --kill-child: the namespace's processes end with unshare.
                let _ = child.kill();
                let _ = child.wait();
                return Ok(None);
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    });
    let _ = std::fs::remove_dir_all(&tmp);
    let text = std::fs::read_to_string(&ray_log).unwrap_or_default();
    match status {
        Ok(Some(st)) if st.success() => {}
        Ok(Some(st)) => {
            cleanup();
            return Err(format!(
                "Ray run failed ({st}), log {}:\n{}",
                ray_log.display(),
                tail(&text, 25)
            ));
        }
        Ok(None) => {
            cleanup();
            return Err(format!(
                "Ray run stopped after {} s, log {}",
                RAY_TIMEOUT.as_secs(),
                ray_log.display()
            ));
        }
        Err(e) => {
            cleanup();
            return Err(format!("cannot run unshare: {e}"));
        }
    }
    let stamp = |k: &str| -> Option<f64> {
        text.lines()
            .find_map(|l| l.strip_prefix(k))
            .and_then(|v| v.trim().parse().ok())
    };
    let (t0, t1, t2) = (stamp("BENCH_T0 "), stamp("BENCH_T1 "), stamp("BENCH_T2 "));
    let driver_s = t1.zip(t2).map(|(a, b)| b - a);
    let phase = driver_job_phase(&text);
    let job_phase_s = phase.or(driver_s);
    let (files, diffs) = compare_tilesets(&seq, &ray);
    let ratio = job_phase_s.map(|r| r / seq_total.max(1e-9));
    eprintln!(
        "   sequential jobs {seq_total:.1} s, Ray job phase {:.1} s: ratio {:.2}; tilesets {}",
        job_phase_s.unwrap_or(f64::NAN),
        ratio.unwrap_or(f64::NAN),
        if diffs.is_empty() {
            "byte-identical"
        } else {
            "DIFFER"
        }
    );
    let v = json!({
        "jobs": n_jobs,
        "job_triangles": job_tris,
        "unshare": unshare,
        "plan_s": plan_a.wall_s,
        "sequential": {"jobs": seq_jobs, "jobs_total_s": seq_total, "merge_s": merge_a.wall_s,
                       "merge_max_rss_bytes": merge_a.max_rss_bytes},
        "ray": {
            "cluster_start_s": t0.zip(t1).map(|(a, b)| b - a),
            "job_phase_s": job_phase_s,
            "job_phase_source": if phase.is_some() { "driver progress bar (tasks submitted to last result)" }
                                else { "driver wall time (includes ray.init and merge)" },
            "driver_with_merge_s": driver_s,
            "log": ray_log,
        },
        "ratio": ratio,
        "ratio_with_merge": driver_s.map(|d| d / (seq_total + merge_a.wall_s).max(1e-9)),
        "tileset_files": files,
        "identical": diffs.is_empty(),
        "differences": diffs.iter().take(20).collect::<Vec<_>>(),
    });
    cleanup();
    Ok(v)
}

/// The 1-minute load average: a busy machine makes every figure slower.
fn loadavg() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

fn read_json(p: &Path) -> Result<Value, String> {
    let bytes = std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()))?;
    serde_json::from_slice(&bytes).map_err(|e| format!("{}: {e}", p.display()))
}

/// What the figures were measured on.
fn machine(ctx: &Ctx) -> Value {
    let meminfo = std::fs::read_to_string("/proc/meminfo").unwrap_or_default();
    let ram = meminfo
        .lines()
        .find(|l| l.starts_with("MemTotal:"))
        .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        .map(|kb| kb * 1024);
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .unwrap_or_default()
        .lines()
        .find(|l| l.starts_with("model name"))
        .and_then(|l| l.split(':').nth(1))
        .map(|s| s.trim().to_string());
    let cmd_out = |c: &mut Command| {
        c.output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    json!({
        "cores": std::thread::available_parallelism().map(|n| n.get()).ok(),
        "ram_bytes": ram,
        "cpu": cpu,
        "kernel": std::fs::read_to_string("/proc/sys/kernel/osrelease").ok().map(|s| s.trim().to_string()),
        "date_utc": cmd_out(Command::new("date").args(["-u", "+%Y-%m-%dT%H:%M:%SZ"])),
        "git": cmd_out(Command::new("git").arg("-C").arg(&ctx.repo).args(["describe", "--always", "--dirty"])),
        "gnu_time": ctx.gnu_time,
        "loadavg_end": loadavg(),
    })
}

/// Two or three significant digits: the figures span decades.
fn sig(v: f64) -> String {
    let a = v.abs();
    if !v.is_finite() {
        "n/a".into()
    } else if a == 0.0 {
        "0".into()
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else {
        let decimals = (1 - a.log10().floor() as i32).max(0) as usize;
        format!("{v:.decimals$}")
    }
}

/// 8200000 -> "8,200,000".
fn thousands(n: u64) -> String {
    let d = n.to_string();
    let mut out = String::new();
    for (i, c) in d.chars().enumerate() {
        if i > 0 && (d.len() - i) % 3 == 0 {
            out.push(',');
        }
        out.push(c);
    }
    out
}

fn pass(b: bool) -> &'static str {
    if b {
        "PASS"
    } else {
        "FAIL"
    }
}

/// The memory budget the conversions ran with: report.json's option when the binary has one,
/// else --memory-budget-gb (the issue's default, 4 GB).
fn budget_bytes(doc: &Value) -> (f64, &'static str) {
    for p in doc["points"].as_array().into_iter().flatten() {
        if let Some(o) = p["options"].as_object() {
            for (k, v) in o {
                if k.contains("memory_budget") {
                    if let Some(b) = v.as_f64().filter(|b| *b > 0.0) {
                        return (b, "report.json options");
                    }
                }
            }
        }
    }
    (f(&doc["memory_budget_gb"]) * GB, "--memory-budget-gb")
}

fn markdown(ctx: &Ctx, doc: &Value, chart_note: Option<&str>) -> String {
    let mut s = String::new();
    let m = &doc["machine"];
    let points = doc["points"].as_array().cloned().unwrap_or_default();
    let _ = writeln!(s, "# Scale benchmark (issue 12)\n");
    let _ = writeln!(
        s,
        "Machine: {} cores, {:.1} GiB RAM, {}; bimtiles {} ({}); load average {} at the start, {} at the end{}.\n",
        m["cores"],
        f(&m["ram_bytes"]) / 1073741824.0,
        m["cpu"].as_str().unwrap_or("unknown CPU"),
        m["git"].as_str().unwrap_or("?"),
        m["date_utc"].as_str().unwrap_or("?"),
        sig(f(&m["loadavg_start"])),
        sig(f(&m["loadavg_end"])),
        // Anything else running shares the 2 cores: the times are then upper bounds.
        if f(&m["loadavg_start"]) > 0.5 {
            " (the machine was busy with other work: times are inflated)"
        } else {
            ""
        }
    );
    let _ = writeln!(
        s,
        "Inputs: `make_campus.py OUT.glb --copies C --inputs {MINI} --bake [--jitter-m {JITTER_M}]` \
         (seed 1; {} triangles a copy). Conversion: `bimtiles convert IN --out DIR --force --quiet` \
         (defaults: HLOD, Draco), one process each; seconds are wall time, peak memory the larger of \
         report.json's `peak_memory_bytes` and the process's max RSS{}.\n",
        doc["per_copy_triangles"],
        if ctx.gnu_time { " (GNU time)" } else { " (GNU time not installed: report.json only)" }
    );
    let _ = writeln!(
        s,
        "| variant | copies | triangles | seconds | peak MB | output MB | tiles | s per M triangles |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|");
    for p in &points {
        if p["ok"].as_bool() == Some(true) {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {:.1} | {:.0} | {:.1} | {} | {:.2} |",
                p["variant"].as_str().unwrap_or("?"),
                p["copies"],
                thousands(p["triangles"].as_u64().unwrap_or(0)),
                f(&p["wall_s"]),
                f(&p["peak_memory_bytes"]) / MB,
                f(&p["output_bytes"]) / MB,
                p["tiles"],
                f(&p["s_per_mtri"])
            );
        } else {
            let _ = writeln!(
                s,
                "| {} | {} | ~{} | FAILED | | | | |",
                p["variant"].as_str().unwrap_or("?"),
                p["copies"],
                thousands(
                    p["copies"].as_u64().unwrap_or(0)
                        * doc["per_copy_triangles"].as_u64().unwrap_or(0)
                )
            );
        }
    }
    // Stage timings: whatever report.json's timings_s holds (total last).
    let mut stages: Vec<String> = Vec::new();
    for p in &points {
        for k in p["timings_s"]
            .as_object()
            .into_iter()
            .flat_map(|o| o.keys())
        {
            if k != "total" && !stages.contains(k) {
                stages.push(k.clone());
            }
        }
    }
    // Pipeline order for the stages known today; others after them, as report.json names them.
    const ORDER: &[&str] = &["ingest", "dedup", "partition", "encode_write", "tileset"];
    stages.sort_by_key(|k| ORDER.iter().position(|o| o == k).unwrap_or(ORDER.len()));
    if !stages.is_empty() {
        let _ = writeln!(s, "\nStage timings (report.json `timings_s`, seconds):\n");
        let _ = writeln!(
            s,
            "| variant | triangles | {} | total |",
            stages.join(" | ")
        );
        let _ = writeln!(s, "|---|---:|{}---:|", "---:|".repeat(stages.len()));
        for p in points.iter().filter(|p| p["ok"].as_bool() == Some(true)) {
            let cells: Vec<String> = stages.iter().map(|k| sig(f(&p["timings_s"][k]))).collect();
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} |",
                p["variant"].as_str().unwrap_or("?"),
                thousands(p["triangles"].as_u64().unwrap_or(0)),
                cells.join(" | "),
                sig(f(&p["timings_s"]["total"]))
            );
        }
    }
    let failed: Vec<&Value> = points
        .iter()
        .filter(|p| p["ok"].as_bool() != Some(true))
        .collect();
    if !failed.is_empty() {
        let _ = writeln!(s, "\nFailed points:\n");
        for p in failed {
            let _ = writeln!(
                s,
                "- {} x{}: {}",
                p["variant"].as_str().unwrap_or("?"),
                p["copies"],
                p["error"].as_str().unwrap_or("?").replace('\n', "\n  ")
            );
        }
    }

    let _ = writeln!(
        s,
        "\nGrowth exponents (least squares on log-log, `y = a n^k`):\n"
    );
    for (v, fit) in doc["fits"].as_object().into_iter().flatten() {
        let show = |x: &Value| match Fit::from_json(x) {
            Some(f) => format!("{:.3} (R² {:.3}, {} points)", f.k, f.r2, f.n),
            None => "n/a (needs two sizes)".into(),
        };
        let _ = writeln!(
            s,
            "- {v}: time {}, peak memory {}",
            show(&fit["time"]),
            show(&fit["memory"])
        );
    }

    let r = &doc["ray"];
    let _ = writeln!(
        s,
        "\nSharded build ({} jobs, one thread each):\n",
        r["jobs"].as_u64().unwrap_or(ctx.opts.ray_jobs as u64)
    );
    if let Some(e) = r["error"].as_str() {
        let _ = writeln!(s, "- failed: {}", e.replace('\n', "\n  "));
    } else if let Some(e) = r["skipped"].as_str() {
        let _ = writeln!(s, "- skipped: {e}");
    } else if r["pending"].as_bool() == Some(true) {
        let _ = writeln!(s, "- not run yet");
    } else {
        let _ = writeln!(
            s,
            "- campus: {} x{} ({}), job triangles {}",
            r["variant"].as_str().unwrap_or("?"),
            r["copies"],
            r["size"].as_str().unwrap_or("?"),
            r["job_triangles"]
        );
        let _ = writeln!(
            s,
            "- jobs one after another: {:.1} s (merge {:.1} s); on Ray, 2 one-CPU nodes: {:.1} s job phase \
             ({}), {:.1} s driver with merge, {:.1} s cluster start",
            f(&r["sequential"]["jobs_total_s"]),
            f(&r["sequential"]["merge_s"]),
            f(&r["ray"]["job_phase_s"]),
            r["ray"]["job_phase_source"].as_str().unwrap_or(""),
            f(&r["ray"]["driver_with_merge_s"]),
            f(&r["ray"]["cluster_start_s"])
        );
        let _ = writeln!(
            s,
            "- ratio Ray / sequential: {:.3} (with merge: {:.3}); merged tilesets {} ({} files)",
            f(&r["ratio"]),
            f(&r["ratio_with_merge"]),
            if r["identical"].as_bool() == Some(true) {
                "byte-identical".to_string()
            } else {
                format!("DIFFER: {}", r["differences"])
            },
            r["tileset_files"]
        );
    }

    let _ = writeln!(s, "\n## Targets\n");
    let _ = writeln!(s, "| target | measured | result |");
    let _ = writeln!(s, "|---|---|---|");
    let issue_8m = points
        .iter()
        .find(|p| p["copies"].as_u64() == Some(ISSUE_COPIES_8M as u64) && p["variant"] == "jitter");
    let na = |why: &str| ("n/a".to_string(), format!("not measured ({why})"));
    let (m8t, r8t, m8m, r8m) = match issue_8m {
        None => {
            let (a, b) = na("no 8M jitter point");
            (a.clone(), b.clone(), a, b)
        }
        Some(p) if p["ok"].as_bool() != Some(true) => (
            "failed".into(),
            "FAIL".into(),
            "failed".into(),
            "FAIL".into(),
        ),
        Some(p) => {
            let (t, peak) = (f(&p["wall_s"]), f(&p["peak_memory_bytes"]));
            (
                format!("{t:.1} s"),
                pass(t <= TARGET_8M_SECONDS).into(),
                format!("{:.2} GB", peak / GB),
                pass(peak <= TARGET_8M_PEAK_GB * GB).into(),
            )
        }
    };
    let _ = writeln!(
        s,
        "| 8.2M jittered campus, HLOD + Draco, in at most {TARGET_8M_SECONDS} s | {m8t} | {r8t} |"
    );
    let _ = writeln!(
        s,
        "| 8.2M jittered campus, peak memory at most {TARGET_8M_PEAK_GB} GB | {m8m} | {r8m} |"
    );
    let (budget, source) = budget_bytes(doc);
    let limit = budget + GB;
    let big: Vec<&Value> = points
        .iter()
        .filter(|p| {
            p["copies"].as_u64().unwrap_or(0) as f64 * f(&doc["per_copy_triangles"]) >= 99e6
        })
        .collect();
    let (mb, rb) = if big.is_empty() {
        na("no 100M point")
    } else {
        let all_ok = big
            .iter()
            .all(|p| p["ok"].as_bool() == Some(true) && f(&p["peak_memory_bytes"]) < limit);
        let cells: Vec<String> = big
            .iter()
            .map(|p| {
                let v = p["variant"].as_str().unwrap_or("?");
                if p["ok"].as_bool() == Some(true) {
                    format!(
                        "{v}: {:.2} GB, {:.0} s",
                        f(&p["peak_memory_bytes"]) / GB,
                        f(&p["wall_s"])
                    )
                } else {
                    format!("{v}: failed")
                }
            })
            .collect();
        (cells.join("; "), pass(all_ok).to_string())
    };
    let _ = writeln!(
        s,
        "| 100M triangles complete, peak memory under the budget + 1 GB ({:.1} GB; budget from {source}) | {mb} | {rb} |",
        limit / GB
    );
    let (m100, r100) = match big.iter().find(|p| p["variant"] == "jitter") {
        None => na("no 100M jitter point"),
        Some(p) if p["ok"].as_bool() != Some(true) => ("failed".into(), "FAIL".into()),
        Some(p) => {
            let (t, peak) = (f(&p["wall_s"]), f(&p["peak_memory_bytes"]));
            let ok = t <= TARGET_100M_SECONDS
                && peak <= TARGET_100M_PEAK_GB * GB
                && budget <= TARGET_100M_PEAK_GB * GB;
            (format!("{t:.0} s, {:.2} GB", peak / GB), pass(ok).into())
        }
    };
    let _ = writeln!(
        s,
        "| 100M jittered campus under a budget of at most {TARGET_100M_PEAK_GB} GB ({:.1} GB), in at most {TARGET_100M_SECONDS} s and {TARGET_100M_PEAK_GB} GB | {m100} | {r100} |",
        budget / GB
    );
    let mut exps = Vec::new();
    let mut exp_ok = true;
    for (v, fit) in doc["fits"].as_object().into_iter().flatten() {
        if let Some(fit) = Fit::from_json(&fit["time"]) {
            exps.push(format!(
                "{v} {:.3} ({}-{}M triangles)",
                fit.k,
                sig(f(&doc["fits"][v]["triangles_min"]) / 1e6),
                sig(f(&doc["fits"][v]["triangles_max"]) / 1e6)
            ));
            exp_ok &= fit.k <= TARGET_EXPONENT;
        }
    }
    let (me, re) = if exps.is_empty() {
        na("needs two sizes")
    } else {
        (exps.join(", "), pass(exp_ok).to_string())
    };
    let _ = writeln!(
        s,
        "| time grows with an exponent of at most {TARGET_EXPONENT} | {me} | {re} |"
    );
    let (mr, rr) = match r["ratio"].as_f64() {
        Some(x) if r["identical"].as_bool() == Some(true) => {
            (format!("{x:.3}"), pass(x <= TARGET_RAY_RATIO).to_string())
        }
        Some(x) => (format!("{x:.3}, tilesets differ"), "FAIL".into()),
        None if r["error"].is_string() => ("failed".into(), "FAIL".into()),
        None if r["pending"].as_bool() == Some(true) => na("not run yet"),
        None => na(r["skipped"].as_str().unwrap_or("skipped")),
    };
    let _ = writeln!(
        s,
        "| Ray on 2 local workers, one thread a job, at most {TARGET_RAY_RATIO}x the jobs one after another | {mr} | {rr} |"
    );
    match chart_note {
        None => {
            let _ = writeln!(s, "\nChart: `scale.png` (time and peak memory against triangles, log-log, with the fits).");
        }
        Some(e) => {
            let _ = writeln!(s, "\nChart not drawn: {e}");
        }
    }
    s
}

/// One variant's measured points (millions of triangles, y) and fit, for a panel.
struct Line {
    variant: Variant,
    points: Vec<(f64, f64)>,
    fit: Option<Fit>,
}

/// Time (left) and peak memory (right) against triangles, log-log, per variant with its fit.
fn draw_chart(path: &Path, doc: &Value, variants: &[Variant]) -> Res<()> {
    let rows = doc["points"].as_array().cloned().unwrap_or_default();
    let lines = |key: &str, fit_key: &str, scale: f64| -> Vec<Line> {
        variants
            .iter()
            .map(|&v| Line {
                variant: v,
                points: ok_rows(&rows, v)
                    .map(|r| (f(&r["triangles"]) / 1e6, f(&r[key]) * scale))
                    .filter(|(x, y)| *x > 0.0 && *y > 0.0)
                    .collect(),
                // The fit is on triangles and the raw unit: rescale both axes.
                fit: Fit::from_json(&doc["fits"][v.name()][fit_key]).map(|mut fit| {
                    fit.ln_a += fit.k * 1e6f64.ln() + scale.ln();
                    fit
                }),
            })
            .collect()
    };
    let time = lines("wall_s", "time", 1.0);
    let mem = lines("peak_memory_bytes", "memory", 1.0 / MB);
    if time.iter().all(|l| l.points.is_empty()) {
        return Err("no conversion succeeded".into());
    }
    load_font()?;
    let root = BitMapBackend::new(path, (1500, 640)).into_drawing_area();
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(750);
    panel(
        &left,
        "Conversion time vs triangles (log-log)",
        "seconds (wall)",
        "time",
        &time,
        None,
    )?;
    let (budget, _) = budget_bytes(doc);
    panel(
        &right,
        "Peak memory vs triangles (log-log)",
        "peak memory (MB)",
        "memory",
        &mem,
        Some((budget / MB, format!("memory budget {:.1} GB", budget / GB))),
    )?;
    root.present()?;
    Ok(())
}

/// Tick values 1-2-5 per decade within [lo, hi] (every integer multiple when that gives too few):
/// plotters labels little more than the powers of ten on a log axis.
fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let ticks = |mults: &[f64]| -> Vec<f64> {
        let (d0, d1) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
        (d0..=d1)
            .flat_map(|d| mults.iter().map(move |m| m * 10f64.powi(d)))
            .filter(|v| (lo..=hi).contains(v))
            .collect()
    };
    let t = ticks(&[1.0, 2.0, 5.0]);
    if t.len() >= 4 {
        t
    } else {
        ticks(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0])
    }
}

fn panel(
    area: &DrawingArea<BitMapBackend, Shift>,
    title: &str,
    y_desc: &str,
    what: &str,
    lines: &[Line],
    hline: Option<(f64, String)>,
) -> Res<()> {
    let font = |size: u32| (FONT, size).into_font();
    let xs: Vec<f64> = lines
        .iter()
        .flat_map(|l| l.points.iter().map(|p| p.0))
        .collect();
    let mut ys: Vec<f64> = lines
        .iter()
        .flat_map(|l| l.points.iter().map(|p| p.1))
        .collect();
    if let Some((y, _)) = &hline {
        ys.push(*y);
    }
    let (x0, x1) = (
        xs.iter().cloned().fold(f64::INFINITY, f64::min),
        xs.iter().cloned().fold(0.0, f64::max),
    );
    let (y0, y1) = (
        ys.iter().cloned().fold(f64::INFINITY, f64::min),
        ys.iter().cloned().fold(0.0, f64::max),
    );
    if !x0.is_finite() || !y0.is_finite() {
        return Ok(());
    }
    let (x0, x1) = (x0 / 1.6, x1 * 1.6);
    // Headroom above for the legend.
    let (y0, y1) = (y0 / 2.0, y1 * 6.0);
    let exps: Vec<String> = lines
        .iter()
        .filter_map(|l| l.fit.map(|f| format!("{} {:.2}", l.variant.name(), f.k)))
        .collect();
    let caption = if exps.is_empty() {
        title.to_string()
    } else {
        format!("{title}; exponent {}", exps.join(", "))
    };
    let mut chart = ChartBuilder::on(area)
        .caption(caption, font(17))
        .margin(14)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(
            (x0..x1).log_scale().with_key_points(log_ticks(x0, x1)),
            (y0..y1).log_scale().with_key_points(log_ticks(y0, y1)),
        )?;
    chart
        .configure_mesh()
        .x_desc("input triangles (millions)")
        .y_desc(y_desc)
        .x_label_formatter(&|v: &f64| sig(*v))
        .y_label_formatter(&|v: &f64| sig(*v))
        .label_style(font(13))
        .axis_desc_style(font(14))
        .draw()?;
    // Dashes (plotters' line-series feature is off): every other piece of a log-spaced polyline.
    let dashed = |f: &dyn Fn(f64) -> f64, style: ShapeStyle| {
        let n = 48;
        let x_at = |i: usize| x0 * (x1 / x0).powf(i as f64 / n as f64);
        (0..n)
            .step_by(2)
            .map(|i| (x_at(i), x_at(i + 1)))
            .filter(|&(a, b)| (y0..=y1).contains(&f(a)) && (y0..=y1).contains(&f(b)))
            .map(|(a, b)| PathElement::new(vec![(a, f(a)), (b, f(b))], style))
            .collect::<Vec<_>>()
    };
    for l in lines.iter().filter(|l| !l.points.is_empty()) {
        let color = l.variant.color();
        chart
            .draw_series(std::iter::once(PathElement::new(
                l.points.clone(),
                color.stroke_width(2),
            )))?
            .label(format!("{}: measured", l.variant.describe()))
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], color.stroke_width(2)));
        chart.draw_series(l.points.iter().map(|&p| Circle::new(p, 4, color.filled())))?;
        if let Some(fit) = l.fit {
            let style = color.mix(0.8).stroke_width(1);
            chart
                .draw_series(dashed(&|x| fit.at(x), style))?
                .label(format!(
                    "{} fit: {what} ~ n^{:.2} (R² {:.3})",
                    l.variant.name(),
                    fit.k,
                    fit.r2
                ))
                .legend(move |(x, y)| {
                    // A dashed sample: two short strokes.
                    EmptyElement::at((x, y))
                        + PathElement::new([(0, 0), (7, 0)], style)
                        + PathElement::new([(11, 0), (18, 0)], style)
                });
        }
    }
    if let Some((y, label)) = hline {
        let style = RGBColor(120, 120, 120).stroke_width(1);
        chart
            .draw_series(dashed(&|_| y, style))?
            .label(label)
            .legend(move |(x, y)| {
                // A dashed sample: two short strokes.
                EmptyElement::at((x, y))
                    + PathElement::new([(0, 0), (7, 0)], style)
                    + PathElement::new([(11, 0), (18, 0)], style)
            });
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(font(12))
        .draw()?;
    Ok(())
}
