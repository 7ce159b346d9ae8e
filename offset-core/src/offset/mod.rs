//! The offset kernel: grow or shrink closed polylines and regions with islands, and offset
//! open polylines to one side, by pair-wise interference removal (Choi & Park 1999; Park 2001).

mod convex;
pub mod index;
mod joins;
mod prune;
mod raw;
pub mod seg;
mod stages;
mod swallowtail;
mod zigzag;

use crate::geom::{hi, lo, Point, Polyline, Region, Shape, Vertex};
use prune::{prune, Chain, InputSet};
use raw::RawPath;
use seg::Seg;
use serde::{Deserialize, Serialize};

/// How a convex corner of the offset is closed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Join {
    /// An exact arc about the corner (the true offset).
    #[default]
    Round,
    /// The two offset segments extended to meet, chamfered beyond the miter limit.
    Miter,
    /// A straight line across the corner.
    Chamfer,
}

/// Settings of one offset.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct OffsetOptions {
    pub join: Join,
    /// With `Join::Miter`: the longest miter, as a multiple of the distance, before it is chamfered.
    pub miter_limit: f64,
    /// One tolerance governs every approximation, in mm.
    pub tolerance: f64,
}

impl Default for OffsetOptions {
    fn default() -> Self {
        OffsetOptions {
            join: Join::Round,
            miter_limit: 4.0,
            tolerance: 1e-3,
        }
    }
}

/// Why an offset could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OffsetError {
    #[error("vertex {vertex} of path {path} is not a finite number")]
    NotFinite { path: usize, vertex: usize },
    #[error("the offset distance {0} is not a finite number")]
    BadDistance(f64),
    #[error("the tolerance {0} must be a positive finite number")]
    BadTolerance(f64),
    #[error("path {path} crosses itself near ({}, {})", at.x, at.y)]
    SelfIntersecting { path: usize, at: Point },
    #[error("the offset kernel is not built yet")]
    NotImplemented,
}

/// Offsets one polyline: a closed one grows (d > 0) or shrinks (d < 0) as a region with no
/// islands; an open one moves left (d > 0) or right (d < 0) of its direction of travel.
///
/// Closed results keep the input's turning sense for their outer loops (holes that a
/// growing concave path encloses turn the other way). Open results run the same way as the
/// input and end where the end points' normals put them (no end caps).
pub fn offset_polyline(
    pl: &Polyline,
    distance: f64,
    opts: &OffsetOptions,
) -> Result<Vec<Polyline>, OffsetError> {
    check_args(distance, opts)?;
    let eps = eps_at(opts.tolerance, check_finite(pl, 0)?);
    let (segs, survey) = clean_surveyed(pl, eps);
    if segs.is_empty() {
        return Ok(Vec::new());
    }
    if pl.closed {
        let ccw = survey.area2 >= 0.0;
        let (segs, convex) = if ccw {
            (segs, Some(survey.convex_ccw))
        } else {
            (reverse(&segs), None)
        };
        let mut paths = vec![(segs, true)];
        let Checked {
            convex,
            tree,
            repaired,
        } = check_input(&mut paths, eps, opts.tolerance, convex)?;
        // (the survey's sums are of the segments in the order it made them)
        let turnings = vec![survey.turning.filter(|_| ccw && !repaired)];
        let segs = paths.pop().map(|(s, _)| s).unwrap_or_default();
        if distance == 0.0 {
            let out = build(segs, true, eps)
                .map(|l| if ccw { l.poly } else { l.poly.reversed() })
                .into_iter()
                .collect();
            return Ok(out);
        }
        if shrinks_away(&survey.bbox, distance) {
            return Ok(Vec::new());
        }
        let loops = run_closed(
            vec![(segs, true)],
            convex,
            tree,
            turnings,
            -distance,
            opts,
            eps,
        );
        Ok(loops
            .loops
            .into_iter()
            .map(|l| if ccw { l.poly } else { l.poly.reversed() })
            .collect())
    } else {
        let mut paths = vec![(segs, false)];
        check_input(&mut paths, eps, opts.tolerance, None)?;
        let segs = paths.pop().map(|(s, _)| s).unwrap_or_default();
        if segs.is_empty() {
            return Ok(Vec::new());
        }
        if distance == 0.0 {
            return Ok(build(segs, false, eps)
                .map(|l| l.poly)
                .into_iter()
                .collect());
        }
        let r = distance.abs();
        let mut splitters = Vec::new();
        for c in [segs[0].a, segs[segs.len() - 1].b] {
            splitters.extend(circle(c, r));
        }
        // a piece of this side's offset may come round to the path's other side: the other
        // side's raw offset marks where it starts to come too near (the dual offset)
        // (as it lies: no swallowtail resolved, every crossing of it marks a cut)
        splitters.extend(raw::raw_path(&segs, false, -distance, eps, 0.0).segs);
        Ok(run(
            &[(segs, false)],
            &splitters,
            index::BoxIndex::default(),
            distance,
            opts,
            eps,
        )
        .loops
        .into_iter()
        .map(|l| l.poly)
        .collect())
    }
}

/// Offsets a region: d > 0 grows the outer and shrinks the islands, d < 0 the reverse. The
/// result may be several regions (the pocket split) or none (offset away).
pub fn offset_region(
    region: &Region,
    distance: f64,
    opts: &OffsetOptions,
) -> Result<Vec<Region>, OffsetError> {
    offset_regions(std::slice::from_ref(region), distance, opts)
}

/// Offsets several regions as one set of points: where growing brings two of them (or a
/// region and the island of another it lies in) together, they merge, as the offset of
/// their union does. Paths are numbered in errors one region after another, outer first.
pub fn offset_regions(
    regions: &[Region],
    distance: f64,
    opts: &OffsetOptions,
) -> Result<Vec<Region>, OffsetError> {
    offset_regions_valid(regions, distance, opts).map(ValidRegions::into_regions)
}

/// Regions the kernel made, which it knows to be valid input: an offset's result is
/// repaired until it passes the input check as it stands (see `finish`), so offsetting it
/// again (a pocket's passes, each from the one before) needs no crossing search of its
/// input. Only the kernel makes one, and its regions can be read but not changed; given
/// regions go through [`offset_regions`] (or [`offset_regions_valid`]), which checks them.
#[derive(Clone, Debug)]
pub struct ValidRegions {
    regions: Vec<Region>,
    /// the geometric epsilon at which they were made valid (NaN: not known to be, so the
    /// next offset checks them)
    eps: f64,
}

impl ValidRegions {
    /// The regions.
    pub fn regions(&self) -> &[Region] {
        &self.regions
    }

    /// The regions, for the caller to keep (and change: they are then plain regions).
    pub fn into_regions(self) -> Vec<Region> {
        self.regions
    }

    /// Offsets these regions as [`offset_regions`] does. When the offset works at the
    /// geometric epsilon they were made valid at (the same tolerance, and coordinates of
    /// the same size), the input check's crossing search is skipped; otherwise they are
    /// checked as any input is.
    pub fn offset(&self, distance: f64, opts: &OffsetOptions) -> Result<ValidRegions, OffsetError> {
        offset_loops(&self.regions, distance, opts, self.eps)
    }
}

/// [`offset_regions`], with the result as [`ValidRegions`] (to offset it again without
/// the input check's crossing search). The given regions are checked.
pub fn offset_regions_valid(
    regions: &[Region],
    distance: f64,
    opts: &OffsetOptions,
) -> Result<ValidRegions, OffsetError> {
    offset_loops(regions, distance, opts, f64::NAN)
}

