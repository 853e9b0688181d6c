//! The learner's core, free of any transport: episodes in, featurised transitions into replay,
//! imitation epochs on Monte-Carlo returns, deep V-learning updates on targets from the target
//! network, the ε schedule and the counters.

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use policy::joint::{featurize_into, HumanOrder};
use policy::method::{Method, ReplayFilter, TrainConfig};
use policy::optim::AdamConfig;
use policy::rollout::EpisodeData;
use policy::train::Trainer;
use policy::{PolicyError, StateBatch, ValueNet, FEATURE_DIM};
use sim::Outcome;

use crate::replay::{Batch, Replay, Transition};

/// What [`LearnerCore::imitation_steps`] reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ImitationStep {
    /// A batch of epoch `epoch` (from 0) was fitted: `done` of `batches`.
    Batch {
        epoch: u32,
        done: usize,
        batches: usize,
    },
    /// Epoch `epoch` (from 0) ended with mean loss `loss`.
    Epoch { epoch: u32, loss: f32 },
}

/// Why the learner refused something.
#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    #[error("method {0} has no value network to train")]
    NotTrainable(Method),
    #[error("rejected episode (setting {setting}, seed {seed}): {reason}")]
    BadEpisode {
        setting: String,
        seed: u64,
        reason: String,
    },
    #[error(transparent)]
    Policy(#[from] PolicyError),
    #[error("out of phase: {0}")]
    Phase(&'static str),
    #[error("environment: {0}")]
    Env(String),
}

/// Progress counters (also checkpointed).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Counters {
    /// Demonstration episodes received.
    pub demo_episodes: u64,
    /// Whether imitation learning has finished.
    pub imitation_done: bool,
    /// RL episodes received.
    pub rl_episodes: u64,
    /// Gradient steps taken (both phases).
    pub updates: u64,
    /// Environment steps received.
    pub env_steps: u64,
    /// Version of the online weights: bumped after every round of updates.
    pub policy_version: u64,
}

/// An episode that passed every check, with its features, returns and (during RL) value
/// targets computed: [`LearnerCore::commit_episode`] stores it without failing.
#[derive(Debug)]
pub struct PreparedEpisode {
    demonstration: bool,
    steps: usize,
    feats: Vec<f32>,
    /// The transitions that go into replay, in order (none when the replay filter drops the
    /// episode).
    stored: Vec<Stored>,
    targets: Vec<f32>,
}

/// One transition of a prepared episode: from state `t` to state `next` (`t + 1`, or `t + n`
/// for an n-step return), the discounted reward in between and the discount of the bootstrap.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Stored {
    t: usize,
    next: usize,
    reward: f32,
    discount: f32,
    mc_return: f32,
}

/// The transitions of an episode of `rewards.len()` steps (SPEC §5 with `n_step = 1` and no
/// mask: `(t, t + 1, r_t, d)` for every step, discount 0 on the last, which ends the episode,
/// a timeout included). With `n_step = n` each bootstraps `n` steps on, with the rewards in
/// between discounted; the return stops at the episode's end (discount 0) and, where
/// `explored` is given, before an ε-random action, and a transition whose own action was
/// random is left out.
fn transitions(
    rewards: &[f32],
    returns: &[f32],
    discount: f32,
    n_step: usize,
    explored: Option<&[bool]>,
) -> Vec<Stored> {
    let t_len = rewards.len();
    let random = |k: usize| explored.is_some_and(|m| m[k]);
    let mut out = Vec::with_capacity(t_len);
    for t in 0..t_len {
        if random(t) {
            continue;
        }
        let (mut reward, mut scale, mut next) = (rewards[t], discount, t + 1);
        while next < t_len && next - t < n_step && !random(next) {
            reward += scale * rewards[next];
            scale *= discount;
            next += 1;
        }
        out.push(Stored {
            t,
            next,
            reward,
            // The last step ends the episode (a timeout is terminal for the target, SPEC §5).
            discount: if next == t_len { 0.0 } else { scale },
            mc_return: returns[t],
        });
    }
    out
}

/// Replay, trainer and schedule of one training run.
pub struct LearnerCore {
    method: Method,
    train: TrainConfig,
    trainer: Trainer,
    replay: Replay,
    rng: ChaCha8Rng,
    counters: Counters,
    order: HumanOrder,
    dt_s: f64,
    humans: usize,
    order_buf: Vec<(f64, usize)>,
    feats: Vec<f32>,
    batch: Batch,
    target_buf: Vec<f32>,
    /// The cached targets predate the target network (refreshed before the next update).
    targets_stale: bool,
    skipped_batches: u64,
    skipped_refreshes: u64,
    /// Size of the robot's action set (replaying an episode's ε draws needs it; 0: not set).
    actions: usize,
}

