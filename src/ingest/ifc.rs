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
    /// IfcSite placement's origin.
    pub anchor: DVec3,
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
    let bytes = std::fs::read(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
    read_ifc_bytes_with_report(path, &bytes)
}

/// The georeference of an IFC file (IfcSite RefLatitude/RefLongitude/RefElevation, true north,
/// IfcMapConversion); `None` when the site has no reference latitude/longitude or the file cannot be
/// read. A file with only an IfcMapConversion is placed from it when its CRS is UTM
/// ([`crate::geodesy::projection`]); other CRSs give `None`.
pub fn read_ifc_georef(path: &Path) -> Option<IfcGeoref> {
    let bytes = std::fs::read(path).ok()?;
    check_step(&bytes).ok()?;
    let engine = engine::IfcLite;
    let raw = guarded(|| engine::IfcEngine::georef(&engine, &bytes))
        .ok()?
        .ok()?;
    georef_from_raw(raw)
}

/// Like [`read_ifc_with_report`], from bytes.
pub fn read_ifc_bytes_with_report(path: &Path, bytes: &[u8]) -> Result<(Scene, IfcReadReport)> {
    let t0 = Instant::now();
    let header = check_step(bytes).map_err(|m| Error::input(path, m))?;
    let check_s = t0.elapsed().as_secs_f64();

    let engine = engine::IfcLite;
    let t1 = Instant::now();
    let geometry = guarded(|| engine::IfcEngine::geometry(&engine, bytes))
        .map_err(|m| Error::input(path, format!("IFC geometry failed: {m}")))?
        .map_err(|m| Error::input(path, m))?;
    let geometry_s = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    let data = guarded(|| engine::IfcEngine::data_model(&engine, bytes))
        .map_err(|m| Error::input(path, format!("IFC property extraction failed: {m}")))?
        .map_err(|m| Error::input(path, m))?;
    let data_model_s = t2.elapsed().as_secs_f64();

    let t3 = Instant::now();
    let georef = guarded(|| engine::IfcEngine::georef(&engine, bytes))
        .ok()
        .and_then(|r| r.ok())
        .and_then(georef_from_raw);
    let mut report = IfcReadReport {
        schema: header.schema.clone(),
        georef,
        ..Default::default()
    };
    let mut scene = assemble(path, bytes.len() as u64, geometry, data, &mut report)?;
    scene.finish();
    report.elements = scene.components.len();
    report.triangles = scene.triangle_count();
    report.timings = IfcTimings {
        check_s,
        geometry_s,
        data_model_s,
        assemble_s: t3.elapsed().as_secs_f64(),
    };
    for s in &report.skipped {
        eprintln!(
            "warning: {}: skipped {} {} ({})",
            path.display(),
            s.class,
            s.guid,
            s.reason
        );
    }
    Ok((scene, report))
}

/// Runs `f`, turning a panic into an error message (ifc-lite is not guaranteed panic-free on
/// malformed input).
fn guarded<T>(f: impl FnOnce() -> T) -> std::result::Result<T, String> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).map_err(|p| {
        let msg = p
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".into());
        format!("the IFC library crashed on this file ({msg})")
    })
}

fn georef_from_raw(raw: engine::RawGeoref) -> Option<IfcGeoref> {
    let Some((lat, lon, h)) = raw.site_reference else {
        return raw
            .map_conversion
            .as_ref()
            .and_then(georef_from_map_conversion);
    };
    if !(lat.is_finite()
        && lon.is_finite()
        && (-90.0..=90.0).contains(&lat)
        && (-180.0..=360.0).contains(&lon))
    {
        return None;
    }
    let lon = if lon > 180.0 { lon - 360.0 } else { lon };
    Some(IfcGeoref {
        longitude_deg: lon,
        latitude_deg: lat,
        height_m: if h.is_finite() { h } else { 0.0 },
        true_north_deg: raw
            .true_north
            .filter(|n| n[0].is_finite() && n[1].is_finite() && (n[0] != 0.0 || n[1] != 0.0))
            .map(|n| (-n[0]).atan2(n[1]).to_degrees()),
        map_conversion: raw.map_conversion,
        anchor: raw.site_origin,
    })
}

