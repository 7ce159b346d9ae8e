//! Profile: cut along a shape's outline with the tool outside, inside or on the line.

use super::{pass_depths, OpError};
use crate::geom::Shape;
use crate::geom::{Polyline, Segment};
use crate::offset::{offset_region, OffsetOptions};
use crate::toolpath::{Move, Tool, Toolpath, P3};
use serde::{Deserialize, Serialize};

/// Which side of the outline the tool runs on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Side {
    /// The tool centre is offset outward by its radius: the part keeps its full size.
    #[default]
    Outside,
    /// The tool centre is offset inward: a hole or pocket wall keeps its size.
    Inside,
    /// The tool centre follows the line (engraving, open paths).
    On,
}

/// Everything a profile needs besides the shape.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProfileParams {
    pub side: Side,
    pub tool: Tool,
    /// How far below the stock top (Z=0) the last pass cuts, mm (positive).
    pub depth: f64,
    /// The most each pass goes down, mm.
    pub stepdown: f64,
    /// Cutting feed, mm/min.
    pub feed: f64,
    /// Plunge feed, mm/min.
    pub plunge_feed: f64,
    /// Height for rapids above the stock, mm.
    pub safe_z: f64,
    /// Climb milling (true) or conventional (false), for a clockwise (M3) spindle.
    pub climb: bool,
    /// Spindle speed, rpm (0 leaves the spindle alone).
    pub spindle_rpm: f64,
    pub tolerance: f64,
}

impl Default for ProfileParams {
    fn default() -> Self {
        ProfileParams {
            side: Side::Outside,
            tool: Tool::flat(3.0),
            depth: 1.0,
            stepdown: 1.0,
            feed: 800.0,
            plunge_feed: 300.0,
            safe_z: 5.0,
            climb: true,
            spindle_rpm: 12000.0,
            tolerance: 1e-3,
        }
    }
}

impl ProfileParams {
    fn check(&self) -> Result<(), OpError> {
        let pos = |v: f64, what: &str| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(OpError::BadParam(format!(
                    "{what} must be a positive number, got {v}"
                )))
            }
        };
        pos(self.tool.diameter, "the tool diameter")?;
        pos(self.stepdown, "the step-down")?;
        pos(self.feed, "the feed")?;
        pos(self.plunge_feed, "the plunge feed")?;
        pos(self.tolerance, "the tolerance")?;
        if !(self.depth.is_finite() && self.depth >= 0.0) {
            return Err(OpError::BadParam(format!(
                "the depth must be 0 or more, got {}",
                self.depth
            )));
        }
        if !(self.safe_z.is_finite() && self.safe_z > 0.0) {
            return Err(OpError::BadParam(format!(
                "the safe Z must be above the stock (> 0), got {}",
                self.safe_z
            )));
        }
        Ok(())
    }
}

