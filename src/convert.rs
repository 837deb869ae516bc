//! The end-to-end conversion: ingest → place → dedup → partition → (HLOD) → encode → tileset →
//! report.
//!
//! Output is built in a temporary folder beside the target and renamed into place at the end, so an
//! interrupted or failed run never leaves a tileset that looks complete. Tiles are encoded in
//! parallel, each written and freed at once; file names and contents depend only on the input and
//! the options, never on the thread count.

use crate::dedup::{deduplicate, DedupOptions, DedupReport};
use crate::encode::glb::encode_content_with_images;
use crate::encode::glb::DEFAULT_MAX_POSITION_ERROR_M;
use crate::encode::{encode_tile, Compression, TileEncoding};
use crate::error::{Error, Result};
use crate::ingest::InputSet;
use crate::partition::{plan_octree, ContentItem, OctreeOptions, TilePlan};
use crate::scene::{Aabb, ComponentId, Scene};
use crate::simplify::hlod::{simplify_children, ErrorReference, HlodContent};
use crate::simplify::lod_chain::{chain_levels, with_lod_chains};
use crate::tile_content::{AppearanceClasses, TileContent};
use crate::tileset::georef::GeoOrigin;
use crate::tileset::metadata::{MetadataSchema, TableScope};
use crate::tileset::view::{
    framed_error_m, paper_delta_mesh_px, paper_geometric_error_m, sse_px, switch_distance_m,
    ViewOptions, PAPER_MAX_DELTA_PX,
};
use crate::tileset::{tileset_json, Refine, TileFacts};
use glam::{DMat4, DVec3};
use rayon::prelude::*;
use serde::Serialize;
use serde_json::json;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Models whose bounding-box centre is farther than this from their own origin are taken to be in
/// projected (map) coordinates: they are re-anchored at their footprint centre.
pub const PROJECTED_COORDINATES_THRESHOLD_M: f64 = 10_000.0;

#[derive(Debug, Clone)]
pub struct ConvertOptions {
    pub out_dir: PathBuf,
    /// Replace an existing output folder (only one that holds a tileset, or an empty one).
    pub force: bool,
    /// Where the model's anchor goes on Earth; `None` = [`GeoOrigin::DEFAULT`].
    pub origin: Option<GeoOrigin>,
    pub octree: OctreeOptions,
    /// Geometry compression of the tiles.
    pub compression: Compression,
    /// Levels of detail: HLOD (default), none, or the paper's discrete chains.
    pub lod: LodMode,
    /// Which error the simplified tiles declare as geometricError (both are reported).
    pub error_metric: ErrorMetric,
    /// Options of the QEM simplifier for LOD content (targets are set per tile).
    pub simplify: crate::simplify::SimplifyOptions,
    /// HLOD tiles are made coarser (up to [`HLOD_COARSEN_TRIES`] smaller triangle targets, each
    /// measured) while their measured error stays under this fraction of their framed error
    /// ([`crate::tileset::view::framed_error_m`] of the tile's bounding sphere: the error at which
    /// a viewer that sees the whole tile draws it). 0: the tile budget and
    /// [`HLOD_CHILDREN_DIVISOR`] alone set how coarse they are. See [`DEFAULT_HLOD_ERROR_FRACTION`].
    pub hlod_error_fraction: f64,
    /// Which properties simplified (HLOD, LOD chain) tiles carry; full-detail tiles carry all.
    pub coarse_tile_properties: CoarseTileProperties,
    /// Redundant and repeated components (paper III.A); `None` leaves the scene as read.
    pub dedup: Option<DedupOptions>,
    /// Write a shape drawn several times in a tile once, placed per instance
    /// (`EXT_mesh_gpu_instancing`); off, every copy is written as plain geometry.
    pub instancing: bool,
    /// Instance a shape in a tile only when that stores at least this many fewer triangles;
    /// `None`: [`default_min_instanced_triangles_saved`] of the compression.
    pub min_instanced_triangles_saved: Option<usize>,
    /// Write a tile's plain-coloured materials that differ only in base colour as one primitive,
    /// the colours in `COLOR_0` ([`AppearanceClasses`]); off, one primitive per material;
    /// `None`: [`default_merge_plain_materials`] of the compression.
    pub merge_plain_materials: Option<bool>,
    /// Show progress bars on stderr.
    pub progress: bool,
    /// Texture elimination, pyramids and level matching (paper III.D–III.F).
    pub texture: crate::texture::TextureOptions,
}

impl ConvertOptions {
    pub fn new(out_dir: impl Into<PathBuf>) -> Self {
        ConvertOptions {
            out_dir: out_dir.into(),
            force: false,
            origin: None,
            octree: OctreeOptions::default(),
            compression: Compression::default(),
            lod: LodMode::default(),
            error_metric: ErrorMetric::default(),
            simplify: crate::simplify::SimplifyOptions::default(),
            hlod_error_fraction: DEFAULT_HLOD_ERROR_FRACTION,
            coarse_tile_properties: CoarseTileProperties::default(),
            dedup: Some(DedupOptions::default()),
            instancing: true,
            min_instanced_triangles_saved: None,
            merge_plain_materials: None,
            progress: false,
            texture: Default::default(),
        }
    }
}

/// Default of [`ConvertOptions::min_instanced_triangles_saved`], chosen by measurement on the
/// sample and the shared models (README, dedup section). Draco already compresses a repeated
/// shape to a few bytes per triangle, so an instanced shape's own node, mesh, accessors and
/// instance attributes (about 1 KB) only pay off for larger savings; plain geometry costs tens of
/// bytes per triangle.
pub fn default_min_instanced_triangles_saved(compression: Compression) -> usize {
    match compression {
        Compression::Draco => 1000,
        Compression::None | Compression::Quantized => 100,
    }
}

/// Default of [`ConvertOptions::merge_plain_materials`], by measurement (README): with Draco,
/// merging cuts primitives 2.6–5x and bytes 7–12% on the shared BIM models (one Draco stream per
/// class instead of per material, 8-bit colours); plain float `COLOR_0` costs 16 bytes a vertex,
/// +20–26% bytes, so without compression materials stay apart.
pub fn default_merge_plain_materials(compression: Compression) -> bool {
    compression == Compression::Draco
}

/// Which properties the tables of simplified tiles carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CoarseTileProperties {
    /// What names an element (id, name, class, storey, building, site, material, source,
    /// aliases): picking a coarse tile names the element; its property sets and hierarchy path
    /// come with full detail ([`TableScope::Identity`]).
    #[default]
    Identity,
    /// Every property in every tile.
    All,
}

/// How levels of detail are made.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum LodMode {
    /// Hierarchical LOD (paper III.C(3)): every internal tile carries its subtree's content merged
    /// and simplified to the tile budget; `refine: "REPLACE"`; leaves hold full detail.
    #[default]
    Hlod,
    /// No simplified content: internal tiles hold the components too large for their children and
    /// refine by adding (`refine: "ADD"`), with a size-bound geometric error.
    None,
    /// The paper's discrete LODs (III.C, Table IV): every leaf becomes a chain of tiles with its
    /// bounds, coarsest first, simplified to these ratios of its triangles (finest first, as
    /// [`crate::simplify::lod_chain::chain_ratios`] gives them), full detail last;
    /// `refine: "REPLACE"`; internal tiles are empty, with a size-bound error.
    Ratios(Vec<f32>),
}

impl LodMode {
    pub fn name(&self) -> &'static str {
        match self {
            LodMode::Hlod => "hlod",
            LodMode::None => "none",
            LodMode::Ratios(_) => "ratios",
        }
    }
}

/// Which error simplified tiles declare as `geometricError`. The report shows both per level
/// (`lod_levels`, as the paper's Table I).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ErrorMetric {
    /// The measured distance between a tile's content and the full detail it stands for (honest:
    /// checked by an independent measurement in the tests).
    #[default]
    Measured,
    /// The paper's screen-space error (III.C(3), formulas (1), (2)): the geometricError that makes
    /// a client switch where Δ(mesh) of the longest collapsed edge reaches
    /// [`PAPER_MAX_DELTA_PX`] at 1920x1080 and 60° ([`paper_geometric_error_m`]). Not a distance
    /// bound: it can be smaller than the real deviation (not honest in general).
    PaperSse,
}

