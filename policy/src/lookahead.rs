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

use sim::{evaluate_step_among, Env, HumanState, RobotState, Vec2};

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
    /// The static obstacle points seen from the current pose (walled settings only).
    obstacles: Vec<Vec2>,
    order_buf: Vec<(f64, usize)>,
    discount_last: f64,
    terminal_previews: bool,
    /// Per candidate of the last decision: its step ends the episode.
    terminal: Vec<bool>,
    /// Per candidate of the last decision: its step touches a wall.
    walled: Vec<bool>,
    /// The people shield's horizon (0: off; `train.shield_s`).
    shield_s: f64,
    /// Per candidate of the last decision: held for `shield_s`, it meets a person moving on at
    /// constant velocity (people shield only).
    threatened: Vec<bool>,
    /// Depth-2 planning over this many best first steps (0: the paper's one-step lookahead).
    planning_top_k: usize,
    /// The second steps planning tries after each first step: this many of the decision's best
    /// first-step actions (0: the whole action set).
    planning_breadth: usize,
    /// The progress tie-break's tolerance (0: off; `train.progress_tolerance`).
    progress_tolerance: f64,
    /// Per candidate of the last decision: the robot after its step (planning or the progress
    /// tie-break only).
    robot_next: Vec<RobotState>,
    plan: PlanBuffers,
    /// The network's batches split over this many threads (1: the caller's alone).
    threads: usize,
    /// One scratch per thread when `threads > 1`.
    split: Vec<Scratch>,
}

/// The second level's buffers (only used with planning).
#[derive(Debug, Clone, Default)]
struct PlanBuffers {
    /// The first steps rescored, best one-step score first.
    chosen: Vec<usize>,
    /// The actions tried as second steps.
    second: Vec<usize>,
    /// The rescored first steps of the last decision: (depth-2 value, action).
    scored: Vec<(f64, usize)>,
    ranked: Vec<(f64, usize)>,
    /// The humans two steps ahead, as the network sees them.
    obs: Vec<HumanObs>,
    velocities: Vec<Vec2>,
    batch: Vec<f32>,
    values: Vec<f32>,
    rewards: Vec<f64>,
    terminal: Vec<bool>,
    walled: Vec<bool>,
    scratch: Scratch,
}

