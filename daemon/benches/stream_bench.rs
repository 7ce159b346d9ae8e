//! GRBL streaming throughput: character counting against plain send-and-wait, through the
//! simulated GRBL on a pty paced at 115200 baud, with motion that finishes at once (the
//! planner never fills), so the serial line is the only limit; and the same program as a
//! job through the daemon's scheduler with its exact journal (every write journaled before
//! and after, every acknowledgement; SQLite WAL, synchronous NORMAL). Same run, same program.
//!
//! `cargo bench -p machlink-sim --bench stream_bench`

use machlink_protocols::gcode::{post, GcodeOptions};
use machlink_protocols::grbl::{GrblLink, GrblOptions};
use machlink_protocols::{Control, Link, LinkEvent, StreamEnd};
use machlink_sim::grbl::{GrblSim, GrblSimConfig};
use offset_core::{Move, Point, Toolpath, P3};
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};

const BAUD: u32 = 115_200;
const LINES: usize = 2000;

/// A posted program: a serpentine of short feed moves with half-circle turns and a
/// helical plunge at each row, the mix a profile or pocket post makes.
fn program() -> Vec<String> {
    let mut tp = Toolpath::new("bench serpentine");
    tp.push(Move::Rapid {
        to: P3::new(0.0, 0.0, 5.0),
    });
    tp.push(Move::Linear {
        to: P3::new(0.0, 0.0, 0.0),
        feed: 300.0,
    });
    let mut y = 0.0;
    let mut row = 0;
    while tp.moves.len() < LINES {
        let dir = if row % 2 == 0 { 1.0 } else { -1.0 };
        let x0 = if row % 2 == 0 { 0.0 } else { 60.0 };
        for k in 1..=30 {
            let x = x0 + dir * k as f64 * 2.0;
            let z = -0.5 - 0.013 * (k % 7) as f64;
            tp.push(Move::Linear {
                to: P3::new(x, y, z),
                feed: 1200.0 + (k % 3) as f64 * 100.0,
            });
        }
        let xe = x0 + dir * 60.0;
        tp.push(Move::Arc {
            to: P3::new(xe, y + 3.0, -0.5),
            center: Point::new(xe, y + 1.5),
            ccw: row % 2 == 0,
            feed: 900.0,
        });
        y += 3.0;
        row += 1;
    }
    match post(&tp, &GcodeOptions::default()).expect("the bench path posts") {
        lines => lines,
        #[allow(unreachable_patterns)]
        _ => unreachable!("a G-code post"),
    }
}

fn bytes(lines: &[String]) -> usize {
    lines.iter().map(|l| l.len() + 1).sum()
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let sim = GrblSim::spawn_pty(GrblSimConfig {
        time_scale: f64::INFINITY,
        baud: Some(BAUD),
        ..Default::default()
    })
    .expect("the simulator starts");
    let opts = GrblOptions {
        baud: BAUD,
        ..Default::default()
    };
    let mut link = GrblLink::open(sim.port().to_str().unwrap(), opts)
        .await
        .expect("the link opens");
    let lines = program();
    let total_bytes = bytes(&lines);
    let capacity = BAUD as f64 / 10.0;

    // character counting
    let program = lines.clone();
    let (etx, mut erx) = mpsc::unbounded_channel();
    let (_ctx, crx) = watch::channel(Control::Run);
    let start = Instant::now();
    let last_ack = tokio::spawn(async move {
        let mut last = start;
        while let Some(ev) = erx.recv().await {
            if let LinkEvent::Acked { .. } = ev {
                last = Instant::now();
            }
        }
        last
    });
    let end = link
        .stream(&program, 0, etx, crx)
        .await
        .expect("the stream runs");
    let done = start.elapsed();
    assert_eq!(end, StreamEnd::Completed);
    let acked = last_ack.await.unwrap().duration_since(start);

    // send and wait, one line at a time
    let start = Instant::now();
    for l in &lines {
        link.send_setting(l).await.expect("each line is accepted");
    }
    let saw = start.elapsed();
    assert_eq!(sim.rx_overflows(), 0);
    drop(link);

    // the same program as a job through the daemon: scheduler, store and exact journal
    let (journaled, commits) = through_the_daemon(&sim.port(), &lines).await;
    assert_eq!(sim.rx_overflows(), 0);

    let row = |name: &str, t: Duration| {
        let s = t.as_secs_f64();
        let bps = total_bytes as f64 / s;
        println!(
            "| {name} | {} lines, {total_bytes} bytes | {:.2} s | {:.0} lines/s | {:.0} bytes/s | {:.1} % |",
            lines.len(),
            s,
            lines.len() as f64 / s,
            bps,
            100.0 * bps / capacity
        );
    };
    println!("GRBL streaming at {BAUD} baud ({capacity:.0} bytes/s), planner never full");
    println!("| method | program | time | lines/s | bytes/s | of the line's capacity |");
    println!("|---|---|---|---|---|---|");
    row("character counting (to the last ok)", acked);
    row("character counting (to Idle)", done);
    row(
        "character counting through the daemon, exact journal (to the last ok)",
        journaled,
    );
    row("send and wait", saw);
    println!(
        "the daemon's journal: {commits} writes for {} lines ({:.1} a line: each write of lines \
         recorded before and after in the progress file, acknowledgements carried with them)",
        lines.len(),
        commits as f64 / lines.len() as f64
    );
    println!(
        "counting is {:.2}x send-and-wait",
        saw.as_secs_f64() / acked.as_secs_f64()
    );
    sim.shutdown();
}

