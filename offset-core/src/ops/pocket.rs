//! Pocket: contour-parallel clearing of regions with islands, with clean-up of what the step-over leaves behind (after Park & Choi 2001) and entries that never plunge into material.
//!
//! For each region of the shape and each depth pass:
//! - The first pass runs on the region offset inward by the tool radius (P0); each next pass
//!   is the previous pass's region offset inward by the step-over (P(k+1) = Pk ⊖ s), until
//!   nothing is left. A region that splits gives several children; each is followed to
//!   its own end (a tree of passes, built and walked with work lists: no recursion, so no
//!   depth of nesting can overflow the stack).
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
//!   otherwise, when the straight link keeps the tool centre inside the tree's first pass
//!   P0, the tool lifts 0.5 mm over the last level's floor (all of P0 swept by the tool was
//!   cleared there) and feeds across, else it retracts to the safe height and rapids; then
//!   it goes down by the entry.
//! - Entries ([`super::entry`]): the tool descends through air to the floor of the last
//!   depth pass, then into the material by a helix tangent to the pass at its start (or at
//!   one of 16 points along it) whose circle lies inside P0, the area the tool centre may
//!   visit, so it never comes nearer a wall or an island than the tool radius; else by a
//!   ramp around the pass (back and forth along an open clean-up stretch), which lies in
//!   P0 by construction; else, on a pass shorter than the tool diameter, straight down,
//!   with a warning in the tool path.
//! - Climb milling (M3 spindle) runs the passes around the walls counter-clockwise and
//!   around the islands clockwise; conventional the other way.

use super::entry::{self, Entry, Plunges};
use super::{pass_depths, Cutting, OpError};
use crate::geom::{winding_of, Point, Polyline, Region, Segment, Shape, Vertex};
use crate::offset::index::{BBox, BoxIndex};
use crate::offset::seg::{self as kseg, Seg};
use crate::offset::{offset_region, OffsetError, OffsetOptions};
use crate::ops::profile::cut;
use crate::toolpath::{Move, Toolpath, P3};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
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
    plan_with_kernel(shape, p, true, None).map(|(tp, _)| tp)
}

/// One pass and the passes inside it, in a tree held in a list (children by index).
#[derive(Clone, Debug)]
struct PassNode {
    region: Region,
    /// Clean-up paths (open or closed) cut after this pass, before the passes inside it.
    cleanup: Vec<Polyline>,
    children: Vec<usize>,
}

/// The most passes (offsets) one pocket may take.
const MAX_PASSES: usize = 100_000;

/// The pass tree from one tool-centre region (P0), with its clean-up: the tree's nodes,
/// the root first. Each node's step inward is made when the node is reached; a node whose
/// own step the offset refuses as self-crossing is a degenerate region (an island grown to
/// meet the wall exactly at this step), and then its parent's step is taken a hair shorter
/// (1e-4 of the step-over), which opens the contact.
fn build(
    first: Region,
    s: f64,
    r: f64,
    tol: f64,
    off: &RegionOffset,
    budget: &mut usize,
) -> Result<Vec<PassNode>, OpError> {
    let mut nodes: Vec<PassNode> = Vec::new();
    // (region, its step inward if made already, parent)
    let mut todo: Vec<(Region, Option<Vec<Region>>, Option<usize>)> = vec![(first, None, None)];
    while let Some((region, inner, parent)) = todo.pop() {
        if *budget == 0 {
            return Err(OpError::BadParam(format!(
                "the pocket needs more than {MAX_PASSES} passes; use a larger step-over"
            )));
        }
        *budget -= 1;
        let mut kids = match inner {
            Some(k) => k,
            None => off(&region, -s)?,
        };
        let mut grand = Vec::with_capacity(kids.len());
        let mut touched = false;
        for k in &kids {
            match off(k, -s) {
                Ok(g) => grand.push(g),
                Err(OffsetError::SelfIntersecting { .. }) => {
                    touched = true;
                    break;
                }
                Err(e) => return Err(e.into()),
            }
        }
        if touched {
            kids = off(&region, -s * (1.0 - 1e-4))?;
            grand = kids
                .iter()
                .map(|k| off(k, -s))
                .collect::<Result<Vec<_>, _>>()?;
        }
        let mut cleanup = Vec::new();
        if s > r + tol {
            let threshold = r - (s - r) - tol;
            let next = Geo::new(kids.iter());
            for missed in off(&region, -r)? {
                for pl in missed.boundaries() {
                    cleanup.extend(far_stretches(pl, &next, threshold));
                }
            }
        }
        let idx = nodes.len();
        nodes.push(PassNode {
            region,
            cleanup,
            children: Vec::new(),
        });
        if let Some(p) = parent {
            nodes[p].children.push(idx);
        }
        for (k, g) in kids.into_iter().zip(grand) {
            todo.push((k, Some(g), Some(idx)));
        }
    }
    Ok(nodes)
}

