//! Laser scans: simulated from a map, read from a sensor, reduced to obstacle points (issue 53).
//!
//! A [`LaserScan`] mirrors ROS `sensor_msgs/LaserScan`: `f32` ranges, beam `i` at angle
//! `angle_min_rad + i·angle_increment_rad` in the sensor frame (x ahead, counter-clockwise),
//! the sensor at the robot's centre facing its heading. Ranges follow REP 117: `+inf` means no
//! return within range, `-inf` an object closer than `range_min_m`, NaN an erroneous reading.
//!
//! The obstacle observation is computed the same way from a map and from a real scan:
//! [`simulate`] (or a sensor) → [`points`] → [`drop_people`] → [`sector_nearest`]; and
//! [`map_sector_nearest`] computes exactly from the map geometry what a dense scan approaches.

use std::f64::consts::{PI, TAU};

use crate::geom::{heading, Vec2};
use crate::map::{cross, Defect, MapError, Segment, Shape, StaticMap};

/// Default largest fraction of NaN ranges [`points`] accepts: above it the scan is refused, so
/// that the robot stops rather than driving blind.
pub const DEFAULT_MAX_NAN_FRACTION: f64 = 0.1;

/// Where a scan's beams point and which ranges count as returns.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanGeometry {
    /// Angle of beam 0 in the sensor frame (0 straight ahead, counter-clockwise positive).
    pub angle_min_rad: f64,
    /// Angle between consecutive beams (positive: beams run counter-clockwise).
    pub angle_increment_rad: f64,
    /// Shortest range the sensor reports; nearer returns are `-inf`.
    pub range_min_m: f64,
    /// Longest range the sensor reports; no return within it is `+inf`.
    pub range_max_m: f64,
    /// Number of beams, and of ranges in a scan.
    pub beams: usize,
}

impl ScanGeometry {
    /// A checked geometry: `beams` ≥ 1, a finite `angle_min_rad`, a finite positive increment,
    /// and 0 ≤ `range_min_m` < `range_max_m`, both finite. Every problem is reported at once.
    pub fn new(
        angle_min_rad: f64,
        angle_increment_rad: f64,
        range_min_m: f64,
        range_max_m: f64,
        beams: usize,
    ) -> Result<ScanGeometry, ScanError> {
        let g = ScanGeometry {
            angle_min_rad,
            angle_increment_rad,
            range_min_m,
            range_max_m,
            beams,
        };
        g.validate()?;
        Ok(g)
    }

    /// `beams` beams evenly over a full turn, beam 0 straight behind (−π), as a 360° lidar.
    pub fn full_turn(
        beams: usize,
        range_min_m: f64,
        range_max_m: f64,
    ) -> Result<ScanGeometry, ScanError> {
        ScanGeometry::new(
            -PI,
            TAU / beams.max(1) as f64,
            range_min_m,
            range_max_m,
            beams,
        )
    }

    /// 360 beams (1° apart) over a full turn, ranges 0.05–8 m: the class of the common 2-D
    /// 360° lidars on small indoor robots (RPLIDAR A1/A2, LDS-01: 1° steps, 0.12–0.15 m
    /// minimum, 3.5–12 m maximum), with a range that covers the simulated scenes' rooms and
    /// corridors from any point and a minimum below the robot's radius.
    pub fn default_360() -> ScanGeometry {
        ScanGeometry {
            angle_min_rad: -PI,
            angle_increment_rad: TAU / 360.0,
            range_min_m: 0.05,
            range_max_m: 8.0,
            beams: 360,
        }
    }

    /// Checks the geometry (the fields are public), reporting every problem at once.
    pub fn validate(&self) -> Result<(), ScanError> {
        let mut problems = Vec::new();
        if self.beams == 0 {
            problems.push("beams must be at least 1, got 0".to_string());
        }
        if !self.angle_min_rad.is_finite() {
            problems.push(format!(
                "angle_min_rad must be finite, got {}",
                self.angle_min_rad
            ));
        }
        if !(self.angle_increment_rad.is_finite() && self.angle_increment_rad > 0.0) {
            problems.push(format!(
                "angle_increment_rad must be positive and finite, got {}",
                self.angle_increment_rad
            ));
        }
        if !(self.range_min_m.is_finite() && self.range_min_m >= 0.0) {
            problems.push(format!(
                "range_min_m must be non-negative and finite, got {}",
                self.range_min_m
            ));
        }
        if !self.range_max_m.is_finite() {
            problems.push(format!(
                "range_max_m must be finite, got {}",
                self.range_max_m
            ));
        } else if self.range_min_m.is_finite() && self.range_max_m <= self.range_min_m {
            problems.push(format!(
                "range_max_m ({}) must exceed range_min_m ({})",
                self.range_max_m, self.range_min_m
            ));
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(ScanError::InvalidGeometry(problems))
        }
    }

    /// Angle of beam `i` in the sensor frame.
    pub fn beam_angle_rad(&self, i: usize) -> f64 {
        self.angle_min_rad + i as f64 * self.angle_increment_rad
    }

    /// Angle of the last beam in the sensor frame (ROS's `angle_max`).
    pub fn angle_max_rad(&self) -> f64 {
        self.beam_angle_rad(self.beams.saturating_sub(1))
    }
}

