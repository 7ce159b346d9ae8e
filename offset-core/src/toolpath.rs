//! The Toolpath IR: moves in millimetres, absolute, in the machine's work frame — the contract
//! between the operations that plan and the posts that speak a machine's language.

use crate::geom::{Point, Segment};
use serde::{Deserialize, Serialize};

/// A point in the machine's work frame, in millimetres.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct P3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

impl P3 {
    pub const fn new(x: f64, y: f64, z: f64) -> Self {
        P3 { x, y, z }
    }
    pub fn xy(&self) -> Point {
        Point::new(self.x, self.y)
    }
    pub fn at_z(p: Point, z: f64) -> Self {
        P3::new(p.x, p.y, z)
    }
    pub fn dist(&self, o: P3) -> f64 {
        ((self.x - o.x).powi(2) + (self.y - o.y).powi(2) + (self.z - o.z).powi(2)).sqrt()
    }
}

/// One move or machine action. Feeds are in mm/min.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "move", rename_all = "snake_case")]
pub enum Move {
    /// Positioning at the machine's rapid rate; never cuts.
    Rapid {
        to: P3,
    },
    /// Straight cut.
    Linear {
        to: P3,
        feed: f64,
    },
    /// Circular cut in the XY plane about `center` (Z moves linearly: helical when it changes).
    Arc {
        to: P3,
        center: Point,
        ccw: bool,
        feed: f64,
    },
    /// Sewing: move the frame to `to` and drop the needle there.
    Stitch {
        to: Point,
    },
    /// Sewing: move the frame to `to` without sewing.
    Jump {
        to: Point,
    },
    /// Sewing: cut the thread.
    Trim,
    /// Sewing: change thread colour (machine stops for the operator).
    ColorChange,
    /// Program stop: the machine waits for the operator.
    Stop,
    /// Spindle on at `rpm` (clockwise), or off when `rpm` is 0.
    Spindle {
        rpm: f64,
    },
    Dwell {
        seconds: f64,
    },
    /// Put another tool in the spindle: its number in the machine's tool table, its name
    /// for the operator ("6 mm flat end mill") and its geometry, where known.
    ToolChange {
        tool: u32,
        #[serde(default, skip_serializing_if = "String::is_empty")]
        name: String,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        geometry: Option<Tool>,
    },
    /// One drilled hole, as a canned cycle (G81 simple, G82 with a dwell, G83 pecking): from
    /// `clear` over the hole, rapid down to `retract` (the R plane), feed to `bottom`, back
    /// to `clear`. With `peck` > 0 the feed goes down `peck` at a time from the R plane,
    /// rapids back up to the R plane after each peck and rapids down again to
    /// [`PECK_BACKOFF`] above the last depth; `dwell` seconds are spent at the bottom
    /// (simple and dwell cycles only). [`Move::drill_moves`] spells it out in rapids and
    /// lines for machines without canned cycles.
    Drill {
        at: Point,
        clear: f64,
        retract: f64,
        bottom: f64,
        #[serde(default)]
        peck: f64,
        #[serde(default)]
        dwell: f64,
        feed: f64,
    },
    /// Measure the tool just loaded on a touch plate: from `clear` over `at`, probe straight
    /// down at `feed`, no lower than `lowest`, until the tool touches the plate; the height
    /// there becomes `thickness` above the work's zero (the plate lies on the stock top), and
    /// the tool goes back up to `clear` (G38.2, then G10 L20 P0 Z`thickness`). Heights are in
    /// the work frame the program had before the probe.
    ProbeToolLength {
        at: Point,
        clear: f64,
        lowest: f64,
        feed: f64,
        thickness: f64,
    },
    /// A note for people; posts may drop it (GRBL never sees comments on the wire).
    Comment {
        text: String,
    },
}

/// How far above the last peck's depth a pecking cycle rapids back down before it feeds
/// again, mm (LinuxCNC's G83 uses 0.010 inch).
pub const PECK_BACKOFF: f64 = 0.254;

