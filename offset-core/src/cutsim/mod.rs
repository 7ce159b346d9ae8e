//! Cutting simulation: replays a tool path against the stock, held as a fine height map, and reports per move the tool's engagement, the material it removed, where it cut air, gouged the part or went through material at the rapid rate; and for the whole program the material left.
//!
//! The model (docs/toolpaths.md, "Cutting simulation"):
//! - The stock is a height map of square cells (`cell` mm, default a 120th of the tool
//!   diameter) over the stock's outline, its top at `top`; a cell stands for the material
//!   column at its centre. The flat end of radius R lowers every cell whose centre it passes
//!   over to the lowest bottom that passes over it (ramps and helices exactly, arcs as
//!   chords within an eighth of a cell and a quarter of the tolerance).
//! - Engagement is read at points every cell along each move, before the tool cuts there:
//!   181 probes on the half of a circle just outside the tool (R + 0.72 cell) that faces the
//!   way it moves, each one degree; a probe is engaged where the material stands above the
//!   tool's bottom. A slot reads 180°, a straight cut at step-over s reads
//!   arccos(1 − 2s/D); a move straight down reads 360° where there is material under the
//!   tool, 0 in air.
//! - With a [`Part`] (the regions to clear down to a floor; everything else is the part at
//!   the stock top), a cell cut below what may be cut there is a gouge (cells outside the
//!   regions count only farther than `tolerance` from them), and at the end a cell of the
//!   regions that the tool could reach (a tool disc that fits touches it) and that stands
//!   above the floor is material left.

pub mod feed;
pub mod grid;
pub mod picture;

use crate::geom::{Point, Region};
use crate::stats::Kinematics;
use crate::toolpath::{arc_segment, Move, Tool, Toolpath, P3};
use grid::Grid;
use serde::{Deserialize, Serialize};

/// Why a simulation could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    #[error("the tool diameter must be a positive number, got {0}")]
    BadTool(f64),
    #[error("the simulation cell must be a positive number of mm, got {0}")]
    BadCell(f64),
    #[error("the stock has no area (give its outline or box)")]
    NoStock,
    #[error("simulating {w:.0} × {h:.0} mm at {cell} mm cells takes {cells} cells, more than {max}; use a larger --cell")]
    TooLarge {
        w: f64,
        h: f64,
        cell: f64,
        cells: usize,
        max: usize,
    },
}

/// The most cells a simulation may hold (about 1 GB of heights and marks).
pub const MAX_CELLS: usize = 150_000_000;

/// The material before the program runs: the stock's outline (regions, islands are holes)
/// and its top.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stock {
    pub outline: Vec<Region>,
    /// Z of the stock's top, mm (default 0).
    pub top: f64,
}

impl Stock {
    /// A block over the box from `min` to `max`, its top at `top`.
    pub fn block(min: Point, max: Point, top: f64) -> Stock {
        Stock {
            outline: vec![Region::new(crate::geom::Polyline::rect(min, max), vec![])],
            top,
        }
    }
}

/// What the program is meant to make: the regions to clear down to `floor` (pockets); the
/// stock everywhere else is the part and must stay at the stock top.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Part {
    pub clear: Vec<Region>,
    /// Z of the pockets' floor.
    pub floor: f64,
}

/// How to simulate.
#[derive(Clone, Debug, PartialEq)]
pub struct SimOptions {
    pub tool: Tool,
    /// Side of a cell, mm (0: the tool diameter / 120).
    pub cell: f64,
    pub part: Option<Part>,
    /// How far from the part a cut may come before it counts as a gouge, and how far
    /// above the floor material may stand before it counts as left, mm.
    pub tolerance: f64,
    /// For the time of each move (removal rate over time).
    pub kinematics: Kinematics,
}

impl SimOptions {
    pub fn new(tool: Tool) -> SimOptions {
        SimOptions {
            tool,
            cell: 0.0,
            part: None,
            tolerance: 0.01,
            kinematics: Kinematics::default(),
        }
    }
    /// The cell side in use.
    pub fn cell_mm(&self) -> f64 {
        if self.cell > 0.0 {
            self.cell
        } else {
            self.tool.diameter / 120.0
        }
    }
}

