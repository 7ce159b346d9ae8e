//! Biarc fitting (after Yoo 2005): dense points or straight-segment polylines into lines and tangent-continuous arcs within a tolerance.
//!
//! The points are split into smooth runs at corners (a turn sharper than the corner
//! angle). Each point of a run gets a tangent from the circle through it and its two
//! neighbours (exact for points on a circle). A greedy pass then covers the run with as few
//! pieces as it can: from the current point it searches (doubling, then bisecting) the
//! farthest point that one piece still fits, where a piece is a line when the points are
//! collinear within the tolerance and otherwise the equal-tangent-length biarc between the
//! two points and their tangents. A piece fits when every input point it spans lies within
//! the tolerance of it and every point sampled on it lies within the tolerance of the input
//! curve. The input curve is the biarc spline through the points with their tangents (a
//! biarc between every two neighbours: a line for collinear points, the circle itself for
//! points on a circle), so a circle sampled at 100 points comes back as the circle at any
//! tolerance, and a single span always fits. Neighbouring biarcs share their end
//! tangent, so the result is tangent-continuous wherever the input is smooth; consecutive
//! arcs on one circle are merged.

use crate::geom::{Point, Polyline, Segment, Vertex};
use std::f64::consts::PI;

/// Settings of a fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BiarcOptions {
    /// Greatest distance between the fitted curve and the input, both ways, mm.
    pub tolerance: f64,
    /// A turn sharper than this between two input segments is a corner, radians.
    pub corner_angle: f64,
}

impl Default for BiarcOptions {
    fn default() -> Self {
        BiarcOptions {
            tolerance: 1e-3,
            corner_angle: 30f64.to_radians(),
        }
    }
}

/// What a fit did: moves (segments) in and out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FitReport {
    pub segments_in: usize,
    pub segments_out: usize,
}

/// Fits the points (a closed loop when `closed`) with lines and arcs.
pub fn fit_points(points: &[Point], closed: bool, opts: &BiarcOptions) -> Polyline {
    let mut pts: Vec<Point> = Vec::with_capacity(points.len());
    for &p in points {
        if pts.last().is_none_or(|q: &Point| q.dist(p) > 1e-12) {
            pts.push(p);
        }
    }
    if closed && pts.len() > 1 && pts[0].dist(pts[pts.len() - 1]) <= 1e-12 {
        pts.pop();
    }
    let tol = if opts.tolerance.is_finite() && opts.tolerance > 0.0 {
        opts.tolerance
    } else {
        1e-3
    };
    if pts.len() < 3 {
        return Polyline::from_points(&pts, closed);
    }
    let n = pts.len();
    let turn = |i: usize| -> f64 {
        let a = pts[(i + n - 1) % n];
        let b = pts[i];
        let c = pts[(i + 1) % n];
        let (u, v) = (b - a, c - b);
        u.cross(v).atan2(u.dot(v)).abs()
    };
    let mut out: Vec<Vertex> = Vec::new();
    if closed {
        let corners: Vec<usize> = (0..n).filter(|&i| turn(i) > opts.corner_angle).collect();
        if corners.is_empty() {
            // one smooth loop: the tangents wrap around
            let mut run: Vec<Point> = pts.clone();
            run.push(pts[0]);
            let tans: Vec<Point> = (0..=n)
                .map(|i| tangent3(pts[(i + n - 1) % n], pts[i % n], pts[(i + 1) % n]))
                .collect();
            fit_run(&run, &tans, tol, &mut out);
        } else {
            let c0 = corners[0];
            let rot: Vec<Point> = (0..=n).map(|k| pts[(c0 + k) % n]).collect();
            let mut cuts: Vec<usize> = corners.iter().map(|&c| (c + n - c0) % n).collect();
            cuts.push(n);
            for w in cuts.windows(2) {
                let run = &rot[w[0]..=w[1]];
                fit_run(run, &run_tangents(run), tol, &mut out);
            }
        }
        merge_arcs(Polyline::new(out, true), tol)
    } else {
        let mut cuts: Vec<usize> = vec![0];
        cuts.extend((1..n - 1).filter(|&i| turn(i) > opts.corner_angle));
        cuts.push(n - 1);
        for w in cuts.windows(2) {
            let run = &pts[w[0]..=w[1]];
            fit_run(run, &run_tangents(run), tol, &mut out);
        }
        out.push(Vertex::line(pts[n - 1]));
        merge_arcs(Polyline::new(out, false), tol)
    }
}

