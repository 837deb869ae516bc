//! Geodesy, below every stage: WGS84 places and frames, projected CRSs through PROJ ([`crs`] over
//! the FFI of [`proj`]), and UTM zone names ([`projection`]).
//!
//! Georeferencing: places the scene frame (metres, x east, y north, z up) on the WGS84 ellipsoid
//! as a local east-north-up frame at a given longitude, latitude and height. This is the root
//! `transform` of the tileset (3D Tiles 1.1, "Coordinate reference system": tileset coordinates
//! are ECEF, and a transform maps local frames into it).

pub mod crs;
pub mod proj;
pub mod projection;

use glam::{DMat4, DVec3, DVec4};

const WGS84_A: f64 = 6_378_137.0;
/// The mean Earth radius (IUGG), for estimates where the ellipsoid's flattening does not matter.
pub const MEAN_EARTH_RADIUS_M: f64 = 6_371_008.8;

/// Great-circle distance between two longitude/latitude points (degrees) on the mean sphere
/// (haversine): enough to tell places kilometres apart, not a survey distance.
pub fn great_circle_m(lon1_deg: f64, lat1_deg: f64, lon2_deg: f64, lat2_deg: f64) -> f64 {
    let (p1, p2) = (lat1_deg.to_radians(), lat2_deg.to_radians());
    let dp = p2 - p1;
    let dl = (lon2_deg - lon1_deg).to_radians();
    let h = (dp / 2.0).sin().powi(2) + p1.cos() * p2.cos() * (dl / 2.0).sin().powi(2);
    2.0 * MEAN_EARTH_RADIUS_M * h.sqrt().min(1.0).asin()
}
const WGS84_F: f64 = 1.0 / 298.257_223_563;

/// The largest coordinate, offset or extent taken as plausible, in metres (book: guide/safety.md):
/// the Earth's circumference. Every place on Earth is nearer in ECEF (at most 6.4e6 m from the
/// centre) and in any projected CRS (web Mercator reaches 2.0e7 m), and no building model spans
/// more; a number beyond it is a broken or hostile input (a 1e30 extrusion, a 1e300 offset) that
/// would give tile boxes no viewer can use. Heights of a place (`--origin`) keep to it too.
pub const PLAUSIBLE_COORDINATE_M: f64 = 4.0e7;

/// The largest (and, inverted, the smallest) scale factor taken as plausible, for map
/// conversion scales: one million converts between any two length units in use (micrometres to
/// metres, millimetres to kilometres). Zero or beyond it collapses or explodes the model.
pub const PLAUSIBLE_SCALE: f64 = 1.0e6;

/// Whether `v` is finite and within [`PLAUSIBLE_COORDINATE_M`] of zero.
pub fn plausible_m(v: f64) -> bool {
    v.is_finite() && v.abs() <= PLAUSIBLE_COORDINATE_M
}

/// Whether `s` is a plausible scale factor: finite, positive, within [1/[`PLAUSIBLE_SCALE`],
/// [`PLAUSIBLE_SCALE`]].
pub fn plausible_scale(s: f64) -> bool {
    s.is_finite() && (1.0 / PLAUSIBLE_SCALE..=PLAUSIBLE_SCALE).contains(&s)
}

/// The first number of `values` that is not [`plausible_m`].
pub fn first_implausible_m(values: impl IntoIterator<Item = f64>) -> Option<f64> {
    values.into_iter().find(|v| !plausible_m(*v))
}

/// Why a `LON,LAT[,HEIGHT]` text is not a place.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OriginError {
    #[error("origin '{text}' must be LON,LAT[,HEIGHT]")]
    Form { text: String },
    #[error("origin '{text}': {what} '{value}' is not a number")]
    NotANumber {
        text: String,
        what: &'static str,
        value: String,
    },
    #[error("origin '{text}': longitude must be in [-180,180] and latitude in [-90,90]")]
    OutOfRange { text: String },
    #[error("origin '{text}': height {height_m:e} m is not plausible (beyond ±{bound:e} m, the Earth's circumference)", bound = PLAUSIBLE_COORDINATE_M)]
    Height { text: String, height_m: f64 },
}

/// What gave a tileset its place on Earth (report.json's `georeference.origin_source`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(into = "&'static str", try_from = "String")]
pub enum OriginSource {
    /// `--origin`.
    Option,
    /// A projected CRS: an IFC map conversion, a CityJSON reference system, `--crs`.
    InputCrs,
    /// An IFC site reference, a manifest's origin.
    InputSite,
    /// Nothing: [`GeoOrigin::DEFAULT`].
    Default,
}

impl OriginSource {
    pub const ALL: [OriginSource; 4] = [
        OriginSource::Option,
        OriginSource::InputCrs,
        OriginSource::InputSite,
        OriginSource::Default,
    ];

    /// Its name in report.json, the one spelling of each value.
    pub fn name(self) -> &'static str {
        match self {
            OriginSource::Option => "option",
            OriginSource::InputCrs => "input-crs",
            OriginSource::InputSite => "input-site",
            OriginSource::Default => "default",
        }
    }
}

impl From<OriginSource> for &'static str {
    fn from(s: OriginSource) -> &'static str {
        s.name()
    }
}

impl TryFrom<String> for OriginSource {
    type Error = String;
    fn try_from(name: String) -> Result<Self, String> {
        (OriginSource::ALL.into_iter())
            .find(|s| s.name() == name)
            .ok_or_else(|| format!("unknown origin source '{name}'"))
    }
}

