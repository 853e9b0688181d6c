//! The walled settings (issue 53): the static part of an episode ([`Walls`]: the map, RVO2's
//! obstacle set built from it, and the people's roadmap) and the four layouts, `corridor`,
//! `doorway`, `room` and `pillars` (`[sim.walls.*]`).
//!
//! **How people find their way.** ORCA alone cannot find a door: it only avoids. People follow
//! a visibility roadmap, as RVO2's `Roadmap` example does. Nodes sit off every convex corner of
//! a polygon (on the corner's outer bisector) and off both ends of every open wall (straight on,
//! and diagonally to both sides), at the person's radius plus `walls.roadmap.corner_offset_m`,
//! and only where a person fits. A person heads for its goal when the straight way there keeps
//! its radius clear of every wall; otherwise for the node, among those it sees so, with the
//! shortest way to the goal (straight to the node, then along the roadmap). The rule is
//! stateless: the target is a function of the position only. Toward a node a person walks at
//! its preferred speed; toward its goal it slows as without walls.

use crate::config::{EnvKind, SimConfig};
use crate::geom::{heading, Vec2, Vec2f};
use crate::map::{MapError, Shape, StaticMap};
use crate::rvo::{ObstacleError, ObstacleSet};

/// Why walls could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WallsError {
    #[error(transparent)]
    Map(#[from] MapError),
    #[error(transparent)]
    Obstacle(#[from] ObstacleError),
}

/// The static part of an episode, shared by every step: built once per layout.
#[derive(Debug, Clone, PartialEq)]
pub struct Walls {
    map: StaticMap,
    obstacles: ObstacleSet,
    roadmap: Roadmap,
    doors: Vec<Gate>,
    door_zone_m: f64,
    /// Where one waits: back from a door's line, aside from its axis.
    door_wait_m: (f64, f64),
}

/// A one-way passage: a gap between the free ends of two walls too narrow for two people to
/// pass each other in it and wide enough for one (`walls.roadmap.one_way_gap_m`), such as the
/// doorway's 1 m door. ORCA cannot solve two people meeting head-on in it (neither backs out:
/// seen as a quarter of the doorway's episodes timing out with two people stuck in the door),
/// so people take turns ([`Walls::door_turn`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gate {
    pub centre: Vec2,
    /// Unit normal of the gap (the way through it).
    pub normal: Vec2,
    /// Unit vector along the gap.
    pub along: Vec2,
    pub width_m: f64,
}

impl Gate {
    /// Which side of the gap `p` is on: +1 or −1 (the gap's line itself counts as +1).
    fn side(&self, p: Vec2) -> f64 {
        if (p - self.centre).dot(&self.normal) >= 0.0 {
            1.0
        } else {
            -1.0
        }
    }

    /// The gates of `map` for people of radius `radius_m`: every pair of free wall ends between
    /// `2 × radius_m` and `narrowest_m` apart with nothing nearer the gap's middle than its ends.
    fn find(map: &StaticMap, radius_m: f64, narrowest_m: f64) -> Vec<Gate> {
        let ends: Vec<Vec2> = map
            .shapes()
            .iter()
            .filter(|s| !s.kind.is_closed())
            .flat_map(|s| [s.vertices[0], s.vertices[s.vertices.len() - 1]])
            .collect();
        let mut gates = Vec::new();
        for (i, a) in ends.iter().enumerate() {
            for b in &ends[i + 1..] {
                let width_m = (b - a).norm();
                if width_m <= 2.0 * radius_m || width_m >= narrowest_m {
                    continue;
                }
                let centre = (a + b) / 2.0;
                if map.distance_m(centre) < width_m / 2.0 - 1e-9 {
                    continue;
                }
                let along = (b - a) / width_m;
                gates.push(Gate {
                    centre,
                    normal: Vec2::new(-along.y, along.x),
                    along,
                    width_m,
                });
            }
        }
        gates
    }
}

/// An agent as the door's turns see it: where it is, where it goes, whether it takes part.
#[derive(Debug, Clone, Copy)]
pub struct Mover {
    pub position: Vec2,
    pub goal: Vec2,
    pub moving: bool,
}

