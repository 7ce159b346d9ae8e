//! The kernel's working segment (a line or an arc with its centre, radius and signed sweep)
//! and the exact intersections of two of them.

use crate::geom::{hi, lo, Point, Segment};
use std::f64::consts::PI;

/// A line (`sw == 0`) or a circular arc about `c` of radius `r` from `a`, sweeping `sw`
/// radians (positive counter-clockwise) to `b`. The start angle is not kept (`start_angle`
/// derives it for the few places that want an angle): a segment is then eight words, and the
/// raw offsets, the index and the prune copy and read hundreds of thousands of them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Seg {
    pub a: Point,
    pub b: Point,
    pub c: Point,
    pub r: f64,
    pub sw: f64,
}

// eight words: a field added here costs every copy of every segment a ninth
const _: () = assert!(std::mem::size_of::<Seg>() == 64);

/// Fast Euclidean norm (no overflow guard: coordinates are finite and far below 1e150).
pub trait Norm {
    fn norm(self) -> f64;
}

impl Norm for Point {
    #[inline]
    fn norm(self) -> f64 {
        (self.x * self.x + self.y * self.y).sqrt()
    }
}

/// atan2(`cr`, `dt`): the signed angle from one direction to another, given their cross
/// and dot products. Within a quarter radian of straight on (a round join at a corner of a
/// dense polyline, the common case) from atan's series, thirteen terms: each one past them
/// is below 1e-17 of the angle, and the sum is within two units in the last place of
/// atan2's (test `the_series_angle_is_atan2s`), in a third of atan2's instructions.
pub fn angle(cr: f64, dt: f64) -> f64 {
    if dt > 0.0 && cr.abs() <= 0.25 * dt {
        let z = cr / dt;
        let w = z * z;
        // 1 - w/3 + w²/5 - ... + w¹²/25, by Horner's rule
        const SERIES: [f64; 12] = [
            -1.0 / 23.0,
            1.0 / 21.0,
            -1.0 / 19.0,
            1.0 / 17.0,
            -1.0 / 15.0,
            1.0 / 13.0,
            -1.0 / 11.0,
            1.0 / 9.0,
            -1.0 / 7.0,
            1.0 / 5.0,
            -1.0 / 3.0,
            1.0,
        ];
        let mut p = 1.0 / 25.0;
        for c in SERIES {
            p = p * w + c;
        }
        z * p
    } else {
        cr.atan2(dt)
    }
}

/// Wraps an angle into [-π, π).
pub fn wrap(a: f64) -> f64 {
    const TAU: f64 = 2.0 * PI;
    let y = a + PI;
    // within a turn of the range the remainder is y itself or y less one turn (exact, as
    // the remainder is): the same numbers without the division's loop
    let x = if (0.0..TAU).contains(&y) {
        y
    } else if y < 0.0 && y > -TAU {
        y + TAU
    } else if (TAU..2.0 * TAU).contains(&y) {
        y - TAU
    } else {
        let x = y % TAU;
        if x < 0.0 {
            x + TAU
        } else {
            x
        }
    };
    x - PI
}

impl Seg {
    pub fn line(a: Point, b: Point) -> Seg {
        Seg {
            a,
            b,
            c: Point::default(),
            r: 0.0,
            sw: 0.0,
        }
    }

    /// The arc about `c` from `a` to `b` sweeping `sw` (its sign gives the direction).
    pub fn arc(c: Point, r: f64, a: Point, b: Point, sw: f64) -> Seg {
        if sw == 0.0 || r <= 0.0 || !r.is_finite() {
            return Seg::line(a, b);
        }
        Seg { a, b, c, r, sw }
    }

    /// The segment from `a` to `b` with a DXF bulge.
    pub fn from_bulge(a: Point, b: Point, bulge: f64) -> Seg {
        // what `Segment::from_bulge` makes of a bulge this small, without the chord's root
        if bulge.abs() < 1e-12 {
            return Seg::line(a, b);
        }
        match Segment::from_bulge(a, b, bulge) {
            Segment::Line { a, b } => Seg::line(a, b),
            Segment::Arc {
                a,
                b,
                center,
                radius,
                ..
            } => Seg::arc(center, radius, a, b, 4.0 * bulge.atan()),
        }
    }

