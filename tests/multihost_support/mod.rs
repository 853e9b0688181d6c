//! Emulated hosts for `tests/multihost.rs`, `tests/partitions.rs` and `benches/multihost.rs`:
//! network namespaces joined by veth pairs (made here, removed on drop; a link can be taken down
//! or given a `tc` queueing discipline), a test CA from `deploy/make-test-ca.sh`,
//! the `deploy/` configs adapted to the namespaces, processes started inside a namespace, and
//! helper processes (observer, rogue publisher, latency probes) that re-run the calling test or
//! bench binary inside a namespace ([`helper_main`]).
#![allow(dead_code)]

pub mod budget;
pub mod cgroup;

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use proto::{keys, Metrics, Role, RunId, SenderId};
use transport::{Transport, TransportConfig, ZenohConfig};

/// Set in a helper process's environment: which helper to run.
pub const HELPER_ENV: &str = "FSRL_MULTIHOST_HELPER";
/// A run config (TOML) whose `[run]` and `[transport.zenoh]` the helper uses.
pub const CONFIG_ENV: &str = "FSRL_MULTIHOST_CONFIG";
/// The observer's config for the weights, if not [`CONFIG_ENV`]'s: the monitor's credentials
/// may not read weights, the evaluator's may.
pub const WEIGHTS_CONFIG_ENV: &str = "FSRL_MULTIHOST_WEIGHTS_CONFIG";

/// The run id that `deploy/router.json5`'s access control names.
pub const DEPLOYED_RUN_ID: &str = "cluster";
/// Extra helper parameter (`latency-pub`: messages, period in ms as `N,MS`).
pub const ARG_ENV: &str = "FSRL_MULTIHOST_ARG";

/// The version the rogue publishers give their weights: no learner ever reaches it.
pub const ROGUE_VERSION: u64 = 1_000_000;

/// Why network namespaces cannot be made here, if they cannot.
pub fn netns_unavailable() -> Option<String> {
    // SAFETY: geteuid has no preconditions and cannot fail.
    if unsafe { libc::geteuid() } != 0 {
        return Some("not running as root (network namespaces need CAP_SYS_ADMIN)".into());
    }
    match Command::new("ip").args(["netns", "list"]).output() {
        Err(e) => return Some(format!("`ip` (iproute2) cannot be run: {e}")),
        Ok(o) if !o.status.success() => {
            return Some(format!(
                "`ip netns list` failed: {}",
                String::from_utf8_lossy(&o.stderr).trim()
            ))
        }
        Ok(_) => {}
    }
    let probe = format!("fmh{}-probe", std::process::id());
    let made = ip(&["netns", "add", &probe]);
    let _ = ip(&["netns", "del", &probe]);
    made.err()
        .map(|e| format!("cannot create a network namespace: {e}"))
}

/// Runs `program ARGS`, returning its error output on failure.
fn run(program: &str, args: &[&str]) -> Result<(), String> {
    let o = Command::new(program)
        .args(args)
        .output()
        .map_err(|e| format!("{program} {}: {e}", args.join(" ")))?;
    if o.status.success() {
        Ok(())
    } else {
        Err(format!(
            "{program} {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&o.stderr).trim()
        ))
    }
}

/// Runs `ip ARGS`, returning its error output on failure.
pub fn ip(args: &[&str]) -> Result<(), String> {
    run("ip", args)
}

/// The arguments that make a test binary re-run only its `helper_process_entry_point` test
/// (the helper processes a test starts inside namespaces, [`helper_main`]).
pub fn helper_args() -> Vec<String> {
    [
        "--exact",
        "helper_process_entry_point",
        "--nocapture",
        "--test-threads",
        "1",
    ]
    .map(String::from)
    .to_vec()
}

/// The last `lines` lines of every `.log` and `.err` file in `dir`, by name, for a failure
/// message.
pub fn log_tails(dir: &Path, lines: usize) -> String {
    let mut names: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    names.sort();
    let mut s = String::new();
    for p in names {
        if p.extension().is_some_and(|x| x == "log" || x == "err") {
            let text = std::fs::read_to_string(&p).unwrap_or_default();
            let tail: Vec<&str> = text.lines().rev().take(lines).collect();
            s += &format!("--- {} (last lines)\n", p.display());
            for l in tail.iter().rev() {
                s += l;
                s += "\n";
            }
        }
    }
    s
}

/// Removes namespaces left behind by runs that were killed before they could clean up
/// (`fmh<pid>-...` whose process is gone).
fn sweep_stale() {
    let Ok(o) = Command::new("ip").args(["netns", "list"]).output() else {
        return;
    };
    for line in String::from_utf8_lossy(&o.stdout).lines() {
        let Some(name) = line.split_whitespace().next() else {
            continue;
        };
        let Some(rest) = name.strip_prefix("fmh") else {
            continue;
        };
        let Some(pid) = rest.split('-').next().and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        if !Path::new(&format!("/proc/{pid}")).exists() {
            let _ = ip(&["netns", "del", name]);
        }
    }
}

