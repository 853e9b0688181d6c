//! Static maps: validated polygons, walls and bounding walls (issue 53).
//!
//! A [`StaticMap`] is a list of [`Shape`]s in the world frame (metres), checked once by
//! [`StaticMap::new`], which reports every problem of every shape at once. Three kinds follow
//! RVO2's conventions for `addObstacle`:
//!
//! - [`ShapeKind::Polygon`]: a solid obstacle, closed, listed counter-clockwise.
//! - [`ShapeKind::Wall`]: an open polyline whose both sides are walls (RVO2's two-vertex
//!   obstacles, one per segment).
//! - [`ShapeKind::Boundary`]: a closed bounding wall with the free space inside, listed clockwise
//!   (RVO2's "negative" obstacle, e.g. a room's outer wall).
//!
//! Different shapes may overlap or touch (furniture against a wall is normal); a shape may not
//! cross itself. The map answers the geometric queries the rest of the simulator needs: distance
//! and closest point, whether a disc fits, the clearance swept by a moving point, ray casts, and
//! a coarse reachability test.

use std::fmt;

use crate::geom::Vec2;

/// Largest grid [`StaticMap::reachable`] accepts, in cells (e.g. 200 m × 200 m at 0.1 m).
pub const MAX_REACHABLE_CELLS: u64 = 4_000_000;

/// Relative tolerance below which a closed outline's area counts as zero: twice the area is
/// compared with 1e-12 × (bounding-box diagonal)².
const DEGENERATE_REL: f64 = 1e-12;

/// Slack on a segment's parameter in ray casts, so that a ray through a shared vertex of two
/// edges cannot slip between them through rounding.
const RAY_SLACK: f64 = 1e-9;

/// What a shape's vertex list describes (RVO2's conventions).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ShapeKind {
    /// A solid obstacle: at least 3 vertices, closed, counter-clockwise.
    Polygon,
    /// An open polyline: at least 2 vertices, n − 1 segments, both sides are walls.
    Wall,
    /// A closed bounding wall with free space inside: at least 3 vertices, clockwise.
    Boundary,
}

impl ShapeKind {
    /// The name used in messages: `polygon`, `wall` or `boundary`.
    pub fn name(&self) -> &'static str {
        match self {
            ShapeKind::Polygon => "polygon",
            ShapeKind::Wall => "wall",
            ShapeKind::Boundary => "boundary",
        }
    }

    /// The fewest vertices a shape of this kind needs.
    pub fn min_vertices(&self) -> usize {
        match self {
            ShapeKind::Wall => 2,
            ShapeKind::Polygon | ShapeKind::Boundary => 3,
        }
    }

    /// Whether the last vertex connects back to the first.
    pub fn is_closed(&self) -> bool {
        !matches!(self, ShapeKind::Wall)
    }
}

impl fmt::Display for ShapeKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One obstacle outline in the world frame (metres).
#[derive(Debug, Clone, PartialEq)]
pub struct Shape {
    /// How the vertex list is read.
    pub kind: ShapeKind,
    /// World-frame vertices (metres), in order; a closed shape's first vertex is not repeated.
    pub vertices: Vec<Vec2>,
}

impl Shape {
    /// A solid polygon (vertices counter-clockwise).
    pub fn polygon(vertices: Vec<Vec2>) -> Shape {
        Shape {
            kind: ShapeKind::Polygon,
            vertices,
        }
    }

    /// An open wall polyline.
    pub fn wall(vertices: Vec<Vec2>) -> Shape {
        Shape {
            kind: ShapeKind::Wall,
            vertices,
        }
    }

    /// A bounding wall (vertices clockwise, free space inside).
    pub fn boundary(vertices: Vec<Vec2>) -> Shape {
        Shape {
            kind: ShapeKind::Boundary,
            vertices,
        }
    }

    /// A solid axis-aligned box from its lower-left to its upper-right corner, counter-clockwise.
    pub fn rectangle(min: Vec2, max: Vec2) -> Shape {
        Shape::polygon(vec![
            min,
            Vec2::new(max.x, min.y),
            max,
            Vec2::new(min.x, max.y),
        ])
    }

    /// An axis-aligned room's outer wall (free inside), clockwise.
    pub fn room(min: Vec2, max: Vec2) -> Shape {
        Shape::boundary(vec![
            min,
            Vec2::new(min.x, max.y),
            max,
            Vec2::new(max.x, min.y),
        ])
    }

    /// The number of edges: n for closed kinds, n − 1 for a wall.
    fn edge_count(&self) -> usize {
        let n = self.vertices.len();
        if self.kind.is_closed() {
            n
        } else {
            n.saturating_sub(1)
        }
    }

    /// Edge `i`, from vertex `i` to vertex `i + 1` (the closing edge ends at vertex 0).
    fn edge(&self, i: usize) -> Segment {
        let n = self.vertices.len();
        Segment {
            a: self.vertices[i],
            b: self.vertices[(i + 1) % n],
        }
    }

    /// Twice the signed area (shoelace); positive when counter-clockwise.
    fn twice_signed_area(&self) -> f64 {
        let n = self.vertices.len();
        (0..n)
            .map(|i| cross(self.vertices[i], self.vertices[(i + 1) % n]))
            .sum()
    }

    /// Whether `p` is strictly inside the closed outline (crossing number; for a point on an
    /// edge the answer is either).
    fn contains(&self, p: Vec2) -> bool {
        let n = self.vertices.len();
        let mut inside = false;
        let mut j = n - 1;
        for i in 0..n {
            let (vi, vj) = (self.vertices[i], self.vertices[j]);
            if (vi.y > p.y) != (vj.y > p.y) {
                let x = vi.x + (p.y - vi.y) * (vj.x - vi.x) / (vj.y - vi.y);
                if p.x < x {
                    inside = !inside;
                }
            }
            j = i;
        }
        inside
    }
}

