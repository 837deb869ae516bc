//! Map points of any projected CRS that PROJ knows (EPSG:28992 RD New, 2056 LV95, 27700 British
//! National Grid, UTM...) placed on WGS84: the point's longitude and latitude, and the linear map
//! from grid metres around it to local east-north metres (the meridian convergence, which turns
//! grid north to true north, and the grid's scale factor there), so a model drawn in map
//! coordinates keeps its size and its north.
//!
//! A CRS that cannot be used (unknown to PROJ, not projected, a unit that is not a length, a point
//! far outside the CRS's area of use) is a [`CrsError`]; callers warn and fall back, or fail
//! under `--strict-georef`.

use super::proj::{self, Context, ProjError};
use super::{geodetic_to_ecef, GeoOrigin};
use glam::{DMat2, DMat3, DVec2};

/// How far (degrees) a point may lie outside its CRS's area of use and still be placed: projected
/// CRSs stay accurate somewhat beyond their nominal area, and sites sit near borders.
pub const AREA_OF_USE_MARGIN_DEG: f64 = 1.0;

/// Grid step (metres) of the finite differences that measure convergence and scale: small
/// against the projection's curvature, large against f64 rounding of map coordinates.
const JACOBIAN_STEP_M: f64 = 10.0;

/// Why a CRS cannot place a model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CrsError {
    #[error("CRS '{crs}' is unknown to PROJ ({why})")]
    Unknown { crs: String, why: String },
    #[error("CRS '{crs}' ({name}) is not a projected CRS, so its coordinates are not map eastings and northings")]
    NotProjected { crs: String, name: String },
    #[error("CRS '{crs}' ({name}) measures in '{unit}', which is not a length")]
    NotALength {
        crs: String,
        name: String,
        unit: String,
    },
    #[error("CRS '{crs}' ({name}): the point E {easting} N {northing} lies at {longitude_deg:.4}°, {latitude_deg:.4}°, far outside the CRS's area of use ({area})")]
    OutsideAreaOfUse {
        crs: String,
        name: String,
        easting: f64,
        northing: f64,
        longitude_deg: f64,
        latitude_deg: f64,
        area: String,
    },
    #[error("CRS '{crs}': {why}")]
    Transform { crs: String, why: String },
}

/// A map point placed on WGS84 by PROJ.
#[derive(Debug, Clone, PartialEq)]
pub struct MapPlace {
    /// The CRS as PROJ identifies it ("EPSG:28992"), or the text given when it has no id.
    pub crs: String,
    /// Its name ("Amersfoort / RD New").
    pub crs_name: String,
    /// Longitude and latitude of the point; the height is the one given (taken as ellipsoidal).
    pub place: GeoOrigin,
    /// Grid metres (east, north offsets, in metres of the CRS's unit) → local east-north metres
    /// at the point: the convergence turn and 1 / scale factor.
    pub grid_to_enu: DMat2,
    /// Angle from true north to grid north, degrees, positive when grid north lies east
    /// (clockwise) of true north.
    pub convergence_deg: f64,
    /// Grid length per ground length at the point (UTM: 0.9996 on the central meridian).
    pub scale_factor: f64,
    /// Metres per unit of the CRS's axes (1 for metres, 0.3048006 for US survey feet).
    pub unit_m: f64,
    /// The operation PROJ used from the CRS to WGS 84, and its accuracy in metres.
    pub operation: String,
    pub accuracy_m: Option<f64>,
}

/// What placed a model through a CRS, for `report.json` and `bimtiles inspect`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CrsUse {
    /// The input file placed.
    pub file: String,
    /// "EPSG:28992".
    pub crs: String,
    pub crs_name: String,
    /// Where the CRS came from: `ifc-name` (IfcProjectedCRS Name), `ifc-map-projection`
    /// (MapProjection + MapZone + GeodeticDatum), `option` (--crs), `manifest` (an entry's "crs").
    pub source: String,
    /// The map point placed (CRS units) and where it went.
    pub easting: f64,
    pub northing: f64,
    pub longitude_deg: f64,
    pub latitude_deg: f64,
    pub height_m: f64,
    /// How the height was read: heights are taken as ellipsoidal (no geoid model is applied).
    pub height_reference: String,
    pub convergence_deg: f64,
    pub scale_factor: f64,
    /// The PROJ operation to WGS 84 and its accuracy (metres; `None`: unknown).
    pub operation: String,
    pub accuracy_m: Option<f64>,
}

