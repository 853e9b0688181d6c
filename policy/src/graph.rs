//! The networks as dfdx autodiff graphs (CPU), built on the flat weights for one forward and
//! backward pass. Used for training ([`crate::train`]) and as the reference the hand-written
//! inference path is tested against.
//!
//! Each parameter tensor is a copy of its block of the flat vector (a [`Mat`]); after
//! `backward`, its gradient is scattered back to the same place, so the gradient comes out in
//! the flat layout of [`crate::config`]. Matrix products go to `gemm` through dfdx, which
//! parallelises them with rayon over `rayon::current_num_threads()` threads (set
//! `RAYON_NUM_THREADS=1` for a single-threaded learner).

use dfdx::prelude::*;

use crate::config::{Linear, LstmIndex, Mat, NetIndex, SarlIndex};
use crate::fast::softmax_shift;
use crate::kernels::{add_column_sums, gemm, relu_inplace, Threads, View};
use crate::net::{StateBatch, ValueNet};
use crate::{PolicyError, FEATURE_DIM, ROBOT_DIM};

type Tp = OwnedTape<f32, Cpu>;
type T1 = Tensor<(usize,), f32, Cpu>;
type T2 = Tensor<(usize, usize), f32, Cpu>;
type G2 = Tensor<(usize, usize), f32, Cpu, Tp>;

/// Parameter tensors of one pass, each remembering its block of the flat vector.
struct Params<'a> {
    dev: &'a Cpu,
    flat: &'a [f32],
    mats: Vec<(Mat, T2)>,
    vecs: Vec<(Mat, T1)>,
}

impl<'a> Params<'a> {
    fn new(dev: &'a Cpu, flat: &'a [f32]) -> Self {
        Self {
            dev,
            flat,
            mats: Vec::new(),
            vecs: Vec::new(),
        }
    }

    /// A weight block as a `(rows, cols)` tensor.
    fn mat(&mut self, m: Mat) -> T2 {
        let t = self
            .dev
            .tensor_from_vec(m.gather(self.flat), (m.rows, m.cols));
        self.mats.push((m, t.clone()));
        t
    }

    /// A bias block (`(n, 1)` in the layout) as an `(n)` tensor.
    fn vec(&mut self, m: Mat) -> T1 {
        let t = self
            .dev
            .tensor_from_vec(m.gather(self.flat), (m.rows * m.cols,));
        self.vecs.push((m, t.clone()));
        t
    }

    /// Scatters every parameter's gradient into `out` (flat layout; added, so zero it first).
    fn scatter_grads(
        &self,
        grads: &mut Gradients<f32, Cpu>,
        out: &mut [f32],
    ) -> Result<(), PolicyError> {
        let dev_err = |e: CpuError| PolicyError::Device(e.to_string());
        for (m, t) in &self.mats {
            m.scatter_add(grads.get_or_alloc_mut(t).map_err(dev_err)?, out);
        }
        for (m, t) in &self.vecs {
            m.scatter_add(grads.get_or_alloc_mut(t).map_err(dev_err)?, out);
        }
        Ok(())
    }
}

/// A copy of a contiguous tensor's values (a plain `memcpy`; dfdx's `as_vec` walks indices).
fn host<S: Shape, T>(t: &Tensor<S, f32, Cpu, T>) -> Vec<f32> {
    let mut v = vec![0.0; t.shape().num_elements()];
    t.copy_into(&mut v);
    v
}

/// `act(x Wᵀ + b)` as one dfdx op (see [`fused_linear`]).
fn linear(x: G2, lin: &Linear, relu: bool, ps: &mut Params<'_>) -> G2 {
    let (w, b) = (ps.mat(lin.w), ps.vec(lin.b));
    fused_linear(x, &w, Bias::Param(&b), relu, true)
}

/// An MLP chain; ReLU after every layer except the last unless `last_relu`.
fn mlp(mut x: G2, layers: &[Linear], last_relu: bool, ps: &mut Params<'_>) -> G2 {
    for (k, lin) in layers.iter().enumerate() {
        x = linear(x, lin, last_relu || k + 1 < layers.len(), ps);
    }
    x
}

