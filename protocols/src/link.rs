//! The link contract: how the daemon streams a program to a device, steers it, and hears back.

use crate::program::Program;
use futures::future::BoxFuture;
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

/// A device's status as last reported.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MachineStatus {
    /// The device's own word for its state (GRBL: Idle, Run, Hold, Alarm, Check, …).
    pub state: String,
    /// Machine or work position, mm.
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
    #[error("link I/O failed: {0}")]
    Io(#[from] std::io::Error),
    #[error("the device rejected unit {unit} ({text}): {reason}")]
    Rejected {
        unit: usize,
        text: String,
        reason: String,
    },
    #[error("the device raised an alarm: {0}")]
    Alarm(String),
    #[error("the device did not answer within {0:?}")]
    Timeout(std::time::Duration),
    #[error("the device broke protocol: {0}")]
    Protocol(String),
    #[error("this link cannot send a {0} program")]
    WrongProgram(&'static str),
}

/// A connection to one device that can stream programs to it.
pub trait Link: Send {
    /// Streams `program` from unit `from` on, reporting progress on `events` and obeying
    /// `control`, until every unit is executed, the stream is cancelled, or it fails.
    fn stream<'a>(
        &'a mut self,
        program: &'a Program,
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>>;
}
