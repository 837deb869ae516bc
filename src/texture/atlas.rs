//! Per-tile texture atlas (paper III.D): the small, non-repeating images one tile samples
//! are packed into one image, so the tile costs one texture request (or one embedded image)
//! instead of one per image, and the encoded bytes lose the per-file overhead (PNG/JPEG headers,
//! compression restarting at each file).
//!
//! For each tile, the candidates are the images its content samples, at the pyramid level chosen
//! for the tile ([`super::TextureLevels::for_tile`]), that
//! - are not *repeated* ([`super::classify`]) and have every UV of this tile's content inside
//!   [0, 1] (a tiling UV reaches across the image's edge, which an atlas cannot wrap),
//! - are sampled through `TEXCOORD_0` by every primitive of the tile that uses them,
//! - are at most [`ATLAS_MAX_IMAGE_SIDE_PX`] texels on their longer side at that level (small:
//!   large images gain little from losing a header and lose the sharing of one file between
//!   tiles).
//!
//! Candidates are grouped by the encoding they ship in (PNG with PNG, JPEG with JPEG: the atlas
//! is encoded as [`super::TextureFormat`] says for that source family, so lossless sources stay
//! lossless) and each group of at least two is shelf-packed ([`shelf_pack`], by height) into one
//! RGBA image, each image with a border of [`ATLAS_BORDER_PX`] copies of its edge texels (a
//! bilinear lookup at an image's edge, and the first mip levels, then see the edge colour, not
//! the neighbour's), slots aligned to [`ATLAS_ALIGN_PX`]. The UVs of the primitives that sample a
//! packed image are remapped into its rectangle, `u' = (x + u w) / W`, `v' = (y + v h) / H` (the
//! rectangle's corner `(x, y)` and size `w x h` in texels, the atlas `W x H`; glTF's v runs down
//! the image as rows do): the point at `u w` texels inside the image is the point at `x + u w`
//! in the atlas, so every texel, and every bilinear blend of texels inside the image, is looked
//! up where it was. Those primitives' materials point to the atlas.
//!
//! An atlas is kept only when it saves ([`keeps`]): at least two images in it, no more requests
//! than the separate images cost, and no more bytes than their encodings plus
//! [`ATLAS_BYTES_PER_SAVED_REQUEST`] per request saved. Otherwise the tile keeps its separate
//! images. A kept atlas is carried like any level: written once under `textures/`, named by its
//! bytes, or embedded below `--embed-textures-below`. Everything is a function of the tile's
//! content (images in id order, ties broken by id), so sharded builds write the same bytes.

use super::TileImage;
use super::{codec, TextureLevels, TileTextures};
use crate::partition::content::{ContentPrimitive, TileContent};
use crate::scene::ImageId;
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::Arc;

/// Texels of copied edge around each packed image: bilinear filtering reads half a texel past
/// the edge, mip level k averages 2^k texels, so 4 keeps levels 0-2 from bleeding.
pub const ATLAS_BORDER_PX: u32 = 4;
/// Slots start and end at multiples of this, so the 2x2 and 4x4 blocks of mip levels 1 and 2
/// never straddle two images.
pub const ATLAS_ALIGN_PX: u32 = 4;
/// Longest side (texels, at the tile's level) of an image that may be packed. Packing small
/// images saves requests and bytes; larger ones save too, but a larger image's file is more
/// often shared by several tiles, which an atlas per tile would copy into each; 256 is the
/// conservative middle (measured: docs/benchmarks.md).
pub const ATLAS_MAX_IMAGE_SIDE_PX: u32 = 256;
/// Largest atlas side: WebGL 2 guarantees textures of 2048 texels (`MAX_TEXTURE_SIZE`).
pub const ATLAS_MAX_SIDE_PX: u32 = 2048;
/// Bytes an atlas may add per request it saves: what an HTTP/1.1 request and response cost in
/// headers (several hundred bytes; the 1 KiB default of `--embed-textures-below` values a
/// request higher still), so an atlas that saves requests for a few bytes more is still kept.
pub const ATLAS_BYTES_PER_SAVED_REQUEST: u64 = 512;

