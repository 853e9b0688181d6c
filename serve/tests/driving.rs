//! `serve::run` on a thread, a robot peer over zenoh on loopback (multicast scouting off), in
//! lockstep (`Trigger::Odometry`) on the odometry's clock:
//!
//! - inputs that keep coming fresh but never stamped alike give a zero command within two
//!   periods, with the reason, not silence (the robot would keep its last command);
//! - an odometry flood (each odometry a decision) does not starve the goal: a goal in another
//!   frame, published during the flood, stops the robot.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use serve::fixtures::{goal, odometry, shipped_model};
use serve::msg::{self, Twist};
use zenoh::{Session, Wait};

/// The shipped model's control period.
const PERIOD: Duration = Duration::from_millis(250);

/// One person in `odom` stamped `t_s`, at (2, 0) walking at (−0.5, 0).
fn people(t_s: f64) -> Vec<u8> {
    serve::fixtures::people("odom", t_s, 1)
}

/// A peer of the server at `endpoint`.
fn session(endpoint: &str) -> Session {
    let cfg = transport::ZenohConfig::peer(vec![], vec![endpoint.to_string()])
        .to_zenoh(1 << 20)
        .unwrap();
    zenoh::open(cfg).wait().unwrap()
}

fn moving(t: &Twist) -> bool {
    *t != Twist::ZERO
}

/// `serve::run` in lockstep with default safety, stopped and joined on drop; a robot peer
/// with the commands it receives and the instant each came.
struct Lockstep {
    server: Option<std::thread::JoinHandle<serve::node::Summary>>,
    stop: serve::Stopper,
    robot: Session,
    endpoint: String,
    cmd: mpsc::Receiver<(Instant, Twist)>,
}

impl Lockstep {
    fn start(name: &str) -> Self {
        let endpoint = format!("tcp/127.0.0.1:{}", testkit::free_port());
        let opts = serve::ServeOptions {
            name: name.into(),
            trigger: serve::Trigger::Odometry,
            clock: serve::Clock::Odometry,
            threads: 1,
            zenoh: transport::ZenohConfig::peer(vec![endpoint.clone()], vec![]),
            ..serve::ServeOptions::new(shipped_model())
        };
        let inbox = serve::Inbox::new();
        let stop = inbox.stopper();
        let (ready_tx, ready) = mpsc::channel();
        let server = std::thread::spawn(move || {
            serve::run(&opts, inbox, move || {
                let _ = ready_tx.send(());
            })
            .unwrap()
        });
        ready
            .recv_timeout(Duration::from_secs(60))
            .expect("serve::run is ready");
        let robot = session(&endpoint);
        let (tx, cmd) = mpsc::channel();
        robot
            .declare_subscriber("cmd_vel")
            .callback(move |s| {
                if let Ok(t) = msg::decode::<Twist>(&s.payload().to_bytes()) {
                    let _ = tx.send((Instant::now(), t));
                }
            })
            .background()
            .wait()
            .unwrap();
        Self {
            server: Some(server),
            stop,
            robot,
            endpoint,
            cmd,
        }
    }

    fn put(&self, key: &str, bytes: Vec<u8>) {
        self.robot.put(key, bytes).wait().unwrap();
    }

    /// Steps in lockstep from `t_s` until a command that moves the robot; the stamp reached.
    fn drive(&self, mut t_s: f64) -> f64 {
        let deadline = Instant::now() + Duration::from_secs(20);
        self.put("goal_pose", goal("odom", 1000.0));
        while Instant::now() < deadline {
            t_s += 0.25;
            self.put("people", people(t_s));
            self.put("odom", odometry(t_s));
            if let Ok((_, t)) = self.cmd.recv_timeout(Duration::from_millis(100)) {
                if moving(&t) {
                    return t_s;
                }
            }
        }
        panic!("no command that moves the robot");
    }

    /// The first command satisfying `pred` within `within`.
    fn first(&self, within: Duration, pred: impl Fn(&Twist) -> bool) -> Option<Instant> {
        let deadline = Instant::now() + within;
        while let Ok((at, t)) = self
            .cmd
            .recv_timeout(deadline.saturating_duration_since(Instant::now()))
        {
            if pred(&t) {
                return Some(at);
            }
        }
        None
    }

