//! A small HTTP/1.1 server for the page: `GET /` (the page), `/app.js`, `/style.css` (compiled
//! into the binary: no CDN, no internet), and `/events`, a Server-Sent Events stream of the
//! hub's events (the history first). Requests other than these get 404 or 405.
//!
//! What it lets in (a page served on a loopback address is for this machine only):
//! - **Host**: a literal loopback address (`127.0.0.0/8` as a dotted quad, `[::1]`) or
//!   `localhost`, with an optional port ([`is_loopback_host`]). Anything else gets 403 and no
//!   data: a name such as `127.attacker.example` is the attacker's to point at 127.0.0.1 (DNS
//!   rebinding), and a page of theirs would then be same-origin with this one.
//! - **Origin**, when a request has one: `http://` and such a host ([`is_loopback_origin`]);
//!   a page of another site gets 403 before any data is written (its browser would not let it
//!   read the stream anyway: no CORS headers are sent).
//! - Served on another address (`--bind`), neither is checked (and nothing authenticates:
//!   put it behind a proxy of your own).
//!
//! What a connection may cost ([`Limits`]): at most [`MAX_CONNECTIONS`] at once, each on a
//! thread of its own. One more takes the place of the oldest connection still sending its
//! request, else of the oldest event stream (a page reconnects within a second and then takes
//! a place in turn), else it gets 503. A request's head (at most 16 KiB) must arrive whole
//! within [`HEAD_DEADLINE`], and a write that makes no progress for [`WRITE_TIMEOUT`] ends the
//! connection: a client that stops reading is dropped with its copy of the history.

use std::io::{self, BufRead, BufReader, Read, Write};
use std::net::{Ipv4Addr, Ipv6Addr, Shutdown, TcpListener, TcpStream};
use std::sync::mpsc::RecvTimeoutError;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crate::hub::Hub;

const INDEX: &str = include_str!("page/index.html");
const APP: &str = include_str!("page/app.js");
const STYLE: &str = include_str!("page/style.css");

/// How often an idle event stream sends a comment (a closed page is noticed then).
pub const PING: Duration = Duration::from_secs(10);
/// Connections served at once (each an /events stream, or a request being read or answered).
pub const MAX_CONNECTIONS: usize = 64;
/// The whole head of a request (request line and headers) must arrive within this.
pub const HEAD_DEADLINE: Duration = Duration::from_secs(5);
/// A write to a client that makes no progress for this long ends its connection.
pub const WRITE_TIMEOUT: Duration = Duration::from_secs(10);
/// Most bytes of a request's head.
const MAX_HEAD: u64 = 16 * 1024;
/// How long a new connection waits for a place to free up before it gets 503.
const ADMIT_WAIT: Duration = Duration::from_secs(2);

/// What connections may cost: [`Limits::default`] is [`MAX_CONNECTIONS`], [`HEAD_DEADLINE`]
/// and [`WRITE_TIMEOUT`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    pub max_connections: usize,
    pub head_deadline: Duration,
    pub write_timeout: Duration,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_connections: MAX_CONNECTIONS,
            head_deadline: HEAD_DEADLINE,
            write_timeout: WRITE_TIMEOUT,
        }
    }
}

/// The server started by [`spawn`]: its accepting thread runs until the process ends.
pub struct Server {
    conns: Arc<Conns>,
}

impl Server {
    /// Connections open now (served, or being read).
    pub fn connections(&self) -> usize {
        self.conns.lock().open.len()
    }
}

/// Serves `listener` on a thread of its own until the process ends, with [`Limits::default`].
pub fn spawn(listener: TcpListener, hub: Hub) -> io::Result<Server> {
    spawn_with(listener, hub, Limits::default())
}

/// [`spawn`] with other limits (tests use short timeouts).
pub fn spawn_with(listener: TcpListener, hub: Hub, limits: Limits) -> io::Result<Server> {
    let loopback = listener.local_addr()?.ip().is_loopback();
    let conns = Arc::new(Conns {
        table: Mutex::default(),
        freed: Condvar::new(),
        hub: hub.clone(),
    });
    let server = Server {
        conns: conns.clone(),
    };
    std::thread::Builder::new()
        .name("http".into())
        .spawn(move || {
            for conn in listener.incoming() {
                let conn = match conn {
                    Ok(c) => c,
                    Err(_) => {
                        // Out of descriptors, for one: let connections end before the next.
                        std::thread::sleep(Duration::from_millis(50));
                        continue;
                    }
                };
                let Some(slot) = Conns::admit(&conns, &conn, limits.max_connections) else {
                    refuse(conn);
                    continue;
                };
                let hub = hub.clone();
                // A thread that cannot start drops its connection and its place with it.
                let _ = std::thread::Builder::new()
                    .name("http-conn".into())
                    .spawn(move || {
                        let _ = handle(conn, &hub, &slot, limits, loopback);
                    });
            }
        })?;
    Ok(server)
}

