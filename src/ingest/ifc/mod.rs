//! IFC reader (IFC2X3, IFC4, IFC4X1–IFC4X3 STEP files, `.ifc`), behind the cargo feature `ifc`.
//!
//! Parsing and triangulation are done by `ifc-lite-processing` (MPL-2.0, pinned `=28.2.0`). Its API
//! changes every major version, so it is reached only through the small internal `engine`
//! module: one trait (`engine::IfcEngine`) that returns plain data (`RawGeometry`, `RawData`, `RawGeoref`); nothing
//! outside that module names an ifc-lite type. Porting to another ifc-lite major (or another IFC
//! kernel) means rewriting `engine::IfcLite` only.
//!
//! # What becomes what
//! * Every IFC product with triangles becomes one [`Component`]: `key` = GlobalId, `name` = IFC
//!   Name, one [`Primitive`] per distinct surface colour/material, one [`Material`] per distinct
//!   colour in the whole file (alpha < 1 → [`AlphaMode::Blend`], metallic 0, roughness 0.85, name =
//!   the IFC material/style name when known). Colours are copied as the IFC style gives them.
//! * Frames: the scene frame is IFC's *world* (project) frame: metres, z-up, the same coordinates
//!   IfcOpenShell writes with `use-world-coords`. Mesh positions are f32 relative to a per-element
//!   local origin (the centre of the element's box); `Component::world` carries that origin in f64
//!   together with the site placement ifc-lite removed (a rotation + translation), so millimetres
//!   survive projected site coordinates. No y-up/z-up swap is involved.
//! * The spatial structure becomes [`Node`]s: Site → Building → Storey (→ Space) → aggregate
//!   parent (IfcStair, IfcCurtainWall, IfcRoof...) → element; `Component::node` is the element's
//!   node, so `Scene::node_path` reads "Site/Building/Storey/Element". The project is not a node.
//! * [`ElementInfo`]: GlobalId, class (IFC spelling, e.g. "IfcWallStandardCase"), storey, building
//!   (or IFC4X3 facility), site (names, found by walking up containment *and* aggregation), material
//!   (the associated IfcMaterial names, from the element or its type), and every property set and
//!   quantity set of the element and of its type (the element's own value wins), typed: booleans
//!   and logicals → `Bool` (UNKNOWN → `Text`), integers → `Integer`, reals and quantities →
//!   `Number`, labels, identifiers, enumerations and references → `Text`.
//!
//! # Classes left out
//! [`SKIPPED_CLASSES`] lists them with the reason (openings are voids, spaces and zones are room
//! volumes that would hide the building, annotations and grids are drawing aids, virtual elements
//! are invisible boundaries). Type objects' own representation maps (geometry drawn for the type
//! library, not placed in the building) are left out too.
//!
//! # Bad input
//! Before ifc-lite sees a byte, the file is checked by [`check_step`]: ISO-10303-21 header, a known
//! `FILE_SCHEMA`, a complete DATA section and trailer (a truncated file fails here), every record
//! well formed, every `#n` reference defined. Problems are an [`Error::Input`] naming the file, the
//! problem and its line. ifc-lite calls run under `catch_unwind`, so a panic inside it becomes an
//! error too. An element that has a representation but yields no usable triangles is skipped with
//! a warning on stderr and listed in [`IfcReadReport::skipped`].

use crate::error::{Error, Result};
use crate::scene::*;
use glam::{DMat4, DVec3};
use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::Path;
use std::time::Instant;

mod assembly;
mod engine;
mod georef;
mod step;

use assembly::assemble;
pub use assembly::parse_loose;
use georef::georef_from_raw;
pub use georef::CrsField;
pub use step::{check_step, RecordProblem, StepError, StepSummary};

