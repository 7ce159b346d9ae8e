//! Points, bulge polylines, segments, regions and shapes: the types every operation starts from.

use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::ops::{Add, Mul, Neg, Sub};

/// A point (or vector) in the XY plane, in millimetres.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Point {
    pub x: f64,
    pub y: f64,
}

impl Point {
    pub const fn new(x: f64, y: f64) -> Self {
        Point { x, y }
    }
    #[inline]
    pub fn dot(self, o: Point) -> f64 {
        self.x * o.x + self.y * o.y
    }
    /// z of the 3D cross product: > 0 when `o` lies counter-clockwise of `self`.
    #[inline]
    pub fn cross(self, o: Point) -> f64 {
        self.x * o.y - self.y * o.x
    }
    #[inline]
    pub fn len(self) -> f64 {
        // the plain square root where the squares neither overflow nor underflow (every
        // coordinate a drawing holds); hypot, several times slower, guards the rest
        let s = self.x * self.x + self.y * self.y;
        if s.is_finite() && s > 1e-290 {
            s.sqrt()
        } else {
            self.x.hypot(self.y)
        }
    }
    #[inline]
    pub fn dist(self, o: Point) -> f64 {
        (self - o).len()
    }
    /// The unit vector in this direction, or zero for the zero vector.
    #[inline]
    pub fn unit(self) -> Point {
        let l = self.len();
        if l > 0.0 {
            self * (1.0 / l)
        } else {
            Point::default()
        }
    }
    /// This vector turned 90° counter-clockwise (its left normal).
    #[inline]
    pub fn perp(self) -> Point {
        Point::new(-self.y, self.x)
    }
    #[inline]
    pub fn lerp(self, o: Point, t: f64) -> Point {
        self + (o - self) * t
    }
    #[inline]
    pub fn is_finite(self) -> bool {
        self.x.is_finite() && self.y.is_finite()
    }
}

impl Add for Point {
    type Output = Point;
    #[inline]
    fn add(self, o: Point) -> Point {
        Point::new(self.x + o.x, self.y + o.y)
    }
}
impl Sub for Point {
    type Output = Point;
    #[inline]
    fn sub(self, o: Point) -> Point {
        Point::new(self.x - o.x, self.y - o.y)
    }
}
impl Mul<f64> for Point {
    type Output = Point;
    #[inline]
    fn mul(self, k: f64) -> Point {
        Point::new(self.x * k, self.y * k)
    }
}
impl Neg for Point {
    type Output = Point;
    #[inline]
    fn neg(self) -> Point {
        Point::new(-self.x, -self.y)
    }
}

/// The smaller of two finite numbers: one comparison, without `f64::min`'s care for NaN
/// (the offset kernel's coordinates are checked finite on the way in; a NaN `b` leaves
/// `a`, as `f64::min` does); for the boxes, which every pass over the segments makes.
#[inline]
pub(crate) fn lo(a: f64, b: f64) -> f64 {
    if b < a {
        b
    } else {
        a
    }
}

/// The larger of two finite numbers (see [`lo`]).
#[inline]
pub(crate) fn hi(a: f64, b: f64) -> f64 {
    if b > a {
        b
    } else {
        a
    }
}

/// An axis-aligned box. An empty box has `min > max`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Bounds {
    pub min: Point,
    pub max: Point,
}

impl Default for Bounds {
    fn default() -> Self {
        Bounds::EMPTY
    }
}

impl Bounds {
    pub const EMPTY: Bounds = Bounds {
        min: Point::new(f64::INFINITY, f64::INFINITY),
        max: Point::new(f64::NEG_INFINITY, f64::NEG_INFINITY),
    };
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y
    }
    pub fn add_point(&mut self, p: Point) {
        self.min.x = lo(self.min.x, p.x);
        self.min.y = lo(self.min.y, p.y);
        self.max.x = hi(self.max.x, p.x);
        self.max.y = hi(self.max.y, p.y);
    }
    pub fn union(&self, o: &Bounds) -> Bounds {
        let mut b = *self;
        if !o.is_empty() {
            b.add_point(o.min);
            b.add_point(o.max);
        }
        b
    }
    pub fn width(&self) -> f64 {
        self.max.x - self.min.x
    }
    pub fn height(&self) -> f64 {
        self.max.y - self.min.y
    }
    pub fn overlaps(&self, o: &Bounds, margin: f64) -> bool {
        self.min.x <= o.max.x + margin
            && o.min.x <= self.max.x + margin
            && self.min.y <= o.max.y + margin
            && o.min.y <= self.max.y + margin
    }
    pub fn contains(&self, p: Point) -> bool {
        p.x >= self.min.x && p.x <= self.max.x && p.y >= self.min.y && p.y <= self.max.y
    }
}