/// The offset of `regions`; `valid_at`: the geometric epsilon at which they are known to
/// be valid input (the kernel's own result), NaN when they are not known to be.
fn offset_loops(
    regions: &[Region],
    distance: f64,
    opts: &OffsetOptions,
    valid_at: f64,
) -> Result<ValidRegions, OffsetError> {
    check_args(distance, opts)?;
    let all: Vec<&Polyline> = regions.iter().flat_map(|r| r.boundaries()).collect();
    let mut extent: f64 = 0.0;
    for (i, p) in all.iter().enumerate() {
        extent = hi(extent, check_finite(p, i)?);
    }
    let eps = eps_at(opts.tolerance, extent);
    // per region: outer counter-clockwise, islands clockwise, whatever the caller handed us;
    // a region whose outer is empty goes with its islands
    let mut loops: Vec<(Vec<Seg>, bool)> = Vec::new();
    // per loop: its box, and whether it is convex as it now runs (None: not known)
    let mut surveys: Vec<(index::BBox, Option<bool>)> = Vec::new();
    // per loop: its length and turns as surveyed, if it runs as surveyed
    let mut turnings: Vec<Option<raw::Turning>> = Vec::new();
    let mut outers: Vec<usize> = Vec::new();
    for r in regions {
        for (i, p) in r.boundaries().enumerate() {
            let (segs, survey) = clean_surveyed(p, eps);
            if segs.is_empty() {
                if i == 0 {
                    break;
                }
                continue;
            }
            let want_ccw = i == 0;
            let as_surveyed = (survey.area2 >= 0.0) == want_ccw;
            let (segs, convex) = if as_surveyed {
                (segs, Some(survey.convex_ccw))
            } else {
                (reverse(&segs), None)
            };
            if i == 0 {
                outers.push(loops.len());
            }
            loops.push((segs, true));
            surveys.push((survey.bbox, convex));
            turnings.push(survey.turning.filter(|_| as_surveyed));
        }
    }
    // whether the loops are one convex loop, as surveyed
    let one_convex = match (loops.as_slice(), surveys.as_slice()) {
        ([(_, true)], [(_, known)]) => *known,
        _ => Some(false),
    };
    let checked = if eps == valid_at {
        // the kernel's own result at this epsilon: valid as it stands (what the check
        // would find, debug builds make sure of)
        debug_assert_eq!(
            check_crossings(
                &loops
                    .iter()
                    .map(|(s, c)| (s.as_slice(), *c))
                    .collect::<Vec<_>>(),
                eps
            )
            .map(|_| ()),
            Ok(()),
            "the kernel's result fails the input check"
        );
        let convex = match (loops.as_slice(), one_convex) {
            ([(segs, true)], None) => convex::is_convex_ccw(segs),
            (_, known) => known == Some(true),
        };
        Checked {
            convex,
            tree: index::BoxIndex::default(),
            repaired: false,
        }
    } else {
        check_input(&mut loops, eps, opts.tolerance, one_convex)?
    };
    let Checked {
        convex,
        mut tree,
        repaired,
    } = checked;
    if repaired {
        turnings = Vec::new();
    }
    // a region whose outer shrinks away goes whole (islands inside it cannot grow out of it)
    let mut keep = vec![true; loops.len()];
    for (k, &o) in outers.iter().enumerate() {
        if shrinks_away(&surveys[o].0, distance) {
            let end = outers.get(k + 1).copied().unwrap_or(loops.len());
            keep[o..end].iter_mut().for_each(|x| *x = false);
        }
    }
    if keep.iter().any(|k| !k) {
        // (the check's tree is of every loop)
        tree = index::BoxIndex::default();
        if !turnings.is_empty() {
            turnings = turnings
                .into_iter()
                .zip(&keep)
                .filter_map(|(t, &k)| k.then_some(t))
                .collect();
        }
    }
    let loops: Vec<(Vec<Seg>, bool)> = loops
        .into_iter()
        .zip(keep)
        .filter_map(|(l, k)| k.then_some(l))
        .collect();
    if loops.is_empty() {
        return Ok(ValidRegions {
            regions: Vec::new(),
            eps,
        });
    }
    if distance == 0.0 {
        // the checked input rebuilt: not the kernel's repaired result, so not vouched for
        let polys = Loops {
            loops: loops
                .into_iter()
                .filter_map(|(s, c)| build(s, c, eps))
                .collect(),
            uncrossed: false,
        };
        return Ok(ValidRegions {
            regions: assemble(polys),
            eps: f64::NAN,
        });
    }
    let polys = run_closed(loops, convex, tree, turnings, -distance, opts, eps);
    Ok(ValidRegions {
        regions: assemble(polys),
        eps,
    })
}

/// Sorts loops into regions: counter-clockwise loops are outers, clockwise ones islands of
/// the smallest outer around them. An island with no outer around it is what is left of an
/// island whose offset swallowed the outer's (Park 2001): it goes.
///
/// Loops that are whole raw curves nothing crossed (`Loops::uncrossed`) with one outer
/// among them need no test: each is part of the boundary of the points at least |d| inside
/// the input, so an island's loop bounds a hole of a piece of that set, and the piece's
/// outer boundary can only be the one outer. (At 100,000 vertices the test walked the
/// outer once for the islands' probes: 5 % of an offset with ten islands.)
fn assemble(polys: Loops) -> Vec<Region> {
    let Loops {
        loops: polys,
        uncrossed,
    } = polys;
    let mut outers: Vec<(Polyline, f64)> = Vec::new();
    let mut slivers: Vec<bool> = Vec::new();
    let mut islands = Vec::new();
    for l in polys {
        if l.area > 0.0 {
            outers.push((l.poly, l.area));
            slivers.push(l.sliver);
        } else {
            islands.push(l.poly);
        }
    }
    let probes: Vec<Point> = islands.iter().map(probe).collect();
    // per island: the smallest outer around its probe; each outer is walked once for all
    // the probes inside its bounds (of several outers: one outer's walk answers for every
    // probe, and its bounds would cost a walk of their own)
    let mut best: Vec<Option<(usize, f64)>> = vec![None; islands.len()];
    let several = outers.len() > 1;
    let one_holds_all = uncrossed && outers.len() == 1;
    if one_holds_all {
        debug_assert!(
            winding_numbers(&outers[0].0, &probes)
                .iter()
                .all(|&w| w != 0),
            "an island of an uncrossed offset lies outside its one outer"
        );
        best.fill(Some((0, outers[0].1)));
    }
    for (k, (o, a)) in outers.iter().enumerate() {
        if probes.is_empty() || one_holds_all {
            break;
        }
        let b = several.then(|| o.bounds());
        let inside: Vec<usize> = (0..probes.len())
            .filter(|&i| {
                b.is_none_or(|b| b.contains(probes[i])) && best[i].is_none_or(|(_, ba)| *a < ba)
            })
            .collect();
        if inside.is_empty() {
            continue;
        }
        let pts: Vec<Point> = inside.iter().map(|&i| probes[i]).collect();
        for (&i, w) in inside.iter().zip(winding_numbers(o, &pts)) {
            if w != 0 {
                best[i] = Some((k, *a));
            }
        }
    }
    let redundant = nested_outers(&outers, &slivers, &islands, &best);
    // (the outers move into their regions: at a million vertices a copy is 24 MB)
    let mut regions: Vec<Region> = outers
        .into_iter()
        .map(|(p, _)| Region {
            outer: p,
            islands: Vec::new(),
        })
        .collect();
    for (isl, b) in islands.into_iter().zip(best) {
        if let Some((k, _)) = b {
            regions[k].islands.push(isl);
        }
    }
    regions
        .into_iter()
        .zip(redundant)
        .filter_map(|(r, gone)| (!gone).then_some(r))
        .collect()
}

/// A point on a loop, the middle of its first segment: which loops are around it says which
/// are around the loop (the result's loops do not cross).
fn probe(p: &Polyline) -> Point {
    Seg::from_bulge(
        p.vertices[0].pos(),
        p.vertices[1 % p.len()].pos(),
        p.vertices[0].bulge,
    )
    .point_at(0.5)
}

/// Per outer, true when it is a sliver (see [`Loop::sliver`]) lying in another region
/// (inside that region's outer, outside its islands) with no island of its own: a region
/// inside another adds nothing to the set, and no valid offset makes one. The prune closes
/// such a loop where a notch of a growing boundary pinches shut and the raw curves cross
/// within a few ε of each other: a lens some micrometres long and nanometres thin (the
/// grown blob of `grown_blob_301_grows_into_one_region_while_its_notch_pinches_shut` grown
/// by 2.126 to 2.131 mm had one inside its outer, which the next pass grew into a disc).
/// `best`: each island's outer, as `assemble` found it.
fn nested_outers(
    outers: &[(Polyline, f64)],
    slivers: &[bool],
    islands: &[Polyline],
    best: &[Option<(usize, f64)>],
) -> Vec<bool> {
    let mut redundant = vec![false; outers.len()];
    if outers.len() < 2 || !slivers.iter().any(|&s| s) {
        return redundant;
    }
    let mut own_islands = vec![false; outers.len()];
    for &(k, _) in best.iter().flatten() {
        own_islands[k] = true;
    }
    let bounds: Vec<_> = outers.iter().map(|(p, _)| p.bounds()).collect();
    let island_bounds: Vec<_> = islands.iter().map(Polyline::bounds).collect();
    for j in (0..outers.len()).filter(|&j| slivers[j] && !own_islands[j]) {
        let probe = [probe(&outers[j].0)];
        // the smallest other outer around it
        let mut around: Option<(usize, f64)> = None;
        for (k, (o, a)) in outers.iter().enumerate() {
            if k != j
                && outers[j].1 < *a
                && around.is_none_or(|(_, ba)| *a < ba)
                && bounds[k].contains(probe[0])
                && winding_numbers(o, &probe)[0] != 0
            {
                around = Some((k, *a));
            }
        }
        let Some((k, _)) = around else { continue };
        // inside one of that outer's islands it is a region of its own in the hole
        let in_a_hole = islands
            .iter()
            .zip(best)
            .zip(&island_bounds)
            .any(|((isl, b), ib)| {
                b.is_some_and(|(o, _)| o == k)
                    && ib.contains(probe[0])
                    && winding_numbers(isl, &probe)[0] != 0
            });
        redundant[j] = !in_a_hole;
    }
    redundant
}
/// `Polyline::winding_numbers` of a closed loop, the same numbers: a segment is asked
/// about a point only when the point's height lies within the segment's reach (its chord's
/// heights for a line, widened as `geom::winding_of` widens an arc's box). The points are
/// sorted by height, so a segment finds the ones in its reach from where the segment
/// before it found its own (neighbours along a loop reach about the same heights: a step
/// or two, not one comparison per point; ten islands' probes against a 100,000-segment
/// outer were a million comparisons).
fn winding_numbers(pl: &Polyline, ps: &[Point]) -> Vec<i32> {
    let mut w = vec![0; ps.len()];
    if !pl.closed {
        return w;
    }
    let mut by_height: Vec<usize> = (0..ps.len()).collect();
    by_height.sort_unstable_by(|&i, &j| ps[i].y.total_cmp(&ps[j].y));
    let heights: Vec<f64> = by_height.iter().map(|&i| ps[i].y).collect();
    let next = pl.vertices.iter().skip(1).chain(pl.vertices.first());
    let mut first = 0;
    for (v, u) in pl.vertices.iter().zip(next) {
        let (a, b) = (v.pos(), u.pos());
        let (lo, hi) = if v.bulge == 0.0 {
            // the crossing rule counts a point only when lo <= p.y < hi
            (lo(a.y, b.y), hi(a.y, b.y))
        } else {
            let m = (b - a).len() * (v.bulge.abs() + 1.0);
            (lo(a.y, b.y) - m, hi(a.y, b.y) + m)
        };
        // the first height at lo or above, moved from the last segment's
        while first > 0 && heights[first - 1] >= lo {
            first -= 1;
        }
        while first < heights.len() && heights[first] < lo {
            first += 1;
        }
        for (&y, &i) in heights[first..].iter().zip(&by_height[first..]) {
            if y > hi {
                break;
            }
            w[i] += crate::geom::winding_of(a, b, v.bulge, ps[i]);
        }
    }
    w
}

