//! The offset checker: how far every point of an offset lies from the shape it came from,
//! against the distance asked for (exact point-to-segment distances through an R-tree).

use crate::geom::{Point, Polyline};
use crate::offset::index::{BBox, BoxIndex};
use crate::offset::seg::Seg;

/// The worst deviations found, and where.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Report {
    /// The most any sample lies farther than |d| from the input (0 when none does).
    pub too_far: f64,
    pub far_at: Point,
    /// The most any sample lies nearer than |d| to the input (0 when none does).
    pub too_close: f64,
    pub close_at: Point,
    /// How many points were measured.
    pub samples: usize,
}

impl Report {
    /// The larger of the two deviations.
    pub fn worst(&self) -> f64 {
        self.too_far.max(self.too_close)
    }
    /// Whether both deviations are within `tolerance`.
    pub fn within(&self, tolerance: f64) -> bool {
        self.worst() <= tolerance
    }
}

/// The input shape's segments in an R-tree.
pub struct Checker {
    segs: Vec<Seg>,
    index: BoxIndex,
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
        Checker {
            index: BoxIndex::new(&boxes),
            segs,
        }
    }

    /// The exact distance from `p` to the nearest input segment (infinite with no input).
    pub fn distance(&self, p: Point) -> f64 {
        let mut best = f64::INFINITY;
        self.index.nearest(
            p.x,
            p.y,
            f64::INFINITY,
            |i| self.segs[i].dist(p),
            |_, d| {
                best = d;
                false
            },
        );
        best
    }

    /// Samples every output segment (its ends and points no farther apart than the
    /// tolerance allows, at most 64 per segment) and measures each against `distance`.
    pub fn check(&self, output: &[Polyline], distance: f64, tolerance: f64) -> Report {
        let want = distance.abs();
        let mut r = Report::default();
        for s in segments(output) {
            let k = ((s.length() / (2.0 * tolerance)).ceil() as usize).clamp(1, 64);
            for i in 0..=k {
                let p = s.point_at(i as f64 / k as f64);
                let d = self.distance(p);
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
        r
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
        for s in segments(from) {
            let k = ((s.length() / step).ceil() as usize).clamp(1, 10_000_000);
            for i in 0..=k {
                let p = s.point_at(i as f64 / k as f64);
                let d = c.distance(p);
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

#[cfg(test)]
mod tests {
    use super::*;

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
    }
}