/// A file without IfcSite reference coordinates but with an IfcMapConversion in a UTM CRS: the
/// project origin is at (Eastings, Northings, OrthogonalHeight); the project's x axis points along
/// (XAxisAbscissa, XAxisOrdinate) in the map grid, and grid north is turned from true north by the
/// meridian convergence there. Other CRSs give `None` (the caller then says no georeference).
fn georef_from_map_conversion(m: &IfcMapConversion) -> Option<IfcGeoref> {
    use crate::geodesy::projection::{utm_to_wgs84, UtmZone};
    let zone = UtmZone::from_crs_name(m.crs_name.as_deref()?)?;
    if !(m.eastings.is_finite() && m.northings.is_finite()) {
        return None;
    }
    let (lat, lon, convergence_deg) = utm_to_wgs84(zone, m.eastings, m.northings);
    if !(lat.is_finite() && lon.is_finite()) {
        return None;
    }
    // Grid north seen from the project: −θ from +y, θ the x axis's angle from grid east. True
    // north is grid north turned back by the convergence.
    let theta_deg = if m.x_axis_abscissa == 0.0 && m.x_axis_ordinate == 0.0 {
        0.0
    } else {
        m.x_axis_ordinate.atan2(m.x_axis_abscissa).to_degrees()
    };
    Some(IfcGeoref {
        longitude_deg: lon,
        latitude_deg: lat,
        height_m: if m.orthogonal_height.is_finite() {
            m.orthogonal_height
        } else {
            0.0
        },
        true_north_deg: Some(convergence_deg - theta_deg).filter(|d| d.abs() > 1e-12),
        map_conversion: Some(m.clone()),
        anchor: DVec3::ZERO,
    })
}

// ------------------------------------------------------------------------------------------------
// STEP check (ours, independent of the IFC library)
// ------------------------------------------------------------------------------------------------

/// What the STEP check learnt about the file.
#[derive(Debug, Clone)]
pub struct StepSummary {
    pub schema: String,
    pub entities: usize,
}

/// Schemas ifc-lite 28 reads (prefix match on FILE_SCHEMA, upper case).
const KNOWN_SCHEMAS: &[&str] = &["IFC2X3", "IFC4X1", "IFC4X2", "IFC4X3", "IFC4"];

