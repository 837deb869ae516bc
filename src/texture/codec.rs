//! Decoding and encoding of texture images with the `image` crate (paper III.E's output side):
//! the formats glTF core allows, PNG (lossless) and JPEG (with a quality setting).
//!
//! WebP is decodable but not written: glTF core does not allow `image/webp` (it needs
//! `EXT_texture_webp` with a fallback image), and the `image` crate's WebP encoder is lossless
//! only, so it would not beat PNG by enough to pay for the extension.

use image::{DynamicImage, ImageFormat};
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
}

/// Default JPEG quality (libjpeg scale 1-100).
pub const DEFAULT_JPEG_QUALITY: u8 = 85;

/// Decodes any supported image without the `image` crate's default 512 MiB allocation limit
/// (a 16k x 16k RGBA texture is 1 GiB of pixels).
pub fn decode(bytes: &[u8]) -> Result<DynamicImage, String> {
    let mut r = image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| e.to_string())?;
    r.no_limits();
    r.decode().map_err(|e| e.to_string())
}

/// Width and height from the header only (no pixel decoding).
pub fn dimensions(bytes: &[u8]) -> Result<(u32, u32), String> {
    image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| e.to_string())?
        .into_dimensions()
        .map_err(|e| e.to_string())
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
) -> Result<(Vec<u8>, &'static str), String> {
    let opaque = rgba.chunks_exact(4).all(|p| p[3] == 255);
    let jpeg = opaque
        && match format {
            TextureFormat::Auto => source_mime == "image/jpeg",
            TextureFormat::Png => false,
            TextureFormat::Jpeg => true,
        };
    let img = image::RgbaImage::from_raw(width, height, rgba).ok_or("pixel buffer size")?;
    let mut out = Vec::new();
    if jpeg {
        let rgb = DynamicImage::ImageRgba8(img).to_rgb8();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, jpeg_quality.clamp(1, 100))
            .encode_image(&rgb)
            .map_err(|e| e.to_string())?;
        Ok((out, "image/jpeg"))
    } else {
        // Opaque images drop their alpha channel (a quarter fewer bytes to compress).
        let dynamic = if opaque {
            DynamicImage::ImageRgb8(DynamicImage::ImageRgba8(img).to_rgb8())
        } else {
            DynamicImage::ImageRgba8(img)
        };
        dynamic
            .write_to(&mut Cursor::new(&mut out), ImageFormat::Png)
            .map_err(|e| e.to_string())?;
        Ok((out, "image/png"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
