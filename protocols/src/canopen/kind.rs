//! The `canopen` machine kind: CiA 402 servo drives on a CAN bus fed a set-point per axis
//! every SYNC (docs/canopen.md), its settings, and the `moves` post whose units — the Toolpath
//! IR's moves themselves — its machines run.

use super::adapter::{self, BusSpec};
use super::cia402::Mode;
use super::master::{Axis, CanopenLink, CanopenOptions, Pace};
use super::trajectory::AxisLimits;
use crate::kind::{started, Joined, MachineKind};
use crate::link::{Link, LinkError};
use crate::post::{Post, PostError, PostFor};
use crate::program::{Unit, Units};
use futures::future::BoxFuture;
use offset_core::{Move, Toolpath};
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::Duration;

/// A move of the Toolpath IR as a program unit (what CANopen machines acknowledge).
impl Unit for Move {
    fn describe(&self) -> String {
        let p = |t: &offset_core::P3| format!("X{:.3} Y{:.3} Z{:.3}", t.x, t.y, t.z);
        match self {
            Move::Rapid { to } => format!("rapid {}", p(to)),
            Move::Linear { to, feed } => format!("linear {} F{feed}", p(to)),
            Move::Arc {
                to,
                center,
                ccw,
                feed,
            } => format!(
                "arc {} {} about X{:.3} Y{:.3} F{feed}",
                if *ccw { "ccw" } else { "cw" },
                p(to),
                center.x,
                center.y
            ),
            Move::Dwell { seconds } => format!("dwell {seconds} s"),
            Move::Spindle { rpm } => format!("spindle {rpm} rpm"),
            Move::ToolChange { tool, name, .. } if !name.is_empty() => {
                format!("tool change T{tool} ({name})")
            }
            Move::ToolChange { tool, .. } => format!("tool change T{tool}"),
            Move::Drill { at, bottom, .. } => {
                format!("drill X{:.3} Y{:.3} to Z{bottom:.3}", at.x, at.y)
            }
            Move::ProbeToolLength { at, .. } => {
                format!("tool-length probe at X{:.3} Y{:.3}", at.x, at.y)
            }
            Move::Comment { text } => format!("({text})"),
            Move::Stop => "program stop".into(),
            Move::Stitch { to } => format!("stitch X{:.3} Y{:.3}", to.x, to.y),
            Move::Jump { to } => format!("jump X{:.3} Y{:.3}", to.x, to.y),
            Move::Trim => "trim".into(),
            Move::ColorChange => "color change".into(),
        }
    }
}

/// The `moves` post: the tool path's moves as they are, one JSON object per line in its file.
/// Sewing moves are refused (a drive does not sew); spindle, tool change, comment and program
/// stop are kept and passed over by the link; a dwell stops the path for its time.
#[derive(Clone, Copy, Debug, Default)]
pub struct MovesPost;

/// The moves of a tool path a CANopen machine can run, or the first it cannot, named.
pub fn machining_moves(tp: &Toolpath) -> Result<Vec<Move>, PostError> {
    // drilling cycles go as the rapids, lines and dwells they make
    let expanded = tp.expanded();
    let tp = &expanded;
    for (i, m) in tp.moves.iter().enumerate() {
        if matches!(
            m,
            Move::Stitch { .. } | Move::Jump { .. } | Move::Trim | Move::ColorChange
        ) {
            return Err(PostError::new(
                "moves",
                format!(
                    "move {i} ({}) is a sewing move; a CANopen machine runs rapids, lines, arcs and dwells",
                    m.describe()
                ),
            ));
        }
    }
    Ok(tp.moves.clone())
}

impl Post for MovesPost {
    type Unit = Move;
    fn name(&self) -> &'static str {
        "moves"
    }
    fn about(&self) -> &'static str {
        "the tool path's moves as they are, one JSON object per line (CANopen drives)"
    }
    fn extension(&self) -> &'static str {
        "jsonl"
    }
    fn units(&self, tp: &Toolpath) -> Result<Vec<Move>, PostError> {
        machining_moves(tp)
    }
    fn file(&self, units: &[Move], _label: &str) -> Result<Vec<u8>, PostError> {
        let mut out = Vec::new();
        for m in units {
            serde_json::to_writer(&mut out, m).map_err(|e| PostError::new("moves", e))?;
            out.push(b'\n');
        }
        Ok(out)
    }
}

