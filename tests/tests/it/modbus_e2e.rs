//! End to end through the daemon: machines configured as `link = "modbus-tcp"` and
//! `link = "modbus-rtu"` run 5,000-block jobs into the simulated device under injected faults,
//! and a daemon crash in the middle of a job leaves the device to run dry (nothing written
//! until the operator's resume), then resumes without losing or repeating a block.

use machlink::config::Config;
use machlink::core::store::{JobRecord, JobState, NewJob};
use machlink::daemon::{Daemon, StartOptions};
use machlink_protocols::modbus::{post_blocks, MotionBlock};
use machlink_protocols::Program;
use machlink_sim::modbus::{Faults, ModbusSim, SimConfig, TraceEvent};
use offset_core::{Move, Point, Toolpath, P3};
use std::path::Path;
use std::time::Duration;

fn job(n: usize) -> Vec<MotionBlock> {
    let mut tp = Toolpath::new("e2e");
    tp.push(Move::Rapid {
        to: P3::new(1.0, 1.0, 5.0),
    });
    for i in 1..n {
        let x = 1.0 + i as f64 * 0.05;
        let to = P3::new(x, 1.0 + (i % 3) as f64 * 0.2, -0.3);
        if i % 5 == 0 {
            tp.push(Move::Arc {
                to,
                center: Point::new(x - 0.025, 1.2),
                ccw: true,
                feed: 900.0,
            });
        } else {
            tp.push(Move::Linear { to, feed: 900.0 });
        }
    }
    post_blocks(&tp).unwrap()
}

fn config(dir: &Path, machine: &str) -> Config {
    let text = format!(
        "[daemon]\nstore = \"{}\"\nsocket = \"{}\"\njournal_every = 50\n\n[[machine]]\nname = \"press\"\n{machine}\ntimeout_ms = 100\npoll_ms = 5\nretries = 8\n",
        dir.join("machlink.db").display(),
        dir.join("machlink.sock").display(),
    );
    Config::parse(&text, &dir.join("cell.toml")).expect("the test config is valid")
}

fn submit(d: &Daemon, blocks: &[MotionBlock]) -> JobRecord {
    d.scheduler
        .submit(NewJob {
            machine: "press".into(),
            op: "profile".into(),
            file_name: "e2e.json".into(),
            params: serde_json::json!({}),
            program: Program::new("modbus", blocks.to_vec()),
        })
        .expect("the job is queued")
}