/// What [`CrsUse::height_reference`] says: PROJ is given no vertical CRS, so a height stays the
/// number it is, taken above the WGS84 ellipsoid.
pub const HEIGHT_TAKEN_AS_ELLIPSOIDAL: &str =
    "ellipsoidal: taken as metres above the WGS84 ellipsoid (no geoid model applied)";

impl CrsUse {
    pub fn new(file: &str, source: &str, place: &MapPlace, easting: f64, northing: f64) -> CrsUse {
        CrsUse {
            file: file.into(),
            crs: place.crs.clone(),
            crs_name: place.crs_name.clone(),
            source: source.into(),
            easting,
            northing,
            longitude_deg: place.place.longitude_deg,
            latitude_deg: place.place.latitude_deg,
            height_m: place.place.height_m,
            height_reference: HEIGHT_TAKEN_AS_ELLIPSOIDAL.into(),
            convergence_deg: place.convergence_deg,
            scale_factor: place.scale_factor,
            operation: place.operation.clone(),
            accuracy_m: place.accuracy_m,
        }
    }
}

/// The PROJ definition for a CRS text: an EPSG code written as `EPSG:n`, a bare number, an OGC
/// URN (`urn:ogc:def:crs:EPSG::n`) or an OGC URL (`http://www.opengis.net/def/crs/EPSG/0/n`)
/// becomes `EPSG:n`; anything else (a name, a WKT) is passed on as written.
pub fn normalize_crs_text(text: &str) -> String {
    match epsg_code_of(text) {
        Some(code) => format!("EPSG:{code}"),
        None => text.trim().to_string(),
    }
}

/// The EPSG code a text writes, in any of the forms [`normalize_crs_text`] reads.
pub fn epsg_code_of(text: &str) -> Option<u32> {
    let t = text.trim();
    let lower = t.to_ascii_lowercase();
    let digits = |s: &str| -> Option<u32> {
        let s = s.trim();
        (!s.is_empty() && s.len() <= 9 && s.chars().all(|c| c.is_ascii_digit()))
            .then(|| s.parse().ok())
            .flatten()
    };
    if let Some(code) = digits(t) {
        return Some(code);
    }
    if let Some(rest) = lower.strip_prefix("epsg:") {
        return digits(rest);
    }
    // The URN may carry a version between the two colons ("EPSG:9.9:28992").
    if let Some(rest) = lower.strip_prefix("urn:ogc:def:crs:epsg:") {
        return digits(rest.rsplit(':').next()?);
    }
    for prefix in ["http://", "https://"] {
        if let Some(rest) = lower
            .strip_prefix(prefix)
            .and_then(|r| r.strip_prefix("www.opengis.net/def/crs/epsg/"))
        {
            return digits(rest.rsplit('/').next()?);
        }
    }
    None
}

thread_local! {
    /// This thread's PROJ context, kept for the process: a new context opens PROJ's database cold
    /// and builds every CRS from its text again, which cost more than a small model's conversion.
    static CONTEXT: Option<Context> = Context::new();
}

/// Runs `f` with this thread's PROJ context; `definition` names the CRS when PROJ cannot start.
fn with_context<R>(
    definition: &str,
    f: impl FnOnce(&Context) -> Result<R, CrsError>,
) -> Result<R, CrsError> {
    CONTEXT.with(|ctx| match ctx {
        Some(ctx) => f(ctx),
        None => Err(transform_error(definition)("PROJ could not start".into())),
    })
}

/// The error of a transformation of `definition` that failed for the reason given.
fn transform_error(definition: &str) -> impl Fn(String) -> CrsError + '_ {
    move |why| CrsError::Transform {
        crs: definition.to_string(),
        why,
    }
}