/// Why packing failed (bad images are left unpacked; these are the output side).
#[derive(Debug, thiserror::Error)]
pub enum AtlasError {
    #[error("texture atlas encoding failed")]
    Encode(#[source] super::codec::CodecError),
    #[error("texture atlas file")]
    Store(#[source] super::external::StoreError),
}

/// One packed image's rectangle in the atlas (its texels, border excluded).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Slot {
    pub x_px: u32,
    pub y_px: u32,
    pub width_px: u32,
    pub height_px: u32,
}

impl Slot {
    /// The slot with its border, aligned: `[x0, y0, x1, y1)`.
    pub fn outer(&self, border_px: u32) -> [u32; 4] {
        let (w, h) = outer_size(self.width_px, self.height_px, border_px);
        let (x0, y0) = (self.x_px - border_px, self.y_px - border_px);
        [x0, y0, x0 + w, y0 + h]
    }
}

/// An atlas layout: its size and a slot per image (in the order the sizes were given).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Packing {
    pub width_px: u32,
    pub height_px: u32,
    pub slots: Vec<Slot>,
}

fn outer_size(w: u32, h: u32, border_px: u32) -> (u32, u32) {
    let a = |n: u32| (n + 2 * border_px).div_ceil(ATLAS_ALIGN_PX) * ATLAS_ALIGN_PX;
    (a(w), a(h))
}

/// Shelf packing at one atlas width: images by decreasing height (then width, then given order),
/// left to right on shelves as high as their first image.
fn shelves(outer: &[(u32, u32)], order: &[usize], width_px: u32) -> (u32, Vec<(u32, u32)>) {
    let mut at = vec![(0, 0); outer.len()];
    let (mut x, mut y, mut shelf_h) = (0u32, 0u32, 0u32);
    for &i in order {
        let (w, h) = outer[i];
        if x > 0 && x + w > width_px {
            y += shelf_h;
            x = 0;
            shelf_h = 0;
        }
        if shelf_h == 0 {
            shelf_h = h;
        }
        at[i] = (x, y);
        x += w;
    }
    (y + shelf_h, at)
}

/// Packs images of `sizes_px` (width, height) with `border_px` around each. Tries a few atlas
/// widths (from the square root of the area up to one shelf) and keeps the smallest area, then
/// the squarest: deterministic, no overlaps (tested), not optimal.
pub fn shelf_pack(sizes_px: &[(u32, u32)], border_px: u32) -> Packing {
    let outer: Vec<(u32, u32)> = sizes_px
        .iter()
        .map(|&(w, h)| outer_size(w, h, border_px))
        .collect();
    let mut order: Vec<usize> = (0..outer.len()).collect();
    order.sort_by_key(|&i| {
        (
            std::cmp::Reverse(outer[i].1),
            std::cmp::Reverse(outer[i].0),
            i,
        )
    });
    let area: u64 = outer.iter().map(|&(w, h)| w as u64 * h as u64).sum();
    let widest = outer.iter().map(|o| o.0).max().unwrap_or(0);
    let one_shelf: u32 = outer.iter().map(|o| o.0).sum();
    let side = (area as f64).sqrt();
    let mut widths: Vec<u32> = [1.0, 1.125, 1.25, 1.5, 2.0]
        .iter()
        .map(|f| {
            let w = ((side * f).ceil() as u32).div_ceil(ATLAS_ALIGN_PX) * ATLAS_ALIGN_PX;
            w.clamp(widest, one_shelf.max(widest))
        })
        .chain([one_shelf.max(widest)])
        .collect();
    widths.sort_unstable();
    widths.dedup();
    // Smallest area, then squarest, then narrowest (the first of equals).
    let (_, width_px, height_px, at) = widths
        .into_iter()
        .map(|w| {
            let (h, at) = shelves(&outer, &order, w);
            // The atlas is as wide as its widest shelf.
            let used_w = outer
                .iter()
                .zip(&at)
                .map(|(o, a)| a.0 + o.0)
                .max()
                .unwrap_or(0);
            let key = (used_w as u64 * h as u64, used_w.max(h), used_w);
            (key, used_w, h, at)
        })
        .min_by_key(|c| c.0)
        .unwrap_or(((0, 0, 0), 0, 0, Vec::new()));
    Packing {
        width_px,
        height_px,
        slots: sizes_px
            .iter()
            .zip(at)
            .map(|(&(w, h), (x, y))| Slot {
                x_px: x + border_px,
                y_px: y + border_px,
                width_px: w,
                height_px: h,
            })
            .collect(),
    }
}

