//! Crash consistency of the learner's persistence (`learner::store`, the code `process::run`
//! uses): a kill, a torn write and a power loss at every file-system step of opening the run
//! directory, appending to the write-ahead log, writing a checkpoint (write → sync → rename →
//! directory sync) and emptying the log, also while recovering from an earlier fault; and a
//! full disk (a real tmpfs). Asserted by identity: every (actor, episode) acknowledged before
//! the fault is in the checkpoint or the log afterwards, and no episode is trained twice.
//!
//! How the faults are made: the store reports every step to a [`Probe`]. The probe here keeps
//! a model of what a power loss would leave (per file the content of its last sync; per
//! directory the entries of its last sync — a rename or a new file whose directory was not
//! synced is lost) and, at the planned step, crashes the "process" by unwinding out of the
//! store (no clean-up code runs; files written so far stay, as after `kill -9`), first cutting
//! the write in half for a torn write, or rebuilding the run directory from the model for a
//! power loss. Then a new "process" opens the store from what is on disk.
//!
//! The learner is modelled by what it has trained on, in order (its lineage). Each checkpoint
//! carries a generation number as a pseudo-actor in `accepted_below`, so that the lineage of
//! whichever checkpoint survives is known; recovery = that lineage + the episodes
//! `store::replay_plan` replays from the log, exactly as `process::run` does.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::io::Write;
use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use learner::checkpoint::{RunIdentity, RunInfo};
use learner::store::{replay_plan, Op, Probe, Store};
use learner::LearnerCore;
use policy::method::{Method, TrainConfig};
use proto::{
    EpisodeMeta, HumanState, Message, Outcome, RewardTerms, RobotState, Role, RunId, SenderId,
    TransitionBatch,
};
use sim::SimConfig;

const ACTORS: u32 = 2;
/// Episodes per actor in a scenario.
const EPISODES: u64 = 4;
/// A checkpoint after this many accepted episodes (and one at the end).
const CHECKPOINT_EVERY: u64 = 3;
/// The pseudo-actor whose `accepted_below` entry is a checkpoint's generation.
const GEN: u32 = u32::MAX;

/// (actor, episode).
type Id = (u32, u64);

fn identity() -> RunIdentity {
    RunIdentity {
        run_id: "crash".into(),
        method: Method::Sarl,
        setting: "env1-invisible".into(),
        run_seed: 7,
    }
}

fn run_info(accepted_below: BTreeMap<u32, u64>) -> RunInfo {
    let id = identity();
    RunInfo {
        run_id: id.run_id,
        setting: id.setting,
        run_seed: id.run_seed,
        accepted_below,
    }
}

struct Fixture {
    core: LearnerCore,
    sim: SimConfig,
}

fn fixture() -> Fixture {
    Fixture {
        core: LearnerCore::new(Method::Sarl, TrainConfig::default(), 5, 0.25, 7).unwrap(),
        sim: SimConfig::default(),
    }
}

