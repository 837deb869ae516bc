#![no_main]
//! Fuzz target: `bimtiles::fuzzing::ifc` on arbitrary bytes. ifc-lite is not panic-free on
//! malformed input, and bimtiles turns its panics into an error (`ingest::ifc`, `guarded`); any
//! other panic is a defect.

libfuzzer_sys::fuzz_target!(
    init: bimtiles::fuzzing::abort_on_panics_outside(&["ifc-lite"]),
    |data: &[u8]| bimtiles::fuzzing::ifc(data)
);