impl std::fmt::Display for OriginSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A place on WGS84: degrees, degrees, metres above the ellipsoid.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GeoOrigin {
    pub longitude_deg: f64,
    pub latitude_deg: f64,
    pub height_m: f64,
}

impl GeoOrigin {
    /// Where a tileset goes when the user gives no `--origin` and the input carries no
    /// georeference: Karlsruhe Institute of Technology, Germany (documented in the book:
    /// guide/georeferencing.md), so that viewers show the model on land, in a known place, rather
    /// than in the ocean at 0°,0°.
    pub const DEFAULT: GeoOrigin = GeoOrigin {
        longitude_deg: 8.4116,
        latitude_deg: 49.0124,
        height_m: 115.0,
    };

    /// Parses "LON,LAT,HEIGHT" (height optional, 0).
    pub fn parse(s: &str) -> Result<GeoOrigin, OriginError> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        if !(2..=3).contains(&parts.len()) {
            return Err(OriginError::Form { text: s.into() });
        }
        let num = |p: &str, what: &'static str| {
            p.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| OriginError::NotANumber {
                    text: s.into(),
                    what,
                    value: p.into(),
                })
        };
        let o = GeoOrigin {
            longitude_deg: num(parts[0], "longitude")?,
            latitude_deg: num(parts[1], "latitude")?,
            height_m: if parts.len() == 3 {
                num(parts[2], "height")?
            } else {
                0.0
            },
        };
        if !(-180.0..=180.0).contains(&o.longitude_deg) || !(-90.0..=90.0).contains(&o.latitude_deg)
        {
            return Err(OriginError::OutOfRange { text: s.into() });
        }
        if !plausible_m(o.height_m) {
            return Err(OriginError::Height {
                text: s.into(),
                height_m: o.height_m,
            });
        }
        Ok(o)
    }

    /// Earth-centred, earth-fixed coordinates of this place.
    pub fn to_ecef(&self) -> DVec3 {
        geodetic_to_ecef(self.longitude_deg, self.latitude_deg, self.height_m)
    }

    /// The east-north-up frame here, as a matrix from local metres to ECEF.
    pub fn enu_to_ecef(&self) -> DMat4 {
        let (lon, lat) = (
            self.longitude_deg.to_radians(),
            self.latitude_deg.to_radians(),
        );
        let east = DVec3::new(-lon.sin(), lon.cos(), 0.0);
        let up = DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
        let north = up.cross(east);
        DMat4::from_cols(
            east.extend(0.0),
            north.extend(0.0),
            up.extend(0.0),
            DVec4::from((self.to_ecef(), 1.0)),
        )
    }
}

/// WGS84 geodetic (degrees, metres) → ECEF (metres).
pub fn geodetic_to_ecef(lon_deg: f64, lat_deg: f64, h: f64) -> DVec3 {
    let (lon, lat) = (lon_deg.to_radians(), lat_deg.to_radians());
    let e2 = WGS84_F * (2.0 - WGS84_F);
    let n = WGS84_A / (1.0 - e2 * lat.sin().powi(2)).sqrt();
    DVec3::new(
        (n + h) * lat.cos() * lon.cos(),
        (n + h) * lat.cos() * lon.sin(),
        (n * (1.0 - e2) + h) * lat.sin(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn origin_sources_have_one_name_each_and_read_back() {
        for source in OriginSource::ALL {
            let json = serde_json::to_value(source).unwrap();
            assert_eq!(json, source.name());
            assert_eq!(
                serde_json::from_value::<OriginSource>(json).unwrap(),
                source
            );
        }
        assert!(serde_json::from_value::<OriginSource>("nowhere".into()).is_err());
    }

    #[test]
    fn ecef_of_known_places() {
        let p = geodetic_to_ecef(0.0, 0.0, 0.0);
        assert!((p - DVec3::new(WGS84_A, 0.0, 0.0)).length() < 1e-9);
        let pole = geodetic_to_ecef(0.0, 90.0, 0.0);
        let b = WGS84_A * (1.0 - WGS84_F);
        assert!((pole.z - b).abs() < 1e-6 && pole.x.abs() < 1e-6);
    }

    #[test]
    fn enu_axes_point_the_right_way() {
        let o = GeoOrigin::parse("8.4116,49.0124,115").unwrap();
        let m = o.enu_to_ecef();
        // 100 m up the local z axis is 100 m higher on the ellipsoid normal.
        let up = m.transform_point3(DVec3::new(0.0, 0.0, 100.0));
        assert!((up - geodetic_to_ecef(8.4116, 49.0124, 215.0)).length() < 1e-3);
        // A small step east increases longitude, north increases latitude.
        let east = m.transform_point3(DVec3::new(1.0, 0.0, 0.0));
        let north = m.transform_point3(DVec3::new(0.0, 1.0, 0.0));
        let lon_east = east.y.atan2(east.x).to_degrees();
        assert!(lon_east > 8.4116);
        assert!(north.z > m.w_axis.z);
        // Orthonormal rotation.
        let r = glam::DMat3::from_mat4(m);
        assert!((r.determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn parse_rejects_garbage() {
        assert!(GeoOrigin::parse("a,b").is_err());
        assert!(GeoOrigin::parse("1").is_err());
        assert!(GeoOrigin::parse("200,0,0").is_err());
        assert_eq!(GeoOrigin::parse("1,2").unwrap().height_m, 0.0);
    }
}
