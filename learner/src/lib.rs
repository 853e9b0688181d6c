//! `learner`: the learner role. [`core::LearnerCore`] holds replay, trainer, schedule and
//! counters with no transport attached, so the same code trains in one process (`fsrl train
//! --single-process`) and behind the wire; [`checkpoint`] saves and restores all of it;
//! [`model`] keeps only the trained policy, to ship (`.fsrlm` files); [`record`] holds the
//! learner process's final figures, part of the run's record.

pub mod checkpoint;
pub mod core;
mod frame;
pub mod imitation;
pub mod model;
#[cfg(feature = "process")]
pub mod process;
pub mod record;
pub mod replay;
pub mod runlog;
pub mod store;
pub mod wal;

pub use crate::core::{Counters, LearnerCore, LearnerError};
