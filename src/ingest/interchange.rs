//! What the readers of mesh interchange formats (Wavefront OBJ, FBX) share: the frame their
//! coordinates are in (up axis and length unit, `--up`/`--unit`), texture files named the way
//! desktop tools write them (absolute Windows paths, backslashes) found beside the model inside
//! its folder ([`crate::uri::confine`]), and the names CAD exporters give nodes (the FBX SDK's
//! `FBXASCnnn` escapes, Revit's `Family Type [element id]`).

use crate::scene::{Image, ImageId, Scene};
use crate::uri::confine;
use glam::DMat4;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Which model axis points up.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    /// +y up, -z forward: what OBJ exporters write unless told otherwise (the glTF convention).
    #[default]
    Y,
    /// +z up (CAD and GIS tools).
    Z,
}

/// The length one model unit stands for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LengthUnit {
    #[default]
    M,
    Cm,
    Mm,
    Ft,
    In,
}

impl LengthUnit {
    pub fn metres(self) -> f64 {
        match self {
            LengthUnit::M => 1.0,
            LengthUnit::Cm => 0.01,
            LengthUnit::Mm => 0.001,
            LengthUnit::Ft => 0.3048,
            LengthUnit::In => 0.0254,
        }
    }
}

impl std::str::FromStr for UpAxis {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "y" => Ok(UpAxis::Y),
            "z" => Ok(UpAxis::Z),
            _ => Err(format!("'{s}' is not an up axis (y or z)")),
        }
    }
}

impl std::str::FromStr for LengthUnit {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "m" => Ok(LengthUnit::M),
            "cm" => Ok(LengthUnit::Cm),
            "mm" => Ok(LengthUnit::Mm),
            "ft" => Ok(LengthUnit::Ft),
            "in" => Ok(LengthUnit::In),
            _ => Err(format!("'{s}' is not a length unit (m, cm, mm, ft or in)")),
        }
    }
}

/// The frame of a model whose file does not say it (OBJ): up axis and unit, each `None` for the
/// default ([`UpAxis::Y`], [`LengthUnit::M`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MeshFrame {
    pub up: Option<UpAxis>,
    pub unit: Option<LengthUnit>,
}

impl MeshFrame {
    /// `self`, with what it leaves open taken from `fallback` (a manifest entry over `--up`).
    pub fn or(self, fallback: MeshFrame) -> MeshFrame {
        MeshFrame {
            up: self.up.or(fallback.up),
            unit: self.unit.or(fallback.unit),
        }
    }

    /// Model coordinates to the scene's frame (metres, z up).
    pub fn to_scene(self) -> DMat4 {
        let scale = DMat4::from_scale(glam::DVec3::splat(self.unit.unwrap_or_default().metres()));
        match self.up.unwrap_or_default() {
            UpAxis::Y => crate::scene::Y_UP_TO_Z_UP * scale,
            UpAxis::Z => scale,
        }
    }
}

/// Texture images read once per file, found as written or, for names no relative path reaches
/// (absolute, backslashed, in a sub-folder that is not there), with `\` read as `/`, then by their
/// bare file name beside the model. Every file stays inside the model's folder.
#[derive(Debug)]
pub struct TextureFiles {
    base_dir: PathBuf,
    loaded: HashMap<String, Option<ImageId>>,
    /// Names found only by their bare file name (for one warning).
    pub by_bare_name: Vec<String>,
    /// Names not found or not images.
    pub missing: Vec<String>,
}

impl TextureFiles {
    pub fn new(base_dir: &Path) -> TextureFiles {
        TextureFiles {
            base_dir: base_dir.to_path_buf(),
            loaded: HashMap::new(),
            by_bare_name: Vec::new(),
            missing: Vec::new(),
        }
    }

    /// The image a texture reference names, read into `scene` on first use.
    pub fn image(&mut self, written: &str, scene: &mut Scene) -> Option<ImageId> {
        if let Some(&known) = self.loaded.get(written) {
            return known;
        }
        let read = |name: &str| -> Option<Vec<u8>> {
            let path = confine::inside(&self.base_dir, name, &confine::INPUT).ok()?;
            super::read_regular(&path).ok()
        };
        let bare = bare_file_name(written);
        // As written; a relative Windows path with `/`; the bare name beside the model.
        let slashed = written.replace('\\', "/");
        let bytes = match read(written) {
            Some(b) => Some(b),
            None => {
                let b = read(&slashed).or_else(|| bare.filter(|b| *b != written).and_then(read));
                if b.is_some() {
                    self.by_bare_name.push(written.to_string());
                }
                b
            }
        };
        let id = match bytes {
            Some(b) => push_image(scene, bare.unwrap_or(written), b),
            None => None,
        };
        if id.is_none() {
            self.missing.push(written.to_string());
        }
        self.loaded.insert(written.to_string(), id);
        id
    }

