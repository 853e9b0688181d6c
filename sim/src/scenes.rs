//! Explicit scenes: episodes whose starts and goals come from a file instead of
//! [`Scenario::generate`]. This module parses the file's *text* (the caller reads it), so `sim`
//! stays free of IO.
//!
//! # Format
//!
//! A scene file is CSV, or TOML for scenes with static obstacles. A file whose first line that
//! is neither blank nor a `#` comment starts with `[` or holds a `=` is TOML: fsrl's scenes
//! with obstacles (polygons, walls, bounding walls) for the whole file or per case, specified
//! in [`crate::scene_map`] and checked there (shapes, starts and goals clear of the
//! obstacles, the robot's goal reachable) before anything runs. Otherwise the file is CSV
//! (comma-separated, no quoting, open floor) in one of two flavours that share one grammar:
//!
//! - **CrowdNav's** (`test_h10_scenes.csv`): columns `case,agent,px,py,gx,gy`. Every agent takes
//!   its radius and preferred speed from the configuration (`robot.*`, `humans.*`) and every
//!   human is dynamic.
//! - **fsrl's**: the same required columns plus any of `radius_m`, `v_pref_mps`, `standing`.
//!   An empty cell takes the configuration's value; `standing` is `true`/`false` (or `1`/`0`)
//!   and must be false or empty for the robot.
//!
//! Rules, checked with the line number of the first offending line:
//! - `#` comment lines and blank lines are ignored anywhere;
//! - the first other line is the header: column names in any order, each at most once, the six
//!   required ones present, no others;
//! - every row has as many cells as the header; numbers are finite; radius > 0, v_pref ≥ 0;
//! - `case` is a non-negative integer and a case's rows are consecutive (a case id may not
//!   come back later);
//! - `agent` is `robot` (exactly one per case) or a human index; a case's humans are numbered
//!   0, 1, 2, … in file order;
//! - positions are metres, `(px, py)` the start and `(gx, gy)` the goal. Everyone starts at
//!   rest; the robot's heading is `robot.heading_rad`. A standing human's goal is its start.
//!
//! ```text
//! # fsrl scenes: one standing human in the robot's way
//! case,agent,px,py,gx,gy,radius_m,v_pref_mps,standing
//! 0,robot,0,-4,0,4,,,
//! 0,0,-3,0,3,0,0.3,1,false
//! 0,1,0,0.5,0,0.5,0.4,,true
//! ```

use std::fmt;

use crate::config::SimConfig;
use crate::geom::Vec2;
use crate::robot::RobotState;
use crate::scenario::{initial_robot, HumanState, Scenario};
pub use crate::scene_problem::SceneProblem;

/// Which flavour a scene file is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneFormat {
    /// `case,agent,px,py,gx,gy`, as CrowdNav's `test_h10_scenes.csv`.
    CrowdNav,
    /// The CrowdNav columns plus at least one of `radius_m`, `v_pref_mps`, `standing`.
    Fsrl,
    /// fsrl's TOML scenes, with or without obstacles ([`crate::scene_map`]).
    Toml,
}

/// One case of a scene file.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneCase {
    /// The case id of the file.
    pub case: u64,
    /// Line of the case's first row (1-based; TOML: its `[[cases]]` header).
    pub line: usize,
    pub scenario: Scenario,
}

/// A parsed scene file.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneFile {
    pub format: SceneFormat,
    /// In file order.
    pub cases: Vec<SceneCase>,
}

