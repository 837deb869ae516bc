//! Writes `tileset.json` (3D Tiles 1.1): the tile tree with tight bounding boxes, geometric errors,
//! refinement and content URIs, and the root transform that georeferences it.

pub mod element_index;
pub mod inline;
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

/// A number in a tileset that no viewer can use: where it sits and what it holds.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NumbersError {
    /// The tileset has no `root` tile.
    #[error("the tileset has no root")]
    NoRoot,
    /// A field is missing, of the wrong shape, or not made of numbers (`found`: its JSON).
    #[error("{what} is {found}")]
    NotNumbers { what: String, found: String },
    /// A field holds `null` (NaN or an infinity, as `serde_json` writes them) or an implausible
    /// value (`value`: `null` or the number in exponent notation).
    #[error("{what} holds {value}")]
    Implausible { what: String, value: String },
}

/// The last check before a tileset is written (book: guide/safety.md): every bounding box,
/// transform and geometric error of `tileset` is a number (`serde_json` writes NaN and infinities
/// as
/// `null`) and plausible (`geodesy::plausible_m`). `Err`: where the first one that is not sits,
/// and its value; a tileset that fails this must not be written.
pub fn check_numbers(tileset: &Value) -> Result<(), NumbersError> {
    let plausible = |what: &str, v: Option<&Value>, n: usize| -> Result<(), NumbersError> {
        let numbers: Vec<Option<f64>> = match v {
            Some(Value::Array(a)) if a.len() == n => a.iter().map(Value::as_f64).collect(),
            Some(Value::Number(x)) if n == 1 => vec![x.as_f64()],
            other => {
                return Err(NumbersError::NotNumbers {
                    what: what.to_string(),
                    found: other.unwrap_or(&Value::Null).to_string(),
                })
            }
        };
        match numbers
            .iter()
            .find(|x| !x.is_some_and(crate::geodesy::plausible_m))
        {
            Some(x) => Err(NumbersError::Implausible {
                what: what.to_string(),
                value: x.map_or("null".into(), |x| format!("{x:e}")),
            }),
            None => Ok(()),
        }
    };
    plausible(
        "the tileset's geometricError",
        tileset.get("geometricError"),
        1,
    )?;
    let root = tileset.get("root").ok_or(NumbersError::NoRoot)?;
    plausible("the root transform", root.get("transform"), 16)?;
    let mut stack = vec![(root, "root".to_string())];
    while let Some((tile, name)) = stack.pop() {
        let volume = tile.pointer("/boundingVolume/box");
        plausible(&format!("the bounding box of tile {name}"), volume, 12)?;
        let error = tile.get("geometricError");
        plausible(&format!("the geometricError of tile {name}"), error, 1)?;
        for (k, c) in tile["children"]
            .as_array()
            .into_iter()
            .flatten()
            .enumerate()
        {
            stack.push((c, format!("{name}/{k}")));
        }
    }
    Ok(())
}

/// Builds the tileset JSON. `records[i]` belongs to `plan.tiles[i]`; `root_transform` maps the
/// scene frame to ECEF; `extras` is stored under `asset.extras`.
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

/// What `asset.extras.bimtiles.edges` tells a viewer: which edges the tiles carry (`--edges`) and
/// whether to show them at first. Shown for models of plain-coloured elements (BIM, CAD, city
/// models without photographs), where they make the shapes readable; not for photo-textured
/// scenes, whose images already draw their edges. `None` without edges.
pub fn edges_extras(
    mode: crate::encode::edges::EdgeMode,
    scene: &crate::scene::Scene,
) -> Option<serde_json::Value> {
    if mode == crate::encode::edges::EdgeMode::None {
        return None;
    }
    let textured = scene
        .materials
        .iter()
        .any(|m| m.base_color_texture.is_some());
    Some(serde_json::json!({"written": mode.name(), "shown": !textured}))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    /// The last check before writing: boxes, transforms and errors must be plausible numbers;
    /// `serde_json` writes NaN as null, which is refused too.
    #[test]
    fn check_numbers_refuses_what_no_viewer_can_use() {
        let b = Aabb {
            min: DVec3::new(-1.0, -2.0, 0.0),
            max: DVec3::new(1.0, 2.0, 3.0),
        };
        let tileset = |b: &Aabb, child: &Aabb| {
            json!({"geometricError": 10.0, "root": {
                "transform": DMat4::IDENTITY.to_cols_array(),
                "boundingVolume": {"box": box_volume(b)}, "geometricError": 1.0,
                "children": [{"boundingVolume": {"box": box_volume(child)}, "geometricError": 0.0}],
            }})
        };
        assert_eq!(check_numbers(&tileset(&b, &b)), Ok(()));
        let far = Aabb {
            min: b.min,
            max: DVec3::new(1e30, 2.0, 3.0),
        };
        let err = check_numbers(&tileset(&b, &far)).unwrap_err().to_string();
        assert!(err.contains("tile root/0") && err.contains("e29"), "{err}");
        let nan = Aabb {
            min: DVec3::NAN,
            max: b.max,
        };
        let err = check_numbers(&tileset(&nan, &b)).unwrap_err().to_string();
        assert!(err.contains("tile root") && err.contains("null"), "{err}");
        let mut t = tileset(&b, &b);
        t["root"]["transform"][12] = json!(1e300);
        let err = check_numbers(&t).unwrap_err().to_string();
        assert!(
            err.contains("root transform") && err.contains("1e300"),
            "{err}"
        );
    }
}
