//! Profile: cut along a shape's outline with the tool outside, inside or on the line, with lead-in/lead-out arcs, holding tabs, and ramps down along the loop instead of plunges.
//!
//! Links between depth passes: a closed loop without leads steps down in place at its
//! start (in its own slot). A loop with leads and no tabs goes back the way it came
//! between passes, `LINK_LIFT` over its own path (`link_back`), instead of up to the safe
//! height; between contours, on open paths and with tabs the tool goes to the safe
//! height (a profile clears nothing between its contours to link through).

use super::entry::{self, Entry, Plunges};
use super::{pass_depths, Cutting, OpError};
use crate::geom::Shape;
use crate::geom::{Point, Polyline, Segment, Vertex};
use crate::offset::{offset_region, OffsetOptions};
use crate::toolpath::{Move, Toolpath, P3};
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

impl Side {
    /// The side as `--side` spells it: `outside`, `inside`, `on`.
    pub fn name(self) -> &'static str {
        match self {
            Side::Outside => "outside",
            Side::Inside => "inside",
            Side::On => "on",
        }
    }

    /// The profile in words: "an outside profile", "an inside profile", "a profile on the
    /// line".
    pub fn profile_words(self) -> &'static str {
        match self {
            Side::Outside => "an outside profile",
            Side::Inside => "an inside profile",
            Side::On => "a profile on the line",
        }
    }
}

/// Everything a profile needs besides the shape (keys left out of JSON take the defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProfileParams {
    pub side: Side,
    /// Tool, depths, feeds and heights (`"cut": { … }` in JSON).
    pub cut: Cutting,
    /// Radius of the tangent lead-in arc onto each closed loop, mm (0: plunge on the loop).
    /// The arc lies on the side away from the material that stays.
    #[serde(default)]
    pub lead_in: f64,
    /// Radius of the tangent lead-out arc off each closed loop, mm (0: none).
    #[serde(default)]
    pub lead_out: f64,
    /// Holding tabs per closed loop (0: none), evenly spaced along it.
    #[serde(default)]
    pub tabs: usize,
    /// Width of the material each tab leaves, mm (the tool rises over this plus its diameter).
    #[serde(default)]
    pub tab_width: f64,
    /// Height of the tabs above the bottom of the cut, mm: passes deeper than
    /// depth - height rise to it over each tab.
    #[serde(default)]
    pub tab_height: f64,
}

impl Default for ProfileParams {
    fn default() -> Self {
        ProfileParams {
            side: Side::Outside,
            cut: Cutting::default(),
            lead_in: 0.0,
            lead_out: 0.0,
            tabs: 0,
            tab_width: 3.0,
            tab_height: 0.5,
        }
    }
}

