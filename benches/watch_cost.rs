//! What watching a run costs it, in one run of this benchmark: short identical trainings with
//! and without the TensorBoard files (`fsrl train --no-tensorboard`) and with a live page
//! attached (`fsrl train --dashboard PORT`, its event stream read as a browser would), the arms
//! interleaved (each repetition runs every arm once, starting one arm later than the last, so a
//! drift of the machine's speed spreads over all of them). Prints each run's wall-clock time,
//! then per arm the median and its ratio to the arm without files of the same mode, with a 95 %
//! bootstrap interval (each arm's runs resampled, 4000 times): a ratio whose interval holds 1
//! is no measurable cost.
//!
//! Arms: single-process without and with TensorBoard files (the mode is deterministic: the
//! same work every time); distributed (`--replay-ratio fixed`: the same updates per episode
//! every time; `FSRL_WATCH_COST_ACTORS` actors, default 2) without files, with files, and with
//! files and the page.
//!
//! `cargo bench -p fsrl --bench watch_cost` (the full measurement: 6 repetitions of 5 arms of
//! FSRL on env1-invisible with 100 demonstrations × 10 epochs and 300 RL episodes, validating
//! 50 episodes every 100, 100 final test episodes; 30 trainings of 35–55 s each on 2 cores,
//! about 22 minutes; 4 repetitions took 14.5 minutes on 2026-12-06). Shorter:
//! `FSRL_WATCH_COST_REPS` (repetitions), `FSRL_WATCH_COST_RL_EPISODES`,
//! `FSRL_WATCH_COST_IL_EPISODES`, `FSRL_WATCH_COST_IL_EPOCHS`, `FSRL_WATCH_COST_MODES`
//! (`single`, `distributed` or `single,distributed`).

