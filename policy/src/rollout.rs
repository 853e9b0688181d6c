//! Running episodes with a behaviour (the ORCA demonstrator, or a value network with ε-greedy
//! lookahead) and recording what the learner needs: raw joint states, actions, reward terms and
//! the outcome.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sim::{run_episode, Env, EpisodeSummary, Outcome, RewardTerms, RobotState, Setting};

use crate::joint::HumanObs;
use crate::lookahead::Lookahead;
use crate::{PolicyError, ValueNet};

/// What the robot observes at one instant.
#[derive(Debug, Clone, PartialEq)]
pub struct JointState {
    pub robot: RobotState,
    pub humans: Vec<HumanObs>,
}

impl JointState {
    /// What the robot observes in `env`: the humans, then (among walls) the static obstacle
    /// points of its sensor as entities of radius 0 ([`HumanObs::obstacle`]).
    pub fn observe(env: &Env) -> Self {
        let mut humans: Vec<HumanObs> = env.humans().iter().map(HumanObs::from).collect();
        let mut points = Vec::new();
        env.static_entities_into(&mut points);
        humans.extend(points.into_iter().map(HumanObs::obstacle));
        Self {
            robot: RobotState {
                goal: env.observed_goal(),
                ..*env.robot()
            },
            humans,
        }
    }
}

/// One finished episode, as the learner receives it.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeData {
    pub setting: Setting,
    pub seed: u64,
    /// States at t = 0 and after every step: `actions.len() + 1` of them.
    pub states: Vec<JointState>,
    pub actions: Vec<u16>,
    pub rewards: Vec<RewardTerms>,
    /// Closest boundary distance to any human during each step.
    pub closest_m: Vec<f64>,
    /// Per human, whether it stands still all episode.
    pub standing: Vec<bool>,
    pub outcome: Outcome,
    /// ε the episode was run with.
    pub epsilon: f64,
    /// Version of the weights that chose the actions (0 for the demonstrator).
    pub policy_version: u64,
    pub summary: EpisodeSummary,
}

impl EpisodeData {
    pub fn steps(&self) -> usize {
        self.actions.len()
    }
}

/// Who chooses the robot's actions.
pub enum Behaviour<'a> {
    /// ORCA's velocity mapped to the nearest action, with an extra ORCA radius.
    Orca { safety_space_m: f64 },
    /// One-step lookahead through `net`; with probability `epsilon` a uniformly random action.
    Net {
        net: &'a ValueNet,
        lookahead: &'a mut Lookahead,
        epsilon: f64,
        policy_version: u64,
    },
}

/// Seed of episode `index` of stream `stream` (an actor, the demonstrator, ...) in a run seeded
/// `run_seed`. The top bit is set, so training seeds never meet the test (1000..1499) or
/// validation (0..99) seeds.
pub fn episode_seed(run_seed: u64, stream: u64, index: u64) -> u64 {
    let mut z = run_seed
        ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ index.wrapping_mul(0xD1B5_4A32_D192_ED03);
    // splitmix64 finaliser
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    (z ^ (z >> 31)) | (1 << 63)
}

/// The ε-greedy draws of one episode: a generator seeded by the episode seed, one uniform draw
/// per step and, when it falls below ε, a uniform action. [`rollout`] draws through it, and the
/// learner replays it ([`exploration_mask`]) to know which of an episode's actions were random
/// without their being sent.
#[derive(Debug, Clone)]
pub struct Explorer {
    rng: ChaCha8Rng,
    epsilon: f64,
}

impl Explorer {
    pub fn new(seed: u64, epsilon: f64) -> Self {
        Self {
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0x005E_ED0F_E951_1015),
            epsilon,
        }
    }

    /// The next step's draw: `Some(random action)` among `n_actions` when it explores.
    pub fn draw(&mut self, n_actions: usize) -> Option<usize> {
        let explore = self.rng.gen::<f64>() < self.epsilon;
        explore.then(|| self.rng.gen_range(0..n_actions))
    }
}

/// Which of the first `steps` actions of the episode run with `seed` and `epsilon` were ε-random
/// (the draws of [`rollout`], replayed; `n_actions` is the size of the action set).
pub fn exploration_mask(seed: u64, epsilon: f64, steps: usize, n_actions: usize) -> Vec<bool> {
    let mut explorer = Explorer::new(seed, epsilon);
    (0..steps)
        .map(|_| explorer.draw(n_actions).is_some())
        .collect()
}

