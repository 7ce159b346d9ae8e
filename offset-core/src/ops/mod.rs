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
