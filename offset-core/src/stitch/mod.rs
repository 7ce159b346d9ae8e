//! Stitch paths: running, bean and tie stitches along seams offset from a base curve, snapped to the 0.1 mm feed grid.
//!
//! A pattern sewing machine's X–Y feed moves in 0.1 mm steps (Oh, Yun & Kim 2006). A seam is
//! sewn as needle drops along a curve: the curve is cut into *runs* at every corner sharper
//! than the corner angle (a needle drop lands exactly on each such corner), and each run gets
//! `n = ceil(len / L)` stitches of equal arc length. Each needle drop is rounded to the grid
//! from its exact absolute position (never by accumulating rounded steps, so nothing drifts).
//! When a stitch (after rounding) would stray farther than the tolerance from the curve — a
//! chord of a tight arc, say — or grow longer than the format's longest stitch, that run gets
//! one more stitch, until every stitch fits. Stitches therefore never exceed `L` by more than
//! the grid's rounding (√2 · 0.05 mm) and never exceed the format's maximum.

use crate::geom::{Bounds, Point, Polyline, Segment, Shape};
use crate::offset::{offset_polyline, Join, OffsetError, OffsetOptions};
use crate::toolpath::{Move, Toolpath};
use serde::{Deserialize, Serialize};

/// The feed grid of pattern sewing machines and embroidery files, mm.
pub const GRID: f64 = 0.1;
/// The farthest rounding to the grid can move a point: half a grid step on each axis.
pub const GRID_SLACK: f64 = 0.070_710_678_118_654_76;
/// The shortest and longest stitch length an operator may set, mm.
pub const MIN_STITCH_LENGTH: f64 = 1.0;
pub const MAX_STITCH_LENGTH: f64 = 12.7;

/// Everything a stitch path needs besides the shape (keys left out of JSON take the defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StitchParams {
    /// Nominal stitch length L, mm (1 to 12.7).
    pub stitch_length: f64,
    /// The rows to sew, as offsets from each base curve in mm: 0 sews on the curve; for a
    /// closed curve a positive offset is outside and a negative one inside; for an open curve
    /// positive is left of the direction of travel and negative right.
    pub rows: Vec<f64>,
    /// Bean stitch: each stitch is sewn three times (forward, back, forward).
    pub bean: bool,
    /// Tie-in and tie-off: the first and last stitch of each seam are locked by sewing
    /// forward, back and forward over `tie_length`.
    pub tie: bool,
    /// Length of the tie stitches, mm (at most one stitch).
    pub tie_length: f64,
    /// A vertex where the direction turns by more than this many degrees is a corner and gets
    /// a needle drop exactly on it.
    pub corner_angle: f64,
    /// Round the corners of offset rows (Join::Round) instead of keeping them sharp (miter).
    pub round_corners: bool,
    /// Every point of every stitch lies within this distance of its curve, mm (at least 0.1,
    /// since the grid alone moves points by up to 0.071 mm).
    pub tolerance: f64,
    /// The target format's longest stitch record, mm (DST: 12.1).
    pub max_stitch: f64,
    /// The target format's longest jump record, mm; longer jumps are split into equal steps.
    pub max_jump: f64,
    /// Cut the thread at the end of each seam before jumping to the next.
    pub trim: bool,
    /// The machine's sewing area, mm; every needle drop and jump must lie inside.
    pub area: Option<Bounds>,
}

impl Default for StitchParams {
    fn default() -> Self {
        StitchParams {
            stitch_length: 2.5,
            rows: vec![0.0],
            bean: false,
            tie: true,
            tie_length: 1.0,
            corner_angle: 20.0,
            round_corners: false,
            tolerance: 0.2,
            max_stitch: 12.1,
            max_jump: 12.1,
            trim: true,
            area: None,
        }
    }
}

/// Why a stitch path could not be planned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StitchError {
    #[error("invalid stitch parameter: {0}")]
    BadParam(String),
    #[error("cannot offset path {path} by {distance} mm for a row")]
    Offset {
        path: usize,
        distance: f64,
        #[source]
        source: OffsetError,
    },
    #[error("path {path} has a vertex that is not a finite number")]
    NotFinite { path: usize },
    #[error("the shape has nothing to sew: {0}")]
    Empty(String),
    #[error(
        "move {index} goes to ({x:.1}, {y:.1}) mm, outside the sewing area \
         ({:.1}, {:.1})–({:.1}, {:.1}) mm", area.min.x, area.min.y, area.max.x, area.max.y
    )]
    OutsideArea {
        index: usize,
        x: f64,
        y: f64,
        area: Bounds,
    },
}

