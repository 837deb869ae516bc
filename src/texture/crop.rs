//! Cropping the texture area no UV reaches (paper III.D, redundant texture elimination).
//!
//! For *standalone* and *shared* images whose UVs all stay inside [0, 1] (not *repeated*), the
//! union of the UV boxes of every primitive that samples the image (over all materials binding
//! it) is cut out, with [`CROP_PADDING_TEXELS`] texels of the original kept around it so bilinear
//! filtering and mipmaps do not bleed in colours from outside, and every such primitive's UVs are
//! remapped to the crop: `u' = (u * w - x0) / w'` (same for v; glTF's v runs down the image, as
//! rows do). A texel at UV `u` before is the texel at `u'` after, so the colours the model shows
//! are unchanged (tested by sampling at each vertex's UV before and after).
//!
//! Repeated textures are left whole (a tiling UV reaches the whole image). Images whose UV use is
//! unknown (a primitive without UVs, or another texCoord set) are left alone. A crop is kept only
//! when it drops at least [`MIN_CROP_SAVING`] of the texels and its encoding is smaller than the
//! original file: crops are encoded losslessly (PNG), which for a JPEG source can be larger.
//! The paper's integer offset of shared textures is this shift by `x0, y0` in texels.
//!
//! Memory: the image is decoded row by row and only the used rectangle is kept ([`crop_rgba8`]).

use super::classify::{ImageUse, TextureClass};
use super::codec::{dimensions, encode_rgba, row_to_rgba8, CodecError, Rows, TextureFormat};
use crate::scene::{ImageId, MeshId, Primitive, Scene};
use serde::Serialize;
use std::sync::Arc;

/// Texels of the original kept around the used area.
pub const CROP_PADDING_TEXELS: u32 = 4;
/// Crops that keep more than this share of the texels are not worth a re-encode.
pub const MIN_CROP_SAVING: f64 = 0.10;

#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct CropReport {
    pub cropped: usize,
    /// Texels and encoded bytes of the cropped images, before and after.
    pub texels_before: u64,
    pub texels_after: u64,
    pub bytes_before: u64,
    pub bytes_after: u64,
}

/// The texel rectangle `[x0, x1) x [y0, y1)` that UVs in `uv_box` reach, padded, in a `w x h`
/// image.
pub fn used_rect(uv_box: ([f32; 2], [f32; 2]), w: u32, h: u32, pad: u32) -> [u32; 4] {
    let (lo, hi) = uv_box;
    let lo_px = |t: f32, n: u32| {
        ((t as f64 * n as f64).floor() as i64 - pad as i64).clamp(0, n as i64) as u32
    };
    let hi_px = |t: f32, n: u32| {
        ((t as f64 * n as f64).ceil() as i64 + pad as i64).clamp(0, n as i64) as u32
    };
    let (x0, x1) = (
        lo_px(lo[0], w),
        hi_px(hi[0], w).max(lo_px(lo[0], w) + 1).min(w),
    );
    let (y0, y1) = (
        lo_px(lo[1], h),
        hi_px(hi[1], h).max(lo_px(lo[1], h) + 1).min(h),
    );
    [x0, y0, x1, y1]
}

/// The texels `[x0, x1) x [y0, y1)` of an encoded image as 8-bit RGBA, decoded row by row: only
/// the rectangle is held (plus the whole decoded image for formats without a row decoder). The
/// image is decoded to its end, so one that does not decode is not cropped.
pub fn crop_rgba8(bytes: &[u8], rect: [u32; 4]) -> Result<Vec<u8>, CodecError> {
    let [x0, y0, x1, y1] = rect.map(|v| v as usize);
    let mut rows = Rows::open(bytes)?;
    let (w, h) = (rows.width() as usize, rows.height() as usize);
    if x0 >= x1 || y0 >= y1 || x1 > w || y1 > h {
        return Err(CodecError::Inconsistent("crop rectangle outside the image"));
    }
    let bpp = rows.color().bytes_per_pixel() as usize;
    let color = rows.color();
    let line = (x1 - x0) * 4;
    let mut out = vec![0u8; line * (y1 - y0)];
    let mut y = 0;
    while let Some(row) = rows.next_row()? {
        if (y0..y1).contains(&y) {
            let dst = &mut out[(y - y0) * line..(y - y0 + 1) * line];
            row_to_rgba8(color, &row[x0 * bpp..x1 * bpp], dst);
        }
        y += 1;
    }
    Ok(out)
}