/// The atlas's RGBA8 texels: each image at its slot, its slot's border (and alignment padding)
/// filled with the nearest edge texel, the rest opaque black (never sampled). `images[i]` is
/// `width x height` RGBA8 of `packing.slots[i]`.
pub fn compose(packing: &Packing, images: &[&[u8]], border_px: u32) -> Vec<u8> {
    let aw = packing.width_px as usize;
    let mut out: Vec<u8> = [0, 0, 0, 255].repeat(aw * packing.height_px as usize);
    for (slot, px) in packing.slots.iter().zip(images) {
        let [x0, y0, x1, y1] = slot.outer(border_px);
        let (w, h) = (slot.width_px as i64, slot.height_px as i64);
        for y in y0..y1 {
            let sy = (y as i64 - slot.y_px as i64).clamp(0, h - 1) as usize;
            let row = &px[sy * w as usize * 4..(sy + 1) * w as usize * 4];
            let dst =
                &mut out[(y as usize * aw + x0 as usize) * 4..(y as usize * aw + x1 as usize) * 4];
            for (k, d) in dst.chunks_exact_mut(4).enumerate() {
                let sx = (x0 as i64 + k as i64 - slot.x_px as i64).clamp(0, w - 1) as usize;
                d.copy_from_slice(&row[sx * 4..sx * 4 + 4]);
            }
        }
    }
    out
}

/// `uv` of an image (clamped to [0, 1]) as the UV of the same point of its slot in a
/// `atlas_w x atlas_h` atlas. In f64, so the texel a point falls in does not move.
pub fn remap_uv(uv: [f32; 2], slot: &Slot, atlas_w: u32, atlas_h: u32) -> [f32; 2] {
    let u = uv[0].clamp(0.0, 1.0) as f64;
    let v = uv[1].clamp(0.0, 1.0) as f64;
    [
        ((slot.x_px as f64 + u * slot.width_px as f64) / atlas_w as f64) as f32,
        ((slot.y_px as f64 + v * slot.height_px as f64) / atlas_h as f64) as f32,
    ]
}

/// Whether an atlas pays: at least two images, no more requests than the separate images, and
/// its bytes at most theirs plus [`ATLAS_BYTES_PER_SAVED_REQUEST`] per request saved.
pub fn keeps(
    images: usize,
    separate_bytes: u64,
    separate_requests: usize,
    atlas_bytes: u64,
    atlas_requests: usize,
) -> bool {
    let saved = separate_requests.saturating_sub(atlas_requests) as u64;
    images >= 2
        && atlas_requests <= separate_requests
        && atlas_bytes <= separate_bytes + saved * ATLAS_BYTES_PER_SAVED_REQUEST
}

/// What `report.json` says about atlases (summed over tiles; a tile with two atlases counts two).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct AtlasReport {
    /// Atlases kept (one per tile and encoding family).
    pub atlases: u64,
    /// Images packed into them (an image counts once per tile).
    pub images_packed: u64,
    /// Encoded bytes of those images as separate levels, and of the atlases.
    pub bytes_before: u64,
    pub bytes_after: u64,
    /// Groups of two or more candidates whose atlas did not pay (the tile kept its images).
    pub declined: u64,
}

/// The atlases of one tile: its content with the packed primitives' UVs remapped, and how the
/// tile carries each atlas.
#[derive(Debug, Clone)]
pub struct TileAtlas {
    pub content: TileContent,
    /// Packed image → index into `atlases`.
    packed: BTreeMap<ImageId, usize>,
    /// How the tile carries each atlas, and its longer side (texels).
    atlases: Vec<(TileImage, u32)>,
}

impl TileAtlas {
    /// The atlas image that replaces `id` in this tile, if `id` was packed.
    pub fn image(&self, id: ImageId) -> Option<&TileImage> {
        self.packed.get(&id).map(|&k| &self.atlases[k].0)
    }

