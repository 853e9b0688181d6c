//! Network tests: sizes, agreement of the three forward implementations (fast, dfdx, f64
//! reference), attention, determinism, and dfdx gradients against finite differences.

use dfdx::prelude::Cpu;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::graph::{mse_loss_and_grad, values_dfdx};
use crate::{reference, LstmRlConfig, NetConfig, SarlConfig, Scratch, StateBatch, ValueNet};

/// Plausible robot-centric joint states `(B, N, 13)`: the robot part repeated in every row.
pub(crate) fn random_states(b: usize, n: usize, seed: u64) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::with_capacity(b * n * 13);
    for _ in 0..b {
        let robot = [
            rng.gen_range(0.0..8.0f32),
            1.0,
            rng.gen_range(-3.1..3.1f32),
            0.3,
            rng.gen_range(-1.0..1.0f32),
            rng.gen_range(-1.0..1.0f32),
        ];
        for _ in 0..n {
            let (px, py) = (rng.gen_range(-5.0..5.0f32), rng.gen_range(-5.0..5.0f32));
            out.extend_from_slice(&robot);
            out.extend_from_slice(&[
                px,
                py,
                rng.gen_range(-1.0..1.0f32),
                rng.gen_range(-1.0..1.0f32),
                0.3,
                (px * px + py * py).sqrt(),
                0.6,
            ]);
        }
    }
    out
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

fn nets() -> Vec<ValueNet> {
    vec![
        ValueNet::new(NetConfig::sarl(), 7).unwrap(),
        ValueNet::new(NetConfig::lstm_rl(), 7).unwrap(),
    ]
}

#[test]
fn built_networks_have_crowdnav_parameter_counts() {
    assert_eq!(
        ValueNet::new(NetConfig::sarl(), 0).unwrap().num_params(),
        96_502
    );
    assert_eq!(
        ValueNet::new(NetConfig::lstm_rl(), 0).unwrap().num_params(),
        46_851
    );
}

#[test]
fn init_is_pytorch_default_uniform_and_seeded() {
    let a = ValueNet::new(NetConfig::sarl(), 42).unwrap();
    let b = ValueNet::new(NetConfig::sarl(), 42).unwrap();
    let c = ValueNet::new(NetConfig::sarl(), 43).unwrap();
    assert_eq!(a.params(), b.params());
    assert_ne!(a.params(), c.params());
    for spec in a.layout().specs() {
        let vals = &a.params()[spec.range()];
        let bound = spec.init_bound as f32;
        assert!(vals.iter().all(|v| v.abs() <= bound), "{}", spec.name);
        // Uniform on (−b, b): the largest magnitude is close to b for big tensors.
        if vals.len() >= 100 {
            let max = vals.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            assert!(max > 0.9 * bound, "{}: max {max} bound {bound}", spec.name);
        }
    }
    let mlp1 = a.layout().get("mlp1.0.weight").unwrap();
    assert!((mlp1.init_bound - 1.0 / 13f64.sqrt()).abs() < 1e-12);
    let lstm = ValueNet::new(NetConfig::lstm_rl(), 0).unwrap();
    let ih = lstm.layout().get("lstm.bias_hh_l0").unwrap();
    assert!((ih.init_bound - 1.0 / 50f64.sqrt()).abs() < 1e-12);
}

#[test]
fn fast_dfdx_and_reference_forward_agree() {
    let dev = Cpu::default();
    for (b, n) in [(1, 1), (7, 5), (51, 10)] {
        let data = random_states(b, n, 3);
        let states = StateBatch::new(&data, b, n).unwrap();
        for net in nets() {
            let fast = net.values(states);
            let (graph, _) = values_dfdx(&net, &dev, states);
            let p64: Vec<f64> = net.params().iter().map(|&v| v as f64).collect();
            let (reference, _) = reference::forward(net.config(), &p64, &data, b, n);
            let reference: Vec<f32> = reference.iter().map(|&v| v as f32).collect();
            let kind = net.kind().name();
            assert!(
                max_abs_diff(&fast, &graph) <= 1e-5,
                "{kind} {b}x{n}: fast vs dfdx"
            );
            assert!(
                max_abs_diff(&fast, &reference) <= 1e-5,
                "{kind} {b}x{n}: fast vs ref"
            );
            assert!(
                fast.iter().any(|v| v.abs() > 1e-3),
                "{kind}: trivial outputs"
            );
        }
    }
}

#[test]
fn forward_is_deterministic() {
    let data = random_states(51, 10, 1);
    let states = StateBatch::new(&data, 51, 10).unwrap();
    for net in nets() {
        let again = ValueNet::new(net.config().clone(), 7).unwrap();
        let mut scratch = Scratch::default();
        let mut out = vec![0.0; 51];
        net.values_into(states, &mut scratch, &mut out);
        assert_eq!(out, again.values(states));
        // Reusing the scratch gives the same bits.
        let mut out2 = vec![0.0; 51];
        net.values_into(states, &mut scratch, &mut out2);
        assert_eq!(out, out2);
    }
}