/// Regions' boundaries as the kernel's segments, with an R-tree over their boxes: the
/// distance and inside questions of the clean-up and of the helix entries, each in about
/// logarithmic time.
struct Geo {
    segs: Vec<Seg>,
    bulges: Vec<f64>,
    index: BoxIndex,
}

impl Geo {
    fn new<'a>(regions: impl Iterator<Item = &'a Region>) -> Geo {
        let mut segs = Vec::new();
        let mut bulges = Vec::new();
        for r in regions {
            for pl in r.boundaries() {
                for i in 0..pl.segment_count() {
                    let (a, b) = (pl.vertices[i], pl.vertices[(i + 1) % pl.len()]);
                    segs.push(Seg::from_bulge(a.pos(), b.pos(), a.bulge));
                    bulges.push(a.bulge);
                }
            }
        }
        let boxes: Vec<BBox> = segs.iter().map(|s| s.bbox()).collect();
        Geo {
            index: BoxIndex::new(&boxes),
            segs,
            bulges,
        }
    }

    /// Distance from `p` to the nearest boundary.
    fn dist(&self, p: Point) -> f64 {
        self.index
            .nearest_one(p.x, p.y, f64::INFINITY, |i| self.segs[i].dist(p))
            .map_or(f64::INFINITY, |(_, d)| d)
    }

    /// Whether `p` lies inside one of the regions: the winding numbers of the outers
    /// (counter-clockwise) and islands (clockwise) add up to 1 inside and 0 outside, and
    /// only the boundaries whose boxes meet the ray from `p` to the right add anything.
    fn contains(&self, p: Point) -> bool {
        let mut w = 0;
        self.index.query(&[p.x, p.y, f64::INFINITY, p.y], |i| {
            let s = &self.segs[i];
            w += winding_of(s.a, s.b, self.bulges[i], p);
            true
        });
        w != 0
    }

    /// Distance from `p` to the union of the regions (0 inside).
    fn dist_to_union(&self, p: Point) -> f64 {
        if self.contains(p) {
            0.0
        } else {
            self.dist(p)
        }
    }

    /// Whether the disc about `c` of radius `rho` lies inside the regions.
    fn holds_disc(&self, c: Point, rho: f64) -> bool {
        self.dist(c) >= rho * (1.0 - 1e-9) && self.contains(c)
    }
}

