//! The end-to-end conversion: ingest → place → dedup → partition → (HLOD) → encode → tileset →
//! report.
//!
//! Output is built in a temporary folder beside the target and renamed into place at the end, so an
//! interrupted or failed run never leaves a tileset that looks complete. Tiles are encoded in
//! parallel, each written and freed at once; file names and contents depend only on the input and
//! the options, never on the thread count.

use crate::encode::{encode_tile, Compression, TileEncoding};
use crate::error::{Error, Result};
use crate::ingest::InputSet;
use crate::output_dir::StagingDir;
use crate::prepare::{prepare, read_scene};
use crate::scene::Scene;
use crate::simplify::model::{simplify_scene, SimplifiedModel};
use crate::tiling::TileWriter;
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

/// Reads an input set (sample, model files or a manifest of many models) and converts it.
pub fn convert_input_set(inputs: &InputSet, opts: &ConvertOptions) -> Result<Report> {
    let t0 = Instant::now();
    let opts = &opts.resolve();
    // The output is locked and checked before the input is read: a second run to the same
    // output, or a folder that may not be replaced, fails at once.
    let staging = StagingDir::beside(&opts.out_dir, opts.force)?;
    let mut scene = read_scene(inputs, opts)?;
    let t_ingest = t0.elapsed().as_secs_f64();
    build_into(staging, &mut scene, opts, t0, t_ingest)
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
    build_into(staging, scene, opts, t0, t_ingest)
}

/// Prepares `scene` and builds its tileset in `staging`, which is then put in place.
fn build_into(
    staging: StagingDir,
    scene: &mut Scene,
    opts: &Settings,
    t0: Instant,
    t_ingest: f64,
) -> Result<Report> {
    let prep = prepare(scene, opts)?;
    let plan = &prep.plan;
    let tmp = staging.path().to_path_buf();
    let uses = &prep.textures_prepared.uses;
    let texture_levels =
        crate::texture::TextureLevels::new(scene, &opts.texture, uses).shared_in(&tmp);
    // The HLOD figures from here on are this conversion's.
    crate::lod::clock::take();
    let result = (|| {
        let t = Instant::now();
        let writer = TileWriter::new(scene, &prep, opts, &tmp, &texture_levels, plan.tiles.len())?;
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
    let mut report = make_report(prep, records, opts, &tmp, timings, texture_levels);
    report.timings_s.total = t0.elapsed().as_secs_f64();
    let hlod_timings = crate::lod::clock::take();
    report.hlod_timings_s = (opts.lod == crate::options::LodMode::Hlod).then_some(hlod_timings);
    report.peak_memory_bytes = peak_memory_bytes();
    report.memory = MemoryReport::of(scene);
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