/// What kind of move a report is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MoveKind {
    Rapid,
    /// A cutting move at one depth (or rising).
    Cut,
    /// A cutting move that goes down while moving across (ramp, helix), and the flat turn
    /// that closes a helix (an arc about the centre of the descending arc before it, which
    /// cuts the wedge the last descending turn leaves).
    Entry,
    /// Straight down.
    Plunge,
}

/// One move of the program, as the simulation saw it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MoveReport {
    /// Index into the tool path's moves.
    pub index: usize,
    pub kind: MoveKind,
    pub from: P3,
    pub to: P3,
    pub length: f64,
    /// mm/min (rapids: the rapid rate).
    pub feed: f64,
    /// The largest and the mean engagement along the move, degrees.
    pub engagement: f64,
    pub mean_engagement: f64,
    /// Material removed, mm³.
    pub removed: f64,
    /// Length of the move where the tool touched no material, mm.
    pub air: f64,
    /// Cells cut where the part is, or below the floor.
    pub gouges: usize,
    /// The time the move takes at its feed, s (no acceleration).
    pub time: f64,
}

/// A point along the path with the engagement there (for the picture).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    pub at: P3,
    pub engagement: f64,
    /// The report (index into [`Report::moves`]) it belongs to.
    pub report: usize,
}

/// The whole program, as the simulation saw it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub moves: Vec<MoveReport>,
    pub samples: Vec<Sample>,
    pub cell: f64,
    /// Material removed in all, mm³.
    pub removed: f64,
    /// Gouged cells and the first place one was found.
    pub gouges: usize,
    pub first_gouge: Option<Point>,
    /// Rapids that went through material, and the first such move's index.
    pub rapid_cuts: usize,
    pub first_rapid_cut: Option<usize>,
    /// With a part: cells of the regions the tool could reach that stand above the floor,
    /// their area (mm²) and one of them; and the cells of the regions in all.
    pub left: usize,
    pub left_area: f64,
    pub first_left: Option<Point>,
    pub region_cells: usize,
}

/// The longest run of cutting in air.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AirCut {
    pub length: f64,
    /// Where it starts, and the report of its first move.
    pub start: P3,
    pub report: usize,
}

impl Report {
    /// The cutting move (not rapid) with the largest engagement of the given kinds.
    pub fn worst(&self, kinds: &[MoveKind]) -> Option<&MoveReport> {
        self.moves
            .iter()
            .filter(|m| kinds.contains(&m.kind))
            .max_by(|a, b| a.engagement.total_cmp(&b.engagement))
    }

    /// The longest stretch of cutting moves in air, unbroken by a rapid or a cut.
    pub fn longest_air(&self) -> Option<AirCut> {
        let mut best: Option<AirCut> = None;
        let mut run: Option<AirCut> = None;
        let mut prev: Option<P3> = None;
        let close = |run: &mut Option<AirCut>, best: &mut Option<AirCut>| {
            if let Some(r) = run.take() {
                if best.is_none_or(|b| r.length > b.length) {
                    *best = Some(r);
                }
            }
        };
        for s in &self.samples {
            let cutting = self.moves[s.report].kind != MoveKind::Rapid;
            if cutting && s.engagement == 0.0 {
                let step = prev.map_or(0.0, |p| p.dist(s.at));
                let r = run.get_or_insert(AirCut {
                    length: 0.0,
                    start: prev.unwrap_or(s.at),
                    report: s.report,
                });
                r.length += step;
            } else {
                close(&mut run, &mut best);
            }
            prev = Some(s.at);
        }
        close(&mut run, &mut best);
        best.filter(|b| b.length > 0.0)
    }

