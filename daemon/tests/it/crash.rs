//! The daemon killed (SIGKILL) at random moments while a GRBL controller, a pattern sewing
//! machine and a Modbus motion-block device each run jobs; after every kill it is started
//! again and the interrupted jobs resumed. On the devices' own traces every unit is run
//! exactly once, and nothing the device had acknowledged before a kill is sent to it again
//! (checked on what each device received: G-code lines, ring writes, pattern uploads).

use crate::proc;

use machlink::core::intake::{JobSpec, Operation};
use machlink::core::store::{JobId, JobState};
use machlink_sim::grbl::{GrblSim, GrblSimConfig, TraceEvent as GrblEvent};
use machlink_sim::modbus::{ModbusSim, SimConfig, TraceEvent as ModbusEvent};
use machlink_sim::sewing::{spawn_on_pty, SewingSimConfig, TraceLine};
use offset_core::stitch::StitchParams;
use proc::*;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// At least this many kills.
const KILLS: usize = 21;
/// Jobs per machine, each submitted when the one before has completed.
const JOBS: usize = 4;

/// A sewing job: an open zigzag of rows across the frame, shifted by `k` so each differs.
pub(crate) fn sewing_job(k: usize) -> JobSpec {
    let mut vertices = Vec::new();
    for row in 0..16 {
        let y = -60.0 + row as f64 * 7.0 + k as f64 * 0.5;
        let (a, b) = if row % 2 == 0 {
            (-110.0, 110.0)
        } else {
            (110.0, -110.0)
        };
        vertices.push([a, y, 0.0]);
        vertices.push([b, y, 0.0]);
    }
    let shape = serde_json::json!({ "units": "mm", "paths": [ { "closed": false, "vertices": vertices } ] });
    JobSpec {
        operation: Some(Operation::Stitch(StitchParams {
            stitch_length: 2.5,
            ..Default::default()
        })),
        ..file_job("sewer", &format!("zigzag{k}.json"), &shape.to_string())
    }
}