/// One sweep of ranges, as `sensor_msgs/LaserScan` carries it.
#[derive(Debug, Clone, PartialEq)]
pub struct LaserScan {
    /// Beam angles and valid range interval.
    pub geometry: ScanGeometry,
    /// One range per beam, metres; REP 117's ±inf and NaN as described in the module docs.
    pub ranges: Vec<f32>,
}

/// The world-frame points of a scan's valid returns, and how many beams gave none.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ScanPoints {
    /// Hit points in beam order.
    pub points: Vec<Vec2>,
    /// Beams whose range is NaN (erroneous readings).
    pub nan_beams: usize,
    /// Beams with no return: ±inf, or outside [range_min_m, range_max_m].
    pub out_of_range_beams: usize,
}

/// A scan or scan geometry refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScanError {
    #[error("invalid scan geometry: {}", .0.join("; "))]
    InvalidGeometry(Vec<String>),
    #[error("the scan has {got} ranges but its geometry has {expected} beams")]
    WrongLength { expected: usize, got: usize },
    #[error("{nan_beams} of {beams} scan ranges are NaN, more than the {:.1} % allowed; the scan is refused rather than driven on blind", max_fraction * 100.0)]
    TooManyInvalid {
        nan_beams: usize,
        beams: usize,
        max_fraction: f64,
    },
    #[error("the largest NaN fraction must be in [0, 1], got {0}")]
    BadThreshold(f64),
}

/// Simulates a scan from `pose` facing `heading_rad`: each beam is cast against the map's
/// segments and the people's discs `(centre, radius_m)`, and reports the nearest hit;
/// deterministic, without noise. No hit within `range_max_m` gives `+inf`, a hit nearer than
/// `range_min_m` gives `-inf` (REP 117). A sensor inside a disc reads 0 there (so `-inf`).
/// The geometry is expected to be valid ([`ScanGeometry::validate`]).
pub fn simulate(
    map: &StaticMap,
    people: &[(Vec2, f64)],
    pose: Vec2,
    heading_rad: f64,
    geometry: &ScanGeometry,
) -> LaserScan {
    let range_max = geometry.range_max_m;
    let ranges = (0..geometry.beams)
        .map(|i| {
            let dir = heading(heading_rad + geometry.beam_angle_rad(i));
            let mut hit = map.ray_hit_m(pose, dir, range_max);
            for &(centre, radius_m) in people {
                if let Some(t) = ray_disc_m(pose, dir, centre, radius_m) {
                    if t <= range_max && hit.is_none_or(|h| t < h) {
                        hit = Some(t);
                    }
                }
            }
            match hit {
                None => f32::INFINITY,
                Some(t) if t < geometry.range_min_m => f32::NEG_INFINITY,
                Some(t) => t as f32,
            }
        })
        .collect();
    LaserScan {
        geometry: *geometry,
        ranges,
    }
}

/// Distance along the ray `origin + t·dir` (unit `dir`, t ≥ 0) to the disc, 0 from inside.
fn ray_disc_m(origin: Vec2, dir: Vec2, centre: Vec2, radius_m: f64) -> Option<f64> {
    let w = origin - centre;
    let c = w.norm_squared() - radius_m * radius_m;
    if c <= 0.0 {
        return Some(0.0);
    }
    let b = w.dot(&dir);
    let disc = b * b - c;
    if disc < 0.0 || b > 0.0 {
        // Missed, or the disc is behind.
        return None;
    }
    Some(-b - disc.sqrt())
}

/// The world-frame points of the valid returns of `scan`, taken from `pose` facing
/// `heading_rad`. Beams with ±inf or a range outside [range_min_m, range_max_m] are "no
/// return" (counted, not errors); NaN beams are counted. Refused: an invalid geometry, a
/// number of ranges other than the geometry's beams, a `max_nan_fraction` outside [0, 1], and
/// a scan with more than `max_nan_fraction` of its beams NaN (see
/// [`DEFAULT_MAX_NAN_FRACTION`]), so that the robot stops rather than driving blind.
pub fn points(
    scan: &LaserScan,
    pose: Vec2,
    heading_rad: f64,
    max_nan_fraction: f64,
) -> Result<ScanPoints, ScanError> {
    let g = &scan.geometry;
    g.validate()?;
    if !(0.0..=1.0).contains(&max_nan_fraction) {
        return Err(ScanError::BadThreshold(max_nan_fraction));
    }
    if scan.ranges.len() != g.beams {
        return Err(ScanError::WrongLength {
            expected: g.beams,
            got: scan.ranges.len(),
        });
    }
    let nan_beams = scan.ranges.iter().filter(|r| r.is_nan()).count();
    if nan_beams as f64 > max_nan_fraction * g.beams as f64 {
        return Err(ScanError::TooManyInvalid {
            nan_beams,
            beams: g.beams,
            max_fraction: max_nan_fraction,
        });
    }
    // Compared in f32, as the ranges were rounded to it.
    let (lo, hi) = (g.range_min_m as f32, g.range_max_m as f32);
    let mut out = ScanPoints {
        points: Vec::with_capacity(g.beams),
        nan_beams,
        out_of_range_beams: 0,
    };
    for (i, &r) in scan.ranges.iter().enumerate() {
        if r.is_nan() {
            continue;
        }
        if !(lo..=hi).contains(&r) {
            out.out_of_range_beams += 1;
            continue;
        }
        let dir = heading(heading_rad + g.beam_angle_rad(i));
        out.points.push(pose + dir * f64::from(r));
    }
    Ok(out)
}

