//! The fuzz corpora (`fuzz/corpus/<target>/`, seeds and every crash the fuzzer found) run on
//! stable in `make test`: each file goes through its target's entry point
//! (`bimtiles::fuzzing::TARGETS`, what `cargo fuzz` runs), which must return (an error is fine)
//! rather than panic.

use crate::common::*;

#[test]
fn every_corpus_file_is_read_without_a_panic() {
    let corpus = repo().join("fuzz/corpus");
    for (name, entry) in bimtiles::fuzzing::TARGETS {
        let target = repo().join(format!("fuzz/fuzz_targets/{name}.rs"));
        assert!(
            target.is_file(),
            "no cargo-fuzz target {}",
            target.display()
        );
        let dir = corpus.join(name);
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        assert!(!files.is_empty(), "{}: no seeds", dir.display());
        for f in files {
            let bytes = std::fs::read(&f).unwrap();
            let outcome = std::panic::catch_unwind(|| entry(&bytes));
            assert!(outcome.is_ok(), "{name}: {} panics", f.display());
        }
    }
}