#[test]
fn attention_weights_sum_to_one_and_match() {
    let dev = Cpu::default();
    let net = ValueNet::new(NetConfig::sarl(), 5).unwrap();
    let (b, n) = (9, 6);
    let data = random_states(b, n, 11);
    let states = StateBatch::new(&data, b, n).unwrap();
    let mut scratch = Scratch::default();
    let mut out = vec![0.0; b];
    net.values_into(states, &mut scratch, &mut out);
    let att = net.attention(&scratch).unwrap().to_vec();
    assert_eq!(att.len(), b * n);
    for row in att.chunks_exact(n) {
        let sum: f32 = row.iter().sum();
        assert!((sum - 1.0).abs() < 1e-5, "row sums to {sum}");
        assert!(row.iter().all(|&w| w > 0.0));
    }
    let (_, graph_att) = values_dfdx(&net, &dev, states);
    assert!(max_abs_diff(&att, &graph_att.unwrap()) < 1e-6);
    let p64: Vec<f64> = net.params().iter().map(|&v| v as f64).collect();
    let (_, ref_att) = reference::forward(net.config(), &p64, &data, b, n);
    let ref_att: Vec<f32> = ref_att.iter().map(|&v| v as f32).collect();
    assert!(max_abs_diff(&att, &ref_att) < 1e-6);
    // Not uniform: the weights depend on the humans.
    assert!(att.iter().any(|&w| (w - 1.0 / n as f32).abs() > 1e-3));
    assert!(ValueNet::new(NetConfig::lstm_rl(), 0)
        .unwrap()
        .attention(&scratch)
        .is_none());
}

#[test]
fn masked_softmax_follows_crowdnav_and_is_safe() {
    let mut w = [0.0f32; 3];
    crate::fast::masked_softmax(&[1.0, 0.0, 2.0], &mut w);
    let e = [1f32.exp(), 0.0, 2f32.exp()];
    let s: f32 = e.iter().sum();
    for (got, want) in w.iter().zip(e.iter().map(|v| v / s)) {
        assert!((got - want).abs() < 1e-6);
    }
    // Scores too large for exp without the shift.
    crate::fast::masked_softmax(&[1000.0, 999.0, -5.0], &mut w);
    assert!(w.iter().all(|v| v.is_finite()));
    assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    // All masked: uniform rather than CrowdNav's 0/0.
    crate::fast::masked_softmax(&[0.0, 0.0, 0.0], &mut w);
    assert_eq!(w, [1.0 / 3.0; 3]);
}

#[test]
fn bad_inputs_are_errors() {
    assert!(StateBatch::new(&[0.0; 26], 1, 3).is_err());
    assert!(StateBatch::new(&[], 0, 3).is_err());
    let mut net = ValueNet::new(NetConfig::sarl(), 0).unwrap();
    assert!(net.set_params(&[0.0; 10]).is_err());
    let mut bad = net.params().to_vec();
    bad[5] = f32::NAN;
    assert!(net.set_params(&bad).is_err());
    assert!(ValueNet::from_params(NetConfig::lstm_rl(), vec![0.0; 3]).is_err());
}

/// dfdx gradients against central finite differences of the f64 reference loss, on a few
/// parameters of every tensor. Fails if any backward op is wrong.
fn check_gradients(config: NetConfig, b: usize, n: usize) {
    let dev = Cpu::default();
    let mut net = ValueNet::new(config, 21).unwrap();
    // Sharpen SARL's attention so that its layers get gradients well above rounding noise.
    let mut p = net.params().to_vec();
    for spec in net
        .layout()
        .specs()
        .iter()
        .filter(|s| s.name.starts_with("attention"))
    {
        p[spec.range()].iter_mut().for_each(|v| *v *= 4.0);
    }
    net.set_params(&p).unwrap();
    let data = random_states(b, n, 5);
    let states = StateBatch::new(&data, b, n).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let targets: Vec<f32> = (0..b).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let mut grad = vec![0.0; net.num_params()];
    let loss = mse_loss_and_grad(&net, &dev, states, &targets, &mut grad).unwrap();

    let p64: Vec<f64> = net.params().iter().map(|&v| v as f64).collect();
    let ref_loss = reference::mse(net.config(), &p64, &data, b, n, &targets);
    assert!(
        (loss as f64 - ref_loss).abs() < 1e-5 * ref_loss.max(1.0),
        "loss {loss} vs {ref_loss}"
    );

    let h = 1e-6;
    let mut checked = Vec::new();
    for spec in net.layout().specs() {
        for _ in 0..6 {
            let i = spec.offset + rng.gen_range(0..spec.len());
            let mut p = p64.clone();
            p[i] += h;
            let up = reference::mse(net.config(), &p, &data, b, n, &targets);
            p[i] -= 2.0 * h;
            let down = reference::mse(net.config(), &p, &data, b, n, &targets);
            checked.push((
                spec.name.clone(),
                i,
                (up - down) / (2.0 * h),
                grad[i] as f64,
            ));
        }
    }
    let scale = checked.iter().fold(0.0f64, |m, c| m.max(c.2.abs()));
    assert!(scale > 1e-3, "gradients too small to test: {scale}");
    // Per tensor: a relative tolerance plus a floor for f32 rounding at that tensor's scale.
    let mut nontrivial = 0;
    for spec in net.layout().specs() {
        let mine: Vec<_> = checked.iter().filter(|c| c.0 == spec.name).collect();
        let scale_t = mine.iter().fold(0.0f64, |m, c| m.max(c.2.abs()));
        for (name, i, fd, g) in &mine {
            let tol = 2e-3 * fd.abs().max(g.abs()) + 1e-4 * scale_t + 1e-9;
            assert!(
                (fd - g).abs() <= tol,
                "{name}[{i}]: dfdx {g:e} vs finite difference {fd:e}"
            );
            if fd.abs() > 1e-6 * scale {
                nontrivial += 1;
            }
        }
        // The score bias cancels in the softmax: its gradient is exactly zero.
        let score_bias =
            spec.name.starts_with("attention") && spec.name.ends_with("bias") && spec.rows == 1;
        assert!(
            scale_t > 1e-7 || score_bias,
            "{}: gradient scale {scale_t:e}",
            spec.name
        );
    }
    assert!(
        nontrivial * 2 > checked.len(),
        "only {nontrivial}/{} non-trivial",
        checked.len()
    );
    // Every tensor but the score bias receives some gradient.
    for spec in net
        .layout()
        .specs()
        .iter()
        .filter(|s| !(s.name.starts_with("attention") && s.rows == 1 && s.cols == 1))
    {
        assert!(
            grad[spec.range()].iter().any(|&g| g != 0.0),
            "{} has no gradient",
            spec.name
        );
    }
}

