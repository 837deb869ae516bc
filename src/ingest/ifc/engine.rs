//! The only code that names ifc-lite types: one trait (`IfcEngine`) returning plain data
//! (`RawGeometry`, `RawData`, `RawGeoref`), implemented by `IfcLite` over
//! `ifc-lite-processing`. Porting to another ifc-lite major (or another IFC kernel) means
//! rewriting `IfcLite` only.

use super::{IfcError, IfcMapConversion};
use glam::{DMat4, DVec3};
use std::collections::{BTreeMap, HashMap, HashSet};

/// One triangle list of one element with one colour. Frame point = origin + position.
pub struct RawPiece {
    pub origin: [f64; 3],
    pub positions: Vec<f32>,
    pub normals: Vec<f32>,
    pub indices: Vec<u32>,
    pub color: [f32; 4],
    pub material_name: Option<String>,
}

pub struct RawElement {
    pub express_id: u32,
    /// IFC spelling ("IfcWallStandardCase").
    pub class: String,
    pub guid: Option<String>,
    pub name: Option<String>,
    pub pieces: Vec<RawPiece>,
}

/// A product that has a representation but no mesh came back for it.
pub struct RawMissing {
    pub express_id: u32,
    pub class: String,
    pub guid: Option<String>,
    pub reason: String,
}

pub struct RawGeometry {
    /// Elements with at least one piece, in file (express id) order.
    pub elements: Vec<RawElement>,
    /// Products left out because every shape representation they have is a curve or points
    /// (IfcAlignment axes, footprints): (express id, IFC class).
    pub curve_only: Vec<(u32, String)>,
    pub missing: Vec<RawMissing>,
    /// Mesh frame → IFC world (metres, z-up).
    pub frame_to_world: DMat4,
}