fn line_of(bytes: &[u8], offset: usize) -> usize {
    1 + bytes[..offset.min(bytes.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
}

fn find(hay: &[u8], needle: &[u8], from: usize) -> Option<usize> {
    if from >= hay.len() {
        return None;
    }
    hay[from..]
        .windows(needle.len())
        .position(|w| w.eq_ignore_ascii_case(needle))
        .map(|p| p + from)
}

/// Checks that `bytes` is a complete, well-formed IFC STEP file: header, known schema, DATA
/// records `#id=TYPE(...);` with balanced parentheses and closed strings, trailer, no reference
/// to an undefined `#id`. Returns the problem as a sentence naming its line.
pub fn check_step(bytes: &[u8]) -> std::result::Result<StepSummary, String> {
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace() && *b != 0xEF && *b != 0xBB && *b != 0xBF)
        .ok_or("empty file")?;
    let body = &bytes[start..];
    if !body.starts_with(b"ISO-10303-21;") {
        return Err(if body.starts_with(b"PK") {
            "looks like a zip archive (.ifczip?): unzip it first".into()
        } else if body.starts_with(b"{") {
            "looks like JSON (IFC5/ifcJSON?), which is not supported: expected an IFC STEP file"
                .into()
        } else if body.starts_with(b"<") {
            "looks like XML (ifcXML?), which is not supported: expected an IFC STEP file".into()
        } else {
            "not an IFC file: it does not start with the STEP header 'ISO-10303-21;'".into()
        });
    }
    let hdr_end =
        find(bytes, b"ENDSEC;", start).ok_or("truncated or malformed: no end of HEADER section")?;
    let header = &bytes[start..hdr_end];
    let fs = find(header, b"FILE_SCHEMA", 0).ok_or("malformed header: no FILE_SCHEMA")?;
    let q1 = header[fs..]
        .iter()
        .position(|&b| b == b'\'')
        .map(|p| p + fs)
        .ok_or("malformed FILE_SCHEMA")?;
    let q2 = header[q1 + 1..]
        .iter()
        .position(|&b| b == b'\'')
        .map(|p| p + q1 + 1)
        .ok_or("malformed FILE_SCHEMA")?;
    let schema = String::from_utf8_lossy(&header[q1 + 1..q2])
        .trim()
        .to_string();
    let up = schema.to_ascii_uppercase();
    if !KNOWN_SCHEMAS.iter().any(|k| up.starts_with(k)) {
        return Err(format!(
            "unknown IFC schema '{schema}' (bimtiles reads IFC2X3, IFC4, IFC4X1, IFC4X2 and IFC4X3)"
        ));
    }
    let data = find(bytes, b"DATA;", hdr_end).ok_or("truncated: no DATA section")?;
    let mut i = data + 5;
    let n = bytes.len();
    // Pass 1: records and definitions; references go to a list checked afterwards.
    let mut defined: Vec<u64> = Vec::new(); // bitset by id
    let mut defined_big: HashSet<u64> = HashSet::new();
    let mut refs: Vec<(u32, u32)> = Vec::new(); // (ref id, offset / 16) compact: ids only to check
    let mut ref_offsets_first_bad: Option<usize> = None;
    let mut entities = 0usize;
    let mut ended = false;
    let set_def = |id: u64, defined: &mut Vec<u64>, big: &mut HashSet<u64>| {
        if id < (1 << 31) {
            let w = (id / 64) as usize;
            if w >= defined.len() {
                defined.resize(w + 1, 0);
            }
            defined[w] |= 1 << (id % 64);
        } else {
            big.insert(id);
        }
    };
    let skip_ws_comments = |mut i: usize| -> std::result::Result<usize, String> {
        loop {
            while i < n && bytes[i].is_ascii_whitespace() {
                i += 1;
            }
            if i + 1 < n && bytes[i] == b'/' && bytes[i + 1] == b'*' {
                match find(bytes, b"*/", i + 2) {
                    Some(e) => i = e + 2,
                    None => {
                        return Err(format!(
                            "truncated: unclosed comment at line {}",
                            line_of(bytes, i)
                        ))
                    }
                }
            } else {
                return Ok(i);
            }
        }
    };
    while i < n {
        i = skip_ws_comments(i)?;
        if i >= n {
            break;
        }
        if bytes[i..].len() >= 7 && bytes[i..i + 7].eq_ignore_ascii_case(b"ENDSEC;") {
            ended = true;
            i += 7;
            break;
        }
        let rec_start = i;
        if bytes[i] != b'#' {
            return Err(format!(
                "malformed record at line {}: expected '#id=' or ENDSEC;",
                line_of(bytes, i)
            ));
        }
        i += 1;
        let ds = i;
        let mut id: u64 = 0;
        while i < n && bytes[i].is_ascii_digit() {
            id = id
                .saturating_mul(10)
                .saturating_add((bytes[i] - b'0') as u64);
            i += 1;
        }
        if i == ds {
            return Err(format!(
                "malformed record at line {}: '#' without a number",
                line_of(bytes, rec_start)
            ));
        }
        i = skip_ws_comments(i)?;
        if i >= n || bytes[i] != b'=' {
            return Err(format!(
                "malformed record #{id} at line {}: expected '='",
                line_of(bytes, rec_start)
            ));
        }
        i += 1;
        // Body up to the ';' at depth 0 outside strings.
        let mut depth: i64 = 0;
        let mut in_str = false;
        let mut saw_paren = false;
        let mut closed = false;
        while i < n {
            let b = bytes[i];
            if in_str {
                if b == b'\'' {
                    in_str = false;
                }
                i += 1;
                continue;
            }
            match b {
                b'\'' => in_str = true,
                b'(' => {
                    depth += 1;
                    saw_paren = true;
                }
                b')' => {
                    depth -= 1;
                    if depth < 0 {
                        return Err(format!(
                            "malformed record #{id} at line {}: unbalanced ')'",
                            line_of(bytes, rec_start)
                        ));
                    }
                }
                b'/' if i + 1 < n && bytes[i + 1] == b'*' => match find(bytes, b"*/", i + 2) {
                    Some(e) => {
                        i = e + 2;
                        continue;
                    }
                    None => {
                        return Err(format!(
                            "truncated: unclosed comment at line {}",
                            line_of(bytes, i)
                        ))
                    }
                },
                b'#' => {
                    let mut j = i + 1;
                    let mut r: u64 = 0;
                    while j < n && bytes[j].is_ascii_digit() {
                        r = r
                            .saturating_mul(10)
                            .saturating_add((bytes[j] - b'0') as u64);
                        j += 1;
                    }
                    if j > i + 1 {
                        if r <= u32::MAX as u64 {
                            refs.push((r as u32, id.min(u32::MAX as u64) as u32));
                        } else if ref_offsets_first_bad.is_none() {
                            ref_offsets_first_bad = Some(rec_start);
                        }
                    }
                    i = j;
                    continue;
                }
                b';' => {
                    if depth != 0 {
                        return Err(format!(
                            "malformed record #{id} at line {}: unbalanced parentheses",
                            line_of(bytes, rec_start)
                        ));
                    }
                    closed = true;
                    i += 1;
                    break;
                }
                _ => {}
            }
            i += 1;
        }
        if !closed {
            return Err(format!(
                "truncated: record #{id} at line {} is not terminated (the file ends inside it)",
                line_of(bytes, rec_start)
            ));
        }
        if !saw_paren || depth != 0 {
            return Err(format!(
                "malformed record #{id} at line {}: no attribute list",
                line_of(bytes, rec_start)
            ));
        }
        set_def(id, &mut defined, &mut defined_big);
        entities += 1;
    }
    if !ended {
        return Err("truncated: the DATA section has no ENDSEC;".into());
    }
    if find(bytes, b"END-ISO-10303-21", i).is_none() {
        return Err("truncated: no 'END-ISO-10303-21;' trailer".into());
    }
    if entities == 0 {
        return Err("the DATA section holds no entities".into());
    }
    if let Some(off) = ref_offsets_first_bad {
        return Err(format!(
            "malformed record at line {}: reference number out of range",
            line_of(bytes, off)
        ));
    }
    let is_def = |r: u32| -> bool {
        let r = r as u64;
        let w = (r / 64) as usize;
        (w < defined.len() && defined[w] & (1 << (r % 64)) != 0) || defined_big.contains(&r)
    };
    let mut bad = refs.iter().filter(|(r, _)| !is_def(*r));
    if let Some(&(r, from)) = bad.next() {
        let more = bad.count();
        return Err(format!(
            "broken reference: #{from} refers to #{r}, which is not defined{}",
            if more > 0 {
                format!(" ({more} more broken references)")
            } else {
                String::new()
            }
        ));
    }
    Ok(StepSummary { schema, entities })
}

// ------------------------------------------------------------------------------------------------
// Scene assembly (ours, on plain data)
// ------------------------------------------------------------------------------------------------

fn skip_reason(class: &str) -> Option<&'static str> {
    SKIPPED_CLASSES
        .iter()
        .find(|(c, _)| c.eq_ignore_ascii_case(class))
        .map(|(_, r)| *r)
}

