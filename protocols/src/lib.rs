//! machlink-protocols: everything that speaks a machine's language. Posts turn the Toolpath
//! IR into a `Program` (G-code lines, Modbus motion blocks, stitch records); links stream a
//! program to a device over a transport (serial, TCP, SLCAN) and report each unit the device
//! acknowledged, so the daemon can journal progress and resume exactly where it stopped.

pub mod gcode;
pub mod gcode_read;
pub mod grbl;
pub mod link;
pub mod program;
pub mod serial;

pub use link::{Control, Link, LinkError, LinkEvent, MachineStatus, StreamEnd};
pub use program::Program;
