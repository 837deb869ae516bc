//! Sharded builds (scenes too large for one machine's time or memory): `plan` → `build-job` × N
//! (any order, any machine that sees DIR and the inputs) → `merge`, giving the tileset `convert`
//! gives, byte for byte.
//!
//! `plan` reads the inputs, runs everything before the tiles (placement, dedup, texture
//! preparation, the octree of `partition::plan_octree`) and splits the tree: from the root, the
//! subtree with the most triangles is replaced by its children until there are at least N
//! subtrees (or nothing left to split); the tiles so opened are the *top levels*, the subtrees are
//! dealt to N jobs, largest first, each to the least loaded. The split only chooses who builds
//! what; the tree is `convert`'s. `DIR/plan.json` records the split, a digest of the plan and the
//! options, and the command that re-creates the options (for the CLI).
//!
//! Each process re-reads the inputs and re-plans (a pure function of input and options; the
//! digest is checked), so nothing but DIR is shared. A job writes its tiles under their final
//! names through temporary names and, last, `DIR/jobs/job-K.bin` ([`wire`]): its tiles' figures
//! and, for HLOD, what its subtree roots hand their parents. `merge` accepts a job only through
//! that file, builds the top levels from the subtree roots exactly as `convert` does
//! ([`crate::tiling::TileWriter`] is the one code path: `convert` is a single job over the whole
//! tree, merged in memory), moves the texture files of one tile into it, and writes schema.json
//! (when the tiles share it), tileset.json and report.json.
//!
//! Identical to `convert`: every tile, texture file, tileset.json and schema.json. report.json differs in its
//! timings, peak memory, dedup seconds, and the texture tallies (`textures.written_*`,
//! pyramid levels), which count what the merging process itself wrote.

pub(crate) mod wire;

use crate::error::{Error, Result};
use crate::ingest::InputSet;
use crate::options::{ConvertOptions, LodMode, Settings};
use crate::output_dir::{check_replaceable, write_renamed, StagingDir};
use crate::partition::TilePlan;
use crate::prepare::{prepare, read_scene, Prepared};
use crate::report::{make_report, peak_memory_bytes, MemoryReport, Report, Timings};
use crate::scene::Scene;
use crate::tiling::TileWriter;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

pub const PLAN_FILE: &str = "plan.json";
pub const JOBS_DIR: &str = "jobs";
const PLAN_FORMAT: &str = "bimtiles-plan/1";

/// `DIR/plan.json`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct PlanFile {
    pub format: String,
    /// What the command line needs to re-create the inputs and options (opaque to the library).
    pub command: serde_json::Value,
    /// Digest of the octree and the options: every process must find the same.
    pub plan_digest: String,
    pub tiles: usize,
    /// Tiles built by `merge`, by path.
    pub top: Vec<String>,
    pub jobs: Vec<PlanJob>,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct PlanJob {
    pub job: usize,
    /// Subtree roots, by tile path.
    pub roots: Vec<String>,
    pub tiles: usize,
    pub triangles: usize,
}

/// What a job did.
#[derive(Debug, Clone, Serialize)]
pub struct JobSummary {
    pub job: usize,
    pub tiles: usize,
    pub seconds: f64,
}

/// Splits `plan` into top levels and `jobs` groups of subtree roots (see the module doc).
pub fn split(plan: &TilePlan, jobs: usize) -> (Vec<usize>, Vec<Vec<usize>>) {
    let jobs = jobs.max(1);
    let n = plan.tiles.len();
    let mut below = vec![0usize; n];
    for i in (0..n).rev() {
        below[i] = plan.tiles[i].content_triangles
            + plan.tiles[i]
                .children
                .iter()
                .map(|&c| below[c])
                .sum::<usize>();
    }
    let mut top = Vec::new();
    let mut frontier: Vec<usize> = if n == 0 { Vec::new() } else { vec![0] };
    while frontier.len() < jobs {
        let open = frontier
            .iter()
            .enumerate()
            .filter(|(_, &t)| !plan.tiles[t].children.is_empty())
            .max_by_key(|(_, &t)| (below[t], std::cmp::Reverse(t)))
            .map(|(k, _)| k);
        let Some(k) = open else { break };
        let t = frontier.swap_remove(k);
        top.push(t);
        frontier.extend(&plan.tiles[t].children);
    }
    top.sort_unstable();
    frontier.sort_by_key(|&t| (std::cmp::Reverse(below[t]), t));
    let mut groups = vec![Vec::new(); jobs];
    let mut load = vec![0usize; jobs];
    for t in frontier {
        let k = (0..jobs).min_by_key(|&k| (load[k], k)).expect("jobs > 0");
        load[k] += below[t].max(1);
        groups[k].push(t);
    }
    for g in &mut groups {
        g.sort_unstable();
    }
    (top, groups)
}

