//! Drilling: holes the drill's size in one canned cycle each (simple, dwell, peck), larger holes bored to size with a helix and a finishing lap, visited in a short tour.

use super::{positive, OpError};
use crate::geom::{Point, Polyline, Shape};
use crate::toolpath::{Move, Tool, Toolpath, P3};
use serde::{Deserialize, Serialize};

/// A hole to make: its centre, its diameter (0 for a DXF POINT: the drill's own size) and
/// a name for messages (`CIRCLE (handle 2A, line 120) on layer HOLES`, `path 3`).
#[derive(Clone, Debug, PartialEq)]
pub struct Hole {
    pub center: Point,
    pub diameter: f64,
    pub name: String,
}

/// Which canned cycle drills a hole.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Cycle {
    /// Feed to depth, rapid out (G81).
    #[default]
    Simple,
    /// Feed to depth, dwell, rapid out (G82).
    Dwell,
    /// Feed down a peck at a time, rapid out to the R plane after each (G83).
    Peck,
}

/// A drilling operation's options (keys left out of a job take the defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DrillParams {
    /// The drill (left out of JSON when it is the default, so that a job operation's own
    /// `tool` key, beside these, is the only one).
    #[serde(skip_serializing_if = "is_default_tool")]
    pub tool: Tool,
    /// How far below the stock top (Z=0) the holes go, mm (positive).
    pub depth: f64,
    pub cycle: Cycle,
    /// Peck cycle: how far each peck goes down, mm.
    pub peck: f64,
    /// Dwell cycle: seconds at the bottom of each hole.
    pub dwell: f64,
    /// Drilling feed, mm/min.
    pub feed: f64,
    /// The R plane: where the feed starts, mm above the stock.
    pub retract: f64,
    /// Height for rapids between holes, mm above the stock.
    pub safe_z: f64,
    /// Spindle speed, rpm (0 leaves the spindle alone).
    pub spindle_rpm: f64,
    /// A circle whose diameter is within this of the tool's is drilled, mm.
    pub diameter_tolerance: f64,
    /// Bore a larger circle with a helix and a finishing lap (true), or refuse it (false).
    pub bore: bool,
    /// Boring: the feed along the helix, mm/min.
    pub bore_feed: f64,
    /// Boring: the most the helix goes down per lap, mm.
    pub stepdown: f64,
}

fn is_default_tool(t: &Tool) -> bool {
    *t == Tool::default()
}

impl Default for DrillParams {
    fn default() -> Self {
        DrillParams {
            tool: Tool::default(),
            depth: 1.0,
            cycle: Cycle::Simple,
            peck: 1.0,
            dwell: 0.5,
            feed: 200.0,
            retract: 1.0,
            safe_z: 5.0,
            spindle_rpm: 12000.0,
            diameter_tolerance: 0.05,
            bore: true,
            bore_feed: 600.0,
            stepdown: 0.5,
        }
    }
}

impl DrillParams {
    /// Every value in range, or a `BadParam` error naming the first that is not.
    pub fn check(&self) -> Result<(), OpError> {
        positive(self.tool.diameter, "the tool diameter")?;
        positive(self.depth, "the drilling depth")?;
        positive(self.feed, "the drilling feed")?;
        positive(self.bore_feed, "the boring feed")?;
        positive(self.stepdown, "the boring step-down")?;
        positive(self.retract, "the R plane height (retract)")?;
        if self.cycle == Cycle::Peck {
            positive(self.peck, "the peck depth")?;
        }
        if self.cycle == Cycle::Dwell {
            positive(self.dwell, "the dwell")?;
        }
        if !(self.diameter_tolerance.is_finite() && self.diameter_tolerance >= 0.0) {
            return Err(OpError::BadParam(format!(
                "the diameter tolerance must be 0 or more, got {}",
                self.diameter_tolerance
            )));
        }
        if !(self.safe_z.is_finite() && self.safe_z >= self.retract) {
            return Err(OpError::BadParam(format!(
                "the safe Z ({}) must be at or above the R plane ({})",
                self.safe_z, self.retract
            )));
        }
        Ok(())
    }
}

/// The tour of a drilling operation: how many holes were drilled and bored, and the rapid
/// length between them in the file's order and in the tour's (both from the origin), mm.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Tour {
    pub drilled: usize,
    pub bored: usize,
    pub rapid_file_order: f64,
    pub rapid_tour: f64,
}