/// The CRS of a PROJ definition; of a compound CRS (e.g. RD New + NAP height), its horizontal
/// part, which places points (heights are taken as ellipsoidal).
fn horizontal_crs<'c>(ctx: &'c Context, definition: &str) -> Result<proj::Object<'c>, CrsError> {
    // "AUTH:h+v" is PROJ's compound of the two codes: its horizontal part is the CRS of "AUTH:h",
    // made without building the compound (a round of database queries of its own).
    let definition = horizontal_code(definition).unwrap_or_else(|| definition.to_string());
    let definition = definition.as_str();
    let created = ctx.create(definition).map_err(|why| CrsError::Unknown {
        crs: definition.to_string(),
        // PROJ says "Unknown error (code 4096)" for a code it does not have.
        why: if why.message.starts_with("Unknown error") {
            "not in its database".into()
        } else {
            why.message
        },
    })?;
    match created.kind() {
        proj::PJ_TYPE_COMPOUND_CRS => {
            created
                .sub_crs(0)
                .map_err(|e: ProjError| CrsError::Transform {
                    crs: definition.to_string(),
                    why: e.message,
                })
        }
        _ => Ok(created),
    }
}

/// Converts map points of `crs_text` (easting, northing in the CRS's units, height in metres taken
/// as ellipsoidal) to east-north-up metres around `origin`, each point exactly: through PROJ to
/// longitude and latitude, then the ellipsoid and ECEF. Unlike the linear map of
/// [`place_map_point`] (exact at its point only), this keeps millimetres across a district of
/// kilometres, where the Earth's curvature alone lowers the far edge by metres. `convert` is
/// called with the converter, which fails on a point PROJ cannot transform.
pub fn with_map_to_enu<R>(
    crs_text: &str,
    origin: &GeoOrigin,
    convert: impl FnOnce(&mut dyn FnMut(glam::DVec3) -> Result<glam::DVec3, CrsError>) -> R,
) -> Result<R, CrsError> {
    let definition = normalize_crs_text(crs_text);
    let fail = transform_error(&definition);
    with_context(&definition, |ctx| {
        let crs = horizontal_crs(ctx, &definition)?;
        let op = ctx
            .operation_to_wgs84(&crs)
            .map_err(|e: ProjError| fail(e.message))?;
        let ecef_to_enu = DMat3::from_mat4(origin.enu_to_ecef()).transpose();
        let origin_ecef = origin.to_ecef();
        let mut to_enu = |p: glam::DVec3| -> Result<glam::DVec3, CrsError> {
            let ll = op.forward(p.x, p.y, 0.0).map_err(|e| fail(e.message))?;
            Ok(ecef_to_enu * (geodetic_to_ecef(ll[0], ll[1], p.z) - origin_ecef))
        };
        Ok(convert(&mut to_enu))
    })
}

/// A projected CRS as PROJ makes it from `definition`: the object, its id ("EPSG:28992", or the
/// text given when it has none), its name and metres per unit of its axes.
fn projected<'c>(
    ctx: &'c Context,
    definition: &str,
) -> Result<(proj::Object<'c>, String, String, f64), CrsError> {
    let crs = horizontal_crs(ctx, definition)?;
    let id = crs.id().unwrap_or_else(|| definition.to_string());
    let name = crs.name();
    let axes = crs.axes().unwrap_or_default();
    match crs.kind() {
        proj::PJ_TYPE_PROJECTED_CRS => {}
        proj::PJ_TYPE_GEOGRAPHIC_2D_CRS | proj::PJ_TYPE_GEOGRAPHIC_3D_CRS => {
            return Err(CrsError::NotALength {
                crs: id,
                name,
                unit: axes
                    .first()
                    .map_or("degree".into(), |a| a.unit_name.clone()),
            })
        }
        _ => return Err(CrsError::NotProjected { crs: id, name }),
    }
    let unit_m = axes.first().map_or(1.0, |a| a.unit_to_si);
    if axes.len() < 2 || !(unit_m.is_finite() && unit_m > 0.0) {
        return Err(CrsError::NotALength {
            crs: id,
            name,
            unit: axes.first().map_or("?".into(), |a| a.unit_name.clone()),
        });
    }
    Ok((crs, id, name, unit_m))
}

/// Metres per unit of the axes of the projected CRS `crs_text` (1 for metres, 0.3048006 for US
/// survey feet), without placing any point: to read map coordinates before knowing where they
/// land.
pub fn projected_unit_m(crs_text: &str) -> Result<f64, CrsError> {
    let definition = normalize_crs_text(crs_text);
    with_context(&definition, |ctx| {
        projected(ctx, &definition).map(|(_, _, _, unit_m)| unit_m)
    })
}

