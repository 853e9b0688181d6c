//! Action selection by one-step lookahead (paper eq. 2, SPEC §4): for every action `a`,
//! `value(a) = R(s, a) + γ^{dt·v_pref} · V(s'_a)`; the best action wins, ties to the lower index.
//! All candidates go through the network as one batch `(A, N, 13)`.
//!
//! `R(s, a)` is `sim::evaluate_step`, the function the simulator pays rewards with, under the
//! reward switches of the environment's config (the method's). The humans' next states come from
//! the simulator's own next ORCA step (CrowdNav's `query_env`) or, as an option, from constant
//! velocity.
//!
//! A candidate whose step ends the episode (collision, goal, time limit) is scored as
//! `R(s, a) + γ·V(s'_a)` like any other, as CrowdNav does; with
//! [`Lookahead::with_terminal_previews`] it is scored `R(s, a)` alone, as the training target
//! `y = r` treats the last step of an episode (the Env 3 experiment, `docs/REPRODUCTION.md`).

use sim::{evaluate_step, Env, HumanState, Vec2};

use crate::joint::{featurize_into, HumanObs, HumanOrder};
use crate::{PolicyError, Scratch, StateBatch, ValueNet};

/// How the lookahead predicts the humans' next states.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum HumanModel {
    /// The simulator's next ORCA step (exact one-step foresight, CrowdNav's `query_env = true`).
    #[default]
    Orca,
    /// Every human keeps its current velocity.
    ConstantVelocity,
}

/// The chosen action and its lookahead value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decision {
    pub action: usize,
    pub value: f64,
}

/// Reusable lookahead: holds every buffer, so that a decision does not allocate after the first.
#[derive(Debug, Clone)]
pub struct Lookahead {
    gamma: f64,
    model: HumanModel,
    order: HumanOrder,
    batch: Vec<f32>,
    values: Vec<f32>,
    rewards: Vec<f64>,
    scratch: Scratch,
    next_humans: Vec<HumanState>,
    velocities: Vec<Vec2>,
    obs: Vec<HumanObs>,
    order_buf: Vec<(f64, usize)>,
    discount_last: f64,
    terminal_previews: bool,
    /// Per candidate of the last decision: its step ends the episode.
    terminal: Vec<bool>,
}

impl Lookahead {
    /// `gamma` is the per-second-at-v_pref discount (0.9); `order` the human order the network
    /// expects (LSTM-RL: farthest first).
    pub fn new(gamma: f64, model: HumanModel, order: HumanOrder) -> Self {
        Self {
            gamma,
            model,
            order,
            batch: Vec::new(),
            values: Vec::new(),
            rewards: Vec::new(),
            scratch: Scratch::default(),
            next_humans: Vec::new(),
            velocities: Vec::new(),
            obs: Vec::new(),
            order_buf: Vec::new(),
            discount_last: 0.0,
            terminal_previews: false,
            terminal: Vec::new(),
        }
    }

    /// Scores a candidate whose step ends the episode by its reward alone (no bootstrap from
    /// the value of the state after it). Off by default (CrowdNav).
    pub fn with_terminal_previews(mut self, on: bool) -> Self {
        self.terminal_previews = on;
        self
    }

    /// The candidate's lookahead value: `r + discount·v`, or `r` for a terminal step when
    /// terminal previews are on.
    fn score(&self, reward: f64, value: f32, terminal: bool, discount: f64) -> f64 {
        if terminal && self.terminal_previews {
            reward
        } else {
            reward + discount * value as f64
        }
    }

