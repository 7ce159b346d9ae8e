//! `resume JOB --from-line N` after a cancel, on the simulated GRBL: the machine is brought
//! back (retract, modes and work offset, spindle, rapid over the start, plunge) and from
//! line N on it runs exactly the planned path, an arc entered at its true start; no
//! cutting move starts away from the planned path. A profile with arcs, a pocket, and a
//! G-code file in work offset G55.

use crate::common;

use common::*;
use machlink::core::intake::{JobSpec, Operation};
use machlink::core::store::JobState;
use machlink_sim::grbl::interp::{clean_line, Action, Interpreter, Motion};
use machlink_sim::grbl::{GrblSim, GrblSimConfig};
use offset_core::ops::{Cutting, PocketParams, ProfileParams, Side};
use offset_core::toolpath::Tool;
use std::time::Duration;

/// A rounded rectangle, 70 × 50 mm with 10 mm corner arcs.
const ROUNDED: &str = r#"{ "units": "mm", "paths": [ { "closed": true, "vertices": [
  [10,0,0],[60,0,0.41421356],[70,10,0],[70,40,0.41421356],[60,50,0],[10,50,0.41421356],[0,40,0],[0,10,0.41421356] ] } ] }"#;

/// G55's zero on the simulated machine.
const G55: [f64; 3] = [20.0, 10.0, 0.0];

fn offsets() -> [[f64; 3]; 6] {
    let mut o = [[0.0; 3]; 6];
    o[1] = G55;
    o
}

fn cutting() -> Cutting {
    Cutting {
        tool: Tool::flat(3.0),
        depth: 2.0,
        stepdown: 1.0,
        ..Default::default()
    }
}

/// One planned move: its line, motion, start, end and arc centre (machine coordinates).
type Planned = (String, Motion, [f64; 3], [f64; 3], Option<[f64; 2]>);

/// The moves lines `from..` make on a machine with `offsets`, after the lines before.
fn planned_from(lines: &[String], from: usize) -> Vec<Planned> {
    let mut i = Interpreter::new();
    i.offsets = offsets();
    let mut out = Vec::new();
    for (k, l) in lines.iter().enumerate() {
        let clean = clean_line(l);
        for a in i.execute(&clean).expect("valid G-code") {
            if let (
                true,
                Action::Move {
                    motion,
                    from,
                    to,
                    center,
                    ..
                },
            ) = (k >= from, a)
            {
                out.push((clean.clone(), motion, from, to, center));
            }
        }
    }
    out
}

fn near(a: [f64; 3], b: [f64; 3]) -> bool {
    (0..3).all(|k| (a[k] - b[k]).abs() < 1e-6)
}

