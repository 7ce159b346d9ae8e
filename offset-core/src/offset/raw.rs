//! The raw offset of one path: every segment moved sideways (lines stay lines, arcs stay
//! concentric arcs, collapsed arcs become a throw-away chord), neighbours that interfere
//! trimmed to their intersection (the pair-wise interference step, which removes the
//! local invalid loops before the curve exists), and round joins at convex corners.

use super::index::{grow, BBox};
use super::seg::{angle, intersect, wrap, Norm, Seg};
use super::swallowtail;
use crate::geom::Point;
use std::f64::consts::PI;

/// What a raw segment is the offset of.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Origin {
    /// the offset of an input segment (or a part of it): every point lies |o| from the
    /// input, and just across it, on the input's side, nearer
    Offset,
    /// the round join about a convex input vertex: every point lies |o| from the vertex,
    /// and inside it nearer
    Join,
    /// a connector that is not the offset of anything: the arc about a concave corner
    /// whose neighbours do not meet (it runs backwards), a line between nearly collinear
    /// neighbours, the chord of an arc that collapsed. Points across it may lie farther
    /// than |o| from the input.
    Bridge,
}

/// A segment of a raw offset curve.
#[derive(Clone, Copy, Debug)]
pub struct RawSeg {
    pub seg: Seg,
    pub origin: Origin,
}

/// A turn smaller than this (radians) is taken as none, one within this of a half turn as
/// a reversal.
const TURN_EPS: f64 = 1e-12;

/// [`raw_path`]'s segments, each beside its origin (for the tests).
#[cfg(test)]
pub fn raw_offset(segs: &[Seg], closed: bool, o: f64, eps: f64) -> Vec<RawSeg> {
    let RawPath { segs, origins, .. } = raw_path(segs, closed, o, eps, o.abs() * (1.0 - 1e-9));
    segs.into_iter()
        .zip(origins)
        .map(|(seg, origin)| RawSeg { seg, origin })
        .collect()
}

/// What the stage schedule reads of a path's segments (`stages::first_stage`): the path's
/// length, and how much it turns away from and towards the side `side` (> 0: left) at its
/// corners and along its arcs, closed (each corner's turn taken as the sine of the turn
/// between unit tangents, π less it past a right angle, so no trigonometry; one root per
/// line for its length and its tangent). One pass over the segments, writing nothing (the
/// raw offset finds the tangents again where it needs them, see `Tangents`), or the same
/// sums made by the pass that makes the segments (see `Turning`).
pub struct Ends {
    pub length: f64,
    pub away: f64,
    pub toward: f64,
}

pub fn ends_of(segs: &[Seg], side: f64) -> Ends {
    let mut turning = Turning::default();
    for s in segs {
        turning.add(s);
    }
    turning.ends(side)
}

/// [`ends_of`] summed one segment at a time, in the path's order, for either side at once:
/// the pass that makes the offset's input segments feeds it (`offset::Surveying`), so no
/// pass of its own reads them again. That pass ran at a million segments in 33 ms, nine
/// times a plain read of them: each segment's root and division filled the core's window
/// with one segment's loads in flight at a time.
#[derive(Clone, Copy, Debug, Default)]
pub struct Turning {
    length: f64,
    /// (away, toward) when the side is the left (> 0), and when it is the right
    left: (f64, f64),
    right: (f64, f64),
    first: Option<Point>,
    last: Option<Point>,
}

impl Turning {
    /// A turn of `t` that is `signed` (its sign the turn's sense, > 0 to the left): away
    /// from the left side when negative, from the right when positive (a zero or NaN sense
    /// counts towards both, as `cr * side < 0.0` found).
    #[inline(always)]
    fn turn(&mut self, t: f64, signed: f64) {
        if signed < 0.0 {
            self.left.0 += t;
            self.right.1 += t;
        } else if signed > 0.0 {
            self.left.1 += t;
            self.right.0 += t;
        } else {
            self.left.1 += t;
            self.right.1 += t;
        }
    }

    /// A corner's turn between unit tangents, without trigonometry.
    #[inline(always)]
    fn corner(&mut self, t_in: Point, t_out: Point) {
        let (cr, dt) = (t_in.cross(t_out), t_in.dot(t_out));
        let t = if dt >= 0.0 { cr.abs() } else { PI - cr.abs() };
        self.turn(t, cr);
    }

    /// The next segment of the path.
    #[inline(always)]
    pub fn add(&mut self, s: &Seg) {
        let (ends, l) = tangents_and_length(s);
        self.length += l;
        if s.is_arc() {
            self.turn(s.sw.abs(), s.sw);
        }
        if let Some(t_in) = self.last {
            self.corner(t_in, ends.0);
        }
        self.first.get_or_insert(ends.0);
        self.last = Some(ends.1);
    }

    /// The sums of the closed path added, to the side `side` (> 0: left).
    pub fn ends(mut self, side: f64) -> Ends {
        // the corner that closes the loop
        if let (Some(t_out), Some(t_in)) = (self.first, self.last) {
            self.corner(t_in, t_out);
        }
        let (away, toward) = if side > 0.0 { self.left } else { self.right };
        Ends {
            length: self.length,
            away,
            toward,
        }
    }
}

