//! CrowdNav parity (issue 8): with `semantics = "crowdnav"` and the holonomic ORCA robot
//! (safety space 0, ORCA radii + 0.01), replaying CrowdNav's test scenes reproduces the
//! per-case outcomes CrowdNav's own ORCA robot had on them, and the aggregate metrics.
//!
//! Data: `test_h10_scenes.csv` and `test_h10_vis{0,1}_outcomes.csv` from the directory named by
//! `FSRL_CROWDNAV_OUTCOMES_DIR`, default the repository's `testdata/crowdnav_cases` (where they
//! come from: `testdata/README.md`). Every case listed in an outcomes file is replayed (0–199 in
//! the repository's data; a file of more cases is checked the same way). Run with `--nocapture`
//! to see the aggregates, also under SPEC's default semantics (`docs/SPEC.md` §2).

use std::path::PathBuf;

use sim::config::Kinematics;
use sim::{
    parse_scenes, run_episode, run_episode_with, Action, Aggregate, Env, EpisodeSummary,
    HumanState, Outcome, RobotState, Scenario, Semantics, Setting, SimConfig, Vec2,
};

/// Per-case outcomes must agree in at least this share of the cases.
const MIN_MATCH_RATE: f64 = 0.97;
const RATE_TOLERANCE: f64 = 0.02;
const NAV_TIME_TOLERANCE_S: f64 = 0.1;

fn data_dir() -> PathBuf {
    match std::env::var_os("FSRL_CROWDNAV_OUTCOMES_DIR") {
        Some(d) => PathBuf::from(d),
        None => PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../testdata/crowdnav_cases"
        )),
    }
}

fn read(name: &str) -> String {
    let path = data_dir().join(name);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "cannot read {} ({e}); set FSRL_CROWDNAV_OUTCOMES_DIR to the folder holding CrowdNav's \
             test_h10_scenes.csv and test_h10_vis{{0,1}}_outcomes.csv",
            path.display()
        )
    });
    assert!(
        text.lines()
            .any(|l| !l.trim().is_empty() && !l.starts_with('#')),
        "{} is empty",
        path.display()
    );
    text
}

/// One row of an outcomes file: CrowdNav's ORCA robot on one case.
#[derive(Debug, Clone, Copy)]
struct CrowdNavCase {
    case: u64,
    outcome: Outcome,
    nav_time_s: f64,
    steps: u32,
    danger_steps: u32,
    /// Smallest closest distance over the danger steps (None without one).
    min_danger_m: Option<f64>,
}

fn cell<T: std::str::FromStr>(text: &str, at: &str) -> T {
    text.trim().parse().unwrap_or_else(|_| panic!("{at}"))
}

fn parse_outcomes(text: &str, name: &str) -> Vec<CrowdNavCase> {
    let mut rows = Vec::new();
    let mut header_seen = false;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if !header_seen {
            assert!(
                line.starts_with("case,outcome,nav_time,steps,danger_steps"),
                "{name}:{}: unexpected header {line:?}",
                i + 1
            );
            header_seen = true;
            continue;
        }
        let c: Vec<&str> = line.split(',').collect();
        let at = format!("{name}:{}: malformed row {line:?}", i + 1);
        assert!(c.len() >= 5, "{at}");
        let outcome = match c[1] {
            "success" => Outcome::ReachGoal,
            "collision" => Outcome::Collision,
            "timeout" => Outcome::Timeout,
            _ => panic!("{at}"),
        };
        rows.push(CrowdNavCase {
            case: cell(c[0], &at),
            outcome,
            nav_time_s: cell(c[2], &at),
            steps: cell(c[3], &at),
            danger_steps: cell(c[4], &at),
            min_danger_m: c
                .get(5)
                .filter(|t| !t.trim().is_empty())
                .map(|t| cell(t, &at)),
        });
    }
    assert!(!rows.is_empty(), "{name} lists no case");
    rows
}

