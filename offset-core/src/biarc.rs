//! Biarc fitting (after Yoo 2005): dense points, straight-segment polylines and runs of short tool moves into lines and tangent-continuous arcs, within a tolerance of the given polyline.
//!
//! What is fitted is the polyline itself, not a curve guessed behind it: every point of the
//! result lies within the tolerance of the polyline and every point of the polyline within
//! the tolerance of the result. The points are split into smooth runs at corners (a turn
//! sharper than the corner angle); corners are kept exactly and never merged across.
//!
//! Along a run, pieces start and end at *knots*. Where the chords sag less than half the
//! tolerance from the circles through neighbouring points, the knots are the points
//! themselves (a densely sampled curve comes back through its samples). Elsewhere there is
//! one knot on every chord, at the parameter τ = (1 − 1/√2)/2 where a chord of a sampled
//! circle crosses the circle midway between the samples and the chords: the knots of a
//! circle sampled at any density lie on one circle, half a chord's sagitta s inside the
//! samples and within s/2 of the polyline everywhere, so whenever s/2 is within the
//! tolerance the circle comes back whole. Run ends (path ends, corners, and both ends of a
//! chord four times longer than its neighbours that would sag more than the tolerance on
//! the circles they bend along: a straight side between dense curves) are knots and stay
//! where they are. Each knot gets the tangent of the circle through it and
//! its neighbours. A greedy search (doubling, then bisecting) covers a run with as few
//! pieces as fit: a line where the polyline runs straight, else the equal-tangent-length
//! biarc between two knots and their tangents, else a line that turns at most 0.6° against
//! those tangents; where not even one chord's worth fits, the polyline itself.
//!
//! A piece is checked exactly, not by sampling: the polyline between its knots is split
//! where it crosses the normal through the biarc's joint, and on each arc the distance of
//! the polyline's chords to the arc is largest at a chord's ends, at its point nearest the
//! arc's centre, or where it crosses the arc's end radii, which are the points measured.
//! Since a piece starts and ends on the polyline and the polyline stays within the
//! tolerance of it, the polyline passes every radius of the arc, so the arc is also within
//! the tolerance of the polyline. Consecutive lines on one line and arcs on one circle are
//! merged; a run whose fit is no shorter than the run is kept as it was.

use crate::geom::{Point, Polyline, Segment, Shape, Vertex};
use crate::toolpath::{Move, Toolpath, P3};
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

impl BiarcOptions {
    /// The default corner angle with the given tolerance (mm).
    pub fn with_tolerance(tolerance: f64) -> Self {
        BiarcOptions {
            tolerance,
            ..Default::default()
        }
    }
    fn tol(&self) -> f64 {
        if self.tolerance.is_finite() && self.tolerance > 0.0 {
            self.tolerance
        } else {
            1e-3
        }
    }
}

/// What a fit did: segments (or moves) in and out.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FitReport {
    pub segments_in: usize,
    pub segments_out: usize,
}

impl std::ops::AddAssign for FitReport {
    fn add_assign(&mut self, o: FitReport) {
        self.segments_in += o.segments_in;
        self.segments_out += o.segments_out;
    }
}

/// The knot parameter along a chord: where a sampled circle's chord meets the circle
/// midway between the samples and the chords.
const KNOT_T: f64 = 0.146_446_609_406_726_24;

/// The sharpest turn (sine of the angle) a line put where no biarc fits may make against
/// the tangents at its ends: the fit stays tangent-continuous to within 0.6° where the
/// input is smooth.
const LINE_KINK: f64 = 0.01;

/// The share of the tolerance kept for merging pieces; the pieces fit within the rest.
const MERGE_SHARE: f64 = 0.01;

