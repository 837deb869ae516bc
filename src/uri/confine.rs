//! Folder confinement: a relative URI resolved to a file inside a root folder, refused when it
//! could lead anywhere else, so that a model, a tileset or a request from elsewhere cannot make
//! bimtiles read other files.
//!
//! Two syntaxes (RFC 3986): a relative reference found in a file (section 4.2: a glTF's buffers
//! and images, a CityJSON texture, a tileset's contents), decoded whole and then split at `/`;
//! and a request path below a mount point (section 3.3), whose segments are decoded one by one,
//! so an encoded `/` or `\` stays inside its segment and is refused. Both refuse what is absolute
//! or has a scheme, `..` that leaves the root, and symlinks leading out of it. Where the callers
//! differ they keep their own [`Rules`]: [`INPUT`], [`TILESET`], [`SERVED`].

use super::{percent, UriError};
use std::path::{Component, Path, PathBuf};

/// What a `..` segment of a relative reference may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DotDot {
    /// Refused wherever it appears.
    Refuse,
    /// Followed while the path stays inside the root (RFC 3986 section 5.2.4 removes it against
    /// the folder before it).
    InsideRoot,
}

/// How strictly one caller confines its URIs.
#[derive(Debug, Clone, Copy)]
pub struct Rules {
    /// How messages name the root, e.g. "the input folder".
    pub folder: &'static str,
    /// A `%` not followed by two hex digits refused ([`percent::decode_strict`]) rather than
    /// kept as a literal `%`.
    pub strict_percent: bool,
    /// `..` in a relative reference. A request path refuses every `.` and `..` segment: a browser
    /// removes them before it sends a path (RFC 3986 section 5.2.4), so one that arrives is an
    /// attempt to climb.
    pub dot_dot: DotDot,
    /// Names starting with `.` refused: a server must not hand out `.git` or `.env`.
    pub refuse_hidden: bool,
}

/// The buffers and images a glTF (or a CityJSON's textures) names: beside it or below, nothing
/// above it (an input folder holds the model, not its parent's files).
pub const INPUT: Rules = Rules {
    folder: "the input folder",
    strict_percent: true,
    dot_dot: DotDot::Refuse,
    refuse_hidden: false,
};

/// The tiles and schemas a tileset names: a tile's schema may sit one folder up, beside
/// tileset.json, so `..` may climb while it stays inside the tileset.
pub const TILESET: Rules = Rules {
    folder: "the tileset's folder",
    strict_percent: false,
    dot_dot: DotDot::InsideRoot,
    refuse_hidden: false,
};

/// The request paths `serve` answers: a browser's paths, where a stray `%` is a literal, and
/// no dot-file is served.
pub const SERVED: Rules = Rules {
    folder: "the served folder",
    strict_percent: false,
    dot_dot: DotDot::Refuse,
    refuse_hidden: true,
};

fn decode<'a>(s: &'a str, rules: &Rules) -> Option<std::borrow::Cow<'a, str>> {
    if rules.strict_percent {
        percent::decode_strict(s)
    } else {
        percent::decode(s)
    }
}

/// The file the relative reference `uri` names inside `root` ([`reference`] from the root).
pub fn inside(root: &Path, uri: &str, rules: &Rules) -> Result<PathBuf, UriError> {
    reference(root, root, uri, rules)
}

