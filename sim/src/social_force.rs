//! The social force model of pysocialforce 1.1.2 (`pysocialforce.Simulator`), ported to f64 so
//! that it reproduces that library's trajectories bit for bit (checked against
//! `testdata/sf_ref` by `sim/tests/sf_ref.rs`; the reference's rules and quirks are written in
//! `testdata/sf_ref/README.md`, this port in `docs/SOCIAL_FORCE.md`).
//!
//! One [`SocialForceSim::step`] is one `Simulator.step(1)`: the forces `DesiredForce`,
//! `SocialForce`, `ObstacleForce` and, with [`SceneParams::enable_group`], the three group forces
//! (`GroupCoherenceForceAlt`, `GroupRepulsiveForce`, `GroupGazeForceAlt`), all from the same old
//! state, summed in that order; then the semi-implicit Euler step with psf's speed cap and its
//! arrival freeze. psf's quirks are kept on purpose: the desired speed is the speed cap
//! (`max_speed_multiplier` × the initial speed), the angle θ of the social force is not wrapped,
//! the group coherence strength is a constant per group size, and an agent within
//! [`SceneParams::arrive_radius_m`] of its goal stops for good.
//!
//! Numerics, as psf computes them: every norm psf takes through its numba helpers (goal
//! distances, pair distances, |D|, obstacle distances, the arrival test, the initial speeds,
//! group norms) is BLAS `dnrm2` on the x87 FPU, reproduced by [`psf_norm`]; only the speed cap
//! and the obstacle sample count use the plain `sqrt(x² + y²)`. `exp` and `atan2` are the
//! system libm's (glibc on Linux, as numpy's and numba's). Expressions keep psf's grouping and
//! order, sums run left to right in index order, and no fused multiply-add is used.
//!
//! The module is pure and allocation-light: [`SocialForceSim`] keeps its scratch buffers, so a
//! step allocates nothing once built.

use crate::geom::Vec2;

/// psf's default number of obstacle sample points per metre (`Simulator`'s fallback).
pub const DEFAULT_RESOLUTION_PER_M: f64 = 10.0;

/// A segment may give at most this many sample points (a guard against absurd lengths).
pub const MAX_SAMPLES_PER_SEGMENT: usize = 10_000_000;

/// Bad input to the social force model. The model never panics on input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SocialForceError {
    #[error("social force: there are no agents")]
    NoAgents,
    #[error("social force: the {what} of agent {agent} is not finite")]
    NonFiniteAgent { agent: usize, what: &'static str },
    #[error("social force: parameter {name} = {value} is invalid: {why}")]
    BadParam {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
    #[error("social force: obstacle segment {segment} has a non-finite end point")]
    NonFiniteSegment { segment: usize },
    #[error(
        "social force: obstacle segment {segment} is {length_m} m long, which gives no sample \
         point at {resolution_per_m} points per metre (pysocialforce raises a ValueError)"
    )]
    ShortSegment {
        segment: usize,
        length_m: f64,
        resolution_per_m: f64,
    },
    #[error(
        "social force: obstacle segment {segment} is {length_m} m long: at {resolution_per_m} \
         points per metre that is more than {MAX_SAMPLES_PER_SEGMENT} sample points"
    )]
    SegmentTooLong {
        segment: usize,
        length_m: f64,
        resolution_per_m: f64,
    },
    #[error("social force: group {group} names agent {member}, but there are {n_agents} agents")]
    GroupMemberOutOfRange {
        group: usize,
        member: usize,
        n_agents: usize,
    },
    #[error("social force: group {group} names agent {member} twice")]
    DuplicateGroupMember { group: usize, member: usize },
    #[error("social force: expected {expected} {what}, got {got}")]
    LengthMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error(
        "social force: the step gave agent {agent} a non-finite {what} (pysocialforce would \
         carry NaN on: e.g. two agents at one point with one velocity); the state is unchanged"
    )]
    NonFiniteStep { agent: usize, what: &'static str },
}

/// psf's scene-level settings (what `PedState` and `Simulator` read; see the data's README for
/// where each comes from). Defaults are the values psf 1.1.2 actually uses with its default
/// config.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneParams {
    /// Time step Δt (psf's `step_width`; 0.4 s: the default toml's `[scene] step_width = 1.0`
    /// is never read).
    pub step_width_s: f64,
    /// Max speed (= desired speed) = this × the agent's initial speed.
    pub max_speed_multiplier: f64,
    /// Used only by the obstacle force.
    pub agent_radius_m: f64,
    /// psf's 7th state column; it never changes the motion.
    pub tau_s: f64,
    /// Obstacle sample points per metre.
    pub resolution_per_m: f64,
    /// Whether the three group forces are summed.
    pub enable_group: bool,
    /// An agent that starts a step closer than this to its goal stops for good (hard-coded 0.5
    /// in psf).
    pub arrive_radius_m: f64,
}

impl Default for SceneParams {
    fn default() -> Self {
        Self {
            step_width_s: 0.4,
            max_speed_multiplier: 1.3,
            agent_radius_m: 0.35,
            tau_s: 0.5,
            resolution_per_m: DEFAULT_RESOLUTION_PER_M,
            enable_group: true,
            arrive_radius_m: 0.5,
        }
    }
}

/// `[desired_force]`: relaxation towards the goal at the max speed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DesiredForceParams {
    pub factor: f64,
    pub relaxation_time_s: f64,
    /// Within this distance of the goal the force only brakes (`F = −v`).
    pub goal_threshold_m: f64,
}

impl Default for DesiredForceParams {
    fn default() -> Self {
        Self {
            factor: 1.0,
            relaxation_time_s: 0.5,
            goal_threshold_m: 0.2,
        }
    }
}