/// What is wrong with a scene file, and where (1-based line numbers).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SceneError {
    #[error("the scene file has no header line (expected e.g. `case,agent,px,py,gx,gy`)")]
    NoHeader,
    #[error("line {line}: unknown column `{name}`; expected case, agent, px, py, gx, gy and optionally radius_m, v_pref_mps, standing")]
    UnknownColumn { line: usize, name: String },
    #[error("line {line}: column `{name}` appears twice")]
    DuplicateColumn { line: usize, name: String },
    #[error("line {line}: the header lacks the column `{name}`")]
    MissingColumn { line: usize, name: &'static str },
    #[error("line {line}: expected {expected} comma-separated cells (one per header column), found {found}")]
    CellCount {
        line: usize,
        expected: usize,
        found: usize,
    },
    #[error("line {line}: column `{column}`: {problem}, got `{text}`")]
    BadCell {
        line: usize,
        column: &'static str,
        text: String,
        problem: &'static str,
    },
    #[error("line {line}: case {case} appears again after other cases; a case's rows must be consecutive")]
    CaseNotConsecutive { line: usize, case: u64 },
    #[error("line {line}: case {case} has a second robot row")]
    SecondRobot { line: usize, case: u64 },
    #[error("line {line}: case {case} has no robot row")]
    NoRobot { line: usize, case: u64 },
    #[error("line {line}: case {case}: expected human {expected}, found human {found} (humans are numbered 0, 1, 2, ... in file order)")]
    HumanOrder {
        line: usize,
        case: u64,
        expected: usize,
        found: u64,
    },
    #[error("line {line}: the robot cannot be standing")]
    StandingRobot { line: usize },
    #[error("the scene file has a header but no case")]
    NoCases,
    /// A TOML scene file that is not valid TOML or not in the scene format (toml's message,
    /// which names the line and column).
    #[error("{message}")]
    Toml {
        line: Option<usize>,
        message: String,
    },
    /// Every problem of a TOML scene file's contents.
    #[error("{}", problem_list(.0))]
    Invalid(Vec<SceneProblem>),
}

fn problem_list(problems: &[SceneProblem]) -> String {
    let mut s = format!(
        "invalid scenes ({} problem{}):",
        problems.len(),
        if problems.len() == 1 { "" } else { "s" }
    );
    for p in problems {
        s.push_str("\n  - ");
        s.push_str(&p.to_string());
    }
    s
}

impl SceneError {
    /// The line the problem was found on, if any (the first problem's for [`SceneError::Invalid`]).
    pub fn line(&self) -> Option<usize> {
        match self {
            SceneError::NoHeader | SceneError::NoCases => None,
            SceneError::Toml { line, .. } => *line,
            SceneError::Invalid(problems) => problems.first().and_then(SceneProblem::line),
            SceneError::UnknownColumn { line, .. }
            | SceneError::DuplicateColumn { line, .. }
            | SceneError::MissingColumn { line, .. }
            | SceneError::CellCount { line, .. }
            | SceneError::BadCell { line, .. }
            | SceneError::CaseNotConsecutive { line, .. }
            | SceneError::SecondRobot { line, .. }
            | SceneError::NoRobot { line, .. }
            | SceneError::HumanOrder { line, .. }
            | SceneError::StandingRobot { line } => Some(*line),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Column {
    Case,
    Agent,
    Px,
    Py,
    Gx,
    Gy,
    Radius,
    VPref,
    Standing,
}

const COLUMNS: [(Column, &str); 9] = [
    (Column::Case, "case"),
    (Column::Agent, "agent"),
    (Column::Px, "px"),
    (Column::Py, "py"),
    (Column::Gx, "gx"),
    (Column::Gy, "gy"),
    (Column::Radius, "radius_m"),
    (Column::VPref, "v_pref_mps"),
    (Column::Standing, "standing"),
];
const REQUIRED: usize = 6;

fn column_name(c: Column) -> &'static str {
    COLUMNS
        .iter()
        .find(|(k, _)| *k == c)
        .map(|(_, n)| *n)
        .expect("every column is listed")
}

impl fmt::Display for SceneFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SceneFormat::CrowdNav => "CrowdNav (case,agent,px,py,gx,gy)",
            SceneFormat::Fsrl => "fsrl (with radius_m / v_pref_mps / standing)",
            SceneFormat::Toml => "fsrl TOML (with obstacles)",
        })
    }
}

/// One data row, cells by column.
struct Row<'a> {
    line: usize,
    cells: [Option<&'a str>; COLUMNS.len()],
}

