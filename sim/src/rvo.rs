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

use thiserror::Error;

use crate::geom::Vec2f;
use crate::orca::{
    abs_sq, det, div, dot, normalize, Line, Orca, OrcaAgent, OrcaParams, RVO_EPSILON,
};

/// RVO2's `RVO_MAX_LEAF_SIZE`: agent tree leaves hold at most this many agents.
const MAX_LEAF_SIZE: usize = 10;

/// Why a list of vertices cannot be an RVO2 obstacle.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ObstacleError {
    #[error("obstacle {obstacle} has {vertices} vertex; an obstacle needs at least two")]
    TooFewVertices { obstacle: usize, vertices: usize },
    #[error("obstacle {obstacle} vertex {vertex} is not finite ({x}, {y})")]
    NonFinite {
        obstacle: usize,
        vertex: usize,
        x: f32,
        y: f32,
    },
    #[error(
        "obstacle {obstacle} vertex {vertex} repeats the vertex before it (a zero-length edge)"
    )]
    ZeroLengthEdge { obstacle: usize, vertex: usize },
}

/// One obstacle vertex and the edge from it to the next (RVO2's `Obstacle`).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Vertex {
    point: Vec2f,
    /// Unit direction of the edge to the next vertex.
    direction: Vec2f,
    next: usize,
    previous: usize,
    convex: bool,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Node {
    vertex: usize,
    left: Option<usize>,
    right: Option<usize>,
}

/// RVO2's obstacles after `processObstacles`: the vertices (split ones included) and the obstacle
/// k-d tree. Immutable once built; shared by every agent's query.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ObstacleSet {
    vertices: Vec<Vertex>,
    nodes: Vec<Node>,
    root: Option<usize>,
}

/// RVO2's `leftOf`: positive when `c` lies to the left of the line from `a` to `b`.
#[inline]
fn left_of(a: Vec2f, b: Vec2f, c: Vec2f) -> f32 {
    det(a - c, b - a)
}

impl ObstacleSet {
    /// `addObstacle` for each list in order, then `processObstacles`.
    pub fn new(lists: &[Vec<Vec2f>]) -> Result<Self, ObstacleError> {
        let mut set = Self::default();
        for (obstacle, list) in lists.iter().enumerate() {
            if list.len() < 2 {
                return Err(ObstacleError::TooFewVertices {
                    obstacle,
                    vertices: list.len(),
                });
            }
            for (vertex, p) in list.iter().enumerate() {
                if !(p.x.is_finite() && p.y.is_finite()) {
                    return Err(ObstacleError::NonFinite {
                        obstacle,
                        vertex,
                        x: p.x,
                        y: p.y,
                    });
                }
                let before = list[(vertex + list.len() - 1) % list.len()];
                if before == *p {
                    return Err(ObstacleError::ZeroLengthEdge { obstacle, vertex });
                }
            }
            set.add(list);
        }
        let all: Vec<usize> = (0..set.vertices.len()).collect();
        set.root = set.build(&all);
        Ok(set)
    }

    /// Whether there is no obstacle at all.
    pub fn is_empty(&self) -> bool {
        self.vertices.is_empty()
    }

    /// Vertices after `processObstacles`, split vertices included.
    pub fn vertex_count(&self) -> usize {
        self.vertices.len()
    }

    fn add(&mut self, list: &[Vec2f]) {
        let first = self.vertices.len();
        let n = list.len();
        for i in 0..n {
            let next = if i == n - 1 { 0 } else { i + 1 };
            let previous = if i == 0 { n - 1 } else { i - 1 };
            self.vertices.push(Vertex {
                point: list[i],
                direction: normalize(list[next] - list[i]),
                next: first + next,
                previous: first + previous,
                convex: n == 2 || left_of(list[previous], list[i], list[next]) >= 0.0,
            });
        }
    }

    /// Which side of edge `i` (from vertex `i` to its next) the edge `j` lies on:
    /// (`leftOf` of j's first point, of its second point).
    fn sides(&self, i: usize, j: usize) -> (f32, f32) {
        let (i1, i2) = (
            self.vertices[i].point,
            self.vertices[self.vertices[i].next].point,
        );
        let (j1, j2) = (
            self.vertices[j].point,
            self.vertices[self.vertices[j].next].point,
        );
        (left_of(i1, i2, j1), left_of(i1, i2, j2))
    }

