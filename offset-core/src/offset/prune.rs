//! The global stage: find every intersection among the raw offset curves with the R-tree,
//! split them there, drop each run that comes nearer the input than |d| (minus a hair), and
//! stitch the surviving runs end to end into the offset's paths.

use super::index::{grow, BBox, BoxIndex};
use super::raw::{Extremes, Origin, RawPath};
use super::seg::{intersect, Norm, Seg};
use crate::geom::{hi, lo, Point};
use std::cell::Cell;
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// The hash of a grid cell of run ends: a multiply and a rotate per coordinate (the
/// standard SipHash, made to resist crafted keys, cost more than the stitching it serves).
#[derive(Default)]
struct CellHasher(u64);

impl Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }
    fn write_u64(&mut self, x: u64) {
        self.0 = (self.0.rotate_left(5) ^ x).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_i64(&mut self, x: i64) {
        self.write_u64(x as u64);
    }
}

/// Run ends by grid cell.
type Cells = HashMap<(i64, i64), Vec<usize>, BuildHasherDefault<CellHasher>>;

/// The input paths' segments, for distance questions. Given the input check's tree over
/// their boxes (packed in path order), every question asks it; without one, a handful of
/// questions is answered by scanning every segment, and for more the tree is packed first
/// (in path order too: neighbours along a path lie side by side, so no sort).
pub struct InputSet<'a> {
    paths: Vec<&'a [Seg]>,
    /// where each path's segments start when they are numbered one path after another
    starts: Vec<usize>,
    /// every segment in that numbering, when there are several paths and more than a
    /// handful of questions (else empty: a search among `starts`)
    flat: Vec<&'a Seg>,
    /// the tree over the segments' boxes in that numbering, or over a superset of each
    /// (the input check's, grown by ε), once there is one
    index: Option<BoxIndex>,
    /// the segment that last answered "nearer": asked first next time (the runs come in
    /// order along their curves, and neighbouring invalid runs mostly come too near the
    /// same stretch of the input)
    hint: Cell<usize>,
}

/// Up to this many questions a scan is cheaper than building the tree.
const SCANS: usize = 4;

impl<'a> InputSet<'a> {
    /// `tree`: over the segments' boxes, one path after another, or a superset of each (the
    /// input check's, grown by ε), if one was made; else an empty one.
    pub fn new(paths: Vec<&'a [Seg]>, tree: BoxIndex) -> InputSet<'a> {
        let mut starts = Vec::with_capacity(paths.len());
        let mut total = 0;
        for p in &paths {
            starts.push(total);
            total += p.len();
        }
        InputSet {
            paths,
            starts,
            flat: Vec::new(),
            index: (total > 0 && tree.len() == total).then_some(tree),
            hint: Cell::new(0),
        }
    }

    /// Prepares for about `questions` distance questions.
    pub fn expect(&mut self, questions: usize) {
        if questions > SCANS && self.paths.len() > 1 && self.flat.is_empty() {
            self.flat = self.paths.iter().flat_map(|p| p.iter()).collect();
        }
        if questions > SCANS && self.index.is_none() {
            let total: usize = self.paths.iter().map(|p| p.len()).sum();
            let mut boxes = Vec::with_capacity(BoxIndex::room(total));
            boxes.extend(self.paths.iter().flat_map(|p| p.iter()).map(|s| s.bbox()));
            self.index = Some(BoxIndex::in_order_owned(boxes));
        }
    }

    /// Segment `i` of the numbering one path after another.
    #[inline]
    fn seg(&self, i: usize) -> &'a Seg {
        if self.paths.len() == 1 {
            &self.paths[0][i]
        } else if !self.flat.is_empty() {
            self.flat[i]
        } else {
            let p = self.starts.partition_point(|&s| s <= i) - 1;
            &self.paths[p][i - self.starts[p]]
        }
    }

    /// Whether some input segment comes nearer `p` or `q` than `thr`: without the tree,
    /// one scan for both (a scan of a million segments reads 64 MB).
    pub fn either_closer(&self, p: Point, q: Point, thr: f64) -> bool {
        if thr <= 0.0 {
            return false;
        }
        if self.index.is_some() {
            return self.any_closer(p, thr) || self.any_closer(q, thr);
        }
        let near = |s: &Seg, p: Point| {
            // the ends' box first: a line wholly outside the query square is skipped
            // without a distance (an arc may bulge into it)
            let out = lo(s.a.x, s.b.x) > p.x + thr
                || hi(s.a.x, s.b.x) < p.x - thr
                || lo(s.a.y, s.b.y) > p.y + thr
                || hi(s.a.y, s.b.y) < p.y - thr;
            (!out || s.is_arc()) && s.dist(p) < thr
        };
        self.paths
            .iter()
            .any(|segs| segs.iter().any(|s| near(s, p) || near(s, q)))
    }

