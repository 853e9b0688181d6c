//! The networks as dfdx autodiff graphs (CPU), built on the flat weights for one forward and
//! backward pass. Used for training ([`crate::train`]) and as the reference the hand-written
//! inference path is tested against.
//!
//! Every operation is recorded on dfdx's tape ([`OwnedTape`]) and every gradient lives in dfdx's
//! [`Gradients`], keyed by tensor; the loss is plain dfdx arithmetic. The network's layers are
//! a few fused custom ops (like cuDNN's fused layers in PyTorch):
//! - [`Ctx::linear`]: `act(x Wᵀ + bias)`, one `gemm` forward, three backward;
//! - [`Ctx::group_mean`]: the mean over each sample's humans;
//! - [`Ctx::attention_pool`]: SARL's masked softmax and the attention-weighted sum;
//! - [`Ctx::lstm`]: the whole LSTM recurrence (input projections of every step in one product,
//!   back-propagation through time, weight gradients of every step in one product).
//!
//! Each op keeps its inputs' and outputs' values on the host ([`Node`]), shared with the ops
//! that read them, so values are never copied back out of tensors; the tensors hold a copy for
//! dfdx (and the loss). Weights are read straight from a snapshot of the flat vector; each
//! parameter also gets a tensor (its block of the flat vector) whose gradient is scattered back
//! to the same place after `backward`, so the gradient comes out in the flat layout of
//! [`crate::config`].
//!
//! Buffers are reused between passes: host values come from a [`Pool`], and dfdx's own
//! allocation cache is switched on for the training devices ([`Shard`]), so a steady-state
//! update allocates nothing large (fresh allocations above glibc's mmap threshold fault their
//! pages in on every update otherwise).

use std::ops::{Deref, DerefMut};
use std::rc::Rc;
use std::sync::{Arc, Mutex};

use dfdx::prelude::*;

use crate::config::{Linear, LstmIndex, Mat, NetIndex, SarlIndex};
use crate::fast::{lstm_cell, masked_softmax};
use crate::kernels::{add_column_sums, dot, gemm, relu_inplace, Threads, View};
use crate::{PolicyError, StateBatch, ValueNet, FEATURE_DIM, ROBOT_DIM};

type Tp = OwnedTape<f32, Cpu>;
type T2 = Tensor<(usize, usize), f32, Cpu>;
type G2 = Tensor<(usize, usize), f32, Cpu, Tp>;

/// Free host buffers, handed out by [`Pool::take`] and returned when the [`Buf`] drops.
#[derive(Clone, Debug, Default)]
pub(crate) struct Pool(Arc<Mutex<Vec<Vec<f32>>>>);

impl Pool {
    /// An empty buffer with room for `len` values: the smallest free one that fits, else new.
    fn take(&self, len: usize) -> Buf {
        let mut free = self.0.lock().unwrap_or_else(|e| e.into_inner());
        let best = free
            .iter()
            .enumerate()
            .filter(|(_, v)| v.capacity() >= len)
            .min_by_key(|(_, v)| v.capacity())
            .map(|(i, _)| i);
        let mut v = match best {
            Some(i) => free.swap_remove(i),
            None => Vec::with_capacity(len),
        };
        drop(free);
        v.clear();
        Buf {
            v,
            pool: self.clone(),
        }
    }

    /// `len` zeros.
    fn zeros(&self, len: usize) -> Buf {
        let mut b = self.take(len);
        b.resize(len, 0.0);
        b
    }
}

/// A host buffer that goes back to its [`Pool`] when dropped.
pub(crate) struct Buf {
    v: Vec<f32>,
    pool: Pool,
}

impl Deref for Buf {
    type Target = Vec<f32>;
    fn deref(&self) -> &Vec<f32> {
        &self.v
    }
}

impl DerefMut for Buf {
    fn deref_mut(&mut self) -> &mut Vec<f32> {
        &mut self.v
    }
}

impl Drop for Buf {
    fn drop(&mut self) {
        let v = std::mem::take(&mut self.v);
        self.pool
            .0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(v);
    }
}

/// A value of the graph: the dfdx tensor that carries the tape (and holds a copy of the
/// values), and the values on the host, shared by every op that reads them.
struct Node {
    t: G2,
    v: Rc<Buf>,
}

impl Node {
    fn rows(&self) -> usize {
        self.t.shape().0
    }

    fn cols(&self) -> usize {
        self.t.shape().1
    }

    /// Another handle on the same value with an empty tape, for a further consumer (the
    /// gradients of all consumers add up in this tensor's).
    fn share(&self) -> Node {
        Node {
            t: self.t.with_empty_tape(),
            v: self.v.clone(),
        }
    }
}

