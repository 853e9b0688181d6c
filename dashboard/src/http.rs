//! A small HTTP/1.1 server for the page: `GET /` (the page), `/app.js`, `/style.css` (compiled
//! into the binary: no CDN, no internet), and `/events`, a Server-Sent Events stream of the
//! hub's events (the history first). One thread per connection; requests other than these
//! get 404 or 405. A page served on a loopback address answers only requests whose `Host` is
//! a loopback name (no other site can read it through DNS rebinding).

use std::io::{self, BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::mpsc::RecvTimeoutError;
use std::time::Duration;

use crate::hub::Hub;

const INDEX: &str = include_str!("page/index.html");
const APP: &str = include_str!("page/app.js");
const STYLE: &str = include_str!("page/style.css");

/// How often an idle event stream sends a comment (a closed page is noticed then).
pub const PING: Duration = Duration::from_secs(10);

/// Serves `listener` on a thread of its own until the process ends.
pub fn spawn(listener: TcpListener, hub: Hub) -> io::Result<std::thread::JoinHandle<()>> {
    let loopback = listener.local_addr()?.ip().is_loopback();
    std::thread::Builder::new()
        .name("http".into())
        .spawn(move || {
            for conn in listener.incoming() {
                let Ok(conn) = conn else { continue };
                let hub = hub.clone();
                let _ = std::thread::Builder::new()
                    .name("http-conn".into())
                    .spawn(move || {
                        let _ = handle(conn, &hub, loopback);
                    });
            }
        })
}

/// The request line's method and path, and the `Host` header.
fn read_head(conn: &TcpStream) -> io::Result<(String, String, Option<String>)> {
    let mut r = BufReader::new(conn.try_clone()?).take(16 * 1024);
    let mut first = String::new();
    r.read_line(&mut first)?;
    let mut parts = first.split_whitespace();
    let method = parts.next().unwrap_or("").to_string();
    let path = parts.next().unwrap_or("").to_string();
    let mut host = None;
    loop {
        let mut line = String::new();
        if r.read_line(&mut line)? == 0 || line.trim().is_empty() {
            break;
        }
        if let Some((k, v)) = line.split_once(':') {
            if k.trim().eq_ignore_ascii_case("host") {
                host = Some(v.trim().to_string());
            }
        }
    }
    Ok((method, path, host))
}

/// Whether `host` (a `Host` header) names this machine's loopback.
pub fn is_loopback_host(host: &str) -> bool {
    let name = if let Some(rest) = host.strip_prefix('[') {
        rest.split(']').next().unwrap_or("")
    } else {
        host.rsplit_once(':').map_or(host, |(h, _)| h)
    };
    matches!(name, "localhost" | "127.0.0.1" | "::1") || name.starts_with("127.")
}

fn respond(conn: &mut TcpStream, status: &str, ctype: &str, body: &str) -> io::Result<()> {
    write!(
        conn,
        "HTTP/1.1 {status}\r\nContent-Type: {ctype}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nContent-Security-Policy: default-src 'self'\r\nX-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )?;
    conn.flush()
}

fn handle(mut conn: TcpStream, hub: &Hub, loopback: bool) -> io::Result<()> {
    conn.set_read_timeout(Some(Duration::from_secs(10)))?;
    let (method, path, host) = read_head(&conn)?;
    if loopback && !host.as_deref().is_some_and(is_loopback_host) {
        return respond(&mut conn, "403 Forbidden", "text/plain", "forbidden host\n");
    }
    if method != "GET" {
        return respond(
            &mut conn,
            "405 Method Not Allowed",
            "text/plain",
            "GET only\n",
        );
    }
    match path.split('?').next().unwrap_or("") {
        "/" | "/index.html" => respond(&mut conn, "200 OK", "text/html; charset=utf-8", INDEX),
        "/app.js" => respond(&mut conn, "200 OK", "text/javascript; charset=utf-8", APP),
        "/style.css" => respond(&mut conn, "200 OK", "text/css; charset=utf-8", STYLE),
        "/events" => events(conn, hub),
        _ => respond(&mut conn, "404 Not Found", "text/plain", "not found\n"),
    }
}

/// The event stream: the history, then each event as it comes, until the page goes.
fn events(conn: TcpStream, hub: &Hub) -> io::Result<()> {
    conn.set_nodelay(true)?;
    let (history, rx) = hub.subscribe();
    let mut out = io::BufWriter::new(conn.try_clone()?);
    write!(
        out,
        "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-store\r\nX-Content-Type-Options: nosniff\r\nConnection: keep-alive\r\n\r\nretry: 1000\n\n"
    )?;
    for e in &history {
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
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
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
    fn loopback_hosts() {
        for h in ["localhost:8080", "127.0.0.1:1", "[::1]:80", "localhost"] {
            assert!(is_loopback_host(h), "{h}");
        }
        for h in [
            "example.com",
            "10.0.0.1:80",
            "localhost.evil.com:80",
            "[fe80::1]:80",
        ] {
            assert!(!is_loopback_host(h), "{h}");
        }
    }
}