    /// The material removed per minute in `bins` equal spans of the program's time (each
    /// move's time at its feed): (start of the span in s, mm³/min).
    pub fn removal_rate(&self, bins: usize) -> Vec<(f64, f64)> {
        let total: f64 = self.moves.iter().map(|m| m.time).sum();
        if bins == 0 || total <= 0.0 {
            return Vec::new();
        }
        let w = total / bins as f64;
        let mut out: Vec<(f64, f64)> = (0..bins).map(|b| (b as f64 * w, 0.0)).collect();
        let mut t = 0.0;
        for m in &self.moves {
            if m.time <= 0.0 {
                continue;
            }
            // spread the move's removal over the spans it covers
            let (t0, t1) = (t, t + m.time);
            let mut b = ((t0 / w) as usize).min(bins - 1);
            while b < bins && (b as f64) * w < t1 {
                let lo = t0.max(b as f64 * w);
                let hi = t1.min((b + 1) as f64 * w);
                if hi > lo {
                    out[b].1 += m.removed * (hi - lo) / m.time;
                }
                b += 1;
            }
            t = t1;
        }
        for o in &mut out {
            o.1 *= 60.0 / w;
        }
        out
    }

    /// The program's time at its feeds (no acceleration), s.
    pub fn time(&self) -> f64 {
        self.moves.iter().map(|m| m.time).sum()
    }
}

/// How often the tool goes up to the safe height (the path's highest Z) from below it by a
/// rapid: the retracts between passes, regions and levels.
pub fn retracts(tp: &Toolpath) -> usize {
    // the path's top (its bounds' top: every move's end, arcs rising no higher than theirs;
    // the arcs' extremes in X and Y are not needed here)
    let mut top = f64::NEG_INFINITY;
    tp.walk(P3::default(), |_, _, to| top = top.max(to.z));
    if top == f64::NEG_INFINITY {
        return 0;
    }
    let mut n = 0;
    tp.walk(P3::default(), |from, m, to| {
        if matches!(m, Move::Rapid { .. }) && from.z < top - 1e-9 && to.z >= top - 1e-9 {
            n += 1;
        }
    });
    n
}

/// Probes per half circle (one degree apart).
const PROBES: usize = 181;

