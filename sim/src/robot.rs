//! The robot: unicycle and holonomic kinematics and the discrete action sets (SPEC §2,
//! CrowdNav's holonomic baselines).

use crate::config::{ActionConfig, Kinematics, SimConfig};
use crate::geom::{heading, wrap_angle, Vec2};

/// A discrete action: a speed and an angle whose meaning depends on the robot's kinematics.
///
/// - Unicycle: `rotation_rad` is a heading change applied at the start of the step, then the
///   robot drives straight at `speed_mps`.
/// - Holonomic: `rotation_rad` is the absolute world-frame direction of the velocity
///   (CrowdNav's `ActionXY(s·cos φ, s·sin φ)`); the heading does not change.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Action {
    pub speed_mps: f64,
    pub rotation_rad: f64,
}

impl Action {
    pub const STOP: Action = Action {
        speed_mps: 0.0,
        rotation_rad: 0.0,
    };
}

/// The robot's full state (what the robot knows about itself).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotState {
    pub position: Vec2,
    pub velocity: Vec2,
    pub goal: Vec2,
    /// Heading, kept in [−π, π).
    pub heading_rad: f64,
    pub radius_m: f64,
    pub v_pref_mps: f64,
}

impl RobotState {
    /// World-frame velocity the unicycle robot holds during a step with action `a`.
    pub fn commanded_velocity(&self, a: Action) -> Vec2 {
        heading(self.heading_rad + a.rotation_rad) * a.speed_mps
    }

    /// World-frame velocity during a step with action `a` under `kinematics`.
    pub fn velocity_for(&self, kinematics: Kinematics, a: Action) -> Vec2 {
        match kinematics {
            Kinematics::Unicycle => self.commanded_velocity(a),
            Kinematics::Holonomic => heading(a.rotation_rad) * a.speed_mps,
        }
    }

    /// The state after applying `a` for `dt_s` under `kinematics`.
    pub fn propagate_with(&self, kinematics: Kinematics, a: Action, dt_s: f64) -> RobotState {
        match kinematics {
            Kinematics::Unicycle => self.propagate(a, dt_s),
            Kinematics::Holonomic => {
                self.move_with_velocity(heading(a.rotation_rad) * a.speed_mps, dt_s)
            }
        }
    }

    /// Holonomic motion: p' = p + v·dt, velocity v, heading unchanged.
    pub fn move_with_velocity(&self, velocity: Vec2, dt_s: f64) -> RobotState {
        RobotState {
            position: self.position + velocity * dt_s,
            velocity,
            ..*self
        }
    }

    /// The unicycle state after applying `a` for `dt_s`: θ' = θ + Δθ, p' = p + v·dt·(cos θ', sin θ').
    pub fn propagate(&self, a: Action, dt_s: f64) -> RobotState {
        let velocity = self.commanded_velocity(a);
        RobotState {
            position: self.position + velocity * dt_s,
            velocity,
            heading_rad: wrap_angle(self.heading_rad + a.rotation_rad),
            ..*self
        }
    }

    pub fn distance_to_goal(&self) -> f64 {
        (self.goal - self.position).norm()
    }
}

/// The discrete action set: index 0 is stop, then rotation-major, speed-minor.
#[derive(Debug, Clone, PartialEq)]
pub struct ActionSet {
    actions: Vec<Action>,
    speeds: usize,
    kinematics: Kinematics,
}

/// Exponential speeds s_i = (e^{(i+1)/n} − 1)/(e − 1)·v_pref, i = 0..n.
fn exponential_speeds(n: usize, v_pref_mps: f64) -> Vec<f64> {
    (0..n)
        .map(|i| {
            (((i + 1) as f64 / n as f64).exp() - 1.0) / (std::f64::consts::E - 1.0) * v_pref_mps
        })
        .collect()
}

fn rotation_major(rotations: &[f64], speeds: &[f64]) -> Vec<Action> {
    let mut actions = Vec::with_capacity(1 + rotations.len() * speeds.len());
    actions.push(Action::STOP);
    for &rotation_rad in rotations {
        for &speed_mps in speeds {
            actions.push(Action {
                speed_mps,
                rotation_rad,
            });
        }
    }
    actions
}

