//! Real georeferenced IFC exports land where their georeferencing says.
//!
//! Every file of the shared `data/georef-ifc/` folder (12d Model, OpenRoads, Civil 3D, Revit,
//! ArchiCAD, BricsCAD/Bonsai exports and a buildingSMART example) is converted once by the real
//! binary. The expected place is read from that folder's MANIFEST.md ("where on Earth", computed
//! with pyproj from the file's own values): its "centre" when given, else its "origin". The
//! output's full-detail (leaf) triangles are read back with the `gltf` crate, their area-weighted
//! centroid taken through the root transform to ECEF and to longitude/latitude (WGS84 formula
//! here, not bimtiles' code). A building must land within 60 m of the expected place; an
//! infrastructure model within its own horizontal extent around its centroid. The file whose
//! MANIFEST row says its place is not determinable (no CRS, national-grid sized coordinates)
//! must warn and suggest `--crs`, and fail under `--strict-georef`. Warnings the exports call for
//! (a unit slip read around, a site reference that contradicts the map conversion) are checked
//! by the words they must contain.

use crate::common::*;
use glam::{DMat4, DVec3};
use serde_json::Value;
use std::path::PathBuf;

/// How near the expected place a building must land (metres).
const BUILDING_TOLERANCE_M: f64 = 60.0;

/// What a file must show besides its place.
struct Expect {
    /// A building (60 m) or infrastructure (its own extent).
    building: bool,
    /// The report's `georeference.crs[0].source`, or `None` for a placement without a CRS.
    field: Option<&'static str>,
    /// Words a warning must contain (all of them, in one warning).
    warning: &'static [&'static str],
}

/// The `georef-ifc` folder, if the shared data is there.
fn folder() -> Option<PathBuf> {
    let d = shared_data()?.join("georef-ifc");
    let found = d.is_dir();
    assert!(
        found || !tools_required(),
        "{}: missing (BIMTILES_REQUIRE_TOOLS is set)",
        d.display()
    );
    found.then_some(d)
}

/// The MANIFEST row's "where on Earth" cell for `file`.
fn manifest_place(dir: &std::path::Path, file: &str) -> String {
    let text = std::fs::read_to_string(dir.join("MANIFEST.md")).unwrap();
    let row = text
        .lines()
        .find(|l| l.split('|').nth(2).map(str::trim) == Some(file))
        .unwrap_or_else(|| panic!("{file}: no MANIFEST row"));
    // | # | file | source | licence | size | schema | conv. | georef | units | where | ...
    row.split('|').nth(10).unwrap().trim().to_string()
}

/// The first "lon E|W, lat N|S" pair after `key` in `cell` (signed degrees).
fn lon_lat_after(cell: &str, key: &str) -> Option<(f64, f64)> {
    let rest = &cell[cell.find(key)? + key.len()..];
    let words: Vec<&str> = rest
        .split(|c: char| c.is_whitespace() || c == ',' || c == ';' || c == '(' || c == ')')
        .filter(|w| !w.is_empty())
        .collect();
    for w in words.windows(4) {
        let (Ok(lon), Ok(lat)) = (w[0].parse::<f64>(), w[2].parse::<f64>()) else {
            continue;
        };
        let lon = match w[1] {
            "E" => lon,
            "W" => -lon,
            _ => continue,
        };
        let lat = match w[3] {
            "N" => lat,
            "S" => -lat,
            _ => continue,
        };
        return Some((lon, lat));
    }
    None
}

/// The expected place: the MANIFEST's centre, else its (site) origin, else the first place
/// named; `None` when the row says it is not determinable.
fn expected_place(cell: &str) -> Option<(f64, f64)> {
    if cell.contains("not determinable") {
        return None;
    }
    lon_lat_after(cell, "centre")
        .or_else(|| lon_lat_after(cell, "origin"))
        .or_else(|| lon_lat_after(cell, ""))
}

/// WGS84 ECEF → (longitude°, latitude°) by Bowring's iteration (independent of the crate).
fn ecef_to_lon_lat(p: DVec3) -> (f64, f64) {
    let a = 6_378_137.0;
    let f = 1.0 / 298.257_223_563;
    let e2 = f * (2.0 - f);
    let lon = p.y.atan2(p.x);
    let r = p.x.hypot(p.y);
    let mut lat = p.z.atan2(r * (1.0 - e2));
    for _ in 0..10 {
        let n = a / (1.0 - e2 * lat.sin().powi(2)).sqrt();
        let h = r / lat.cos() - n;
        lat = p.z.atan2(r * (1.0 - e2 * n / (n + h)));
    }
    (lon.to_degrees(), lat.to_degrees())
}

