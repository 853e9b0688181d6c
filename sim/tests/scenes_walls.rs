//! Scene files with static obstacles (issue 53): the example scenes of `examples/scenes/` parse
//! into walled scenarios and run an ORCA-robot episode to its end; every bad input is refused
//! before anything runs, with a message naming its line, its case and its obstacle or agent.

use sim::walled::fixed_map;
use sim::{
    parse_scenes, run_episode_with, Env, EnvKind, SceneError, SceneFile, SceneFormat, Setting,
    SimConfig,
};

fn example(name: &str) -> String {
    let path = format!(
        "{}/../examples/scenes/{name}.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("cannot read {path}: {e}"))
}

fn parse(text: &str) -> SceneFile {
    parse_scenes(text, &SimConfig::default()).unwrap_or_else(|e| panic!("{e}"))
}

/// The problems of a refused file, as messages.
fn problems(text: &str) -> Vec<String> {
    match parse_scenes(text, &SimConfig::default()) {
        Err(SceneError::Invalid(list)) => list.iter().map(ToString::to_string).collect(),
        Err(other) => panic!("refused, but not for its contents: {other}"),
        Ok(_) => panic!("accepted:\n{text}"),
    }
}

/// The one problem of a refused file, checked to be exactly `expected`.
fn refused(text: &str, expected: &str) {
    let list = problems(text);
    assert_eq!(list, [expected], "for\n{text}");
}

/// A case whose robot goes from (0, -4) to (0, 4), after `obstacles` (file-level TOML).
fn with_obstacles(obstacles: &str) -> String {
    format!("{obstacles}\n[[cases]]\nrobot = {{ start = [0, -4], goal = [0, 4] }}\n")
}

#[test]
fn examples_are_walled_scenes() {
    let cfg = SimConfig::default();
    for name in ["corridor", "doorway", "room", "pillars"] {
        let file = parse(&example(name));
        assert_eq!(file.format, SceneFormat::Toml, "{name}");
        assert_eq!(file.cases.len(), 1, "{name}");
        let s = &file.cases[0].scenario;
        let walls = s
            .walls
            .as_ref()
            .unwrap_or_else(|| panic!("{name} has walls"));
        assert!(walls.map().is_free(s.robot.position, s.robot.radius_m));
        assert!(!s.humans.is_empty(), "{name}");
    }
    // The corridor's and the doorway's walls are the built-in layouts' by default.
    for (name, env) in [
        ("corridor", EnvKind::Corridor),
        ("doorway", EnvKind::Doorway),
    ] {
        let file = parse(&example(name));
        let walls = file.cases[0].scenario.walls.as_ref().unwrap();
        assert_eq!(Some(walls.map()), fixed_map(&cfg, env).as_ref(), "{name}");
    }
}

#[test]
fn an_orca_robot_runs_each_example_to_its_end() {
    let cfg = SimConfig::default();
    for name in ["corridor", "doorway", "room", "pillars"] {
        let file = parse(&example(name));
        for visible in [false, true] {
            let case = &file.cases[0];
            let setting = Setting::new(EnvKind::Env1, visible);
            let mut env =
                Env::from_scenario(cfg.clone(), setting, case.case, case.scenario.clone()).unwrap();
            assert!(env.walls().is_some());
            let episode =
                run_episode_with(&mut env, |env| env.orca_robot_command(0.0), false).unwrap();
            let sum = &episode.summary;
            assert!(sum.outcome.is_terminal(), "{name} {visible}: {sum:?}");
            assert!(!sum.wall_collision, "{name} (visible {visible}): {sum:?}");
            // Nobody ends inside a wall: people keep out of the obstacles too.
            let map = env.wall_map().unwrap();
            for h in env.humans() {
                assert!(map.is_free(h.position, 0.0), "{name}: {h:?}");
            }
        }
    }
}

#[test]
fn cases_share_the_files_obstacles_and_add_their_own() {
    let text = "[[obstacles]]\nkind = \"wall\"\nvertices = [[-1, -7], [-1, 7]]\n\
                [[cases]]\nrobot = { start = [0, -4], goal = [0, 4] }\n\
                [[cases]]\nid = 7\nrobot = { start = [0, -4], goal = [0, 4], radius_m = 0.25 }\n\
                [[cases.humans]]\nstart = [0.5, 3]\ngoal = [0.5, -3]\nradius_m = 0.4\n\
                [[cases.humans]]\nstart = [-0.5, 0]\nstanding = true\n\
                [[cases.obstacles]]\nkind = \"polygon\"\nvertices = [[2, 0], [3, 0], [3, 1]]\n\
                [[cases]]\nrobot = { start = [0, -4], goal = [0, 4] }\n";
    let file = parse(text);
    let ids: Vec<(u64, usize)> = file.cases.iter().map(|c| (c.case, c.line)).collect();
    assert_eq!(ids, [(0, 4), (7, 6), (2, 19)]);
    let shapes = |k: usize| {
        file.cases[k]
            .scenario
            .walls
            .as_ref()
            .unwrap()
            .map()
            .shapes()
            .len()
    };
    assert_eq!((shapes(0), shapes(1), shapes(2)), (1, 2, 1));
    // Cases with the file's obstacles only share one set of walls.
    let (a, c) = (&file.cases[0].scenario, &file.cases[2].scenario);
    assert!(std::sync::Arc::ptr_eq(
        a.walls.as_ref().unwrap(),
        c.walls.as_ref().unwrap()
    ));
    let s = &file.cases[1].scenario;
    assert_eq!(s.robot.radius_m, 0.25);
    assert_eq!((s.humans[0].radius_m, s.humans[1].radius_m), (0.4, 0.3));
    assert!(s.humans[1].standing && s.humans[1].goal == s.humans[1].position);
    // Without obstacles, a TOML scene is an open floor.
    let open = parse("[[cases]]\nrobot = { start = [0, -4], goal = [0, 4] }\n");
    assert!(open.cases[0].scenario.walls.is_none());
}

#[test]
fn a_shape_with_too_few_vertices_is_refused() {
    let text = "[[cases]]\nrobot = { start = [0, -4], goal = [0, 4] }\n\
                [[cases.obstacles]]\nkind = \"wall\"\nvertices = [[3, 0]]\n";
    refused(
        text,
        "line 3: case 0's obstacle 0 (wall) has 1 vertex; a wall needs at least 2",
    );
    refused(
        &with_obstacles("[[obstacles]]\nkind = \"polygon\"\nvertices = [[3, 0], [4, 0]]\n"),
        "line 1: obstacle 0 (polygon) has 2 vertices; a polygon needs at least 3",
    );
}

#[test]
fn a_clockwise_polygon_is_refused() {
    refused(
        &with_obstacles(
            "[[obstacles]]\nkind = \"polygon\"\nvertices = [[2, 0], [2, 1], [3, 1], [3, 0]]\n",
        ),
        "line 1: obstacle 0 (polygon) is listed clockwise; solid polygons are listed \
         counter-clockwise",
    );
}

#[test]
fn a_counter_clockwise_boundary_is_refused() {
    refused(
        &with_obstacles(
            "[[obstacles]]\nkind = \"boundary\"\nvertices = [[-5, -5], [5, -5], [5, 5], [-5, 5]]\n",
        ),
        "line 1: obstacle 0 (boundary) is listed counter-clockwise; a bounding wall is \
         listed clockwise",
    );
}

#[test]
fn a_self_intersecting_polygon_is_refused() {
    refused(
        &with_obstacles(
            "[[obstacles]]\nkind = \"polygon\"\nvertices = [[2, 0], [3, 1], [3, 0], [2, 1]]\n",
        ),
        "line 1: obstacle 0 (polygon) crosses itself: edges 0 and 2 intersect or touch \
         (edge k runs from vertex k to the next)",
    );
}

#[test]
fn non_finite_vertices_are_refused() {
    refused(
        &with_obstacles(
            "[[obstacles]]\nkind = \"polygon\"\nvertices = [[2, 0], [nan, 0], [3, 1]]\n",
        ),
        "line 1: obstacle 0 (polygon) vertex 1 is (NaN, 0); coordinates must be finite \
         numbers",
    );
    refused(
        &with_obstacles("[[obstacles]]\nkind = \"wall\"\nvertices = [[2, 0], [2, -inf]]\n"),
        "line 1: obstacle 0 (wall) vertex 1 is (2, -inf); coordinates must be finite \
         numbers",
    );
}

#[test]
fn non_finite_starts_and_goals_are_refused() {
    refused(
        "[[cases]]\nrobot = { start = [0, -4], goal = [inf, 4] }\n",
        "line 2: case 0: the robot's goal is (inf, 4); coordinates must be finite numbers",
    );
    refused(
        "[[cases]]\nrobot = { start = [0, -4], goal = [0, 4] }\n\
         [[cases.humans]]\nstart = [nan, 1]\ngoal = [1, 1]\n",
        "line 3: case 0: human 0's start is (NaN, 1); coordinates must be finite numbers",
    );
}

#[test]
fn a_robot_start_inside_an_obstacle_is_refused() {
    refused(
        &with_obstacles(
            "[[obstacles]]\nkind = \"polygon\"\nvertices = [[-1, -5], [1, -5], [1, -3], [-1, -3]]\n",
        ),
        "line 6: case 0: the robot's start (0, -4) is inside obstacle 0 (polygon, line 1)",
    );
}

#[test]
fn a_robot_goal_overlapping_an_obstacle_by_its_radius_is_refused() {
    refused(
        &with_obstacles("[[obstacles]]\nkind = \"wall\"\nvertices = [[-1, 4.2], [1, 4.2]]\n"),
        "line 6: case 0: the robot's goal (0, 4) overlaps obstacle 0 (wall, line 1): it is \
         0.200 m from it, closer than its radius 0.3 m",
    );
}

#[test]
fn a_start_outside_a_bounding_wall_is_refused() {
    refused(
        &with_obstacles(
            "[[obstacles]]\nkind = \"boundary\"\nvertices = [[-3, -3], [-3, 5], [3, 5], [3, -3]]\n",
        ),
        "line 6: case 0: the robot's start (0, -4) is outside obstacle 0 (boundary, line 1), a \
         bounding wall whose free space is inside",
    );
}

#[test]
fn a_person_start_or_goal_inside_an_obstacle_is_refused() {
    let text = "[[cases]]\nrobot = { start = [0, -4], goal = [0, 4] }\n\
                [[cases.humans]]\nstart = [2.5, 0.5]\ngoal = [-3, 0]\n\
                [[cases.humans]]\nstart = [-3, 1]\ngoal = [3, 0]\nradius_m = 0.4\n\
                [[cases.obstacles]]\nkind = \"polygon\"\nvertices = [[2, 0], [3, 0], [3, 1], [2, 1]]\n";
    assert_eq!(
        problems(text),
        [
            "line 3: case 0: human 0's start (2.5, 0.5) is inside case 0's obstacle 0 \
             (polygon, line 10)",
            "line 6: case 0: human 1's goal (3, 0) lies on an edge of case 0's obstacle 0 \
             (polygon, line 10)",
        ]
    );
}

#[test]
fn an_unreachable_robot_goal_is_refused() {
    let refused_at_robot_line = |text: String| {
        let line = text.lines().position(|l| l.starts_with("robot")).unwrap() + 1;
        refused(
            &text,
            &format!(
                "line {line}: case 0: the robot cannot reach its goal (0, 4) from its start \
                 (0, -4): the obstacles leave no way for its radius 0.3 m (searched on a 0.1 m \
                 grid)"
            ),
        );
    };
    // A closed hall cut by a cross wall.
    let hall = "[[obstacles]]\nkind = \"boundary\"\n\
                vertices = [[-1, -7], [-1, 7], [1, 7], [1, -7]]\n";
    refused_at_robot_line(with_obstacles(&format!(
        "{hall}[[obstacles]]\nkind = \"wall\"\nvertices = [[-1, 0], [1, 0]]\n"
    )));
    // A door narrower than the robot.
    let door = |half: f64| {
        with_obstacles(&format!(
            "{hall}[[obstacles]]\nkind = \"wall\"\nvertices = [[-1, 0], [-{half}, 0]]\n\
             [[obstacles]]\nkind = \"wall\"\nvertices = [[{half}, 0], [1, 0]]\n"
        ))
    };
    refused_at_robot_line(door(0.25));
    // A door wide enough is accepted.
    parse(&door(0.5));
}

#[test]
fn every_problem_is_reported_at_once() {
    let text = "[[obstacles]]\nkind = \"polygon\"\nvertices = [[2, 0], [2, 1], [3, 1], [3, 0]]\n\
                [[cases]]\nrobot = { start = [0, -4], goal = [0, 4], radius_m = -1 }\n\
                [[cases]]\nid = 0\nrobot = { start = [0, -4], goal = [0, 4] }\n\
                [[cases.humans]]\nstart = [1, 1]\n";
    let err = parse_scenes(text, &SimConfig::default()).unwrap_err();
    assert_eq!(err.line(), Some(1));
    assert_eq!(
        err.to_string(),
        "invalid scenes (4 problems):\n  \
         - line 1: obstacle 0 (polygon) is listed clockwise; solid polygons are listed \
         counter-clockwise\n  \
         - line 5: case 0: the robot's radius_m must be a finite number > 0, got -1\n  \
         - line 6: case 0 appears again (first at line 4); case ids must differ\n  \
         - line 9: case 0: human 0 has no goal; only a standing human (standing = true) may \
         leave it out"
    );
}

#[test]
fn malformed_toml_names_its_line() {
    let cfg = SimConfig::default();
    let unknown = "[[cases]]\nrobot = { start = [0, -4], goal = [0, 4] }\n\
                   [[cases.obstacles]]\nkind = \"wall\"\nvertices = [[0, 0], [1, 0]]\ncolour = 1\n";
    let err = parse_scenes(unknown, &cfg).unwrap_err();
    assert_eq!(err.line(), Some(6), "{err}");
    assert!(err.to_string().contains("unknown field `colour`"), "{err}");
    let bad_kind = "[[obstacles]]\nkind = \"circle\"\nvertices = [[0, 0], [1, 0]]\n";
    let err = parse_scenes(bad_kind, &cfg).unwrap_err();
    assert_eq!(err.line(), Some(2), "{err}");
    assert!(err.to_string().contains("polygon"), "{err}");
    let three = "[[obstacles]]\nkind = \"wall\"\nvertices = [[0, 0, 1], [1, 0]]\n";
    let err = parse_scenes(three, &cfg).unwrap_err();
    assert_eq!(err.line(), Some(3), "{err}");
    assert_eq!(
        parse_scenes("# nothing yet\nobstacles = []\n", &cfg)
            .unwrap_err()
            .to_string(),
        "invalid scenes (1 problem):\n  - the scene file has no case (add a [[cases]] table \
         with a robot)"
    );
}
