//! The served policy: a model file's network deciding from an observed state, through the same
//! code `fsrl eval` runs (`policy::lookahead::Lookahead::decide` on a `sim::Env` holding the
//! state), so the same state gives the same action.

use std::path::Path;
use std::sync::Arc;

use learner::model::Model;
use policy::lookahead::Lookahead;
use sim::map::StaticMap;
use sim::{
    ActionSet, Env, HumanState, Kinematics, RobotState, Scenario, Setting, SimConfig, Vec2, Walls,
};

use crate::people::PersonObs;

/// Why the policy gave no decision.
#[derive(Debug, thiserror::Error)]
pub enum PolicyFailure {
    #[error("cannot load the model {path}: {reason}")]
    Load { path: String, reason: String },
    #[error("method {0} has no network to serve (ORCA is not a learned policy)")]
    NoNetwork(String),
    #[error("the observation is not usable: {0}")]
    Observation(String),
    #[error("the policy failed: {0}")]
    Decide(String),
    #[error("{0}")]
    NoWalls(String),
}

/// Largest distance from the frame's origin accepted, for the robot, its goal, a person and a
/// person's goal: the simulator's ORCA computes in f32, whose resolution is ~6 mm at 100 km.
pub const MAX_COORDINATE_M: f64 = 1.0e5;
/// Largest speed accepted, for the robot's velocity, a person's velocity and preferred speed.
pub const MAX_SPEED_MPS: f64 = 100.0;
/// Largest radius accepted for a person.
pub const MAX_RADIUS_M: f64 = 100.0;

/// Why `obs` holds values out of the simulator's range (see [`ServedPolicy::decide`]).
fn check_bounds(obs: &Observation) -> Result<(), String> {
    let far = |v: Vec2| v.x.abs() > MAX_COORDINATE_M || v.y.abs() > MAX_COORDINATE_M;
    // A speed that is not a number counts as too fast.
    let fast = |v: Vec2| v.norm() > MAX_SPEED_MPS || v.norm().is_nan();
    if far(obs.robot.position) || far(obs.goal) {
        return Err(format!(
            "the robot or its goal is farther than {MAX_COORDINATE_M} m from the origin"
        ));
    }
    if fast(obs.robot.velocity) {
        return Err(format!("the robot moves faster than {MAX_SPEED_MPS} m/s"));
    }
    for (i, p) in obs.humans.iter().enumerate() {
        let finite = |v: Vec2| v.x.is_finite() && v.y.is_finite();
        if !finite(p.position) || !finite(p.velocity) || p.goal.is_some_and(|g| !finite(g)) {
            return Err(format!("person {i}: a value is not finite"));
        }
        if far(p.position) || p.goal.is_some_and(far) {
            return Err(format!(
                "person {i} or its goal is farther than {MAX_COORDINATE_M} m from the origin"
            ));
        }
        if fast(p.velocity)
            || p.v_pref_mps
                .is_some_and(|v| !(v > 0.0 && v <= MAX_SPEED_MPS))
        {
            return Err(format!(
                "person {i}: speeds must be at most {MAX_SPEED_MPS} m/s (a preferred speed positive)"
            ));
        }
        if p.radius_m.is_some_and(|r| !(r > 0.0 && r <= MAX_RADIUS_M)) {
            return Err(format!(
                "person {i}: the radius must be positive and at most {MAX_RADIUS_M} m"
            ));
        }
    }
    Ok(())
}

/// The robot's state as observed, world (odometry) frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotObs {
    pub position: Vec2,
    /// World-frame velocity.
    pub velocity: Vec2,
    pub heading_rad: f64,
}

/// Everything one decision needs.
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    pub robot: RobotObs,
    pub goal: Vec2,
    pub humans: Vec<PersonObs>,
    /// Control periods since the goal was set.
    pub steps: u32,
}

