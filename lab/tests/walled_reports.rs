//! Reports of the walled settings (issue 53): wall collisions, people collisions and frozen
//! robots apart, written only where there are walls, so that every report of the paper's six
//! settings reads and writes back byte for byte as it was recorded.

use std::path::{Path, PathBuf};

use lab::evaluation::{default_settings, evaluate_orca, EvalPlan};
use lab::report::{EvalReport, SettingReport, SubjectReport, EVAL_KIND};
use sim::{run_episode_with, Aggregate, Env, Kinematics, Outcome, RobotCommand, Setting, Vec2};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Every `fsrl eval` report under `dir` (eval.json, or a grid's NAME.json beside NAME.md).
fn recorded_reports(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for path in entries.filter_map(|e| e.ok().map(|e| e.path())) {
        if path.is_dir() {
            recorded_reports(&path, out);
        } else if path.extension().is_some_and(|e| e == "json")
            && std::fs::read_to_string(&path)
                .is_ok_and(|t| t.contains(&format!("\"kind\": \"{EVAL_KIND}\"")))
        {
            out.push(path);
        }
    }
}

/// The Markdown (and CSV) written beside a recorded report.
fn sibling(json: &Path, ext: &str) -> Option<String> {
    std::fs::read_to_string(json.with_extension(ext)).ok()
}

/// The keys of a JSON text, in the order they are written.
fn keys_in_order(text: &str) -> Vec<&str> {
    text.lines()
        .filter_map(|l| l.trim_start().strip_prefix('"'))
        .filter_map(|l| l.split_once("\": ").map(|(k, _)| k))
        .collect()
}

/// The same header and rows, field by field; numbers within 1e-12 (relative) of each other.
fn same_csv(ours: &str, recorded: &str, path: &Path) {
    let (ours, recorded): (Vec<&str>, Vec<&str>) =
        (ours.lines().collect(), recorded.lines().collect());
    assert_eq!(ours.len(), recorded.len(), "{}: CSV rows", path.display());
    assert_eq!(ours[0], recorded[0], "{}: CSV header", path.display());
    for (a, b) in ours.iter().zip(&recorded) {
        let (fa, fb): (Vec<&str>, Vec<&str>) = (a.split(',').collect(), b.split(',').collect());
        assert_eq!(fa.len(), fb.len(), "{}: {a}", path.display());
        for (x, y) in fa.iter().zip(&fb) {
            match (x.parse::<f64>(), y.parse::<f64>()) {
                (Ok(x), Ok(y)) => assert!(
                    (x - y).abs() <= 1e-12 * x.abs().max(y.abs()),
                    "{}: {x} against {y} in {a}",
                    path.display()
                ),
                _ => assert_eq!(x, y, "{}: {a}", path.display()),
            }
        }
    }
}

/// Every recorded report (the shipped models' grid, the experiments' evaluations, the walled
/// baselines) is written again with the same keys in the same order and the same values, its
/// CSV with the same columns and values, and the Markdown of a paper-settings report is the
/// recorded file byte for byte: the walled settings' fields appear only in walled settings.
/// (Values are compared as parsed: serde_json reads some floats one unit in the last place off,
/// the same way for the file and for the report.)
#[test]
fn recorded_reports_write_back_as_recorded() {
    let mut files = Vec::new();
    recorded_reports(&repo().join("docs/results"), &mut files);
    files.sort();
    assert!(
        files.len() >= 60,
        "the shipped models' reports: {}",
        files.len()
    );
    let (mut md, mut csv) = (0, 0);
    for path in &files {
        let text = std::fs::read_to_string(path).unwrap();
        let report: EvalReport =
            serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        // A walled setting's report (docs/results/walls-baselines.json) has its split, a paper
        // setting's none.
        let mut walled = false;
        for r in report.subjects.iter().flat_map(|s| &s.settings) {
            let among_walls = !r.parsed_setting().unwrap().is_paper();
            assert_eq!(
                r.walls.is_some(),
                among_walls,
                "{}: {}",
                path.display(),
                r.setting
            );
            r.check()
                .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            walled |= among_walls;
        }
        let again = serde_json::to_string_pretty(&report).unwrap();
        // Older fsrl versions wrote a `checkpoint_crc32` that today's reports ignore.
        let old_only = |k: &&str| *k != "checkpoint_crc32";
        let recorded_keys: Vec<&str> = keys_in_order(&text).into_iter().filter(old_only).collect();
        assert_eq!(
            keys_in_order(&again),
            recorded_keys,
            "{}: keys",
            path.display()
        );
        let mut recorded: serde_json::Value = serde_json::from_str(&text).unwrap();
        for subject in recorded["subjects"].as_array_mut().unwrap() {
            subject.as_object_mut().unwrap().remove("checkpoint_crc32");
        }
        assert_eq!(
            serde_json::to_value(&report).unwrap(),
            recorded,
            "{}: values",
            path.display()
        );
        // The walled baselines' Markdown is a document with the commands, not `fsrl eval`'s.
        if let Some(m) = sibling(path, "md").filter(|_| !walled) {
            assert_eq!(report.markdown(), m, "{}: Markdown", path.display());
            md += 1;
        }
        if let Some(c) = sibling(path, "csv") {
            same_csv(&report.csv(), &c, path);
            csv += 1;
        }
    }
    assert!(
        md >= 60 && csv >= 1,
        "{md} Markdown, {csv} CSV files compared"
    );
}

fn plan(settings: Vec<Setting>, episodes: u32) -> EvalPlan {
    EvalPlan {
        settings,
        seed_start: 1000,
        episodes,
        threads: 2,
        orca_safety_space_m: 0.0,
        planning_top_k: None,
        planning_breadth: None,
        crowd: Default::default(),
        shield_s: None,
        progress_tolerance: None,
    }
}

fn setting(name: &str) -> Setting {
    name.parse().unwrap()
}

/// The keys a paper setting's report has always had, in their order.
const PAPER_KEYS: [&str; 22] = [
    "setting",
    "episodes",
    "successes",
    "collisions",
    "timeouts",
    "success",
    "success_ci95",
    "collision",
    "collision_ci95",
    "timeout",
    "timeout_ci95",
    "nav_time_s",
    "nav_time_ci95_s",
    "nav_time_std_s",
    "disc",
    "danger_steps",
    "steps",
    "path_length_m",
    "path_length_std_m",
    "mean_abs_rotation_rad",
    "mean_return",
    "return_std",
];

const WALL_KEYS: [&str; 9] = [
    "wall_collisions",
    "people_collisions",
    "frozen_robots",
    "wall_collision",
    "wall_collision_ci95",
    "people_collision",
    "people_collision_ci95",
    "frozen_robot",
    "frozen_robot_ci95",
];

fn keys(r: &SettingReport) -> Vec<String> {
    // serde_json's map keeps its keys sorted unless told otherwise: read them in writing order.
    let text = serde_json::to_string_pretty(r).unwrap();
    text.lines()
        .filter_map(|l| l.strip_prefix("  \""))
        .filter_map(|l| l.split('"').next())
        .map(str::to_string)
        .collect()
}

#[test]
fn a_walled_setting_evaluated_end_to_end_reports_the_three_rates_and_a_paper_setting_none() {
    let sim = sim::SimConfig::default();
    let settings = vec![
        setting("env1-invisible"),
        setting("corridor"),
        setting("room-visible"),
    ];
    let orca = evaluate_orca(&sim, &plan(settings, 12), &|| {}).unwrap();
    let paper = &orca.settings[0];
    assert_eq!(paper.walls, None);
    let paper_keys = PAPER_KEYS.to_vec();
    assert_eq!(keys(paper), paper_keys);
    for r in &orca.settings[1..] {
        r.check().unwrap();
        let w = r.walls.as_ref().unwrap_or_else(|| panic!("{}", r.setting));
        assert_eq!(r.episodes, 12);
        assert_eq!(w.wall_collisions + w.people_collisions, r.collisions);
        assert!(w.frozen_robots <= r.timeouts);
        assert_eq!(w.wall_collision, f64::from(w.wall_collisions) / 12.0);
        assert_eq!(w.frozen_robot, f64::from(w.frozen_robots) / 12.0);
        let k = keys(r);
        assert_eq!(&k[..paper_keys.len()], &paper_keys[..], "{}", r.setting);
        assert_eq!(&k[paper_keys.len()..], &WALL_KEYS[..], "{}", r.setting);
        // Read back as written.
        let again: SettingReport =
            serde_json::from_str(&serde_json::to_string(r).unwrap()).unwrap();
        let again = again.walls.unwrap();
        assert_eq!(
            (
                again.wall_collisions,
                again.people_collisions,
                again.frozen_robots
            ),
            (w.wall_collisions, w.people_collisions, w.frozen_robots)
        );
    }
    let report = EvalReport {
        kind: EVAL_KIND.into(),
        crowd: None,
        test_seed_start: 1000,
        episodes_per_setting: 12,
        subjects: vec![orca.clone()],
    };
    let md = report.markdown();
    assert!(md.contains("## Walled settings"), "{md}");
    assert!(md.contains("| orca | corridor | "), "{md}");
    assert!(md.contains("| orca | room-visible | "), "{md}");
    // The paper's layout has the paper setting; the details table the extra columns, "–" for it.
    assert!(md.contains("## Succ. (success rate)"), "{md}");
    assert!(
        md.contains("| Wall coll. | People coll. | Frozen |"),
        "{md}"
    );
    assert!(md.contains("| env1-invisible | 12 |"), "{md}");
    let csv = report.csv();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    assert_eq!(header.last(), Some(&"frozen_robot_hi"));
    for line in csv.lines().skip(1) {
        assert_eq!(line.split(',').count(), header.len(), "{line}");
    }
    let corridor = csv.lines().find(|l| l.contains(",corridor,")).unwrap();
    let w = orca.settings[1].walls.as_ref().unwrap();
    assert!(
        corridor.contains(&format!(
            ",{},{},{},",
            w.wall_collisions, w.people_collisions, w.frozen_robots
        )),
        "{corridor}"
    );

    // Walled settings alone: no empty paper tables.
    let walled_only = EvalReport {
        subjects: vec![SubjectReport {
            settings: orca.settings[1..].to_vec(),
            ..orca
        }],
        ..report
    };
    let md = walled_only.markdown();
    assert!(!md.contains("## Succ. (success rate)"), "{md}");
    assert!(!md.contains("AVG") && !md.contains("(paper)"), "{md}");
    assert!(md.contains("## Walled settings"), "{md}");
}

#[test]
fn a_paper_setting_report_refuses_wall_figures_and_a_walled_one_inconsistent_ones() {
    let a = Aggregate {
        episodes: 10,
        successes: 6,
        collisions: 3,
        timeouts: 1,
        wall_collisions: 2,
        frozen: 1,
        success_time_s: 60.0,
        success_path_m: 50.0,
        steps: 300,
        ..Aggregate::default()
    };
    let good = SettingReport::new("doorway", &a);
    good.check().unwrap();
    let w = good.walls.clone().unwrap();
    assert_eq!(
        (w.wall_collisions, w.people_collisions, w.frozen_robots),
        (2, 1, 1)
    );
    assert_eq!(
        (w.wall_collision, w.people_collision, w.frozen_robot),
        (0.2, 0.1, 0.1)
    );
    let mut paper = SettingReport::new("env2-visible", &a);
    assert_eq!(paper.walls, None);
    paper.walls = Some(w.clone());
    assert!(paper.check().unwrap_err().contains("setting without walls"));
    let mut split = good.clone();
    split.walls.as_mut().unwrap().people_collisions = 2;
    assert!(split.check().unwrap_err().contains("do not split"));
    let mut frozen = good.clone();
    frozen.walls.as_mut().unwrap().frozen_robots = 2;
    assert!(frozen.check().unwrap_err().contains("do not split"));
    let mut rate = good;
    rate.walls.as_mut().unwrap().wall_collision = 0.3;
    assert!(rate.check().unwrap_err().contains("wall_collision 0.3"));
}

/// The robot drives straight into the corridor's right wall (x = +1 m): the episode ends in a
/// collision with the wall, counted as a collision and as a wall collision, not a people one.
#[test]
fn driving_into_the_corridor_wall_is_a_wall_collision() {
    let mut cfg = sim::SimConfig::default();
    cfg.robot.kinematics = Kinematics::Holonomic;
    let corridor = setting("corridor");
    let mut env = Env::new(cfg, corridor, 1000).unwrap();
    let start = env.robot().position;
    let ep = run_episode_with(
        &mut env,
        |_| RobotCommand::Velocity(Vec2::new(1.0, 0.0)),
        false,
    )
    .unwrap();
    assert_eq!(ep.summary.outcome, Outcome::Collision);
    assert!(ep.summary.wall_collision);
    let end = env.robot().position;
    assert!(end.x > start.x + 0.3 && end.x < 1.0, "{start:?} -> {end:?}");
    let mut a = Aggregate::default();
    a.add(&ep.summary);
    let r = SettingReport::new(corridor.name(), &a);
    r.check().unwrap();
    assert_eq!((r.episodes, r.collisions, r.collision), (1, 1, 1.0));
    let w = r.walls.unwrap();
    assert_eq!(
        (w.wall_collisions, w.people_collisions, w.frozen_robots),
        (1, 0, 0)
    );
    assert_eq!((w.wall_collision, w.people_collision), (1.0, 0.0));
}

#[test]
fn a_model_trained_among_walls_is_evaluated_on_its_own_setting_by_default() {
    assert_eq!(
        default_settings(setting("env2-visible")),
        Setting::ALL.to_vec()
    );
    assert_eq!(
        default_settings(setting("corridor")),
        vec![setting("corridor")]
    );
    assert_eq!(
        default_settings(setting("pillars-invisible")),
        vec![setting("pillars-invisible")]
    );
}
