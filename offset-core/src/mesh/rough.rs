//! Roughing (rough3d): z-level clearing of the stock round a mesh, each level a pocket of
//! the stock outline with the part's section (grown by the stock allowance) as islands.
//!
//! Levels run from the stock top down to the floor, no more than the step-down apart, plus
//! a level on every flat the part shows between them (raised by the allowance). A level
//! at Z keeps the stock allowance a by taking the part's section at Z - a (the section
//! just above that plane) grown by a in 2D, with the exact offset kernel: for a part with
//! no undercut, sections only shrink upward, so every point of the part within a of the
//! level's plane lies in that grown section, and a flat cutter kept out of it stands at
//! least a above and a beside the part. (Slicing the mesh offset by multiple normals
//! instead would keep the allowance exactly on slopes, but that offset is not trimmed
//! in concave corners, and its folds there make crossing sections.) The levels are
//! cleared from the top down with the 2D pocket (`ops::pocket`, with its entries and
//! clean-up), whose outline is the stock's plan view grown by the tool radius so the tool
//! runs off the stock's edge.
//!
//! Links at depth: a level knows the level cut before it (its Z and its tool-centre
//! regions P0, the pocket's first passes), or, for the first level cut, the stock top and
//! its own P0. A link from one pass or region of the level to the next, and from the end
//! of one level to the start of the next, lifts only [`crate::ops::pocket::LINK_LIFT`]
//! over the floor above and feeds across there when the straight link keeps the tool
//! centre inside that P0; else it goes to the safe height as before. Why that moves
//! through air: the level above swept its flat tool (a cylinder) over every point within
//! the tool radius of its P0 (the pocket's coverage), so over its floor nothing of the
//! stock is left there; and the part does not reach there either, since the islands of
//! that level hold the part above its plane (sections shrink upward on a part without
//! undercut, the only kind roughed from sections, and the envelope's islands at a level
//! hold everything above it by construction), and P0 keeps the tool radius from them.
//! The check is made against what the level above really cleared, not against this
//! level's free area, so it does not rest on the free area shrinking downward (which
//! overhangs or the envelope's grid could break). Under the stock top, the first level's
//! own P0 is used: nothing of the stock stands above the top, and the part above the top
//! lies inside that level's islands. The entries go down to the floor above (through air
//! where the level above cleared over the entry, which on a part without undercut is
//! everywhere this level's P0 reaches; elsewhere the descent cuts what stands there at
//! the plunge feed, as every entry did before) and from there into the material by the
//! pocket's helix or ramp (they used to plunge the whole step-down).
//! `rough3d_safe_links` plans the old way, for comparison.
//!
//! A section is all a cutter at that level meets only when the part is a closed solid and
//! no face looks down above the floor (no undercut). Any other mesh — open, non-manifold,
//! several shells or touching bodies, turned faces, undercuts — is roughed from its upper
//! envelope instead (`Envelope` below: drop-cutter heights on a grid, marked per level),
//! which is all a 3-axis cutter meets; the plan carries one warning naming the defects.
//! A level whose section cannot be grown (walls that touch) is taken from the envelope too.
//! A rough that would clear nothing is refused in a sentence, never written empty.

use super::dropcutter::{Cutter, DropCutter};
use super::envelope::{grid_step, HeightField};
use super::slice::{flat_heights, slice_at};
use super::{Mesh, MeshError, V3};
use crate::geom::{Point, Polyline, Region, Shape};
use crate::offset::{offset_shape, Join, OffsetError, OffsetOptions};
use crate::ops::pocket::{pocket_level, Above};
use crate::ops::{pass_depths, pocket, Cutting, OpError, PocketParams, Stepover};
use crate::toolpath::{Move, Tool, Toolpath, P3};
use serde::{Deserialize, Serialize};

