//! Transport benchmarks. Criterion's statistics first, then a report that measures the targets
//! of issue 4 in one run, in interleaved rounds (zenoh, iceoryx2, zenoh, ...), so that the
//! ratios compare like with like on a noisy machine:
//!
//! * `batch_throughput/*`: episode batches (45 steps, 10 humans) published by an actor and
//!   received by the learner, pipelined; one element = one batch. `typed_pub_sub` includes
//!   encoding, decoding and validation (what the roles do); `raw_bytes` sends the same encoded
//!   bytes without the codec (the transport alone). `memcpy` is the ceiling: a plain
//!   in-process copy of the same encoded bytes.
//! * `weights_latency/*`: a SARL weight blob (96 502 f32) published by the learner until every
//!   one of 3 subscribers (2 actors + evaluator, each its own transport) holds the decoded
//!   weights. Criterion reports the mean; the report gives p50 and p99 over 3000 broadcasts.
//!
//! zenoh runs peer-to-peer over TCP loopback (separate sessions in one process); iceoryx2 runs
//! its shared-memory data plane (zenoh loopback only for telemetry, not exercised here).
//! `cargo bench -p transport --bench transport -- report` runs the report alone.

use std::hint::black_box;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Barrier};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use criterion::{BenchmarkId, Criterion, Throughput};
use proto::{fixtures, keys, RunId, SenderId, TransitionBatch, Weights};
use transport::{
    DataPlane, LatestPublisher, Publisher, Subscriber, Transport, TransportConfig, ZenohConfig,
};

const WAIT: Duration = Duration::from_secs(30);
const PLANES: [DataPlane; 2] = [DataPlane::Zenoh, DataPlane::Iceoryx2];

struct Net {
    run: RunId,
    plane: DataPlane,
    endpoint: String,
    prefix: String,
}

impl Net {
    fn new(plane: DataPlane) -> Self {
        let id: u64 = rand::random();
        let port = testkit::free_port();
        Self {
            run: RunId::new(format!("bench{id:016x}")).expect("run id"),
            plane,
            endpoint: format!("tcp/127.0.0.1:{port}"),
            prefix: format!("fsrlb{id:016x}_"),
        }
    }

    fn open(&self, sender: SenderId, hub: bool) -> Transport {
        let mut c = TransportConfig::new(self.run.clone(), sender);
        c.data_plane = self.plane;
        c.iceoryx2.prefix = Some(self.prefix.clone());
        c.iceoryx2.max_processes = 8;
        c.zenoh = if hub {
            ZenohConfig::peer(vec![self.endpoint.clone()], vec![])
        } else {
            ZenohConfig::peer(vec!["tcp/127.0.0.1:0".into()], vec![self.endpoint.clone()])
        };
        Transport::open(c).expect("open transport")
    }
}

fn name(plane: DataPlane) -> &'static str {
    match plane {
        DataPlane::Zenoh => "zenoh",
        DataPlane::Iceoryx2 => "iceoryx2",
    }
}

/// An actor's transitions publisher and the learner's subscriber on one backend.
struct Pipe {
    plane: DataPlane,
    batch: TransitionBatch,
    bytes: Vec<u8>,
    sub: Subscriber<TransitionBatch>,
    publisher: Publisher<TransitionBatch>,
    _transports: [Transport; 2],
}

impl Pipe {
    fn new(plane: DataPlane, batch: &TransitionBatch, bytes: &[u8]) -> Self {
        let net = Net::new(plane);
        let learner = net.open(SenderId::learner(), true);
        let actor = net.open(SenderId::actor(0), false);
        let sub = learner
            .subscriber(&keys::all_transitions(&net.run))
            .expect("subscriber");
        let publisher = actor
            .publisher(&keys::transitions(&net.run, 0))
            .expect("publisher");
        assert!(publisher.wait_for_subscribers(WAIT).expect("matching"));
        Self {
            plane,
            batch: batch.clone(),
            bytes: bytes.to_vec(),
            sub,
            publisher,
            _transports: [learner, actor],
        }
    }

