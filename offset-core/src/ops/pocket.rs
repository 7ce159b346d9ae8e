//! Pocket: contour-parallel clearing of regions with islands, with clean-up of what the step-over leaves behind (after Park & Choi 2001).
//!
//! For each region of the shape and each depth pass:
//! - The first pass runs on the region offset inward by the tool radius (P0); each next pass
//!   is the previous pass's region offset inward by the step-over (P(k+1) = Pk ⊖ s), until
//!   nothing is left. A region that splits gives several children; each is followed to
//!   its own end (a tree of passes).
//! - Uncut material: the tool running on the boundary of Pk clears everything within the
//!   tool radius R of it, so what it misses lies in Nk = Pk ⊖ R, and the later passes
//!   (inside P(k+1)) clear what lies within R of P(k+1). Where s ≤ R that is all of Nk.
//!   Where s > R, a point x of Nk farther than R from P(k+1) is less than a = s - R from
//!   Nk's boundary (else x would lie in Nk ⊖ a = P(k+1)); the point y of that boundary
//!   nearest x is within R of x and farther than R - a from P(k+1). So a clean-up pass
//!   along the stretches of Nk's boundary that lie farther than R - a from P(k+1) clears
//!   every cusp in corners, every narrow neck the next pass skips and the middle of the
//!   last pass, and stays inside Pk (no gouge).
//! - Order: outer to inner (each tree depth-first), so every link from a pass to the next
//!   one inside it starts over floor the last pass has just cleared. A link is cut at depth
//!   when it is a short hop (at most 1.5 step-overs) that stays inside the area the tool
//!   centre may visit (the parent pass's region, so it never touches a wall or an island);
//!   otherwise the tool retracts to the safe height, rapids and plunges.
//! - Climb milling (M3 spindle) runs the passes around the walls counter-clockwise and
//!   around the islands clockwise; conventional the other way.

use super::{pass_depths, Cutting, OpError};
use crate::geom::{Point, Polyline, Region, Segment, Shape, Vertex};
use crate::offset::{offset_region, OffsetError, OffsetOptions};
use crate::ops::profile::cut;
use crate::toolpath::{Move, Toolpath, P3};
use serde::{Deserialize, Serialize};
use std::str::FromStr;

/// How far apart neighbouring passes are.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stepover {
    /// In millimetres.
    Mm(f64),
    /// As a percentage of the tool diameter.
    Percent(f64),
}

impl Stepover {
    /// The step-over in mm for a tool of diameter `d`.
    pub fn mm(&self, d: f64) -> f64 {
        match *self {
            Stepover::Mm(v) => v,
            Stepover::Percent(p) => d * p / 100.0,
        }
    }
}

impl FromStr for Stepover {
    type Err = String;
    /// `1.2` is 1.2 mm, `40%` is 40 % of the tool diameter.
    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim();
        let (num, pct) = match t.strip_suffix('%') {
            Some(n) => (n.trim(), true),
            None => (t.strip_suffix("mm").unwrap_or(t).trim(), false),
        };
        let v: f64 = num.parse().map_err(|_| {
            format!("step-over \"{s}\" is neither a length in mm (1.2) nor a percentage (40%)")
        })?;
        if !(v.is_finite() && v > 0.0) {
            return Err(format!("step-over \"{s}\" must be more than 0"));
        }
        if pct && v > 100.0 {
            return Err(format!(
                "step-over \"{s}\" is more than the tool diameter (at most 100%)"
            ));
        }
        Ok(if pct {
            Stepover::Percent(v)
        } else {
            Stepover::Mm(v)
        })
    }
}

/// Everything a pocket needs besides the shape (keys left out of JSON take the defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PocketParams {
    /// Tool, depths, feeds and heights (`"cut": { … }` in JSON).
    pub cut: Cutting,
    /// Distance between neighbouring passes.
    pub stepover: Stepover,
}

impl Default for PocketParams {
    fn default() -> Self {
        PocketParams {
            cut: Cutting::default(),
            stepover: Stepover::Percent(40.0),
        }
    }
}

impl PocketParams {
    fn check(&self) -> Result<(), OpError> {
        self.cut.check()?;
        let s = self.stepover.mm(self.cut.tool.diameter);
        super::positive(s, "the step-over")?;
        if s > self.cut.tool.diameter {
            return Err(OpError::BadParam(format!(
                "the step-over {s} mm is more than the tool diameter {} mm: material would stay between passes",
                self.cut.tool.diameter
            )));
        }
        Ok(())
    }
}

/// An inward or outward offset of a region (negative distance shrinks it).
pub type RegionOffset<'a> = dyn Fn(&Region, f64) -> Result<Vec<Region>, OffsetError> + 'a;

