//! Walls from a laser scan (`fsrl serve --scan`), the same way a map is used: a
//! `sensor_msgs/LaserScan` is checked on arrival ([`of_msg`]: its angles, its range interval,
//! one range per beam, at most `max_nan_fraction` of them NaN; a scan refused stops the robot),
//! and at each decision turned into walls ([`walls`]): the scan's points in the odometry frame
//! from the robot's pose and the sensor's place on it ([`sim::scan::points`]), the points within
//! a tracked person's radius dropped ([`sim::scan::drop_people`]: a real scan hits people, who
//! are observed as people already), consecutive points joined into wall polylines simplified
//! within a tolerance ([`sim::scan::scan_map_within`]), and [`sim::Walls`] from that map, as from `--map`.
//!
//! The stand-in publishes the scan of its scene ([`to_msg`] of [`sim::scan::simulate`]).

use sim::scan::{self, LaserScan, ScanError, ScanGeometry};
use sim::{SimConfig, Vec2, Walls, WallsError};

use crate::msg::{self, Header};
use crate::people::PersonObs;
use crate::served::RobotObs;

/// Most beams one scan may have (a 0.1° full-turn lidar has 3,600).
pub const MAX_BEAMS: usize = 1 << 16;
/// Consecutive points farther apart than this are not joined into one wall by default: 0.3 m,
/// below the robot's diameter (0.6 m), so a gap the map does not close is one the robot could
/// not pass anyway, and above the spacing of a 1° lidar's returns up to 8 m (0.14 m).
pub const DEFAULT_MAX_GAP_M: f64 = 0.3;
/// Each wall polyline of a scan is simplified within this by default (Douglas–Peucker,
/// [`sim::scan::scan_map_within`]): 2 cm, below the 1° lidar's own spacing and noise, and a
/// straight wall is one segment (a decision among a 360-point scan's walls unsimplified took
/// 58 ms with 6 people, over ten times a map's).
pub const DEFAULT_TOLERANCE_M: f64 = 0.02;
/// A wall seen on both sides of a person (the person's returns dropped between two wall
/// returns at most this far apart, the wall running straight into the shadow from both sides)
/// is taken to run on behind the person: 3 m by default. Without it the scan's walls have a
/// hole in each person's shadow where the map has its wall: served on corridor seeds
/// 1000..1499, success was the map's 0.940 with the scan of the walls alone, 0.900 with holes,
/// 0.846 bridging every shadow (a person ahead closes the corridor), 0.926 bridging straight
/// walls (docs/WALLS.md).
pub const DEFAULT_SHADOW_GAP_M: f64 = 3.0;
/// Points within a tracked person's radius plus this are the person's, not a wall's.
pub const DEFAULT_PEOPLE_MARGIN_M: f64 = 0.1;

/// How the scan is read (`fsrl serve --scan` and its flags).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanOptions {
    /// The sensor's place in the robot's base frame (x ahead, y to the left), metres.
    pub x_m: f64,
    pub y_m: f64,
    /// The sensor's yaw in the base frame (counter-clockwise).
    pub yaw_rad: f64,
    /// Consecutive points at most this far apart are one wall ([`sim::scan::scan_map`]).
    pub max_gap_m: f64,
    /// Wall polylines simplified within this ([`sim::scan::scan_map_within`]).
    pub tolerance_m: f64,
    /// Points within a person's radius plus this are dropped.
    pub people_margin_m: f64,
    /// A wall seen on both sides of a person, its returns at most this far apart, runs on
    /// behind the person (0: never).
    pub shadow_gap_m: f64,
    /// Largest fraction of NaN ranges before the scan is refused.
    pub max_nan_fraction: f64,
}

impl Default for ScanOptions {
    /// The sensor at the robot's centre facing ahead, [`DEFAULT_MAX_GAP_M`],
    /// [`DEFAULT_PEOPLE_MARGIN_M`], [`sim::scan::DEFAULT_MAX_NAN_FRACTION`].
    fn default() -> Self {
        Self {
            x_m: 0.0,
            y_m: 0.0,
            yaw_rad: 0.0,
            max_gap_m: DEFAULT_MAX_GAP_M,
            tolerance_m: DEFAULT_TOLERANCE_M,
            people_margin_m: DEFAULT_PEOPLE_MARGIN_M,
            shadow_gap_m: DEFAULT_SHADOW_GAP_M,
            max_nan_fraction: scan::DEFAULT_MAX_NAN_FRACTION,
        }
    }
}