/// Replays `tp` against `stock` (see the module).
pub fn simulate(tp: &Toolpath, stock: &Stock, o: &SimOptions) -> Result<Report, SimError> {
    let r = o.tool.radius();
    if !(r.is_finite() && r > 0.0) {
        return Err(SimError::BadTool(o.tool.diameter));
    }
    let h = o.cell_mm();
    if !(h.is_finite() && h > 0.0) {
        return Err(SimError::BadCell(o.cell));
    }
    let mut b = crate::geom::Bounds::EMPTY;
    for reg in &stock.outline {
        b = b.union(&reg.bounds());
    }
    if b.is_empty() || b.width() <= 0.0 || b.height() <= 0.0 {
        return Err(SimError::NoStock);
    }
    let pad = 2.0 * h;
    let nx = ((b.width() + 2.0 * pad) / h).ceil() as usize + 1;
    let ny = ((b.height() + 2.0 * pad) / h).ceil() as usize + 1;
    if nx.saturating_mul(ny) > MAX_CELLS {
        return Err(SimError::TooLarge {
            w: b.width(),
            h: b.height(),
            cell: h,
            cells: nx.saturating_mul(ny),
            max: MAX_CELLS,
        });
    }
    let mut g = Grid::new(b.min - Point::new(pad, pad), h, nx, ny);
    let in_stock = g.inside(&stock.outline);
    for (t, &s) in g.top.iter_mut().zip(&in_stock) {
        if s {
            *t = stock.top as f32;
        }
    }
    drop(in_stock);
    let clear = o.part.as_ref().map(|p| g.inside(&p.clear));
    let floor = o.part.as_ref().map_or(f64::NEG_INFINITY, |p| p.floor);
    let ztol = o.tolerance.max(1e-6);

    let mut rep = Report {
        moves: Vec::new(),
        samples: Vec::new(),
        cell: h,
        removed: 0.0,
        gouges: 0,
        first_gouge: None,
        rapid_cuts: 0,
        first_rapid_cut: None,
        left: 0,
        left_area: 0.0,
        first_left: None,
        region_cells: 0,
    };
    let vrapid = o.kinematics.rapid_feed;
    let vmax = o.kinematics.max_feed;
    // the tool's disc at its position is already cut (not at the start: it is above the stock)
    let mut arrived = false;
    let mut pos = P3::default();
    let mut first = true;
    // the centre and radius of the last arc that went down (a helix)
    let mut helix: Option<(Point, f64)> = None;
    for (index, m) in tp.moves.iter().enumerate() {
        let (to, feed, rapid) = match m {
            Move::Rapid { to } => (*to, vrapid, true),
            Move::Linear { to, feed } | Move::Arc { to, feed, .. } => (*to, *feed, false),
            _ => continue,
        };
        if first {
            // the first position is where the machine starts: take it as reached
            first = false;
            if matches!(m, Move::Rapid { .. }) {
                pos = to;
                continue;
            }
        }
        let from = pos;
        // the move as chords
        let pts: Vec<P3> = match m {
            Move::Arc { center, ccw, .. } => {
                let seg = arc_segment(from.xy(), to.xy(), *center, *ccw);
                let xy = grid::flatten_segment(&seg, (h / 8.0).min(o.tolerance / 4.0));
                let n = xy.len() - 1;
                xy.iter()
                    .enumerate()
                    .map(|(i, p)| P3::at_z(*p, from.z + (to.z - from.z) * i as f64 / n as f64))
                    .collect()
            }
            _ => vec![from, to],
        };
        let xy_len: f64 = pts.windows(2).map(|w| w[0].xy().dist(w[1].xy())).sum();
        let length: f64 = pts.windows(2).map(|w| w[0].dist(w[1])).sum();
        let closes_helix = match (m, helix) {
            (Move::Arc { center, .. }, Some((c, rho))) => {
                center.dist(c) < 1e-6 && (from.xy().dist(c) - rho).abs() < 1e-6
            }
            _ => false,
        };
        let kind = if rapid {
            MoveKind::Rapid
        } else if xy_len < 1e-9 {
            MoveKind::Plunge
        } else if to.z < from.z - 1e-9 || closes_helix {
            MoveKind::Entry
        } else {
            MoveKind::Cut
        };
        helix = match m {
            Move::Arc { center, .. } if to.z < from.z - 1e-9 => {
                Some((*center, from.xy().dist(*center)))
            }
            Move::Arc { .. } if closes_helix => helix,
            _ => None,
        };
        let ri = rep.moves.len();
        let mut mr = MoveReport {
            index,
            kind,
            from,
            to,
            length,
            feed: if rapid { vrapid } else { feed.min(vmax) },
            engagement: 0.0,
            mean_engagement: 0.0,
            removed: 0.0,
            air: 0.0,
            gouges: 0,
            time: 0.0,
        };
        mr.time = if mr.feed > 0.0 {
            length / mr.feed * 60.0
        } else {
            0.0
        };
        let mut eng_sum = 0.0;
        let mut eng_n = 0usize;
        for w in pts.windows(2) {
            let (a, c) = (w[0], w[1]);
            let d = c.xy() - a.xy();
            let l = d.len();
            // engagement before cutting this chord
            let steps = ((l / h).ceil() as usize).max(1);
            for s in 1..=steps {
                let t = s as f64 / steps as f64;
                let p = P3::new(
                    a.x + (c.x - a.x) * t,
                    a.y + (c.y - a.y) * t,
                    a.z + (c.z - a.z) * t,
                );
                let e = if l < 1e-12 {
                    // straight down: material anywhere under the disc
                    let under = disc_has_material(&g, p, r, h);
                    if under {
                        360.0
                    } else {
                        0.0
                    }
                } else {
                    // the way the tool moves there: the arc's tangent, or the chord's
                    let u = match m {
                        Move::Arc { center, ccw, .. } => {
                            let v = (p.xy() - *center).perp().unit();
                            if *ccw {
                                v
                            } else {
                                -v
                            }
                        }
                        _ => d * (1.0 / l),
                    };
                    side_engagement(&g, p, u, r)
                };
                if !rapid {
                    mr.engagement = mr.engagement.max(e);
                    eng_sum += e;
                    eng_n += 1;
                    if e == 0.0 {
                        mr.air += a.dist(c) / steps as f64;
                    }
                }
                rep.samples.push(Sample {
                    at: p,
                    engagement: if rapid { 0.0 } else { e },
                    report: ri,
                });
            }
            // cut the chord
            let mut removed = 0.0f64;
            let mut gouged: Vec<usize> = Vec::new();
            g.cut(a, c, r, arrived, |k, old, new| {
                let lo = old.max(f32::MIN);
                removed += (lo - new) as f64;
                if let Some(cl) = &clear {
                    let limit = if cl[k] { floor } else { stock.top };
                    if (new as f64) < limit - ztol {
                        gouged.push(k);
                    }
                }
            });
            arrived = true;
            mr.removed += removed * h * h;
            for k in gouged {
                let (i, j) = (k % g.nx, k / g.nx);
                let p = g.centre(i, j);
                let cl = clear.as_ref().expect("gouges need a part");
                // outside the raster's regions (their boundaries flattened to an eighth of
                // a cell): a gouge farther than the tolerance from the true boundary and
                // not inside it (a cell between a chord and its arc is not the part)
                let real = cl[k] || {
                    let part = o.part.as_ref().expect("gouges need a part");
                    distance_to_regions(&part.clear, p) > o.tolerance
                        && !part.clear.iter().any(|r| r.contains(p))
                };
                if real {
                    mr.gouges += 1;
                    rep.first_gouge.get_or_insert(p);
                }
            }
        }
        if eng_n > 0 {
            mr.mean_engagement = eng_sum / eng_n as f64;
        }
        if rapid && mr.removed > 0.0 {
            rep.rapid_cuts += 1;
            rep.first_rapid_cut.get_or_insert(index);
        }
        rep.removed += mr.removed;
        rep.gouges += mr.gouges;
        rep.moves.push(mr);
        pos = to;
    }
    if let (Some(cl), Some(_)) = (&clear, &o.part) {
        // reachable: within R − h of a centre whose disc (R + h for the raster) fits
        let outside: Vec<bool> = cl.iter().map(|&c| !c).collect();
        let wall = g.distance_to(&outside);
        let fits: Vec<bool> = wall.iter().map(|&d| d >= r + h).collect();
        let reach = g.distance_to(&fits);
        for k in 0..cl.len() {
            if !cl[k] {
                continue;
            }
            rep.region_cells += 1;
            if reach[k] <= r - h && (g.top[k] as f64) > floor + ztol {
                rep.left += 1;
                rep.first_left.get_or_insert(g.centre(k % g.nx, k / g.nx));
            }
        }
        rep.left_area = rep.left as f64 * h * h;
    }
    Ok(rep)
}