/// Roadmap nodes, and which pairs see each other with a person's radius of clearance.
#[derive(Debug, Clone, PartialEq)]
struct Roadmap {
    radius_m: f64,
    nodes: Vec<Vec2>,
    /// `edges[i]`: (node, length) pairs visible from node i.
    edges: Vec<Vec<(usize, f64)>>,
}

/// One person's way to its goal over the roadmap: the length of the shortest way from each
/// node to the goal (∞ where there is none).
#[derive(Debug, Clone, PartialEq)]
pub struct Route {
    goal: Vec2,
    to_goal_m: Vec<f64>,
}

fn to_f32(v: Vec2) -> Vec2f {
    Vec2f::new(v.x as f32, v.y as f32)
}

impl Walls {
    /// Walls from a validated map, with a roadmap for people of radius `person_radius_m`.
    pub fn new(map: StaticMap, cfg: &SimConfig, person_radius_m: f64) -> Result<Self, WallsError> {
        let lists: Vec<Vec<Vec2f>> = map
            .rvo2_obstacles()
            .into_iter()
            .map(|l| l.into_iter().map(to_f32).collect())
            .collect();
        let obstacles = ObstacleSet::new(&lists)?;
        let roadmap = Roadmap::new(
            &map,
            person_radius_m,
            person_radius_m + cfg.walls.roadmap.corner_offset_m,
        );
        let r = &cfg.walls.roadmap;
        let doors = Gate::find(&map, person_radius_m, r.one_way_gap_m);
        Ok(Self {
            map,
            obstacles,
            roadmap,
            doors,
            door_zone_m: r.door_zone_m,
            door_wait_m: (r.door_wait_back_m, r.door_wait_aside_m),
        })
    }

    /// The one-way passages ([`Gate`]).
    pub fn doors(&self) -> &[Gate] {
        &self.doors
    }

    /// Whether mover `k` must wait for its turn at a door, and where: `Some(spot)` when it is
    /// within the door's zone about to cross it (its goal on the far side) and another mover it
    /// `sees`, about to cross the other way, is nearer the door (the lower index on a tie). The
    /// spot is on its own side, back from the door and aside from its axis, so that the one
    /// coming through passes. Stateless, as the roadmap: the nearest to the door goes first,
    /// and whoever follows it the same way goes too.
    pub fn door_turn(
        &self,
        k: usize,
        movers: &[Mover],
        sees: impl Fn(usize) -> bool,
    ) -> Option<Vec2> {
        let me = movers[k];
        if !me.moving {
            return None;
        }
        for door in &self.doors {
            let crossing = |m: &Mover| {
                let d = (m.position - door.centre).norm();
                let (here, there) = (door.side(m.position), door.side(m.goal));
                (d <= self.door_zone_m && here != there).then_some((d, there))
            };
            let Some((d_me, way)) = crossing(&me) else {
                continue;
            };
            let first = movers.iter().enumerate().any(|(j, m)| {
                j != k
                    && m.moving
                    && sees(j)
                    && crossing(m).is_some_and(|(d, w)| w != way && (d, j) < (d_me, k))
            });
            if first {
                let aside = if (me.position - door.centre).dot(&door.along) >= 0.0 {
                    1.0
                } else {
                    -1.0
                };
                let (back, beside) = self.door_wait_m;
                return Some(
                    door.centre - door.normal * (way * back) + door.along * (aside * beside),
                );
            }
        }
        None
    }

    pub fn map(&self) -> &StaticMap {
        &self.map
    }

    /// RVO2's obstacles (the map in float32, processed).
    pub fn obstacles(&self) -> &ObstacleSet {
        &self.obstacles
    }

    /// The roadmap's nodes (for pictures and tests).
    pub fn roadmap_nodes(&self) -> &[Vec2] {
        &self.roadmap.nodes
    }

    /// Whether the straight way from `a` to `b` keeps `radius_m` clear of every wall.
    pub fn sees(&self, a: Vec2, b: Vec2, radius_m: f64) -> bool {
        self.map.swept_clearance_m(a, b) >= radius_m
    }

