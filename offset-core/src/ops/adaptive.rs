//! Adaptive clearing: a region with islands cleared by passes that advance from a helix-cut core, each step's direction chosen so the simulated engagement of the tool stays at or under a bound, links kept inside cleared material.
//!
//! The method (docs/toolpaths.md, "Adaptive clearing"), one plan in XY repeated at every
//! depth pass (each level starts from the same uncut cross-section):
//! - A planning raster of the cutting simulation's kind ([`crate::cutsim::grid::Grid`],
//!   cell D/40) holds the level's material, the part included (the simulation's probes see
//!   it too). It is cut by a disc half a cell smaller than the tool, so a cell counts as cut
//!   only where the simulation's finer cells surely are.
//! - Each connected part of the area where the raster puts the tool centre R + allowance
//!   (+ the finishing stock) + 1.5 cells or more from the part gets a core: a helix at its
//!   deepest point (a circle of at most the tool radius). The first level's helix bores the
//!   core to the last level's depth and comes back up; the levels after go straight down
//!   the bored core, through air.
//! - Engagement-controlled advancement (after FreeCAD's Adaptive2d): a pass starts at the
//!   cleared spot nearest the tool whose disc is clear (2 cells to spare) and that has
//!   material it may remove within 4 cells, setting off with that material on the right
//!   (climb; on the left conventional). Each step of two cells takes the direction, of 25
//!   within ±120° of the last then bisected towards the material, whose engagement read by
//!   the simulation's own probe ([`crate::cutsim::side_engagement`]) on the raster is the
//!   largest at or under the bound less [`MARGIN_DEG`]; its end must be a centre of the
//!   part, the exact distance from the part's boundary (bucketed segments) at least
//!   R + allowance + 0.02 mm, a step that would pass it pushed back onto it. The pass ends
//!   where no direction engages material or nothing was removed for a tool diameter; the
//!   next starts where the first rule says, until none is left. So fronts turn away before
//!   they run into a wall or a corner, and passes reach the walls only as the bound allows.
//! - Links: at depth where the line cuts nothing on the raster (the tool's disc swept
//!   along it, R less half a cell, meets no material but the part) and keeps R + allowance
//!   from the part; else at depth round the material, by a way found on the raster (A*
//!   over the cells R or more from material) and pulled straight; else lifted 0.5 mm over
//!   the last level's floor where the level's final raster is clear there (the level above
//!   cut it); else at the safe height. Every link ends over a spot already cleared at depth.
//! - Then each wall (the region offset inward by R + allowance, by the offset kernel)
//!   once round, entered from a spot 3 cells inside it whose disc is clear, in steps of two
//!   cells looked at half a millimetre ahead: where the straight way would pass the bound,
//!   trochoidal loops (full circles inside the walls, up to 0.5 mm, each advanced along
//!   the wall by the most of 0.25 … 0.02 mm that keeps the bound, tried and undone on the
//!   raster) take the material. Loops of 0.25 mm or less (a neck less than a millimetre
//!   wider than the tool), and loops where no trial keeps the bound, advance instead by
//!   the closed form of a loop in a slot (`loop_reading`: the simulation's reading round
//!   the loop on cells of D/60, aimed 4° under the planner's aim), which the raster is too
//!   coarse to read. With `finish`, those passes leave [`finish_stock`] and one
//!   last pass round each wall at the full depth takes it (in from the roughing wall, out
//!   again).
//! - What the bound does not cover (the tool path's warnings say where and how much): the
//!   helix into each level's core goes down through material (the simulation reads 180°
//!   for any move that descends into material, and for its closing flat turn, which cuts
//!   the wedge the last descending turn leaves; both are the entry, "going down"); the
//!   tool's way into a sharp corner of a wall, where no path can hold a bound under the
//!   wall's turn there (a round tool going into a corner meets material or the part over
//!   the corner's normal cone, 180° less its angle: [`crate::cutsim::corner_reading`]),
//!   warned apart.
//! - The passes' runs of cuts go out fitted into lines and arcs within an eighth of a
//!   cell; the walls and loops as exact lines and arcs.

use super::entry;
use super::profile::cut;
use super::{pass_depths, Cutting, OpError};
use crate::cutsim::grid::{flatten_segment, Grid};
use crate::cutsim::side_engagement;
use crate::geom::{Point, Polyline, Region, Segment, Shape};
use crate::offset::{offset_region, OffsetOptions};
use crate::toolpath::{Move, Toolpath, P3};
use serde::{Deserialize, Serialize};
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// The engagement bound when none is given, degrees.
pub const DEFAULT_ENGAGEMENT: f64 = 70.0;

/// How far under the bound the planner aims, degrees (the check's raster differs).
const MARGIN_DEG: f64 = 6.0;

/// The planning raster is cut by a disc this many cells smaller than the tool: a cell
/// counts as cut only where the simulation's finer cells in it surely are, so the slivers
/// the finer raster keeps at the edge of each cut still read as material.
const SHRINK: f64 = 0.5;

/// How far over the last level's floor a lifted link goes, mm (as the pocket's).
pub const LINK_LIFT: f64 = super::pocket::LINK_LIFT;

/// Everything adaptive clearing needs besides the shape (keys left out of JSON take the
/// defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdaptiveParams {
    /// Tool, depths, feeds and heights (`"cut": { … }` in JSON).
    pub cut: Cutting,
    /// The largest engagement of the tool in the material, degrees.
    pub engagement: f64,
    /// Stock left on the walls and islands, mm.
    pub allowance: f64,
    /// A last pass round each wall at the full depth (the levels leave [`finish_stock`]).
    pub finish: bool,
    /// Side of the planning raster's cells, mm (0: the tool diameter / 40).
    pub cell: f64,
}

impl Default for AdaptiveParams {
    fn default() -> Self {
        AdaptiveParams {
            cut: Cutting::default(),
            engagement: DEFAULT_ENGAGEMENT,
            allowance: 0.0,
            finish: false,
            cell: 0.0,
        }
    }
}

/// The radial stock the levels leave for the finishing pass: 2 % of the tool diameter.
pub fn finish_stock(d: f64) -> f64 {
    0.02 * d
}

impl AdaptiveParams {
    fn check(&self) -> Result<(), OpError> {
        self.cut.check()?;
        if !(self.engagement.is_finite() && self.engagement >= 10.0 && self.engagement <= 180.0) {
            return Err(OpError::BadParam(format!(
                "the engagement must be from 10° to 180°, got {}",
                self.engagement
            )));
        }
        if !(self.allowance.is_finite() && self.allowance >= 0.0) {
            return Err(OpError::BadParam(format!(
                "the allowance must be 0 or more mm, got {}",
                self.allowance
            )));
        }
        if !(self.cell.is_finite() && self.cell >= 0.0) {
            return Err(OpError::BadParam(format!(
                "the planning cell must be 0 (the tool diameter / 40) or more mm, got {}",
                self.cell
            )));
        }
        Ok(())
    }
}

/// One step of the plan in XY, the same at every level.
#[derive(Clone, Debug)]
enum Step {
    /// Down a helix about `c` (tool centre on the circle of radius `rho`), starting and
    /// ending at `c + (rho, 0)`.
    Helix { c: Point, rho: f64 },
    /// A link to `to`; `depth` when it may stay at the cutting depth (else lifted or at
    /// the safe height, decided on the level's final raster).
    Go { to: Point, depth: bool },
    /// A cut at depth to `to`.
    Cut { to: Point },
    /// A line or arc at depth from where the tool stands (walls and their loops).
    Seg { seg: Segment },
    /// A wall loop the tool must go down into: a ramp round it.
    Ramp { pl: Polyline },
}

