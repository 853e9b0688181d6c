//! `sim`: the crowd simulator of fsrl (SPEC §2–3). A pure, deterministic library: no IO, no
//! tensors, no async.
//!
//! - [`orca`]: ORCA with RVO2's semantics (float32) and per-agent avoidance responsibility.
//! - [`robot`]: unicycle kinematics and the 51-action set; CrowdNav's holonomic robot and its
//!   81-action set (`robot.kinematics`).
//! - [`scenario`]: the six settings' initial states from (setting, seed).
//! - [`scenes`]: explicit scenes parsed from a scene file's text (CrowdNav's test scenes or
//!   fsrl's format).
//! - [`env`]: the step (humans' ORCA step, robot action, swept closest distance, outcome) and
//!   side-effect-free previews for one-step lookahead; SPEC's step semantics by default,
//!   CrowdNav's exactly with `semantics = "crowdnav"` ([`Semantics::CrowdNav`]).
//! - [`reward`]: the FSRL reward term by term, as a pure function shared by env and policies.
//! - [`episode`]: whole episodes and the paper's metrics.
//!
//! ```
//! use sim::{Env, Setting, SimConfig, run_episode};
//! let setting: Setting = "env2-invisible".parse().unwrap();
//! let mut env = Env::new(SimConfig::default(), setting, 1000).unwrap();
//! let episode = run_episode(&mut env, |env| env.orca_robot_action(0.0), false).unwrap();
//! assert!(episode.summary.outcome.is_terminal());
//! ```

pub mod config;
pub mod env;
pub mod episode;
pub mod geom;
pub mod map;
pub mod obstacles;
pub mod orca;
pub mod reward;
pub mod robot;
pub mod rvo;
pub mod rvo_math;
pub mod scan;
pub mod scenario;
pub mod scene_map;
pub mod scene_problem;
pub mod scenes;
pub mod social_force;
pub mod walled;

pub use config::{
    ConfigError, CrowdModel, DynamicReading, EnvKind, Kinematics, Semantics, Setting, SimConfig,
};
pub use env::{Env, EnvError, RobotCommand, StepInfo};
pub use episode::{
    is_frozen, run_episode, run_episode_with, Aggregate, Episode, EpisodeSummary, Frame,
};
pub use geom::Vec2;
pub use reward::{
    evaluate_step, evaluate_step_among, evaluate_velocity_step, evaluate_velocity_step_among,
    Outcome, RewardTerms, StepEval,
};
pub use robot::{Action, ActionSet, RobotState};
pub use scenario::{HumanState, Scenario, ScenarioError};
pub use scene_map::parse_scenes;
pub use scenes::{SceneCase, SceneError, SceneFile, SceneFormat};
pub use walled::{Walls, WallsError};