/// Everything a z-level rough needs besides the mesh.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Rough3dParams {
    /// The roughing cutter (flat end).
    pub tool: Tool,
    /// The most each level goes down from the one above, mm.
    pub stepdown: f64,
    /// Distance between neighbouring pocket passes within a level.
    pub stepover: Stepover,
    /// Material left on the part for finishing, mm (0 or more).
    pub stock_allowance: f64,
    /// The stock top, Z in the mesh's frame (None: the mesh's highest Z).
    #[serde(default)]
    pub stock_top: Option<f64>,
    /// The lowest level, Z (None: the mesh's lowest Z).
    #[serde(default)]
    pub floor: Option<f64>,
    /// How far the stock reaches beyond the part's plan-view extents, mm.
    #[serde(default)]
    pub stock_margin: f64,
    /// Cutting feed, mm/min.
    pub feed: f64,
    /// Plunge feed, mm/min.
    pub plunge_feed: f64,
    /// Height of rapids above the stock top, mm.
    pub safe_z: f64,
    /// Climb milling (true) or conventional.
    pub climb: bool,
    /// Spindle speed, rpm (0 leaves the spindle alone).
    pub spindle_rpm: f64,
    /// Geometric tolerance (mesh offset, slices, pocket), mm.
    pub tolerance: f64,
}

impl Default for Rough3dParams {
    fn default() -> Self {
        Rough3dParams {
            tool: Tool::flat(6.0),
            stepdown: 2.0,
            stepover: Stepover::Percent(40.0),
            stock_allowance: 0.3,
            stock_top: None,
            floor: None,
            stock_margin: 0.0,
            feed: 1000.0,
            plunge_feed: 300.0,
            safe_z: 5.0,
            climb: true,
            spindle_rpm: 12000.0,
            tolerance: 0.01,
        }
    }
}

impl Rough3dParams {
    fn check(&self) -> Result<(), MeshError> {
        let bad = |what: &str, v: f64| {
            MeshError::BadParam(format!("{what} must be a positive number, got {v}"))
        };
        for (v, what) in [
            (self.tool.diameter, "the tool diameter"),
            (self.stepdown, "the step-down"),
            (self.feed, "the feed"),
            (self.plunge_feed, "the plunge feed"),
            (self.safe_z, "the safe Z"),
            (self.tolerance, "the tolerance"),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(what, v));
            }
        }
        for (v, what) in [
            (self.stock_allowance, "the stock allowance"),
            (self.stock_margin, "the stock margin"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(MeshError::BadParam(format!(
                    "{what} must be 0 or more, got {v}"
                )));
            }
        }
        Ok(())
    }
}

/// The most grid points of the upper envelope a rough samples (a coarser grid than the
/// tolerance where the part is large; the comment at the path's start names the step).
pub const ENVELOPE_POINTS: usize = 1_000_000;

/// Plans a z-level rough of the mesh in its own frame: from its sections where it is a
/// closed solid with no undercut above the floor, else from its upper envelope (any
/// triangle soup), with one warning naming what kept it from being a solid.
pub fn rough3d(mesh: &Mesh, p: &Rough3dParams) -> Result<Toolpath, MeshError> {
    rough(mesh, p, true)
}

/// The rough as it was planned before links at depth: every level starts and ends at the
/// safe height, and so does every link that is not the pocket's short hop at depth (for
/// comparison: retract counts, machine time).
pub fn rough3d_safe_links(mesh: &Mesh, p: &Rough3dParams) -> Result<Toolpath, MeshError> {
    rough(mesh, p, false)
}