/// A straight piece of wall from `a` to `b` (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// Start (metres).
    pub a: Vec2,
    /// End (metres).
    pub b: Vec2,
}

impl Segment {
    /// The point of the segment nearest to `p`.
    pub fn closest_point(&self, p: Vec2) -> Vec2 {
        let e = self.b - self.a;
        let ee = e.norm_squared();
        if ee == 0.0 {
            return self.a;
        }
        let t = ((p - self.a).dot(&e) / ee).clamp(0.0, 1.0);
        self.a + e * t
    }

    /// Distance from `p` to the segment.
    pub fn distance_m(&self, p: Vec2) -> f64 {
        (p - self.closest_point(p)).norm()
    }

    /// Whether the two segments share a point (crossing or touching).
    pub fn intersects(&self, other: &Segment) -> bool {
        segments_intersect(self.a, self.b, other.a, other.b)
    }

    /// The smallest distance between two segments (0 when they share a point).
    pub fn distance_to_segment_m(&self, other: &Segment) -> f64 {
        if self.intersects(other) {
            return 0.0;
        }
        self.distance_m(other.a)
            .min(self.distance_m(other.b))
            .min(other.distance_m(self.a))
            .min(other.distance_m(self.b))
    }

    /// The distance along the ray `origin + t·dir` (t ≥ 0, `dir` a unit vector) to where it
    /// first meets the segment, if it does. A ray running along the segment meets it at its
    /// nearest point ahead.
    pub fn ray_hit_m(&self, origin: Vec2, dir: Vec2) -> Option<f64> {
        let e = self.b - self.a;
        let w = self.a - origin;
        let denom = cross(dir, e);
        if denom != 0.0 {
            let t = cross(w, e) / denom;
            let s = cross(w, dir) / denom;
            (t >= 0.0 && (-RAY_SLACK..=1.0 + RAY_SLACK).contains(&s)).then_some(t)
        } else if cross(w, dir) == 0.0 {
            // Collinear: the nearest point of the segment ahead of the origin, if any.
            let t0 = w.dot(&dir);
            let t1 = (self.b - origin).dot(&dir);
            (t0.max(t1) >= 0.0).then(|| t0.min(t1).max(0.0))
        } else {
            None
        }
    }
}

/// What is wrong with one shape.
#[derive(Debug, Clone, PartialEq)]
pub enum Defect {
    /// Fewer vertices than the kind needs.
    TooFewVertices { got: usize },
    /// A coordinate of this vertex is NaN or infinite.
    NonFinite { vertex: usize, x: f64, y: f64 },
    /// Edge `edge` (vertex `edge` to the next) has zero length: a vertex repeated.
    ZeroLengthEdge { edge: usize, closing: bool },
    /// A polygon listed clockwise.
    Clockwise,
    /// A boundary listed counter-clockwise.
    CounterClockwise,
    /// A closed outline enclosing no area.
    NoArea,
    /// Two edges that are not neighbours intersect or touch.
    SelfIntersection { edges: (usize, usize) },
    /// Two neighbouring edges run back over each other.
    FoldsBack { edges: (usize, usize) },
}

/// One problem found in a map: which shape, of what kind, and what is wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct ShapeProblem {
    /// Index of the shape in the list given to [`StaticMap::new`].
    pub shape: usize,
    /// The shape's kind, named in the message.
    pub kind: ShapeKind,
    /// What is wrong.
    pub defect: Defect,
}

impl fmt::Display for ShapeProblem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (shape, kind) = (self.shape, self.kind);
        write!(f, "shape {shape} ({kind}) ")?;
        match &self.defect {
            Defect::TooFewVertices { got } => write!(
                f,
                "has {got} {}; a {kind} needs at least {}",
                if *got == 1 { "vertex" } else { "vertices" },
                kind.min_vertices()
            ),
            Defect::NonFinite { vertex, x, y } => write!(
                f,
                "vertex {vertex} is ({x}, {y}); coordinates must be finite numbers"
            ),
            Defect::ZeroLengthEdge {
                edge,
                closing: true,
            } => write!(
                f,
                "repeats its first vertex as its last (vertex {edge}); a {kind} closes itself, \
                 do not list the first vertex again"
            ),
            Defect::ZeroLengthEdge {
                edge,
                closing: false,
            } => write!(
                f,
                "has a zero-length edge {edge}: vertex {} repeats vertex {edge}",
                edge + 1
            ),
            Defect::Clockwise => {
                f.write_str("is listed clockwise; solid polygons are listed counter-clockwise")
            }
            Defect::CounterClockwise => {
                f.write_str("is listed counter-clockwise; a bounding wall is listed clockwise")
            }
            Defect::NoArea => f.write_str("encloses no area"),
            Defect::SelfIntersection { edges: (i, j) } => write!(
                f,
                "crosses itself: edges {i} and {j} intersect or touch \
                 (edge k runs from vertex k to the next)"
            ),
            Defect::FoldsBack { edges: (i, j) } => write!(
                f,
                "folds back on itself: edges {i} and {j} overlap \
                 (edge k runs from vertex k to the next)"
            ),
        }
    }
}

/// A map refused, or a query it cannot answer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MapError {
    /// Every problem of every shape, in shape order.
    #[error("{}", problem_list(.0))]
    Invalid(Vec<ShapeProblem>),
    /// [`StaticMap::reachable`] would need a grid larger than [`MAX_REACHABLE_CELLS`].
    #[error("reachability grid of {cells} cells exceeds the limit of {max} cells; use a larger cell size")]
    GridTooLarge { cells: u64, max: u64 },
    /// A query argument out of its domain.
    #[error("{what} must be {domain}, got {value}")]
    BadArgument {
        what: &'static str,
        domain: &'static str,
        value: f64,
    },
}