    /// The angle of the arc's start `a` about its centre (the few callers that need an
    /// angle derive it: most of the kernel asks cross products instead).
    pub fn start_angle(&self) -> f64 {
        let v = self.a - self.c;
        v.y.atan2(v.x)
    }

    pub fn is_arc(&self) -> bool {
        self.sw != 0.0
    }

    /// tan(sw / 4), the polyline's bulge. Up to 2 radians of sweep it comes from the half
    /// chord h, no trigonometry: r sin(sw / 2) = h, r cos(sw / 2) = √(r² − h²), and
    /// tan(x / 2) = sin x / (1 + cos x), a form that keeps its precision on short arcs
    /// (nearer a half turn the root would lose it, so `tan` there).
    pub fn bulge(&self) -> f64 {
        if !self.is_arc() {
            0.0
        } else if self.sw.abs() <= 2.0 {
            let h = 0.5 * (self.b - self.a).norm();
            let c = (self.r * self.r - h * h).max(0.0).sqrt();
            (h / (self.r + c)).copysign(self.sw)
        } else {
            (self.sw / 4.0).tan()
        }
    }

    pub fn length(&self) -> f64 {
        if self.is_arc() {
            self.r * self.sw.abs()
        } else {
            (self.b - self.a).norm()
        }
    }

    /// The squared length: no root for a line (to compare lengths, or a length with a
    /// bound, in the passes over every segment).
    pub fn length2(&self) -> f64 {
        if self.is_arc() {
            let l = self.r * self.sw;
            l * l
        } else {
            let d = self.b - self.a;
            d.dot(d)
        }
    }

    /// Whether the segment is shorter than `len` (≥ 0), by its squared length.
    pub fn shorter_than(&self, len: f64) -> bool {
        self.length2() < len * len
    }

    /// The parameter (0 at `a`, 1 at `b`) of the point of the segment's line or circle
    /// nearest `p`; outside [0, 1] when `p` lies beyond an end.
    pub fn param(&self, p: Point) -> f64 {
        if self.is_arc() {
            // the angle from the start to `p` about the centre: one atan2, as with a stored
            // start angle
            let (u, v) = (self.a - self.c, p - self.c);
            let d = wrap(angle(u.cross(v), u.dot(v)) - self.sw * 0.5);
            (d + self.sw * 0.5) / self.sw
        } else {
            let ab = self.b - self.a;
            let l2 = ab.dot(ab);
            if l2 == 0.0 {
                0.0
            } else {
                (p - self.a).dot(ab) / l2
            }
        }
    }

    pub fn point_at(&self, t: f64) -> Point {
        if t <= 0.0 {
            return self.a;
        }
        if t >= 1.0 {
            return self.b;
        }
        if self.is_arc() {
            let ang = self.start_angle() + self.sw * t;
            self.c + Point::new(ang.cos(), ang.sin()) * self.r
        } else {
            self.a.lerp(self.b, t)
        }
    }

    /// Unit tangent in the direction of travel at parameter t.
    pub fn tangent_at(&self, t: f64) -> Point {
        if self.is_arc() {
            let rad = if t <= 0.0 {
                (self.a - self.c) * (1.0 / self.r)
            } else if t >= 1.0 {
                (self.b - self.c) * (1.0 / self.r)
            } else {
                let ang = self.start_angle() + self.sw * t;
                Point::new(ang.cos(), ang.sin())
            };
            if self.sw > 0.0 {
                rad.perp()
            } else {
                -rad.perp()
            }
        } else {
            (self.b - self.a).unit()
        }
    }

    /// The part between parameters t0 < t1, with the given exact end points.
    pub fn sub(&self, t0: f64, p0: Point, t1: f64, p1: Point) -> Seg {
        if self.is_arc() {
            Seg {
                a: p0,
                b: p1,
                c: self.c,
                r: self.r,
                sw: self.sw * (t1 - t0),
            }
        } else {
            Seg::line(p0, p1)
        }
    }

    /// The same segment run backwards.
    pub fn reversed(&self) -> Seg {
        if self.is_arc() {
            Seg {
                a: self.b,
                b: self.a,
                c: self.c,
                r: self.r,
                sw: -self.sw,
            }
        } else {
            Seg::line(self.b, self.a)
        }
    }

