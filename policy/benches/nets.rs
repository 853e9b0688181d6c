//! Network benchmarks: one decision (51 actions × 10 humans through SARL), one learner update
//! (batch 100 × 10 humans: target forward, forward, backward, Adam), and a 512³ matrix product
//! as the core's FP32 reference peak, all single-threaded, in one run. After criterion, a report
//! with the ratios is printed.
//!
//! `RAYON_NUM_THREADS` is set to 1 unless given: dfdx hands its matrix products to `gemm` with
//! `rayon::current_num_threads()` threads; the inference path never threads.

use std::hint::black_box;
use std::time::Instant;

use criterion::Criterion;
use policy::optim::AdamConfig;
use policy::train::Trainer;
use policy::{NetConfig, NetKind, Scratch, StateBatch, ValueNet};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const ACTIONS: usize = 51;
const HUMANS: usize = 10;
const BATCH: usize = 100;
/// CrowdNav's SARL, 10 humans, one decision on this kind of machine (issue 3).
const CROWDNAV_DECISION_MS: f64 = 136.0;

fn states(b: usize, n: usize, seed: u64) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::with_capacity(b * n * 13);
    for _ in 0..b {
        let robot = [
            rng.gen_range(0.0..8.0),
            1.0,
            rng.gen_range(-3.0..3.0),
            0.3,
            0.5,
            0.1,
        ];
        for _ in 0..n {
            let (px, py): (f32, f32) = (rng.gen_range(-5.0..5.0), rng.gen_range(-5.0..5.0));
            out.extend_from_slice(&robot);
            out.extend_from_slice(&[px, py, 0.3, -0.2, 0.3, (px * px + py * py).sqrt(), 0.6]);
        }
    }
    out
}

/// Matrix-product multiply-accumulates of one forward pass as this crate computes it (see
/// `fast.rs`: attention layer 0 split, mlp2's last layer after the pooling).
fn performed_forward_macs(config: &NetConfig, b: usize, n: usize) -> f64 {
    let chain = |inp: usize, dims: &[usize]| -> usize {
        let mut prev = inp;
        dims.iter()
            .map(|&d| {
                let m = prev * d;
                prev = d;
                m
            })
            .sum()
    };
    let (b, r) = (b as f64, (b * n) as f64);
    match config {
        NetConfig::Sarl(c) => {
            let d_e = *c.mlp1_dims.last().unwrap();
            let n2 = c.mlp2_dims.len();
            let d_z = if n2 > 1 { c.mlp2_dims[n2 - 2] } else { d_e };
            let d_h = c.mlp2_dims[n2 - 1];
            let d_a0 = c.attention_dims[0];
            r * (chain(13, &c.mlp1_dims)
                + d_e * d_a0
                + chain(d_a0, &c.attention_dims[1..])
                + chain(d_e, &c.mlp2_dims[..n2 - 1])
                + d_z) as f64
                + b * (d_e * d_a0 + d_z * d_h + chain(6 + d_h, &c.mlp3_dims)) as f64
        }
        NetConfig::LstmRl(c) => {
            let h = c.hidden_dim;
            r * (4 * h * 13) as f64
                + (r - b) * (4 * h * h) as f64
                + b * chain(6 + h, &c.mlp_dims) as f64
        }
    }
}