    /// Per packed image, the longer side of the atlas it is sampled from (Draco's UV bits must
    /// resolve the atlas's texels, not the image's).
    pub fn texels_px(&self) -> BTreeMap<ImageId, u32> {
        self.packed
            .iter()
            .map(|(&id, &k)| (id, self.atlases[k].1))
            .collect()
    }

    /// Images packed, in id order.
    pub fn packed(&self) -> impl Iterator<Item = ImageId> + '_ {
        self.packed.keys().copied()
    }
}

/// One candidate of a tile: an image at its level, as the tile would ship it.
struct Candidate {
    id: ImageId,
    level: usize,
    bytes: Arc<Vec<u8>>,
}

/// The image a primitive samples, and whether its use allows packing (UVs through TEXCOORD_0,
/// all inside [0, 1]).
fn packable_use(levels: &TextureLevels, p: &ContentPrimitive) -> Option<(ImageId, bool)> {
    let t = p.material.and_then(|m| {
        levels.scene.materials[m.index()]
            .base_color_texture
            .as_ref()
    })?;
    let tol = super::classify::UV_RANGE_TOLERANCE;
    let ok = t.tex_coord == 0
        && !p.uvs.is_empty()
        && p.uvs.len() == p.positions.len()
        && p.uvs
            .iter()
            .all(|uv| uv.iter().all(|&x| (-tol..=1.0 + tol).contains(&x)));
    Some((t.image, ok))
}

