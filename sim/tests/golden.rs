//! Golden scenarios checked by hand: one per outcome, each reward term, bit-for-bit replay, the
//! Env 3 cup, standing humans, and bad configuration.

use sim::config::ActionConfig;
use sim::reward::{dynamic_penalty, standing_penalty};
use sim::{
    evaluate_step, run_episode, Action, DynamicReading, Env, EnvError, HumanState, Outcome,
    RobotState, Scenario, Setting, SimConfig, Vec2,
};

const EPS: f64 = 1e-9;

/// A config whose action set is stop + 5 speeds straight ahead (one rotation: 0).
fn straight_config() -> SimConfig {
    let mut cfg = SimConfig::default();
    cfg.actions = ActionConfig {
        speeds: 5,
        rotations: 1,
        max_rotation_rad: 0.0,
    };
    cfg
}
/// Index of "full speed, straight ahead" in `straight_config`.
const FULL_AHEAD: usize = 5;

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

fn human(x: f64, y: f64, gx: f64, gy: f64, standing: bool) -> HumanState {
    HumanState {
        position: Vec2::new(x, y),
        velocity: Vec2::zeros(),
        goal: Vec2::new(gx, gy),
        radius_m: 0.3,
        v_pref_mps: 1.0,
        standing,
    }
}

fn env_with(cfg: SimConfig, setting: &str, robot: RobotState, humans: Vec<HumanState>) -> Env {
    Env::from_scenario(
        cfg,
        setting.parse().unwrap(),
        0,
        Scenario {
            robot,
            humans,
            walls: None,
        },
    )
    .unwrap()
}

#[test]
fn head_on_collision() {
    // A human walks straight down the robot's line at 1 m/s; the robot drives up at 1 m/s.
    // Gap 4 − 0.6 = 3.4 m closing at 2 m/s: contact at t = 1.7 s, i.e. during step 7
    // (t 1.5 → 1.75). At t = 1.5 s the centres are 1.0 m apart; the step closes 0.5 m, so the
    // swept boundary distance is 1.0 − 0.5 − 0.6 = −0.1 m.
    let mut env = env_with(
        straight_config(),
        "env1-invisible",
        robot_at(0.0, -4.0),
        vec![human(0.0, 0.0, 0.0, -10.0, false)],
    );
    let ep = run_episode(&mut env, |_| FULL_AHEAD, false).unwrap();
    assert_eq!(ep.summary.outcome, Outcome::Collision);
    assert_eq!(ep.summary.steps, 7);
    let last = ep.steps.last().unwrap().eval;
    assert!((last.closest_m + 0.1).abs() < 1e-9, "{}", last.closest_m);
    assert_eq!(last.reward.collision_goal, -0.25);
    assert!(!last.danger);
    // Step 6 (t 1.25 → 1.5) ends 0.4 m apart: no discomfort yet.
    let six = ep.steps[5].eval;
    assert!((six.closest_m - 0.4).abs() < 1e-9);
    assert_eq!(six.reward.collision_goal, 0.0);
    // And stepping a finished episode is an error, not a panic.
    assert!(matches!(
        env.step(0),
        Err(EnvError::EpisodeOver("collision"))
    ));
}

#[test]
fn clean_reach_goal() {
    // Straight up at 1 m/s from y = −4: the end position is within 0.3 m of y = 4 first after
    // 31 steps (y = 3.75), t = 7.75 s. R_c = +1, R_t = −0.1·7.75/25 = −0.031.
    // A standing human 3 m to the side never enters the 2 m effective range.
    let mut env = env_with(
        straight_config(),
        "env2-invisible",
        robot_at(0.0, -4.0),
        vec![human(3.0, 0.0, 3.0, 0.0, true)],
    );
    let ep = run_episode(&mut env, |_| FULL_AHEAD, true).unwrap();
    assert_eq!(ep.summary.outcome, Outcome::ReachGoal);
    assert_eq!(ep.summary.steps, 31);
    assert!((ep.summary.time_s - 7.75).abs() < EPS);
    assert!((ep.summary.path_length_m - 7.75).abs() < 1e-9);
    assert_eq!(ep.summary.danger_steps, 0);
    assert_eq!(ep.summary.total_abs_rotation_rad, 0.0);
    let r = ep.steps.last().unwrap().eval.reward;
    assert_eq!(r.collision_goal, 1.0);
    assert!((r.time + 0.031).abs() < 1e-12, "{}", r.time);
    assert!((r.total - 0.969).abs() < 1e-12);
    assert_eq!(r.standing, 0.0);
    assert_eq!(ep.frames.len(), 32);
    assert_eq!(ep.frames[31].humans[0], Vec2::new(3.0, 0.0));
}

