//! Texture files shared by the tiles of a tileset (issue 6, paper III.F's loading claim): each
//! distinct image level (after identical images are merged and unused areas cropped) is written
//! once under `<tileset>/textures/` and tiles reference it by a relative `uri` (glTF 2.0 §3.3.3:
//! relative URIs resolve against the GLB's own location; CesiumJS derives them from the tile's
//! URL and caches images by their resolved URL, so a file is fetched once however many tiles use
//! it). File names are the 64-bit FNV-1a hash of the bytes: deterministic, stable between runs,
//! and the same bytes reached from two images or levels make one file. `tiles/` keeps holding
//! only tile GLBs; a tile reaches the files as `../textures/<name>` (our gltf-validator runner
//! is given the tileset folder as the root such URIs may reach).

use super::view::{self, FirstView, ViewOptions};
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// Folder of the shared files, in the tileset's folder.
pub const TEXTURE_DIR: &str = "textures";
/// How a tile GLB (in `tiles/`) reaches that folder.
const FROM_TILES: &str = "../textures/";

/// Writes shared texture files, each once.
#[derive(Debug)]
pub struct ExternalTextures {
    dir: PathBuf,
    /// File name → its bytes (to tell a hash collision from a repeat) and the finest pyramid
    /// level that shipped them.
    files: Mutex<BTreeMap<String, (Arc<Vec<u8>>, usize)>>,
}

/// 64-bit FNV-1a.
fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// The file name of encoded image bytes: hash and the extension of the MIME type.
pub fn file_name(bytes: &[u8], mime: &str) -> String {
    let ext = match mime {
        "image/png" => "png",
        "image/jpeg" => "jpg",
        "image/webp" => "webp",
        "image/ktx2" => "ktx2",
        _ => "bin",
    };
    format!("{:016x}.{ext}", fnv1a64(bytes))
}

impl ExternalTextures {
    /// Files go to `<tileset_dir>/textures/` (created on the first file).
    pub fn new(tileset_dir: &Path) -> ExternalTextures {
        ExternalTextures {
            dir: tileset_dir.join(TEXTURE_DIR),
            files: Mutex::new(BTreeMap::new()),
        }
    }

    /// Writes `bytes` (pyramid level `level`) unless already written; returns the URI relative to
    /// a tile GLB and whether the file is new.
    pub fn store(
        &self,
        bytes: &Arc<Vec<u8>>,
        mime: &str,
        level: usize,
    ) -> Result<(String, bool), String> {
        let name = file_name(bytes, mime);
        let mut files = self.files.lock().map_err(|_| "texture writer poisoned")?;
        let new = match files.get_mut(&name) {
            Some((b, l)) if b.as_slice() == bytes.as_slice() => {
                *l = (*l).min(level);
                false
            }
            Some(_) => return Err(format!("two texture files hash to {name}")),
            None => {
                std::fs::create_dir_all(&self.dir)
                    .map_err(|e| format!("{}: {e}", self.dir.display()))?;
                let path = self.dir.join(&name);
                // Through a temporary name: sharded jobs may write the same file, and a killed
                // job must not leave a half-written one under its final name.
                let tmp = self.dir.join(format!(".{name}.tmp-{}", std::process::id()));
                std::fs::write(&tmp, bytes.as_slice())
                    .and_then(|()| std::fs::rename(&tmp, &path))
                    .map_err(|e| {
                        let _ = std::fs::remove_file(&tmp);
                        format!("{}: {e}", path.display())
                    })?;
                files.insert(name.clone(), (bytes.clone(), level));
                true
            }
        };
        Ok((format!("{FROM_TILES}{name}"), new))
    }

    /// Shared texture files in the folder (by any process: a sharded build's jobs each write
    /// some, the merging process none), not counting temporary names.
    pub fn file_count(&self) -> usize {
        std::fs::read_dir(&self.dir).map_or(0, |d| {
            d.flatten()
                .filter(|e| !e.file_name().to_string_lossy().starts_with('.'))
                .count()
        })
    }

    /// Bytes of the files written, per pyramid level (each file at the finest level that
    /// shipped it, so the sum does not depend on which tile came first).
    pub fn bytes_per_level(&self) -> BTreeMap<usize, u64> {
        let mut out = BTreeMap::new();
        for (b, l) in self.files.lock().expect("texture writer").values() {
            *out.entry(*l).or_insert(0) += b.len() as u64;
        }
        out
    }
}

