//! Simulated CANopen: CiA 402 drives on an in-memory bus ([`drive`] is the model, this module
//! runs it), an SLCAN adapter on a pty in front of that bus ([`adapter`]), the `sim-canopen`
//! machine kind ([`kind`]) and `machlink-sim canopen` ([`cli`]).

pub mod adapter;
pub mod cli;
pub mod drive;
pub mod kind;

pub use adapter::{spawn_adapter, SlcanAdapter};
pub use drive::{Drive, DriveFault, SyncRecord};

use machlink_protocols::canopen::MemoryBus;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::task::JoinHandle;

/// Drives running on an in-memory bus; they stop when this is dropped.
pub struct SimDrives {
    bus: MemoryBus,
    drives: Vec<Arc<Mutex<Drive>>>,
    tasks: Vec<JoinHandle<()>>,
}

impl SimDrives {
    /// Starts a drive for each of `nodes` on `bus`; each sends its boot-up at once. Their
    /// heartbeat clock runs `time_scale` times as fast as the wall clock. Must run inside a
    /// tokio runtime.
    pub fn spawn(bus: &MemoryBus, nodes: &[u8], time_scale: f64) -> SimDrives {
        let mut drives = Vec::new();
        let mut tasks = Vec::new();
        for &node in nodes {
            let drive = Arc::new(Mutex::new(Drive::new(node)));
            let mut port = bus.attach();
            let d = drive.clone();
            let scale = if time_scale.is_finite() && time_scale > 0.0 {
                time_scale
            } else {
                1.0
            };
            tasks.push(tokio::spawn(async move {
                let t0 = Instant::now();
                let mut out = Vec::new();
                let mut tick = tokio::time::interval(Duration::from_millis(2));
                tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
                loop {
                    tokio::select! {
                        f = machlink_protocols::canopen::CanBus::recv(&mut port) => {
                            let Ok(f) = f else { return };
                            d.lock().unwrap().on_frame(&f, &mut out);
                        }
                        _ = tick.tick() => {
                            let now = t0.elapsed().mul_f64(scale);
                            d.lock().unwrap().tick(now, &mut out);
                        }
                    }
                    for f in out.drain(..) {
                        port.send_now(&f);
                    }
                }
            }));
            drives.push(drive);
        }
        SimDrives {
            bus: bus.clone(),
            drives,
            tasks,
        }
    }

    /// The bus the drives are on.
    pub fn bus(&self) -> &MemoryBus {
        &self.bus
    }

    fn find(&self, node: u8) -> Option<&Arc<Mutex<Drive>>> {
        self.drives.iter().find(|d| d.lock().unwrap().node == node)
    }

    /// The nodes, in order.
    pub fn nodes(&self) -> Vec<u8> {
        self.drives.iter().map(|d| d.lock().unwrap().node).collect()
    }

    /// Node `node`'s record of every SYNC with operation enabled.
    pub fn trace(&self, node: u8) -> Vec<SyncRecord> {
        self.find(node)
            .map(|d| d.lock().unwrap().trace().to_vec())
            .unwrap_or_default()
    }

    /// Forgets every drive's record.
    pub fn clear_traces(&self) {
        for d in &self.drives {
            d.lock().unwrap().clear_trace();
        }
    }

    /// Arms `fault` on node `node`; false when there is no such node.
    pub fn inject(&self, node: u8, fault: DriveFault) -> bool {
        match self.find(node) {
            Some(d) => {
                d.lock().unwrap().inject(fault);
                true
            }
            None => false,
        }
    }

    /// Runs `f` on node `node`'s drive.
    pub fn with_drive<T>(&self, node: u8, f: impl FnOnce(&mut Drive) -> T) -> Option<T> {
        self.find(node).map(|d| f(&mut d.lock().unwrap()))
    }
}

impl Drop for SimDrives {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}