    fn finish(mut self) -> serve::node::Summary {
        self.stop.stop();
        self.server.take().unwrap().join().unwrap()
    }
}

impl Drop for Lockstep {
    fn drop(&mut self) {
        self.stop.stop();
    }
}

#[test]
fn inputs_never_stamped_alike_give_a_zero_command_within_two_periods() {
    let served = Lockstep::start("out-of-step");
    let mut t_s = served.drive(1000.0);
    while served.cmd.try_recv().is_ok() {}
    // From now on people come 3 ms behind the odometry, every 50 ms, fresh: no decision.
    let out_of_step = Instant::now();
    let feeding = Arc::new(AtomicBool::new(true));
    let feeder = {
        let (robot, feeding) = (served.robot.clone(), feeding.clone());
        std::thread::spawn(move || {
            while feeding.load(Ordering::Relaxed) {
                t_s += 0.05;
                robot.put("people", people(t_s - 0.003)).wait().unwrap();
                robot.put("odom", odometry(t_s)).wait().unwrap();
                std::thread::sleep(Duration::from_millis(50));
            }
        })
    };
    let zero = served.first(Duration::from_secs(5), |t| !moving(t));
    feeding.store(false, Ordering::Relaxed);
    feeder.join().unwrap();
    let zero = zero.expect("no zero command while the inputs were never in step");
    let after = zero - out_of_step;
    assert!(after < 2 * PERIOD, "the zero command came {after:?} after");
    let summary = served.finish();
    assert_eq!(summary.counters.stops, 0, "{summary:?}");
}

#[test]
fn an_odometry_flood_does_not_starve_the_goal() {
    let served = Lockstep::start("flood");
    let t_s = served.drive(1000.0);
    // From a peer of its own, odometry of this stamp as fast as it can be put, each one a
    // decision, and the people of the same stamp again every 50 ms (kept fresh).
    let flooding = Arc::new(AtomicBool::new(true));
    let flood = {
        let (flooder, flooding) = (session(&served.endpoint), flooding.clone());
        std::thread::spawn(move || {
            let publisher = flooder.declare_publisher("odom").wait().unwrap();
            let bytes = odometry(t_s);
            let mut n = 0u64;
            let mut people_at = Instant::now();
            while flooding.load(Ordering::Relaxed) {
                if people_at.elapsed() > Duration::from_millis(50) {
                    flooder.put("people", people(t_s)).wait().unwrap();
                    people_at = Instant::now();
                }
                publisher.put(bytes.clone()).wait().unwrap();
                n += 1;
            }
            n
        })
    };
    // Still driving under the flood, then a goal in another frame: refused, a stop.
    assert!(served.first(Duration::from_secs(2), moving).is_some());
    std::thread::sleep(Duration::from_millis(300));
    while served.cmd.try_recv().is_ok() {}
    let sent = Instant::now();
    // (Another stamp: the same goal again would be no new goal.)
    served.put("goal_pose", goal("map", t_s));
    // Every command from two periods after it on is a stop (the policy may stop by itself
    // too: what counts is that it no longer drives).
    let mut last_moving = None;
    while let Ok((at, t)) = served.cmd.recv_timeout(Duration::from_secs(1)) {
        if at - sent > Duration::from_secs(1) {
            break;
        }
        if moving(&t) {
            last_moving = Some(at - sent);
        }
    }
    flooding.store(false, Ordering::Relaxed);
    let n = flood.join().unwrap();
    let summary = served.finish();
    eprintln!(
        "{n} odometry messages in the flood; {} decisions, {} replaced before read; the last command that moves {last_moving:?} after the goal",
        summary.counters.decisions, summary.replaced_inputs,
    );
    assert!(summary.replaced_inputs > 0, "no flood: {summary:?}");
    assert!(
        last_moving.is_none_or(|t| t < 2 * PERIOD),
        "still driving {last_moving:?} after a goal in another frame"
    );
    assert!(summary.counters.refused_goals > 0, "{summary:?}");
}
