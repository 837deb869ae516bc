//! Speed of `bimtiles::simplify` vs meshoptimizer (`harness = false`):
//! `cargo bench --bench simplify`. Uses every `*.glb` in /work/shared/data
//! (or `$BIMTILES_SHARED/data`) when present, loaded as the quality test does
//! (world transforms, normals, node index as group), and a ~1M-triangle
//! synthetic grid.
//!
//! Environment: `BENCH_REPS` (default 3; the minimum time is reported),
//! `BENCH_MODELS` (comma-separated name substrings; default all),
//! `BENCH_ERROR=1` also times the measured error (`error_m`) separately.
//! Each line ends with a hash of the output (positions, indices, error_m),
//! to check that a pure speed change leaves the result bit-identical.
//! `cpu` is the process CPU time of ours / meshoptimizer's: a large mesh is
//! simplified in parallel (groups of parts or cells: `src/simplify/parts.rs`),
//! meshoptimizer on one thread. Paper-scale inputs: a folder with `data/` made
//! by `make_campus.py --bake` (e.g. 34 copies of Mini_Project: 8.2M triangles)
//! as `BIMTILES_SHARED`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use bimtiles::simplify::{simplify, MeshInput, SimplifiedMesh, SimplifyOptions};

#[path = "../tests/support/world.rs"]
#[allow(dead_code)]
mod world;

struct Model {
    name: String,
    positions: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    groups: Option<Vec<u32>>,
    indices: Vec<u32>,
}

fn grid(n: usize) -> Model {
    let mut p = Vec::new();
    for y in 0..=n {
        for x in 0..=n {
            let (fx, fy) = (x as f32 / n as f32, y as f32 / n as f32);
            p.push([
                fx * 100.0,
                fy * 100.0,
                2.0 * (fx * 13.0).sin() * (fy * 11.0).cos(),
            ]);
        }
    }
    let w = n as u32 + 1;
    let mut idx = Vec::new();
    for y in 0..n as u32 {
        for x in 0..n as u32 {
            let i = y * w + x;
            idx.extend([i, i + 1, i + w + 1, i, i + w + 1, i + w]);
        }
    }
    Model {
        name: "grid-1M".into(),
        positions: p,
        normals: None,
        groups: None,
        indices: idx,
    }
}

/// All primitives merged in world coordinates, group id = node index (the loader of
/// tests/simplify_quality.rs).
fn load_glb(path: &Path) -> Option<Model> {
    let name = path.file_stem()?.to_string_lossy().into_owned();
    let m = world::world_mesh(path)?;
    (!m.indices.is_empty()).then_some(Model {
        name,
        positions: m.positions,
        normals: Some(m.normals),
        groups: Some(m.groups),
        indices: m.indices,
    })
}

/// CPU time of the process (all threads) in seconds, from /proc/self/stat
/// (0 where unavailable): less disturbed than wall time by other jobs on a
/// shared machine.
fn cpu_time() -> f64 {
    let Ok(s) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // Fields after the parenthesised command name; utime and stime are the
    // 14th and 15th fields of the line, in clock ticks (100 Hz on Linux).
    let rest = s.rsplit_once(')').map_or("", |r| r.1);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|x| x.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

/// FNV-1a over the output positions, indices and declared error.
fn hash(r: &SimplifiedMesh) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |x: u64| {
        h ^= x;
        h = h.wrapping_mul(0x0100_0000_01b3);
    };
    r.positions
        .iter()
        .flatten()
        .for_each(|x| eat(x.to_bits() as u64));
    r.indices.iter().for_each(|&i| eat(i as u64));
    if r.error_m.is_finite() {
        eat(r.error_m.to_bits());
    }
    h
}