impl Move {
    /// A drilling cycle spelt out in rapids, lines and a dwell, from the tool's position
    /// `from`, moving exactly as a controller runs the canned cycle (G98: back to `clear`);
    /// a tool-length probe as the moves it makes when the plate is where it should be (down
    /// to the plate's top, `thickness`); any other move as it is.
    pub fn drill_moves(&self, from: P3) -> Vec<Move> {
        if let &Move::ProbeToolLength {
            at,
            clear,
            thickness,
            feed,
            ..
        } = self
        {
            // as planned: the tool touches the plate at its top, `thickness` above the zero
            return vec![
                Move::Rapid {
                    to: P3::new(from.x, from.y, clear),
                },
                Move::Rapid {
                    to: P3::at_z(at, clear),
                },
                Move::Linear {
                    to: P3::at_z(at, thickness),
                    feed,
                },
                Move::Rapid {
                    to: P3::at_z(at, clear),
                },
            ];
        }
        let &Move::Drill {
            at,
            clear,
            retract,
            bottom,
            peck,
            dwell,
            feed,
        } = self
        else {
            return vec![self.clone()];
        };
        let mut out = Vec::new();
        if from.z != clear {
            out.push(Move::Rapid {
                to: P3::new(from.x, from.y, clear),
            });
        }
        let here = |z| P3::at_z(at, z);
        out.push(Move::Rapid { to: here(clear) });
        out.push(Move::Rapid { to: here(retract) });
        if peck > 0.0 {
            let depths = peck_depths(retract, bottom, peck);
            let last = depths.len() - 1;
            for (i, &d) in depths.iter().enumerate() {
                if i > 0 {
                    out.push(Move::Rapid {
                        to: here(depths[i - 1] + PECK_BACKOFF),
                    });
                }
                out.push(Move::Linear { to: here(d), feed });
                if i < last {
                    out.push(Move::Rapid { to: here(retract) });
                }
            }
        } else {
            out.push(Move::Linear {
                to: here(bottom),
                feed,
            });
            if dwell > 0.0 {
                out.push(Move::Dwell { seconds: dwell });
            }
        }
        out.push(Move::Rapid { to: here(clear) });
        out
    }
}

/// The depths a pecking cycle feeds to: `peck` at a time down from the R plane `retract`,
/// the last one `bottom` (as LinuxCNC's G83 counts them).
pub fn peck_depths(retract: f64, bottom: f64, peck: f64) -> Vec<f64> {
    let mut out = Vec::new();
    let mut z = retract;
    loop {
        z -= peck;
        if z <= bottom + 1e-9 || out.len() >= 10_000 {
            out.push(bottom);
            return out;
        }
        out.push(z);
    }
}

/// The shape of a cutter's end.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ToolKind {
    #[default]
    FlatEnd,
    BallEnd,
    /// A sewing needle: no radius, stitches only.
    Needle,
}

/// The tool a path was planned for (keys left out of JSON take a 3 mm flat end mill, tool 1).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Tool {
    pub number: u32,
    pub diameter: f64,
    pub kind: ToolKind,
}

impl Default for Tool {
    fn default() -> Self {
        Tool::flat(3.0)
    }
}

impl Tool {
    pub fn flat(diameter: f64) -> Self {
        Tool {
            number: 1,
            diameter,
            kind: ToolKind::FlatEnd,
        }
    }
    pub fn radius(&self) -> f64 {
        self.diameter / 2.0
    }
}

/// Extents of a tool path in 3D.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Bounds3 {
    pub min: P3,
    pub max: P3,
}

/// A planned path: moves plus what made them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Toolpath {
    pub moves: Vec<Move>,
    /// The tool the path was planned for (None for sewing).
    pub tool: Option<Tool>,
    /// The operation that made it, e.g. "profile inside".
    pub operation: String,
    /// Where the shape came from (file name or job id).
    pub source: String,
    /// What the operation could not do as asked, in sentences for the operator (an entry
    /// that had to plunge into the material, say).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

impl Toolpath {
    pub fn new(operation: impl Into<String>) -> Self {
        Toolpath {
            operation: operation.into(),
            ..Default::default()
        }
    }
    pub fn push(&mut self, m: Move) {
        self.moves.push(m);
    }

    /// Walks the moves from `start`, calling `f(from, move, to)` for every move that goes
    /// somewhere; returns the end position. Sewing moves keep the last Z.
    /// Drilling cycles are walked as the rapids and lines they make.
    pub fn walk(&self, start: P3, mut f: impl FnMut(P3, &Move, P3)) -> P3 {
        let mut pos = start;
        for m in &self.moves {
            if let Move::Drill { .. } | Move::ProbeToolLength { .. } = m {
                for d in m.drill_moves(pos) {
                    if let Move::Rapid { to } | Move::Linear { to, .. } = d {
                        f(pos, &d, to);
                        pos = to;
                    }
                }
                continue;
            }
            let to = match m {
                Move::Rapid { to } | Move::Linear { to, .. } | Move::Arc { to, .. } => *to,
                Move::Stitch { to } | Move::Jump { to } => P3::at_z(*to, pos.z),
                _ => continue,
            };
            f(pos, m, to);
            pos = to;
        }
        pos
    }

    /// The path with every drilling cycle spelt out in rapids, lines and dwells, for the
    /// machines that have no canned cycles (tool-length probes stay as they are).
    pub fn expanded(&self) -> Toolpath {
        if !self.moves.iter().any(|m| matches!(m, Move::Drill { .. })) {
            return self.clone();
        }
        let mut out = Toolpath {
            moves: Vec::with_capacity(self.moves.len()),
            ..self.clone()
        };
        let mut pos = P3::default();
        for m in &self.moves {
            if let Move::ProbeToolLength { at, clear, .. } = m {
                // a probe is no drilling cycle: it stays one move, for the post to write
                out.moves.push(m.clone());
                pos = P3::at_z(*at, *clear);
                continue;
            }
            for d in m.drill_moves(pos) {
                if let Move::Rapid { to } | Move::Linear { to, .. } | Move::Arc { to, .. } = &d {
                    pos = *to;
                }
                out.moves.push(d);
            }
        }
        out
    }

