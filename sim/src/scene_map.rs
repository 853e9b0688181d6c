//! fsrl's TOML scene files: explicit cases with static obstacles (issue 53), the flavour of
//! [`crate::scenes::parse_scenes`] for scenes with walls. Parsed from text, so `sim` stays free
//! of IO; every problem of the file is checked before anything runs and reported at once, each
//! naming its line, its case and its obstacle or agent.
//!
//! # Format
//!
//! ```toml
//! # Obstacles of every case (optional): kind, and vertices as [x, y] in metres.
//! [[obstacles]]
//! kind = "wall"                            # an open polyline, walls on both sides
//! vertices = [[-1, -7], [-1, 7]]
//!
//! [[obstacles]]
//! kind = "polygon"                         # solid, counter-clockwise
//! vertices = [[0.5, 0], [1, 0], [1, 0.5], [0.5, 0.5]]
//!
//! [[cases]]
//! id = 0                                   # optional; default: the case's index in the file
//! robot = { start = [0, -4], goal = [0, 4] }   # optional radius_m, v_pref_mps
//!
//! [[cases.humans]]                         # humans 0, 1, 2, ... in file order (optional)
//! start = [0.3, 3]
//! goal = [-0.2, -5]                        # optional for a standing human
//! radius_m = 0.3                           # optional, as v_pref_mps and standing
//!
//! [[cases.obstacles]]                      # this case's own obstacles (optional), after the
//! kind = "boundary"                        # file's: a bounding wall, clockwise, free inside
//! vertices = [[-4, -6], [-4, 6], [4, 6], [4, -6]]
//! ```
//!
//! Keys are exactly these (an unknown key is an error); integers may stand for numbers.
//! Radii and preferred speeds left out come from the configuration, as in the CSV flavour.
//! The shapes follow [`crate::map`]'s rules (RVO2's conventions): a `polygon` has at least 3
//! vertices listed counter-clockwise, a `boundary` at least 3 listed clockwise, a `wall` at
//! least 2; no shape crosses itself; a closed shape does not repeat its first vertex; shapes
//! may overlap each other. In a case with obstacles, no start or goal may be inside an obstacle
//! or closer to one than the agent's radius, and the robot's goal must be reachable from its
//! start by a disc of the robot's radius ([`StaticMap::reachable`] on a [`REACH_CELL_M`] grid).
//! A case with obstacles gets [`Walls`] whose roadmap is for its largest person
//! (`radius_m + orca.radius_margin_m`); cases without obstacles are open floors.

use std::sync::Arc;

use serde::Deserialize;
use toml::Spanned;

use crate::config::SimConfig;
use crate::geom::Vec2;
use crate::map::{MapError, Shape, ShapeKind, StaticMap};
use crate::scenario::{initial_robot, HumanState, Scenario};
use crate::scene_problem::{AgentRef, Contact, End, SceneProblem, ShapePlace};
use crate::scenes::{SceneCase, SceneError, SceneFile, SceneFormat};
use crate::walled::Walls;

/// Grid cell of the robot's reachability check (metres).
pub const REACH_CELL_M: f64 = 0.1;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DocFile {
    #[serde(default)]
    obstacles: Vec<Spanned<DocShape>>,
    #[serde(default)]
    cases: Vec<Spanned<DocCase>>,
}

/// A point `[x, y]` in metres (exactly two numbers).
#[derive(Deserialize, Clone, Copy)]
#[serde(try_from = "Vec<f64>")]
struct Point([f64; 2]);

