//! Universal Transverse Mercator zones as BIM files name them ("EPSG:326zz" / "327zz" / "258zz",
//! "WGS 84 / UTM zone 32N", or an IfcProjectedCRS MapProjection "UTM" with MapZone "32N"), turned
//! into EPSG codes that PROJ places ([`super::crs`]).
//!
//! The inverse Transverse Mercator below (Krüger's series in the third flattening n, to n³; Karney,
//! "Transverse Mercator with an accuracy of a few nanometres", J. Geodesy 2011, eqs. 15–21) placed
//! UTM models before PROJ did; it stays, in tests only, as the independent check that PROJ agrees
//! with it to a millimetre.

#[cfg(test)]
const A: f64 = 6_378_137.0;
#[cfg(test)]
const F: f64 = 1.0 / 298.257_223_563;
#[cfg(test)]
const K0: f64 = 0.9996;
#[cfg(test)]
const FALSE_EASTING_M: f64 = 500_000.0;
#[cfg(test)]
const FALSE_NORTHING_SOUTH_M: f64 = 10_000_000.0;

/// A UTM zone: number 1..=60 and hemisphere.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UtmZone {
    pub zone: u8,
    pub north: bool,
}

impl UtmZone {
    /// The zone a CRS name stands for, if it is one we know: "EPSG:32632", "EPSG:25832",
    /// "urn:ogc:def:crs:EPSG::32632", "WGS 84 / UTM zone 32N", "ETRS89 / UTM zone 32N".
    pub fn from_crs_name(name: &str) -> Option<UtmZone> {
        let upper = name.trim().to_ascii_uppercase();
        if let Some(i) = upper.find("UTM ZONE") {
            let rest = upper[i + 8..].trim_start();
            let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
            let zone: u8 = digits.parse().ok()?;
            let north = match rest[digits.len()..].trim_start().chars().next() {
                Some('S') => false,
                Some('N') | None => true,
                Some(_) => return None,
            };
            return UtmZone::new(zone, north);
        }
        let code: u32 = upper
            .rsplit(|c: char| !c.is_ascii_digit())
            .find(|s| !s.is_empty())?
            .parse()
            .ok()?;
        match code {
            32601..=32660 => UtmZone::new((code - 32600) as u8, true),
            32701..=32760 => UtmZone::new((code - 32700) as u8, false),
            25828..=25838 => UtmZone::new((code - 25800) as u8, true),
            _ => None,
        }
    }

    /// The EPSG code of this zone on `datum` (an IfcProjectedCRS GeodeticDatum: "WGS84",
    /// "ETRS89", "NAD83"...; `None` is WGS 84): 326zz/327zz, 258zz, 269zz.
    pub fn epsg_code(self, datum: Option<&str>) -> Option<u32> {
        let d: String = datum
            .unwrap_or("WGS84")
            .chars()
            .filter(char::is_ascii_alphanumeric)
            .collect::<String>()
            .to_ascii_uppercase();
        let z = u32::from(self.zone);
        match (d.as_str(), self.north) {
            ("WGS84" | "EPSG4326" | "WORLDGEODETICSYSTEM1984", true) => Some(32600 + z),
            ("WGS84" | "EPSG4326" | "WORLDGEODETICSYSTEM1984", false) => Some(32700 + z),
            ("ETRS89" | "EPSG4258" | "EUROPEANTERRESTRIALREFERENCESYSTEM1989", true)
                if (28..=38).contains(&z) =>
            {
                Some(25800 + z)
            }
            ("NAD83" | "EPSG4269" | "NORTHAMERICANDATUM1983", true) if (1..=23).contains(&z) => {
                Some(26900 + z)
            }
            _ => None,
        }
    }

    fn new(zone: u8, north: bool) -> Option<UtmZone> {
        (1..=60).contains(&zone).then_some(UtmZone { zone, north })
    }