/// Plans a profile of every path of `shape`: closed paths are nested into regions and
/// offset by the tool radius (outward for `Outside`, inward for `Inside`); open paths are
/// followed as they are (only `On` makes sense for them). Each loop is cut at every pass
/// depth before the next loop starts.
pub fn profile(shape: &Shape, p: &ProfileParams) -> Result<Toolpath, OpError> {
    p.check()?;
    let opts = OffsetOptions {
        tolerance: p.tolerance,
        ..Default::default()
    };
    // (loop, whether the material to keep lies inside the loop)
    let mut loops: Vec<(Polyline, bool)> = Vec::new();
    for region in shape.regions() {
        match p.side {
            Side::On => {
                loops.push((region.outer.clone(), true));
                loops.extend(region.islands.iter().map(|i| (i.clone(), false)));
            }
            Side::Outside | Side::Inside => {
                let d = if p.side == Side::Outside {
                    p.tool.radius()
                } else {
                    -p.tool.radius()
                };
                for r in offset_region(&region, d, &opts)? {
                    // Outside: the part is inside the outer loop; Inside: the part (the
                    // material around the hole) lies outside the outer loop, and the islands
                    // are material either way.
                    loops.push((r.outer, p.side == Side::Outside));
                    loops.extend(r.islands.into_iter().map(|i| (i, true)));
                }
            }
        }
    }
    for open in shape.open_paths() {
        loops.push((open.clone(), false));
    }
    if loops.is_empty() {
        return Err(OpError::Empty(format!(
            "a {:?} profile with a {} mm tool leaves no path",
            p.side, p.tool.diameter
        )));
    }

    let mut tp = Toolpath::new(format!("profile {:?}", p.side).to_lowercase());
    tp.tool = Some(p.tool);
    tp.push(Move::Rapid {
        to: P3::new(0.0, 0.0, p.safe_z),
    });
    if p.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: p.spindle_rpm });
    }
    let depths = pass_depths(p.depth, p.stepdown);
    for (pl, material_inside) in loops {
        let pl = oriented(pl, material_inside, p.climb);
        let start = pl.vertices[0].pos();
        tp.push(Move::Rapid {
            to: P3::at_z(start, p.safe_z),
        });
        for &z in &depths {
            tp.push(Move::Linear {
                to: P3::at_z(start, z),
                feed: p.plunge_feed,
            });
            for seg in pl.segments() {
                tp.push(cut(seg, z, p.feed));
            }
            if !pl.closed {
                // back to the start at the safe height for the next pass of an open path
                tp.push(Move::Rapid {
                    to: P3::at_z(pl.vertices[pl.len() - 1].pos(), p.safe_z),
                });
                tp.push(Move::Rapid {
                    to: P3::at_z(start, p.safe_z),
                });
            }
        }
        tp.push(Move::Rapid {
            to: P3::at_z(pl.segments().last().map_or(start, |s| s.end()), p.safe_z),
        });
    }
    if p.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: 0.0 });
    }
    Ok(tp)
}

/// One segment of a loop as a cutting move at height `z`.
pub fn cut(seg: Segment, z: f64, feed: f64) -> Move {
    match seg {
        Segment::Line { b, .. } => Move::Linear {
            to: P3::at_z(b, z),
            feed,
        },
        Segment::Arc { b, center, ccw, .. } => Move::Arc {
            to: P3::at_z(b, z),
            center,
            ccw,
            feed,
        },
    }
}

/// Climb milling with an M3 spindle keeps the material on the right of travel: a loop with
/// the material inside runs clockwise, one with the material outside counter-clockwise.
fn oriented(pl: Polyline, material_inside: bool, climb: bool) -> Polyline {
    if !pl.closed {
        return pl;
    }
    let want_ccw = material_inside != climb;
    if pl.is_ccw() == want_ccw {
        pl
    } else {
        pl.reversed()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Point;

    #[test]
    fn on_line_profile_follows_the_outline_at_each_depth() {
        let sq = Polyline::rect(Point::new(0.0, 0.0), Point::new(10.0, 10.0));
        let p = ProfileParams {
            side: Side::On,
            depth: 2.0,
            stepdown: 0.8,
            ..Default::default()
        };
        let tp = profile(&Shape::new(vec![sq]), &p).unwrap();
        let b = tp.bounds().unwrap();
        assert!((b.min.z + 2.0).abs() < 1e-12);
        assert_eq!(pass_depths(2.0, 0.8).len(), 3);
        // every cutting move stays on the square's outline
        let outline = Polyline::rect(Point::new(0.0, 0.0), Point::new(10.0, 10.0));
        tp.walk(P3::default(), |_, m, to| {
            if let Move::Linear { .. } = m {
                assert!(outline.distance_to(to.xy()) < 1e-9);
            }
        });
        let (cut, _) = tp.lengths();
        // three laps, the plunge from the safe Z to the first depth, then two step-downs
        assert!((cut - (3.0 * 40.0 + 5.0 + 2.0)).abs() < 1e-9, "{cut}");
    }

    #[test]
    fn bad_parameters_are_errors() {
        let sq = Polyline::rect(Point::new(0.0, 0.0), Point::new(10.0, 10.0));
        let p = ProfileParams {
            stepdown: 0.0,
            ..Default::default()
        };
        assert!(matches!(
            profile(&Shape::new(vec![sq]), &p),
            Err(OpError::BadParam(_))
        ));
    }
}
