//! [`ValueNet`]: a network description plus its flat parameter vector; its input is a
//! [`StateBatch`].

use std::sync::OnceLock;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::batch::StateBatch;
use crate::config::{NetConfig, NetIndex, NetKind, ParamLayout};
use crate::fast::{self, PackedSarl, Scratch};
use crate::{PolicyError, FEATURE_DIM};

/// Fewest rows each thread of [`ValueNet::values_split`] takes (below, one thread is faster).
pub const MIN_ROWS_PER_THREAD: usize = 32;

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
    /// SARL's weights packed for the inference kernels, built on first use; emptied whenever
    /// the weights may change (`set_params`, `params_mut`). `None` inside: no packed kernels
    /// here (or LSTM-RL).
    packed: OnceLock<Option<PackedSarl>>,
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
            packed: OnceLock::new(),
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
        self.packed = OnceLock::new();
        Ok(())
    }

    /// Mutable access for the optimiser (the packed copy is rebuilt on the next inference).
    pub(crate) fn params_mut(&mut self) -> &mut [f32] {
        self.packed = OnceLock::new();
        &mut self.params
    }

    /// The packed weights of a SARL network where the packed kernels run.
    fn packed(&self) -> Option<&PackedSarl> {
        self.packed
            .get_or_init(|| match &self.index {
                NetIndex::Sarl(ix) => PackedSarl::new(ix, &self.params),
                NetIndex::Lstm(_) => None,
            })
            .as_ref()
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
            NetIndex::Sarl(ix) => {
                fast::sarl_forward(ix, &self.params, states, scratch, out, self.packed())
            }
            NetIndex::Lstm(ix) => fast::lstm_forward(ix, &self.params, states, scratch, out),
        }
    }

    /// [`ValueNet::values_into`] through `gemm` alone (no packed kernels): the reference the
    /// packed kernels equal bit for bit (`tests::packed_values_are_the_reference_ones`); for
    /// tests and for benches that time both in one run.
    #[doc(hidden)]
    pub fn values_reference_into(
        &self,
        states: StateBatch<'_>,
        scratch: &mut Scratch,
        out: &mut [f32],
    ) {
        assert_eq!(out.len(), states.batch());
        match &self.index {
            NetIndex::Sarl(ix) => fast::sarl_forward(ix, &self.params, states, scratch, out, None),
            NetIndex::Lstm(ix) => fast::lstm_forward(ix, &self.params, states, scratch, out),
        }
    }

    /// [`ValueNet::values_into`] with the batch split into `scratches.len()` consecutive parts,
    /// one per thread (the first on the caller's). A row's value does not depend on the rows
    /// beside it, so the values are the single-threaded ones bit for bit
    /// (`tests::split_values_are_the_single_threaded_ones`). Small batches stay on one thread.
    pub fn values_split(&self, states: StateBatch<'_>, scratches: &mut [Scratch], out: &mut [f32]) {
        assert_eq!(
            out.len(),
            states.batch(),
            "output length must equal the batch size"
        );
        let parts = scratches
            .len()
            .min(states.batch() / MIN_ROWS_PER_THREAD)
            .max(1);
        if parts <= 1 {
            self.values_into(states, &mut scratches[0], out);
            return;
        }
        let (batch, humans) = (states.batch(), states.humans());
        let stride = humans * FEATURE_DIM;
        let per = batch.div_ceil(parts);
        std::thread::scope(|scope| {
            let mut data = states.data();
            let mut rest = &mut out[..];
            let mut first = None;
            for (i, scratch) in scratches.iter_mut().take(parts).enumerate() {
                let rows = per.min(rest.len());
                if rows == 0 {
                    break;
                }
                let (chunk, tail) = data.split_at(rows * stride);
                let (values, more) = std::mem::take(&mut rest).split_at_mut(rows);
                data = tail;
                rest = more;
                let part = StateBatch {
                    data: chunk,
                    batch: rows,
                    humans,
                };
                if i == 0 {
                    first = Some((part, scratch, values));
                } else {
                    scope.spawn(move || self.values_into(part, scratch, values));
                }
            }
            if let Some((part, scratch, values)) = first {
                self.values_into(part, scratch, values);
            }
        });
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::NetConfig;

    /// Split over 2 to 4 threads, every value equals the single-threaded one bit for bit, for
    /// both networks and batch sizes around the split points; fewer rows than
    /// `MIN_ROWS_PER_THREAD` per thread stay on one.
    #[test]
    fn split_values_are_the_single_threaded_ones() {
        for config in [NetConfig::sarl(), NetConfig::lstm_rl()] {
            let humans: usize = 5;
            let net = ValueNet::new(config, 7).unwrap();
            for batch in [1, 31, 64, 65, 204, 459] {
                let data: Vec<f32> = (0..batch * humans * FEATURE_DIM)
                    .map(|i| ((i * 7919 % 1000) as f32 / 500.0) - 1.0)
                    .collect();
                let states = StateBatch::new(&data, batch, humans).unwrap();
                let want = net.values(states);
                for threads in 2..=4 {
                    let mut scratches = vec![Scratch::default(); threads];
                    let mut got = vec![f32::NAN; batch];
                    net.values_split(states, &mut scratches, &mut got);
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&got), bits(&want), "batch {batch}, {threads} threads");
                }
            }
        }
    }

    /// The packed kernels change no value: every SARL value through them equals the `gemm`
    /// reference path's bit for bit, for the paper's sizes and for odd ones (chunk and tile
    /// remainders, an attention without hidden layer, a one-layer mlp2), on random states of
    /// 1 to 22 entities and on the lookahead's own candidate batches along ORCA episodes of an
    /// open setting and of walled ones (people and wall points). Fails when a kernel sums in
    /// another order. Skipped where the packed kernels do not run.
    #[test]
    fn packed_values_are_the_reference_ones() {
        use crate::joint::{featurize_into, HumanObs, HumanOrder};
        use crate::SarlConfig;
        use sim::{Env, RobotState, Setting, SimConfig};

        if !crate::kernels::packed_kernels() {
            eprintln!("no AVX-512 here: the packed kernels do not run, nothing to compare");
            return;
        }
        let odd = SarlConfig {
            mlp1_dims: vec![37, 97],
            mlp2_dims: vec![49],
            attention_dims: vec![1],
            mlp3_dims: vec![9, 17, 1],
        };
        let deep = SarlConfig {
            mlp1_dims: vec![150, 100],
            mlp2_dims: vec![100, 50],
            attention_dims: vec![100, 33, 1],
            mlp3_dims: vec![150, 100, 100, 1],
        };
        let configs = [
            NetConfig::sarl(),
            NetConfig::Sarl(odd),
            NetConfig::Sarl(deep),
        ];
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let mut compared = 0;
        for (c, config) in configs.into_iter().enumerate() {
            for seed in 0..3u64 {
                let net = ValueNet::new(config.clone(), 100 * c as u64 + seed).unwrap();
                assert!(net.packed().is_some_and(|p| !p.is_empty()));
                let (mut s1, mut s2) = (Scratch::default(), Scratch::default());
                let mut check = |data: &[f32], batch: usize, humans: usize| {
                    let states = StateBatch::new(data, batch, humans).unwrap();
                    let (mut want, mut got) = (vec![0.0; batch], vec![0.0; batch]);
                    net.values_reference_into(states, &mut s1, &mut want);
                    net.values_into(states, &mut s2, &mut got);
                    assert_eq!(
                        bits(&got),
                        bits(&want),
                        "config {c} seed {seed} {batch}×{humans}"
                    );
                    assert_eq!(bits(s2.attention()), bits(s1.attention()));
                    compared += batch;
                };
                // Random states, features of the scale the network meets.
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                for (batch, humans) in [(1, 1), (1, 5), (7, 3), (81, 10), (145, 10), (81, 22)] {
                    let data: Vec<f32> = (0..batch * humans * FEATURE_DIM)
                        .map(|_| rng.gen_range(-4.0..4.0))
                        .collect();
                    check(&data, batch, humans);
                }
                // The lookahead's candidate batches along ORCA episodes.
                for name in ["env1-invisible", "corridor", "room-visible"] {
                    let setting: Setting = name.parse().unwrap();
                    let mut env = Env::new(SimConfig::default(), setting, seed).unwrap();
                    env.reset(seed).unwrap();
                    let (mut humans, mut walls) = (Vec::new(), Vec::new());
                    let (mut batch, mut order) = (Vec::new(), Vec::new());
                    for _ in 0..12 {
                        if env.is_done() {
                            break;
                        }
                        env.next_humans(&mut humans);
                        let mut obs: Vec<HumanObs> = humans.iter().map(HumanObs::from).collect();
                        walls.clear();
                        env.static_entities_into(&mut walls);
                        obs.extend(walls.iter().map(|&p| HumanObs::obstacle(p)));
                        let goal = env.observed_goal();
                        batch.clear();
                        let n_actions = env.action_set().len();
                        for a in 0..n_actions {
                            let next = env.preview(a).unwrap().robot_next;
                            let robot = RobotState { goal, ..next };
                            featurize_into(
                                &robot,
                                &obs,
                                HumanOrder::AsGiven,
                                &mut order,
                                &mut batch,
                            );
                        }
                        check(&batch, n_actions, obs.len());
                        let action = env.orca_robot_action(0.0);
                        env.step(action).unwrap();
                    }
                }
            }
        }
        assert!(compared > 10_000, "{compared}");
    }
}