/// Removes the points within `radius_m + margin_m` of a tracked person `(centre, radius_m)`
/// (a real scan also hits people, who are observed as people already); returns how many.
pub fn drop_people(points: &mut Vec<Vec2>, people: &[(Vec2, f64)], margin_m: f64) -> usize {
    let before = points.len();
    points.retain(|p| {
        people
            .iter()
            .all(|&(c, r)| (p - c).norm_squared() > (r + margin_m) * (r + margin_m))
    });
    before - points.len()
}

/// Angular width of one of `sectors` equal sectors.
fn sector_width_rad(sectors: usize) -> f64 {
    TAU / sectors as f64
}

/// For each of `sectors` equal angular sectors around `pose` (sector 0 centred on
/// `heading_rad`, numbered counter-clockwise; each covers [centre − w/2, centre + w/2)), the
/// nearest of `points` within `max_range_m`, or None. A point at `pose` itself counts in
/// sector 0. Of equally near points, the first.
pub fn sector_nearest(
    points: &[Vec2],
    pose: Vec2,
    heading_rad: f64,
    sectors: usize,
    max_range_m: f64,
) -> Vec<Option<Vec2>> {
    if sectors == 0 {
        return Vec::new();
    }
    let mut best: Vec<Option<(f64, Vec2)>> = vec![None; sectors];
    let w = sector_width_rad(sectors);
    let max2 = max_range_m * max_range_m;
    for &p in points {
        let d = p - pose;
        let d2 = d.norm_squared();
        if d2.is_nan() || d2 > max2 {
            continue;
        }
        let rel = d.y.atan2(d.x) - heading_rad + w / 2.0;
        let k = ((rel.rem_euclid(TAU) / w) as usize).min(sectors - 1);
        if best[k].is_none_or(|(b, _)| d2 < b) {
            best[k] = Some((d2, p));
        }
    }
    best.into_iter().map(|b| b.map(|(_, p)| p)).collect()
}

/// What [`sector_nearest`] approaches for a dense scan, computed exactly from the map: for
/// each sector (as there), the point of the map's segments nearest to `pose` within the
/// sector's wedge and within `max_range_m`, or None. The nearest point of a wedge is always in
/// sight of `pose`, so a scan sees it. A point on the line between two sectors counts in both.
pub fn map_sector_nearest(
    map: &StaticMap,
    pose: Vec2,
    heading_rad: f64,
    sectors: usize,
    max_range_m: f64,
) -> Vec<Option<Vec2>> {
    if sectors == 0 {
        return Vec::new();
    }
    let w = sector_width_rad(sectors);
    let max2 = max_range_m * max_range_m;
    (0..sectors)
        .map(|k| {
            let centre = heading_rad + k as f64 * w;
            // The wedge between its lower and upper edge rays (convex for sectors ≥ 2; the
            // whole plane for one sector).
            let edges =
                (sectors > 1).then(|| (heading(centre - w / 2.0), heading(centre + w / 2.0)));
            let mut best: Option<(f64, Vec2)> = None;
            for s in map.segments() {
                if let Some(q) = closest_in_wedge(s, pose, edges) {
                    let d2 = (q - pose).norm_squared();
                    if d2 <= max2 && best.is_none_or(|(b, _)| d2 < b) {
                        best = Some((d2, q));
                    }
                }
            }
            best.map(|(_, q)| q)
        })
        .collect()
}

/// The point of `s` nearest to `apex` among those in the wedge left of `lower` and right of
/// `upper` (rays from `apex`; a wedge of at most π), or in the whole plane for None.
fn closest_in_wedge(s: &Segment, apex: Vec2, edges: Option<(Vec2, Vec2)>) -> Option<Vec2> {
    let a = s.a - apex;
    let e = s.b - s.a;
    let (mut t_lo, mut t_hi) = (0.0f64, 1.0f64);
    if let Some((lower, upper)) = edges {
        // Each constraint g0 + t·g1 ≥ 0 on the segment's parameter t.
        for (g0, g1) in [
            (cross(lower, a), cross(lower, e)),
            (-cross(upper, a), -cross(upper, e)),
        ] {
            if g1 == 0.0 {
                if g0 < 0.0 {
                    return None;
                }
            } else if g1 > 0.0 {
                t_lo = t_lo.max(-g0 / g1);
            } else {
                t_hi = t_hi.min(-g0 / g1);
            }
        }
        if t_lo > t_hi {
            return None;
        }
    }
    let ee = e.norm_squared();
    let t = if ee == 0.0 {
        t_lo
    } else {
        (-a.dot(&e) / ee).clamp(t_lo, t_hi)
    };
    Some(s.a + e * t)
}

