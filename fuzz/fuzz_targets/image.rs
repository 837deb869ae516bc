#![no_main]
//! Fuzz target: `bimtiles::fuzzing::image` on arbitrary bytes.
libfuzzer_sys::fuzz_target!(|data: &[u8]| bimtiles::fuzzing::image(data));