#[test]
fn timeout_with_a_robot_that_stops() {
    let mut env = env_with(
        SimConfig::default(),
        "env1-invisible",
        robot_at(0.0, -4.0),
        vec![human(3.0, 3.0, -3.0, 3.0, false)],
    );
    let ep = run_episode(&mut env, |_| 0, false).unwrap();
    assert_eq!(ep.summary.outcome, Outcome::Timeout);
    assert_eq!(ep.summary.steps, 100);
    assert!((ep.summary.time_s - 25.0).abs() < EPS);
    assert_eq!(ep.summary.path_length_m, 0.0);
    let r = ep.steps.last().unwrap().eval.reward;
    assert_eq!(r.time, -0.2);
    assert_eq!(r.collision_goal, 0.0);
    assert!((r.total + 0.2).abs() < EPS);
    for s in &ep.steps[..99] {
        assert_eq!(s.eval.outcome, Outcome::Running);
        assert_eq!(s.eval.reward.time, 0.0);
    }
}

#[test]
fn discomfort_term_of_r_c() {
    // A standing human 0.7 m ahead (boundary 0.1 m) of a robot that stops: d = 0.1,
    // R_c = 0.25·(−0.1 + 0.1/2) = −0.0125 and the step is a danger step.
    let cfg = SimConfig::default();
    let robot = robot_at(0.0, 0.0);
    let humans = [human(0.0, 0.7, 0.0, 0.7, true)];
    let e = evaluate_step(&cfg, &robot, Action::STOP, &humans, &[Vec2::zeros()], 1);
    assert!((e.closest_m - 0.1).abs() < 1e-12);
    assert!((e.reward.collision_goal + 0.0125).abs() < 1e-12);
    assert!(e.danger);
    assert_eq!(e.outcome, Outcome::Running);
}

#[test]
fn foresight_terms_by_hand() {
    // SPEC §3's literal weights (the defaults are these times dt, docs/REPRODUCTION.md).
    let mut cfg = SimConfig::default();
    cfg.reward.dynamic_reading = DynamicReading::After;
    cfg.reward.standing_alpha = 0.15;
    cfg.reward.dynamic_beta = 0.5;
    let robot = robot_at(0.0, 0.0);
    let ahead = Action {
        speed_mps: 1.0,
        rotation_rad: 0.0,
    };
    let v = robot.commanded_velocity(ahead);
    // Standing: A (0, 1.5) in range and in the 2 m path → hit; B (1.5, 0) in range, passes at
    // 1.5 m → no hit; C (0, 3) out of range. N_static 2, N_col 1: R_st = −0.15·1/2 = −0.075.
    // Dynamic: D at (1, 1) moving (−0.5, 0): after 1 s D is at (0.5, 1), the robot at (0, 1),
    // boundary distance 0.5 − 0.6 = −0.1: R_dy = 0.5·(−0.1 − 0.2) = −0.15. E far away is ignored.
    let mut d = human(1.0, 1.0, -10.0, 1.0, false);
    d.velocity = Vec2::new(-0.5, 0.0);
    let humans = [
        human(0.0, 1.5, 0.0, 1.5, true),
        human(1.5, 0.0, 1.5, 0.0, true),
        human(0.0, 3.0, 0.0, 3.0, true),
        d,
        human(5.0, 5.0, -5.0, -5.0, false),
    ];
    assert!((standing_penalty(&cfg, &robot, v, &humans) + 0.075).abs() < 1e-12);
    assert!((dynamic_penalty(&cfg, &robot, v, &humans) + 0.15).abs() < 1e-12);
    let vel: Vec<Vec2> = humans.iter().map(|h| h.velocity).collect();
    let e = evaluate_step(&cfg, &robot, ahead, &humans, &vel, 1);
    // Swept closest: D, relative (1, 1) moving (−0.5, −1) for 0.25 s → |(0.875, 0.75)| − 0.6.
    let expected_closest = (0.875f64.powi(2) + 0.75f64.powi(2)).sqrt() - 0.6;
    assert!((e.closest_m - expected_closest).abs() < 1e-12);
    assert_eq!(e.reward.collision_goal, 0.0);
    assert!((e.reward.standing + 0.075).abs() < 1e-12);
    assert!((e.reward.dynamic + 0.15).abs() < 1e-12);
    assert!((e.reward.total + 0.225).abs() < 1e-12);
    // Ablation switches change the total, never the reported terms.
    cfg.reward.foresight = false;
    let e2 = evaluate_step(&cfg, &robot, ahead, &humans, &vel, 1);
    assert_eq!(e2.reward.total, 0.0);
    assert_eq!(e2.reward.standing, e.reward.standing);
    // Stopping: no standing human would be hit (R_st = 0); D after 1 s is 1.118 m away → R_dy 0.
    cfg.reward.foresight = true;
    let stop = evaluate_step(&cfg, &robot, Action::STOP, &humans, &vel, 1);
    assert_eq!(stop.reward.standing, 0.0);
    assert_eq!(stop.reward.dynamic, 0.0);
    // Without standing humans in range R_st is 0, not NaN.
    assert_eq!(standing_penalty(&cfg, &robot, v, &humans[3..]), 0.0);
}