/// Offsets a whole shape: its closed paths as nested regions, all at once (grown regions
/// that meet merge), its open paths to one side.
pub fn offset_shape(
    shape: &Shape,
    distance: f64,
    opts: &OffsetOptions,
) -> Result<Shape, OffsetError> {
    let mut out = Vec::new();
    for o in offset_regions(&shape.regions(), distance, opts)? {
        out.push(o.outer);
        out.extend(o.islands);
    }
    for p in shape.open_paths() {
        out.extend(offset_polyline(p, distance, opts)?);
    }
    Ok(Shape::new(out))
}

/// Whether shrinking a loop whose box is `b` by -`distance` leaves nothing: every point
/// inside a loop lies within half the smaller side of its bounding box of the loop (walk
/// towards the nearer side of the box and you leave the loop), so a larger shrink is
/// empty. Answering this up front spares the collapse of a dense loop into a knot of
/// crossing offsets. (A box larger than the loop's only answers no more often: the box of
/// a loop before the input check cut zig-zag lobes off it serves.)
fn shrinks_away(b: &index::BBox, distance: f64) -> bool {
    if distance >= 0.0 {
        return false;
    }
    -distance >= 0.5 * (b[2] - b[0]).min(b[3] - b[1])
}

fn check_args(distance: f64, opts: &OffsetOptions) -> Result<(), OffsetError> {
    if !distance.is_finite() {
        return Err(OffsetError::BadDistance(distance));
    }
    if !(opts.tolerance.is_finite() && opts.tolerance > 0.0) {
        return Err(OffsetError::BadTolerance(opts.tolerance));
    }
    Ok(())
}

/// Refuses a path with a coordinate or bulge that is not a finite number, naming the
/// vertex; else the path's extent, its largest |coordinate| (what `eps_at` asks, found in
/// the same pass over the vertices).
fn check_finite(pl: &Polyline, path: usize) -> Result<f64, OffsetError> {
    let mut m = 0.0;
    for (vertex, v) in pl.vertices.iter().enumerate() {
        if !(v.x.is_finite() && v.y.is_finite() && v.bulge.is_finite()) {
            return Err(OffsetError::NotFinite { path, vertex });
        }
        // (finite: a plain comparison, not f64::max's NaN rule)
        let a = hi(v.x.abs(), v.y.abs());
        if a > m {
            m = a;
        }
    }
    Ok(m)
}

/// The kernel's geometric epsilon: a ten-thousandth of the tolerance, but never below what
/// doubles can resolve at the shape's coordinates (`extent`, the largest |coordinate|).
fn eps_at(tol: f64, extent: f64) -> f64 {
    (tol * 1e-4).max(extent.max(1.0) * 1e-14)
}

/// [`eps_at`] the extent of `paths` (a path that is not finite counts as none: the callers
/// that may be handed one refuse it with `check_finite` first).
fn geometric_eps(tol: f64, paths: &[&Polyline]) -> f64 {
    let extent = paths
        .iter()
        .enumerate()
        .filter_map(|(i, p)| check_finite(p, i).ok())
        .fold(0.0, hi);
    eps_at(tol, extent)
}

/// The path's segments with the ones shorter than `eps` left out (their ends merged). The
/// segment after a short one keeps its shape: a vertex within `eps` of the one kept before
/// it goes, and the kept one takes its bulge (the bulge of the vertex that goes is the
/// segment leaving it; the kept one's was the short segment's), so an arc that starts a
/// nanometre after a vertex stays an arc rather than becoming its chord.
fn clean(pl: &Polyline, eps: f64) -> Vec<Seg> {
    clean_with::<()>(pl, eps).0
}

/// What the pass that makes a path's segments finds out about them on the way (at 100,000
/// segments every further pass over them reads 6.4 MB, a third of a millisecond): twice
/// the signed area of the loop they close, their box, whether they make one convex loop
/// of lines, counter-clockwise (`convex::is_convex_ccw`), and, when one of the first
/// `SURVEY_HEAD` segments rules that out, their length and turns as the stage schedule
/// reads them (`raw::ends_of`; a convex loop of lines shrinks without the schedule, and
/// their root and division per segment were a seventh of the time of the dense circle of
/// 30,000 shrunk to near collapse).
struct Survey {
    area2: f64,
    bbox: index::BBox,
    convex_ccw: bool,
    turning: Option<raw::Turning>,
}

/// What `segments_of` tells each segment it makes, in order: nothing (`()`), or a
/// [`Surveying`]. (A value of its own per pass, so the sums stay in registers.)
trait Look: Default {
    fn add(&mut self, s: &Seg);
}

impl Look for () {
    fn add(&mut self, _: &Seg) {}
}

/// How many of a path's first segments a [`Surveying`] keeps, to sum from the start once
/// the path turns out not to be a convex loop of lines (a gear's first valley comes within
/// a few; a loop that is convex longer gets its sums from a pass of their own).
const SURVEY_HEAD: usize = 16;

/// A [`Survey`] in the making.
struct Surveying {
    area2: f64,
    bbox: index::BBox,
    turns: convex::Turns,
    /// started at the first segment that rules out a convex loop of lines, if that is
    /// one of the first `SURVEY_HEAD`
    turning: Option<raw::Turning>,
    /// the first segments, and how many of them came
    head: [Seg; SURVEY_HEAD],
    count: usize,
}

impl Default for Surveying {
    fn default() -> Surveying {
        Surveying {
            area2: 0.0,
            bbox: [
                f64::INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
            ],
            turns: convex::Turns::default(),
            turning: None,
            head: [Seg::line(Point::default(), Point::default()); SURVEY_HEAD],
            count: 0,
        }
    }
}

impl Look for Surveying {
    // (inlined into the pass, as `Turns::add` is: called once per segment, the sums went
    // through memory and the dense circle of 100,000 took 3 % more instructions)
    #[inline(always)]
    fn add(&mut self, s: &Seg) {
        self.area2 += s.area2();
        // a line's box is its ends' (no call, no sweep test)
        let sb = if s.is_arc() {
            s.bbox()
        } else {
            [
                lo(s.a.x, s.b.x),
                lo(s.a.y, s.b.y),
                hi(s.a.x, s.b.x),
                hi(s.a.y, s.b.y),
            ]
        };
        self.bbox = index::union(&self.bbox, &sb);
        self.turns.add(s);
        match &mut self.turning {
            Some(t) => t.add(s),
            None if self.count < SURVEY_HEAD => {
                self.head[self.count] = *s;
                self.count += 1;
                if self.turns.refused() {
                    // the sums from the path's start, in its order
                    let mut t = raw::Turning::default();
                    for h in &self.head[..self.count] {
                        t.add(h);
                    }
                    self.turning = Some(t);
                }
            }
            None => {}
        }
    }
}

/// [`clean`] with its [`Survey`] (what the offset's input asks; the stages' and the
/// zig-zag repair's loops only want their segments).
fn clean_surveyed(pl: &Polyline, eps: f64) -> (Vec<Seg>, Survey) {
    let (segs, sv) = clean_with::<Surveying>(pl, eps);
    let survey = Survey {
        area2: sv.area2,
        bbox: sv.bbox,
        convex_ccw: pl.closed && sv.turns.convex_ccw(),
        turning: sv.turning,
    };
    (segs, survey)
}

