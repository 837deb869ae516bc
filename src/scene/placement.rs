//! Placement: which point of a model's own coordinates goes to its place on Earth, and the
//! transform that brings the model there (anchor at the origin, turned to true north). One rule
//! for `convert` and for every entry of a campus manifest.

use super::{Aabb, Scene};
use glam::{DMat4, DVec3};

/// Models whose bounding-box centre is farther than this from their own origin are taken to be in
/// projected (map) coordinates: they are re-anchored at their footprint centre.
pub const PROJECTED_COORDINATES_THRESHOLD_M: f64 = 10_000.0;

/// Where a scene is anchored.
#[derive(Debug, Clone, PartialEq)]
pub struct Placement {
    /// The point of the input's coordinates placed at the geographic origin (scene frame, m).
    pub anchor: DVec3,
    /// Why that point, for the report.
    pub rule: String,
    /// Scene frame → anchored frame: the anchor to the origin, then (with a georeference) the turn
    /// from the model's north to true north.
    pub local: DMat4,
}

impl Placement {
    /// The input's own georeference (IFC site) gives the anchor and the true-north turn;
    /// otherwise [`choose_anchor`] over the scene's bounds.
    pub fn of(scene: &Scene) -> Placement {
        match scene.georeference {
            Some(g) => Placement {
                anchor: g.anchor,
                rule: format!(
                    "the input's site reference point (turned {:.3}° to true north)",
                    g.true_north_deg.unwrap_or(0.0)
                ),
                local: DMat4::from_rotation_z((-g.true_north_deg.unwrap_or(0.0)).to_radians())
                    * DMat4::from_translation(-g.anchor),
            },
            None => {
                let (anchor, rule) = choose_anchor(&scene.bounds());
                Placement {
                    anchor,
                    rule,
                    local: DMat4::from_translation(-anchor),
                }
            }
        }
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
