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
//! With `--update` (book: guide/updating.md) the build goes beside the live tileset, in
//! `DIR/.bimtiles/shard/` (never served): `plan.json`, `jobs/` and the new tileset in `tileset/`.
//! `plan` checks the update as `convert --update` does; when something changed it builds every
//! leaf, keys every tile in the tile cache ([`crate::lod::subtree_cache`]) and marks a job
//! `"changed": false` when every HLOD tile of its subtrees would be taken from the cache. Such a
//! job has nothing to do and no result file; `merge` keys and takes its subtrees (building their
//! leaves, which are cheap, and remaking a root's hand-over from its recipe if its parent is
//! built), builds the top levels, writes the tile cache and the update state, and puts the new
//! tileset in place of the live one by one atomic exchange, its unchanged files kept
//! ([`crate::update::reuse_unchanged_files`]). The result is `convert --update`'s, byte for
//! byte; the jobs marked changed are the only ones that simplify anything.
//!
//! Identical to `convert`: every tile, texture file, tileset.json and schema.json. report.json differs in its
//! timings, peak memory, dedup seconds, and the texture tallies (`textures.written_*`,
//! pyramid levels), which count what the merging process itself wrote.

pub(crate) mod wire;

use crate::convert::{given_paths, up_to_date, Tracked, Updated};
use crate::error::{Error, Result};
use crate::ingest::InputSet;
use crate::lod::subtree_cache::SubtreeCache;
use crate::options::{ConvertOptions, LodMode, Settings};
use crate::output_dir::{check_replaceable, write_renamed, StagingDir};
use crate::partition::TilePlan;
use crate::prepare::{prepare, read_scene, Prepared};
use crate::report::{make_report, peak_memory_bytes, MemoryReport, Timings};
use crate::scene::Scene;
use crate::tiling::{JobOutput, TileWriter};
use crate::update::{UpdateReport, Verdict};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

pub const PLAN_FILE: &str = "plan.json";
pub const JOBS_DIR: &str = "jobs";
/// An update's build folder, in the live tileset's folder (a dot-folder: never served).
pub const UPDATE_DIR: &str = ".bimtiles/shard";
/// The new tileset's folder in an update's build folder.
const UPDATE_TILESET: &str = "tileset";
const PLAN_FORMAT: &str = "bimtiles-plan/1";
/// What an update may replace: a tileset, or a folder holding only an update's build.
const TILESET_OR_UPDATE: &[&str] = &["tileset.json", ".bimtiles/shard/plan.json"];
const TILESET_OR_UPDATE_WHAT: &str = "a tileset";

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
    /// With `--update`: what the update found (absent for a plain build).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub update: Option<PlanUpdate>,
}

/// What a sharded update's `plan` found.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct PlanUpdate {
    /// The inputs, options and tool are those of the tileset: no job runs, `merge` only
    /// rewrites report.json.
    pub up_to_date: bool,
    /// Why the tileset is built again (one line).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub full_build_reason: Option<String>,
    #[serde(default)]
    pub changed_inputs: Vec<String>,
    /// Why no tile can be taken from the tile cache (then every job runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tile_cache_note: Option<String>,
}

fn yes() -> bool {
    true
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct PlanJob {
    pub job: usize,
    /// Subtree roots, by tile path.
    pub roots: Vec<String>,
    pub tiles: usize,
    pub triangles: usize,
    /// Whether the job has work: always for a plain build; in an update, only when some HLOD
    /// tile of its subtrees is not in the tile cache (an unchanged job needs no run and no
    /// result file: `merge` takes its tiles).
    #[serde(default = "yes")]
    pub changed: bool,
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

/// The plan file of `plan` split for `jobs` jobs (every job changed).
fn plan_file(p: &TilePlan, opts: &Settings, jobs: usize, command: serde_json::Value) -> PlanFile {
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
    PlanFile {
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
                changed: true,
            })
            .collect(),
        update: None,
    }
}

