//! CANopen through the daemon: a pocket submitted to three simulated CiA 402 drives behind
//! an SLCAN adapter runs on the path, pauses and resumes; a drive that faults stops the job
//! with its reason and the machine shows the alarm; after `unlock` the next job runs.

use crate::common;

use common::*;
use machlink::core::intake::Operation;
use machlink::core::store::JobState;
use machlink::daemon::StartOptions;
use machlink_protocols::DeviceState;
use machlink_sim::canopen::kind::SimCanopen;
use offset_core::ops::{Cutting, PocketParams, Stepover};

/// Counts per mm of every axis (the drives' encoder resolution).
const COUNTS: f64 = 100_000.0;

/// The gantry's config. Heartbeats every 50 ms, taken as lost after 1.5 s: these tests are
/// about set-points, pauses and drive faults, and a machine loaded by other test threads
/// once let a heartbeat run 403 ms late (heartbeat loss has its own test:
/// `canopen_disable::a_silent_drive_mid_job_leaves_every_drive_disabled` in sim/).
fn machine(faults: &str) -> String {
    format!(
        "[[machine]]\nname = \"gantry\"\nlink = \"sim-canopen\"\ntransport = \"slcan\"\n\
         period_ms = 2\nheartbeat_ms = 50\nheartbeat_timeout_ms = 1500\nreport_timeout_ms = 2000\n{faults}\
         axes = [\n  {{ axis = \"x\", node = 1, counts_per_mm = {COUNTS}, max_velocity = 60, max_acceleration = 800, max_jerk = 20000 }},\n  \
         {{ axis = \"y\", node = 2, counts_per_mm = {COUNTS}, max_velocity = 50, max_acceleration = 600, max_jerk = 20000 }},\n  \
         {{ axis = \"z\", node = 3, counts_per_mm = {COUNTS}, max_velocity = 15, max_acceleration = 400, max_jerk = 20000 }},\n]\n"
    )
}

/// A 24 × 16 mm pocket, 1 mm deep, as a job for `gantry`.
fn pocket_job() -> machlink::core::intake::JobSpec {
    let part = r#"{ "units": "mm", "paths": [ { "closed": true,
      "vertices": [[0,0,0],[24,0,0],[24,16,0],[0,16,0]] } ] }"#;
    machlink::core::intake::JobSpec {
        operation: Some(Operation::Pocket(PocketParams {
            cut: Cutting {
                tool: offset_core::Tool::flat(6.0),
                depth: 1.0,
                stepdown: 1.0,
                feed: 1800.0,
                plunge_feed: 400.0,
                safe_z: 3.0,
                spindle_rpm: 0.0,
                ..Cutting::default()
            },
            stepover: Stepover::Percent(50.0),
        })),
        ..job("gantry", "plate.json", part)
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pocket_on_three_drives_runs_on_its_path_pauses_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let d = start(dir.path(), &machine(""), StartOptions::default()).await;
    let c = client(&d);
    let job = c.submit(&pocket_job()).await.unwrap();
    // the daemon's default post for a CANopen machine: the moves themselves
    let moves: Vec<offset_core::Move> = stored(&d, job.id);
    assert_eq!(moves.len(), job.total_units);
    let running = wait_until(&c, job.id, |j| j.acked_units > 5).await;
    assert_eq!(running.state, JobState::Running);
    assert_eq!(
        c.act(job.id, "pause").await.unwrap().state,
        JobState::Paused
    );
    tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    assert_eq!(
        c.act(job.id, "resume").await.unwrap().state,
        JobState::Running
    );
    let done = wait_end(&c, job.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
    assert_eq!(done.acked_units, job.total_units);
    // every drive ended where the last move ends
    let sim = d.device::<SimCanopen>("gantry").unwrap();
    let end = moves
        .iter()
        .rev()
        .find_map(|m| match m {
            offset_core::Move::Rapid { to }
            | offset_core::Move::Linear { to, .. }
            | offset_core::Move::Arc { to, .. } => Some(*to),
            _ => None,
        })
        .unwrap();
    for (node, want) in [(1u8, end.x), (2, end.y), (3, end.z)] {
        let last = sim.drives.trace(node).last().copied().expect("a trace");
        let at = last.actual / COUNTS;
        assert!(
            (at - want).abs() < 0.01,
            "node {node} ended at {at} mm, the path at {want} mm"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_drive_fault_fails_the_job_with_its_reason_and_after_unlock_the_next_job_runs() {
    let dir = tempfile::tempdir().unwrap();
    let faults = "faults = [ { node = 2, fault = \"following_error\", after_syncs = 300 } ]\n";
    let d = start(dir.path(), &machine(faults), StartOptions::default()).await;
    let c = client(&d);
    let job = c.submit(&pocket_job()).await.unwrap();
    let failed = wait_end(&c, job.id).await;
    assert_eq!(failed.state, JobState::Failed);
    let e = failed.error.unwrap_or_default();
    assert!(
        e.contains("node 2") && e.contains("0x8611"),
        "the failure names the drive and its EMCY: {e}"
    );
    let m = &c.machines().await.unwrap()[0];
    assert!(
        matches!(
            m.status.state,
            DeviceState::Alarm {
                code: Some(0x8611),
                ..
            }
        ),
        "{:?}",
        m.status
    );
    // the alarm waits for the operator (as every kind's): unlocked, the next job completes
    // on the same machine (the fault fires once)
    c.operate("gantry", &machlink_protocols::Operation::Unlock)
        .await
        .unwrap();
    let next = c.submit(&pocket_job()).await.unwrap();
    let done = wait_end(&c, next.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
}
