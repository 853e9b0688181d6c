//! Simulator configuration: every number of SPEC §2–3 with its default, the six settings, and
//! validation that reports every problem at once.
//!
//! The config structs are the one place in `sim` that derives serde: they are the user-facing
//! schema of the `[sim]` table in a run's TOML file (unknown keys are rejected).

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// The environment family of a setting (paper §IV.A).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum EnvKind {
    /// Ten dynamic humans.
    Env1,
    /// Dynamic humans plus randomly placed standing humans.
    Env2,
    /// Dynamic humans plus two fixed groups of standing humans that form traps.
    Env3,
    /// A corridor about 2 m wide with people walking both ways (`[sim.walls.corridor]`).
    Corridor,
    /// A hall cut by a cross wall with a 1 m door (`[sim.walls.doorway]`).
    Doorway,
    /// A walled room with random rectangular furniture and 5–8 people (`[sim.walls.room]`).
    Room,
    /// Circle crossing around static pillars (`[sim.walls.pillars]`).
    Pillars,
}

impl EnvKind {
    /// Whether the environment has static obstacles.
    pub fn is_walled(self) -> bool {
        matches!(
            self,
            EnvKind::Corridor | EnvKind::Doorway | EnvKind::Room | EnvKind::Pillars
        )
    }
}

/// Env 3's fixed standing humans: a cup of three, concave toward the robot's start, with gaps
/// narrower than the robot, and a wall of two.
pub const ENV3_TRAPS: [[f64; 2]; 5] = [
    [-0.6, -1.2],
    [0.0, -0.9],
    [0.6, -1.2],
    [0.9, 1.5],
    [1.5, 1.5],
];

/// One of the six settings: an environment and whether the humans see the robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Setting {
    pub env: EnvKind,
    /// Visible: the robot is in every human's ORCA neighbourhood as a reciprocal agent.
    pub robot_visible: bool,
}

impl Setting {
    /// The six settings in the paper's order (invisible first, then visible).
    pub const ALL: [Setting; 6] = [
        Setting::new(EnvKind::Env1, false),
        Setting::new(EnvKind::Env2, false),
        Setting::new(EnvKind::Env3, false),
        Setting::new(EnvKind::Env1, true),
        Setting::new(EnvKind::Env2, true),
        Setting::new(EnvKind::Env3, true),
    ];

    /// The settings with static obstacles (issue 53), beyond the paper's six. The corridor and the
    /// doorway exist only with the robot visible: in a 2 m corridor or a 1 m door, people who
    /// cannot see the robot walk into it whatever it does.
    pub const WALLED: [Setting; 6] = [
        Setting::new(EnvKind::Corridor, true),
        Setting::new(EnvKind::Doorway, true),
        Setting::new(EnvKind::Room, false),
        Setting::new(EnvKind::Room, true),
        Setting::new(EnvKind::Pillars, false),
        Setting::new(EnvKind::Pillars, true),
    ];

    /// Every setting: the paper's six, then the walled ones.
    pub fn every() -> impl Iterator<Item = Setting> {
        Setting::ALL.into_iter().chain(Setting::WALLED)
    }

    pub const fn new(env: EnvKind, robot_visible: bool) -> Self {
        Self { env, robot_visible }
    }

    /// The canonical name, e.g. `env2-visible`.
    pub fn name(&self) -> &'static str {
        match (self.env, self.robot_visible) {
            (EnvKind::Env1, false) => "env1-invisible",
            (EnvKind::Env2, false) => "env2-invisible",
            (EnvKind::Env3, false) => "env3-invisible",
            (EnvKind::Env1, true) => "env1-visible",
            (EnvKind::Env2, true) => "env2-visible",
            (EnvKind::Env3, true) => "env3-visible",
            (EnvKind::Corridor, _) => "corridor",
            (EnvKind::Doorway, _) => "doorway",
            (EnvKind::Room, false) => "room-invisible",
            (EnvKind::Room, true) => "room-visible",
            (EnvKind::Pillars, false) => "pillars-invisible",
            (EnvKind::Pillars, true) => "pillars-visible",
        }
    }

    /// Index in [`Setting::every`]: the paper's six are 0–5 (their index in [`Setting::ALL`]),
    /// the walled ones follow.
    pub fn index(&self) -> usize {
        Setting::every()
            .position(|s| s == *self)
            .expect("every() lists every setting")
    }

    /// Whether this is one of the paper's six settings.
    pub fn is_paper(&self) -> bool {
        !self.env.is_walled()
    }
}

impl fmt::Display for Setting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// An unknown setting name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown setting `{0}`; expected one of env1-invisible, env2-invisible, env3-invisible, env1-visible, env2-visible, env3-visible, corridor, doorway, room-invisible, room-visible, pillars-invisible, pillars-visible")]
pub struct UnknownSetting(pub String);

impl FromStr for Setting {
    type Err = UnknownSetting;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Setting::every()
            .find(|setting| setting.name() == s)
            .ok_or_else(|| UnknownSetting(s.to_string()))
    }
}

/// Every problem found in a configuration, reported together.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct ConfigError {
    pub problems: Vec<String>,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "invalid configuration ({} problem", self.problems.len())?;
        if self.problems.len() != 1 {
            f.write_str("s")?;
        }
        f.write_str("):")?;
        for p in &self.problems {
            write!(f, "\n  - {p}")?;
        }
        Ok(())
    }
}

