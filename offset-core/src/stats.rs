//! Planner figures of a tool path: cutting and rapid length, moves by kind, the arcs-to-lines ratio, and the machining time a trapezoidal velocity profile per move gives from the machine's feeds and acceleration.
//!
//! The time model is the one GRBL's planner uses: every move runs a trapezoid (accelerate,
//! cruise at its feed, decelerate) between its entry and exit speeds; the speed through a
//! junction of two moves is limited by the angle between them and the junction deviation
//! (a centripetal bound), the speed along an arc by its radius (v² ≤ a r), every move by
//! the machine's largest feed, and the speeds are made reachable by a backward and a
//! forward pass over the moves (a move cannot stop or speed up in less than v²/2a). The
//! machine stops wherever anything but a move comes (spindle, dwell, tool change, stop)
//! and at the end. Dwells add their seconds; tool changes and stops for the operator add
//! nothing (their time is not the machine's). With feeds and acceleration from the
//! machine's configuration the figure is what the machine takes within a few per cent; the
//! defaults ([`Kinematics::default`]) are those of a small router.

use crate::toolpath::{arc_segment, Move, Toolpath, P3};
use serde::{Deserialize, Serialize};

/// What the machine can do, for the time estimate.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Kinematics {
    /// The rapid rate, mm/min (default 5000).
    pub rapid_feed: f64,
    /// The largest feed any move runs at, mm/min (default 5000): a cutting move runs at
    /// its own feed or this, whichever is less.
    pub max_feed: f64,
    /// Acceleration (and deceleration) along every axis, mm/s² (default 500).
    pub acceleration: f64,
    /// How far a junction's path may stray from the corner, mm (GRBL's `$11`, default
    /// 0.01): it sets the speed through a corner.
    pub junction_deviation: f64,
}

impl Default for Kinematics {
    fn default() -> Self {
        Kinematics {
            rapid_feed: 5000.0,
            max_feed: 5000.0,
            acceleration: 500.0,
            junction_deviation: 0.01,
        }
    }
}

/// The figures of a plan.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PlanStats {
    /// Length of the cutting moves (lines and arcs, helical ones along their helix), mm.
    pub cutting_length: f64,
    /// Length of the rapids, mm.
    pub rapid_length: f64,
    /// Cutting moves that are straight lines (plunges and ramps included).
    pub lines: usize,
    /// Cutting moves that are arcs (helical ones included).
    pub arcs: usize,
    pub rapids: usize,
    /// Sewing: stitches and jumps.
    pub stitches: usize,
    pub jumps: usize,
    /// Estimated time at the cutting feeds, at the rapid rate, and dwelling, s.
    pub cutting_time: f64,
    pub rapid_time: f64,
    pub dwell_time: f64,
}

impl PlanStats {
    /// The whole estimated machining time, s.
    pub fn time(&self) -> f64 {
        self.cutting_time + self.rapid_time + self.dwell_time
    }
    /// Arcs per straight cutting move (None with no straight move).
    pub fn arcs_to_lines(&self) -> Option<f64> {
        (self.lines > 0).then(|| self.arcs as f64 / self.lines as f64)
    }
}

/// One move for the planner: length, the feed it asks for, its direction at both ends,
/// and the speed its own curvature allows (mm/s).
struct Leg {
    len: f64,
    v: f64,
    dir0: [f64; 3],
    dir1: [f64; 3],
    rapid: bool,
}

impl Toolpath {
    /// The planner figures of this tool path on a machine with kinematics `k`.
    pub fn stats(&self, k: &Kinematics) -> PlanStats {
        stats(self, k)
    }
}