/// What the plan of one level found.
#[derive(Clone, Debug, Default)]
struct Found {
    /// The largest planned engagement of a cut, where, and the passes that kept more
    /// than the bound.
    worst: f64,
    worst_at: Point,
    over: Vec<(Point, f64)>,
    /// The most read going into each sharp corner of a wall (the last half millimetre
    /// before it and after), where no plan reads less than the corner's turn: where, how
    /// much, and the turn, degrees.
    corners: Vec<(Point, f64, f64)>,
    cores: usize,
    passes: usize,
}

/// The most a wall pass reads: away from its sharp corners, and going into each of them.
#[derive(Clone, Debug)]
struct Worst {
    away: (f64, Point),
    /// The wall loop's sharp corners (where it turns on the spot) and their turns, with
    /// the most read going into each ([`crate::cutsim::near_corner`]).
    sharp: Vec<(Point, f64, f64)>,
}

impl Worst {
    /// The sharp corners of a wall loop ([`crate::cutsim::path_corners`]).
    fn of(pl: &Polyline) -> Worst {
        let sharp = crate::cutsim::path_corners(pl)
            .into_iter()
            .map(|(c, turn)| (c, turn, 0.0))
            .collect();
        Worst {
            away: (0.0, Point::default()),
            sharp,
        }
    }

    fn note(&mut self, e: f64, p: Point) {
        if let Some(c) = self
            .sharp
            .iter_mut()
            .find(|c| crate::cutsim::near_corner(c.0, c.1, p))
        {
            c.2 = c.2.max(e);
        } else if e > self.away.0 {
            self.away = (e, p);
        }
    }
}

/// The planning raster of one region and what the planner asks of it.
struct Plan {
    g: Grid,
    r: f64,
    h: f64,
    /// Where the region is not (the part).
    part: Vec<bool>,
    steps: Vec<Step>,
    at: Point,
    found: Found,
    bound: f64,
    climb: bool,
    /// The region's boundary segments by bucket, for exact distances near the walls.
    near: Near,
    /// The raster distance to the part per cell (set by `clear`).
    wall: Vec<f64>,
    /// The least exact distance of a tool centre from the part: R + allowance (+ stock).
    kexact: f64,
}

/// Plans adaptive clearing of every region of `shape` (see the module).
pub fn adaptive(shape: &Shape, p: &AdaptiveParams) -> Result<Toolpath, OpError> {
    p.check()?;
    super::check_range(shape)?;
    let regions = shape.regions();
    if regions.is_empty() {
        return Err(OpError::Empty(
            "adaptive clearing needs closed outlines; the shape has none".into(),
        ));
    }
    let d = p.cut.tool.diameter;
    let r = p.cut.tool.radius();
    let h = if p.cell > 0.0 { p.cell } else { d / 40.0 };
    let fs = if p.finish { finish_stock(d) } else { 0.0 };
    let opts = OffsetOptions {
        tolerance: p.cut.tolerance,
        ..Default::default()
    };
    let mut tp = Toolpath::new("adaptive");
    tp.tool = Some(p.cut.tool);
    let mut at = P3::new(0.0, 0.0, p.cut.safe_z);
    tp.push(Move::Rapid { to: at });
    if p.cut.spindle_rpm > 0.0 {
        tp.push(Move::Spindle {
            rpm: p.cut.spindle_rpm,
        });
    }
    let depths = pass_depths(p.cut.depth, p.cut.stepdown);
    let slope = p.cut.ramp_angle.to_radians().tan();
    let mut any = false;
    let mut summary = Found::default();
    for region in &regions {
        let walls = offset_region(region, -(r + p.allowance + fs), &opts)?;
        if walls.is_empty() {
            continue;
        }
        any = true;
        let b = region.bounds();
        let cells = (b.width() / h + 1.0) * (b.height() / h + 1.0);
        if cells > crate::cutsim::MAX_CELLS as f64 {
            return Err(OpError::BadParam(format!(
                "planning {:.0} × {:.0} mm at {h} mm cells takes {cells:.0} cells, more than {}; use a larger cell",
                b.width(),
                b.height(),
                crate::cutsim::MAX_CELLS
            )));
        }
        let mut plan = Plan::new(region, r, h, p.engagement - MARGIN_DEG, p.cut.climb);
        plan.at = at.xy();
        plan.kexact = r + p.allowance + fs;
        plan.near = Near::new(region, r, plan.kexact + 4.0 * h);
        plan.clear(r + p.allowance + fs + 1.5 * h);
        plan.walls(&walls);
        let finals = if p.finish {
            offset_region(region, -(r + p.allowance), &opts)?
        } else {
            Vec::new()
        };
        let f = &plan.found;
        summary.cores += f.cores;
        summary.passes += f.passes;
        if f.worst > summary.worst {
            summary.worst = f.worst;
            summary.worst_at = f.worst_at;
        }
        summary.over.extend(f.over.iter().copied());
        summary.corners.extend(f.corners.iter().copied());
        let mut em = Emit {
            tp: &mut tp,
            c: &p.cut,
            at,
            slope,
            g: &plan.g,
        };
        let bottom = depths.last().copied().unwrap_or(0.0);
        for (k, &z) in depths.iter().enumerate() {
            let z_top = if k == 0 { 0.0 } else { depths[k - 1] };
            em.level(&plan.steps, z, z_top, (k == 0).then_some(bottom));
        }
        if let (true, Some(&z)) = (p.finish, depths.last()) {
            let z_top = if depths.len() > 1 {
                depths[depths.len() - 2]
            } else {
                0.0
            };
            em.finish(&finals, &walls, z, z_top);
        }
        at = em.at;
    }
    if !any {
        return Err(OpError::Empty(format!(
            "a {d} mm tool does not fit in the region"
        )));
    }
    if at.z < p.cut.safe_z {
        tp.push(Move::Rapid {
            to: P3::at_z(at.xy(), p.cut.safe_z),
        });
    }
    if p.cut.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: 0.0 });
    }
    tp.moves.insert(
        0,
        Move::Comment {
            text: format!(
                "adaptive: engagement at most {}°, {} cores, {} passes a level, planned worst {:.1}° at ({:.2}, {:.2})",
                p.engagement, summary.cores, summary.passes, summary.worst, summary.worst_at.x, summary.worst_at.y
            ),
        },
    );
    if let Some(&(q, e)) = summary.over.iter().max_by(|a, b| a.1.total_cmp(&b.1)) {
        tp.warnings.push(format!(
            "{} wall passes could not keep the engagement at {}° (through a neck, or along a wall the passes left too thick); the worst reads {e:.0}° at ({:.2}, {:.2})",
            summary.over.len(),
            p.engagement,
            q.x,
            q.y
        ));
    }
    if let Some(&(q, e, turn)) = summary.corners.iter().max_by(|a, b| a.1.total_cmp(&b.1)) {
        tp.warnings.push(format!(
            "going into {} sharp corners of the walls the tool meets the material over more than {}°, the most {e:.0}° at ({:.2}, {:.2}), where the wall turns by {turn:.0}°: a round tool cannot go into a corner with less than that turn (180° less the corner's angle)",
            summary.corners.len(),
            p.engagement,
            q.x,
            q.y
        ));
    }
    Ok(tp)
}

/// The 16 neighbours of a cell and the distances to them, in cells.
const NEIGHBOURS: [(i64, i64); 16] = [
    (1, 0),
    (-1, 0),
    (0, 1),
    (0, -1),
    (1, 1),
    (1, -1),
    (-1, 1),
    (-1, -1),
    (1, 2),
    (2, 1),
    (-1, 2),
    (-2, 1),
    (1, -2),
    (2, -1),
    (-1, -2),
    (-2, -1),
];

