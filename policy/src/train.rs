//! The training step: mean-squared error against scalar targets, dfdx autodiff for the
//! gradient, Adam on the flat weights, and a target network for V-learning targets.

use std::sync::Arc;

use crate::graph::{sharded_loss_and_grad, Shard};
use crate::optim::{Adam, AdamConfig};
use crate::{PolicyError, Scratch, StateBatch, ValueNet};

/// An online network, its target copy and the online network's Adam state.
///
/// Gradients come from dfdx graphs over parts of the batch run in parallel on
/// `rayon::current_num_threads()` threads ([`crate::graph`]); a run is reproducible bit for bit
/// for a given thread count. Target values use the single-threaded inference path.
#[derive(Debug)]
pub struct Trainer {
    online: ValueNet,
    target: ValueNet,
    adam: Adam,
    /// Per-thread graph state, reused between updates.
    shards: Vec<Shard>,
    /// Copy of the online weights that the graph's backward closures read.
    snapshot: Arc<Vec<f32>>,
    grad: Vec<f32>,
    scratch: Scratch,
    td_targets: Vec<f32>,
}

impl Trainer {
    /// Starts from `net`, with the target network a copy of it and fresh Adam state.
    pub fn new(net: ValueNet, adam: AdamConfig) -> Self {
        let adam = Adam::new(adam, net.num_params());
        let target = net.clone();
        Self::assemble(net, target, adam)
    }

    /// Resumes from saved parts; all three must describe the same network.
    pub fn from_parts(online: ValueNet, target: ValueNet, adam: Adam) -> Result<Self, PolicyError> {
        if online.config() != target.config() {
            return Err(PolicyError::Config(format!(
                "online {:?} and target {:?} networks differ",
                online.config(),
                target.config()
            )));
        }
        if adam.m().len() != online.num_params() {
            return Err(PolicyError::Length {
                what: "Adam state",
                expected: online.num_params(),
                got: adam.m().len(),
            });
        }
        Ok(Self::assemble(online, target, adam))
    }

    fn assemble(online: ValueNet, target: ValueNet, adam: Adam) -> Self {
        let grad = vec![0.0; online.num_params()];
        Self {
            online,
            target,
            adam,
            shards: Vec::new(),
            snapshot: Arc::new(Vec::new()),
            grad,
            scratch: Scratch::default(),
            td_targets: Vec::new(),
        }
    }

    /// The network being trained.
    pub fn online(&self) -> &ValueNet {
        &self.online
    }

    /// The target network.
    pub fn target(&self) -> &ValueNet {
        &self.target
    }

    /// The optimiser state.
    pub fn adam(&self) -> &Adam {
        &self.adam
    }

    /// The gradient of the last [`Trainer::fit`] (flat layout).
    pub fn last_gradient(&self) -> &[f32] {
        &self.grad
    }

    /// Changes the learning rate, keeping Adam's moments (e.g. imitation → RL).
    pub fn set_learning_rate(&mut self, lr: f32) {
        self.adam.set_lr(lr);
    }

    /// Copies the online weights into the target network.
    pub fn sync_target(&mut self) {
        self.target.clone_from(&self.online);
    }

    /// One Adam step on `mean_b (V(s_b) − y_b)²`. Returns the loss before the step. A
    /// non-finite loss or gradient is an error and leaves the weights untouched.
    ///
    /// `states`: `(B, N, 13)`; `targets`: `(B)`.
    pub fn fit(&mut self, states: StateBatch<'_>, targets: &[f32]) -> Result<f32, PolicyError> {
        // The graph's closures are gone after the last update, so the snapshot is ours again.
        match Arc::get_mut(&mut self.snapshot) {
            Some(v) => {
                v.clear();
                v.extend_from_slice(self.online.params());
            }
            None => self.snapshot = Arc::new(self.online.params().to_vec()),
        }
        let loss = sharded_loss_and_grad(
            &self.online,
            &self.snapshot,
            &mut self.shards,
            states,
            targets,
            &mut self.grad,
        )?;
        if !loss.is_finite() {
            return Err(PolicyError::NonFinite("loss"));
        }
        if !self.grad.iter().all(|g| g.is_finite()) {
            return Err(PolicyError::NonFinite("gradient"));
        }
        self.adam.update(self.online.params_mut(), &self.grad);
        Ok(loss)
    }

    /// V-learning targets `y_b = r_b + discount_b · V_target(s'_b)` (discount 0 ends the
    /// episode; otherwise γ^{dt·v_pref}). `next_states`: `(B, N, 13)`; the others `(B)`.
    pub fn td_targets(
        &mut self,
        next_states: StateBatch<'_>,
        rewards: &[f32],
        discounts: &[f32],
    ) -> Result<&[f32], PolicyError> {
        let b = next_states.batch();
        for (what, buf) in [("rewards", rewards), ("discounts", discounts)] {
            if buf.len() != b {
                return Err(PolicyError::Length {
                    what,
                    expected: b,
                    got: buf.len(),
                });
            }
        }
        self.td_targets.resize(b, 0.0);
        self.target
            .values_into(next_states, &mut self.scratch, &mut self.td_targets);
        for ((y, &r), &d) in self.td_targets.iter_mut().zip(rewards).zip(discounts) {
            *y = r + d * *y;
        }
        Ok(&self.td_targets)
    }