/// The engagement of a tool of radius `r` at `p` (its bottom at `p.z`) moving the unit
/// way `u` over the material `g`, before it cuts there, degrees: the probes of the half
/// circle just outside the tool (R + 0.72 cell) facing `u` where the material stands above
/// the tool's bottom (see the module).
pub fn side_engagement(g: &Grid, p: P3, u: Point, r: f64) -> f64 {
    static PROBE_DIRS: std::sync::OnceLock<Vec<(f64, f64)>> = std::sync::OnceLock::new();
    let probes = PROBE_DIRS.get_or_init(|| {
        (0..PROBES)
            .map(|k| {
                let a = (-90.0 + k as f64 * 180.0 / (PROBES - 1) as f64).to_radians();
                (a.cos(), a.sin())
            })
            .collect()
    });
    let rp = r + 0.72 * g.h;
    let n = u.perp();
    let zb = p.z + 1e-4;
    let mut on = 0.0;
    for (k, &(ca, sa)) in probes.iter().enumerate() {
        let q = p.xy() + u * (rp * ca) + n * (rp * sa);
        if (g.top_at(q) as f64) > zb {
            on += if k == 0 || k == PROBES - 1 { 0.5 } else { 1.0 };
        }
    }
    on * 180.0 / (PROBES - 1) as f64
}

