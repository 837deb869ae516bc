//! Identical images stored once (paper III.D, redundant texture elimination).
//!
//! Two images are identical when their *decoded pixels* are (same size, same colour type, same
//! samples), whatever their file bytes (a PNG saved twice with other compression settings, a
//! re-exported copy). A pass over the scene before tiling points every material at the first
//! such image (lowest id), so tiles embed one copy. The dropped images stay in `Scene::images`
//! (ids do not move) but share the kept image's bytes, so their memory is freed.
//!
//! Images are decoded one at a time, row by row ([`Rows`]: one row held for PNG); only a 64-bit
//! hash per image is kept. Images with equal bytes are equal without decoding; a hash match is
//! confirmed by decoding both again and comparing row by row, so a collision cannot merge two
//! different images.

use super::codec::{CodecError, Rows};
use crate::error::chain_text;
use crate::scene::{ImageId, Scene};
use serde::Serialize;
use std::collections::BTreeMap;
use std::hash::{Hash, Hasher};

#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct IdenticalReport {
    /// Images found identical to an earlier one (now stored once).
    pub duplicates: usize,
    /// Encoded bytes of those duplicates.
    pub bytes_saved: u64,
    /// Images that could not be decoded (then dropped from their materials: `admit`).
    pub undecodable: usize,
    /// Those images, each with why it does not decode.
    #[serde(skip)]
    pub undecodable_images: Vec<(ImageId, String)>,
}

/// A hash of the decoded pixels (size, colour type and samples), or why the image does not
/// decode. Decoded row by row: one row held at a time (for PNG). This is the one pass that
/// decodes every image before tiling, so it is also where undecodable images are found.
pub fn pixel_key(bytes: &[u8]) -> Result<(u32, u32, u64), CodecError> {
    let mut rows = Rows::open(bytes)?;
    // DefaultHasher::new() has fixed keys: deterministic across runs.
    let mut h = std::collections::hash_map::DefaultHasher::new();
    format!("{:?}", rows.color()).hash(&mut h);
    while let Some(row) = rows.next_row()? {
        h.write(row);
    }
    Ok((rows.width(), rows.height(), h.finish()))
}

/// Whether two images decode to the same pixels, compared a row pair at a time; an image that
/// does not decode to its end equals none.
pub fn same_pixels(a: &[u8], b: &[u8]) -> bool {
    let (Ok(mut x), Ok(mut y)) = (Rows::open(a), Rows::open(b)) else {
        return false;
    };
    if (x.width(), x.height(), x.color()) != (y.width(), y.height(), y.color()) {
        return false;
    }
    loop {
        match (x.next_row(), y.next_row()) {
            (Ok(Some(r)), Ok(Some(s))) if r == s => {}
            (Ok(None), Ok(None)) => return true,
            _ => return false,
        }
    }
}

/// Points materials at one image per set of identical images; returns what it merged.
pub fn merge_identical(scene: &mut Scene) -> IdenticalReport {
    let mut report = IdenticalReport::default();
    let bound = super::classify::bound_images(scene);
    // Canonical image of each bound image.
    let mut canonical: BTreeMap<ImageId, ImageId> = BTreeMap::new();
    let mut by_key: BTreeMap<(u32, u32, u64), Vec<ImageId>> = BTreeMap::new();
    for &id in &bound {
        let bytes = scene.images[id.index()].bytes.clone();
        // Equal bytes: equal pixels, no decoding needed.
        if let Some(&earlier) = bound
            .iter()
            .take_while(|&&e| e < id)
            .find(|&&e| *scene.images[e.index()].bytes == *bytes)
        {
            canonical.insert(id, canonical.get(&earlier).copied().unwrap_or(earlier));
            continue;
        }
        let key = match pixel_key(&bytes) {
            Ok(key) => key,
            Err(e) => {
                report.undecodable += 1;
                report.undecodable_images.push((id, chain_text(&e)));
                continue;
            }
        };
        let list = by_key.entry(key).or_default();
        let found = list
            .iter()
            .copied()
            .find(|&e| same_pixels(&scene.images[e.index()].bytes, &bytes));
        match found {
            Some(e) => {
                canonical.insert(id, e);
            }
            None => list.push(id),
        }
    }
    for (&dup, &keep) in &canonical {
        report.duplicates += 1;
        report.bytes_saved += scene.images[dup.index()].bytes.len() as u64;
        let kept = scene.images[keep.index()].clone();
        let d = &mut scene.images[dup.index()];
        d.bytes = kept.bytes;
        d.mime_type = kept.mime_type;
    }
    for m in &mut scene.materials {
        if let Some(t) = m.base_color_texture.as_mut() {
            if let Some(&keep) = canonical.get(&t.image) {
                t.image = keep;
            }
        }
    }
    report
}

#[cfg(test)]
mod tests {
    use super::super::classify::tests::{quad, scene_of, textured_material};
    use super::*;
    use std::sync::Arc;

    fn png(px: &[u8], w: u32, h: u32, level: image::codecs::png::CompressionType) -> Vec<u8> {
        use image::ImageEncoder;
        let mut out = Vec::new();
        image::codecs::png::PngEncoder::new_with_quality(
            &mut out,
            level,
            image::codecs::png::FilterType::Adaptive,
        )
        .write_image(px, w, h, image::ExtendedColorType::Rgba8)
        .unwrap();
        out
    }

    #[test]
    fn same_pixels_in_other_bytes_are_merged_and_different_ones_kept() {
        use image::codecs::png::CompressionType::{Best, Fast};
        let a: Vec<u8> = (0..64u32).flat_map(|i| [i as u8, 2, 3, 255]).collect();
        let mut b = a.clone();
        b[5] = 99;
        let mut s = scene_of(
            (0..4)
                .map(|m| vec![quad(m, [0.0, 0.0], [1.0, 1.0])])
                .collect(),
            (0..4).map(textured_material).collect(),
            4,
        );
        let (fast, best) = (png(&a, 8, 8, Fast), png(&a, 8, 8, Best));
        assert_ne!(fast, best, "the test needs different bytes");
        s.images[0].bytes = Arc::new(fast);
        s.images[1].bytes = Arc::new(png(&b, 8, 8, Fast));
        s.images[2].bytes = Arc::new(best.clone());
        s.images[3].bytes = Arc::new(best);
        let r = merge_identical(&mut s);
        assert_eq!(r.duplicates, 2);
        let img = |m: usize| s.materials[m].base_color_texture.as_ref().unwrap().image;
        assert_eq!(img(0), ImageId(0));
        assert_eq!(img(1), ImageId(1));
        assert_eq!(img(2), ImageId(0));
        assert_eq!(img(3), ImageId(0));
        assert_eq!(super::super::classify::bound_images(&s).len(), 2);
    }
}