/// Which step semantics the simulator follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Semantics {
    /// SPEC §2: exact swept distance with the humans' new velocities; timeout after the step.
    #[default]
    Spec,
    /// CrowdNav's `CrowdSim.step` exactly, a compatibility mode for reproducing its numbers
    /// (`crowdnav-facts.md` §1.6, §7):
    /// - collision and closest distance on the *relative segment* built from each human's
    ///   previous velocity (the one stored from the last step, not this step's ORCA velocity) and
    ///   the robot's commanded velocity, with CrowdNav's point-to-segment arithmetic; the scan
    ///   stops at the first colliding human;
    /// - timeout first, when the time at the *start* of the step is ≥ time_limit − 1 s (with
    ///   the defaults the 97th step, ending at 24.25 s), then collision, then reach-goal, then
    ///   danger; R_c is 0 on the timeout step;
    /// - danger only on non-terminal steps.
    ///
    /// The humans still move with this step's ORCA velocities and time advances by dt.
    #[serde(rename = "crowdnav")]
    CrowdNav,
}

impl Semantics {
    pub fn name(self) -> &'static str {
        match self {
            Semantics::Spec => "spec",
            Semantics::CrowdNav => "crowdnav",
        }
    }
}

impl fmt::Display for Semantics {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// An unknown semantics or kinematics name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown {what} `{name}`; expected one of {expected}")]
pub struct UnknownName {
    pub what: &'static str,
    pub name: String,
    pub expected: &'static str,
}

impl FromStr for Semantics {
    type Err = UnknownName;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "spec" => Ok(Semantics::Spec),
            "crowdnav" => Ok(Semantics::CrowdNav),
            _ => Err(UnknownName {
                what: "semantics",
                name: s.to_string(),
                expected: "spec, crowdnav",
            }),
        }
    }
}

/// How the robot moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Kinematics {
    /// SPEC §2: an action (v, Δθ) turns the heading by Δθ, then the robot drives straight at v.
    #[default]
    Unicycle,
    /// CrowdNav's holonomic robot: it moves at any world-frame velocity; its heading never
    /// changes. The action set is stop plus `holonomic_headings` world-frame directions
    /// k·2π/headings × the exponential speeds (CrowdNav: 16 × 5 = 81 actions).
    Holonomic,
}

impl Kinematics {
    pub fn name(self) -> &'static str {
        match self {
            Kinematics::Unicycle => "unicycle",
            Kinematics::Holonomic => "holonomic",
        }
    }
}

impl fmt::Display for Kinematics {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Kinematics {
    type Err = UnknownName;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "unicycle" => Ok(Kinematics::Unicycle),
            "holonomic" => Ok(Kinematics::Holonomic),
            _ => Err(UnknownName {
                what: "kinematics",
                name: s.to_string(),
                expected: "unicycle, holonomic",
            }),
        }
    }
}

/// The robot (SPEC §2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobotConfig {
    pub radius_m: f64,
    pub v_pref_mps: f64,
    pub start_m: [f64; 2],
    pub goal_m: [f64; 2],
    pub heading_rad: f64,
    /// Unicycle (SPEC, the default) or holonomic (CrowdNav's baselines).
    pub kinematics: Kinematics,
    /// World-frame directions of the holonomic action set, evenly spaced over [0, 2π) starting
    /// at 0 (CrowdNav: 16). Unused by the unicycle robot, whose rotations are `actions.*`.
    pub holonomic_headings: usize,
}

impl Default for RobotConfig {
    fn default() -> Self {
        Self {
            radius_m: 0.3,
            v_pref_mps: 1.0,
            start_m: [0.0, -4.0],
            goal_m: [0.0, 4.0],
            heading_rad: std::f64::consts::FRAC_PI_2,
            kinematics: Kinematics::Unicycle,
            holonomic_headings: 16,
        }
    }
}

/// The humans and how scenarios place them (SPEC §2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HumanConfig {
    /// Humans per episode (dynamic + standing).
    pub count: usize,
    /// Standing humans in Env 2 and Env 3 (Env 1 has none; Env 3's traps need exactly 5).
    pub standing: usize,
    pub radius_m: f64,
    pub v_pref_mps: f64,
    /// Circle-crossing circle radius.
    pub circle_radius_m: f64,
    /// Half-width of the uniform start noise (times v_pref), per axis.
    pub start_noise_m: f64,
    /// Standing humans of Env 2 are uniform in [−w, w]².
    pub square_half_width_m: f64,
    /// Extra clearance between sampled agents (CrowdNav's discomfort distance).
    pub spawn_gap_m: f64,
    /// Env 2 standing humans keep at least this far from the robot's start and goal.
    pub standing_clear_of_robot_m: f64,
    /// Give up placing a human after this many rejected draws.
    pub max_spawn_attempts: usize,
    /// How the people decide where to walk: ORCA (the default), the social force model
    /// (`[sim.social_force]`), or a mix of both. Standing humans stand whatever their model.
    #[serde(skip_serializing_if = "CrowdModel::is_orca")]
    pub model: CrowdModel,
    /// With `model = "mixed"`: the probability that a person follows the social force model,
    /// drawn per person per episode from the episode's seed (a stream of its own: the scenario's
    /// draws are unchanged).
    #[serde(skip_serializing_if = "is_default_social_force_fraction")]
    pub social_force_fraction: f64,
    /// HEIGHT's `visible_prob`: the probability that a person notices the robot, drawn per
    /// person per episode from the seed. One who does not leaves the robot out of its ORCA
    /// neighbours or its social force, as everyone does in an invisible setting.
    #[serde(skip_serializing_if = "is_one")]
    pub visible_prob: f64,
    /// Crowds of any size (issue 54): each episode of the paper's settings draws its
    /// `humans.count` uniformly from `count..=count_max` (from the episode's seed, a stream of
    /// its own), and the networks see `count_max` person rows, the empty ones as "no return"
    /// points ([`SimConfig::people_slots`]). Unset: every episode has `count` people.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub count_max: Option<usize>,
    /// The person rows the networks see when no count range is drawn (`fsrl eval --people`
    /// testing a model trained with `count_max` in a crowd of one size keeps its rows)
    /// [default: `count_max`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slots: Option<usize>,
    /// The most moving people the circle-crossing circle holds at `circle_radius_m`: an episode
    /// with more crosses a circle grown by √(people / this), the same people per square metre
    /// (twenty people do not fit on the paper's 4 m circle with their goals clear). Unset: the
    /// circle never grows.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub circle_grows_past: Option<usize>,
}

