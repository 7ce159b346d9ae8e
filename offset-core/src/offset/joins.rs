//! Miter and chamfer joins: each surviving whole round join (an arc about an input corner,
//! tangent to both neighbours) is replaced by the neighbours' tangents extended to meet, cut
//! at the miter limit, or by the straight line across it.

use super::seg::Seg;
use super::{Join, OffsetOptions};

/// Replaces the whole round joins in `segs` as `opts.join` asks.
pub fn apply(segs: Vec<Seg>, whole_join: &[bool], opts: &OffsetOptions) -> Vec<Seg> {
    if opts.join == Join::Round {
        return segs;
    }
    let mut out = Vec::with_capacity(segs.len() + 8);
    for (s, &wj) in segs.iter().zip(whole_join) {
        if !wj || !s.is_arc() {
            out.push(*s);
            continue;
        }
        let (p1, p2) = (s.a, s.b);
        let half = s.sw.abs() * 0.5;
        let (cos_h, sin_h) = (half.cos(), half.sin());
        let r = s.r;
        if opts.join == Join::Chamfer || sin_h <= 0.0 {
            out.push(Seg::line(p1, p2));
            continue;
        }
        let limit = if opts.miter_limit.is_finite() {
            opts.miter_limit.max(0.0)
        } else {
            f64::MAX
        };
        let apex_dir = (s.point_at(0.5) - s.c).unit();
        if cos_h > 1e-12 && 1.0 / cos_h <= limit {
            let m = s.c + apex_dir * (r / cos_h);
            out.push(Seg::line(p1, m));
            out.push(Seg::line(m, p2));
            continue;
        }
        // beyond the limit: cut the miter square to its bisector at limit × distance
        let reach = limit * r;
        if reach <= r * cos_h {
            out.push(Seg::line(p1, p2));
            continue;
        }
        let k = (reach - r * cos_h) / sin_h;
        let q1 = p1 + s.tangent_at(0.0) * k;
        let q2 = p2 - s.tangent_at(1.0) * k;
        out.push(Seg::line(p1, q1));
        out.push(Seg::line(q1, q2));
        out.push(Seg::line(q2, p2));
    }
    out
}