/// Moves `t`'s gradient out of `grads`, so that other gradients can be borrowed meanwhile;
/// [`put_grad`] puts it back.
fn take_grad<S: Shape>(
    grads: &mut Gradients<f32, Cpu>,
    t: &Tensor<S, f32, Cpu>,
) -> Result<Vec<f32>, CpuError> {
    Ok(std::mem::take(&mut **grads.get_or_alloc_mut(t)?))
}

fn put_grad<S: Shape>(
    grads: &mut Gradients<f32, Cpu>,
    t: &Tensor<S, f32, Cpu>,
    g: Vec<f32>,
) -> Result<(), CpuError> {
    **grads.get_or_alloc_mut(t)? = g;
    Ok(())
}

/// What [`Ctx::linear`] adds after the product.
enum Bias {
    /// A parameter vector `(N)` (a bias block of the flat vector), the same for every row.
    Param(Mat),
    /// A computed `(G, N)` value: row `r` gets row `r / group` (e.g. one per sample).
    Grouped(Node, usize),
}

/// Backward of [`lstm_cell`] for one sample: from the activations `a` (4H: i, f, g, o),
/// `tanh(c_t)`, `c_{t−1}`, `∂h_t` and `∂c_t` (from step t + 1; replaced by `∂c_{t−1}`), the
/// gradient of the gate pre-activations `d` (4H).
#[inline]
fn lstm_cell_backward(
    a: &[f32],
    tc: &[f32],
    c_prev: &[f32],
    dh: &[f32],
    dc: &mut [f32],
    d: &mut [f32],
) {
    let hd = dc.len();
    let (ai, rest) = a.split_at(hd);
    let (af, rest) = rest.split_at(hd);
    let (ag, ao) = rest.split_at(hd);
    let (di, rest) = d.split_at_mut(hd);
    let (df, rest) = rest.split_at_mut(hd);
    let (dg, dout) = rest.split_at_mut(hd);
    let (ao, dout, tc, c_prev, dh) = (
        &ao[..hd],
        &mut dout[..hd],
        &tc[..hd],
        &c_prev[..hd],
        &dh[..hd],
    );
    for j in 0..hd {
        let (i_g, f_g, g_g, o_g) = (ai[j], af[j], ag[j], ao[j]);
        let t = tc[j];
        let dc_t = dc[j] + dh[j] * o_g * (1.0 - t * t);
        di[j] = dc_t * g_g * i_g * (1.0 - i_g);
        df[j] = dc_t * c_prev[j] * f_g * (1.0 - f_g);
        dg[j] = dc_t * i_g * (1.0 - g_g * g_g);
        dout[j] = dh[j] * t * o_g * (1.0 - o_g);
        dc[j] = dc_t * f_g;
    }
}

/// The backward half of [`Ctx::linear`].
struct LinearBackward {
    y: T2,
    /// The output, if a ReLU was applied (its gradient is masked by `y > 0`).
    mask: Option<Rc<Buf>>,
    x: T2,
    x_grad: bool,
    xv: Rc<Buf>,
    w: T2,
    w_at: Mat,
    flat: Arc<Vec<f32>>,
    b_param: Option<T2>,
    b_grouped: Option<(T2, usize)>,
    threads: Threads,
}

impl LinearBackward {
    #[inline(never)]
    fn run(self, grads: &mut Gradients<f32, Cpu>) -> Result<(), CpuError> {
        let (rows, n) = *self.y.shape();
        let k = self.w_at.cols;
        let (xv, flat, w) = (&self.xv, &self.flat, self.w_at);
        let mut g = take_grad(grads, &self.y)?;
        if let Some(out) = &self.mask {
            for (g, &o) in g.iter_mut().zip(out.iter()) {
                *g = if o > 0.0 { *g } else { 0.0 };
            }
        }
        if let Some(b) = &self.b_param {
            add_column_sums(&g, n, grads.get_or_alloc_mut(b)?);
        }
        if let Some((t, group)) = &self.b_grouped {
            let gb = grads.get_or_alloc_mut(t)?;
            for (dst, src) in gb.chunks_exact_mut(n).zip(g.chunks_exact(group * n)) {
                add_column_sums(src, n, dst);
            }
        }
        // ∂W (N × K) += gᵀ (N × R) · x (R × K)
        let gw = grads.get_or_alloc_mut(&self.w)?;
        if n == 1 {
            for (&gr, xr) in g.iter().zip(xv.chunks_exact(k)) {
                for (d, &xv) in gw.iter_mut().zip(xr) {
                    *d += gr * xv;
                }
            }
        } else {
            gemm(
                n,
                k,
                rows,
                gw,
                k,
                View::transposed(&g, n),
                View::rows(xv, k),
                true,
                self.threads,
            );
        }
        if self.x_grad {
            // ∂x (R × K) += g (R × N) · W (N × K)
            let gx = grads.get_or_alloc_mut(&self.x)?;
            if n == 1 {
                let wr = &flat[w.offset..w.offset + k];
                for (&gr, dst) in g.iter().zip(gx.chunks_exact_mut(k)) {
                    for (d, &wv) in dst.iter_mut().zip(wr) {
                        *d += gr * wv;
                    }
                }
            } else {
                gemm(
                    rows,
                    k,
                    n,
                    gx,
                    k,
                    View::rows(&g, n),
                    View::rows(&flat[w.offset..], w.ld),
                    true,
                    self.threads,
                );
            }
        }
        put_grad(grads, &self.y, g)
    }
}

