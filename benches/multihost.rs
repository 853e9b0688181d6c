//! Across machines, emulated: the hosts of `tests/multihost.rs` (network namespaces joined by
//! veth pairs; a hub with the router and the learner, two actor hosts), every process the real
//! `fsrl` binary with the `deploy/` configs (TLS, user/password, access control). Measures, in
//! one run:
//!
//! 1. episodes/s with the two actors on their own hosts vs the same processes all on the hub
//!    talking over loopback (same router, TLS and credentials; learner updates off,
//!    `batches_per_episode = 0`, so that the actors and the transport set the pace);
//! 2. weight broadcast latency (SARL weights, 386,819 bytes, learner → router → 3 subscribers:
//!    one per actor host and one on the hub), p50/p99 over tcp/ vs tls/ endpoints of the same
//!    router (both authenticated and access-controlled). Send and receive times are
//!    CLOCK_MONOTONIC, which every namespace shares; receive is after decoding and validation.
//!
//! Needs root and `ip netns`. `cargo bench -p fsrl --bench multihost`

#[path = "../tests/multihost_support/mod.rs"]
mod multihost_support;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use mh::{Hosts, Observer, Procs};
use multihost_support as mh;

const WARM_EPISODES: f64 = 30.0;
const MEASURE: Duration = Duration::from_secs(20);
const WEIGHTS_SENT: u64 = 300;
const WEIGHTS_PERIOD_MS: u64 = 20;

fn main() {
    if mh::helper_main() {
        return;
    }
    if let Some(why) = mh::netns_unavailable() {
        println!("multihost benchmark skipped: {why}");
        return;
    }
    let hosts = Hosts::create("b").expect("creating the emulated hosts");
    let dir = tempfile::tempdir().unwrap();
    let ips: Vec<String> = (0..2).map(Hosts::hub_addr).collect();
    mh::make_secrets(dir.path(), &ips).unwrap();

    println!(
        "episodes/s, 2 actors, learner updates off, {} s measured after {WARM_EPISODES} episodes:",
        MEASURE.as_secs()
    );
    let across = episodes_per_s(&hosts, dir.path(), true);
    println!("  actors on their own hosts (veth, TLS): {across:.2} episodes/s");
    let local = episodes_per_s(&hosts, dir.path(), false);
    println!("  everything on one host (loopback, TLS): {local:.2} episodes/s");
    println!("  ratio across hosts / loopback: {:.3}", across / local);

    println!("weight broadcast latency ({WEIGHTS_SENT} × SARL weights every {WEIGHTS_PERIOD_MS} ms, 3 subscribers, via the router):");
    let mut results = Vec::new();
    for proto in ["tcp", "tls", "tcp", "tls"] {
        let lat = weight_latency(&hosts, dir.path(), proto);
        println!(
            "  {proto}: {} deliveries, p50 {:.2} ms, p99 {:.2} ms",
            lat.len(),
            pct(&lat, 0.50),
            pct(&lat, 0.99)
        );
        results.push((proto, lat));
    }
    let pooled = |p: &str| -> Vec<f64> {
        let mut v: Vec<f64> = results
            .iter()
            .filter(|(q, _)| *q == p)
            .flat_map(|(_, l)| l.iter().copied())
            .collect();
        v.sort_by(f64::total_cmp);
        v
    };
    let (tcp, tls) = (pooled("tcp"), pooled("tls"));
    println!(
        "  pooled: tcp p50 {:.2} ms p99 {:.2} ms; tls p50 {:.2} ms p99 {:.2} ms; TLS overhead p50 {:+.2} ms ({:+.0} %), p99 {:+.2} ms ({:+.0} %)",
        pct(&tcp, 0.5),
        pct(&tcp, 0.99),
        pct(&tls, 0.5),
        pct(&tls, 0.99),
        pct(&tls, 0.5) - pct(&tcp, 0.5),
        100.0 * (pct(&tls, 0.5) / pct(&tcp, 0.5) - 1.0),
        pct(&tls, 0.99) - pct(&tcp, 0.99),
        100.0 * (pct(&tls, 0.99) / pct(&tcp, 0.99) - 1.0),
    );
}