/// FNV-1a over formatted text: a digest stable across processes and machines.
struct Fnv(u64);

impl std::fmt::Write for Fnv {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        for b in s.bytes() {
            self.0 = (self.0 ^ b as u64).wrapping_mul(0x100_0000_01b3);
        }
        Ok(())
    }
}

/// Digest of the plan and of the options that shape the tiles.
fn digest(plan: &TilePlan, opts: &ConvertOptions) -> String {
    use std::fmt::Write;
    let mut o = opts.clone();
    o.out_dir = PathBuf::new();
    o.force = false;
    o.progress = false;
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    let _ = write!(h, "{o:?}");
    for t in &plan.tiles {
        let _ = write!(h, "{t:?}");
    }
    format!("{:016x}", h.0)
}

fn subtree_tiles(plan: &TilePlan, root: usize) -> usize {
    let mut n = 0;
    let mut stack = vec![root];
    while let Some(j) = stack.pop() {
        n += 1;
        stack.extend(&plan.tiles[j].children);
    }
    n
}

/// `bimtiles plan`: writes `opts.out_dir/plan.json` for `jobs` jobs. The folder must not exist,
/// unless `opts.force` (then it must hold a plan or a tileset, and is emptied).
pub fn plan(
    inputs: &InputSet,
    opts: &ConvertOptions,
    jobs: usize,
    command: serde_json::Value,
) -> Result<PlanFile> {
    let opts = &opts.resolve();
    let dir = &opts.out_dir;
    if matches!(opts.lod, LodMode::Ratios(_)) {
        // A chain hangs below a whole leaf; jobs split the tree above leaves (not built yet).
        return Err(Error::output(
            dir,
            "--lod-ratios is supported by convert only, not by sharded builds",
        ));
    }
    // Inputs and options are checked before anything is replaced: the old folder goes only
    // when the new plan is complete (`StagingDir::commit`).
    const PLAN_OR_TILESET: &[&str] = &[PLAN_FILE, "tileset.json"];
    const WHAT: &str = "a plan or a tileset";
    check_replaceable(dir, opts.force, PLAN_OR_TILESET, WHAT)?;
    let mut scene = read_scene(inputs, opts)?;
    let prep = prepare(&mut scene, opts)?;
    let p = &prep.plan;
    let (top, groups) = split(p, jobs);
    let tri = |r: &usize| {
        let mut n = 0;
        let mut stack = vec![*r];
        while let Some(j) = stack.pop() {
            n += p.tiles[j].content_triangles;
            stack.extend(&p.tiles[j].children);
        }
        n
    };
    let file = PlanFile {
        format: PLAN_FORMAT.into(),
        command,
        plan_digest: digest(p, opts),
        tiles: p.tiles.len(),
        top: top.iter().map(|&t| p.tiles[t].path.clone()).collect(),
        jobs: groups
            .iter()
            .enumerate()
            .map(|(k, g)| PlanJob {
                job: k,
                roots: g.iter().map(|&t| p.tiles[t].path.clone()).collect(),
                tiles: g.iter().map(|&t| subtree_tiles(p, t)).sum(),
                triangles: g.iter().map(tri).sum(),
            })
            .collect(),
    };
    let staging = StagingDir::beside_for(dir, opts.force, PLAN_OR_TILESET, WHAT)?;
    let jobs_dir = staging.path().join(JOBS_DIR);
    std::fs::create_dir_all(&jobs_dir)
        .map_err(|e| Error::output_from(dir.join(JOBS_DIR), "cannot create the folder", e))?;
    let json = serde_json::to_vec_pretty(&file)
        .map_err(|e| Error::output_from(dir, "cannot serialize plan.json", e))?;
    staging.commit(&[(PLAN_FILE, &json)])?;
    Ok(file)
}

/// Reads `dir/plan.json` (for the CLI, which re-creates the options from its `command`).
pub fn read_plan(dir: &Path) -> Result<PlanFile> {
    let path = dir.join(PLAN_FILE);
    let bytes = std::fs::read(&path).map_err(|e| {
        Error::input(
            &path,
            if e.kind() == std::io::ErrorKind::NotFound {
                "no plan here (run `bimtiles plan` first)".to_string()
            } else {
                e.to_string()
            },
        )
    })?;
    let file: PlanFile = serde_json::from_slice(&bytes)
        .map_err(|e| Error::input(&path, format!("not a bimtiles plan: {e}")))?;
    if file.format != PLAN_FORMAT {
        return Err(Error::input(
            &path,
            format!("plan format '{}', expected '{PLAN_FORMAT}'", file.format),
        ));
    }
    Ok(file)
}