fn is_storey(c: &str) -> bool {
    c.eq_ignore_ascii_case("IfcBuildingStorey")
}
fn is_building(c: &str) -> bool {
    [
        "IfcBuilding",
        "IfcFacility",
        "IfcBridge",
        "IfcRoad",
        "IfcRailway",
        "IfcMarineFacility",
        "IfcTunnel",
    ]
    .iter()
    .any(|k| k.eq_ignore_ascii_case(c))
}
fn is_site(c: &str) -> bool {
    c.eq_ignore_ascii_case("IfcSite")
}
fn is_project(c: &str) -> bool {
    c.eq_ignore_ascii_case("IfcProject")
}

/// Types a property value the IFC library gave as text.
fn typed_value(v: &engine::RawValue) -> Option<PropertyValue> {
    use engine::ValueKind as K;
    let t = v.text.trim();
    Some(match v.kind {
        K::Null => return None,
        K::Bool | K::Logical => match t.to_ascii_lowercase().as_str() {
            "true" | ".t." | "t" => PropertyValue::Bool(true),
            "false" | ".f." | "f" => PropertyValue::Bool(false),
            "" | "unknown" | ".u." => PropertyValue::Text("UNKNOWN".into()),
            _ => PropertyValue::Text(t.to_string()),
        },
        K::Integer => t
            .parse::<i64>()
            .map(PropertyValue::Integer)
            .or_else(|_| t.parse::<f64>().map(PropertyValue::Number))
            .unwrap_or_else(|_| PropertyValue::Text(t.to_string())),
        K::Real => t
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .map(PropertyValue::Number)
            .unwrap_or_else(|| PropertyValue::Text(t.to_string())),
        K::Text => PropertyValue::Text(v.text.clone()),
        K::Unknown => parse_loose(t),
    })
}