/// Emulated hosts: `hub` (router, learner, evaluator) and two actor hosts, each joined to the
/// hub by its own veth pair: actor host k (0, 1) is `10.201.<k+1>.2/24` on its `eth0`, the hub
/// `10.201.<k+1>.1/24` on `to-a<k+1>`. [`Hosts::create_with_learner_host`] adds a fourth host for
/// the learner alone (`10.201.3.2/24` on its `eth0`, the hub `10.201.3.1/24` on `to-ln`), so the
/// learner's link can fail by itself. The namespaces (and with them the veths and any queueing
/// discipline on them) are removed on drop. Names are unique per process and tag.
pub struct Hosts {
    pub hub: String,
    pub actors: [String; 2],
    /// The learner's own host, if made ([`Hosts::create_with_learner_host`]).
    pub learner: Option<String>,
    /// Every host but the hub, with the hub's end of its link.
    spokes: Vec<(String, String)>,
    created: Vec<String>,
}

impl Hosts {
    pub fn create(tag: &str) -> Result<Self, String> {
        Self::make(tag, false)
    }

    /// [`Hosts::create`] plus the learner's own host.
    pub fn create_with_learner_host(tag: &str) -> Result<Self, String> {
        Self::make(tag, true)
    }

    fn make(tag: &str, learner_host: bool) -> Result<Self, String> {
        sweep_stale();
        let pid = std::process::id();
        let name = |role: &str| format!("fmh{pid}-{tag}-{role}");
        let mut h = Hosts {
            hub: name("hub"),
            actors: [name("a1"), name("a2")],
            learner: learner_host.then(|| name("ln")),
            spokes: Vec::new(),
            created: Vec::new(),
        };
        let hub = h.hub.clone();
        h.add_namespace(&hub)?;
        for k in 0..2 {
            let a = h.actors[k].clone();
            h.add_spoke(&a, &format!("to-a{}", k + 1), k as u8 + 1)?;
        }
        if let Some(l) = h.learner.clone() {
            h.add_spoke(&l, "to-ln", 3)?;
        }
        Ok(h)
    }

    fn add_namespace(&mut self, ns: &str) -> Result<(), String> {
        ip(&["netns", "add", ns])?;
        self.created.push(ns.to_string());
        ip(&["-n", ns, "link", "set", "lo", "up"])
    }

    /// Namespace `ns` joined to the hub: `10.201.<subnet>.2/24` on its `eth0`, the hub
    /// `10.201.<subnet>.1/24` on `hub_if`.
    fn add_spoke(&mut self, ns: &str, hub_if: &str, subnet: u8) -> Result<(), String> {
        self.add_namespace(ns)?;
        let hub = self.hub.clone();
        ip(&[
            "link", "add", "eth0", "netns", ns, "type", "veth", "peer", "name", hub_if, "netns",
            &hub,
        ])?;
        self.spokes.push((ns.to_string(), hub_if.to_string()));
        ip(&[
            "-n",
            &hub,
            "addr",
            "add",
            &format!("10.201.{subnet}.1/24"),
            "dev",
            hub_if,
        ])?;
        ip(&[
            "-n",
            ns,
            "addr",
            "add",
            &format!("10.201.{subnet}.2/24"),
            "dev",
            "eth0",
        ])?;
        ip(&["-n", &hub, "link", "set", hub_if, "up"])?;
        ip(&["-n", ns, "link", "set", "eth0", "up"])
    }

    /// The hub's address as seen from actor host `k`.
    pub fn hub_addr(k: usize) -> String {
        format!("10.201.{}.1", k + 1)
    }

    /// The hub's address as seen from the learner's host.
    pub fn learner_hub_addr() -> String {
        "10.201.3.1".into()
    }

    /// Takes actor host `k`'s only link down or up.
    pub fn set_actor_link(&self, k: usize, up: bool) -> Result<(), String> {
        self.set_link(&self.actors[k], up)
    }

    /// Takes the only link of host `ns` (an actor's or the learner's host) down or up.
    pub fn set_link(&self, ns: &str, up: bool) -> Result<(), String> {
        self.hub_end(ns)?;
        ip(&[
            "-n",
            ns,
            "link",
            "set",
            "eth0",
            if up { "up" } else { "down" },
        ])
    }

