#![no_main]
//! Fuzz target: `bimtiles::fuzzing::inspect` on arbitrary bytes.
libfuzzer_sys::fuzz_target!(|data: &[u8]| bimtiles::fuzzing::inspect(data));
