//! The socketcan transport: a Linux CAN interface (can0, vcan0) through the `socketcan`
//! crate's tokio socket. Its bit rate is the interface's (`ip link set can0 type can bitrate …`).

use super::bus::{BusError, CanBus, FrameSink};
use super::frame::CanFrame;
use futures::future::BoxFuture;
use socketcan::{EmbeddedFrame, ExtendedId, Id, StandardId};

/// A CAN bus on a Linux CAN interface.
pub struct SocketCanBus {
    socket: socketcan::tokio::CanSocket,
    interface: String,
}

impl SocketCanBus {
    /// Opens interface `name` (it must exist and be up).
    pub fn open(name: &str) -> std::io::Result<SocketCanBus> {
        Ok(SocketCanBus {
            socket: socketcan::tokio::CanSocket::open(name)?,
            interface: name.to_string(),
        })
    }
}

fn to_socketcan(f: &CanFrame) -> Option<socketcan::CanFrame> {
    let id: Id = if f.is_extended() {
        ExtendedId::new(f.id())?.into()
    } else {
        StandardId::new(f.id() as u16)?.into()
    };
    if f.is_remote() {
        socketcan::CanFrame::new_remote(id, f.len())
    } else {
        socketcan::CanFrame::new(id, f.data())
    }
}

fn from_socketcan(f: &socketcan::CanFrame) -> Option<CanFrame> {
    let (id, extended) = match f.id() {
        Id::Standard(s) => (s.as_raw() as u32, false),
        Id::Extended(e) => (e.as_raw(), true),
    };
    match f {
        socketcan::CanFrame::Data(_) => CanFrame::with_id(id, extended, f.data()).ok(),
        socketcan::CanFrame::Remote(_) => CanFrame::remote(id, extended, f.dlc() as u8).ok(),
        socketcan::CanFrame::Error(_) => None,
    }
}

impl CanBus for SocketCanBus {
    fn send<'a>(&'a mut self, frame: &'a CanFrame) -> BoxFuture<'a, Result<(), BusError>> {
        Box::pin(async move {
            let f = to_socketcan(frame).ok_or_else(|| {
                BusError::Io(std::io::Error::other(format!(
                    "frame {frame} does not convert"
                )))
            })?;
            self.socket.write_frame(f).await?;
            Ok(())
        })
    }
    fn recv(&mut self) -> BoxFuture<'_, Result<CanFrame, BusError>> {
        Box::pin(async move {
            loop {
                let f = self.socket.read_frame().await?;
                // error frames (bus errors the kernel reports) are not CANopen traffic
                if let Some(f) = from_socketcan(&f) {
                    return Ok(f);
                }
            }
        })
    }
    fn frame_sink(&mut self) -> Option<Box<dyn FrameSink>> {
        // a second, blocking socket on the interface (its frames reach this socket too, as
        // any other node's would; the master ignores its own SYNC and RPDOs)
        use socketcan::Socket;
        let socket = socketcan::CanSocket::open(&self.interface).ok()?;
        Some(Box::new(SocketCanSink(socket)))
    }
}

/// Sends from the SYNC clock's thread on a blocking socket.
struct SocketCanSink(socketcan::CanSocket);

impl FrameSink for SocketCanSink {
    fn send_now(&mut self, frames: &[CanFrame]) -> std::io::Result<()> {
        use socketcan::Socket;
        for f in frames {
            let f = to_socketcan(f)
                .ok_or_else(|| std::io::Error::other(format!("frame {f} does not convert")))?;
            self.0.write_frame(&f)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_convert_both_ways() {
        for f in [
            CanFrame::new(0x181, &[1, 2, 3]).unwrap(),
            CanFrame::with_id(0x1234_5678, true, &[]).unwrap(),
            CanFrame::remote(0x701, false, 1).unwrap(),
        ] {
            assert_eq!(from_socketcan(&to_socketcan(&f).unwrap()), Some(f));
        }
    }
}