    /// Whether some input segment comes nearer `p` than `thr`.
    pub fn any_closer(&self, p: Point, thr: f64) -> bool {
        if thr <= 0.0 {
            return false;
        }
        let Some(index) = &self.index else {
            return self.either_closer(p, p, thr);
        };
        let hint = self.hint.get();
        if hint < index.len() && self.seg(hint).dist(p) < thr {
            return true;
        }
        let mut found = false;
        index.query_disc(p.x, p.y, thr, |i| {
            if self.seg(i).dist(p) < thr {
                found = true;
                self.hint.set(i);
                return false;
            }
            true
        });
        found
    }
}

/// A sweep up to this (radians) has its midpoint from the bisector of its ends' radii.
const BISECTED_SWEEP: f64 = 2.5;

/// The points of `s` at parameters 0.5 and 0.25 (`Seg::point_at`). An arc's, when it
/// sweeps at most `BISECTED_SWEEP`, come from bisecting its ends' radii and then the
/// first half's, without trigonometry: its start angle's atan2 and the sine and cosine of
/// each point were a tenth of a later stage's time (the prune asks them of every run).
fn mid_and_quarter(s: &Seg) -> (Point, Point) {
    if !s.is_arc() || s.sw.abs() > BISECTED_SWEEP {
        return (s.point_at(0.5), s.point_at(0.25));
    }
    // the radii's sum points at the middle of a sweep below π, and is at least
    // 2 r cos(1.25) long
    let on_circle = |v: Point| s.c + v * (s.r / v.norm());
    let mid = on_circle((s.a - s.c) + (s.b - s.c));
    let quarter = on_circle((s.a - s.c) + (mid - s.c));
    (mid, quarter)
}

/// A stitched piece of the result.
pub struct Chain {
    pub segs: Vec<Seg>,
    /// per segment: it is a whole round join (one a miter or chamfer may replace)
    pub whole_join: Vec<bool>,
    pub closed: bool,
    /// the least squared length of its segments where the pass that made them found it
    /// (a whole raw curve), else 0: known to be no less
    pub shortest2: f64,
}

/// Whether `s1` followed by `s2` (joined end to start) can meet nowhere but at their joint:
/// two lines going on at less than a right angle, or a line and an arc tangent at the
/// joint (a tangent line touches a circle once; the slack allows for the arc's radius).
pub fn meet_only_at_the_joint(s1: &Seg, s2: &Seg, eps: f64) -> bool {
    match (s1.is_arc(), s2.is_arc()) {
        (false, false) => (s1.b - s1.a).dot(s2.b - s2.a) > 0.0,
        (true, true) => false,
        _ => {
            // the line's direction `d` and the arc's radius `w` at the joint, neither made
            // a unit: the arc's tangent there is ±w⊥ / r, so the unit tangents' dot product
            // has the sign of d · ±w⊥, and their cross product times r is
            // |d × w⊥| / |d| = |d · w| / |d| (no root, no division)
            let (line, arc, w) = if s1.is_arc() {
                (s2, s1, s1.b - s1.c)
            } else {
                (s1, s2, s2.a - s2.c)
            };
            let d = line.b - line.a;
            let tangent = if arc.sw > 0.0 { w.perp() } else { -w.perp() };
            let off = d.dot(w);
            let slack = eps * 0.25;
            d.dot(tangent) > 0.0 && off * off <= slack * slack * d.dot(d)
        }
    }
}

/// Which piece of a raw segment, on either side of a point where another raw curve crosses
/// it, lies on the input's side of that curve (and so nearer the input than |o|).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Inside {
    Unknown,
    /// the piece before the crossing
    Before,
    /// the piece after it
    After,
}

