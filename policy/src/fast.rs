//! Hand-written inference path: the same functions as the dfdx graphs in [`crate::graph`],
//! computed straight from the flat weights with `gemm` (single-threaded) and fused bias/ReLU.
//! Tests assert both agree to 1e-5. Where the CPU has AVX-512, SARL's layers run through the
//! packed kernels of [`crate::kernels::dense_packed`] instead (weights packed once per set of
//! weights, [`PackedSarl`]), which sum every element exactly as `gemm` does: the values are the
//! `gemm` path's bit for bit (`net::tests::packed_values_are_the_reference_ones`; issue 54),
//! leaving out the inputs a ReLU zeroed in every row of a register tile.
//!
//! Two exact rewrites of CrowdNav's SARL keep the work down (both are also used by the dfdx
//! graph, so training and inference compute the same function):
//! - the first attention layer on `[e_i, ē]` is split into `e_i W_Lᵀ + (ē W_Rᵀ + b)`: the mean
//!   half is computed once per sample instead of once per human;
//! - the last (linear) layer of `mlp2` commutes with the attention-weighted sum because the
//!   weights sum to one: `Σ_i w_i (z_i Wᵀ + b) = (Σ_i w_i z_i) Wᵀ + b`, so it runs once per sample.

use crate::batch::StateBatch;
use crate::config::{Linear, LstmIndex, Mat, SarlIndex};
use crate::kernels::{
    dense_packed, dot, gemm, packed_kernels, relu_inplace, PackedMat, Threads, View,
};
use crate::{FEATURE_DIM, ROBOT_DIM};

/// Reusable buffers for [`crate::ValueNet::values_into`]; also keeps the last attention weights.
#[derive(Default, Debug, Clone)]
pub struct Scratch {
    layers: Vec<Vec<f32>>,
    attention: Vec<f32>,
}

impl Scratch {
    /// Attention weights `(B, N)` of the last SARL forward pass.
    pub fn attention(&self) -> &[f32] {
        &self.attention
    }

    fn buffers(&mut self, n: usize) -> &mut [Vec<f32>] {
        if self.layers.len() < n {
            self.layers.resize_with(n, Vec::new);
        }
        &mut self.layers[..n]
    }
}

/// SARL's weight matrices packed for [`dense_packed`] (built once per set of weights, where
/// [`packed_kernels`] holds): every layer with at least two outputs and 3..=512 inputs, and
/// both halves of the first attention layer.
#[derive(Clone, Debug)]
pub(crate) struct PackedSarl {
    mats: Vec<(Mat, PackedMat)>,
}

impl PackedSarl {
    /// `None` where the packed kernels do not run.
    pub fn new(ix: &SarlIndex, p: &[f32]) -> Option<Self> {
        if !packed_kernels() {
            return None;
        }
        let d_e = ix.mlp1.last()?.out_dim();
        let att0 = ix.attention.first()?;
        let halves = [att0.w.cols(0, d_e), att0.w.cols(d_e, 2 * d_e)];
        let layers = ix
            .mlp1
            .iter()
            .chain(&ix.attention[1..])
            .chain(&ix.mlp2)
            .chain(&ix.mlp3)
            .map(|l| l.w)
            .chain(halves);
        let mats = layers
            .filter(|w| w.rows >= 2 && (3..=512).contains(&w.cols))
            .map(|w| (w, PackedMat::new(&p[w.offset..], w.ld, w.rows, w.cols)))
            .collect();
        Some(PackedSarl { mats })
    }

    /// Whether no layer was packed.
    #[cfg(test)]
    pub fn is_empty(&self) -> bool {
        self.mats.is_empty()
    }

    fn get(&self, w: Mat) -> Option<&PackedMat> {
        self.mats.iter().find(|(m, _)| *m == w).map(|(_, pm)| pm)
    }
}

