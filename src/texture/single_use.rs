//! Shared texture files whose copies cost less than a request, moved into the tiles that reference
//! them: once every tile is written, each file under `textures/` ([`super::external`])
//! whose copies pass [`copies_cost_less_than_a_request`] (`n` tiles reference it, `(n - 1) x its
//! bytes` is at most a request's worth) becomes a `bufferView` image of each of those tiles' GLBs
//! (glTF 2.0 §3.6.1.1, "images" with `bufferView` and `mimeType`) and the file is removed. A
//! separate file is downloaded and cached once, but costs every tile that uses it a request
//! (CesiumJS fetches a tile's images only after its GLB, so one round trip more before the tile
//! shows): it pays off only when its copies would cost more than that, the rule the schema's
//! placement follows. A file of one tile always moves. Run over the written tiles, not while they
//! are written, because which tiles use a pyramid level is known only at the end (HLOD content,
//! atlases, sharded jobs): the result depends only on the tiles' bytes, so every build of the same
//! tileset (threads, memory budgets, shards) gives the same bytes.

use super::external::TEXTURE_DIR;
use crate::error::{Error, Result};
use crate::glb_container::glb_container;
use crate::output_dir::write_renamed;
use crate::transfer::copies_cost_less_than_a_request;
use rayon::prelude::*;
use serde_json::{json, Value};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// How a tile in `tiles/` refers to a shared file.
const FROM_TILES: &str = "../textures/";

/// What moving texture files into the tiles that use them did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FilesEmbedded {
    /// Files moved into the tiles that use them (and removed from `textures/`).
    pub files: usize,
    /// New size of each rewritten tile, by its URI relative to the tileset.
    pub tile_bytes: BTreeMap<String, u64>,
}

/// The header and JSON chunk of the GLB at `path` (the whole file is not needed to list its
/// images).
fn read_json_chunk(path: &Path) -> Result<Value> {
    use std::io::Read;
    let fail = |e: std::io::Error| Error::output_from(path, "cannot read the written tile", e);
    let mut f = std::fs::File::open(path).map_err(fail)?;
    let mut header = [0u8; 20];
    f.read_exact(&mut header).map_err(fail)?;
    let n = u32::from_le_bytes(header[12..16].try_into().expect("4 bytes")) as usize;
    let mut glb = header.to_vec();
    glb.resize(20 + n, 0);
    f.read_exact(&mut glb[20..]).map_err(fail)?;
    crate::glb_container::json_chunk(&glb)
        .map_err(|e| Error::output_from(path, "not a GLB this build wrote", e))
}

/// Shared files each image of `gltf` references, by image index.
fn shared_files(gltf: &Value) -> Vec<(usize, String)> {
    let images = gltf["images"].as_array().map_or(&[][..], |v| v.as_slice());
    images
        .iter()
        .enumerate()
        .filter_map(|(i, im)| {
            let uri = im["uri"].as_str()?.strip_prefix(FROM_TILES)?;
            Some((i, uri.to_string()))
        })
        .collect()
}

/// Why a written tile could not take its images in.
#[derive(Debug, thiserror::Error)]
pub enum EmbedError {
    #[error(transparent)]
    Glb(#[from] crate::glb_container::GlbError),
    #[error("GLB shorter than its buffer")]
    Short,
    #[error("a GLB without bufferViews")]
    NoBufferViews,
    #[error("no image {0}")]
    NoImage(usize),
    #[error("cannot serialize the glTF JSON: {0}")]
    Json(#[from] serde_json::Error),
}

/// `glb` with each image of `files` (image index, file bytes) stored in its BIN chunk instead
/// of referenced by URI.
pub fn embed_images(
    glb: &[u8],
    files: &[(usize, Vec<u8>)],
) -> std::result::Result<Vec<u8>, EmbedError> {
    let mut gltf = crate::glb_container::json_chunk(glb)?;
    let json_len = u32::from_le_bytes(glb[12..16].try_into().expect("4 bytes")) as usize;
    // The BIN chunk's data, without its padding: buffer 0's byteLength (glTF 2.0 §4.4.3.3).
    let bin_start = 20 + json_len + 8;
    let bin_len = gltf["buffers"][0]["byteLength"].as_u64().unwrap_or(0) as usize;
    let mut bin = match bin_len {
        0 => Vec::new(),
        n => glb
            .get(bin_start..bin_start + n)
            .ok_or(EmbedError::Short)?
            .to_vec(),
    };
    // Images with the same bytes (one file referenced twice) share one view.
    let mut view_of: BTreeMap<&[u8], usize> = BTreeMap::new();
    for (image, bytes) in files {
        let view = match view_of.get(&bytes[..]) {
            Some(&view) => view,
            None => {
                bin.resize(bin.len().next_multiple_of(4), 0);
                let views = gltf["bufferViews"]
                    .as_array_mut()
                    .ok_or(EmbedError::NoBufferViews)?;
                views
                    .push(json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len()}));
                bin.extend_from_slice(bytes);
                view_of.insert(bytes, views.len() - 1);
                views.len() - 1
            }
        };
        let im = gltf["images"][*image]
            .as_object_mut()
            .ok_or(EmbedError::NoImage(*image))?;
        im.remove("uri");
        im.insert("bufferView".into(), json!(view));
    }
    // Buffer 0 is the BIN chunk; others (an EXT_meshopt_compression fallback) stay as they are.
    match gltf["buffers"].as_array_mut() {
        Some(buffers) if !buffers.is_empty() => buffers[0] = json!({"byteLength": bin.len()}),
        _ => gltf["buffers"] = json!([{"byteLength": bin.len()}]),
    }
    let json = serde_json::to_vec(&gltf)?;
    Ok(glb_container(&json, &bin))
}