/// `[social_force]`: Moussaïd et al. (2009) pedestrian interaction, as psf writes it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SocialTermParams {
    pub factor: f64,
    /// λ: weight of the relative velocity in the interaction vector D.
    pub lambda_importance: f64,
    /// γ: B = γ·|D|.
    pub gamma: f64,
    /// n: angular width of the turning term.
    pub n: f64,
    /// n′: angular width of the decelerating term.
    pub n_prime: f64,
}

impl Default for SocialTermParams {
    fn default() -> Self {
        Self {
            factor: 5.1,
            lambda_importance: 2.0,
            gamma: 0.35,
            n: 2.0,
            n_prime: 3.0,
        }
    }
}

/// `[obstacle_force]`: exponential repulsion from every sampled obstacle point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObstacleForceParams {
    pub factor: f64,
    pub sigma_m: f64,
    /// Points count while `distance − agent_radius < threshold + agent_radius`.
    pub threshold_m: f64,
}

impl Default for ObstacleForceParams {
    fn default() -> Self {
        Self {
            factor: 10.0,
            sigma_m: 0.2,
            threshold_m: 3.0,
        }
    }
}

/// `GroupCoherenceForceAlt` (no toml table in psf's default config: factor 1.0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroupCoherenceParams {
    pub factor: f64,
}

impl Default for GroupCoherenceParams {
    fn default() -> Self {
        Self { factor: 1.0 }
    }
}

/// `[group_repulsive_force]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroupRepulsiveParams {
    pub factor: f64,
    /// Member pairs farther apart than this do not repel.
    pub threshold_m: f64,
}

impl Default for GroupRepulsiveParams {
    fn default() -> Self {
        Self {
            factor: 1.0,
            threshold_m: 0.55,
        }
    }
}

/// `GroupGazeForceAlt` (no toml table in psf's default config: factor 1.0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroupGazeParams {
    pub factor: f64,
}

impl Default for GroupGazeParams {
    fn default() -> Self {
        Self { factor: 1.0 }
    }
}

/// Every setting of the model; the default is what pysocialforce 1.1.2 uses with its default
/// config (the data README's `# param` table).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SocialForceParams {
    pub scene: SceneParams,
    pub desired_force: DesiredForceParams,
    pub social_force: SocialTermParams,
    pub obstacle_force: ObstacleForceParams,
    pub group_coherence_force_alt: GroupCoherenceParams,
    pub group_repulsive_force: GroupRepulsiveParams,
    pub group_gaze_force_alt: GroupGazeParams,
}

impl SocialForceParams {
    /// Every value finite, and the divisors and the time step positive.
    pub fn validate(&self) -> Result<(), SocialForceError> {
        let s = &self.scene;
        let positive: [(&'static str, f64); 5] = [
            ("scene.step_width", s.step_width_s),
            ("scene.resolution", s.resolution_per_m),
            (
                "desired_force.relaxation_time",
                self.desired_force.relaxation_time_s,
            ),
            ("obstacle_force.sigma", self.obstacle_force.sigma_m),
            ("scene.max_speed_multiplier", s.max_speed_multiplier),
        ];
        for (name, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(SocialForceError::BadParam {
                    name,
                    value,
                    why: "must be finite and positive",
                });
            }
        }
        let finite: [(&'static str, f64); 15] = [
            ("scene.agent_radius", s.agent_radius_m),
            ("scene.tau", s.tau_s),
            ("scene.arrive_radius", s.arrive_radius_m),
            ("desired_force.factor", self.desired_force.factor),
            (
                "desired_force.goal_threshold",
                self.desired_force.goal_threshold_m,
            ),
            ("social_force.factor", self.social_force.factor),
            (
                "social_force.lambda_importance",
                self.social_force.lambda_importance,
            ),
            ("social_force.gamma", self.social_force.gamma),
            ("social_force.n", self.social_force.n),
            ("social_force.n_prime", self.social_force.n_prime),
            ("obstacle_force.factor", self.obstacle_force.factor),
            ("obstacle_force.threshold", self.obstacle_force.threshold_m),
            (
                "group_coherence_force_alt.factor",
                self.group_coherence_force_alt.factor,
            ),
            (
                "group_repulsive_force.factor",
                self.group_repulsive_force.factor,
            ),
            (
                "group_gaze_force_alt.factor",
                self.group_gaze_force_alt.factor,
            ),
        ];
        for (name, value) in finite {
            if !value.is_finite() {
                return Err(SocialForceError::BadParam {
                    name,
                    value,
                    why: "must be finite",
                });
            }
        }
        let t = self.group_repulsive_force.threshold_m;
        if !t.is_finite() {
            return Err(SocialForceError::BadParam {
                name: "group_repulsive_force.threshold",
                value: t,
                why: "must be finite",
            });
        }
        Ok(())
    }
}

/// One person's initial state. psf's desired speed (and speed cap) is
/// `max_speed_multiplier · |velocity|` of this state: a person that starts at rest never moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pedestrian {
    pub position: Vec2,
    pub velocity: Vec2,
    /// psf has no waypoints: the goal never changes.
    pub goal: Vec2,
}

/// An obstacle line segment. psf writes it `[x1, x2, y1, y2]` (both x first):
/// [`Segment::from_psf`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub start: Vec2,
    pub end: Vec2,
}

impl Segment {
    /// From psf's order: start x, end x, start y, end y.
    pub fn from_psf([x1, x2, y1, y2]: [f64; 4]) -> Self {
        Self {
            start: Vec2::new(x1, y1),
            end: Vec2::new(x2, y2),
        }
    }
}

