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

/// The statusword a drive shows, read by SDO as machlink reads it.
fn statusword(d: &mut Drive) -> u16 {
    let b = sdo(d, 0x6041, 0, None).unwrap();
    u16::from_le_bytes([b[0], b[1]])
}

/// docs/canopen.md's statusword table, as (bits 6, 5, 3–0 mask, value) per row.
fn in_row(sw: u16, mask: u16, value: u16) -> bool {
    sw & mask == value
}

#[test]
fn the_device_type_names_profile_402_in_its_low_16_bits() {
    let mut d = Drive::new(NODE);
    let b = sdo(&mut d, 0x1000, 0, None).unwrap();
    let v = u32::from_le_bytes(b[..4].try_into().unwrap());
    assert_eq!(v & 0xFFFF, 402, "0x1000 = {v:#010x}");
}

#[test]
fn the_power_state_machine_follows_the_statusword_table_row_by_row() {
    let mut d = Drive::new(NODE);
    let mut out = Vec::new();
    d.take_output(&mut out);
    // switch on disabled: x1xx 0000
    let sw = statusword(&mut d);
    assert!(
        in_row(sw, 0x4F, 0x40),
        "switch on disabled, statusword {sw:#06x}"
    );
    // 0x0006 → ready to switch on: x01x 0001
    controlword(&mut d, Command::Shutdown);
    let sw = statusword(&mut d);
    assert!(
        in_row(sw, 0x6F, 0x21),
        "ready to switch on, statusword {sw:#06x}"
    );
    // 0x0007 → switched on: x01x 0011
    controlword(&mut d, Command::SwitchOn);
    let sw = statusword(&mut d);
    assert!(in_row(sw, 0x6F, 0x23), "switched on, statusword {sw:#06x}");
    // 0x000F → operation enabled: x01x 0111
    controlword(&mut d, Command::EnableOperation);
    let sw = statusword(&mut d);
    assert!(
        in_row(sw, 0x6F, 0x27),
        "operation enabled, statusword {sw:#06x}"
    );
    // quick stop with 0x605A = 6: x00x 0111, and 0x000F back to operation enabled
    write(&mut d, 0x605A, 0, &6i16.to_le_bytes());
    controlword(&mut d, Command::QuickStop);
    let sw = statusword(&mut d);
    assert!(
        in_row(sw, 0x6F, 0x07),
        "quick stop active, statusword {sw:#06x}"
    );
    controlword(&mut d, Command::EnableOperation);
    let sw = statusword(&mut d);
    assert!(
        in_row(sw, 0x6F, 0x27),
        "operation enabled again, statusword {sw:#06x}"
    );
}

#[test]
fn a_fault_is_cleared_by_0x0000_then_a_rising_edge_of_bit_7_to_switch_on_disabled() {
    let mut d = enabled_drive();
    cycle(&mut d, 10);
    let mut out = Vec::new();
    for c in [20i32, 30] {
        d.on_frame(
            &CanFrame::new(0x200 + NODE as u16, &c.to_le_bytes()).unwrap(),
            &mut out,
        );
    }
    let sw = statusword(&mut d);
    assert!(
        in_row(sw, 0x4F, 0x08),
        "fault: x0xx 1000, statusword {sw:#06x}"
    );
    write(&mut d, 0x6040, 0, &0x0000u16.to_le_bytes());
    write(&mut d, 0x6040, 0, &0x0080u16.to_le_bytes());
    let sw = statusword(&mut d);
    assert!(
        in_row(sw, 0x4F, 0x40),
        "switch on disabled after the reset, statusword {sw:#06x}"
    );
}

#[test]
fn the_set_point_received_before_sync_k_is_the_target_at_sync_k_and_every_sync_is_answered() {
    let mut d = enabled_drive();
    d.clear_trace();
    for (k, counts) in [100i32, 250, -40, 0].into_iter().enumerate() {
        let out = cycle(&mut d, counts);
        let tpdos = out.iter().filter(|f| f.id() == 0x180 + NODE as u32).count();
        assert_eq!(tpdos, 1, "one TPDO1 for SYNC {}", k + 1);
        let last = d.trace().last().expect("a record of the SYNC");
        assert_eq!(last.demand, counts, "SYNC {} applies its set-point", k + 1);
    }
}

#[test]
fn pdo_mapping_is_accepted_while_the_pdo_is_not_valid_and_refused_with_0x08000022_otherwise() {
    let mut d = enabled_drive();
    // RPDO1 is valid: a change of its mapping is refused
    let e = sdo(&mut d, 0x1600, 0, Some(&[0])).unwrap_err();
    assert!(e.contains("08000022"), "{e}");
    // made not valid (bit 31), the same write is taken
    let rpdo = 0x200 + NODE as u32;
    write(&mut d, 0x1400, 1, &(rpdo | 0x8000_0000).to_le_bytes());
    assert!(sdo(&mut d, 0x1600, 0, Some(&[0])).is_ok());
}

#[test]
fn the_heartbeat_comes_at_the_period_written_to_0x1017_in_the_nmt_state() {
    let mut d = Drive::new(NODE);
    let mut out = Vec::new();
    d.take_output(&mut out);
    write(&mut d, 0x1017, 0, &100u16.to_le_bytes());
    d.on_frame(&NmtCommand::Start.frame(NODE), &mut out);
    out.clear();
    let mut beats = Vec::new();
    for ms in (0..=1000u64).step_by(5) {
        d.tick(std::time::Duration::from_millis(ms), &mut out);
        for f in out.drain(..) {
            if let Some((node, state)) = nmt::parse_heartbeat(&f) {
                assert_eq!(node, NODE);
                beats.push((ms, state));
            }
        }
    }
    assert_eq!(
        beats.len(),
        11,
        "one heartbeat per 100 ms over 1 s: {beats:?}"
    );
    assert!(
        beats.windows(2).all(|w| w[1].0 - w[0].0 == 100),
        "{beats:?}"
    );
    assert!(beats
        .iter()
        .all(|(_, s)| *s == machlink_protocols::canopen::nmt::NmtState::Operational));
}

#[test]
fn a_drive_sent_enter_pre_operational_processes_no_pdos() {
    let mut d = enabled_drive();
    let mut out = Vec::new();
    d.on_frame(&NmtCommand::PreOperational.frame(NODE), &mut out);
    let before = d.trace().len();
    let out = cycle(&mut d, 500);
    assert!(
        !out.iter().any(|f| f.id() == 0x180 + NODE as u32),
        "no TPDO1 in pre-operational"
    );
    assert!(
        d.trace().len() == before || d.trace().last().unwrap().demand != 500,
        "the set-point was not taken in pre-operational"
    );
}
