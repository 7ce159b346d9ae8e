//! The link contract: how the daemon streams a program's units to a device, steers it, and
//! hears back, in typed words (states, events, errors) that no caller has to parse.

use futures::future::BoxFuture;
use serde::{Deserialize, Serialize};
use tokio::sync::{mpsc, watch};

/// What the operator asks of a running stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Control {
    Run,
    /// Feed hold: the machine decelerates and waits; `Run` continues.
    Hold,
    /// Stop as soon as it is safe; what was acknowledged stays acknowledged.
    Cancel,
}

/// Why a machine waits for someone at it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "reason", rename_all = "snake_case")]
pub enum OperatorReason {
    /// A sewing machine's thread broke: rethread, then resume.
    ThreadBreak,
    /// A safety door is open.
    Door,
    /// The program asks for another tool.
    ToolChange,
    /// The program stopped itself (M0, M1) or the machine's own hold button was pressed.
    ProgramStop,
    /// Anything else the device names.
    Other { text: String },
}

impl std::fmt::Display for OperatorReason {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match self {
            OperatorReason::ThreadBreak => f.write_str("thread break"),
            OperatorReason::Door => f.write_str("door open"),
            OperatorReason::ToolChange => f.write_str("tool change"),
            OperatorReason::ProgramStop => f.write_str("program stop"),
            OperatorReason::Other { text } => f.write_str(text),
        }
    }
}

/// What a device is doing, in the daemon's words. Each kind maps its own states onto these;
/// the daemon reacts to these and never to a device's own state text.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum DeviceState {
    /// Nothing reported yet.
    #[default]
    Unknown,
    Idle,
    Running,
    /// Held on the operator's request; resuming continues.
    Held,
    /// Stopped by a fault; needs clearing before it moves again.
    Alarm {
        /// The device's code, when it gives one (GRBL `ALARM:1`, a Modbus fault word).
        code: Option<u32>,
        text: String,
    },
    /// Waiting for someone at the machine.
    NeedsOperator {
        #[serde(flatten)]
        reason: OperatorReason,
    },
    /// The link is down.
    Offline,
}

impl std::fmt::Display for DeviceState {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match self {
            DeviceState::Unknown => f.write_str("unknown"),
            DeviceState::Idle => f.write_str("idle"),
            DeviceState::Running => f.write_str("running"),
            DeviceState::Held => f.write_str("held"),
            DeviceState::Alarm {
                code: Some(c),
                text,
            } => write!(f, "alarm {c}: {text}"),
            DeviceState::Alarm { code: None, text } => write!(f, "alarm: {text}"),
            DeviceState::NeedsOperator { reason } => write!(f, "needs operator: {reason}"),
            DeviceState::Offline => f.write_str("offline"),
        }
    }
}

/// A device's status as last reported.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MachineStatus {
    pub state: DeviceState,
    /// The device's own word for its state (GRBL `Hold:0`, a sewing machine's `ThreadBreak`),
    /// for people to read; nothing decides on it.
    pub detail: String,
    /// Work position, mm.
    pub position: [f64; 3],
    /// Current feed, mm/min.
    pub feed: f64,
}

/// What a link reports while it streams.
#[derive(Clone, Debug, PartialEq)]
pub enum LinkEvent {
    /// The device acknowledged units up to and including `unit` (0-based).
    Acked {
        unit: usize,
    },
    Status(MachineStatus),
    /// A message from the device worth showing the operator.
    Message(String),
}

/// How a stream ended without error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StreamEnd {
    /// Every unit was acknowledged and the device finished moving.
    Completed,
    /// Stopped on request; `acked` units had been acknowledged.
    Cancelled { acked: usize },
}

/// Why a stream failed.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("cannot open {port}: {source}")]
    Open {
        port: String,
        #[source]
        source: std::io::Error,
    },
    /// The port is held by another program (or by a link closed a moment ago).
    #[error("{port} is in use by another program")]
    PortBusy { port: String },
    #[error("link I/O failed: {0}")]
    Io(#[from] std::io::Error),
    #[error("the device rejected unit {unit} ({text}): {reason}")]
    Rejected {
        unit: usize,
        text: String,
        reason: String,
    },
    /// The device stopped with an alarm; it keeps talking, and needs clearing.
    #[error("the device raised an alarm: {text}")]
    Alarm { code: Option<u32>, text: String },
    #[error("the device did not answer within {0:?}")]
    Timeout(std::time::Duration),
    #[error("the device broke protocol: {0}")]
    Protocol(String),
}

impl LinkError {
    /// Whether the device is still talking after this error, so the same link can serve the
    /// next job (a refused line, an alarm); otherwise the link is opened afresh.
    pub fn keeps_link(&self) -> bool {
        matches!(self, LinkError::Rejected { .. } | LinkError::Alarm { .. })
    }
}

/// A connection to one device that streams programs of units `U` (G-code lines, stitch
/// records, motion blocks, …) to it.
pub trait Link<U>: Send {
    /// Streams `units` from unit `from` on, reporting progress on `events` and obeying
    /// `control`, until every unit is executed, the stream is cancelled, or it fails.
    fn stream<'a>(
        &'a mut self,
        units: &'a [U],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>>;
}