impl Plan {
    fn new(region: &Region, r: f64, h: f64, bound: f64, climb: bool) -> Plan {
        let b = region.bounds();
        let pad = r + 4.0 * h;
        let nx = ((b.width() + 2.0 * pad) / h).ceil() as usize + 1;
        let ny = ((b.height() + 2.0 * pad) / h).ceil() as usize + 1;
        let mut g = Grid::new(b.min - Point::new(pad, pad), h, nx, ny);
        let inside = g.inside(std::slice::from_ref(region));
        g.top.iter_mut().for_each(|t| *t = 0.0);
        Plan {
            g,
            r,
            h,
            part: inside.iter().map(|&i| !i).collect(),
            steps: Vec::new(),
            at: Point::default(),
            found: Found::default(),
            bound,
            climb,
            near: Near::default(),
            wall: Vec::new(),
            kexact: r,
        }
    }

    fn xy(&self, k: usize) -> Point {
        self.g.centre(k % self.g.nx, k / self.g.nx)
    }

    /// Clears the area the tool centre may visit (`keep` mm or more from the part): cores,
    /// then the iso-lines of the geodesic distance from each.
    fn clear(&mut self, keep: f64) {
        let (nx, ny) = (self.g.nx, self.g.ny);
        let wall = self.g.distance_to(&self.part);
        let allowed: Vec<bool> = wall.iter().map(|&w| w >= keep).collect();
        self.wall = wall.clone();
        let mut geo = vec![f64::INFINITY; nx * ny];
        let mut comp = vec![u32::MAX; nx * ny];
        // cells by depth, deepest first: each next unreached one starts a part
        let mut order: Vec<usize> = (0..nx * ny).filter(|&k| allowed[k]).collect();
        order.sort_by(|&a, &b| wall[b].total_cmp(&wall[a]));
        let mut next_comp = 0u32;
        for &seed in &order {
            if comp[seed] != u32::MAX {
                continue;
            }
            let id = next_comp;
            next_comp += 1;
            let (_, bbox) = self.spread(seed, id, &allowed, &mut geo, &mut comp);
            let c = self.xy(seed);
            let rho = (wall[seed] - keep).min(self.r);
            if rho < 0.1 * self.r {
                // too narrow for a core: the wall pass alone clears it
                continue;
            }
            self.found.cores += 1;
            self.steps.push(Step::Helix { c, rho });
            let ring: Vec<Point> = (0..=64)
                .map(|i| {
                    let a = i as f64 / 64.0 * std::f64::consts::TAU;
                    c + Point::new(rho * a.cos(), rho * a.sin())
                })
                .collect();
            for w in ring.windows(2) {
                self.g.cut(
                    P3::at_z(w[0], -1.0),
                    P3::at_z(w[1], -1.0),
                    self.r,
                    false,
                    |_, _, _| {},
                );
            }
            self.at = c + Point::new(rho, 0.0);
            self.advance(&comp, id, bbox);
        }
    }

    /// Dijkstra from `seed` over the allowed cells: the geodesic distance (mm) and the
    /// part's id; its cells and their box (i0, j0, i1, j1).
    fn spread(
        &self,
        seed: usize,
        id: u32,
        allowed: &[bool],
        geo: &mut [f64],
        comp: &mut [u32],
    ) -> (Vec<usize>, [usize; 4]) {
        let (nx, ny) = (self.g.nx as i64, self.g.ny as i64);
        let mut heap = BinaryHeap::new();
        geo[seed] = 0.0;
        heap.push(Reverse((0u64, seed)));
        let mut cells = Vec::new();
        let mut bbox = [usize::MAX, usize::MAX, 0, 0];
        while let Some(Reverse((dq, k))) = heap.pop() {
            let dk = f64::from_bits(dq);
            if comp[k] != u32::MAX || dk > geo[k] {
                continue;
            }
            comp[k] = id;
            cells.push(k);
            let (i, j) = ((k as i64) % nx, (k as i64) / nx);
            bbox[0] = bbox[0].min(i as usize);
            bbox[1] = bbox[1].min(j as usize);
            bbox[2] = bbox[2].max(i as usize);
            bbox[3] = bbox[3].max(j as usize);
            for (di, dj) in NEIGHBOURS {
                let (a, b) = (i + di, j + dj);
                if a < 0 || b < 0 || a >= nx || b >= ny {
                    continue;
                }
                let q = (b * nx + a) as usize;
                if !allowed[q] || comp[q] != u32::MAX {
                    continue;
                }
                let nd = dk + ((di * di + dj * dj) as f64).sqrt() * self.h;
                if nd < geo[q] {
                    geo[q] = nd;
                    // non-negative f64s order as their bits
                    heap.push(Reverse((nd.to_bits(), q)));
                }
            }
        }
        (cells, bbox)
    }

    /// The passes of one part (the cells of `comp` equal to `id`, their box `bbox`):
    /// engagement-controlled advancement from the cleared core until nothing the part's
    /// tool centres can remove is left that a pass can take under the bound.
    fn advance(&mut self, comp: &[u32], id: u32, bbox: [usize; 4]) {
        let (nx, ny) = (self.g.nx, self.g.ny);
        let (r, h) = (self.r, self.h);
        let mine: Vec<bool> = comp.iter().map(|&c| c == id).collect();
        // the cells a centre of this part reaches (within R less half a cell)
        let reach = self.g.distance_to(&mine);
        let removable: Vec<bool> = reach.iter().map(|&d| d <= r - 0.5 * h).collect();
        let pad = (r / h).ceil() as usize + 4;
        let i0 = bbox[0].saturating_sub(pad).max(1);
        let j0 = bbox[1].saturating_sub(pad).max(1);
        let i1 = (bbox[2] + pad).min(nx - 2);
        let j1 = (bbox[3] + pad).min(ny - 2);
        let mut tried = vec![false; nx * ny];
        let mut cands: Vec<usize> = Vec::new();
        let mut d_rem: Vec<f64> = Vec::new();
        let mut fresh = true;
        loop {
            if fresh {
                let mat: Vec<bool> = self.g.top.iter().map(|&t| t > -0.5).collect();
                let rem: Vec<bool> = mat.iter().zip(&removable).map(|(&m, &q)| m && q).collect();
                if !rem.iter().any(|&x| x) {
                    break;
                }
                let d_all = self.g.distance_to(&mat);
                d_rem = self.g.distance_to(&rem);
                cands = (j0..=j1)
                    .flat_map(|j| (i0..=i1).map(move |i| j * nx + i))
                    .filter(|&k| mine[k] && d_all[k] >= r + 2.0 * h && d_rem[k] < r + 4.0 * h)
                    .collect();
                fresh = false;
            }
            let at = self.at;
            let Some(&k) = cands
                .iter()
                .filter(|&&k| !tried[k])
                .min_by(|&&a, &&b| self.xy(a).dist(at).total_cmp(&self.xy(b).dist(at)))
            else {
                break;
            };
            tried[k] = true;
            // towards the nearest material the part may remove: down its distance
            let grad = Point::new(d_rem[k + 1] - d_rem[k - 1], d_rem[k + nx] - d_rem[k - nx]);
            let v = -grad.unit();
            if v.len() < 0.5 {
                continue;
            }
            let u = if self.climb { v.perp() } else { -v.perp() };
            let mut bx = [
                f64::INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
            ];
            if self.run_pass(&mine, &reach, self.xy(k), u, &mut bx) > 0 {
                fresh = true;
                // the candidates near the pass may take something now
                let m = 2.0 * r + 2.0 * h;
                let a0 = self.g.cell_of(Point::new(bx[0] - m, bx[1] - m));
                let a1 = self.g.cell_of(Point::new(bx[2] + m, bx[3] + m));
                let (ci0, cj0) = a0.map_or((0, 0), |a| (a % nx, a / nx));
                let (ci1, cj1) = a1.map_or((nx - 1, ny - 1), |a| (a % nx, a / nx));
                for j in cj0..=cj1 {
                    for i in ci0..=ci1 {
                        tried[j * nx + i] = false;
                    }
                }
            }
        }
    }