impl LearnerCore {
    /// A new run of `method` whose episodes have `humans` humans; weights initialised from `seed`.
    /// `dt_s` is the simulator's step (for the per-step discount γ^{dt·v_pref}).
    pub fn new(
        method: Method,
        train: TrainConfig,
        humans: usize,
        dt_s: f64,
        seed: u64,
    ) -> Result<Self, LearnerError> {
        let net_cfg = method.net().ok_or(LearnerError::NotTrainable(method))?;
        let net = ValueNet::new(net_cfg, seed)?;
        let trainer = Trainer::new(
            net,
            AdamConfig::with_lr(train.imitation.learning_rate as f32),
        );
        Ok(Self::assemble(
            method,
            train,
            trainer,
            Replay::new(0, humans),
            ChaCha8Rng::seed_from_u64(seed ^ 0x1EA7_0E12),
            Counters::default(),
            dt_s,
        ))
    }

    pub(crate) fn assemble(
        method: Method,
        train: TrainConfig,
        trainer: Trainer,
        replay: Replay,
        rng: ChaCha8Rng,
        counters: Counters,
        dt_s: f64,
    ) -> Self {
        let humans = replay.humans();
        let replay = if replay.capacity() == 0 {
            Replay::new(train.rl.replay_capacity, humans)
        } else {
            replay
        };
        Self {
            order: method.human_order(),
            dt_s,
            method,
            train,
            trainer,
            replay,
            rng,
            counters,
            humans,
            order_buf: Vec::new(),
            feats: Vec::new(),
            batch: Batch::default(),
            target_buf: Vec::new(),
            targets_stale: true,
            skipped_batches: 0,
            skipped_refreshes: 0,
            actions: 0,
        }
    }

    pub fn method(&self) -> Method {
        self.method
    }
    pub fn config(&self) -> &TrainConfig {
        &self.train
    }
    pub fn counters(&self) -> Counters {
        self.counters
    }
    pub fn replay(&self) -> &Replay {
        &self.replay
    }
    pub fn trainer(&self) -> &Trainer {
        &self.trainer
    }
    pub fn online(&self) -> &ValueNet {
        self.trainer.online()
    }
    pub(crate) fn rng(&self) -> &ChaCha8Rng {
        &self.rng
    }
    pub fn humans(&self) -> usize {
        self.humans
    }

    /// The size of the robot's action set (`sim::ActionSet::for_config(..).len()`), which
    /// `train.rl.greedy_targets` needs to replay an episode's ε draws.
    pub fn set_action_count(&mut self, actions: usize) {
        self.actions = actions;
    }

    /// Changes how many RL episodes the run lasts (to extend a resumed run).
    pub fn set_rl_episodes(&mut self, episodes: u64) {
        self.train.rl.episodes = episodes;
    }

    /// ε for the next RL episode.
    pub fn epsilon(&self) -> f64 {
        self.train.rl.epsilon(self.counters.rl_episodes)
    }

    fn check(&self, ep: &EpisodeData) -> Result<(), String> {
        if ep.states.len() != ep.actions.len() + 1 || ep.rewards.len() != ep.actions.len() {
            return Err(format!(
                "{} states, {} actions and {} rewards do not fit together",
                ep.states.len(),
                ep.actions.len(),
                ep.rewards.len()
            ));
        }
        if ep.actions.is_empty() {
            return Err("no steps".into());
        }
        if let Some(s) = ep.states.iter().find(|s| s.humans.len() != self.humans) {
            return Err(format!(
                "{} humans, this run has {}",
                s.humans.len(),
                self.humans
            ));
        }
        let finite_state = |s: &policy::rollout::JointState| {
            let r = &s.robot;
            [
                r.position.x,
                r.position.y,
                r.velocity.x,
                r.velocity.y,
                r.goal.x,
                r.goal.y,
                r.heading_rad,
                r.radius_m,
                r.v_pref_mps,
            ]
            .iter()
            .all(|v| v.is_finite())
                && s.humans.iter().all(|h| {
                    [
                        h.position.x,
                        h.position.y,
                        h.velocity.x,
                        h.velocity.y,
                        h.radius_m,
                    ]
                    .iter()
                    .all(|v| v.is_finite())
                })
        };
        if !ep.states.iter().all(finite_state) {
            return Err("non-finite value in a state".into());
        }
        if !ep.rewards.iter().all(|r| r.total.is_finite()) {
            return Err("non-finite reward".into());
        }
        if ep.states[0].robot.v_pref_mps <= 0.0 {
            return Err("robot v_pref must be > 0".into());
        }
        Ok(())
    }