fn bench(m: &Model, reps: usize, time_error: bool) {
    let tris = m.indices.len() / 3;
    let input = MeshInput {
        positions: &m.positions,
        normals: m.normals.as_deref(),
        groups: m.groups.as_deref(),
        indices: &m.indices,
        ..Default::default()
    };
    let bytes: Vec<u8> = m
        .positions
        .iter()
        .flat_map(|v| v.iter().flat_map(|x| x.to_le_bytes()))
        .collect();
    let ad = meshopt::VertexDataAdapter::new(&bytes, 12, 0).unwrap();
    for ratio in [0.5f32, 0.1] {
        let o = SimplifyOptions {
            target_ratio: ratio,
            compute_error_bound: false,
            ..Default::default()
        };
        let (mut ours, mut theirs, mut full) = (f64::MAX, f64::MAX, f64::MAX);
        let (mut ours_cpu, mut theirs_cpu) = (f64::MAX, f64::MAX);
        let mut r = None;
        let mut mo_tris = 0;
        for _ in 0..reps {
            let (t, c) = (Instant::now(), cpu_time());
            let out = simplify(&input, &o).unwrap();
            ours = ours.min(t.elapsed().as_secs_f64());
            ours_cpu = ours_cpu.min(cpu_time() - c);
            let (t, c) = (Instant::now(), cpu_time());
            let mo = meshopt::simplify(
                &m.indices,
                &ad,
                out.indices.len(),
                1.0,
                meshopt::SimplifyOptions::Permissive,
                None,
            );
            theirs = theirs.min(t.elapsed().as_secs_f64());
            theirs_cpu = theirs_cpu.min(cpu_time() - c);
            mo_tris = mo.len() / 3;
            r = Some(out);
        }
        let mut r = r.unwrap();
        if time_error {
            for _ in 0..reps {
                let t = Instant::now();
                r = simplify(
                    &input,
                    &SimplifyOptions {
                        target_ratio: ratio,
                        ..Default::default()
                    },
                )
                .unwrap();
                full = full.min(t.elapsed().as_secs_f64());
            }
        }
        let err = if time_error {
            format!(
                " | error_m {:.5} in {:.3} s",
                r.error_m,
                (full - ours).max(0.0)
            )
        } else {
            String::new()
        };
        println!(
            "{:<26} {:>3.0}% {:>8} -> {:>7} | ours {:>7.3} s ({:>5.2} Mtri/s) | meshopt {:>6.3} s ({} tris) | ratio {:>5.2}x | cpu {:.2} / {:.2} s | hash {:016x}{err}",
            m.name,
            ratio * 100.0,
            tris,
            r.triangle_count(),
            ours,
            tris as f64 / ours / 1e6,
            theirs,
            mo_tris,
            ours / theirs,
            ours_cpu,
            theirs_cpu,
            hash(&r),
        );
    }
}

fn main() {
    let reps: usize = std::env::var("BENCH_REPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(3);
    let time_error = std::env::var("BENCH_ERROR").is_ok_and(|v| v == "1");
    let filter: Vec<String> = std::env::var("BENCH_MODELS")
        .map(|s| s.split(',').map(str::to_owned).collect())
        .unwrap_or_default();
    let wanted = |name: &str| filter.is_empty() || filter.iter().any(|f| name.contains(f));
    let dir = std::env::var("BIMTILES_SHARED")
        .map(|s| PathBuf::from(s).join("data"))
        .unwrap_or_else(|_| PathBuf::from("/work/shared/data"));
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "glb"))
                .collect()
        })
        .unwrap_or_default();
    paths.sort();
    if paths.is_empty() {
        println!("no *.glb in {}: real models skipped", dir.display());
    }
    for p in paths {
        let name = p.file_stem().unwrap_or_default().to_string_lossy();
        if !wanted(&name) {
            continue;
        }
        match load_glb(&p) {
            Some(m) => bench(&m, reps, time_error),
            None => println!("{} unreadable or empty, skipped", p.display()),
        }
    }
    if wanted("grid-1M") {
        bench(&grid(708), reps, time_error);
    }
}