/// Crops every eligible image of `scene` in place and remaps the UVs that sample it.
pub fn crop_unused(scene: &mut Scene, uses: &[ImageUse]) -> CropReport {
    let mut report = CropReport::default();
    for (i, u) in uses.iter().enumerate() {
        if !matches!(u.class, TextureClass::Standalone | TextureClass::Shared) || u.uv_unknown {
            continue;
        }
        let Some(uv_box) = u.uv_box else { continue };
        let id = ImageId(i as u32);
        let original = scene.images[i].clone();
        let Ok((w, h)) = dimensions(&original.bytes) else {
            continue;
        };
        let [x0, y0, x1, y1] = used_rect(uv_box, w, h, CROP_PADDING_TEXELS);
        let (cw, ch) = (x1 - x0, y1 - y0);
        let (before, after) = (w as u64 * h as u64, cw as u64 * ch as u64);
        if after as f64 > before as f64 * (1.0 - MIN_CROP_SAVING) {
            continue;
        }
        let Ok(sub) = crop_rgba8(&original.bytes, [x0, y0, x1, y1]) else {
            continue;
        };
        let Ok((bytes, mime)) = encode_rgba(cw, ch, sub, TextureFormat::Png, "", 0) else {
            continue;
        };
        if bytes.len() >= original.bytes.len() {
            continue;
        }
        report.cropped += 1;
        report.texels_before += before;
        report.texels_after += after;
        report.bytes_before += original.bytes.len() as u64;
        report.bytes_after += bytes.len() as u64;
        let im = &mut scene.images[i];
        im.bytes = Arc::new(bytes);
        im.mime_type = mime.into();
        remap_uvs(scene, id, [x0, y0], [w, h], [cw, ch]);
    }
    report
}

