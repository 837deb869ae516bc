//! The end-to-end conversion: ingest → place → dedup → partition → (HLOD) → encode → tileset →
//! report.
//!
//! With `--update` (`crate::update`), an output whose inputs, options and tool did not change is
//! left as it is, and a new build is published over the old tileset, its unchanged files kept.
//!
//! Output is built in a temporary folder beside the target and renamed into place at the end, so an
//! interrupted or failed run never leaves a tileset that looks complete. Tiles are encoded in
//! parallel, each written and freed at once; file names and contents depend only on the input and
//! the options, never on the thread count.

use crate::encode::{encode_tile, Compression, TileEncoding};
use crate::error::{Error, Result};
use crate::ingest::InputSet;
use crate::lod::subtree_cache::{CacheTally, SubtreeCache};
use crate::output_dir::StagingDir;
use crate::prepare::{prepare, read_scene};
use crate::scene::Scene;
use crate::simplify::model::{simplify_scene, SimplifiedModel};
use crate::tiling::TileWriter;
use crate::update::{self, InputHash, UpdateReport, UpdateState, Verdict};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

pub use crate::options::*;
pub use crate::report::*;

/// Reads `inputs` (none: the embedded sample building), converts them and writes the tileset to
/// `opts.out_dir`.
pub fn convert(inputs: &[PathBuf], opts: &ConvertOptions) -> Result<Report> {
    convert_input_set(&InputSet::new(inputs, None), opts)
}

/// Reads an input set (sample, model files or a manifest of many models) and converts it. With
/// `opts.update`, use [`update_input_set`], which may find nothing to build.
pub fn convert_input_set(inputs: &InputSet, opts: &ConvertOptions) -> Result<Report> {
    match update_input_set(inputs, opts)? {
        Updated::Built(report) => Ok(*report),
        Updated::UpToDate(_) => Err(Error::output(
            &opts.out_dir,
            "the tileset is up to date: nothing was built (report.json says so)",
        )),
    }
}

/// What a run with `--update` did.
#[derive(Debug)]
pub enum Updated {
    /// The inputs, options and tool are those of the tileset: no model read, only report.json
    /// rewritten.
    UpToDate(Box<UpdateReport>),
    /// A tileset was built (a full build; with `--update`, published over the old one).
    Built(Box<Report>),
}

/// The inputs as given, as the update state records them.
pub(crate) fn given_paths(inputs: &InputSet) -> Vec<PathBuf> {
    match inputs {
        InputSet::Sample => Vec::new(),
        InputSet::Files(f) => f.clone(),
        InputSet::Manifest(m) => vec![m.clone()],
    }
}

/// Converts an input set, or with `opts.update` brings the tileset at the output up to date
/// (`crate::update`): nothing to build when the inputs, options and tool are those of the
/// tileset, else a full build published over it, its unchanged files kept as they are.
pub fn update_input_set(inputs: &InputSet, opts: &ConvertOptions) -> Result<Updated> {
    let t0 = Instant::now();
    let opts = &opts.resolve();
    let given = given_paths(inputs);
    // An update replaces a tileset (never another folder: the lock's check still applies).
    let live = opts.update && opts.out_dir.join("tileset.json").is_file();
    // The output is locked and checked before the input is read: a second run to the same
    // output, or a folder that may not be replaced, fails at once.
    let staging = StagingDir::beside(&opts.out_dir, opts.force || live)?;
    let mut update = UpdateReport::default();
    let mut hashed = Vec::new();
    if opts.update {
        let verdict = match live {
            true => update::check(&opts.out_dir, &given, opts),
            false => Verdict::Rebuild {
                reason: "no tileset at the output yet".into(),
                changed: Vec::new(),
                hashed: Vec::new(),
            },
        };
        match verdict {
            Verdict::Unchanged { state, hashed } => {
                return up_to_date(staging, opts, &state, &hashed, t0)
                    .map(|u| Updated::UpToDate(Box::new(u)))
            }
            Verdict::Rebuild {
                reason,
                changed,
                hashed: h,
            } => {
                update = UpdateReport {
                    mode: "rebuilt",
                    full_build_reason: Some(reason),
                    changed_inputs: changed,
                    inputs_hashed: h.len(),
                    input_bytes_hashed: h.iter().map(|i| i.bytes).sum(),
                    ..UpdateReport::default()
                };
                hashed = h;
            }
        }
    }
    let mut scene = read_scene(inputs, opts)?;
    let t_ingest = t0.elapsed().as_secs_f64();
    // Only an update leaves the state for the next one: a plain build's output stays the
    // tileset and its report. The bundled sample is part of the binary: its version covers it.
    let tracked = opts.update.then(|| Tracked {
        sources: match inputs {
            InputSet::Sample => Vec::new(),
            _ => scene.sources.iter().map(|s| s.path.clone()).collect(),
        },
        given,
        hashed,
        update,
    });
    let report = build_into(staging, &mut scene, opts, t0, t_ingest, tracked)?;
    Ok(Updated::Built(Box::new(report)))
}

