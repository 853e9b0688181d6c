//! What every test binary that runs processes or opens sockets needs: a free loopback port,
//! children killed and reaped however a test ends, a forgiving file read, and a raw zenoh
//! client of the test router logged in as one of the test CA's users.
#![allow(dead_code)]

use std::net::TcpListener;
use std::path::Path;
use std::process::Child;
use std::time::{Duration, Instant};

use zenoh::{Session, Wait};

/// A TCP port on 127.0.0.1 that was free a moment ago, below the kernel's ephemeral range
/// (`/proc/sys/net/ipv4/ip_local_port_range`) and never the same twice in one test binary.
/// A port the kernel hands out for `bind(0)` is an ephemeral one, which any outgoing
/// connection (another test's zenoh client) may take as its source port before the process the
/// port was meant for binds it: a fresh-clone CI run lost a learner that way ("Address already
/// in use" on its `--listen` port for three minutes).
pub fn free_port() -> u16 {
    use std::sync::atomic::{AtomicU32, Ordering};
    static NEXT: AtomicU32 = AtomicU32::new(0);
    const LOW: u32 = 10_000;
    let high = ephemeral_low().clamp(LOW + 1000, 65_535);
    let span = high - LOW;
    // Binaries run one after another, but start each at its own place.
    let start = std::process::id().wrapping_mul(7919) % span;
    for _ in 0..span {
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let port = (LOW + (start + n) % span) as u16;
        if TcpListener::bind(("127.0.0.1", port)).is_ok() {
            return port;
        }
    }
    panic!("no free TCP port on 127.0.0.1 in {LOW}..{high}");
}

/// The lowest ephemeral port (Linux's default 32768 when the file cannot be read).
pub fn ephemeral_low() -> u32 {
    std::fs::read_to_string("/proc/sys/net/ipv4/ip_local_port_range")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(32_768)
}

/// Child processes killed and reaped when the test ends, whatever happens.
pub struct Children(pub Vec<Child>);

impl Drop for Children {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// One child, killed and reaped on drop.
pub struct Reaped(pub Child);

impl Drop for Reaped {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The file's text, or nothing if it cannot be read (yet).
pub fn read(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_default()
}

/// `user`'s password, from the test CA's files in `secrets`
/// (`multihost_support::make_secrets`).
pub fn password(secrets: &Path, user: &str) -> String {
    std::fs::read_to_string(secrets.join(format!("{user}.password")))
        .unwrap()
        .lines()
        .next()
        .unwrap()
        .to_string()
}

/// A raw zenoh client of the TLS router at 127.0.0.1:`port` as `user` (scouting off), retried
/// until the router answers or `patience` runs out.
pub fn router_session(secrets: &Path, port: u16, user: &str, patience: Duration) -> Session {
    let q = |s: &str| serde_json::to_string(s).unwrap();
    let mut c = zenoh::Config::default();
    for (k, v) in [
        ("mode", q("client")),
        (
            "connect/endpoints",
            format!("[{}]", q(&format!("tls/127.0.0.1:{port}"))),
        ),
        ("scouting/multicast/enabled", "false".into()),
        (
            "transport/link/tls/root_ca_certificate",
            q(&secrets.join("certs/ca.crt").to_string_lossy()),
        ),
        ("transport/auth/usrpwd/user", q(user)),
        (
            "transport/auth/usrpwd/password",
            q(&password(secrets, user)),
        ),
    ] {
        c.insert_json5(k, &v).unwrap_or_else(|e| panic!("{k}: {e}"));
    }
    let start = Instant::now();
    loop {
        match zenoh::open(c.clone()).wait() {
            Ok(s) => return s,
            Err(e) if start.elapsed() > patience => panic!("{user}: no session: {e}"),
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    }
}