/// `u' = (u * w - x0) / w'`, `v' = (v * h - y0) / h'` on every primitive sampling `image`.
fn remap_uvs(scene: &mut Scene, image: ImageId, offset: [u32; 2], size: [u32; 2], crop: [u32; 2]) {
    let uses: Vec<bool> = scene
        .materials
        .iter()
        .map(|m| {
            m.base_color_texture
                .as_ref()
                .is_some_and(|t| t.image == image)
        })
        .collect();
    let sampling = |p: &Primitive| p.uvs.is_some() && p.material.is_some_and(|m| uses[m.index()]);
    // Which meshes sample the image first (a spilled mesh is read, not rewritten, when it does not).
    let touched = scene.meshes.par_map(|m| m.primitives.iter().any(sampling));
    for (i, _) in touched.iter().enumerate().filter(|t| *t.1) {
        scene.meshes.update(MeshId(i as u32), |mesh| {
            for p in mesh.primitives.iter_mut().filter(|p| sampling(p)) {
                for uv in p.uvs.iter_mut().flatten() {
                    for a in 0..2 {
                        uv[a] = ((uv[a] as f64 * size[a] as f64 - offset[a] as f64)
                            / crop[a] as f64) as f32;
                    }
                }
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::super::classify::classify;
    use super::super::classify::tests::{quad, scene_of, textured_material};
    use super::super::codec::decode;
    use super::*;

    /// The texel (nearest, clamped) an image shows at `uv`.
    pub fn texel(img: &image::RgbaImage, uv: [f32; 2]) -> [u8; 4] {
        let (w, h) = img.dimensions();
        let x = ((uv[0] as f64 * w as f64).floor() as i64).clamp(0, w as i64 - 1) as u32;
        let y = ((uv[1] as f64 * h as f64).floor() as i64).clamp(0, h as i64 - 1) as u32;
        img.get_pixel(x, y).0
    }

    fn noise_png(w: u32, h: u32) -> Vec<u8> {
        let mut s = 12345u64;
        let px: Vec<u8> = (0..w * h * 4)
            .map(|i| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                if i % 4 == 3 {
                    255
                } else {
                    (s >> 59) as u8 * 16 // few colours: compressible, like a texture
                }
            })
            .collect();
        encode_rgba(w, h, px, TextureFormat::Png, "", 0).unwrap().0
    }

    /// Points inside each triangle near its corners (off texel borders) and the corners.
    fn sample_points(p: &crate::scene::Primitive) -> Vec<[f32; 2]> {
        let uvs = p.uvs.as_ref().unwrap();
        let mut out = Vec::new();
        for t in p.indices.chunks_exact(3) {
            let c: Vec<[f32; 2]> = t.iter().map(|&i| uvs[i as usize]).collect();
            let m = [
                (c[0][0] + c[1][0] + c[2][0]) / 3.0,
                (c[0][1] + c[1][1] + c[2][1]) / 3.0,
            ];
            for k in &c {
                out.push([k[0] * 0.99 + m[0] * 0.01, k[1] * 0.99 + m[1] * 0.01]);
            }
        }
        out
    }

    #[test]
    fn cropping_keeps_the_colours_at_every_uv_and_drops_the_rest() {
        // Image 0: standalone, UVs in a corner; image 1: shared by two materials with two boxes;
        // image 2: repeated (left whole).
        let mut s = scene_of(
            vec![
                vec![quad(0, [0.1, 0.2], [0.4, 0.35])],
                vec![
                    quad(1, [0.5, 0.5], [0.6, 0.7]),
                    quad(2, [0.55, 0.6], [0.8, 0.75]),
                ],
                vec![quad(3, [0.0, 0.0], [2.0, 2.0])],
            ],
            vec![
                textured_material(0),
                textured_material(1),
                textured_material(1),
                textured_material(2),
            ],
            3,
        );
        for i in 0..3 {
            s.images[i].bytes = Arc::new(noise_png(200 + i as u32, 120));
        }
        let before = s.clone();
        let uses = classify(&s);
        let r = crop_unused(&mut s, &uses);
        assert_eq!(r.cropped, 2);
        assert!(r.texels_after < r.texels_before / 4);
        // Image 0: u 0.1..0.4 of 200 = 20..80 (0.4f32 is a hair above: 81), v 0.2..0.35 of
        // 120 = 24..42, padded by 4.
        assert_eq!(dimensions(&s.images[0].bytes).unwrap(), (69, 26));
        assert_eq!(
            *s.images[2].bytes, *before.images[2].bytes,
            "repeated: untouched"
        );
        for (mb, ma) in before.meshes.iter().zip(s.meshes.iter()) {
            for (pb, pa) in mb.primitives.iter().zip(&ma.primitives) {
                let img = |sc: &Scene| {
                    let m = &sc.materials[pb.material.unwrap().index()];
                    let id = m.base_color_texture.as_ref().unwrap().image;
                    decode(&sc.images[id.index()].bytes).unwrap().to_rgba8()
                };
                let (ib, ia) = (img(&before), img(&s));
                let (sb, sa) = (sample_points(pb), sample_points(pa));
                for (b, a) in sb.iter().zip(&sa) {
                    assert_eq!(texel(&ib, *b), texel(&ia, *a), "uv {b:?} → {a:?}");
                }
            }
        }
    }

    #[test]
    fn crop_by_rows_is_the_crop_of_the_whole_image() {
        use super::super::codec::tests::{interlaced_png, jpeg_of, noise, png_cases};
        let (w, h) = (37u32, 22u32);
        let mut cases = png_cases(w, h);
        cases.push((
            "interlaced".into(),
            interlaced_png(w, h, &noise((w * h * 4) as usize, 5)),
        ));
        cases.push(("jpeg".into(), jpeg_of(w, h, false)));
        for (name, bytes) in cases {
            let whole = decode(&bytes).unwrap().to_rgba8();
            for rect in [[0, 0, w, h], [3, 5, 20, 6], [30, 0, 37, 22], [0, 21, 1, 22]] {
                let [x0, y0, x1, y1] = rect;
                let reference = image::imageops::crop_imm(&whole, x0, y0, x1 - x0, y1 - y0);
                assert_eq!(
                    crop_rgba8(&bytes, rect).unwrap(),
                    reference.to_image().into_raw(),
                    "{name} {rect:?}"
                );
            }
            assert!(crop_rgba8(&bytes, [0, 0, w + 1, h]).is_err());
            assert!(crop_rgba8(&bytes, [4, 4, 4, 8]).is_err());
            // Not decodable to the end, not cropped (JPEG: `image` decodes what is there).
            let half = &bytes[..bytes.len() / 2];
            assert_eq!(
                crop_rgba8(half, [0, 0, 2, 2]).is_err(),
                decode(half).is_err(),
                "{name}"
            );
            assert_eq!(decode(half).is_err(), name != "jpeg", "{name}");
        }
    }

    #[test]
    fn used_rect_is_padded_and_clamped() {
        assert_eq!(
            used_rect(([0.0, 0.0], [1.0, 1.0]), 64, 32, 4),
            [0, 0, 64, 32]
        );
        assert_eq!(
            used_rect(([0.5, 0.25], [0.5, 0.25]), 64, 32, 2),
            [30, 6, 34, 10]
        );
    }
}
