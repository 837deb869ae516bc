//! CityGML input with the real binary on every file of ../shared/data/citygml/ (CityGML 2.0 and
//! 3.0, PLATEAU with its `uro` ADE, SIG3D, citygml4j, OGC examples). Each file is converted once
//! and the tileset shared between the checks here: every triangle written once, gltf-validator and
//! the 3D Tiles schemas pass; the gml:ids are in the property tables and PLATEAU's ADE attributes
//! keep their `uro:` prefix; windows and doors are elements with their names; textured files keep
//! images and UVs through the atlas; `--citygml-lod` reads one LoD and names those present when
//! asked for one no object has; a prototype's appearance keeps its placements one shape.
//! Element counts, polygon areas and placement against pyproj are
//! checked independently in `tests/python/test_citygml_pyproj.py`.

use crate::common::*;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

fn citygml_files() -> Vec<PathBuf> {
    let Some(root) = shared_data()
        .map(|d| d.join("citygml"))
        .filter(|d| d.is_dir())
    else {
        assert!(!tools_required(), "shared/data/citygml is missing");
        return Vec::new();
    };
    let mut out = Vec::new();
    let mut stack = vec![root];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "gml") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// A name for a file's tileset folder.
fn key(path: &Path) -> String {
    let parent = path
        .parent()
        .unwrap()
        .file_name()
        .unwrap()
        .to_string_lossy();
    format!("{parent}-{}", path.file_stem().unwrap().to_string_lossy())
}

/// Every shared file converted once (plain tiles, full detail): (input, tileset folder, report).
fn converted() -> &'static Vec<(PathBuf, PathBuf, Value)> {
    static ONCE: OnceLock<Vec<(PathBuf, PathBuf, Value)>> = OnceLock::new();
    ONCE.get_or_init(|| {
        citygml_files()
            .into_iter()
            .map(|p| {
                let out = tmpdir(&format!("citygml-{}", key(&p))).join("tiles");
                let report = convert(&p, &out, &["--lod", "none", "--compression", "none"]);
                (p, out, report)
            })
            .collect()
    })
}

fn all_tile_bytes(dir: &Path) -> Vec<u8> {
    tileset_contents(dir)
        .into_iter()
        .flat_map(|(_, b)| b)
        .collect()
}

#[test]
fn every_citygml_file_converts_to_a_valid_tileset() {
    for (path, out, report) in converted() {
        let tris = report["input"]["triangles"].as_u64().unwrap() as usize;
        assert!(tris > 0, "{}: triangles", path.display());
        check_tileset(out, tris);
        gltf_validator(out);
    }
}

#[test]
fn gml_ids_and_ade_attributes_are_in_the_property_tables() {
    let Some((path, out, _)) = converted()
        .iter()
        .find(|(p, _, _)| p.to_string_lossy().contains("52397519_bldg"))
    else {
        return;
    };
    let text = std::fs::read_to_string(path).unwrap();
    let bytes = all_tile_bytes(out);
    let contains = |needle: &str| bytes.windows(needle.len()).any(|w| w == needle.as_bytes());
    // The Buildings' gml:ids, read from the file's text.
    let mut ids = 0;
    for part in text.split("<bldg:Building gml:id=\"").skip(1) {
        let id = part.split('"').next().unwrap();
        assert!(contains(id), "{}: gml:id {id} in the tiles", path.display());
        ids += 1;
    }
    assert_eq!(ids, 13, "the file's Buildings");
    assert!(
        contains("attributes.uro:buildingID"),
        "an uro: ADE attribute in the property schema"
    );
    assert!(
        contains("attributes.measuredHeight"),
        "bldg:measuredHeight as a property"
    );
}

#[test]
fn windows_and_doors_are_elements_with_their_names() {
    let Some((path, out, _)) = converted()
        .iter()
        .find(|(p, _, _)| p.ends_with("citygml2/Building_LOD3-EPSG25832.gml"))
    else {
        return;
    };
    let text = std::fs::read_to_string(path).unwrap();
    let bytes = all_tile_bytes(out);
    let contains = |needle: &str| bytes.windows(needle.len()).any(|w| w == needle.as_bytes());
    let mut openings = 0;
    for class in ["Window", "Door"] {
        for part in text.split(&format!("<bldg:{class} gml:id=\"")).skip(1) {
            let id = part.split('"').next().unwrap();
            let name = part
                .split("<gml:name>")
                .nth(1)
                .and_then(|n| n.split('<').next())
                .unwrap();
            assert!(
                contains(id),
                "{}: {class} {id} in the tiles",
                path.display()
            );
            assert!(contains(name), "{}: {class} name {name:?}", path.display());
            openings += 1;
        }
    }
    assert_eq!(openings, 3, "the file's two windows and a door");
}

#[test]
fn citygml_textures_survive_the_atlas() {
    for (path, out, _) in converted().iter().filter(|(p, _, _)| {
        let s = p.to_string_lossy();
        s.contains("52397519_bldg") || s.contains("lod3_building_v2")
    }) {
        let (_, tiles) = decode_tileset(out);
        let mut textured = 0;
        for uri in tiles.iter().filter_map(|t| t.uri.as_ref()) {
            for t in read_textured(out, uri) {
                assert!(!t.image.is_empty() && t.uvs.len() == t.positions.len());
                textured += t.indices.len() / 3;
            }
        }
        assert!(textured > 0, "{}: textured triangles", path.display());
    }
}

