//! Placement: which point of a model's own coordinates goes to its place on Earth, and the
//! transform that brings the model there (anchor at the origin, turned to true north; for map
//! coordinates, also scaled from grid to ground). One rule for `convert` and for every entry of a
//! manifest of many models.

use super::{Aabb, Scene, SourceGeoreference};
use crate::geodesy::crs::{place_map_point, with_map_to_enu, CrsError, CrsUse, MapPlace};
use glam::{DMat3, DMat4, DVec3};

/// Models whose bounding-box centre is farther than this from their own origin are taken to be in
/// projected (map) coordinates: they are re-anchored at their footprint centre.
pub const PROJECTED_COORDINATES_THRESHOLD_M: f64 = 10_000.0;

/// Why a point of the input was chosen as its anchor (report.json's `georeference.anchor_rule`,
/// tagged by `rule`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "rule", rename_all = "kebab-case")]
pub enum AnchorRule {
    /// A map conversion's point, turned to true north.
    MapPoint { true_north_deg: f64 },
    /// An IFC site's reference point, turned to true north.
    SiteReference { true_north_deg: f64 },
    /// The model's own origin: its coordinates are local.
    ModelOrigin,
    /// The footprint centre at the lowest point: the model lies this far from its own origin, so
    /// its coordinates are projected ones.
    FootprintCentre { distance_m: f64 },
}

impl std::fmt::Display for AnchorRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            AnchorRule::MapPoint { true_north_deg } => write!(
                f,
                "the input's map point (turned {true_north_deg:.4}° to true north)"
            ),
            AnchorRule::SiteReference { true_north_deg } => write!(
                f,
                "the input's site reference point (turned {true_north_deg:.3}° to true north)"
            ),
            AnchorRule::ModelOrigin => f.write_str("model origin (coordinates are local)"),
            AnchorRule::FootprintCentre { distance_m } => write!(
                f,
                "footprint centre at the lowest point (the model lies {distance_m:.0} m from its origin: projected coordinates)"
            ),
        }
    }
}

/// Where a scene is anchored.
#[derive(Debug, Clone, PartialEq)]
pub struct Placement {
    /// The point of the input's coordinates placed at the geographic origin (scene frame, m).
    pub anchor: DVec3,
    /// Why that point, for the report.
    pub rule: AnchorRule,
    /// Scene frame → anchored frame: the anchor to the origin, then (with a georeference) the turn
    /// from the model's north to true north.
    pub local: DMat4,
}

