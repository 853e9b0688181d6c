//! Adam on the flat parameter vector (PyTorch's `torch.optim.Adam` update, no weight decay, no
//! AMSGrad). The state (`m`, `v`, step count) lives in flat vectors in the parameter layout, so
//! it can be checkpointed and restored bit-exactly.

use crate::PolicyError;

/// Adam hyper-parameters (PyTorch defaults except the learning rate).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamConfig {
    /// Learning rate (SPEC §5: 0.01 for imitation, 1e-4 for RL).
    pub lr: f32,
    /// First-moment decay.
    pub beta1: f32,
    /// Second-moment decay.
    pub beta2: f32,
    /// Denominator term.
    pub eps: f32,
}

impl AdamConfig {
    /// PyTorch's defaults with learning rate `lr`.
    pub fn with_lr(lr: f32) -> Self {
        Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
        }
    }
}

/// Adam state for one parameter vector.
#[derive(Clone, Debug, PartialEq)]
pub struct Adam {
    config: AdamConfig,
    m: Vec<f32>,
    v: Vec<f32>,
    step: u64,
}

impl Adam {
    /// Zero state for `num_params` parameters.
    pub fn new(config: AdamConfig, num_params: usize) -> Self {
        Self {
            config,
            m: vec![0.0; num_params],
            v: vec![0.0; num_params],
            step: 0,
        }
    }

    /// Restores a state (e.g. from a checkpoint).
    pub fn from_state(
        config: AdamConfig,
        m: Vec<f32>,
        v: Vec<f32>,
        step: u64,
    ) -> Result<Self, PolicyError> {
        if m.len() != v.len() {
            return Err(PolicyError::Length {
                what: "Adam second moment",
                expected: m.len(),
                got: v.len(),
            });
        }
        Ok(Self { config, m, v, step })
    }

    /// Hyper-parameters.
    pub fn config(&self) -> AdamConfig {
        self.config
    }

    /// Changes the learning rate, keeping the moments (PyTorch's `param_group['lr'] = …`).
    pub fn set_lr(&mut self, lr: f32) {
        self.config.lr = lr;
    }

    /// Steps taken.
    pub fn step_count(&self) -> u64 {
        self.step
    }

    /// First moments (flat layout).
    pub fn m(&self) -> &[f32] {
        &self.m
    }

    /// Second moments (flat layout).
    pub fn v(&self) -> &[f32] {
        &self.v
    }

    /// One update of `params` with gradient `grad` (same length as the state; panics otherwise).
    ///
    /// `m ← β1 m + (1−β1) g`, `v ← β2 v + (1−β2) g²`,
    /// `p ← p − (lr / (1−β1^t)) · m / (√v / √(1−β2^t) + ε)`.
    pub fn update(&mut self, params: &mut [f32], grad: &[f32]) {
        assert_eq!(params.len(), self.m.len(), "Adam: parameter count changed");
        assert_eq!(grad.len(), self.m.len(), "Adam: gradient length");
        self.step += 1;
        let AdamConfig {
            lr,
            beta1,
            beta2,
            eps,
        } = self.config;
        let t = self.step as f64;
        let bc1 = 1.0 - (beta1 as f64).powf(t);
        let bc2 = 1.0 - (beta2 as f64).powf(t);
        let step_size = (lr as f64 / bc1) as f32;
        let inv_sqrt_bc2 = (1.0 / bc2.sqrt()) as f32;
        for (((p, &g), m), v) in params
            .iter_mut()
            .zip(grad)
            .zip(&mut self.m)
            .zip(&mut self.v)
        {
            *m = beta1 * *m + (1.0 - beta1) * g;
            *v = beta2 * *v + (1.0 - beta2) * g * g;
            *p -= step_size * *m / (v.sqrt() * inv_sqrt_bc2 + eps);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_step_moves_each_parameter_by_lr() {
        // With m̂ = g and v̂ = g², the first step is lr · sign(g) (up to ε).
        let mut adam = Adam::new(AdamConfig::with_lr(0.1), 3);
        let mut p = vec![1.0f32, 1.0, 1.0];
        adam.update(&mut p, &[0.5, -2.0, 1e-3]);
        for (got, want) in p.iter().zip([0.9f32, 1.1, 0.9]) {
            assert!((got - want).abs() < 1e-4, "{got} vs {want}");
        }
        assert_eq!(adam.step_count(), 1);
    }
}
