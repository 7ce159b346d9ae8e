//! Operations: turn shapes into tool paths (profile, pocket, adaptive clearing, drill) with entries that never plunge into material, and stitch paths; jobs of several of them.

pub mod adaptive;
pub mod drill;
pub mod entry;
pub mod job;
pub mod pocket;
pub mod profile;

pub use adaptive::{adaptive, AdaptiveParams};
pub use drill::{drill, Cycle, DrillParams, Hole};
pub use entry::Entry;
pub use job::{join, Step, StepFigures, Take};
pub use pocket::{pocket, pocket_safe_links, pocket_with, PocketParams, Stepover};
pub use profile::{profile, profile_safe_links, ProfileParams, Side};

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
    /// The simulation an operation plans by (feed control) could not run.
    #[error(transparent)]
    Simulation(#[from] crate::cutsim::SimError),
    #[error("path {path} reaches ({}, {}) mm, beyond the ±{} mm (10 km) a shape may span; check its units", at.x, at.y, crate::io::MAX_COORDINATE)]
    OutOfRange { path: usize, at: crate::geom::Point },
}

/// Refuses a shape that reaches beyond ±[`crate::io::MAX_COORDINATE`] mm, naming the first
/// path that does.
pub fn check_range(shape: &crate::geom::Shape) -> Result<(), OpError> {
    match shape.first_beyond(crate::io::MAX_COORDINATE) {
        None => Ok(()),
        Some((path, at)) => Err(OpError::OutOfRange { path, at }),
    }
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
    /// How the tool goes down into the material at the start of each pass: a helix where
    /// one fits (the default), else a ramp along the pass, else straight down with a
    /// warning in the tool path. Profiles have no room of their own for a helix and ramp.
    #[serde(default)]
    pub entry: Entry,
    /// The steepest a ramp or helix entry descends, degrees from the horizontal.
    #[serde(default = "default_ramp_angle")]
    pub ramp_angle: f64,
    /// Diameter of the circle the tool centre follows down a helix entry, mm; 0 for the
    /// tool diameter, shrunk down to half of it where a pass has no room for more.
    #[serde(default)]
    pub helix_diameter: f64,
    /// Closed profiles: go down from pass to pass in one unbroken helix along the loop
    /// (at most the step-down per lap, never steeper than the ramp angle), then once round
    /// at the bottom, instead of a ramp at each depth. Pockets ignore it; so do profiles
    /// with tabs (with a warning).
    #[serde(default)]
    pub spiral: bool,
}

/// The ramp angle when none is given: 3°, gentle enough for small end mills in steel.
pub const DEFAULT_RAMP_ANGLE: f64 = 3.0;

fn default_ramp_angle() -> f64 {
    DEFAULT_RAMP_ANGLE
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
            entry: Entry::default(),
            ramp_angle: DEFAULT_RAMP_ANGLE,
            helix_diameter: 0.0,
            spiral: false,
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
        if !(self.ramp_angle.is_finite() && self.ramp_angle > 0.0 && self.ramp_angle <= 90.0) {
            return Err(OpError::BadParam(format!(
                "the ramp angle must be more than 0° and at most 90°, got {}",
                self.ramp_angle
            )));
        }
        if !(self.helix_diameter.is_finite() && self.helix_diameter >= 0.0) {
            return Err(OpError::BadParam(format!(
                "the helix diameter must be 0 (the tool diameter) or more, got {}",
                self.helix_diameter
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entry_options_default_when_absent_and_round_trip() {
        // parameters written before entries existed still read, with the defaults
        let old = r#"{"cut":{"tool":{"number":1,"diameter":6.0,"kind":"flat_end"},"depth":2.0,"stepdown":1.0,"feed":800.0,"plunge_feed":300.0,"safe_z":5.0,"climb":true,"spindle_rpm":0.0},"stepover":{"percent":40.0}}"#;
        let p: PocketParams = serde_json::from_str(old).unwrap();
        assert_eq!(p.cut.entry, Entry::Helix);
        assert_eq!(p.cut.ramp_angle, DEFAULT_RAMP_ANGLE);
        assert_eq!((p.cut.helix_diameter, p.cut.spiral), (0.0, false));
        let mut q = ProfileParams::default();
        q.cut.entry = Entry::Ramp;
        q.cut.ramp_angle = 2.0;
        q.cut.spiral = true;
        let text = serde_json::to_string(&q).unwrap();
        assert!(text.contains(r#""entry":"ramp""#), "{text}");
        assert_eq!(serde_json::from_str::<ProfileParams>(&text).unwrap(), q);
    }

    #[test]
    fn entry_parameters_out_of_range_are_named() {
        let bad = |f: fn(&mut Cutting)| {
            let mut c = Cutting::default();
            f(&mut c);
            c.check().unwrap_err().to_string()
        };
        assert!(bad(|c| c.ramp_angle = 0.0).contains("ramp angle"));
        assert!(bad(|c| c.ramp_angle = 91.0).contains("ramp angle"));
        assert!(bad(|c| c.helix_diameter = -1.0).contains("helix diameter"));
    }
}
