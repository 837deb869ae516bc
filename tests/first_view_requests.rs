//! Fewer sequential requests before the first frame (issue 28): a texture file one tile alone
//! uses is inside that tile, files shared by several tiles stay files, and the metadata schema is
//! inline in the tiles of a small tileset (no tileset.json schema, no schema.json) or one shared
//! file otherwise. Read back with the `gltf` and `image` crates, checked by gltf-validator and the
//! official 3D Tiles JSON schemas.

use crate::common::*;
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Per image of each tile GLB: `Ok(bytes)` when embedded, `Err(uri)` when a file; by tile URI
/// (a data URI for an inlined root).
fn tile_images(dir: &Path) -> BTreeMap<String, Vec<Result<Vec<u8>, String>>> {
    let (_, tiles) = decode_tileset(dir);
    let mut out = BTreeMap::new();
    for uri in tiles.iter().filter_map(|t| t.uri.clone()) {
        let bytes = read_content(dir, &uri);
        let g = gltf::Gltf::from_slice_without_validation(&bytes)
            .expect("the gltf crate reads the tile");
        let blob = g.blob.as_deref().unwrap_or(&[]);
        let images = g
            .images()
            .map(|im| match im.source() {
                gltf::image::Source::View { view, .. } => {
                    Ok(blob[view.offset()..view.offset() + view.length()].to_vec())
                }
                gltf::image::Source::Uri { uri, .. } => Err(uri.to_string()),
            })
            .collect();
        out.insert(uri, images);
    }
    out
}

fn decodes(bytes: &[u8]) -> bool {
    image::load_from_memory(bytes).is_ok()
}

/// The `EXT_structural_metadata` of a tile GLB.
fn metadata_of(dir: &Path, tile_uri: &str) -> Value {
    let json = glb_json(&content_bytes(dir, tile_uri));
    json["extensions"]["EXT_structural_metadata"].clone()
}

/// The one tile of a one-tile conversion of LoD3_Railway (without the coarse root above it)
/// carries all its textures (the input's
/// own bytes, without cropping) and its schema: the client asks for tileset.json and the GLB.
#[test]
fn one_tile_carries_its_textures_and_schema() {
    let Some(model) = shared_file("LoD3_Railway.glb") else {
        return;
    };
    let inputs = input_images(&model);
    for (name, extra) in [
        ("uncropped", &["--texture-crop", "off"][..]),
        ("cropped", &[][..]),
        ("ktx2", &["--texture-format", "ktx2"][..]),
    ] {
        let dir = tmpdir(&format!("trips-one-tile-{name}")).join("tiles");
        let report = convert(&model, &dir, &[extra, &["--no-coarse-root"]].concat());
        assert_eq!(report["output"]["tiles_with_content"], 1, "{name}");
        assert!(!dir.join("textures").exists(), "{name}: no texture file");
        assert!(!dir.join("schema.json").exists(), "{name}: no schema file");
        assert_eq!(report["textures"]["external_files"], 0, "{name}");
        let images = tile_images(&dir);
        let (tile, images) = images.iter().next().unwrap();
        assert_eq!(images.len(), inputs.len(), "{name}: every input image");
        for im in images {
            let bytes = im.as_ref().expect("embedded");
            match name {
                // Level 0 uncropped is the input's bytes, untouched.
                "uncropped" => assert!(inputs.contains(bytes), "{name}: an input image"),
                "ktx2" => assert_eq!(&bytes[..12], b"\xABKTX 20\xBB\r\n\x1A\n"),
                _ => assert!(decodes(bytes), "{name}: the image decodes"),
            }
        }
        let ext = metadata_of(&dir, tile);
        assert!(ext.get("schemaUri").is_none(), "{name}");
        check_inline_schema(&dir, &ext["schema"]);
        gltf_validator(&dir);
    }
}

