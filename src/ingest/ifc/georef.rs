//! Georeferencing of an IFC file: the CRS and map placement it writes (IFC4.3 IfcMapConversion
//! and IfcMapConversionScaled, IfcRigidOperation, IfcProjectedCRS, IfcGeographicCRS; IFC2X3
//! property sets ePSet_MapConversion and ePSet_ProjectedCRS), else its site's longitude/latitude
//! (IfcSite RefLatitude/RefLongitude), turned into the place, true-north turn and scales of the
//! model.
//!
//! # Which field names the CRS
//! Tried in this order; a field that names no CRS PROJ can use for the placement moves on to the
//! next one, and the report says which one placed the model ([`CrsField`]):
//! 1. an IfcGeographicCRS target of an IfcRigidOperation: the operation's coordinates are
//!    longitude and latitude (degrees, already read through the plane-angle unit);
//! 2. `Name`: `EPSG:n`, a bare code, an OGC URN or URL, or any name PROJ knows; `Name` 'WKT'
//!    with the WKT in `Description` (a WKT in `Description` is tried after the name);
//! 3. `MapProjection` 'EPSG' with the code in `MapZone`;
//! 4. an explicit code (`EPSG:n`, URN, URL) in another field (`GeodeticDatum`, `Description`...);
//! 5. `MapProjection` UTM with `MapZone` and `GeodeticDatum` (WGS 84, ETRS89, NAD83, GDA94,
//!    GDA2020);
//! 6. `MapProjection` Gauss-Krüger with a 3° `MapZone`: DHDN's zones 2 to 5;
//! 7. `Description` as a name PROJ knows;
//! 8. `--crs`.
//!
//! A code with a `VerticalDatum` code that PROJ accepts as a compound CRS is reported as that
//! compound; heights are still taken as ellipsoidal, so the vertical part never fails a file.
//!
//! # Where the model goes
//! The anchor is the model's own origin, or its footprint centre when it lies far from it (map
//! coordinates: [`choose_anchor`]); the anchor's map point is what PROJ places, and where the
//! CRS's area of use is checked. Eastings, Northings and OrthogonalHeight are in the MapUnit (the
//! CRS's own unit when none is given); Scale (IFC4: converting project units to map units) and
//! the IFC4.3 factors scale the project axes. When Eastings/Northings read so fall outside the
//! CRS's area of use but read in project units land inside it (and near the site reference, if
//! any), that reading is taken with a warning: some exporters write them in project units.

use super::*;
use crate::geodesy::crs::{
    compound_crs, epsg_code_of, is_vertical_crs, place_geographic_point, place_map_point,
    projected_unit_m, CrsError, CrsUse, MapPlace,
};
use crate::geodesy::projection::UtmZone;
use crate::geodesy::{great_circle_m, MEAN_EARTH_RADIUS_M};
use crate::scene::placement::{choose_anchor, AnchorRule};
use glam::{DMat2, DMat3, DMat4, DVec2};

/// A map placement farther than this from the site's RefLatitude/RefLongitude is reported; so are
/// coordinates this far from the origin in a file that names no CRS (national-grid sized).
pub const FAR_M: f64 = 100_000.0;

/// The field of the file (or the option) that named the CRS that placed the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CrsField {
    /// IfcGeographicCRS, the target of an IfcRigidOperation in plane angles.
    GeographicCrs,
    /// IfcProjectedCRS `Name` (a code, URN, URL or a name PROJ knows).
    Name,
    /// A WKT: in `Description` (with `Name` 'WKT' or on its own).
    DescriptionWkt,
    /// `Description` as a name PROJ knows.
    Description,
    /// An EPSG code in `MapZone`: bare under `MapProjection` 'EPSG', or written out ('EPSG:n').
    MapZoneCode,
    /// An explicit EPSG code written in a field not meant for it (`GeodeticDatum`...).
    CodeInOtherField,
    /// `MapProjection` UTM + `MapZone` + `GeodeticDatum`.
    UtmZone,
    /// `MapProjection` Gauss-Krüger + a 3° `MapZone`.
    GaussKruegerZone,
    /// `--crs` (or a manifest entry's "crs").
    Option,
}

impl CrsField {
    /// The report's label (`georeference.crs[].source`); property-set fields start `epset-`.
    pub fn label(self, operation: MapOperation) -> &'static str {
        let pset = operation == MapOperation::PropertySets;
        match (self, pset) {
            (CrsField::GeographicCrs, _) => "ifc-geographic-crs",
            (CrsField::Name, false) => "ifc-name",
            (CrsField::Name, true) => "epset-name",
            (CrsField::DescriptionWkt, false) => "ifc-description-wkt",
            (CrsField::DescriptionWkt, true) => "epset-description-wkt",
            (CrsField::Description, false) => "ifc-description",
            (CrsField::Description, true) => "epset-description",
            (CrsField::MapZoneCode, false) => "ifc-map-zone-code",
            (CrsField::MapZoneCode, true) => "epset-map-zone-code",
            (CrsField::CodeInOtherField, false) => "ifc-code-in-other-field",
            (CrsField::CodeInOtherField, true) => "epset-code-in-other-field",
            (CrsField::UtmZone, false) => "ifc-map-projection",
            (CrsField::UtmZone, true) => "epset-map-projection",
            (CrsField::GaussKruegerZone, false) => "ifc-gauss-krueger-zone",
            (CrsField::GaussKruegerZone, true) => "epset-gauss-krueger-zone",
            (CrsField::Option, _) => "option",
        }
    }
}

/// What the georeference of a file came to.
#[derive(Debug, Default)]
pub(super) struct GeorefOutcome {
    pub georef: Option<IfcGeoref>,
    /// Why the file's map placement could not be used (the model falls back).
    pub warning: Option<String>,
    /// Placed, but with something to say (a unit slip read around, a far site reference, map
    /// coordinates without a CRS), one line each naming the file.
    pub notes: Vec<String>,
}