/// A polyline vertex: a position and the bulge of the segment that starts here
/// (tan of a quarter of the arc's sweep, positive counter-clockwise, 0 for a line), as in DXF.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vertex {
    pub x: f64,
    pub y: f64,
    pub bulge: f64,
}

impl Vertex {
    pub const fn new(x: f64, y: f64, bulge: f64) -> Self {
        Vertex { x, y, bulge }
    }
    pub fn line(p: Point) -> Self {
        Vertex::new(p.x, p.y, 0.0)
    }
    pub fn pos(&self) -> Point {
        Point::new(self.x, self.y)
    }
}

/// One piece of a polyline: a straight line or a circular arc.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Segment {
    Line {
        a: Point,
        b: Point,
    },
    Arc {
        a: Point,
        b: Point,
        center: Point,
        radius: f64,
        /// true when the arc turns counter-clockwise from `a` to `b`.
        ccw: bool,
    },
}

/// Points along a segment by its parameter t in [0, 1], as [`Segment::point_at`] gives
/// them, with an arc's sweep and start direction worked out once: for the walks that ask
/// many points of one segment (samplers, distance checks).
#[derive(Clone, Copy, Debug)]
pub struct PointsAlong {
    seg: Segment,
    /// An arc's unit direction from its centre to its start.
    start_dir: Point,
    sweep: f64,
}

impl PointsAlong {
    pub fn new(seg: &Segment) -> PointsAlong {
        let (start_dir, sweep) = match *seg {
            Segment::Line { .. } => (Point::new(1.0, 0.0), 0.0),
            Segment::Arc { a, center, .. } => {
                let u = a - center;
                let l = u.len();
                let u = if l > 0.0 {
                    u * (1.0 / l)
                } else {
                    Point::new(1.0, 0.0)
                };
                (u, seg.sweep())
            }
        };
        PointsAlong {
            seg: *seg,
            start_dir,
            sweep,
        }
    }

    /// The point at t: a line's by interpolation, an arc's as the start's direction turned
    /// by the swept part (no angle of the start).
    pub fn at(&self, t: f64) -> Point {
        match self.seg {
            Segment::Line { a, b } => a.lerp(b, t),
            Segment::Arc { center, radius, .. } => {
                let u = self.start_dir;
                let (sin, cos) = (self.sweep * t).sin_cos();
                center + Point::new(u.x * cos - u.y * sin, u.x * sin + u.y * cos) * radius
            }
        }
    }
}