/// The stretches of the closed polyline whose segments come farther than `threshold` from
/// the regions of `next` (a segment is kept whole when one of five points along it does).
fn far_stretches(pl: &Polyline, next: &Geo, threshold: f64) -> Vec<Polyline> {
    let n = pl.segment_count();
    if n == 0 {
        return Vec::new();
    }
    let keep: Vec<bool> = pl
        .segments()
        .map(|sg| {
            [0.0, 0.25, 0.5, 0.75, 1.0]
                .iter()
                .any(|&t| next.dist_to_union(sg.point_at(t)) > threshold)
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
    plan(shape, p, off, true, None).map(|(tp, _)| tp)
}

/// What a level of 3D roughing knows of the material over it, for links at depth.
#[derive(Clone, Debug)]
pub(crate) struct Above {
    /// The floor the level above left (or the stock top), over this level, mm (> 0).
    pub height: f64,
    /// The tool-centre regions (P0) of the level above: everything within the tool radius
    /// of them was cleared down to that floor. None for the first level cut, under the
    /// stock top, where this level's own P0 is taken (it keeps off every island, and the
    /// part over the stock top lies inside the islands of a part without undercut).
    pub cleared: Option<Vec<Region>>,
    /// Where the tool stands when this level begins, in the level's frame (the end of the
    /// level above, on its floor), or None: at the safe height over the origin. A level
    /// does not go up at its end (the rough retracts after its last).
    pub from: Option<P3>,
}

/// A pocket of depth 0 that is a level of 3D roughing (`mesh::rough`) under `above`:
/// entries go down from the floor above, and links stay at [`LINK_LIFT`] over it where
/// the straight link keeps the tool centre inside the P0 of the level above (see
/// [`Above`]), else at the safe height. Returns the tool path and this level's P0 (for
/// the level below).
pub(crate) fn pocket_level(
    shape: &Shape,
    p: &PocketParams,
    above: &Above,
) -> Result<(Toolpath, Vec<Region>), OpError> {
    plan_with_kernel(shape, p, true, Some(above))
}

/// The pocket as it was planned before links at depth: every link that is not a short hop
/// goes up to the safe height (for comparison: retract counts, machine time).
pub fn pocket_safe_links(shape: &Shape, p: &PocketParams) -> Result<Toolpath, OpError> {
    plan_with_kernel(shape, p, false, None).map(|(tp, _)| tp)
}

/// [`plan`] with the offset kernel at the pocket's tolerance.
fn plan_with_kernel(
    shape: &Shape,
    p: &PocketParams,
    links_at_depth: bool,
    above: Option<&Above>,
) -> Result<(Toolpath, Vec<Region>), OpError> {
    let opts = OffsetOptions {
        tolerance: p.cut.tolerance,
        ..Default::default()
    };
    plan(
        shape,
        p,
        &|r: &Region, d: f64| offset_region(r, d, &opts),
        links_at_depth,
        above,
    )
}

fn plan(
    shape: &Shape,
    p: &PocketParams,
    off: &RegionOffset,
    links_at_depth: bool,
    above: Option<&Above>,
) -> Result<(Toolpath, Vec<Region>), OpError> {
    p.check()?;
    super::check_range(shape)?;
    let r = p.cut.tool.radius();
    let s = p.stepover.mm(p.cut.tool.diameter);
    let regions = shape.regions();
    if regions.is_empty() {
        return Err(OpError::Empty(
            "a pocket needs closed outlines; the shape has none".into(),
        ));
    }
    // the passes a region takes, at most: no point lies deeper inside it than half its box's
    // smaller side, nor than the radius of a disc of its area
    let passes: f64 = regions
        .iter()
        .map(|g| {
            let b = g.bounds();
            let inradius = (0.5 * b.width().min(b.height())).min((g.area().abs() / PI).sqrt());
            ((inradius - r) / s).max(0.0) + 1.0
        })
        .sum();
    if passes > MAX_PASSES as f64 {
        let b = shape.bounds();
        return Err(OpError::BadParam(format!(
            "pocketing the shape ({:.0} × {:.0} mm) with a {} mm tool at a step-over of {} mm would take up to {:.0} passes, more than {MAX_PASSES}; use a larger tool or step-over, or check the drawing's units",
            b.width(),
            b.height(),
            p.cut.tool.diameter,
            s,
            passes
        )));
    }
    let mut trees = Vec::new();
    let mut budget = MAX_PASSES;
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
    let from = above.and_then(|a| a.from);
    let mut em = Emitter {
        tp: &mut tp,
        p,
        s,
        at: from.unwrap_or(P3::new(0.0, 0.0, p.cut.safe_z)),
        z: 0.0,
        z_top: 0.0,
        slope: p.cut.ramp_angle.to_radians().tan(),
        plunges: Plunges::default(),
        p0: None,
    };
    if from.is_none() {
        em.tp.push(Move::Rapid { to: em.at });
    }
    if p.cut.spindle_rpm > 0.0 {
        em.tp.push(Move::Spindle {
            rpm: p.cut.spindle_rpm,
        });
    }
    let depths = pass_depths(p.cut.depth, p.cut.stepdown);
    let p0s: Vec<Region> = trees.iter().map(|t| t[0].region.clone()).collect();
    // a level of 3D roughing links through what the level above cleared (all its trees
    // at once: the level above may have been one region where this one is several)
    let level_links = match above {
        Some(a) if links_at_depth => Some(LinkArea::new(
            a.cleared.clone().unwrap_or_else(|| p0s.clone()),
        )),
        _ => None,
    };
    for tree in &trees {
        let root = Geo::new(std::iter::once(&tree[0].region));
        // a pocket of depth 0 without `above` does not know where the stock's top is: it
        // links at the safe height
        em.p0 = match &level_links {
            Some(c) => Some(c.clone()),
            None => (links_at_depth && p.cut.depth > 0.0)
                .then(|| LinkArea::new(vec![tree[0].region.clone()])),
        };
        for (k, &z) in depths.iter().enumerate() {
            em.z = z;
            em.z_top = match (k, above) {
                (0, Some(a)) => a.height,
                (0, None) => 0.0,
                _ => depths[k - 1],
            };
            if !em.link_low(em.at.xy()) {
                em.retract();
            }
            em.tree(tree, &root);
        }
    }
    // a level of 3D roughing stays where it ends (the rough goes on from there)
    if above.is_none() {
        em.retract();
    }
    let warning = em.plunges.warning(
        "no helix fitted there and the pass was shorter than the tool diameter for a ramp",
    );
    if p.cut.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: 0.0 });
    }
    tp.warnings.extend(warning);
    Ok((tp, p0s))
}

