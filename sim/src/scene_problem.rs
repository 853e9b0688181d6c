//! What can be wrong with a scene file with obstacles, where: the problems
//! [`crate::scene_map`] finds, kept below it and [`crate::scenes`] (whose `SceneError` lists
//! them) so that neither imports the other's parser.

use std::fmt;

use crate::geom::Vec2;
use crate::map::{MapError, ShapeKind, ShapeProblem};
use crate::walled::WallsError;

/// An agent of a case.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AgentRef {
    Robot,
    /// Human k of the case (0-based, file order).
    Human(usize),
}

impl fmt::Display for AgentRef {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            AgentRef::Robot => f.write_str("the robot"),
            AgentRef::Human(k) => write!(f, "human {k}"),
        }
    }
}

/// Which end of an agent's trip.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum End {
    Start,
    Goal,
}

impl fmt::Display for End {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            End::Start => "start",
            End::Goal => "goal",
        })
    }
}

/// Where an obstacle is given: in the file's `[[obstacles]]` or in a case's, by index.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ShapePlace {
    /// The case whose `[[cases.obstacles]]` list it is in; None for the file's list.
    pub case: Option<u64>,
    /// Its index in that list (0-based).
    pub index: usize,
    pub kind: ShapeKind,
    /// Its line (1-based).
    pub line: usize,
}

impl ShapePlace {
    /// `obstacle 2 (polygon)` or `case 3's obstacle 0 (wall)`, without its line.
    pub fn name(&self) -> String {
        match self.case {
            None => format!("obstacle {} ({})", self.index, self.kind),
            Some(case) => format!("case {case}'s obstacle {} ({})", self.index, self.kind),
        }
    }
}

/// `obstacle 2 (polygon, line 14)`.
impl fmt::Display for ShapePlace {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let name = self.name();
        let name = name.strip_suffix(')').unwrap_or(&name);
        write!(f, "{name}, line {})", self.line)
    }
}

/// How a start or goal meets an obstacle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Contact {
    /// Inside a solid polygon.
    Inside,
    /// Outside a bounding wall (its free space is inside).
    Outside,
    /// On one of its edges.
    On,
    /// In free space, but nearer to it than the agent's radius.
    Within { distance_m: f64, radius_m: f64 },
}

/// One problem of a TOML scene file (1-based lines).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SceneProblem {
    /// A shape the map refuses ([`crate::map::Defect`]: too few vertices, non-finite
    /// coordinates, wrong orientation, self-intersection, ...).
    #[error("line {}: {} {}", place.line, place.name(), defect_text(.problem))]
    Shape {
        place: ShapePlace,
        problem: ShapeProblem,
    },
    /// A start or goal coordinate that is NaN or infinite.
    #[error("line {line}: case {case}: {agent}'s {end} is ({}, {}); coordinates must be finite numbers", .point[0], .point[1])]
    NonFinitePoint {
        line: usize,
        case: u64,
        agent: AgentRef,
        end: End,
        point: [f64; 2],
    },
    /// A radius or preferred speed out of its domain.
    #[error("line {line}: case {case}: {agent}'s {field} must be {domain}, got {value}")]
    BadNumber {
        line: usize,
        case: u64,
        agent: AgentRef,
        field: &'static str,
        domain: &'static str,
        value: f64,
    },
    /// A walking human without a goal.
    #[error("line {line}: case {case}: human {human} has no goal; only a standing human (standing = true) may leave it out")]
    NoGoal {
        line: usize,
        case: u64,
        human: usize,
    },
    /// A start or goal inside an obstacle, or overlapping one by the agent's radius.
    #[error("line {line}: case {case}: {agent}'s {end} ({}, {}) {}", .point.x, .point.y, contact_text(.contact, .obstacle))]
    Blocked {
        line: usize,
        case: u64,
        agent: AgentRef,
        end: End,
        point: Vec2,
        obstacle: ShapePlace,
        contact: Contact,
    },
    /// The robot's goal cannot be reached from its start.
    #[error("line {line}: case {case}: the robot cannot reach its goal ({}, {}) from its start ({}, {}): the obstacles leave no way for its radius {radius_m} m (searched on a {cell_m} m grid)", .goal.x, .goal.y, .start.x, .start.y)]
    Unreachable {
        line: usize,
        case: u64,
        start: Vec2,
        goal: Vec2,
        radius_m: f64,
        cell_m: f64,
    },
    /// The reachability check could not run (e.g. a map too large for its grid).
    #[error("line {line}: case {case}: cannot check that the robot's goal is reachable: {error}")]
    Reachability {
        line: usize,
        case: u64,
        error: MapError,
    },
    /// RVO2's obstacles could not be built from the map.
    #[error("line {line}: case {case}: {error}")]
    Walls {
        line: usize,
        case: u64,
        error: WallsError,
    },
    /// Two cases with one id.
    #[error(
        "line {line}: case {case} appears again (first at line {first_line}); case ids must differ"
    )]
    DuplicateCase {
        line: usize,
        case: u64,
        first_line: usize,
    },
    /// A file without `[[cases]]`.
    #[error("the scene file has no case (add a [[cases]] table with a robot)")]
    NoCases,
    /// A map file ([`parse_toml_map`]) without `[[obstacles]]`.
    #[error("the map file has no obstacle (add [[obstacles]] tables with kind and vertices)")]
    NoObstacles,
}

impl SceneProblem {
    /// The line the problem is on, if any.
    pub fn line(&self) -> Option<usize> {
        match self {
            SceneProblem::Shape { place, .. } => Some(place.line),
            SceneProblem::NonFinitePoint { line, .. }
            | SceneProblem::BadNumber { line, .. }
            | SceneProblem::NoGoal { line, .. }
            | SceneProblem::Blocked { line, .. }
            | SceneProblem::Unreachable { line, .. }
            | SceneProblem::Reachability { line, .. }
            | SceneProblem::Walls { line, .. }
            | SceneProblem::DuplicateCase { line, .. } => Some(*line),
            SceneProblem::NoCases | SceneProblem::NoObstacles => None,
        }
    }
}

/// The defect part of a map's problem message (which names the shape by its index in the map,
/// not by its place in the file).
fn defect_text(p: &ShapeProblem) -> String {
    let full = p.to_string();
    let prefix = format!("shape {} ({}) ", p.shape, p.kind);
    full.strip_prefix(&prefix).unwrap_or(&full).to_string()
}

fn contact_text(contact: &Contact, obstacle: &ShapePlace) -> String {
    match contact {
        Contact::Inside => format!("is inside {obstacle}"),
        Contact::Outside => {
            format!("is outside {obstacle}, a bounding wall whose free space is inside")
        }
        Contact::On => format!("lies on an edge of {obstacle}"),
        Contact::Within {
            distance_m,
            radius_m,
        } => format!(
            "overlaps {obstacle}: it is {distance_m:.3} m from it, closer than its radius \
             {radius_m} m"
        ),
    }
}