    /// Sends `n` batches while another thread receives them; the time until the last arrived.
    /// `typed`: encode, send, receive, decode and validate; else the encoded bytes as they are.
    fn round(&self, n: u64, typed: bool) -> Duration {
        std::thread::scope(|s| {
            let start = Arc::new(Barrier::new(2));
            let start2 = Arc::clone(&start);
            let (sub, plane) = (&self.sub, self.plane);
            let receiver = s.spawn(move || {
                start2.wait();
                for i in 0..n {
                    let got = if typed {
                        sub.recv_timeout(WAIT)
                            .expect("recv")
                            .map(|m| black_box(m).header.seq as usize)
                    } else {
                        sub.recv_bytes_timeout(WAIT, |b| black_box(b.len()))
                            .expect("recv")
                    };
                    assert!(
                        got.is_some(),
                        "{}: batch {i} of {n} (typed: {typed}) not received within {WAIT:?}",
                        name(plane)
                    );
                }
                Instant::now()
            });
            start.wait();
            let t0 = Instant::now();
            for _ in 0..n {
                if typed {
                    self.publisher.publish(1, &self.batch).expect("publish");
                } else {
                    self.publisher
                        .publish_raw(self.bytes.clone())
                        .expect("publish");
                }
            }
            receiver.join().expect("receiver") - t0
        })
    }
}

/// The learner's weights publisher and 3 subscribers (2 actors, the evaluator), each its own
/// transport and thread, reporting the time they hold each new version.
struct Broadcast {
    publisher: LatestPublisher<Weights>,
    weights: Vec<Weights>,
    arrivals: mpsc::Receiver<(u64, Instant)>,
    n_subs: usize,
    next: u64,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    _transports: Vec<Transport>,
}

impl Broadcast {
    fn new(plane: DataPlane) -> Self {
        let net = Net::new(plane);
        let learner = net.open(SenderId::learner(), true);
        let subscribers: Vec<Transport> = [
            SenderId::actor(0),
            SenderId::actor(1),
            SenderId::evaluator(0),
        ]
        .into_iter()
        .map(|s| net.open(s, false))
        .collect();
        let publisher = learner
            .latest_publisher(&keys::weights(&net.run))
            .expect("publisher");
        let (tx, arrivals) = mpsc::channel::<(u64, Instant)>();
        let stop = Arc::new(AtomicBool::new(false));
        let threads = subscribers
            .iter()
            .map(|t| {
                let ws = t
                    .latest_subscriber(&keys::weights(&net.run))
                    .expect("subscriber");
                let tx = tx.clone();
                let stop = Arc::clone(&stop);
                std::thread::spawn(move || {
                    while !stop.load(Ordering::Relaxed) {
                        if let Some(m) = ws.next(Duration::from_millis(100)).expect("next") {
                            let _ = tx.send((m.header.seq, Instant::now()));
                        }
                    }
                })
            })
            .collect();
        assert!(publisher.wait_for_subscribers(WAIT).expect("matching"));
        let n_subs = subscribers.len();
        let mut all = subscribers;
        all.push(learner);
        Self {
            publisher,
            weights: (0..2).map(fixtures::sarl_weights).collect(),
            arrivals,
            n_subs,
            next: 0,
            stop,
            threads,
            _transports: all,
        }
    }

    /// One broadcast: publish, then wait until every subscriber holds this version.
    fn once(&mut self) -> Duration {
        self.next += 1;
        let w = &self.weights[(self.next % 2) as usize];
        let t0 = Instant::now();
        let seq = self.publisher.publish(self.next, w).expect("publish");
        let mut last = t0;
        let mut got = 0;
        while got < self.n_subs {
            let (s, t) = self
                .arrivals
                .recv_timeout(WAIT)
                .expect("subscriber got weights");
            if s == seq {
                got += 1;
                last = last.max(t);
            }
        }
        last - t0
    }
}

