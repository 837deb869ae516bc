//! Request → reply, independent of the socket layer: routing onto the mounts, conditional
//! requests (`ETag` / `Last-Modified` → 304), `Range` (206 / 416), gzip and cache headers.

use crate::uri::confine::{self, SERVED};
use crate::uri::mime::{self, Compress};
use crate::uri::UriError;
use flate2::write::GzEncoder;
use std::collections::HashMap;
use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// Files smaller than this are never compressed (headers would eat the gain).
pub const GZIP_MIN_LEN: u64 = 256;
/// Files larger than this are sent as they are (compression happens in memory).
pub const GZIP_MAX_LEN: u64 = 64 << 20;
/// For `Compress::IfSmaller` types, the gzip body is used only if it saves at least this share.
pub const GZIP_MIN_SAVING: f64 = 0.10;
/// Memory kept for compressed bodies before the cache is emptied.
const GZIP_CACHE_BYTES: usize = 256 << 20;

/// Where a URL prefix is served from.
#[derive(Debug, Clone)]
pub struct Mount {
    /// URL prefix, starting and ending with `/` (`/` itself for the fallback mount).
    pub prefix: String,
    /// Canonical root directory.
    pub root: PathBuf,
    /// `Cache-Control` value for its files.
    pub cache_control: &'static str,
}

/// A reply body.
pub enum Body {
    Empty,
    Bytes(Arc<Vec<u8>>),
    /// `len` bytes of `file` starting at `offset`.
    File {
        file: File,
        offset: u64,
        len: u64,
    },
}

impl Body {
    /// A reader over the body (the file is positioned and limited).
    pub fn into_reader(self) -> std::io::Result<Box<dyn Read + Send>> {
        Ok(match self {
            Body::Empty => Box::new(std::io::empty()),
            Body::Bytes(b) => Box::new(std::io::Cursor::new(ArcBytes(b))),
            Body::File {
                mut file,
                offset,
                len,
            } => {
                use std::io::Seek;
                file.seek(std::io::SeekFrom::Start(offset))?;
                Box::new(file.take(len))
            }
        })
    }
}

struct ArcBytes(Arc<Vec<u8>>);
impl AsRef<[u8]> for ArcBytes {
    fn as_ref(&self) -> &[u8] {
        &self.0
    }
}

pub struct Reply {
    pub status: u16,
    pub headers: Vec<(&'static str, String)>,
    /// `Content-Length` to announce: the body's length, or for HEAD / 304 the length the GET /
    /// 200 would have had.
    pub length: u64,
    pub body: Body,
}

impl Reply {
    pub(crate) fn text(status: u16, msg: &str) -> Reply {
        let bytes = format!("{status} {msg}\n").into_bytes();
        Reply {
            status,
            headers: vec![
                ("Content-Type", "text/plain; charset=utf-8".into()),
                ("X-Content-Type-Options", "nosniff".into()),
                ("Cache-Control", "no-store".into()),
            ],
            length: bytes.len() as u64,
            body: Body::Bytes(Arc::new(bytes)),
        }
    }

    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }
}

struct GzEntry {
    etag: String,
    /// `None`: compression does not pay for this file.
    body: Option<Arc<Vec<u8>>>,
}

#[derive(Default)]
struct GzCache {
    map: HashMap<PathBuf, GzEntry>,
    bytes: usize,
}

/// The request handler shared by all worker threads.
pub struct Handler {
    mounts: Vec<Mount>,
    gz: Mutex<GzCache>,
}

/// What a request needs from its headers.
pub trait Headers {
    fn get(&self, name: &str) -> Option<&str>;
}

impl Headers for [(&str, &str)] {
    fn get(&self, name: &str) -> Option<&str> {
        self.iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| *v)
    }
}

impl Handler {
    /// `mounts` are tried longest prefix first.
    pub fn new(mut mounts: Vec<Mount>) -> Handler {
        mounts.sort_by_key(|m| std::cmp::Reverse(m.prefix.len()));
        Handler {
            mounts,
            gz: Mutex::new(GzCache::default()),
        }
    }