    /// Featurises `ep` into replay (unless the filter drops it). `demonstration` marks imitation
    /// data. Returns whether the episode was stored. A malformed episode is refused whole: every
    /// check (shape, finiteness, finite features and value targets) runs before anything —
    /// counters, replay — changes.
    pub fn add_episode(
        &mut self,
        ep: &EpisodeData,
        demonstration: bool,
    ) -> Result<bool, LearnerError> {
        let prepared = self.prepare_episode(ep, demonstration)?;
        Ok(self.commit_episode(prepared))
    }

    /// Every check and computation of [`LearnerCore::add_episode`], changing nothing: the
    /// episode can then be made durable before [`LearnerCore::commit_episode`] stores it.
    pub fn prepare_episode(
        &mut self,
        ep: &EpisodeData,
        demonstration: bool,
    ) -> Result<PreparedEpisode, LearnerError> {
        let bad = |reason: String| LearnerError::BadEpisode {
            setting: ep.setting.name().to_string(),
            seed: ep.seed,
            reason,
        };
        self.check(ep).map_err(bad)?;
        let keep = match self.train.rl.replay_filter {
            ReplayFilter::All => true,
            ReplayFilter::SuccessCollision => {
                matches!(ep.outcome, Outcome::ReachGoal | Outcome::Collision)
            }
        };
        let row = self.humans * FEATURE_DIM;
        let t_len = ep.steps();
        let discount = self
            .train
            .gamma
            .powf(self.dt_s * ep.states[0].robot.v_pref_mps) as f32;
        let rewards: Vec<f32> = ep.rewards.iter().map(|r| r.total as f32).collect();
        let mut stored = Vec::new();
        let mut targets = Vec::new();
        if keep {
            // Features of every state, once (scratch buffers only).
            self.feats.clear();
            for s in &ep.states {
                featurize_into(
                    &s.robot,
                    &s.humans,
                    self.order,
                    &mut self.order_buf,
                    &mut self.feats,
                );
            }
            if !self.feats.iter().all(|f| f.is_finite()) {
                return Err(bad("non-finite feature".into()));
            }
            let mut returns = vec![0f32; t_len];
            let mut mc = 0f32;
            for t in (0..t_len).rev() {
                mc = rewards[t] + discount * mc;
                returns[t] = mc;
            }
            if !returns.iter().all(|r| r.is_finite()) {
                return Err(bad("non-finite return".into()));
            }
            let explored = if self.train.rl.greedy_targets && ep.epsilon > 0.0 {
                if self.actions == 0 {
                    return Err(LearnerError::Phase(
                        "train.rl.greedy_targets needs the action count (set_action_count)",
                    ));
                }
                Some(policy::rollout::exploration_mask(
                    ep.seed,
                    ep.epsilon,
                    t_len,
                    self.actions,
                ))
            } else {
                None
            };
            stored = transitions(
                &rewards,
                &returns,
                discount,
                self.train.rl.n_step.max(1) as usize,
                explored.as_deref(),
            );
            if !stored.iter().all(|s| s.reward.is_finite()) {
                return Err(bad("non-finite n-step reward".into()));
            }
            if self.counters.imitation_done && !self.targets_stale && !stored.is_empty() {
                // New transitions get their targets from the current target network.
                targets = vec![0f32; stored.len()];
                let one_step = stored.len() == t_len && stored.iter().all(|s| s.next == s.t + 1);
                let gathered;
                let next_feats = if one_step {
                    &self.feats[row..(t_len + 1) * row]
                } else {
                    gathered = stored
                        .iter()
                        .flat_map(|s| &self.feats[s.next * row..(s.next + 1) * row])
                        .copied()
                        .collect::<Vec<f32>>();
                    &gathered[..]
                };
                let next = StateBatch::new(next_feats, stored.len(), self.humans)?;
                let mut scratch = policy::Scratch::default();
                self.trainer
                    .target()
                    .values_into(next, &mut scratch, &mut targets);
                for (y, s) in targets.iter_mut().zip(&stored) {
                    *y = s.reward + s.discount * *y;
                }
                if !targets.iter().all(|y| y.is_finite()) {
                    return Err(bad("non-finite value target".into()));
                }
            }
        }
        Ok(PreparedEpisode {
            demonstration,
            steps: t_len,
            feats: if keep {
                std::mem::take(&mut self.feats)
            } else {
                Vec::new()
            },
            stored,
            targets,
        })
    }