fn gcode_job(machine: &str, k: usize) -> (JobSpec, Vec<String>) {
    let lines = serpentine(12, k as f64 * 0.25);
    (
        file_job(machine, &format!("{machine}{k}.nc"), &lines.join("\n")),
        lines,
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigkill_at_random_moments_loses_and_repeats_no_unit_on_grbl_sewing_and_modbus() {
    let dir = tempfile::tempdir().unwrap();
    let grbl_port = dir.path().join("grbl0");
    let grbl = GrblSim::spawn_linked(
        GrblSimConfig {
            time_scale: 8.0,
            ..Default::default()
        },
        &grbl_port,
    )
    .unwrap();
    let sewer = spawn_on_pty(SewingSimConfig {
        time_scale: 3.0,
        spm: 3000,
        ..Default::default()
    })
    .unwrap();
    let press = ModbusSim::spawn_tcp(
        SimConfig {
            time_scale: 8.0,
            ..Default::default()
        },
        "127.0.0.1:0".parse().unwrap(),
    )
    .await
    .unwrap();
    write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nport = \"{}\"\nspindle_dwell_s = 0.5\n\n\
             [[machine]]\nname = \"sewer\"\nlink = \"sewing\"\nport = \"{}\"\n\n\
             [[machine]]\nname = \"press\"\nlink = \"modbus-tcp\"\nhost = \"127.0.0.1\"\nport = {}\ntimeout_ms = 300\n",
            grbl_port.display(),
            sewer.path,
            press.addr().port()
        ),
    );
    let mut daemon = Daemon::start(dir.path()).await;

    // each machine's jobs, submitted one after another; the programs the devices must run
    let mut grbl_programs: Vec<Vec<String>> = Vec::new();
    let mut press_blocks: Vec<usize> = Vec::new();
    let mut sewer_records: Vec<usize> = Vec::new();
    let mut current: BTreeMap<&str, (usize, JobId)> = BTreeMap::new();
    async fn submit(d: &Daemon, m: &str, k: usize) -> machlink::core::store::JobRecord {
        let spec = match m {
            "sewer" => sewing_job(k),
            m => gcode_job(m, k).0,
        };
        d.client().submit(&spec).await.expect("the job is taken")
    }
    for m in ["mill", "sewer", "press"] {
        let j = submit(&daemon, m, 0).await;
        current.insert(m, (0, j.id));
    }

    // keeps every machine busy: the next job once one completed, resume once interrupted
    async fn tend(
        daemon: &Daemon,
        current: &mut BTreeMap<&'static str, (usize, JobId)>,
    ) -> Vec<(&'static str, usize)> {
        let c = daemon.client();
        let mut done = Vec::new();
        for (m, (k, id)) in current.iter() {
            let Ok(j) = c.job(*id).await else { continue };
            match j.state {
                JobState::Completed => done.push((*m, *k)),
                JobState::Interrupted | JobState::Paused => {
                    let _ = c.act(*id, "resume").await;
                }
                JobState::Failed | JobState::Cancelled => panic!(
                    "job {id} on {m} ended {}: {:?}\n{}",
                    j.state,
                    j.error,
                    daemon.log()
                ),
                _ => {}
            }
        }
        done
    }

    let mut rng = Rng(0x5eed_c0de);
    let mut kills = 0;
    let mut killed_while_running: BTreeMap<&str, usize> = BTreeMap::new();
    let mut finished: BTreeMap<&str, usize> = BTreeMap::new();
    let give_up = Instant::now() + Duration::from_secs(400);
    loop {
        assert!(Instant::now() < give_up, "the jobs never finished");
        for (m, k) in tend(&daemon, &mut current).await {
            *finished.entry(m).or_default() += 1;
            if k + 1 < JOBS {
                let j = submit(&daemon, m, k + 1).await;
                current.insert(m, (k + 1, j.id));
            } else {
                current.remove(m);
            }
        }
        if current.is_empty() {
            break;
        }
        if kills >= KILLS {
            tokio::time::sleep(Duration::from_millis(100)).await;
            continue;
        }
        // a random moment, then SIGKILL
        tokio::time::sleep(Duration::from_millis(rng.between(150, 1400))).await;
        let running: Vec<&str> = {
            let c = daemon.client();
            let mut r = Vec::new();
            for (m, (_, id)) in &current {
                if let Ok(j) = c.job(*id).await {
                    if j.state == JobState::Running && j.acked_units > 0 {
                        r.push(*m);
                    }
                }
            }
            r
        };
        daemon.kill();
        kills += 1;
        for m in running {
            *killed_while_running.entry(m).or_default() += 1;
        }
        daemon = Daemon::start(dir.path()).await;
    }
    assert!(kills >= KILLS);
    for m in ["mill", "sewer", "press"] {
        assert_eq!(finished.get(m), Some(&JOBS), "{m} finished all its jobs");
        assert!(
            killed_while_running.get(m).copied().unwrap_or(0) >= 3,
            "{m} was killed under only {:?} times: {killed_while_running:?}",
            killed_while_running.get(m)
        );
    }
    let c = daemon.client();
    let jobs = c.jobs().await.unwrap();
    assert!(jobs.iter().all(|j| j.state == JobState::Completed));

    // GRBL: the program lines it received (the resumes' own lines left out) are every
    // job's lines, each once, in order; the moves it executed are the programs' moves
    for k in 0..JOBS {
        grbl_programs.push(gcode_job("mill", k).1);
    }
    let received: Vec<String> = grbl
        .events()
        .into_iter()
        .filter_map(|e| match e {
            GrblEvent::Received { n: Some(_), line } if !line.contains("(resume)") => Some(line),
            _ => None,
        })
        .collect();
    let want: Vec<String> = grbl_programs.concat();
    assert_eq!(
        received.len(),
        want.len(),
        "lines received by the GRBL controller"
    );
    for (i, (got, want)) in received.iter().zip(&want).enumerate() {
        assert_eq!(got, want, "line {i} the GRBL controller received");
    }
    assert_eq!(grbl.rx_overflows(), 0);

    // Modbus: every block of every job executed once, in order; no block written into
    // the ring again once the device had run it
    for k in 0..JOBS {
        let j = jobs
            .iter()
            .find(|j| j.machine == "press" && j.file_name == format!("press{k}.nc"))
            .unwrap();
        press_blocks.push(j.total_units);
    }
    let events = press.events_from(0);
    let executed: Vec<u32> = events
        .iter()
        .filter_map(|e| match e {
            ModbusEvent::Executed { seq, .. } => Some(*seq),
            _ => None,
        })
        .collect();
    let want: Vec<u32> = press_blocks.iter().flat_map(|&n| 1..=n as u32).collect();
    assert_eq!(executed, want, "blocks the Modbus device executed");
    let resent: Vec<_> = events
        .iter()
        .filter(|e| matches!(e, ModbusEvent::Written { seq, consumed } if seq <= consumed))
        .collect();
    assert!(
        resent.is_empty(),
        "blocks written again after they ran: {resent:?}"
    );

    // sewing: every record of every job sewn once, in order; no pattern uploaded again
    // once the machine had started sewing it
    for k in 0..JOBS {
        let j = jobs
            .iter()
            .find(|j| j.machine == "sewer" && j.file_name == format!("zigzag{k}.json"))
            .unwrap();
        sewer_records.push(j.total_units);
    }
    let lines = sewer.trace.lock().unwrap().lines.clone();
    let sewn: Vec<u32> = lines
        .iter()
        .filter_map(|l| match l {
            TraceLine::Record { index, .. } => Some(*index),
            _ => None,
        })
        .collect();
    let want: Vec<u32> = sewer_records.iter().flat_map(|&n| 0..n as u32).collect();
    assert_eq!(sewn, want, "records the sewing machine executed");
    // an upload only ever comes before a job's first stitch (or after the last record of
    // the job before): never in the middle of one
    let mut last_record: Option<u32> = None;
    for l in &lines {
        match l {
            TraceLine::Record { index, .. } => last_record = Some(*index),
            TraceLine::Note { text } if text.starts_with("upload begun") => {
                if let Some(i) = last_record {
                    assert!(
                        sewer_records.iter().any(|&n| i + 1 == n as u32),
                        "the pattern was uploaded again after record {i}"
                    );
                }
            }
            _ => {}
        }
    }
    let sewing_started = last_record.is_some();
    assert!(sewing_started);
    let resumes = grbl
        .events()
        .iter()
        .filter(|e| matches!(e, GrblEvent::Received { line, .. } if line.starts_with("G0 X") && line.contains("(resume)")))
        .count();
    let syncs = events
        .iter()
        .filter(|e| matches!(e, ModbusEvent::Synced { .. }))
        .count();
    let uploads = lines
        .iter()
        .filter(|l| matches!(l, TraceLine::Note { text } if text.starts_with("upload begun")))
        .count();
    eprintln!(
        "{kills} kills; killed while running: {killed_while_running:?}; GRBL repositioned {resumes} times, \
         the Modbus device was synced {syncs} times and the sewing machine got {uploads} uploads for {JOBS} jobs each"
    );
    drop(daemon);
}
