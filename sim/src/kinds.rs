//! The simulated machine kinds (`sim-grbl`, `sim-sewing`, `sim-modbus`, `sim-canopen` in
//! `crate::canopen::kind`): each starts its
//! simulator when the daemon starts and opens the real kind's link on it, so a config can
//! swap `link = "grbl"` for `link = "sim-grbl"` and nothing else changes.

use crate::grbl::{GrblSim, GrblSimConfig, GrblSimHandle};
use crate::modbus::{ModbusSim, SimConfig};
use crate::sewing::{spawn_on_pty, SewingSim, SewingSimConfig};
use futures::future::BoxFuture;
use machlink_protocols::gcode::Dialect;
use machlink_protocols::grbl::kind::{
    check_dwell, check_silent_timeout, default_silent_timeout, default_spindle_dwell,
    gcode_file_units, gcode_time, grbl_posts, grbl_resume_plan, open_machine, ESTIMATE_RAPID,
};
use machlink_protocols::grbl::resume::ResumeOptions;
use machlink_protocols::grbl::GrblOptions;
use machlink_protocols::kind::{MachineKind, OpenLink, Registry};
use machlink_protocols::modbus::kind::{gcode_file_blocks, modbus_posts, open_ring, RingSettings};
use machlink_protocols::modbus::{MotionBlock, Transport};
use machlink_protocols::post::{PostError, PostFor};
use machlink_protocols::sewing::kind::{open_sewing, stitch_posts};
use machlink_protocols::sewing::StitchRecord;
use machlink_protocols::{ResumePlan, Units};
use offset_core::Toolpath;
use serde::{Deserialize, Serialize};

/// Registers the simulated kinds.
pub fn register(registry: &mut Registry) {
    registry
        .add_kind(SimGrblKind)
        .add_kind(SimSewingKind)
        .add_kind(SimModbusKind)
        .add_kind(crate::canopen::kind::SimCanopenKind);
}

fn default_time_scale() -> f64 {
    1.0
}

fn positive(v: f64, what: &str) -> Result<(), String> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(format!("{what} must be a positive number, got {v}"))
    }
}

/// `link = "sim-grbl"`: a simulated GRBL 1.1 on a pty the daemon starts.
pub struct SimGrblKind;

/// The keys of a `link = "sim-grbl"` machine.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimGrblSettings {
    /// How many times faster than real time the simulated machine moves.
    #[serde(default = "default_time_scale")]
    pub time_scale: f64,
    /// Homing enabled: the machine starts locked until `machlink home` (or `unlock`).
    #[serde(default)]
    pub homing: bool,
    /// How long a resume waits for the spindle to reach speed, s.
    #[serde(default = "default_spindle_dwell")]
    pub spindle_dwell_s: f64,
    /// How long the controller may answer nothing before the job pauses, s (as for `grbl`).
    #[serde(default = "default_silent_timeout")]
    pub silent_timeout_s: f64,
}

impl MachineKind for SimGrblKind {
    type Settings = SimGrblSettings;
    type Unit = String;
    type Device = GrblSimHandle;

    fn link(&self) -> &'static str {
        "sim-grbl"
    }
    fn about(&self) -> &'static str {
        "a simulated GRBL 1.1 the daemon starts on a pseudo-terminal"
    }
    fn posts(&self) -> Vec<PostFor<String>> {
        grbl_posts()
    }
    fn check(&self, s: &SimGrblSettings) -> Result<(), String> {
        positive(s.time_scale, "time_scale")?;
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
    fn start(
        &self,
        _machine: &str,
        s: &SimGrblSettings,
    ) -> BoxFuture<'static, std::io::Result<GrblSimHandle>> {
        let cfg = GrblSimConfig {
            time_scale: s.time_scale,
            homing: s.homing,
            ..Default::default()
        };
        Box::pin(async move { GrblSim::spawn_pty(cfg) })
    }
    fn open(&self, _machine: &str, s: &SimGrblSettings, sim: &GrblSimHandle) -> OpenLink<String> {
        let port = sim.port().display().to_string();
        let opts = GrblOptions {
            resume: ResumeOptions {
                spindle_dwell_s: s.spindle_dwell_s,
            },
            ack_timeout: std::time::Duration::from_secs_f64(s.silent_timeout_s),
            ..Default::default()
        };
        // a simulator's alarm needs nobody to look at it first
        open_machine(port, opts, true)
    }
    fn resume_plan(
        &self,
        s: &SimGrblSettings,
        lines: Units<'_, String>,
        from: usize,
    ) -> Result<ResumePlan, String> {
        grbl_resume_plan(lines, from, s.spindle_dwell_s)
    }
    fn estimate(&self, s: &SimGrblSettings, lines: Units<'_, String>) -> Option<f64> {
        gcode_time(lines, ESTIMATE_RAPID).map(|t| t / s.time_scale)
    }
}

/// `link = "sim-sewing"`: a simulated pattern sewing machine on a pty the daemon starts
/// (`machlink-sim sewing` is the same machine from the command line).
pub struct SimSewingKind;

/// The keys of a `link = "sim-sewing"` machine.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimSewingSettings {
    /// How many times faster than real time the simulated machine sews.
    #[serde(default = "default_time_scale")]
    pub time_scale: f64,
    /// Stitches per minute.
    #[serde(default = "default_spm")]
    pub spm: u32,
    /// Probability per byte, each direction, of line noise (lost or corrupted bytes).
    #[serde(default)]
    pub noise: f64,
    /// The thread breaks before these records (0-based).
    #[serde(default)]
    pub thread_break_at: Vec<u32>,
    /// The power fails (the pattern is lost) before these records (0-based).
    #[serde(default)]
    pub power_loss_at: Vec<u32>,
}

