//! bimtiles: building models (glTF/GLB, IFC) to OGC 3D Tiles 1.1.
//!
//! The pipeline follows the modules in order, data flowing one way:
//! `ingest` (readers) → `scene` (the model) → `dedup` (repeated shapes shared, duplicates
//! aliased) → `partition` (octree plan) → `partition::content` (a tile's merged geometry) →
//! `simplify` (QEM, HLOD) → `texture` (redundant textures removed, Haar pyramid level per tile)
//! → `encode` (GLB) → `tileset` (tileset.json, georeferencing);
//! `convert` runs it end to end, `inspect` reads a
//! result back and `serve` shows it in a local CesiumJS viewer.

pub mod convert;
pub mod dedup;
pub mod draco;
pub mod encode;
pub mod error;
pub mod fuzzing;
pub mod geodesy;
pub mod geometry;
pub mod glb_container;
pub mod ingest;
pub mod inspect;
pub mod lod;
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
pub mod tiling;
pub mod transfer;
pub mod update;
pub mod uri;

pub use error::{Error, Result};

/// The library's modules from the bottom up: a module may use the modules of lower layers only,
/// never one of its own layer or above (so imports flow one way and no two modules form a cycle).
/// Base modules first, then the pipeline's stages in the order the data flows, then the drivers.
/// `src/cli/` (the binary) sits on top and may use anything.
pub const LAYERS: &[&[&str]] = &[
    &["error", "memory"],
    &[
        "geometry",
        "geodesy",
        "glb_container",
        "output_dir",
        "draco",
        "transfer",
        "uri",
    ],
    &["scene"],
    &["ingest"],
    &["dedup"],
    &["partition"],
    &["simplify"],
    &["texture"],
    &["encode"],
    &["tileset"],
    &["options"],
    &["update"],
    &["lod"],
    &["prepare"],
    &["tiling"],
    &["report"],
    &["inspect"],
    &["convert"],
    &["shard", "serve"],
    &["fuzzing"],
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

    /// Every `.rs` file under `dir` (also used by the function-length test).
    pub(super) fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
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

/// Functions short enough to read at once: none longer than [`function_length::MAX_FUNCTION_LINES`]
/// lines.
///
/// A function's length counts its lines from `fn` to its closing brace (signature and body; a
/// nested function counts in its own length and in the enclosing one's). Exempt: test code, i.e.
/// `tests.rs` files and items under `#[cfg(test)]` (such as `mod tests { ... }`); a long test
/// reads as a list of cases. The scanner blanks comments, strings and character literals, then
/// counts braces, so a brace in a string or comment does not end a function.
#[cfg(test)]
mod function_length {
    use std::path::Path;

    pub const MAX_FUNCTION_LINES: usize = 150;

    /// `text` with comments (line, nested block), string literals (plain, byte, raw) and char
    /// literals replaced by spaces, newlines kept (so byte offsets and line numbers still hold).
    /// Lifetimes (`'a`) are left as they are.
    pub fn blank_non_code(text: &str) -> String {
        let b = text.as_bytes();
        let mut out = b.to_vec();
        let blank = |out: &mut Vec<u8>, from: usize, to: usize| {
            for c in &mut out[from..to.min(b.len())] {
                if *c != b'\n' {
                    *c = b' ';
                }
            }
        };
        let is_ident = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
        let mut i = 0;
        while i < b.len() {
            let prev_ident = i > 0 && is_ident(b[i - 1]);
            match b[i] {
                b'/' if b.get(i + 1) == Some(&b'/') => {
                    let end = text[i..].find('\n').map_or(b.len(), |k| i + k);
                    blank(&mut out, i, end);
                    i = end;
                }
                b'/' if b.get(i + 1) == Some(&b'*') => {
                    let (mut depth, mut j) = (0usize, i);
                    while j < b.len() {
                        if b[j..].starts_with(b"/*") {
                            depth += 1;
                            j += 2;
                        } else if b[j..].starts_with(b"*/") {
                            depth -= 1;
                            j += 2;
                            if depth == 0 {
                                break;
                            }
                        } else {
                            j += 1;
                        }
                    }
                    blank(&mut out, i, j);
                    i = j;
                }
                // Raw strings: r"..", r#".."#, br"..". (`r#ident` is a raw identifier.)
                b'r' if !prev_ident || (i == 1 || !is_ident(b[i - 2])) && b[i - 1] == b'b' => {
                    let hashes = b[i + 1..].iter().take_while(|&&c| c == b'#').count();
                    if b.get(i + 1 + hashes) != Some(&b'"') {
                        i += 1;
                        continue;
                    }
                    let close = format!("\"{}", "#".repeat(hashes));
                    let start = i + 2 + hashes;
                    let end = text[start..]
                        .find(&close)
                        .map_or(b.len(), |k| start + k + close.len());
                    blank(&mut out, i, end);
                    i = end;
                }
                b'"' => {
                    let mut j = i + 1;
                    while j < b.len() && b[j] != b'"' {
                        j += if b[j] == b'\\' { 2 } else { 1 };
                    }
                    blank(&mut out, i, j + 1);
                    i = j + 1;
                }
                b'\'' => {
                    // A char literal: an escape, or one character then a quote; else a lifetime.
                    let rest = &text[i + 1..];
                    let len = if rest.starts_with('\\') {
                        rest[2..].find('\'').map(|k| k + 3)
                    } else {
                        let mut cs = rest.chars();
                        match (cs.next(), cs.next()) {
                            (Some(c), Some('\'')) => Some(c.len_utf8() + 1),
                            _ => None,
                        }
                    };
                    match len {
                        Some(n) => {
                            blank(&mut out, i, i + 1 + n);
                            i += 1 + n;
                        }
                        None => i += 1,
                    }
                }
                _ => i += 1,
            }
        }
        String::from_utf8(out).expect("only ASCII bytes were replaced")
    }

    /// The byte offset of the `{` opening the item whose signature starts at `from`, or `None`
    /// when a `;` ends it first (a declaration without a body). `;` and braces inside `()`
    /// and `[]` (array types `[u32; 3]`) do not count.
    fn body_start(code: &[u8], from: usize) -> Option<usize> {
        let mut depth = 0i32;
        for (k, &c) in code.iter().enumerate().skip(from) {
            match c {
                b'(' | b'[' => depth += 1,
                b')' | b']' => depth -= 1,
                b'{' if depth == 0 => return Some(k),
                b';' if depth == 0 => return None,
                _ => {}
            }
        }
        None
    }

    /// The byte offset of the `}` matching the `{` at `open`.
    fn matching_brace(code: &[u8], open: usize) -> usize {
        let mut depth = 0usize;
        for (k, &c) in code.iter().enumerate().skip(open) {
            match c {
                b'{' => depth += 1,
                b'}' => {
                    depth -= 1;
                    if depth == 0 {
                        return k;
                    }
                }
                _ => {}
            }
        }
        code.len()
    }

    /// Every function with a body outside `#[cfg(test)]` items: (name, first line (1-based),
    /// length in lines).
    pub fn functions(text: &str) -> Vec<(String, usize, usize)> {
        let code = blank_non_code(text);
        let b = code.as_bytes();
        let line_of = |at: usize| code[..at].matches('\n').count() + 1;
        let is_ident = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
        let mut exempt = Vec::new();
        for (at, _) in code.match_indices("#[cfg(test)]") {
            if let Some(open) = body_start(b, at + "#[cfg(test)]".len()) {
                exempt.push(open..=matching_brace(b, open));
            }
        }
        let mut out = Vec::new();
        for (at, _) in code.match_indices("fn") {
            let before_ok = at == 0 || !is_ident(b[at - 1]);
            let after = &code[at + 2..];
            let name: String = after
                .trim_start()
                .chars()
                .take_while(|&c| c.is_alphanumeric() || c == '_')
                .collect();
            // `fn(u32) -> u32` (a pointer type) has no name; `fnord` is another word.
            if !before_ok || !after.starts_with(char::is_whitespace) || name.is_empty() {
                continue;
            }
            if exempt.iter().any(|r| r.contains(&at)) {
                continue;
            }
            let Some(open) = body_start(b, at) else {
                continue;
            };
            let (first, last) = (line_of(at), line_of(matching_brace(b, open)));
            out.push((name, first, last - first + 1));
        }
        out
    }

    use super::layering::sources;

    #[test]
    fn no_function_is_longer_than_the_limit() {
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
        let mut files = Vec::new();
        sources(&src, &mut files);
        files.sort();
        let mut long = Vec::new();
        for f in files.iter().filter(|f| !f.ends_with("tests.rs")) {
            let text = std::fs::read_to_string(f).unwrap();
            for (name, line, len) in functions(&text) {
                if len > MAX_FUNCTION_LINES {
                    let rel = f.strip_prefix(&src).unwrap().display();
                    long.push(format!("src/{rel}:{line}: fn {name} is {len} lines"));
                }
            }
        }
        assert!(
            long.is_empty(),
            "functions over {MAX_FUNCTION_LINES} lines (issue 27):\n{}",
            long.join("\n")
        );
    }

    #[test]
    fn the_scanner_skips_strings_comments_chars_and_test_code() {
        let text = r####"
/// Doc with a brace {
fn a<'x>(s: &'x str) -> [u8; 3] {
    let _ = "}}} \" }";
    let _ = r#"}"#;
    let _ = b'}';
    let _ = '{';
    /* { nested /* } */ { */
    // }
    let f: fn(u32) -> u32 = |x| x;
    fn inner() {
    }
}
trait T {
    fn declared(&self) -> [u32; 2];
}
#[cfg(test)]
mod tests {
    fn skipped() {
    }
}
fn last() {}
"####;
        let found = functions(text);
        let want = [("a", 3, 11), ("inner", 11, 2), ("last", 22, 1)]
            .map(|(n, l, k)| (n.to_string(), l, k));
        assert_eq!(found, want);
        assert_eq!(blank_non_code("x = 'a'; y"), "x =    ; y");
    }
}