/// Makes the CRS `definition` names and its operation to WGS 84 in this thread's context, and
/// ignores failures (whoever uses the CRS reports them): a context's first queries open PROJ's
/// database, which costs more than placing a small model, and can run while other threads read
/// the model's geometry.
pub fn warm_up(definition: &str) {
    let definition = normalize_crs_text(definition);
    let _ = with_context(&definition, |ctx| {
        let crs = horizontal_crs(ctx, &definition)?;
        ctx.operation_to_wgs84(&crs)
            .map(drop)
            .map_err(|e| transform_error(&definition)(e.message))
    });
}

/// "AUTH:h" of a compound "AUTH:h+v" given by two codes of one authority.
fn horizontal_code(definition: &str) -> Option<String> {
    let (authority, codes) = definition.split_once(':')?;
    let (h, v) = codes.split_once('+')?;
    let is_code = |c: &str| !c.is_empty() && c.bytes().all(|b| b.is_ascii_digit());
    (is_code(h) && is_code(v) && authority.bytes().all(|b| b.is_ascii_alphabetic()))
        .then(|| format!("{authority}:{h}"))
}

/// Whether PROJ knows `definition` as a vertical CRS (a height system such as "EPSG:5711").
pub fn is_vertical_crs(definition: &str) -> bool {
    with_context(definition, |ctx| {
        Ok(ctx
            .create(definition)
            .is_ok_and(|crs| crs.kind() == proj::PJ_TYPE_VERTICAL_CRS))
    })
    .unwrap_or(false)
}

/// The id and name of `definition` when PROJ makes a compound CRS of it (a projected CRS with a
/// height, such as "EPSG:9897"): points are placed by its horizontal part, the report names the
/// whole.
pub fn compound_crs(definition: &str) -> Option<(String, String)> {
    with_context(definition, |ctx| {
        let crs = ctx.create(&normalize_crs_text(definition)).ok();
        Ok(crs
            .filter(|c| c.kind() == proj::PJ_TYPE_COMPOUND_CRS)
            .map(|c| {
                (
                    c.id().unwrap_or_else(|| definition.trim().to_string()),
                    c.name(),
                )
            }))
    })
    .ok()
    .flatten()
}

/// Refuses a place (`at`: longitude, latitude) farther than [`AREA_OF_USE_MARGIN_DEG`] outside
/// the area of use of `crs`; (`easting`, `northing`) name the point in the error.
fn check_area_of_use(
    crs: &proj::Object<'_>,
    (id, name): (&str, &str),
    (easting, northing): (f64, f64),
    at: DVec2,
) -> Result<(), CrsError> {
    let Some(area) = crs.area_of_use() else {
        return Ok(());
    };
    let m = AREA_OF_USE_MARGIN_DEG;
    let lon_inside = if area.west_deg <= area.east_deg {
        (area.west_deg - m..=area.east_deg + m).contains(&at.x)
    } else {
        // Across the antimeridian.
        at.x >= area.west_deg - m || at.x <= area.east_deg + m
    };
    let lat_inside = (area.south_deg - m..=area.north_deg + m).contains(&at.y);
    if lon_inside && lat_inside {
        return Ok(());
    }
    Err(CrsError::OutsideAreaOfUse {
        crs: id.to_string(),
        name: name.to_string(),
        easting,
        northing,
        longitude_deg: at.x,
        latitude_deg: at.y,
        area: format!(
            "{}: {:.2}°..{:.2}° E, {:.2}°..{:.2}° N",
            area.name, area.west_deg, area.east_deg, area.south_deg, area.north_deg
        ),
    })
}

