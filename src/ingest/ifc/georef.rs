//! Georeferencing of an IFC file: an `IfcMapConversion` in a projected CRS that PROJ knows, else
//! its site's longitude/latitude, turned into the place, true-north turn and (for a map
//! conversion) scales of the model.
//!
//! The CRS of a map conversion is chosen in this order: the IfcProjectedCRS `Name` ("EPSG:28992"
//! or a bare code, or a name PROJ knows such as "ETRS89 / UTM zone 32N"), else its
//! `MapProjection` + `MapZone` + `GeodeticDatum` (UTM), else `--crs`. A conversion that names a CRS
//! that cannot be used gives one warning, and the file falls back to its site reference or the
//! default placement.

use super::*;
use crate::geodesy::crs::{place_map_point, CrsError, CrsUse, MapPlace};
use crate::geodesy::projection::UtmZone;
use glam::{DMat2, DMat3};

/// The georeference of a file's raw data and, when its map conversion could not be used, why.
pub(super) fn georef_from_raw(
    raw: engine::RawGeoref,
    path: &Path,
    crs_option: Option<&str>,
) -> (Option<IfcGeoref>, Option<String>) {
    let mut warning = None;
    if let Some(m) = &raw.map_conversion {
        match georef_from_map_conversion(m, path, crs_option) {
            Ok(Some(g)) => return (Some(g), None),
            Ok(None) => {}
            Err(e) => warning = Some(e.to_string()),
        }
    }
    (georef_from_site(raw), warning)
}

fn georef_from_site(raw: engine::RawGeoref) -> Option<IfcGeoref> {
    let (lat, lon, h) = raw.site_reference?;
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
        map_linear: None,
        crs: None,
    })
}

/// The CRSs a map conversion names, in the order they are tried, with where each came from.
fn crs_candidates(m: &IfcMapConversion, crs_option: Option<&str>) -> Vec<(String, &'static str)> {
    let mut out = Vec::new();
    if let Some(name) = m.crs_name.as_deref().filter(|n| !n.trim().is_empty()) {
        out.push((name.trim().to_string(), "ifc-name"));
    }
    if let Some(code) = crs_of_map_projection(m) {
        out.push((code, "ifc-map-projection"));
    }
    if let Some(c) = crs_option {
        out.push((c.to_string(), "option"));
    }
    out
}

/// MapProjection + MapZone + GeodeticDatum → an EPSG code: UTM ("UTM", "32N") on WGS 84, ETRS89 or
/// NAD83.
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
    zone.epsg_code(m.geodetic_datum.as_deref())
        .map(|c| format!("EPSG:{c}"))
}

