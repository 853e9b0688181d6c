//! The environment: state, the humans' ORCA step, the robot's step and one-step previews.

use std::sync::Arc;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::config::{ConfigError, CrowdModel, Kinematics, Setting, SimConfig};
use crate::geom::{Vec2, Vec2f};
use crate::map::StaticMap;
use crate::orca::{Orca, OrcaAgent, OrcaParams};
use crate::reward::{evaluate_step_among, evaluate_velocity_step_among, Outcome, StepEval};
use crate::robot::{ActionSet, RobotState};
use crate::scenario::{HumanState, Scenario, ScenarioError};
use crate::social_force::{self as sf, SocialForceParams};
use crate::walled::{Mover, Route, Walls};

/// Why an environment could not be built or stepped.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EnvError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    #[error("action index {index} is out of range: the action set has {len} actions")]
    UnknownAction { index: usize, len: usize },
    #[error("the episode is over ({0}); reset before stepping again")]
    EpisodeOver(&'static str),
    #[error("a direct velocity command needs robot.kinematics = \"holonomic\"; the robot is {0}")]
    NotHolonomic(Kinematics),
}

/// What the robot does for one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RobotCommand {
    /// An index into the env's [`ActionSet`].
    Action(usize),
    /// A world-frame velocity executed directly (holonomic robot only), e.g. the velocity ORCA
    /// chose, as CrowdNav's holonomic ORCA robot does.
    Velocity(Vec2),
}

/// What one executed step produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepInfo {
    /// The action executed; for a [`RobotCommand::Velocity`] step, the action of the set whose
    /// velocity is closest to the executed one.
    pub action_index: usize,
    /// Whether the robot executed a direct velocity ([`RobotCommand::Velocity`]).
    pub direct_velocity: bool,
    pub eval: StepEval,
    /// Simulated time at the end of the step.
    pub time_s: f64,
}

/// A crowd-navigation episode in progress.
///
/// The humans' ORCA velocities for the coming step depend only on the current state (the robot's
/// action does not change what humans decide this step), so they are computed once per state and
/// shared by [`Env::preview`] over all candidate actions and by [`Env::step`].
#[derive(Debug, Clone)]
pub struct Env {
    cfg: SimConfig,
    setting: Setting,
    seed: u64,
    actions: ActionSet,
    orca: Orca,
    orca_agents: Vec<OrcaAgent>,
    robot: RobotState,
    humans: Vec<HumanState>,
    steps: u32,
    outcome: Outcome,
    human_velocity: Vec<Vec2>,
    human_velocity_valid: bool,
    /// Static obstacles, and every human's way to its goal then the robot's (walled only).
    walls: Option<Arc<Walls>>,
    routes: Vec<Route>,
    /// Every agent as the doors' turns see it, kept between steps (`take_turns_at_doors`).
    movers: Vec<Mover>,
    /// Per person, drawn from the seed at every reset ([`Env::social_force_humans`],
    /// [`Env::humans_noticing_robot`]).
    social: Vec<bool>,
    notices: Vec<bool>,
    /// The social force model at the env's `dt_s`, and the walls' sample points it reads (only
    /// when some person follows it).
    sf_params: SocialForceParams,
    sf_points: Vec<Vec2>,
}

/// The ChaCha stream of an episode's seed that the people's models and noticing are drawn
/// from; the scenario draws from stream 0, which this leaves untouched.
pub const PEOPLE_STREAM: u64 = 1;

fn orca_params(cfg: &SimConfig) -> OrcaParams {
    OrcaParams {
        neighbor_dist_m: cfg.orca.neighbor_dist_m as f32,
        max_neighbors: cfg.orca.max_neighbors,
        time_horizon_s: cfg.orca.time_horizon_s as f32,
        time_step_s: cfg.dt_s as f32,
        time_horizon_obst_s: cfg.orca.time_horizon_obst_s as f32,
    }
}