/// Places a point given in a geographic CRS (`longitude_deg`, `latitude_deg` in degrees on its
/// datum, `height_m` taken as ellipsoidal): IFC4.3 IfcRigidOperation into an IfcGeographicCRS.
/// The model's own axes are then east, north, up at the point: no convergence, scale 1.
pub fn place_geographic_point(
    crs_text: &str,
    longitude_deg: f64,
    latitude_deg: f64,
    height_m: f64,
) -> Result<MapPlace, CrsError> {
    let definition = normalize_crs_text(crs_text);
    let fail = transform_error(&definition);
    with_context(&definition, |ctx| {
        let crs = horizontal_crs(ctx, &definition)?;
        let id = crs.id().unwrap_or_else(|| definition.clone());
        let name = crs.name();
        if !matches!(
            crs.kind(),
            proj::PJ_TYPE_GEOGRAPHIC_2D_CRS | proj::PJ_TYPE_GEOGRAPHIC_3D_CRS
        ) {
            return Err(fail(format!(
            "{name} is not a geographic CRS, so (longitude, latitude) in degrees cannot be placed in it"
        )));
        }
        if !((-180.0..=360.0).contains(&longitude_deg) && (-90.0..=90.0).contains(&latitude_deg)) {
            return Err(fail(format!(
                "longitude {longitude_deg}° and latitude {latitude_deg}° are not a place on Earth"
            )));
        }
        let op = ctx
            .operation_to_wgs84(&crs)
            .map_err(|e: ProjError| fail(e.message))?;
        let ll = op
            .forward(longitude_deg, latitude_deg, 0.0)
            .map_err(|e| fail(e.message))?;
        let at = DVec2::new(ll[0], ll[1]);
        check_area_of_use(&crs, (&id, &name), (longitude_deg, latitude_deg), at)?;
        let (operation, accuracy_m) = op
            .last_used()
            .unwrap_or_else(|| ("unknown operation".into(), None));
        Ok(MapPlace {
            crs: id,
            crs_name: name,
            place: GeoOrigin {
                longitude_deg: at.x,
                latitude_deg: at.y,
                height_m,
            },
            grid_to_enu: DMat2::IDENTITY,
            convergence_deg: 0.0,
            scale_factor: 1.0,
            // Degrees have no length; nothing is measured in them past this point.
            unit_m: 1.0,
            operation,
            accuracy_m,
        })
    })
}