impl TextureLevels<'_> {
    /// The atlases of one tile (`None`: the tile keeps separate images), for the levels
    /// `chosen` for it. A kept atlas is written (or prepared for embedding) and counted here,
    /// once; the images it replaces are not written for this tile.
    pub fn atlas_for_tile(
        &self,
        content: &TileContent,
        chosen: &TileTextures,
    ) -> Result<Option<TileAtlas>, AtlasError> {
        if !self.opts.atlas {
            return Ok(None);
        }
        // Images every use of which allows packing, in id order.
        let mut usable: BTreeMap<ImageId, bool> = BTreeMap::new();
        let prims = content
            .primitives
            .iter()
            .chain(content.instanced.iter().flat_map(|s| &s.primitives));
        for p in prims {
            if let Some((id, ok)) = packable_use(self, p) {
                let repeated = self.repeated.get(id.index()).copied().unwrap_or(true);
                *usable.entry(id).or_insert(true) &= ok && !repeated;
            }
        }
        // Candidates by the MIME type they ship in (BTreeMap: a fixed order).
        let mut groups: BTreeMap<String, Vec<Candidate>> = BTreeMap::new();
        for (id, _) in usable.into_iter().filter(|&(_, ok)| ok) {
            let level = chosen.0.get(&id).copied().unwrap_or(0);
            let (bytes, mime, level) = self.level_bytes(id, level);
            let small = codec::dimensions(&bytes)
                .is_ok_and(|(w, h)| w.max(h) <= ATLAS_MAX_IMAGE_SIDE_PX && w > 0 && h > 0);
            if small {
                groups
                    .entry(mime)
                    .or_default()
                    .push(Candidate { id, level, bytes });
            }
        }
        let mut packed = BTreeMap::new();
        let mut atlases = Vec::new();
        let mut slots: BTreeMap<ImageId, (Slot, u32, u32)> = BTreeMap::new();
        for (mime, group) in groups {
            if group.len() < 2 {
                continue;
            }
            let Some(built) = self.build_atlas(&mime, group)? else {
                continue;
            };
            for (id, slot) in &built.slots {
                packed.insert(*id, atlases.len());
                slots.insert(*id, (*slot, built.width_px, built.height_px));
            }
            atlases.push((built.image, built.width_px.max(built.height_px)));
        }
        if atlases.is_empty() {
            return Ok(None);
        }
        let mut content = content.clone();
        let remap = |p: &mut ContentPrimitive| {
            let Some(t) = p
                .material
                .and_then(|m| self.scene.materials[m.index()].base_color_texture.as_ref())
            else {
                return;
            };
            if let Some((slot, w, h)) = slots.get(&t.image) {
                for uv in &mut p.uvs {
                    *uv = remap_uv(*uv, slot, *w, *h);
                }
            }
        };
        content.primitives.iter_mut().for_each(remap);
        for s in &mut content.instanced {
            s.primitives.iter_mut().for_each(remap);
        }
        Ok(Some(TileAtlas {
            content,
            packed,
            atlases,
        }))
    }

    /// Packs one group (two or more candidates of one MIME type), or `None` when the atlas does
    /// not pay (counted as declined) or an image does not decode.
    fn build_atlas(
        &self,
        mime: &str,
        mut group: Vec<Candidate>,
    ) -> Result<Option<BuiltAtlas>, AtlasError> {
        let mut pixels = Vec::new();
        for c in &group {
            match codec::decode(&c.bytes) {
                Ok(img) => pixels.push(img.to_rgba8()),
                Err(_) => return Ok(None),
            }
        }
        // Too large for one texture: drop the largest images until it fits.
        let mut packing;
        loop {
            let sizes: Vec<(u32, u32)> = pixels.iter().map(|p| p.dimensions()).collect();
            packing = shelf_pack(&sizes, ATLAS_BORDER_PX);
            if packing.width_px.max(packing.height_px) <= ATLAS_MAX_SIDE_PX || group.len() < 2 {
                break;
            }
            let largest = (0..sizes.len())
                .max_by_key(|&i| (sizes[i].0 as u64 * sizes[i].1 as u64, std::cmp::Reverse(i)))
                .expect("non-empty");
            group.remove(largest);
            pixels.remove(largest);
        }
        if group.len() < 2 {
            return Ok(None);
        }
        let raw: Vec<&[u8]> = pixels.iter().map(|p| p.as_raw().as_slice()).collect();
        let rgba = compose(&packing, &raw, ATLAS_BORDER_PX);
        let (bytes, out_mime) = codec::encode_rgba(
            packing.width_px,
            packing.height_px,
            rgba,
            self.opts.format,
            mime,
            self.opts.jpeg_quality,
        )
        .map_err(AtlasError::Encode)?;
        let shared = self.external.as_ref();
        let requests = |n: usize| match shared {
            Some(_) if n >= self.opts.embed_below_bytes => 1,
            _ => 0,
        };
        let separate_bytes: u64 = group.iter().map(|c| c.bytes.len() as u64).sum();
        let separate_requests: usize = group.iter().map(|c| requests(c.bytes.len())).sum();
        if !keeps(
            group.len(),
            separate_bytes,
            separate_requests,
            bytes.len() as u64,
            requests(bytes.len()),
        ) {
            self.atlas_tally.lock().expect("atlas tally").declined += 1;
            return Ok(None);
        }
        // Counted at the finest level packed (a file's level, as `ExternalTextures` keeps it).
        let level = group.iter().map(|c| c.level).min().unwrap_or(0);
        let bytes = Arc::new(bytes);
        let image = match shared {
            Some(ext) if bytes.len() >= self.opts.embed_below_bytes => {
                let (uri, _) = ext
                    .store(&bytes, out_mime, level)
                    .map_err(AtlasError::Store)?;
                self.tally(level, 0);
                TileImage::External {
                    uri,
                    mime: out_mime.into(),
                }
            }
            _ => {
                self.tally(level, bytes.len());
                TileImage::Embedded {
                    bytes: bytes.clone(),
                    mime: out_mime.into(),
                }
            }
        };
        {
            let mut t = self.atlas_tally.lock().expect("atlas tally");
            t.atlases += 1;
            t.images_packed += group.len() as u64;
            t.bytes_before += separate_bytes;
            t.bytes_after += bytes.len() as u64;
        }
        Ok(Some(BuiltAtlas {
            image,
            width_px: packing.width_px,
            height_px: packing.height_px,
            slots: group.iter().map(|c| c.id).zip(packing.slots).collect(),
        }))
    }
}

struct BuiltAtlas {
    image: TileImage,
    width_px: u32,
    height_px: u32,
    slots: Vec<(ImageId, Slot)>,
}

