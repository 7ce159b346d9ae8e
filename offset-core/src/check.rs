//! The offset checker: how far every point of an offset lies from the shape it came from,
//! against the distance asked for, and whether every point that should have an offset has
//! one (exact point-to-segment distances through an R-tree, both ways).

use crate::geom::{Point, Polyline};
use crate::offset::index::{BBox, BoxIndex};
use crate::offset::seg::Seg;

/// The worst deviations found, and where.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Report {
    /// The most any output sample lies farther than |d| from the input (0 when none does).
    pub too_far: f64,
    pub far_at: Point,
    /// The most any output sample lies nearer than |d| to the input (0 when none does).
    pub too_close: f64,
    pub close_at: Point,
    /// How many output points were measured.
    pub samples: usize,
    /// The other way: the most any point that should be on the offset (an input point moved
    /// |d| along its normal to the offset's side, where nothing else of the input is nearer)
    /// lies from the output, when that is more than half the tolerance (0 otherwise);
    /// infinite when such points exist and the output is empty.
    pub missing: f64,
    /// Where the offset should have passed but did not.
    pub missing_at: Point,
    /// How many input points were expected to have an offset: those the output passes
    /// within half the tolerance, and those it misses by more that should have one.
    pub expected: usize,
}

impl Report {
    /// The largest of the three deviations (too far, too close, missing).
    pub fn worst(&self) -> f64 {
        self.too_far.max(self.too_close).max(self.missing)
    }
    /// Whether every deviation is within `tolerance`.
    pub fn within(&self, tolerance: f64) -> bool {
        self.worst() <= tolerance
    }
}

/// At most this many input points are sampled per input segment for the missing check.
const MAX_COVERAGE_SAMPLES: usize = 256;

/// The input shape's segments in an R-tree, with the side of each on which a region lies.
pub struct Checker {
    segs: Vec<Seg>,
    index: BoxIndex,
    /// Per segment, the unit multiplier of its left normal that points into the region it
    /// bounds (closed paths, by even-odd nesting), or `None` for a segment of an open path.
    inside: Vec<Option<f64>>,
    /// Per segment, the closed input path it belongs to (`None` for an open path's).
    path: Vec<Option<usize>>,
}

fn segments(paths: &[Polyline]) -> Vec<Seg> {
    let mut segs = Vec::new();
    for p in paths {
        if p.len() == 1 {
            let v = p.vertices[0].pos();
            segs.push(Seg::line(v, v));
        }
        for i in 0..p.segment_count() {
            let a = p.vertices[i];
            let b = p.vertices[(i + 1) % p.len()];
            segs.push(Seg::from_bulge(a.pos(), b.pos(), a.bulge));
        }
    }
    segs
}

impl Checker {
    pub fn new(input: &[Polyline]) -> Checker {
        let segs = segments(input);
        let boxes: Vec<BBox> = segs.iter().map(|s| s.bbox()).collect();
        let mut inside = Vec::with_capacity(segs.len());
        let mut path = Vec::with_capacity(segs.len());
        for (i, p) in input.iter().enumerate() {
            let n = p.segment_count() + usize::from(p.len() == 1);
            let side = if p.closed && p.len() > 1 {
                // the region lies inside a boundary nested an even number of times (an
                // outer), outside one nested an odd number of times (an island), whatever
                // its orientation; inside is left of a counter-clockwise loop
                let at = p.vertices[0].pos();
                let depth = input
                    .iter()
                    .enumerate()
                    .filter(|&(j, q)| j != i && q.closed && q.len() > 1 && q.contains(at))
                    .count();
                let left_is_inside = if p.is_ccw() { 1.0 } else { -1.0 };
                Some(if depth % 2 == 0 {
                    left_is_inside
                } else {
                    -left_is_inside
                })
            } else {
                None
            };
            inside.extend(std::iter::repeat_n(side, n));
            path.extend(std::iter::repeat_n(side.map(|_| i), n));
        }
        Checker {
            index: BoxIndex::new(&boxes),
            segs,
            inside,
            path,
        }
    }