/// One pass: the device, the buffer pool, the parameter snapshot and the parameter tensors.
struct Ctx<'a> {
    dev: &'a Cpu,
    pool: &'a Pool,
    flat: &'a Arc<Vec<f32>>,
    threads: Threads,
    params: Vec<(Mat, T2)>,
}

impl<'a> Ctx<'a> {
    fn new(dev: &'a Cpu, pool: &'a Pool, flat: &'a Arc<Vec<f32>>, threads: Threads) -> Self {
        Self {
            dev,
            pool,
            flat,
            threads,
            params: Vec::new(),
        }
    }

    /// A `(rows, cols)` tensor holding `v` (storage from dfdx's cache when it is on).
    fn tensor(&self, rows: usize, cols: usize, v: &[f32]) -> T2 {
        let mut t: T2 = self.dev.zeros_like(&(rows, cols));
        t.copy_from(v);
        t
    }

    /// A node from host values, starting a tape (for inputs, which get no gradient).
    fn node(&self, v: Buf, rows: usize, cols: usize, tape: Tp) -> Node {
        let t = self.tensor(rows, cols, &v);
        Node {
            t: t.put_tape(tape),
            v: Rc::new(v),
        }
    }

    /// The tensor of a parameter block; its gradient is collected by [`Ctx::scatter_grads`].
    fn param(&mut self, m: Mat) -> T2 {
        let mut v = self.pool.take(m.rows * m.cols);
        m.gather_into(self.flat, &mut v);
        let t = self.tensor(m.rows, m.cols, &v);
        self.params.push((m, t.clone()));
        t
    }

    /// Scatters every parameter's gradient into `out` (flat layout; added, so zero it first).
    fn scatter_grads(
        &self,
        grads: &mut Gradients<f32, Cpu>,
        out: &mut [f32],
    ) -> Result<(), PolicyError> {
        let dev_err = |e: CpuError| PolicyError::Device(e.to_string());
        for (m, t) in &self.params {
            m.scatter_add(grads.get_or_alloc_mut(t).map_err(dev_err)?, out);
        }
        Ok(())
    }

    /// `act(x Wᵀ + bias)` (`x (R, K)`, `W (N, K)`, a block of the flat vector) as one dfdx op
    /// instead of matmul, broadcast, add and ReLU: forward is one `gemm` into a
    /// bias-initialised buffer; backward masks the incoming gradient by `y > 0` once, then
    /// `∂bias` = row sums (per group), `∂W += gᵀ x` and, if `x_grad`, `∂x += g W`. Gradients
    /// accumulate by tensor id like every dfdx op, so any input may also feed other ops.
    fn linear(&mut self, x: Node, w: Mat, bias: Bias, relu: bool, x_grad: bool) -> Node {
        let (rows, k, n) = (x.rows(), x.cols(), w.rows);
        assert_eq!(w.cols, k, "linear: input width");
        let w_t = self.param(w);
        let (x_t, mut tape) = x.t.split_tape();
        let xv = x.v;
        let mut out = self.pool.take(rows * n);
        let (mut b_param, mut b_grouped) = (None, None);
        match bias {
            Bias::Param(b) => {
                let bv = &self.flat[b.offset..b.offset + n];
                for _ in 0..rows {
                    out.extend_from_slice(bv);
                }
                b_param = Some(self.param(b));
            }
            Bias::Grouped(g, group) => {
                assert_eq!(
                    (g.rows(), g.cols()),
                    (rows / group, n),
                    "linear: grouped bias shape"
                );
                let (g_t, g_tape) = g.t.split_tape();
                tape = tape.merge(g_tape);
                for row in g.v.chunks_exact(n) {
                    for _ in 0..group {
                        out.extend_from_slice(row);
                    }
                }
                b_grouped = Some((g_t, group));
            }
        }
        let flat = self.flat.clone();
        if n == 1 {
            let wr = &flat[w.offset..w.offset + k];
            for (o, xr) in out.iter_mut().zip(xv.chunks_exact(k)) {
                *o += dot(xr, wr);
            }
        } else {
            gemm(
                rows,
                n,
                k,
                &mut out,
                n,
                View::rows(&xv, k),
                View::transposed(&flat[w.offset..], w.ld),
                true,
                self.threads,
            );
        }
        if relu {
            relu_inplace(&mut out);
        }
        let y = self.tensor(rows, n, &out);
        let out = Rc::new(out);
        let back = LinearBackward {
            y: y.clone(),
            mask: relu.then(|| out.clone()),
            x: x_t,
            x_grad,
            xv,
            w: w_t,
            w_at: w,
            flat,
            b_param,
            b_grouped,
            threads: self.threads,
        };
        tape.add_backward_op(move |grads| back.run(grads));
        Node {
            t: y.put_tape(tape),
            v: out,
        }
    }

