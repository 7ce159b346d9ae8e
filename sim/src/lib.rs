//! machlink-sim: simulated devices that speak the real protocols (GRBL over a pty, Modbus
//! over TCP or RTU, a pattern sewing machine, CANopen drives), with a motion model in
//! simulated time, fault injection, and a trace of what they executed for tests to read.
//!
//! Every simulator opens its serial port through one pty harness (`pty`) or runs on any
//! byte stream, e.g. an in-memory cable paced at a baud rate (`line`), where a test under
//! tokio's paused clock gets exact line timing. `conformance` holds the protocol documents'
//! state tables as data and drives a device (these simulators, the reference devices, or a
//! real one) through every cell. It never imports the daemon.

pub mod canopen;
pub mod conformance;
pub mod grbl;
pub mod kinds;
pub mod line;
pub mod modbus;
pub mod pty;
pub mod sewing;