/// What an open connection is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    /// Reading the request's head (a client yet to say what it wants), or starting to answer.
    Head,
    /// Answering with a file.
    Answer,
    /// Streaming the events of the hub's page of this id.
    Stream(u64),
}

struct Entry {
    id: u64,
    stage: Stage,
    since: Instant,
    /// The connection itself, to shut it down when it must give its place up.
    socket: TcpStream,
    /// Told to give its place up (its thread has yet to end).
    evicted: bool,
}

#[derive(Default)]
struct Table {
    next_id: u64,
    open: Vec<Entry>,
}

/// The open connections: at most `max_connections`, each holding a [`Slot`].
struct Conns {
    table: Mutex<Table>,
    freed: Condvar,
    /// To end an evicted stream's wait for the next event at once.
    hub: Hub,
}

/// A connection's place among the open ones, given back when dropped.
struct Slot {
    conns: Arc<Conns>,
    id: u64,
}

impl Conns {
    fn lock(&self) -> MutexGuard<'_, Table> {
        self.table.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A place for `conn`: a free one, else the place of the oldest connection still sending
    /// its request, else of the oldest event stream (shut down, and its page dropped from the
    /// hub; its thread ends at once and gives the place back), waiting up to [`ADMIT_WAIT`].
    /// `None` if every place is answering a request.
    fn admit(conns: &Arc<Conns>, conn: &TcpStream, max: usize) -> Option<Slot> {
        let socket = conn.try_clone().ok()?;
        let deadline = Instant::now() + ADMIT_WAIT;
        let mut t = conns.lock();
        loop {
            if t.open.len() < max.max(1) {
                let id = t.next_id;
                t.next_id += 1;
                t.open.push(Entry {
                    id,
                    stage: Stage::Head,
                    since: Instant::now(),
                    socket,
                    evicted: false,
                });
                return Some(Slot {
                    conns: conns.clone(),
                    id,
                });
            }
            // One told to go already: wait for it; else tell the oldest of the first kind.
            if !t.open.iter().any(|e| e.evicted) {
                let heads = t.open.iter_mut().filter(|e| e.stage == Stage::Head);
                let victim = match heads.min_by_key(|e| e.since) {
                    Some(v) => v,
                    None => t
                        .open
                        .iter_mut()
                        .filter(|e| matches!(e.stage, Stage::Stream(_)))
                        .min_by_key(|e| e.since)?,
                };
                victim.evicted = true;
                let _ = victim.socket.shutdown(Shutdown::Both);
                if let Stage::Stream(page) = victim.stage {
                    conns.hub.forget(page);
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return None;
            }
            t = conns
                .freed
                .wait_timeout(t, left)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }
}

impl Slot {
    fn set_stage(&self, stage: Stage) {
        let mut t = self.conns.lock();
        if let Some(e) = t.open.iter_mut().find(|e| e.id == self.id) {
            e.stage = stage;
            e.since = Instant::now();
        }
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        self.conns.lock().open.retain(|e| e.id != self.id);
        self.conns.freed.notify_all();
    }
}

/// 503 to a connection with no place, without waiting for it.
fn refuse(mut conn: TcpStream) {
    let _ = conn.set_nonblocking(true);
    let body = "busy: too many connections\n";
    let _ = write!(
        conn,
        "HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain\r\nContent-Length: {}\r\nRetry-After: 1\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
}

/// Reads of a connection that give up at one deadline, however the bytes trickle in.
struct Deadline<'a> {
    conn: &'a TcpStream,
    until: Instant,
}

impl Read for Deadline<'_> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let left = self.until.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(io::Error::new(
                io::ErrorKind::TimedOut,
                "the request's head came too slowly",
            ));
        }
        self.conn.set_read_timeout(Some(left))?;
        let mut conn: &TcpStream = self.conn;
        conn.read(buf)
    }
}

/// The head of a request: its method and path, and its `Host` and `Origin` headers (`None`
/// when absent; a header given twice counts as wrong: an empty value).
#[derive(Debug, Default)]
struct Head {
    method: String,
    path: String,
    host: Option<String>,
    origin: Option<String>,
}

