//! Dev-only helpers shared by every crate's tests and benches (never a normal dependency).
//!
//! - [`free_port`]: a loopback TCP port for a process a test starts. Every test and bench that
//!   needs one asks here; none calls `bind(0)` itself (see the function for why).
//! - [`Children`], [`Reaped`]: child processes killed and reaped however a test ends.
//! - [`read_timed`]: one read of a socket with a read timeout, a timeout not being an end.
//! - [`assert_same_spacing`]: two series of times (seconds) spaced alike, whatever their start.

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

/// One read of `r` (a socket with a read timeout): `Some(n)` for `n` bytes read, `Some(0)` when
/// the timeout passed with nothing to read (`WouldBlock`, `TimedOut`), `None` at the end of the
/// stream or on any other error.
pub fn read_timed(r: &mut impl std::io::Read, buf: &mut [u8]) -> Option<usize> {
    use std::io::ErrorKind::{TimedOut, WouldBlock};
    match r.read(buf) {
        Ok(0) => None,
        Ok(n) => Some(n),
        Err(e) if matches!(e.kind(), WouldBlock | TimedOut) => Some(0),
        Err(_) => None,
    }
}

/// Asserts that the times `got` (seconds, one per point) keep the spacing of `want`: each less
/// its series' first agrees within 1 ms. `what` says where `got` was read, for the message.
pub fn assert_same_spacing(got: &[f64], want: &[f64], what: &str) {
    assert_eq!(got.len(), want.len(), "{got:?} in {what} against {want:?}");
    for (i, (t, w)) in got.iter().zip(want).enumerate() {
        let (dt, dw) = (t - got[0], w - want[0]);
        assert!(
            (dt - dw).abs() < 1e-3,
            "point {i}: {dt:.4} s after the first in {what}, {dw:.4} s in the log"
        );
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
            assert!(
                (10_000..low.max(11_000)).contains(&u32::from(p)),
                "{p} vs {low}"
            );
            TcpListener::bind(("127.0.0.1", p)).expect("still free");
        }
    }

    #[test]
    fn spacing_ignores_the_start_and_nothing_else() {
        assert_same_spacing(&[100.0, 110.0, 110.5], &[3.0, 13.0, 13.5], "here");
        let shifted = std::panic::catch_unwind(|| {
            assert_same_spacing(&[100.0, 110.0, 111.0], &[3.0, 13.0, 13.5], "here")
        });
        assert!(shifted.is_err());
    }

    #[test]
    fn a_timed_read_tells_data_from_the_timeout_and_the_end() {
        struct Script(Vec<std::io::Result<usize>>);
        impl std::io::Read for Script {
            fn read(&mut self, _: &mut [u8]) -> std::io::Result<usize> {
                self.0.remove(0)
            }
        }
        let err = |k| Err(std::io::Error::from(k));
        use std::io::ErrorKind::{BrokenPipe, TimedOut, WouldBlock};
        let mut r = Script(vec![
            Ok(5),
            err(WouldBlock),
            err(TimedOut),
            Ok(0),
            err(BrokenPipe),
        ]);
        let mut buf = [0u8; 8];
        let got: Vec<_> = (0..5).map(|_| read_timed(&mut r, &mut buf)).collect();
        assert_eq!(got, [Some(5), Some(0), Some(0), None, None]);
    }
}