/// Fits the points (a closed loop when `closed`) with lines and arcs.
pub fn fit_points(points: &[Point], closed: bool, opts: &BiarcOptions) -> Polyline {
    let tol = opts.tol();
    // drop repeated points (a zero chord has no direction)
    let scale = points
        .iter()
        .fold(1.0f64, |m, p| m.max(p.x.abs()).max(p.y.abs()));
    let dup = (scale * 1e-14).max(1e-12);
    let mut pts: Vec<Point> = Vec::with_capacity(points.len());
    for &p in points {
        if pts.last().is_none_or(|q: &Point| q.dist(p) > dup) {
            pts.push(p);
        }
    }
    if closed {
        while pts.len() > 1 && pts[0].dist(pts[pts.len() - 1]) <= dup {
            pts.pop();
        }
    }
    if pts.len() < 3 {
        return Polyline::from_points(&pts, closed);
    }
    let n = pts.len();
    let chord = |i: usize| pts[i % n].dist(pts[(i + 1) % n]);
    // a chord many times longer than both its neighbours is a straight side
    // the sagitta chord k would have on the circle through it and the point before (or
    // after) it: how far from a smooth curve bending as its neighbours bend it is
    let sag = |k: usize, before: bool| {
        let (a, b, c) = if before {
            (pts[(k + n - 1) % n], pts[k % n], pts[(k + 1) % n])
        } else {
            (pts[k % n], pts[(k + 1) % n], pts[(k + 2) % n])
        };
        let area2 = (b - a).cross(c - a).abs();
        if area2 == 0.0 {
            return 0.0;
        }
        let r = a.dist(b) * b.dist(c) * c.dist(a) / (2.0 * area2);
        let l = chord(k);
        l * l / (8.0 * r)
    };
    // a chord many times longer than both its neighbours that sags more than the tolerance
    // on the circles they bend along is a straight side (a rounded rectangle's); the sides
    // of an offset polygon, between its short round joins, bend with them and are not
    let long = |k: usize| {
        let l = chord(k);
        l > LONG_CHORD * chord(k + n - 1)
            && l > LONG_CHORD * chord(k + 1)
            && sag(k, true) > tol
            && sag(k, false) > tol
    };
    // where runs break: corners (a turn sharper than the corner angle) and both ends of a
    // straight side between dense curves, which stays a line
    let is_break = |i: usize| -> bool {
        let a = pts[(i + n - 1) % n];
        let b = pts[i];
        let c = pts[(i + 1) % n];
        let (u, v) = (b - a, c - b);
        u.cross(v).atan2(u.dot(v)).abs() > opts.corner_angle
            || (closed || i >= 2) && long(i + n - 1)
            || (closed || i + 2 < n) && long(i)
    };
    let mut out: Vec<Vertex> = Vec::new();
    if closed {
        let breaks: Vec<usize> = (0..n).filter(|&i| is_break(i)).collect();
        if breaks.is_empty() {
            let k = Knots::closed_loop(&pts, max_sagitta(&pts, true) <= tol / 2.0);
            let mut fitted = Vec::new();
            k.fit(tol * (1.0 - MERGE_SHARE), &mut fitted);
            let fitted = merge(fitted, true, None, tol);
            if fitted.len() < n {
                out = fitted;
            } else {
                out = pts.iter().map(|&p| Vertex::line(p)).collect();
            }
        } else {
            let c0 = breaks[0];
            let rot: Vec<Point> = (0..=n).map(|k| pts[(c0 + k) % n]).collect();
            let mut cuts: Vec<usize> = breaks.iter().map(|&c| (c + n - c0) % n).collect();
            cuts.push(n);
            for w in cuts.windows(2) {
                fit_open_run(&rot[w[0]..=w[1]], tol, &mut out);
            }
            out = merge(out, true, None, tol);
        }
        Polyline::new(out, true)
    } else {
        let mut cuts: Vec<usize> = vec![0];
        cuts.extend((1..n - 1).filter(|&i| is_break(i)));
        cuts.push(n - 1);
        for w in cuts.windows(2) {
            fit_open_run(&pts[w[0]..=w[1]], tol, &mut out);
        }
        let mut out = merge(out, false, Some(pts[n - 1]), tol);
        out.push(Vertex::line(pts[n - 1]));
        Polyline::new(out, false)
    }
}

/// A chord this many times longer than both its neighbours (and far from bending with
/// them) is a straight side: runs break at its ends.
const LONG_CHORD: f64 = 4.0;