    /// Whether the direction of `p` from the centre lies within the sweep.
    pub(super) fn within_sweep(&self, p: Point) -> bool {
        let v = p - self.c;
        let s = self.sw.signum();
        let after_start = s * (self.a - self.c).cross(v) >= 0.0;
        let before_end = s * v.cross(self.b - self.c) >= 0.0;
        if self.sw.abs() <= PI {
            after_start && before_end
        } else {
            after_start || before_end
        }
    }

    pub fn closest_point(&self, p: Point) -> Point {
        if self.is_arc() {
            let v = p - self.c;
            if v.norm() > 0.0 && self.within_sweep(p) {
                return self.c + v * (self.r / v.norm());
            }
            if (p - self.a).norm() <= (p - self.b).norm() {
                self.a
            } else {
                self.b
            }
        } else {
            let ab = self.b - self.a;
            let l2 = ab.dot(ab);
            if l2 == 0.0 {
                return self.a;
            }
            let t = ((p - self.a).dot(ab) / l2).clamp(0.0, 1.0);
            self.a.lerp(self.b, t)
        }
    }

    pub fn dist(&self, p: Point) -> f64 {
        (p - self.closest_point(p)).norm()
    }

    /// Bounding box as [min x, min y, max x, max y].
    pub fn bbox(&self) -> [f64; 4] {
        let mut bb = [
            lo(self.a.x, self.b.x),
            lo(self.a.y, self.b.y),
            hi(self.a.x, self.b.x),
            hi(self.a.y, self.b.y),
        ];
        if self.is_arc() {
            // `within_sweep` of the four axis directions, its cross products written out (a
            // unit axis has one zero coordinate, so each is a signed coordinate of the
            // ends' radii: the same signs)
            let (ua, ub) = (self.a - self.c, self.b - self.c);
            let s = self.sw.signum();
            let wide = self.sw.abs() > PI;
            let within = |after_start: bool, before_end: bool| {
                if wide {
                    after_start || before_end
                } else {
                    after_start && before_end
                }
            };
            let r = self.r;
            if within(s * -ua.y >= 0.0, s * ub.y >= 0.0) {
                bb[2] = hi(bb[2], self.c.x + r);
            }
            if within(s * ua.x >= 0.0, s * -ub.x >= 0.0) {
                bb[3] = hi(bb[3], self.c.y + r);
            }
            if within(s * ua.y >= 0.0, s * -ub.y >= 0.0) {
                bb[0] = lo(bb[0], self.c.x - r);
            }
            if within(s * -ua.x >= 0.0, s * ub.x >= 0.0) {
                bb[1] = lo(bb[1], self.c.y - r);
            }
        }
        bb
    }

    /// Twice the signed area this segment adds to a closed loop.
    pub fn area2(&self) -> f64 {
        self.area2_about(Point::new(0.0, 0.0))
    }

    /// Twice the signed area this segment adds to a loop closed by a chord through `o`:
    /// summed over a chain of segments from `o`, the area of the chain closed by the chord
    /// from its end back to `o`, whether or not it ends there (about the origin, a chain
    /// that ends a hair from its start adds the area of the sliver between the two ends and
    /// the origin, which grows with the distance from it).
    pub fn area2_about(&self, o: Point) -> f64 {
        let chord = (self.a - o).cross(self.b - o);
        if self.is_arc() {
            chord + self.r * self.r * (self.sw - self.sw.sin())
        } else {
            chord
        }
    }
}

/// Where two segments meet: up to two points, each with its parameter on both.
#[derive(Clone, Copy, Debug, Default)]
pub struct Hits {
    pub n: usize,
    pub p: [(Point, f64, f64); 2],
}

impl Hits {
    fn push(&mut self, p: Point, t: f64, u: f64) {
        if self.n < 2 {
            // two hits closer than the caller's tolerance are one (tangency)
            self.p[self.n] = (p, t, u);
            self.n += 1;
        }
    }
    pub fn iter(&self) -> impl Iterator<Item = (Point, f64, f64)> + '_ {
        self.p[..self.n].iter().copied()
    }
}

/// Parameter slack on `s` that corresponds to a distance `eps` along it.
fn slack(s: &Seg, eps: f64) -> f64 {
    let l = s.length();
    if l > 0.0 {
        eps / l
    } else {
        0.0
    }
}