/// Runs `spec` on a simulated GRBL (G55 offset set), cancels it once it has cut a few
/// moves, resumes it from its first arc line at or after line `at` and checks the path.
async fn resume_at_an_arc(spec: JobSpec, at: usize) {
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("grbl0");
    let sim = GrblSim::spawn_linked(
        GrblSimConfig {
            time_scale: 50.0,
            work_offsets: offsets(),
            ..Default::default()
        },
        &port,
    )
    .unwrap();
    let d = start(
        dir.path(),
        &format!("{}spindle_dwell_s = 0.5\n", machine_on(&port)),
        machlink::daemon::StartOptions::default(),
    )
    .await;
    let c = client(&d);
    let job = c.submit(&spec).await.expect("submitted");
    let lines = stored::<String>(&d, job.id);
    // let it cut a little, then stop it the way an operator would
    for _ in 0..3000 {
        if sim.trace().len() >= 4 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert!(sim.trace().len() >= 4, "the job never started cutting");
    let stopped = c.act(job.id, "cancel").await.unwrap();
    assert_eq!(stopped.state, JobState::Cancelled);
    let stood = sim.position();
    let n = (at..lines.len())
        .find(|&k| lines[k].starts_with("G2") || lines[k].starts_with("G3"))
        .expect("an arc line to resume at");
    // the daemon shows what it will do first
    let p = c.resume_preview(job.id, Some(n + 1)).await.unwrap();
    assert!(p.moves, "{p:?}");
    assert!(
        p.steps.iter().any(|s| s.contains("retract"))
            && p.steps.iter().any(|s| s.contains("plunge")),
        "{:?}",
        p.steps
    );
    let j = c.resume_from_line(job.id, n + 1).await.unwrap();
    assert_ne!(j.state, JobState::Cancelled);
    let done = wait_end(&c, job.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);

    let resume = resume_lines(&sim);
    assert!(!resume.is_empty(), "the resume sent its lines");
    let last_resume = *resume.iter().max().unwrap();
    let trace = sim.trace();
    let want = planned_from(&lines, n);
    let start = want[0].2;
    // the machine did not stand at the arc's start: the resume had to bring it there
    assert!(
        !near(stood, start),
        "the tool stood at the resume point already"
    );
    // from line N on, the machine ran exactly the planned moves
    let ran: Vec<_> = trace.iter().filter(|e| e.index > last_resume).collect();
    assert_eq!(ran.len(), want.len(), "moves run after the resume");
    for (e, (line, motion, from, to, center)) in ran.iter().zip(&want) {
        assert_eq!(&e.line, line);
        assert_eq!(e.motion, *motion, "{line}");
        assert!(
            near(e.from, *from),
            "{line} starts at {:?}, planned {from:?}",
            e.from
        );
        assert!(near(e.to, *to), "{line} ends at {:?}, planned {to:?}", e.to);
        match (e.center, center) {
            (Some(a), Some(b)) => assert!((a[0] - b[0]).abs() < 1e-6 && (a[1] - b[1]).abs() < 1e-6),
            (None, None) => {}
            other => panic!("{line}: centres {other:?}"),
        }
    }
    assert!(matches!(want[0].1, Motion::ArcCw | Motion::ArcCcw));
    // the resume's own cutting moves: one plunge, straight down onto the arc's start
    let back: Vec<_> = trace
        .iter()
        .filter(|e| resume.contains(&e.index) && e.motion != Motion::Rapid)
        .collect();
    assert_eq!(back.len(), 1, "one plunge: {back:?}");
    let plunge = back[0];
    assert!(
        near(plunge.to, start),
        "the plunge ends at {:?}, not {start:?}",
        plunge.to
    );
    assert!(
        (plunge.from[0] - start[0]).abs() < 1e-6
            && (plunge.from[1] - start[1]).abs() < 1e-6
            && plunge.from[2] > start[2],
        "the plunge starts at {:?}, not above {start:?}",
        plunge.from
    );
    // the rapids of the resume end above the start point, at the program's highest Z or higher
    let rapids: Vec<_> = trace
        .iter()
        .filter(|e| resume.contains(&e.index) && e.motion == Motion::Rapid)
        .collect();
    let over = rapids.last().expect("a rapid over the start point");
    assert!((over.to[0] - start[0]).abs() < 1e-6 && (over.to[1] - start[1]).abs() < 1e-6);
    assert_eq!(sim.rx_overflows(), 0);
}

fn shape_job(op: Operation) -> JobSpec {
    JobSpec {
        operation: Some(op),
        ..job("mill", "rounded.json", ROUNDED)
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn resume_from_an_arc_of_a_profile_runs_the_planned_path_from_its_true_start() {
    let spec = shape_job(Operation::Profile(ProfileParams {
        side: Side::Outside,
        cut: cutting(),
        ..Default::default()
    }));
    resume_at_an_arc(spec, 12).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn resume_from_an_arc_of_a_pocket_runs_the_planned_path_from_its_true_start() {
    let spec = shape_job(Operation::Pocket(PocketParams {
        cut: cutting(),
        ..Default::default()
    }));
    resume_at_an_arc(spec, 20).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn resume_from_an_arc_of_a_gcode_file_in_g55_restores_the_work_offset() {
    let text = "G21 G90 G17 G94\nG55\nG0 Z5\nM3 S10000\nG0 X0 Y0\nG1 Z-1 F200\n\
                G1 X30 F800\nG2 X40 Y10 I0 J10\nG1 Y30\nG3 X30 Y40 I-10 J0\nG1 X0\nG1 Y0\n\
                G1 Z-2 F200\nG1 X30 F800\nG2 X40 Y10 I0 J10\nG1 Y30\nG3 X30 Y40 I-10 J0\n\
                G1 X0\nG1 Y0\nG0 Z5\nM5\nM2\n";
    resume_at_an_arc(job("mill", "frame.nc", text), 13).await;
}