/// Points nearer than this to the last point kept are duplicates: [`scan_map`] skips them
/// (a repeated vertex would be a zero-length edge; 0.1 mm is below what a lidar resolves).
pub const SCAN_DUPLICATE_M: f64 = 1.0e-4;
/// Half the length of the short wall [`scan_map`] puts at a point with no neighbour within the
/// gap (a thin pole, a chair leg: one return is an obstacle too).
pub const SCAN_POLE_HALF_M: f64 = 0.005;

/// The walls a scan shows, as a map: consecutive points (in beam order) closer than
/// `max_gap_m` are joined into one wall polyline, a farther one starts the next polyline. A
/// point within [`SCAN_DUPLICATE_M`] of the last point kept is skipped, as is a point that is
/// not finite; a point alone (no neighbour within the gap) becomes a wall
/// 2·[`SCAN_POLE_HALF_M`] long centred on it. A polyline that would cross or fold back on
/// itself (points of several sensors, noise along a line seen edge-on) is cut there into
/// polylines that do not, so the map is always valid ([`StaticMap::new`]); shapes may overlap.
/// A `max_gap_m` that is not a positive number joins nothing.
pub fn scan_map(points: &[Vec2], max_gap_m: f64) -> StaticMap {
    scan_map_within(points, max_gap_m, 0.0)
}

/// [`scan_map`] with each polyline simplified within `tolerance_m` (Douglas–Peucker: a vertex
/// is kept where leaving it out would move the wall by more than the tolerance; the ends are
/// always kept): a 360-beam scan of a corridor's straight wall is one segment, not hundreds,
/// and every later use of the map (RVO2's obstacles, the sensor's sectors, contact) costs by
/// segment. Every point of the scan stays within `tolerance_m` of the map. A tolerance that is
/// not a positive number keeps every vertex.
pub fn scan_map_within(points: &[Vec2], max_gap_m: f64, tolerance_m: f64) -> StaticMap {
    let mut chains: Vec<Vec<Vec2>> = Vec::new();
    let mut last: Option<Vec2> = None;
    for &p in points {
        if !(p.x.is_finite() && p.y.is_finite()) {
            continue;
        }
        match last {
            Some(q) if (p - q).norm() <= SCAN_DUPLICATE_M => continue,
            Some(q) if (p - q).norm() <= max_gap_m => {
                chains.last_mut().expect("a chain is open").push(p);
            }
            _ => chains.push(vec![p]),
        }
        last = Some(p);
    }
    if tolerance_m > 0.0 {
        for c in &mut chains {
            *c = simplified(c, tolerance_m);
        }
    }
    let pole = Vec2::new(SCAN_POLE_HALF_M, 0.0);
    let mut shapes: Vec<Shape> = chains
        .into_iter()
        .map(|c| match c[..] {
            [p] => Shape::wall(vec![p - pole, p + pole]),
            _ => Shape::wall(c),
        })
        .collect();
    // Each round cuts every faulty polyline once, at the later vertex of its first problem:
    // every piece keeps at least two vertices, and the rounds end (at worst one edge each).
    loop {
        let problems = match StaticMap::new(shapes.clone()) {
            Ok(map) => return map,
            Err(MapError::Invalid(problems)) => problems,
            Err(other) => unreachable!("StaticMap::new refuses only with Invalid: {other}"),
        };
        let mut cut_at: Vec<Option<usize>> = vec![None; shapes.len()];
        for p in &problems {
            let at = match p.defect {
                Defect::SelfIntersection { edges: (i, j) }
                | Defect::FoldsBack { edges: (i, j) } => i.max(j),
                // Skipped duplicates and finite points leave no other defect in a polyline;
                // should one come, the shape is cut into its edges.
                _ => 1,
            };
            cut_at[p.shape].get_or_insert(at.max(1));
        }
        let mut next = Vec::with_capacity(shapes.len() + problems.len());
        for (shape, cut) in shapes.into_iter().zip(cut_at) {
            match cut {
                Some(j) if j + 1 < shape.vertices.len() => {
                    next.push(Shape::wall(shape.vertices[..=j].to_vec()));
                    next.push(Shape::wall(shape.vertices[j..].to_vec()));
                }
                Some(_) => {
                    next.extend(shape.vertices.windows(2).map(|w| Shape::wall(w.to_vec())));
                }
                None => next.push(shape),
            }
        }
        shapes = next;
    }
}

