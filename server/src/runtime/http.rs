//! A small HTTP/1.1 server for `GET` requests: the metrics endpoint and the web viewer.
//!
//! Deliberately small and bounded: one thread per connection with at most
//! [`MAX_CONNECTIONS`] at once (beyond that, `503` and close), a request head of at most
//! [`MAX_HEAD_BYTES`] read within [`READ_TIMEOUT`], one request per connection. A handler
//! answers with bytes, or with a stream (server-sent events) that writes until the peer goes or
//! the server stops. Nothing a client sends can panic it: a head it cannot read gets `400`.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

/// Connections served at once.
pub const MAX_CONNECTIONS: usize = 64;
/// Longest request head read.
pub const MAX_HEAD_BYTES: usize = 8 * 1024;
/// Time a client has to send its request head.
pub const READ_TIMEOUT: Duration = Duration::from_secs(5);

/// A request: method, path and query string (without `?`).
#[derive(Clone, Debug)]
pub struct Request {
    /// `GET` or `HEAD`.
    pub method: String,
    /// The path, e.g. `/metrics`.
    pub path: String,
    /// The query string, e.g. `tick=120`.
    pub query: String,
}

impl Request {
    /// The value of `name` in the query string.
    pub fn param(&self, name: &str) -> Option<&str> {
        self.query.split('&').filter_map(|kv| kv.split_once('=')).find(|(k, _)| *k == name).map(|(_, v)| v)
    }
}

/// Writes a streamed body until the peer goes (a write fails) or `stop` is set.
pub type Streamer = Box<dyn FnOnce(&mut dyn Write, &AtomicBool) + Send>;

/// What a handler answers.
pub enum Body {
    /// A complete body.
    Bytes(Vec<u8>),
    /// A body written as it comes (`Content-Type: text/event-stream`).
    Stream(Streamer),
}

impl std::fmt::Debug for Body {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Body::Bytes(b) => write!(f, "Bytes({})", b.len()),
            Body::Stream(_) => f.write_str("Stream"),
        }
    }
}

/// A response.
#[derive(Debug)]
pub struct Response {
    /// Status code.
    pub status: u16,
    /// Content type.
    pub content_type: &'static str,
    /// Body.
    pub body: Body,
}

impl Response {
    /// `200` with a body.
    pub fn ok(content_type: &'static str, body: Vec<u8>) -> Response {
        Response { status: 200, content_type, body: Body::Bytes(body) }
    }

    /// `404`.
    pub fn not_found() -> Response {
        Response::error(404, "not found\n")
    }

    /// A status with a plain-text message.
    pub fn error(status: u16, message: &str) -> Response {
        Response { status, content_type: "text/plain; charset=utf-8", body: Body::Bytes(message.as_bytes().to_vec()) }
    }

    /// `200` with a stream of server-sent events.
    pub fn events(stream: Streamer) -> Response {
        Response { status: 200, content_type: "text/event-stream", body: Body::Stream(stream) }
    }
}

/// Answers requests.
pub type Handler = Arc<dyn Fn(&Request) -> Response + Send + Sync>;

/// A running server; stops when dropped.
#[derive(Debug)]
pub struct Server {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Server {
    /// Listens on `addr` (`host:port`; port 0 picks a free one) and serves with `handler`.
    pub fn start(addr: &str, name: &str, handler: Handler) -> std::io::Result<Server> {
        let listener = TcpListener::bind(addr)?;
        listener.set_nonblocking(true)?;
        let local = listener.local_addr()?;
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let name = name.to_string();
        let thread = std::thread::Builder::new().name(name.clone()).spawn(move || accept(listener, handler, stop2))?;
        Ok(Server { addr: local, stop, thread: Some(thread) })
    }