/// The georeference of a file's raw data; `bounds`: the model's box in the scene frame (metres;
/// empty when unknown, then the anchor is the origin).
pub(super) fn georef_from_raw(
    raw: engine::RawGeoref,
    path: &Path,
    crs_option: Option<&str>,
    bounds: &Aabb,
) -> GeorefOutcome {
    let file = path.display();
    let anchor = if bounds.min.is_finite() && bounds.max.is_finite() {
        choose_anchor(bounds).0
    } else {
        DVec3::ZERO
    };
    let site = site_lon_lat(&raw);
    let mut out = GeorefOutcome::default();
    if let Some(m) = &raw.map_conversion {
        match georef_from_map_conversion(m, path, crs_option, anchor, site, raw.true_north, bounds)
        {
            Ok((g, slip)) => {
                out.notes.extend(slip);
                if let Some((lon, lat)) = site {
                    let d = great_circle_m(lon, lat, g.longitude_deg, g.latitude_deg);
                    if d > FAR_M {
                        out.notes.push(format!(
                            "{file}: the map conversion places the model at {}, {:.0} km from where IfcSite RefLatitude/RefLongitude put it ({}); the map conversion is used",
                            lon_lat_text(g.longitude_deg, g.latitude_deg),
                            d / 1000.0,
                            lon_lat_text(lon, lat)
                        ));
                    }
                }
                out.georef = Some(g);
                return out;
            }
            Err(e) => out.warning = Some(e.to_string()),
        }
    }
    out.georef = georef_from_site(raw);
    let centre = bounds.center();
    if crs_option.is_none() && centre.is_finite() && centre.truncate().length() > FAR_M {
        let grid = format!(
            "its coordinates lie {:.0} km from the origin (national-grid sized) but no CRS places them",
            centre.truncate().length() / 1000.0
        );
        match &mut out.warning {
            // The advice once, after both facts.
            Some(w) => {
                let facts = w.strip_suffix(GIVE_CRS).unwrap_or(w);
                *w = format!("{facts}; {grid}{GIVE_CRS}");
            }
            None => out.notes.push(format!("{file}: {grid}{GIVE_CRS}")),
        }
    }
    out
}

/// The advice that ends a warning about a model no CRS places.
const GIVE_CRS: &str = ": give --crs EPSG:CODE";

/// IfcSite RefLongitude, RefLatitude (degrees), when both are there and a place on Earth.
fn site_lon_lat(raw: &engine::RawGeoref) -> Option<(f64, f64)> {
    let (lat, lon, _) = raw.site_reference?;
    let ok = lat.is_finite()
        && lon.is_finite()
        && (-90.0..=90.0).contains(&lat)
        && (-180.0..=360.0).contains(&lon);
    ok.then_some((if lon > 180.0 { lon - 360.0 } else { lon }, lat))
}

fn lon_lat_text(lon: f64, lat: f64) -> String {
    format!(
        "{:.5}° {}, {:.5}° {}",
        lon.abs(),
        if lon < 0.0 { 'W' } else { 'E' },
        lat.abs(),
        if lat < 0.0 { 'S' } else { 'N' }
    )
}

fn georef_from_site(raw: engine::RawGeoref) -> Option<IfcGeoref> {
    let (lon, lat) = site_lon_lat(&raw)?;
    let h = raw.site_reference.map_or(0.0, |s| s.2);
    Some(IfcGeoref {
        longitude_deg: lon,
        latitude_deg: lat,
        height_m: if h.is_finite() { h } else { 0.0 },
        true_north_deg: true_north_deg(raw.true_north),
        map_conversion: raw.map_conversion,
        anchor: raw.site_origin,
        map_linear: None,
        crs: None,
        crs_field: None,
        per_vertex_map: None,
    })
}

/// The model context's TrueNorth (x, y) as degrees counter-clockwise from the project +y axis.
fn true_north_deg(true_north: Option<[f64; 2]>) -> Option<f64> {
    true_north
        .filter(|n| n[0].is_finite() && n[1].is_finite() && (n[0] != 0.0 || n[1] != 0.0))
        .map(|n| (-n[0]).atan2(n[1]).to_degrees())
}

/// The CRSs a map placement names, in the order of the module doc, each once, with the field.
fn crs_candidates(m: &IfcMapConversion, crs_option: Option<&str>) -> Vec<(String, CrsField)> {
    fn text(t: &Option<String>) -> Option<&str> {
        t.as_deref().map(str::trim).filter(|t| !t.is_empty())
    }
    let mut out: Vec<(String, CrsField)> = Vec::new();
    let mut push = |def: String, field: CrsField| {
        let def = crate::geodesy::crs::normalize_crs_text(&def);
        if !out.iter().any(|(d, _)| *d == def) {
            out.push((def, field));
        }
    };
    let name = text(&m.crs_name);
    let description = text(&m.crs_description);
    if m.geographic {
        if let Some(n) = name {
            push(n.to_string(), CrsField::GeographicCrs);
        }
        return out;
    }
    let wkt = description.filter(|d| looks_like_wkt(d));
    match name {
        Some(n) if n.eq_ignore_ascii_case("WKT") => {}
        Some(n) => push(n.to_string(), CrsField::Name),
        None => {}
    }
    if let Some(w) = wkt {
        push(w.to_string(), CrsField::DescriptionWkt);
    }
    let projection = text(&m.map_projection).unwrap_or("");
    if projection.to_ascii_uppercase().contains("EPSG") {
        if let Some(code) = text(&m.map_zone).and_then(epsg_code_of) {
            push(format!("EPSG:{code}"), CrsField::MapZoneCode);
        }
    }
    // Only explicit codes here: a bare number in these fields is a zone or a datum's name.
    for (field, label) in [
        (&m.geodetic_datum, CrsField::CodeInOtherField),
        (&m.crs_description, CrsField::CodeInOtherField),
        (&m.map_zone, CrsField::MapZoneCode),
        (&m.map_projection, CrsField::CodeInOtherField),
    ] {
        if let Some(code) = text(field)
            .filter(|t| !t.chars().all(|c| c.is_ascii_digit()))
            .and_then(epsg_code_of)
        {
            push(format!("EPSG:{code}"), label);
        }
    }
    if let Some(code) = crs_of_map_projection(m) {
        push(code, CrsField::UtmZone);
    }
    if let Some(code) = gauss_krueger_crs(m) {
        push(code, CrsField::GaussKruegerZone);
    }
    if let Some(d) = description.filter(|d| !looks_like_wkt(d)) {
        push(d.to_string(), CrsField::Description);
    }
    if let Some(c) = crs_option {
        push(c.to_string(), CrsField::Option);
    }
    out
}