impl ScanOptions {
    /// Every problem of the numbers, one per item, named by their flags.
    pub fn check(&self) -> Vec<String> {
        let mut problems = Vec::new();
        for (flag, v) in [
            ("--scan-x-m", self.x_m),
            ("--scan-y-m", self.y_m),
            ("--scan-yaw-rad", self.yaw_rad),
        ] {
            if !(v.is_finite() && v.abs() <= 100.0) {
                problems.push(format!(
                    "{flag} {v}: must be finite and at most 100 in size"
                ));
            }
        }
        if !(self.max_gap_m.is_finite() && self.max_gap_m > 0.0) {
            problems.push(format!(
                "--scan-max-gap-m {}: must be positive and finite",
                self.max_gap_m
            ));
        }
        if !(self.tolerance_m.is_finite() && self.tolerance_m >= 0.0) {
            problems.push(format!(
                "--scan-tolerance-m {}: must be finite and at least 0",
                self.tolerance_m
            ));
        }
        if !(self.shadow_gap_m.is_finite() && self.shadow_gap_m >= 0.0) {
            problems.push(format!(
                "--scan-shadow-gap-m {}: must be finite and at least 0",
                self.shadow_gap_m
            ));
        }
        if !(self.people_margin_m.is_finite() && self.people_margin_m >= 0.0) {
            problems.push(format!(
                "--scan-people-margin-m {}: must be finite and at least 0",
                self.people_margin_m
            ));
        }
        if !(0.0..=1.0).contains(&self.max_nan_fraction) {
            problems.push(format!(
                "--scan-max-nan-fraction {}: must be in [0, 1]",
                self.max_nan_fraction
            ));
        }
        problems
    }
}

/// Why a scan message is refused (the robot stops).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScanRefusal {
    #[error("scan angles: {0}")]
    Angles(String),
    #[error("the scan's angles give {beams} beams, more than the {MAX_BEAMS} accepted")]
    TooManyBeams { beams: f64 },
    #[error(transparent)]
    Scan(#[from] ScanError),
    #[error("walls from the scan: {0}")]
    Walls(#[from] WallsError),
}

/// The message as the simulator's scan, checked: finite angles and a non-zero increment (a
/// negative one, beams running clockwise, is turned around), as many beams as the angles give
/// (`round((angle_max − angle_min) / angle_increment) + 1`, at most [`MAX_BEAMS`]) and one
/// range each, a valid range interval, and at most `max_nan_fraction` of the ranges NaN
/// ([`sim::scan::points`]'s checks).
pub fn of_msg(m: &msg::LaserScan, max_nan_fraction: f64) -> Result<LaserScan, ScanRefusal> {
    let (lo, hi, inc) = (
        f64::from(m.angle_min),
        f64::from(m.angle_max),
        f64::from(m.angle_increment),
    );
    if !(lo.is_finite() && hi.is_finite() && inc.is_finite() && inc != 0.0) {
        return Err(ScanRefusal::Angles(format!(
            "angle_min {lo}, angle_max {hi}, angle_increment {inc}: must be finite, the increment not 0"
        )));
    }
    let steps = ((hi - lo) / inc).round();
    if steps < 0.0 {
        return Err(ScanRefusal::Angles(format!(
            "angle_max {hi} is not reached from angle_min {lo} in steps of {inc}"
        )));
    }
    if steps + 1.0 > MAX_BEAMS as f64 {
        return Err(ScanRefusal::TooManyBeams { beams: steps + 1.0 });
    }
    let beams = steps as usize + 1;
    let (angle_min, ranges) = if inc > 0.0 {
        (lo, m.ranges.clone())
    } else {
        (lo + steps * inc, m.ranges.iter().rev().copied().collect())
    };
    let geometry = ScanGeometry::new(
        angle_min,
        inc.abs(),
        f64::from(m.range_min),
        f64::from(m.range_max),
        beams,
    )?;
    let s = LaserScan { geometry, ranges };
    scan::points(&s, Vec2::zeros(), 0.0, max_nan_fraction)?;
    Ok(s)
}

/// The message of a simulated scan (the stand-in's), stamped by `header`.
pub fn to_msg(s: &LaserScan, header: Header) -> msg::LaserScan {
    let g = &s.geometry;
    msg::LaserScan {
        header,
        angle_min: g.angle_min_rad as f32,
        angle_max: g.angle_max_rad() as f32,
        angle_increment: g.angle_increment_rad as f32,
        time_increment: 0.0,
        scan_time: 0.0,
        range_min: g.range_min_m as f32,
        range_max: g.range_max_m as f32,
        ranges: s.ranges.clone(),
        intensities: Vec::new(),
    }
}

/// What one scan gave.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ScanUse {
    /// Points kept (walls).
    pub points: usize,
    /// Points dropped as people's.
    pub people_points: usize,
    /// Wall polylines.
    pub walls: usize,
}

