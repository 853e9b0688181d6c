//! Transport benchmarks (one run, so the ratios are meaningful):
//!
//! * `batch_throughput/*`: episode batches (45 steps, 10 humans) published by an actor and
//!   received by the learner, pipelined; one element = one batch. `typed_pub_sub` includes
//!   encoding, decoding and validation (what the roles do); `raw_bytes` sends the same encoded
//!   bytes without the codec (the transport alone). `memcpy` is the ceiling: a plain
//!   in-process copy of the same encoded bytes.
//! * `weights_latency/*`: a SARL weight blob (96 502 f32) published by the learner until every
//!   one of 3 subscribers (2 actors + evaluator, each its own transport) holds the decoded
//!   weights. Criterion reports the mean; p50 and p99 over 300 broadcasts are printed.
//!
//! zenoh runs peer-to-peer over TCP loopback (separate sessions in one process); iceoryx2 runs
//! its shared-memory data plane (zenoh loopback only for telemetry, not exercised here).

use std::hint::black_box;
use std::net::TcpListener;
use std::sync::mpsc;
use std::sync::{Arc, Barrier};
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use proto::{fixtures, keys, RunId, SenderId, TransitionBatch};
use transport::{DataPlane, Transport, TransportConfig, ZenohConfig};

const WAIT: Duration = Duration::from_secs(30);

struct Net {
    run: RunId,
    plane: DataPlane,
    endpoint: String,
    prefix: String,
}

impl Net {
    fn new(plane: DataPlane) -> Self {
        let id: u64 = rand::random();
        let port = TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .expect("free port");
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

fn batch_throughput(c: &mut Criterion) {
    let batch = fixtures::episode(45, 10, 0);
    let header = proto::Header::new::<TransitionBatch>(fixtures::run(), SenderId::actor(0), 0, 1);
    let bytes = proto::encode(&header, &batch).expect("encode");
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

    for plane in [DataPlane::Zenoh, DataPlane::Iceoryx2] {
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
        g.bench_function(BenchmarkId::new("typed_pub_sub", name(plane)), |b| {
            b.iter_custom(|iters| {
                std::thread::scope(|s| {
                    let start = Arc::new(Barrier::new(2));
                    let start2 = Arc::clone(&start);
                    let sub = &sub;
                    let receiver = s.spawn(move || {
                        start2.wait();
                        for _ in 0..iters {
                            let m = sub.recv_timeout(WAIT).expect("recv").expect("batch");
                            black_box(m);
                        }
                        Instant::now()
                    });
                    start.wait();
                    let t0 = Instant::now();
                    for _ in 0..iters {
                        publisher.publish(1, &batch).expect("publish");
                    }
                    let t1 = receiver.join().expect("receiver");
                    t1 - t0
                })
            })
        });
        // The same bytes without encode/decode: what the transport itself costs.
        g.bench_function(BenchmarkId::new("raw_bytes", name(plane)), |b| {
            b.iter_custom(|iters| {
                std::thread::scope(|s| {
                    let start = Arc::new(Barrier::new(2));
                    let start2 = Arc::clone(&start);
                    let sub = &sub;
                    let receiver = s.spawn(move || {
                        start2.wait();
                        for _ in 0..iters {
                            let n = sub
                                .recv_bytes_timeout(WAIT, |b| b.len())
                                .expect("recv")
                                .expect("batch");
                            black_box(n);
                        }
                        Instant::now()
                    });
                    start.wait();
                    let t0 = Instant::now();
                    for _ in 0..iters {
                        publisher.publish_raw(bytes.clone()).expect("publish");
                    }
                    let t1 = receiver.join().expect("receiver");
                    t1 - t0
                })
            })
        });
    }
    g.finish();
}

fn weights_latency(c: &mut Criterion) {
    let mut g = c.benchmark_group("weights_latency");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(5));
    for plane in [DataPlane::Zenoh, DataPlane::Iceoryx2] {
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
        let wp = learner
            .latest_publisher(&keys::weights(&net.run))
            .expect("publisher");
        let weights: Vec<_> = (0..2).map(fixtures::sarl_weights).collect();
        let (tx, rx) = mpsc::channel::<(u64, Instant)>();
        let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let mut threads = Vec::new();
        for t in &subscribers {
            let ws = t
                .latest_subscriber(&keys::weights(&net.run))
                .expect("subscriber");
            let tx = tx.clone();
            let stop = Arc::clone(&stop);
            threads.push(std::thread::spawn(move || {
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    if let Some(m) = ws.next(Duration::from_millis(100)).expect("next") {
                        let _ = tx.send((m.header.seq, Instant::now()));
                    }
                }
            }));
        }
        assert!(wp.wait_for_subscribers(WAIT).expect("matching"));
        let n_subs = subscribers.len();
        // One broadcast: publish, then wait until every subscriber holds this version.
        let broadcast = |i: u64| -> Duration {
            let w = &weights[(i % 2) as usize];
            let t0 = Instant::now();
            let seq = wp.publish(i, w).expect("publish");
            let mut last = t0;
            let mut got = 0;
            while got < n_subs {
                let (s, t) = rx.recv_timeout(WAIT).expect("subscriber got weights");
                if s == seq {
                    got += 1;
                    last = last.max(t);
                }
            }
            last - t0
        };
        let mut i = 0u64;
        // Percentiles over 300 broadcasts.
        let mut lat: Vec<Duration> = (0..300)
            .map(|_| {
                i += 1;
                broadcast(i)
            })
            .collect();
        lat.sort();
        let pct = |p: f64| lat[((lat.len() as f64 * p) as usize).min(lat.len() - 1)];
        eprintln!(
            "weights_latency/{}: {} broadcasts of {} params to {} subscribers: p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms",
            name(plane),
            lat.len(),
            weights[0].params.len(),
            n_subs,
            pct(0.50).as_secs_f64() * 1e3,
            pct(0.99).as_secs_f64() * 1e3,
            lat[lat.len() - 1].as_secs_f64() * 1e3,
        );
        g.bench_function(BenchmarkId::new("put_to_all_3_hold", name(plane)), |b| {
            b.iter_custom(|iters| {
                (0..iters)
                    .map(|_| {
                        i += 1;
                        broadcast(i)
                    })
                    .sum()
            })
        });
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        for t in threads {
            let _ = t.join();
        }
    }
    g.finish();
}

criterion_group!(benches, batch_throughput, weights_latency);
criterion_main!(benches);
