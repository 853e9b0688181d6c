//! Time to the plateau on emulated hosts (issue 34, item 2; docs/REPRODUCTION.md, Experiment
//! 17): FSRL on env1-invisible, the fixed schedule (20 batches per episode) against the adaptive
//! replay ratio (`[train.rl] replay_ratio = { min = 2, max = 20 }`) with 1, 2 and 4 actor hosts,
//! on one emulated cluster: the router on a hub, the learner on its own host (0.75 core, one
//! update thread), each actor host 0.2 core, the evaluator on the hub in its own 0.2-core group
//! (validating the latest weights on the 100 validation seeds as often as it can, every 100 RL
//! episodes at most, and keeping each validated snapshot), every process the real `fsrl` binary
//! with the `deploy/` configs (TLS, per-role users), each host a network namespace in its own
//! CPU cgroup.
//!
//! Every run of a seed starts from the same warm start (the fast schedule's 1000 demonstrations
//! × 30 epochs, trained once per seed by `fsrl train --single-process --rl-episodes 0` on the
//! whole machine and copied into each run), so the clock measures RL only. A run lasts
//! `PLATEAU_CAP_S` seconds (default 720); afterwards each validated snapshot whose validation
//! success is at least 0.95 is tested on the 500 test seeds (`fsrl eval`), in the order they were
//! made, until one reaches the fast schedule's test success interval (0.983 ± 0.008: at least
//! 0.975). Its time (the evaluator's clock when it took the weights for that validation: the
//! evaluator starts with the learner and validates the newest weights it has) is the run's
//! time to the plateau; a run that does not get there within its cap has none.
//!
//! Results go to `docs/results/plateau/<config>-s<seed>.json`, one file per run, with the
//! evaluator's validation log beside it (`<config>-s<seed>.validation.jsonl`); a run whose
//! file exists is not run again (resumable; delete a file to redo it). The table of all files
//! is printed at the end. Configs and seeds: `PLATEAU_CONFIGS` (default
//! `fixed-4,adaptive-4,adaptive-2,adaptive-1`), `PLATEAU_SEEDS` (default `0,1,2`).
//!
//! **Budget mode** (`PLATEAU_BUDGET_S=T`; issue 43, item 4; docs/REPRODUCTION.md, Experiment
//! 28): every run lasts `T` seconds of RL and is then judged by what it would ship: the
//! snapshot its own `train.select` rule chooses (with its ε-decay boundary, both read from the
//! run's checkpoint) among the validations the evaluator made within those `T` seconds, tested
//! on the 500 test seeds (success, timeouts, Nav. Time, Disc.; the whole `fsrl eval` report
//! kept as `<config>-s<seed>.eval.json`, for `fsrl compare`). No plateau search. Results go to
//! `docs/results/budget/<method>-<T>s/` unless `PLATEAU_OUT` says otherwise.
//! `PLATEAU_METHOD` (default `fsrl`) is the method the runs train, in both modes.
//!
//! Needs root, `ip netns` and a CPU cgroup controller; skips with a message otherwise. About
//! 13 minutes per run plus the tests of its snapshots, and nothing else should run meanwhile.
//! `cargo bench --workspace --bench plateau`

#[path = "../tests/multihost_support/mod.rs"]
mod multihost_support;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use mh::budget::{self, actor_hub_addr};
use mh::cgroup::CpuGroup;
use mh::{adapt_actor_config, adapt_deploy_config, router_args_for_run, table, Hosts, Procs};
use multihost_support as mh;
use policy::method::Method;

const LEARNER_CORES: f64 = 0.75;
const ACTOR_CORES: f64 = 0.2;
const EVALUATOR_CORES: f64 = 0.2;
const HUB_CORES: f64 = 0.2;
const RATIO: (f64, f64) = (2.0, 20.0);
const VALIDATION_EVERY: u64 = 100;
/// Validation success a snapshot needs before it is tested.
const VALIDATION_BAR: f64 = 0.95;
/// The fast schedule's test success, 0.983 ± 0.008 over three seeds: its interval's low end.
const TEST_BAR: f64 = 0.975;

fn fsrl() -> &'static Path {
    Path::new(env!("CARGO_BIN_EXE_fsrl"))
}