    /// A linear layer of the network.
    fn layer(&mut self, x: Node, lin: &Linear, relu: bool) -> Node {
        self.linear(x, lin.w, Bias::Param(lin.b), relu, true)
    }

    /// An MLP chain; ReLU after every layer except the last unless `last_relu`.
    fn mlp(&mut self, mut x: Node, layers: &[Linear], last_relu: bool) -> Node {
        for (k, lin) in layers.iter().enumerate() {
            x = self.layer(x, lin, last_relu || k + 1 < layers.len());
        }
        x
    }

    /// `(R / n, D)` means of each group of `n` consecutive rows of `x (R, D)`.
    fn group_mean(&mut self, x: Node, n: usize) -> Node {
        let (rows, d) = (x.rows(), x.cols());
        let b = rows / n;
        let inv_n = 1.0 / n as f32;
        let mut m = self.pool.zeros(b * d);
        for (acc, group) in m.chunks_exact_mut(d).zip(x.v.chunks_exact(n * d)) {
            for row in group.chunks_exact(d) {
                for (a, v) in acc.iter_mut().zip(row) {
                    *a += v;
                }
            }
            for a in acc.iter_mut() {
                *a *= inv_n;
            }
        }
        let (x_t, mut tape) = x.t.split_tape();
        let y = self.tensor(b, d, &m);
        let y_id = y.clone();
        tape.add_backward_op(move |grads| {
            let gm = take_grad(grads, &y_id)?;
            let gx = grads.get_or_alloc_mut(&x_t)?;
            for (src, dst) in gm.chunks_exact(d).zip(gx.chunks_exact_mut(n * d)) {
                for row in dst.chunks_exact_mut(d) {
                    for (o, g) in row.iter_mut().zip(src) {
                        *o += g * inv_n;
                    }
                }
            }
            put_grad(grads, &y_id, gm)
        });
        Node {
            t: y.put_tape(tape),
            v: Rc::new(m),
        }
    }

