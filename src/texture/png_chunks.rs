//! Colour-space chunks taken out of PNG images. glTF 2.0 ("Images") has texture colours in sRGB
//! (or linear, by the texture's use) whatever the file says, and tells clients to ignore a PNG's
//! colour-space information (`cHRM`, `gAMA`, `iCCP`, `sRGB`) and pixel aspect; gltf-validator
//! warns of them (`IMAGE_FEATURES_UNSUPPORTED`), and so every 3D Tiles validator that runs it on
//! the tiles. Dropping them changes nothing a client draws: the other chunks, the pixel data
//! (`IDAT`) above all, are copied byte for byte, never decoded or re-encoded. A `pHYs` chunk goes
//! only when its pixels are not square.

use crate::scene::Scene;
use std::sync::Arc;

const SIGNATURE: &[u8; 8] = b"\x89PNG\r\n\x1a\n";
/// The colour-space chunks glTF clients ignore.
const COLOUR_SPACE_CHUNKS: [&[u8; 4]; 4] = [b"cHRM", b"gAMA", b"iCCP", b"sRGB"];

/// Whether a chunk (`kind`, `data`) is one a glTF image should not carry.
fn is_ignored(kind: &[u8], data: &[u8]) -> bool {
    COLOUR_SPACE_CHUNKS.iter().any(|c| kind == *c)
        || (kind == b"pHYs" && data.len() >= 8 && data[0..4] != data[4..8])
}

/// `png` without its colour-space chunks (and a non-square `pHYs`); `None` when it has none, or is
/// not a well-formed PNG (left to the decoder to judge).
pub fn without_colour_space(png: &[u8]) -> Option<Vec<u8>> {
    let body = png.strip_prefix(SIGNATURE)?;
    let mut kept = Vec::with_capacity(png.len());
    kept.extend_from_slice(SIGNATURE);
    let mut dropped = false;
    let mut at = 0;
    loop {
        let header = body.get(at..at + 8)?;
        let data_bytes = u32::from_be_bytes(header[0..4].try_into().ok()?) as usize;
        let end = at.checked_add(12)?.checked_add(data_bytes)?;
        let chunk = body.get(at..end)?;
        let kind = &header[4..8];
        if is_ignored(kind, &chunk[8..8 + data_bytes]) {
            dropped = true;
        } else {
            kept.extend_from_slice(chunk);
        }
        at = end;
        if kind == b"IEND" {
            break;
        }
    }
    // Bytes after IEND are not part of the image.
    dropped.then_some(kept)
}

/// Takes the colour-space chunks out of every PNG image of `scene`; returns how many images
/// changed.
pub fn clean_images(scene: &mut Scene) -> usize {
    let mut cleaned = 0;
    for image in &mut scene.images {
        if image.mime_type != "image/png" {
            continue;
        }
        if let Some(bytes) = without_colour_space(&image.bytes) {
            image.bytes = Arc::new(bytes);
            cleaned += 1;
        }
    }
    cleaned
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A PNG's chunk list: (type, data), read independently of the code under test.
    fn chunks(png: &[u8]) -> Vec<(String, Vec<u8>)> {
        let decoder = png::Decoder::new(std::io::Cursor::new(png));
        decoder.read_info().expect("a valid PNG");
        let mut out = Vec::new();
        let mut at = 8;
        while at < png.len() {
            let n = u32::from_be_bytes(png[at..at + 4].try_into().unwrap()) as usize;
            let kind = String::from_utf8_lossy(&png[at + 4..at + 8]).to_string();
            out.push((kind, png[at + 8..at + 8 + n].to_vec()));
            at += 12 + n;
        }
        out
    }

    /// A 3x2 RGBA PNG written by the `png` crate with the given colour and aspect chunks.
    fn png_with(srgb: bool, gamma: bool, aspect: Option<(u32, u32)>) -> Vec<u8> {
        let mut out = Vec::new();
        {
            let mut e = png::Encoder::new(&mut out, 3, 2);
            e.set_color(png::ColorType::Rgba);
            if srgb {
                e.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
            }
            if gamma {
                e.set_source_gamma(png::ScaledFloat::new(1.0 / 2.2));
            }
            if let Some((x, y)) = aspect {
                e.set_pixel_dims(Some(png::PixelDimensions {
                    xppu: x,
                    yppu: y,
                    unit: png::Unit::Meter,
                }));
            }
            e.add_text_chunk("Comment".into(), "kept".into()).unwrap();
            let mut w = e.write_header().unwrap();
            w.write_image_data(&(0..24).collect::<Vec<u8>>()).unwrap();
        }
        out
    }

    fn decoded(png: &[u8]) -> Vec<u8> {
        image::load_from_memory(png).unwrap().to_rgba8().into_raw()
    }

    #[test]
    fn colour_space_chunks_go_and_everything_else_stays_byte_for_byte() {
        let kinds = |p: &[u8]| chunks(p).into_iter().map(|c| c.0).collect::<Vec<_>>();
        for (png, present) in [
            (png_with(true, false, Some((3780, 2835))), ["sRGB", "pHYs"]),
            (png_with(false, true, None), ["gAMA", "tEXt"]),
        ] {
            for k in present.iter().chain(&["tEXt"]) {
                assert!(
                    kinds(&png).contains(&k.to_string()),
                    "{k}: {:?}",
                    kinds(&png)
                );
            }
            let clean = without_colour_space(&png).expect("something to drop");
            let expected: Vec<_> = chunks(&png)
                .into_iter()
                .filter(|(k, _)| !["sRGB", "gAMA", "cHRM", "iCCP", "pHYs"].contains(&k.as_str()))
                .collect();
            assert_eq!(chunks(&clean), expected);
            assert!(kinds(&clean).contains(&"tEXt".to_string()));
            assert_eq!(decoded(&clean), decoded(&png));
        }
        // Square pixels: pHYs stays; with nothing to drop the image is left alone.
        let square = png_with(false, false, Some((3780, 3780)));
        assert!(kinds(&square).contains(&"pHYs".to_string()));
        assert_eq!(without_colour_space(&square), None);
    }

    #[test]
    fn what_is_not_a_whole_png_is_left_to_the_decoder() {
        let png = png_with(true, false, None);
        assert_eq!(without_colour_space(b"\xff\xd8\xff\xe0 jpeg"), None);
        assert_eq!(without_colour_space(&png[..png.len() - 6]), None);
        assert_eq!(without_colour_space(&png[..20]), None);
        let mut huge = png.clone();
        huge[8..12].copy_from_slice(&u32::MAX.to_be_bytes());
        assert_eq!(without_colour_space(&huge), None);
    }

    #[test]
    fn only_png_images_of_a_scene_change() {
        let mut s = Scene::default();
        for (mime, bytes) in [
            ("image/png", png_with(true, false, None)),
            ("image/png", png_with(false, false, None)),
            ("image/jpeg", png_with(true, false, None)),
        ] {
            s.images.push(crate::scene::Image {
                name: None,
                mime_type: mime.into(),
                bytes: Arc::new(bytes),
            });
        }
        let before: Vec<_> = s.images.iter().map(|i| i.bytes.clone()).collect();
        assert_eq!(clean_images(&mut s), 1);
        assert!(s.images[0].bytes.len() < before[0].len());
        assert!(Arc::ptr_eq(&s.images[1].bytes, &before[1]));
        assert!(Arc::ptr_eq(&s.images[2].bytes, &before[2]));
    }
}
