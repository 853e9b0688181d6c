//! `policy`: the value networks of fsrl (SARL, also FSRL's network, and LSTM-RL) on dfdx (CPU).
//!
//! - [`NetConfig`] describes a network (family and layer sizes, SPEC §4); [`ValueNet`] holds one
//!   with its weights in a single flat `Vec<f32>` (order in [`config`]), initialised like
//!   PyTorch from a seed.
//! - Inference: [`ValueNet::values`] / [`ValueNet::values_into`] take a [`StateBatch`]
//!   `(B, N, 13)` and return `(B)` values, on a hand-written single-threaded `gemm` path
//!   (SARL's attention weights via [`ValueNet::attention`]).
//! - Training: [`graph::mse_loss_and_grad`] runs the same network as a dfdx autodiff graph;
//!   [`train::Trainer`] adds Adam ([`optim::Adam`]) and a target network.
//! - Weights and optimiser state are saved and loaded bit-exactly ([`codec`]).

mod batch;
pub mod codec;
pub mod config;
mod error;
mod fast;
pub mod graph;
pub mod joint;
mod kernels;
pub mod lookahead;
pub mod method;
mod net;
pub mod optim;
#[cfg(test)]
mod reference;
pub mod rollout;
#[cfg(test)]
mod tests;
pub mod train;
pub mod wire;

pub use batch::StateBatch;
pub use config::{LstmRlConfig, NetConfig, NetKind, ParamLayout, ParamSpec, SarlConfig};
pub use error::PolicyError;
pub use fast::Scratch;
pub use net::ValueNet;

/// Robot features at the start of every row: `[d_g, v_pref, θ_rel, r, v_x, v_y]`.
pub const ROBOT_DIM: usize = 6;
/// Human features after them: `[p_x, p_y, v_x, v_y, r_i, d_i, r_i + r]`.
pub const HUMAN_DIM: usize = 7;
/// Features per row (robot + human).
pub const FEATURE_DIM: usize = ROBOT_DIM + HUMAN_DIM;