/// The walls `s` shows, taken at the robot's pose `robot` with the sensor where `opts` puts it:
/// points, minus those of `humans` (radius as observed, else the config's), joined into walls,
/// with the people's roadmap for the config's people (as the walled settings build it).
pub fn walls(
    s: &LaserScan,
    robot: &RobotObs,
    humans: &[PersonObs],
    cfg: &SimConfig,
    opts: &ScanOptions,
) -> Result<(Walls, ScanUse), ScanRefusal> {
    let (sin, cos) = robot.heading_rad.sin_cos();
    let pose = robot.position
        + Vec2::new(
            opts.x_m * cos - opts.y_m * sin,
            opts.x_m * sin + opts.y_m * cos,
        );
    let heading = robot.heading_rad + opts.yaw_rad;
    let mut points = scan::points(s, pose, heading, opts.max_nan_fraction)?.points;
    let people: Vec<(Vec2, f64)> = humans
        .iter()
        .map(|p| (p.position, p.radius_m.unwrap_or(cfg.humans.radius_m)))
        .collect();
    let people_points = drop_people_bridging(&mut points, &people, opts);
    let map = scan::scan_map_within(&points, opts.max_gap_m, opts.tolerance_m);
    let used = ScanUse {
        points: points.len(),
        people_points,
        walls: map.shapes().len(),
    };
    let w = Walls::new(map, cfg, cfg.roadmap_radius_m())?;
    Ok((w, used))
}