/// Runs `lines` as a job on a `grbl` machine on `port` through the daemon's scheduler, its
/// SQLite store in a temporary folder; returns the time from the job's start to its last
/// acknowledged line, and how many journal commits the store made for it.
async fn through_the_daemon(port: &std::path::Path, lines: &[String]) -> (Duration, u64) {
    use machlink::core::machine::MachineConfig;
    use machlink::core::scheduler::{Event, JournalPolicy, MachineSetup, Scheduler};
    use machlink::core::store::{JobState, NewJob, Store};
    use machlink_protocols::Program;
    let dir = tempfile::tempdir().expect("a temporary folder");
    let path = dir.path().join("bench.db");
    let store = Store::open(&path).expect("the store opens");
    let registry = machlink::core::registry::standard();
    let config = MachineConfig::new(
        &registry,
        "bench",
        "grbl",
        serde_json::json!({ "port": port.display().to_string(), "baud": BAUD }),
    )
    .expect("a grbl machine");
    let sched = Scheduler::start(
        store,
        vec![MachineSetup {
            config,
            device: std::sync::Arc::new(()),
        }],
        JournalPolicy {
            every: 1,
            max_lag: Duration::from_secs(1),
        },
    )
    .expect("the scheduler starts");
    let job = |name: &str, l: &[String]| NewJob {
        machine: "bench".into(),
        op: "bench".into(),
        file_name: name.into(),
        params: serde_json::json!({}),
        program: Program::new("grbl", l.to_vec()),
    };
    let mut rx = sched.subscribe();
    // a short job first opens the link, as a daemon's first job on a machine does
    let warm = sched.submit(job("warm.nc", &lines[..10])).unwrap().id;
    loop {
        if let Ok(Event::State { job, state, .. }) = rx.recv().await {
            if job == warm && state.is_final() {
                assert_eq!(state, JobState::Completed);
                break;
            }
        }
    }
    let counted = sched.store().commit_count();
    let id = sched.submit(job("bench.nc", lines)).unwrap().id;
    let (mut start, mut last) = (None, None);
    loop {
        match rx.recv().await {
            Ok(Event::State { job, state, .. }) if job == id => {
                if state == JobState::Running && start.is_none() {
                    start = Some(Instant::now());
                }
                if state.is_final() {
                    assert_eq!(state, JobState::Completed);
                    break;
                }
            }
            Ok(Event::Progress {
                job, acked, total, ..
            }) if job == id && acked == total => last = Some(Instant::now()),
            _ => {}
        }
    }
    let (first, end) = (start.unwrap(), last.unwrap());
    assert_eq!(sched.store().handed(id).unwrap().sent, lines.len());
    let commits = sched.store().commit_count() - counted;
    sched.abort();
    (end.duration_since(first), commits)
}