/// `c (m × w.rows, dense) += a (m × w.cols, row stride lda) · wᵀ`, `w` read from `params`.
fn gemm_acc(m: usize, a: &[f32], lda: usize, w: Mat, params: &[f32], c: &mut [f32]) {
    let wt = View::transposed(&params[w.offset..], w.ld);
    gemm(
        m,
        w.rows,
        w.cols,
        c,
        w.rows,
        View::rows(a, lda),
        wt,
        true,
        Threads::One,
    );
}

/// `out` resized to `len` without writing it when it already has that length (the packed
/// kernels overwrite every value).
fn sized(out: &mut Vec<f32>, len: usize) {
    if out.len() != len {
        out.clear();
        out.resize(len, 0.0);
    }
}

/// `out (rows × lin.out) = act(x Wᵀ + b)`, `x` rows of stride `ldx`; through the packed
/// kernels when `packed` holds the layer (the same values bit for bit; `alike`: rows per
/// sample, see [`dense_packed`]).
#[allow(clippy::too_many_arguments)]
fn dense(
    x: &[f32],
    rows: usize,
    ldx: usize,
    lin: &Linear,
    p: &[f32],
    relu: bool,
    out: &mut Vec<f32>,
    packed: Option<&PackedSarl>,
    alike: usize,
) {
    let n = lin.out_dim();
    let bias = &p[lin.b.offset..lin.b.offset + n];
    if let Some(pw) = packed.and_then(|pk| pk.get(lin.w)) {
        sized(out, rows * n);
        dense_packed(rows, x, ldx, pw, bias, usize::MAX, relu, out, alike);
        return;
    }
    out.clear();
    if n == 1 {
        let w = &p[lin.w.offset..lin.w.offset + lin.w.cols];
        out.extend((0..rows).map(|r| dot(&x[r * ldx..r * ldx + lin.w.cols], w) + bias[0]));
    } else {
        for _ in 0..rows {
            out.extend_from_slice(bias);
        }
        gemm_acc(rows, x, ldx, lin.w, p, out);
    }
    if relu {
        relu_inplace(out);
    }
}

/// CrowdNav's masked softmax, `w_i = exp(s_i)·[s_i ≠ 0] / Σ_j exp(s_j)·[s_j ≠ 0]`, computed
/// with the maximum unmasked score subtracted first (same value, no overflow). If every score
/// is exactly 0 (CrowdNav divides 0 by 0), the weights are uniform.
pub(crate) fn masked_softmax(scores: &[f32], out: &mut [f32]) {
    let shift = softmax_shift(scores);
    match shift {
        None => out.fill(1.0 / scores.len() as f32),
        Some(m) => {
            let mut sum = 0.0f32;
            for (o, &s) in out.iter_mut().zip(scores) {
                *o = if s != 0.0 { (s - m).exp() } else { 0.0 };
                sum += *o;
            }
            for o in out.iter_mut() {
                *o /= sum;
            }
        }
    }
}

/// Maximum over the non-zero scores, `None` if all are exactly zero.
pub(crate) fn softmax_shift(scores: &[f32]) -> Option<f32> {
    scores
        .iter()
        .copied()
        .filter(|&s| s != 0.0)
        .fold(None, |m: Option<f32>, s| Some(m.map_or(s, |m| m.max(s))))
}

/// Runs an MLP chain on `x`, each layer into `bufs[k]`; ReLU after every layer except the last
/// unless `last_relu`. Returns the output width. `alike`: rows per sample (see [`dense_packed`]).
#[allow(clippy::too_many_arguments)]
fn mlp_chain(
    x: &[f32],
    rows: usize,
    ldx: usize,
    layers: &[Linear],
    p: &[f32],
    last_relu: bool,
    bufs: &mut [Vec<f32>],
    packed: Option<&PackedSarl>,
    alike: usize,
) -> usize {
    let mut width = ldx;
    for (k, lin) in layers.iter().enumerate() {
        let relu = last_relu || k + 1 < layers.len();
        let (done, rest) = bufs.split_at_mut(k);
        let input: &[f32] = if k == 0 { x } else { &done[k - 1] };
        let ld = if k == 0 { ldx } else { width };
        dense(input, rows, ld, lin, p, relu, &mut rest[0], packed, alike);
        width = lin.out_dim();
    }
    width
}

