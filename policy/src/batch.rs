//! [`StateBatch`], the networks' input: a borrowed batch of featurised joint states.

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
    // Crate-visible so that `ValueNet::values_split` cuts a checked batch into parts without
    // checking each again.
    pub(crate) data: &'a [f32],
    pub(crate) batch: usize,
    pub(crate) humans: usize,
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