    /// The attention weights `(A, N)` of the last decision's candidates (SARL only).
    pub fn attention<'s>(&'s self, net: &ValueNet) -> Option<&'s [f32]> {
        net.attention(&self.scratch)
    }

    /// Lookahead values of every action from the last [`Lookahead::decide`].
    pub fn last_values(&self) -> impl Iterator<Item = f64> + '_ {
        self.rewards
            .iter()
            .zip(&self.values)
            .zip(&self.terminal)
            .map(|((r, v), t)| self.score(*r, *v, *t, self.discount_last))
    }

    /// Evaluates every action of `env`'s action set and returns the best.
    pub fn decide(&mut self, env: &mut Env, net: &ValueNet) -> Result<Decision, PolicyError> {
        let dt_s = env.config().dt_s;
        let robot = *env.robot();
        let n_actions = env.action_set().len();
        let discount = self.gamma.powf(dt_s * robot.v_pref_mps);
        self.discount_last = discount;

        // The humans' next states are the same whatever the robot does.
        match self.model {
            HumanModel::Orca => env.next_humans(&mut self.next_humans),
            HumanModel::ConstantVelocity => {
                self.next_humans.clear();
                self.next_humans
                    .extend(env.humans().iter().map(|h| HumanState {
                        position: h.position + h.velocity * dt_s,
                        ..*h
                    }));
                self.velocities.clear();
                self.velocities
                    .extend(env.humans().iter().map(|h| h.velocity));
            }
        }
        self.obs.clear();
        self.obs.extend(self.next_humans.iter().map(HumanObs::from));

        self.batch.clear();
        self.rewards.clear();
        self.terminal.clear();
        for a in 0..n_actions {
            let eval = match self.model {
                HumanModel::Orca => env.preview(a).expect("index within the action set"),
                HumanModel::ConstantVelocity => {
                    let action = env
                        .action_set()
                        .get(a)
                        .expect("index within the action set");
                    evaluate_step(
                        env.config(),
                        &robot,
                        action,
                        env.humans(),
                        &self.velocities,
                        env.steps() + 1,
                    )
                }
            };
            self.rewards.push(eval.reward.total);
            self.terminal.push(eval.outcome.is_terminal());
            featurize_into(
                &eval.robot_next,
                &self.obs,
                self.order,
                &mut self.order_buf,
                &mut self.batch,
            );
        }
        let states = StateBatch::new(&self.batch, n_actions, self.obs.len())?;
        self.values.resize(n_actions, 0.0);
        net.values_into(states, &mut self.scratch, &mut self.values);

        let mut best = Decision {
            action: 0,
            value: f64::NEG_INFINITY,
        };
        for (a, ((r, v), t)) in self
            .rewards
            .iter()
            .zip(&self.values)
            .zip(&self.terminal)
            .enumerate()
        {
            let value = self.score(*r, *v, *t, discount);
            // Strictly greater: ties keep the lower index. A NaN never wins.
            if value > best.value {
                best = Decision { action: a, value };
            }
        }
        if !best.value.is_finite() {
            return Err(PolicyError::NonFinite("lookahead values"));
        }
        Ok(best)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::joint::HumanOrder;
    use crate::{NetConfig, ValueNet};
    use sim::{Setting, SimConfig};

    /// Walks ORCA episodes of env3-invisible (the robot meets the cup) and compares both
    /// scorings on every state: equal for candidates that continue the episode, the reward
    /// alone for terminal ones under terminal previews; until terminal candidates were seen.
    #[test]
    fn terminal_previews_score_a_terminal_candidate_by_its_reward_alone() {
        let setting: Setting = "env3-invisible".parse().unwrap();
        let mut env = Env::new(SimConfig::default(), setting, 0).unwrap();
        let net = ValueNet::new(NetConfig::sarl(), 5).unwrap();
        let mut plain = Lookahead::new(0.9, HumanModel::Orca, HumanOrder::AsGiven);
        let mut terminal =
            Lookahead::new(0.9, HumanModel::Orca, HumanOrder::AsGiven).with_terminal_previews(true);
        let (mut terminal_seen, mut running_seen) = (0, 0);
        for seed in 0..20 {
            env.reset(seed).unwrap();
            while !env.is_done() {
                plain.decide(&mut env, &net).unwrap();
                terminal.decide(&mut env, &net).unwrap();
                let a: Vec<f64> = plain.last_values().collect();
                let b: Vec<f64> = terminal.last_values().collect();
                for (i, (a, b)) in a.iter().zip(&b).enumerate() {
                    let eval = env.preview(i).unwrap();
                    if eval.outcome.is_terminal() {
                        terminal_seen += 1;
                        assert_eq!(*b, eval.reward.total, "action {i}");
                    } else {
                        running_seen += 1;
                        assert_eq!(a, b, "action {i}");
                    }
                }
                let action = env.orca_robot_action(0.0);
                env.step(action).unwrap();
            }
            if terminal_seen > 10 {
                break;
            }
        }
        assert!(
            terminal_seen > 10 && running_seen > 100,
            "{terminal_seen} {running_seen}"
        );
    }
}