impl Segment {
    /// The segment from `a` to `b` with the given bulge. Bulges too small to matter
    /// (|bulge| < 1e-12) or on a zero-length chord give a line.
    pub fn from_bulge(a: Point, b: Point, bulge: f64) -> Segment {
        let chord = b - a;
        let c = chord.len();
        if bulge.abs() < 1e-12 || c == 0.0 {
            return Segment::Line { a, b };
        }
        // sagitta-based centre: the centre lies on the chord's bisector.
        let radius = c * (1.0 + bulge * bulge) / (4.0 * bulge.abs());
        let mid = a.lerp(b, 0.5);
        // signed distance from the mid-chord to the centre, along the chord's left normal
        let d = c * (1.0 - bulge * bulge) / (4.0 * bulge);
        let center = mid + chord.unit().perp() * d;
        Segment::Arc {
            a,
            b,
            center,
            radius,
            ccw: bulge > 0.0,
        }
    }
    /// The same line, or an arc of the same circle turning the same way, from `a` to `b`
    /// (two points on it): a piece of this segment.
    pub fn with_ends(&self, a: Point, b: Point) -> Segment {
        match *self {
            Segment::Line { .. } => Segment::Line { a, b },
            Segment::Arc {
                center,
                radius,
                ccw,
                ..
            } => Segment::Arc {
                a,
                b,
                center,
                radius,
                ccw,
            },
        }
    }
    pub fn start(&self) -> Point {
        match *self {
            Segment::Line { a, .. } | Segment::Arc { a, .. } => a,
        }
    }
    pub fn end(&self) -> Point {
        match *self {
            Segment::Line { b, .. } | Segment::Arc { b, .. } => b,
        }
    }
    /// Signed sweep of an arc in radians (positive counter-clockwise); 0 for a line.
    pub fn sweep(&self) -> f64 {
        match *self {
            Segment::Line { .. } => 0.0,
            Segment::Arc {
                a, b, center, ccw, ..
            } => {
                // the turn from a to b in (-π, π], from their cross and dot products (one
                // atan2, not one per end)
                let (va, vb) = (a - center, b - center);
                let mut s = va.cross(vb).atan2(va.dot(vb));
                if ccw {
                    while s <= 0.0 {
                        s += 2.0 * PI;
                    }
                } else {
                    while s >= 0.0 {
                        s -= 2.0 * PI;
                    }
                }
                s
            }
        }
    }
    pub fn length(&self) -> f64 {
        match *self {
            Segment::Line { a, b } => a.dist(b),
            Segment::Arc { radius, .. } => radius * self.sweep().abs(),
        }
    }
    /// The point at parameter t in [0, 1] along the segment (by arc length).
    pub fn point_at(&self, t: f64) -> Point {
        PointsAlong::new(self).at(t)
    }
    /// Unit tangent in the direction of travel at parameter t.
    pub fn tangent_at(&self, t: f64) -> Point {
        match *self {
            Segment::Line { a, b } => (b - a).unit(),
            Segment::Arc {
                a, b, center, ccw, ..
            } => {
                // at the ends the radius is the end's own (no point to place)
                let r = if t == 0.0 {
                    (a - center).unit()
                } else if t == 1.0 {
                    (b - center).unit()
                } else {
                    (self.point_at(t) - center).unit()
                };
                if ccw {
                    r.perp()
                } else {
                    -r.perp()
                }
            }
        }
    }
    /// The closest point of the segment to `p`.
    pub fn closest_point(&self, p: Point) -> Point {
        match *self {
            Segment::Line { a, b } => {
                let ab = b - a;
                let l2 = ab.dot(ab);
                if l2 == 0.0 {
                    return a;
                }
                let t = ((p - a).dot(ab) / l2).clamp(0.0, 1.0);
                a.lerp(b, t)
            }
            Segment::Arc {
                a,
                b,
                center,
                radius,
                ..
            } => {
                let v = p - center;
                if v.len() > 0.0 && self.angle_within(v) {
                    return center + v.unit() * radius;
                }
                if p.dist(a) <= p.dist(b) {
                    a
                } else {
                    b
                }
            }
        }
    }
    /// Distance from `p` to the segment.
    pub fn distance_to(&self, p: Point) -> f64 {
        p.dist(self.closest_point(p))
    }
    /// Whether the direction `v` (from the centre) lies within the arc's sweep, ends
    /// included: decided by cross products, without angles. An arc whose ends coincide is a
    /// full turn (as `sweep` measures it).
    fn angle_within(&self, v: Point) -> bool {
        match *self {
            Segment::Line { .. } => false,
            Segment::Arc {
                a, b, center, ccw, ..
            } => {
                let (va, vb) = (a - center, b - center);
                let s = if ccw { 1.0 } else { -1.0 };
                let after_start = s * va.cross(v) >= 0.0;
                let before_end = s * v.cross(vb) >= 0.0;
                let turn = va.cross(vb);
                if a == b || (turn == 0.0 && va.dot(vb) > 0.0) {
                    // a full turn
                    true
                } else if s * turn < 0.0 {
                    // more than a half turn
                    after_start || before_end
                } else {
                    after_start && before_end
                }
            }
        }
    }
    /// Tight bounds, including the arc's extreme points.
    pub fn bounds(&self) -> Bounds {
        let mut b = Bounds::EMPTY;
        b.add_point(self.start());
        b.add_point(self.end());
        if let Segment::Arc { center, radius, .. } = *self {
            for d in [
                Point::new(1.0, 0.0),
                Point::new(0.0, 1.0),
                Point::new(-1.0, 0.0),
                Point::new(0.0, -1.0),
            ] {
                if self.angle_within(d) {
                    b.add_point(center + d * radius);
                }
            }
        }
        b
    }
    /// Twice the signed area this segment adds to a closed polyline's area
    /// (shoelace term of the chord plus the arc's circular segment).
    pub fn area2(&self) -> f64 {
        let (a, b) = (self.start(), self.end());
        let chord = a.cross(b);
        match *self {
            Segment::Line { .. } => chord,
            Segment::Arc { radius, .. } => {
                let s = self.sweep();
                chord + radius * radius * (s - s.sin())
            }
        }
    }
}

