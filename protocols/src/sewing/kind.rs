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
    /// How long the machine may answer nothing at all (no reply to a request, no STATUS)
    /// before the job pauses with its last acknowledged record and the link reconnects, s
    /// (2 to 3600).
    #[serde(default = "default_sewing_silent_timeout")]
    pub silent_timeout_s: f64,
}

/// The default of a sewing machine's `silent_timeout_s`: the link's 40 attempts of 150 ms.
pub fn default_sewing_silent_timeout() -> f64 {
    let t = SewingTiming::default();
    (t.reply_timeout * t.attempts).as_secs_f64()
}

/// The link's timing for a machine that may be silent `silent_timeout_s`: as many reply
/// timeouts as fit in it.
pub fn sewing_timing(silent_timeout_s: f64) -> SewingTiming {
    let t = SewingTiming::default();
    // (less a nanosecond's worth: 6 s / 150 ms is 40 attempts, not 41 by rounding)
    let attempts = (silent_timeout_s / t.reply_timeout.as_secs_f64() - 1e-6).ceil();
    SewingTiming {
        attempts: attempts.clamp(1.0, u32::MAX as f64) as u32,
        ..t
    }
}

/// Opens a pattern sewing machine on `port` as a machine link.
pub fn open_sewing(port: String, baud: u32) -> OpenLink<StitchRecord> {
    open_sewing_timed(port, baud, SewingTiming::default())
}

/// Opens a pattern sewing machine on `port` with the link's `timing`.
pub fn open_sewing_timed(port: String, baud: u32, timing: SewingTiming) -> OpenLink<StitchRecord> {
    Box::pin(async move {
        let link = SewingLink::open(&port, baud, timing)?;
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
        check_port(&s.port, s.baud)?;
        crate::grbl::kind::check_silent_timeout(s.silent_timeout_s)
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
        open_sewing_timed(s.port.clone(), s.baud, sewing_timing(s.silent_timeout_s))
    }
}

#[cfg(test)]
mod tests {
    use crate::kind::AnyKind;
    use serde_json::json;

    #[test]
    fn the_silence_key_of_sewing_and_modbus_machines_is_checked_and_sets_the_links_patience() {
        let sewing = super::SewingKind;
        let e = AnyKind::settings(
            &sewing,
            json!({ "port": "/dev/ttyUSB1", "silent_timeout_s": 1.0 }),
        )
        .unwrap_err();
        assert!(e.contains("silent_timeout_s must be 2 to 3600"), "{e}");
        let ok = AnyKind::settings(&sewing, json!({ "port": "/dev/ttyUSB1" })).unwrap();
        assert_eq!(
            ok.get::<super::SewingSettings>().unwrap().silent_timeout_s,
            6.0
        );
        assert_eq!(
            super::sewing_timing(6.0),
            super::SewingTiming::default(),
            "the default silence is the link's own 40 attempts"
        );
        let t = super::sewing_timing(30.0);
        let patience = t.reply_timeout * t.attempts;
        assert!(
            patience.as_secs_f64() >= 30.0 && patience.as_secs_f64() < 30.2,
            "30 s of silence allowed, the link waits {patience:?}"
        );

        let modbus = crate::modbus::ModbusTcpKind::default();
        let e = AnyKind::settings(
            &modbus,
            json!({ "host": "10.0.0.5", "silent_timeout_s": 7200 }),
        )
        .unwrap_err();
        assert!(e.contains("silent_timeout_s must be 2 to 3600"), "{e}");
        let ok = AnyKind::settings(
            &modbus,
            json!({ "host": "10.0.0.5", "silent_timeout_s": 12 }),
        );
        assert!(ok.is_ok(), "{ok:?}");
    }
}