fn pct(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let mut v = sorted.to_vec();
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn fsrl() -> &'static Path {
    Path::new(env!("CARGO_BIN_EXE_fsrl"))
}

fn spawn(procs: &mut Procs, dir: &Path, name: &str, ns: &str, args: &[String]) {
    procs.spawn(
        name,
        ns,
        fsrl(),
        args,
        &[("RUST_LOG", "warn".into())],
        &dir.join(format!("{name}.log")),
    );
}

fn strings(a: &[&str]) -> Vec<String> {
    a.iter().map(|s| s.to_string()).collect()
}

/// A deploy config with the run and endpoint of this benchmark and learner updates off
/// (`batches_per_episode = 0`: the actors and the transport set the pace); `deploy` is a file of
/// `deploy/` or `actor-<k>`.
fn config(dir: &Path, deploy: &str, out: &str, run_id: &str, endpoint: &str) -> PathBuf {
    mh::budget::run_config(dir, deploy, out, run_id, endpoint, 0, None, None)
}

fn episodes_per_s(hosts: &Hosts, dir: &Path, across: bool) -> f64 {
    let run_id = format!(
        "bench-{}-{}",
        if across { "hosts" } else { "loop" },
        std::process::id()
    );
    let local = "tls/127.0.0.1:7447";
    let mut procs = Procs::default();
    let learner = config(
        dir,
        "cluster-learner.toml",
        "b-learner.toml",
        &run_id,
        local,
    );
    let monitor = config(
        dir,
        "cluster-monitor.toml",
        "b-monitor.toml",
        &run_id,
        local,
    );
    spawn(
        &mut procs,
        dir,
        "router",
        &hosts.hub,
        &mh::router_args_for_run(dir, &run_id, &[]),
    );
    spawn(
        &mut procs,
        dir,
        "learner",
        &hosts.hub,
        &strings(&["learner", "--config", &learner.to_string_lossy()]),
    );
    for k in 0..2 {
        let (ns, endpoint) = if across {
            (
                hosts.actors[k].clone(),
                format!("tls/{}:7447", Hosts::hub_addr(k)),
            )
        } else {
            (hosts.hub.clone(), local.to_string())
        };
        let cfg = config(
            dir,
            &format!("actor-{k}"),
            &format!("b-actor{k}.toml"),
            &run_id,
            &endpoint,
        );
        spawn(
            &mut procs,
            dir,
            &format!("actor-{k}"),
            &ns,
            &strings(&[
                "actor",
                "--config",
                &cfg.to_string_lossy(),
                "--id",
                &k.to_string(),
            ]),
        );
    }
    let obs = Observer::start(
        &mut procs,
        &hosts.hub,
        &[],
        &monitor,
        &dir.join("b-observer.log"),
    );
    let sample = |obs: &Observer| {
        obs.with(|s| {
            (
                s.value("learner-0", "msg_wall_time_s").unwrap_or(0.0),
                s.value("learner-0", "episodes").unwrap_or(0.0),
            )
        })
    };
    obs.wait_until(Duration::from_secs(120), |s| {
        s.value("learner-0", "episodes").unwrap_or(0.0) >= WARM_EPISODES
            && s.value("learner-0", "actors_alive") == Some(2.0)
    })
    .unwrap_or_else(|()| panic!("no training within 2 minutes; logs in {}", dir.display()));
    let (w0, e0) = sample(&obs);
    std::thread::sleep(MEASURE);
    let (w1, e1) = sample(&obs);
    procs.kill_all();
    (e1 - e0) / (w1 - w0)
}