impl Drop for Broadcast {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

fn episode_batch() -> (TransitionBatch, Vec<u8>) {
    let batch = fixtures::episode(45, 10, 0);
    let header = proto::Header::new::<TransitionBatch>(fixtures::run(), SenderId::actor(0), 0, 1);
    let bytes = proto::encode(&header, &batch).expect("encode");
    (batch, bytes)
}

fn batch_throughput(c: &mut Criterion) {
    let (batch, bytes) = episode_batch();
    eprintln!(
        "episode batch (45 steps, 10 humans): {} bytes encoded",
        bytes.len()
    );
    let mut g = c.benchmark_group("batch_throughput");
    g.throughput(Throughput::Elements(1));
    g.sample_size(20);
    g.measurement_time(Duration::from_secs(5));

    let mut dst = vec![0u8; bytes.len()];
    g.bench_function("memcpy", |b| {
        b.iter(|| {
            dst.copy_from_slice(black_box(&bytes));
            black_box(&dst);
        })
    });
    for plane in PLANES {
        let pipe = Pipe::new(plane, &batch, &bytes);
        g.bench_function(BenchmarkId::new("typed_pub_sub", name(plane)), |b| {
            b.iter_custom(|iters| pipe.round(iters, true))
        });
        // The same bytes without encode/decode: what the transport itself costs.
        g.bench_function(BenchmarkId::new("raw_bytes", name(plane)), |b| {
            b.iter_custom(|iters| pipe.round(iters, false))
        });
    }
    g.finish();
}

fn weights_latency(c: &mut Criterion) {
    let mut g = c.benchmark_group("weights_latency");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(5));
    for plane in PLANES {
        let mut bc = Broadcast::new(plane);
        g.bench_function(BenchmarkId::new("put_to_all_3_hold", name(plane)), |b| {
            b.iter_custom(|iters| (0..iters).map(|_| bc.once()).sum())
        });
    }
    g.finish();
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    sorted[((sorted.len() as f64 * p) as usize).min(sorted.len() - 1)]
}

fn verdict(met: bool) -> &'static str {
    if met {
        "met"
    } else {
        "MISSED"
    }
}

