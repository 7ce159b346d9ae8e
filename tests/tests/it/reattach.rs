//! A daemon that loses its machine, by its own crash or by a cable pulled, finds out what
//! the machine did meanwhile and never starts it again or sends it a unit twice: a sewing
//! machine that kept sewing is followed to the end; a GRBL controller whose pty closed
//! pauses the job, shows offline, and after it is back and `resume` is said runs every
//! line once.

use crate::common;

use common::*;
use machlink::core::intake::{JobSpec, Operation};
use machlink::core::store::JobState;
use machlink::daemon::StartOptions;
use machlink_protocols::DeviceState;
use machlink_sim::grbl::{GrblSim, GrblSimConfig, TraceEvent};
use machlink_sim::sewing::{spawn_on_pty, SewingSimConfig, TraceLine};
use offset_core::stitch::StitchParams;
use std::time::Duration;

fn zigzag_stitches() -> JobSpec {
    JobSpec {
        operation: Some(Operation::Stitch(StitchParams {
            stitch_length: 2.5,
            ..Default::default()
        })),
        ..job(
            "sewer",
            "zigzag.json",
            &sewing::zigzag_seam(10, -50.0, 8.0, 100.0),
        )
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_daemon_killed_while_the_machine_sews_follows_it_to_the_end_without_starting_it_again() {
    let sim = spawn_on_pty(SewingSimConfig {
        time_scale: 4.0,
        spm: 3000,
        ..Default::default()
    })
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let machine = format!(
        "[[machine]]\nname = \"sewer\"\nlink = \"sewing\"\nport = \"{}\"\n",
        sim.path
    );
    let d = start(dir.path(), &machine, StartOptions::default()).await;
    let c = client(&d);
    let job = c.submit(&zigzag_stitches()).await.unwrap();
    wait_until(&c, job.id, |j| j.acked_units >= 100).await;
    d.crash().await;
    let sewn_at_crash = sim.trace.lock().unwrap().drops.len();
    // the machine sews on while no daemon is there
    tokio::time::sleep(Duration::from_millis(200)).await;
    let d = start(dir.path(), &machine, StartOptions::default()).await;
    let c = client(&d);
    // nobody says resume: the daemon finds the machine sewing this pattern and follows it
    let done = wait_state(&c, job.id, JobState::Completed).await;
    assert_eq!(done.acked_units, job.total_units);
    let t = sim.trace.lock().unwrap().clone();
    let records: Vec<u32> = t
        .lines
        .iter()
        .filter_map(|l| match l {
            TraceLine::Record { index, .. } => Some(*index),
            _ => None,
        })
        .collect();
    assert_eq!(
        records,
        (0..job.total_units as u32).collect::<Vec<_>>(),
        "every record sewn once, in order"
    );
    let notes: Vec<&str> = t
        .lines
        .iter()
        .filter_map(|l| match l {
            TraceLine::Note { text } => Some(text.as_str()),
            _ => None,
        })
        .collect();
    let uploads = notes
        .iter()
        .filter(|n| n.starts_with("upload begun"))
        .count();
    let starts = notes.iter().filter(|n| n.starts_with("start at")).count();
    assert_eq!((uploads, starts), (1, 1), "{notes:?}");
    assert!(sewn_at_crash < t.drops.len(), "the crash came mid-pattern");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pulled_cable_pauses_the_job_and_after_it_is_back_resume_runs_every_line_once() {
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("grbl0");
    let sim = GrblSim::spawn_linked(
        GrblSimConfig {
            time_scale: 10.0,
            ..Default::default()
        },
        &port,
    )
    .unwrap();
    let d = start(dir.path(), &machine_on(&port), StartOptions::default()).await;
    let c = client(&d);
    let lines = zigzag(600);
    let job = submit_gcode(&c, "mill", "zigzag", &lines).await;
    wait_until(&c, job.id, |j| j.acked_units >= 150).await;
    sim.unplug();
    // the job pauses, saying why, and the machine shows offline
    let paused = wait_until(&c, job.id, |j| {
        j.state == JobState::Paused && j.note.as_deref().is_some_and(|n| n.contains("dropped"))
    })
    .await;
    assert!(paused.acked_units < lines.len());
    let m = &c.machines().await.unwrap()[0];
    assert_eq!(m.status.state, DeviceState::Offline, "{m:?}");
    assert!(m.age_ms.is_some());
    let e = c.act(job.id, "resume").await.unwrap_err().to_string();
    assert!(e.contains("offline"), "{e}");
    // the cable comes back; the daemon reconnects by itself and asks the machine
    sim.replug().unwrap();
    let back = wait_until(&c, job.id, |j| {
        j.note.as_deref().is_some_and(|n| n.contains("is back"))
    })
    .await;
    assert_eq!(back.state, JobState::Paused);
    // motion never resumes by itself
    let ran = sim.trace().len();
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert_eq!(sim.trace().len(), ran, "the machine moved without a resume");
    assert_eq!(c.job(job.id).await.unwrap().state, JobState::Paused);
    assert_ne!(
        c.machines().await.unwrap()[0].status.state,
        DeviceState::Offline
    );
    c.act(job.id, "resume").await.unwrap();
    let done = wait_end(&c, job.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
    // every program line reached the machine once, and every move ran once
    let received: Vec<String> = sim
        .events()
        .into_iter()
        .filter_map(|e| match e {
            TraceEvent::Received { n: Some(_), line } if !line.contains("(resume)") => Some(line),
            _ => None,
        })
        .collect();
    assert_eq!(received, lines);
    assert_eq!(
        program_motion(&sim)
            .into_iter()
            .map(|e| e.line)
            .collect::<Vec<_>>(),
        expected_motion(&lines)
    );
    let events = sim.events();
    assert!(events.contains(&TraceEvent::Unplugged) && events.contains(&TraceEvent::Plugged));
}
