//! Partitions with exact accounting (issue 16): the multi-host harness of `tests/multihost.rs`
//! (network namespaces joined by veth pairs, the real `fsrl` binary, the `deploy/` configs with
//! TLS, per-actor users and access control) with the learner on a host of its own, so that its
//! link can fail. While two actors train, the test
//!
//! 1. takes the learner's link down for less than the link lease (nobody should notice), then
//!    for longer (the actors must see the learner leave), and up again;
//! 2. kills the router and starts it again on the same port;
//! 3. puts loss and delay on actor 0's link (`tc netem loss 10% delay 50ms`; where the kernel
//!    has no netem, a token bucket `tbf` whose queue delays and whose full queue drops packets;
//!    the dropped packets are counted from the qdisc's statistics);
//! 4. slows actor 1 down (SIGSTOP/SIGCONT duty cycle), then freezes it for longer than the lease;
//!
//! and after each disruption waits until both actors have episodes acknowledged again (the
//! recovery time is printed). Then it kills the learner (SIGKILL: no final checkpoint) and the
//! actors and does the accounting, per episode index:
//!
//! - the learner's **accepted set** is what is durable in its run directory, read with the
//!   `learner` crate's own recovery code (`store::Store::open`, the checkpoint's `accepted_below`
//!   per actor, the write-ahead log's records through `store::replay_plan`): per actor exactly
//!   `0..n`, no gap, no episode twice (log records the checkpoint already holds are dropped by
//!   `replay_plan`, none is replayed twice);
//! - the episodes each actor **dropped from its outbox because of an acknowledgement** are read
//!   from its log (`actor=debug`: "acknowledged; dropped from the outbox", one line per episode);
//!   each was dropped once, they are `0..d` for some d, and **every one is in the accepted set**.
//!
//! A recovery that never comes (an actor waiting for an episode nobody will re-send) fails the
//! test too, with the accounting of what is durable at that moment.
//!
//! Needs root, `ip netns` and `tc` (CI runs as root); elsewhere it prints why it skips.
//! Everything it makes — namespaces, veths (and the qdiscs on them), processes, temporary files,
//! shared memory — is removed at the end, also on failure. `cargo test --release --test
//! partitions -- --nocapture` shows the timeline and the numbers; `FSRL_MULTIHOST_KEEP=1` keeps
//! the logs and the run directory after a passing run.

mod multihost_support;
mod shm_support;

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use learner::checkpoint::RunIdentity;
use learner::store::{replay_plan, Probe, Store};
use mh::{adapt_actor_config, adapt_deploy_config, table, Hosts, Observer, Procs};
use multihost_support as mh;
use shm_support::ShmSnapshot;

/// Longest wait for the actors to make progress after a disruption.
const RECOVERY: Duration = Duration::from_secs(90);
/// The clients' link lease (the test's zenoh override; deploy/router.json5 has 10 s).
const LEASE: Duration = Duration::from_secs(2);
/// Newly acknowledged episodes per actor that count as progress: more than an actor may have
/// in flight (`learner.in_flight_per_actor` = 2 in deploy/cluster-learner.toml), so at least one
/// of them was simulated after the disruption.
const PROGRESS: u64 = 3;
/// The learner checkpoints every this many RL episodes, so the run directory ends with a
/// checkpoint *and* a write-ahead log.
const CHECKPOINT_EVERY: u64 = 20;
const METHOD: &str = "sarl";
const SETTING: &str = "env2-visible";
const SEED: u64 = 0;
/// What an actor logs (debug) for each episode an acknowledgement drops from its outbox.
const DROPPED: &str = "acknowledged; dropped from the outbox";

/// Not a test: the entry point of the observer helper that the partition test starts inside
/// the hub's namespace. Does nothing when run as a test.
#[test]
fn helper_process_entry_point() {
    mh::helper_main();
}

struct Cluster {
    // Drop order: processes first, then the namespaces, then the files.
    procs: Procs,
    hosts: Hosts,
    dir: tempfile::TempDir,
    run_id: String,
    learner: PathBuf,
    actors: [PathBuf; 2],
    monitor: PathBuf,
    run_dir: PathBuf,
    /// The name (and log) of the router process now running.
    router: String,
    t0: Instant,
}