/// The full circles of a shape, as holes (a closed path of arcs about one centre with one
/// radius); the other paths beside them.
pub fn holes_in(shape: &Shape) -> (Vec<Hole>, Vec<Polyline>) {
    let mut holes = Vec::new();
    let mut rest = Vec::new();
    for (i, p) in shape.paths.iter().enumerate() {
        match circle_of(p) {
            Some((center, r)) => holes.push(Hole {
                center,
                diameter: 2.0 * r,
                name: format!(
                    "circle {} (path {i}) at ({:.3}, {:.3})",
                    2.0 * r,
                    center.x,
                    center.y
                ),
            }),
            None => rest.push(p.clone()),
        }
    }
    (holes, rest)
}

/// The centre and radius of a closed path that is one full circle: arcs about one centre,
/// or (a circle drawn as curves: an SVG `<circle>` is four cubic Béziers, each within
/// 2.7e-4 of the radius of the circle, fitted into arcs that stray a little) a closed path
/// all of whose points lie within 1 µm + 3e-4 × r of one circle, taken by a least-squares
/// fit of points sampled along it.
pub fn circle_of(p: &Polyline) -> Option<(Point, f64)> {
    exact_circle_of(p).or_else(|| drawn_circle_of(p))
}

/// A closed path of curves that stays near one circle (see [`circle_of`]).
fn drawn_circle_of(p: &Polyline) -> Option<(Point, f64)> {
    if !p.closed || p.vertices.len() < 3 {
        return None;
    }
    let pts: Vec<Point> = p
        .segments()
        .flat_map(|s| (0..16).map(move |k| s.point_at(k as f64 / 16.0)))
        .collect();
    // Kåsa's fit: x² + y² + a x + b y + c = 0 in least squares, about the points' mean
    let n = pts.len() as f64;
    let m = Point::new(
        pts.iter().map(|q| q.x).sum::<f64>() / n,
        pts.iter().map(|q| q.y).sum::<f64>() / n,
    );
    let (mut suu, mut svv, mut suv, mut suuu, mut svvv, mut suvv, mut svuu) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for q in &pts {
        let (u, v) = (q.x - m.x, q.y - m.y);
        suu += u * u;
        svv += v * v;
        suv += u * v;
        suuu += u * u * u;
        svvv += v * v * v;
        suvv += u * v * v;
        svuu += v * u * u;
    }
    let det = suu * svv - suv * suv;
    if det.abs() < 1e-18 {
        return None;
    }
    let (ru, rv) = (0.5 * (suuu + suvv), 0.5 * (svvv + svuu));
    let uc = (ru * svv - rv * suv) / det;
    let vc = (rv * suu - ru * suv) / det;
    let c = Point::new(m.x + uc, m.y + vc);
    let r = pts.iter().map(|q| q.dist(c)).sum::<f64>() / n;
    let tol = 1e-3 + 3e-4 * r;
    (r > 0.0 && pts.iter().all(|q| (q.dist(c) - r).abs() <= tol)).then_some((c, r))
}

/// A closed path of arcs about one centre making one full turn.
fn exact_circle_of(p: &Polyline) -> Option<(Point, f64)> {
    if !p.closed || p.vertices.len() < 2 {
        return None;
    }
    let mut found: Option<(Point, f64, bool)> = None;
    let mut sweep = 0.0;
    for s in p.segments() {
        let crate::geom::Segment::Arc {
            center,
            radius,
            ccw,
            ..
        } = s
        else {
            return None;
        };
        match found {
            None => found = Some((center, radius, ccw)),
            Some((c, r, d)) => {
                let tol = 1e-6 * r.max(1.0);
                if c.dist(center) > tol || (r - radius).abs() > tol || d != ccw {
                    return None;
                }
            }
        }
        sweep += s.sweep().abs();
    }
    let (c, r, _) = found?;
    ((sweep - std::f64::consts::TAU).abs() < 1e-6).then_some((c, r))
}