/// A sequence of vertices joined by lines or arcs; closed when the last joins the first.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Polyline {
    pub vertices: Vec<Vertex>,
    pub closed: bool,
}

impl Polyline {
    pub fn new(vertices: Vec<Vertex>, closed: bool) -> Self {
        Polyline { vertices, closed }
    }
    /// A polyline through the points with straight segments.
    pub fn from_points(points: &[Point], closed: bool) -> Self {
        Polyline::new(points.iter().map(|&p| Vertex::line(p)).collect(), closed)
    }
    /// A full circle as two half-circle arcs, counter-clockwise.
    pub fn circle(center: Point, radius: f64) -> Self {
        Polyline::new(
            vec![
                Vertex::new(center.x + radius, center.y, 1.0),
                Vertex::new(center.x - radius, center.y, 1.0),
            ],
            true,
        )
    }
    /// An axis-aligned rectangle, counter-clockwise.
    pub fn rect(min: Point, max: Point) -> Self {
        Polyline::from_points(
            &[min, Point::new(max.x, min.y), max, Point::new(min.x, max.y)],
            true,
        )
    }
    pub fn len(&self) -> usize {
        self.vertices.len()
    }
    pub fn is_empty(&self) -> bool {
        self.vertices.is_empty()
    }
    pub fn segment_count(&self) -> usize {
        match self.vertices.len() {
            0 | 1 => 0,
            n if self.closed => n,
            n => n - 1,
        }
    }
    /// The i-th segment (0-based); segment i starts at vertex i.
    pub fn segment(&self, i: usize) -> Segment {
        let n = self.vertices.len();
        let v = self.vertices[i];
        let w = self.vertices[(i + 1) % n];
        Segment::from_bulge(v.pos(), w.pos(), v.bulge)
    }
    pub fn segments(&self) -> impl Iterator<Item = Segment> + '_ {
        (0..self.segment_count()).map(move |i| self.segment(i))
    }
    /// Signed area (positive counter-clockwise); 0 for open polylines.
    pub fn area(&self) -> f64 {
        if !self.closed {
            return 0.0;
        }
        self.segments().map(|s| s.area2()).sum::<f64>() * 0.5
    }
    pub fn length(&self) -> f64 {
        self.segments().map(|s| s.length()).sum()
    }
    pub fn bounds(&self) -> Bounds {
        let mut b = Bounds::EMPTY;
        for v in &self.vertices {
            b.add_point(v.pos());
        }
        for s in self.segments() {
            if matches!(s, Segment::Arc { .. }) {
                b = b.union(&s.bounds());
            }
        }
        b
    }
    pub fn is_ccw(&self) -> bool {
        self.area() > 0.0
    }
    /// The same curve traversed the other way (bulges move to the other end and flip sign).
    pub fn reversed(&self) -> Polyline {
        let n = self.vertices.len();
        if n == 0 {
            return self.clone();
        }
        let mut out = Vec::with_capacity(n);
        if self.closed {
            // reversed order: v0, v(n-1), ..., v1; the segment from v(i) back to v(i-1) takes -bulge(i-1)
            for k in 0..n {
                let i = (n - k) % n;
                let prev = (i + n - 1) % n;
                let v = self.vertices[i];
                out.push(Vertex::new(v.x, v.y, -self.vertices[prev].bulge));
            }
        } else {
            for k in (0..n).rev() {
                let v = self.vertices[k];
                let b = if k > 0 {
                    -self.vertices[k - 1].bulge
                } else {
                    0.0
                };
                out.push(Vertex::new(v.x, v.y, b));
            }
        }
        Polyline::new(out, self.closed)
    }
    /// Distance from `p` to the nearest point of the polyline.
    pub fn distance_to(&self, p: Point) -> f64 {
        if self.vertices.len() == 1 {
            return p.dist(self.vertices[0].pos());
        }
        self.segments()
            .map(|s| s.distance_to(p))
            .fold(f64::INFINITY, f64::min)
    }
    /// Winding number of the closed polyline around `p` (nonzero = inside).
    pub fn winding_number(&self, p: Point) -> i32 {
        self.winding_numbers(&[p])[0]
    }
    /// The winding numbers of several points, in one walk over the vertices.
    pub fn winding_numbers(&self, ps: &[Point]) -> Vec<i32> {
        let mut w = vec![0; ps.len()];
        if !self.closed {
            return w;
        }
        let n = self.vertices.len();
        for i in 0..n {
            let v = self.vertices[i];
            let (a, b) = (v.pos(), self.vertices[(i + 1) % n].pos());
            for (wk, &p) in w.iter_mut().zip(ps) {
                *wk += winding_of(a, b, v.bulge, p);
            }
        }
        w
    }
    /// Whether `p` lies inside the closed polyline (nonzero winding).
    pub fn contains(&self, p: Point) -> bool {
        self.winding_number(p) != 0
    }
    /// All coordinates and bulges are finite numbers.
    pub fn is_finite(&self) -> bool {
        self.vertices
            .iter()
            .all(|v| v.x.is_finite() && v.y.is_finite() && v.bulge.is_finite())
    }
}

