//! Entries: how the tool goes down into the material at the start of a pass (a helix, a ramp along the pass, or straight down), never steeper than the ramp angle.
//!
//! The operations descend through air at the plunge feed down to the floor the last depth
//! pass left (the stock top for the first), and from there into the material by one of:
//! - a helix: half-turn arcs about a centre beside the pass, tangent to it at its start,
//!   descending at most the ramp angle, then one flat turn at the depth, ending where the
//!   pass starts and heading its way (the operation checks it has room for the circle);
//! - a ramp around a closed pass: along the pass from its start, descending at the ramp
//!   angle until the depth is reached; the pass then starts there;
//! - a ramp back and forth (zig-zag) along the first stretch of a pass, an even number of
//!   legs, so it ends at the pass's start at the depth.
//!
//! Where neither fits (a pass shorter than the tool diameter), the tool plunges, and the
//! operation says so in the tool path's warnings.

use crate::geom::{Point, Polyline, Segment, Vertex};
use crate::toolpath::{Move, P3};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::str::FromStr;

/// How the tool goes down into the material at the start of a pass.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Entry {
    /// Straight down at the plunge feed (for tools that cut at the centre, or drilled
    /// starting holes).
    Plunge,
    /// Down along the pass at the ramp angle.
    Ramp,
    /// Down a helix at the ramp angle where one fits, else as [`Entry::Ramp`], else
    /// straight down with a warning.
    #[default]
    Helix,
}

impl FromStr for Entry {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "plunge" => Ok(Entry::Plunge),
            "ramp" => Ok(Entry::Ramp),
            "helix" => Ok(Entry::Helix),
            _ => Err(format!("entry \"{s}\" is none of plunge, ramp, helix")),
        }
    }
}

impl std::fmt::Display for Entry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Entry::Plunge => "plunge",
            Entry::Ramp => "ramp",
            Entry::Helix => "helix",
        })
    }
}

/// The part of `s` between lengths `l0` and `l1` along it (0 ≤ l0 < l1 ≤ its length).
pub(crate) fn part(s: Segment, l0: f64, l1: f64) -> Segment {
    let len = s.length();
    if len <= 0.0 {
        return s;
    }
    let (t0, t1) = ((l0 / len).clamp(0.0, 1.0), (l1 / len).clamp(0.0, 1.0));
    let a = if t0 == 0.0 { s.start() } else { s.point_at(t0) };
    let b = if t1 == 1.0 { s.end() } else { s.point_at(t1) };
    s.with_ends(a, b)
}

/// `s` run the other way.
pub(crate) fn reversed(s: Segment) -> Segment {
    match s {
        Segment::Line { a, b } => Segment::Line { a: b, b: a },
        Segment::Arc {
            a,
            b,
            center,
            radius,
            ccw,
        } => Segment::Arc {
            a: b,
            b: a,
            center,
            radius,
            ccw: !ccw,
        },
    }
}

/// `s` as a cutting move from wherever the tool is (at the start of `s`) to height `z1` at
/// its end, the height changing evenly along it (an arc whose height changes is a
/// helical arc).
pub(crate) fn descend(s: Segment, z1: f64, feed: f64) -> Move {
    match s {
        Segment::Line { b, .. } => Move::Linear {
            to: P3::at_z(b, z1),
            feed,
        },
        Segment::Arc { b, center, ccw, .. } => Move::Arc {
            to: P3::at_z(b, z1),
            center,
            ccw,
            feed,
        },
    }
}

/// The bulge of segment `s`.
fn bulge(s: &Segment) -> f64 {
    match s {
        Segment::Line { .. } => 0.0,
        Segment::Arc { .. } => (s.sweep() / 4.0).tan(),
    }
}

/// The closed loop restarted `l` mm into its segment `i` (split there).
pub(crate) fn restart(pl: &Polyline, i: usize, l: f64) -> Polyline {
    let n = pl.len();
    let seg = pl.segment(i);
    let len = seg.length();
    if l <= 1e-12 {
        return Polyline::new((0..n).map(|k| pl.vertices[(i + k) % n]).collect(), true);
    }
    if l >= len - 1e-12 {
        return Polyline::new((0..n).map(|k| pl.vertices[(i + 1 + k) % n]).collect(), true);
    }
    let (head, tail) = (part(seg, 0.0, l), part(seg, l, len));
    let q = tail.start();
    let mut vs = Vec::with_capacity(n + 1);
    vs.push(Vertex::new(q.x, q.y, bulge(&tail)));
    for k in 1..n {
        vs.push(pl.vertices[(i + k) % n]);
    }
    let v = pl.vertices[i];
    vs.push(Vertex::new(v.x, v.y, bulge(&head)));
    Polyline::new(vs, true)
}