/// The paper's five numbers over a set of episodes.
#[derive(Debug, Clone, Copy)]
struct Numbers {
    cases: usize,
    success: f64,
    collision: f64,
    timeout: f64,
    nav_time_s: f64,
    danger_frequency: f64,
}

impl Numbers {
    fn of_ours(a: &Aggregate, time_limit_steps: u32) -> Self {
        Self {
            cases: a.episodes as usize,
            success: a.success_rate(),
            collision: a.collision_rate(),
            timeout: a.timeout_rate(),
            nav_time_s: a.nav_time_s().unwrap_or(25.0),
            danger_frequency: a.danger_frequency(time_limit_steps),
        }
    }

    /// CrowdNav's explorer: nav time over successes; danger steps over (steps of
    /// non-timeouts + 100 per timeout).
    fn of_crowdnav(rows: &[CrowdNavCase]) -> Self {
        let n = rows.len() as f64;
        let count = |o| rows.iter().filter(|r| r.outcome == o).count() as f64;
        let successes: Vec<f64> = rows
            .iter()
            .filter(|r| r.outcome == Outcome::ReachGoal)
            .map(|r| r.nav_time_s)
            .collect();
        let denominator: u64 = rows
            .iter()
            .map(|r| {
                if r.outcome == Outcome::Timeout {
                    100
                } else {
                    r.steps as u64
                }
            })
            .sum();
        let danger: u64 = rows.iter().map(|r| r.danger_steps as u64).sum();
        Self {
            cases: rows.len(),
            success: count(Outcome::ReachGoal) / n,
            collision: count(Outcome::Collision) / n,
            timeout: count(Outcome::Timeout) / n,
            nav_time_s: if successes.is_empty() {
                25.0
            } else {
                successes.iter().sum::<f64>() / successes.len() as f64
            },
            danger_frequency: danger as f64 / denominator as f64,
        }
    }

    fn row(&self, label: &str) -> String {
        format!(
            "| {label} | {} | {:.3} | {:.3} | {:.3} | {:.2} | {:.3} |",
            self.cases,
            self.success,
            self.collision,
            self.timeout,
            self.nav_time_s,
            self.danger_frequency
        )
    }
}

const TABLE_HEADER: &str = "| run | cases | success | collision | timeout | nav time (s) | danger steps / steps |\n|---|---|---|---|---|---|---|";

fn crowdnav_config(semantics: Semantics) -> SimConfig {
    let mut cfg = SimConfig::default();
    cfg.semantics = semantics;
    cfg.robot.kinematics = Kinematics::Holonomic;
    cfg
}

/// Replays every case of `rows` with the holonomic ORCA robot (safety space 0).
fn replay(cfg: &SimConfig, visible: bool, rows: &[CrowdNavCase]) -> Vec<EpisodeSummary> {
    let scenes = parse_scenes(&read("test_h10_scenes.csv"), cfg).expect("CrowdNav's scene file");
    let setting = Setting::new(sim::EnvKind::Env1, visible);
    let mut env: Option<Env> = None;
    rows.iter()
        .map(|r| {
            let scene = scenes
                .cases
                .iter()
                .find(|c| c.case == r.case)
                .unwrap_or_else(|| panic!("case {} is not in test_h10_scenes.csv", r.case));
            let scenario = scene.scenario.clone();
            let env = match &mut env {
                Some(e) => {
                    e.reset_to_scenario(r.case, scenario);
                    e
                }
                None => {
                    env.insert(Env::from_scenario(cfg.clone(), setting, r.case, scenario).unwrap())
                }
            };
            run_episode_with(env, |env| env.orca_robot_command(0.0), false)
                .unwrap()
                .summary
        })
        .collect()
}

fn aggregate(summaries: &[EpisodeSummary]) -> Aggregate {
    let mut a = Aggregate::default();
    for s in summaries {
        a.add(s);
    }
    a
}