pub struct RawEntity {
    pub class: String,
    pub guid: Option<String>,
    pub name: Option<String>,
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum RelKind {
    Aggregates,
    Contains,
    Nests,
    DefinesByType,
    DefinesByProperties,
    /// A type object's own set (related = type, relating = set).
    TypeHasSet,
}

pub struct RawRel {
    pub kind: RelKind,
    pub relating: u32,
    pub related: u32,
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum ValueKind {
    Text,
    Bool,
    Logical,
    Integer,
    Real,
    Null,
    Unknown,
}

pub struct RawValue {
    pub text: String,
    pub kind: ValueKind,
}

pub struct RawSet {
    pub name: String,
    pub values: Vec<(String, RawValue)>,
}

pub struct RawData {
    /// Products, spatial elements and type objects by express id (IFC-spelled classes).
    pub entities: HashMap<u32, RawEntity>,
    pub rels: Vec<RawRel>,
    /// Property and quantity sets by express id.
    pub sets: HashMap<u32, RawSet>,
    /// (object, IfcMaterial name) in layer order.
    pub materials: Vec<(u32, String)>,
}

pub struct RawGeoref {
    /// (latitude, longitude, elevation) from IfcSite.
    pub site_reference: Option<(f64, f64, f64)>,
    pub site_origin: DVec3,
    pub true_north: Option<[f64; 2]>,
    pub map_conversion: Option<IfcMapConversion>,
}

/// What bimtiles needs from an IFC kernel.
pub trait IfcEngine {
    fn geometry(&self, content: &[u8]) -> Result<RawGeometry, IfcError>;
    fn data_model(&self, content: &[u8]) -> Result<RawData, IfcError>;
    fn georef(&self, content: &[u8]) -> Result<RawGeoref, IfcError>;
}

/// ifc-lite-processing / -core 28.2.0.
pub struct IfcLite;

use ifc_lite_core as core;
use ifc_lite_processing as lite;

fn ifc_name(upper_or_any: &str) -> String {
    match core::IfcType::from_str(upper_or_any) {
        core::IfcType::Unknown(_) => upper_or_any.to_string(),
        t => t.name().to_string(),
    }
}

fn frame_matrix(frame: lite::MeshFrame) -> DMat4 {
    match frame.site_placement() {
        Some(_) => {
            // ifc-lite removes the site rotation only when it is not (near) identity; restore
            // exactly what it removed, via its own mapping of the axes.
            let o = frame.to_world([0.0; 3]);
            let x = frame.to_world([1.0, 0.0, 0.0]);
            let y = frame.to_world([0.0, 1.0, 0.0]);
            let z = frame.to_world([0.0, 0.0, 1.0]);
            let o = DVec3::from(o);
            DMat4::from_cols(
                (DVec3::from(x) - o).extend(0.0),
                (DVec3::from(y) - o).extend(0.0),
                (DVec3::from(z) - o).extend(0.0),
                o.extend(1.0),
            )
        }
        None => DMat4::from_translation(DVec3::from(frame.to_world([0.0; 3]))),
    }
}

impl IfcEngine for IfcLite {
    fn geometry(&self, content: &[u8]) -> Result<RawGeometry, IfcError> {
        let req = lite::ProcessingRequest::full_pass();
        let res = lite::process(content, &req, &mut ());
        if let Some(unit) = res.metadata.length_unit_refused {
            return Err(IfcError::UnusableLengthUnit { entity: unit });
        }
        let frame_to_world = frame_matrix(res.frame);
        let curve_only = curve_only_products(content);
        let mut by_id: BTreeMap<u32, RawElement> = BTreeMap::new();
        for m in res.meshes {
            if curve_only.contains_key(&m.express_id) {
                continue;
            }
            // 1 = orphan type map, 2 = instanced type map: type-library geometry, not placed.
            if m.geometry_class == 1 || m.geometry_class == 2 {
                continue;
            }
            let e = by_id.entry(m.express_id).or_insert_with(|| RawElement {
                express_id: m.express_id,
                class: ifc_name(&m.ifc_type),
                guid: m.global_id.clone(),
                name: m.name.clone(),
                pieces: Vec::new(),
            });
            if m.indices.is_empty() {
                continue;
            }
            e.pieces.push(RawPiece {
                origin: m.origin,
                positions: m.positions,
                normals: m.normals,
                indices: m.indices,
                color: m.color,
                material_name: m.material_name,
            });
        }
        // Products whose class carries geometry, that have a Representation, and got no mesh.
        let index = std::sync::Arc::new(core::build_entity_index(content));
        let mut dec = core::EntityDecoder::with_arc_index(content, index);
        let mut scanner = core::EntityScanner::new(content);
        let mut missing = Vec::new();
        let mut seen: HashSet<u32> = HashSet::new();
        while let Some((id, type_name, start, end)) = scanner.next_entity() {
            if !core::has_geometry_by_name(type_name)
                || by_id.get(&id).is_some_and(|e| !e.pieces.is_empty())
                || curve_only.contains_key(&id)
            {
                continue;
            }
            let upper = type_name.to_ascii_uppercase();
            if upper.ends_with("TYPE") || upper.ends_with("STYLE") {
                continue;
            }
            let Ok(ent) = dec.decode_at(start, end) else {
                continue;
            };
            // IfcProduct: GlobalId 0, Name 2, ObjectPlacement 5, Representation 6.
            let has_rep = ent.get_ref(6).is_some();
            let guid = ent.get_string(0).map(str::to_string);
            if !has_rep || guid.is_none() || !seen.insert(id) {
                continue;
            }
            missing.push(RawMissing {
                express_id: id,
                class: ifc_name(type_name),
                guid,
                reason: "has a representation but the IFC library produced no triangles from it"
                    .into(),
            });
        }
        let elements = by_id
            .into_values()
            .filter(|e| !e.pieces.is_empty())
            .collect();
        Ok(RawGeometry {
            elements,
            curve_only: curve_only.into_iter().collect(),
            missing,
            frame_to_world,
        })
    }