/// The inline schema holds the properties of the tile's table, and passes the official 3D Tiles
/// schema (as a tileset's `schema`); tileset.json itself names no schema.
fn check_inline_schema(dir: &Path, schema: &Value) {
    let ts: Value =
        serde_json::from_slice(&std::fs::read(dir.join("tileset.json")).unwrap()).unwrap();
    assert!(ts.get("schema").is_none() && ts.get("schemaUri").is_none());
    assert_eq!(schema["id"], "bimtiles");
    let mut with_schema = ts.clone();
    with_schema["schema"] = schema.clone();
    if let Some(errors) = tileset_schema_errors(&with_schema) {
        assert!(errors.is_empty(), "{errors:?}");
    }
}

/// Many tiles (LoD3_Railway at 1000 triangles a tile): a texture level whose copies in the tiles
/// using it would cost more than a request (100 KB) stays one file, the others are inside those
/// tiles; every image decodes; the schema is one file (too big to repeat in every tile).
#[test]
fn shared_textures_stay_files_in_a_multi_tile_tileset() {
    let Some(model) = shared_file("LoD3_Railway.glb") else {
        return;
    };
    let dir = tmpdir("trips-many-tiles").join("tiles");
    let report = convert(&model, &dir, &["--max-tile-triangles", "1000"]);
    assert!(report["output"]["tiles_with_content"].as_u64().unwrap() > 1);
    let images = tile_images(&dir);
    let mut users: BTreeMap<&str, usize> = BTreeMap::new();
    let mut embedded_large = 0;
    for ims in images.values() {
        for im in ims {
            match im {
                Ok(bytes) => {
                    assert!(decodes(bytes));
                    embedded_large += usize::from(bytes.len() >= 1024);
                }
                Err(uri) => {
                    let file = std::fs::read(dir.join("tiles").join(uri)).unwrap();
                    assert!(decodes(&file), "{uri} decodes");
                    *users.entry(uri).or_default() += 1;
                }
            }
        }
    }
    assert!(!users.is_empty(), "shared levels stay files");
    assert!(embedded_large > 0, "a level of one tile moved into it");
    for (uri, n) in &users {
        let bytes = std::fs::metadata(dir.join("tiles").join(uri))
            .unwrap()
            .len();
        assert!(
            (*n as u64 - 1) * bytes > bimtiles::transfer::SEQUENTIAL_REQUEST_WORTH_BYTES as u64,
            "{uri}: {n} copies of {bytes} B cost less than a request"
        );
    }
    let files = std::fs::read_dir(dir.join("textures")).unwrap().count();
    assert_eq!(files, users.len(), "no file left that no tile uses");
    assert_eq!(report["textures"]["external_files"], files);
    for tile in images.keys() {
        assert_eq!(metadata_of(&dir, tile)["schemaUri"], "../schema.json");
    }
    let schema: Value =
        serde_json::from_slice(&std::fs::read(dir.join("schema.json")).unwrap()).unwrap();
    check_inline_schema(&dir, &schema);
    gltf_validator(&dir);
}

/// A small schema repeated in a few tiles: inline in each, only what its table uses.
#[test]
fn a_small_schema_is_inline_in_each_of_a_few_tiles() {
    let dir = tmpdir("trips-sample").join("tiles");
    let report = convert(&sample(), &dir, &["--max-tile-triangles", "2000"]);
    let tiles = report["output"]["tiles_with_content"].as_u64().unwrap();
    assert!(tiles > 1);
    assert!(!dir.join("schema.json").exists());
    let (_, decoded) = decode_tileset(&dir);
    for t in decoded.iter().filter(|t| t.uri.is_some()) {
        let ext = metadata_of(&dir, t.uri.as_deref().unwrap());
        let name = t.name.as_deref().unwrap();
        let props = ext["schema"]["classes"]["element"]["properties"]
            .as_object()
            .unwrap();
        let columns = ext["propertyTables"][0]["properties"].as_object().unwrap();
        let (a, b): (BTreeSet<_>, BTreeSet<_>) = (props.keys().collect(), columns.keys().collect());
        assert_eq!(
            a, b,
            "{name}: the schema has the table's properties, no more"
        );
        check_inline_schema(&dir, &ext["schema"]);
    }
    gltf_validator(&dir);
}