    /// Puts the queueing discipline `qdisc` (`tc` words, e.g. `netem loss 10% delay 50ms`) at
    /// the root of both ends of host `ns`'s link, so traffic in both directions goes through it;
    /// `None` removes it from both ends.
    pub fn set_link_qdisc(&self, ns: &str, qdisc: Option<&[&str]>) -> Result<(), String> {
        let hub_if = self.hub_end(ns)?;
        for (n, dev) in [(ns, "eth0"), (self.hub.as_str(), hub_if)] {
            let mut args = vec!["-n", n, "qdisc"];
            match qdisc {
                Some(q) => {
                    args.extend(["replace", "dev", dev, "root"]);
                    args.extend(q);
                }
                None => args.extend(["del", "dev", dev, "root"]),
            }
            tc(&args)?;
        }
        Ok(())
    }

    /// The hub's end of host `ns`'s link.
    fn hub_end(&self, ns: &str) -> Result<&str, String> {
        self.spokes
            .iter()
            .find(|(n, _)| n == ns)
            .map(|(_, h)| h.as_str())
            .ok_or_else(|| format!("{ns} is not a host joined to the hub"))
    }
}

/// Runs `tc ARGS`, returning its error output on failure.
pub fn tc(args: &[&str]) -> Result<(), String> {
    run("tc", args)
}

impl Drop for Hosts {
    fn drop(&mut self) {
        for ns in self.created.drain(..) {
            if let Err(e) = ip(&["netns", "del", &ns]) {
                eprintln!("warning: {e}");
            }
        }
    }
}

/// Makes the test CA, certificates, passwords and router dictionary in `dir`
/// (`deploy/make-test-ca.sh`), the router's certificate naming `router_ips`.
pub fn make_secrets(dir: &Path, router_ips: &[String]) -> Result<(), String> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/make-test-ca.sh");
    let mut c = Command::new("bash");
    c.arg(&script).arg(dir);
    for ip in router_ips {
        c.args(["--router-ip", ip]);
    }
    let o = c
        .output()
        .map_err(|e| format!("{}: {e}", script.display()))?;
    if o.status.success() {
        Ok(())
    } else {
        Err(format!(
            "{} failed: {}{}",
            script.display(),
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        ))
    }
}

/// `fsrl router` arguments: `deploy/router.json5` (whose access control names the run
/// [`DEPLOYED_RUN_ID`]) with its certificate and dictionary paths pointed at `secrets` (made by
/// [`make_secrets`]), plus `extra` `--cfg KEY:VALUE` settings.
pub fn router_args(secrets: &Path, extra: &[String]) -> Vec<String> {
    let router = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/router.json5");
    router_args_with(&router, secrets, extra)
}

/// [`router_args`] for the run `run_id`: `deploy/router.json5` with the run id in its access
/// control changed as `deploy/README.md` says (`fsrl/cluster/` → `fsrl/<run_id>/`), written to
/// `secrets/router-<run_id>.json5`.
pub fn router_args_for_run(secrets: &Path, run_id: &str, extra: &[String]) -> Vec<String> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/router.json5");
    let text = std::fs::read_to_string(&src).unwrap_or_else(|e| panic!("{}: {e}", src.display()));
    let from = format!("fsrl/{DEPLOYED_RUN_ID}/");
    assert!(
        text.contains(&from),
        "{} names no {from} keys",
        src.display()
    );
    let router = secrets.join(format!("router-{run_id}.json5"));
    std::fs::write(&router, text.replace(&from, &format!("fsrl/{run_id}/"))).unwrap();
    router_args_with(&router, secrets, extra)
}

fn router_args_with(router: &Path, secrets: &Path, extra: &[String]) -> Vec<String> {
    let d = secrets.to_string_lossy();
    let mut args = vec![
        "router".to_string(),
        "--config".into(),
        router.to_string_lossy().into_owned(),
    ];
    let files = [
        format!("transport/link/tls/root_ca_certificate:\"{d}/certs/ca.crt\""),
        format!("transport/link/tls/listen_certificate:\"{d}/certs/router.crt\""),
        format!("transport/link/tls/listen_private_key:\"{d}/certs/router.key\""),
        format!("transport/auth/usrpwd/dictionary_file:\"{d}/router-users.txt\""),
    ];
    for c in files.iter().chain(extra) {
        args.push("--cfg".into());
        args.push(c.clone());
    }
    args
}

/// `deploy/<name>` parsed, changed by `edit`, written to `dir/<out>`: the deployed file as an
/// operator would adapt it (its relative certificate and password paths then resolve in `dir`).
pub fn adapt_deploy_config(
    name: &str,
    dir: &Path,
    out: &str,
    edit: impl FnOnce(&mut toml::Table),
) -> PathBuf {
    adapt(name, |text| text, dir, out, edit)
}