impl TryFrom<Vec<f64>> for Point {
    type Error = String;
    fn try_from(v: Vec<f64>) -> Result<Self, String> {
        match v[..] {
            [x, y] => Ok(Point([x, y])),
            _ => Err(format!(
                "a point is [x, y] (two numbers, metres), got {} number{}",
                v.len(),
                if v.len() == 1 { "" } else { "s" }
            )),
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DocShape {
    kind: DocKind,
    vertices: Vec<Point>,
}

#[derive(Deserialize, Clone, Copy)]
#[serde(rename_all = "lowercase")]
enum DocKind {
    Polygon,
    Wall,
    Boundary,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DocCase {
    id: Option<u64>,
    robot: Spanned<DocRobot>,
    #[serde(default)]
    humans: Vec<Spanned<DocHuman>>,
    #[serde(default)]
    obstacles: Vec<Spanned<DocShape>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DocRobot {
    start: Point,
    goal: Point,
    radius_m: Option<f64>,
    v_pref_mps: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DocHuman {
    start: Point,
    goal: Option<Point>,
    radius_m: Option<f64>,
    v_pref_mps: Option<f64>,
    #[serde(default)]
    standing: bool,
}

fn line_of(text: &str, byte: usize) -> usize {
    let end = byte.min(text.len());
    text.as_bytes()[..end]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

fn to_shape(doc: &DocShape) -> Shape {
    Shape {
        kind: match doc.kind {
            DocKind::Polygon => ShapeKind::Polygon,
            DocKind::Wall => ShapeKind::Wall,
            DocKind::Boundary => ShapeKind::Boundary,
        },
        vertices: doc
            .vertices
            .iter()
            .map(|Point([x, y])| Vec2::new(*x, *y))
            .collect(),
    }
}

/// One checked shape: where it is given, and it alone as a map (for naming the obstacle an
/// agent meets). None when the shape is invalid.
struct Checked {
    place: ShapePlace,
    shape: Shape,
    alone: Option<StaticMap>,
}

fn check_shapes(
    text: &str,
    case: Option<u64>,
    docs: &[Spanned<DocShape>],
    problems: &mut Vec<SceneProblem>,
) -> Vec<Checked> {
    docs.iter()
        .enumerate()
        .map(|(index, doc)| {
            let shape = to_shape(doc.get_ref());
            let place = ShapePlace {
                case,
                index,
                kind: shape.kind,
                line: line_of(text, doc.span().start),
            };
            let alone = match StaticMap::new(vec![shape.clone()]) {
                Ok(map) => Some(map),
                Err(MapError::Invalid(list)) => {
                    problems.extend(
                        list.into_iter()
                            .map(|problem| SceneProblem::Shape { place, problem }),
                    );
                    None
                }
                Err(other) => unreachable!("StaticMap::new refuses only with Invalid: {other}"),
            };
            Checked {
                place,
                shape,
                alone,
            }
        })
        .collect()
}

/// How `p` with `radius_m` meets the shape `alone`, if it does.
fn contact(alone: &StaticMap, p: Vec2, radius_m: f64) -> Option<Contact> {
    if alone.is_free(p, radius_m) {
        return None;
    }
    let distance_m = alone.distance_m(p);
    let kind = alone.shapes()[0].kind;
    Some(if distance_m == 0.0 {
        Contact::On
    } else if !alone.is_free(p, 0.0) {
        if kind == ShapeKind::Boundary {
            Contact::Outside
        } else {
            Contact::Inside
        }
    } else {
        Contact::Within {
            distance_m,
            radius_m,
        }
    })
}

/// `value` or, when left out, `default`; a problem when `ok` refuses it.
#[allow(clippy::too_many_arguments)]
fn number(
    problems: &mut Vec<SceneProblem>,
    case: u64,
    line: usize,
    agent: AgentRef,
    field: &'static str,
    value: Option<f64>,
    default: f64,
    ok: fn(f64) -> bool,
    domain: &'static str,
) -> f64 {
    let v = value.unwrap_or(default);
    if !ok(v) {
        problems.push(SceneProblem::BadNumber {
            line,
            case,
            agent,
            field,
            domain,
            value: v,
        });
    }
    v
}

fn finite(p: [f64; 2]) -> bool {
    p[0].is_finite() && p[1].is_finite()
}

/// A map file: the scene format's `[[obstacles]]` and nothing else.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DocMap {
    #[serde(default)]
    obstacles: Vec<Spanned<DocShape>>,
}

/// Parses a scene file's text, CSV or TOML (`crate::scenes`' module docs); radii and preferred
/// speeds not given in the file come from `cfg` (`robot.radius_m`, `robot.v_pref_mps`,
/// `humans.radius_m`, `humans.v_pref_mps`).
pub fn parse_scenes(text: &str, cfg: &SimConfig) -> Result<SceneFile, SceneError> {
    if crate::scenes::is_toml(text) {
        parse_toml_scenes(text, cfg)
    } else {
        crate::scenes::parse_csv_scenes(text, cfg)
    }
}

/// Parses a map file: `[[obstacles]]` tables exactly as in a scene file (see the module docs)
/// and nothing else (no cases: a served robot's map, in its odometry frame, `fsrl serve
/// --map`). Every shape is checked as in a scene file and every problem reported at once, each
/// naming its line and obstacle; a file without obstacles is refused.
pub fn parse_toml_map(text: &str) -> Result<StaticMap, SceneError> {
    let doc: DocMap = toml::from_str(text).map_err(|e| SceneError::Toml {
        line: e.span().map(|s| line_of(text, s.start)),
        message: e.to_string().trim_end().to_string(),
    })?;
    let mut problems = Vec::new();
    if doc.obstacles.is_empty() {
        problems.push(SceneProblem::NoObstacles);
    }
    let checked = check_shapes(text, None, &doc.obstacles, &mut problems);
    if !problems.is_empty() {
        return Err(SceneError::Invalid(problems));
    }
    let shapes = checked.into_iter().map(|c| c.shape).collect();
    StaticMap::new(shapes).map_err(|e| match e {
        MapError::Invalid(list) => SceneError::Invalid(
            list.into_iter()
                .map(|problem| SceneProblem::Shape {
                    place: ShapePlace {
                        case: None,
                        index: problem.shape,
                        kind: problem.kind,
                        line: line_of(text, doc.obstacles[problem.shape].span().start),
                    },
                    problem,
                })
                .collect(),
        ),
        other => unreachable!("StaticMap::new refuses only with Invalid: {other}"),
    })
}

/// Parses fsrl's TOML scene text (see the module docs); defaults from `cfg`. Each case is read
/// in steps, every problem of every step collected before the file is refused: its robot
/// ([`case_robot`]), its people ([`case_humans`]), and, with obstacles, where its agents stand
/// ([`check_placement`]), whether the robot can reach its goal ([`check_reachable`]) and its
/// walls ([`SharedWalls`]).
pub fn parse_toml_scenes(text: &str, cfg: &SimConfig) -> Result<SceneFile, SceneError> {
    let doc: DocFile = toml::from_str(text).map_err(|e| SceneError::Toml {
        line: e.span().map(|s| line_of(text, s.start)),
        message: e.to_string().trim_end().to_string(),
    })?;
    let mut problems = Vec::new();
    let shared = check_shapes(text, None, &doc.obstacles, &mut problems);
    let shared_valid = shared.iter().all(|c| c.alone.is_some());
    if doc.cases.is_empty() {
        problems.push(SceneProblem::NoCases);
    }
    let mut shared_walls = SharedWalls::default();
    let mut first_line_of: std::collections::HashMap<u64, usize> = Default::default();
    let mut cases = Vec::with_capacity(doc.cases.len());
    for (index, spanned) in doc.cases.iter().enumerate() {
        let line = line_of(text, spanned.span().start);
        let c = spanned.get_ref();
        let case = c.id.unwrap_or(index as u64);
        if let Some(&first_line) = first_line_of.get(&case) {
            problems.push(SceneProblem::DuplicateCase {
                line,
                case,
                first_line,
            });
        } else {
            first_line_of.insert(case, line);
        }
        let before = problems.len();
        let (robot, robot_line) = case_robot(text, cfg, case, c, &mut problems);
        let (humans, human_lines) = case_humans(text, cfg, case, c, &mut problems);
        let own = check_shapes(text, Some(case), &c.obstacles, &mut problems);
        let has_obstacles = !(shared.is_empty() && own.is_empty());
        let mut walls = None;
        // Placement and reachability need a valid map and finite agents.
        if has_obstacles && shared_valid && problems.len() == before {
            let all: Vec<&Checked> = shared.iter().chain(&own).collect();
            let agents = Agents {
                case,
                robot: &robot,
                robot_line,
                humans: &humans,
                human_lines: &human_lines,
            };
            check_placement(&agents, &all, &mut problems);
            let shapes: Vec<Shape> = all.iter().map(|c| c.shape.clone()).collect();
            let map = StaticMap::new(shapes).expect("every shape is valid alone");
            if problems.len() == before {
                check_reachable(&agents, &map, &mut problems);
            }
            walls = shared_walls
                .for_case(map, own.is_empty(), &humans, cfg)
                .map_err(|error| problems.push(SceneProblem::Walls { line, case, error }))
                .ok();
        }
        cases.push(SceneCase {
            case,
            line,
            scenario: Scenario {
                robot,
                humans,
                walls,
            },
        });
    }
    if !problems.is_empty() {
        return Err(SceneError::Invalid(problems));
    }
    Ok(SceneFile {
        format: SceneFormat::Toml,
        cases,
    })
}

/// A case's robot, its radius and preferred speed defaulting to `cfg`'s, and the line of its
/// table; its problems (non-finite start or goal, bad numbers) pushed to `problems`.
fn case_robot(
    text: &str,
    cfg: &SimConfig,
    case: u64,
    c: &DocCase,
    problems: &mut Vec<SceneProblem>,
) -> (crate::robot::RobotState, usize) {
    let robot_line = line_of(text, c.robot.span().start);
    let rd = c.robot.get_ref();
    let (start, goal) = (rd.start.0, rd.goal.0);
    let mut robot = initial_robot(cfg);
    for (end, p) in [(End::Start, start), (End::Goal, goal)] {
        if !finite(p) {
            problems.push(SceneProblem::NonFinitePoint {
                line: robot_line,
                case,
                agent: AgentRef::Robot,
                end,
                point: p,
            });
        }
    }
    robot.position = Vec2::new(start[0], start[1]);
    robot.goal = Vec2::new(goal[0], goal[1]);
    let positive = |v: f64| v.is_finite() && v > 0.0;
    robot.radius_m = number(
        problems,
        case,
        robot_line,
        AgentRef::Robot,
        "radius_m",
        rd.radius_m,
        cfg.robot.radius_m,
        positive,
        "a finite number > 0",
    );
    robot.v_pref_mps = number(
        problems,
        case,
        robot_line,
        AgentRef::Robot,
        "v_pref_mps",
        rd.v_pref_mps,
        cfg.robot.v_pref_mps,
        positive,
        "a finite number > 0",
    );
    (robot, robot_line)
}

/// A case's people (a standing person's goal is its start; a walking one needs a goal), their
/// radii and preferred speeds defaulting to `cfg`'s, and the line of each one's table.
fn case_humans(
    text: &str,
    cfg: &SimConfig,
    case: u64,
    c: &DocCase,
    problems: &mut Vec<SceneProblem>,
) -> (Vec<HumanState>, Vec<usize>) {
    let mut humans = Vec::with_capacity(c.humans.len());
    let mut human_lines = Vec::with_capacity(c.humans.len());
    for (k, spanned) in c.humans.iter().enumerate() {
        let hline = line_of(text, spanned.span().start);
        let h = spanned.get_ref();
        let agent = AgentRef::Human(k);
        let radius_m = number(
            problems,
            case,
            hline,
            agent,
            "radius_m",
            h.radius_m,
            cfg.humans.radius_m,
            |v| v.is_finite() && v > 0.0,
            "a finite number > 0",
        );
        let v_pref_mps = number(
            problems,
            case,
            hline,
            agent,
            "v_pref_mps",
            h.v_pref_mps,
            cfg.humans.v_pref_mps,
            |v| v.is_finite() && v >= 0.0,
            "a finite number >= 0",
        );
        let start = h.start.0;
        let goal = match (h.goal, h.standing) {
            (_, true) => start,
            (Some(g), false) => g.0,
            (None, false) => {
                problems.push(SceneProblem::NoGoal {
                    line: hline,
                    case,
                    human: k,
                });
                start
            }
        };
        for (end, p) in [(End::Start, start), (End::Goal, goal)] {
            if !finite(p) && (end == End::Start || !h.standing) {
                problems.push(SceneProblem::NonFinitePoint {
                    line: hline,
                    case,
                    agent,
                    end,
                    point: p,
                });
            }
        }
        humans.push(HumanState {
            position: Vec2::new(start[0], start[1]),
            velocity: Vec2::zeros(),
            goal: Vec2::new(goal[0], goal[1]),
            radius_m,
            v_pref_mps,
            standing: h.standing,
        });
        human_lines.push(hline);
    }
    (humans, human_lines)
}

/// A case's agents as read, with the lines that give them (for the problems' messages).
struct Agents<'a> {
    case: u64,
    robot: &'a crate::robot::RobotState,
    robot_line: usize,
    humans: &'a [HumanState],
    human_lines: &'a [usize],
}

/// Every start and goal (a standing person's start only) clear of every obstacle by the agent's
/// radius; each one that is not, a problem naming the obstacle and how it meets it.
fn check_placement(agents: &Agents<'_>, all: &[&Checked], problems: &mut Vec<SceneProblem>) {
    let robot = agents.robot;
    let mut points: Vec<(usize, AgentRef, End, Vec2, f64)> = vec![
        (
            agents.robot_line,
            AgentRef::Robot,
            End::Start,
            robot.position,
            robot.radius_m,
        ),
        (
            agents.robot_line,
            AgentRef::Robot,
            End::Goal,
            robot.goal,
            robot.radius_m,
        ),
    ];
    for (k, h) in agents.humans.iter().enumerate() {
        let (line, agent) = (agents.human_lines[k], AgentRef::Human(k));
        points.push((line, agent, End::Start, h.position, h.radius_m));
        if !h.standing {
            points.push((line, agent, End::Goal, h.goal, h.radius_m));
        }
    }
    for (line, agent, end, point, radius_m) in points {
        let hit = all.iter().find_map(|c| {
            let alone = c.alone.as_ref().expect("checked valid");
            contact(alone, point, radius_m).map(|k| (c.place, k))
        });
        if let Some((obstacle, contact)) = hit {
            problems.push(SceneProblem::Blocked {
                line,
                case: agents.case,
                agent,
                end,
                point,
                obstacle,
                contact,
            });
        }
    }
}

/// The robot's goal reachable from its start on `map` (a grid of [`REACH_CELL_M`]); a problem
/// otherwise.
fn check_reachable(agents: &Agents<'_>, map: &StaticMap, problems: &mut Vec<SceneProblem>) {
    let (robot, line, case) = (agents.robot, agents.robot_line, agents.case);
    match map.reachable(robot.position, robot.goal, robot.radius_m, REACH_CELL_M) {
        Ok(true) => {}
        Ok(false) => problems.push(SceneProblem::Unreachable {
            line,
            case,
            start: robot.position,
            goal: robot.goal,
            radius_m: robot.radius_m,
            cell_m: REACH_CELL_M,
        }),
        Err(error) => problems.push(SceneProblem::Reachability { line, case, error }),
    }
}

/// The walls of cases that have only the file's obstacles, built once per roadmap radius and
/// shared (a roadmap is the costly part).
#[derive(Default)]
struct SharedWalls(Vec<(f64, Arc<Walls>)>);

impl SharedWalls {
    /// The walls of a case on `map` (`shared_only`: the file's obstacles alone), with the
    /// roadmap for the case's largest person (its ORCA radius).
    fn for_case(
        &mut self,
        map: StaticMap,
        shared_only: bool,
        humans: &[HumanState],
        cfg: &SimConfig,
    ) -> Result<Arc<Walls>, crate::walled::WallsError> {
        let roadmap_radius_m = if humans.is_empty() {
            cfg.humans.radius_m
        } else {
            humans.iter().map(|h| h.radius_m).fold(0.0, f64::max)
        } + cfg.orca.radius_margin_m;
        if shared_only {
            if let Some((_, w)) = self.0.iter().find(|(r, _)| *r == roadmap_radius_m) {
                return Ok(Arc::clone(w));
            }
        }
        let w = Arc::new(Walls::new(map, cfg, roadmap_radius_m)?);
        if shared_only {
            self.0.push((roadmap_radius_m, Arc::clone(&w)));
        }
        Ok(w)
    }
}