    /// The exact distance from `p` to the nearest input segment (infinite with no input).
    pub fn distance(&self, p: Point) -> f64 {
        self.index
            .nearest_one(p.x, p.y, f64::INFINITY, |i| self.segs[i].dist(p))
            .map_or(f64::INFINITY, |(_, d)| d)
    }

    /// [`Checker::distance`], helped by the distance `d` already measured at a point `q`
    /// nearby (the sample before, as the checks walk along a path): the nearest segment lies
    /// within d + |p − q| of `p` (the triangle inequality), so the search starts from that
    /// bound instead of from infinity and opens only the boxes within it. The same answer
    /// as `distance`; a search that finds nothing within the bound (rounding) asks again
    /// unbounded.
    pub fn distance_near(&self, p: Point, near: Option<(Point, f64)>) -> f64 {
        let Some((q, d)) = near.filter(|(_, d)| d.is_finite()) else {
            return self.distance(p);
        };
        let bound = d + p.dist(q);
        let bound = bound + 1e-9 * (1.0 + bound);
        match self
            .index
            .nearest_one(p.x, p.y, bound, |i| self.segs[i].dist(p))
        {
            Some((_, d)) => d,
            None => self.distance(p),
        }
    }

    /// Whether some input segment lies nearer than `r` to `p` (stops at the first found).
    fn nearer_than(&self, p: Point, r: f64) -> bool {
        self.index
            .nearest_one(p.x, p.y, r, |i| self.segs[i].dist(p))
            .is_some_and(|(_, d)| d < r)
    }

    /// Whether `p` lies in the region the closed input paths bound, nested even-odd (each
    /// path counts when it winds round `p`): only segments whose box meets the ray from `p`
    /// to +x can wind round it, so the R-tree finds them.
    fn in_region(&self, p: Point) -> bool {
        let mut winding: Vec<(usize, i32)> = Vec::new();
        let ray = [p.x, p.y, f64::INFINITY, p.y];
        self.index.query(&ray, |i| {
            if let Some(k) = self.path[i] {
                let s = &self.segs[i];
                let w = crate::geom::winding_of(s.a, s.b, s.bulge(), p);
                if w != 0 {
                    match winding.iter_mut().find(|(j, _)| *j == k) {
                        Some((_, sum)) => *sum += w,
                        None => winding.push((k, w)),
                    }
                }
            }
            true
        });
        winding.iter().filter(|(_, w)| *w != 0).count() % 2 == 1
    }

    /// Measures both ways. Samples every output segment (its ends and points no farther
    /// apart than twice the tolerance, at most 64 per segment) and measures each against
    /// `distance`; then samples every input segment as densely (at most 256 per segment),
    /// moves each sample |d| along its normal to the side the offset goes (out of a region
    /// for d > 0, into it for d < 0; left of an open path for d > 0, right for d < 0) and,
    /// where the offset is due there (nothing of the input nearer than |d|, see
    /// [`Checker::is_due`]), measures how far the output is from it (`missing`).
    pub fn check(&self, output: &[Polyline], distance: f64, tolerance: f64) -> Report {
        let want = distance.abs();
        let mut r = Report::default();
        let mut near = None;
        for s in segments(output) {
            let k = ((s.length() / (2.0 * tolerance)).ceil() as usize).clamp(1, 64);
            for i in 0..=k {
                let p = s.point_at(i as f64 / k as f64);
                let d = self.distance_near(p, near);
                near = Some((p, d));
                r.samples += 1;
                if d - want > r.too_far {
                    r.too_far = d - want;
                    r.far_at = p;
                }
                if want - d > r.too_close {
                    r.too_close = want - d;
                    r.close_at = p;
                }
            }
        }
        self.coverage(output, distance, tolerance, &mut r);
        r
    }

    /// The points the offset by `distance` must pass through: input samples moved |d| along
    /// their normal to the offset's side, kept where they are due (see [`Checker::is_due`]).
    /// Each is returned with the input point it came from.
    pub fn expected_points(&self, distance: f64, tolerance: f64) -> Vec<(Point, Point)> {
        let mut out = Vec::new();
        self.candidates(distance, tolerance, |c, q, n, closed| {
            if self.is_due(c, q, n, closed, distance, tolerance) {
                out.push((c, q));
            }
        });
        out
    }