/// [`clean`], with what `L` made of the segments kept.
fn clean_with<L: Look>(pl: &Polyline, eps: f64) -> (Vec<Seg>, L) {
    // (squared distances, no root per vertex)
    let eps2 = eps * eps;
    let near = |a: &Vertex, b: &Vertex| {
        let d = a.pos() - b.pos();
        d.dot(d) <= eps2
    };
    let vs = &pl.vertices;
    // most drawings have no such segment: their segments straight from the vertices, the
    // pass that makes them finding whether one is short
    let (segs, short, look) = segments_of::<L>(vs, pl.closed, eps2);
    if !short {
        return (segs, look);
    }
    let mut pts: Vec<Vertex> = Vec::with_capacity(vs.len());
    for v in vs {
        if let Some(last) = pts.last_mut() {
            if near(last, v) {
                last.bulge = v.bulge;
                continue;
            }
        }
        pts.push(*v);
    }
    if pl.closed {
        while pts.len() > 1 && near(&pts[pts.len() - 1], &pts[0]) {
            pts.pop();
        }
    }
    let (segs, _, look) = segments_of::<L>(&pts, pl.closed, eps2);
    (segs, look)
}

/// The segments between the vertices `pts`, each with its bulge (and from the last to the
/// first when `closed`), each told to a fresh `L`; true beside them when a chord is no
/// longer than the root of `short2`.
fn segments_of<L: Look>(pts: &[Vertex], closed: bool, short2: f64) -> (Vec<Seg>, bool, L) {
    let segs_n = match pts.len() {
        0 | 1 => 0,
        k if closed => k,
        k => k - 1,
    };
    let mut look = L::default();
    let mut short = false;
    // each vertex with the next (the first after the last when closed), no division
    let next = pts.iter().skip(1).chain(pts.first());
    let segs = pts
        .iter()
        .zip(next)
        .take(segs_n)
        .map(|(a, b)| {
            let s = Seg::from_bulge(a.pos(), b.pos(), a.bulge);
            let d = s.b - s.a;
            short |= d.dot(d) <= short2;
            look.add(&s);
            s
        })
        .collect();
    (segs, short, look)
}

fn reverse(segs: &[Seg]) -> Vec<Seg> {
    segs.iter().rev().map(|s| s.reversed()).collect()
}

/// The validity slack: how much nearer than |d| a kept run may come (rounding where curves
/// meet almost at one point), and the most the kernel moves a point of its result (a
/// sliver absorbed).
fn slack(tolerance: f64, eps: f64) -> f64 {
    (tolerance * 0.01).max(eps * 10.0)
}

/// The widest zig-zag of the input that is cut off rather than refused: a tenth of the
/// tolerance, so the offset of the repaired input stays within a tenth of the tolerance of
/// the exact offset of the input given (see `zigzag`).
fn zigzag_bound(tolerance: f64, eps: f64) -> f64 {
    (tolerance * 0.1).max(slack(tolerance, eps))
}

/// The input check (see `check_crossings`), after cutting off the zig-zags narrower than
/// `zigzag_bound` where paths cross themselves (see `zigzag`). Ok(true) when the paths are
/// one convex loop of lines, counter-clockwise (see `convex`), which cannot cross itself
/// and needs no crossing search.
/// `convex`: what a survey of the paths found of `is_convex_ccw`, when they are one loop
/// (None: find out).
fn check_input(
    paths: &mut [(Vec<Seg>, bool)],
    eps: f64,
    tolerance: f64,
    convex: Option<bool>,
) -> Result<Checked, OffsetError> {
    if let [(segs, true)] = &*paths {
        if convex.unwrap_or_else(|| convex::is_convex_ccw(segs)) {
            return Ok(Checked {
                convex: true,
                tree: index::BoxIndex::default(),
                repaired: false,
            });
        }
    }
    let checked = |tree, repaired| Checked {
        convex: false,
        tree,
        repaired,
    };
    let views: Vec<(&[Seg], bool)> = paths.iter().map(|(s, c)| (s.as_slice(), *c)).collect();
    let first = check_crossings(&views, eps);
    if first.is_ok() || !zigzag::remove(paths, eps, zigzag_bound(tolerance, eps)) {
        return first.map(|tree| checked(tree, false));
    }
    let views: Vec<(&[Seg], bool)> = paths.iter().map(|(s, c)| (s.as_slice(), *c)).collect();
    check_crossings(&views, eps).map(|tree| checked(tree, true))
}

/// What the input check found: whether the paths are one convex loop of lines, the tree
/// its crossing search walked over the boxes of the paths' segments as they now are, grown
/// by ε (none for a convex loop), and whether it cut zig-zags off them (then what a survey
/// found of them no longer holds).
struct Checked {
    convex: bool,
    tree: index::BoxIndex,
    repaired: bool,
}

/// Rejects input paths that cross themselves or each other, naming the path and the point.
/// Neighbouring segments may meet only at their shared vertex (a spike that runs back along
/// itself is allowed: it offsets as a 180° turn).
/// Ok: the tree the search walked, over each segment's box grown by ε, the paths one after
/// another (what the offset's distance questions ask of the same segments: see
/// `InputSet::new`).
fn check_crossings(paths: &[(&[Seg], bool)], eps: f64) -> Result<index::BoxIndex, OffsetError> {
    // report the crossing met first along the paths
    let best = std::cell::Cell::new(usize::MAX);
    let mut first: Option<Crossing> = None;
    let tree = each_crossing(
        paths,
        eps,
        |order, _, _| order < best.get(),
        |c| {
            if c.order < best.get() {
                best.set(c.order);
                first = Some(c);
            }
        },
    );
    match first {
        Some(c) => Err(OffsetError::SelfIntersecting {
            path: c.a.0,
            at: c.at,
        }),
        None => Ok(tree),
    }
}

/// A place where input paths cross: segment `a` = (path, index) at parameter `ta` meets
/// segment `b` at `tb`. `order` numbers the segments one path after another: the smaller of
/// the two.
#[derive(Clone, Copy, Debug)]
struct Crossing {
    at: Point,
    a: (usize, usize),
    ta: f64,
    b: (usize, usize),
    tb: f64,
    order: usize,
}

/// Calls `found` for the crossings (by the input rule) of every pair of segments `wanted`
/// asks for (it is given the pair's order and both segments' (path, index)); at most one
/// crossing per pair. Returns the tree it walked: over the segments' boxes grown by ε, one
/// path after another.
fn each_crossing(
    paths: &[(&[Seg], bool)],
    eps: f64,
    mut wanted: impl FnMut(usize, (usize, usize), (usize, usize)) -> bool,
    mut found: impl FnMut(Crossing),
) -> index::BoxIndex {
    // the segments numbered one path after another, each number's (path, index) beside
    // it; the segments themselves are read where they lie (at a million segments a copy
    // of them all is 64 MB written and read again)
    let total: usize = paths.iter().map(|(segs, _)| segs.len()).sum();
    let mut owner: Vec<(u32, u32)> = Vec::with_capacity(total);
    // (with the room for the levels of the tree packed over them)
    let mut boxes: Vec<index::BBox> = Vec::with_capacity(index::BoxIndex::room(total));
    for (pi, (segs, _)) in paths.iter().enumerate() {
        for (k, s) in segs.iter().enumerate() {
            owner.push((pi as u32, k as u32));
            boxes.push(index::grow(s.bbox(), eps));
        }
    }
    let tree = index::BoxIndex::in_order_owned(boxes);
    let owner_of = |i: usize| -> (usize, usize) {
        let (p, k) = owner[i];
        (p as usize, k as usize)
    };
    // whether segment (path, kb) follows (path, ka) on one path
    let follows = |(pa, ka): (usize, usize), (pb, kb): (usize, usize)| -> bool {
        if pa != pb {
            return false;
        }
        let (segs, closed) = paths[pa];
        kb == ka + 1 || (closed && ka == segs.len() - 1 && kb == 0)
    };
    tree.overlapping_pairs(|i, j| {
        let (oi, oj) = (owner_of(i), owner_of(j));
        if !wanted(i.min(j), oi, oj) {
            return;
        }
        let (si, sj) = (&paths[oi.0].0[oi.1], &paths[oj.0].0[oj.1]);
        let (adj_ij, adj_ji) = (follows(oi, oj), follows(oj, oi));
        if (adj_ij && prune::meet_only_at_the_joint(si, sj, eps))
            || (adj_ji && prune::meet_only_at_the_joint(sj, si, eps))
        {
            return;
        }
        let h = seg::intersect(si, sj, eps);
        if h.n == 0 {
            return;
        }
        if (adj_ij || adj_ji) && !si.is_arc() && !sj.is_arc() {
            // lines sharing a vertex: only a spike can overlap, and a spike is allowed
            let d1 = si.b - si.a;
            let d2 = sj.b - sj.a;
            if d1.cross(d2).abs() <= eps * d1.len().max(d2.len()) {
                return;
            }
        }
        for (p, t, u) in h.iter() {
            if adj_ij && p.dist(si.b) <= eps * 4.0 {
                continue;
            }
            if adj_ji && p.dist(si.a) <= eps * 4.0 {
                continue;
            }
            if !adj_ij && !adj_ji && touches(paths, oi, t, oj, u, p, eps) {
                continue;
            }
            found(Crossing {
                at: p,
                a: oi,
                ta: t,
                b: oj,
                tb: u,
                order: i.min(j),
            });
            return;
        }
    });
    tree
}

