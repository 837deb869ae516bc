#![no_main]
//! Fuzz target: `bimtiles::fuzzing::manifest` on arbitrary bytes.
libfuzzer_sys::fuzz_target!(|data: &[u8]| bimtiles::fuzzing::manifest(data));
