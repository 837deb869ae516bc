#![no_main]
//! Fuzz target: `bimtiles::fuzzing::citygml` on arbitrary bytes.
libfuzzer_sys::fuzz_target!(|data: &[u8]| bimtiles::fuzzing::citygml(data));