/// The two readings of R_dy on an oncoming human 1.2 m ahead walking at the robot at 1 m/s.
/// Driving through at full speed: the snapshot after 1 s sees the human 0.8 m behind (boundary
/// 0.2 m, no penalty) while the swept minimum sees the overlap (−0.6 m: 0.5·(−0.8) = −0.4).
/// Stopping: both see the human arrive 0.2 m away (boundary −0.4 m: −0.3).
#[test]
fn dynamic_readings_on_an_oncoming_human() {
    let mut cfg = SimConfig::default();
    cfg.reward.dynamic_beta = 0.5;
    let robot = robot_at(0.0, 0.0);
    let ahead = Action {
        speed_mps: 1.0,
        rotation_rad: 0.0,
    };
    let mut h = human(0.0, 1.2, 0.0, -4.0, false);
    h.velocity = Vec2::new(0.0, -1.0);
    let humans = [h];
    let through = robot.commanded_velocity(ahead);
    let stop = Vec2::zeros();
    cfg.reward.dynamic_reading = DynamicReading::After;
    assert_eq!(dynamic_penalty(&cfg, &robot, through, &humans), 0.0);
    assert!((dynamic_penalty(&cfg, &robot, stop, &humans) + 0.3).abs() < 1e-12);
    cfg.reward.dynamic_reading = DynamicReading::Within;
    assert!((dynamic_penalty(&cfg, &robot, through, &humans) + 0.4).abs() < 1e-12);
    assert!((dynamic_penalty(&cfg, &robot, stop, &humans) + 0.3).abs() < 1e-12);
    // β scales the term linearly: the default is β·dt = 0.5·0.25.
    cfg.reward.dynamic_beta = SimConfig::default().reward.dynamic_beta;
    assert_eq!(cfg.reward.dynamic_beta, 0.125);
    assert!((dynamic_penalty(&cfg, &robot, through, &humans) + 0.1).abs() < 1e-12);
}

/// The defaults are the reading chosen by experiment (docs/REPRODUCTION.md): R_dy at t + ΔT_dy,
/// both foresight weights per step times dt; `configs/spec-literal.toml` restores SPEC's.
#[test]
fn default_foresight_weights_are_the_papers_times_dt() {
    let w = SimConfig::default().reward;
    assert_eq!(w.dynamic_reading, DynamicReading::After);
    assert_eq!(w.standing_alpha, 0.15 * 0.25);
    assert_eq!(w.dynamic_beta, 0.5 * 0.25);
    assert_eq!(w.standing_alpha, 0.0375);
}

#[test]
fn efficiency_switch() {
    let mut cfg = straight_config();
    cfg.reward.efficiency = false;
    let mut env = env_with(cfg, "env1-invisible", robot_at(0.0, -4.0), vec![]);
    let ep = run_episode(&mut env, |_| FULL_AHEAD, false).unwrap();
    let r = ep.steps.last().unwrap().eval.reward;
    assert!((r.time + 0.031).abs() < 1e-12);
    assert_eq!(r.total, 1.0);
}

#[test]
fn episodes_replay_bit_for_bit_from_their_seed() {
    for setting in Setting::ALL {
        let run = || {
            let mut env = Env::new(SimConfig::default(), setting, 1007).unwrap();
            run_episode(&mut env, |env| env.orca_robot_action(0.0), true).unwrap()
        };
        let (a, b) = (run(), run());
        assert_eq!(a, b, "{setting}");
        assert!(a.summary.steps > 0);
        // reset() reuses buffers and gives the same episode again.
        let mut env = Env::new(SimConfig::default(), setting, 5).unwrap();
        let _ = run_episode(&mut env, |env| env.orca_robot_action(0.0), false).unwrap();
        env.reset(1007).unwrap();
        let c = run_episode(&mut env, |env| env.orca_robot_action(0.0), true).unwrap();
        assert_eq!(a, c, "{setting} after reset");
    }
}

