//! The in-memory bus: any number of nodes in one process, every frame delivered to every
//! other node in the order sent, and each frame counted in bits for bus-load figures.

use super::bus::{BusError, CanBus, FrameSink};
use super::frame::CanFrame;
use futures::future::BoxFuture;
use std::sync::{Arc, Mutex};
use tokio::sync::mpsc;

/// Frames and bits carried so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BusStats {
    pub frames: u64,
    /// Bits on the wire, stuff bits and interframe space included.
    pub bits: u64,
}

#[derive(Default)]
struct Hub {
    ports: Vec<(usize, mpsc::UnboundedSender<CanFrame>)>,
    next: usize,
    stats: BusStats,
}

/// The bus itself; cheap to clone. Nodes join with [`MemoryBus::attach`].
#[derive(Clone, Default)]
pub struct MemoryBus {
    hub: Arc<Mutex<Hub>>,
}

/// One node's connection to a [`MemoryBus`].
pub struct MemoryPort {
    id: usize,
    rx: mpsc::UnboundedReceiver<CanFrame>,
    hub: Arc<Mutex<Hub>>,
}

impl MemoryBus {
    pub fn new() -> MemoryBus {
        MemoryBus::default()
    }

    /// A new node on the bus; it hears every frame sent after this by the others.
    pub fn attach(&self) -> MemoryPort {
        let (tx, rx) = mpsc::unbounded_channel();
        let mut hub = self.hub.lock().unwrap();
        let id = hub.next;
        hub.next += 1;
        hub.ports.push((id, tx));
        MemoryPort {
            id,
            rx,
            hub: self.hub.clone(),
        }
    }

    /// What the bus has carried.
    pub fn stats(&self) -> BusStats {
        self.hub.lock().unwrap().stats
    }
}

/// A handle that sends as one port (so its frames do not come back to that port), for a
/// task other than the one receiving.
#[derive(Clone)]
pub struct MemorySender {
    id: usize,
    hub: Arc<Mutex<Hub>>,
}

impl MemorySender {
    /// Sends without waiting (the in-memory bus never blocks).
    pub fn send_now(&self, frame: &CanFrame) {
        let mut hub = self.hub.lock().unwrap();
        hub.stats.frames += 1;
        hub.stats.bits += frame.bits_on_wire() as u64;
        hub.ports
            .retain(|(id, tx)| *id == self.id || tx.send(*frame).is_ok());
    }
}

impl MemoryPort {
    /// Sends without waiting (the in-memory bus never blocks).
    pub fn send_now(&self, frame: &CanFrame) {
        self.sender().send_now(frame)
    }

    /// A handle that sends as this port.
    pub fn sender(&self) -> MemorySender {
        MemorySender {
            id: self.id,
            hub: self.hub.clone(),
        }
    }

    /// The next frame if one is waiting.
    pub fn try_recv(&mut self) -> Option<CanFrame> {
        self.rx.try_recv().ok()
    }
}

impl Drop for MemoryPort {
    fn drop(&mut self) {
        if let Ok(mut hub) = self.hub.lock() {
            hub.ports.retain(|(id, _)| *id != self.id);
        }
    }
}

impl CanBus for MemoryPort {
    fn send<'a>(&'a mut self, frame: &'a CanFrame) -> BoxFuture<'a, Result<(), BusError>> {
        self.send_now(frame);
        Box::pin(async { Ok(()) })
    }
    fn recv(&mut self) -> BoxFuture<'_, Result<CanFrame, BusError>> {
        Box::pin(async move { self.rx.recv().await.ok_or(BusError::Closed) })
    }
    fn frame_sink(&mut self) -> Option<Box<dyn FrameSink>> {
        Some(Box::new(self.sender()))
    }
}

impl FrameSink for MemorySender {
    fn send_now(&mut self, frames: &[CanFrame]) -> std::io::Result<()> {
        for f in frames {
            MemorySender::send_now(self, f);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn every_other_node_hears_each_frame_in_order_and_bits_are_counted() {
        let bus = MemoryBus::new();
        let mut a = bus.attach();
        let mut b = bus.attach();
        let mut c = bus.attach();
        let f1 = CanFrame::new(0x080, &[]).unwrap();
        let f2 = CanFrame::new(0x201, &[1, 2, 3, 4]).unwrap();
        a.send(&f1).await.unwrap();
        a.send(&f2).await.unwrap();
        for p in [&mut b, &mut c] {
            assert_eq!(p.recv().await.unwrap(), f1);
            assert_eq!(p.recv().await.unwrap(), f2);
        }
        assert!(a.try_recv().is_none());
        let s = bus.stats();
        assert_eq!(s.frames, 2);
        assert_eq!(s.bits, (f1.bits_on_wire() + f2.bits_on_wire()) as u64);
    }
}