/// SARL forward: `values (B)` for `states (B, N, 13)`; attention weights land in `scratch`.
/// With `packed` (the weights of `p` packed), the per-row layers run through the packed
/// kernels; without, through `gemm` (the reference path); the values are the same bit for bit.
pub(crate) fn sarl_forward(
    ix: &SarlIndex,
    p: &[f32],
    states: StateBatch<'_>,
    scratch: &mut Scratch,
    out: &mut [f32],
    packed: Option<&PackedSarl>,
) {
    let (b, n, rows) = (states.batch(), states.humans(), states.rows());
    let (n1, n2, na, n3) = (
        ix.mlp1.len(),
        ix.mlp2.len(),
        ix.attention.len(),
        ix.mlp3.len(),
    );
    // Buffer plan: mlp1 | mean, g | attention | mlp2 hidden | pooled, h, head input | mlp3.
    let total = n1 + 2 + na + (n2 - 1) + 3 + n3;
    let mut attention = std::mem::take(&mut scratch.attention);
    let bufs = scratch.buffers(total);
    let (mlp1_b, rest) = bufs.split_at_mut(n1);
    let (glob_b, rest) = rest.split_at_mut(2);
    let (att_b, rest) = rest.split_at_mut(na);
    let (mlp2_b, rest) = rest.split_at_mut(n2 - 1);
    let (pool_b, mlp3_b) = rest.split_at_mut(3);

    // e = mlp1(x), ReLU after every layer.
    let d_e = mlp_chain(
        states.data(),
        rows,
        FEATURE_DIM,
        &ix.mlp1,
        p,
        true,
        mlp1_b,
        packed,
        n,
    );
    let e: &[f32] = &mlp1_b[n1 - 1];

    // ē per sample, then g = ē W_Rᵀ + b (the mean half of attention layer 0).
    let (mean, g) = glob_b.split_at_mut(1);
    let (mean, g) = (&mut mean[0], &mut g[0]);
    mean.clear();
    mean.resize(b * d_e, 0.0);
    let inv_n = 1.0 / n as f32;
    for s in 0..b {
        let m = &mut mean[s * d_e..(s + 1) * d_e];
        for h in 0..n {
            let row = &e[(s * n + h) * d_e..(s * n + h + 1) * d_e];
            for (a, v) in m.iter_mut().zip(row) {
                *a += v;
            }
        }
        for a in m.iter_mut() {
            *a *= inv_n;
        }
    }
    let att0 = &ix.attention[0];
    let d_a0 = att0.out_dim();
    let half = Linear {
        w: att0.w.cols(d_e, 2 * d_e),
        b: att0.b,
    };
    dense(mean, b, d_e, &half, p, false, g, packed, 1);

    // Attention layer 0 on the e half, plus g of the row's sample; then the other layers.
    let a0 = &mut att_b[0];
    let e_half = att0.w.cols(0, d_e);
    if let Some(pw) = packed.and_then(|pk| pk.get(e_half)) {
        // g of row r's sample is row r / n of g; the ReLU in the same pass.
        sized(a0, rows * d_a0);
        dense_packed(rows, e, d_e, pw, g, n, na > 1, a0, n);
    } else {
        attention_e_half(e, g, rows, n, d_e, att0, e_half, p, na > 1, a0);
    }
    if na > 1 {
        let (first, others) = att_b.split_at_mut(1);
        mlp_chain(
            &first[0],
            rows,
            d_a0,
            &ix.attention[1..],
            p,
            false,
            others,
            packed,
            n,
        );
    }
    let scores: &[f32] = &att_b[na - 1];
    softmax_pool_and_head(
        ix,
        p,
        states,
        e,
        d_e,
        scores,
        &mut attention,
        mlp2_b,
        pool_b,
        mlp3_b,
        out,
        packed,
    );
    scratch.attention = attention;
}