/// Plans a pocket of every region of `shape` with the offset kernel.
pub fn pocket(shape: &Shape, p: &PocketParams) -> Result<Toolpath, OpError> {
    let opts = OffsetOptions {
        tolerance: p.cut.tolerance,
        ..Default::default()
    };
    pocket_with(shape, p, &|r: &Region, d: f64| offset_region(r, d, &opts))
}

/// One pass and the passes inside it.
#[derive(Clone, Debug)]
struct PassNode {
    region: Region,
    /// Clean-up paths (open or closed) cut after this pass, before the passes inside it.
    cleanup: Vec<Polyline>,
    children: Vec<PassNode>,
}

/// The pass tree from one tool-centre region, with its clean-up.
fn build(
    region: Region,
    s: f64,
    r: f64,
    tol: f64,
    off: &RegionOffset,
    budget: &mut usize,
) -> Result<PassNode, OpError> {
    if *budget == 0 {
        return Err(OpError::BadParam(
            "the pocket needs more than 100000 passes; use a larger step-over".into(),
        ));
    }
    *budget -= 1;
    // A pass whose walls exactly touch (an island grown to meet the wall at this step) is
    // a degenerate region the offset may refuse as self-crossing; then this step is taken
    // a hair shorter (1e-4 of the step-over), which opens the contact.
    let mut children = Vec::new();
    let mut touched = false;
    for c in off(&region, -s)? {
        match build(c, s, r, tol, off, budget) {
            Ok(n) => children.push(n),
            Err(OpError::Offset(OffsetError::SelfIntersecting { .. })) => {
                touched = true;
                break;
            }
            Err(e) => return Err(e),
        }
    }
    if touched {
        children.clear();
        for c in off(&region, -s * (1.0 - 1e-4))? {
            children.push(build(c, s, r, tol, off, budget)?);
        }
    }
    let mut cleanup = Vec::new();
    if s > r + tol {
        let threshold = r - (s - r) - tol;
        let next: Vec<&Region> = children.iter().map(|c| &c.region).collect();
        for missed in off(&region, -r)? {
            for pl in missed.boundaries() {
                cleanup.extend(far_stretches(pl, &next, threshold));
            }
        }
    }
    Ok(PassNode {
        region,
        cleanup,
        children,
    })
}

/// Distance from `p` to the union of `regions` (0 inside one).
fn dist_to(regions: &[&Region], p: Point) -> f64 {
    if regions.iter().any(|r| r.contains(p)) {
        return 0.0;
    }
    regions
        .iter()
        .flat_map(|r| r.boundaries())
        .map(|b| b.distance_to(p))
        .fold(f64::INFINITY, f64::min)
}

/// The stretches of the closed polyline whose segments come farther than `threshold` from
/// `regions` (a segment is kept whole when one of five points along it does).
fn far_stretches(pl: &Polyline, regions: &[&Region], threshold: f64) -> Vec<Polyline> {
    let n = pl.segment_count();
    if n == 0 {
        return Vec::new();
    }
    let keep: Vec<bool> = pl
        .segments()
        .map(|sg| {
            [0.0, 0.25, 0.5, 0.75, 1.0]
                .iter()
                .any(|&t| dist_to(regions, sg.point_at(t)) > threshold)
        })
        .collect();
    if keep.iter().all(|&k| k) {
        return vec![pl.clone()];
    }
    let Some(first_off) = keep.iter().position(|&k| !k) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    let mut run: Vec<Vertex> = Vec::new();
    for k in 1..=n {
        let i = (first_off + k) % n;
        if keep[i] {
            run.push(pl.vertices[i]);
        } else if !run.is_empty() {
            run.push(Vertex::line(pl.vertices[i].pos()));
            out.push(Polyline::new(std::mem::take(&mut run), false));
        }
    }
    if !run.is_empty() {
        run.push(Vertex::line(pl.vertices[first_off].pos()));
        out.push(Polyline::new(run, false));
    }
    out
}

