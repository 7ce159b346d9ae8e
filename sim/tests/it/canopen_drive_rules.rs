//! docs/canopen.md's rules for a drive ("Rules a drive is built to" and "What each stop
//! leaves the drives in"), each checked on the simulated drive, the reference device, by
//! frames alone: quick stop with 0x605A = 2 ends switch on disabled (and with 6 stays in
//! quick stop), shutdown from operation enabled ends ready to switch on, the following
//! error is demand − actual as a little-endian i32 in TPDO1 bytes 4–7, a change of 0x6060
//! in operation enabled is refused with 0x08000022, and a second set-point before a SYNC
//! faults with EMCY 0x8700.

use machlink_protocols::canopen::cia402::{Command, PowerState};
use machlink_protocols::canopen::frame::CanFrame;
use machlink_protocols::canopen::nmt::{self, Emcy, NmtCommand};
use machlink_protocols::canopen::sdo::{SdoClient, SdoStep};
use machlink_sim::canopen::Drive;

const NODE: u8 = 4;

/// One SDO transfer with the drive: Ok(data) or Err(the abort, as text).
fn sdo(d: &mut Drive, index: u16, sub: u8, write: Option<&[u8]>) -> Result<Vec<u8>, String> {
    let mut c = SdoClient::new();
    let mut req = match write {
        Some(v) => c.download(index, sub, v),
        None => c.upload(index, sub),
    };
    loop {
        let mut out = Vec::new();
        d.on_frame(&CanFrame::new(0x600 + NODE as u16, &req).unwrap(), &mut out);
        let resp = out
            .iter()
            .find(|f| f.id() == 0x580 + NODE as u32)
            .expect("an SDO answer");
        match c.on_response(resp.data()).map_err(|e| e.to_string())? {
            SdoStep::Send(r) => req = r,
            SdoStep::Done(v) => return Ok(v),
        }
    }
}

fn write(d: &mut Drive, index: u16, sub: u8, v: &[u8]) {
    sdo(d, index, sub, Some(v)).unwrap_or_else(|e| panic!("{index:04X}:{sub:02X}: {e}"));
}

fn controlword(d: &mut Drive, cmd: Command) {
    write(d, 0x6040, 0, &cmd.controlword().to_le_bytes());
}

/// A drive in cyclic synchronous position mode, operational, in operation enabled, with
/// RPDO1 (0x607A) and TPDO1 (0x6064, 0x60F4) as machlink maps them.
fn enabled_drive() -> Drive {
    let mut d = Drive::new(NODE);
    let mut out = Vec::new();
    d.take_output(&mut out);
    write(&mut d, 0x6060, 0, &[8]);
    let rpdo = 0x200 + NODE as u32;
    let tpdo = 0x180 + NODE as u32;
    write(&mut d, 0x1400, 1, &(rpdo | 0x8000_0000).to_le_bytes());
    write(&mut d, 0x1600, 0, &[0]);
    write(&mut d, 0x1600, 1, &0x607A_0020u32.to_le_bytes());
    write(&mut d, 0x1600, 0, &[1]);
    write(&mut d, 0x1400, 2, &[1]);
    write(&mut d, 0x1400, 1, &rpdo.to_le_bytes());
    write(&mut d, 0x1800, 1, &(tpdo | 0x8000_0000).to_le_bytes());
    write(&mut d, 0x1A00, 0, &[0]);
    write(&mut d, 0x1A00, 1, &0x6064_0020u32.to_le_bytes());
    write(&mut d, 0x1A00, 2, &0x60F4_0020u32.to_le_bytes());
    write(&mut d, 0x1A00, 0, &[2]);
    write(&mut d, 0x1800, 2, &[1]);
    write(&mut d, 0x1800, 1, &tpdo.to_le_bytes());
    d.on_frame(&NmtCommand::Start.frame(NODE), &mut out);
    for c in [
        Command::Shutdown,
        Command::SwitchOn,
        Command::EnableOperation,
    ] {
        controlword(&mut d, c);
    }
    assert_eq!(d.power_state(), PowerState::OperationEnabled);
    d
}

/// Sends the set-point `counts` and a SYNC; returns the frames the drive answered.
fn cycle(d: &mut Drive, counts: i32) -> Vec<CanFrame> {
    let mut out = Vec::new();
    d.on_frame(
        &CanFrame::new(0x200 + NODE as u16, &counts.to_le_bytes()).unwrap(),
        &mut out,
    );
    d.on_frame(&nmt::sync_frame(), &mut out);
    out
}

#[test]
fn quick_stop_with_option_code_2_ends_switch_on_disabled() {
    let mut d = enabled_drive();
    assert_eq!(sdo(&mut d, 0x605A, 0, None).unwrap(), 2i16.to_le_bytes());
    write(&mut d, 0x605A, 0, &2i16.to_le_bytes());
    controlword(&mut d, Command::QuickStop);
    assert_eq!(d.power_state(), PowerState::SwitchOnDisabled);
}

#[test]
fn quick_stop_with_option_code_6_stays_in_quick_stop_active() {
    let mut d = enabled_drive();
    write(&mut d, 0x605A, 0, &6i16.to_le_bytes());
    controlword(&mut d, Command::QuickStop);
    assert_eq!(d.power_state(), PowerState::QuickStopActive);
}

#[test]
fn shutdown_from_operation_enabled_ends_ready_to_switch_on() {
    let mut d = enabled_drive();
    controlword(&mut d, Command::Shutdown);
    assert_eq!(d.power_state(), PowerState::ReadyToSwitchOn);
}

#[test]
fn the_following_error_is_demand_minus_actual_little_endian_in_tpdo1_bytes_4_to_7() {
    let mut d = enabled_drive();
    let out = cycle(&mut d, 100_000);
    let tpdo = out
        .iter()
        .find(|f| f.id() == 0x180 + NODE as u32)
        .expect("TPDO1 after the SYNC");
    let b = tpdo.data();
    assert_eq!(b.len(), 8);
    let actual = i32::from_le_bytes(b[0..4].try_into().unwrap());
    let following = i32::from_le_bytes(b[4..8].try_into().unwrap());
    assert!(actual > 0 && actual < 100_000, "actual {actual}");
    assert_eq!(following, 100_000 - actual, "demand − actual");
    assert!(following > 0, "behind a growing set-point: positive");
}

#[test]
fn a_change_of_mode_in_operation_enabled_is_refused_with_0x08000022() {
    let mut d = enabled_drive();
    let e = sdo(&mut d, 0x6060, 0, Some(&[7])).unwrap_err();
    assert!(e.contains("08000022"), "{e}");
}

#[test]
fn a_second_set_point_before_a_sync_faults_with_emcy_0x8700() {
    let mut d = enabled_drive();
    cycle(&mut d, 10);
    let mut out = Vec::new();
    for c in [20i32, 30] {
        d.on_frame(
            &CanFrame::new(0x200 + NODE as u16, &c.to_le_bytes()).unwrap(),
            &mut out,
        );
    }
    let emcy = out.iter().find_map(Emcy::parse).expect("an EMCY");
    assert_eq!(emcy.code, 0x8700);
    assert_eq!(d.power_state(), PowerState::Fault);
}