    /// Stores a prepared episode (never fails); returns whether it went into replay.
    pub fn commit_episode(&mut self, p: PreparedEpisode) -> bool {
        let PreparedEpisode {
            demonstration,
            steps: t_len,
            feats,
            stored,
            targets,
        } = p;
        let row = self.humans * FEATURE_DIM;
        if demonstration {
            self.counters.demo_episodes += 1;
        } else {
            self.counters.rl_episodes += 1;
        }
        self.counters.env_steps += t_len as u64;
        if feats.is_empty() {
            return false;
        }
        let mut first_slot = None;
        for s in &stored {
            let slot = self.replay.push(Transition {
                state: &feats[s.t * row..(s.t + 1) * row],
                next_state: &feats[s.next * row..(s.next + 1) * row],
                reward: s.reward,
                discount: s.discount,
                mc_return: s.mc_return,
            });
            first_slot.get_or_insert(slot);
        }
        if !targets.is_empty() {
            let first = first_slot.expect("targets are computed for stored transitions only");
            let cap = self.replay.capacity();
            let head = (cap - first).min(targets.len());
            self.replay.set_targets(first, &targets[..head]);
            self.replay.set_targets(0, &targets[head..]);
        }
        // Hand the buffer back for the next episode's features.
        self.feats = feats;
        !stored.is_empty()
    }

    /// One gradient step towards `targets`; a batch whose loss or gradient is not finite is
    /// skipped (the weights stay as they were) and counted. Returns the loss of a taken step.
    fn fit_or_skip(&mut self, n: usize, use_returns: bool) -> Result<Option<f32>, LearnerError> {
        let states = StateBatch::new(&self.batch.states, n, self.humans)?;
        let targets = if use_returns {
            &self.batch.returns
        } else {
            &self.batch.targets
        };
        match self.trainer.fit(states, targets) {
            Ok(loss) => {
                self.counters.updates += 1;
                Ok(Some(loss))
            }
            Err(PolicyError::NonFinite(what)) => {
                self.skipped_batches += 1;
                if self.skipped_batches.is_power_of_two() {
                    tracing::warn!(
                        skipped = self.skipped_batches,
                        "skipped a batch with a non-finite {what}"
                    );
                }
                Ok(None)
            }
            Err(e) => Err(e.into()),
        }
    }

    /// Batches skipped because their loss or gradient was not finite (not checkpointed).
    pub fn skipped_batches(&self) -> u64 {
        self.skipped_batches
    }

    /// Rounds of updates skipped because the target network's values were not finite (not
    /// checkpointed).
    pub fn skipped_refreshes(&self) -> u64 {
        self.skipped_refreshes
    }

    /// Imitation learning: `epochs` shuffled passes over replay fitting the Monte-Carlo returns.
    /// Calls `progress(epoch, mean loss)` after each epoch; returns the last epoch's mean loss.
    pub fn imitation(
        &mut self,
        epochs: u32,
        mut progress: impl FnMut(u32, f32),
    ) -> Result<f32, LearnerError> {
        let last = self.imitation_steps(epochs, |step| {
            if let ImitationStep::Epoch { epoch, loss } = step {
                progress(epoch, loss);
            }
            true
        })?;
        Ok(last.unwrap_or(f32::NAN))
    }

    /// [`LearnerCore::imitation`] that reports every batch as well as every epoch and stops
    /// when `step` returns `false` (after a batch or an epoch; the epoch is then left
    /// unfinished and `Ok(None)` returned). An epoch of a long warm start takes seconds to
    /// minutes: the learner process drains its transitions between batches, and a stop request
    /// is seen within one batch. The draws and updates are those of [`LearnerCore::imitation`].
    pub fn imitation_steps(
        &mut self,
        epochs: u32,
        mut step: impl FnMut(ImitationStep) -> bool,
    ) -> Result<Option<f32>, LearnerError> {
        let bs = self.train.imitation.batch_size;
        let mut order: Vec<usize> = (0..self.replay.len()).collect();
        let batches = order.len().div_ceil(bs.max(1));
        let mut last = f32::NAN;
        for epoch in 0..epochs {
            order.shuffle(&mut self.rng);
            let (mut sum, mut n) = (0f64, 0usize);
            for (k, chunk) in order.chunks(bs).enumerate() {
                self.replay.gather(chunk.iter().copied(), &mut self.batch);
                if let Some(loss) = self.fit_or_skip(chunk.len(), true)? {
                    sum += loss as f64;
                    n += 1;
                }
                let at = ImitationStep::Batch {
                    epoch,
                    done: k + 1,
                    batches,
                };
                if !step(at) {
                    return Ok(None);
                }
            }
            last = (sum / n.max(1) as f64) as f32;
            self.counters.policy_version += 1;
            if !step(ImitationStep::Epoch { epoch, loss: last }) {
                return Ok(None);
            }
        }
        Ok(Some(last))
    }