/// Metres between two places on the sphere of mean radius (enough at these tolerances).
fn ground_distance_m(a: (f64, f64), b: (f64, f64)) -> f64 {
    let (p1, p2) = (a.1.to_radians(), b.1.to_radians());
    let h = ((p2 - p1) / 2.0).sin().powi(2)
        + p1.cos() * p2.cos() * ((b.0 - a.0).to_radians() / 2.0).sin().powi(2);
    2.0 * 6_371_008.8 * h.sqrt().asin()
}

/// The area-weighted centroid of the leaf tiles' triangles (ECEF) and their largest horizontal
/// distance from it (metres, in the root frame).
fn leaf_centroid(out: &std::path::Path) -> (DVec3, f64) {
    let (ts, tiles) = decode_tileset(out);
    let root: Vec<f64> = ts["root"]["transform"]
        .as_array()
        .expect("a georeferenced root has a transform")
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let to_ecef = DMat4::from_cols_slice(&root);
    let parents: std::collections::HashSet<usize> = tiles.iter().filter_map(|t| t.parent).collect();
    let (mut sum, mut area) = (DVec3::ZERO, 0.0);
    let mut points = Vec::new();
    for (i, t) in tiles.iter().enumerate() {
        if parents.contains(&i) || t.triangles == 0 {
            continue;
        }
        for tri in t.indices.chunks_exact(3) {
            let v = |k: usize| t.positions[tri[k] as usize];
            let a = (v(1) - v(0)).cross(v(2) - v(0)).length() * 0.5;
            sum += a * (v(0) + v(1) + v(2)) / 3.0;
            area += a;
        }
        points.extend_from_slice(&t.positions);
    }
    assert!(area > 0.0, "{}: no leaf triangles", out.display());
    let c = sum / area;
    let extent = points
        .iter()
        .map(|p| (p.truncate() - c.truncate()).length())
        .fold(0.0, f64::max);
    (to_ecef.transform_point3(c), extent)
}

