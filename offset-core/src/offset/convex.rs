//! Convex loops of lines: recognised in one pass, and shrunk without the global stage.
//!
//! A closed polygon whose every corner turns left by less than π and whose turns add up to
//! one full turn is convex and simple (a locally convex closed curve of total curvature 2π
//! bounds a convex set), so it needs no crossing search. Shrinking it by `o` gives the
//! intersection of its sides' half-planes moved inward by `o` (for a point inside a convex
//! polygon the distance to the boundary is the least distance to a side's line), which the
//! usual deque over half-planes sorted by angle makes in one pass; the sides already come
//! in that order. This is the case where the global stage costs most for least (a dense
//! circle shrunk almost to a point: every raw side lies within micrometres of every other
//! near the centre), and the result here is exact and checked before it is used: every
//! dropped side's half-plane must hold the vertex whose corner covers its direction, which
//! (the result being convex) means it holds the whole result. When the check fails, or the
//! loop seems to shrink away, the caller goes the general way.

use super::seg::Seg;
use crate::geom::Point;

/// Whether the closed loop `segs` (all lines) turns left at every corner by less than π and
/// once round in all: then it is convex and simple. Stops at the first arc or the first
/// corner that does not turn left (a gear's offset: at 100,000 vertices the whole pass
/// read 8 MB for an answer its first valley gives).
pub(super) fn is_convex_ccw(segs: &[Seg]) -> bool {
    let mut turns = Turns::default();
    for s in segs {
        turns.add(s);
        if turns.refused() {
            return false;
        }
    }
    turns.convex_ccw()
}

/// [`is_convex_ccw`] fed one segment at a time, in order round the loop (so the pass that
/// makes a loop's segments answers it on the way).
#[derive(Default)]
pub(super) struct Turns {
    first: Point,
    t_in: Point,
    segments: usize,
    arcs: bool,
    all_left: bool,
    east: usize,
}

impl Turns {
    #[inline(always)]
    pub(super) fn add(&mut self, s: &Seg) {
        self.arcs |= s.is_arc();
        let t_out = s.b - s.a;
        if self.segments == 0 {
            self.first = t_out;
            self.all_left = true;
        } else {
            self.corner(t_out);
        }
        self.t_in = t_out;
        self.segments += 1;
    }

    // each corner turns the direction counter-clockwise by less than π, so the direction
    // passes east (from below the x axis to on or above it) once per full turn
    fn corner(&mut self, t_out: Point) {
        if !above(self.t_in.cross(t_out), 0.0) {
            self.all_left = false;
        }
        self.east += usize::from(self.t_in.y < 0.0 && t_out.y >= 0.0);
    }

    /// Whether the segments added so far already rule the loop out (an arc, or a corner
    /// that does not turn left), whatever follows.
    #[inline(always)]
    pub(super) fn refused(&self) -> bool {
        self.arcs || !self.all_left
    }

    /// Whether the segments added make a loop (the last followed by the first) as
    /// `is_convex_ccw` asks.
    pub(super) fn convex_ccw(mut self) -> bool {
        if self.segments < 3 || self.arcs {
            return false;
        }
        self.corner(self.first);
        self.all_left && self.east == 1
    }
}

/// `x` > `y`, false for NaN (so `!above` refuses a NaN).
fn above(x: f64, y: f64) -> bool {
    x > y
}

fn direction(s: &Seg) -> Point {
    let d = s.b - s.a;
    d * (1.0 / d.len())
}

/// The convex loop `segs` (counter-clockwise, see `is_convex_ccw`) shrunk by `o` > 0:
/// true when `segs` now holds the result's sides, in order; false, leaving `segs` as they
/// were, when the result would be empty or could not be checked (the caller then takes the
/// general way, which also decides emptiness). The result takes the input's storage: a
/// dense loop's result is as long as it.
#[cfg(test)]
pub(super) fn shrink(segs: &mut Vec<Seg>, o: f64, eps: f64) -> bool {
    match shrunk(segs, o, eps) {
        Some(result) => {
            result.sides_into(segs);
            true
        }
        None => false,
    }
}

/// [`shrink`]'s result as its vertices (what the caller may resample without making the
/// sides: a dense loop at near collapse keeps all of its 100,000, 6.4 MB written and read
/// again as segments for 600 lines).
pub(super) struct Shrunk {
    pts: Vec<Point>,
    head: usize,
}

impl Shrunk {
    /// The result's vertices in order round it: side j runs from vertex j - 1 to vertex j
    /// (side 0 from the last vertex).
    pub(super) fn vertices(&self) -> &[Point] {
        &self.pts[self.head..]
    }

