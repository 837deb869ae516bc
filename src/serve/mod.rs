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
//! One thread per connection (see `http.rs` for why), kept alive until idle for
//! [`ServeOptions::idle_timeout`]. Slow clients cannot starve others: a request head must arrive
//! within [`ServeOptions::head_timeout`] of its first byte, and when every slot is taken a new
//! connection takes the slot of the connection that has waited longest for a request (idle or
//! trickling its head in); only when all are answering requests is it refused with 503. `BIMTILES_SERVE_LOG=1` logs every connection and request
//! with its timing to stderr (for a page load that hangs: was the request read, answered?).
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
mod http;

pub use handler::{Handler, Mount, Reply};
pub use http::{read_request, HeadError, Request};

use std::collections::HashMap;
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

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
    /// Connections served at once (a thread each). Past it, a new one takes the slot of the
    /// connection that has waited longest for a request; when all are answering, it is answered
    /// 503 and closed. Default 256 (a browser opens 6 per host).
    pub max_connections: usize,
    /// A kept-alive connection with no request for this long is closed; default 15 s.
    pub idle_timeout: Duration,
    /// A request head must be complete this long after its first byte; default 10 s.
    pub head_timeout: Duration,
    /// Print one line per request to stderr.
    pub log_requests: bool,
    /// Also log connections opened / closed and requests started, with times; default: the
    /// environment variable `BIMTILES_SERVE_LOG` is `1`.
    pub log_connections: bool,
}