/// An update with nothing to build: report.json (the last build's) gets the update's figures.
pub(crate) fn up_to_date(
    staging: StagingDir,
    opts: &Settings,
    state: &UpdateState,
    hashed: &[InputHash],
    t0: Instant,
) -> Result<UpdateReport> {
    let out = &opts.out_dir;
    let report_path = out.join("report.json");
    let mut report: serde_json::Value = std::fs::read(&report_path)
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok())
        .ok_or_else(|| Error::output(&report_path, "cannot read the last build's report"))?;
    let stale = update::settle_stale_files(out, &state.files, opts.keep_stale)?;
    let update = UpdateReport {
        mode: "unchanged",
        files_removed: stale.removed,
        bytes_removed: stale.removed_bytes,
        files_kept_stale: stale.kept,
        inputs_hashed: hashed.len(),
        input_bytes_hashed: hashed.iter().map(|i| i.bytes).sum(),
        files_reused: state.files.len(),
        bytes_reused: state.files.iter().map(|f| f.bytes).sum(),
        state_bytes: std::fs::metadata(out.join(update::STATE_FILE)).map_or(0, |m| m.len()),
        seconds: t0.elapsed().as_secs_f64(),
        ..UpdateReport::default()
    };
    report["update"] = serde_json::to_value(&update)
        .map_err(|e| Error::output_from(&report_path, "cannot serialize", e))?;
    let bytes = serde_json::to_vec_pretty(&report)
        .map_err(|e| Error::output_from(&report_path, "cannot serialize", e))?;
    crate::output_dir::write_renamed(&report_path, &bytes)?;
    // Dropped unused: its empty folder goes, the lock is released.
    drop(staging);
    Ok(update)
}

/// What an update's build records for the next one.
pub(crate) struct Tracked {
    given: Vec<PathBuf>,
    /// The models read.
    sources: Vec<PathBuf>,
    /// Inputs the update's check hashed already.
    hashed: Vec<InputHash>,
    /// The update's report, to be completed.
    update: UpdateReport,
}

impl Tracked {
    /// What an update that hashed `hashed` (none: all are hashed at the end) and reports
    /// `update` records, for the inputs `given` whose models are `sources`.
    pub(crate) fn new(
        given: Vec<PathBuf>,
        sources: Vec<PathBuf>,
        hashed: Vec<InputHash>,
        update: UpdateReport,
    ) -> Tracked {
        Tracked {
            given,
            sources,
            hashed,
            update,
        }
    }

