//! machlink-protocols: everything that speaks a machine's language, and never anything of
//! the daemon's (no store, no jobs, no API).
//!
//! Posts turn the Toolpath IR into a `Program` of the units one kind of device takes (G-code
//! lines, Modbus motion blocks, stitch records, moves for CANopen drives); links stream a
//! program to a device over a transport (serial, TCP, a CAN bus) and report each unit the device acknowledged, so the daemon can
//! journal progress and resume exactly where it stopped. Each machine kind (`kind`) ties its
//! settings, posts and link together in one module; [`standard_kinds`] registers them all.

pub mod canopen;
pub mod estimate;
pub mod gcode;
pub mod gcode_read;
pub mod grbl;
pub mod kind;
pub mod link;
pub mod modbus;
pub mod post;
pub mod program;
pub mod serial;
pub mod sewing;
pub mod untrusted;

pub use kind::{AnyKind, MachineKind, MachineLink, Registry};
pub use link::{
    Control, DeviceState, Handed, Link, LinkError, LinkEvent, MachineStatus, Operation,
    OperatorReason, Overrides, Reattach, ResumePlan, SendJournal, StreamEnd,
};
pub use post::{AnyPost, Post, PostError};
pub use program::{Paged, Program, Unit, UnitPages, Units, UnitsError};

/// Registers the machine kinds of real devices (grbl, modbus-tcp, modbus-rtu, sewing, canopen), their
/// posts, and the posts no kind runs (linuxcnc, generic).
pub fn standard_kinds(registry: &mut Registry) {
    registry
        .add_kind(grbl::kind::GrblKind)
        .add_kind(modbus::ModbusTcpKind::default())
        .add_kind(modbus::ModbusRtuKind::default())
        .add_kind(sewing::SewingKind)
        .add_kind(canopen::CanopenKind)
        .add_post(gcode::GcodePost(gcode::Dialect::Linuxcnc))
        .add_post(gcode::GcodePost(gcode::Dialect::Generic));
}