impl ServeOptions {
    pub fn new(tileset_dir: impl Into<PathBuf>, viewer_dir: impl Into<PathBuf>) -> ServeOptions {
        ServeOptions {
            tileset_dir: tileset_dir.into(),
            viewer_dir: viewer_dir.into(),
            cesium_dir: None,
            host: "127.0.0.1".into(),
            port: 8080,
            max_connections: 256,
            idle_timeout: Duration::from_secs(15),
            head_timeout: Duration::from_secs(10),
            log_requests: false,
            log_connections: std::env::var("BIMTILES_SERVE_LOG").is_ok_and(|v| v == "1"),
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
    shared: Arc<Shared>,
    acceptor: Option<JoinHandle<()>>,
}

/// What the accepting thread and the connection threads share.
struct Shared {
    handler: Handler,
    stop: AtomicBool,
    /// Open connections, by id.
    conns: Mutex<HashMap<u64, Slot>>,
    /// Signalled when a connection ends.
    conn_ended: Condvar,
    max_connections: usize,
    conn: http::ConnConfig,
    log: http::Log,
}

/// One open connection.
struct Slot {
    /// A clone of its socket, to end it (at shutdown, or to give its slot to a new client).
    stream: TcpStream,
    phase: http::Phase,
    /// When it entered that phase.
    since: Instant,
}

impl Shared {
    fn set_phase(&self, id: u64, phase: http::Phase) {
        let mut conns = self.conns.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(slot) = conns.get_mut(&id) {
            slot.phase = phase;
            slot.since = Instant::now();
        }
    }
}

/// The connection whose slot a new client takes when all are taken: of those waiting for a
/// request (idle, or trickling a head in), the one waiting longest. `None`: all are answering.
fn slot_to_reclaim(conns: &HashMap<u64, Slot>) -> Option<u64> {
    conns
        .iter()
        .filter(|(_, s)| s.phase == http::Phase::Reading)
        .min_by_key(|(id, s)| (s.since, **id))
        .map(|(id, _)| *id)
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
        if let Some(a) = self.acceptor.take() {
            let _ = a.join();
        }
    }

    /// Stops accepting, lets the connections finish their current request (up to 10 s), and
    /// closes them.
    pub fn shutdown(mut self) {
        self.stop();
    }

    fn stop(&mut self) {
        let Some(acceptor) = self.acceptor.take() else {
            return;
        };
        self.shared.stop.store(true, Ordering::SeqCst);
        // accept() has no timeout: a connection of our own wakes it.
        let mut wake = self.addr;
        if wake.ip().is_unspecified() {
            wake.set_ip(match wake {
                SocketAddr::V4(_) => std::net::Ipv4Addr::LOCALHOST.into(),
                SocketAddr::V6(_) => std::net::Ipv6Addr::LOCALHOST.into(),
            });
        }
        let _ = TcpStream::connect_timeout(&wake, Duration::from_secs(1));
        let _ = acceptor.join();
        // Ends the reads of idle connections; a response being written is finished first.
        let mut conns = self.shared.conns.lock().unwrap_or_else(|p| p.into_inner());
        for s in conns.values() {
            let _ = s.stream.shutdown(Shutdown::Read);
        }
        let deadline = Instant::now() + Duration::from_secs(10);
        while !conns.is_empty() && Instant::now() < deadline {
            conns = self
                .shared
                .conn_ended
                .wait_timeout(conns, Duration::from_millis(100))
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
    }
}

impl Drop for ServerHandle {
    fn drop(&mut self) {
        self.stop();
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
    let handler = handler(opts)?;
    let bind = format!("{}:{}", bracket_v6(&opts.host), opts.port);
    let listener = TcpListener::bind(bind.as_str()).map_err(|e| ServeError::Bind {
        addr: bind.clone(),
        message: e.to_string(),
    })?;
    let addr = listener.local_addr()?;
    let shared = Arc::new(Shared {
        handler,
        stop: AtomicBool::new(false),
        conns: Mutex::new(HashMap::new()),
        conn_ended: Condvar::new(),
        max_connections: opts.max_connections.max(1),
        conn: http::ConnConfig {
            idle: opts.idle_timeout,
            head: opts.head_timeout,
            write: Duration::from_secs(60),
        },
        log: http::Log {
            requests: opts.log_requests,
            trace: opts.log_connections,
            start: Instant::now(),
        },
    });
    let s = shared.clone();
    let acceptor = std::thread::Builder::new()
        .name("bimtiles-serve-accept".into())
        .spawn(move || accept_loop(listener, s))?;
    Ok(ServerHandle {
        addr,
        shared,
        acceptor: Some(acceptor),
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

fn accept_loop(listener: TcpListener, shared: Arc<Shared>) {
    static NEXT_ID: AtomicU64 = AtomicU64::new(1);
    for stream in listener.incoming() {
        if shared.stop.load(Ordering::SeqCst) {
            return;
        }
        let stream = match stream {
            Ok(s) => s,
            // Out of descriptors and the like: the client retries; do not spin.
            Err(_) => {
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
        };
        let id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
        let Ok(clone) = stream.try_clone() else {
            continue;
        };
        {
            let mut conns = shared.conns.lock().unwrap_or_else(|p| p.into_inner());
            if conns.len() >= shared.max_connections {
                let Some(victim) = slot_to_reclaim(&conns) else {
                    drop(conns);
                    refuse_busy(stream, id, &shared.log);
                    continue;
                };
                // Its thread sees the closed socket at once and ends.
                if let Some(v) = conns.remove(&victim) {
                    let _ = v.stream.shutdown(Shutdown::Both);
                }
                if shared.log.trace {
                    shared.log.line(format_args!(
                        "conn {victim} closed: its slot was taken by conn {id}"
                    ));
                }
            }
            conns.insert(
                id,
                Slot {
                    stream: clone,
                    phase: http::Phase::Reading,
                    since: Instant::now(),
                },
            );
        }
        let s = shared.clone();
        let spawned = std::thread::Builder::new()
            .name(format!("bimtiles-serve-conn-{id}"))
            .spawn(move || {
                let phase = |p| s.set_phase(id, p);
                http::serve_connection(stream, id, &s.handler, s.conn, &s.log, &phase);
                s.conns
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .remove(&id);
                s.conn_ended.notify_all();
            });
        if spawned.is_err() {
            // No thread for it: the socket (dropped with the closure) closes, the client retries.
            shared
                .conns
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .remove(&id);
        }
    }
}

/// Too many connections: a short 503 (the browser retries later) instead of a queue nobody reads.
fn refuse_busy(mut stream: TcpStream, id: u64, log: &http::Log) {
    use std::io::Read;
    // Closing a socket with unread request bytes sends a reset, which can destroy the 503
    // before the client reads it: read what came, answer, then wait briefly for the client's
    // close. On the accepting thread, so at most ~0.3 s each, and only when overloaded.
    let t = Duration::from_millis(100);
    let _ = stream.set_read_timeout(Some(t));
    let _ = stream.set_write_timeout(Some(t));
    let mut buf = [0u8; 8192];
    let _ = stream.read(&mut buf);
    let reply = Reply::text(503, "Service Unavailable");
    let _ = http::write_reply(&stream, reply, false, true);
    let _ = stream.shutdown(Shutdown::Write);
    while matches!(stream.read(&mut buf), Ok(n) if n > 0) {}
    if log.requests || log.trace {
        log.line(format_args!(
            "conn {id} refused: too many connections (503)"
        ));
    }
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

    /// Reads exactly one `Content-Length`-framed response from a kept-alive connection.
    fn read_response(s: &mut TcpStream) -> std::io::Result<(String, Vec<u8>)> {
        let mut buf = Vec::new();
        let mut byte = [0u8; 1];
        while !buf.ends_with(b"\r\n\r\n") {
            s.read_exact(&mut byte)?;
            buf.push(byte[0]);
        }
        let head = String::from_utf8(buf).unwrap();
        let n: usize = header(&head, "Content-Length").unwrap().parse().unwrap();
        let mut body = vec![0u8; n];
        s.read_exact(&mut body)?;
        Ok((head, body))
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
    /// Bursts of new keep-alive connections, each asking once and staying open until every one
    /// has its answer (a browser opening its 6 sockets at once, then keeping them). Every request
    /// must be answered: a connection accepted but never read shows up as a read timeout.
    #[test]
    fn bursts_of_keep_alive_connections_are_all_answered() {
        let (_t, o) = setup();
        let h = start(&o).unwrap();
        let a = h.addr();
        for round in 0..40 {
            let mut conns: Vec<TcpStream> =
                (0..12).map(|_| TcpStream::connect(a).unwrap()).collect();
            for s in &mut conns {
                s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
                s.write_all(b"GET /tileset/tileset.json HTTP/1.1\r\nHost: x\r\n\r\n")
                    .unwrap();
            }
            for (i, s) in conns.iter_mut().enumerate() {
                if let Err(e) = read_response(s) {
                    // tiny_http 0.12 failed here in 5 of 6 runs, in round 0 (its pool starts
                    // with 4 idle threads; the 5th connection of the burst was never read).
                    panic!("round {round}, connection {i}: no answer ({e})");
                }
            }
            drop(conns);
            // Let the server's connection threads go idle again before the next burst.
            std::thread::sleep(Duration::from_millis(20));
        }
        h.shutdown();
    }

    /// Kept-alive connections left idle do not hold up another client, are closed by the
    /// server after the idle timeout, and do not hold up a shutdown.
    #[test]
    fn idle_keep_alive_connections() {
        let (_t, mut o) = setup();
        o.idle_timeout = Duration::from_millis(500);
        let h = start(&o).unwrap();
        let a = h.addr();
        let ask = |s: &mut TcpStream| {
            s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            s.write_all(b"GET /tileset/tileset.json HTTP/1.1\r\nHost: x\r\n\r\n")
                .unwrap();
            let (head, _) = read_response(s).unwrap();
            assert!(head.starts_with("HTTP/1.1 200"), "{head}");
            assert_eq!(header(&head, "Connection"), None, "kept alive");
        };
        let mut idle: Vec<TcpStream> = (0..10).map(|_| TcpStream::connect(a).unwrap()).collect();
        idle.iter_mut().for_each(ask);
        let t = std::time::Instant::now();
        let (head, _) = raw(a, &req("GET", "/", ""));
        assert!(head.starts_with("HTTP/1.1 200"), "{head}");
        assert_eq!(header(&head, "Connection"), Some("close"));
        assert!(t.elapsed() < Duration::from_secs(1));
        for s in &mut idle {
            let mut b = [0u8; 1];
            assert_eq!(s.read(&mut b).unwrap(), 0, "closed by the server when idle");
        }
        let mut s = TcpStream::connect(a).unwrap();
        ask(&mut s);
        let t = std::time::Instant::now();
        h.shutdown();
        assert!(
            t.elapsed() < Duration::from_millis(400),
            "{:?}",
            t.elapsed()
        );
    }

    /// Connections answering a request that the client does not read: the server blocks
    /// writing a body larger than the socket buffers.
    fn hold_answering(a: SocketAddr, o: &ServeOptions, n: usize) -> Vec<TcpStream> {
        std::fs::write(o.tileset_dir.join("tiles/big.bin"), vec![1u8; 64 << 20]).unwrap();
        let held: Vec<TcpStream> = (0..n)
            .map(|_| {
                let mut s = TcpStream::connect(a).unwrap();
                s.write_all(b"GET /tileset/tiles/big.bin HTTP/1.1\r\nHost: x\r\n\r\n")
                    .unwrap();
                s
            })
            .collect();
        // Give the server time to take the requests and fill the buffers.
        std::thread::sleep(Duration::from_millis(300));
        held
    }

    #[test]
    fn too_many_answering_connections_get_503() {
        let (_t, mut o) = setup();
        o.max_connections = 2;
        let h = start(&o).unwrap();
        let a = h.addr();
        let held = hold_answering(a, &o, 2);
        let (head, _) = raw(a, &req("GET", "/", ""));
        assert!(head.starts_with("HTTP/1.1 503"), "{head}");
        drop(held);
        // Once they are gone, new connections are served again.
        let deadline = std::time::Instant::now() + Duration::from_secs(5);
        loop {
            let (head, _) = raw(a, &req("GET", "/", ""));
            if head.starts_with("HTTP/1.1 200") {
                break;
            }
            assert!(std::time::Instant::now() < deadline, "{head}");
            std::thread::sleep(Duration::from_millis(20));
        }
        h.shutdown();
    }

    /// A client sending its head one line at a time, a line every 100 ms: each read is well
    /// within the idle timeout, but the whole head is not within the head timeout.
    fn trickle(a: SocketAddr, lines: usize) -> std::thread::JoinHandle<(String, usize)> {
        use std::io::ErrorKind::{TimedOut, WouldBlock};
        std::thread::spawn(move || {
            let mut s = TcpStream::connect(a).unwrap();
            s.set_read_timeout(Some(Duration::from_millis(50))).unwrap();
            let mut sent = 0;
            let mut answer = Vec::new();
            if s.write_all(b"GET / HTTP/1.1\r\n").is_ok() {
                while sent < lines {
                    std::thread::sleep(Duration::from_millis(100));
                    if s.write_all(b"X-Slow: y\r\n").is_err() {
                        break;
                    }
                    sent += 1;
                    match s.read_to_end(&mut answer) {
                        // Still open: go on trickling.
                        Err(e) if matches!(e.kind(), WouldBlock | TimedOut) => {}
                        // Closed by the server (after its answer, if any).
                        _ => break,
                    }
                }
            }
            (String::from_utf8_lossy(&answer).into_owned(), sent)
        })
    }

    #[test]
    fn a_head_trickled_in_is_cut_at_the_head_timeout() {
        let (_t, mut o) = setup();
        o.idle_timeout = Duration::from_secs(5);
        o.head_timeout = Duration::from_millis(600);
        let h = start(&o).unwrap();
        let (answer, sent) = trickle(h.addr(), 40).join().unwrap();
        assert!(answer.starts_with("HTTP/1.1 408"), "{answer:?}");
        // 600 ms at a line per 100 ms: cut after about 6 lines, far before 40 (4 s).
        assert!(sent < 20, "{sent} lines sent before the cut");
        h.shutdown();
    }

    /// Slow clients holding every slot do not starve a normal one: it takes the slot of the
    /// connection that has waited longest for a complete request.
    #[test]
    fn slow_clients_do_not_starve_others() {
        let (_t, mut o) = setup();
        o.max_connections = 4;
        o.idle_timeout = Duration::from_secs(30);
        o.head_timeout = Duration::from_secs(30);
        let h = start(&o).unwrap();
        let a = h.addr();
        let slow: Vec<_> = (0..4).map(|_| trickle(a, 30)).collect();
        std::thread::sleep(Duration::from_millis(300));
        for _ in 0..5 {
            let (head, _) = raw(a, &req("GET", "/", ""));
            assert!(head.starts_with("HTTP/1.1 200"), "{head}");
        }
        // Idle kept-alive connections give up their slots the same way.
        let mut idle: Vec<TcpStream> = (0..4).map(|_| TcpStream::connect(a).unwrap()).collect();
        for s in &mut idle {
            s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            s.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
            read_response(s).unwrap();
        }
        let (head, _) = raw(a, &req("GET", "/", ""));
        assert!(head.starts_with("HTTP/1.1 200"), "{head}");
        h.shutdown();
        for t in slow {
            let (_, sent) = t.join().unwrap();
            assert!(sent < 30, "a slow client was closed to make room");
        }
    }
}
