//! Campus manifests end to end (issue 12): models placed by a manifest become one tileset whose
//! tiles pass the glTF validator and the 3D Tiles schema, draw every input triangle once, keep each
//! element's identity and building, and put the geometry at the right place on Earth.

use crate::common::*;
use bimtiles::geodesy::GeoOrigin;
use glam::{DMat4, DVec3};
use serde_json::Value;
use std::path::Path;

/// Puts `model` into `dir` (manifest paths must stay inside the manifest's folder); its name.
fn link(model: &Path, dir: &Path) -> String {
    let to = put_model_in(model, dir);
    to.file_name().unwrap().to_string_lossy().to_string()
}

/// Every vertex of a model in its own anchored scene frame (z-up metres), read by the library.
fn model_points(model: &Path) -> Vec<DVec3> {
    let s = bimtiles::ingest::read_input(model).unwrap();
    let mut out = Vec::new();
    for c in &s.components {
        for p in &s.mesh(c.mesh).primitives {
            out.extend(p.positions.iter().map(|v| {
                c.world
                    .transform_point3(DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64))
            }));
        }
    }
    out
}

#[test]
fn sample_placed_twice_keeps_identity_building_and_place() {
    let dir = tmpdir("manifest-sample");
    let name = link(&sample(), &dir);
    // One copy by an offset and a heading, one by longitude/latitude/height (about 40 m away).
    let manifest = serde_json::json!({
        "origin": {"longitude_deg": 8.4116, "latitude_deg": 49.0124, "height_m": 115.0},
        "models": [
            {"name": "north", "path": name, "east_m": 5.0, "north_m": 60.0, "up_m": 1.5, "heading_deg": 30.0},
            {"name": "south", "path": name, "longitude_deg": 8.4120, "latitude_deg": 49.0121, "height_m": 116.0, "heading_deg": -45.0}
        ]
    });
    std::fs::write(dir.join("campus.json"), manifest.to_string()).unwrap();
    let out = dir.join("out");
    let o = run(&[
        "convert",
        "--manifest",
        dir.join("campus.json").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
        "--max-tile-triangles",
        "3000",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let sample_scene = bimtiles::ingest::read_input(&sample()).unwrap();
    let one = sample_scene.triangle_count();
    assert_eq!(report["input"]["triangles"].as_u64(), Some(2 * one as u64));
    let tiles = check_tileset(&out, 2 * one);
    assert!(tiles.len() > 3, "a campus over several tiles");
    if let Some((_, errors, _)) = gltf_validator(&out) {
        assert_eq!(errors, 0, "gltf-validator errors");
    }

    // Identity and building: the same element of both copies, under prefixed ids.
    let key = &sample_scene.element(bimtiles::scene::ComponentId(0)).key;
    for building in ["north", "south"] {
        let id = format!("{building}/{key}");
        let o = run(&["inspect", out.to_str().unwrap(), "--feature", &id, "--json"]);
        assert!(
            o.status.success(),
            "{id}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let f: Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(f["properties"]["Building"], building, "{f}");
        assert!(
            f["properties"]["Hierarchy path"]
                .as_str()
                .unwrap()
                .starts_with(&format!("{building}/")),
            "{f}"
        );
    }
    let o = run(&["inspect", out.to_str().unwrap(), "--feature", key]);
    assert!(
        !o.status.success(),
        "a clashing id is only found with its building's prefix"
    );

    // Place: the input's extreme vertex along (1,2,3) of each copy, expected in ECEF from the
    // manifest alone, is a vertex of the leaf tiles (to the mm).
    let ts: Value =
        serde_json::from_slice(&std::fs::read(out.join("tileset.json")).unwrap()).unwrap();
    let root: Vec<f64> = ts["root"]["transform"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let root = DMat4::from_cols_array(&root.try_into().unwrap());
    let leaves: Vec<DVec3> = tiles
        .iter()
        .enumerate()
        .filter(|(i, _)| !tiles.iter().any(|t| t.parent == Some(*i)))
        .flat_map(|(_, t)| t.positions.iter().map(|p| root.transform_point3(*p)))
        .collect();
    let d = DVec3::new(1.0, 2.0, 3.0);
    let extreme = model_points(&sample())
        .into_iter()
        .max_by(|a, b| a.dot(d).total_cmp(&b.dot(d)))
        .unwrap();
    let origin = GeoOrigin {
        longitude_deg: 8.4116,
        latitude_deg: 49.0124,
        height_m: 115.0,
    };
    let north = origin.enu_to_ecef()
        * DMat4::from_translation(DVec3::new(5.0, 60.0, 1.5))
        * DMat4::from_rotation_z(-30f64.to_radians());
    let here = GeoOrigin {
        longitude_deg: 8.4120,
        latitude_deg: 49.0121,
        height_m: 116.0,
    };
    let south = here.enu_to_ecef() * DMat4::from_rotation_z(45f64.to_radians());
    for (what, m) in [("north", north), ("south", south)] {
        let want = m.transform_point3(extreme);
        let got = leaves
            .iter()
            .map(|p| (*p - want).length())
            .fold(f64::INFINITY, f64::min);
        assert!(
            got < 0.001,
            "{what}: nearest decoded vertex {got} m from {want}"
        );
    }
}

#[test]
fn shared_models_in_one_campus() {
    let Some(models) = ["IfcOpenHouse_IFC4.ifc", "duplex.glb", "AC20-FZK-Haus.glb"]
        .iter()
        .map(|m| shared_file(m))
        .collect::<Option<Vec<_>>>()
    else {
        return;
    };
    let dir = tmpdir("manifest-shared");
    let entries: Vec<Value> = models
        .iter()
        .enumerate()
        .map(|(i, m)| serde_json::json!({"path": link(m, &dir), "east_m": 80.0 * i as f64, "heading_deg": 15.0 * i as f64}))
        .collect();
    std::fs::write(
        dir.join("campus.json"),
        serde_json::json!({"models": entries}).to_string(),
    )
    .unwrap();
    let out = dir.join("out");
    let o = run(&[
        "convert",
        "--manifest",
        dir.join("campus.json").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let total: usize = models
        .iter()
        .map(|m| bimtiles::ingest::read_input(m).unwrap().triangle_count())
        .sum();
    check_tileset(&out, total);
    if let Some((_, errors, _)) = gltf_validator(&out) {
        assert_eq!(errors, 0, "gltf-validator errors");
    }
}

#[test]
fn bad_manifests_get_one_line_errors_and_no_output() {
    let dir = tmpdir("manifest-bad");
    let name = link(&sample(), &dir);
    for (json, want) in [
        (
            r#"{"models":[{"path":"missing.glb"}]}"#.to_string(),
            "no such model file",
        ),
        (
            r#"{"models":[{"path":"../x/sample_building.glb"}]}"#.to_string(),
            "inside the manifest",
        ),
        (
            format!(r#"{{"models":[{{"path":"{name}","height":3}}]}}"#),
            "unknown field `height`",
        ),
        ("{\"models\": [".to_string(), "not a valid manifest"),
    ] {
        std::fs::write(dir.join("bad.json"), &json).unwrap();
        let out = dir.join("out");
        let o = run(&[
            "convert",
            "--manifest",
            dir.join("bad.json").to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--quiet",
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{json}");
        assert!(
            err.contains("bad.json") && err.contains(want) && err.trim().lines().count() == 1,
            "{json}: {err}"
        );
        assert!(!out.exists(), "no output for a bad manifest");
    }
    let o = run(&[
        "convert",
        "--manifest",
        dir.join("none.json").to_str().unwrap(),
        "--out",
        dir.join("o").to_str().unwrap(),
    ]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("none.json: no such manifest file"));
}

/// `schemas/manifest.schema.json` accepts the manifests the reader accepts and refuses what it
/// refuses (structure only: files and path escapes are the reader's).
#[test]
fn manifest_schema_agrees_with_the_reader() {
    let schema: Value = serde_json::from_slice(
        &std::fs::read(repo().join("schemas/manifest.schema.json")).unwrap(),
    )
    .unwrap();
    let v = jsonschema::options()
        .with_draft(jsonschema::Draft::Draft202012)
        .build(&schema)
        .expect("schema compiles");
    let good = [
        r#"{"models":[{"path":"a.glb"}]}"#,
        r#"{"origin":{"longitude_deg":8,"latitude_deg":49},"models":[{"name":"x","path":"a.glb","east_m":1,"heading_deg":90}]}"#,
        r#"{"models":[{"path":"a.ifc","longitude_deg":8,"latitude_deg":49,"height_m":110}]}"#,
    ];
    let bad = [
        r#"{"models":[]}"#,
        r#"{"models":[{"path":"a.glb","colour":1}]}"#,
        r#"{"models":[{"path":"a.glb","east_m":1,"longitude_deg":8,"latitude_deg":49}]}"#,
        r#"{"models":[{"path":"a.glb","longitude_deg":8}]}"#,
        r#"{"models":[{"path":"a.glb","name":"a/b"}]}"#,
        r#"{"origin":{"longitude_deg":8},"models":[{"path":"a.glb"}]}"#,
    ];
    let dir = tmpdir("manifest-schema");
    std::fs::write(dir.join("a.glb"), std::fs::read(sample()).unwrap()).unwrap();
    std::fs::write(dir.join("a.ifc"), b"not read").unwrap();
    for (json, ok) in good
        .iter()
        .map(|j| (j, true))
        .chain(bad.iter().map(|j| (j, false)))
    {
        let doc: Value = serde_json::from_str(json).unwrap();
        assert_eq!(v.is_valid(&doc), ok, "schema on {json}");
        std::fs::write(dir.join("m.json"), json).unwrap();
        let read = bimtiles::ingest::manifest::Manifest::read(&dir.join("m.json"));
        assert_eq!(read.is_ok(), ok, "reader on {json}: {:?}", read.err());
    }
}