/// The points psf samples on a segment (`EnvState`): `int(length · resolution)` points from
/// `np.linspace` on each coordinate, the last one exactly the end. `segment_index` only names the
/// segment in an error.
pub fn sample_segment(
    segment: &Segment,
    resolution_per_m: f64,
    segment_index: usize,
    out: &mut Vec<Vec2>,
) -> Result<(), SocialForceError> {
    let (s, e) = (segment.start, segment.end);
    if !(s.x.is_finite() && s.y.is_finite() && e.x.is_finite() && e.y.is_finite()) {
        return Err(SocialForceError::NonFiniteSegment {
            segment: segment_index,
        });
    }
    let (dx, dy) = (s.x - e.x, s.y - e.y);
    let length_m = (dx * dx + dy * dy).sqrt();
    let samples_f = length_m * resolution_per_m;
    // A count beyond any memory (or an overflowed length) is refused.
    if samples_f.is_nan() || samples_f >= MAX_SAMPLES_PER_SEGMENT as f64 {
        return Err(SocialForceError::SegmentTooLong {
            segment: segment_index,
            length_m,
            resolution_per_m,
        });
    }
    // `int()` truncates.
    if samples_f < 1.0 {
        return Err(SocialForceError::ShortSegment {
            segment: segment_index,
            length_m,
            resolution_per_m,
        });
    }
    let samples = samples_f as usize;
    out.reserve(samples);
    let xs = Linspace::new(s.x, e.x, samples);
    let ys = Linspace::new(s.y, e.y, samples);
    for k in 0..samples {
        out.push(Vec2::new(xs.at(k), ys.at(k)));
    }
    Ok(())
}

/// numpy 2's `linspace(start, stop, num)` (endpoint included), one value at a time.
struct Linspace {
    start: f64,
    stop: f64,
    num: usize,
    div: f64,
    delta: f64,
    step: f64,
}

impl Linspace {
    fn new(start: f64, stop: f64, num: usize) -> Self {
        let div = num.saturating_sub(1) as f64;
        let delta = stop - start;
        Self {
            start,
            stop,
            num,
            div,
            delta,
            step: delta / div,
        }
    }

    fn at(&self, k: usize) -> f64 {
        if self.num == 1 {
            // div = 0: numpy multiplies by delta instead of a NaN step.
            return k as f64 * self.delta + self.start;
        }
        if k + 1 == self.num {
            return self.stop;
        }
        let y = if self.step == 0.0 {
            (k as f64 / self.div) * self.delta
        } else {
            k as f64 * self.step
        };
        y + self.start
    }
}

/// `GroupCoherenceForceAlt`'s strength for a group of `size`: `(tanh(−(size−1)/2) + 1)/2` (psf
/// means a distance in place of the 0, but its helper reads empty columns). Sizes 2–4 are
/// numpy's tanh values as pysocialforce got them (`c₄` differs from glibc's by one ulp); other
/// sizes use the system `tanh`.
pub fn group_coherence_factor(size: usize) -> f64 {
    match size {
        0 | 1 => 0.5,
        2 => 0.268_941_421_369_995_1,
        3 => 0.119_202_922_022_117_57,
        4 => 0.047_425_873_177_566_746,
        _ => ((-((size - 1) as f64 / 2.0)).tanh() + 1.0) / 2.0,
    }
}

/// |(x, y)| as pysocialforce's numba helpers get it: `np.linalg.norm` of a 2-vector compiles to
/// BLAS `dnrm2`, which OpenBLAS runs on the x87 FPU (64-bit significand), giving
/// `rnd53(rnd64(sqrt(rnd64(rnd64(x²) + rnd64(y²)))))`. It differs from `sqrt(x·x + y·y)` by one
/// ulp in about a sixth of cases, enough for crowded scenes to drift apart. Emulated exactly in
/// integers. NaN in, NaN out; otherwise an infinite component gives infinity.
pub fn psf_norm(x: f64, y: f64) -> f64 {
    if x.is_nan() || y.is_nan() {
        return f64::NAN;
    }
    if x.is_infinite() || y.is_infinite() {
        return f64::INFINITY;
    }
    let sum = match (square64(x), square64(y)) {
        (None, None) => return 0.0,
        (Some(a), None) | (None, Some(a)) => a,
        (Some(a), Some(b)) => add64(a, b),
    };
    let root = sqrt64(sum);
    let (m, e) = round_sig(root.0 as u128, root.1, 53, false);
    to_f64(m as u64, e)
}

/// A positive extended value `m · 2^e`, `m` normalised to exactly 64 bits.
type Ext = (u64, i32);

/// The significand and exponent of |v| (`|v| = m · 2^e`), or `None` for ±0.
fn decompose(v: f64) -> Option<(u64, i32)> {
    let bits = v.to_bits() & !(1u64 << 63);
    if bits == 0 {
        return None;
    }
    let biased = (bits >> 52) as i32;
    let frac = bits & ((1u64 << 52) - 1);
    Some(if biased == 0 {
        (frac, -1074)
    } else {
        (frac | (1u64 << 52), biased - 1075)
    })
}

/// Rounds `m · 2^e` to `bits` significant bits, to nearest, ties to even; `sticky` says that
/// nonzero bits were already dropped below `m` (then a tie is above half).
fn round_sig(m: u128, e: i32, bits: u32, sticky: bool) -> (u128, i32) {
    let len = 128 - m.leading_zeros();
    if len <= bits {
        return (m, e);
    }
    let excess = len - bits;
    let rem = m & ((1u128 << excess) - 1);
    let half = 1u128 << (excess - 1);
    let mut q = m >> excess;
    let mut e = e + excess as i32;
    if rem > half || (rem == half && (sticky || q & 1 == 1)) {
        q += 1;
        if q >> bits != 0 {
            q >>= 1;
            e += 1;
        }
    }
    (q, e)
}

fn normalize64((m, e): (u128, i32)) -> Ext {
    let shift = m.leading_zeros().saturating_sub(64);
    ((m << shift) as u64, e - shift as i32)
}

