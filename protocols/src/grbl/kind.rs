//! The `grbl` machine kind: a GRBL 1.1 / grblHAL controller on a serial port (docs/grbl.md).

use super::resume::ResumeOptions;
use super::{GrblLink, GrblOptions};
use crate::gcode::{Dialect, GcodePost};
use crate::kind::{started, MachineKind, OpenLink};
use crate::link::{
    Control, DeviceState, Handed, Link, LinkError, LinkEvent, MachineStatus, Operation, Overrides,
    Reattach, ResumePlan, SendJournal, StreamEnd,
};
use crate::post::{PostError, PostFor};
use crate::program::Units;
use crate::serial::{check_port, default_baud, warn_missing_port};
use futures::future::BoxFuture;
use offset_core::Toolpath;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use tokio::sync::{mpsc, watch};

/// `link = "grbl"`.
pub struct GrblKind;

/// The keys of a `link = "grbl"` machine.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GrblSettings {
    /// The serial port, e.g. /dev/ttyUSB0.
    pub port: String,
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// Run every program through GRBL's check mode ($C) before cutting.
    #[serde(default)]
    pub check_first: bool,
    /// Unlock ($X) a machine an earlier job left in alarm before the next job starts.
    /// False by default: someone at the machine looks at an alarm first and clears it
    /// with `machlink unlock` or `machlink home`.
    #[serde(default)]
    pub auto_unlock: bool,
    /// How long a resume waits for the spindle to reach speed before the tool goes down, s.
    #[serde(default = "default_spindle_dwell")]
    pub spindle_dwell_s: f64,
    /// How long the controller may answer nothing (no `ok`, no status report) before the
    /// job pauses with its last acknowledged line and the link reconnects, s.
    #[serde(default = "default_silent_timeout")]
    pub silent_timeout_s: f64,
}

/// Twenty seconds: GRBL answers `?` within milliseconds, so this is a hung controller or a
/// dead cable, not a busy one; long enough that a slow `$` command is not cut short.
pub fn default_silent_timeout() -> f64 {
    20.0
}

/// Checks a silence limit: 2 s to an hour (below 2 s a controller busy writing its EEPROM
/// would be taken for a hung one).
pub fn check_silent_timeout(s: f64) -> Result<(), String> {
    if s.is_finite() && (2.0..=3600.0).contains(&s) {
        Ok(())
    } else {
        Err(format!(
            "silent_timeout_s must be 2 to 3600 seconds, got {s}"
        ))
    }
}

/// Two seconds: what a small router spindle takes to reach speed.
pub fn default_spindle_dwell() -> f64 {
    2.0
}

/// Checks a spindle dwell setting.
pub fn check_dwell(s: f64) -> Result<(), String> {
    if s.is_finite() && (0.0..=60.0).contains(&s) {
        Ok(())
    } else {
        Err(format!("spindle_dwell_s must be 0 to 60 seconds, got {s}"))
    }
}

/// The resume plan of a GRBL machine: retract, restore, spin up, rapid, plunge (docs/grbl.md).
pub fn grbl_resume_plan(
    lines: Units<'_, String>,
    from: usize,
    dwell: f64,
) -> Result<ResumePlan, String> {
    super::resume::plan(
        lines,
        from,
        &ResumeOptions {
            spindle_dwell_s: dwell,
        },
    )
}

/// How long a G-code program takes, s: cutting moves at their feed (capped at `max_feed`),
/// rapids at `rapid` mm/min, dwells as written. Acceleration is left out, so short moves
/// take a little longer than this says.
pub fn gcode_time(lines: Units<'_, String>, rapid: f64) -> Option<f64> {
    // line by line, so a long file's moves are never held
    let mut reader = crate::gcode_read::Reader::default();
    let (mut t, mut pos) = (0.0, offset_core::P3::default());
    for l in lines.iter(0..lines.len()) {
        if let Some(m) = reader.line(&l.ok()?).ok()? {
            let (dt, to) = crate::estimate::move_seconds(pos, &m, rapid);
            t += dt;
            pos = to;
        }
    }
    Some(t)
}

/// The rapid rate assumed for estimates, mm/min (GRBL's default `$110` is 500; routers run
/// 3000 to 10000).
pub const ESTIMATE_RAPID: f64 = crate::estimate::RAPID;

/// The G-code posts a GRBL controller runs.
pub fn grbl_posts() -> Vec<PostFor<String>> {
    vec![Arc::new(GcodePost(Dialect::Grbl))]
}

/// A GRBL machine's G-code file: its lines as they are (the intake has checked them).
pub fn gcode_file_units(lines: &[String]) -> Option<Result<Vec<String>, PostError>> {
    Some(Ok(lines.to_vec()))
}