impl ProfileParams {
    fn check(&self) -> Result<(), OpError> {
        self.cut.check()?;
        for (v, what) in [
            (self.lead_in, "the lead-in radius"),
            (self.lead_out, "the lead-out radius"),
            (self.tab_width, "the tab width"),
            (self.tab_height, "the tab height"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(OpError::BadParam(format!(
                    "{what} must be 0 or more, got {v}"
                )));
            }
        }
        if self.tabs > 0 && (self.tab_width <= 0.0 || self.tab_height <= 0.0) {
            return Err(OpError::BadParam(
                "tabs need a width and a height above 0".into(),
            ));
        }
        if self.tabs > 0 && self.tab_height >= self.cut.depth {
            return Err(OpError::BadParam(format!(
                "a tab height of {} mm would not cut below the stock top at depth {} mm",
                self.tab_height, self.cut.depth
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
    plan(shape, p, true)
}

/// The profile as it was planned before links at depth: a loop with lead arcs goes up to
/// the safe height after every depth pass (for comparison: retract counts, machine time).
pub fn profile_safe_links(shape: &Shape, p: &ProfileParams) -> Result<Toolpath, OpError> {
    plan(shape, p, false)
}

fn plan(shape: &Shape, p: &ProfileParams, links: bool) -> Result<Toolpath, OpError> {
    p.check()?;
    super::check_range(shape)?;
    let opts = OffsetOptions {
        tolerance: p.cut.tolerance,
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
                    p.cut.tool.radius()
                } else {
                    -p.cut.tool.radius()
                };
                for r in offset_region(&region, d, &opts)? {
                    // Outside: the part is inside the outer loop and its holes' loops lie
                    // in the holes, the part outside them; Inside: the part (the material
                    // around the hole) lies outside the outer loop, and the islands left
                    // standing in the hole are material inside their loops.
                    loops.push((r.outer, p.side == Side::Outside));
                    loops.extend(r.islands.into_iter().map(|i| (i, p.side == Side::Inside)));
                }
            }
        }
    }
    // an open contour has no inside or outside: the tool can only follow its line
    let open: Vec<&Polyline> = shape.open_paths().collect();
    let mut open_warning = None;
    if p.side != Side::On && !open.is_empty() {
        let ends = |pl: &Polyline| match (pl.vertices.first(), pl.vertices.last()) {
            (Some(a), Some(b)) => {
                let (a, b) = (a.pos(), b.pos());
                format!("from ({:.3}, {:.3}) to ({:.3}, {:.3})", a.x, a.y, b.x, b.y)
            }
            _ => "empty".to_string(),
        };
        let what = format!(
            "{} open contour{} ({}{}) {} no {}: only a closed contour does",
            open.len(),
            if open.len() == 1 { "" } else { "s" },
            ends(open[0]),
            if open.len() > 1 { ", …" } else { "" },
            if open.len() == 1 { "has" } else { "have" },
            p.side.name()
        );
        if loops.is_empty() {
            return Err(OpError::BadParam(format!(
                "{} needs a closed contour: {what}; close it, or cut along it with --side on",
                p.side.profile_words()
            )));
        }
        open_warning = Some(format!(
            "{what}; {} cut along {} line (as --side on), not {}",
            if open.len() == 1 { "it is" } else { "they are" },
            if open.len() == 1 { "its" } else { "their" },
            p.side.name()
        ));
    }
    for pl in open {
        loops.push((pl.clone(), false));
    }
    if loops.is_empty() {
        return Err(OpError::Empty(format!(
            "{} with a {} mm tool leaves no path",
            p.side.profile_words(),
            p.cut.tool.diameter
        )));
    }

    let mut tp = Toolpath::new(format!("profile {}", p.side.name()));
    tp.tool = Some(p.cut.tool);
    tp.warnings.extend(open_warning);
    tp.push(Move::Rapid {
        to: P3::new(0.0, 0.0, p.cut.safe_z),
    });
    if p.cut.spindle_rpm > 0.0 {
        tp.push(Move::Spindle {
            rpm: p.cut.spindle_rpm,
        });
    }
    let depths = pass_depths(p.cut.depth, p.cut.stepdown);
    let tab_z = -p.cut.depth + p.tab_height;
    let ramps = p.cut.entry != Entry::Plunge;
    let slope = p.cut.ramp_angle.to_radians().tan();
    let (feed, plunge) = (p.cut.feed, p.cut.plunge_feed);
    let d = p.cut.tool.diameter;
    let mut plunges = Plunges::default();
    if p.cut.spiral && ramps && p.tabs > 0 {
        tp.warnings.push(
            "a spiral cannot leave tabs: the passes go down one by one, each by its own ramp"
                .into(),
        );
    }
    for (pl, material_inside) in loops {
        let mut pl = oriented(pl, material_inside, p.cut.climb);
        // the most a lead arc may bend away from the loop's start without crossing it
        let mut lead_room = f64::INFINITY;
        if pl.closed && (p.lead_in > 0.0 || p.lead_out > 0.0) {
            (pl, lead_room) = start_clear_of_corners(pl);
            if p.lead_in.max(p.lead_out) > lead_room {
                tp.warnings.push(format!(
                    "a loop's straight sides are too short for {} mm leads: its leads are {lead_room} mm",
                    p.lead_in.max(p.lead_out)
                ));
            }
        }
        let start = pl.vertices[0].pos();
        if !pl.closed {
            let len = pl.length();
            tp.push(Move::Rapid {
                to: P3::at_z(start, p.cut.safe_z),
            });
            for (k, &z) in depths.iter().enumerate() {
                let z_top = if k == 0 { 0.0 } else { depths[k - 1] };
                if ramps && len >= d {
                    tp.push(Move::Linear {
                        to: P3::at_z(start, z_top),
                        feed: plunge,
                    });
                    tp.moves
                        .extend(entry::zigzag(&pl, len, z_top, z, slope, feed));
                } else {
                    if ramps {
                        plunges.note(P3::at_z(start, z));
                    }
                    tp.push(Move::Linear {
                        to: P3::at_z(start, z),
                        feed: plunge,
                    });
                }
                for seg in pl.segments() {
                    tp.push(cut(seg, z, feed));
                }
                // back to the start at the safe height for the next pass of an open path
                tp.push(Move::Rapid {
                    to: P3::at_z(pl.vertices[pl.len() - 1].pos(), p.cut.safe_z),
                });
                tp.push(Move::Rapid {
                    to: P3::at_z(start, p.cut.safe_z),
                });
            }
            continue;
        }
        // the side free of material: left of travel when the material is on the right
        let free_left = pl.is_ccw() != material_inside;
        let t_start = pl.segment(0).tangent_at(0.0);
        let t_end = pl.segment(pl.segment_count() - 1).tangent_at(1.0);
        let (r_in, r_out) = (p.lead_in.min(lead_room), p.lead_out.min(lead_room));
        let lead_in = (r_in > 0.0).then(|| lead_arc(start, t_start, r_in, free_left, true));
        let lead_out = (r_out > 0.0).then(|| lead_arc(start, t_end, r_out, free_left, false));
        let tabs = if p.tabs > 0 {
            tab_spans(pl.length(), p.tabs, p.tab_width + p.cut.tool.diameter)
        } else {
            Vec::new()
        };
        // without leads the tool steps down in place at the loop's start
        let in_place = lead_in.is_none() && lead_out.is_none();
        if ramps && p.cut.spiral && tabs.is_empty() {
            spiral(&mut tp, &pl, lead_in, lead_out, &depths, slope, p);
            continue;
        }
        // room for a ramp back and forth from the start: up to the first tab, or the loop
        let room = tabs.first().map_or(pl.length(), |t| t.0);
        // the loop as this pass cuts it (a ramp around it restarts it where it reached depth)
        let mut cur = pl.clone();
        // links at depth between the passes of a loop with leads (see `link_back`)
        let link = links && !in_place && tabs.is_empty() && p.cut.safe_z > super::pocket::LINK_LIFT;
        for (k, &z) in depths.iter().enumerate() {
            let z_top = if k == 0 { 0.0 } else { depths[k - 1] };
            let entry = lead_in.map_or(start, |(a, _, _)| a);
            // where the lead-in ran at this pass: from the height at its start to the
            // height at the loop's start
            let mut lead_in_z = (z, z);
            if k == 0 || !(in_place || link) {
                tp.push(Move::Rapid {
                    to: P3::at_z(entry, p.cut.safe_z),
                });
            }
            if !ramps {
                tp.push(Move::Linear {
                    to: P3::at_z(entry, z),
                    feed: plunge,
                });
                if let Some((_, center, ccw)) = lead_in {
                    tp.push(Move::Arc {
                        to: P3::at_z(start, z),
                        center,
                        ccw,
                        feed,
                    });
                }
            } else {
                // the height the ramp along the loop starts from
                let z_from = if let Some((a, center, ccw)) = lead_in {
                    // from the stock top at the lead-in's start (air at every pass), down
                    // the lead-in as far as the ramp angle lets it
                    if tp_pos(&tp).is_some_and(|q| q.z > 1e-12) {
                        tp.push(Move::Linear {
                            to: P3::at_z(a, 0.0),
                            feed: plunge,
                        });
                    }
                    let len = crate::toolpath::arc_segment(a, start, center, ccw).length();
                    let za = (-(len * slope)).max(z);
                    lead_in_z = (0.0, za);
                    tp.push(Move::Arc {
                        to: P3::at_z(start, za),
                        center,
                        ccw,
                        feed,
                    });
                    za
                } else {
                    // down through the air to the floor of the last pass
                    let here = tp_pos(&tp).unwrap_or(P3::at_z(entry, p.cut.safe_z));
                    if here.z > z_top + 1e-12 {
                        tp.push(Move::Linear {
                            to: P3::at_z(here.xy(), z_top),
                            feed: plunge,
                        });
                    }
                    z_top
                };
                if z_from > z + 1e-12 {
                    if tabs.is_empty() && in_place && cur.length() >= d {
                        let (moves, rest) = entry::ramp_around(&cur, z_from, z, slope, feed);
                        tp.moves.extend(moves);
                        cur = rest;
                    } else if room >= d {
                        tp.moves
                            .extend(entry::zigzag(&pl, room, z_from, z, slope, feed));
                    } else {
                        plunges.note(P3::at_z(cur.vertices[0].pos(), z));
                        tp.push(Move::Linear {
                            to: P3::at_z(cur.vertices[0].pos(), z),
                            feed: plunge,
                        });
                    }
                }
            }
            if z < tab_z - 1e-9 && !tabs.is_empty() {
                cut_with_tabs(&mut tp, &pl, &tabs, z, tab_z, ramps.then_some(slope), p);
            } else {
                for seg in cur.segments() {
                    tp.push(cut(seg, z, feed));
                }
            }
            let mut exit = cur.vertices[0].pos();
            if let Some((b, center, ccw)) = lead_out {
                tp.push(Move::Arc {
                    to: P3::at_z(b, z),
                    center,
                    ccw,
                    feed,
                });
                exit = b;
            }
            if link && k + 1 < depths.len() {
                link_back(&mut tp, start, lead_in, lead_out, lead_in_z, z, p);
            } else if !in_place || k + 1 == depths.len() {
                tp.push(Move::Rapid {
                    to: P3::at_z(exit, p.cut.safe_z),
                });
            }
        }
    }
    if p.cut.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: 0.0 });
    }
    tp.warnings.extend(plunges.warning(
        "the pass was shorter than the tool diameter (or its first tab nearer) for a ramp",
    ));
    Ok(tp)
}

