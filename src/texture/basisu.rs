//! KTX2 textures with Basis Universal (glTF `KHR_texture_basisu`; paper III.E's output side, GPU
//! compressed): the encoder is Binomial's, compiled by the crate `basis-universal-sys`; the shim
//! `shim/basisu_shim.cc` calls its KTX2 entry point.
//!
//! The extension requires each image's width and height to be multiples of 4
//! (KHR_texture_basisu, "KTX v2 Images with Basis Universal Supercompression"); [`encode_ktx2`]
//! resamples an image that is not to the next multiples of 4 (normalised UVs are unchanged).

use super::codec::CodecError;

// Links the encoder's static library (nothing of its Rust API is used).
use basis_universal_sys as _;

extern "C" {
    fn bt_basisu_ktx2(
        rgba: *const u8,
        width: u32,
        height: u32,
        uastc: i32,
        level: u32,
        srgb: i32,
        mipmaps: i32,
        wrap: i32,
        size: *mut usize,
    ) -> *mut std::ffi::c_void;
    fn bt_basisu_free(data: *mut std::ffi::c_void);
}

/// Basis Universal's two codecs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BasisCodec {
    /// ETC1S with BasisLZ: about 1-2 bits per texel in the file, transcoded to ETC1/BC1 (4 bpp on
    /// the GPU); lower quality.
    Etc1s,
    /// UASTC: 8 bits per texel (no Zstd in this build), transcoded to ASTC/BC7 (8 bpp).
    Uastc,
}

/// The codec written by `--texture-format ktx2`, chosen by measurement (book: guide/textures.md,
/// "Texture formats").
pub const KTX2_CODEC: BasisCodec = BasisCodec::Etc1s;
/// ETC1S quality (1-255): basisu's default is 128.
const ETC1S_QUALITY: u32 = 128;
/// UASTC pack level (0 fastest .. 4 slowest): basisu's default, 2.
const UASTC_PACK_LEVEL: u32 = 2;

/// The width and height a KTX2 image of a `width` x `height` image gets: the next multiples of 4.
pub fn ktx2_size(width: u32, height: u32) -> (u32, u32) {
    (width.div_ceil(4) * 4, height.div_ceil(4) * 4)
}

/// Encodes 8-bit RGBA (colour data, sRGB) as a KTX2 file with a full mip chain.
pub fn encode_ktx2(
    width: u32,
    height: u32,
    rgba: Vec<u8>,
    codec: BasisCodec,
) -> Result<Vec<u8>, CodecError> {
    if width == 0 || height == 0 || rgba.len() != width as usize * height as usize * 4 {
        return Err(CodecError::Inconsistent("pixel buffer size"));
    }
    let (w4, h4) = ktx2_size(width, height);
    let rgba = if (w4, h4) == (width, height) {
        rgba
    } else {
        let img = image::RgbaImage::from_raw(width, height, rgba)
            .ok_or(CodecError::Inconsistent("pixel buffer size"))?;
        image::imageops::resize(&img, w4, h4, image::imageops::FilterType::Triangle).into_raw()
    };
    let (uastc, level) = match codec {
        BasisCodec::Etc1s => (0, ETC1S_QUALITY),
        BasisCodec::Uastc => (1, UASTC_PACK_LEVEL),
    };
    let mut size = 0usize;
    // SAFETY: `rgba` holds w4 * h4 RGBA texels (checked or made above) and outlives the call; the
    // shim catches every C++ exception and returns NULL on failure.
    let data = unsafe { bt_basisu_ktx2(rgba.as_ptr(), w4, h4, uastc, level, 1, 1, 1, &mut size) };
    if data.is_null() || size == 0 {
        return Err(CodecError::Basisu {
            width_px: w4,
            height_px: h4,
        });
    }
    // SAFETY: the shim returned `size` bytes at `data`, ours until bt_basisu_free.
    let out = unsafe { std::slice::from_raw_parts(data as *const u8, size).to_vec() };
    // SAFETY: `data` came from bt_basisu_ktx2 and is freed once.
    unsafe { bt_basisu_free(data) };
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gradient(w: u32, h: u32) -> Vec<u8> {
        (0..w * h)
            .flat_map(|i| [(i % w * 255 / w) as u8, (i / w * 255 / h) as u8, 128, 255])
            .collect()
    }

    #[test]
    fn ktx2_files_have_the_ktx2_signature_and_multiple_of_4_sizes() {
        for codec in [BasisCodec::Etc1s, BasisCodec::Uastc] {
            let out = encode_ktx2(30, 17, gradient(30, 17), codec).unwrap();
            assert_eq!(&out[..12], b"\xABKTX 20\xBB\r\n\x1A\n", "{codec:?}");
            let word = |i: usize| u32::from_le_bytes(out[i..i + 4].try_into().unwrap());
            // Header: vkFormat 0 (Basis), pixelWidth, pixelHeight at bytes 12, 20, 24.
            assert_eq!((word(12), word(20), word(24)), (0, 32, 20), "{codec:?}");
            // supercompressionScheme: 1 (BasisLZ) for ETC1S, 0 for UASTC without Zstd.
            assert_eq!(word(44), (codec == BasisCodec::Etc1s) as u32, "{codec:?}");
            // levelCount: the full chain, 32x20 down to 1x1.
            assert_eq!(word(40), 6, "{codec:?}");
        }
    }

    #[test]
    fn a_wrong_pixel_buffer_is_an_error() {
        assert!(encode_ktx2(4, 4, vec![0; 10], BasisCodec::Etc1s).is_err());
        assert!(encode_ktx2(0, 4, vec![], BasisCodec::Etc1s).is_err());
    }
}