/// What a client fetches for the tile `uri` (a GLB relative to `dir`): its bytes and those of the
/// shared texture files it references.
pub fn fetched_bytes(dir: &Path, uri: &str) -> Result<u64> {
    let path = dir.join(uri);
    let size = |p: &Path| {
        std::fs::metadata(p)
            .map(|m| m.len())
            .map_err(|e| Error::output_from(p, "cannot read the written file", e))
    };
    let mut bytes = size(&path)?;
    for (_, name) in shared_files(&read_json_chunk(&path)?) {
        bytes += size(&dir.join(TEXTURE_DIR).join(name))?;
    }
    Ok(bytes)
}

/// Moves every file of `<dir>/textures/` whose copies cost less than a request (module docs)
/// into each of `tiles` (GLB URIs relative to `dir`) that references it, then removes the file.
pub fn embed_files_cheaper_than_a_request(dir: &Path, tiles: &[&str]) -> Result<FilesEmbedded> {
    let texture_dir = dir.join(TEXTURE_DIR);
    if !texture_dir.is_dir() {
        return Ok(FilesEmbedded::default());
    }
    let listed = tiles
        .par_iter()
        .map(|&uri| Ok(shared_files(&read_json_chunk(&dir.join(uri))?)))
        .collect::<Result<Vec<_>>>()?;
    // The tiles referencing each file (a tile may do so from several images).
    let mut users: BTreeMap<&str, BTreeSet<usize>> = BTreeMap::new();
    for (t, files) in listed.iter().enumerate() {
        for (_, name) in files {
            users.entry(name).or_default().insert(t);
        }
    }
    let file_bytes = |name: &str| {
        let p = texture_dir.join(name);
        std::fs::metadata(&p)
            .map(|m| m.len())
            .map_err(|e| Error::output_from(&p, "cannot read the written texture", e))
    };
    let mut cheap = BTreeSet::new();
    for (&name, tiles) in &users {
        if copies_cost_less_than_a_request(tiles.len() as u64, file_bytes(name)?) {
            cheap.insert(name);
        }
    }
    // Per tile, the images whose file moves into it.
    let mut moves: BTreeMap<usize, Vec<(usize, &str)>> = BTreeMap::new();
    for (t, files) in listed.iter().enumerate() {
        for (image, name) in files {
            if cheap.contains(name.as_str()) {
                moves.entry(t).or_default().push((*image, name));
            }
        }
    }
    let rewritten = moves
        .par_iter()
        .map(|(&t, images)| {
            let path = dir.join(tiles[t]);
            let files = images
                .iter()
                .map(|&(image, name)| {
                    let p = texture_dir.join(name);
                    let bytes = std::fs::read(&p).map_err(|e| {
                        Error::output_from(&p, "cannot read the written texture", e)
                    })?;
                    Ok((image, bytes))
                })
                .collect::<Result<Vec<_>>>()?;
            let glb = std::fs::read(&path)
                .map_err(|e| Error::output_from(&path, "cannot read the written tile", e))?;
            let glb = embed_images(&glb, &files)
                .map_err(|e| Error::output_from(&path, "cannot embed its textures", e))?;
            write_renamed(&path, &glb)?;
            Ok((tiles[t].to_string(), glb.len() as u64))
        })
        .collect::<Result<BTreeMap<_, _>>>()?;
    for name in &cheap {
        let p = texture_dir.join(name);
        std::fs::remove_file(&p)
            .map_err(|e| Error::output_from(&p, "cannot remove the embedded texture", e))?;
    }
    if std::fs::read_dir(&texture_dir).is_ok_and(|mut d| d.next().is_none()) {
        let _ = std::fs::remove_dir(&texture_dir);
    }
    Ok(FilesEmbedded {
        files: cheap.len(),
        tile_bytes: rewritten,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transfer::SEQUENTIAL_REQUEST_WORTH_BYTES;

    /// A GLB of two images, both files, and 6 bytes of buffer.
    fn glb_of_two_files() -> Vec<u8> {
        let gltf = json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": 6}],
            "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 6}],
            "images": [
                {"uri": "../textures/a.png", "mimeType": "image/png"},
                {"uri": "../textures/b.jpg", "mimeType": "image/jpeg"},
            ],
        });
        glb_container(&serde_json::to_vec(&gltf).unwrap(), &[1, 2, 3, 4, 5, 6])
    }

    #[test]
    fn an_embedded_image_is_a_view_after_the_buffer_aligned_and_the_other_stays_a_file() {
        let glb = embed_images(&glb_of_two_files(), &[(1, vec![9, 8, 7])]).unwrap();
        let g = gltf::Gltf::from_slice(&glb).expect("the gltf crate reads it back");
        let bin = g.blob.as_deref().unwrap();
        let images: Vec<_> = g.images().collect();
        assert!(
            matches!(images[0].source(), gltf::image::Source::Uri { uri, .. } if uri == "../textures/a.png")
        );
        match images[1].source() {
            gltf::image::Source::View { view, mime_type } => {
                assert_eq!(mime_type, "image/jpeg");
                assert_eq!(view.offset() % 4, 0);
                assert_eq!(
                    &bin[view.offset()..view.offset() + view.length()],
                    &[9, 8, 7]
                );
            }
            other => panic!("image 1 is not a view: {other:?}"),
        }
        assert_eq!(&bin[..6], &[1, 2, 3, 4, 5, 6], "the old buffer is kept");
        assert_eq!(g.buffers().next().unwrap().length(), 11);
        let twice = embed_images(&glb_of_two_files(), &[(0, vec![5]), (1, vec![5])]).unwrap();
        let g = gltf::Gltf::from_slice(&twice).unwrap();
        let views: Vec<usize> = (g.images())
            .map(|im| match im.source() {
                gltf::image::Source::View { view, .. } => view.index(),
                _ => panic!("embedded"),
            })
            .collect();
        assert_eq!(views[0], views[1], "the same bytes are stored once");
    }

    #[test]
    fn files_cheaper_than_a_request_move_and_are_removed() {
        let dir = std::env::temp_dir().join(format!("bimtiles-single-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("tiles")).unwrap();
        std::fs::create_dir_all(dir.join(TEXTURE_DIR)).unwrap();
        let big = SEQUENTIAL_REQUEST_WORTH_BYTES / 2 + 1;
        std::fs::write(dir.join("textures/a.png"), vec![1u8; big]).unwrap();
        std::fs::write(dir.join("textures/b.jpg"), [2u8; 7]).unwrap();
        // Tiles r and r1 use a and b, tile r0 uses a only: two copies of b cost less than a
        // request, so b moves into r and r1; two more copies of a would cost more: a stays.
        std::fs::write(dir.join("tiles/r.glb"), glb_of_two_files()).unwrap();
        std::fs::write(dir.join("tiles/r1.glb"), glb_of_two_files()).unwrap();
        let only_a = embed_images(&glb_of_two_files(), &[(1, vec![0])]).unwrap();
        std::fs::write(dir.join("tiles/r0.glb"), &only_a).unwrap();
        let tiles = ["tiles/r.glb", "tiles/r0.glb", "tiles/r1.glb"];
        let done = embed_files_cheaper_than_a_request(&dir, &tiles).unwrap();
        assert_eq!(done.files, 1);
        let rewritten: Vec<&String> = done.tile_bytes.keys().collect();
        assert_eq!(rewritten, ["tiles/r.glb", "tiles/r1.glb"]);
        assert!(dir.join("textures/a.png").exists());
        assert!(!dir.join("textures/b.jpg").exists());
        let r = std::fs::read(dir.join("tiles/r.glb")).unwrap();
        assert_eq!(done.tile_bytes["tiles/r.glb"], r.len() as u64);
        assert_eq!(std::fs::read(dir.join("tiles/r1.glb")).unwrap(), r);
        let files = shared_files(&crate::glb_container::json_chunk(&r).unwrap());
        assert_eq!(files, vec![(0, "a.png".to_string())]);
        assert_eq!(
            fetched_bytes(&dir, "tiles/r.glb").unwrap(),
            (r.len() + big) as u64,
            "the GLB and the file it still references"
        );
        assert_eq!(std::fs::read(dir.join("tiles/r0.glb")).unwrap(), only_a);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