/// zenoh settings of the test (as tests/multihost.rs): a 2 s lease and quick reconnection.
fn test_overrides() -> toml::Value {
    let pairs = [
        ("transport/link/tx/lease", "2000"),
        ("transport/link/tx/keep_alive", "4"),
        (
            "connect/retry",
            "{period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2}",
        ),
    ];
    toml::Value::Array(
        pairs
            .iter()
            .map(|(k, v)| toml::Value::Array(vec![(*k).into(), (*v).into()]))
            .collect(),
    )
}

impl Cluster {
    fn new(hosts: Hosts) -> Self {
        let dir = tempfile::tempdir().unwrap();
        let mut ips: Vec<String> = (0..2).map(Hosts::hub_addr).collect();
        ips.push(Hosts::learner_hub_addr());
        mh::make_secrets(dir.path(), &ips).unwrap();
        let run_id = format!("part{}", std::process::id());
        let d = dir.path();
        let run = |t: &mut toml::Table, endpoint: String| {
            let r = table(t, &["run"]);
            r.insert("id".into(), run_id.clone().into());
            r.insert("method".into(), METHOD.into());
            r.insert("setting".into(), SETTING.into());
            r.insert("seed".into(), (SEED as i64).into());
            let z = table(t, &["transport", "zenoh"]);
            z.insert("connect".into(), toml::Value::Array(vec![endpoint.into()]));
            z.insert("overrides".into(), test_overrides());
            let i = table(t, &["train", "imitation"]);
            i.insert("episodes".into(), 6.into());
            i.insert("epochs".into(), 1.into());
            let tr = table(t, &["train"]);
            tr.insert(
                "checkpoint_every_episodes".into(),
                (CHECKPOINT_EVERY as i64).into(),
            );
            let rl = table(t, &["train", "rl"]);
            rl.insert("episodes".into(), 1_000_000.into());
            rl.insert("batches_per_episode".into(), 10.into());
        };
        let run_dir = d.join("run");
        let learner = adapt_deploy_config("cluster-learner.toml", d, "learner.toml", |t| {
            run(t, format!("tls/{}:7447", Hosts::learner_hub_addr()));
            let l = table(t, &["learner"]);
            l.insert("run_dir".into(), run_dir.to_string_lossy().as_ref().into());
            l.insert("metrics_interval_ms".into(), 200.into());
            l.insert("linger_ms".into(), 1000.into());
        });
        let actor = |k: usize| {
            adapt_actor_config(k as u32, d, &format!("actor-{k}.toml"), |t| {
                run(t, format!("tls/{}:7447", Hosts::hub_addr(k)))
            })
        };
        let actors = [actor(0), actor(1)];
        let monitor = adapt_deploy_config("cluster-monitor.toml", d, "monitor.toml", |t| {
            run(t, "tls/127.0.0.1:7447".into())
        });
        Self {
            procs: Procs::default(),
            hosts,
            run_id,
            learner,
            actors,
            monitor,
            run_dir,
            dir,
            router: String::new(),
            t0: Instant::now(),
        }
    }

    fn log(&self, name: &str) -> PathBuf {
        self.dir.path().join(format!("{name}.log"))
    }

    fn fsrl(&mut self, name: &str, ns: &str, args: &[String]) {
        let log = self.log(name);
        // The actors' debug events are the per-episode evidence (DROPPED), the learner's show
        // what it accepted (for a failure's logs); the router's transport events show when it
        // saw a link expire and when it closed the session (a failure to notice the learner
        // leaving is then visible in its log).
        let filter = if name.starts_with("router") {
            "info,zenoh=warn,zenoh_transport=debug"
        } else {
            "info,zenoh=warn,actor=debug,learner=debug"
        };
        self.procs.spawn(
            name,
            ns,
            Path::new(env!("CARGO_BIN_EXE_fsrl")),
            args,
            &[("RUST_LOG", filter.to_string())],
            &log,
        );
    }

    /// Starts the router (in the hub) as process `name`.
    fn start_router(&mut self, name: &str) {
        let args = mh::router_args_for_run(self.dir.path(), &self.run_id, &[]);
        let hub = self.hosts.hub.clone();
        self.fsrl(name, &hub, &args);
        self.router = name.to_string();
    }

    fn start_learner(&mut self) {
        let ns = self.hosts.learner.clone().expect("a learner host");
        let args = ["learner", "--config"].map(String::from);
        let mut args = args.to_vec();
        args.push(self.learner.to_string_lossy().into_owned());
        self.fsrl("learner", &ns, &args);
    }