fn gemm_512(a: &[f32], b: &[f32], c: &mut [f32]) {
    let n = 512;
    // SAFETY: all three buffers hold 512×512 values, row-major, and do not overlap.
    unsafe {
        gemm::gemm(
            n,
            n,
            n,
            c.as_mut_ptr(),
            1,
            n as isize,
            false,
            a.as_ptr(),
            1,
            n as isize,
            b.as_ptr(),
            1,
            n as isize,
            0.0,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

struct Setup {
    decision: Vec<f32>,
    batch: Vec<f32>,
    next_batch: Vec<f32>,
    rewards: Vec<f32>,
    discounts: Vec<f32>,
}

impl Setup {
    fn new() -> Self {
        Self {
            decision: states(ACTIONS, HUMANS, 1),
            batch: states(BATCH, HUMANS, 2),
            next_batch: states(BATCH, HUMANS, 3),
            rewards: vec![0.01; BATCH],
            discounts: vec![0.9f32.powf(0.25); BATCH],
        }
    }

    fn trainer(&self, kind: NetKind) -> Trainer {
        let config = match kind {
            NetKind::Sarl => NetConfig::sarl(),
            NetKind::LstmRl => NetConfig::lstm_rl(),
        };
        Trainer::new(
            ValueNet::new(config, 0).expect("valid config"),
            AdamConfig::with_lr(1e-4),
        )
    }

    fn update(&self, t: &mut Trainer) -> f32 {
        let s = StateBatch::new(&self.batch, BATCH, HUMANS).expect("shape");
        let s2 = StateBatch::new(&self.next_batch, BATCH, HUMANS).expect("shape");
        t.td_step(s, s2, &self.rewards, &self.discounts)
            .expect("finite")
    }
}

fn benches(c: &mut Criterion, setup: &Setup) {
    let decision = StateBatch::new(&setup.decision, ACTIONS, HUMANS).expect("shape");
    for kind in [NetKind::Sarl, NetKind::LstmRl] {
        let net = setup.trainer(kind).online().clone();
        let mut scratch = Scratch::default();
        let mut out = vec![0.0; ACTIONS];
        c.bench_function(&format!("{}_values_51x10", kind.name()), |b| {
            b.iter(|| net.values_into(black_box(decision), &mut scratch, &mut out))
        });
        let mut trainer = setup.trainer(kind);
        c.bench_function(&format!("{}_learner_update_100x10", kind.name()), |b| {
            b.iter(|| setup.update(&mut trainer))
        });
    }
    let (a, bm, mut cm) = (
        vec![0.5f32; 512 * 512],
        vec![0.25f32; 512 * 512],
        vec![0.0f32; 512 * 512],
    );
    c.bench_function("gemm_f32_512x512x512", |b| {
        b.iter(|| gemm_512(&a, &bm, &mut cm))
    });
}

/// This thread's CPU time in ns (Linux `schedstat`), to see through contention on a shared
/// machine.
fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Per call of `f` over `reps` timed blocks of `inner` calls: (median wall s, median thread CPU s).
fn median_secs(reps: usize, inner: usize, mut f: impl FnMut()) -> (f64, f64) {
    for _ in 0..inner {
        f();
    }
    let mut wall = Vec::with_capacity(reps);
    let mut cpu = Vec::with_capacity(reps);
    for _ in 0..reps {
        let (s, c) = (Instant::now(), thread_cpu_ns());
        for _ in 0..inner {
            f();
        }
        wall.push(s.elapsed().as_secs_f64() / inner as f64);
        if let (Some(c0), Some(c1)) = (c, thread_cpu_ns()) {
            cpu.push((c1 - c0) as f64 * 1e-9 / inner as f64);
        }
    }
    wall.sort_by(f64::total_cmp);
    cpu.sort_by(f64::total_cmp);
    (
        wall[reps / 2],
        cpu.get(cpu.len() / 2).copied().unwrap_or(f64::NAN),
    )
}

fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_owned())
        })
        .unwrap_or_else(|| "unknown".to_owned())
}

fn report(setup: &Setup) {
    let decision = StateBatch::new(&setup.decision, ACTIONS, HUMANS).expect("shape");
    let (a, b, mut c) = (
        vec![0.5f32; 512 * 512],
        vec![0.25f32; 512 * 512],
        vec![0.0f32; 512 * 512],
    );
    let flop_512 = 2.0 * 512f64.powi(3);
    let (w, cpu) = median_secs(15, 5, || gemm_512(&a, &b, &mut c));
    let (peak, peak_cpu) = (flop_512 / w / 1e9, flop_512 / cpu / 1e9);
    println!("\n=== policy network report (wall-clock median; thread CPU time in brackets) ===");
    println!(
        "machine: {} | nproc {} | RAYON_NUM_THREADS={} | load average {}",
        cpu_model(),
        std::thread::available_parallelism().map_or(0, |n| n.get()),
        std::env::var("RAYON_NUM_THREADS").unwrap_or_default(),
        std::fs::read_to_string("/proc/loadavg")
            .unwrap_or_default()
            .trim()
    );
    println!(
        "FP32 reference peak, gemm 512x512x512 on 1 thread: {peak:.1} GFLOP/s [{peak_cpu:.1}]"
    );
    for kind in [NetKind::Sarl, NetKind::LstmRl] {
        let mut trainer = setup.trainer(kind);
        let net = trainer.online().clone();
        let config = net.config().clone();
        let mut scratch = Scratch::default();
        let mut out = vec![0.0; ACTIONS];
        let (t, tc) = median_secs(21, 100, || {
            net.values_into(decision, &mut scratch, &mut out)
        });
        let flop = 2.0 * performed_forward_macs(&config, ACTIONS, HUMANS);
        let extra = if kind == NetKind::Sarl {
            format!(
                " | target <= 1.5 ms, aim 1 ms | CrowdNav {CROWDNAV_DECISION_MS} ms -> {:.0}x [{:.0}x]",
                CROWDNAV_DECISION_MS / (t * 1e3),
                CROWDNAV_DECISION_MS / (tc * 1e3)
            )
        } else {
            String::new()
        };
        println!(
            "{:8} network part of one decision (51 x 10): {:.3} ms [{:.3}] | {:.1} GFLOP/s [{:.1}]{extra}",
            kind.name(),
            t * 1e3,
            tc * 1e3,
            flop / t / 1e9,
            flop / tc / 1e9,
        );
        for _ in 0..50 {
            setup.update(&mut trainer);
        }
        let (t, tc) = median_secs(15, 10, || {
            black_box(setup.update(&mut trainer));
        });
        // Target forward + forward + backward (two products per forward product).
        let fwd = performed_forward_macs(&config, BATCH, HUMANS);
        let flop = 2.0 * 4.0 * fwd;
        let crowdnav_flop = 2.0 * 4.0 * config.forward_macs(BATCH, HUMANS) as f64;
        println!(
            "{:8} learner update (100 x 10): {:.2} ms [{:.2}] | {:.0} samples/s [{:.0}] | {:.1} GFLOP/s [{:.1}] \
             = {:.0}% [{:.0}%] of peak (target >= 40%) | {:.0} MFLOP counted, {:.0} in CrowdNav's formulation",
            kind.name(),
            t * 1e3,
            tc * 1e3,
            BATCH as f64 / t,
            BATCH as f64 / tc,
            flop / t / 1e9,
            flop / tc / 1e9,
            100.0 * flop / t / 1e9 / peak,
            100.0 * flop / tc / 1e9 / peak_cpu,
            flop / 1e6,
            crowdnav_flop / 1e6,
        );
    }
}

