//! bimtiles: building models (glTF/GLB, IFC) to OGC 3D Tiles 1.1.
//!
//! The pipeline follows the modules in order, data flowing one way:
//! `ingest` (readers) → `scene` (the model) → `dedup` (repeated shapes shared, duplicates
//! aliased) → `partition` (octree plan) → `partition::content` (a tile's merged geometry) →
//! `simplify` (QEM, HLOD) → `texture` (redundant textures removed, Haar pyramid level per tile)
//! → `encode` (GLB) → `tileset` (tileset.json, georeferencing);
//! `convert` runs it end to end, `inspect` reads a
//! result back and `serve` shows it in a local CesiumJS viewer.

pub mod build;
pub mod convert;
pub mod dedup;
pub mod encode;
pub mod error;
pub mod geodesy;
pub mod geometry;
pub mod glb_container;
pub mod ingest;
pub mod inspect;
pub mod memory;
pub mod options;
pub mod output_dir;
pub mod partition;
pub mod prepare;
pub mod report;
pub mod scene;
pub mod serve;
pub mod shard;
pub mod simplify;
pub mod texture;
pub mod tileset;

pub use error::{Error, Result};

/// The library's modules from the bottom up: a module may use the modules of lower layers only,
/// never one of its own layer or above (so imports flow one way and no two modules form a cycle).
/// Base modules first, then the pipeline's stages in the order the data flows, then the drivers.
/// `src/cli/` (the binary) sits on top and may use anything.
pub const LAYERS: &[&[&str]] = &[
    &["error", "memory"],
    &["geometry", "geodesy", "glb_container", "output_dir"],
    &["scene"],
    &["ingest"],
    &["dedup"],
    &["partition"],
    &["simplify"],
    &["texture"],
    &["encode"],
    &["tileset"],
    &["options"],
    &["prepare"],
    &["build"],
    &["report"],
    &["convert", "inspect"],
    &["shard", "serve"],
];

#[cfg(test)]
mod layering {
    use super::LAYERS;
    use std::collections::BTreeSet;
    use std::path::{Path, PathBuf};

    fn layer_of(module: &str) -> Option<usize> {
        LAYERS.iter().position(|l| l.contains(&module))
    }

    /// Top-level modules a source file names through `crate::` paths (comments left out).
    fn imports(text: &str) -> BTreeSet<String> {
        let code: String = text
            .lines()
            .map(|l| l.split("//").next().unwrap_or(""))
            .collect::<Vec<_>>()
            .join("\n");
        let ident = |s: &str| -> String {
            s.trim_start()
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect()
        };
        let mut out = BTreeSet::new();
        let mut rest = code.as_str();
        while let Some(i) = rest.find("crate::") {
            rest = &rest[i + "crate::".len()..];
            let Some(group) = rest.strip_prefix('{') else {
                out.insert(ident(rest));
                continue;
            };
            // `crate::{a::X, b::{Y, Z}}`: the first name of each top-level item.
            let (mut depth, mut item_start) = (0usize, true);
            for (k, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => item_start = true,
                    c if item_start && !c.is_whitespace() => {
                        item_start = false;
                        out.insert(ident(&group[k..]));
                    }
                    _ => {}
                }
            }
        }
        out.remove("");
        out
    }

    fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                sources(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }

    #[test]
    fn imports_flow_down_the_layers() {
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
        let mut files = Vec::new();
        sources(&src, &mut files);
        files.sort();
        let mut wrong = Vec::new();
        let mut seen = BTreeSet::new();
        for f in &files {
            let rel = f.strip_prefix(&src).unwrap();
            let first = rel
                .components()
                .next()
                .unwrap()
                .as_os_str()
                .to_string_lossy();
            let module = first.trim_end_matches(".rs").to_string();
            if module == "cli" || module == "main" || module == "lib" {
                continue;
            }
            let Some(mine) = layer_of(&module) else {
                wrong.push(format!("{}: module {module} is in no layer", rel.display()));
                continue;
            };
            seen.insert(module.clone());
            for used in imports(&std::fs::read_to_string(f).unwrap()) {
                if used == module {
                    continue;
                }
                match layer_of(&used) {
                    Some(l) if l < mine => {}
                    Some(_) => wrong.push(format!(
                        "{}: {module} (layer {mine}) uses {used} (layer {})",
                        rel.display(),
                        layer_of(&used).unwrap()
                    )),
                    None => wrong.push(format!("{}: uses crate::{used}", rel.display())),
                }
            }
        }
        assert!(
            wrong.is_empty(),
            "imports against the layers:\n{}",
            wrong.join("\n")
        );
        let listed: BTreeSet<String> = LAYERS
            .iter()
            .flat_map(|l| l.iter().map(|m| m.to_string()))
            .collect();
        assert_eq!(seen, listed, "LAYERS lists exactly the library's modules");
    }

    #[test]
    fn the_check_sees_grouped_and_inline_paths() {
        let found = imports(
            "use crate::{\n    scene::{Aabb, Scene},\n    error,\n};\nlet x = crate::tileset::view::f(); // crate::shard\n",
        );
        let want: BTreeSet<String> = ["scene", "error", "tileset"].map(String::from).into();
        assert_eq!(found, want);
    }
}