/// A WKT CRS definition (WKT1 or WKT2), not a description in words.
fn looks_like_wkt(text: &str) -> bool {
    let upper = text.trim_start().to_ascii_uppercase();
    [
        "PROJCS[",
        "PROJCRS[",
        "PROJECTEDCRS[",
        "COMPD_CS[",
        "COMPOUNDCRS[",
        "BOUNDCRS[",
    ]
    .iter()
    .any(|k| upper.starts_with(k))
}

/// Opens PROJ on this thread for the CRS the map placement names first, so that reading the
/// georeference later finds it made (see [`crate::geodesy::crs::warm_up`]).
pub(super) fn warm_up_proj(raw: &engine::RawGeoref, crs_option: Option<&str>) {
    let first = raw
        .map_conversion
        .as_ref()
        .and_then(|m| crs_candidates(m, crs_option).into_iter().next());
    if let Some((definition, _)) = first {
        crate::geodesy::crs::warm_up(&definition);
    }
}

/// MapProjection + MapZone + GeodeticDatum → an EPSG code: UTM ("UTM", "32N") on WGS 84, ETRS89,
/// NAD83, GDA94 or GDA2020.
fn crs_of_map_projection(m: &IfcMapConversion) -> Option<String> {
    let projection = m.map_projection.as_deref()?.trim().to_ascii_uppercase();
    if !projection.contains("UTM") && !projection.contains("TRANSVERSE MERCATOR") {
        return None;
    }
    // "UTM zone 32N" may be in MapProjection itself.
    let zone = match m.map_zone.as_deref() {
        Some(z) => UtmZone::from_crs_name(&format!("UTM zone {}", z.trim())),
        None => UtmZone::from_crs_name(&projection),
    }?;
    // Southern-hemisphere grids name the zone without its letter.
    let datum = m.geodetic_datum.as_deref();
    let southern = utm_southern_code(zone.zone, datum);
    southern
        .or_else(|| zone.epsg_code(datum))
        .map(|c| format!("EPSG:{c}"))
}

/// Australia's MGA zones (GDA94: EPSG:283zz, GDA2020: EPSG:78zz), by datum name or code.
fn utm_southern_code(zone: u8, datum: Option<&str>) -> Option<u32> {
    let d: String = datum?
        .chars()
        .filter(char::is_ascii_alphanumeric)
        .collect::<String>()
        .to_ascii_uppercase();
    let z = u32::from(zone);
    if !(46..=59).contains(&z) {
        return None;
    }
    match d.as_str() {
        "GDA2020" | "EPSG7844" | "GEOCENTRICDATUMOFAUSTRALIA2020" => Some(7800 + z),
        "GDA94" | "EPSG4283" | "GEOCENTRICDATUMOFAUSTRALIA1994" => Some(28300 + z),
        _ => None,
    }
}

/// MapProjection Gauss-Krüger + MapZone 2..5 → DHDN / 3-degree Gauss-Krüger zone (EPSG:31466 to
/// 31469), the grid that bare name stands for in German files.
fn gauss_krueger_crs(m: &IfcMapConversion) -> Option<String> {
    let projection: String = m
        .map_projection
        .as_deref()?
        .to_ascii_uppercase()
        .chars()
        .filter(char::is_ascii_alphabetic)
        .collect();
    if !(projection.contains("GAUSS") && projection.contains("KR")) {
        return None;
    }
    let zone: u32 = m.map_zone.as_deref()?.trim().parse().ok()?;
    (2..=5)
        .contains(&zone)
        .then(|| format!("EPSG:{}", 31464 + zone))
}

/// Metres per project length unit (1 when the file's is unusable).
fn project_unit_m(m: &IfcMapConversion) -> f64 {
    if m.project_unit_m.is_finite() && m.project_unit_m > 0.0 {
        m.project_unit_m
    } else {
        1.0
    }
}

/// One reading of a map conversion in a CRS: the anchor's map point placed, the linear map of
/// project metres to east-north-up metres there, and the map point (CRS units).
struct Reading {
    place: MapPlace,
    linear: DMat3,
    /// Scene metres → map coordinates (easting, northing in the CRS's units; height in metres).
    to_map: DMat4,
    /// The scene point placed at the map point (scene metres).
    anchor: DVec3,
    /// True metres per scene metre: 1, or the ratio of the length unit the geometry is really in
    /// to the declared project unit ([`read_projected`]).
    geometry_scale: f64,
    easting: f64,
    northing: f64,
    theta_deg: f64,
}