/// Types text whose IFC type is not known: ".T."/"TRUE" → Bool, "12" → Integer, "1.5" → Number,
/// anything else (including enumerations) → Text.
pub fn parse_loose(t: &str) -> PropertyValue {
    let t = t.trim();
    match t.to_ascii_uppercase().as_str() {
        "TRUE" | ".T." => return PropertyValue::Bool(true),
        "FALSE" | ".F." => return PropertyValue::Bool(false),
        _ => {}
    }
    if let Ok(i) = t.parse::<i64>() {
        return PropertyValue::Integer(i);
    }
    if t.chars().any(|c| c.is_ascii_digit()) {
        if let Ok(x) = t.parse::<f64>() {
            if x.is_finite() {
                return PropertyValue::Number(x);
            }
        }
    }
    PropertyValue::Text(t.to_string())
}

struct Builder<'a> {
    scene: Scene,
    data: &'a engine::RawData,
    parent: HashMap<u32, u32>,
    node_of: HashMap<u32, NodeId>,
    materials: HashMap<([u32; 4], Option<String>), MaterialId>,
    /// element → its type object.
    type_of: HashMap<u32, u32>,
    /// set id → (set name, properties) and object → set ids.
    sets_of: HashMap<u32, Vec<u32>>,
    materials_of: HashMap<u32, Vec<String>>,
    /// Repeated metadata text (classes, storeys, property names), one copy each.
    texts: std::cell::RefCell<TextInterner>,
}

impl<'a> Builder<'a> {
    fn shared(&self, s: &str) -> SharedText {
        self.texts.borrow_mut().get(s)
    }

    fn entity(&self, id: u32) -> Option<&engine::RawEntity> {
        self.data.entities.get(&id)
    }

    /// The node of `id` (a spatial structure element or an aggregate parent), creating it and its
    /// ancestors; `None` for the project and for unknown ids.
    fn node(&mut self, id: u32, depth: usize) -> Option<NodeId> {
        if let Some(n) = self.node_of.get(&id) {
            return Some(*n);
        }
        let e = self.entity(id)?;
        if is_project(&e.class) || depth > 64 {
            return None;
        }
        let name = e
            .name
            .clone()
            .filter(|s| !s.is_empty())
            .or_else(|| e.guid.clone())
            .unwrap_or_else(|| format!("{}#{id}", e.class));
        let extras = serde_json::value::to_raw_value(
            &serde_json::json!({"ifc_class": e.class, "guid": e.guid}),
        )
        .ok();
        let parent = self.parent.get(&id).copied();
        let parent_node = parent.and_then(|p| self.node(p, depth + 1));
        let nid = NodeId(self.scene.nodes.len() as u32);
        self.scene.nodes.push(Node {
            name: Some(name),
            parent: parent_node,
            extras,
            name_repeat: 0,
        });
        self.node_of.insert(id, nid);
        Some(nid)
    }

    /// (storey, building, site) names above `id`.
    fn containers(&self, id: u32) -> (Option<String>, Option<String>, Option<String>) {
        let (mut st, mut b, mut s) = (None, None, None);
        let mut cur = self.parent.get(&id).copied();
        let mut steps = 0;
        while let Some(p) = cur {
            steps += 1;
            if steps > 64 {
                break;
            }
            if let Some(e) = self.entity(p) {
                let name = || e.name.clone().filter(|n| !n.is_empty());
                if st.is_none() && is_storey(&e.class) {
                    st = name();
                } else if b.is_none() && is_building(&e.class) {
                    b = name();
                } else if s.is_none() && is_site(&e.class) {
                    s = name();
                }
            }
            cur = self.parent.get(&p).copied();
        }
        (st, b, s)
    }

