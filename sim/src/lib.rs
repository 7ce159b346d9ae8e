//! machlink-sim: simulated devices that speak the real protocols (GRBL over a pty, Modbus
//! over TCP or RTU, a pattern sewing machine, CANopen drives), with a motion model in
//! simulated time, fault injection, and a trace of what they executed for tests to read.

pub mod canopen;
pub mod grbl;
pub mod kinds;
pub mod modbus;
pub mod pty;
pub mod sewing;