/// The largest sagitta of the points' chords against the circle through each point and
/// its neighbours: how far the polyline lies from a smooth curve through its points.
fn max_sagitta(pts: &[Point], closed: bool) -> f64 {
    let n = pts.len();
    let inner = if closed { 0..n } else { 1..n.saturating_sub(1) };
    inner
        .map(|i| {
            let (a, b, c) = (pts[(i + n - 1) % n], pts[i], pts[(i + 1) % n]);
            let area2 = (b - a).cross(c - a).abs();
            if area2 == 0.0 {
                return 0.0;
            }
            // circumradius abc / (4 area) = abc / (2 area2); sagitta of a chord l: l²/(8r)
            let r = a.dist(b) * b.dist(c) * c.dist(a) / (2.0 * area2);
            let l = a.dist(b).max(b.dist(c));
            l * l / (8.0 * r)
        })
        .fold(0.0, f64::max)
}

/// Fits an open run (its ends kept): pushes the start vertex of every piece, not the
/// run's last point. Knots sit on the vertices when the chords sag less than half the
/// tolerance from the curve through them, else on the midway curve. A run whose fit is
/// no shorter is pushed as it was.
fn fit_open_run(run: &[Point], tol: f64, out: &mut Vec<Vertex>) {
    if run.len() <= 2 {
        out.extend(run[..run.len() - 1].iter().map(|&p| Vertex::line(p)));
        return;
    }
    let k = Knots::open_run(run, max_sagitta(run, false) <= tol / 2.0);
    let mut fitted = Vec::new();
    k.fit(tol * (1.0 - MERGE_SHARE), &mut fitted);
    let fitted = merge(fitted, false, Some(run[run.len() - 1]), tol);
    if fitted.len() < run.len() - 1 {
        out.extend(fitted);
    } else {
        out.extend(run[..run.len() - 1].iter().map(|&p| Vertex::line(p)));
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
        // split at the arcs: each straight run is fitted on its own, ends kept. A closed
        // path starts at an arc, so no straight run is cut at vertex 0.
        let n = pl.segment_count();
        let first = if pl.closed {
            (0..n)
                .find(|&i| matches!(pl.segment(i), Segment::Arc { .. }))
                .unwrap_or(0)
        } else {
            0
        };
        let mut verts: Vec<Vertex> = Vec::new();
        let mut run: Vec<Point> = Vec::new();
        let flush = |run: &mut Vec<Point>, verts: &mut Vec<Vertex>| {
            if run.len() >= 2 {
                let f = fit_points(run, false, opts);
                verts.extend_from_slice(&f.vertices[..f.vertices.len() - 1]);
            }
            run.clear();
        };
        for k in 0..n {
            let s = pl.segment((first + k) % n);
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

/// Fits every path of a shape (see [`fit_polyline`]).
pub fn fit_shape(shape: &Shape, opts: &BiarcOptions) -> (Shape, FitReport) {
    let mut rep = FitReport::default();
    let paths = shape
        .paths
        .iter()
        .map(|p| {
            let (f, r) = fit_polyline(p, opts);
            rep += r;
            f
        })
        .collect();
    (Shape::new(paths), rep)
}

/// Fits the tool path's runs of level cutting moves (in a row at one Z and one feed, two or
/// more of them straight lines) with lines and arcs within `opts.tolerance` of the moves,
/// never across a corner sharper than `opts.corner_angle`: the straight lines and short
/// arcs an offset of points gives (a pass of a polygon is its sides and the round joins
/// between them) come back as a few arcs. Arcs in such a run are followed within half the
/// tolerance by points, which are fitted within the other half; a run that would not come
/// out shorter, runs with fewer than two lines, and every other move are kept as they are.
/// The report counts moves in and out.
pub fn fit_toolpath(tp: &Toolpath, opts: &BiarcOptions) -> (Toolpath, FitReport) {
    let tol = opts.tol();
    let mut out = Toolpath {
        moves: Vec::with_capacity(tp.moves.len()),
        ..tp.clone()
    };
    out.moves.clear();
    // the run: where it starts, and its moves
    let mut run: Vec<Move> = Vec::new();
    let mut run_start = P3::default();
    let flush = |run: &mut Vec<Move>, start: P3, moves: &mut Vec<Move>| {
        let lines = run
            .iter()
            .filter(|m| matches!(m, Move::Linear { .. }))
            .count();
        if lines < 2 {
            moves.append(run);
            return;
        }
        let (z, feed) = match run[0] {
            Move::Linear { to, feed } | Move::Arc { to, feed, .. } => (to.z, feed),
            _ => (start.z, 0.0),
        };
        let has_arcs = lines < run.len();
        let fit_tol = if has_arcs { tol / 2.0 } else { tol };
        let mut pts = vec![start.xy()];
        let mut at = start.xy();
        for m in run.iter() {
            match m {
                Move::Arc {
                    to, center, ccw, ..
                } => {
                    let seg = crate::toolpath::arc_segment(at, to.xy(), *center, *ccw);
                    let r = at.dist(*center);
                    let step = 2.0 * (1.0 - (tol / 2.0 / r).min(1.0)).acos();
                    let k =
                        ((seg.sweep().abs() / step.max(1e-6)).ceil() as usize).clamp(1, 100_000);
                    for i in 1..k {
                        pts.push(seg.point_at(i as f64 / k as f64));
                    }
                    pts.push(to.xy());
                    at = to.xy();
                }
                Move::Linear { to, .. } => {
                    pts.push(to.xy());
                    at = to.xy();
                }
                _ => {}
            }
        }
        let f = fit_points(
            &pts,
            false,
            &BiarcOptions {
                tolerance: fit_tol,
                ..*opts
            },
        );
        if f.segment_count() < run.len() {
            for sg in f.segments() {
                moves.push(crate::ops::profile::cut(sg, z, feed));
            }
            run.clear();
        } else {
            moves.append(run);
        }
    };
    let mut pos: Option<P3> = None;
    for m in &tp.moves {
        let level = match m {
            Move::Linear { to, feed } | Move::Arc { to, feed, .. } => pos
                .filter(|p| p.z == to.z && p.xy().dist(to.xy()) > 0.0)
                .map(|p| (p, to.z, *feed)),
            _ => None,
        };
        match level {
            Some((from, z, feed)) => {
                let same = run.first().is_some_and(|f| match f {
                    Move::Linear { to, feed: g } | Move::Arc { to, feed: g, .. } => {
                        to.z == z && *g == feed
                    }
                    _ => false,
                });
                if !same {
                    flush(&mut run, run_start, &mut out.moves);
                    run_start = from;
                }
                run.push(m.clone());
            }
            None => {
                flush(&mut run, run_start, &mut out.moves);
                out.moves.push(m.clone());
            }
        }
        if let Move::Rapid { to } | Move::Linear { to, .. } | Move::Arc { to, .. } = m {
            pos = Some(*to);
        }
    }
    flush(&mut run, run_start, &mut out.moves);
    out.moves = join_arcs_of_one_circle(std::mem::take(&mut out.moves), tol / 100.0);
    let rep = FitReport {
        segments_in: tp.moves.len(),
        segments_out: out.moves.len(),
    };
    (out, rep)
}

/// Joins neighbouring arcs of one circle (centres and radii within `eps`, the same way
/// round, level, at one feed) into one arc: a circle cut at a seam, or split where the
/// input's fit put a knot, comes out as the fewest arcs (never a whole turn in one).
fn join_arcs_of_one_circle(moves: Vec<Move>, eps: f64) -> Vec<Move> {
    let mut out: Vec<Move> = Vec::with_capacity(moves.len());
    // where the last move of `out` starts, and where the tool is
    let (mut start_of_last, mut at): (Option<P3>, Option<P3>) = (None, None);
    for m in moves {
        if let (
            Move::Arc {
                to,
                center,
                ccw,
                feed,
            },
            Some(a),
            Some(Move::Arc {
                to: pto,
                center: pc,
                ccw: pccw,
                feed: pf,
            }),
            Some(s0),
        ) = (&m, at, out.last(), start_of_last)
        {
            let level = to.z == pto.z && pto.z == s0.z;
            let r0 = s0.xy().dist(*pc);
            let r1 = a.xy().dist(*center);
            let sweep = crate::toolpath::arc_segment(s0.xy(), a.xy(), *pc, *pccw)
                .sweep()
                .abs()
                + crate::toolpath::arc_segment(a.xy(), to.xy(), *center, *ccw)
                    .sweep()
                    .abs();
            // the joined arc's centre: on the bisector of its ends (so that both lie on
            // one circle, to rounding), nearest the first arc's centre; within `eps` of
            // both arcs' centres, or the arcs stay apart
            let joined_center = on_the_bisector(s0.xy(), to.xy(), *pc);
            if level
                && ccw == pccw
                && feed == pf
                && center.dist(*pc) <= eps
                && (r0 - r1).abs() <= eps
                && sweep < std::f64::consts::TAU - 1e-6
                && joined_center.is_some_and(|c| c.dist(*pc) <= eps && c.dist(*center) <= eps)
            {
                let joined = Move::Arc {
                    to: *to,
                    center: joined_center.expect("checked above"),
                    ccw: *ccw,
                    feed: *feed,
                };
                at = Some(*to);
                *out.last_mut().expect("the arc before") = joined;
                continue;
            }
        }
        if let Move::Rapid { to } | Move::Linear { to, .. } | Move::Arc { to, .. } = &m {
            start_of_last = at;
            at = Some(*to);
        } else if let Move::Stitch { .. } | Move::Jump { .. } = &m {
            start_of_last = None;
            at = None;
        }
        out.push(m);
    }
    out
}

/// The point of the perpendicular bisector of `a`–`b` nearest `near`: the centre of a
/// circle through both ends, moved as little as may be. `None` for a zero chord.
fn on_the_bisector(a: Point, b: Point, near: Point) -> Option<Point> {
    let chord = b - a;
    if chord.len() == 0.0 {
        return None;
    }
    let mid = a.lerp(b, 0.5);
    let n = chord.unit().perp();
    let t = (near - mid).dot(n);
    Some(mid + n * t)
}

/// The knots of one run: where pieces may start and end, with their tangents.
struct Knots<'a> {
    /// The run's vertices (a closed loop's chords wrap around).
    v: &'a [Point],
    pos: Vec<Point>,
    /// The chord each knot lies on, counted along the run without wrapping: the polyline
    /// from knot i goes on to vertex `chord[i] + 1` (mod the vertex count).
    chord: Vec<usize>,
    tan: Vec<Point>,
}

impl<'a> Knots<'a> {
    /// An open run: its end points and a knot on every chord (on the vertices themselves
    /// when `at_vertices`).
    fn open_run(v: &'a [Point], at_vertices: bool) -> Knots<'a> {
        let m = v.len() - 1;
        let (pos, chord): (Vec<Point>, Vec<usize>) = if at_vertices {
            (v.to_vec(), (0..m).chain(std::iter::once(m - 1)).collect())
        } else {
            std::iter::once((v[0], 0))
                .chain((0..m).map(|c| (v[c].lerp(v[c + 1], KNOT_T), c)))
                .chain(std::iter::once((v[m], m - 1)))
                .unzip()
        };
        let k = pos.len();
        let mut tan: Vec<Point> = (0..k)
            .map(|i| {
                if i == 0 || i == k - 1 {
                    Point::default()
                } else {
                    tangent3(pos[i - 1], pos[i], pos[i + 1])
                }
            })
            .collect();
        if k >= 3 {
            tan[0] = end_tangent(pos[0], pos[1], pos[2]);
            tan[k - 1] = -end_tangent(pos[k - 1], pos[k - 2], pos[k - 3]);
        } else {
            let d = (pos[k - 1] - pos[0]).unit();
            tan = vec![d; k];
        }
        Knots { v, pos, chord, tan }
    }

    /// A closed loop with no corner: a knot on every chord (or vertex), the first repeated
    /// at the end.
    fn closed_loop(v: &'a [Point], at_vertices: bool) -> Knots<'a> {
        let n = v.len();
        let mut pos: Vec<Point> = if at_vertices {
            v.to_vec()
        } else {
            (0..n).map(|c| v[c].lerp(v[(c + 1) % n], KNOT_T)).collect()
        };
        let mut tan: Vec<Point> = (0..n)
            .map(|i| tangent3(pos[(i + n - 1) % n], pos[i], pos[(i + 1) % n]))
            .collect();
        pos.push(pos[0]);
        tan.push(tan[0]);
        let chord = (0..=n).collect();
        Knots { v, pos, chord, tan }
    }

    fn vertex(&self, k: usize) -> Point {
        self.v[k % self.v.len()]
    }

    /// The polyline from knot i to knot j as points (the knots and the vertices between).
    fn path(&self, i: usize, j: usize) -> impl Iterator<Item = Point> + '_ {
        std::iter::once(self.pos[i])
            .chain((self.chord[i] + 1..=self.chord[j]).map(move |k| self.vertex(k)))
            .chain(std::iter::once(self.pos[j]))
    }

    /// Covers the knots greedily with pieces; pushes the start vertex of every piece.
    fn fit(&self, tol: f64, out: &mut Vec<Vertex>) {
        let m = self.pos.len() - 1;
        let mut i = 0;
        while i < m {
            let mut best = self
                .piece(i, i + 1, tol)
                .unwrap_or_else(|| self.exact(i, i + 1));
            let mut good = i + 1;
            let mut step = 1;
            let mut bad = None;
            while good < m {
                step *= 2;
                let j = (i + step).min(m);
                match self.piece(i, j, tol) {
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
                    match self.piece(i, mid, tol) {
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

    /// The polyline itself from knot i to knot j, as line vertices.
    fn exact(&self, i: usize, j: usize) -> Vec<Vertex> {
        let end = self.pos[j];
        let mut vs: Vec<Vertex> = Vec::new();
        for p in self.path(i, j) {
            if p != end && vs.last().is_none_or(|v: &Vertex| v.pos() != p) {
                vs.push(Vertex::line(p));
            }
        }
        if vs.is_empty() {
            vs.push(Vertex::line(self.pos[i]));
        }
        vs
    }

    /// The piece from knot i to knot j (start vertices with bulges), if one fits: a line
    /// when the polyline between lies within `tol` of the chord, else the biarc.
    fn piece(&self, i: usize, j: usize, tol: f64) -> Option<Vec<Vertex>> {
        let (p0, p1) = (self.pos[i], self.pos[j]);
        if p0.dist(p1) <= 1e-12 {
            return None;
        }
        // a line where the polyline runs straight (its tangents within a millionth of a
        // radian of the chord, so the fit stays tangent-continuous) or no biarc fits
        let line = Part::Line {
            a: p0,
            b: p1,
            bulge: 0.0,
            sagitta: 0.0,
        };
        let dir = (p1 - p0).unit();
        let kink = self.tan[i]
            .cross(dir)
            .abs()
            .max(self.tan[j].cross(dir).abs());
        let straight = kink <= 1e-6;
        // where no biarc fits, a line may, if it leaves the tangents by little
        let line_fits = || kink <= LINE_KINK && self.path(i, j).all(|p| line.dist(p) <= tol);
        if straight && line_fits() {
            return Some(vec![Vertex::line(p0)]);
        }
        let Some((joint, tj, b0, b1)) = biarc(p0, self.tan[i], p1, self.tan[j]) else {
            return (!straight && line_fits()).then(|| vec![Vertex::line(p0)]);
        };
        let parts = [Part::new(p0, joint, b0, tol), Part::new(joint, p1, b1, tol)];
        // the polyline's points on either side of the normal through the joint
        let side = |p: Point| (p - joint).dot(tj);
        let mut prev: Option<Point> = None;
        let mut ok = true;
        for p in self.path(i, j) {
            if let Some(q) = prev {
                let (sq, sp) = (side(q), side(p));
                ok = if (sq <= 0.0) == (sp <= 0.0) {
                    parts[usize::from(sq > 0.0)].chord_within(q, p, tol)
                } else {
                    let x = q.lerp(p, sq / (sq - sp));
                    parts[usize::from(sq > 0.0)].chord_within(q, x, tol)
                        && parts[usize::from(sp > 0.0)].chord_within(x, p, tol)
                };
                if !ok {
                    break;
                }
            }
            prev = Some(p);
        }
        if !ok {
            return (!straight && line_fits()).then(|| vec![Vertex::line(p0)]);
        }
        let mut vs = Vec::with_capacity(2);
        for (k, part) in parts.iter().enumerate() {
            let a = if k == 0 { p0 } else { joint };
            vs.push(Vertex::new(a.x, a.y, part.bulge()));
        }
        Some(vs)
    }
}

/// One arc of a biarc, with what the exact distance check needs; an arc flatter than a
/// thousandth of the tolerance is measured as its chord, less its sagitta from the
/// tolerance.
enum Part {
    Line {
        a: Point,
        b: Point,
        bulge: f64,
        sagitta: f64,
    },
    Arc {
        a: Point,
        b: Point,
        c: Point,
        r: f64,
        ccw: bool,
        bulge: f64,
    },
}

impl Part {
    fn new(a: Point, b: Point, bulge: f64, tol: f64) -> Part {
        let chord = a.dist(b);
        // sagitta of the arc: chord/2 · tan(sweep/4) = chord/2 · bulge
        let sagitta = chord * bulge.abs() * 0.5;
        if bulge == 0.0 || sagitta <= tol * 1e-3 {
            return Part::Line {
                a,
                b,
                bulge,
                sagitta,
            };
        }
        match Segment::from_bulge(a, b, bulge) {
            Segment::Arc {
                center,
                radius,
                ccw,
                ..
            } => Part::Arc {
                a,
                b,
                c: center,
                r: radius,
                ccw,
                bulge,
            },
            Segment::Line { .. } => Part::Line {
                a,
                b,
                bulge: 0.0,
                sagitta: 0.0,
            },
        }
    }

    fn bulge(&self) -> f64 {
        match *self {
            Part::Line { bulge, .. } | Part::Arc { bulge, .. } => bulge,
        }
    }

    /// Distance from `p` to this line or arc.
    fn dist(&self, p: Point) -> f64 {
        match *self {
            Part::Line { a, b, sagitta, .. } => Segment::Line { a, b }.distance_to(p) + sagitta,
            Part::Arc {
                a, b, c, r, ccw, ..
            } => {
                let (u, w, q) = (a - c, b - c, p - c);
                let inside = if ccw {
                    u.cross(q) >= 0.0 && q.cross(w) >= 0.0
                } else {
                    u.cross(q) <= 0.0 && q.cross(w) <= 0.0
                };
                if inside {
                    (q.len() - r).abs()
                } else {
                    p.dist(a).min(p.dist(b))
                }
            }
        }
    }

    /// Whether every point of the chord p→q lies within `tol` of this part. The distance
    /// along a chord is largest at its ends, at its point nearest the arc's centre, or where
    /// it crosses the arc's end radii (it is convex between those, or the distance to the
    /// centre less the radius, whose maximum is at the nearest point).
    fn chord_within(&self, p: Point, q: Point, tol: f64) -> bool {
        if self.dist(p) > tol || self.dist(q) > tol {
            return false;
        }
        let Part::Arc { a, b, c, .. } = *self else {
            return true;
        };
        let d = q - p;
        let dd = d.dot(d);
        if dd == 0.0 {
            return true;
        }
        let at = |s: f64| s > 0.0 && s < 1.0 && self.dist(p + d * s) > tol;
        if at((c - p).dot(d) / dd) {
            return false;
        }
        for e in [a, b] {
            let u = e - c;
            let den = u.cross(d);
            if den != 0.0 && at(-u.cross(p - c) / den) {
                return false;
            }
        }
        true
    }
}

/// Merges consecutive lines on one line (every point merged over within a two-hundredth of
/// the tolerance of the merged line) and arcs on one circle (the same centre and radius
/// within a two-hundredth of the tolerance and the same direction, at most a half turn in
/// all), so a merge moves the curve by at most [`MERGE_SHARE`] of the tolerance. `end` is
/// where an open path's last piece ends.
fn merge(vs: Vec<Vertex>, closed: bool, end: Option<Point>, tol: f64) -> Vec<Vertex> {
    let n = vs.len();
    if n < 2 {
        return vs;
    }
    let seg = |k: usize| -> Segment {
        let b = if k + 1 < n {
            vs[k + 1].pos()
        } else if closed {
            vs[0].pos()
        } else {
            end.unwrap_or(vs[k].pos())
        };
        Segment::from_bulge(vs[k].pos(), b, vs[k].bulge)
    };
    let eps = tol * MERGE_SHARE / 2.0;
    let mut out: Vec<Vertex> = Vec::with_capacity(n);
    let mut k = 0;
    while k < n {
        let first = seg(k);
        let a = first.start();
        let mut e = k + 1;
        match first {
            Segment::Line { b, .. } => {
                // the points merged over, each to stay within eps of the merged line
                let mut inner = vec![b];
                while e < n && inner.len() < 64 {
                    let Segment::Line { b: nb, .. } = seg(e) else {
                        break;
                    };
                    let d = nb - a;
                    let l = d.len();
                    if l == 0.0
                        || !inner.iter().all(|&p| {
                            d.cross(p - a).abs() <= eps * l
                                && (p - a).dot(d) > 0.0
                                && (nb - p).dot(d) > 0.0
                        })
                    {
                        break;
                    }
                    inner.push(nb);
                    e += 1;
                }
                out.push(Vertex::line(a));
            }
            Segment::Arc {
                center,
                radius,
                ccw,
                ..
            } => {
                let mut sweep = first.sweep();
                while e < n {
                    let next = seg(e);
                    let Segment::Arc {
                        center: c1,
                        radius: r1,
                        ccw: w1,
                        ..
                    } = next
                    else {
                        break;
                    };
                    if w1 != ccw
                        || center.dist(c1) > eps
                        || (radius - r1).abs() > eps
                        || (sweep + next.sweep()).abs() > PI + 1e-9
                    {
                        break;
                    }
                    sweep += next.sweep();
                    e += 1;
                }
                out.push(Vertex::new(a.x, a.y, (sweep / 4.0).tan()));
            }
        }
        k = e;
    }
    out
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

/// The equal-tangent-length biarc from `p0` (unit tangent `t0`) to `p1` (unit tangent
/// `t1`): its joint, the unit tangent there and the two arcs' bulges; None when there is
/// none within half turns.
fn biarc(p0: Point, t0: Point, p1: Point, t1: Point) -> Option<(Point, Point, f64, f64)> {
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
    let tj = (q1 - q0).unit();
    let b0 = bulge_from_tangent(p0, t0, joint)?;
    let b1 = bulge_from_tangent(joint, tj, p1)?;
    Some((joint, tj, b0, b1))
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

    #[test]
    fn knots_of_a_sampled_circle_lie_on_the_midway_circle() {
        let n = 100;
        let r = 300.0;
        let pts: Vec<Point> = (0..n)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                Point::new(r * a.cos(), r * a.sin())
            })
            .collect();
        let k = Knots::closed_loop(&pts, false);
        let s = r * (1.0 - (PI / n as f64).cos());
        for p in &k.pos {
            assert!((p.len() - (r - s / 2.0)).abs() < s * 1e-3, "{}", p.len());
        }
    }

    #[test]
    fn an_arc_part_measures_a_chord_dipping_inside_it() {
        // a half circle of radius 10; the chord from (10,0) to (-10,0) through the centre
        // is 10 from the arc in its middle, though both its ends lie on the arc
        let part = Part::new(Point::new(10.0, 0.0), Point::new(-10.0, 0.0), 1.0, 1e-3);
        assert!(part.chord_within(Point::new(10.0, 0.0), Point::new(10.0, 0.0), 1e-9));
        assert!(!part.chord_within(Point::new(10.0, 0.0), Point::new(-10.0, 0.0), 9.9));
        assert!(part.chord_within(Point::new(10.0, 0.0), Point::new(-10.0, 0.0), 10.0 + 1e-9));
    }
}