/// `deploy/<name>`, its text changed by `rewrite`, parsed, changed by `edit`, written to
/// `dir/<out>`.
fn adapt(
    name: &str,
    rewrite: impl FnOnce(String) -> String,
    dir: &Path,
    out: &str,
    edit: impl FnOnce(&mut toml::Table),
) -> PathBuf {
    let src = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("deploy")
        .join(name);
    let text = std::fs::read_to_string(&src).unwrap_or_else(|e| panic!("{}: {e}", src.display()));
    let mut t: toml::Table = rewrite(text)
        .parse()
        .unwrap_or_else(|e| panic!("{} (adapted): {e}", src.display()));
    edit(&mut t);
    let path = dir.join(out);
    std::fs::write(&path, toml::to_string(&t).expect("a TOML table serialises")).unwrap();
    path
}

/// `deploy/cluster-actor.toml` (actor 0's) made actor `id`'s as `deploy/README.md` does it
/// (`sed s/actor-0/actor-<id>/g`: user `actor-<id>`, password file `actor-<id>.password`), then
/// changed by `edit` and written to `dir/<out>`.
pub fn adapt_actor_config(
    id: u32,
    dir: &Path,
    out: &str,
    edit: impl FnOnce(&mut toml::Table),
) -> PathBuf {
    adapt(
        "cluster-actor.toml",
        |text| text.replace("actor-0", &format!("actor-{id}")),
        dir,
        out,
        edit,
    )
}

/// `t[a][b]...` as a table, created if missing.
pub fn table<'a>(t: &'a mut toml::Table, path: &[&str]) -> &'a mut toml::Table {
    let mut cur = t;
    for p in path {
        cur = cur
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()
            .expect("a table");
    }
    cur
}

/// Child processes, killed (and reaped) on drop.
#[derive(Default)]
pub struct Procs {
    list: Vec<(String, Child)>,
}

impl Procs {
    /// Starts `program ARGS` inside namespace `ns` (`ip netns exec`, which execs: the child's
    /// pid is the program's), stdout and stderr to `log`.
    pub fn spawn(
        &mut self,
        name: &str,
        ns: &str,
        program: &Path,
        args: &[String],
        envs: &[(&str, String)],
        log: &Path,
    ) {
        let f = std::fs::File::create(log).unwrap();
        let child = Command::new("ip")
            .args(["netns", "exec", ns])
            .arg(program)
            .args(args)
            .envs(envs.iter().map(|(k, v)| (*k, v.as_str())))
            .stdin(Stdio::null())
            .stdout(f.try_clone().unwrap())
            .stderr(f)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        self.list.push((name.to_string(), child));
    }

    /// Adds an already started child.
    pub fn adopt(&mut self, name: &str, child: Child) {
        self.list.push((name.to_string(), child));
    }

    /// Whether `name` still runs (None if no such process).
    pub fn running(&mut self, name: &str) -> Option<bool> {
        let (_, c) = self.list.iter_mut().find(|(n, _)| n == name)?;
        Some(matches!(c.try_wait(), Ok(None)))
    }