/// Where the boundary runs on either side of `p`, a point of segment `k` of `path` at
/// parameter `t`: the segment and parameter just before `p` and just after it, and how much
/// length each side has to sample from. None at an open path's end.
fn sides(
    paths: &[(&[Seg], bool)],
    (path, k): (usize, usize),
    t: f64,
    p: Point,
    eps: f64,
) -> Option<[(Seg, f64, f64); 2]> {
    let (segs, closed) = paths[path];
    let m = segs.len();
    let s = segs[k];
    let prev = if k > 0 {
        Some(segs[k - 1])
    } else if closed {
        Some(segs[m - 1])
    } else {
        None
    };
    let next = if k + 1 < m {
        Some(segs[k + 1])
    } else if closed {
        Some(segs[0])
    } else {
        None
    };
    let len = s.length();
    if p.dist(s.b) <= eps * 4.0 {
        let n = next?;
        Some([(s, 1.0, len), (n, 0.0, n.length())])
    } else if p.dist(s.a) <= eps * 4.0 {
        let q = prev?;
        Some([(q, 1.0, q.length()), (s, 0.0, len)])
    } else {
        Some([(s, t, t * len), (s, t, (1.0 - t) * len)])
    }
}

/// Whether the boundaries only touch at `p` (segment `a` at parameter `ta`, segment `b` at
/// `tb`) rather than cross there: the boundary of `b` stays on one side of the boundary of
/// `a` just before and just after `p`, as sampled at the same length along both. An
/// island touching the outer at one point is a valid region (its offset inward is pinched
/// off there); overlaps and undecidable cases count as crossings.
fn touches(
    paths: &[(&[Seg], bool)],
    a: (usize, usize),
    ta: f64,
    b: (usize, usize),
    tb: f64,
    p: Point,
    eps: f64,
) -> bool {
    let (Some(sa), Some(sb)) = (sides(paths, a, ta, p, eps), sides(paths, b, tb, p, eps)) else {
        return false;
    };
    let rho = 0.25
        * sa.iter()
            .chain(sb.iter())
            .map(|&(_, _, l)| l)
            .fold(f64::INFINITY, f64::min);
    if rho <= eps * 100.0 {
        return false;
    }
    // the point `rho` back (side 0) or on (side 1) from the hit along one boundary
    let at = |side: usize, (s, t, _): (Seg, f64, f64)| -> Point {
        let dt = rho / s.length();
        if side == 0 {
            s.point_at(t - dt)
        } else {
            s.point_at(t + dt)
        }
    };
    let (a0, a1) = (at(0, sa[0]) - p, at(1, sa[1]) - p);
    let ccw = |from: Point, to: Point| -> f64 {
        let x = from.cross(to).atan2(from.dot(to));
        if x < 0.0 {
            x + std::f64::consts::TAU
        } else {
            x
        }
    };
    // the side of `a` left of its travel: counter-clockwise from its way on to its way back
    let wedge = ccw(a1, a0);
    let margin = 1e-9;
    let side = |q: Point| -> Option<bool> {
        let x = ccw(a1, q);
        if x <= margin || (x - wedge).abs() <= margin || x >= std::f64::consts::TAU - margin {
            None
        } else {
            Some(x < wedge)
        }
    };
    match (side(at(0, sb[0]) - p), side(at(1, sb[1]) - p)) {
        (Some(x), Some(y)) => x == y,
        _ => false,
    }
}

/// The first place where `paths` cross themselves or each other, as (path, point); the
/// rule of the offset's input check (neighbours meet only at their shared vertex).
pub fn first_crossing(paths: &[Polyline], tolerance: f64) -> Option<(usize, Point)> {
    let refs: Vec<&Polyline> = paths.iter().collect();
    let eps = geometric_eps(tolerance, &refs);
    let cleaned: Vec<(Vec<Seg>, bool)> = paths.iter().map(|p| (clean(p, eps), p.closed)).collect();
    let views: Vec<(&[Seg], bool)> = cleaned.iter().map(|(s, c)| (s.as_slice(), *c)).collect();
    match check_crossings(&views, eps) {
        Err(OffsetError::SelfIntersecting { path, at }) => Some((path, at)),
        _ => None,
    }
}

/// The circle about `c` of radius `r`, as two half arcs.
fn circle(c: Point, r: f64) -> [Seg; 2] {
    let (e, w) = (c + Point::new(r, 0.0), c - Point::new(r, 0.0));
    [
        Seg::arc(c, r, e, w, std::f64::consts::PI),
        Seg::arc(c, r, w, e, std::f64::consts::PI),
    ]
}

/// Closed, oriented loops (outers counter-clockwise, islands clockwise) offset by `o` to
/// the left: in one stage, or with round joins and a distance much larger than the
/// loops' features in several (see `stages`), each from the loops the one before left.
/// `convex`: the loops are one convex loop of lines (as `check_input` found); `tree`: the
/// input check's over the loops' segments' boxes grown by ε if it made one (see `run`),
/// else an empty one;
/// `turnings`: per loop, its length and turns if its survey found them as it now runs
/// (see `Survey`), else empty or None.
#[allow(clippy::too_many_arguments)]
fn run_closed(
    mut loops: Vec<(Vec<Seg>, bool)>,
    convex: bool,
    mut tree: index::BoxIndex,
    mut turnings: Vec<Option<raw::Turning>>,
    o: f64,
    opts: &OffsetOptions,
    eps: f64,
) -> Loops {
    // one convex loop of lines shrunk: the intersection of its moved sides, no global stage
    if let [(segs, true)] = loops.as_mut_slice() {
        if let Some(result) = convex.then(|| convex::shrunk(segs, o, eps)).flatten() {
            // all of a dense loop's sides shorter than the slack: resampled from the
            // vertices as `despike` would resample its sides
            let delta = slack(opts.tolerance, eps);
            if let Some(lines) = resample_vertices(result.vertices(), delta) {
                return finish_despiked(vec![(lines, true)], false, opts, eps);
            }
            result.sides_into(segs);
            return finish(loops, opts, eps);
        }
    }
    let mut rest = o;
    let mut on_input = true;
    loop {
        let timer = stages::Timer::start(&loops);
        let step = match opts.join {
            Join::Round => {
                // the loops' sums as their survey found them where it did (the first stage,
                // one per loop), else a pass over them
                let known = std::mem::take(&mut turnings);
                let known = if known.len() == loops.len() {
                    known
                } else {
                    Vec::new()
                };
                let ends: Vec<raw::Ends> = loops
                    .iter()
                    .enumerate()
                    .map(|(k, (s, _))| match known.get(k) {
                        Some(Some(t)) => t.ends(rest),
                        _ => raw::ends_of(s, rest),
                    })
                    .collect();
                stages::first_stage(&loops, &ends, rest, on_input)
            }
            Join::Miter | Join::Chamfer => None,
        };
        on_input = false;
        let Some(step) = step else {
            let result = run(&loops, &[], tree, rest, opts, eps);
            timer.report("last stage", rest);
            return result;
        };
        // the stage's loops as regions, so an island left without its outer goes, then
        // as the next stage's input (the result is valid input: see `despike`, `zigzag`)
        let regions = assemble(run(&loops, &[], std::mem::take(&mut tree), step, opts, eps));
        timer.report("stage", step);
        rest -= step;
        loops = regions
            .iter()
            .flat_map(|r| r.boundaries())
            .map(|p| (clean(p, eps), true))
            .filter(|(s, _)| !s.is_empty())
            .collect();
        if loops.is_empty() {
            return Loops {
                loops: Vec::new(),
                uncrossed: false,
            };
        }
    }
}