struct Emitter<'a> {
    tp: &'a mut Toolpath,
    p: &'a PocketParams,
    s: f64,
    at: P3,
    /// The depth of this pass, and the floor the last one left (the stock top at first).
    z: f64,
    z_top: f64,
    /// tan of the ramp angle
    slope: f64,
    plunges: Plunges,
    /// Where links at depth may go: the first pass (P0) of the tree being cut, or for a
    /// level of 3D roughing the P0 of the level above.
    p0: Option<LinkArea>,
}

/// The regions a link at depth must stay inside, with their boxes (shared, not copied,
/// by the trees of a level).
#[derive(Clone)]
struct LinkArea(std::rc::Rc<Vec<(crate::geom::Bounds, Region)>>);

impl LinkArea {
    fn new(regions: Vec<Region>) -> LinkArea {
        LinkArea(std::rc::Rc::new(
            regions.into_iter().map(|r| (r.bounds(), r)).collect(),
        ))
    }

    /// Whether the straight move a→b stays inside one of the regions.
    fn holds(&self, a: Point, b: Point) -> bool {
        let inside = |p: Point, bx: &crate::geom::Bounds| {
            let e = 1e-7;
            p.x >= bx.min.x - e && p.x <= bx.max.x + e && p.y >= bx.min.y - e && p.y <= bx.max.y + e
        };
        self.0
            .iter()
            .any(|(bx, r)| inside(a, bx) && inside(b, bx) && segment_inside(a, b, r))
    }
}