/// The most [`side_engagement`] reads, on cells of `h` mm, as a tool of radius `r` arrives
/// in a sharp corner where its centre's path turns by `turn` degrees, with nothing left
/// to cut there; degrees. A round tool cannot go into a corner with less: the material
/// only the tool at the corner reaches, and the part just beyond it, lie round its edge over
/// the corner's normal cone, `turn` wide (180° less the corner's angle), and those
/// directions face the tool's way whatever way it comes in. Beyond the cone the probes
/// (R + 0.72 h) touch the wall ahead over arccos(R / (R + 0.72 h + h/√2)), the cell's
/// half diagonal included; one probe's degree on top.
pub fn corner_reading(turn: f64, r: f64, h: f64) -> f64 {
    let reach = r + 0.72 * h + h * std::f64::consts::FRAC_1_SQRT_2;
    turn + (r / reach).clamp(-1.0, 1.0).acos().to_degrees() + 1.0
}

/// The sharp corners of the tool centre's path round the walls of `regions` (each offset
/// inward by `r`): the vertices where it turns on the spot, going into a corner of a
/// region, and by how much it turns there, degrees.
pub fn sharp_corners(regions: &[Region], r: f64) -> Vec<(Point, f64)> {
    let mut out = Vec::new();
    for region in regions {
        let Ok(walls) = crate::offset::offset_region(region, -r, &Default::default()) else {
            continue;
        };
        for pl in walls.iter().flat_map(|w| w.boundaries()) {
            out.extend(path_corners(pl));
        }
    }
    out
}

/// The vertices of a closed path where its tangent turns by more than 2.5°, and the turn,
/// degrees.
pub fn path_corners(pl: &crate::geom::Polyline) -> Vec<(Point, f64)> {
    let n = pl.segment_count();
    (0..n)
        .filter_map(|k| {
            let (a, b) = (pl.segment(k), pl.segment((k + 1) % n));
            let cos = a.tangent_at(1.0).dot(b.tangent_at(0.0)).clamp(-1.0, 1.0);
            (cos < 0.999).then(|| (a.end(), cos.acos().to_degrees()))
        })
        .collect()
}

/// How near a sharp corner turning by 90° a tool centre counts as going into it, mm; more
/// before a sharper one (over the sine of half the corner's angle, times √½).
pub const CORNER_NEAR: f64 = 0.75;

/// Whether a tool centre at `p` is going into the sharp corner at `c` where the path turns
/// by `turn` degrees ([`CORNER_NEAR`]).
pub fn near_corner(c: Point, turn: f64, p: Point) -> bool {
    let half = (180.0 - turn).to_radians() / 2.0;
    c.dist(p) <= CORNER_NEAR * std::f64::consts::FRAC_1_SQRT_2 / half.sin().max(0.05)
}

/// The turn of the sharp corner among `corners` that `p` is going into ([`near_corner`]),
/// the sharpest if several.
pub fn going_into(corners: &[(Point, f64)], p: Point) -> Option<f64> {
    corners
        .iter()
        .filter(|&&(c, turn)| near_corner(c, turn, p))
        .map(|c| c.1)
        .fold(None, |m: Option<f64>, t| Some(m.map_or(t, |m| m.max(t))))
}

/// Whether any cell under the disc of radius `r` about `p` stands above its bottom.
fn disc_has_material(g: &Grid, p: P3, r: f64, h: f64) -> bool {
    let n = (r / h).ceil() as i64;
    for dj in -n..=n {
        for di in -n..=n {
            let q = Point::new(p.x + di as f64 * h, p.y + dj as f64 * h);
            if q.dist(p.xy()) <= r && (g.top_at(q) as f64) > p.z + 1e-4 {
                return true;
            }
        }
    }
    false
}

/// Distance from `p` to the nearest boundary of `regions`.
fn distance_to_regions(regions: &[Region], p: Point) -> f64 {
    regions
        .iter()
        .flat_map(|r| r.boundaries())
        .map(|b| b.distance_to(p))
        .fold(f64::INFINITY, f64::min)
}
