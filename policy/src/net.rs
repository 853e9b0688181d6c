//! [`ValueNet`]: a network description plus its flat parameter vector, and [`StateBatch`], the
//! network input.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::config::{NetConfig, NetIndex, NetKind, ParamLayout};
use crate::fast::{self, Scratch};
use crate::{PolicyError, FEATURE_DIM, ROBOT_DIM};

/// A borrowed batch of joint states: `batch` samples × `humans` rows × 13 features, row-major
/// and contiguous (`data[(sample · humans + human) · 13 + feature]`).
///
/// Row layout (CrowdNav `rotate()`): `[d_g, v_pref, θ_rel, r, v_x, v_y | p_x, p_y, v_x, v_y, r_i,
/// d_i, r_i + r]`. The robot's 6 features are read from each sample's **row 0**; every sample has
/// the same number of humans. LSTM-RL reads the rows in the given order (the featurisation sorts
/// them by decreasing distance).
#[derive(Clone, Copy, Debug)]
pub struct StateBatch<'a> {
    data: &'a [f32],
    batch: usize,
    humans: usize,
}

impl<'a> StateBatch<'a> {
    /// Wraps `data`, checking `data.len() == batch × humans × 13` and `batch, humans ≥ 1`.
    pub fn new(data: &'a [f32], batch: usize, humans: usize) -> Result<Self, PolicyError> {
        if batch == 0 || humans == 0 {
            return Err(PolicyError::EmptyBatch { batch, humans });
        }
        let expected = batch * humans * FEATURE_DIM;
        if data.len() != expected {
            return Err(PolicyError::StateShape {
                len: data.len(),
                batch,
                humans,
                expected,
            });
        }
        Ok(Self {
            data,
            batch,
            humans,
        })
    }

    /// The flat values.
    pub fn data(&self) -> &'a [f32] {
        self.data
    }

    /// Number of samples `B`.
    pub fn batch(&self) -> usize {
        self.batch
    }

    /// Humans per sample `N`.
    pub fn humans(&self) -> usize {
        self.humans
    }

    /// Total rows `B · N`.
    pub fn rows(&self) -> usize {
        self.batch * self.humans
    }

    /// Sample `i`'s robot features (the first 6 values of its row 0).
    pub fn robot(&self, i: usize) -> &'a [f32] {
        let s = i * self.humans * FEATURE_DIM;
        &self.data[s..s + ROBOT_DIM]
    }
}

/// A value network: SARL or LSTM-RL, described by a [`NetConfig`], with all weights in one flat
/// `Vec<f32>` in the order documented in [`crate::config`].
///
/// Inference ([`ValueNet::values`]) runs a hand-written single-threaded path on the flat weights;
/// training goes through dfdx autodiff ([`crate::train`]). Both compute the same function.
#[derive(Clone, Debug)]
pub struct ValueNet {
    config: NetConfig,
    layout: ParamLayout,
    index: NetIndex,
    params: Vec<f32>,
}

impl ValueNet {
    /// A freshly initialised network, PyTorch's default init: every linear layer's weight and
    /// bias from U(−1/√fan_in, 1/√fan_in), LSTM tensors from U(−1/√H, 1/√H). Values are drawn
    /// from ChaCha8(`seed`) in flat-layout order, so a seed gives the same weights everywhere.
    pub fn new(config: NetConfig, seed: u64) -> Result<Self, PolicyError> {
        config.validate()?;
        let layout = config.layout();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut params = Vec::with_capacity(layout.len());
        for spec in layout.specs() {
            let b = spec.init_bound as f32;
            params.extend((0..spec.len()).map(|_| rng.gen_range(-b..b)));
        }
        Ok(Self::assemble(config, layout, params))
    }

    /// Rebuilds a network from its description and flat weights (e.g. from a checkpoint or a
    /// weight broadcast). Rejects a wrong length or a non-finite value.
    pub fn from_params(config: NetConfig, params: Vec<f32>) -> Result<Self, PolicyError> {
        config.validate()?;
        let layout = config.layout();
        check_params(config.kind(), layout.len(), &params)?;
        Ok(Self::assemble(config, layout, params))
    }

    fn assemble(config: NetConfig, layout: ParamLayout, params: Vec<f32>) -> Self {
        let index = NetIndex::new(&config, &layout);
        Self {
            config,
            layout,
            index,
            params,
        }
    }

    /// The description (enough to rebuild the network).
    pub fn config(&self) -> &NetConfig {
        &self.config
    }

    /// The family.
    pub fn kind(&self) -> NetKind {
        self.config.kind()
    }

    /// The flat layout.
    pub fn layout(&self) -> &ParamLayout {
        &self.layout
    }

    /// Number of parameters.
    pub fn num_params(&self) -> usize {
        self.params.len()
    }

    /// The flat weights, in layout order.
    pub fn params(&self) -> &[f32] {
        &self.params
    }

    /// Replaces all weights (same length, all finite), e.g. on a weight broadcast.
    pub fn set_params(&mut self, params: &[f32]) -> Result<(), PolicyError> {
        check_params(self.kind(), self.params.len(), params)?;
        self.params.copy_from_slice(params);
        Ok(())
    }

    /// Mutable access for the optimiser.
    pub(crate) fn params_mut(&mut self) -> &mut [f32] {
        &mut self.params
    }

    pub(crate) fn index(&self) -> &NetIndex {
        &self.index
    }

    /// State values `V(s)` for every sample of `states`, shape `(B)`.
    pub fn values(&self, states: StateBatch<'_>) -> Vec<f32> {
        let mut scratch = Scratch::default();
        let mut out = vec![0.0; states.batch()];
        self.values_into(states, &mut scratch, &mut out);
        out
    }

    /// [`ValueNet::values`] without allocating: `out` must hold `B` values (panics otherwise);
    /// `scratch` is reused between calls. Single-threaded.
    pub fn values_into(&self, states: StateBatch<'_>, scratch: &mut Scratch, out: &mut [f32]) {
        assert_eq!(
            out.len(),
            states.batch(),
            "output length must equal the batch size"
        );
        match &self.index {
            NetIndex::Sarl(ix) => fast::sarl_forward(ix, &self.params, states, scratch, out),
            NetIndex::Lstm(ix) => fast::lstm_forward(ix, &self.params, states, scratch, out),
        }
    }

    /// SARL's attention weights from the last [`ValueNet::values_into`] with this `scratch`:
    /// `(B, N)` row-major, each row sums to one. `None` for LSTM-RL.
    pub fn attention<'s>(&self, scratch: &'s Scratch) -> Option<&'s [f32]> {
        match self.index {
            NetIndex::Sarl(_) => Some(scratch.attention()),
            NetIndex::Lstm(_) => None,
        }
    }
}

fn check_params(kind: NetKind, expected: usize, params: &[f32]) -> Result<(), PolicyError> {
    if params.len() != expected {
        return Err(PolicyError::ParamCount {
            kind: kind.name(),
            expected,
            got: params.len(),
        });
    }
    if !params.iter().all(|v| v.is_finite()) {
        return Err(PolicyError::NonFinite("network parameters"));
    }
    Ok(())
}
