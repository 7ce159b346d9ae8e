//! The Modbus link against the simulated device, over TCP and over RTU on a pty: long jobs
//! under injected faults arrive complete, in order, each block executed exactly once; and
//! exceptions and device faults stop the job with errors that name the register or code.

use machlink_protocols::modbus::{ModbusLink, ModbusSettings, MotionBlock, WordOrder};
use machlink_protocols::{Control, Link, LinkError, LinkEvent, StreamEnd};
use machlink_sim::modbus::{Faults, ModbusSim, SimConfig};
use std::time::Duration;

use crate::common;
use common::{assert_exactly_once, job};
use tokio::sync::{mpsc, watch};

fn fast(mut s: ModbusSettings) -> ModbusSettings {
    s.timeout = Duration::from_millis(100);
    s.poll_interval = Duration::from_millis(5);
    s.backoff_initial = Duration::from_millis(10);
    s.backoff_max = Duration::from_millis(200);
    s.rtu_quiet = Duration::from_millis(100);
    s
}

async fn stream(
    link: &mut ModbusLink,
    blocks: Vec<MotionBlock>,
) -> (Result<StreamEnd, LinkError>, Vec<LinkEvent>) {
    let program = blocks;
    let (tx, mut rx) = mpsc::unbounded_channel();
    let (_ctl, ctl_rx) = watch::channel(Control::Run);
    let r = tokio::time::timeout(
        Duration::from_secs(60),
        link.stream(&program, 0, tx, ctl_rx),
    )
    .await
    .expect("the stream finishes within a minute");
    let mut events = Vec::new();
    while let Ok(e) = rx.try_recv() {
        events.push(e);
    }
    (r, events)
}

fn faulty() -> Faults {
    Faults {
        drop_replies: vec![30, 300, 700],
        late_replies: vec![80, 450],
        late_by: Duration::from_millis(150),
        exceptions: vec![(150, 0x06)],
        disconnects: vec![220],
        silence: Duration::from_millis(150),
        fault_at_block: None,
        silent_after_block: None,
    }
}