/// Plans a pocket with the given region offset (the kernel's, or another for comparison).
pub fn pocket_with(
    shape: &Shape,
    p: &PocketParams,
    off: &RegionOffset,
) -> Result<Toolpath, OpError> {
    p.check()?;
    let r = p.cut.tool.radius();
    let s = p.stepover.mm(p.cut.tool.diameter);
    let regions = shape.regions();
    if regions.is_empty() {
        return Err(OpError::Empty(
            "a pocket needs closed outlines; the shape has none".into(),
        ));
    }
    let mut trees = Vec::new();
    let mut budget = 100_000usize;
    for region in &regions {
        for first in off(region, -r)? {
            trees.push(build(first, s, r, p.cut.tolerance, off, &mut budget)?);
        }
    }
    if trees.is_empty() {
        return Err(OpError::Empty(format!(
            "a {} mm tool does not fit in the pocket",
            p.cut.tool.diameter
        )));
    }
    let mut tp = Toolpath::new("pocket");
    tp.tool = Some(p.cut.tool);
    let mut em = Emitter {
        tp: &mut tp,
        p,
        s,
        at: P3::new(0.0, 0.0, p.cut.safe_z),
    };
    em.tp.push(Move::Rapid { to: em.at });
    if p.cut.spindle_rpm > 0.0 {
        em.tp.push(Move::Spindle {
            rpm: p.cut.spindle_rpm,
        });
    }
    let depths = pass_depths(p.cut.depth, p.cut.stepdown);
    for tree in &trees {
        for &z in &depths {
            em.retract();
            em.node(tree, None, z);
        }
    }
    em.retract();
    if p.cut.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: 0.0 });
    }
    Ok(tp)
}

struct Emitter<'a> {
    tp: &'a mut Toolpath,
    p: &'a PocketParams,
    s: f64,
    at: P3,
}

impl Emitter<'_> {
    fn push(&mut self, m: Move) {
        if let Move::Rapid { to } | Move::Linear { to, .. } | Move::Arc { to, .. } = m {
            self.at = to;
        }
        self.tp.push(m);
    }

    fn retract(&mut self) {
        if self.at.z < self.p.cut.safe_z {
            self.push(Move::Rapid {
                to: P3::at_z(self.at.xy(), self.p.cut.safe_z),
            });
        }
    }

    /// Goes to `q` at depth `z`: a feed move when the hop is short and inside `within`,
    /// else up, across and down.
    fn link(&mut self, q: Point, z: f64, within: Option<&Region>) {
        let here = self.at.xy();
        let at_depth = (self.at.z - z).abs() < 1e-9;
        if at_depth && here.dist(q) <= 1e-9 {
            return;
        }
        let inside = within.is_some_and(|reg| segment_inside(here, q, reg));
        if at_depth && inside && here.dist(q) <= 1.5 * self.s + self.p.cut.tolerance {
            self.push(Move::Linear {
                to: P3::at_z(q, z),
                feed: self.p.cut.feed,
            });
            return;
        }
        self.retract();
        self.push(Move::Rapid {
            to: P3::at_z(q, self.p.cut.safe_z),
        });
        self.push(Move::Linear {
            to: P3::at_z(q, z),
            feed: self.p.cut.plunge_feed,
        });
    }

    fn node(&mut self, n: &PassNode, parent: Option<&Region>, z: f64) {
        // the loops of this pass: the nearest first
        let mut todo: Vec<usize> = (0..=n.region.islands.len()).collect();
        while !todo.is_empty() {
            let here = self.at.xy();
            let (k, _) = todo
                .iter()
                .enumerate()
                .map(|(k, &li)| (k, boundary(&n.region, li).distance_to(here)))
                .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
            let li = todo.remove(k);
            let pl = boundary(&n.region, li);
            let pl = if self.p.cut.climb {
                pl.clone()
            } else {
                pl.reversed()
            };
            let (pl, start) = start_near(&pl, here);
            self.link(start, z, parent.or(Some(&n.region)));
            for seg in pl.segments() {
                self.push(cut(seg, z, self.p.cut.feed));
            }
        }
        // clean-up stretches, the nearest end first
        let mut todo: Vec<&Polyline> = n.cleanup.iter().collect();
        while !todo.is_empty() {
            let here = self.at.xy();
            let (k, _) = todo
                .iter()
                .enumerate()
                .map(|(k, c)| (k, c.distance_to(here)))
                .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
            let c = todo.remove(k);
            let (pl, start) = if c.closed {
                start_near(c, here)
            } else if c.vertices[0].pos().dist(here) <= c.vertices[c.len() - 1].pos().dist(here) {
                (c.clone(), c.vertices[0].pos())
            } else {
                let r = c.reversed();
                let s0 = r.vertices[0].pos();
                (r, s0)
            };
            self.link(start, z, Some(&n.region));
            for seg in pl.segments() {
                self.push(cut(seg, z, self.p.cut.feed));
            }
        }
        let mut kids: Vec<&PassNode> = n.children.iter().collect();
        while !kids.is_empty() {
            let here = self.at.xy();
            let (k, _) = kids
                .iter()
                .enumerate()
                .map(|(k, c)| (k, c.region.outer.distance_to(here)))
                .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
            let c = kids.remove(k);
            self.node(c, Some(&n.region), z);
        }
    }
}

