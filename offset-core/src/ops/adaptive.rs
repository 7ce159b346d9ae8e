//! Adaptive clearing: a region with islands cleared by passes that grow outward from a helix-cut core, each step chosen so the simulated engagement of the tool stays at or under a bound, links kept inside cleared material.
//!
//! The method (docs/toolpaths.md, "Adaptive clearing"), one plan in XY repeated at every
//! depth pass (each level starts from the same uncut cross-section):
//! - A planning raster of the cutting simulation's kind ([`crate::cutsim::grid::Grid`],
//!   cell D/40) holds the level's material. The tool centre may go where the region's
//!   boundary is at least R + allowance (+ the finishing stock) + 1.5 cells away: the
//!   raster's distance transform, the 1.5 cells covering its error of at most 0.71 cell.
//! - Each connected part of that area gets a core: a helix at its deepest point (a circle
//!   of at most the tool radius). From the core, the geodesic distance inside the area
//!   (Dijkstra over 16 neighbours, within 3 % of the true length) orders the material: the
//!   passes are its iso-lines, the boundaries of the cleared area offset outward and
//!   clipped by the walls, traced by marching squares with the cleared side on the left
//!   (climb: counter-clockwise about what is cleared).
//! - Step: each next iso-line is tried at the last step × 1.2 (at most R(1 − cos E), the
//!   straight cut's), cut on a copy of the raster with the simulation's own engagement
//!   probe ([`crate::cutsim::side_engagement`]); while the largest engagement passes the
//!   bound less 3°, the step shrinks by a quarter, down to two cells. So corners, necks and
//!   the first rings round the core get the small steps they need and open stretches the
//!   large one.
//! - A pass's stretches that cut nothing are replaced by links; a pass that cuts all round
//!   (the rings round the core) is entered by a lead-in from a point whose tool disc is
//!   already cleared, at a slant of a few degrees. Links: at depth where the tool's disc
//!   swept along the straight link (R + 1 cell) touches no material at that moment; else
//!   lifted 0.5 mm over the last level's floor where the level's final raster is clear
//!   there (the level above cut it); else at the safe height. Every link ends over a spot
//!   already cleared at depth, so the tool goes down through air.
//! - Then each wall (the region offset inward by R + allowance, by the offset kernel)
//!   once round, exact arcs and lines: it takes the last 1.5 cells, the coverage to the
//!   wall. With `finish`, those passes leave [`finish_stock`] and one last pass round each
//!   wall at the full depth takes it (in from the roughing wall, out again).
//! - What the bound does not cover: the helix into each level's core goes down through
//!   material (the simulation reads 180° for any move that descends into material);
//!   where no step down to two cells keeps the bound, the pass is kept and the tool
//!   path's warnings say where and how much. That happens today wherever a front meets a
//!   wall (the pass runs along the wall into the corner the front makes with it: 90° to
//!   180° whatever the step) and in necks (a slot): the bound is NOT yet held there.
//! - The passes' runs of cuts go out fitted into lines and arcs within a quarter of a cell.

use super::entry;
use super::profile::cut;
use super::{pass_depths, Cutting, OpError};
use crate::cutsim::grid::{flatten_segment, Grid};
use crate::cutsim::side_engagement;
use crate::geom::{Point, Polyline, Region, Shape};
use crate::offset::{offset_region, OffsetOptions};
use crate::toolpath::{Move, Toolpath, P3};
use serde::{Deserialize, Serialize};
use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap};

/// The engagement bound when none is given, degrees.
pub const DEFAULT_ENGAGEMENT: f64 = 70.0;

