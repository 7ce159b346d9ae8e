//! How far what a machine cut strayed from the planned tool path.

use super::interp::Motion;
use super::machine::arc_sweep;
use super::Executed;
use offset_core::geom::PointsAlong;
use offset_core::toolpath::arc_segment;
use offset_core::{Move, Point, Segment, Toolpath, P3};

/// Spacing of the points sampled along the executed path, mm.
const SAMPLE_STEP: f64 = 0.05;
/// At most this many samples per executed move (long moves are sampled more coarsely).
const MAX_SAMPLES: usize = 2000;

enum Piece {
    Line(P3, P3),
    Arc { seg: Segment, z0: f64, z1: f64 },
}

impl Piece {
    fn xy_bounds(&self) -> (Point, Point) {
        match self {
            Piece::Line(a, b) => (
                Point::new(a.x.min(b.x), a.y.min(b.y)),
                Point::new(a.x.max(b.x), a.y.max(b.y)),
            ),
            Piece::Arc { seg, .. } => {
                let b = seg.bounds();
                (b.min, b.max)
            }
        }
    }

    fn distance(&self, p: P3) -> f64 {
        match self {
            Piece::Line(a, b) => {
                let ab = [b.x - a.x, b.y - a.y, b.z - a.z];
                let ap = [p.x - a.x, p.y - a.y, p.z - a.z];
                let l2 = ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2];
                let t = if l2 > 0.0 {
                    ((ap[0] * ab[0] + ap[1] * ab[1] + ap[2] * ab[2]) / l2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                p.dist(P3::new(a.x + ab[0] * t, a.y + ab[1] * t, a.z + ab[2] * t))
            }
            Piece::Arc { seg, z0, z1 } if z0 == z1 => {
                let q = seg.closest_point(p.xy());
                ((q.x - p.x).powi(2) + (q.y - p.y).powi(2) + (p.z - z0).powi(2)).sqrt()
            }
            Piece::Arc { seg, z0, z1 } => {
                // a helix: the nearest point lies near where its height matches the point's
                // or where its angle does; refine the best of those within half a turn
                let Segment::Arc { a, center, .. } = *seg else {
                    return f64::INFINITY;
                };
                let sweep = seg.sweep();
                let along = PointsAlong::new(seg);
                let squared = |t: f64| {
                    let q = along.at(t);
                    let z = z0 + (z1 - z0) * t;
                    (q.x - p.x).powi(2) + (q.y - p.y).powi(2) + (p.z - z).powi(2)
                };
                let mut candidates = vec![0.0, 1.0, ((p.z - z0) / (z1 - z0)).clamp(0.0, 1.0)];
                let a0 = (a - center).y.atan2((a - center).x);
                let phi = (p.y - center.y).atan2(p.x - center.x);
                let tau = std::f64::consts::TAU;
                let turns = (sweep.abs() / tau).ceil() as i64 + 1;
                for k in -turns..=turns {
                    let t = (phi + k as f64 * tau - a0) / sweep;
                    if (0.0..=1.0).contains(&t) {
                        candidates.push(t);
                    }
                }
                let (mut best_t, mut best) = (0.0, f64::INFINITY);
                for t in candidates {
                    let d = squared(t);
                    if d < best {
                        (best_t, best) = (t, d);
                    }
                }
                let half = (std::f64::consts::PI / sweep.abs()).min(1.0);
                let (lo, hi) = ((best_t - half).max(0.0), (best_t + half).min(1.0));
                best.min(golden_section_min(squared, lo, hi)).sqrt()
            }
        }
    }
}

/// The least value of `f` on [lo, hi], for `f` with one minimum there: a golden-section
/// search, one evaluation a step, narrowed to 1e-10 of the interval (48 steps).
fn golden_section_min(f: impl Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..48 {
        if f1 < f2 {
            hi = x2;
            (x2, f2) = (x1, f1);
            x1 = hi - g * (hi - lo);
            f1 = f(x1);
        } else {
            lo = x1;
            (x1, f1) = (x2, f2);
            x2 = lo + g * (hi - lo);
            f2 = f(x2);
        }
    }
    f1.min(f2)
}

struct Grid {
    min: Point,
    cell: f64,
    nx: usize,
    ny: usize,
    cells: Vec<Vec<usize>>,
}

impl Grid {
    fn new(pieces: &[Piece]) -> Grid {
        let mut lo = Point::new(f64::INFINITY, f64::INFINITY);
        let mut hi = Point::new(f64::NEG_INFINITY, f64::NEG_INFINITY);
        for p in pieces {
            let (a, b) = p.xy_bounds();
            lo = Point::new(lo.x.min(a.x), lo.y.min(a.y));
            hi = Point::new(hi.x.max(b.x), hi.y.max(b.y));
        }
        let extent = (hi.x - lo.x).max(hi.y - lo.y).max(1e-6);
        let cell = (extent / 256.0).max(0.25);
        let nx = ((hi.x - lo.x) / cell) as usize + 1;
        let ny = ((hi.y - lo.y) / cell) as usize + 1;
        let mut g = Grid {
            min: lo,
            cell,
            nx,
            ny,
            cells: vec![Vec::new(); nx * ny],
        };
        // each piece goes into the cells its points pass through (sampled every half cell,
        // so every point of it is within a quarter cell of a registered cell)
        for (i, p) in pieces.iter().enumerate() {
            let step = g.cell / 2.0;
            let samples: Vec<Point> = match p {
                Piece::Line(a, b) => {
                    let n = ((a.xy().dist(b.xy()) / step).ceil() as usize).max(1);
                    (0..=n)
                        .map(|k| a.xy().lerp(b.xy(), k as f64 / n as f64))
                        .collect()
                }
                Piece::Arc { seg, .. } => {
                    let n = ((seg.length() / step).ceil() as usize).max(1);
                    (0..=n).map(|k| seg.point_at(k as f64 / n as f64)).collect()
                }
            };
            for q in samples {
                let (x, y) = g.cell_of(q);
                let c = &mut g.cells[y * nx + x];
                if c.last() != Some(&i) {
                    c.push(i);
                }
            }
        }
        g
    }