/// One raw offset curve: its segments and, beside them, what each is the offset of (kept
/// apart, so a curve the prune keeps whole becomes the result's segments as they lie, not
/// copied), with every segment's box grown by ε (what the prune's search for crossings
/// asks).
pub struct RawPath {
    pub segs: Vec<Seg>,
    pub origins: Vec<Origin>,
    pub boxes: Vec<BBox>,
    pub closed: bool,
    /// the longest segment (the first of the longest) and the shortest one's squared
    /// length, found while boxing; None when not known (some segment was dropped, or one's
    /// length is not a positive number)
    pub extremes: Option<Extremes>,
}

/// See [`RawPath::extremes`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Extremes {
    pub longest: usize,
    pub shortest2: f64,
}

/// Offsets one cleaned path's segments by `o` to the left of travel (negative: right).
/// `closed` joins the last segment to the first. `eps` is the geometric tolerance.
///
/// Corners between two lines that turn towards the offset side are resolved with a stack
/// (the pair-wise interference step of Choi & Park 1999): each new offset line meets the
/// last one kept, and a kept line whose meeting point falls before its own start is
/// dominated by its neighbours (the whole of it lies nearer the input than |o|) and is
/// popped. Over a stretch that turns one way by less than π this is the intersection of the
/// offset half-planes, i.e. the exact local offset, so the local invalid loops of a curve
/// whose curvature radius falls below |o| never reach the global stage. Anything else
/// (arcs, turns the other way, a stretch turning more than `MAX_RUN_TURN`) is joined the
/// old pair-wise way; where that leaves a swallowtail (neighbours that do not meet at a
/// corner towards the offset side), it is taken apart as far as each piece that goes is
/// proven nearer the input than `sure` (see `swallowtail`; `sure` ≤ 0: never), and the
/// rest is left to the global stage.
///
/// The boxes are made as soon as each segment is final, while it is still in the cache (at
/// a million segments a pass of its own over the raw offset read 100 MB again).
pub fn raw_path(segs: &[Seg], closed: bool, o: f64, eps: f64, sure: f64) -> RawPath {
    let mut boxing = Boxing::new(eps, 2 * segs.len());
    let Out {
        segs: mut out,
        mut origins,
    } = unfinished(segs, closed, o, eps, sure, &mut boxing);
    let Boxing {
        mut boxes,
        short,
        extremes,
        ..
    } = boxing;
    if short {
        // (rare) the segments shorter than ε / 1000 go, with their boxes
        let short2 = short_length2(eps);
        let mut kept = 0;
        for i in 0..out.len() {
            if out[i].length2() <= short2 {
                continue;
            }
            out[kept] = out[i];
            origins[kept] = origins[i];
            boxes[kept] = boxes[i];
            kept += 1;
        }
        out.truncate(kept);
        origins.truncate(kept);
        boxes.truncate(kept);
    }
    let extremes = match extremes {
        Some((longest, _, shortest2)) if !short && shortest2 > 0.0 && !out.is_empty() => {
            Some(Extremes { longest, shortest2 })
        }
        _ => None,
    };
    RawPath {
        segs: out,
        origins,
        boxes,
        closed,
        extremes,
    }
}

/// The last segments of a raw offset in the making that stay unboxed: the next corner may
/// still trim the last, and a swallowtail pop the ones before (see `swallowtail`).
const UNBOXED: usize = 16;

/// A raw segment no longer than the root of this goes (ε / 1000).
fn short_length2(eps: f64) -> f64 {
    (eps * 1e-3) * (eps * 1e-3)
}

/// The boxes of a raw offset in the making, grown by ε. While it is made, its first
/// segment (the closing corner trims it) and its last (the next corner trims or pops it)
/// may still change, and every segment between is final: `catch_up` boxes those; `finish`
/// the rest. `short`: some segment is shorter than ε / 1000. `extremes`: the longest
/// segment so far (index, squared length; the first of equals in the path's order) and the
/// shortest squared length, or None once a length is not a number.
struct Boxing {
    /// the first one's box is a placeholder until `finish`
    boxes: Vec<BBox>,
    short: bool,
    extremes: Option<(usize, f64, f64)>,
    eps: f64,
    short2: f64,
}

impl Boxing {
    /// `room`: the most segments expected.
    fn new(eps: f64, room: usize) -> Boxing {
        let mut boxes = Vec::with_capacity(room.max(1));
        boxes.push([0.0; 4]);
        Boxing {
            boxes,
            short: false,
            extremes: Some((0, 0.0, f64::INFINITY)),
            eps,
            short2: short_length2(eps),
        }
    }