/// x² rounded to 64 bits.
fn square64(x: f64) -> Option<Ext> {
    let (m, e) = decompose(x)?;
    let m = m as u128;
    Some(normalize64(round_sig(m * m, 2 * e, 64, false)))
}

/// a + b rounded to 64 bits (both positive, normalised).
fn add64(a: Ext, b: Ext) -> Ext {
    let (big, small) = if a.1 >= b.1 { (a, b) } else { (b, a) };
    let d = (big.1 - small.1) as u32;
    let hi = (big.0 as u128) << 62;
    let (lo, sticky) = if d <= 62 {
        ((small.0 as u128) << (62 - d), false)
    } else {
        let shift = d - 62;
        if shift >= 64 {
            (0, true)
        } else {
            let s = small.0 as u128;
            (s >> shift, s & ((1u128 << shift) - 1) != 0)
        }
    };
    normalize64(round_sig(hi + lo, big.1 - 62, 64, sticky))
}

/// sqrt(a) rounded to 64 bits, digit by digit (no big integers: the remainder stays small).
fn sqrt64((m, e): Ext) -> Ext {
    // Even exponent: the radicand r < 2^65 with r · 2^e2 = a.
    let (r, e2) = if e % 2 != 0 {
        ((m as u128) << 1, e - 1)
    } else {
        (m as u128, e)
    };
    // Root of r · 4^EXTRA: at least 66 bits (64 + guard bits), the rest goes into the sticky bit.
    const R_PAIRS: u32 = 33;
    const EXTRA: u32 = 35;
    let (mut rem, mut root) = (0u128, 0u128);
    for p in (0..R_PAIRS + EXTRA).rev() {
        let pair = if p >= EXTRA {
            (r >> (2 * (p - EXTRA))) & 3
        } else {
            0
        };
        rem = (rem << 2) | pair;
        let trial = (root << 2) | 1;
        root <<= 1;
        if rem >= trial {
            rem -= trial;
            root |= 1;
        }
    }
    normalize64(round_sig(root, e2 / 2 - EXTRA as i32, 64, rem != 0))
}

/// `m · 2^e` (m at most 53 bits) as an f64: exact unless it overflows (infinity) or falls in the
/// subnormal range (rounded twice there; no 2-vector norm of this model gets near it).
fn to_f64(m: u64, e: i32) -> f64 {
    if m == 0 {
        return 0.0;
    }
    let len = 64 - m.leading_zeros() as i32;
    let lead = e + len - 1;
    if lead > 1023 {
        return f64::INFINITY;
    }
    if lead >= -1022 && len == 53 {
        let biased = (lead + 1023) as u64;
        return f64::from_bits((biased << 52) | (m & ((1u64 << 52) - 1)));
    }
    // Small or short: scale in two exact steps where possible.
    let half = e / 2;
    (m as f64) * 2f64.powi(half) * 2f64.powi(e - half)
}

/// (u/|u|, |u|) with psf's `normalize`: the unit vector is (0, 0) when the norm is 0.
fn unit(x: f64, y: f64) -> (f64, f64, f64) {
    let n = psf_norm(x, y);
    if n == 0.0 {
        (0.0, 0.0, n)
    } else {
        (x / n, y / n, n)
    }
}

/// numpy's `sign`: ±1, 0 for either zero, NaN for NaN.
fn np_sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else if x == 0.0 {
        0.0
    } else {
        x
    }
}

/// numpy's `minimum` (NaN propagates).
fn np_minimum(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if b < a {
        b
    } else {
        a
    }
}

/// A left-to-right sum that starts from its first term, as numpy's reductions do (so the sign
/// of a zero total is psf's).
#[derive(Clone, Copy)]
struct Sum(Option<(f64, f64)>);

impl Sum {
    fn add(&mut self, x: f64, y: f64) {
        self.0 = Some(match self.0 {
            None => (x, y),
            Some((a, b)) => (a + x, b + y),
        });
    }

    fn or_zero(self) -> (f64, f64) {
        self.0.unwrap_or((0.0, 0.0))
    }
}

/// The social force model: people, sampled obstacles, groups and psf's `step`.
#[derive(Debug, Clone)]
pub struct SocialForceSim {
    params: SocialForceParams,
    peds: Vec<Pedestrian>,
    initial_speeds_mps: Vec<f64>,
    max_speeds_mps: Vec<f64>,
    taus_s: Vec<f64>,
    obstacle_points: Vec<Vec2>,
    groups: Vec<Vec<usize>>,
    /// Scratch: the summed force, the three group forces, the next (position, velocity).
    forces: Vec<Vec2>,
    group_forces: [Vec<Vec2>; 3],
    next: Vec<(Vec2, Vec2)>,
}