#[cfg(test)]
mod tests {
    use super::super::classify::tests::{quad, scene_of, textured_material};
    use super::super::codec::tests::noise;
    use super::super::{TextureFormat, TextureOptions};
    use super::*;

    /// Deterministic sizes, 1 to 80 texels a side.
    fn sizes(n: usize, seed: u64) -> Vec<(u32, u32)> {
        noise(2 * n, seed)
            .chunks_exact(2)
            .map(|c| (1 + c[0] as u32 % 80, 1 + c[1] as u32 % 80))
            .collect()
    }

    #[test]
    fn packing_never_overlaps() {
        for (n, seed) in [(1, 1), (2, 2), (3, 3), (7, 4), (20, 5), (64, 6)] {
            for border in [0, 2, ATLAS_BORDER_PX] {
                let s = sizes(n, seed);
                let p = shelf_pack(&s, border);
                assert_eq!(p.slots.len(), n);
                let rects: Vec<[u32; 4]> = p.slots.iter().map(|sl| sl.outer(border)).collect();
                for (i, (r, sl)) in rects.iter().zip(&p.slots).enumerate() {
                    assert_eq!((sl.width_px, sl.height_px), s[i]);
                    assert!(r[2] <= p.width_px && r[3] <= p.height_px, "{r:?} in atlas");
                    assert_eq!(r[0] % ATLAS_ALIGN_PX, 0);
                    assert_eq!(r[1] % ATLAS_ALIGN_PX, 0);
                    // The image and its full border inside the slot.
                    assert!(sl.x_px >= r[0] + border && sl.x_px + sl.width_px + border <= r[2]);
                    assert!(sl.y_px >= r[1] + border && sl.y_px + sl.height_px + border <= r[3]);
                    for q in &rects[i + 1..] {
                        let apart = r[2] <= q[0] || q[2] <= r[0] || r[3] <= q[1] || q[3] <= r[1];
                        assert!(apart, "{r:?} overlaps {q:?} ({n} images, border {border})");
                    }
                }
                // Not wasteful: at most twice the slots' area.
                let area: u64 = rects
                    .iter()
                    .map(|r| (r[2] - r[0]) as u64 * (r[3] - r[1]) as u64)
                    .sum();
                assert!((p.width_px as u64 * p.height_px as u64) <= 2 * area.max(1));
                assert_eq!(p, shelf_pack(&s, border), "deterministic");
            }
        }
    }

    /// `w x h` RGBA8 noise, opaque.
    fn picture(w: u32, h: u32, seed: u64) -> Vec<u8> {
        let mut px = noise((w * h * 4) as usize, seed);
        px.chunks_exact_mut(4).for_each(|p| p[3] = 255);
        px
    }

    /// `n` pictures of random sizes (`seed`; their texels from `picture_seed` on), packed and
    /// composed: the packing, the pictures and the atlas.
    fn packed_pictures(n: usize, seed: u64, picture_seed: u64) -> (Packing, Vec<Vec<u8>>, Vec<u8>) {
        let s = sizes(n, seed);
        let p = shelf_pack(&s, ATLAS_BORDER_PX);
        let imgs: Vec<Vec<u8>> = s
            .iter()
            .enumerate()
            .map(|(i, &(w, h))| picture(w, h, picture_seed + i as u64))
            .collect();
        let raw: Vec<&[u8]> = imgs.iter().map(|v| v.as_slice()).collect();
        let atlas = compose(&p, &raw, ATLAS_BORDER_PX);
        (p, imgs, atlas)
    }

    #[test]
    fn borders_copy_the_edge_texels() {
        let (p, imgs, atlas) = packed_pictures(9, 7, 0);
        let at = |x: u32, y: u32| {
            let i = ((y * p.width_px + x) * 4) as usize;
            &atlas[i..i + 4]
        };
        for (sl, img) in p.slots.iter().zip(&imgs) {
            let [x0, y0, x1, y1] = sl.outer(ATLAS_BORDER_PX);
            for y in y0..y1 {
                for x in x0..x1 {
                    let sx = (x as i64 - sl.x_px as i64).clamp(0, sl.width_px as i64 - 1);
                    let sy = (y as i64 - sl.y_px as i64).clamp(0, sl.height_px as i64 - 1);
                    let i = ((sy * sl.width_px as i64 + sx) * 4) as usize;
                    assert_eq!(at(x, y), &img[i..i + 4], "texel {x},{y}");
                }
            }
        }
    }