    pub fn handle<H: Headers + ?Sized>(&self, method: &str, target: &str, headers: &H) -> Reply {
        let head = match method {
            "GET" => false,
            "HEAD" => true,
            _ => {
                let mut r = Reply::text(405, "Method Not Allowed");
                r.headers.push(("Allow", "GET, HEAD".into()));
                return r;
            }
        };
        // Origin-form only ("/path?query"); no "*", no absolute-form.
        if !target.starts_with('/') {
            return Reply::text(400, "Bad Request");
        }
        let path_part = target.split(['?', '#']).next().unwrap_or("");
        // A mount prefix without its trailing slash: redirect, so relative URLs work.
        for m in &self.mounts {
            if m.prefix.len() > 1 && path_part == &m.prefix[..m.prefix.len() - 1] {
                let mut r = Reply::text(301, "Moved Permanently");
                r.headers.push(("Location", m.prefix.clone()));
                return r;
            }
        }
        let Some(mount) = self
            .mounts
            .iter()
            .find(|m| path_part.starts_with(m.prefix.as_str()))
        else {
            return Reply::text(404, "Not Found");
        };
        let rest = &path_part[mount.prefix.len()..];
        let file_path = match confine::resolve_request(&mount.root, rest, "index.html", &SERVED) {
            Ok(p) => p,
            Err(e) => {
                let (status, msg) = refusal_status(&e);
                return Reply::text(status, msg);
            }
        };
        match self.serve_file(&file_path, mount.cache_control, head, headers) {
            Ok(r) => r,
            Err(_) => Reply::text(500, "Internal Server Error"),
        }
    }

    fn serve_file<H: Headers + ?Sized>(
        &self,
        file_path: &Path,
        cache_control: &'static str,
        head: bool,
        headers: &H,
    ) -> std::io::Result<Reply> {
        let file = File::open(file_path)?;
        let meta = file.metadata()?;
        let len = meta.len();
        let mtime = meta.modified().unwrap_or(UNIX_EPOCH);
        let mtime_ns = mtime
            .duration_since(UNIX_EPOCH)
            .unwrap_or_default()
            .as_nanos();
        let id = format!("{len:x}-{mtime_ns:x}");
        let etag_identity = format!("\"{id}\"");
        let etag_gzip = format!("\"{id}-gz\"");
        let last_modified = httpdate::fmt_http_date(mtime);
        let (content_type, policy) = mime::for_path(file_path);

        let range_header = headers.get("Range");
        let wants_gzip = range_header.is_none()
            && policy != Compress::Never
            && (GZIP_MIN_LEN..=GZIP_MAX_LEN).contains(&len)
            && accepts_gzip(headers.get("Accept-Encoding"));
        let gz_body = if wants_gzip {
            self.gzipped(file_path, &etag_gzip, policy, file.try_clone()?)?
        } else {
            None
        };
        let etag = if gz_body.is_some() {
            &etag_gzip
        } else {
            &etag_identity
        };

        let mut hdrs: Vec<(&'static str, String)> = vec![
            ("Content-Type", content_type.into()),
            ("ETag", etag.clone()),
            ("Last-Modified", last_modified.clone()),
            ("Cache-Control", cache_control.into()),
            ("Accept-Ranges", "bytes".into()),
            ("X-Content-Type-Options", "nosniff".into()),
        ];
        if policy != Compress::Never {
            hdrs.push(("Vary", "Accept-Encoding".into()));
        }
        if gz_body.is_some() {
            hdrs.push(("Content-Encoding", "gzip".into()));
        }
        let full_len = gz_body.as_ref().map_or(len, |b| b.len() as u64);

        // Conditional GET: If-None-Match wins over If-Modified-Since (RFC 9110 13.2.2).
        let not_modified = match headers.get("If-None-Match") {
            Some(inm) => etag_matches(inm, etag),
            None => headers
                .get("If-Modified-Since")
                .and_then(|d| httpdate::parse_http_date(d).ok())
                .is_some_and(|since| truncate_to_secs(mtime) <= since),
        };
        if not_modified {
            // 304 keeps the validators and caching headers, but no body/type.
            hdrs.retain(|(k, _)| *k != "Content-Type" && *k != "Content-Encoding");
            return Ok(Reply {
                status: 304,
                headers: hdrs,
                length: full_len,
                body: Body::Empty,
            });
        }

        if let Some(range) = range_header {
            let if_range_ok = match headers.get("If-Range") {
                None => true,
                Some(v) if v.trim_start().starts_with('"') => v.trim() == etag_identity,
                Some(v) if v.trim_start().starts_with("W/") => false,
                Some(v) => httpdate::parse_http_date(v).is_ok_and(|d| d == truncate_to_secs(mtime)),
            };
            if if_range_ok {
                match parse_range(range, len) {
                    RangeSpec::Ignore => {}
                    RangeSpec::Unsatisfiable => {
                        let mut r = Reply::text(416, "Range Not Satisfiable");
                        r.headers.push(("Content-Range", format!("bytes */{len}")));
                        r.headers.push(("Accept-Ranges", "bytes".into()));
                        return Ok(r);
                    }
                    RangeSpec::Bytes(start, end) => {
                        let n = end - start + 1;
                        hdrs.push(("Content-Range", format!("bytes {start}-{end}/{len}")));
                        return Ok(Reply {
                            status: 206,
                            headers: hdrs,
                            length: n,
                            body: if head {
                                Body::Empty
                            } else {
                                Body::File {
                                    file,
                                    offset: start,
                                    len: n,
                                }
                            },
                        });
                    }
                }
            }
        }

        let body = if head {
            Body::Empty
        } else if let Some(b) = gz_body {
            Body::Bytes(b)
        } else {
            Body::File {
                file,
                offset: 0,
                len,
            }
        };
        Ok(Reply {
            status: 200,
            headers: hdrs,
            length: full_len,
            body,
        })
    }