    /// The process id of `name` (the program's own: `ip netns exec` execs it).
    pub fn pid(&self, name: &str) -> Option<u32> {
        self.list
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, c)| c.id())
    }

    /// Sends `signal` to `name` (only to that process, by its id) if it is still running.
    pub fn signal(&mut self, name: &str, signal: i32) -> Result<(), String> {
        if self.running(name) != Some(true) {
            return Err(format!("{name} is not running"));
        }
        let pid = self.pid(name).expect("running") as libc::pid_t;
        // SAFETY: kill(2) on our own, not yet reaped child: the pid cannot have been reused.
        if unsafe { libc::kill(pid, signal) } == 0 {
            Ok(())
        } else {
            Err(format!(
                "signal {signal} to {name}: {}",
                std::io::Error::last_os_error()
            ))
        }
    }

    /// Kills `name` (SIGKILL, by its id), reaps it and forgets it, so that a process of the same
    /// name can be started again.
    pub fn kill(&mut self, name: &str) {
        if let Some(i) = self.list.iter().position(|(n, _)| n == name) {
            let (_, mut c) = self.list.remove(i);
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// The processes that have exited, with their status.
    pub fn exited(&mut self) -> Vec<(String, std::process::ExitStatus)> {
        self.list
            .iter_mut()
            .filter_map(|(n, c)| c.try_wait().ok().flatten().map(|s| (n.clone(), s)))
            .collect()
    }

    /// Kills and reaps every process.
    pub fn kill_all(&mut self) {
        for (_, c) in &mut self.list {
            let _ = c.kill();
        }
        for (_, c) in &mut self.list {
            let _ = c.wait();
        }
        self.list.clear();
    }
}

impl Drop for Procs {
    fn drop(&mut self) {
        self.kill_all();
    }
}

/// A real `fsrl router` on loopback (`tls/127.0.0.1`, no namespaces) with the deployed access
/// control for run `run` and the test CA made in `dir`, for the tests that attack it with an
/// actor's real credentials. Every process logs to `dir/<name>.log` and is killed on drop.
pub struct LoopbackRouter {
    pub dir: PathBuf,
    pub run: String,
    pub port: u16,
    /// `tls/127.0.0.1:<port>`.
    pub endpoint: String,
    pub procs: Procs,
    fsrl: PathBuf,
}

impl LoopbackRouter {
    /// Makes the test CA in `dir` and starts the router (`fsrl` is the binary).
    pub fn start(dir: &Path, run: &str, fsrl: &Path) -> Self {
        make_secrets(dir, &[]).unwrap();
        let port = testkit::free_port();
        let endpoint = format!("tls/127.0.0.1:{port}");
        let mut r = Self {
            dir: dir.to_path_buf(),
            run: run.to_string(),
            port,
            endpoint: endpoint.clone(),
            procs: Procs::default(),
            fsrl: fsrl.to_path_buf(),
        };
        let listen = format!("listen/endpoints:[\"{endpoint}\"]");
        r.spawn("router", &router_args_for_run(dir, run, &[listen]));
        r
    }

    /// Starts `fsrl ARGS` as `name` (`RUST_LOG=info,zenoh=warn`).
    pub fn spawn(&mut self, name: &str, args: &[String]) {
        let log = std::fs::File::create(self.dir.join(format!("{name}.log"))).unwrap();
        let child = Command::new(&self.fsrl)
            .args(args)
            .env("RUST_LOG", "info,zenoh=warn")
            .stdin(Stdio::null())
            .stdout(log.try_clone().unwrap())
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        self.procs.adopt(name, child);
    }

    /// Points a deployed config at this run (SARL) and this router.
    pub fn configure(&self, t: &mut toml::Table) {
        let r = table(t, &["run"]);
        r.insert("id".into(), self.run.clone().into());
        r.insert("method".into(), "sarl".into());
        let z = table(t, &["transport", "zenoh"]);
        z.insert(
            "connect".into(),
            toml::Value::Array(vec![self.endpoint.clone().into()]),
        );
    }
}

/// Everything the observer helper reported so far.
#[derive(Debug, Default)]
pub struct Seen {
    /// Latest metric values per sender (`learner-0`, `actor-1`, ...), plus `episodes` and
    /// `wall_time_s` from the message itself.
    pub metrics: BTreeMap<String, BTreeMap<String, f64>>,
    /// Largest `weights_version` metric each sender ever reported.
    pub max_weights_metric: BTreeMap<String, f64>,
    /// Every weights version the observer received, in order.
    pub weights: Vec<u64>,
    /// Liveliness events: (`joined` | `left`, member).
    pub membership: Vec<(String, String)>,
    pub eval_reports: u64,
    /// Metrics messages carrying the rogue helper's marker.
    pub rogue_markers: u64,
    pub ready: bool,
}

impl Seen {
    pub fn value(&self, sender: &str, key: &str) -> Option<f64> {
        self.metrics.get(sender)?.get(key).copied()
    }

    /// Members (`actor-0#...`) with the given event.
    pub fn members(&self, event: &str, prefix: &str) -> Vec<String> {
        self.membership
            .iter()
            .filter(|(e, m)| e == event && m.starts_with(prefix))
            .map(|(_, m)| m.clone())
            .collect()
    }
}

/// The observer helper's reports, gathered by a reader thread from its stdout.
pub struct Observer {
    state: Arc<(Mutex<Seen>, Condvar)>,
}

impl Observer {
    /// Starts the observer helper (this test/bench binary, `helper_args`) in `ns` with the
    /// run config `config`; its raw output is copied to `log`.
    pub fn start(
        procs: &mut Procs,
        ns: &str,
        helper_args: &[String],
        config: &Path,
        log: &Path,
    ) -> Self {
        Self::start_with(procs, ns, helper_args, config, None, log)
    }

    /// [`Observer::start`], reading the weights with `weights_config`'s credentials.
    pub fn start_with(
        procs: &mut Procs,
        ns: &str,
        helper_args: &[String],
        config: &Path,
        weights_config: Option<&Path>,
        log: &Path,
    ) -> Self {
        let mut cmd = Command::new("ip");
        cmd.args(["netns", "exec", ns])
            .arg(std::env::current_exe().unwrap())
            .args(helper_args)
            .env(HELPER_ENV, "observer")
            .env(CONFIG_ENV, config);
        if let Some(w) = weights_config {
            cmd.env(WEIGHTS_CONFIG_ENV, w);
        }
        let child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(log.with_extension("err")).unwrap())
            .spawn()
            .expect("cannot start the observer helper");
        let mut child = child;
        let stdout = child.stdout.take().expect("piped");
        procs.adopt("observer", child);
        let state = Arc::new((Mutex::new(Seen::default()), Condvar::new()));
        let st = Arc::clone(&state);
        let mut raw = std::fs::File::create(log).unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                let _ = writeln!(raw, "{line}");
                let Ok(v) = serde_json::from_str::<serde_json::Value>(&line) else {
                    continue;
                };
                let (m, cv) = &*st;
                let mut s = m.lock().unwrap_or_else(|p| p.into_inner());
                absorb(&mut s, &v);
                cv.notify_all();
            }
        });
        Self { state }
    }

    /// Reads the state.
    pub fn with<R>(&self, f: impl FnOnce(&Seen) -> R) -> R {
        f(&self.state.0.lock().unwrap_or_else(|p| p.into_inner()))
    }

    /// Waits until `pred` holds on what the observer saw, up to `timeout`.
    pub fn wait_until(
        &self,
        timeout: Duration,
        mut pred: impl FnMut(&Seen) -> bool,
    ) -> Result<Duration, ()> {
        let start = Instant::now();
        let (m, cv) = &*self.state;
        let mut s = m.lock().unwrap_or_else(|p| p.into_inner());
        loop {
            if pred(&s) {
                return Ok(start.elapsed());
            }
            let left = timeout.saturating_sub(start.elapsed());
            if left.is_zero() {
                return Err(());
            }
            s = cv
                .wait_timeout(s, left)
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
    }
}