use std::io::Write;
use std::net::TcpStream;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn env_u64(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

#[derive(Clone, Copy, PartialEq)]
enum Mode {
    Single,
    Distributed,
}

struct Arm {
    name: &'static str,
    mode: Mode,
    tensorboard: bool,
    page: bool,
    times_s: Vec<f64>,
}

use testkit::free_port;

/// Reads the page's event stream as a browser would, reconnecting until `done`.
fn read_page(port: u16, done: Arc<AtomicBool>) -> std::thread::JoinHandle<u64> {
    std::thread::spawn(move || {
        let mut bytes = 0u64;
        while !done.load(Ordering::Relaxed) {
            let Ok(mut c) = TcpStream::connect(("127.0.0.1", port)) else {
                std::thread::sleep(Duration::from_millis(100));
                continue;
            };
            let _ = c.set_read_timeout(Some(Duration::from_millis(500)));
            if write!(c, "GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n").is_err() {
                continue;
            }
            let mut buf = [0u8; 16384];
            while !done.load(Ordering::Relaxed) {
                let Some(n) = testkit::read_timed(&mut c, &mut buf) else {
                    break;
                };
                bytes += n as u64;
            }
        }
        bytes
    })
}

/// One training of `arm`; its wall-clock time in seconds.
fn train(arm: &Arm, config: &Path, out: &Path, actors: &str) -> f64 {
    let mut c = Command::new(env!("CARGO_BIN_EXE_fsrl"));
    c.args(["train", "--method", "fsrl", "--setting", "env1-invisible"])
        .args(["--seed", "0", "--config"])
        .arg(config)
        .arg("--out")
        .arg(out)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    match arm.mode {
        Mode::Single => {
            c.arg("--single-process");
        }
        Mode::Distributed => {
            c.args(["--actors", actors, "--replay-ratio", "fixed"]);
        }
    }
    if !arm.tensorboard {
        c.arg("--no-tensorboard");
    }
    let page = arm.page.then(|| {
        let port = free_port();
        c.arg("--dashboard").arg(port.to_string());
        port
    });
    let done = Arc::new(AtomicBool::new(false));
    let t = Instant::now();
    let child = c.spawn().expect("fsrl runs");
    let reader = page.map(|port| read_page(port, done.clone()));
    let o = child.wait_with_output().expect("fsrl runs");
    let wall = t.elapsed().as_secs_f64();
    done.store(true, Ordering::Relaxed);
    let read = reader.map(|r| r.join().unwrap_or(0));
    assert!(
        o.status.success(),
        "{}: {}",
        arm.name,
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(
        out.join("tb").exists(),
        arm.tensorboard,
        "{}: tb/ written or not as asked",
        arm.name
    );
    if let Some(bytes) = read {
        assert!(bytes > 0, "{}: the page streamed nothing", arm.name);
    }
    wall
}

fn median(xs: &[f64]) -> f64 {
    let mut v = xs.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// The ratio of medians `arm / base` and its 95 % percentile bootstrap interval.
fn ratio(arm: &[f64], base: &[f64]) -> (f64, f64, f64) {
    // xorshift64*: a fixed seed, so the same times give the same interval.
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move |n: usize| {
        state ^= state >> 12;
        state ^= state << 25;
        state ^= state >> 27;
        (state.wrapping_mul(0x2545_f491_4f6c_dd1d) % n as u64) as usize
    };
    let mut ratios: Vec<f64> = (0..4000)
        .map(|_| {
            let a: Vec<f64> = (0..arm.len()).map(|_| arm[next(arm.len())]).collect();
            let b: Vec<f64> = (0..base.len()).map(|_| base[next(base.len())]).collect();
            median(&a) / median(&b)
        })
        .collect();
    ratios.sort_by(f64::total_cmp);
    let at = |q: f64| ratios[((q * (ratios.len() - 1) as f64).round()) as usize];
    (median(arm) / median(base), at(0.025), at(0.975))
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let reps = env_u64("FSRL_WATCH_COST_REPS", 6).max(1);
    let rl = env_u64("FSRL_WATCH_COST_RL_EPISODES", 300).max(1);
    let il = env_u64("FSRL_WATCH_COST_IL_EPISODES", 100).max(1);
    let epochs = env_u64("FSRL_WATCH_COST_IL_EPOCHS", 10).max(1);
    let actors = std::env::var("FSRL_WATCH_COST_ACTORS").unwrap_or_else(|_| "2".into());
    let modes =
        std::env::var("FSRL_WATCH_COST_MODES").unwrap_or_else(|_| "single,distributed".into());
    let tmp = tempfile::tempdir().expect("a temporary directory");
    let config = tmp.path().join("short.toml");
    let every = (rl / 3).max(1);
    std::fs::write(
        &config,
        format!(
            "[train]\nvalidation_every_episodes = {every}\nvalidation_episodes = {}\neval_episodes = {}\n\n[train.imitation]\nepisodes = {il}\nepochs = {epochs}\n\n[train.rl]\nepisodes = {rl}\nepsilon_decay_episodes = {}\n",
            (rl / 6).clamp(4, 50),
            (rl / 3).clamp(4, 100),
            (rl * 2 / 5).max(1)
        ),
    )
    .expect("the config");
    let mut arms = Vec::new();
    for mode in modes.split(',') {
        match mode.trim() {
            "single" => {
                for (name, tensorboard) in [
                    ("single-process, no files", false),
                    ("single-process, TensorBoard files", true),
                ] {
                    arms.push(Arm {
                        name,
                        mode: Mode::Single,
                        tensorboard,
                        page: false,
                        times_s: Vec::new(),
                    });
                }
            }
            "distributed" => {
                for (name, tensorboard, page) in [
                    ("distributed, no files", false, false),
                    ("distributed, TensorBoard files", true, false),
                    ("distributed, files + live page", true, true),
                ] {
                    arms.push(Arm {
                        name,
                        mode: Mode::Distributed,
                        tensorboard,
                        page,
                        times_s: Vec::new(),
                    });
                }
            }
            other => panic!("FSRL_WATCH_COST_MODES: `{other}` is neither single nor distributed"),
        }
    }
    let load = || {
        std::fs::read_to_string("/proc/loadavg")
            .unwrap_or_default()
            .split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    };
    println!(
        "watch_cost: FSRL env1-invisible seed 0, {il} demonstrations x {epochs} epochs, {rl} RL episodes (validating every {every}), {reps} repetitions of {} arms interleaved; load average before {}",
        arms.len(),
        load()
    );
    for rep in 0..reps as usize {
        for k in 0..arms.len() {
            let i = (rep + k) % arms.len();
            let out = tmp.path().join(format!("run-{rep}-{i}"));
            let wall = train(&arms[i], &config, &out, &actors);
            let _ = std::fs::remove_dir_all(&out);
            println!("  repetition {rep}: {:<34} {wall:8.2} s", arms[i].name);
            arms[i].times_s.push(wall);
        }
    }
    println!("load average after: {}", load());
    println!(
        "\n{:<34} {:>4} {:>10}  {:>24}",
        "arm", "runs", "median s", "ratio to no files [95 %]"
    );
    for arm in &arms {
        let base = arms
            .iter()
            .find(|b| b.mode == arm.mode && !b.tensorboard)
            .expect("a base arm per mode");
        let cell = if std::ptr::eq(arm, base) {
            "1 (base)".to_string()
        } else {
            let (r, lo, hi) = ratio(&arm.times_s, &base.times_s);
            format!("{r:.3} [{lo:.3}, {hi:.3}]")
        };
        println!(
            "{:<34} {:>4} {:>10.2}  {:>24}",
            arm.name,
            arm.times_s.len(),
            median(&arm.times_s),
            cell
        );
    }
}