    /// `q`, or `q` pushed out from the walls to the least distance (plus [`INSIDE`]), if a
    /// tool centre of the part (`mine`) may go there: within three cells of its cells
    /// (`reach`), the exact distance from the part checked wherever the raster's is not
    /// clearly enough.
    fn fit_centre(&self, mine: &[bool], reach: &[f64], q: Point) -> Option<Point> {
        let keep = self.kexact + INSIDE;
        let mut q = q;
        for _ in 0..3 {
            let k = self.g.cell_of(q)?;
            if reach[k] > 3.0 * self.h || self.wall[k] < self.kexact - self.h {
                return None;
            }
            if mine[k] && self.wall[k] >= self.kexact + 3.0 * self.h {
                return Some(q);
            }
            match self.near.closest(q) {
                None => return Some(q),
                Some((d, _)) if d >= keep => return Some(q),
                Some((d, c)) => {
                    if d < 1e-9 {
                        return None;
                    }
                    q = c + (q - c) * ((keep + 1e-6) / d);
                }
            }
        }
        None
    }

    /// One pass from `p` (its tool disc cleared), setting off along `u`: steps of two
    /// cells, each in the direction (searched over ±120° from the last, then bisected
    /// towards the material) whose engagement on the raster is the largest at or under
    /// the bound, its end inside the part's centres `mine`; the pass ends where no
    /// direction engages material or the tool has removed nothing for a tool diameter.
    /// The cells removed (the pass is kept only if some); `bx` grows by its points.
    fn run_pass(
        &mut self,
        mine: &[bool],
        reach: &[f64],
        p0: Point,
        u: Point,
        bx: &mut [f64; 4],
    ) -> usize {
        let (r, h, bound) = (self.r, self.h, self.bound);
        let s = 2.0 * h;
        // turning towards the material: clockwise when climbing (material on the right)
        let sgn = if self.climb { -1.0 } else { 1.0 };
        let eval = |me: &Plan, p: Point, t: f64| -> Option<(f64, Point)> {
            let q = me.fit_centre(mine, reach, p + Point::new(t.cos(), t.sin()) * s)?;
            let l = q.dist(p);
            if l < 0.25 * s {
                return None;
            }
            let mid = p.lerp(q, 0.5);
            if me.fit_centre(mine, reach, mid) != Some(mid) {
                return None;
            }
            let u = (q - p) * (1.0 / l);
            let n = ((l / h).ceil() as usize).max(1);
            let mut e = 0.0f64;
            for i in 1..=n {
                let x = p.lerp(q, i as f64 / n as f64);
                e = e.max(side_engagement(&me.g, P3::at_z(x, -1.0), u, r));
            }
            Some((e, q))
        };
        let mut th = u.y.atan2(u.x);
        let mut p = p0;
        let mut steps = Vec::new();
        let mut at = self.at;
        self.link(&self.g, &mut steps, &mut at, p0);
        let (mut useful, mut at_useful) = (steps.len(), at);
        let mut total = 0usize;
        let mut idle = 0.0;
        let mut worst = (0.0f64, Point::default());
        let dth = 10f64.to_radians();
        while total < usize::MAX / 2 {
            let samples: Vec<Sample> = (-12..=12)
                .map(|k| {
                    let t = th + sgn * k as f64 * dth;
                    (k, t, eval(self, p, t))
                })
                .collect();
            let mut best: Option<(i32, f64, f64, Point)> = None;
            for &(k, t, ev) in &samples {
                if let Some((e, q)) = ev {
                    let better = match best {
                        None => true,
                        Some((bk, _, be, _)) => e > be || (e == be && k.abs() < bk.abs()),
                    };
                    if e <= bound && better {
                        best = Some((k, t, e, q));
                    }
                }
            }
            let Some((bk, bt, mut be, mut bq)) = best else {
                break;
            };
            if be <= 0.0 {
                break;
            }
            if let Some(&(_, t_hi, ev_hi)) = samples.iter().find(|x| x.0 == bk + 1) {
                if ev_hi.is_some_and(|(e, _)| e > bound) || ev_hi.is_none() {
                    let (mut lo, mut hi) = (bt, t_hi);
                    for _ in 0..4 {
                        let mid = 0.5 * (lo + hi);
                        match eval(self, p, mid) {
                            Some((e, q)) if e <= bound => {
                                lo = mid;
                                if e >= be {
                                    (be, bq) = (e, q);
                                }
                            }
                            _ => hi = mid,
                        }
                    }
                }
            }
            let mut removed = 0usize;
            self.g.cut(
                P3::at_z(p, -1.0),
                P3::at_z(bq, -1.0),
                r - SHRINK * h,
                true,
                |_, _, _| removed += 1,
            );
            if be > worst.0 {
                worst = (be, p);
            }
            steps.push(Step::Cut { to: bq });
            at = bq;
            bx[0] = bx[0].min(bq.x);
            bx[1] = bx[1].min(bq.y);
            bx[2] = bx[2].max(bq.x);
            bx[3] = bx[3].max(bq.y);
            // on from the way the step went (a pushed-back step turns along the wall)
            th = (bq - p).y.atan2((bq - p).x);
            p = bq;
            total += removed;
            if removed == 0 {
                idle += s;
                if idle > 2.0 * r {
                    break;
                }
            } else {
                idle = 0.0;
                useful = steps.len();
                at_useful = at;
            }
        }
        if total > 0 {
            steps.truncate(useful);
            self.steps.extend(steps);
            self.at = at_useful;
            self.found.passes += 1;
            if worst.0 > self.found.worst {
                self.found.worst = worst.0;
                self.found.worst_at = worst.1;
            }
        }
        total
    }

    /// A link from `at` to `to`, at depth when the swept disc meets no material now.
    fn link(&self, g: &Grid, steps: &mut Vec<Step>, at: &mut Point, to: Point) {
        if at.dist(to) < 1e-9 {
            return;
        }
        if self.link_clear(g, *at, to) {
            steps.push(Step::Go { to, depth: true });
        } else if let Some(way) = self.way_at_depth(g, *at, to) {
            steps.extend(way.into_iter().map(|q| Step::Go { to: q, depth: true }));
        } else {
            steps.push(Step::Go { to, depth: false });
        }
        *at = to;
    }

    /// Whether the tool may go from `p` to `q` at depth: its disc swept along the line cuts
    /// nothing on the raster (the raster's own cut, R less half a cell, meets no material
    /// but the part), and its centre keeps R + allowance from the part by the exact
    /// distance, every half cell.
    fn link_clear(&self, g: &Grid, p: Point, q: Point) -> bool {
        if capsule_cuts(g, &self.part, p, q, self.r - SHRINK * self.h) {
            return false;
        }
        let n = ((p.dist(q) / (0.5 * self.h)).ceil() as usize).max(1);
        (0..=n).all(|i| {
            let x = p.lerp(q, i as f64 / n as f64);
            let Some(k) = g.cell_of(x) else {
                return false;
            };
            self.wall[k] >= self.kexact - self.h
                && self.near.closest(x).is_none_or(|(d, _)| d >= self.kexact)
        })
    }