impl ActionSet {
    /// The set of the robot `cfg` describes: [`ActionSet::new`] for the unicycle robot,
    /// [`ActionSet::holonomic`] for the holonomic one.
    pub fn for_config(cfg: &SimConfig) -> Self {
        match cfg.robot.kinematics {
            Kinematics::Unicycle => Self::new(&cfg.actions, cfg.robot.v_pref_mps),
            Kinematics::Holonomic => Self::holonomic(
                cfg.actions.speeds,
                cfg.robot.holonomic_headings,
                cfg.robot.v_pref_mps,
            ),
        }
    }

    /// CrowdNav's holonomic set: stop, then `headings` world-frame directions k·2π/headings
    /// (k = 0..headings, as `np.linspace(0, 2π, headings, endpoint=False)`) × `speeds`
    /// exponential speeds, rotation-major. With 5 speeds and 16 headings: 81 actions.
    pub fn holonomic(speeds: usize, headings: usize, v_pref_mps: f64) -> Self {
        let n = speeds.max(1);
        let m = headings.max(1);
        let step = std::f64::consts::TAU / m as f64;
        let rotations: Vec<f64> = (0..m).map(|k| k as f64 * step).collect();
        Self {
            actions: rotation_major(&rotations, &exponential_speeds(n, v_pref_mps)),
            speeds: n,
            kinematics: Kinematics::Holonomic,
        }
    }

    /// Builds the unicycle set for a robot of preferred speed `v_pref_mps`. Speeds are
    /// exponential, s_i = (e^{(i+1)/n} − 1)/(e − 1)·v_pref; rotations evenly spaced over
    /// [−max, max] with both ends included (a single rotation is 0).
    pub fn new(cfg: &ActionConfig, v_pref_mps: f64) -> Self {
        let n = cfg.speeds.max(1);
        let speeds = exponential_speeds(n, v_pref_mps);
        let m = cfg.rotations.max(1);
        let rotations: Vec<f64> = if m == 1 {
            vec![0.0]
        } else {
            (0..m)
                .map(|k| {
                    -cfg.max_rotation_rad + 2.0 * cfg.max_rotation_rad * k as f64 / (m - 1) as f64
                })
                .collect()
        };
        Self {
            actions: rotation_major(&rotations, &speeds),
            speeds: n,
            kinematics: Kinematics::Unicycle,
        }
    }

    /// The kinematics the actions are meant for.
    pub fn kinematics(&self) -> Kinematics {
        self.kinematics
    }

    /// World-frame velocity of action `a` for a robot heading `heading_rad`.
    pub fn velocity(&self, heading_rad: f64, a: Action) -> Vec2 {
        match self.kinematics {
            Kinematics::Unicycle => heading(heading_rad + a.rotation_rad) * a.speed_mps,
            Kinematics::Holonomic => heading(a.rotation_rad) * a.speed_mps,
        }
    }

    pub fn len(&self) -> usize {
        self.actions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.actions.is_empty()
    }

    pub fn get(&self, index: usize) -> Option<Action> {
        self.actions.get(index).copied()
    }

    pub fn as_slice(&self) -> &[Action] {
        &self.actions
    }

    /// Number of speeds per rotation.
    pub fn speeds(&self) -> usize {
        self.speeds
    }

