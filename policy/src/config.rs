//! Network descriptions (layer sizes) and the flat parameter layout they imply.
//!
//! A [`NetConfig`] is all a reader needs to rebuild a network: the layout of the flat
//! parameter vector follows from it ([`NetConfig::layout`]), and the weights come in that order.
//!
//! # Flat parameter order
//! Every linear layer contributes its weight, shape `(out, in)` row-major (PyTorch's
//! `nn.Linear.weight`), then its bias `(out)`. Names follow CrowdNav's `state_dict` keys.
//! - **SARL**: `mlp1.*`, `mlp2.*`, `attention.*`, `mlp3.*`, each in layer order; linear layer `k`
//!   of a block is named `<block>.<2k>.weight` / `.bias` (ReLUs sit at the odd indices).
//!   `attention.0.weight` has `2 · mlp1_out` columns: `[e_i | mean_j e_j]`.
//!   `mlp3.0.weight` has `6 + mlp2_out` columns: `[robot | attended feature]`.
//! - **LSTM-RL**: `mlp.*` (first weight's columns: `[robot 6 | h_N]`), then
//!   `lstm.weight_ih_l0 (4H, 13)`, `lstm.weight_hh_l0 (4H, H)`, `lstm.bias_ih_l0 (4H)`,
//!   `lstm.bias_hh_l0 (4H)`, gate blocks in PyTorch's order i, f, g, o.

use crate::{PolicyError, FEATURE_DIM, ROBOT_DIM};

/// Which network family.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum NetKind {
    /// SARL's attention network (also FSRL's).
    Sarl,
    /// LSTM-RL (CrowdNav's `ValueNetwork1`: no interaction module).
    LstmRl,
}

impl NetKind {
    /// Stable lower-case name (`"sarl"`, `"lstm-rl"`).
    pub fn name(self) -> &'static str {
        match self {
            NetKind::Sarl => "sarl",
            NetKind::LstmRl => "lstm-rl",
        }
    }
}

/// SARL layer sizes (CrowdNav `policy.config [sarl]`). Hidden ReLUs as in CrowdNav: every layer
/// of `mlp1` (last included), between the layers of `mlp2`, `attention` and `mlp3`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SarlConfig {
    /// Per-human embedding, from 13 inputs: default `[150, 100]`.
    pub mlp1_dims: Vec<usize>,
    /// Per-human feature, from `mlp1`'s output: default `[100, 50]`.
    pub mlp2_dims: Vec<usize>,
    /// Attention scorer on `[e_i, mean_j e_j]`, last size must be 1: default `[100, 100, 1]`.
    pub attention_dims: Vec<usize>,
    /// Value head on `[robot 6 | attended]`, last size must be 1: default `[150, 100, 100, 1]`.
    pub mlp3_dims: Vec<usize>,
}

impl Default for SarlConfig {
    fn default() -> Self {
        Self {
            mlp1_dims: vec![150, 100],
            mlp2_dims: vec![100, 50],
            attention_dims: vec![100, 100, 1],
            mlp3_dims: vec![150, 100, 100, 1],
        }
    }
}

/// LSTM-RL sizes (CrowdNav `policy.config [lstm_rl]`, `with_interaction_module = false`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LstmRlConfig {
    /// LSTM hidden size (`global_state_dim`): default 50.
    pub hidden_dim: usize,
    /// Value head on `[robot 6 | h_N]`, last size must be 1: default `[150, 100, 100, 1]`.
    pub mlp_dims: Vec<usize>,
}

impl Default for LstmRlConfig {
    fn default() -> Self {
        Self {
            hidden_dim: 50,
            mlp_dims: vec![150, 100, 100, 1],
        }
    }
}

/// A complete network description: family and layer sizes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum NetConfig {
    /// SARL / FSRL.
    Sarl(SarlConfig),
    /// LSTM-RL.
    LstmRl(LstmRlConfig),
}

impl NetConfig {
    /// The paper's SARL network (96,502 parameters).
    pub fn sarl() -> Self {
        NetConfig::Sarl(SarlConfig::default())
    }

