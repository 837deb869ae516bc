//! Textures (paper III.D–III.F): redundant texture elimination, a Haar wavelet pyramid per image,
//! and the pyramid level matched to each tile's level of detail.
//!
//! Before tiling, [`prepare`] runs four passes over the scene, in order:
//! 0. PNG colour-space chunks, which glTF clients ignore, dropped ([`png_chunks`]);
//! 1. identical images stored once ([`identical`]);
//! 2. classification into repeated / shared / standalone ([`classify`]);
//! 3. cropping of the area no UV reaches, UVs remapped ([`crop`]).
//!
//! While tiles are written, [`TextureLevels`] gives each tile, per image, the pyramid level of
//! [`lod`] (from the tile's geometricError and its triangles' texel size) and the encoded bytes of
//! that level ([`haar`] + [`codec`]). A pyramid is built once per image, on the first tile that
//! needs a coarser level, and kept encoded. Level 0 is decoded row by row into it, so a worker
//! thread holds the coarser levels in 8 bits (a third of the image's RGBA bytes), not the image
//! (JPEG and WebP, which have no row decoder, are decoded whole in their own colour type). Level
//! 0 is the image as the scene holds it: the input's own bytes (less ignored chunks) unless it
//! was cropped, never re-encoded. Each level a tile uses is written once under `<tileset>/textures/` and referenced
//! by the tiles ([`external`]), or embedded in every tile GLB with `embed`; once every tile is
//! written, a file whose copies cost less than a request moves into the tiles that reference it
//! ([`single_use`]). With `atlas`, a tile's small non-repeating images are packed into one image
//! when that saves requests and bytes ([`atlas`]). `tileset::view` measures what a client loads
//! for a first whole-model view.

pub mod admit;
pub mod atlas;
pub mod basisu;
pub mod classify;
pub mod codec;
pub mod crop;
pub mod external;
pub mod haar;
pub mod identical;
pub mod lod;
pub mod png_chunks;
pub mod single_use;

pub use codec::{TextureFormat, DEFAULT_JPEG_QUALITY};

use crate::partition::content::TileContent;
use crate::scene::{ImageId, Scene};
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, OnceLock};

/// How one tile carries an image (e.g. the texture pyramid level matched to the tile:
/// [`TextureLevels`]); the encoder writes it.
#[derive(Debug, Clone)]
pub enum TileImage {
    /// The bytes go into the GLB's BIN chunk (a bufferView).
    Embedded {
        bytes: std::sync::Arc<Vec<u8>>,
        mime: String,
    },
    /// A file shared by the tiles of the tileset, referenced by a URI relative to the GLB (glTF
    /// 2.0 §3.3.3: relative URIs resolve against the glTF's own location).
    External { uri: String, mime: String },
}

/// Gives the image of one tile, or why it cannot.
pub type ImageSource<'a> =
    &'a (dyn Fn(ImageId) -> std::result::Result<TileImage, external::StoreError> + Sync);

/// What the texture stage does.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TextureOptions {
    /// Match each tile's texture level to its geometric error (off: every tile gets level 0).
    pub lod: bool,
    /// Crop the area of standalone/shared images that no UV reaches.
    pub crop: bool,
    /// Encoding of re-encoded levels.
    pub format: TextureFormat,
    pub jpeg_quality: u8,
    /// Embed each tile's images in its GLB instead of sharing one file per image level.
    pub embed: bool,
    /// Image levels smaller than this are embedded even when sharing (a request costs more than
    /// repeating a few hundred bytes).
    pub embed_below_bytes: usize,
    /// Pack each tile's small non-repeating images into one atlas when that saves ([`atlas`]).
    pub atlas: bool,
}

/// Default of [`TextureOptions::embed_below_bytes`]: large enough to embed the coarse levels (a
/// few hundred bytes each), saving requests for few more texture bytes; larger thresholds save
/// few more requests for many more bytes (chosen by measurement: docs/benchmarks.md).
pub const DEFAULT_EMBED_BELOW_BYTES: usize = 1024;

