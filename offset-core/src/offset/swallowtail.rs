//! Swallowtails resolved where the raw offset makes them. At a corner that turns to the
//! offset side, the offsets of its two neighbours normally cross and are trimmed to their
//! meeting point (`raw::pair_corner`). When the distance is larger than the stretch about
//! the corner, they do not meet: the offset folds back over the corner in a loop (a
//! swallowtail), which the global stage must find and prune. After a first stage the
//! corners between a gear's teeth make such a loop at every later stage, and each loop
//! reaches over the next tooth's, so each tooth cost five crossings and ten runs there.
//!
//! Here the loop is taken apart on the spot, as the stack does for lines: the last kept
//! piece is popped, or the next one skipped, while it is proven to lie nearer the input
//! than |o| (every point of it, not a sample: see [`within`]), until the two pieces at
//! the ends meet; the parts of those two beyond their meeting point are proven the same
//! way. Anything not proven stays as it was, for the global stage. So nothing the prune
//! would keep is lost, and what goes is what it would have dropped.

use super::raw::Origin;
use super::seg::{intersect, Norm, Seg};
use crate::geom::Point;

/// What the resolution leaves: the last `popped` kept pieces go, the next `skipped`
/// offsets are not made, the piece kept last is cut at `at` (its parameter `t`), and
/// `after`, what is kept of the next offset made, starts there.
pub(super) struct Cut {
    pub popped: usize,
    pub skipped: usize,
    pub at: Point,
    pub t: f64,
    pub after: Seg,
}

/// How many pieces one resolution may pop and skip together.
pub(super) const MOST: usize = 64;

/// Resolves the swallowtail at a corner whose neighbours' offsets do not meet: `kept` is
/// the raw offset so far (its last piece the offset into the corner) beside the origins,
/// of which all but the first may change; `ahead(b)` the `b`-th offset after the
/// corner beside the input segment it is the offset of (None where the path, or what may
/// change of it, ends). `sure`: a distance below which a point is surely too near the
/// input (|o| less the prune's slack). None when some piece cannot be proven.
pub(super) fn resolve(
    kept: &[Seg],
    origins: &[Origin],
    mut ahead: impl FnMut(usize) -> Option<(Seg, Seg)>,
    o: f64,
    eps: f64,
    sure: f64,
) -> Option<Cut> {
    // (the first piece stays: the closing corner trims it)
    let last = kept.len().checked_sub(1)?;
    if last < 1 {
        return None;
    }
    let (mut popped, mut skipped) = (0, 0);
    let (mut next, mut next_input) = ahead(0)?;
    for _ in 0..MOST {
        let k = last - popped;
        let top = kept[k];
        // a piece proven nearer the input than |o| cannot meet the other one, every point
        // of which lies |o| from its own input: so the meeting is asked only when neither
        // goes
        if k > 1 && within(&top, &next_input, sure, None, eps) {
            popped += 1;
            continue;
        }
        let top_input = feature(&top, origins[k], o)?;
        if within(&next, &top_input, sure, None, eps) {
            skipped += 1;
            (next, next_input) = ahead(skipped)?;
            continue;
        }
        // (the corner's own neighbours are known not to meet)
        if popped + skipped == 0 {
            return None;
        }
        let (x, t, u) = meeting(&top, &next, eps)?;
        let tail = top.sub(t, x, 1.0, top.b);
        let head = next.sub(0.0, next.a, u, x);
        let proven = within(&tail, &next_input, sure, Some(x), eps)
            && within(&head, &top_input, sure, Some(x), eps);
        return proven.then_some(Cut {
            popped,
            skipped,
            at: x,
            t,
            after: next.sub(u, x, 1.0, next.b),
        });
    }
    None
}

/// Where `top` (kept) and `next` meet with something of each left: the meeting last
/// along `top` that leaves no other meeting on both kept parts (`top` before it, `next`
/// after it). Cut at the other one of two, the two kept parts would cross again right by
/// their new joint, a loop the global stage does not look for between neighbours.
fn meeting(top: &Seg, next: &Seg, eps: f64) -> Option<(Point, f64, f64)> {
    let hits = intersect(top, next, eps);
    let ok = |&(_, t, u): &(Point, f64, f64)| t > 0.0 && u < 1.0;
    hits.iter()
        .filter(ok)
        .filter(|&(_, t, u)| !hits.iter().filter(ok).any(|(_, t2, u2)| t2 < t && u2 > u))
        .max_by(|x, y| x.1.total_cmp(&y.1))
}