impl StitchParams {
    /// The stitch length actually planned: `L`, but short enough that rounding to the grid
    /// cannot push a stitch past the format's maximum.
    pub fn effective_length(&self) -> f64 {
        self.stitch_length.min(self.max_stitch - 2.0 * GRID_SLACK)
    }

    fn check(&self) -> Result<(), StitchError> {
        let bad = |m: String| Err(StitchError::BadParam(m));
        if !(self.stitch_length.is_finite()
            && (MIN_STITCH_LENGTH..=MAX_STITCH_LENGTH).contains(&self.stitch_length))
        {
            return bad(format!(
                "the stitch length must be {MIN_STITCH_LENGTH} to {MAX_STITCH_LENGTH} mm, got {}",
                self.stitch_length
            ));
        }
        if !(self.max_stitch.is_finite() && self.max_stitch >= 1.0 + 2.0 * GRID_SLACK) {
            return bad(format!(
                "the format's longest stitch must be at least 1.15 mm, got {}",
                self.max_stitch
            ));
        }
        if !(self.max_jump.is_finite() && self.max_jump >= 1.0) {
            return bad(format!(
                "the format's longest jump must be at least 1 mm, got {}",
                self.max_jump
            ));
        }
        if !(self.tolerance.is_finite() && self.tolerance >= 0.1) {
            return bad(format!(
                "the tolerance must be at least 0.1 mm (the 0.1 mm feed grid alone moves \
                 points by up to 0.071 mm), got {}",
                self.tolerance
            ));
        }
        if !(self.corner_angle.is_finite() && (0.0..180.0).contains(&self.corner_angle)) {
            return bad(format!(
                "the corner angle must be 0 to 180 degrees, got {}",
                self.corner_angle
            ));
        }
        if !(self.tie_length.is_finite() && self.tie_length > 0.0) {
            return bad(format!(
                "the tie length must be a positive number, got {}",
                self.tie_length
            ));
        }
        if self.rows.is_empty() {
            return bad("at least one row is needed (0 sews on the curve)".into());
        }
        if let Some(r) = self.rows.iter().find(|r| !r.is_finite()) {
            return bad(format!("the row offset {r} is not a finite number"));
        }
        if let Some(a) = self.area {
            if a.is_empty() || !a.min.is_finite() || !a.max.is_finite() {
                return bad("the sewing area is empty".into());
            }
        }
        Ok(())
    }
}

/// Rounds a point to the 0.1 mm grid (from its absolute position).
pub fn snap(p: Point) -> Point {
    Point::new((p.x / GRID).round() * GRID, (p.y / GRID).round() * GRID)
}

/// Whether a coordinate lies on the 0.1 mm grid (within floating-point noise).
pub fn on_grid(v: f64) -> bool {
    let u = v / GRID;
    (u - u.round()).abs() < 1e-6
}

/// Plans the stitch path of every path of `shape`, row by row: each path's rows in the
/// order given, a trim and a jump between seams, a trim at the end.
pub fn stitch(shape: &Shape, p: &StitchParams) -> Result<Toolpath, StitchError> {
    p.check()?;
    let opts = OffsetOptions {
        join: if p.round_corners {
            Join::Round
        } else {
            Join::Miter
        },
        // generous: a label's corners stay sharp down to ~11° (1 / sin(θ/2) ≤ 10)
        miter_limit: 10.0,
        tolerance: (p.tolerance / 20.0).min(0.01),
    };
    let mut seams: Vec<Polyline> = Vec::new();
    for (i, path) in shape.paths.iter().enumerate() {
        if !path.is_finite() {
            return Err(StitchError::NotFinite { path: i });
        }
        if path.segment_count() == 0 || path.length() < GRID {
            continue;
        }
        for &d in &p.rows {
            if d == 0.0 {
                seams.push(path.clone());
            } else {
                let rows =
                    offset_polyline(path, d, &opts).map_err(|source| StitchError::Offset {
                        path: i,
                        distance: d,
                        source,
                    })?;
                seams.extend(
                    rows.into_iter()
                        .filter(|r| r.segment_count() > 0 && r.length() >= GRID),
                );
            }
        }
    }
    if seams.is_empty() {
        return Err(StitchError::Empty(
            "no path (or row) is long enough for a stitch".into(),
        ));
    }
    let mut tp = Toolpath::new("stitch");
    let mut at = Point::default();
    for (k, seam) in seams.iter().enumerate() {
        let drops = seam_drops(seam, p);
        if k > 0 && p.trim {
            tp.push(Move::Trim);
        }
        let first = drops[0];
        for step in split_move(at, first, p.max_jump) {
            tp.push(Move::Jump { to: step });
        }
        let mut last: Option<Point> = None;
        for d in drops {
            if last == Some(d) {
                continue;
            }
            tp.push(Move::Stitch { to: d });
            last = Some(d);
        }
        at = last.unwrap_or(first);
    }
    if p.trim {
        tp.push(Move::Trim);
    }
    if let Some(area) = p.area {
        check_area(&tp, area)?;
    }
    Ok(tp)
}