    /// The paper's LSTM-RL network (46,851 parameters).
    pub fn lstm_rl() -> Self {
        NetConfig::LstmRl(LstmRlConfig::default())
    }

    /// The family.
    pub fn kind(&self) -> NetKind {
        match self {
            NetConfig::Sarl(_) => NetKind::Sarl,
            NetConfig::LstmRl(_) => NetKind::LstmRl,
        }
    }

    /// Checks every size at once; the error lists all problems.
    pub fn validate(&self) -> Result<(), PolicyError> {
        let mut problems = Vec::new();
        let mut check = |name: &str, dims: &[usize], last_one: bool| {
            if dims.is_empty() {
                problems.push(format!("{name} has no layers"));
            }
            if dims.contains(&0) {
                problems.push(format!("{name} has a layer of size 0: {dims:?}"));
            }
            if last_one && dims.last().is_some_and(|&d| d != 1) {
                problems.push(format!("{name} must end in size 1, got {dims:?}"));
            }
        };
        match self {
            NetConfig::Sarl(c) => {
                check("mlp1_dims", &c.mlp1_dims, false);
                check("mlp2_dims", &c.mlp2_dims, false);
                check("attention_dims", &c.attention_dims, true);
                check("mlp3_dims", &c.mlp3_dims, true);
            }
            NetConfig::LstmRl(c) => {
                check("mlp_dims", &c.mlp_dims, true);
                if c.hidden_dim == 0 {
                    problems.push("hidden_dim is 0".to_owned());
                }
            }
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(PolicyError::Config(problems.join("; ")))
        }
    }

    /// The flat parameter layout. Call [`NetConfig::validate`] first.
    pub fn layout(&self) -> ParamLayout {
        let mut b = LayoutBuilder::default();
        match self {
            NetConfig::Sarl(c) => {
                let d_e = *c.mlp1_dims.last().unwrap_or(&0);
                let d_h = *c.mlp2_dims.last().unwrap_or(&0);
                b.mlp("mlp1", FEATURE_DIM, &c.mlp1_dims);
                b.mlp("mlp2", d_e, &c.mlp2_dims);
                b.mlp("attention", 2 * d_e, &c.attention_dims);
                b.mlp("mlp3", ROBOT_DIM + d_h, &c.mlp3_dims);
            }
            NetConfig::LstmRl(c) => {
                let h = c.hidden_dim;
                let bound = 1.0 / (h as f64).sqrt();
                b.mlp("mlp", ROBOT_DIM + h, &c.mlp_dims);
                b.push("lstm.weight_ih_l0", 4 * h, FEATURE_DIM, bound);
                b.push("lstm.weight_hh_l0", 4 * h, h, bound);
                b.push("lstm.bias_ih_l0", 4 * h, 1, bound);
                b.push("lstm.bias_hh_l0", 4 * h, 1, bound);
            }
        }
        ParamLayout {
            specs: b.specs,
            len: b.len,
        }
    }

    /// Number of parameters.
    pub fn num_params(&self) -> usize {
        self.layout().len()
    }

    /// Multiply-accumulates of one forward pass over `batch` samples of `humans` humans, as
    /// CrowdNav computes it (matrix products only; used for GFLOP/s figures).
    pub fn forward_macs(&self, batch: usize, humans: usize) -> u64 {
        let chain = |inp: usize, dims: &[usize]| -> u64 {
            let mut prev = inp;
            let mut macs = 0u64;
            for &d in dims {
                macs += (prev * d) as u64;
                prev = d;
            }
            macs
        };
        let rows = (batch * humans) as u64;
        match self {
            NetConfig::Sarl(c) => {
                let d_e = *c.mlp1_dims.last().unwrap_or(&0);
                let d_h = *c.mlp2_dims.last().unwrap_or(&0);
                rows * (chain(FEATURE_DIM, &c.mlp1_dims)
                    + chain(d_e, &c.mlp2_dims)
                    + chain(2 * d_e, &c.attention_dims)
                    + d_h as u64)
                    + batch as u64 * chain(ROBOT_DIM + d_h, &c.mlp3_dims)
            }
            NetConfig::LstmRl(c) => {
                let h = c.hidden_dim;
                rows * (4 * h * (FEATURE_DIM + h)) as u64
                    + batch as u64 * chain(ROBOT_DIM + h, &c.mlp_dims)
            }
        }
    }
}