    /// The edge of `edges` that splits the rest most evenly (RVO2's `optimalSplit`, with its
    /// early exit and its lexicographic (larger side, smaller side) order), and the two sizes.
    fn optimal_split(&self, edges: &[usize]) -> (usize, usize, usize) {
        let key = |l: usize, r: usize| (l.max(r), l.min(r));
        let (mut optimal, mut min_left, mut min_right) = (0, edges.len(), edges.len());
        for (i, &ei) in edges.iter().enumerate() {
            let (mut left, mut right) = (0usize, 0usize);
            for (j, &ej) in edges.iter().enumerate() {
                if i == j {
                    continue;
                }
                let (a, b) = self.sides(ei, ej);
                if a >= -RVO_EPSILON && b >= -RVO_EPSILON {
                    left += 1;
                } else if a <= RVO_EPSILON && b <= RVO_EPSILON {
                    right += 1;
                } else {
                    left += 1;
                    right += 1;
                }
                if key(left, right) >= key(min_left, min_right) {
                    break;
                }
            }
            if key(left, right) < key(min_left, min_right) {
                (min_left, min_right, optimal) = (left, right, i);
            }
        }
        (optimal, min_left, min_right)
    }

    /// RVO2's `buildObstacleTreeRecursive`.
    fn build(&mut self, edges: &[usize]) -> Option<usize> {
        if edges.is_empty() {
            return None;
        }
        let (optimal, min_left, min_right) = self.optimal_split(edges);
        let mut left = Vec::with_capacity(min_left);
        let mut right = Vec::with_capacity(min_right);
        let ei = edges[optimal];
        for (j, &ej) in edges.iter().enumerate() {
            if j == optimal {
                continue;
            }
            let (a, b) = self.sides(ei, ej);
            if a >= -RVO_EPSILON && b >= -RVO_EPSILON {
                left.push(ej);
            } else if a <= RVO_EPSILON && b <= RVO_EPSILON {
                right.push(ej);
            } else {
                let split = self.split_edge(ei, ej);
                if a > 0.0 {
                    left.push(ej);
                    right.push(split);
                } else {
                    right.push(ej);
                    left.push(split);
                }
            }
        }
        let node = self.nodes.len();
        self.nodes.push(Node {
            vertex: ei,
            left: None,
            right: None,
        });
        let l = self.build(&left);
        let r = self.build(&right);
        self.nodes[node].left = l;
        self.nodes[node].right = r;
        Some(node)
    }

    /// Splits edge `j` where it crosses the line of edge `i`; returns the new vertex.
    fn split_edge(&mut self, i: usize, j: usize) -> usize {
        let (i1, i2) = (
            self.vertices[i].point,
            self.vertices[self.vertices[i].next].point,
        );
        let j2_index = self.vertices[j].next;
        let (j1, j2) = (self.vertices[j].point, self.vertices[j2_index].point);
        let t = det(i2 - i1, j1 - i1) / det(i2 - i1, j1 - j2);
        let new = self.vertices.len();
        self.vertices.push(Vertex {
            point: j1 + (j2 - j1) * t,
            direction: self.vertices[j].direction,
            next: j2_index,
            previous: j,
            convex: true,
        });
        self.vertices[j].next = new;
        self.vertices[j2_index].previous = new;
        new
    }

    /// RVO2's obstacle neighbours of an agent at `position`: every edge closer than
    /// `sqrt(range_sq)` that the agent sees from its right side, in tree order, kept sorted by
    /// squared distance (ties in visiting order). Appends (squared distance, edge) to `out`.
    pub(crate) fn neighbors(&self, position: Vec2f, range_sq: f32, out: &mut Vec<(f32, usize)>) {
        self.query(self.root, position, range_sq, out);
    }

    fn query(
        &self,
        node: Option<usize>,
        position: Vec2f,
        range_sq: f32,
        out: &mut Vec<(f32, usize)>,
    ) {
        let Some(node) = node.map(|n| self.nodes[n]) else {
            return;
        };
        let o1 = self.vertices[node.vertex];
        let o2 = self.vertices[o1.next];
        let agent_left_of_line = left_of(o1.point, o2.point, position);
        let (near, far) = if agent_left_of_line >= 0.0 {
            (node.left, node.right)
        } else {
            (node.right, node.left)
        };
        self.query(near, position, range_sq, out);
        let dist_sq_line = agent_left_of_line * agent_left_of_line / abs_sq(o2.point - o1.point);
        if dist_sq_line < range_sq {
            if agent_left_of_line < 0.0 {
                // The agent is on the edge's right (outer) side and can see it.
                self.insert_neighbor(node.vertex, position, range_sq, out);
            }
            self.query(far, position, range_sq, out);
        }
    }

    /// RVO2's `Agent::insertObstacleNeighbor`.
    fn insert_neighbor(
        &self,
        edge: usize,
        position: Vec2f,
        range_sq: f32,
        out: &mut Vec<(f32, usize)>,
    ) {
        let a = self.vertices[edge].point;
        let b = self.vertices[self.vertices[edge].next].point;
        let r = dot(position - a, b - a) / abs_sq(b - a);
        let dist_sq = if r < 0.0 {
            abs_sq(position - a)
        } else if r > 1.0 {
            abs_sq(position - b)
        } else {
            abs_sq(position - (a + (b - a) * r))
        };
        if dist_sq < range_sq {
            out.push((dist_sq, edge));
            let mut i = out.len() - 1;
            while i != 0 && dist_sq < out[i - 1].0 {
                out[i] = out[i - 1];
                i -= 1;
            }
            out[i] = (dist_sq, edge);
        }
    }