/// `bimtiles plan`: writes `opts.out_dir/plan.json` for `jobs` jobs. The folder must not exist,
/// unless `opts.force` (then it must hold a plan or a tileset, and is emptied). With
/// `opts.update`, plans an update of the tileset there instead ([`plan_update`]).
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
    if opts.update {
        return plan_update(inputs, opts, jobs, command);
    }
    // Inputs and options are checked before anything is replaced: the old folder goes only
    // when the new plan is complete (`StagingDir::commit`).
    const PLAN_OR_TILESET: &[&str] = &[PLAN_FILE, "tileset.json"];
    const WHAT: &str = "a plan or a tileset";
    check_replaceable(dir, opts.force, PLAN_OR_TILESET, WHAT)?;
    let mut scene = read_scene(inputs, opts)?;
    let prep = prepare(&mut scene, opts)?;
    let file = plan_file(&prep.plan, opts, jobs, command);
    let staging = StagingDir::beside_for(dir, opts.force, PLAN_OR_TILESET, WHAT)?;
    let jobs_dir = staging.path().join(JOBS_DIR);
    std::fs::create_dir_all(&jobs_dir)
        .map_err(|e| Error::output_from(dir.join(JOBS_DIR), "cannot create the folder", e))?;
    let json = serde_json::to_vec_pretty(&file)
        .map_err(|e| Error::output_from(dir, "cannot serialize plan.json", e))?;
    staging.commit(&[(PLAN_FILE, &json)])?;
    Ok(file)
}