impl Observation {
    /// What a perfect tracker would report of `env`: the robot, its goal, and every human with
    /// its radius, goal, preferred speed and standing flag (the stand-in, tests and benchmarks).
    pub fn of_env(env: &Env) -> Observation {
        let r = env.robot();
        Observation {
            robot: RobotObs {
                position: r.position,
                velocity: r.velocity,
                heading_rad: r.heading_rad,
            },
            goal: r.goal,
            humans: env.humans().iter().map(PersonObs::of_human).collect(),
            steps: env.steps(),
        }
    }
}

impl Observation {
    /// The most a decision can meet with `people` people (the start-up's timing of the
    /// decision budget): the robot at the origin heading for a goal 4 m ahead, the people on a
    /// grid 0.8 m apart from 2 m ahead, walking across its way, none close enough to collide
    /// in one step (a collision ends a preview early).
    pub fn crowd(people: usize) -> Observation {
        let side = (people as f64).sqrt().ceil().max(1.0) as usize;
        Observation {
            robot: RobotObs {
                position: Vec2::zeros(),
                velocity: Vec2::zeros(),
                heading_rad: std::f64::consts::FRAC_PI_2,
            },
            goal: Vec2::new(0.0, 4.0),
            humans: (0..people)
                .map(|i| {
                    let (row, col) = ((i / side) as f64, (i % side) as f64);
                    PersonObs::tracked(
                        Vec2::new((col - side as f64 / 2.0) * 0.8, 2.0 + row * 0.8),
                        Vec2::new(-0.5, 0.0),
                    )
                })
                .collect(),
            steps: 0,
        }
    }
}

/// A body-frame velocity command for one control period.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Command {
    pub linear_x_mps: f64,
    pub linear_y_mps: f64,
    pub angular_z_radps: f64,
}

impl Command {
    pub const STOP: Command = Command {
        linear_x_mps: 0.0,
        linear_y_mps: 0.0,
        angular_z_radps: 0.0,
    };

    /// The command within `limits`: the linear speed scaled down to `max_speed_mps`, the turn
    /// rate clamped to ±`max_turn_rate_radps` (each when given).
    pub fn limited(self, limits: &Limits) -> Command {
        let speed = self.linear_x_mps.hypot(self.linear_y_mps);
        let scale = match limits.max_speed_mps {
            Some(max) if speed > max => max / speed,
            _ => 1.0,
        };
        let turn = match limits.max_turn_rate_radps {
            Some(max) => self.angular_z_radps.clamp(-max, max),
            None => self.angular_z_radps,
        };
        Command {
            linear_x_mps: self.linear_x_mps * scale,
            linear_y_mps: self.linear_y_mps * scale,
            angular_z_radps: turn,
        }
    }
}

/// Limits applied to the policy's command (none by default: the action set's own).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Limits {
    pub max_speed_mps: Option<f64>,
    pub max_turn_rate_radps: Option<f64>,
}

impl Limits {
    /// Every limit given is a positive, finite number (a negative speed limit would reverse
    /// the robot, NaN or a negative turn rate make `clamp` panic); every problem, one per item.
    pub fn check(&self) -> Vec<String> {
        [
            ("--max-speed-mps", self.max_speed_mps),
            ("--max-turn-rate-radps", self.max_turn_rate_radps),
        ]
        .into_iter()
        .filter_map(|(flag, v)| {
            let v = v?;
            (!(v.is_finite() && v > 0.0)).then(|| {
                format!("{flag} {v}: must be positive and finite (leave it out for no limit)")
            })
        })
        .collect()
    }
}

/// One decision.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decision {
    /// Index into the action set.
    pub action: usize,
    pub speed_mps: f64,
    pub rotation_rad: f64,
    /// The lookahead value (0 when nobody is around and the robot heads for the goal).
    pub value: f64,
    /// The command of the action, before limits.
    pub command: Command,
    /// Nobody was around: the action nearest to full speed toward the goal, not the network.
    pub no_people: bool,
}