/// The points where `s1` and `s2` meet, within `eps`. Overlapping collinear lines and
/// overlapping arcs of one circle report the ends of their overlap.
pub fn intersect(s1: &Seg, s2: &Seg, eps: f64) -> Hits {
    match (s1.is_arc(), s2.is_arc()) {
        (false, false) => line_line(s1, s2, eps),
        (false, true) => line_arc(s1, s2, eps, false),
        (true, false) => line_arc(s2, s1, eps, true),
        (true, true) => arc_arc(s1, s2, eps),
    }
}

/// `accept(arc.param(p), e)` for a point `p` on the arc's circle, where `e` stands for a
/// length `eps` along the arc: a point outside the sweep (decided by cross products) and
/// more than 2 `eps` from both ends lies more than `eps` of arc beyond an end, so it is
/// refused without the `atan2` of `param` (the distances compared squared, without their
/// roots: the prune asks this of every crossing of an arc).
fn accept_on_arc(arc: &Seg, p: Point, e: f64, eps: f64) -> Option<f64> {
    let (to_a, to_b) = (p - arc.a, p - arc.b);
    let near = 4.0 * eps * eps;
    if !arc.within_sweep(p) && to_a.dot(to_a) > near && to_b.dot(to_b) > near {
        return None;
    }
    accept(arc.param(p), e)
}

fn accept(t: f64, e: f64) -> Option<f64> {
    if t >= -e && t <= 1.0 + e {
        Some(t.clamp(0.0, 1.0))
    } else {
        None
    }
}

fn line_line(s1: &Seg, s2: &Seg, eps: f64) -> Hits {
    let mut h = Hits::default();
    let o = s1.a;
    let d1 = s1.b - s1.a;
    let d2 = s2.b - s2.a;
    let a2 = s2.a - o;
    let b2 = s2.b - o;
    let l1 = d1.norm();
    let l2 = d2.norm();
    if l1 == 0.0 || l2 == 0.0 {
        return h;
    }
    // distances of s2's ends from s1's line
    let da = d1.cross(a2) / l1;
    let db = d1.cross(b2) / l1;
    let den = d1.cross(d2);
    if da.abs() <= eps && db.abs() <= eps {
        // collinear: report the ends of the overlap
        let ta = a2.dot(d1) / (l1 * l1);
        let tb = b2.dot(d1) / (l1 * l1);
        let (lo, hi) = (ta.min(tb).max(0.0), ta.max(tb).min(1.0));
        let e = eps / l1;
        if lo > hi + e {
            return h;
        }
        for t in [lo, hi] {
            let t = t.clamp(0.0, 1.0);
            let p = s1.point_at(t);
            let u = s2.param(p).clamp(0.0, 1.0);
            if h.n == 1 && (h.p[0].1 - t).abs() * l1 <= eps {
                continue;
            }
            h.push(p, t, u);
        }
        return h;
    }
    if den.abs() <= f64::EPSILON * l1 * l2 {
        return h;
    }
    let t = a2.cross(d2) / den;
    let u = a2.cross(d1) / den;
    if let (Some(t), Some(u)) = (accept(t, eps / l1), accept(u, eps / l2)) {
        h.push(s1.point_at(t), t, u);
    }
    h
}

/// `l` a line, `c` an arc; `swap` reports the parameters as (arc, line).
fn line_arc(l: &Seg, c: &Seg, eps: f64, swap: bool) -> Hits {
    let mut h = Hits::default();
    let o = c.c;
    let a = l.a - o;
    let d = l.b - l.a;
    let len = d.norm();
    if len == 0.0 {
        return h;
    }
    let dir = d * (1.0 / len);
    // foot of the centre on the line, relative to the centre
    let s0 = -a.dot(dir);
    let foot = a + dir * s0;
    let hd = foot.norm();
    let r = c.r;
    if hd > r + eps {
        return h;
    }
    let (el, ea) = (eps / len, slack(c, eps));
    // the point `s` along the line, with its parameters in the caller's order, when it lies
    // on both
    let on_both = |s: f64| -> Option<(Point, f64, f64)> {
        let t = accept(s / len, el)?;
        let p = l.point_at(t);
        let u = accept_on_arc(c, p, ea, eps)?;
        Some(if swap { (p, u, t) } else { (p, t, u) })
    };
    // the two crossings lie k either side of the foot
    let k = ((r - hd) * (r + hd)).max(0.0).sqrt();
    if hd >= r - eps {
        // tangent within eps: one point
        if let Some((p, t, u)) = on_both(s0) {
            h.push(p, t, u);
        } else if hd < r {
            // a graze taken as one touching point that lies just off an end: the two
            // crossings it stands for lie up to √(2 r ε) either side of it, and one of them
            // may still lie on both (a line through an arc's end at a shallow angle, as
            // where an offset arc meets the offset of a line it was nearly tangent to)
            if let Some((p, t, u)) = [s0 - k, s0 + k].into_iter().find_map(on_both) {
                h.push(p, t, u);
            }
        }
    } else {
        for (p, t, u) in [s0 - k, s0 + k].into_iter().filter_map(on_both) {
            h.push(p, t, u);
        }
    }
    h
}