/// The people's motion model (`humans.model`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CrowdModel {
    /// Every person runs ORCA (SPEC §2).
    #[default]
    Orca,
    /// Every person follows pysocialforce's social force model (`docs/SOCIAL_FORCE.md`).
    SocialForce,
    /// Each person follows the social force model with probability `humans.social_force_fraction`,
    /// ORCA otherwise.
    Mixed,
}

impl CrowdModel {
    pub fn name(self) -> &'static str {
        match self {
            CrowdModel::Orca => "orca",
            CrowdModel::SocialForce => "social-force",
            CrowdModel::Mixed => "mixed",
        }
    }

    fn is_orca(&self) -> bool {
        *self == CrowdModel::Orca
    }
}

impl fmt::Display for CrowdModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for CrowdModel {
    type Err = UnknownName;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "orca" => Ok(CrowdModel::Orca),
            "social-force" => Ok(CrowdModel::SocialForce),
            "mixed" => Ok(CrowdModel::Mixed),
            _ => Err(UnknownName {
                what: "crowd model",
                name: s.to_string(),
                expected: "orca, social-force, mixed",
            }),
        }
    }
}

/// The most people `humans.count_max` and `humans.slots` accept.
pub const MAX_PEOPLE: usize = 40;

/// `humans.social_force_fraction`'s default.
pub const DEFAULT_SOCIAL_FORCE_FRACTION: f64 = 0.5;

fn is_default_social_force_fraction(v: &f64) -> bool {
    *v == DEFAULT_SOCIAL_FORCE_FRACTION
}

fn is_one(v: &f64) -> bool {
    *v == 1.0
}

impl HumanConfig {
    /// Whether every person runs ORCA and notices the robot (today's crowd): the env then draws
    /// nothing for the people's models.
    pub fn is_plain_orca(&self) -> bool {
        self.model == CrowdModel::Orca && self.visible_prob == 1.0
    }
}

impl Default for HumanConfig {
    fn default() -> Self {
        Self {
            count: 10,
            standing: 5,
            radius_m: 0.3,
            v_pref_mps: 1.0,
            circle_radius_m: 4.0,
            start_noise_m: 0.5,
            square_half_width_m: 4.0,
            spawn_gap_m: 0.2,
            standing_clear_of_robot_m: 1.0,
            max_spawn_attempts: 10_000,
            model: CrowdModel::Orca,
            social_force_fraction: DEFAULT_SOCIAL_FORCE_FRACTION,
            visible_prob: 1.0,
            count_max: None,
            slots: None,
            circle_grows_past: None,
        }
    }
}

/// ORCA parameters for the humans (and the ORCA robot).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OrcaConfig {
    pub neighbor_dist_m: f64,
    pub max_neighbors: usize,
    pub time_horizon_s: f64,
    pub time_horizon_obst_s: f64,
    /// Added to every body radius to form the ORCA radius.
    pub radius_margin_m: f64,
}

impl Default for OrcaConfig {
    fn default() -> Self {
        Self {
            neighbor_dist_m: 10.0,
            max_neighbors: 10,
            time_horizon_s: 5.0,
            time_horizon_obst_s: 5.0,
            radius_margin_m: 0.01,
        }
    }
}

/// The robot's discrete action set (SPEC §2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ActionConfig {
    /// Exponentially spaced speeds up to v_pref.
    pub speeds: usize,
    /// Heading changes evenly spaced over [−max, max], both ends included.
    pub rotations: usize,
    pub max_rotation_rad: f64,
}

impl Default for ActionConfig {
    fn default() -> Self {
        Self {
            speeds: 5,
            rotations: 10,
            max_rotation_rad: std::f64::consts::FRAC_PI_8,
        }
    }
}

/// Which closest distance R_dy (paper eq. 7) reads. The paper's text says "the minimum distance
/// … after ΔT_dy"; its Fig. 2(c) keeps the comfort distance "within ΔT_dy".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DynamicReading {
    /// SPEC §3 literally: the distance at exactly t + ΔT_dy (a snapshot; blind to passing
    /// through a human before ΔT_dy).
    #[default]
    After,
    /// The swept minimum over [t, t + ΔT_dy] (as R_st already reads its horizon).
    Within,
}

impl DynamicReading {
    pub fn name(self) -> &'static str {
        match self {
            DynamicReading::After => "after",
            DynamicReading::Within => "within",
        }
    }
}

/// The FSRL reward (SPEC §3, paper eq. 4–9).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RewardConfig {
    pub success_reward: f64,
    pub collision_penalty: f64,
    /// Comfort distance r_c (boundary to boundary).
    pub comfort_dist_m: f64,
    /// R_c's discomfort slope: 0.25·(−0.1 + d/2) = 0.125·(d − 0.2).
    pub discomfort_slope_per_m: f64,
    /// Effective range r_e (centre distance) of the foresight terms.
    pub effective_range_m: f64,
    /// ΔT_st of R_st.
    pub standing_horizon_s: f64,
    /// α of R_st per step. Default 0.15·dt = 0.0375: the paper's α = 0.15 scaled by the step
    /// (dt = 0.25 s) as R_c's discomfort term is; SPEC's literal per-step 0.15 is
    /// `configs/spec-literal.toml` (the experiment behind the choice: `docs/REPRODUCTION.md`).
    pub standing_alpha: f64,
    /// ΔT_dy of R_dy.
    pub dynamic_horizon_s: f64,
    /// β of R_dy per step. Default 0.5·dt = 0.125 (see `standing_alpha`); SPEC literal 0.5.
    pub dynamic_beta: f64,
    /// Which distance R_dy penalises (the paper is ambiguous; see `docs/REPRODUCTION.md`).
    pub dynamic_reading: DynamicReading,
    /// R_t on reaching the goal is −factor·t/t_limit.
    pub time_goal_factor: f64,
    /// R_t on timeout.
    pub timeout_penalty: f64,
    /// Include R_st + R_dy in the total.
    pub foresight: bool,
    /// Include R_t in the total.
    pub efficiency: bool,
}