/// Links at depth between two depth passes of a closed loop with leads: instead of the
/// safe height, the tool goes back the way it came, [`super::pocket::LINK_LIFT`] over it:
/// up from the lead-out's end, back along the lead-out (cut at depth `z`), up at the loop's
/// start, and back up the lead-in as it ran at this pass (from `lead_in_z.0` at its start
/// to `lead_in_z.1` at the loop's start), to stand over the lead-in's start. Every
/// position lies straight over one the flat tool took on this pass, whose column above its
/// end the tool itself cleared, so the link moves through air; the next pass goes down from
/// there as it did from the safe height.
fn link_back(
    tp: &mut Toolpath,
    start: Point,
    lead_in: Option<(Point, Point, bool)>,
    lead_out: Option<(Point, Point, bool)>,
    lead_in_z: (f64, f64),
    z: f64,
    p: &ProfileParams,
) {
    let lift = super::pocket::LINK_LIFT;
    let (feed, plunge) = (p.cut.feed, p.cut.plunge_feed);
    let Some(here) = tp_pos(tp) else { return };
    tp.push(Move::Linear {
        to: P3::at_z(here.xy(), z + lift),
        feed: plunge,
    });
    if let Some((_, center, ccw)) = lead_out {
        tp.push(Move::Arc {
            to: P3::at_z(start, z + lift),
            center,
            ccw: !ccw,
            feed,
        });
    }
    if let Some((a, center, ccw)) = lead_in {
        if lead_in_z.1 > z + 1e-12 {
            tp.push(Move::Linear {
                to: P3::at_z(start, lead_in_z.1 + lift),
                feed: plunge,
            });
        }
        tp.push(Move::Arc {
            to: P3::at_z(a, lead_in_z.0 + lift),
            center,
            ccw: !ccw,
            feed,
        });
    }
}