impl<'a> Row<'a> {
    fn cell(&self, c: Column) -> Option<&'a str> {
        self.cells[c as usize].filter(|t| !t.is_empty())
    }

    fn bad(&self, c: Column, problem: &'static str) -> SceneError {
        SceneError::BadCell {
            line: self.line,
            column: column_name(c),
            text: self.cells[c as usize].unwrap_or("").to_string(),
            problem,
        }
    }

    fn number(&self, c: Column) -> Result<f64, SceneError> {
        let text = self
            .cell(c)
            .ok_or_else(|| self.bad(c, "a number is required"))?;
        match text.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(self.bad(c, "not a finite number")),
            Err(_) => Err(self.bad(c, "not a number")),
        }
    }

    fn optional_number(
        &self,
        c: Column,
        default: f64,
        ok: fn(f64) -> bool,
        problem: &'static str,
    ) -> Result<f64, SceneError> {
        if self.cell(c).is_none() {
            return Ok(default);
        }
        let v = self.number(c)?;
        if ok(v) {
            Ok(v)
        } else {
            Err(self.bad(c, problem))
        }
    }

    fn standing(&self) -> Result<bool, SceneError> {
        match self.cell(Column::Standing) {
            None | Some("false") | Some("0") => Ok(false),
            Some("true") | Some("1") => Ok(true),
            Some(_) => Err(self.bad(Column::Standing, "expected true, false, 1 or 0")),
        }
    }
}

enum Agent {
    Robot,
    Human(u64),
}

/// The case being read.
struct OpenCase {
    case: u64,
    /// Its first line.
    line: usize,
    robot: Option<RobotState>,
    humans: Vec<HumanState>,
}

impl OpenCase {
    fn finish(self) -> Result<SceneCase, SceneError> {
        let robot = self.robot.ok_or(SceneError::NoRobot {
            line: self.line,
            case: self.case,
        })?;
        Ok(SceneCase {
            case: self.case,
            line: self.line,
            scenario: Scenario {
                robot,
                humans: self.humans,
                walls: None,
            },
        })
    }
}

/// Parses a CSV scene file's text ([`crate::scene_map::parse_scenes`] reads CSV and TOML);
/// radii and preferred speeds not given in the file come from `cfg`.
pub fn parse_csv_scenes(text: &str, cfg: &SimConfig) -> Result<SceneFile, SceneError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));

    let (header_line, header) = lines.next().ok_or(SceneError::NoHeader)?;
    let mut index_of: [Option<usize>; COLUMNS.len()] = [None; COLUMNS.len()];
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    for (i, name) in names.iter().enumerate() {
        let Some((col, _)) = COLUMNS.iter().find(|(_, n)| n == name) else {
            return Err(SceneError::UnknownColumn {
                line: header_line,
                name: name.to_string(),
            });
        };
        if index_of[*col as usize].replace(i).is_some() {
            return Err(SceneError::DuplicateColumn {
                line: header_line,
                name: name.to_string(),
            });
        }
    }
    for (col, name) in &COLUMNS[..REQUIRED] {
        if index_of[*col as usize].is_none() {
            return Err(SceneError::MissingColumn {
                line: header_line,
                name,
            });
        }
    }
    let format = if index_of[REQUIRED..].iter().any(Option::is_some) {
        SceneFormat::Fsrl
    } else {
        SceneFormat::CrowdNav
    };

    let mut cases: Vec<SceneCase> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    let mut current: Option<OpenCase> = None;

    for (line, text) in lines {
        let cells: Vec<&str> = text.split(',').map(str::trim).collect();
        if cells.len() != names.len() {
            return Err(SceneError::CellCount {
                line,
                expected: names.len(),
                found: cells.len(),
            });
        }
        let mut row = Row {
            line,
            cells: [None; COLUMNS.len()],
        };
        for (k, idx) in index_of.iter().enumerate() {
            row.cells[k] = idx.map(|i| cells[i]);
        }
        let case = row
            .cell(Column::Case)
            .and_then(|t| t.parse::<u64>().ok())
            .ok_or_else(|| row.bad(Column::Case, "expected a non-negative integer"))?;
        let agent = match row.cell(Column::Agent) {
            Some("robot") => Agent::Robot,
            Some(t) => Agent::Human(
                t.parse::<u64>()
                    .map_err(|_| row.bad(Column::Agent, "expected `robot` or a human index"))?,
            ),
            None => return Err(row.bad(Column::Agent, "expected `robot` or a human index")),
        };
        let position = Vec2::new(row.number(Column::Px)?, row.number(Column::Py)?);
        let goal = Vec2::new(row.number(Column::Gx)?, row.number(Column::Gy)?);
        let standing = row.standing()?;

        if current.as_ref().map(|c| c.case) != Some(case) {
            if let Some(done) = current.take() {
                cases.push(done.finish()?);
            }
            if !seen.insert(case) {
                return Err(SceneError::CaseNotConsecutive { line, case });
            }
            current = Some(OpenCase {
                case,
                line,
                robot: None,
                humans: Vec::new(),
            });
        }
        let OpenCase { robot, humans, .. } = current.as_mut().expect("a case is open");
        match agent {
            Agent::Robot => {
                if standing {
                    return Err(SceneError::StandingRobot { line });
                }
                if robot.is_some() {
                    return Err(SceneError::SecondRobot { line, case });
                }
                let mut r = initial_robot(cfg);
                r.position = position;
                r.goal = goal;
                r.radius_m = row.optional_number(
                    Column::Radius,
                    cfg.robot.radius_m,
                    |v| v > 0.0,
                    "the radius must be > 0",
                )?;
                r.v_pref_mps = row.optional_number(
                    Column::VPref,
                    cfg.robot.v_pref_mps,
                    |v| v > 0.0,
                    "the robot's preferred speed must be > 0",
                )?;
                *robot = Some(r);
            }
            Agent::Human(k) => {
                if k != humans.len() as u64 {
                    return Err(SceneError::HumanOrder {
                        line,
                        case,
                        expected: humans.len(),
                        found: k,
                    });
                }
                humans.push(HumanState {
                    position,
                    velocity: Vec2::zeros(),
                    goal: if standing { position } else { goal },
                    radius_m: row.optional_number(
                        Column::Radius,
                        cfg.humans.radius_m,
                        |v| v > 0.0,
                        "the radius must be > 0",
                    )?,
                    v_pref_mps: row.optional_number(
                        Column::VPref,
                        cfg.humans.v_pref_mps,
                        |v| v >= 0.0,
                        "the preferred speed must be >= 0",
                    )?,
                    standing,
                });
            }
        }
    }
    if let Some(done) = current {
        cases.push(done.finish()?);
    }
    if cases.is_empty() {
        return Err(SceneError::NoCases);
    }
    Ok(SceneFile { format, cases })
}

