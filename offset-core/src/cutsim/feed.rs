//! Feed that follows the load: a tool path's level cuts split where the simulated engagement changes and each piece given the feed at which the chip is as thick as the full feed makes it at the nominal engagement, within the machine's largest feed.
//!
//! The chip a tooth takes at feed per tooth f_z and engagement φ is at most
//! f_z · sin φ thick while φ < 90° and f_z from 90° on (radial chip thinning). A piece whose
//! largest engagement is φ gets the feed f · k(φ₀) / k(φ), k(φ) = sin(min(φ, 90°)), where f
//! is the programmed feed and φ₀ the nominal engagement (the step-over's,
//! arccos(1 − 2s/D)); rounded down to a 3 % ladder so neighbouring pieces of nearly equal
//! load share one feed, never above `max_feed`; a piece in air runs at `max_feed`. Pieces
//! shorter than `min_piece` are merged into the slower neighbour. Entries, plunges and
//! rapids keep their feed.

use super::{simulate, MoveKind, SimError, SimOptions, Stock};
use crate::geom::Point;
use crate::toolpath::{Move, Toolpath, P3};
use serde::{Deserialize, Serialize};

/// The ratio between neighbouring feeds of the ladder.
const LADDER: f64 = 1.03;

/// What feed control needs besides the simulation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeedControl {
    /// The largest feed the machine runs, mm/min.
    pub max_feed: f64,
    /// The shortest piece a move is split into, mm.
    pub min_piece: f64,
    /// Side of a simulation cell, mm (0: the tool diameter / 60).
    pub cell: f64,
}

impl Default for FeedControl {
    fn default() -> Self {
        FeedControl {
            max_feed: crate::stats::Kinematics::default().max_feed,
            min_piece: 1.0,
            cell: 0.0,
        }
    }
}

/// A contour-parallel pocket whose feed follows the load (`--op pocket --feed-control`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeedControlledPocket {
    pub pocket: crate::ops::PocketParams,
    pub feed_control: FeedControl,
}

/// Plans the pocket, simulates it on a block over the shape, and scales its level cuts'
/// feeds to the load (see the module); a comment at the start gives the estimated time at
/// the programmed feeds and after.
pub fn pocket(
    shape: &crate::geom::Shape,
    p: &FeedControlledPocket,
) -> Result<Toolpath, crate::ops::OpError> {
    let fc = &p.feed_control;
    crate::ops::positive(fc.max_feed, "the largest feed")?;
    if !(fc.min_piece.is_finite() && fc.min_piece >= 0.0) {
        return Err(crate::ops::OpError::BadParam(format!(
            "the shortest piece must be 0 mm or more, got {}",
            fc.min_piece
        )));
    }
    let tp = crate::ops::pocket(shape, &p.pocket)?;
    let d = p.pocket.cut.tool.diameter;
    let b = shape.bounds();
    let stock = Stock::block(b.min, b.max, 0.0);
    let mut o = SimOptions::new(p.pocket.cut.tool);
    o.cell = if fc.cell > 0.0 { fc.cell } else { d / 60.0 };
    o.tolerance = p.pocket.cut.tolerance.max(0.01);
    let nominal = stepover_engagement(p.pocket.stepover.mm(d), d);
    let mut out = control(&tp, &stock, &o, nominal, fc)?;
    let k = crate::stats::Kinematics {
        max_feed: fc.max_feed,
        ..Default::default()
    };
    let (before, after) = (tp.stats(&k).time(), out.stats(&k).time());
    out.moves.insert(
        0,
        Move::Comment {
            text: format!(
                "feed control: estimated {:.1} s at the programmed feeds, {:.1} s following the load (chip as at {:.1} deg, at most {} mm/min)",
                before, after, nominal, fc.max_feed
            ),
        },
    );
    out.operation = "pocket, feed following the load".into();
    Ok(out)
}

/// How thick the chip is for a given feed per tooth, relative to it, at `deg` of engagement.
pub fn chip_factor(deg: f64) -> f64 {
    deg.clamp(0.0, 90.0).to_radians().sin()
}

/// The engagement of a straight cut at step-over `s` with a tool of diameter `d`, degrees.
pub fn stepover_engagement(s: f64, d: f64) -> f64 {
    (1.0 - 2.0 * s / d).clamp(-1.0, 1.0).acos().to_degrees()
}

/// The feed for a piece whose largest engagement is `deg`: see the module.
pub fn feed_for(deg: f64, feed: f64, nominal_deg: f64, max_feed: f64) -> f64 {
    let k = chip_factor(deg);
    if k <= 1e-9 {
        return max_feed;
    }
    let want = feed * chip_factor(nominal_deg) / k;
    if want >= max_feed {
        return max_feed;
    }
    // down to the 5 % ladder about the programmed feed
    let steps = (want / feed).ln() / LADDER.ln();
    (feed * LADDER.powf(steps.floor())).min(max_feed)
}