impl SocialForceSim {
    /// psf's `Simulator(state, groups, obstacles)`: the max speeds come from these initial
    /// velocities for good, every segment is sampled as `EnvState` does, and the tau column is
    /// `params.scene.tau_s`. With `enable_group` off the groups are kept but exert nothing.
    pub fn new(
        params: SocialForceParams,
        peds: &[Pedestrian],
        obstacles: &[Segment],
        groups: &[Vec<usize>],
    ) -> Result<Self, SocialForceError> {
        params.validate()?;
        if peds.is_empty() {
            return Err(SocialForceError::NoAgents);
        }
        for (agent, p) in peds.iter().enumerate() {
            check_finite(agent, "position", p.position)?;
            check_finite(agent, "velocity", p.velocity)?;
            check_finite(agent, "goal", p.goal)?;
        }
        let n = peds.len();
        for (g, members) in groups.iter().enumerate() {
            for (k, &member) in members.iter().enumerate() {
                if member >= n {
                    return Err(SocialForceError::GroupMemberOutOfRange {
                        group: g,
                        member,
                        n_agents: n,
                    });
                }
                if members[..k].contains(&member) {
                    return Err(SocialForceError::DuplicateGroupMember { group: g, member });
                }
            }
        }
        let mut obstacle_points = Vec::new();
        for (j, seg) in obstacles.iter().enumerate() {
            sample_segment(seg, params.scene.resolution_per_m, j, &mut obstacle_points)?;
        }
        let initial_speeds_mps: Vec<f64> = peds
            .iter()
            .map(|p| psf_norm(p.velocity.x, p.velocity.y))
            .collect();
        let max_speeds_mps = initial_speeds_mps
            .iter()
            .map(|s| params.scene.max_speed_multiplier * s)
            .collect();
        Ok(Self {
            params,
            peds: peds.to_vec(),
            initial_speeds_mps,
            max_speeds_mps,
            taus_s: vec![params.scene.tau_s; n],
            obstacle_points,
            groups: groups.to_vec(),
            forces: vec![Vec2::zeros(); n],
            group_forces: [
                vec![Vec2::zeros(); n],
                vec![Vec2::zeros(); n],
                vec![Vec2::zeros(); n],
            ],
            next: vec![(Vec2::zeros(), Vec2::zeros()); n],
        })
    }

    pub fn params(&self) -> &SocialForceParams {
        &self.params
    }

    /// The people now (goals unchanged since `new`).
    pub fn pedestrians(&self) -> &[Pedestrian] {
        &self.peds
    }

    pub fn len(&self) -> usize {
        self.peds.len()
    }

    pub fn is_empty(&self) -> bool {
        self.peds.is_empty()
    }

    /// |initial velocity| per agent (psf's `initial_speeds`, x87 norm).
    pub fn initial_speeds_mps(&self) -> &[f64] {
        &self.initial_speeds_mps
    }

    /// Desired speed = speed cap per agent: `max_speed_multiplier · initial speed`.
    pub fn max_speeds_mps(&self) -> &[f64] {
        &self.max_speeds_mps
    }

    /// psf's tau column (inert).
    pub fn taus_s(&self) -> &[f64] {
        &self.taus_s
    }

    /// Every sampled obstacle point, segment by segment.
    pub fn obstacle_points(&self) -> &[Vec2] {
        &self.obstacle_points
    }

    pub fn groups(&self) -> &[Vec<usize>] {
        &self.groups
    }

    /// Replaces every position and velocity (goals, max speeds and groups stay): for replaying a
    /// recorded state, or for a caller that moves people itself.
    pub fn set_kinematics(
        &mut self,
        positions: &[Vec2],
        velocities: &[Vec2],
    ) -> Result<(), SocialForceError> {
        let n = self.peds.len();
        for (what, got) in [
            ("positions", positions.len()),
            ("velocities", velocities.len()),
        ] {
            if got != n {
                return Err(SocialForceError::LengthMismatch {
                    what,
                    expected: n,
                    got,
                });
            }
        }
        for (agent, (p, v)) in positions.iter().zip(velocities).enumerate() {
            check_finite(agent, "position", *p)?;
            check_finite(agent, "velocity", *v)?;
        }
        for (ped, (p, v)) in self.peds.iter_mut().zip(positions.iter().zip(velocities)) {
            ped.position = *p;
            ped.velocity = *v;
        }
        Ok(())
    }

