//! Emulated hosts with their own CPU budget, for `benches/hosts.rs` and `tests/hosts.rs`: the
//! router (and the observer) on the hub, the learner on its own host, N actor hosts (one actor
//! process each), every host a network namespace joined to the hub by a veth pair and every
//! host's processes in its own CPU cgroup with a quota ([`super::cgroup`]). Every process is
//! the real `fsrl` binary with the `deploy/` configs (TLS, per-role users, access control).
//! [`run`] starts one such cluster, lets it warm up, measures a window and stops it.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::cgroup::{process_cpu_s, CpuGroup, Throttling};
use super::{
    adapt_actor_config, adapt_deploy_config, log_tails, router_args_for_run, table, Hosts,
    Observer, Procs,
};

/// The hub's address as seen from actor host `k` (0-based; hosts 0 and 1 are [`Hosts`]'s own,
/// the others are added by [`Hosts::add_actor_hosts`] on subnets 10.201.12, 10.201.13, ...).
pub fn actor_hub_addr(k: usize) -> String {
    if k < 2 {
        Hosts::hub_addr(k)
    } else {
        format!("10.201.{}.1", 10 + k)
    }
}

impl Hosts {
    /// Adds actor hosts after the two [`Hosts`] makes, until there are `n`, and returns the
    /// namespaces of all `n` actor hosts in order. Actor host `k` reaches the hub at
    /// [`actor_hub_addr`]`(k)`; the added ones are removed on drop like the rest.
    pub fn add_actor_hosts(&mut self, n: usize) -> Result<Vec<String>, String> {
        let prefix = self
            .hub
            .strip_suffix("-hub")
            .expect("hub names end in -hub")
            .to_string();
        let mut all: Vec<String> = self.actors.iter().take(n).cloned().collect();
        for k in 2..n {
            let ns = format!("{prefix}-a{}", k + 1);
            self.add_spoke(&ns, &format!("to-a{}", k + 1), 10 + k as u8)?;
            all.push(ns);
        }
        Ok(all)
    }
}

/// One cluster's shape and schedule.
#[derive(Clone, Debug)]
pub struct Spec {
    /// Actor hosts, one actor process each.
    pub actors: usize,
    /// CPU quota of each actor host, in cores.
    pub actor_cores: f64,
    /// CPU quota of the learner's host, in cores.
    pub learner_cores: f64,
    /// `[learner] threads`.
    pub learner_threads: u32,
    /// CPU quota of the hub (router and observer), in cores.
    pub hub_cores: f64,
    /// `[train.rl] batches_per_episode` (0: learner updates off).
    pub batches_per_episode: u32,
    /// `[train.rl] replay_ratio` (min, max): the adaptive mode; None: the fixed schedule.
    pub replay_ratio: Option<(f64, f64)>,
    /// RL episodes the learner must have taken in (and every actor be alive) before measuring.
    pub warm_episodes: f64,
    /// The measured window.
    pub measure: Duration,
    /// Longest wait for the warm-up.
    pub patience: Duration,
    /// `RUST_LOG` of the processes.
    pub log: String,
}

/// One process's CPU use over the window against its host's quota.
#[derive(Clone, Debug)]
pub struct ProcCpu {
    pub name: String,
    /// The host (cgroup) it ran in.
    pub host: String,
    /// CPU seconds per second of the window.
    pub cores: f64,
    /// Its host's quota, in cores.
    pub quota: f64,
    /// The fraction of CFS periods in which its host was throttled (stopped at its quota).
    pub host_throttled: f64,
}

/// What one cluster did in the measured window.
#[derive(Clone, Debug)]
pub struct Measured {
    pub spec: Spec,
    /// Length of the window by the learner's clock, s.
    pub window_s: f64,
    /// RL episodes the learner took in during the window.
    pub episodes: f64,
    pub episodes_per_s: f64,
    pub updates_per_s: f64,
    /// Realised replay ratio: updates per accepted episode.
    pub updates_per_episode: f64,
    /// Updates per environment step taken in.
    pub updates_per_step: f64,
    /// Environment steps per episode taken in.
    pub steps_per_episode: f64,
    /// The learner's policy lag (versions between the weights an episode was made with and the
    /// learner's when it took it in) over its last window of episodes, mean and p95.
    pub lag_mean: f64,
    pub lag_p95: f64,
    /// Bytes per second into and out of the router (the hub's ends of every link).
    pub router_in_bps: f64,
    pub router_out_bps: f64,
    /// Into the router from the actor hosts (episodes), out of it to the actor hosts (weights,
    /// control, acknowledgements), per second.
    pub from_actors_bps: f64,
    pub to_actors_bps: f64,
    pub procs: Vec<ProcCpu>,
    /// Actor CPU seconds per episode taken in (all actors).
    pub actor_cpu_s_per_episode: f64,
    /// Learner CPU seconds per update (intake included), if it updated.
    pub learner_cpu_s_per_update: f64,
    /// Actors' time spent waiting for credits, per actor and second of the window.
    pub actor_wait_frac: f64,
}

