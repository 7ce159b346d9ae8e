//! Every CANopen stop is jerk-limited to standstill, read off the set-points the simulated
//! drives applied at each SYNC: the end of a job, a hold (and the resume after it) and a
//! cancel, in interpolated position (IP) and cyclic synchronous position (CSP) mode. Each
//! axis's speed, acceleration and jerk — the first, second and third differences of its
//! set-points over the period — stay within that axis's `max_velocity`, `max_acceleration`
//! and `max_jerk` from the settings, and every set-point lies on the job's path.
//!
//! The job is one straight line cut into 1 mm moves (no corner, so no corner of the path can
//! excuse a jump), and the drives count 10⁶ per mm: rounding a set-point to whole counts
//! changes a third difference by at most 4 counts, 500 mm/s³ at 2 ms, which the jerk bound
//! allows on top of the limit (the knock these tests catch was 80 000 mm/s³ against 10 000).

use crate::canopen_line;

use canopen_line::*;
use machlink_protocols::{Control, DeviceState, LinkEvent, StreamEnd};
use offset_core::P3;

/// Every axis within its limits over `points` (standing at `from` for three SYNCs before),
/// and every point on the line from the origin to `END`.
fn check_stream(what: &str, from: P3, points: &[P3]) {
    assert!(points.len() > 50, "{what}: {} SYNCs recorded", points.len());
    let all: Vec<P3> = std::iter::repeat_n(from, 3)
        .chain(points.iter().copied())
        .collect();
    let c = |p: &P3, i: usize| [p.x, p.y, p.z][i];
    let q = 1.0 / COUNTS;
    let t = PERIOD;
    for (i, (vmax, amax, jmax)) in LIMITS.iter().enumerate() {
        for (k, w) in all.windows(4).enumerate() {
            let (p0, p1, p2, p3) = (c(&w[0], i), c(&w[1], i), c(&w[2], i), c(&w[3], i));
            let v = (p3 - p2).abs() / t;
            let a = (p3 - 2.0 * p2 + p1).abs() / (t * t);
            let j = (p3 - 3.0 * p2 + 3.0 * p1 - p0).abs() / (t * t * t);
            assert!(
                v <= vmax + q / t,
                "{what}: axis {i} at SYNC {k}: {v:.4} mm/s, limit {vmax}"
            );
            assert!(
                a <= amax + 2.0 * q / (t * t),
                "{what}: axis {i} at SYNC {k}: {a:.2} mm/s², limit {amax}"
            );
            assert!(
                j <= jmax + 4.0 * q / (t * t * t),
                "{what}: axis {i} at SYNC {k}: {j:.0} mm/s³, limit {jmax}"
            );
        }
    }
    // on the line: the distance from each set-point to it (the rounding is 1e-6 mm)
    let len = (END.x * END.x + END.y * END.y + END.z * END.z).sqrt();
    let u = P3::new(END.x / len, END.y / len, END.z / len);
    for p in points {
        let along = p.x * u.x + p.y * u.y + p.z * u.z;
        let off = P3::new(p.x - along * u.x, p.y - along * u.y, p.z - along * u.z);
        let d = (off.x * off.x + off.y * off.y + off.z * off.z).sqrt();
        assert!(
            d <= 2e-6,
            "{what}: the set-point {p:?} is {d} mm off the path"
        );
        assert!(
            (-1e-6..=len + 1e-6).contains(&along),
            "{what}: the set-point {p:?} is beyond the path's ends"
        );
    }
}

fn last_acked(events: &[LinkEvent]) -> Option<usize> {
    events
        .iter()
        .filter_map(|e| match e {
            LinkEvent::Acked { unit } => Some(*unit),
            _ => None,
        })
        .next_back()
}

async fn stops_in(mode: &str) {
    let mut m = Machine::start(mode).await;
    let program = m.program(&line_job());

    // 1. the whole job: the stop at its end
    let (end, events) = m.stream(&program, 0, |_, _, _| {}).await;
    assert_eq!(end.expect("the job runs"), StreamEnd::Completed);
    assert_eq!(last_acked(&events), Some(UNITS - 1));
    let sp = m.setpoints();
    check_stream(&format!("{mode}: the end of the job"), P3::default(), &sp);
    let last = *sp.last().unwrap();
    assert!(last.dist(END) < 1e-5, "{mode}: ended at {last:?}");

    // 2. held a fifth of the way and resumed 40 SYNCs later (fresh drives at the origin)
    let mut m = Machine::start(mode).await;
    let mut hold_sent = false;
    let mut held_at: Option<u64> = None;
    let mut resumed = false;
    let (end, events) = m
        .stream(&program, 0, |ev, ctl, sim| match ev {
            LinkEvent::Acked { unit } if *unit >= 12 && !hold_sent => {
                hold_sent = true;
                ctl.send(Control::Hold).unwrap();
            }
            LinkEvent::Status(s) if s.state == DeviceState::Held && !resumed => {
                let now = sim.drives.with_drive(1, |d| d.syncs()).unwrap();
                let at = *held_at.get_or_insert(now);
                if now >= at + 40 {
                    resumed = true;
                    ctl.send(Control::Run).unwrap();
                }
            }
            _ => {}
        })
        .await;
    assert_eq!(end.expect("the held job runs"), StreamEnd::Completed);
    assert!(resumed, "{mode}: the job was held and resumed");
    assert_eq!(last_acked(&events), Some(UNITS - 1));
    let sp = m.setpoints();
    let standing = sp.windows(2).filter(|w| w[0] == w[1]).count();
    assert!(standing >= 40, "{mode}: stood {standing} SYNCs while held");
    check_stream(
        &format!("{mode}: a hold and its resume"),
        P3::default(),
        &sp,
    );

    // 3. a cancel halfway
    let mut m = Machine::start(mode).await;
    let mut cancel_sent = false;
    let (end, events) = m
        .stream(&program, 0, |ev, ctl, _| {
            if let LinkEvent::Acked { unit } = ev {
                if *unit >= 25 && !cancel_sent {
                    cancel_sent = true;
                    ctl.send(Control::Cancel).unwrap();
                }
            }
        })
        .await;
    let acked = match end.expect("the cancel ends the stream") {
        StreamEnd::Cancelled { acked } => acked,
        other => panic!("{mode}: {other:?} after a cancel"),
    };
    assert!(acked < UNITS, "{mode}: cancelled after {acked} units");
    assert_eq!(last_acked(&events).map(|u| u + 1), Some(acked));
    // no SYNC follows the cancel's last set-point: the drives stand there. Standing for
    // three SYNCs more must be within the limits too, which it is only if the braking
    // ended at rest (a speed left at the last set-point would stop within one SYNC)
    let mut sp = m.setpoints();
    let last = *sp.last().expect("set-points");
    sp.extend([last; 3]);
    check_stream(&format!("{mode}: a cancel"), P3::default(), &sp);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_stop_in_interpolated_position_mode_is_jerk_limited_to_standstill() {
    stops_in("ip").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_stop_in_cyclic_synchronous_position_mode_is_jerk_limited_to_standstill() {
    stops_in("csp").await;
}