    /// Measures segment `k` (`first`: the path's first, measured last, which wins a tie).
    #[inline]
    fn measure(&mut self, k: usize, s: &Seg, first: bool) {
        let l2 = s.length2();
        self.short |= l2 <= self.short2;
        if let Some((longest, max2, min2)) = &mut self.extremes {
            if l2.is_nan() {
                self.extremes = None;
                return;
            }
            if l2 > *max2 || (first && l2 == *max2) {
                (*longest, *max2) = (k, l2);
            }
            *min2 = min2.min(l2);
        }
    }

    fn add(&mut self, s: &Seg) {
        self.measure(self.boxes.len(), s, false);
        self.boxes.push(grow(s.bbox(), self.eps));
    }

    /// Forgets the boxes from segment `k` on (a swallowtail popped or cut them), and with
    /// them what was measured: the longest and shortest are no longer known.
    fn forget_from(&mut self, k: usize) {
        if k < self.boxes.len() {
            self.boxes.truncate(k.max(1));
            self.extremes = None;
        }
    }

    /// Boxes every segment of `out` but its first and its last not yet boxed.
    #[inline]
    fn catch_up(&mut self, out: &[Seg]) {
        for s in out
            .iter()
            .take(out.len().saturating_sub(UNBOXED))
            .skip(self.boxes.len())
        {
            self.add(s);
        }
    }

    /// Boxes the segments left, the first included.
    fn finish(&mut self, out: &[Seg]) {
        for s in out.iter().skip(self.boxes.len()) {
            self.add(s);
        }
        if let Some(first) = out.first() {
            self.measure(0, first, true);
            self.boxes[0] = grow(first.bbox(), self.eps);
        }
        self.boxes.truncate(out.len());
    }
}

/// A raw offset in the making: its segments, and beside them what each is the offset of.
struct Out {
    segs: Vec<Seg>,
    origins: Vec<Origin>,
}

impl Out {
    fn with_capacity(n: usize) -> Out {
        Out {
            segs: Vec::with_capacity(n),
            origins: Vec::with_capacity(n),
        }
    }

    fn push(&mut self, r: RawSeg) {
        self.segs.push(r.seg);
        self.origins.push(r.origin);
    }

    fn pop(&mut self) -> Option<RawSeg> {
        let seg = self.segs.pop()?;
        let origin = self.origins.pop()?;
        Some(RawSeg { seg, origin })
    }

    fn get(&self, k: usize) -> RawSeg {
        RawSeg {
            seg: self.segs[k],
            origin: self.origins[k],
        }
    }
}