/// Whether the first line that is neither blank nor a comment is TOML (a table header or a
/// key = value), not a CSV header.
pub(crate) fn is_toml(text: &str) -> bool {
    text.lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))
        .is_some_and(|l| l.starts_with('[') || l.contains('='))
}

#[cfg(test)]
mod tests {
    use super::*;

    const CROWDNAV: &str = "# comment\ncase,agent,px,py,gx,gy\n0,robot,0.0,-4.0,0.0,4.0\n0,0,-2.5,-2.75,2.5,2.75\n0,1,3.5,0.25,-3.5,-0.25\n1,robot,0.0,-4.0,0.0,4.0\n\n1,0,1.0,1.0,-1.0,-1.0\n";

    #[test]
    fn crowdnav_format_takes_radii_and_speeds_from_the_config() {
        let cfg = SimConfig::default();
        let f = parse_csv_scenes(CROWDNAV, &cfg).unwrap();
        assert_eq!(f.format, SceneFormat::CrowdNav);
        assert_eq!(f.cases.len(), 2);
        assert_eq!((f.cases[0].case, f.cases[0].line), (0, 3));
        assert_eq!((f.cases[1].case, f.cases[1].line), (1, 6));
        let s = &f.cases[0].scenario;
        assert_eq!(s.robot, initial_robot(&cfg));
        assert_eq!(s.humans.len(), 2);
        let h = s.humans[1];
        assert_eq!(h.position, Vec2::new(3.5, 0.25));
        assert_eq!(h.goal, Vec2::new(-3.5, -0.25));
        assert_eq!(h.velocity, Vec2::zeros());
        assert_eq!((h.radius_m, h.v_pref_mps, h.standing), (0.3, 1.0, false));
        assert_eq!(f.cases[1].scenario.humans.len(), 1);
    }