/// The planner figures of `tp` on a machine with kinematics `k` (see the module).
pub fn stats(tp: &Toolpath, k: &Kinematics) -> PlanStats {
    // drilling cycles count as the moves they make (a path without any is taken as it is,
    // not copied)
    let expanded;
    let tp = if tp.moves.iter().any(|m| matches!(m, Move::Drill { .. })) {
        expanded = tp.expanded();
        &expanded
    } else {
        tp
    };
    let mut s = PlanStats::default();
    let a = if k.acceleration.is_finite() && k.acceleration > 0.0 {
        k.acceleration
    } else {
        Kinematics::default().acceleration
    };
    let vmax = positive(k.max_feed, 5000.0) / 60.0;
    let vrapid = positive(k.rapid_feed, 5000.0) / 60.0;
    // runs of moves between stops, planned one run at a time
    let mut run: Vec<Leg> = Vec::new();
    let flush = |run: &mut Vec<Leg>, s: &mut PlanStats| {
        for (leg, t) in run.iter().zip(plan(run, a, k.junction_deviation)) {
            if leg.rapid {
                s.rapid_time += t;
            } else {
                s.cutting_time += t;
            }
        }
        run.clear();
    };
    let mut pos = P3::default();
    for m in &tp.moves {
        let (to, feed, rapid) = match m {
            Move::Rapid { to } => (*to, f64::INFINITY, true),
            Move::Linear { to, feed } | Move::Arc { to, feed, .. } => (*to, *feed, false),
            Move::Stitch { to } => (P3::at_z(*to, pos.z), f64::INFINITY, false),
            Move::Jump { to } => (P3::at_z(*to, pos.z), f64::INFINITY, true),
            Move::Dwell { seconds } => {
                flush(&mut run, &mut s);
                s.dwell_time += seconds.max(0.0);
                continue;
            }
            _ => {
                flush(&mut run, &mut s);
                continue;
            }
        };
        let v = if rapid {
            vrapid
        } else {
            (positive(feed, f64::INFINITY) / 60.0).min(vmax)
        };
        let leg = match m {
            Move::Arc { center, ccw, .. } => {
                let seg = arc_segment(pos.xy(), to.xy(), *center, *ccw);
                let xy = seg.length();
                let dz = to.z - pos.z;
                let len = xy.hypot(dz);
                let r = pos.xy().dist(*center);
                let tan = |t: f64| {
                    let d = seg.tangent_at(t) * xy;
                    unit3([d.x, d.y, dz])
                };
                s.arcs += 1;
                s.cutting_length += len;
                Leg {
                    len,
                    // centripetal: v²/r ≤ a
                    v: v.min((a * r).sqrt()),
                    dir0: tan(0.0),
                    dir1: tan(1.0),
                    rapid: false,
                }
            }
            _ => {
                let d = [to.x - pos.x, to.y - pos.y, to.z - pos.z];
                let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                match m {
                    Move::Rapid { .. } => {
                        s.rapids += 1;
                        s.rapid_length += len;
                    }
                    Move::Jump { .. } => {
                        s.jumps += 1;
                        s.rapid_length += len;
                    }
                    Move::Stitch { .. } => {
                        s.stitches += 1;
                        s.cutting_length += len;
                    }
                    _ => {
                        s.lines += 1;
                        s.cutting_length += len;
                    }
                }
                let u = unit3(d);
                Leg {
                    len,
                    v,
                    dir0: u,
                    dir1: u,
                    rapid,
                }
            }
        };
        pos = to;
        if leg.len > 0.0 {
            run.push(leg);
        }
    }
    flush(&mut run, &mut s);
    s
}

/// `v` when it is a positive number (infinity included), else `or`.
fn positive(v: f64, or: f64) -> f64 {
    if v > 0.0 {
        v
    } else {
        or
    }
}

fn unit3(d: [f64; 3]) -> [f64; 3] {
    let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    if l > 0.0 {
        [d[0] / l, d[1] / l, d[2] / l]
    } else {
        [0.0; 3]
    }
}

/// The time of each leg of a run that starts and ends at rest: junction speeds from the
/// angle and the junction deviation, made reachable backward and forward, then a
/// trapezoid (or triangle) per leg.
fn plan(run: &[Leg], a: f64, deviation: f64) -> Vec<f64> {
    let n = run.len();
    if n == 0 {
        return Vec::new();
    }
    // speed at the junction before each leg (0 at the run's start) and after the last
    let mut vj = vec![0.0; n + 1];
    for i in 1..n {
        let (p, q) = (&run[i - 1], &run[i]);
        let cos = -(p.dir1[0] * q.dir0[0] + p.dir1[1] * q.dir0[1] + p.dir1[2] * q.dir0[2]);
        // GRBL: v² = a δ sin(θ/2) / (1 - sin(θ/2)), θ the angle between the reversed
        // incoming and the outgoing direction
        let limit = if cos < -0.999_999 {
            f64::INFINITY // straight on
        } else if cos > 0.999_999 {
            0.0 // a full reversal
        } else {
            let sin_half = ((1.0 - cos) / 2.0).sqrt();
            (a * deviation.max(0.0) * sin_half / (1.0 - sin_half)).sqrt()
        };
        vj[i] = limit.min(p.v).min(q.v);
    }
    // backward: each junction no faster than the next allows within the leg
    for i in (0..n).rev() {
        vj[i] = vj[i].min((vj[i + 1] * vj[i + 1] + 2.0 * a * run[i].len).sqrt());
    }
    // forward
    for i in 0..n {
        vj[i + 1] = vj[i + 1].min((vj[i] * vj[i] + 2.0 * a * run[i].len).sqrt());
    }
    run.iter()
        .enumerate()
        .map(|(i, leg)| trapezoid(leg.len, vj[i], vj[i + 1], leg.v, a))
        .collect()
}

