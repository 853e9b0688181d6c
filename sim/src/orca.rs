//! ORCA (optimal reciprocal collision avoidance) with the semantics of the RVO2 library.
//!
//! This is a port of RVO2 v2.0.3's `Agent::computeNewVelocity`, static obstacles included
//! ([`crate::rvo::ObstacleSet`]), written on nalgebra in **float32** with RVO2's order of
//! operations, so that it reproduces RVO2's velocities bit for bit (checked against
//! `testdata/orca_ref` and `testdata/orca_ref_obstacles` by replaying whole runs). Neighbour
//! selection keeps the `max_neighbors` closest agents with squared centre distance strictly below
//! `neighbor_dist²`, sorted by distance, as RVO2's k-d tree query does (in index order, which is
//! the tree's order up to RVO2's leaf size of ten agents; [`crate::rvo::Simulator`] has the tree).
//! Obstacle lines come first and stay hard in the third linear program, as in RVO2.
//!
//! One extension over RVO2: per-pair **avoidance responsibility**. RVO2 always takes half of the
//! avoidance (reciprocal). Here an agent whose [`OrcaAgent::reciprocal`] flag is false (a standing
//! human that will not move aside) is avoided with full responsibility: the ORCA half-plane is
//! moved by the whole of `u` rather than `u/2`.
//!
//! No allocation happens per call once the solver's scratch buffers have grown to the crowd size.

use crate::geom::Vec2f;
use crate::obstacles::ObstacleSet;
use crate::rvo_math::{abs_sq, det, div, dot, normalize, Line, RVO_EPSILON};

/// Parameters shared by every agent of one simulation (RVO2's simulator defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrcaParams {
    /// Agents farther than this (centre distance) are not neighbours.
    pub neighbor_dist_m: f32,
    /// At most this many closest agents are considered.
    pub max_neighbors: usize,
    /// Time horizon of the velocity obstacles.
    pub time_horizon_s: f32,
    /// Simulation step, used for the already-overlapping case.
    pub time_step_s: f32,
    /// Time horizon of the obstacles' velocity obstacles (RVO2's `timeHorizonObst`); also sets
    /// the obstacle neighbour range, `time_horizon_obst_s · max_speed + radius`. Unused without
    /// obstacles.
    pub time_horizon_obst_s: f32,
}

/// One agent as ORCA sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrcaAgent {
    pub position: Vec2f,
    pub velocity: Vec2f,
    /// Velocity the agent would like to have (only read for the ego agent).
    pub pref_velocity: Vec2f,
    /// ORCA radius (the body radius plus any margin).
    pub radius_m: f32,
    /// Speed limit (only read for the ego agent).
    pub max_speed_mps: f32,
    /// Whether this agent takes its half of the avoidance. Others avoid a non-reciprocal agent
    /// with full responsibility.
    pub reciprocal: bool,
}

/// Reusable ORCA solver: holds scratch buffers so that a call does not allocate.
#[derive(Debug, Clone)]
pub struct Orca {
    params: OrcaParams,
    neighbors: Vec<(f32, usize)>,
    obstacle_neighbors: Vec<(f32, usize)>,
    lines: Vec<Line>,
    proj_lines: Vec<Line>,
}

impl Orca {
    pub fn new(params: OrcaParams) -> Self {
        Self {
            params,
            neighbors: Vec::with_capacity(params.max_neighbors + 1),
            obstacle_neighbors: Vec::new(),
            lines: Vec::with_capacity(params.max_neighbors),
            proj_lines: Vec::with_capacity(params.max_neighbors),
        }
    }

    pub fn params(&self) -> &OrcaParams {
        &self.params
    }

    /// The new velocity of `agents[ego]` given every agent in `agents` as a potential neighbour.
    pub fn new_velocity(&mut self, ego: usize, agents: &[OrcaAgent]) -> Vec2f {
        self.compute_neighbors(ego, agents);
        self.obstacle_neighbors.clear();
        self.solve(ego, agents, None)
    }

    /// The new velocity of `agents[ego]` among `agents` and the static obstacles of `obstacles`
    /// (RVO2's obstacle neighbours, then its agent neighbours).
    pub fn new_velocity_among(
        &mut self,
        ego: usize,
        agents: &[OrcaAgent],
        obstacles: &ObstacleSet,
    ) -> Vec2f {
        self.find_obstacle_neighbors(&agents[ego], obstacles);
        self.compute_neighbors(ego, agents);
        self.solve(ego, agents, Some(obstacles))
    }