/// How far over the last level's floor a link at depth lifts the tool, mm.
pub const LINK_LIFT: f64 = 0.5;

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

    /// Over `q`, then down to `z` at the plunge feed: low over the floor of the last level
    /// when the straight link stays inside this tree's first pass (see `link_low`), else
    /// at the safe height.
    fn down_to(&mut self, q: Point, z: f64) {
        if self.link_low(q) {
            return self.push(Move::Linear {
                to: P3::at_z(q, z),
                feed: self.p.cut.plunge_feed,
            });
        }
        self.retract();
        if self.at.xy().dist(q) > 1e-12 {
            self.push(Move::Rapid {
                to: P3::at_z(q, self.p.cut.safe_z),
            });
        }
        self.push(Move::Linear {
            to: P3::at_z(q, z),
            feed: self.p.cut.plunge_feed,
        });
    }

    /// Links at depth: from a pass of this level to the start `q` of the next, the tool
    /// lifts to [`LINK_LIFT`] over the last level's floor and feeds across there, when the
    /// straight link keeps the tool centre inside the tree's first pass P0: every point
    /// within R of P0 was cleared by the last level (the pocket's coverage), so the tool
    /// moves through air. Returns whether it did (then it stands over `q` at the lift).
    fn link_low(&mut self, q: Point) -> bool {
        let lift = self.z_top + LINK_LIFT;
        let here = self.at;
        let Some(p0) = self.p0.as_ref() else {
            return false;
        };
        if here.z > lift + 1e-9 || here.z < self.z - 1e-9 || lift >= self.p.cut.safe_z {
            return false;
        }
        if here.xy().dist(q) > 1e-9 && !p0.holds(here.xy(), q) {
            return false;
        }
        if (here.z - lift).abs() > 1e-12 {
            self.push(Move::Linear {
                to: P3::at_z(here.xy(), lift),
                feed: self.p.cut.plunge_feed,
            });
        }
        if here.xy().dist(q) > 1e-12 {
            self.push(Move::Linear {
                to: P3::at_z(q, lift),
                feed: self.p.cut.feed,
            });
        }
        true
    }

    /// One tree of passes at the current depth: each pass, then its clean-up, then the
    /// passes inside it, the nearest first, depth-first with a work list.
    fn tree(&mut self, nodes: &[PassNode], root: &Geo) {
        self.node(nodes, 0, None, root);
        let mut stack: Vec<(usize, Vec<usize>)> = vec![(0, nodes[0].children.clone())];
        while let Some((n, kids)) = stack.last_mut() {
            if kids.is_empty() {
                stack.pop();
                continue;
            }
            let here = self.at.xy();
            let k = if kids.len() == 1 {
                0
            } else {
                kids.iter()
                    .enumerate()
                    .map(|(k, &c)| (k, nodes[c].region.outer.distance_to(here)))
                    .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a })
                    .0
            };
            let kid = kids.swap_remove(k);
            let parent = *n;
            self.node(nodes, kid, Some(parent), root);
            stack.push((kid, nodes[kid].children.clone()));
        }
    }

    /// The loops of one pass (the nearest first), then its clean-up stretches.
    fn node(&mut self, nodes: &[PassNode], n: usize, parent: Option<usize>, root: &Geo) {
        let node = &nodes[n];
        let within = parent.map_or(&node.region, |p| &nodes[p].region);
        let loops: Vec<&Polyline> = node.region.boundaries().collect();
        let mut todo: Vec<usize> = (0..loops.len()).collect();
        while !todo.is_empty() {
            let here = self.at.xy();
            let mut best = (0usize, 0usize, f64::INFINITY, here);
            for (k, &li) in todo.iter().enumerate() {
                if let Some((i, d, q)) = nearest_on(loops[li], here, best.2) {
                    best = (k, i, d, q);
                }
            }
            let (k, i, _, q) = best;
            let li = todo.swap_remove(k);
            let pl = loops[li];
            let l = along(&pl.segment(i), q).unwrap_or(0.0);
            let started = entry::restart(pl, i, l);
            let started = if self.p.cut.climb {
                started
            } else {
                started.reversed()
            };
            self.pass(started, within, root);
        }
        let mut todo: Vec<&Polyline> = node.cleanup.iter().collect();
        while !todo.is_empty() {
            let here = self.at.xy();
            let (k, _) = todo
                .iter()
                .enumerate()
                .map(|(k, c)| (k, c.distance_to(here)))
                .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
            let c = todo.swap_remove(k);
            let pl = if c.closed {
                match nearest_on(c, here, f64::INFINITY) {
                    Some((i, _, q)) => {
                        let l = along(&c.segment(i), q).unwrap_or(0.0);
                        entry::restart(c, i, l)
                    }
                    None => c.clone(),
                }
            } else if c.vertices[0].pos().dist(here) <= c.vertices[c.len() - 1].pos().dist(here) {
                c.clone()
            } else {
                c.reversed()
            };
            self.pass(pl, &node.region, root);
        }
    }

    /// Cuts the pass `pl` at the current depth from its first vertex: reached by a short
    /// feed at depth when one stays inside `within`, else from above by the entry.
    fn pass(&mut self, pl: Polyline, within: &Region, root: &Geo) {
        let z = self.z;
        let q = pl.vertices[0].pos();
        let here = self.at.xy();
        let at_depth = (self.at.z - z).abs() < 1e-9;
        let pl = if at_depth && here.dist(q) <= 1e-9 {
            pl
        } else if at_depth
            && here.dist(q) <= 1.5 * self.s + self.p.cut.tolerance
            && segment_inside(here, q, within)
        {
            self.push(Move::Linear {
                to: P3::at_z(q, z),
                feed: self.p.cut.feed,
            });
            pl
        } else {
            self.enter(pl, root)
        };
        for seg in pl.segments() {
            self.push(cut(seg, z, self.p.cut.feed));
        }
    }

    /// Goes down into the material at the start of `pl` by the entry asked for; returns the
    /// pass to cut, restarted where the entry ended.
    fn enter(&mut self, pl: Polyline, root: &Geo) -> Polyline {
        let c = &self.p.cut;
        let (z, z_top, slope, feed) = (self.z, self.z_top, self.slope, c.feed);
        let q = pl.vertices[0].pos();
        match c.entry {
            Entry::Plunge => {
                self.down_to(q, z);
                return pl;
            }
            Entry::Helix => {
                if let Some((pl, centre, ccw)) = self.find_helix(&pl, root) {
                    let start = pl.vertices[0].pos();
                    self.down_to(start, z_top);
                    for m in entry::helix(start, centre, ccw, z_top, z, slope, feed) {
                        self.push(m);
                    }
                    return pl;
                }
            }
            Entry::Ramp => {}
        }
        let len = pl.length();
        if len >= c.tool.diameter {
            self.down_to(q, z_top);
            if pl.closed {
                let (moves, rest) = entry::ramp_around(&pl, z_top, z, slope, feed);
                for m in moves {
                    self.push(m);
                }
                return rest;
            }
            for m in entry::zigzag(&pl, len, z_top, z, slope, feed) {
                self.push(m);
            }
            return pl;
        }
        self.plunges.note(P3::at_z(q, z));
        self.down_to(q, z);
        pl
    }

    /// A helix circle tangent to the pass at its start (or, for a closed pass, at one of
    /// 16 points along it, the nearest first) that lies inside the root region: the pass
    /// restarted there, the circle's centre, and whether it turns counter-clockwise (so it
    /// ends heading the pass's way). Diameters: the one asked for, or the tool diameter
    /// and down to half of it.
    fn find_helix(&self, pl: &Polyline, root: &Geo) -> Option<(Polyline, Point, bool)> {
        let d = self.p.cut.tool.diameter;
        let radii: Vec<f64> = if self.p.cut.helix_diameter > 0.0 {
            vec![self.p.cut.helix_diameter / 2.0]
        } else {
            vec![d / 2.0, d * 0.375, d / 4.0]
        };
        let total = pl.length();
        let spots: Vec<f64> = if pl.closed {
            let mut v = vec![0.0];
            for k in 1..=8 {
                v.push(total * k as f64 / 16.0);
                if k < 8 {
                    v.push(total * (16 - k) as f64 / 16.0);
                }
            }
            v
        } else {
            vec![0.0]
        };
        for l in spots {
            let (i, li) = seg_at(pl, l)?;
            let seg = pl.segment(i);
            let len = seg.length();
            let t = if len > 0.0 { li / len } else { 0.0 };
            let (p, tan) = (seg.point_at(t), seg.tangent_at(t));
            for &rho in &radii {
                for left in [true, false] {
                    let n = if left { tan.perp() } else { -tan.perp() };
                    let c = p + n * rho;
                    if root.holds_disc(c, rho) {
                        let started = if pl.closed {
                            entry::restart(pl, i, li)
                        } else {
                            pl.clone()
                        };
                        return Some((started, c, left));
                    }
                }
            }
        }
        None
    }
}