/// Where the results go: `PLATEAU_OUT`, by default `docs/results/plateau` (budget mode:
/// `docs/results/budget/<method>-<T>s`).
fn results_dir() -> PathBuf {
    let default = match budget() {
        Some(t) => format!("docs/results/budget/{}-{}s", method().name(), t.as_secs()),
        None => "docs/results/plateau".to_string(),
    };
    std::env::var_os("PLATEAU_OUT").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join(default),
        PathBuf::from,
    )
}

/// The method the runs train: `PLATEAU_METHOD`, by default `fsrl` (Experiment 17's).
fn method() -> Method {
    std::env::var("PLATEAU_METHOD").map_or(Method::Fsrl, |m| {
        m.parse()
            .unwrap_or_else(|e| panic!("PLATEAU_METHOD: bad method `{m}`: {e}"))
    })
}

/// Budget mode's wall-clock budget: `PLATEAU_BUDGET_S` (unset: the plateau mode).
fn budget() -> Option<Duration> {
    std::env::var("PLATEAU_BUDGET_S").ok().map(|s| {
        let t: u64 = s
            .parse()
            .unwrap_or_else(|_| panic!("PLATEAU_BUDGET_S: whole seconds, not `{s}`"));
        assert!(t > 0, "PLATEAU_BUDGET_S: a budget of 0 s trains nothing");
        Duration::from_secs(t)
    })
}

/// One run's shape: the fixed schedule or the adaptive mode, and the actor hosts.
#[derive(Clone, Copy, Debug)]
struct Config {
    adaptive: bool,
    actors: usize,
}

impl Config {
    fn parse(s: &str) -> Option<Self> {
        let (mode, n) = s.split_once('-')?;
        let adaptive = match mode {
            "fixed" => false,
            "adaptive" => true,
            _ => return None,
        };
        let actors = n.parse().ok().filter(|n| (1..=4).contains(n))?;
        Some(Self { adaptive, actors })
    }
    fn name(&self) -> String {
        format!(
            "{}-{}",
            if self.adaptive { "adaptive" } else { "fixed" },
            self.actors
        )
    }
}

fn env_list(key: &str, default: &str) -> Vec<String> {
    std::env::var(key)
        .unwrap_or_else(|_| default.to_string())
        .split(',')
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .collect()
}

fn main() {
    if mh::helper_main() {
        return;
    }
    let configs: Vec<Config> = env_list(
        "PLATEAU_CONFIGS",
        "fixed-4,adaptive-4,adaptive-2,adaptive-1",
    )
    .iter()
    .map(|s| {
        Config::parse(s).unwrap_or_else(|| {
            panic!("PLATEAU_CONFIGS: bad entry `{s}` (fixed-N or adaptive-N, N in 1..=4)")
        })
    })
    .collect();
    let seeds: Vec<u64> = env_list("PLATEAU_SEEDS", "0,1,2")
        .iter()
        .map(|s| {
            s.parse()
                .unwrap_or_else(|_| panic!("PLATEAU_SEEDS: bad seed `{s}`"))
        })
        .collect();
    let cap = budget().unwrap_or_else(|| {
        Duration::from_secs(
            std::env::var("PLATEAU_CAP_S")
                .ok()
                .map(|s| s.parse().expect("PLATEAU_CAP_S: seconds"))
                .unwrap_or(720),
        )
    });
    let method = method();
    let out = results_dir();
    std::fs::create_dir_all(&out).unwrap();
    let todo: Vec<(u64, Config)> = seeds
        .iter()
        .flat_map(|&s| configs.iter().map(move |&c| (s, c)))
        .filter(|(s, c)| !out.join(format!("{}-s{s}.json", c.name())).exists())
        .collect();
    if !todo.is_empty() {
        if let Some(why) = mh::netns_unavailable().or_else(mh::cgroup::cgroups_unavailable) {
            println!("plateau benchmark skipped: {why}");
            return;
        }
        let work = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/plateau-work");
        std::fs::create_dir_all(&work).unwrap();
        let secrets = tempfile::tempdir().unwrap();
        let (hosts, actor_hosts) =
            budget::make_hosts("p", 4, secrets.path()).expect("making the emulated hosts");
        for (seed, config) in todo {
            let warm = warm_start(&work, method, seed);
            eprintln!(
                "plateau: {} {} seed {seed} (cap {} s)",
                method.name(),
                config.name(),
                cap.as_secs()
            );
            let result = run(
                &hosts,
                &actor_hosts,
                secrets.path(),
                &work,
                &warm,
                method,
                seed,
                config,
                cap,
            )
            .unwrap_or_else(|e| panic!("{} seed {seed}: {e}", config.name()));
            let path = out.join(format!("{}-s{seed}.json", config.name()));
            std::fs::write(&path, serde_json::to_string_pretty(&result).unwrap() + "\n").unwrap();
            eprintln!("plateau: wrote {}", path.display());
        }
        drop(hosts);
    }
    print_table(&out);
}