    /// The gzip body of a file, from the cache or compressed now; `None` when it does not pay.
    fn gzipped(
        &self,
        file_path: &Path,
        etag: &str,
        policy: Compress,
        mut file: File,
    ) -> std::io::Result<Option<Arc<Vec<u8>>>> {
        if let Some(e) = self
            .gz
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .map
            .get(file_path)
        {
            if e.etag == etag {
                return Ok(e.body.clone());
            }
        }
        let mut raw = Vec::new();
        file.read_to_end(&mut raw)?;
        // Binaries (GLB...) at level 1: on real tiles nearly the size of the default level, for
        // less time (docs/benchmarks.md). Text (compressed once, then cached) at the default level.
        let level = match policy {
            Compress::Always => flate2::Compression::default(),
            _ => flate2::Compression::fast(),
        };
        let mut enc = GzEncoder::new(Vec::with_capacity(raw.len() / 3), level);
        enc.write_all(&raw)?;
        let packed = enc.finish()?;
        let pays = match policy {
            Compress::Always => packed.len() < raw.len(),
            _ => (packed.len() as f64) <= (raw.len() as f64) * (1.0 - GZIP_MIN_SAVING),
        };
        let body = pays.then(|| Arc::new(packed));
        let mut cache = self.gz.lock().unwrap_or_else(|p| p.into_inner());
        let add = body.as_ref().map_or(0, |b| b.len());
        if cache.bytes + add > GZIP_CACHE_BYTES {
            cache.map.clear();
            cache.bytes = 0;
        }
        let old = cache.map.insert(
            file_path.to_path_buf(),
            GzEntry {
                etag: etag.to_string(),
                body: body.clone(),
            },
        );
        let freed = old.and_then(|o| o.body).map_or(0, |b| b.len());
        cache.bytes = (cache.bytes + add).saturating_sub(freed);
        Ok(body)
    }
}

