//! Dev-only helpers shared by every crate's tests and benches (never a normal dependency).
//!
//! - [`free_port`]: a loopback TCP port for a process a test starts. Every test and bench that
//!   needs one asks here; none calls `bind(0)` itself (see the function for why).
//! - [`Children`], [`Reaped`]: child processes killed and reaped however a test ends.

use std::net::TcpListener;
use std::process::Child;

/// A TCP port on 127.0.0.1 that was free a moment ago, below the kernel's ephemeral range
/// (`/proc/sys/net/ipv4/ip_local_port_range`) and never the same twice in one test binary.
///
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ports_are_below_the_ephemeral_range_and_never_repeat() {
        let low = ephemeral_low();
        let a = free_port();
        let b = free_port();
        assert_ne!(a, b);
        for p in [a, b] {
            assert!((10_000..low.max(11_000)).contains(&u32::from(p)), "{p} vs {low}");
            TcpListener::bind(("127.0.0.1", p)).expect("still free");
        }
    }
}