/// The request's head, whole, within `until`.
fn read_head(conn: &TcpStream, until: Instant) -> io::Result<Head> {
    let mut r = BufReader::new(Deadline { conn, until }).take(MAX_HEAD);
    let mut first = String::new();
    r.read_line(&mut first)?;
    let mut parts = first.split_whitespace();
    let mut head = Head {
        method: parts.next().unwrap_or("").to_string(),
        path: parts.next().unwrap_or("").to_string(),
        ..Head::default()
    };
    loop {
        let mut line = String::new();
        if r.read_line(&mut line)? == 0 {
            return Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                "the request's head ended early or is too long",
            ));
        }
        if line.trim().is_empty() {
            return Ok(head);
        }
        if let Some((k, v)) = line.split_once(':') {
            let field = if k.trim().eq_ignore_ascii_case("host") {
                &mut head.host
            } else if k.trim().eq_ignore_ascii_case("origin") {
                &mut head.origin
            } else {
                continue;
            };
            *field = match field {
                None => Some(v.trim().to_string()),
                Some(_) => Some(String::new()),
            };
        }
    }
}

/// Whether `host` (a `Host` header: a name or address, and an optional port) names this
/// machine's loopback literally: `localhost`, an IPv4 address in 127.0.0.0/8 as a dotted quad
/// or `[::1]`. A name that merely begins with `127.` is anybody's.
pub fn is_loopback_host(host: &str) -> bool {
    let (name, port, bracketed) = if let Some(rest) = host.strip_prefix('[') {
        let Some((ip, after)) = rest.split_once(']') else {
            return false;
        };
        let port = match after {
            "" => None,
            p => match p.strip_prefix(':') {
                Some(p) => Some(p),
                None => return false,
            },
        };
        (ip, port, true)
    } else {
        match host.split_once(':') {
            Some((h, p)) => (h, Some(p), false),
            None => (host, None, false),
        }
    };
    if let Some(p) = port {
        if p.is_empty() || !p.bytes().all(|b| b.is_ascii_digit()) || p.parse::<u16>().is_err() {
            return false;
        }
    }
    if bracketed {
        name.parse::<Ipv6Addr>().is_ok_and(|a| a.is_loopback())
    } else {
        name.eq_ignore_ascii_case("localhost")
            || name.parse::<Ipv4Addr>().is_ok_and(|a| a.is_loopback())
    }
}

/// Whether `origin` (an `Origin` header) is a page served over http from a loopback host
/// ([`is_loopback_host`]); `null`, https and every other host are not.
pub fn is_loopback_origin(origin: &str) -> bool {
    origin.strip_prefix("http://").is_some_and(is_loopback_host)
}

/// Why a request is refused, if it is.
fn refusal(head: &Head, loopback: bool) -> Option<&'static str> {
    if !loopback {
        return None;
    }
    if !head.host.as_deref().is_some_and(is_loopback_host) {
        return Some("forbidden host\n");
    }
    if head
        .origin
        .as_deref()
        .is_some_and(|o| !is_loopback_origin(o))
    {
        return Some("forbidden origin\n");
    }
    None
}