/// A ramp around the closed loop `pl` from its start at `z_top` down to `z`, no steeper
/// than `slope` (dz per mm along the loop): the moves, and the loop restarted where the
/// ramp reaches `z`.
pub(crate) fn ramp_around(
    pl: &Polyline,
    z_top: f64,
    z: f64,
    slope: f64,
    feed: f64,
) -> (Vec<Move>, Polyline) {
    let n = pl.segment_count();
    let need = (z_top - z) / slope;
    let mut moves = Vec::new();
    if n == 0 || need <= 0.0 || pl.length() <= 0.0 {
        return (moves, pl.clone());
    }
    let mut walked = 0.0;
    let mut zc = z_top;
    let mut k = 0usize;
    loop {
        let i = k % n;
        let seg = pl.segment(i);
        let len = seg.length();
        if walked + len >= need - 1e-12 {
            let l = (need - walked).max(0.0);
            if l > 1e-12 {
                moves.push(descend(part(seg, 0.0, l), z, feed));
            }
            return (moves, restart(pl, i, l));
        }
        zc -= len * slope;
        walked += len;
        if len > 0.0 {
            moves.push(descend(seg, zc, feed));
        }
        k += 1;
    }
}

/// The segments of the first `len` mm of `path`.
pub(crate) fn prefix(path: &Polyline, len: f64) -> Vec<Segment> {
    let mut out = Vec::new();
    let mut at = 0.0;
    for s in path.segments() {
        let l = s.length();
        if at + l >= len {
            if len - at > 1e-12 {
                out.push(part(s, 0.0, len - at));
            }
            break;
        }
        if l > 0.0 {
            out.push(s);
        }
        at += l;
    }
    out
}

/// Back along the first `len` mm of `path` (from there to its start) at height `z`: the
/// way home after a ramp that went on along the pass's start.
pub(crate) fn back_along(path: &Polyline, len: f64, z: f64, feed: f64) -> Vec<Move> {
    let total = path.length();
    let mut moves = Vec::new();
    if total <= 0.0 {
        return moves;
    }
    // a ramp longer than the loop went round it: only the last lap's part is to go back
    let len = len % total;
    for s in prefix(path, len).into_iter().rev() {
        moves.push(descend(reversed(s), z, feed));
    }
    moves
}

/// A ramp back and forth along the first `room` mm of `path`, from its start at `z_top`
/// down to `z`, no steeper than `slope`, in an even number of legs so it ends at the start:
/// each leg as long as one leg at the full slope needs, or `room` if that is less.
pub(crate) fn zigzag(
    path: &Polyline,
    room: f64,
    z_top: f64,
    z: f64,
    slope: f64,
    feed: f64,
) -> Vec<Move> {
    let drop = z_top - z;
    if drop <= 0.0 {
        return Vec::new();
    }
    let leg = room.min(drop / slope);
    if leg <= 0.0 {
        return Vec::new();
    }
    let mut legs = (drop / (leg * slope) - 1e-9).ceil().max(1.0) as usize;
    legs += legs % 2;
    let fwd = prefix(path, leg);
    let total: f64 = fwd.iter().map(|s| s.length()).sum();
    let dz = drop / legs as f64;
    let mut moves = Vec::new();
    let mut zc = z_top;
    for k in 0..legs {
        let segs: Vec<Segment> = if k % 2 == 0 {
            fwd.clone()
        } else {
            fwd.iter().rev().map(|&s| reversed(s)).collect()
        };
        for s in segs {
            zc -= dz * s.length() / total;
            moves.push(descend(s, zc.max(z), feed));
        }
    }
    // the last move ends exactly at the depth
    if let Some(Move::Linear { to, .. } | Move::Arc { to, .. }) = moves.last_mut() {
        to.z = z;
    }
    moves
}

/// A helix about `c` through `q`, turning counter-clockwise when `ccw`, from `z_top` down
/// to `z` in half turns no steeper than `slope`, an even number of them so it ends at `q`,
/// then one flat turn at `z`.
pub(crate) fn helix(
    q: Point,
    c: Point,
    ccw: bool,
    z_top: f64,
    z: f64,
    slope: f64,
    feed: f64,
) -> Vec<Move> {
    let rho = q.dist(c);
    let half = PI * rho;
    let drop = (z_top - z).max(0.0);
    let mut k = (drop / (half * slope) - 1e-9).ceil().max(2.0) as usize;
    k += k % 2;
    let dz = drop / k as f64;
    let far = c * 2.0 - q;
    let mut moves = Vec::with_capacity(k + 2);
    for i in 0..k + 2 {
        let to = if i % 2 == 0 { far } else { q };
        let zi = if i < k {
            z_top - dz * (i + 1) as f64
        } else {
            z
        };
        moves.push(Move::Arc {
            to: P3::at_z(to, zi),
            center: c,
            ccw,
            feed,
        });
    }
    moves
}