/// Where raw segment `a` at parameter `ta` crosses raw segment `b` at `tb`: which piece of
/// `a` lies on the input's side of `b` (`left`: the offset runs to the left of the input,
/// so the input lies right of every raw curve). Just across an offset segment or a round
/// join from the outside, every point lies nearer the input than |o|; so that piece of
/// `a`, and the whole run it belongs to, is invalid, however little nearer it comes.
///
/// Answered only where that holds and the sign is sure: `b` is no bridge, the crossing
/// lies inside both segments (not at a joint, where the pieces beside it belong to other
/// segments), and the two cross at an angle whose sine is well above what rounding can
/// make of it (the tangents' directions, and how far the crossing may slide along the
/// curves: less than ε).
#[allow(clippy::too_many_arguments)]
fn inside_of(
    a: &Seg,
    ta: f64,
    b: &Seg,
    b_origin: Origin,
    tb: f64,
    p: Point,
    left: bool,
    eps: f64,
) -> Inside {
    if b_origin == Origin::Bridge {
        return Inside::Unknown;
    }
    let margin = 4.0 * eps;
    let (la, lb) = (a.length(), b.length());
    if ta * la <= margin
        || (1.0 - ta) * la <= margin
        || tb * lb <= margin
        || (1.0 - tb) * lb <= margin
    {
        return Inside::Unknown;
    }
    let (da, db) = (tangent_through(a, p), tangent_through(b, p));
    let c = db.cross(da);
    let scale = |s: &Seg| -> (f64, f64) {
        let m =
            s.a.x
                .abs()
                .max(s.a.y.abs())
                .max(s.b.x.abs())
                .max(s.b.y.abs());
        let m = if s.is_arc() {
            m.max(s.c.x.abs()).max(s.c.y.abs())
        } else {
            m
        };
        (m.max(1.0), if s.is_arc() { s.r } else { s.length() })
    };
    let ((ma, ra), (mb, rb)) = (scale(a), scale(b));
    let m = ma.max(mb);
    let sure = 16.0 * f64::EPSILON * m * (1.0 / eps + 1.0 / ra + 1.0 / rb);
    if !(c.abs() > sure) {
        return Inside::Unknown;
    }
    // `a` turns left of `b` at the crossing: its piece after lies left of `b`
    if (c > 0.0) == left {
        Inside::Before
    } else {
        Inside::After
    }
}

/// The splits in the order of their segments, and along each segment by parameter: a
/// counting sort by segment (most raw segments have none, a few have several), then a sort
/// of each segment's few. Same order as a sort by (segment, parameter), in O(n + splits).
fn by_segment_and_parameter<T: Copy>(
    splits: Vec<(u32, f64, Point, T)>,
    n: usize,
) -> Vec<(u32, f64, Point, T)> {
    if splits.len() < 2 {
        return splits;
    }
    // first[g]: where segment g's splits start in the result
    let mut first = vec![0u32; n + 1];
    for s in &splits {
        first[s.0 as usize + 1] += 1;
    }
    for g in 0..n {
        first[g + 1] += first[g];
    }
    let mut at: Vec<u32> = first[..n].to_vec();
    let mut out = vec![splits[0]; splits.len()];
    for s in splits {
        let k = &mut at[s.0 as usize];
        out[*k as usize] = s;
        *k += 1;
    }
    for g in 0..n {
        let (a, b) = (first[g] as usize, first[g + 1] as usize);
        if b - a > 1 {
            out[a..b].sort_unstable_by(|x, y| x.1.total_cmp(&y.1));
        }
    }
    out
}

/// The unit tangent of `s` where it passes through `p` (a point on it): an arc's from the
/// radius through `p`, without the angle of its parameter.
fn tangent_through(s: &Seg, p: Point) -> Point {
    if s.is_arc() {
        let rad = (p - s.c).unit();
        if s.sw > 0.0 {
            rad.perp()
        } else {
            -rad.perp()
        }
    } else {
        s.tangent_at(0.0)
    }
}

/// What the prune leaves.
pub struct Pruned {
    pub chains: Vec<Chain>,
    /// nothing crossed: every path was closed and no pair of raw segments met anywhere but
    /// at the shared end of neighbours (by the rule of the input check, or stricter), so
    /// every chain is a whole raw curve, and a crossing search of the chains by the input
    /// check's rule finds nothing
    pub uncrossed: bool,
}