/// The posts a CANopen machine runs.
pub fn moves_posts() -> Vec<PostFor<Move>> {
    vec![Arc::new(MovesPost)]
}

/// `link = "canopen"`'s own key.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusSettings {
    /// `socketcan:IFACE` or `slcan:PORT[@BITRATE]`.
    pub bus: String,
}

/// One axis in the config.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisSettings {
    /// "x", "y" or "z".
    pub axis: String,
    /// The drive's node id, 1 to 127.
    pub node: u8,
    /// Position counts per millimetre.
    pub counts_per_mm: f64,
    /// 1, or −1 where the drive counts against the machine's axis.
    #[serde(default = "one")]
    pub sign: i8,
    /// mm/s.
    pub max_velocity: f64,
    /// mm/s².
    pub max_acceleration: f64,
    /// mm/s³.
    pub max_jerk: f64,
}

fn one() -> i8 {
    1
}

/// The keys every CANopen machine takes, real or simulated.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriveSettings {
    /// "ip" (interpolated position, default) or "csp" (cyclic synchronous position).
    #[serde(default)]
    pub mode: Mode,
    /// The SYNC period, ms (1 to 255).
    #[serde(default = "default_period")]
    pub period_ms: u32,
    pub axes: Vec<AxisSettings>,
    /// The heartbeat time written to every drive, ms.
    #[serde(default = "default_heartbeat")]
    pub heartbeat_ms: u32,
    /// A drive silent for longer than this stops the job, ms.
    #[serde(default = "default_heartbeat_timeout")]
    pub heartbeat_timeout_ms: u32,
    /// How long an SDO answer may take, ms.
    #[serde(default = "default_sdo_timeout")]
    pub sdo_timeout_ms: u32,
    /// How long one CiA 402 power state transition may take, ms.
    #[serde(default = "default_state_timeout")]
    pub state_timeout_ms: u32,
    /// How long after a SYNC a drive's position report may come, ms.
    #[serde(default = "default_report_timeout")]
    pub report_timeout_ms: u32,
    /// Written to 0x6065 (counts) when given; else the drive's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub following_error_window: Option<u32>,
}

fn default_period() -> u32 {
    2
}
fn default_heartbeat() -> u32 {
    100
}
fn default_heartbeat_timeout() -> u32 {
    500
}
fn default_sdo_timeout() -> u32 {
    300
}
fn default_state_timeout() -> u32 {
    500
}
fn default_report_timeout() -> u32 {
    200
}

/// The settings of a `link = "canopen"` machine.
pub type CanopenSettings = Joined<BusSettings, DriveSettings>;

fn positive(v: f64, what: &str) -> Result<(), String> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(format!("{what} must be a positive number, got {v}"))
    }
}

