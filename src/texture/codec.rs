//! Decoding and encoding of texture images with the `image` crate (paper III.E's output side):
//! the formats glTF core allows, PNG (lossless) and JPEG (with a quality setting), and KTX2
//! through [`super::basisu`].
//!
//! WebP is decodable but not written: glTF core does not allow `image/webp` (it needs
//! `EXT_texture_webp` with a fallback image), and the `image` crate's WebP encoder is lossless
//! only, so it would not beat PNG by enough to pay for the extension.
//!
//! Memory: [`Rows`] hands out the decoded pixels one row at a time, so the texture passes never
//! hold a whole decoded image. Non-interlaced PNG is decoded row by row with the `png` crate
//! itself, set up as the `image` crate sets it up (so the same samples); other images (JPEG,
//! WebP, interlaced PNG) are decoded whole by `image`, as their decoders have no row interface,
//! and read out by rows ([`row_to_rgba8`] then converts a row as `DynamicImage::to_rgba8` would,
//! without the image-sized RGBA copy).

use image::{ColorType, DynamicImage, ImageBuffer, ImageFormat};
use std::io::Cursor;

/// How re-encoded images (coarser levels, crops) are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TextureFormat {
    /// The source's family: PNG sources stay PNG (lossless), JPEG sources stay JPEG (at the
    /// JPEG quality); re-encoding a JPEG photograph as PNG makes it several times larger.
    #[default]
    Auto,
    /// PNG (lossless) for everything.
    Png,
    /// JPEG for everything without transparency (images with alpha < 255 stay PNG).
    Jpeg,
    /// KTX2 with Basis Universal for everything, level 0 included (glTF `KHR_texture_basisu`):
    /// textures the GPU keeps compressed ([`super::basisu`]).
    Ktx2,
}

/// Why an image could not be decoded or encoded.
#[derive(Debug, thiserror::Error)]
pub enum CodecError {
    #[error(transparent)]
    Image(#[from] image::ImageError),
    #[error(transparent)]
    Io(#[from] std::io::Error),
    #[error("PNG")]
    Png(#[from] png::DecodingError),
    /// Data that contradicts itself (rows past the header's height, a pixel buffer of the wrong
    /// size).
    #[error("{0}")]
    Inconsistent(&'static str),
    /// The decoder panicked on this file (a bug in it, caught by [`guarded`]).
    #[error("the image decoder failed on this file ({0})")]
    DecoderPanicked(String),
    /// The Basis Universal encoder (KTX2) refused the image.
    #[error("the Basis Universal encoder failed on a {width_px}x{height_px} image")]
    Basisu { width_px: u32, height_px: u32 },
}

/// Default JPEG quality (libjpeg scale 1-100).
pub const DEFAULT_JPEG_QUALITY: u8 = 85;

/// Decodes any supported image without the `image` crate's default 512 MiB allocation limit
/// (a 16k x 16k RGBA texture is 1 GiB of pixels).
pub fn decode(bytes: &[u8]) -> Result<DynamicImage, CodecError> {
    guarded(|| {
        let mut r = image::ImageReader::new(Cursor::new(bytes)).with_guessed_format()?;
        r.no_limits();
        Ok(r.decode()?)
    })
}

/// Runs a decoder call, a panic inside it becoming [`CodecError::DecoderPanicked`]: the image
/// crates are not panic-free on malformed files (png 0.18.1 slices past a palette whose tRNS
/// chunk says more than it holds; found by the image fuzz target), and one bad texture is one
/// warning, not the end of the run.
fn guarded<T>(f: impl FnOnce() -> Result<T, CodecError>) -> Result<T, CodecError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).unwrap_or_else(|payload| {
        Err(CodecError::DecoderPanicked(crate::error::panic_message(
            payload.as_ref(),
        )))
    })
}

/// Decoded pixels of an image, read one row at a time, top to bottom, in the `image` crate's
/// layout for [`Rows::color`] (native-endian samples): the bytes of row `y` are the bytes of row
/// `y` of `decode(bytes)?.as_bytes()`.
pub struct Rows<'a> {
    width: u32,
    height: u32,
    color: ColorType,
    /// Rows handed out so far.
    next: u32,
    source: RowSource<'a>,
}

enum RowSource<'a> {
    /// Row by row: only the decoder's state and one row are held.
    Png {
        reader: Box<png::Reader<Cursor<&'a [u8]>>>,
        row: Vec<u8>,
    },
    /// Decoded whole by `image` (formats without a row interface).
    Whole(DynamicImage),
}