#[test]
fn sarl_gradients_match_finite_differences() {
    check_gradients(NetConfig::sarl(), 3, 4);
}

#[test]
fn lstm_gradients_match_finite_differences() {
    check_gradients(NetConfig::lstm_rl(), 3, 3);
}

#[test]
fn small_configs_work_on_every_path() {
    let dev = Cpu::default();
    let sarl = NetConfig::Sarl(SarlConfig {
        mlp1_dims: vec![8],
        mlp2_dims: vec![5],
        attention_dims: vec![1],
        mlp3_dims: vec![4, 1],
    });
    let lstm = NetConfig::LstmRl(LstmRlConfig {
        hidden_dim: 4,
        mlp_dims: vec![1],
    });
    for config in [sarl, lstm] {
        let net = ValueNet::new(config.clone(), 1).unwrap();
        let data = random_states(4, 3, 2);
        let states = StateBatch::new(&data, 4, 3).unwrap();
        let (graph, _) = values_dfdx(&net, &dev, states);
        assert!(max_abs_diff(&net.values(states), &graph) < 1e-5);
        check_gradients(config, 2, 3);
    }
}

/// The training path splits a batch over threads, one dfdx graph per part, and adds the parts'
/// gradients: the result must be the whole-batch gradient (up to float reassociation), for any
/// thread count, and the same bits again for the same thread count.
#[test]
fn sharded_gradients_equal_the_whole_batch_gradient() {
    use crate::graph::{shard_count, sharded_loss_and_grad};
    use std::sync::Arc;
    for config in [NetConfig::sarl(), NetConfig::lstm_rl()] {
        let net = ValueNet::new(config, 3).unwrap();
        let (b, n) = (100, 7);
        let data = random_states(b, n, 11);
        let states = StateBatch::new(&data, b, n).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let targets: Vec<f32> = (0..b).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let mut whole = vec![0.0; net.num_params()];
        let loss = mse_loss_and_grad(&net, &Cpu::default(), states, &targets, &mut whole).unwrap();
        let flat = Arc::new(net.params().to_vec());
        let scale = whole.iter().fold(0.0f32, |m, g| m.max(g.abs()));
        assert!(scale > 1e-4, "gradient too small to compare: {scale}");
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let run = || {
                pool.install(|| {
                    assert_eq!(shard_count(b), threads, "{threads} threads");
                    let mut shards = Vec::new();
                    let mut g = vec![0.0; net.num_params()];
                    let l =
                        sharded_loss_and_grad(&net, &flat, &mut shards, states, &targets, &mut g)
                            .unwrap();
                    (l, g)
                })
            };
            let (l, g) = run();
            assert!(
                (l - loss).abs() <= 1e-5 * loss.abs().max(1.0),
                "loss {l} vs {loss}"
            );
            for (i, (a, w)) in g.iter().zip(&whole).enumerate() {
                assert!(
                    (a - w).abs() <= 1e-4 * scale,
                    "{threads} threads: gradient[{i}] {a:e} vs whole batch {w:e}"
                );
            }
            let (l2, g2) = run();
            assert_eq!(l.to_bits(), l2.to_bits());
            assert!(g.iter().zip(&g2).all(|(a, b)| a.to_bits() == b.to_bits()));
        }
    }
}