    /// The summed force on every agent in the current state (psf's `compute_forces`), in m/s².
    pub fn compute_forces(&mut self) -> &[Vec2] {
        let n = self.peds.len();
        let group = self.params.scene.enable_group;
        if group {
            self.group_terms();
        }
        for i in 0..n {
            let me = &self.peds[i];
            let others = self
                .peds
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, o)| (o.position, o.velocity));
            let mut f = agent_force(
                &self.params,
                me.position,
                me.velocity,
                me.goal,
                self.max_speeds_mps[i],
                others,
                &self.obstacle_points,
            );
            if group {
                for g in &self.group_forces {
                    f.x += g[i].x;
                    f.y += g[i].y;
                }
            }
            self.forces[i] = f;
        }
        &self.forces
    }

    /// One `Simulator.step(1)`: forces from the current state, then for every agent
    /// `v* = cap(v + Δt·F)`, `v* = 0` if it started within the arrive radius of its goal,
    /// `p += v*·Δt`, `v = v*`. On a non-finite result the state is left unchanged.
    pub fn step(&mut self) -> Result<(), SocialForceError> {
        self.compute_forces();
        let dt = self.params.scene.step_width_s;
        for (i, ped) in self.peds.iter().enumerate() {
            let next_v = step_velocity(
                &self.params.scene,
                ped.position,
                ped.velocity,
                ped.goal,
                self.max_speeds_mps[i],
                self.forces[i],
            );
            let p = ped.position;
            let next_p = Vec2::new(p.x + next_v.x * dt, p.y + next_v.y * dt);
            if !(next_v.x.is_finite() && next_v.y.is_finite()) {
                return Err(SocialForceError::NonFiniteStep {
                    agent: i,
                    what: "velocity",
                });
            }
            if !(next_p.x.is_finite() && next_p.y.is_finite()) {
                return Err(SocialForceError::NonFiniteStep {
                    agent: i,
                    what: "position",
                });
            }
            self.next[i] = (next_p, next_v);
        }
        for (ped, (p, v)) in self.peds.iter_mut().zip(&self.next) {
            ped.position = *p;
            ped.velocity = *v;
        }
        Ok(())
    }

    /// The three group forces into `group_forces` (coherence, repulsion, gaze), each summed over
    /// the groups from zero and then scaled by its factor.
    fn group_terms(&mut self) {
        for g in &mut self.group_forces {
            g.iter_mut().for_each(|f| *f = Vec2::zeros());
        }
        let peds = &self.peds;
        let pos = |i: usize| peds[i].position;
        let [coh, rep, gaze] = &mut self.group_forces;
        let rep_threshold = self.params.group_repulsive_force.threshold_m;
        for members in &self.groups {
            let size = members.len();
            if size == 0 {
                continue;
            }
            // Coherence: (com − p_m)·c_size.
            let c = group_coherence_factor(size);
            let (mut cx, mut cy) = (0.0, 0.0);
            for &m in members {
                cx += pos(m).x;
                cy += pos(m).y;
            }
            let (cx, cy) = (cx / size as f64, cy / size as f64);
            for &m in members {
                coh[m].x += (cx - pos(m).x) * c;
                coh[m].y += (cy - pos(m).y) * c;
            }
            // Repulsion: Σ_j (p_i − p_j) over members closer than the threshold.
            for &i in members {
                let mut sum = Sum(None);
                for &j in members {
                    if j == i {
                        continue;
                    }
                    let (rx, ry) = (pos(i).x - pos(j).x, pos(i).y - pos(j).y);
                    if psf_norm(rx, ry) > rep_threshold {
                        sum.add(0.0, 0.0);
                    } else {
                        sum.add(rx, ry);
                    }
                }
                let (x, y) = sum.or_zero();
                rep[i].x += x;
                rep[i].y += y;
            }
            // Gaze: ((|c|·(d·ĉ))/dist)·d, c = mean of the others − p_i, d = goal direction.
            if size < 2 {
                continue;
            }
            for &i in members {
                let me = &peds[i];
                let (dx, dy, dist) = unit(me.goal.x - me.position.x, me.goal.y - me.position.y);
                let (mut ox, mut oy) = (0.0, 0.0);
                for &j in members {
                    if j != i {
                        ox += pos(j).x;
                        oy += pos(j).y;
                    }
                }
                let others = (size - 1) as f64;
                let (hx, hy, c_len) =
                    unit(ox / others - me.position.x, oy / others - me.position.y);
                let prod = dx * hx + dy * hy;
                let k = (c_len * prod) / dist;
                gaze[i].x += k * dx;
                gaze[i].y += k * dy;
            }
        }
        let factors = [
            self.params.group_coherence_force_alt.factor,
            self.params.group_repulsive_force.factor,
            self.params.group_gaze_force_alt.factor,
        ];
        for (g, factor) in self.group_forces.iter_mut().zip(factors) {
            g.iter_mut().for_each(|f| *f *= factor);
        }
    }
}

/// The force psf's `compute_forces` puts on one agent, groups left out: `DesiredForce` toward
/// `goal` at `speed_mps` (psf's max speed), plus `SocialForce` from `others` (each as
/// (position, velocity), summed in the order given), plus `ObstacleForce` from
/// `obstacle_points`, in m/s². [`SocialForceSim`] sums exactly this (then the group forces), so
/// a caller that keeps its own agents (fsrl's environment, `sim::env`) steps the same model.
pub fn agent_force(
    params: &SocialForceParams,
    position: Vec2,
    velocity: Vec2,
    goal: Vec2,
    speed_mps: f64,
    others: impl IntoIterator<Item = (Vec2, Vec2)>,
    obstacle_points: &[Vec2],
) -> Vec2 {
    // Python's `sum` starts from the integer 0.
    let (mut fx, mut fy) =
        desired_force(&params.desired_force, position, velocity, goal, speed_mps);
    fx += 0.0;
    fy += 0.0;
    let (sx, sy) = social_term(&params.social_force, position, velocity, others);
    fx += sx;
    fy += sy;
    let (ox, oy) = obstacle_term(params, position, obstacle_points);
    fx += ox;
    fy += oy;
    Vec2::new(fx, fy)
}

/// psf's `PedState.step` velocity for one agent: `v* = v + Δt·F` (Δt = `scene.step_width_s`)
/// capped at `max_speed_mps`, and 0 when the agent starts the step closer than
/// `scene.arrive_radius_m` to `goal`.
pub fn step_velocity(
    scene: &SceneParams,
    position: Vec2,
    velocity: Vec2,
    goal: Vec2,
    max_speed_mps: f64,
    force: Vec2,
) -> Vec2 {
    let dt = scene.step_width_s;
    let mut wx = velocity.x + dt * force.x;
    let mut wy = velocity.y + dt * force.y;
    // capped_velocity: plain double norm here.
    let speed = (wx * wx + wy * wy).sqrt();
    let factor = if speed == 0.0 {
        0.0
    } else {
        np_minimum(1.0, max_speed_mps / speed)
    };
    wx *= factor;
    wy *= factor;
    if psf_norm(goal.x - position.x, goal.y - position.y) < scene.arrive_radius_m {
        wx = 0.0;
        wy = 0.0;
    }
    Vec2::new(wx, wy)
}

/// `DesiredForce`: `(e·max_speed − v)/relaxation_time · factor` beyond the goal threshold,
/// `(−v)/relaxation_time · factor` within it.
fn desired_force(
    prm: &DesiredForceParams,
    position: Vec2,
    velocity: Vec2,
    goal: Vec2,
    speed_mps: f64,
) -> (f64, f64) {
    let (ex, ey, dist) = unit(goal.x - position.x, goal.y - position.y);
    let (fx, fy) = if dist > prm.goal_threshold_m {
        (ex * speed_mps - velocity.x, ey * speed_mps - velocity.y)
    } else {
        (-velocity.x, -velocity.y)
    };
    (
        (fx / prm.relaxation_time_s) * prm.factor,
        (fy / prm.relaxation_time_s) * prm.factor,
    )
}