/// What the segment from `a` to `b` with `bulge` adds to the winding number of a closed
/// path around `p`: the chord's crossing, and ±1 for an arc when `p` lies between the arc
/// and its chord (the loop "arc a→b, chord b→a" winds once around such points, all of
/// which lie within (|bulge| + 1) chords of the chord's box; farther points skip the exact
/// test). A point on the chord's line counts as if a hair above (then a hair right), as in
/// the crossing rule.
pub(crate) fn winding_of(a: Point, b: Point, bulge: f64, p: Point) -> i32 {
    let mut w = crossing(a, b, p);
    if bulge == 0.0 {
        return w;
    }
    let m = (b - a).len() * (bulge.abs() + 1.0);
    if p.x < a.x.min(b.x) - m
        || p.x > a.x.max(b.x) + m
        || p.y < a.y.min(b.y) - m
        || p.y > a.y.max(b.y) + m
    {
        return w;
    }
    if let Segment::Arc {
        center,
        radius,
        ccw,
        ..
    } = Segment::from_bulge(a, b, bulge)
    {
        // inside the circle and on the side of the chord the arc bulges to (right for
        // ccw, left for cw)
        let d = b - a;
        let mut side = d.cross(p - a);
        if side == 0.0 {
            side = if d.x != 0.0 { d.x } else { -d.y };
        }
        let on_bulge_side = if ccw { side < 0.0 } else { side > 0.0 };
        if on_bulge_side && p.dist(center) < radius {
            w += if ccw { 1 } else { -1 };
        }
    }
    w
}

/// Winding contribution of the directed edge a→b for point p (standard crossing rule).
fn crossing(a: Point, b: Point, p: Point) -> i32 {
    if a.y <= p.y {
        if b.y > p.y && (b - a).cross(p - a) > 0.0 {
            return 1;
        }
    } else if b.y <= p.y && (b - a).cross(p - a) < 0.0 {
        return -1;
    }
    0
}

