//! Waterline finishing: closed contours at constant tool-tip heights, for the steep walls
//! a raster leaves coarse, with a ball, flat or bull cutter on any triangle soup.
//!
//! The contours come from the drop-cutter's own cutter model (`super::dropcutter`): the
//! cutter at tip height z collides with the part exactly where its drop-cutter height is
//! above z, so the waterline at z is the boundary of that set. It is traced over a grid of
//! drop-cutter heights (`super::envelope`, a step of √(8·R·tolerance) at most, so a chord
//! round the cutter's radius sags by the tolerance), each crossing of a grid edge halved
//! down to a tenth of the tolerance and taken on its free side, and every chord the cutter
//! would gouge along by more than a quarter of the tolerance split again. Levels run from
//! the stock top down to the floor, no more than `stepdown` apart; each contour is cut
//! climb (clockwise round material, with an M3 spindle), entered from the safe height and
//! left back up to it. A mesh's defects (open, non-manifold, turned faces) are one warning;
//! the contours do not need a solid.

use super::dropcutter::{Cutter, DropCutter};
use super::envelope::{grid_step, HeightField};
use super::finish::{describe, tool_of};
use super::{Mesh, MeshError};
use crate::geom::{Point, Polyline};
use crate::ops::pass_depths;
use crate::toolpath::{Move, Toolpath, P3};
use serde::{Deserialize, Serialize};

/// Everything a waterline finish needs besides the mesh.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WaterlineParams {
    /// The cutter (ball, flat or bull).
    pub cutter: Cutter,
    #[serde(default = "one")]
    pub tool_number: u32,
    /// The most between neighbouring contours in Z, mm.
    pub stepdown: f64,
    /// Tolerance of the offset the contours come from, mm.
    pub tolerance: f64,
    pub feed: f64,
    pub plunge_feed: f64,
    /// Height of rapids above the stock top, mm.
    pub safe_z: f64,
    /// The stock top (None: the mesh's highest Z).
    #[serde(default)]
    pub stock_top: Option<f64>,
    /// The lowest contour's tip height (None: the mesh's lowest Z).
    #[serde(default)]
    pub floor: Option<f64>,
    pub spindle_rpm: f64,
    /// Climb milling (true) or conventional.
    pub climb: bool,
}

fn one() -> u32 {
    1
}

impl Default for WaterlineParams {
    fn default() -> Self {
        WaterlineParams {
            cutter: Cutter::ball(6.0),
            tool_number: 1,
            stepdown: 0.5,
            tolerance: 0.01,
            feed: 1200.0,
            plunge_feed: 300.0,
            safe_z: 5.0,
            stock_top: None,
            floor: None,
            spindle_rpm: 12000.0,
            climb: true,
        }
    }
}

/// The most grid points the waterline's height field samples.
pub const WATERLINE_POINTS: usize = 2_000_000;

/// Plans waterline contours of the mesh (any triangle soup) with a ball, flat or bull
/// cutter, in the mesh's frame.
pub fn waterline3d(mesh: &Mesh, p: &WaterlineParams) -> Result<Toolpath, MeshError> {
    p.cutter.check()?;
    for (v, what) in [
        (p.stepdown, "the step-down"),
        (p.tolerance, "the tolerance"),
        (p.feed, "the feed"),
        (p.plunge_feed, "the plunge feed"),
        (p.safe_z, "the safe Z"),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(MeshError::BadParam(format!(
                "{what} must be a positive number, got {v}"
            )));
        }
    }
    let dc = DropCutter::new(mesh, p.cutter)?;
    let (lo, hi) = mesh.bounds().ok_or_else(|| MeshError::Empty {
        name: mesh.name.clone(),
    })?;
    let top = p.stock_top.unwrap_or(hi.z);
    let floor = p.floor.unwrap_or(lo.z);
    if floor.partial_cmp(&top) != Some(std::cmp::Ordering::Less) {
        return Err(MeshError::BadParam(format!(
            "the floor Z {floor} must lie below the stock top Z {top}"
        )));
    }
    let r = p.cutter.radius();
    let tol = p.tolerance;
    // a step whose chords sag no more than the tolerance round the cutter's own radius
    let want = (8.0 * r * tol).sqrt().min(r / 2.0);
    let reach = r + want;
    let h = grid_step(
        hi.x - lo.x + 2.0 * reach,
        hi.y - lo.y + 2.0 * reach,
        want,
        WATERLINE_POINTS,
    );
    let below = lo.z - 1.0;
    let field = HeightField::new(
        &dc,
        [lo.x - reach, lo.y - reach, hi.x + reach, hi.y + reach],
        h,
        below,
    );
    let safe = top.max(hi.z) + p.safe_z;
    let mut tp = Toolpath::new("waterline3d");
    tp.tool = Some(tool_of(&p.cutter, p.tool_number));
    tp.source = mesh.name.clone();
    if let Some(d) = mesh.report().defects() {
        tp.warnings.push(format!("{} is {d}", mesh.name));
    }
    tp.push(Move::Comment {
        text: format!(
            "waterline3d: {} cutter, step-down {} mm, tolerance {} mm",
            describe(&p.cutter),
            p.stepdown,
            p.tolerance
        ),
    });
    if p.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: p.spindle_rpm });
    }
    let mut contours = 0usize;
    for d in pass_depths(top - floor, p.stepdown) {
        let z = top + d;
        let loops = level_contours(&dc, &field, z, tol, below);
        for pl in loops {
            contours += 1;
            // contours run counter-clockwise round material; climb runs clockwise
            let pl = if p.climb { pl.reversed() } else { pl };
            let first = pl.vertices[0].pos();
            tp.push(Move::Rapid {
                to: P3::at_z(first, safe),
            });
            tp.push(Move::Linear {
                to: P3::at_z(first, z),
                feed: p.plunge_feed,
            });
            for v in pl
                .vertices
                .iter()
                .skip(1)
                .chain(std::iter::once(&pl.vertices[0]))
            {
                tp.push(Move::Linear {
                    to: P3::at_z(v.pos(), z),
                    feed: p.feed,
                });
            }
            tp.push(Move::Rapid {
                to: P3::at_z(first, safe),
            });
        }
    }
    if contours == 0 {
        return Err(MeshError::BadParam(format!(
            "{}: no waterline contour lies between Z {top} and Z {floor}: the {} cutter touches the part at no level there",
            mesh.name,
            describe(&p.cutter)
        )));
    }
    if p.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: 0.0 });
    }
    Ok(tp)
}

