//! HTTP/1.1 on std's TCP sockets for `bimtiles serve`: one thread per connection, keep-alive
//! with an idle timeout, `Content-Length` framing, GET / HEAD (no request bodies are read).
//!
//! Why not tiny_http (used before): its connection pool (0.12) counts idle threads when a
//! connection is queued, not when a thread takes it, so in a burst of new connections one can be
//! queued behind threads that each then hold a keep-alive connection: it is never read until
//! one of those connections closes. A browser keeps its sockets open for minutes, so the
//! request on it stays pending (seen in `make test-browser`: two tile requests pending for
//! 120 s). A thread of our own per connection cannot be starved that way.

use super::handler::{Handler, Headers, Reply};
use std::io::{self, BufRead, BufReader, BufWriter, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant, SystemTime};

/// Longest request head (request line + headers) accepted.
pub const MAX_HEAD: usize = 32 << 10;
/// Most header lines accepted.
pub const MAX_HEADERS: usize = 100;

/// One connection's settings.
#[derive(Debug, Clone, Copy)]
pub struct ConnConfig {
    /// A kept-alive connection with no new request for this long is closed (the browser opens
    /// another when it needs one).
    pub idle: Duration,
    /// A whole request head must arrive within this time of its first byte, however the bytes
    /// trickle in (a client sending one header line every few seconds would otherwise hold its
    /// connection for as long as it likes): past it, 408 and the connection is closed.
    pub head: Duration,
    /// A client that reads nothing of a response for this long is dropped.
    pub write: Duration,
}

/// A parsed request head.
#[derive(Debug, PartialEq, Eq)]
pub struct Request {
    pub method: String,
    /// The request target as sent (`/path?query`).
    pub target: String,
    /// Minor version of HTTP/1.x.
    pub minor: u8,
    pub headers: Vec<(String, String)>,
}

impl Headers for Request {
    fn get(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }
}

impl Request {
    /// Whether the connection stays open after the answer: HTTP/1.1 without `Connection:
    /// close`, and no request body (we do not read bodies, so we could not find the next
    /// request). HTTP/1.0 is closed after each request.
    pub fn keep_alive(&self) -> bool {
        let has_body = self.get("Transfer-Encoding").is_some()
            || self.get("Content-Length").is_some_and(|v| v.trim() != "0");
        let close = self
            .get("Connection")
            .is_some_and(|v| v.split(',').any(|t| t.trim().eq_ignore_ascii_case("close")));
        self.minor >= 1 && !close && !has_body
    }
}

/// Why no request could be read.
#[derive(Debug)]
pub enum HeadError {
    /// The client closed the connection (or timed out) between requests.
    Closed,
    /// Idle for [`ConnConfig::idle`] before a request started.
    Idle,
    /// Malformed or too large: answer with this status and close.
    Bad(u16),
    Io(io::Error),
}

fn is_timeout(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
    )
}

/// Reads and parses one request head (`httparse`). The head is read line by line, so that
/// limits and timeouts apply before anything is parsed. Leading empty lines are skipped
/// (RFC 9112 2.2).
pub fn read_request<R: BufRead>(r: &mut R) -> Result<Request, HeadError> {
    let mut head: Vec<u8> = Vec::new();
    let mut lines = 0usize;
    loop {
        let limit = (MAX_HEAD + 1 - head.len()) as u64;
        let start = head.len();
        let n = match r.by_ref().take(limit).read_until(b'\n', &mut head) {
            Ok(n) => n,
            Err(e) if is_timeout(&e) && head.is_empty() => return Err(HeadError::Idle),
            Err(e) if is_timeout(&e) => return Err(HeadError::Bad(408)),
            Err(e) => return Err(HeadError::Io(e)),
        };
        if head.len() > MAX_HEAD {
            return Err(HeadError::Bad(431));
        }
        if n == 0 || !head.ends_with(b"\n") {
            // End of stream: between requests a normal close, within one a cut request.
            return Err(if head.is_empty() {
                HeadError::Closed
            } else {
                HeadError::Bad(400)
            });
        }
        let line = head[start..].strip_suffix(b"\n").unwrap_or_default();
        if line.strip_suffix(b"\r").unwrap_or(line).is_empty() {
            if lines == 0 {
                head.clear();
                continue;
            }
            return parse_head(&head);
        }
        lines += 1;
        if lines > MAX_HEADERS + 1 {
            return Err(HeadError::Bad(431));
        }
    }
}