    /// Mean squared error of the online network against the Monte-Carlo returns of everything
    /// in replay (no update).
    pub fn imitation_loss(&mut self) -> Result<f32, LearnerError> {
        let bs = self.train.imitation.batch_size.max(1);
        let mut values = Vec::new();
        let mut scratch = policy::Scratch::default();
        let (mut sum, mut n) = (0f64, 0usize);
        let len = self.replay.len();
        for start in (0..len).step_by(bs) {
            let end = (start + bs).min(len);
            self.replay.gather(start..end, &mut self.batch);
            let states = StateBatch::new(&self.batch.states, end - start, self.humans)?;
            values.resize(end - start, 0.0);
            self.trainer
                .online()
                .values_into(states, &mut scratch, &mut values);
            for (v, y) in values.iter().zip(&self.batch.returns) {
                sum += ((v - y) as f64).powi(2);
                n += 1;
            }
        }
        Ok((sum / n.max(1) as f64) as f32)
    }

    /// Ends imitation: fresh Adam at the RL learning rate, target network = online network.
    pub fn start_rl(&mut self) -> Result<(), LearnerError> {
        let online = self.trainer.online().clone();
        self.trainer = Trainer::new(
            online,
            AdamConfig::with_lr(self.train.rl.learning_rate as f32),
        );
        self.counters.imitation_done = true;
        self.targets_stale = true;
        Ok(())
    }

    /// Marks every cached target out of date (the target network changed or was loaded).
    pub(crate) fn invalidate_targets(&mut self) {
        self.targets_stale = true;
    }

    /// Recomputes the cached V-learning targets y = r + discount·V_target(s') of slots `range`.
    /// Between target-network refreshes V_target is fixed, so caching y is exactly equivalent
    /// to computing it at every update, at a fraction of the cost.
    pub(crate) fn refresh_targets(
        &mut self,
        range: std::ops::Range<usize>,
    ) -> Result<(), LearnerError> {
        use rayon::prelude::*;
        // Fixed chunks (not per thread), so the values do not depend on the thread count.
        const CHUNK: usize = 512;
        let (next, rewards, discounts) = self.replay.target_inputs(range.clone());
        let row = self.humans * FEATURE_DIM;
        let (net, humans) = (self.trainer.target(), self.humans);
        self.target_buf.resize(range.len(), 0.0);
        self.target_buf
            .par_chunks_mut(CHUNK)
            .zip(next.par_chunks(CHUNK * row))
            .try_for_each_init(policy::Scratch::default, |scratch, (out, next)| {
                let states = StateBatch::new(next, out.len(), humans)?;
                net.values_into(states, scratch, out);
                Ok::<_, PolicyError>(())
            })?;
        for ((y, r), d) in self.target_buf.iter_mut().zip(rewards).zip(discounts) {
            *y = r + d * *y;
        }
        if !self.target_buf.iter().all(|y| y.is_finite()) {
            return Err(PolicyError::NonFinite("value targets").into());
        }
        self.replay.set_targets(range.start, &self.target_buf);
        Ok(())
    }

    /// `batches` V-learning updates on uniform samples from replay; returns the mean loss.
    /// Bumps the policy version and refreshes the target network on schedule (every
    /// `target_update_episodes` RL episodes: the fixed schedule, one call per accepted episode).
    pub fn train_rl(&mut self, batches: u32) -> Result<f32, LearnerError> {
        if !self.counters.imitation_done {
            return Err(LearnerError::Phase("train_rl before start_rl"));
        }
        let loss = self.fit_batches(batches)?;
        self.counters.policy_version += 1;
        if self
            .counters
            .rl_episodes
            .is_multiple_of(self.train.rl.target_update_episodes)
        {
            self.trainer.sync_target();
            self.targets_stale = true;
        }
        Ok(loss)
    }

