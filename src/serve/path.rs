//! Mapping a request path onto a file inside one root directory, refusing anything that could
//! leave it: `..` (plain or percent-encoded), encoded separators, absolute paths, NUL bytes,
//! dot-files, and symlinks whose target lies outside the root.

use percent_encoding::percent_decode_str;
use std::path::{Path, PathBuf};

/// Why a path was not served.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refused {
    /// Not valid percent-encoded UTF-8, or a NUL byte.
    BadEncoding,
    /// A `.` / `..` segment, or an encoded `/` or `\` inside a segment.
    Traversal,
    /// An empty segment (`//`), i.e. an absolute path after the mount point.
    Absolute,
    /// A segment starting with `.` (`.git`, `.env`...).
    Hidden,
    /// The file exists but (through a symlink) lies outside the root.
    Escapes,
    /// No such regular file (or a directory without `index.html`).
    NotFound,
}

impl Refused {
    pub fn status(self) -> u16 {
        match self {
            Refused::BadEncoding | Refused::Traversal | Refused::Absolute => 400,
            Refused::Hidden | Refused::Escapes => 403,
            Refused::NotFound => 404,
        }
    }
}

/// Checks the still percent-encoded path below a mount point (no leading `/`, no query) and
/// returns the relative file-system path it names. Purely lexical: touches no file.
pub fn sanitize(raw: &str) -> Result<PathBuf, Refused> {
    let mut rel = PathBuf::new();
    if raw.is_empty() {
        return Ok(rel);
    }
    let segments: Vec<&str> = raw.split('/').collect();
    let last = segments.len() - 1;
    for (i, seg) in segments.iter().enumerate() {
        if seg.is_empty() {
            if i == last {
                break; // trailing slash: a directory
            }
            return Err(Refused::Absolute);
        }
        let decoded = percent_decode_str(seg)
            .decode_utf8()
            .map_err(|_| Refused::BadEncoding)?;
        if decoded.contains('\0') {
            return Err(Refused::BadEncoding);
        }
        if decoded == "." || decoded == ".." || decoded.contains('/') || decoded.contains('\\') {
            return Err(Refused::Traversal);
        }
        if decoded.starts_with('.') {
            return Err(Refused::Hidden);
        }
        // A Windows drive or stream name (`C:`, `a:b`) has no business in a URL path either.
        if decoded.contains(':') {
            return Err(Refused::Traversal);
        }
        rel.push(decoded.as_ref());
    }
    debug_assert!(rel.is_relative());
    Ok(rel)
}

/// Resolves `raw` (see [`sanitize`]) inside `root`, which must already be canonical. A directory
/// resolves to its `index.html`. The result is canonical and guaranteed to lie inside `root`.
pub fn resolve(root: &Path, raw: &str) -> Result<PathBuf, Refused> {
    let rel = sanitize(raw)?;
    let mut canon = root
        .join(&rel)
        .canonicalize()
        .map_err(|_| Refused::NotFound)?;
    if !canon.starts_with(root) {
        return Err(Refused::Escapes);
    }
    if raw.ends_with('/') && !canon.is_dir() {
        return Err(Refused::NotFound); // "file.json/"
    }
    if canon.is_dir() {
        canon = canon
            .join("index.html")
            .canonicalize()
            .map_err(|_| Refused::NotFound)?;
        if !canon.starts_with(root) {
            return Err(Refused::Escapes);
        }
    }
    if !canon.is_file() {
        return Err(Refused::NotFound);
    }
    Ok(canon)
}

#[cfg(test)]
mod tests {
    use super::super::tests_support::TempDir;
    use super::*;

    #[test]
    fn plain_paths() {
        assert_eq!(sanitize("").unwrap(), PathBuf::new());
        assert_eq!(
            sanitize("tiles/r0.glb").unwrap(),
            PathBuf::from("tiles").join("r0.glb")
        );
        assert_eq!(sanitize("tiles/").unwrap(), PathBuf::from("tiles"));
        assert_eq!(sanitize("a%20b.json").unwrap(), PathBuf::from("a b.json"));
    }