/// The tool path with its level cuts' feeds following the load (see the module).
pub fn control(
    tp: &Toolpath,
    stock: &Stock,
    o: &SimOptions,
    nominal_deg: f64,
    fc: &FeedControl,
) -> Result<Toolpath, SimError> {
    let rep = simulate(tp, stock, o)?;
    // samples of each report, in order
    let mut by_report: Vec<Vec<(P3, f64)>> = vec![Vec::new(); rep.moves.len()];
    for s in &rep.samples {
        by_report[s.report].push((s.at, s.engagement));
    }
    let mut report_of: Vec<Option<usize>> = vec![None; tp.moves.len()];
    for (k, m) in rep.moves.iter().enumerate() {
        report_of[m.index] = Some(k);
    }
    let mut out = tp.clone();
    out.moves.clear();
    for (i, m) in tp.moves.iter().enumerate() {
        let Some(k) = report_of[i] else {
            out.moves.push(m.clone());
            continue;
        };
        let mr = &rep.moves[k];
        let feed = match m {
            Move::Linear { feed, .. } | Move::Arc { feed, .. } => *feed,
            _ => 0.0,
        };
        if mr.kind != MoveKind::Cut || feed <= 0.0 || by_report[k].is_empty() {
            out.moves.push(m.clone());
            continue;
        }
        // the feed of each step between samples: the one its end's engagement asks for
        // (read there before the tool cuts the step)
        let samples = &by_report[k];
        let mut points = vec![mr.from];
        let mut feeds = Vec::with_capacity(samples.len());
        for &(p, e) in samples {
            points.push(p);
            feeds.push(feed_for(e, feed, nominal_deg, fc.max_feed));
        }
        let pieces = merge(&points, &feeds, fc.min_piece);
        for (n, (end, f)) in pieces.iter().enumerate() {
            let last = n + 1 == pieces.len();
            let to = if last { mr.to } else { points[*end] };
            out.moves.push(match m {
                Move::Arc { center, ccw, .. } => {
                    let to = if last {
                        to
                    } else {
                        onto_arc(to, *center, mr.from)
                    };
                    Move::Arc {
                        to,
                        center: *center,
                        ccw: *ccw,
                        feed: *f,
                    }
                }
                _ => Move::Linear { to, feed: *f },
            });
        }
    }
    Ok(out)
}

/// Runs of equal feed over the steps between `points` (step i goes from point i to i + 1),
/// as (index of the point the run ends at, feed); runs shorter than `min` merged into the
/// slower neighbour.
fn merge(points: &[P3], feeds: &[f64], min: f64) -> Vec<(usize, f64)> {
    // (start point, end point, feed, length)
    let mut runs: Vec<(usize, usize, f64, f64)> = Vec::new();
    for (i, &f) in feeds.iter().enumerate() {
        let l = points[i].dist(points[i + 1]);
        match runs.last_mut() {
            Some(r) if r.2 == f => {
                r.1 = i + 1;
                r.3 += l;
            }
            _ => runs.push((i, i + 1, f, l)),
        }
    }
    // merge the shortest short run into its slower neighbour until none is short
    while runs.len() > 1 {
        let Some((k, _)) = runs
            .iter()
            .enumerate()
            .filter(|(_, r)| r.3 < min)
            .min_by(|a, b| a.1 .3.total_cmp(&b.1 .3))
        else {
            break;
        };
        let left = k.checked_sub(1);
        let right = (k + 1 < runs.len()).then_some(k + 1);
        let with = match (left, right) {
            (Some(l), Some(r)) => {
                if runs[l].2 <= runs[r].2 {
                    l
                } else {
                    r
                }
            }
            (Some(l), None) => l,
            (None, Some(r)) => r,
            (None, None) => break,
        };
        let (a, b) = (k.min(with), k.max(with));
        let merged = (
            runs[a].0,
            runs[b].1,
            runs[a].2.min(runs[b].2),
            runs[a].3 + runs[b].3,
        );
        runs[a] = merged;
        runs.remove(b);
        // neighbours of equal feed join
        if a + 1 < runs.len() && runs[a + 1].2 == runs[a].2 {
            let r = runs.remove(a + 1);
            runs[a].1 = r.1;
            runs[a].3 += r.3;
        }
        if a > 0 && runs[a - 1].2 == runs[a].2 {
            let r = runs.remove(a);
            runs[a - 1].1 = r.1;
            runs[a - 1].3 += r.3;
        }
    }
    runs.into_iter().map(|r| (r.1, r.2)).collect()
}

/// `p` moved onto the circle about `c` through `on` (a sample of a chord, onto its arc).
fn onto_arc(p: P3, c: Point, on: P3) -> P3 {
    let rho = on.xy().dist(c);
    let u = (p.xy() - c).unit();
    P3::at_z(c + u * rho, p.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_feed_keeps_the_chip_and_never_passes_the_largest() {
        let nominal = stepover_engagement(2.4, 6.0);
        assert!((nominal - 78.46).abs() < 0.01);
        // at the nominal engagement, the programmed feed
        assert_eq!(feed_for(nominal, 800.0, nominal, 5000.0), 800.0);
        // a slot: the chip is no thicker than at 90°, so barely slower
        let slot = feed_for(180.0, 800.0, nominal, 5000.0);
        assert!(
            slot <= 800.0 * chip_factor(nominal) && slot > 800.0 * chip_factor(nominal) / LADDER
        );
        // light cuts go faster, up to the largest feed; air at the largest
        let light = feed_for(20.0, 800.0, nominal, 5000.0);
        let chip = light * chip_factor(20.0) / (800.0 * chip_factor(nominal));
        assert!(chip <= 1.0 && chip > 1.0 / LADDER, "{light} {chip}");
        assert_eq!(feed_for(2.0, 800.0, nominal, 5000.0), 5000.0);
        assert_eq!(feed_for(0.0, 800.0, nominal, 5000.0), 5000.0);
    }

    #[test]
    fn short_runs_join_their_slower_neighbour() {
        let pts: Vec<P3> = (0..=10).map(|i| P3::new(i as f64, 0.0, 0.0)).collect();
        let feeds = [
            800.0, 800.0, 800.0, 900.0, 800.0, 800.0, 1000.0, 1000.0, 1000.0, 1000.0,
        ];
        let runs = merge(&pts, &feeds, 1.5);
        assert_eq!(runs, vec![(6, 800.0), (10, 1000.0)]);
    }
}