/// How far under the bound the planner aims, degrees (the check's raster differs).
const MARGIN_DEG: f64 = 3.0;

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
    /// A wall loop from its first vertex (the tool stands there at depth).
    Wall { pl: Polyline },
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
    cores: usize,
    passes: usize,
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
        let mut em = Emit {
            tp: &mut tp,
            c: &p.cut,
            at,
            slope,
            g: &plan.g,
        };
        for (k, &z) in depths.iter().enumerate() {
            let z_top = if k == 0 { 0.0 } else { depths[k - 1] };
            em.level(&plan.steps, z, z_top);
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
            "{} passes could not keep the engagement at {}° even at the smallest step; the worst reads {e:.0}° at ({:.2}, {:.2})",
            summary.over.len(),
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
            let (cells, bbox) = self.spread(seed, id, &allowed, &mut geo, &mut comp);
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
            let far = cells.iter().map(|&k| geo[k]).fold(0.0, f64::max);
            self.grow(&geo, &comp, id, bbox, rho, far, c);
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

    /// The passes of one part: iso-lines of `geo` from the core's ring (`from`) out to
    /// the farthest cell (`far`), each step tried on a copy of the raster.
    #[allow(clippy::too_many_arguments)]
    fn grow(
        &mut self,
        geo: &[f64],
        comp: &[u32],
        id: u32,
        bbox: [usize; 4],
        from: f64,
        far: f64,
        core: Point,
    ) {
        let s_max = self.r * (1.0 - (self.bound.to_radians()).cos());
        let s_min = 2.0 * self.h;
        let mut s = s_max * 0.5;
        let mut level = from;
        while level < far + self.h * 0.5 {
            let mut step = (s * 1.2).min(s_max);
            loop {
                let next = (level + step).min(far + self.h);
                let loops = iso_lines(&self.g, geo, comp, id, bbox, next, self.h);
                let mut trial = self.g.clone();
                let mut steps = Vec::new();
                let mut at = self.at;
                let (worst, where_) =
                    self.pass(&mut trial, &loops, &mut steps, &mut at, core, step);
                if worst <= self.bound || step <= s_min {
                    if worst > self.bound {
                        self.found.over.push((where_, worst));
                    }
                    if worst > self.found.worst {
                        self.found.worst = worst;
                        self.found.worst_at = where_;
                    }
                    self.g = trial;
                    self.steps.extend(steps);
                    self.at = at;
                    self.found.passes += 1;
                    level = next;
                    s = step;
                    break;
                }
                step = (step * 0.75).max(s_min);
            }
        }
    }

    /// Cuts the loops of one pass on `g`, nearest first, into `steps`: the largest
    /// engagement and where.
    fn pass(
        &self,
        g: &mut Grid,
        loops: &[Vec<Point>],
        steps: &mut Vec<Step>,
        at: &mut Point,
        core: Point,
        step: f64,
    ) -> (f64, Point) {
        let mut worst = (0.0, Point::default());
        let mut todo: Vec<&Vec<Point>> = loops.iter().filter(|l| l.len() >= 3).collect();
        while !todo.is_empty() {
            // the loop with the vertex nearest the tool
            let (li, vi) = todo
                .iter()
                .enumerate()
                .flat_map(|(li, l)| l.iter().enumerate().map(move |(vi, q)| (li, vi, *q)))
                .min_by(|a, b| a.2.dist(*at).total_cmp(&b.2.dist(*at)))
                .map(|(li, vi, _)| (li, vi))
                .expect("loops left");
            let lp = todo.swap_remove(li);
            let n = lp.len();
            let air: Vec<bool> = (0..n)
                .map(|i| !capsule_has(g, lp[i], lp[(i + 1) % n], self.r + self.h, -1.0))
                .collect();
            if air.iter().all(|&a| a) {
                continue;
            }
            // start where the loop comes out of air into material, or by a lead-in
            let start = (0..n).find(|&i| air[(i + n - 1) % n] && !air[i]);
            let order: Vec<Point> = match start {
                Some(i0) => {
                    self.link(g, steps, at, lp[i0]);
                    (1..=n).map(|k| lp[(i0 + k) % n]).collect()
                }
                None => {
                    // a ring that cuts all round: a spiral out to it from the last ring
                    // over one turn, then once round on it
                    let q = lp[vi];
                    let Some(a) = self.lead_from(g, q, core, step) else {
                        // no cleared spot found: take the loop from the nearest vertex
                        self.link(g, steps, at, q);
                        let pts: Vec<Point> = (1..=n).map(|k| lp[(vi + k) % n]).collect();
                        self.chain(g, steps, at, &pts, &mut worst);
                        continue;
                    };
                    let inset = a.dist(q);
                    self.link(g, steps, at, a);
                    let mut order: Vec<Point> = (1..=n)
                        .map(|k| {
                            let p = lp[(vi + k) % n];
                            let u = (core - p) * (1.0 / p.dist(core).max(1e-12));
                            let f = 1.0 - k as f64 / n as f64;
                            p + u * (inset.min(p.dist(core)) * f)
                        })
                        .collect();
                    order.extend((1..=n).map(|k| lp[(vi + k) % n]));
                    order
                }
            };
            self.chain(g, steps, at, &order, &mut worst);
        }
        worst
    }

    /// A spot on the way from `q` to the core whose tool disc is cleared.
    fn lead_from(&self, g: &Grid, q: Point, core: Point, step: f64) -> Option<Point> {
        let len = q.dist(core);
        let u = (core - q) * (1.0 / len.max(1e-12));
        let mut t = step;
        while t < len {
            let a = q + u * t;
            if !disc_has(g, a, self.r + self.h, -1.0) {
                return Some(a);
            }
            t += 0.5 * step.max(self.h);
        }
        (!disc_has(g, core, self.r + self.h, -1.0)).then_some(core)
    }

    /// A link from `at` to `to`, at depth when the swept disc meets no material now.
    fn link(&self, g: &Grid, steps: &mut Vec<Step>, at: &mut Point, to: Point) {
        if at.dist(to) < 1e-9 {
            return;
        }
        let depth = !capsule_has(g, *at, to, self.r + self.h, -1.0);
        steps.push(Step::Go { to, depth });
        *at = to;
    }

    /// Cuts the points in turn from `at` (a cut to each), stretches in air longer than the
    /// tool diameter replaced by links.
    fn chain(
        &self,
        g: &mut Grid,
        steps: &mut Vec<Step>,
        at: &mut Point,
        pts: &[Point],
        worst: &mut (f64, Point),
    ) {
        let mut pending: Vec<Point> = Vec::new();
        let mut pending_len = 0.0;
        let mut last = *at;
        for &b in pts {
            let a = last;
            last = b;
            if a.dist(b) < 1e-9 {
                continue;
            }
            if !capsule_has(g, a, b, self.r + self.h, -1.0) {
                pending_len += a.dist(b);
                pending.push(b);
                continue;
            }
            // material ahead: the air before it, as cuts or a link
            if pending_len > 2.0 * self.r {
                self.link(g, steps, at, a);
            } else {
                for &q in &pending {
                    steps.push(Step::Cut { to: q });
                }
            }
            pending.clear();
            pending_len = 0.0;
            let e = cut_chord(g, a, b, self.r, self.h);
            if e > worst.0 {
                *worst = (e, a);
            }
            steps.push(Step::Cut { to: b });
            *at = b;
        }
        // trailing air is left out: the tool stays where it last cut
        let _ = at;
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
            let (li, vi) = todo
                .iter()
                .enumerate()
                .flat_map(|(li, l)| {
                    l.vertices
                        .iter()
                        .enumerate()
                        .map(move |(vi, v)| (li, vi, v.pos()))
                })
                .min_by(|a, b| a.2.dist(at).total_cmp(&b.2.dist(at)))
                .map(|(li, vi, _)| (li, vi))
                .expect("walls left");
            let pl = todo.swap_remove(li);
            let pl = entry::restart(&pl, vi, 0.0);
            let q = pl.vertices[0].pos();
            let open = !disc_has(&self.g, q, self.r + self.h, -1.0);
            let mut g = std::mem::replace(&mut self.g, Grid::new(Point::default(), 1.0, 0, 0));
            let mut steps = Vec::new();
            if open {
                let mut here = self.at;
                self.link(&g, &mut steps, &mut here, q);
            }
            let mut worst = (0.0, Point::default());
            for seg in pl.segments() {
                let pts = flatten_segment(&seg, self.h / 8.0);
                for w in pts.windows(2) {
                    let e = cut_chord(&mut g, w[0], w[1], self.r, self.h);
                    if e > worst.0 {
                        worst = (e, w[0]);
                    }
                }
            }
            self.g = g;
            self.steps.extend(steps);
            if worst.0 > self.found.worst {
                self.found.worst = worst.0;
                self.found.worst_at = worst.1;
            }
            if worst.0 > self.bound {
                self.found.over.push((worst.1, worst.0));
            }
            self.steps.push(if open {
                Step::Wall { pl }
            } else {
                Step::Ramp { pl }
            });
            self.at = q;
        }
    }
}