fn absorb(s: &mut Seen, v: &serde_json::Value) {
    let str_of = |k: &str| v[k].as_str().unwrap_or("").to_string();
    match v["k"].as_str() {
        Some("ready") => s.ready = true,
        Some("metrics") => {
            let sender = str_of("sender");
            let mut vals: BTreeMap<String, f64> = v["values"]
                .as_object()
                .map(|o| {
                    o.iter()
                        .filter_map(|(k, x)| x.as_f64().map(|x| (k.clone(), x)))
                        .collect()
                })
                .unwrap_or_default();
            if vals.contains_key("rogue_marker") {
                s.rogue_markers += 1;
                return;
            }
            if let Some(w) = vals.get("weights_version") {
                let e = s.max_weights_metric.entry(sender.clone()).or_insert(0.0);
                *e = e.max(*w);
            }
            vals.insert("msg_episodes".into(), v["episodes"].as_f64().unwrap_or(0.0));
            vals.insert(
                "msg_wall_time_s".into(),
                v["wall_time_s"].as_f64().unwrap_or(0.0),
            );
            vals.insert(
                "msg_env_steps".into(),
                v["env_steps"].as_f64().unwrap_or(0.0),
            );
            s.metrics.insert(sender, vals);
        }
        Some("weights") => s.weights.push(v["version"].as_u64().unwrap_or(0)),
        Some(e @ ("joined" | "left")) => s.membership.push((e.to_string(), str_of("member"))),
        Some("eval") => s.eval_reports += 1,
        _ => {}
    }
}

/// Runs a helper (`observer`, `rogue`, `latency-pub`, `latency-sub`) in this process, as told
/// by the environment, printing JSON lines on stdout. Returns false when this process is not
/// a helper.
pub fn helper_main() -> bool {
    let Ok(mode) = std::env::var(HELPER_ENV) else {
        return false;
    };
    if let Err(e) = run_helper(&mode) {
        emit(serde_json::json!({"k": "error", "e": e}));
        eprintln!("helper {mode}: {e}");
        std::process::exit(1);
    }
    true
}

fn emit(v: serde_json::Value) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{v}");
    let _ = out.flush();
}

/// `[run]` and `[transport.zenoh]` of a run config, as the fsrl binary reads them.
fn helper_transport(role: Role, index: u32) -> Result<(TransportConfig, String), String> {
    helper_transport_from(CONFIG_ENV, role, index)
}

/// [`helper_transport`] from the config named by the environment variable `env`.
fn helper_transport_from(
    env: &str,
    role: Role,
    index: u32,
) -> Result<(TransportConfig, String), String> {
    let path = PathBuf::from(std::env::var(env).map_err(|_| format!("no config given ({env})"))?);
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let t: toml::Table = text
        .parse()
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let run = t
        .get("run")
        .and_then(|r| r.get("id"))
        .and_then(|v| v.as_str())
        .ok_or("no run.id")?
        .to_string();
    let method = t
        .get("run")
        .and_then(|r| r.get("method"))
        .and_then(|v| v.as_str())
        .unwrap_or("fsrl")
        .to_string();
    let z = t
        .get("transport")
        .and_then(|x| x.get("zenoh"))
        .cloned()
        .ok_or("no [transport.zenoh]")?;
    let mut zenoh: ZenohConfig = z.try_into().map_err(|e: toml::de::Error| e.to_string())?;
    zenoh.resolve_paths(path.parent().unwrap_or(Path::new("/")));
    let mut cfg = TransportConfig::new(
        RunId::new(run).map_err(|e| e.to_string())?,
        SenderId::new(role, index),
    );
    cfg.zenoh = zenoh;
    Ok((cfg, method))
}