/// Checks that every stitch and jump of `tp` lies inside the sewing area; the error names
/// the first move outside and its coordinates.
pub fn check_area(tp: &Toolpath, area: Bounds) -> Result<(), StitchError> {
    for (index, m) in tp.moves.iter().enumerate() {
        if let Move::Stitch { to } | Move::Jump { to } = m {
            // compare on the grid: a drop at 100.0 is inside an area ending at 100.0
            let inside = to.x >= area.min.x - 1e-9
                && to.x <= area.max.x + 1e-9
                && to.y >= area.min.y - 1e-9
                && to.y <= area.max.y + 1e-9;
            if !inside {
                return Err(StitchError::OutsideArea {
                    index,
                    x: to.x,
                    y: to.y,
                    area,
                });
            }
        }
    }
    Ok(())
}

/// The grid points of a straight move from `from` to `to` in equal steps no longer than
/// `max` (after rounding), excluding `from`; empty when the two coincide.
pub fn split_move(from: Point, to: Point, max: f64) -> Vec<Point> {
    let d = from.dist(to);
    if d == 0.0 {
        return vec![];
    }
    let usable = (max - 2.0 * GRID_SLACK).max(GRID);
    let mut n = (d / usable).ceil().max(1.0) as usize;
    loop {
        let pts: Vec<Point> = (1..=n)
            .map(|i| {
                if i == n {
                    snap(to)
                } else {
                    snap(from.lerp(to, i as f64 / n as f64))
                }
            })
            .collect();
        let mut prev = snap(from);
        let ok = pts.iter().all(|&q| {
            let fits = prev.dist(q) <= max + 1e-9;
            prev = q;
            fits
        });
        if ok {
            return pts;
        }
        n += 1;
    }
}

/// The needle drops of one seam in sewing order, tie and bean stitches included.
pub fn seam_drops(seam: &Polyline, p: &StitchParams) -> Vec<Point> {
    let runs = runs(seam, p.corner_angle);
    let mut pts: Vec<Point> = Vec::new();
    // the run and arc length of each drop, for placing the tie stitches
    for run in &runs {
        let ds = run_drops(run, p);
        let skip = if pts.is_empty() { 0 } else { 1 };
        pts.extend(ds.into_iter().skip(skip));
    }
    let mut out: Vec<Point> = Vec::with_capacity(pts.len() * 3 + 6);
    let tie_in = if p.tie && pts.len() >= 2 {
        tie_point(&runs[0], 0.0, pts[1], p)
    } else {
        None
    };
    let tie_off = if p.tie && pts.len() >= 2 {
        let last = &runs[runs.len() - 1];
        tie_point(last, last.len, pts[pts.len() - 2], p)
    } else {
        None
    };
    out.push(pts[0]);
    if let Some(t) = tie_in {
        out.push(t);
        out.push(pts[0]);
    }
    for w in pts.windows(2) {
        out.push(w[1]);
        if p.bean {
            out.push(w[0]);
            out.push(w[1]);
        }
    }
    if let Some(t) = tie_off {
        out.push(t);
        out.push(pts[pts.len() - 1]);
    }
    out
}