    /// Completes an update's build in the build folder `dir`: writes the tile cache (if any) and
    /// the update state, links the unchanged files in (see [`Tracked::record`]); returns the
    /// update's report.
    pub(crate) fn finish(
        mut self,
        dir: &Path,
        opts: &Settings,
        cache: Option<&SubtreeCache>,
        t0: Instant,
    ) -> Result<UpdateReport> {
        let (cache_bytes, tally, note) = match cache {
            Some(c) => (c.write_into(dir)?, c.tally(), c.note.clone()),
            None => (0, CacheTally::default(), None),
        };
        self.update = UpdateReport {
            tiles_built: tally.tiles_built,
            tile_bytes_built: tally.tile_bytes_built,
            internal_tiles: tally.internal_tiles,
            internal_tiles_built: tally.internal_tiles_built,
            tiles_reused: tally.tiles_reused,
            tile_bytes_reused: tally.tile_bytes_reused,
            tiles_rewritten: tally.tiles_rewritten,
            tiles_remade: tally.tiles_remade,
            leaves_reused: tally.leaves_reused,
            leaf_bytes_reused: tally.leaf_bytes_reused,
            tile_cache_bytes: cache_bytes,
            tile_cache_note: match cache {
                Some(_) => note,
                // Said only when there was a tileset to take tiles from.
                None => opts.out_dir.join("tileset.json").is_file().then(|| {
                    "no tile is taken from the tile cache: the tiles use textures or no HLOD".into()
                }),
            },
            ..self.update
        };
        self.record(dir, opts, t0)
    }
    /// Writes the update state into the build folder `dir` and prepares the folder to replace the
    /// live tileset (its unchanged files linked in); returns the update's report.
    fn record(mut self, dir: &Path, opts: &Settings, t0: Instant) -> Result<UpdateReport> {
        let inputs = match update::input_files(&self.given, &self.sources) {
            Some(files) => {
                let known: std::collections::BTreeMap<&Path, &InputHash> =
                    self.hashed.iter().map(|h| (h.path.as_path(), h)).collect();
                let unknown: Vec<PathBuf> = files
                    .iter()
                    .filter(|f| !known.contains_key(f.as_path()))
                    .cloned()
                    .collect();
                let mut all = update::hash_inputs(&unknown)?;
                // Counted with those the check hashed: a sharded update's merge hashes them all.
                self.update.inputs_hashed += all.len();
                self.update.input_bytes_hashed += all.iter().map(|h| h.bytes).sum::<u64>();
                all.extend(
                    files
                        .iter()
                        .filter_map(|f| known.get(f.as_path()).map(|h| (*h).clone())),
                );
                all.sort_by(|a, b| a.path.cmp(&b.path));
                Some(all)
            }
            None => None,
        };
        let state = update::state_of(dir, opts, &self.given, inputs)?;
        update::reuse_unchanged_files(dir, &opts.out_dir, opts.keep_stale, &mut self.update)?;
        let state_bytes = state.write_into(dir)?;
        Ok(UpdateReport {
            state_bytes,
            seconds: t0.elapsed().as_secs_f64(),
            ..self.update
        })
    }
}

/// Converts an already-read scene (used by `convert` and by tests that build scenes in memory).
/// The tiles are built as one subtree job over the whole tree, then merged: the code path of the
/// sharded build (`crate::shard`) with a single job.
pub fn convert_scene(
    scene: &mut Scene,
    opts: &ConvertOptions,
    t0: Instant,
    t_ingest: f64,
) -> Result<Report> {
    let opts = &opts.resolve();
    let staging = StagingDir::beside(&opts.out_dir, opts.force)?;
    build_into(staging, scene, opts, t0, t_ingest, None)
}

