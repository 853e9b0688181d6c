//! RVO2 v2.0.3's static obstacles (`RVOSimulator::addObstacle`, `processObstacles`, `KdTree.cc`'s
//! obstacle tree and query, the obstacle half of `Agent::computeNewVelocity`), in float32 with
//! RVO2's order of operations. See [`crate::rvo`] for the whole and how it is checked.

use thiserror::Error;

use crate::geom::Vec2f;
use crate::rvo_math::{abs_sq, det, div, dot, normalize, Line, RVO_EPSILON};

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

    /// The ORCA line of obstacle edge `edge` for an agent at `position` moving at `velocity` with
    /// radius `radius_m`, appended to `lines` unless the lines
    /// already there cover it or the edge is ignored (RVO2's `computeNewVelocity`, first loop).
    pub(crate) fn push_line(
        &self,
        edge: usize,
        (position, velocity, radius_m): (Vec2f, Vec2f, f32),
        time_horizon_obst_s: f32,
        lines: &mut Vec<Line>,
    ) {
        let inv_time_horizon_obst = 1.0f32 / time_horizon_obst_s;
        let radius = radius_m;
        let mut o1 = edge;
        let mut o2 = self.vertices[o1].next;
        let relative_position1 = self.vertices[o1].point - position;
        let relative_position2 = self.vertices[o2].point - position;

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
        let left_cutoff = (v1.point - position) * inv_time_horizon_obst;
        let right_cutoff = (v2.point - position) * inv_time_horizon_obst;
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
}