/// IFC classes never turned into components, with the reason (exact class names; subtypes such as
/// IfcOpeningStandardCase are listed on their own).
pub const SKIPPED_CLASSES: &[(&str, &str)] = &[
    (
        "IfcOpeningElement",
        "a void cut out of its host, not a solid",
    ),
    (
        "IfcOpeningStandardCase",
        "a void cut out of its host, not a solid",
    ),
    (
        "IfcVoidingFeature",
        "a void cut out of its host, not a solid",
    ),
    (
        "IfcSpace",
        "a room volume: it would enclose and hide the building",
    ),
    (
        "IfcSpatialZone",
        "a zone volume: it would enclose and hide the building",
    ),
    (
        "IfcExternalSpatialElement",
        "an outdoor zone volume, not a built object",
    ),
    (
        "IfcAnnotation",
        "2D drawing content (texts, dimensions, symbols)",
    ),
    ("IfcGrid", "setting-out lines, not a built object"),
    ("IfcVirtualElement", "an invisible boundary between spaces"),
];
// Products of any class whose only shape representations are curves or points (IfcAlignment's
// Axis, a FootPrint) are left out too, like grids: counted in `IfcReadReport::curve_only`.

/// Roughness given to every IFC material (IFC surface styles rarely carry PBR data).
pub const IFC_ROUGHNESS: f32 = 0.85;

/// An element that could not be used, for the conversion report.
#[derive(Debug, Clone, PartialEq)]
pub struct SkippedElement {
    pub guid: String,
    pub class: String,
    pub reason: String,
}

/// IfcMapConversion (+ IfcProjectedCRS) as found in the file: project (x, y, z) →
/// (E, N, H) = (E0 + s(a·x − b·y), N0 + s(b·x + a·y), H0 + z) with (a, b) the normalised
/// x-axis abscissa/ordinate.
#[derive(Debug, Clone, PartialEq)]
pub struct IfcMapConversion {
    pub eastings: f64,
    pub northings: f64,
    pub orthogonal_height: f64,
    pub x_axis_abscissa: f64,
    pub x_axis_ordinate: f64,
    pub scale: f64,
    /// e.g. "EPSG:25832".
    pub crs_name: Option<String>,
    /// IfcProjectedCRS GeodeticDatum, MapProjection, MapZone ("ETRS89", "UTM", "32N"): the CRS
    /// when the name is not one PROJ knows.
    pub geodetic_datum: Option<String>,
    pub map_projection: Option<String>,
    pub map_zone: Option<String>,
    /// IFC4X3 IfcMapConversionScaled FactorX/Y/Z (1 when absent), on top of `scale`.
    pub factors: [f64; 3],
    /// Metres per IfcProjectedCRS MapUnit (`None`: not given, the project's length unit).
    pub map_unit_m: Option<f64>,
    /// Metres per project length unit (1 for metres, 0.001 for millimetres).
    pub project_unit_m: f64,
    /// IfcProjectedCRS Description and VerticalDatum (a WKT, a vertical CRS code).
    pub crs_description: Option<String>,
    pub vertical_datum: Option<String>,
    /// Which entity wrote the placement.
    pub operation: MapOperation,
    /// The target is an IfcGeographicCRS: Eastings/Northings are longitude/latitude in degrees
    /// (an IFC4.3 IfcRigidOperation with plane angles, already converted from the angle unit).
    pub geographic: bool,
}

/// The entity that carries a file's placement in map coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MapOperation {
    /// IfcMapConversion (or IfcMapConversionScaled) and its IfcProjectedCRS.
    #[default]
    MapConversion,
    /// IFC4.3 IfcRigidOperation: a translation only, into a projected or geographic CRS.
    RigidOperation,
    /// IFC2X3 property sets ePSet_MapConversion and ePSet_ProjectedCRS (on IfcProject or
    /// IfcSite).
    PropertySets,
}

/// Where the model sits on Earth, as the IFC file says.
#[derive(Debug, Clone, PartialEq)]
pub struct IfcGeoref {
    /// IfcSite.RefLongitude (WGS84 degrees, east positive).
    pub longitude_deg: f64,
    /// IfcSite.RefLatitude (WGS84 degrees, north positive).
    pub latitude_deg: f64,
    /// IfcSite.RefElevation (metres; 0 when absent).
    pub height_m: f64,
    /// Direction of true north, degrees counter-clockwise from the project +y axis (from the model
    /// context's TrueNorth (x, y): atan2(−x, y)). To turn the scene so +y is true north, rotate it
    /// by −true_north_deg about z.
    pub true_north_deg: Option<f64>,
    pub map_conversion: Option<IfcMapConversion>,
    /// The scene-frame point (metres, z-up) that the longitude/latitude/height refer to: the
    /// IfcSite placement's origin (the project origin for a map conversion).
    pub anchor: DVec3,
    /// A map conversion used: project metres → local east-north-up metres (rotation, scales,
    /// convergence and grid scale factor).
    pub map_linear: Option<glam::DMat3>,
    /// The CRS that placed the model, for the report.
    pub crs: Option<crate::geodesy::crs::CrsUse>,
    /// The field that named that CRS.
    pub crs_field: Option<CrsField>,
    /// Scene metres → map coordinates of `crs` (easting, northing in its units, height in
    /// metres), when one linear map at the anchor would be off by more than a millimetre
    /// somewhere in the model: then every vertex goes through PROJ instead.
    pub per_vertex_map: Option<DMat4>,
}

