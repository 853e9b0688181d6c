//! The imitation warm start, shared by the single-process trainer and the learner process:
//! ORCA demonstrations (run here: they are cheap), then epochs on Monte-Carlo returns.

use std::sync::atomic::{AtomicBool, Ordering};

use policy::method::RunSpec;
use policy::rollout::{episode_seed, rollout, Behaviour};
use sim::Env;

use crate::core::{ImitationStep, LearnerCore, LearnerError};

/// Episode-seed stream of the demonstrations.
pub const DEMO_STREAM: u64 = 0;

/// Progress of the warm start.
#[derive(Debug, Clone, Copy)]
pub enum ImitationProgress {
    Demo {
        done: u64,
        total: u64,
    },
    /// The demonstrations are in replay: their transitions and the mean and variance of their
    /// Monte-Carlo returns (an imitation loss means little without the spread of its targets).
    DemosDone {
        transitions: usize,
        target_mean: f64,
        target_var: f64,
    },
    /// A batch of an imitation epoch was fitted (epoch `epoch` from 0; `done` of `batches`).
    /// Sent after every batch, so whoever watches can drain queues and see a stop request
    /// within one batch however long an epoch is.
    Batch {
        epoch: u32,
        done: usize,
        batches: usize,
    },
    Epoch {
        done: u32,
        total: u32,
        loss: f32,
    },
}

/// Runs demonstrations and imitation epochs, then switches `core` to RL. Returns `Ok(false)`
/// if `stop` was raised (seen after each demonstration and each batch; nothing is kept: the
/// warm start is redone on the next start).
pub fn run(
    core: &mut LearnerCore,
    spec: &RunSpec,
    stop: &AtomicBool,
    mut progress: impl FnMut(ImitationProgress),
) -> Result<bool, LearnerError> {
    let il = &spec.train.imitation;
    let mut env = Env::new(spec.method_sim(), spec.setting, 0)
        .map_err(|e| LearnerError::Env(e.to_string()))?;
    for k in 0..il.episodes {
        let ep = rollout(
            &mut env,
            episode_seed(spec.seed, DEMO_STREAM, k),
            Behaviour::Orca {
                safety_space_m: il.safety_space_m,
            },
        )?;
        core.add_episode(&ep, true)?;
        progress(ImitationProgress::Demo {
            done: k + 1,
            total: il.episodes,
        });
        if stop.load(Ordering::SeqCst) {
            return Ok(false);
        }
    }
    let returns = core.replay().columns().returns;
    let n = returns.len().max(1) as f64;
    let target_mean = returns.iter().map(|&r| r as f64).sum::<f64>() / n;
    let target_var = returns
        .iter()
        .map(|&r| (r as f64 - target_mean).powi(2))
        .sum::<f64>()
        / n;
    progress(ImitationProgress::DemosDone {
        transitions: core.replay().len(),
        target_mean,
        target_var,
    });
    let total = il.epochs;
    let finished = core.imitation_steps(total, |step| {
        progress(match step {
            ImitationStep::Batch {
                epoch,
                done,
                batches,
            } => ImitationProgress::Batch {
                epoch,
                done,
                batches,
            },
            ImitationStep::Epoch { epoch, loss } => ImitationProgress::Epoch {
                done: epoch + 1,
                total,
                loss,
            },
        });
        !stop.load(Ordering::SeqCst)
    })?;
    if finished.is_none() {
        return Ok(false);
    }
    core.start_rl()?;
    Ok(true)
}