/// The reference path of attention layer 0's `e` half: `a0 = act(g[sample] + e W_Lᵀ)` with
/// `g` copied to every row of its sample, then `gemm` (or a dot product for one output).
#[allow(clippy::too_many_arguments)]
fn attention_e_half(
    e: &[f32],
    g: &[f32],
    rows: usize,
    n: usize,
    d_e: usize,
    att0: &Linear,
    e_half: Mat,
    p: &[f32],
    relu: bool,
    a0: &mut Vec<f32>,
) {
    let d_a0 = att0.out_dim();
    let b = rows / n;
    a0.clear();
    for s in 0..b {
        for _ in 0..n {
            a0.extend_from_slice(&g[s * d_a0..(s + 1) * d_a0]);
        }
    }
    if d_a0 == 1 {
        let w = &p[att0.w.offset..att0.w.offset + d_e];
        for (r, v) in a0.iter_mut().enumerate() {
            *v += dot(&e[r * d_e..(r + 1) * d_e], w);
        }
    } else {
        gemm_acc(rows, e, d_e, e_half, p, a0);
    }
    if relu {
        relu_inplace(a0);
    }
}

/// Masked softmax of `scores` into `attention`, `z = mlp2(e)` without its last layer, the
/// attention-weighted sum, mlp2's last layer and the value head into `out`.
#[allow(clippy::too_many_arguments)]
fn softmax_pool_and_head(
    ix: &SarlIndex,
    p: &[f32],
    states: StateBatch<'_>,
    e: &[f32],
    d_e: usize,
    scores: &[f32],
    attention: &mut Vec<f32>,
    mlp2_b: &mut [Vec<f32>],
    pool_b: &mut [Vec<f32>],
    mlp3_b: &mut [Vec<f32>],
    out: &mut [f32],
    packed: Option<&PackedSarl>,
) {
    let (b, n, rows) = (states.batch(), states.humans(), states.rows());
    let (n2, n3) = (ix.mlp2.len(), ix.mlp3.len());
    // Masked softmax over each sample's humans.
    attention.clear();
    attention.resize(b * n, 0.0);
    for s in 0..b {
        masked_softmax(
            &scores[s * n..(s + 1) * n],
            &mut attention[s * n..(s + 1) * n],
        );
    }

    // z = mlp2 without its last layer (ReLU after each); pooled = Σ_i w_i z_i.
    let (z, d_z): (&[f32], usize) = if n2 > 1 {
        let d = mlp_chain(e, rows, d_e, &ix.mlp2[..n2 - 1], p, true, mlp2_b, packed, n);
        (&mlp2_b[n2 - 2], d)
    } else {
        (e, d_e)
    };
    let (pooled, rest) = pool_b.split_at_mut(1);
    let (hbuf, head) = rest.split_at_mut(1);
    let (pooled, hbuf, head) = (&mut pooled[0], &mut hbuf[0], &mut head[0]);
    pooled.clear();
    pooled.resize(b * d_z, 0.0);
    for s in 0..b {
        let acc = &mut pooled[s * d_z..(s + 1) * d_z];
        for h in 0..n {
            let w = attention[s * n + h];
            let row = &z[(s * n + h) * d_z..(s * n + h + 1) * d_z];
            for (a, v) in acc.iter_mut().zip(row) {
                *a += w * v;
            }
        }
    }
    // h = pooled W2ᵀ + b (mlp2's last layer, no ReLU).
    let last2 = &ix.mlp2[n2 - 1];
    dense(pooled, b, d_z, last2, p, false, hbuf, packed, 1);
    let d_h = last2.out_dim();

    // Value head on [robot | h].
    let d_in = ROBOT_DIM + d_h;
    head.clear();
    for s in 0..b {
        head.extend_from_slice(states.robot(s));
        head.extend_from_slice(&hbuf[s * d_h..(s + 1) * d_h]);
    }
    mlp_chain(head, b, d_in, &ix.mlp3, p, false, mlp3_b, packed, 1);
    out.copy_from_slice(&mlp3_b[n3 - 1][..b]);
}