    /// The shortest ways from every roadmap node to `goal` (Dijkstra from the goal).
    pub fn route(&self, goal: Vec2) -> Route {
        let rm = &self.roadmap;
        let n = rm.nodes.len();
        let mut dist = vec![f64::INFINITY; n];
        for (i, node) in rm.nodes.iter().enumerate() {
            if self.sees(*node, goal, rm.radius_m) {
                dist[i] = (goal - node).norm();
            }
        }
        let mut done = vec![false; n];
        loop {
            let next = (0..n)
                .filter(|&i| !done[i] && dist[i].is_finite())
                .min_by(|&a, &b| dist[a].total_cmp(&dist[b]));
            let Some(i) = next else { break };
            done[i] = true;
            for &(j, len) in &rm.edges[i] {
                if dist[i] + len < dist[j] {
                    dist[j] = dist[i] + len;
                }
            }
        }
        Route {
            goal,
            to_goal_m: dist,
        }
    }

    /// Where a person at `position` heads on `route`: its goal when it sees it, else the visible
    /// node with the shortest way to the goal, else the goal (ORCA then keeps it off the walls).
    /// The flag says whether the target is the goal itself.
    pub fn target(&self, position: Vec2, route: &Route, radius_m: f64) -> (Vec2, bool) {
        if self.sees(position, route.goal, radius_m) {
            return (route.goal, true);
        }
        let mut best: Option<(f64, Vec2)> = None;
        for (node, to_goal) in self.roadmap.nodes.iter().zip(&route.to_goal_m) {
            if !to_goal.is_finite() {
                continue;
            }
            let total = (node - position).norm() + to_goal;
            if best.is_some_and(|(b, _)| total >= b) {
                continue;
            }
            if self.sees(position, *node, radius_m) {
                best = Some((total, *node));
            }
        }
        match best {
            Some((_, node)) => (node, false),
            None => (route.goal, true),
        }
    }
}

impl Roadmap {
    fn new(map: &StaticMap, radius_m: f64, offset_m: f64) -> Self {
        let mut nodes: Vec<Vec2> = Vec::new();
        let mut add = |p: Vec2| {
            if map.is_free(p, radius_m) && nodes.iter().all(|q| (q - p).norm() > 1e-6) {
                nodes.push(p);
            }
        };
        for shape in map.shapes() {
            let v = &shape.vertices;
            let n = v.len();
            if shape.kind.is_closed() {
                // Convex corners of a solid polygon (counter-clockwise: a left turn), and of a
                // bounding wall seen from inside (clockwise: a right turn, a pillar-like corner
                // poking into the room).
                let solid = shape.kind == crate::map::ShapeKind::Polygon;
                for i in 0..n {
                    let (a, b, c) = (v[(i + n - 1) % n], v[i], v[(i + 1) % n]);
                    let (u, w) = ((b - a).normalize(), (c - b).normalize());
                    let turn = u.x * w.y - u.y * w.x;
                    let convex = if solid { turn > 0.0 } else { turn < 0.0 };
                    if convex {
                        let out = (u - w).normalize();
                        add(b + out * offset_m);
                    }
                }
            } else {
                for (end, inner) in [(v[0], v[1]), (v[n - 1], v[n - 2])] {
                    let dir = (end - inner).normalize();
                    let side = Vec2::new(-dir.y, dir.x);
                    let diag = std::f64::consts::FRAC_1_SQRT_2;
                    add(end + dir * offset_m);
                    add(end + (dir + side) * (offset_m * diag));
                    add(end + (dir - side) * (offset_m * diag));
                }
            }
        }
        let mut edges = vec![Vec::new(); nodes.len()];
        for i in 0..nodes.len() {
            for j in i + 1..nodes.len() {
                if map.swept_clearance_m(nodes[i], nodes[j]) >= radius_m {
                    let len = (nodes[j] - nodes[i]).norm();
                    edges[i].push((j, len));
                    edges[j].push((i, len));
                }
            }
        }
        Self {
            radius_m,
            nodes,
            edges,
        }
    }
}