impl DriveSettings {
    /// Checks what serde cannot; the sentence names the axis and key.
    pub fn check(&self) -> Result<(), String> {
        if self.axes.is_empty() {
            return Err(
                "axes must name at least one axis, e.g. axes = [{ axis = \"x\", node = 1, … }]"
                    .into(),
            );
        }
        if !(1..=255).contains(&self.period_ms) {
            return Err(format!(
                "period_ms must be 1 to 255, got {}",
                self.period_ms
            ));
        }
        if self.heartbeat_ms == 0 || self.heartbeat_ms > 65_535 {
            return Err(format!(
                "heartbeat_ms must be 1 to 65535, got {}",
                self.heartbeat_ms
            ));
        }
        if self.heartbeat_timeout_ms <= self.heartbeat_ms {
            return Err(format!(
                "heartbeat_timeout_ms ({}) must be longer than heartbeat_ms ({})",
                self.heartbeat_timeout_ms, self.heartbeat_ms
            ));
        }
        for (what, v) in [
            ("sdo_timeout_ms", self.sdo_timeout_ms),
            ("state_timeout_ms", self.state_timeout_ms),
            ("report_timeout_ms", self.report_timeout_ms),
        ] {
            if v == 0 {
                return Err(format!("{what} must be above 0"));
            }
        }
        let mut seen_axes = Vec::new();
        let mut seen_nodes = Vec::new();
        for (i, a) in self.axes.iter().enumerate() {
            let at = format!("axes[{i}] (axis \"{}\")", a.axis);
            if !["x", "y", "z"].contains(&a.axis.as_str()) {
                return Err(format!(
                    "axes[{i}]: axis must be \"x\", \"y\" or \"z\", not \"{}\"",
                    a.axis
                ));
            }
            if seen_axes.contains(&a.axis) {
                return Err(format!("{at}: axis \"{}\" is given twice", a.axis));
            }
            seen_axes.push(a.axis.clone());
            if !(1..=127).contains(&a.node) {
                return Err(format!("{at}: node must be 1 to 127, got {}", a.node));
            }
            if seen_nodes.contains(&a.node) {
                return Err(format!("{at}: node {} drives another axis too", a.node));
            }
            seen_nodes.push(a.node);
            if a.sign != 1 && a.sign != -1 {
                return Err(format!("{at}: sign must be 1 or -1, got {}", a.sign));
            }
            positive(a.counts_per_mm, &format!("{at}: counts_per_mm"))?;
            positive(a.max_velocity, &format!("{at}: max_velocity"))?;
            positive(a.max_acceleration, &format!("{at}: max_acceleration"))?;
            positive(a.max_jerk, &format!("{at}: max_jerk"))?;
        }
        Ok(())
    }

    /// The master's options (real-time pace).
    pub fn options(&self) -> CanopenOptions {
        let axes = self
            .axes
            .iter()
            .map(|a| Axis {
                axis: match a.axis.as_str() {
                    "x" => 0,
                    "y" => 1,
                    _ => 2,
                },
                node: a.node,
                counts_per_mm: a.counts_per_mm,
                sign: a.sign as f64,
                limits: AxisLimits {
                    velocity: a.max_velocity,
                    acceleration: a.max_acceleration,
                    jerk: a.max_jerk,
                },
            })
            .collect();
        let ms = |v: u32| Duration::from_millis(v as u64);
        CanopenOptions {
            mode: self.mode,
            period: ms(self.period_ms),
            pace: Pace::RealTime { scale: 1.0 },
            heartbeat: ms(self.heartbeat_ms),
            heartbeat_timeout: ms(self.heartbeat_timeout_ms),
            sdo_timeout: ms(self.sdo_timeout_ms),
            state_timeout: ms(self.state_timeout_ms),
            report_timeout: ms(self.report_timeout_ms),
            following_error_window: self.following_error_window,
            ..CanopenOptions::new(axes)
        }
    }
}

/// Opens a CANopen link on the bus `spec` names.
pub fn open_canopen(
    spec: BusSpec,
    opts: CanopenOptions,
) -> BoxFuture<'static, Result<Box<dyn Link<Move>>, LinkError>> {
    Box::pin(async move {
        let bus = adapter::open(&spec).await?;
        Ok(Box::new(CanopenLink::new(bus, opts)) as Box<dyn Link<Move>>)
    })
}

/// A G-code file for a CANopen machine: the moves it reads as.
pub fn gcode_file_moves(moves: &Toolpath) -> Option<Result<Vec<Move>, PostError>> {
    Some(machining_moves(moves))
}

/// `link = "canopen"`.
pub struct CanopenKind;

impl MachineKind for CanopenKind {
    type Settings = CanopenSettings;
    type Unit = Move;
    type Device = ();

