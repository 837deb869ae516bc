//! The one record of a tile of a build. The encoder fills in what the written content holds
//! ([`ContentFigures`]); the tile builder adds the URI, the geometric error and (simplified
//! tiles) how the error was measured; `tileset.json` reads the URI, box and error from it, and
//! `report.json` serializes it as it is (`tiles[]`).

use crate::scene::Aabb;
use serde::Serialize;

/// What an encoded tile's content holds.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ContentFigures {
    /// Size of the GLB.
    pub bytes: u64,
    /// Features (components) with a row in the tile's property table.
    pub features: usize,
    /// Triangles and vertices drawn (an instanced shape once per instance).
    pub triangles: usize,
    pub vertices: usize,
    /// Triangles stored (an instanced shape once).
    pub stored_triangles: usize,
    /// Instanced shapes and the components drawn through them.
    pub instanced_shapes: usize,
    pub instances: usize,
    /// Bytes of the property table (buffers and its JSON), 0 without metadata.
    pub metadata_bytes: u64,
    /// Bytes of the edge visibility data (`EXT_mesh_primitive_edge_visibility` views), and
    /// what they cost gzipped as a server sends them; 0 with `--edges none`.
    pub edge_bytes: u64,
    pub edge_gzip_bytes: u64,
    /// Exact box of the written vertices once decoded (quantization included), in the scene
    /// frame; empty for a tile without content.
    #[serde(skip)]
    pub bounds: Aabb,
}

/// One tile of a build, from the encoder to `tileset.json` and `report.json`.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct TileRecord {
    /// The tile's path in the plan (`r`, `r0`, `r03`...) and its depth; set from the plan when
    /// the build's tiles are gathered.
    pub path: String,
    pub depth: u32,
    /// Content URI relative to tileset.json, if the tile has content.
    #[serde(rename = "content")]
    pub uri: Option<String>,
    pub geometric_error_m: f64,
    #[serde(flatten)]
    pub content: ContentFigures,
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
    /// detail has 1 mm with every compression but `none`). `None`: the encoding's default.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_position_error_m: Option<f64>,
    /// Discrete chains (`--lod-ratios`): the tile's LOD (0 = full detail).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lod_level: Option<usize>,
    /// The root's content went into tileset.json as a data URI (the default; `--no-inline-root`
    /// keeps it a file); `uri` names the file it would have been, and is not written.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub inlined_in_tileset: bool,
}

impl TileRecord {
    /// A record that holds only the tile's geometric error (content and figures come later).
    pub fn with_error(geometric_error_m: f64) -> Self {
        TileRecord {
            geometric_error_m,
            ..Default::default()
        }
    }
}