    /// Every input segment sampled (its ends and points no farther apart than twice the
    /// tolerance, at most 256 per segment), each sample `q` moved |d| along its unit normal
    /// `n` to the offset's side: out of a region for d > 0, into it for d < 0; left of an
    /// open path for d > 0, right for d < 0. Calls `f(c, q, n, closed)`.
    fn candidates(
        &self,
        distance: f64,
        tolerance: f64,
        mut f: impl FnMut(Point, Point, Point, bool),
    ) {
        let want = distance.abs();
        if want == 0.0 {
            return;
        }
        for (s, side) in self.segs.iter().zip(&self.inside) {
            let len = s.length();
            if len <= 1e-12 {
                continue;
            }
            // which multiple of the left normal points to the offset's side
            let towards = match side {
                Some(inside) => -inside * distance.signum(),
                None => distance.signum(),
            };
            let k = ((len / (2.0 * tolerance)).ceil() as usize).clamp(1, MAX_COVERAGE_SAMPLES);
            for i in 0..=k {
                let t = i as f64 / k as f64;
                let q = s.point_at(t);
                let n = s.tangent_at(t).perp() * towards;
                f(q + n * want, q, n, side.is_some());
            }
        }
    }

    /// Whether the offset must pass through `c` (= `q` + |d| `n`): no input lies nearer than
    /// |d| to it; the offset is not pinched there (nothing of the input nearer than
    /// |d| + tolerance to `q` moved |d| + tolerance: where two stretches of the input come
    /// within tolerance of meeting at the offset, as a strip exactly 2|d| wide, the offset
    /// may or may not pass); and, for a closed input, `c` lies inside its region for d < 0
    /// and outside for d > 0 (a point exactly |d| from the input on the far side of a
    /// boundary it only touches is not on the offset).
    fn is_due(
        &self,
        c: Point,
        q: Point,
        n: Point,
        closed: bool,
        distance: f64,
        tolerance: f64,
    ) -> bool {
        let want = distance.abs();
        // a point this much nearer than |d| to the input is off the offset
        let slack = 1e-9 * (1.0 + want);
        !(self.nearer_than(c, want - slack)
            || self.nearer_than(q + n * (want + tolerance), want + tolerance - slack)
            || (closed && self.in_region(c) != (distance < 0.0)))
    }

    /// The other way: every candidate point (see [`Checker::candidates`]) the output misses
    /// by more than half the tolerance is asked whether it is due, and the worst due one is
    /// `missing`. One the output passes within half the tolerance cannot fail the check and
    /// counts as met without the question (which costs a search of the whole input where it
    /// has nearly collapsed, all of it nearly |d| away).
    fn coverage(&self, output: &[Polyline], distance: f64, tolerance: f64, r: &mut Report) {
        let out = Checker::new(output);
        let mut expected = 0;
        let mut missing = (0.0, Point::default());
        let mut near = None;
        self.candidates(distance, tolerance, |c, q, n, closed| {
            let m = out.distance_near(c, near);
            near = Some((c, m));
            if m <= 0.5 * tolerance {
                expected += 1;
            } else if self.is_due(c, q, n, closed, distance, tolerance) {
                expected += 1;
                if m > missing.0 {
                    missing = (m, q);
                }
            }
        });
        r.expected = expected;
        (r.missing, r.missing_at) = missing;
    }
}

/// Checks `output` against `input` offset by `distance`: see [`Checker::check`].
pub fn check_offset(
    input: &[Polyline],
    output: &[Polyline],
    distance: f64,
    tolerance: f64,
) -> Report {
    Checker::new(input).check(output, distance, tolerance)
}