impl ErrorMetric {
    pub fn name(&self) -> &'static str {
        match self {
            ErrorMetric::Measured => "measured",
            ErrorMetric::PaperSse => "paper-sse",
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct InputReport {
    pub files: Vec<String>,
    pub bytes: u64,
    /// Elements a reader could not use (e.g. IFC elements that failed to triangulate).
    pub skipped_elements: usize,
    pub triangles: usize,
    pub vertices: usize,
    pub components: usize,
    pub meshes: usize,
    pub materials: usize,
    pub images: usize,
    pub skipped_primitives: usize,
    /// Elements whose id was numbered or prefixed because it repeated (README, "Element ids").
    pub renamed_ids: usize,
}

#[derive(Debug, Clone, Serialize)]
pub struct OutputReport {
    pub bytes: u64,
    pub tiles: usize,
    pub tiles_with_content: usize,
    pub max_depth: u32,
    /// Triangles and vertices drawn (an instanced shape once per instance).
    pub triangles: usize,
    pub vertices: usize,
    /// Triangles stored in the tiles (an instanced shape once per tile).
    pub stored_triangles: usize,
    /// Instanced shapes (counted per tile) and the components drawn through them.
    pub instanced_shapes: usize,
    pub instances: usize,
    /// Bytes of the property tables (EXT_structural_metadata) over all tiles.
    pub metadata_bytes: u64,
}

/// One tile, for scripts that want more than the per-level summary.
#[derive(Debug, Clone, Serialize)]
pub struct TileReport {
    pub path: String,
    pub depth: u32,
    pub content: Option<String>,
    pub features: usize,
    pub triangles: usize,
    pub stored_triangles: usize,
    pub instances: usize,
    pub bytes: u64,
    pub metadata_bytes: u64,
    pub geometric_error_m: f64,
    /// HLOD tiles: the triangles their content was simplified from (their children's content).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub simplified_from_triangles: Option<usize>,
    /// HLOD tiles: largest distance measured from full detail to this tile's content (metres).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub full_to_coarse_m: Option<f64>,
    /// HLOD tiles: bound of the distance from this tile's content to full detail (metres).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub coarse_to_full_bound_m: Option<f64>,
    /// Simplified tiles: the measured error (the geometricError under `--error-metric measured`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measured_error_m: Option<f64>,
    /// Simplified tiles: longest edge collapsed between full detail and this content (metres).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_folding_edge_m: Option<f64>,
    /// Simplified tiles: the paper's error of that edge (the geometricError under
    /// `--error-metric paper-sse`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub paper_error_m: Option<f64>,
    /// Simplified tiles: the largest per-axis position error quantization may add (metres; full
    /// detail has 1 mm with `draco` and `quantized`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_position_error_m: Option<f64>,
    /// Discrete chains: the tile's LOD (0 = full detail).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lod_level: Option<usize>,
}

/// One level of detail, as the paper's Table I (LOD level, patches, maximum folding edge length,
/// range of visibility, Δ(mesh)), with the measured error beside the paper's.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct LodLevelReport {
    /// "LOD0 (full detail)", "LOD2 (ratio 0.70)" for chains, "HLOD depth 3" for HLOD tiles.
    pub level: String,
    pub tiles: usize,
    /// Triangles drawn by the level's tiles (the paper's "patches").
    pub patches: usize,
    /// Longest edge collapsed between full detail and any tile of the level (metres).
    pub max_folding_edge_m: f64,
    /// Largest measured error of a tile of the level (metres).
    pub measured_error_max_m: f64,
    /// Largest paper error of a tile of the level ([`paper_geometric_error_m`], metres).
    pub paper_error_max_m: f64,
    /// Largest declared geometricError of the level (metres), from the selected metric.
    pub geometric_error_max_m: f64,
    /// Nearest distance at which a client (1920x1080, 60°, 16 px) still draws the level's
    /// largest-error tile (metres): the paper's "range of visibility".
    pub range_of_visibility_m: f64,
    /// The paper's Δ(mesh) (formula (2), pixels) of the longest folding edge at that distance.
    pub delta_mesh_px: f64,
    /// The measured error on screen at that distance (pixels): 16 px or less is honest.
    pub measured_sse_px: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct LevelReport {
    pub depth: u32,
    pub tiles: usize,
    pub triangles: usize,
    pub bytes: u64,
    pub geometric_error_min_m: f64,
    pub geometric_error_max_m: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct GeoReport {
    pub origin: GeoOrigin,
    /// "option" (from --origin), "input-site" (the input's georeference) or "default".
    pub origin_source: String,
    /// The point of the input's coordinates placed at `origin` (metres, z-up scene frame).
    pub anchor_m: [f64; 3],
    pub anchor_rule: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Timings {
    pub ingest: f64,
    pub dedup: f64,
    pub partition: f64,
    pub encode_write: f64,
    pub tileset: f64,
    pub total: f64,
}

/// What `report.json` holds.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub tool: String,
    pub input: InputReport,
    pub output: OutputReport,
    pub levels: Vec<LevelReport>,
    /// The levels of detail as the paper's Table I (absent without LOD).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub lod_levels: Vec<LodLevelReport>,
    pub tiles: Vec<TileReport>,
    pub georeference: GeoReport,
    /// What dedup found (absent when it was turned off).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dedup: Option<DedupReport>,
    /// Which metric produced the tiles' geometricError.
    pub geometric_error_metric: String,
    pub options: serde_json::Value,
    pub timings_s: Timings,
    pub peak_memory_bytes: u64,
    /// The memory budget and where the geometry was kept (absent without a budget).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub memory: Option<MemoryReport>,
    /// Texture classification, bytes before and per pyramid level, bytes written per level.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub textures: Option<crate::texture::TextureReport>,
}

pub use crate::memory::peak_memory_bytes;

/// `--memory-budget` and what it did: how many meshes stayed in memory and how many were spilled.
#[derive(Debug, Clone, Serialize)]
pub struct MemoryReport {
    pub budget_bytes: u64,
    pub geometry: crate::scene::StoreStats,
    /// Where the per-element metadata records were kept.
    pub metadata: crate::scene::ElementStats,
    /// Why meshes or metadata stayed in memory past the budget (the spill file could not be
    /// written).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub spill_error: Option<String>,
}

impl MemoryReport {
    /// The process's budget (see [`crate::scene::set_memory_budget`]) and `scene`'s store.
    pub fn of(scene: &Scene) -> Option<MemoryReport> {
        crate::scene::memory_budget().map(|b| MemoryReport {
            budget_bytes: b.bytes,
            geometry: scene.meshes.stats(),
            metadata: scene.elements.stats(),
            spill_error: scene
                .meshes
                .spill_error()
                .or(scene.elements.spill_error())
                .map(str::to_string),
        })
    }
}

/// The anchor (the input point placed at the geographic origin): the model's own origin, unless the
/// model lies far from it (projected coordinates), then its footprint centre at ground level.
pub fn choose_anchor(bounds: &Aabb) -> (DVec3, String) {
    let c = bounds.center();
    if c.length() <= PROJECTED_COORDINATES_THRESHOLD_M {
        (DVec3::ZERO, "model origin (coordinates are local)".into())
    } else {
        (
            DVec3::new(c.x, c.y, bounds.min.z),
            format!(
                "footprint centre at the lowest point (the model lies {:.0} m from its origin: projected coordinates)",
                c.length()
            ),
        )
    }
}

fn progress_bar(show: bool, len: usize, what: &'static str) -> indicatif::ProgressBar {
    if !show {
        return indicatif::ProgressBar::hidden();
    }
    let pb = indicatif::ProgressBar::new(len as u64);
    pb.set_style(
        indicatif::ProgressStyle::with_template("{prefix:>10} [{bar:30}] {pos}/{len} {elapsed}")
            .expect("static template")
            .progress_chars("=> "),
    );
    pb.set_prefix(what);
    pb
}

/// Checks that `out` may be written: absent, or replaceable with `force`.
fn check_output(out: &Path, force: bool) -> Result<()> {
    if !out.exists() {
        return Ok(());
    }
    if !force {
        return Err(Error::output(
            out,
            "output folder exists (use --force to replace it)",
        ));
    }
    if !out.is_dir() {
        return Err(Error::output(out, "output path exists and is not a folder"));
    }
    let empty = std::fs::read_dir(out)
        .map_err(|e| Error::output(out, e))?
        .next()
        .is_none();
    if !empty && !out.join("tileset.json").exists() {
        return Err(Error::output(
            out,
            "refusing to replace a folder that does not hold a tileset (no tileset.json)",
        ));
    }
    Ok(())
}

/// Reads `inputs` (none: the embedded sample building), converts them and writes the tileset to
/// `opts.out_dir`.
pub fn convert(inputs: &[PathBuf], opts: &ConvertOptions) -> Result<Report> {
    convert_input_set(&InputSet::new(inputs, None), opts)
}

/// Reads an input set (sample, model files or a campus manifest) and converts it.
pub fn convert_input_set(inputs: &InputSet, opts: &ConvertOptions) -> Result<Report> {
    let t0 = Instant::now();
    check_output(&opts.out_dir, opts.force)?;
    let mut scene = read_scene(inputs)?;
    let t_ingest = t0.elapsed().as_secs_f64();
    convert_scene(&mut scene, opts, t0, t_ingest)
}

/// Reads an input set into one scene; an input without triangles is an error.
pub(crate) fn read_scene(inputs: &InputSet) -> Result<Scene> {
    let scene = inputs.read()?;
    if scene.triangle_count() == 0 {
        let name = scene
            .sources
            .first()
            .map(|s| s.path.clone())
            .unwrap_or_default();
        return Err(Error::input(name, "the input has no triangles to tile"));
    }
    Ok(scene)
}

/// A scene placed, deduplicated and planned: everything before the tiles are built. A pure
/// function of the input and the options, so every process of a sharded build gets the same.
pub(crate) struct Prepared {
    pub input: InputReport,
    pub anchor: DVec3,
    pub anchor_rule: String,
    pub origin: GeoOrigin,
    pub origin_source: &'static str,
    pub dedup: Option<DedupReport>,
    pub textures_prepared: crate::texture::Prepared,
    /// White twin materials added to the scene for merging plain colours per tile.
    pub appearance: AppearanceClasses,
    pub plan: TilePlan,
    /// Per plan tile, its level in a discrete LOD chain (`--lod-ratios`; empty otherwise).
    pub chain_level: Vec<Option<usize>>,
    pub t_dedup: f64,
    pub t_partition: f64,
}

/// Place, dedup, texture preparation and the octree plan.
pub(crate) fn prepare(scene: &mut Scene, opts: &ConvertOptions) -> Prepared {
    let input = InputReport {
        files: scene
            .sources
            .iter()
            .map(|s| s.path.display().to_string())
            .collect(),
        bytes: scene.sources.iter().map(|s| s.bytes).sum(),
        skipped_elements: scene.skipped_elements,
        triangles: scene.triangle_count(),
        vertices: scene.vertex_count(),
        components: scene.components.len(),
        meshes: scene.meshes.len(),
        materials: scene.materials.len(),
        images: scene.images.len(),
        skipped_primitives: scene.skipped_primitives,
        renamed_ids: scene.renamed_ids,
    };

    // Place: the anchor goes to the scene frame's origin, in f64, before anything is rounded. An
    // input's own georeference (IFC site) gives the anchor, the true-north turn and, unless
    // --origin overrides it, the place on Earth.
    let (anchor, anchor_rule, origin, origin_source) = match (scene.georeference, opts.origin) {
        (Some(g), user) => {
            let turn = DMat4::from_rotation_z((-g.true_north_deg.unwrap_or(0.0)).to_radians());
            scene.apply_transform(&(turn * DMat4::from_translation(-g.anchor)));
            let source_origin = GeoOrigin {
                longitude_deg: g.longitude_deg,
                latitude_deg: g.latitude_deg,
                height_m: g.height_m,
            };
            (
                g.anchor,
                format!(
                    "the input's site reference point (turned {:.3}° to true north)",
                    g.true_north_deg.unwrap_or(0.0)
                ),
                user.unwrap_or(source_origin),
                if user.is_some() {
                    "option"
                } else {
                    "input-site"
                },
            )
        }
        (None, user) => {
            let (anchor, rule) = choose_anchor(&scene.bounds());
            if anchor != DVec3::ZERO {
                scene.apply_transform(&DMat4::from_translation(-anchor));
            }
            let source = if user.is_some() { "option" } else { "default" };
            (anchor, rule, user.unwrap_or(GeoOrigin::DEFAULT), source)
        }
    };

    let t_dedup_start = Instant::now();
    let dedup = opts.dedup.as_ref().map(|d| deduplicate(scene, d));
    let t_dedup = t_dedup_start.elapsed().as_secs_f64();

    let textures_prepared = crate::texture::prepare(scene, &opts.texture);
    let merge_materials = opts
        .merge_plain_materials
        .unwrap_or_else(|| default_merge_plain_materials(opts.compression));
    let appearance = match merge_materials {
        true => AppearanceClasses::add_to(scene),
        false => AppearanceClasses::default(),
    };
    let t1 = Instant::now();
    let mut plan = plan_octree(scene, &opts.octree);
    let mut chain_level = Vec::new();
    match &opts.lod {
        LodMode::Hlod => plan = plan.with_content_in_leaves(),
        LodMode::Ratios(r) => {
            let c = with_lod_chains(&plan.with_content_in_leaves(), r.len());
            (plan, chain_level) = (c.plan, c.level);
        }
        LodMode::None => {}
    }
    let t_partition = t1.elapsed().as_secs_f64();
    Prepared {
        input,
        anchor,
        anchor_rule,
        origin,
        origin_source,
        dedup,
        textures_prepared,
        appearance,
        plan,
        chain_level,
        t_dedup,
        t_partition,
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
    check_output(&opts.out_dir, opts.force)?;
    let prep = prepare(scene, opts);
    let plan = &prep.plan;

    // Temporary folder beside the target, renamed at the end.
    let out = &opts.out_dir;
    let parent = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = out
        .file_name()
        .ok_or_else(|| Error::output(out, "output path has no folder name"))?
        .to_string_lossy()
        .to_string();
    std::fs::create_dir_all(parent).map_err(|e| Error::output(parent, e))?;
    let tmp = parent.join(format!(".{name}.tmp-{}", std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|e| Error::output(&tmp, e))?;
    }
    let uses = &prep.textures_prepared.uses;
    let texture_levels =
        crate::texture::TextureLevels::new(scene, &opts.texture, uses).shared_in(&tmp);
    let result = (|| {
        let t = Instant::now();
        let writer = TileWriter::new(
            scene,
            plan,
            opts,
            &tmp,
            &texture_levels,
            &prep.appearance,
            &prep.chain_level,
            plan.tiles.len(),
        )?;
        let job = writer.build_subtrees(&[0], &Default::default(), Default::default())?;
        writer.finish_progress();
        let t_encode = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let stats = writer.merge(vec![job], &[0], prep.origin, prep.anchor)?;
        Ok((stats, t_encode, t.elapsed().as_secs_f64()))
    })();
    let (facts_bytes, t_encode, t_tileset) = match result {
        Ok(x) => x,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    let timings = Timings {
        ingest: t_ingest,
        dedup: prep.t_dedup,
        partition: prep.t_partition,
        encode_write: t_encode,
        tileset: t_tileset,
        total: 0.0,
    };
    let mut report = make_report(prep, &facts_bytes, opts, &tmp, timings, texture_levels);
    report.timings_s.total = t0.elapsed().as_secs_f64();
    report.peak_memory_bytes = peak_memory_bytes();
    report.memory = MemoryReport::of(scene);
    let report_json = serde_json::to_vec_pretty(&report).map_err(|e| Error::output(&tmp, e))?;
    let finish = || -> std::io::Result<()> {
        std::fs::write(tmp.join("report.json"), &report_json)?;
        if out.exists() {
            let old = parent.join(format!(".{name}.old-{}", std::process::id()));
            std::fs::rename(out, &old)?;
            std::fs::rename(&tmp, out)?;
            std::fs::remove_dir_all(&old)?;
        } else {
            std::fs::rename(&tmp, out)?;
        }
        Ok(())
    };
    if let Err(e) = finish() {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(Error::output(out, e));
    }
    Ok(report)
}

/// The report of a finished build in `dir` (tileset.json and schema.json written), from the tiles'
/// figures; timings and peak memory are the caller's.
pub(crate) fn make_report(
    prep: Prepared,
    facts_bytes: &[TileStats],
    opts: &ConvertOptions,
    dir: &Path,
    timings: Timings,
    texture_levels: crate::texture::TextureLevels,
) -> Report {
    let plan = &prep.plan;
    let mut levels: Vec<LevelReport> = Vec::new();
    let (mut out_tris, mut out_verts, mut out_stored, mut out_shapes, mut out_instances) =
        (0, 0, 0, 0, 0);
    let mut out_bytes = 0u64;
    let mut tiles = Vec::new();
    for (t, st) in plan.tiles.iter().zip(facts_bytes) {
        let (ge, bytes, tris, verts) = (
            &st.geometric_error_m,
            &st.bytes,
            &st.triangles,
            &st.vertices,
        );
        out_tris += tris;
        out_verts += verts;
        out_stored += st.stored_triangles;
        out_shapes += st.instanced_shapes;
        out_instances += st.instances;
        out_bytes += bytes;
        tiles.push(TileReport {
            path: t.path.clone(),
            depth: t.depth,
            content: st.uri.clone(),
            features: st.features,
            triangles: st.triangles,
            stored_triangles: st.stored_triangles,
            instances: st.instances,
            bytes: st.bytes,
            metadata_bytes: st.metadata_bytes,
            geometric_error_m: st.geometric_error_m,
            simplified_from_triangles: st.simplified_from_triangles,
            full_to_coarse_m: st.full_to_coarse_m,
            coarse_to_full_bound_m: st.coarse_to_full_bound_m,
            measured_error_m: st.measured_error_m,
            max_folding_edge_m: st.max_folding_edge_m,
            paper_error_m: st.paper_error_m,
            max_position_error_m: st.max_position_error_m,
            lod_level: prep.chain_level.get(tiles.len()).copied().flatten(),
        });
        let d = t.depth as usize;
        while levels.len() <= d {
            levels.push(LevelReport {
                depth: levels.len() as u32,
                tiles: 0,
                triangles: 0,
                bytes: 0,
                geometric_error_min_m: f64::INFINITY,
                geometric_error_max_m: 0.0,
            });
        }
        let l = &mut levels[d];
        l.tiles += 1;
        l.triangles += tris;
        l.bytes += bytes;
        l.geometric_error_min_m = l.geometric_error_min_m.min(*ge);
        l.geometric_error_max_m = l.geometric_error_max_m.max(*ge);
    }
    let tileset_bytes = ["tileset.json", "schema.json"]
        .iter()
        .map(|f| std::fs::metadata(dir.join(f)).map_or(0, |m| m.len()))
        .sum::<u64>();
    Report {
        tool: concat!("bimtiles ", env!("CARGO_PKG_VERSION")).into(),
        input: prep.input,
        output: OutputReport {
            bytes: out_bytes + tileset_bytes,
            tiles: plan.tiles.len(),
            tiles_with_content: plan.tiles.iter().filter(|t| !t.content.is_empty()).count(),
            max_depth: plan.max_depth(),
            triangles: out_tris,
            vertices: out_verts,
            stored_triangles: out_stored,
            instanced_shapes: out_shapes,
            instances: out_instances,
            metadata_bytes: tiles.iter().map(|t| t.metadata_bytes).sum(),
        },
        levels,
        lod_levels: if opts.lod == LodMode::None {
            Vec::new()
        } else {
            lod_levels(&tiles, &opts.lod)
        },
        tiles,
        georeference: GeoReport {
            origin: prep.origin,
            origin_source: prep.origin_source.into(),
            anchor_m: prep.anchor.to_array(),
            anchor_rule: prep.anchor_rule,
        },
        dedup: prep.dedup,
        geometric_error_metric: match (&opts.lod, opts.error_metric) {
            (LodMode::None, _) => SIZE_BOUND_ERROR_METRIC,
            (_, ErrorMetric::PaperSse) => PAPER_SSE_ERROR_METRIC,
            (LodMode::Hlod, _) => HLOD_ERROR_METRIC,
            (LodMode::Ratios(_), _) => CHAIN_ERROR_METRIC,
        }
        .into(),
        options: json!({
            "max_tile_triangles": opts.octree.max_tile_triangles,
            "max_tile_bytes": opts.octree.max_tile_bytes,
            "max_depth": opts.octree.max_depth,
            "compression": format!("{:?}", opts.compression).to_lowercase(),
            "lod": opts.lod.name(),
            "lod_ratios": match &opts.lod { LodMode::Ratios(r) => json!(r), _ => json!(null) },
            "error_metric": opts.error_metric.name(),
            "dedup": opts.dedup.is_some(),
            "dedup_tolerance_m": opts.dedup.as_ref().map(|d| d.tolerance_m),
            "instancing": opts.instancing,
            "min_instanced_triangles_saved": opts.min_instanced_triangles_saved
                .unwrap_or_else(|| default_min_instanced_triangles_saved(opts.compression)),
            "texture": opts.texture,
        }),
        timings_s: timings,
        peak_memory_bytes: 0,
        memory: None,
        textures: (prep.textures_prepared.images_bound > 0)
            .then(|| texture_levels.report(prep.textures_prepared)),
    }
}

/// The geometric error of HLOD tilesets, as the report describes it.
pub const HLOD_ERROR_METRIC: &str = "measured: a tile's geometricError bounds the distance between its \
simplified content and the full detail it stands for (symmetric Hausdorff distance: full-detail samples measured \
against the content, content samples bounded through the children's content and errors; times 1.1, plus the \
quantization bound with Draco); leaves have 0";

/// The geometric error of discrete LOD chains, as the report describes it.
pub const CHAIN_ERROR_METRIC: &str = "measured: a chain tile's geometricError bounds the distance between its \
simplified content and the leaf's full detail (symmetric Hausdorff distance, measured as for HLOD tiles, times 1.1, \
plus the quantization bound with Draco), strictly decreasing down the chain; full detail has 0; empty internal tiles \
have their bounding-box diagonal (everything below is missing when they are drawn)";

/// The paper's screen-space error, as the report describes it.
pub const PAPER_SSE_ERROR_METRIC: &str = "paper-sse: a simplified tile's geometricError is the paper's (III.C(3), \
formulas (1) and (2)): the error that makes a client switch (1920x1080, 60 degrees, 16 px) where Delta(mesh) of the \
longest edge collapsed for the tile reaches 16 px, 3.77 x that edge length; held above the children's. It is not a \
distance bound: compare measured_error_m (the honest value) per tile and measured_sse_px per level";

/// The paper's Table I from the tile reports: one row for full detail, then one per chain level
/// (chains) or per HLOD depth, deepest first.
fn lod_levels(tiles: &[TileReport], lod: &LodMode) -> Vec<LodLevelReport> {
    let v = ViewOptions::default();
    let mut rows: BTreeMap<(i64, String), LodLevelReport> = BTreeMap::new();
    for t in tiles.iter().filter(|t| t.content.is_some()) {
        let key = match (lod, t.lod_level, t.measured_error_m) {
            (LodMode::Ratios(r), Some(k), _) if k > 0 => {
                (k as i64, format!("LOD{k} (ratio {:.2})", r[k - 1]))
            }
            (LodMode::Hlod, _, Some(_)) => {
                (1000 - t.depth as i64, format!("HLOD depth {}", t.depth))
            }
            _ => (0, "LOD0 (full detail)".to_string()),
        };
        let row = rows.entry(key.clone()).or_insert_with(|| LodLevelReport {
            level: key.1,
            tiles: 0,
            patches: 0,
            max_folding_edge_m: 0.0,
            measured_error_max_m: 0.0,
            paper_error_max_m: 0.0,
            geometric_error_max_m: 0.0,
            range_of_visibility_m: 0.0,
            delta_mesh_px: 0.0,
            measured_sse_px: 0.0,
        });
        row.tiles += 1;
        row.patches += t.triangles;
        row.max_folding_edge_m = row
            .max_folding_edge_m
            .max(t.max_folding_edge_m.unwrap_or(0.0));
        row.measured_error_max_m = row
            .measured_error_max_m
            .max(t.measured_error_m.unwrap_or(0.0));
        row.paper_error_max_m = row.paper_error_max_m.max(t.paper_error_m.unwrap_or(0.0));
        row.geometric_error_max_m = row.geometric_error_max_m.max(t.geometric_error_m);
    }
    rows.into_values()
        .map(|mut r| {
            r.range_of_visibility_m = switch_distance_m(r.geometric_error_max_m, &v);
            if r.range_of_visibility_m > 0.0 {
                r.delta_mesh_px =
                    paper_delta_mesh_px(r.max_folding_edge_m, r.range_of_visibility_m, &v);
                r.measured_sse_px = sse_px(r.measured_error_max_m, r.range_of_visibility_m, &v);
            }
            r
        })
        .collect()
}

/// The geometricError a simplified tile declares under `metric`, from its measured error and its
/// longest folding edge, held strictly above its children's (3D Tiles); also the paper's value.
fn declared_error(
    metric: ErrorMetric,
    measured_m: f64,
    folding_edge_m: f64,
    children_max_m: f64,
) -> (f64, f64) {
    let paper_m =
        paper_geometric_error_m(folding_edge_m, &ViewOptions::default(), PAPER_MAX_DELTA_PX);
    let base = match metric {
        ErrorMetric::Measured => measured_m,
        ErrorMetric::PaperSse => paper_m,
    };
    (base.max(children_max_m * (1.0 + 1e-6) + 1e-6), paper_m)
}

/// Default of [`ConvertOptions::hlod_error_fraction`]. A client measures the distance to the
/// bounding box, which from a corner is nearer than the sphere [`framed_error_m`] assumes (0.91 of
/// it on Mini_Project's root); 0.8 keeps a first view of the whole model on the root alone.
pub const DEFAULT_HLOD_ERROR_FRACTION: f64 = 0.8;

/// An HLOD tile keeps at most this fraction (1/n) of what its children draw, and the tile budget:
/// about one child's worth in an octree, so every level costs about the same to draw.
pub const HLOD_CHILDREN_DIVISOR: usize = 4;

/// Coarsening an HLOD tile below the budget stops at this many triangles.
pub const HLOD_MIN_TRIANGLES: usize = 500;

/// At most this many coarser tries per HLOD tile: each simplifies the tile again and measures it
/// against all the full detail below it (Mini_Project.glb converts in 2.6 s with the tries, 1.5 s
/// without).
pub const HLOD_COARSEN_TRIES: usize = 2;

/// Share of a simplified tile's measured error that Draco's position quantization may add on top
/// of it: a tile that stands for full detail within 0.2 m needs no millimetre grid. Its vertices
/// then cost fewer bits (Mini_Project's root, 37 m across: 15 -> 11 bits per coordinate); the
/// declared error includes the quantization, so it stays honest and grows by at most this share.
pub const COARSE_QUANTIZATION_SHARE: f64 = 0.1;

/// Quantization of a simplified tile whose content lies within `measured_m` of full detail:
/// `(per_axis_m, error_m)`, the largest per-axis position error it may add (1 mm, or with Draco a
/// share of the measured error when that is more; KHR_mesh_quantization keeps 16 bits whatever
/// the grid, so gains nothing from a coarser one) and the tile's error with it added (decoded
/// vertices move by up to √3 times the per-axis error).
fn with_quantization(c: Compression, measured_m: f64) -> (f64, f64) {
    let per_axis_m = match c {
        Compression::Draco => {
            DEFAULT_MAX_POSITION_ERROR_M.max(COARSE_QUANTIZATION_SHARE * measured_m / 3f64.sqrt())
        }
        Compression::Quantized => DEFAULT_MAX_POSITION_ERROR_M,
        Compression::None => 0.0,
    };
    (per_axis_m, measured_m + per_axis_m * 3f64.sqrt())
}

/// The geometric error without LOD (additive refinement), as the report describes it.
pub const SIZE_BOUND_ERROR_METRIC: &str = "size-bound: a tile's geometricError is the largest bounding-box diagonal \
among the components of its descendants (what is missing from the view when the tile is drawn without its children, \
additive refinement); leaves have 0";

/// A tile's content as the options want it written: instanced or plain.
fn gather(
    scene: &Scene,
    opts: &ConvertOptions,
    items: &[ContentItem],
    center: DVec3,
) -> TileContent {
    if opts.instancing {
        let min_saved = opts
            .min_instanced_triangles_saved
            .unwrap_or_else(|| default_min_instanced_triangles_saved(opts.compression));
        TileContent::gather_instanced(scene, items, center, min_saved)
    } else {
        TileContent::gather(scene, items, center)
    }
}

/// What writing one tile gave.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct TileStats {
    pub uri: Option<String>,
    pub geometric_error_m: f64,
    pub bytes: u64,
    pub triangles: usize,
    pub vertices: usize,
    pub stored_triangles: usize,
    pub instanced_shapes: usize,
    pub instances: usize,
    pub features: usize,
    pub metadata_bytes: u64,
    pub simplified_from_triangles: Option<usize>,
    pub full_to_coarse_m: Option<f64>,
    pub coarse_to_full_bound_m: Option<f64>,
    pub measured_error_m: Option<f64>,
    pub max_folding_edge_m: Option<f64>,
    pub paper_error_m: Option<f64>,
    /// Largest per-axis position error quantization may add (`None`: the encoding's default).
    pub max_position_error_m: Option<f64>,
}

/// Encodes and writes the tiles of one build under `dir/tiles/` (each to a temporary name, then
/// renamed, so a killed process leaves no tile under its final name half-written), and assembles
/// the tileset from the tiles' figures. Used by `convert` (one job over the whole tree) and by the
/// sharded build (`crate::shard`: each job builds its subtrees, `merge` the levels above them).
pub(crate) struct TileWriter<'a> {
    scene: &'a Scene,
    plan: &'a TilePlan,
    opts: &'a ConvertOptions,
    dir: &'a Path,
    textures: &'a crate::texture::TextureLevels<'a>,
    appearance: &'a AppearanceClasses,
    /// Per plan tile, its level in a discrete LOD chain (`--lod-ratios`; empty otherwise).
    chain_level: &'a [Option<usize>],
    schema: MetadataSchema,
    encoding: TileEncoding,
    pb: indicatif::ProgressBar,
}

/// What building some subtrees gave: the figures of every tile written, and (HLOD) what each
/// subtree root hands its parent.
#[derive(Debug, Default, PartialEq)]
pub(crate) struct JobOutput {
    pub tiles: Vec<(usize, Aabb, TileStats)>,
    pub roots: Vec<(usize, BuiltSubtree)>,
}

impl<'a> TileWriter<'a> {
    /// `progress_len`: tiles this process will write (for the progress bar).
    pub(crate) fn new(
        scene: &'a Scene,
        plan: &'a TilePlan,
        opts: &'a ConvertOptions,
        dir: &'a Path,
        textures: &'a crate::texture::TextureLevels<'a>,
        appearance: &'a AppearanceClasses,
        chain_level: &'a [Option<usize>],
        progress_len: usize,
    ) -> Result<Self> {
        let tiles_dir = dir.join("tiles");
        std::fs::create_dir_all(&tiles_dir).map_err(|e| Error::output(&tiles_dir, e))?;
        Ok(TileWriter {
            scene,
            plan,
            opts,
            dir,
            textures,
            appearance,
            chain_level,
            // The metadata schema, once for the tileset (schema.json), referenced by every tile.
            schema: MetadataSchema::from_scene(scene),
            encoding: TileEncoding {
                compression: opts.compression,
                ..TileEncoding::default()
            },
            pb: progress_bar(opts.progress, progress_len, "tiles"),
        })
    }

    pub(crate) fn finish_progress(&self) {
        self.pb.finish_and_clear();
    }

    fn write(
        &self,
        i: usize,
        content: &TileContent,
        mut st: TileStats,
    ) -> Result<(Aabb, TileStats)> {
        let (scene, opts, textures) = (self.scene, self.opts, self.textures);
        let tile = &self.plan.tiles[i];
        let uri = format!("tiles/{}.glb", tile.path);
        let path = self.dir.join(&uri);
        // The texture level matched to the tile's error (REPLACE content; ADD content is full).
        let texture_error = if opts.lod != LodMode::None {
            st.geometric_error_m
        } else {
            0.0
        };
        let merged = self.appearance.merge(scene, content);
        let content = merged.as_ref().unwrap_or(content);
        let chosen = textures.for_tile(content, texture_error);
        // Small non-repeating images packed into an atlas: UVs remapped in a copy of the content.
        let atlas = textures
            .atlas_for_tile(content, &chosen)
            .map_err(|e| Error::output(&path, e))?;
        let content = atlas.as_ref().map_or(content, |a| &a.content);
        let image = |id| textures.image_for(id, &chosen, atlas.as_ref());
        let sampled_px = atlas.as_ref().map(|a| a.texels_px()).unwrap_or_default();
        let scope = match (st.simplified_from_triangles, opts.coarse_tile_properties) {
            (Some(_), CoarseTileProperties::Identity) => TableScope::Identity,
            _ => TableScope::All,
        };
        let make_table = |features: &[crate::scene::ComponentId]| {
            self.schema
                .property_table(scene, features, "../schema.json", scope)
        };
        let coarse_encoding;
        // Simplified content: its own position grid, its normals from the faces as drawn.
        let encoding = match st.max_position_error_m {
            Some(e) => {
                coarse_encoding = TileEncoding {
                    max_position_error_m: e,
                    normals_from_drawn_faces: true,
                    ..self.encoding.clone()
                };
                &coarse_encoding
            }
            _ => &self.encoding,
        };
        let enc = encode_content_with_images(
            scene,
            content,
            encoding,
            Some(&make_table),
            &image,
            &sampled_px,
        )
        .map_err(|e| Error::output(&path, e))?;
        write_renamed(&path, &enc.glb)?;
        self.pb.inc(1);
        st.uri = Some(uri);
        st.bytes = enc.glb.len() as u64;
        st.triangles = enc.triangles;
        st.vertices = enc.vertices;
        st.stored_triangles = enc.stored_triangles;
        st.instanced_shapes = enc.instanced_shapes;
        st.instances = enc.instances;
        st.features = enc.features.len();
        st.metadata_bytes = enc.metadata_bytes as u64;
        Ok((enc.bounds, st))
    }

    /// Builds and writes the subtrees under `roots`, not descending into tiles of `stop`, whose
    /// results are `provided` (HLOD: what those subtree roots hand up).
    pub(crate) fn build_subtrees(
        &self,
        roots: &[usize],
        stop: &std::collections::BTreeSet<usize>,
        provided: BTreeMap<usize, BuiltSubtree>,
    ) -> Result<JobOutput> {
        let (scene, plan, opts) = (self.scene, self.plan, self.opts);
        let write = |i: usize, content: &TileContent, st: TileStats| self.write(i, content, st);
        match &opts.lod {
            LodMode::None => {
                let mut owned = Vec::new();
                let mut stack: Vec<usize> = roots.iter().rev().copied().collect();
                while let Some(j) = stack.pop() {
                    if !stop.contains(&j) {
                        owned.push(j);
                        stack.extend(plan.tiles[j].children.iter().rev());
                    }
                }
                let tiles = owned
                    .par_iter()
                    .map(|&i| {
                        let tile = &plan.tiles[i];
                        let st = TileStats {
                            geometric_error_m: tile.omitted_size_m,
                            ..Default::default()
                        };
                        if tile.content.is_empty() {
                            self.pb.inc(1);
                            return Ok((i, Aabb::EMPTY, st));
                        }
                        let content =
                            gather(scene, opts, &tile.content, tile.content_bounds.center());
                        let (b, st) = write(i, &content, st)?;
                        Ok((i, b, st))
                    })
                    .collect::<Result<Vec<_>>>()?;
                Ok(JobOutput {
                    tiles,
                    roots: Vec::new(),
                })
            }
            LodMode::Hlod => {
                let slots: Vec<std::sync::Mutex<Option<(Aabb, TileStats)>>> =
                    plan.tiles.iter().map(|_| Default::default()).collect();
                let hlod = HlodBuilder {
                    scene,
                    plan,
                    opts,
                    write: &write,
                    slots: &slots,
                    stop,
                    provided: std::sync::Mutex::new(provided),
                };
                let built = roots
                    .par_iter()
                    .map(|&r| hlod.build(r))
                    .collect::<Result<Vec<_>>>()?;
                let tiles = slots
                    .into_iter()
                    .enumerate()
                    .filter_map(|(i, m)| {
                        m.into_inner()
                            .expect("no poisoned slot")
                            .map(|(b, st)| (i, b, st))
                    })
                    .collect();
                Ok(JobOutput {
                    tiles,
                    roots: roots.iter().copied().zip(built).collect(),
                })
            }
            LodMode::Ratios(ratios) => {
                // Chains sit below whole leaves: a job builds them over the whole tree, or none.
                if stop.contains(&0) {
                    return Ok(JobOutput::default());
                }
                if roots != [0] || !stop.is_empty() {
                    return Err(Error::output(
                        self.dir,
                        "--lod-ratios chains are built by convert, not by sharded jobs",
                    ));
                }
                let tiles = build_chains(scene, plan, self.chain_level, ratios, opts, &write)?;
                Ok(JobOutput {
                    tiles,
                    roots: Vec::new(),
                })
            }
        }
    }

    /// Builds the tiles above the subtree `roots` from the jobs' outputs, then writes schema.json
    /// and tileset.json; returns every tile's figures, in plan order.
    pub(crate) fn merge(
        &self,
        jobs: Vec<JobOutput>,
        roots: &[usize],
        origin: GeoOrigin,
        anchor: DVec3,
    ) -> Result<Vec<TileStats>> {
        let (plan, opts, tmp) = (self.plan, self.opts, self.dir);
        let mut slots: Vec<Option<(Aabb, TileStats)>> = vec![None; plan.tiles.len()];
        let mut provided = BTreeMap::new();
        for job in jobs {
            for (i, b, st) in job.tiles {
                slots[i] = Some((b, st));
            }
            provided.extend(job.roots);
        }
        let stop: std::collections::BTreeSet<usize> = roots.iter().copied().collect();
        let top = self.build_subtrees(&[0], &stop, provided)?;
        for (i, b, st) in top.tiles {
            slots[i] = Some((b, st));
        }
        let mut facts = Vec::with_capacity(slots.len());
        let mut tile_stats = Vec::with_capacity(slots.len());
        for (i, s) in slots.into_iter().enumerate() {
            let (content_bounds, st) = s.ok_or_else(|| {
                Error::output(
                    tmp,
                    format!("tile {} was built by no job", plan.tiles[i].path),
                )
            })?;
            facts.push(TileFacts {
                content_uri: st.uri.clone(),
                content_bounds,
                geometric_error_m: st.geometric_error_m,
            });
            tile_stats.push(st);
        }
        let schema_json = serde_json::to_vec_pretty(&self.schema.to_json(None))
            .map_err(|e| Error::output(tmp, e))?;
        write_renamed(&tmp.join("schema.json"), &schema_json)?;
        let extras = json!({"bimtiles": {
            "origin": {"longitude_deg": origin.longitude_deg, "latitude_deg": origin.latitude_deg, "height_m": origin.height_m},
            "anchor_m": anchor.to_array(),
            "frame": "root transform maps local east-north-up metres to ECEF; glTF content is y-up",
        }});
        let refine = match opts.lod {
            LodMode::Hlod | LodMode::Ratios(_) => Refine::Replace,
            LodMode::None => Refine::Add,
        };
        let mut ts = tileset_json(plan, &facts, refine, &origin.enu_to_ecef(), extras);
        ts["schemaUri"] = json!("schema.json");
        let bytes = serde_json::to_vec_pretty(&ts).map_err(|e| Error::output(tmp, e))?;
        write_renamed(&tmp.join("tileset.json"), &bytes)?;
        Ok(tile_stats)
    }
}

/// Writes `bytes` to `path` through a temporary name beside it (`.NAME.tmp-PID`), renamed at
/// the end: a reader never sees a half-written file under the final name.
pub(crate) fn write_renamed(path: &Path, bytes: &[u8]) -> Result<()> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}.tmp-{}", std::process::id()));
    std::fs::write(&tmp, bytes)
        .and_then(|()| std::fs::rename(&tmp, path))
        .map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            Error::output(path, e)
        })
}

