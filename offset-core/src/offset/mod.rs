//! The offset kernel: grow or shrink closed polylines and regions with islands, and offset
//! open polylines to one side, by pair-wise interference removal (Choi & Park 1999; Park 2001).

use crate::geom::{Point, Polyline, Region, Shape};
use serde::{Deserialize, Serialize};

/// How a convex corner of the offset is closed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Join {
    /// An exact arc about the corner (the true offset).
    #[default]
    Round,
    /// The two offset segments extended to meet, chamfered beyond the miter limit.
    Miter,
    /// A straight line across the corner.
    Chamfer,
}

/// Settings of one offset.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct OffsetOptions {
    pub join: Join,
    /// With `Join::Miter`: the longest miter, as a multiple of the distance, before it is chamfered.
    pub miter_limit: f64,
    /// One tolerance governs every approximation, in mm.
    pub tolerance: f64,
}

impl Default for OffsetOptions {
    fn default() -> Self {
        OffsetOptions {
            join: Join::Round,
            miter_limit: 4.0,
            tolerance: 1e-3,
        }
    }
}

/// Why an offset could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OffsetError {
    #[error("vertex {vertex} of path {path} is not a finite number")]
    NotFinite { path: usize, vertex: usize },
    #[error("the offset distance {0} is not a finite number")]
    BadDistance(f64),
    #[error("the tolerance {0} must be a positive finite number")]
    BadTolerance(f64),
    #[error("path {path} crosses itself near ({}, {})", at.x, at.y)]
    SelfIntersecting { path: usize, at: Point },
    #[error("the offset kernel is not built yet")]
    NotImplemented,
}

/// Offsets one polyline: a closed one grows (d > 0) or shrinks (d < 0) as a region with no
/// islands; an open one moves left (d > 0) or right (d < 0) of its direction of travel.
pub fn offset_polyline(
    _pl: &Polyline,
    _distance: f64,
    _opts: &OffsetOptions,
) -> Result<Vec<Polyline>, OffsetError> {
    Err(OffsetError::NotImplemented)
}

/// Offsets a region: d > 0 grows the outer and shrinks the islands, d < 0 the reverse. The
/// result may be several regions (the pocket split) or none (offset away).
pub fn offset_region(
    _region: &Region,
    _distance: f64,
    _opts: &OffsetOptions,
) -> Result<Vec<Region>, OffsetError> {
    Err(OffsetError::NotImplemented)
}

/// Offsets a whole shape: its closed paths as nested regions, its open paths to one side.
pub fn offset_shape(
    shape: &Shape,
    distance: f64,
    opts: &OffsetOptions,
) -> Result<Shape, OffsetError> {
    let mut out = Vec::new();
    for r in shape.regions() {
        for o in offset_region(&r, distance, opts)? {
            out.push(o.outer);
            out.extend(o.islands);
        }
    }
    for p in shape.open_paths() {
        out.extend(offset_polyline(p, distance, opts)?);
    }
    Ok(Shape::new(out))
}
