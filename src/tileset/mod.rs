//! Writes `tileset.json` (3D Tiles 1.1): the tile tree with tight bounding boxes, geometric errors,
//! refinement and content URIs, and the root transform that georeferences it.

pub mod metadata;
pub mod view;

use crate::encode::TileRecord;
use crate::partition::octree::TilePlan;
use crate::scene::Aabb;
use glam::DMat4;
use serde_json::{json, Value};

/// Grows a box just enough to absorb the f32 rounding of vertices written relative to a tile
/// centre (a few ulps of the tile size) and to never be degenerate.
pub fn padded(b: &Aabb) -> Aabb {
    let pad = 1e-4 + b.size().max_element() * 1e-6;
    Aabb {
        min: b.min - glam::DVec3::splat(pad),
        max: b.max + glam::DVec3::splat(pad),
    }
}

/// `boundingVolume.box`: centre and three half-axes, in the tileset's local frame.
pub fn box_volume(b: &Aabb) -> Value {
    let b = padded(b);
    let c = b.center();
    let h = b.size() * 0.5;
    json!([c.x, c.y, c.z, h.x, 0.0, 0.0, 0.0, h.y, 0.0, 0.0, 0.0, h.z])
}

/// How a tile's children refine it (3D Tiles `refine`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refine {
    /// Children are drawn in addition to the tile.
    Add,
    /// Children replace the tile (HLOD).
    Replace,
}

/// How many times the model's diagonal the tileset's own geometricError is: the model is then
/// drawn once it spans about 16/4 = 4 pixels at CesiumJS's default maximumScreenSpaceError of 16.
pub const TOP_ERROR_PER_DIAGONAL: f64 = 4.0;

/// Builds the tileset JSON. `records[i]` belongs to `plan.tiles[i]`; `root_transform` maps the scene
/// frame to ECEF; `extras` is stored under `asset.extras`.
pub fn tileset_json(
    plan: &TilePlan,
    records: &[TileRecord],
    refine: Refine,
    root_transform: &DMat4,
    extras: Value,
) -> Value {
    // Bounding volumes from the written content, children first (tiles are in pre-order), so
    // every child's volume lies inside its parent's.
    let mut bounds: Vec<Aabb> = records.iter().map(|r| r.content.bounds).collect();
    for i in (0..plan.tiles.len()).rev() {
        for &c in &plan.tiles[i].children {
            bounds[i] = bounds[i].union(&bounds[c]);
        }
    }
    fn tile(plan: &TilePlan, records: &[TileRecord], bounds: &[Aabb], i: usize) -> Value {
        let t = &plan.tiles[i];
        let mut v = json!({
            "boundingVolume": {"box": box_volume(&bounds[i])},
            "geometricError": records[i].geometric_error_m,
        });
        if let Some(uri) = &records[i].uri {
            v["content"] = json!({"uri": uri});
        }
        if !t.children.is_empty() {
            v["children"] = Value::Array(
                t.children
                    .iter()
                    .map(|&c| tile(plan, records, bounds, c))
                    .collect(),
            );
        }
        v
    }
    let mut root = tile(plan, records, &bounds, 0);
    root["refine"] = json!(match refine {
        Refine::Add => "ADD",
        Refine::Replace => "REPLACE",
    });
    root["transform"] = json!(root_transform.to_cols_array());
    // The whole model is what goes missing when the root is not drawn: it should appear once it
    // covers a few pixels.
    let top_error =
        (bounds[0].diagonal() * TOP_ERROR_PER_DIAGONAL).max(records[0].geometric_error_m);
    json!({
        "asset": {"version": "1.1", "generator": concat!("bimtiles ", env!("CARGO_PKG_VERSION")), "extras": extras},
        "geometricError": top_error,
        "root": root,
    })
}
