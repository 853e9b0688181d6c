//! `fsrl serve` among walls (issue 53), its refusals: a `--map` file with a bad shape is refused
//! with the file, line and obstacle named before anything starts (the model is not even
//! opened), as is `--map` with `--scan`; a malformed laser scan (NaN ranges beyond the allowed
//! fraction, the wrong number of ranges) is counted and stops the robot at once, saying why,
//! and so does a scan that stops coming, rather than letting the robot drive on blind. The
//! closed loops among walls (`--map` against `fsrl eval`, `--scan`) are in `serve.rs`.

mod net_support;
mod serve_support;

use std::process::Command;
use std::time::Duration;

use net_support::free_port;
use serve::msg;
use serve_support::{goal, moving, now_s, odometry, people, zero, Robot, Served};
use sim::map::{Shape, StaticMap};
use sim::scan::ScanGeometry;
use sim::Vec2;

fn fsrl_serve(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .arg("serve")
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn a_bad_map_is_refused_with_its_file_line_and_shape_before_anything_starts() {
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("office.toml");
    // Obstacle 1 is listed clockwise; obstacle 2 has one vertex; obstacle 3 crosses itself.
    std::fs::write(
        &map,
        "[[obstacles]]\nkind = \"wall\"\nvertices = [[-1, -7], [-1, 7]]\n\n\
         [[obstacles]]\nkind = \"polygon\"\nvertices = [[0, 0], [0, 1], [1, 1], [1, 0]]\n\n\
         [[obstacles]]\nkind = \"wall\"\nvertices = [[2, 2]]\n\n\
         [[obstacles]]\nkind = \"polygon\"\nvertices = [[0, 3], [1, 4], [1, 3], [0, 4]]\n",
    )
    .unwrap();
    let map_arg = map.to_str().unwrap();
    // The model does not exist: the map is refused before it would be opened.
    let out = fsrl_serve(&["no-such-model.fsrlm", "--map", map_arg]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).is_empty(), "ready?");
    for part in [
        &format!("--map {map_arg}"),
        "line 5: obstacle 1 (polygon) is listed clockwise",
        "line 9: obstacle 2 (wall) has 1 vertex",
        "line 13: obstacle 3 (polygon) crosses itself",
    ] {
        assert!(err.contains(part), "{part:?} not in:\n{err}");
    }
    assert!(
        !err.contains("no-such-model"),
        "the model was looked at:\n{err}"
    );

    // A file that is not one, and one without obstacles.
    std::fs::write(
        &map,
        "[[cases]]\nrobot = { start = [0, -4], goal = [0, 4] }\n",
    )
    .unwrap();
    let err =
        String::from_utf8_lossy(&fsrl_serve(&["m.fsrlm", "--map", map_arg]).stderr).into_owned();
    assert!(err.contains("unknown field `cases`"), "{err}");
    std::fs::write(&map, "# nothing\n").unwrap();
    let err =
        String::from_utf8_lossy(&fsrl_serve(&["m.fsrlm", "--map", map_arg]).stderr).into_owned();
    assert!(err.contains("the map file has no obstacle"), "{err}");
    let err =
        String::from_utf8_lossy(&fsrl_serve(&["m.fsrlm", "--map", "/no/such/map.toml"]).stderr)
            .into_owned();
    assert!(
        err.contains("--map /no/such/map.toml: cannot read it"),
        "{err}"
    );

    // --map with --scan, and bad scan numbers: refused in one line, naming the flags.
    std::fs::write(
        &map,
        "[[obstacles]]\nkind = \"wall\"\nvertices = [[-1, -7], [-1, 7]]\n",
    )
    .unwrap();
    let out = fsrl_serve(&[
        "m.fsrlm",
        "--map",
        map_arg,
        "--scan",
        "--scan-max-gap-m",
        "0",
        "--scan-max-nan-fraction",
        "2",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    for part in [
        "--map and --scan together: choose one",
        "--scan-max-gap-m 0",
        "--scan-max-nan-fraction 2",
    ] {
        assert!(err.contains(part), "{part:?} not in:\n{err}");
    }
}

/// The scan a robot at (0, −4) heading +y reads in a 3 m wide corridor (the fixtures'
/// odometry), stamped `t_s` in `base_link`; its ranges as `edit` leaves them.
fn scan(t_s: f64, edit: impl FnOnce(&mut Vec<f32>)) -> Vec<u8> {
    let corridor = StaticMap::new(vec![
        Shape::wall(vec![Vec2::new(-1.5, -10.0), Vec2::new(-1.5, 10.0)]),
        Shape::wall(vec![Vec2::new(1.5, 10.0), Vec2::new(1.5, -10.0)]),
    ])
    .unwrap();
    let mut s = sim::scan::simulate(
        &corridor,
        &[],
        Vec2::new(0.0, -4.0),
        std::f64::consts::FRAC_PI_2,
        &ScanGeometry::default_360(),
    );
    edit(&mut s.ranges);
    let header = serve::fixtures::header("base_link", t_s);
    msg::encode(&serve::scan::to_msg(&s, header)).unwrap()
}

#[test]
fn a_malformed_or_missing_scan_stops_the_robot_and_is_counted() {
    let port = free_port();
    let mut serve = Served::shipped(port, &["--scan"]);
    let robot = Robot::connect(&format!("tcp/127.0.0.1:{port}"));
    let within = Duration::from_secs(10);
    let inputs = |scan_bytes: Option<Vec<u8>>| {
        let t = now_s();
        robot.put("goal_pose", goal("odom", t));
        robot.put("people", people("odom", t, 1));
        if let Some(b) = scan_bytes {
            robot.put("scan", b);
        }
        robot.put("odom", odometry(t));
    };
    // Goal, people and odometry but no scan: a stop, no scan yet.
    robot.until("a stop without a scan", || inputs(None), zero);
    serve.skip_log();
    let phase = |what: &str, edit: fn(&mut Vec<f32>), reason: &str| {
        robot.until(
            "driving with a good scan",
            || inputs(Some(scan(now_s(), |_| {}))),
            moving,
        );
        serve.wait_log("driving", within);
        robot.drain();
        robot.until(what, || inputs(Some(scan(now_s(), edit))), zero);
        let got = serve.next_stop_reason(within);
        assert!(
            got.contains(reason),
            "{what}: the zero command says {got:?}"
        );
    };
    phase(
        "NaN ranges",
        |r| r[..40].fill(f32::NAN),
        "scan refused, not driving blind: 40 of 360 scan ranges are NaN",
    );
    phase(
        "a range short",
        |r| {
            r.pop();
        },
        "scan refused, not driving blind: the scan has 359 ranges but its geometry has 360 beams",
    );
    // Undecodable bytes are counted; the last good scan goes stale.
    robot.until(
        "driving with a good scan",
        || inputs(Some(scan(now_s(), |_| {}))),
        moving,
    );
    robot.drain();
    serve.skip_log();
    robot.until(
        "a stale scan",
        || inputs(Some(b"\x00\x01\x00\x00junk".to_vec())),
        zero,
    );
    assert!(serve
        .next_stop_reason(within)
        .contains("the laser scan is stale"));

    assert!(serve.terminate().success());
    let stopped = serve.wait_log("stopped", within);
    let count = |name: &str| -> u64 {
        serve_support::summary_field(&stopped, name)
            .unwrap_or_else(|| panic!("no {name} in {stopped}"))
    };
    assert!(count("refused_scans") >= 2, "{stopped}");
    assert!(count("undecodable_scans") >= 1, "{stopped}");
    assert!(count("scans") >= 3, "{stopped}");
}