/// Fits a polyline: runs of straight segments are fitted, arcs already there are kept.
pub fn fit_polyline(pl: &Polyline, opts: &BiarcOptions) -> (Polyline, FitReport) {
    let segments_in = pl.segment_count();
    let has_arcs = pl.segments().any(|s| matches!(s, Segment::Arc { .. }));
    let out = if !has_arcs {
        let pts: Vec<Point> = pl.vertices.iter().map(|v| v.pos()).collect();
        fit_points(&pts, pl.closed, opts)
    } else {
        // split at the arcs: each straight run is fitted on its own
        let mut verts: Vec<Vertex> = Vec::new();
        let mut run: Vec<Point> = Vec::new();
        let flush = |run: &mut Vec<Point>, verts: &mut Vec<Vertex>| {
            if run.len() >= 2 {
                let f = fit_points(run, false, opts);
                verts.extend_from_slice(&f.vertices[..f.vertices.len() - 1]);
            }
            run.clear();
        };
        for s in pl.segments() {
            match s {
                Segment::Line { a, b } => {
                    if run.is_empty() {
                        run.push(a);
                    }
                    run.push(b);
                }
                Segment::Arc { a, .. } => {
                    flush(&mut run, &mut verts);
                    let bulge = (s.sweep() / 4.0).tan();
                    verts.push(Vertex::new(a.x, a.y, bulge));
                }
            }
        }
        flush(&mut run, &mut verts);
        if !pl.closed {
            if let Some(v) = pl.vertices.last() {
                verts.push(Vertex::line(v.pos()));
            }
        }
        Polyline::new(verts, pl.closed)
    };
    let segments_out = out.segment_count();
    (
        out,
        FitReport {
            segments_in,
            segments_out,
        },
    )
}

/// The unit tangent at `p` of the circle through `a`, `p`, `b` (the chord direction when
/// they are collinear), pointing from `a` towards `b`.
fn tangent3(a: Point, p: Point, b: Point) -> Point {
    let (u, v) = (a - p, b - p);
    let den = 2.0 * u.cross(v);
    let chord = (b - a).unit();
    let scale = u.len().max(v.len());
    if den.abs() <= 1e-14 * scale * scale {
        return chord;
    }
    let c = Point::new(
        (v.y * u.dot(u) - u.y * v.dot(v)) / den,
        (u.x * v.dot(v) - v.x * u.dot(u)) / den,
    );
    let t = c.perp().unit();
    if t.dot(chord) >= 0.0 {
        t
    } else {
        -t
    }
}

/// The unit tangent at the end `p` of the circle through `p`, `q`, `r`, pointing from `p`
/// towards `q`: on a circle the chord p→q makes equal angles with the tangents at its
/// ends, so the tangent at `p` is the one at `q` mirrored about the chord.
fn end_tangent(p: Point, q: Point, r: Point) -> Point {
    let tq = tangent3(p, q, r);
    let chord = (q - p).unit();
    (chord * (2.0 * chord.dot(tq)) - tq).unit()
}

/// Tangents for an open run: interior ones from three points, the ends from the end circle.
fn run_tangents(run: &[Point]) -> Vec<Point> {
    let m = run.len();
    if m < 3 {
        let d = (run[m - 1] - run[0]).unit();
        return vec![d; m];
    }
    let mut t: Vec<Point> = (0..m)
        .map(|i| {
            if i == 0 || i == m - 1 {
                Point::default()
            } else {
                tangent3(run[i - 1], run[i], run[i + 1])
            }
        })
        .collect();
    t[0] = end_tangent(run[0], run[1], run[2]);
    // the last end, by symmetry: walk the run backwards and turn the tangent round
    t[m - 1] = -end_tangent(run[m - 1], run[m - 2], run[m - 3]);
    t
}

