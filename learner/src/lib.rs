//! `learner`: the learner role. [`core::LearnerCore`] holds replay, trainer, schedule and
//! counters with no transport attached, so the same code trains in one process (`fsrl train
//! --single-process`) and behind the wire; [`checkpoint`] saves and restores all of it.

pub mod checkpoint;
pub mod core;
pub mod imitation;
pub mod process;
pub mod replay;
pub mod wal;

pub use crate::core::{Counters, LearnerCore, LearnerError};