/// `SocialForce` on the agent at (`position`, `velocity`) from `others` in the order given. θ is
/// not wrapped (psf).
fn social_term(
    prm: &SocialTermParams,
    position: Vec2,
    velocity: Vec2,
    others: impl IntoIterator<Item = (Vec2, Vec2)>,
) -> (f64, f64) {
    let mut sum = Sum(None);
    for (other_position, other_velocity) in others {
        let (ex, ey, dist) = unit(position.x - other_position.x, position.y - other_position.y);
        let dvx = -(velocity.x - other_velocity.x);
        let dvy = -(velocity.y - other_velocity.y);
        let (tx, ty, d_len) = unit(
            prm.lambda_importance * dvx + ex,
            prm.lambda_importance * dvy + ey,
        );
        let theta = ty.atan2(tx) - ey.atan2(ex);
        let b = prm.gamma * d_len;
        let base = -dist / b;
        let wv = (prm.n_prime * b) * theta;
        let wa = (prm.n * b) * theta;
        let a_v = (base - wv * wv).exp();
        let a_theta = -np_sign(theta) * (base - wa * wa).exp();
        // left normal of t: (t_y·(−1), t_x·1), both exact.
        let (nx, ny) = (-ty, tx);
        sum.add(a_v * tx + a_theta * nx, a_v * ty + a_theta * ny);
    }
    let (x, y) = sum.or_zero();
    (x * prm.factor, y * prm.factor)
}

/// `ObstacleForce`: `Σ unit(p − o)·exp(−s/σ)` over the sampled points o with
/// `s = |p − o| − agent_radius < threshold + agent_radius`, times the factor.
fn obstacle_term(params: &SocialForceParams, p: Vec2, obstacle_points: &[Vec2]) -> (f64, f64) {
    if obstacle_points.is_empty() {
        return (0.0, 0.0);
    }
    let prm = &params.obstacle_force;
    let radius = params.scene.agent_radius_m;
    let threshold = prm.threshold_m + radius;
    // A point that the plain norm puts surely beyond the threshold (`d < threshold_m + 2·radius`
    // fails) is skipped before psf's costly x87 norm: the two norms differ by an ulp, far less
    // than the margin, so the sum is the same, bit for bit.
    let reach = (prm.threshold_m + 2.0 * radius).abs() * (1.0 + 1e-9);
    let reach_sq = reach * reach;
    let mut sum = Sum(None);
    for o in obstacle_points {
        let (dx, dy) = (p.x - o.x, p.y - o.y);
        if dx * dx + dy * dy > reach_sq {
            continue;
        }
        let (ex, ey, d) = unit(dx, dy);
        let s = d - radius;
        if s < threshold {
            let w = (-s / prm.sigma_m).exp();
            sum.add(ex * w, ey * w);
        }
    }
    // Every point beyond the threshold: psf leaves the row at +0.
    let (x, y) = sum.or_zero();
    (x * prm.factor, y * prm.factor)
}