/// Covers `run` (points with tangents) greedily with lines and biarcs; pushes the start
/// vertex of every piece (the run's last point is not pushed).
fn fit_run(run: &[Point], tans: &[Point], tol: f64, out: &mut Vec<Vertex>) {
    let m = run.len() - 1;
    let mut i = 0;
    while i < m {
        // the longest piece from i: double the span while it fits, then bisect
        let mut good = i + 1;
        let mut best = piece(run, tans, i, i + 1, tol).unwrap_or_else(|| line_piece(run, i));
        let mut step = 1;
        let mut bad = None;
        while good < m {
            let j = (i + step * 2).min(m);
            step *= 2;
            match piece(run, tans, i, j, tol) {
                Some(p) => {
                    good = j;
                    best = p;
                }
                None => {
                    bad = Some(j);
                    break;
                }
            }
        }
        if let Some(mut hi) = bad {
            let mut lo = good;
            while hi - lo > 1 {
                let mid = (lo + hi) / 2;
                match piece(run, tans, i, mid, tol) {
                    Some(p) => {
                        lo = mid;
                        best = p;
                    }
                    None => hi = mid,
                }
            }
            good = lo;
        }
        out.extend(best);
        i = good;
    }
}

fn line_piece(run: &[Point], i: usize) -> Vec<Vertex> {
    vec![Vertex::line(run[i])]
}

/// The piece from run[i] to run[j] (start vertices with bulges) if one fits.
fn piece(run: &[Point], tans: &[Point], i: usize, j: usize, tol: f64) -> Option<Vec<Vertex>> {
    let (p0, p1) = (run[i], run[j]);
    let chord = p1 - p0;
    if chord.len() <= 1e-12 {
        return None;
    }
    // a line when every point lies on the chord and the tangents agree with it
    let line = Segment::Line { a: p0, b: p1 };
    let dir = chord.unit();
    // (only for truly straight input: a dense circle would otherwise come back as chords)
    let ang_tol = 1e-9;
    if run[i..=j].iter().all(|&p| line.distance_to(p) <= tol)
        && tans[i].cross(dir).abs() <= ang_tol
        && tans[j].cross(dir).abs() <= ang_tol
    {
        return Some(vec![Vertex::line(p0)]);
    }
    let (s0, s1, joint, b0, b1) = biarc(p0, tans[i], p1, tans[j])?;
    if j == i + 1 {
        // one span: the biarc is the input curve itself
        return Some(vec![
            Vertex::new(p0.x, p0.y, b0),
            Vertex::new(joint.x, joint.y, b1),
        ]);
    }
    // both ways within the tolerance
    let near = |p: Point| s0.distance_to(p).min(s1.distance_to(p)) <= tol;
    if !run[i..=j].iter().all(|&p| near(p)) {
        return None;
    }
    // the input curve: the biarc through each pair of neighbours with their tangents
    let spans: Vec<[Segment; 2]> = (i..j)
        .map(|k| match biarc(run[k], tans[k], run[k + 1], tans[k + 1]) {
            Some((a, b, ..)) => [a, b],
            None => {
                let l = Segment::Line {
                    a: run[k],
                    b: run[k + 1],
                };
                [l, l]
            }
        })
        .collect();
    // cumulative chord lengths, to start each search at the span that lies as far along
    // the input as the sample lies along the biarc
    let mut cum = Vec::with_capacity(spans.len() + 1);
    cum.push(0.0);
    for sp in &spans {
        cum.push(cum[cum.len() - 1] + sp[0].start().dist(sp[1].end()));
    }
    let total_in = cum[cum.len() - 1];
    let (l0, l1) = (s0.length(), s1.length());
    // whether some span lies within `limit` of p, searching outward from the guess
    let within = |p: Point, along: f64, limit: f64| {
        let target = along / (l0 + l1) * total_in;
        let g = cum
            .partition_point(|&c| c < target)
            .saturating_sub(1)
            .min(spans.len() - 1);
        let n = spans.len();
        let close = |k: usize| spans[k].iter().any(|sg| sg.distance_to(p) <= limit);
        (0..n).any(|d| (g >= d && close(g - d)) || (d > 0 && g + d < n && close(g + d)))
    };
    // sampled, so keep a margin for what lies between the samples
    let k = 16;
    for q in 1..k {
        let t = q as f64 / k as f64;
        if !within(s0.point_at(t), l0 * t, 0.95 * tol)
            || !within(s1.point_at(t), l0 + l1 * t, 0.95 * tol)
        {
            return None;
        }
    }
    if !within(joint, l0, tol) {
        return None;
    }
    Some(vec![
        Vertex::new(p0.x, p0.y, b0),
        Vertex::new(joint.x, joint.y, b1),
    ])
}