    /// The adaptive mode's round of updates (`train.rl.replay_ratio`): `batches` updates, not
    /// tied to an episode. Bumps the policy version; the target network is refreshed whenever
    /// the update count passes a multiple of `target_update_episodes × batches_per_episode`,
    /// the fixed schedule's updates between refreshes.
    pub fn train_round(&mut self, batches: u32) -> Result<f32, LearnerError> {
        if !self.counters.imitation_done {
            return Err(LearnerError::Phase("train_round before start_rl"));
        }
        let period = self
            .train
            .rl
            .target_update_episodes
            .saturating_mul(self.train.rl.batches_per_episode as u64)
            .max(1);
        let before = self.counters.updates / period;
        let skipped = self.skipped_refreshes;
        let loss = self.fit_batches(batches)?;
        self.counters.policy_version += 1;
        if self.skipped_refreshes > skipped {
            // A skipped refresh: no update, and in this mode only updates bring the next sync,
            // so the next round would skip again, for ever (issue 44). The target network is
            // re-synchronised from the online one; when they are the same already, no round
            // can change anything and training stops with an error.
            let (online, target) = (
                self.trainer.online().params(),
                self.trainer.target().params(),
            );
            if online
                .iter()
                .zip(target)
                .all(|(a, b)| a.to_bits() == b.to_bits())
            {
                return Err(PolicyError::NonFinite(
                    "value targets from the online network itself (training has diverged; the adaptive mode cannot go on)",
                )
                .into());
            }
            self.trainer.sync_target();
            self.targets_stale = true;
        } else if self.counters.updates / period > before {
            self.trainer.sync_target();
            self.targets_stale = true;
        }
        Ok(loss)
    }