    fn data_model(&self, content: &[u8]) -> Result<RawData, IfcError> {
        let dm = lite::data_model::extract_data_model(content);
        let mut entities = HashMap::new();
        for e in dm.entities {
            entities.insert(
                e.entity_id,
                RawEntity {
                    class: ifc_name(&e.type_name),
                    guid: e.global_id,
                    name: e.name,
                },
            );
        }
        let mut rels = Vec::new();
        for r in dm.relationships {
            let t = r.rel_type.to_ascii_uppercase();
            let kind = match t.as_str() {
                "IFCRELAGGREGATES" => RelKind::Aggregates,
                "IFCRELCONTAINEDINSPATIALSTRUCTURE" => RelKind::Contains,
                "IFCRELNESTS" => RelKind::Nests,
                "IFCRELDEFINESBYTYPE" => RelKind::DefinesByType,
                "IFCRELDEFINESBYPROPERTIES" => RelKind::DefinesByProperties,
                "TYPEHASPROPERTYSETS" => RelKind::TypeHasSet,
                _ => continue,
            };
            rels.push(RawRel {
                kind,
                relating: r.relating_id,
                related: r.related_id,
            });
        }
        let mut sets = HashMap::new();
        for ps in dm.property_sets {
            let values = ps
                .properties
                .into_iter()
                .map(|p| {
                    let kind = match p.property_type.as_str() {
                        "string" => ValueKind::Text,
                        "boolean" => ValueKind::Bool,
                        "logical" => ValueKind::Logical,
                        "integer" => ValueKind::Integer,
                        "real" => ValueKind::Real,
                        "null" => ValueKind::Null,
                        _ => ValueKind::Unknown,
                    };
                    (
                        p.property_name,
                        RawValue {
                            text: p.property_value,
                            kind,
                        },
                    )
                })
                .collect();
            sets.insert(
                ps.pset_id,
                RawSet {
                    name: ps.pset_name,
                    values,
                },
            );
        }
        for qs in dm.quantity_sets {
            let values = qs
                .quantities
                .into_iter()
                .map(|q| {
                    let integral = q.quantity_type.eq_ignore_ascii_case("count")
                        && q.quantity_value.fract() == 0.0;
                    (
                        q.quantity_name,
                        RawValue {
                            text: if integral {
                                format!("{}", q.quantity_value as i64)
                            } else {
                                format!("{}", q.quantity_value)
                            },
                            kind: if integral {
                                ValueKind::Integer
                            } else {
                                ValueKind::Real
                            },
                        },
                    )
                })
                .collect();
            sets.insert(
                qs.qset_id,
                RawSet {
                    name: qs.qset_name,
                    values,
                },
            );
        }
        let mut mats: Vec<_> = dm.materials.into_iter().collect();
        mats.sort_by_key(|m| (m.element_id, m.association_id, m.layer_index));
        let materials = mats
            .into_iter()
            .filter(|m| m.material_name_present)
            .map(|m| (m.element_id, m.material_name))
            .collect();
        Ok(RawData {
            entities,
            rels,
            sets,
            materials,
        })
    }

