//! Georeferencing of an IFC file: its site's longitude/latitude, or `IfcMapConversion` with a
//! projected CRS (UTM), turned into the place and true-north turn of the model.

use super::*;

pub(super) fn georef_from_raw(raw: engine::RawGeoref) -> Option<IfcGeoref> {
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
pub(super) fn georef_from_map_conversion(m: &IfcMapConversion) -> Option<IfcGeoref> {
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