/// Plans the holes: the drill's size drilled, larger ones bored (or refused by name with
/// `bore = false`), smaller ones refused by name; every hole visited once, in a
/// nearest-neighbour tour from the origin improved by 2-opt.
pub fn drill(holes: &[Hole], p: &DrillParams) -> Result<(Toolpath, Tour), OpError> {
    p.check()?;
    if holes.is_empty() {
        return Err(OpError::Empty(
            "there are no holes (circles or points) to drill".into(),
        ));
    }
    let d = p.tool.diameter;
    for h in holes {
        if !(h.center.is_finite() && h.diameter.is_finite()) {
            return Err(OpError::BadParam(format!(
                "{} is not a finite hole",
                h.name
            )));
        }
        if h.diameter > 0.0 && h.diameter < d - p.diameter_tolerance {
            return Err(OpError::BadParam(format!(
                "{} is {} mm across, smaller than the {} mm tool T{}",
                h.name, h.diameter, d, p.tool.number
            )));
        }
        if !p.bore && h.diameter > d + p.diameter_tolerance {
            return Err(OpError::BadParam(format!(
                "{} is {} mm across, larger than the {} mm drill T{}, and this operation does not bore (bore = false)",
                h.name, h.diameter, d, p.tool.number
            )));
        }
    }
    let centres: Vec<Point> = holes.iter().map(|h| h.center).collect();
    let order = tour(&centres);
    let mut t = Tour {
        rapid_file_order: path_length(&centres, &(0..centres.len()).collect::<Vec<_>>()),
        rapid_tour: path_length(&centres, &order),
        ..Default::default()
    };
    let mut tp = Toolpath::new("drill");
    tp.tool = Some(p.tool);
    if p.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: p.spindle_rpm });
    }
    for &i in &order {
        let h = &holes[i];
        if h.diameter > d + p.diameter_tolerance {
            bore(&mut tp, h, p);
            t.bored += 1;
        } else {
            tp.push(Move::Drill {
                at: h.center,
                clear: p.safe_z,
                retract: p.retract,
                bottom: -p.depth,
                peck: if p.cycle == Cycle::Peck { p.peck } else { 0.0 },
                dwell: if p.cycle == Cycle::Dwell {
                    p.dwell
                } else {
                    0.0
                },
                feed: p.feed,
            });
            t.drilled += 1;
        }
    }
    Ok((tp, t))
}

/// A hole bored with the tool: down a counter-clockwise helix (climb for an M3 spindle) of
/// at most `stepdown` per lap from the R plane to the depth, a finishing lap at the depth,
/// then off the wall to the centre and out.
fn bore(tp: &mut Toolpath, h: &Hole, p: &DrillParams) {
    let r = (h.diameter - p.tool.diameter) / 2.0;
    let c = h.center;
    let east = Point::new(c.x + r, c.y);
    let west = Point::new(c.x - r, c.y);
    tp.push(Move::Rapid {
        to: P3::at_z(east, p.safe_z),
    });
    tp.push(Move::Rapid {
        to: P3::at_z(east, p.retract),
    });
    let top = p.retract;
    let bottom = -p.depth;
    let laps = ((top - bottom) / p.stepdown).ceil().max(1.0) as usize;
    let half = |tp: &mut Toolpath, to: Point, z: f64| {
        tp.push(Move::Arc {
            to: P3::at_z(to, z),
            center: c,
            ccw: true,
            feed: p.bore_feed,
        })
    };
    for lap in 0..laps {
        let z0 = top - (top - bottom) * lap as f64 / laps as f64;
        let z1 = top - (top - bottom) * (lap + 1) as f64 / laps as f64;
        half(tp, west, 0.5 * (z0 + z1));
        half(tp, east, z1);
    }
    // the finishing lap, flat at the depth
    half(tp, west, bottom);
    half(tp, east, bottom);
    tp.push(Move::Linear {
        to: P3::at_z(c, bottom),
        feed: p.bore_feed,
    });
    tp.push(Move::Rapid {
        to: P3::at_z(c, p.safe_z),
    });
}

/// Length of the open path from the origin through `pts` in `order`.
fn path_length(pts: &[Point], order: &[usize]) -> f64 {
    let mut at = Point::new(0.0, 0.0);
    let mut len = 0.0;
    for &i in order {
        len += at.dist(pts[i]);
        at = pts[i];
    }
    len
}

/// The most holes 2-opt improves (its passes cost the square of the count).
const MAX_TWO_OPT: usize = 2000;