/// The obstacle points the robot sees from `pose` facing `heading_rad` (`[sim.walls.sensor]`):
/// per sector, the nearest point of `map` within range, or the point at range on the sector's
/// centre line when there is none. Always `sensor.sectors` points, sector 0 first.
pub fn obstacle_points(
    map: &StaticMap,
    sensor: &crate::config::SensorConfig,
    pose: Vec2,
    heading_rad: f64,
) -> Vec<Vec2> {
    sector_points_or_range(
        crate::scan::map_sector_nearest(map, pose, heading_rad, sensor.sectors, sensor.range_m),
        sensor,
        pose,
        heading_rad,
    )
}

/// [`obstacle_points`] from a sensor's sector minima (a scan's, [`crate::scan::sector_nearest`]).
pub fn sector_points_or_range(
    nearest: Vec<Option<Vec2>>,
    sensor: &crate::config::SensorConfig,
    pose: Vec2,
    heading_rad: f64,
) -> Vec<Vec2> {
    let width = std::f64::consts::TAU / sensor.sectors as f64;
    nearest
        .into_iter()
        .enumerate()
        .map(|(k, p)| {
            p.unwrap_or_else(|| pose + heading(heading_rad + k as f64 * width) * sensor.range_m)
        })
        .collect()
}

/// The map of a fixed layout (`corridor`, `doorway`); None for the drawn ones and the paper's.
pub fn fixed_map(cfg: &SimConfig, env: EnvKind) -> Option<StaticMap> {
    let shapes = match env {
        EnvKind::Corridor => {
            let k = &cfg.walls.corridor;
            let (x, y) = (k.width_m / 2.0, k.length_m / 2.0);
            vec![
                Shape::wall(vec![Vec2::new(-x, -y), Vec2::new(-x, y)]),
                Shape::wall(vec![Vec2::new(x, y), Vec2::new(x, -y)]),
            ]
        }
        EnvKind::Doorway => {
            let d = &cfg.walls.doorway;
            let (x, y, door) = (d.hall_width_m / 2.0, d.length_m / 2.0, d.door_width_m / 2.0);
            vec![
                Shape::wall(vec![Vec2::new(-x, -y), Vec2::new(-x, y)]),
                Shape::wall(vec![Vec2::new(x, y), Vec2::new(x, -y)]),
                Shape::wall(vec![Vec2::new(-x, 0.0), Vec2::new(-door, 0.0)]),
                Shape::wall(vec![Vec2::new(door, 0.0), Vec2::new(x, 0.0)]),
            ]
        }
        _ => return None,
    };
    // The fixed layouts are valid whenever the config is (checked by `SimConfig::validate`).
    StaticMap::new(shapes).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn doorway() -> Walls {
        let cfg = SimConfig::default();
        Walls::new(fixed_map(&cfg, EnvKind::Doorway).unwrap(), &cfg, 0.31).unwrap()
    }

    #[test]
    fn a_person_behind_the_cross_wall_heads_for_the_door() {
        let walls = doorway();
        let route = walls.route(Vec2::new(1.5, 4.0));
        // Seen from beside the door, the goal is hidden: the target is a node near the door.
        let (target, is_goal) = walls.target(Vec2::new(-1.5, -0.8), &route, 0.31);
        assert!(!is_goal);
        assert!(target.x.abs() < 0.6 && target.y.abs() < 0.6, "{target:?}");
        // Straight below the door the goal is visible.
        let route = walls.route(Vec2::new(0.2, 4.0));
        let (target, is_goal) = walls.target(Vec2::new(0.0, -2.0), &route, 0.31);
        assert!(is_goal && target == Vec2::new(0.2, 4.0), "{target:?}");
    }

    #[test]
    fn corner_nodes_keep_a_person_clear_of_a_box() {
        let cfg = SimConfig::default();
        let map = StaticMap::new(vec![Shape::rectangle(
            Vec2::new(-1.0, -1.0),
            Vec2::new(1.0, 1.0),
        )])
        .unwrap();
        let walls = Walls::new(map, &cfg, 0.31).unwrap();
        assert_eq!(walls.roadmap_nodes().len(), 4);
        let route = walls.route(Vec2::new(0.0, 3.0));
        let (target, is_goal) = walls.target(Vec2::new(0.1, -3.0), &route, 0.31);
        assert!(!is_goal && target.y < -1.0 && target.x > 1.0, "{target:?}");
    }
}