/// `e^x` as a straight-line polynomial, so that a loop over a slice of it vectorises: Cephes'
/// `expf` (range reduction `x = n ln 2 + r`, `|r| ≤ ln 2 / 2`, a degree-5 polynomial, then
/// `2^n` through the exponent bits), relative error about 2e-7. Inputs are clamped to
/// [−87, 88], so the result is a normal finite number.
#[inline(always)]
fn exp_v(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    // Adding 1.5 · 2^23 rounds x log2 e to the nearest integer n (|x log2 e| < 2^22) ...
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let t = x * LOG2E + ROUND;
    let n = t - ROUND;
    // ... and t's bits minus ROUND's are n: integer arithmetic, no saturating cast.
    let ni = (t.to_bits() as i32).wrapping_sub(ROUND.to_bits() as i32);
    // ln 2 in two parts (Cody–Waite), so r is exact to f32 precision.
    let r = (x - n * 0.693_359_4) + n * 2.121_944_4e-4;
    let mut p = 1.987_569_1e-4f32;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let y = p * (r * r) + r + 1.0;
    y * f32::from_bits((ni.wrapping_add(127) << 23) as u32)
}

/// σ over a slice, in place (vectorises).
#[inline]
fn sigmoid_slice(v: &mut [f32]) {
    for x in v {
        *x = 1.0 / (1.0 + exp_v(-*x));
    }
}

/// `tanh(x) = sign(x) (1 − e^{−2|x|}) / (1 + e^{−2|x|})`, absolute error about 2e-7.
#[inline(always)]
fn tanh_v(x: f32) -> f32 {
    let e = exp_v(-2.0 * x.abs());
    ((1.0 - e) / (1.0 + e)).copysign(x)
}

/// One LSTM cell for one sample, hidden size `H = c.len()`: `pre` (4H, PyTorch's gate blocks
/// i, f, g, o) is replaced by the activations σ(i), σ(f), tanh(g), σ(o); `c` holds `c_{t−1}` on
/// entry and `c_t = f c_{t−1} + i g` on exit; `tc = tanh(c_t)`, `h = o tanh(c_t)`. Shared by
/// inference and the training graph; vectorises.
#[inline]
pub(crate) fn lstm_cell(pre: &mut [f32], c: &mut [f32], tc: &mut [f32], h: &mut [f32]) {
    let hd = c.len();
    let (i, rest) = pre.split_at_mut(hd);
    let (f, rest) = rest.split_at_mut(hd);
    let (g, o) = rest.split_at_mut(hd);
    let (o, tc, h) = (&mut o[..hd], &mut tc[..hd], &mut h[..hd]);
    // The activations slice by slice, so that each loop vectorises.
    sigmoid_slice(i);
    sigmoid_slice(f);
    for x in g.iter_mut() {
        *x = tanh_v(*x);
    }
    sigmoid_slice(o);
    for j in 0..hd {
        c[j] = f[j] * c[j] + i[j] * g[j];
    }
    for (t, &c_t) in tc.iter_mut().zip(c.iter()) {
        *t = tanh_v(c_t);
    }
    for j in 0..hd {
        h[j] = o[j] * tc[j];
    }
}

