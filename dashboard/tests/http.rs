//! The page's HTTP server as a client sees it, over raw TCP on 127.0.0.1: whom it answers
//! (`Host`, `Origin`: no DNS rebinding, no other site), and what a silent or slow client may
//! cost (a deadline on the request's head, a timeout on writes, a bounded number of places).

use std::io::Write;
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

use dashboard::http::{self, Limits};
use dashboard::Hub;

/// An event of the run whose secrets a foreign page must not read.
const SECRET: &str = r#"{"k":"m","r":"r1","v":{"secret":42}}"#;

fn serve(limits: Limits) -> (u16, Hub, http::Server) {
    let port = testkit::free_port();
    let l = TcpListener::bind(("127.0.0.1", port)).unwrap();
    let hub = Hub::new(Some("r1"));
    hub.publish(SECRET.into(), false);
    let server = http::spawn_with(l, hub.clone(), limits).unwrap();
    (port, hub, server)
}

/// Sends `head` (the request line is `GET path`) and reads the answer until it ends, or until
/// an event stream has sent the history's secret event.
fn ask(port: u16, path: &str, headers: &[(&str, &str)]) -> String {
    let mut c = TcpStream::connect(("127.0.0.1", port)).unwrap();
    let mut req = format!("GET {path} HTTP/1.1\r\n");
    for (k, v) in headers {
        req += &format!("{k}: {v}\r\n");
    }
    req += "\r\n";
    c.write_all(req.as_bytes()).unwrap();
    c.set_read_timeout(Some(Duration::from_millis(100)))
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    while Instant::now() < deadline && !String::from_utf8_lossy(&out).contains("secret") {
        let Some(n) = testkit::read_timed(&mut c, &mut buf) else {
            break;
        };
        out.extend_from_slice(&buf[..n]);
    }
    String::from_utf8_lossy(&out).into_owned()
}

fn refused(answer: &str) -> bool {
    answer.starts_with("HTTP/1.1 403") && !answer.contains("secret") && !answer.contains("data:")
}

fn streams(answer: &str) -> bool {
    answer.starts_with("HTTP/1.1 200")
        && answer.contains("text/event-stream")
        && answer.contains("secret")
}

#[test]
fn only_a_literal_loopback_host_is_answered() {
    let (port, _hub, _server) = serve(Limits::default());
    // The names of the issue's attack (and its kin) can be pointed at 127.0.0.1 by whoever
    // owns them: DNS rebinding.
    for host in [
        format!("127.attacker.example:{port}"),
        "127.attacker.example".to_string(),
        format!("127.0.0.1.nip.io:{port}"),
        format!("localhost.attacker.example:{port}"),
        format!("attacker.example:{port}"),
        format!("127.0.0.1:{port}x"),
        format!("[::1].attacker.example:{port}"),
    ] {
        for path in ["/events", "/"] {
            let answer = ask(port, path, &[("Host", &host)]);
            assert!(refused(&answer), "Host {host} {path}: {answer:?}");
        }
    }
    assert!(refused(&ask(port, "/events", &[])), "no Host");
    // Two Host headers, one of them loopback.
    let two = ask(
        port,
        "/events",
        &[("Host", "127.0.0.1"), ("Host", "127.attacker.example")],
    );
    assert!(refused(&two), "{two:?}");
    for host in [
        format!("127.0.0.1:{port}"),
        format!("localhost:{port}"),
        format!("[::1]:{port}"),
        format!("127.3.2.1:{port}"),
        "localhost".to_string(),
    ] {
        let answer = ask(port, "/events", &[("Host", &host)]);
        assert!(streams(&answer), "Host {host}: {answer:?}");
        assert!(
            ask(port, "/", &[("Host", &host)]).starts_with("HTTP/1.1 200"),
            "{host}"
        );
    }
}

#[test]
fn a_foreign_origin_is_refused() {
    let (port, _hub, _server) = serve(Limits::default());
    let host = format!("127.0.0.1:{port}");
    for origin in [
        "http://attacker.example".to_string(),
        format!("http://127.attacker.example:{port}"),
        format!("https://127.0.0.1:{port}"),
        "null".to_string(),
        format!("http://127.0.0.1:{port}.attacker.example"),
    ] {
        let answer = ask(port, "/events", &[("Host", &host), ("Origin", &origin)]);
        assert!(refused(&answer), "Origin {origin}: {answer:?}");
    }
    for origin in [
        format!("http://127.0.0.1:{port}"),
        format!("http://localhost:{port}"),
        format!("http://[::1]:{port}"),
    ] {
        let answer = ask(port, "/events", &[("Host", &host), ("Origin", &origin)]);
        assert!(streams(&answer), "Origin {origin}: {answer:?}");
    }
}