/// Time to cover `d` mm starting at `v0` and ending at `v1` mm/s, cruising at no more than
/// `v` with acceleration `a` (the ends are reachable: the passes saw to it).
fn trapezoid(d: f64, v0: f64, v1: f64, v: f64, a: f64) -> f64 {
    let v = v.max(v0).max(v1);
    // the speed reached if the move only accelerated then decelerated
    let peak = ((2.0 * a * d + v0 * v0 + v1 * v1) / 2.0).sqrt();
    if peak <= v {
        (peak - v0) / a + (peak - v1) / a
    } else {
        let da = (v * v - v0 * v0) / (2.0 * a);
        let dd = (v * v - v1 * v1) / (2.0 * a);
        (v - v0) / a + (v - v1) / a + (d - da - dd) / v
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Point;

    fn k() -> Kinematics {
        Kinematics {
            rapid_feed: 6000.0,
            max_feed: 6000.0,
            acceleration: 100.0,
            junction_deviation: 0.01,
        }
    }

    #[test]
    fn one_long_line_is_a_trapezoid() {
        // 100 mm at 600 mm/min (10 mm/s), 100 mm/s²: 0.1 s up over 0.5 mm, same down,
        // 99 mm at speed: 9.9 s + 0.2 s = 10.1 s
        let mut tp = Toolpath::new("t");
        tp.push(Move::Linear {
            to: P3::new(100.0, 0.0, 0.0),
            feed: 600.0,
        });
        let s = tp.stats(&k());
        assert!((s.cutting_time - 10.1).abs() < 1e-9, "{s:?}");
        assert_eq!((s.lines, s.arcs), (1, 0));
        assert_eq!(s.arcs_to_lines(), Some(0.0));
    }

    #[test]
    fn a_short_line_never_reaches_its_feed() {
        // 1 mm at 100 mm/s² from rest to rest: a triangle, 2 sqrt(d / a) = 0.2 s
        let mut tp = Toolpath::new("t");
        tp.push(Move::Rapid {
            to: P3::new(1.0, 0.0, 0.0),
        });
        let s = tp.stats(&k());
        assert!((s.rapid_time - 0.2).abs() < 1e-9, "{s:?}");
        assert!((s.rapid_length - 1.0).abs() < 1e-12);
    }

    #[test]
    fn straight_on_junctions_keep_the_speed_and_corners_slow_it() {
        let line = |tp: &mut Toolpath, x: f64, y: f64| {
            tp.push(Move::Linear {
                to: P3::new(x, y, 0.0),
                feed: 600.0,
            })
        };
        // ten collinear pieces of 10 mm take as long as one of 100 mm
        let mut straight = Toolpath::new("t");
        for i in 1..=10 {
            line(&mut straight, 10.0 * i as f64, 0.0);
        }
        let s = straight.stats(&k());
        assert!((s.cutting_time - 10.1).abs() < 1e-9, "{s:?}");
        // a zig-zag of right angles: slower, but faster than stopping at every corner
        let mut zig = Toolpath::new("t");
        for i in 1..=10 {
            line(
                &mut zig,
                10.0 * i as f64,
                if i % 2 == 0 { 0.0 } else { 10.0 },
            );
        }
        let z = zig.stats(&k()).cutting_time;
        let stop_each = 10.0 * trapezoid(200f64.sqrt(), 0.0, 0.0, 10.0, 100.0);
        let free = 10.0 * 200f64.sqrt() / 10.0;
        assert!(
            z > free && z < stop_each,
            "{z} between {free} and {stop_each}"
        );
    }

    #[test]
    fn a_circle_as_arcs_runs_at_its_feed_and_counts_as_arcs() {
        let mut tp = Toolpath::new("t");
        tp.push(Move::Rapid {
            to: P3::new(50.0, 0.0, 0.0),
        });
        // the spindle starting stops the machine: the circle starts from rest
        tp.push(Move::Spindle { rpm: 10000.0 });
        for (x, y) in [(-50.0, 0.0), (50.0, 0.0)] {
            tp.push(Move::Arc {
                to: P3::new(x, y, 0.0),
                center: Point::new(0.0, 0.0),
                ccw: true,
                feed: 600.0,
            });
        }
        let s = tp.stats(&k());
        assert_eq!((s.arcs, s.lines, s.rapids), (2, 0, 1));
        assert_eq!(s.arcs_to_lines(), None);
        let len = std::f64::consts::TAU * 50.0;
        assert!((s.cutting_length - len).abs() < 1e-9);
        // tangent at the joint: one trapezoid over the whole circle
        assert!((s.cutting_time - (len / 10.0 + 0.1)).abs() < 1e-9, "{s:?}");
        assert!(s.time() > s.cutting_time);
    }
}