fn problem_list(problems: &[ShapeProblem]) -> String {
    let mut s = format!(
        "invalid map ({} problem{}):",
        problems.len(),
        if problems.len() == 1 { "" } else { "s" }
    );
    for p in problems {
        s.push_str("\n  - ");
        s.push_str(&p.to_string());
    }
    s
}

/// A validated set of static obstacles, with its segments precomputed.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StaticMap {
    shapes: Vec<Shape>,
    /// Every edge of every shape, in shape order (closed shapes closed, walls open).
    segments: Vec<Segment>,
}

impl StaticMap {
    /// Validates `shapes` and builds the map, or lists every problem found (see [`Defect`]).
    ///
    /// Per shape, in this order: the vertex count; finite coordinates (the remaining checks are
    /// skipped for a shape failing either); zero-length edges; self-intersection between
    /// non-neighbouring edges and neighbouring edges folding back (skipped when an edge has zero
    /// length, since a repeated vertex touches both its neighbours); then, for closed shapes
    /// that do not cross themselves, the area and orientation. Shapes may overlap each other.
    pub fn new(shapes: Vec<Shape>) -> Result<StaticMap, MapError> {
        let mut problems = Vec::new();
        for (index, shape) in shapes.iter().enumerate() {
            check_shape(index, shape, &mut problems);
        }
        if !problems.is_empty() {
            return Err(MapError::Invalid(problems));
        }
        let segments = shapes
            .iter()
            .flat_map(|s| (0..s.edge_count()).map(move |i| s.edge(i)))
            .collect();
        Ok(StaticMap { shapes, segments })
    }

    /// The map with no obstacle (an open floor).
    pub fn empty() -> StaticMap {
        StaticMap::default()
    }

    /// Whether the map has no shape.
    pub fn is_empty(&self) -> bool {
        self.shapes.is_empty()
    }

    /// The shapes, as given.
    pub fn shapes(&self) -> &[Shape] {
        &self.shapes
    }

    /// Every edge of every shape, in shape order.
    pub fn segments(&self) -> &[Segment] {
        &self.segments
    }

    /// The vertex lists to pass to RVO2's `addObstacle` one by one, in shape order: a polygon
    /// or boundary as it is, a wall polyline as one two-vertex list per segment.
    pub fn rvo2_obstacles(&self) -> Vec<Vec<Vec2>> {
        let mut out = Vec::new();
        for shape in &self.shapes {
            match shape.kind {
                ShapeKind::Polygon | ShapeKind::Boundary => out.push(shape.vertices.clone()),
                ShapeKind::Wall => out.extend(shape.vertices.windows(2).map(|w| w.to_vec())),
            }
        }
        out
    }

    /// Distance from `p` to the nearest segment: ∞ for an empty map, NaN for a non-finite `p`.
    pub fn distance_m(&self, p: Vec2) -> f64 {
        if !is_finite(p) {
            return f64::NAN;
        }
        self.segments
            .iter()
            .map(|s| s.distance_m(p))
            .fold(f64::INFINITY, f64::min)
    }

    /// The point of the map's segments nearest to `p` (None for an empty map or a non-finite
    /// `p`). Of equally near points, the first segment's.
    pub fn closest_point(&self, p: Vec2) -> Option<Vec2> {
        if !is_finite(p) {
            return None;
        }
        let mut best: Option<(f64, Vec2)> = None;
        for s in &self.segments {
            let q = s.closest_point(p);
            let d2 = (q - p).norm_squared();
            if best.is_none_or(|(b, _)| d2 < b) {
                best = Some((d2, q));
            }
        }
        best.map(|(_, q)| q)
    }

    /// Whether a disc of radius `radius_m` centred at `p` is in free space: false when `p` is
    /// inside a solid polygon, outside or on any boundary, on any segment, closer than
    /// `radius_m` to a segment, or not finite.
    pub fn is_free(&self, p: Vec2, radius_m: f64) -> bool {
        if !is_finite(p) {
            return false;
        }
        let d = self.distance_m(p);
        if d < radius_m || d == 0.0 {
            return false;
        }
        self.shapes.iter().all(|s| match s.kind {
            ShapeKind::Polygon => !s.contains(p),
            ShapeKind::Boundary => s.contains(p),
            ShapeKind::Wall => true,
        })
    }

    /// The smallest distance between the moving point's path `p0 → p1` and any segment of the
    /// map (0 when it crosses or touches one, ∞ for an empty map). Contact of a disc of radius
    /// r moving along the path is `swept_clearance_m < r`.
    pub fn swept_clearance_m(&self, p0: Vec2, p1: Vec2) -> f64 {
        let path = Segment { a: p0, b: p1 };
        let mut best = f64::INFINITY;
        for s in &self.segments {
            best = best.min(path.distance_to_segment_m(s));
            if best == 0.0 {
                break;
            }
        }
        best
    }

    /// Distance along the ray from `origin` at `angle_rad` (world frame) to the first segment
    /// it meets, or `max_range_m` when it meets none within that range.
    pub fn raycast_m(&self, origin: Vec2, angle_rad: f64, max_range_m: f64) -> f64 {
        self.ray_hit_m(origin, crate::geom::heading(angle_rad), max_range_m)
            .unwrap_or(max_range_m)
    }

    /// Distance along the ray `origin + t·dir` (`dir` a unit vector) to the first segment it
    /// meets within `max_range_m`, if any.
    pub fn ray_hit_m(&self, origin: Vec2, dir: Vec2, max_range_m: f64) -> Option<f64> {
        let mut best: Option<f64> = None;
        for s in &self.segments {
            if let Some(t) = s.ray_hit_m(origin, dir) {
                if t <= max_range_m && best.is_none_or(|b| t < b) {
                    best = Some(t);
                }
            }
        }
        best
    }