/// CLOCK_MONOTONIC in ns: the same clock in every network namespace of the machine.
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

fn rogue_weights(method: &str, version: u64) -> Result<proto::Weights, String> {
    let m: policy::method::Method = method.parse().map_err(|e| format!("{e}"))?;
    let net_cfg = m.net().ok_or("method without a network")?;
    let net = policy::ValueNet::new(net_cfg, 7).map_err(|e| e.to_string())?;
    policy::wire::weights_message(&net, version).map_err(|e| e.to_string())
}

fn run_helper(mode: &str) -> Result<(), String> {
    match mode {
        "observer" => observer(),
        "rogue" => rogue(),
        "latency-pub" => latency_pub(),
        "latency-sub" => latency_sub(),
        m => Err(format!("unknown helper {m}")),
    }
}

/// Subscribes (monitor role) to metrics, evaluation reports and liveliness of the run, and to
/// its weights (with [`WEIGHTS_CONFIG_ENV`]'s credentials if given), and prints every one.
fn observer() -> Result<(), String> {
    let (cfg, _) = helper_transport(Role::Monitor, 900)?;
    let t = open_retrying(cfg, Duration::from_secs(60))?;
    let run = t.run().clone();
    let e = |e: transport::TransportError| e.to_string();
    let metrics = t.subscriber(&keys::all_metrics(&run)).map_err(e)?;
    let reports = t.subscriber(&keys::all_eval_reports(&run)).map_err(e)?;
    let reader = if std::env::var_os(WEIGHTS_CONFIG_ENV).is_some() {
        let (cfg, _) = helper_transport_from(WEIGHTS_CONFIG_ENV, Role::Evaluator, 900)?;
        open_retrying(cfg, Duration::from_secs(60))?
    } else {
        t.clone()
    };
    let weights = reader.latest_subscriber(&keys::weights(&run)).map_err(e)?;
    let alive = t.watch_alive().map_err(e)?;
    std::thread::spawn(move || loop {
        match weights.next(Duration::from_secs(1)) {
            Ok(Some(w)) => emit(serde_json::json!({
                "k": "weights", "version": w.body.version, "sender": w.header.sender.to_string()
            })),
            Ok(None) => {}
            Err(_) => return,
        }
    });
    std::thread::spawn(move || loop {
        match alive.recv_timeout(Duration::from_secs(1)) {
            Ok(Some(transport::AliveEvent::Joined(m))) => {
                emit(serde_json::json!({"k": "joined", "member": m.to_string()}))
            }
            Ok(Some(transport::AliveEvent::Left(m))) => {
                emit(serde_json::json!({"k": "left", "member": m.to_string()}))
            }
            Ok(None) => {}
            Err(_) => return,
        }
    });
    std::thread::spawn(move || loop {
        match reports.recv_timeout(Duration::from_secs(1)) {
            Ok(Some(r)) => {
                emit(serde_json::json!({"k": "eval", "sender": r.header.sender.to_string()}))
            }
            Ok(None) => {}
            Err(_) => return,
        }
    });
    emit(serde_json::json!({"k": "ready"}));
    loop {
        if let Some(m) = metrics.recv_timeout(Duration::from_secs(1)).map_err(e)? {
            emit(serde_json::json!({
                "k": "metrics",
                "sender": m.header.sender.to_string(),
                "episodes": m.body.episodes,
                "wall_time_s": m.body.wall_time_s,
                "env_steps": m.body.env_steps,
                "values": m.body.values,
            }));
        }
    }
}

fn open_retrying(cfg: TransportConfig, patience: Duration) -> Result<Transport, String> {
    let start = Instant::now();
    loop {
        match Transport::open(cfg.clone()) {
            Ok(t) => return Ok(t),
            Err(e) if start.elapsed() >= patience => return Err(e.to_string()),
            Err(_) => std::thread::sleep(Duration::from_millis(200)),
        }
    }
}

/// The metrics key a user may publish: `actor-<id>`'s, else the learner's.
fn own_metrics_sender(cfg: &TransportConfig) -> SenderId {
    let user = cfg.zenoh.auth.as_ref().map(|a| a.user.as_str());
    match user.and_then(|u| u.strip_prefix("actor-")?.parse().ok()) {
        Some(id) => SenderId::new(Role::Actor, id),
        None => SenderId::new(Role::Learner, 0),
    }
}

