//! The trajectory: a program's moves time-parameterised at the SYNC period, one set-point
//! per axis per cycle, within each axis's velocity, acceleration and jerk limits, on the path.
//!
//! The path (lines and helical arcs, in mm) is followed exactly: corners are not rounded, so
//! a sharp corner is passed at the speed that keeps each axis's change of velocity within one
//! cycle inside its limit, and a tangent join at the slower of its two segments' speeds.
//! Each segment has a speed cap (the feed, every axis's velocity for its direction, and on
//! arcs the centripetal acceleration and jerk). Along the path the speed follows a
//! jerk-limited profile chosen cycle by cycle with look-ahead: each cycle takes the largest
//! change of acceleration after which braking still meets every cap ahead and stops before
//! the next stop point (a dwell, the end). Braking is an exact stop in discrete time: full
//! jerk down (to the acceleration limit) while an exact stop stays possible after it, then
//! one cycle of adjustment and a constant jerk that brings speed and acceleration to zero at
//! the same cycle's end, so no stop ends with its deceleration dropping to zero in one
//! cycle. A straight run reaches its feed, a corner slows to what the limits allow, and a
//! hold or a cancel brakes along the path the same way.
//!
//! Budget per axis: the speed along the path changes at most at half the smallest axis's
//! acceleration (and jerk), leaving the other half for the centripetal acceleration of arcs
//! and for the turn at a corner, so the second difference of every axis's set-points over
//! the period never exceeds its acceleration limit.

use crate::link::OperatorReason;
use offset_core::{Move, P3};
use std::f64::consts::PI;

/// One axis's limits, in mm/s, mm/s² and mm/s³.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisLimits {
    pub velocity: f64,
    pub acceleration: f64,
    pub jerk: f64,
}

/// The limits of X, Y and Z; None for an axis no drive moves (its coordinate is planned but
/// not limited, and no set-point is sent for it).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Limits {
    pub axes: [Option<AxisLimits>; 3],
}

/// Why a program cannot be planned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error("move {unit} ({what}) has feed {feed} mm/min; it must be above 0")]
    Feed {
        unit: usize,
        what: String,
        feed: f64,
    },
    #[error("move {unit} ({what}) is not a machining move a CANopen machine runs")]
    Unsupported { unit: usize, what: String },
    #[error("move {unit} ({what}) goes to a coordinate that is not a finite number")]
    NotFinite { unit: usize, what: String },
    #[error("no axis has limits")]
    NoAxes,
}

#[derive(Clone, Copy, Debug)]
enum Geometry {
    Line {
        a: P3,
        b: P3,
    },
    Helix {
        cx: f64,
        cy: f64,
        r0: f64,
        r1: f64,
        a0: f64,
        sweep: f64,
        z0: f64,
        z1: f64,
    },
}

impl Geometry {
    /// Distance from `p` to the segment (exact for lines; for arcs at the point of the
    /// same angle, and at the ends).
    #[cfg(test)]
    fn distance(&self, p: P3) -> f64 {
        match *self {
            Geometry::Line { a, b } => {
                let d = [b.x - a.x, b.y - a.y, b.z - a.z];
                let l2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                let t = if l2 > 0.0 {
                    (((p.x - a.x) * d[0] + (p.y - a.y) * d[1] + (p.z - a.z) * d[2]) / l2)
                        .clamp(0.0, 1.0)
                } else {
                    0.0
                };
                self.point(t).dist(p)
            }
            Geometry::Helix {
                cx, cy, a0, sweep, ..
            } => {
                let ang = (p.y - cy).atan2(p.x - cx);
                let mut best = self.point(0.0).dist(p).min(self.point(1.0).dist(p));
                for k in -2..=2 {
                    let t = (ang + k as f64 * 2.0 * PI - a0) / sweep;
                    if (0.0..=1.0).contains(&t) {
                        best = best.min(self.point(t).dist(p));
                    }
                }
                best
            }
        }
    }

    fn point(&self, t: f64) -> P3 {
        match *self {
            Geometry::Line { a, b } => P3::new(
                a.x + (b.x - a.x) * t,
                a.y + (b.y - a.y) * t,
                a.z + (b.z - a.z) * t,
            ),
            Geometry::Helix {
                cx,
                cy,
                r0,
                r1,
                a0,
                sweep,
                z0,
                z1,
            } => {
                let ang = a0 + sweep * t;
                let r = r0 + (r1 - r0) * t;
                P3::new(cx + r * ang.cos(), cy + r * ang.sin(), z0 + (z1 - z0) * t)
            }
        }
    }
    /// Unit tangent at parameter t.
    fn tangent(&self, t: f64, len: f64) -> [f64; 3] {
        match *self {
            Geometry::Line { a, b } => [(b.x - a.x) / len, (b.y - a.y) / len, (b.z - a.z) / len],
            Geometry::Helix {
                r0,
                r1,
                a0,
                sweep,
                z0,
                z1,
                ..
            } => {
                let ang = a0 + sweep * t;
                let r = r0 + (r1 - r0) * t;
                let (dx, dy) = (-r * sweep * ang.sin(), r * sweep * ang.cos());
                let dz = z1 - z0;
                let n = (dx * dx + dy * dy + dz * dz).sqrt().max(1e-300);
                [dx / n, dy / n, dz / n]
            }
        }
    }
}