/// The larger of the two one-way distances between `a` and `b` (how far a point of either
/// lies from the other), measured at every vertex and at points no farther apart than
/// `step` along every segment, with where it was found.
pub fn sampled_deviation(a: &[Polyline], b: &[Polyline], step: f64) -> (f64, Point) {
    let mut worst = (0.0, Point::default());
    for (from, to) in [(a, b), (b, a)] {
        let c = Checker::new(to);
        let mut near = None;
        for s in segments(from) {
            let k = ((s.length() / step).ceil() as usize).clamp(1, 10_000_000);
            for i in 0..=k {
                let p = s.point_at(i as f64 / k as f64);
                let d = c.distance_near(p, near);
                near = Some((p, d));
                if d > worst.0 {
                    worst = (d, p);
                }
            }
        }
    }
    worst
}

/// The first place where the paths cross themselves or each other (neighbouring segments
/// meeting at their shared vertex do not count), as (path, point).
pub fn first_crossing(paths: &[Polyline], tolerance: f64) -> Option<(usize, Point)> {
    crate::offset::first_crossing(paths, tolerance)
}

/// How many cases a property test runs: `default` in a plain run, and `PROPTEST_CASES` when
/// that is set, because proptest reads the variable itself and it overrides the count a
/// `proptest!` block configures (`.ci/run` sets 256, so CI runs 256 cases of every property
/// test; docs/testing.md). This says the same for the tests that count their own cases.
pub fn proptest_cases(default: u32) -> u32 {
    cases_for(default, std::env::var("PROPTEST_CASES").ok().as_deref())
}

