//! The raw offset of one path: every segment moved sideways (lines stay lines, arcs stay
//! concentric arcs, collapsed arcs become a throw-away chord), neighbours that interfere
//! trimmed to their intersection (the pair-wise interference step, which removes the
//! local invalid loops before the curve exists), and round joins at convex corners.

use super::seg::{intersect, wrap, Seg};
use crate::geom::Point;
use std::f64::consts::PI;

/// What a raw segment is the offset of.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Origin {
    /// the offset of input segment `seg`
    Offset,
    /// the round join about an input vertex
    Join,
}

/// A segment of a raw offset curve.
#[derive(Clone, Copy, Debug)]
pub struct RawSeg {
    pub seg: Seg,
    pub origin: Origin,
}

/// The signed turn (radians, in (-π, π]) from tangent `t1` to tangent `t2`.
fn turn(t1: Point, t2: Point) -> f64 {
    t1.cross(t2).atan2(t1.dot(t2))
}

/// Offsets one cleaned path's segments by `o` to the left of travel (negative: right).
/// `closed` joins the last segment to the first. `eps` is the geometric tolerance.
pub fn raw_offset(segs: &[Seg], closed: bool, o: f64, eps: f64) -> Vec<RawSeg> {
    let m = segs.len();
    let mut off: Vec<Seg> = segs.iter().map(|s| offset_seg(s, o)).collect();
    if m == 0 {
        return Vec::new();
    }
    // joins[k]: what connects off[k] to off[k+1]
    let mut joins: Vec<Option<Seg>> = vec![None; m];
    let corners = if closed { m } else { m - 1 };
    for k in 0..corners {
        let k2 = (k + 1) % m;
        let v = segs[k].b;
        let t1 = segs[k].tangent_at(1.0);
        let t2 = segs[k2].tangent_at(0.0);
        let th = turn(t1, t2);
        let p1 = off[k].b;
        let p2 = off[k2].a;
        let collinear = th.abs() <= 1e-12 || (p1.dist(p2) <= eps && th.abs() < PI * 0.5);
        if collinear {
            if p1.dist(p2) > 0.0 {
                joins[k] = Some(Seg::line(p1, p2));
            }
            continue;
        }
        let concave = th * o > 0.0 && th.abs() < PI - 1e-12;
        if concave {
            // pair-wise interference: trim both to their meeting point nearest the corner
            let h =
                if !off[k].is_arc() && !off[k2].is_arc() && !segs[k].is_arc() && !segs[k2].is_arc()
                {
                    // two lines: their offsets meet on the corner's bisector, at the miter point;
                    // computed directly it stays exact for nearly parallel neighbours
                    let (n1, n2) = (t1.perp(), t2.perp());
                    let x = v + (n1 + n2) * (o / (1.0 + n1.dot(n2)));
                    let (t, u) = (off[k].param(x), off[k2].param(x));
                    let (e1, e2) = (
                        eps / off[k].length().max(eps),
                        eps / off[k2].length().max(eps),
                    );
                    let mut h = super::seg::Hits::default();
                    if t >= -e1 && t <= 1.0 + e1 && u >= -e2 && u <= 1.0 + e2 {
                        h.n = 1;
                        h.p[0] = (x, t.clamp(0.0, 1.0), u.clamp(0.0, 1.0));
                    }
                    h
                } else {
                    intersect(&off[k], &off[k2], eps)
                };
            let best = h
                .iter()
                .filter(|&(_, t, u)| t >= 0.0 && u >= 0.0)
                .min_by(|x, y| x.0.dist(v).total_cmp(&y.0.dist(v)));
            if let Some((x, t, u)) = best {
                let a = &off[k];
                off[k] = a.sub(0.0, a.a, t, x);
                let b = &off[k2];
                off[k2] = b.sub(u, x, 1.0, b.b);
                continue;
            }
        }
        joins[k] = Some(join_arc(v, p1, p2, o, concave));
    }
    let mut out = Vec::with_capacity(2 * m);
    for k in 0..m {
        if off[k].length() > eps * 1e-3 {
            out.push(RawSeg {
                seg: off[k],
                origin: Origin::Offset,
            });
        }
        if let Some(j) = joins[k] {
            if j.length() > eps * 1e-3 {
                out.push(RawSeg {
                    seg: j,
                    origin: Origin::Join,
                });
            }
        }
    }
    out
}

/// The arc about the corner `v` from `p1` to `p2`: the convex way for `o` when `concave` is
/// false (a reversal turns to the offset side), the short way otherwise.
fn join_arc(v: Point, p1: Point, p2: Point, o: f64, concave: bool) -> Seg {
    let v1 = p1 - v;
    let v2 = p2 - v;
    let mut sw = v1.cross(v2).atan2(v1.dot(v2));
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
    let r = (v1.len() + v2.len()) * 0.5;
    if r == 0.0 || sw == 0.0 {
        return Seg::line(p1, p2);
    }
    // the arc through p1 and p2 with this sweep (centre at v when both are at distance r)
    let chord = p1.dist(p2);
    if chord == 0.0 {
        return Seg::line(p1, p2);
    }
    Seg::from_bulge(p1, p2, (sw / 4.0).tan())
}

/// One segment moved by `o` to its left. An arc whose radius would fall to zero or below
/// becomes the chord between its moved ends: every point of it lies nearer the input than
/// |o|, so the pruning drops it.
pub fn offset_seg(s: &Seg, o: f64) -> Seg {
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
                sa: s.sa,
                sw: s.sw,
            }
        } else {
            Seg::line(a, b)
        }
    } else {
        let n = (s.b - s.a).unit().perp() * o;
        Seg::line(s.a + n, s.b + n)
    }
}