    /// Whether a disc of radius `radius_m` can travel from `start` to `goal`, by a coarse
    /// flood fill over a square grid of `cell_m` cells (4-connected). A cell is passable when
    /// a disc of radius `radius_m + cell_m / 2` is [free](Self::is_free) at its centre, so
    /// that the step between two passable neighbours is clear for the disc. The grid covers
    /// the map's segments, the start and the goal, padded by `radius_m` plus two cells so
    /// that the open floor around the obstacles is included; cells are tested only as the
    /// fill reaches them. The start (goal) joins the grid through any passable cell of the
    /// 3 × 3 around it whose centre it reaches in a straight line without contact.
    ///
    /// A `true` is certain (a contact-free path exists); a `false` may be wrong for a gap
    /// narrower than about 2·`radius_m` + 2·`cell_m`. False when the start or the goal is not
    /// free. Refused (an error) for a
    /// non-positive or non-finite `cell_m`, a negative or non-finite `radius_m`, a non-finite
    /// point, or a grid of more than [`MAX_REACHABLE_CELLS`] cells (checked only when the
    /// straight line from start to goal is blocked and the grid is needed).
    pub fn reachable(
        &self,
        start: Vec2,
        goal: Vec2,
        radius_m: f64,
        cell_m: f64,
    ) -> Result<bool, MapError> {
        let bad = |what, domain, value| MapError::BadArgument {
            what,
            domain,
            value,
        };
        if !(cell_m.is_finite() && cell_m > 0.0) {
            return Err(bad("reachable: cell_m", "positive and finite", cell_m));
        }
        if !(radius_m.is_finite() && radius_m >= 0.0) {
            return Err(bad(
                "reachable: radius_m",
                "non-negative and finite",
                radius_m,
            ));
        }
        for (what, p) in [("reachable: start", start), ("reachable: goal", goal)] {
            for v in [p.x, p.y] {
                if !v.is_finite() {
                    return Err(bad(what, "a finite point", v));
                }
            }
        }
        if !self.is_free(start, radius_m) || !self.is_free(goal, radius_m) {
            return Ok(false);
        }
        if self.clear_path(start, goal, radius_m) {
            return Ok(true);
        }
        let mut lo = start.inf(&goal);
        let mut hi = start.sup(&goal);
        for s in &self.segments {
            lo = lo.inf(&s.a).inf(&s.b);
            hi = hi.sup(&s.a).sup(&s.b);
        }
        let pad = radius_m + 2.0 * cell_m;
        let origin = lo - Vec2::new(pad, pad);
        let extent = hi + Vec2::new(pad, pad) - origin;
        let nx_f = (extent.x / cell_m).ceil();
        let ny_f = (extent.y / cell_m).ceil();
        let cells_f = nx_f * ny_f;
        if cells_f.is_nan() || cells_f > MAX_REACHABLE_CELLS as f64 {
            return Err(MapError::GridTooLarge {
                cells: if cells_f.is_finite() {
                    cells_f as u64
                } else {
                    u64::MAX
                },
                max: MAX_REACHABLE_CELLS,
            });
        }
        let (nx, ny) = (nx_f as usize, ny_f as usize);
        let centre = |i: usize, j: usize| {
            origin + Vec2::new((i as f64 + 0.5) * cell_m, (j as f64 + 0.5) * cell_m)
        };
        let cell_radius_m = radius_m + cell_m / 2.0;
        // 0 = untested, 1 = blocked, 2 = reached.
        const UNTESTED: u8 = 0;
        const BLOCKED: u8 = 1;
        const REACHED: u8 = 2;
        let mut state = vec![UNTESTED; nx * ny];
        let neighbourhood = |p: Vec2| {
            let ci = ((p.x - origin.x) / cell_m).floor() as i64;
            let cj = ((p.y - origin.y) / cell_m).floor() as i64;
            (-1..=1).flat_map(move |di| (-1..=1).map(move |dj| (ci + di, cj + dj)))
        };
        let in_grid = |i: i64, j: i64| i >= 0 && j >= 0 && (i as usize) < nx && (j as usize) < ny;
        let joins = |p: Vec2, i: usize, j: usize| {
            let c = centre(i, j);
            self.is_free(c, cell_radius_m) && self.clear_path(p, c, radius_m)
        };
        let mut stack = Vec::new();
        for (i, j) in neighbourhood(start) {
            if in_grid(i, j) && joins(start, i as usize, j as usize) {
                let k = j as usize * nx + i as usize;
                if state[k] != REACHED {
                    state[k] = REACHED;
                    stack.push((i as usize, j as usize));
                }
            }
        }
        while let Some((i, j)) = stack.pop() {
            let next = [
                (i.wrapping_sub(1), j),
                (i + 1, j),
                (i, j.wrapping_sub(1)),
                (i, j + 1),
            ];
            for (ni, nj) in next {
                if ni >= nx || nj >= ny {
                    continue;
                }
                let k = nj * nx + ni;
                if state[k] == UNTESTED {
                    if self.is_free(centre(ni, nj), cell_radius_m) {
                        state[k] = REACHED;
                        stack.push((ni, nj));
                    } else {
                        state[k] = BLOCKED;
                    }
                }
            }
        }
        Ok(neighbourhood(goal).any(|(i, j)| {
            in_grid(i, j)
                && state[j as usize * nx + i as usize] == REACHED
                && joins(goal, i as usize, j as usize)
        }))
    }
}