/// An area to machine or to offset: one outer boundary (counter-clockwise) and the islands
/// inside it (clockwise).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Region {
    pub outer: Polyline,
    pub islands: Vec<Polyline>,
}

impl Region {
    /// A region with orientations normalised: outer CCW, islands CW.
    pub fn new(outer: Polyline, islands: Vec<Polyline>) -> Self {
        let outer = if outer.area() < 0.0 {
            outer.reversed()
        } else {
            outer
        };
        let islands = islands
            .into_iter()
            .map(|i| if i.area() > 0.0 { i.reversed() } else { i })
            .collect();
        Region { outer, islands }
    }
    /// Net area: the outer's less the islands'.
    pub fn area(&self) -> f64 {
        self.outer.area() + self.islands.iter().map(|i| i.area()).sum::<f64>()
    }
    pub fn contains(&self, p: Point) -> bool {
        self.outer.contains(p) && !self.islands.iter().any(|i| i.contains(p))
    }
    pub fn boundaries(&self) -> impl Iterator<Item = &Polyline> {
        std::iter::once(&self.outer).chain(self.islands.iter())
    }
    pub fn bounds(&self) -> Bounds {
        self.outer.bounds()
    }
}

/// What a shape file holds: closed and open paths, in millimetres.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Shape {
    pub paths: Vec<Polyline>,
}