    /// RVO2's `Agent::computeNeighbors` for obstacles: every obstacle edge within
    /// `time_horizon_obst · max_speed + radius`, in the obstacle tree's order, sorted by distance.
    pub(crate) fn find_obstacle_neighbors(&mut self, me: &OrcaAgent, obstacles: &ObstacleSet) {
        self.obstacle_neighbors.clear();
        let range = self.params.time_horizon_obst_s * me.max_speed_mps + me.radius_m;
        obstacles.neighbors(me.position, range * range, &mut self.obstacle_neighbors);
    }

    /// The agent neighbours' buffer, for a caller that finds them itself (RVO2's k-d tree).
    pub(crate) fn neighbors_mut(&mut self) -> &mut Vec<(f32, usize)> {
        &mut self.neighbors
    }

    /// RVO2's `Agent::computeNewVelocity` from the neighbours already found.
    pub(crate) fn solve(
        &mut self,
        ego: usize,
        agents: &[OrcaAgent],
        obstacles: Option<&ObstacleSet>,
    ) -> Vec2f {
        self.lines.clear();
        if let Some(set) = obstacles {
            for &(_, edge) in &self.obstacle_neighbors {
                let me = &agents[ego];
                set.push_line(
                    edge,
                    (me.position, me.velocity, me.radius_m),
                    self.params.time_horizon_obst_s,
                    &mut self.lines,
                );
            }
        }
        let num_obst_lines = self.lines.len();
        self.build_lines(ego, agents);
        let me = &agents[ego];
        let mut result = Vec2f::zeros();
        let line_fail = linear_program2(
            &self.lines,
            me.max_speed_mps,
            me.pref_velocity,
            false,
            &mut result,
        );
        if line_fail < self.lines.len() {
            linear_program3(
                &self.lines,
                num_obst_lines,
                line_fail,
                me.max_speed_mps,
                &mut result,
                &mut self.proj_lines,
            );
        }
        result
    }

    fn compute_neighbors(&mut self, ego: usize, agents: &[OrcaAgent]) {
        self.neighbors.clear();
        let max = self.params.max_neighbors;
        if max == 0 {
            return;
        }
        let mut range_sq = self.params.neighbor_dist_m * self.params.neighbor_dist_m;
        let me = agents[ego].position;
        for (j, other) in agents.iter().enumerate() {
            if j == ego {
                continue;
            }
            let dist_sq = abs_sq(me - other.position);
            if dist_sq < range_sq {
                if self.neighbors.len() < max {
                    self.neighbors.push((dist_sq, j));
                }
                let mut i = self.neighbors.len() - 1;
                while i != 0 && dist_sq < self.neighbors[i - 1].0 {
                    self.neighbors[i] = self.neighbors[i - 1];
                    i -= 1;
                }
                self.neighbors[i] = (dist_sq, j);
                if self.neighbors.len() == max {
                    range_sq = self.neighbors[max - 1].0;
                }
            }
        }
    }