fn sim_config(faults: Faults) -> SimConfig {
    SimConfig {
        capacity: 48,
        time_scale: 400.0,
        faults,
        ..SimConfig::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tcp_job_of_5000_blocks_survives_drops_late_replies_busy_and_a_hang_up() {
    let sim = ModbusSim::spawn_tcp(sim_config(faulty()), "127.0.0.1:0".parse().unwrap())
        .await
        .unwrap();
    let mut s = fast(ModbusSettings::tcp("127.0.0.1", sim.addr().port()));
    s.max_write_registers = 100;
    let mut link = ModbusLink::new(s).unwrap();
    let blocks = job(5000);
    let (r, events) = stream(&mut link, blocks.clone()).await;
    assert_eq!(r.unwrap(), StreamEnd::Completed);
    assert_exactly_once(&sim, &blocks, &events);
    let st = sim.stats();
    assert_eq!(
        (st.dropped, st.late, st.exceptions, st.disconnects),
        (3, 2, 1, 1),
        "{st:?}"
    );
    assert!(
        st.connections >= 5,
        "every lost reply costs a new connection: {st:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtu_job_of_5000_blocks_survives_drops_late_replies_busy_and_a_dead_line() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("modbus-rtu");
    let mut cfg = sim_config(faulty());
    cfg.word_order = WordOrder::LowFirst;
    cfg.unit_id = 7;
    cfg.base_address = 1000;
    let sim = ModbusSim::spawn_pty(cfg, Some(&path)).await.unwrap();
    let mut s = fast(ModbusSettings::rtu(path.to_str().unwrap(), 115_200));
    s.word_order = WordOrder::LowFirst;
    s.unit_id = 7;
    s.base_address = 1000;
    s.max_write_registers = 12;
    let mut link = ModbusLink::new(s).unwrap();
    let blocks = job(5000);
    let (r, events) = stream(&mut link, blocks.clone()).await;
    assert_eq!(r.unwrap(), StreamEnd::Completed);
    assert_exactly_once(&sim, &blocks, &events);
    let st = sim.stats();
    assert_eq!(
        (st.dropped, st.late, st.exceptions, st.disconnects),
        (3, 2, 1, 1),
        "{st:?}"
    );
}

#[tokio::test]
async fn an_exception_names_the_register_and_the_code() {
    // Request 3 is the first block write (the status read, the sync with the header read
    // back in the same FC23 request, then the blocks).
    let faults = Faults {
        exceptions: vec![(3, 0x02)],
        ..Faults::default()
    };
    let sim = ModbusSim::spawn_tcp(sim_config(faults), "127.0.0.1:0".parse().unwrap())
        .await
        .unwrap();
    let mut link =
        ModbusLink::new(fast(ModbusSettings::tcp("127.0.0.1", sim.addr().port()))).unwrap();
    let (r, _) = stream(&mut link, job(100)).await;
    let msg = r.unwrap_err().to_string();
    assert!(
        msg.contains("exception 0x02 Illegal Data Address")
            && msg.contains("holding registers 32..=154 (ring slot 0 to ring slot 7)"),
        "{msg}"
    );
    assert!(sim.trace().is_empty());
}

#[tokio::test]
async fn a_device_fault_stops_the_job_with_its_code_and_block_and_a_resume_finishes_it() {
    let faults = Faults {
        fault_at_block: Some((250, 0x0107)),
        silent_after_block: None,
        ..Faults::default()
    };
    let sim = ModbusSim::spawn_tcp(sim_config(faults), "127.0.0.1:0".parse().unwrap())
        .await
        .unwrap();
    let mut link =
        ModbusLink::new(fast(ModbusSettings::tcp("127.0.0.1", sim.addr().port()))).unwrap();
    let blocks = job(1000);
    let (r, events) = stream(&mut link, blocks.clone()).await;
    let e = r.unwrap_err();
    assert!(matches!(e, LinkError::Alarm { .. }), "{e:?}");
    let msg = e.to_string();
    assert!(
        msg.contains("faulted with code 0x0107") && msg.contains("at block 250"),
        "{msg}"
    );
    let trace = sim.trace();
    assert_eq!(trace.len(), 249);
    let last_ack = events.iter().rev().find_map(|e| match e {
        LinkEvent::Acked { unit } => Some(*unit),
        _ => None,
    });
    assert_eq!(
        last_ack,
        Some(248),
        "the journal ends at the last executed block"
    );

    // A new stream refuses to start over a standing fault, naming it.
    let program = blocks.clone();
    let (tx, _rx) = mpsc::unbounded_channel();
    let (_ctl, ctl_rx) = watch::channel(Control::Run);
    let e = link
        .stream(&program, 249, tx.clone(), ctl_rx.clone())
        .await
        .unwrap_err();
    assert!(e.to_string().contains("in fault 0x0107"), "{e}");
    // Cleared, the job resumes after the last acknowledged block and finishes exactly once.
    link.clear_fault().await.unwrap();
    let end = link.stream(&program, 249, tx, ctl_rx).await.unwrap();
    assert_eq!(end, StreamEnd::Completed);
    let trace = sim.trace();
    assert_eq!(trace.len(), blocks.len());
    assert!(trace
        .iter()
        .enumerate()
        .all(|(i, e)| e.seq as usize == i + 1 && e.block == blocks[i]));
}

#[tokio::test]
async fn hold_pauses_and_cancel_stops_with_what_was_executed() {
    let sim = ModbusSim::spawn_tcp(
        SimConfig {
            time_scale: 20.0,
            ..SimConfig::default()
        },
        "127.0.0.1:0".parse().unwrap(),
    )
    .await
    .unwrap();
    let mut link =
        ModbusLink::new(fast(ModbusSettings::tcp("127.0.0.1", sim.addr().port()))).unwrap();
    let program = job(2000);
    let (tx, mut rx) = mpsc::unbounded_channel();
    let (ctl, ctl_rx) = watch::channel(Control::Run);
    let run = tokio::spawn(async move {
        let r = link.stream(&program, 0, tx, ctl_rx).await;
        (r, link)
    });
    // Wait for progress, hold, and check the device stops executing.
    while !matches!(rx.recv().await, Some(LinkEvent::Acked { unit }) if unit >= 20) {}
    ctl.send(Control::Hold).unwrap();
    loop {
        match rx.recv().await {
            Some(LinkEvent::Status(s)) if s.state == machlink_protocols::DeviceState::Held => break,
            Some(_) => {}
            None => panic!("the stream ended while holding"),
        }
    }
    let held = sim.trace().len();
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert!(
        sim.trace().len() <= held + 1,
        "blocks executed during a hold"
    );
    ctl.send(Control::Run).unwrap();
    while !matches!(rx.recv().await, Some(LinkEvent::Acked { unit }) if unit >= held + 20) {}
    ctl.send(Control::Cancel).unwrap();
    let (r, _link) = run.await.unwrap();
    let StreamEnd::Cancelled { acked } = r.unwrap() else {
        panic!("a cancel ends the stream as cancelled")
    };
    let executed = sim.trace().len();
    assert_eq!(
        acked, executed,
        "what was acknowledged is what was executed"
    );
    assert!(executed < 2000);
    tokio::time::sleep(Duration::from_millis(50)).await;
    assert_eq!(
        sim.trace().len(),
        executed,
        "the device kept moving after the stop"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fault_every_few_requests_with_blocks_split_across_writes_still_delivers_exactly_once() {
    // Ring of 8, 10 registers per write: every block straddles two writes, so lost replies
    // leave half-written slots that the resynchronisation must find and rewrite.
    let mut faults = Faults {
        late_by: Duration::from_millis(120),
        silence: Duration::from_millis(120),
        ..Faults::default()
    };
    for n in (20..1500).step_by(37) {
        match (n / 37) % 4 {
            0 => faults.drop_replies.push(n),
            1 => faults.late_replies.push(n),
            2 => faults.exceptions.push((n, 0x06)),
            _ => faults.disconnects.push(n),
        }
    }
    let cfg = SimConfig {
        capacity: 8,
        time_scale: 0.0,
        faults,
        ..SimConfig::default()
    };
    let sim = ModbusSim::spawn_tcp(cfg, "127.0.0.1:0".parse().unwrap())
        .await
        .unwrap();
    let mut s = fast(ModbusSettings::tcp("127.0.0.1", sim.addr().port()));
    s.max_write_registers = 10;
    s.max_retries = 20;
    let mut link = ModbusLink::new(s).unwrap();
    let blocks = job(400);
    let (r, events) = stream(&mut link, blocks.clone()).await;
    assert_eq!(r.unwrap(), StreamEnd::Completed);
    assert_exactly_once(&sim, &blocks, &events);
    let st = sim.stats();
    assert!(
        st.dropped + st.late + st.exceptions + st.disconnects >= 20,
        "{st:?}"
    );
}

#[tokio::test]
async fn a_device_that_never_answers_gives_up_after_the_retry_limit_naming_the_request() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = listener.local_addr().unwrap().port();
    let mute = tokio::spawn(async move {
        let mut held = Vec::new();
        while let Ok((sock, _)) = listener.accept().await {
            held.push(sock); // accept, read nothing, answer nothing
        }
    });
    let mut s = fast(ModbusSettings::tcp("127.0.0.1", port));
    s.timeout = Duration::from_millis(50);
    s.max_retries = 3;
    let mut link = ModbusLink::new(s).unwrap();
    let (r, events) = stream(&mut link, job(10)).await;
    let msg = r.unwrap_err().to_string();
    assert!(
        msg.contains("after 4 failed attempts in a row")
            && msg.contains("did not answer the read of holding registers 0..=15"),
        "{msg}"
    );
    let retries = events
        .iter()
        .filter(|e| matches!(e, LinkEvent::Message(m) if m.starts_with("retrying")))
        .count();
    assert_eq!(retries, 3, "the operator hears of each retry");
    mute.abort();
}

#[test]
fn settings_outside_the_protocol_are_refused_by_name() {
    let mut s = ModbusSettings::tcp("127.0.0.1", 502);
    s.max_write_registers = 124;
    let e = ModbusLink::new(s).err().unwrap().to_string();
    assert!(e.contains("max_write_registers is 124"), "{e}");
    let mut s = ModbusSettings::rtu("/dev/ttyUSB0", 19_200);
    s.unit_id = 0;
    assert!(ModbusLink::new(s).is_err());
}

/// docs/modbus.md rule 10a: the simulated device holds at each tool change block with the
/// block unfinished; the link reports the tool to load and resumes only after the operator's
/// hold and run; a job stopped there and started again from that block holds there again;
/// and every block runs once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_device_holds_at_a_tool_block_until_the_operator_and_again_after_a_stop() {
    use machlink_protocols::modbus::{post_blocks, BlockKind};
    use machlink_protocols::{DeviceState, OperatorReason};
    use machlink_sim::modbus::TraceEvent;
    use offset_core::{Move, Toolpath, P3};
    let sim = ModbusSim::spawn_tcp(
        SimConfig {
            time_scale: 50.0,
            capacity: 8,
            ..SimConfig::default()
        },
        "127.0.0.1:0".parse().unwrap(),
    )
    .await
    .unwrap();
    let mut tp = Toolpath::new("tools");
    for (k, tool) in [1u32, 2].into_iter().enumerate() {
        tp.push(Move::ToolChange {
            tool,
            name: String::new(),
            geometry: None,
        });
        for i in 0..12 {
            tp.push(Move::Linear {
                to: P3::new(k as f64 * 10.0 + i as f64 * 0.5, 1.0, -0.5),
                feed: 900.0,
            });
        }
    }
    let blocks = post_blocks(&tp).unwrap();
    let at = |tool: u32| {
        blocks
            .iter()
            .position(|b| b.kind == BlockKind::ToolChange && b.feed == tool)
            .unwrap() as u32
    };
    let asks = |tool: u32| DeviceState::NeedsOperator {
        reason: OperatorReason::LoadTool {
            number: tool,
            name: String::new(),
        },
    };
    async fn until(rx: &mut mpsc::UnboundedReceiver<LinkEvent>, want: &DeviceState) {
        tokio::time::timeout(Duration::from_secs(20), async {
            loop {
                match rx.recv().await {
                    Some(LinkEvent::Status(s)) if &s.state == want => break,
                    Some(_) => {}
                    None => panic!("the stream ended before {want}"),
                }
            }
        })
        .await
        .unwrap_or_else(|_| panic!("the link never reported {want}"));
    }
    let stops = |sim: &ModbusSim| -> Vec<u32> {
        sim.events_from(0)
            .into_iter()
            .filter_map(|e| match e {
                TraceEvent::ToolStop { seq, .. } => Some(seq),
                _ => None,
            })
            .collect()
    };

    // the first stream: held at T1, released by hold + run, held at T2, cancelled there
    let mut link =
        ModbusLink::new(fast(ModbusSettings::tcp("127.0.0.1", sim.addr().port()))).unwrap();
    let (tx, mut rx) = mpsc::unbounded_channel();
    let (ctl, ctl_rx) = watch::channel(Control::Run);
    let program = blocks.clone();
    let run = tokio::spawn(async move {
        let r = link.stream(&program, 0, tx, ctl_rx).await;
        (r, link)
    });
    until(&mut rx, &asks(1)).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (state, _, consumed, _) = sim.registers();
    assert_eq!((state, consumed), (2, at(1)), "held before the T1 block");
    assert!(sim.trace().is_empty(), "{:?}", sim.trace());
    // once the operator has the stop (the daemon's hold came), the link says it no more:
    // a repeat, read before the operator's resume took effect, would pause the resumed
    // job a second time (the daemon pauses a running job on every such report)
    let says = |rx: &mut mpsc::UnboundedReceiver<LinkEvent>, tool: u32| {
        let mut n = 0;
        while let Ok(ev) = rx.try_recv() {
            n += matches!(&ev, LinkEvent::Status(s) if s.state == asks(tool)) as usize;
        }
        n
    };
    says(&mut rx, 1);
    ctl.send(Control::Hold).unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    says(&mut rx, 1); // (a round under way when the hold came may still say it)
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert_eq!(sim.registers().2, at(1), "the hold alone released it");
    assert_eq!(says(&mut rx, 1), 0, "the link said T1 again after the hold");
    ctl.send(Control::Run).unwrap();
    until(&mut rx, &asks(2)).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(sim.registers().2, at(2), "held before the T2 block");
    assert_eq!(stops(&sim), [at(1) + 1, at(2) + 1]);
    ctl.send(Control::Cancel).unwrap();
    let (r, mut link) = run.await.unwrap();
    assert_eq!(
        r.unwrap(),
        StreamEnd::Cancelled {
            acked: at(2) as usize
        }
    );

    // started again from the T2 block: the device holds there again
    let (tx, mut rx) = mpsc::unbounded_channel();
    let (ctl, ctl_rx) = watch::channel(Control::Run);
    let program = blocks.clone();
    let from = at(2) as usize;
    let run = tokio::spawn(async move { link.stream(&program, from, tx, ctl_rx).await });
    until(&mut rx, &asks(2)).await;
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert_eq!(sim.registers().2, at(2));
    assert_eq!(stops(&sim), [at(1) + 1, at(2) + 1, at(2) + 1]);
    // the daemon's hold and the operator's resume both between two of the link's rounds
    // (the link sees only the run, and a change since the stop): that releases it too
    ctl.send(Control::Hold).unwrap();
    ctl.send(Control::Run).unwrap();
    let r = tokio::time::timeout(Duration::from_secs(30), run)
        .await
        .expect("the stream ends")
        .unwrap();
    assert_eq!(r.unwrap(), StreamEnd::Completed);
    let seqs: Vec<u32> = sim.trace().iter().map(|e| e.seq).collect();
    assert_eq!(seqs, (1..=blocks.len() as u32).collect::<Vec<_>>());
}