    /// A way at depth from `a` to `b` round the material: the points after `a`, ending at
    /// `b`, of lines each [`Plan::link_clear`]. Found on the raster's cells whose centre is
    /// R or more from any material and R + allowance + a cell from the part (A* over eight
    /// neighbours; cells within two of `a` or `b` let through), then pulled straight where
    /// a line keeps clear (doubling, then halving, so a long way costs few checks). None
    /// when there is no such way.
    fn way_at_depth(&self, g: &Grid, a: Point, b: Point) -> Option<Vec<Point>> {
        let (nx, ny) = (g.nx, g.ny);
        let (ka, kb) = (g.cell_of(a)?, g.cell_of(b)?);
        let material: Vec<bool> = g
            .top
            .iter()
            .zip(&self.part)
            .map(|(&t, &part)| !part && t > -1.0 + 1e-4)
            .collect();
        let dist = g.distance_to(&material);
        let near = |k: usize, p: Point| g.centre(k % nx, k / nx).dist(p) <= 2.0 * g.h;
        let free = |k: usize| {
            (dist[k] >= self.r && self.wall[k] >= self.kexact + g.h) || near(k, a) || near(k, b)
        };
        let goal = g.centre(kb % nx, kb / nx);
        let mut cost = vec![f64::INFINITY; nx * ny];
        let mut from = vec![usize::MAX; nx * ny];
        let mut heap = BinaryHeap::new();
        cost[ka] = 0.0;
        heap.push(Reverse((0u64, ka)));
        while let Some(Reverse((_, k))) = heap.pop() {
            if k == kb {
                break;
            }
            let (i, j) = ((k % nx) as i64, (k / nx) as i64);
            for (di, dj) in NEIGHBOURS.iter().take(8) {
                let (ii, jj) = (i + di, j + dj);
                if ii < 0 || jj < 0 || ii >= nx as i64 || jj >= ny as i64 {
                    continue;
                }
                let n = jj as usize * nx + ii as usize;
                if !free(n) {
                    continue;
                }
                let c = cost[k] + ((di * di + dj * dj) as f64).sqrt();
                if c < cost[n] {
                    cost[n] = c;
                    from[n] = k;
                    let left = g.centre(ii as usize, jj as usize).dist(goal) / g.h;
                    heap.push(Reverse(((c + left).to_bits(), n)));
                }
            }
        }
        if !cost[kb].is_finite() {
            return None;
        }
        let mut cells = vec![kb];
        while let Some(&k) = cells.last() {
            if k == ka {
                break;
            }
            cells.push(from[k]);
        }
        cells.reverse();
        let mut pts: Vec<Point> = cells.iter().map(|&k| g.centre(k % nx, k / nx)).collect();
        pts[0] = a;
        *pts.last_mut()? = b;
        let mut out = Vec::new();
        let mut i = 0;
        let last = pts.len() - 1;
        while i < last {
            if !self.link_clear(g, pts[i], pts[i + 1]) {
                return None;
            }
            let (mut ok, mut step) = (i + 1, 1);
            while ok < last {
                let j = (i + 2 * step).min(last);
                if !self.link_clear(g, pts[i], pts[j]) {
                    break;
                }
                ok = j;
                step *= 2;
            }
            let mut hi = (i + 2 * step).min(last);
            while hi > ok + 1 {
                let mid = (ok + hi) / 2;
                if self.link_clear(g, pts[i], pts[mid]) {
                    ok = mid;
                } else {
                    hi = mid;
                }
            }
            out.push(pts[ok]);
            i = ok;
        }
        Some(out)
    }