/// Douglas–Peucker: the vertices of `chain` that keep every vertex within `tolerance_m` of
/// the polyline, the ends always.
fn simplified(chain: &[Vec2], tolerance_m: f64) -> Vec<Vec2> {
    let n = chain.len();
    if n <= 2 {
        return chain.to_vec();
    }
    let mut keep = vec![false; n];
    keep[0] = true;
    keep[n - 1] = true;
    let mut stack = vec![(0, n - 1)];
    while let Some((a, b)) = stack.pop() {
        let seg = Segment {
            a: chain[a],
            b: chain[b],
        };
        let far = (a + 1..b)
            .map(|i| (seg.distance_m(chain[i]), i))
            .max_by(|x, y| x.0.total_cmp(&y.0));
        if let Some((d, i)) = far {
            if d > tolerance_m {
                keep[i] = true;
                stack.push((a, i));
                stack.push((i, b));
            }
        }
    }
    chain
        .iter()
        .zip(keep)
        .filter_map(|(p, k)| k.then_some(*p))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::tests::{corridor, room_with_box};

    fn v(x: f64, y: f64) -> Vec2 {
        Vec2::new(x, y)
    }

    /// Beam index of sensor angle `deg` in the default 360-beam geometry.
    fn beam(deg: i32) -> usize {
        (deg + 180) as usize
    }

    #[test]
    fn geometry_validated_with_every_problem() {
        let err = ScanGeometry::new(f64::NAN, 0.0, -1.0, f64::INFINITY, 0).unwrap_err();
        let ScanError::InvalidGeometry(problems) = &err else {
            panic!("{err}")
        };
        assert_eq!(problems.len(), 5, "{err}");
        assert_eq!(
            ScanGeometry::new(0.0, 0.01, 5.0, 2.0, 10)
                .unwrap_err()
                .to_string(),
            "invalid scan geometry: range_max_m (2) must exceed range_min_m (5)"
        );
        assert!(ScanGeometry::new(0.0, 0.01, 0.0, 2.0, 1).is_ok());
        let g = ScanGeometry::default_360();
        assert_eq!(g.validate(), Ok(()));
        assert_eq!(ScanGeometry::full_turn(360, 0.05, 8.0), Ok(g));
        assert!((g.angle_max_rad() - (PI - TAU / 360.0)).abs() < 1e-12);
        assert!(g.beam_angle_rad(beam(0)).abs() < 1e-12);
    }

    #[test]
    fn corridor_scan_sees_walls_one_metre_each_side() {
        let map = corridor();
        let g = ScanGeometry::default_360();
        let scan = simulate(&map, &[], v(0.0, 0.0), 0.0, &g);
        assert_eq!(scan.ranges.len(), 360);
        assert!((scan.ranges[beam(90)] - 1.0).abs() < 1e-6);
        assert!((scan.ranges[beam(-90)] - 1.0).abs() < 1e-6);
        assert!((f64::from(scan.ranges[beam(45)]) - 2f64.sqrt()).abs() < 1e-6);
        // Along the corridor: nothing within 8 m.
        assert_eq!(scan.ranges[beam(0)], f32::INFINITY);
        assert_eq!(scan.ranges[beam(-180)], f32::INFINITY);
        // Turned by 90°, the sensor frame turns with it.
        let scan = simulate(&map, &[], v(0.0, 0.5), PI / 2.0, &g);
        assert!((scan.ranges[beam(0)] - 0.5).abs() < 1e-6);
        assert!((scan.ranges[beam(-180)] - 1.5).abs() < 1e-6);
        assert_eq!(scan.ranges[beam(90)], f32::INFINITY);
        // Every point lies on a wall.
        let pts = points(&scan, v(0.0, 0.5), PI / 2.0, DEFAULT_MAX_NAN_FRACTION).unwrap();
        assert_eq!(pts.nan_beams, 0);
        assert_eq!(pts.points.len() + pts.out_of_range_beams, 360);
        assert!(pts.points.len() > 100);
        assert!(pts.points.iter().all(|p| map.distance_m(*p) < 1e-5));
    }

    #[test]
    fn person_ahead_shortens_the_beam_and_is_dropped() {
        let map = corridor();
        let g = ScanGeometry::default_360();
        let people = [(v(2.0, 0.0), 0.3)];
        let scan = simulate(&map, &people, v(0.0, 0.0), 0.0, &g);
        assert!((scan.ranges[beam(0)] - 1.7).abs() < 1e-6);
        assert!((scan.ranges[beam(90)] - 1.0).abs() < 1e-6);
        // A person behind the sensor does not show ahead.
        let behind = simulate(&map, &[(v(-2.0, 0.0), 0.3)], v(0.0, 0.0), 0.0, &g);
        assert_eq!(behind.ranges[beam(0)], f32::INFINITY);
        assert!((behind.ranges[beam(-180)] - 1.7).abs() < 1e-6);

        let mut pts = points(&scan, v(0.0, 0.0), 0.0, DEFAULT_MAX_NAN_FRACTION)
            .unwrap()
            .points;
        let n = pts.len();
        let on_person = pts
            .iter()
            .filter(|p| (*p - people[0].0).norm() < 0.3 + 1e-5)
            .count();
        assert!(on_person >= 5, "{on_person}");
        let removed = drop_people(&mut pts, &people, 0.05);
        assert_eq!(removed, on_person);
        assert_eq!(pts.len(), n - removed);
        assert!(pts.iter().all(|p| (p - people[0].0).norm() > 0.35));
        assert!(pts.iter().all(|p| map.distance_m(*p) < 1e-5));
        // Nobody tracked: nothing dropped.
        assert_eq!(drop_people(&mut pts, &[], 0.05), 0);
    }

    #[test]
    fn too_near_is_minus_inf() {
        let map = corridor();
        let g = ScanGeometry::default_360();
        let scan = simulate(&map, &[], v(0.0, 0.97), 0.0, &g);
        assert_eq!(scan.ranges[beam(90)], f32::NEG_INFINITY);
        assert!((scan.ranges[beam(-90)] - 1.97).abs() < 1e-6);
    }

    #[test]
    fn wrong_length_refused() {
        let scan = LaserScan {
            geometry: ScanGeometry::default_360(),
            ranges: vec![1.0; 359],
        };
        let err = points(&scan, v(0.0, 0.0), 0.0, DEFAULT_MAX_NAN_FRACTION).unwrap_err();
        assert_eq!(
            err,
            ScanError::WrongLength {
                expected: 360,
                got: 359
            }
        );
        assert_eq!(
            err.to_string(),
            "the scan has 359 ranges but its geometry has 360 beams"
        );
        let mut bad_geometry = scan.clone();
        bad_geometry.geometry.beams = 0;
        bad_geometry.ranges.clear();
        assert!(matches!(
            points(&bad_geometry, v(0.0, 0.0), 0.0, 0.1),
            Err(ScanError::InvalidGeometry(_))
        ));
    }

    #[test]
    fn nan_heavy_scan_refused_light_one_counted() {
        let mut scan = LaserScan {
            geometry: ScanGeometry::default_360(),
            ranges: vec![2.0; 360],
        };
        for r in scan.ranges.iter_mut().take(36) {
            *r = f32::NAN;
        }
        let pts = points(&scan, v(0.0, 0.0), 0.0, DEFAULT_MAX_NAN_FRACTION).unwrap();
        assert_eq!(pts.nan_beams, 36);
        assert_eq!(pts.points.len(), 324);
        scan.ranges[36] = f32::NAN;
        let err = points(&scan, v(0.0, 0.0), 0.0, DEFAULT_MAX_NAN_FRACTION).unwrap_err();
        assert_eq!(
            err.to_string(),
            "37 of 360 scan ranges are NaN, more than the 10.0 % allowed; the scan is refused \
             rather than driven on blind"
        );
        // A stricter threshold refuses fewer NaNs; a bad threshold is refused itself.
        scan.ranges[36] = 2.0;
        assert!(matches!(
            points(&scan, v(0.0, 0.0), 0.0, 0.05),
            Err(ScanError::TooManyInvalid { nan_beams: 36, .. })
        ));
        assert!(matches!(
            points(&scan, v(0.0, 0.0), 0.0, f64::NAN),
            Err(ScanError::BadThreshold(t)) if t.is_nan()
        ));
        assert!(matches!(
            points(&scan, v(0.0, 0.0), 0.0, 1.5),
            Err(ScanError::BadThreshold(_))
        ));
    }

    #[test]
    fn no_return_beams_give_no_point() {
        let mut scan = LaserScan {
            geometry: ScanGeometry::default_360(),
            ranges: vec![3.0; 360],
        };
        scan.ranges[0] = f32::INFINITY;
        scan.ranges[1] = f32::NEG_INFINITY;
        scan.ranges[2] = 0.01; // below range_min
        scan.ranges[3] = 8.5; // above range_max
        scan.ranges[4] = -1.0;
        scan.ranges[5] = 8.0; // exactly range_max: a return
        let pts = points(&scan, v(1.0, 2.0), 0.0, DEFAULT_MAX_NAN_FRACTION).unwrap();
        assert_eq!(pts.out_of_range_beams, 5);
        assert_eq!(pts.nan_beams, 0);
        assert_eq!(pts.points.len(), 355);
        // Beam 5 at −175°, 8 m from (1, 2).
        let expected = v(1.0, 2.0) + heading((-175.0f64).to_radians()) * 8.0;
        assert!((pts.points[0] - expected).norm() < 1e-9);
        assert!(pts
            .points
            .iter()
            .skip(1)
            .all(|p| ((p - v(1.0, 2.0)).norm() - 3.0).abs() < 1e-9));
    }

    #[test]
    fn sectors_numbered_counter_clockwise_from_ahead() {
        let pose = v(1.0, 1.0);
        let pts = [
            v(3.0, 1.0),  // ahead (heading 0): sector 0
            v(2.0, 1.0),  // nearer, ahead
            v(1.0, 2.0),  // left: sector 1 of 4
            v(-1.0, 1.0), // behind: sector 2
            v(1.0, -5.0), // right, beyond range
        ];
        let s = sector_nearest(&pts, pose, 0.0, 4, 4.0);
        assert_eq!(
            s,
            vec![
                Some(v(2.0, 1.0)),
                Some(v(1.0, 2.0)),
                Some(v(-1.0, 1.0)),
                None
            ]
        );
        // Heading left: the left point is ahead now.
        let s = sector_nearest(&pts, pose, PI / 2.0, 4, 10.0);
        assert_eq!(
            s,
            vec![
                Some(v(1.0, 2.0)),
                Some(v(-1.0, 1.0)),
                Some(v(1.0, -5.0)),
                Some(v(2.0, 1.0))
            ]
        );
        assert!(sector_nearest(&pts, pose, 0.0, 0, 4.0).is_empty());
        assert_eq!(
            sector_nearest(&pts, pose, 0.0, 1, 4.0),
            vec![Some(v(2.0, 1.0))]
        );
    }

    /// `sector_nearest` of a dense simulated scan against the exact map geometry.
    fn assert_scan_matches_map(map: &StaticMap, pose: Vec2, heading_rad: f64, sectors: usize) {
        let max_range_m = 4.0;
        let g = ScanGeometry::full_turn(3600, 0.0, 8.0).unwrap();
        let scan = simulate(map, &[], pose, heading_rad, &g);
        let pts = points(&scan, pose, heading_rad, 0.0).unwrap();
        let from_scan = sector_nearest(&pts.points, pose, heading_rad, sectors, max_range_m);
        let from_map = map_sector_nearest(map, pose, heading_rad, sectors, max_range_m);
        let mut seen = 0;
        for (k, (s, m)) in from_scan.iter().zip(&from_map).enumerate() {
            match (s, m) {
                (Some(s), Some(m)) => {
                    seen += 1;
                    assert!(
                        (s - m).norm() < 0.03,
                        "sector {k}: scan {s:?} map {m:?} (pose {pose:?})"
                    );
                }
                (None, None) => {}
                _ => panic!("sector {k}: scan {s:?} map {m:?} (pose {pose:?})"),
            }
        }
        assert!(seen > 0);
    }

    #[test]
    fn dense_scan_agrees_with_map_geometry() {
        let corridor = corridor();
        for (pose, heading_rad) in [(v(0.0, 0.2), 0.0), (v(1.3, -0.4), 0.7), (v(4.2, 0.6), -2.0)] {
            for sectors in [1, 2, 8, 16] {
                assert_scan_matches_map(&corridor, pose, heading_rad, sectors);
            }
        }
        let room = room_with_box();
        for (pose, heading_rad) in [(v(0.1, 0.3), 0.0), (v(-2.0, 1.5), 2.5), (v(2.2, -1.0), 1.0)] {
            for sectors in [1, 2, 8, 16] {
                assert_scan_matches_map(&room, pose, heading_rad, sectors);
            }
        }
        // Exactly: in the corridor at the origin, left and right walls 1 m away; ahead and
        // behind (±45° wedges) the nearest points are the wedges' corners on the walls, √2 m
        // away (of the two equally near, the first shape's: the lower wall).
        let s = map_sector_nearest(&corridor, v(0.0, 0.0), 0.0, 4, 4.0);
        assert_eq!(
            s,
            vec![
                Some(v(1.0, -1.0)),
                Some(v(0.0, 1.0)),
                Some(v(-1.0, -1.0)),
                Some(v(0.0, -1.0))
            ]
        );
        let s = map_sector_nearest(&corridor, v(0.0, 0.0), 0.0, 4, 1.41);
        assert_eq!(s, vec![None, Some(v(0.0, 1.0)), None, Some(v(0.0, -1.0))]);
        assert!(
            map_sector_nearest(&StaticMap::empty(), v(0.0, 0.0), 0.0, 8, 4.0)
                .iter()
                .all(Option::is_none)
        );
        let single = StaticMap::new(vec![Shape::wall(vec![v(1.0, -1.0), v(1.0, 1.0)])]).unwrap();
        assert_eq!(
            map_sector_nearest(&single, v(0.0, 0.0), PI, 2, 4.0),
            vec![None, Some(v(1.0, 0.0))]
        );
    }

    /// Every vertex of `map` lies on a shape of `truth` (within `tol_m`), and every point of
    /// `truth` a dense scan sees is within `tol_m` of `map` (the scan's walls are the walls).
    fn assert_map_traces(map: &StaticMap, truth: &StaticMap, points: &[Vec2], tol_m: f64) {
        for s in map.shapes() {
            for &p in &s.vertices {
                assert!(truth.distance_m(p) < tol_m, "vertex {p:?} off the walls");
            }
        }
        for &p in points {
            assert!(
                map.distance_m(p) < tol_m,
                "scan point {p:?} not on the scan's map"
            );
        }
    }

    #[test]
    fn scan_map_of_a_corridor_is_its_two_walls() {
        let truth = corridor();
        let g = ScanGeometry::default_360();
        let pose = v(0.0, -0.5);
        let scan = simulate(&truth, &[], pose, 0.3, &g);
        let pts = points(&scan, pose, 0.3, DEFAULT_MAX_NAN_FRACTION)
            .unwrap()
            .points;
        let map = scan_map(&pts, 0.3);
        // Both walls, each cut where the beams toward its ends run out of range or where
        // consecutive beams hit the two walls (no joining across the corridor).
        assert!(map.shapes().len() >= 2, "{}", map.shapes().len());
        assert!(map
            .shapes()
            .iter()
            .all(|s| s.kind == crate::map::ShapeKind::Wall));
        assert_map_traces(&map, &truth, &pts, 1e-5);
        // No segment crosses the corridor.
        for s in map.segments() {
            assert!((s.a.x - s.b.x).abs() < 0.3, "{s:?} crosses the corridor");
        }
        // The robot sees the same walls in every sector (within the beams' spacing).
        let from_map = map_sector_nearest(&map, pose, 0.3, 12, 4.0);
        let from_truth = map_sector_nearest(&truth, pose, 0.3, 12, 4.0);
        for (a, b) in from_map.iter().zip(&from_truth) {
            match (a, b) {
                (Some(a), Some(b)) => assert!((a - b).norm() < 0.03, "{a:?} vs {b:?}"),
                (a, b) => assert_eq!(a.is_some(), b.is_some()),
            }
        }
    }

    #[test]
    fn scan_map_skips_duplicates_and_joins_within_the_gap_only() {
        let pts = [
            v(0.0, 0.0),
            v(0.0, 0.0),
            v(0.0, 0.00005),
            v(0.1, 0.0),
            v(0.2, 0.0),
            v(f64::NAN, 0.0),
            v(0.2, f64::INFINITY),
            v(1.0, 0.0),
            v(1.1, 0.0),
            v(3.0, 3.0),
        ];
        let map = scan_map(&pts, 0.15);
        let shapes: Vec<Vec<Vec2>> = map.shapes().iter().map(|s| s.vertices.clone()).collect();
        assert_eq!(
            shapes,
            vec![
                vec![v(0.0, 0.0), v(0.1, 0.0), v(0.2, 0.0)],
                vec![v(1.0, 0.0), v(1.1, 0.0)],
                // A point alone is a 1 cm wall, centred on it.
                vec![
                    v(3.0 - SCAN_POLE_HALF_M, 3.0),
                    v(3.0 + SCAN_POLE_HALF_M, 3.0)
                ],
            ]
        );
        // Without a gap nothing joins; an empty scan is an open floor.
        assert_eq!(scan_map(&pts, f64::NAN).shapes().len(), 6);
        assert_eq!(scan_map(&pts, 0.0).shapes().len(), 6);
        assert!(scan_map(&[], 0.3).is_empty());
        // The map's walls are RVO2 obstacles.
        let lists: Vec<Vec<crate::geom::Vec2f>> = map
            .rvo2_obstacles()
            .into_iter()
            .map(|l| {
                l.iter()
                    .map(|p| crate::geom::Vec2f::new(p.x as f32, p.y as f32))
                    .collect()
            })
            .collect();
        assert!(crate::rvo::ObstacleSet::new(&lists).is_ok());
    }

    #[test]
    fn scan_map_cuts_a_polyline_that_would_cross_or_fold_back() {
        // A zigzag that crosses itself (a square's diagonals), and points running back along
        // a line (noise on a wall seen edge-on): joined as given they are not a valid wall.
        let crossing = [v(0.0, 0.0), v(1.0, 1.0), v(1.0, 0.0), v(0.0, 1.0)];
        assert!(StaticMap::new(vec![Shape::wall(crossing.to_vec())]).is_err());
        let map = scan_map(&crossing, 2.0);
        assert!(map.shapes().len() >= 2);
        assert_map_traces(&map, &map.clone(), &crossing, 1e-12);
        let back = [v(0.0, 0.0), v(0.2, 0.0), v(0.1, 0.0), v(0.3, 0.0)];
        assert!(StaticMap::new(vec![Shape::wall(back.to_vec())]).is_err());
        let map = scan_map(&back, 1.0);
        assert!(map.shapes().len() >= 2);
        for &p in &back {
            assert!(map.distance_m(p) < 1e-12);
        }
        // Every segment of the input is a segment of the map.
        let segs: Vec<(Vec2, Vec2)> = map.segments().iter().map(|s| (s.a, s.b)).collect();
        for w in back.windows(2) {
            assert!(segs.contains(&(w[0], w[1])), "{:?} missing", w);
        }
    }

    #[test]
    fn a_simplified_scan_map_keeps_every_point_within_the_tolerance() {
        let truth = room_with_box();
        let g = ScanGeometry::default_360();
        let pose = v(-1.0, 0.5);
        let scan = simulate(&truth, &[], pose, 0.0, &g);
        let pts = points(&scan, pose, 0.0, DEFAULT_MAX_NAN_FRACTION)
            .unwrap()
            .points;
        let full = scan_map(&pts, 0.3);
        let slim = scan_map_within(&pts, 0.3, 0.02);
        assert!(
            slim.segments().len() * 10 < full.segments().len(),
            "{} of {} segments",
            slim.segments().len(),
            full.segments().len()
        );
        for &p in &pts {
            assert!(slim.distance_m(p) <= 0.02 + 1e-9, "{p:?}");
        }
        // Every vertex kept is a scan point, the ends of each polyline included.
        for s in slim.shapes() {
            for q in &s.vertices {
                assert!(pts
                    .iter()
                    .any(|p| (p - q).norm() < 1e-12 || s.vertices.len() == 2));
            }
        }
        // A straight run of points is one segment; a corner keeps its vertex.
        let line: Vec<Vec2> = (0..50).map(|i| v(i as f64 * 0.05, 0.0)).collect();
        assert_eq!(scan_map_within(&line, 0.1, 0.01).segments().len(), 1);
        let corner: Vec<Vec2> = (0..20)
            .map(|i| v(i as f64 * 0.05, 0.0))
            .chain((1..20).map(|i| v(0.95, i as f64 * 0.05)))
            .collect();
        let m = scan_map_within(&corner, 0.1, 0.01);
        assert_eq!(
            m.shapes()[0].vertices,
            vec![corner[0], corner[19], corner[38]]
        );
        assert_eq!(scan_map_within(&corner, 0.1, 0.0).segments().len(), 38);
    }
}
