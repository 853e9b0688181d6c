//! The joint state (what the robot observes) and its featurisation into the robot-centric
//! 13-vectors of SPEC §4 / CrowdNav's `rotate()`.
//!
//! Frame: origin at the robot, x-axis toward its goal. Row layout:
//! `[d_g, v_pref, θ_rel, r, v_x, v_y | p_x, p_y, v_x, v_y, r_i, d_i, r_i + r]`, with the robot's
//! six features repeated in every row. θ_rel is wrapped to (−π, π].

use sim::{HumanState, RobotState, Vec2};

use crate::FEATURE_DIM;

/// What the robot observes of one human.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HumanObs {
    pub position: Vec2,
    pub velocity: Vec2,
    pub radius_m: f64,
}

impl HumanObs {
    /// A static obstacle point as the networks see it: an entity that never moves, of radius 0
    /// (people have a radius), so that walls need no change to the networks (issue 53).
    pub fn obstacle(position: Vec2) -> Self {
        Self {
            position,
            velocity: Vec2::zeros(),
            radius_m: 0.0,
        }
    }
}

impl From<&HumanState> for HumanObs {
    fn from(h: &HumanState) -> Self {
        Self {
            position: h.position,
            velocity: h.velocity,
            radius_m: h.radius_m,
        }
    }
}

/// Human order in the featurised rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HumanOrder {
    /// As given (SARL is permutation invariant).
    AsGiven,
    /// By decreasing distance to the robot, so the closest human comes last (LSTM-RL).
    FarthestFirst,
}

fn wrap_pi(a: f64) -> f64 {
    // (−π, π]
    let w = sim::geom::wrap_angle(a);
    if w == -std::f64::consts::PI {
        std::f64::consts::PI
    } else {
        w
    }
}

/// Appends the `N × 13` rows of the joint state (`robot`, `humans`) to `out`.
///
/// `order_buf` is scratch for sorting (kept by the caller so that no allocation happens).
pub fn featurize_into(
    robot: &RobotState,
    humans: &[HumanObs],
    order: HumanOrder,
    order_buf: &mut Vec<(f64, usize)>,
    out: &mut Vec<f32>,
) {
    let d = robot.goal - robot.position;
    let rot = d.y.atan2(d.x);
    let (sin, cos) = rot.sin_cos();
    let rotate = |v: Vec2| (v.x * cos + v.y * sin, v.y * cos - v.x * sin);
    let (vx, vy) = rotate(robot.velocity);
    let robot_row = [
        d.norm() as f32,
        robot.v_pref_mps as f32,
        wrap_pi(robot.heading_rad - rot) as f32,
        robot.radius_m as f32,
        vx as f32,
        vy as f32,
    ];
    order_buf.clear();
    order_buf.extend(
        humans
            .iter()
            .enumerate()
            .map(|(i, h)| ((h.position - robot.position).norm(), i)),
    );
    if order == HumanOrder::FarthestFirst {
        // Stable: equal distances keep their index order.
        order_buf.sort_by(|a, b| b.0.total_cmp(&a.0));
    }
    out.reserve(humans.len() * FEATURE_DIM);
    for &(dist, i) in order_buf.iter() {
        let h = &humans[i];
        let (px, py) = rotate(h.position - robot.position);
        let (hvx, hvy) = rotate(h.velocity);
        out.extend_from_slice(&robot_row);
        out.extend_from_slice(&[
            px as f32,
            py as f32,
            hvx as f32,
            hvy as f32,
            h.radius_m as f32,
            dist as f32,
            (h.radius_m + robot.radius_m) as f32,
        ]);
    }
}

/// The rows of one joint state as a new vector (`N × 13`).
pub fn featurize(robot: &RobotState, humans: &[HumanObs], order: HumanOrder) -> Vec<f32> {
    let mut out = Vec::with_capacity(humans.len() * FEATURE_DIM);
    featurize_into(robot, humans, order, &mut Vec::new(), &mut out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn robot() -> RobotState {
        RobotState {
            position: Vec2::new(0.0, -4.0),
            velocity: Vec2::new(0.0, 0.5),
            goal: Vec2::new(0.0, 4.0),
            heading_rad: std::f64::consts::FRAC_PI_2,
            radius_m: 0.3,
            v_pref_mps: 1.0,
        }
    }

    #[test]
    fn rows_follow_crowdnav_rotate() {
        // Goal straight up: rot = π/2, so world (x, y) becomes (y, −x).
        let humans = [HumanObs {
            position: Vec2::new(1.0, -2.0),
            velocity: Vec2::new(-1.0, 0.0),
            radius_m: 0.3,
        }];
        let f = featurize(&robot(), &humans, HumanOrder::AsGiven);
        let expected = [
            8.0,
            1.0,
            0.0,
            0.3,
            0.5,
            0.0, // robot: d_g, v_pref, θ_rel, r, v_x, v_y
            2.0,
            -1.0,
            0.0,
            1.0,
            0.3,
            5f32.sqrt(),
            0.6,
        ];
        assert_eq!(f.len(), 13);
        for (k, (a, b)) in f.iter().zip(expected).enumerate() {
            assert!((a - b).abs() < 1e-6, "feature {k}: {a} vs {b}");
        }
    }

    #[test]
    fn heading_relative_to_goal_is_wrapped() {
        let mut r = robot();
        r.heading_rad = -std::f64::consts::FRAC_PI_2 - 0.1; // facing away, a little left
        let f = featurize(
            &r,
            &[HumanObs {
                position: Vec2::new(3.0, 3.0),
                velocity: Vec2::zeros(),
                radius_m: 0.3,
            }],
            HumanOrder::AsGiven,
        );
        assert!(
            (f[2] as f64 - (std::f64::consts::PI - 0.1)).abs() < 1e-6,
            "{}",
            f[2]
        );
    }

    #[test]
    fn farthest_first_puts_the_closest_human_last() {
        let near = HumanObs {
            position: Vec2::new(0.0, -3.0),
            velocity: Vec2::zeros(),
            radius_m: 0.3,
        };
        let far = HumanObs {
            position: Vec2::new(0.0, 3.0),
            velocity: Vec2::zeros(),
            radius_m: 0.3,
        };
        let mid = HumanObs {
            position: Vec2::new(2.0, -4.0),
            velocity: Vec2::zeros(),
            radius_m: 0.3,
        };
        let f = featurize(&robot(), &[near, far, mid], HumanOrder::FarthestFirst);
        let dists: Vec<f32> = f.chunks(13).map(|r| r[11]).collect();
        assert_eq!(dists, vec![7.0, 2.0, 1.0]);
        let g = featurize(&robot(), &[near, far, mid], HumanOrder::AsGiven);
        let dists: Vec<f32> = g.chunks(13).map(|r| r[11]).collect();
        assert_eq!(dists, vec![1.0, 7.0, 2.0]);
    }
}