#[derive(Clone, Debug)]
struct Segment {
    geom: Geometry,
    /// Where the segment starts along the path, mm.
    s0: f64,
    len: f64,
    /// The highest speed anywhere on it, mm/s.
    cap: f64,
}

/// A point where the path must come to rest: a dwell (for `cycles` cycles), an operator
/// stop (a tool change or a program stop: at rest until [`Planner::release`]; `operator`
/// indexes [`Path::operator_stops`]) or the end.
#[derive(Clone, Copy, Debug)]
struct Stop {
    s: f64,
    cycles: u64,
    operator: Option<usize>,
}

/// The path of a program, with its speed caps.
#[derive(Clone, Debug)]
pub struct Path {
    segs: Vec<Segment>,
    /// The cap at the start of segment i (the corner before it); one more for the end.
    corner: Vec<f64>,
    stops: Vec<Stop>,
    /// Why the path waits at each operator stop, in path order.
    operator_stops: Vec<OperatorReason>,
    /// For each unit, the path position at which it is passed.
    unit_ends: Vec<f64>,
    start: P3,
    end: P3,
    total: f64,
}

fn describe(m: &Move) -> String {
    match m {
        Move::Rapid { to } => format!("rapid to {:.3} {:.3} {:.3}", to.x, to.y, to.z),
        Move::Linear { to, feed } => {
            format!("linear to {:.3} {:.3} {:.3} at {feed}", to.x, to.y, to.z)
        }
        Move::Arc { to, ccw, feed, .. } => format!(
            "{} arc to {:.3} {:.3} {:.3} at {feed}",
            if *ccw { "ccw" } else { "cw" },
            to.x,
            to.y,
            to.z
        ),
        other => format!("{other:?}").to_lowercase(),
    }
}

