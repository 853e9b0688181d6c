//! RVO2 v2.0.3 with static obstacles, in float32 with RVO2's order of operations (snape/RVO2
//! `RVOSimulator.cc`, `KdTree.cc`, `Agent.cc`), so that it reproduces RVO2 bit for bit:
//!
//! - [`ObstacleSet`]: `addObstacle` for each vertex list (a counter-clockwise polygon, a
//!   clockwise bounding wall, or a two-vertex wall), then `processObstacles`: the obstacle k-d tree,
//!   whose construction splits the edges that cross a splitting line (so the set holds more
//!   vertices than were listed). Its neighbour query visits edges in tree order and keeps them
//!   sorted by distance with ties in visiting order (equal distances are normal at shared
//!   vertices, and their order decides the order of the ORCA lines). [`ObstacleSet::push_line`]
//!   is the obstacle half of `Agent::computeNewVelocity`.
//! - [`Simulator`]: `RVOSimulator` itself (agents in RVO2's agent k-d tree, whose persistent
//!   ordering decides ties between equally distant agents in crowds of more than ten; `doStep`),
//!   used to replay RVO2's reference runs (`sim/tests/orca_ref.rs`).
//!
//! Python-RVO2 (sybrenstuvel/Python-RVO2, which CrowdNav uses) differs from v2.0.3 in one place,
//! the segment-collision test of `computeNewVelocity`: `s < 1` where v2.0.3 has `s <= 1`. This
//! port follows v2.0.3 (`docs/SIMULATOR.md`, "Obstacles").

use crate::geom::Vec2f;
pub use crate::obstacles::{ObstacleError, ObstacleSet};
use crate::orca::{Orca, OrcaAgent, OrcaParams};
use crate::rvo_math::abs_sq;

/// RVO2's `RVO_MAX_LEAF_SIZE`: agent tree leaves hold at most this many agents.
const MAX_LEAF_SIZE: usize = 10;

#[derive(Debug, Clone, Copy, Default)]
struct AgentNode {
    begin: usize,
    end: usize,
    left: usize,
    right: usize,
    max_x: f32,
    max_y: f32,
    min_x: f32,
    min_y: f32,
}

/// RVO2's agent k-d tree. Its agent order persists from one build to the next, as in RVO2.
#[derive(Debug, Clone, Default)]
struct AgentTree {
    order: Vec<usize>,
    nodes: Vec<AgentNode>,
}

/// C++'s `std::max` and `std::min` on floats (the first argument unless the second is larger or
/// smaller).
fn cpp_max(a: f32, b: f32) -> f32 {
    if a < b {
        b
    } else {
        a
    }
}
fn cpp_min(a: f32, b: f32) -> f32 {
    if b < a {
        b
    } else {
        a
    }
}

impl AgentTree {
    fn build(&mut self, agents: &[OrcaAgent]) {
        if self.order.len() < agents.len() {
            self.order.extend(self.order.len()..agents.len());
            self.nodes
                .resize(2 * self.order.len() - 1, AgentNode::default());
        }
        if !self.order.is_empty() {
            self.build_recursive(agents, 0, self.order.len(), 0);
        }
    }

    fn build_recursive(&mut self, agents: &[OrcaAgent], begin: usize, end: usize, node: usize) {
        let p = |k: usize| agents[self.order[k]].position;
        let mut n = AgentNode {
            begin,
            end,
            max_x: p(begin).x,
            min_x: p(begin).x,
            max_y: p(begin).y,
            min_y: p(begin).y,
            ..self.nodes[node]
        };
        for i in begin + 1..end {
            n.max_x = cpp_max(n.max_x, p(i).x);
            n.min_x = cpp_min(n.min_x, p(i).x);
            n.max_y = cpp_max(n.max_y, p(i).y);
            n.min_y = cpp_min(n.min_y, p(i).y);
        }
        self.nodes[node] = n;
        if end - begin <= MAX_LEAF_SIZE {
            return;
        }
        let vertical = n.max_x - n.min_x > n.max_y - n.min_y;
        let split = 0.5f32
            * if vertical {
                n.max_x + n.min_x
            } else {
                n.max_y + n.min_y
            };
        let coord = |order: &[usize], k: usize| {
            let q = agents[order[k]].position;
            if vertical {
                q.x
            } else {
                q.y
            }
        };
        let (mut left, mut right) = (begin, end);
        while left < right {
            while left < right && coord(&self.order, left) < split {
                left += 1;
            }
            while right > left && coord(&self.order, right - 1) >= split {
                right -= 1;
            }
            if left < right {
                self.order.swap(left, right - 1);
                left += 1;
                right -= 1;
            }
        }
        if left == begin {
            left += 1;
        }
        self.nodes[node].left = node + 1;
        self.nodes[node].right = node + 2 * (left - begin);
        self.build_recursive(agents, begin, left, node + 1);
        self.build_recursive(agents, left, end, node + 2 * (left - begin));
    }

