/*
 * bimtiles Basis Universal shim: one C function over the Basis Universal encoder's own
 * "simple C-style wrapper" (basisu::basis_compress, encoder/basisu_comp.h), which the crate
 * basis-universal-sys compiles from the Binomial sources it vendors (1.16) but does not expose:
 * its Rust API writes .basis files only, and glTF's KHR_texture_basisu needs KTX2.
 *
 * The three declarations below are copied from basisu_comp.h / basisu_enc.h of that version
 * (the crate is pinned, =0.3.1, in Cargo.toml); the flag values too. No exception crosses the
 * C ABI. The Rust side (src/texture/basisu.rs) is the only user.
 */
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <mutex>

namespace basisu {
struct image_stats;
void basisu_encoder_init(bool use_opencl, bool opencl_force_serialization);
void* basis_compress(const uint8_t* pImageRGBA, uint32_t width, uint32_t height, uint32_t pitch_in_pixels,
                     uint32_t flags_and_quality, float uastc_rdo_quality, size_t* pSize, image_stats* pStats);
void basis_free_data(void* p);
}  // namespace basisu

namespace {
// basisu_comp.h, enum of basis_compress's flags.
const uint32_t kFlagKTX2 = 1u << 11;
const uint32_t kFlagSRGB = 1u << 13;
const uint32_t kFlagGenMipsClamp = 1u << 14;
const uint32_t kFlagGenMipsWrap = 1u << 15;
const uint32_t kFlagUASTC = 1u << 17;
std::once_flag g_init;
}  // namespace

extern "C" {

/* Encodes `width` x `height` RGBA8 pixels (rows top first, no padding) as a KTX2 file with
 * Basis Universal: UASTC when `uastc` (then `level` is the UASTC pack level 0-4), else ETC1S
 * (`level` is its quality 1-255). `srgb`: colour data (perceptual metrics, sRGB transfer
 * function); `mipmaps`: full mip chain (`wrap`: wrap addressing while filtering, else clamp).
 * On success returns the file (free it with bt_basisu_free) and its size in *size;
 * on failure NULL. */
void* bt_basisu_ktx2(const uint8_t* rgba, uint32_t width, uint32_t height, int uastc, uint32_t level, int srgb,
                     int mipmaps, int wrap, size_t* size) {
  try {
    std::call_once(g_init, [] { basisu::basisu_encoder_init(false, false); });
    uint32_t flags = kFlagKTX2 | (level & 0xff);
    if (uastc) flags |= kFlagUASTC;
    if (srgb) flags |= kFlagSRGB;
    if (mipmaps) flags |= wrap ? kFlagGenMipsWrap : kFlagGenMipsClamp;
    *size = 0;
    return basisu::basis_compress(rgba, width, height, width, flags, 0.0f, size, nullptr);
  } catch (...) {
    return nullptr;
  }
}

void bt_basisu_free(void* data) { basisu::basis_free_data(data); }

}  // extern "C"