/// The contours at tip height `z`: where the drop-cutter height crosses z, each crossing
/// of a grid edge found by halving down to a tenth of the tolerance and taken on its free
/// side (the cutter there touches nothing below z), then every chord whose middle or
/// quarters the cutter would gouge by more than a quarter of the tolerance split at a
/// free point found across it.
fn level_contours(
    dc: &DropCutter,
    field: &HeightField,
    z: f64,
    tol: f64,
    below: f64,
) -> Vec<Polyline> {
    let hits = |q: Point| dc.drop(q.x, q.y, below) > z;
    let edge_tol = 0.1 * tol;
    // the free end of [inside, outside] after halving it below edge_tol
    let crossing = |mut inside: Point, mut outside: Point| {
        while inside.dist(outside) > edge_tol {
            let mid = inside.lerp(outside, 0.5);
            if hits(mid) {
                inside = mid;
            } else {
                outside = mid;
            }
        }
        outside
    };
    let loops = field.contours(|hz| hz > z, crossing);
    let gouges = |q: Point| dc.drop(q.x, q.y, below) > z + 0.25 * tol;
    let h = field.h;
    loops
        .into_iter()
        .map(|pl| {
            let pts: Vec<Point> = pl.vertices.iter().map(|v| v.pos()).collect();
            let n = pts.len();
            let mut out = Vec::with_capacity(n);
            for k in 0..n {
                let (a, b) = (pts[k], pts[(k + 1) % n]);
                out.push(a);
                refine(a, b, 0, &mut out, &gouges, &hits, &crossing, h);
            }
            Polyline::from_points(&out, true)
        })
        .collect()
}

/// Splits the chord a→b where the cutter along it would gouge: a free point across its
/// middle (on its right, the free side) goes between, and each half is looked at again.
#[allow(clippy::too_many_arguments)]
fn refine(
    a: Point,
    b: Point,
    depth: u32,
    out: &mut Vec<Point>,
    gouges: &impl Fn(Point) -> bool,
    hits: &impl Fn(Point) -> bool,
    crossing: &impl Fn(Point, Point) -> Point,
    h: f64,
) {
    if depth > 12 || a.dist(b) < 1e-9 {
        return;
    }
    let m = a.lerp(b, 0.5);
    if !(gouges(m) || gouges(a.lerp(b, 0.25)) || gouges(a.lerp(b, 0.75))) {
        return;
    }
    let d = (b - a).unit();
    let right = Point::new(d.y, -d.x);
    // walk out across the chord until the cutter is free, then find the crossing
    let mut reach = h;
    let mut far = m + right * reach;
    while hits(far) && reach < 8.0 * h {
        reach *= 2.0;
        far = m + right * reach;
    }
    if hits(far) {
        return;
    }
    let c = if hits(m) { crossing(m, far) } else { m };
    refine(a, c, depth + 1, out, gouges, hits, crossing, h);
    out.push(c);
    refine(c, b, depth + 1, out, gouges, hits, crossing, h);
}