fn parse_head(head: &[u8]) -> Result<Request, HeadError> {
    let mut slots = [httparse::EMPTY_HEADER; MAX_HEADERS];
    let mut rq = httparse::Request::new(&mut slots);
    match rq.parse(head) {
        Ok(httparse::Status::Complete(_)) => {}
        // An HTTP version other than 1.x.
        Err(httparse::Error::Version) if head.windows(5).any(|w| w == b"HTTP/") => {
            return Err(HeadError::Bad(505))
        }
        Err(httparse::Error::TooManyHeaders) => return Err(HeadError::Bad(431)),
        _ => return Err(HeadError::Bad(400)),
    }
    let (Some(method), Some(target), Some(minor)) = (rq.method, rq.path, rq.version) else {
        return Err(HeadError::Bad(400));
    };
    // Header values may be Latin-1; nothing here needs them exact.
    let headers = rq
        .headers
        .iter()
        .map(|h| {
            (
                h.name.to_string(),
                String::from_utf8_lossy(h.value).trim().to_string(),
            )
        })
        .collect();
    Ok(Request {
        method: method.to_string(),
        target: target.to_string(),
        minor,
        headers,
    })
}

pub fn reason(status: u16) -> &'static str {
    match status {
        200 => "OK",
        206 => "Partial Content",
        301 => "Moved Permanently",
        304 => "Not Modified",
        400 => "Bad Request",
        403 => "Forbidden",
        404 => "Not Found",
        405 => "Method Not Allowed",
        408 => "Request Timeout",
        416 => "Range Not Satisfiable",
        431 => "Request Header Fields Too Large",
        500 => "Internal Server Error",
        503 => "Service Unavailable",
        505 => "HTTP Version Not Supported",
        _ => "",
    }
}

/// Writes a reply: status line, `Date`, `Server`, the reply's headers, `Content-Length`
/// (always: never chunked), `Connection: close` when `close`, then the body unless
/// `head_only` or the status has none. Returns the body bytes written. A body shorter than
/// announced (a file cut while sent) is an error: the connection must then be closed.
pub fn write_reply<W: Write>(w: W, reply: Reply, head_only: bool, close: bool) -> io::Result<u64> {
    let mut w = BufWriter::with_capacity(64 << 10, w);
    let status = reply.status;
    write!(
        w,
        "HTTP/1.1 {status} {}\r\nDate: {}\r\nServer: bimtiles\r\n",
        reason(status),
        httpdate::fmt_http_date(SystemTime::now())
    )?;
    for (k, v) in &reply.headers {
        // Our own values; a line break would split the response, so such a header is dropped.
        if v.contains(['\r', '\n']) || k.eq_ignore_ascii_case("Content-Length") {
            continue;
        }
        write!(w, "{k}: {v}\r\n")?;
    }
    let no_body = head_only || matches!(status, 100..=199 | 204 | 304);
    if !matches!(status, 100..=199 | 204) {
        write!(w, "Content-Length: {}\r\n", reply.length)?;
    }
    if close {
        w.write_all(b"Connection: close\r\n")?;
    }
    w.write_all(b"\r\n")?;
    let mut sent = 0;
    if !no_body {
        let mut body = reply.body.into_reader()?.take(reply.length);
        sent = io::copy(&mut body, &mut w)?;
        if sent != reply.length {
            return Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                format!("body ended at {sent} of {} bytes", reply.length),
            ));
        }
    }
    w.flush()?;
    Ok(sent)
}

/// Where log lines go, and what they say.
pub struct Log {
    /// One line per answered request.
    pub requests: bool,
    /// Also connections opened / closed and requests started (`BIMTILES_SERVE_LOG=1`).
    pub trace: bool,
    pub start: Instant,
}