#[test]
fn citygml_lod_reads_one_lod_and_an_unknown_one_names_those_present() {
    let Some(path) = citygml_files()
        .into_iter()
        .find(|p| p.to_string_lossy().contains("52397519_bldg"))
    else {
        return;
    };
    let dir = tmpdir("citygml-lod");
    let all = converted()
        .iter()
        .find(|(p, _, _)| *p == path)
        .map(|(_, _, r)| r["input"]["triangles"].as_u64().unwrap())
        .unwrap();
    let report = convert(
        &path,
        &dir.join("lod1"),
        &["--lod", "none", "--citygml-lod", "1"],
    );
    let lod1 = report["input"]["triangles"].as_u64().unwrap();
    assert!(
        lod1 > 0 && lod1 < all,
        "LoD1 blocks: {lod1} of {all} triangles"
    );
    let missing = dir.join("lod3");
    let o = run(&[
        "convert",
        path.to_str().unwrap(),
        "--out",
        missing.to_str().unwrap(),
        "--citygml-lod",
        "3",
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("LoD 3") && err.contains("0, 1, 2"), "{err}");
    assert!(!missing.exists(), "nothing written");
}

#[test]
fn a_manifest_entry_reads_a_citygml_file_at_its_lod() {
    let Some(path) = citygml_files()
        .into_iter()
        .find(|p| p.to_string_lossy().contains("52397519_bldg"))
    else {
        return;
    };
    let dir = tmpdir("citygml-manifest");
    let name = put_model_in(&path, &dir);
    let manifest = serde_json::json!({
        "origin": {"longitude_deg": 139.7389, "latitude_deg": 35.2599, "height_m": 0.0},
        "models": [{"name": "yokosuka", "path": name.file_name().unwrap().to_str().unwrap(), "lod": "1"}]
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
        "--lod",
        "none",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let lod1 = convert(
        &path,
        &dir.join("lod1"),
        &["--lod", "none", "--citygml-lod", "1"],
    );
    assert_eq!(
        report["input"]["triangles"], lod1["input"]["triangles"],
        "the entry's LoD"
    );
}

#[test]
fn a_prototype_with_a_material_stays_one_shape_on_its_placements() {
    // Two placements of one panel, the second turned 90 degrees about z, with an X3DMaterial on
    // the prototype's polygon: both copies wear it, so dedup still shares one mesh.
    let dir = tmpdir("citygml-implicit-look");
    let panel = r#"<gml:MultiSurface gml:id="panel"><gml:surfaceMember><gml:Polygon gml:id="panel-face">
  <gml:exterior><gml:LinearRing><gml:posList srsDimension="3">0 0 0 1 0 0 1 0 1 0 0 1 0 0 0</gml:posList>
  </gml:LinearRing></gml:exterior></gml:Polygon></gml:surfaceMember></gml:MultiSurface>"#;
    let xml = format!(
        r##"<?xml version="1.0" encoding="UTF-8"?>
<CityModel xmlns="http://www.opengis.net/citygml/2.0" xmlns:gml="http://www.opengis.net/gml"
  xmlns:frn="http://www.opengis.net/citygml/cityfurniture/2.0" xmlns:xlink="http://www.w3.org/1999/xlink"
  xmlns:app="http://www.opengis.net/citygml/appearance/2.0">
<cityObjectMember><frn:CityFurniture gml:id="sign-1"><frn:lod2ImplicitRepresentation><ImplicitGeometry>
  <transformationMatrix>1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</transformationMatrix>
  <referencePoint><gml:Point><gml:pos>100 200 5</gml:pos></gml:Point></referencePoint>
  <relativeGMLGeometry>{panel}</relativeGMLGeometry>
</ImplicitGeometry></frn:lod2ImplicitRepresentation></frn:CityFurniture></cityObjectMember>
<cityObjectMember><frn:CityFurniture gml:id="sign-2"><frn:lod2ImplicitRepresentation><ImplicitGeometry>
  <transformationMatrix>0 -1 0 0 1 0 0 0 0 0 1 0 0 0 0 1</transformationMatrix>
  <referencePoint><gml:Point><gml:pos>120 200 5</gml:pos></gml:Point></referencePoint>
  <relativeGMLGeometry xlink:href="#panel"/>
</ImplicitGeometry></frn:lod2ImplicitRepresentation></frn:CityFurniture></cityObjectMember>
<app:appearanceMember><app:Appearance><app:surfaceDataMember><app:X3DMaterial>
  <app:diffuseColor>0.2 0.4 0.6</app:diffuseColor><app:target>#panel-face</app:target>
</app:X3DMaterial></app:surfaceDataMember></app:Appearance></app:appearanceMember>
</CityModel>"##
    );
    let path = dir.join("signs.gml");
    std::fs::write(&path, xml).unwrap();
    let report = convert(&path, &dir.join("out"), &[]);
    let dedup = &report["dedup"];
    assert_eq!(dedup["components"], 2, "{dedup}");
    assert_eq!(dedup["unique_shapes"], 1, "{dedup}");
    assert_eq!(dedup["congruent_rewritten"], 1, "{dedup}");
}
