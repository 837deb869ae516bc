//! What `report.json` holds (input and output counts, tiles, levels as the paper's Table I,
//! georeference, timings, memory, textures) and how a finished build's figures become it.
//! `inspect` reads it back.

use crate::dedup::DedupReport;
use crate::encode::TileRecord;
use crate::geodesy::{GeoOrigin, OriginSource};
use crate::options::{ErrorMetric, LodMode, Settings};
use crate::prepare::{InputReport, Prepared};
use crate::scene::placement::AnchorRule;
use crate::scene::Scene;
use crate::tileset::view::{paper_delta_mesh_px, sse_px, switch_distance_m, ViewOptions};
use serde::Serialize;
use serde_json::json;
use std::collections::BTreeMap;
use std::path::Path;

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
    /// Bytes of the edges (`EXT_mesh_primitive_edge_visibility` data) over all tiles, and what
    /// they cost gzipped as served (each tile's edge data gzipped alone); the tiles' own figures
    /// are in `tiles[]`, so a view's share is the sum over the tiles it loads.
    pub edge_bytes: u64,
    pub edge_gzip_bytes: u64,
    /// The gzipped edge data of the tiles a first whole-model view loads (`inspect`'s selection;
    /// the root inlined in tileset.json is its tile); 0 without edges.
    pub first_view_edge_gzip_bytes: u64,
    /// Bytes of the element index (`element-index.json`, for a viewer's model tree and search;
    /// not in `bytes`, which a first view may load).
    pub element_index_bytes: u64,
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

#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct GeoReport {
    pub origin: GeoOrigin,
    /// What gave the place: `option` (from --origin), `input-crs` (a projected CRS: an IFC map
    /// conversion, --crs), `input-site` (an IFC site reference, a manifest's origin) or `default`.
    pub origin_source: OriginSource,
    /// Every projected CRS that placed an input: which, where it came from, the PROJ operation
    /// and its accuracy, convergence and scale factor, and how heights were read.
    #[serde(default)]
    pub crs: Vec<crate::geodesy::crs::CrsUse>,
    /// Georeferences that could not be used (the input was placed without them).
    #[serde(default)]
    pub warnings: Vec<String>,
    /// The point of the input's coordinates placed at `origin` (metres, z-up scene frame).
    pub anchor_m: [f64; 3],
    pub anchor_rule: AnchorRule,
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
    /// Every tile, for scripts that want more than the per-level summary.
    pub tiles: Vec<TileRecord>,
    pub georeference: GeoReport,
    /// What dedup found (absent when it was turned off).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dedup: Option<DedupReport>,
    /// Which metric produced the tiles' geometricError.
    pub geometric_error_metric: String,
    pub options: serde_json::Value,
    pub timings_s: Timings,
    /// Seconds per part of the HLOD stage, summed over tiles (absent without HLOD).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hlod_timings_s: Option<crate::lod::clock::HlodTimings>,
    pub peak_memory_bytes: u64,
    /// The memory budget and where the geometry was kept (absent without a budget).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub memory: Option<MemoryReport>,
    /// Texture classification, bytes before and per pyramid level, bytes written per level.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub textures: Option<crate::texture::TextureReport>,
    /// What the user should know although the build succeeded (an image dropped...), one line
    /// each; the CLI prints them on stderr unless `--quiet`.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    /// What `--update` reused, rebuilt and removed, and why it built anew (absent without
    /// `--update`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub update: Option<crate::update::UpdateReport>,
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