/// The most first steps [`Lookahead::with_planning`] rescores (the whole action set of the
/// paper's robot is 81).
pub const MAX_PLANNING_TOP_K: usize = 81;

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
            obstacles: Vec::new(),
            order_buf: Vec::new(),
            discount_last: 0.0,
            terminal_previews: false,
            terminal: Vec::new(),
            walled: Vec::new(),
            shield_s: 0.0,
            threatened: Vec::new(),
            progress_tolerance: 0.0,
            planning_top_k: 0,
            planning_breadth: 0,
            robot_next: Vec::new(),
            plan: PlanBuffers::default(),
            threads: 1,
            split: Vec::new(),
        }
    }

    /// Depth-2 planning over the `top_k` best first steps (0: off, the paper). Beyond the paper
    /// (`train.planning_top_k`, docs/REPRODUCTION.md Experiment 21). Values above the action
    /// set's size rescore every action.
    pub fn with_planning(mut self, top_k: usize) -> Self {
        self.planning_top_k = top_k;
        self
    }

    /// The second steps depth-2 planning tries after each first step: the `breadth` actions
    /// with the best one-step scores of the decision (the same for every first step; 0: every
    /// action, as [`Lookahead::with_planning`] alone). Cuts the second level from `k × 81`
    /// states to `k × breadth` (`train.planning_breadth`, docs/REPRODUCTION.md Experiment 24).
    pub fn with_planning_breadth(mut self, breadth: usize) -> Self {
        self.planning_breadth = breadth;
        self
    }

    /// Splits each decision's network batches over `threads` threads (at least 1; the values,
    /// and so the decisions, are the single-threaded ones bit for bit:
    /// `ValueNet::values_split`). For one decision at a time (`fsrl serve`), where planning's
    /// larger batches leave cores idle; the evaluator and actors already use every core.
    /// [`Lookahead::attention`] is then `None`.
    pub fn with_threads(mut self, threads: usize) -> Self {
        self.threads = threads.max(1);
        self.split = if self.threads > 1 {
            vec![Scratch::default(); self.threads]
        } else {
            Vec::new()
        };
        self
    }

    /// The people shield (issue 54; 0: off, the paper): a candidate whose velocity, held for
    /// `horizon_s` from the robot's position, comes within touching distance of a person
    /// walking on at their current velocity is never chosen while some candidate keeps clear
    /// (with the walls' shield: walls first, they stay hard). Beyond the paper
    /// (`train.shield_s`; docs/CROWDS.md).
    pub fn with_shield(mut self, horizon_s: f64) -> Self {
        self.shield_s = horizon_s;
        self
    }

    /// The progress tie-break (issue 54 item 4; 0: off, the paper): among the candidates whose
    /// final lookahead value (one-step, or depth-2 with planning) is within `tolerance` of the
    /// best, the one whose step ends nearest the goal is chosen (ties keep the best, then the
    /// lower index). Walls and the people shield come first: a vetoed candidate has value −∞.
    /// Beyond the paper (`train.progress_tolerance`; docs/REPRODUCTION.md Experiment 31).
    pub fn with_progress_tolerance(mut self, tolerance: f64) -> Self {
        self.progress_tolerance = tolerance;
        self
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
        score(self.terminal_previews, reward, value, terminal, discount)
    }

    /// The attention weights `(A, N)` of the last decision's candidates (SARL only).
    pub fn attention<'s>(&'s self, net: &ValueNet) -> Option<&'s [f32]> {
        if self.threads > 1 {
            return None;
        }
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
        // Walls are static: the points seen now stand for every candidate's next state.
        self.obstacles.clear();
        env.static_entities_into(&mut self.obstacles);
        self.obs
            .extend(self.obstacles.iter().map(|&p| HumanObs::obstacle(p)));

        // The goal the robot observes (`Env::observed_goal`), seen from the current pose for
        // every candidate as the walls' points are; the rewards keep the goal itself.
        let seen_goal = env.observed_goal();
        self.batch.clear();
        self.rewards.clear();
        self.terminal.clear();
        self.walled.clear();
        self.threatened.clear();
        self.robot_next.clear();
        for a in 0..n_actions {
            let eval = match self.model {
                HumanModel::Orca => env.preview(a).expect("index within the action set"),
                HumanModel::ConstantVelocity => {
                    let action = env
                        .action_set()
                        .get(a)
                        .expect("index within the action set");
                    evaluate_step_among(
                        env.config(),
                        env.wall_map(),
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
            self.walled.push(eval.wall_contact);
            if self.shield_s > 0.0 {
                self.threatened.push(threatens(
                    &robot,
                    eval.robot_next.velocity,
                    env.humans(),
                    self.shield_s,
                ));
            }
            if self.planning_top_k > 0 || self.progress_tolerance > 0.0 {
                self.robot_next.push(eval.robot_next);
            }
            featurize_into(
                &RobotState {
                    goal: seen_goal,
                    ..eval.robot_next
                },
                &self.obs,
                self.order,
                &mut self.order_buf,
                &mut self.batch,
            );
        }
        shield_walls(&mut self.rewards, &self.walled);
        if self.shield_s > 0.0 {
            shield_people(&mut self.rewards, &self.threatened);
        }
        let states = StateBatch::new(&self.batch, n_actions, self.obs.len())?;
        self.values.resize(n_actions, 0.0);
        net_values(
            net,
            &mut self.split,
            &mut self.scratch,
            states,
            &mut self.values,
        );

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
        if self.planning_top_k == 0 {
            if self.progress_tolerance <= 0.0 {
                return Ok(best);
            }
            let scores = (0..n_actions).map(|a| {
                let value = self.score(self.rewards[a], self.values[a], self.terminal[a], discount);
                (value, a)
            });
            return Ok(self.prefer_progress(best, robot.goal, scores));
        }
        let best = self.plan_second_step(env, net, discount, seen_goal)?;
        if self.progress_tolerance <= 0.0 {
            return Ok(best);
        }
        let scores = self.plan.scored.iter().copied();
        Ok(self.prefer_progress(best, robot.goal, scores))
    }

    /// The progress tie-break over `candidates` (value, action) of a decision whose best is
    /// `best`: the candidate within the tolerance of the best value whose step ends nearest
    /// `goal`; `best` itself when no other is nearer.
    fn prefer_progress(
        &self,
        best: Decision,
        goal: Vec2,
        candidates: impl Iterator<Item = (f64, usize)>,
    ) -> Decision {
        let floor = best.value - self.progress_tolerance;
        let distance = |a: usize| (goal - self.robot_next[a].position).norm();
        let mut chosen = (best, distance(best.action));
        for (value, action) in candidates {
            if value.is_finite() && value >= floor {
                let d = distance(action);
                // Strictly nearer: ties keep the best, then the lower index.
                if d < chosen.1 {
                    chosen = (Decision { action, value }, d);
                }
            }
        }
        chosen.0
    }

    /// Depth-2 planning: rescores the `planning_top_k` best first steps of the decision just
    /// made (`rewards`, `values`, `terminal`, `robot_next` hold its candidates) and returns the
    /// best rescored one. A first step that ends the episode keeps its one-step score.
    /// `seen_goal`: the goal the robot observes, as the first step saw it.
    fn plan_second_step(
        &mut self,
        env: &Env,
        net: &ValueNet,
        discount: f64,
        seen_goal: Vec2,
    ) -> Result<Decision, PolicyError> {
        let dt_s = env.config().dt_s;
        let n_actions = self.rewards.len();
        let previews = self.terminal_previews;
        let score = |reward: f64, value: f32, terminal: bool| {
            score(previews, reward, value, terminal, discount)
        };
        let plan = &mut self.plan;
        plan.ranked.clear();
        for a in 0..n_actions {
            let first = score(self.rewards[a], self.values[a], self.terminal[a]);
            if first.is_finite() {
                plan.ranked.push((first, a));
            }
        }
        // Best first; ties to the lower index, as the one-step decision.
        plan.ranked
            .sort_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)));
        plan.chosen.clear();
        plan.chosen.extend(
            plan.ranked
                .iter()
                .take(self.planning_top_k)
                .map(|&(_, a)| a),
        );
        let breadth = match self.planning_breadth {
            0 => n_actions,
            m => m.min(plan.ranked.len()),
        };
        plan.second.clear();
        if breadth >= n_actions {
            plan.second.extend(0..n_actions);
        } else {
            plan.second
                .extend(plan.ranked.iter().take(breadth).map(|&(_, a)| a));
        }

        // The humans' second step: on at the velocities predicted for the first.
        plan.velocities.clear();
        plan.velocities
            .extend(self.next_humans.iter().map(|h| h.velocity));
        plan.obs.clear();
        plan.obs.extend(self.next_humans.iter().map(|h| HumanObs {
            position: h.position + h.velocity * dt_s,
            velocity: h.velocity,
            radius_m: h.radius_m,
        }));
        plan.obs
            .extend(self.obstacles.iter().map(|&p| HumanObs::obstacle(p)));

        plan.batch.clear();
        plan.rewards.clear();
        plan.terminal.clear();
        plan.walled.clear();
        let mut rows = 0;
        for &a in &plan.chosen {
            if self.terminal[a] {
                continue;
            }
            let robot = self.robot_next[a];
            for &b in &plan.second {
                let action = env
                    .action_set()
                    .get(b)
                    .expect("index within the action set");
                let eval = evaluate_step_among(
                    env.config(),
                    env.wall_map(),
                    &robot,
                    action,
                    &self.next_humans,
                    &plan.velocities,
                    env.steps() + 2,
                );
                plan.rewards.push(eval.reward.total);
                plan.terminal.push(eval.outcome.is_terminal());
                plan.walled.push(eval.wall_contact);
                featurize_into(
                    &RobotState {
                        goal: seen_goal,
                        ..eval.robot_next
                    },
                    &plan.obs,
                    self.order,
                    &mut self.order_buf,
                    &mut plan.batch,
                );
                rows += 1;
            }
            let group = rows - plan.second.len()..rows;
            shield_walls(&mut plan.rewards[group.clone()], &plan.walled[group]);
        }
        plan.values.resize(rows, 0.0);
        if rows > 0 {
            let states = StateBatch::new(&plan.batch, rows, plan.obs.len())?;
            net_values(
                net,
                &mut self.split,
                &mut plan.scratch,
                states,
                &mut plan.values,
            );
        }

        let mut best = Decision {
            action: 0,
            value: f64::NEG_INFINITY,
        };
        plan.scored.clear();
        let mut row = 0;
        for &a in &plan.chosen {
            let value = if self.terminal[a] {
                score(self.rewards[a], self.values[a], true)
            } else {
                let mut second = f64::NEG_INFINITY;
                for _ in 0..plan.second.len() {
                    let v = score(plan.rewards[row], plan.values[row], plan.terminal[row]);
                    if v > second {
                        second = v;
                    }
                    row += 1;
                }
                self.rewards[a] + discount * second
            };
            plan.scored.push((value, a));
            // Candidates come best first: strictly greater keeps the better one-step score.
            if value > best.value {
                best = Decision { action: a, value };
            }
        }
        if !best.value.is_finite() {
            return Err(PolicyError::NonFinite("planning values"));
        }
        Ok(best)
    }
}

