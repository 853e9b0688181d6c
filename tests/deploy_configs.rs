//! Every file in `deploy/` is parsed and validated, and broken ones are refused:
//! * the run configs by `fsrl check-config`, with the certificates and passwords that
//!   `deploy/make-test-ca.sh` makes, laid out as in `/etc/fsrl`;
//! * the router's JSON5 by zenoh itself (and opened as a router, which checks its access
//!   control), its rules against the keys `proto::keys` builds (who may publish what);
//! * the systemd units for the fields they need and the commands and files they name.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use proto::{keys, Member, Role, RunId, SenderId};
use zenoh::Wait;

fn deploy() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy")
}

fn fsrl(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .args(args)
        .output()
        .unwrap()
}

fn files_with(ext: &str, dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == ext))
        .collect();
    files.sort();
    files
}

/// A directory laid out like `/etc/fsrl`: the test CA's files and copies of the run configs.
fn etc_fsrl() -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    let o = Command::new("bash")
        .arg(deploy().join("make-test-ca.sh"))
        .arg(d.path())
        .args(["--router-ip", "10.0.0.1"])
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "make-test-ca.sh: {}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    for f in files_with("toml", &deploy()) {
        std::fs::copy(&f, d.path().join(f.file_name().unwrap())).unwrap();
    }
    d
}

