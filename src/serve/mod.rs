//! `bimtiles serve`: a small static HTTP server for a tileset and the CesiumJS viewer page.
//!
//! URL layout:
//! - `/tileset/...` → `tileset_dir` (the converter's output: `tileset.json`, `tiles/*.glb`)
//! - `/cesium/...`  → `cesium_dir` (CesiumJS's `Build/Cesium`), when given
//! - `/...`         → `viewer_dir` (our `index.html`, `viewer.js`, `sw.js`)
//!
//! Only files inside those roots are served (no `..`, encoded or not, no absolute paths, no
//! dot-files, no symlink leading out). GET and HEAD; `ETag` / `Last-Modified` with 304;
//! single `Range` requests (206/416); gzip for text types and for binaries where it saves at
//! least 10% (decided per file and cached in memory). Binds to loopback unless told otherwise.
//!
//! ```no_run
//! # use bimtiles::serve::*;
//! let mut opts = ServeOptions::new("out/tileset", "viewer");
//! opts.cesium_dir = Some("tools/node_modules/cesium/Build/Cesium".into());
//! opts.port = 0; // any free port
//! let server = start(&opts)?;
//! println!("{}", server.url());
//! server.shutdown();
//! # Ok::<(), ServeError>(())
//! ```

mod handler;
mod mime;
mod path;

pub use handler::{Handler, Mount, Reply};

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

/// `Cache-Control` for the tileset and the viewer page: always revalidate (cheap 304s), so a
/// re-converted tileset or an edited page shows up at once.
pub const CACHE_REVALIDATE: &str = "no-cache";
/// `Cache-Control` for CesiumJS's build, which only changes with the npm package.
pub const CACHE_CESIUM: &str = "public, max-age=86400";

/// What to serve and where.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    /// The tileset folder (holding `tileset.json`), served under `/tileset/`.
    pub tileset_dir: PathBuf,
    /// The viewer page folder (`index.html`...), served under `/`.
    pub viewer_dir: PathBuf,
    /// CesiumJS's `Build/Cesium` folder, served under `/cesium/`; `None`: not mounted.
    pub cesium_dir: Option<PathBuf>,
    /// Address to bind; default `127.0.0.1`.
    pub host: String,
    /// Port; default 8080; 0 picks a free one (see [`ServerHandle::addr`]).
    pub port: u16,
    /// Worker threads answering requests; default 8.
    pub threads: usize,
    /// Print one line per request to stderr.
    pub log_requests: bool,
}