/// CPU time of every thread of this process in ns (sum of `/proc/self/task/*/schedstat`).
fn process_cpu_ns() -> u64 {
    let Ok(dir) = std::fs::read_dir("/proc/self/task") else {
        return 0;
    };
    dir.filter_map(|e| {
        std::fs::read_to_string(e.ok()?.path().join("schedstat"))
            .ok()?
            .split_whitespace()
            .next()?
            .parse::<u64>()
            .ok()
    })
    .sum()
}

/// `FSRL_NETS_PROFILE=<seconds>`: only learner updates as the schedule runs them ([`Trainer::fit`]
/// on cached targets), SARL then LSTM-RL, for `perf record` and quick before/after figures:
/// median wall and main-thread CPU time per update, and all threads' CPU per update.
fn profile(secs: f64, setup: &Setup) {
    let kinds: Vec<NetKind> = match std::env::var("FSRL_NETS_PROFILE_NET").as_deref() {
        Ok("sarl") => vec![NetKind::Sarl],
        Ok("lstm-rl") => vec![NetKind::LstmRl],
        _ => vec![NetKind::Sarl, NetKind::LstmRl],
    };
    let s = StateBatch::new(&setup.batch, BATCH, HUMANS).expect("shape");
    let targets = vec![0.1f32; BATCH];
    for kind in kinds {
        let mut trainer = setup.trainer(kind);
        let inner = 20;
        let reps = ((secs / 0.01 / inner as f64) as usize).max(5);
        let p0 = process_cpu_ns();
        let (w, c) = median_secs(reps, inner, || {
            black_box(trainer.fit(s, &targets).expect("finite"));
        });
        let all = (process_cpu_ns() - p0) as f64 * 1e-9 / ((reps + 1) * inner) as f64;
        println!(
            "profile {:8} fit (100 x 10): {:.3} ms wall, {:.3} ms main-thread CPU, {:.3} ms all-threads CPU (RAYON_NUM_THREADS={})",
            kind.name(),
            w * 1e3,
            c * 1e3,
            all * 1e3,
            std::env::var("RAYON_NUM_THREADS").unwrap_or_default()
        );
    }
}

fn main() {
    if let Some(secs) = std::env::var("FSRL_NETS_PROFILE")
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
    {
        if std::env::var_os("RAYON_NUM_THREADS").is_none() {
            std::env::set_var("RAYON_NUM_THREADS", "1");
        }
        profile(secs, &Setup::new());
        return;
    }
    if std::env::var_os("RAYON_NUM_THREADS").is_none() {
        // Before rayon's global pool exists: single-threaded dfdx matrix products.
        std::env::set_var("RAYON_NUM_THREADS", "1");
    }
    let setup = Setup::new();
    let mut c = Criterion::default()
        .sample_size(20)
        .warm_up_time(std::time::Duration::from_secs(1))
        .measurement_time(std::time::Duration::from_secs(3))
        .configure_from_args();
    benches(&mut c, &setup);
    c.final_summary();
    report(&setup);
}
