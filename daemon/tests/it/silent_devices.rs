//! Silent devices are caught: a controller that stops answering mid-job (no `ok`, no reply
//! to its status request) shows as not answering in `machlink machines` and in the API's
//! machine state within the documented time, the job pauses after the machine's
//! `silent_timeout_s` with its last acknowledged unit, nothing moves when the device
//! answers again, and the operator's `resume --yes` completes the job with every line
//! exactly once on the device's trace. Through the `machlink` binary against simulators
//! that live in this test's process (so their traces can be read), hung on purpose.

use crate::proc;

use machlink::core::store::JobState;
use machlink_protocols::DeviceState;
use machlink_sim::grbl::{GrblFault, GrblSim, GrblSimConfig, TraceEvent as GrblEvent};
use machlink_sim::modbus::{Faults, ModbusSim, SimConfig, TraceEvent as ModbusEvent};
use machlink_sim::sewing::{spawn_on_pty, SewingSimConfig, TraceLine};
use proc::*;
use std::time::{Duration, Instant};

/// The G-code lines a GRBL controller took (its `$` lines and resume lines left out).
fn program_lines_received(events: &[GrblEvent]) -> Vec<String> {
    events
        .iter()
        .filter_map(|e| match e {
            GrblEvent::Received { n: Some(_), line } if !line.contains("(resume)") => {
                Some(line.clone())
            }
            _ => None,
        })
        .collect()
}