fn check_parity(visible: bool) {
    let file = format!("test_h10_vis{}_outcomes.csv", visible as u8);
    let rows = parse_outcomes(&read(&file), &file);
    let cfg = crowdnav_config(Semantics::CrowdNav);
    let ours = replay(&cfg, visible, &rows);

    let mut matches = 0;
    let mut mismatches = Vec::new();
    let mut time_problems = Vec::new();
    let mut exact_steps = 0;
    let mut worst_danger_dist_m: f64 = 0.0;
    for (r, s) in rows.iter().zip(&ours) {
        if r.outcome == s.outcome {
            matches += 1;
            if s.steps == r.steps && s.danger_steps == r.danger_steps {
                exact_steps += 1;
                if let Some(d) = r.min_danger_m {
                    worst_danger_dist_m = worst_danger_dist_m.max((d - s.min_danger_m).abs());
                }
            }
            if r.outcome == Outcome::ReachGoal && (s.time_s - r.nav_time_s).abs() > cfg.dt_s + 1e-9
            {
                time_problems.push(format!(
                    "case {}: nav time {} s, CrowdNav {} s",
                    r.case, s.time_s, r.nav_time_s
                ));
            }
        } else {
            mismatches.push(format!(
                "case {}: {} after {} steps, CrowdNav {} after {}",
                r.case,
                s.outcome.name(),
                s.steps,
                r.outcome.name(),
                r.steps
            ));
        }
    }
    let rate = matches as f64 / rows.len() as f64;
    let theirs = Numbers::of_crowdnav(&rows);
    let mine = Numbers::of_ours(&aggregate(&ours), cfg.max_steps());
    let spec_runs = replay(&crowdnav_config(Semantics::Spec), visible, &rows);
    let spec = Numbers::of_ours(&aggregate(&spec_runs), cfg.max_steps());
    let spec_differs: Vec<String> = rows
        .iter()
        .zip(&spec_runs)
        .filter(|(r, s)| r.outcome != s.outcome || r.steps != s.steps)
        .map(|(r, s)| {
            format!(
                "case {}: {} after {} steps (CrowdNav {} after {})",
                r.case,
                s.outcome.name(),
                s.steps,
                r.outcome.name(),
                r.steps
            )
        })
        .collect();
    let who = if visible { "visible" } else { "invisible" };
    println!(
        "{who} robot, {} cases of {file}: outcome matches in {matches} ({:.1}%), identical \
         steps and danger steps in {exact_steps}, there min_danger_dist within {:.1e} m\n\
         {TABLE_HEADER}\n{}\n{}\n{}\n",
        rows.len(),
        100.0 * rate,
        worst_danger_dist_m,
        theirs.row(&format!("CrowdNav ({who})")),
        mine.row(&format!("fsrl, crowdnav semantics ({who})")),
        spec.row(&format!("fsrl, SPEC semantics ({who})")),
    );
    for m in &mismatches {
        println!("  mismatch: {m}");
    }
    println!(
        "SPEC semantics end {} of {} cases differently:",
        spec_differs.len(),
        rows.len()
    );
    for m in &spec_differs {
        println!("  {m}");
    }
    assert!(
        rate >= MIN_MATCH_RATE,
        "{who}: outcome matches in only {matches} of {} cases:\n{}",
        rows.len(),
        mismatches.join("\n")
    );
    assert!(
        time_problems.is_empty(),
        "{who}: nav times differ by more than one step:\n{}",
        time_problems.join("\n")
    );
    for (name, a, b, tol) in [
        ("success rate", mine.success, theirs.success, RATE_TOLERANCE),
        (
            "collision rate",
            mine.collision,
            theirs.collision,
            RATE_TOLERANCE,
        ),
        ("timeout rate", mine.timeout, theirs.timeout, RATE_TOLERANCE),
        (
            "danger frequency",
            mine.danger_frequency,
            theirs.danger_frequency,
            RATE_TOLERANCE,
        ),
        (
            "nav time",
            mine.nav_time_s,
            theirs.nav_time_s,
            NAV_TIME_TOLERANCE_S,
        ),
    ] {
        assert!(
            (a - b).abs() <= tol,
            "{who}: {name} {a:.4} vs CrowdNav {b:.4} (tolerance {tol})"
        );
    }
}

