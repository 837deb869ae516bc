//! CityGML `srsName` (GML 3.1/3.2 §10.1.3.2): the CRS of the coordinates, as a PROJ definition,
//! and how its axes are ordered. EPSG codes come as a URN (`urn:ogc:def:crs:EPSG::6697`, with or
//! without a version), an OGC URL (`http://www.opengis.net/def/crs/EPSG/0/6697`), `EPSG:n`, or a
//! compound URN (`urn:ogc:def:crs,crs:EPSG::25832,crs:EPSG::5783`) of a horizontal and a
//! vertical CRS. A geographic CRS's axis order is PROJ's: EPSG:6697 is latitude, longitude.

use crate::geodesy::crs::{
    normalize_crs_text, place_geographic_point, with_map_to_enu, CrsError, MapPlace,
};
use crate::geodesy::proj;
use glam::DVec3;

/// The PROJ definition of an srsName (`EPSG:25832+5783` for a compound URN), or the text as
/// written when it is none of the known forms.
pub fn srs_name_definition(srs_name: &str) -> String {
    let t = srs_name.trim();
    if let Some(parts) = t.strip_prefix("urn:ogc:def:crs,") {
        let codes: Vec<String> = parts
            .split(',')
            .filter_map(|p| {
                let p = p.trim().strip_prefix("crs:").unwrap_or(p.trim());
                crate::geodesy::crs::epsg_code_of(&format!("urn:ogc:def:crs:{p}"))
                    .map(|c| c.to_string())
            })
            .collect();
        if !codes.is_empty() {
            return format!("EPSG:{}", codes.join("+"));
        }
    }
    normalize_crs_text(t)
}

/// What a CRS's coordinates are, as far as placing them goes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CrsKind {
    /// Eastings and northings (placed per vertex by the scene's placement).
    Projected,
    /// Degrees; `latitude_first` when the CRS's first axis points north.
    Geographic { latitude_first: bool },
    /// PROJ does not know it, or it is neither.
    Other,
}

/// The kind of the CRS PROJ makes of `definition` (of a compound CRS, its horizontal part).
pub fn crs_kind(definition: &str) -> CrsKind {
    let Some(ctx) = proj::Context::new() else {
        return CrsKind::Other;
    };
    let Ok(mut crs) = ctx.create(definition) else {
        return CrsKind::Other;
    };
    if crs.kind() == proj::PJ_TYPE_COMPOUND_CRS {
        match crs.sub_crs(0) {
            Ok(h) => crs = h,
            Err(_) => return CrsKind::Other,
        }
    }
    match crs.kind() {
        proj::PJ_TYPE_PROJECTED_CRS => CrsKind::Projected,
        proj::PJ_TYPE_GEOGRAPHIC_2D_CRS | proj::PJ_TYPE_GEOGRAPHIC_3D_CRS => {
            let first = crs.axes().ok().and_then(|a| a.into_iter().next());
            CrsKind::Geographic {
                latitude_first: first.is_some_and(|a| a.direction.eq_ignore_ascii_case("north")),
            }
        }
        _ => CrsKind::Other,
    }
}

/// Places geographic points (longitude, latitude in degrees, ellipsoidal height in metres) in
/// place: each to east-north-up metres around the centre of their extent at their lowest
/// height, through PROJ and the ellipsoid one by one. Returns where that centre lies.
pub(super) fn geographic_to_enu(
    definition: &str,
    polygons: &mut [super::parse::Polygon],
) -> Result<MapPlace, CrsError> {
    // The drawn points; a placed prototype is its reference point (its offsets are metres).
    let all = || {
        polygons.iter().filter(|p| !p.template).flat_map(|p| {
            let own = p.rings.iter().flatten().filter(move |_| p.anchor.is_none());
            own.copied().chain(p.anchor)
        })
    };
    let (min, max) = all().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(a, b), p| (a.min(p), b.max(p)),
    );
    let centre = (min + max) / 2.0;
    let place = place_geographic_point(definition, centre.x, centre.y, min.z)?;
    with_map_to_enu(definition, &place.place, |to_enu| {
        for polygon in polygons.iter_mut().filter(|p| !p.template) {
            match polygon.anchor.take() {
                // A prototype's axes are taken as east, north and up at its reference point.
                Some(anchor) => {
                    let at = to_enu(anchor)?;
                    polygon.rings.iter_mut().flatten().for_each(|v| *v += at);
                }
                None => {
                    for v in polygon.rings.iter_mut().flatten() {
                        *v = to_enu(*v)?;
                    }
                }
            }
        }
        Ok(())
    })??;
    Ok(place)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srs_names_become_proj_definitions() {
        for (text, def) in [
            ("http://www.opengis.net/def/crs/EPSG/0/6697", "EPSG:6697"),
            ("urn:ogc:def:crs:EPSG::25832", "EPSG:25832"),
            ("EPSG:32755", "EPSG:32755"),
            (
                "urn:ogc:def:crs,crs:EPSG::25832,crs:EPSG::5783",
                "EPSG:25832+5783",
            ),
            (
                "urn:ogc:def:crs,crs:EPSG:6.12:3068,crs:EPSG:6.12:5783",
                "EPSG:3068+5783",
            ),
        ] {
            assert_eq!(srs_name_definition(text), def, "{text}");
        }
    }

    #[test]
    fn proj_gives_the_axis_order() {
        assert_eq!(
            crs_kind("EPSG:6697"),
            CrsKind::Geographic {
                latitude_first: true
            }
        );
        assert_eq!(crs_kind("EPSG:25832+5783"), CrsKind::Projected);
        assert_eq!(crs_kind("not a crs"), CrsKind::Other);
    }
}