/// The state every job and the merge start from: the inputs read and planned again, checked
/// against the plan file.
struct Loaded {
    file: PlanFile,
    scene: Scene,
    prep: Prepared,
    t_ingest: f64,
    /// Each job's subtree roots, as tile indices.
    roots: Vec<Vec<usize>>,
}

fn load(dir: &Path, inputs: &InputSet, opts: &Settings) -> Result<Loaded> {
    let t0 = Instant::now();
    let file = read_plan(dir)?;
    let mut scene = read_scene(inputs, opts)?;
    let t_ingest = t0.elapsed().as_secs_f64();
    let prep = prepare(&mut scene, opts)?;
    if digest(&prep.plan, opts) != file.plan_digest {
        return Err(Error::input(
            dir.join(PLAN_FILE),
            "the inputs or options no longer give the planned octree (run `bimtiles plan` again)",
        ));
    }
    let index: BTreeMap<&str, usize> = prep
        .plan
        .tiles
        .iter()
        .enumerate()
        .map(|(i, t)| (t.path.as_str(), i))
        .collect();
    let roots = file
        .jobs
        .iter()
        .map(|j| {
            j.roots
                .iter()
                .map(|r| {
                    index.get(r.as_str()).copied().ok_or_else(|| {
                        Error::input(dir.join(PLAN_FILE), format!("unknown tile '{r}'"))
                    })
                })
                .collect::<Result<Vec<_>>>()
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Loaded {
        file,
        scene,
        prep,
        t_ingest,
        roots,
    })
}

fn job_path(dir: &Path, job: usize) -> PathBuf {
    dir.join(JOBS_DIR).join(format!("job-{job}.bin"))
}

/// `bimtiles build-job`: builds job `job`'s subtrees into `dir` and writes its result file last.
pub fn build_job(
    dir: &Path,
    job: usize,
    inputs: &InputSet,
    opts: &ConvertOptions,
) -> Result<JobSummary> {
    let t0 = Instant::now();
    let opts = &opts.resolve();
    let l = load(dir, inputs, opts)?;
    let Some(roots) = l.roots.get(job) else {
        return Err(Error::Options(format!(
            "--job {job}: the plan in {} has jobs 0 to {}",
            dir.display(),
            l.roots.len().saturating_sub(1)
        )));
    };
    let result = job_path(dir, job);
    if result.exists() {
        std::fs::remove_file(&result).map_err(|e| Error::output(&result, e))?;
    }
    let plan = &l.prep.plan;
    let uses = &l.prep.textures_prepared.uses;
    let textures = crate::texture::TextureLevels::new(&l.scene, &opts.texture, uses).shared_in(dir);
    let count = roots.iter().map(|&r| subtree_tiles(plan, r)).sum();
    let writer = TileWriter::new(&l.scene, &l.prep, opts, dir, &textures, count)?;
    let output = writer.build_subtrees(roots, &Default::default(), Default::default())?;
    writer.finish_progress();
    let tiles = output.tiles.len();
    let seconds = t0.elapsed().as_secs_f64();
    let bytes = wire::encode(&wire::JobFile {
        plan_digest: l.file.plan_digest.clone(),
        job,
        seconds,
        output,
    });
    std::fs::create_dir_all(dir.join(JOBS_DIR)).map_err(|e| Error::output(dir, e))?;
    write_renamed(&result, &bytes)?;
    Ok(JobSummary {
        job,
        tiles,
        seconds,
    })
}

/// Jobs of the plan in `dir` without a result file yet (what to run again).
pub fn missing_jobs(dir: &Path) -> Result<Vec<usize>> {
    let file = read_plan(dir)?;
    Ok((0..file.jobs.len())
        .filter(|&k| !job_path(dir, k).is_file())
        .collect())
}

/// Leftover temporary files of killed processes (`.NAME.tmp-PID`) under `dir`'s tiles and jobs.
fn leftover_temp_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for sub in ["tiles", crate::texture::external::TEXTURE_DIR, JOBS_DIR] {
        if let Ok(rd) = std::fs::read_dir(dir.join(sub)) {
            for e in rd.flatten() {
                let name = e.file_name().to_string_lossy().to_string();
                if name.starts_with('.') && name.contains(".tmp-") {
                    out.push(e.path());
                }
            }
        }
    }
    out.sort();
    out
}