fn arc_arc(s1: &Seg, s2: &Seg, eps: f64) -> Hits {
    let mut h = Hits::default();
    let dv = s2.c - s1.c;
    let d = dv.norm();
    let (r1, r2) = (s1.r, s2.r);
    let e1 = slack(s1, eps);
    let e2 = slack(s2, eps);
    if d <= eps && (r1 - r2).abs() <= eps {
        // one circle: the ends of either arc that lie on the other
        for p in [s1.a, s1.b, s2.a, s2.b] {
            let (Some(t), Some(u)) = (accept(s1.param(p), e1), accept(s2.param(p), e2)) else {
                continue;
            };
            if h.iter().any(|(q, _, _)| (q - p).norm() <= eps) {
                continue;
            }
            h.push(p, t, u);
        }
        return h;
    }
    if d == 0.0 || d > r1 + r2 + eps || d < (r1 - r2).abs() - eps {
        return h;
    }
    // measured from the smaller circle, with differences of squares factored: beside a
    // nearly straight arc (radius 5e5 next to coordinates of 10) the foot of the common
    // chord, measured from the huge circle's centre, would keep only a few digits of its
    // distance to that circle and put the crossings a micrometre off
    let (cs, rs, rl, toward) = if r1 <= r2 {
        (s1.c, r1, r2, dv)
    } else {
        (s2.c, r2, r1, -dv)
    };
    let a = ((rs - rl) * (rs + rl) + d * d) / (2.0 * d);
    let u = toward * (1.0 / d);
    let hh = (rs - a) * (rs + a);
    let base = cs + u * a;
    // tangent within eps: two circles that far from touching part by about s² / (2ρ) at a
    // distance s from the contact, ρ = r1 r2 / (r1 + r2) (at most the smaller radius), so
    // their two crossings lie within √(2 ρ eps) of each other. Scaling by r1 alone let a
    // nearly straight arc (radius 4e5) merge crossings half a millimetre apart.
    let rho = r1 * r2 / (r1 + r2);
    let pts: [Option<Point>; 2] = if hh <= (eps * rho).max(0.0) * 2.0 || hh <= 0.0 {
        [Some(base), None]
    } else {
        let k = hh.sqrt();
        if k <= eps {
            [Some(base), None]
        } else {
            [Some(base + u.perp() * k), Some(base - u.perp() * k)]
        }
    };
    // (the second arc is asked only when the point lies on the first)
    let on_both = |p: Point| -> Option<(f64, f64)> {
        let t = accept_on_arc(s1, p, e1, eps)?;
        Some((t, accept_on_arc(s2, p, e2, eps)?))
    };
    for p in pts.into_iter().flatten() {
        let Some((t, w)) = on_both(p) else {
            continue;
        };
        h.push(p, t, w);
    }
    if h.n == 0 && pts[1].is_none() && hh > 0.0 {
        // a graze taken as one touching point that lies just off an arc's end: one of the
        // two crossings it stands for may still lie on both arcs (a curve grazing a nearly
        // collapsed offset arc enters its circle beside the arc and leaves through it)
        let k = hh.sqrt();
        for p in [base + u.perp() * k, base - u.perp() * k] {
            if let Some((t, w)) = on_both(p) {
                h.push(p, t, w);
                break;
            }
        }
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_series_angle_is_atan2s() {
        // directions on both sides of the series' edge (a quarter radian), tiny turns,
        // both signs, vectors of many lengths; within two units in the last place
        let mut rnd = crate::test_rng::uniform(7);
        for k in 0..200_000 {
            let a = match k % 4 {
                0 => (rnd() - 0.5) * 0.3,
                1 => (rnd() - 0.5) * 1e-6,
                2 => 0.25f64.atan() * (1.0 + (rnd() - 0.5) * 1e-9),
                _ => (rnd() - 0.5) * 6.5,
            };
            let scale = 10f64.powf(rnd() * 12.0 - 6.0);
            let (cr, dt) = (a.sin() * scale, a.cos() * scale);
            let (ours, libm) = (angle(cr, dt), cr.atan2(dt));
            let ulp = f64::EPSILON * libm.abs().max(f64::MIN_POSITIVE);
            assert!(
                (ours - libm).abs() <= 2.0 * ulp,
                "angle({cr:e}, {dt:e}) = {ours:e}, atan2 {libm:e}"
            );
        }
    }

    #[test]
    fn crossing_lines_and_overlaps() {
        let s1 = Seg::line(Point::new(0.0, 0.0), Point::new(2.0, 2.0));
        let s2 = Seg::line(Point::new(0.0, 2.0), Point::new(2.0, 0.0));
        let h = intersect(&s1, &s2, 1e-9);
        assert_eq!(h.n, 1);
        assert!(h.p[0].0.dist(Point::new(1.0, 1.0)) < 1e-12);
        let s3 = Seg::line(Point::new(1.0, 1.0), Point::new(3.0, 3.0));
        let h = intersect(&s1, &s3, 1e-9);
        assert_eq!(h.n, 2);
    }

    #[test]
    fn arcs_meet_lines_and_arcs() {
        let c = Seg::from_bulge(Point::new(1.0, 0.0), Point::new(-1.0, 0.0), 1.0);
        let l = Seg::line(Point::new(0.0, -2.0), Point::new(0.0, 2.0));
        let h = intersect(&l, &c, 1e-9);
        assert_eq!(h.n, 1);
        assert!(h.p[0].0.dist(Point::new(0.0, 1.0)) < 1e-12);
        assert!((h.p[0].2 - 0.5).abs() < 1e-12);
        let c2 = Seg::from_bulge(Point::new(0.0, 0.0), Point::new(0.0, 2.0), -1.0);
        let h = intersect(&c, &c2, 1e-9);
        assert_eq!(h.n, 1, "{h:?}");
        assert!((h.p[0].0.dist(Point::default()) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn a_line_grazing_an_arc_through_its_end_meets_it_there() {
        // a chord 5.4e-7 inside a circle of radius 3 (a graze within ε = 1e-6): its two
        // crossings lie 1.8e-3 either side of the top, and the arc ends at the left one
        let (r, a) = (3.0f64, 0.0006f64);
        let end = Point::new(-r * a.sin(), r * a.cos());
        let start = Point::new(-r * (a + 0.3).sin(), r * (a + 0.3).cos());
        let arc = Seg::arc(Point::new(0.0, 0.0), r, start, end, -0.3);
        let line = Seg::line(Point::new(-1.0, end.y), Point::new(1.0, end.y));
        for (h, arc_first) in [
            (intersect(&line, &arc, 1e-6), false),
            (intersect(&arc, &line, 1e-6), true),
        ] {
            assert_eq!(h.n, 1, "{h:?}");
            assert!(h.p[0].0.dist(end) < 1e-9, "{h:?}");
            let on_arc = if arc_first { h.p[0].1 } else { h.p[0].2 };
            assert!((on_arc - 1.0).abs() < 1e-9, "{h:?}");
        }
    }

    #[test]
    fn arc_boxes_are_the_sweep_tests_boxes() {
        // the box as it was written before its cross products were written out: each axis
        // direction's extreme when `within_sweep` holds of it
        let by_sweep = |s: &Seg| {
            let mut bb = [
                s.a.x.min(s.b.x),
                s.a.y.min(s.b.y),
                s.a.x.max(s.b.x),
                s.a.y.max(s.b.y),
            ];
            for (k, d) in [
                Point::new(1.0, 0.0),
                Point::new(0.0, 1.0),
                Point::new(-1.0, 0.0),
                Point::new(0.0, -1.0),
            ]
            .into_iter()
            .enumerate()
            {
                if s.within_sweep(s.c + d) {
                    let q = s.c + d * s.r;
                    match k {
                        0 => bb[2] = bb[2].max(q.x),
                        1 => bb[3] = bb[3].max(q.y),
                        2 => bb[0] = bb[0].min(q.x),
                        _ => bb[1] = bb[1].min(q.y),
                    }
                }
            }
            bb
        };
        let mut rnd = crate::test_rng::uniform(7);
        for i in 0..100_000 {
            let c = Point::new(rnd() * 2000.0 - 1000.0, rnd() * 2000.0 - 1000.0);
            let r = 10f64.powf(rnd() * 8.0 - 4.0);
            // starts anywhere, and on the axes (quarter turns) a fifth of the time
            let sa = if i % 5 == 0 {
                (rnd() * 8.0).floor() * PI / 2.0
            } else {
                rnd() * 4.0 * PI - 2.0 * PI
            };
            let sw = if i % 7 == 0 {
                ((rnd() * 8.0).floor() - 4.0) * PI / 2.0
            } else {
                rnd() * 4.0 * PI - 2.0 * PI
            };
            if sw == 0.0 {
                continue;
            }
            let at = |t: f64| c + Point::new(t.cos(), t.sin()) * r;
            let s = Seg::arc(c, r, at(sa), at(sa + sw), sw);
            assert_eq!(s.bbox(), by_sweep(&s), "{s:?}");
        }
    }

    #[test]
    fn wrapping_is_the_remainders_wrap() {
        // the wrap by the remainder, as it was written before its fast paths
        let by_remainder = |a: f64| {
            let mut x = (a + PI) % (2.0 * PI);
            if x < 0.0 {
                x += 2.0 * PI;
            }
            x - PI
        };
        let mut rnd = crate::test_rng::uniform(42);
        let mut angles: Vec<f64> = (0..100_000).map(|_| (rnd() - 0.5) * 40.0).collect();
        for k in -6..=6 {
            let edge = k as f64 * PI;
            angles.extend([edge, edge.next_up(), edge.next_down(), -edge]);
        }
        angles.extend([0.0, -0.0, 1e300, -1e300, 3.0 * PI, -3.0 * PI, -PI, PI]);
        for a in angles {
            assert_eq!(wrap(a).to_bits(), by_remainder(a).to_bits(), "wrap({a:e})");
        }
    }

    #[test]
    fn the_bulge_from_the_half_chord_is_tan_of_a_quarter_sweep() {
        // short and long arcs, both ways round, small and large radii far from the origin
        for &r in &[1e-3, 0.7, 4.4, 400.0] {
            for &sw in &[1e-9, 1e-4, 0.1, 0.46, 1.5, 1.999, 2.0, 2.001, 3.0, 6.0] {
                for sign in [1.0, -1.0] {
                    let sw = sw * sign;
                    let c = Point::new(1000.0, -250.0);
                    let a0: f64 = 0.3;
                    let a = c + Point::new(a0.cos(), a0.sin()) * r;
                    let b = c + Point::new((a0 + sw).cos(), (a0 + sw).sin()) * r;
                    let arc = Seg { a, b, c, r, sw };
                    let want = (sw / 4.0).tan();
                    // the ends carry the rounding of coordinates near 1000 (1e-13): as
                    // much of the chord, so of the bulge, relative to the arc's size
                    let tol = 1e-12 * want.abs() + 4e-13 / r;
                    assert!(
                        (arc.bulge() - want).abs() <= tol,
                        "r {r} sw {sw}: {} against {want}",
                        arc.bulge()
                    );
                }
            }
        }
    }

    #[test]
    fn params_and_bulges_round_trip() {
        let c = Seg::from_bulge(Point::new(1.0, 0.0), Point::new(0.0, 1.0), -0.3);
        assert!((c.bulge() + 0.3).abs() < 1e-12);
        assert!(c.param(c.point_at(0.3)) - 0.3 < 1e-12);
        let r = c.reversed();
        assert!(r.point_at(0.25).dist(c.point_at(0.75)) < 1e-12);
        assert!((c.area2() + r.area2()).abs() < 1e-12);
    }
}
