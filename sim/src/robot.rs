//! The robot: unicycle kinematics and the discrete action set (SPEC §2).

use crate::config::ActionConfig;
use crate::geom::{heading, wrap_angle, Vec2};

/// A unicycle action: a heading change applied at the start of the step, then straight motion.
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
    /// World-frame velocity the robot holds during a step with action `a`.
    pub fn commanded_velocity(&self, a: Action) -> Vec2 {
        heading(self.heading_rad + a.rotation_rad) * a.speed_mps
    }

    /// The state after applying `a` for `dt_s`: θ' = θ + Δθ, p' = p + v·dt·(cos θ', sin θ').
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
}

impl ActionSet {
    /// Builds the set for a robot of preferred speed `v_pref_mps`. Speeds are exponential,
    /// s_i = (e^{(i+1)/n} − 1)/(e − 1)·v_pref; rotations evenly spaced over
    /// [−max, max] with both ends included (a single rotation is 0).
    pub fn new(cfg: &ActionConfig, v_pref_mps: f64) -> Self {
        let n = cfg.speeds.max(1);
        let speeds: Vec<f64> = (0..n)
            .map(|i| {
                (((i + 1) as f64 / n as f64).exp() - 1.0) / (std::f64::consts::E - 1.0) * v_pref_mps
            })
            .collect();
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
        let mut actions = Vec::with_capacity(1 + n * m);
        actions.push(Action::STOP);
        for &rotation_rad in &rotations {
            for &speed_mps in &speeds {
                actions.push(Action {
                    speed_mps,
                    rotation_rad,
                });
            }
        }
        Self { actions, speeds: n }
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
            let v = heading(heading_rad + a.rotation_rad) * a.speed_mps;
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