impl Measured {
    /// Actor processes' CPU use.
    pub fn actors(&self) -> impl Iterator<Item = &ProcCpu> {
        self.procs.iter().filter(|p| p.name.starts_with("actor-"))
    }
}

fn fsrl() -> &'static Path {
    Path::new(env!("CARGO_BIN_EXE_fsrl"))
}

/// A deploy config for a run of the emulated cluster (SARL on env1-invisible, a short warm
/// start, RL without end, `batches_per_episode` updates per episode or the adaptive mode's
/// `replay_ratio` bounds, the learner's update `threads` when given, else its default);
/// `deploy` is a file of `deploy/` or `actor-<k>` (actor k's own file, made as
/// `deploy/README.md` makes it). The benchmarks share it.
#[allow(clippy::too_many_arguments)]
pub fn run_config(
    dir: &Path,
    deploy: &str,
    out: &str,
    run_id: &str,
    endpoint: &str,
    batches_per_episode: u32,
    replay_ratio: Option<(f64, f64)>,
    threads: Option<u32>,
) -> PathBuf {
    let run_dir = dir.join(format!("run-{run_id}"));
    let edit = |t: &mut toml::Table| {
        let r = table(t, &["run"]);
        r.insert("id".into(), run_id.into());
        r.insert("method".into(), "sarl".into());
        r.insert("setting".into(), "env1-invisible".into());
        let z = table(t, &["transport", "zenoh"]);
        z.insert("connect".into(), toml::Value::Array(vec![endpoint.into()]));
        let i = table(t, &["train", "imitation"]);
        i.insert("episodes".into(), 5.into());
        i.insert("epochs".into(), 1.into());
        let rl = table(t, &["train", "rl"]);
        rl.insert("episodes".into(), 1_000_000.into());
        rl.insert(
            "batches_per_episode".into(),
            i64::from(batches_per_episode).into(),
        );
        if let Some((min, max)) = replay_ratio {
            let mut bounds = toml::Table::new();
            bounds.insert("min".into(), min.into());
            bounds.insert("max".into(), max.into());
            rl.insert("replay_ratio".into(), toml::Value::Table(bounds));
        }
        if t.contains_key("learner") {
            let l = table(t, &["learner"]);
            l.insert(
                "run_dir".into(),
                run_dir.to_string_lossy().into_owned().into(),
            );
            l.insert("in_flight_per_actor".into(), 8.into());
            l.insert("metrics_interval_ms".into(), 250.into());
            if let Some(n) = threads {
                l.insert("threads".into(), i64::from(n).into());
            }
        }
    };
    match deploy.strip_prefix("actor-") {
        Some(k) => adapt_actor_config(k.parse().expect("an actor id"), dir, out, edit),
        None => adapt_deploy_config(deploy, dir, out, edit),
    }
}

/// [`run_config`] with this spec's schedule and learner threads.
fn config(
    dir: &Path,
    spec: &Spec,
    deploy: &str,
    out: &str,
    run_id: &str,
    endpoint: &str,
) -> PathBuf {
    run_config(
        dir,
        deploy,
        out,
        run_id,
        endpoint,
        spec.batches_per_episode,
        spec.replay_ratio,
        Some(spec.learner_threads),
    )
}

/// Bytes received and sent by the hub's interface `dev`, from the hub's `/proc/net/dev`.
fn hub_link_bytes(hub: &str) -> Result<Vec<(String, u64, u64)>, String> {
    let o = std::process::Command::new("ip")
        .args(["netns", "exec", hub, "cat", "/proc/net/dev"])
        .output()
        .map_err(|e| format!("reading the hub's /proc/net/dev: {e}"))?;
    let text = String::from_utf8_lossy(&o.stdout);
    Ok(text
        .lines()
        .filter_map(|l| {
            let (name, rest) = l.split_once(':')?;
            let f: Vec<u64> = rest
                .split_whitespace()
                .filter_map(|x| x.parse().ok())
                .collect();
            (f.len() >= 9).then(|| (name.trim().to_string(), f[0], f[8]))
        })
        .filter(|(n, _, _)| n.starts_with("to-"))
        .collect())
}

struct Sample {
    at: Instant,
    learner: [f64; 4], // wall s, episodes, updates, env steps
    cpu: Vec<Option<f64>>,
    throttling: Vec<Throttling>,
    links: Vec<(String, u64, u64)>,
    actor_wait: f64,
}