#[test]
fn invisible_robot_reproduces_crowdnav() {
    check_parity(false);
}

#[test]
fn visible_robot_reproduces_crowdnav() {
    check_parity(true);
}

// ---- CrowdNav's step semantics by hand -----------------------------------------------------

fn robot_at(x: f64, y: f64) -> RobotState {
    RobotState {
        position: Vec2::new(x, y),
        velocity: Vec2::zeros(),
        goal: Vec2::new(x, 4.0),
        heading_rad: std::f64::consts::FRAC_PI_2,
        radius_m: 0.3,
        v_pref_mps: 1.0,
    }
}

fn human(x: f64, y: f64, gx: f64, gy: f64) -> HumanState {
    HumanState {
        position: Vec2::new(x, y),
        velocity: Vec2::zeros(),
        goal: Vec2::new(gx, gy),
        radius_m: 0.3,
        v_pref_mps: 1.0,
        standing: false,
    }
}

fn env_with(cfg: SimConfig, robot: RobotState, humans: Vec<HumanState>) -> Env {
    Env::from_scenario(
        cfg,
        Setting::ALL[0],
        0,
        Scenario {
            robot,
            humans,
            walls: None,
        },
    )
    .unwrap()
}

/// The holonomic action "full speed, straight up" (k = 4: π/2, last speed).
const UP_FULL: usize = 1 + 4 * 5 + 4;

#[test]
fn crowdnav_timeout_is_the_97th_step_and_beats_collision() {
    // A robot that stops, a human far away: the step starting at 24.0 s is the timeout step.
    let cfg = crowdnav_config(Semantics::CrowdNav);
    let mut env = env_with(
        cfg.clone(),
        robot_at(0.0, -4.0),
        vec![human(3.0, 3.0, -3.0, 3.0)],
    );
    let ep = run_episode(&mut env, |_| 0, false).unwrap();
    assert_eq!(ep.summary.outcome, Outcome::Timeout);
    assert_eq!(ep.summary.steps, 97);
    assert_eq!(ep.summary.time_s, 24.25);
    let last = ep.steps.last().unwrap().eval;
    assert_eq!(last.reward.collision_goal, 0.0);

    // Timeout outranks collision: a human sitting on the robot at t = 24 s.
    let mut env = env_with(cfg, robot_at(0.0, 0.0), vec![human(3.0, 3.0, 3.0, 3.0)]);
    for _ in 0..96 {
        env.step(0).unwrap();
    }
    let mut on_top = env.humans().to_vec();
    on_top[0].position = Vec2::new(0.1, 0.0);
    let eval = sim::evaluate_step(
        env.config(),
        env.robot(),
        Action::STOP,
        &on_top,
        &[Vec2::zeros()],
        97,
    );
    assert!(eval.closest_m < 0.0);
    assert_eq!(eval.outcome, Outcome::Timeout);
    assert!(!eval.danger, "danger only on non-terminal steps");
    let eval96 = sim::evaluate_step(
        env.config(),
        env.robot(),
        Action::STOP,
        &on_top,
        &[Vec2::zeros()],
        96,
    );
    assert_eq!(eval96.outcome, Outcome::Collision);
}

