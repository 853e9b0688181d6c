//! Test-only reference: CrowdNav's forward passes transcribed literally (per row, no rewrites),
//! in f64, on an f64 copy of the flat weights. Used to check both the dfdx graph and the fast
//! path, and as the function for finite-difference gradient checks.

use crate::config::{NetConfig, ParamLayout};
use crate::{FEATURE_DIM, ROBOT_DIM};

fn linear(layout: &ParamLayout, p: &[f64], block: &str, k: usize, x: &[f64]) -> Vec<f64> {
    let w = layout
        .get(&format!("{block}.{}.weight", 2 * k))
        .expect("weight");
    let b = layout
        .get(&format!("{block}.{}.bias", 2 * k))
        .expect("bias");
    assert_eq!(w.cols, x.len());
    (0..w.rows)
        .map(|r| {
            let row = &p[w.offset + r * w.cols..w.offset + (r + 1) * w.cols];
            p[b.offset + r] + row.iter().zip(x).map(|(a, v)| a * v).sum::<f64>()
        })
        .collect()
}

/// CrowdNav `mlp(in, dims, last_relu)`.
fn mlp(
    layout: &ParamLayout,
    p: &[f64],
    block: &str,
    layers: usize,
    last_relu: bool,
    x: &[f64],
) -> Vec<f64> {
    let mut x = x.to_vec();
    for k in 0..layers {
        x = linear(layout, p, block, k, &x);
        if last_relu || k + 1 < layers {
            x.iter_mut().for_each(|v| *v = v.max(0.0));
        }
    }
    x
}

fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// Values `(B)` and, for SARL, attention weights `(B·N)`.
pub(crate) fn forward(
    config: &NetConfig,
    p: &[f64],
    data: &[f32],
    b: usize,
    n: usize,
) -> (Vec<f64>, Vec<f64>) {
    let layout = config.layout();
    let rows: Vec<Vec<f64>> = data
        .chunks_exact(FEATURE_DIM)
        .map(|r| r.iter().map(|&v| v as f64).collect())
        .collect();
    let mut values = Vec::with_capacity(b);
    let mut attention = Vec::new();
    for s in 0..b {
        let sample = &rows[s * n..(s + 1) * n];
        let robot = &sample[0][..ROBOT_DIM];
        let feature = match config {
            NetConfig::Sarl(c) => {
                let e: Vec<Vec<f64>> = sample
                    .iter()
                    .map(|x| mlp(&layout, p, "mlp1", c.mlp1_dims.len(), true, x))
                    .collect();
                let h: Vec<Vec<f64>> = e
                    .iter()
                    .map(|x| mlp(&layout, p, "mlp2", c.mlp2_dims.len(), false, x))
                    .collect();
                let d_e = e[0].len();
                let mean: Vec<f64> = (0..d_e)
                    .map(|j| e.iter().map(|r| r[j]).sum::<f64>() / n as f64)
                    .collect();
                let scores: Vec<f64> = e
                    .iter()
                    .map(|ei| {
                        let inp: Vec<f64> = ei.iter().chain(&mean).copied().collect();
                        mlp(&layout, p, "attention", c.attention_dims.len(), false, &inp)[0]
                    })
                    .collect();
                // exp(s)·[s ≠ 0] / Σ exp(s)·[s ≠ 0], no max subtraction, as CrowdNav.
                let ex: Vec<f64> = scores
                    .iter()
                    .map(|&s| if s != 0.0 { s.exp() } else { 0.0 })
                    .collect();
                let sum: f64 = ex.iter().sum();
                let w: Vec<f64> = ex.iter().map(|v| v / sum).collect();
                let d_h = h[0].len();
                let pooled: Vec<f64> = (0..d_h)
                    .map(|j| w.iter().zip(&h).map(|(wi, hi)| wi * hi[j]).sum())
                    .collect();
                attention.extend(w);
                pooled
            }
            NetConfig::LstmRl(c) => {
                let hd = c.hidden_dim;
                let get = |name: &str| layout.get(name).expect("lstm tensor").clone();
                let (w_ih, w_hh, b_ih, b_hh) = (
                    get("lstm.weight_ih_l0"),
                    get("lstm.weight_hh_l0"),
                    get("lstm.bias_ih_l0"),
                    get("lstm.bias_hh_l0"),
                );
                let mut h = vec![0.0; hd];
                let mut cell = vec![0.0; hd];
                for x in sample {
                    let gates: Vec<f64> = (0..4 * hd)
                        .map(|r| {
                            let wi = &p[w_ih.offset + r * FEATURE_DIM
                                ..w_ih.offset + (r + 1) * FEATURE_DIM];
                            let wh = &p[w_hh.offset + r * hd..w_hh.offset + (r + 1) * hd];
                            p[b_ih.offset + r]
                                + p[b_hh.offset + r]
                                + wi.iter().zip(x).map(|(a, v)| a * v).sum::<f64>()
                                + wh.iter().zip(&h).map(|(a, v)| a * v).sum::<f64>()
                        })
                        .collect();
                    for j in 0..hd {
                        let (i, f) = (sigmoid(gates[j]), sigmoid(gates[hd + j]));
                        let (g, o) = (gates[2 * hd + j].tanh(), sigmoid(gates[3 * hd + j]));
                        cell[j] = f * cell[j] + i * g;
                        h[j] = o * cell[j].tanh();
                    }
                }
                h
            }
        };
        let joint: Vec<f64> = robot.iter().chain(&feature).copied().collect();
        let (block, layers) = match config {
            NetConfig::Sarl(c) => ("mlp3", c.mlp3_dims.len()),
            NetConfig::LstmRl(c) => ("mlp", c.mlp_dims.len()),
        };
        values.push(mlp(&layout, p, block, layers, false, &joint)[0]);
    }
    (values, attention)
}

/// `mean_b (V(s_b) − y_b)²` in f64.
pub(crate) fn mse(
    config: &NetConfig,
    p: &[f64],
    data: &[f32],
    b: usize,
    n: usize,
    targets: &[f32],
) -> f64 {
    let (v, _) = forward(config, p, data, b, n);
    v.iter()
        .zip(targets)
        .map(|(v, &y)| (v - y as f64).powi(2))
        .sum::<f64>()
        / b as f64
}