/// CrowdNav's preferred velocity: the vector to the goal, normalised only when longer than 1.
fn pref_velocity(position: Vec2, goal: Vec2) -> Vec2f {
    let d = goal - position;
    let n = d.norm();
    let v = if n > 1.0 { d / n } else { d };
    Vec2f::new(v.x as f32, v.y as f32)
}

fn to_f32(v: Vec2) -> Vec2f {
    Vec2f::new(v.x as f32, v.y as f32)
}

/// The preferred velocity among walls: toward the goal as on an open floor when the goal is in
/// sight, else straight at the roadmap node ahead at full speed (`walled`'s module docs).
fn routed_pref_velocity(
    walls: &Walls,
    route: &Route,
    position: Vec2,
    goal: Vec2,
    radius_m: f64,
) -> Vec2f {
    let (target, is_goal) = walls.target(position, route, radius_m);
    if is_goal {
        return pref_velocity(position, goal);
    }
    let d = target - position;
    let n = d.norm();
    to_f32(if n > 0.0 { d / n } else { d })
}

impl Env {
    /// The episode of `setting` for `seed`.
    pub fn new(cfg: SimConfig, setting: Setting, seed: u64) -> Result<Self, EnvError> {
        cfg.resolve_settings(&[setting.name()])?;
        let scenario = Scenario::generate(&cfg, setting, seed)?;
        Ok(Self::from_parts(cfg, setting, seed, scenario))
    }

    /// An episode that starts from an explicit scenario.
    pub fn from_scenario(
        cfg: SimConfig,
        setting: Setting,
        seed: u64,
        scenario: Scenario,
    ) -> Result<Self, EnvError> {
        cfg.validate()?;
        Ok(Self::from_parts(cfg, setting, seed, scenario))
    }

    fn from_parts(cfg: SimConfig, setting: Setting, seed: u64, scenario: Scenario) -> Self {
        let actions = ActionSet::for_config(&cfg);
        let n = scenario.humans.len();
        let mut env = Self {
            orca: Orca::new(orca_params(&cfg)),
            orca_agents: Vec::with_capacity(n + 1),
            human_velocity: Vec::with_capacity(n),
            human_velocity_valid: false,
            robot: scenario.robot,
            humans: scenario.humans,
            steps: 0,
            outcome: Outcome::Running,
            walls: None,
            routes: Vec::new(),
            movers: Vec::new(),
            social: Vec::with_capacity(n),
            notices: Vec::with_capacity(n),
            sf_params: cfg.social_force.params(cfg.dt_s),
            sf_points: Vec::new(),
            cfg,
            setting,
            seed,
            actions,
        };
        env.set_walls(scenario.walls);
        env.draw_people();
        env
    }

    /// Draws each person's model and whether it notices the robot from the seed's
    /// [`PEOPLE_STREAM`] (two draws per person, in order, whatever the config, so that changing
    /// one probability does not reshuffle the other), then samples the walls for the social
    /// force model if anyone follows it. Today's crowd (all ORCA, all noticing) draws nothing.
    fn draw_people(&mut self) {
        let h = &self.cfg.humans;
        let n = self.humans.len();
        self.social.clear();
        self.notices.clear();
        if h.is_plain_orca() {
            self.social.resize(n, false);
            self.notices.resize(n, true);
        } else {
            let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
            rng.set_stream(PEOPLE_STREAM);
            for _ in 0..n {
                let model_draw: f64 = rng.gen();
                let notice_draw: f64 = rng.gen();
                self.social.push(match h.model {
                    CrowdModel::Orca => false,
                    CrowdModel::SocialForce => true,
                    CrowdModel::Mixed => model_draw < h.social_force_fraction,
                });
                self.notices.push(notice_draw < h.visible_prob);
            }
        }
        self.sf_points.clear();
        if let (Some(w), true) = (&self.walls, self.social.contains(&true)) {
            let resolution = self.sf_params.scene.resolution_per_m;
            for (k, seg) in w.map().segments().iter().enumerate() {
                let seg = sf::Segment {
                    start: seg.a,
                    end: seg.b,
                };
                // psf refuses a segment too short for one sample; here it is its start point.
                if sf::sample_segment(&seg, resolution, k, &mut self.sf_points).is_err() {
                    self.sf_points.push(seg.start);
                }
            }
        }
    }