    #[cfg(test)]
    fn central_meridian_deg(self) -> f64 {
        f64::from(self.zone) * 6.0 - 183.0
    }
}

/// (latitude°, longitude°, meridian convergence°) of easting/northing `e_m`, `n_m` in `zone`.
/// The convergence is the angle from true north to grid north, positive when grid north lies
/// east (clockwise) of true north.
#[cfg(test)]
pub fn utm_to_wgs84(zone: UtmZone, e_m: f64, n_m: f64) -> (f64, f64, f64) {
    let n = F / (2.0 - F);
    let (n2, n3) = (n * n, n * n * n);
    let big_a = A / (1.0 + n) * (1.0 + n2 / 4.0 + n2 * n2 / 64.0);
    let beta = [
        n / 2.0 - 2.0 * n2 / 3.0 + 37.0 * n3 / 96.0,
        n2 / 48.0 + n3 / 15.0,
        17.0 * n3 / 480.0,
    ];
    let delta = [
        2.0 * n - 2.0 * n2 / 3.0 - 2.0 * n3,
        7.0 * n2 / 3.0 - 8.0 * n3 / 5.0,
        56.0 * n3 / 15.0,
    ];
    let northing = if zone.north {
        n_m
    } else {
        n_m - FALSE_NORTHING_SOUTH_M
    };
    let xi = northing / (K0 * big_a);
    let eta = (e_m - FALSE_EASTING_M) / (K0 * big_a);
    let (mut xi_p, mut eta_p) = (xi, eta);
    for (j, b) in beta.iter().enumerate() {
        let k = 2.0 * (j + 1) as f64;
        xi_p -= b * (k * xi).sin() * (k * eta).cosh();
        eta_p -= b * (k * xi).cos() * (k * eta).sinh();
    }
    let chi = (xi_p.sin() / eta_p.cosh()).asin();
    let mut phi = chi;
    for (j, d) in delta.iter().enumerate() {
        phi += d * (2.0 * (j + 1) as f64 * chi).sin();
    }
    let dlambda = eta_p.sinh().atan2(xi_p.cos());
    let lat = phi.to_degrees();
    let lon = zone.central_meridian_deg() + dlambda.to_degrees();
    // Convergence on the sphere, tan γ = tan Δλ sin φ: within 0.1″ of the ellipsoidal value
    // inside a zone, far below what turning a building needs.
    let gamma = (dlambda.tan() * phi.sin()).atan().to_degrees();
    (lat, lon, gamma)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crs_names() {
        let z = |s| UtmZone::from_crs_name(s);
        assert_eq!(
            z("EPSG:32632"),
            Some(UtmZone {
                zone: 32,
                north: true
            })
        );
        assert_eq!(
            z("EPSG:32733"),
            Some(UtmZone {
                zone: 33,
                north: false
            })
        );
        assert_eq!(
            z("EPSG:25832"),
            Some(UtmZone {
                zone: 32,
                north: true
            })
        );
        assert_eq!(
            z("urn:ogc:def:crs:EPSG::25833"),
            Some(UtmZone {
                zone: 33,
                north: true
            })
        );
        assert_eq!(
            z("WGS 84 / UTM zone 17S"),
            Some(UtmZone {
                zone: 17,
                north: false
            })
        );
        assert_eq!(
            z("ETRS89 / UTM zone 32N"),
            Some(UtmZone {
                zone: 32,
                north: true
            })
        );
        assert_eq!(z("EPSG:31467"), None, "Gauss-Krüger is not UTM");
        assert_eq!(z("EPSG:4326"), None);
        assert_eq!(z("UTM zone 61N"), None);
        assert_eq!(z(""), None);
    }

    /// Forward Transverse Mercator by the other textbook route (Snyder, USGS Professional Paper
    /// 1395, eqs. 8-9..8-10: series in e'² and A = Δλ cos φ), so the inverse is not checked
    /// against itself. Snyder's series is good to about a millimetre near the central meridian.
    fn snyder_forward(zone: UtmZone, lat: f64, lon: f64) -> (f64, f64) {
        let e2 = F * (2.0 - F);
        let ep2 = e2 / (1.0 - e2);
        let (phi, dl) = (
            lat.to_radians(),
            (lon - zone.central_meridian_deg()).to_radians(),
        );
        let nu = A / (1.0 - e2 * phi.sin().powi(2)).sqrt();
        let t = phi.tan().powi(2);
        let c = ep2 * phi.cos().powi(2);
        let a = dl * phi.cos();
        let m = A
            * ((1.0 - e2 / 4.0 - 3.0 * e2 * e2 / 64.0 - 5.0 * e2.powi(3) / 256.0) * phi
                - (3.0 * e2 / 8.0 + 3.0 * e2 * e2 / 32.0 + 45.0 * e2.powi(3) / 1024.0)
                    * (2.0 * phi).sin()
                + (15.0 * e2 * e2 / 256.0 + 45.0 * e2.powi(3) / 1024.0) * (4.0 * phi).sin()
                - (35.0 * e2.powi(3) / 3072.0) * (6.0 * phi).sin());
        let x = K0
            * nu
            * (a + (1.0 - t + c) * a.powi(3) / 6.0
                + (5.0 - 18.0 * t + t * t + 72.0 * c - 58.0 * ep2) * a.powi(5) / 120.0);
        let y = K0
            * (m + nu
                * phi.tan()
                * (a * a / 2.0
                    + (5.0 - t + 9.0 * c + 4.0 * c * c) * a.powi(4) / 24.0
                    + (61.0 - 58.0 * t + t * t + 600.0 * c - 330.0 * ep2) * a.powi(6) / 720.0));
        let n = if zone.north {
            y
        } else {
            y + FALSE_NORTHING_SOUTH_M
        };
        (FALSE_EASTING_M + x, n)
    }

    #[test]
    fn inverse_matches_an_independent_forward_projection() {
        let z32 = UtmZone {
            zone: 32,
            north: true,
        };
        // Karlsruhe, Sydney (zone 56 S), a point on the central meridian, the equator.
        for (zone, lat, lon) in [
            (z32, 49.0124, 8.4116),
            (
                UtmZone {
                    zone: 56,
                    north: false,
                },
                -33.8568,
                151.2153,
            ),
            (z32, 60.0, 9.0),
            (
                UtmZone {
                    zone: 31,
                    north: true,
                },
                0.0,
                3.5,
            ),
        ] {
            let (e, n) = snyder_forward(zone, lat, lon);
            let (lat2, lon2, _) = utm_to_wgs84(zone, e, n);
            // 1e-7 degrees is about a centimetre.
            assert!((lat2 - lat).abs() < 1e-7, "{lat} -> {lat2}");
            assert!((lon2 - lon).abs() < 1e-7, "{lon} -> {lon2}");
        }
        // The zone's origin: the central meridian on the equator.
        let (lat, lon, gamma) = utm_to_wgs84(z32, 500_000.0, 0.0);
        assert!(lat.abs() < 1e-12 && (lon - 9.0).abs() < 1e-12 && gamma.abs() < 1e-12);
    }

    #[test]
    fn convergence_sign_follows_the_side_of_the_central_meridian() {
        let z32 = UtmZone {
            zone: 32,
            north: true,
        };
        // 8.4116°E is west of 9°E: grid north is west of true north there.
        let (e, n) = snyder_forward(z32, 49.0124, 8.4116);
        let (_, _, gamma) = utm_to_wgs84(z32, e, n);
        let expected = ((8.4116f64 - 9.0).to_radians().tan() * 49.0124f64.to_radians().sin())
            .atan()
            .to_degrees();
        assert!(
            gamma < 0.0 && (gamma - expected).abs() < 1e-6,
            "{gamma} vs {expected}"
        );
    }
}