    fn properties(&self, id: u32) -> Vec<Property> {
        let mut out: Vec<Property> = Vec::new();
        let mut seen: HashSet<(String, String)> = HashSet::new();
        let mut owners = vec![id];
        if let Some(t) = self.type_of.get(&id) {
            owners.push(*t); // the element's own values first: they win
        }
        for owner in owners {
            for sid in self.sets_of.get(&owner).into_iter().flatten() {
                let Some(set) = self.data.sets.get(sid) else {
                    continue;
                };
                for (name, v) in &set.values {
                    let Some(value) = typed_value(v) else {
                        continue;
                    };
                    if seen.insert((set.name.clone(), name.clone())) {
                        out.push(Property {
                            set: self.shared(&set.name),
                            name: self.shared(name),
                            value,
                        });
                    }
                }
            }
        }
        out
    }

    fn material_name(&self, id: u32) -> Option<String> {
        let names = self
            .materials_of
            .get(&id)
            .or_else(|| self.type_of.get(&id).and_then(|t| self.materials_of.get(t)))?;
        let mut uniq: Vec<&str> = Vec::new();
        for n in names {
            if !n.is_empty() && !uniq.contains(&n.as_str()) {
                uniq.push(n);
            }
        }
        (!uniq.is_empty()).then(|| uniq.join(", "))
    }

    fn material(&mut self, color: [f32; 4], name: Option<String>) -> MaterialId {
        let c = color.map(|x| {
            if x.is_finite() {
                x.clamp(0.0, 1.0)
            } else {
                1.0
            }
        });
        let key = (c.map(f32::to_bits), name.clone());
        if let Some(m) = self.materials.get(&key) {
            return *m;
        }
        let id = MaterialId(self.scene.materials.len() as u32);
        self.scene.materials.push(Material {
            name,
            base_color: c,
            metallic: 0.0,
            roughness: IFC_ROUGHNESS,
            alpha_mode: if c[3] < 1.0 {
                AlphaMode::Blend
            } else {
                AlphaMode::Opaque
            },
            double_sided: c[3] < 1.0,
            ..Material::default()
        });
        self.materials.insert(key, id);
        id
    }
}

/// Area-weighted vertex normals for a triangle list.
fn vertex_normals(pos: &[[f32; 3]], idx: &[u32]) -> Vec<[f32; 3]> {
    let mut acc = vec![glam::Vec3::ZERO; pos.len()];
    for t in idx.chunks_exact(3) {
        let [a, b, c] = [t[0], t[1], t[2]].map(|i| glam::Vec3::from(pos[i as usize]));
        let n = (b - a).cross(c - a);
        for &i in t {
            acc[i as usize] += n;
        }
    }
    acc.into_iter()
        .map(|n| n.try_normalize().unwrap_or(glam::Vec3::Z).to_array())
        .collect()
}