fn boundary(r: &Region, i: usize) -> &Polyline {
    if i == 0 {
        &r.outer
    } else {
        &r.islands[i - 1]
    }
}

/// The closed polyline started at its point nearest `p` (the segment there split in two).
fn start_near(pl: &Polyline, p: Point) -> (Polyline, Point) {
    let mut best = (0usize, f64::INFINITY, pl.vertices[0].pos());
    for (i, s) in pl.segments().enumerate() {
        let q = s.closest_point(p);
        let d = q.dist(p);
        if d < best.1 {
            best = (i, d, q);
        }
    }
    let (i, _, q) = best;
    let n = pl.len();
    let seg = pl.segment(i);
    let mut vs: Vec<Vertex> = Vec::with_capacity(n + 1);
    let (a, b) = (seg.start(), seg.end());
    let bulge = pl.vertices[i].bulge;
    if q.dist(a) < 1e-9 {
        vs.extend((0..n).map(|k| pl.vertices[(i + k) % n]));
        return (Polyline::new(vs, true), a);
    }
    if q.dist(b) < 1e-9 {
        vs.extend((0..n).map(|k| pl.vertices[(i + 1 + k) % n]));
        return (Polyline::new(vs, true), b);
    }
    // split segment i at q: q→b, the other segments, then a→q
    let (b1, b2) = match seg {
        Segment::Line { .. } => (0.0, 0.0),
        Segment::Arc { center, .. } => {
            let total = seg.sweep();
            let part = crate::toolpath::arc_segment(a, q, center, total > 0.0).sweep();
            ((part / 4.0).tan(), ((total - part) / 4.0).tan())
        }
    };
    let _ = bulge;
    vs.push(Vertex::new(q.x, q.y, b2));
    for k in 1..n {
        vs.push(pl.vertices[(i + k) % n]);
    }
    let mut va = pl.vertices[i];
    va.bulge = b1;
    vs.push(va);
    (Polyline::new(vs, true), q)
}

/// Whether the straight move a→b stays inside the region (crosses none of its boundaries).
fn segment_inside(a: Point, b: Point, reg: &Region) -> bool {
    if !reg.contains(a.lerp(b, 0.5)) {
        return false;
    }
    let link = Segment::Line { a, b };
    let lb = link.bounds();
    for pl in reg.boundaries() {
        if !pl.bounds().overlaps(&lb, 1e-9) {
            continue;
        }
        for s in pl.segments() {
            if !s.bounds().overlaps(&lb, 1e-9) {
                continue;
            }
            // sample the boundary segment finely enough for a crossing test
            let k = match s {
                Segment::Line { .. } => 1,
                Segment::Arc { .. } => ((s.sweep().abs() / 0.05).ceil() as usize).clamp(1, 256),
            };
            for q in 0..k {
                let p0 = s.point_at(q as f64 / k as f64);
                let p1 = s.point_at((q + 1) as f64 / k as f64);
                if proper_cross(a, b, p0, p1) {
                    return false;
                }
            }
        }
    }
    true
}

/// Segments ab and cd cross at a point interior to ab (touching at a's or b's end does not count).
fn proper_cross(a: Point, b: Point, c: Point, d: Point) -> bool {
    let r = b - a;
    let s = d - c;
    let den = r.cross(s);
    if den.abs() < 1e-18 {
        return false;
    }
    let t = (c - a).cross(s) / den;
    let u = (c - a).cross(r) / den;
    t > 1e-9 && t < 1.0 - 1e-9 && (0.0..=1.0).contains(&u)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stepover_parses_mm_and_percent() {
        assert_eq!("1.5".parse::<Stepover>(), Ok(Stepover::Mm(1.5)));
        assert_eq!("40%".parse::<Stepover>(), Ok(Stepover::Percent(40.0)));
        assert_eq!("2mm".parse::<Stepover>(), Ok(Stepover::Mm(2.0)));
        assert!("abc".parse::<Stepover>().unwrap_err().contains("neither"));
        assert!("-1".parse::<Stepover>().is_err());
        assert!("150%".parse::<Stepover>().is_err());
        assert_eq!(Stepover::Percent(40.0).mm(6.0), 2.4);
    }

    #[test]
    fn start_near_splits_an_arc_on_the_circle() {
        let c = Polyline::circle(Point::default(), 10.0);
        let (pl, q) = start_near(&c, Point::new(0.0, 20.0));
        assert!(q.dist(Point::new(0.0, 10.0)) < 1e-9);
        assert!((pl.area() - c.area()).abs() < 1e-6);
        for s in pl.segments() {
            assert!((s.point_at(0.5).len() - 10.0).abs() < 1e-9);
        }
    }
}