#[test]
fn every_deploy_run_config_is_valid_beside_its_certificates_and_passwords() {
    let etc = etc_fsrl();
    let files = files_with("toml", etc.path());
    let names: Vec<String> = files
        .iter()
        .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    for want in [
        "cluster-actor.toml",
        "cluster-evaluator.toml",
        "cluster-learner.toml",
        "cluster-monitor.toml",
        "local.toml",
    ] {
        assert!(names.iter().any(|n| n == want), "{want} missing: {names:?}");
    }
    let mut args = vec!["check-config".to_string()];
    args.extend(files.iter().map(|f| f.to_string_lossy().into_owned()));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = fsrl(&args);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(
        out.lines().filter(|l| l.starts_with("ok: ")).count(),
        files.len(),
        "{out}"
    );
    // The cluster configs use TLS and credentials; the resolved form names the files.
    let o = fsrl(&[
        "check-config",
        "--print",
        &etc.path().join("cluster-actor.toml").to_string_lossy(),
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    let ca = etc.path().join("certs/ca.crt");
    assert!(out.contains(&*ca.to_string_lossy()), "{out}");
    assert!(out.contains("user = \"actor\""), "{out}");
    assert!(
        !out.contains("password ="),
        "the password must stay in its file: {out}"
    );
}

#[test]
fn a_cluster_config_without_its_files_is_refused_naming_every_missing_path() {
    let o = fsrl(&[
        "check-config",
        &deploy().join("cluster-actor.toml").to_string_lossy(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    for p in ["deploy/certs/ca.crt", "deploy/actor.password"] {
        assert!(err.contains(p), "{p} not named in: {err}");
    }
    // The process itself stops at once with the same message instead of retrying.
    let o = fsrl(&[
        "actor",
        "--config",
        &deploy().join("cluster-actor.toml").to_string_lossy(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("deploy/actor.password"), "{err}");

    // An empty password file, half a client certificate, a tls/ endpoint without a CA.
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("ca.crt"), "not checked here").unwrap();
    std::fs::write(d.path().join("empty.password"), "\n").unwrap();
    let p = d.path().join("bad.toml");
    std::fs::write(
        &p,
        "[transport.zenoh]\nmode = \"client\"\nconnect = [\"tls/10.0.0.1:7447\"]\n\
         [transport.zenoh.tls]\nroot_ca = \"ca.crt\"\ncert = \"me.crt\"\n\
         [transport.zenoh.auth]\nuser = \"actor\"\npassword_file = \"empty.password\"\n",
    )
    .unwrap();
    let o = fsrl(&["check-config", &p.to_string_lossy()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    for needle in [
        "empty.password is empty",
        "cert and zenoh.tls.key go together",
    ] {
        assert!(err.contains(needle), "missing {needle:?} in {err}");
    }
    std::fs::write(
        &p,
        "[transport.zenoh]\nmode = \"client\"\nconnect = [\"tls/10.0.0.1:7447\"]\n",
    )
    .unwrap();
    let o = fsrl(&["check-config", &p.to_string_lossy()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("needs [transport.zenoh.tls] root_ca"), "{err}");
}

#[test]
fn a_broken_config_is_refused_with_every_problem() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("bad.toml");
    std::fs::write(
        &p,
        "[run]\nid = \"a/b\"\nmethod = \"ppo\"\n[learner]\nin_flight_per_actor = 0\n",
    )
    .unwrap();
    let o = fsrl(&["check-config", &p.to_string_lossy()]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    for needle in ["run.id", "unknown method `ppo`", "in_flight_per_actor"] {
        assert!(err.contains(needle), "missing {needle} in {err}");
    }
    std::fs::write(&p, "[transport.zenoh]\nlisen = []\n").unwrap();
    let o = fsrl(&["check-config", &p.to_string_lossy()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown field `lisen`"));
    std::fs::write(
        &p,
        "[transport.zenoh.auth]\nuser = \"actor\"\npassword = \"x\"\n",
    )
    .unwrap();
    let o = fsrl(&["check-config", &p.to_string_lossy()]);
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("unknown field `password`"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn router_overrides(etc: &Path) -> Vec<(String, String)> {
    let q = |p: &str| format!("\"{}\"", etc.join(p).display());
    vec![
        (
            "transport/link/tls/root_ca_certificate".into(),
            q("certs/ca.crt"),
        ),
        (
            "transport/link/tls/listen_certificate".into(),
            q("certs/router.crt"),
        ),
        (
            "transport/link/tls/listen_private_key".into(),
            q("certs/router.key"),
        ),
        (
            "transport/auth/usrpwd/dictionary_file".into(),
            q("router-users.txt"),
        ),
    ]
}

fn json(c: &zenoh::Config, key: &str) -> serde_json::Value {
    serde_json::from_str(&c.get_json(key).unwrap()).unwrap()
}

#[test]
fn the_router_config_is_zenoh_json5_that_opens_a_tls_router() {
    let path = deploy().join("router.json5");
    let c = zenoh::Config::from_file(&path).expect("zenoh parses deploy/router.json5");
    assert_eq!(json(&c, "mode"), "router");
    let listen = json(&c, "listen/endpoints");
    let listen = listen.as_array().expect("one list of endpoints");
    assert!(
        !listen.is_empty()
            && listen
                .iter()
                .all(|e| e.as_str().unwrap().starts_with("tls/")),
        "{listen:?}"
    );
    assert_eq!(
        json(&c, "transport/link/protocols"),
        serde_json::json!(["tls"])
    );
    assert_eq!(json(&c, "scouting/multicast/enabled"), false);
    assert_eq!(json(&c, "access_control/enabled"), true);
    assert_eq!(json(&c, "access_control/default_permission"), "deny");
    assert!(json(&c, "transport/auth/usrpwd/dictionary_file").is_string());

    // In place the files under /etc/fsrl are missing: `fsrl router --check` names each.
    let o = fsrl(&["router", "--check", "--config", &path.to_string_lossy()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    for f in ["ca.crt", "router.crt", "router.key", "router-users.txt"] {
        assert!(err.contains("/etc/fsrl/") && err.contains(f), "{f}: {err}");
    }
    // With the test CA's files it checks, and zenoh opens it as a router (which validates the
    // access control rules too).
    let etc = etc_fsrl();
    let mut args = vec![
        "router".to_string(),
        "--check".into(),
        "--config".into(),
        path.to_string_lossy().into_owned(),
    ];
    for (k, v) in router_overrides(etc.path()) {
        args.push("--cfg".into());
        args.push(format!("{k}:{v}"));
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = fsrl(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).starts_with("ok: "));

    let mut c = c;
    for (k, v) in router_overrides(etc.path()) {
        c.insert_json5(&k, &v).unwrap();
    }
    c.insert_json5("listen/endpoints", "[\"tls/127.0.0.1:0\"]")
        .unwrap();
    let session = zenoh::open(c).wait().expect("the router opens");
    session.close().wait().unwrap();

    // A broken file is refused by name.
    let d = tempfile::tempdir().unwrap();
    let bad = d.path().join("bad.json5");
    std::fs::write(&bad, "{ mode: \"router\", listen: { endpoints: [ }").unwrap();
    let o = fsrl(&["router", "--check", "--config", &bad.to_string_lossy()]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("bad.json5"));
    std::fs::write(&bad, "{ mode: \"peer\" }").unwrap();
    let o = fsrl(&["router", "--check", "--config", &bad.to_string_lossy()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("mode must be \"router\""));
}

/// The router's access control for ingress (what a client may send), read from the file:
/// user name → message → key expressions allowed.
fn ingress_rights() -> BTreeMap<String, BTreeMap<String, Vec<String>>> {
    let c = zenoh::Config::from_file(deploy().join("router.json5")).unwrap();
    let acl = json(&c, "access_control");
    let strings = |v: &serde_json::Value| -> Vec<String> {
        v.as_array()
            .map(|a| a.iter().map(|x| x.as_str().unwrap().to_string()).collect())
            .unwrap_or_default()
    };
    let rules: BTreeMap<String, &serde_json::Value> = acl["rules"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| (r["id"].as_str().unwrap().to_string(), r))
        .collect();
    for r in rules.values() {
        // Only allow rules: then "allowed" is simply "some rule allows".
        assert_eq!(r["permission"], "allow", "{r}");
    }
    let subjects: BTreeMap<String, Vec<String>> = acl["subjects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| {
            (
                s["id"].as_str().unwrap().to_string(),
                strings(&s["usernames"]),
            )
        })
        .collect();
    let mut rights: BTreeMap<String, BTreeMap<String, Vec<String>>> = BTreeMap::new();
    for p in acl["policies"].as_array().unwrap() {
        for s in strings(&p["subjects"]) {
            let users = subjects.get(&s).unwrap_or_else(|| panic!("subject {s}"));
            assert!(!users.is_empty(), "subject {s} must name users");
            for r in strings(&p["rules"]) {
                let rule = rules.get(&r).unwrap_or_else(|| panic!("rule {r}"));
                let flows = strings(&rule["flows"]);
                if !flows.is_empty() && !flows.iter().any(|f| f == "ingress") {
                    continue;
                }
                for u in users {
                    for m in strings(&rule["messages"]) {
                        rights
                            .entry(u.clone())
                            .or_default()
                            .entry(m)
                            .or_default()
                            .extend(strings(&rule["key_exprs"]));
                    }
                }
            }
        }
    }
    rights
}

#[test]
fn the_access_control_lets_each_role_send_only_its_own_topics() {
    let rights = ingress_rights();
    let users: Vec<&String> = rights.keys().collect();
    assert_eq!(users, ["actor", "evaluator", "learner", "monitor"]);
    let allowed = |user: &str, message: &str, key: &str| -> bool {
        let key = zenoh::key_expr::KeyExpr::try_from(key.to_string()).unwrap();
        rights[user].get(message).is_some_and(|kes| {
            kes.iter().any(|ke| {
                zenoh::key_expr::KeyExpr::try_from(ke.clone())
                    .unwrap_or_else(|e| panic!("{ke}: {e}"))
                    .includes(&key)
            })
        })
    };
    let run = RunId::new("cluster").unwrap();
    let member = |role, index| Member {
        sender: SenderId::new(role, index),
        instance: 0x0123_4567_89ab_cdef,
    };
    let weights = keys::weights(&run).key_expr().to_string();
    let control = keys::control(&run).key_expr().to_string();
    let ack = keys::ack(&run, 3).key_expr().to_string();
    let transitions = keys::transitions(&run, 3).key_expr().to_string();
    let report = keys::eval_report(&run, 0).key_expr().to_string();
    let metrics = |r, i| {
        keys::metrics(&run, SenderId::new(r, i))
            .key_expr()
            .to_string()
    };
    let status = |r, i| {
        keys::status(&run, SenderId::new(r, i))
            .key_expr()
            .to_string()
    };

    // (user, message, key, allowed?)
    let table: Vec<(&str, &str, String, bool)> = vec![
        ("learner", "put", weights.clone(), true),
        ("learner", "put", control.clone(), true),
        ("learner", "put", ack.clone(), true),
        ("learner", "put", metrics(Role::Learner, 0), true),
        ("learner", "put", status(Role::Learner, 0), true),
        ("learner", "declare_queryable", weights.clone(), true),
        ("learner", "reply", weights.clone(), true),
        ("learner", "reply", control.clone(), true),
        (
            "learner",
            "liveliness_token",
            keys::alive(&run, member(Role::Learner, 0)),
            true,
        ),
        ("learner", "put", transitions.clone(), false),
        ("learner", "put", report.clone(), false),
        ("actor", "put", transitions.clone(), true),
        ("actor", "put", metrics(Role::Actor, 3), true),
        ("actor", "put", status(Role::Actor, 3), true),
        (
            "actor",
            "liveliness_token",
            keys::alive(&run, member(Role::Actor, 3)),
            true,
        ),
        ("actor", "put", weights.clone(), false),
        ("actor", "put", control.clone(), false),
        ("actor", "put", ack.clone(), false),
        ("actor", "put", report.clone(), false),
        ("actor", "put", metrics(Role::Learner, 0), false),
        ("actor", "declare_queryable", weights.clone(), false),
        ("actor", "reply", weights.clone(), false),
        ("actor", "reply", control.clone(), false),
        ("actor", "delete", weights.clone(), false),
        (
            "actor",
            "liveliness_token",
            keys::alive(&run, member(Role::Learner, 0)),
            false,
        ),
        ("evaluator", "put", report.clone(), true),
        ("evaluator", "put", metrics(Role::Evaluator, 0), true),
        (
            "evaluator",
            "liveliness_token",
            keys::alive(&run, member(Role::Evaluator, 0)),
            true,
        ),
        ("evaluator", "put", weights.clone(), false),
        ("evaluator", "put", transitions.clone(), false),
        ("evaluator", "reply", weights.clone(), false),
        ("monitor", "put", metrics(Role::Monitor, 0), false),
        ("monitor", "put", weights.clone(), false),
        ("monitor", "reply", weights.clone(), false),
        (
            "monitor",
            "liveliness_token",
            keys::alive(&run, member(Role::Monitor, 0)),
            false,
        ),
    ];
    // Everyone may subscribe, query the latest values and watch liveliness.
    let mut table = table;
    for u in ["learner", "actor", "evaluator", "monitor"] {
        table.push((
            u,
            "declare_subscriber",
            keys::all_metrics(&run).key_expr().to_string(),
            true,
        ));
        table.push((u, "declare_subscriber", weights.clone(), true));
        table.push((u, "query", weights.clone(), true));
        table.push((
            u,
            "declare_liveliness_subscriber",
            keys::all_alive(&run),
            true,
        ));
    }
    let wrong: Vec<String> = table
        .iter()
        .filter(|(u, m, k, want)| allowed(u, m, k) != *want)
        .map(|(u, m, k, want)| format!("{u} {m} {k}: expected allowed = {want}"))
        .collect();
    assert!(wrong.is_empty(), "{wrong:#?}");
}

/// `[section] key=value` lines of a unit file.
fn unit_fields(text: &str) -> BTreeMap<(String, String), Vec<String>> {
    let mut fields: BTreeMap<(String, String), Vec<String>> = BTreeMap::new();
    let mut section = String::new();
    for line in text.lines().map(str::trim) {
        if line.is_empty() || line.starts_with('#') || line.starts_with(';') {
            continue;
        }
        if let Some(s) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = s.to_string();
            continue;
        }
        let (k, v) = line
            .split_once('=')
            .unwrap_or_else(|| panic!("not key=value: {line}"));
        fields
            .entry((section.clone(), k.trim().to_string()))
            .or_default()
            .push(v.trim().to_string());
    }
    fields
}

#[test]
fn the_systemd_units_start_each_role_with_a_deployed_config() {
    let dir = deploy().join("systemd");
    let units = files_with("service", &dir);
    let names: Vec<String> = units
        .iter()
        .map(|u| u.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        names,
        [
            "fsrl-actor@.service",
            "fsrl-evaluator.service",
            "fsrl-learner.service",
            "fsrl-router.service"
        ]
    );
    let analyze = Command::new("systemd-analyze")
        .arg("--version")
        .output()
        .is_ok();
    let scratch = tempfile::tempdir().unwrap();
    for (unit, name) in units.iter().zip(&names) {
        let text = std::fs::read_to_string(unit).unwrap();
        let f = unit_fields(&text);
        let one = |s: &str, k: &str| -> String {
            let v = f
                .get(&(s.to_string(), k.to_string()))
                .unwrap_or_else(|| panic!("{name}: no {k}= in [{s}]"));
            assert_eq!(v.len(), 1, "{name}: {k}= given {} times", v.len());
            v[0].clone()
        };
        assert!(!one("Unit", "Description").is_empty());
        assert!(
            one("Unit", "After").contains("network-online.target"),
            "{name}"
        );
        assert_eq!(one("Service", "User"), "fsrl", "{name}");
        assert_eq!(one("Service", "Restart"), "on-failure", "{name}");
        assert_eq!(one("Install", "WantedBy"), "multi-user.target", "{name}");
        let exec = one("Service", "ExecStart");
        let argv: Vec<&str> = exec.split_whitespace().collect();
        assert_eq!(argv[0], "/usr/local/bin/fsrl", "{name}");
        let role = name
            .trim_start_matches("fsrl-")
            .trim_end_matches(".service")
            .trim_end_matches('@');
        assert_eq!(argv[1], role, "{name} must run `fsrl {role}`");
        let config = argv
            .iter()
            .position(|a| *a == "--config")
            .and_then(|i| argv.get(i + 1))
            .unwrap_or_else(|| panic!("{name}: no --config"));
        let file = config
            .strip_prefix("/etc/fsrl/")
            .unwrap_or_else(|| panic!("{name}: config {config} outside /etc/fsrl"));
        assert!(
            deploy().join(file).is_file(),
            "{name} names /etc/fsrl/{file}, which deploy/ does not provide"
        );
        if name.contains('@') {
            assert!(
                exec.contains("--id %i"),
                "{name}: the instance must be the actor id"
            );
        }
        if role != "router" {
            assert!(
                one("Service", "StateDirectory") == "fsrl",
                "{name}: run state lives in /var/lib/fsrl"
            );
        }
        // systemd's own parser, where it is installed: no unknown keys or sections.
        if analyze {
            let copy = scratch.path().join(name);
            std::fs::write(
                &copy,
                text.replace("/usr/local/bin/fsrl", env!("CARGO_BIN_EXE_fsrl")),
            )
            .unwrap();
            let target = if name.contains('@') {
                scratch.path().join(name.replace('@', "@0"))
            } else {
                copy.clone()
            };
            let o = Command::new("systemd-analyze")
                .arg("verify")
                .arg(&target)
                .output()
                .unwrap();
            let err = String::from_utf8_lossy(&o.stderr);
            let complaints: Vec<&str> = err
                .lines()
                .filter(|l| l.contains(&*scratch.path().to_string_lossy()))
                .collect();
            assert!(
                o.status.success() && complaints.is_empty(),
                "systemd-analyze verify {name}: {err}"
            );
        }
    }
    if !analyze {
        println!(
            "systemd-analyze not installed: the units were checked by this test's parser only"
        );
    }
}

/// The schedules and reward readings in `configs/` are valid run
/// configs, and `configs/spec-literal.toml` really is SPEC §3's literal reward.
#[test]
fn every_config_in_configs_is_valid() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = files_with("toml", &root.join("configs"));
    files.extend(files_with("toml", &root.join("configs/experiments")));
    assert!(files.len() >= 6, "{files:?}");
    for f in &files {
        let o = fsrl(&["check-config", f.to_str().unwrap()]);
        assert!(
            o.status.success(),
            "{}: {}",
            f.display(),
            String::from_utf8_lossy(&o.stderr)
        );
    }
    let o = fsrl(&[
        "check-config",
        root.join("configs/spec-literal.toml").to_str().unwrap(),
        "--print",
    ]);
    let printed = String::from_utf8_lossy(&o.stdout);
    for line in [
        "standing_alpha = 0.15",
        "dynamic_beta = 0.5",
        "dynamic_reading = \"after\"",
    ] {
        assert!(printed.contains(line), "{line} missing in:\n{printed}");
    }
}
