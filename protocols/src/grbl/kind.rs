//! The `grbl` machine kind: a GRBL 1.1 / grblHAL controller on a serial port (docs/grbl.md).

use super::{GrblLink, GrblOptions};
use crate::gcode::{Dialect, GcodePost};
use crate::kind::{started, MachineKind, OpenLink};
use crate::link::{Control, DeviceState, Link, LinkError, LinkEvent, StreamEnd};
use crate::post::{PostError, PostFor};
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
    /// Say false where an alarm must be looked at by someone first.
    #[serde(default = "yes")]
    pub auto_unlock: bool,
}

fn yes() -> bool {
    true
}

/// 115200 baud, GRBL 1.1's default.
pub fn default_baud() -> u32 {
    115_200
}

/// The G-code posts a GRBL controller runs.
pub fn grbl_posts() -> Vec<PostFor<String>> {
    vec![Arc::new(GcodePost(Dialect::Grbl))]
}

/// A GRBL machine's G-code file: its lines as they are (the intake has checked them).
pub fn gcode_file_units(lines: &[String]) -> Option<Result<Vec<String>, PostError>> {
    Some(Ok(lines.to_vec()))
}

/// Warns of a serial port that is not there (yet): its jobs fail until it is.
pub fn warn_missing_port(machine: &str, port: &str) {
    if !std::path::Path::new(port).exists() {
        tracing::warn!(
            "machine `{machine}`: the port {port} does not exist (yet); its jobs fail until it does"
        );
    }
}

/// Checks a serial port setting and its speed.
pub fn check_port(port: &str, baud: u32) -> Result<(), String> {
    if port.trim().is_empty() {
        return Err("port must not be empty".into());
    }
    if baud == 0 {
        return Err("baud must be above 0".into());
    }
    Ok(())
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
        check_port(&s.port, s.baud)
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
    fn start(&self, machine: &str, s: &GrblSettings) -> BoxFuture<'static, std::io::Result<()>> {
        warn_missing_port(machine, &s.port);
        started(())
    }
    fn open(&self, _machine: &str, s: &GrblSettings, _device: &()) -> OpenLink<String> {
        let opts = GrblOptions {
            baud: s.baud,
            check_first: s.check_first,
            ..Default::default()
        };
        open_machine(s.port.clone(), opts, s.auto_unlock)
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
        Box::pin(async move {
            let status = self.link.query_status().await?;
            if let DeviceState::Alarm { .. } = status.device_state() {
                if !self.auto_unlock {
                    return Err(LinkError::Alarm {
                        code: None,
                        text: "the machine is in alarm from before this job: clear its cause, unlock it ($X) or set auto_unlock = true".into(),
                    });
                }
                self.link.send_setting("$X").await?;
                let _ = events.send(LinkEvent::Message(
                    "the machine was in alarm from an earlier job; unlocked it with $X".into(),
                ));
            }
            self.link.stream(lines, from, events, control).await
        })
    }
}