/// Reads the conversion with Eastings/Northings/OrthogonalHeight in `map_unit_m` metres per unit,
/// and places the `anchor`'s map point (scene metres) in `crs` (`crs_unit_m` metres per unit).
fn read_in_unit(
    m: &IfcMapConversion,
    crs: &str,
    crs_unit_m: f64,
    map_unit_m: f64,
    anchor: DVec3,
    geometry_scale: f64,
) -> Result<Reading, CrsError> {
    let (a, b) = if m.x_axis_abscissa == 0.0 && m.x_axis_ordinate == 0.0 {
        (1.0, 0.0)
    } else {
        let l = m.x_axis_abscissa.hypot(m.x_axis_ordinate);
        (m.x_axis_abscissa / l, m.x_axis_ordinate / l)
    };
    let scale = if m.scale.is_finite() && m.scale != 0.0 {
        m.scale
    } else {
        1.0
    };
    // Scene metres → project units → (Scale, factors) map units → grid metres, per axis. Scale
    // converts project units to map units (IFC4); when that makes a grid that is not the size of
    // the ground while Scale alone does, the units were converted already (IFC4.3 reading).
    let units = map_unit_m / project_unit_m(m);
    let ground_sized = |k: f64| (0.5..=2.0).contains(&k);
    let units = if !ground_sized(scale * units) && ground_sized(scale) {
        1.0
    } else {
        units
    };
    let per_axis = |f: f64| {
        let f = if f.is_finite() && f != 0.0 { f } else { 1.0 };
        scale * f * units * geometry_scale
    };
    let (sx, sy, sz) = (
        per_axis(m.factors[0]),
        per_axis(m.factors[1]),
        per_axis(m.factors[2]),
    );
    let rotation = DMat2::from_cols(DVec2::new(a, b), DVec2::new(-b, a));
    let offset_m = rotation * DVec2::new(sx * anchor.x, sy * anchor.y);
    let ratio = map_unit_m / crs_unit_m;
    let easting = m.eastings * ratio + offset_m.x / crs_unit_m;
    let northing = m.northings * ratio + offset_m.y / crs_unit_m;
    let height = if m.orthogonal_height.is_finite() {
        m.orthogonal_height
    } else {
        0.0
    };
    let height_m = height * map_unit_m + sz * anchor.z;
    let place = place_map_point(crs, easting, northing, height_m)?;
    let horizontal = place.grid_to_enu * rotation * DMat2::from_diagonal(DVec2::new(sx, sy));
    let linear = DMat3::from_cols(
        horizontal.x_axis.extend(0.0),
        horizontal.y_axis.extend(0.0),
        DVec3::new(0.0, 0.0, sz),
    );
    let grid = rotation * DMat2::from_diagonal(DVec2::new(sx, sy)) / crs_unit_m;
    let grid = DMat3::from_cols(
        grid.x_axis.extend(0.0),
        grid.y_axis.extend(0.0),
        DVec3::new(0.0, 0.0, sz),
    );
    let at_anchor = DVec3::new(easting, northing, height_m);
    let to_map = DMat4::from_translation(at_anchor)
        * DMat4::from_mat3(grid)
        * DMat4::from_translation(-anchor);
    Ok(Reading {
        place,
        linear,
        to_map,
        anchor,
        geometry_scale,
        easting,
        northing,
        theta_deg: b.atan2(a).to_degrees(),
    })
}

/// Farthest any corner of `bounds` lies from `anchor`, horizontally (metres).
fn reach_m(bounds: &Aabb, anchor: DVec3) -> f64 {
    if !(bounds.min.is_finite() && bounds.max.is_finite()) {
        return 0.0;
    }
    let (lo, hi) = (bounds.min.truncate(), bounds.max.truncate());
    [lo, hi, DVec2::new(lo.x, hi.y), DVec2::new(hi.x, lo.y)]
        .iter()
        .map(|c| (*c - anchor.truncate()).length())
        .fold(0.0, f64::max)
}

/// Whether one linear map at the anchor would be off by more than [`PER_VERTEX_ABOVE_M`]
/// somewhere in a model reaching `reach_m` from it: the Earth's curvature lowers a point `r`
/// from the anchor by about r² / 2R below the anchor's tangent plane, which the linear map keeps
/// it on.
fn needs_per_vertex(reach_m: f64) -> bool {
    reach_m.powi(2) / (2.0 * MEAN_EARTH_RADIUS_M) > PER_VERTEX_ABOVE_M
}

/// The error of one linear map above which every vertex goes through PROJ.
pub const PER_VERTEX_ABOVE_M: f64 = 0.001;

/// Places a projected map conversion in `crs`: as declared, else (a unit slip) with
/// Eastings/Northings in project units, which must then land near the site reference if there
/// is one. The second value is the warning for a slip.
fn read_projected(
    m: &IfcMapConversion,
    path: &Path,
    crs: &str,
    (anchor, bounds): (DVec3, &Aabb),
    site: Option<(f64, f64)>,
) -> Result<(Reading, Option<String>), CrsError> {
    let crs_unit_m = projected_unit_m(crs)?;
    let declared_m = m
        .map_unit_m
        .filter(|u| u.is_finite() && *u > 0.0)
        .unwrap_or(crs_unit_m);
    let first = match read_in_unit(m, crs, crs_unit_m, declared_m, anchor, 1.0) {
        Ok(r) => return Ok((r, None)),
        Err(e) => e,
    };
    let near_site = |r: &Reading| {
        let (lon, lat) = (r.place.place.longitude_deg, r.place.place.latitude_deg);
        site.is_none_or(|(slon, slat)| great_circle_m(slon, slat, lon, lat) <= FAR_M)
    };
    let project_m = project_unit_m(m);
    let map_unit_slip = ((project_m / declared_m - 1.0).abs() > 1e-9)
        .then(|| read_in_unit(m, crs, crs_unit_m, project_m, anchor, 1.0).ok())
        .flatten()
        .filter(near_site);
    let Some(r) = map_unit_slip else {
        return read_geometry_unit_slip(m, path, crs, (crs_unit_m, declared_m), bounds, near_site)
            .map(|(r, warning)| (r, Some(warning)))
            .ok_or(first);
    };
    let (lon, lat) = (r.place.place.longitude_deg, r.place.place.latitude_deg);
    let warning = format!(
        "{}: IfcMapConversion Eastings {} Northings {} read in the MapUnit ({declared_m} m) give no place in {} ({first}); read in the project unit ({project_m} m) they land at {}{}: that reading is used",
        path.display(),
        m.eastings,
        m.northings,
        r.place.crs,
        lon_lat_text(lon, lat),
        if site.is_some() { ", near the IfcSite reference" } else { "" },
    );
    Ok((r, Some(warning)))
}

/// Length units an exporter may have written geometry in (metres per unit): metre, millimetre,
/// centimetre, foot, inch, US survey foot.
const GEOMETRY_UNITS_M: [f64; 6] = [1.0, 0.001, 0.01, 0.3048, 0.0254, 1200.0 / 3937.0];

