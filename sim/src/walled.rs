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

use std::sync::Arc;

use rand::Rng;

use crate::config::{EnvKind, Setting, SimConfig};
use crate::geom::{heading, Vec2, Vec2f};
use crate::map::{MapError, Shape, StaticMap};
use crate::rvo::{ObstacleError, ObstacleSet};
use crate::scenario::{initial_robot, HumanState, Scenario, ScenarioError};

/// Grid cell of the reachability checks of generated layouts.
const REACH_CELL_M: f64 = 0.1;
/// Attempts at drawing the people of a layout before giving up.
const PEOPLE_ATTEMPTS: usize = 20;
/// Attempts at drawing a layout whose robot goal is reachable before giving up.
const LAYOUT_ATTEMPTS: usize = 200;

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
        Ok(Self {
            map,
            obstacles,
            roadmap,
        })
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

/// The most people a walled layout has (`Some` for the walled kinds): the networks see this
/// many person slots, empty ones as "no return" points ([`crate::Env::static_entities_into`]).
pub fn people_slots(cfg: &SimConfig, env: EnvKind) -> Option<usize> {
    match env {
        EnvKind::Corridor => Some(cfg.walls.corridor.people),
        EnvKind::Doorway => Some(cfg.walls.doorway.people),
        EnvKind::Room => Some(cfg.walls.room.people_max),
        EnvKind::Pillars => Some(cfg.walls.pillars.people),
        EnvKind::Env1 | EnvKind::Env2 | EnvKind::Env3 => None,
    }
}

/// The rows (entities) the networks see per state in `setting`: the humans on an open floor;
/// among walls the person slots plus the sensor's sectors ([`crate::Env::static_entities_into`]).
pub fn entity_count(cfg: &SimConfig, setting: Setting) -> usize {
    match people_slots(cfg, setting.env) {
        Some(slots) => slots + cfg.walls.sensor.sectors,
        None => cfg.humans.count,
    }
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

fn uniform<R: Rng>(rng: &mut R, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.gen::<f64>()
}

/// A solid rectangle of half sides (hx, hy) centred at `c`, rotated by `angle_rad`,
/// counter-clockwise.
fn rotated_box(c: Vec2, hx: f64, hy: f64, angle_rad: f64) -> Shape {
    let (s, co) = angle_rad.sin_cos();
    let corner = |x: f64, y: f64| c + Vec2::new(co * x - s * y, s * x + co * y);
    Shape::polygon(vec![
        corner(-hx, -hy),
        corner(hx, -hy),
        corner(hx, hy),
        corner(-hx, hy),
    ])
}

/// A regular polygon of `sides` with circumradius `r`, counter-clockwise.
fn regular(c: Vec2, r: f64, sides: usize, angle_rad: f64) -> Shape {
    Shape::polygon(
        (0..sides)
            .map(|k| c + heading(angle_rad + std::f64::consts::TAU * k as f64 / sides as f64) * r)
            .collect(),
    )
}

/// Draws a layout from `rng`: the room's furniture or the pillars, with the robot's goal
/// reachable from its start.
fn drawn_map<R: Rng>(
    cfg: &SimConfig,
    setting: Setting,
    seed: u64,
    rng: &mut R,
) -> Result<StaticMap, ScenarioError> {
    let robot = initial_robot(cfg);
    let fail = |why: String| ScenarioError::Layout { setting, seed, why };
    for _ in 0..LAYOUT_ATTEMPTS {
        let mut shapes = Vec::new();
        match setting.env {
            EnvKind::Room => {
                let r = &cfg.walls.room;
                let h = r.side_m / 2.0;
                shapes.push(Shape::room(Vec2::new(-h, -h), Vec2::new(h, h)));
                let count = rng.gen_range(r.furniture_min..=r.furniture_max);
                let mut centres: Vec<(Vec2, f64)> = Vec::new();
                let mut tries = 0;
                while centres.len() < count && tries < 1000 {
                    tries += 1;
                    let (hx, hy) = (
                        uniform(
                            rng,
                            r.furniture_half_side_min_m,
                            r.furniture_half_side_max_m,
                        ),
                        uniform(
                            rng,
                            r.furniture_half_side_min_m,
                            r.furniture_half_side_max_m,
                        ),
                    );
                    let bound = hx.hypot(hy);
                    let lim = h - bound - r.furniture_clearance_m;
                    if lim <= 0.0 {
                        continue;
                    }
                    let c = Vec2::new(uniform(rng, -lim, lim), uniform(rng, -lim, lim));
                    let angle = uniform(rng, 0.0, std::f64::consts::PI);
                    let clear = centres
                        .iter()
                        .all(|(o, ob)| (c - o).norm() >= bound + ob + r.furniture_clearance_m)
                        && (c - robot.position).norm() >= bound + r.furniture_clearance_m
                        && (c - robot.goal).norm() >= bound + r.furniture_clearance_m;
                    if clear {
                        centres.push((c, bound));
                        shapes.push(rotated_box(c, hx, hy, angle));
                    }
                }
            }
            EnvKind::Pillars => {
                let p = &cfg.walls.pillars;
                let count = rng.gen_range(p.pillars_min..=p.pillars_max);
                let mut centres: Vec<Vec2> = Vec::new();
                let mut tries = 0;
                while centres.len() < count && tries < 1000 {
                    tries += 1;
                    let c = heading(uniform(rng, 0.0, std::f64::consts::TAU))
                        * (p.centre_radius_m * rng.gen::<f64>().sqrt());
                    if centres.iter().all(|o| (c - o).norm() >= p.spacing_m) {
                        centres.push(c);
                        let size = uniform(rng, p.size_min_m, p.size_max_m);
                        let angle = uniform(rng, 0.0, std::f64::consts::FRAC_PI_2);
                        shapes.push(if rng.gen::<bool>() {
                            rotated_box(c, size, size, angle)
                        } else {
                            regular(c, size, 8, angle)
                        });
                    }
                }
            }
            _ => unreachable!("drawn_map is called for the drawn layouts only"),
        }
        let map = StaticMap::new(shapes).map_err(|e| fail(e.to_string()))?;
        let reachable = map
            .reachable(robot.position, robot.goal, robot.radius_m, REACH_CELL_M)
            .map_err(|e| fail(e.to_string()))?;
        if reachable {
            return Ok(map);
        }
    }
    Err(fail(format!(
        "no layout with a reachable robot goal in {LAYOUT_ATTEMPTS} draws"
    )))
}

/// Which places of the people already placed a new place keeps clear of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Clear {
    /// Their starts and their goals (people cross each other's ways: room, pillars).
    Both,
    /// Their starts only (a start in a lane: corridor, doorway).
    Starts,
    /// Their goals only (a goal in a lane).
    Goals,
}