impl RewardConfig {
    /// The smallest and largest total one step can pay, for agents whose radii sum to at most
    /// `radius_sum_m` (a receiver checks rewards it did not compute against this).
    pub fn step_bounds(&self, radius_sum_m: f64) -> (f64, f64) {
        // Boundary distances are ≥ −(r_robot + r_human): the deepest overlap.
        let deepest_m = self.comfort_dist_m + radius_sum_m.max(0.0);
        let mut lo = self
            .collision_penalty
            .min(self.success_reward)
            .min(-self.discomfort_slope_per_m.abs() * deepest_m)
            .min(0.0);
        let mut hi = self.collision_penalty.max(self.success_reward).max(0.0);
        if self.foresight {
            lo -= self.standing_alpha.abs() + self.dynamic_beta.abs() * deepest_m;
        }
        if self.efficiency {
            lo += self
                .timeout_penalty
                .min(-self.time_goal_factor.abs())
                .min(0.0);
            hi += self.timeout_penalty.max(0.0);
        }
        (lo, hi)
    }
}

impl Default for RewardConfig {
    fn default() -> Self {
        Self {
            success_reward: 1.0,
            collision_penalty: -0.25,
            comfort_dist_m: 0.2,
            discomfort_slope_per_m: 0.125,
            effective_range_m: 2.0,
            standing_horizon_s: 2.0,
            standing_alpha: 0.15 * 0.25,
            dynamic_horizon_s: 1.0,
            dynamic_beta: 0.5 * 0.25,
            dynamic_reading: DynamicReading::default(),
            time_goal_factor: 0.1,
            timeout_penalty: -0.2,
            foresight: true,
            efficiency: true,
        }
    }
}

/// Everything the simulator needs besides the setting and the seed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    pub dt_s: f64,
    pub time_limit_s: f64,
    pub semantics: Semantics,
    pub robot: RobotConfig,
    pub humans: HumanConfig,
    pub orca: OrcaConfig,
    pub actions: ActionConfig,
    pub reward: RewardConfig,
    /// The walled settings' layouts. Left out of a serialised config when it holds the defaults,
    /// so that every config, model and report written before walls existed is byte-identical.
    #[serde(skip_serializing_if = "WallsConfig::is_default")]
    pub walls: WallsConfig,
    /// The social force model's parameters (people with `humans.model` social-force or mixed).
    /// Left out of a serialised config when it holds the defaults.
    #[serde(skip_serializing_if = "SocialForceConfig::is_default")]
    pub social_force: SocialForceConfig,
}

/// The social force model's parameters (`[sim.social_force]`): pysocialforce 1.1.2's defaults,
/// in SI units. What fsrl takes elsewhere: the time step is `dt_s` (psf: 0.4 s), the desired
/// speed and speed cap are each person's `humans.v_pref_mps` (psf: 1.3 × the initial speed), and
/// groups are not used. See `docs/SOCIAL_FORCE.md`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SocialForceConfig {
    /// `desired_force.factor`.
    pub desired_factor: f64,
    /// `desired_force.relaxation_time`.
    pub relaxation_time_s: f64,
    /// `desired_force.goal_threshold`: nearer its goal a person only brakes.
    pub goal_threshold_m: f64,
    /// `social_force.factor`.
    pub social_factor: f64,
    /// `social_force.lambda_importance` (λ).
    pub lambda_importance: f64,
    /// `social_force.gamma` (γ).
    pub gamma: f64,
    /// `social_force.n`.
    pub n: f64,
    /// `social_force.n_prime` (n′).
    pub n_prime: f64,
    /// `obstacle_force.factor`.
    pub obstacle_factor: f64,
    /// `obstacle_force.sigma`.
    pub obstacle_sigma_m: f64,
    /// `obstacle_force.threshold`.
    pub obstacle_threshold_m: f64,
    /// `scene.agent_radius`: the radius the obstacle force reads (not `humans.radius_m`).
    pub agent_radius_m: f64,
    /// `scene.resolution`: points sampled per metre of wall.
    pub resolution_per_m: f64,
    /// psf's hard-coded 0.5 m: a person who starts a step nearer its goal stands still.
    pub arrive_radius_m: f64,
}

impl Default for SocialForceConfig {
    fn default() -> Self {
        let p = crate::social_force::SocialForceParams::default();
        Self {
            desired_factor: p.desired_force.factor,
            relaxation_time_s: p.desired_force.relaxation_time_s,
            goal_threshold_m: p.desired_force.goal_threshold_m,
            social_factor: p.social_force.factor,
            lambda_importance: p.social_force.lambda_importance,
            gamma: p.social_force.gamma,
            n: p.social_force.n,
            n_prime: p.social_force.n_prime,
            obstacle_factor: p.obstacle_force.factor,
            obstacle_sigma_m: p.obstacle_force.sigma_m,
            obstacle_threshold_m: p.obstacle_force.threshold_m,
            agent_radius_m: p.scene.agent_radius_m,
            resolution_per_m: p.scene.resolution_per_m,
            arrive_radius_m: p.scene.arrive_radius_m,
        }
    }
}