/// LSTM-RL forward: `values (B)` for `states (B, N, 13)`, humans fed in the given order. The
/// input projections of all steps are one product (inputs copied time-major first).
pub(crate) fn lstm_forward(
    ix: &LstmIndex,
    p: &[f32],
    states: StateBatch<'_>,
    scratch: &mut Scratch,
    out: &mut [f32],
) {
    let (b, n, hd) = (states.batch(), states.humans(), ix.hidden);
    let g4 = 4 * hd;
    let nm = ix.mlp.len();
    let bufs = scratch.buffers(6 + nm);
    let (state_b, mlp_b) = bufs.split_at_mut(6);
    let [x, gates, h, c, tc, head] = state_b else {
        unreachable!("six state buffers")
    };
    let data = states.data();
    x.clear();
    for t in 0..n {
        for s in 0..b {
            let r = (s * n + t) * FEATURE_DIM;
            x.extend_from_slice(&data[r..r + FEATURE_DIM]);
        }
    }
    let b_ih = &p[ix.b_ih.offset..ix.b_ih.offset + g4];
    let b_hh = &p[ix.b_hh.offset..ix.b_hh.offset + g4];
    gates.clear();
    gates.extend(b_ih.iter().zip(b_hh).map(|(x, y)| x + y));
    for _ in 1..n * b {
        gates.extend_from_within(..g4);
    }
    gemm_acc(n * b, x, FEATURE_DIM, ix.w_ih, p, gates);
    for v in [&mut *h, &mut *c, &mut *tc] {
        v.clear();
        v.resize(b * hd, 0.0);
    }
    for t in 0..n {
        let pre = &mut gates[t * b * g4..(t + 1) * b * g4];
        if t > 0 {
            gemm_acc(b, h, hd, ix.w_hh, p, pre);
        }
        for (((g, cs), ts), hs) in pre
            .chunks_exact_mut(g4)
            .zip(c.chunks_exact_mut(hd))
            .zip(tc.chunks_exact_mut(hd))
            .zip(h.chunks_exact_mut(hd))
        {
            lstm_cell(g, cs, ts, hs);
        }
    }
    let d_in = ROBOT_DIM + hd;
    head.clear();
    for s in 0..b {
        head.extend_from_slice(states.robot(s));
        head.extend_from_slice(&h[s * hd..(s + 1) * hd]);
    }
    mlp_chain(head, b, d_in, &ix.mlp, p, false, mlp_b, None, 1);
    out.copy_from_slice(&mlp_b[nm - 1][..b]);
}

#[cfg(test)]
mod activation_tests {
    use super::{exp_v, sigmoid_slice, tanh_v};

    #[test]
    fn polynomial_exp_and_activations_are_accurate_and_saturate() {
        let mut worst = 0.0f64;
        for k in -8700..=8800 {
            let x = k as f32 * 0.01;
            let (got, want) = (exp_v(x) as f64, (x as f64).exp());
            worst = worst.max(((got - want) / want).abs());
        }
        assert!(worst < 1e-6, "relative error of exp {worst:e}");
        for x in [
            -1e30f32,
            -200.0,
            -88.0,
            88.0,
            200.0,
            1e30,
            f32::MAX,
            f32::MIN,
        ] {
            assert!(exp_v(x).is_finite() && exp_v(x) > 0.0, "exp({x})");
        }
        let mut v = vec![-1e4f32, -30.0, -1.0, 0.0, 1.0, 30.0, 1e4];
        sigmoid_slice(&mut v);
        for (s, x) in v.iter().zip([-1e4f64, -30.0, -1.0, 0.0, 1.0, 30.0, 1e4]) {
            let want = 1.0 / (1.0 + (-x).exp());
            assert!((*s as f64 - want).abs() < 1e-6, "σ({x}) = {s}");
        }
        for k in -2000..=2000 {
            let x = k as f32 * 0.005;
            assert!(
                (tanh_v(x) as f64 - (x as f64).tanh()).abs() < 1e-6,
                "tanh({x})"
            );
        }
        assert_eq!(tanh_v(1e4), 1.0);
        assert_eq!(tanh_v(-1e4), -1.0);
    }
}
