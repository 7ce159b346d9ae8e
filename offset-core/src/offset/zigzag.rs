//! Zig-zags in the input: a path that runs back on itself for a moment and on again, so that
//! it crosses itself (or two neighbours overlap away from their joint) round a lobe that is
//! narrower than a bound. Results of this kernel before issue 13's closure fix carried them
//! (≈ 0.01 mm long and a few 1e-6 mm wide), and sliced meshes and scans can too.
//!
//! Such a lobe is cut off at its crossing: the path keeps everything else and runs straight
//! through the crossing. Every point of the lobe lies within the bound of what is kept (the
//! two boundaries are within the bound of each other, in Hausdorff distance), so the offset
//! of the repaired path lies within the bound of the exact offset of the path given. A
//! crossing round anything wider, or spanning more than `MAX_LOBE` segments, or between
//! two paths, is left alone (and refused by the input check).

use super::seg::Seg;
use super::{clean, each_crossing, Crossing};
use crate::geom::{Point, Polyline, Vertex};

/// The most segments a lobe may span.
const MAX_LOBE: usize = 64;
/// Rounds of repair: each cuts off the lobes found, then looks again.
const ROUNDS: usize = 8;
/// The most points sampled along one lobe (a longer lobe is no zig-zag).
const MAX_SAMPLES: usize = 1 << 16;

/// Cuts off every zig-zag narrower than `bound` in `paths` (cleaned segments, closed or
/// not); returns whether any was cut.
pub(super) fn remove(paths: &mut [(Vec<Seg>, bool)], eps: f64, bound: f64) -> bool {
    let mut any = false;
    for _ in 0..ROUNDS {
        let mut found: Vec<Crossing> = Vec::new();
        {
            let views: Vec<(&[Seg], bool)> =
                paths.iter().map(|(s, c)| (s.as_slice(), *c)).collect();
            let near = |a: (usize, usize), b: (usize, usize)| -> bool {
                if a.0 != b.0 {
                    return false;
                }
                let (m, closed) = (views[a.0].0.len(), views[a.0].1);
                let gap = a.1.abs_diff(b.1);
                gap <= MAX_LOBE + 1 || (closed && m - gap <= MAX_LOBE + 1)
            };
            each_crossing(&views, eps, |_, a, b| near(a, b), |c| found.push(c));
        }
        if found.is_empty() {
            break;
        }
        let mut changed = false;
        for (pi, (segs, closed)) in paths.iter_mut().enumerate() {
            let mut lobes: Vec<Lobe> = found
                .iter()
                .filter(|c| c.a.0 == pi)
                .filter_map(|c| Lobe::at(segs, *closed, c))
                .filter(|l| l.within(segs, *closed, bound))
                .collect();
            if lobes.is_empty() {
                continue;
            }
            // one wrapping lobe alone, else the ones that do not overlap, from the back so
            // the indices before them stay put
            let chosen: Vec<Lobe> = match lobes.iter().position(|l| l.wraps) {
                Some(k) => vec![lobes.swap_remove(k)],
                None => {
                    lobes.sort_by(|x, y| y.k1.cmp(&x.k1).then(x.k2.cmp(&y.k2)));
                    let mut keep: Vec<Lobe> = Vec::new();
                    for l in lobes {
                        if keep.last().is_none_or(|k| l.k2 < k.k1) {
                            keep.push(l);
                        }
                    }
                    keep
                }
            };
            let mut cut = segs.clone();
            for l in &chosen {
                cut = l.cut_off(&cut);
            }
            *segs = reclean(&cut, *closed, eps);
            changed = true;
        }
        if !changed {
            break;
        }
        any = true;
    }
    any
}

/// The stretch of a path between the two visits of a crossing: from segment `k1` at `t1`
/// to segment `k2` at `t2` (k1 < k2), forward, or (`wraps`) from `k2` on through the end of
/// a closed path to `k1`.
#[derive(Clone, Copy, Debug)]
struct Lobe {
    at: Point,
    k1: usize,
    t1: f64,
    k2: usize,
    t2: f64,
    wraps: bool,
}

impl Lobe {
    fn at(segs: &[Seg], closed: bool, c: &Crossing) -> Option<Lobe> {
        let ((k1, t1), (k2, t2)) = if c.a.1 < c.b.1 {
            ((c.a.1, c.ta), (c.b.1, c.tb))
        } else {
            ((c.b.1, c.tb), (c.a.1, c.ta))
        };
        let m = segs.len();
        let forward = k2 - k1 - 1;
        let around = m - k2 - 1 + k1;
        let wraps = closed && around < forward;
        if forward.min(if closed { around } else { usize::MAX }) > MAX_LOBE {
            return None;
        }
        Some(Lobe {
            at: c.at,
            k1,
            t1,
            k2,
            t2,
            wraps,
        })
    }