const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";

impl<'a> Rows<'a> {
    /// Starts decoding `bytes` (any format [`decode`] reads).
    pub fn open(bytes: &'a [u8]) -> Result<Rows<'a>, CodecError> {
        if bytes.starts_with(PNG_SIGNATURE) {
            if let Some(rows) = guarded(|| Self::open_png(bytes))? {
                return Ok(rows);
            }
        }
        let img = match decode(bytes)? {
            // Colour types of a later `image` version: read as RGBA8 (no PNG gives them).
            i @ (DynamicImage::ImageLuma8(_)
            | DynamicImage::ImageLumaA8(_)
            | DynamicImage::ImageRgb8(_)
            | DynamicImage::ImageRgba8(_)
            | DynamicImage::ImageLuma16(_)
            | DynamicImage::ImageLumaA16(_)
            | DynamicImage::ImageRgb16(_)
            | DynamicImage::ImageRgba16(_)
            | DynamicImage::ImageRgb32F(_)
            | DynamicImage::ImageRgba32F(_)) => i,
            other => DynamicImage::ImageRgba8(other.to_rgba8()),
        };
        Ok(Rows {
            width: img.width(),
            height: img.height(),
            color: img.color(),
            next: 0,
            source: RowSource::Whole(img),
        })
    }

    /// A row reader for a non-interlaced PNG, `None` for the PNGs left to `image` (interlaced:
    /// rows arrive in passes; an animation whose first frame is smaller than the image).
    fn open_png(bytes: &'a [u8]) -> Result<Option<Rows<'a>>, CodecError> {
        // As `image::codecs::png::PngDecoder::with_limits` with no limits: the same checks,
        // errors and output samples.
        let mut decoder =
            png::Decoder::new_with_limits(Cursor::new(bytes), png::Limits { bytes: usize::MAX });
        decoder.set_ignore_text_chunk(false);
        decoder.read_header_info()?;
        decoder.set_transformations(png::Transformations::EXPAND);
        let reader = decoder.read_info()?;
        let info = reader.info();
        let (width, height) = (info.width, info.height);
        let subframe_differs = info
            .frame_control
            .is_some_and(|f| (f.width, f.height) != (width, height));
        if info.interlaced || subframe_differs {
            return Ok(None);
        }
        use png::BitDepth::{Eight, Sixteen};
        let color = match reader.output_color_type() {
            (png::ColorType::Grayscale, Eight) => ColorType::L8,
            (png::ColorType::Grayscale, Sixteen) => ColorType::L16,
            (png::ColorType::GrayscaleAlpha, Eight) => ColorType::La8,
            (png::ColorType::GrayscaleAlpha, Sixteen) => ColorType::La16,
            (png::ColorType::Rgb, Eight) => ColorType::Rgb8,
            (png::ColorType::Rgb, Sixteen) => ColorType::Rgb16,
            (png::ColorType::Rgba, Eight) => ColorType::Rgba8,
            (png::ColorType::Rgba, Sixteen) => ColorType::Rgba16,
            // Whatever `image` makes of it (an error today).
            _ => return Ok(None),
        };
        let line = color.bytes_per_pixel() as usize * width as usize;
        Ok(Some(Rows {
            width,
            height,
            color,
            next: 0,
            source: RowSource::Png {
                reader: Box::new(reader),
                row: vec![0; line],
            },
        }))
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    pub fn color(&self) -> ColorType {
        self.color
    }

    /// The next row, `None` after the last one. An image is decoded without error only if every
    /// row and then `None` came back.
    pub fn next_row(&mut self) -> Result<Option<&[u8]>, CodecError> {
        let line = self.color.bytes_per_pixel() as usize * self.width as usize;
        let y = self.next as usize;
        match &mut self.source {
            RowSource::Whole(img) => {
                if self.next == self.height {
                    return Ok(None);
                }
                self.next += 1;
                Ok(Some(&img.as_bytes()[y * line..(y + 1) * line]))
            }
            RowSource::Png { reader, row } => {
                let got = guarded(|| Ok(reader.read_row(row)?))?;
                if self.next == self.height {
                    // Past the last row the reader consumes the rest of the image data, as
                    // `next_frame` does (its errors are the image's).
                    return match got {
                        None => Ok(None),
                        Some(_) => Err(CodecError::Inconsistent(
                            "more PNG rows than the header says",
                        )),
                    };
                }
                if got.is_none() {
                    return Err(CodecError::Inconsistent("PNG image data ends early"));
                }
                self.next += 1;
                if self.color.bytes_per_pixel() / self.color.channel_count() == 2 {
                    // PNG samples are big-endian; `image` gives them native-endian.
                    for c in row.chunks_exact_mut(2) {
                        let v = u16::from_be_bytes([c[0], c[1]]);
                        c.copy_from_slice(&v.to_ne_bytes());
                    }
                }
                Ok(Some(&row[..line]))
            }
        }
    }
}

/// Converts pixels of one row (`color` layout, as [`Rows::next_row`] gives them) to 8-bit RGBA
/// in `out` (4 bytes a pixel), the values `DynamicImage::to_rgba8` gives.
pub fn row_to_rgba8(color: ColorType, row: &[u8], out: &mut [u8]) {
    let n = row.len() / color.bytes_per_pixel() as usize;
    let out = &mut out[..n * 4];
    match color {
        ColorType::Rgba8 => out.copy_from_slice(row),
        ColorType::Rgb8 => {
            for (o, p) in out.chunks_exact_mut(4).zip(row.chunks_exact(3)) {
                o.copy_from_slice(&[p[0], p[1], p[2], 255]);
            }
        }
        ColorType::La8 => {
            for (o, p) in out.chunks_exact_mut(4).zip(row.chunks_exact(2)) {
                o.copy_from_slice(&[p[0], p[0], p[0], p[1]]);
            }
        }
        ColorType::L8 => {
            for (o, &v) in out.chunks_exact_mut(4).zip(row) {
                o.copy_from_slice(&[v, v, v, 255]);
            }
        }
        // Deeper samples: `image`'s own conversion of a one-row image (rounding included).
        _ => out.copy_from_slice(one_row_image(color, n as u32, row).to_rgba8().as_raw()),
    }
}

/// A `width x 1` image of `color` from native-endian bytes ([`Rows`] only gives the colour types
/// listed here).
fn one_row_image(color: ColorType, width: u32, row: &[u8]) -> DynamicImage {
    fn samples<T, const N: usize>(row: &[u8], f: fn([u8; N]) -> T) -> Vec<T> {
        row.chunks_exact(N)
            .map(|c| f(c.try_into().expect("N bytes")))
            .collect()
    }
    let u16s = || samples(row, u16::from_ne_bytes);
    let f32s = || samples(row, f32::from_ne_bytes);
    let size = "row length";
    match color {
        ColorType::L8 => {
            DynamicImage::ImageLuma8(ImageBuffer::from_raw(width, 1, row.to_vec()).expect(size))
        }
        ColorType::La8 => {
            DynamicImage::ImageLumaA8(ImageBuffer::from_raw(width, 1, row.to_vec()).expect(size))
        }
        ColorType::Rgb8 => {
            DynamicImage::ImageRgb8(ImageBuffer::from_raw(width, 1, row.to_vec()).expect(size))
        }
        ColorType::Rgba8 => {
            DynamicImage::ImageRgba8(ImageBuffer::from_raw(width, 1, row.to_vec()).expect(size))
        }
        ColorType::L16 => {
            DynamicImage::ImageLuma16(ImageBuffer::from_raw(width, 1, u16s()).expect(size))
        }
        ColorType::La16 => {
            DynamicImage::ImageLumaA16(ImageBuffer::from_raw(width, 1, u16s()).expect(size))
        }
        ColorType::Rgb16 => {
            DynamicImage::ImageRgb16(ImageBuffer::from_raw(width, 1, u16s()).expect(size))
        }
        ColorType::Rgba16 => {
            DynamicImage::ImageRgba16(ImageBuffer::from_raw(width, 1, u16s()).expect(size))
        }
        ColorType::Rgb32F => {
            DynamicImage::ImageRgb32F(ImageBuffer::from_raw(width, 1, f32s()).expect(size))
        }
        ColorType::Rgba32F => {
            DynamicImage::ImageRgba32F(ImageBuffer::from_raw(width, 1, f32s()).expect(size))
        }
        other => unreachable!("Rows gives no {other:?}"),
    }
}

/// Width and height from the header only (no pixel decoding).
pub fn dimensions(bytes: &[u8]) -> Result<(u32, u32), CodecError> {
    guarded(|| {
        Ok(image::ImageReader::new(Cursor::new(bytes))
            .with_guessed_format()?
            .into_dimensions()?)
    })
}

/// Encodes 8-bit RGBA; returns the bytes and their MIME type. `source_mime` picks the family
/// for [`TextureFormat::Auto`].
pub fn encode_rgba(
    width: u32,
    height: u32,
    rgba: Vec<u8>,
    format: TextureFormat,
    source_mime: &str,
    jpeg_quality: u8,
) -> Result<(Vec<u8>, &'static str), CodecError> {
    if rgba.len() != width as usize * height as usize * 4 {
        return Err(CodecError::Inconsistent("pixel buffer size"));
    }
    if format == TextureFormat::Ktx2 {
        let ktx2 = super::basisu::encode_ktx2(width, height, rgba, super::basisu::KTX2_CODEC)?;
        return Ok((ktx2, "image/ktx2"));
    }
    let opaque = rgba.chunks_exact(4).all(|p| p[3] == 255);
    let jpeg = opaque
        && match format {
            TextureFormat::Auto => source_mime == "image/jpeg",
            TextureFormat::Png | TextureFormat::Ktx2 => false,
            TextureFormat::Jpeg => true,
        };
    let mut out = Vec::new();
    // Opaque images drop their alpha channel (a quarter fewer bytes to compress), in place: no
    // second copy of the level.
    let img = if opaque {
        let rgb = rgba_to_rgb_in_place(rgba);
        DynamicImage::ImageRgb8(
            image::RgbImage::from_raw(width, height, rgb)
                .ok_or(CodecError::Inconsistent("pixel buffer size"))?,
        )
    } else {
        DynamicImage::ImageRgba8(
            image::RgbaImage::from_raw(width, height, rgba)
                .ok_or(CodecError::Inconsistent("pixel buffer size"))?,
        )
    };
    if jpeg {
        let DynamicImage::ImageRgb8(rgb) = &img else {
            unreachable!("JPEG only for opaque images")
        };
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, jpeg_quality.clamp(1, 100))
            .encode_image(rgb)?;
        Ok((out, "image/jpeg"))
    } else {
        img.write_to(&mut Cursor::new(&mut out), ImageFormat::Png)?;
        Ok((out, "image/png"))
    }
}

/// RGBA to RGB (alpha dropped, as `to_rgb8` does), reusing the buffer.
fn rgba_to_rgb_in_place(mut px: Vec<u8>) -> Vec<u8> {
    let n = px.len() / 4;
    for i in 0..n {
        px.copy_within(i * 4..i * 4 + 3, i * 3);
    }
    px.truncate(n * 3);
    px.shrink_to_fit();
    px
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Deterministic pseudo-random bytes.
    pub fn noise(n: usize, seed: u64) -> Vec<u8> {
        let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
        (0..n)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 56) as u8
            })
            .collect()
    }

    /// A PNG written by the `png` crate from raw (filtered-free, big-endian) samples.
    pub fn png_of(
        w: u32,
        h: u32,
        color: png::ColorType,
        depth: png::BitDepth,
        data: &[u8],
        palette: Option<Vec<u8>>,
        trns: Option<Vec<u8>>,
    ) -> Vec<u8> {
        let mut out = Vec::new();
        let mut e = png::Encoder::new(&mut out, w, h);
        e.set_color(color);
        e.set_depth(depth);
        if let Some(p) = palette {
            e.set_palette(p);
        }
        if let Some(t) = trns {
            e.set_trns(t);
        }
        let mut wr = e.write_header().unwrap();
        wr.write_image_data(data).unwrap();
        wr.finish().unwrap();
        out
    }

    /// Bytes of the raw image data of a `w x h` PNG of `channels` samples of `bits`.
    pub fn raw_len(w: u32, h: u32, channels: u32, bits: u32) -> usize {
        ((w * channels * bits).div_ceil(8) * h) as usize
    }

    /// An Adam7-interlaced RGBA8 PNG, written by hand (the `png` crate writes no interlacing).
    pub fn interlaced_png(w: u32, h: u32, rgba: &[u8]) -> Vec<u8> {
        use std::io::Write;
        fn crc32(b: &[u8]) -> u32 {
            let mut c = !0u32;
            for &x in b {
                c ^= x as u32;
                for _ in 0..8 {
                    c = if c & 1 != 0 {
                        0xEDB8_8320 ^ (c >> 1)
                    } else {
                        c >> 1
                    };
                }
            }
            !c
        }
        fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
            out.extend((data.len() as u32).to_be_bytes());
            let body: Vec<u8> = kind.iter().chain(data).copied().collect();
            out.extend(&body);
            out.extend(crc32(&body).to_be_bytes());
        }
        let mut raw = Vec::new();
        let passes = [
            (0, 0, 8, 8),
            (4, 0, 8, 8),
            (0, 4, 4, 8),
            (2, 0, 4, 4),
            (0, 2, 2, 4),
            (1, 0, 2, 2),
            (0, 1, 1, 2),
        ];
        for (x0, y0, dx, dy) in passes {
            if x0 >= w {
                continue;
            }
            for y in (y0..h).step_by(dy) {
                raw.push(0); // filter: none
                for x in (x0..w).step_by(dx) {
                    let i = ((y * w + x) * 4) as usize;
                    raw.extend(&rgba[i..i + 4]);
                }
            }
        }
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        z.write_all(&raw).unwrap();
        let mut out = PNG_SIGNATURE.to_vec();
        let mut ihdr = Vec::new();
        ihdr.extend(w.to_be_bytes());
        ihdr.extend(h.to_be_bytes());
        ihdr.extend([8, 6, 0, 0, 1]); // 8 bits, RGBA, deflate, adaptive filters, Adam7
        chunk(&mut out, b"IHDR", &ihdr);
        chunk(&mut out, b"IDAT", &z.finish().unwrap());
        chunk(&mut out, b"IEND", &[]);
        out
    }

    pub fn jpeg_of(w: u32, h: u32, grey: bool) -> Vec<u8> {
        let px = noise((w * h * 3) as usize, 9);
        let img = if grey {
            DynamicImage::ImageLuma8(
                ImageBuffer::from_raw(w, h, px[..(w * h) as usize].to_vec()).unwrap(),
            )
        } else {
            DynamicImage::ImageRgb8(ImageBuffer::from_raw(w, h, px).unwrap())
        };
        let mut out = Vec::new();
        img.write_to(&mut Cursor::new(&mut out), ImageFormat::Jpeg)
            .unwrap();
        out
    }

    /// Every row and the end, or the first error.
    fn read_all(bytes: &[u8]) -> Result<(Rows<'_>, Vec<u8>), CodecError> {
        let mut rows = Rows::open(bytes)?;
        let mut all = Vec::new();
        while let Some(r) = rows.next_row()? {
            all.extend_from_slice(r);
        }
        Ok((rows, all))
    }

    /// PNGs of every colour type and depth (palettes and tRNS included), each `(name, bytes)`.
    pub fn png_cases(w: u32, h: u32) -> Vec<(String, Vec<u8>)> {
        use png::BitDepth::*;
        use png::ColorType::*;
        let mut out = Vec::new();
        for (color, channels) in [(Grayscale, 1), (GrayscaleAlpha, 2), (Rgb, 3), (Rgba, 4)] {
            for depth in [Eight, Sixteen] {
                let bits = depth as u32;
                let data = noise(
                    raw_len(w, h, channels, bits),
                    w as u64 * 7 + channels as u64,
                );
                out.push((
                    format!("{color:?} {bits}"),
                    png_of(w, h, color, depth, &data, None, None),
                ));
            }
        }
        for depth in [One, Two, Four] {
            let bits = depth as u32;
            let data = noise(raw_len(w, h, 1, bits), 5);
            out.push((
                format!("grey {bits}"),
                png_of(w, h, Grayscale, depth, &data, None, None),
            ));
            // Indices below 2^bits: a full palette of that size.
            let plte = noise(3 << bits, 6);
            out.push((
                format!("palette {bits}"),
                png_of(w, h, Indexed, depth, &data, Some(plte), None),
            ));
        }
        let data = noise(raw_len(w, h, 1, 8), 8);
        out.push((
            "palette 8 with tRNS".into(),
            png_of(
                w,
                h,
                Indexed,
                Eight,
                &data,
                Some(noise(768, 2)),
                Some(noise(100, 3)),
            ),
        ));
        let grey_key = vec![0, data[0]];
        out.push((
            "grey 8 with tRNS".into(),
            png_of(w, h, Grayscale, Eight, &data, None, Some(grey_key)),
        ));
        let rgb = noise(raw_len(w, h, 3, 8), 4);
        let rgb_key = vec![0, rgb[0], 0, rgb[1], 0, rgb[2]];
        out.push((
            "rgb 8 with tRNS".into(),
            png_of(w, h, Rgb, Eight, &rgb, None, Some(rgb_key)),
        ));
        let rgb16 = noise(raw_len(w, h, 3, 16), 4);
        let rgb16_key = rgb16[..6].to_vec();
        out.push((
            "rgb 16 with tRNS".into(),
            png_of(w, h, Rgb, Sixteen, &rgb16, None, Some(rgb16_key)),
        ));
        out
    }

    /// A palette PNG whose PLTE is not a multiple of 3 bytes made png 0.18.1 slice past it (found
    /// by the image fuzz target): an error naming the decoder's failure, not a panic.
    #[test]
    fn a_decoder_panic_is_an_error() {
        let bytes = std::fs::read(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("fuzz/corpus/image/crash-png-palette-trns.png"),
        )
        .unwrap();
        let rows = Rows::open(&bytes).and_then(|mut rows| {
            while rows.next_row()?.is_some() {}
            Ok(())
        });
        assert!(
            matches!(rows, Err(CodecError::DecoderPanicked(_))),
            "{rows:?}"
        );
        assert!(
            matches!(decode(&bytes), Err(CodecError::DecoderPanicked(_)))
                || decode(&bytes).is_err()
        );
    }

    #[test]
    fn rows_are_the_decoded_image_row_by_row() {
        for (w, h) in [(1, 1), (7, 5), (33, 17), (64, 3), (2, 9)] {
            let mut cases = png_cases(w, h);
            let rgba = noise((w * h * 4) as usize, 11);
            cases.push(("interlaced".into(), interlaced_png(w, h, &rgba)));
            cases.push(("jpeg".into(), jpeg_of(w, h, false)));
            cases.push(("grey jpeg".into(), jpeg_of(w, h, true)));
            for (name, bytes) in cases {
                let img = decode(&bytes).unwrap();
                let (rows, all) = read_all(&bytes).unwrap();
                let streamed = matches!(rows.source, RowSource::Png { .. });
                assert_eq!(
                    streamed,
                    !(name.contains("jpeg") || name == "interlaced"),
                    "{name}"
                );
                assert_eq!((rows.width(), rows.height()), (w, h), "{name}");
                assert_eq!(rows.color(), img.color(), "{name} {w}x{h}");
                assert_eq!(all, img.as_bytes(), "{name} {w}x{h}");
                if name == "interlaced" {
                    assert_eq!(all, rgba);
                }
                let line = rows.color().bytes_per_pixel() as usize * w as usize;
                let mut px = vec![0u8; w as usize * 4];
                let converted: Vec<u8> = all
                    .chunks_exact(line)
                    .flat_map(|r| {
                        row_to_rgba8(rows.color(), r, &mut px);
                        px.clone()
                    })
                    .collect();
                assert_eq!(converted, img.to_rgba8().into_raw(), "{name} {w}x{h}");
            }
        }
    }

    #[test]
    fn rows_fail_where_decoding_fails() {
        let mut cases = png_cases(20, 13);
        cases.push(("jpeg".into(), jpeg_of(20, 13, false)));
        for (name, bytes) in cases {
            for cut in [
                bytes.len() - 4,
                bytes.len() - 12,
                bytes.len() - 20,
                bytes.len() / 2,
            ] {
                let part = &bytes[..cut];
                assert_eq!(
                    read_all(part).is_ok(),
                    decode(part).is_ok(),
                    "{name} cut at {cut} of {}",
                    bytes.len()
                );
            }
            let mut bad = bytes.clone();
            let n = bad.len();
            bad[n - 30] ^= 0x55;
            assert_eq!(
                read_all(&bad).is_ok(),
                decode(&bad).is_ok(),
                "{name} corrupted"
            );
        }
        assert!(Rows::open(b"not an image").is_err());
    }

    #[test]
    fn rgb_in_place_is_to_rgb8() {
        let px = noise(4 * 35, 1);
        let img = image::RgbaImage::from_raw(7, 5, px.clone()).unwrap();
        assert_eq!(
            rgba_to_rgb_in_place(px),
            DynamicImage::ImageRgba8(img).to_rgb8().into_raw()
        );
    }

    #[test]
    fn png_round_trip_is_lossless_and_jpeg_keeps_alpha_images_png() {
        let (w, h) = (5u32, 3u32);
        let px: Vec<u8> = (0..w * h * 4).map(|i| (i * 17 % 256) as u8).collect();
        let (png, mime) = encode_rgba(w, h, px.clone(), TextureFormat::Png, "", 85).unwrap();
        assert_eq!(mime, "image/png");
        assert_eq!(decode(&png).unwrap().to_rgba8().into_raw(), px);
        assert_eq!(dimensions(&png).unwrap(), (5, 3));
        // Alpha varies: JPEG is not used.
        let (_, mime) = encode_rgba(w, h, px, TextureFormat::Jpeg, "", 85).unwrap();
        assert_eq!(mime, "image/png");
        let opaque: Vec<u8> = (0..w * h).flat_map(|_| [200, 100, 50, 255]).collect();
        let (jpg, mime) = encode_rgba(w, h, opaque, TextureFormat::Auto, "image/jpeg", 85).unwrap();
        assert_eq!(mime, "image/jpeg");
        assert_eq!(dimensions(&jpg).unwrap(), (5, 3));
    }
}
