//! [`Weights`]: a versioned snapshot of the value network, learner → actors and evaluator.

use serde::{Deserialize, Serialize};

use crate::columns::{check_finite, check_len, check_max, check_name, f32_le, f32_le_bytes};
use crate::error::ValidationError;
use crate::header::{Body, MessageKind};

/// Most parameters a weight message may carry (16 Mi f32 = 64 MiB; SARL has 96 502).
pub const MAX_PARAMS: u64 = 16 * 1024 * 1024;
/// Most tensors in a network description.
pub const MAX_TENSORS: usize = 1024;
/// Most dimensions per tensor.
pub const MAX_TENSOR_RANK: usize = 8;
/// Longest tensor name, in bytes.
pub const MAX_TENSOR_NAME_LEN: usize = 128;

/// The network family.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum NetworkKind {
    /// SARL value network (also FSRL's).
    #[serde(rename = "sarl")]
    Sarl,
    /// LSTM-RL value network.
    #[serde(rename = "lstm-rl")]
    LstmRl,
}

/// One parameter tensor: its name and shape. Parameters are stored flat, tensor after tensor
/// in the order of [`NetworkDesc::tensors`], each row-major.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TensorDesc {
    /// Name, `[a-z0-9_./-]`, e.g. `mlp1.0.weight`.
    pub name: String,
    /// Shape, e.g. `[150, 13]` for a 13 → 150 linear layer's weight.
    pub shape: Vec<u32>,
}

impl TensorDesc {
    /// A tensor description.
    pub fn new(name: impl Into<String>, shape: impl Into<Vec<u32>>) -> Self {
        Self {
            name: name.into(),
            shape: shape.into(),
        }
    }

    /// Number of elements (None on overflow).
    pub fn numel(&self) -> Option<u64> {
        self.shape
            .iter()
            .try_fold(1u64, |acc, d| acc.checked_mul(u64::from(*d)))
    }
}

/// What the flat parameter vector is: network kind and its tensors (layer sizes).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct NetworkDesc {
    /// Network family.
    pub kind: NetworkKind,
    /// Parameter tensors in storage order.
    pub tensors: Vec<TensorDesc>,
}

impl NetworkDesc {
    /// Total parameter count, or an error if the description is invalid.
    pub fn param_count(&self) -> Result<u64, ValidationError> {
        check_max(
            "network.tensors",
            self.tensors.len() as u64,
            MAX_TENSORS as u64,
        )?;
        let mut total = 0u64;
        for t in &self.tensors {
            check_name("network.tensors.name", &t.name, MAX_TENSOR_NAME_LEN)?;
            check_max(
                "network.tensors.shape",
                t.shape.len() as u64,
                MAX_TENSOR_RANK as u64,
            )?;
            let n = t.numel().ok_or(ValidationError::LimitExceeded {
                field: "network.tensors.shape",
                value: u64::MAX,
                limit: MAX_PARAMS,
            })?;
            total = total.saturating_add(n);
            check_max("network.param_count", total, MAX_PARAMS)?;
        }
        Ok(total)
    }
}

/// Versioned weights. `crc32` is the CRC-32 (IEEE, as `zlib.crc32`) of the little-endian bytes
/// of `params`, checked on decode along with finiteness and the length implied by `network`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Weights {
    /// Monotonically increasing version (the learner's update counter at export).
    pub version: u64,
    /// What the parameters are.
    pub network: NetworkDesc,
    /// All parameters, flat, in tensor order.
    #[serde(with = "f32_le")]
    pub params: Vec<f32>,
    /// CRC-32 of the parameter bytes.
    pub crc32: u32,
    /// RL episodes the learner had taken in when it exported these weights. Absent from older
    /// learners, whose versions advanced once per RL episode after imitation; in the adaptive
    /// mode (`train.rl.replay_ratio`) a version is a round of updates, so only this says how
    /// far the run is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rl_episodes: Option<u64>,
}

impl Weights {
    /// The same weights, saying how many RL episodes they were trained on.
    pub fn with_rl_episodes(mut self, rl_episodes: u64) -> Self {
        self.rl_episodes = Some(rl_episodes);
        self
    }

    /// Builds a weight message, computing the checksum and validating everything.
    pub fn new(
        version: u64,
        network: NetworkDesc,
        params: Vec<f32>,
    ) -> Result<Self, ValidationError> {
        let crc32 = params_crc32(&params);
        let w = Self {
            version,
            network,
            params,
            crc32,
            rl_episodes: None,
        };
        w.validate()?;
        Ok(w)
    }
}

/// CRC-32 of the little-endian bytes of `params`.
pub fn params_crc32(params: &[f32]) -> u32 {
    crc32fast::hash(&f32_le_bytes(params))
}

impl Body for Weights {
    const KIND: MessageKind = MessageKind::Weights;

    fn validate(&self) -> Result<(), ValidationError> {
        let n = self.network.param_count()?;
        check_len(
            "params",
            self.params.len(),
            usize::try_from(n).unwrap_or(usize::MAX),
        )?;
        check_finite("params", &self.params)?;
        let computed = params_crc32(&self.params);
        if computed != self.crc32 {
            return Err(ValidationError::ChecksumMismatch {
                expected: self.crc32,
                computed,
            });
        }
        Ok(())
    }
}