/// Read timings, seconds.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct IfcTimings {
    /// Our STEP well-formedness check.
    pub check_s: f64,
    /// ifc-lite: parse + triangulate.
    pub geometry_s: f64,
    /// ifc-lite: properties, relationships, materials.
    pub data_model_s: f64,
    /// Georeference read + building the scene.
    pub assemble_s: f64,
}

/// What [`read_ifc_with_report`] tells besides the scene.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct IfcReadReport {
    /// FILE_SCHEMA as written (e.g. "IFC4", "IFC2X3").
    pub schema: String,
    /// Components made.
    pub elements: usize,
    pub triangles: usize,
    /// Elements with a representation that gave no usable triangles (guid, class, reason).
    pub skipped: Vec<SkippedElement>,
    /// Elements of the classes in [`SKIPPED_CLASSES`] that had geometry, by class.
    pub excluded_by_class: BTreeMap<String, usize>,
    pub georef: Option<IfcGeoref>,
    /// A georeference the file asked for that could not be used (the model falls back to its
    /// site reference or the default placement).
    pub georef_warning: Option<String>,
    /// Products left out because their only geometry is a curve (IfcAlignment axes and the like).
    pub curve_only: usize,
    pub timings: IfcTimings,
}

/// Reads one IFC file into a new scene.
pub fn read_ifc(path: &Path) -> Result<Scene> {
    read_ifc_with_report(path).map(|(s, _)| s)
}

/// Reads IFC bytes; `path` names the file in errors and in `Scene::sources`.
pub fn read_ifc_bytes(path: &Path, bytes: &[u8]) -> Result<Scene> {
    read_ifc_bytes_with_report(path, bytes).map(|(s, _)| s)
}

/// Reads one IFC file and reports skipped elements, georeference and timings.
pub fn read_ifc_with_report(path: &Path) -> Result<(Scene, IfcReadReport)> {
    let bytes = super::read_regular(path).map_err(|e| Error::input_from(path, "cannot read", e))?;
    read_ifc_bytes_with_report(path, &bytes)
}

/// The georeference of an IFC file (IfcSite RefLatitude/RefLongitude/RefElevation, true north,
/// IfcMapConversion); `None` when the site has no reference latitude/longitude or the file cannot be
/// read. An IfcMapConversion whose CRS PROJ knows wins over the site reference
/// ([`crate::geodesy::crs`]); one that cannot be used is a warning in the result.
pub fn read_ifc_georef(path: &Path) -> Option<IfcGeoref> {
    let bytes = super::read_regular(path).ok()?;
    check_step(&bytes).ok()?;
    let engine = engine::IfcLite;
    let raw = guarded(IfcStage::Georef, || {
        engine::IfcEngine::georef(&engine, &bytes)
    })
    .ok()?;
    georef_from_raw(raw, path, None, &Aabb::EMPTY).georef
}

/// Like [`read_ifc_with_report`], from bytes.
pub fn read_ifc_bytes_with_report(path: &Path, bytes: &[u8]) -> Result<(Scene, IfcReadReport)> {
    read_ifc_bytes_with_crs(path, bytes, None)
}

/// Like [`read_ifc_with_report`]; `crs_option` (`--crs`) names the CRS of an IfcMapConversion
/// whose IfcProjectedCRS names none PROJ knows.
pub fn read_ifc_with_crs(path: &Path, crs_option: Option<&str>) -> Result<(Scene, IfcReadReport)> {
    let bytes = super::read_regular(path).map_err(|e| Error::input_from(path, "cannot read", e))?;
    read_ifc_bytes_with_crs(path, &bytes, crs_option)
}