    /// One wall loop at depth from its first vertex (the tool there), cut on `g` into
    /// `steps` as exact lines and arcs: in steps of two cells, each looked at half a
    /// millimetre ahead; where the straight way would pass the bound, trochoidal loops
    /// (circles inside the walls, each advanced as far along the wall as keeps the
    /// bound) take the material until the straight way keeps it again.
    fn trace_wall(&self, g: &mut Grid, pl: &Polyline, steps: &mut Vec<Step>, worst: &mut Worst) {
        let (r, h, bound) = (self.r, self.h, self.bound);
        let look = 0.5_f64.max(2.0 * h);
        let note = |e: f64, p: Point, worst: &mut Worst| worst.note(e, p);
        // the closed-form advance of small loops, by their radius
        let mut memo: Vec<(f64, f64)> = Vec::new();
        for seg in pl.segments() {
            let len = seg.length();
            if len < 1e-12 {
                continue;
            }
            let n = ((len / (2.0 * h)).ceil() as usize).max(1);
            let along = crate::geom::PointsAlong::new(&seg);
            let part = |t0: f64, t1: f64| seg.with_ends(along.at(t0), along.at(t1));
            // the stretch of this segment cut but not yet written
            let mut t_from = 0.0;
            let mut t = 0.0;
            let mut i = 0usize;
            // loops in a row that did not advance
            let mut stuck = 0;
            while i < n {
                let t1 = (i + 1) as f64 / n as f64;
                let (a, b) = (along.at(t), along.at(t1));
                let u = (b - a).unit();
                let ahead = a + u * look;
                let e_here = chord_engagement(g, a, b, r, h);
                let e_ahead = side_engagement(g, P3::at_z(ahead, -1.0), u, r);
                if e_here.max(e_ahead) <= bound {
                    note(cut_chord(g, a, b, r, h), a, worst);
                    t = t1;
                    i += 1;
                    continue;
                }
                // loops from here: write the stretch so far
                if t > t_from {
                    steps.push(Step::Seg {
                        seg: part(t_from, t),
                    });
                }
                // towards the cleared side, square to the wall where the tool stands
                let ut = seg.tangent_at(t);
                let side = if self.climb { ut.perp() } else { -ut.perp() };
                // each loop tried on the raster (and undone unless it stays): the first of
                // a few radii and advances along the wall that keeps the bound, else the
                // closed form's advance
                let trial = |g: &mut Grid, rho: f64, adv: f64, log: &mut Vec<(usize, f32)>| {
                    let tn = (t + adv / len).min(t1);
                    let an = along.at(tn);
                    // the room for the loop where it is (a corner ahead leaves less)
                    let rho = rho.min(self.loop_radius(an, side)?);
                    let mut e = 0.0f64;
                    if an.dist(a) > 1e-9 {
                        e = e.max(cut_logged(g, a, an, r, h, log));
                    }
                    let circle = circle_segments(an, an + side * rho, rho, self.climb);
                    for cs in &circle {
                        let pts = flatten_segment(cs, h / 8.0);
                        for w in pts.windows(2) {
                            e = e.max(cut_logged(g, w[0], w[1], r, h, log));
                        }
                    }
                    Some((e, tn, an, circle, rho))
                };
                let mut done = None;
                let room = self.loop_radius(a, side);
                if let Some(rho) = room.filter(|&rho| rho > SMALL_LOOP && stuck < 2) {
                    'trials: for f in [1.0, 0.5, 0.25] {
                        for adv in [0.25, 0.15, 0.08, 0.04, 0.02, 0.0] {
                            let mut log = Vec::new();
                            let Some((e, tn, an, circle, _)) = trial(g, f * rho, adv, &mut log)
                            else {
                                continue;
                            };
                            if e <= bound {
                                done = Some((tn, an, circle, e));
                                break 'trials;
                            }
                            undo(g, &log);
                        }
                    }
                }
                if let (None, Some(rho)) = (&done, room) {
                    // loops finer than the raster resolves, or none of its trials keeps
                    // the bound or advances: advanced by the closed form
                    let mut advance = |rho: f64| match memo.iter().find(|m| m.0 == rho) {
                        Some(m) => m.1,
                        None => {
                            let adv = loop_advance(r, rho, bound - 4.0);
                            memo.push((rho, adv));
                            adv
                        }
                    };
                    let mut log = Vec::new();
                    let mut got = trial(g, rho, advance(rho), &mut log);
                    // the loop's room where it lands is less: tried again at its advance
                    if let Some((_, _, _, _, less)) = got {
                        if less < rho - 1e-9 {
                            undo(g, &log);
                            got = trial(g, less, advance(less), &mut Vec::new());
                        }
                    }
                    if let Some((_, tn, an, circle, rho)) = got {
                        done = Some((tn, an, circle, loop_reading(r, rho, (tn.max(t) - t) * len)));
                    }
                }
                let Some((tn, an, circle, e)) = done else {
                    // no room for a loop here: straight on
                    note(cut_chord(g, a, b, r, h), a, worst);
                    steps.push(Step::Seg { seg: part(t, t1) });
                    t = t1;
                    t_from = t;
                    i += 1;
                    stuck = 0;
                    continue;
                };
                note(e, an, worst);
                if tn > t {
                    steps.push(Step::Seg { seg: part(t, tn) });
                }
                for cs in circle {
                    steps.push(Step::Seg { seg: cs });
                }
                if tn >= t1 - 1e-12 {
                    i += 1;
                }
                stuck = if tn > t { 0 } else { stuck + 1 };
                t = tn;
                t_from = t;
            }
            if t > t_from {
                steps.push(Step::Seg {
                    seg: part(t_from, t),
                });
            }
        }
    }

    /// The radius of a trochoidal loop at `a` on a wall loop (the loop's centre at
    /// `a + side·ρ`), as large as half a millimetre and the walls allow; none under 0.05 mm.
    fn loop_radius(&self, a: Point, side: Point) -> Option<f64> {
        for rho in [0.5, 0.35, 0.25, 0.18, 0.12, 0.08, 0.05] {
            let c = a + side * rho;
            let d = match self.near.closest(c) {
                None => f64::INFINITY,
                Some((d, _)) => d,
            };
            if d >= self.kexact + rho - 1e-3 {
                return Some(rho);
            }
        }
        None
    }

    /// Each wall loop once round, nearest first, from its vertex nearest the tool.
    fn walls(&mut self, walls: &[Region]) {
        let mut todo: Vec<Polyline> = walls
            .iter()
            .flat_map(|w| w.boundaries().cloned())
            .map(|pl| if self.climb { pl } else { pl.reversed() })
            .collect();
        while !todo.is_empty() {
            let at = self.at;
            // the middles of the segments, nearest first; the first whose spot three cells
            // inside (towards the cleared side) has a clear tool disc starts its loop
            let mut mids: Vec<(f64, usize, usize)> = todo
                .iter()
                .enumerate()
                .flat_map(|(li, l)| {
                    l.segments()
                        .enumerate()
                        .map(move |(si, sg)| (sg.point_at(0.5).dist(at), li, si))
                })
                .collect();
            mids.sort_by(|a, b| a.0.total_cmp(&b.0));
            let inward = |pl: &Polyline, si: usize| {
                let sg = pl.segment(si);
                let u0 = sg.tangent_at(0.5);
                let side = if self.climb { u0.perp() } else { -u0.perp() };
                sg.point_at(0.5) + side * (3.0 * self.h)
            };
            let pick = mids
                .iter()
                .find(|&&(_, li, si)| {
                    !disc_has(&self.g, inward(&todo[li], si), self.r + 2.0 * self.h, -1.0)
                })
                .or(mids.first())
                .map(|&(_, li, si)| (li, si));
            let Some((li, si)) = pick else {
                break;
            };
            let q_in = inward(&todo[li], si);
            let open = !disc_has(&self.g, q_in, self.r + 2.0 * self.h, -1.0);
            let pl = todo.swap_remove(li);
            let pl = entry::restart(&pl, si, 0.5 * pl.segment(si).length());
            let q = pl.vertices[0].pos();
            let mut g = std::mem::replace(&mut self.g, Grid::new(Point::default(), 1.0, 0, 0));
            let mut steps = Vec::new();
            if open {
                let mut here = self.at;
                self.link(&g, &mut steps, &mut here, q_in);
                cut_chord(&mut g, q_in, q, self.r, self.h);
                steps.push(Step::Seg {
                    seg: Segment::Line { a: q_in, b: q },
                });
            }
            let mut worst = Worst::of(&pl);
            if open {
                self.trace_wall(&mut g, &pl, &mut steps, &mut worst);
            } else {
                for seg in pl.segments() {
                    let pts = flatten_segment(&seg, self.h / 8.0);
                    for w in pts.windows(2) {
                        let e = cut_chord(&mut g, w[0], w[1], self.r, self.h);
                        worst.note(e, w[0]);
                    }
                }
            }
            self.g = g;
            self.steps.extend(steps);
            let (e, at) = worst.away;
            if e > self.found.worst {
                self.found.worst = e;
                self.found.worst_at = at;
            }
            // the user's bound: the planner aims MARGIN_DEG under it
            let user = self.bound + MARGIN_DEG;
            if e > user {
                self.found.over.push((at, e));
            }
            self.found.corners.extend(
                worst
                    .sharp
                    .iter()
                    .filter(|c| c.2 > user)
                    .map(|&(c, turn, e)| (c, e, turn)),
            );
            if !open {
                self.steps.push(Step::Ramp { pl });
            }
            self.at = q;
        }
    }
}

/// Trochoidal loops of this radius or less (mm) are finer than the planning raster
/// resolves (a neck less than a millimetre wider than the tool): they advance by the
/// closed form ([`loop_advance`]) instead of trials on the raster.
const SMALL_LOOP: f64 = 0.25;

/// The most engagement round a trochoidal loop of radius `rho` advanced `adv` along a slot
/// (the loops before it cut a disc of R + ρ about a centre `adv` behind), as the cutting
/// simulation reads it on cells of D/60 (its probes R + 0.72 cell out, on the half circle
/// facing the way the tool moves; its default cell, D/120, reads less), degrees: every 5°
/// round the loop, the probes of 1° outside the last loop's disc.
fn loop_reading(r: f64, rho: f64, adv: f64) -> f64 {
    let rp = r + 0.72 * (2.0 * r / 60.0);
    let cut = r + rho;
    let mut most = 0usize;
    for i in 0..72 {
        let psi = (i as f64 * 5.0).to_radians();
        // the tool's centre from the last loop's centre (a loop turning left, advancing +x)
        let t = Point::new(rho * psi.cos() + adv, rho * psi.sin());
        let on = (0..=180)
            .filter(|&k| {
                let th = psi + (k as f64).to_radians();
                (t + Point::new(rp * th.cos(), rp * th.sin())).len() > cut
            })
            .count();
        most = most.max(on);
    }
    most as f64
}