/// Default of [`TextureOptions::atlas`], chosen by measurement (docs/benchmarks.md).
pub const DEFAULT_ATLAS: bool = false;

impl Default for TextureOptions {
    fn default() -> Self {
        TextureOptions {
            lod: true,
            crop: true,
            format: TextureFormat::default(),
            jpeg_quality: DEFAULT_JPEG_QUALITY,
            embed: false,
            embed_below_bytes: DEFAULT_EMBED_BELOW_BYTES,
            atlas: DEFAULT_ATLAS,
        }
    }
}

/// What the passes before tiling found and did.
#[derive(Debug, Clone, Serialize)]
pub struct Prepared {
    /// Images materials bind, and their encoded bytes, as read.
    pub images_bound: usize,
    pub original_bytes: u64,
    pub identical: identical::IdenticalReport,
    /// Classes of the images still bound after identical ones were merged.
    pub classes: classify::ClassCounts,
    pub crop: crop::CropReport,
    /// Images that could not be decoded, dropped from their materials ([`admit`]).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub dropped_images: Vec<admit::DroppedImage>,
    #[serde(skip)]
    pub uses: Vec<classify::ImageUse>,
}

/// Images admitted under `limits` (an image over them is refused, with its input file; an
/// undecodable one dropped), PNG colour-space chunks dropped ([`png_chunks`]), identical images
/// merged, images classified, unused areas cropped
/// (with `opts.crop`).
pub fn prepare(
    scene: &mut Scene,
    opts: &TextureOptions,
    limits: &admit::ImageLimits,
) -> Result<Prepared, (std::path::PathBuf, admit::ImageRefused)> {
    let bound = classify::bound_images(scene);
    let original_bytes = bound
        .iter()
        .map(|i| scene.images[i.index()].bytes.len() as u64)
        .sum();
    let mut dropped_images = admit::admit_images(scene, limits)?;
    // Before the identical-image pass: two files that differ only in colour-space chunks are the
    // same image to a glTF client.
    png_chunks::clean_images(scene);
    let identical = identical::merge_identical(scene);
    dropped_images.extend(admit::drop_images(scene, &identical.undecodable_images));
    let uses = classify::classify(scene);
    let classes = classify::counts(
        &classify::bound_images(scene)
            .iter()
            .map(|i| uses[i.index()].clone())
            .collect::<Vec<_>>(),
    );
    let crop = if opts.crop {
        crop::crop_unused(scene, &uses)
    } else {
        crop::CropReport::default()
    };
    Ok(Prepared {
        images_bound: bound.len(),
        original_bytes,
        identical,
        classes,
        crop,
        dropped_images,
        uses,
    })
}

/// One encoded pyramid level.
#[derive(Debug, Clone)]
pub struct EncodedLevel {
    pub width: u32,
    pub height: u32,
    pub bytes: Arc<Vec<u8>>,
    pub mime: String,
}

