//! The daemon streams jobs to a simulated GRBL: every line once, in order, no overflow;
//! device errors and alarms fail one job, never the daemon.

use crate::common;

use common::*;
use machlink::core::store::JobState;
use machlink_sim::grbl::{GrblFault, GrblSimConfig};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_long_job_runs_every_line_exactly_once_in_order() {
    let (sim, _dir, d, c) = grbl_cell(GrblSimConfig {
        time_scale: 400.0,
        ..Default::default()
    })
    .await;
    let lines = zigzag(2400);
    let job = submit_gcode(&c, "mill", "zigzag", &lines).await;
    assert_eq!(job.total_units, 2400);
    let done = wait_end(&c, job.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
    assert_eq!(done.acked_units, 2400);
    // what the store kept is what was sent, and what the machine ran
    assert_eq!(stored::<String>(&d, job.id), lines);
    let executed: Vec<String> = sim.trace().into_iter().map(|e| e.line).collect();
    assert_eq!(executed, expected_motion(&lines));
    assert_eq!(sim.received_lines(), 2400);
    assert_eq!(sim.rx_overflows(), 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_error_fails_the_job_naming_the_line_and_the_next_job_completes() {
    let (sim, _dir, _d, c) = grbl_cell(GrblSimConfig {
        time_scale: 400.0,
        faults: vec![GrblFault::ErrorAtLine {
            line: 150,
            code: 33,
        }],
        ..Default::default()
    })
    .await;
    let first = zigzag(400);
    let a = submit_gcode(&c, "mill", "first", &first).await;
    let second = zigzag(300);
    let b = submit_gcode(&c, "mill", "second", &second).await;
    let a = wait_end(&c, a.id).await;
    assert_eq!(a.state, JobState::Failed);
    let msg = a.error.unwrap();
    assert!(
        msg.contains("line 150") && msg.contains(&first[149]),
        "{msg}"
    );
    assert!(msg.contains("error:33"), "{msg}");
    assert_eq!(a.acked_units, 149);
    let b = wait_end(&c, b.id).await;
    assert_eq!(b.state, JobState::Completed, "{:?}", b.error);
    // the second job ran whole, after what the first got to run
    let executed: Vec<String> = sim.trace().into_iter().map(|e| e.line).collect();
    let want = expected_motion(&second);
    assert_eq!(executed[executed.len() - want.len()..], want[..]);
    // Of the first job, the rejected line did not move. GRBL goes on with the lines behind
    // it in its receive buffer until the link's feed hold and reset reach it (as the real
    // controller does), so a later line may have moved only if it was within the buffer
    // when the error came, the rejected line first; the reset drops what the planner still
    // held, acknowledged or not, so what moved is a prefix of those lines.
    let rx = GrblSimConfig::default().rx_buffer;
    let mut bytes = first[149].len() + 1;
    let buffered = first[150..]
        .iter()
        .take_while(|l| {
            bytes += l.len() + 1;
            bytes <= rx
        })
        .count();
    let may_move: Vec<String> = first[..149]
        .iter()
        .chain(&first[150..150 + buffered])
        .cloned()
        .collect();
    let moved = &executed[..executed.len() - want.len()];
    assert!(
        expected_motion(&may_move).starts_with(moved),
        "the first job moved {} lines: {:?}",
        moved.len(),
        &moved[moved.len().saturating_sub(5)..]
    );
    assert_eq!(sim.rx_overflows(), 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_alarm_fails_the_job_naming_the_line_and_after_unlock_the_next_job_completes() {
    let (sim, _dir, _d, c) = grbl_cell(GrblSimConfig {
        time_scale: 400.0,
        faults: vec![GrblFault::AlarmAtLine { line: 120, code: 1 }],
        ..Default::default()
    })
    .await;
    let first = zigzag(400);
    let a = submit_gcode(&c, "mill", "first", &first).await;
    let a = wait_end(&c, a.id).await;
    assert_eq!(a.state, JobState::Failed);
    let msg = a.error.unwrap();
    assert!(
        msg.contains("ALARM:1") && msg.contains("line 120") && msg.contains(&first[119]),
        "{msg}"
    );
    // a real link does not unlock by itself (auto_unlock is off): the next job is refused
    // before anything moves, saying what to do
    let second = zigzag(300);
    let b = submit_gcode(&c, "mill", "second", &second).await;
    let b = wait_end(&c, b.id).await;
    assert_eq!(b.state, JobState::Failed);
    assert!(
        b.error.as_deref().unwrap().contains("machlink unlock"),
        "{:?}",
        b.error
    );
    // the operator clears it, and the daemon goes on
    let said = c
        .operate("mill", &machlink_protocols::Operation::Unlock)
        .await
        .unwrap();
    assert!(said.said.contains("unlocked"), "{}", said.said);
    let b = submit_gcode(&c, "mill", "second", &second).await;
    let b = wait_end(&c, b.id).await;
    assert_eq!(b.state, JobState::Completed, "{:?}", b.error);
    let executed: Vec<String> = sim.trace().into_iter().map(|e| e.line).collect();
    let want = expected_motion(&second);
    assert_eq!(executed[executed.len() - want.len()..], want[..]);
    assert_eq!(sim.rx_overflows(), 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_planned_shape_job_runs_whole_and_follows_the_planned_path() {
    // a dense open zig-zag of 2,100 vertices (sharp corners: no arc fits it, so it stays
    // 2,100 lines), profiled on the line: the daemon plans and posts it, and the machine
    // must run every line of that program
    let vertices: Vec<[f64; 3]> = (0..2100)
        .map(|i| {
            let x = i as f64 * 0.05;
            [x, 20.0 + 0.5 * (i % 2) as f64, 0.0]
        })
        .collect();
    let shape = serde_json::json!({ "units": "mm", "paths": [ { "closed": false, "vertices": vertices } ] });
    let (sim, _dir, d, c) = grbl_cell(GrblSimConfig {
        time_scale: 1000.0,
        ..Default::default()
    })
    .await;
    let spec = machlink::core::intake::JobSpec {
        operation: Some(machlink::core::intake::Operation::Profile(
            offset_core::ops::ProfileParams {
                side: offset_core::ops::Side::On,
                cut: offset_core::ops::Cutting {
                    depth: 0.5,
                    stepdown: 0.5,
                    feed: 1200.0,
                    safe_z: 2.0,
                    spindle_rpm: 0.0,
                    ..Default::default()
                },
                ..Default::default()
            },
        )),
        ..job("mill", "wave.json", &shape.to_string())
    };
    let job = c.submit(&spec).await.unwrap();
    assert!(job.total_units >= 2000, "{} lines", job.total_units);
    let done = wait_end(&c, job.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
    let lines: Vec<String> = stored(&d, job.id);
    let trace = sim.trace();
    let executed: Vec<String> = trace.iter().map(|e| e.line.clone()).collect();
    assert_eq!(executed, expected_motion(&lines));
    assert_eq!(sim.received_lines(), lines.len() as u64);
    assert_eq!(sim.rx_overflows(), 0);
    let (part, _) = machlink::core::intake::read_shape(&spec).unwrap();
    let planned = machlink::core::intake::toolpath(&spec, &part).unwrap();
    let dev = machlink_sim::grbl::max_deviation(&planned, &trace);
    assert!(dev < 0.01, "the machine strayed {dev} mm from the plan");
}

/// Three GRBL machines on three ports run a job each at the same time: while the last to
/// start has 100 lines acknowledged, the others are still running (they overlap), and each
/// device ran exactly its own program, every line once and in order (the programs differ,
/// so a line sent to the wrong port shows).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_machines_stream_at_once_and_each_runs_exactly_its_own_program() {
    let names = ["mill", "router", "engraver"];
    let sims: Vec<_> = names
        .iter()
        .map(|_| {
            machlink_sim::grbl::GrblSim::spawn_pty(GrblSimConfig {
                time_scale: 400.0,
                ..Default::default()
            })
            .expect("the simulator starts")
        })
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let machines: String = names
        .iter()
        .zip(&sims)
        .map(|(n, s)| {
            format!(
                "[[machine]]\nname = \"{n}\"\nlink = \"grbl\"\nport = \"{}\"\n\n",
                s.port().display()
            )
        })
        .collect();
    let d = start(dir.path(), &machines, Default::default()).await;
    let c = client(&d);
    // the same zig-zag, 10 mm further in Y on each machine (Y0.5 becomes Y10.5, Y20.5)
    let programs: Vec<Vec<String>> = (0..names.len())
        .map(|k| {
            zigzag(2400)
                .into_iter()
                .map(|l| l.replace('Y', &format!("Y{}", k)))
                .collect()
        })
        .collect();
    let mut ids = Vec::new();
    for (n, lines) in names.iter().zip(&programs) {
        ids.push(submit_gcode(&c, n, &format!("{n}-zigzag"), lines).await.id);
    }
    // overlap: when every job has 100 lines acknowledged, none has ended yet
    for &id in &ids {
        wait_until(&c, id, |r| r.acked_units >= 100).await;
    }
    for &id in &ids {
        let r = c.job(id).await.unwrap();
        assert!(
            !r.state.is_final(),
            "job {id} ended before the others had 100 lines: the machines ran one after another"
        );
    }
    for ((id, sim), lines) in ids.iter().zip(&sims).zip(&programs) {
        let done = wait_end(&c, *id).await;
        assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
        assert_eq!(done.acked_units, 2400);
        let executed: Vec<String> = sim.trace().into_iter().map(|e| e.line).collect();
        assert_eq!(
            executed,
            expected_motion(lines),
            "job {id}: its machine ran another program"
        );
        assert_eq!(sim.received_lines(), 2400);
        assert_eq!(sim.rx_overflows(), 0);
    }
}
