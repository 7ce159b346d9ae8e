//! Operations: turn shapes into tool paths (profile, and later pocket, 3D) and stitch paths.

pub mod pocket;
pub mod profile;

pub use pocket::{pocket, pocket_with, PocketParams, Stepover};
pub use profile::{profile, ProfileParams, Side};

use crate::offset::OffsetError;

/// Why an operation could not plan a path.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OpError {
    #[error(transparent)]
    Offset(#[from] OffsetError),
    #[error("invalid parameter: {0}")]
    BadParam(String),
    #[error("the shape has nothing to cut: {0}")]
    Empty(String),
}

/// What every milling operation needs: the tool, the depths, the feeds and the heights.
/// Keys left out of a JSON job take the defaults below.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Cutting {
    pub tool: crate::toolpath::Tool,
    /// How far below the stock top (Z=0) the last pass cuts, mm (positive).
    pub depth: f64,
    /// The most each depth pass goes down, mm.
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
    /// Geometric tolerance of every approximation, mm.
    pub tolerance: f64,
}

impl Default for Cutting {
    fn default() -> Self {
        Cutting {
            tool: crate::toolpath::Tool::default(),
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

impl Cutting {
    /// Every value in range, or a `BadParam` error naming the first that is not.
    pub fn check(&self) -> Result<(), OpError> {
        positive(self.tool.diameter, "the tool diameter")?;
        positive(self.stepdown, "the step-down")?;
        positive(self.feed, "the feed")?;
        positive(self.plunge_feed, "the plunge feed")?;
        positive(self.tolerance, "the tolerance")?;
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

/// `Ok` when `v` is a positive finite number, else a `BadParam` error naming `what`.
pub(crate) fn positive(v: f64, what: &str) -> Result<(), OpError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(OpError::BadParam(format!(
            "{what} must be a positive number, got {v}"
        )))
    }
}

/// Depths of successive passes, from the first step down to `depth` (both positive mm below
/// the stock top, Z=0), returned as Z values (negative).
pub fn pass_depths(depth: f64, stepdown: f64) -> Vec<f64> {
    if depth <= 0.0 {
        return vec![0.0];
    }
    let n = (depth / stepdown).ceil().max(1.0) as usize;
    (1..=n).map(|i| -(depth * i as f64 / n as f64)).collect()
}