#[test]
fn env3_cup_cannot_be_crossed() {
    // Adjacent cup members are 0.67 m apart centre to centre: a 0.07 m gap for a 0.6 m robot.
    let cup = &sim::scenario::ENV3_TRAPS[..3];
    for w in cup.windows(2) {
        let gap = (Vec2::new(w[0][0], w[0][1]) - Vec2::new(w[1][0], w[1][1])).norm() - 0.6;
        assert!(gap < 0.6, "gap {gap}");
    }
    // Driving straight up anywhere across the cup's span hits it.
    let mut checked = 0;
    for k in 0..=120 {
        let x = -0.6 + k as f64 * 0.01;
        let humans = cup
            .iter()
            .map(|p| human(p[0], p[1], p[0], p[1], true))
            .collect();
        let mut env = env_with(
            straight_config(),
            "env3-invisible",
            robot_at(x, -4.0),
            humans,
        );
        let ep = run_episode(&mut env, |_| FULL_AHEAD, false).unwrap();
        assert_eq!(ep.summary.outcome, Outcome::Collision, "x = {x}");
        checked += 1;
    }
    assert_eq!(checked, 121);
}

#[test]
fn standing_humans_never_move() {
    for setting in ["env2-visible", "env3-visible", "env2-invisible"] {
        for seed in 0..20 {
            let mut env = Env::new(SimConfig::default(), setting.parse().unwrap(), seed).unwrap();
            let start: Vec<HumanState> = env.humans().to_vec();
            let ep = run_episode(&mut env, |env| env.orca_robot_action(0.0), true).unwrap();
            for f in &ep.frames {
                for (i, h) in start.iter().enumerate() {
                    if h.standing {
                        assert_eq!(f.humans[i], h.position, "{setting} seed {seed}");
                    }
                }
            }
        }
    }
}

#[test]
fn dynamic_humans_walk_to_their_goals() {
    // Without a robot in the way, ORCA humans cross the circle: most reach their goals in 25 s.
    let mut env = Env::new(SimConfig::default(), "env1-invisible".parse().unwrap(), 3).unwrap();
    let ep = run_episode(&mut env, |_| 0, true).unwrap();
    let last = ep.frames.last().unwrap();
    let arrived = env
        .humans()
        .iter()
        .zip(&last.humans)
        .filter(|(h, p)| (h.goal - **p).norm() < 0.3)
        .count();
    assert!(arrived >= 8, "only {arrived} of 10 humans arrived");
}

#[test]
fn bad_configuration_is_one_error_listing_every_problem() {
    let mut cfg = SimConfig::default();
    cfg.dt_s = -0.25;
    cfg.humans.radius_m = -1.0;
    cfg.orca.time_horizon_s = f64::NAN;
    let err = Env::new(cfg, Setting::ALL[0], 0).unwrap_err();
    let EnvError::Config(c) = err else {
        panic!("expected a config error, got {err}")
    };
    assert_eq!(c.problems.len(), 3, "{c}");
    let text = c.to_string();
    assert!(
        text.contains("dt_s")
            && text.contains("humans.radius_m")
            && text.contains("orca.time_horizon_s")
    );
    // Env 3 needs its five fixed standing humans.
    let mut cfg = SimConfig::default();
    cfg.humans.standing = 4;
    let err = Env::new(cfg, "env3-visible".parse().unwrap(), 0).unwrap_err();
    assert!(err.to_string().contains("5 fixed standing humans"), "{err}");
    // An out-of-range action is an error.
    let mut env = Env::new(SimConfig::default(), Setting::ALL[0], 0).unwrap();
    assert!(matches!(
        env.step(51),
        Err(EnvError::UnknownAction { index: 51, len: 51 })
    ));
}

#[test]
fn preview_matches_step_and_changes_nothing() {
    let mut env = Env::new(SimConfig::default(), "env2-visible".parse().unwrap(), 42).unwrap();
    for _ in 0..10 {
        let humans_before = env.humans().to_vec();
        let previews: Vec<_> = (0..51).map(|a| env.preview(a).unwrap()).collect();
        assert_eq!(env.humans(), &humans_before[..]);
        let a = env.orca_robot_action(0.0);
        let info = env.step(a).unwrap();
        assert_eq!(info.eval, previews[a]);
        if env.is_done() {
            break;
        }
    }
}
