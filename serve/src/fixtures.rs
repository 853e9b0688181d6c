//! What the tests of `serve` and of `fsrl serve` feed the server: the shipped model, and a
//! robot's inputs as CDR bytes (a goal, odometry, people), stamped as the caller says. Test
//! support, not part of the API.

use std::path::PathBuf;

use crate::msg::{self, Header, Odometry, People, Point, Pose, PoseStamped, Quaternion, Time};
use crate::people::{person_with_tags, PersonObs};

/// The shipped model (`models/fsrl-env1-invisible-s0.fsrlm` of this source tree).
pub fn shipped_model() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../models/fsrl-env1-invisible-s0.fsrlm")
}

/// A header in `frame` stamped `t_s`.
pub fn header(frame: &str, t_s: f64) -> Header {
    Header {
        stamp: Time::from_secs_f64(t_s),
        frame_id: frame.into(),
    }
}

/// The goal (0, 4) in `frame` stamped `t_s`.
pub fn goal(frame: &str, t_s: f64) -> Vec<u8> {
    msg::encode(&PoseStamped {
        header: header(frame, t_s),
        pose: Pose {
            position: Point {
                x: 0.0,
                y: 4.0,
                z: 0.0,
            },
            ..Pose::default()
        },
    })
    .expect("a goal encodes")
}

/// Odometry in `frame` stamped `t_s`: the robot at (0, `y`) heading +y, at rest.
pub fn odometry_at(frame: &str, t_s: f64, y: f64) -> Vec<u8> {
    let mut o = Odometry {
        header: header(frame, t_s),
        child_frame_id: "base_link".into(),
        ..Odometry::default()
    };
    o.pose.pose.position.y = y;
    o.pose.pose.orientation = Quaternion::from_yaw(std::f64::consts::FRAC_PI_2);
    msg::encode(&o).expect("odometry encodes")
}

/// Odometry at (0, −4) heading +y in `odom`, stamped `t_s`.
pub fn odometry(t_s: f64) -> Vec<u8> {
    odometry_at("odom", t_s, -4.0)
}

/// `n` people in `frame` stamped `t_s`, walking across the robot's way: person `i` (named
/// `i`) at (2 + 0.7 i, i mod 3), walking at (−0.5, 0).
pub fn people(frame: &str, t_s: f64, n: usize) -> Vec<u8> {
    let m = People {
        header: header(frame, t_s),
        people: (0..n)
            .map(|i| {
                person_with_tags(
                    i.to_string(),
                    &PersonObs::tracked(
                        sim::Vec2::new(2.0 + 0.7 * i as f64, (i % 3) as f64),
                        sim::Vec2::new(-0.5, 0.0),
                    ),
                )
            })
            .collect(),
    };
    msg::encode(&m).expect("people encode")
}