/// Latencies (ms) of every weight delivery to 3 subscribers over `proto` (tcp or tls).
fn weight_latency(hosts: &Hosts, dir: &Path, proto: &str) -> Vec<f64> {
    let run_id = format!("lat-{proto}-{}", std::process::id());
    let port = if proto == "tls" { 7447 } else { 7448 };
    let mut procs = Procs::default();
    let extra = [
        "transport/link/protocols:[\"tls\",\"tcp\"]".to_string(),
        "listen/endpoints:[\"tls/0.0.0.0:7447\",\"tcp/0.0.0.0:7448\"]".to_string(),
    ];
    spawn(
        &mut procs,
        dir,
        &format!("router-{proto}"),
        &hosts.hub,
        &mh::router_args_for_run(dir, &run_id, &extra),
    );
    let ep = |host: &str| format!("{proto}/{host}:{port}");
    let publisher = config(
        dir,
        "cluster-learner.toml",
        "l-pub.toml",
        &run_id,
        &ep("127.0.0.1"),
    );
    let subs = [
        (
            hosts.actors[0].clone(),
            config(
                dir,
                "actor-0",
                "l-sub0.toml",
                &run_id,
                &ep(&Hosts::hub_addr(0)),
            ),
        ),
        (
            hosts.actors[1].clone(),
            config(
                dir,
                "actor-1",
                "l-sub1.toml",
                &run_id,
                &ep(&Hosts::hub_addr(1)),
            ),
        ),
        (
            hosts.hub.clone(),
            config(
                dir,
                "cluster-evaluator.toml",
                "l-sub2.toml",
                &run_id,
                &ep("127.0.0.1"),
            ),
        ),
    ];
    let helper = |mode: &str, ns: &str, cfg: &Path, arg: String| {
        Command::new("ip")
            .args(["netns", "exec", ns])
            .arg(std::env::current_exe().unwrap())
            .env(mh::HELPER_ENV, mode)
            .env(mh::CONFIG_ENV, cfg)
            .env(mh::ARG_ENV, arg)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("helper")
    };
    // Each helper's stdout: (ready?, lines) gathered by a thread.
    let (tx, rx) = std::sync::mpsc::channel::<(usize, serde_json::Value)>();
    let start_reader = |idx: usize, mut child: std::process::Child, procs: &mut Procs| {
        let out = child.stdout.take().unwrap();
        procs.adopt(&format!("helper-{idx}"), child);
        let tx = tx.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if let Ok(v) = serde_json::from_str(&line) {
                    let _ = tx.send((idx, v));
                }
            }
        });
    };
    for (i, (ns, cfg)) in subs.iter().enumerate() {
        start_reader(i, helper("latency-sub", ns, cfg, i.to_string()), &mut procs);
    }
    let mut sent = std::collections::BTreeMap::new();
    let mut recv: Vec<(usize, u64, u64)> = Vec::new();
    let mut ready = 0;
    let mut published = false;
    let mut done = false;
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut done_at: Option<Instant> = None;
    while Instant::now() < deadline {
        if ready == subs.len() && !published {
            start_reader(
                9,
                helper(
                    "latency-pub",
                    &hosts.hub,
                    &publisher,
                    format!("{WEIGHTS_SENT},{WEIGHTS_PERIOD_MS}"),
                ),
                &mut procs,
            );
            published = true;
        }
        if done_at.is_some_and(|t| t.elapsed() > Duration::from_secs(2)) {
            break;
        }
        let Ok((idx, v)) = rx.recv_timeout(Duration::from_millis(100)) else {
            continue;
        };
        match v["k"].as_str() {
            Some("ready") if idx < 9 => ready += 1,
            Some("sent") => {
                sent.insert(v["v"].as_u64().unwrap(), v["t"].as_u64().unwrap());
            }
            Some("recv") => recv.push((idx, v["v"].as_u64().unwrap(), v["t"].as_u64().unwrap())),
            Some("done") if !done => {
                done = true;
                done_at = Some(Instant::now());
            }
            Some("error") => panic!("helper {idx}: {v}"),
            _ => {}
        }
    }
    procs.kill_all();
    assert!(
        done,
        "the latency publisher did not finish; logs in {}",
        dir.display()
    );
    let mut lat: Vec<f64> = recv
        .iter()
        .filter_map(|(_, v, t1)| sent.get(v).map(|t0| (*t1 as f64 - *t0 as f64) / 1e6))
        .collect();
    lat.sort_by(f64::total_cmp);
    lat
}