#[test]
fn crowdnav_collision_uses_the_humans_previous_velocity() {
    // A human 0.7 m ahead (boundary 0.1 m) that stood still last step but whose ORCA velocity
    // this step would carry it into the robot: CrowdNav sees no collision (old velocity 0), a
    // danger step at 0.1 m; SPEC's semantics sees the new velocity.
    let robot = robot_at(0.0, 0.0);
    let humans = [human(0.0, 0.7, 0.0, -5.0)];
    let new_velocity = [Vec2::new(0.0, -1.0)];
    let cn = sim::evaluate_step(
        &crowdnav_config(Semantics::CrowdNav),
        &robot,
        Action::STOP,
        &humans,
        &new_velocity,
        1,
    );
    assert_eq!(cn.outcome, Outcome::Running);
    assert!((cn.closest_m - 0.1).abs() < 1e-12, "{}", cn.closest_m);
    assert!(cn.danger);
    assert!((cn.reward.collision_goal - 0.5 * 0.25 * (0.1 - 0.2)).abs() < 1e-12);
    let spec = sim::evaluate_step(
        &crowdnav_config(Semantics::Spec),
        &robot,
        Action::STOP,
        &humans,
        &new_velocity,
        1,
    );
    assert_eq!(spec.outcome, Outcome::Collision);

    // With the old velocity moving, the robot's commanded velocity counts: driving up at
    // 1 m/s toward a human coming down at 1 m/s, 1.0 m apart (boundary 0.4 m): closing 0.5 m in
    // the step, collision.
    let mut h = human(0.0, 1.0, 0.0, -5.0);
    h.velocity = Vec2::new(0.0, -1.0);
    let mut env = env_with(crowdnav_config(Semantics::CrowdNav), robot, vec![h]);
    let info = env.step(UP_FULL).unwrap();
    assert_eq!(info.eval.outcome, Outcome::Collision);
    assert!((info.eval.closest_m + 0.1).abs() < 1e-12);
    // The terminal step still moves everyone and advances time.
    assert!((env.robot().position - Vec2::new(0.0, 0.25)).norm() < 1e-12);
    assert_eq!(env.time_s(), 0.25);
}

#[test]
fn crowdnav_goal_and_danger_priority() {
    // Straight up at 1 m/s from y = −4: within 0.3 m of y = 4 after 31 steps (y = 3.75).
    let cfg = crowdnav_config(Semantics::CrowdNav);
    let mut env = env_with(cfg, robot_at(0.0, -4.0), vec![human(0.65, 3.9, 0.65, 3.9)]);
    let ep = run_episode(&mut env, |_| UP_FULL, false).unwrap();
    assert_eq!(ep.summary.outcome, Outcome::ReachGoal);
    assert_eq!(ep.summary.steps, 31);
    let last = ep.steps.last().unwrap().eval;
    // The last step passes 0.07 m from the human, yet it is the goal step, not a danger step.
    assert!(last.closest_m < 0.2, "{}", last.closest_m);
    assert!(!last.danger);
    assert_eq!(last.reward.collision_goal, 1.0);
    assert!(ep.steps[29].eval.danger);
    assert!(!ep.steps[28].eval.danger);
    assert_eq!(ep.summary.danger_steps, 1);
}

#[test]
fn the_holonomic_orca_robot_executes_orcas_velocity() {
    let cfg = crowdnav_config(Semantics::CrowdNav);
    let mut env = Env::new(cfg, Setting::ALL[0], 1000).unwrap();
    for _ in 0..20 {
        let v = env.orca_robot_velocity(0.0);
        let before = *env.robot();
        let command = env.orca_robot_command(0.0);
        let info = env.step_command(command).unwrap();
        assert!(info.direct_velocity);
        assert_eq!(env.robot().velocity, v);
        assert_eq!(env.robot().position, before.position + v * 0.25);
        assert_eq!(env.robot().heading_rad, before.heading_rad);
        if env.is_done() {
            break;
        }
    }
    // A unicycle robot cannot execute a velocity.
    let mut env = Env::new(SimConfig::default(), Setting::ALL[0], 1000).unwrap();
    assert!(matches!(
        env.step_velocity(Vec2::new(0.0, 1.0)),
        Err(sim::EnvError::NotHolonomic(Kinematics::Unicycle))
    ));
}