impl Placement {
    /// The input's own georeference (IFC site) gives the anchor and the true-north turn;
    /// otherwise [`choose_anchor`] over the scene's bounds.
    pub fn of(scene: &Scene) -> Placement {
        match scene.georeference {
            Some(g) if g.map_linear.is_some() => Placement {
                anchor: g.anchor,
                rule: AnchorRule::MapPoint {
                    true_north_deg: g.true_north_deg.unwrap_or(0.0),
                },
                local: DMat4::from_mat3(g.map_linear.unwrap_or(DMat3::IDENTITY))
                    * DMat4::from_translation(-g.anchor),
            },
            Some(g) => Placement {
                anchor: g.anchor,
                rule: AnchorRule::SiteReference {
                    true_north_deg: g.true_north_deg.unwrap_or(0.0),
                },
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

/// Adds where the anchor's map point went (`p`) to the report's `georeference.crs`, under the
/// scene's first file.
fn record_crs_use(scene: &mut Scene, source: &str, p: &MapPlace, anchor: DVec3) {
    let file = scene
        .sources
        .first()
        .map(|s| s.path.display().to_string())
        .unwrap_or_default();
    scene
        .crs_used
        .push(CrsUse::new(&file, source, p, anchor.x, anchor.y));
}

/// The anchor (the input point placed at the geographic origin): the model's own origin, unless the
/// model lies far from it (projected coordinates), then its footprint centre at ground level.
pub fn choose_anchor(bounds: &Aabb) -> (DVec3, AnchorRule) {
    let c = bounds.center();
    if c.length() <= PROJECTED_COORDINATES_THRESHOLD_M {
        (DVec3::ZERO, AnchorRule::ModelOrigin)
    } else {
        (
            DVec3::new(c.x, c.y, bounds.min.z),
            AnchorRule::FootprintCentre {
                distance_m: c.length(),
            },
        )
    }
}

/// Georeferences a scene whose coordinates are map coordinates of `crs` (`--crs`, a manifest
/// entry's `"crs"`): x = easting, y = northing (in the CRS's units), z = height (metres, taken as
/// ellipsoidal). The anchor is chosen by [`choose_anchor`]; its map point is placed by PROJ, and the
/// grid's convergence and scale factor there turn and scale the model to true north and ground
/// metres. `source` says where the CRS came from (report).
pub fn georeference_map_coordinates(
    scene: &mut Scene,
    crs: &str,
    source: &str,
) -> Result<(), CrsError> {
    let (anchor, _) = choose_anchor(&scene.bounds());
    let p = place_map_point(crs, anchor.x, anchor.y, anchor.z)?;
    let grid = p.grid_to_enu * p.unit_m;
    let linear = DMat3::from_cols(grid.x_axis.extend(0.0), grid.y_axis.extend(0.0), DVec3::Z);
    record_crs_use(scene, source, &p, anchor);
    scene.georeference = Some(SourceGeoreference {
        longitude_deg: p.place.longitude_deg,
        latitude_deg: p.place.latitude_deg,
        height_m: p.place.height_m,
        true_north_deg: Some(p.convergence_deg),
        anchor,
        map_linear: Some(linear),
    });
    Ok(())
}

/// Why [`georeference_map_coordinates_per_vertex`] did not place a scene.
#[derive(Debug, thiserror::Error)]
pub enum PerVertexError {
    /// PROJ could not place the anchor: nothing moved, the scene is as it was.
    #[error(transparent)]
    NotPlaced(CrsError),
    /// PROJ placed the anchor but refused a vertex: part of the scene moved, so it cannot be
    /// used at all.
    #[error("{0} (the model is only partly placed)")]
    Midway(CrsError),
}

/// Like [`georeference_map_coordinates`], but every vertex is converted on its own
/// ([`with_map_to_enu`]) instead of by one linear map at the anchor: for inputs that cover a
/// district (CityJSON), where the linear map would be centimetres to metres off at the edges.
/// The scene ends in the east-north-up frame of the anchor's place (anchor at the origin, no
/// turn left to apply); each component keeps its vertices relative to its own corner, so f32
/// positions stay exact to the micrometre. A mesh drawn by several components is copied per
/// component (each copy bends where it stands).
pub fn georeference_map_coordinates_per_vertex(
    scene: &mut Scene,
    crs: &str,
    source: &str,
) -> Result<(), PerVertexError> {
    let (anchor, _) = choose_anchor(&scene.bounds());
    let p =
        place_map_point(crs, anchor.x, anchor.y, anchor.z).map_err(PerVertexError::NotPlaced)?;
    // Normals turn with the grid's convergence (the map is conformal: no shear to undo).
    let turn = DMat3::from_cols(
        p.grid_to_enu.x_axis.extend(0.0),
        p.grid_to_enu.y_axis.extend(0.0),
        DVec3::Z,
    );
    let mut uses = vec![0u32; scene.meshes.len()];
    for c in &scene.components {
        uses[c.mesh.index()] += 1;
    }
    let Scene {
        components, meshes, ..
    } = scene;
    with_map_to_enu(crs, &p.place, |to_enu| -> Result<(), CrsError> {
        for c in components.iter_mut() {
            let mut mesh = std::sync::Arc::unwrap_or_clone(meshes.get(c.mesh));
            mesh.local_bounds = None;
            let corner = to_enu(c.world.transform_point3(DVec3::ZERO))?;
            for prim in &mut mesh.primitives {
                for v in &mut prim.positions {
                    let map = c
                        .world
                        .transform_point3(DVec3::from_array(v.map(f64::from)));
                    *v = (to_enu(map)? - corner).as_vec3().to_array();
                }
                let normal_turn = turn * c.normal_matrix();
                for n in prim.normals.iter_mut().flatten() {
                    let turned = normal_turn * DVec3::from_array(n.map(f64::from));
                    *n = turned.normalize_or_zero().as_vec3().to_array();
                }
            }
            if uses[c.mesh.index()] > 1 {
                c.mesh = meshes.push(mesh);
            } else {
                meshes.set(c.mesh, mesh);
            }
            c.world = DMat4::from_translation(corner);
        }
        Ok(())
    })
    .map_err(PerVertexError::NotPlaced)?
    .map_err(PerVertexError::Midway)?;
    record_crs_use(scene, source, &p, anchor);
    scene.georeference = Some(SourceGeoreference {
        longitude_deg: p.place.longitude_deg,
        latitude_deg: p.place.latitude_deg,
        height_m: p.place.height_m,
        true_north_deg: Some(0.0),
        anchor: DVec3::ZERO,
        map_linear: Some(DMat3::IDENTITY),
    });
    scene.finish();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anchor_rules_read_back_from_the_report_and_read_as_sentences() {
        for rule in [
            AnchorRule::MapPoint {
                true_north_deg: -35.25,
            },
            AnchorRule::SiteReference {
                true_north_deg: 50.0,
            },
            AnchorRule::ModelOrigin,
            AnchorRule::FootprintCentre {
                distance_m: 5_516_000.0,
            },
        ] {
            let json = serde_json::to_value(rule).unwrap();
            assert!(json["rule"].is_string(), "{json}");
            assert_eq!(serde_json::from_value::<AnchorRule>(json).unwrap(), rule);
        }
        let far = AnchorRule::FootprintCentre {
            distance_m: 5_516_000.4,
        };
        assert_eq!(
            serde_json::to_value(far).unwrap(),
            serde_json::json!({"rule": "footprint-centre", "distance_m": 5_516_000.4})
        );
        assert!(far.to_string().contains("5516000 m from its origin"));
    }
}