/// Where the tool path last moved to.
fn tp_pos(tp: &Toolpath) -> Option<P3> {
    tp.moves.iter().rev().find_map(|m| match m {
        Move::Rapid { to } | Move::Linear { to, .. } | Move::Arc { to, .. } => Some(*to),
        _ => None,
    })
}

/// A closed loop cut as one helix along itself: from the stock top down to the depth at
/// most a step-down per lap and never steeper than the ramp angle, then once round at the
/// depth, then on round to the loop's start for the lead-out.
fn spiral(
    tp: &mut Toolpath,
    pl: &Polyline,
    lead_in: Option<(Point, Point, bool)>,
    lead_out: Option<(Point, Point, bool)>,
    depths: &[f64],
    slope: f64,
    p: &ProfileParams,
) {
    let start = pl.vertices[0].pos();
    let feed = p.cut.feed;
    let z = *depths.last().unwrap_or(&0.0);
    let entry = lead_in.map_or(start, |(a, _, _)| a);
    tp.push(Move::Rapid {
        to: P3::at_z(entry, p.cut.safe_z),
    });
    tp.push(Move::Linear {
        to: P3::at_z(entry, 0.0),
        feed: p.cut.plunge_feed,
    });
    if let Some((_, center, ccw)) = lead_in {
        tp.push(Move::Arc {
            to: P3::at_z(start, 0.0),
            center,
            ccw,
            feed,
        });
    }
    let len = pl.length();
    let s = slope.min(p.cut.stepdown / len);
    let (moves, rest) = entry::ramp_around(pl, 0.0, z, s, feed);
    tp.moves.extend(moves);
    for seg in rest.segments() {
        tp.push(cut(seg, z, feed));
    }
    let mut exit = rest.vertices[0].pos();
    if let Some((b, center, ccw)) = lead_out {
        // on along the loop to its start, where the lead-out leaves it
        let back = entry::restart(&rest, 0, 0.0);
        let to_start = len - along_loop(pl, exit);
        let mut at = 0.0;
        for seg in back.segments() {
            if at >= to_start - 1e-9 {
                break;
            }
            let l = seg.length();
            let piece = if at + l > to_start {
                entry::part(seg, 0.0, to_start - at)
            } else {
                seg
            };
            tp.push(cut(piece, z, feed));
            at += l;
        }
        tp.push(Move::Arc {
            to: P3::at_z(b, z),
            center,
            ccw,
            feed,
        });
        exit = b;
    }
    tp.push(Move::Rapid {
        to: P3::at_z(exit, p.cut.safe_z),
    });
}

