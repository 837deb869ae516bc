//! Texture files shared by the tiles of a tileset (paper III.F's loading claim): each
//! distinct image level (after identical images are merged and unused areas cropped) is written
//! once under `<tileset>/textures/` and tiles reference it by a relative `uri` (glTF 2.0 §3.3.3:
//! relative URIs resolve against the GLB's own location; CesiumJS derives them from the tile's
//! URL and caches images by their resolved URL, so a file is fetched once however many tiles use
//! it). File names are the 64-bit FNV-1a hash of the bytes: deterministic, stable between runs,
//! and the same bytes reached from two images or levels make one file. `tiles/` keeps holding
//! only tile GLBs; a tile reaches the files as `../textures/<name>` (our gltf-validator runner
//! is given the tileset folder as the root such URIs may reach).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// Folder of the shared files, in the tileset's folder.
pub const TEXTURE_DIR: &str = "textures";
/// How a tile GLB (in `tiles/`) reaches that folder.
const FROM_TILES: &str = "../textures/";

/// Why a shared texture file could not be written.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("{path}: cannot write")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("two texture files hash to {name}")]
    HashCollision { name: String },
    #[error("the texture writer is poisoned (a thread panicked while writing)")]
    Poisoned,
}

/// Writes shared texture files, each once.
#[derive(Debug)]
pub struct ExternalTextures {
    dir: PathBuf,
    /// File name → what was written under it.
    files: Mutex<BTreeMap<String, WrittenFile>>,
}

/// A shared file: its bytes (to tell a hash collision from a repeat) and the finest pyramid
/// level that shipped them.
#[derive(Debug)]
struct WrittenFile {
    bytes: Arc<Vec<u8>>,
    finest_level: usize,
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
    ) -> Result<(String, bool), StoreError> {
        let name = file_name(bytes, mime);
        let mut files = self.files.lock().map_err(|_| StoreError::Poisoned)?;
        let new = match files.get_mut(&name) {
            Some(f) if f.bytes.as_slice() == bytes.as_slice() => {
                f.finest_level = f.finest_level.min(level);
                false
            }
            Some(_) => return Err(StoreError::HashCollision { name }),
            None => {
                std::fs::create_dir_all(&self.dir).map_err(|source| StoreError::Io {
                    path: self.dir.clone(),
                    source,
                })?;
                let path = self.dir.join(&name);
                // Through a temporary name: sharded jobs may write the same file, and a killed
                // job must not leave a half-written one under its final name.
                let tmp = self.dir.join(format!(".{name}.tmp-{}", std::process::id()));
                std::fs::write(&tmp, bytes.as_slice())
                    .and_then(|()| std::fs::rename(&tmp, &path))
                    .map_err(|source| {
                        let _ = std::fs::remove_file(&tmp);
                        StoreError::Io {
                            path: path.clone(),
                            source,
                        }
                    })?;
                files.insert(
                    name.clone(),
                    WrittenFile {
                        bytes: bytes.clone(),
                        finest_level: level,
                    },
                );
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
        for f in self.files.lock().expect("texture writer").values() {
            *out.entry(f.finest_level).or_insert(0) += f.bytes.len() as u64;
        }
        out
    }
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
}