    fn cell_of(&self, p: Point) -> (usize, usize) {
        let x = ((p.x - self.min.x) / self.cell).floor().max(0.0) as usize;
        let y = ((p.y - self.min.y) / self.cell).floor().max(0.0) as usize;
        (x.min(self.nx - 1), y.min(self.ny - 1))
    }

    fn nearest(&self, pieces: &[Piece], p: P3) -> f64 {
        // a point outside the grid starts from the nearest cell; the bound below still holds
        let (x, y) = self.cell_of(p.xy());
        let mut best = f64::INFINITY;
        let max_ring = self.nx.max(self.ny);
        for r in 0..=max_ring {
            let (x0, x1) = (x.saturating_sub(r), (x + r).min(self.nx - 1));
            let (y0, y1) = (y.saturating_sub(r), (y + r).min(self.ny - 1));
            for yy in y0..=y1 {
                for xx in x0..=x1 {
                    let on_ring = xx + r == x || xx == x + r || yy + r == y || yy == y + r;
                    if !on_ring {
                        continue;
                    }
                    for &i in &self.cells[yy * self.nx + xx] {
                        best = best.min(pieces[i].distance(p));
                    }
                }
            }
            // anything not seen yet is at least this far in plan
            if best <= (r as f64 - 0.25) * self.cell {
                break;
            }
        }
        best
    }
}

/// How far what was cut and what was planned lie apart, each way (mm).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Deviation {
    /// The worst distance from a point of the executed cuts to the planned cuts (infinite
    /// when something was cut and nothing was planned).
    pub strayed: f64,
    /// The worst distance from a point of the planned cuts to the executed cuts (infinite
    /// when something was planned and nothing was cut): a planned move left out shows here.
    pub missed: f64,
    /// The planned point that lies farthest from what was cut.
    pub missed_at: P3,
}

impl Deviation {
    /// The larger of the two.
    pub fn worst(&self) -> f64 {
        self.strayed.max(self.missed)
    }
}

/// The planned cuts (linear and arc moves) as pieces.
fn planned_pieces(planned: &Toolpath) -> Vec<Piece> {
    let mut pieces = Vec::new();
    planned.walk(P3::default(), |from, m, to| match m {
        Move::Linear { .. } => pieces.push(Piece::Line(from, to)),
        Move::Arc { center, ccw, .. } => pieces.push(Piece::Arc {
            seg: arc_segment(from.xy(), to.xy(), *center, *ccw),
            z0: from.z,
            z1: to.z,
        }),
        _ => {}
    });
    pieces
}

/// The executed cuts (linear and arc moves) as pieces.
fn executed_pieces(executed: &[Executed]) -> Vec<Piece> {
    executed
        .iter()
        .filter(|e| e.motion != Motion::Rapid)
        .map(|e| {
            let from = P3::new(e.from[0], e.from[1], e.from[2]);
            let to = P3::new(e.to[0], e.to[1], e.to[2]);
            match (e.motion, e.center) {
                (Motion::ArcCw | Motion::ArcCcw, Some(c)) => Piece::Arc {
                    seg: arc_segment(
                        from.xy(),
                        to.xy(),
                        Point::new(c[0], c[1]),
                        e.motion == Motion::ArcCcw,
                    ),
                    z0: from.z,
                    z1: to.z,
                },
                _ => Piece::Line(from, to),
            }
        })
        .collect()
}