/// What a subtree gives its parent when building HLOD bottom-up.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct BuiltSubtree {
    /// What the tile draws (full detail for leaves, simplified above).
    pub content: TileContent,
    pub geometric_error_m: f64,
    /// Bound of the distance from `content` to full detail (0 for leaves).
    pub coarse_to_full_m: f64,
    /// Longest edge collapsed between full detail and `content` (0 for leaves).
    pub max_folding_edge_m: f64,
    /// Triangles per cut component in the subtree (only components cut across tiles).
    pub cut_triangles: BTreeMap<ComponentId, usize>,
}

type WriteTile<'a> =
    dyn Fn(usize, &TileContent, TileStats) -> Result<(Aabb, TileStats)> + Sync + 'a;

/// Builds HLOD content bottom-up, children in parallel; each tile is written as soon as it is made
/// and only its content travels up to its parent.
struct HlodBuilder<'a> {
    scene: &'a Scene,
    plan: &'a TilePlan,
    opts: &'a ConvertOptions,
    write: &'a WriteTile<'a>,
    slots: &'a [std::sync::Mutex<Option<(Aabb, TileStats)>>],
    /// Tiles not to build: their subtrees were built elsewhere (sharded jobs) and their roots'
    /// results are in `provided`.
    stop: &'a std::collections::BTreeSet<usize>,
    provided: std::sync::Mutex<BTreeMap<usize, BuiltSubtree>>,
}