/// Prepares `scene` and builds its tileset in `staging`, which is then put in place.
fn build_into(
    staging: StagingDir,
    scene: &mut Scene,
    opts: &Settings,
    t0: Instant,
    t_ingest: f64,
    tracked: Option<Tracked>,
) -> Result<Report> {
    let prep = prepare(scene, opts)?;
    let plan = &prep.plan;
    let tmp = staging.path().to_path_buf();
    let uses = &prep.textures_prepared.uses;
    let texture_levels =
        crate::texture::TextureLevels::new(scene, &opts.texture, uses).shared_in(&tmp);
    // The HLOD figures from here on are this conversion's.
    crate::lod::clock::take();
    let mut cache = None;
    let result = (|| {
        let t = Instant::now();
        let writer = TileWriter::new(scene, &prep, opts, &tmp, &texture_levels, plan.tiles.len())?;
        // An update takes the HLOD tiles whose subtree did not change from the tile cache.
        let digest = writer.cache_digest(&prep.origin, prep.anchor);
        let writer = match (&tracked, digest) {
            (Some(_), Some(global)) => {
                let c = cache.insert(SubtreeCache::open(
                    &opts.out_dir,
                    &tmp,
                    global,
                    writer.appearance(),
                ));
                writer.with_cache(c)
            }
            _ => writer,
        };
        let job = writer.build_subtrees(&[0], &Default::default(), Default::default())?;
        writer.finish_progress();
        let t_encode = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let records = writer.merge(vec![job], &[0], prep.origin, prep.anchor)?;
        Ok((records, t_encode, t.elapsed().as_secs_f64()))
    })();
    // On an error the staging folder is removed when `staging` is dropped; the error names the
    // output, not the temporary folder.
    let (records, t_encode, t_tileset) =
        result.map_err(|e: Error| e.relocated(&tmp, &opts.out_dir))?;
    let timings = Timings {
        ingest: t_ingest,
        dedup: prep.t_dedup,
        partition: prep.t_partition,
        encode_write: t_encode,
        tileset: t_tileset,
        total: 0.0,
    };
    let first_view_edges = crate::inspect::first_view::edge_gzip_bytes(&records, &tmp);
    let mut report = make_report(prep, records, opts, &tmp, timings, texture_levels);
    report.output.first_view_edge_gzip_bytes = first_view_edges;
    report.timings_s.total = t0.elapsed().as_secs_f64();
    let hlod_timings = crate::lod::clock::take();
    report.hlod_timings_s = (opts.lod == crate::options::LodMode::Hlod).then_some(hlod_timings);
    report.peak_memory_bytes = peak_memory_bytes();
    report.memory = MemoryReport::of(scene);
    if let Some(t) = tracked {
        let update = t.finish(&tmp, opts, cache.as_ref(), t0);
        report.update = Some(update.map_err(|e| e.relocated(&tmp, &opts.out_dir))?);
    }
    let report_json = serde_json::to_vec_pretty(&report)
        .map_err(|e| Error::output_from(&tmp, "cannot serialize report.json", e))?;
    staging.commit(&[("report.json", &report_json)])?;
    Ok(report)
}

/// What `simplify_model` did.
#[derive(Debug, Clone, Serialize)]
pub struct SimplifyReport {
    pub input: String,
    pub output: String,
    pub triangles_in: usize,
    pub triangles_out: usize,
    /// The largest simplification error of any mesh (metres; measured Hausdorff distance with
    /// the simplifier's safety factor).
    pub error_m: f64,
    pub seconds: f64,
}

/// Simplifies a whole model with our QEM and writes the result as one GLB (the `bimtiles
/// simplify` command, for comparing simplifiers). All components are merged in the scene frame into
/// one mesh whose vertex groups are the materials, so one global queue takes the cheapest
/// collapses anywhere in the model and no collapse crosses a material boundary; the result is
/// written as one primitive per material.
pub fn simplify_model(
    input: &Path,
    output: &Path,
    opts: &crate::simplify::SimplifyOptions,
) -> Result<SimplifyReport> {
    let t0 = Instant::now();
    let scene = crate::ingest::read_input(input)?;
    let triangles_in = scene.triangle_count();
    let SimplifiedModel {
        scene: out,
        center,
        error_m,
    } = simplify_scene(&scene, opts).map_err(|e| Error::simplify(input, e))?;
    let items = [crate::partition::ContentItem {
        component: crate::scene::ComponentId(0),
        triangles: None,
    }];
    let enc = TileEncoding {
        compression: Compression::None,
        ..TileEncoding::default()
    };
    let tile =
        encode_tile(&out, &items, center, &enc, None).map_err(|e| Error::encode(output, e))?;
    let tmp = output.with_extension("glb.tmp");
    std::fs::write(&tmp, &tile.glb).map_err(|e| Error::output_from(&tmp, "cannot write", e))?;
    std::fs::rename(&tmp, output).map_err(|e| {
        Error::output_from(output, "cannot rename the written file to this name", e)
    })?;
    Ok(SimplifyReport {
        input: input.display().to_string(),
        output: output.display().to_string(),
        triangles_in,
        triangles_out: tile.figures.triangles,
        error_m,
        seconds: t0.elapsed().as_secs_f64(),
    })
}