/// Like [`read_ifc_with_crs`], from bytes.
pub fn read_ifc_bytes_with_crs(
    path: &Path,
    bytes: &[u8],
    crs_option: Option<&str>,
) -> Result<(Scene, IfcReadReport)> {
    let t0 = Instant::now();
    // The STEP and IFC errors name the problem themselves: "<file>: <problem>".
    let header = check_step(bytes).map_err(|e| Error::input_from(path, "", e))?;
    let check_s = t0.elapsed().as_secs_f64();

    let engine = engine::IfcLite;
    // The geometry is read on a thread of its own while this one reads the georeference and
    // opens PROJ for its CRS (this thread places the model afterwards, with that context).
    let (geometry, geometry_s, raw_georef) = std::thread::scope(|scope| {
        let geometry = scope.spawn(|| {
            let t1 = Instant::now();
            let g = guarded(IfcStage::Geometry, || {
                engine::IfcEngine::geometry(&engine, bytes)
            });
            (g, t1.elapsed().as_secs_f64())
        });
        let raw_georef = guarded(IfcStage::Georef, || {
            engine::IfcEngine::georef(&engine, bytes)
        })
        .ok();
        if let Some(raw) = &raw_georef {
            georef::warm_up_proj(raw, crs_option);
        }
        let (g, geometry_s) = geometry
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        (g, geometry_s, raw_georef)
    });
    let geometry = geometry.map_err(|e| Error::input_from(path, "", e))?;
    let t2 = Instant::now();
    let data = guarded(IfcStage::DataModel, || {
        engine::IfcEngine::data_model(&engine, bytes)
    })
    .map_err(|e| Error::input_from(path, "", e))?;
    let data_model_s = t2.elapsed().as_secs_f64();

    let t3 = Instant::now();
    let conversion = raw_georef.as_ref().and_then(|r| r.map_conversion.as_ref());
    if let Some(problem) = conversion.and_then(georef::implausible_map_number) {
        return Err(Error::input(path, problem));
    }
    let mut report = IfcReadReport {
        schema: header.schema.clone(),
        curve_only: geometry.curve_only.len(),
        ..Default::default()
    };
    let mut scene = assemble(path, bytes.len() as u64, geometry, data, &mut report)?;
    scene.finish();
    // The model's own box decides the anchor and where the CRS's area of use is checked.
    if let Some(raw) = raw_georef {
        let placed = georef_from_raw(raw, path, crs_option, &scene.bounds());
        report.georef = placed.georef;
        report.georef_warning = placed.warning;
        scene.reader_warnings.extend(placed.notes);
    }
    report.elements = scene.components.len();
    report.triangles = scene.triangle_count();
    report.timings = IfcTimings {
        check_s,
        geometry_s,
        data_model_s,
        assemble_s: t3.elapsed().as_secs_f64(),
    };
    for s in &report.skipped {
        scene.reader_warnings.push(format!(
            "{}: skipped {} {} ({})",
            path.display(),
            s.class,
            s.guid,
            s.reason
        ));
    }
    Ok((scene, report))
}

/// The IFC kernel failed on a file that passed the STEP check.
#[derive(Debug, thiserror::Error)]
pub enum IfcError {
    /// The project's length unit cannot be turned into metres.
    #[error("unusable length unit (#{entity}): no geometry can be scaled")]
    UnusableLengthUnit { entity: u32 },
    /// ifc-lite panicked during `stage`; `message` is the panic's text.
    #[error("{stage} failed: the IFC library crashed on this file ({message})")]
    Crashed { stage: IfcStage, message: String },
}

/// A call into the IFC kernel, to say which one failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IfcStage {
    Geometry,
    DataModel,
    Georef,
}

impl std::fmt::Display for IfcStage {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str(match self {
            IfcStage::Geometry => "IFC geometry",
            IfcStage::DataModel => "IFC property extraction",
            IfcStage::Georef => "IFC georeference",
        })
    }
}