/// Issue 4's targets, measured in interleaved rounds within this run.
fn report() {
    const ROUNDS: usize = 7;
    const ROUND_S: f64 = 0.5;
    let (batch, bytes) = episode_batch();
    let mb = |rate: f64| rate * bytes.len() as f64 / 1e6;
    println!("\n== transport report (this run; rounds interleaved across backends) ==");

    // The ceiling: an in-process copy of the same bytes.
    let mut dst = vec![0u8; bytes.len()];
    let n_copy = 200_000u32;
    let t0 = Instant::now();
    for _ in 0..n_copy {
        dst.copy_from_slice(black_box(&bytes));
        black_box(&dst);
    }
    let memcpy = f64::from(n_copy) / t0.elapsed().as_secs_f64();

    let pipes: Vec<Pipe> = PLANES
        .iter()
        .map(|p| Pipe::new(*p, &batch, &bytes))
        .collect();
    // rates[typed][plane][round]; batches per round sized so that a round lasts ~ROUND_S.
    let mut rates = [[Vec::new(), Vec::new()], [Vec::new(), Vec::new()]];
    for (k, typed) in [false, true].into_iter().enumerate() {
        let sizes: Vec<u64> = pipes
            .iter()
            .map(|p| {
                let warm = p.round(2_000, typed);
                ((ROUND_S * 2_000.0 / warm.as_secs_f64()) as u64).max(2_000)
            })
            .collect();
        for _ in 0..ROUNDS {
            for (i, p) in pipes.iter().enumerate() {
                let t = p.round(sizes[i], typed);
                rates[k][i].push(sizes[i] as f64 / t.as_secs_f64());
            }
        }
    }
    drop(pipes);
    println!(
        "episode batches (45 steps, 10 humans, {} bytes), {ROUNDS} rounds of ~{ROUND_S} s per backend:",
        bytes.len()
    );
    println!(
        "  {:<42} {:>11.0} batches/s {:>8.0} MB/s",
        "in-process memcpy (ceiling)",
        memcpy,
        mb(memcpy)
    );
    let mut ratio = [0.0; 2];
    let mut zenoh_typed = 0.0;
    for (k, what) in ["transport alone", "encode + send + receive + decode"]
        .into_iter()
        .enumerate()
    {
        let per_round: Vec<f64> = rates[k][1]
            .iter()
            .zip(&rates[k][0])
            .map(|(iox, z)| iox / z)
            .collect();
        let lo = per_round.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = per_round.iter().copied().fold(0.0, f64::max);
        let med = [median(&mut rates[k][0]), median(&mut rates[k][1])];
        for (i, plane) in PLANES.iter().enumerate() {
            println!(
                "  {:<42} {:>11.0} batches/s {:>8.0} MB/s",
                format!("{}, {what}", name(*plane)),
                med[i],
                mb(med[i])
            );
        }
        ratio[k] = median(&mut per_round.clone());
        println!(
            "  iceoryx2 / zenoh, {what}: {:.2}x (median of rounds; min {lo:.2}x, max {hi:.2}x)",
            ratio[k]
        );
        if k == 1 {
            zenoh_typed = med[0];
        }
    }

    const BROADCASTS: usize = 3_000;
    const CHUNK: usize = 500;
    let mut bcs: Vec<Broadcast> = PLANES.iter().map(|p| Broadcast::new(*p)).collect();
    for bc in &mut bcs {
        for _ in 0..20 {
            bc.once();
        }
    }
    let mut lat = [Vec::new(), Vec::new()];
    for _ in 0..BROADCASTS / CHUNK {
        for (i, bc) in bcs.iter_mut().enumerate() {
            lat[i].extend((0..CHUNK).map(|_| bc.once()));
        }
    }
    drop(bcs);
    println!(
        "SARL weights ({} params) to 3 subscribers, {BROADCASTS} broadcasts per backend (put until all hold them):",
        fixtures::sarl_weights(0).params.len()
    );
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    let mut p99 = [Duration::ZERO; 2];
    for (i, plane) in PLANES.iter().enumerate() {
        lat[i].sort();
        p99[i] = percentile(&lat[i], 0.99);
        println!(
            "  {:<9} p50 {:.3} ms  p99 {:.3} ms  max {:.3} ms",
            name(*plane),
            ms(percentile(&lat[i], 0.50)),
            ms(p99[i]),
            ms(lat[i][lat[i].len() - 1])
        );
    }
    println!("targets:");
    println!(
        "  zenoh >= 20,000 batches/s (typed): {zenoh_typed:.0}/s, {}",
        verdict(zenoh_typed >= 20_000.0)
    );
    println!(
        "  iceoryx2 >= 5x zenoh (typed): {:.2}x, {}",
        ratio[1],
        verdict(ratio[1] >= 5.0)
    );
    println!(
        "  weights p99: zenoh <= 5 ms: {:.3} ms, {}; iceoryx2 <= 1 ms: {:.3} ms, {}",
        ms(p99[0]),
        verdict(p99[0] <= Duration::from_millis(5)),
        ms(p99[1]),
        verdict(p99[1] <= Duration::from_millis(1))
    );
}

/// Runs the report unless a filter names only criterion benchmarks.
fn wants_report() -> bool {
    let filters: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    filters.is_empty() || filters.iter().any(|f| "report".contains(f.as_str()))
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    batch_throughput(&mut c);
    weights_latency(&mut c);
    c.final_summary();
    if wants_report() {
        report();
    }
}