/// [`view::first_view`] counting shared texture files once: the texture bytes a client loads
/// for the first whole-model view are the embedded images of the selected tiles plus each
/// distinct external file they reference. The selection is `first_view`'s own, read back by
/// probing it with stub tilesets (tile `k` of a batch of 63 carries an "image" of 2^k bytes,
/// so the sum names the selected tiles), so both measurements always select the same tiles.
/// Also returns how many distinct files that is (requests on top of the tiles').
pub fn first_view_shared(dir: &Path, v: &ViewOptions) -> Result<(FirstView, usize), String> {
    let mut out = view::first_view(dir, v)?;
    let tileset: Value = serde_json::from_slice(
        &std::fs::read(dir.join("tileset.json")).map_err(|e| e.to_string())?,
    )
    .map_err(|e| e.to_string())?;
    let mut uris = Vec::new();
    let mut stack = vec![&tileset["root"]];
    while let Some(t) = stack.pop() {
        if let Some(u) = t["content"]["uri"].as_str() {
            uris.push(u.to_string());
        }
        stack.extend(t["children"].as_array().into_iter().flatten());
    }
    uris.sort();
    uris.dedup();
    let probe = std::env::temp_dir().join(format!(
        "bimtiles-view-probe-{}-{:x}",
        std::process::id(),
        fnv1a64(dir.as_os_str().as_encoded_bytes())
    ));
    let selected = select_by_probing(&probe, &tileset, &uris, v);
    let _ = std::fs::remove_dir_all(&probe);
    let mut files = BTreeSet::new();
    let mut references = 0;
    for uri in selected? {
        let tile = dir.join(&uri);
        let glb = std::fs::read(&tile).map_err(|e| format!("{uri}: {e}"))?;
        let json = glb_json(&glb).map_err(|e| format!("{uri}: {e}"))?;
        for im in json["images"].as_array().into_iter().flatten() {
            if let Some(u) = im["uri"].as_str() {
                references += 1;
                let base = tile.parent().unwrap_or(dir);
                files.insert(normalize(&base.join(u)));
            }
        }
    }
    for f in &files {
        out.texture_bytes += std::fs::metadata(f)
            .map_err(|e| format!("{}: {e}", f.display()))?
            .len();
    }
    // `images` counts what is downloaded: embedded copies and distinct files.
    out.images = out.images - references + files.len();
    Ok((out, files.len()))
}

/// The JSON chunk of a GLB.
fn glb_json(glb: &[u8]) -> Result<Value, String> {
    if glb.len() < 20 || &glb[0..4] != b"glTF" {
        return Err("not a GLB".into());
    }
    let n = u32::from_le_bytes(glb[12..16].try_into().expect("4 bytes")) as usize;
    serde_json::from_slice(glb.get(20..20 + n).ok_or("short GLB")?).map_err(|e| e.to_string())
}

/// `a/b/../c` → `a/c` (no file system access).
fn normalize(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            std::path::Component::ParentDir => {
                out.pop();
            }
            std::path::Component::CurDir => {}
            c => out.push(c),
        }
    }
    out
}

/// The content URIs `first_view` selects, found with stub tilesets in `probe`.
fn select_by_probing(
    probe: &Path,
    tileset: &Value,
    uris: &[String],
    v: &ViewOptions,
) -> Result<Vec<String>, String> {
    const BATCH: usize = 63;
    let io = |e: std::io::Error| format!("{}: {e}", probe.display());
    std::fs::create_dir_all(probe).map_err(io)?;
    std::fs::write(probe.join("tileset.json"), tileset.to_string()).map_err(io)?;
    let stub = |byte_length: u64| {
        let json = if byte_length == 0 {
            serde_json::json!({"asset": {"version": "2.0"}})
        } else {
            serde_json::json!({"asset": {"version": "2.0"},
                "bufferViews": [{"buffer": 0, "byteLength": byte_length}],
                "images": [{"bufferView": 0}]})
        };
        crate::encode::glb::glb_container(json.to_string().as_bytes(), &[])
    };
    let mut selected = Vec::new();
    for (batch, chunk) in uris.chunks(BATCH).enumerate() {
        for (i, uri) in uris.iter().enumerate() {
            let path = probe.join(uri);
            if let Some(parent) = path.parent() {
                std::fs::create_dir_all(parent).map_err(io)?;
            }
            let bits = if i / BATCH == batch {
                1u64 << (i % BATCH)
            } else {
                0
            };
            std::fs::write(&path, stub(bits)).map_err(io)?;
        }
        let mask = view::first_view(probe, v)?.texture_bytes;
        selected.extend(
            chunk
                .iter()
                .enumerate()
                .filter(|(k, _)| mask >> k & 1 == 1)
                .map(|(_, u)| u.clone()),
        );
    }
    Ok(selected)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_follow_the_bytes_and_files_are_written_once() {
        let dir = std::env::temp_dir().join(format!("bimtiles-ext-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let ext = ExternalTextures::new(&dir);
        let a = Arc::new(vec![1u8, 2, 3]);
        let b = Arc::new(vec![1u8, 2, 4]);
        let (ua, new_a) = ext.store(&a, "image/png", 2).unwrap();
        let (ua2, again) = ext.store(&a.clone(), "image/png", 1).unwrap();
        let (ub, _) = ext.store(&b, "image/jpeg", 0).unwrap();
        assert!(new_a && !again);
        assert_eq!(ua, ua2);
        assert_ne!(ua, ub);
        assert!(ua.starts_with("../textures/") && ua.ends_with(".png"));
        assert!(ub.ends_with(".jpg"));
        assert_eq!(ext.file_count(), 2);
        assert_eq!(
            ext.bytes_per_level(),
            BTreeMap::from([(0, 3), (1, 3)]),
            "a file counts at the finest level that used it"
        );
        let name = ua.trim_start_matches("../textures/");
        assert_eq!(std::fs::read(dir.join("textures").join(name)).unwrap(), *a);
        assert_eq!(name, file_name(&a, "image/png"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn normalize_resolves_parent_steps() {
        assert_eq!(
            normalize(Path::new("/x/tiles/../textures/a.png")),
            PathBuf::from("/x/textures/a.png")
        );
    }
}