/// Splits, prunes and stitches. `splitters` only cut raw curves (the circles of radius |o|
/// about an open path's ends). `o` is the signed offset (positive: to the left); `eps` the
/// geometric tolerance. A run is dropped when its sample comes nearer the input than
/// |o| - `valid_eps`, or when it leaves or reaches a crossing on the input's side of the
/// other curve (however shallow its loop: see `inside_of`).
pub fn prune(
    paths: Vec<RawPath>,
    splitters: &[Seg],
    input: &mut InputSet,
    o: f64,
    eps: f64,
    valid_eps: f64,
) -> Pruned {
    let dist = o.abs();
    let left = o > 0.0;
    // global numbering of raw segments: the paths one after another (the first one's
    // storage is taken over, not copied)
    let closed: Vec<bool> = paths.iter().map(|p| p.closed).collect();
    let mut start = Vec::with_capacity(paths.len() + 1);
    let extremes: Vec<Option<Extremes>> = paths.iter().map(|p| p.extremes).collect();
    let mut rs: Vec<Seg> = Vec::new();
    let mut origins: Vec<Origin> = Vec::new();
    let mut boxes: Vec<BBox> = Vec::new();
    let mut owner: Vec<u32> = Vec::new();
    for (pi, p) in paths.into_iter().enumerate() {
        start.push(rs.len());
        owner.extend(std::iter::repeat_n(pi as u32, p.segs.len()));
        if rs.is_empty() {
            rs = p.segs;
            origins = p.origins;
            boxes = p.boxes;
        } else {
            rs.extend(p.segs);
            origins.extend(p.origins);
            boxes.extend(p.boxes);
        }
    }
    start.push(rs.len());
    let n = rs.len();
    let next = |g: usize| -> Option<usize> {
        let p = owner[g] as usize;
        if g + 1 < start[p + 1] {
            Some(g + 1)
        } else if closed[p] {
            Some(start[p])
        } else {
            None
        }
    };
    // Some(length between them) when raw segment `j` follows `i` after at most
    // NEAR_STEPS - 1 segments in between, all of them together no longer than NEAR_LEN ε
    const NEAR_STEPS: usize = 8;
    const NEAR_LEN: f64 = 4.0;
    let gap = |i: usize, j: usize| -> Option<f64> {
        let mut g = next(i)?;
        let mut len = 0.0;
        for _ in 1..NEAR_STEPS {
            if g == i {
                return None;
            }
            len += rs[g].length();
            if len > NEAR_LEN * eps {
                return None;
            }
            g = next(g)?;
            if g == j {
                return Some(len);
            }
        }
        None
    };
    // a hit farther than this from either end of a stretch cannot be within ε + its
    // length of both, so `gap` is asked only of hits nearer
    let reach = eps * (1.0 + NEAR_LEN);
    boxes.extend(splitters.iter().map(|s| grow(s.bbox(), eps)));
    let tree = BoxIndex::in_order_owned(boxes);
    // (segment, parameter, point, which piece is inside the other curve) of every split
    let mut splits: Vec<(u32, f64, Point, Inside)> = Vec::new();
    tree.overlapping_pairs(|i, j| {
        if i >= n {
            return;
        }
        let si = rs[i];
        if j >= n {
            let h = intersect(&si, &splitters[j - n], eps);
            for (p, t, _) in h.iter() {
                splits.push((i as u32, t, p, Inside::Unknown));
            }
            return;
        }
        let sj = &rs[j];
        let (ni, nj) = (next(i), next(j));
        if (ni == Some(j) && meet_only_at_the_joint(&si, sj, eps))
            || (nj == Some(i) && meet_only_at_the_joint(sj, &si, eps))
        {
            return;
        }
        let h = intersect(&si, sj, eps);
        if h.n == 0 {
            return;
        }
        // segments a few sub-ε pieces apart along the curve (a dense loop shrunk almost to a
        // point leaves pieces shorter than ε): where they meet near the stretch between them
        // they only touch through it, no loop of any size lies between them
        let (mut gij, mut gji) = (None, None);
        for (p, t, u) in h.iter() {
            // the shared end of neighbours is no crossing
            if ni == Some(j) && p.dist(si.b) <= eps && u <= 0.5 {
                continue;
            }
            if nj == Some(i) && p.dist(si.a) <= eps && t <= 0.5 {
                continue;
            }
            let (to_ib, to_ja) = (p.dist(si.b), p.dist(sj.a));
            if to_ib <= reach && to_ja <= reach {
                let g = *gij.get_or_insert_with(|| gap(i, j));
                if g.is_some_and(|g| to_ib <= eps + g && to_ja <= eps + g) {
                    continue;
                }
            }
            let (to_ia, to_jb) = (p.dist(si.a), p.dist(sj.b));
            if to_ia <= reach && to_jb <= reach {
                let g = *gji.get_or_insert_with(|| gap(j, i));
                if g.is_some_and(|g| to_ia <= eps + g && to_jb <= eps + g) {
                    continue;
                }
            }
            splits.push((
                i as u32,
                t,
                p,
                inside_of(&rs[i], t, &rs[j], origins[j], u, p, left, eps),
            ));
            splits.push((
                j as u32,
                u,
                p,
                inside_of(&rs[j], u, &rs[i], origins[i], t, p, left, eps),
            ));
        }
    });
    let splits = by_segment_and_parameter(splits, n);
    let uncrossed = splits.is_empty() && closed.iter().all(|&c| c);

    // pieces per path, with a break flag where a run ends before them
    struct Piece {
        seg: Seg,
        brk: bool,
        whole_join: bool,
        /// it starts (ends) at a crossing on the input's side of the other curve
        inside_from_start: bool,
        inside_to_end: bool,
    }
    let mut chains = Vec::new();
    // a closed raw curve that nothing crosses is one run: kept whole or dropped whole
    let mut uncut = vec![false; closed.len()];
    let mut sp = 0;
    for (pi, &p_closed) in closed.iter().enumerate() {
        let (a, b) = (start[pi], start[pi + 1]);
        while sp < splits.len() && (splits[sp].0 as usize) < a {
            sp += 1;
        }
        if !p_closed || b == a || (sp < splits.len() && (splits[sp].0 as usize) < b) {
            continue;
        }
        uncut[pi] = true;
    }
    let mut pieces: Vec<Piece> = Vec::with_capacity(n + splits.len());
    let mut pstart: Vec<usize> = Vec::with_capacity(closed.len() + 1);
    let mut sp = 0;
    for (pi, &p_closed) in closed.iter().enumerate() {
        pstart.push(pieces.len());
        if uncut[pi] {
            continue;
        }
        let first = pieces.len();
        let mut brk = false;
        for g in start[pi]..start[pi + 1] {
            let s = rs[g];
            let len = s.length();
            let tiny = if len > 0.0 { eps / len } else { 1.0 };
            let (mut t0, mut p0) = (0.0, s.a);
            let mut end_brk = false;
            // what the crossing at t0 says of the piece starting there; a cut where several
            // crossings fall within ε of each other says nothing (which piece lies between
            // them is not sure)
            let mut inside_from_start = false;
            let mut cut_here = false;
            while sp < splits.len() && splits[sp].0 as usize == g {
                let (_, t, q, inside) = splits[sp];
                sp += 1;
                if t <= tiny {
                    brk = true;
                } else if t >= 1.0 - tiny {
                    end_brk = true;
                } else if t - t0 <= tiny {
                    brk = true;
                    if cut_here {
                        inside_from_start = false;
                        if let Some(last) = pieces.last_mut() {
                            last.inside_to_end = false;
                        }
                    }
                } else {
                    pieces.push(Piece {
                        seg: s.sub(t0, p0, t, q),
                        brk,
                        whole_join: false,
                        inside_from_start,
                        inside_to_end: inside == Inside::Before,
                    });
                    brk = true;
                    t0 = t;
                    p0 = q;
                    inside_from_start = inside == Inside::After;
                    cut_here = true;
                }
            }
            pieces.push(Piece {
                seg: s.sub(t0, p0, 1.0, s.b),
                brk,
                whole_join: origins[g] == Origin::Join && t0 == 0.0,
                inside_from_start,
                inside_to_end: false,
            });
            brk = end_brk;
        }
        if p_closed && brk && pieces.len() > first {
            pieces[first].brk = true;
        }
    }
    pstart.push(pieces.len());

    // runs: maximal stretches of pieces without a break
    struct Run {
        path: usize,
        first: usize,
        count: usize,
        whole: bool,
    }
    let mut runs: Vec<Run> = Vec::with_capacity(splits.len() + closed.len());
    for (pi, &p_closed) in closed.iter().enumerate() {
        let (a, b) = (pstart[pi], pstart[pi + 1]);
        let m = b - a;
        if m == 0 {
            continue;
        }
        let breaks: Vec<usize> = (a..b).filter(|&k| pieces[k].brk).collect();
        if p_closed {
            if breaks.is_empty() {
                runs.push(Run {
                    path: pi,
                    first: a,
                    count: m,
                    whole: true,
                });
                continue;
            }
            for (bi, &k) in breaks.iter().enumerate() {
                let nk = breaks[(bi + 1) % breaks.len()];
                let count = if nk > k { nk - k } else { nk + m - k };
                runs.push(Run {
                    path: pi,
                    first: k,
                    count,
                    whole: false,
                });
            }
        } else {
            let mut k = a;
            while k < b {
                let mut e = k + 1;
                while e < b && !pieces[e].brk {
                    e += 1;
                }
                runs.push(Run {
                    path: pi,
                    first: k,
                    count: e - k,
                    whole: false,
                });
                k = e;
            }
        }
    }
    let piece_at = |r: &Run, k: usize| -> &Piece {
        let (a, b) = (pstart[r.path], pstart[r.path + 1]);
        let idx = r.first + k;
        &pieces[if idx >= b { idx - (b - a) } else { idx }]
    };

    let uncut_count = uncut.iter().filter(|&&u| u).count();
    input.expect(2 * (uncut_count + runs.len()));
    let input = &*input;
    // the validity test of a run: the midpoint and the quarter point of its longest piece
    // must keep their distance (two samples: a run may pass through a point exactly |d|
    // from two boundaries, where an island touches the outer, its offset's crossing with
    // the outer's lies symmetric about that point, while the rest of it comes nearer)
    let thr = dist - valid_eps;
    let keeps_distance = |longest: &Seg| -> bool {
        let (mid, quarter) = mid_and_quarter(longest);
        !input.either_closer(mid, quarter, thr)
    };
    // the curves nothing cuts, kept whole or dropped whole, from the last path to the first
    // so each one's segments are split off the end of the numbering (the first path's,
    // usually the outer and much the longest, are taken as they lie: at a million segments
    // a copy read 72 MB and wrote 64)
    let mut whole: Vec<Option<Chain>> = (0..closed.len()).map(|_| None).collect();
    for pi in (0..closed.len()).rev().filter(|&pi| uncut[pi]) {
        let (a, b) = (start[pi], start[pi + 1]);
        if let Some(Extremes { longest, shortest2 }) = extremes[pi] {
            // every segment has a positive length (the raw offset measured them)
            if !keeps_distance(&rs[a + longest]) {
                continue;
            }
            let whole_join = origins[a..b].iter().map(|&o| o == Origin::Join).collect();
            rs.truncate(b);
            let segs = if a == 0 {
                std::mem::take(&mut rs)
            } else {
                rs.split_off(a)
            };
            debug_assert!(segs.iter().all(|s| s.length2() > 0.0));
            whole[pi] = Some(Chain {
                segs,
                whole_join,
                closed: true,
                shortest2,
            });
            continue;
        }
        // the whole curve as it would be kept, its longest segment found on the way (one
        // pass over it; squared lengths, the same order), dropped if that one comes too near
        let mut segs = Vec::with_capacity(b - a);
        let mut whole_join = Vec::with_capacity(b - a);
        let mut longest = (0.0, 0);
        let mut shortest2 = f64::INFINITY;
        for (s, &o) in rs[a..b].iter().zip(&origins[a..b]) {
            let l2 = s.length2();
            if l2 > 0.0 {
                if l2 > longest.0 {
                    longest = (l2, segs.len());
                }
                shortest2 = shortest2.min(l2);
                segs.push(*s);
                whole_join.push(o == Origin::Join);
            }
        }
        if longest.0 > 0.0 && keeps_distance(&segs[longest.1]) {
            whole[pi] = Some(Chain {
                segs,
                whole_join,
                closed: true,
                shortest2,
            });
        }
    }
    chains.extend(whole.into_iter().flatten());
    let valid: Vec<bool> = runs
        .iter()
        .map(|r| {
            let mut best = (0.0, 0usize);
            for k in 0..r.count {
                let l = piece_at(r, k).seg.length();
                if l > best.0 {
                    best = (l, k);
                }
            }
            best.0 > 0.0
                && !piece_at(r, 0).inside_from_start
                && !piece_at(r, r.count - 1).inside_to_end
                && keeps_distance(&piece_at(r, best.1).seg)
        })
        .collect();
    let collect = |r: &Run, out: &mut Vec<Seg>, wj: &mut Vec<bool>| {
        for k in 0..r.count {
            let pc = piece_at(r, k);
            if pc.seg.length() > 0.0 {
                out.push(pc.seg);
                wj.push(pc.whole_join);
            }
        }
    };
    let run_start = |r: &Run| piece_at(r, 0).seg.a;
    let run_end = |r: &Run| piece_at(r, r.count - 1).seg.b;
    let mut used = vec![false; runs.len()];
    for (ri, r) in runs.iter().enumerate() {
        if valid[ri] && r.whole {
            used[ri] = true;
            let mut segs = Vec::with_capacity(r.count);
            let mut whole_join = Vec::with_capacity(r.count);
            collect(r, &mut segs, &mut whole_join);
            chains.push(Chain {
                segs,
                whole_join,
                closed: true,
                shortest2: 0.0,
            });
        }
    }
    // hash of run starts
    let cell = (eps * 16.0).max(f64::MIN_POSITIVE);
    let key = |p: Point| ((p.x / cell).floor() as i64, (p.y / cell).floor() as i64);
    let mut starts = Cells::default();
    let mut ends = Cells::default();
    for (ri, r) in runs.iter().enumerate() {
        if valid[ri] && !used[ri] {
            starts.entry(key(run_start(r))).or_default().push(ri);
            ends.entry(key(run_end(r))).or_default().push(ri);
        }
    }
    let near = |map: &Cells, p: Point, f: &mut dyn FnMut(usize)| {
        let (kx, ky) = key(p);
        for dx in -1..=1 {
            for dy in -1..=1 {
                if let Some(v) = map.get(&(kx.wrapping_add(dx), ky.wrapping_add(dy))) {
                    for &ri in v {
                        f(ri);
                    }
                }
            }
        }
    };
    let match_eps = eps * 16.0;
    // the run that goes on along run `k`'s curve where it ends (None at an open curve's end)
    let mut path_first_run = vec![usize::MAX; closed.len()];
    for (ri, r) in runs.iter().enumerate().rev() {
        path_first_run[r.path] = ri;
    }
    let straight_on = |k: usize| -> Option<usize> {
        let p = runs[k].path;
        match runs.get(k + 1) {
            Some(n) if n.path == p => Some(k + 1),
            _ if closed[p] => Some(path_first_run[p]),
            _ => None,
        }
    };
    // whether a valid run other than `cur` ends at `e`
    let another_arrives = |cur: usize, e: Point| -> bool {
        let mut found = false;
        near(&ends, e, &mut |k| {
            found |= k != cur && run_end(&runs[k]).dist(e) <= match_eps;
        });
        found
    };
    // of the runs `cands` starting at `e`, one of `cur`'s own curve first, then the nearest
    let nearest = |cur: usize, e: Point, cands: &[usize]| -> Option<usize> {
        let mut best: Option<(usize, f64, bool)> = None;
        for &k in cands {
            let d = run_start(&runs[k]).dist(e);
            let same = runs[k].path == runs[cur].path;
            let better = match best {
                None => true,
                Some((_, bd, bs)) => (same && !bs) || (same == bs && d < bd),
            };
            if better {
                best = Some((k, d, same));
            }
        }
        best.map(|(k, _, _)| k)
    };
    // Open chains first start where no valid run ends. A closed curve's run that no valid
    // run leads into is a spur (half of a zig-zag whose other half was pruned, where raw
    // curves overlap along a line): it cannot close, so it goes last, after the loops it
    // would otherwise have robbed of the run it leads into. So does a run that one valid
    // run leads into when that run goes on along its own curve there (see the stitch's
    // choice below): started first, it would close a sliver of a loop through the pieces
    // the real loop needs.
    let mut order: Vec<usize> = Vec::new();
    let mut spurs: Vec<usize> = Vec::new();
    let mut is_spur = vec![false; runs.len()];
    for (ri, r) in runs.iter().enumerate() {
        if !valid[ri] || used[ri] {
            continue;
        }
        let s = run_start(r);
        let (mut preds, mut pred) = (0, 0);
        near(&ends, s, &mut |k| {
            if k != ri && run_end(&runs[k]).dist(s) <= match_eps {
                preds += 1;
                pred = k;
            }
        });
        let forked_off = preds == 1
            && straight_on(pred).is_some_and(|n| {
                n != ri && valid[n] && !used[n] && run_start(&runs[n]).dist(s) <= match_eps
            });
        if preds == 0 && !closed[r.path] {
            order.push(ri);
        } else if forked_off || (preds == 0 && closed[r.path]) {
            spurs.push(ri);
            is_spur[ri] = true;
        }
    }
    order.extend((0..runs.len()).filter(|&ri| !is_spur[ri]));
    order.extend(spurs);
    let mut cands: Vec<usize> = Vec::new();
    for &ri in &order {
        if !valid[ri] || used[ri] {
            continue;
        }
        used[ri] = true;
        let first_start = run_start(&runs[ri]);
        let mut segs = Vec::new();
        let mut whole_join = Vec::new();
        collect(&runs[ri], &mut segs, &mut whole_join);
        let mut cur = ri;
        let is_loop;
        loop {
            let e = run_end(&runs[cur]);
            if e.dist(first_start) <= match_eps {
                is_loop = true;
                break;
            }
            cands.clear();
            near(&starts, e, &mut |k| {
                if !used[k] && run_start(&runs[k]).dist(e) <= match_eps {
                    cands.push(k);
                }
            });
            // Of several, the ones the chain can go on from (a valid run starts where each
            // ends, or it closes the chain, or its curve ends there) are kept: where three
            // crossings fall within a few ε (a notch closing as the boundary grows), the
            // run along the arriving curve may end at a crossing no valid run leaves, and
            // taking it stranded the chain, and with it the loop.
            if cands.len() > 1 {
                let goes_on = |k: usize| -> bool {
                    let f = run_end(&runs[k]);
                    if f.dist(first_start) <= match_eps || straight_on(k).is_none() {
                        return true;
                    }
                    let mut on = false;
                    near(&starts, f, &mut |k2| {
                        on |= k2 != k && !used[k2] && run_start(&runs[k2]).dist(f) <= match_eps;
                    });
                    on
                };
                let live = cands.iter().filter(|&&k| goes_on(k)).count();
                if live > 0 && live < cands.len() {
                    cands.retain(|&k| goes_on(k));
                }
            }
            // Where one valid run arrives and two leave, the one that goes on along the
            // arriving run's own curve is taken: at a crossing the curves divide the plane,
            // so the arriving curve's next piece lies inside the other and is invalid; two
            // valid pieces of one curve on either side of a cut mean the other curve only
            // touched it there, or was a bridge. What leaves along the other curve is then a
            // piece of a local loop too thin for the distance test (a collapsed arc's chord
            // grazing the next offset arc within ε), and taking it strands the chain.
            let best = if cands.len() > 1 && !another_arrives(cur, e) {
                cands.iter().copied().find(|&k| Some(k) == straight_on(cur))
            } else {
                None
            }
            .or_else(|| nearest(cur, e, &cands));
            match best {
                Some(k) => {
                    used[k] = true;
                    collect(&runs[k], &mut segs, &mut whole_join);
                    cur = k;
                }
                None => {
                    // a chain that comes back to its start within the validity slack is a
                    // loop (a sliver at the crossing where it closes may have been dropped),
                    // for an open path's offset as for a closed one's
                    is_loop = e.dist(first_start) <= match_eps.max(valid_eps);
                    break;
                }
            }
        }
        if closed[runs[ri].path] && !is_loop {
            // a broken loop of a closed curve: numerically lost, drop it
            continue;
        }
        chains.push(Chain {
            segs,
            whole_join,
            closed: is_loop,
            shortest2: 0.0,
        });
    }
    Pruned { chains, uncrossed }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rule in unit tangents, as `meet_only_at_the_joint` states it.
    fn by_unit_tangents(s1: &Seg, s2: &Seg, eps: f64) -> bool {
        let (t1, t2) = (s1.tangent_at(1.0), s2.tangent_at(0.0));
        let r = if s1.is_arc() { s1.r } else { s2.r };
        t1.dot(t2) > 0.0 && t1.cross(t2).abs() * r <= eps * 0.25
    }

    #[test]
    fn a_runs_samples_are_its_points_at_a_half_and_a_quarter() {
        let mut rand = crate::test_rng::uniform(7);
        for k in 0..2000 {
            let c = Point::new(200.0 * rand() - 100.0, 200.0 * rand() - 100.0);
            let r = 1e-3 * 10f64.powf(6.0 * rand());
            let start = std::f64::consts::TAU * rand();
            // sweeps of either sense up to a whole turn, most of them bisected
            let sw = (if k % 2 == 0 { 1.0 } else { -1.0 }) * 3.2 * rand().powi(2) * 1.9;
            let on = |t: f64| c + Point::new(t.cos(), t.sin()) * r;
            let arc = Seg::arc(c, r, on(start), on(start + sw), sw);
            let (mid, quarter) = mid_and_quarter(&arc);
            for (got, t) in [(mid, 0.5), (quarter, 0.25)] {
                let want = arc.point_at(t);
                assert!(
                    got.dist(want) <= 1e-12 * (r + c.len()),
                    "sweep {sw}, radius {r}: {got:?} for {want:?} at {t}"
                );
            }
        }
        let line = Seg::line(Point::new(1.0, 2.0), Point::new(5.0, -2.0));
        assert_eq!(
            mid_and_quarter(&line),
            (Point::new(3.0, 0.0), Point::new(2.0, 1.0))
        );
    }

    #[test]
    fn a_line_and_an_arc_meet_only_at_the_joint_when_tangent_there() {
        let eps = 1e-6;
        let mut rnd = crate::test_rng::uniform(2501);
        let mut tangent = 0;
        for _ in 0..2000 {
            // an arc about c from angle a0 through sw, and a line into its start (or out
            // of its end) at an angle `kink` off the arc's tangent there
            let c = Point::new(rnd() * 20.0 - 10.0, rnd() * 20.0 - 10.0);
            let r = 0.01 + rnd() * 50.0;
            let (a0, sw) = (rnd() * 6.0, (rnd() - 0.5) * 3.0);
            let at = |a: f64| c + Point::new(a.cos(), a.sin()) * r;
            let arc = Seg::arc(c, r, at(a0), at(a0 + sw), sw);
            // a kink of a few ε / r either way of the rule's bound, or a large one
            let kink = match rnd() {
                x if x < 0.7 => (rnd() - 0.5) * 2.0 * eps / r,
                x if x < 0.9 => (rnd() - 0.5) * 4.0,
                _ => std::f64::consts::PI - rnd() * 0.1,
            };
            let len = 0.001 + rnd() * 10.0;
            let rot = |t: Point, k: f64| {
                Point::new(t.x * k.cos() - t.y * k.sin(), t.x * k.sin() + t.y * k.cos())
            };
            let into = rot(arc.tangent_at(0.0), kink);
            let line_in = Seg::line(arc.a - into * len, arc.a);
            let out = rot(arc.tangent_at(1.0), kink);
            let line_out = Seg::line(arc.b, arc.b + out * len);
            for (s1, s2) in [(&line_in, &arc), (&arc, &line_out)] {
                let want = by_unit_tangents(s1, s2, eps);
                let got = meet_only_at_the_joint(s1, s2, eps);
                // the two forms round differently only right at the bound
                let sine = kink.sin().abs() * r;
                if (sine - eps * 0.25).abs() > 1e-9 * eps {
                    assert_eq!(got, want, "kink {kink}, r {r}, sw {sw}");
                }
                tangent += got as usize;
            }
        }
        // both answers came up often
        assert!(tangent > 500 && tangent < 3500, "{tangent} of 4000 tangent");
        // two lines: on at less than a right angle, not back
        let (o, x, y) = (
            Point::new(0.0, 0.0),
            Point::new(1.0, 0.0),
            Point::new(0.0, 1.0),
        );
        assert!(meet_only_at_the_joint(
            &Seg::line(o - x, o),
            &Seg::line(o, x + y),
            eps
        ));
        assert!(!meet_only_at_the_joint(
            &Seg::line(o - x, o),
            &Seg::line(o, y - x),
            eps
        ));
    }
}
