#![no_main]
//! Fuzz target: `bimtiles::fuzzing::fbx` on arbitrary bytes.
libfuzzer_sys::fuzz_target!(|data: &[u8]| bimtiles::fuzzing::fbx(data));