/// The part of the input a raw piece is the offset of by `o` (to the left): a line moved
/// back, an arc about the same centre, a join's corner (a point); None for a bridge, which
/// is the offset of nothing. A part of an input segment is enough: whatever lies nearer
/// it than |o| lies nearer the input.
fn feature(r: &Seg, origin: Origin, o: f64) -> Option<Seg> {
    match origin {
        Origin::Bridge => None,
        Origin::Join => Some(Seg::line(r.c, r.c)),
        Origin::Offset if r.is_arc() => {
            // (the inverse of `raw::offset_seg`'s radius)
            let r0 = if r.sw > 0.0 { r.r + o } else { r.r - o };
            let k = r0 / r.r;
            (r0 > 0.0).then(|| Seg {
                a: r.c + (r.a - r.c) * k,
                b: r.c + (r.b - r.c) * k,
                c: r.c,
                r: r0,
                sw: r.sw,
            })
        }
        Origin::Offset => {
            let d = r.b - r.a;
            let l = d.norm();
            let n = d.perp() * (o / l);
            (l > 0.0).then(|| Seg::line(r.a - n, r.b - n))
        }
    }
}

/// Whether every point of `p` lies nearer `f` than `sure`, but for those within `eps` of
/// `except` (a meeting point, exactly |o| from `f`). The distance is largest at a point
/// among [`critical_points`], so those are all that is asked.
pub(super) fn within(p: &Seg, f: &Seg, sure: f64, except: Option<Point>, eps: f64) -> bool {
    // first the disc on the chord (which holds a piece turning at most a half turn): all
    // of it nearer than `sure` when its centre is nearer by the radius
    if p.is_arc() && except.is_none() && p.sw.abs() <= std::f64::consts::PI {
        let m = (p.a + p.b) * 0.5;
        let half = p.a.dist(m);
        if half < sure && nearer(f, m, sure - half) {
            return true;
        }
    }
    // (a distance that is not a number is not nearer; the first point too far ends it)
    critical_points(p, f, &mut |q| {
        nearer(f, q, sure) || except.is_some_and(|x| q.dist(x) <= eps)
    })
}