/// The status and text of a refused request path: a malformed or climbing path is the client's
/// mistake (400), a dot-file or a symlink out of the root is there but not served (403).
fn refusal_status(e: &UriError) -> (u16, &'static str) {
    match e {
        UriError::NotFound { .. } => (404, "Not Found"),
        UriError::Hidden { .. } | UriError::LeadsOutside { .. } => (403, "Forbidden"),
        _ => (400, "Bad Request"),
    }
}

fn truncate_to_secs(t: SystemTime) -> SystemTime {
    let secs = t.duration_since(UNIX_EPOCH).unwrap_or_default().as_secs();
    UNIX_EPOCH + Duration::from_secs(secs)
}

/// Whether an `Accept-Encoding` value admits gzip (`gzip`, `x-gzip` or `*` with q > 0).
pub fn accepts_gzip(value: Option<&str>) -> bool {
    let Some(value) = value else { return false };
    let mut star = None;
    for item in value.split(',') {
        let mut parts = item.split(';');
        let coding = parts.next().unwrap_or("").trim().to_ascii_lowercase();
        let q = parts
            .filter_map(|p| {
                let p = p.trim();
                p.strip_prefix("q=").or_else(|| p.strip_prefix("Q="))
            })
            .next()
            .and_then(|q| q.trim().parse::<f32>().ok())
            .unwrap_or(1.0);
        match coding.as_str() {
            "gzip" | "x-gzip" => return q > 0.0,
            "*" => star = Some(q > 0.0),
            _ => {}
        }
    }
    star.unwrap_or(false)
}

/// `If-None-Match` against the current entity tag (weak comparison, `*` matches).
pub fn etag_matches(if_none_match: &str, etag: &str) -> bool {
    let strip = |t: &str| t.trim().trim_start_matches("W/").to_string();
    let current = strip(etag);
    if_none_match
        .split(',')
        .any(|t| t.trim() == "*" || strip(t) == current)
}

#[derive(Debug, PartialEq, Eq)]
pub enum RangeSpec {
    /// Absent, malformed or multi-range: send the whole file.
    Ignore,
    Unsatisfiable,
    /// Inclusive byte positions.
    Bytes(u64, u64),
}

/// Parses a single `bytes=` range against a file of `len` bytes.
pub fn parse_range(value: &str, len: u64) -> RangeSpec {
    let value = value.trim();
    let Some(spec) = value
        .get(..6)
        .filter(|p| p.eq_ignore_ascii_case("bytes="))
        .map(|_| value[6..].trim())
    else {
        return RangeSpec::Ignore;
    };
    if spec.contains(',') {
        return RangeSpec::Ignore; // multipart/byteranges is not worth it here
    }
    let Some((a, b)) = spec.split_once('-') else {
        return RangeSpec::Ignore;
    };
    let (a, b) = (a.trim(), b.trim());
    let num = |s: &str| -> Option<u64> {
        (!s.is_empty() && s.bytes().all(|c| c.is_ascii_digit()))
            .then(|| s.parse().ok())
            .flatten()
    };
    if a.is_empty() {
        // Suffix range: the last N bytes.
        let Some(n) = num(b) else {
            return RangeSpec::Ignore;
        };
        if n == 0 || len == 0 {
            return RangeSpec::Unsatisfiable;
        }
        return RangeSpec::Bytes(len - n.min(len), len - 1);
    }
    let Some(start) = num(a) else {
        return RangeSpec::Ignore;
    };
    let end = if b.is_empty() {
        u64::MAX
    } else {
        match num(b) {
            Some(e) if e >= start => e,
            _ => return RangeSpec::Ignore,
        }
    };
    if start >= len {
        return RangeSpec::Unsatisfiable;
    }
    RangeSpec::Bytes(start, end.min(len - 1))
}

#[cfg(test)]
mod tests {
    use super::super::tests_support::TempDir;
    use super::*;
    use flate2::read::GzDecoder;

