//! 2,000 clients that connect and never read (a quarter never finish their request, a quarter
//! ask for the event stream of a long history, a quarter for the page, a quarter say nothing):
//! the server's threads and memory stay bounded, and a well-behaved client still gets the page
//! and its events meanwhile. Alone in its test binary: the counts are this process's.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

use dashboard::http::{self, MAX_CONNECTIONS};
use dashboard::Hub;

const CLIENTS: usize = 2_000;

/// A field of /proc/self/status (threads; memory in kB).
fn status(field: &str) -> u64 {
    let s = std::fs::read_to_string("/proc/self/status").unwrap();
    s.lines()
        .find_map(|l| l.strip_prefix(field)?.strip_prefix(':'))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("no {field} in /proc/self/status"))
}

/// Room for this test's descriptors: its clients and the server's side of them.
fn raise_fd_limit(need: u64) {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit/setrlimit on a struct of ours.
    unsafe {
        assert_eq!(libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim), 0);
        if lim.rlim_cur < need as libc::rlim_t {
            lim.rlim_cur = lim.rlim_max.min(need as libc::rlim_t);
            assert_eq!(libc::setrlimit(libc::RLIMIT_NOFILE, &lim), 0);
        }
    }
    assert!(
        lim.rlim_cur >= need as libc::rlim_t,
        "this test needs {need} file descriptors; the hard limit is {}",
        lim.rlim_max
    );
}

/// GET / as a browser would: the whole answer.
fn page(port: u16) -> String {
    let mut c = TcpStream::connect(("127.0.0.1", port)).unwrap();
    write!(c, "GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n").unwrap();
    c.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    let mut s = String::new();
    let _ = c.read_to_string(&mut s);
    s
}

#[test]
fn two_thousand_clients_that_never_read_cost_bounded_threads_and_memory() {
    raise_fd_limit(3 * CLIENTS as u64 + 256);
    let port = testkit::free_port();
    let listener = TcpListener::bind(("127.0.0.1", port)).unwrap();
    let hub = Hub::new(Some("r1"));
    // A long run's history (4,000 events, 2 MB): each stream used to keep its own copy.
    let event = format!(r#"{{"k":"m","r":"r1","pad":"{}"}}"#, "p".repeat(500));
    for _ in 0..4_000 {
        hub.publish(event.clone(), false);
    }
    let server = http::spawn(listener, hub.clone()).unwrap();
    assert!(page(port).starts_with("HTTP/1.1 200"));
    let (threads_before, rss_before) = (status("Threads"), status("VmRSS"));
    // The server's threads: at most one per place (and a few whose place is given back and
    // that are ending), whatever the number of clients.
    let max_threads = threads_before + MAX_CONNECTIONS as u64 + 32;
    let mut most_threads = threads_before;

    let host = format!("127.0.0.1:{port}");
    let mut clients = Vec::with_capacity(CLIENTS);
    for i in 0..CLIENTS {
        let mut c =
            TcpStream::connect_timeout(&([127, 0, 0, 1], port).into(), Duration::from_secs(20))
                .unwrap_or_else(|e| panic!("client {i} cannot connect: {e}"));
        let _ = match i % 4 {
            0 => Ok(()),
            1 => write!(c, "GET /events HTTP/1.1\r\nHost: {host}\r\n"),
            2 => write!(c, "GET /events HTTP/1.1\r\nHost: {host}\r\n\r\n"),
            _ => write!(c, "GET / HTTP/1.1\r\nHost: {host}\r\n\r\n"),
        };
        clients.push(c);
        if i % 50 == 0 {
            most_threads = most_threads.max(status("Threads"));
        }
    }
    most_threads = most_threads.max(status("Threads"));
    assert!(
        most_threads <= max_threads,
        "{most_threads} threads with {CLIENTS} clients that never read (at most {max_threads})"
    );
    assert!(server.connections() <= MAX_CONNECTIONS);

    // Meanwhile, with every client still connected: the page, and its live events.
    assert!(
        page(port).starts_with("HTTP/1.1 200"),
        "the page is not served"
    );
    let mut c = TcpStream::connect(("127.0.0.1", port)).unwrap();
    write!(c, "GET /events HTTP/1.1\r\nHost: {host}\r\n\r\n").unwrap();
    c.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    let mut r = BufReader::new(c);
    let mut line = String::new();
    r.read_line(&mut line).unwrap();
    assert!(line.starts_with("HTTP/1.1 200"), "{line:?}");
    // Through the history to a new event (bounded: the history's lines and then some).
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut published = false;
    let mut seen = false;
    for _ in 0..100_000 {
        line.clear();
        if r.read_line(&mut line).unwrap_or(0) == 0 || Instant::now() > deadline {
            break;
        }
        if !published && line.contains("\"run\":\"r1\"") {
            hub.publish(r#"{"k":"now"}"#.into(), false);
            published = true;
        }
        if line.contains(r#""k":"now""#) {
            seen = true;
            break;
        }
    }
    assert!(seen, "the well-behaved page got no live event");

    let (threads, rss) = (status("Threads"), status("VmRSS"));
    most_threads = most_threads.max(threads);
    assert!(
        most_threads <= max_threads,
        "{most_threads} threads (at most {max_threads})"
    );
    // Memory: the places' copies of the history and their buffers, far below one copy per
    // client (2,000 × 4,000 events).
    let grown_mb = rss.saturating_sub(rss_before) / 1024;
    eprintln!(
        "threads {threads_before} -> at most {most_threads}; memory +{grown_mb} MB; {} connections",
        server.connections()
    );
    assert!(grown_mb < 48, "memory grew by {grown_mb} MB");
    drop(clients);
}