    /// Nearest texel (clamped) of a `w x h` RGBA8 image at `uv`.
    fn texel(px: &[u8], w: u32, h: u32, uv: [f32; 2]) -> [u8; 4] {
        let x = ((uv[0] as f64 * w as f64).floor() as i64).clamp(0, w as i64 - 1);
        let y = ((uv[1] as f64 * h as f64).floor() as i64).clamp(0, h as i64 - 1);
        let i = ((y * w as i64 + x) * 4) as usize;
        px[i..i + 4].try_into().unwrap()
    }

    #[test]
    fn remapped_uvs_show_the_same_texels() {
        let (p, imgs, atlas) = packed_pictures(12, 9, 100);
        let uvs = noise(2000, 3);
        for (k, (sl, img)) in p.slots.iter().zip(&imgs).enumerate() {
            let (w, h) = (sl.width_px, sl.height_px);
            // Random UVs, texel centres, and the image's corners and edges (the border answers
            // past the edge as clamping would).
            let mut pts: Vec<[f32; 2]> = uvs
                .chunks_exact(2)
                .map(|c| [c[0] as f32 / 255.0, c[1] as f32 / 255.0])
                .collect();
            pts.extend((0..w).map(|x| [(x as f32 + 0.5) / w as f32, 0.5]));
            pts.extend((0..h).map(|y| [0.5, (y as f32 + 0.5) / h as f32]));
            pts.extend([[0.0, 0.0], [1.0, 1.0], [0.0, 1.0], [1.0, 0.0]]);
            for uv in pts {
                let a = remap_uv(uv, sl, p.width_px, p.height_px);
                // On a texel border inside the image either side is right (the image's own
                // edges, 0 and 1, are not: the border must answer as clamping).
                let on_border = |t: f32, n: u32| {
                    t > 0.0 && t < 1.0 && {
                        let x = t as f64 * n as f64;
                        (x - x.round()).abs() < 1e-4
                    }
                };
                if on_border(uv[0], w) || on_border(uv[1], h) {
                    continue;
                }
                assert_eq!(
                    texel(&atlas, p.width_px, p.height_px, a),
                    texel(img, w, h, uv),
                    "image {k} ({w}x{h}) uv {uv:?} -> {a:?}"
                );
            }
        }
    }

    #[test]
    fn the_rule_keeps_only_atlases_that_save() {
        assert!(!keeps(1, 5000, 1, 100, 0), "one image");
        assert!(keeps(2, 5000, 2, 5000, 1));
        assert!(keeps(2, 5000, 2, 5000 + ATLAS_BYTES_PER_SAVED_REQUEST, 1));
        assert!(!keeps(2, 5000, 2, 5001 + ATLAS_BYTES_PER_SAVED_REQUEST, 1));
        assert!(!keeps(2, 1600, 0, 1500, 1), "embedded images, atlas a file");
        assert!(keeps(3, 1600, 0, 900, 0), "embedded and smaller");
        assert!(!keeps(3, 1600, 0, 1601, 0));
    }

    fn png(w: u32, h: u32, seed: u64) -> Vec<u8> {
        // Smooth: a noise image does not compress, so no atlas of it would pay.
        let px: Vec<u8> = (0..w * h)
            .flat_map(|i| {
                let (x, y) = (i % w, i / w);
                [
                    (x * 3 + seed as u32 * 40) as u8,
                    (y * 5) as u8,
                    seed as u8 * 60,
                    255,
                ]
            })
            .collect();
        codec::encode_rgba(w, h, px, TextureFormat::Png, "", 0)
            .unwrap()
            .0
    }