    fn build_lines(&mut self, ego: usize, agents: &[OrcaAgent]) {
        let me = &agents[ego];
        let inv_time_horizon = 1.0f32 / self.params.time_horizon_s;
        for &(_, j) in &self.neighbors {
            let other = &agents[j];
            let relative_position = other.position - me.position;
            let relative_velocity = me.velocity - other.velocity;
            let dist_sq = abs_sq(relative_position);
            let combined_radius = me.radius_m + other.radius_m;
            let combined_radius_sq = combined_radius * combined_radius;

            let direction;
            let u;
            if dist_sq > combined_radius_sq {
                // No collision.
                let w = relative_velocity - relative_position * inv_time_horizon;
                let w_length_sq = abs_sq(w);
                let dot_product1 = dot(w, relative_position);
                if dot_product1 < 0.0
                    && dot_product1 * dot_product1 > combined_radius_sq * w_length_sq
                {
                    // Project on the cut-off circle.
                    let w_length = w_length_sq.sqrt();
                    let unit_w = div(w, w_length);
                    direction = Vec2f::new(unit_w.y, -unit_w.x);
                    u = unit_w * (combined_radius * inv_time_horizon - w_length);
                } else {
                    // Project on the legs.
                    let leg = (dist_sq - combined_radius_sq).sqrt();
                    let (rx, ry) = (relative_position.x, relative_position.y);
                    if det(relative_position, w) > 0.0 {
                        direction = div(
                            Vec2f::new(
                                rx * leg - ry * combined_radius,
                                rx * combined_radius + ry * leg,
                            ),
                            dist_sq,
                        );
                    } else {
                        direction = -div(
                            Vec2f::new(
                                rx * leg + ry * combined_radius,
                                -rx * combined_radius + ry * leg,
                            ),
                            dist_sq,
                        );
                    }
                    let dot_product2 = dot(relative_velocity, direction);
                    u = direction * dot_product2 - relative_velocity;
                }
            } else {
                // Already overlapping: project on the cut-off circle of one time step.
                let inv_time_step = 1.0f32 / self.params.time_step_s;
                let w = relative_velocity - relative_position * inv_time_step;
                let w_length = abs_sq(w).sqrt();
                let unit_w = div(w, w_length);
                direction = Vec2f::new(unit_w.y, -unit_w.x);
                u = unit_w * (combined_radius * inv_time_step - w_length);
            }
            let share = if other.reciprocal { 0.5f32 } else { 1.0f32 };
            self.lines.push(Line {
                point: me.velocity + u * share,
                direction,
            });
        }
    }
}

fn linear_program1(
    lines: &[Line],
    line_no: usize,
    radius: f32,
    opt_velocity: Vec2f,
    direction_opt: bool,
    result: &mut Vec2f,
) -> bool {
    let line = lines[line_no];
    let dot_product = dot(line.point, line.direction);
    let discriminant = dot_product * dot_product + radius * radius - abs_sq(line.point);
    if discriminant < 0.0 {
        // The max-speed circle fully invalidates this line.
        return false;
    }
    let sqrt_discriminant = discriminant.sqrt();
    let mut t_left = -dot_product - sqrt_discriminant;
    let mut t_right = -dot_product + sqrt_discriminant;

    for other in &lines[..line_no] {
        let denominator = det(line.direction, other.direction);
        let numerator = det(other.direction, line.point - other.point);
        if denominator.abs() <= RVO_EPSILON {
            // (Almost) parallel lines.
            if numerator < 0.0 {
                return false;
            }
            continue;
        }
        let t = numerator / denominator;
        if denominator >= 0.0 {
            t_right = t_right.min(t);
        } else {
            t_left = t_left.max(t);
        }
        if t_left > t_right {
            return false;
        }
    }

    if direction_opt {
        if dot(opt_velocity, line.direction) > 0.0 {
            *result = line.point + line.direction * t_right;
        } else {
            *result = line.point + line.direction * t_left;
        }
    } else {
        let t = dot(line.direction, opt_velocity - line.point);
        if t < t_left {
            *result = line.point + line.direction * t_left;
        } else if t > t_right {
            *result = line.point + line.direction * t_right;
        } else {
            *result = line.point + line.direction * t;
        }
    }
    true
}

fn linear_program2(
    lines: &[Line],
    radius: f32,
    opt_velocity: Vec2f,
    direction_opt: bool,
    result: &mut Vec2f,
) -> usize {
    if direction_opt {
        *result = opt_velocity * radius;
    } else if abs_sq(opt_velocity) > radius * radius {
        *result = normalize(opt_velocity) * radius;
    } else {
        *result = opt_velocity;
    }
    for (i, line) in lines.iter().enumerate() {
        if det(line.direction, line.point - *result) > 0.0 {
            let temp = *result;
            if !linear_program1(lines, i, radius, opt_velocity, direction_opt, result) {
                *result = temp;
                return i;
            }
        }
    }
    lines.len()
}

