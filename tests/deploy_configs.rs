//! Every file in `deploy/` is parsed and validated, and broken ones are refused:
//! * the run configs by `fsrl check-config`, with the certificates and passwords that
//!   `deploy/make-test-ca.sh` makes, laid out as in `/etc/fsrl` (one actor config per actor, made
//!   from `cluster-actor.toml` as the README says); password files others may read are refused;
//! * the router's JSON5 by zenoh itself (and opened as a router, which checks its access
//!   control), its rules against the keys `proto::keys` builds (who may publish and see what:
//!   least privilege per role and per actor, for the deployed run id only);
//! * the systemd units for the fields they need and the commands, users, credentials and files
//!   they name.

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

/// The actors `router.json5` lists and `make-test-ca.sh` makes users for by default.
const ACTORS: u32 = 4;

/// `cluster-actor.toml` (actor 0's) made actor `id`'s, as the README and the file say:
/// `sed "s/actor-0/actor-<id>/g"`.
fn actor_config_text(id: u32) -> String {
    let text = std::fs::read_to_string(deploy().join("cluster-actor.toml")).unwrap();
    assert!(text.contains("user = \"actor-0\""), "{text}");
    text.replace("actor-0", &format!("actor-{id}"))
}

/// A directory laid out like `/etc/fsrl`: the test CA's files, copies of the run configs and
/// each actor's `cluster-actor-<id>.toml`.
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
    for id in 0..ACTORS {
        let p = d.path().join(format!("cluster-actor-{id}.toml"));
        std::fs::write(p, actor_config_text(id)).unwrap();
    }
    d
}