fn assemble(
    path: &Path,
    file_bytes: u64,
    geom: engine::RawGeometry,
    data: engine::RawData,
    report: &mut IfcReadReport,
) -> Result<Scene> {
    let mut b = Builder {
        scene: Scene::default(),
        data: &data,
        parent: HashMap::new(),
        node_of: HashMap::new(),
        materials: HashMap::new(),
        type_of: HashMap::new(),
        sets_of: HashMap::new(),
        materials_of: HashMap::new(),
        texts: Default::default(),
    };
    b.scene.sources.push(SourceFile {
        path: path.to_path_buf(),
        bytes: file_bytes,
    });
    // Relationships: the parent of each object (aggregation > containment > nesting), types,
    // property sets, materials.
    let mut rank: HashMap<u32, u8> = HashMap::new();
    for r in &data.rels {
        use engine::RelKind as R;
        let prio = match r.kind {
            R::Aggregates => 3,
            R::Contains => 2,
            R::Nests => 1,
            R::DefinesByType => {
                b.type_of.entry(r.related).or_insert(r.relating);
                continue;
            }
            R::DefinesByProperties | R::TypeHasSet => {
                b.sets_of.entry(r.related).or_default().push(r.relating);
                continue;
            }
        };
        if r.related == r.relating {
            continue;
        }
        let cur = rank.get(&r.related).copied().unwrap_or(0);
        if prio > cur {
            rank.insert(r.related, prio);
            b.parent.insert(r.related, r.relating);
        }
    }
    for (el, name) in &data.materials {
        b.materials_of.entry(*el).or_default().push(name.clone());
    }

    let frame = geom.frame_to_world;
    for el in geom.elements {
        let class = el.class.clone();
        let guid = el
            .guid
            .clone()
            .unwrap_or_else(|| format!("#{}", el.express_id));
        if let Some(_r) = skip_reason(&class) {
            *report.excluded_by_class.entry(class).or_default() += 1;
            continue;
        }
        // Frame-space box of the element, f64.
        let mut bx = Aabb::EMPTY;
        let mut bad: Option<String> = None;
        for p in &el.pieces {
            if p.positions.len() % 3 != 0 || p.indices.len() % 3 != 0 {
                bad = Some("malformed triangle data".into());
                break;
            }
            let nv = (p.positions.len() / 3) as u32;
            if let Some(i) = p.indices.iter().find(|&&i| i >= nv) {
                bad = Some(format!("index {i} out of range ({nv} vertices)"));
                break;
            }
            for v in p.positions.chunks_exact(3) {
                if !v.iter().all(|x| x.is_finite()) || !p.origin.iter().all(|x| x.is_finite()) {
                    bad = Some("non-finite vertex coordinates".into());
                    break;
                }
                bx.extend(DVec3::new(
                    p.origin[0] + v[0] as f64,
                    p.origin[1] + v[1] as f64,
                    p.origin[2] + v[2] as f64,
                ));
            }
        }
        let tris: usize = el.pieces.iter().map(|p| p.indices.len() / 3).sum();
        if bad.is_none() && (tris == 0 || bx.is_empty()) {
            bad = Some("no triangles".into());
        }
        if let Some(reason) = bad {
            report.skipped.push(SkippedElement {
                guid,
                class,
                reason,
            });
            continue;
        }
        let local = bx.center();
        // One primitive per (colour, material name).
        let mut prims: Vec<Primitive> = Vec::new();
        let mut prim_of: HashMap<MaterialId, usize> = HashMap::new();
        for p in &el.pieces {
            if p.indices.is_empty() {
                continue;
            }
            let mat = b.material(p.color, p.material_name.clone());
            let k = *prim_of.entry(mat).or_insert_with(|| {
                prims.push(Primitive {
                    material: Some(mat),
                    normals: Some(Vec::new()),
                    ..Default::default()
                });
                prims.len() - 1
            });
            let prim = &mut prims[k];
            let base = prim.positions.len() as u32;
            let off = DVec3::from(p.origin) - local;
            let positions: Vec<[f32; 3]> = p
                .positions
                .chunks_exact(3)
                .map(|v| {
                    [
                        (off.x + v[0] as f64) as f32,
                        (off.y + v[1] as f64) as f32,
                        (off.z + v[2] as f64) as f32,
                    ]
                })
                .collect();
            let normals: Vec<[f32; 3]> = if p.normals.len() == p.positions.len()
                && p.normals.iter().all(|x| x.is_finite())
            {
                p.normals
                    .chunks_exact(3)
                    .map(|n| {
                        glam::Vec3::new(n[0], n[1], n[2])
                            .try_normalize()
                            .unwrap_or(glam::Vec3::Z)
                            .to_array()
                    })
                    .collect()
            } else {
                vertex_normals(&positions, &p.indices)
            };
            prim.positions.extend(positions);
            prim.normals.as_mut().unwrap().extend(normals);
            prim.indices.extend(p.indices.iter().map(|i| i + base));
        }
        let (storey, building, site) = b.containers(el.express_id);
        let parent_node = b
            .parent
            .get(&el.express_id)
            .copied()
            .and_then(|p| b.node(p, 0));
        let node = NodeId(b.scene.nodes.len() as u32);
        b.scene.nodes.push(Node {
            name: Some(
                el.name
                    .clone()
                    .filter(|s| !s.is_empty())
                    .unwrap_or_else(|| guid.clone()),
            ),
            parent: parent_node,
            extras: None,
            name_repeat: 0,
        });
        b.node_of.insert(el.express_id, node);
        let mesh = MeshId(b.scene.meshes.len() as u32);
        b.scene.meshes.push(Mesh {
            name: el.name.clone(),
            primitives: prims,
            local_bounds: None,
        });
        let info = ElementInfo {
            key: guid,
            name: el.name.clone(),
            guid: el.guid.clone(),
            class: Some(b.shared(&class)),
            storey: storey.map(|t| b.shared(&t)),
            building: building.map(|t| b.shared(&t)),
            site: site.map(|t| b.shared(&t)),
            material: b.material_name(el.express_id).map(|t| b.shared(&t)),
            properties: b.properties(el.express_id),
        };
        b.scene.push_component(
            Component {
                node: Some(node),
                ..Component::new(mesh, frame * DMat4::from_translation(local))
            },
            &info,
        );
    }
    for m in geom.missing {
        if skip_reason(&m.class).is_some() {
            continue;
        }
        report.skipped.push(SkippedElement {
            guid: m.guid.unwrap_or_else(|| format!("#{}", m.express_id)),
            class: m.class,
            reason: m.reason,
        });
    }
    if b.scene.components.is_empty() {
        return Err(Error::input(
            path,
            format!(
                "no element with geometry in this IFC file ({} skipped)",
                report.skipped.len()
            ),
        ));
    }
    Ok(b.scene)
}