/// The equal-tangent-length biarc from `p0` (unit tangent `t0`) to `p1` (unit tangent
/// `t1`): its two arcs, the joint and their bulges; None when there is none within half
/// turns.
fn biarc(
    p0: Point,
    t0: Point,
    p1: Point,
    t1: Point,
) -> Option<(Segment, Segment, Point, f64, f64)> {
    let chord = p1 - p0;
    if chord.len() <= 1e-12 {
        return None;
    }
    let t = t0 + t1;
    let vt = chord.dot(t);
    let denom = 2.0 * (1.0 - t0.dot(t1));
    let d = if denom.abs() < 1e-12 {
        // parallel tangents: the equation is linear
        if vt.abs() < 1e-12 {
            return None;
        }
        chord.dot(chord) / (4.0 * chord.dot(t0))
    } else {
        (-vt + (vt * vt + denom * chord.dot(chord)).sqrt()) / denom
    };
    if !(d.is_finite() && d > 0.0) {
        return None;
    }
    let q0 = p0 + t0 * d;
    let q1 = p1 - t1 * d;
    let joint = q0.lerp(q1, 0.5);
    let b0 = bulge_from_tangent(p0, t0, joint)?;
    let b1 = bulge_from_tangent(joint, (q1 - q0).unit(), p1)?;
    Some((
        Segment::from_bulge(p0, joint, b0),
        Segment::from_bulge(joint, p1, b1),
        joint,
        b0,
        b1,
    ))
}

/// The bulge of the arc that leaves `a` along the unit tangent `t` and ends at `b`;
/// None past a half turn.
fn bulge_from_tangent(a: Point, t: Point, b: Point) -> Option<f64> {
    let c = b - a;
    // half the sweep is the signed angle from the tangent to the chord
    let half = t.cross(c).atan2(t.dot(c));
    if half.abs() > PI / 2.0 {
        return None;
    }
    let bulge = (half / 2.0).tan();
    Some(if bulge.abs() < 1e-12 { 0.0 } else { bulge })
}

/// Merges consecutive arcs on one circle (same centre and radius within a hundredth of
/// the tolerance, same direction) while the merged sweep stays within a half turn.
fn merge_arcs(pl: Polyline, tol: f64) -> Polyline {
    let segs: Vec<Segment> = pl.segments().collect();
    if segs.len() < 2 {
        return pl;
    }
    let eps = tol * 1e-2;
    let same = |a: &Segment, b: &Segment| match (a, b) {
        (
            Segment::Arc {
                center: c0,
                radius: r0,
                ccw: w0,
                ..
            },
            Segment::Arc {
                center: c1,
                radius: r1,
                ccw: w1,
                ..
            },
        ) => w0 == w1 && c0.dist(*c1) <= eps && (r0 - r1).abs() <= eps,
        _ => false,
    };
    let mut out: Vec<Vertex> = Vec::new();
    let mut k = 0;
    while k < segs.len() {
        let first = segs[k];
        let mut sweep = first.sweep();
        let mut e = k + 1;
        while e < segs.len()
            && same(&first, &segs[e])
            && (sweep + segs[e].sweep()).abs() <= PI + 1e-9
        {
            sweep += segs[e].sweep();
            e += 1;
        }
        let a = first.start();
        let bulge = if matches!(first, Segment::Arc { .. }) {
            (sweep / 4.0).tan()
        } else {
            0.0
        };
        out.push(Vertex::new(a.x, a.y, bulge));
        k = e;
    }
    if !pl.closed {
        if let Some(v) = pl.vertices.last() {
            out.push(Vertex::line(v.pos()));
        }
    }
    Polyline::new(out, pl.closed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tangent_of_three_points_on_a_circle_is_exact() {
        let on = |a: f64| Point::new(a.cos() * 10.0, a.sin() * 10.0);
        let t = tangent3(on(0.1), on(0.3), on(0.4));
        assert!((t - Point::new(-(0.3f64).sin(), 0.3f64.cos())).len() < 1e-12);
        let e = end_tangent(on(0.1), on(0.3), on(0.4));
        assert!((e - Point::new(-(0.1f64).sin(), 0.1f64.cos())).len() < 1e-12);
    }
}