    fn georef(&self, content: &[u8]) -> Result<RawGeoref, IfcError> {
        let index = std::sync::Arc::new(core::build_entity_index(content));
        let mut dec = core::EntityDecoder::with_arc_index(content, index);
        let scale = dec.length_unit_scale();
        let scale = if scale.is_finite() && scale > 0.0 {
            scale
        } else {
            1.0
        };
        let mut site = None;
        let mut context = None;
        let mut conversion = None;
        let mut scanner = core::EntityScanner::new(content);
        while let Some((id, t, _, _)) = scanner.next_entity() {
            if site.is_none() && t.eq_ignore_ascii_case("IFCSITE") {
                site = Some(id);
            } else if conversion.is_none()
                && (t.eq_ignore_ascii_case("IFCMAPCONVERSION")
                    || t.eq_ignore_ascii_case("IFCMAPCONVERSIONSCALED"))
            {
                conversion = Some(id);
            } else if context.is_none()
                && t.eq_ignore_ascii_case("IFCGEOMETRICREPRESENTATIONCONTEXT")
            {
                if let Ok(c) = dec.decode_by_id(id) {
                    let ty = c.get_string(1).unwrap_or("");
                    if ty.eq_ignore_ascii_case("Model") || context.is_none() && ty.is_empty() {
                        context = Some(id);
                    }
                }
            }
        }
        let mut out = RawGeoref {
            site_reference: None,
            site_origin: DVec3::ZERO,
            true_north: None,
            map_conversion: None,
        };
        if let Some(site) = site.and_then(|s| dec.decode_by_id(s).ok()) {
            // IfcSite: ObjectPlacement 5, RefLatitude 9, RefLongitude 10, RefElevation 11.
            let angle = |i: usize| -> Option<f64> {
                let l = site.get_list(i)?;
                let parts: Vec<f64> = l
                    .iter()
                    .filter_map(|v| v.as_int().map(|x| x as f64).or_else(|| v.as_float()))
                    .collect();
                if parts.is_empty() {
                    return None;
                }
                let w = [1.0, 1.0 / 60.0, 1.0 / 3600.0, 1.0 / 3.6e9];
                Some(parts.iter().zip(w).map(|(p, w)| p * w).sum())
            };
            if let (Some(lat), Some(lon)) = (angle(9), angle(10)) {
                let h = site.get_float(11).map_or(0.0, |h| h * scale);
                out.site_reference = Some((lat, lon, h));
            }
            if let Some(p) = site.get_ref(5) {
                out.site_origin = placement(&mut dec, p, scale, 0).transform_point3(DVec3::ZERO);
            }
        }
        if let Some(ctx) = context.and_then(|c| dec.decode_by_id(c).ok()) {
            if let Some(d) = ctx.get_ref(5).and_then(|d| dec.decode_by_id(d).ok()) {
                let r: Vec<f64> = d
                    .get_list(0)
                    .unwrap_or(&[])
                    .iter()
                    .filter_map(|v| v.as_float())
                    .collect();
                if r.len() >= 2 {
                    out.true_north = Some([r[0], r[1]]);
                }
            }
        }
        // ifc-lite also reports IfcSite's RefLatitude/RefLongitude as a pseudo map conversion
        // ("siteLocation"): only a real IfcMapConversion (or IFC2X3 ePSet_MapConversion, or
        // IFC4X3 IfcRigidOperation) counts here.
        if let Some(g) = lite::extract_georeferencing(content)
            .filter(|g| g.source.as_deref().is_some_and(|s| s != "siteLocation"))
        {
            let operation = match g.source.as_deref() {
                Some("rigidOperation") => super::MapOperation::RigidOperation,
                Some("ePSetMapConversion") => super::MapOperation::PropertySets,
                _ => super::MapOperation::MapConversion,
            };
            // ifc-lite marks an IfcGeographicCRS target by the unit 'DEGREE'; a rigid operation
            // in plane angles is only read against one.
            let geographic = operation == super::MapOperation::RigidOperation
                && g.map_unit.as_deref() == Some("DEGREE");
            out.map_conversion = Some(IfcMapConversion {
                eastings: g.eastings,
                northings: g.northings,
                orthogonal_height: g.orthogonal_height,
                x_axis_abscissa: g.x_axis_abscissa,
                x_axis_ordinate: g.x_axis_ordinate,
                scale: g.scale,
                crs_name: g.crs_name,
                geodetic_datum: g.geodetic_datum,
                map_projection: g.map_projection,
                map_zone: g.map_zone,
                factors: [g.factor_x, g.factor_y, g.factor_z],
                map_unit_m: g.map_unit_scale.filter(|_| !geographic),
                project_unit_m: scale,
                crs_description: g.crs_description,
                vertical_datum: g.vertical_datum,
                operation,
                geographic,
            });
        }
        // ifc-lite reads a Scale or Factor of 0 (or not finite) as 1: the file's own values, so
        // that an absurd one is refused (`georef::implausible_map_number`), not replaced.
        let written = conversion.and_then(|c| dec.decode_by_id(c).ok());
        if let (Some(m), Some(written)) = (out.map_conversion.as_mut(), written) {
            // IfcMapConversion: Scale 7; IfcMapConversionScaled: FactorX/Y/Z 8..10.
            m.scale = written.get_float(7).unwrap_or(m.scale);
            for (k, f) in m.factors.iter_mut().enumerate() {
                *f = written.get_float(8 + k).unwrap_or(*f);
            }
        }
        Ok(out)
    }
}

/// IfcShapeRepresentation RepresentationTypes that hold no surface: curves and points (an
/// IfcAlignment's Axis, a FootPrint outline). A product with only these draws no triangles of its
/// own; a kernel that sweeps them into strips would make clickable walls out of set-out lines.
const CURVE_REPRESENTATION_TYPES: &[&str] = &[
    "Curve",
    "Curve2D",
    "Curve3D",
    "GeometricCurveSet",
    "Point",
    "PointCloud",
    "Segment",
];

/// Products whose every shape representation is a curve or points, by express id (IFC class).
fn curve_only_products(content: &[u8]) -> BTreeMap<u32, String> {
    let index = std::sync::Arc::new(core::build_entity_index(content));
    let mut dec = core::EntityDecoder::with_arc_index(content, index);
    let mut scanner = core::EntityScanner::new(content);
    let mut out = BTreeMap::new();
    while let Some((id, type_name, start, end)) = scanner.next_entity() {
        let upper = type_name.to_ascii_uppercase();
        if !(core::has_geometry_by_name(type_name) || upper.starts_with("IFCALIGNMENT"))
            || upper.ends_with("TYPE")
        {
            continue;
        }
        let Ok(product) = dec.decode_at(start, end) else {
            continue;
        };
        // IfcProduct.Representation (6) → IfcProductDefinitionShape.Representations (2).
        let Some(shape) = product.get_ref(6).and_then(|r| dec.decode_by_id(r).ok()) else {
            continue;
        };
        let reps: Vec<u32> = shape
            .get_list(2)
            .unwrap_or(&[])
            .iter()
            .filter_map(|v| v.as_entity_ref())
            .collect();
        let kinds: Vec<String> = reps
            .iter()
            .filter_map(|r| dec.decode_by_id(*r).ok())
            .map(|rep| rep.get_string(2).unwrap_or("").to_string())
            .collect();
        if !kinds.is_empty()
            && kinds.len() == reps.len()
            && kinds.iter().all(|k| {
                CURVE_REPRESENTATION_TYPES
                    .iter()
                    .any(|c| c.eq_ignore_ascii_case(k))
            })
        {
            out.insert(id, ifc_name(type_name));
        }
    }
    out
}

/// IfcLocalPlacement → world matrix (metres).
fn placement(dec: &mut core::EntityDecoder, id: u32, scale: f64, depth: usize) -> DMat4 {
    if depth > 32 {
        return DMat4::IDENTITY;
    }
    let Ok(lp) = dec.decode_by_id(id) else {
        return DMat4::IDENTITY;
    };
    let parent = lp
        .get_ref(0)
        .map_or(DMat4::IDENTITY, |p| placement(dec, p, scale, depth + 1));
    let local = lp
        .get_ref(1)
        .map_or(DMat4::IDENTITY, |a| axis2(dec, a, scale));
    parent * local
}

fn axis2(dec: &mut core::EntityDecoder, id: u32, scale: f64) -> DMat4 {
    let Ok(a) = dec.decode_by_id(id) else {
        return DMat4::IDENTITY;
    };
    let mut vec_of = |i: usize| -> Option<DVec3> {
        let e = dec.decode_by_id(a.get_ref(i)?).ok()?;
        let v: Vec<f64> = e.get_list(0)?.iter().filter_map(|x| x.as_float()).collect();
        Some(DVec3::new(
            *v.first()?,
            *v.get(1)?,
            v.get(2).copied().unwrap_or(0.0),
        ))
    };
    let loc = vec_of(0).unwrap_or(DVec3::ZERO) * scale;
    let z = vec_of(1)
        .and_then(|v| v.try_normalize())
        .unwrap_or(DVec3::Z);
    let xr = vec_of(2).unwrap_or(DVec3::X);
    let x = (xr - z * xr.dot(z)).try_normalize().unwrap_or(DVec3::X);
    let y = z.cross(x);
    DMat4::from_cols(x.extend(0.0), y.extend(0.0), z.extend(0.0), loc.extend(1.0))
}