/// A loaded model ready to decide.
pub struct ServedPolicy {
    model: Model,
    cfg: SimConfig,
    setting: Setting,
    env: Option<Env>,
    lookahead: Lookahead,
    actions: ActionSet,
    /// The walls every decision's scenario holds (a map's, or the latest scan's).
    walls: Option<Arc<Walls>>,
    /// Why deciding without walls is refused (a server that sees walls through its scan, asked
    /// through the queryable, which carries none).
    walls_required: Option<String>,
}

impl ServedPolicy {
    /// Loads a model file or a checkpoint (as `fsrl eval`, told apart by content).
    /// `robot_visible`: whether people react to the robot (the setting's visibility in the
    /// lookahead's ORCA step for the people); default the model's trained setting's.
    pub fn load(path: &Path, robot_visible: Option<bool>) -> Result<Self, PolicyFailure> {
        let (model, _) = learner::model::load_policy(path).map_err(|e| PolicyFailure::Load {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        Self::from_model(model, robot_visible)
    }

    /// Decides with depth-2 planning over the `top_k` best first steps (0: the paper's one-step
    /// lookahead), whatever the model was trained with; [`ServedPolicy::model`] then says so.
    pub fn with_planning_top_k(mut self, top_k: usize) -> Self {
        self.model.train.planning_top_k = top_k;
        self.lookahead = self.lookahead.with_planning(top_k);
        self
    }

    /// Tries the `breadth` best one-step actions as second steps when planning (0: every
    /// action), whatever the model says; [`ServedPolicy::model`] then says so.
    pub fn with_planning_breadth(mut self, breadth: usize) -> Self {
        self.model.train.planning_breadth = breadth;
        self.lookahead = self.lookahead.with_planning_breadth(breadth);
        self
    }

    /// Splits each decision's network batches over `threads` threads (the decisions are the
    /// same bit for bit; `Lookahead::with_threads`).
    pub fn with_threads(mut self, threads: usize) -> Self {
        self.lookahead = self.lookahead.with_threads(threads);
        self
    }

    pub fn from_model(model: Model, robot_visible: Option<bool>) -> Result<Self, PolicyFailure> {
        if model.method.net().is_none() {
            return Err(PolicyFailure::NoNetwork(model.method.to_string()));
        }
        let cfg = model.method_sim();
        let mut setting = model.setting;
        if let Some(v) = robot_visible {
            setting.robot_visible = v;
        }
        // Exactly the evaluator's lookahead (evaluator::evaluate).
        let lookahead = model.train.lookahead(model.method.human_order());
        let actions = ActionSet::for_config(&cfg);
        Ok(Self {
            model,
            cfg,
            setting,
            env: None,
            lookahead,
            actions,
            walls: None,
            walls_required: None,
        })
    }

    /// Walls from `map` (in the odometry frame) for this policy's world: RVO2's obstacles and
    /// the people's roadmap for the config's people, as the walled settings build them.
    pub fn walls_of(&self, map: StaticMap) -> Result<Arc<Walls>, PolicyFailure> {
        Walls::new(map, &self.cfg, self.cfg.roadmap_radius_m())
            .map(Arc::new)
            .map_err(|e| PolicyFailure::Observation(format!("the walls: {e}")))
    }

    /// Decides among `walls` from now on (None: an open floor): the scenario of every decision
    /// holds them, so the networks see them and the lookahead counts touching one a collision,
    /// exactly as `fsrl eval` among the same walls.
    pub fn set_walls(&mut self, walls: Option<Arc<Walls>>) {
        self.walls = walls;
    }

    /// [`ServedPolicy::set_walls`], by value.
    pub fn with_walls(mut self, walls: Option<Arc<Walls>>) -> Self {
        self.walls = walls;
        self
    }

    /// The walls decisions are made among.
    pub fn walls(&self) -> Option<&Arc<Walls>> {
        self.walls.as_ref()
    }

    /// Refuses every decision without walls, saying `why` (a server driving on its scan asked
    /// through the queryable, whose requests carry no scan: deciding wall-blind is worse than
    /// refusing).
    pub fn requiring_walls(mut self, why: impl Into<String>) -> Self {
        self.walls_required = Some(why.into());
        self
    }

    pub fn model(&self) -> &Model {
        &self.model
    }

    /// The simulator config the policy plans with (the model's, with its method's switches).
    pub fn sim_config(&self) -> &SimConfig {
        &self.cfg
    }

    /// The setting whose visibility the lookahead assumes.
    pub fn setting(&self) -> Setting {
        self.setting
    }

    /// The control period: the simulator's step.
    pub fn period_s(&self) -> f64 {
        self.cfg.dt_s
    }

    pub fn action_set(&self) -> &ActionSet {
        &self.actions
    }

    /// The state the simulator would hold: the robot's radius and preferred speed from the
    /// model's config; a person's radius, preferred speed, goal and standing flag from the
    /// observation when given, else the config's radius and speed, a goal straight on at the
    /// current velocity one second ahead (ORCA then prefers the current velocity) and walking.
    pub fn scenario(&self, obs: &Observation) -> Scenario {
        let r = &self.cfg.robot;
        let h = &self.cfg.humans;
        Scenario {
            robot: RobotState {
                position: obs.robot.position,
                velocity: obs.robot.velocity,
                goal: obs.goal,
                heading_rad: obs.robot.heading_rad,
                radius_m: r.radius_m,
                v_pref_mps: r.v_pref_mps,
            },
            humans: obs
                .humans
                .iter()
                .map(|p| HumanState {
                    position: p.position,
                    velocity: p.velocity,
                    goal: p.goal.unwrap_or(p.position + p.velocity),
                    radius_m: p.radius_m.unwrap_or(h.radius_m),
                    v_pref_mps: p.v_pref_mps.unwrap_or(h.v_pref_mps),
                    standing: p.standing.unwrap_or(false),
                })
                .collect(),
            walls: self.walls.clone(),
        }
    }

    /// The command that executes `action` for one period: unicycle `linear.x = v`,
    /// `angular.z = Δθ / period`; holonomic the action's world velocity in the body frame.
    pub fn command_of(&self, heading_rad: f64, action: usize) -> Command {
        let Some(a) = self.actions.get(action) else {
            return Command::STOP;
        };
        match self.actions.kinematics() {
            Kinematics::Unicycle => Command {
                linear_x_mps: a.speed_mps,
                linear_y_mps: 0.0,
                angular_z_radps: a.rotation_rad / self.cfg.dt_s,
            },
            Kinematics::Holonomic => {
                let rel = a.rotation_rad - heading_rad;
                Command {
                    linear_x_mps: a.speed_mps * rel.cos(),
                    linear_y_mps: a.speed_mps * rel.sin(),
                    angular_z_radps: 0.0,
                }
            }
        }
    }

    /// The action a body-frame command stands for (the robot stand-in's inverse of
    /// [`ServedPolicy::command_of`]): unicycle the action nearest in (speed, Δθ), holonomic the
    /// action nearest to the command's world velocity.
    pub fn action_of(actions: &ActionSet, dt_s: f64, heading_rad: f64, c: &Command) -> usize {
        match actions.kinematics() {
            Kinematics::Unicycle => {
                let rot = c.angular_z_radps * dt_s;
                let mut best = (f64::INFINITY, 0);
                for (i, a) in actions.as_slice().iter().enumerate() {
                    let d = (a.speed_mps - c.linear_x_mps).abs() + (a.rotation_rad - rot).abs();
                    if d < best.0 {
                        best = (d, i);
                    }
                }
                best.1
            }
            Kinematics::Holonomic => {
                let (s, co) = heading_rad.sin_cos();
                let world = Vec2::new(
                    c.linear_x_mps * co - c.linear_y_mps * s,
                    c.linear_x_mps * s + c.linear_y_mps * co,
                );
                actions.nearest(heading_rad, world)
            }
        }
    }

    /// The step counter's ceiling: the first step at which every episode of the model's world
    /// has timed out. A larger count (a goal stamped on another clock, a query's `steps`)
    /// plans exactly as this one and cannot overflow the simulator's `steps + 1`.
    pub fn step_limit(&self) -> u32 {
        let n = (self.cfg.time_limit_s / self.cfg.dt_s).ceil();
        if n.is_finite() && n >= 0.0 {
            n.min(u32::MAX as f64 - 1.0) as u32
        } else {
            0
        }
    }

    /// Decides the action for `obs`. Refuses values the simulator cannot hold: not finite,
    /// positions farther than [`MAX_COORDINATE_M`], speeds above [`MAX_SPEED_MPS`], radii
    /// above [`MAX_RADIUS_M`]. The step count is clamped to [`ServedPolicy::step_limit`].
    pub fn decide(&mut self, obs: &Observation) -> Result<Decision, PolicyFailure> {
        let finite = |v: Vec2| v.x.is_finite() && v.y.is_finite();
        if !finite(obs.robot.position)
            || !finite(obs.robot.velocity)
            || !obs.robot.heading_rad.is_finite()
            || !finite(obs.goal)
        {
            return Err(PolicyFailure::Observation(
                "robot or goal values are not finite".into(),
            ));
        }
        check_bounds(obs).map_err(PolicyFailure::Observation)?;
        if let (None, Some(why)) = (&self.walls, &self.walls_required) {
            return Err(PolicyFailure::NoWalls(why.clone()));
        }
        // The simulator keeps headings in [−π, π); wrapping one already there could change
        // its last bits.
        let h = obs.robot.heading_rad;
        let pi = std::f64::consts::PI;
        let heading = if (-pi..pi).contains(&h) {
            h
        } else {
            sim::geom::wrap_angle(h)
        };
        if obs.humans.is_empty() && self.walls.is_none() {
            // The network needs at least one person; with nobody around, head for the goal.
            // Among walls the network sees the walls' points (and the empty person slots).
            let to_goal = obs.goal - obs.robot.position;
            let n = to_goal.norm();
            let v = if n > 0.0 {
                to_goal / n * self.cfg.robot.v_pref_mps
            } else {
                Vec2::zeros()
            };
            let action = self.actions.nearest(heading, v);
            let a = self.actions.get(action).unwrap_or(sim::Action::STOP);
            return Ok(Decision {
                action,
                speed_mps: a.speed_mps,
                rotation_rad: a.rotation_rad,
                value: 0.0,
                command: self.command_of(heading, action),
                no_people: true,
            });
        }
        let mut scenario = self.scenario(obs);
        scenario.robot.heading_rad = heading;
        let steps = obs.steps.min(self.step_limit());
        let env = match &mut self.env {
            Some(env) => {
                env.resume_from_scenario(0, scenario, steps);
                env
            }
            slot => {
                let env = Env::from_scenario(self.cfg.clone(), self.setting, 0, scenario.clone())
                    .map_err(|e| PolicyFailure::Observation(e.to_string()))?;
                let env = slot.insert(env);
                env.resume_from_scenario(0, scenario, steps);
                env
            }
        };
        let d = self
            .lookahead
            .decide(env, &self.model.net)
            .map_err(|e| PolicyFailure::Decide(e.to_string()))?;
        let a = self.actions.get(d.action).unwrap_or(sim::Action::STOP);
        Ok(Decision {
            action: d.action,
            speed_mps: a.speed_mps,
            rotation_rad: a.rotation_rad,
            value: d.value,
            command: self.command_of(heading, d.action),
            no_people: false,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use policy::joint::HumanOrder;
    use policy::lookahead::HumanModel;

    fn model() -> Model {
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/fsrl-env1-invisible-s0.fsrlm");
        learner::model::load_policy(&path).unwrap().0
    }

    /// Along whole evaluator episodes, the served decision from the observed state is the
    /// evaluator's decision, at every step.
    #[test]
    fn served_decisions_equal_the_evaluators_along_episodes() {
        let m = model();
        let mut served = ServedPolicy::from_model(m.clone(), None).unwrap();
        let cfg = m.method_sim();
        let mut env = Env::new(cfg, m.setting, 1000).unwrap();
        let mut la = Lookahead::new(
            m.train.gamma,
            m.train.human_model.into(),
            m.method.human_order(),
        )
        .with_terminal_previews(m.train.terminal_previews)
        .with_planning(m.train.planning_top_k);
        let mut steps = 0;
        for seed in 1000..1003 {
            env.reset(seed).unwrap();
            while !env.is_done() {
                let want = la.decide(&mut env, &m.net).unwrap();
                let got = served.decide(&Observation::of_env(&env)).unwrap();
                assert_eq!(got.action, want.action, "seed {seed} step {}", env.steps());
                assert_eq!(got.value, want.value);
                env.step(want.action).unwrap();
                steps += 1;
            }
        }
        assert!(steps > 30);
        let _ = (HumanOrder::AsGiven, HumanModel::Orca);
    }

    /// `fsrl serve --planning-top-k 3 --planning-breadth 4`: the served decision is the
    /// evaluator's planned one, planning changes some decisions of the model's own (one-step)
    /// lookahead, and the breadth some values of planning over every second step.
    #[test]
    fn served_planning_decides_as_the_evaluators_planning() {
        let m = model();
        assert_eq!(m.train.planning_top_k, 0);
        let mut served = ServedPolicy::from_model(m.clone(), None)
            .unwrap()
            .with_planning_top_k(3)
            .with_planning_breadth(4);
        assert_eq!(served.model().train.planning_top_k, 3);
        assert_eq!(served.model().train.planning_breadth, 4);
        let cfg = m.method_sim();
        let mut env = Env::new(cfg, m.setting, 1000).unwrap();
        let new = || {
            Lookahead::new(
                m.train.gamma,
                m.train.human_model.into(),
                m.method.human_order(),
            )
            .with_terminal_previews(m.train.terminal_previews)
        };
        let (mut planned, mut one_step) = (new().with_planning(3).with_planning_breadth(4), new());
        let mut wide = new().with_planning(3);
        let (mut steps, mut differ, mut narrower) = (0, 0, 0);
        for seed in 1000..1002 {
            env.reset(seed).unwrap();
            while !env.is_done() {
                let want = planned.decide(&mut env, &m.net).unwrap();
                let plain = one_step.decide(&mut env, &m.net).unwrap();
                let every = wide.decide(&mut env, &m.net).unwrap();
                let got = served.decide(&Observation::of_env(&env)).unwrap();
                assert_eq!((got.action, got.value), (want.action, want.value));
                differ += usize::from(plain.action != want.action);
                narrower += usize::from(every.value != want.value);
                env.step(want.action).unwrap();
                steps += 1;
            }
        }
        assert!(
            steps > 20 && differ > 0 && narrower > 0,
            "{differ}, {narrower} of {steps}"
        );
    }

    #[test]
    fn commands_map_back_to_their_action_and_limits_apply() {
        let served = ServedPolicy::from_model(model(), None).unwrap();
        let dt = served.period_s();
        for a in 0..served.action_set().len() {
            let c = served.command_of(0.7, a);
            assert_eq!(ServedPolicy::action_of(served.action_set(), dt, 0.7, &c), a);
        }
        let c = Command {
            linear_x_mps: 1.0,
            linear_y_mps: 0.0,
            angular_z_radps: -2.0,
        };
        let l = c.limited(&Limits {
            max_speed_mps: Some(0.5),
            max_turn_rate_radps: Some(1.0),
        });
        assert_eq!(l.linear_x_mps, 0.5);
        assert_eq!(l.angular_z_radps, -1.0);
        assert_eq!(c.limited(&Limits::default()), c);
    }

    #[test]
    fn nobody_around_heads_for_the_goal_and_bad_values_are_refused() {
        let mut served = ServedPolicy::from_model(model(), None).unwrap();
        let obs = Observation {
            robot: RobotObs {
                position: Vec2::new(0.0, -4.0),
                velocity: Vec2::zeros(),
                heading_rad: std::f64::consts::FRAC_PI_2,
            },
            goal: Vec2::new(0.0, 4.0),
            humans: vec![],
            steps: 0,
        };
        let d = served.decide(&obs).unwrap();
        assert!(d.no_people);
        assert!(d.command.linear_x_mps > 0.9 && d.command.angular_z_radps.abs() < 0.2);
        let mut bad = obs.clone();
        bad.goal.x = f64::NAN;
        assert!(served.decide(&bad).is_err());
    }

    fn crossing() -> Observation {
        Observation {
            robot: RobotObs {
                position: Vec2::new(0.0, -4.0),
                velocity: Vec2::new(0.0, 0.5),
                heading_rad: std::f64::consts::FRAC_PI_2,
            },
            goal: Vec2::new(0.0, 4.0),
            humans: vec![PersonObs::tracked(
                Vec2::new(1.0, -2.0),
                Vec2::new(-0.5, 0.0),
            )],
            steps: 3,
        }
    }

    #[test]
    fn a_step_count_beyond_the_time_limit_plans_as_the_limit() {
        let mut served = ServedPolicy::from_model(model(), None).unwrap();
        let limit = served.step_limit();
        assert_eq!(limit, 100, "25 s of 0.25 s steps");
        let mut obs = crossing();
        obs.steps = limit;
        let at_limit = served.decide(&obs).unwrap();
        // u32::MAX would wrap the simulator's `steps + 1` to 0 (a fresh episode) in a release
        // build and panic in a debug one.
        obs.steps = u32::MAX;
        assert_eq!(served.decide(&obs).unwrap(), at_limit);
        obs.steps = 0;
        assert_ne!(served.decide(&obs).unwrap().value, at_limit.value);
    }

    #[test]
    fn values_beyond_the_simulators_range_are_refused() {
        let mut served = ServedPolicy::from_model(model(), None).unwrap();
        assert!(served.decide(&crossing()).is_ok());
        let bad: [fn(&mut Observation); 6] = [
            |o| o.robot.position.x = 1e6,
            |o| o.goal.y = -1e300,
            |o| o.robot.velocity.x = 1e3,
            |o| o.humans[0].velocity.y = f64::INFINITY,
            |o| o.humans[0].radius_m = Some(1e9),
            |o| o.humans[0].v_pref_mps = Some(0.0),
        ];
        for (i, f) in bad.iter().enumerate() {
            let mut o = crossing();
            f(&mut o);
            assert!(
                matches!(served.decide(&o), Err(PolicyFailure::Observation(_))),
                "case {i}"
            );
        }
    }

    #[test]
    fn limits_must_be_positive_and_finite() {
        assert!(Limits::default().check().is_empty());
        let ok = Limits {
            max_speed_mps: Some(0.5),
            max_turn_rate_radps: Some(1.0),
        };
        assert!(ok.check().is_empty());
        for bad in [-1.0, 0.0, f64::NAN, f64::INFINITY, -0.5] {
            let l = Limits {
                max_speed_mps: Some(bad),
                max_turn_rate_radps: Some(bad),
            };
            let problems = l.check();
            assert_eq!(problems.len(), 2, "{bad}: {problems:?}");
            assert!(problems[0].starts_with("--max-speed-mps"));
            assert!(problems[1].starts_with("--max-turn-rate-radps"));
        }
    }
}