impl ServeOptions {
    pub fn new(tileset_dir: impl Into<PathBuf>, viewer_dir: impl Into<PathBuf>) -> ServeOptions {
        ServeOptions {
            tileset_dir: tileset_dir.into(),
            viewer_dir: viewer_dir.into(),
            cesium_dir: None,
            host: "127.0.0.1".into(),
            port: 8080,
            threads: 8,
            log_requests: false,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("{what} folder {path}: {source}")]
    Root {
        what: &'static str,
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{0}: no tileset.json in this folder")]
    NoTileset(PathBuf),
    #[error("CesiumJS not found at {0} (install it: cd tools && npm ci)")]
    NoCesium(PathBuf),
    #[error("cannot listen on {addr}: {message}")]
    Bind { addr: String, message: String },
    #[error("server: {0}")]
    Io(#[from] std::io::Error),
}

/// A running server. Dropping it (or [`ServerHandle::shutdown`]) stops it.
pub struct ServerHandle {
    addr: SocketAddr,
    server: Arc<tiny_http::Server>,
    stop: Arc<AtomicBool>,
    workers: Vec<JoinHandle<()>>,
}

impl ServerHandle {
    /// The bound address (with the real port when 0 was asked for).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// `http://HOST:PORT/`, the viewer page.
    pub fn url(&self) -> String {
        format!("http://{}/", self.addr)
    }

    /// Blocks until the server stops (it does not stop by itself: for `serve`).
    pub fn wait(mut self) {
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }

    /// Stops accepting, lets the workers finish their current request, and joins them.
    pub fn shutdown(mut self) {
        self.stop_workers();
    }

    fn stop_workers(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        for _ in 0..self.workers.len() {
            self.server.unblock();
        }
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }
}

impl Drop for ServerHandle {
    fn drop(&mut self) {
        if !self.workers.is_empty() {
            self.stop_workers();
        }
    }
}

fn canonical_root(what: &'static str, path: &Path) -> Result<PathBuf, ServeError> {
    let canon = path.canonicalize().map_err(|source| ServeError::Root {
        what,
        path: path.to_path_buf(),
        source,
    })?;
    if !canon.is_dir() {
        return Err(ServeError::Root {
            what,
            path: path.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a folder"),
        });
    }
    Ok(canon)
}

/// The handler for these options (roots checked and made canonical).
pub fn handler(opts: &ServeOptions) -> Result<Handler, ServeError> {
    let tileset = canonical_root("tileset", &opts.tileset_dir)?;
    if !tileset.join("tileset.json").is_file() {
        return Err(ServeError::NoTileset(opts.tileset_dir.clone()));
    }
    let viewer = canonical_root("viewer", &opts.viewer_dir)?;
    let mut mounts = vec![
        Mount {
            prefix: "/tileset/".into(),
            root: tileset,
            cache_control: CACHE_REVALIDATE,
        },
        Mount {
            prefix: "/".into(),
            root: viewer,
            cache_control: CACHE_REVALIDATE,
        },
    ];
    if let Some(c) = &opts.cesium_dir {
        if !c.join("Cesium.js").is_file() {
            return Err(ServeError::NoCesium(c.clone()));
        }
        mounts.push(Mount {
            prefix: "/cesium/".into(),
            root: canonical_root("cesium", c)?,
            cache_control: CACHE_CESIUM,
        });
    }
    Ok(Handler::new(mounts))
}

/// Starts the server in background threads and returns at once (tests: port 0, then
/// [`ServerHandle::addr`]).
pub fn start(opts: &ServeOptions) -> Result<ServerHandle, ServeError> {
    let handler = Arc::new(handler(opts)?);
    let bind = format!("{}:{}", bracket_v6(&opts.host), opts.port);
    let server = tiny_http::Server::http(bind.as_str()).map_err(|e| ServeError::Bind {
        addr: bind.clone(),
        message: e.to_string(),
    })?;
    let addr = server
        .server_addr()
        .to_ip()
        .ok_or_else(|| ServeError::Bind {
            addr: bind.clone(),
            message: "not an IP socket".into(),
        })?;
    let server = Arc::new(server);
    let stop = Arc::new(AtomicBool::new(false));
    let workers = (0..opts.threads.max(1))
        .map(|i| {
            let (server, stop, handler) = (server.clone(), stop.clone(), handler.clone());
            let log = opts.log_requests;
            std::thread::Builder::new()
                .name(format!("bimtiles-serve-{i}"))
                .spawn(move || worker(&server, &stop, &handler, log))
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(ServerHandle {
        addr,
        server,
        stop,
        workers,
    })
}

/// Serves until the process is killed, after printing the viewer's URL on stdout.
pub fn serve(opts: &ServeOptions) -> Result<(), ServeError> {
    let handle = start(opts)?;
    if !handle.addr().ip().is_loopback() {
        eprintln!(
            "warning: listening on {}, reachable from other machines",
            handle.addr()
        );
    }
    println!(
        "Serving {} at {}  (Ctrl-C to stop)",
        opts.tileset_dir.display(),
        handle.url()
    );
    use std::io::Write;
    let _ = std::io::stdout().flush();
    handle.wait();
    Ok(())
}

fn bracket_v6(host: &str) -> String {
    if host.contains(':') && !host.starts_with('[') {
        format!("[{host}]")
    } else {
        host.to_string()
    }
}

fn worker(server: &tiny_http::Server, stop: &AtomicBool, handler: &Handler, log: bool) {
    loop {
        match server.recv() {
            Ok(rq) => respond(handler, rq, log),
            Err(_) if stop.load(Ordering::SeqCst) => return,
            Err(_) => std::thread::sleep(Duration::from_millis(10)),
        }
        if stop.load(Ordering::SeqCst) {
            return;
        }
    }
}

struct TinyHeaders<'a>(&'a [tiny_http::Header]);

impl handler::Headers for TinyHeaders<'_> {
    fn get(&self, name: &str) -> Option<&str> {
        self.0
            .iter()
            .find(|h| h.field.as_str().as_str().eq_ignore_ascii_case(name))
            .map(|h| h.value.as_str())
    }
}

fn respond(handler: &Handler, rq: tiny_http::Request, log: bool) {
    let method = rq.method().as_str().to_string();
    let reply = handler.handle(&method, rq.url(), &TinyHeaders(rq.headers()));
    if log {
        eprintln!("{} {} {} {}", method, rq.url(), reply.status, reply.length);
    }
    let headers = reply
        .headers
        .iter()
        .filter_map(|(k, v)| tiny_http::Header::from_bytes(k.as_bytes(), v.as_bytes()).ok())
        .collect::<Vec<_>>();
    let (status, length) = (reply.status, reply.length);
    let reader = match reply.body.into_reader() {
        Ok(r) => r,
        Err(_) => {
            let _ = rq.respond(tiny_http::Response::empty(500));
            return;
        }
    };
    let response = tiny_http::Response::new(
        tiny_http::StatusCode(status),
        headers,
        reader,
        Some(length as usize),
        None,
    )
    // Always `Content-Length` (tiny_http would switch to chunked above 32 KiB).
    .with_chunked_threshold(usize::MAX);
    let _ = rq.respond(response); // the client may have gone: nothing to do
}

#[cfg(test)]
pub(crate) mod tests_support {
    use std::path::{Path, PathBuf};

    /// A temporary folder removed on drop (no extra dev-dependency).
    pub struct TempDir(PathBuf);

    impl TempDir {
        pub fn new(tag: &str) -> TempDir {
            use std::sync::atomic::{AtomicUsize, Ordering};
            static N: AtomicUsize = AtomicUsize::new(0);
            let p = std::env::temp_dir().join(format!(
                "bimtiles-serve-{tag}-{}-{}",
                std::process::id(),
                N.fetch_add(1, Ordering::SeqCst)
            ));
            let _ = std::fs::remove_dir_all(&p);
            std::fs::create_dir_all(&p).unwrap();
            TempDir(p)
        }
        pub fn path(&self) -> &Path {
            &self.0
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::tests_support::TempDir;
    use super::*;
    use std::io::{Read, Write};
    use std::net::TcpStream;

    fn setup() -> (TempDir, ServeOptions) {
        let t = TempDir::new("mod");
        let ts = t.path().join("ts");
        std::fs::create_dir_all(ts.join("tiles")).unwrap();
        std::fs::write(
            ts.join("tileset.json"),
            "{\"asset\":{\"version\":\"1.1\"}}".repeat(50),
        )
        .unwrap();
        std::fs::write(ts.join("tiles/a.glb"), vec![7u8; 100_000]).unwrap();
        std::fs::create_dir_all(t.path().join("viewer")).unwrap();
        std::fs::write(t.path().join("viewer/index.html"), "<!doctype html>").unwrap();
        std::fs::create_dir_all(t.path().join("cesium/Workers")).unwrap();
        std::fs::write(
            t.path().join("cesium/Cesium.js"),
            "var Cesium={};".repeat(100),
        )
        .unwrap();
        std::fs::write(t.path().join("secret.txt"), "no").unwrap();
        let mut o = ServeOptions::new(ts, t.path().join("viewer"));
        o.cesium_dir = Some(t.path().join("cesium"));
        o.port = 0;
        o.threads = 2;
        (t, o)
    }

    /// One raw HTTP/1.1 exchange; returns (status line + headers, body).
    fn raw(addr: SocketAddr, request: &str) -> (String, Vec<u8>) {
        let mut s = TcpStream::connect(addr).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        s.write_all(request.as_bytes()).unwrap();
        let mut buf = Vec::new();
        s.read_to_end(&mut buf).unwrap();
        let split = buf.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
        let head = String::from_utf8(buf[..split].to_vec()).unwrap();
        (head, buf[split + 4..].to_vec())
    }

    fn req(method: &str, path: &str, extra: &str) -> String {
        format!("{method} {path} HTTP/1.1\r\nHost: localhost\r\n{extra}Connection: close\r\n\r\n")
    }

    fn header<'a>(head: &'a str, name: &str) -> Option<&'a str> {
        head.lines().skip(1).find_map(|l| {
            let (k, v) = l.split_once(':')?;
            k.eq_ignore_ascii_case(name).then(|| v.trim())
        })
    }

    #[test]
    fn defaults_bind_to_loopback() {
        let o = ServeOptions::new("a", "b");
        assert_eq!(o.host, "127.0.0.1");
        assert_eq!(o.port, 8080);
        let (_t, o) = setup();
        let h = start(&o).unwrap();
        assert!(h.addr().ip().is_loopback());
        assert_ne!(h.addr().port(), 0);
        assert!(h.url().starts_with("http://127.0.0.1:"));
        h.shutdown();
    }

    #[test]
    fn missing_roots_are_errors() {
        let (t, mut o) = setup();
        o.tileset_dir = t.path().join("nope");
        assert!(matches!(start(&o), Err(ServeError::Root { .. })));
        o.tileset_dir = t.path().join("viewer");
        assert!(matches!(start(&o), Err(ServeError::NoTileset(_))));
        o.tileset_dir = t.path().join("ts");
        o.cesium_dir = Some(t.path().join("viewer"));
        let e = start(&o).err().unwrap();
        assert!(matches!(e, ServeError::NoCesium(_)));
        assert!(e.to_string().contains("npm ci"), "{e}");
    }

    #[test]
    fn over_the_wire() {
        let (_t, o) = setup();
        let h = start(&o).unwrap();
        let a = h.addr();

        let (head, body) = raw(a, &req("GET", "/tileset/tiles/a.glb", ""));
        assert!(head.starts_with("HTTP/1.1 200"), "{head}");
        assert_eq!(header(&head, "Content-Type"), Some("model/gltf-binary"));
        assert_eq!(header(&head, "Content-Length"), Some("100000"));
        assert_eq!(header(&head, "Transfer-Encoding"), None);
        assert_eq!(body.len(), 100_000);
        let etag = header(&head, "ETag").unwrap().to_string();

        let (head, body) = raw(a, &req("HEAD", "/tileset/tiles/a.glb", ""));
        assert!(head.starts_with("HTTP/1.1 200"), "{head}");
        assert_eq!(header(&head, "Content-Length"), Some("100000"));
        assert!(body.is_empty());

        let (head, body) = raw(
            a,
            &req(
                "GET",
                "/tileset/tiles/a.glb",
                &format!("If-None-Match: {etag}\r\n"),
            ),
        );
        assert!(head.starts_with("HTTP/1.1 304"), "{head}");
        assert!(body.is_empty());

        let (head, body) = raw(
            a,
            &req("GET", "/tileset/tiles/a.glb", "Range: bytes=100-199\r\n"),
        );
        assert!(head.starts_with("HTTP/1.1 206"), "{head}");
        assert_eq!(header(&head, "Content-Range"), Some("bytes 100-199/100000"));
        assert_eq!(body.len(), 100);

        // Constant bytes compress: the GLB goes gzip when the client accepts it.
        let (head, body) = raw(
            a,
            &req("GET", "/tileset/tiles/a.glb", "Accept-Encoding: gzip\r\n"),
        );
        assert_eq!(header(&head, "Content-Encoding"), Some("gzip"));
        assert!(body.len() < 1000);

        let (head, _) = raw(a, &req("GET", "/cesium/Cesium.js", ""));
        assert_eq!(header(&head, "Cache-Control"), Some(CACHE_CESIUM));
        assert_eq!(
            header(&head, "Content-Type"),
            Some("text/javascript; charset=utf-8")
        );
        let (head, _) = raw(a, &req("GET", "/", ""));
        assert!(head.starts_with("HTTP/1.1 200"));
        let (head, _) = raw(a, &req("GET", "/tileset/../secret.txt", ""));
        assert!(head.starts_with("HTTP/1.1 400"), "{head}");
        let (head, _) = raw(a, &req("GET", "/cesium/%2e%2e/secret.txt", ""));
        assert!(head.starts_with("HTTP/1.1 400"), "{head}");
        let (head, _) = raw(a, &req("DELETE", "/", ""));
        assert!(head.starts_with("HTTP/1.1 405"), "{head}");
        h.shutdown();
    }

    #[test]
    fn concurrent_keep_alive_clients() {
        let (_t, o) = setup();
        let h = start(&o).unwrap();
        let a = h.addr();
        let threads: Vec<_> = (0..6)
            .map(|_| {
                std::thread::spawn(move || {
                    let mut s = TcpStream::connect(a).unwrap();
                    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
                    for _ in 0..5 {
                        s.write_all(b"GET /tileset/tileset.json HTTP/1.1\r\nHost: x\r\n\r\n")
                            .unwrap();
                        // Read exactly one response (Content-Length framed).
                        let mut buf = Vec::new();
                        let mut byte = [0u8; 1];
                        while !buf.ends_with(b"\r\n\r\n") {
                            s.read_exact(&mut byte).unwrap();
                            buf.push(byte[0]);
                        }
                        let head = String::from_utf8(buf).unwrap();
                        let n: usize = header(&head, "Content-Length").unwrap().parse().unwrap();
                        let mut body = vec![0u8; n];
                        s.read_exact(&mut body).unwrap();
                        assert!(body.starts_with(b"{\"asset\""));
                    }
                })
            })
            .collect();
        for t in threads {
            t.join().unwrap();
        }
        h.shutdown();
    }
}