/// A declared project unit that the geometry contradicts: a model in map coordinates (so far from
/// the origin once read in another length unit that [`choose_anchor`] anchors it at its
/// footprint) that no CRS can place in the declared unit, but that lands inside the CRS's area of
/// use (and near the site reference, if any) read in that other unit. The first such unit wins,
/// anchored where its reading puts the anchor, with the warning that names both readings.
fn read_geometry_unit_slip(
    m: &IfcMapConversion,
    path: &Path,
    crs: &str,
    (crs_unit_m, map_unit_m): (f64, f64),
    bounds: &Aabb,
    near_site: impl Fn(&Reading) -> bool,
) -> Option<(Reading, String)> {
    if !(bounds.min.is_finite() && bounds.max.is_finite()) {
        return None;
    }
    let declared_m = project_unit_m(m);
    let (real_m, r) = GEOMETRY_UNITS_M
        .into_iter()
        .filter(|u| (u / declared_m - 1.0).abs() > 1e-9)
        .find_map(|u| {
            let scale = u / declared_m;
            let (anchor, rule) = choose_anchor(&Aabb {
                min: bounds.min * scale,
                max: bounds.max * scale,
            });
            if rule == AnchorRule::ModelOrigin {
                return None;
            }
            let r = read_in_unit(m, crs, crs_unit_m, map_unit_m, anchor / scale, scale).ok()?;
            near_site(&r).then_some((u, r))
        })?;
    let warning = format!(
        "{}: the geometry lies in map coordinates that give no place in {} in the declared project unit ({declared_m} m); read in {real_m} m units it lands at {}: that reading is used",
        path.display(),
        r.place.crs,
        lon_lat_text(r.place.place.longitude_deg, r.place.place.latitude_deg),
    );
    Some((r, warning))
}

/// A map placement (IfcMapConversion, IfcRigidOperation, ePSet_MapConversion) placed through the
/// first of its CRSs that can place it. `Err`: the one-line warning when none can.
fn georef_from_map_conversion(
    m: &IfcMapConversion,
    path: &Path,
    crs_option: Option<&str>,
    anchor: DVec3,
    site: Option<(f64, f64)>,
    true_north: Option<[f64; 2]>,
    bounds: &Aabb,
) -> std::result::Result<(IfcGeoref, Option<String>), MapConversionProblem> {
    let candidates = crs_candidates(m, crs_option);
    if candidates.is_empty() {
        return Err(MapConversionProblem::NoCrs);
    }
    if !(m.eastings.is_finite() && m.northings.is_finite()) {
        return Err(MapConversionProblem::NotNumbers);
    }
    let mut first_error: Option<CrsError> = None;
    for (crs, field) in candidates {
        let placed = if m.geographic {
            georef_geographic(m, &crs, true_north).map(|g| (g, None))
        } else {
            read_projected(m, path, &crs, (anchor, bounds), site).map(|(r, slip)| {
                // Grid north seen from the project: −θ from +y, θ the x axis's angle from grid
                // east; true north is grid north turned back by the convergence.
                let true_north_deg = Some(r.place.convergence_deg - r.theta_deg);
                let g = IfcGeoref {
                    longitude_deg: r.place.place.longitude_deg,
                    latitude_deg: r.place.place.latitude_deg,
                    height_m: r.place.place.height_m,
                    true_north_deg: true_north_deg.filter(|d| d.abs() > 1e-12),
                    map_conversion: Some(m.clone()),
                    anchor: r.anchor,
                    map_linear: Some(r.linear),
                    crs: Some(CrsUse::new("", "", &r.place, r.easting, r.northing)),
                    crs_field: None,
                    per_vertex_map: needs_per_vertex(reach_m(bounds, r.anchor) * r.geometry_scale)
                        .then_some(r.to_map),
                };
                (g, slip)
            })
        };
        match placed {
            Ok((mut g, slip)) => {
                if let Some(u) = g.crs.as_mut() {
                    u.file = path.display().to_string();
                    u.source = field.label(m.operation).to_string();
                    with_vertical_part(u, &crs, m.vertical_datum.as_deref());
                }
                g.crs_field = Some(field);
                return Ok((g, slip));
            }
            Err(err) => {
                first_error.get_or_insert(err);
            }
        }
    }
    Err(MapConversionProblem::Unplaceable { first_error })
}

/// An IfcRigidOperation into an IfcGeographicCRS: the project origin at (longitude, latitude,
/// Height), the project's axes east, north, up (turned by the context's TrueNorth if given).
fn georef_geographic(
    m: &IfcMapConversion,
    crs: &str,
    true_north: Option<[f64; 2]>,
) -> Result<IfcGeoref, CrsError> {
    let height_m = if m.orthogonal_height.is_finite() {
        m.orthogonal_height * project_unit_m(m)
    } else {
        0.0
    };
    let p = place_geographic_point(crs, m.eastings, m.northings, height_m)?;
    let north = true_north_deg(true_north);
    Ok(IfcGeoref {
        longitude_deg: p.place.longitude_deg,
        latitude_deg: p.place.latitude_deg,
        height_m,
        true_north_deg: north,
        map_conversion: Some(m.clone()),
        anchor: DVec3::ZERO,
        map_linear: Some(DMat3::from_rotation_z((-north.unwrap_or(0.0)).to_radians())),
        crs: Some(CrsUse::new("", "", &p, m.eastings, m.northings)),
        crs_field: None,
        per_vertex_map: None,
    })
}

/// Reports a compound CRS the file names as that compound, and `EPSG:h` with a `VerticalDatum`
/// code `v` of a vertical CRS as the compound `EPSG:h+v` (heights stay ellipsoidal: the vertical
/// part only names the file's intent). The horizontal CRS is known by now, and PROJ composes any
/// horizontal CRS with a vertical one, so the compound itself need not be built.
fn with_vertical_part(u: &mut CrsUse, crs: &str, vertical: Option<&str>) {
    if let Some((id, name)) = compound_crs(crs) {
        u.crs = id;
        u.crs_name = format!("{name} (vertical part not applied)");
        return;
    }
    let (Some(h), Some(v)) = (epsg_code_of(crs), vertical.and_then(epsg_code_of)) else {
        return;
    };
    let compound = format!("EPSG:{h}+{v}");
    if u.crs == format!("EPSG:{h}") && is_vertical_crs(&format!("EPSG:{v}")) {
        u.crs_name = format!("{} + EPSG:{v} (vertical, not applied)", u.crs_name);
        u.crs = compound;
    }
}