/// A short open tour from the origin through every point: nearest neighbour, then 2-opt
/// passes until none shortens it.
pub fn tour(pts: &[Point]) -> Vec<usize> {
    let n = pts.len();
    let mut left: Vec<usize> = (0..n).collect();
    let mut order = Vec::with_capacity(n);
    let mut at = Point::new(0.0, 0.0);
    while !left.is_empty() {
        let (k, _) = left
            .iter()
            .enumerate()
            .map(|(k, &i)| (k, at.dist(pts[i])))
            .fold((0, f64::INFINITY), |b, c| if c.1 < b.1 { c } else { b });
        let i = left.swap_remove(k);
        at = pts[i];
        order.push(i);
    }
    if n > MAX_TWO_OPT {
        return order;
    }
    // 2-opt on the open path whose first node is the origin: reversing order[i..=j]
    let origin = Point::new(0.0, 0.0);
    let node = |order: &[usize], k: isize| -> Point {
        if k < 0 {
            origin
        } else {
            pts[order[k as usize]]
        }
    };
    let mut improved = true;
    let mut passes = 0;
    while improved && passes < 100 {
        improved = false;
        passes += 1;
        for i in 0..n {
            for j in i + 1..n {
                let a = node(&order, i as isize - 1);
                let b = node(&order, i as isize);
                let c = node(&order, j as isize);
                let before = a.dist(b)
                    + if j + 1 < n {
                        c.dist(node(&order, j as isize + 1))
                    } else {
                        0.0
                    };
                let after = a.dist(c)
                    + if j + 1 < n {
                        b.dist(node(&order, j as isize + 1))
                    } else {
                        0.0
                    };
                if after < before - 1e-9 {
                    order[i..=j].reverse();
                    improved = true;
                }
            }
        }
    }
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hole(x: f64, y: f64, d: f64) -> Hole {
        Hole {
            center: Point::new(x, y),
            diameter: d,
            name: format!("hole at ({x}, {y})"),
        }
    }

    #[test]
    fn the_tour_visits_every_hole_once_and_is_no_longer_than_the_file_order() {
        // a zig-zag file order over a grid
        let mut pts = Vec::new();
        for k in 0..30 {
            let x = (k * 7 % 10) as f64 * 10.0;
            let y = (k * 3 % 10) as f64 * 10.0;
            pts.push(Point::new(x, y));
        }
        let order = tour(&pts);
        let mut seen = order.clone();
        seen.sort();
        assert_eq!(seen, (0..pts.len()).collect::<Vec<_>>());
        let file = path_length(&pts, &(0..pts.len()).collect::<Vec<_>>());
        assert!(
            path_length(&pts, &order) < file,
            "{} vs {file}",
            path_length(&pts, &order)
        );
    }

    #[test]
    fn pecks_reach_the_depth_and_bored_holes_keep_their_radius() {
        let p = DrillParams {
            tool: Tool::flat(3.0),
            depth: 4.0,
            cycle: Cycle::Peck,
            peck: 1.5,
            ..Default::default()
        };
        let (tp, t) = drill(&[hole(10.0, 10.0, 3.0), hole(30.0, 10.0, 8.0)], &p).unwrap();
        assert_eq!((t.drilled, t.bored), (1, 1));
        let lows: Vec<P3> = tp
            .expanded()
            .moves
            .iter()
            .filter_map(|m| match m {
                Move::Linear { to, .. } if (to.x - 10.0).abs() < 1e-12 => Some(*to),
                _ => None,
            })
            .collect();
        // from the R plane at 1: -0.5, -2, -3.5, -4
        let zs: Vec<f64> = lows.iter().map(|p| p.z).collect();
        assert_eq!(zs, vec![-0.5, -2.0, -3.5, -4.0]);
        for m in &tp.moves {
            if let Move::Arc { to, center, .. } = m {
                assert!((to.xy().dist(*center) + 1.5 - 4.0).abs() < 1e-9);
            }
        }
        let small = drill(&[hole(0.0, 0.0, 2.0)], &p).unwrap_err().to_string();
        assert!(
            small.contains("hole at (0, 0)") && small.contains("smaller"),
            "{small}"
        );
        let no_bore = DrillParams { bore: false, ..p };
        let e = drill(&[hole(30.0, 10.0, 8.0)], &no_bore)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("hole at (30, 10)") && e.contains("bore = false"),
            "{e}"
        );
    }
}