/// The engagement along the chord a→b at the level (bottom −1) before it cuts, then the
/// cut: the largest engagement, degrees.
fn cut_chord(g: &mut Grid, a: Point, b: Point, r: f64, h: f64) -> f64 {
    let d = b - a;
    let l = d.len();
    if l < 1e-12 {
        return 0.0;
    }
    let u = d * (1.0 / l);
    let n = ((l / h).ceil() as usize).max(1);
    let mut worst = 0.0f64;
    for s in 1..=n {
        let p = a + d * (s as f64 / n as f64);
        worst = worst.max(side_engagement(g, P3::at_z(p, -1.0), u, r));
    }
    g.cut(P3::at_z(a, -1.0), P3::at_z(b, -1.0), r, true, |_, _, _| {});
    worst
}

/// Whether material stands above `z` in the disc of radius `rad` about `p`.
fn disc_has(g: &Grid, p: Point, rad: f64, z: f64) -> bool {
    capsule_has(g, p, p, rad, z)
}

/// Whether material stands above `z` within `rad` of the segment a→b.
fn capsule_has(g: &Grid, a: Point, b: Point, rad: f64, z: f64) -> bool {
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
            if t <= zf {
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

/// The closed iso-lines at `level` of the geodesic distance of part `id` (cells of other
/// parts and outside count as infinitely far), by marching squares over cell centres with
/// the nearer side on the left, simplified to within a quarter of a cell.
fn iso_lines(
    g: &Grid,
    geo: &[f64],
    comp: &[u32],
    id: u32,
    bbox: [usize; 4],
    level: f64,
    h: f64,
) -> Vec<Vec<Point>> {
    let nx = g.nx;
    let val = |i: usize, j: usize| {
        let k = j * nx + i;
        if comp[k] == id {
            geo[k]
        } else {
            f64::INFINITY
        }
    };
    let i0 = bbox[0].saturating_sub(1);
    let j0 = bbox[1].saturating_sub(1);
    let i1 = (bbox[2] + 1).min(g.nx - 2);
    let j1 = (bbox[3] + 1).min(g.ny - 2);
    // edge ids: horizontal (i,j)-(i+1,j) 2k, vertical (i,j)-(i,j+1) 2k+1
    // ordered, so each loop starts at the same edge in every run (the same job plans the
    // same program twice)
    let mut next: BTreeMap<usize, (usize, Point)> = BTreeMap::new();
    for j in j0..=j1 {
        for i in i0..=i1 {
            let c = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)];
            let v: Vec<f64> = c.iter().map(|&(a, b)| val(a, b)).collect();
            let inside: Vec<bool> = v.iter().map(|&x| x <= level).collect();
            if inside.iter().all(|&x| x) || inside.iter().all(|&x| !x) {
                continue;
            }
            let edge = |e: usize| -> usize {
                match e {
                    0 => 2 * (j * nx + i),
                    1 => 2 * (j * nx + i + 1) + 1,
                    2 => 2 * ((j + 1) * nx + i),
                    _ => 2 * (j * nx + i) + 1,
                }
            };
            let point = |e: usize| -> Point {
                let (a, b) = (e, (e + 1) % 4);
                let (pa, pb) = (g.centre(c[a].0, c[a].1), g.centre(c[b].0, c[b].1));
                let (va, vb) = (v[a], v[b]);
                let t = if va.is_finite() && vb.is_finite() {
                    ((level - va) / (vb - va)).clamp(0.0, 1.0)
                } else if va.is_finite() {
                    0.0
                } else {
                    1.0
                };
                pa + (pb - pa) * t
            };
            for e in 0..4 {
                // entry: this corner inside, the next (counter-clockwise) outside
                if !inside[e] || inside[(e + 1) % 4] {
                    continue;
                }
                // its exit: the first edge clockwise from it going outside → inside
                for back in 1..4 {
                    let x = (e + 4 - back) % 4;
                    if !inside[x] && inside[(x + 1) % 4] {
                        next.insert(edge(e), (edge(x), point(e)));
                        break;
                    }
                }
            }
        }
    }
    let mut loops = Vec::new();
    while let Some(&start) = next.keys().next() {
        let mut pts = Vec::new();
        let mut e = start;
        while let Some((to, p)) = next.remove(&e) {
            pts.push(p);
            e = to;
        }
        if pts.len() >= 3 {
            loops.push(simplify_closed(&pts, h / 4.0));
        }
    }
    loops
}