    /// SARL's pooling: per sample of `n` rows, `w = masked_softmax(scores)` (CrowdNav's mask:
    /// exact-zero scores get weight 0, see [`masked_softmax`]) and `pooled = Σ_i w_i z_i`.
    /// `scores (R, 1)`, `z (R, D)` → `pooled (R / n, D)` and the weights `(R)`.
    ///
    /// Backward: `∂z_i += w_i g`, and with `∂w_i = g · z_i`, the softmax's
    /// `∂s_i += w_i (∂w_i − Σ_j w_j ∂w_j)` (masked entries have `w_i = 0`, a constant).
    fn attention_pool(&mut self, scores: Node, z: Node, n: usize) -> (Node, Rc<Buf>) {
        let (rows, d) = (z.rows(), z.cols());
        assert_eq!(scores.rows(), rows, "attention: scores per row");
        let b = rows / n;
        let mut w = self.pool.zeros(rows);
        for (s, o) in scores.v.chunks_exact(n).zip(w.chunks_exact_mut(n)) {
            masked_softmax(s, o);
        }
        let mut pooled = self.pool.zeros(b * d);
        for ((acc, zs), ws) in pooled
            .chunks_exact_mut(d)
            .zip(z.v.chunks_exact(n * d))
            .zip(w.chunks_exact(n))
        {
            for (zr, &wi) in zs.chunks_exact(d).zip(ws) {
                for (a, v) in acc.iter_mut().zip(zr) {
                    *a += wi * v;
                }
            }
        }
        let w = Rc::new(w);
        let (s_t, s_tape) = scores.t.split_tape();
        let (z_t, z_tape) = z.t.split_tape();
        let mut tape = s_tape.merge(z_tape);
        let y = self.tensor(b, d, &pooled);
        let (y_id, zv, wv) = (y.clone(), z.v, w.clone());
        tape.add_backward_op(move |grads| {
            let gp = take_grad(grads, &y_id)?;
            let gs = grads.get_or_alloc_mut(&s_t)?;
            for ((g, zs), (ws, dst)) in gp
                .chunks_exact(d)
                .zip(zv.chunks_exact(n * d))
                .zip(wv.chunks_exact(n).zip(gs.chunks_exact_mut(n)))
            {
                let mut dw = [0.0f32; 64];
                let mut dw_heap = Vec::new();
                let dw: &mut [f32] = if n <= dw.len() {
                    &mut dw[..n]
                } else {
                    dw_heap.resize(n, 0.0);
                    &mut dw_heap
                };
                let mut t = 0.0f32;
                for ((zr, &wi), dwi) in zs.chunks_exact(d).zip(ws).zip(dw.iter_mut()) {
                    *dwi = dot(g, zr);
                    t += wi * *dwi;
                }
                for ((o, &wi), &dwi) in dst.iter_mut().zip(ws).zip(dw.iter()) {
                    *o += wi * (dwi - t);
                }
            }
            let gz = grads.get_or_alloc_mut(&z_t)?;
            for ((g, dst), ws) in gp
                .chunks_exact(d)
                .zip(gz.chunks_exact_mut(n * d))
                .zip(wv.chunks_exact(n))
            {
                for (row, &wi) in dst.chunks_exact_mut(d).zip(ws) {
                    for (o, gv) in row.iter_mut().zip(g) {
                        *o += wi * gv;
                    }
                }
            }
            put_grad(grads, &y_id, gp)
        });
        (
            Node {
                t: y.put_tape(tape),
                v: Rc::new(pooled),
            },
            w,
        )
    }

    /// Each sample's robot features `(B, 6)` (a constant input).
    fn robot(&mut self, states: StateBatch<'_>) -> Node {
        let b = states.batch();
        let mut v = self.pool.take(b * ROBOT_DIM);
        for s in 0..b {
            v.extend_from_slice(states.robot(s));
        }
        self.node(v, b, ROBOT_DIM, Tp::default())
    }

    /// The value head on `[robot | feature]`, its first weight split by columns:
    /// `act(feature W_fᵀ + (robot W_rᵀ + b))`.
    fn head(&mut self, robot: Node, feature: Node, layers: &[Linear]) -> Node {
        let first = &layers[0];
        let d_in = first.w.cols;
        let robot_part = self.linear(
            robot,
            first.w.cols(0, ROBOT_DIM),
            Bias::Param(first.b),
            false,
            false,
        );
        let y = self.linear(
            feature,
            first.w.cols(ROBOT_DIM, d_in),
            Bias::Grouped(robot_part, 1),
            layers.len() > 1,
            true,
        );
        self.mlp(y, &layers[1..], false)
    }

    /// SARL: values `(B, 1)` and attention weights `(B·N)`.
    fn sarl(&mut self, ix: &SarlIndex, states: StateBatch<'_>) -> (Node, Rc<Buf>) {
        let (n, rows) = (states.humans(), states.rows());
        let mut x = self.pool.take(rows * FEATURE_DIM);
        x.extend_from_slice(states.data());
        let x = self.node(x, rows, FEATURE_DIM, Tp::default());
        // mlp1 with ReLU everywhere; no gradient for the input itself.
        let first = &ix.mlp1[0];
        let e = self.linear(x, first.w, Bias::Param(first.b), true, false);
        let e = self.mlp(e, &ix.mlp1[1..], true);
        let d_e = e.cols();

        // Attention layer 0 on [e_i, ē] = e_i W_Lᵀ + (ē W_Rᵀ + b).
        let mean = self.group_mean(e.share(), n);
        let att0 = &ix.attention[0];
        let na = ix.attention.len();
        let g = self.linear(
            mean,
            att0.w.cols(d_e, 2 * d_e),
            Bias::Param(att0.b),
            false,
            true,
        );
        let mut a = self.linear(
            e.share(),
            att0.w.cols(0, d_e),
            Bias::Grouped(g, n),
            na > 1,
            true,
        );
        if na > 1 {
            a = self.mlp(a, &ix.attention[1..], false);
        }

        // Σ_i w_i z_i with z = mlp2 minus its last layer, then that last layer once per sample.
        let n2 = ix.mlp2.len();
        let z = self.mlp(e, &ix.mlp2[..n2 - 1], true);
        let (pooled, attention) = self.attention_pool(a, z, n);
        let h = self.layer(pooled, &ix.mlp2[n2 - 1], false);
        let robot = self.robot(states);
        (self.head(robot, h, &ix.mlp3), attention)
    }