impl Shape {
    pub fn new(paths: Vec<Polyline>) -> Self {
        Shape { paths }
    }
    pub fn bounds(&self) -> Bounds {
        self.paths
            .iter()
            .fold(Bounds::EMPTY, |b, p| b.union(&p.bounds()))
    }
    /// The first path that reaches beyond ±`limit` in x or y (arcs by their extent) or
    /// holds a number that is not finite, with a point where it does.
    pub fn first_beyond(&self, limit: f64) -> Option<(usize, Point)> {
        for (i, p) in self.paths.iter().enumerate() {
            if let Some(v) = p
                .vertices
                .iter()
                .find(|v| !(v.x.abs() <= limit && v.y.abs() <= limit && v.bulge.is_finite()))
            {
                return Some((i, v.pos()));
            }
            let b = p.bounds();
            for q in [b.min, b.max] {
                if !(q.x.abs() <= limit && q.y.abs() <= limit) {
                    return Some((i, q));
                }
            }
        }
        None
    }
    pub fn open_paths(&self) -> impl Iterator<Item = &Polyline> {
        self.paths.iter().filter(|p| !p.closed)
    }
    /// The closed paths nested into regions by containment: even depth = outer boundary,
    /// odd depth = island of the region just outside it, whatever their orientation.
    pub fn regions(&self) -> Vec<Region> {
        let closed: Vec<&Polyline> = self
            .paths
            .iter()
            .filter(|p| p.closed && p.len() >= 2)
            .collect();
        // depth[i] = how many other closed paths contain path i; parent = the smallest of them.
        let areas: Vec<f64> = closed.iter().map(|p| p.area().abs()).collect();
        let probe: Vec<Point> = closed.iter().map(|p| p.vertices[0].pos()).collect();
        let mut depth = vec![0usize; closed.len()];
        let mut parent: Vec<Option<usize>> = vec![None; closed.len()];
        for i in 0..closed.len() {
            for j in 0..closed.len() {
                if i != j && areas[j] > areas[i] && closed[j].contains(probe[i]) {
                    depth[i] += 1;
                    if parent[i].is_none_or(|k| areas[j] < areas[k]) {
                        parent[i] = Some(j);
                    }
                }
            }
        }
        let mut out: Vec<(usize, Region)> = Vec::new();
        for i in 0..closed.len() {
            if depth[i].is_multiple_of(2) {
                out.push((i, Region::new(closed[i].clone(), vec![])));
            }
        }
        for i in 0..closed.len() {
            if !depth[i].is_multiple_of(2) {
                if let Some(p) = parent[i] {
                    if let Some((_, r)) = out.iter_mut().find(|(k, _)| *k == p) {
                        let isl = closed[i].clone();
                        r.islands.push(if isl.area() > 0.0 {
                            isl.reversed()
                        } else {
                            isl
                        });
                    }
                }
            }
        }
        out.into_iter().map(|(_, r)| r).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The angle-based forms `sweep`, `point_at` and `angle_within` had before they were
    /// written with cross and dot products (the reference the new forms must agree with).
    fn angle_of(v: Point) -> f64 {
        v.y.atan2(v.x)
    }
    fn sweep_by_angles(a: Point, b: Point, c: Point, ccw: bool) -> f64 {
        let mut s = angle_of(b - c) - angle_of(a - c);
        if ccw {
            while s <= 0.0 {
                s += 2.0 * PI;
            }
        } else {
            while s >= 0.0 {
                s -= 2.0 * PI;
            }
        }
        s
    }

    #[test]
    fn arc_sweeps_points_and_bounds_agree_with_the_angle_based_forms() {
        let mut x: u64 = 0x2545_F491_4F6C_DD1D;
        let mut rnd = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut checked = 0;
        for _ in 0..20_000 {
            let a = Point::new(rnd() * 200.0 - 100.0, rnd() * 200.0 - 100.0);
            let b = Point::new(rnd() * 200.0 - 100.0, rnd() * 200.0 - 100.0);
            // bulges from a sliver to nearly a full turn, both ways
            let bulge = (0.001 + rnd() * 20.0) * if rnd() < 0.5 { 1.0 } else { -1.0 };
            let seg = Segment::from_bulge(a, b, bulge);
            let Segment::Arc {
                center: c,
                radius: r,
                ccw,
                ..
            } = seg
            else {
                continue;
            };
            let want = sweep_by_angles(a, b, c, ccw);
            assert!(
                (seg.sweep() - want).abs() <= 1e-12 * want.abs().max(1.0),
                "{seg:?}"
            );
            for t in [0.0, 0.25, 0.5, 0.9, 1.0] {
                let ang = angle_of(a - c) + want * t;
                let p = c + Point::new(ang.cos(), ang.sin()) * r;
                assert!(
                    seg.point_at(t).dist(p) <= 1e-9 * r.max(1.0),
                    "{seg:?} at {t}"
                );
                let tan = seg.tangent_at(t);
                let radial = (p - c).unit();
                assert!(tan.dot(radial).abs() < 1e-9 && (tan.len() - 1.0).abs() < 1e-12);
                assert!(radial.cross(tan) * if ccw { 1.0 } else { -1.0 } > 0.0);
            }
            // directions: within the sweep exactly when their angle from the start, taken
            // the arc's way, is at most the sweep (those within 1e-9 rad of an end skipped)
            for k in 0..16 {
                let th = k as f64 / 16.0 * 2.0 * PI + rnd() * 0.1;
                let v = Point::new(th.cos(), th.sin()) * (0.5 + rnd());
                let mut d = angle_of(v) - angle_of(a - c);
                if ccw {
                    while d < 0.0 {
                        d += 2.0 * PI;
                    }
                } else {
                    while d > 0.0 {
                        d -= 2.0 * PI;
                    }
                }
                if d.abs() < 1e-9 || (d - want).abs() < 1e-9 || (d.abs() - 2.0 * PI).abs() < 1e-9 {
                    continue;
                }
                let inside = if ccw { d <= want } else { d >= want };
                assert_eq!(seg.angle_within(v), inside, "{seg:?} direction {v:?}");
                checked += 1;
            }
            // bounds: the ends and every extreme point of the circle the sweep passes
            let bb = seg.bounds();
            let mut want_b = Bounds::EMPTY;
            want_b.add_point(a);
            want_b.add_point(b);
            for i in 0..=2000 {
                want_b.add_point(seg.point_at(i as f64 / 2000.0));
            }
            let slack = r * 2e-6 + 1e-9;
            assert!(bb.min.x <= want_b.min.x + 1e-9 && bb.min.x >= want_b.min.x - slack);
            assert!(bb.min.y <= want_b.min.y + 1e-9 && bb.min.y >= want_b.min.y - slack);
            assert!(bb.max.x >= want_b.max.x - 1e-9 && bb.max.x <= want_b.max.x + slack);
            assert!(bb.max.y >= want_b.max.y - 1e-9 && bb.max.y <= want_b.max.y + slack);
        }
        assert!(checked > 100_000, "{checked} directions checked");
        // a full turn (ends coincide) holds every direction
        let full = Segment::Arc {
            a: Point::new(1.0, 0.0),
            b: Point::new(1.0, 0.0),
            center: Point::default(),
            radius: 1.0,
            ccw: false,
        };
        assert!((full.sweep() + 2.0 * PI).abs() < 1e-15);
        for th in [0.1, 2.0, 4.0, 6.0] {
            assert!(full.angle_within(Point::new(f64::cos(th), f64::sin(th))));
        }
    }

    #[test]
    fn bulge_one_is_a_half_circle() {
        let s = Segment::from_bulge(Point::new(1.0, 0.0), Point::new(-1.0, 0.0), 1.0);
        match s {
            Segment::Arc {
                center,
                radius,
                ccw,
                ..
            } => {
                assert!(center.dist(Point::default()) < 1e-12);
                assert!((radius - 1.0).abs() < 1e-12);
                assert!(ccw);
            }
            _ => panic!("expected an arc"),
        }
        assert!((s.sweep() - PI).abs() < 1e-12);
        // ccw half circle from (1,0) to (-1,0) passes through (0,1)
        assert!(s.point_at(0.5).dist(Point::new(0.0, 1.0)) < 1e-12);
    }

    #[test]
    fn circle_area_and_bounds() {
        let c = Polyline::circle(Point::new(2.0, 3.0), 5.0);
        assert!((c.area() - PI * 25.0).abs() < 1e-9);
        let b = c.bounds();
        assert!((b.min.x + 3.0).abs() < 1e-12 && (b.max.y - 8.0).abs() < 1e-12);
        assert!((c.reversed().area() + PI * 25.0).abs() < 1e-9);
    }

    #[test]
    fn winding_with_arcs() {
        let c = Polyline::circle(Point::default(), 10.0);
        for (p, inside) in [
            (Point::new(0.0, 9.9), true),
            (Point::new(0.0, -9.9), true),
            (Point::new(9.0, 0.0), true),
            (Point::new(0.0, 10.1), false),
            (Point::new(7.2, 7.2), false),
            (Point::new(7.0, 7.0), true),
        ] {
            assert_eq!(c.contains(p), inside, "{p:?}");
            assert_eq!(c.reversed().contains(p), inside, "{p:?} reversed");
        }
        // a rectangle with one bulged side (half circle outward on the right)
        let d = Polyline::new(
            vec![
                Vertex::new(0.0, 0.0, 0.0),
                Vertex::new(10.0, 0.0, 1.0),
                Vertex::new(10.0, 10.0, 0.0),
                Vertex::new(0.0, 10.0, 0.0),
            ],
            true,
        );
        assert!(d.contains(Point::new(14.0, 5.0)));
        assert!(!d.contains(Point::new(15.5, 5.0)));
        assert!(d.contains(Point::new(5.0, 5.0)));
        let expect = 100.0 + PI * 25.0 / 2.0;
        assert!((d.area() - expect).abs() < 1e-9);
    }

    #[test]
    fn regions_nest_by_containment() {
        let outer = Polyline::rect(Point::new(0.0, 0.0), Point::new(100.0, 100.0)).reversed();
        let island = Polyline::rect(Point::new(10.0, 10.0), Point::new(50.0, 50.0));
        let inner = Polyline::rect(Point::new(20.0, 20.0), Point::new(30.0, 30.0));
        let other = Polyline::circle(Point::new(200.0, 0.0), 5.0);
        let regions = Shape::new(vec![inner, other, island, outer]).regions();
        assert_eq!(regions.len(), 3);
        let big = regions.iter().find(|r| r.islands.len() == 1).unwrap();
        assert!(big.outer.is_ccw());
        assert!(!big.islands[0].is_ccw());
        assert!((big.area() - (10000.0 - 1600.0)).abs() < 1e-9);
    }
}