    /// RVO2's `queryAgentTreeRecursive` with `Agent::insertAgentNeighbor`.
    fn query(
        &self,
        agents: &[OrcaAgent],
        ego: usize,
        max_neighbors: usize,
        range_sq: &mut f32,
        node: usize,
        out: &mut Vec<(f32, usize)>,
    ) {
        let n = self.nodes[node];
        let me = agents[ego].position;
        if n.end - n.begin <= MAX_LEAF_SIZE {
            for &j in &self.order[n.begin..n.end] {
                if j == ego {
                    continue;
                }
                let dist_sq = abs_sq(me - agents[j].position);
                if dist_sq < *range_sq {
                    if out.len() < max_neighbors {
                        out.push((dist_sq, j));
                    }
                    let mut i = out.len() - 1;
                    while i != 0 && dist_sq < out[i - 1].0 {
                        out[i] = out[i - 1];
                        i -= 1;
                    }
                    out[i] = (dist_sq, j);
                    if out.len() == max_neighbors {
                        *range_sq = out[out.len() - 1].0;
                    }
                }
            }
            return;
        }
        let box_dist_sq = |b: &AgentNode| {
            let min_x = cpp_max(0.0, b.min_x - me.x);
            let max_x = cpp_max(0.0, me.x - b.max_x);
            let min_y = cpp_max(0.0, b.min_y - me.y);
            let max_y = cpp_max(0.0, me.y - b.max_y);
            min_x * min_x + max_x * max_x + min_y * min_y + max_y * max_y
        };
        let dist_sq_left = box_dist_sq(&self.nodes[n.left]);
        let dist_sq_right = box_dist_sq(&self.nodes[n.right]);
        if dist_sq_left < dist_sq_right {
            if dist_sq_left < *range_sq {
                self.query(agents, ego, max_neighbors, range_sq, n.left, out);
                if dist_sq_right < *range_sq {
                    self.query(agents, ego, max_neighbors, range_sq, n.right, out);
                }
            }
        } else if dist_sq_right < *range_sq {
            self.query(agents, ego, max_neighbors, range_sq, n.right, out);
            if dist_sq_left < *range_sq {
                self.query(agents, ego, max_neighbors, range_sq, n.left, out);
            }
        }
    }
}

/// RVO2's `RVOSimulator` with one set of parameters for every agent: agents, static obstacles
/// and `doStep`. Agents are always reciprocal, as in RVO2.
#[derive(Debug, Clone)]
pub struct Simulator {
    params: OrcaParams,
    agents: Vec<OrcaAgent>,
    obstacles: ObstacleSet,
    tree: AgentTree,
    orca: Orca,
    new_velocities: Vec<Vec2f>,
}

impl Simulator {
    /// An empty simulation with `obstacles` already processed.
    pub fn new(params: OrcaParams, obstacles: ObstacleSet) -> Self {
        Self {
            params,
            agents: Vec::new(),
            obstacles,
            tree: AgentTree::default(),
            orca: Orca::new(params),
            new_velocities: Vec::new(),
        }
    }

    /// `addAgent` with velocity zero; returns the agent's index.
    pub fn add_agent(&mut self, position: Vec2f, radius_m: f32, max_speed_mps: f32) -> usize {
        self.agents.push(OrcaAgent {
            position,
            velocity: Vec2f::zeros(),
            pref_velocity: Vec2f::zeros(),
            radius_m,
            max_speed_mps,
            reciprocal: true,
        });
        self.agents.len() - 1
    }

    pub fn agents(&self) -> &[OrcaAgent] {
        &self.agents
    }

    pub fn set_pref_velocity(&mut self, agent: usize, velocity: Vec2f) {
        self.agents[agent].pref_velocity = velocity;
    }

    /// One `doStep`: every agent's new velocity from the same state, then every agent moves.
    pub fn do_step(&mut self) {
        self.tree.build(&self.agents);
        self.new_velocities.clear();
        for i in 0..self.agents.len() {
            self.orca
                .find_obstacle_neighbors(&self.agents[i], &self.obstacles);
            let neighbors = self.orca.neighbors_mut();
            neighbors.clear();
            if self.params.max_neighbors > 0 {
                let mut range_sq = self.params.neighbor_dist_m * self.params.neighbor_dist_m;
                self.tree.query(
                    &self.agents,
                    i,
                    self.params.max_neighbors,
                    &mut range_sq,
                    0,
                    neighbors,
                );
            }
            let v = self.orca.solve(i, &self.agents, Some(&self.obstacles));
            self.new_velocities.push(v);
        }
        let dt = self.params.time_step_s;
        for (agent, v) in self.agents.iter_mut().zip(&self.new_velocities) {
            agent.velocity = *v;
            agent.position += *v * dt;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f32, y: f32) -> Vec2f {
        Vec2f::new(x, y)
    }

    #[test]
    fn an_agent_walking_into_a_wall_stops_at_it() {
        let params = OrcaParams {
            neighbor_dist_m: 10.0,
            max_neighbors: 10,
            time_horizon_s: 5.0,
            time_step_s: 0.25,
            time_horizon_obst_s: 5.0,
        };
        let wall = ObstacleSet::new(&[vec![v(1.0, -2.0), v(1.0, 2.0)]]).unwrap();
        let mut sim = Simulator::new(params, wall);
        let a = sim.add_agent(v(0.0, 0.0), 0.3, 1.0);
        for _ in 0..40 {
            sim.set_pref_velocity(a, v(1.0, 0.0));
            sim.do_step();
            let x = sim.agents()[a].position.x;
            assert!(x <= 0.7 + 1e-5, "the agent crossed into the wall: x = {x}");
        }
        assert!(sim.agents()[a].position.x > 0.6);
    }
}