/// Walls are hard: while some candidate keeps clear of every wall, a candidate whose step
/// touches one is never chosen (its reward becomes −∞; at depth two, among the second steps of
/// one first step). Stopping never touches a wall, so among walls the robot's own choice never
/// hits one. Without walls nothing is touched and nothing changes.
fn shield_walls(rewards: &mut [f64], walled: &[bool]) {
    if walled.iter().any(|&w| w) && walled.iter().any(|&w| !w) {
        for (r, &w) in rewards.iter_mut().zip(walled) {
            if w {
                *r = f64::NEG_INFINITY;
            }
        }
    }
}

/// Whether `robot`, moving from where it is at `velocity` for `horizon_s`, comes within
/// touching distance of one of `humans` walking on at their velocities (exact closest approach
/// of the two straight lines).
fn threatens(robot: &RobotState, velocity: Vec2, humans: &[HumanState], horizon_s: f64) -> bool {
    humans.iter().any(|h| {
        let reach = robot.radius_m + h.radius_m;
        sim::geom::closest_approach(
            h.position - robot.position,
            h.velocity - velocity,
            horizon_s,
        ) < reach
    })
}

/// People are soft walls: while some candidate still open (reward not −∞ after the walls'
/// shield) keeps clear of everyone, a threatened one is never chosen. When every open
/// candidate is threatened, nothing changes: the network chooses among them as without the
/// shield.
fn shield_people(rewards: &mut [f64], threatened: &[bool]) {
    let open = |r: &f64| *r != f64::NEG_INFINITY;
    if rewards.iter().zip(threatened).any(|(r, &t)| open(r) && !t) {
        for (r, &t) in rewards.iter_mut().zip(threatened) {
            if t {
                *r = f64::NEG_INFINITY;
            }
        }
    }
}