impl SocialForceConfig {
    pub fn is_default(&self) -> bool {
        *self == SocialForceConfig::default()
    }

    /// The model's parameters for an environment stepping every `dt_s`: psf's defaults with
    /// these values, Δt = `dt_s`, and groups off.
    pub fn params(&self, dt_s: f64) -> crate::social_force::SocialForceParams {
        use crate::social_force::*;
        let d = SocialForceParams::default();
        SocialForceParams {
            scene: SceneParams {
                step_width_s: dt_s,
                agent_radius_m: self.agent_radius_m,
                resolution_per_m: self.resolution_per_m,
                enable_group: false,
                arrive_radius_m: self.arrive_radius_m,
                ..d.scene
            },
            desired_force: DesiredForceParams {
                factor: self.desired_factor,
                relaxation_time_s: self.relaxation_time_s,
                goal_threshold_m: self.goal_threshold_m,
            },
            social_force: SocialTermParams {
                factor: self.social_factor,
                lambda_importance: self.lambda_importance,
                gamma: self.gamma,
                n: self.n,
                n_prime: self.n_prime,
            },
            obstacle_force: ObstacleForceParams {
                factor: self.obstacle_factor,
                sigma_m: self.obstacle_sigma_m,
                threshold_m: self.obstacle_threshold_m,
            },
            ..d
        }
    }

    fn check(&self, c: &mut Checker) {
        for (name, v) in [
            ("social_force.desired_factor", self.desired_factor),
            ("social_force.social_factor", self.social_factor),
            ("social_force.lambda_importance", self.lambda_importance),
            ("social_force.n", self.n),
            ("social_force.n_prime", self.n_prime),
            ("social_force.obstacle_factor", self.obstacle_factor),
        ] {
            c.finite(name, v);
        }
        c.positive("social_force.relaxation_time_s", self.relaxation_time_s);
        c.positive("social_force.gamma", self.gamma);
        c.positive("social_force.obstacle_sigma_m", self.obstacle_sigma_m);
        c.positive("social_force.resolution_per_m", self.resolution_per_m);
        if self.resolution_per_m.is_finite() && self.resolution_per_m > MAX_RESOLUTION_PER_M {
            c.0.push(format!(
                "social_force.resolution_per_m must be at most {MAX_RESOLUTION_PER_M} points per \
                 metre, got {}",
                self.resolution_per_m
            ));
        }
        c.non_negative("social_force.goal_threshold_m", self.goal_threshold_m);
        c.non_negative(
            "social_force.obstacle_threshold_m",
            self.obstacle_threshold_m,
        );
        c.non_negative("social_force.agent_radius_m", self.agent_radius_m);
        c.non_negative("social_force.arrive_radius_m", self.arrive_radius_m);
    }
}

/// The most wall points per metre `social_force.resolution_per_m` may ask for (every point
/// costs an `exp` per person per step).
pub const MAX_RESOLUTION_PER_M: f64 = 1000.0;

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            dt_s: 0.25,
            time_limit_s: 25.0,
            semantics: Semantics::Spec,
            robot: RobotConfig::default(),
            humans: HumanConfig::default(),
            orca: OrcaConfig::default(),
            actions: ActionConfig::default(),
            reward: RewardConfig::default(),
            walls: WallsConfig::default(),
            social_force: SocialForceConfig::default(),
        }
    }
}

/// The walled settings' layouts (`[sim.walls.*]`). Lengths in metres, in the world frame where
/// the robot drives from `robot.start_m` to `robot.goal_m` (by default (0, −4) to (0, 4)).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WallsConfig {
    pub corridor: CorridorConfig,
    pub doorway: DoorwayConfig,
    pub room: RoomConfig,
    pub pillars: PillarsConfig,
    pub roadmap: RoadmapConfig,
    pub sensor: SensorConfig,
}

/// How the robot sees static obstacles: in each of `sectors` equal angular sectors around it
/// (sector 0 straight ahead), the nearest obstacle point within `range_m`; an empty sector is
/// a point at `range_m` on the sector's centre line (a range sensor's "no return"). The same
/// points come from a map ([`crate::scan::map_sector_nearest`]) or a laser scan
/// ([`crate::scan::sector_nearest`]); the value networks see each as a static entity of radius 0.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorConfig {
    pub sectors: usize,
    pub range_m: f64,
}

impl Default for SensorConfig {
    fn default() -> Self {
        Self {
            sectors: 12,
            range_m: 4.0,
        }
    }
}

impl WallsConfig {
    pub fn is_default(&self) -> bool {
        *self == WallsConfig::default()
    }

