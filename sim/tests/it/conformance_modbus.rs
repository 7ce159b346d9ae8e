//! docs/modbus.md's state table, cell by cell, against the simulated device (the reference
//! device) over RTU and over TCP: one test per request row, each taking a fresh device to
//! every state and checking the reply, the next state and the registers.

use machlink_protocols::modbus::{ModbusLink, ModbusSettings, WordOrder};
use machlink_sim::conformance::modbus::{check, markdown_table, Ask, ASKS, STATES};
use machlink_sim::conformance::{document_holds, every_column};
use machlink_sim::line;
use machlink_sim::modbus::{ModbusSim, SimConfig};
use std::time::Duration;

fn device() -> SimConfig {
    SimConfig {
        unit_id: 3,
        base_address: 400,
        word_order: WordOrder::LowFirst,
        capacity: 16,
        time_scale: 1.0,
        ..SimConfig::default()
    }
}

fn settings(mut s: ModbusSettings) -> ModbusSettings {
    s.unit_id = 3;
    s.base_address = 400;
    s.word_order = WordOrder::LowFirst;
    s.timeout = Duration::from_secs(2);
    s
}

/// Every state of `ask`'s row, on a fresh device each, over both transports.
async fn row(ask: Ask) {
    every_column(&STATES, ask.text(), |state| async move {
        // RTU on an in-memory cable
        let (host, dev) = line::cable(None);
        let _sim = ModbusSim::spawn_rtu_on(device(), dev);
        let rtu = settings(ModbusSettings::rtu("cable", 19_200));
        let mut link = ModbusLink::from_stream(host, rtu).unwrap();
        check(&mut link, state, ask)
            .await
            .map_err(|e| format!("over RTU: {e}"))?;
        // TCP on loopback
        let sim = ModbusSim::spawn_tcp(device(), "127.0.0.1:0".parse().unwrap())
            .await
            .unwrap();
        let tcp = settings(ModbusSettings::tcp("127.0.0.1", sim.addr().port()));
        let mut link = ModbusLink::new(tcp).unwrap();
        check(&mut link, state, ask)
            .await
            .map_err(|e| format!("over TCP: {e}"))
    })
    .await;
}

machlink_sim::conformance_rows! {
    row, ASKS;
    command_1_start => Ask::Start,
    command_2_hold => Ask::Hold,
    command_3_resume => Ask::Resume,
    command_4_stop => Ask::Stop,
    command_5_clear_fault => Ask::ClearFault,
    command_6_sync => Ask::Sync,
    command_0_is_no_command => Ask::NoCommand,
    command_7_or_above_is_refused => Ask::UnknownCommand,
    write_sequence_forward_within_the_ring => Ask::SeqForward,
    write_sequence_past_the_ring => Ask::SeqPastRing,
    write_sequence_back => Ask::SeqBack,
    half_of_the_write_sequence => Ask::SeqHalf,
    write_to_a_read_only_register => Ask::ReadOnly,
    write_to_a_reserved_register => Ask::Reserved,
    write_to_a_free_slot => Ask::FreeSlot,
    write_to_a_committed_slot => Ask::CommittedSlot,
    read_inside_the_map => Ask::ReadHeader,
    read_past_the_map => Ask::ReadPastMap,
    read_of_too_many_registers => Ask::ReadTooMany,
    unknown_function => Ask::UnknownFunction,
}

#[test]
fn the_document_holds_the_table_this_test_runs() {
    document_holds("modbus.md", &markdown_table()).unwrap();
}