    #[test]
    fn a_tile_packs_its_small_non_repeating_images() {
        // Three quads in one tile: images 0 and 1 inside [0, 1], image 2 tiling (repeated).
        let mut s = scene_of(
            vec![
                vec![quad(0, [0.1, 0.2], [0.9, 0.7])],
                vec![quad(1, [0.0, 0.0], [1.0, 1.0])],
                vec![quad(2, [0.0, 0.0], [3.0, 2.0])],
            ],
            vec![
                textured_material(0),
                textured_material(1),
                textured_material(2),
            ],
            3,
        );
        for (i, (w, h)) in [(40, 30), (24, 24), (16, 16)].into_iter().enumerate() {
            s.images[i].bytes = Arc::new(png(w, h, i as u64));
        }
        let content = TileContent::gather(
            &s,
            &(0..3)
                .map(|c| crate::partition::ContentItem {
                    component: crate::scene::ComponentId(c),
                    triangles: None,
                })
                .collect::<Vec<_>>(),
            glam::DVec3::ZERO,
        );
        let opts = TextureOptions {
            atlas: true,
            embed: true,
            ..Default::default()
        };
        let uses = crate::texture::classify::classify(&s);
        let levels = TextureLevels::new(&s, &opts, &uses);
        let chosen = levels.for_tile(&content, 0.0);
        let atlas = levels.atlas_for_tile(&content, &chosen).unwrap().unwrap();
        assert_eq!(atlas.packed().collect::<Vec<_>>(), [ImageId(0), ImageId(1)]);
        assert!(atlas.image(ImageId(2)).is_none(), "repeated: never packed");
        let TileImage::Embedded { bytes, mime } = atlas.image(ImageId(0)).unwrap() else {
            panic!("embedded")
        };
        assert_eq!(mime, "image/png");
        let atlas_px = codec::decode(bytes).unwrap().to_rgba8();
        let (aw, ah) = atlas_px.dimensions();
        assert_eq!(atlas.texels_px()[&ImageId(1)], aw.max(ah));
        // Every vertex UV (nudged inside its texel) shows the same colour.
        let mut checked = 0;
        for (before, after) in content.primitives.iter().zip(&atlas.content.primitives) {
            let id = s.materials[before.material.unwrap().index()]
                .base_color_texture
                .as_ref()
                .unwrap()
                .image;
            if id == ImageId(2) {
                assert_eq!(before.uvs, after.uvs, "repeated image's UVs untouched");
                continue;
            }
            let img = codec::decode(&s.images[id.index()].bytes)
                .unwrap()
                .to_rgba8();
            let (w, h) = img.dimensions();
            for (a, b) in before.uvs.iter().zip(&after.uvs) {
                let inside = a.map(|t| (t * 0.98 + 0.01).clamp(0.0, 1.0));
                let b2 = remap_uv(inside, &atlas_slot(&atlas, &s, id, aw, ah), aw, ah);
                assert_eq!(
                    texel(atlas_px.as_raw(), aw, ah, b2),
                    texel(img.as_raw(), w, h, inside)
                );
                // The stored UV is the remap of the old one.
                let slot = atlas_slot(&atlas, &s, id, aw, ah);
                assert_eq!(*b, remap_uv(*a, &slot, aw, ah));
                checked += 1;
            }
        }
        assert_eq!(checked, 8);
        let t = levels.atlas_tally.lock().unwrap().clone();
        assert_eq!((t.atlases, t.images_packed), (1, 2));
        assert_eq!(t.bytes_after, bytes.len() as u64);
        // Off: nothing.
        let off = TextureLevels::new(&s, &TextureOptions::default(), &uses);
        assert!(off.atlas_for_tile(&content, &chosen).unwrap().is_none());
    }

    /// The slot of `id` in the tile's atlas, recovered from the remapped UVs' box against the
    /// old ones (the packing is recomputed: same sizes, same layout).
    fn atlas_slot(
        atlas: &TileAtlas,
        s: &crate::scene::Scene,
        id: ImageId,
        aw: u32,
        ah: u32,
    ) -> Slot {
        let sizes: Vec<(u32, u32)> = atlas
            .packed()
            .map(|i| codec::dimensions(&s.images[i.index()].bytes).unwrap())
            .collect();
        let p = shelf_pack(&sizes, ATLAS_BORDER_PX);
        assert_eq!((p.width_px, p.height_px), (aw, ah));
        let k = atlas.packed().position(|i| i == id).unwrap();
        p.slots[k]
    }
}
