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

/// The receive-buffer overflows a machine's device has counted, for the devices that count
/// them (the GRBL simulator); None for the others. Asked of the kinds' own crates, which
/// know their device types.
pub fn rx_overflows(device: &machlink_protocols::kind::Device) -> Option<u64> {
    machlink_sim::kinds::rx_overflows(device)
}