/// The report of a finished build in `dir` (tileset.json and schema.json written), from the tiles'
/// records (in plan order); timings and peak memory are the caller's.
pub(crate) fn make_report(
    prep: Prepared,
    tiles: Vec<TileRecord>,
    opts: &Settings,
    dir: &Path,
    timings: Timings,
    texture_levels: crate::texture::TextureLevels,
) -> Report {
    let mut levels: Vec<LevelReport> = Vec::new();
    let (mut out_tris, mut out_verts, mut out_stored, mut out_shapes, mut out_instances) =
        (0, 0, 0, 0, 0);
    let mut out_bytes = 0u64;
    for t in &tiles {
        let c = &t.content;
        let (ge, bytes, tris) = (&t.geometric_error_m, &c.bytes, &c.triangles);
        out_tris += tris;
        out_verts += c.vertices;
        out_stored += c.stored_triangles;
        out_shapes += c.instanced_shapes;
        out_instances += c.instances;
        out_bytes += bytes;
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
            tiles: tiles.len(),
            tiles_with_content: tiles.iter().filter(|t| t.uri.is_some()).count(),
            max_depth: tiles.iter().map(|t| t.depth).max().unwrap_or(0),
            triangles: out_tris,
            vertices: out_verts,
            stored_triangles: out_stored,
            instanced_shapes: out_shapes,
            instances: out_instances,
            metadata_bytes: tiles.iter().map(|t| t.content.metadata_bytes).sum(),
            edge_bytes: tiles.iter().map(|t| t.content.edge_bytes).sum(),
            edge_gzip_bytes: tiles.iter().map(|t| t.content.edge_gzip_bytes).sum(),
            // Filled by the caller, which may read the written tileset back.
            first_view_edge_gzip_bytes: 0,
            element_index_bytes: std::fs::metadata(
                dir.join(crate::tileset::element_index::ELEMENT_INDEX_FILE),
            )
            .map_or(0, |m| m.len()),
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
            origin_source: prep.origin_source,
            crs: prep.crs_used,
            warnings: prep.georef_warnings.clone(),
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
            "client": opts.client,
            "schema_in_every_tile": opts.schema_in_every_tile,
            "compression": format!("{:?}", opts.compression).to_lowercase(),
            "lod": opts.lod.name(),
            "lod_ratios": match &opts.lod { LodMode::Ratios(r) => json!(r), _ => json!(null) },
            "error_metric": opts.error_metric.name(),
            "coarse_root": opts.coarse_root,
            "dedup": opts.dedup.is_some(),
            "dedup_tolerance_m": opts.dedup.as_ref().map(|d| d.tolerance_m),
            "instancing": opts.instancing,
            "min_instanced_triangles_saved": opts.min_instanced_triangles_saved,
            "texture": opts.texture,
            "cityjson_lod": opts.cityjson_lod,
            "obj_up": opts.mesh_frame.up,
            "obj_unit": opts.mesh_frame.unit,
            "citygml_lod": opts.citygml_lod,
            "citygml_theme": opts.citygml_theme,
        }),
        timings_s: timings,
        hlod_timings_s: None,
        peak_memory_bytes: 0,
        memory: None,
        warnings: prep
            .reader_warnings
            .iter()
            .chain(&prep.georef_warnings)
            .cloned()
            .chain(
                prep.textures_prepared
                    .dropped_images
                    .iter()
                    .map(|d| d.to_string()),
            )
            .collect(),
        textures: (prep.textures_prepared.images_bound > 0)
            .then(|| texture_levels.report(prep.textures_prepared)),
        update: None,
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
pub(crate) fn lod_levels(tiles: &[TileRecord], lod: &LodMode) -> Vec<LodLevelReport> {
    let v = ViewOptions::default();
    let mut rows: BTreeMap<(i64, String), LodLevelReport> = BTreeMap::new();
    for t in tiles.iter().filter(|t| t.uri.is_some()) {
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
        row.patches += t.content.triangles;
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

/// The geometric error without LOD (additive refinement), as the report describes it.
pub const SIZE_BOUND_ERROR_METRIC: &str = "size-bound: a tile's geometricError is the largest bounding-box diagonal \
among the components of its descendants (what is missing from the view when the tile is drawn without its children, \
additive refinement); leaves have 0";
