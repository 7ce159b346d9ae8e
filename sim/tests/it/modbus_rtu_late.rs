//! Modbus RTU on a line the simulator times exactly (tokio's paused clock, an in-memory
//! cable): replies that come 1, 2 or 3 quiet times (3.5 characters) after the link gave up
//! on them are never taken for the answer to a later request, and a 5,000-block job under
//! late replies, lost replies, busy exceptions and a dead line still executes every block
//! exactly once, in order.

use machlink_protocols::modbus::{ModbusLink, ModbusSettings, MotionBlock, ReplyFate, WordOrder};
use machlink_protocols::{Control, Link, LinkEvent, StreamEnd};
use machlink_sim::line;
use machlink_sim::modbus::{Faults, ModbusSim, SimConfig};
use std::time::Duration;

use crate::common;
use common::{assert_exactly_once, job};
use tokio::sync::{mpsc, watch};

const BAUD: u32 = 9600;
const TIMEOUT: Duration = Duration::from_millis(400);

/// The link as adversarial as it can be about late replies: it sends the next request the
/// moment it gives up (no backoff), after only the shortest drain RTU allows.
fn settings() -> ModbusSettings {
    let mut s = ModbusSettings::rtu("in-memory cable", BAUD);
    s.unit_id = 7;
    s.base_address = 1000;
    s.word_order = WordOrder::LowFirst;
    s.timeout = TIMEOUT;
    s.rtu_quiet = Duration::ZERO; // raised to 3.5 characters by the link
    s.backoff_initial = Duration::ZERO;
    s.backoff_max = Duration::ZERO;
    s.max_retries = 12;
    s.poll_interval = Duration::from_millis(5);
    s
}

/// A device slower than the line (blocks of about 30 ms), so that the ring fills and most
/// requests are polls of the header: a late poll's reply has the very shape of the next
/// poll's, and only the settling read tells them apart.
fn device(faults: Faults) -> SimConfig {
    SimConfig {
        unit_id: 7,
        base_address: 1000,
        word_order: WordOrder::LowFirst,
        capacity: 48,
        time_scale: 1.0,
        line_baud: Some(BAUD),
        faults,
        ..SimConfig::default()
    }
}

/// Every reply frame the link saw, in the order the device sent them: a frame the link took
/// as the answer to its request `h` must be the device's reply to request `h`.
fn assert_no_stale_reply_taken(sim: &ModbusSim, link: &ModbusLink) -> (usize, usize) {
    let sent = sim.replies();
    let seen = link.replies();
    assert_eq!(
        seen.len(),
        sent.len(),
        "the link accounts for every reply frame the device sent"
    );
    let (mut stale, mut drained) = (0, 0);
    for (i, (fate, answered)) in seen.iter().zip(&sent).enumerate() {
        match *fate {
            ReplyFate::Taken { request } => assert_eq!(
                request, *answered,
                "reply frame {i} answered request {answered} but was taken for request {request}"
            ),
            ReplyFate::Stale => stale += 1,
            ReplyFate::Drained => drained += 1,
        }
    }
    (stale, drained)
}

async fn stream(link: &mut ModbusLink, blocks: &[MotionBlock]) -> (StreamEnd, Vec<LinkEvent>) {
    let (tx, mut rx) = mpsc::unbounded_channel();
    let (_ctl, ctl_rx) = watch::channel(Control::Run);
    let end = link.stream(blocks, 0, tx, ctl_rx).await.unwrap();
    let mut events = Vec::new();
    while let Ok(e) = rx.try_recv() {
        events.push(e);
    }
    (end, events)
}

/// `late_by` for a reply whose last byte reaches the link `k` quiet times after it gave up.
fn late_by(k: u32) -> Duration {
    TIMEOUT + line::t35(BAUD) * k
}