/// The file the relative reference `uri` names, relative to `base` (`root` or a folder inside
/// it), refused unless it stays inside `root`, by its text and through symlinks. With `..`
/// refused the result is `base` joined with the decoded text as it is (a trailing `/` still names
/// a folder); followed, it is built segment by segment.
pub fn reference(root: &Path, base: &Path, uri: &str, rules: &Rules) -> Result<PathBuf, UriError> {
    let uri_text = || uri.to_string();
    let decoded =
        decode(uri, rules).ok_or_else(|| UriError::BadPercentEncoding { uri: uri_text() })?;
    // `:` is a scheme (`file:`, `http:`) or a Windows drive, `\` a Windows separator: none is a
    // path relative to the folder. A NUL is left to the file system, which refuses such a name.
    if decoded.contains(':') || decoded.contains('\\') || decoded.starts_with('/') {
        return Err(UriError::Absolute { uri: uri_text() });
    }
    let escapes = || UriError::Escapes {
        uri: uri_text(),
        folder: rules.folder,
    };
    let rel = Path::new(decoded.as_ref());
    let path = match rules.dot_dot {
        DotDot::Refuse => {
            if rel
                .components()
                .any(|c| !matches!(c, Component::Normal(_) | Component::CurDir))
            {
                return Err(escapes());
            }
            base.join(rel)
        }
        DotDot::InsideRoot => {
            let mut path = base.to_path_buf();
            for c in rel.components() {
                match c {
                    Component::Normal(n) => path.push(n),
                    Component::CurDir => {}
                    Component::ParentDir if path != root => {
                        path.pop();
                    }
                    _ => return Err(escapes()),
                }
            }
            if !path.starts_with(root) {
                return Err(escapes());
            }
            path
        }
    };
    let hidden =
        |c: Component| matches!(c, Component::Normal(n) if n.as_encoded_bytes().starts_with(b"."));
    if rules.refuse_hidden && rel.components().any(hidden) {
        return Err(UriError::Hidden { uri: uri_text() });
    }
    // A symlink inside the folder could still point out of it.
    if leads_outside(&path, root) {
        return Err(UriError::LeadsOutside {
            uri: uri_text(),
            folder: rules.folder,
        });
    }
    Ok(path)
}

/// Whether `path` (inside `folder` by its text) leads out of it through a symlink. A path or
/// folder that does not resolve leads nowhere: its read fails on its own.
pub fn leads_outside(path: &Path, folder: &Path) -> bool {
    let folder = if folder.as_os_str().is_empty() {
        Path::new(".")
    } else {
        folder
    };
    match (path.canonicalize(), folder.canonicalize()) {
        (Ok(path), Ok(folder)) => !path.starts_with(folder),
        _ => false,
    }
}

/// The relative file-system path a request path names: `raw` still percent-encoded, below a
/// mount point (no leading `/`, no query). Every segment must decode to a plain name: no `.` or
/// `..`, no encoded separator, no NUL, no `:`, and (by the rules) no leading `.`; an empty
/// segment (`//`) would make the rest absolute, and a trailing `/` names a folder. Purely
/// lexical: touches no file.
pub fn request_path(raw: &str, rules: &Rules) -> Result<PathBuf, UriError> {
    let mut rel = PathBuf::new();
    if raw.is_empty() {
        return Ok(rel);
    }
    let uri_text = || raw.to_string();
    let segments: Vec<&str> = raw.split('/').collect();
    let last = segments.len() - 1;
    for (i, seg) in segments.iter().enumerate() {
        if seg.is_empty() {
            if i == last {
                break; // trailing slash: a folder
            }
            return Err(UriError::Absolute { uri: uri_text() });
        }
        let decoded =
            decode(seg, rules).ok_or_else(|| UriError::BadPercentEncoding { uri: uri_text() })?;
        if decoded.contains('\0') {
            return Err(UriError::Nul { uri: uri_text() });
        }
        if decoded == "." || decoded == ".." || decoded.contains('/') || decoded.contains('\\') {
            return Err(UriError::Escapes {
                uri: uri_text(),
                folder: rules.folder,
            });
        }
        if rules.refuse_hidden && decoded.starts_with('.') {
            return Err(UriError::Hidden { uri: uri_text() });
        }
        // A Windows drive or stream name (`C:`, `a:b`) has no business in a URL path either.
        if decoded.contains(':') {
            return Err(UriError::Absolute { uri: uri_text() });
        }
        rel.push(decoded.as_ref());
    }
    debug_assert!(rel.is_relative());
    Ok(rel)
}

