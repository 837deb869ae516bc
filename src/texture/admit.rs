//! Admission of a scene's images, before any texture pass allocates for them: limits from the
//! header alone (book: guide/safety.md), and the dropping of images that cannot be used.
//!
//! - An image larger than [`MAX_IMAGE_SIDE_PX`] a side (the largest texture GPUs take), or whose
//!   decoded pixels would need more than a quarter of `--memory-budget` (and at least 64 MiB), is
//!   refused: the run
//!   fails with one line naming the file and the image. A 78-byte PNG may claim 65535 x 65535.
//! - An image that cannot be decoded is dropped with a warning naming it: its materials draw their
//!   base colour, and no undecodable bytes are written as a texture that viewers would reject.

use super::classify::bound_images;
use super::codec;
use crate::error::chain_text;
use crate::scene::{ImageId, Scene};
use serde::Serialize;
use std::path::PathBuf;

/// Largest width or height of an image accepted as a texture (WebGL2 and most GPUs).
pub const MAX_IMAGE_SIDE_PX: u32 = 16_384;

/// Decoded RGBA bytes an image may need, as a fraction of the memory budget: two worker threads
/// may each hold one image's pyramid, beside the geometry.
const BUDGET_SHARE_PER_IMAGE: u64 = 4;

/// What an image may need decoded under any budget (a 4096 x 4096 RGBA texture): a budget set
/// small to make the geometry spill to disk should not refuse ordinary textures.
pub const MIN_DECODED_BYTES_PER_IMAGE: u64 = 64 << 20;

/// What images are allowed to cost.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImageLimits {
    pub max_side_px: u32,
    /// Largest decoded size (RGBA, 4 bytes a pixel); `None`: no limit.
    pub max_decoded_bytes: Option<u64>,
}

impl ImageLimits {
    /// The limits under a memory budget in bytes (`None`: no budget).
    pub fn under_budget(budget_bytes: Option<u64>) -> ImageLimits {
        ImageLimits {
            max_side_px: MAX_IMAGE_SIDE_PX,
            max_decoded_bytes: budget_bytes
                .map(|b| (b / BUDGET_SHARE_PER_IMAGE).max(MIN_DECODED_BYTES_PER_IMAGE)),
        }
    }
}

/// An image dropped because it cannot be decoded (in `report.json`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DroppedImage {
    pub image: u32,
    pub name: Option<String>,
    /// The input file it came from.
    pub file: PathBuf,
    pub reason: String,
}

impl std::fmt::Display for DroppedImage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: image {}{} cannot be decoded ({}); dropped: its materials draw their base colour",
            self.file.display(),
            self.image,
            quoted(&self.name),
            self.reason
        )
    }
}

/// Why an image is refused.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ImageRefused {
    #[error(
        "image {image}{name}: {width_px}x{height_px} px is larger than {max_px} px a side, the largest texture GPUs take",
        name = quoted(name)
    )]
    TooLarge {
        image: u32,
        name: Option<String>,
        width_px: u32,
        height_px: u32,
        max_px: u32,
    },
    #[error(
        "image {image}{name}: {width_px}x{height_px} px needs {decoded_bytes} bytes decoded, more than --memory-budget allows for one image ({max_bytes} bytes: a quarter of it, at least 64 MiB)",
        name = quoted(name)
    )]
    OverBudget {
        image: u32,
        name: Option<String>,
        width_px: u32,
        height_px: u32,
        decoded_bytes: u64,
        max_bytes: u64,
    },
}

fn quoted(name: &Option<String>) -> String {
    name.as_ref().map_or(String::new(), |n| format!(" '{n}'"))
}

/// Which limit an image's header breaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OverLimit {
    /// Wider or taller than `max_side_px`.
    Side,
    /// Its decoded RGBA pixels would need more than `max_decoded_bytes`.
    Budget { decoded_bytes: u64, max_bytes: u64 },
}

/// An image's size from its header alone (`Err`: the header does not read), and the limit it
/// breaks, if any: what [`admit_images`] checks for each image, before anything is decoded.
pub fn header_size(
    bytes: &[u8],
    limits: &ImageLimits,
) -> Result<((u32, u32), Option<OverLimit>), codec::CodecError> {
    let (width_px, height_px) = codec::dimensions(bytes)?;
    let decoded_bytes = width_px as u64 * height_px as u64 * 4;
    let over = if width_px.max(height_px) > limits.max_side_px {
        Some(OverLimit::Side)
    } else {
        limits
            .max_decoded_bytes
            .filter(|&m| decoded_bytes > m)
            .map(|max_bytes| OverLimit::Budget {
                decoded_bytes,
                max_bytes,
            })
    };
    Ok(((width_px, height_px), over))
}

/// Checks every image a material uses against `limits`, from its header alone. Refuses the first
/// image over a limit, with the input file it came from; drops (and returns) those whose header
/// does not read. Whether the pixels decode is found by the one pass that decodes them all
/// (`identical::merge_identical`), whose failures go to [`drop_images`].
pub fn admit_images(
    scene: &mut Scene,
    limits: &ImageLimits,
) -> Result<Vec<DroppedImage>, (PathBuf, ImageRefused)> {
    let mut unreadable = Vec::new();
    for id in bound_images(scene) {
        let image = &scene.images[id.index()];
        let ((width_px, height_px), over) = match header_size(&image.bytes, limits) {
            Ok(size) => size,
            Err(e) => {
                unreadable.push((id, chain_text(&e)));
                continue;
            }
        };
        let name = image.name.clone();
        let refused = match over {
            None => continue,
            Some(OverLimit::Side) => ImageRefused::TooLarge {
                image: id.0,
                name,
                width_px,
                height_px,
                max_px: limits.max_side_px,
            },
            Some(OverLimit::Budget {
                decoded_bytes,
                max_bytes,
            }) => ImageRefused::OverBudget {
                image: id.0,
                name,
                width_px,
                height_px,
                decoded_bytes,
                max_bytes,
            },
        };
        return Err((source_file(scene, id), refused));
    }
    Ok(drop_images(scene, &unreadable))
}