    /// The LSTM over each sample's humans in the given order (`h_0 = c_0 = 0`), PyTorch's
    /// gates i, f, g, o: `h_N (B, H)`, as one op.
    ///
    /// Forward: the input projections `x_t W_ihᵀ + b_ih + b_hh` of every step in one product,
    /// then per step `+ h W_hhᵀ` and the cell. Backward (through time): per step the gate
    /// gradients `∂pre_t` and `∂h_{t−1} = ∂pre_t W_hh`; then `∂W_ih += Σ_t ∂pre_tᵀ x_t` and
    /// `∂W_hh += Σ_t ∂pre_tᵀ h_{t−1}` as one product each, and the biases' column sums.
    fn lstm(&mut self, ix: &LstmIndex, states: StateBatch<'_>) -> Node {
        let (b, n, hd) = (states.batch(), states.humans(), ix.hidden);
        let g4 = 4 * hd;
        let (wih_t, whh_t) = (self.param(ix.w_ih), self.param(ix.w_hh));
        let (bih_t, bhh_t) = (self.param(ix.b_ih), self.param(ix.b_hh));
        let (flat, threads, whh) = (self.flat.clone(), self.threads, ix.w_hh);
        // Inputs time-major: row t·B + s is human t of sample s.
        let data = states.data();
        let mut x = self.pool.take(n * b * FEATURE_DIM);
        for t in 0..n {
            for s in 0..b {
                let r = (s * n + t) * FEATURE_DIM;
                x.extend_from_slice(&data[r..r + FEATURE_DIM]);
            }
        }
        // Gate pre-activations, replaced by the activations i, f, g, o step by step.
        let mut acts = self.pool.take(n * b * g4);
        {
            let b_ih = &flat[ix.b_ih.offset..ix.b_ih.offset + g4];
            let b_hh = &flat[ix.b_hh.offset..ix.b_hh.offset + g4];
            let mut bias = self.pool.take(g4);
            bias.extend(b_ih.iter().zip(b_hh).map(|(x, y)| x + y));
            for _ in 0..n * b {
                acts.extend_from_slice(&bias);
            }
        }
        gemm(
            n * b,
            g4,
            FEATURE_DIM,
            &mut acts,
            g4,
            View::rows(&x, FEATURE_DIM),
            View::transposed(&flat[ix.w_ih.offset..], ix.w_ih.ld),
            true,
            threads,
        );
        let mut c_all = self.pool.zeros(n * b * hd);
        let mut tc_all = self.pool.zeros(n * b * hd);
        let mut h_all = self.pool.zeros(n * b * hd);
        let step = b * hd;
        for t in 0..n {
            let pre = &mut acts[t * b * g4..(t + 1) * b * g4];
            if t > 0 {
                gemm(
                    b,
                    g4,
                    hd,
                    pre,
                    g4,
                    View::rows(&h_all[(t - 1) * step..t * step], hd),
                    View::transposed(&flat[ix.w_hh.offset..], ix.w_hh.ld),
                    true,
                    threads,
                );
            }
            let (c_done, c_rest) = c_all.split_at_mut(t * step);
            let c_t = &mut c_rest[..step];
            if t > 0 {
                c_t.copy_from_slice(&c_done[(t - 1) * step..]);
            }
            let tc_t = &mut tc_all[t * step..(t + 1) * step];
            let h_t = &mut h_all[t * step..(t + 1) * step];
            for (((g, cs), ts), hs) in pre
                .chunks_exact_mut(g4)
                .zip(c_t.chunks_exact_mut(hd))
                .zip(tc_t.chunks_exact_mut(hd))
                .zip(h_t.chunks_exact_mut(hd))
            {
                lstm_cell(g, cs, ts, hs);
            }
        }
        let mut h_last = self.pool.take(step);
        h_last.extend_from_slice(&h_all[(n - 1) * step..]);
        let y = self.tensor(b, hd, &h_last);
        let (y_id, pool) = (y.clone(), self.pool.clone());
        let mut tape = Tp::default();
        tape.add_backward_op(move |grads| {
            let gh = take_grad(grads, &y_id)?;
            let mut dh = pool.take(step);
            dh.extend_from_slice(&gh);
            let mut dc = pool.zeros(step);
            let zeros = pool.zeros(step);
            let mut dpre = pool.zeros(n * b * g4);
            for t in (0..n).rev() {
                let a_t = &acts[t * b * g4..(t + 1) * b * g4];
                let tc_t = &tc_all[t * step..(t + 1) * step];
                let c_prev = if t > 0 {
                    &c_all[(t - 1) * step..t * step]
                } else {
                    &zeros[..]
                };
                let d_t = &mut dpre[t * b * g4..(t + 1) * b * g4];
                for s in 0..b {
                    let r = s * hd..(s + 1) * hd;
                    lstm_cell_backward(
                        &a_t[s * g4..(s + 1) * g4],
                        &tc_t[r.clone()],
                        &c_prev[r.clone()],
                        &dh[r.clone()],
                        &mut dc[r],
                        &mut d_t[s * g4..(s + 1) * g4],
                    );
                }
                if t > 0 {
                    // ∂h_{t−1} (B × H) = ∂pre_t (B × 4H) · W_hh (4H × H)
                    gemm(
                        b,
                        hd,
                        g4,
                        &mut dh,
                        hd,
                        View::rows(d_t, g4),
                        View::rows(&flat[whh.offset..], whh.ld),
                        false,
                        threads,
                    );
                }
            }
            drop((dc, zeros));
            let gw = grads.get_or_alloc_mut(&wih_t)?;
            gemm(
                g4,
                FEATURE_DIM,
                n * b,
                gw,
                FEATURE_DIM,
                View::transposed(&dpre, g4),
                View::rows(&x, FEATURE_DIM),
                true,
                threads,
            );
            if n > 1 {
                let gw = grads.get_or_alloc_mut(&whh_t)?;
                gemm(
                    g4,
                    hd,
                    (n - 1) * b,
                    gw,
                    hd,
                    View::transposed(&dpre[b * g4..], g4),
                    View::rows(&h_all, hd),
                    true,
                    threads,
                );
            }
            let mut gb = pool.zeros(g4);
            add_column_sums(&dpre, g4, &mut gb);
            for bias in [&bih_t, &bhh_t] {
                for (o, v) in grads.get_or_alloc_mut(bias)?.iter_mut().zip(gb.iter()) {
                    *o += v;
                }
            }
            put_grad(grads, &y_id, gh)
        });
        Node {
            t: y.put_tape(tape),
            v: Rc::new(h_last),
        }
    }

