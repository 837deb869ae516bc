#![no_main]
//! Fuzz target: `bimtiles::fuzzing::ifc` on arbitrary bytes.

libfuzzer_sys::fuzz_target!(
    init: {
        // ifc-lite is not panic-free on malformed input, and bimtiles turns its panics into an
        // error (`ingest::ifc`, `guarded`). Any other panic is a defect: abort, as libfuzzer-sys
        // does for every panic.
        std::panic::set_hook(Box::new(|info| {
            if !info.location().is_some_and(|l| l.file().contains("ifc-lite")) {
                eprintln!("{info}");
                std::process::abort();
            }
        }));
    },
    |data: &[u8]| bimtiles::fuzzing::ifc(data)
);
