//! The bus: send and receive CAN frames, whatever carries them (socketcan, an SLCAN adapter
//! on a serial port, or the in-memory bus of tests); the `bus = "…"` setting that names one is
//! `adapter`'s.

use super::frame::CanFrame;
use futures::future::BoxFuture;

/// Why the bus failed.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    #[error("CAN bus I/O failed: {0}")]
    Io(#[from] std::io::Error),
    #[error("the CAN bus was closed")]
    Closed,
    /// The SLCAN adapter refused a command or frame (answered BEL), or did not answer.
    #[error("the SLCAN adapter on {port} {what}")]
    Adapter { port: String, what: String },
}

/// A CAN bus as the master sees it. Frames sent are not received back.
pub trait CanBus: Send {
    /// Puts one frame on the bus.
    fn send<'a>(&'a mut self, frame: &'a CanFrame) -> BoxFuture<'a, Result<(), BusError>>;
    /// The next frame from another node. Cancel-safe: a dropped call loses no frame, so it
    /// can sit in a `select!` beside a timer.
    fn recv(&mut self) -> BoxFuture<'_, Result<CanFrame, BusError>>;
    /// A handle that sends from another thread without the async runtime (the SYNC clock
    /// sends each cycle's frames itself, on time); None when the bus has none.
    fn frame_sink(&mut self) -> Option<Box<dyn FrameSink>> {
        None
    }
}

/// Sends frames from a plain thread, blocking until they are written.
pub trait FrameSink: Send {
    fn send_now(&mut self, frames: &[CanFrame]) -> std::io::Result<()>;
}