/// Douglas–Peucker on a closed loop of points, within `tol`.
fn simplify_closed(pts: &[Point], tol: f64) -> Vec<Point> {
    let n = pts.len();
    // split at the point farthest from the first
    let far = (0..n)
        .max_by(|&a, &b| pts[0].dist(pts[a]).total_cmp(&pts[0].dist(pts[b])))
        .unwrap_or(0);
    let mut keep = vec![false; n + 1];
    keep[0] = true;
    keep[far] = true;
    keep[n] = true;
    let at = |k: usize| pts[k % n];
    let mut stack = vec![(0usize, far), (far, n)];
    while let Some((a, b)) = stack.pop() {
        if b <= a + 1 {
            continue;
        }
        let seg = crate::geom::Segment::Line { a: at(a), b: at(b) };
        let (mut best, mut bd) = (a, -1.0);
        for k in a + 1..b {
            let d = seg.distance_to(at(k));
            if d > bd {
                bd = d;
                best = k;
            }
        }
        if bd > tol {
            keep[best] = true;
            stack.push((a, best));
            stack.push((best, b));
        }
    }
    (0..n).filter(|&k| keep[k]).map(|k| pts[k]).collect()
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

    fn level(&mut self, steps: &[Step], z: f64, z_top: f64) {
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
                    self.down(z_top);
                    for m in entry::helix(q, *c, ccw, z_top, z, self.slope, feed) {
                        self.push(m);
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
                Step::Wall { pl } => {
                    for seg in pl.segments() {
                        self.push(cut(seg, z, feed));
                    }
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
            &crate::biarc::BiarcOptions::with_tolerance(self.g.h / 4.0),
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