    /// Extents of every position the path visits, arcs included; None for a path that
    /// never moves.
    pub fn bounds(&self) -> Option<Bounds3> {
        let mut b: Option<Bounds3> = None;
        let mut add = |p: P3| {
            let bb = b.get_or_insert(Bounds3 { min: p, max: p });
            bb.min = P3::new(bb.min.x.min(p.x), bb.min.y.min(p.y), bb.min.z.min(p.z));
            bb.max = P3::new(bb.max.x.max(p.x), bb.max.y.max(p.y), bb.max.z.max(p.z));
        };
        let mut first = true;
        self.walk(P3::default(), |from, m, to| {
            if first {
                first = false;
            } else {
                add(from);
            }
            add(to);
            if let Move::Arc { center, ccw, .. } = m {
                let seg = arc_segment(from.xy(), to.xy(), *center, *ccw);
                let sb = seg.bounds();
                add(P3::new(sb.min.x, sb.min.y, to.z));
                add(P3::new(sb.max.x, sb.max.y, to.z));
            }
        });
        b
    }

    /// Total length of cutting moves (linear and arc) and of rapids, in mm.
    pub fn lengths(&self) -> (f64, f64) {
        let (mut cut, mut rapid) = (0.0, 0.0);
        self.walk(P3::default(), |from, m, to| match m {
            Move::Linear { .. } | Move::Stitch { .. } => cut += from.dist(to),
            Move::Arc { center, ccw, .. } => {
                let xy = arc_segment(from.xy(), to.xy(), *center, *ccw).length();
                cut += xy.hypot(to.z - from.z)
            }
            Move::Rapid { .. } | Move::Jump { .. } => rapid += from.dist(to),
            _ => {}
        });
        (cut, rapid)
    }

    /// The path as points no farther apart than `step` mm (arcs sampled), starting at
    /// `start`: what a machine that follows the path exactly would pass through.
    pub fn sample(&self, start: P3, step: f64) -> Vec<P3> {
        let mut pts = vec![start];
        self.walk(start, |from, m, to| {
            let n = |len: f64| ((len / step).ceil() as usize).clamp(1, 1_000_000);
            match m {
                Move::Arc { center, ccw, .. } => {
                    let seg = arc_segment(from.xy(), to.xy(), *center, *ccw);
                    let k = n(seg.length());
                    for i in 1..=k {
                        let t = i as f64 / k as f64;
                        pts.push(P3::at_z(seg.point_at(t), from.z + (to.z - from.z) * t));
                    }
                }
                _ => {
                    let k = n(from.dist(to));
                    for i in 1..=k {
                        let t = i as f64 / k as f64;
                        pts.push(P3::new(
                            from.x + (to.x - from.x) * t,
                            from.y + (to.y - from.y) * t,
                            from.z + (to.z - from.z) * t,
                        ));
                    }
                }
            }
        });
        pts
    }
}

/// The XY arc from `from` to `to` about `center`; the radius is taken from the start point.
pub fn arc_segment(from: Point, to: Point, center: Point, ccw: bool) -> Segment {
    Segment::Arc {
        a: from,
        b: to,
        center,
        radius: from.dist(center),
        ccw,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_include_arc_extremes_and_lengths_add_up() {
        let mut tp = Toolpath::new("test");
        tp.push(Move::Rapid {
            to: P3::new(10.0, 0.0, 5.0),
        });
        tp.push(Move::Linear {
            to: P3::new(10.0, 0.0, -1.0),
            feed: 100.0,
        });
        // a half circle ccw from (10,0) to (-10,0) about the origin passes through (0,10)
        tp.push(Move::Arc {
            to: P3::new(-10.0, 0.0, -1.0),
            center: Point::new(0.0, 0.0),
            ccw: true,
            feed: 100.0,
        });
        let b = tp.bounds().unwrap();
        assert!((b.max.y - 10.0).abs() < 1e-9, "{b:?}");
        assert!((b.min.z + 1.0).abs() < 1e-12 && (b.max.z - 5.0).abs() < 1e-12);
        let (cut, rapid) = tp.lengths();
        assert!((cut - (6.0 + std::f64::consts::PI * 10.0)).abs() < 1e-9);
        assert!((rapid - (125.0f64).sqrt()).abs() < 1e-9);
        let pts = tp.sample(P3::default(), 0.5);
        assert!(pts.windows(2).all(|w| w[0].dist(w[1]) <= 0.5 + 1e-9));
        assert!(pts.iter().any(|p| (p.y - 10.0).abs() < 0.01));
    }
}
