//! [`ValueNet`]: a network description plus its flat parameter vector; its input is a
//! [`StateBatch`].

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::batch::StateBatch;
use crate::config::{NetConfig, NetIndex, NetKind, ParamLayout};
use crate::fast::{self, Scratch};
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
}