    /// The result's sides, in `segs` (in place of what it held).
    pub(super) fn sides_into(&self, segs: &mut Vec<Seg>) {
        let verts = self.vertices();
        segs.clear();
        let mut prev = verts[verts.len() - 1];
        segs.extend(verts.iter().map(|&v| {
            let s = Seg::line(prev, v);
            prev = v;
            s
        }));
    }
}

/// [`shrink`], the result as its vertices; None when the result would be empty or could
/// not be checked.
pub(super) fn shrunk(segs: &[Seg], o: f64, eps: f64) -> Option<Shrunk> {
    let m = segs.len();
    if !above(o, 0.0) || m < 3 {
        return None;
    }
    let mut scale: f64 = 1.0;
    // the sides' unit directions
    let dirs: Vec<Point> = segs
        .iter()
        .map(|s| {
            let a = s.a.x.abs().max(s.a.y.abs());
            if a > scale {
                scale = a;
            }
            direction(s)
        })
        .collect();
    let sides: &[Seg] = segs;
    // how far `q` lies left of side i moved by `o` to its left
    let left = |i: usize, q: Point| -> f64 { dirs[i].cross(q - sides[i].a) - o };
    // where the sides i and j moved meet: for neighbours from their corner (exact for
    // nearly parallel sides), else by intersecting the moved lines
    // (the corner before side j, from side i = j - 1: the common case, kept small)
    let corner = |i: usize, j: usize| -> Option<Point> {
        let (n1, n2) = (dirs[i].perp(), dirs[j].perp());
        let den = 1.0 + n1.dot(n2);
        if !above(den, 0.0) {
            return None;
        }
        Some(sides[j].a + (n1 + n2) * (o / den))
    };
    let meet = |i: usize, j: usize| -> Option<Point> {
        if j == i + 1 || (j == 0 && i == m - 1) {
            return corner(i, j);
        }
        let (da, db) = (dirs[i], dirs[j]);
        let den = da.cross(db);
        // more than a half turn apart (or parallel): their meeting point is behind them
        if !above(den, 1e-12) {
            return None;
        }
        let (pa, pb) = (sides[i].a + da.perp() * o, sides[j].a + db.perp() * o);
        let t = (pb - pa).cross(db) / den;
        Some(pa + da * t)
    };
    // how far outside a half-plane a point may lie and still count as inside it: rounding
    let slack = (eps * 1e-2).max(scale * 1e-13);
    // the kept lines, and where each meets the next (pts[i]: dq[i] with dq[i + 1]); lines
    // leave at the back, and rarely at the front (from `head` on are the kept ones)
    let mut dq: Vec<u32> = Vec::with_capacity(m);
    let mut pts: Vec<Point> = Vec::with_capacity(m);
    let mut head = 0;
    for k in 0..m {
        while pts.len() > head && left(k, pts[pts.len() - 1]) <= 0.0 {
            pts.pop();
            dq.pop();
        }
        while pts.len() > head && left(k, pts[head]) <= 0.0 {
            head += 1;
        }
        if dq.len() > head {
            let b = dq[dq.len() - 1] as usize;
            // a half turn or more from the line kept before: the result is empty, or
            // nearly so (the general way decides)
            if !above(dirs[b].cross(dirs[k]), 0.0) {
                return None;
            }
            match if b + 1 == k { corner(b, k) } else { meet(b, k) } {
                Some(x) => pts.push(x),
                None => return None,
            }
        }
        dq.push(k as u32);
    }
    loop {
        let n = dq.len() - head;
        if n < 3 {
            return None;
        }
        let (first, last) = (dq[head] as usize, dq[dq.len() - 1] as usize);
        if left(first, pts[pts.len() - 1]) <= 0.0 {
            pts.pop();
            dq.pop();
            continue;
        }
        if left(last, pts[head]) <= 0.0 {
            head += 1;
            continue;
        }
        let closing = meet(last, first)?;
        let (second, before_last) = (dq[head + 1] as usize, dq[dq.len() - 2] as usize);
        if !above(dirs[last].cross(dirs[first]), 0.0)
            || left(second, closing) <= 0.0
            || left(before_last, closing) <= 0.0
        {
            return None;
        }
        pts.push(closing);
        break;
    }
    let kept = &dq[head..];
    let verts = &pts[head..];
    let n = kept.len();
    // the check: each kept side runs forward between its two vertices, and each dropped
    // line's half-plane holds the vertex between the kept lines around it (the lines after
    // the last kept one and before the first are dropped ones too)
    let holds = |range: std::ops::Range<usize>, v: Point| -> bool {
        range.into_iter().all(|i| left(i, v) >= -slack)
    };
    for j in 0..n {
        let v0 = verts[if j == 0 { n - 1 } else { j - 1 }];
        let v1 = verts[j];
        let kj = kept[j] as usize;
        if (v1 - v0).dot(dirs[kj]) < -slack {
            return None;
        }
        let ok = if j + 1 < n {
            holds(kj + 1..kept[j + 1] as usize, v1)
        } else {
            holds(kj + 1..m, v1) && holds(0..kept[0] as usize, v1)
        };
        if !ok {
            return None;
        }
    }
    Some(Shrunk { pts, head })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn loop_of(pts: &[Point]) -> Vec<Seg> {
        (0..pts.len())
            .map(|i| Seg::line(pts[i], pts[(i + 1) % pts.len()]))
            .collect()
    }

    fn ngon(n: usize, r: f64) -> Vec<Seg> {
        let pts: Vec<Point> = (0..n)
            .map(|i| {
                let a = i as f64 / n as f64 * std::f64::consts::TAU;
                Point::new(r * a.cos(), r * a.sin())
            })
            .collect();
        loop_of(&pts)
    }

    #[test]
    fn convexity_is_recognised_and_refused_where_it_does_not_hold() {
        assert!(is_convex_ccw(&ngon(5, 1.0)));
        assert!(is_convex_ccw(&ngon(100_000, 10.0)));
        // clockwise, a reflex corner, a pentagram (left turns only, but twice round)
        let cw: Vec<Seg> = ngon(5, 1.0).iter().rev().map(|s| s.reversed()).collect();
        assert!(!is_convex_ccw(&cw));
        let dart = loop_of(&[
            Point::new(0.0, 0.0),
            Point::new(2.0, 0.0),
            Point::new(1.0, 0.5),
            Point::new(2.0, 2.0),
            Point::new(0.0, 2.0),
        ]);
        assert!(!is_convex_ccw(&dart));
        let star: Vec<Point> = (0..5)
            .map(|i| {
                let a = (2 * i) as f64 / 5.0 * std::f64::consts::TAU;
                Point::new(a.cos(), a.sin())
            })
            .collect();
        assert!(!is_convex_ccw(&loop_of(&star)));
    }

    /// Whether `q` lies at least `d` - `tol` inside every side of the convex loop `segs`.
    fn deep_inside(segs: &[Seg], q: Point, d: f64, tol: f64) -> bool {
        segs.iter().all(|s| direction(s).cross(q - s.a) >= d - tol)
    }

    #[test]
    fn a_shrunk_rectangle_is_the_rectangle_of_the_moved_sides() {
        let r = loop_of(&[
            Point::new(0.0, 0.0),
            Point::new(10.0, 0.0),
            Point::new(10.0, 4.0),
            Point::new(0.0, 4.0),
        ]);
        let mut out = r.clone();
        assert!(shrink(&mut out, 1.0, 1e-7), "a 8 × 2 rectangle");
        let want = [
            Point::new(1.0, 1.0),
            Point::new(9.0, 1.0),
            Point::new(9.0, 3.0),
            Point::new(1.0, 3.0),
        ];
        assert_eq!(out.len(), 4);
        for w in want {
            assert!(
                out.iter().any(|s| s.a.dist(w) < 1e-12),
                "{w:?} missing: {out:?}"
            );
        }
        // shrunk to nothing: left to the general way, the input as it was
        let mut gone = r.clone();
        assert!(!shrink(&mut gone, 2.5, 1e-7));
        assert_eq!(gone.len(), r.len());
        assert!(gone.iter().zip(&r).all(|(x, y)| x.a == y.a && x.b == y.b));
    }

    #[test]
    fn sides_that_shrink_away_are_dropped_and_every_vertex_keeps_its_distance() {
        // a triangle with a corner cut by a short side, and a slanted quadrilateral whose
        // short side goes as it shrinks: the result's vertices lie d from the input and
        // no nearer, and its sides are the kept lines
        let shapes = [
            loop_of(&[
                Point::new(0.0, 0.0),
                Point::new(10.0, 0.0),
                Point::new(10.1, 0.2),
                Point::new(0.0, 8.0),
            ]),
            loop_of(&[
                Point::new(0.0, 0.0),
                Point::new(6.0, 0.0),
                Point::new(6.3, 0.4),
                Point::new(6.2, 3.0),
                Point::new(-1.0, 5.0),
            ]),
        ];
        for segs in shapes {
            assert!(is_convex_ccw(&segs));
            for d in [0.05, 0.3, 1.0] {
                let mut out = segs.clone();
                assert!(shrink(&mut out, d, 1e-7), "empty at d {d}");
                assert!(out.len() >= 3 && out.len() <= segs.len());
                for s in &out {
                    assert!(deep_inside(&segs, s.a, d, 1e-9), "{:?} at d {d}", s.a);
                    // on some side's moved line
                    let on = segs
                        .iter()
                        .any(|t| (direction(t).cross(s.a - t.a) - d).abs() < 1e-9);
                    assert!(on, "{:?} lies on no moved side at d {d}", s.a);
                }
                assert!(is_convex_ccw(&out), "the result is not convex at d {d}");
            }
        }
    }

    #[test]
    fn the_shrink_agrees_with_the_general_way_on_random_convex_loops() {
        // convex loops (points on ellipses at sorted random angles, some dense, some with
        // long and tiny sides), shrunk from a hair to near collapse: the result of this
        // module and that of the raw offset with the global stage have the same area
        // (to rounding), and every vertex of one lies on the other's boundary
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let opts = super::super::OffsetOptions::default();
        let mut compared = 0;
        for case in 0..60 {
            let n = [5, 12, 40, 300, 2000][case % 5];
            let (ra, rb) = (1.0 + 20.0 * rnd(), 1.0 + 20.0 * rnd());
            let (cx, cy) = (100.0 * rnd() - 50.0, 100.0 * rnd() - 50.0);
            let mut angles: Vec<f64> = (0..n).map(|_| rnd() * std::f64::consts::TAU).collect();
            angles.sort_by(f64::total_cmp);
            let pts: Vec<Point> = angles
                .iter()
                .map(|a| Point::new(cx + ra * a.cos(), cy + rb * a.sin()))
                .collect();
            let pl = crate::geom::Polyline::from_points(&pts, true);
            let eps = super::super::geometric_eps(opts.tolerance, &[&pl]);
            // as the kernel cleans its input (sides shorter than eps merged away)
            let segs = super::super::clean(&pl, eps);
            if !is_convex_ccw(&segs) {
                continue;
            }
            let inr = ra.min(rb);
            for f in [1e-3, 0.2, 0.6, 0.9, 0.999] {
                let o = f * inr;
                let mut fast = segs.clone();
                if !shrink(&mut fast, o, eps) {
                    continue;
                }
                let fast = super::super::finish(vec![(fast, true)], &opts, eps).loops;
                let general = super::super::run(
                    &[(segs.clone(), true)],
                    &[],
                    Default::default(),
                    o,
                    &opts,
                    eps,
                )
                .loops;
                assert_eq!(fast.len(), 1, "case {case}, o {o}");
                // the general way may leave sliver loops of a few nm² beside the loop
                // (seen on the dense ones: up to 7 of them, 6e-9 mm² at most): compare
                // with its largest loop
                let main = general
                    .iter()
                    .max_by(|x, y| x.area.abs().total_cmp(&y.area.abs()))
                    .expect("the general way's loop");
                assert!(
                    general
                        .iter()
                        .all(|l| std::ptr::eq(l, main) || l.area.abs() < 1e-6),
                    "case {case}, o {o}: the general way made a second loop"
                );
                let (a, b) = (fast[0].area, main.area);
                assert!(
                    (a - b).abs() <= 1e-6 * (1.0 + b.abs()),
                    "case {case}, n {n}, o {o}: area {a} against {b}"
                );
                let gv = &main.poly.vertices;
                let bsegs: Vec<Seg> = (0..gv.len())
                    .map(|i| {
                        let (p, q) = (gv[i], gv[(i + 1) % gv.len()]);
                        Seg::from_bulge(p.pos(), q.pos(), p.bulge)
                    })
                    .collect();
                let slack = super::super::slack(opts.tolerance, eps);
                for v in &fast[0].poly.vertices {
                    let q = v.pos();
                    let d = bsegs
                        .iter()
                        .map(|s| s.dist(q))
                        .fold(f64::INFINITY, f64::min);
                    assert!(d <= 2.0 * slack, "case {case}, o {o}: {q:?} is {d} off");
                }
                compared += 1;
            }
        }
        assert!(compared > 150, "only {compared} shrinks compared");
    }
}