fn check_finite(agent: usize, what: &'static str, v: Vec2) -> Result<(), SocialForceError> {
    if v.x.is_finite() && v.y.is_finite() {
        Ok(())
    } else {
        Err(SocialForceError::NonFiniteAgent { agent, what })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ped(px: f64, py: f64, vx: f64, vy: f64, gx: f64, gy: f64) -> Pedestrian {
        Pedestrian {
            position: Vec2::new(px, py),
            velocity: Vec2::new(vx, vy),
            goal: Vec2::new(gx, gy),
        }
    }

    #[test]
    fn psf_norm_is_the_x87_norm_not_the_plain_one() {
        // testdata/sf_ref/circle_n05_s105: agent 1's initial velocity and psf's max speed.
        let (vx, vy) = (0.7774194646001996, 0.08768362457783625);
        assert_eq!(1.3 * psf_norm(vx, vy), 1.0170532714217293);
        assert_ne!(1.3 * (vx * vx + vy * vy).sqrt(), 1.0170532714217293);
    }

    #[test]
    fn psf_norm_basics() {
        assert_eq!(psf_norm(3.0, 4.0), 5.0);
        assert_eq!(psf_norm(-3.0, 4.0), 5.0);
        assert_eq!(psf_norm(0.0, -0.0), 0.0);
        assert_eq!(psf_norm(0.0, -2.5), 2.5);
        assert_eq!(psf_norm(1e300, 1e300), 1e300 * std::f64::consts::SQRT_2);
        assert_eq!(psf_norm(f64::MAX, f64::MAX), f64::INFINITY);
        assert_eq!(psf_norm(f64::INFINITY, 1.0), f64::INFINITY);
        assert!(psf_norm(f64::NAN, f64::INFINITY).is_nan());
        assert_eq!(psf_norm(5e-324, 0.0), 5e-324);
        // Within one ulp of the plain norm, symmetric, and exact under scaling by 2^k.
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 * 20.0 - 10.0
        };
        let mut differ = 0;
        for _ in 0..20_000 {
            let (x, y) = (next(), next());
            let n = psf_norm(x, y);
            let plain = (x * x + y * y).sqrt();
            assert!(
                (n - plain).abs() <= plain * f64::EPSILON,
                "{x} {y}: {n} vs {plain}"
            );
            differ += usize::from(n != plain);
            assert_eq!(n, psf_norm(y, -x));
            assert_eq!(psf_norm(x * 1024.0, y * 1024.0), n * 1024.0);
        }
        // The README: about 17% of cases differ from the plain norm.
        assert!((2000..5000).contains(&differ), "{differ} of 20000 differ");
    }

    #[test]
    fn segments_are_sampled_like_numpy_linspace() {
        let mut pts = Vec::new();
        let wall = Segment::from_psf([-10.0, 10.0, 1.5, 1.5]);
        sample_segment(&wall, 10.0, 0, &mut pts).unwrap();
        assert_eq!(pts.len(), 200);
        assert_eq!(pts[0], Vec2::new(-10.0, 1.5));
        assert_eq!(pts[199], Vec2::new(10.0, 1.5));
        assert_eq!(pts[1].x, 20.0 / 199.0 - 10.0);
        pts.clear();
        let short = Segment::from_psf([0.0, 0.15, 0.0, 0.0]);
        sample_segment(&short, 10.0, 0, &mut pts).unwrap();
        assert_eq!(pts, vec![Vec2::new(0.0, 0.0)]);
        let tiny = Segment::from_psf([0.0, 0.05, 0.0, 0.0]);
        assert!(matches!(
            sample_segment(&tiny, 10.0, 3, &mut pts),
            Err(SocialForceError::ShortSegment { segment: 3, .. })
        ));
        let huge = Segment::from_psf([-1e308, 1e308, 0.0, 0.0]);
        assert!(matches!(
            sample_segment(&huge, 10.0, 4, &mut pts),
            Err(SocialForceError::SegmentTooLong { segment: 4, .. })
        ));
    }

    #[test]
    fn bad_input_is_an_error() {
        let p = SocialForceParams::default();
        let a = ped(0.0, 0.0, 1.0, 0.0, 5.0, 0.0);
        let b = ped(2.0, 0.0, -1.0, 0.0, -5.0, 0.0);
        assert_eq!(
            SocialForceSim::new(p, &[], &[], &[]).unwrap_err(),
            SocialForceError::NoAgents
        );
        let nan = ped(f64::NAN, 0.0, 1.0, 0.0, 5.0, 0.0);
        assert!(matches!(
            SocialForceSim::new(p, &[a, nan], &[], &[]),
            Err(SocialForceError::NonFiniteAgent {
                agent: 1,
                what: "position"
            })
        ));
        assert!(matches!(
            SocialForceSim::new(p, &[a, b], &[], &[vec![0, 2]]),
            Err(SocialForceError::GroupMemberOutOfRange { member: 2, .. })
        ));
        assert!(matches!(
            SocialForceSim::new(p, &[a, b], &[], &[vec![1, 1]]),
            Err(SocialForceError::DuplicateGroupMember { member: 1, .. })
        ));
        let mut bad = p;
        bad.scene.step_width_s = 0.0;
        assert!(matches!(
            SocialForceSim::new(bad, &[a, b], &[], &[]),
            Err(SocialForceError::BadParam {
                name: "scene.step_width",
                ..
            })
        ));
        let mut bad = p;
        bad.social_force.gamma = f64::NAN;
        assert!(matches!(
            SocialForceSim::new(bad, &[a, b], &[], &[]),
            Err(SocialForceError::BadParam {
                name: "social_force.gamma",
                ..
            })
        ));
        let mut sim = SocialForceSim::new(p, &[a, b], &[], &[]).unwrap();
        assert!(matches!(
            sim.set_kinematics(&[Vec2::zeros()], &[Vec2::zeros(), Vec2::zeros()]),
            Err(SocialForceError::LengthMismatch {
                what: "positions",
                expected: 2,
                got: 1
            })
        ));
        assert!(matches!(
            sim.set_kinematics(
                &[Vec2::zeros(); 2],
                &[Vec2::zeros(), Vec2::new(0.0, f64::INFINITY)]
            ),
            Err(SocialForceError::NonFiniteAgent {
                agent: 1,
                what: "velocity"
            })
        ));
    }

    #[test]
    fn coincident_agents_with_one_velocity_are_an_error_and_leave_the_state() {
        // psf divides 0 by B = 0 here and carries NaN on.
        let a = ped(1.0, 1.0, 0.5, 0.0, 5.0, 1.0);
        let mut sim = SocialForceSim::new(SocialForceParams::default(), &[a, a], &[], &[]).unwrap();
        assert!(matches!(
            sim.step(),
            Err(SocialForceError::NonFiniteStep { agent: 0, .. })
        ));
        assert_eq!(sim.pedestrians(), &[a, a]);
    }

    #[test]
    fn psf_quirks_resting_starts_and_arrival() {
        // An agent that starts at rest has desired speed 0 and never moves; one that starts
        // within 0.5 m of its goal is frozen at once.
        let resting = ped(0.0, 0.0, 0.0, 0.0, 10.0, 0.0);
        let near = ped(0.0, 5.0, 0.3, 0.0, 0.4, 5.0);
        let mover = ped(0.0, -5.0, 1.0, 0.0, 10.0, -5.0);
        let p = SocialForceParams::default();
        let mut sim = SocialForceSim::new(p, &[resting, near, mover], &[], &[]).unwrap();
        assert_eq!(sim.max_speeds_mps()[2], 1.3);
        for _ in 0..20 {
            sim.step().unwrap();
        }
        let peds = sim.pedestrians();
        // Its cap is 0: whatever the forces, the capped velocity is 0.
        assert_eq!(peds[0].position, resting.position);
        assert_eq!(peds[1].position, near.position);
        assert_eq!(peds[1].velocity, Vec2::zeros());
        // The mover walks at its cap, 1.3 × its initial speed, 0.4 s a step.
        assert!(
            peds[2].position.x > 10.0 - 0.5 - 1.3 * 0.4,
            "{:?}",
            peds[2].position
        );
        assert!(peds[2].velocity.norm() <= 1.3 + 1e-12);
    }

    #[test]
    fn coherence_factors_are_psf_constants() {
        assert_eq!(group_coherence_factor(2), 0.2689414213699951);
        assert_eq!(group_coherence_factor(1), 0.5);
        let c5 = group_coherence_factor(5);
        assert!(
            (c5 - ((-2f64).tanh() + 1.0) / 2.0).abs() < 1e-16 && c5 < group_coherence_factor(4)
        );
    }
}