/// Raw offsets of every path by `o` to the left, the global prune, then polylines.
/// `tree`: the input check's over the paths' segments' boxes one path after another, grown
/// by ε (the distance questions ask it: at a million segments, making the boxes again read
/// 64 MB and wrote 32 MB); empty: none made yet.
fn run(
    paths: &[(Vec<Seg>, bool)],
    splitters: &[Seg],
    tree: index::BoxIndex,
    o: f64,
    opts: &OffsetOptions,
    eps: f64,
) -> Loops {
    let valid_eps = slack(opts.tolerance, eps);
    // nearer the input than this, a point is dropped by the prune's test of a run too
    let sure = o.abs() - valid_eps;
    let raws: Vec<RawPath> = paths
        .iter()
        .map(|(segs, closed)| raw::raw_path(segs, *closed, o, eps, sure))
        .collect();
    let mut input = InputSet::new(paths.iter().map(|(s, _)| s.as_slice()).collect(), tree);
    let prune::Pruned { chains, uncrossed } = prune(raws, splitters, &mut input, o, eps, valid_eps);
    let mut pieces: Vec<(Vec<Seg>, bool)> = Vec::with_capacity(chains.len());
    // per piece: no segment of it is shorter than the slack, as the prune found (round
    // joins leave the segments as they are)
    let mut long: Vec<bool> = Vec::with_capacity(chains.len());
    for Chain {
        segs,
        whole_join,
        closed,
        shortest2,
    } in chains
    {
        // an open piece no longer than the validity slack is a sliver at a crossing (three
        // curves meeting almost at one point), not a path of its own
        if !closed && segs.iter().map(|s| s.length()).sum::<f64>() <= valid_eps {
            continue;
        }
        long.push(opts.join == Join::Round && shortest2 >= valid_eps * valid_eps);
        pieces.push((joins::apply(segs, &whole_join, opts), closed));
    }
    // whole raw curves that cross nothing, round joins as they are: nothing for the
    // zig-zag repair to find, unless the sliver repair changes them (see `finish`)
    let uncrossed = uncrossed && opts.join == Join::Round;
    finish_known(pieces, &long, opts, eps, uncrossed)
}

/// The offset's pieces as the result: slivers replaced (see `despike`), zig-zags cut off,
/// then polylines.
fn finish(pieces: Vec<(Vec<Seg>, bool)>, opts: &OffsetOptions, eps: f64) -> Loops {
    finish_known(pieces, &[], opts, eps, false)
}

/// `finish`; `uncrossed`: the pieces are whole raw curves among which the prune's crossing
/// search found nothing (see `prune::Pruned`). Then, when the sliver repair leaves them as
/// they are (no segment shorter than the slack), the zig-zag repair's crossing search would
/// find nothing either (it asks about a subset of the same pairs of the same segments, by
/// a rule that lets through every meeting the prune let through), and is skipped.
/// `long`: per piece, true when no segment of it is shorter than the slack (then the
/// sliver repair need not read it: at a million segments each pass reads 80 MB); empty
/// or false: not known.
fn finish_known(
    pieces: Vec<(Vec<Seg>, bool)>,
    long: &[bool],
    opts: &OffsetOptions,
    eps: f64,
    uncrossed: bool,
) -> Loops {
    let valid_eps = slack(opts.tolerance, eps);
    // (despike says whether it left a piece as it was: no segment shorter than the slack)
    let mut as_raw = uncrossed;
    let pieces: Vec<(Vec<Seg>, bool)> = pieces
        .into_iter()
        .enumerate()
        .map(|(k, (segs, closed))| {
            if long.get(k) == Some(&true) {
                debug_assert!(segs.iter().all(|s| !s.shorter_than(valid_eps)));
                return (segs, closed);
            }
            let (segs, untouched) = despike(segs, closed, valid_eps);
            as_raw &= untouched;
            (segs, closed)
        })
        .collect();
    finish_despiked(pieces, as_raw, opts, eps)
}

/// The rest of `finish_known` once the pieces are despiked; `as_raw`: they are whole raw
/// curves the prune found uncrossed, and despiking left them as they were.
fn finish_despiked(
    mut pieces: Vec<(Vec<Seg>, bool)>,
    as_raw: bool,
    opts: &OffsetOptions,
    eps: f64,
) -> Loops {
    // what the prune and the joins leave may still zig-zag by less than the bound where
    // nearly tangent offsets were cut and stitched: cut those lobes off here, so the result
    // is valid input as it stands (the same repair the input check makes); one convex
    // loop has none (despiking a convex loop keeps a subset of its vertices: still convex)
    let convex = matches!(pieces.as_slice(), [(segs, true)] if convex::is_convex_ccw(segs));
    if as_raw {
        // (debug builds make sure the repair would have found nothing)
        debug_assert!(
            !zigzag::remove(&mut pieces.clone(), eps, zigzag_bound(opts.tolerance, eps)),
            "the zig-zag repair found a crossing among raw curves the prune found uncrossed"
        );
    } else if !convex {
        zigzag::remove(&mut pieces, eps, zigzag_bound(opts.tolerance, eps));
    }
    let mut out = Vec::with_capacity(pieces.len());
    for (segs, closed) in pieces {
        if let Some(p) = build(segs, closed, eps) {
            out.push(p);
        }
    }
    Loops {
        loops: out,
        uncrossed: as_raw,
    }
}

/// Replaces the slivers the prune can leave where it cut and stitched (runs of segments
/// each shorter than `delta`, which may turn back on themselves by a few nanometres) so the
/// result is valid input again: a run shorter than `delta` in all is absorbed by a
/// neighbouring line (that line's end moves onto the run's far end), a longer one becomes
/// lines about `delta` long. No point moves by more than `delta`. True beside the result
/// when no segment was short (the segments as they came).
fn despike(mut segs: Vec<Seg>, closed: bool, delta: f64) -> (Vec<Seg>, bool) {
    let long = |s: &Seg| !s.shorter_than(delta);
    if segs.iter().all(long) {
        return (segs, true);
    }
    if closed && !long(&segs[0]) {
        // start at a long segment, so no run wraps round the seam; with none, resampled
        // (one pass finds out which: a dense loop at near collapse has 100,000 to read)
        match resample_loop(segs, delta) {
            Ok(resampled) => return (resampled, false),
            Err((back, k)) => {
                segs = back;
                segs.rotate_left(k);
            }
        }
    }
    let n = segs.len();
    let mut out: Vec<Seg> = Vec::with_capacity(n);
    let mut k = 0;
    while k < n {
        if segs[k].length() >= delta {
            out.push(segs[k]);
            k += 1;
            continue;
        }
        let mut e = k;
        while e < n && segs[e].length() < delta {
            e += 1;
        }
        let (p, q) = (segs[k].a, segs[e - 1].b);
        let total: f64 = segs[k..e].iter().map(|s| s.length()).sum();
        if total < delta {
            if let Some(last) = out.last_mut().filter(|l| !l.is_arc()) {
                *last = Seg::line(last.a, q);
            } else if e < n && !segs[e].is_arc() {
                segs[e] = Seg::line(p, segs[e].b);
            } else if e == n && closed && !out[0].is_arc() {
                out[0] = Seg::line(p, out[0].b);
            } else {
                out.push(Seg::line(p, q));
            }
        } else {
            let mut start = p;
            let mut acc = 0.0;
            for s in &segs[k..e] {
                acc += s.length();
                if acc >= delta {
                    out.push(Seg::line(start, s.b));
                    start = s.b;
                    acc = 0.0;
                }
            }
            if start != q {
                if let Some(last) = out.last_mut() {
                    *last = Seg::line(last.a, q);
                }
            }
        }
        k = e;
    }
    (out, false)
}

/// A closed loop all of whose segments are shorter than `delta` (a dense loop shrunk to
/// near collapse: 100,000 sides of 6e-8 mm): the same loop through every vertex at which
/// its length since the last one kept reaches `delta`, so its lines are about `delta` long
/// and no point moves by more than `delta`. A loop shorter than three times `delta` stays
/// as it is. Err(the loop as it came, k) when its segment k is not that short.
fn resample_loop(segs: Vec<Seg>, delta: f64) -> Result<Vec<Seg>, (Vec<Seg>, usize)> {
    let sides = segs.iter().map(|s| (s.length2(), s.length(), s.b));
    match resample_sides(segs[0].a, sides, delta) {
        Resampled::Lines(out) => Ok(out),
        Resampled::AsItIs => Ok(segs),
        Resampled::Long(k) => Err((segs, k)),
    }
}

/// `resample_loop` of the closed loop of lines through `verts` (side j from vertex j - 1
/// to vertex j, side 0 from the last), without its sides made first; None where that would
/// leave the loop as it is or refuse it (some side is not that short).
fn resample_vertices(verts: &[Point], delta: f64) -> Option<Vec<Seg>> {
    let first = *verts.last()?;
    let mut prev = first;
    let sides = verts.iter().map(|&v| {
        let d = v - prev;
        prev = v;
        let l2 = d.dot(d);
        (l2, l2.sqrt(), v)
    });
    match resample_sides(first, sides, delta) {
        Resampled::Lines(out) => Some(out),
        Resampled::AsItIs | Resampled::Long(_) => None,
    }
}

/// What `resample_sides` made of a loop.
enum Resampled {
    Lines(Vec<Seg>),
    /// shorter than three times `delta`: it stays as it is
    AsItIs,
    /// its side k is not shorter than `delta`
    Long(usize),
}

/// The resampling of `resample_loop`, from the loop's start and each side's squared
/// length, length and end, in order.
fn resample_sides(
    first: Point,
    sides: impl Iterator<Item = (f64, f64, Point)>,
    delta: f64,
) -> Resampled {
    let mut out: Vec<Seg> = Vec::new();
    let (mut start, mut acc, mut total) = (first, 0.0, 0.0);
    for (k, (l2, l, b)) in sides.enumerate() {
        // (`Seg::shorter_than`: a NaN is not short)
        let short = l2 < delta * delta;
        if !short {
            return Resampled::Long(k);
        }
        acc += l;
        total += l;
        if acc >= delta {
            out.push(Seg::line(start, b));
            start = b;
            acc = 0.0;
        }
    }
    if total < 3.0 * delta {
        return Resampled::AsItIs;
    }
    // close the loop: the last line ends at the first point, a stub is absorbed
    match out.last_mut() {
        Some(last) if acc < delta * 0.5 || start == first => *last = Seg::line(last.a, first),
        _ => out.push(Seg::line(start, first)),
    }
    out.retain(|s| s.a != s.b);
    Resampled::Lines(out)
}