/// The largest advance per trochoidal loop of radius `rho`, from 0.005 to 0.25 mm, whose
/// [`loop_reading`] keeps `bound` (the least when none does).
fn loop_advance(r: f64, rho: f64, bound: f64) -> f64 {
    let (mut lo, mut hi) = (0.005, 0.25);
    if loop_reading(r, rho, lo) > bound {
        return lo;
    }
    if loop_reading(r, rho, hi) <= bound {
        return hi;
    }
    for _ in 0..30 {
        let mid = 0.5 * (lo + hi);
        if loop_reading(r, rho, mid) <= bound {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// The engagement along the chord a→b at the level (bottom −1) before it cuts, then the
/// cut: the largest engagement, degrees.
fn cut_chord(g: &mut Grid, a: Point, b: Point, r: f64, h: f64) -> f64 {
    if a.dist(b) < 1e-12 {
        return 0.0;
    }
    let worst = chord_engagement(g, a, b, r, h);
    g.cut(
        P3::at_z(a, -1.0),
        P3::at_z(b, -1.0),
        r - SHRINK * h,
        true,
        |_, _, _| {},
    );
    worst
}

/// The largest engagement along the chord a→b on `g` (bottom −1), nothing cut.
fn chord_engagement(g: &Grid, a: Point, b: Point, r: f64, h: f64) -> f64 {
    let d = b - a;
    let l = d.len();
    if l < 1e-12 {
        return 0.0;
    }
    let u = d * (1.0 / l);
    let n = ((l / h).ceil() as usize).max(1);
    (1..=n)
        .map(|s| side_engagement(g, P3::at_z(a + d * (s as f64 / n as f64), -1.0), u, r))
        .fold(0.0, f64::max)
}

/// Puts back the cells a trial cut changed (its log, last first).
fn undo(g: &mut Grid, log: &[(usize, f32)]) {
    for &(k, old) in log.iter().rev() {
        g.top[k] = old;
    }
}

/// [`cut_chord`], the cells it lowers and their old heights added to `log`.
fn cut_logged(
    g: &mut Grid,
    a: Point,
    b: Point,
    r: f64,
    h: f64,
    log: &mut Vec<(usize, f32)>,
) -> f64 {
    let e = chord_engagement(g, a, b, r, h);
    g.cut(
        P3::at_z(a, -1.0),
        P3::at_z(b, -1.0),
        r - SHRINK * h,
        true,
        |k, old, _| log.push((k, old)),
    );
    e
}

/// A full circle from `a` about `c` (radius `rho`) as two half arcs, counter-clockwise
/// when `ccw`.
fn circle_segments(a: Point, c: Point, rho: f64, ccw: bool) -> [Segment; 2] {
    let o = c + (c - a);
    [
        Segment::Arc {
            a,
            b: o,
            center: c,
            radius: rho,
            ccw,
        },
        Segment::Arc {
            a: o,
            b: a,
            center: c,
            radius: rho,
            ccw,
        },
    ]
}

/// Whether material stands above `z` in the disc of radius `rad` about `p`.
fn disc_has(g: &Grid, p: Point, rad: f64, z: f64) -> bool {
    capsule_has(g, p, p, rad, z)
}

/// Whether material stands above `z` within `rad` of the segment a→b.
fn capsule_has(g: &Grid, a: Point, b: Point, rad: f64, z: f64) -> bool {
    capsule_meets(g, a, b, rad, z, &[])
}

/// Whether the disc of radius `rad` swept from `a` to `b` meets material at the level that
/// is not the part (`part` per cell).
fn capsule_cuts(g: &Grid, part: &[bool], a: Point, b: Point, rad: f64) -> bool {
    capsule_meets(g, a, b, rad, -1.0, part)
}

/// [`capsule_has`], the cells where `skip` is true left out (none when it is empty).
fn capsule_meets(g: &Grid, a: Point, b: Point, rad: f64, z: f64, skip: &[bool]) -> bool {
    let h = g.h;
    let lo = Point::new(a.x.min(b.x) - rad, a.y.min(b.y) - rad);
    let hi = Point::new(a.x.max(b.x) + rad, a.y.max(b.y) + rad);
    let i0 = ((lo.x - g.origin.x) / h).floor().max(0.0) as usize;
    let j0 = ((lo.y - g.origin.y) / h).floor().max(0.0) as usize;
    let i1 = (((hi.x - g.origin.x) / h).ceil() as usize).min(g.nx.saturating_sub(1));
    let j1 = (((hi.y - g.origin.y) / h).ceil() as usize).min(g.ny.saturating_sub(1));
    let zf = z as f32 + 1e-4;
    let d = b - a;
    let l2 = d.dot(d);
    let r2 = rad * rad;
    for j in j0..=j1 {
        let row = &g.top[j * g.nx..(j + 1) * g.nx];
        for (i, &t) in row.iter().enumerate().take(i1 + 1).skip(i0) {
            if t <= zf || skip.get(j * g.nx + i) == Some(&true) {
                continue;
            }
            let v = g.centre(i, j) - a;
            let t = if l2 > 0.0 {
                (v.dot(d) / l2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let w = v - d * t;
            if w.dot(w) <= r2 {
                return true;
            }
        }
    }
    false
}

/// A direction tried for a step: its index from the last (positive towards the material),
/// its angle, and the engagement and end of the step if its end may be a centre.
type Sample = (i32, f64, Option<(f64, Point)>);

/// How far inside the least distance from the part the passes keep, mm (more than the
/// fit of the runs into lines and arcs, an eighth of a cell for the 6 mm tool's cells).
const INSIDE: f64 = 0.02;

/// The boundary segments of a region in square buckets, each holding every segment within
/// `reach` of it: exact distances to the boundary near it.
#[derive(Clone, Debug, Default)]
struct Near {
    segs: Vec<crate::geom::Segment>,
    origin: Point,
    cell: f64,
    nx: usize,
    ny: usize,
    buckets: Vec<Vec<u32>>,
    reach: f64,
}

impl Near {
    fn new(region: &Region, cell: f64, reach: f64) -> Near {
        let segs: Vec<_> = region.boundaries().flat_map(|b| b.segments()).collect();
        let b = region.bounds();
        let origin = b.min - Point::new(reach + cell, reach + cell);
        let nx = ((b.width() + 2.0 * (reach + cell)) / cell).ceil() as usize + 1;
        let ny = ((b.height() + 2.0 * (reach + cell)) / cell).ceil() as usize + 1;
        let mut buckets = vec![Vec::new(); nx * ny];
        for (k, sg) in segs.iter().enumerate() {
            let sb = sg.bounds();
            let i0 = ((sb.min.x - reach - origin.x) / cell).floor().max(0.0) as usize;
            let j0 = ((sb.min.y - reach - origin.y) / cell).floor().max(0.0) as usize;
            let i1 = (((sb.max.x + reach - origin.x) / cell).floor() as usize).min(nx - 1);
            let j1 = (((sb.max.y + reach - origin.y) / cell).floor() as usize).min(ny - 1);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    buckets[j * nx + i].push(k as u32);
                }
            }
        }
        Near {
            segs,
            origin,
            cell,
            nx,
            ny,
            buckets,
            reach,
        }
    }

    /// The nearest boundary point to `p` and its distance, if one is within `reach`.
    fn closest(&self, p: Point) -> Option<(f64, Point)> {
        if self.cell <= 0.0 {
            return None;
        }
        let i = ((p.x - self.origin.x) / self.cell).floor();
        let j = ((p.y - self.origin.y) / self.cell).floor();
        if i < 0.0 || j < 0.0 || i >= self.nx as f64 || j >= self.ny as f64 {
            return None;
        }
        let mut best: Option<(f64, Point)> = None;
        for &k in &self.buckets[j as usize * self.nx + i as usize] {
            let c = self.segs[k as usize].closest_point(p);
            let d = c.dist(p);
            if best.is_none_or(|b| d < b.0) {
                best = Some((d, c));
            }
        }
        best.filter(|b| b.0 < self.reach)
    }
}

/// Writes the plan at each level.
struct Emit<'a> {
    tp: &'a mut Toolpath,
    c: &'a Cutting,
    at: P3,
    slope: f64,
    /// The level's raster at its end (what the level above cleared).
    g: &'a Grid,
}

impl Emit<'_> {
    fn push(&mut self, m: Move) {
        if let Move::Rapid { to } | Move::Linear { to, .. } | Move::Arc { to, .. } = m {
            self.at = to;
        }
        self.tp.push(m);
    }

    /// Over `q` at `z_top + LINK_LIFT` (lifted when the level above cleared the way,
    /// else by the safe height), from wherever the tool is.
    fn over(&mut self, q: Point, z: f64, z_top: f64) {
        let lift = z_top + LINK_LIFT;
        let r = self.c.tool.radius();
        let here = self.at;
        let low_ok = lift < self.c.safe_z
            && here.z <= lift + 1e-9
            && here.z >= z - 1e-9
            && (z_top >= -1e-12 || !capsule_has(self.g, here.xy(), q, r + self.g.h, -1.0));
        if low_ok {
            if here.z < lift - 1e-9 {
                self.push(Move::Linear {
                    to: P3::at_z(here.xy(), lift),
                    feed: self.c.plunge_feed,
                });
            }
            if here.xy().dist(q) > 1e-9 {
                self.push(Move::Linear {
                    to: P3::at_z(q, lift),
                    feed: self.c.feed,
                });
            }
            return;
        }
        if here.z < self.c.safe_z {
            self.push(Move::Rapid {
                to: P3::at_z(here.xy(), self.c.safe_z),
            });
        }
        if here.xy().dist(q) > 1e-9 {
            self.push(Move::Rapid {
                to: P3::at_z(q, self.c.safe_z),
            });
        }
        self.push(Move::Rapid {
            to: P3::at_z(q, lift),
        });
    }

    fn down(&mut self, z: f64) {
        if self.at.z > z + 1e-9 {
            self.push(Move::Linear {
                to: P3::at_z(self.at.xy(), z),
                feed: self.c.plunge_feed,
            });
        }
    }

    /// One level at `z` (the last at `z_top`). The first level's helices bore each core
    /// down to `bore`, the last level's depth, and come back up it; the levels after go
    /// straight down the bored cores, through air.
    fn level(&mut self, steps: &[Step], z: f64, z_top: f64, bore: Option<f64>) {
        let feed = self.c.feed;
        let ccw = self.c.climb;
        let mut run: Vec<Point> = Vec::new();
        for s in steps {
            if let Step::Cut { to } = s {
                if run.is_empty() {
                    run.push(self.at.xy());
                }
                run.push(*to);
                continue;
            }
            self.cuts(&mut run, z);
            match s {
                Step::Helix { c, rho } => {
                    let q = *c + Point::new(*rho, 0.0);
                    self.over(q, z, z_top);
                    match bore {
                        Some(bottom) => {
                            self.down(z_top);
                            let to = bottom.min(z);
                            for m in entry::helix(q, *c, ccw, z_top, to, self.slope, feed) {
                                self.push(m);
                            }
                            if to < z - 1e-9 {
                                // back up the bored core to this level
                                self.push(Move::Linear {
                                    to: P3::at_z(q, z),
                                    feed: self.c.plunge_feed,
                                });
                            }
                        }
                        None => self.down(z),
                    }
                }
                Step::Go { to, depth } => {
                    if *depth && (self.at.z - z).abs() < 1e-9 {
                        self.push(Move::Linear {
                            to: P3::at_z(*to, z),
                            feed,
                        });
                    } else {
                        self.over(*to, z, z_top);
                        self.down(z);
                    }
                }
                // gathered into the run above
                Step::Cut { .. } => {}
                Step::Seg { seg } => {
                    self.push(cut(*seg, z, feed));
                }
                Step::Ramp { pl } => {
                    let q = pl.vertices[0].pos();
                    if self.at.xy().dist(q) > 1e-9 || self.at.z < z_top - 1e-9 {
                        self.over(q, z, z_top);
                    }
                    self.down(z_top);
                    let (moves, rest) = entry::ramp_around(pl, z_top, z, self.slope, feed);
                    for m in moves {
                        self.push(m);
                    }
                    for seg in rest.segments() {
                        self.push(cut(seg, z, feed));
                    }
                }
            }
        }
        self.cuts(&mut run, z);
    }

    /// A run of cuts at depth from its first point, fitted into lines and arcs within a
    /// quarter of a planning cell (the passes are traced off the raster; every one keeps
    /// 1.5 cells or more from the wall, so the fit cannot reach the part).
    fn cuts(&mut self, run: &mut Vec<Point>, z: f64) {
        if run.len() < 2 {
            run.clear();
            return;
        }
        let fit = crate::biarc::fit_points(
            run,
            false,
            &crate::biarc::BiarcOptions::with_tolerance(self.g.h / 8.0),
        );
        for seg in fit.segments() {
            self.push(cut(seg, z, self.c.feed));
        }
        run.clear();
    }

    /// The finishing pass at the full depth `z`: round each final wall, in from the
    /// roughing wall's nearest point and back out to it.
    fn finish(&mut self, finals: &[Region], rough: &[Region], z: f64, z_top: f64) {
        let feed = self.c.feed;
        let climb = self.c.climb;
        let rough_loops: Vec<&Polyline> = rough.iter().flat_map(|w| w.boundaries()).collect();
        for w in finals {
            for pl in w.boundaries() {
                let pl = if climb { pl.clone() } else { pl.reversed() };
                let here = self.at.xy();
                let vi = (0..pl.len())
                    .min_by(|&a, &b| {
                        pl.vertices[a]
                            .pos()
                            .dist(here)
                            .total_cmp(&pl.vertices[b].pos().dist(here))
                    })
                    .unwrap_or(0);
                let pl = entry::restart(&pl, vi, 0.0);
                let q = pl.vertices[0].pos();
                let Some(from) = rough_loops
                    .iter()
                    .flat_map(|l| l.segments())
                    .map(|s| s.closest_point(q))
                    .min_by(|a, b| a.dist(q).total_cmp(&b.dist(q)))
                else {
                    continue;
                };
                if (self.at.z - z).abs() < 1e-9
                    && !capsule_has(
                        self.g,
                        self.at.xy(),
                        from,
                        self.c.tool.radius() + self.g.h,
                        -1.0,
                    )
                {
                    self.push(Move::Linear {
                        to: P3::at_z(from, z),
                        feed,
                    });
                } else {
                    self.over(from, z, z_top);
                    self.down(z);
                }
                self.push(Move::Linear {
                    to: P3::at_z(q, z),
                    feed,
                });
                for seg in pl.segments() {
                    self.push(cut(seg, z, feed));
                }
                self.push(Move::Linear {
                    to: P3::at_z(from, z),
                    feed,
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ring_outside_a_cleared_core_reads_the_closed_form() {
        let h = 0.15;
        let mut g = Grid::new(Point::new(-15.0, -15.0), h, 200, 200);
        g.top.iter_mut().for_each(|t| *t = 0.0);
        let ring: Vec<Point> = (0..=64)
            .map(|i| {
                let a = i as f64 / 64.0 * std::f64::consts::TAU;
                Point::new(3.0 * a.cos(), 3.0 * a.sin())
            })
            .collect();
        for w in ring.windows(2) {
            g.cut(
                P3::at_z(w[0], -1.0),
                P3::at_z(w[1], -1.0),
                3.0,
                false,
                |_, _, _| {},
            );
        }
        let e = side_engagement(&g, P3::new(3.3, 0.0, -1.0), Point::new(0.0, 1.0), 3.0);
        // B = 6, rho = 3.3, R = 3: cos a = (36 - 3.3² - 9) / (2 · 3.3 · 3)
        let want = ((36.0f64 - 3.3 * 3.3 - 9.0) / 19.8).acos().to_degrees();
        assert!((e - want).abs() < 5.0, "{e} vs {want}");
    }
}