/// The segment `l` mm along the path and how far into it.
fn seg_at(pl: &Polyline, l: f64) -> Option<(usize, f64)> {
    let n = pl.segment_count();
    let mut at = 0.0;
    for i in 0..n {
        let len = pl.segment(i).length();
        if at + len >= l || i + 1 == n {
            return Some((i, (l - at).clamp(0.0, len)));
        }
        at += len;
    }
    None
}

/// How far along `s` its point `q` lies.
fn along(s: &Segment, q: Point) -> Option<f64> {
    match *s {
        Segment::Line { a, .. } => Some(a.dist(q)),
        Segment::Arc { a, center, .. } => {
            let total = s.sweep();
            let part = crate::toolpath::arc_segment(a, q, center, total > 0.0).sweep();
            let part = if part.abs() > total.abs() + 1e-12 {
                0.0
            } else {
                part
            };
            Some(s.length() * (part / total).abs())
        }
    }
}

/// A box around a segment given by its ends and bulge: the chord's box grown by the
/// sagitta (the arc strays no farther from its chord).
fn rough_box(a: Point, b: Point, bulge: f64) -> BBox {
    let g = a.dist(b) * bulge.abs() * 0.5;
    [
        a.x.min(b.x) - g,
        a.y.min(b.y) - g,
        a.x.max(b.x) + g,
        a.y.max(b.y) + g,
    ]
}