/// The raw offset before segments shorter than ε / 1000 are dropped, boxed by `boxing` as
/// it is made.
fn unfinished(segs: &[Seg], closed: bool, o: f64, eps: f64, sure: f64, boxing: &mut Boxing) -> Out {
    let m = segs.len();
    if m == 0 {
        boxing.finish(&[]);
        return Out::with_capacity(0);
    }
    let corners = if closed { m } else { m - 1 };
    let ring = Ring { m };
    let tangents = Tangents { segs, ring };
    // (each corner's tangents are found once a step and handed to what asks them: a root
    // and a division per line each time, and four askers, were a tenth of a gear's offset)
    let stackable = |k: usize, (t1, t2): (Point, Point)| -> bool {
        let (cr, dt) = (t1.cross(t2), t1.dot(t2));
        // two lines turning towards the offset side, neither straight on nor reversing
        !segs[k].is_arc()
            && !segs[ring.next(k)].is_arc()
            && cr * o > 0.0
            && (cr.abs() > 1e-9 || dt < 0.0)
            && !(dt < 0.0 && cr.abs() < 1e-9)
    };
    // whether the line after corner k has turned less than MAX_RUN_TURN from `first`, the
    // run's first line (the run turns one way, checked at every corner, so it cannot wrap)
    let within_cap = |first: Point, (_, t): (Point, Point)| -> bool {
        first.cross(t) * o >= 0.0 && first.dot(t) > MAX_RUN_TURN.cos()
    };
    // a closed path starts after a corner the stack does not handle, so no run wraps
    let s0 = if closed {
        (0..m)
            .find(|&k| !stackable(k, tangents.corner(k)))
            .map_or(0, |k| ring.next(k))
    } else {
        0
    };
    let mut out = Out::with_capacity(2 * m);
    out.push(offset_raw(&segs[s0], tangents.at(s0).0, o));
    // the stack's scratch, one for every run of this path, and the tangents out of the
    // run's corners as its search found them
    let mut stack: Vec<(Seg, Seg, f64)> = Vec::new();
    let mut run_outs: Vec<Point> = Vec::new();
    let mut step = 0;
    // corners before this one are joined the pair-wise way (a run the stack could not resolve)
    let mut pairwise_until = 0;
    while step < corners {
        boxing.catch_up(&out.segs);
        let k = ring.at(s0, step);
        let closing = closed && step == m - 1;
        let at_k = tangents.corner(k);
        if !closing && step >= pairwise_until && stackable(k, at_k) {
            // the longest run of stackable corners from here, turning less than the cap
            let first = at_k.0;
            let mut end = step;
            let mut at_e = at_k;
            run_outs.clear();
            while end < corners && !(closed && end == m - 1) {
                let ke = ring.at(s0, end);
                if end > step {
                    // segment ke is a line (the corner before is stackable): its tangent
                    // at its end is the one out of that corner
                    at_e = (at_e.1, tangents.at(ring.next(ke)).0);
                }
                if !(stackable(ke, at_e) && within_cap(first, at_e)) {
                    break;
                }
                run_outs.push(at_e.1);
                end += 1;
            }
            if end > step {
                let floor = out
                    .pop()
                    .map(|r| r.seg)
                    .unwrap_or_else(|| offset_seg(&segs[k], tangents.at(k).0, o));
                let run = Run {
                    s0,
                    from: step,
                    t_in: at_k.0,
                    outs: &run_outs,
                };
                if stack_run(segs, ring, run, floor, o, eps, &mut stack) {
                    for (seg, _, _) in stack.drain(..) {
                        out.push(RawSeg {
                            seg,
                            origin: Origin::Offset,
                        });
                    }
                    step = end;
                    continue;
                }
                out.push(RawSeg {
                    seg: floor,
                    origin: Origin::Offset,
                });
                pairwise_until = end;
            }
        }
        // the old pair-wise way for this one corner
        let k2 = ring.next(k);
        let next_raw = if closing {
            out.get(0)
        } else {
            // (the tangent out of corner k is segment k2's at its start)
            offset_raw(&segs[k2], at_k.1, o)
        };
        let mut next = next_raw.seg;
        let last = out.segs.len() - 1;
        let mut prev = out.segs[last];
        let join = pair_corner(&segs[k], &segs[k2], at_k, &mut prev, &mut next, o, eps);
        // neighbours that do not meet at a corner to the offset side: the swallowtail
        // taken apart here where every piece of it is proven too near
        let folds = join.is_some_and(|j| j.origin == Origin::Bridge && j.seg.is_arc());
        if folds && !closing && sure > 0.0 {
            // the offsets after the corner, as far as the path (a closed one up to its
            // first segment, which the closing corner trims) goes
            let ahead = |b: usize| -> Option<(Seg, Seg)> {
                if step + 1 + b >= m {
                    return None;
                }
                let kb = ring.at(s0, step + 1 + b);
                let t = if b == 0 { at_k.1 } else { tangents.at(kb).0 };
                Some((offset_seg(&segs[kb], t, o), segs[kb]))
            };
            let cut = swallowtail::resolve(&out.segs, &out.origins, ahead, o, eps, sure);
            // the offset the cut starts must meet the one after it at its own corner: cut
            // past that meeting, what is left of it is a sliver beside its successor (a
            // stretch nearly straight on), which neither the next corner nor the global
            // stage takes apart; then the swallowtail goes to the global stage whole
            let cut = cut.filter(|cut| {
                let end = step + 1 + cut.skipped;
                end >= corners
                    || meets_after(segs, ring, tangents, s0, end, &cut.after, &out, o, eps)
            });
            if let Some(cut) = cut {
                let keep = out.segs.len() - cut.popped;
                // the boxes of what changed go too (made again as the rest are)
                boxing.forget_from(keep - 1);
                out.segs.truncate(keep);
                out.origins.truncate(keep);
                let top = out.segs[keep - 1];
                out.segs[keep - 1] = top.sub(0.0, top.a, cut.t, cut.at);
                let kb = ring.at(s0, step + 1 + cut.skipped);
                out.push(RawSeg {
                    seg: cut.after,
                    origin: moved_origin(&segs[kb], &cut.after),
                });
                step += 1 + cut.skipped;
                continue;
            }
        }
        out.segs[last] = prev;
        if let Some(j) = join {
            out.push(j);
        }
        if closing {
            out.segs[0] = next;
        } else {
            out.push(RawSeg {
                seg: next,
                origin: next_raw.origin,
            });
        }
        step += 1;
    }
    boxing.finish(&out.segs);
    out
}

/// Whether `kept`, what a swallowtail's cut keeps of the offset of segment `end` after
/// `s0`, meets the offset after it at its own corner, as `pair_corner` would find (the
/// closing corner's: `out`'s first). Out of line: asked once a swallowtail, it stays out
/// of the loop over the corners.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn meets_after(
    segs: &[Seg],
    ring: Ring,
    tangents: Tangents,
    s0: usize,
    end: usize,
    kept: &Seg,
    out: &Out,
    o: f64,
    eps: f64,
) -> bool {
    let m = segs.len();
    let kb = ring.at(s0, end);
    let mut kept = *kept;
    let kb2 = ring.next(kb);
    let at_kb = tangents.corner(kb);
    let mut after = if end == m - 1 {
        out.segs[0]
    } else {
        offset_seg(&segs[kb2], at_kb.1, o)
    };
    let join = pair_corner(&segs[kb], &segs[kb2], at_kb, &mut kept, &mut after, o, eps);
    !join.is_some_and(|j| j.origin == Origin::Bridge && j.seg.is_arc())
}