impl Path {
    /// The path through `moves` from `start`, and the caps of `limits` at `period` seconds.
    pub fn new(moves: &[Move], start: P3, limits: &Limits, period: f64) -> Result<Path, PlanError> {
        let driven: Vec<(usize, AxisLimits)> = limits
            .axes
            .iter()
            .enumerate()
            .filter_map(|(i, l)| l.map(|l| (i, l)))
            .collect();
        if driven.is_empty() {
            return Err(PlanError::NoAxes);
        }
        let amin_xy = driven
            .iter()
            .filter(|(i, _)| *i < 2)
            .map(|(_, l)| l.acceleration)
            .fold(f64::INFINITY, f64::min);
        let jmin_xy = driven
            .iter()
            .filter(|(i, _)| *i < 2)
            .map(|(_, l)| l.jerk)
            .fold(f64::INFINITY, f64::min);
        let mut segs: Vec<Segment> = Vec::new();
        let mut stops = Vec::new();
        let mut operator_stops = Vec::new();
        let mut unit_ends = Vec::with_capacity(moves.len());
        let mut pos = start;
        let mut s = 0.0;
        let vcap_dir = |u: [f64; 3]| {
            driven
                .iter()
                .map(|(i, l)| {
                    if u[*i].abs() > 1e-12 {
                        l.velocity / u[*i].abs()
                    } else {
                        f64::INFINITY
                    }
                })
                .fold(f64::INFINITY, f64::min)
        };
        for (unit, m) in moves.iter().enumerate() {
            let feed_of = |feed: f64| {
                if feed.is_finite() && feed > 0.0 {
                    Ok(feed / 60.0)
                } else {
                    Err(PlanError::Feed {
                        unit,
                        what: describe(m),
                        feed,
                    })
                }
            };
            let finite = |p: &P3| {
                if p.x.is_finite() && p.y.is_finite() && p.z.is_finite() {
                    Ok(())
                } else {
                    Err(PlanError::NotFinite {
                        unit,
                        what: describe(m),
                    })
                }
            };
            let seg = match m {
                Move::Rapid { to } => {
                    finite(to)?;
                    Some((Geometry::Line { a: pos, b: *to }, f64::INFINITY, *to))
                }
                Move::Linear { to, feed } => {
                    finite(to)?;
                    Some((Geometry::Line { a: pos, b: *to }, feed_of(*feed)?, *to))
                }
                Move::Arc {
                    to,
                    center,
                    ccw,
                    feed,
                } => {
                    finite(to)?;
                    let f = feed_of(*feed)?;
                    if !(center.x.is_finite() && center.y.is_finite()) {
                        return Err(PlanError::NotFinite {
                            unit,
                            what: describe(m),
                        });
                    }
                    let (cx, cy) = (center.x, center.y);
                    let r0 = (pos.x - cx).hypot(pos.y - cy);
                    let r1 = (to.x - cx).hypot(to.y - cy);
                    if r0 < 1e-9 || r1 < 1e-9 {
                        Some((Geometry::Line { a: pos, b: *to }, f, *to))
                    } else {
                        let a0 = (pos.y - cy).atan2(pos.x - cx);
                        let a1 = (to.y - cy).atan2(to.x - cx);
                        let mut sweep = a1 - a0;
                        if *ccw {
                            while sweep <= 1e-12 {
                                sweep += 2.0 * PI;
                            }
                        } else {
                            while sweep >= -1e-12 {
                                sweep -= 2.0 * PI;
                            }
                        }
                        let g = Geometry::Helix {
                            cx,
                            cy,
                            r0,
                            r1,
                            a0,
                            sweep,
                            z0: pos.z,
                            z1: to.z,
                        };
                        Some((g, f, *to))
                    }
                }
                Move::Dwell { seconds } => {
                    let cycles = if seconds.is_finite() && *seconds > 0.0 {
                        (seconds / period).ceil() as u64
                    } else {
                        0
                    };
                    stops.push(Stop {
                        s,
                        cycles,
                        operator: None,
                    });
                    None
                }
                // the master comes to rest and waits for the operator: a tool to load, or
                // whatever the program's stop asks
                Move::ToolChange { tool, name, .. } => {
                    stops.push(Stop {
                        s,
                        cycles: 0,
                        operator: Some(operator_stops.len()),
                    });
                    operator_stops.push(OperatorReason::LoadTool {
                        number: *tool,
                        name: name.clone(),
                    });
                    None
                }
                Move::Stop => {
                    stops.push(Stop {
                        s,
                        cycles: 0,
                        operator: Some(operator_stops.len()),
                    });
                    operator_stops.push(OperatorReason::ProgramStop);
                    None
                }
                Move::Stitch { .. }
                | Move::Jump { .. }
                | Move::Trim
                | Move::ColorChange
                | Move::ProbeToolLength { .. } => {
                    return Err(PlanError::Unsupported {
                        unit,
                        what: describe(m),
                    })
                }
                Move::Spindle { .. } | Move::Drill { .. } | Move::Comment { .. } => None,
            };
            if let Some((geom, feed, to)) = seg {
                let len = match geom {
                    Geometry::Line { a, b } => a.dist(b),
                    Geometry::Helix {
                        r0,
                        r1,
                        sweep,
                        z0,
                        z1,
                        ..
                    } => (0.5 * (r0 + r1) * sweep.abs()).hypot(z1 - z0),
                };
                if len > 1e-9 {
                    let cap = match geom {
                        Geometry::Line { .. } => feed.min(vcap_dir(geom.tangent(0.0, len))),
                        Geometry::Helix {
                            r0,
                            r1,
                            sweep,
                            z0,
                            z1,
                            ..
                        } => {
                            let r = r0.min(r1);
                            let horiz = 0.5 * (r0 + r1) * sweep.abs() / len;
                            let vert = (z1 - z0).abs() / len;
                            let kappa = horiz * horiz / r;
                            let mut cap = feed.min(vcap_dir([horiz, horiz, vert]));
                            cap = cap.min((0.5 * amin_xy / kappa).sqrt());
                            cap = cap.min((0.5 * jmin_xy / (kappa * kappa)).cbrt());
                            cap
                        }
                    };
                    segs.push(Segment {
                        geom,
                        s0: s,
                        len,
                        cap,
                    });
                    s += len;
                }
                pos = to;
            }
            unit_ends.push(s);
        }
        stops.push(Stop {
            s,
            cycles: 0,
            operator: None,
        });
        // corners: the change of direction each axis can take within one cycle
        let mut corner = vec![0.0; segs.len() + 1];
        for i in 1..segs.len() {
            let (p, n) = (&segs[i - 1], &segs[i]);
            let u1 = p.geom.tangent(1.0, p.len);
            let u2 = n.geom.tangent(0.0, n.len);
            let mut cap = p.cap.min(n.cap);
            for (ax, l) in &driven {
                let du = (u2[*ax] - u1[*ax]).abs();
                if du > 1e-9 {
                    cap = cap.min(0.5 * l.acceleration * period / du);
                }
            }
            corner[i] = cap;
        }
        if let Some(first) = segs.first() {
            corner[0] = first.cap;
        }
        Ok(Path {
            segs,
            corner,
            stops,
            operator_stops,
            unit_ends,
            start,
            end: pos,
            total: s,
        })
    }

    /// Length of the path, mm.
    pub fn length(&self) -> f64 {
        self.total
    }