/// The write-ahead log record of `actor`'s `episode`: an encoded message, as the learner logs.
fn record(actor: u32, episode: u64, steps: u32) -> Vec<u8> {
    let humans = [HumanState {
        radius_m: 0.3,
        ..HumanState::default()
    }; 5];
    let robot = RobotState {
        radius_m: 0.3,
        v_pref_mps: 1.0,
        ..RobotState::default()
    };
    let meta = EpisodeMeta {
        setting: "env1-invisible".into(),
        seed: episode,
        episode,
        n_actions: 81,
        epsilon: 0.1,
        human_standing: vec![false; 5],
    };
    let mut b = TransitionBatch::builder(meta, robot, &humans);
    for _ in 0..steps {
        b.push_step(1, RewardTerms::default(), 1.0, &robot, &humans);
    }
    let batch = b.finish(Outcome::ReachGoal).unwrap();
    let msg = Message::new(
        RunId::new("crash").unwrap(),
        SenderId::new(Role::Actor, actor),
        episode,
        0,
        batch,
    );
    proto::encode_message(&msg).unwrap()
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Fault {
    /// The process dies after the step (`kill -9`): what it wrote stays.
    Kill,
    /// The process dies half-way through a write (only at `Written` steps).
    Torn,
    /// The machine loses power after the step: only what was synced stays.
    PowerLoss,
}

/// The unwinding payload of a planned crash.
struct Crash;

/// What the file system holds, and what a power loss would leave.
#[derive(Default)]
struct Disk {
    /// Per inode, its content at its last sync (`None`: never synced).
    synced: Vec<Option<Vec<u8>>>,
    /// Names as the running process sees them.
    live: HashMap<PathBuf, usize>,
    /// Names as they would be after a power loss.
    durable: HashMap<PathBuf, usize>,
    /// Steps seen so far, over every session.
    steps: u64,
    /// The fault to inject at a step number (1-based).
    plan: Vec<(u64, Fault)>,
    /// Every step, for the messages.
    trace: Vec<String>,
    crashed: Option<Fault>,
}

impl Disk {
    fn see(&mut self, op: Op<'_>, path: &Path) {
        match op {
            Op::Created => {
                self.synced.push(None);
                self.live.insert(path.to_path_buf(), self.synced.len() - 1);
            }
            Op::Synced => {
                let id = self.live[path];
                self.synced[id] = Some(std::fs::read(path).unwrap());
            }
            Op::Written | Op::SetLen => {}
            Op::Renamed { from } => {
                let id = self.live.remove(from).unwrap();
                self.live.insert(path.to_path_buf(), id);
            }
            Op::Removed => {
                self.live.remove(path);
            }
            Op::DirSynced => {
                self.durable.retain(|p, _| p.parent() != Some(path));
                for (p, id) in &self.live {
                    if p.parent() == Some(path) {
                        self.durable.insert(p.clone(), *id);
                    }
                }
            }
        }
        self.trace.push(format!(
            "{} {op:?} {}",
            self.steps,
            path.file_name().unwrap().to_string_lossy()
        ));
    }

    /// Cuts the write just made to `path` in half.
    fn tear(&self, path: &Path) {
        let synced = self.synced[self.live[path]].as_ref().map_or(0, Vec::len) as u64;
        let now = std::fs::metadata(path).unwrap().len();
        let f = std::fs::OpenOptions::new().write(true).open(path).unwrap();
        f.set_len(synced + (now - synced) / 2).unwrap();
    }

    /// Replaces the files of `run_dir` by what a power loss leaves of them.
    fn power_loss(&mut self, run_dir: &Path) {
        for dir in [run_dir.to_path_buf(), run_dir.join("checkpoints")] {
            for e in std::fs::read_dir(&dir).unwrap() {
                let e = e.unwrap();
                if e.file_type().unwrap().is_file() && e.file_name() != "lock" {
                    std::fs::remove_file(e.path()).unwrap();
                }
            }
        }
        let mut synced = Vec::new();
        let mut names = HashMap::new();
        for (p, id) in &self.durable {
            let bytes = self.synced[*id].clone().unwrap_or_default();
            std::fs::write(p, &bytes).unwrap();
            synced.push(Some(bytes));
            names.insert(p.clone(), synced.len() - 1);
        }
        self.synced = synced;
        self.live = names.clone();
        self.durable = names;
    }

    fn probe(disk: &Arc<Mutex<Disk>>) -> Probe {
        let disk = Arc::clone(disk);
        Probe::new(move |op, path| {
            let crash = {
                let mut d = disk.lock().unwrap();
                d.steps += 1;
                d.see(op, path);
                let step = d.steps;
                match d.plan.iter().find(|(s, _)| *s == step).map(|p| p.1) {
                    Some(Fault::Torn) if op != Op::Written => None,
                    Some(f) => {
                        if f == Fault::Torn {
                            d.tear(path);
                        }
                        d.crashed = Some(f);
                        Some(f)
                    }
                    None => None,
                }
            };
            if crash.is_some() {
                resume_unwind(Box::new(Crash));
            }
            Ok(())
        })
    }
}

/// The actors and what they were told.
#[derive(Default)]
struct World {
    acked: BTreeSet<Id>,
    /// Per actor, its first episode not yet acknowledged (the one it sends).
    next: BTreeMap<u32, u64>,
    /// Per checkpoint generation, what the learner had trained on when writing it.
    lineages: HashMap<u64, Vec<Id>>,
    generations: u64,
    /// Step count when each session's store was open.
    opened_at: Vec<u64>,
}

/// The learner as far as persistence goes.
struct Learner {
    below: BTreeMap<u32, u64>,
    lineage: Vec<Id>,
}

/// Opens what is on disk like a restarting learner and checks the invariant.
fn recover(store: &Store, world: &World, ctx: &dyn Fn() -> String) -> Learner {
    let loaded = store
        .load_checkpoint(&identity())
        .unwrap_or_else(|e| panic!("{e}\n{}", ctx()));
    let (mut below, mut lineage) = match loaded {
        None => (BTreeMap::new(), Vec::new()),
        Some(l) => {
            let generation = l.run.accepted_below[&GEN];
            (l.run.accepted_below, world.lineages[&generation].clone())
        }
    };
    let in_checkpoint: BTreeSet<Id> = lineage.iter().copied().collect();
    let plan = replay_plan(store.wal_records(), &below);
    assert_eq!(plan.unreadable, 0, "{}", ctx());
    // As `process::run` does: every planned episode is accepted and trained on.
    for msg in &plan.episodes {
        let id = (msg.header.sender.index, msg.body.episode);
        lineage.push(id);
        below.insert(id.0, id.1 + 1);
    }
    let mut times: BTreeMap<Id, u32> = BTreeMap::new();
    for id in &lineage {
        *times.entry(*id).or_default() += 1;
    }
    let twice: Vec<_> = times.iter().filter(|(_, n)| **n > 1).collect();
    assert!(twice.is_empty(), "trained twice: {twice:?}\n{}", ctx());
    let lost: Vec<_> = world
        .acked
        .iter()
        .filter(|id| !times.contains_key(id))
        .collect();
    assert!(
        lost.is_empty(),
        "acknowledged, then lost: {lost:?}\n{}",
        ctx()
    );
    // Whatever the log holds is either replayed or already in the checkpoint.
    for rec in store.wal_records() {
        let msg = proto::decode::<TransitionBatch>(rec).unwrap();
        let id = (msg.header.sender.index, msg.body.episode);
        assert!(times.contains_key(&id), "{id:?} dropped\n{}", ctx());
        if in_checkpoint.contains(&id) {
            assert!(
                !plan
                    .episodes
                    .iter()
                    .any(|m| (m.header.sender.index, m.body.episode) == id),
                "{id:?} replayed although in the checkpoint\n{}",
                ctx()
            );
        }
    }
    Learner { below, lineage }
}

fn checkpoint(
    store: &mut Store,
    l: &mut Learner,
    world: &mut World,
    fx: &Fixture,
) -> Result<(), learner::checkpoint::CheckpointError> {
    world.generations += 1;
    let generation = world.generations;
    world.lineages.insert(generation, l.lineage.clone());
    l.below.insert(GEN, generation);
    store.checkpoint(&fx.core, &fx.sim, &run_info(l.below.clone()))
}

/// One learner process: recover, then accept episodes until every actor is done.
fn session(run_dir: &Path, disk: &Arc<Mutex<Disk>>, world: &mut World, fx: &Fixture) {
    let ctx = || {
        let d = disk.lock().unwrap();
        format!("fault plan {:?}; steps:\n{}", d.plan, d.trace.join("\n"))
    };
    let mut store = Store::open(run_dir, Disk::probe(disk))
        .unwrap_or_else(|e| panic!("opening the store: {e}\n{}", ctx()));
    world.opened_at.push(disk.lock().unwrap().steps);
    // Recovered in place: the log file is exactly its whole records, ready for appending.
    let on_disk = std::fs::metadata(store.wal().path()).unwrap().len();
    assert_eq!(on_disk, store.wal().len_bytes(), "{}", ctx());
    let mut l = recover(&store, world, &ctx);
    let mut accepted = 0;
    while let Some(actor) = (0..ACTORS)
        .filter(|a| world.next.get(a).copied().unwrap_or(0) < EPISODES)
        .min_by_key(|a| world.next.get(a).copied().unwrap_or(0))
    {
        let episode = world.next.get(&actor).copied().unwrap_or(0);
        if episode >= l.below.get(&actor).copied().unwrap_or(0) {
            store.append(&record(actor, episode, 3)).unwrap();
            l.lineage.push((actor, episode));
            l.below.insert(actor, episode + 1);
            accepted += 1;
        }
        // Durable (logged now, or earlier): acknowledged.
        world.acked.insert((actor, episode));
        world.next.insert(actor, episode + 1);
        if accepted > 0 && accepted % CHECKPOINT_EVERY == 0 {
            checkpoint(&mut store, &mut l, world, fx).unwrap();
        }
    }
    checkpoint(&mut store, &mut l, world, fx).unwrap();
}

struct Run {
    /// Steps of the whole scenario.
    steps: u64,
    trace: Vec<String>,
    /// Step count when each session had opened its store.
    opened_at: Vec<u64>,
}

/// Runs the scenario with `plan`'s faults, restarting after each, and checks the end state.
fn scenario(plan: &[(u64, Fault)], fx: &Fixture) -> Run {
    let tmp = scratch_dir();
    let run_dir = tmp.path().join("run");
    let disk = Arc::new(Mutex::new(Disk {
        plan: plan.to_vec(),
        ..Disk::default()
    }));
    let mut world = World::default();
    for _ in 0..=plan.len() {
        match catch_unwind(AssertUnwindSafe(|| {
            session(&run_dir, &disk, &mut world, fx)
        })) {
            Ok(()) => break,
            Err(p) if p.is::<Crash>() => {
                let mut d = disk.lock().unwrap();
                if d.crashed.take() == Some(Fault::PowerLoss) {
                    d.power_loss(&run_dir);
                }
            }
            Err(p) => resume_unwind(p),
        }
    }
    let d = disk.lock().unwrap();
    let ctx = || format!("fault plan {plan:?}; steps:\n{}", d.trace.join("\n"));
    let all: BTreeSet<Id> = (0..ACTORS)
        .flat_map(|a| (0..EPISODES).map(move |e| (a, e)))
        .collect();
    assert_eq!(world.acked, all, "{}", ctx());
    // A last restart sees everything, once.
    let store = Store::open(&run_dir, Probe::none()).unwrap();
    let l = recover(&store, &world, &ctx);
    assert_eq!(l.lineage.len(), all.len(), "{}", ctx());
    Run {
        steps: d.steps,
        trace: d.trace.clone(),
        opened_at: world.opened_at.clone(),
    }
}

/// A directory for a scenario; in memory when possible (the model, not the disk, decides what
/// a power loss keeps, and thousands of real syncs would only be slow).
fn scratch_dir() -> tempfile::TempDir {
    let shm = Path::new("/dev/shm");
    if shm.is_dir() {
        if let Ok(d) = tempfile::Builder::new()
            .prefix("fsrl-crash")
            .tempdir_in(shm)
        {
            return d;
        }
    }
    tempfile::tempdir().unwrap()
}

fn faults_at(step: &str) -> Vec<Fault> {
    if step.contains(" Written ") {
        vec![Fault::Kill, Fault::Torn, Fault::PowerLoss]
    } else {
        vec![Fault::Kill, Fault::PowerLoss]
    }
}

#[test]
fn acknowledged_episodes_survive_a_fault_at_every_step_and_none_is_trained_twice() {
    let fx = fixture();
    let clean = scenario(&[], &fx);
    assert!(clean.steps > 30, "{}", clean.trace.join("\n"));
    let mut scenarios = 1;
    for (i, step) in clean.trace.iter().enumerate() {
        let k = i as u64 + 1;
        for f in faults_at(step) {
            let once = scenario(&[(k, f)], &fx);
            scenarios += 1;
            // A second fault while the next process opens the store and recovers (cutting a
            // torn tail, removing a stale temporary file, creating the log): steps k+1..=end.
            let Some(&end) = once.opened_at.iter().find(|&&s| s > k) else {
                continue;
            };
            for j in k + 1..=end {
                for g in faults_at(&once.trace[j as usize - 1]) {
                    scenario(&[(k, f), (j, g)], &fx);
                    scenarios += 1;
                }
            }
            // After a torn write, a kill at any later step (appending after the cut tail).
            if f == Fault::Torn {
                for j in end + 1..=once.steps {
                    scenario(&[(k, f), (j, Fault::Kill)], &fx);
                    scenarios += 1;
                }
            }
        }
    }
    eprintln!(
        "crash consistency: {scenarios} scenarios over {} steps",
        clean.steps
    );
}

#[test]
fn a_checkpoint_of_another_run_is_refused_naming_both_values() {
    let fx = fixture();
    let tmp = scratch_dir();
    let mut store = Store::open(tmp.path(), Probe::none()).unwrap();
    store
        .checkpoint(&fx.core, &fx.sim, &run_info(BTreeMap::new()))
        .unwrap();
    assert!(store.load_checkpoint(&identity()).unwrap().is_some());
    let other = RunIdentity {
        run_id: "other".into(),
        method: Method::LstmRl,
        setting: "env2-visible".into(),
        run_seed: 8,
    };
    let msg = store.load_checkpoint(&other).err().unwrap().to_string();
    for part in [
        "latest.ckpt",
        "run id `crash` in the checkpoint, `other` configured",
        "method `sarl` in the checkpoint, `lstm-rl` configured",
        "setting `env1-invisible` in the checkpoint, `env2-visible` configured",
        "seed `7` in the checkpoint, `8` configured",
        "refusing to resume",
    ] {
        assert!(msg.contains(part), "{part:?} not in {msg}");
    }
}

/// A tmpfs of `size`, unmounted when dropped (also when the test fails).
struct Tmpfs {
    dir: tempfile::TempDir,
}

impl Tmpfs {
    fn mount(size: &str) -> Result<Self, String> {
        let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
        let euid = status
            .lines()
            .find_map(|l| l.strip_prefix("Uid:"))
            .and_then(|l| l.split_whitespace().nth(1))
            .unwrap_or("?");
        if euid != "0" {
            return Err(format!("not running as root (effective uid {euid})"));
        }
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        let out = std::process::Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(dir.path())
            .output()
            .map_err(|e| format!("cannot run mount: {e}"))?;
        if !out.status.success() {
            return Err(format!(
                "mount -t tmpfs failed: {}",
                String::from_utf8_lossy(&out.stderr).trim()
            ));
        }
        Ok(Self { dir })
    }

    fn path(&self) -> &Path {
        self.dir.path()
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let ok = std::process::Command::new("umount")
            .arg(self.dir.path())
            .status()
            .is_ok_and(|s| s.success());
        if !ok {
            let _ = std::process::Command::new("umount")
                .arg("-l")
                .arg(self.dir.path())
                .status();
        }
    }
}

/// Writes to `path` until the file system is full.
fn fill(path: &Path) {
    let mut f = std::fs::File::create(path).unwrap();
    let chunk = vec![0xA5u8; 1024];
    loop {
        match f.write(&chunk) {
            Ok(0) => break,
            Ok(_) => {}
            Err(e) => {
                assert_eq!(e.raw_os_error(), Some(28), "expected ENOSPC, got {e}");
                break;
            }
        }
    }
}

fn wal_ids(run_dir: &Path) -> Vec<Id> {
    let store = Store::open(run_dir, Probe::none()).unwrap();
    store
        .wal_records()
        .iter()
        .map(|r| {
            let m = proto::decode::<TransitionBatch>(r).unwrap();
            (m.header.sender.index, m.body.episode)
        })
        .collect()
}

#[test]
fn a_full_disk_fails_cleanly_and_the_store_goes_on_after_space_is_freed() {
    let fx = fixture();
    let probe_dir = scratch_dir();
    {
        let mut s = Store::open(probe_dir.path(), Probe::none()).unwrap();
        s.checkpoint(&fx.core, &fx.sim, &run_info(BTreeMap::new()))
            .unwrap();
    }
    let ckpt_len = std::fs::metadata(probe_dir.path().join("checkpoints/latest.ckpt"))
        .unwrap()
        .len();
    // Room for a checkpoint, its successor being written, and the log.
    let size = format!("{}k", (2 * ckpt_len + 256 * 1024) / 1024);
    let fs = match Tmpfs::mount(&size) {
        Ok(fs) => fs,
        Err(why) => {
            eprintln!("skipping the full-disk test: {why}");
            return;
        }
    };
    let run_dir = fs.path().join("run");
    let filler = fs.path().join("filler");
    let ckpt = run_dir.join("checkpoints/latest.ckpt");
    let tmp = run_dir.join("checkpoints/latest.tmp");
    let wal = run_dir.join("wal.bin");
    let mut acked: Vec<Id> = Vec::new();
    let mut below = BTreeMap::new();
    {
        let mut store = Store::open(&run_dir, Probe::none()).unwrap();
        // Records larger than a page, so that a full disk cuts one in the middle.
        for e in 0..3 {
            store.append(&record(0, e, 60)).unwrap();
            acked.push((0, e));
            below.insert(0, e + 1);
        }
        store
            .checkpoint(&fx.core, &fx.sim, &run_info(below.clone()))
            .unwrap();
        for e in 3..5 {
            store.append(&record(0, e, 60)).unwrap();
            acked.push((0, e));
            below.insert(0, e + 1);
        }
        let ckpt_before = std::fs::read(&ckpt).unwrap();
        let wal_before = std::fs::read(&wal).unwrap();

        fill(&filler);
        // The log: the append fails, and not even part of the record stays.
        let err = store.append(&record(0, 5, 60)).unwrap_err();
        assert_eq!(err.raw_os_error(), Some(28), "{err}");
        assert_eq!(std::fs::read(&wal).unwrap(), wal_before);
        // A checkpoint: fails, leaves no temporary file, and the log keeps its records.
        let err = store
            .checkpoint(&fx.core, &fx.sim, &run_info(below.clone()))
            .unwrap_err();
        assert!(err.to_string().contains("latest.tmp"), "{err}");
        assert!(!tmp.exists(), "a partial checkpoint was left behind");
        assert_eq!(std::fs::read(&ckpt).unwrap(), ckpt_before);
        assert_eq!(std::fs::read(&wal).unwrap(), wal_before);

        // Space again: the same store goes on.
        std::fs::remove_file(&filler).unwrap();
        store.append(&record(0, 5, 60)).unwrap();
        acked.push((0, 5));
        below.insert(0, 6);
        store.append(&record(1, 0, 60)).unwrap();
        acked.push((1, 0));
        below.insert(1, 1);
    }
    // What a restart sees: the checkpoint's episodes, then the log's, each once.
    let logged = wal_ids(&run_dir);
    assert_eq!(logged, [(0, 3), (0, 4), (0, 5), (1, 0)]);
    let mut store = Store::open(&run_dir, Probe::none()).unwrap();
    let loaded = store.load_checkpoint(&identity()).unwrap().unwrap();
    let in_ckpt: Vec<Id> = (0..loaded.run.accepted_below[&0]).map(|e| (0, e)).collect();
    let mut all: Vec<Id> = in_ckpt.into_iter().chain(logged).collect();
    all.sort();
    assert_eq!(all, acked);
    // And a checkpoint now succeeds and empties the log.
    store
        .checkpoint(&fx.core, &fx.sim, &run_info(below.clone()))
        .unwrap();
    drop(store);
    assert!(wal_ids(&run_dir).is_empty());
    assert!(!tmp.exists());
}