/// [`sim::scan::drop_people`]'s rule (a point within a person's radius plus the margin is the
/// person's), and where a run of people's points lies between two wall points at most
/// `shadow_gap_m` apart, the wall continues straight between them: points are put along it,
/// closer than the join gap, for [`sim::scan::scan_map_within`] to join (and simplify away).
/// The number of people's points dropped.
fn drop_people_bridging(
    points: &mut Vec<Vec2>,
    people: &[(Vec2, f64)],
    opts: &ScanOptions,
) -> usize {
    let mut kept = points.clone();
    let dropped = scan::drop_people(&mut kept, people, opts.people_margin_m);
    if dropped == 0 || opts.shadow_gap_m <= 0.0 {
        *points = kept;
        return dropped;
    }
    let is_wall = |p: &Vec2| {
        people
            .iter()
            .all(|&(c, r)| (p - c).norm_squared() > (r + opts.people_margin_m).powi(2))
    };
    // The wall points, each marked when a shadow (people's points) came just before it.
    let mut walls: Vec<(Vec2, bool)> = Vec::with_capacity(kept.len());
    let mut in_shadow = false;
    for &p in points.iter() {
        if is_wall(&p) {
            walls.push((p, in_shadow));
            in_shadow = false;
        } else {
            in_shadow = true;
        }
    }
    // A shadow is bridged where the wall runs straight into it from both sides: each end's
    // neighbour within the join gap, and both ends' directions within 15° of the bridge (a
    // person ahead in a corridor shadows its far end: the wall points on either side of the
    // shadow are on the two walls, and no wall runs across).
    let straight = |a: Vec2, b: Vec2, bridge: Vec2| {
        let d = b - a;
        let n = d.norm();
        n > 0.0
            && n <= opts.max_gap_m
            && (d.perp(&bridge) / (n * bridge.norm())).abs() < 0.26
            && d.dot(&bridge) > 0.0
    };
    let step = opts.max_gap_m / 2.0;
    let mut out = Vec::with_capacity(points.len());
    for i in 0..walls.len() {
        let (p, after_shadow) = walls[i];
        if after_shadow && i >= 2 && i + 1 < walls.len() {
            let a = walls[i - 1].0;
            let bridge = p - a;
            let d = bridge.norm();
            if d <= opts.shadow_gap_m
                && d > 0.0
                && !walls[i - 1].1
                && straight(walls[i - 2].0, a, bridge)
                && straight(p, walls[i + 1].0, bridge)
            {
                let n = (d / step).ceil() as usize;
                out.extend((1..n).map(|k| a + bridge * (k as f64 / n as f64)));
            }
        }
        out.push(p);
    }
    *points = out;
    dropped
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::map::{Shape, StaticMap};

    fn corridor() -> StaticMap {
        StaticMap::new(vec![
            Shape::wall(vec![Vec2::new(-1.0, -7.0), Vec2::new(-1.0, 7.0)]),
            Shape::wall(vec![Vec2::new(1.0, 7.0), Vec2::new(1.0, -7.0)]),
        ])
        .unwrap()
    }

    fn message(ranges: Vec<f32>) -> msg::LaserScan {
        let g = ScanGeometry::default_360();
        to_msg(
            &LaserScan {
                geometry: g,
                ranges,
            },
            Header::default(),
        )
    }

    #[test]
    fn a_message_round_trips_and_a_clockwise_scan_is_turned_around() {
        let pose = Vec2::new(0.2, -1.0);
        let sim_scan = scan::simulate(&corridor(), &[], pose, 0.4, &ScanGeometry::default_360());
        let m = message(sim_scan.ranges.clone());
        let bytes = msg::encode(&m).unwrap();
        let back = of_msg(&msg::decode(&bytes).unwrap(), 0.1).unwrap();
        assert_eq!(back.geometry.beams, 360);
        assert_eq!(back.ranges, sim_scan.ranges);
        let mut cw = m.clone();
        std::mem::swap(&mut cw.angle_min, &mut cw.angle_max);
        cw.angle_increment = -cw.angle_increment;
        cw.ranges.reverse();
        let turned = of_msg(&cw, 0.1).unwrap();
        assert_eq!(turned.ranges, back.ranges);
        assert!((turned.geometry.angle_min_rad - back.geometry.angle_min_rad).abs() < 1e-5);
    }

    #[test]
    fn malformed_scans_are_refused_with_their_reason() {
        let ok = vec![2.0f32; 360];
        assert!(of_msg(&message(ok.clone()), 0.1).is_ok());
        let short = of_msg(&message(vec![2.0; 359]), 0.1).unwrap_err();
        assert!(
            matches!(
                short,
                ScanRefusal::Scan(ScanError::WrongLength {
                    expected: 360,
                    got: 359
                })
            ),
            "{short}"
        );
        let mut nan = ok.clone();
        nan[..37].fill(f32::NAN);
        let e = of_msg(&message(nan.clone()), 0.1).unwrap_err();
        assert!(
            e.to_string().contains("37 of 360 scan ranges are NaN"),
            "{e}"
        );
        nan[36] = 2.0;
        assert!(
            of_msg(&message(nan), 0.1).is_ok(),
            "36 of 360 NaN: within 10 %"
        );
        let mut m = message(ok.clone());
        m.angle_increment = 0.0;
        assert!(matches!(of_msg(&m, 0.1), Err(ScanRefusal::Angles(_))));
        m.angle_increment = 1e-9;
        assert!(matches!(
            of_msg(&m, 0.1),
            Err(ScanRefusal::TooManyBeams { .. })
        ));
        let mut m = message(ok);
        m.range_max = f32::NAN;
        assert!(matches!(
            of_msg(&m, 0.1),
            Err(ScanRefusal::Scan(ScanError::InvalidGeometry(_)))
        ));
    }

    /// A scan of a corridor with a person in it: the walls are the corridor's, the person's
    /// points dropped, and the sensor's offset and yaw on the robot are applied.
    #[test]
    fn walls_from_a_scan_are_the_corridors_without_the_person() {
        let cfg = SimConfig::default();
        let truth = corridor();
        let person = PersonObs::tracked(Vec2::new(0.3, 1.0), Vec2::zeros());
        let robot = RobotObs {
            position: Vec2::new(0.0, -1.0),
            velocity: Vec2::zeros(),
            heading_rad: std::f64::consts::FRAC_PI_2,
        };
        let opts = ScanOptions {
            x_m: 0.2,
            yaw_rad: -0.5,
            ..ScanOptions::default()
        };
        // The sensor 0.2 m ahead of the robot (ahead is +y), turned by −0.5 rad.
        let sensor = Vec2::new(0.0, -0.8);
        let s = scan::simulate(
            &truth,
            &[(person.position, cfg.humans.radius_m)],
            sensor,
            robot.heading_rad - 0.5,
            &ScanGeometry::default_360(),
        );
        let (w, used) = walls(&s, &robot, &[person], &cfg, &opts).unwrap();
        assert!(used.people_points > 5, "{used:?}");
        assert!(used.walls >= 2, "{used:?}");
        // On the walls: within f32's rounding of the ranges, or the half length of a lone
        // return's short wall (far along the corridor the beams graze the walls far apart).
        for shape in w.map().shapes() {
            for v in &shape.vertices {
                let tol = 1e-4 + sim::scan::SCAN_POLE_HALF_M;
                assert!(truth.distance_m(*v) < tol, "{v:?} is not on a wall");
            }
        }
        // Without dropping the person, its points would be walls too.
        let (blind, _) = walls(&s, &robot, &[], &cfg, &opts).unwrap();
        assert!(blind.map().distance_m(person.position) < 0.31);
        assert!(w.map().distance_m(person.position) > 0.5);
    }

    /// A person beside a wall: the wall runs on behind the person (one wall where a hole
    /// would split it); a person ahead in the corridor shadows its far end, and no wall is put
    /// across the corridor.
    #[test]
    fn a_wall_runs_on_behind_a_person_but_never_across_the_corridor() {
        let cfg = SimConfig::default();
        let truth = corridor();
        let robot = RobotObs {
            position: Vec2::new(0.0, -3.0),
            velocity: Vec2::zeros(),
            heading_rad: std::f64::consts::FRAC_PI_2,
        };
        let beside = PersonObs::tracked(Vec2::new(0.6, -2.0), Vec2::zeros());
        let ahead = PersonObs::tracked(Vec2::new(0.0, 0.0), Vec2::zeros());
        let people = [beside, ahead];
        let discs: Vec<(Vec2, f64)> = people
            .iter()
            .map(|p| (p.position, cfg.humans.radius_m))
            .collect();
        let s = scan::simulate(
            &truth,
            &discs,
            robot.position,
            robot.heading_rad,
            &ScanGeometry::default_360(),
        );
        let bridged = walls(&s, &robot, &people, &cfg, &ScanOptions::default())
            .unwrap()
            .0;
        let holes = ScanOptions {
            shadow_gap_m: 0.0,
            ..ScanOptions::default()
        };
        let holed = walls(&s, &robot, &people, &cfg, &holes).unwrap().0;
        // Behind the person beside it, the right wall (x = 1) is in the map only when bridged.
        let behind = Vec2::new(1.0, -1.7);
        assert!(holed.map().distance_m(behind) > 0.05);
        assert!(bridged.map().distance_m(behind) < 0.03);
        for s in bridged.map().segments() {
            assert!(
                (s.a.x - s.b.x).abs() < 0.3,
                "{s:?} runs across the corridor"
            );
            assert!(truth.distance_m(s.a) < 0.03 && truth.distance_m(s.b) < 0.03);
        }
    }
}