/// Segment indices round a path of `m` segments (a closed path's last is followed by its
/// first), by a comparison: no division in the loops over the corners.
#[derive(Clone, Copy)]
struct Ring {
    m: usize,
}

impl Ring {
    /// The segment after `k`.
    fn next(self, k: usize) -> usize {
        if k + 1 == self.m {
            0
        } else {
            k + 1
        }
    }

    /// The segment `step` after `s0` (both below `m`).
    fn at(self, s0: usize, step: usize) -> usize {
        let k = s0 + step;
        if k >= self.m {
            k - self.m
        } else {
            k
        }
    }
}

/// The unit tangents of a path's segments at their ends, computed where they are asked
/// (a root per line: cheaper than an array of them made in a pass of its own, written and
/// read again, 32 MB at a million segments).
#[derive(Clone, Copy)]
struct Tangents<'a> {
    segs: &'a [Seg],
    ring: Ring,
}

impl Tangents<'_> {
    /// The unit tangents of segment `k` at its start and its end.
    #[inline]
    fn at(self, k: usize) -> (Point, Point) {
        tangents_and_length(&self.segs[k]).0
    }

    /// The unit tangents into and out of corner `k`, the end of segment `k`.
    #[inline]
    fn corner(self, k: usize) -> (Point, Point) {
        (self.at(k).1, self.at(self.ring.next(k)).0)
    }
}

/// A segment's unit tangents at its start and its end (`Seg::tangent_at` at 0 and 1; a
/// zero-length line's are zero), and its length: a line's share the root.
#[inline]
fn tangents_and_length(s: &Seg) -> ((Point, Point), f64) {
    if s.is_arc() {
        ((s.tangent_at(0.0), s.tangent_at(1.0)), s.length())
    } else {
        let d = s.b - s.a;
        let l = d.len();
        let t = if l > 0.0 {
            d * (1.0 / l)
        } else {
            Point::default()
        };
        ((t, t), l)
    }
}

/// A run of corners for the stack: the corners `from..from + outs.len()`, counted from
/// segment `s0`, with the unit tangent into the first and the one out of each (as the
/// run's search found them: a root a line, not three).
#[derive(Clone, Copy)]
struct Run<'a> {
    s0: usize,
    from: usize,
    t_in: Point,
    outs: &'a [Point],
}

/// The stack over the corners of `run`, starting with `floor`, the offset of the segment
/// before the run's first corner as it stands. Leaves in `stack` (the
/// caller's scratch, kept from run to run: cleared here) the kept lines, each beside the
/// whole offset segment it is part of and that segment's length, the first being `floor`
/// trimmed; false when the run does not resolve into lines each kept within its own offset
/// segment (then the corners are joined the pair-wise way).
fn stack_run(
    segs: &[Seg],
    ring: Ring,
    run: Run,
    floor: Seg,
    o: f64,
    eps: f64,
    stack: &mut Vec<(Seg, Seg, f64)>,
) -> bool {
    stack.clear();
    let k0 = ring.at(run.s0, run.from);
    // the run is of lines: a line's tangent at its end is the one at its start, so the
    // tangent into each corner is the one out of the corner before
    let mut t_in = run.t_in;
    let first = offset_seg(&segs[k0], t_in, o);
    stack.push((floor, first, first.length()));
    for (step, &t_out) in (run.from..).zip(run.outs) {
        let k = ring.at(run.s0, step);
        let k2 = ring.next(k);
        let whole = offset_seg(&segs[k2], t_out, o);
        let mut next = whole;
        let mut adjacent = true;
        loop {
            let (top, top_whole, top_length) = stack[stack.len() - 1];
            let x = if adjacent {
                miter_point(segs[k].b, (t_in, t_out), o)
            } else {
                match line_meet(&top_whole, &whole) {
                    Some(x) => x,
                    None => return false,
                }
            };
            // how far past the kept line's start, along its own direction
            let ahead = (x - top.a).dot(top_whole.b - top_whole.a) / top_length;
            if ahead > eps * 1e-3 {
                let last = stack.len() - 1;
                stack[last].0 = Seg::line(top.a, x);
                next = Seg::line(x, next.b);
                break;
            }
            if stack.len() == 1 {
                return false;
            }
            // dominated by its neighbours: every point of it lies too near the input
            stack.pop();
            adjacent = false;
        }
        stack.push((next, whole, whole.length()));
        t_in = t_out;
    }
    // every kept line must lie, in its own direction, within its own offset segment
    let n = stack.len();
    stack.iter().enumerate().all(|(i, (kept, whole, length))| {
        let e = eps / length.max(eps);
        let (ta, tb) = (whole.param(kept.a), whole.param(kept.b));
        let start_ok = i == 0 || ta >= -e;
        let end_ok = i == n - 1 || tb <= 1.0 + e;
        start_ok && end_ok && tb > ta
    })
}

/// How far one stack run may turn: the stack is exact for a stretch turning one way by
/// less than π; a margin keeps the meeting points well conditioned.
const MAX_RUN_TURN: f64 = 0.9 * PI;