    /// Values `(B, 1)` (and SARL's attention weights `(B·N)`).
    fn forward(&mut self, net: &ValueNet, states: StateBatch<'_>) -> (Node, Option<Rc<Buf>>) {
        match net.index() {
            NetIndex::Sarl(ix) => {
                let (v, a) = self.sarl(ix, states);
                (v, Some(a))
            }
            NetIndex::Lstm(ix) => {
                let h = self.lstm(ix, states);
                let robot = self.robot(states);
                (self.head(robot, h, &ix.mlp), None)
            }
        }
    }
}

/// Reusable state for computing gradients over (part of) a batch: a dfdx CPU device with its
/// allocation cache on, the host buffer pool, and the gradient in flat layout.
#[derive(Debug)]
pub(crate) struct Shard {
    dev: Cpu,
    pool: Pool,
    pub grad: Vec<f32>,
}

impl Shard {
    pub fn new(num_params: usize) -> Self {
        let dev = Cpu::default();
        // Tensor storage and gradients are recycled between passes (every pass allocates the
        // same sizes, all through the cache: see `Ctx::tensor`).
        dev.enable_cache();
        Self {
            dev,
            pool: Pool::default(),
            grad: vec![0.0; num_params],
        }
    }
}

fn check_lengths(
    net: &ValueNet,
    states: StateBatch<'_>,
    targets: &[f32],
    grad: &[f32],
) -> Result<(), PolicyError> {
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
    Ok(())
}

/// `scale · Σ_b (V(s_b) − y_b)²` and its gradient (flat layout, overwritten) through the dfdx
/// graph, the weights read from `flat` (a copy of `net`'s).
#[allow(clippy::too_many_arguments)]
fn loss_and_grad(
    net: &ValueNet,
    flat: &Arc<Vec<f32>>,
    dev: &Cpu,
    pool: &Pool,
    threads: Threads,
    states: StateBatch<'_>,
    targets: &[f32],
    scale: f32,
    grad: &mut [f32],
) -> Result<f32, PolicyError> {
    check_lengths(net, states, targets, grad)?;
    let b = states.batch();
    let mut ctx = Ctx::new(dev, pool, flat, threads);
    let (v, _) = ctx.forward(net, states);
    let mut y: Tensor<(usize,), f32, Cpu> = dev.zeros_like(&(b,));
    y.copy_from(targets);
    let loss = (v.t.reshape_like(&(b,)) - y).square().sum::<(), Axis<0>>() * scale;
    let value = loss.array();
    let mut grads = loss.backward();
    grad.fill(0.0);
    ctx.scatter_grads(&mut grads, grad)?;
    Ok(value)
}