/// A run of segments between two needle-drop corners, with cumulative lengths.
#[derive(Clone, Debug)]
pub struct Run {
    segs: Vec<Segment>,
    /// cum[i] = arc length at the start of segs[i]; cum[len] = total.
    cum: Vec<f64>,
    pub len: f64,
}

impl Run {
    fn new(segs: Vec<Segment>) -> Run {
        let mut cum = Vec::with_capacity(segs.len() + 1);
        let mut s = 0.0;
        for g in &segs {
            cum.push(s);
            s += g.length();
        }
        cum.push(s);
        Run { segs, cum, len: s }
    }
    /// The point at arc length `s` along the run.
    pub fn point_at(&self, s: f64) -> Point {
        let s = s.clamp(0.0, self.len);
        let i = match self.cum.partition_point(|&c| c <= s) {
            0 => 0,
            k => (k - 1).min(self.segs.len() - 1),
        };
        let l = self.cum[i + 1] - self.cum[i];
        let t = if l > 0.0 { (s - self.cum[i]) / l } else { 0.0 };
        self.segs[i].point_at(t.clamp(0.0, 1.0))
    }
    pub fn start(&self) -> Point {
        self.segs[0].start()
    }
    pub fn end(&self) -> Point {
        self.segs[self.segs.len() - 1].end()
    }
    /// Distance from `q` to the part of the run between arc lengths `s0` and `s1`.
    fn distance_between(&self, q: Point, s0: f64, s1: f64) -> f64 {
        let mut best = f64::INFINITY;
        for (i, g) in self.segs.iter().enumerate() {
            let (a, b) = (self.cum[i], self.cum[i + 1]);
            if b < s0 || a > s1 || b <= a {
                continue;
            }
            let t0 = ((s0 - a) / (b - a)).clamp(0.0, 1.0);
            let t1 = ((s1 - a) / (b - a)).clamp(0.0, 1.0);
            best = best.min(piece_distance(g, t0, t1, q));
        }
        best
    }
}

/// Distance from `q` to the part of `g` between parameters t0 ≤ t1.
fn piece_distance(g: &Segment, t0: f64, t1: f64, q: Point) -> f64 {
    match *g {
        Segment::Line { a, b } => {
            let (pa, pb) = (a.lerp(b, t0), a.lerp(b, t1));
            Segment::Line { a: pa, b: pb }.distance_to(q)
        }
        Segment::Arc {
            a, center, radius, ..
        } => {
            let sweep = g.sweep();
            let v = q - center;
            let ends = q.dist(g.point_at(t0)).min(q.dist(g.point_at(t1)));
            if v.len() == 0.0 || sweep == 0.0 {
                return ends;
            }
            let sa = (a - center).y.atan2((a - center).x);
            let mut d = v.y.atan2(v.x) - sa;
            let tau = 2.0 * std::f64::consts::PI;
            if sweep > 0.0 {
                d = d.rem_euclid(tau);
            } else {
                d = -((-d).rem_euclid(tau));
            }
            let t = d / sweep;
            if t >= t0 && t <= t1 {
                (v.len() - radius).abs()
            } else {
                ends
            }
        }
    }
}

/// Splits a polyline into runs at every vertex whose turn exceeds `corner_angle` degrees.
/// A closed polyline with a corner starts at its first corner.
pub fn runs(pl: &Polyline, corner_angle: f64) -> Vec<Run> {
    let segs: Vec<Segment> = pl.segments().filter(|s| s.length() > 1e-9).collect();
    if segs.is_empty() {
        return vec![];
    }
    let limit = corner_angle.to_radians();
    let turn = |a: &Segment, b: &Segment| {
        let (u, v) = (a.tangent_at(1.0), b.tangent_at(0.0));
        u.cross(v).atan2(u.dot(v)).abs()
    };
    let n = segs.len();
    // corner[i]: a needle drop is forced at the start of segs[i]
    let mut corner = vec![false; n];
    for i in 1..n {
        corner[i] = turn(&segs[i - 1], &segs[i]) > limit;
    }
    let mut order: Vec<usize> = (0..n).collect();
    if pl.closed {
        corner[0] = turn(&segs[n - 1], &segs[0]) > limit;
        if let Some(first) = corner.iter().position(|&c| c) {
            order.rotate_left(first);
        }
    }
    let mut out = Vec::new();
    let mut cur: Vec<Segment> = Vec::new();
    for (k, &i) in order.iter().enumerate() {
        if k > 0 && corner[i] && !cur.is_empty() {
            out.push(Run::new(std::mem::take(&mut cur)));
        }
        cur.push(segs[i]);
    }
    out.push(Run::new(cur));
    out
}