/// Writes `text` to `path` with permission bits `mode`.
fn write_mode(path: &Path, text: &str, mode: u32) {
    use std::os::unix::fs::PermissionsExt as _;
    std::fs::write(path, text).unwrap();
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).unwrap();
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
    assert!(out.contains("user = \"actor-0\""), "{out}");
    assert!(
        !out.contains("password ="),
        "the password must stay in its file: {out}"
    );
    // Each actor its own user and password file.
    for id in 0..ACTORS {
        let p = etc.path().join(format!("cluster-actor-{id}.toml"));
        let o = fsrl(&["check-config", "--print", &p.to_string_lossy()]);
        let out = String::from_utf8_lossy(&o.stdout);
        let password = etc.path().join(format!("actor-{id}.password"));
        assert!(
            o.status.success()
                && out.contains(&format!("user = \"actor-{id}\""))
                && out.contains(&*password.to_string_lossy()),
            "{out}{}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    // Under systemd (LoadCredential=), the password is the unit's credential, not the file
    // beside the config.
    let creds = tempfile::tempdir().unwrap();
    write_mode(
        &creds.path().join("actor-1.password"),
        "from-systemd\n",
        0o400,
    );
    let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .args(["check-config", "--print"])
        .arg(etc.path().join("cluster-actor-1.toml"))
        .env("CREDENTIALS_DIRECTORY", creds.path())
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    let credential = creds.path().join("actor-1.password");
    assert!(
        o.status.success()
            && out.contains(&format!("password_file = \"{}\"", credential.display())),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn a_password_file_others_may_read_is_refused_naming_it_its_mode_and_the_fix() {
    let etc = etc_fsrl();
    let password = etc.path().join("actor-2.password");
    let config = etc.path().join("cluster-actor-2.toml");
    let config = config.to_string_lossy();
    assert!(fsrl(&["check-config", &config]).status.success());
    let pw = std::fs::read_to_string(&password).unwrap();
    write_mode(&password, &pw, 0o644);
    let o = fsrl(&["check-config", &config]);
    let err = String::from_utf8_lossy(&o.stderr);
    let shown = password.display().to_string();
    assert!(!o.status.success(), "{err}");
    for needle in [
        shown.clone(),
        "mode 0644".into(),
        format!("chmod 600 {shown}"),
    ] {
        assert!(err.contains(&needle), "{needle:?} missing in {err}");
    }
    // The process itself stops at start-up with it (instead of retrying).
    write_mode(&password, &pw, 0o640);
    let o = fsrl(&["actor", "--config", &config, "--id", "2"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("mode 0640") && err.contains("chmod 600"),
        "{err}"
    );
    write_mode(&password, &pw, 0o600);
    assert!(fsrl(&["check-config", &config]).status.success());
}

#[test]
fn a_cluster_config_without_its_files_is_refused_naming_every_missing_path() {
    let o = fsrl(&[
        "check-config",
        &deploy().join("cluster-actor.toml").to_string_lossy(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    for p in ["deploy/certs/ca.crt", "deploy/actor-0.password"] {
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
    assert!(err.contains("deploy/actor-0.password"), "{err}");

    // An empty password file, half a client certificate, a tls/ endpoint without a CA.
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("ca.crt"), "not checked here").unwrap();
    write_mode(&d.path().join("empty.password"), "\n", 0o600);
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
    // A client that stops reading stalls reliable traffic through the router for at most 2 s
    // (zenoh's default: 5 s), then loses its session.
    let wait_us = json(
        &c,
        "transport/link/tx/queue/congestion_control/block/wait_before_close",
    );
    assert!(
        wait_us.as_i64().is_some_and(|us| us > 0 && us <= 2_000_000),
        "wait_before_close {wait_us}"
    );

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

/// `fsrl router` refuses its private key or users file when group or others may read it, as
/// the clients refuse their password files and keys: naming each file, its mode and the fix,
/// with `--check` and when starting.
#[test]
fn the_router_refuses_a_key_or_users_file_others_may_read() {
    let path = deploy().join("router.json5");
    let etc = etc_fsrl();
    let router = |check: bool| {
        let mut args = vec!["router".to_string()];
        if check {
            args.push("--check".into());
        }
        args.extend(["--config".into(), path.to_string_lossy().into_owned()]);
        for (k, v) in router_overrides(etc.path()) {
            args.push("--cfg".into());
            args.push(format!("{k}:{v}"));
        }
        // Never left running: a loopback port of its own (only reached if it were accepted).
        args.push("--cfg".into());
        args.push("listen/endpoints:[\"tls/127.0.0.1:0\"]".into());
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        fsrl(&args)
    };
    let o = router(true);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let key = etc.path().join("certs/router.key");
    let users = etc.path().join("router-users.txt");
    let set = |p: &Path, mode: u32| {
        use std::os::unix::fs::PermissionsExt as _;
        std::fs::set_permissions(p, std::fs::Permissions::from_mode(mode)).unwrap();
    };
    set(&key, 0o640);
    set(&users, 0o644);
    for check in [true, false] {
        let o = router(check);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "check={check}: {err}");
        for (file, mode) in [(&key, "0640"), (&users, "0644")] {
            let file = file.display().to_string();
            assert!(
                err.contains(&format!("{file} is a secret"))
                    && err.contains(&format!("mode {mode}"))
                    && err.contains(&format!("chmod 600 {file}")),
                "check={check}, {file}: {err}"
            );
        }
    }
    // Only the owner's bits: accepted (0400 as well as 0600). The certificates stay public.
    set(&key, 0o400);
    set(&users, 0o600);
    set(&etc.path().join("certs/router.crt"), 0o644);
    let o = router(true);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
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

/// The run id every `cluster-*.toml` names (they must agree).
fn deployed_run_id() -> String {
    let ids: std::collections::BTreeSet<String> = files_with("toml", &deploy())
        .iter()
        .filter(|f| {
            f.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with("cluster-")
        })
        .map(|f| {
            let t: toml::Table = std::fs::read_to_string(f).unwrap().parse().unwrap();
            t["run"]["id"].as_str().unwrap().to_string()
        })
        .collect();
    assert_eq!(
        ids.len(),
        1,
        "the cluster configs name different runs: {ids:?}"
    );
    ids.into_iter().next().unwrap()
}

/// Whether `user` may send `message` on `key` into the router.
fn allowed(
    rights: &BTreeMap<String, BTreeMap<String, Vec<String>>>,
    user: &str,
    message: &str,
    key: &str,
) -> bool {
    let key = zenoh::key_expr::KeyExpr::try_from(key.to_string()).unwrap();
    rights
        .get(user)
        .and_then(|r| r.get(message))
        .is_some_and(|kes| {
            kes.iter().any(|ke| {
                zenoh::key_expr::KeyExpr::try_from(ke.clone())
                    .unwrap_or_else(|e| panic!("{ke}: {e}"))
                    .includes(&key)
            })
        })
}

/// The messages by which a client publishes (as opposed to subscribing or asking).
const PUBLISHING: [&str; 5] = [
    "put",
    "delete",
    "reply",
    "declare_queryable",
    "liveliness_token",
];

#[test]
fn the_access_control_lets_each_role_send_and_see_only_its_own_topics() {
    let rights = ingress_rights();
    let users: Vec<&String> = rights.keys().collect();
    let mut want: Vec<String> = (0..ACTORS).map(|k| format!("actor-{k}")).collect();
    want.extend(["evaluator", "learner", "monitor"].map(String::from));
    assert_eq!(users, want.iter().collect::<Vec<_>>());
    let run = RunId::new(deployed_run_id()).unwrap();
    let member = |role, index| Member {
        sender: SenderId::new(role, index),
        instance: 0x0123_4567_89ab_cdef,
    };
    let alive = |role, index| keys::alive(&run, member(role, index));
    let weights = keys::weights(&run).key_expr().to_string();
    let control = keys::control(&run).key_expr().to_string();
    let ack = |k| keys::ack(&run, k).key_expr().to_string();
    let transitions = |k| keys::transitions(&run, k).key_expr().to_string();
    let all_transitions = keys::all_transitions(&run).key_expr().to_string();
    let report = keys::eval_report(&run, 0).key_expr().to_string();
    let all_reports = keys::all_eval_reports(&run).key_expr().to_string();
    let all_metrics = keys::all_metrics(&run).key_expr().to_string();
    let all_status = keys::all_status(&run).key_expr().to_string();
    let all_alive = keys::all_alive(&run);
    let everything = keys::run_prefix(&run);
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
    let mut table: Vec<(String, &str, String, bool)> = Vec::new();
    let mut row = |u: &str, m: &'static str, k: String, ok: bool| {
        table.push((u.to_string(), m, k, ok));
    };
    // The learner: what it declares (learner::process) and nothing more.
    for k in [
        &weights,
        &control,
        &ack(3),
        &metrics(Role::Learner, 0),
        &status(Role::Learner, 0),
    ] {
        row("learner", "put", k.clone(), true);
    }
    for m in ["declare_queryable", "reply"] {
        row("learner", m, weights.clone(), true);
        row("learner", m, control.clone(), true);
    }
    row("learner", "liveliness_token", alive(Role::Learner, 0), true);
    row(
        "learner",
        "declare_subscriber",
        all_transitions.clone(),
        true,
    );
    row("learner", "declare_subscriber", all_reports.clone(), true);
    row("learner", "declare_subscriber", all_status.clone(), true);
    row(
        "learner",
        "declare_liveliness_subscriber",
        all_alive.clone(),
        true,
    );
    row("learner", "liveliness_query", all_alive.clone(), true);
    row("learner", "put", transitions(3), false);
    row("learner", "put", report.clone(), false);
    row("learner", "liveliness_token", alive(Role::Actor, 3), false);
    row("learner", "declare_subscriber", everything.clone(), false);
    row("learner", "declare_subscriber", all_metrics.clone(), false);
    // Every actor: its own keys only.
    for k in 0..ACTORS {
        let u = format!("actor-{k}");
        let other = (k + 1) % ACTORS;
        row(&u, "put", transitions(k), true);
        row(&u, "put", metrics(Role::Actor, k), true);
        row(&u, "put", status(Role::Actor, k), true);
        row(&u, "liveliness_token", alive(Role::Actor, k), true);
        row(&u, "declare_subscriber", ack(k), true);
        for key in [&weights, &control] {
            row(&u, "declare_subscriber", key.clone(), true);
            row(&u, "query", key.clone(), true);
        }
        row(&u, "declare_liveliness_subscriber", all_alive.clone(), true);
        row(&u, "liveliness_query", all_alive.clone(), true);
        // Not another actor's.
        row(&u, "put", transitions(other), false);
        row(&u, "put", metrics(Role::Actor, other), false);
        row(&u, "put", status(Role::Actor, other), false);
        row(&u, "liveliness_token", alive(Role::Actor, other), false);
        row(&u, "declare_subscriber", ack(other), false);
        row(&u, "delete", transitions(k), false);
        // Not the learner's, the evaluator's or anyone's data.
        for key in [&weights, &control, &ack(k), &report] {
            row(&u, "put", key.clone(), false);
        }
        row(&u, "put", metrics(Role::Learner, 0), false);
        row(&u, "declare_queryable", weights.clone(), false);
        row(&u, "reply", weights.clone(), false);
        row(&u, "reply", control.clone(), false);
        row(&u, "delete", weights.clone(), false);
        row(&u, "liveliness_token", alive(Role::Learner, 0), false);
        for key in [
            &all_transitions,
            &transitions(other),
            &all_metrics,
            &all_reports,
            &everything,
        ] {
            row(&u, "declare_subscriber", key.clone(), false);
        }
        row(&u, "query", all_transitions.clone(), false);
    }
    // The evaluator: reports out; weights and control in.
    row("evaluator", "put", report.clone(), true);
    row("evaluator", "put", metrics(Role::Evaluator, 0), true);
    row(
        "evaluator",
        "liveliness_token",
        alive(Role::Evaluator, 0),
        true,
    );
    for key in [&weights, &control] {
        row("evaluator", "declare_subscriber", key.clone(), true);
        row("evaluator", "query", key.clone(), true);
    }
    row("evaluator", "put", weights.clone(), false);
    row("evaluator", "put", transitions(0), false);
    row("evaluator", "reply", weights.clone(), false);
    row(
        "evaluator",
        "declare_subscriber",
        all_transitions.clone(),
        false,
    );
    row("evaluator", "declare_subscriber", everything.clone(), false);
    // The monitor: telemetry in, nothing out.
    for key in [&all_metrics, &all_status, &all_reports] {
        row("monitor", "declare_subscriber", key.clone(), true);
    }
    row(
        "monitor",
        "declare_liveliness_subscriber",
        all_alive.clone(),
        true,
    );
    row("monitor", "liveliness_query", all_alive.clone(), true);
    for key in [
        &weights,
        &control,
        &ack(0),
        &all_transitions,
        &transitions(0),
        &everything,
    ] {
        row("monitor", "declare_subscriber", key.clone(), false);
    }
    row("monitor", "query", weights.clone(), false);
    row("monitor", "put", metrics(Role::Monitor, 0), false);
    row("monitor", "put", weights.clone(), false);
    row("monitor", "reply", weights.clone(), false);
    row(
        "monitor",
        "liveliness_token",
        alive(Role::Monitor, 0),
        false,
    );
    // Another run: nothing at all.
    let other_run = RunId::new("other").unwrap();
    for u in &want {
        row(
            u,
            "put",
            keys::metrics(&other_run, SenderId::new(Role::Learner, 0))
                .key_expr()
                .to_string(),
            false,
        );
        row(
            u,
            "declare_subscriber",
            keys::weights(&other_run).key_expr().to_string(),
            false,
        );
        row(
            u,
            "declare_liveliness_subscriber",
            keys::all_alive(&other_run),
            false,
        );
    }
    let wrong: Vec<String> = table
        .iter()
        .filter(|(u, m, k, want)| allowed(&rights, u, m, k) != *want)
        .map(|(u, m, k, want)| format!("{u} {m} {k}: expected allowed = {want}"))
        .collect();
    assert!(wrong.is_empty(), "{wrong:#?}");
}

#[test]
fn the_access_control_is_least_privilege_by_construction() {
    let run = deployed_run_id();
    let c = zenoh::Config::from_file(deploy().join("router.json5")).unwrap();
    let acl = json(&c, "access_control");
    // Every rule names the deployed run's keys, never `fsrl/**` or `fsrl/*/...` (any run).
    let prefix = format!("fsrl/{run}/");
    for r in acl["rules"].as_array().unwrap() {
        for ke in r["key_exprs"].as_array().unwrap() {
            let ke = ke.as_str().unwrap();
            assert!(
                ke.starts_with(&prefix),
                "rule {}: {ke} is not of run {run}",
                r["id"]
            );
        }
    }
    let rights = ingress_rights();
    let users: Vec<String> = rights.keys().cloned().collect();
    // No key of the run may be subscribed to by every user (the data topics least of all).
    let everyone =
        |message: &str, key: &str| users.iter().all(|u| allowed(&rights, u, message, key));
    let r = RunId::new(&run).unwrap();
    let every_topic = [
        keys::run_prefix(&r),
        keys::all_transitions(&r).key_expr().to_string(),
        keys::transitions(&r, 0).key_expr().to_string(),
        keys::weights(&r).key_expr().to_string(),
        keys::control(&r).key_expr().to_string(),
        keys::ack(&r, 0).key_expr().to_string(),
        keys::all_eval_reports(&r).key_expr().to_string(),
        keys::all_metrics(&r).key_expr().to_string(),
        keys::all_status(&r).key_expr().to_string(),
    ];
    for key in &every_topic {
        assert!(
            !everyone("declare_subscriber", key),
            "everyone may subscribe to {key}"
        );
        assert!(!everyone("query", key), "everyone may query {key}");
    }
    for (user, messages) in &rights {
        let keys_of = |m: &str| messages.get(m).cloned().unwrap_or_default();
        // The monitor publishes nothing.
        if user == "monitor" {
            for m in PUBLISHING {
                assert!(keys_of(m).is_empty(), "monitor may {m} on {:?}", keys_of(m));
            }
        }
        // An actor publishes on concrete keys of its own, only its own transitions key among
        // the transitions, and no wildcard beyond its liveliness instance.
        if let Some(id) = user.strip_prefix("actor-") {
            let own = format!("fsrl/{run}/transitions/{id}");
            let puts = keys_of("put");
            assert!(
                puts.iter().all(|k| !k.contains('*')),
                "{user} puts on {puts:?}"
            );
            let transition_puts: Vec<&String> = puts
                .iter()
                .filter(|k| k.starts_with(&format!("fsrl/{run}/transitions/")))
                .collect();
            assert_eq!(transition_puts, [&own], "{user}");
            assert!(
                keys_of("delete").is_empty() && keys_of("reply").is_empty(),
                "{user}"
            );
            assert!(keys_of("declare_queryable").is_empty(), "{user}");
            assert_eq!(
                keys_of("liveliness_token"),
                [format!("fsrl/{run}/alive/actor/{id}/*")],
                "{user}"
            );
            let subs = keys_of("declare_subscriber");
            assert!(
                subs.iter()
                    .all(|k| !k.contains("transitions") && !k.contains("**")),
                "{user} subscribes to {subs:?}"
            );
        }
    }
    // The users are exactly those make-test-ca.sh makes by default.
    let etc = etc_fsrl();
    let dict = std::fs::read_to_string(etc.path().join("router-users.txt")).unwrap();
    let mut made: Vec<String> = dict
        .lines()
        .map(|l| l.split_once(':').unwrap().0.to_string())
        .collect();
    made.sort();
    assert_eq!(made, users);
    for u in &users {
        assert!(
            etc.path().join(format!("{u}.password")).is_file(),
            "{u}.password"
        );
    }
    assert!(
        !etc.path().join("actor.password").exists(),
        "no shared actor password any more"
    );
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
        let role = name
            .trim_start_matches("fsrl-")
            .trim_end_matches(".service")
            .trim_end_matches('@');
        // One system user per role, and per actor instance (`%i`, the actor id): none can
        // read another's secrets or write its state, not even two actors on one host.
        let user = if name.contains('@') {
            format!("fsrl-{role}-%i")
        } else {
            format!("fsrl-{role}")
        };
        assert_eq!(one("Service", "User"), user, "{name}");
        assert_eq!(one("Service", "Group"), user, "{name}");
        assert_eq!(one("Service", "UMask"), "0077", "{name}");
        assert_eq!(one("Service", "Restart"), "on-failure", "{name}");
        assert_eq!(one("Install", "WantedBy"), "multi-user.target", "{name}");
        let exec = one("Service", "ExecStart");
        let argv: Vec<&str> = exec.split_whitespace().collect();
        assert_eq!(argv[0], "/usr/local/bin/fsrl", "{name}");
        assert_eq!(argv[1], role, "{name} must run `fsrl {role}`");
        let config = argv
            .iter()
            .position(|a| *a == "--config")
            .and_then(|i| argv.get(i + 1))
            .unwrap_or_else(|| panic!("{name}: no --config"));
        let file = config
            .strip_prefix("/etc/fsrl/")
            .unwrap_or_else(|| panic!("{name}: config {config} outside /etc/fsrl"));
        // The config as installed for instance 0: the actor's is made from
        // cluster-actor.toml (README), the others are deploy/'s files as they are.
        let (file, config_text) = if name.contains('@') {
            assert!(
                exec.contains("--id %i"),
                "{name}: the instance must be the actor id"
            );
            assert_eq!(file, "cluster-actor-%i.toml", "{name}");
            ("cluster-actor.toml".to_string(), actor_config_text(0))
        } else {
            let text = std::fs::read_to_string(deploy().join(file)).unwrap_or_else(|_| {
                panic!("{name} names /etc/fsrl/{file}, which deploy/ does not provide")
            });
            (file.to_string(), text)
        };
        let instance = |s: &str| s.replace("%i", "0");
        if role == "router" {
            assert!(
                !f.contains_key(&("Service".into(), "StateDirectory".into())),
                "{name}"
            );
        } else {
            // Its own state directory (the learner's is nobody else's to write; each actor
            // instance its own).
            let state = instance(&one("Service", "StateDirectory"));
            let own = if name.contains('@') {
                format!("fsrl/{role}-0")
            } else {
                format!("fsrl/{role}")
            };
            assert_eq!(state, own, "{name}");
            assert_eq!(
                instance(&one("Service", "WorkingDirectory")),
                format!("/var/lib/{state}"),
                "{name}"
            );
            let t: toml::Table = config_text.parse().unwrap();
            for (section, key) in [("learner", "run_dir"), ("evaluator", "out_dir")] {
                if let Some(dir) = t.get(section).and_then(|s| s.get(key)) {
                    let dir = dir.as_str().unwrap();
                    assert!(
                        dir.starts_with(&format!("/var/lib/{state}/")),
                        "{file}: {dir}"
                    );
                }
            }
            // The password as a systemd credential named as the config's password file (a
            // relative name: looked up in $CREDENTIALS_DIRECTORY first), from a root-only file.
            let password = t["transport"]["zenoh"]["auth"]["password_file"]
                .as_str()
                .unwrap()
                .to_string();
            assert!(
                !password.contains('/'),
                "{file}: {password} must be a plain file name"
            );
            let cred = instance(&one("Service", "LoadCredential"));
            assert_eq!(cred, format!("{password}:/etc/fsrl/{password}"), "{name}");
        }
        if name.contains('@') {
            template_instances_are_isolated(name, &f);
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

/// Two instances of a template unit on one host (actors 0 and 1) share nothing a secret or
/// state could leak through: each its own user and group (allocated by systemd with
/// `DynamicUser=`, so no `useradd` can make them one), its own credential from its own
/// root-only file, its own state and working directory, and no supplementary group, shared
/// writable path or credential directory of the other.
fn template_instances_are_isolated(name: &str, f: &BTreeMap<(String, String), Vec<String>>) {
    let get = |k: &str| -> Vec<String> {
        f.get(&("Service".to_string(), k.to_string()))
            .cloned()
            .unwrap_or_default()
    };
    assert_eq!(
        get("DynamicUser"),
        ["yes"],
        "{name}: each instance a user of its own (DynamicUser=yes)"
    );
    for k in [
        "SupplementaryGroups",
        "ReadWritePaths",
        "BindPaths",
        "SetCredential",
        "LoadCredentialEncrypted",
        "ImportCredential",
    ] {
        assert!(get(k).is_empty(), "{name}: {k}= shared between instances");
    }
    let at = |id: u32| -> BTreeMap<&str, Vec<String>> {
        [
            "User",
            "Group",
            "LoadCredential",
            "StateDirectory",
            "WorkingDirectory",
            "RuntimeDirectory",
            "CacheDirectory",
            "LogsDirectory",
        ]
        .into_iter()
        .map(|k| {
            let v = get(k)
                .iter()
                .map(|v| v.replace("%i", &id.to_string()))
                .collect();
            (k, v)
        })
        .collect()
    };
    let (a, b) = (at(0), at(1));
    for (k, va) in &a {
        let vb = &b[k];
        for v in va {
            assert!(
                !vb.contains(v),
                "{name}: instances 0 and 1 share {k}={v}: actor 0 could read or write actor 1's"
            );
        }
    }
    assert_eq!(
        a["LoadCredential"],
        ["actor-0.password:/etc/fsrl/actor-0.password"],
        "{name}"
    );
    assert_eq!(
        b["LoadCredential"],
        ["actor-1.password:/etc/fsrl/actor-1.password"],
        "{name}"
    );
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
    // SPEC §5's imitation rate there; the default schedule departs from it (Experiment 5).
    assert_eq!(imitation_learning_rate(&printed), 0.01, "{printed}");
    let o = fsrl(&[
        "check-config",
        root.join("configs/fast.toml").to_str().unwrap(),
        "--print",
    ]);
    let printed = String::from_utf8_lossy(&o.stdout);
    assert_eq!(imitation_learning_rate(&printed), 0.001, "{printed}");
}

/// `train.imitation.learning_rate` of a `check-config --print` output (an `ok: ...` line, then
/// the resolved config as TOML).
fn imitation_learning_rate(printed: &str) -> f64 {
    let start = printed.find("\n[").expect("a TOML table after the ok line") + 1;
    let t: toml::Table = printed[start..]
        .parse()
        .expect("check-config --print is TOML");
    t["train"]["imitation"]["learning_rate"]
        .as_float()
        .expect("train.imitation.learning_rate is a number")
}

/// The `[train]` table of a `check-config --print` output.
fn printed_train(printed: &str) -> toml::Table {
    let start = printed.find("\n[").expect("a TOML table after the ok line") + 1;
    let t: toml::Table = printed[start..]
        .parse()
        .expect("check-config --print is TOML");
    t["train"].as_table().expect("a [train] table").clone()
}

/// One default schedule: `fsrl check-config --print` without a file shows the built-in
/// defaults, `configs/fast.toml` spells out exactly those, and `configs/paper.toml` is the
/// paper's schedule.
#[test]
fn the_default_schedule_is_configs_fast_and_the_paper_schedule_is_one_file_away() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let print = |file: Option<&Path>| -> toml::Table {
        let mut args = vec!["check-config".to_string(), "--print".to_string()];
        if let Some(f) = file {
            args.push(f.to_string_lossy().into_owned());
        }
        let args: Vec<&str> = args.iter().map(|a| a.as_str()).collect();
        let o = fsrl(&args);
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success(),
            "{out}{}",
            String::from_utf8_lossy(&o.stderr)
        );
        printed_train(&out)
    };
    let defaults = print(None);
    assert_eq!(print(Some(&root.join("configs/fast.toml"))), defaults);
    let get = |t: &toml::Table, path: &[&str]| -> toml::Value {
        let mut v = toml::Value::Table(t.clone());
        for k in path {
            v = v[*k].clone();
        }
        v
    };
    for (path, value) in [
        (&["imitation", "episodes"][..], toml::Value::Integer(1000)),
        (&["imitation", "epochs"], toml::Value::Integer(30)),
        (&["rl", "episodes"], toml::Value::Integer(5000)),
        (&["rl", "batches_per_episode"], toml::Value::Integer(20)),
        (&["select"], toml::Value::String("low-disc".into())),
    ] {
        assert_eq!(get(&defaults, path), value, "default {path:?}");
    }
    let paper = print(Some(&root.join("configs/paper.toml")));
    for (path, value) in [
        (&["imitation", "episodes"][..], toml::Value::Integer(3000)),
        (&["imitation", "epochs"], toml::Value::Integer(50)),
        (&["rl", "episodes"], toml::Value::Integer(10_000)),
        (
            &["rl", "epsilon_decay_episodes"],
            toml::Value::Integer(4000),
        ),
        (&["rl", "batches_per_episode"], toml::Value::Integer(100)),
        (&["select"], toml::Value::String("last".into())),
    ] {
        assert_eq!(get(&paper, path), value, "paper {path:?}");
    }
}

/// The number of runs `fsrl reproduce` plans for `args` (its `--dry-run` header).
fn grid_runs(args: &[&str]) -> usize {
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("runs");
    let mut all = vec!["reproduce", "--dry-run", "--runs", runs.to_str().unwrap()];
    all.extend_from_slice(args);
    let o = fsrl(&all);
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let head = out.lines().next().unwrap_or_default();
    let runs = head
        .split(" = ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no run count in {head}"));
    runs
}

/// The Slurm array script runs the paper's grid with one task per run: its array size is the
/// size of the grid its `fsrl reproduce` line plans, and it lets fsrl read the task id.
#[test]
fn the_slurm_array_has_one_task_per_run_of_the_grid() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let script = std::fs::read_to_string(root.join("deploy/slurm/reproduce.sbatch")).unwrap();
    let array = script
        .lines()
        .find_map(|l| l.strip_prefix("#SBATCH --array="))
        .expect("an #SBATCH --array line");
    let (lo, hi) = array.split_once('-').expect("an array range lo-hi");
    let tasks = hi.trim().parse::<usize>().unwrap() - lo.trim().parse::<usize>().unwrap() + 1;
    let exec = script
        .lines()
        .find(|l| l.starts_with("exec \"$FSRL\" reproduce"))
        .expect("the exec line");
    assert!(
        !exec.contains("--shard"),
        "fsrl reads the Slurm variables itself: {exec}"
    );
    let flag = |name: &str| -> String {
        let mut words = exec.split_whitespace();
        words.find(|w| *w == name);
        words
            .next()
            .unwrap_or_else(|| panic!("{name} in {exec}"))
            .to_string()
    };
    let (methods, seeds) = (flag("--methods"), flag("--seeds"));
    assert_eq!(tasks, 54);
    assert_eq!(
        grid_runs(&["--methods", &methods, "--seeds", &seeds]),
        tasks
    );
}

/// The Kubernetes Indexed Job: parses, names the image and the command, and has one completion
/// per run of the grid its arguments plan, with FSRL_SHARDS equal to the completions.
#[test]
fn the_kubernetes_job_has_one_indexed_completion_per_run_of_the_grid() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let job: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(root.join("deploy/k8s/reproduce-job.json")).unwrap(),
    )
    .expect("the Job manifest is JSON");
    assert_eq!(job["kind"], "Job");
    assert_eq!(job["apiVersion"], "batch/v1");
    let spec = &job["spec"];
    assert_eq!(spec["completionMode"], "Indexed");
    let completions = spec["completions"].as_u64().unwrap() as usize;
    let c = &spec["template"]["spec"]["containers"][0];
    assert!(!c["image"].as_str().unwrap().is_empty());
    assert_eq!(c["command"][0], "fsrl");
    let args: Vec<&str> = c["args"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a.as_str().unwrap())
        .collect();
    assert_eq!(args[0], "reproduce");
    let shards = c["env"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["name"] == "FSRL_SHARDS")
        .expect("FSRL_SHARDS")["value"]
        .as_str()
        .unwrap()
        .parse::<usize>()
        .unwrap();
    assert_eq!(shards, completions);
    let flag = |name: &str| args[args.iter().position(|a| *a == name).unwrap() + 1];
    assert_eq!(
        grid_runs(&["--methods", flag("--methods"), "--seeds", flag("--seeds")]),
        completions
    );
    assert_eq!(completions, 54);
}
