//! What the tests of `fsrl serve` share (`serve.rs`, `serve_flood.rs`): the server started and
//! waited for, its log read line by line, a robot on the bridge keys (odometry, people and goal
//! stamped with this computer's clock, the commands it receives with the instant they came),
//! and the server's resident memory.
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

pub use serve::fixtures::{goal, odometry, people};
use serve::msg::{self, Twist};
use zenoh::Wait;

use crate::net_support::Reaped;

/// The shipped model `fsrl serve` drives with.
pub fn model_path() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("models/fsrl-env1-invisible-s0.fsrlm")
        .to_string_lossy()
        .into_owned()
}

/// A running `fsrl serve`: killed on drop; its stderr lines (echoed to the test's) in `log`.
pub struct Served {
    pub proc: Reaped,
    pub log: mpsc::Receiver<String>,
}

impl Served {
    /// Starts `fsrl serve MODEL` listening on `listen` (an endpoint) and waits for `ready`.
    pub fn start(model: &Path, listen: &str, extra: &[&str]) -> Served {
        let mut c = Command::new(env!("CARGO_BIN_EXE_fsrl"))
            .arg("serve")
            .arg(model)
            .arg("--listen")
            .arg(listen)
            .args(extra)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let stdout = c.stdout.take().unwrap();
        let stderr = c.stderr.take().unwrap();
        let proc = Reaped(c);
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                let _ = tx.send(line);
            }
        });
        let (tx, log) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("[serve] {line}");
                let _ = tx.send(line);
            }
        });
        let ready = rx.recv_timeout(Duration::from_secs(60));
        assert_eq!(
            ready.as_deref(),
            Ok("ready"),
            "fsrl serve did not become ready"
        );
        Served { proc, log }
    }

    /// The shipped model on 127.0.0.1:`port`.
    pub fn shipped(port: u16, extra: &[&str]) -> Served {
        Self::start(
            Path::new(&model_path()),
            &format!("tcp/127.0.0.1:{port}"),
            extra,
        )
    }

    pub fn pid(&self) -> u32 {
        self.proc.0.id()
    }

    /// The next log line containing `what` (earlier lines are passed over).
    pub fn wait_log(&self, what: &str, within: Duration) -> String {
        let deadline = Instant::now() + within;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.log.recv_timeout(left) {
                Ok(line) if line.contains(what) => return line,
                Ok(_) => {}
                Err(_) => panic!("no log line with {what:?} within {within:?}"),
            }
        }
    }

    /// Passes over every log line printed so far: what is waited for next comes after now.
    pub fn skip_log(&self) {
        while self.log.try_recv().is_ok() {}
    }

    /// The reason of the next zero command logged (`zero command: REASON`): the first one after
    /// the lines read so far, whatever it says.
    pub fn next_stop_reason(&self, within: Duration) -> String {
        let line = self.wait_log("zero command: ", within);
        line.split("zero command: ")
            .nth(1)
            .unwrap_or("")
            .to_string()
    }

    /// Sends SIGTERM and waits for the exit; its status.
    pub fn terminate(&mut self) -> std::process::ExitStatus {
        // SAFETY: sending a signal to our own child.
        unsafe {
            libc::kill(self.pid() as i32, libc::SIGTERM);
        }
        self.proc.0.wait().unwrap()
    }
}

/// This computer's clock, seconds since the epoch (what a robot stamps with).
pub fn now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

/// Resident memory of process `pid` in MB (`VmRSS` of `/proc/<pid>/status`).
pub fn rss_mb(pid: u32) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next()?.parse::<f64>().ok())
        .map_or(0.0, |kb| kb / 1024.0)
}

/// A zenoh peer of `fsrl serve` on loopback (multicast scouting off), connecting to
/// `endpoint`.
pub fn session(endpoint: &str) -> zenoh::Session {
    let cfg = transport::ZenohConfig::peer(vec!["tcp/127.0.0.1:0".into()], vec![endpoint.into()])
        .to_zenoh(8 << 20)
        .unwrap();
    zenoh::open(cfg).wait().unwrap()
}