/// How far along the closed loop (from its start) its point `q` lies.
fn along_loop(pl: &Polyline, q: Point) -> f64 {
    let mut best = (f64::INFINITY, 0.0);
    let mut at = 0.0;
    for s in pl.segments() {
        let c = s.closest_point(q);
        let d = c.dist(q);
        if d < best.0 {
            let l = match s {
                Segment::Line { a, .. } => a.dist(c),
                Segment::Arc { a, center, .. } => {
                    let part = crate::toolpath::arc_segment(a, c, center, s.sweep() > 0.0);
                    part.length().min(s.length())
                }
            };
            best = (d, at + l);
        }
        at += s.length();
    }
    best.1
}

/// A quarter-circle lead of radius `r` touching the loop at `s` with tangent `t`, on the
/// free side. A lead-in returns (its start, centre, ccw) and ends at `s`; a lead-out
/// returns (its end, centre, ccw) and starts at `s`.
fn lead_arc(s: Point, t: Point, r: f64, free_left: bool, entering: bool) -> (Point, Point, bool) {
    let n = if free_left { t.perp() } else { -t.perp() };
    let center = s + n * r;
    let far = if entering {
        center - t * r
    } else {
        center + t * r
    };
    (far, center, free_left)
}

/// A closed loop that turns sharply at its first vertex (an inside profile's corner) starts
/// instead at the middle of its longest straight side: a lead arc leaves the loop's start
/// backwards (lead-in) or forwards (lead-out), and at a sharp corner that is across the
/// next side, into the part. Returns the loop and the largest lead radius that stays within
/// its start side's halves (infinite for a loop smooth at its start, kept as it is: round
/// joins).
fn start_clear_of_corners(pl: Polyline) -> (Polyline, f64) {
    if pl.segment_count() < 2 {
        return (pl, f64::INFINITY);
    }
    let t_in = pl.segment(pl.segment_count() - 1).tangent_at(1.0);
    let t_out = pl.segment(0).tangent_at(0.0);
    if t_in.cross(t_out).atan2(t_in.dot(t_out)).abs() < 1e-3 {
        return (pl, f64::INFINITY);
    }
    let n = pl.len();
    let side = |i: usize| pl.vertices[i].pos().dist(pl.vertices[(i + 1) % n].pos());
    let longest = (0..n)
        .filter(|&i| pl.vertices[i].bulge == 0.0)
        .max_by(|&i, &j| side(i).total_cmp(&side(j)));
    let Some(i) = longest else {
        // all arcs and sharp at the start: no straight side to start on
        return (pl, 0.0);
    };
    let room = side(i) / 2.0;
    let mid = pl.vertices[i]
        .pos()
        .lerp(pl.vertices[(i + 1) % n].pos(), 0.5);
    let mut vertices = vec![Vertex::new(mid.x, mid.y, 0.0)];
    vertices.extend((1..=n).map(|k| pl.vertices[(i + k) % n]));
    (Polyline::new(vertices, true), room)
}