    /// The point at path position `s` (clamped to the path).
    pub fn point_at(&self, s: f64) -> P3 {
        if self.segs.is_empty() || s <= 0.0 {
            return if s <= 0.0 { self.start } else { self.end };
        }
        if s >= self.total {
            return self.end;
        }
        let i = self
            .segs
            .partition_point(|g| g.s0 + g.len < s)
            .min(self.segs.len() - 1);
        self.point_in(i, s)
    }

    fn point_in(&self, i: usize, s: f64) -> P3 {
        let g = &self.segs[i];
        g.geom.point(((s - g.s0) / g.len).clamp(0.0, 1.0))
    }

    /// Where the path ends.
    pub fn end(&self) -> P3 {
        self.end
    }
}

/// The state along the path: position, speed, acceleration.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Motion {
    s: f64,
    v: f64,
    a: f64,
}

/// One cycle's output.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cycle {
    /// Where every axis should be at the SYNC that applies it, mm.
    pub position: P3,
    /// Speed along the path, mm/s.
    pub speed: f64,
    /// How many of the program's units the set-point has passed (the end of unit
    /// `passed − 1` is at or behind it).
    pub passed: usize,
}

/// Plans cycle by cycle along a [`Path`].
#[derive(Clone, Debug)]
pub struct Planner {
    path: Path,
    period: f64,
    accel: f64,
    jerk: f64,
    m: Motion,
    seg: usize,
    stop: usize,
    dwell_left: u64,
    /// At an operator stop (its index in the path's `operator_stops`) until released.
    waiting: Option<usize>,
    hold: bool,
    done: bool,
    creep: u32,
}

/// How close to a stop counts as there, mm.
const AT_STOP: f64 = 1e-5;
/// A speed (mm/s) and an acceleration (mm/s²) this small at a cycle's end are rest.
const REST_V: f64 = 1e-9;
const REST_A: f64 = 1e-6;

