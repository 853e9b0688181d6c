//! A hostile actor against the live router: the real `fsrl router` with `deploy/router.json5`
//! (its run id changed as `deploy/README.md` says) and the test CA's users, on loopback
//! (`tls/127.0.0.1`, multicast scouting off). With actor 0's valid credentials a client tries
//! to put control, weights, acknowledgements, an evaluation report, transitions, metrics and
//! status under other senders' keys, to delete, to declare a learner's and another actor's
//! liveliness token, to answer late joiners' queries for the weights, and to subscribe to (and
//! query) every actor's transitions, another actor's acknowledgements, the whole run and
//! `fsrl/**`. Legitimate clients (learner, evaluator, monitor, actor 1), each subscribed to
//! what its role may see, must receive none of it within a deadline, while the legitimate
//! messages sent before, during and after it (actor 0's own included) do arrive: the checks
//! can fail.

mod multihost_support;
mod net_support;

use std::any::Any;
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use multihost_support as mh;
use net_support::{free_port, Reaped};
use zenoh::query::{ConsolidationMode, QueryTarget};
use zenoh::sample::SampleKind;
use zenoh::{Session, Wait};

/// Longest wait for the router, a session, or the legitimate traffic.
const PATIENCE: Duration = Duration::from_secs(60);
/// How long the hostile traffic has to show up where it must not.
const DEADLINE: Duration = Duration::from_secs(2);
const LEGIT: &[u8] = b"legit";
const HOSTILE: &[u8] = b"hostile";
/// The liveliness instance of the hostile tokens.
const HOSTILE_INSTANCE: &str = "00000000deadbeef";

/// What one watcher received: (watcher, key, kind, payload).
type Log = Arc<Mutex<Vec<(String, String, SampleKind, Vec<u8>)>>>;

struct World {
    port: u16,
    secrets: std::path::PathBuf,
    log: Log,
    /// Subscribers, queryables, tokens: kept until the end.
    keep: Vec<Box<dyn Any + Send>>,
}

impl World {
    /// A client session of the router as `user` (its password from the test CA's files).
    fn session(&self, user: &str) -> Session {
        net_support::router_session(&self.secrets, self.port, user, PATIENCE)
    }

    /// `who` subscribes to `key`, logging what arrives.
    fn watch(&mut self, s: &Session, who: &str, key: &str) {
        let (log, who) = (self.log.clone(), who.to_string());
        let sub = s
            .declare_subscriber(key.to_string())
            .callback(move |sample| {
                log.lock().unwrap().push((
                    who.clone(),
                    sample.key_expr().as_str().to_string(),
                    sample.kind(),
                    sample.payload().to_bytes().to_vec(),
                ))
            })
            .wait()
            .unwrap();
        self.keep.push(Box::new(sub));
    }

    /// `who` watches liveliness tokens under `key` (current ones too), logging them.
    fn watch_alive(&mut self, s: &Session, who: &str, key: &str) {
        let (log, who) = (self.log.clone(), who.to_string());
        let sub = s
            .liveliness()
            .declare_subscriber(key.to_string())
            .history(true)
            .callback(move |sample| {
                log.lock().unwrap().push((
                    who.clone(),
                    sample.key_expr().as_str().to_string(),
                    sample.kind(),
                    Vec::new(),
                ))
            })
            .wait()
            .unwrap();
        self.keep.push(Box::new(sub));
    }

    /// A queryable on `key` answering `payload`.
    fn answer(&mut self, s: &Session, key: &str, payload: &'static [u8]) {
        let k = key.to_string();
        let q = s
            .declare_queryable(key.to_string())
            .callback(move |query| {
                let _ = query.reply(k.clone(), payload.to_vec()).wait();
            })
            .wait()
            .unwrap();
        self.keep.push(Box::new(q));
    }

    fn seen(&self, pred: impl Fn(&str, &str, SampleKind, &[u8]) -> bool) -> usize {
        self.log
            .lock()
            .unwrap()
            .iter()
            .filter(|(w, k, kind, p)| pred(w, k, *kind, p))
            .count()
    }
}

/// The payloads of the replies to a query for `key` (every queryable asked, none merged).
fn ask(s: &Session, key: &str) -> Vec<Vec<u8>> {
    let replies = s
        .get(key.to_string())
        .target(QueryTarget::All)
        .consolidation(ConsolidationMode::None)
        .timeout(DEADLINE)
        .wait()
        .unwrap();
    let mut out = Vec::new();
    while let Ok(r) = replies.recv() {
        if let Ok(sample) = r.result() {
            out.push(sample.payload().to_bytes().to_vec());
        }
    }
    out
}

