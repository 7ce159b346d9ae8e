//! The `sewing` machine kind: a pattern sewing machine on a serial port (docs/sewing-link.md),
//! and the stitch posts (DST, JEF) whose records it sews.

use super::link::{SewingLink, SewingTiming};
use super::{dst, jef, records, RecordLimits, StitchRecord};
use crate::kind::{started, MachineKind, OpenLink};
use crate::link::Link;
use crate::post::{Post, PostError, PostFor};
use crate::program::Units;
use crate::serial::{check_port, default_baud, warn_missing_port};
use futures::future::BoxFuture;
use offset_core::Toolpath;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// The embroidery file format a stitch program is written as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StitchFormat {
    /// Tajima DST (steps of at most 12.1 mm).
    Dst,
    /// Janome JEF (steps of at most 12.7 mm).
    Jef,
}

/// A stitch post: units are stitch records within the format's step limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StitchPost(pub StitchFormat);

impl Post for StitchPost {
    type Unit = StitchRecord;
    fn name(&self) -> &'static str {
        match self.0 {
            StitchFormat::Dst => "dst",
            StitchFormat::Jef => "jef",
        }
    }
    fn about(&self) -> &'static str {
        match self.0 {
            StitchFormat::Dst => "stitches as a Tajima DST embroidery file (stitch operation)",
            StitchFormat::Jef => "stitches as a Janome JEF embroidery file (stitch operation)",
        }
    }
    fn extension(&self) -> &'static str {
        self.name()
    }
    fn units(&self, tp: &Toolpath) -> Result<Vec<StitchRecord>, PostError> {
        let limits = match self.0 {
            StitchFormat::Dst => RecordLimits::DST,
            StitchFormat::Jef => RecordLimits::JEF,
        };
        records(tp, limits).map_err(|e| PostError::new(self.name(), e))
    }
    fn file(&self, units: &[StitchRecord], label: &str) -> Result<Vec<u8>, PostError> {
        match self.0 {
            StitchFormat::Dst => dst::write(units, label),
            StitchFormat::Jef => jef::write(units, &Default::default()),
        }
        .map_err(|e| PostError::new(self.name(), e))
    }
}

/// The posts a pattern sewing machine sews: DST first, JEF.
pub fn stitch_posts() -> Vec<PostFor<StitchRecord>> {
    vec![
        Arc::new(StitchPost(StitchFormat::Dst)),
        Arc::new(StitchPost(StitchFormat::Jef)),
    ]
}

/// `link = "sewing"`.
pub struct SewingKind;

/// The keys of a `link = "sewing"` machine.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SewingSettings {
    /// The serial port, e.g. /dev/ttyUSB1.
    pub port: String,
    #[serde(default = "default_baud")]
    pub baud: u32,
}

/// Opens a pattern sewing machine on `port` as a machine link.
pub fn open_sewing(port: String, baud: u32) -> OpenLink<StitchRecord> {
    Box::pin(async move {
        let link = SewingLink::open(&port, baud, SewingTiming::default())?;
        Ok(Box::new(link) as Box<dyn Link<StitchRecord>>)
    })
}

impl MachineKind for SewingKind {
    type Settings = SewingSettings;
    type Unit = StitchRecord;
    type Device = ();

    fn link(&self) -> &'static str {
        "sewing"
    }
    fn about(&self) -> &'static str {
        "a pattern sewing machine on a serial port (CRC-checked pattern transfer)"
    }
    fn posts(&self) -> Vec<PostFor<StitchRecord>> {
        stitch_posts()
    }
    fn check(&self, s: &SewingSettings) -> Result<(), String> {
        check_port(&s.port, s.baud)
    }
    fn estimate(&self, _s: &SewingSettings, stitches: Units<'_, StitchRecord>) -> Option<f64> {
        Some(crate::estimate::stitches_seconds(
            stitches.len(),
            crate::estimate::SPM,
        ))
    }
    fn start(&self, machine: &str, s: &SewingSettings) -> BoxFuture<'static, std::io::Result<()>> {
        warn_missing_port(machine, &s.port);
        started(())
    }
    fn open(&self, _machine: &str, s: &SewingSettings, _device: &()) -> OpenLink<StitchRecord> {
        open_sewing(s.port.clone(), s.baud)
    }
}