fn run_id(seed: u64) -> String {
    format!("plateau-s{seed}")
}

/// The warm start of `method` and `seed` (trained once, on the whole machine): its checkpoint.
fn warm_start(work: &Path, method: Method, seed: u64) -> PathBuf {
    let dir = work
        .join(format!("warm-{}-s{seed}", method.name()))
        .join(run_id(seed));
    let ckpt = dir.join("checkpoints/latest.ckpt");
    if ckpt.exists() {
        return ckpt;
    }
    let _ = std::fs::remove_dir_all(&dir);
    eprintln!("plateau: warm start of {} seed {seed}", method.name());
    let o = Command::new(fsrl())
        .args(["train", "--single-process", "--method", method.name()])
        .args(["--setting", "env1-invisible", "--seed", &seed.to_string()])
        .args(["--rl-episodes", "0", "--eval-episodes", "1", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "warm start: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    ckpt
}

fn config_edit(
    t: &mut toml::Table,
    method: Method,
    seed: u64,
    config: Config,
    endpoint: &str,
    run_dir: &Path,
) {
    let r = table(t, &["run"]);
    r.insert("id".into(), run_id(seed).into());
    r.insert("method".into(), method.name().into());
    r.insert("setting".into(), "env1-invisible".into());
    r.insert("seed".into(), (seed as i64).into());
    let z = table(t, &["transport", "zenoh"]);
    z.insert("connect".into(), toml::Value::Array(vec![endpoint.into()]));
    let tr = table(t, &["train"]);
    tr.insert(
        "validation_every_episodes".into(),
        (VALIDATION_EVERY as i64).into(),
    );
    let rl = table(t, &["train", "rl"]);
    rl.insert("episodes".into(), 1_000_000.into());
    if config.adaptive {
        let mut ratio = toml::Table::new();
        ratio.insert("min".into(), RATIO.0.into());
        ratio.insert("max".into(), RATIO.1.into());
        rl.insert("replay_ratio".into(), toml::Value::Table(ratio));
    }
    if t.contains_key("learner") {
        let l = table(t, &["learner"]);
        l.insert(
            "run_dir".into(),
            run_dir.to_string_lossy().into_owned().into(),
        );
        l.insert("threads".into(), 1.into());
        l.insert("metrics_interval_ms".into(), 500.into());
    }
    if t.contains_key("evaluator") {
        let e = table(t, &["evaluator"]);
        e.insert("every_episodes".into(), 0.into());
        e.insert("threads".into(), 1.into());
        e.insert(
            "out_dir".into(),
            run_dir
                .join("evaluator")
                .to_string_lossy()
                .into_owned()
                .into(),
        );
    }
}

#[derive(serde::Serialize, serde::Deserialize)]
struct Validation {
    /// RL episodes the validated weights were trained on.
    episode: u64,
    success: f64,
    /// The evaluator's clock when it took these weights (s since it started, with the learner).
    at_s: Option<f64>,
    test_success: Option<f64>,
}

/// Test metrics of one policy on the 500 test seeds of env1-invisible.
#[derive(serde::Serialize, serde::Deserialize)]
struct Tested {
    success: f64,
    collision: f64,
    timeout: f64,
    nav_time_s: Option<f64>,
    disc: f64,
}

/// Budget mode: the snapshot the run's own rule ships at the budget, and its test.
#[derive(serde::Serialize, serde::Deserialize)]
struct Shipped {
    /// The run's `train.select` rule and the end of its ε decay (RL episodes).
    select: String,
    epsilon_decay_episodes: u64,
    episode: u64,
    validation_success: f64,
    test: Tested,
}

#[derive(serde::Serialize, serde::Deserialize)]
struct RunResult {
    /// Absent in Experiment 17's files: FSRL.
    #[serde(default)]
    method: Option<String>,
    config: String,
    seed: u64,
    cap_s: f64,
    learner_cores: f64,
    actor_cores: f64,
    replay_ratio: Option<(f64, f64)>,
    rl_episodes: u64,
    updates: u64,
    episodes_per_s: f64,
    updates_per_s: f64,
    updates_per_episode: f64,
    learner_wall_s: f64,
    validations: Vec<Validation>,
    /// Time to the plateau (s of the learner's clock), if reached within the cap.
    plateau_s: Option<f64>,
    plateau_episode: Option<u64>,
    /// Budget mode's shipped policy (absent in the plateau mode).
    #[serde(default)]
    shipped: Option<Shipped>,
}

#[allow(clippy::too_many_arguments)]
fn run(
    hosts: &Hosts,
    actor_hosts: &[String],
    secrets: &Path,
    work: &Path,
    warm: &Path,
    method: Method,
    seed: u64,
    config: Config,
    cap: Duration,
) -> Result<RunResult, String> {
    let name = format!("{}-s{seed}", config.name());
    let run_dir = work.join("runs").join(&name);
    let _ = std::fs::remove_dir_all(&run_dir);
    std::fs::create_dir_all(run_dir.join("checkpoints")).unwrap();
    std::fs::copy(warm, run_dir.join("checkpoints/latest.ckpt")).unwrap();
    let learner_ns = hosts.learner.clone().ok_or("no learner host")?;
    let id = run_id(seed);
    let hub_group = CpuGroup::create("pl-hub", HUB_CORES)?;
    let eval_group = CpuGroup::create("pl-eval", EVALUATOR_CORES)?;
    let learner_group = CpuGroup::create("pl-learner", LEARNER_CORES)?;
    let actor_groups: Vec<CpuGroup> = (0..config.actors)
        .map(|k| CpuGroup::create(&format!("pl-actor{k}"), ACTOR_CORES))
        .collect::<Result<_, _>>()?;
    let mut procs = Procs::default();
    let env = [("RUST_LOG", "warn".to_string())];
    let log = |n: &str| run_dir.join(format!("{n}.log"));
    let s = |a: &[&str]| a.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    procs.spawn(
        "router",
        &hosts.hub,
        fsrl(),
        &router_args_for_run(secrets, &id, &[]),
        &env,
        &log("router"),
    );
    hub_group.add(procs.pid("router").unwrap())?;
    std::thread::sleep(Duration::from_millis(500));
    let cfg = |deploy: &str, out: &str, endpoint: String| {
        adapt_deploy_config(deploy, secrets, out, |t| {
            config_edit(t, method, seed, config, &endpoint, &run_dir)
        })
    };
    let learner_cfg = cfg(
        "cluster-learner.toml",
        &format!("{name}-learner.toml"),
        format!("tls/{}:7447", Hosts::learner_hub_addr()),
    );
    let eval_cfg = cfg(
        "cluster-evaluator.toml",
        &format!("{name}-evaluator.toml"),
        "tls/127.0.0.1:7447".to_string(),
    );
    let started = Instant::now();
    procs.spawn(
        "learner",
        &learner_ns,
        fsrl(),
        &s(&["learner", "--config", &learner_cfg.to_string_lossy()]),
        &env,
        &log("learner"),
    );
    learner_group.add(procs.pid("learner").unwrap())?;
    procs.spawn(
        "evaluator",
        &hosts.hub,
        fsrl(),
        &s(&["evaluator", "--config", &eval_cfg.to_string_lossy()]),
        &env,
        &log("evaluator"),
    );
    eval_group.add(procs.pid("evaluator").unwrap())?;
    for (k, ns) in actor_hosts.iter().enumerate().take(config.actors) {
        let actor_cfg =
            adapt_actor_config(k as u32, secrets, &format!("{name}-actor{k}.toml"), |t| {
                config_edit(
                    t,
                    method,
                    seed,
                    config,
                    &format!("tls/{}:7447", actor_hub_addr(k)),
                    &run_dir,
                )
            });
        let pname = format!("actor-{k}");
        procs.spawn(
            &pname,
            ns,
            fsrl(),
            &s(&[
                "actor",
                "--config",
                &actor_cfg.to_string_lossy(),
                "--id",
                &k.to_string(),
            ]),
            &env,
            &log(&pname),
        );
        actor_groups[k].add(procs.pid(&pname).unwrap())?;
    }
    while started.elapsed() < cap {
        std::thread::sleep(Duration::from_secs(2));
        if let Some((n, status)) = procs.exited().into_iter().next() {
            return Err(format!(
                "{n} exited: {status}; logs:\n{}",
                mh::log_tails(&run_dir, 15)
            ));
        }
    }
    // The learner checkpoints on SIGTERM: its counters are the run's.
    let _ = procs.signal("learner", libc::SIGTERM);
    let deadline = Instant::now() + Duration::from_secs(60);
    while procs.running("learner") == Some(true) && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(200));
    }
    procs.kill_all();
    drop(procs);
    drop((hub_group, eval_group, learner_group, actor_groups));

    let loaded = learner::checkpoint::load(&run_dir.join("checkpoints/latest.ckpt"))
        .map_err(|e| format!("the run's checkpoint: {e}"))?;
    let warm_core = learner::checkpoint::load(warm)
        .map_err(|e| e.to_string())?
        .core;
    let c = loaded.core.counters();
    let updates = c.updates - warm_core.counters().updates;
    // The learner's clock at its last RL episode, from its log.
    let text = std::fs::read_to_string(run_dir.join("metrics.jsonl")).unwrap_or_default();
    let learner_wall = text
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|v| v["phase"] == "rl")
        .filter_map(|v| v["wall_s"].as_f64())
        .fold(0.0, f64::max);
    let eval_dir = run_dir.join("evaluator");
    let log = std::fs::read_to_string(eval_dir.join("validation.jsonl")).unwrap_or_default();
    std::fs::write(results_dir().join(format!("{name}.validation.jsonl")), &log)
        .map_err(|e| e.to_string())?;
    let mut validations: Vec<Validation> = log
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|v| {
            Some(Validation {
                episode: v["episode"].as_u64()?,
                success: v["success_rate"].as_f64()?,
                at_s: v["wall_s"].as_f64(),
                test_success: None,
            })
        })
        .collect();
    let (mut plateau_s, mut plateau_episode) = (None, None);
    let shipped = match budget() {
        Some(_) => Some(shipped_at_budget(&loaded.core, &log, &eval_dir, &run_dir)?),
        None => None,
    };
    for v in validations.iter_mut().filter(|_| shipped.is_none()) {
        if v.success < VALIDATION_BAR {
            continue;
        }
        let snapshot = learner::model::snapshot_path(&eval_dir, v.episode);
        let test = test(&snapshot, &run_dir)?.success;
        eprintln!(
            "plateau: {name}: episode {} validation {:.2} test {test:.3}",
            v.episode, v.success
        );
        v.test_success = Some(test);
        if test >= TEST_BAR {
            plateau_s = v.at_s;
            plateau_episode = Some(v.episode);
            break;
        }
    }
    let rl_episodes = c.rl_episodes;
    Ok(RunResult {
        method: Some(method.name().to_string()),
        config: config.name(),
        seed,
        cap_s: cap.as_secs_f64(),
        learner_cores: LEARNER_CORES,
        actor_cores: ACTOR_CORES,
        replay_ratio: config.adaptive.then_some(RATIO),
        rl_episodes,
        updates,
        episodes_per_s: rl_episodes as f64 / learner_wall.max(1e-9),
        updates_per_s: updates as f64 / learner_wall.max(1e-9),
        updates_per_episode: updates as f64 / (rl_episodes as f64).max(1.0),
        learner_wall_s: learner_wall,
        validations,
        plateau_s,
        plateau_episode,
        shipped,
    })
}

