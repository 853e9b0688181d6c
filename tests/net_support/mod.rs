//! What every test binary that runs processes or opens sockets needs: a free loopback port,
//! children killed and reaped however a test ends, a forgiving file read, and a raw zenoh
//! client of the test router logged in as one of the test CA's users.
#![allow(dead_code)]

use std::path::Path;
use std::time::{Duration, Instant};

use zenoh::{Session, Wait};

/// Free loopback ports and reaped children: the workspace's one dev-only helper crate.
#[allow(unused_imports)] // each test binary takes what it needs
pub use testkit::{ephemeral_low, free_port, Children, Reaped};

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