    fn body_bytes(r: Reply) -> Vec<u8> {
        let mut out = Vec::new();
        r.body.into_reader().unwrap().read_to_end(&mut out).unwrap();
        out
    }

    struct Fixture {
        _t: TempDir,
        h: Handler,
        json: Vec<u8>,
        glb: Vec<u8>,
    }

    fn fixture() -> Fixture {
        let t = TempDir::new("handler");
        let tiles = t.path().join("tileset");
        let viewer = t.path().join("viewer");
        std::fs::create_dir_all(tiles.join("tiles")).unwrap();
        std::fs::create_dir_all(&viewer).unwrap();
        let json = format!(
            "{{\"asset\":{{\"version\":\"1.1\"}},\"pad\":\"{}\"}}",
            "ab".repeat(2000)
        )
        .into_bytes();
        std::fs::write(tiles.join("tileset.json"), &json).unwrap();
        // Pseudo-random bytes: gzip cannot shrink them.
        let mut x: u32 = 12345;
        let glb: Vec<u8> = (0..100_000)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                (x >> 24) as u8
            })
            .collect();
        std::fs::write(tiles.join("tiles/r0.glb"), &glb).unwrap();
        std::fs::write(
            viewer.join("index.html"),
            b"<!doctype html><title>v</title>",
        )
        .unwrap();
        let h = Handler::new(vec![
            Mount {
                prefix: "/tileset/".into(),
                root: tiles.canonicalize().unwrap(),
                cache_control: "no-cache",
            },
            Mount {
                prefix: "/".into(),
                root: viewer.canonicalize().unwrap(),
                cache_control: "no-cache",
            },
        ]);
        Fixture {
            _t: t,
            h,
            json,
            glb,
        }
    }

    const NONE: &[(&str, &str)] = &[];

    #[test]
    fn get_head_and_types() {
        let f = fixture();
        let r = f.h.handle("GET", "/tileset/tileset.json", NONE);
        assert_eq!(r.status, 200);
        assert_eq!(r.header("Content-Type"), Some("application/json"));
        assert_eq!(r.header("Cache-Control"), Some("no-cache"));
        assert!(r.header("ETag").is_some() && r.header("Last-Modified").is_some());
        assert_eq!(r.length, f.json.len() as u64);
        assert_eq!(body_bytes(r), f.json);

        let r = f.h.handle("HEAD", "/tileset/tiles/r0.glb?v=1", NONE);
        assert_eq!(r.status, 200);
        assert_eq!(r.header("Content-Type"), Some("model/gltf-binary"));
        assert_eq!(r.length, f.glb.len() as u64);
        assert!(body_bytes(r).is_empty());

        let r = f.h.handle("GET", "/", NONE);
        assert_eq!(r.status, 200);
        assert_eq!(r.header("Content-Type"), Some("text/html; charset=utf-8"));
    }

    #[test]
    fn the_update_cache_is_never_served() {
        let f = fixture();
        let state = f._t.path().join("tileset").join(crate::update::STATE_FILE);
        std::fs::create_dir_all(state.parent().unwrap()).unwrap();
        std::fs::write(&state, b"{}").unwrap();
        for path in [
            "/tileset/.bimtiles/update-state.json",
            "/tileset/%2ebimtiles/update-state.json",
            "/tileset/.bimtiles/",
        ] {
            assert_eq!(f.h.handle("GET", path, NONE).status, 403, "{path}");
            assert_eq!(f.h.handle("HEAD", path, NONE).status, 403, "{path}");
        }
        assert_eq!(f.h.handle("GET", "/tileset/tileset.json", NONE).status, 200);
    }

    #[test]
    fn errors() {
        let f = fixture();
        assert_eq!(f.h.handle("POST", "/", NONE).status, 405);
        assert_eq!(f.h.handle("GET", "*", NONE).status, 400);
        assert_eq!(f.h.handle("GET", "http://x/", NONE).status, 400);
        assert_eq!(f.h.handle("GET", "/nope.js", NONE).status, 404);
        assert_eq!(
            f.h.handle("GET", "/tileset/../viewer/index.html", NONE)
                .status,
            400
        );
        assert_eq!(
            f.h.handle("GET", "/tileset/%2e%2e/viewer/index.html", NONE)
                .status,
            400
        );
        assert_eq!(f.h.handle("GET", "/tileset//etc/passwd", NONE).status, 400);
        assert_eq!(f.h.handle("GET", "//etc/passwd", NONE).status, 400);
        assert_eq!(f.h.handle("GET", "/.hidden", NONE).status, 403);
        let r = f.h.handle("GET", "/tileset", NONE);
        assert_eq!(r.status, 301);
        assert_eq!(r.header("Location"), Some("/tileset/"));
    }

    #[test]
    fn gzip_for_json_not_for_incompressible_glb() {
        let f = fixture();
        let ae: &[(&str, &str)] = &[("Accept-Encoding", "gzip, deflate, br")];
        let r = f.h.handle("GET", "/tileset/tileset.json", ae);
        assert_eq!(r.header("Content-Encoding"), Some("gzip"));
        assert_eq!(r.header("Vary"), Some("Accept-Encoding"));
        assert!(r.header("ETag").unwrap().ends_with("-gz\""));
        assert!(r.length < f.json.len() as u64 / 4);
        let packed = body_bytes(r);
        let mut out = Vec::new();
        GzDecoder::new(&packed[..]).read_to_end(&mut out).unwrap();
        assert_eq!(out, f.json);
        // Second time from the cache, same bytes.
        let r2 = f.h.handle("GET", "/tileset/tileset.json", ae);
        assert_eq!(body_bytes(r2), packed);

        let r = f.h.handle("GET", "/tileset/tiles/r0.glb", ae);
        assert_eq!(r.header("Content-Encoding"), None);
        assert_eq!(r.length, f.glb.len() as u64);

        // q=0 refuses gzip.
        let no: &[(&str, &str)] = &[("Accept-Encoding", "gzip;q=0, identity")];
        assert_eq!(
            f.h.handle("GET", "/tileset/tileset.json", no)
                .header("Content-Encoding"),
            None
        );
    }

    #[test]
    fn conditional_requests() {
        let f = fixture();
        let r = f.h.handle("GET", "/tileset/tiles/r0.glb", NONE);
        let etag = r.header("ETag").unwrap().to_string();
        let lm = r.header("Last-Modified").unwrap().to_string();
        let inm = [("If-None-Match", etag.as_str())];
        let r = f.h.handle("GET", "/tileset/tiles/r0.glb", &inm[..]);
        assert_eq!(r.status, 304);
        assert_eq!(r.header("ETag"), Some(etag.as_str()));
        assert!(body_bytes(r).is_empty());
        let weak = format!("W/{etag}");
        let r = f.h.handle(
            "GET",
            "/tileset/tiles/r0.glb",
            &[("If-None-Match", weak.as_str())][..],
        );
        assert_eq!(r.status, 304);
        let r = f.h.handle(
            "GET",
            "/tileset/tiles/r0.glb",
            &[("If-None-Match", "\"other\"")][..],
        );
        assert_eq!(r.status, 200);
        let r = f.h.handle(
            "GET",
            "/tileset/tiles/r0.glb",
            &[("If-Modified-Since", lm.as_str())][..],
        );
        assert_eq!(r.status, 304);
        let r = f.h.handle(
            "GET",
            "/tileset/tiles/r0.glb",
            &[("If-Modified-Since", "Thu, 01 Jan 1970 00:00:00 GMT")][..],
        );
        assert_eq!(r.status, 200);
        // The gzip variant has its own tag: an identity tag does not validate it.
        let h = [
            ("If-None-Match", etag.as_str()),
            ("Accept-Encoding", "gzip"),
        ];
        assert_eq!(
            f.h.handle("GET", "/tileset/tiles/r0.glb", &h[..]).status,
            304
        ); // glb stays identity
        let r = f.h.handle(
            "GET",
            "/tileset/tileset.json",
            &[("Accept-Encoding", "gzip")][..],
        );
        let gz_tag = r.header("ETag").unwrap().to_string();
        let h = [
            ("If-None-Match", gz_tag.as_str()),
            ("Accept-Encoding", "gzip"),
        ];
        assert_eq!(
            f.h.handle("GET", "/tileset/tileset.json", &h[..]).status,
            304
        );
        let h = [("If-None-Match", gz_tag.as_str())];
        assert_eq!(
            f.h.handle("GET", "/tileset/tileset.json", &h[..]).status,
            200
        );
    }

    #[test]
    fn ranges() {
        let f = fixture();
        let n = f.glb.len() as u64;
        let get = |range: &str| {
            f.h.handle("GET", "/tileset/tiles/r0.glb", &[("Range", range)][..])
        };
        let r = get("bytes=10-19");
        assert_eq!(r.status, 206);
        assert_eq!(
            r.header("Content-Range"),
            Some(format!("bytes 10-19/{n}").as_str())
        );
        assert_eq!(body_bytes(r), f.glb[10..20]);
        let r = get("bytes=-5");
        assert_eq!(body_bytes(r), f.glb[f.glb.len() - 5..]);
        let r = get(&format!("bytes={}-", n - 3));
        assert_eq!(r.status, 206);
        assert_eq!(body_bytes(r), f.glb[f.glb.len() - 3..]);
        let r = get(&format!("bytes={n}-"));
        assert_eq!(r.status, 416);
        assert_eq!(
            r.header("Content-Range"),
            Some(format!("bytes */{n}").as_str())
        );
        assert_eq!(get("bytes=0-1,5-6").status, 200);
        assert_eq!(get("items=0-1").status, 200);
        // Range disables gzip.
        let h = [("Range", "bytes=0-9"), ("Accept-Encoding", "gzip")];
        let r = f.h.handle("GET", "/tileset/tileset.json", &h[..]);
        assert_eq!(r.status, 206);
        assert_eq!(r.header("Content-Encoding"), None);
        assert_eq!(body_bytes(r), f.json[..10]);
        // If-Range with a stale tag: whole file.
        let h = [("Range", "bytes=0-9"), ("If-Range", "\"stale\"")];
        assert_eq!(
            f.h.handle("GET", "/tileset/tiles/r0.glb", &h[..]).status,
            200
        );
    }

    #[test]
    fn range_parser() {
        assert_eq!(parse_range("bytes=0-0", 10), RangeSpec::Bytes(0, 0));
        assert_eq!(parse_range("bytes=5-100", 10), RangeSpec::Bytes(5, 9));
        assert_eq!(parse_range("bytes=-100", 10), RangeSpec::Bytes(0, 9));
        assert_eq!(parse_range("bytes=-0", 10), RangeSpec::Unsatisfiable);
        assert_eq!(parse_range("bytes=0-", 0), RangeSpec::Unsatisfiable);
        assert_eq!(parse_range("bytes=5-2", 10), RangeSpec::Ignore);
        assert_eq!(parse_range("bytes=a-2", 10), RangeSpec::Ignore);
        assert_eq!(parse_range("bytes=+1-2", 10), RangeSpec::Ignore);
        assert_eq!(parse_range("bytes", 10), RangeSpec::Ignore);
    }

    #[test]
    fn accept_encoding_parser() {
        assert!(accepts_gzip(Some("gzip")));
        assert!(accepts_gzip(Some("br, gzip;q=0.5")));
        assert!(accepts_gzip(Some("*")));
        assert!(!accepts_gzip(Some("gzip;q=0")));
        assert!(!accepts_gzip(Some("*;q=0")));
        assert!(!accepts_gzip(Some("br, deflate")));
        assert!(!accepts_gzip(None));
    }
}