/// Budget mode: the snapshot the run's own `train.select` chooses among the evaluator's
/// validations (`log`, all made within the budget, as the run stopped there), tested.
fn shipped_at_budget(
    core: &learner::LearnerCore,
    log: &str,
    eval_dir: &Path,
    run_dir: &Path,
) -> Result<Shipped, String> {
    let rule = core.config().select;
    let decay = core.config().rl.epsilon_decay_episodes;
    let (all, _) = lab::select::validations(log);
    let on_disk = all
        .into_iter()
        .filter(|v| learner::model::snapshot_path(eval_dir, v.rl_episodes).exists());
    let v = lab::select::choose(rule, on_disk, decay)
        .ok_or_else(|| format!("`{}` chose no validation snapshot", rule.name()))?;
    let snapshot = learner::model::snapshot_path(eval_dir, v.rl_episodes);
    let test = test(&snapshot, run_dir)?;
    // The whole report beside the run's file, for `fsrl compare` between the arms.
    let name = run_dir.file_name().unwrap_or_default().to_string_lossy();
    std::fs::copy(
        run_dir.join("test/eval.json"),
        results_dir().join(format!("{name}.eval.json")),
    )
    .map_err(|e| format!("keeping the test report: {e}"))?;
    eprintln!(
        "plateau: shipped at the budget: episode {} ({}), validation {:.2}, test {:.3} success {:.3} timeouts",
        v.rl_episodes,
        rule.name(),
        v.success,
        test.success,
        test.timeout
    );
    Ok(Shipped {
        select: rule.name().to_string(),
        epsilon_decay_episodes: decay,
        episode: v.rl_episodes,
        validation_success: v.success,
        test,
    })
}