/// A candidate's lookahead value: `r + discount·v`, or `r` for a terminal step when terminal
/// previews are on.
fn score(previews: bool, reward: f64, value: f32, terminal: bool, discount: f64) -> f64 {
    if terminal && previews {
        reward
    } else {
        reward + discount * value as f64
    }
}

/// The network's values of `states` into `out`: split over `split`'s scratches when there are
/// several (`Lookahead::with_threads`), else on this thread with `scratch`.
fn net_values(
    net: &ValueNet,
    split: &mut [Scratch],
    scratch: &mut Scratch,
    states: StateBatch<'_>,
    out: &mut [f32],
) {
    if split.len() > 1 {
        net.values_split(states, split, out);
    } else {
        net.values_into(states, scratch, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::joint::HumanOrder;
    use crate::{NetConfig, ValueNet};
    use sim::{evaluate_step, Setting, SimConfig};

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

    /// Walls are hard (issue 53): a robot in the corridor driven against a wall by untrained
    /// networks never chooses an action whose step touches it, at depth one and with planning.
    #[test]
    fn an_action_into_a_wall_is_never_chosen() {
        let cfg = SimConfig::default();
        let setting: Setting = "corridor".parse().unwrap();
        let mut env = Env::new(cfg, setting, 3).unwrap();
        let mut contacts_offered = 0;
        for net_seed in 0..6u64 {
            let net = ValueNet::new(NetConfig::sarl(), net_seed).unwrap();
            for planning in [0, 4] {
                let mut la = Lookahead::new(0.9, HumanModel::Orca, HumanOrder::AsGiven)
                    .with_planning(planning);
                for (x, heading) in [(0.62, 0.3), (-0.62, 2.8), (0.55, 0.0), (-0.6, 3.1)] {
                    let mut scenario = sim::Scenario::generate(env.config(), setting, 3).unwrap();
                    scenario.robot.position = Vec2::new(x, -3.0);
                    scenario.robot.heading_rad = heading;
                    env.reset_to_scenario(3, scenario);
                    let n = env.action_set().len();
                    contacts_offered += (0..n)
                        .filter(|&a| env.preview(a).unwrap().wall_contact)
                        .count();
                    let d = la.decide(&mut env, &net).unwrap();
                    assert!(
                        !env.preview(d.action).unwrap().wall_contact,
                        "net {net_seed} planning {planning} at x = {x}: action {} hits the wall",
                        d.action
                    );
                }
            }
        }
        assert!(contacts_offered > 100, "{contacts_offered}");
    }

    /// The people shield (issue 54): along ORCA episodes of env1 driven by untrained networks,
    /// the shielded decision never takes an action that meets a person within the horizon
    /// while one keeps clear; the unshielded one does, and with every action threatened the
    /// shield leaves the decision as it was.
    #[test]
    fn the_people_shield_vetoes_actions_that_meet_a_person_while_one_keeps_clear() {
        let cfg = SimConfig::default();
        let setting: Setting = "env1-invisible".parse().unwrap();
        let horizon_s = 1.5;
        let (mut vetoed, mut unshielded_threatened) = (0, 0);
        for net_seed in 0..3u64 {
            let net = ValueNet::new(NetConfig::sarl(), net_seed).unwrap();
            for planning in [0, 4] {
                let mut env = Env::new(cfg.clone(), setting, 7 + net_seed).unwrap();
                let mut plain = Lookahead::new(0.9, HumanModel::Orca, HumanOrder::AsGiven)
                    .with_planning(planning);
                let mut shielded = Lookahead::new(0.9, HumanModel::Orca, HumanOrder::AsGiven)
                    .with_planning(planning)
                    .with_shield(horizon_s);
                for _ in 0..40 {
                    if env.outcome().is_terminal() {
                        break;
                    }
                    let robot = *env.robot();
                    let n = env.action_set().len();
                    let threat: Vec<bool> = (0..n)
                        .map(|a| {
                            let v = env.preview(a).unwrap().robot_next.velocity;
                            threatens(&robot, v, env.humans(), horizon_s)
                        })
                        .collect();
                    let a = plain.decide(&mut env, &net).unwrap().action;
                    let b = shielded.decide(&mut env, &net).unwrap().action;
                    if threat.iter().all(|&t| t) {
                        assert_eq!(a, b, "every action threatened: the shield changes nothing");
                    } else {
                        assert!(
                            !threat[b],
                            "net {net_seed}: shielded action {b} is threatened"
                        );
                        unshielded_threatened += usize::from(threat[a]);
                        vetoed += threat.iter().filter(|&&t| t).count();
                    }
                    let action = env.orca_robot_action(0.0);
                    env.step(action).unwrap();
                }
            }
        }
        assert!(vetoed > 100, "{vetoed}");
        assert!(
            unshielded_threatened > 0,
            "the shield has something to change"
        );
    }

    #[test]
    fn a_threat_is_the_exact_closest_approach_of_two_straight_lines() {
        let robot = RobotState {
            position: Vec2::new(0.0, 0.0),
            radius_m: 0.3,
            ..*Env::new(SimConfig::default(), Setting::ALL[0], 1)
                .unwrap()
                .robot()
        };
        let person = |x: f64, vx: f64| HumanState {
            position: Vec2::new(x, 0.0),
            velocity: Vec2::new(vx, 0.0),
            radius_m: 0.3,
            ..sim::Scenario::generate(&SimConfig::default(), Setting::ALL[0], 1)
                .unwrap()
                .humans[0]
        };
        let ahead = Vec2::new(1.0, 0.0);
        // 2 m apart closing at 2 m/s: touching (0.6 m) after 0.7 s.
        assert!(threatens(&robot, ahead, &[person(2.0, -1.0)], 0.75));
        assert!(!threatens(&robot, ahead, &[person(2.0, -1.0)], 0.65));
        // Walking away, or passing 0.7 m to the side: never.
        assert!(!threatens(&robot, ahead, &[person(2.0, 2.0)], 5.0));
        let mut beside = person(2.0, -1.0);
        beside.position.y = 0.7;
        assert!(!threatens(&robot, ahead, &[beside], 5.0));
        let mut rewards = vec![1.0, 2.0, f64::NEG_INFINITY];
        shield_people(&mut rewards, &[false, true, false]);
        assert_eq!(rewards, vec![1.0, f64::NEG_INFINITY, f64::NEG_INFINITY]);
        // Only a walled (−∞) candidate keeps clear: nothing changes.
        let mut rewards = vec![1.0, 2.0, f64::NEG_INFINITY];
        shield_people(&mut rewards, &[true, true, false]);
        assert_eq!(rewards, vec![1.0, 2.0, f64::NEG_INFINITY]);
    }

    /// The depth-2 value of one state written out by hand: every first step `a`, every second
    /// step `b` of `second` (`None`: every action), the humans on at constant velocity,
    /// `r1 + d·max_b[r2 + d·V(s'')]`.
    fn depth_two_by_hand(
        env: &Env,
        net: &ValueNet,
        gamma: f64,
        second: Option<&[usize]>,
    ) -> Vec<f64> {
        let cfg = env.config();
        let robot = *env.robot();
        let d = gamma.powf(cfg.dt_s * robot.v_pref_mps);
        let velocities: Vec<Vec2> = env.humans().iter().map(|h| h.velocity).collect();
        let ahead = |k: f64| -> Vec<HumanState> {
            env.humans()
                .iter()
                .map(|h| HumanState {
                    position: h.position + h.velocity * (k * cfg.dt_s),
                    ..*h
                })
                .collect()
        };
        let (one, two) = (ahead(1.0), ahead(2.0));
        let seen: Vec<HumanObs> = two.iter().map(HumanObs::from).collect();
        let actions = env.action_set();
        (0..actions.len())
            .map(|a| {
                let first = evaluate_step(
                    cfg,
                    &robot,
                    actions.get(a).unwrap(),
                    env.humans(),
                    &velocities,
                    env.steps() + 1,
                );
                assert!(!first.outcome.is_terminal(), "pick states far from the end");
                let mut best = f64::NEG_INFINITY;
                let every: Vec<usize> = (0..actions.len()).collect();
                for &b in second.unwrap_or(&every) {
                    let second = evaluate_step(
                        cfg,
                        &first.robot_next,
                        actions.get(b).unwrap(),
                        &one,
                        &velocities,
                        env.steps() + 2,
                    );
                    let mut row = Vec::new();
                    featurize_into(
                        &second.robot_next,
                        &seen,
                        HumanOrder::AsGiven,
                        &mut Vec::new(),
                        &mut row,
                    );
                    let v = net.values(StateBatch::new(&row, 1, seen.len()).unwrap())[0];
                    best = best.max(second.reward.total + d * v as f64);
                }
                first.reward.total + d * best
            })
            .collect()
    }

    /// `planned` is the argmax of the depth-2 values written out by hand (ties to the lower
    /// action), with that value.
    fn assert_is_the_best_by_hand(planned: Decision, by_hand: &[f64], seed: u64) {
        let best = by_hand
            .iter()
            .copied()
            .enumerate()
            .fold(
                (0, f64::NEG_INFINITY),
                |b, (a, v)| if v > b.1 { (a, v) } else { b },
            );
        assert_eq!(planned.action, best.0, "seed {seed}");
        assert!(
            (planned.value - best.1).abs() < 1e-9,
            "{} vs {}",
            planned.value,
            best.1
        );
    }

    /// The actions of `la`'s last decision, best one-step value first (ties to the lower index).
    fn one_step_ranking(la: &Lookahead) -> Vec<usize> {
        let mut ranked: Vec<(f64, usize)> =
            la.last_values().enumerate().map(|(a, v)| (v, a)).collect();
        ranked.sort_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)));
        ranked.into_iter().map(|(_, a)| a).collect()
    }

    /// Planning over every first step decides the argmax of the depth-2 values written out by
    /// hand, with that value; planning off (k = 0) decides exactly as the paper's lookahead.
    /// Fails when `with_planning` is ignored: the one-step decision's value is not the depth-2
    /// value (and the decisions differ on some of these states).
    #[test]
    fn planning_over_every_first_step_takes_the_best_depth_two_value() {
        let setting: Setting = "env1-invisible".parse().unwrap();
        let mut env = Env::new(SimConfig::default(), setting, 0).unwrap();
        let net = ValueNet::new(NetConfig::sarl(), 5).unwrap();
        let model = HumanModel::ConstantVelocity;
        let mut paper = Lookahead::new(0.9, model, HumanOrder::AsGiven);
        let mut off = Lookahead::new(0.9, model, HumanOrder::AsGiven).with_planning(0);
        let mut all =
            Lookahead::new(0.9, model, HumanOrder::AsGiven).with_planning(MAX_PLANNING_TOP_K);
        let (mut states, mut differ) = (0, 0);
        for seed in 0..3 {
            env.reset(seed).unwrap();
            // The first steps of an episode: the goal is metres away, nothing is terminal.
            for _ in 0..4 {
                let by_hand = depth_two_by_hand(&env, &net, 0.9, None);
                let planned = all.decide(&mut env, &net).unwrap();
                assert_is_the_best_by_hand(planned, &by_hand, seed);
                let one_step = paper.decide(&mut env, &net).unwrap();
                let k0 = off.decide(&mut env, &net).unwrap();
                assert_eq!(one_step, k0);
                differ += usize::from(one_step.action != planned.action);
                states += 1;
                let action = env.orca_robot_action(0.0);
                env.step(action).unwrap();
            }
        }
        assert!(differ > 0, "planning changed none of {states} decisions");
    }

    /// Threads change nothing a decision returns, with planning or without.
    #[test]
    fn threads_decide_exactly_as_one() {
        let setting: Setting = "env2-invisible".parse().unwrap();
        let mut env = Env::new(SimConfig::default(), setting, 0).unwrap();
        let net = ValueNet::new(NetConfig::sarl(), 10).unwrap();
        for k in [0, 3] {
            let new =
                || Lookahead::new(0.9, HumanModel::Orca, HumanOrder::AsGiven).with_planning(k);
            let (mut one, mut two) = (new(), new().with_threads(2));
            env.reset(1).unwrap();
            let mut steps = 0;
            while !env.is_done() && steps < 40 {
                let a = one.decide(&mut env, &net).unwrap();
                let b = two.decide(&mut env, &net).unwrap();
                assert_eq!(a, b, "top-k {k}, step {steps}");
                assert!(two.attention(&net).is_none() && one.attention(&net).is_some());
                let action = env.orca_robot_action(0.0);
                env.step(action).unwrap();
                steps += 1;
            }
            assert!(steps > 10);
        }
    }

    /// The progress tie-break decides, among the candidates within the tolerance of the best
    /// value (one-step, or depth-2 over every first step written out by hand), the one whose
    /// step ends nearest the goal; a tolerance of 0 is the plain decision. Fails when the
    /// tolerance is ignored (the decisions differ on some of these states) or misapplied.
    #[test]
    fn the_progress_tie_break_takes_the_nearest_to_the_goal_among_the_near_best() {
        let setting: Setting = "env1-invisible".parse().unwrap();
        let mut env = Env::new(SimConfig::default(), setting, 0).unwrap();
        let net = ValueNet::new(NetConfig::sarl(), 5).unwrap();
        let model = HumanModel::ConstantVelocity;
        let new = || Lookahead::new(0.9, model, HumanOrder::AsGiven);
        let mut plain = new();
        let mut zero = new().with_progress_tolerance(0.0);
        // Several tolerances, so that one applied at the wrong scale is caught too.
        let mut bold: Vec<(f64, Lookahead, Lookahead)> = [0.005, 0.02, 0.08]
            .into_iter()
            .map(|t| {
                let planned = new()
                    .with_planning(MAX_PLANNING_TOP_K)
                    .with_progress_tolerance(t);
                (t, new().with_progress_tolerance(t), planned)
            })
            .collect();
        // By hand: the best (lowest index among equals), then any strictly nearer one within
        // the tolerance.
        fn nearest_within(env: &mut Env, values: &[f64], tolerance: f64) -> (usize, f64) {
            let best = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let goal = env.robot().goal;
            let mut d = |a: usize| (goal - env.preview(a).unwrap().robot_next.position).norm();
            let mut chosen = values.iter().position(|&v| v == best).unwrap();
            let mut nearest = d(chosen);
            for (a, &v) in values.iter().enumerate() {
                let da = d(a);
                if v >= best - tolerance && da < nearest {
                    (chosen, nearest) = (a, da);
                }
            }
            (chosen, values[chosen])
        }
        let (mut states, mut differ) = (0, 0);
        for seed in 0..4 {
            env.reset(seed).unwrap();
            for _ in 0..5 {
                let paper = plain.decide(&mut env, &net).unwrap();
                assert_eq!(zero.decide(&mut env, &net).unwrap(), paper);
                let one_step: Vec<f64> = plain.last_values().collect();
                let by_hand = depth_two_by_hand(&env, &net, 0.9, None);
                for (tolerance, one, two) in &mut bold {
                    let (a, v) = nearest_within(&mut env, &one_step, *tolerance);
                    let d = one.decide(&mut env, &net).unwrap();
                    assert_eq!(
                        (d.action, d.value),
                        (a, v),
                        "seed {seed}, one step, {tolerance}"
                    );
                    differ += usize::from(d.action != paper.action);
                    let (a, v) = nearest_within(&mut env, &by_hand, *tolerance);
                    let d = two.decide(&mut env, &net).unwrap();
                    assert_eq!(d.action, a, "seed {seed}, depth two, {tolerance}");
                    assert!((d.value - v).abs() < 1e-5, "{} against {v}", d.value);
                }
                states += 1;
                let action = env.orca_robot_action(0.0);
                env.step(action).unwrap();
            }
        }
        assert!(
            differ > 0,
            "the tie-break changed none of {states} decisions"
        );
    }

    /// With k first steps rescored, the decision is one of the k best one-step candidates, and
    /// k = 1 is the one-step decision itself.
    #[test]
    fn planning_picks_among_the_k_best_first_steps() {
        let setting: Setting = "env2-invisible".parse().unwrap();
        let mut env = Env::new(SimConfig::default(), setting, 0).unwrap();
        let net = ValueNet::new(NetConfig::sarl(), 10).unwrap();
        let mut paper = Lookahead::new(0.9, HumanModel::Orca, HumanOrder::AsGiven);
        let mut one = Lookahead::new(0.9, HumanModel::Orca, HumanOrder::AsGiven).with_planning(1);
        let mut three = Lookahead::new(0.9, HumanModel::Orca, HumanOrder::AsGiven).with_planning(3);
        let mut steps = 0;
        for seed in 0..3 {
            env.reset(seed).unwrap();
            while !env.is_done() && steps < 150 {
                let d1 = one.decide(&mut env, &net).unwrap();
                let d3 = three.decide(&mut env, &net).unwrap();
                let d0 = paper.decide(&mut env, &net).unwrap();
                assert_eq!(d1.action, d0.action);
                let ranked = one_step_ranking(&paper);
                assert!(
                    ranked.iter().take(3).any(|&a| a == d3.action),
                    "{} not in {:?}",
                    d3.action,
                    &ranked[..3]
                );
                let action = env.orca_robot_action(0.0);
                env.step(action).unwrap();
                steps += 1;
            }
        }
        assert!(steps > 50);
    }

    /// With a breadth of m, each first step's second steps are the m best one-step actions of
    /// the decision: the planned value is the depth-2 value written out by hand over that
    /// subset; a breadth of the whole action set decides as no breadth at all. Fails when
    /// `with_planning_breadth` is ignored: the full second level's value is not the subset's
    /// (checked to differ on some of these states).
    #[test]
    fn planning_breadth_tries_the_m_best_one_step_actions_as_second_steps() {
        let setting: Setting = "env1-invisible".parse().unwrap();
        let mut env = Env::new(SimConfig::default(), setting, 0).unwrap();
        let net = ValueNet::new(NetConfig::sarl(), 5).unwrap();
        let model = HumanModel::ConstantVelocity;
        let new = || Lookahead::new(0.9, model, HumanOrder::AsGiven);
        let mut paper = new();
        let mut full = new().with_planning(MAX_PLANNING_TOP_K);
        let mut wide = new()
            .with_planning(MAX_PLANNING_TOP_K)
            .with_planning_breadth(MAX_PLANNING_TOP_K);
        let mut narrow = new()
            .with_planning(MAX_PLANNING_TOP_K)
            .with_planning_breadth(4);
        let (mut states, mut differ) = (0, 0);
        for seed in 0..3 {
            env.reset(seed).unwrap();
            for _ in 0..4 {
                paper.decide(&mut env, &net).unwrap();
                let ranked = one_step_ranking(&paper);
                let subset: Vec<usize> = ranked.iter().take(4).copied().collect();
                let by_hand = depth_two_by_hand(&env, &net, 0.9, Some(&subset));
                let planned = narrow.decide(&mut env, &net).unwrap();
                assert_is_the_best_by_hand(planned, &by_hand, seed);
                let everything = full.decide(&mut env, &net).unwrap();
                assert_eq!(wide.decide(&mut env, &net).unwrap(), everything);
                differ += usize::from((everything.value - planned.value).abs() > 1e-12);
                states += 1;
                let action = env.orca_robot_action(0.0);
                env.step(action).unwrap();
            }
        }
        assert!(differ > 0, "the breadth changed none of {states} values");
    }
}