/// Whether `q` lies nearer `f` than `sure` (> 0): `Seg::dist` compared, its roots
/// squared away (a proof asks this of every point it finds).
#[inline]
fn nearer(f: &Seg, q: Point, sure: f64) -> bool {
    let sure2 = sure * sure;
    if f.is_arc() {
        let v = q - f.c;
        let d2 = v.dot(v);
        if d2 > 0.0 && f.within_sweep(q) {
            // |(|v| − r)| < sure
            let (low, high) = (f.r - sure, f.r + sure);
            return (low <= 0.0 || d2 > low * low) && d2 < high * high;
        }
        let (da, db) = (q - f.a, q - f.b);
        return da.dot(da).min(db.dot(db)) < sure2;
    }
    let e = f.b - f.a;
    let l2 = e.dot(e);
    let t = if l2 > 0.0 {
        ((q - f.a).dot(e) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let d = q - f.a.lerp(f.b, t);
    d.dot(d) < sure2
}

/// The points of `p` where its distance from `f` can be largest, handed to `each` until it
/// returns false (then false): its ends, and where the distance along `p` has a critical
/// point or a kink. Away from `f` itself the distance from a line, a point or an arc is
/// smooth (where the nearest point moves from an arc's sector to its end, both measures
/// meet with the same gradient), but for the ridge where the nearest point jumps from one
/// end of an arc to the other: the line through its centre square to its chord. So the
/// points asked are those on that line, and where each measure has its critical points: on
/// an arc `p`, the points farthest from each point measured from (and nearest to an arc's
/// centre, whose distance is a cone's), and the extremes across a line; on a line `p` only
/// the point nearest an arc's centre, the distance from a point or a line being convex
/// along a line.
fn critical_points(p: &Seg, f: &Seg, each: &mut impl FnMut(Point) -> bool) -> bool {
    if !(each(p.a) && each(p.b)) {
        return false;
    }
    if f.is_arc() {
        let (c, a, b) = (f.c, f.a, f.b);
        if !line_cuts(p, c, (b - a).perp(), each) {
            return false;
        }
        return if p.is_arc() {
            extremes_from(p, c, true, each)
                && extremes_from(p, a, false, each)
                && extremes_from(p, b, false, each)
        } else {
            nearest_on_line(p, c, each)
        };
    }
    if !p.is_arc() {
        return true;
    }
    if !extremes_from(p, f.a, false, each) {
        return false;
    }
    let d = f.b - f.a;
    if d.x == 0.0 && d.y == 0.0 {
        return true;
    }
    if !extremes_from(p, f.b, false, each) {
        return false;
    }
    let u = d.perp() * (p.r / d.norm());
    [p.c + u, p.c - u]
        .into_iter()
        .all(|q| !p.within_sweep(q) || each(q))
}

/// The points of `p` on the line through `o` along `dir` (as `critical_points` hands them).
fn line_cuts(p: &Seg, o: Point, dir: Point, each: &mut impl FnMut(Point) -> bool) -> bool {
    if dir.x == 0.0 && dir.y == 0.0 {
        return true;
    }
    if p.is_arc() {
        let l = dir.norm();
        let u = dir * (1.0 / l);
        let w = o - p.c;
        let half_b = w.dot(u);
        let disc = half_b * half_b - (w.dot(w) - p.r * p.r);
        if disc < 0.0 {
            return true;
        }
        let root = disc.sqrt();
        [-half_b - root, -half_b + root]
            .into_iter()
            .map(|s| o + u * s)
            .all(|q| !p.within_sweep(q) || each(q))
    } else {
        let e = p.b - p.a;
        let den = dir.cross(e);
        if den == 0.0 {
            return true;
        }
        let t = -dir.cross(p.a - o) / den;
        !(0.0..=1.0).contains(&t) || each(p.a + e * t)
    }
}

/// On the arc `p`, the point farthest from `x` and, with `nearest`, the one nearest it
/// (as `critical_points` hands them).
fn extremes_from(p: &Seg, x: Point, nearest: bool, each: &mut impl FnMut(Point) -> bool) -> bool {
    let v = p.c - x;
    let l = v.norm();
    if l == 0.0 {
        // the centre: every point of the arc is as far
        return true;
    }
    let u = v * (p.r / l);
    (!p.within_sweep(p.c + u) || each(p.c + u))
        && (!nearest || !p.within_sweep(p.c - u) || each(p.c - u))
}

/// On the line `p`, the point nearest `x` when it lies between the ends (as
/// `critical_points` hands them).
fn nearest_on_line(p: &Seg, x: Point, each: &mut impl FnMut(Point) -> bool) -> bool {
    let e = p.b - p.a;
    let l2 = e.dot(e);
    if l2 > 0.0 {
        let t = (x - p.a).dot(e) / l2;
        if t > 0.0 && t < 1.0 {
            return each(p.a + e * t);
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::uniform;

    const SAMPLES: usize = 2000;

    /// The largest distance from `p` to `f` over a dense sampling of `p`.
    fn sampled(p: &Seg, f: &Seg) -> f64 {
        (0..=SAMPLES)
            .map(|i| f.dist(p.point_at(i as f64 / SAMPLES as f64)))
            .fold(0.0, f64::max)
    }

    fn found(p: &Seg, f: &Seg) -> f64 {
        let mut m: f64 = 0.0;
        critical_points(p, f, &mut |q| {
            m = m.max(f.dist(q));
            true
        });
        m
    }

    fn random_seg(rng: &mut impl FnMut() -> f64) -> Seg {
        let mut range = |lo: f64, hi: f64| lo + (hi - lo) * rng();
        let a = Point::new(range(-5.0, 5.0), range(-5.0, 5.0));
        let b = Point::new(range(-5.0, 5.0), range(-5.0, 5.0));
        if range(0.0, 1.0) < 0.4 {
            return Seg::line(a, b);
        }
        let c = Point::new(range(-5.0, 5.0), range(-5.0, 5.0));
        let r = range(0.2, 6.0);
        let a0 = range(-3.2, 3.2);
        let sw = range(-6.0, 6.0);
        let at = |t: f64| c + Point::new(t.cos(), t.sin()) * r;
        Seg {
            a: at(a0),
            b: at(a0 + sw),
            c,
            r,
            sw,
        }
    }

    #[test]
    fn the_critical_points_find_the_largest_distance_of_any_piece_from_any_feature() {
        let mut rng = uniform(0x5a11_0771);
        for case in 0..6000 {
            let p = random_seg(&mut rng);
            let mut f = random_seg(&mut rng);
            if case % 10 == 0 {
                // a join's corner: a point
                f = Seg::line(f.a, f.a);
            }
            let (exact, dense) = (found(&p, &f), sampled(&p, &f));
            // a dense sampling can only fall short of the largest distance, and (the
            // distance changing no faster than the point moves) by at most half a step
            let step = p.length() / SAMPLES as f64;
            assert!(
                exact >= dense - 1e-9,
                "case {case}: {exact} < {dense}: {p:?} {f:?}"
            );
            assert!(
                exact <= dense + step / 2.0 + 1e-9,
                "case {case}: {exact} > {dense}: {p:?} {f:?}"
            );
        }
    }

    #[test]
    fn nearer_says_what_the_distance_says() {
        let mut rng = uniform(0x000e_a2e2);
        for case in 0..20000 {
            let f = random_seg(&mut rng);
            let f = if case % 10 == 0 {
                Seg::line(f.a, f.a)
            } else {
                f
            };
            let q = random_seg(&mut rng).a;
            for sure in [0.5, 2.0, 7.0] {
                let d = f.dist(q);
                // (a point within a rounding of the distance may be said either way)
                if (d - sure).abs() > 1e-9 {
                    assert_eq!(nearer(&f, q, sure), d < sure, "case {case}: {f:?} {q:?}");
                }
            }
        }
    }

    #[test]
    fn a_feature_is_what_its_offset_was_made_from() {
        let line = Seg::line(Point::new(0.0, 0.0), Point::new(4.0, 0.0));
        // moved 1 to the left (up): the input comes back
        let raw = Seg::line(Point::new(0.0, 1.0), Point::new(4.0, 1.0));
        let f = feature(&raw, Origin::Offset, 1.0).unwrap();
        assert!(f.a.dist(line.a) < 1e-12 && f.b.dist(line.b) < 1e-12);
        // a counter-clockwise arc of radius 3 offset 1 to its left (inwards): radius 2
        let at = |r: f64, t: f64| Point::new(r * t.cos(), r * t.sin());
        let raw = Seg {
            a: at(2.0, 0.0),
            b: at(2.0, 1.0),
            c: Point::default(),
            r: 2.0,
            sw: 1.0,
        };
        let f = feature(&raw, Origin::Offset, 1.0).unwrap();
        assert!((f.r - 3.0).abs() < 1e-12 && f.a.dist(at(3.0, 0.0)) < 1e-12);
        assert!(feature(&raw, Origin::Bridge, 1.0).is_none());
    }

    #[test]
    fn a_piece_is_within_only_when_all_of_it_is() {
        // a line 1 above the feature line, sticking out past its end by 2
        let f = Seg::line(Point::new(0.0, 0.0), Point::new(4.0, 0.0));
        let p = Seg::line(Point::new(1.0, 1.0), Point::new(6.0, 1.0));
        assert!(
            !within(&p, &f, 2.0, None, 1e-9),
            "its end lies sqrt(5) away"
        );
        assert!(within(&p, &f, 2.3, None, 1e-9));
        // an arc bulging away between two ends that are near: its middle is far
        let arc = Seg {
            a: Point::new(1.0, 1.0),
            b: Point::new(3.0, 1.0),
            c: Point::new(2.0, 1.0),
            r: 1.0,
            sw: -std::f64::consts::PI,
        };
        assert!(!within(&arc, &f, 1.5, None, 1e-9), "its top lies 2 away");
        assert!(within(&arc, &f, 2.01, None, 1e-9));
        // a meeting point exactly at the distance is let through, and only it
        let tail = Seg::line(Point::new(2.0, 1.0), Point::new(2.0, 0.5));
        assert!(within(&tail, &f, 1.0, Some(Point::new(2.0, 1.0)), 1e-9));
        assert!(!within(&tail, &f, 1.0, None, 1e-9));
    }
}
