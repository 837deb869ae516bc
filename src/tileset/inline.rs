//! The root tile's GLB inlined in tileset.json as a data URI (3D Tiles 1.1, "URIs": content URIs
//! may be data URIs, RFC 2397). A client reads tileset.json before it can ask for the root's
//! content, so a one-tile model's first view then needs one sequential request instead of two.
//! Only a GLB that names no other file is inlined (inside a data URI its relative references
//! would have no base), only while base64's growth costs at most the request it saves
//! ([`crate::transfer::inlining_costs_less_than_a_request`]), and only while CesiumJS's resource
//! cache can afford the URI ([`CACHE_KEY_CHARS_MAX`]).

use crate::encode::TileRecord;
use crate::error::{Error, Result};
use serde_json::Value;
use std::path::Path;

/// CesiumJS keys its resource cache (`ResourceCache`, `ResourceCacheKey`) by the content's URL, one
/// key per buffer view, accessor, image and texture of a glTF, each looked up as a property name:
/// with a data URI every lookup hashes the whole GLB in base64. A GLB is inlined only while its
/// resources times its URI's length stay within this many characters (the book's
/// design/first-view.md has what it cost).
pub const CACHE_KEY_CHARS_MAX: u64 = 10_000_000;

/// The characters CesiumJS's cache keys hash for a glTF (`json`) inlined as a data URI of
/// `uri_chars` characters ([`CACHE_KEY_CHARS_MAX`]).
fn cache_key_chars(json: &Value, uri_chars: u64) -> u64 {
    let resources: usize = ["bufferViews", "accessors", "images", "textures"]
        .iter()
        .map(|k| json[*k].as_array().map_or(0, Vec::len))
        .sum();
    resources as u64 * uri_chars
}

/// Moves the root's content file (`root.uri`, in `dir`) into `tileset["root"]["content"]["uri"]`
/// as a data URI and removes the file, when that pays off; returns whether it did. `root` is
/// marked [`TileRecord::inlined_in_tileset`].
pub fn inline_root_content(dir: &Path, tileset: &mut Value, root: &mut TileRecord) -> Result<bool> {
    let Some(uri) = root.uri.as_deref() else {
        return Ok(false);
    };
    if tileset.pointer("/root/content/uri").and_then(Value::as_str) != Some(uri) {
        return Ok(false);
    }
    let path = dir.join(uri);
    // The size decides first, so a heavy root (megabytes on a wide scene) is never read back.
    let bytes = std::fs::metadata(&path)
        .map_err(|e| Error::output_from(&path, "cannot read the root tile to inline it", e))?
        .len();
    if !crate::transfer::inlining_costs_less_than_a_request(bytes) {
        return Ok(false);
    }
    let glb = std::fs::read(&path)
        .map_err(|e| Error::output_from(&path, "cannot read the root tile to inline it", e))?;
    let json = crate::glb_container::json_chunk(&glb)
        .map_err(|e| Error::output_from(&path, "cannot read the root tile's JSON", e))?;
    if !crate::glb_container::external_uris(&json).is_empty() {
        return Ok(false);
    }
    let data_uri = crate::uri::data::encode_glb(&glb);
    if cache_key_chars(&json, data_uri.len() as u64) > CACHE_KEY_CHARS_MAX {
        return Ok(false);
    }
    tileset["root"]["content"]["uri"] = Value::String(data_uri);
    std::fs::remove_file(&path)
        .map_err(|e| Error::output_from(&path, "cannot remove the inlined root tile", e))?;
    // A tiles folder the root was alone in goes too (the output holds no empty folder).
    if let Some(folder) = path.parent().filter(|f| *f != dir) {
        let empty = std::fs::read_dir(folder).is_ok_and(|mut d| d.next().is_none());
        if empty {
            std::fs::remove_dir(folder).map_err(|e| {
                Error::output_from(folder, "cannot remove the empty tiles folder", e)
            })?;
        }
    }
    root.inlined_in_tileset = true;
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::glb_container::glb_container;
    use serde_json::json;

    fn setup(json: &[u8], bin_bytes: usize) -> (tempfile::TempDir, Value, TileRecord) {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("tiles")).unwrap();
        let glb = glb_container(json, &vec![7; bin_bytes]);
        std::fs::write(dir.path().join("tiles/r.glb"), glb).unwrap();
        let ts = json!({"root": {"content": {"uri": "tiles/r.glb"}}});
        let record = TileRecord {
            uri: Some("tiles/r.glb".into()),
            ..Default::default()
        };
        (dir, ts, record)
    }

    #[test]
    fn a_self_contained_root_goes_into_the_tileset_and_its_file_away() {
        let (dir, mut ts, mut root) = setup(br#"{"asset":{"version":"2.0"}}"#, 1000);
        let glb = std::fs::read(dir.path().join("tiles/r.glb")).unwrap();
        assert!(inline_root_content(dir.path(), &mut ts, &mut root).unwrap());
        let uri = ts["root"]["content"]["uri"].as_str().unwrap();
        assert_eq!(crate::uri::data::decode(uri).unwrap().unwrap(), glb);
        assert!(
            !dir.path().join("tiles").exists(),
            "no empty tiles folder left"
        );
        assert!(root.inlined_in_tileset);
        assert_eq!(root.uri.as_deref(), Some("tiles/r.glb"));
    }

    #[test]
    fn a_root_that_reads_other_files_or_costs_more_than_it_saves_stays_a_file() {
        let json = br#"{"images":[{"uri":"../textures/a.png"}]}"#;
        let (dir, mut ts, mut root) = setup(json, 1000);
        assert!(!inline_root_content(dir.path(), &mut ts, &mut root).unwrap());
        assert_eq!(ts["root"]["content"]["uri"], "tiles/r.glb");
        assert!(dir.path().join("tiles/r.glb").exists() && !root.inlined_in_tileset);

        let big = 3 * crate::transfer::SEQUENTIAL_REQUEST_WORTH_BYTES + 300;
        let (dir, mut ts, mut root) = setup(br#"{"asset":{"version":"2.0"}}"#, big);
        assert!(!inline_root_content(dir.path(), &mut ts, &mut root).unwrap());
        assert!(dir.path().join("tiles/r.glb").exists() && !root.inlined_in_tileset);

        // 100 resources x a URI of about 133 KB: over CesiumJS's cache-key budget.
        let views = vec![json!({"buffer": 0, "byteLength": 4}); 100];
        let json = serde_json::to_vec(&json!({"bufferViews": views})).unwrap();
        let (dir, mut ts, mut root) = setup(&json, 100_000);
        assert!(!inline_root_content(dir.path(), &mut ts, &mut root).unwrap());
        assert!(dir.path().join("tiles/r.glb").exists() && !root.inlined_in_tileset);
        // The same resources in a small GLB are within it.
        let (dir, mut ts, mut root) = setup(&json, 10_000);
        assert!(inline_root_content(dir.path(), &mut ts, &mut root).unwrap());
    }
}