fn rough(mesh: &Mesh, p: &Rough3dParams, links: bool) -> Result<Toolpath, MeshError> {
    p.check()?;
    mesh.check_finite()?;
    let (lo, hi) = mesh.bounds().ok_or_else(|| MeshError::Empty {
        name: mesh.name.clone(),
    })?;
    let top = p.stock_top.unwrap_or(hi.z);
    let floor = p.floor.unwrap_or(lo.z);
    if !(top.is_finite() && floor.is_finite()) || floor >= top {
        return Err(MeshError::BadParam(format!(
            "the floor Z {floor} must lie below the stock top Z {top}"
        )));
    }
    let mut warnings = Vec::new();
    // the exact way needs a closed solid with nothing looking down above the floor
    let solid = match mesh.solid() {
        Ok((solid, _)) => match undercut(&solid, floor, p.tolerance) {
            None => Some(solid),
            Some((f, z)) => {
                warnings.push(format!(
                    "{}: face {f} looks down at Z {z:.4} (an undercut): roughed from its upper envelope, which leaves the material under it",
                    mesh.name
                ));
                None
            }
        },
        Err(_) => {
            let why = mesh
                .report()
                .defects()
                .unwrap_or_else(|| "not a closed solid".into());
            warnings.push(format!(
                "{} is {why}: roughed from its upper envelope",
                mesh.name
            ));
            None
        }
    };
    let a = p.stock_allowance;
    let r = p.tool.radius();
    let m = p.stock_margin + p.stock_allowance;
    let envelope = Envelope::new(mesh, lo, hi, a, p.tolerance);
    // the stock in plan, grown by the tool radius (and a hair) so the tool runs off it,
    // and past every island the envelope can give
    let g = (m + r + p.tolerance).max(envelope.reach + p.tolerance);
    let outline = Polyline::rect(
        Point::new(lo.x - g, lo.y - g),
        Point::new(hi.x + g, hi.y + g),
    );
    let mut levels: Vec<f64> = pass_depths(top - floor, p.stepdown)
        .into_iter()
        .map(|d| top + d)
        .collect();
    // a level on each flat of the part, the allowance above it, between the top and the floor
    // (a soup's faces may face either way: its flats are those of either side)
    let flats = match &solid {
        Some(s) => flat_heights(s),
        None => [flat_heights(mesh), flat_heights(&mesh.flipped())].concat(),
    };
    for z in flats.into_iter().map(|z| z + a) {
        if z < top - p.tolerance && z > floor + p.tolerance {
            levels.push(z);
        }
    }
    levels.sort_by(|a, b| b.total_cmp(a));
    levels.dedup_by(|a, b| (*a - *b).abs() <= p.tolerance);
    let safe = top + p.safe_z;

    let mut tp = Toolpath::new("rough3d");
    tp.tool = Some(p.tool);
    tp.source = mesh.name.clone();
    tp.push(Move::Comment {
        text: format!(
            "rough3d: flat d{} from Z {top} to Z {floor}, step-down {}, allowance {}",
            p.tool.diameter, p.stepdown, p.stock_allowance
        ),
    });
    if p.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: p.spindle_rpm });
    }
    tp.push(Move::Rapid {
        to: P3::new(lo.x - g, lo.y - g, safe),
    });
    let mut from_envelope = 0usize;
    // links at depth: the P0 of the last level cut and its Z, and where the tool stands
    let mut prev: Option<(Vec<Region>, f64)> = None;
    let mut at: Option<P3> = None;
    for &z in &levels {
        let mut paths = vec![outline.clone()];
        let exact = match &solid {
            Some(s) => section(s, (z - a).max(lo.z), a, p.tolerance).ok(),
            None => None,
        };
        match exact {
            Some(cut) => paths.extend(cut.paths),
            None => {
                from_envelope += 1;
                paths.extend(envelope.islands(z - a));
            }
        }
        let shape = Shape::new(paths);
        // one pass at the level (depth 0 below a stock top at Z = z); the pocket's other
        // settings (its entries among them) keep their defaults
        #[allow(clippy::needless_update)]
        let level = PocketParams {
            cut: Cutting {
                tool: p.tool,
                depth: 0.0,
                stepdown: p.stepdown,
                feed: p.feed,
                plunge_feed: p.plunge_feed,
                safe_z: safe - z,
                climb: p.climb,
                spindle_rpm: 0.0,
                tolerance: p.tolerance,
                ..Cutting::default()
            },
            stepover: p.stepover,
            ..PocketParams::default()
        };
        let planned = if links {
            let above = Above {
                height: prev.as_ref().map_or(top, |(_, zp)| *zp) - z,
                cleared: prev.as_ref().map(|(c, _)| c.clone()),
                from: at.map(|e| P3::new(e.x, e.y, e.z - z)),
            };
            pocket_level(&shape, &level, &above).map(|(t, p0)| {
                prev = Some((p0, z));
                t
            })
        } else {
            pocket(&shape, &level)
        };
        let cut = match planned {
            Ok(t) => t,
            // the part fills the stock at this level: nothing to clear
            Err(OpError::Empty(_)) => continue,
            Err(e) => {
                return Err(MeshError::BadParam(format!(
                    "{}: the level at Z {z} cannot be cleared: {e}",
                    mesh.name
                )))
            }
        };
        for mv in cut.moves {
            tp.push(match mv {
                Move::Rapid { to } => Move::Rapid {
                    to: P3::new(to.x, to.y, to.z + z),
                },
                Move::Linear { to, feed } => Move::Linear {
                    to: P3::new(to.x, to.y, to.z + z),
                    feed,
                },
                Move::Arc {
                    to,
                    center,
                    ccw,
                    feed,
                } => Move::Arc {
                    to: P3::new(to.x, to.y, to.z + z),
                    center,
                    ccw,
                    feed,
                },
                other => other,
            });
        }
        at = links.then_some(tp_at(&tp)).flatten();
    }
    if let Some(e) = at.filter(|e| e.z < safe) {
        tp.push(Move::Rapid {
            to: P3::new(e.x, e.y, safe),
        });
    }
    if p.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: 0.0 });
    }
    if solid.is_some() && from_envelope > 0 {
        warnings.push(format!(
            "{}: {from_envelope} of {} levels were roughed from the upper envelope (their sections could not be grown by the allowance)",
            mesh.name,
            levels.len()
        ));
    }
    if from_envelope > 0 {
        tp.moves.insert(
            1,
            Move::Comment {
                text: format!(
                    "upper envelope on a {:.4} mm grid: up to {:.4} mm more than the allowance is left",
                    envelope.h,
                    envelope.h * (1.0 + std::f64::consts::SQRT_2)
                ),
            },
        );
    }
    let cuts = tp
        .moves
        .iter()
        .any(|mv| matches!(mv, Move::Linear { .. } | Move::Arc { .. }));
    if !cuts {
        return Err(nothing_to_cut(mesh, p, top, floor, hi.z));
    }
    tp.warnings.extend(warnings);
    Ok(tp)
}