    /// Per person: whether it follows the social force model this episode (else ORCA).
    pub fn social_force_humans(&self) -> &[bool] {
        &self.social
    }

    /// Per person: whether it notices the robot this episode (`humans.visible_prob`). The robot
    /// is in a person's ORCA neighbours or social force only when it also is visible in the
    /// setting.
    pub fn humans_noticing_robot(&self) -> &[bool] {
        &self.notices
    }

    /// Whether person `i` takes the robot into account (its ORCA neighbours, its social force):
    /// the robot is visible in the setting and the person notices it.
    fn sees_robot(&self, i: usize) -> bool {
        self.setting.robot_visible && self.notices[i]
    }

    /// Takes the scenario's walls and plans every agent's way to its goal over them.
    fn set_walls(&mut self, walls: Option<Arc<Walls>>) {
        self.routes.clear();
        if let Some(w) = &walls {
            self.routes
                .extend(self.humans.iter().map(|h| w.route(h.goal)));
            self.routes.push(w.route(self.robot.goal));
        }
        self.walls = walls;
    }

    /// The goal the robot observes: its goal, or among walls with
    /// `walls.roadmap.robot_waypoint` where the roadmap leads it next (its goal when in sight
    /// with its radius of clearance, else the node on the shortest way there), as the ORCA
    /// robot and the people find their way. The reward and the episode's end keep the goal.
    pub fn observed_goal(&self) -> Vec2 {
        match (&self.walls, self.routes.last()) {
            (Some(w), Some(route)) if self.cfg.walls.roadmap.robot_waypoint => {
                let radius_m = self.robot.radius_m + self.cfg.orca.radius_margin_m;
                w.target(self.robot.position, route, radius_m).0
            }
            _ => self.robot.goal,
        }
    }

    /// The episode's static obstacles (None on an open floor).
    pub fn walls(&self) -> Option<&Arc<Walls>> {
        self.walls.as_ref()
    }

    /// The static entities the robot sees now, appended to `out`; nothing on an open floor
    /// unless its crowd size varies (`humans.count_max`: the empty person slots). Among walls:
    /// first one "no return" point per person slot left empty (the room has 5–8
    /// people and the networks a fixed number of entities per run: [`SimConfig::people_slots`]),
    /// then the sensor's obstacle points ([`crate::walled::obstacle_points`]). A "no return" point
    /// is what an empty sensor sector reads: at the sensor's range, here straight behind.
    pub fn static_entities_into(&self, out: &mut Vec<Vec2>) {
        let Some(slots) = self.cfg.people_slots(self.setting.env) else {
            return;
        };
        let sensor = &self.cfg.walls.sensor;
        let (pose, heading) = (self.robot.position, self.robot.heading_rad);
        let behind = pose - crate::geom::heading(heading) * sensor.range_m;
        out.extend(std::iter::repeat_n(
            behind,
            slots.saturating_sub(self.humans.len()),
        ));
        let Some(w) = &self.walls else {
            return;
        };
        out.extend(crate::walled::obstacle_points(
            w.map(),
            sensor,
            pose,
            heading,
        ));
    }

    /// The walls' map, if any (for rewards computed outside the env).
    pub fn wall_map(&self) -> Option<&StaticMap> {
        self.walls.as_deref().map(Walls::map)
    }

    /// Starts the episode of `seed` in the same setting, reusing every buffer.
    pub fn reset(&mut self, seed: u64) -> Result<(), EnvError> {
        let scenario = Scenario::generate(&self.cfg, self.setting, seed)?;
        self.reset_to_scenario(seed, scenario);
        Ok(())
    }

