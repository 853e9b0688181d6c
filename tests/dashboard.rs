//! `fsrl train --dashboard PORT`: the live page opened in headless Chromium (Debian's
//! `chromium`, or FSRL_CHROMIUM; tools/test.sh installs it), driven over the DevTools protocol
//! on a pipe (`--remote-debugging-pipe`: JSON messages ending in a NUL byte on fds 3 and 4).
//! From the page's DOM: the validation curve gains points while the run goes on, and the count
//! of actors alive drops when an actor process is killed. With FSRL_DASHBOARD_SCREENSHOT=PATH
//! the test also writes its screenshot there, after FSRL_DASHBOARD_SCREENSHOT_EPISODES RL
//! episodes (default: at once), with 200 demonstrations × 20 epochs and validating 20 episodes
//! every 25 (docs/pictures/dashboard.png:
//! `FSRL_DASHBOARD_SCREENSHOT=docs/pictures/dashboard.png FSRL_DASHBOARD_SCREENSHOT_EPISODES=600
//! cargo test --release --test dashboard`).
//!
//! `fsrl dashboard` without `--run`: every run it sees, each under its id, and every process's
//! state and last error from its status heartbeats (a real learner's, and this test's own
//! zenoh sessions publishing a second run).
//!
//! Through a secured cluster's router (`fsrl router` with `deploy/router.json5` and the test
//! CA, on loopback): a page with the monitor's credentials (`deploy/cluster-monitor.toml`)
//! streams the learner's metrics; one with an actor's credentials gets none of them.

mod multihost_support;
mod net_support;

use std::fs::File;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::os::fd::FromRawFd;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use net_support::free_port;
use proto::{keys, Metrics, Role, RunId, SenderId};
use serde_json::{json, Value};
use transport::{Transport, TransportConfig, ZenohConfig};

/// The descendants of `pid` (from /proc), children first.
fn descendants(pid: u32) -> Vec<u32> {
    let mut out = Vec::new();
    let mut frontier = vec![pid];
    while let Some(p) = frontier.pop() {
        for entry in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
            let Ok(child) = entry.file_name().to_string_lossy().parse::<u32>() else {
                continue;
            };
            let stat = std::fs::read_to_string(entry.path().join("stat")).unwrap_or_default();
            // pid (comm) state ppid ...: the comm may hold spaces, so from the last ')'.
            let ppid = stat
                .rsplit_once(')')
                .and_then(|(_, rest)| rest.split_whitespace().nth(1))
                .and_then(|p| p.parse::<u32>().ok());
            if ppid == Some(p) {
                out.push(child);
                frontier.push(child);
            }
        }
    }
    out
}

fn cmdline(pid: u32) -> Vec<String> {
    std::fs::read(format!("/proc/{pid}/cmdline"))
        .unwrap_or_default()
        .split(|&b| b == 0)
        .map(|s| String::from_utf8_lossy(s).into_owned())
        .collect()
}

fn signal(pid: u32, sig: i32) {
    // SAFETY: kill(2) on a process this test started (or one of its children).
    unsafe {
        libc::kill(pid as libc::pid_t, sig);
    }
}

/// A process tree stopped on every way out: SIGINT (the launcher stops its children), then
/// SIGKILL for whatever is left.
struct Tree(Child);

impl Drop for Tree {
    fn drop(&mut self) {
        let all = descendants(self.0.id());
        if let Ok(None) = self.0.try_wait() {
            signal(self.0.id(), libc::SIGINT);
            let deadline = Instant::now() + Duration::from_secs(30);
            while Instant::now() < deadline && matches!(self.0.try_wait(), Ok(None)) {
                std::thread::sleep(Duration::from_millis(100));
            }
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
        for p in all {
            signal(p, libc::SIGKILL);
        }
    }
}

/// Headless Chromium driven over the DevTools protocol on a pipe.
struct Browser {
    child: Child,
    to: File,
    from: BufReader<File>,
    id: u64,
    session: Option<String>,
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        for p in descendants(self.child.id()) {
            signal(p, libc::SIGKILL);
        }
    }
}