// ------------------------------------------------------------------------------------------------
// The IFC library adapter: the only place that names ifc-lite types.
// ------------------------------------------------------------------------------------------------

mod engine {
    use super::IfcMapConversion;
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
        fn geometry(&self, content: &[u8]) -> Result<RawGeometry, String>;
        fn data_model(&self, content: &[u8]) -> Result<RawData, String>;
        fn georef(&self, content: &[u8]) -> Result<RawGeoref, String>;
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
        fn geometry(&self, content: &[u8]) -> Result<RawGeometry, String> {
            let req = lite::ProcessingRequest::full_pass();
            let res = lite::process(content, &req, &mut ());
            if let Some(unit) = res.metadata.length_unit_refused {
                return Err(format!(
                    "unusable length unit (#{unit}): no geometry can be scaled"
                ));
            }
            let frame_to_world = frame_matrix(res.frame);
            let mut by_id: BTreeMap<u32, RawElement> = BTreeMap::new();
            for m in res.meshes {
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
                    reason:
                        "has a representation but the IFC library produced no triangles from it"
                            .into(),
                });
            }
            let elements = by_id
                .into_values()
                .filter(|e| !e.pieces.is_empty())
                .collect();
            Ok(RawGeometry {
                elements,
                missing,
                frame_to_world,
            })
        }

        fn data_model(&self, content: &[u8]) -> Result<RawData, String> {
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

        fn georef(&self, content: &[u8]) -> Result<RawGeoref, String> {
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
            let mut scanner = core::EntityScanner::new(content);
            while let Some((id, t, _, _)) = scanner.next_entity() {
                if site.is_none() && t.eq_ignore_ascii_case("IFCSITE") {
                    site = Some(id);
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
                    out.site_origin =
                        placement(&mut dec, p, scale, 0).transform_point3(DVec3::ZERO);
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
                out.map_conversion = Some(IfcMapConversion {
                    eastings: g.eastings,
                    northings: g.northings,
                    orthogonal_height: g.orthogonal_height,
                    x_axis_abscissa: g.x_axis_abscissa,
                    x_axis_ordinate: g.x_axis_ordinate,
                    scale: g.scale,
                    crs_name: g.crs_name,
                });
            }
            Ok(out)
        }
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
}

#[cfg(test)]
mod tests {
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
            .contains("truncated"));
        assert!(check_step(b"").unwrap_err().contains("empty"));
        assert!(check_step(b"hello world")
            .unwrap_err()
            .contains("not an IFC"));
        let unk = MINI.replace("'IFC4'", "'IFC9X9'");
        assert!(check_step(unk.as_bytes())
            .unwrap_err()
            .contains("unknown IFC schema"));
        let broken = MINI.replace("#2=IFCAXIS2PLACEMENT3D(#1", "#2=IFCAXIS2PLACEMENT3D(#42");
        let e = check_step(broken.as_bytes()).unwrap_err();
        assert!(e.contains("#2 refers to #42"), "{e}");
        let garbage = MINI.replace("#3=IFCLABEL", "garbage #3=IFCLABEL");
        assert!(check_step(garbage.as_bytes())
            .unwrap_err()
            .contains("malformed"));
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
