//! Nothing moves without the operator: after the daemon is stopped (SIGTERM) and started
//! again, a held machine stays where it is and a queued job waits until the operator
//! resumes the interrupted one; `resume` without a terminal and without `--yes` sends
//! nothing and exits 1; a jog is checked against the work area and `max_feed` and asks
//! before it drags the tool sideways below the stock top; a CANopen drive fault waits for
//! `unlock` like every kind's alarm. Each through the `machlink` binary against simulators
//! that live in this test's process (so they outlive the daemon), checked on their traces.

use crate::proc;

use machlink::core::store::{JobId, JobState};
use machlink_sim::grbl::{GrblSim, GrblSimConfig, TraceEvent as GrblEvent};
use machlink_sim::modbus::{ModbusSim, SimConfig, TraceEvent as ModbusEvent};
use proc::*;
use std::time::{Duration, Instant};

/// The G-code lines a GRBL controller received (its `$` lines left out) and the moves it
/// ran, from event `from` on.
fn grbl_motion_since(events: &[GrblEvent], from: usize) -> Vec<String> {
    events[from..]
        .iter()
        .filter_map(|e| match e {
            GrblEvent::Received { n: Some(_), line } => Some(format!("received {line}")),
            GrblEvent::Executed(x) => Some(format!("executed {x:?}")),
            GrblEvent::Jogged { to } => Some(format!("jogged to {to:?}")),
            _ => None,
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restarted_daemon_leaves_a_held_grbl_machine_still_and_its_queue_waits_for_resume() {
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("grbl0");
    let grbl = GrblSim::spawn_linked(
        GrblSimConfig {
            time_scale: 4.0,
            ..Default::default()
        },
        &port,
    )
    .unwrap();
    write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nport = \"{}\"\nspindle_dwell_s = 0.2\n",
            port.display()
        ),
    );
    let mut daemon = Daemon::start(dir.path()).await;
    let one = serpentine(10, 0.0);
    let two = serpentine(2, 0.5);
    let c = daemon.client();
    let j1 = c
        .submit(&file_job("mill", "one.nc", &one.join("\n")))
        .await
        .unwrap();
    let j2 = c
        .submit(&file_job("mill", "two.nc", &two.join("\n")))
        .await
        .unwrap();
    wait_job(&daemon, j1.id, "running past line 25", |j| {
        j.acked_units >= 25
    })
    .await;
    assert!(daemon.terminate().success(), "{}", daemon.log());
    // the shutdown held the machine; let it come to rest
    tokio::time::sleep(Duration::from_millis(300)).await;
    let at_stop = grbl.events().len();
    let pos_at_stop = grbl.position();

    let daemon = Daemon::start(dir.path()).await;
    let c = daemon.client();
    tokio::time::sleep(Duration::from_secs(4)).await;
    let moved = grbl_motion_since(&grbl.events(), at_stop);
    assert!(
        moved.is_empty(),
        "the restarted daemon moved the machine by itself: {moved:?}\n{}",
        daemon.log()
    );
    assert_eq!(
        grbl.position(),
        pos_at_stop,
        "the tool stands where the stop left it"
    );
    let (s1, s2) = (c.job(j1.id).await.unwrap(), c.job(j2.id).await.unwrap());
    assert_eq!(s1.state, JobState::Interrupted, "{s1:?}");
    assert_eq!(s2.state, JobState::Queued, "{s2:?}");
    assert!(
        s2.note
            .as_deref()
            .unwrap_or("")
            .contains(&format!("holds job {}", j1.id)),
        "the queued job says why it waits: {:?}",
        s2.note
    );

    // no terminal, no --yes: the plan is shown, nothing is sent, exit 1
    let o = cli(dir.path(), &["resume", &j1.id.to_string()]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("nothing was sent"), "{}", stderr(&o));
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert!(grbl_motion_since(&grbl.events(), at_stop).is_empty());

    // the operator's word: job 1 goes on, then job 2 runs; every line once, in order
    let o = cli(dir.path(), &["resume", &j1.id.to_string(), "--yes"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let done = wait_job(&daemon, j1.id, "completed", |j| j.state.is_final()).await;
    assert_eq!(done.state, JobState::Completed, "{done:?}");
    let done = wait_job(&daemon, j2.id, "completed", |j| j.state.is_final()).await;
    assert_eq!(done.state, JobState::Completed, "{done:?}");
    let received: Vec<String> = grbl
        .events()
        .into_iter()
        .filter_map(|e| match e {
            GrblEvent::Received { n: Some(_), line } if !line.contains("(resume)") => Some(line),
            _ => None,
        })
        .collect();
    assert_eq!(
        received,
        [one, two].concat(),
        "every line received once, in order"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn resume_without_a_terminal_or_yes_sends_nothing_to_a_modbus_machine_and_exits_1() {
    let dir = tempfile::tempdir().unwrap();
    let press = ModbusSim::spawn_tcp(
        SimConfig {
            time_scale: 2.0,
            ..Default::default()
        },
        "127.0.0.1:0".parse().unwrap(),
    )
    .await
    .unwrap();
    write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"press\"\nlink = \"modbus-tcp\"\nhost = \"127.0.0.1\"\nport = {}\ntimeout_ms = 300\n",
            press.addr().port()
        ),
    );
    let mut daemon = Daemon::start(dir.path()).await;
    let lines = serpentine(10, 0.0);
    let j = daemon
        .client()
        .submit(&file_job("press", "press.nc", &lines.join("\n")))
        .await
        .unwrap();
    wait_job(&daemon, j.id, "running past block 5", |j| {
        j.acked_units >= 5
    })
    .await;
    assert!(daemon.terminate().success(), "{}", daemon.log());
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (_, _, consumed, _) = press.registers();
    let at_stop = press.events_from(0).len();

    let daemon = Daemon::start(dir.path()).await;
    let stopped = daemon.client().job(j.id).await.unwrap();
    assert_eq!(stopped.state, JobState::Interrupted);
    assert_eq!(
        stopped.acked_units, consumed as usize,
        "the store says where the machine is"
    );
    let o = cli(dir.path(), &["resume", &j.id.to_string()]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(err.contains("nothing was sent"), "{err}");
    assert!(
        err.contains(&format!("line {} of {}", consumed + 1, j.total_units)),
        "the plan names the real resume point: {err}"
    );
    tokio::time::sleep(Duration::from_secs(2)).await;
    let after: Vec<ModbusEvent> = press.events_from(at_stop);
    assert!(
        !after
            .iter()
            .any(|e| matches!(e, ModbusEvent::Executed { .. })),
        "the machine moved: {after:?}"
    );
    assert_eq!(press.registers().2, consumed);
    assert_eq!(
        daemon.client().job(j.id).await.unwrap().state,
        JobState::Interrupted
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_jog_is_checked_against_the_work_area_and_max_feed_and_asks_below_the_stock_top() {
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("grbl0");
    let grbl = GrblSim::spawn_linked(
        GrblSimConfig {
            time_scale: 20.0,
            ..Default::default()
        },
        &port,
    )
    .unwrap();
    write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"router\"\nlink = \"grbl\"\nport = \"{}\"\nmax_feed = 3000\n\
             work_area = {{ min = [0, 0, -50], max = [300, 200, 50] }}\n",
            port.display()
        ),
    );
    let _daemon = Daemon::start(dir.path()).await;
    let jogs = |g: &machlink_sim::grbl::GrblSimHandle| {
        g.events()
            .iter()
            .filter(|e| matches!(e, GrblEvent::Jogged { .. }))
            .count()
    };

    let o = cli(
        dir.path(),
        &["jog", "router", "--x", "1000", "--feed", "500"],
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("outside machine `router`'s work area (X 0 to 300)"),
        "{}",
        stderr(&o)
    );
    let o = cli(
        dir.path(),
        &["jog", "router", "--x", "10", "--feed", "9000"],
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("3000 mm/min"), "{}", stderr(&o));
    assert_eq!(jogs(&grbl), 0, "a refused jog moves nothing");

    // the tool goes into the stock (as a cancel may leave it); sideways then asks first
    let o = cli(dir.path(), &["jog", "router", "--z", "-2", "--feed", "300"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = cli(dir.path(), &["jog", "router", "--x", "5", "--feed", "300"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("below the stock top"), "{}", stderr(&o));
    assert_eq!(jogs(&grbl), 1);
    let o = cli(
        dir.path(),
        &["jog", "router", "--x", "5", "--feed", "300", "--yes"],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(jogs(&grbl), 2);
    let p = grbl.position();
    assert!(
        (p[0] - 5.0).abs() < 1e-6 && (p[2] + 2.0).abs() < 1e-6,
        "{p:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_canopen_drive_fault_waits_for_unlock_before_the_next_job_runs() {
    let dir = tempfile::tempdir().unwrap();
    write_config(
        dir.path(),
        "[[machine]]\nname = \"gantry\"\nlink = \"sim-canopen\"\n\
         period_ms = 2\nheartbeat_ms = 50\nheartbeat_timeout_ms = 1500\nreport_timeout_ms = 2000\n\
         faults = [ { node = 2, fault = \"following_error\", after_syncs = 300 } ]\n\
         axes = [\n  { axis = \"x\", node = 1, counts_per_mm = 1000, max_velocity = 60, max_acceleration = 800, max_jerk = 20000 },\n  \
         { axis = \"y\", node = 2, counts_per_mm = 1000, max_velocity = 50, max_acceleration = 600, max_jerk = 20000 },\n  \
         { axis = \"z\", node = 3, counts_per_mm = 1000, max_velocity = 15, max_acceleration = 400, max_jerk = 20000 },\n]\n",
    );
    let daemon = Daemon::start(dir.path()).await;
    let c = daemon.client();
    let program =
        "G21 G90\nG0 Z3\nG0 X0 Y0\nG1 Z-1 F400\nG1 X24 F1800\nG1 Y16\nG1 X0\nG1 Y0\nG0 Z3\n";
    let first = c
        .submit(&file_job("gantry", "plate.nc", program))
        .await
        .unwrap();
    let failed = wait_job(&daemon, first.id, "ended", |j| j.state.is_final()).await;
    assert_eq!(failed.state, JobState::Failed, "{failed:?}");
    // the alarm waits for the operator: the next job is refused, nothing cleared by itself
    let next = c
        .submit(&file_job("gantry", "plate.nc", program))
        .await
        .unwrap();
    let refused = wait_job(&daemon, next.id, "ended", |j| j.state.is_final()).await;
    assert_eq!(refused.state, JobState::Failed, "{refused:?}");
    let e = refused.error.unwrap_or_default();
    assert!(
        e.contains("in fault from before this job") && e.contains("unlock"),
        "{e}"
    );
    let o = cli(dir.path(), &["unlock", "gantry"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let after = c
        .submit(&file_job("gantry", "plate.nc", program))
        .await
        .unwrap();
    let done = wait_job(&daemon, after.id, "ended", |j| j.state.is_final()).await;
    assert_eq!(done.state, JobState::Completed, "{done:?}");
}

/// How far each simulated machine has moved: a number that grows with every motion it
/// makes (lines and moves run, blocks executed, needle drops, set-points that moved a
/// drive), read from its own trace.
struct Cell {
    grbl: machlink_sim::grbl::GrblSimHandle,
    press: ModbusSim,
    sewer: machlink_sim::sewing::SewingSim,
    drives: machlink_sim::canopen::SimDrives,
    _adapter: machlink_sim::canopen::adapter::AdapterHandle,
}

impl Cell {
    /// Each machine's motion so far, by name.
    fn motion(&self) -> [(&'static str, u64); 4] {
        let grbl = self
            .grbl
            .events()
            .iter()
            .filter(|e| matches!(e, GrblEvent::Executed(_) | GrblEvent::Jogged { .. }))
            .count() as u64;
        let press = self
            .press
            .events_from(0)
            .iter()
            .filter(|e| matches!(e, ModbusEvent::Executed { .. }))
            .count() as u64;
        let sewer = self.sewer.trace.lock().unwrap().drops.len() as u64;
        let mut moved = 0u64;
        for node in self.drives.nodes() {
            let t = self.drives.trace(node);
            moved += t
                .windows(2)
                .filter(|w| (w[1].actual - w[0].actual).abs() > 0.5)
                .count() as u64;
        }
        [
            ("mill", grbl),
            ("press", press),
            ("sewer", sewer),
            ("gantry", moved),
        ]
    }

    /// Waits (bounded) until no machine has moved for `quiet`: what a killed daemon left
    /// them (a GRBL runs the lines it holds, a sewing machine the pattern) has run out.
    async fn settle(&self, quiet: Duration) {
        let until = Instant::now() + Duration::from_secs(60);
        let mut last = self.motion();
        let mut still_since = Instant::now();
        while Instant::now() < until {
            tokio::time::sleep(Duration::from_millis(50)).await;
            let now = self.motion();
            if now != last {
                last = now;
                still_since = Instant::now();
            } else if still_since.elapsed() >= quiet {
                return;
            }
        }
        panic!("the machines never came to rest: {last:?}");
    }
}

/// A sewing job: an open zigzag of `rows` rows across the frame.
fn zigzag(rows: usize) -> machlink::core::intake::JobSpec {
    let shape = crate::common::sewing::zigzag_seam(rows, -60.0, 7.0, 110.0);
    machlink::core::intake::JobSpec {
        operation: Some(machlink::core::intake::Operation::Stitch(
            offset_core::stitch::StitchParams {
                stitch_length: 2.5,
                ..Default::default()
            },
        )),
        ..file_job("sewer", &format!("zigzag{rows}.json"), &shape)
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stops_at_random_moments_move_no_machine_until_the_operator_resumes() {
    let seed = std::env::var("MACHLINK_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| {
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap()
                .as_nanos() as u64
                | 1
        });
    eprintln!("seed {seed} (MACHLINK_SEED={seed} repeats this run)");
    let mut rng = Rng(seed);
    const STOPS: usize = 4;

    let dir = tempfile::tempdir().unwrap();
    let grbl_port = dir.path().join("grbl0");
    let bus = machlink_protocols::canopen::MemoryBus::new();
    let cell = Cell {
        grbl: GrblSim::spawn_linked(
            GrblSimConfig {
                time_scale: 6.0,
                ..Default::default()
            },
            &grbl_port,
        )
        .unwrap(),
        press: ModbusSim::spawn_tcp(
            SimConfig {
                time_scale: 6.0,
                ..Default::default()
            },
            "127.0.0.1:0".parse().unwrap(),
        )
        .await
        .unwrap(),
        sewer: machlink_sim::sewing::spawn_on_pty(machlink_sim::sewing::SewingSimConfig {
            time_scale: 3.0,
            spm: 3000,
            ..Default::default()
        })
        .unwrap(),
        drives: machlink_sim::canopen::SimDrives::spawn(&bus, &[1, 2, 3], 1.0),
        _adapter: machlink_sim::canopen::spawn_adapter(&bus).unwrap(),
    };
    write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nport = \"{}\"\nspindle_dwell_s = 0.2\n\n\
             [[machine]]\nname = \"press\"\nlink = \"modbus-tcp\"\nhost = \"127.0.0.1\"\nport = {}\ntimeout_ms = 300\n\n\
             [[machine]]\nname = \"sewer\"\nlink = \"sewing\"\nport = \"{}\"\n\n\
             [[machine]]\nname = \"gantry\"\nlink = \"canopen\"\nbus = \"slcan:{}\"\n\
             period_ms = 2\nheartbeat_ms = 50\nheartbeat_timeout_ms = 1500\nreport_timeout_ms = 2000\n\
             axes = [\n  {{ axis = \"x\", node = 1, counts_per_mm = 1000, max_velocity = 60, max_acceleration = 800, max_jerk = 20000 }},\n  \
             {{ axis = \"y\", node = 2, counts_per_mm = 1000, max_velocity = 50, max_acceleration = 600, max_jerk = 20000 }},\n  \
             {{ axis = \"z\", node = 3, counts_per_mm = 1000, max_velocity = 15, max_acceleration = 400, max_jerk = 20000 }},\n]\n",
            grbl_port.display(),
            cell.press.addr().port(),
            cell.sewer.path,
            cell._adapter.path,
        ),
    );
    let mut daemon = Daemon::start(dir.path()).await;
    // per machine a long job running and a short one queued behind it
    let mut jobs: Vec<(&str, JobId)> = Vec::new();
    {
        let c = daemon.client();
        for (m, long, short) in [
            ("mill", serpentine(12, 0.0), serpentine(2, 0.5)),
            ("press", serpentine(12, 0.0), serpentine(2, 0.5)),
            ("gantry", serpentine(3, 0.0), serpentine(1, 0.5)),
        ] {
            for (k, lines) in [long, short].into_iter().enumerate() {
                let j = c
                    .submit(&file_job(m, &format!("{m}{k}.nc"), &lines.join("\n")))
                    .await
                    .unwrap_or_else(|e| panic!("{m}: {e}\n{}", daemon.log()));
                jobs.push((m, j.id));
            }
        }
        for rows in [10, 2] {
            jobs.push(("sewer", c.submit(&zigzag(rows)).await.unwrap().id));
        }
    }

    let mut checked = 0;
    for stop in 0..STOPS {
        tokio::time::sleep(Duration::from_millis(rng.between(300, 1500))).await;
        let sigterm = rng.next().is_multiple_of(2);
        if sigterm {
            assert!(daemon.terminate().success(), "{}", daemon.log());
        } else {
            daemon.kill();
        }
        // what the stop left running on its own runs out first (a GRBL's buffer, a
        // sewing machine's pattern, a ring's blocks)
        cell.settle(Duration::from_millis(600)).await;
        let before = cell.motion();
        daemon = Daemon::start(dir.path()).await;
        tokio::time::sleep(Duration::from_millis(2500)).await;
        let after = cell.motion();
        let c = daemon.client();
        let all = c.jobs().await.unwrap();
        for (i, (m, was)) in before.iter().enumerate() {
            let stopped = all.iter().any(|j| {
                j.machine == *m && matches!(j.state, JobState::Interrupted | JobState::Paused)
            });
            if stopped {
                checked += 1;
                assert_eq!(
                    after[i].1, *was,
                    "stop {stop} ({}): machine `{m}` moved before the operator's resume; seed {seed}\n{}",
                    if sigterm { "SIGTERM" } else { "SIGKILL" },
                    daemon.log()
                );
            }
        }
        // the operator resumes every stopped job
        for j in &all {
            if matches!(j.state, JobState::Interrupted | JobState::Paused) {
                let _ = c.act(j.id, "resume").await;
            }
        }
    }
    assert!(
        checked >= STOPS,
        "only {checked} machines were found stopped; seed {seed}"
    );
    // every job ends, completed, once the operator has resumed what stopped
    let until = Instant::now() + Duration::from_secs(240);
    loop {
        let all = daemon.client().jobs().await.unwrap();
        if all.iter().all(|j| j.state == JobState::Completed) {
            break;
        }
        for j in &all {
            assert!(
                !matches!(j.state, JobState::Failed | JobState::Cancelled),
                "job {} on {} ended {}: {:?}; seed {seed}\n{}",
                j.id,
                j.machine,
                j.state,
                j.error,
                daemon.log()
            );
            if j.state == JobState::Interrupted {
                let _ = daemon.client().act(j.id, "resume").await;
            }
        }
        assert!(
            Instant::now() < until,
            "the jobs never completed: {all:?}; seed {seed}\n{}",
            daemon.log()
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let _ = jobs;
}