    /// The lobe's pieces, and the pieces kept next to it (up to `MAX_LOBE` segments on
    /// either side).
    fn pieces(&self, segs: &[Seg], closed: bool) -> (Vec<Seg>, Vec<Seg>) {
        let m = segs.len();
        let (s1, s2) = (segs[self.k1], segs[self.k2]);
        let head1 = s1.sub(0.0, s1.a, self.t1, self.at);
        let tail1 = s1.sub(self.t1, self.at, 1.0, s1.b);
        let head2 = s2.sub(0.0, s2.a, self.t2, self.at);
        let tail2 = s2.sub(self.t2, self.at, 1.0, s2.b);
        let mut lobe = Vec::new();
        let mut kept = Vec::new();
        if !self.wraps {
            lobe.push(tail1);
            lobe.extend_from_slice(&segs[self.k1 + 1..self.k2]);
            lobe.push(head2);
            kept.push(head1);
            kept.push(tail2);
            // kept segments before k1 and after k2, stopping at the lobe (closed) or the ends
            let room = m - (self.k2 - self.k1 + 1);
            let reach = MAX_LOBE.min(room);
            for j in 1..=reach {
                if self.k1 >= j {
                    kept.push(segs[self.k1 - j]);
                } else if closed {
                    kept.push(segs[self.k1 + m - j]);
                }
                if self.k2 + j < m {
                    kept.push(segs[self.k2 + j]);
                } else if closed {
                    kept.push(segs[self.k2 + j - m]);
                }
            }
        } else {
            lobe.push(tail2);
            lobe.extend_from_slice(&segs[self.k2 + 1..]);
            lobe.extend_from_slice(&segs[..self.k1]);
            lobe.push(head1);
            kept.push(tail1);
            kept.push(head2);
            let inner = &segs[self.k1 + 1..self.k2];
            let reach = MAX_LOBE.min(inner.len());
            kept.extend_from_slice(&inner[..reach]);
            kept.extend_from_slice(&inner[inner.len() - reach..]);
        }
        (lobe, kept)
    }

    /// Whether every point of the lobe lies within `bound` of the pieces kept beside it:
    /// sampled at most h = bound / 4 apart, and the distance to a fixed set changes by at
    /// most h / 2 between samples.
    fn within(&self, segs: &[Seg], closed: bool, bound: f64) -> bool {
        let (lobe, kept) = self.pieces(segs, closed);
        let h = bound * 0.25;
        let total: f64 = lobe.iter().map(|s| s.length()).sum();
        if !(total / h < MAX_SAMPLES as f64) {
            return false;
        }
        let reach = bound - h * 0.5;
        lobe.iter().all(|s| {
            let k = (s.length() / h).ceil().max(1.0) as usize;
            (0..=k).all(|i| {
                let q = s.point_at(i as f64 / k as f64);
                kept.iter().any(|t| t.dist(q) <= reach)
            })
        })
    }

    /// `segs` without the lobe: the path runs through the crossing.
    fn cut_off(&self, segs: &[Seg]) -> Vec<Seg> {
        let (s1, s2) = (segs[self.k1], segs[self.k2]);
        if !self.wraps {
            let mut out = Vec::with_capacity(segs.len());
            out.extend_from_slice(&segs[..self.k1]);
            out.push(s1.sub(0.0, s1.a, self.t1, self.at));
            out.push(s2.sub(self.t2, self.at, 1.0, s2.b));
            out.extend_from_slice(&segs[self.k2 + 1..]);
            out
        } else {
            let mut out = Vec::with_capacity(self.k2 - self.k1 + 1);
            out.push(s1.sub(self.t1, self.at, 1.0, s1.b));
            out.extend_from_slice(&segs[self.k1 + 1..self.k2]);
            out.push(s2.sub(0.0, s2.a, self.t2, self.at));
            out
        }
    }
}

/// The segments as a polyline cleaned again (a cut may leave a piece shorter than ε).
fn reclean(segs: &[Seg], closed: bool, eps: f64) -> Vec<Seg> {
    let mut vs: Vec<Vertex> = segs
        .iter()
        .map(|s| Vertex::new(s.a.x, s.a.y, s.bulge()))
        .collect();
    if !closed {
        if let Some(last) = segs.last() {
            vs.push(Vertex::new(last.b.x, last.b.y, 0.0));
        }
    }
    clean(&Polyline::new(vs, closed), eps)
}
