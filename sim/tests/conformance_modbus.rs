//! docs/modbus.md's state table, cell by cell, against the simulated device (the reference
//! device) over RTU and over TCP: one test per request row, each taking a fresh device to
//! every state and checking the reply, the next state and the registers.

use machlink_protocols::modbus::{ModbusLink, ModbusSettings, WordOrder};
use machlink_sim::conformance::document_holds;
use machlink_sim::conformance::modbus::{check, markdown_table, Ask, ASKS, STATES};
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
    let mut failures = Vec::new();
    for state in STATES {
        // RTU on an in-memory cable
        let (host, dev) = line::cable(None);
        let _sim = ModbusSim::spawn_rtu_on(device(), dev);
        let mut link =
            ModbusLink::from_stream(host, settings(ModbusSettings::rtu("cable", 19_200))).unwrap();
        if let Err(e) = check(&mut link, state, ask).await {
            failures.push(format!("{state:?} × {} over RTU: {e}", ask.text()));
        }
        // TCP on loopback
        let sim = ModbusSim::spawn_tcp(device(), "127.0.0.1:0".parse().unwrap())
            .await
            .unwrap();
        let mut link = ModbusLink::new(settings(ModbusSettings::tcp(
            "127.0.0.1",
            sim.addr().port(),
        )))
        .unwrap();
        if let Err(e) = check(&mut link, state, ask).await {
            failures.push(format!("{state:?} × {} over TCP: {e}", ask.text()));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

macro_rules! rows {
    ($($name:ident => $ask:expr),* $(,)?) => {
        $(
            #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
            async fn $name() {
                row($ask).await;
            }
        )*

        #[test]
        fn every_row_of_the_table_has_its_test() {
            assert_eq!([$($ask),*].to_vec(), ASKS.to_vec());
        }
    };
}

rows! {
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