/// Points along a piece, no farther apart than the sample step (at most 2000), ends included.
fn sample_piece(p: &Piece) -> Vec<P3> {
    match p {
        Piece::Line(a, b) => {
            let n = ((a.dist(*b) / SAMPLE_STEP).ceil() as usize).clamp(1, MAX_SAMPLES);
            (0..=n)
                .map(|i| {
                    let t = i as f64 / n as f64;
                    P3::new(
                        a.x + (b.x - a.x) * t,
                        a.y + (b.y - a.y) * t,
                        a.z + (b.z - a.z) * t,
                    )
                })
                .collect()
        }
        Piece::Arc { seg, z0, z1 } => {
            let n =
                ((seg.length().hypot(z1 - z0) / SAMPLE_STEP).ceil() as usize).clamp(1, MAX_SAMPLES);
            let along = PointsAlong::new(seg);
            (0..=n)
                .map(|i| {
                    let t = i as f64 / n as f64;
                    let q = along.at(t);
                    P3::new(q.x, q.y, z0 + (z1 - z0) * t)
                })
                .collect()
        }
    }
}

/// The worst distance from a sample of `from` to the pieces `to` (with where), infinite
/// when `from` has pieces and `to` none, 0 when `from` has none.
fn one_way(from: &[Piece], to: &[Piece]) -> (f64, P3) {
    if from.is_empty() {
        return (0.0, P3::default());
    }
    if to.is_empty() {
        return (
            f64::INFINITY,
            from.iter()
                .flat_map(sample_piece)
                .next()
                .unwrap_or_default(),
        );
    }
    let grid = Grid::new(to);
    let mut worst = (0.0, P3::default());
    for piece in from {
        for p in sample_piece(piece) {
            let d = grid.nearest(to, p);
            if d > worst.0 {
                worst = (d, p);
            }
        }
    }
    worst
}

/// How far the executed cuts and the planned cuts (linear and arc moves, sampled every
/// 0.05 mm but at most 2000 times a move, arcs followed exactly) lie from each other, both
/// ways. Rapids are left out on both sides: a controller may take any path between their
/// end points.
pub fn deviation(planned: &Toolpath, executed: &[Executed]) -> Deviation {
    let plan = planned_pieces(planned);
    let cut = executed_pieces(executed);
    let (strayed, _) = one_way(&cut, &plan);
    let (missed, missed_at) = one_way(&plan, &cut);
    Deviation {
        strayed,
        missed,
        missed_at,
    }
}

/// The worst distance (mm) between what was cut and what was planned, measured both ways
/// (see [`deviation`]): a point cut off the plan and a planned cut left out both count.
/// Infinite when something was cut and nothing planned, or planned and nothing cut; 0 when
/// neither has a cut.
pub fn max_deviation(planned: &Toolpath, executed: &[Executed]) -> f64 {
    deviation(planned, executed).worst()
}

/// The worst distance (mm) from a point of the executed cuts to the planned cuts only:
/// what a partial run (a job cancelled or resumed half-way) can be held to.
pub fn max_stray(planned: &Toolpath, executed: &[Executed]) -> f64 {
    deviation(planned, executed).strayed
}