/// Where the tool path leaves the tool: the end of its last motion.
fn tp_at(tp: &Toolpath) -> Option<P3> {
    tp.moves.iter().rev().find_map(|mv| match mv {
        Move::Rapid { to } | Move::Linear { to, .. } | Move::Arc { to, .. } => Some(*to),
        _ => None,
    })
}

/// Why a rough that clears nothing is refused: the stock is the part itself, or (a
/// planner fault) the stock holds material above the part and still nothing was cut.
fn nothing_to_cut(
    mesh: &Mesh,
    p: &Rough3dParams,
    top: f64,
    floor: f64,
    part_top: f64,
) -> MeshError {
    if p.stock_margin <= p.tolerance && top <= part_top + p.tolerance {
        MeshError::BadParam(format!(
            "{}: nothing to rough: the stock is the part's own plan-view box from Z {top} down to Z {floor} (no stock margin), and a d{} cutter finds no material in it to clear; give a stock margin (--stock-margin) or a stock top above Z {part_top}",
            mesh.name, p.tool.diameter
        ))
    } else {
        MeshError::BadParam(format!(
            "{}: the rough would cut nothing, though the stock holds material beside or above the part (margin {} mm, top Z {top}): refused rather than sent empty",
            mesh.name, p.stock_margin
        ))
    }
}