    /// The address it listens on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn accept(listener: TcpListener, handler: Handler, stop: Arc<AtomicBool>) {
    let open = Arc::new(AtomicUsize::new(0));
    while !stop.load(Ordering::SeqCst) {
        match listener.accept() {
            Ok((mut conn, _)) => {
                if open.load(Ordering::SeqCst) >= MAX_CONNECTIONS {
                    let _ = respond(&mut conn, Response::error(503, "too many connections\n"), &stop);
                    continue;
                }
                open.fetch_add(1, Ordering::SeqCst);
                let (h, s, o) = (handler.clone(), stop.clone(), open.clone());
                let spawned = std::thread::Builder::new().name("impact-http".into()).spawn(move || {
                    serve(conn, &h, &s);
                    o.fetch_sub(1, Ordering::SeqCst);
                });
                if spawned.is_err() {
                    open.fetch_sub(1, Ordering::SeqCst);
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => std::thread::sleep(Duration::from_millis(20)),
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}

fn serve(mut conn: TcpStream, handler: &Handler, stop: &AtomicBool) {
    let _ = conn.set_nonblocking(false);
    let _ = conn.set_read_timeout(Some(READ_TIMEOUT));
    let _ = conn.set_write_timeout(Some(Duration::from_secs(10)));
    let response = match read_head(&mut conn) {
        Some(req) if req.method == "GET" || req.method == "HEAD" => handler(&req),
        Some(_) => Response::error(405, "only GET\n"),
        None => Response::error(400, "bad request\n"),
    };
    let _ = respond(&mut conn, response, stop);
}

/// Reads the request head and parses its first line.
fn read_head(conn: &mut TcpStream) -> Option<Request> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 1024];
    while !buf.windows(4).any(|w| w == b"\r\n\r\n") {
        if buf.len() >= MAX_HEAD_BYTES {
            return None;
        }
        let n = conn.read(&mut chunk).ok()?;
        if n == 0 {
            return None;
        }
        buf.extend_from_slice(&chunk[..n]);
    }
    let head = std::str::from_utf8(&buf).ok()?;
    let mut parts = head.lines().next()?.split(' ');
    let (method, target, version) = (parts.next()?, parts.next()?, parts.next()?);
    if !version.starts_with("HTTP/1.") || !target.starts_with('/') {
        return None;
    }
    let (path, query) = target.split_once('?').unwrap_or((target, ""));
    Some(Request { method: method.to_string(), path: path.to_string(), query: query.to_string() })
}

fn respond(conn: &mut TcpStream, r: Response, stop: &AtomicBool) -> std::io::Result<()> {
    let reason = match r.status {
        200 => "OK",
        400 => "Bad Request",
        404 => "Not Found",
        405 => "Method Not Allowed",
        503 => "Service Unavailable",
        _ => "Error",
    };
    match r.body {
        Body::Bytes(b) => {
            let head = format!(
                "HTTP/1.1 {} {reason}\r\nContent-Type: {}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
                r.status,
                r.content_type,
                b.len()
            );
            conn.write_all(head.as_bytes())?;
            conn.write_all(&b)?;
            conn.flush()
        }
        Body::Stream(f) => {
            let head = format!(
                "HTTP/1.1 {} {reason}\r\nContent-Type: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
                r.status, r.content_type
            );
            conn.write_all(head.as_bytes())?;
            conn.flush()?;
            f(conn, stop);
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn get(addr: SocketAddr, raw: &[u8]) -> String {
        let mut c = TcpStream::connect(addr).unwrap();
        c.write_all(raw).unwrap();
        let mut out = String::new();
        let _ = c.read_to_string(&mut out);
        out
    }

    #[test]
    fn answers_get_and_refuses_what_it_cannot_read() {
        let h: Handler = Arc::new(|r: &Request| match r.path.as_str() {
            "/x" => Response::ok("text/plain", format!("x={}", r.param("x").unwrap_or("-")).into_bytes()),
            _ => Response::not_found(),
        });
        let s = Server::start("127.0.0.1:0", "test-http", h).unwrap();
        let ok = get(s.addr(), b"GET /x?x=5 HTTP/1.1\r\nHost: a\r\n\r\n");
        assert!(ok.starts_with("HTTP/1.1 200 OK") && ok.ends_with("x=5"), "{ok}");
        assert!(get(s.addr(), b"GET /nope HTTP/1.1\r\n\r\n").starts_with("HTTP/1.1 404"));
        assert!(get(s.addr(), b"POST /x HTTP/1.1\r\n\r\n").starts_with("HTTP/1.1 405"));
        assert!(get(s.addr(), b"\x00\xff garbage\r\n\r\n").starts_with("HTTP/1.1 400"));
        // A head that never ends is cut off at the bound.
        let long = vec![b'a'; MAX_HEAD_BYTES + 10];
        assert!(get(s.addr(), &long).starts_with("HTTP/1.1 400"));
    }
}