impl Planner {
    /// A planner for `moves` starting at `start`, one set-point every `period` seconds.
    pub fn new(
        moves: &[Move],
        start: P3,
        limits: &Limits,
        period: f64,
    ) -> Result<Planner, PlanError> {
        let path = Path::new(moves, start, limits, period)?;
        let driven = limits.axes.iter().flatten();
        let accel = 0.5
            * driven
                .clone()
                .map(|l| l.acceleration)
                .fold(f64::INFINITY, f64::min);
        let jerk = 0.5 * driven.map(|l| l.jerk).fold(f64::INFINITY, f64::min);
        let mut p = Planner {
            path,
            period,
            accel,
            jerk,
            m: Motion::default(),
            seg: 0,
            stop: 0,
            dwell_left: 0,
            waiting: None,
            hold: false,
            done: false,
            creep: 0,
        };
        p.arrive_at_stops();
        Ok(p)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Hold (true): brake along the path to a stop and stay; false: go on from there.
    pub fn set_hold(&mut self, hold: bool) {
        self.hold = hold;
    }

    /// Why the path stands at an operator stop and waits (a tool to load, a program stop),
    /// or None while it runs.
    pub fn operator_stop(&self) -> Option<&OperatorReason> {
        self.waiting.map(|i| &self.path.operator_stops[i])
    }

    /// The operator has done what the stop asked: the path goes on (unless held).
    pub fn release(&mut self) {
        self.waiting = None;
    }

    /// At rest (speed and acceleration zero).
    pub fn is_at_rest(&self) -> bool {
        self.m.v == 0.0 && self.m.a == 0.0
    }

    /// Every set-point has been given.
    pub fn is_done(&self) -> bool {
        self.done
    }

    /// The current set-point (where the last cycle left the axes).
    pub fn position(&self) -> P3 {
        self.point()
    }

    fn point(&self) -> P3 {
        if self.path.segs.is_empty() {
            return self.path.start;
        }
        let mut i = self.seg.min(self.path.segs.len() - 1);
        while i + 1 < self.path.segs.len() && self.path.segs[i + 1].s0 <= self.m.s {
            i += 1;
        }
        self.path.point_in(i, self.m.s)
    }

    /// Units passed at the current position.
    fn passed(&self) -> usize {
        let s = self.m.s;
        // a unit ending at a dwell is passed once the dwell is over
        let dwelling = self.dwell_left > 0 || self.waiting.is_some();
        self.path
            .unit_ends
            .iter()
            .take_while(|&&e| {
                e < s - 1e-9 || (e <= s + 1e-9 && !(dwelling && (e - s).abs() <= 1e-9))
            })
            .count()
    }

    /// One constant-jerk step of `j` (the acceleration clamped to its limit); a speed that
    /// would go below zero stops.
    fn advance(&self, m: Motion, j: f64) -> Motion {
        let t = self.period;
        let mut a1 = (m.a + j * t).clamp(-self.accel, self.accel);
        if m.a < 0.0 && j > 0.0 && m.v <= m.a * m.a / (2.0 * self.jerk) {
            // easing out of a brake: the acceleration comes back to zero, not past it
            a1 = a1.min(0.0);
        }
        let je = (a1 - m.a) / t;
        let v1 = m.v + m.a * t + je * t * t / 2.0;
        if v1 <= REST_V && a1.abs() <= REST_A {
            // an exact stop's last cycle
            return Motion {
                s: m.s + (m.v * t + m.a * t * t / 2.0 + je * t * t * t / 6.0).max(0.0),
                v: 0.0,
                a: 0.0,
            };
        }
        if v1 <= 1e-12 {
            // comes to rest within the step: the distance to rest at the mean speed
            return Motion {
                s: m.s + (m.v * t / 2.0).max(0.0),
                v: 0.0,
                a: 0.0,
            };
        }
        Motion {
            s: m.s + m.v * t + m.a * t * t / 2.0 + je * t * t * t / 6.0,
            v: v1,
            a: a1,
        }
    }

    /// The jerk of braking, chosen cycle by cycle so that speed and acceleration reach zero
    /// together at a cycle's end: the full jerk down (to the acceleration limit) while an
    /// exact stop stays possible after it, else the first cycle of the shortest exact stop
    /// from here ([`Planner::exact_stop`]). None where no exact stop is left (a state the
    /// planner never chooses: braking from it would end with acceleration dropping to zero
    /// in one cycle).
    fn brake_jerk(&self, m: Motion) -> Option<f64> {
        if m.v == 0.0 && m.a == 0.0 {
            return Some(0.0);
        }
        let down = self.advance(m, -self.jerk);
        let je =
            ((m.a - self.jerk * self.period).clamp(-self.accel, self.accel) - m.a) / self.period;
        if (down.v == 0.0 && down.a == 0.0 && self.rests_exactly(m, je))
            || (down.v > 0.0 && self.can_stop_exactly(down))
        {
            return Some(-self.jerk);
        }
        self.exact_stop(m)
    }

    /// Whether an exact stop is possible from `m`: at once, or after the cycles of full
    /// jerk down that bring a rising acceleration below zero.
    fn can_stop_exactly(&self, mut m: Motion) -> bool {
        for _ in 0..100_000 {
            if (m.v == 0.0 && m.a == 0.0) || self.exact_stop(m).is_some() {
                return true;
            }
            if m.a <= 0.0 || m.v == 0.0 {
                return false;
            }
            m = self.advance(m, -self.jerk);
        }
        false
    }

    /// Whether one step of jerk `j` from `m` ends at rest with the speed and acceleration
    /// of that step's own end (not by the rest clamp of [`Planner::advance`]).
    fn rests_exactly(&self, m: Motion, j: f64) -> bool {
        let t = self.period;
        let a1 = m.a + j * t;
        let v1 = m.v + m.a * t + j * t * t / 2.0;
        a1.abs() <= REST_A && v1.abs() <= REST_V
    }

    /// The first cycle's jerk of the shortest exact stop from `m`: one cycle of jerk j1,
    /// then N − 1 cycles of one constant jerk j2 that bring the speed and the acceleration
    /// to zero at the same instant, every jerk within the limit, the acceleration within
    /// its limit and the speed never below zero. With N cycles in all and
    /// c = (2v + aT)/T²: j1 = −a/T − c/N, the acceleration after it −cT/N, and
    /// j2 = c/(N(N−1)); the shortest N meeting every bound is taken.
    fn exact_stop(&self, m: Motion) -> Option<f64> {
        let (t, jmax, amax) = (self.period, self.jerk, self.accel);
        let (v, a) = (m.v, m.a);
        let mut c = (2.0 * v + a * t) / (t * t);
        if c.abs() <= 1e-9 * (2.0 * v.abs() + a.abs() * t) / (t * t) {
            c = 0.0;
        }
        if c < 0.0 {
            return None;
        }
        if c == 0.0 {
            // one cycle of jerk −a/T ends at rest
            let j = -a / t;
            return (j.abs() <= jmax * (1.0 + 1e-12)).then_some(j);
        }
        if jmax - a / t <= 0.0 {
            return None;
        }
        let mut n = 2.0f64
            .max((c * t / amax).ceil())
            .max((c / (jmax - a / t)).ceil());
        // N(N − 1) ≥ c / J
        let q = c / jmax;
        n = n.max(((1.0 + (1.0 + 4.0 * q).sqrt()) / 2.0).ceil());
        // rounding: step up past a bound missed by a hair
        for _ in 0..3 {
            if c / (n * (n - 1.0)) <= jmax * (1.0 + 1e-12) && c * t / n <= amax * (1.0 + 1e-12) {
                break;
            }
            n += 1.0;
        }
        let j1 = -a / t - c / n;
        if j1 < -jmax * (1.0 + 1e-12) || j1 > jmax * (1.0 + 1e-12) {
            return None;
        }
        if j1 > 0.0 && a < 0.0 {
            // the lowest speed within the first cycle, where the acceleration crosses zero
            let tz = -a / j1;
            if tz < t && v - a * a / (2.0 * j1) < -REST_V {
                return None;
            }
        }
        Some(j1)
    }

    /// Whether braking from `m` meets every cap ahead and stops before the next stop.
    fn safe(&self, from: Motion, m: Motion) -> bool {
        let stop_s = self.path.stops[self.stop].s;
        let segs = &self.path.segs;
        let mut i = self.seg;
        let mut prev = from;
        let mut cur = m;
        for _ in 0..1_000_000 {
            if cur.s > stop_s + AT_STOP * 0.5 {
                return false;
            }
            // the segments and corners crossed in this step
            while i < segs.len() && segs[i].s0 + segs[i].len < cur.s {
                i += 1;
                if i < segs.len()
                    && segs[i].s0 > prev.s
                    && prev.v.max(cur.v) > self.path.corner[i] * (1.0 + 1e-9) + 1e-12
                {
                    return false;
                }
            }
            if i < segs.len() && cur.v > segs[i].cap * (1.0 + 1e-9) + 1e-12 {
                return false;
            }
            if i < segs.len()
                && segs[i].s0 > prev.s
                && segs[i].s0 <= cur.s
                && prev.v.max(cur.v) > self.path.corner[i] * (1.0 + 1e-9) + 1e-12
            {
                return false;
            }
            if cur.v == 0.0 {
                return true;
            }
            let Some(j) = self.brake_jerk(cur) else {
                return false;
            };
            prev = cur;
            cur = self.advance(cur, j);
        }
        false
    }

    /// Arrived at a stop: start its dwell, or finish at the end.
    fn arrive_at_stops(&mut self) {
        while self.stop < self.path.stops.len() {
            let st = self.path.stops[self.stop];
            if self.m.v == 0.0 && (st.s - self.m.s).abs() <= AT_STOP {
                self.m.s = st.s;
                if self.stop + 1 == self.path.stops.len() {
                    self.done = true;
                    return;
                }
                self.dwell_left += st.cycles;
                if st.operator.is_some() {
                    self.waiting = st.operator;
                    self.stop += 1;
                    return;
                }
                self.stop += 1;
            } else {
                return;
            }
        }
    }

    /// The next cycle's set-point; None when the program's end has been reached (the last
    /// cycle returned passes every unit).
    pub fn next_cycle(&mut self) -> Option<Cycle> {
        if self.done {
            return None;
        }
        if self.waiting.is_some() {
            // at rest where the operator is asked for; nothing moves until released
        } else if self.dwell_left > 0 {
            self.dwell_left -= 1;
        } else if self.hold {
            let j = self.brake_jerk(self.m).unwrap_or(-self.jerk);
            self.m = self.advance(self.m, j);
        } else {
            self.m = self.choose();
        }
        while self.seg + 1 < self.path.segs.len() && self.path.segs[self.seg + 1].s0 <= self.m.s {
            self.seg += 1;
        }
        if !self.hold && self.waiting.is_none() {
            self.arrive_at_stops();
        }
        let passed = if self.done {
            self.path.unit_ends.len()
        } else {
            self.passed()
        };
        Some(Cycle {
            position: if self.done {
                self.path.end
            } else {
                self.point()
            },
            speed: self.m.v,
            passed,
        })
    }

    /// The next state: the largest jerk that stays safe.
    fn choose(&mut self) -> Motion {
        let m = self.m;
        let stop_s = self.path.stops[self.stop].s;
        if m.v == 0.0 && stop_s - m.s <= AT_STOP {
            return Motion { s: stop_s, ..m };
        }
        let up = self.advance(m, self.jerk);
        if self.safe(m, up) {
            self.creep = 0;
            return up;
        }
        let jb = self.brake_jerk(m).unwrap_or(-self.jerk);
        let (mut lo, mut hi) = (jb, self.jerk);
        if !self.safe(m, self.advance(m, lo)) {
            // nothing is safe (only after a change of caps): brake
            return self.advance(m, lo);
        }
        for _ in 0..12 {
            let mid = 0.5 * (lo + hi);
            if self.safe(m, self.advance(m, mid)) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let next = self.advance(m, lo);
        if m.v == 0.0 && next.v == 0.0 {
            // creeping toward a stop closer than one step can brake for
            self.creep += 1;
            if self.creep > 8 {
                self.creep = 0;
                let s = (m.s + (stop_s - m.s).min(AT_STOP * 0.9)).min(stop_s);
                return Motion { s, v: 0.0, a: 0.0 };
            }
        }
        next
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use offset_core::Point;

    fn limits() -> Limits {
        let l = AxisLimits {
            velocity: 100.0,
            acceleration: 1000.0,
            jerk: 20000.0,
        };
        Limits {
            axes: [
                Some(l),
                Some(l),
                Some(AxisLimits {
                    velocity: 20.0,
                    ..l
                }),
            ],
        }
    }

    fn run(moves: &[Move], hold_at: Option<(usize, usize)>) -> (Vec<Cycle>, Planner) {
        let mut p = Planner::new(moves, P3::default(), &limits(), 0.002).unwrap();
        let mut out = Vec::new();
        while let Some(c) = p.next_cycle() {
            if let Some((from, to)) = hold_at {
                p.set_hold(out.len() >= from && out.len() < to);
            }
            out.push(c);
            assert!(out.len() < 200_000, "never ends");
        }
        (out, p)
    }

    fn check_limits(cycles: &[Cycle], l: &Limits, t: f64) {
        let pos: Vec<[f64; 3]> = std::iter::once([0.0; 3])
            .chain(
                cycles
                    .iter()
                    .map(|c| [c.position.x, c.position.y, c.position.z]),
            )
            .collect();
        for ax in 0..3 {
            let lim = l.axes[ax].unwrap();
            for (k, w) in pos.windows(3).enumerate() {
                let v = (w[2][ax] - w[1][ax]).abs() / t;
                let a = (w[2][ax] - 2.0 * w[1][ax] + w[0][ax]).abs() / (t * t);
                assert!(
                    v <= lim.velocity * 1.001 + 1e-6,
                    "axis {ax} cycle {k}: v {v}"
                );
                assert!(
                    a <= lim.acceleration * 1.001 + 1e-3,
                    "axis {ax} cycle {k}: a {a}"
                );
            }
        }
    }

    #[test]
    fn a_straight_run_reaches_its_feed_and_stops_at_the_end() {
        let moves = [Move::Linear {
            to: P3::new(100.0, 0.0, 0.0),
            feed: 3000.0,
        }];
        let (c, _) = run(&moves, None);
        let top = c.iter().map(|c| c.speed).fold(0.0, f64::max);
        assert!((top - 50.0).abs() < 1e-6, "top speed {top}");
        assert_eq!(c.last().unwrap().position, P3::new(100.0, 0.0, 0.0));
        assert_eq!(c.last().unwrap().passed, 1);
        check_limits(&c, &limits(), 0.002);
    }

    #[test]
    fn corners_slow_down_arcs_stay_round_and_no_axis_exceeds_its_limits() {
        let moves = vec![
            Move::Rapid {
                to: P3::new(10.0, 0.0, 2.0),
            },
            Move::Linear {
                to: P3::new(10.0, 0.0, -1.0),
                feed: 600.0,
            },
            Move::Linear {
                to: P3::new(40.0, 0.0, -1.0),
                feed: 4000.0,
            },
            Move::Arc {
                to: P3::new(40.0, 20.0, -1.0),
                center: Point::new(40.0, 10.0),
                ccw: true,
                feed: 4000.0,
            },
            Move::Linear {
                to: P3::new(10.0, 20.0, -1.0),
                feed: 4000.0,
            },
            Move::Dwell { seconds: 0.1 },
            Move::Linear {
                to: P3::new(10.0, 0.0, -1.0),
                feed: 4000.0,
            },
        ];
        let (c, p) = run(&moves, None);
        check_limits(&c, &limits(), 0.002);
        for cy in &c {
            let d = distance_to_path(&p.path, cy.position);
            assert!(d < 1e-6, "{cy:?} is {d} mm off the path");
        }
        // the sharp corner at (40,0)→ up is not passed at full speed
        let at_corner = c
            .iter()
            .filter(|cy| {
                (cy.position.x - 10.0).abs() < 0.05
                    && cy.position.y.abs() < 0.05
                    && cy.position.z < -0.99
            })
            .map(|cy| cy.speed)
            .fold(f64::INFINITY, f64::min);
        assert!(at_corner < 2.0, "{at_corner}");
        assert_eq!(c.last().unwrap().passed, moves.len());
        // units are passed in order
        assert!(c.windows(2).all(|w| w[0].passed <= w[1].passed));
        // the dwell holds for 50 cycles at (10, 20)
        let still = c
            .iter()
            .filter(|cy| cy.position == P3::new(10.0, 20.0, -1.0))
            .count();
        assert!(still >= 50, "{still}");
    }

    #[test]
    fn a_hold_brakes_on_the_path_within_limits_and_resumes() {
        let moves = [Move::Linear {
            to: P3::new(80.0, 60.0, 0.0),
            feed: 6000.0,
        }];
        let (c, p) = run(&moves, Some((100, 300)));
        check_limits(&c, &limits(), 0.002);
        let held = &c[250..300];
        assert!(
            held.windows(2).all(|w| w[0].position == w[1].position),
            "stands still when held"
        );
        assert!(held[0].speed == 0.0);
        for cy in &c {
            assert!(distance_to_path(&p.path, cy.position) < 1e-9);
        }
        assert_eq!(c.last().unwrap().position, P3::new(80.0, 60.0, 0.0));
    }

    /// Every axis's speed, acceleration and jerk, as the set-points' first, second and
    /// third differences over the period, within its limits (`from` the cycle given).
    fn check_jerk(cycles: &[Cycle], l: &Limits, t: f64, what: &str) {
        let pos: Vec<[f64; 3]> = std::iter::repeat_n([0.0; 3], 3)
            .chain(
                cycles
                    .iter()
                    .map(|c| [c.position.x, c.position.y, c.position.z]),
            )
            .collect();
        for ax in 0..3 {
            let lim = l.axes[ax].unwrap();
            for (k, w) in pos.windows(4).enumerate() {
                let v = (w[3][ax] - w[2][ax]).abs() / t;
                let a = (w[3][ax] - 2.0 * w[2][ax] + w[1][ax]).abs() / (t * t);
                let j = (w[3][ax] - 3.0 * w[2][ax] + 3.0 * w[1][ax] - w[0][ax]).abs() / (t * t * t);
                assert!(
                    v <= lim.velocity * (1.0 + 1e-6),
                    "{what}: axis {ax} cycle {k}: v {v}"
                );
                assert!(
                    a <= lim.acceleration * (1.0 + 1e-6),
                    "{what}: axis {ax} cycle {k}: a {a}"
                );
                assert!(
                    j <= lim.jerk * (1.0 + 1e-6),
                    "{what}: axis {ax} cycle {k}: jerk {j}"
                );
            }
        }
    }

    fn diagonal() -> [Move; 1] {
        [Move::Linear {
            to: P3::new(80.0, 60.0, -3.0),
            feed: 6000.0,
        }]
    }

    #[test]
    fn the_end_of_a_run_is_jerk_limited_to_standstill_at_every_period() {
        for period in [0.001, 0.002, 0.004] {
            for feed in [60.0, 600.0, 3000.0, 6000.0] {
                let moves = [Move::Linear {
                    to: P3::new(30.0, 20.0, -2.0),
                    feed,
                }];
                let mut p = Planner::new(&moves, P3::default(), &limits(), period).unwrap();
                let mut c = Vec::new();
                while let Some(cy) = p.next_cycle() {
                    c.push(cy);
                    assert!(c.len() < 400_000, "never ends");
                }
                // standing still at the end for three cycles more
                let last = *c.last().unwrap();
                c.extend([last; 3]);
                check_jerk(&c, &limits(), period, &format!("{period} s, F{feed}"));
                assert_eq!(last.position, P3::new(30.0, 20.0, -2.0));
            }
        }
    }

    #[test]
    fn a_hold_at_any_moment_brakes_jerk_limited_and_resumes_jerk_limited() {
        for hold_at in [3, 10, 40, 77, 150, 400] {
            let (c, p) = run(&diagonal(), Some((hold_at, hold_at + 300)));
            check_jerk(&c, &limits(), 0.002, &format!("hold at cycle {hold_at}"));
            for cy in &c {
                assert!(distance_to_path(&p.path, cy.position) < 1e-9);
            }
            assert_eq!(c.last().unwrap().position, P3::new(80.0, 60.0, -3.0));
        }
    }

    #[test]
    fn an_exact_stop_brings_speed_and_acceleration_to_zero_together() {
        let p = Planner::new(&diagonal(), P3::default(), &limits(), 0.002).unwrap();
        for (v, a) in [
            (50.0, 0.0),
            (50.0, -250.0),
            (4.0, -250.0),
            (0.4, -40.0),
            (10.0, 200.0),
            (1e-3, 0.0),
        ] {
            let mut m = Motion { s: 0.0, v, a };
            let mut n = 0;
            while !(m.v == 0.0 && m.a == 0.0) {
                let j = p
                    .brake_jerk(m)
                    .unwrap_or_else(|| panic!("no stop from v {v} a {a}: {m:?}"));
                assert!(j.abs() <= p.jerk * (1.0 + 1e-9), "v {v} a {a}: jerk {j}");
                let next = p.advance(m, j);
                assert!(
                    p.rests_exactly(m, j) || next.v > 0.0,
                    "v {v} a {a}: clamped to rest from {m:?}"
                );
                m = next;
                n += 1;
                assert!(n < 100_000);
            }
        }
    }

    pub(crate) fn distance_to_path(path: &Path, p: P3) -> f64 {
        path.segs
            .iter()
            .map(|g| g.geom.distance(p))
            .fold(path.start.dist(p), f64::min)
    }
}