/// What [`fused_linear`] adds after the product.
enum Bias<'a> {
    /// A parameter vector `(N)`, the same for every row.
    Param(&'a T1),
    /// A computed `(G, N)` tensor: row `r` gets row `r / group` (e.g. one per sample).
    Grouped(G2, usize),
    /// Both: a computed per-row `(R, N)` tensor plus a parameter vector.
    RowsAndParam(G2, &'a T1),
}

/// A linear layer with optional ReLU, `y = act(x Wᵀ + bias)` (`x (R, K)`, `W (N, K)`),
/// recorded on the dfdx tape as one operation instead of matmul, broadcast, add and ReLU:
/// forward is one `gemm` into a bias-initialised buffer; backward masks the incoming gradient
/// by `y > 0` once, then `∂bias` = row sums (per group), `∂W += gᵀ x` and, if `x_grad`,
/// `∂x += g W`. Gradients accumulate by tensor id like every dfdx op, so any of the tensors may
/// also feed other ops; `W` is a parameter (its gradient is collected, not propagated).
fn fused_linear(x: G2, w: &T2, bias: Bias<'_>, relu: bool, x_grad: bool) -> G2 {
    let (x, mut tape) = x.split_tape();
    let (rows, k) = *x.shape();
    let n = w.shape().0;
    assert_eq!(w.shape().1, k, "linear: input width");
    let xv = host(&x);
    let wv = host(w);
    let mut out = Vec::with_capacity(rows * n);
    let mut bias_ids = Vec::with_capacity(2);
    let (grouped, param) = match bias {
        Bias::Param(b) => (None, Some(b)),
        Bias::Grouped(g, group) => (Some((g, group)), None),
        Bias::RowsAndParam(g, b) => (Some((g, 1)), Some(b)),
    };
    match grouped {
        Some((g, group)) => {
            let (g, gtape) = g.split_tape();
            tape = tape.merge(gtape);
            assert_eq!(*g.shape(), (rows / group, n), "linear: grouped bias shape");
            let gv = host(&g);
            for row in gv.chunks_exact(n) {
                for _ in 0..group {
                    out.extend_from_slice(row);
                }
            }
            bias_ids.push(BiasId::Grouped(g, group));
        }
        None => out.resize(rows * n, 0.0),
    }
    if let Some(b) = param {
        let bv = host(b);
        for row in out.chunks_exact_mut(n) {
            for (o, v) in row.iter_mut().zip(&bv) {
                *o += v;
            }
        }
        bias_ids.push(BiasId::Param(b.clone()));
    }
    gemm(
        rows,
        n,
        k,
        &mut out,
        n,
        View::rows(&xv, k),
        View::transposed(&wv, k),
        true,
        Threads::Rayon,
    );
    if relu {
        relu_inplace(&mut out);
    }
    let y: T2 = x.device().tensor_from_vec(out.clone(), (rows, n));
    let mask = if relu { Some(out) } else { None };
    let (x_id, w_id, y_id) = (x, w.clone(), y.clone());
    tape.add_backward_op(move |grads| {
        let go = grads.get_or_alloc_mut(&y_id)?;
        let g: Vec<f32> = match &mask {
            Some(out) => go
                .iter()
                .zip(out)
                .map(|(&g, &o)| if o > 0.0 { g } else { 0.0 })
                .collect(),
            None => go.to_vec(),
        };
        for bias_id in &bias_ids {
            match bias_id {
                BiasId::Param(b) => add_column_sums(&g, n, grads.get_or_alloc_mut(b)?),
                BiasId::Grouped(t, group) => {
                    let gb = grads.get_or_alloc_mut(t)?;
                    for (dst, src) in gb.chunks_exact_mut(n).zip(g.chunks_exact(group * n)) {
                        add_column_sums(src, n, dst);
                    }
                }
            }
        }
        // ∂W (N × K) += gᵀ (N × R) · x (R × K)
        let gw = grads.get_or_alloc_mut(&w_id)?;
        gemm(
            n,
            k,
            rows,
            gw,
            k,
            View::transposed(&g, n),
            View::rows(&xv, k),
            true,
            Threads::Rayon,
        );
        if x_grad {
            // ∂x (R × K) += g (R × N) · W (N × K)
            let gx = grads.get_or_alloc_mut(&x_id)?;
            gemm(
                rows,
                k,
                n,
                gx,
                k,
                View::rows(&g, n),
                View::rows(&wv, k),
                true,
                Threads::Rayon,
            );
        }
        Ok(())
    });
    y.put_tape(tape)
}

/// The bias tensor a [`fused_linear`] backward writes to.
enum BiasId {
    Param(T1),
    Grouped(T2, usize),
}

/// The value head on `[robot | feature]`, its first weight split by columns:
/// `act(feature W_fᵀ + (robot W_rᵀ + b))`.
fn head(robot: G2, feature: G2, layers: &[Linear], ps: &mut Params<'_>) -> G2 {
    let first = &layers[0];
    let d_in = first.w.cols;
    let (w_r, w_f, b) = (
        ps.mat(first.w.cols(0, ROBOT_DIM)),
        ps.mat(first.w.cols(ROBOT_DIM, d_in)),
        ps.vec(first.b),
    );
    let robot_part = fused_linear(robot, &w_r, Bias::Param(&b), false, false);
    let y = fused_linear(
        feature,
        &w_f,
        Bias::Grouped(robot_part, 1),
        layers.len() > 1,
        true,
    );
    mlp(y, &layers[1..], false, ps)
}

fn robot_tensor(dev: &Cpu, states: StateBatch<'_>) -> G2 {
    let b = states.batch();
    let mut v = Vec::with_capacity(b * ROBOT_DIM);
    for s in 0..b {
        v.extend_from_slice(states.robot(s));
    }
    dev.tensor_from_vec(v, (b, ROBOT_DIM)).retaped::<Tp>()
}

/// `mlp1` on the network input: ReLU everywhere, no gradient for the input itself.
fn mlp_input(x: G2, layers: &[Linear], ps: &mut Params<'_>) -> G2 {
    let (w, b) = (ps.mat(layers[0].w), ps.vec(layers[0].b));
    let e = fused_linear(x, &w, Bias::Param(&b), true, false);
    mlp(e, &layers[1..], true, ps)
}

/// SARL: values `(B, 1)` and attention weights `(B·N)`.
fn sarl(dev: &Cpu, ix: &SarlIndex, states: StateBatch<'_>, ps: &mut Params<'_>) -> (G2, Vec<f32>) {
    let (b, n, rows) = (states.batch(), states.humans(), states.rows());
    let x: G2 = dev
        .tensor_from_vec(states.data().to_vec(), (rows, FEATURE_DIM))
        .retaped::<Tp>();
    let e = mlp_input(x, &ix.mlp1, ps);
    let d_e = e.shape().1;

    // Attention layer 0 on [e_i, ē] = e_i W_Lᵀ + (ē W_Rᵀ + b).
    let mean: G2 = e
        .with_empty_tape()
        .reshape_like(&(b, n, d_e))
        .mean::<(usize, usize), Axis<1>>();
    let att0 = &ix.attention[0];
    let (w_l, w_r, b_a0) = (
        ps.mat(att0.w.cols(0, d_e)),
        ps.mat(att0.w.cols(d_e, 2 * d_e)),
        ps.vec(att0.b),
    );
    let g = fused_linear(mean, &w_r, Bias::Param(&b_a0), false, true);
    let mut a = fused_linear(
        e.with_empty_tape(),
        &w_l,
        Bias::Grouped(g, n),
        ix.attention.len() > 1,
        true,
    );
    if ix.attention.len() > 1 {
        a = mlp(a, &ix.attention[1..], false, ps);
    }
    let scores = a.reshape_like(&(b, n));

    // Masked softmax: shift by the max unmasked score, zero the masked entries (constants).
    let sv = host(&scores);
    let mut shift = Vec::with_capacity(b * n);
    let mut mask = Vec::with_capacity(b * n);
    for s in sv.chunks_exact(n) {
        match softmax_shift(s) {
            Some(m) => {
                shift.extend(std::iter::repeat_n(m, n));
                mask.extend(s.iter().map(|&v| if v != 0.0 { 1.0 } else { 0.0 }));
            }
            None => {
                shift.extend(std::iter::repeat_n(0.0, n));
                mask.extend(std::iter::repeat_n(1.0, n));
            }
        }
    }
    let shift: T2 = dev.tensor_from_vec(shift, (b, n));
    let mask: T2 = dev.tensor_from_vec(mask, (b, n));
    let ex = (scores - shift).exp() * mask;
    let den = ex
        .with_empty_tape()
        .sum::<(usize,), Axis<1>>()
        .broadcast_like::<(usize, usize), Axis<1>>(&(b, n));
    let w = ex / den;
    let attention = host(&w);

    // Σ_i w_i z_i with z = mlp2 minus its last layer, then that last layer once per sample.
    let n2 = ix.mlp2.len();
    let z = mlp(e, &ix.mlp2[..n2 - 1], true, ps);
    let d_z = z.shape().1;
    let pooled = w
        .reshape_like(&(b, 1, n))
        .matmul(z.reshape_like(&(b, n, d_z)))
        .reshape_like(&(b, d_z));
    let h = linear(pooled, &ix.mlp2[n2 - 1], false, ps);
    (head(robot_tensor(dev, states), h, &ix.mlp3, ps), attention)
}

/// LSTM-RL: values `(B, 1)`. Per step, `pre = h W_hhᵀ + b_hh + (x_t W_ihᵀ + b_ih)` as two
/// fused linear ops (`h_0 = c_0 = 0`), then the gate blocks i, f, g, o are column slices of
/// `pre`.
fn lstm(dev: &Cpu, ix: &LstmIndex, states: StateBatch<'_>, ps: &mut Params<'_>) -> G2 {
    let (b, n, hd) = (states.batch(), states.humans(), ix.hidden);
    let (w_ih, w_hh) = (ps.mat(ix.w_ih), ps.mat(ix.w_hh));
    let (b_ih, b_hh) = (ps.vec(ix.b_ih), ps.vec(ix.b_hh));
    let data = states.data();
    let mut h: G2 = dev.zeros_like(&(b, hd)).retaped::<Tp>();
    let mut c: G2 = dev.zeros_like(&(b, hd)).retaped::<Tp>();
    for t in 0..n {
        let mut xt = Vec::with_capacity(b * FEATURE_DIM);
        for s in 0..b {
            let r = (s * n + t) * FEATURE_DIM;
            xt.extend_from_slice(&data[r..r + FEATURE_DIM]);
        }
        let xt: G2 = dev.tensor_from_vec(xt, (b, FEATURE_DIM)).retaped::<Tp>();
        let xg = fused_linear(xt, &w_ih, Bias::Param(&b_ih), false, false);
        let pre = fused_linear(h, &w_hh, Bias::RowsAndParam(xg, &b_hh), false, t > 0);
        // The slices read `pre` by id, so their gradients add up in `pre`'s; its tape goes
        // with the last one.
        let gate = |k: usize, p: G2| p.slice((.., k * hd..(k + 1) * hd));
        let i = gate(0, pre.with_empty_tape()).sigmoid();
        let g = gate(2, pre.with_empty_tape()).tanh();
        let o = gate(3, pre.with_empty_tape()).sigmoid();
        let c_new = gate(1, pre).sigmoid() * c + i * g;
        // c's history tape goes into h (always consumed); the next step gets an empty-tape copy.
        c = c_new.with_empty_tape();
        h = o * c_new.tanh();
    }
    head(robot_tensor(dev, states), h, &ix.mlp, ps)
}

fn forward(
    net: &ValueNet,
    dev: &Cpu,
    states: StateBatch<'_>,
    ps: &mut Params<'_>,
) -> (G2, Option<Vec<f32>>) {
    match net.index() {
        NetIndex::Sarl(ix) => {
            let (v, a) = sarl(dev, ix, states, ps);
            (v, Some(a))
        }
        NetIndex::Lstm(ix) => (lstm(dev, ix, states, ps), None),
    }
}

/// Values `(B)` (and SARL's attention weights `(B·N)`) through the dfdx graph, no backward.
pub fn values_dfdx(
    net: &ValueNet,
    dev: &Cpu,
    states: StateBatch<'_>,
) -> (Vec<f32>, Option<Vec<f32>>) {
    let mut ps = Params::new(dev, net.params());
    let (v, a) = forward(net, dev, states, &mut ps);
    (v.as_vec(), a)
}

/// Mean-squared error `mean_b (V(s_b) − y_b)²` and its gradient with respect to every
/// parameter, written into `grad` (flat layout, overwritten). dfdx autodiff.
pub fn mse_loss_and_grad(
    net: &ValueNet,
    dev: &Cpu,
    states: StateBatch<'_>,
    targets: &[f32],
    grad: &mut [f32],
) -> Result<f32, PolicyError> {
    let b = states.batch();
    if targets.len() != b {
        return Err(PolicyError::Length {
            what: "targets",
            expected: b,
            got: targets.len(),
        });
    }
    if grad.len() != net.num_params() {
        return Err(PolicyError::Length {
            what: "gradient buffer",
            expected: net.num_params(),
            got: grad.len(),
        });
    }
    let mut ps = Params::new(dev, net.params());
    let (v, _) = forward(net, dev, states, &mut ps);
    let y: T1 = dev.tensor_from_vec(targets.to_vec(), (b,));
    let loss = (v.reshape_like(&(b,)) - y).square().mean::<(), Axis<0>>();
    let value = loss.array();
    let mut grads = loss.backward();
    grad.fill(0.0);
    ps.scatter_grads(&mut grads, grad)?;
    Ok(value)
}
