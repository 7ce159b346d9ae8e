//! A failed start-up or a silent drive leaves every drive disabled, on simulated CiA 402
//! drives: when one drive fails its start-up after the others reached operation enabled,
//! each is shut down (ready to switch on) and back in pre-operational; when one drive's
//! heartbeat stops mid-job, each is quick-stopped, which with the quick stop option code
//! machlink writes (0x605A = 2) ends in switch on disabled. None is left in operation
//! enabled, and the next start-up (after a reset communication, sent only once every drive
//! is disabled) runs the job.

use crate::canopen_line;

use canopen_line::*;
use machlink_protocols::canopen::cia402::PowerState;
use machlink_protocols::canopen::nmt::NmtState;
use machlink_protocols::{DeviceState, LinkEvent, StreamEnd};
use machlink_sim::canopen::DriveFault;
use std::time::Duration;

fn states(m: &Machine) -> Vec<(u8, PowerState, NmtState)> {
    (1..=3)
        .map(|n| {
            m.sim()
                .drives
                .with_drive(n, |d| (n, d.power_state(), d.nmt_state()))
                .expect("a drive")
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_drive_failing_its_start_up_leaves_every_drive_shut_down_and_pre_operational() {
    let mut m = Machine::start("ip").await;
    let program = m.program(&line_job());
    // node 3 is the last to power up: nodes 1 and 2 are in operation enabled when it fails
    assert!(m.sim().drives.inject(
        3,
        DriveFault::SdoAbort {
            index: 0x6061,
            sub: 0,
            code: 0x0800_0022,
        }
    ));
    let (end, _) = m.stream(&program, 0, |_, _, _| {}).await;
    let e = end.expect_err("the start-up fails");
    assert!(e.to_string().contains("node 3"), "{e}");
    // the NMT commands went out last: give the drives' tasks a moment to take them
    let mut left = states(&m);
    for _ in 0..100 {
        if left.iter().all(|s| s.2 == NmtState::PreOperational) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
        left = states(&m);
    }
    for (n, power, nmt) in left {
        assert_eq!(
            power,
            PowerState::ReadyToSwitchOn,
            "node {n} after a failed start-up"
        );
        assert_eq!(
            nmt,
            NmtState::PreOperational,
            "node {n} after a failed start-up"
        );
    }
    assert!(
        m.sim().drives.trace(1).is_empty(),
        "no set-point was applied"
    );
    // the next start-up runs the job
    let (end, _) = m.stream(&program, 0, |_, _, _| {}).await;
    assert_eq!(end.expect("the next start-up runs"), StreamEnd::Completed);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_drive_mid_job_leaves_every_drive_disabled() {
    // in real time (a lockstep run would finish before a heartbeat is missed)
    let mut table = settings("csp");
    table["lockstep"] = false.into();
    table["heartbeat_timeout_ms"] = 400.into();
    let mut m = Machine::start_with(table).await;
    let program = m.program(&line_job());
    assert!(m
        .sim()
        .drives
        .inject(2, DriveFault::Silent { after_syncs: 50 }));
    let (end, events) = m.stream(&program, 0, |_, _, _| {}).await;
    let e = end.expect_err("the job stops");
    assert!(
        e.to_string().contains("node 2") && e.to_string().contains("silent"),
        "{e}"
    );
    assert!(
        events
            .iter()
            .any(|e| matches!(e, LinkEvent::Status(s) if s.state == DeviceState::Offline)),
        "the machine shows offline"
    );
    for (n, power, _) in states(&m) {
        assert_eq!(
            power,
            PowerState::SwitchOnDisabled,
            "node {n} after node 2 went silent"
        );
    }
    let (end, _) = m.stream(&program, 0, |_, _, _| {}).await;
    assert_eq!(end.expect("the next start-up runs"), StreamEnd::Completed);
}
