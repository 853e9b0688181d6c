//! The served policy: a model file's network deciding from an observed state, through the same
//! code `fsrl eval` runs (`policy::lookahead::Lookahead::decide` on a `sim::Env` holding the
//! state), so the same state gives the same action.

use std::path::Path;

use learner::model::Model;
use policy::lookahead::Lookahead;
use sim::{ActionSet, Env, HumanState, Kinematics, RobotState, Scenario, Setting, SimConfig, Vec2};

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
    /// rate clamped to ±`max_turn_rate_radps`.
    pub fn limited(self, limits: &Limits) -> Command {
        let speed = self.linear_x_mps.hypot(self.linear_y_mps);
        let scale = if speed > limits.max_speed_mps {
            limits.max_speed_mps / speed
        } else {
            1.0
        };
        Command {
            linear_x_mps: self.linear_x_mps * scale,
            linear_y_mps: self.linear_y_mps * scale,
            angular_z_radps: self
                .angular_z_radps
                .clamp(-limits.max_turn_rate_radps, limits.max_turn_rate_radps),
        }
    }
}

/// Limits applied to the policy's command (none by default: the action set's own).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    pub max_speed_mps: f64,
    pub max_turn_rate_radps: f64,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_speed_mps: f64::INFINITY,
            max_turn_rate_radps: f64::INFINITY,
        }
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
        let lookahead = Lookahead::new(
            model.train.gamma,
            model.train.human_model.into(),
            model.method.human_order(),
        )
        .with_terminal_previews(model.train.terminal_previews);
        let actions = ActionSet::for_config(&cfg);
        Ok(Self {
            model,
            cfg,
            setting,
            env: None,
            lookahead,
            actions,
        })
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

    /// Decides the action for `obs`.
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
        // The simulator keeps headings in [−π, π); wrapping one already there could change
        // its last bits.
        let h = obs.robot.heading_rad;
        let pi = std::f64::consts::PI;
        let heading = if (-pi..pi).contains(&h) {
            h
        } else {
            sim::geom::wrap_angle(h)
        };
        if obs.humans.is_empty() {
            // The network needs at least one person; with nobody around, head for the goal.
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
        let env = match &mut self.env {
            Some(env) => {
                env.resume_from_scenario(0, scenario, obs.steps);
                env
            }
            slot => {
                let env = Env::from_scenario(self.cfg.clone(), self.setting, 0, scenario.clone())
                    .map_err(|e| PolicyFailure::Observation(e.to_string()))?;
                let env = slot.insert(env);
                env.resume_from_scenario(0, scenario, obs.steps);
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
        .with_terminal_previews(m.train.terminal_previews);
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
            max_speed_mps: 0.5,
            max_turn_rate_radps: 1.0,
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
}
