//! The machine kinds this daemon knows: the real devices' kinds from machlink-protocols and
//! the simulated ones from machlink-sim. A test or an integrator adds its own to a copy.

use machlink_protocols::kind::Registry;

/// Every kind machlink ships: grbl, sim-grbl, modbus-tcp, modbus-rtu, sim-modbus, sewing,
/// sim-sewing, and their posts (plus linuxcnc and generic, which `plan` writes).
pub fn standard() -> Registry {
    let mut r = Registry::new();
    machlink_protocols::standard_kinds(&mut r);
    machlink_sim::kinds::register(&mut r);
    r
}