/// The part's upper envelope for roughing: a flat cutter of radius a + h·√2 dropped on a
/// grid of step h. At level z every point whose height is at or above z − a is marked,
/// and the loops round the marked points (edges cut at their middles) hold every cell
/// whose four corners are marked. A point of the part above z − a lies within a of the
/// grid points within h·√2 of it, so all four corners of its cell are marked: the
/// islands hold the part's shadow above z − a grown by a, and a cutter kept out of them
/// stands at least a from the part, on slopes and flats alike (and at most h·(1 + √2)
/// farther than a).
struct Envelope<'m> {
    field: std::sync::OnceLock<HeightField>,
    mesh: &'m Mesh,
    area: [f64; 4],
    h: f64,
    radius: f64,
    floor: f64,
    /// How far beyond the part's plan-view box an island can reach, mm.
    reach: f64,
}

impl<'m> Envelope<'m> {
    fn new(mesh: &'m Mesh, lo: V3, hi: V3, a: f64, tol: f64) -> Envelope<'m> {
        let guess = a + 2.5 * tol;
        let h = grid_step(
            hi.x - lo.x + 2.0 * guess,
            hi.y - lo.y + 2.0 * guess,
            tol,
            ENVELOPE_POINTS,
        );
        let radius = a + h * std::f64::consts::SQRT_2;
        let pad = radius + h;
        Envelope {
            field: std::sync::OnceLock::new(),
            mesh,
            area: [lo.x - pad, lo.y - pad, hi.x + pad, hi.y + pad],
            h,
            radius,
            floor: lo.z - 1.0,
            reach: radius + h,
        }
    }

    /// The islands at a level whose tool keeps off the part above `z` (= level − a).
    fn islands(&self, z: f64) -> Vec<Polyline> {
        let field = self.field.get_or_init(|| {
            let dc = DropCutter::new(self.mesh, Cutter::flat(2.0 * self.radius))
                .expect("the mesh and the cutter were checked");
            HeightField::new(&dc, self.area, self.h, self.floor)
        });
        field.contours(|hz| hz >= z - 1e-9, |a, b| a.lerp(b, 0.5))
    }
}

/// The part's section just above `z`, grown by `allowance` in the plane.
///
/// A level that falls exactly where two walls meet (the bottom of a V groove between two
/// blocks, on the plate's top) slices them into loops that share an edge, which the offset
/// refuses as crossing; just above it they part. So such a level is sliced again a tenth,
/// then half, of the tolerance higher (the section "just above" it, as this function
/// promises); loops that still cross there are refused by name.
fn section(solid: &Mesh, z: f64, allowance: f64, tol: f64) -> Result<Shape, MeshError> {
    let opts = OffsetOptions {
        join: Join::Round,
        tolerance: tol,
        ..OffsetOptions::default()
    };
    let mut first_error = None;
    for lift in [0.0, 0.1 * tol, 0.5 * tol] {
        let cut = Shape::new(slice_at(solid, z + lift)?);
        if allowance <= 0.0 || cut.paths.is_empty() {
            return Ok(cut);
        }
        match offset_shape(&cut, allowance, &opts) {
            Ok(grown) => return Ok(grown),
            Err(e @ OffsetError::SelfIntersecting { .. }) => {
                first_error.get_or_insert(e);
            }
            Err(e) => {
                first_error = Some(e);
                break;
            }
        }
    }
    let e = first_error.expect("a failed try leaves its error");
    Err(MeshError::BadParam(format!(
        "{}: the section at Z {z} cannot be grown by the allowance: {e}",
        solid.name
    )))
}

/// The first face that looks down above the floor (an undercut a 3-axis rough by slices
/// would cut under), with its highest Z.
fn undercut(m: &Mesh, floor: f64, tol: f64) -> Option<(usize, f64)> {
    (0..m.faces.len()).find_map(|f| {
        let n = m.face_normal(f);
        let [a, b, c] = m.triangle(f);
        let zmax = a.z.max(b.z).max(c.z);
        (n.z < -1e-6 && zmax > floor + tol).then_some((f, zmax))
    })
}