/// The plunges an operation had to make where no entry fitted: how many, and the first.
#[derive(Debug, Default)]
pub(crate) struct Plunges {
    count: usize,
    first: Option<P3>,
}

impl Plunges {
    pub fn note(&mut self, at: P3) {
        self.count += 1;
        self.first.get_or_insert(at);
    }
    /// The warning for the tool path, if any plunge was made.
    pub fn warning(&self, why: &str) -> Option<String> {
        let at = self.first?;
        Some(format!(
            "the tool went straight down into the material {} time{} (the first at ({:.3}, {:.3}) down to Z{:.3}): {why}",
            self.count,
            if self.count == 1 { "" } else { "s" },
            at.x,
            at.y,
            at.z
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn slope_of(from: P3, m: &Move, to: P3) -> f64 {
        let xy = match m {
            Move::Arc { center, ccw, .. } => {
                crate::toolpath::arc_segment(from.xy(), to.xy(), *center, *ccw).length()
            }
            _ => from.xy().dist(to.xy()),
        };
        (from.z - to.z) / xy
    }

    fn walk(start: P3, moves: &[Move]) -> Vec<(P3, Move, P3)> {
        let mut out = Vec::new();
        let mut at = start;
        for m in moves {
            if let Move::Linear { to, .. } | Move::Arc { to, .. } = m {
                out.push((at, m.clone(), *to));
                at = *to;
            }
        }
        out
    }

    #[test]
    fn a_helix_ends_where_it_began_at_depth_never_steeper_than_asked() {
        let q = Point::new(10.0, 0.0);
        let moves = helix(q, Point::new(8.5, 0.0), true, 0.0, -2.0, 0.05, 500.0);
        let w = walk(P3::at_z(q, 0.0), &moves);
        for (a, m, b) in &w {
            assert!(slope_of(*a, m, *b) <= 0.05 + 1e-12);
            assert!((b.xy().dist(Point::new(8.5, 0.0)) - 1.5).abs() < 1e-12);
        }
        let last = w.last().unwrap().2;
        assert!(last.xy().dist(q) < 1e-12 && (last.z + 2.0).abs() < 1e-12);
        // the last two half turns are flat
        assert!(w[w.len() - 2..]
            .iter()
            .all(|(a, _, b)| a.z == -2.0 && b.z == -2.0));
    }

    #[test]
    fn a_ramp_around_a_square_reaches_depth_and_restarts_the_loop_there() {
        let sq = Polyline::rect(Point::new(0.0, 0.0), Point::new(10.0, 10.0));
        let (moves, rest) = ramp_around(&sq, 0.0, -1.0, 0.02, 500.0);
        // 1 mm at 0.02 per mm takes 50 mm: a lap and a quarter
        let w = walk(P3::new(0.0, 0.0, 0.0), &moves);
        let len: f64 = w.iter().map(|(a, _, b)| a.xy().dist(b.xy())).sum();
        assert!((len - 50.0).abs() < 1e-9);
        assert!(w
            .iter()
            .all(|(a, m, b)| slope_of(*a, m, *b) <= 0.02 + 1e-12));
        let end = w.last().unwrap().2;
        assert!(end.xy().dist(Point::new(10.0, 0.0)) < 1e-9 && (end.z + 1.0).abs() < 1e-12);
        assert!(rest.vertices[0].pos().dist(end.xy()) < 1e-9);
        assert!((rest.area() - sq.area()).abs() < 1e-9);
    }

    #[test]
    fn a_zigzag_ends_at_the_start_of_its_path() {
        let line = Polyline::from_points(&[Point::new(0.0, 0.0), Point::new(30.0, 0.0)], false);
        let moves = zigzag(&line, 5.0, 0.0, -1.0, 0.05, 500.0);
        let w = walk(P3::new(0.0, 0.0, 0.0), &moves);
        assert_eq!(w.len(), 4, "1 mm at 0.05 over legs of 5 mm: four legs");
        assert!(w
            .iter()
            .all(|(a, m, b)| slope_of(*a, m, *b) <= 0.05 + 1e-12));
        let end = w.last().unwrap().2;
        assert_eq!(end, P3::new(0.0, 0.0, -1.0));
        assert!(w.iter().all(|(_, _, b)| b.x <= 5.0 + 1e-12));
    }

    #[test]
    fn entries_parse_by_name() {
        assert_eq!("helix".parse::<Entry>(), Ok(Entry::Helix));
        assert_eq!(" Ramp".parse::<Entry>(), Ok(Entry::Ramp));
        assert_eq!("plunge".parse::<Entry>(), Ok(Entry::Plunge));
        assert!("dive".parse::<Entry>().unwrap_err().contains("none of"));
        assert_eq!(Entry::default(), Entry::Helix);
    }
}