/// Drops `images` (each with why it cannot be used) from the materials that use them: they draw
/// their base colour. Returns them, named, for the report.
pub fn drop_images(scene: &mut Scene, images: &[(ImageId, String)]) -> Vec<DroppedImage> {
    images
        .iter()
        .map(|(id, reason)| {
            let file = source_file(scene, *id);
            for m in &mut scene.materials {
                if m.base_color_texture
                    .as_ref()
                    .is_some_and(|t| t.image == *id)
                {
                    m.base_color_texture = None;
                }
            }
            DroppedImage {
                image: id.0,
                name: scene.images[id.index()].name.clone(),
                file,
                reason: reason.clone(),
            }
        })
        .collect()
}

/// The input file of the first component whose material uses `image` (the first input if none).
/// Reads the meshes (perhaps from the spill file): only for an image that is refused or dropped.
fn source_file(scene: &Scene, image: ImageId) -> PathBuf {
    let uses = |c: &crate::scene::Component| {
        scene.meshes.get(c.mesh).primitives.iter().any(|p| {
            p.material.is_some_and(|m| {
                scene.materials[m.index()]
                    .base_color_texture
                    .as_ref()
                    .is_some_and(|t| t.image == image)
            })
        })
    };
    let source = scene
        .components
        .iter()
        .find(|c| uses(c))
        .map_or(0, |c| c.source);
    scene
        .sources
        .get(source as usize)
        .map(|s| s.path.clone())
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Material, TextureRef};
    use crate::texture::classify::tests::image;
    use crate::texture::codec::tests::png_of;

    fn png(w: u32, h: u32) -> Vec<u8> {
        let rgba = vec![9u8; (w * h * 4) as usize];
        png_of(
            w,
            h,
            png::ColorType::Rgba,
            png::BitDepth::Eight,
            &rgba,
            None,
            None,
        )
    }

    /// A PNG whose header (IHDR) claims `w` x `h`, followed by the pixel data of a 1 x 1 image.
    fn png_header_only(w: u32, h: u32) -> Vec<u8> {
        let mut head = Vec::new();
        let mut e = png::Encoder::new(&mut head, w, h);
        e.set_color(png::ColorType::Rgba);
        drop(e.write_header().unwrap());
        let mut b = head[..33].to_vec(); // signature, IHDR
        b.extend_from_slice(&png(1, 1)[33..]); // IDAT, IEND
        b
    }

    fn scene_with(images: Vec<Vec<u8>>) -> Scene {
        let mut s = Scene::default();
        s.sources.push(crate::scene::SourceFile {
            path: "in.glb".into(),
            bytes: 0,
        });
        for (i, bytes) in images.into_iter().enumerate() {
            s.images.push(image(bytes));
            s.materials.push(Material {
                base_color_texture: Some(TextureRef {
                    image: ImageId(i as u32),
                    sampler: Default::default(),
                    tex_coord: 0,
                }),
                ..Default::default()
            });
        }
        s
    }

    #[test]
    fn a_header_claiming_a_huge_image_is_refused_before_decoding() {
        let bomb = png_header_only(65535, 65535);
        assert!(bomb.len() < 100);
        let mut s = scene_with(vec![png(2, 2), bomb]);
        let (file, refused) = admit_images(&mut s, &ImageLimits::under_budget(None)).unwrap_err();
        assert_eq!(file, PathBuf::from("in.glb"));
        assert!(matches!(
            refused,
            ImageRefused::TooLarge {
                image: 1,
                width_px: 65535,
                ..
            }
        ));
        assert!(refused.to_string().contains("65535x65535 px"), "{refused}");
    }

    #[test]
    fn decoded_size_is_held_to_the_budget() {
        let mut s = scene_with(vec![png_header_only(8000, 6000)]);
        let limits = ImageLimits::under_budget(Some(4 * 100_000_000));
        let (_, refused) = admit_images(&mut s, &limits).unwrap_err();
        assert!(matches!(
            refused,
            ImageRefused::OverBudget {
                decoded_bytes: 192_000_000,
                max_bytes: 100_000_000,
                ..
            }
        ));
        // A budget set tiny to spill geometry still admits a 4096 x 4096 texture.
        let mut s = scene_with(vec![png_header_only(4096, 4096)]);
        let limits = ImageLimits::under_budget(Some(64 << 10));
        assert!(admit_images(&mut s, &limits).is_ok());
    }

    #[test]
    fn undecodable_images_are_dropped_from_their_materials() {
        let good = png(2, 2);
        let mut cut = good.clone();
        cut.truncate(good.len() - 20);
        let mut s = scene_with(vec![good, b"not an image".to_vec(), cut]);
        // The header of image 1 does not read (admission); image 2's pixels end early (found by
        // the pass that decodes every image, identical-image merging).
        let limits = ImageLimits::under_budget(None);
        let options = crate::texture::TextureOptions::default();
        let dropped = crate::texture::prepare(&mut s, &options, &limits)
            .unwrap()
            .dropped_images;
        assert_eq!(
            dropped.iter().map(|d| d.image).collect::<Vec<_>>(),
            vec![1, 2]
        );
        assert!(s.materials[0].base_color_texture.is_some());
        assert!(s.materials[1].base_color_texture.is_none());
        assert!(s.materials[2].base_color_texture.is_none());
        let line = dropped[0].to_string();
        assert!(
            line.starts_with("in.glb: image 1 cannot be decoded"),
            "{line}"
        );
    }
}
