//! Actor scaling: 1, 2 and 4 actor processes against one learner with updates off
//! (`train.rl.batches_per_episode = 0`), iceoryx2 data plane. Prints episodes/s per
//! configuration and the ratios to one actor, all measured in this one run.
//!
//! `cargo bench -p fsrl --bench scaling`
//!
//! With `FSRL_BASELINE_BIN=/path/to/an/older/fsrl` each configuration is measured with that
//! binary and with this build, alternately in the same run, and the table gains the ratio
//! (how a change affects throughput, free of the machine's drift between runs).

#[path = "../tests/shm_support/mod.rs"]
mod shm_support;

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use proto::{keys, Role, RunId, SenderId};
use shm_support::ShmSnapshot;
use transport::{Transport, TransportConfig, ZenohConfig};

const MEASURE: Duration = Duration::from_secs(20);

struct Procs(Vec<Child>);
impl Drop for Procs {
    /// SIGTERM first, so that every process stops cleanly and removes its iceoryx2 shared
    /// memory (SIGKILL would leave it in /dev/shm); SIGKILL whatever is still running after 10 s.
    fn drop(&mut self) {
        for c in &self.0 {
            // SAFETY: kill(2) on the pid of a child we have not yet waited for.
            unsafe {
                libc::kill(c.id() as libc::pid_t, libc::SIGTERM);
            }
        }
        let deadline = Instant::now() + Duration::from_secs(10);
        for c in &mut self.0 {
            while matches!(c.try_wait(), Ok(None)) && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(50));
            }
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn episodes_per_s(bin: &str, actors: u32) -> f64 {
    let port = testkit::free_port();
    let ep = format!("tcp/127.0.0.1:{port}");
    let dir = tempfile::tempdir().unwrap();
    let id = format!("scale{actors}-{}", std::process::id());
    let cfg = dir.path().join("run.toml");
    std::fs::write(
        &cfg,
        format!(
            "[run]\nid = \"{id}\"\nmethod = \"sarl\"\nsetting = \"env1-invisible\"\n[transport]\ndata_plane = \"iceoryx2\"\n\
             [train.imitation]\nepisodes = 5\nepochs = 1\n[train.rl]\nepisodes = 1000000\nbatches_per_episode = 0\n\
             [learner]\nin_flight_per_actor = 8\nmetrics_interval_ms = 250\n"
        ),
    )
    .unwrap();
    let spawn = |args: &[&str]| {
        Command::new(bin)
            .args(args)
            .arg("--config")
            .arg(&cfg)
            .arg("--run-dir")
            .arg(dir.path().join("run"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap()
    };
    let mut procs = Procs(vec![spawn(&["learner", "--listen", &ep])]);
    for k in 0..actors {
        procs.0.push(spawn(&[
            "actor",
            "--id",
            &k.to_string(),
            "--listen",
            "tcp/127.0.0.1:0",
            "--connect",
            &ep,
        ]));
    }
    let mut tc = TransportConfig::new(RunId::new(id).unwrap(), SenderId::new(Role::Monitor, 0));
    tc.zenoh = ZenohConfig::peer(vec!["tcp/127.0.0.1:0".into()], vec![ep]);
    let t = Transport::open(tc).unwrap();
    let sub = t.subscriber(&keys::all_metrics(t.run())).unwrap();
    let read = || -> Option<(Instant, f64, f64)> {
        let m = sub.recv_timeout(Duration::from_secs(1)).unwrap()?;
        if m.header.sender.role != Role::Learner {
            return None;
        }
        let v = &m.body.values;
        Some((
            Instant::now(),
            *v.get("episodes")?,
            *v.get("actors_alive").unwrap_or(&0.0),
        ))
    };
    // Warm up: every actor connected and a few episodes done.
    let deadline = Instant::now() + Duration::from_secs(120);
    let (t0, e0) = loop {
        assert!(Instant::now() < deadline, "the run did not start");
        if let Some((t, e, alive)) = read() {
            if alive as u32 == actors && e >= 4.0 * actors as f64 {
                break (t, e);
            }
        }
    };
    let mut last = (t0, e0);
    while last.0.duration_since(t0) < MEASURE {
        if let Some((t, e, _)) = read() {
            last = (t, e);
        }
    }
    (last.1 - e0) / last.0.duration_since(t0).as_secs_f64()
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let shm_before = ShmSnapshot::take();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let current = env!("CARGO_BIN_EXE_fsrl");
    let baseline = std::env::var("FSRL_BASELINE_BIN").ok();
    let mut rows = Vec::new();
    for actors in [1, 2, 4] {
        let before = baseline.as_deref().map(|b| episodes_per_s(b, actors));
        let r = episodes_per_s(current, actors);
        match before {
            Some(b) => println!("{actors} actor(s): {r:.2} episodes/s (baseline {b:.2})"),
            None => println!("{actors} actor(s): {r:.2} episodes/s"),
        }
        rows.push((actors, r, before));
    }
    let base = rows[0].1;
    println!("\n== actor scaling, learner updates off, iceoryx2, {cores} cores ==");
    if let Some(b) = &baseline {
        println!("baseline: {b}");
        println!("| actors | episodes/s | vs 1 actor | baseline episodes/s | this / baseline |\n|---|---|---|---|---|");
        for (a, r, before) in &rows {
            let before = before.unwrap_or(f64::NAN);
            println!(
                "| {a} | {r:.2} | {:.2}x | {before:.2} | {:.2}x |",
                r / base,
                r / before
            );
        }
    } else {
        println!("| actors | episodes/s | vs 1 actor |\n|---|---|---|");
        for (a, r, _) in &rows {
            println!("| {a} | {r:.2} | {:.2}x |", r / base);
        }
    }
    let leaked = shm_before.new_since(|e| e.starts_with("fsrl_scale")).len();
    if leaked > 0 {
        eprintln!("warning: {leaked} shared-memory files left in /dev/shm by the processes");
        std::process::exit(1);
    }
}