/// One named tensor inside the flat parameter vector.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamSpec {
    /// CrowdNav/PyTorch `state_dict` key, e.g. `mlp1.0.weight`.
    pub name: String,
    /// Rows (output features).
    pub rows: usize,
    /// Columns (input features; 1 for a bias).
    pub cols: usize,
    /// First index in the flat vector.
    pub offset: usize,
    /// PyTorch default init bound `b`: values are drawn from U(−b, b).
    pub init_bound: f64,
}

impl ParamSpec {
    /// Number of values.
    pub fn len(&self) -> usize {
        self.rows * self.cols
    }

    /// Whether the tensor is empty (never, for a validated config).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The index range in the flat vector.
    pub fn range(&self) -> std::ops::Range<usize> {
        self.offset..self.offset + self.len()
    }
}

/// The ordered list of tensors of a network's flat parameter vector.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamLayout {
    specs: Vec<ParamSpec>,
    len: usize,
}

impl ParamLayout {
    /// Tensors in flat order.
    pub fn specs(&self) -> &[ParamSpec] {
        &self.specs
    }

    /// Total number of parameters.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are no parameters.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The tensor called `name`.
    pub fn get(&self, name: &str) -> Option<&ParamSpec> {
        self.specs.iter().find(|s| s.name == name)
    }
}

#[derive(Default)]
struct LayoutBuilder {
    specs: Vec<ParamSpec>,
    len: usize,
}

impl LayoutBuilder {
    fn push(&mut self, name: &str, rows: usize, cols: usize, init_bound: f64) {
        self.specs.push(ParamSpec {
            name: name.to_owned(),
            rows,
            cols,
            offset: self.len,
            init_bound,
        });
        self.len += rows * cols;
    }

    fn mlp(&mut self, block: &str, inp: usize, dims: &[usize]) {
        let mut prev = inp;
        for (k, &d) in dims.iter().enumerate() {
            let bound = 1.0 / (prev as f64).sqrt();
            self.push(&format!("{block}.{}.weight", 2 * k), d, prev, bound);
            self.push(&format!("{block}.{}.bias", 2 * k), d, 1, bound);
            prev = d;
        }
    }
}

/// A (sub-)matrix inside the flat vector: `rows × cols` values, row `r` starting at
/// `offset + r · ld`. Lets a layer's weight be split by columns without copying.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Mat {
    pub offset: usize,
    pub rows: usize,
    pub cols: usize,
    pub ld: usize,
}

impl Mat {
    fn whole(spec: &ParamSpec) -> Self {
        Mat {
            offset: spec.offset,
            rows: spec.rows,
            cols: spec.cols,
            ld: spec.cols,
        }
    }

    /// Columns `start..end` of this matrix.
    pub fn cols(self, start: usize, end: usize) -> Self {
        Mat {
            offset: self.offset + start,
            rows: self.rows,
            cols: end - start,
            ld: self.ld,
        }
    }

    /// Appends the values to `out`, row-major and dense.
    pub fn gather_into(&self, params: &[f32], out: &mut Vec<f32>) {
        for r in 0..self.rows {
            let s = self.offset + r * self.ld;
            out.extend_from_slice(&params[s..s + self.cols]);
        }
    }

    /// Adds a dense row-major `rows × cols` block into its place in `flat`.
    pub fn scatter_add(&self, dense: &[f32], flat: &mut [f32]) {
        for r in 0..self.rows {
            let s = self.offset + r * self.ld;
            let src = &dense[r * self.cols..(r + 1) * self.cols];
            for (d, v) in flat[s..s + self.cols].iter_mut().zip(src) {
                *d += *v;
            }
        }
    }
}

/// A linear layer `y = x Wᵀ + b`: `w` is `(out, in)`, `b` is `(out, 1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Linear {
    pub w: Mat,
    pub b: Mat,
}

impl Linear {
    pub fn out_dim(&self) -> usize {
        self.w.rows
    }
}