    fn check(&self, c: &mut Checker) {
        let range = |c: &mut Checker, name: &str, lo: usize, hi: usize| {
            if lo > hi {
                c.0.push(format!(
                    "walls.{name}_min ({lo}) must not exceed walls.{name}_max ({hi})"
                ));
            }
        };
        let k = &self.corridor;
        c.positive("walls.corridor.width_m", k.width_m);
        c.positive("walls.corridor.length_m", k.length_m);
        let d = &self.doorway;
        c.positive("walls.doorway.hall_width_m", d.hall_width_m);
        c.positive("walls.doorway.length_m", d.length_m);
        c.positive("walls.doorway.door_width_m", d.door_width_m);
        if d.door_width_m.is_finite()
            && d.hall_width_m.is_finite()
            && d.door_width_m >= d.hall_width_m
        {
            c.0.push(format!(
                "walls.doorway.door_width_m ({}) must be smaller than walls.doorway.hall_width_m ({})",
                d.door_width_m, d.hall_width_m
            ));
        }
        let r = &self.room;
        c.positive("walls.room.side_m", r.side_m);
        range(c, "room.people", r.people_min, r.people_max);
        range(c, "room.furniture", r.furniture_min, r.furniture_max);
        c.positive(
            "walls.room.furniture_half_side_min_m",
            r.furniture_half_side_min_m,
        );
        c.positive(
            "walls.room.furniture_half_side_max_m",
            r.furniture_half_side_max_m,
        );
        if r.furniture_half_side_min_m > r.furniture_half_side_max_m {
            c.0.push(
                "walls.room.furniture_half_side_min_m must not exceed furniture_half_side_max_m"
                    .into(),
            );
        }
        c.non_negative("walls.room.furniture_clearance_m", r.furniture_clearance_m);
        c.non_negative("walls.room.min_trip_m", r.min_trip_m);
        let p = &self.pillars;
        range(c, "pillars.pillars", p.pillars_min, p.pillars_max);
        c.non_negative("walls.pillars.centre_radius_m", p.centre_radius_m);
        c.non_negative("walls.pillars.spacing_m", p.spacing_m);
        c.positive("walls.pillars.size_min_m", p.size_min_m);
        c.positive("walls.pillars.size_max_m", p.size_max_m);
        if p.size_min_m > p.size_max_m {
            c.0.push("walls.pillars.size_min_m must not exceed walls.pillars.size_max_m".into());
        }
        c.non_negative(
            "walls.roadmap.corner_offset_m",
            self.roadmap.corner_offset_m,
        );
        c.non_negative("walls.roadmap.one_way_gap_m", self.roadmap.one_way_gap_m);
        c.non_negative("walls.roadmap.door_zone_m", self.roadmap.door_zone_m);
        c.non_negative(
            "walls.roadmap.door_wait_back_m",
            self.roadmap.door_wait_back_m,
        );
        c.non_negative(
            "walls.roadmap.door_wait_aside_m",
            self.roadmap.door_wait_aside_m,
        );
    }
}

/// A straight corridor along y between two walls at x = ±width/2, people walking both ways.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CorridorConfig {
    pub width_m: f64,
    pub length_m: f64,
    /// People per episode: the first half walk toward the robot (down), the rest along with it.
    pub people: usize,
}

impl Default for CorridorConfig {
    fn default() -> Self {
        Self {
            width_m: 2.0,
            length_m: 14.0,
            people: 6,
        }
    }
}

/// A hall along y between walls at x = ±hall_width/2, cut at y = 0 by a cross wall with a door
/// centred on x = 0; people cross the door both ways.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DoorwayConfig {
    pub hall_width_m: f64,
    pub length_m: f64,
    pub door_width_m: f64,
    /// People per episode: even ones start on the robot's side, odd ones on the far side.
    pub people: usize,
}

impl Default for DoorwayConfig {
    fn default() -> Self {
        Self {
            hall_width_m: 4.0,
            length_m: 14.0,
            door_width_m: 1.0,
            people: 6,
        }
    }
}

/// A square room (a bounding wall) with random rectangular furniture and people walking between
/// random places (HEIGHT-like).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RoomConfig {
    pub side_m: f64,
    pub people_min: usize,
    pub people_max: usize,
    pub furniture_min: usize,
    pub furniture_max: usize,
    pub furniture_half_side_min_m: f64,
    pub furniture_half_side_max_m: f64,
    /// Furniture keeps at least this far from the robot's start and goal, and from each other.
    pub furniture_clearance_m: f64,
    /// A person's goal is at least this far from its start.
    pub min_trip_m: f64,
}

impl Default for RoomConfig {
    fn default() -> Self {
        Self {
            side_m: 9.0,
            people_min: 5,
            people_max: 8,
            furniture_min: 3,
            furniture_max: 6,
            furniture_half_side_min_m: 0.2,
            furniture_half_side_max_m: 0.6,
            furniture_clearance_m: 0.8,
            min_trip_m: 4.0,
        }
    }
}

/// Env 1's circle crossing (`humans.*`) around square and octagonal pillars near the centre.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PillarsConfig {
    pub people: usize,
    pub pillars_min: usize,
    pub pillars_max: usize,
    /// Pillar centres are uniform in the disc of this radius around the origin.
    pub centre_radius_m: f64,
    /// Pillar centres at least this far apart.
    pub spacing_m: f64,
    pub size_min_m: f64,
    pub size_max_m: f64,
}

impl Default for PillarsConfig {
    fn default() -> Self {
        Self {
            people: 5,
            pillars_min: 2,
            pillars_max: 4,
            centre_radius_m: 1.3,
            spacing_m: 1.4,
            size_min_m: 0.2,
            size_max_m: 0.35,
        }
    }
}

/// How people find their way around obstacles: a visibility roadmap (RVO2's `Roadmap` example).
/// Nodes sit off every convex corner and wall end; a person heads for its goal when it sees it
/// (with its radius of clearance), else for the visible node with the shortest way to the goal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RoadmapConfig {
    /// How far off a corner its node sits (beyond the person's radius).
    pub corner_offset_m: f64,
    /// A gap between the free ends of two walls narrower than this (and wide enough for one
    /// person) is a one-way passage, a door: people take turns at it (`sim::walled::Gate`).
    /// 0 turns the turn-taking off.
    pub one_way_gap_m: f64,
    /// How near a door an agent about to cross it takes part in the turns.
    pub door_zone_m: f64,
    /// Where one waits for one's turn: this far back from the door's line...
    pub door_wait_back_m: f64,
    /// ...and this far aside from its axis (so that the one coming through passes).
    pub door_wait_aside_m: f64,
    /// The robot observes, instead of its goal, where the roadmap leads it next (its goal when
    /// in sight, else the roadmap node on the shortest way there: `Env::observed_goal`). Off
    /// by default (what every walled model shipped before it was trained with).
    pub robot_waypoint: bool,
}

