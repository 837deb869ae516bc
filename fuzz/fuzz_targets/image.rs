#![no_main]
//! Fuzz target: `bimtiles::fuzzing::image` on arbitrary bytes. The image decoders are not
//! panic-free on malformed files, and bimtiles turns their panics into an error
//! (`texture::codec`, `guarded`); any other panic is a defect.

libfuzzer_sys::fuzz_target!(
    init: bimtiles::fuzzing::abort_on_panics_outside(bimtiles::fuzzing::IMAGE_DECODER_CRATES),
    |data: &[u8]| bimtiles::fuzzing::image(data)
);