/// A robot on the bridge keys: puts inputs, receives `cmd_vel` with the instant it came.
pub struct Robot {
    pub session: zenoh::Session,
    pub cmd: mpsc::Receiver<(Instant, Twist)>,
    _sub: zenoh::pubsub::Subscriber<()>,
}

impl Robot {
    pub fn connect(endpoint: &str) -> Self {
        Self::with_session(session(endpoint))
    }

    /// A robot on `session` (a router's client, say).
    pub fn with_session(session: zenoh::Session) -> Self {
        let (tx, cmd) = mpsc::channel();
        let sub = session
            .declare_subscriber("cmd_vel")
            .callback(move |s| {
                if let Ok(t) = msg::decode::<Twist>(&s.payload().to_bytes()) {
                    let _ = tx.send((Instant::now(), t));
                }
            })
            .wait()
            .unwrap();
        Self {
            session,
            cmd,
            _sub: sub,
        }
    }

    pub fn put(&self, key: &str, bytes: Vec<u8>) {
        self.session.put(key, bytes).wait().unwrap();
    }

    /// Goal, people and odometry stamped now: a robot with everything fresh.
    pub fn fresh(&self) {
        let t = now_s();
        self.put("goal_pose", goal("odom", t));
        self.put("people", people("odom", t, 1));
        self.put("odom", odometry(t));
    }

    /// Waits (20 s at most) for a command satisfying `pred` while `feed` runs every 50 ms.
    pub fn until(&self, what: &str, mut feed: impl FnMut(), pred: impl Fn(&Twist) -> bool) {
        let deadline = Instant::now() + Duration::from_secs(20);
        while Instant::now() < deadline {
            feed();
            if let Ok((_, t)) = self.cmd.recv_timeout(Duration::from_millis(50)) {
                if pred(&t) {
                    return;
                }
            }
        }
        panic!("no command: {what}");
    }

    /// Forgets the commands received so far.
    pub fn drain(&self) {
        while self.cmd.try_recv().is_ok() {}
    }
}

pub fn moving(t: &Twist) -> bool {
    t.linear.x != 0.0 || t.angular.z != 0.0
}

pub fn zero(t: &Twist) -> bool {
    *t == Twist::ZERO
}

/// One TCP socket on this machine from `/proc/net/tcp`: its ports and the bytes in its send
/// queue (sent, not acknowledged: the peer's window is full) and its receive queue (received,
/// not read by its process).
#[derive(Debug, Clone, Copy)]
pub struct TcpQueues {
    pub local_port: u16,
    pub remote_port: u16,
    pub tx_bytes: u64,
    pub rx_bytes: u64,
}

/// Every IPv4 TCP socket with `port` at either end.
pub fn tcp_queues(port: u16) -> Vec<TcpQueues> {
    let text = std::fs::read_to_string("/proc/net/tcp").unwrap_or_default();
    let port_of = |addr: &str| {
        addr.split(':')
            .nth(1)
            .and_then(|p| u16::from_str_radix(p, 16).ok())
    };
    text.lines()
        .skip(1)
        .filter_map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            let (tx, rx) = f.get(4)?.split_once(':')?;
            Some(TcpQueues {
                local_port: port_of(f.get(1)?)?,
                remote_port: port_of(f.get(2)?)?,
                tx_bytes: u64::from_str_radix(tx, 16).ok()?,
                rx_bytes: u64::from_str_radix(rx, 16).ok()?,
            })
        })
        .filter(|q| q.local_port == port || q.remote_port == port)
        .collect()
}

/// The value of `name=` in a log line of the server (its exit summary's counts), if it is there.
pub fn summary_field(line: &str, name: &str) -> Option<u64> {
    line.split(&format!(" {name}="))
        .nth(1)
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
}