impl StaticMap {
    /// Whether a disc of radius `radius_m` moves from `p0` to `p1` without contact (touching
    /// counts as contact, also for a zero radius).
    fn clear_path(&self, p0: Vec2, p1: Vec2, radius_m: f64) -> bool {
        let clearance = self.swept_clearance_m(p0, p1);
        clearance >= radius_m && clearance > 0.0
    }
}

fn is_finite(p: Vec2) -> bool {
    p.x.is_finite() && p.y.is_finite()
}

/// z-component of the cross product.
pub(crate) fn cross(a: Vec2, b: Vec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Whether segments p1p2 and q1q2 share a point (inclusive of touching and collinear overlap).
fn segments_intersect(p1: Vec2, p2: Vec2, q1: Vec2, q2: Vec2) -> bool {
    let d1 = cross(q2 - q1, p1 - q1);
    let d2 = cross(q2 - q1, p2 - q1);
    let d3 = cross(p2 - p1, q1 - p1);
    let d4 = cross(p2 - p1, q2 - p1);
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return true;
    }
    (d1 == 0.0 && within_box(q1, q2, p1))
        || (d2 == 0.0 && within_box(q1, q2, p2))
        || (d3 == 0.0 && within_box(p1, p2, q1))
        || (d4 == 0.0 && within_box(p1, p2, q2))
}

/// Whether p lies in the bounding box of ab (for p collinear with ab: on the segment).
fn within_box(a: Vec2, b: Vec2, p: Vec2) -> bool {
    p.x >= a.x.min(b.x) && p.x <= a.x.max(b.x) && p.y >= a.y.min(b.y) && p.y <= a.y.max(b.y)
}

