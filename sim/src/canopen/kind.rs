//! The `sim-canopen` machine kind: simulated CiA 402 drives the daemon starts in-process, on
//! the in-memory bus or behind a simulated SLCAN adapter on a pty, run by the real master.

use super::adapter::{spawn_adapter, AdapterHandle};
use super::{DriveFault, SimDrives};
use futures::future::BoxFuture;
use machlink_protocols::canopen::adapter::open_slcan;
use machlink_protocols::canopen::kind::{gcode_file_moves, moves_posts, DriveSettings};
use machlink_protocols::canopen::master::{CanopenLink, Pace};
use machlink_protocols::canopen::MemoryBus;
use machlink_protocols::kind::{Joined, MachineKind};
use machlink_protocols::post::{PostError, PostFor};
use machlink_protocols::{Link, LinkError, Units};
use offset_core::{Move, Toolpath};
use serde::{Deserialize, Serialize};

/// How the link reaches the simulated drives.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SimTransport {
    /// The in-memory bus.
    #[default]
    Memory,
    /// A simulated SLCAN adapter on a pty, opened as a serial port.
    Slcan,
}

/// A fault armed on one node when the daemon starts. (No `deny_unknown_fields`: serde
/// cannot deny them beside a flattened enum, and would refuse every key.)
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimFault {
    pub node: u8,
    #[serde(flatten)]
    pub fault: DriveFault,
}

/// `link = "sim-canopen"`'s own keys.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimCanopenOwn {
    /// SYNCs come this many times as often as the period says (the drives' clock runs as
    /// fast), so a job runs this many times faster than on real drives.
    #[serde(default = "default_scale")]
    pub time_scale: f64,
    /// The next SYNC as soon as every drive has reported the last (as fast as it goes).
    #[serde(default)]
    pub lockstep: bool,
    /// "memory" (default) or "slcan".
    #[serde(default)]
    pub transport: SimTransport,
    /// Faults armed at start, e.g. `{ node = 2, fault = "following_error", after_syncs = 500 }`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub faults: Vec<SimFault>,
}

fn default_scale() -> f64 {
    1.0
}

/// The settings of a `link = "sim-canopen"` machine: its own keys and every CANopen key but
/// `bus`.
pub type SimCanopenSettings = Joined<SimCanopenOwn, DriveSettings>;

/// What `sim-canopen` starts: the drives, their bus, and the adapter when on SLCAN.
pub struct SimCanopen {
    pub drives: SimDrives,
    pub bus: MemoryBus,
    pub adapter: Option<AdapterHandle>,
}

/// `link = "sim-canopen"`.
pub struct SimCanopenKind;

impl MachineKind for SimCanopenKind {
    type Settings = SimCanopenSettings;
    type Unit = Move;
    type Device = SimCanopen;

    fn link(&self) -> &'static str {
        "sim-canopen"
    }
    fn about(&self) -> &'static str {
        "simulated CiA 402 drives the daemon starts in-process (in-memory bus or SLCAN on a pty)"
    }
    fn keys(&self) -> Vec<&'static str> {
        SimCanopenSettings::keys()
    }
    fn estimate(&self, s: &SimCanopenSettings, moves: Units<'_, Move>) -> Option<f64> {
        let t = machlink_protocols::estimate::moves_seconds(
            &moves.to_vec().ok()?,
            machlink_protocols::estimate::RAPID,
        );
        Some(t / s.own.time_scale)
    }
    fn posts(&self) -> Vec<PostFor<Move>> {
        moves_posts()
    }
    fn check(&self, s: &SimCanopenSettings) -> Result<(), String> {
        if !(s.own.time_scale.is_finite() && s.own.time_scale > 0.0) {
            return Err(format!(
                "time_scale must be a positive number, got {}",
                s.own.time_scale
            ));
        }
        s.common.check()?;
        for f in &s.own.faults {
            if !s.common.axes.iter().any(|a| a.node == f.node) {
                return Err(format!("faults: node {} drives no axis", f.node));
            }
        }
        Ok(())
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
    fn start(
        &self,
        _machine: &str,
        s: &SimCanopenSettings,
    ) -> BoxFuture<'static, std::io::Result<SimCanopen>> {
        let nodes: Vec<u8> = s.common.axes.iter().map(|a| a.node).collect();
        let (scale, transport, faults) = (s.own.time_scale, s.own.transport, s.own.faults.clone());
        Box::pin(async move {
            let bus = MemoryBus::new();
            let drives = SimDrives::spawn(&bus, &nodes, scale);
            for f in faults {
                drives.inject(f.node, f.fault);
            }
            let adapter = match transport {
                SimTransport::Memory => None,
                SimTransport::Slcan => Some(spawn_adapter(&bus)?),
            };
            Ok(SimCanopen {
                drives,
                bus,
                adapter,
            })
        })
    }
    fn open(
        &self,
        _machine: &str,
        s: &SimCanopenSettings,
        sim: &SimCanopen,
    ) -> BoxFuture<'static, Result<Box<dyn Link<Move>>, LinkError>> {
        let mut opts = s.common.options();
        opts.pace = if s.own.lockstep {
            Pace::Lockstep
        } else {
            Pace::RealTime {
                scale: s.own.time_scale,
            }
        };
        // the drives' heartbeat clock runs time_scale times as fast
        opts.heartbeat = opts.heartbeat.mul_f64(s.own.time_scale.max(1.0));
        let port = sim.adapter.as_ref().map(|a| a.path.clone());
        let memory = port.is_none().then(|| sim.bus.attach());
        Box::pin(async move {
            let bus: Box<dyn machlink_protocols::canopen::CanBus> = match (memory, port) {
                (Some(m), _) => Box::new(m),
                (None, Some(path)) => Box::new(open_slcan(&path, 1_000_000).await?),
                (None, None) => unreachable!("memory or a port"),
            };
            Ok(Box::new(CanopenLink::new(bus, opts)) as Box<dyn Link<Move>>)
        })
    }
}
