//! Waterline finishing with a ball cutter: closed contours at constant tool-tip heights,
//! for the steep walls a raster leaves coarse.
//!
//! A ball's centre touching the part lies on the part's offset by the ball radius R, so the
//! waterline at tip height z is the section of that offset (multiple normals, within the
//! tolerance) at z + R. Levels run from the stock top down to the floor, no more than
//! `stepdown` apart; each contour is cut climb (clockwise round material, with an M3
//! spindle), entered from the safe height and left back up to it. Flat and bull cutters
//! are refused: their cutter-location surface is not an offset of the part.

use super::dropcutter::{Cutter, CutterShape};
use super::finish::{describe, tool_of};
use super::offset::{offset, MeshOffsetOptions};
use super::slice::slice_at;
use super::{Mesh, MeshError};
use crate::ops::pass_depths;
use crate::toolpath::{Move, Toolpath, P3};
use serde::{Deserialize, Serialize};

/// Everything a waterline finish needs besides the mesh.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WaterlineParams {
    /// A ball cutter.
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

/// Plans waterline contours of the closed mesh with a ball cutter, in the mesh's frame.
pub fn waterline3d(mesh: &Mesh, p: &WaterlineParams) -> Result<Toolpath, MeshError> {
    p.cutter.check()?;
    if p.cutter.shape != CutterShape::Ball {
        return Err(MeshError::BadParam(format!(
            "waterline contours are made for ball cutters only, not a {} cutter",
            describe(&p.cutter)
        )));
    }
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
    let r = p.cutter.radius();
    let grown = offset(
        mesh,
        r,
        &MeshOffsetOptions {
            tolerance: p.tolerance,
        },
    )?
    .mesh;
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
    let safe = top.max(hi.z) + p.safe_z;
    let mut tp = Toolpath::new("waterline3d");
    tp.tool = Some(tool_of(&p.cutter, p.tool_number));
    tp.source = mesh.name.clone();
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
    for d in pass_depths(top - floor, p.stepdown) {
        let z = top + d;
        for pl in slice_at(&grown, z + r)? {
            // slices run counter-clockwise round material; climb runs clockwise
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
    if p.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: 0.0 });
    }
    Ok(tp)
}
