#![no_main]
//! Fuzz target: `bimtiles::fuzzing::gltf` on arbitrary bytes.
libfuzzer_sys::fuzz_target!(|data: &[u8]| bimtiles::fuzzing::gltf(data));