impl MachineKind for GrblKind {
    type Settings = GrblSettings;
    type Unit = String;
    type Device = ();

    fn link(&self) -> &'static str {
        "grbl"
    }
    fn about(&self) -> &'static str {
        "a GRBL 1.1 / grblHAL controller on a serial port (character counting)"
    }
    fn posts(&self) -> Vec<PostFor<String>> {
        grbl_posts()
    }
    fn check(&self, s: &GrblSettings) -> Result<(), String> {
        check_port(&s.port, s.baud)?;
        check_dwell(s.spindle_dwell_s)?;
        check_silent_timeout(s.silent_timeout_s)
    }
    fn gcode_units(
        &self,
        lines: &[String],
        _moves: &Toolpath,
    ) -> Option<Result<Vec<String>, PostError>> {
        gcode_file_units(lines)
    }
    fn gcode_lines_are_units(&self) -> bool {
        true
    }
    fn gcode_dialect(&self) -> Option<Dialect> {
        Some(Dialect::Grbl)
    }
    fn start(&self, machine: &str, s: &GrblSettings) -> BoxFuture<'static, std::io::Result<()>> {
        warn_missing_port(machine, &s.port);
        started(())
    }
    fn open(&self, _machine: &str, s: &GrblSettings, _device: &()) -> OpenLink<String> {
        let opts = GrblOptions {
            baud: s.baud,
            check_first: s.check_first,
            resume: ResumeOptions {
                spindle_dwell_s: s.spindle_dwell_s,
            },
            ack_timeout: std::time::Duration::from_secs_f64(s.silent_timeout_s),
            ..Default::default()
        };
        open_machine(s.port.clone(), opts, s.auto_unlock)
    }
    fn resume_plan(
        &self,
        s: &GrblSettings,
        lines: Units<'_, String>,
        from: usize,
    ) -> Result<ResumePlan, String> {
        grbl_resume_plan(lines, from, s.spindle_dwell_s)
    }
    fn estimate(&self, _s: &GrblSettings, lines: Units<'_, String>) -> Option<f64> {
        gcode_time(lines, ESTIMATE_RAPID)
    }
}

/// Opens a GRBL controller on `port` as a machine link.
pub fn open_machine(port: String, opts: GrblOptions, auto_unlock: bool) -> OpenLink<String> {
    Box::pin(async move {
        let link = GrblLink::open(&port, opts).await?;
        Ok(Box::new(GrblMachine { link, auto_unlock }) as Box<dyn Link<String>>)
    })
}

/// A GRBL link that, with `auto_unlock`, clears an alarm lock left by an earlier job (`$X`)
/// before streaming, and says so.
pub struct GrblMachine {
    pub link: GrblLink,
    pub auto_unlock: bool,
}

impl Link<String> for GrblMachine {
    fn stream<'a>(
        &'a mut self,
        lines: &'a [String],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        self.stream_units(lines.into(), from, events, control)
    }
    fn stream_units<'a>(
        &'a mut self,
        lines: Units<'a, String>,
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        Box::pin(async move {
            let status = self.link.query_status().await?;
            if let DeviceState::Alarm { .. } = status.device_state() {
                if !self.auto_unlock {
                    return Err(LinkError::Alarm {
                        code: None,
                        text: "the machine is in alarm from before this job: clear its cause, then `machlink unlock` (or `machlink home`) it, or set auto_unlock = true".into(),
                    });
                }
                self.link.send_setting("$X").await?;
                let _ = events.send(LinkEvent::Message(
                    "the machine was in alarm from an earlier job; unlocked it with $X".into(),
                ));
            }
            self.link.stream_units(lines, from, events, control).await
        })
    }
    fn inquire(&mut self) -> BoxFuture<'_, Result<MachineStatus, LinkError>> {
        self.link.inquire()
    }
    fn reattach<'a>(
        &'a mut self,
        lines: &'a [String],
        handed: Handed,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<Reattach, LinkError>> {
        self.link.reattach(lines, handed, events, control)
    }
    fn reattach_units<'a>(
        &'a mut self,
        lines: Units<'a, String>,
        handed: Handed,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<Reattach, LinkError>> {
        self.link.reattach_units(lines, handed, events, control)
    }
    fn operate<'a>(&'a mut self, op: &'a Operation) -> BoxFuture<'a, Result<String, LinkError>> {
        self.link.operate(op)
    }
    fn follow_overrides(&mut self, overrides: watch::Receiver<Overrides>) -> Result<(), LinkError> {
        self.link.follow_overrides(overrides)
    }
    fn keep_journal(&mut self, journal: Box<dyn SendJournal>) {
        self.link.keep_journal(journal)
    }
}