/// A finished path with its signed area (0 when open), measured from its segments while
/// they are at hand.
struct Loop {
    poly: Polyline,
    area: f64,
    /// closed, its area at most `SLIVER_WIDTH` ε times its length (so on average that thin
    /// or thinner): the kind of loop the stitch closes where curves cross within a few ε,
    /// which `assemble` drops when it lies inside another region (see `nested_outers`)
    sliver: bool,
}

/// How thin on average (in ε) a loop may be and still count as a sliver ([`Loop::sliver`]);
/// the lens of `nested_outers` was about 1.4 ε (its area over its length), 4 ε across.
const SLIVER_WIDTH: f64 = 64.0;

/// The loops of one offset (or of one stage of it).
struct Loops {
    loops: Vec<Loop>,
    /// they are whole raw curves among which the prune found no crossing, none of them
    /// repaired (see `finish_known`): `assemble` then needs no test of which outer holds
    /// an island when there is one outer
    uncrossed: bool,
}

/// How many segments ahead `build` asks the cache for (a prefetch): at a million segments
/// its loads of each next one were more than half of its time, and its time a tenth of the
/// offset's; 16 ahead took 6 % off the million-vertex gear and nothing off the 10k one.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
const BUILD_AHEAD: usize = 16;

/// A polyline from stitched segments: zero-length pieces dropped, collinear lines and
/// co-circular arcs merged, loops with no area (a region offset to a line) dropped.
///
/// One pass: a segment's vertex, area and length are taken as soon as the next one does
/// not merge into it, while it is in the cache (at a million segments a second pass read
/// 80 MB again). Only where the loop's last segment merges into its first (a loop that
/// starts inside a line) are they taken again in a second pass.
fn build(mut out: Vec<Seg>, closed: bool, eps: f64) -> Option<Loop> {
    let tiny = eps * 1e-2;
    // the vertices, the length's upper bound |dx| + |dy| for lines (no root: the exact
    // length is summed only for a loop whose area comes near ε times that) and twice the
    // area about the first point (a stitched loop may end a few ε from where it starts: the
    // stitch matches ends within 16 ε, and its area is that of the loop closed there)
    let mut vs: Vec<Vertex> = Vec::with_capacity(out.len() + 1);
    let (mut len_bound, mut area2) = (0.0, 0.0);
    let mut o = Point::new(0.0, 0.0);
    let take = |s: &Seg, o: Point, vs: &mut Vec<Vertex>, len_bound: &mut f64, area2: &mut f64| {
        vs.push(Vertex::new(s.a.x, s.a.y, s.bulge()));
        *len_bound += if s.is_arc() {
            s.length()
        } else {
            (s.b.x - s.a.x).abs() + (s.b.y - s.a.y).abs()
        };
        *area2 += s.area2_about(o);
    };
    // merged in place: the kept segments move to the front
    let mut kept = 0;
    for i in 0..out.len() {
        #[cfg(target_arch = "x86_64")]
        if let Some(ahead) = out.get(i + BUILD_AHEAD) {
            // SAFETY: a prefetch reads nothing a fault could come from
            unsafe {
                std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                    (ahead as *const Seg).cast::<i8>(),
                );
            }
        }
        let s = out[i];
        if s.shorter_than(tiny) {
            continue;
        }
        if kept > 0 {
            if let Some(m) = merge(&out[kept - 1], &s, eps) {
                out[kept - 1] = m;
                continue;
            }
            // nothing more merges into the one before: it is final
            take(&out[kept - 1], o, &mut vs, &mut len_bound, &mut area2);
        } else {
            o = s.a;
        }
        if kept != i {
            out[kept] = s;
        }
        kept += 1;
    }
    out.truncate(kept);
    let closing_merges =
        closed && out.len() > 2 && merge(&out[out.len() - 1], &out[0], eps).is_some();
    if closing_merges {
        while out.len() > 2 {
            let (first, last) = (out[0], out[out.len() - 1]);
            match merge(&last, &first, eps) {
                Some(m) => {
                    out.pop();
                    out[0] = m;
                }
                None => break,
            }
        }
        // the first segment changed: everything again, about its new start
        vs.clear();
        (len_bound, area2) = (0.0, 0.0);
        o = out[0].a;
        for s in &out {
            take(s, o, &mut vs, &mut len_bound, &mut area2);
        }
    } else if let Some(last) = out.last() {
        take(last, o, &mut vs, &mut len_bound, &mut area2);
    } else if !closed {
        return None;
    }
    let area = if closed { area2 * 0.5 } else { 0.0 };
    let no_area = || area.abs() <= eps * out.iter().map(|s| s.length()).sum::<f64>();
    if closed && (out.len() < 2 || (area.abs() <= eps * len_bound && no_area())) {
        return None;
    }
    if !closed {
        let e = out[out.len() - 1].b;
        vs.push(Vertex::new(e.x, e.y, 0.0));
    }
    Some(Loop {
        poly: Polyline::new(vs, closed),
        area,
        sliver: closed && area.abs() <= SLIVER_WIDTH * eps * len_bound,
    })
}