/// Where the offsets by `o` of two lines meeting at `v` with unit tangents `t1`, `t2`
/// meet: on the corner's bisector. Computed from the corner, it stays exact for nearly
/// parallel neighbours, where intersecting the two offset lines would not.
fn miter_point(v: Point, (t1, t2): (Point, Point), o: f64) -> Point {
    let (n1, n2) = (t1.perp(), t2.perp());
    v + (n1 + n2) * (o / (1.0 + n1.dot(n2)))
}

/// Where the lines through `top` and `next` meet.
/// None when they are parallel.
fn line_meet(top: &Seg, next: &Seg) -> Option<Point> {
    let d1 = top.b - top.a;
    let d2 = next.b - next.a;
    let den = d1.cross(d2);
    if den.abs() <= 1e-14 * d1.norm() * d2.norm() {
        return None;
    }
    let t = (next.a - top.a).cross(d2) / den;
    Some(top.a + d1 * t)
}

/// The old pair-wise handling of one corner between `prev` (the offset of `s1`, maybe
/// trimmed at its start) and `next` (the offset of `s2`): trims both to their meeting point
/// when they interfere, else returns the arc (or line) that joins them: a round join at a
/// convex corner, a bridge anywhere else.
fn pair_corner(
    s1: &Seg,
    s2: &Seg,
    tangents: (Point, Point),
    prev: &mut Seg,
    next: &mut Seg,
    o: f64,
    eps: f64,
) -> Option<RawSeg> {
    let v = s1.b;
    // the turn from the unit tangents' sine and cosine, no angle: straight on (within
    // TURN_EPS; the sine is the angle to double precision there), under a right angle, a
    // reversal
    let (sin, cos) = (tangents.0.cross(tangents.1), tangents.0.dot(tangents.1));
    let straight_on = cos > 0.0 && sin.abs() <= TURN_EPS * cos;
    let reversal = cos < 0.0 && sin.abs() <= TURN_EPS * -cos;
    let p1 = prev.b;
    let p2 = next.a;
    let collinear = straight_on || (p1.dist(p2) <= eps && cos > 0.0);
    if collinear {
        let gap = p1 - p2;
        if gap.dot(gap) <= short_length2(eps) {
            // no wider than a bridge that would go as too short (the offsets of a smooth
            // joint, a rounding apart): a line's end is moved across it instead
            if !next.is_arc() {
                next.a = p1;
                return None;
            }
            if !prev.is_arc() {
                prev.b = p2;
                return None;
            }
        }
        if p1.dist(p2) > 0.0 {
            return Some(RawSeg {
                seg: Seg::line(p1, p2),
                origin: Origin::Bridge,
            });
        }
        return None;
    }
    let concave = sin * o > 0.0 && !reversal;
    if concave {
        // pair-wise interference: trim both to their meeting point nearest the corner
        let h = if !prev.is_arc() && !next.is_arc() && !s1.is_arc() && !s2.is_arc() {
            let x = miter_point(v, tangents, o);
            let (t, u) = (prev.param(x), next.param(x));
            let (e1, e2) = (eps / prev.length().max(eps), eps / next.length().max(eps));
            let mut h = super::seg::Hits::default();
            if t >= -e1 && t <= 1.0 + e1 && u >= -e2 && u <= 1.0 + e2 {
                h.n = 1;
                h.p[0] = (x, t.clamp(0.0, 1.0), u.clamp(0.0, 1.0));
            }
            h
        } else {
            intersect(prev, next, eps)
        };
        let best = h
            .iter()
            .filter(|&(_, t, u)| t >= 0.0 && u >= 0.0)
            .min_by(|x, y| x.0.dist(v).total_cmp(&y.0.dist(v)));
        if let Some((x, t, u)) = best {
            *prev = prev.sub(0.0, prev.a, t, x);
            *next = next.sub(u, x, 1.0, next.b);
            return None;
        }
    }
    // at a concave corner whose neighbours do not meet, the arc runs backwards between
    // them: a local loop the global stage removes
    Some(RawSeg {
        seg: join_arc(v, p1, p2, o, concave),
        origin: if concave {
            Origin::Bridge
        } else {
            Origin::Join
        },
    })
}

/// The arc about the corner `v` from `p1` to `p2`: the convex way for `o` when `concave` is
/// false (a reversal turns to the offset side), the short way otherwise.
fn join_arc(v: Point, p1: Point, p2: Point, o: f64, concave: bool) -> Seg {
    let v1 = p1 - v;
    let v2 = p2 - v;
    let mut sw = angle(v1.cross(v2), v1.dot(v2));
    let want = -o.signum(); // convex joins turn against the offset side
    if !concave && (sw.abs() >= PI - 1e-9 || sw * want < 0.0) {
        if sw.abs() >= PI - 1e-9 {
            sw = want * PI;
        } else {
            sw = wrap(sw) + want * 2.0 * PI;
            if sw.abs() > PI {
                sw = want * PI;
            }
        }
    }
    // both ends lie |o| from the corner (each is the end of a segment moved by o): the
    // radius is |o|, no root
    let r = o.abs();
    if r == 0.0 || sw == 0.0 || p1 == p2 {
        return Seg::line(p1, p2);
    }
    // both ends lie |o| from the corner: the arc is about it
    Seg {
        a: p1,
        b: p2,
        c: v,
        r,
        sw,
    }
}