impl Default for RoadmapConfig {
    fn default() -> Self {
        Self {
            corner_offset_m: 0.15,
            one_way_gap_m: 1.4,
            door_zone_m: 2.0,
            door_wait_back_m: 1.2,
            door_wait_aside_m: 0.9,
            robot_waypoint: false,
        }
    }
}

struct Checker(Vec<String>);

impl Checker {
    fn finite(&mut self, name: &str, v: f64) -> bool {
        if v.is_finite() {
            true
        } else {
            self.0
                .push(format!("{name} must be a finite number, got {v}"));
            false
        }
    }
    fn positive(&mut self, name: &str, v: f64) {
        if self.finite(name, v) && v <= 0.0 {
            self.0.push(format!("{name} must be > 0, got {v}"));
        }
    }
    fn non_negative(&mut self, name: &str, v: f64) {
        if self.finite(name, v) && v < 0.0 {
            self.0.push(format!("{name} must be >= 0, got {v}"));
        }
    }
    fn at_least(&mut self, name: &str, v: usize, min: usize) {
        if v < min {
            self.0
                .push(format!("{name} must be at least {min}, got {v}"));
        }
    }
}

impl SimConfig {
    /// Checks every field; `Err` lists every problem found.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let mut c = Checker(Vec::new());
        self.check(&mut c);
        if c.0.is_empty() {
            Ok(())
        } else {
            Err(ConfigError { problems: c.0 })
        }
    }

    fn check(&self, c: &mut Checker) {
        c.positive("dt_s", self.dt_s);
        c.positive("time_limit_s", self.time_limit_s);
        if self.dt_s.is_finite() && self.time_limit_s.is_finite() && self.dt_s > self.time_limit_s {
            c.0.push(format!(
                "dt_s ({}) must not exceed time_limit_s ({})",
                self.dt_s, self.time_limit_s
            ));
        }
        let r = &self.robot;
        c.positive("robot.radius_m", r.radius_m);
        c.positive("robot.v_pref_mps", r.v_pref_mps);
        for (name, v) in [
            ("robot.start_m[0]", r.start_m[0]),
            ("robot.start_m[1]", r.start_m[1]),
            ("robot.goal_m[0]", r.goal_m[0]),
            ("robot.goal_m[1]", r.goal_m[1]),
            ("robot.heading_rad", r.heading_rad),
        ] {
            c.finite(name, v);
        }
        if r.kinematics == Kinematics::Holonomic {
            c.at_least("robot.holonomic_headings", r.holonomic_headings, 1);
        }
        let h = &self.humans;
        c.positive("humans.radius_m", h.radius_m);
        c.positive("humans.v_pref_mps", h.v_pref_mps);
        c.positive("humans.circle_radius_m", h.circle_radius_m);
        c.non_negative("humans.start_noise_m", h.start_noise_m);
        c.positive("humans.square_half_width_m", h.square_half_width_m);
        c.non_negative("humans.spawn_gap_m", h.spawn_gap_m);
        c.non_negative(
            "humans.standing_clear_of_robot_m",
            h.standing_clear_of_robot_m,
        );
        c.at_least("humans.max_spawn_attempts", h.max_spawn_attempts, 1);
        let unit_interval = |c: &mut Checker, name: &str, v: f64| {
            if c.finite(name, v) && !(0.0..=1.0).contains(&v) {
                c.0.push(format!("{name} must be a probability in [0, 1], got {v}"));
            }
        };
        unit_interval(c, "humans.visible_prob", h.visible_prob);
        unit_interval(c, "humans.social_force_fraction", h.social_force_fraction);
        if h.model != CrowdModel::Mixed && h.social_force_fraction != DEFAULT_SOCIAL_FORCE_FRACTION
        {
            c.0.push(format!(
                "humans.social_force_fraction ({}) is read only with humans.model = \"mixed\"; \
                 humans.model is \"{}\"",
                h.social_force_fraction, h.model
            ));
        }
        self.social_force.check(c);
        if let Some(max) = h.count_max {
            if max < h.count || max > MAX_PEOPLE {
                c.0.push(format!(
                    "humans.count_max ({max}) must be in humans.count ({})..={MAX_PEOPLE}",
                    h.count
                ));
            }
        }
        if let Some(n) = h.circle_grows_past {
            c.at_least("humans.circle_grows_past", n, 1);
        }
        if let Some(slots) = h.slots {
            if slots == 0 || slots > MAX_PEOPLE {
                c.0.push(format!(
                    "humans.slots ({slots}) must be in 1..={MAX_PEOPLE}"
                ));
            }
        }
        if h.standing > h.count {
            c.0.push(format!(
                "humans.standing ({}) must not exceed humans.count ({})",
                h.standing, h.count
            ));
        }
        let o = &self.orca;
        c.positive("orca.neighbor_dist_m", o.neighbor_dist_m);
        c.positive("orca.time_horizon_s", o.time_horizon_s);
        c.positive("orca.time_horizon_obst_s", o.time_horizon_obst_s);
        c.non_negative("orca.radius_margin_m", o.radius_margin_m);
        let a = &self.actions;
        c.at_least("actions.speeds", a.speeds, 1);
        c.at_least("actions.rotations", a.rotations, 1);
        c.non_negative("actions.max_rotation_rad", a.max_rotation_rad);
        if a.max_rotation_rad.is_finite() && a.max_rotation_rad > std::f64::consts::PI {
            c.0.push(format!(
                "actions.max_rotation_rad must be <= pi, got {}",
                a.max_rotation_rad
            ));
        }
        let w = &self.reward;
        for (name, v) in [
            ("reward.success_reward", w.success_reward),
            ("reward.collision_penalty", w.collision_penalty),
            ("reward.discomfort_slope_per_m", w.discomfort_slope_per_m),
            ("reward.standing_alpha", w.standing_alpha),
            ("reward.dynamic_beta", w.dynamic_beta),
            ("reward.time_goal_factor", w.time_goal_factor),
            ("reward.timeout_penalty", w.timeout_penalty),
        ] {
            c.finite(name, v);
        }
        c.non_negative("reward.comfort_dist_m", w.comfort_dist_m);
        c.non_negative("reward.effective_range_m", w.effective_range_m);
        c.non_negative("reward.standing_horizon_s", w.standing_horizon_s);
        c.non_negative("reward.dynamic_horizon_s", w.dynamic_horizon_s);
        self.walls.check(c);
    }

    /// Validates the config and resolves setting names, reporting every problem of both at once.
    pub fn resolve_settings<S: AsRef<str>>(
        &self,
        names: &[S],
    ) -> Result<Vec<Setting>, ConfigError> {
        let mut c = Checker(Vec::new());
        self.check(&mut c);
        let mut settings = Vec::with_capacity(names.len());
        for name in names {
            match name.as_ref().parse::<Setting>() {
                Ok(s) => {
                    if s.env == EnvKind::Env3 && self.humans.standing != ENV3_TRAPS.len() {
                        c.0.push(format!(
                            "{s} has {} fixed standing humans; humans.standing is {}",
                            ENV3_TRAPS.len(),
                            self.humans.standing
                        ));
                    }
                    settings.push(s);
                }
                Err(e) => c.0.push(e.to_string()),
            }
        }
        if c.0.is_empty() {
            Ok(settings)
        } else {
            Err(ConfigError { problems: c.0 })
        }
    }

    /// The rows (entities) a value network sees per state in `setting`: `humans.count` in the
    /// paper's six; person slots plus obstacle sectors among walls.
    pub fn entities(&self, setting: Setting) -> usize {
        match self.people_slots(setting.env) {
            Some(slots) if setting.env.is_walled() => slots + self.walls.sensor.sectors,
            Some(slots) => slots.max(self.humans.count),
            None => self.humans.count,
        }
    }

    /// The radius the people's roadmap among walls is built for: the configured people's ORCA
    /// radius (`humans.radius_m` + `orca.radius_margin_m`).
    pub fn roadmap_radius_m(&self) -> f64 {
        self.humans.radius_m + self.orca.radius_margin_m
    }

    /// The most people a walled layout has (`Some` for the walled kinds), or in the paper's
    /// settings `humans.slots` / `humans.count_max` when set: the networks see this many person
    /// slots, empty ones as "no return" points (`Env::static_entities_into`).
    pub fn people_slots(&self, env: EnvKind) -> Option<usize> {
        match env {
            EnvKind::Corridor => Some(self.walls.corridor.people),
            EnvKind::Doorway => Some(self.walls.doorway.people),
            EnvKind::Room => Some(self.walls.room.people_max),
            EnvKind::Pillars => Some(self.walls.pillars.people),
            EnvKind::Env1 | EnvKind::Env2 | EnvKind::Env3 => {
                self.humans.slots.or(self.humans.count_max)
            }
        }
    }

    /// The number of steps after which an episode times out.
    pub fn max_steps(&self) -> u32 {
        (self.time_limit_s / self.dt_s - 1e-9).ceil() as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_match_the_spec() {
        let c = SimConfig::default();
        c.validate().unwrap();
        assert_eq!(c.max_steps(), 100);
    }

    #[test]
    fn setting_names_round_trip() {
        for s in Setting::ALL {
            assert_eq!(s.name().parse::<Setting>().unwrap(), s);
            assert_eq!(Setting::ALL[s.index()], s);
        }
        assert!("env4-visible".parse::<Setting>().is_err());
    }

    #[test]
    fn semantics_and_kinematics_names() {
        for s in [Semantics::Spec, Semantics::CrowdNav] {
            assert_eq!(s.name().parse::<Semantics>().unwrap(), s);
        }
        for k in [Kinematics::Unicycle, Kinematics::Holonomic] {
            assert_eq!(k.name().parse::<Kinematics>().unwrap(), k);
        }
        let err = "crowd-nav".parse::<Semantics>().unwrap_err().to_string();
        assert!(err.contains("expected one of spec, crowdnav"), "{err}");
        assert!("omni".parse::<Kinematics>().is_err());
        let mut c = SimConfig::default();
        assert_eq!(c.semantics, Semantics::Spec);
        assert_eq!(c.robot.kinematics, Kinematics::Unicycle);
        c.robot.kinematics = Kinematics::Holonomic;
        c.robot.holonomic_headings = 0;
        let err = c.validate().unwrap_err().to_string();
        assert!(
            err.contains("robot.holonomic_headings must be at least 1"),
            "{err}"
        );
    }

    #[test]
    fn every_problem_is_reported_at_once() {
        let mut c = SimConfig::default();
        c.dt_s = 0.0;
        c.robot.radius_m = -0.3;
        c.humans.standing = 11;
        c.reward.dynamic_beta = f64::NAN;
        c.robot.goal_m[1] = f64::INFINITY;
        let err = c
            .resolve_settings(&["env1-visible", "env9-hidden"])
            .unwrap_err();
        let text = err.to_string();
        assert_eq!(err.problems.len(), 6, "{text}");
        for needle in [
            "dt_s must be > 0",
            "robot.radius_m must be > 0",
            "humans.standing (11) must not exceed humans.count (10)",
            "reward.dynamic_beta must be a finite number",
            "robot.goal_m[1] must be a finite number",
            "unknown setting `env9-hidden`",
        ] {
            assert!(text.contains(needle), "missing {needle:?} in\n{text}");
        }
    }
}