fn respond(conn: &mut TcpStream, status: &str, ctype: &str, body: &str) -> io::Result<()> {
    write!(
        conn,
        "HTTP/1.1 {status}\r\nContent-Type: {ctype}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nContent-Security-Policy: default-src 'self'\r\nX-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )?;
    conn.flush()
}

fn handle(
    mut conn: TcpStream,
    hub: &Hub,
    slot: &Slot,
    limits: Limits,
    loopback: bool,
) -> io::Result<()> {
    let head = read_head(&conn, Instant::now() + limits.head_deadline)?;
    conn.set_write_timeout(Some(limits.write_timeout))?;
    let path = head.path.split('?').next().unwrap_or("");
    if path != "/events" {
        slot.set_stage(Stage::Answer);
    }
    if let Some(why) = refusal(&head, loopback) {
        return respond(&mut conn, "403 Forbidden", "text/plain", why);
    }
    if head.method != "GET" {
        return respond(
            &mut conn,
            "405 Method Not Allowed",
            "text/plain",
            "GET only\n",
        );
    }
    match path {
        "/" | "/index.html" => respond(&mut conn, "200 OK", "text/html; charset=utf-8", INDEX),
        "/app.js" => respond(&mut conn, "200 OK", "text/javascript; charset=utf-8", APP),
        "/style.css" => respond(&mut conn, "200 OK", "text/css; charset=utf-8", STYLE),
        "/events" => events(conn, hub, slot),
        _ => respond(&mut conn, "404 Not Found", "text/plain", "not found\n"),
    }
}

/// The event stream: the history, then each event as it comes, until the page goes (or is
/// too slow to read, or gives its place up: its socket is shut down and its page dropped from
/// the hub).
fn events(conn: TcpStream, hub: &Hub, slot: &Slot) -> io::Result<()> {
    conn.set_nodelay(true)?;
    let (history, rx) = hub.subscribe();
    slot.set_stage(Stage::Stream(rx.id()));
    let mut out = io::BufWriter::new(conn);
    write!(
        out,
        "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-store\r\nX-Content-Type-Options: nosniff\r\nConnection: keep-alive\r\n\r\nretry: 1000\n\n"
    )?;
    // Each event is let go of once written: a stream keeps no copy of the history.
    for e in history {
        write!(out, "data: {e}\n\n")?;
    }
    out.flush()?;
    loop {
        match rx.recv_timeout(PING) {
            Ok(e) => {
                write!(out, "data: {e}\n\n")?;
                // Whatever else is waiting goes in the same write.
                while let Ok(e) = rx.try_recv() {
                    write!(out, "data: {e}\n\n")?;
                }
                out.flush()?;
            }
            Err(RecvTimeoutError::Timeout) => {
                out.write_all(b": ping\n\n")?;
                out.flush()?;
            }
            Err(RecvTimeoutError::Disconnected) => return Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn get(addr: std::net::SocketAddr, path: &str, host: &str) -> String {
        let mut c = TcpStream::connect(addr).unwrap();
        write!(c, "GET {path} HTTP/1.1\r\nHost: {host}\r\n\r\n").unwrap();
        let mut s = String::new();
        c.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        let _ = c.read_to_string(&mut s);
        s
    }

    #[test]
    fn the_page_its_scripts_and_the_event_stream() {
        let l = TcpListener::bind(("127.0.0.1", testkit::free_port())).unwrap();
        let addr = l.local_addr().unwrap();
        let hub = Hub::new(Some("r1"));
        spawn(l, hub.clone()).unwrap();
        let host = format!("127.0.0.1:{}", addr.port());
        let page = get(addr, "/", &host);
        assert!(page.starts_with("HTTP/1.1 200"), "{page}");
        assert!(page.contains("<script src=\"app.js\""), "{page}");
        // Every script and style is ours: nothing from another origin.
        assert!(!page.contains("http://") && !page.contains("https://"));
        assert!(!APP.contains("http://") && !APP.contains("https://"));
        assert!(get(addr, "/app.js", &host).contains("EventSource"));
        assert!(get(addr, "/nothing", &host).starts_with("HTTP/1.1 404"));
        assert!(get(addr, "/", "evil.example:80").starts_with("HTTP/1.1 403"));
        // The stream: the history, then a new event.
        let mut c = TcpStream::connect(addr).unwrap();
        write!(c, "GET /events HTTP/1.1\r\nHost: localhost\r\n\r\n").unwrap();
        c.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        let mut r = BufReader::new(c);
        let mut seen = String::new();
        while !seen.contains("\"run\":\"r1\"") {
            r.read_line(&mut seen).unwrap();
        }
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        while hub.pages() == 0 {
            assert!(std::time::Instant::now() < deadline);
            std::thread::yield_now();
        }
        hub.publish("{\"k\":\"x\"}".into(), false);
        let mut line = String::new();
        while !line.contains("\"k\":\"x\"") {
            line.clear();
            r.read_line(&mut line).unwrap();
        }
    }

    #[test]
    fn loopback_hosts_and_origins() {
        for h in [
            "localhost:8080",
            "LocalHost",
            "127.0.0.1:1",
            "127.255.0.9:65535",
            "[::1]:80",
            "[::1]",
            "localhost",
        ] {
            assert!(is_loopback_host(h), "{h}");
            assert!(is_loopback_origin(&format!("http://{h}")), "{h}");
        }
        for h in [
            "example.com",
            "10.0.0.1:80",
            "localhost.evil.com:80",
            "[fe80::1]:80",
            // Names an attacker may point at 127.0.0.1 (DNS rebinding).
            "127.attacker.example:8080",
            "127.0.0.1.nip.io",
            "127.1:80",
            "127.0.0.1.",
            // Not a Host at all.
            "::1",
            "[::1]x",
            "localhost:",
            "localhost:80:80",
            "localhost:99999",
            "localhost:+80",
            "",
        ] {
            assert!(!is_loopback_host(h), "{h}");
            assert!(!is_loopback_origin(&format!("http://{h}")), "{h}");
        }
        for o in [
            "null",
            "https://127.0.0.1:8080",
            "http://127.0.0.1:8080/",
            "127.0.0.1",
        ] {
            assert!(!is_loopback_origin(o), "{o}");
        }
    }
}