    fn link(&self) -> &'static str {
        "canopen"
    }
    fn about(&self) -> &'static str {
        "CiA 402 servo drives on a CAN bus (socketcan or SLCAN), a set-point per axis every SYNC"
    }
    fn keys(&self) -> Vec<&'static str> {
        CanopenSettings::keys()
    }
    fn estimate(&self, _s: &CanopenSettings, moves: Units<'_, Move>) -> Option<f64> {
        Some(crate::estimate::moves_seconds(
            &moves.to_vec().ok()?,
            crate::estimate::RAPID,
        ))
    }
    fn posts(&self) -> Vec<PostFor<Move>> {
        moves_posts()
    }
    fn check(&self, s: &CanopenSettings) -> Result<(), String> {
        s.own.bus.parse::<BusSpec>()?;
        s.common.check()
    }
    fn gcode_units(
        &self,
        _lines: &[String],
        moves: &Toolpath,
    ) -> Option<Result<Vec<Move>, PostError>> {
        gcode_file_moves(moves)
    }
    fn gcode_runs_as_moves(&self) -> bool {
        true
    }
    fn start(&self, machine: &str, s: &CanopenSettings) -> BoxFuture<'static, std::io::Result<()>> {
        if let Ok(BusSpec::Slcan { port, .. }) = s.own.bus.parse::<BusSpec>() {
            crate::serial::warn_missing_port(machine, &port);
        }
        started(())
    }
    fn open(
        &self,
        _machine: &str,
        s: &CanopenSettings,
        _device: &(),
    ) -> BoxFuture<'static, Result<Box<dyn Link<Move>>, LinkError>> {
        match s.own.bus.parse::<BusSpec>() {
            Ok(spec) => open_canopen(spec, s.common.options()),
            Err(e) => Box::pin(async move { Err(LinkError::Protocol(e)) }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kind::Registry;

    fn table() -> serde_json::Value {
        serde_json::json!({
            "bus": "slcan:/dev/ttyACM0@500000",
            "mode": "csp",
            "axes": [
                { "axis": "x", "node": 1, "counts_per_mm": 1000.0, "max_velocity": 100.0,
                  "max_acceleration": 1000.0, "max_jerk": 20000.0 },
                { "axis": "y", "node": 2, "counts_per_mm": 1000.0, "sign": -1, "max_velocity": 100.0,
                  "max_acceleration": 1000.0, "max_jerk": 20000.0 }
            ]
        })
    }

    #[test]
    fn settings_parse_with_defaults_and_bad_values_are_named() {
        let mut r = Registry::new();
        crate::standard_kinds(&mut r);
        let k = r.kind("canopen").expect("registered");
        let s = k.settings(table()).unwrap();
        let typed = s.get::<CanopenSettings>().unwrap();
        assert_eq!(typed.common.mode, Mode::CyclicSynchronousPosition);
        assert_eq!(typed.common.period_ms, 2);
        assert_eq!(typed.common.options().axes[1].sign, -1.0);
        let mut bad = table();
        bad["axes"][1]["node"] = 1.into();
        let e = k.settings(bad).unwrap_err();
        assert!(e.contains("axes[1]") && e.contains("node 1"), "{e}");
        let mut bad = table();
        bad["axes"][0]["max_jerk"] = (-1.0).into();
        let e = k.settings(bad).unwrap_err();
        assert!(e.contains("max_jerk"), "{e}");
        let mut bad = table();
        bad["bus"] = "can0".into();
        assert!(k.settings(bad).unwrap_err().contains("socketcan:IFACE"));
        let mut bad = table();
        bad["mode"] = "pp".into();
        assert!(k.settings(bad).is_err());
        let mut bad = table();
        bad["speed"] = 3.into();
        assert!(k.settings(bad).unwrap_err().contains("unknown key `speed`"));
        assert!(r.post("moves").is_some());
    }

    #[test]
    fn the_moves_post_writes_json_lines_and_refuses_sewing() {
        let mut tp = Toolpath::new("t");
        tp.push(Move::Rapid {
            to: offset_core::P3::new(1.0, 2.0, 3.0),
        });
        tp.push(Move::Linear {
            to: offset_core::P3::new(4.0, 2.0, 3.0),
            feed: 600.0,
        });
        let units = MovesPost.units(&tp).unwrap();
        let file = String::from_utf8(MovesPost.file(&units, "job").unwrap()).unwrap();
        let back: Vec<Move> = file
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(back, tp.moves);
        tp.push(Move::Stitch {
            to: offset_core::Point::new(0.0, 0.0),
        });
        let e = MovesPost.units(&tp).unwrap_err();
        assert!(e.message.contains("move 2"), "{}", e.message);
    }
}