fn linear_program3(
    lines: &[Line],
    num_obst_lines: usize,
    begin_line: usize,
    radius: f32,
    result: &mut Vec2f,
    proj_lines: &mut Vec<Line>,
) {
    let mut distance = 0.0f32;
    for i in begin_line..lines.len() {
        if det(lines[i].direction, lines[i].point - *result) > distance {
            // The result does not satisfy line i. Obstacle lines stay hard.
            proj_lines.clear();
            proj_lines.extend_from_slice(&lines[..num_obst_lines]);
            for j in num_obst_lines..i {
                let determinant = det(lines[i].direction, lines[j].direction);
                let point = if determinant.abs() <= RVO_EPSILON {
                    if dot(lines[i].direction, lines[j].direction) > 0.0 {
                        // Same direction.
                        continue;
                    }
                    (lines[i].point + lines[j].point) * 0.5
                } else {
                    lines[i].point
                        + lines[i].direction
                            * (det(lines[j].direction, lines[i].point - lines[j].point)
                                / determinant)
                };
                let direction = normalize(lines[j].direction - lines[i].direction);
                proj_lines.push(Line { point, direction });
            }
            let temp = *result;
            let opt = Vec2f::new(-lines[i].direction.y, lines[i].direction.x);
            if linear_program2(proj_lines, radius, opt, true, result) < proj_lines.len() {
                // Floating-point error only: keep the current result, as RVO2 does.
                *result = temp;
            }
            distance = det(lines[i].direction, lines[i].point - *result);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> OrcaParams {
        OrcaParams {
            neighbor_dist_m: 10.0,
            max_neighbors: 10,
            time_horizon_s: 5.0,
            time_step_s: 0.25,
            time_horizon_obst_s: 5.0,
        }
    }

    fn agent(x: f32, y: f32, vx: f32, vy: f32, px: f32, py: f32) -> OrcaAgent {
        OrcaAgent {
            position: Vec2f::new(x, y),
            velocity: Vec2f::new(vx, vy),
            pref_velocity: Vec2f::new(px, py),
            radius_m: 0.31,
            max_speed_mps: 1.0,
            reciprocal: true,
        }
    }

    #[test]
    fn free_agent_gets_its_preferred_velocity() {
        let mut orca = Orca::new(params());
        let agents = [agent(0.0, 0.0, 0.0, 0.0, 0.6, 0.3)];
        assert_eq!(orca.new_velocity(0, &agents), Vec2f::new(0.6, 0.3));
        // Clipped to the max speed.
        let agents = [agent(0.0, 0.0, 0.0, 0.0, 3.0, 4.0)];
        let v = orca.new_velocity(0, &agents);
        assert!((v - Vec2f::new(0.6, 0.8)).norm() < 1e-6);
    }

    #[test]
    fn head_on_agents_deviate_symmetrically_and_slow() {
        let mut orca = Orca::new(params());
        let agents = [
            agent(-2.0, 0.0, 1.0, 0.0, 1.0, 0.0),
            agent(2.0, 0.0, -1.0, 0.0, -1.0, 0.0),
        ];
        let a = orca.new_velocity(0, &agents);
        let b = orca.new_velocity(1, &agents);
        // Mirror symmetry through the origin.
        assert!((a + b).norm() < 1e-5, "{a:?} {b:?}");
        assert!(a.x < 1.0);
    }

    #[test]
    fn full_responsibility_toward_non_reciprocal_agent_doubles_the_correction() {
        let mut orca = Orca::new(params());
        let mut agents = [
            agent(-2.0, 0.05, 1.0, 0.0, 1.0, 0.0),
            agent(0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        ];
        let half = orca.new_velocity(0, &agents);
        agents[1].reciprocal = false;
        let full = orca.new_velocity(0, &agents);
        // The correction away from the preferred velocity is larger with full responsibility.
        let pref = Vec2f::new(1.0, 0.0);
        assert!(
            (full - pref).norm() > (half - pref).norm() * 1.5,
            "{half:?} {full:?}"
        );
    }

    #[test]
    fn neighbour_selection_keeps_the_closest_within_range() {
        let mut orca = Orca::new(OrcaParams {
            max_neighbors: 2,
            neighbor_dist_m: 3.0,
            ..params()
        });
        let agents = [
            agent(0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            agent(2.5, 0.0, 0.0, 0.0, 0.0, 0.0),
            agent(1.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            agent(3.5, 0.0, 0.0, 0.0, 0.0, 0.0),
            agent(0.0, 2.0, 0.0, 0.0, 0.0, 0.0),
        ];
        orca.compute_neighbors(0, &agents);
        let picked: Vec<usize> = orca.neighbors.iter().map(|&(_, j)| j).collect();
        assert_eq!(picked, vec![2, 4]);
    }
}