/// The regular file the request path `raw` ([`request_path`]) names inside `root`, which must
/// already be canonical; a folder names its `index` file. The result is canonical and lies
/// inside `root`.
pub fn resolve_request(
    root: &Path,
    raw: &str,
    index: &str,
    rules: &Rules,
) -> Result<PathBuf, UriError> {
    let rel = request_path(raw, rules)?;
    let not_found = || UriError::NotFound {
        uri: raw.to_string(),
    };
    let outside = || UriError::LeadsOutside {
        uri: raw.to_string(),
        folder: rules.folder,
    };
    let mut canon = root.join(&rel).canonicalize().map_err(|_| not_found())?;
    if !canon.starts_with(root) {
        return Err(outside());
    }
    if raw.ends_with('/') && !canon.is_dir() {
        return Err(not_found()); // "file.json/"
    }
    if canon.is_dir() {
        canon = canon.join(index).canonicalize().map_err(|_| not_found())?;
        if !canon.starts_with(root) {
            return Err(outside());
        }
    }
    if !canon.is_file() {
        return Err(not_found());
    }
    Ok(canon)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A folder `root` (canonical) holding `tiles/a.glb`, `schema.json` and `index.html`, beside
    /// a folder `outside` holding `secret.json`.
    fn setup() -> (tempfile::TempDir, PathBuf) {
        let t = tempfile::tempdir().unwrap();
        let root = t.path().join("root");
        std::fs::create_dir_all(root.join("tiles")).unwrap();
        std::fs::create_dir_all(t.path().join("outside")).unwrap();
        std::fs::write(root.join("tiles/a.glb"), b"x").unwrap();
        std::fs::write(root.join("schema.json"), b"{}").unwrap();
        std::fs::write(root.join("index.html"), b"<p>").unwrap();
        std::fs::write(t.path().join("outside/secret.json"), b"{}").unwrap();
        let root = root.canonicalize().unwrap();
        (t, root)
    }

    #[test]
    fn input_uri_escapes_are_refused() {
        let base = Path::new("/tmp");
        for bad in [
            "../secret.bin",
            "a/../../x",
            "%2e%2e/x",
            "/etc/passwd",
            "file:///etc/passwd",
            "http://host/x",
            "..%2Fx",
            "a\\b.bin",
            "C:%5Cx.bin",
        ] {
            assert!(inside(base, bad, &INPUT).is_err(), "{bad} must be refused");
        }
        assert!(inside(base, "textures/a%20b.png", &INPUT).is_ok());
        assert!(inside(base, "./buf.bin", &INPUT).is_ok());
        // Each refusal says why.
        let e = |uri| inside(base, uri, &INPUT).unwrap_err();
        assert!(matches!(e("a/../../x"), UriError::Escapes { uri, .. } if uri == "a/../../x"));
        assert!(matches!(e("%2e%2e/x"), UriError::Escapes { .. }));
        assert!(matches!(e("/etc/passwd"), UriError::Absolute { .. }));
        assert!(matches!(e("http://host/x"), UriError::Absolute { .. }));
        assert!(matches!(e("%zz.bin"), UriError::BadPercentEncoding { .. }));
        assert!(matches!(e("%ff.bin"), UriError::BadPercentEncoding { .. }));
        assert_eq!(
            e("../x").to_string(),
            "URI '../x' escapes the input folder (refused)"
        );
        assert_eq!(
            e("/x").to_string(),
            "URI '/x' is absolute or has a scheme (refused)"
        );
    }

    #[test]
    fn input_paths_keep_their_text() {
        // Joined as written: an error names the file as the model wrote it, and a trailing `/`
        // still names a folder (a file there is not read as one).
        let base = Path::new("/m");
        let text = |uri| inside(base, uri, &INPUT).unwrap().into_os_string();
        assert_eq!(text("./b.bin"), "/m/./b.bin");
        assert_eq!(text("t/"), "/m/t/");
        // An encoded `/` in a reference is decoded before the split: a separator.
        assert_eq!(
            inside(base, "t%2Fa.png", &INPUT).unwrap(),
            Path::new("/m/t/a.png")
        );
        // Dot-files are fine in a model's folder.
        assert!(inside(base, ".textures/a.png", &INPUT).is_ok());
    }

    #[cfg(unix)]
    #[test]
    fn references_through_symlinks_leading_out_are_refused() {
        let (t, root) = setup();
        let outside = t.path().join("outside");
        std::os::unix::fs::symlink(outside.join("secret.json"), root.join("leak.json")).unwrap();
        std::os::unix::fs::symlink(&outside, root.join("leakdir")).unwrap();
        std::os::unix::fs::symlink(root.join("schema.json"), root.join("alias.json")).unwrap();
        for rules in [&INPUT, &TILESET] {
            let e = inside(&root, "leak.json", rules).unwrap_err();
            assert!(matches!(e, UriError::LeadsOutside { .. }), "{e}");
            let e = inside(&root, "leakdir/secret.json", rules).unwrap_err();
            assert!(matches!(e, UriError::LeadsOutside { .. }), "{e}");
            assert_eq!(
                inside(&root, "alias.json", rules).unwrap(),
                root.join("alias.json")
            );
        }
        let e = inside(&root, "leak.json", &TILESET).unwrap_err();
        assert_eq!(
            e.to_string(),
            "URI 'leak.json' leads outside the tileset's folder (refused)"
        );
        // A file that does not exist leads nowhere: reading it fails on its own.
        assert!(inside(&root, "missing.bin", &INPUT).is_ok());
    }

    #[test]
    fn a_tileset_may_climb_back_to_its_root_but_not_above() {
        let (_t, root) = setup();
        let tiles = root.join("tiles");
        let r = |base: &Path, uri| reference(&root, base, uri, &TILESET);
        assert_eq!(
            r(&tiles, "../schema.json").unwrap(),
            root.join("schema.json")
        );
        assert_eq!(r(&tiles, "./a.glb").unwrap(), tiles.join("a.glb"));
        assert_eq!(
            r(&root, "tiles/../schema.json").unwrap(),
            root.join("schema.json")
        );
        assert_eq!(r(&root, "a%20b.glb").unwrap(), root.join("a b.glb"));
        // A stray `%` is a literal here.
        assert_eq!(r(&root, "100%.glb").unwrap(), root.join("100%.glb"));
        for bad in [
            "../x",
            "../../x",
            "%2e%2e/x",
            "tiles/../../x",
            "/etc/passwd",
            "file:///etc/passwd",
            "a\\b",
            "%ff",
        ] {
            assert!(r(&root, bad).is_err(), "{bad} must be refused");
        }
        assert!(r(&tiles, "../../x").is_err());
        assert!(matches!(r(&root, "../x"), Err(UriError::Escapes { .. })));
    }

    #[test]
    fn request_paths() {
        let p = |raw| request_path(raw, &SERVED);
        assert_eq!(p("").unwrap(), PathBuf::new());
        assert_eq!(
            p("tiles/r0.glb").unwrap(),
            PathBuf::from("tiles").join("r0.glb")
        );
        assert_eq!(p("tiles/").unwrap(), PathBuf::from("tiles"));
        assert_eq!(p("a%20b.json").unwrap(), PathBuf::from("a b.json"));
        // Double encoding decodes once: "%2e%2e" is then a harmless literal file name.
        assert_eq!(p("%252e%252e").unwrap(), PathBuf::from("%2e%2e"));
    }

    #[test]
    fn request_paths_refuse_dot_dot_plain_or_encoded() {
        let escapes = |raw| matches!(request_path(raw, &SERVED), Err(UriError::Escapes { .. }));
        for raw in [
            "..",
            "../etc/passwd",
            "tiles/../../x",
            "tiles/./r0.glb",
            "%2e%2e/etc/passwd",
            "%2E%2E/etc/passwd",
            ".%2e/x",
            "tiles%2f..%2f..%2fx",
            "..%5c..%5cx",
            "%2Fetc%2Fpasswd",
            "C%5Cwindows",
        ] {
            assert!(escapes(raw), "{raw}");
        }
    }

    #[test]
    fn request_paths_refuse_absolute_bad_encoding_and_hidden() {
        let p = |raw| request_path(raw, &SERVED).unwrap_err();
        assert!(matches!(p("/etc/passwd"), UriError::Absolute { .. }));
        assert!(matches!(p("tiles//r0.glb"), UriError::Absolute { .. }));
        assert!(matches!(p("C:"), UriError::Absolute { .. }));
        assert!(matches!(p("a:b"), UriError::Absolute { .. }));
        // The `\` is refused before the drive.
        assert!(matches!(p("C:%5Cwindows"), UriError::Escapes { .. }));
        assert!(matches!(p("a%00b"), UriError::Nul { .. }));
        assert!(matches!(p("%ff%fe"), UriError::BadPercentEncoding { .. }));
        assert!(matches!(p(".git/config"), UriError::Hidden { .. }));
        assert!(matches!(p("tiles/.secret"), UriError::Hidden { .. }));
        // The first bad segment decides.
        assert!(matches!(p(".git/.."), UriError::Hidden { .. }));
        assert!(matches!(p("../.git"), UriError::Escapes { .. }));
        // Rules without the dot-file refusal serve them.
        let open = Rules {
            refuse_hidden: false,
            ..SERVED
        };
        assert_eq!(
            request_path(".well-known/x", &open).unwrap(),
            PathBuf::from(".well-known/x")
        );
    }

    #[test]
    fn hidden_references_are_refused_by_the_rules_that_say_so() {
        let strict = Rules {
            refuse_hidden: true,
            ..INPUT
        };
        let e = inside(Path::new("/m"), "t/.env", &strict).unwrap_err();
        assert!(matches!(e, UriError::Hidden { .. }), "{e}");
        assert!(inside(Path::new("/m"), "./t/a.png", &strict).is_ok());
    }

    #[test]
    fn resolve_inside_root_and_index() {
        let (_t, root) = setup();
        let r = |raw| resolve_request(&root, raw, "index.html", &SERVED);
        assert_eq!(r("tiles/a.glb").unwrap(), root.join("tiles/a.glb"));
        assert_eq!(r("").unwrap(), root.join("index.html"));
        assert!(matches!(r("tiles/b.glb"), Err(UriError::NotFound { .. })));
        // A folder without an index.
        assert!(matches!(r("tiles/"), Err(UriError::NotFound { .. })));
        assert!(matches!(r("tiles/a.glb/"), Err(UriError::NotFound { .. })));
    }

    #[cfg(unix)]
    #[test]
    fn requests_through_symlinks_leading_out_are_refused() {
        let (t, root) = setup();
        let outside = t.path().join("outside");
        std::os::unix::fs::symlink(outside.join("secret.json"), root.join("leak.json")).unwrap();
        std::os::unix::fs::symlink(&outside, root.join("leakdir")).unwrap();
        std::os::unix::fs::symlink(root.join("schema.json"), root.join("alias.json")).unwrap();
        std::os::unix::fs::symlink("/", root.join("slash")).unwrap();
        let r = |raw| resolve_request(&root, raw, "index.html", &SERVED);
        for raw in ["leak.json", "leakdir/secret.json", "slash/etc/passwd"] {
            assert!(
                matches!(r(raw), Err(UriError::LeadsOutside { .. })),
                "{raw}"
            );
        }
        // A symlink that stays inside the root is fine.
        assert_eq!(r("alias.json").unwrap(), root.join("schema.json"));
    }
}