/// `bimtiles merge`: checks every job's result, builds the top levels and writes schema.json,
/// tileset.json and report.json into `dir`.
pub fn merge(dir: &Path, inputs: &InputSet, opts: &ConvertOptions) -> Result<Report> {
    let t0 = Instant::now();
    let opts = &opts.resolve();
    let missing = missing_jobs(dir)?;
    if !missing.is_empty() {
        let list: Vec<String> = missing.iter().map(|k| k.to_string()).collect();
        return Err(Error::input(
            dir,
            format!(
                "{} of {} jobs have no result yet (jobs {}): run `bimtiles build-job {} --job K` for them",
                missing.len(),
                read_plan(dir)?.jobs.len(),
                list.join(", "),
                dir.display()
            ),
        ));
    }
    let l = load(dir, inputs, opts)?;
    let mut outputs = Vec::new();
    let mut job_seconds = 0.0;
    for k in 0..l.roots.len() {
        let path = job_path(dir, k);
        let bytes = std::fs::read(&path).map_err(|e| Error::input(&path, e.to_string()))?;
        let f = wire::decode(&bytes)
            .map_err(|e| Error::input(&path, format!("{e} (run build-job --job {k} again)")))?;
        if f.plan_digest != l.file.plan_digest || f.job != k {
            return Err(Error::input(
                &path,
                format!("made for another plan or job (run build-job --job {k} again)"),
            ));
        }
        for (_, record) in &f.output.tiles {
            if let Some(uri) = &record.uri {
                let tile = dir.join(uri);
                if std::fs::metadata(&tile).map(|m| m.len()).ok() != Some(record.content.bytes) {
                    return Err(Error::input(
                        &tile,
                        format!(
                            "missing or not the size job {k} wrote (run build-job --job {k} again)"
                        ),
                    ));
                }
            }
        }
        job_seconds += f.seconds;
        outputs.push(f.output);
    }
    for leftover in leftover_temp_files(dir) {
        std::fs::remove_file(&leftover).map_err(|e| Error::output(&leftover, e))?;
    }
    let all_roots: Vec<usize> = l.roots.iter().flatten().copied().collect();
    let uses = &l.prep.textures_prepared.uses;
    let textures = crate::texture::TextureLevels::new(&l.scene, &opts.texture, uses).shared_in(dir);
    let t = Instant::now();
    let writer = TileWriter::new(&l.scene, &l.prep, opts, dir, &textures, l.file.top.len())?;
    let records = writer.merge(outputs, &all_roots, l.prep.origin, l.prep.anchor)?;
    writer.finish_progress();
    let timings = Timings {
        ingest: l.t_ingest,
        dedup: l.prep.t_dedup,
        partition: l.prep.t_partition,
        encode_write: job_seconds + t.elapsed().as_secs_f64(),
        tileset: 0.0,
        total: 0.0,
    };
    let memory = MemoryReport::of(&l.scene);
    let first_view_edges = crate::inspect::first_view::edge_gzip_bytes(&records, dir);
    let mut report = make_report(l.prep, records, opts, dir, timings, textures);
    report.output.first_view_edge_gzip_bytes = first_view_edges;
    report.timings_s.total = t0.elapsed().as_secs_f64() + job_seconds;
    report.peak_memory_bytes = peak_memory_bytes();
    report.memory = memory;
    let json = serde_json::to_vec_pretty(&report).map_err(|e| Error::output(dir, e))?;
    write_renamed(&dir.join("report.json"), &json)?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whatever N, the top levels and the jobs' subtrees cover every tile exactly once, a top
    /// tile's children are top tiles or subtree roots, and the jobs carry every triangle.
    #[test]
    fn split_covers_the_tree_once() {
        let mut scene = crate::ingest::read_embedded_sample().unwrap();
        let mut opts = ConvertOptions::new("unused");
        opts.octree.max_tile_triangles = 1500;
        let prep = prepare(&mut scene, &opts.resolve()).unwrap();
        let plan = &prep.plan;
        assert!(plan.tiles.len() > 10);
        for n in 1..=7 {
            let (top, jobs) = split(plan, n);
            assert_eq!(jobs.len(), n);
            if n == 1 {
                assert!(top.is_empty() && jobs[0] == vec![0]);
            }
            let mut seen = vec![0; plan.tiles.len()];
            for &t in &top {
                seen[t] += 1;
            }
            let roots: Vec<usize> = jobs.iter().flatten().copied().collect();
            for &r in &roots {
                let mut stack = vec![r];
                while let Some(j) = stack.pop() {
                    seen[j] += 1;
                    stack.extend(&plan.tiles[j].children);
                }
            }
            assert!(seen.iter().all(|&s| s == 1), "n={n}: {seen:?}");
            for &t in &top {
                for c in &plan.tiles[t].children {
                    assert!(top.contains(c) || roots.contains(c));
                }
            }
            assert!(jobs.iter().filter(|j| !j.is_empty()).count() == n.min(roots.len()));
        }
    }
}