/// The point of the closed polyline nearest `p`, if nearer than `limit`: (segment, distance,
/// point). Segments whose rough box lies farther than the best so far are skipped.
fn nearest_on(pl: &Polyline, p: Point, limit: f64) -> Option<(usize, f64, Point)> {
    let n = pl.segment_count();
    let mut best: Option<(usize, f64, Point)> = None;
    let mut lim = limit;
    for i in 0..n {
        let (va, vb) = (pl.vertices[i], pl.vertices[(i + 1) % pl.len()]);
        let bx = rough_box(va.pos(), vb.pos(), va.bulge);
        let dx = (bx[0] - p.x).max(0.0).max(p.x - bx[2]);
        let dy = (bx[1] - p.y).max(0.0).max(p.y - bx[3]);
        if dx * dx + dy * dy >= lim * lim {
            continue;
        }
        let q = Segment::from_bulge(va.pos(), vb.pos(), va.bulge).closest_point(p);
        let d = q.dist(p);
        if d < lim {
            lim = d;
            best = Some((i, d, q));
        }
    }
    best
}

/// Whether the straight move a→b stays inside the region (crosses none of its boundaries;
/// touching at a or b does not count).
fn segment_inside(a: Point, b: Point, reg: &Region) -> bool {
    if !reg.contains(a.lerp(b, 0.5)) {
        return false;
    }
    let link = Seg::line(a, b);
    let lb = link.bbox();
    for pl in reg.boundaries() {
        for i in 0..pl.segment_count() {
            let (va, vb) = (pl.vertices[i], pl.vertices[(i + 1) % pl.len()]);
            let bx = rough_box(va.pos(), vb.pos(), va.bulge);
            if bx[0] > lb[2] || bx[2] < lb[0] || bx[1] > lb[3] || bx[3] < lb[1] {
                continue;
            }
            let s = Seg::from_bulge(va.pos(), vb.pos(), va.bulge);
            let h = kseg::intersect(&link, &s, 1e-12);
            if h.iter().any(|(_, t, _)| t > 1e-9 && t < 1.0 - 1e-9) {
                return false;
            }
        }
    }
    true
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
    fn a_loop_restarts_at_its_point_nearest_the_tool_on_the_circle() {
        let c = Polyline::circle(Point::default(), 10.0);
        let (i, d, q) = nearest_on(&c, Point::new(0.0, 20.0), f64::INFINITY).unwrap();
        assert!((d - 10.0).abs() < 1e-9 && q.dist(Point::new(0.0, 10.0)) < 1e-9);
        let pl = entry::restart(&c, i, along(&c.segment(i), q).unwrap());
        assert!(pl.vertices[0].pos().dist(q) < 1e-9);
        assert!((pl.area() - c.area()).abs() < 1e-6);
        for s in pl.segments() {
            assert!((s.point_at(0.5).len() - 10.0).abs() < 1e-9);
        }
    }
}