/// Waits (bounded) until machine `name`'s state satisfies `ok`; that state.
async fn wait_machine(
    d: &Daemon,
    name: &str,
    what: &str,
    ok: impl Fn(&DeviceState) -> bool,
) -> DeviceState {
    let until = Instant::now() + Duration::from_secs(60);
    loop {
        if let Ok(ms) = d.client().machines().await {
            if let Some(m) = ms.iter().find(|m| m.name == name) {
                if ok(&m.status.state) {
                    return m.status.state.clone();
                }
                assert!(
                    Instant::now() < until,
                    "machine {name} never became {what}: {m:?}\n{}",
                    d.log()
                );
            }
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_grbl_controller_that_goes_silent_pauses_its_job_at_the_last_ok_and_resume_completes_it()
{
    const SILENT_AFTER: u64 = 40;
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("grbl0");
    let grbl = GrblSim::spawn_linked(
        GrblSimConfig {
            time_scale: 4.0,
            faults: vec![GrblFault::SilentAfterLine {
                line: SILENT_AFTER,
                seconds: 7.0,
            }],
            ..Default::default()
        },
        &port,
    )
    .unwrap();
    write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nport = \"{}\"\nspindle_dwell_s = 0.2\nsilent_timeout_s = 3\n",
            port.display()
        ),
    );
    let daemon = Daemon::start(dir.path()).await;
    let program = serpentine(10, 0.0);
    let j = daemon
        .client()
        .submit(&file_job("mill", "silent.nc", &program.join("\n")))
        .await
        .unwrap();

    // within a second or so of silence the API and `machines` say so
    let state = wait_machine(&daemon, "mill", "not answering", |s| {
        matches!(s, DeviceState::NotAnswering { .. })
    })
    .await;
    assert!(
        matches!(state, DeviceState::NotAnswering { silent_s } if silent_s < 3),
        "shown before the limit: {state:?}"
    );
    let o = cli(dir.path(), &["machines"]);
    let listing = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success() && listing.contains("not answering for"),
        "`machines` says the machine is not answering:\n{listing}{}",
        stderr(&o)
    );

    // after silent_timeout_s the job pauses at the last line the controller acknowledged
    let paused = wait_job(&daemon, j.id, "paused by the silence", |j| {
        j.state == JobState::Paused
    })
    .await;
    assert_eq!(
        paused.acked_units, SILENT_AFTER as usize,
        "the job stops at the controller's last ok: {paused:?}"
    );

    // the controller answers again: the daemon reconnects, and the job waits for the
    // operator; nothing is sent that moves the machine
    let back = wait_job(&daemon, j.id, "waiting after the machine came back", |j| {
        j.state == JobState::Paused && j.note.as_deref().unwrap_or("").contains("is back")
    })
    .await;
    assert_eq!(back.acked_units, SILENT_AFTER as usize, "{back:?}");
    let events_back = grbl.events().len();
    let pos_back = grbl.position();
    tokio::time::sleep(Duration::from_secs(2)).await;
    let moved: Vec<_> = grbl.events()[events_back..]
        .iter()
        .filter(|e| {
            matches!(
                e,
                GrblEvent::Received { n: Some(_), .. }
                    | GrblEvent::Executed(_)
                    | GrblEvent::Jogged { .. }
            )
        })
        .cloned()
        .collect();
    assert!(
        moved.is_empty(),
        "the machine moved before the operator's resume: {moved:?}\n{}",
        daemon.log()
    );
    assert_eq!(grbl.position(), pos_back);
    assert_eq!(
        program_lines_received(&grbl.events()),
        program[..SILENT_AFTER as usize],
        "the controller took the lines it acknowledged and nothing after"
    );

    let o = cli(dir.path(), &["resume", &j.id.to_string(), "--yes"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let done = wait_job(&daemon, j.id, "completed", |j| j.state.is_final()).await;
    assert_eq!(
        done.state,
        JobState::Completed,
        "{done:?}\n{}",
        daemon.log()
    );
    assert_eq!(
        program_lines_received(&grbl.events()),
        program,
        "every line received once, in order"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_modbus_device_that_stops_replying_pauses_its_job_at_its_consumed_block_and_resume_completes_it(
) {
    const SILENT_AFTER: u32 = 30;
    let dir = tempfile::tempdir().unwrap();
    let press = ModbusSim::spawn_tcp(
        SimConfig {
            time_scale: 4.0,
            faults: Faults {
                silent_after_block: Some((SILENT_AFTER, Duration::from_secs(6))),
                ..Default::default()
            },
            ..Default::default()
        },
        "127.0.0.1:0".parse().unwrap(),
    )
    .await
    .unwrap();
    write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"press\"\nlink = \"modbus-tcp\"\nhost = \"127.0.0.1\"\nport = {}\ntimeout_ms = 300\nretries = 5\n",
            press.addr().port()
        ),
    );
    let daemon = Daemon::start(dir.path()).await;
    let lines = serpentine(10, 0.0);
    let j = daemon
        .client()
        .submit(&file_job("press", "press.nc", &lines.join("\n")))
        .await
        .unwrap();

    wait_machine(&daemon, "press", "not answering", |s| {
        matches!(s, DeviceState::NotAnswering { .. })
    })
    .await;
    let o = cli(dir.path(), &["machines"]);
    let listing = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        listing.contains("not answering for"),
        "`machines` says the device is not answering:\n{listing}"
    );
    let paused = wait_job(&daemon, j.id, "paused by the silence", |j| {
        j.state == JobState::Paused
    })
    .await;
    assert!(
        paused.acked_units <= SILENT_AFTER as usize,
        "no more than the device consumed: {paused:?}"
    );

    // the device answers again, holding at block 30; the daemon watches it and waits for
    // the operator (its note says so)
    wait_machine(&daemon, "press", "answering again, held", |s| {
        *s == DeviceState::Held
    })
    .await;
    // (the note of the held machine can come before the count read back from it: the
    // job is waiting once both are in)
    let back = wait_job(&daemon, j.id, "waiting after the device came back", |j| {
        let note = j.note.as_deref().unwrap_or("");
        j.state == JobState::Paused
            && !note.contains("reconnecting")
            && note.contains("resume")
            && j.acked_units >= SILENT_AFTER as usize
    })
    .await;
    assert_eq!(
        back.acked_units, SILENT_AFTER as usize,
        "the job stands at the device's consumed block: {back:?}"
    );
    let at_back = press.events_from(0).len();
    tokio::time::sleep(Duration::from_secs(2)).await;
    let after = press.events_from(at_back);
    assert!(
        !after
            .iter()
            .any(|e| matches!(e, ModbusEvent::Executed { .. })),
        "the machine moved before the operator's resume: {after:?}"
    );

    let o = cli(dir.path(), &["resume", &j.id.to_string(), "--yes"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let done = wait_job(&daemon, j.id, "completed", |j| j.state.is_final()).await;
    assert_eq!(
        done.state,
        JobState::Completed,
        "{done:?}\n{}",
        daemon.log()
    );
    let executed: Vec<u32> = press
        .events_from(0)
        .iter()
        .filter_map(|e| match e {
            ModbusEvent::Executed { seq, .. } => Some(*seq),
            _ => None,
        })
        .collect();
    assert_eq!(
        executed,
        (1..=done.total_units as u32).collect::<Vec<_>>(),
        "every block executed once, in order"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sewing_machine_that_stops_answering_status_pauses_its_job_and_resume_sews_every_record_once(
) {
    const SILENT_AFTER: u32 = 100;
    let dir = tempfile::tempdir().unwrap();
    let sewer = spawn_on_pty(SewingSimConfig {
        time_scale: 3.0,
        spm: 3000,
        silent_after: Some((SILENT_AFTER, Duration::from_secs(6))),
        ..Default::default()
    })
    .unwrap();
    write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"sewer\"\nlink = \"sewing\"\nport = \"{}\"\n",
            sewer.path
        ),
    );
    let daemon = Daemon::start(dir.path()).await;
    let j = daemon
        .client()
        .submit(&crate::crash::sewing_job(0))
        .await
        .unwrap();

    wait_machine(&daemon, "sewer", "not answering", |s| {
        matches!(s, DeviceState::NotAnswering { .. })
    })
    .await;
    let o = cli(dir.path(), &["machines"]);
    let listing = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        listing.contains("not answering for"),
        "`machines` says the machine is not answering:\n{listing}"
    );
    let paused = wait_job(&daemon, j.id, "paused by the silence", |j| {
        j.state == JobState::Paused
    })
    .await;
    assert!(
        paused.acked_units <= SILENT_AFTER as usize,
        "no more than the machine sewed: {paused:?}"
    );

    wait_machine(&daemon, "sewer", "answering again, held", |s| {
        *s == DeviceState::Held
    })
    .await;
    // (the note of the held machine can come before the count read back from it: the
    // job is waiting once both are in)
    let back = wait_job(&daemon, j.id, "waiting after the machine came back", |j| {
        let note = j.note.as_deref().unwrap_or("");
        j.state == JobState::Paused
            && !note.contains("reconnecting")
            && note.contains("resume")
            && j.acked_units >= SILENT_AFTER as usize
    })
    .await;
    assert_eq!(
        back.acked_units, SILENT_AFTER as usize,
        "the job stands at the machine's stitch counter: {back:?}"
    );
    let records = |t: &[TraceLine]| -> Vec<u32> {
        t.iter()
            .filter_map(|l| match l {
                TraceLine::Record { index, .. } => Some(*index),
                _ => None,
            })
            .collect()
    };
    let sewn_back = records(&sewer.trace.lock().unwrap().lines);
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert_eq!(
        records(&sewer.trace.lock().unwrap().lines),
        sewn_back,
        "the machine sewed before the operator's resume"
    );

    let o = cli(dir.path(), &["resume", &j.id.to_string(), "--yes"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let done = wait_job(&daemon, j.id, "completed", |j| j.state.is_final()).await;
    assert_eq!(
        done.state,
        JobState::Completed,
        "{done:?}\n{}",
        daemon.log()
    );
    assert_eq!(
        records(&sewer.trace.lock().unwrap().lines),
        (0..done.total_units as u32).collect::<Vec<_>>(),
        "every record sewn once, in order"
    );
}