/// Runs the kernel call `f`, turning a panic into [`IfcError::Crashed`] (ifc-lite is not
/// guaranteed panic-free on malformed input).
fn guarded<T>(
    stage: IfcStage,
    f: impl FnOnce() -> std::result::Result<T, IfcError>,
) -> std::result::Result<T, IfcError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).unwrap_or_else(|p| {
        Err(IfcError::Crashed {
            stage,
            message: crate::error::panic_message(p.as_ref()),
        })
    })
}

#[cfg(test)]
mod tests {
    use super::assembly::typed_value;
    use super::*;

    const MINI: &str = "ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION((''),'2;1');\nFILE_NAME('a','',(''),(''),'','','');\nFILE_SCHEMA(('IFC4'));\nENDSEC;\nDATA;\n#1=IFCCARTESIANPOINT((0.,0.,0.));\n#2=IFCAXIS2PLACEMENT3D(#1,$,$);\n/* comment ; with #99 */\n#3=IFCLABEL('it''s #7; fine');\nENDSEC;\nEND-ISO-10303-21;\n";

    #[test]
    fn step_check_accepts_and_rejects() {
        let s = check_step(MINI.as_bytes()).unwrap();
        assert_eq!(s.schema, "IFC4");
        assert_eq!(s.entities, 3);
        let trunc = &MINI[..MINI.len() / 2 + 40];
        assert!(check_step(trunc.as_bytes())
            .unwrap_err()
            .to_string()
            .contains("truncated"));
        assert!(check_step(b"").unwrap_err().to_string().contains("empty"));
        assert!(check_step(b"hello world")
            .unwrap_err()
            .to_string()
            .contains("not an IFC"));
        let unk = MINI.replace("'IFC4'", "'IFC9X9'");
        assert!(matches!(
            check_step(unk.as_bytes()).unwrap_err(),
            StepError::UnknownSchema { schema } if schema == "IFC9X9"
        ));
        let broken = MINI.replace("#2=IFCAXIS2PLACEMENT3D(#1", "#2=IFCAXIS2PLACEMENT3D(#42");
        let e = check_step(broken.as_bytes()).unwrap_err().to_string();
        assert!(e.contains("#2 refers to #42"), "{e}");
        let garbage = MINI.replace("#3=IFCLABEL", "garbage #3=IFCLABEL");
        assert!(check_step(garbage.as_bytes())
            .unwrap_err()
            .to_string()
            .contains("malformed"));
    }

    #[test]
    fn a_kernel_panic_becomes_a_typed_error() {
        let e = guarded::<()>(IfcStage::Geometry, || panic!("boom")).unwrap_err();
        assert!(
            matches!(&e, IfcError::Crashed { stage: IfcStage::Geometry, message } if message == "boom")
        );
        assert_eq!(
            e.to_string(),
            "IFC geometry failed: the IFC library crashed on this file (boom)"
        );
        let e = Error::input_from("a.ifc", "", e);
        assert_eq!(
            crate::error::chain_text(&e),
            "a.ifc: IFC geometry failed: the IFC library crashed on this file (boom)"
        );
        assert_eq!(guarded(IfcStage::Georef, || Ok(3)).unwrap(), 3);
    }

    #[test]
    fn values_are_typed() {
        use engine::{RawValue, ValueKind as K};
        let v = |t: &str, k| {
            typed_value(&RawValue {
                text: t.into(),
                kind: k,
            })
        };
        assert_eq!(v("true", K::Bool), Some(PropertyValue::Bool(true)));
        assert_eq!(
            v("", K::Logical),
            Some(PropertyValue::Text("UNKNOWN".into()))
        );
        assert_eq!(v("12", K::Integer), Some(PropertyValue::Integer(12)));
        assert_eq!(v("1.5", K::Real), Some(PropertyValue::Number(1.5)));
        assert_eq!(v("1.5", K::Text), Some(PropertyValue::Text("1.5".into())));
        assert_eq!(v("", K::Null), None);
        assert_eq!(parse_loose("FALSE"), PropertyValue::Bool(false));
        assert_eq!(parse_loose("1.5"), PropertyValue::Number(1.5));
        assert_eq!(parse_loose("-3"), PropertyValue::Integer(-3));
        assert_eq!(
            parse_loose("NOTDEFINED"),
            PropertyValue::Text("NOTDEFINED".into())
        );
        assert_eq!(parse_loose("inf"), PropertyValue::Text("inf".into()));
    }
}