    /// `batches` updates on uniform samples from replay (targets refreshed first when stale);
    /// the mean loss, NaN when none was taken.
    fn fit_batches(&mut self, batches: u32) -> Result<f32, LearnerError> {
        let mut batches = batches;
        if batches > 0 && self.targets_stale {
            match self.refresh_targets(0..self.replay.len()) {
                Ok(()) => self.targets_stale = false,
                Err(LearnerError::Policy(PolicyError::NonFinite(what))) => {
                    // A target network whose values are not finite: no update on targets it
                    // cannot give (the replay keeps its old ones, the refresh is tried again
                    // next round, and the next target-network sync replaces it); skipped and
                    // counted like a non-finite batch, never fatal (a restarted learner would
                    // replay the same log into the same error).
                    self.skipped_refreshes += 1;
                    if self.skipped_refreshes.is_power_of_two() {
                        tracing::warn!(
                            skipped = self.skipped_refreshes,
                            "skipped a round of updates: the target network gives non-finite {what}"
                        );
                    }
                    batches = 0;
                }
                Err(e) => return Err(e),
            }
        }
        let bs = self.train.rl.batch_size;
        let (mut sum, mut n) = (0f64, 0u32);
        for _ in 0..batches {
            if self.replay.is_empty() {
                break;
            }
            self.replay.sample(&mut self.rng, bs, &mut self.batch);
            let b = self.batch.rewards.len();
            if let Some(loss) = self.fit_or_skip(b, false)? {
                sum += loss as f64;
                n += 1;
            }
        }
        Ok(if n == 0 {
            f32::NAN
        } else {
            (sum / n as f64) as f32
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use policy::rollout::{rollout, Behaviour};

    fn orca_episode(seed: u64) -> EpisodeData {
        let cfg = sim::SimConfig::default();
        let mut env = sim::Env::new(cfg, "env1-invisible".parse().unwrap(), 0).unwrap();
        rollout(
            &mut env,
            seed,
            Behaviour::Orca {
                safety_space_m: 0.0,
            },
        )
        .unwrap()
    }

    /// An episode refused at the last check (its value targets overflow) leaves counters and
    /// replay exactly as they were; a batch whose loss overflows is skipped and counted, and
    /// the weights stay as they were.
    #[test]
    fn a_refused_episode_changes_nothing_and_a_non_finite_batch_is_skipped() {
        let cfg = sim::SimConfig::default();
        let mut core = LearnerCore::new(
            Method::Sarl,
            TrainConfig::default(),
            cfg.humans.count,
            cfg.dt_s,
            1,
        )
        .unwrap();
        for seed in 0..3 {
            core.add_episode(&orca_episode(seed), true).unwrap();
        }
        core.start_rl().unwrap();
        core.train_rl(1).unwrap();
        let (counters, len) = (core.counters(), core.replay().len());
        // A target network whose values overflow f32.
        let online = core.trainer.online().clone();
        let huge: Vec<f32> = online.params().iter().map(|p| p * 1e30).collect();
        let target = ValueNet::from_params(online.config().clone(), huge).unwrap();
        let adam = core.trainer.adam().clone();
        core.trainer = Trainer::from_parts(online.clone(), target, adam).unwrap();
        // The cached targets are current (as between two target-network refreshes).
        core.targets_stale = false;
        let err = core.add_episode(&orca_episode(7), false).unwrap_err();
        assert!(err.to_string().contains("non-finite value target"), "{err}");
        assert_eq!(core.counters(), counters);
        assert_eq!(core.replay().len(), len);
        // Targets that overflow make every batch's loss non-finite: skipped, counted.
        // Refreshing the cached targets over the whole replay finds them non-finite: the round
        // of updates is skipped and counted, not an error; the weights stay, the version moves.
        core.targets_stale = true;
        let before = core.trainer.online().params().to_vec();
        let version = core.counters().policy_version;
        let loss = core.train_rl(3).unwrap();
        assert!(loss.is_nan());
        assert_eq!(core.skipped_refreshes(), 1);
        assert_eq!(core.trainer.online().params(), &before[..]);
        assert_eq!(core.counters().policy_version, version + 1);
        assert_eq!(core.counters().updates, counters.updates);
        let states: Vec<f32> = core.replay.target_inputs(0..1).0.to_vec();
        core.batch.states = states;
        core.batch.targets = vec![f32::INFINITY];
        assert_eq!(core.fit_or_skip(1, false).unwrap(), None);
        assert_eq!(core.skipped_batches(), 1);
        assert_eq!(core.trainer.online().params(), &before[..]);
    }

    #[test]
    fn n_step_transitions_sum_discounted_rewards_and_stop_at_the_end_or_a_random_action() {
        let r = [1.0f32, 2.0, 3.0, 4.0, 5.0];
        let g = [0.0f32; 5];
        let d = 0.5f32;
        // n = 1, no mask: SPEC §5's transitions, discount 0 on the last.
        let one = transitions(&r, &g, d, 1, None);
        assert_eq!(one.len(), 5);
        for (t, s) in one.iter().enumerate() {
            assert_eq!((s.t, s.next, s.reward), (t, t + 1, r[t]));
            assert_eq!(s.discount, if t == 4 { 0.0 } else { d });
        }
        // n = 3: three rewards, bootstrap three steps on at d^3; cut at the episode's end.
        let three = transitions(&r, &g, d, 3, None);
        assert_eq!(
            (three[0].next, three[0].reward),
            (3, 1.0 + 0.5 * 2.0 + 0.25 * 3.0)
        );
        assert_eq!(three[0].discount, 0.125);
        assert_eq!(
            (three[3].next, three[3].reward, three[3].discount),
            (5, 4.0 + 2.5, 0.0)
        );
        // Step 2 random: left out, and the returns of steps 0 and 1 stop before it.
        let mask = [false, false, true, false, false];
        let greedy = transitions(&r, &g, d, 3, Some(&mask));
        let ts: Vec<usize> = greedy.iter().map(|s| s.t).collect();
        assert_eq!(ts, [0, 1, 3, 4]);
        assert_eq!(
            (greedy[0].next, greedy[0].reward, greedy[0].discount),
            (2, 2.0, 0.25)
        );
        assert_eq!(
            (greedy[1].next, greedy[1].reward, greedy[1].discount),
            (2, 2.0, 0.5)
        );
        assert_eq!((greedy[2].next, greedy[2].discount), (5, 0.0));
    }

    fn rl_episode(core: &LearnerCore, seed: u64, epsilon: f64) -> EpisodeData {
        let cfg = Method::Fsrl.sim_config(&sim::SimConfig::default());
        let mut env = sim::Env::new(cfg, "env1-invisible".parse().unwrap(), 0).unwrap();
        let mut la = policy::lookahead::Lookahead::new(
            0.9,
            policy::lookahead::HumanModel::Orca,
            HumanOrder::AsGiven,
        );
        rollout(
            &mut env,
            seed,
            Behaviour::Net {
                net: core.online(),
                lookahead: &mut la,
                epsilon,
                policy_version: 1,
            },
        )
        .unwrap()
    }

    /// `train.rl.greedy_targets` leaves the ε-random steps out of replay (the learner replays
    /// the episode's draws), and `train.rl.n_step` stores n-step rewards; off, every step goes
    /// in with its one-step reward (the paper).
    #[test]
    fn the_target_switches_change_what_goes_into_replay() {
        let cfg = sim::SimConfig::default();
        let core_with = |n_step: u32, greedy: bool| {
            let mut train = TrainConfig::default();
            train.rl.n_step = n_step;
            train.rl.greedy_targets = greedy;
            let mut core =
                LearnerCore::new(Method::Fsrl, train, cfg.humans.count, cfg.dt_s, 1).unwrap();
            core.set_action_count(sim::ActionSet::for_config(&cfg).len());
            for seed in 0..2 {
                core.add_episode(&orca_episode(seed), true).unwrap();
            }
            core.start_rl().unwrap();
            core
        };
        let mut paper = core_with(1, false);
        let ep = rl_episode(&paper, 1 << 63 | 77, 0.5);
        let steps = ep.steps();
        let actions = sim::ActionSet::for_config(&cfg).len();
        let mask = policy::rollout::exploration_mask(ep.seed, ep.epsilon, steps, actions);
        let random = mask.iter().filter(|m| **m).count();
        assert!(random > 0 && random < steps, "{random} of {steps}");
        let before = paper.replay().len();
        paper.add_episode(&ep, false).unwrap();
        assert_eq!(paper.replay().len() - before, steps);

        let mut greedy = core_with(1, true);
        let before = greedy.replay().len();
        greedy.add_episode(&ep, false).unwrap();
        assert_eq!(greedy.replay().len() - before, steps - random);
        // Without the action count the draws cannot be replayed: refused, nothing stored.
        greedy.set_action_count(0);
        assert!(greedy.add_episode(&ep, false).is_err());

        let mut nstep = core_with(4, false);
        let before = nstep.replay().len();
        nstep.add_episode(&ep, false).unwrap();
        assert_eq!(nstep.replay().len() - before, steps);
        let len = paper.replay().len();
        let (_, r1, d1) = paper.replay().target_inputs(before..len);
        let (_, r4, d4) = nstep.replay().target_inputs(before..len);
        let disc = d1[0];
        assert!(
            (d4[0] - disc * disc * disc * disc).abs() < 1e-7,
            "{}",
            d4[0]
        );
        let expected = r1[0] + disc * r1[1] + disc * disc * r1[2] + disc.powi(3) * r1[3];
        assert!((r4[0] - expected).abs() < 1e-6, "{} {expected}", r4[0]);
        assert_eq!(d4[steps - 1], 0.0);
        assert_ne!(r1, r4);
    }

    /// The adaptive mode's rounds: each bumps the version once; the target network follows
    /// the online one exactly when the update count passes a multiple of
    /// `target_update_episodes × batches_per_episode`, however the rounds are cut.
    #[test]
    fn rounds_refresh_the_target_network_every_period_of_updates() {
        let cfg = sim::SimConfig::default();
        let mut train = TrainConfig::default();
        train.rl.target_update_episodes = 2;
        train.rl.batches_per_episode = 3;
        let mut core =
            LearnerCore::new(Method::Sarl, train, cfg.humans.count, cfg.dt_s, 1).unwrap();
        for seed in 0..3 {
            core.add_episode(&orca_episode(seed), true).unwrap();
        }
        assert!(core.train_round(1).is_err(), "rounds before RL");
        core.start_rl().unwrap();
        let same =
            |core: &LearnerCore| core.trainer.online().params() == core.trainer.target().params();
        assert!(same(&core));
        let (u0, v0) = (core.counters().updates, core.counters().policy_version);
        // Period 6 updates; the imitation's updates (none here) shift where it falls.
        assert_eq!(u0 % 6, 0);
        for (batches, refreshed) in [(4, false), (1, false), (2, true), (4, false), (1, true)] {
            core.train_round(batches).unwrap();
            assert_eq!(
                same(&core),
                refreshed,
                "after {} updates",
                core.counters().updates - u0
            );
        }
        assert_eq!(core.counters().updates - u0, 12);
        assert_eq!(core.counters().policy_version - v0, 5);
        // Episodes taken in between do not move the target network in this mode.
        core.add_episode(&orca_episode(9), false).unwrap();
        core.train_round(1).unwrap();
        assert!(!same(&core));
    }
}
