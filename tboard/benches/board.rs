//! What the TensorBoard files cost a training run per RL episode: one `metrics.jsonl` line
//! appended and taken in by `RunBoard::poll` (read, parsed, mapped to its points, framed and
//! written), on a log that already holds `n` episodes; and one live metrics message of the
//! learner (`RunBoard::live`). `cargo bench -p tboard --bench board`.

use std::io::Write;

use criterion::{criterion_group, criterion_main, Criterion};
use proto::{Metrics, Role, SenderId};
use tboard::{Mode, RunBoard};

fn line(e: u64) -> String {
    format!(
        "{{\"phase\":\"rl\",\"episode\":{e},\"epsilon\":0.41,\"outcome\":\"reach-goal\",\"steps\":57,\"return_sum\":0.61,\"loss\":0.0123,\"success_rate_window\":0.8,\"collision_rate_window\":0.1,\"timeout_rate_window\":0.1,\"policy_version\":{e},\"env_steps\":{},\"replay_size\":100000,\"wall_s\":{},\"actor\":{},\"actor_episode\":{}}}\n",
        e * 57,
        e as f64 * 0.25,
        e % 2,
        e / 2
    )
}

fn bench(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("metrics.jsonl");
    let mut f = std::fs::File::create(&log).unwrap();
    for e in 0..10_000 {
        f.write_all(line(e).as_bytes()).unwrap();
    }
    let mut board = RunBoard::open(dir.path(), Mode::Distributed).unwrap();
    let mut e = 10_000;
    c.bench_function("one RL line appended and polled", |b| {
        b.iter(|| {
            f.write_all(line(e).as_bytes()).unwrap();
            e += 1;
            board.poll().unwrap();
        })
    });
    let learner = SenderId::new(Role::Learner, 0);
    let mut m = Metrics {
        episodes: e,
        wall_time_s: 1.0,
        values: [
            ("imitation_done", 1.0),
            ("updates_per_episode", 8.0),
            ("policy_lag_mean", 1.2),
            ("policy_lag_max", 3.0),
            ("actors_alive", 2.0),
        ]
        .map(|(k, v)| (k.to_string(), v))
        .into(),
        ..Default::default()
    };
    c.bench_function("one live learner message", |b| {
        b.iter(|| {
            m.episodes += 1;
            board.live(learner, &m).unwrap();
        })
    });
    // A resumed run's rebuild: a 10,000-episode log read and written anew.
    let resumed = tempfile::tempdir().unwrap();
    let text: String = (0..10_000).map(line).collect();
    std::fs::write(resumed.path().join("metrics.jsonl"), text).unwrap();
    c.bench_function("rebuild of a 10,000-episode run", |b| {
        b.iter(|| RunBoard::open(resumed.path(), Mode::Distributed).unwrap())
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