/// Where the tabs sit along a loop of length `len`: `count` stretches of `width`,
/// centred at evenly spaced lengths (a tab never wider than its share of the loop).
fn tab_spans(len: f64, count: usize, width: f64) -> Vec<(f64, f64)> {
    let share = len / count as f64;
    let w = width.min(share * 0.5);
    (0..count)
        .map(|k| {
            let mid = share * (k as f64 + 0.5);
            (mid - w / 2.0, mid + w / 2.0)
        })
        .collect()
}

/// One closed pass at `z` that rises to `tab_z` over every tab span. After a tab the tool
/// goes back down along the loop no steeper than `slope` when one is given (the tab is
/// then a trapezoid, `tab_width` wide at its top), else straight down.
fn cut_with_tabs(
    tp: &mut Toolpath,
    pl: &Polyline,
    tabs: &[(f64, f64)],
    z: f64,
    tab_z: f64,
    slope: Option<f64>,
    p: &ProfileParams,
) {
    // break points along the loop, and whether the stretch after each is a tab
    let mut at = 0.0;
    let mut on_tab = false;
    let mut zc = z;
    let feed = p.cut.feed;
    for seg in pl.segments() {
        let len = seg.length();
        let mut cuts: Vec<f64> = tabs
            .iter()
            .flat_map(|&(a, b)| [a, b])
            .filter(|&l| l > at && l < at + len)
            .map(|l| l - at)
            .collect();
        cuts.push(len);
        let mut from = 0.0;
        for c in cuts {
            if c - from > 1e-9 {
                let piece = entry::part(seg, from, c);
                let mid = at + 0.5 * (from + c);
                let tab = tabs.iter().any(|&(a, b)| mid > a && mid < b);
                if tab {
                    if !on_tab {
                        tp.push(Move::Linear {
                            to: P3::at_z(piece.start(), tab_z),
                            feed: p.cut.plunge_feed,
                        });
                    }
                    tp.push(cut(piece, tab_z, feed));
                    zc = tab_z;
                } else if on_tab && slope.is_none() {
                    tp.push(Move::Linear {
                        to: P3::at_z(piece.start(), z),
                        feed: p.cut.plunge_feed,
                    });
                    tp.push(cut(piece, z, feed));
                    zc = z;
                } else if zc > z + 1e-12 {
                    // on down from the tab along the loop
                    let k = slope.unwrap_or(f64::INFINITY);
                    let plen = piece.length();
                    let need = (zc - z) / k;
                    if need >= plen {
                        zc -= plen * k;
                        tp.push(entry::descend(piece, zc, feed));
                    } else {
                        tp.push(entry::descend(entry::part(piece, 0.0, need), z, feed));
                        tp.push(cut(entry::part(piece, need, plen), z, feed));
                        zc = z;
                    }
                } else {
                    tp.push(cut(piece, z, feed));
                }
                on_tab = tab;
            }
            from = c;
        }
        at += len;
    }
    if zc > z + 1e-12 {
        match slope {
            // on down along the loop's start, which this pass has cut to the depth already,
            // and back to the start at the depth
            Some(k) => {
                tp.moves.extend(entry::ramp_around(pl, zc, z, k, feed).0);
                tp.moves
                    .extend(entry::back_along(pl, (zc - z) / k, z, feed));
            }
            None => tp.push(Move::Linear {
                to: P3::at_z(pl.vertices[0].pos(), z),
                feed: p.cut.plunge_feed,
            }),
        }
    }
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
            cut: Cutting {
                depth: 2.0,
                stepdown: 0.8,
                entry: Entry::Plunge,
                ..ProfileParams::default().cut
            },
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
    fn without_a_lead_in_the_loop_is_ramped_down_along_itself() {
        let sq = Polyline::rect(Point::new(0.0, 0.0), Point::new(10.0, 10.0));
        let p = ProfileParams {
            side: Side::On,
            cut: Cutting {
                depth: 2.0,
                stepdown: 0.8,
                ..ProfileParams::default().cut
            },
            ..Default::default()
        };
        let tp = profile(&Shape::new(vec![sq.clone()]), &p).unwrap();
        let slope = p.cut.ramp_angle.to_radians().tan();
        let mut descents = 0;
        tp.walk(P3::default(), |from, m, to| {
            if matches!(m, Move::Linear { .. } | Move::Arc { .. }) && to.z < from.z - 1e-12 {
                let xy = from.xy().dist(to.xy());
                if from.z <= 1e-12 {
                    // below the stock top: along the outline, never steeper than the angle
                    assert!(xy > 0.0, "a plunge to {to:?}");
                    assert!(
                        (from.z - to.z) <= xy * slope * (1.0 + 1e-9),
                        "{from:?} -> {to:?}"
                    );
                    assert!(sq.distance_to(to.xy()) < 1e-9);
                    descents += 1;
                }
            }
        });
        assert!(descents >= 3);
        assert!(tp.warnings.is_empty(), "{:?}", tp.warnings);
        assert!((tp.bounds().unwrap().min.z + 2.0).abs() < 1e-12);
    }

    #[test]
    fn bad_parameters_are_errors() {
        let sq = Polyline::rect(Point::new(0.0, 0.0), Point::new(10.0, 10.0));
        let p = ProfileParams {
            cut: Cutting {
                stepdown: 0.0,
                ..ProfileParams::default().cut
            },
            ..Default::default()
        };
        assert!(matches!(
            profile(&Shape::new(vec![sq]), &p),
            Err(OpError::BadParam(_))
        ));
    }

    #[test]
    fn lead_arcs_are_tangent_and_stay_off_the_part() {
        let sq = Polyline::rect(Point::new(0.0, 0.0), Point::new(20.0, 20.0));
        for climb in [true, false] {
            let p = ProfileParams {
                side: Side::On,
                lead_in: 3.0,
                lead_out: 2.0,
                cut: Cutting {
                    climb,
                    ..ProfileParams::default().cut
                },
                ..Default::default()
            };
            let tp = profile(&Shape::new(vec![sq.clone()]), &p).unwrap();
            let arcs: Vec<(P3, P3, Point)> = {
                let mut v = Vec::new();
                tp.walk(P3::default(), |from, m, to| {
                    if let Move::Arc { center, .. } = m {
                        v.push((from, to, *center));
                    }
                });
                v
            };
            assert_eq!(arcs.len(), 2);
            for (from, to, c) in arcs {
                // quarter circles of the lead radius, touching the square at its corner start,
                // and never inside the part (the material of an On profile of a closed
                // outline is taken to be inside it)
                let r = from.xy().dist(c);
                assert!((r - to.xy().dist(c)).abs() < 1e-9);
                assert!((from.xy().dist(to.xy()) - r * 2f64.sqrt()).abs() < 1e-9);
                let seg = crate::toolpath::arc_segment(from.xy(), to.xy(), c, {
                    let mut ccw = false;
                    tp.walk(P3::default(), |_, m, _| {
                        if let Move::Arc { center, ccw: w, .. } = m {
                            if *center == c {
                                ccw = *w;
                            }
                        }
                    });
                    ccw
                });
                for k in 1..10 {
                    let q = seg.point_at(k as f64 / 10.0);
                    assert!(!sq.contains(q), "lead point {q:?} inside the part");
                }
            }
        }
    }

    #[test]
    fn tabs_rise_on_the_last_passes_only() {
        let sq = Polyline::rect(Point::new(0.0, 0.0), Point::new(40.0, 40.0));
        let p = ProfileParams {
            side: Side::On,
            tabs: 4,
            tab_width: 2.0,
            tab_height: 1.5,
            cut: Cutting {
                depth: 3.0,
                stepdown: 1.0,
                ..ProfileParams::default().cut
            },
            ..Default::default()
        };
        let tp = profile(&Shape::new(vec![sq]), &p).unwrap();
        // raised length per depth: the passes at -2 and -3 lie below the tab top at -1.5
        let mut raised = std::collections::BTreeMap::<i64, f64>::new();
        let mut rises = 0;
        tp.walk(P3::default(), |from, m, to| {
            if matches!(m, Move::Linear { .. })
                && (from.z + 1.5).abs() < 1e-9
                && (to.z + 1.5).abs() < 1e-9
            {
                *raised.entry(0).or_default() += from.dist(to);
            }
            if matches!(m, Move::Linear { .. })
                && from.xy().dist(to.xy()) < 1e-12
                && (to.z + 1.5).abs() < 1e-9
                && from.z < to.z
            {
                rises += 1;
            }
        });
        assert_eq!(rises, 8, "four tabs on each of two passes");
        // each tab: its width plus the tool diameter (3 mm)
        assert!((raised[&0] - 8.0 * 5.0).abs() < 1e-9, "{raised:?}");
        assert!((tp.bounds().unwrap().min.z + 3.0).abs() < 1e-12);
    }
}
