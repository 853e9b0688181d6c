//! `fsrl serve` under floods, against the real process over loopback (multicast scouting off),
//! each test bounded in time and its processes killed however it ends:
//!
//! - 10,000 queries a second on `fsrl/serve/<name>/act` and 1,000 people messages a second
//!   while the robot drives, then its odometry stops: the zero command must go out within two
//!   control periods of the last odometry, with the reason "odometry is stale", and the
//!   server's resident memory (`VmRSS`) stay under 100 MB throughout; the queries beyond the
//!   queue are refused and counted;
//! - a `cmd_vel` subscriber that never reads (its link's buffers full, as its socket's queues
//!   show, its own queries' replies piling up): the commands to the robot keep their period and
//!   the stop still goes out in time;
//! - two askers that never read their replies, behind `fsrl router` with the robot and the
//!   server (the router stuck forwarding replies to them): the server still reads the robot's
//!   inputs (no stale stop while they come) and the robot receives the stop in time.
//!
//! All run the server with the default staleness ([`serve::control::DEFAULT_STALE_PERIODS`]):
//! the promise is a zero command within two periods of the last input with the default flags.
//! Run alone: `cargo test --release --test serve_flood`.

mod net_support;
mod serve_support;

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use net_support::free_port;
use serve::msg::Twist;
use serve_support::{
    goal, moving, now_s, odometry, people, rss_mb, session, tcp_queues, zero, Robot, Served,
};
use zenoh::Wait;

/// The shipped model's control period.
const PERIOD: Duration = Duration::from_millis(250);
/// The most resident memory the server may use under a flood.
const MAX_RSS_MB: f64 = 100.0;

/// A valid query: the robot, its goal and 5 people.
fn request() -> Vec<u8> {
    use proto::serve::{ActRequest, GoalObs, HumanObs, RobotObs};
    ActRequest {
        robot: RobotObs {
            x_m: 0.0,
            y_m: -4.0,
            vx_mps: 0.0,
            vy_mps: 0.5,
            heading_rad: std::f64::consts::FRAC_PI_2,
        },
        goal: GoalObs { x_m: 0.0, y_m: 4.0 },
        humans: (0..5)
            .map(|i| HumanObs::walking(1.0 + i as f64, -1.0 + 0.5 * i as f64, -0.5, 0.0))
            .collect(),
        steps: 0,
    }
    .encode()
}