async fn wait_for(
    d: &Daemon,
    id: machlink::core::store::JobId,
    done: impl Fn(&JobRecord) -> bool,
) -> JobRecord {
    let t = tokio::time::Instant::now();
    loop {
        let j = d.scheduler.job(id).unwrap();
        if done(&j) {
            return j;
        }
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "job {id} stuck: {j:?}"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

fn assert_executed_once_in_order(sim: &ModbusSim, blocks: &[MotionBlock]) {
    let trace = sim.trace();
    assert_eq!(
        trace.len(),
        blocks.len(),
        "executed {} of {}",
        trace.len(),
        blocks.len()
    );
    for (i, (e, b)) in trace.iter().zip(blocks).enumerate() {
        assert_eq!((e.seq as usize, &e.block), (i + 1, b), "block {i}");
    }
}

fn faults() -> Faults {
    Faults {
        drop_replies: vec![40, 260],
        late_replies: vec![120],
        late_by: Duration::from_millis(150),
        exceptions: vec![(200, 0x06)],
        disconnects: vec![330],
        silence: Duration::from_millis(150),
        fault_at_block: None,
        silent_after_block: None,
    }
}

fn sim_config() -> SimConfig {
    SimConfig {
        capacity: 40,
        time_scale: 400.0,
        faults: faults(),
        ..SimConfig::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn daemon_streams_5000_blocks_over_modbus_tcp_under_faults() {
    let dir = tempfile::tempdir().unwrap();
    let sim = ModbusSim::spawn_tcp(sim_config(), "127.0.0.1:0".parse().unwrap())
        .await
        .unwrap();
    let machine = format!(
        "link = \"modbus-tcp\"\nhost = \"127.0.0.1\"\nport = {}\nmax_write_registers = 60",
        sim.addr().port()
    );
    let d = Daemon::start(config(dir.path(), &machine), StartOptions::default())
        .await
        .unwrap();
    let blocks = job(5000);
    let id = submit(&d, &blocks).id;
    let j = wait_for(&d, id, |j| j.state.is_final()).await;
    assert_eq!(j.state, JobState::Completed, "{j:?}");
    assert_eq!(j.acked_units, blocks.len());
    assert_executed_once_in_order(&sim, &blocks);
    let st = sim.stats();
    assert_eq!(
        (st.dropped, st.late, st.exceptions, st.disconnects),
        (2, 1, 1, 1)
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn daemon_streams_5000_blocks_over_modbus_rtu_under_faults() {
    let dir = tempfile::tempdir().unwrap();
    let pty = dir.path().join("press-rtu");
    let sim = ModbusSim::spawn_pty(
        SimConfig {
            unit_id: 17,
            ..sim_config()
        },
        Some(&pty),
    )
    .await
    .unwrap();
    let machine = format!(
        "link = \"modbus-rtu\"\nport = \"{}\"\nbaud = 115200\nunit = 17\nmax_write_registers = 12\nquiet_ms = 100",
        pty.display()
    );
    let d = Daemon::start(config(dir.path(), &machine), StartOptions::default())
        .await
        .unwrap();
    let blocks = job(5000);
    let id = submit(&d, &blocks).id;
    let j = wait_for(&d, id, |j| j.state.is_final()).await;
    assert_eq!(j.state, JobState::Completed, "{j:?}");
    assert_executed_once_in_order(&sim, &blocks);
    let st = sim.stats();
    assert_eq!(
        (st.dropped, st.late, st.exceptions, st.disconnects),
        (2, 1, 1, 1)
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_daemon_killed_mid_job_writes_nothing_until_resume_then_finishes_without_resending_a_block(
) {
    let dir = tempfile::tempdir().unwrap();
    // slow enough that the ring (40 blocks) still holds work when the daemon is back
    let sim = ModbusSim::spawn_tcp(
        SimConfig {
            capacity: 40,
            time_scale: 20.0,
            ..SimConfig::default()
        },
        "127.0.0.1:0".parse().unwrap(),
    )
    .await
    .unwrap();
    let machine = format!(
        "link = \"modbus-tcp\"\nhost = \"127.0.0.1\"\nport = {}",
        sim.addr().port()
    );
    let blocks = job(600);
    let d = Daemon::start(config(dir.path(), &machine), StartOptions::default())
        .await
        .unwrap();
    let id = submit(&d, &blocks).id;
    wait_for(&d, id, |j| j.acked_units >= 100).await;
    d.crash().await;
    let consumed_at_crash = sim.trace().len();
    // the device goes on with the blocks already in its ring while the daemon is down
    let d = Daemon::start(config(dir.path(), &machine), StartOptions::default())
        .await
        .unwrap();
    // nobody says resume: the restarted daemon asks the device, watches it run the
    // blocks its ring holds and writes nothing; the job waits at the consumed sequence
    // (the restart marks the job interrupted at once and moves its count on as it watches
    // the device drain its ring: wait until the two agree and stay so)
    let mut waits = None;
    for _ in 0..100 {
        let j = wait_for(&d, id, |j| {
            j.state == JobState::Interrupted && j.acked_units == sim.registers().2 as usize
        })
        .await;
        tokio::time::sleep(Duration::from_millis(300)).await;
        if sim.registers().2 as usize == j.acked_units {
            waits = Some(j);
            break;
        }
    }
    let waits = waits.expect("the device's ring drained and the job stood at its end");
    let written_before_resume = sim.events_from(0).len();
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (_, _, consumed, _) = sim.registers();
    assert_eq!(
        waits.acked_units, consumed as usize,
        "the store says where the device is"
    );
    assert_eq!(sim.trace().len(), consumed as usize);
    assert!(
        !sim.events_from(written_before_resume)
            .iter()
            .any(|e| matches!(e, TraceEvent::Written { .. } | TraceEvent::Executed { .. })),
        "the device was fed before the operator's resume"
    );
    // the operator's resume feeds it from there to the end
    d.scheduler.resume(id).await.unwrap();
    let j = wait_for(&d, id, |j| j.state == JobState::Completed).await;
    assert_eq!(j.acked_units, blocks.len());
    assert_executed_once_in_order(&sim, &blocks);
    // no block was written into the ring again after the device had run it, and the
    // device was never synced (restarted) again after the job's start
    let events = sim.events_from(0);
    let resent: Vec<_> = events
        .iter()
        .filter(|e| matches!(e, TraceEvent::Written { seq, consumed } if seq <= consumed))
        .collect();
    assert!(
        resent.is_empty(),
        "blocks sent again after they ran: {resent:?}"
    );
    let syncs = events
        .iter()
        .filter(|e| matches!(e, TraceEvent::Synced { .. }))
        .count();
    assert_eq!(syncs, 1, "the device was restarted");
    assert!(consumed_at_crash < blocks.len(), "the crash came mid-job");
}