/// Converts `file` once and checks it against its MANIFEST row and `expect`.
fn lands_where_the_manifest_says(file: &str, expect: Expect) {
    let Some(dir) = folder() else {
        return;
    };
    let input = dir.join(file);
    let stem = input.file_stem().unwrap().to_string_lossy().to_string();
    let out = tmpdir(&format!("georef-ifc-{stem}")).join("tiles");
    let o = run(&[
        "convert",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{file}: convert failed: {stderr}");
    let report: Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    // Placed or not, the tileset is whole and valid.
    let triangles = report["input"]["triangles"].as_u64().unwrap() as usize;
    check_tileset(&out, triangles);
    gltf_validator(&out);
    let geo = &report["georeference"];
    let warnings: Vec<String> = report["warnings"]
        .as_array()
        .into_iter()
        .flatten()
        .chain(geo["warnings"].as_array().into_iter().flatten())
        .filter_map(|w| w.as_str().map(str::to_string))
        .collect();
    if !expect.warning.is_empty() {
        assert!(
            warnings
                .iter()
                .any(|w| expect.warning.iter().all(|k| w.contains(k))),
            "{file}: no warning with {:?} in {warnings:#?}",
            expect.warning
        );
        assert!(
            expect.warning.iter().all(|k| stderr.contains(k)),
            "{file}: the warning is not printed: {stderr}"
        );
    }
    // The summary says where it landed, and by what.
    let place = stdout
        .lines()
        .find(|l| l.trim_start().starts_with("place :"))
        .unwrap_or_else(|| panic!("{file}: no place line in {stdout}"));
    let source = geo["crs"][0]["source"].as_str();
    assert_eq!(source, expect.field, "{file}: {geo:#}");
    if let Some(s) = source {
        assert!(place.contains(s), "{file}: {place}");
        assert!(
            place.contains(geo["crs"][0]["crs"].as_str().unwrap()),
            "{file}: {place}"
        );
    }
    let cell = manifest_place(&dir, file);
    let Some(expected) = expected_place(&cell) else {
        // Not determinable: it warns (checked above) and --strict-georef refuses the fallback.
        assert_eq!(geo["origin_source"], "default", "{file}: {geo:#}");
        let strict = tmpdir(&format!("georef-ifc-{stem}-strict")).join("tiles");
        let o = run(&[
            "convert",
            input.to_str().unwrap(),
            "--out",
            strict.to_str().unwrap(),
            "--quiet",
            "--strict-georef",
        ]);
        assert!(!o.status.success(), "{file}: --strict-georef must fail");
        assert!(!strict.join("tileset.json").exists());
        return;
    };
    assert_ne!(geo["origin_source"], "default", "{file}: {geo:#}");
    let (centroid, extent_m) = leaf_centroid(&out);
    let landed = ecef_to_lon_lat(centroid);
    let d = ground_distance_m(landed, expected);
    let allowed_m = if expect.building {
        BUILDING_TOLERANCE_M
    } else {
        extent_m.max(BUILDING_TOLERANCE_M)
    };
    eprintln!(
        "{file}: landed {:.6}, {:.6}; MANIFEST {:.6}, {:.6}: {d:.1} m (allowed {allowed_m:.0} m), by {source:?}",
        landed.0, landed.1, expected.0, expected.1
    );
    assert!(
        d <= allowed_m,
        "{file}: lands at {landed:?}, {d:.0} m from the MANIFEST's {expected:?} (allowed {allowed_m:.0} m; {cell})"
    );
}

macro_rules! georef_file {
    ($test:ident, $file:expr, building: $b:expr, field: $field:expr, warning: $w:expr) => {
        #[test]
        fn $test() {
            lands_where_the_manifest_says(
                $file,
                Expect {
                    building: $b,
                    field: $field,
                    warning: $w,
                },
            );
        }
    };
}

georef_file!(earthworks_in_map_coordinates, "12d_Georeferencing-Earthworks-12d-1.ifc",
    building: false, field: Some("ifc-name"), warning: &[]);
georef_file!(tin_with_an_offset, "12d_Georeferencing-Tin-12d-2.ifc",
    building: false, field: Some("ifc-name"), warning: &[]);
georef_file!(gauss_krueger_map_coordinates, "12d_Georeferencing-Alignment-Tin-12d-1-Map-Coords.ifc",
    building: false, field: Some("ifc-name"), warning: &[]);
georef_file!(gauss_krueger_truncated_with_offset, "12d_Georeferencing-Alignment-Tin-12d-1-Truncated-Coords.ifc",
    building: false, field: Some("ifc-name"), warning: &[]);
georef_file!(code_in_map_zone, "OpenRoads_test1_IFC4X3_RC4.ifc",
    building: false, field: Some("ifc-map-zone-code"), warning: &[]);
georef_file!(no_crs_but_national_grid_coordinates, "OpenRoads_INDOT_PR-Twin-Branch-PavementElements.ifc",
    building: false, field: None, warning: &["--crs", "national-grid"]);
georef_file!(rigid_operation_to_a_projected_crs, "Civil3D_Hoeveelheden_Verharding_NZ.ifc",
    building: false, field: Some("ifc-name"), warning: &[]);
georef_file!(eastings_in_project_millimetres, "Revit2020_LaanOpZuid_OWL_20230717.ifc",
    building: true, field: Some("ifc-name"), warning: &["project unit", "MapUnit"]);
georef_file!(ifc2x3_property_sets_on_the_site, "Duplex_A_20110907_georeferenced.ifc",
    building: true, field: Some("epset-name"), warning: &["IfcSite", "km"]);
georef_file!(site_reference_only, "ArchiCAD20_ISSUE_005_haus.ifc",
    building: true, field: None, warning: &[]);
georef_file!(rigid_operation_in_degrees, "bSI_geographic-referencing-rigid-operation.ifc",
    building: true, field: Some("ifc-geographic-crs"), warning: &[]);
georef_file!(bridge_with_a_contradicting_site, "Van_Brienenoordbrug-IFC4X3.ifc",
    building: false, field: Some("ifc-name"), warning: &["IfcSite", "km"]);
georef_file!(scale_carries_millimetres, "ifcbridge-model03_georeferenced.ifc",
    building: false, field: Some("ifc-name"), warning: &[]);

/// The MANIFEST reader used above: centre before origin, W and S negative, the row that names no
/// place.
#[test]
fn manifest_places_are_read() {
    assert_eq!(
        expected_place("origin 150.5453 E, 26.9963 S; centre 150.5457 E, 26.9959 S (Western)"),
        Some((150.5457, -26.9959))
    );
    assert_eq!(
        expected_place("site origin 80.9108 W, 35.2548 N (Charlotte) via EPSG:32119"),
        Some((-80.9108, 35.2548))
    );
    assert_eq!(
        expected_place("14.0902217 E, 46.3623297 N, 475 m (bell tower)"),
        Some((14.0902217, 46.3623297))
    );
    assert_eq!(
        expected_place("**not determinable**: no CRS code (84.803 W, 39.705 N)"),
        None
    );
    // The forward WGS84 formula (textbook), then back.
    for (lon, lat, h) in [
        (4.3592, 50.7967, 120.0),
        (-80.91, 35.25, 0.0),
        (150.6, -23.4, 18.0),
    ] {
        let (a, f) = (6_378_137.0_f64, 1.0 / 298.257_223_563);
        let e2 = f * (2.0 - f);
        let (l, p) = (f64::to_radians(lon), f64::to_radians(lat));
        let n = a / (1.0 - e2 * p.sin().powi(2)).sqrt();
        let ecef = DVec3::new(
            (n + h) * p.cos() * l.cos(),
            (n + h) * p.cos() * l.sin(),
            (n * (1.0 - e2) + h) * p.sin(),
        );
        let back = ecef_to_lon_lat(ecef);
        assert!(ground_distance_m(back, (lon, lat)) < 1e-3, "{back:?}");
    }
}