/// Values `(B)` (and SARL's attention weights `(B·N)`) through the dfdx graph, no backward.
pub fn values_dfdx(
    net: &ValueNet,
    dev: &Cpu,
    states: StateBatch<'_>,
) -> (Vec<f32>, Option<Vec<f32>>) {
    let (pool, flat) = (Pool::default(), Arc::new(net.params().to_vec()));
    let mut ctx = Ctx::new(dev, &pool, &flat, Threads::Rayon);
    let (v, a) = ctx.forward(net, states);
    (v.t.as_vec(), a.map(|a| a.to_vec()))
}

/// Mean-squared error `mean_b (V(s_b) − y_b)²` and its gradient with respect to every
/// parameter, written into `grad` (flat layout, overwritten). dfdx autodiff, one pass over the
/// whole batch (matrix products over `rayon::current_num_threads()` threads).
pub fn mse_loss_and_grad(
    net: &ValueNet,
    dev: &Cpu,
    states: StateBatch<'_>,
    targets: &[f32],
    grad: &mut [f32],
) -> Result<f32, PolicyError> {
    let (pool, flat) = (Pool::default(), Arc::new(net.params().to_vec()));
    let scale = 1.0 / states.batch() as f32;
    loss_and_grad(
        net,
        &flat,
        dev,
        &pool,
        Threads::Rayon,
        states,
        targets,
        scale,
        grad,
    )
}

/// Samples per shard below which a batch is not split.
const MIN_SHARD_SAMPLES: usize = 32;

/// How many shards [`sharded_loss_and_grad`] splits a batch of `b` samples into: one per rayon
/// thread, each of at least [`MIN_SHARD_SAMPLES`] samples.
pub(crate) fn shard_count(b: usize) -> usize {
    rayon::current_num_threads()
        .min(b / MIN_SHARD_SAMPLES)
        .max(1)
}

/// [`mse_loss_and_grad`] with the batch split into [`shard_count`] contiguous parts, one dfdx
/// graph each, run in parallel on rayon's threads (each single-threaded inside); the parts'
/// gradients are added in shard order, so the result is a pure function of the inputs and the
/// thread count. With one shard the matrix products themselves use the rayon threads.
/// `flat` must hold `net`'s weights; `shards` grows as needed; `grad` is overwritten.
pub(crate) fn sharded_loss_and_grad(
    net: &ValueNet,
    flat: &Arc<Vec<f32>>,
    shards: &mut Vec<Shard>,
    states: StateBatch<'_>,
    targets: &[f32],
    grad: &mut [f32],
) -> Result<f32, PolicyError> {
    use rayon::prelude::*;
    check_lengths(net, states, targets, grad)?;
    let (b, n) = (states.batch(), states.humans());
    let k = shard_count(b);
    while shards.len() < k {
        shards.push(Shard::new(net.num_params()));
    }
    let scale = 1.0 / b as f32;
    if k == 1 {
        let sh = &mut shards[0];
        return loss_and_grad(
            net,
            flat,
            &sh.dev,
            &sh.pool,
            Threads::Rayon,
            states,
            targets,
            scale,
            grad,
        );
    }
    let row = n * FEATURE_DIM;
    let losses = shards[..k]
        .par_iter_mut()
        .enumerate()
        .map(|(i, sh)| {
            let (s0, s1) = (i * b / k, (i + 1) * b / k);
            let part = StateBatch::new(&states.data()[s0 * row..s1 * row], s1 - s0, n)?;
            loss_and_grad(
                net,
                flat,
                &sh.dev,
                &sh.pool,
                Threads::One,
                part,
                &targets[s0..s1],
                scale,
                &mut sh.grad,
            )
        })
        .collect::<Vec<_>>();
    let mut loss = 0.0;
    for l in losses {
        loss += l?;
    }
    grad.copy_from_slice(&shards[0].grad);
    for sh in &shards[1..k] {
        for (g, v) in grad.iter_mut().zip(&sh.grad) {
            *g += v;
        }
    }
    Ok(loss)
}