fn pipe() -> (i32, i32) {
    let mut fds = [0i32; 2];
    // SAFETY: pipe2 fills the two descriptors; close-on-exec keeps them out of other children.
    assert_eq!(unsafe { libc::pipe2(fds.as_mut_ptr(), libc::O_CLOEXEC) }, 0);
    (fds[0], fds[1])
}

impl Browser {
    fn launch(url: &str, profile: &Path) -> Browser {
        let exe = std::env::var("FSRL_CHROMIUM").unwrap_or_else(|_| "chromium".into());
        let (chrome_reads, we_write) = pipe();
        let (we_read, chrome_writes) = pipe();
        let mut cmd = Command::new(&exe);
        cmd.args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--disable-extensions",
            "--hide-scrollbars",
            "--remote-debugging-pipe",
            "--window-size=1400,1000",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(url)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null());
        // SAFETY: between fork and exec only async-signal-safe calls: the two pipe ends are
        // copied above 10 (so neither is overwritten) and then onto fds 3 and 4, which dup2
        // leaves open across exec.
        unsafe {
            std::os::unix::process::CommandExt::pre_exec(&mut cmd, move || {
                let a = libc::fcntl(chrome_reads, libc::F_DUPFD, 10);
                let b = libc::fcntl(chrome_writes, libc::F_DUPFD, 10);
                if a < 0 || b < 0 || libc::dup2(a, 3) < 0 || libc::dup2(b, 4) < 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
        let child = cmd.spawn().unwrap_or_else(|e| {
            panic!("cannot start {exe} (tools/test.sh installs Debian's chromium; or set FSRL_CHROMIUM): {e}")
        });
        // SAFETY: the descriptors are ours; the child's copies were made at fork.
        unsafe {
            libc::close(chrome_reads);
            libc::close(chrome_writes);
        }
        // SAFETY: each descriptor is owned by exactly one File from here on.
        let (to, from) = unsafe { (File::from_raw_fd(we_write), File::from_raw_fd(we_read)) };
        Browser {
            child,
            to,
            from: BufReader::new(from),
            id: 0,
            session: None,
        }
    }

    /// Sends a command and returns its result (events in between are skipped).
    fn call(&mut self, method: &str, params: Value) -> Value {
        self.id += 1;
        let mut msg = json!({"id": self.id, "method": method, "params": params});
        if let Some(s) = &self.session {
            msg["sessionId"] = json!(s);
        }
        let mut bytes = serde_json::to_vec(&msg).unwrap();
        bytes.push(0);
        self.to.write_all(&bytes).unwrap();
        loop {
            let mut buf = Vec::new();
            let n = self.from.read_until(0, &mut buf).unwrap();
            assert!(n > 0, "chromium closed its DevTools pipe");
            buf.pop();
            let v: Value = serde_json::from_slice(&buf).unwrap();
            if v["id"] == json!(self.id) {
                assert!(v.get("error").is_none(), "{method}: {v}");
                return v["result"].clone();
            }
        }
    }

    /// Attaches to the page showing `url`.
    fn attach(&mut self, url: &str) {
        let deadline = Instant::now() + Duration::from_secs(60);
        let target = loop {
            let t = self.call("Target.getTargets", json!({}));
            let page = t["targetInfos"]
                .as_array()
                .unwrap()
                .iter()
                .find(|i| i["type"] == "page" && i["url"].as_str().unwrap_or("").starts_with(url))
                .map(|i| i["targetId"].clone());
            if let Some(id) = page {
                break id;
            }
            assert!(Instant::now() < deadline, "no page for {url}: {t}");
            std::thread::sleep(Duration::from_millis(100));
        };
        let s = self.call(
            "Target.attachToTarget",
            json!({"targetId": target, "flatten": true}),
        );
        self.session = Some(s["sessionId"].as_str().unwrap().to_string());
    }

    /// The value of a JavaScript expression in the page.
    fn eval(&mut self, expr: &str) -> Value {
        let r = self.call(
            "Runtime.evaluate",
            json!({"expression": expr, "returnByValue": true}),
        );
        r["result"]["value"].clone()
    }

    fn screenshot(&mut self) -> Vec<u8> {
        let height = self
            .eval("document.documentElement.scrollHeight")
            .as_u64()
            .unwrap_or(1000);
        self.call(
            "Emulation.setDeviceMetricsOverride",
            json!({"width": 1400, "height": height, "deviceScaleFactor": 1, "mobile": false}),
        );
        let r = self.call("Page.captureScreenshot", json!({"format": "png"}));
        base64(r["data"].as_str().unwrap())
    }
}

fn base64(s: &str) -> Vec<u8> {
    let val = |c: u8| -> u32 {
        match c {
            b'A'..=b'Z' => (c - b'A') as u32,
            b'a'..=b'z' => (c - b'a' + 26) as u32,
            b'0'..=b'9' => (c - b'0' + 52) as u32,
            b'+' => 62,
            b'/' => 63,
            _ => panic!("not base64: {c}"),
        }
    };
    let clean: Vec<u8> = s.bytes().filter(|&c| c != b'=' && c != b'\n').collect();
    let mut out = Vec::with_capacity(clean.len() * 3 / 4);
    for chunk in clean.chunks(4) {
        let mut n = 0u32;
        for (i, &c) in chunk.iter().enumerate() {
            n |= val(c) << (18 - 6 * i);
        }
        out.extend_from_slice(&n.to_be_bytes()[1..chunk.len()]);
    }
    out
}

/// Waits until the page answers on `port`.
fn wait_for_page(port: u16, train: &mut Child, log: &Path) {
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        if let Ok(mut c) = TcpStream::connect(("127.0.0.1", port)) {
            let _ = write!(c, "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
            let mut s = String::new();
            let _ = c.read_to_string(&mut s);
            if s.starts_with("HTTP/1.1 200") {
                return;
            }
        }
        assert!(
            train.try_wait().unwrap().is_none(),
            "fsrl train stopped: {}",
            std::fs::read_to_string(log).unwrap_or_default()
        );
        assert!(Instant::now() < deadline, "no page on port {port}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[derive(Debug)]
struct Seen {
    validation_points: u64,
    actors_alive: u64,
}

/// What the page's DOM shows (nothing while the page is still loading).
fn seen(b: &mut Browser) -> Seen {
    let v = b.eval(
        "(() => { const c = document.getElementById('chart-validation'), a = document.getElementById('actors-alive'); return c && a ? [Number(c.dataset.points), Number(a.textContent)] : [0, 0]; })()",
    );
    Seen {
        validation_points: v[0].as_u64().unwrap_or(0),
        actors_alive: v[1].as_u64().unwrap_or(0),
    }
}

#[test]
fn the_live_page_follows_a_run_in_a_real_browser() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("short.toml");
    let picture = std::env::var("FSRL_DASHBOARD_SCREENSHOT").ok();
    // The picture's run warms up on more demonstrations, so that its curve shows learning.
    let (every, episodes, il, epochs, rl) = match &picture {
        Some(_) => (25, 20, "200", "20", "1000"),
        None => (10, 5, "8", "2", "100000"),
    };
    std::fs::write(
        &cfg,
        format!("[train]\nvalidation_every_episodes = {every}\nvalidation_episodes = {episodes}\n"),
    )
    .unwrap();
    let port = free_port();
    let log = dir.path().join("train.log");
    let mut train = Tree(
        Command::new(env!("CARGO_BIN_EXE_fsrl"))
            .args(["train", "--actors", "2", "--method", "sarl"])
            .args(["--setting", "env2-visible", "--il-episodes", il])
            .args(["--il-epochs", epochs, "--eval-episodes", "4"])
            .args(["--rl-episodes", rl, "--config"])
            .arg(&cfg)
            .arg("--dashboard")
            .arg(port.to_string())
            .arg("--out")
            .arg(dir.path().join("run"))
            .stdout(Stdio::null())
            .stderr(File::create(&log).unwrap())
            .spawn()
            .unwrap(),
    );
    wait_for_page(port, &mut train.0, &log);
    let url = format!("http://127.0.0.1:{port}/");
    let mut b = Browser::launch(&url, &dir.path().join("chromium"));
    b.attach(&url);

    // Both actors alive and a first validation drawn; then more points while the run goes on.
    let warm_up = Duration::from_secs(if picture.is_some() { 1800 } else { 240 });
    let deadline = Instant::now() + warm_up;
    let first = loop {
        let s = seen(&mut b);
        if s.validation_points > 0 && s.actors_alive == 2 {
            break s;
        }
        assert!(Instant::now() < deadline, "the page never showed {s:?}");
        std::thread::sleep(Duration::from_millis(250));
    };
    let mut later = seen(&mut b);
    while later.validation_points <= first.validation_points {
        assert!(
            Instant::now() < deadline,
            "the curve gained no points: {first:?} then {later:?}"
        );
        std::thread::sleep(Duration::from_millis(250));
        later = seen(&mut b);
    }

    // Kill actor 1: the page counts one actor alive.
    let actor = descendants(train.0.id())
        .into_iter()
        .find(|&p| {
            let c = cmdline(p);
            c.get(1).is_some_and(|a| a == "actor")
                && c.windows(2).any(|w| w[0] == "--id" && w[1] == "1")
        })
        .expect("the process of actor 1");
    signal(actor, libc::SIGKILL);
    let killed = Instant::now();
    loop {
        let s = seen(&mut b);
        if s.actors_alive == 1 {
            eprintln!(
                "the page showed 1 actor alive {:.1} s after the kill",
                killed.elapsed().as_secs_f64()
            );
            break;
        }
        assert!(
            killed.elapsed() < Duration::from_secs(60),
            "the page still shows {s:?} a minute after actor 1 was killed"
        );
        std::thread::sleep(Duration::from_millis(250));
    }
    let table = b.eval(
        "[...document.querySelectorAll('#processes tr')].map(r => r.dataset.sender + '=' + r.dataset.alive).join(' ')",
    );
    let table = table.as_str().unwrap();
    assert!(
        table.contains("actor-1=false") && table.contains("actor-0=true"),
        "{table}"
    );
    // The killed actor's state column says what it was, not what it is; the live one's is
    // its state.
    let shown = b.eval(
        "[...document.querySelectorAll('#processes tr')].map(r => r.dataset.sender + '=' + r.querySelector('td.state').textContent).join(' ')",
    );
    let shown = shown.as_str().unwrap();
    assert!(
        shown.contains("actor-1=was ") && !shown.contains("actor-0=was "),
        "{shown}"
    );
    // The processes' states, from their heartbeats; the page shows this run only.
    let states = b.eval(
        "[...document.querySelectorAll('#processes tr')].map(r => r.dataset.run + '/' + r.dataset.sender + '=' + r.dataset.state).join(' ')",
    );
    let states = states.as_str().unwrap();
    for sender in ["learner-0", "actor-0", "evaluator-0"] {
        assert!(
            ["running", "idle"]
                .iter()
                .any(|s| states.contains(&format!("/{sender}={s}"))),
            "{sender} has no state: {states}"
        );
    }
    let run = states.split('/').next().unwrap_or("");
    assert!(
        !run.is_empty() && states.split(' ').all(|r| r.starts_with(&format!("{run}/"))),
        "another run on the page: {states}"
    );

    if let Some(e) = std::env::var("FSRL_DASHBOARD_SCREENSHOT_EPISODES")
        .ok()
        .and_then(|e| e.parse::<u64>().ok())
    {
        let deadline = Instant::now() + Duration::from_secs(3600);
        loop {
            let text = b.eval("document.getElementById('episodes').textContent");
            let done: u64 = text
                .as_str()
                .and_then(|t| t.split(' ').next())
                .and_then(|t| t.parse().ok())
                .unwrap_or(0);
            if done >= e || Instant::now() > deadline {
                break;
            }
            std::thread::sleep(Duration::from_secs(1));
        }
    }
    let png = b.screenshot();
    assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"), "not a PNG");
    let shot = dir.path().join("dashboard.png");
    std::fs::write(&shot, &png).unwrap();
    if let Some(path) = picture {
        std::fs::copy(&shot, PathBuf::from(path)).unwrap();
    }
}

/// What the page on `port` streams in `wait` (a new connection: the history, then live events).
fn stream(port: u16, wait: Duration) -> String {
    let Ok(mut c) = TcpStream::connect(("127.0.0.1", port)) else {
        return String::new();
    };
    c.set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let _ = write!(c, "GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
    let mut out = Vec::new();
    let end = Instant::now() + wait;
    let mut buf = [0u8; 8192];
    while Instant::now() < end {
        match c.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => out.extend_from_slice(&buf[..n]),
            Err(_) => {}
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

#[test]
fn through_a_secured_router_the_page_shows_the_run_to_the_monitor_and_no_one_else() {
    use multihost_support::{self as mh, adapt_actor_config, adapt_deploy_config, table};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let run = format!("db{}", std::process::id());
    let mut router = mh::LoopbackRouter::start(d, &run, Path::new(env!("CARGO_BIN_EXE_fsrl")));
    let learner = adapt_deploy_config("cluster-learner.toml", d, "learner.toml", |t| {
        router.configure(t);
        let l = table(t, &["learner"]);
        l.insert(
            "run_dir".into(),
            d.join("run").to_string_lossy().into_owned().into(),
        );
        l.insert("metrics_interval_ms".into(), 200.into());
        let i = table(t, &["train", "imitation"]);
        i.insert("episodes".into(), 30.into());
        i.insert("epochs".into(), 30.into());
    });
    let monitor = adapt_deploy_config("cluster-monitor.toml", d, "monitor.toml", |t| {
        router.configure(t)
    });
    let actor = adapt_actor_config(0, d, "actor-0.toml", |t| router.configure(t));
    let s = |p: &Path| p.to_string_lossy().into_owned();
    router.spawn(
        "learner",
        &["learner".into(), "--config".into(), s(&learner)],
    );
    let page = |router: &mut mh::LoopbackRouter, name: &str, config: &Path| {
        let port = free_port();
        let args = ["dashboard", "--config", &s(config), "--run", &run, "--port"];
        let mut args: Vec<String> = args.iter().map(|a| a.to_string()).collect();
        args.push(port.to_string());
        router.spawn(name, &args);
        port
    };
    let allowed = page(&mut router, "page-monitor", &monitor);
    let refused = page(&mut router, "page-actor", &actor);
    let logs = || mh::log_tails(d, 20);

    // The monitor's page streams the learner's metrics (its warm start's, at first).
    let deadline = Instant::now() + Duration::from_secs(120);
    let learner_event = "\"s\":\"learner-0\"";
    loop {
        let seen = stream(allowed, Duration::from_millis(500));
        if seen.contains(learner_event) && seen.contains("\"k\":\"m\"") {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the monitor's page showed no learner metrics:\n{seen}\n{}",
            logs()
        );
        std::thread::sleep(Duration::from_millis(250));
    }
    // The actor's page, up as long: the router lets no metrics through to it.
    let seen = stream(refused, Duration::from_secs(3));
    assert!(
        seen.starts_with("HTTP/1.1 200"),
        "the actor's page is not up: {seen:?}\n{}",
        logs()
    );
    assert!(
        !seen.contains("\"k\":\"m\""),
        "metrics reached a page with an actor's credentials:\n{seen}"
    );
}

/// A transport of this test: `sender` of `run`, listening on `port`, connected to `connect`.
fn test_transport(run: &str, sender: SenderId, port: u16, connect: &[String]) -> Transport {
    let mut cfg = TransportConfig::new(RunId::new(run).unwrap(), sender);
    cfg.zenoh = ZenohConfig::peer(vec![format!("tcp/127.0.0.1:{port}")], connect.to_vec());
    Transport::open(cfg).unwrap()
}

/// `fsrl dashboard` without `--run`: every run it sees on one page, each under its id. Run a
/// is a real learner process (a short warm start, then idle: no actor ever joins); run b is
/// this test, publishing a learner's and an evaluator's metrics and heartbeats through zenoh
/// sessions of its own. The page lists both runs with their data and draws run b's validation
/// curve once it is selected; its processes table shows the state of run a's learner from the
/// learner's own heartbeats (`proto::Status`: idle, waiting for actors), and its last error, a
/// message the learner rejected (garbage on its transitions key), as the learner reported it.
#[test]
fn a_page_of_every_run_shows_each_run_and_each_processs_state_and_last_error() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (run_a, run_b) = (
        format!("every-a{}", std::process::id()),
        format!("every-b{}", std::process::id()),
    );
    let (port_a, port_b, port_e) = (free_port(), free_port(), free_port());
    let endpoint = |p: u16| format!("tcp/127.0.0.1:{p}");
    std::fs::write(
        d.join("a.toml"),
        format!(
            "[run]\nid = \"{run_a}\"\nmethod = \"sarl\"\nsetting = \"env2-visible\"\n[train.imitation]\nepisodes = 4\nepochs = 1\n[learner]\nmetrics_interval_ms = 200\n"
        ),
    )
    .unwrap();
    let log = d.join("learner-a.log");
    let _learner = Tree(
        Command::new(env!("CARGO_BIN_EXE_fsrl"))
            .arg("learner")
            .arg("--config")
            .arg(d.join("a.toml"))
            .args(["--data-plane", "zenoh", "--listen", &endpoint(port_a)])
            .arg("--run-dir")
            .arg(d.join("run-a"))
            .stdout(Stdio::null())
            .stderr(File::create(&log).unwrap())
            .spawn()
            .unwrap(),
    );
    // Run b: its learner (connected to run a's learner too, to send it garbage) and evaluator.
    let learner_b = test_transport(
        &run_b,
        SenderId::new(Role::Learner, 0),
        port_b,
        &[endpoint(port_a)],
    );
    let evaluator_b = test_transport(&run_b, SenderId::new(Role::Evaluator, 0), port_e, &[]);
    // Run a's learner is up once its metrics arrive.
    let every = learner_b.subscriber(&keys::every_run_metrics()).unwrap();
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        if let Some(m) = every.recv_timeout(Duration::from_millis(200)).unwrap() {
            if m.header.run.as_str() == run_a {
                break;
            }
        }
        assert!(
            Instant::now() < deadline,
            "run a's learner published nothing: {}",
            std::fs::read_to_string(&log).unwrap_or_default()
        );
    }
    drop(every);

    let port = free_port();
    let page_log = d.join("dashboard.log");
    let mut page = Tree(
        Command::new(env!("CARGO_BIN_EXE_fsrl"))
            .args(["dashboard", "--port", &port.to_string()])
            .args(["--connect", &endpoint(port_a)])
            .args(["--connect", &endpoint(port_b)])
            .args(["--connect", &endpoint(port_e)])
            .stdout(Stdio::null())
            .stderr(File::create(&page_log).unwrap())
            .spawn()
            .unwrap(),
    );
    wait_for_page(port, &mut page.0, &page_log);
    let url = format!("http://127.0.0.1:{port}/");
    let mut b = Browser::launch(&url, &d.join("chromium"));
    b.attach(&url);

    // Run b: a learner in RL and two validations, with heartbeats.
    let lm = learner_b
        .publisher(&keys::metrics(learner_b.run(), learner_b.sender()))
        .unwrap();
    let em = evaluator_b
        .publisher(&keys::metrics(evaluator_b.run(), evaluator_b.sender()))
        .unwrap();
    let heartbeats = [
        transport::Heartbeat::new(&learner_b).unwrap(),
        transport::Heartbeat::new(&evaluator_b).unwrap(),
    ];
    let publish_run_b = |round: u64| {
        let mut m = Metrics {
            episodes: 10 * round,
            wall_time_s: round as f64,
            ..Metrics::default()
        };
        for (k, v) in [
            ("imitation_done", 1.0),
            ("episodes_target", 100.0),
            ("policy_lag_mean", 1.5),
            ("policy_lag_max", 3.0),
            ("updates_per_episode", 20.0),
        ] {
            m.values.insert(k.into(), v);
        }
        let _ = lm.publish(round, &m);
        let mut v = Metrics {
            episodes: 10 * round,
            ..Metrics::default()
        };
        for (k, x) in [
            ("validation_episode", 10.0 * round as f64),
            ("validation_success_rate", 0.5),
            ("validation_collision_rate", 0.25),
            ("validation_timeout_rate", 0.25),
            ("validation_discomfort", 0.1),
            ("validation_nav_time_s", 12.0),
        ] {
            v.values.insert(k.into(), x);
        }
        let _ = em.publish(round, &v);
        for h in &heartbeats {
            h.set_state(proto::ProcessState::Running);
            h.beat();
        }
    };
    // Garbage on run a's transitions key: its learner rejects it, and says so in its status.
    let evil = learner_b
        .publisher(&keys::transitions(&RunId::new(run_a.clone()).unwrap(), 7))
        .unwrap();

    let runs_js = "[...document.querySelectorAll('#runs tr')].map(r => r.dataset.run + ':' + r.dataset.episodes + ':' + r.dataset.validations).join(' ')";
    let row_js = |run: &str, sender: &str| {
        format!(
            "(() => {{ const r = document.querySelector('#processes tr[data-run=\"{run}\"][data-sender=\"{sender}\"]'); return r ? r.dataset.state + '|' + r.querySelector('td.err').textContent : ''; }})()"
        )
    };
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut round = 1;
    let (runs, learner_a) = loop {
        publish_run_b(round.min(2));
        round += 1;
        let _ = evil.publish_raw(b"not an episode".to_vec());
        std::thread::sleep(Duration::from_millis(250));
        let runs = b.eval(runs_js).as_str().unwrap_or("").to_string();
        let learner_a = b
            .eval(&row_js(&run_a, "learner-0"))
            .as_str()
            .unwrap_or("")
            .to_string();
        let both = runs.contains(&format!("{run_b}:20:2")) && runs.contains(&format!("{run_a}:"));
        if both && learner_a.starts_with("idle|") && learner_a.contains("rejected a message") {
            break (runs, learner_a);
        }
        assert!(
            Instant::now() < deadline,
            "the page shows runs {runs:?}, run a's learner {learner_a:?}\n{}",
            std::fs::read_to_string(&log).unwrap_or_default()
        );
    };
    eprintln!("runs: {runs}; run a's learner: {learner_a}");
    assert!(
        learner_a.contains(&format!("fsrl/{run_a}/transitions")),
        "{learner_a}"
    );
    // Run b's processes, by their heartbeats; its curve once it is selected.
    let learner_b_row = b.eval(&row_js(&run_b, "learner-0"));
    assert!(
        learner_b_row.as_str().unwrap_or("").starts_with("running|"),
        "{learner_b_row}"
    );
    b.eval(&format!(
        "document.querySelector('#runs tr[data-run=\"{run_b}\"] button').click()"
    ));
    let shown = b.eval(
        "[document.getElementById('run').textContent, Number(document.getElementById('chart-validation').dataset.points)]",
    );
    assert_eq!(shown[0].as_str(), Some(run_b.as_str()), "{shown}");
    assert_eq!(
        shown[1].as_u64(),
        Some(6),
        "two points of three series: {shown}"
    );
}