    /// The reader's warnings about its textures (at most one line each for fallbacks and misses).
    pub fn warnings(&self, model: &Path) -> Vec<String> {
        let named = |list: &[String]| {
            let shown: Vec<&str> = list.iter().take(3).map(String::as_str).collect();
            let more = if list.len() > shown.len() {
                ", …"
            } else {
                ""
            };
            format!("{}{more}", shown.join(", "))
        };
        let mut out = Vec::new();
        if !self.by_bare_name.is_empty() {
            out.push(format!(
                "{}: {} texture paths are absolute, backslashed or point to a missing folder ({}): the images were found with `/` for `\\` or by their file name beside the model",
                model.display(),
                self.by_bare_name.len(),
                named(&self.by_bare_name)
            ));
        }
        if !self.missing.is_empty() {
            out.push(format!(
                "{}: {} texture images are missing or unreadable ({}): their surfaces are drawn untextured",
                model.display(),
                self.missing.len(),
                named(&self.missing)
            ));
        }
        out
    }
}

/// An image's bytes added to the scene, when they are an image format we read.
pub fn push_image(scene: &mut Scene, name: &str, bytes: Vec<u8>) -> Option<ImageId> {
    let mime = crate::uri::mime::sniff_image(&bytes)?;
    let id = ImageId(scene.images.len() as u32);
    scene.images.push(Image {
        name: Some(name.to_string()),
        mime_type: mime.to_string(),
        bytes: Arc::new(bytes),
    });
    Some(id)
}

/// The last segment of a path written with `/` or `\` separators (`None` when empty).
fn bare_file_name(written: &str) -> Option<&str> {
    written
        .rsplit(['/', '\\'])
        .next()
        .filter(|n| !n.is_empty() && *n != "." && *n != "..")
}

/// A node name with the FBX SDK's escapes undone: `FBXASC032` is the character with code 32
/// (the SDK writes every character it cannot keep in a name so, and OBJ files converted from FBX
/// keep them).
pub fn unescape_fbx_name(name: &str) -> String {
    const MARK: &str = "FBXASC";
    let mut out = String::with_capacity(name.len());
    let mut rest = name;
    while let Some(at) = rest.find(MARK) {
        out.push_str(&rest[..at]);
        let after = &rest[at + MARK.len()..];
        let code = after
            .get(..3)
            .filter(|d| d.bytes().all(|b| b.is_ascii_digit()))
            .and_then(|d| d.parse::<u32>().ok())
            .and_then(char::from_u32);
        match code {
            Some(c) => {
                out.push(c);
                rest = &after[3..];
            }
            None => {
                out.push_str(MARK);
                rest = after;
            }
        }
    }
    out.push_str(rest);
    out
}

/// The element id Revit puts at the end of a node's name (`Basic Wall Generic - 200mm [320878]`).
pub fn revit_element_id(name: &str) -> Option<i64> {
    let inner = name.trim_end().strip_suffix(']')?;
    let (_, digits) = inner.rsplit_once('[')?;
    match digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        true => None,
        false => digits.parse().ok(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fbx_escapes_and_revit_ids() {
        let n = unescape_fbx_name("BasicFBXASC032WallFBXASC032FBXASC091320878FBXASC093");
        assert_eq!(n, "Basic Wall [320878]");
        assert_eq!(revit_element_id(&n), Some(320878));
        assert_eq!(unescape_fbx_name("FBXASC"), "FBXASC");
        assert_eq!(unescape_fbx_name("aFBXASC9x"), "aFBXASC9x");
        assert_eq!(revit_element_id("Wall [a1]"), None);
        assert_eq!(revit_element_id("Wall []"), None);
        assert_eq!(revit_element_id("Wall"), None);
    }

    #[test]
    fn bare_names_of_windows_and_unix_paths() {
        assert_eq!(bare_file_name(r"D:\a\b\c.jpg"), Some("c.jpg"));
        assert_eq!(bare_file_name("tex/c.jpg"), Some("c.jpg"));
        assert_eq!(bare_file_name("dir/"), None);
        assert_eq!(bare_file_name(".."), None);
    }

    #[test]
    fn frames_scale_and_turn() {
        let f = MeshFrame {
            up: Some(UpAxis::Y),
            unit: Some(LengthUnit::Cm),
        };
        let p = f
            .to_scene()
            .transform_point3(glam::DVec3::new(0.0, 100.0, 0.0));
        assert!((p - glam::DVec3::Z).length() < 1e-12);
        assert_eq!("FT".parse::<LengthUnit>(), Ok(LengthUnit::Ft));
        assert!("yard".parse::<LengthUnit>().is_err());
    }
}