/// One segment moved by `o` to its left (`t` its unit tangent at the start), as a raw
/// segment: an arc that collapsed to its chord is a bridge.
fn offset_raw(s: &Seg, t: Point, o: f64) -> RawSeg {
    let seg = offset_seg(s, t, o);
    let origin = moved_origin(s, &seg);
    RawSeg { seg, origin }
}

/// What `moved`, the offset of input segment `s` (or a part of it), is: a bridge where an
/// arc collapsed to its chord, else an offset.
fn moved_origin(s: &Seg, moved: &Seg) -> Origin {
    if s.is_arc() && !moved.is_arc() {
        Origin::Bridge
    } else {
        Origin::Offset
    }
}

/// One segment moved by `o` to its left; `t` is its unit tangent at the start (the caller
/// has it: a line moves along its normal). An arc whose radius would fall to zero or below
/// becomes the chord between its moved ends: every point of it lies nearer the input than
/// |o|, so the pruning drops it.
fn offset_seg(s: &Seg, t: Point, o: f64) -> Seg {
    if s.is_arc() {
        // left of a counter-clockwise arc is towards its centre
        let r2 = if s.sw > 0.0 { s.r - o } else { s.r + o };
        let ua = (s.a - s.c) * (1.0 / s.r);
        let ub = (s.b - s.c) * (1.0 / s.r);
        let a = s.c + ua * r2;
        let b = s.c + ub * r2;
        if r2 > 0.0 {
            Seg {
                a,
                b,
                c: s.c,
                r: r2,
                sw: s.sw,
            }
        } else {
            Seg::line(a, b)
        }
    } else {
        let n = t.perp() * o;
        Seg::line(s.a + n, s.b + n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_raw_path_knows_its_longest_and_shortest_segment_unless_one_was_dropped() {
        let p = |x: f64, y: f64| Point::new(x, y);
        // a square grown by 1: four lines and four round joins
        let square = [p(0.0, 0.0), p(4.0, 0.0), p(4.0, 3.0), p(0.0, 3.0)];
        let segs: Vec<Seg> = (0..4)
            .map(|i| Seg::line(square[i], square[(i + 1) % 4]))
            .collect();
        let raw = raw_path(&segs, true, -1.0, 1e-9, 1.0 - 1e-9);
        let e = raw.extremes.expect("no segment dropped");
        let l2: Vec<f64> = raw.segs.iter().map(|s| s.length2()).collect();
        let max = l2.iter().cloned().fold(0.0, f64::max);
        let first_longest = l2.iter().position(|&x| x == max).unwrap();
        assert_eq!(e.longest, first_longest);
        assert_eq!(
            e.shortest2,
            l2.iter().cloned().fold(f64::INFINITY, f64::min)
        );
        assert_eq!(
            (raw.segs.len(), raw.origins.len(), raw.boxes.len()),
            (8, 8, 8)
        );
        assert_eq!(
            raw.origins.iter().filter(|&&o| o == Origin::Join).count(),
            4
        );
        // a line of 1e-13 between two collinear ones: its offset is shorter than ε / 1000
        // and goes, so what the boxing measured no longer holds
        let segs = vec![
            Seg::line(p(0.0, 0.0), p(5.0, 0.0)),
            Seg::line(p(5.0, 0.0), p(5.0 + 1e-13, 0.0)),
            Seg::line(p(5.0 + 1e-13, 0.0), p(10.0, 0.0)),
        ];
        let raw = raw_path(&segs, false, 1.0, 1e-9, 1.0 - 1e-9);
        assert!(raw.segs.iter().all(|s| s.length2() > short_length2(1e-9)));
        assert_eq!(
            (raw.segs.len(), raw.origins.len()),
            (2, 2),
            "{:?}",
            raw.segs
        );
        assert_eq!(raw.extremes, None);
    }

    /// A long line, a dense bend of radius `rho` turning `turn` radians to the left, and a
    /// long line out: the inside of the bend is to the left.
    fn bend(rho: f64, turn: f64, n: usize) -> Vec<Seg> {
        let mut pts = vec![Point::new(-20.0, -rho)];
        for i in 0..=n {
            let a = -PI / 2.0 + turn * i as f64 / n as f64;
            pts.push(Point::new(rho * a.cos(), rho * a.sin()));
        }
        let a = -PI / 2.0 + turn;
        let last = pts[pts.len() - 1];
        pts.push(last + Point::new(-a.sin(), a.cos()) * 20.0);
        pts.windows(2).map(|w| Seg::line(w[0], w[1])).collect()
    }

    fn dist_to(segs: &[Seg], p: Point) -> f64 {
        segs.iter().map(|s| s.dist(p)).fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn the_stack_removes_the_local_loops_of_a_bend_tighter_than_the_distance() {
        // curvature radius 0.3 and 0.6 against a distance of 1: the offset of the bend
        // folds back on itself (a swallowtail); a sparse and a dense sampling of it
        for (rho, n) in [(0.3, 12), (0.3, 400), (0.6, 50), (0.6, 2000)] {
            let segs = bend(rho, 2.0, n);
            let d = 1.0;
            let raw = raw_offset(&segs, false, d, 1e-7);
            // nothing of the raw offset is nearer the input than d: the loop is gone
            for r in &raw {
                for t in [0.0, 0.25, 0.5, 0.75, 1.0] {
                    let p = r.seg.point_at(t);
                    let got = dist_to(&segs, p);
                    assert!(
                        got > d - 1e-9,
                        "rho {rho} n {n}: {p:?} is {got} from the input"
                    );
                }
            }
            // and no two raw pieces cross: the global stage has nothing to do
            for i in 0..raw.len() {
                for j in i + 2..raw.len() {
                    let h = intersect(&raw[i].seg, &raw[j].seg, 1e-9);
                    assert_eq!(h.n, 0, "rho {rho} n {n}: pieces {i} and {j} cross");
                }
            }
            // the two long lines' offsets meet inside the bend, at distance d from both
            let first = raw[0].seg;
            let last = raw[raw.len() - 1].seg;
            assert!((dist_to(&segs, first.b) - d).abs() < 1e-9);
            assert!(
                first.b.dist(last.a) < 1e-9,
                "one corner: {first:?} {last:?}"
            );
        }
    }

    #[test]
    fn a_bend_wider_than_the_distance_keeps_every_offset_segment() {
        let segs = bend(3.0, 2.0, 40);
        let raw = raw_offset(&segs, false, 1.0, 1e-7);
        assert_eq!(raw.len(), segs.len());
        for (r, s) in raw.iter().zip(&segs) {
            let mid = r.seg.point_at(0.5);
            assert!((s.dist(mid) - 1.0).abs() < 1e-9);
        }
    }

    /// A stage's result: the bench's gear of 1,000 vertices (50 teeth) shrunk by 4.4 mm,
    /// smooth arcs and lines but for the corners between teeth, which turn to the inside.
    fn shrunk_gear() -> Vec<Seg> {
        let n = 1000;
        let pts: Vec<Point> = (0..n)
            .map(|i| {
                let a = i as f64 / n as f64 * std::f64::consts::TAU;
                let r = 100.0 + 3.0 * (50.0 * a).sin();
                Point::new(r * a.cos(), r * a.sin())
            })
            .collect();
        let gear = crate::geom::Region {
            outer: crate::geom::Polyline::from_points(&pts, true),
            islands: Vec::new(),
        };
        let r = crate::offset::offset_regions_valid(&[gear], -4.4, &Default::default()).unwrap();
        super::super::clean(&r.regions()[0].outer, 1e-9)
    }

    #[test]
    fn a_swallowtail_is_taken_apart_and_nothing_valid_with_it() {
        let segs = shrunk_gear();
        let (o, eps) = (8.0, 1e-9);
        let sure = o - 1e-7;
        let taken = raw_path(&segs, true, o, eps, sure).segs;
        let left = raw_path(&segs, true, o, eps, 0.0).segs;
        // every tooth's swallowtail went: far fewer pieces, and no two of them cross but
        // neighbours at their joint (the global stage has nothing to do), or by the seam,
        // where the first piece stays for the closing corner to trim
        assert!(
            taken.len() * 3 < left.len(),
            "{} of {}",
            taken.len(),
            left.len()
        );
        let seam = |i: usize| i < 16 || i + 16 > taken.len();
        for i in 0..taken.len() {
            for j in i + 2..taken.len() {
                if seam(i) && seam(j) {
                    continue;
                }
                let h = intersect(&taken[i], &taken[j], eps);
                assert_eq!(h.n, 0, "pieces {i} and {j} of {} cross", taken.len());
            }
        }
        // every point of the raw offset left whole that keeps its distance (a point of the
        // exact offset) lies on what is left once the swallowtails are taken apart
        let mut kept = 0;
        for s in &left {
            for k in 0..=16 {
                let p = s.point_at(k as f64 / 16.0);
                if dist_to(&segs, p) > o - 1e-7 {
                    kept += 1;
                    assert!(
                        dist_to(&taken, p) < 1e-7,
                        "{p:?} keeps its distance but went"
                    );
                }
            }
        }
        assert!(kept > 500, "only {kept} points keep their distance");
        // and what is left away from the seam is the exact offset: every point keeps its
        // distance
        for (i, s) in taken.iter().enumerate().filter(|(i, _)| !seam(*i)) {
            for k in 0..=16 {
                let p = s.point_at(k as f64 / 16.0);
                assert!(
                    dist_to(&segs, p) > o - 1e-6,
                    "{p:?} of {i} is too near, yet kept"
                );
            }
        }
    }
}