impl Log {
    pub fn line(&self, msg: std::fmt::Arguments<'_>) {
        let t = self.start.elapsed().as_secs_f64();
        // One write per line so lines from different connections do not interleave.
        let _ = io::stderr().write_all(format!("[{t:9.3}] {msg}\n").as_bytes());
    }
}

/// A socket reader whose timeout is [`ConnConfig::idle`] until the first byte of a request head
/// and then what is left of [`ConnConfig::head`], so the deadline of a head is not reset by each
/// line that arrives.
struct HeadTimedReader {
    stream: TcpStream,
    idle: Duration,
    head: Duration,
    /// When the head being read must be complete; `None` before its first byte.
    deadline: Option<Instant>,
}

impl HeadTimedReader {
    /// The next bytes start a new request head.
    fn start_head(&mut self) {
        self.deadline = None;
    }
}

impl Read for HeadTimedReader {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let timeout = match self.deadline {
            None => self.idle,
            Some(d) => d.saturating_duration_since(Instant::now()),
        };
        if timeout.is_zero() {
            return Err(io::ErrorKind::TimedOut.into());
        }
        self.stream.set_read_timeout(Some(timeout))?;
        let n = self.stream.read(buf)?;
        if n > 0 && self.deadline.is_none() {
            self.deadline = Some(Instant::now() + self.head);
        }
        Ok(n)
    }
}

/// What a connection is doing, for the server's choice of which connection to close when all
/// slots are taken (see `accept_loop` in mod.rs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Waiting for a request or reading its head: can be closed for a new client.
    Reading,
    /// Answering a request.
    Answering,
}

