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
        let t = self.dev.tensor_from_vec(m.gather(self.flat), (m.rows, m.cols));
        self.mats.push((m, t.clone()));
        t
    }

    /// A bias block (`(n, 1)` in the layout) as an `(n)` tensor.
    fn vec(&mut self, m: Mat) -> T1 {
        let t = self.dev.tensor_from_vec(m.gather(self.flat), (m.rows * m.cols,));
        self.vecs.push((m, t.clone()));
        t
    }

    /// Scatters every parameter's gradient into `out` (flat layout; added, so zero it first).
    fn scatter_grads(&self, grads: &mut Gradients<f32, Cpu>, out: &mut [f32]) -> Result<(), PolicyError> {
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

/// `x Wᵀ` with `W` given as `(out, in)`.
fn mul_wt(x: G2, w: &T2) -> G2 {
    x.matmul(w.retaped::<Tp>().permute::<(usize, usize), Axes2<1, 0>>())
}

/// `y + b` with `b` broadcast over rows.
fn add_bias(y: G2, b: &T1) -> G2 {
    let shape = *y.shape();
    y + b.retaped::<Tp>().broadcast_like::<(usize, usize), Axis<0>>(&shape)
}

fn linear(x: G2, lin: &Linear, ps: &mut Params<'_>) -> G2 {
    let (w, b) = (ps.mat(lin.w), ps.vec(lin.b));
    add_bias(mul_wt(x, &w), &b)
}

/// An MLP chain; ReLU after every layer except the last unless `last_relu`.
fn mlp(mut x: G2, layers: &[Linear], last_relu: bool, ps: &mut Params<'_>) -> G2 {
    for (k, lin) in layers.iter().enumerate() {
        x = linear(x, lin, ps);
        if last_relu || k + 1 < layers.len() {
            x = x.relu();
        }
    }
    x
}

/// The value head on `[robot | feature]`, its first weight split by columns.
fn head(robot: G2, feature: G2, layers: &[Linear], ps: &mut Params<'_>) -> G2 {
    let first = &layers[0];
    let d_in = first.w.cols;
    let (w_r, w_f, b) = (
        ps.mat(first.w.cols(0, ROBOT_DIM)),
        ps.mat(first.w.cols(ROBOT_DIM, d_in)),
        ps.vec(first.b),
    );
    let mut y = add_bias(mul_wt(robot, &w_r) + mul_wt(feature, &w_f), &b);
    if layers.len() > 1 {
        y = mlp(y.relu(), &layers[1..], false, ps);
    }
    y
}

fn robot_tensor(dev: &Cpu, states: StateBatch<'_>) -> G2 {
    let b = states.batch();
    let mut v = Vec::with_capacity(b * ROBOT_DIM);
    for s in 0..b {
        v.extend_from_slice(states.robot(s));
    }
    dev.tensor_from_vec(v, (b, ROBOT_DIM)).retaped::<Tp>()
}

/// SARL: values `(B, 1)` and attention weights `(B·N)`.
fn sarl(dev: &Cpu, ix: &SarlIndex, states: StateBatch<'_>, ps: &mut Params<'_>) -> (G2, Vec<f32>) {
    let (b, n, rows) = (states.batch(), states.humans(), states.rows());
    let x: G2 = dev
        .tensor_from_vec(states.data().to_vec(), (rows, FEATURE_DIM))
        .retaped::<Tp>();
    let e = mlp(x, &ix.mlp1, true, ps);
    let d_e = e.shape().1;

    // Attention layer 0 on [e_i, ē] = e_i W_Lᵀ + (ē W_Rᵀ + b).
    let mean: G2 = e
        .with_empty_tape()
        .reshape_like(&(b, n, d_e))
        .mean::<(usize, usize), Axis<1>>();
    let att0 = &ix.attention[0];
    let d_a0 = att0.out_dim();
    let (w_l, w_r, b_a0) = (
        ps.mat(att0.w.cols(0, d_e)),
        ps.mat(att0.w.cols(d_e, 2 * d_e)),
        ps.vec(att0.b),
    );
    let g = add_bias(mul_wt(mean, &w_r), &b_a0)
        .broadcast_like::<(usize, usize, usize), Axis<1>>(&(b, n, d_a0));
    let mut a = (mul_wt(e.with_empty_tape(), &w_l).reshape_like(&(b, n, d_a0)) + g)
        .reshape_like(&(rows, d_a0));
    if ix.attention.len() > 1 {
        a = mlp(a.relu(), &ix.attention[1..], false, ps);
    }
    let scores = a.reshape_like(&(b, n));

    // Masked softmax: shift by the max unmasked score, zero the masked entries (constants).
    let sv = scores.as_vec();
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
    let attention = w.as_vec();

    // Σ_i w_i z_i with z = mlp2 minus its last layer, then that last layer once per sample.
    let n2 = ix.mlp2.len();
    let z = mlp(e, &ix.mlp2[..n2 - 1], true, ps);
    let d_z = z.shape().1;
    let pooled = w
        .reshape_like(&(b, 1, n))
        .matmul(z.reshape_like(&(b, n, d_z)))
        .reshape_like(&(b, d_z));
    let h = linear(pooled, &ix.mlp2[n2 - 1], ps);
    (head(robot_tensor(dev, states), h, &ix.mlp3, ps), attention)
}

/// LSTM-RL: values `(B, 1)`. Gates i, f, g, o as four blocks of rows of `W_ih`, `W_hh`.
fn lstm(dev: &Cpu, ix: &LstmIndex, states: StateBatch<'_>, ps: &mut Params<'_>) -> G2 {
    let (b, n, hd) = (states.batch(), states.humans(), ix.hidden);
    let gate = |m: Mat, k: usize| m.rows(k * hd, (k + 1) * hd);
    let w_ih: Vec<T2> = (0..4).map(|k| ps.mat(gate(ix.w_ih, k))).collect();
    let w_hh: Vec<T2> = if n > 1 {
        (0..4).map(|k| ps.mat(gate(ix.w_hh, k))).collect()
    } else {
        Vec::new()
    };
    let b_ih: Vec<T1> = (0..4).map(|k| ps.vec(gate(ix.b_ih, k))).collect();
    let b_hh: Vec<T1> = (0..4).map(|k| ps.vec(gate(ix.b_hh, k))).collect();
    let data = states.data();
    let mut h: Option<G2> = None;
    let mut c: Option<G2> = None;
    for t in 0..n {
        let mut xt = Vec::with_capacity(b * FEATURE_DIM);
        for s in 0..b {
            let r = (s * n + t) * FEATURE_DIM;
            xt.extend_from_slice(&data[r..r + FEATURE_DIM]);
        }
        let xt: G2 = dev.tensor_from_vec(xt, (b, FEATURE_DIM)).retaped::<Tp>();
        // The previous h enters all four gates; its own tape goes into the last one.
        let mut pre = Vec::with_capacity(4);
        for k in 0..4 {
            let bias = (b_ih[k].retaped::<Tp>() + b_hh[k].retaped::<Tp>())
                .broadcast_like::<(usize, usize), Axis<0>>(&(b, hd));
            let mut a = mul_wt(xt.with_empty_tape(), &w_ih[k]) + bias;
            let hp = if k < 3 {
                h.as_ref().map(|h| h.with_empty_tape())
            } else {
                h.take()
            };
            if let Some(hp) = hp {
                a = a + mul_wt(hp, &w_hh[k]);
            }
            pre.push(a);
        }
        let mut pre = pre.into_iter();
        let (Some(pi), Some(pf), Some(pg), Some(po)) = (pre.next(), pre.next(), pre.next(), pre.next())
        else {
            unreachable!("four gates")
        };
        let (i, g, o) = (pi.sigmoid(), pg.tanh(), po.sigmoid());
        let c_new = match c.take() {
            None => i * g,
            Some(cp) => pf.sigmoid() * cp + i * g,
        };
        // c's history tape goes into h (always consumed); the next step gets an empty-tape copy.
        c = Some(c_new.with_empty_tape());
        h = Some(o * c_new.tanh());
    }
    let h = h.expect("at least one human");
    head(robot_tensor(dev, states), h, &ix.mlp, ps)
}

fn forward(net: &ValueNet, dev: &Cpu, states: StateBatch<'_>, ps: &mut Params<'_>) -> (G2, Option<Vec<f32>>) {
    match net.index() {
        NetIndex::Sarl(ix) => {
            let (v, a) = sarl(dev, ix, states, ps);
            (v, Some(a))
        }
        NetIndex::Lstm(ix) => (lstm(dev, ix, states, ps), None),
    }
}

/// Values `(B)` (and SARL's attention weights `(B·N)`) through the dfdx graph, no backward.
pub fn values_dfdx(net: &ValueNet, dev: &Cpu, states: StateBatch<'_>) -> (Vec<f32>, Option<Vec<f32>>) {
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