/// A map conversion placed through its CRS: the project origin is at (Eastings, Northings,
/// OrthogonalHeight); project metres go to grid metres by Scale (and IFC4X3 FactorX/Y/Z, and the
/// map and project units) and the x axis's direction (XAxisAbscissa, XAxisOrdinate), then to
/// ground east-north metres by the grid's convergence and scale factor there. `Ok(None)`: no CRS
/// is named at all; `Err`: the one-line warning for a CRS that cannot be used.
fn georef_from_map_conversion(
    m: &IfcMapConversion,
    path: &Path,
    crs_option: Option<&str>,
) -> std::result::Result<Option<IfcGeoref>, MapConversionProblem> {
    let candidates = crs_candidates(m, crs_option);
    if candidates.is_empty() {
        return Err(MapConversionProblem::NoCrs);
    }
    if !(m.eastings.is_finite() && m.northings.is_finite()) {
        return Err(MapConversionProblem::NotNumbers);
    }
    let project_unit_m = if m.project_unit_m.is_finite() && m.project_unit_m > 0.0 {
        m.project_unit_m
    } else {
        1.0
    };
    let given_map_unit_m = m.map_unit_m.filter(|u| u.is_finite() && *u > 0.0);
    let orthogonal_height = if m.orthogonal_height.is_finite() {
        m.orthogonal_height
    } else {
        0.0
    };
    let mut first_error: Option<CrsError> = None;
    for (crs, source) in candidates {
        // Eastings/Northings/OrthogonalHeight are in the MapUnit, or (none given) in the CRS's
        // own unit; PROJ takes the CRS's unit.
        let first = place_map_point(
            &crs,
            m.eastings,
            m.northings,
            orthogonal_height * given_map_unit_m.unwrap_or(1.0),
        );
        let placed = first.and_then(|p| {
            let map_unit_m = given_map_unit_m.unwrap_or(p.unit_m);
            let ratio = map_unit_m / p.unit_m;
            if (ratio - 1.0).abs() < 1e-12 {
                let h = orthogonal_height * map_unit_m;
                let p = MapPlace {
                    place: crate::geodesy::GeoOrigin {
                        height_m: h,
                        ..p.place
                    },
                    ..p
                };
                Ok((p, m.eastings, m.northings, map_unit_m))
            } else {
                let (e, n) = (m.eastings * ratio, m.northings * ratio);
                place_map_point(&crs, e, n, orthogonal_height * map_unit_m)
                    .map(|p| (p, e, n, map_unit_m))
            }
        });
        let (p, e, n, map_unit_m) = match placed {
            Ok(x) => x,
            Err(err) => {
                first_error.get_or_insert(err);
                continue;
            }
        };
        let height_m = p.place.height_m;
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
        // Project metres → map units → grid metres, per axis.
        let per_axis = |f: f64| {
            let f = if f.is_finite() && f != 0.0 { f } else { 1.0 };
            scale * f * map_unit_m / project_unit_m
        };
        let (sx, sy, sz) = (
            per_axis(m.factors[0]),
            per_axis(m.factors[1]),
            per_axis(m.factors[2]),
        );
        let rotation = DMat2::from_cols(glam::DVec2::new(a, b), glam::DVec2::new(-b, a));
        let horizontal = p.grid_to_enu * rotation * DMat2::from_diagonal(glam::DVec2::new(sx, sy));
        let linear = DMat3::from_cols(
            horizontal.x_axis.extend(0.0),
            horizontal.y_axis.extend(0.0),
            glam::DVec3::new(0.0, 0.0, sz),
        );
        // Grid north seen from the project: −θ from +y, θ the x axis's angle from grid east;
        // true north is grid north turned back by the convergence.
        let theta_deg = b.atan2(a).to_degrees();
        let crs_use = CrsUse::new(&path.display().to_string(), source, &p, e, n);
        return Ok(Some(IfcGeoref {
            longitude_deg: p.place.longitude_deg,
            latitude_deg: p.place.latitude_deg,
            height_m,
            true_north_deg: Some(p.convergence_deg - theta_deg).filter(|d| d.abs() > 1e-12),
            map_conversion: Some(m.clone()),
            anchor: DVec3::ZERO,
            map_linear: Some(linear),
            crs: Some(crs_use),
        }));
    }
    Err(MapConversionProblem::Unplaceable { first_error })
}

/// What makes a map conversion unusable at all, whatever its CRS (README, "Safety"; an error, not
/// a fallback): a Scale or FactorX/Y/Z that is zero, negative or not plausible
/// (`geodesy::plausible_scale`), or Eastings/Northings/OrthogonalHeight that are not plausible
/// metres. Absent values read as 1 (scales) and 0.
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
    let place = [
        ("Eastings", m.eastings),
        ("Northings", m.northings),
        ("OrthogonalHeight", m.orthogonal_height),
    ];
    let (name, v) = place.into_iter().find(|(_, v)| !plausible_m(v * unit_m))?;
    Some(format!(
        "IfcMapConversion {name} {v:e} is not a plausible coordinate (beyond ±{:e} m, the Earth's circumference)",
        crate::geodesy::PLAUSIBLE_COORDINATE_M
    ))
}

/// Why an IfcMapConversion cannot place the model (a warning: the model falls back).
#[derive(Debug, thiserror::Error)]
pub(super) enum MapConversionProblem {
    #[error("its IfcMapConversion names no projected CRS PROJ can use (no IfcProjectedCRS Name or MapProjection/MapZone): give --crs EPSG:CODE")]
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
        }
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
        let g =
            georef_from_map_conversion(&conversion(Some("EPSG:28992")), Path::new("t.ifc"), None)
                .unwrap()
                .unwrap();
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
        let g = georef_from_map_conversion(&conversion(None), Path::new("t.ifc"), Some("28992"))
            .unwrap()
            .unwrap();
        assert_eq!(g.crs.unwrap().source, "option");
        let w = georef_from_map_conversion(&conversion(None), Path::new("t.ifc"), None)
            .unwrap_err()
            .to_string();
        assert!(w.contains("--crs"), "{w}");
    }
}