/// Tries to publish weights of version [`ROGUE_VERSION`] (the real wire format, a valid network
/// of the run's method, the learner's sender id in the header), as the latest value (publisher
/// plus queryable, like the learner). Also publishes a marked metrics message on the metrics
/// key its credentials may publish (`actor-<id>`'s), from a second session of the same user
/// with that sender (receivers refuse a sender other than the key's): seeing it proves the
/// credentials were accepted. Publishes `ARG_ENV` rounds (default 30), one every 100 ms: the
/// learner's weights overwrite the rogue's in latest-value subscribers, so a control that must
/// be seen publishes for longer.
fn rogue() -> Result<(), String> {
    let (cfg, method) = helper_transport(Role::Learner, 0)?;
    let rounds: u32 = match std::env::var(ARG_ENV) {
        Ok(a) => a
            .parse()
            .map_err(|_| format!("ARG must be a count of rounds, not {a:?}"))?,
        Err(_) => 30,
    };
    let mut marker_cfg = cfg.clone();
    marker_cfg.sender = own_metrics_sender(&cfg);
    let mut last = String::new();
    let mut t = None;
    for _ in 0..3 {
        match Transport::open(cfg.clone()) {
            Ok(x) => {
                t = Some(x);
                break;
            }
            Err(e) => last = e.to_string(),
        }
    }
    let Some(t) = t else {
        emit(serde_json::json!({"k": "open_failed", "e": last}));
        return Ok(());
    };
    emit(serde_json::json!({"k": "opened"}));
    let run = t.run().clone();
    let e = |e: transport::TransportError| e.to_string();
    let w = rogue_weights(&method, ROGUE_VERSION)?;
    let weights = t.latest_publisher(&keys::weights(&run)).map_err(e)?;
    let marker_t = open_retrying(marker_cfg, Duration::from_secs(10))?;
    let marker = marker_t
        .publisher(&keys::metrics(&run, marker_t.sender()))
        .map_err(e)?;
    let mut m = Metrics::default();
    m.values.insert("rogue_marker".into(), 1.0);
    for _ in 0..rounds {
        weights.publish(ROGUE_VERSION, &w).map_err(e)?;
        marker.publish(0, &m).map_err(e)?;
        std::thread::sleep(Duration::from_millis(100));
    }
    emit(serde_json::json!({"k": "done"}));
    Ok(())
}

/// Publishes `N` weight messages (versions 1..=N) every `MS` ms (`ARG_ENV` = `N,MS`), printing
/// each one's monotonic send time.
fn latency_pub() -> Result<(), String> {
    let (cfg, method) = helper_transport(Role::Learner, 0)?;
    let arg = std::env::var(ARG_ENV).unwrap_or_else(|_| "300,20".into());
    let (n, ms) = arg
        .split_once(',')
        .and_then(|(a, b)| Some((a.parse::<u64>().ok()?, b.parse::<u64>().ok()?)))
        .ok_or("ARG must be N,MS")?;
    let t = open_retrying(cfg, Duration::from_secs(30))?;
    let run = t.run().clone();
    let e = |e: transport::TransportError| e.to_string();
    let mut w = rogue_weights(&method, 1)?;
    let publisher = t.latest_publisher(&keys::weights(&run)).map_err(e)?;
    emit(serde_json::json!({"k": "ready"}));
    // Give subscribers' declarations time to reach us (they are already running).
    publisher
        .wait_for_subscribers(Duration::from_secs(10))
        .map_err(e)?;
    std::thread::sleep(Duration::from_millis(500));
    for v in 1..=n {
        w.version = v;
        let t0 = monotonic_ns();
        publisher.publish(v, &w).map_err(e)?;
        emit(serde_json::json!({"k": "sent", "v": v, "t": t0}));
        std::thread::sleep(Duration::from_millis(ms));
    }
    emit(serde_json::json!({"k": "done"}));
    // Stay until killed: leaving early would only race with the last deliveries.
    loop {
        std::thread::sleep(Duration::from_secs(1));
    }
}

/// Receives weights and prints each one's version and monotonic receive time (after decoding
/// and validation, as an actor would use them).
fn latency_sub() -> Result<(), String> {
    let index = std::env::var(ARG_ENV)
        .ok()
        .and_then(|a| a.parse().ok())
        .unwrap_or(0);
    let (cfg, _) = helper_transport(Role::Actor, index)?;
    let t = open_retrying(cfg, Duration::from_secs(30))?;
    let run = t.run().clone();
    let e = |e: transport::TransportError| e.to_string();
    let weights = t.latest_subscriber(&keys::weights(&run)).map_err(e)?;
    emit(serde_json::json!({"k": "ready"}));
    loop {
        if let Some(w) = weights.next(Duration::from_secs(1)).map_err(e)? {
            let t1 = monotonic_ns();
            emit(serde_json::json!({"k": "recv", "v": w.body.version, "t": t1}));
        }
    }
}