/// The root inlined (the default): a one-tile model's GLB goes into tileset.json as a data URI,
/// the bytes of the tile a `--no-inline-root` run writes (decoded here with the `base64` crate,
/// checked by gltf-validator where it is), and the rest of tileset.json as the plain run's (valid
/// against the 3D Tiles schemas); `inspect` reads it. A root that names other files (Mini_Project's
/// schema.json), whose base64 grows by more than a request's worth (LoD3_Railway's coarse root,
/// 406 KB) or whose resources would cost CesiumJS's cache keys too much (the sample: 177
/// resources x 155 KB) stays a file: the output is the plain run's.
#[test]
fn inline_root_puts_a_self_contained_root_in_tileset_json() {
    let Some(model) = shared_file("IfcOpenHouse_IFC4.glb") else {
        return;
    };
    let base = tmpdir("inline-root");
    let (plain, inlined) = (base.join("plain"), base.join("inlined"));
    convert(&model, &plain, &["--no-inline-root"]);
    let report = convert(&model, &inlined, &[]);
    let names: BTreeSet<String> = std::fs::read_dir(&inlined)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    // The element index is fetched by the viewer after the first view, not before it.
    assert_eq!(
        names,
        BTreeSet::from([
            "element-index.json".into(),
            "report.json".into(),
            "tileset.json".into()
        ])
    );
    let read_json =
        |p: &Path| -> Value { serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap() };
    let ts = read_json(&inlined.join("tileset.json"));
    let uri = ts["root"]["content"]["uri"].as_str().unwrap();
    assert!(
        uri.starts_with("data:model/gltf-binary;base64,"),
        "a GLB data URI"
    );
    let glb = content_bytes(&inlined, uri);
    assert_eq!(glb, std::fs::read(plain.join("tiles/r.glb")).unwrap());
    let mut expected = read_json(&plain.join("tileset.json"));
    expected["root"]["content"]["uri"] = Value::from(uri);
    assert_eq!(ts, expected, "only the root's content URI differs");
    if let Some(errors) = tileset_schema_errors(&ts) {
        assert!(errors.is_empty(), "{errors:?}");
    }
    // The validator reads the inlined GLB from tileset.json itself.
    if let Some((files, errors, _)) = gltf_validator(&inlined) {
        assert_eq!((files, errors), (1, 0));
    }
    assert_eq!(report["tiles"][0]["content"], "tiles/r.glb");
    assert_eq!(report["tiles"][0]["inlined_in_tileset"], true);
    let summary = |dir: &Path| {
        let o = run(&["inspect", dir.to_str().unwrap()]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8(o.stdout).unwrap()
    };
    assert_eq!(summary(&inlined), summary(&plain));

    let sample = sample();
    for (name, model, files) in [
        (
            "schema-file",
            shared_file("ISSUE_021_Mini_Project.glb"),
            &["schema.json"][..],
        ),
        (
            "heavy",
            shared_file("LoD3_Railway.glb"),
            &["tiles/r-lod1.glb"][..],
        ),
        ("cache-keys", Some(sample), &[][..]),
    ] {
        let Some(model) = model else {
            continue;
        };
        let (plain, kept) = (base.join(format!("{name}-plain")), base.join(name));
        convert(&model, &plain, &["--no-inline-root"]);
        let report = convert(&model, &kept, &[]);
        assert!(report["tiles"]
            .as_array()
            .unwrap()
            .iter()
            .all(|t| t.get("inlined_in_tileset").is_none()));
        for f in ["tileset.json", "tiles/r.glb"].iter().chain(files) {
            assert_eq!(
                std::fs::read(kept.join(f)).unwrap(),
                std::fs::read(plain.join(f)).unwrap(),
                "{name}: {f}"
            );
        }
    }
}
