//! docs/grbl.md's state table, cell by cell, against the simulated GRBL 1.1 controller on
//! a pty: one test per row, each taking a fresh controller to every state and checking
//! what it says and the state its next status report names.

use machlink_sim::conformance::grbl::{check, markdown_table, Ask, Column, ASKS, COLUMNS};
use machlink_sim::conformance::{document_holds, every_column};
use machlink_sim::grbl::{GrblFault, GrblSim, GrblSimConfig};

/// Every state of `ask`'s row, on a fresh controller each.
async fn row(ask: Ask) {
    every_column(&COLUMNS, ask.text(), |column| async move {
        let faults = if column == Column::AlarmBeforeReset {
            // the alarm a limit switch would raise, on the first G-code line
            vec![GrblFault::AlarmAtLine { line: 1, code: 1 }]
        } else {
            vec![]
        };
        let sim = GrblSim::spawn_pty(GrblSimConfig {
            faults,
            ..GrblSimConfig::default()
        })
        .unwrap();
        let path = sim.port().display().to_string();
        let port = machlink_protocols::serial::open(&path, 115_200).unwrap();
        check(port, column, ask).await
    })
    .await;
}

machlink_sim::conformance_rows! {
    row, ASKS;
    a_motion_line => Ask::Motion,
    a_line_grbl_refuses => Ask::Rejected,
    a_line_too_long => Ask::TooLong,
    status_query => Ask::Status,
    feed_hold => Ask::FeedHold,
    cycle_start => Ask::CycleStart,
    soft_reset => Ask::Reset,
    unlock => Ask::Unlock,
    check_mode => Ask::CheckMode,
    homing => Ask::Home,
    settings_list => Ask::Settings,
    build_info => Ask::Info,
    a_setting => Ask::SetSetting,
}

#[test]
fn the_document_holds_the_table_this_test_runs() {
    document_holds("grbl.md", &markdown_table()).unwrap();
}