#[test]
fn a_hostile_actor_reaches_no_one_through_the_live_router() {
    let dir = tempfile::tempdir().unwrap();
    let secrets = dir.path().to_path_buf();
    mh::make_secrets(&secrets, &[]).unwrap();
    let run = format!("hr{}", std::process::id());
    let port = free_port();
    let listen = format!("listen/endpoints:[\"tls/127.0.0.1:{port}\"]");
    let args = mh::router_args_for_run(&secrets, &run, &[listen]);
    let log_file = std::fs::File::create(secrets.join("router.log")).unwrap();
    let _router = Reaped(
        Command::new(env!("CARGO_BIN_EXE_fsrl"))
            .args(&args)
            .env("RUST_LOG", "info,zenoh=warn")
            .stdin(Stdio::null())
            .stdout(log_file.try_clone().unwrap())
            .stderr(log_file)
            .spawn()
            .unwrap(),
    );
    let router_log = || std::fs::read_to_string(secrets.join("router.log")).unwrap_or_default();
    let mut w = World {
        port,
        secrets: secrets.clone(),
        log: Log::default(),
        keep: Vec::new(),
    };
    let k = |rest: &str| format!("fsrl/{run}/{rest}");

    // The legitimate clients, each watching what its role may see.
    let learner = w.session("learner");
    let evaluator = w.session("evaluator");
    let monitor = w.session("monitor");
    let actor1 = w.session("actor-1");
    for key in ["transitions/*", "eval/*", "status/**"] {
        w.watch(&learner, "learner", &k(key));
    }
    w.watch_alive(&learner, "learner", &k("alive/**"));
    for key in ["weights", "control", "ack/1"] {
        w.watch(&actor1, "actor-1", &k(key));
    }
    w.watch_alive(&actor1, "actor-1", &k("alive/**"));
    for key in ["weights", "control"] {
        w.watch(&evaluator, "evaluator", &k(key));
    }
    for key in ["metrics/**", "status/**", "eval/*"] {
        w.watch(&monitor, "monitor", &k(key));
    }
    w.watch_alive(&monitor, "monitor", &k("alive/**"));
    w.answer(&learner, &k("weights"), LEGIT);
    let learner_token = |w: &mut World, instance: &str| {
        let token = learner
            .liveliness()
            .declare_token(k(&format!("alive/learner/0/{instance}")))
            .wait()
            .unwrap();
        w.keep.push(Box::new(token));
    };
    learner_token(&mut w, "0000000000000001");

    // Actor 0: one session that publishes, one that spies (so that its own puts are not
    // delivered to its subscribers inside the process).
    let hostile = w.session("actor-0");
    let spy = w.session("actor-0");
    for key in [
        k("transitions/*"),
        k("transitions/1"),
        k("ack/1"),
        k("metrics/**"),
        k("**"),
        "fsrl/**".to_string(),
        "**".to_string(),
    ] {
        w.watch(&spy, "spy", &key);
    }
    w.watch_alive(&spy, "spy", "fsrl/**");
    // What actor 0 may read: the weights (its sessions work). In a session of its own: a
    // session hands a sample it receives to every matching subscriber it has, allowed or not.
    let reader = w.session("actor-0");
    w.watch(&reader, "spy-weights", &k("weights"));

    // Legitimate traffic, every key family from the user allowed to send it.
    let legit = || {
        let put = |s: &Session, key: String| s.put(key, LEGIT.to_vec()).wait().unwrap();
        put(&learner, k("weights"));
        put(&learner, k("control"));
        put(&learner, k("ack/1"));
        put(&actor1, k("transitions/1"));
        put(&actor1, k("metrics/actor/1"));
        put(&actor1, k("status/actor/1"));
        put(&evaluator, k("eval/0"));
        put(&hostile, k("transitions/0"));
        put(&hostile, k("metrics/actor/0"));
    };
    let expected_with = |token: &str| -> Vec<(&'static str, String)> {
        vec![
            ("actor-1", k("weights")),
            ("actor-1", k("control")),
            ("actor-1", k("ack/1")),
            ("evaluator", k("weights")),
            ("evaluator", k("control")),
            ("learner", k("transitions/1")),
            ("learner", k("transitions/0")),
            ("learner", k("status/actor/1")),
            ("learner", k("eval/0")),
            ("monitor", k("metrics/actor/1")),
            ("monitor", k("metrics/actor/0")),
            ("monitor", k("status/actor/1")),
            ("monitor", k("eval/0")),
            ("monitor", k(&format!("alive/learner/0/{token}"))),
            ("actor-1", k(&format!("alive/learner/0/{token}"))),
            ("spy-weights", k("weights")),
        ]
    };
    let count_legit = |w: &World, who: &str, key: &str| {
        w.seen(|w2, k2, kind, p| {
            w2 == who && k2 == key && (p == LEGIT || (p.is_empty() && kind == SampleKind::Put))
        })
    };
    let wait_legit = |w: &World, what: &str, expected: &[(&str, String)], before: &[usize]| {
        let start = Instant::now();
        loop {
            legit();
            let missing: Vec<String> = expected
                .iter()
                .zip(before)
                .filter(|((who, key), n)| count_legit(w, who, key) <= **n)
                .map(|((who, key), _)| format!("{who} {key}"))
                .collect();
            if missing.is_empty() {
                return;
            }
            assert!(
                start.elapsed() < PATIENCE,
                "{what}: legitimate messages never arrived: {missing:#?}\nrouter log:\n{}",
                router_log()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    };
    // 1. Legitimate messages arrive (so what follows could fail).
    let expected = expected_with("0000000000000001");
    let zero = vec![0; expected.len()];
    wait_legit(&w, "before", &expected, &zero);
    let late_joiner = ask(&evaluator, &k("weights"));
    assert_eq!(
        late_joiner,
        [LEGIT.to_vec()],
        "the learner answers late joiners"
    );
    // A late liveliness watcher sees the tokens alive before it.
    let late = w.session("monitor");
    w.watch_alive(&late, "monitor-late", &k("alive/**"));
    wait_legit(
        &w,
        "late watcher",
        &[("monitor-late", k("alive/learner/0/0000000000000001"))],
        &[0],
    );

    // 2. Everything actor 0 must not do.
    let put = |key: String| hostile.put(key, HOSTILE.to_vec()).wait().unwrap();
    for key in [
        "control",
        "weights",
        "ack/1",
        "ack/0",
        "eval/0",
        "transitions/1",
        "metrics/actor/1",
        "status/actor/1",
        "metrics/learner/0",
        "status/learner/0",
    ] {
        put(k(key));
    }
    for key in ["transitions/0", "transitions/1", "weights", "control"] {
        hostile.delete(k(key)).wait().unwrap();
    }
    for role in ["learner/0", "actor/1", "evaluator/0"] {
        let t = hostile
            .liveliness()
            .declare_token(k(&format!("alive/{role}/{HOSTILE_INSTANCE}")))
            .wait()
            .unwrap();
        w.keep.push(Box::new(t));
    }
    w.answer(&hostile, &k("weights"), HOSTILE);
    w.answer(&hostile, &k("control"), HOSTILE);
    let spied: Vec<Vec<u8>> = [k("transitions/*"), k("**"), "fsrl/**".to_string()]
        .iter()
        .flat_map(|key| ask(&spy, key))
        .collect();
    let spied_alive = spy
        .liveliness()
        .get("fsrl/**")
        .timeout(DEADLINE)
        .wait()
        .unwrap();

    // 3. Legitimate traffic goes on, for the deadline and until fresh messages of every kind
    //    (actor 0's own, sent after its hostile ones, and a new learner token included)
    //    arrived.
    // (The counts before come first: the new token's event may arrive at once.)
    let expected = expected_with("0000000000000002");
    let before: Vec<usize> = expected
        .iter()
        .map(|(who, key)| count_legit(&w, who, key))
        .collect();
    learner_token(&mut w, "0000000000000002");
    let start = Instant::now();
    while start.elapsed() < DEADLINE {
        legit();
        std::thread::sleep(Duration::from_millis(100));
    }
    wait_legit(&w, "after", &expected, &before);
    let late_joiner = ask(&evaluator, &k("weights"));
    assert!(
        !late_joiner.is_empty() && late_joiner.iter().all(|p| p == LEGIT),
        "a late joiner got {late_joiner:?}"
    );
    let mut tokens = Vec::new();
    while let Ok(r) = spied_alive.recv() {
        if let Ok(s) = r.result() {
            tokens.push(s.key_expr().as_str().to_string());
        }
    }

    // 4. None of it reached anyone.
    let log = w.log.lock().unwrap().clone();
    let leaked: Vec<String> = log
        .iter()
        .filter(|(who, key, kind, payload)| {
            payload.as_slice() == HOSTILE
                || *kind == SampleKind::Delete && !key.contains("/alive/")
                || key.contains(HOSTILE_INSTANCE)
                || who == "spy"
        })
        .map(|(who, key, kind, p)| {
            format!("{who} got {kind:?} {key} {:?}", String::from_utf8_lossy(p))
        })
        .collect();
    assert!(
        leaked.is_empty(),
        "hostile traffic got through:\n{leaked:#?}\nrouter log:\n{}",
        router_log()
    );
    assert!(spied.is_empty(), "actor 0 queried {} replies", spied.len());
    assert!(
        tokens.is_empty(),
        "actor 0 saw liveliness tokens {tokens:?}"
    );
    // Actor 0's sessions were up all along: one received the weights it may read.
    assert!(log
        .iter()
        .any(|(who, _, _, p)| who == "spy-weights" && p == LEGIT));
    drop(w);
}
