#![no_main]
//! Fuzz target: `bimtiles::fuzzing::http_head` on arbitrary bytes.
libfuzzer_sys::fuzz_target!(|data: &[u8]| bimtiles::fuzzing::http_head(data));