impl HlodBuilder<'_> {
    /// The content of every leaf below tile `i` (the full detail it stands for).
    fn leaves_below(&self, i: usize) -> Vec<&[crate::partition::ContentItem]> {
        let mut out = Vec::new();
        let mut stack = vec![i];
        while let Some(j) = stack.pop() {
            let t = &self.plan.tiles[j];
            if t.children.is_empty() {
                out.push(&t.content[..]);
            }
            stack.extend(t.children.iter().rev());
        }
        out
    }

    fn build(&self, i: usize) -> Result<BuiltSubtree> {
        let tile = &self.plan.tiles[i];
        let path = || format!("tiles/{}.glb", tile.path);
        if self.stop.contains(&i) {
            let done = self.provided.lock().expect("provided").remove(&i);
            return done.ok_or_else(|| Error::output(path(), "no job built this subtree"));
        }
        let built = if tile.children.is_empty() {
            let content = gather(
                self.scene,
                self.opts,
                &tile.content,
                tile.content_bounds.center(),
            );
            let mut cut_triangles = BTreeMap::new();
            for item in &tile.content {
                if let Some(t) = &item.triangles {
                    *cut_triangles.entry(item.component).or_default() += t.len();
                }
            }
            let written = (self.write)(i, &content, TileStats::default())?;
            *self.slots[i].lock().expect("slot") = Some(written);
            BuiltSubtree {
                // Parents simplify one surface: instances go up as plain geometry.
                content: content.expand(),
                geometric_error_m: 0.0,
                coarse_to_full_m: 0.0,
                max_folding_edge_m: 0.0,
                cut_triangles,
            }
        } else {
            let kids: Vec<BuiltSubtree> = tile
                .children
                .par_iter()
                .map(|&c| self.build(c))
                .collect::<Result<_>>()?;
            let mut cut_triangles: BTreeMap<ComponentId, usize> = BTreeMap::new();
            for k in &kids {
                for (&c, &n) in &k.cut_triangles {
                    *cut_triangles.entry(c).or_default() += n;
                }
            }
            let continuing = continuing(self.scene, &cut_triangles);
            let contents: Vec<&TileContent> = kids.iter().map(|k| &k.content).collect();
            let children: Vec<(&TileContent, f64)> = kids
                .iter()
                .map(|k| (&k.content, k.coarse_to_full_m))
                .collect();
            let leaves = self.leaves_below(i);
            // How coarse the tile may get: its framed error (what a viewer that sees all of it
            // accepts), a fraction of it for the margin between the view's box distance and the
            // bounding sphere. `None`: the budget alone.
            let allowed_m = (self.opts.hlod_error_fraction > 0.0).then(|| {
                self.opts.hlod_error_fraction
                    * framed_error_m(tile.bounds.diagonal() / 2.0, &ViewOptions::default())
            });
            let reference =
                ErrorReference::new(self.scene, tile.bounds.center(), &children, &leaves, 0);
            // A try over `limit_m` is given up as soon as its measurement shows it (`None`).
            let build_at = |from: &[&TileContent], target: usize, limit_m: f64| -> Result<_> {
                let r = simplify_children(
                    from,
                    tile.bounds.center(),
                    &continuing,
                    target,
                    &self.opts.simplify,
                )
                .map_err(|e| Error::output(path(), format!("simplification failed: {e}")))?;
                let err = reference.measure_within(&r.content, &self.opts.simplify, limit_m);
                Ok(err.map(|e| (r, e)))
            };
            let input_triangles: usize = contents.iter().map(|c| c.triangle_count()).sum();
            let mut target = self
                .opts
                .octree
                .max_tile_triangles
                .min(input_triangles.div_ceil(HLOD_CHILDREN_DIVISOR))
                .max(1);
            let (mut r, mut err) = build_at(&contents, target, f64::INFINITY)?.expect("no limit");
            // Coarser while the measured error leaves room: the first view of a model is its root
            // alone, as small as its error allows. Each try costs a simplification and a
            // measurement against all full detail below, so the count is predicted (the error of
            // a simplified surface grows about as 1/triangles; aim at 0.7 of the allowed error)
            // and the tries are few. A try simplifies the last accepted content, a quarter or less
            // of the children's (it is measured against full detail all the same): on a
            // 1.9M-triangle campus the tries took as long as the first simplifications.
            if let Some(allowed) = allowed_m {
                for _ in 0..HLOD_COARSEN_TRIES {
                    let predicted = target as f64 * err.error_m / (0.7 * allowed);
                    let next = (predicted as usize).clamp(target / 16, target / 2);
                    if err.error_m >= allowed || next < HLOD_MIN_TRIANGLES {
                        break;
                    }
                    let Some((r2, err2)) = build_at(&[&r.content], next, allowed)? else {
                        break;
                    };
                    (r, err, target) = (
                        // Figures of the whole chain: children -> last content -> this one.
                        HlodContent {
                            input_triangles: r.input_triangles,
                            max_collapsed_edge_m: r
                                .max_collapsed_edge_m
                                .max(r2.max_collapsed_edge_m),
                            content: r2.content,
                        },
                        err2,
                        next,
                    );
                }
            }
            // The measurement's reference (children's BVHs) and inputs are not needed to write.
            drop(reference);
            drop((contents, children, leaves));
            let (position_error, measured) = with_quantization(self.opts.compression, err.error_m);
            let children_max = kids.iter().map(|k| k.geometric_error_m).fold(0.0, f64::max);
            let folding = kids
                .iter()
                .map(|k| k.max_folding_edge_m)
                .fold(r.max_collapsed_edge_m, f64::max);
            // Strictly above the children's, whatever the sampling found.
            let (ge, paper) =
                declared_error(self.opts.error_metric, measured, folding, children_max);
            drop(kids);
            let st = TileStats {
                geometric_error_m: ge,
                simplified_from_triangles: Some(r.input_triangles),
                full_to_coarse_m: Some(err.full_to_coarse_m),
                coarse_to_full_bound_m: Some(err.coarse_to_full_m),
                measured_error_m: Some(measured),
                max_folding_edge_m: Some(folding),
                paper_error_m: Some(paper),
                max_position_error_m: Some(position_error),
                ..Default::default()
            };
            let written = (self.write)(i, &r.content, st)?;
            *self.slots[i].lock().expect("slot") = Some(written);
            BuiltSubtree {
                content: r.content,
                geometric_error_m: ge,
                coarse_to_full_m: err.coarse_to_full_m,
                max_folding_edge_m: folding,
                cut_triangles,
            }
        };
        Ok(built)
    }
}

