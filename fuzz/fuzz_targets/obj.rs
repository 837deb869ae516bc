#![no_main]
//! Fuzz target: `bimtiles::fuzzing::obj` on arbitrary bytes.
libfuzzer_sys::fuzz_target!(|data: &[u8]| bimtiles::fuzzing::obj(data));