    #[test]
    fn refuses_dot_dot() {
        assert_eq!(sanitize(".."), Err(Refused::Traversal));
        assert_eq!(sanitize("../etc/passwd"), Err(Refused::Traversal));
        assert_eq!(sanitize("tiles/../../x"), Err(Refused::Traversal));
        assert_eq!(sanitize("tiles/./r0.glb"), Err(Refused::Traversal));
    }

    #[test]
    fn refuses_percent_encoded_dot_dot() {
        assert_eq!(sanitize("%2e%2e/etc/passwd"), Err(Refused::Traversal));
        assert_eq!(sanitize("%2E%2E/etc/passwd"), Err(Refused::Traversal));
        assert_eq!(sanitize(".%2e/x"), Err(Refused::Traversal));
        assert_eq!(sanitize("tiles%2f..%2f..%2fx"), Err(Refused::Traversal));
        assert_eq!(sanitize("..%5c..%5cx"), Err(Refused::Traversal));
        // Double encoding decodes once: "%2e%2e" is then a harmless literal file name.
        assert_eq!(sanitize("%252e%252e").unwrap(), PathBuf::from("%2e%2e"));
    }

    #[test]
    fn refuses_absolute_paths() {
        assert_eq!(sanitize("/etc/passwd"), Err(Refused::Absolute));
        assert_eq!(sanitize("tiles//r0.glb"), Err(Refused::Absolute));
        assert_eq!(sanitize("%2Fetc%2Fpasswd"), Err(Refused::Traversal));
        assert_eq!(sanitize("C:%5Cwindows"), Err(Refused::Traversal));
        assert_eq!(sanitize("C:"), Err(Refused::Traversal));
    }

    #[test]
    fn refuses_bad_encoding_and_hidden() {
        assert_eq!(sanitize("a%00b"), Err(Refused::BadEncoding));
        assert_eq!(sanitize("%ff%fe"), Err(Refused::BadEncoding));
        assert_eq!(sanitize(".git/config"), Err(Refused::Hidden));
        assert_eq!(sanitize("tiles/.secret"), Err(Refused::Hidden));
    }

    #[test]
    fn resolve_inside_root_and_index() {
        let t = TempDir::new("resolve");
        let root = t.path().join("root");
        std::fs::create_dir_all(root.join("tiles")).unwrap();
        std::fs::write(root.join("tiles/a.glb"), b"x").unwrap();
        std::fs::write(root.join("index.html"), b"<p>").unwrap();
        let root = root.canonicalize().unwrap();
        assert_eq!(
            resolve(&root, "tiles/a.glb").unwrap(),
            root.join("tiles/a.glb")
        );
        assert_eq!(resolve(&root, "").unwrap(), root.join("index.html"));
        assert_eq!(resolve(&root, "tiles/b.glb"), Err(Refused::NotFound));
        assert_eq!(resolve(&root, "tiles/"), Err(Refused::NotFound)); // dir without index
        assert_eq!(resolve(&root, "tiles/a.glb/"), Err(Refused::NotFound));
    }

    #[cfg(unix)]
    #[test]
    fn refuses_symlinks_escaping_the_root() {
        let t = TempDir::new("symlink");
        let root = t.path().join("root");
        let outside = t.path().join("outside");
        std::fs::create_dir_all(&root).unwrap();
        std::fs::create_dir_all(&outside).unwrap();
        std::fs::write(outside.join("secret.json"), b"{}").unwrap();
        std::fs::write(root.join("ok.json"), b"{}").unwrap();
        std::os::unix::fs::symlink(outside.join("secret.json"), root.join("leak.json")).unwrap();
        std::os::unix::fs::symlink(&outside, root.join("leakdir")).unwrap();
        std::os::unix::fs::symlink(root.join("ok.json"), root.join("alias.json")).unwrap();
        std::os::unix::fs::symlink("/", root.join("slash")).unwrap();
        let root = root.canonicalize().unwrap();
        assert_eq!(resolve(&root, "leak.json"), Err(Refused::Escapes));
        assert_eq!(resolve(&root, "leakdir/secret.json"), Err(Refused::Escapes));
        assert_eq!(resolve(&root, "slash/etc/passwd"), Err(Refused::Escapes));
        // A symlink that stays inside the root is fine.
        assert_eq!(resolve(&root, "alias.json").unwrap(), root.join("ok.json"));
    }
}