/// A free place for a person of radius `r` on `map`, clear by `gap` of the `clear` places of
/// everybody `placed` (start, goal, radius), drawn by `draw`.
#[allow(clippy::too_many_arguments)]
fn place<R: Rng>(
    rng: &mut R,
    attempts: usize,
    map: &StaticMap,
    placed: &[(Vec2, Vec2, f64)],
    clear: Clear,
    r: f64,
    gap: f64,
    mut draw: impl FnMut(&mut R) -> Vec2,
) -> Option<Vec2> {
    (0..attempts).map(|_| draw(rng)).find(|&p| {
        map.is_free(p, r + gap)
            && placed.iter().all(|(s, g, pr)| {
                let min = r + pr + gap;
                (clear == Clear::Goals || (p - s).norm() >= min)
                    && (clear == Clear::Starts || (p - g).norm() >= min)
            })
    })
}

/// The scenario of a walled `setting` for `seed`.
pub(crate) fn generate<R: Rng>(
    cfg: &SimConfig,
    setting: Setting,
    seed: u64,
    rng: &mut R,
) -> Result<Scenario, ScenarioError> {
    let robot = initial_robot(cfg);
    let h = &cfg.humans;
    let fail = |why: String| ScenarioError::Layout { setting, seed, why };
    let map = match fixed_map(cfg, setting.env) {
        Some(map) => map,
        None => drawn_map(cfg, setting, seed, rng)?,
    };
    let (r, gap) = (h.radius_m, h.spawn_gap_m);
    let too_crowded = |human: usize| ScenarioError::TooCrowded {
        setting,
        seed,
        human,
        attempts: h.max_spawn_attempts,
    };
    // People drawn one after the other can leave no room for the last in a lane: the whole
    // crowd is drawn again (from the same generator, so still a function of the seed).
    let draw_people = |rng: &mut R| -> Result<Vec<HumanState>, ScenarioError> {
        let mut placed = vec![(robot.position, robot.goal, robot.radius_m)];
        let mut humans = Vec::new();
        let people = match setting.env {
            EnvKind::Corridor => cfg.walls.corridor.people,
            EnvKind::Doorway => cfg.walls.doorway.people,
            EnvKind::Room => rng.gen_range(cfg.walls.room.people_min..=cfg.walls.room.people_max),
            EnvKind::Pillars => cfg.walls.pillars.people,
            _ => unreachable!("walled::generate is called for walled settings only"),
        };
        for k in 0..people {
            let attempts = h.max_spawn_attempts;
            let (start, goal) = match setting.env {
                EnvKind::Corridor | EnvKind::Doorway => {
                    let (half_w, half_l) = match setting.env {
                        EnvKind::Corridor => (
                            cfg.walls.corridor.width_m / 2.0,
                            cfg.walls.corridor.length_m / 2.0,
                        ),
                        _ => (
                            cfg.walls.doorway.hall_width_m / 2.0,
                            cfg.walls.doorway.length_m / 2.0,
                        ),
                    };
                    let x_lim = (half_w - r - gap).max(0.0);
                    // Corridor: the first half come toward the robot; doorway: even people start
                    // on the robot's side (y < 0), odd ones on the far side.
                    let down = match setting.env {
                        EnvKind::Corridor => k < people / 2,
                        _ => k % 2 == 1,
                    };
                    let sign = if down { 1.0 } else { -1.0 };
                    let (y0, y1) = match setting.env {
                        EnvKind::Corridor => (0.5, half_l - 1.0),
                        _ => (1.0, half_l - 1.5),
                    };
                    let start = place(rng, attempts, &map, &placed, Clear::Starts, r, gap, |rng| {
                        Vec2::new(uniform(rng, -x_lim, x_lim), sign * uniform(rng, y0, y1))
                    })
                    .ok_or_else(|| too_crowded(k))?;
                    let goal = place(rng, attempts, &map, &placed, Clear::Goals, r, gap, |rng| {
                        Vec2::new(
                            uniform(rng, -x_lim, x_lim),
                            -sign * uniform(rng, half_l - 4.5, half_l - 0.5),
                        )
                    })
                    .ok_or_else(|| too_crowded(k))?;
                    (start, goal)
                }
                EnvKind::Room => {
                    let room = &cfg.walls.room;
                    let lim = room.side_m / 2.0 - r - gap;
                    let mut found = None;
                    for _ in 0..attempts {
                        let Some(start) =
                            place(rng, 1, &map, &placed, Clear::Both, r, gap, |rng| {
                                Vec2::new(uniform(rng, -lim, lim), uniform(rng, -lim, lim))
                            })
                        else {
                            continue;
                        };
                        let Some(goal) = place(rng, 1, &map, &placed, Clear::Both, r, gap, |rng| {
                            Vec2::new(uniform(rng, -lim, lim), uniform(rng, -lim, lim))
                        }) else {
                            continue;
                        };
                        if (goal - start).norm() >= room.min_trip_m
                            && map
                                .reachable(start, goal, r, REACH_CELL_M)
                                .map_err(|e| fail(e.to_string()))?
                        {
                            found = Some((start, goal));
                            break;
                        }
                    }
                    found.ok_or_else(|| too_crowded(k))?
                }
                EnvKind::Pillars => {
                    let start = place(rng, attempts, &map, &placed, Clear::Both, r, gap, |rng| {
                        let angle = rng.gen::<f64>() * std::f64::consts::TAU;
                        let noise = Vec2::new(
                            (rng.gen::<f64>() * 2.0 - 1.0) * h.start_noise_m,
                            (rng.gen::<f64>() * 2.0 - 1.0) * h.start_noise_m,
                        );
                        heading(angle) * h.circle_radius_m + noise
                    })
                    .ok_or_else(|| too_crowded(k))?;
                    (start, -start)
                }
                _ => unreachable!("walled::generate is called for walled settings only"),
            };
            placed.push((start, goal, r));
            humans.push(HumanState {
                position: start,
                velocity: Vec2::zeros(),
                goal,
                radius_m: r,
                v_pref_mps: h.v_pref_mps,
                standing: false,
            });
        }
        Ok(humans)
    };
    let mut humans = draw_people(rng);
    for _ in 1..PEOPLE_ATTEMPTS {
        match humans {
            Err(ScenarioError::TooCrowded { .. }) => humans = draw_people(rng),
            _ => break,
        }
    }
    let humans = humans?;
    let walls =
        Walls::new(map, cfg, r + cfg.orca.radius_margin_m).map_err(|e| fail(e.to_string()))?;
    Ok(Scenario {
        robot,
        humans,
        walls: Some(Arc::new(walls)),
    })
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

    #[test]
    fn layouts_are_deterministic_and_keep_everybody_free() {
        use rand::SeedableRng;
        let cfg = SimConfig::default();
        for setting in Setting::WALLED {
            for seed in (0..200).chain([15479352932571408521]) {
                let mut a = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
                let mut b = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
                let s = generate(&cfg, setting, seed, &mut a).unwrap();
                assert_eq!(s, generate(&cfg, setting, seed, &mut b).unwrap());
                let walls = s.walls.as_ref().unwrap();
                assert!(walls.map().is_free(s.robot.position, s.robot.radius_m));
                assert!(walls.map().is_free(s.robot.goal, s.robot.radius_m));
                for h in &s.humans {
                    assert!(
                        walls.map().is_free(h.position, h.radius_m),
                        "{setting} {seed}"
                    );
                    assert!(walls.map().is_free(h.goal, h.radius_m), "{setting} {seed}");
                }
            }
        }
    }
}