    /// Starts a new episode from an explicit scenario (e.g. a scene file's case), reusing every
    /// buffer; `seed` only names the episode.
    pub fn reset_to_scenario(&mut self, seed: u64, scenario: Scenario) {
        self.robot = scenario.robot;
        self.humans = scenario.humans;
        self.seed = seed;
        self.steps = 0;
        self.outcome = Outcome::Running;
        self.human_velocity_valid = false;
        self.set_walls(scenario.walls);
        self.draw_people();
    }

    /// Puts the episode in an explicit state with `steps` steps already taken, reusing every
    /// buffer: a state observed from outside (a served policy on a robot), where the step count
    /// decides the time limit and the time reward as in a simulated episode.
    pub fn resume_from_scenario(&mut self, seed: u64, scenario: Scenario, steps: u32) {
        self.reset_to_scenario(seed, scenario);
        self.steps = steps;
    }

    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }
    pub fn setting(&self) -> Setting {
        self.setting
    }
    pub fn seed(&self) -> u64 {
        self.seed
    }
    pub fn action_set(&self) -> &ActionSet {
        &self.actions
    }
    pub fn robot(&self) -> &RobotState {
        &self.robot
    }
    pub fn humans(&self) -> &[HumanState] {
        &self.humans
    }
    /// Steps taken so far.
    pub fn steps(&self) -> u32 {
        self.steps
    }
    /// Simulated time.
    pub fn time_s(&self) -> f64 {
        self.steps as f64 * self.cfg.dt_s
    }
    /// `Running` until a terminal step.
    pub fn outcome(&self) -> Outcome {
        self.outcome
    }
    pub fn is_done(&self) -> bool {
        self.outcome.is_terminal()
    }

    fn fill_orca_agents(&mut self, robot_extra_radius_m: f64) {
        let margin = self.cfg.orca.radius_margin_m;
        self.orca_agents.clear();
        let walls = self.walls.as_deref();
        let pref = |k: usize, position: Vec2, goal: Vec2, radius_m: f64| match walls {
            Some(w) => routed_pref_velocity(w, &self.routes[k], position, goal, radius_m),
            None => pref_velocity(position, goal),
        };
        for (k, h) in self.humans.iter().enumerate() {
            self.orca_agents.push(OrcaAgent {
                position: to_f32(h.position),
                velocity: to_f32(h.velocity),
                pref_velocity: pref(k, h.position, h.goal, h.radius_m + margin),
                radius_m: (h.radius_m + margin) as f32,
                max_speed_mps: h.v_pref_mps as f32,
                reciprocal: !h.standing,
            });
        }
        self.orca_agents.push(OrcaAgent {
            position: to_f32(self.robot.position),
            velocity: to_f32(self.robot.velocity),
            pref_velocity: pref(
                self.humans.len(),
                self.robot.position,
                self.robot.goal,
                self.robot.radius_m + margin + robot_extra_radius_m,
            ),
            radius_m: (self.robot.radius_m + margin + robot_extra_radius_m) as f32,
            max_speed_mps: self.robot.v_pref_mps as f32,
            reciprocal: true,
        });
        if let Some(w) = self.walls.clone().filter(|w| !w.doors().is_empty()) {
            self.take_turns_at_doors(&w);
        }
    }

    /// People (and the ORCA robot) wait for their turn at a one-way door
    /// ([`Walls::door_turn`]): a waiting agent's preferred velocity heads for its waiting spot.
    /// People see the robot only when it is visible; the ORCA robot sees everyone.
    fn take_turns_at_doors(&mut self, w: &Walls) {
        let n = self.humans.len();
        let mut movers = std::mem::take(&mut self.movers);
        movers.clear();
        movers.extend(self.humans.iter().map(|h| Mover {
            position: h.position,
            goal: h.goal,
            moving: !h.standing,
        }));
        movers.push(Mover {
            position: self.robot.position,
            goal: self.robot.goal,
            moving: true,
        });
        let robot_seen = self.setting.robot_visible;
        for (k, agent) in self.orca_agents.iter_mut().enumerate() {
            if let Some(spot) = w.door_turn(k, &movers, |j| j < n || robot_seen || k == n) {
                agent.pref_velocity = pref_velocity(movers[k].position, spot);
            }
        }
        self.movers = movers;
    }

    /// The velocity every human takes during the coming step, from the current state: zero for
    /// standing humans; for dynamic ones ORCA, or the social force model for those who follow it
    /// ([`Env::social_force_humans`]). The robot counts only when it is visible and the person
    /// notices it ([`Env::humans_noticing_robot`]).
    pub fn human_step_velocities(&mut self) -> &[Vec2] {
        if !self.human_velocity_valid {
            self.fill_orca_agents(0.0);
            let n = self.humans.len();
            self.human_velocity.clear();
            for i in 0..n {
                let v = if self.humans[i].standing {
                    Vec2::zeros()
                } else if self.social[i] {
                    self.social_force_velocity(i)
                } else {
                    let visible_len = if self.sees_robot(i) { n + 1 } else { n };
                    let agents = &self.orca_agents[..visible_len];
                    let v = match &self.walls {
                        Some(w) => self.orca.new_velocity_among(i, agents, w.obstacles()),
                        None => self.orca.new_velocity(i, agents),
                    };
                    Vec2::new(v.x as f64, v.y as f64)
                };
                self.human_velocity.push(v);
            }
            self.human_velocity_valid = true;
        }
        &self.human_velocity
    }

    /// The social force model's velocity for person `i` over the coming step (psf's
    /// [`sf::agent_force`] then [`sf::step_velocity`] at `dt_s`): desired speed and speed cap
    /// are the person's `v_pref_mps`; every other person pushes, the robot too when it is
    /// visible and noticed, and the walls' sample points. On an open floor the person heads for
    /// its goal; among walls for the point ORCA's preferred velocity leads to (the roadmap node
    /// ahead, or a waiting spot at a door), the goal once in sight. A non-finite result (two
    /// people on one point with one velocity) stands the person still for the step.
    fn social_force_velocity(&self, i: usize) -> Vec2 {
        let h = &self.humans[i];
        let target = match &self.walls {
            None => h.goal,
            Some(_) => {
                let p = self.orca_agents[i].pref_velocity;
                h.position + Vec2::new(p.x as f64, p.y as f64)
            }
        };
        let others = self
            .humans
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .map(|(_, o)| (o.position, o.velocity));
        let robot = self
            .sees_robot(i)
            .then_some((self.robot.position, self.robot.velocity));
        let force = sf::agent_force(
            &self.sf_params,
            h.position,
            h.velocity,
            target,
            h.v_pref_mps,
            others.chain(robot),
            &self.sf_points,
        );
        let v = sf::step_velocity(
            &self.sf_params.scene,
            h.position,
            h.velocity,
            h.goal,
            h.v_pref_mps,
            force,
        );
        if v.x.is_finite() && v.y.is_finite() {
            v
        } else {
            Vec2::zeros()
        }
    }

    /// The humans as they will be after the coming step, whatever the robot does.
    pub fn next_humans(&mut self, out: &mut Vec<HumanState>) {
        let dt = self.cfg.dt_s;
        self.human_step_velocities();
        out.clear();
        out.extend(
            self.humans
                .iter()
                .zip(&self.human_velocity)
                .map(|(h, v)| HumanState {
                    position: h.position + v * dt,
                    velocity: *v,
                    ..*h
                }),
        );
    }

    /// What the step with `action_index` would give, without changing the episode.
    pub fn preview(&mut self, action_index: usize) -> Result<StepEval, EnvError> {
        let action = self
            .actions
            .get(action_index)
            .ok_or(EnvError::UnknownAction {
                index: action_index,
                len: self.actions.len(),
            })?;
        self.human_step_velocities();
        Ok(evaluate_step_among(
            &self.cfg,
            self.wall_map(),
            &self.robot,
            action,
            &self.humans,
            &self.human_velocity,
            self.steps + 1,
        ))
    }

    /// What a direct-velocity step would give (holonomic robot only), without changing the
    /// episode.
    pub fn preview_velocity(&mut self, velocity: Vec2) -> Result<StepEval, EnvError> {
        if self.cfg.robot.kinematics != Kinematics::Holonomic {
            return Err(EnvError::NotHolonomic(self.cfg.robot.kinematics));
        }
        self.human_step_velocities();
        Ok(evaluate_velocity_step_among(
            &self.cfg,
            self.wall_map(),
            &self.robot,
            velocity,
            &self.humans,
            &self.human_velocity,
            self.steps + 1,
        ))
    }

    /// Executes one step: SPEC §2's order (or CrowdNav's, by `cfg.semantics`), then every agent
    /// moves and time advances.
    pub fn step(&mut self, action_index: usize) -> Result<StepInfo, EnvError> {
        self.step_command(RobotCommand::Action(action_index))
    }

    /// Executes one step with a world-frame velocity (holonomic robot only).
    pub fn step_velocity(&mut self, velocity: Vec2) -> Result<StepInfo, EnvError> {
        self.step_command(RobotCommand::Velocity(velocity))
    }

    /// Executes one step of `command`.
    pub fn step_command(&mut self, command: RobotCommand) -> Result<StepInfo, EnvError> {
        if self.outcome.is_terminal() {
            return Err(EnvError::EpisodeOver(self.outcome.name()));
        }
        let (action_index, direct_velocity, eval) = match command {
            RobotCommand::Action(i) => (i, false, self.preview(i)?),
            RobotCommand::Velocity(v) => {
                let eval = self.preview_velocity(v)?;
                (self.actions.nearest(self.robot.heading_rad, v), true, eval)
            }
        };
        let dt = self.cfg.dt_s;
        self.robot = eval.robot_next;
        for (h, v) in self.humans.iter_mut().zip(&self.human_velocity) {
            h.velocity = *v;
            h.position += v * dt;
        }
        self.steps += 1;
        self.outcome = eval.outcome;
        self.human_velocity_valid = false;
        Ok(StepInfo {
            action_index,
            direct_velocity,
            eval,
            time_s: self.time_s(),
        })
    }

    /// ORCA's velocity for the robot (the robot as ego, every human a neighbour, its ORCA radius
    /// enlarged by `safety_space_m`), as a world-frame velocity.
    pub fn orca_robot_velocity(&mut self, safety_space_m: f64) -> Vec2 {
        self.fill_orca_agents(safety_space_m);
        let ego = self.humans.len();
        let v = match &self.walls {
            Some(w) => self
                .orca
                .new_velocity_among(ego, &self.orca_agents, w.obstacles()),
            None => self.orca.new_velocity(ego, &self.orca_agents),
        };
        Vec2::new(v.x as f64, v.y as f64)
    }

    /// The ORCA robot policy as an action index: ORCA's velocity mapped to the nearest action
    /// of the set (the unicycle set, or the holonomic set for a holonomic robot).
    pub fn orca_robot_action(&mut self, safety_space_m: f64) -> usize {
        let v = self.orca_robot_velocity(safety_space_m);
        self.actions.nearest(self.robot.heading_rad, v)
    }

    /// The ORCA robot: a holonomic robot executes ORCA's velocity directly (CrowdNav's ORCA
    /// baseline); a unicycle robot takes the nearest action ([`Env::orca_robot_action`]).
    pub fn orca_robot_command(&mut self, safety_space_m: f64) -> RobotCommand {
        match self.cfg.robot.kinematics {
            Kinematics::Holonomic => {
                RobotCommand::Velocity(self.orca_robot_velocity(safety_space_m))
            }
            Kinematics::Unicycle => RobotCommand::Action(self.orca_robot_action(safety_space_m)),
        }
    }
}