    /// The ORCA line of obstacle edge `edge` for agent `me`, appended to `lines` unless the lines
    /// already there cover it or the edge is ignored (RVO2's `computeNewVelocity`, first loop).
    pub(crate) fn push_line(
        &self,
        edge: usize,
        me: &OrcaAgent,
        time_horizon_obst_s: f32,
        lines: &mut Vec<Line>,
    ) {
        let inv_time_horizon_obst = 1.0f32 / time_horizon_obst_s;
        let radius = me.radius_m;
        let mut o1 = edge;
        let mut o2 = self.vertices[o1].next;
        let relative_position1 = self.vertices[o1].point - me.position;
        let relative_position2 = self.vertices[o2].point - me.position;

        // Already covered by an earlier obstacle line?
        let covers = |line: &Line, rp: Vec2f| {
            det(rp * inv_time_horizon_obst - line.point, line.direction)
                - inv_time_horizon_obst * radius
                >= -RVO_EPSILON
        };
        if lines
            .iter()
            .any(|l| covers(l, relative_position1) && covers(l, relative_position2))
        {
            return;
        }

        let dist_sq1 = abs_sq(relative_position1);
        let dist_sq2 = abs_sq(relative_position2);
        let radius_sq = radius * radius;
        let obstacle_vector = self.vertices[o2].point - self.vertices[o1].point;
        let s = dot(-relative_position1, obstacle_vector) / abs_sq(obstacle_vector);
        let dist_sq_line = abs_sq(-relative_position1 - obstacle_vector * s);
        let at_origin = |direction: Vec2f| Line {
            point: Vec2f::zeros(),
            direction,
        };

        if s < 0.0 && dist_sq1 <= radius_sq {
            // Collision with the left vertex; ignored if it is not convex.
            if self.vertices[o1].convex {
                lines.push(at_origin(normalize(Vec2f::new(
                    -relative_position1.y,
                    relative_position1.x,
                ))));
            }
            return;
        }
        if s > 1.0 && dist_sq2 <= radius_sq {
            // Collision with the right vertex; ignored if not convex or if the next edge will
            // take care of it.
            if self.vertices[o2].convex
                && det(relative_position2, self.vertices[o2].direction) >= 0.0
            {
                lines.push(at_origin(normalize(Vec2f::new(
                    -relative_position2.y,
                    relative_position2.x,
                ))));
            }
            return;
        }
        // RVO2 v2.0.3: `s <= 1` (Python-RVO2: `s < 1`).
        if (0.0..=1.0).contains(&s) && dist_sq_line <= radius_sq {
            // Collision with the segment.
            lines.push(at_origin(-self.vertices[o1].direction));
            return;
        }

        // No collision: the legs. Seen obliquely, both legs can come from one vertex.
        let left_leg_of = |rp: Vec2f, dist_sq: f32| {
            let leg = (dist_sq - radius_sq).sqrt();
            div(
                Vec2f::new(rp.x * leg - rp.y * radius, rp.x * radius + rp.y * leg),
                dist_sq,
            )
        };
        let right_leg_of = |rp: Vec2f, dist_sq: f32| {
            let leg = (dist_sq - radius_sq).sqrt();
            div(
                Vec2f::new(rp.x * leg + rp.y * radius, -rp.x * radius + rp.y * leg),
                dist_sq,
            )
        };
        let (mut left_leg, mut right_leg);
        if s < 0.0 && dist_sq_line <= radius_sq {
            // The left vertex defines the velocity obstacle.
            if !self.vertices[o1].convex {
                return;
            }
            o2 = o1;
            left_leg = left_leg_of(relative_position1, dist_sq1);
            right_leg = right_leg_of(relative_position1, dist_sq1);
        } else if s > 1.0 && dist_sq_line <= radius_sq {
            // The right vertex defines the velocity obstacle.
            if !self.vertices[o2].convex {
                return;
            }
            o1 = o2;
            left_leg = left_leg_of(relative_position2, dist_sq2);
            right_leg = right_leg_of(relative_position2, dist_sq2);
        } else {
            left_leg = if self.vertices[o1].convex {
                left_leg_of(relative_position1, dist_sq1)
            } else {
                // A non-convex left vertex: the left leg extends the cut-off line.
                -self.vertices[o1].direction
            };
            right_leg = if self.vertices[o2].convex {
                right_leg_of(relative_position2, dist_sq2)
            } else {
                self.vertices[o1].direction
            };
        }

        // Legs never point into a neighbouring edge at a convex vertex: take the edge instead,
        // and mark the leg foreign.
        let v1 = self.vertices[o1];
        let v2 = self.vertices[o2];
        let left_neighbor = self.vertices[v1.previous];
        let mut left_foreign = false;
        let mut right_foreign = false;
        if v1.convex && det(left_leg, -left_neighbor.direction) >= 0.0 {
            left_leg = -left_neighbor.direction;
            left_foreign = true;
        }
        if v2.convex && det(right_leg, v2.direction) <= 0.0 {
            right_leg = v2.direction;
            right_foreign = true;
        }

        // Cut-off centres, and the current velocity projected on the velocity obstacle.
        let velocity = me.velocity;
        let left_cutoff = (v1.point - me.position) * inv_time_horizon_obst;
        let right_cutoff = (v2.point - me.position) * inv_time_horizon_obst;
        let cutoff_vector = right_cutoff - left_cutoff;
        let same = o1 == o2;
        let t = if same {
            0.5f32
        } else {
            dot(velocity - left_cutoff, cutoff_vector) / abs_sq(cutoff_vector)
        };
        let t_left = dot(velocity - left_cutoff, left_leg);
        let t_right = dot(velocity - right_cutoff, right_leg);
        let offset = radius * inv_time_horizon_obst;
        let on_circle = |cutoff: Vec2f| {
            let unit_w = normalize(velocity - cutoff);
            Line {
                direction: Vec2f::new(unit_w.y, -unit_w.x),
                point: cutoff + unit_w * offset,
            }
        };
        let on_leg = |cutoff: Vec2f, direction: Vec2f| Line {
            direction,
            point: cutoff + Vec2f::new(-direction.y, direction.x) * offset,
        };

        if (t < 0.0 && t_left < 0.0) || (same && t_left < 0.0 && t_right < 0.0) {
            lines.push(on_circle(left_cutoff));
            return;
        }
        if t > 1.0 && t_right < 0.0 {
            lines.push(on_circle(right_cutoff));
            return;
        }

        // The closest of the left leg, the right leg and the cut-off line. (RVO2's test as it
        // is: a NaN `t` falls through to the cut-off line, which `!contains` would not.)
        #[allow(clippy::manual_range_contains)]
        let dist_sq_cutoff = if t < 0.0 || t > 1.0 || same {
            f32::INFINITY
        } else {
            abs_sq(velocity - (left_cutoff + cutoff_vector * t))
        };
        let dist_sq_left = if t_left < 0.0 {
            f32::INFINITY
        } else {
            abs_sq(velocity - (left_cutoff + left_leg * t_left))
        };
        let dist_sq_right = if t_right < 0.0 {
            f32::INFINITY
        } else {
            abs_sq(velocity - (right_cutoff + right_leg * t_right))
        };
        if dist_sq_cutoff <= dist_sq_left && dist_sq_cutoff <= dist_sq_right {
            lines.push(on_leg(left_cutoff, -v1.direction));
        } else if dist_sq_left <= dist_sq_right {
            if !left_foreign {
                lines.push(on_leg(left_cutoff, left_leg));
            }
        } else if !right_foreign {
            lines.push(on_leg(right_cutoff, -right_leg));
        }
    }
}

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
    fn bad_vertex_lists_are_refused() {
        assert_eq!(
            ObstacleSet::new(&[vec![v(0.0, 0.0)]]),
            Err(ObstacleError::TooFewVertices {
                obstacle: 0,
                vertices: 1
            })
        );
        assert!(matches!(
            ObstacleSet::new(&[vec![v(0.0, 0.0), v(f32::NAN, 1.0)]]),
            Err(ObstacleError::NonFinite { vertex: 1, .. })
        ));
        assert_eq!(
            ObstacleSet::new(&[vec![v(0.0, 0.0), v(1.0, 0.0), v(1.0, 0.0)]]),
            Err(ObstacleError::ZeroLengthEdge {
                obstacle: 0,
                vertex: 2
            })
        );
    }

    #[test]
    fn a_crossing_edge_is_split_by_the_tree() {
        // Two crossing walls: whichever splits first, the other is cut in two.
        let set = ObstacleSet::new(&[
            vec![v(-2.0, 0.0), v(2.0, 0.0)],
            vec![v(0.0, -1.0), v(0.0, 1.0)],
        ])
        .unwrap();
        assert_eq!(set.vertex_count(), 6);
        let set = ObstacleSet::new(&[
            vec![v(-2.0, 0.0), v(2.0, 0.0)],
            vec![v(0.0, 1.0), v(0.0, 3.0)],
        ])
        .unwrap();
        assert_eq!(set.vertex_count(), 4);
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
