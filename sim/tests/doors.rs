//! One-way doors (issue 53): two people meeting head-on in the doorway's 1 m door deadlock
//! under ORCA alone (neither backs out); taking turns (`sim::walled::Walls::door_turn`) lets
//! both through. The deadlock is shown with the turns switched off (`one_way_gap_m = 0`), so
//! the test fails if the turns stop working.

use std::sync::Arc;

use sim::walled::fixed_map;
use sim::{Env, EnvKind, HumanState, RobotState, Scenario, Setting, SimConfig, Vec2, Walls};

fn person(from: (f64, f64), to: (f64, f64), cfg: &SimConfig) -> HumanState {
    HumanState {
        position: Vec2::new(from.0, from.1),
        velocity: Vec2::zeros(),
        goal: Vec2::new(to.0, to.1),
        radius_m: cfg.humans.radius_m,
        v_pref_mps: cfg.humans.v_pref_mps,
        standing: false,
    }
}

/// Two people walking at each other through the door, the robot standing far off on its own
/// side; the people's positions after `seconds`.
fn meet_in_the_door(cfg: SimConfig, seconds: f64) -> Vec<Vec2> {
    let setting: Setting = "doorway".parse().unwrap();
    let map = fixed_map(&cfg, EnvKind::Doorway).unwrap();
    let walls = Walls::new(map, &cfg, cfg.roadmap_radius_m()).unwrap();
    let robot = RobotState {
        position: Vec2::new(-1.5, -6.0),
        velocity: Vec2::zeros(),
        goal: Vec2::new(-1.5, -4.0),
        heading_rad: std::f64::consts::FRAC_PI_2,
        radius_m: cfg.robot.radius_m,
        v_pref_mps: cfg.robot.v_pref_mps,
    };
    let humans = vec![
        person((0.1, -2.5), (0.0, 3.0), &cfg),
        person((-0.1, 2.5), (0.0, -3.0), &cfg),
    ];
    let scenario = Scenario {
        robot,
        humans,
        walls: Some(Arc::new(walls)),
    };
    let mut env = Env::from_scenario(cfg, setting, 0, scenario).unwrap();
    let stop = env
        .action_set()
        .nearest(env.robot().heading_rad, Vec2::zeros());
    let steps = (seconds / env.config().dt_s).round() as u32;
    for _ in 0..steps {
        assert!(
            !env.is_done(),
            "the robot stands still: the episode runs on"
        );
        env.step(stop).unwrap();
    }
    env.humans().iter().map(|h| h.position).collect()
}

#[test]
fn the_doorway_has_one_door() {
    let cfg = SimConfig::default();
    let map = fixed_map(&cfg, EnvKind::Doorway).unwrap();
    let walls = Walls::new(map, &cfg, cfg.roadmap_radius_m()).unwrap();
    let doors = walls.doors();
    assert_eq!(doors.len(), 1, "{doors:?}");
    assert!(doors[0].centre.norm() < 1e-12);
    assert!((doors[0].width_m - cfg.walls.doorway.door_width_m).abs() < 1e-12);
    // A 2 m corridor is no one-way door: two people pass each other in it.
    let map = fixed_map(&cfg, EnvKind::Corridor).unwrap();
    let walls = Walls::new(map, &cfg, cfg.roadmap_radius_m()).unwrap();
    assert!(walls.doors().is_empty());
}

#[test]
fn people_meeting_in_the_door_take_turns_instead_of_deadlocking() {
    let taking_turns = meet_in_the_door(SimConfig::default(), 20.0);
    assert!(
        taking_turns[0].y > 2.5 && taking_turns[1].y < -2.5,
        "both through the door within 20 s: {taking_turns:?}"
    );

    let mut cfg = SimConfig::default();
    cfg.walls.roadmap.one_way_gap_m = 0.0;
    let orca_alone = meet_in_the_door(cfg, 20.0);
    assert!(
        orca_alone.iter().all(|p| p.norm() < 1.5),
        "ORCA alone: both still at the door after 20 s: {orca_alone:?}"
    );
}

/// With `walls.roadmap.robot_waypoint`, the robot observes where the roadmap leads it: from
/// beside the door, behind the cross wall, a node at the door; straight below the door, its
/// goal. Without it (the default), its goal.
#[test]
fn the_robot_observes_its_waypoint_when_asked() {
    let observed = |waypoint: bool, at: (f64, f64)| {
        let mut cfg = SimConfig::default();
        cfg.walls.roadmap.robot_waypoint = waypoint;
        let setting: Setting = "doorway".parse().unwrap();
        let mut env = Env::new(cfg, setting, 7).unwrap();
        let mut scenario = Scenario {
            robot: *env.robot(),
            humans: env.humans().to_vec(),
            walls: env.walls().cloned(),
        };
        scenario.robot.position = Vec2::new(at.0, at.1);
        env.reset_to_scenario(7, scenario);
        (env.observed_goal(), env.robot().goal)
    };
    let (seen, goal) = observed(true, (-1.4, -1.0));
    assert!(
        seen.x.abs() < 0.8 && seen.y.abs() < 0.8,
        "a node at the door: {seen:?}"
    );
    assert_ne!(seen, goal);
    let (seen, goal) = observed(true, (0.0, -2.0));
    assert_eq!(seen, goal, "the goal in sight through the door");
    let (seen, goal) = observed(false, (-1.4, -1.0));
    assert_eq!(seen, goal, "off by default");
}