    fn start_actor(&mut self, k: usize) {
        let ns = self.hosts.actors[k].clone();
        let args = vec![
            "actor".to_string(),
            "--config".into(),
            self.actors[k].to_string_lossy().into_owned(),
            "--id".into(),
            k.to_string(),
        ];
        self.fsrl(&format!("actor-{k}"), &ns, &args);
    }

    /// What actor `k` has logged so far.
    fn actor_log(&self, k: u32) -> ActorLog {
        let text = std::fs::read_to_string(self.log(&format!("actor-{k}"))).unwrap_or_default();
        ActorLog::parse(&text, k)
    }

    fn actor_logs(&self) -> [ActorLog; 2] {
        [self.actor_log(0), self.actor_log(1)]
    }

    fn say(&self, what: &str) {
        println!("[{:6.1} s] {what}", self.t0.elapsed().as_secs_f64());
    }

    /// Processes that should run and do not.
    fn dead(&mut self) -> Vec<String> {
        let mut names = vec![
            "learner".to_string(),
            "actor-0".into(),
            "actor-1".into(),
            self.router.clone(),
        ];
        names.retain(|n| self.procs.running(n) != Some(true));
        names
    }

    /// Polls the actors' logs until `pred` holds (or `timeout`), failing early when a process
    /// died. Returns how long it took.
    fn wait_logs(
        &mut self,
        what: &str,
        timeout: Duration,
        mut pred: impl FnMut(&[ActorLog; 2]) -> bool,
    ) -> Result<Duration, String> {
        let start = Instant::now();
        loop {
            if pred(&self.actor_logs()) {
                let d = start.elapsed();
                self.say(&format!("{what} ({:.1} s)", d.as_secs_f64()));
                return Ok(d);
            }
            let dead = self.dead();
            if !dead.is_empty() {
                return Err(format!("waiting for {what}: {dead:?} not running"));
            }
            if start.elapsed() >= timeout {
                let logs = self.actor_logs();
                return Err(format!(
                    "timed out after {:.0} s waiting for {what} (acknowledged so far: actor 0 {}, actor 1 {})",
                    timeout.as_secs_f64(),
                    logs[0].dropped.len(),
                    logs[1].dropped.len()
                ));
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Waits until each actor has [`PROGRESS`] more episodes acknowledged than in `before`.
    fn wait_progress(&mut self, what: &str, before: &[ActorLog; 2]) -> Result<Duration, String> {
        let base = [before[0].dropped.len(), before[1].dropped.len()];
        self.wait_logs(what, RECOVERY, |l| {
            (0..2).all(|k| l[k].dropped.len() as u64 >= base[k] as u64 + PROGRESS)
        })
    }

    /// Every log, for a failure message.
    fn logs(&self) -> String {
        mh::log_tails(self.dir.path(), 30)
    }
}

/// What an actor's log says, in order.
#[derive(Debug, Default, Clone)]
struct ActorLog {
    /// Episodes dropped from the outbox because an acknowledgement covered them (DROPPED).
    dropped: Vec<u64>,
    /// "learner left; holding off" lines.
    learner_left: usize,
    /// "learner joined" lines (each one re-sends the outbox).
    learner_joined: usize,
    /// Re-sends after [`actor`]'s 5 s without acknowledgement progress.
    resends: usize,
}

impl ActorLog {
    fn parse(text: &str, id: u32) -> Self {
        let mut l = Self::default();
        let field = |line: &str, name: &str| -> Option<u64> {
            line.split_whitespace()
                .find_map(|w| w.strip_prefix(name)?.strip_prefix('='))
                .and_then(|v| v.parse().ok())
        };
        for line in text.lines() {
            if line.contains(DROPPED) {
                assert_eq!(field(line, "actor"), Some(id as u64), "{line}");
                let e = field(line, "episode").unwrap_or_else(|| panic!("no episode: {line}"));
                l.dropped.push(e);
            } else if line.contains("learner left; holding off") {
                l.learner_left += 1;
            } else if line.contains("learner joined") {
                l.learner_joined += 1;
            } else if line.contains("re-sending the outbox") {
                l.resends += 1;
            }
        }
        l
    }
}

/// The learner's durable state, read back as a restarted learner would.
#[derive(Debug)]
struct Durable {
    /// The checkpoint's `accepted_below` per actor (absent: nothing below).
    checkpoint: BTreeMap<u32, u64>,
    /// Every record of the write-ahead log: (actor, episode), in order.
    wal: Vec<(u32, u64)>,
    /// What `replay_plan` replays: (actor, episode), in order.
    replayed: Vec<(u32, u64)>,
    /// Records `replay_plan` drops as already held.
    duplicates: u64,
    unreadable: u64,
}

impl Durable {
    fn read(run_dir: &Path, run_id: &str) -> Result<Self, String> {
        let store = Store::open(run_dir, Probe::none()).map_err(|e| e.to_string())?;
        let expected = RunIdentity {
            run_id: run_id.to_string(),
            method: METHOD.parse().map_err(|e| format!("{e}"))?,
            setting: SETTING.into(),
            run_seed: SEED,
        };
        let checkpoint = store
            .load_checkpoint(&expected)
            .map_err(|e| e.to_string())?
            .map(|l| l.run.accepted_below)
            .ok_or("the learner left no checkpoint")?;
        let mut wal = Vec::new();
        for rec in store.wal_records() {
            let msg = proto::decode::<proto::TransitionBatch>(rec)
                .map_err(|e| format!("a write-ahead log record does not decode: {e}"))?;
            wal.push((msg.header.sender.index, msg.body.episode));
        }
        let plan = replay_plan(store.wal_records(), &checkpoint);
        Ok(Self {
            checkpoint,
            wal,
            replayed: plan
                .episodes
                .iter()
                .map(|m| (m.header.sender.index, m.body.episode))
                .collect(),
            duplicates: plan.duplicates,
            unreadable: plan.unreadable,
        })
    }

    /// The accepted set of `actor`: below the checkpoint's mark, and what the log replays.
    fn accepted(&self, actor: u32) -> Vec<u64> {
        let below = self.checkpoint.get(&actor).copied().unwrap_or(0);
        let mut a: Vec<u64> = (0..below).collect();
        a.extend(
            self.replayed
                .iter()
                .filter(|(k, _)| *k == actor)
                .map(|(_, e)| *e),
        );
        a
    }

    /// Problems with the store itself: per actor the accepted set must be `0..n` (no gap, no
    /// episode twice), and `replay_plan` must drop exactly the log records the checkpoint (or an
    /// earlier record) holds.
    fn problems(&self) -> Vec<String> {
        let mut p = Vec::new();
        if self.unreadable > 0 {
            p.push(format!(
                "{} write-ahead log records are not an actor's episode",
                self.unreadable
            ));
        }
        let mut held: BTreeMap<u32, u64> = self.checkpoint.clone();
        let mut dups = 0;
        for &(k, e) in &self.wal {
            let next = held.entry(k).or_insert(0);
            if e < *next {
                dups += 1;
            } else if e > *next {
                p.push(format!(
                    "the write-ahead log holds episode {e} of actor {k} while {next} is missing (a gap)"
                ));
                *next = e + 1;
            } else {
                *next = e + 1;
            }
        }
        if dups != self.duplicates {
            p.push(format!(
                "{dups} log records are already held, replay_plan drops {}",
                self.duplicates
            ));
        }
        for k in self.actors() {
            let a = self.accepted(k);
            let exact: Vec<u64> = (0..a.len() as u64).collect();
            if a != exact {
                p.push(format!(
                    "actor {k}'s accepted set is not 0..{}: {a:?}",
                    a.len()
                ));
            }
        }
        p
    }

    fn actors(&self) -> BTreeSet<u32> {
        self.checkpoint
            .keys()
            .chain(self.wal.iter().map(|(k, _)| k))
            .copied()
            .collect()
    }
}

/// The accounting: every episode an actor dropped because of an acknowledgement is in the
/// learner's accepted set. Returns the problems (empty: all is well) and a summary.
fn account(logs: &[ActorLog; 2], durable: &Durable) -> (Vec<String>, String) {
    let mut p = durable.problems();
    let mut summary = String::new();
    for k in 0..2u32 {
        let dropped = &logs[k as usize].dropped;
        let accepted: BTreeSet<u64> = durable.accepted(k).into_iter().collect();
        let mut seen = BTreeSet::new();
        let twice: Vec<u64> = dropped
            .iter()
            .filter(|e| !seen.insert(**e))
            .copied()
            .collect();
        if !twice.is_empty() {
            p.push(format!("actor {k} dropped episodes twice: {twice:?}"));
        }
        let exact: BTreeSet<u64> = (0..seen.len() as u64).collect();
        if seen != exact {
            p.push(format!(
                "actor {k} dropped {} episodes, not 0..{}: {:?}",
                seen.len(),
                seen.len(),
                seen.difference(&exact).collect::<Vec<_>>()
            ));
        }
        let lost: Vec<u64> = seen.difference(&accepted).copied().collect();
        if !lost.is_empty() {
            p.push(format!(
                "actor {k} dropped episodes because of an acknowledgement that the learner never stored: {lost:?}"
            ));
        }
        summary += &format!(
            "actor {k}: {} episodes dropped because acknowledged (max {:?}), {} accepted (checkpoint below {}, {} more in the log)\n",
            seen.len(),
            seen.last(),
            accepted.len(),
            durable.checkpoint.get(&k).copied().unwrap_or(0),
            durable.replayed.iter().filter(|(a, _)| *a == k).count(),
        );
    }
    summary += &format!(
        "write-ahead log: {} records, {} already in the checkpoint (dropped by replay_plan)",
        durable.wal.len(),
        durable.duplicates
    );
    (p, summary)
}

/// Loss and delay on actor 0's link: netem where the kernel has it, else a token bucket whose
/// queue delays (up to 50 ms) and whose full queue drops packets (TCP sees loss).
fn impairment(c: &Cluster) -> (Vec<&'static str>, &'static str) {
    let netem = ["netem", "loss", "10%", "delay", "50ms"];
    match c.hosts.set_link_qdisc(&c.hosts.actors[0], Some(&netem)) {
        Ok(()) => (netem.to_vec(), "netem"),
        Err(e) => {
            println!("no netem here ({e}); using tbf (queueing delay, tail drops)");
            let _ = c.hosts.set_link_qdisc(&c.hosts.actors[0], None);
            let tbf = ["tbf", "rate", "8mbit", "burst", "32kb", "latency", "50ms"];
            c.hosts
                .set_link_qdisc(&c.hosts.actors[0], Some(&tbf))
                .expect("tbf on actor 0's link");
            (tbf.to_vec(), "tbf")
        }
    }
}

/// Packets dropped by the root qdisc of `dev` in `ns` (`tc -s` statistics).
fn qdisc_drops(ns: &str, dev: &str) -> u64 {
    let o = std::process::Command::new("tc")
        .args(["-n", ns, "-s", "qdisc", "show", "dev", dev])
        .output();
    let Ok(o) = o else { return 0 };
    let text = String::from_utf8_lossy(&o.stdout);
    text.split([',', '(', ')'])
        .find_map(|w| w.trim().strip_prefix("dropped ")?.trim().parse().ok())
        .unwrap_or(0)
}

/// Recovery times and other numbers of the scenario, printed at the end.
#[derive(Default)]
struct Timeline {
    recoveries: Vec<(String, f64)>,
    notes: Vec<String>,
}

/// The disruptions, in order; an error ends the scenario (the accounting still runs).
fn scenario(c: &mut Cluster, tl: &mut Timeline) -> Result<(), String> {
    let learner_ns = c.hosts.learner.clone().expect("a learner host");
    let start = c.actor_logs();
    c.wait_progress("both actors training", &start)?;

    // 1a. The learner's link down for less than the lease: TCP rides it out.
    c.hosts.set_link(&learner_ns, false)?;
    std::thread::sleep(LEASE / 2);
    c.hosts.set_link(&learner_ns, true)?;
    c.say("learner's link was down for 1 s");
    let after = c.actor_logs();
    let d = c.wait_progress("progress after the short learner outage", &after)?;
    tl.recoveries
        .push(("learner link down 1 s".into(), d.as_secs_f64()));

    // 1b. Down for longer than the lease: the router drops the learner's liveliness token, the
    //     actors see it leave (and hold off); when the link is back they see it join and re-send
    //     their outboxes.
    let before = c.actor_logs();
    c.hosts.set_link(&learner_ns, false)?;
    let down = Instant::now();
    let noticed = c.wait_logs(
        "both actors to see the learner leave",
        Duration::from_secs(30),
        |l| (0..2).all(|k| l[k].learner_left > before[k].learner_left),
    );
    // Lost while the link is down: whatever is in flight (episodes, acks).
    std::thread::sleep(Duration::from_secs(1));
    c.hosts.set_link(&learner_ns, true)?;
    c.say(&format!(
        "learner's link was down for {:.1} s",
        down.elapsed().as_secs_f64()
    ));
    let after = c.actor_logs();
    let noticed = noticed?;
    tl.notes.push(format!(
        "long learner outage noticed by both actors after {:.1} s",
        noticed.as_secs_f64()
    ));
    let d = c.wait_progress("progress after the long learner outage", &after)?;
    tl.recoveries
        .push(("learner link down > lease".into(), d.as_secs_f64()));
    let rejoined = c.actor_logs();
    if !(0..2).all(|k| rejoined[k].learner_joined > before[k].learner_joined) {
        return Err("an actor did not see the learner join again after its outage".into());
    }

    // 2. The router is killed (a crash) and started again on the same port.
    let old = c.router.clone();
    c.procs.kill(&old);
    c.say("router killed");
    std::thread::sleep(LEASE + Duration::from_secs(1));
    c.start_router("router-restarted");
    c.say("router started again");
    let after = c.actor_logs();
    let d = c.wait_progress("progress after the router restart", &after)?;
    tl.recoveries
        .push(("router restart".into(), d.as_secs_f64()));
    let restarted = c.actor_logs();
    tl.notes.push(format!(
        "router restart: the actors saw the learner leave {} and {} times, join {} and {} times",
        restarted[0].learner_left - rejoined[0].learner_left,
        restarted[1].learner_left - rejoined[1].learner_left,
        restarted[0].learner_joined - rejoined[0].learner_joined,
        restarted[1].learner_joined - rejoined[1].learner_joined,
    ));

    // 3. Loss and delay on actor 0's link for a while; training goes on.
    let before = c.actor_logs();
    let (qdisc, kind) = impairment(c);
    c.say(&format!("actor 0's link: {}", qdisc.join(" ")));
    std::thread::sleep(Duration::from_secs(10));
    let during = c.actor_logs();
    let drops = qdisc_drops(&c.hosts.actors[0], "eth0") + qdisc_drops(&c.hosts.hub, "to-a1");
    c.hosts.set_link_qdisc(&c.hosts.actors[0], None)?;
    c.say("actor 0's link clean again");
    let after = c.actor_logs();
    tl.notes.push(format!(
        "{kind} on actor 0's link for 10 s: {drops} packets dropped; meanwhile {} episodes of actor 0 and {} of actor 1 acknowledged",
        during[0].dropped.len() - before[0].dropped.len(),
        during[1].dropped.len() - before[1].dropped.len()
    ));
    let d = c.wait_progress("progress after loss and delay", &after)?;
    tl.recoveries
        .push((format!("{kind} loss/delay 10 s"), d.as_secs_f64()));

    // 4. Actor 1 slowed down (stopped 2/3 of the time), then frozen for longer than the lease
    //    (the router drops its session; it reconnects when it runs again).
    let before = c.actor_logs();
    let slow = Instant::now();
    while slow.elapsed() < Duration::from_secs(8) {
        c.procs.signal("actor-1", libc::SIGSTOP)?;
        std::thread::sleep(Duration::from_millis(300));
        c.procs.signal("actor-1", libc::SIGCONT)?;
        std::thread::sleep(Duration::from_millis(150));
    }
    let during = c.actor_logs();
    tl.notes.push(format!(
        "actor 1 slowed for 8 s: {} of its episodes acknowledged meanwhile (actor 0: {})",
        during[1].dropped.len() - before[1].dropped.len(),
        during[0].dropped.len() - before[0].dropped.len()
    ));
    c.procs.signal("actor-1", libc::SIGSTOP)?;
    std::thread::sleep(LEASE * 2);
    c.procs.signal("actor-1", libc::SIGCONT)?;
    c.say("actor 1 slowed for 8 s, then frozen for 4 s");
    let after = c.actor_logs();
    let d = c.wait_progress("progress after the slow actor", &after)?;
    tl.recoveries
        .push(("slow, then frozen actor".into(), d.as_secs_f64()));

    // 5. The learner killed (SIGKILL) mid-run and started again: it resumes from its checkpoint
    //    and write-ahead log, cuts its training log back, and the actors re-send what it never
    //    acknowledged.
    let before = c.actor_logs();
    c.procs.kill("learner");
    let _ = std::fs::rename(c.log("learner"), c.log("learner-killed"));
    c.start_learner();
    c.say("learner killed (SIGKILL) and started again");
    let d = c.wait_progress("progress after the learner's restart", &before)?;
    tl.recoveries
        .push(("learner killed and restarted".into(), d.as_secs_f64()));
    Ok(())
}

/// The learner's training log, episode by episode: its RL lines name the actor that played each
/// episode and the episode's index in that actor's numbering. Every actor's trained episodes must
/// be exactly 0..n, each once and in order (a restarted learner cuts its log back to its
/// checkpoint and trains the log's episodes again), the lines' own count 0..N with N the sum of
/// the actors' n, and every trained episode one the store holds as accepted.
fn trained(run_dir: &Path, durable: &Durable) -> (Vec<String>, String) {
    let mut p = Vec::new();
    let text = match std::fs::read_to_string(run_dir.join("metrics.jsonl")) {
        Ok(t) => t,
        Err(e) => return (vec![format!("reading metrics.jsonl: {e}")], String::new()),
    };
    let mut per_actor: BTreeMap<u64, Vec<u64>> = BTreeMap::new();
    let mut count = 0u64;
    for (i, line) in text.lines().enumerate() {
        let Ok(v) = serde_json::from_str::<serde_json::Value>(line) else {
            p.push(format!("metrics.jsonl line {}: not JSON", i + 1));
            continue;
        };
        if v["phase"] != "rl" {
            continue;
        }
        if v["episode"].as_u64() != Some(count) {
            p.push(format!(
                "metrics.jsonl line {}: RL episode {} where {count} was due",
                i + 1,
                v["episode"]
            ));
        }
        count += 1;
        match (v["actor"].as_u64(), v["actor_episode"].as_u64()) {
            (Some(a), Some(e)) => per_actor.entry(a).or_default().push(e),
            _ => p.push(format!(
                "metrics.jsonl line {}: no actor or actor_episode",
                i + 1
            )),
        }
    }
    let mut summary = format!("training log: {count} RL episodes");
    let mut sum = 0;
    for (a, eps) in &per_actor {
        let n = eps.len() as u64;
        sum += n;
        if !eps.iter().copied().eq(0..n) {
            let mut seen = BTreeSet::new();
            let twice: Vec<u64> = eps.iter().filter(|e| !seen.insert(**e)).copied().collect();
            p.push(format!(
                "actor {a}: trained episodes are not 0..{n} once each in order (twice: {twice:?}; first ones: {:?})",
                &eps[..eps.len().min(20)]
            ));
        }
        let accepted: BTreeSet<u64> = durable.accepted(*a as u32).into_iter().collect();
        let unknown: Vec<u64> = eps
            .iter()
            .filter(|e| !accepted.contains(e))
            .copied()
            .collect();
        if !unknown.is_empty() {
            p.push(format!(
                "actor {a}: trained episodes the store does not hold as accepted: {unknown:?}"
            ));
        }
        summary += &format!(", actor {a}: 0..{n} ({} accepted)", accepted.len());
    }
    if sum != count {
        p.push(format!(
            "the actors' trained episodes add up to {sum}, the log has {count}"
        ));
    }
    (p, summary)
}

#[test]
fn every_episode_an_actor_dropped_on_an_ack_is_in_the_learners_store_despite_partitions() {
    if std::env::var(mh::HELPER_ENV).is_ok() {
        return;
    }
    let unavailable = mh::netns_unavailable().or_else(|| {
        std::process::Command::new("tc")
            .arg("-V")
            .output()
            .err()
            .map(|e| format!("`tc` (iproute2) cannot be run: {e}"))
    });
    if let Some(why) = unavailable {
        use std::io::Write as _;
        let _ = writeln!(
            std::io::stderr(),
            "SKIPPED partitions test: {why}. It runs where network namespaces can be made (root with iproute2, as in CI)."
        );
        return;
    }
    let shm_before = ShmSnapshot::take();
    let mut c =
        Cluster::new(Hosts::create_with_learner_host("p").expect("creating the emulated hosts"));
    c.t0 = Instant::now();
    c.start_router("router");
    c.start_learner();
    c.start_actor(0);
    c.start_actor(1);
    let hub = c.hosts.hub.clone();
    let obs_log = c.log("observer");
    let monitor = c.monitor.clone();
    let obs = Observer::start(&mut c.procs, &hub, &mh::helper_args(), &monitor, &obs_log);

    let mut tl = Timeline::default();
    let outcome = scenario(&mut c, &mut tl);
    let (learner_metrics, resent) = obs.with(|s| {
        let l = |k: &str| s.value("learner-0", k).unwrap_or(f64::NAN);
        let r = |k: u32| {
            s.value(&format!("actor-{k}"), "episodes_resent")
                .unwrap_or(f64::NAN)
        };
        (
            format!(
                "learner (last metrics): {} episodes, {} duplicates, {} out of order",
                l("episodes"),
                l("duplicate_episodes"),
                l("out_of_order_episodes")
            ),
            format!(
                "episodes re-sent (metrics): actor 0 {}, actor 1 {}",
                r(0),
                r(1)
            ),
        )
    });

    // The end: the learner dies without a last checkpoint; what it acknowledged must be on disk.
    c.procs.kill("learner");
    c.say("learner killed (SIGKILL)");
    c.procs.kill("actor-0");
    c.procs.kill("actor-1");
    let logs = c.actor_logs();
    let durable = Durable::read(&c.run_dir, &c.run_id);
    let (problems, summary) = match &durable {
        Ok(d) => {
            let (mut p, mut s) = account(&logs, d);
            let (tp, ts) = trained(&c.run_dir, d);
            p.extend(tp);
            s = format!("{s}\n{ts}");
            (p, s)
        }
        Err(e) => (
            vec![format!("reading the learner's store: {e}")],
            String::new(),
        ),
    };
    println!("{summary}");
    println!("{learner_metrics}\n{resent}");
    for (k, l) in logs.iter().enumerate() {
        println!(
            "actor {k}: saw the learner leave {} times and join {} times, {} re-sends after 5 s without progress",
            l.learner_left, l.learner_joined, l.resends
        );
    }
    for n in &tl.notes {
        println!("{n}");
    }
    for (what, s) in &tl.recoveries {
        println!("recovery after {what}: {s:.1} s");
    }
    println!("whole test {:.1} s", c.t0.elapsed().as_secs_f64());
    let few: Vec<String> = (0..2)
        .filter(|&k| (logs[k].dropped.len() as u64) < 6 * PROGRESS)
        .map(|k| {
            format!(
                "actor {k} has only {} episodes acknowledged",
                logs[k].dropped.len()
            )
        })
        .collect();
    if outcome.is_err() || !problems.is_empty() || !few.is_empty() {
        panic!(
            "scenario: {}\naccounting problems: {problems:#?}\n{}\n{}",
            outcome.err().unwrap_or_else(|| "completed".into()),
            few.join("\n"),
            c.logs()
        );
    }

    // Clean-up (also done by the drops on a panic): processes, namespaces, files.
    let ns = [
        c.hosts.hub.clone(),
        c.hosts.actors[0].clone(),
        c.hosts.actors[1].clone(),
        learner_ns_name(&c),
    ];
    let run_id = c.run_id.clone();
    let dir = c.dir.path().to_path_buf();
    if std::env::var_os("FSRL_MULTIHOST_KEEP").is_some() {
        let kept = std::mem::replace(&mut c.dir, tempfile::tempdir().unwrap()).keep();
        println!("logs and the run directory kept in {}", kept.display());
        return;
    }
    drop(obs);
    drop(c);
    let listed = std::process::Command::new("ip")
        .args(["netns", "list"])
        .output()
        .unwrap();
    let listed = String::from_utf8_lossy(&listed.stdout);
    for n in &ns {
        assert!(!listed.contains(n.as_str()), "namespace {n} left behind");
    }
    assert!(!dir.exists(), "{} left behind", dir.display());
    let leaked =
        shm_before.new_since(|e| e.contains("zenoh") || e.contains("fsrl") || e.contains(&run_id));
    assert!(leaked.is_empty(), "shared memory left behind: {leaked:?}");
}

fn learner_ns_name(c: &Cluster) -> String {
    c.hosts.learner.clone().expect("a learner host")
}