/// Components of `cut_triangles` (triangles per component cut across tiles, in a subtree) that go
/// on outside the subtree: their open borders stay locked (no cracks). Sorted.
fn continuing(scene: &Scene, cut_triangles: &BTreeMap<ComponentId, usize>) -> Vec<ComponentId> {
    cut_triangles
        .iter()
        .filter(|&(&c, &n)| n < scene.meshes.triangle_count(scene.component(c).mesh))
        .map(|(&c, _)| c)
        .collect()
}

/// Discrete LOD chains: each chain (found at its full-detail tile, level 0) is built and written
/// at once, chains in parallel; then the empty internal tiles get their size-bound error, bottom
/// up, strictly above their children's.
fn build_chains(
    scene: &Scene,
    plan: &TilePlan,
    chain_level: &[Option<usize>],
    ratios: &[f32],
    opts: &ConvertOptions,
    write: &WriteTile<'_>,
) -> Result<Vec<(usize, Aabb, TileStats)>> {
    let n = ratios.len();
    let fulls: Vec<usize> = (0..plan.tiles.len())
        .filter(|&i| chain_level[i] == Some(0))
        .collect();
    let built: Vec<Vec<(usize, Aabb, TileStats)>> = fulls
        .par_iter()
        .map(|&i| -> Result<Vec<(usize, Aabb, TileStats)>> {
            let tile = &plan.tiles[i];
            let center = tile.content_bounds.center();
            let content = gather(scene, opts, &tile.content, center);
            let mut out = vec![{
                let (b, st) = write(i, &content, TileStats::default())?;
                (i, b, st)
            }];
            let full = content.expand();
            let mut cut = BTreeMap::new();
            for item in &tile.content {
                if let Some(t) = &item.triangles {
                    *cut.entry(item.component).or_default() += t.len();
                }
            }
            let levels = chain_levels(
                scene,
                tile,
                &full,
                &continuing(scene, &cut),
                ratios,
                &opts.simplify,
            )
            .map_err(|e| {
                Error::output(
                    format!("tiles/{}.glb", tile.path),
                    format!("simplification failed: {e}"),
                )
            })?;
            // Finest first: chain tile i - k holds level k.
            let mut below = 0.0;
            for (k, l) in levels.iter().enumerate() {
                let (position_error, measured) =
                    with_quantization(opts.compression, l.error.error_m);
                let (ge, paper) =
                    declared_error(opts.error_metric, measured, l.max_collapsed_edge_m, below);
                below = ge;
                let st = TileStats {
                    geometric_error_m: ge,
                    simplified_from_triangles: Some(full.triangle_count()),
                    full_to_coarse_m: Some(l.error.full_to_coarse_m),
                    coarse_to_full_bound_m: Some(l.error.coarse_to_full_m),
                    measured_error_m: Some(measured),
                    max_folding_edge_m: Some(l.max_collapsed_edge_m),
                    paper_error_m: Some(paper),
                    max_position_error_m: Some(position_error),
                    ..Default::default()
                };
                let at = i - (k + 1);
                debug_assert_eq!(chain_level[at], Some(k + 1));
                let (b, st) = write(at, &l.content, st)?;
                out.push((at, b, st));
            }
            debug_assert_eq!(levels.len(), n);
            Ok(out)
        })
        .collect::<Result<_>>()?;
    let mut slots: Vec<Option<(Aabb, TileStats)>> = vec![None; plan.tiles.len()];
    for (i, b, st) in built.into_iter().flatten() {
        slots[i] = Some((b, st));
    }
    // Internal tiles (pre-order: children after parents).
    for i in (0..plan.tiles.len()).rev() {
        if slots[i].is_some() {
            continue;
        }
        let t = &plan.tiles[i];
        let children_max = t
            .children
            .iter()
            .filter_map(|&c| slots[c].as_ref().map(|s| s.1.geometric_error_m))
            .fold(0.0, f64::max);
        let ge = if t.children.is_empty() {
            0.0
        } else {
            t.bounds.diagonal().max(children_max * (1.0 + 1e-6) + 1e-6)
        };
        slots[i] = Some((
            Aabb::EMPTY,
            TileStats {
                geometric_error_m: ge,
                ..Default::default()
            },
        ));
    }
    Ok(slots
        .into_iter()
        .enumerate()
        .map(|(i, s)| {
            let (b, st) = s.expect("every tile built");
            (i, b, st)
        })
        .collect())
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
    use crate::scene::{Component, ComponentId, ElementInfo, Mesh, MeshId, Primitive};
    use crate::simplify::{simplify, MeshInput};
    let t0 = Instant::now();
    let scene = crate::ingest::read_input(input)?;
    let triangles_in = scene.triangle_count();
    let center = scene.bounds().center();
    let all_have = |f: &dyn Fn(&Primitive) -> bool| {
        scene
            .components
            .iter()
            .all(|c| scene.mesh(c.mesh).primitives.iter().all(f))
    };
    let (with_n, with_uv, with_c) = (
        all_have(&|p| p.normals.is_some()),
        all_have(&|p| p.uvs.is_some()),
        all_have(&|p| p.colors.is_some()),
    );
    let (mut pos, mut nrm, mut uv, mut col, mut grp, mut idx) = (
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
    );
    for c in &scene.components {
        let nm = c.normal_matrix();
        let flip = c.mirrors();
        for p in &scene.mesh(c.mesh).primitives {
            let base = pos.len() as u32;
            let g = p.material.map_or(u32::MAX, |m| m.0);
            for v in &p.positions {
                let w = c
                    .world
                    .transform_point3(DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64))
                    - center;
                pos.push([w.x as f32, w.y as f32, w.z as f32]);
                grp.push(g);
            }
            if let (true, Some(ns)) = (with_n, &p.normals) {
                nrm.extend(ns.iter().map(|n| {
                    let w = (nm * DVec3::new(n[0] as f64, n[1] as f64, n[2] as f64))
                        .normalize_or(DVec3::Z);
                    [w.x as f32, w.y as f32, w.z as f32]
                }));
            }
            if let (true, Some(u)) = (with_uv, &p.uvs) {
                uv.extend_from_slice(u);
            }
            if let (true, Some(k)) = (with_c, &p.colors) {
                col.extend_from_slice(k);
            }
            for t in p.indices.chunks_exact(3) {
                let t = if flip {
                    [t[0], t[2], t[1]]
                } else {
                    [t[0], t[1], t[2]]
                };
                idx.extend(t.iter().map(|i| base + i));
            }
        }
    }
    let mesh_in = MeshInput {
        positions: &pos,
        normals: with_n.then_some(&nrm[..]),
        uvs: with_uv.then_some(&uv[..]),
        colors: with_c.then_some(&col[..]),
        groups: Some(&grp),
        locked: None,
        indices: &idx,
    };
    let r = simplify(&mesh_in, opts)
        .map_err(|e| Error::input(input, format!("simplification failed: {e}")))?;
    // One primitive per material (vertex group), in the scene frame around `center`.
    let mut out = Scene {
        sources: scene.sources.clone(),
        materials: scene.materials.clone(),
        images: scene.images.clone(),
        ..Default::default()
    };
    let mut by_group: std::collections::BTreeMap<u32, Vec<u32>> = Default::default();
    for t in r.indices.chunks_exact(3) {
        by_group
            .entry(r.groups[t[0] as usize])
            .or_default()
            .extend_from_slice(t);
    }
    let mut prims = Vec::new();
    for (g, tris) in by_group {
        let mut used: Vec<u32> = tris.clone();
        used.sort_unstable();
        used.dedup();
        let remap = |i: &u32| used.binary_search(i).expect("used vertex") as u32;
        prims.push(Primitive {
            material: (g != u32::MAX).then_some(crate::scene::MaterialId(g)),
            positions: used.iter().map(|&v| r.positions[v as usize]).collect(),
            normals: r
                .normals
                .as_ref()
                .map(|n| used.iter().map(|&v| n[v as usize]).collect()),
            uvs: r
                .uvs
                .as_ref()
                .map(|u| used.iter().map(|&v| u[v as usize]).collect()),
            colors: r
                .colors
                .as_ref()
                .map(|c| used.iter().map(|&v| c[v as usize]).collect()),
            indices: tris.iter().map(remap).collect(),
        });
    }
    out.meshes.push(Mesh {
        name: Some("simplified".into()),
        primitives: prims,
        local_bounds: None,
    });
    out.push_component(
        Component::new(MeshId(0), DMat4::from_translation(center)),
        &ElementInfo {
            name: Some("simplified".into()),
            ..ElementInfo::keyed("simplified")
        },
    );
    out.finish();
    let items = [crate::partition::ContentItem {
        component: ComponentId(0),
        triangles: None,
    }];
    let enc = TileEncoding {
        compression: Compression::None,
        ..TileEncoding::default()
    };
    let tile = encode_tile(&out, &items, center, &enc, None)?;
    let tmp = output.with_extension("glb.tmp");
    std::fs::write(&tmp, &tile.glb).map_err(|e| Error::output(&tmp, e))?;
    std::fs::rename(&tmp, output).map_err(|e| Error::output(output, e))?;
    Ok(SimplifyReport {
        input: input.display().to_string(),
        output: output.display().to_string(),
        triangles_in,
        triangles_out: tile.triangles,
        error_m: r.error_m,
        seconds: t0.elapsed().as_secs_f64(),
    })
}