/// What makes a map conversion unusable at all, whatever its CRS (book: guide/safety.md; an error,
/// not a fallback): a Scale or FactorX/Y/Z that is zero, negative or not plausible
/// (`geodesy::plausible_scale`), or Eastings/Northings/OrthogonalHeight that are not plausible
/// metres in the MapUnit nor in the project unit (an exporter's slip). Absent values read as 1
/// (scales) and 0.
pub(super) fn implausible_map_number(m: &IfcMapConversion) -> Option<String> {
    use crate::geodesy::{plausible_m, plausible_scale, PLAUSIBLE_SCALE};
    let scales = [
        ("Scale", m.scale),
        ("FactorX", m.factors[0]),
        ("FactorY", m.factors[1]),
        ("FactorZ", m.factors[2]),
    ];
    if let Some((name, v)) = scales.into_iter().find(|(_, v)| !plausible_scale(*v)) {
        return Some(format!(
            "IfcMapConversion {name} {v:e} is not a plausible scale (from {:e} to {PLAUSIBLE_SCALE:e})",
            1.0 / PLAUSIBLE_SCALE
        ));
    }
    // In the MapUnit (millimetres make a UTM northing 5e9); the CRS's own unit when none is given.
    let unit_m = m.map_unit_m.filter(|u| plausible_scale(*u)).unwrap_or(1.0);
    let project_m = Some(m.project_unit_m)
        .filter(|u| plausible_scale(*u))
        .unwrap_or(unit_m);
    let place = [
        ("Eastings", m.eastings),
        ("Northings", m.northings),
        ("OrthogonalHeight", m.orthogonal_height),
    ];
    let (name, v) = place
        .into_iter()
        .find(|(_, v)| !plausible_m(v * unit_m) && !plausible_m(v * project_m))?;
    Some(format!(
        "IfcMapConversion {name} {v:e} is not a plausible coordinate (beyond ±{:e} m, the Earth's circumference)",
        crate::geodesy::PLAUSIBLE_COORDINATE_M
    ))
}

/// Why an IfcMapConversion cannot place the model (a warning: the model falls back).
#[derive(Debug, thiserror::Error)]
pub(super) enum MapConversionProblem {
    #[error("its IfcMapConversion names no projected CRS PROJ can use (no IfcProjectedCRS Name, code or MapProjection/MapZone){GIVE_CRS}")]
    NoCrs,
    #[error("its IfcMapConversion Eastings/Northings are not numbers")]
    NotNumbers,
    #[error("its IfcMapConversion cannot be placed: {}", first_error.as_ref().map_or_else(|| "no CRS".to_string(), |e| e.to_string()))]
    Unplaceable { first_error: Option<CrsError> },
}

// ------------------------------------------------------------------------------------------------
// STEP check (ours, independent of the IFC library)
// ------------------------------------------------------------------------------------------------

#[cfg(test)]
mod tests {
    use super::*;

    fn conversion(crs: Option<&str>) -> IfcMapConversion {
        IfcMapConversion {
            eastings: 155_000.0,
            northings: 463_000.0,
            orthogonal_height: 4.0,
            x_axis_abscissa: 0.0,
            x_axis_ordinate: 1.0,
            scale: 1.0,
            crs_name: crs.map(str::to_string),
            geodetic_datum: None,
            map_projection: None,
            map_zone: None,
            factors: [2.0, 1.0, 0.5],
            map_unit_m: None,
            project_unit_m: 1.0,
            crs_description: None,
            vertical_datum: None,
            operation: MapOperation::MapConversion,
            geographic: false,
        }
    }

    fn place(
        m: &IfcMapConversion,
        crs_option: Option<&str>,
    ) -> std::result::Result<IfcGeoref, MapConversionProblem> {
        georef_from_map_conversion(
            m,
            Path::new("t.ifc"),
            crs_option,
            DVec3::ZERO,
            None,
            None,
            &Aabb::EMPTY,
        )
        .map(|(g, _)| g)
    }

    /// Scales and factors of zero, below 1e-6 or above 1e6, and places beyond 4e7 m (in the map
    /// unit), are refused by name; the usual ones (feet, millimetre map units) are not.
    #[test]
    fn implausible_map_numbers_are_named() {
        assert_eq!(implausible_map_number(&conversion(None)), None);
        let with = |edit: fn(&mut IfcMapConversion)| {
            let mut m = conversion(None);
            edit(&mut m);
            implausible_map_number(&m)
        };
        assert_eq!(with(|m| m.factors = [0.3048; 3]), None);
        let mm = with(|m| {
            m.map_unit_m = Some(0.001);
            m.northings = 5.4e9;
        });
        assert_eq!(mm, None);
        let named = |edit: fn(&mut IfcMapConversion), what: &str| {
            let problem = with(edit).unwrap_or_default();
            assert!(problem.contains(what), "{problem} should name {what}");
        };
        named(|m| m.scale = 0.0, "Scale 0e0");
        named(|m| m.scale = 1e300, "Scale 1e300");
        named(|m| m.scale = -1.0, "Scale -1e0");
        named(|m| m.factors[1] = 1e-9, "FactorY 1e-9");
        named(|m| m.factors[2] = f64::NAN, "FactorZ NaN");
        named(|m| m.eastings = 1e300, "Eastings 1e300");
        named(
            |m| m.orthogonal_height = f64::INFINITY,
            "OrthogonalHeight inf",
        );
    }

    /// IFC4X3 IfcMapConversionScaled: FactorX/Y/Z scale the project axes before the rotation; the
    /// x axis at 90° points to grid north, which at RD's origin is true north.
    #[test]
    fn scaled_conversion_scales_each_axis_then_turns() {
        let g = place(&conversion(Some("EPSG:28992")), None).unwrap();
        let k = g.crs.as_ref().unwrap().scale_factor;
        let l = g.map_linear.unwrap();
        let x = l * DVec3::X;
        assert!((x - DVec3::new(0.0, 2.0 / k, 0.0)).length() < 1e-5, "{x}");
        let y = l * DVec3::Y;
        assert!((y - DVec3::new(-1.0 / k, 0.0, 0.0)).length() < 1e-5, "{y}");
        assert_eq!(l * DVec3::Z, DVec3::new(0.0, 0.0, 0.5));
        assert_eq!(g.crs.unwrap().source, "ifc-name");
    }

    #[test]
    fn crs_from_map_projection_and_from_the_option() {
        let mut m = conversion(Some("Local grid"));
        m.map_projection = Some("UTM".into());
        m.map_zone = Some("32N".into());
        m.geodetic_datum = Some("ETRS89".into());
        assert_eq!(crs_of_map_projection(&m).as_deref(), Some("EPSG:25832"));
        m.geodetic_datum = None;
        assert_eq!(crs_of_map_projection(&m).as_deref(), Some("EPSG:32632"));
        // No CRS in the file: --crs names it.
        let g = place(&conversion(None), Some("28992")).unwrap();
        assert_eq!(g.crs.unwrap().source, "option");
        let w = place(&conversion(None), None).unwrap_err().to_string();
        assert!(w.contains("--crs"), "{w}");
    }