/// The pyramid of one image: level 0 is the image as given (its bytes untouched), then the LL
/// band of each Haar step, encoded, down to 1x1.
///
/// Memory: level 0 is decoded row by row into the levels' accumulation ([`haar::RowPyramid`]),
/// so what is held is the coarser levels in 8 bits (a third of level 0's RGBA bytes) plus, for
/// formats decoded whole (JPEG, WebP, interlaced PNG), the decoded image in its own colour type.
pub fn build_pyramid(
    image: &crate::scene::Image,
    format: TextureFormat,
    jpeg_quality: u8,
) -> Result<Vec<EncodedLevel>, codec::CodecError> {
    let mut rows = codec::Rows::open(&image.bytes)?;
    let (w, h, color) = (rows.width(), rows.height(), rows.color());
    let mut pyramid = haar::RowPyramid::new(w, h);
    let mut rgba = vec![0u8; w as usize * 4];
    // KTX2 re-encodes level 0 too (a tile cannot mix it with PNG/JPEG levels it does not
    // require), so the rows are kept for it.
    let ktx2 = format == TextureFormat::Ktx2;
    let mut level0 = Vec::with_capacity(if ktx2 { w as usize * h as usize * 4 } else { 0 });
    while let Some(row) = rows.next_row()? {
        codec::row_to_rgba8(color, row, &mut rgba);
        pyramid.push_row(&rgba);
        if ktx2 {
            level0.extend_from_slice(&rgba);
        }
    }
    drop(rows);
    let (bytes, mime) = match ktx2 {
        true => {
            let (b, m) = codec::encode_rgba(w, h, level0, format, "", jpeg_quality)?;
            (Arc::new(b), m.to_string())
        }
        false => (image.bytes.clone(), image.mime_type.clone()),
    };
    let mut out = vec![EncodedLevel {
        width: w,
        height: h,
        bytes,
        mime,
    }];
    for (width, height, px) in pyramid.finish() {
        let (bytes, mime) =
            codec::encode_rgba(width, height, px, format, &image.mime_type, jpeg_quality)?;
        out.push(EncodedLevel {
            width,
            height,
            bytes: Arc::new(bytes),
            mime: mime.into(),
        });
    }
    Ok(out)
}

/// Bytes written into tiles at one pyramid level.
#[derive(Debug, Clone, Default, Serialize)]
pub struct LevelWritten {
    pub level: usize,
    /// Images at this level referenced by tiles (embedded or external), over all tiles.
    pub embeddings: u64,
    /// Bytes written: every embedded copy, each shared file once.
    pub bytes: u64,
}

/// One pyramid level summed over the images whose pyramid was built.
#[derive(Debug, Clone, Default, Serialize)]
pub struct LevelTotal {
    pub level: usize,
    pub images: usize,
    pub texels: u64,
    pub bytes: u64,
}

/// One image, in the report.
#[derive(Debug, Clone, Serialize)]
pub struct ImageReport {
    pub image: u32,
    pub name: Option<String>,
    pub class: classify::TextureClass,
    pub width: u32,
    pub height: u32,
    /// Bytes of level 0 (after cropping).
    pub bytes: u64,
    /// (width, height, bytes) of each built level, level 0 first; empty when no tile needed a
    /// coarser level.
    pub levels: Vec<(u32, u32, u64)>,
}

/// What `report.json` says about textures.
#[derive(Debug, Clone, Serialize)]
pub struct TextureReport {
    pub options: TextureOptions,
    #[serde(flatten)]
    pub prepared: Prepared,
    /// Encoded bytes of the distinct images still bound after merging and cropping.
    pub stored_bytes: u64,
    /// Images whose pixels could not be decoded (always written at level 0).
    pub undecodable: usize,
    /// Pyramid levels summed over the images whose pyramid was built.
    pub pyramid_levels: Vec<LevelTotal>,
    /// Image bytes written (embedded in tiles or shared files), per level.
    pub written_per_level: Vec<LevelWritten>,
    pub written_bytes: u64,
    /// Shared texture files under `textures/` (0 when embedded).
    pub external_files: usize,
    /// Per-tile atlases: how many, images packed, bytes before and after.
    pub atlas: atlas::AtlasReport,
    pub images: Vec<ImageReport>,
}

/// Per-image pyramids, built lazily and shared by all tiles, and the level choice per tile.
pub struct TextureLevels<'a> {
    scene: &'a Scene,
    opts: TextureOptions,
    /// Level sizes per image (from the header), `None` if unreadable.
    sizes: Vec<Option<Vec<(u32, u32)>>>,
    pyramids: Vec<OnceLock<Option<Vec<EncodedLevel>>>>,
    written: Mutex<BTreeMap<usize, LevelWritten>>,
    /// Where shared files go; `None`: images are embedded.
    external: Option<external::ExternalTextures>,
    /// Per image: classified *repeated* (never packed into an atlas); empty without `atlas`.
    repeated: Vec<bool>,
    atlas_tally: Mutex<atlas::AtlasReport>,
}