    /// The action whose world velocity (for a robot heading `heading_rad`) is closest to
    /// `desired`; ties go to the lower index.
    pub fn nearest(&self, heading_rad: f64, desired: Vec2) -> usize {
        let mut best = 0;
        let mut best_d = f64::INFINITY;
        for (i, a) in self.actions.iter().enumerate() {
            let v = self.velocity(heading_rad, *a);
            let d = (v - desired).norm_squared();
            if d < best_d {
                best_d = d;
                best = i;
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_paper_action_set_has_51_actions_in_spec_order() {
        let set = ActionSet::new(&ActionConfig::default(), 1.0);
        assert_eq!(set.len(), 51);
        assert_eq!(set.get(0), Some(Action::STOP));
        let expected = [0.128851, 0.286231, 0.478454, 0.713236, 1.0];
        for (i, e) in expected.iter().enumerate() {
            assert!((set.get(1 + i).unwrap().speed_mps - e).abs() < 1e-6);
        }
        let pi8 = std::f64::consts::FRAC_PI_8;
        // Rotation-major: indices 1..=5 share the first rotation −π/8; the last five +π/8.
        for i in 1..=5 {
            assert!((set.get(i).unwrap().rotation_rad + pi8).abs() < 1e-12);
        }
        for i in 46..=50 {
            assert!((set.get(i).unwrap().rotation_rad - pi8).abs() < 1e-12);
        }
        // 10 rotations evenly spaced: step π/36.
        let step = set.get(6).unwrap().rotation_rad - set.get(1).unwrap().rotation_rad;
        assert!((step - std::f64::consts::PI / 36.0).abs() < 1e-12);
        assert_eq!(set.get(51), None);
    }

    #[test]
    fn unicycle_rotates_then_moves() {
        let r = RobotState {
            position: Vec2::new(0.0, -4.0),
            velocity: Vec2::zeros(),
            goal: Vec2::new(0.0, 4.0),
            heading_rad: std::f64::consts::FRAC_PI_2,
            radius_m: 0.3,
            v_pref_mps: 1.0,
        };
        let a = Action {
            speed_mps: 1.0,
            rotation_rad: -std::f64::consts::FRAC_PI_2,
        };
        let n = r.propagate(a, 0.25);
        assert!((n.position - Vec2::new(0.25, -4.0)).norm() < 1e-12);
        assert!(n.heading_rad.abs() < 1e-12);
        assert!((n.velocity - Vec2::new(1.0, 0.0)).norm() < 1e-12);
    }

    #[test]
    fn crowdnav_holonomic_set_has_81_actions_in_its_order() {
        let set = ActionSet::holonomic(5, 16, 1.0);
        assert_eq!(set.len(), 81);
        assert_eq!(set.kinematics(), Kinematics::Holonomic);
        assert_eq!(set.get(0), Some(Action::STOP));
        let speeds = [0.128851, 0.286231, 0.478454, 0.713236, 1.0];
        for k in 0..16 {
            for (i, s) in speeds.iter().enumerate() {
                let a = set.get(1 + k * 5 + i).unwrap();
                assert!((a.speed_mps - s).abs() < 1e-6);
                assert_eq!(a.rotation_rad, k as f64 * (std::f64::consts::TAU / 16.0));
            }
        }
        // k·π/8, world frame: index 1 + 4·5 + 4 is full speed straight up whatever the heading.
        let up = set.get(25).unwrap();
        let v = set.velocity(0.3, up);
        assert!((v - Vec2::new(0.0, 1.0)).norm() < 1e-12);
        assert_eq!(set.nearest(-2.0, Vec2::new(0.0, 0.98)), 25);
        assert_eq!(set.nearest(1.0, Vec2::new(0.01, 0.0)), 0);
        let cfg = SimConfig {
            robot: crate::config::RobotConfig {
                kinematics: Kinematics::Holonomic,
                ..Default::default()
            },
            ..Default::default()
        };
        assert_eq!(ActionSet::for_config(&cfg), set);
    }

    #[test]
    fn holonomic_robot_moves_without_turning() {
        let r = RobotState {
            position: Vec2::new(0.0, -4.0),
            velocity: Vec2::zeros(),
            goal: Vec2::new(0.0, 4.0),
            heading_rad: std::f64::consts::FRAC_PI_2,
            radius_m: 0.3,
            v_pref_mps: 1.0,
        };
        let a = Action {
            speed_mps: 1.0,
            rotation_rad: 0.0,
        };
        let n = r.propagate_with(Kinematics::Holonomic, a, 0.25);
        assert_eq!(n.position, Vec2::new(0.25, -4.0));
        assert_eq!(n.velocity, Vec2::new(1.0, 0.0));
        assert_eq!(n.heading_rad, r.heading_rad);
        assert_eq!(
            r.velocity_for(Kinematics::Holonomic, a),
            Vec2::new(1.0, 0.0)
        );
        // Unicycle through the same entry point is the unicycle step, bit for bit.
        assert_eq!(
            r.propagate_with(Kinematics::Unicycle, a, 0.25),
            r.propagate(a, 0.25)
        );
        let v = Vec2::new(0.3, -0.2);
        let m = r.move_with_velocity(v, 0.25);
        assert_eq!(m.position, r.position + v * 0.25);
    }

    #[test]
    fn nearest_action_prefers_lower_index_on_ties() {
        let set = ActionSet::new(&ActionConfig::default(), 1.0);
        // Zero desired velocity: stop (index 0) is exact.
        assert_eq!(set.nearest(0.0, Vec2::zeros()), 0);
        // Straight ahead at full speed: the two rotations closest to 0 (±π/72) tie; lower index wins.
        let i = set.nearest(0.0, Vec2::new(1.0, 0.0));
        let a = set.get(i).unwrap();
        assert_eq!(a.speed_mps, 1.0);
        assert!(a.rotation_rad < 0.0 && a.rotation_rad.abs() < 0.05);
    }
}