    /// One learner update: target-network values of `next_states`, then [`Trainer::fit`] on
    /// the resulting targets. Returns the loss before the step.
    pub fn td_step(
        &mut self,
        states: StateBatch<'_>,
        next_states: StateBatch<'_>,
        rewards: &[f32],
        discounts: &[f32],
    ) -> Result<f32, PolicyError> {
        if next_states.batch() != states.batch() {
            return Err(PolicyError::Length {
                what: "next states",
                expected: states.batch(),
                got: next_states.batch(),
            });
        }
        self.td_targets(next_states, rewards, discounts)?;
        let targets = std::mem::take(&mut self.td_targets);
        let loss = self.fit(states, &targets);
        self.td_targets = targets;
        loss
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tests::random_states;
    use crate::NetConfig;

    /// A smooth synthetic value: near humans is bad, near the goal is good.
    fn synthetic_targets(data: &[f32], b: usize, n: usize) -> Vec<f32> {
        (0..b)
            .map(|s| {
                let rows = &data[s * n * 13..(s + 1) * n * 13];
                let d_goal = rows[0];
                let closest = rows
                    .chunks_exact(13)
                    .map(|r| r[11])
                    .fold(f32::MAX, f32::min);
                0.8 * (-d_goal / 4.0).exp() - 0.5 * (-closest).exp()
            })
            .collect()
    }

    fn learns(config: NetConfig) {
        let (b, n, batches) = (100, 5, 5);
        let data = random_states(b * batches, n, 17);
        let targets = synthetic_targets(&data, b * batches, n);
        let mut trainer =
            Trainer::new(ValueNet::new(config, 3).unwrap(), AdamConfig::with_lr(1e-3));
        let stride = b * n * 13;
        let full = StateBatch::new(&data, b * batches, n).unwrap();
        let mse = |net: &ValueNet| {
            let v = net.values(full);
            v.iter()
                .zip(&targets)
                .map(|(v, y)| (v - y).powi(2))
                .sum::<f32>()
                / v.len() as f32
        };
        let before = mse(trainer.online());
        for step in 0..300 {
            let k = step % batches;
            let states = StateBatch::new(&data[k * stride..(k + 1) * stride], b, n).unwrap();
            let loss = trainer.fit(states, &targets[k * b..(k + 1) * b]).unwrap();
            assert!(loss.is_finite());
        }
        let after = mse(trainer.online());
        assert!(
            after < before / 10.0,
            "{}: loss {before} → {after}",
            trainer.online().kind().name()
        );
        // The target network has not moved until synced.
        assert_ne!(trainer.online().params(), trainer.target().params());
        trainer.sync_target();
        assert_eq!(trainer.online().params(), trainer.target().params());
    }

    #[test]
    fn sarl_learns_a_synthetic_regression() {
        learns(NetConfig::sarl());
    }

    #[test]
    fn lstm_learns_a_synthetic_regression() {
        learns(NetConfig::lstm_rl());
    }

    #[test]
    fn td_step_uses_the_target_network() {
        let (b, n) = (8, 4);
        let s = random_states(b, n, 1);
        let s2 = random_states(b, n, 2);
        let (states, next) = (
            StateBatch::new(&s, b, n).unwrap(),
            StateBatch::new(&s2, b, n).unwrap(),
        );
        let mut trainer = Trainer::new(
            ValueNet::new(NetConfig::sarl(), 0).unwrap(),
            AdamConfig::with_lr(1e-3),
        );
        let rewards = vec![0.5; b];
        let mut discounts = vec![0.9f32.powf(0.25); b];
        discounts[0] = 0.0;
        let v_next = trainer.target().values(next);
        let y = trainer
            .td_targets(next, &rewards, &discounts)
            .unwrap()
            .to_vec();
        assert_eq!(y[0], 0.5);
        assert!((y[1] - (0.5 + discounts[1] * v_next[1])).abs() < 1e-6);
        let before = trainer.online().params().to_vec();
        let loss = trainer.td_step(states, next, &rewards, &discounts).unwrap();
        assert!(loss.is_finite());
        assert_ne!(trainer.online().params(), &before[..]);
        assert_eq!(trainer.target().params(), &before[..]);
        assert!(trainer
            .td_step(states, next, &rewards[..3], &discounts)
            .is_err());
    }

    #[test]
    fn non_finite_targets_are_rejected_without_update() {
        let (b, n) = (4, 3);
        let s = random_states(b, n, 1);
        let states = StateBatch::new(&s, b, n).unwrap();
        let mut trainer = Trainer::new(
            ValueNet::new(NetConfig::sarl(), 0).unwrap(),
            AdamConfig::with_lr(1e-3),
        );
        let before = trainer.online().params().to_vec();
        let err = trainer.fit(states, &[0.0, f32::NAN, 0.0, 0.0]).unwrap_err();
        assert!(matches!(err, PolicyError::NonFinite(_)), "{err}");
        assert_eq!(trainer.online().params(), &before[..]);
        assert_eq!(trainer.adam().step_count(), 0);
    }
}