/// A snapshot's test on the 500 test seeds of env1-invisible (`fsrl eval`).
fn test(snapshot: &Path, run_dir: &Path) -> Result<Tested, String> {
    let out = run_dir.join("test");
    let o = Command::new(fsrl())
        .arg("eval")
        .arg(snapshot)
        .args(["--settings", "env1-invisible", "--out"])
        .arg(&out)
        .output()
        .map_err(|e| e.to_string())?;
    if !o.status.success() {
        return Err(format!(
            "fsrl eval {}: {}",
            snapshot.display(),
            String::from_utf8_lossy(&o.stderr)
        ));
    }
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("eval.json")).map_err(|e| e.to_string())?,
    )
    .map_err(|e| e.to_string())?;
    let row = &report["subjects"][0]["settings"][0];
    let num = |k: &str| {
        row[k]
            .as_f64()
            .ok_or_else(|| format!("no `{k}` in {}", out.join("eval.json").display()))
    };
    Ok(Tested {
        success: num("success")?,
        collision: num("collision")?,
        timeout: num("timeout")?,
        nav_time_s: row["nav_time_s"].as_f64(),
        disc: num("disc")?,
    })
}

fn print_table(dir: &Path) {
    let mut rows: Vec<RunResult> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| serde_json::from_str(&std::fs::read_to_string(e.path()).ok()?).ok())
        .collect();
    rows.sort_by(|a, b| (a.config.as_str(), a.seed).cmp(&(b.config.as_str(), b.seed)));
    if rows.iter().any(|r| r.shipped.is_some()) {
        println!("\n| method | config | seed | budget (s) | RL episodes | updates/episode | shipped (rule, episode) | validation | test success | timeouts | Nav. Time (s) | Disc. |");
        println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
        for r in &rows {
            let Some(p) = &r.shipped else { continue };
            println!(
                "| {} | {} | {} | {:.0} | {} | {:.1} | {} ep {} | {:.2} | {:.3} | {:.3} | {} | {:.3} |",
                r.method.as_deref().unwrap_or("fsrl"),
                r.config,
                r.seed,
                r.cap_s,
                r.rl_episodes,
                r.updates_per_episode,
                p.select,
                p.episode,
                p.validation_success,
                p.test.success,
                p.test.timeout,
                p.test.nav_time_s.map_or("–".into(), |t| format!("{t:.2}")),
                p.test.disc,
            );
        }
        return;
    }
    println!("\n| config | seed | RL episodes/s | updates/s | updates/episode | validations | time to plateau (s) | at episode |");
    println!("|---|---|---|---|---|---|---|---|");
    for r in &rows {
        println!(
            "| {} | {} | {:.2} | {:.1} | {:.1} | {} | {} | {} |",
            r.config,
            r.seed,
            r.episodes_per_s,
            r.updates_per_s,
            r.updates_per_episode,
            r.validations.len(),
            r.plateau_s
                .map_or(format!("> {:.0} (not reached)", r.cap_s), |t| format!(
                    "{t:.0}"
                )),
            r.plateau_episode.map_or("–".into(), |e| e.to_string()),
        );
    }
}