/// The level chosen for each image of one tile.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TileTextures(pub BTreeMap<ImageId, usize>);

impl<'a> TextureLevels<'a> {
    /// `uses`: the classification [`prepare`] made (`Prepared::uses`), which tells the atlas
    /// which images repeat (classifying again would read all the geometry once more).
    pub fn new(
        scene: &'a Scene,
        opts: &TextureOptions,
        uses: &[classify::ImageUse],
    ) -> TextureLevels<'a> {
        let bound = classify::bound_images(scene);
        let sizes = (0..scene.images.len())
            .map(|i| {
                bound.binary_search(&ImageId(i as u32)).ok()?;
                let (w, h) = codec::dimensions(&scene.images[i].bytes).ok()?;
                Some(haar::level_sizes(w, h))
            })
            .collect();
        TextureLevels {
            scene,
            opts: opts.clone(),
            sizes,
            pyramids: (0..scene.images.len()).map(|_| OnceLock::new()).collect(),
            written: Mutex::new(BTreeMap::new()),
            external: None,
            repeated: match opts.atlas {
                true => uses
                    .iter()
                    .map(|u| u.class == classify::TextureClass::Repeated)
                    .collect(),
                false => Vec::new(),
            },
            atlas_tally: Mutex::new(atlas::AtlasReport::default()),
        }
    }

    /// Shares image levels as files under `<tileset_dir>/textures/`, unless the options embed.
    pub fn shared_in(mut self, tileset_dir: &std::path::Path) -> TextureLevels<'a> {
        if !self.opts.embed {
            self.external = Some(external::ExternalTextures::new(tileset_dir));
        }
        self
    }

    /// The level of each image a tile samples, for its geometric error (0 for leaves).
    pub fn for_tile(&self, content: &TileContent, geometric_error_m: f64) -> TileTextures {
        let mut areas: BTreeMap<ImageId, (f64, f64)> = BTreeMap::new();
        for p in &content.primitives {
            let Some(t) = p
                .material
                .and_then(|m| self.scene.materials[m.index()].base_color_texture.as_ref())
            else {
                continue;
            };
            let (w, u) = lod::areas(p);
            let a = areas.entry(t.image).or_default();
            a.0 += w;
            a.1 += u;
        }
        TileTextures(
            areas
                .into_iter()
                .map(|(id, (w, u))| {
                    let level = match (&self.sizes[id.index()], self.opts.lod) {
                        (Some(sizes), true) => lod::choose_level(sizes, w, u, geometric_error_m),
                        _ => 0,
                    };
                    (id, level)
                })
                .collect(),
        )
    }

    /// The pyramid of `id`, built on first use; `None` if the image cannot be decoded.
    fn pyramid(&self, id: ImageId) -> Option<&Vec<EncodedLevel>> {
        self.pyramids[id.index()]
            .get_or_init(|| {
                build_pyramid(
                    &self.scene.images[id.index()],
                    self.opts.format,
                    self.opts.jpeg_quality,
                )
                .ok()
            })
            .as_ref()
    }

    /// The encoded bytes and MIME type of `id` at `level` (level 0: the scene's bytes as they
    /// are), or of a finer level when that one is smaller; counted as written into one tile.
    pub fn fetch(&self, id: ImageId, level: usize) -> (Arc<Vec<u8>>, String) {
        let (bytes, mime, level) = self.level_bytes(id, level);
        self.tally(level, bytes.len());
        (bytes, mime)
    }

    /// The bytes a tile fetches for `id` at `level` (what [`Self::fetch`] gives; nothing counted).
    pub fn shipped_bytes(&self, id: ImageId, level: usize) -> usize {
        self.level_bytes(id, level).0.len()
    }

    /// How one tile carries `id` at `level` (as [`Self::fetch`]): a shared file written on first
    /// use, or embedded bytes.
    pub fn tile_image(&self, id: ImageId, level: usize) -> Result<TileImage, external::StoreError> {
        let (bytes, mime, level) = self.level_bytes(id, level);
        let ext = match &self.external {
            Some(ext) if bytes.len() >= self.opts.embed_below_bytes => ext,
            _ => {
                self.tally(level, bytes.len());
                return Ok(TileImage::Embedded { bytes, mime });
            }
        };
        let (uri, _) = ext.store(&bytes, &mime, level)?;
        self.tally(level, 0);
        Ok(TileImage::External { uri, mime })
    }

    /// How one tile carries `id`: the atlas that packed it, or its level as [`Self::tile_image`].
    pub fn image_for(
        &self,
        id: ImageId,
        chosen: &TileTextures,
        atlas: Option<&atlas::TileAtlas>,
    ) -> Result<TileImage, external::StoreError> {
        match atlas.and_then(|a| a.image(id)) {
            Some(im) => Ok(im.clone()),
            None => self.tile_image(id, chosen.0.get(&id).copied().unwrap_or(0)),
        }
    }

    /// One more reference at `level`, of `embedded_bytes` in the tile.
    fn tally(&self, level: usize, embedded_bytes: usize) {
        let mut w = self.written.lock().expect("tally");
        let e = w.entry(level).or_insert_with(|| LevelWritten {
            level,
            ..Default::default()
        });
        e.embeddings += 1;
        e.bytes += embedded_bytes as u64;
    }

    /// The bytes, MIME type and level actually shipped for `id` at `level`.
    fn level_bytes(&self, id: ImageId, level: usize) -> (Arc<Vec<u8>>, String, usize) {
        let im = &self.scene.images[id.index()];
        let (bytes, mime, level) = match level {
            0 if self.opts.format != TextureFormat::Ktx2 => {
                (im.bytes.clone(), im.mime_type.clone(), 0)
            }
            l => match self.pyramid(id) {
                Some(p) => {
                    // A finer level that encodes smaller is shipped instead (more detail for
                    // fewer bytes: averaging flat-colour art adds colours PNG compresses worse).
                    let l = (0..=l.min(p.len() - 1))
                        .rev()
                        .min_by_key(|&k| p[k].bytes.len())
                        .expect("level 0 exists");
                    (p[l].bytes.clone(), p[l].mime.clone(), l)
                }
                None => (im.bytes.clone(), im.mime_type.clone(), 0),
            },
        };
        (bytes, mime, level)
    }

    /// The report, once every tile is written.
    pub fn report(self, prepared: Prepared) -> TextureReport {
        let bound = classify::bound_images(self.scene);
        let mut totals: Vec<LevelTotal> = Vec::new();
        let mut images = Vec::new();
        let mut undecodable = 0;
        for &id in &bound {
            let im = &self.scene.images[id.index()];
            let (w, h) = self.sizes[id.index()].as_ref().map_or((0, 0), |s| s[0]);
            let built = self.pyramids[id.index()].get();
            if self.sizes[id.index()].is_none() || matches!(built, Some(None)) {
                undecodable += 1;
            }
            let levels: Vec<(u32, u32, u64)> = built
                .and_then(|p| p.as_ref())
                .map(|p| {
                    p.iter()
                        .map(|l| (l.width, l.height, l.bytes.len() as u64))
                        .collect()
                })
                .unwrap_or_default();
            for (l, &(lw, lh, b)) in levels.iter().enumerate() {
                if totals.len() <= l {
                    totals.push(LevelTotal {
                        level: l,
                        ..Default::default()
                    });
                }
                totals[l].images += 1;
                totals[l].texels += lw as u64 * lh as u64;
                totals[l].bytes += b;
            }
            images.push(ImageReport {
                image: id.0,
                name: im.name.clone(),
                class: prepared.uses[id.index()].class,
                width: w,
                height: h,
                bytes: im.bytes.len() as u64,
                levels,
            });
        }
        let mut written = self.written.into_inner().expect("tally");
        for (level, bytes) in self
            .external
            .as_ref()
            .map(|e| e.bytes_per_level())
            .unwrap_or_default()
        {
            written
                .entry(level)
                .or_insert_with(|| LevelWritten {
                    level,
                    ..Default::default()
                })
                .bytes += bytes;
        }
        let written_per_level: Vec<LevelWritten> = written.into_values().collect();
        TextureReport {
            external_files: self.external.as_ref().map_or(0, |e| e.file_count()),
            atlas: self.atlas_tally.into_inner().expect("atlas tally"),
            options: self.opts,
            stored_bytes: images.iter().map(|i| i.bytes).sum(),
            undecodable,
            pyramid_levels: totals,
            written_bytes: written_per_level.iter().map(|l| l.bytes).sum(),
            written_per_level,
            images,
            prepared,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::classify::tests::{quad, scene_of, textured_material};
    use super::*;

    fn facade_png(w: u32, h: u32) -> Vec<u8> {
        // Smooth bands plus a grid of "windows": structure in both directions, like a facade.
        let px: Vec<u8> = (0..h)
            .flat_map(|y| {
                (0..w).flat_map(move |x| {
                    let win = (x % 16 < 8) && (y % 20 < 12);
                    let v = if win {
                        40
                    } else {
                        150 + ((x + 2 * y) % 60) as u8
                    };
                    [v, v / 2 + 20, 255 - v, 255]
                })
            })
            .collect();
        codec::encode_rgba(w, h, px, TextureFormat::Png, "", 0)
            .unwrap()
            .0
    }

    #[test]
    fn pyramid_levels_agree_with_an_area_downsample() {
        let image = classify::tests::image(facade_png(256, 192));
        let p = build_pyramid(&image, TextureFormat::Png, 85).unwrap();
        assert_eq!(p.len(), haar::level_sizes(256, 192).len());
        assert!(Arc::ptr_eq(&p[0].bytes, &image.bytes), "level 0 untouched");
        let orig = codec::decode(&image.bytes).unwrap().to_rgba8();
        for (l, lv) in p.iter().enumerate().skip(1).take(5) {
            let got = codec::decode(&lv.bytes).unwrap().to_rgba8();
            assert_eq!(got.dimensions(), (256 >> l, 192 >> l));
            // image's own area-averaging downsample (an independent implementation).
            let reference = image::imageops::thumbnail(&orig, 256 >> l, 192 >> l);
            let db = haar::psnr(got.as_raw(), reference.as_raw());
            assert!(db > 45.0, "level {l}: PSNR {db:.1} dB");
            assert!(lv.bytes.len() < p[l - 1].bytes.len() || lv.bytes.len() < 200);
        }
    }

    #[test]
    fn tiles_get_levels_by_error_and_bytes_are_counted() {
        // A 1 m x 1 m quad (the unit quad of the helper) mapped to a whole 256 x 192 image:
        // texel 1/256 m across.
        let mut s = scene_of(
            vec![vec![quad(0, [0.0, 0.0], [1.0, 1.0])]],
            vec![textured_material(0)],
            1,
        );
        s.images[0].bytes = Arc::new(facade_png(256, 192));
        let content = TileContent::gather(
            &s,
            &[crate::partition::ContentItem {
                component: crate::scene::ComponentId(0),
                triangles: None,
            }],
            glam::DVec3::ZERO,
        );
        let uses = classify::classify(&s);
        let levels = TextureLevels::new(&s, &TextureOptions::default(), &uses);
        assert_eq!(levels.for_tile(&content, 0.0).0[&ImageId(0)], 0);
        // sqrt(1 / (256 * 192)) = 4.5 mm per texel at level 0, 9 mm at 1, 18 mm at 2.
        assert_eq!(levels.for_tile(&content, 0.01).0[&ImageId(0)], 1);
        assert_eq!(levels.for_tile(&content, 0.02).0[&ImageId(0)], 2);
        let (b0, _) = levels.fetch(ImageId(0), 0);
        let (b2, mime) = levels.fetch(ImageId(0), 2);
        assert_eq!(mime, "image/png");
        assert_eq!(codec::dimensions(&b2).unwrap(), (64, 48));
        let off = TextureLevels::new(
            &s,
            &TextureOptions {
                lod: false,
                ..Default::default()
            },
            &uses,
        );
        assert_eq!(off.for_tile(&content, 0.02).0[&ImageId(0)], 0);
        let prepared = prepare(
            &mut s.clone(),
            &TextureOptions::default(),
            &admit::ImageLimits::under_budget(None),
        )
        .unwrap();
        let r = levels.report(prepared);
        assert_eq!(r.written_bytes, (b0.len() + b2.len()) as u64);
        assert_eq!(r.written_per_level.len(), 2);
        assert_eq!(r.pyramid_levels[2].texels, 64 * 48);
        assert_eq!(r.prepared.classes.standalone, 1);
    }

    /// The pyramid as it was built before rows were streamed: the whole image decoded to RGBA8,
    /// level 1 from it, then each level from the previous one in f32.
    fn whole_image_pyramid(bytes: &[u8], format: TextureFormat, mime: &str) -> Vec<Vec<u8>> {
        let img = codec::decode(bytes).unwrap().to_rgba8();
        let (w, h) = img.dimensions();
        let mut out = Vec::new();
        if w <= 1 && h <= 1 {
            return out;
        }
        let mut level = haar::next_level_rgba8(w, h, img.as_raw());
        loop {
            let enc = codec::encode_rgba(
                level.width,
                level.height,
                level.to_rgba8(),
                format,
                mime,
                85,
            );
            out.push(enc.unwrap().0);
            if level.width <= 1 && level.height <= 1 {
                return out;
            }
            level = haar::next_level(&level);
        }
    }

    #[test]
    fn streamed_pyramid_encodes_as_the_whole_image_path() {
        use codec::tests::{interlaced_png, jpeg_of, noise, png_cases};
        for (w, h) in [(1, 1), (5, 1), (37, 22), (64, 48), (45, 27)] {
            let mut cases: Vec<(String, Vec<u8>, &str)> = png_cases(w, h)
                .into_iter()
                .map(|(n, b)| (n, b, "image/png"))
                .collect();
            let rgba = noise((w * h * 4) as usize, 3);
            cases.push((
                "interlaced".into(),
                interlaced_png(w, h, &rgba),
                "image/png",
            ));
            cases.push(("jpeg".into(), jpeg_of(w, h, false), "image/jpeg"));
            cases.push(("grey jpeg".into(), jpeg_of(w, h, true), "image/jpeg"));
            cases.push(("facade".into(), facade_png(w, h), "image/png"));
            for (name, bytes, mime) in cases {
                let mut image = classify::tests::image(bytes.clone());
                image.mime_type = mime.into();
                for format in [TextureFormat::Auto, TextureFormat::Png, TextureFormat::Jpeg] {
                    let p = build_pyramid(&image, format, 85).unwrap();
                    let got: Vec<Vec<u8>> = p[1..].iter().map(|l| l.bytes.to_vec()).collect();
                    assert_eq!(
                        got,
                        whole_image_pyramid(&bytes, format, mime),
                        "{name} {w}x{h} {format:?}"
                    );
                }
            }
        }
        let broken = facade_png(40, 30);
        let image = classify::tests::image(broken[..broken.len() / 2].to_vec());
        assert!(build_pyramid(&image, TextureFormat::Auto, 85).is_err());
    }
}