    #[test]
    fn fsrl_format_has_radius_speed_and_standing_per_agent() {
        let text = "standing,case,agent,px,py,gx,gy,radius_m,v_pref_mps\n\
                    ,0,robot,1,-4,1,4,0.25,\n\
                    false,0,0,-3,0,3,0,0.4,1.2\n\
                    true,0,1,0,0.5,9,9,,0\n";
        let f = parse_csv_scenes(text, &SimConfig::default()).unwrap();
        assert_eq!(f.format, SceneFormat::Fsrl);
        let s = &f.cases[0].scenario;
        assert_eq!(s.robot.position, Vec2::new(1.0, -4.0));
        assert_eq!((s.robot.radius_m, s.robot.v_pref_mps), (0.25, 1.0));
        assert_eq!((s.humans[0].radius_m, s.humans[0].v_pref_mps), (0.4, 1.2));
        assert!(!s.humans[0].standing);
        let st = s.humans[1];
        assert!(st.standing);
        assert_eq!((st.radius_m, st.v_pref_mps), (0.3, 0.0));
        assert_eq!(st.goal, st.position, "a standing human's goal is its start");
    }

    #[test]
    fn malformed_files_name_the_line() {
        let cfg = SimConfig::default();
        let h = "case,agent,px,py,gx,gy\n";
        let cases: [(String, usize, &str); 12] = [
            ("case,agent,px,py,gx\n".into(), 1, "lacks the column `gy`"),
            (
                "# x\ncase,agent,px,py,gx,gy,colour\n".into(),
                2,
                "unknown column `colour`",
            ),
            ("case,agent,px,px,gx,gy\n".into(), 1, "`px` appears twice"),
            (
                format!("{h}0,robot,0,-4,0\n"),
                2,
                "expected 6 comma-separated cells (one per header column), found 5",
            ),
            (
                format!("{h}0,robot,0,-4,0,x\n"),
                2,
                "column `gy`: not a number, got `x`",
            ),
            (format!("{h}0,robot,0,-4,0,inf\n"), 2, "not a finite number"),
            (format!("{h}-1,robot,0,-4,0,4\n"), 2, "column `case`"),
            (
                format!("{h}0,robbot,0,-4,0,4\n"),
                2,
                "`robot` or a human index",
            ),
            (
                format!("{h}0,robot,0,-4,0,4\n0,1,0,0,0,0\n"),
                3,
                "expected human 0, found human 1",
            ),
            (
                format!("{h}0,robot,0,-4,0,4\n1,robot,0,-4,0,4\n\n0,0,1,1,1,1\n"),
                5,
                "case 0 appears again",
            ),
            (
                format!("{h}0,0,1,1,1,1\n1,robot,0,-4,0,4\n"),
                2,
                "case 0 has no robot",
            ),
            (
                format!("{h}0,robot,0,-4,0,4\n0,robot,0,-4,0,4\n"),
                3,
                "second robot",
            ),
        ];
        for (text, line, needle) in cases {
            let err = parse_csv_scenes(&text, &cfg).unwrap_err();
            let msg = err.to_string();
            assert_eq!(err.line(), Some(line), "{msg}");
            assert!(msg.starts_with(&format!("line {line}: ")), "{msg}");
            assert!(msg.contains(needle), "{needle:?} not in {msg:?}");
        }
        let fsrl = "case,agent,px,py,gx,gy,radius_m,standing\n";
        let err = parse_csv_scenes(&format!("{fsrl}0,robot,0,-4,0,4,,true\n"), &cfg).unwrap_err();
        assert_eq!(err, SceneError::StandingRobot { line: 2 });
        let err = parse_csv_scenes(&format!("{fsrl}0,robot,0,-4,0,4,0,\n"), &cfg).unwrap_err();
        assert!(err.to_string().contains("radius must be > 0"), "{err}");
        let err = parse_csv_scenes(&format!("{fsrl}0,robot,0,-4,0,4,,maybe\n"), &cfg).unwrap_err();
        assert!(err.to_string().contains("true, false, 1 or 0"), "{err}");
        assert_eq!(
            parse_csv_scenes("# only\n\n", &cfg),
            Err(SceneError::NoHeader)
        );
        assert_eq!(parse_csv_scenes(h, &cfg), Err(SceneError::NoCases));
    }
}