    /// Each way exporters name the CRS, in the documented order: a field that names nothing PROJ
    /// can use gives way to the next one.
    #[test]
    fn every_field_that_names_a_crs_is_read() {
        let field_of = |edit: &dyn Fn(&mut IfcMapConversion)| {
            let mut m = conversion(None);
            m.factors = [1.0; 3];
            edit(&mut m);
            let g = place(&m, None).unwrap();
            (g.crs.clone().unwrap().crs, g.crs_field.unwrap())
        };
        let rd = "EPSG:28992".to_string();
        for name in [
            "28992",
            "urn:ogc:def:crs:EPSG::28992",
            "http://www.opengis.net/def/crs/EPSG/0/28992",
            "Amersfoort / RD New",
        ] {
            let got = field_of(&|m| m.crs_name = Some(name.into()));
            assert_eq!(got, (rd.clone(), CrsField::Name), "{name}");
        }
        // A short name PROJ does not know; the code in MapZone.
        let got = field_of(&|m| {
            m.crs_name = Some("RDNEW".into());
            m.map_projection = Some("EPSG".into());
            m.map_zone = Some("28992".into());
        });
        assert_eq!(got, (rd.clone(), CrsField::MapZoneCode));
        // The projected code in GeodeticDatum wins over building a Gauss-Krüger zone.
        let gk = |m: &mut IfcMapConversion| {
            m.eastings = 3_513_038.0;
            m.northings = 5_516_199.0;
            m.map_projection = Some("Gauss-Krueger".into());
            m.map_zone = Some("3".into());
        };
        let got = field_of(&|m| {
            gk(m);
            m.geodetic_datum = Some("EPSG:31467".into());
        });
        assert_eq!(got, ("EPSG:31467".into(), CrsField::CodeInOtherField));
        let got = field_of(&|m| gk(m));
        assert_eq!(got, ("EPSG:31467".into(), CrsField::GaussKruegerZone));
        // MGA 2020 by UTM zone and datum code; the vertical code makes it a compound.
        let got = field_of(&|m| {
            m.eastings = 256_400.0;
            m.northings = 7_011_600.0;
            m.map_projection = Some("UTM".into());
            m.map_zone = Some("56".into());
            m.geodetic_datum = Some("EPSG:7844".into());
            m.vertical_datum = Some("EPSG:5711".into());
        });
        assert_eq!(got, ("EPSG:7856+5711".into(), CrsField::UtmZone));
        // Name 'WKT' with the WKT in Description.
        let got = field_of(&|m| {
            m.eastings = 458_000.0;
            m.northings = 5_438_000.0;
            m.crs_name = Some("WKT".into());
            m.crs_description = Some(UTM32_WKT.into());
        });
        assert_eq!(got.1, CrsField::DescriptionWkt);
        // A compound code is reported as such, placed by its horizontal part.
        let got = field_of(&|m| {
            m.eastings = 76_670.0;
            m.northings = 77_179.0;
            m.crs_name = Some("EPSG:9897".into());
        });
        assert_eq!(got, ("EPSG:9897".into(), CrsField::Name));
        // The property-set labels say so.
        assert_eq!(
            CrsField::Name.label(MapOperation::PropertySets),
            "epset-name"
        );
    }

    const UTM32_WKT: &str = r#"PROJCS["WGS 84 / UTM zone 32N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",9],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],PARAMETER["false_northing",0],UNIT["metre",1]]"#;

    /// The WKT places a point where its EPSG twin does.
    #[test]
    fn a_wkt_places_like_its_code() {
        let a = place_map_point(UTM32_WKT, 458_000.0, 5_438_000.0, 0.0).unwrap();
        let b = place_map_point("EPSG:32632", 458_000.0, 5_438_000.0, 0.0).unwrap();
        assert!((a.place.to_ecef() - b.place.to_ecef()).length() < 1e-3);
    }

    /// Model in map coordinates with E/N 0: placed at its footprint (the anchor), not at (0, 0),
    /// which lies outside the CRS's area of use.
    #[test]
    fn map_coordinates_with_a_zero_offset_are_placed_at_the_model() {
        let mut m = conversion(Some("EPSG:28992"));
        (m.eastings, m.northings, m.orthogonal_height) = (0.0, 0.0, 0.0);
        m.factors = [1.0; 3];
        m.x_axis_ordinate = 0.0;
        m.x_axis_abscissa = 1.0;
        let anchor = DVec3::new(155_000.0, 463_000.0, 2.0);
        let (g, slip) = georef_from_map_conversion(
            &m,
            Path::new("t.ifc"),
            None,
            anchor,
            None,
            None,
            &Aabb::EMPTY,
        )
        .unwrap();
        assert!(slip.is_none());
        assert!((g.longitude_deg - 5.3872).abs() < 1e-3, "{g:?}");
        assert!((g.latitude_deg - 52.1552).abs() < 1e-3, "{g:?}");
        assert_eq!(g.anchor, anchor);
        assert!((g.height_m - 2.0).abs() < 1e-9);
    }

    /// State Plane in US survey feet (no MapUnit: the CRS's unit) under a project in the same
    /// feet: one scene metre stays one ground metre (up to the grid's scale factor).
    #[test]
    fn us_survey_feet_map_and_project() {
        let mut m = conversion(Some("EPSG:2263"));
        (m.eastings, m.northings) = (988_000.0, 200_000.0);
        m.factors = [1.0; 3];
        m.project_unit_m = 1200.0 / 3937.0;
        let g = place(&m, None).unwrap();
        // Manhattan.
        assert!((g.longitude_deg + 73.98).abs() < 0.05, "{g:?}");
        assert!((g.latitude_deg - 40.75).abs() < 0.05, "{g:?}");
        let l = g.map_linear.unwrap();
        let k = g.crs.unwrap().scale_factor;
        assert!(((l * DVec3::X).length() - 1.0 / k).abs() < 1e-6);
    }