/// Runs `each` `per_s` times a second (in bursts every millisecond) until `stop`; how many.
fn at_rate(per_s: u64, stop: &AtomicBool, mut each: impl FnMut()) -> u64 {
    let start = Instant::now();
    let mut sent = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let due = (start.elapsed().as_secs_f64() * per_s as f64) as u64;
        while sent < due {
            each();
            sent += 1;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    sent
}

/// Samples the server's resident memory every 50 ms until `stop`; the largest.
fn rss_watch(pid: u32, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<f64> {
    std::thread::spawn(move || {
        let mut max = 0.0f64;
        while !stop.load(Ordering::Relaxed) {
            max = max.max(rss_mb(pid));
            std::thread::sleep(Duration::from_millis(50));
        }
        max
    })
}

/// The robot's inputs fed at 20 Hz (stamped now) until its odometry stops, then its people
/// only, until `stop`.
struct RobotInputs {
    odometry_stops: Arc<AtomicBool>,
    last_odometry: mpsc::Receiver<Instant>,
    thread: std::thread::JoinHandle<()>,
}

impl RobotInputs {
    fn start(robot: zenoh::Session, stop: Arc<AtomicBool>) -> Self {
        let odometry_stops = Arc::new(AtomicBool::new(false));
        let (last_tx, last_odometry) = mpsc::channel();
        let thread = {
            let odometry_stops = odometry_stops.clone();
            std::thread::spawn(move || {
                let mut last = None;
                while !stop.load(Ordering::Relaxed) {
                    let t = now_s();
                    let _ = robot.put("people", people("odom", t, 5)).wait();
                    if !odometry_stops.load(Ordering::Relaxed) {
                        let _ = robot.put("odom", odometry(t)).wait();
                        last = Some(Instant::now());
                    } else if let Some(at) = last.take() {
                        let _ = last_tx.send(at);
                    }
                    std::thread::sleep(Duration::from_millis(50));
                }
            })
        };
        Self {
            odometry_stops,
            last_odometry,
            thread,
        }
    }

    /// Stops the odometry (the people go on); the instant the last one was put.
    fn stop_odometry(&self) -> Instant {
        self.odometry_stops.store(true, Ordering::Relaxed);
        self.last_odometry
            .recv_timeout(Duration::from_secs(5))
            .unwrap()
    }
}

/// The first command satisfying `pred` received after `after`, within `within`.
fn first_after(
    cmd: &mpsc::Receiver<(Instant, Twist)>,
    after: Instant,
    within: Duration,
    pred: impl Fn(&Twist) -> bool,
) -> Option<Instant> {
    let deadline = Instant::now() + within;
    while let Ok((at, t)) = cmd.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
        if at > after && pred(&t) {
            return Some(at);
        }
    }
    None
}

/// The value of `name=` in a log line (0 when it is not there).
fn field(line: &str, name: &str) -> u64 {
    serve_support::summary_field(line, name).unwrap_or(0)
}

#[test]
fn under_a_query_and_people_flood_the_stop_goes_out_within_two_periods_and_memory_stays_bounded() {
    let port = free_port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut serve = Served::shipped(port, &["--name", "flood"]);
    let robot = Robot::connect(&endpoint);
    robot.put("goal_pose", goal("odom", now_s()));
    robot.until("driving before the flood", || robot.fresh(), moving);

    let stop = Arc::new(AtomicBool::new(false));
    let rss = rss_watch(serve.pid(), stop.clone());
    let inputs = RobotInputs::start(robot.session.clone(), stop.clone());

    // 10,000 queries a second from one peer, 1,000 people messages a second from another.
    let replies = Arc::new(AtomicU64::new(0));
    let queries = {
        let (stop, replies, endpoint) = (stop.clone(), replies.clone(), endpoint.clone());
        std::thread::spawn(move || {
            let s = session(&endpoint);
            let key = proto::keys::serve_act("flood").unwrap();
            let payload = request();
            let started = Instant::now();
            let n = at_rate(10_000, &stop, || {
                let replies = replies.clone();
                let _ = s
                    .get(&key)
                    .payload(payload.clone())
                    .timeout(Duration::from_secs(1))
                    .callback(move |_| {
                        replies.fetch_add(1, Ordering::Relaxed);
                    })
                    .wait();
            });
            n as f64 / started.elapsed().as_secs_f64()
        })
    };
    let crowd = {
        let (stop, endpoint) = (stop.clone(), endpoint.clone());
        std::thread::spawn(move || {
            let s = session(&endpoint);
            let publisher = s.declare_publisher("people").wait().unwrap();
            let started = Instant::now();
            let n = at_rate(1_000, &stop, || {
                let _ = publisher.put(people("odom", now_s(), 5)).wait();
            });
            n as f64 / started.elapsed().as_secs_f64()
        })
    };

    // Under the flood the robot still drives.
    std::thread::sleep(Duration::from_millis(1500));
    robot.drain();
    let flood_on = Instant::now();
    assert!(
        first_after(&robot.cmd, flood_on, Duration::from_secs(2), moving).is_some(),
        "no driving command under the flood"
    );
    // The odometry stops; the flood goes on. The stop asked about below is the one for this
    // odometry, not a zero command from before the first odometry arrived (a fresh-clone CI run
    // logged "no odometry received yet" at start-up, and the test read that one).
    serve.skip_log();
    let last = inputs.stop_odometry();
    let stopped_at = first_after(&robot.cmd, last, Duration::from_secs(5), zero);
    std::thread::sleep(Duration::from_secs(2));
    stop.store(true, Ordering::Relaxed);
    let query_rate = queries.join().unwrap();
    let people_rate = crowd.join().unwrap();
    let max_rss = rss.join().unwrap();
    inputs.thread.join().unwrap();

    let latency = stopped_at.map(|t| t - last);
    eprintln!(
        "flood: {query_rate:.0} queries/s ({} replies), {people_rate:.0} people messages/s; \
         zero command {latency:?} after the last odometry; max VmRSS {max_rss:.1} MB",
        replies.load(Ordering::Relaxed)
    );
    assert!(
        query_rate >= 9_000.0,
        "the queries came at {query_rate:.0}/s"
    );
    assert!(people_rate >= 900.0, "people came at {people_rate:.0}/s");
    let latency = latency.expect("no zero command after the odometry stopped");
    assert!(
        latency < 2 * PERIOD,
        "the zero command went out {latency:?} after the last odometry"
    );
    assert!(
        max_rss > 0.0 && max_rss < MAX_RSS_MB,
        "VmRSS {max_rss:.1} MB"
    );
    // Its reason, and the queries refused and counted.
    assert!(
        serve
            .next_stop_reason(Duration::from_secs(5))
            .contains("odometry is stale"),
        "the first stop is not for stale odometry"
    );
    // The refusals are counted in the exit summary (below). Not waited for in the log: it says
    // them at powers of two of the count, and the lines before the odometry stopped were passed
    // over, so the next one came after 5 s or not, by the machine's speed (a streak of
    // tools/test.sh runs failed here).
    let status = serve.terminate();
    assert!(status.success(), "{status:?}");
    let summary = serve.wait_log("stopped", Duration::from_secs(5));
    let (answered, refused) = (
        field(&summary, "queries"),
        field(&summary, "refused_queries"),
    );
    eprintln!("flood: {answered} queries answered, {refused} refused");
    assert!(answered > 0 && refused > 0, "{summary}");
}

/// Bytes in a socket queue that say a link is congested (the stuck peers' receive buffers are
/// 4 KiB, the server's send buffer as small).
const CONGESTED_BYTES: u64 = 1024;

/// Samples the TCP queues on `port` every 20 ms until `stop`: the most bytes a peer's socket
/// to `port` held unread, and the most a socket of `port` held unsent.
fn congestion_watch(port: u16, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<(u64, u64)> {
    std::thread::spawn(move || {
        let (mut unread, mut unsent) = (0, 0);
        while !stop.load(Ordering::Relaxed) {
            for q in tcp_queues(port) {
                if q.remote_port == port {
                    unread = unread.max(q.rx_bytes);
                } else {
                    unsent = unsent.max(q.tx_bytes);
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        (unread, unsent)
    })
}

/// A session that subscribes to `cmd_vel` and never reads it: its callback blocks until the
/// returned sender is dropped, so its link stops reading and its socket buffers (small, by the
/// endpoint's `so_rcvbuf`) fill; it also asks queries whose replies pile up on that link.
fn stuck_subscriber(
    endpoint: &str,
) -> (
    zenoh::Session,
    zenoh::pubsub::Subscriber<()>,
    mpsc::Sender<()>,
) {
    let cfg = transport::ZenohConfig::peer(vec![], vec![format!("{endpoint}#so_rcvbuf=4096")])
        .to_zenoh(1 << 20)
        .unwrap();
    let s = zenoh::open(cfg).wait().unwrap();
    let (release, gate) = mpsc::channel::<()>();
    let gate = std::sync::Mutex::new(gate);
    let sub = s
        .declare_subscriber("cmd_vel")
        .callback(move |_| {
            // Never returns while the test runs.
            let _ = gate.lock().map(|g| g.recv());
        })
        .wait()
        .unwrap();
    (s, sub, release)
}

/// The robot in lockstep (`--trigger odometry`, a simulator's clock): each command answered by
/// the next step's people and odometry at once, so commands flow as fast as the policy
/// decides (~1,000 a second) and a link that does not read them fills within a second or two.
#[test]
fn a_cmd_vel_subscriber_that_never_reads_cannot_stall_the_loop() {
    let port = free_port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    // Small send buffers on the server's side, so a link that does not read fills quickly.
    let mut serve = Served::start(
        std::path::Path::new(&serve_support::model_path()),
        &format!("{endpoint}#so_sndbuf=4096"),
        &["--name", "stuck", "--trigger", "odometry", "--use-sim-time"],
    );
    let robot = Robot::connect(&endpoint);
    let mut t_s = 1000.0;
    robot.put("goal_pose", goal("odom", t_s));
    let step = |robot: &Robot, t_s: &mut f64| {
        *t_s += 0.25;
        robot.put("people", people("odom", *t_s, 5));
        robot.put("odom", odometry(*t_s));
    };
    robot.until("driving", || step(&robot, &mut t_s), moving);

    let stop = Arc::new(AtomicBool::new(false));
    let rss = rss_watch(serve.pid(), stop.clone());
    let (stuck, stuck_sub, release) = stuck_subscriber(&endpoint);
    let asking = {
        let stop = stop.clone();
        let s = stuck.clone();
        std::thread::spawn(move || {
            let key = proto::keys::serve_act("stuck").unwrap();
            let payload = request();
            at_rate(2_000, &stop, || {
                let _ = s
                    .get(&key)
                    .payload(payload.clone())
                    .timeout(Duration::from_secs(1))
                    .callback(|_| {})
                    .wait();
            })
        })
    };

    // For 5 s, step as fast as the commands come; the longest wait for one. Meanwhile the
    // socket queues of the server's port: what the stuck peer has not read, what the server
    // could not send.
    let congestion = congestion_watch(port, stop.clone());
    robot.drain();
    let watch_from = Instant::now();
    let (mut steps, mut max_gap) = (0u64, Duration::ZERO);
    while watch_from.elapsed() < Duration::from_secs(5) {
        let asked = Instant::now();
        step(&robot, &mut t_s);
        let got = robot.cmd.recv_timeout(Duration::from_secs(2));
        max_gap = max_gap.max(asked.elapsed());
        if got.is_err() {
            break;
        }
        steps += 1;
        while robot.cmd.try_recv().is_ok() {}
    }
    // Then the inputs stop: the watchdog's zero command.
    let last = Instant::now();
    let stopped_at = first_after(&robot.cmd, last, Duration::from_secs(5), zero);
    stop.store(true, Ordering::Relaxed);
    let asked = asking.join().unwrap();
    let max_rss = rss.join().unwrap();
    let (unread, unsent) = congestion.join().unwrap();
    drop(release);
    drop(stuck_sub);

    let latency = stopped_at.map(|t| t - last);
    eprintln!(
        "stuck subscriber: {steps} lockstep steps in 5 s, the longest wait for a command \
         {max_gap:?}; zero command {latency:?} after the last input; {asked} queries from the \
         stuck peer; max VmRSS {max_rss:.1} MB; at most {unread} bytes unread by a peer, \
         {unsent} unsent by the server"
    );
    // The link really was congested: the stuck peer's socket full of what it did not read, the
    // server's send queue to it holding what the peer's window would not take.
    assert!(
        unread >= CONGESTED_BYTES && unsent >= CONGESTED_BYTES,
        "no congestion: {unread} bytes unread, {unsent} unsent"
    );
    assert!(
        max_gap < 2 * PERIOD,
        "a command took {max_gap:?} ({steps} steps in 5 s)"
    );
    let latency = latency.expect("no zero command after the inputs stopped");
    assert!(
        latency < 2 * PERIOD,
        "the zero command went out {latency:?} after the last input"
    );
    assert!(
        max_rss > 0.0 && max_rss < MAX_RSS_MB,
        "VmRSS {max_rss:.1} MB"
    );
    let status = serve.terminate();
    assert!(status.success(), "{status:?}");
    drop(stuck);
}

/// An asker behind the router at `endpoint` that never reads: its replies' callback blocks
/// until the process ends, so its link stops reading (its socket buffer 4 KiB); it asks
/// `per_s` queries a second, counted in `asked`, until the process ends.
fn stuck_asker(endpoint: &str, name: &str, per_s: u64, asked: Arc<AtomicU64>) {
    let c = transport::ZenohConfig::client(format!("{endpoint}#so_rcvbuf=4096"));
    let s = zenoh::open(c.to_zenoh(1 << 20).unwrap()).wait().unwrap();
    let key = proto::keys::serve_act(name).unwrap();
    std::thread::spawn(move || {
        let payload = request();
        let never = AtomicBool::new(false);
        at_rate(per_s, &never, || {
            let _ = s
                .get(&key)
                .payload(payload.clone())
                .timeout(Duration::from_secs(10))
                .callback(|_| std::thread::park())
                .wait();
            asked.fetch_add(1, Ordering::Relaxed);
        });
    });
}

/// The environment variable that names the router [`stuck_askers_process`] connects to.
const ASKERS_ROUTER: &str = "FSRL_TEST_STUCK_ASKERS_ROUTER";

/// Not a test of its own: the process of the two stuck askers of the router test, run by it
/// (this test binary again). Their blocked callbacks hold zenoh's receiving threads, which every
/// session of a process shares (two by default): in the test's own process they would stall the
/// robot's session too, whatever the server and the router do. Asks until its stdin closes,
/// then prints how many queries it asked.
#[test]
#[ignore = "the stuck askers' process, run by the router test"]
fn stuck_askers_process() {
    let Ok(router) = std::env::var(ASKERS_ROUTER) else {
        return;
    };
    let asked = Arc::new(AtomicU64::new(0));
    for _ in 0..2 {
        stuck_asker(&router, "askers", 1_000, asked.clone());
    }
    println!("asking");
    let _ = std::io::Read::read_to_end(&mut std::io::stdin(), &mut Vec::new());
    println!("asked {}", asked.load(Ordering::Relaxed));
    // The sessions are not closed: their callbacks never return.
    std::process::exit(0);
}

/// Starts [`stuck_askers_process`] on the router at `endpoint`; the process and its output's
/// lines.
fn stuck_askers(endpoint: &str) -> (net_support::Reaped, mpsc::Receiver<String>) {
    use std::io::BufRead;
    let mut c = std::process::Command::new(std::env::current_exe().unwrap())
        .args([
            "stuck_askers_process",
            "--exact",
            "--ignored",
            "--nocapture",
        ])
        .env(ASKERS_ROUTER, endpoint)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = c.stdout.take().unwrap();
    let (tx, lines) = mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
        {
            let _ = tx.send(line);
        }
    });
    let askers = net_support::Reaped(c);
    let deadline = Instant::now() + Duration::from_secs(30);
    while lines.recv_timeout(deadline.saturating_duration_since(Instant::now()))
        != Ok("asking".into())
    {
        assert!(Instant::now() < deadline, "the stuck askers did not start");
    }
    (askers, lines)
}

/// A client of the router at `endpoint` (no listening, multicast scouting off).
fn router_client(endpoint: &str) -> zenoh::Session {
    let c = transport::ZenohConfig::client(endpoint.to_string());
    zenoh::open(c.to_zenoh(8 << 20).unwrap()).wait().unwrap()
}

/// Two askers that never read their replies, behind `fsrl router` with the robot and a server
/// of default flags (but `--connect`): the router, stuck forwarding replies toward the askers,
/// must not hold back the server's inputs nor its commands. What the robot sees is asserted:
/// no stale stop while its inputs come, and, once its odometry stops, the zero command
/// received within two control periods of the last odometry (the input turns stale at 1.5
/// periods, [`serve::control::DEFAULT_STALE_PERIODS`]: the last half period is the loop's and
/// the transport's, as in the other floods here).
#[test]
fn askers_that_never_read_behind_a_router_cannot_hold_back_the_robots_inputs_or_its_stop() {
    // `fsrl router` on loopback, plain TCP, no access control (the test's own), with small
    // send buffers, so that a link that does not read fills within the test.
    let dir = tempfile::tempdir().unwrap();
    let router_port = free_port();
    let router = format!("tcp/127.0.0.1:{router_port}");
    let config = dir.path().join("router.json5");
    std::fs::write(
        &config,
        format!(
            "{{ mode: \"router\", listen: {{ endpoints: [\"{router}#so_sndbuf=4096\"] }}, \
             scouting: {{ multicast: {{ enabled: false }} }} }}"
        ),
    )
    .unwrap();
    let _router = net_support::Reaped(
        std::process::Command::new(env!("CARGO_BIN_EXE_fsrl"))
            .args(["router", "--config"])
            .arg(&config)
            .stdin(std::process::Stdio::null())
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap(),
    );
    let deadline = Instant::now() + Duration::from_secs(30);
    while std::net::TcpStream::connect(("127.0.0.1", router_port)).is_err() {
        assert!(Instant::now() < deadline, "fsrl router did not listen");
        std::thread::sleep(Duration::from_millis(50));
    }
    // The server connects to the router, its flags the default otherwise.
    let mut serve = Served::shipped(free_port(), &["--name", "askers", "--connect", &router]);
    let robot = Robot::with_session(router_client(&router));
    robot.put("goal_pose", goal("odom", now_s()));
    robot.until("driving before the askers", || robot.fresh(), moving);

    let stop = Arc::new(AtomicBool::new(false));
    let inputs = RobotInputs::start(robot.session.clone(), stop.clone());
    let congestion = congestion_watch(router_port, stop.clone());
    let (mut askers, asker_lines) = stuck_askers(&router);
    // 4 s of both askers stuck while the robot's inputs come fresh: no stale stop.
    serve.skip_log();
    std::thread::sleep(Duration::from_secs(4));
    let mut stale = Vec::new();
    while let Ok(line) = serve.log.try_recv() {
        if line.contains("is stale") || line.contains("people data stopped") {
            stale.push(line);
        }
    }
    // Then the odometry stops: the robot receives the zero command in time.
    let last = inputs.stop_odometry();
    let stopped_at = first_after(&robot.cmd, last, Duration::from_secs(5), zero);
    stop.store(true, Ordering::Relaxed);
    inputs.thread.join().unwrap();
    let (unread, unsent) = congestion.join().unwrap();
    drop(askers.0.stdin.take());
    let asked = asker_lines
        .recv_timeout(Duration::from_secs(10))
        .unwrap_or_default();
    let latency = stopped_at.map(|t| t - last);
    eprintln!(
        "stuck askers: {asked} queries; at most {unread} bytes unread by a client of the \
         router, {unsent} unsent by it; the zero command received {latency:?} after the last \
         odometry; stale stops while the inputs came: {stale:?}"
    );
    assert!(
        unread >= CONGESTED_BYTES && unsent >= CONGESTED_BYTES,
        "no congestion: {unread} bytes unread, {unsent} unsent"
    );
    assert!(stale.is_empty(), "the inputs were held back: {stale:?}");
    let latency = latency.expect("the robot received no zero command after its odometry stopped");
    assert!(
        latency < 2 * PERIOD,
        "the robot received the zero command {latency:?} after its last odometry"
    );
    let stop_reason = serve.next_stop_reason(Duration::from_secs(5));
    assert!(stop_reason.contains("odometry is stale"), "{stop_reason}");
    let status = serve.terminate();
    assert!(status.success(), "{status:?}");
    // The askers' queries did reach the queryable (answered or refused, counted).
    let summary = serve.wait_log("stopped", Duration::from_secs(5));
    assert!(
        field(&summary, "queries") + field(&summary, "refused_queries") > 0,
        "no query reached the server: {summary}"
    );
}