/// A sharded update's plan (see the module doc): checks the tileset in `opts.out_dir` as
/// `convert --update` does and writes the build folder `DIR/.bimtiles/shard/`, replacing an
/// earlier one; the live tileset is not touched.
fn plan_update(
    inputs: &InputSet,
    opts: &Settings,
    jobs: usize,
    command: serde_json::Value,
) -> Result<PlanFile> {
    let out = &opts.out_dir;
    // Held to the end: one run per output at a time; only a tileset (or an update's build) is
    // updated.
    let _lock = StagingDir::beside_for(out, true, TILESET_OR_UPDATE, TILESET_OR_UPDATE_WHAT)?;
    let live = out.join("tileset.json").is_file();
    let verdict = match live {
        true => crate::update::check(out, &given_paths(inputs), opts),
        false => Verdict::Rebuild {
            reason: "no tileset at the output yet".into(),
            changed: Vec::new(),
            hashed: Vec::new(),
        },
    };
    let build = out.join(UPDATE_DIR);
    // Build folders of plans killed before theirs was put in place (the output's lock is ours).
    if let Ok(entries) = std::fs::read_dir(out.join(crate::update::STATE_DIR)) {
        for e in entries.flatten() {
            if e.file_name().to_string_lossy().starts_with("shard.tmp-") {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
    }
    let tmp = out.join(format!("{UPDATE_DIR}.tmp-{}", std::process::id()));
    let tiles = tmp.join(UPDATE_TILESET);
    std::fs::create_dir_all(tmp.join(JOBS_DIR))
        .map_err(|e| Error::output_from(&tmp, "cannot create the folder", e))?;
    let made = (|| {
        let file = match verdict {
            Verdict::Unchanged { .. } => PlanFile {
                format: PLAN_FORMAT.into(),
                command,
                plan_digest: String::new(),
                tiles: 0,
                top: Vec::new(),
                jobs: (0..jobs.max(1))
                    .map(|job| PlanJob {
                        job,
                        roots: Vec::new(),
                        tiles: 0,
                        triangles: 0,
                        changed: false,
                    })
                    .collect(),
                update: Some(PlanUpdate {
                    up_to_date: true,
                    ..PlanUpdate::default()
                }),
            },
            Verdict::Rebuild {
                reason, changed, ..
            } => {
                let mut file = plan_changed_jobs(inputs, opts, jobs, command, &tiles)?;
                if let Some(u) = &mut file.update {
                    u.full_build_reason = Some(reason);
                    u.changed_inputs = changed;
                }
                file
            }
        };
        let json = serde_json::to_vec_pretty(&file)
            .map_err(|e| Error::output_from(&build, "cannot serialize plan.json", e))?;
        write_renamed(&tmp.join(PLAN_FILE), &json)?;
        Ok(file)
    })();
    let placed = made.and_then(|file| {
        if build.exists() {
            std::fs::remove_dir_all(&build)
                .map_err(|e| Error::output_from(&build, "cannot remove the earlier build", e))?;
        }
        std::fs::rename(&tmp, &build)
            .map_err(|e| Error::output_from(&build, "cannot put the build folder in place", e))?;
        Ok(file)
    });
    if placed.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    placed
}

/// The plan of an update that builds: the inputs read and planned, every leaf built into
/// `tiles` and every tile keyed in the live tileset's tile cache; a job is changed unless every
/// HLOD tile of its subtrees would be taken from the cache.
fn plan_changed_jobs(
    inputs: &InputSet,
    opts: &Settings,
    jobs: usize,
    command: serde_json::Value,
    tiles: &Path,
) -> Result<PlanFile> {
    let mut scene = read_scene(inputs, opts)?;
    let prep = prepare(&mut scene, opts)?;
    let plan = &prep.plan;
    let mut file = plan_file(plan, opts, jobs, command);
    let uses = &prep.textures_prepared.uses;
    let textures = crate::texture::TextureLevels::new(&scene, &opts.texture, uses).shared_in(tiles);
    let writer = TileWriter::new(&scene, &prep, opts, tiles, &textures, 0)?;
    let cache = writer
        .cache_digest(&prep.origin, prep.anchor)
        .map(|g| SubtreeCache::open(&opts.out_dir, tiles, g, writer.appearance()));
    let live = opts.out_dir.join("tileset.json").is_file();
    let note = match &cache {
        Some(c) => c.note.clone(),
        None => live.then(|| {
            "no tile is taken from the tile cache: the tiles use textures or no HLOD".to_string()
        }),
    };
    if let (Some(c), true) = (&cache, live) {
        let keys = writer.with_cache(c).tile_keys()?;
        let index: BTreeMap<&str, usize> = plan
            .tiles
            .iter()
            .enumerate()
            .map(|(i, t)| (t.path.as_str(), i))
            .collect();
        for job in &mut file.jobs {
            let roots = job.roots.iter().filter_map(|r| index.get(r.as_str()));
            job.changed = roots.into_iter().any(|&r| {
                subtree(plan, r).into_iter().any(|t| {
                    let tile = &plan.tiles[t];
                    !tile.children.is_empty() && !keys[t].is_some_and(|k| c.would_take(tile, &k))
                })
            });
        }
    }
    for job in &mut file.jobs {
        // A job without subtrees has nothing to do.
        job.changed &= !job.roots.is_empty();
    }
    file.update = Some(PlanUpdate {
        tile_cache_note: note,
        ..PlanUpdate::default()
    });
    Ok(file)
}

/// The tiles of the subtree of `root`.
fn subtree(plan: &TilePlan, root: usize) -> Vec<usize> {
    let mut out = Vec::new();
    let mut stack = vec![root];
    while let Some(j) = stack.pop() {
        out.push(j);
        stack.extend(&plan.tiles[j].children);
    }
    out
}

/// Where the plan and the jobs' results of the build in `dir` are: `dir`, or an update's build
/// folder in it.
fn build_dir(dir: &Path) -> PathBuf {
    let update = dir.join(UPDATE_DIR);
    match update.join(PLAN_FILE).is_file() {
        true => update,
        false => dir.to_path_buf(),
    }
}

/// Where the build in `dir` writes its tiles: `dir`, or an update's new tileset.
fn tiles_dir(dir: &Path, file: &PlanFile) -> PathBuf {
    match file.update {
        Some(_) => dir.join(UPDATE_DIR).join(UPDATE_TILESET),
        None => dir.to_path_buf(),
    }
}

/// Reads `dir/plan.json` (for the CLI, which re-creates the options from its `command`).
pub fn read_plan(dir: &Path) -> Result<PlanFile> {
    let path = build_dir(dir).join(PLAN_FILE);
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
            build_dir(dir).join(PLAN_FILE),
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
    build_dir(dir).join(JOBS_DIR).join(format!("job-{job}.bin"))
}

/// `bimtiles build-job`: builds job `job`'s subtrees into `dir` and writes its result file last.
/// A job an update's plan marks unchanged has nothing to do (`merge` takes its tiles).
pub fn build_job(
    dir: &Path,
    job: usize,
    inputs: &InputSet,
    opts: &ConvertOptions,
) -> Result<JobSummary> {
    let t0 = Instant::now();
    let opts = &opts.resolve();
    if read_plan(dir)?.jobs.get(job).is_some_and(|j| !j.changed) {
        return Ok(JobSummary {
            job,
            tiles: 0,
            seconds: t0.elapsed().as_secs_f64(),
        });
    }
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
    let tiles_dir = tiles_dir(dir, &l.file);
    let uses = &l.prep.textures_prepared.uses;
    let textures =
        crate::texture::TextureLevels::new(&l.scene, &opts.texture, uses).shared_in(&tiles_dir);
    let count = roots.iter().map(|&r| subtree_tiles(plan, r)).sum();
    let writer = TileWriter::new(&l.scene, &l.prep, opts, &tiles_dir, &textures, count)?;
    // An update takes the tiles of its subtrees that did not change from the live tile cache.
    let cache = match (
        &l.file.update,
        writer.cache_digest(&l.prep.origin, l.prep.anchor),
    ) {
        (Some(_), Some(g)) => Some(SubtreeCache::open(dir, &tiles_dir, g, writer.appearance())),
        _ => None,
    };
    let writer = match &cache {
        Some(c) => writer.with_cache(c),
        None => writer,
    };
    let output = writer.build_subtrees(roots, &Default::default(), Default::default())?;
    writer.finish_progress();
    let tiles = output.tiles.len();
    let seconds = t0.elapsed().as_secs_f64();
    let bytes = wire::encode(&wire::JobFile {
        plan_digest: l.file.plan_digest.clone(),
        job,
        seconds,
        output,
        cache: cache.map(|c| c.export()),
    });
    let jobs_dir = build_dir(dir).join(JOBS_DIR);
    std::fs::create_dir_all(&jobs_dir).map_err(|e| Error::output(&jobs_dir, e))?;
    write_renamed(&result, &bytes)?;
    Ok(JobSummary {
        job,
        tiles,
        seconds,
    })
}

/// Jobs of the plan in `dir` that have work and no result file yet (what to run again).
pub fn missing_jobs(dir: &Path) -> Result<Vec<usize>> {
    let file = read_plan(dir)?;
    Ok(file
        .jobs
        .iter()
        .filter(|j| j.changed && !job_path(dir, j.job).is_file())
        .map(|j| j.job)
        .collect())
}

/// Leftover temporary files of killed processes (`.NAME.tmp-PID`) under the tiles and jobs of the
/// build in `dir`.
fn leftover_temp_files(dir: &Path, tiles: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let folders = [
        tiles.join("tiles"),
        tiles.join(crate::texture::external::TEXTURE_DIR),
        build_dir(dir).join(JOBS_DIR),
    ];
    for folder in folders {
        if let Ok(rd) = std::fs::read_dir(folder) {
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

/// The results of the jobs that ran.
#[derive(Default)]
struct JobResults {
    outputs: Vec<JobOutput>,
    /// An update's jobs' parts of the tile cache, with their result files.
    caches: Vec<(PathBuf, Vec<u8>)>,
    seconds: f64,
}

/// The results of the jobs that ran, checked against the plan and the tiles they wrote.
fn job_results(dir: &Path, l: &Loaded, tiles: &Path) -> Result<JobResults> {
    let mut results = JobResults::default();
    for k in l.file.jobs.iter().filter(|j| j.changed).map(|j| j.job) {
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
                let tile = tiles.join(uri);
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
        results.seconds += f.seconds;
        results.outputs.push(f.output);
        results.caches.extend(f.cache.map(|c| (path, c)));
    }
    Ok(results)
}

/// `bimtiles merge`: checks every job's result, builds the top levels and writes schema.json,
/// tileset.json and report.json into `dir`. An update (see the module doc) also takes the
/// unchanged jobs' tiles, and puts the new tileset in place of the live one; or, when `plan`
/// found nothing to build and that still holds, only rewrites report.json.
pub fn merge(dir: &Path, inputs: &InputSet, opts: &ConvertOptions) -> Result<Updated> {
    let t0 = Instant::now();
    let opts = &opts.resolve();
    let file = read_plan(dir)?;
    // An update holds the output's lock to the end (one run per output at a time).
    let staging = match &file.update {
        Some(_) => Some(StagingDir::beside_for(
            dir,
            true,
            TILESET_OR_UPDATE,
            TILESET_OR_UPDATE_WHAT,
        )?),
        None => None,
    };
    if file.update.as_ref().is_some_and(|u| u.up_to_date) {
        let staging = staging.expect("an update holds the output's lock");
        return merge_up_to_date(dir, inputs, opts, staging, t0);
    }
    let missing = missing_jobs(dir)?;
    if !missing.is_empty() {
        let list: Vec<String> = missing.iter().map(|k| k.to_string()).collect();
        return Err(Error::input(
            dir,
            format!(
                "{} of {} jobs have no result yet (jobs {}): run `bimtiles build-job {} --job K` for them",
                missing.len(),
                file.jobs.iter().filter(|j| j.changed).count(),
                list.join(", "),
                dir.display()
            ),
        ));
    }
    let l = load(dir, inputs, opts)?;
    let tiles = tiles_dir(dir, &l.file);
    let JobResults {
        outputs,
        caches,
        seconds: job_seconds,
    } = job_results(dir, &l, &tiles)?;
    for leftover in leftover_temp_files(dir, &tiles) {
        std::fs::remove_file(&leftover).map_err(|e| Error::output(&leftover, e))?;
    }
    // The jobs' subtrees; an update's unchanged jobs' subtrees are merge's.
    let built_roots: Vec<usize> = l
        .file
        .jobs
        .iter()
        .zip(&l.roots)
        .filter(|(j, _)| j.changed)
        .flat_map(|(_, r)| r.iter().copied())
        .collect();
    let uses = &l.prep.textures_prepared.uses;
    let textures =
        crate::texture::TextureLevels::new(&l.scene, &opts.texture, uses).shared_in(&tiles);
    let t = Instant::now();
    let writer = TileWriter::new(&l.scene, &l.prep, opts, &tiles, &textures, l.file.top.len())?;
    let cache = match (
        &l.file.update,
        writer.cache_digest(&l.prep.origin, l.prep.anchor),
    ) {
        (Some(_), Some(g)) => Some(SubtreeCache::open(dir, &tiles, g, writer.appearance())),
        _ => None,
    };
    if let Some(c) = &cache {
        for (path, bytes) in &caches {
            c.absorb(bytes).map_err(|e| {
                Error::input(path, format!("{e} (run build-job for this job again)"))
            })?;
        }
    }
    let writer = match &cache {
        Some(c) => writer.with_cache(c),
        None => writer,
    };
    let records = writer.merge(outputs, &built_roots, l.prep.origin, l.prep.anchor)?;
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
    let first_view_edges = crate::inspect::first_view::edge_gzip_bytes(&records, &tiles);
    let sources = l.scene.sources.iter().map(|s| s.path.clone()).collect();
    let mut report = make_report(l.prep, records, opts, &tiles, timings, textures);
    report.output.first_view_edge_gzip_bytes = first_view_edges;
    report.peak_memory_bytes = peak_memory_bytes();
    report.memory = memory;
    if let Some(u) = &l.file.update {
        let tracked = Tracked::new(
            given_paths(inputs),
            match inputs {
                InputSet::Sample => Vec::new(),
                _ => sources,
            },
            Vec::new(),
            UpdateReport {
                mode: "rebuilt",
                full_build_reason: u.full_build_reason.clone(),
                changed_inputs: u.changed_inputs.clone(),
                ..UpdateReport::default()
            },
        );
        report.update = Some(tracked.finish(&tiles, opts, cache.as_ref(), t0)?);
    }
    report.timings_s.total = t0.elapsed().as_secs_f64() + job_seconds;
    let json = serde_json::to_vec_pretty(&report).map_err(|e| Error::output(dir, e))?;
    match staging {
        Some(staging) => publish(staging, &tiles, &json)?,
        None => write_renamed(&dir.join("report.json"), &json)?,
    }
    Ok(Updated::Built(Box::new(report)))
}

/// Puts an update's new tileset `tiles` (complete but report.json) in place of the live one:
/// moved into the staging folder beside the output, then exchanged with the output in one step.
/// The old tileset, with the update's build folder in it, is then removed.
fn publish(staging: StagingDir, tiles: &Path, report_json: &[u8]) -> Result<()> {
    let at = staging.path().to_path_buf();
    std::fs::remove_dir(&at)
        .and_then(|()| std::fs::rename(tiles, &at))
        .map_err(|e| Error::output_from(staging.target(), "cannot move the new tileset", e))?;
    staging.commit(&[("report.json", report_json)])
}

/// An update's merge when `plan` found nothing to build: checked again (the inputs may have
/// changed since), report.json rewritten, the build folder removed.
fn merge_up_to_date(
    dir: &Path,
    inputs: &InputSet,
    opts: &Settings,
    staging: StagingDir,
    t0: Instant,
) -> Result<Updated> {
    let (state, hashed) = match crate::update::check(dir, &given_paths(inputs), opts) {
        Verdict::Unchanged { state, hashed } => (state, hashed),
        Verdict::Rebuild { reason, .. } => {
            return Err(Error::input(
                build_dir(dir).join(PLAN_FILE),
                format!("{reason} since the plan (run `bimtiles plan --update` again)"),
            ))
        }
    };
    let u = up_to_date(staging, opts, &state, &hashed, t0)?;
    let build = dir.join(UPDATE_DIR);
    std::fs::remove_dir_all(&build)
        .map_err(|e| Error::output_from(&build, "cannot remove the build folder", e))?;
    Ok(Updated::UpToDate(Box::new(u)))
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