/// Answers the requests of one connection until it closes, goes idle or errs; `phase` is told
/// when it starts reading a request and when it starts answering one.
pub fn serve_connection(
    stream: TcpStream,
    id: u64,
    handler: &Handler,
    cfg: ConnConfig,
    log: &Log,
    phase: &dyn Fn(Phase),
) {
    let peer = stream
        .peer_addr()
        .map_or_else(|_| "?".to_string(), |a| a.to_string());
    if log.trace {
        log.line(format_args!("conn {id} open from {peer}"));
    }
    let _ = stream.set_nodelay(true);
    let reader = stream
        .set_write_timeout(Some(cfg.write))
        .and_then(|_| stream.try_clone());
    let mut reader = match reader {
        Ok(r) => BufReader::new(HeadTimedReader {
            stream: r,
            idle: cfg.idle,
            head: cfg.head,
            deadline: None,
        }),
        Err(e) => {
            if log.trace {
                log.line(format_args!("conn {id} closed: {e}"));
            }
            return;
        }
    };
    let mut n = 0u64;
    let end: String = loop {
        phase(Phase::Reading);
        reader.get_mut().start_head();
        let rq = match read_request(&mut reader) {
            Ok(rq) => rq,
            Err(HeadError::Closed) => break "by the client".into(),
            Err(HeadError::Idle) => break format!("idle for {} s", cfg.idle.as_secs()),
            Err(HeadError::Io(e)) => break format!("read error: {e}"),
            Err(HeadError::Bad(status)) => {
                let reply = Reply::text(status, reason(status));
                let _ = write_reply(&stream, reply, false, true);
                break format!("bad request head ({status})");
            }
        };
        n += 1;
        phase(Phase::Answering);
        let t = Instant::now();
        if log.trace {
            log.line(format_args!("conn {id} #{n} {} {}", rq.method, rq.target));
        }
        let keep = rq.keep_alive();
        let reply = handler.handle(&rq.method, &rq.target, &rq);
        let (status, length) = (reply.status, reply.length);
        let res = write_reply(&stream, reply, rq.method == "HEAD", !keep);
        if log.requests || log.trace {
            let ms = t.elapsed().as_secs_f64() * 1e3;
            let err = res
                .as_ref()
                .err()
                .map_or(String::new(), |e| format!(" write error: {e}"));
            log.line(format_args!(
                "conn {id} #{n} {} {} {status} {length} ({ms:.1} ms){err}",
                rq.method, rq.target
            ));
        }
        match res {
            Err(e) => break format!("write error: {e}"),
            Ok(_) if !keep => break "after a closing request".into(),
            Ok(_) => {}
        }
    };
    if log.trace {
        log.line(format_args!("conn {id} closed {end}, {n} request(s)"));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> Result<Request, HeadError> {
        read_request(&mut io::Cursor::new(s.as_bytes().to_vec()))
    }

    fn status(r: Result<Request, HeadError>) -> u16 {
        match r {
            Err(HeadError::Bad(s)) => s,
            other => panic!("expected a bad request, got {other:?}"),
        }
    }

    #[test]
    fn parses_heads() {
        let r =
            parse("\r\nGET /a?b HTTP/1.1\r\nHost: x\r\nAccept-Encoding:  gzip \r\n\r\n").unwrap();
        assert_eq!(r.method, "GET");
        assert_eq!(r.target, "/a?b");
        assert_eq!(r.minor, 1);
        assert_eq!(r.get("accept-encoding"), Some("gzip"));
        assert!(r.keep_alive());
        // Bare LF line ends are accepted.
        let r = parse("HEAD / HTTP/1.0\nHost: x\n\n").unwrap();
        assert_eq!((r.method.as_str(), r.minor), ("HEAD", 0));
        assert!(!r.keep_alive());
        let r = parse("GET / HTTP/1.1\r\nConnection: keep-alive, Close\r\n\r\n").unwrap();
        assert!(!r.keep_alive());
        let r = parse("POST / HTTP/1.1\r\nContent-Length: 5\r\n\r\nhello").unwrap();
        assert!(!r.keep_alive(), "a body we do not read ends the connection");
    }

    #[test]
    fn refuses_bad_heads() {
        assert!(matches!(parse(""), Err(HeadError::Closed)));
        assert_eq!(status(parse("GET / HTTP/1.1\r\nHost: x\r\n")), 400); // cut
        assert_eq!(status(parse("GET /\r\n\r\n")), 400);
        assert_eq!(status(parse("GET / HTTP/2.0\r\n\r\n")), 505);
        assert_eq!(status(parse("GET  / HTTP/1.1\r\n\r\n")), 400);
        assert_eq!(status(parse("G=T / HTTP/1.1\r\n\r\n")), 400);
        assert_eq!(status(parse("GET / HTTP/1.1\r\nHost : x\r\n\r\n")), 400);
        assert_eq!(status(parse("GET / HTTP/1.1\r\n folded\r\n\r\n")), 400);
        assert_eq!(status(parse("GET / HTTP/1.1\r\nNoColon\r\n\r\n")), 400);
        let big = format!("GET / HTTP/1.1\r\nX: {}\r\n\r\n", "a".repeat(MAX_HEAD));
        assert_eq!(status(parse(&big)), 431);
        let many = format!(
            "GET / HTTP/1.1\r\n{}\r\n",
            "X: y\r\n".repeat(MAX_HEADERS + 1)
        );
        assert_eq!(status(parse(&many)), 431);
    }

    #[test]
    fn writes_framed_replies() {
        let mut out = Vec::new();
        let reply = Reply::text(404, "Not Found");
        let n = reply.length;
        write_reply(&mut out, reply, false, true).unwrap();
        let s = String::from_utf8(out).unwrap();
        assert!(s.starts_with("HTTP/1.1 404 Not Found\r\n"), "{s}");
        assert!(s.contains(&format!("\r\nContent-Length: {n}\r\n")));
        assert!(s.contains("\r\nConnection: close\r\n"));
        assert!(s.ends_with("\r\n\r\n404 Not Found\n"), "{s}");
        // HEAD: the length of the body it would have, no body.
        let mut out = Vec::new();
        write_reply(&mut out, Reply::text(404, "Not Found"), true, false).unwrap();
        let s = String::from_utf8(out).unwrap();
        assert!(s.ends_with("\r\n\r\n") && !s.contains("Connection"), "{s}");
        assert!(s.contains(&format!("\r\nContent-Length: {n}\r\n")));
    }
}