/// Runs one cluster on `hosts` (the hub, the learner's host and `actor_hosts`, made by
/// [`Hosts::create_with_learner_host`] and [`Hosts::add_actor_hosts`]) with the secrets in
/// `dir` ([`super::make_secrets`] naming every hub address), measures it and stops it. The
/// cgroups are removed before it returns, also on error or panic. `helper_args`: what makes
/// this binary run the observer helper ([`super::helper_args`] in a test, none in a bench).
pub fn run(
    hosts: &Hosts,
    actor_hosts: &[String],
    dir: &Path,
    run_id: &str,
    spec: &Spec,
    helper_args: &[String],
) -> Result<Measured, String> {
    let n = spec.actors;
    assert!(
        n <= actor_hosts.len(),
        "{n} actors, {} hosts",
        actor_hosts.len()
    );
    let learner_ns = hosts
        .learner
        .clone()
        .ok_or("the learner needs its own host (Hosts::create_with_learner_host)")?;
    let tag = run_id.rsplit('-').next().unwrap_or("x");
    // Declared before the processes: dropped (removed) after they are killed.
    let hub_group = CpuGroup::create(&format!("{tag}-hub"), spec.hub_cores)?;
    let learner_group = CpuGroup::create(&format!("{tag}-learner"), spec.learner_cores)?;
    let actor_groups: Vec<CpuGroup> = (0..n)
        .map(|k| CpuGroup::create(&format!("{tag}-actor{k}"), spec.actor_cores))
        .collect::<Result<_, _>>()?;
    let mut procs = Procs::default();
    // (process name, group index: 0 hub, 1 learner, 2 + k actor k)
    let mut members: Vec<(String, usize)> = Vec::new();
    let group = |i: usize| -> &CpuGroup {
        match i {
            0 => &hub_group,
            1 => &learner_group,
            k => &actor_groups[k - 2],
        }
    };
    let env = [("RUST_LOG", spec.log.clone())];
    let start = |procs: &mut Procs,
                 members: &mut Vec<(String, usize)>,
                 name: &str,
                 ns: &str,
                 args: Vec<String>,
                 g: usize|
     -> Result<(), String> {
        procs.spawn(
            name,
            ns,
            fsrl(),
            &args,
            &env,
            &dir.join(format!("{run_id}-{name}.log")),
        );
        group(g).add(procs.pid(name).expect("just started"))?;
        members.push((name.to_string(), g));
        Ok(())
    };
    let s = |a: &[&str]| a.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    start(
        &mut procs,
        &mut members,
        "router",
        &hosts.hub,
        router_args_for_run(dir, run_id, &[]),
        0,
    )?;
    let learner_cfg = config(
        dir,
        spec,
        "cluster-learner.toml",
        &format!("{run_id}-learner.toml"),
        run_id,
        &format!("tls/{}:7447", Hosts::learner_hub_addr()),
    );
    start(
        &mut procs,
        &mut members,
        "learner",
        &learner_ns,
        s(&["learner", "--config", &learner_cfg.to_string_lossy()]),
        1,
    )?;
    for (k, ns) in actor_hosts.iter().enumerate().take(n) {
        let cfg = config(
            dir,
            spec,
            &format!("actor-{k}"),
            &format!("{run_id}-actor{k}.toml"),
            run_id,
            &format!("tls/{}:7447", actor_hub_addr(k)),
        );
        start(
            &mut procs,
            &mut members,
            &format!("actor-{k}"),
            ns,
            s(&[
                "actor",
                "--config",
                &cfg.to_string_lossy(),
                "--id",
                &k.to_string(),
            ]),
            2 + k,
        )?;
    }
    let monitor = config(
        dir,
        spec,
        "cluster-monitor.toml",
        &format!("{run_id}-monitor.toml"),
        run_id,
        "tls/127.0.0.1:7447",
    );
    let obs = Observer::start(
        &mut procs,
        &hosts.hub,
        helper_args,
        &monitor,
        &dir.join(format!("{run_id}-observer.log")),
    );
    hub_group.add(procs.pid("observer").expect("started"))?;
    members.push(("observer".into(), 0));

    let fail = |what: String| format!("{what}; logs:\n{}", log_tails(dir, 15));
    obs.wait_until(spec.patience, |s| {
        s.value("learner-0", "episodes").unwrap_or(0.0) >= spec.warm_episodes
            && s.value("learner-0", "actors_alive") == Some(n as f64)
    })
    .map_err(|()| {
        fail(format!(
            "the learner did not take in {} RL episodes from {n} actors within {:?}",
            spec.warm_episodes, spec.patience
        ))
    })?;
    let groups: Vec<&CpuGroup> = (0..n + 2).map(group).collect();
    let sample = |procs: &Procs| -> Result<Sample, String> {
        let (learner, actor_wait) = obs.with(|s| {
            let v = |k: &str| s.value("learner-0", k).unwrap_or(0.0);
            let wait: f64 = (0..n)
                .map(|k| s.value(&format!("actor-{k}"), "wait_s").unwrap_or(0.0))
                .sum();
            (
                [
                    v("msg_wall_time_s"),
                    v("episodes"),
                    v("updates"),
                    v("msg_env_steps"),
                ],
                wait,
            )
        });
        Ok(Sample {
            at: Instant::now(),
            learner,
            cpu: members
                .iter()
                .map(|(name, _)| procs.pid(name).and_then(process_cpu_s))
                .collect(),
            throttling: groups.iter().map(|g| g.throttling()).collect(),
            links: hub_link_bytes(&hosts.hub)?,
            actor_wait,
        })
    };
    let a = sample(&procs)?;
    std::thread::sleep(spec.measure);
    let b = sample(&procs)?;
    if let Some((name, status)) = procs.exited().into_iter().next() {
        return Err(fail(format!("{name} exited during the window: {status}")));
    }
    procs.kill_all();
    drop(procs);

    let wall = b.learner[0] - a.learner[0];
    if wall <= 0.0 {
        return Err(fail("no learner metrics during the window".into()));
    }
    let episodes = b.learner[1] - a.learner[1];
    let updates = b.learner[2] - a.learner[2];
    let steps = b.learner[3] - a.learner[3];
    let secs = b.at.duration_since(a.at).as_secs_f64();
    let link = |pick: &dyn Fn(&str) -> bool, rx: bool| -> f64 {
        let sum = |v: &[(String, u64, u64)]| -> u64 {
            v.iter()
                .filter(|(d, _, _)| pick(d))
                .map(|(_, r, t)| if rx { *r } else { *t })
                .sum()
        };
        sum(&b.links).saturating_sub(sum(&a.links)) as f64 / secs
    };
    let any = |_: &str| true;
    let to_actor = |d: &str| d.starts_with("to-a");
    let procs_cpu: Vec<ProcCpu> = members
        .iter()
        .enumerate()
        .map(|(i, (name, g))| {
            let used = match (a.cpu[i], b.cpu[i]) {
                (Some(x), Some(y)) => (y - x) / secs,
                _ => f64::NAN,
            };
            ProcCpu {
                name: name.clone(),
                host: match g {
                    0 => "hub".into(),
                    1 => "learner".into(),
                    k => format!("actor host {}", k - 2),
                },
                cores: used,
                quota: groups[*g].cores(),
                host_throttled: b.throttling[*g].since(&a.throttling[*g]).fraction(),
            }
        })
        .collect();
    let cpu_of = |pred: &dyn Fn(&str) -> bool| -> f64 {
        procs_cpu
            .iter()
            .filter(|p| pred(&p.name))
            .map(|p| p.cores)
            .sum::<f64>()
            * secs
    };
    let actor_cpu = cpu_of(&|n| n.starts_with("actor-"));
    let learner_cpu = cpu_of(&|n| n == "learner");
    Ok(Measured {
        spec: spec.clone(),
        window_s: wall,
        episodes,
        episodes_per_s: episodes / wall,
        updates_per_s: updates / wall,
        updates_per_episode: if episodes > 0.0 {
            updates / episodes
        } else {
            0.0
        },
        updates_per_step: if steps > 0.0 { updates / steps } else { 0.0 },
        steps_per_episode: if episodes > 0.0 {
            steps / episodes
        } else {
            0.0
        },
        lag_mean: obs.with(|s| s.value("learner-0", "policy_lag_mean").unwrap_or(f64::NAN)),
        lag_p95: obs.with(|s| s.value("learner-0", "policy_lag_p95").unwrap_or(f64::NAN)),
        router_in_bps: link(&any, true),
        router_out_bps: link(&any, false),
        from_actors_bps: link(&to_actor, true),
        to_actors_bps: link(&to_actor, false),
        procs: procs_cpu,
        actor_cpu_s_per_episode: if episodes > 0.0 {
            actor_cpu / episodes
        } else {
            f64::NAN
        },
        learner_cpu_s_per_update: if updates > 0.0 {
            learner_cpu / updates
        } else {
            f64::NAN
        },
        actor_wait_frac: (b.actor_wait - a.actor_wait) / secs / n as f64,
    })
}

/// Makes the hosts for up to `max_actors` actor hosts plus the learner's, and the secrets in
/// `dir` with a router certificate naming every hub address. Returns the hosts and the actor
/// hosts' namespaces.
pub fn make_hosts(
    tag: &str,
    max_actors: usize,
    dir: &Path,
) -> Result<(Hosts, Vec<String>), String> {
    let mut hosts = Hosts::create_with_learner_host(tag)?;
    let actors = hosts.add_actor_hosts(max_actors)?;
    let mut ips: Vec<String> = (0..max_actors).map(actor_hub_addr).collect();
    ips.push(Hosts::learner_hub_addr());
    super::make_secrets(dir, &ips)?;
    Ok((hosts, actors))
}