    /// Revit's slip: E/N in project millimetres under a foot-sized MapUnit are read in project
    /// units, near the site reference, with a warning naming both readings.
    #[test]
    fn eastings_in_project_units_are_read_around() {
        let mut m = conversion(Some("EPSG:28992"));
        (m.eastings, m.northings, m.orthogonal_height) = (155_000_000.0, 463_000_000.0, 0.0);
        m.factors = [1.0; 3];
        m.map_unit_m = Some(0.3048);
        m.project_unit_m = 0.001;
        assert_eq!(implausible_map_number(&m), None);
        let site = Some((5.387, 52.155));
        let (g, slip) = georef_from_map_conversion(
            &m,
            Path::new("t.ifc"),
            None,
            DVec3::ZERO,
            site,
            None,
            &Aabb::EMPTY,
        )
        .unwrap();
        let slip = slip.expect("a warning");
        assert!(slip.contains("MapUnit (0.3048 m)") && slip.contains("project unit (0.001 m)"));
        assert!((g.latitude_deg - 52.1552).abs() < 1e-3, "{g:?}");
        // One scene metre is one grid metre: the project-unit reading has no unit change.
        let x = g.map_linear.unwrap() * DVec3::X;
        assert!((x.length() - 1.0).abs() < 1e-3, "{x}");
        // Far from the site reference, the slip is not taken.
        let far = Some((-87.6, 41.9));
        assert!(georef_from_map_conversion(
            &m,
            Path::new("t.ifc"),
            None,
            DVec3::ZERO,
            far,
            None,
            &Aabb::EMPTY
        )
        .is_err());
    }

    /// A project declared in millimetres whose geometry is in metres of the map: read in the
    /// declared unit it lies a thousand times nearer the grid's origin, outside the CRS; read in
    /// metres it lands where its coordinates say, with a warning, one scene metre a thousand
    /// grid metres (the scene is in declared metres).
    #[test]
    fn geometry_in_another_unit_than_declared_is_read_around() {
        let mut m = conversion(Some("EPSG:28992"));
        (m.eastings, m.northings, m.orthogonal_height) = (0.0, 0.0, 0.0);
        m.factors = [1.0; 3];
        (m.x_axis_abscissa, m.x_axis_ordinate) = (1.0, 0.0);
        m.project_unit_m = 0.001;
        // The Amersfoort tower's block, 100 m wide, read as millimetres into scene metres.
        let bounds = Aabb {
            min: DVec3::new(155.0, 463.0, 0.0),
            max: DVec3::new(155.1, 463.1, 0.02),
        };
        let (anchor, _) = choose_anchor(&bounds);
        let site = Some((5.387, 52.155));
        let (g, slip) =
            georef_from_map_conversion(&m, Path::new("t.ifc"), None, anchor, site, None, &bounds)
                .unwrap();
        let slip = slip.expect("a warning");
        assert!(
            slip.contains("declared project unit (0.001 m)") && slip.contains("in 1 m units"),
            "{slip}"
        );
        assert!((g.longitude_deg - 5.3879).abs() < 1e-3, "{g:?}");
        assert!((g.latitude_deg - 52.1557).abs() < 1e-3, "{g:?}");
        let x = g.map_linear.unwrap() * DVec3::X;
        assert!((x.length() / 1000.0 - 1.0).abs() < 1e-3, "{x}");
        assert_eq!(
            g.anchor * 1000.0,
            choose_anchor(&Aabb {
                min: bounds.min * 1000.0,
                max: bounds.max * 1000.0
            })
            .0
        );
        // Local coordinates (a building near its own origin) are never read around.
        let local = Aabb {
            min: DVec3::ZERO,
            max: DVec3::new(0.1, 0.1, 0.02),
        };
        assert!(georef_from_map_conversion(
            &m,
            Path::new("t.ifc"),
            None,
            DVec3::ZERO,
            None,
            None,
            &local
        )
        .is_err());
    }

    /// A millimetre project under a metre map: Scale 0.001 converts the units (IFC4); with Scale
    /// omitted the units are converted all the same, not read as a grid a thousand times the
    /// ground; a Scale near 1 that is not the unit conversion stays as written.
    #[test]
    fn millimetre_projects_under_a_metre_map() {
        let x_length = |scale: f64| {
            let mut m = conversion(Some("EPSG:28992"));
            m.factors = [1.0; 3];
            m.project_unit_m = 0.001;
            m.scale = scale;
            let g = place(&m, None).unwrap();
            let k = g.crs.unwrap().scale_factor;
            (g.map_linear.unwrap() * DVec3::X).length() * k
        };
        assert!((x_length(0.001) - 1.0).abs() < 1e-5);
        assert!((x_length(1.0) - 1.0).abs() < 1e-5);
        assert!((x_length(0.0015) - 1.5).abs() < 1e-5);
    }

    /// One linear map is kept while the Earth's curvature across the model stays within a
    /// millimetre of the anchor's tangent plane; past that, every vertex goes through PROJ.
    #[test]
    fn wide_models_go_vertex_by_vertex() {
        let box_of = |half_m: f64| Aabb {
            min: DVec3::new(-half_m, -half_m, 0.0),
            max: DVec3::new(half_m, half_m, 10.0),
        };
        assert!(!needs_per_vertex(reach_m(&box_of(50.0), DVec3::ZERO)));
        assert!(needs_per_vertex(reach_m(&box_of(200.0), DVec3::ZERO)));
        assert!(!needs_per_vertex(reach_m(&Aabb::EMPTY, DVec3::ZERO)));
        // The map of a wide model takes the anchor to its map point.
        let mut m = conversion(Some("EPSG:28992"));
        m.factors = [1.0; 3];
        let anchor = DVec3::new(300.0, -200.0, 5.0);
        let (g, _) = georef_from_map_conversion(
            &m,
            Path::new("t.ifc"),
            None,
            anchor,
            None,
            None,
            &box_of(200.0),
        )
        .unwrap();
        let to_map = g.per_vertex_map.unwrap();
        let u = g.crs.unwrap();
        let at = to_map.transform_point3(anchor);
        assert!((at - DVec3::new(u.easting, u.northing, g.height_m)).length() < 1e-6);
    }
}