/// Places the map point (`easting`, `northing`, in the CRS's units) of CRS `crs_text`, with
/// `height_m` taken as the ellipsoidal height.
pub fn place_map_point(
    crs_text: &str,
    easting: f64,
    northing: f64,
    height_m: f64,
) -> Result<MapPlace, CrsError> {
    let definition = normalize_crs_text(crs_text);
    let fail = transform_error(&definition);
    with_context(&definition, |ctx| {
        let (crs, id, name, unit_m) = projected(ctx, &definition)?;
        if let Some(v) = crate::geodesy::first_implausible_m([easting, northing, height_m]) {
            return Err(fail(format!(
            "the map point ({easting}, {northing}, {height_m}) holds {v:e}, not a plausible number of metres"
        )));
        }
        let op = ctx
            .operation_to_wgs84(&crs)
            .map_err(|e: ProjError| fail(e.message))?;
        let lon_lat = |e: f64, n: f64| op.forward(e, n, 0.0).map(|p| DVec2::new(p[0], p[1]));
        let centre = lon_lat(easting, northing).map_err(|e| fail(e.message))?;
        if !(centre.is_finite() && (-180.0..=180.0).contains(&centre.x)) {
            return Err(fail(format!(
            "PROJ gives no place on Earth for E {easting} N {northing} (longitude {}, latitude {})",
            centre.x, centre.y
        )));
        }
        let (operation, accuracy_m) = op
            .last_used()
            .unwrap_or_else(|| ("unknown operation".into(), None));
        check_area_of_use(&crs, (&id, &name), (easting, northing), centre)?;
        if !(-90.0..=90.0).contains(&centre.y) {
            return Err(fail(format!("latitude {} out of range", centre.y)));
        }
        let place = GeoOrigin {
            longitude_deg: centre.x,
            latitude_deg: centre.y,
            height_m,
        };
        // Local east-north metres of a grid point near the centre (on the ellipsoid: the height
        // does not change the horizontal map at this scale).
        let ecef_to_enu = DMat3::from_mat4(place.enu_to_ecef()).transpose();
        let origin_ecef = geodetic_to_ecef(centre.x, centre.y, 0.0);
        let step = JACOBIAN_STEP_M / unit_m;
        let enu_of = |de: f64, dn: f64| -> Result<DVec2, CrsError> {
            let ll = lon_lat(easting + de, northing + dn).map_err(|e| fail(e.message))?;
            let local = ecef_to_enu * (geodetic_to_ecef(ll.x, ll.y, 0.0) - origin_ecef);
            Ok(local.truncate())
        };
        let d_east = (enu_of(step, 0.0)? - enu_of(-step, 0.0)?) / (2.0 * JACOBIAN_STEP_M);
        let d_north = (enu_of(0.0, step)? - enu_of(0.0, -step)?) / (2.0 * JACOBIAN_STEP_M);
        let grid_to_enu = DMat2::from_cols(d_east, d_north);
        let det = grid_to_enu.determinant();
        if !(det.is_finite() && det > 0.0) {
            return Err(fail(format!(
                "the grid around E {easting} N {northing} does not map to the ground (det {det})"
            )));
        }
        Ok(MapPlace {
            crs: id,
            crs_name: name,
            place,
            grid_to_enu,
            // Grid north (0, 1) lands at (sin γ, cos γ) / k in east-north.
            convergence_deg: d_north.x.atan2(d_north.y).to_degrees(),
            scale_factor: 1.0 / det.sqrt(),
            unit_m,
            operation,
            accuracy_m,
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geodesy::projection::{utm_to_wgs84, UtmZone};

    /// PROJ and our own Transverse Mercator series (Karney's Krüger n³, kept as the independent
    /// check) agree to a millimetre on UTM, and on the convergence to 0.1″.
    #[test]
    fn proj_agrees_with_our_utm_to_a_millimetre() {
        for (crs, zone, north, e, n) in [
            ("EPSG:32632", 32, true, 458_000.0, 5_438_000.0),
            ("EPSG:32756", 56, false, 334_000.0, 6_252_000.0),
            ("EPSG:32631", 31, true, 700_000.0, 10_000.0),
            ("WGS 84 / UTM zone 17N", 17, true, 250_000.0, 4_000_000.0),
        ] {
            let p = place_map_point(crs, e, n, 12.0).unwrap();
            let (lat, lon, gamma) = utm_to_wgs84(UtmZone { zone, north }, e, n);
            let ours = geodetic_to_ecef(lon, lat, 12.0);
            let theirs = p.place.to_ecef();
            assert!((ours - theirs).length() < 1e-3, "{crs}: {ours} vs {theirs}");
            assert!(
                (p.convergence_deg - gamma).abs() < 0.1 / 3600.0,
                "{crs}: {} vs {gamma}",
                p.convergence_deg
            );
            assert_eq!(p.accuracy_m, Some(0.0), "{crs}: no datum shift");
        }
    }

    #[test]
    fn national_grids_convergence_and_scale() {
        // RD New at Amersfoort: its own origin, no convergence, scale 0.9999079.
        let rd = place_map_point("28992", 155_000.0, 463_000.0, 0.0).unwrap();
        assert_eq!(rd.crs, "EPSG:28992");
        assert!(rd.convergence_deg.abs() < 1e-3, "{rd:?}");
        // (The datum shift to WGS 84 adds a few ppm of scale.)
        assert!((rd.scale_factor - 0.9999079).abs() < 1e-5, "{rd:?}");
        assert!(rd.accuracy_m.is_some_and(|a| a >= 1.0), "datum shift");
        // UTM 32N at Karlsruhe: west of 9°E, grid north is west of true north; k < 1.
        let utm = place_map_point("EPSG:25832", 458_000.0, 5_438_000.0, 0.0).unwrap();
        assert!(utm.convergence_deg < -0.4 && utm.convergence_deg > -0.5);
        assert!((utm.scale_factor - 0.99962).abs() < 1e-4, "{utm:?}");
        // Gauss-Krüger's axes are northing, easting: PROJ's normalization still takes (E, N).
        let gk = place_map_point("EPSG:31467", 3_458_000.0, 5_438_000.0, 0.0).unwrap();
        assert!((gk.place.longitude_deg - 8.42).abs() < 0.01, "{gk:?}");
        // US survey feet.
        let ft = place_map_point("EPSG:2264", 2_000_000.0, 700_000.0, 0.0).unwrap();
        assert!((ft.unit_m - 0.3048006).abs() < 1e-6, "{ft:?}");
    }

    /// Per vertex, a point 5 km from the anchor lies where PROJ puts it, below the anchor's
    /// horizon by the Earth's curvature (about 2 m), which one linear map at the anchor misses.
    #[test]
    fn map_points_go_to_east_north_up_exactly() {
        let p = place_map_point("EPSG:28992", 155_000.0, 463_000.0, 10.0).unwrap();
        let far = glam::DVec3::new(160_000.0, 463_000.0, 10.0);
        let (anchor, far_enu) = with_map_to_enu("EPSG:28992", &p.place, |to_enu| {
            (
                to_enu(glam::DVec3::new(155_000.0, 463_000.0, 10.0)).unwrap(),
                to_enu(far).unwrap(),
            )
        })
        .unwrap();
        assert!(anchor.length() < 1e-6, "{anchor}");
        let drop_m = 5_000.0_f64.powi(2) / (2.0 * 6_371_000.0);
        assert!((far_enu.z + drop_m).abs() < 0.05, "{far_enu}");
        let linear = p.grid_to_enu * glam::DVec2::new(5_000.0, 0.0);
        assert!(
            (far_enu.truncate() - linear).length() < 0.05,
            "{far_enu} vs {linear}"
        );
    }

    #[test]
    fn unusable_crs_are_errors() {
        let e = place_map_point("EPSG:99999", 0.0, 0.0, 0.0).unwrap_err();
        assert!(matches!(e, CrsError::Unknown { .. }), "{e}");
        let e = place_map_point("EPSG:4326", 8.0, 49.0, 0.0).unwrap_err();
        assert!(matches!(e, CrsError::NotALength { .. }), "{e}");
        assert!(e.to_string().contains("degree"), "{e}");
        // RD New coordinates read as LV95: far outside Switzerland.
        let e = place_map_point("EPSG:2056", 155_000.0, 463_000.0, 0.0).unwrap_err();
        assert!(matches!(e, CrsError::OutsideAreaOfUse { .. }), "{e}");
        assert!(!e.to_string().contains('\n'));
    }

    #[test]
    fn compounds_of_two_codes_are_placed_by_their_first() {
        assert_eq!(
            horizontal_code("EPSG:25832+7837").as_deref(),
            Some("EPSG:25832")
        );
        for not_two_codes in [
            "EPSG:25832",
            "EPSG:+7837",
            "EPSG:25832+",
            "EPSG:2a+5",
            "+proj=utm",
        ] {
            assert_eq!(horizontal_code(not_two_codes), None, "{not_two_codes}");
        }
        let a = place_map_point("EPSG:25832+7837", 457_300.0, 5_439_400.0, 0.0).unwrap();
        let b = place_map_point("EPSG:25832", 457_300.0, 5_439_400.0, 0.0).unwrap();
        assert_eq!(a.place, b.place);
        assert!(is_vertical_crs("EPSG:7837") && !is_vertical_crs("EPSG:25832"));
    }

    #[test]
    fn epsg_codes_in_every_form() {
        for t in [
            "EPSG:28992",
            " epsg:28992 ",
            "28992",
            "urn:ogc:def:crs:EPSG::28992",
            "urn:ogc:def:crs:EPSG:9.9:28992",
            "http://www.opengis.net/def/crs/EPSG/0/28992",
            "https://www.opengis.net/def/crs/EPSG/0/28992",
        ] {
            assert_eq!(epsg_code_of(t), Some(28992), "{t}");
            assert_eq!(normalize_crs_text(t), "EPSG:28992", "{t}");
        }
        for t in ["", "NC83", "EPSG:", "Amersfoort / RD New", "EPSG:28992x"] {
            assert_eq!(epsg_code_of(t), None, "{t}");
        }
    }

    /// ETRS89 longitude/latitude: placed as given (a sub-metre datum difference to WGS 84), with
    /// no grid turn or scale.
    #[test]
    fn geographic_points_are_placed() {
        let p = place_geographic_point("EPSG:4258", 14.0902217, 46.3623297, 475.0).unwrap();
        assert!((p.place.longitude_deg - 14.0902217).abs() < 1e-5, "{p:?}");
        assert!((p.place.latitude_deg - 46.3623297).abs() < 1e-5, "{p:?}");
        assert_eq!(p.grid_to_enu, DMat2::IDENTITY);
        let e = place_geographic_point("EPSG:28992", 5.0, 52.0, 0.0).unwrap_err();
        assert!(e.to_string().contains("not a geographic CRS"), "{e}");
    }
}