fn check_shape(index: usize, shape: &Shape, problems: &mut Vec<ShapeProblem>) {
    let kind = shape.kind;
    let mut report = |defect| {
        problems.push(ShapeProblem {
            shape: index,
            kind,
            defect,
        })
    };
    let v = &shape.vertices;
    let n = v.len();
    if n < kind.min_vertices() {
        report(Defect::TooFewVertices { got: n });
        return;
    }
    let mut finite = true;
    for (vertex, p) in v.iter().enumerate() {
        if !is_finite(*p) {
            report(Defect::NonFinite {
                vertex,
                x: p.x,
                y: p.y,
            });
            finite = false;
        }
    }
    if !finite {
        return;
    }
    let edges = shape.edge_count();
    let mut zero_edge = false;
    for e in 0..edges {
        let s = shape.edge(e);
        if s.a == s.b {
            report(Defect::ZeroLengthEdge {
                edge: e,
                closing: kind.is_closed() && e == n - 1,
            });
            zero_edge = true;
        }
    }
    let mut crossed = false;
    if !zero_edge {
        let neighbours =
            |i: usize, j: usize| j == i + 1 || (kind.is_closed() && i == 0 && j == edges - 1);
        for i in 0..edges {
            for j in i + 1..edges {
                let (si, sj) = (shape.edge(i), shape.edge(j));
                if neighbours(i, j) {
                    // Neighbours share a vertex; they overlap further only when they fold back.
                    let (first, second) = if j == i + 1 { (si, sj) } else { (sj, si) };
                    let u = first.b - first.a;
                    let w = second.b - second.a;
                    if cross(u, w) == 0.0 && u.dot(&w) < 0.0 {
                        report(Defect::FoldsBack { edges: (i, j) });
                        crossed = true;
                    }
                } else if si.intersects(&sj) {
                    report(Defect::SelfIntersection { edges: (i, j) });
                    crossed = true;
                }
            }
        }
    }
    if kind.is_closed() && !crossed {
        let area2 = shape.twice_signed_area();
        let lo = v.iter().fold(v[0], |m, p| m.inf(p));
        let hi = v.iter().fold(v[0], |m, p| m.sup(p));
        let scale = (hi - lo).norm_squared();
        if area2.abs() <= DEGENERATE_REL * scale {
            report(Defect::NoArea);
        } else if kind == ShapeKind::Polygon && area2 < 0.0 {
            report(Defect::Clockwise);
        } else if kind == ShapeKind::Boundary && area2 > 0.0 {
            report(Defect::CounterClockwise);
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    fn v(x: f64, y: f64) -> Vec2 {
        Vec2::new(x, y)
    }

    /// The problems' messages, or empty for a valid map.
    fn messages(shapes: Vec<Shape>) -> Vec<String> {
        match StaticMap::new(shapes) {
            Ok(_) => Vec::new(),
            Err(MapError::Invalid(problems)) => problems.iter().map(|p| p.to_string()).collect(),
            Err(e) => panic!("unexpected error {e}"),
        }
    }

    fn unit_square_ccw() -> Vec<Vec2> {
        vec![v(0.0, 0.0), v(1.0, 0.0), v(1.0, 1.0), v(0.0, 1.0)]
    }

    /// A corridor 2 m wide along x (y ∈ [−1, 1]), x ∈ [−5, 5], as two walls.
    pub(crate) fn corridor() -> StaticMap {
        StaticMap::new(vec![
            Shape::wall(vec![v(-5.0, -1.0), v(5.0, -1.0)]),
            Shape::wall(vec![v(-5.0, 1.0), v(5.0, 1.0)]),
        ])
        .unwrap()
    }

    /// A 6 m × 6 m room centred on the origin with a 1 m box at x ∈ [0.5, 1.5], y ∈ [−0.5, 0.5].
    pub(crate) fn room_with_box() -> StaticMap {
        StaticMap::new(vec![
            Shape::room(v(-3.0, -3.0), v(3.0, 3.0)),
            Shape::rectangle(v(0.5, -0.5), v(1.5, 0.5)),
        ])
        .unwrap()
    }

    /// A room x ∈ [−4, 4], y ∈ [−2, 2] split by a cross wall at x = 0 with a door of `door_m`
    /// centred on y = 0.
    fn doorway(door_m: f64) -> StaticMap {
        let h = door_m / 2.0;
        StaticMap::new(vec![
            Shape::room(v(-4.0, -2.0), v(4.0, 2.0)),
            Shape::wall(vec![v(0.0, -2.0), v(0.0, -h)]),
            Shape::wall(vec![v(0.0, h), v(0.0, 2.0)]),
        ])
        .unwrap()
    }

    #[test]
    fn too_few_vertices_refused_per_kind() {
        let msgs = messages(vec![
            Shape::polygon(vec![v(0.0, 0.0), v(1.0, 0.0)]),
            Shape::wall(vec![v(0.0, 0.0)]),
            Shape::boundary(vec![]),
        ]);
        assert_eq!(
            msgs,
            vec![
                "shape 0 (polygon) has 2 vertices; a polygon needs at least 3".to_string(),
                "shape 1 (wall) has 1 vertex; a wall needs at least 2".to_string(),
                "shape 2 (boundary) has 0 vertices; a boundary needs at least 3".to_string(),
            ]
        );
        // With enough vertices each passes.
        assert!(messages(vec![
            Shape::polygon(vec![v(0.0, 0.0), v(1.0, 0.0), v(0.0, 1.0)]),
            Shape::wall(vec![v(0.0, 0.0), v(1.0, 0.0)]),
            Shape::boundary(vec![v(0.0, 0.0), v(0.0, 1.0), v(1.0, 0.0)]),
        ])
        .is_empty());
    }

    #[test]
    fn non_finite_vertices_named() {
        let mut square = unit_square_ccw();
        square[1].x = f64::NAN;
        square[3].y = f64::INFINITY;
        let msgs = messages(vec![
            Shape::polygon(square),
            Shape::wall(vec![v(0.0, 0.0), v(f64::NEG_INFINITY, 1.0)]),
        ]);
        assert_eq!(
            msgs,
            vec![
                "shape 0 (polygon) vertex 1 is (NaN, 0); coordinates must be finite numbers",
                "shape 0 (polygon) vertex 3 is (0, inf); coordinates must be finite numbers",
                "shape 1 (wall) vertex 1 is (-inf, 1); coordinates must be finite numbers",
            ]
        );
        assert!(messages(vec![Shape::polygon(unit_square_ccw())]).is_empty());
    }

    #[test]
    fn zero_length_edges_refused() {
        let mut repeated = unit_square_ccw();
        repeated.insert(2, v(1.0, 0.0));
        let mut closed_twice = unit_square_ccw();
        closed_twice.push(v(0.0, 0.0));
        let msgs = messages(vec![
            Shape::polygon(repeated),
            Shape::polygon(closed_twice),
            Shape::wall(vec![v(0.0, 0.0), v(0.0, 0.0), v(1.0, 0.0)]),
        ]);
        assert_eq!(
            msgs,
            vec![
                "shape 0 (polygon) has a zero-length edge 1: vertex 2 repeats vertex 1",
                "shape 1 (polygon) repeats its first vertex as its last (vertex 4); a polygon \
                 closes itself, do not list the first vertex again",
                "shape 2 (wall) has a zero-length edge 0: vertex 1 repeats vertex 0",
            ]
        );
    }

    #[test]
    fn orientation_checked_both_ways() {
        let ccw = unit_square_ccw();
        let cw: Vec<Vec2> = ccw.iter().rev().copied().collect();
        let msgs = messages(vec![
            Shape::polygon(ccw.clone()),
            Shape::boundary(cw.clone()),
            Shape::wall(cw.clone()),
            Shape::polygon(cw.clone()),
            Shape::boundary(ccw.clone()),
        ]);
        assert_eq!(
            msgs,
            vec![
                "shape 3 (polygon) is listed clockwise; solid polygons are listed counter-clockwise",
                "shape 4 (boundary) is listed counter-clockwise; a bounding wall is listed clockwise",
            ]
        );
        // The helpers list each kind the right way round.
        assert!(messages(vec![
            Shape::rectangle(v(0.0, 0.0), v(2.0, 1.0)),
            Shape::room(v(-5.0, -5.0), v(5.0, 5.0)),
        ])
        .is_empty());
    }

    #[test]
    fn degenerate_outlines_refused() {
        // Three collinear vertices: the closing edge runs back over the second.
        let msgs = messages(vec![Shape::polygon(vec![
            v(0.0, 0.0),
            v(1.0, 0.0),
            v(2.0, 0.0),
        ])]);
        assert_eq!(
            msgs,
            vec![
                "shape 0 (polygon) folds back on itself: edges 0 and 2 overlap (edge k runs from vertex k to the next)",
                "shape 0 (polygon) folds back on itself: edges 1 and 2 overlap (edge k runs from vertex k to the next)",
            ]
        );
        // A sliver whose area is lost in rounding.
        let msgs = messages(vec![Shape::boundary(vec![
            v(0.0, 0.0),
            v(1.0, 0.0),
            v(2.0, 1e-13),
        ])]);
        assert_eq!(msgs, vec!["shape 0 (boundary) encloses no area"]);
        assert!(messages(vec![Shape::polygon(vec![
            v(0.0, 0.0),
            v(1.0, 0.0),
            v(2.0, 1e-3)
        ])])
        .is_empty());
    }

    #[test]
    fn bow_tie_crosses_itself() {
        let bow_tie = vec![v(0.0, 0.0), v(1.0, 1.0), v(1.0, 0.0), v(0.0, 1.0)];
        let msgs = messages(vec![Shape::polygon(bow_tie)]);
        assert_eq!(
            msgs,
            vec!["shape 0 (polygon) crosses itself: edges 0 and 2 intersect or touch (edge k runs from vertex k to the next)"]
        );
        // Touching counts too: vertex 4 lies on edge 1.
        let touching = vec![
            v(0.0, 0.0),
            v(2.0, 0.0),
            v(2.0, 2.0),
            v(1.0, 2.0),
            v(2.0, 1.0),
            v(0.0, 2.0),
        ];
        let msgs = messages(vec![Shape::polygon(touching)]);
        assert!(
            msgs.iter().any(|m| m.contains("edges 1 and 3"))
                && msgs.iter().any(|m| m.contains("edges 1 and 4")),
            "{msgs:?}"
        );
        // A wall zig-zag crossing itself, and one folding back onto itself.
        let msgs = messages(vec![
            Shape::wall(vec![v(0.0, 0.0), v(2.0, 0.0), v(2.0, 1.0), v(1.0, -1.0)]),
            Shape::wall(vec![v(0.0, 0.0), v(2.0, 0.0), v(1.0, 0.0)]),
        ]);
        assert_eq!(
            msgs,
            vec![
                "shape 0 (wall) crosses itself: edges 0 and 2 intersect or touch (edge k runs from vertex k to the next)",
                "shape 1 (wall) folds back on itself: edges 0 and 1 overlap (edge k runs from vertex k to the next)",
            ]
        );
        // Untangled, each passes.
        assert!(messages(vec![
            Shape::polygon(vec![v(0.0, 0.0), v(1.0, 0.0), v(1.0, 1.0), v(0.0, 1.0)]),
            Shape::wall(vec![v(0.0, 0.0), v(2.0, 0.0), v(2.0, 1.0), v(3.0, -1.0)]),
        ])
        .is_empty());
    }

    #[test]
    fn every_problem_reported_at_once_and_overlap_allowed() {
        let err = StaticMap::new(vec![
            Shape::polygon(vec![v(0.0, 0.0), v(0.0, 1.0), v(1.0, 0.0)]),
            Shape::rectangle(v(0.0, 0.0), v(1.0, 1.0)),
            Shape::wall(vec![v(f64::NAN, 0.0), v(1.0, 1.0)]),
        ])
        .unwrap_err();
        let text = err.to_string();
        assert_eq!(text.lines().count(), 3, "{text}");
        assert!(text.starts_with("invalid map (2 problems):\n  - shape 0 (polygon)"));
        assert!(text.contains("\n  - shape 2 (wall) vertex 0"));
        // Overlapping and touching shapes are fine.
        let map = StaticMap::new(vec![
            Shape::room(v(0.0, 0.0), v(4.0, 4.0)),
            Shape::rectangle(v(0.0, 0.0), v(1.0, 1.0)),
            Shape::rectangle(v(0.5, 0.5), v(1.5, 1.5)),
        ])
        .unwrap();
        assert_eq!(map.segments().len(), 12);
        assert_eq!(map.shapes().len(), 3);
    }

    #[test]
    fn rvo2_obstacles_split_walls() {
        let map = StaticMap::new(vec![
            Shape::wall(vec![v(0.0, 0.0), v(1.0, 0.0), v(1.0, 1.0)]),
            Shape::rectangle(v(2.0, 2.0), v(3.0, 3.0)),
        ])
        .unwrap();
        let obstacles = map.rvo2_obstacles();
        assert_eq!(
            obstacles,
            vec![
                vec![v(0.0, 0.0), v(1.0, 0.0)],
                vec![v(1.0, 0.0), v(1.0, 1.0)],
                map.shapes()[1].vertices.clone(),
            ]
        );
        assert_eq!(map.segments().len(), 2 + 4);
    }

    #[test]
    fn empty_map_queries() {
        let map = StaticMap::empty();
        assert!(map.is_empty());
        assert_eq!(map.distance_m(v(1.0, 2.0)), f64::INFINITY);
        assert_eq!(map.closest_point(v(1.0, 2.0)), None);
        assert!(map.is_free(v(1.0, 2.0), 10.0));
        assert!(!map.is_free(v(f64::NAN, 2.0), 0.1));
        assert_eq!(map.raycast_m(v(0.0, 0.0), 1.0, 7.0), 7.0);
        assert_eq!(
            map.swept_clearance_m(v(0.0, 0.0), v(1.0, 0.0)),
            f64::INFINITY
        );
        assert_eq!(
            map.reachable(v(0.0, 0.0), v(100.0, 0.0), 0.3, 0.1),
            Ok(true)
        );
    }

    #[test]
    fn corridor_queries() {
        let map = corridor();
        assert!(!map.is_empty());
        assert!((map.distance_m(v(0.0, 0.0)) - 1.0).abs() < 1e-12);
        assert!((map.distance_m(v(2.0, 0.7)) - 0.3).abs() < 1e-12);
        assert_eq!(map.closest_point(v(2.0, 0.7)), Some(v(2.0, 1.0)));
        // Past the end of the walls, the nearest point is a wall's end.
        assert!((map.distance_m(v(8.0, 0.0)) - (9.0f64 + 1.0).sqrt()).abs() < 1e-12);
        use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};
        assert!((map.raycast_m(v(0.0, 0.0), FRAC_PI_2, 8.0) - 1.0).abs() < 1e-12);
        assert!((map.raycast_m(v(0.0, 0.0), -FRAC_PI_2, 8.0) - 1.0).abs() < 1e-12);
        assert!((map.raycast_m(v(0.0, 0.5), FRAC_PI_4, 8.0) - 0.5 * 2f64.sqrt()).abs() < 1e-12);
        assert_eq!(map.raycast_m(v(0.0, 0.0), 0.0, 8.0), 8.0);
        assert_eq!(map.raycast_m(v(0.0, 0.0), FRAC_PI_2, 0.5), 0.5);
        // Along a wall's line the ray meets its near end.
        assert!((map.raycast_m(v(-7.0, 1.0), 0.0, 8.0) - 2.0).abs() < 1e-12);
        assert!(map.is_free(v(0.0, 0.5), 0.3));
        assert!(!map.is_free(v(0.0, 0.8), 0.3));
        assert!(!map.is_free(v(0.0, 1.0), 0.0));
        // Walls are open: beyond them is free space too.
        assert!(map.is_free(v(0.0, 2.0), 0.3));
    }

    #[test]
    fn room_with_box_queries() {
        let map = room_with_box();
        assert!((map.distance_m(v(0.0, 0.0)) - 0.5).abs() < 1e-12);
        assert!((map.raycast_m(v(0.0, 0.0), 0.0, 8.0) - 0.5).abs() < 1e-12);
        assert!((map.raycast_m(v(0.0, 0.0), std::f64::consts::PI, 8.0) - 3.0).abs() < 1e-12);
        // From the box's far side, x = 1.5 to the wall at x = 3.
        assert!((map.raycast_m(v(2.0, 0.0), 0.0, 8.0) - 1.0).abs() < 1e-12);
        // Inside the box, outside the room, on an edge: not free whatever the radius.
        assert!(!map.is_free(v(1.0, 0.0), 0.0));
        assert!(!map.is_free(v(4.0, 0.0), 0.0));
        assert!(!map.is_free(v(0.5, 0.0), 0.0));
        assert!(!map.is_free(v(-3.0, 0.0), 0.0));
        // Free spots, and too close to the box for a 0.3 m disc.
        assert!(map.is_free(v(0.0, 0.0), 0.3));
        assert!(map.is_free(v(-2.0, 2.0), 0.3));
        assert!(!map.is_free(v(0.3, 0.0), 0.3));
        assert!(!map.is_free(v(2.8, 0.0), 0.3));
        assert_eq!(map.closest_point(v(1.0, 1.0)), Some(v(1.0, 0.5)));
    }

    #[test]
    fn swept_clearance_crossing_and_parallel() {
        let map = corridor();
        // Crossing the upper wall: 0.
        assert_eq!(map.swept_clearance_m(v(0.0, 0.0), v(0.5, 1.5)), 0.0);
        // Touching it at the end: 0.
        assert_eq!(map.swept_clearance_m(v(0.0, 0.0), v(0.0, 1.0)), 0.0);
        // Parallel to both walls on the centre line: 1.
        assert!((map.swept_clearance_m(v(-2.0, 0.0), v(2.0, 0.0)) - 1.0).abs() < 1e-12);
        // Approaching the lower wall: the end point is nearest.
        assert!((map.swept_clearance_m(v(0.0, 0.0), v(1.0, -0.8)) - 0.2).abs() < 1e-12);
        // Passing a wall's end: the end vertex is nearest.
        assert!((map.swept_clearance_m(v(6.0, 3.0), v(6.0, -3.0)) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn reachable_through_wide_door_not_narrow() {
        // The straight line is blocked by the upper part of the cross wall.
        let start = v(-2.0, 1.5);
        let goal = v(2.0, 1.5);
        assert_eq!(doorway(1.0).reachable(start, goal, 0.3, 0.05), Ok(true));
        assert_eq!(doorway(0.5).reachable(start, goal, 0.3, 0.05), Ok(false));
        // A closed cross wall stops even a point.
        assert_eq!(doorway(0.0).reachable(start, goal, 0.0, 0.05), Ok(false));
        assert_eq!(
            doorway(0.0).reachable(v(-2.0, 0.0), v(2.0, 0.0), 0.0, 0.05),
            Ok(false)
        );
        // The narrow door still lets a small disc through.
        assert_eq!(doorway(0.5).reachable(start, goal, 0.1, 0.05), Ok(true));
        // A goal inside the box, or outside the room, is not reachable.
        let room = room_with_box();
        assert_eq!(
            room.reachable(v(-2.0, 0.0), v(2.0, 0.0), 0.3, 0.1),
            Ok(true)
        );
        assert_eq!(
            room.reachable(v(-2.0, 0.0), v(1.0, 0.0), 0.0, 0.1),
            Ok(false)
        );
        assert_eq!(
            room.reachable(v(-2.0, 0.0), v(5.0, 0.0), 0.3, 0.1),
            Ok(false)
        );
        // Around the end of a free-standing wall.
        let wall = StaticMap::new(vec![Shape::wall(vec![v(0.0, -3.0), v(0.0, 3.0)])]).unwrap();
        assert_eq!(
            wall.reachable(v(-1.0, 0.0), v(1.0, 0.0), 0.3, 0.1),
            Ok(true)
        );
    }

    #[test]
    fn reachable_refuses_bad_arguments_and_huge_grids() {
        let map = doorway(1.0);
        let (s, g) = (v(-2.0, 1.5), v(2.0, 1.5));
        let err = map.reachable(s, g, 0.3, 0.0).unwrap_err();
        assert_eq!(
            err.to_string(),
            "reachable: cell_m must be positive and finite, got 0"
        );
        assert!(matches!(
            map.reachable(s, g, f64::NAN, 0.1),
            Err(MapError::BadArgument { .. })
        ));
        assert!(matches!(
            map.reachable(v(f64::INFINITY, 0.0), g, 0.3, 0.1),
            Err(MapError::BadArgument { .. })
        ));
        let err = map.reachable(s, g, 0.3, 1e-4).unwrap_err();
        assert!(
            matches!(
                err,
                MapError::GridTooLarge {
                    max: MAX_REACHABLE_CELLS,
                    ..
                }
            ),
            "{err}"
        );
    }
}
