//! TensorBoard event files of a training run, written without TensorFlow: the file format
//! (`event`: TFRecord framing with the masked CRC-32C of `crc32c`, the `Event`/`Summary`
//! protobuf fields, hand-written: the Rust crates that write these files pull a protobuf
//! runtime of their own and are not maintained), a writer (`writer`), the scalars of a run's
//! logs and live metrics under CleanRL/Sample Factory-style tags (`tags`), and the run's
//! `tb/` directory kept in step with its logs, resumed runs included (`board`).
//!
//! Read by TensorBoard (`tensorboard --logdir runs`) and by Python's
//! `tensorboard.backend.event_processing.event_accumulator.EventAccumulator`
//! (`tests/tensorboard.rs`).

pub mod board;
pub mod crc32c;
pub mod event;
pub mod tags;
pub mod writer;

pub use board::{Follower, Keeper, LiveBoard, RunBoard};
pub use event::Scalar;
pub use tags::Mode;