/// Whether the server has closed `c` (an end of stream or a reset, seen within 50 ms).
fn closed(c: &mut TcpStream) -> bool {
    c.set_read_timeout(Some(Duration::from_millis(50))).unwrap();
    let mut buf = [0u8; 1024];
    testkit::read_timed(c, &mut buf).is_none()
}

#[test]
fn a_request_head_that_trickles_in_is_cut_at_its_deadline() {
    let limits = Limits {
        head_deadline: Duration::from_secs(1),
        ..Limits::default()
    };
    let (port, _hub, server) = serve(limits);
    let mut c = TcpStream::connect(("127.0.0.1", port)).unwrap();
    c.write_all(format!("GET /events HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n").as_bytes())
        .unwrap();
    // A header line every 200 ms (each read gets bytes well within any per-read timeout),
    // never the blank line that ends the head: for up to 20 s.
    let mut cut = false;
    for i in 0..100 {
        if c.write_all(format!("X-Slow-{i}: a\r\n").as_bytes())
            .is_err()
            || closed(&mut c)
        {
            cut = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(150));
    }
    assert!(cut, "a head trickling in for 20 s was still being read");
    let deadline = Instant::now() + Duration::from_secs(10);
    while server.connections() > 0 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(server.connections(), 0);
}

#[test]
fn a_page_that_stops_reading_its_stream_is_dropped() {
    let (port, hub, server) = serve(Limits {
        write_timeout: Duration::from_secs(1),
        ..Limits::default()
    });
    // A history far larger than the socket buffers of both ends.
    let big = format!(r#"{{"k":"x","pad":"{}"}}"#, "p".repeat(10_000));
    for _ in 0..4_000 {
        hub.publish(big.clone(), false);
    }
    let mut c = TcpStream::connect(("127.0.0.1", port)).unwrap();
    write!(c, "GET /events HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n").unwrap();
    // The stream is up (its page subscribed), then never read.
    let deadline = Instant::now() + Duration::from_secs(20);
    while hub.pages() == 0 {
        assert!(Instant::now() < deadline, "the stream never started");
        std::thread::sleep(Duration::from_millis(20));
    }
    let deadline = Instant::now() + Duration::from_secs(60);
    while server.connections() > 0 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(
        server.connections(),
        0,
        "a page that reads nothing still holds its connection"
    );
    // Its place and its subscription are gone (the next event forgets it).
    hub.publish("{}".into(), false);
    assert_eq!(hub.pages(), 0);
    drop(c);
}

#[test]
fn past_the_cap_the_oldest_silent_connection_then_the_oldest_stream_give_their_place_up() {
    let limits = Limits {
        max_connections: 4,
        ..Limits::default()
    };
    let (port, hub, server) = serve(limits);
    let wait_for = |n: usize| {
        let deadline = Instant::now() + Duration::from_secs(20);
        while server.connections() != n {
            assert!(
                Instant::now() < deadline,
                "{} connections, not {n}",
                server.connections()
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    };
    // Four that never say a word fill the places.
    let mut silent = Vec::new();
    for _ in 0..4 {
        silent.push(TcpStream::connect(("127.0.0.1", port)).unwrap());
        wait_for(silent.len());
    }
    // A client with a request is served all the same, in the place of the oldest.
    let host = format!("127.0.0.1:{port}");
    assert!(ask(port, "/", &[("Host", &host)]).starts_with("HTTP/1.1 200"));
    assert!(
        closed(&mut silent[0]),
        "the oldest silent connection is still open"
    );
    // Four event streams: each newcomer takes a silent one's place first.
    let mut pages = Vec::new();
    for n in 1..=4 {
        let mut c = TcpStream::connect(("127.0.0.1", port)).unwrap();
        write!(c, "GET /events HTTP/1.1\r\nHost: {host}\r\n\r\n").unwrap();
        pages.push(c);
        // One after the other: the first is the oldest.
        let deadline = Instant::now() + Duration::from_secs(20);
        while hub.pages() < n {
            assert!(Instant::now() < deadline, "{} pages", hub.pages());
            std::thread::sleep(Duration::from_millis(10));
        }
    }
    wait_for(4);
    for s in &mut silent {
        assert!(
            closed(s),
            "a silent connection kept its place before a page"
        );
    }
    // A fifth page: the oldest gives its place up (its browser would reconnect).
    assert!(streams(&ask(port, "/events", &[("Host", &host)])));
    let mut first = pages.remove(0);
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut ended = false;
    while !ended && Instant::now() < deadline {
        ended = closed(&mut first);
    }
    assert!(ended, "the oldest page kept its place");
}