/// `s1` followed by `s2` as one segment, when they lie on one line or one arc.
fn merge(s1: &Seg, s2: &Seg, eps: f64) -> Option<Seg> {
    if s1.is_arc() != s2.is_arc() {
        return None;
    }
    if !s1.is_arc() {
        let d = s2.b - s1.a;
        let l2 = d.dot(d);
        if l2 <= eps * eps {
            return None;
        }
        // the shared point must lie on the line from s1.a to s2.b (within 0.1 ε), between
        // them: squared, no root or division
        let (cr, along) = (d.cross(s1.b - s1.a), (s1.b - s1.a).dot(d));
        let tol = eps * 0.1;
        if cr * cr <= tol * tol * l2 && along > 0.0 && along < l2 {
            return Some(Seg::line(s1.a, s2.b));
        }
        return None;
    }
    if s1.c.dist(s2.c) <= eps * 0.1
        && (s1.r - s2.r).abs() <= eps * 0.1
        && s1.sw * s2.sw > 0.0
        && (s1.sw + s2.sw).abs() <= 1.5 * std::f64::consts::PI
    {
        return Some(Seg {
            a: s1.a,
            b: s2.b,
            c: s1.c,
            r: s1.r,
            sw: s1.sw + s2.sw,
        });
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_survey_finds_the_lengths_and_turns_the_stage_schedule_would() {
        use std::f64::consts::TAU;
        // a star of lines, and a circle of two arcs
        let star: Vec<Point> = (0..10)
            .map(|i| {
                let a = i as f64 * TAU / 10.0;
                let r = if i % 2 == 0 { 10.0 } else { 4.0 };
                Point::new(r * a.cos(), r * a.sin())
            })
            .collect();
        for pl in [
            Polyline::from_points(&star, true),
            Polyline::circle(Point::new(1.0, 2.0), 3.0),
        ] {
            let (segs, survey) = clean_surveyed(&pl, 1e-9);
            let bits = |e: &raw::Ends| [e.length, e.away, e.toward].map(f64::to_bits);
            for side in [1.0, -2.5] {
                let turning = survey.turning.expect("neither is a convex loop of lines");
                let (a, b) = (turning.ends(side), raw::ends_of(&segs, side));
                assert_eq!(bits(&a), bits(&b), "side {side}");
            }
            // what turns away from one side turns towards the other
            let (l, r) = (raw::ends_of(&segs, 1.0), raw::ends_of(&segs, -1.0));
            assert_eq!((l.away, l.toward), (r.toward, r.away));
        }
        // a convex loop of lines shrinks without the stage schedule: no sums for it
        let square =
            [(0.0, 0.0), (4.0, 0.0), (4.0, 3.0), (0.0, 3.0)].map(|(x, y)| Point::new(x, y));
        let (_, survey) = clean_surveyed(&Polyline::from_points(&square, true), 1e-9);
        assert!(survey.convex_ccw && survey.turning.is_none());
        // the star turns both ways: five sharp corners left (past a right angle), five
        // right; the circle turns left only, once round
        let (segs, _) = clean_surveyed(&Polyline::from_points(&star, true), 1e-9);
        let e = raw::ends_of(&segs, 1.0);
        assert!(
            e.away > 0.5 && e.toward > e.away + 5.0,
            "{} away, {} toward",
            e.away,
            e.toward
        );
        let (segs, _) = clean_surveyed(&Polyline::circle(Point::new(0.0, 0.0), 1.0), 1e-9);
        let e = raw::ends_of(&segs, 1.0);
        assert_eq!(e.away, 0.0);
        assert!((e.toward - TAU).abs() <= 1e-12 && (e.length - TAU).abs() <= 1e-12);
    }

    #[test]
    fn a_loop_resampled_from_its_vertices_is_the_loop_resampled_from_its_sides() {
        // loops round a tiny circle whose sides are mostly shorter than delta, some not
        let mut rand = crate::test_rng::uniform(25);
        let mut resampled = 0;
        for round in 0..400 {
            let n = 3 + (rand() * 300.0) as usize;
            let r = 1e-8 * (1.0 + 200.0 * rand());
            let verts: Vec<Point> = (0..n)
                .map(|i| {
                    let a = (i as f64 + 0.3 * rand()) / n as f64 * std::f64::consts::TAU;
                    Point::new(3.0 + r * a.cos(), -2.0 + r * a.sin())
                })
                .collect();
            let delta = if round % 5 == 0 { 1e-9 } else { 1e-7 };
            let mut sides = Vec::with_capacity(n);
            let mut prev = verts[n - 1];
            for &v in &verts {
                sides.push(Seg::line(prev, v));
                prev = v;
            }
            let from_sides = match resample_loop(sides.clone(), delta) {
                Ok(out) if out != sides => Some(out),
                _ => None,
            };
            let from_vertices = resample_vertices(&verts, delta);
            assert_eq!(
                from_vertices, from_sides,
                "round {round}: {n} vertices, r {r}"
            );
            resampled += usize::from(from_vertices.is_some());
        }
        assert!(resampled > 100, "only {resampled} loops resampled");
    }

    #[test]
    fn cleaning_keeps_an_arc_that_starts_within_eps_of_the_vertex_before_it() {
        // what `zigzag::remove` left of a shrink by 0.2 (grown_blob_386_…): a line, a
        // 0.4 nm line, then a concave arc of radius 0.2035 and sweep 0.639 rad (sagitta
        // 0.0103 mm); the 0.4 nm line goes, the arc after it must stay an arc
        let eps = 1e-7;
        let arc = Seg::arc(
            Point::new(-21.572587720103957, -7.444997710648487),
            0.20345217907695698,
            Point::new(-21.419196973490408, -7.3113411806004),
            Point::new(-21.36974897259746, -7.429210637419051),
            -0.6390830870277823,
        );
        let v = |p: Point, bulge: f64| Vertex::new(p.x, p.y, bulge);
        let pl = Polyline::new(
            vec![
                v(Point::new(-21.87098600542156, -5.954168590876454), 0.0),
                v(Point::new(-21.41919697374588, -7.31134118030719), 0.0),
                v(arc.a, arc.bulge()),
                v(arc.b, 0.0),
            ],
            false,
        );
        let segs = clean(&pl, eps);
        assert_eq!(segs.len(), 2, "the 0.4 nm line goes: {segs:?}");
        let kept = segs[1];
        assert!(kept.is_arc(), "the arc became its chord: {kept:?}");
        assert!((kept.sw - arc.sw).abs() < 1e-6, "{kept:?}");
        // every point of the arc given lies within eps of what is kept
        for i in 0..=100 {
            let q = arc.point_at(i as f64 / 100.0);
            assert!(
                kept.dist(q) <= eps,
                "({}, {}) is {} off",
                q.x,
                q.y,
                kept.dist(q)
            );
        }
    }

    #[test]
    fn the_filtered_winding_numbers_are_the_polylines() {
        // random loops of lines and bulges (some crossing themselves), points scattered
        // over and around them, some at vertex heights exactly (the crossing rule's edge)
        let mut rnd = crate::test_rng::uniform(987654321);
        for n in [1usize, 2, 3, 7, 40, 300] {
            for _ in 0..20 {
                let vs: Vec<Vertex> = (0..n)
                    .map(|_| {
                        let bulge = if rnd() < 0.5 { 0.0 } else { rnd() * 4.0 - 2.0 };
                        Vertex::new(rnd() * 20.0 - 10.0, rnd() * 20.0 - 10.0, bulge)
                    })
                    .collect();
                let mut ps: Vec<Point> = (0..200)
                    .map(|_| Point::new(rnd() * 30.0 - 15.0, rnd() * 30.0 - 15.0))
                    .collect();
                ps.extend(vs.iter().map(|v| Point::new(rnd() * 30.0 - 15.0, v.y)));
                for closed in [true, false] {
                    let pl = Polyline::new(vs.clone(), closed);
                    assert_eq!(winding_numbers(&pl, &ps), pl.winding_numbers(&ps), "{pl:?}");
                }
            }
        }
    }

    #[test]
    fn cleaning_a_closed_path_keeps_the_arc_after_a_vertex_within_eps() {
        // a half disc whose arc starts 1e-9 after the diameter's end, as a closed path
        let eps = 1e-7;
        let pl = Polyline::new(
            vec![
                Vertex::new(-1.0, 0.0, 0.0),
                Vertex::new(1.0, 0.0, 0.0),
                Vertex::new(1.0 + 1e-9, 0.0, 1.0),
            ],
            true,
        );
        let segs = clean(&pl, eps);
        assert_eq!(segs.len(), 2, "{segs:?}");
        let area: f64 = segs.iter().map(|s| s.area2()).sum::<f64>() * 0.5;
        assert!(
            (area - std::f64::consts::FRAC_PI_2).abs() < 1e-6,
            "the half disc's area is {area}"
        );
    }

    #[test]
    fn a_stitched_sliver_that_ends_a_few_eps_from_its_start_has_no_area() {
        // what the prune left of a grow by 1.084 (grown_blob_327_…): a closed chain of two
        // lines 10 µm long in all, nearly collinear, ending 3.3 µm from its start (within
        // the stitch's 16 ε). About the origin, 21 mm away, its area came out 3.5e-5, far
        // above ε × its length, so it was kept as an island crossing the loop beside it
        let eps = 1e-6;
        let segs = vec![
            Seg::line(
                Point::new(-20.58760941313336, -4.594124690639476),
                Point::new(-20.587608681580587, -4.5941279353858056),
            ),
            Seg::line(
                Point::new(-20.58760868158291, -4.594127935375481),
                Point::new(-20.587610144362692, -4.594121445817104),
            ),
        ];
        assert!(
            build(segs, true, eps).is_none(),
            "the sliver was kept as a loop"
        );
    }

    #[test]
    fn a_loop_that_ends_a_few_eps_from_its_start_has_its_area_wherever_it_lies() {
        // a unit square whose last side stops 3 ε short of its start, far from the origin
        let eps = 1e-6;
        for c in [Point::new(0.0, 0.0), Point::new(-2000.0, 3000.0)] {
            let p = |x: f64, y: f64| c + Point::new(x, y);
            let segs = vec![
                Seg::line(p(0.0, 0.0), p(1.0, 0.0)),
                Seg::line(p(1.0, 0.0), p(1.0, 1.0)),
                Seg::line(p(1.0, 1.0), p(0.0, 1.0)),
                Seg::line(p(0.0, 1.0), p(0.0, 3.0 * eps)),
            ];
            let l = build(segs, true, eps).expect("the square is a loop");
            assert!((l.area - 1.0).abs() < 1e-9, "about {c:?}: area {}", l.area);
        }
    }

    #[test]
    fn a_sliver_inside_another_region_goes_and_one_in_a_hole_stays() {
        // a 100 mm square with a 40 mm hole; small squares (counter-clockwise: outers) in
        // its solid part, in its hole and beside it, of 1 mm, and slivers of 1e-3 by 1e-9
        let eps = 1e-6;
        let square = |x: f64, y: f64, w: f64, h: f64| {
            Polyline::rect(Point::new(x, y), Point::new(x + w, y + h))
        };
        let as_loop = |p: Polyline| Loop {
            area: p.area(),
            sliver: p.area().abs() <= SLIVER_WIDTH * eps * p.length(),
            poly: p,
        };
        for (w, h, kept) in [(1.0, 1.0, true), (1e-3, 1e-9, false)] {
            let loops = vec![
                as_loop(square(0.0, 0.0, 100.0, 100.0)),
                as_loop(square(30.0, 30.0, 40.0, 40.0).reversed()),
                as_loop(square(10.0, 10.0, w, h)),
                as_loop(square(50.0, 50.0, w, h)),
                as_loop(square(150.0, 50.0, w, h)),
            ];
            assert_eq!(loops[2].sliver, !kept);
            let regions = assemble(Loops {
                loops,
                uncrossed: false,
            });
            let starts: Vec<Point> = regions.iter().map(|r| r.outer.vertices[0].pos()).collect();
            // (a region of its own inside another is no offset's result: only slivers go)
            let mut want = vec![Point::new(0.0, 0.0)];
            if kept {
                want.push(Point::new(10.0, 10.0));
            }
            want.extend([Point::new(50.0, 50.0), Point::new(150.0, 50.0)]);
            assert_eq!(starts, want, "{w} by {h}");
            assert_eq!(regions[0].islands.len(), 1);
        }
    }
}