fn default_spm() -> u32 {
    2500
}

impl MachineKind for SimSewingKind {
    type Settings = SimSewingSettings;
    type Unit = StitchRecord;
    type Device = SewingSim;

    fn link(&self) -> &'static str {
        "sim-sewing"
    }
    fn about(&self) -> &'static str {
        "a simulated pattern sewing machine the daemon starts on a pseudo-terminal"
    }
    fn posts(&self) -> Vec<PostFor<StitchRecord>> {
        stitch_posts()
    }
    fn estimate(&self, s: &SimSewingSettings, stitches: Units<'_, StitchRecord>) -> Option<f64> {
        let t = machlink_protocols::estimate::stitches_seconds(stitches.len(), s.spm as f64);
        Some(t / s.time_scale)
    }
    fn check(&self, s: &SimSewingSettings) -> Result<(), String> {
        positive(s.time_scale, "time_scale")?;
        if s.spm == 0 {
            return Err("spm must be above 0".into());
        }
        if !(s.noise.is_finite() && (0.0..=0.1).contains(&s.noise)) {
            return Err(format!("noise must be 0 to 0.1, got {}", s.noise));
        }
        Ok(())
    }
    fn start(
        &self,
        _machine: &str,
        s: &SimSewingSettings,
    ) -> BoxFuture<'static, std::io::Result<SewingSim>> {
        let cfg = SewingSimConfig {
            time_scale: s.time_scale,
            spm: s.spm,
            noise: s.noise,
            thread_break_at: s.thread_break_at.clone(),
            power_loss_at: s.power_loss_at.clone(),
            ..Default::default()
        };
        Box::pin(async move { spawn_on_pty(cfg) })
    }
    fn open(
        &self,
        _machine: &str,
        _s: &SimSewingSettings,
        sim: &SewingSim,
    ) -> OpenLink<StitchRecord> {
        open_sewing(sim.path.clone(), 115_200)
    }
}

/// `link = "sim-modbus"`: a simulated motion-block device the daemon serves on a loopback
/// TCP port of its own choosing.
pub struct SimModbusKind;

/// The keys of a `link = "sim-modbus"` machine.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimModbusSettings {
    /// How many times faster than real time the simulated device moves.
    #[serde(default = "default_time_scale")]
    pub time_scale: f64,
    /// Ring capacity in blocks.
    #[serde(default = "default_capacity")]
    pub capacity: u16,
}

fn default_capacity() -> u16 {
    64
}

impl MachineKind for SimModbusKind {
    type Settings = SimModbusSettings;
    type Unit = MotionBlock;
    type Device = ModbusSim;

    fn link(&self) -> &'static str {
        "sim-modbus"
    }
    fn about(&self) -> &'static str {
        "a simulated Modbus motion-block device the daemon serves on loopback TCP"
    }
    fn posts(&self) -> Vec<PostFor<MotionBlock>> {
        modbus_posts()
    }
    fn estimate(&self, s: &SimModbusSettings, blocks: Units<'_, MotionBlock>) -> Option<f64> {
        let t = machlink_protocols::estimate::blocks_seconds(
            &blocks.to_vec().ok()?,
            machlink_protocols::estimate::RAPID,
        );
        Some(t / s.time_scale)
    }
    fn check(&self, s: &SimModbusSettings) -> Result<(), String> {
        positive(s.time_scale, "time_scale")?;
        if s.capacity == 0 {
            return Err("capacity must be above 0".into());
        }
        Ok(())
    }
    fn gcode_units(
        &self,
        _lines: &[String],
        moves: &Toolpath,
    ) -> Option<Result<Vec<MotionBlock>, PostError>> {
        gcode_file_blocks(moves)
    }
    fn gcode_runs_as_moves(&self) -> bool {
        true
    }
    fn gcode_move_refused(&self, m: &offset_core::toolpath::Move) -> Option<String> {
        machlink_protocols::modbus::kind::gcode_file_refuses(m)
    }
    fn start(
        &self,
        _machine: &str,
        s: &SimModbusSettings,
    ) -> BoxFuture<'static, std::io::Result<ModbusSim>> {
        let cfg = SimConfig {
            time_scale: s.time_scale,
            capacity: s.capacity,
            ..Default::default()
        };
        Box::pin(async move { ModbusSim::spawn_tcp(cfg, ([127, 0, 0, 1], 0).into()).await })
    }
    fn open(
        &self,
        _machine: &str,
        _s: &SimModbusSettings,
        sim: &ModbusSim,
    ) -> OpenLink<MotionBlock> {
        let addr = sim.addr();
        open_ring(RingSettings::default().settings(Transport::Tcp {
            host: addr.ip().to_string(),
            port: addr.port(),
        }))
    }
}

/// The receive-buffer overflows the simulator behind a `sim-…` machine has counted, when it
/// counts them (the GRBL simulator): for the daemon's metrics.
pub fn rx_overflows(device: &machlink_protocols::kind::Device) -> Option<u64> {
    device
        .downcast_ref::<GrblSimHandle>()
        .map(GrblSimHandle::rx_overflows)
}
