//! CityJSON appearance textures (CityJSON 2.0 §8.2 "Texture Object", §8.3 geometry `texture`
//! values): a document's `appearance.textures` become scene images (read once per image file,
//! relative to the CityJSON file, never outside its folder), `vertices-texture` the UVs, and a
//! ring's texture values `[texture, uv, uv…]` give each polygon corner its UV.

use crate::scene::{ImageId, Sampler, Scene, TextureRef};
use crate::uri::confine;
use serde_json::Value;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The glTF wrap of a CityJSON or CityGML `wrapMode` ("none" and "wrap", the default, both
/// repeat in glTF terms).
pub(crate) fn wrap_of_mode(mode: Option<&str>) -> u32 {
    match mode.map(str::trim) {
        Some("mirror") => Sampler::MIRRORED_REPEAT,
        Some("clamp" | "border") => Sampler::CLAMP_TO_EDGE,
        _ => Sampler::REPEAT,
    }
}

/// The textures and UVs of one document (a CityJSON file, or one CityJSONFeature with its own
/// `appearance`).
#[derive(Debug, Default)]
pub struct DocumentTextures {
    /// Per CityJSON texture index: its image and sampler, `None` when the image is missing.
    pub textures: Vec<Option<TextureRef>>,
    /// `vertices-texture`, in glTF's convention (v from the image's top).
    pub uvs: Vec<[f32; 2]>,
    /// The theme to draw (`default-theme-texture`, else each geometry's first).
    pub default_theme: Option<String>,
}

/// Images read so far (by file), and those that could not be, for one warning.
#[derive(Debug, Default)]
pub struct ImageFiles {
    loaded: HashMap<PathBuf, Option<ImageId>>,
    /// Texture images not found or unreadable (the first few named in the warning).
    pub missing: Vec<String>,
}

impl ImageFiles {
    /// Reads the textures of a document's `appearance` (images relative to `base_dir`).
    pub fn document_textures(
        &mut self,
        appearance: &Value,
        base_dir: &Path,
        scene: &mut Scene,
    ) -> DocumentTextures {
        let textures = appearance
            .get("textures")
            .and_then(Value::as_array)
            .map(|list| {
                list.iter()
                    .map(|t| self.texture(t, base_dir, scene))
                    .collect()
            })
            .unwrap_or_default();
        let uvs = appearance
            .get("vertices-texture")
            .and_then(Value::as_array)
            .map(|list| {
                list.iter()
                    .map(|uv| {
                        let c = |i: usize| uv.get(i).and_then(Value::as_f64).unwrap_or(0.0);
                        // CityJSON's v runs up from the image's bottom, glTF's down from its top.
                        [c(0) as f32, (1.0 - c(1)) as f32]
                    })
                    .collect()
            })
            .unwrap_or_default();
        DocumentTextures {
            textures,
            uvs,
            default_theme: appearance
                .get("default-theme-texture")
                .and_then(Value::as_str)
                .map(str::to_string),
        }
    }

    fn texture(
        &mut self,
        texture: &Value,
        base_dir: &Path,
        scene: &mut Scene,
    ) -> Option<TextureRef> {
        let name = texture.get("image").and_then(Value::as_str)?;
        let image = self.image(name, base_dir, scene)?;
        let wrap = wrap_of_mode(texture.get("wrapMode").and_then(Value::as_str));
        Some(TextureRef::on_first_uvs(image, wrap))
    }

    pub(crate) fn image(
        &mut self,
        name: &str,
        base_dir: &Path,
        scene: &mut Scene,
    ) -> Option<ImageId> {
        let key = base_dir.join(name);
        if let Some(&known) = self.loaded.get(&key) {
            return known;
        }
        let id = confine::inside(base_dir, name, &confine::INPUT)
            .ok()
            .and_then(|path| super::super::read_regular(&path).ok())
            .and_then(|bytes| crate::ingest::interchange::push_image(scene, name, bytes));
        if id.is_none() {
            self.missing.push(name.to_string());
        }
        self.loaded.insert(key, id);
        id
    }

    /// The warning for the images that could not be read, naming the first few; `None` when every
    /// image was read.
    pub(crate) fn missing_warning(&self, path: &Path) -> Option<String> {
        if self.missing.is_empty() {
            return None;
        }
        let named: Vec<&str> = self
            .missing
            .iter()
            .take(MISSING_IMAGES_NAMED)
            .map(String::as_str)
            .collect();
        Some(format!(
            "{}: {} texture images are missing or unreadable ({}{}): their surfaces are drawn untextured",
            path.display(),
            self.missing.len(),
            named.join(", "),
            if self.missing.len() > named.len() { ", …" } else { "" }
        ))
    }
}

/// How many missing texture images the warning names.
const MISSING_IMAGES_NAMED: usize = 3;

/// A ring's texture: its texture index and one UV index per vertex (`[t, uv0, uv1…]`), or
/// `None` for an untextured ring (`[null]`) or values that do not fit the ring.
pub fn ring_texture(values: Option<&Value>, ring_len: usize) -> Option<(usize, Vec<usize>)> {
    let list = values?.as_array()?;
    let texture = list.first()?.as_u64()? as usize;
    let uvs: Option<Vec<usize>> = list[1..]
        .iter()
        .map(|i| i.as_u64().map(|i| i as usize))
        .collect();
    uvs.filter(|u| u.len() == ring_len).map(|u| (texture, u))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ring_values_fit_their_ring() {
        let v = serde_json::json!([2, 10, 11, 12]);
        assert_eq!(ring_texture(Some(&v), 3), Some((2, vec![10, 11, 12])));
        assert_eq!(ring_texture(Some(&v), 4), None, "one UV per vertex");
        assert_eq!(ring_texture(Some(&serde_json::json!([null])), 3), None);
        assert_eq!(ring_texture(None, 3), None);
    }

    #[test]
    fn a_missing_image_is_counted_once_and_uvs_are_flipped() {
        let appearance = serde_json::json!({
            "textures": [{"type": "PNG", "image": "nowhere/a.png"},
                         {"type": "PNG", "image": "nowhere/a.png", "wrapMode": "clamp"}],
            "vertices-texture": [[0.25, 0.0], [1.0, 0.75]]
        });
        let mut files = ImageFiles::default();
        let mut scene = Scene::default();
        let t = files.document_textures(&appearance, Path::new("/nonexistent"), &mut scene);
        assert_eq!(t.textures, vec![None, None]);
        assert_eq!(files.missing, vec!["nowhere/a.png".to_string()]);
        assert_eq!(t.uvs, vec![[0.25, 1.0], [1.0, 0.25]]);
    }
}