/// Resets `env` to `seed` and runs the episode to its end with `behaviour`. The ε draws come
/// from an [`Explorer`] seeded by the episode seed, so (seed, weights, ε) replays bit for bit.
pub fn rollout(
    env: &mut Env,
    seed: u64,
    behaviour: Behaviour<'_>,
) -> Result<EpisodeData, PolicyError> {
    env.reset(seed)
        .map_err(|e| PolicyError::Config(e.to_string()))?;
    let mut states = Vec::with_capacity(env.config().max_steps() as usize + 1);
    let mut actions = Vec::with_capacity(env.config().max_steps() as usize);
    let mut failure = None;
    let (epsilon, policy_version) = match &behaviour {
        Behaviour::Orca { .. } => (0.0, 0),
        Behaviour::Net {
            epsilon,
            policy_version,
            ..
        } => (*epsilon, *policy_version),
    };
    let mut explorer = Explorer::new(seed, epsilon);
    let mut behaviour = behaviour;
    let episode = run_episode(
        env,
        |env| {
            states.push(JointState::observe(env));
            let action = match &mut behaviour {
                Behaviour::Orca { safety_space_m } => env.orca_robot_action(*safety_space_m),
                Behaviour::Net { net, lookahead, .. } => {
                    match explorer.draw(env.action_set().len()) {
                        Some(random) => random,
                        None => match lookahead.decide(env, net) {
                            Ok(d) => d.action,
                            Err(e) => {
                                failure.get_or_insert(e);
                                0
                            }
                        },
                    }
                }
            };
            actions.push(action as u16);
            action
        },
        false,
    )
    .map_err(|e| PolicyError::Config(e.to_string()))?;
    if let Some(e) = failure {
        return Err(e);
    }
    states.push(JointState::observe(env));
    let entities = states[0].humans.len();
    Ok(EpisodeData {
        setting: env.setting(),
        seed,
        states,
        actions,
        rewards: episode.steps.iter().map(|s| s.eval.reward).collect(),
        closest_m: episode.steps.iter().map(|s| s.eval.closest_m).collect(),
        // Obstacle entities (after the humans) never move.
        standing: env
            .humans()
            .iter()
            .map(|h| h.standing)
            .chain(std::iter::repeat(true))
            .take(entities)
            .collect(),
        outcome: episode.summary.outcome,
        epsilon,
        policy_version,
        summary: episode.summary,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::joint::HumanOrder;
    use crate::lookahead::HumanModel;
    use crate::NetConfig;
    use sim::SimConfig;

    #[test]
    fn seeds_are_distinct_and_far_from_test_seeds() {
        let mut seen = std::collections::HashSet::new();
        for stream in 0..4 {
            for i in 0..1000 {
                let s = episode_seed(7, stream, i);
                assert!(s >= 1 << 63);
                assert!(seen.insert(s));
            }
        }
        assert_eq!(episode_seed(7, 1, 2), episode_seed(7, 1, 2));
        assert_ne!(episode_seed(7, 1, 2), episode_seed(8, 1, 2));
    }

    /// The mask the learner replays marks exactly the steps whose action the ε draw chose:
    /// an episode run with ε = 0.4 and one with ε = 0 from the same weights agree on every
    /// step before the first random one, and at every marked step the action is the draw's.
    #[test]
    fn the_exploration_mask_replays_the_episodes_draws() {
        let setting: Setting = "env1-invisible".parse().unwrap();
        let mut env = Env::new(SimConfig::default(), setting, 0).unwrap();
        let net = ValueNet::new(NetConfig::sarl(), 3).unwrap();
        let mut la = Lookahead::new(0.9, HumanModel::Orca, HumanOrder::AsGiven);
        let seed = 1 << 63 | 5;
        let ep = rollout(
            &mut env,
            seed,
            Behaviour::Net {
                net: &net,
                lookahead: &mut la,
                epsilon: 0.4,
                policy_version: 1,
            },
        )
        .unwrap();
        let n = env.action_set().len();
        let mask = exploration_mask(seed, 0.4, ep.steps(), n);
        assert!(mask.iter().any(|m| *m) && !mask.iter().all(|m| *m));
        let mut explorer = Explorer::new(seed, 0.4);
        for (t, &random) in mask.iter().enumerate() {
            match explorer.draw(n) {
                Some(a) => {
                    assert!(random);
                    assert_eq!(ep.actions[t] as usize, a, "step {t}");
                }
                None => assert!(!random),
            }
        }
        let greedy = rollout(
            &mut env,
            seed,
            Behaviour::Net {
                net: &net,
                lookahead: &mut la,
                epsilon: 0.0,
                policy_version: 1,
            },
        )
        .unwrap();
        let first = mask.iter().position(|m| *m).unwrap();
        assert_eq!(ep.actions[..first], greedy.actions[..first]);
        assert!(exploration_mask(seed, 0.0, 50, n).iter().all(|m| !*m));
        assert!(exploration_mask(seed, 1.0, 50, n).iter().all(|m| *m));
    }

    #[test]
    fn recorded_episodes_are_consistent_and_replayable() {
        let setting: Setting = "env2-visible".parse().unwrap();
        let mut env = Env::new(SimConfig::default(), setting, 0).unwrap();
        let demo = rollout(
            &mut env,
            2000,
            Behaviour::Orca {
                safety_space_m: 0.15,
            },
        )
        .unwrap();
        assert_eq!(demo.states.len(), demo.actions.len() + 1);
        assert_eq!(demo.rewards.len(), demo.actions.len());
        assert_eq!(demo.summary.steps as usize, demo.steps());
        assert!(demo.outcome.is_terminal());

        let net = ValueNet::new(NetConfig::sarl(), 3).unwrap();
        let mut la = Lookahead::new(0.9, HumanModel::Orca, HumanOrder::AsGiven);
        let mut run = |env: &mut Env| {
            rollout(
                env,
                2001,
                Behaviour::Net {
                    net: &net,
                    lookahead: &mut la,
                    epsilon: 0.3,
                    policy_version: 4,
                },
            )
            .unwrap()
        };
        let a = run(&mut env);
        let b = run(&mut env);
        assert_eq!(a, b);
        assert_eq!(a.policy_version, 4);
        assert_eq!(a.epsilon, 0.3);
    }
}