/// Points along an executed move, no farther apart than the sample step, ends included.
pub fn sample_executed(e: &Executed) -> Vec<P3> {
    let from = P3::new(e.from[0], e.from[1], e.from[2]);
    let to = P3::new(e.to[0], e.to[1], e.to[2]);
    match (e.motion, e.center) {
        (Motion::ArcCw | Motion::ArcCcw, Some(c)) => {
            let ccw = e.motion == Motion::ArcCcw;
            let sweep = arc_sweep(e.from, e.to, c, ccw);
            let r = (e.from[0] - c[0]).hypot(e.from[1] - c[1]);
            let a0 = (e.from[1] - c[1]).atan2(e.from[0] - c[0]);
            let n = ((r * sweep.abs()).hypot(to.z - from.z) / SAMPLE_STEP).ceil() as usize;
            let n = n.clamp(1, MAX_SAMPLES);
            (0..=n)
                .map(|i| {
                    let t = i as f64 / n as f64;
                    let ang = a0 + sweep * t;
                    P3::new(
                        c[0] + r * ang.cos(),
                        c[1] + r * ang.sin(),
                        from.z + (to.z - from.z) * t,
                    )
                })
                .collect()
        }
        _ => {
            let n = ((from.dist(to) / SAMPLE_STEP).ceil() as usize).clamp(1, MAX_SAMPLES);
            (0..=n)
                .map(|i| {
                    let t = i as f64 / n as f64;
                    P3::new(
                        from.x + (to.x - from.x) * t,
                        from.y + (to.y - from.y) * t,
                        from.z + (to.z - from.z) * t,
                    )
                })
                .collect()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ex(motion: Motion, from: [f64; 3], to: [f64; 3], center: Option<[f64; 2]>) -> Executed {
        Executed {
            index: 1,
            line: String::new(),
            motion,
            from,
            to,
            center,
            feed: 100.0,
        }
    }

    #[test]
    fn deviation_measures_offsets_of_lines_arcs_and_helices() {
        let mut tp = Toolpath::new("t");
        tp.push(Move::Rapid {
            to: P3::new(10.0, 0.0, 0.0),
        });
        tp.push(Move::Arc {
            to: P3::new(10.0, 0.0, -2.0),
            center: Point::new(0.0, 0.0),
            ccw: true,
            feed: 100.0,
        });
        tp.push(Move::Linear {
            to: P3::new(20.0, 0.0, -2.0),
            feed: 100.0,
        });
        // the same helix: no deviation of what was cut (only the helix was run, so measured
        // both ways the line after it, 10 mm long, is missed)
        let same = ex(
            Motion::ArcCcw,
            [10.0, 0.0, 0.0],
            [10.0, 0.0, -2.0],
            Some([0.0, 0.0]),
        );
        assert!(max_stray(&tp, std::slice::from_ref(&same)) < 1e-6);
        assert!((max_deviation(&tp, std::slice::from_ref(&same)) - 10.0).abs() < 1e-6);
        // the helix 0.1 mm larger in radius
        let wide = ex(
            Motion::ArcCcw,
            [10.1, 0.0, 0.0],
            [10.1, 0.0, -2.0],
            Some([0.0, 0.0]),
        );
        assert!((max_stray(&tp, &[wide]) - 0.1).abs() < 1e-3);
        // the helix run flat at the start height: near the end of the turn the helix is
        // almost 2 mm below, until the flat circle comes back near the helix's start
        let flat = ex(
            Motion::ArcCcw,
            [10.0, 0.0, 0.0],
            [10.0, 0.0, 0.0],
            Some([0.0, 0.0]),
        );
        let d = max_stray(&tp, &[flat]);
        assert!(d > 1.9 && d < 2.0, "{d}");
        // a line 0.3 mm above the planned one
        let high = ex(Motion::Linear, [10.0, 0.0, -1.7], [20.0, 0.0, -1.7], None);
        assert!((max_stray(&tp, &[high]) - 0.3).abs() < 1e-6);
        // rapids do not count; cuts with nothing planned are infinitely off, and so is a
        // plan of which nothing was cut
        let rapid = ex(Motion::Rapid, [50.0, 50.0, 5.0], [60.0, 50.0, 5.0], None);
        assert_eq!(max_stray(&tp, std::slice::from_ref(&rapid)), 0.0);
        assert!(max_deviation(&tp, &[rapid]).is_infinite());
        assert!(max_deviation(&tp, &[]).is_infinite());
        assert!(max_deviation(&Toolpath::new("empty"), std::slice::from_ref(&same)).is_infinite());
        assert_eq!(max_deviation(&Toolpath::new("empty"), &[]), 0.0);
    }

    #[test]
    fn a_planned_cut_left_out_is_a_deviation() {
        let mut tp = Toolpath::new("two passes");
        tp.push(Move::Rapid {
            to: P3::new(0.0, 0.0, 1.0),
        });
        for z in [-1.0, -2.0] {
            tp.push(Move::Linear {
                to: P3::new(0.0, 0.0, z),
                feed: 100.0,
            });
            tp.push(Move::Linear {
                to: P3::new(10.0, 0.0, z),
                feed: 100.0,
            });
            tp.push(Move::Rapid {
                to: P3::new(0.0, 0.0, 1.0),
            });
        }
        let first = [
            ex(Motion::Linear, [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], None),
            ex(Motion::Linear, [0.0, 0.0, -1.0], [10.0, 0.0, -1.0], None),
        ];
        // the second depth pass skipped: nothing cut strays, the whole of it is missed
        let d = deviation(&tp, &first);
        assert!(d.strayed < 1e-9, "{d:?}");
        assert!((d.missed - 1.0).abs() < 1e-9, "{d:?}");
        assert!((d.missed_at.z + 2.0).abs() < 1e-9, "{d:?}");
        let mut both = first.to_vec();
        both.push(ex(Motion::Rapid, [10.0, 0.0, -1.0], [0.0, 0.0, 1.0], None));
        both.push(ex(Motion::Linear, [0.0, 0.0, 1.0], [0.0, 0.0, -2.0], None));
        both.push(ex(
            Motion::Linear,
            [0.0, 0.0, -2.0],
            [10.0, 0.0, -2.0],
            None,
        ));
        assert!(deviation(&tp, &both).missed < 1e-9);
    }
}