fn cases_for(default: u32, env: Option<&str>) -> u32 {
    match env.and_then(|v| v.trim().parse::<u32>().ok()) {
        Some(n) => n.max(1),
        None => default.max(1),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_distance_bounded_by_the_sample_before_is_the_unbounded_distance() {
        // a wavy loop of 2000 arcs and lines with a round island: many boxes, near ties
        let n = 2000;
        let wavy = Polyline::new(
            (0..n)
                .map(|i| {
                    let t = i as f64 / n as f64 * std::f64::consts::TAU;
                    let r = 40.0 + 2.0 * (60.0 * t).sin();
                    let bulge = if i % 3 == 0 { 0.2 } else { 0.0 };
                    crate::geom::Vertex::new(r * t.cos(), r * t.sin(), bulge)
                })
                .collect(),
            true,
        );
        let c = Checker::new(&[wavy, Polyline::circle(Point::new(5.0, -3.0), 7.0)]);
        let mut near = None;
        let mut walked = 0;
        // a walk in small steps (as the checks sample a path), with jumps across the part
        for k in 0..20_000 {
            let t = k as f64 * 0.0007;
            let p = if k % 997 == 0 {
                Point::new(60.0 * (3.1 * t).cos(), -70.0 * (1.7 * t).sin())
            } else {
                Point::new(
                    45.0 * t.cos() * (0.5 + 0.5 * (7.0 * t).sin()),
                    45.0 * t.sin(),
                )
            };
            let d = c.distance_near(p, near);
            assert_eq!(d, c.distance(p), "at {p:?} after {near:?}");
            near = Some((p, d));
            walked += 1;
        }
        assert_eq!(walked, 20_000);
        assert_eq!(
            c.distance_near(Point::new(1.0, 2.0), None),
            c.distance(Point::new(1.0, 2.0))
        );
    }

    #[test]
    fn distances_are_exact_for_lines_and_arcs() {
        let c = Checker::new(&[Polyline::circle(Point::new(1.0, 1.0), 2.0)]);
        assert!((c.distance(Point::new(1.0, 1.0)) - 2.0).abs() < 1e-12);
        assert!((c.distance(Point::new(6.0, 1.0)) - 3.0).abs() < 1e-12);
        let sq = Polyline::rect(Point::new(0.0, 0.0), Point::new(10.0, 10.0));
        let out = Polyline::rect(Point::new(-1.0, -1.0), Point::new(11.0, 11.0));
        let r = check_offset(&[sq], &[out], 1.0, 1e-3);
        // the mitred corners lie sqrt(2) away
        assert!((r.too_far - (2f64.sqrt() - 1.0)).abs() < 1e-9, "{r:?}");
        assert_eq!(r.too_close, 0.0);
        assert!(r.missing < 1e-12 && r.expected > 0, "{r:?}");
    }

    #[test]
    fn an_empty_offset_where_one_is_due_fails() {
        let sq = Polyline::rect(Point::new(0.0, 0.0), Point::new(10.0, 10.0));
        for d in [1.0, -1.0] {
            let r = check_offset(std::slice::from_ref(&sq), &[], d, 1e-3);
            assert!(r.missing.is_infinite() && !r.within(1e-3), "{d}: {r:?}");
        }
        // a square 2 mm wide shrunk by 1.5: nothing is due, nothing is missing
        let small = Polyline::rect(Point::new(0.0, 0.0), Point::new(2.0, 2.0));
        let r = check_offset(&[small], &[], -1.5, 1e-3);
        assert_eq!(r.expected, 0, "{r:?}");
        assert!(r.within(1e-3));
    }

    #[test]
    fn an_offset_on_the_wrong_side_or_with_a_gap_fails() {
        let l = Polyline::from_points(&[Point::new(0.0, 0.0), Point::new(10.0, 0.0)], false);
        let left = Polyline::from_points(&[Point::new(0.0, 2.0), Point::new(10.0, 2.0)], false);
        let right = Polyline::from_points(&[Point::new(0.0, -2.0), Point::new(10.0, -2.0)], false);
        assert!(check_offset(
            std::slice::from_ref(&l),
            std::slice::from_ref(&left),
            2.0,
            1e-3
        )
        .within(1e-3));
        assert!(check_offset(
            std::slice::from_ref(&l),
            std::slice::from_ref(&right),
            -2.0,
            1e-3
        )
        .within(1e-3));
        // the right offset handed back for a left one: every point at 2 mm, none where due
        let r = check_offset(
            std::slice::from_ref(&l),
            std::slice::from_ref(&right),
            2.0,
            1e-3,
        );
        assert!((r.missing - 4.0).abs() < 1e-9, "{r:?}");
        // the middle dropped: both ends kept, each point of them at 2 mm
        let ends = [
            Polyline::from_points(&[Point::new(0.0, 2.0), Point::new(3.0, 2.0)], false),
            Polyline::from_points(&[Point::new(7.0, 2.0), Point::new(10.0, 2.0)], false),
        ];
        let r = check_offset(std::slice::from_ref(&l), &ends, 2.0, 1e-3);
        assert!(r.too_far == 0.0 && r.too_close == 0.0, "{r:?}");
        assert!((r.missing - 2.0).abs() < 1e-2, "{r:?}");
        // a region grown where it should shrink (an island's side flipped)
        let outer = Polyline::rect(Point::new(0.0, 0.0), Point::new(30.0, 30.0));
        let island = Polyline::rect(Point::new(10.0, 10.0), Point::new(20.0, 20.0));
        let shrunk = [
            Polyline::rect(Point::new(1.0, 1.0), Point::new(29.0, 29.0)),
            Polyline::rect(Point::new(9.0, 9.0), Point::new(21.0, 21.0)),
        ];
        let input = [outer.clone(), island.clone()];
        let r = check_offset(&input, &shrunk, -1.0, 1e-3);
        assert!(r.missing < 1e-9 && r.expected > 0, "{r:?}");
        let island_shrunk = [
            Polyline::rect(Point::new(1.0, 1.0), Point::new(29.0, 29.0)),
            Polyline::rect(Point::new(11.0, 11.0), Point::new(19.0, 19.0)),
        ];
        // 2 mm off along the island's sides, sqrt(5) at its corners: (9, 10) is due, (11, 11)
        // is the nearest cut
        let r = check_offset(&input, &island_shrunk, -1.0, 1e-3);
        assert!((r.missing - 5f64.sqrt()).abs() < 1e-9, "{r:?}");
    }

    #[test]
    fn case_counts_are_proptest_cases_when_set() {
        assert_eq!(cases_for(64, None), 64);
        assert_eq!(cases_for(64, Some("256")), 256);
        assert_eq!(cases_for(16, Some("2560")), 2560);
        assert_eq!(cases_for(1, Some("0")), 1);
        assert_eq!(cases_for(5, Some("junk")), 5);
    }
}