/// The needle drops of one run, from its start to its end, both included: `n` equal
/// stitches, with `n` raised until every stitch is within tolerance and short enough.
fn run_drops(run: &Run, p: &StitchParams) -> Vec<Point> {
    let l = p.effective_length();
    let mut n = ((run.len / l).ceil() as usize).max(1);
    // a run can always be sewn with stitches of a grid step or two; stop there at the latest
    let n_max = ((run.len / GRID).ceil() as usize).max(n) + 1;
    loop {
        let pts: Vec<Point> = (0..=n)
            .map(|k| {
                if k == 0 {
                    snap(run.start())
                } else if k == n {
                    snap(run.end())
                } else {
                    snap(run.point_at(run.len * k as f64 / n as f64))
                }
            })
            .collect();
        let fits = (1..=n).all(|k| {
            let s0 = run.len * (k - 1) as f64 / n as f64;
            let s1 = run.len * k as f64 / n as f64;
            stitch_fits(run, pts[k - 1], pts[k], s0, s1, p)
        });
        if fits || n >= n_max {
            return pts;
        }
        n += 1;
    }
}

/// Whether the stitch a→b (grid points) sewn for the part of the run between arc lengths
/// s0 and s1 is short enough and stays within tolerance of that part.
fn stitch_fits(run: &Run, a: Point, b: Point, s0: f64, s1: f64, p: &StitchParams) -> bool {
    let len = a.dist(b);
    if len > p.max_stitch + 1e-9 || len > p.stitch_length + 2.0 * GRID_SLACK + 1e-9 {
        return false;
    }
    // distance to the curve is 1-Lipschitz along the chord: sampling every h and keeping
    // the samples within tol - h/2 keeps every point within tol.
    let h = p.tolerance / 4.0;
    let m = ((len / h).ceil() as usize).max(1);
    let limit = p.tolerance - h / 2.0;
    (0..=m).all(|i| run.distance_between(a.lerp(b, i as f64 / m as f64), s0, s1) <= limit)
}

/// A tie point `tie_length` into the run from the end at arc length `from` (0 = start,
/// run.len = end), falling back to `fallback` (the neighbouring drop) when the short tie
/// stitch would leave the tolerance after rounding.
fn tie_point(run: &Run, from: f64, fallback: Point, p: &StitchParams) -> Option<Point> {
    let tie = p.tie_length.min(run.len);
    let (s0, s1, s) = if from == 0.0 {
        (0.0, tie, tie)
    } else {
        (run.len - tie, run.len, run.len - tie)
    };
    let t = snap(run.point_at(s));
    let end = snap(run.point_at(from));
    if t == end {
        return Some(fallback).filter(|f| *f != end);
    }
    if stitch_fits(run, end, t, s0, s1, p) {
        let closer = end.dist(t) < end.dist(fallback);
        Some(if closer { t } else { fallback })
    } else {
        Some(fallback)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn straight_run_gets_ceil_len_over_l_equal_stitches() {
        let pl = Polyline::from_points(&[Point::new(0.0, 0.0), Point::new(10.0, 0.0)], false);
        let p = StitchParams {
            tie: false,
            ..Default::default()
        };
        let d = seam_drops(&pl, &p);
        assert_eq!(d.len(), 5);
        for (k, q) in d.iter().enumerate() {
            assert!(q.dist(Point::new(2.5 * k as f64, 0.0)) < 0.051, "{q:?}");
        }
    }

    #[test]
    fn ties_and_beans_go_back_and_forth() {
        let pl = Polyline::from_points(&[Point::new(0.0, 0.0), Point::new(5.0, 0.0)], false);
        let p = StitchParams {
            bean: true,
            ..Default::default()
        };
        let xs: Vec<f64> = seam_drops(&pl, &p)
            .iter()
            .map(|q| (q.x * 10.0).round() / 10.0)
            .collect();
        assert_eq!(
            xs,
            vec![0.0, 1.0, 0.0, 2.5, 0.0, 2.5, 5.0, 2.5, 5.0, 4.0, 5.0]
        );
    }
}