/// Where SARL's layers live in the flat vector.
#[derive(Clone, Debug)]
pub(crate) struct SarlIndex {
    pub mlp1: Vec<Linear>,
    pub mlp2: Vec<Linear>,
    pub attention: Vec<Linear>,
    pub mlp3: Vec<Linear>,
}

/// Where LSTM-RL's tensors live in the flat vector.
#[derive(Clone, Debug)]
pub(crate) struct LstmIndex {
    pub hidden: usize,
    pub mlp: Vec<Linear>,
    pub w_ih: Mat,
    pub w_hh: Mat,
    pub b_ih: Mat,
    pub b_hh: Mat,
}

/// Layer positions for a network.
#[derive(Clone, Debug)]
pub(crate) enum NetIndex {
    Sarl(SarlIndex),
    Lstm(LstmIndex),
}

fn linears(layout: &ParamLayout, block: &str) -> Vec<Linear> {
    let mut out = Vec::new();
    for k in 0.. {
        let (Some(w), Some(b)) = (
            layout.get(&format!("{block}.{}.weight", 2 * k)),
            layout.get(&format!("{block}.{}.bias", 2 * k)),
        ) else {
            break;
        };
        out.push(Linear {
            w: Mat::whole(w),
            b: Mat::whole(b),
        });
    }
    out
}

impl NetIndex {
    pub fn new(config: &NetConfig, layout: &ParamLayout) -> Self {
        match config {
            NetConfig::Sarl(_) => NetIndex::Sarl(SarlIndex {
                mlp1: linears(layout, "mlp1"),
                mlp2: linears(layout, "mlp2"),
                attention: linears(layout, "attention"),
                mlp3: linears(layout, "mlp3"),
            }),
            NetConfig::LstmRl(c) => {
                let get = |n: &str| Mat::whole(layout.get(n).expect("LSTM layout has all tensors"));
                NetIndex::Lstm(LstmIndex {
                    hidden: c.hidden_dim,
                    mlp: linears(layout, "mlp"),
                    w_ih: get("lstm.weight_ih_l0"),
                    w_hh: get("lstm.weight_hh_l0"),
                    b_ih: get("lstm.bias_ih_l0"),
                    b_hh: get("lstm.bias_hh_l0"),
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parameter_counts_match_crowdnav() {
        assert_eq!(NetConfig::sarl().num_params(), 96_502);
        assert_eq!(NetConfig::lstm_rl().num_params(), 46_851);
    }

    #[test]
    fn layout_names_follow_state_dict() {
        let l = NetConfig::sarl().layout();
        let names: Vec<&str> = l.specs().iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names[0], "mlp1.0.weight");
        assert_eq!(names[4], "mlp2.0.weight");
        assert_eq!(
            l.get("attention.0.weight").map(|s| (s.rows, s.cols)),
            Some((100, 200))
        );
        assert_eq!(
            l.get("mlp3.0.weight").map(|s| (s.rows, s.cols)),
            Some((150, 56))
        );
        assert_eq!(names.last(), Some(&"mlp3.6.bias"));
        let l = NetConfig::lstm_rl().layout();
        assert_eq!(
            l.get("lstm.weight_ih_l0").map(|s| (s.rows, s.cols)),
            Some((200, 13))
        );
        assert_eq!(
            l.specs().last().map(|s| s.name.as_str()),
            Some("lstm.bias_hh_l0")
        );
    }

    #[test]
    fn validate_reports_every_problem() {
        let bad = NetConfig::Sarl(SarlConfig {
            mlp1_dims: vec![],
            mlp2_dims: vec![10, 0],
            attention_dims: vec![10, 2],
            mlp3_dims: vec![10, 1],
        });
        let msg = bad.validate().unwrap_err().to_string();
        assert!(msg.contains("mlp1_dims has no layers"), "{msg}");
        assert!(msg.contains("mlp2_dims has a layer of size 0"), "{msg}");
        assert!(msg.contains("attention_dims must end in size 1"), "{msg}");
        assert!(NetConfig::sarl().validate().is_ok());
        assert!(NetConfig::lstm_rl().validate().is_ok());
    }
}