async fn late_by_k_quiet_times(k: u32) {
    // Every 11th request from the 4th on is answered k quiet times after the timeout.
    let faults = Faults {
        late_replies: (4..2000).step_by(11).collect(),
        late_by: late_by(k),
        ..Faults::default()
    };
    let (host, dev) = line::cable(None);
    let sim = ModbusSim::spawn_rtu_on(device(faults), dev);
    let mut link = ModbusLink::from_stream(host, settings()).unwrap();
    link.record_replies();
    let blocks = job(1500);
    let (end, events) = stream(&mut link, &blocks).await;
    assert_eq!(end, StreamEnd::Completed);
    assert_exactly_once(&sim, &blocks, &events);
    let (stale, drained) = assert_no_stale_reply_taken(&sim, &link);
    let late = sim.stats().late as usize;
    assert!(late >= 20, "only {late} late replies were injected");
    // Each late reply was thrown away, by the drain or as stale; none was taken.
    assert_eq!(stale + drained, late, "stale {stale} + drained {drained}");
    if k > 1 {
        assert!(
            stale > 0,
            "late by {k} quiet times, some replies must come after the drain"
        );
    }
}

#[tokio::test(start_paused = true)]
async fn replies_late_by_one_quiet_time_are_never_taken_for_a_later_request() {
    late_by_k_quiet_times(1).await;
}

#[tokio::test(start_paused = true)]
async fn replies_late_by_two_quiet_times_are_never_taken_for_a_later_request() {
    late_by_k_quiet_times(2).await;
}

#[tokio::test(start_paused = true)]
async fn replies_late_by_three_quiet_times_are_never_taken_for_a_later_request() {
    late_by_k_quiet_times(3).await;
}

#[tokio::test(start_paused = true)]
async fn five_thousand_blocks_go_exactly_once_under_every_fault_with_no_stale_reply_taken() {
    let mut faults = Faults {
        silence: Duration::from_millis(900),
        ..Faults::default()
    };
    // One fault every 13 requests, cycling through: late by 1, 2 or 3 quiet times (the
    // simulator has one lateness, so these come as separate runs below), lost replies,
    // busy exceptions and a dead line.
    for n in (5..6000).step_by(13) {
        match (n / 13) % 4 {
            0 => faults.late_replies.push(n),
            1 => faults.drop_replies.push(n),
            2 => faults.exceptions.push((n, 0x06)),
            _ => faults.disconnects.push(n),
        }
    }
    let mut stale_total = 0;
    for k in 1..=3 {
        let (host, dev) = line::cable(None);
        let sim = ModbusSim::spawn_rtu_on(
            device(Faults {
                late_by: late_by(k),
                ..faults.clone()
            }),
            dev,
        );
        let mut link = ModbusLink::from_stream(host, settings()).unwrap();
        link.record_replies();
        let blocks = job(5000);
        let (end, events) = stream(&mut link, &blocks).await;
        assert_eq!(end, StreamEnd::Completed, "late by {k} quiet times");
        assert_exactly_once(&sim, &blocks, &events);
        let (stale, _) = assert_no_stale_reply_taken(&sim, &link);
        stale_total += stale;
        let st = sim.stats();
        assert!(
            st.late >= 20 && st.dropped >= 20 && st.exceptions >= 20 && st.disconnects >= 20,
            "late by {k}: {st:?}"
        );
    }
    assert!(stale_total > 0, "no late reply ever came after a drain");
}

#[tokio::test(start_paused = true)]
async fn a_device_without_fc23_gets_its_commits_and_reads_apart() {
    let (host, dev) = line::cable(None);
    let sim = ModbusSim::spawn_rtu_on(
        SimConfig {
            read_write: false,
            ..device(Faults::default())
        },
        dev,
    );
    let mut link = ModbusLink::from_stream(host, settings()).unwrap();
    let blocks = job(300);
    let (end, events) = stream(&mut link, &blocks).await;
    assert_eq!(end, StreamEnd::Completed);
    assert_exactly_once(&sim, &blocks, &events);
    assert_eq!(link.uses_read_write(), Some(false));
}
