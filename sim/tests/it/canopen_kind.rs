//! CANopen at the kind level, as the daemon drives it (registry → settings → start → open →
//! stream a program made by the `moves` post): a pocket on three simulated CiA 402 drives
//! behind a simulated SLCAN adapter on a pty follows the planned path, keeps every axis
//! within its velocity and acceleration, holds and resumes on the path, and stops on each
//! injected fault with the drive's reason, after which the same link runs the next program.
//! Also: a cancel brakes on the path and a resume starts after the last acknowledged move;
//! cyclic synchronous position paced by the clock thread; NMT commands from the link.

use machlink_protocols::{Control, DeviceState, LinkError, LinkEvent, StreamEnd};
use machlink_sim::canopen::{DriveFault, SyncRecord};
use offset_core::geom::Segment;
use offset_core::ops::{pocket, PocketParams, Stepover};
use offset_core::toolpath::arc_segment;
use offset_core::{Move, Polyline, Shape, Toolpath, Vertex, P3};
use std::time::Duration;

const PERIOD: f64 = 0.002;
const COUNTS: f64 = 100_000.0;
/// Each axis's limits: (velocity mm/s, acceleration mm/s²).
const LIMITS: [(f64, f64); 3] = [(60.0, 800.0), (50.0, 600.0), (15.0, 400.0)];
/// How the drives count against the machine's axes.
const SIGN: [f64; 3] = [1.0, -1.0, 1.0];

fn settings() -> serde_json::Value {
    let axis = |name: &str, node: u8, i: usize| {
        serde_json::json!({
            "axis": name, "node": node, "counts_per_mm": COUNTS, "sign": SIGN[i] as i8,
            "max_velocity": LIMITS[i].0, "max_acceleration": LIMITS[i].1, "max_jerk": 20000.0
        })
    };
    serde_json::json!({
        "transport": "slcan",
        "lockstep": true,
        "mode": "ip",
        "period_ms": 2,
        "heartbeat_ms": 50,
        // a heartbeat is taken as lost after 1.5 s: under load a drive's heartbeat came
        // 600 ms late in tests that do not test its loss (the fault test sets 400 ms)
        "heartbeat_timeout_ms": 1500,
        "report_timeout_ms": 2000,
        "axes": [axis("x", 1, 0), axis("y", 2, 1), axis("z", 3, 2)]
    })
}

/// A pocket in a rectangle with a rounded end, so the path has lines, arcs and corners.
fn pocket_path() -> Toolpath {
    pocket_of_depth(1.0)
}

fn pocket_of_depth(depth: f64) -> Toolpath {
    let outline = Polyline::new(
        vec![
            Vertex::new(0.0, 0.0, 0.0),
            Vertex::new(24.0, 0.0, 1.0),
            Vertex::new(24.0, 16.0, 0.0),
            Vertex::new(0.0, 16.0, 0.0),
        ],
        true,
    );
    let mut p = PocketParams {
        stepover: Stepover::Percent(50.0),
        ..Default::default()
    };
    p.cut.tool = offset_core::Tool::flat(6.0);
    p.cut.feed = 1800.0;
    p.cut.plunge_feed = 400.0;
    p.cut.safe_z = 3.0;
    p.cut.depth = depth;
    p.cut.stepdown = 1.0;
    p.cut.spindle_rpm = 0.0;
    pocket(&Shape::new(vec![outline]), &p).expect("a pocket")
}

fn square(size: f64) -> Toolpath {
    let mut tp = Toolpath::new("square");
    for (x, y) in [(size, 0.0), (size, size), (0.0, size), (0.0, 0.0)] {
        tp.push(Move::Linear {
            to: P3::new(x, y, 0.0),
            feed: 1200.0,
        });
    }
    tp
}

/// The drives' harness this file shares with the stop and disable tests.
use crate::canopen_line::Machine;

/// The drives' records joined by SYNC: (sync, demand mm, actual mm) per axis.
fn positions(m: &Machine) -> Vec<(u64, P3, P3)> {
    let traces: Vec<Vec<SyncRecord>> = (1..=3).map(|n| m.sim().drives.trace(n)).collect();
    let mut out = Vec::new();
    for r in &traces[0] {
        let at = |i: usize| traces[i].iter().find(|t| t.sync == r.sync).copied();
        let (Some(y), Some(z)) = (at(1), at(2)) else {
            continue;
        };
        let mm = |i: usize, c: f64| c / (SIGN[i] * COUNTS);
        out.push((
            r.sync,
            P3::new(
                mm(0, r.demand as f64),
                mm(1, y.demand as f64),
                mm(2, z.demand as f64),
            ),
            P3::new(mm(0, r.actual), mm(1, y.actual), mm(2, z.actual)),
        ));
    }
    out
}

/// The tool path's pieces, in order from the origin, with offset-core's own geometry.
enum Piece {
    Line(P3, P3),
    Arc(Segment, f64, f64),
}

fn pieces(tp: &Toolpath, start: P3) -> Vec<Piece> {
    let mut out = Vec::new();
    tp.walk(start, |from, m, to| match m {
        Move::Arc { center, ccw, .. } => out.push(Piece::Arc(
            arc_segment(from.xy(), to.xy(), *center, *ccw),
            from.z,
            to.z,
        )),
        _ => out.push(Piece::Line(from, to)),
    });
    out
}

fn distance(piece: &Piece, p: P3) -> f64 {
    match piece {
        Piece::Line(a, b) => {
            let d = P3::new(b.x - a.x, b.y - a.y, b.z - a.z);
            let l2 = d.x * d.x + d.y * d.y + d.z * d.z;
            let t = if l2 > 0.0 {
                (((p.x - a.x) * d.x + (p.y - a.y) * d.y + (p.z - a.z) * d.z) / l2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            p.dist(P3::new(a.x + d.x * t, a.y + d.y * t, a.z + d.z * t))
        }
        Piece::Arc(seg, z0, z1) => {
            let q = seg.closest_point(p.xy());
            let Segment::Arc { a, center, ccw, .. } = *seg else {
                unreachable!("arcs only")
            };
            let t = if q.dist(a) < 1e-9 {
                0.0
            } else {
                arc_segment(a, q, center, ccw).length() / seg.length().max(1e-12)
            };
            let z = z0 + (z1 - z0) * t.clamp(0.0, 1.0);
            (q.dist(p.xy()).powi(2) + (p.z - z).powi(2)).sqrt()
        }
    }
}

/// The largest distance from recorded positions to the path: positions come in path order,
/// so each is looked up near where the last one was.
fn worst_distance(path: &[Piece], points: impl Iterator<Item = P3>) -> (f64, P3) {
    let mut cur = 0usize;
    let mut worst = (0.0, P3::default());
    for p in points {
        // the first piece from the last one that the point lies on, else the nearest
        let (mut best, mut at) = (f64::INFINITY, cur);
        for (i, piece) in path.iter().enumerate().skip(cur).take(60) {
            let d = distance(piece, p);
            if d < best {
                best = d;
                at = i;
            }
            if d <= 1e-4 {
                break;
            }
        }
        cur = at;
        if best > worst.0 {
            worst = (best, p);
        }
    }
    worst
}

/// The fastest speed and acceleration of each axis over consecutive SYNCs.
fn peaks(points: &[P3]) -> [(f64, f64); 3] {
    let mut out = [(0.0f64, 0.0f64); 3];
    let c = |p: &P3, i: usize| [p.x, p.y, p.z][i];
    for (i, o) in out.iter_mut().enumerate() {
        for w in points.windows(2) {
            o.0 = o.0.max((c(&w[1], i) - c(&w[0], i)).abs() / PERIOD);
        }
        for w in points.windows(3) {
            o.1 =
                o.1.max((c(&w[2], i) - 2.0 * c(&w[1], i) + c(&w[0], i)).abs() / (PERIOD * PERIOD));
        }
    }
    out
}

fn check_limits(what: &str, points: &[P3]) {
    let p = peaks(points);
    for (i, ((v, a), (vmax, amax))) in p.iter().zip(LIMITS).enumerate() {
        // one count of rounding each way is 2e-5 mm: 0.01 mm/s and 5 mm/s² at 2 ms
        assert!(
            *v <= vmax * 1.001 + 0.02,
            "{what}: axis {i} reached {v:.3} mm/s, limit {vmax}"
        );
        assert!(
            *a <= amax * 1.001 + 10.0,
            "{what}: axis {i} reached {a:.1} mm/s², limit {amax}"
        );
    }
}

fn acked(events: &[LinkEvent]) -> Vec<usize> {
    events
        .iter()
        .filter_map(|e| match e {
            LinkEvent::Acked { unit } => Some(*unit),
            _ => None,
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pocket_on_three_drives_over_slcan_follows_the_path_within_the_limits_and_holds_on_it() {
    let mut m = Machine::start_with(settings()).await;
    let tp = pocket_path();
    let program = m.program(&tp);
    let path = pieces(&tp, P3::default());
    assert!(
        tp.moves.iter().any(|mv| matches!(mv, Move::Arc { .. })),
        "the pocket has arcs"
    );

    // 1. the whole pocket
    let (end, events) = m.stream(&program, 0, |_, _, _| {}).await;
    assert_eq!(end.expect("the pocket runs"), StreamEnd::Completed);
    let a = acked(&events);
    assert!(
        a.windows(2).all(|w| w[0] < w[1]),
        "acknowledged in order: {a:?}"
    );
    assert_eq!(
        a.last(),
        Some(&(program.len() - 1)),
        "every move acknowledged"
    );
    let pos = positions(&m);
    assert!(pos.len() > 1000, "{} SYNCs recorded", pos.len());
    let demand: Vec<P3> = pos.iter().map(|p| p.1).collect();
    let actual: Vec<P3> = pos.iter().map(|p| p.2).collect();
    let (d, at) = worst_distance(&path, demand.iter().copied());
    assert!(d <= 1e-3, "a set-point is {d:.6} mm off the path at {at:?}");
    let (d, at) = worst_distance(&path, actual.iter().copied());
    assert!(d <= 0.02, "a drive was {d:.6} mm off the path at {at:?}");
    check_limits("set-points", &demand);
    check_limits("positions", &actual);
    let last = *actual.last().unwrap();
    let end_of_path = tp.walk(P3::default(), |_, _, _| {});
    assert!(
        last.dist(end_of_path) < 1e-3,
        "ends at {last:?}, not {end_of_path:?}"
    );

    // 2. the same pocket again, held a third of the way and resumed 50 SYNCs later
    m.sim().drives.clear_traces();
    let third = program.len() / 3;
    let mut hold_sent = false;
    let mut held_at: Option<u64> = None;
    let mut resumed_at: Option<u64> = None;
    let (end, events) = m
        .stream(&program, 0, |ev, ctl, sim| match ev {
            LinkEvent::Acked { unit } if *unit >= third && !hold_sent => {
                hold_sent = true;
                ctl.send(Control::Hold).unwrap();
            }
            LinkEvent::Status(s) if s.state == DeviceState::Held && resumed_at.is_none() => {
                let now = sim.drives.with_drive(1, |d| d.syncs()).unwrap();
                let at = *held_at.get_or_insert(now);
                // the master reports its state every 100 ms while it keeps cycling
                if now >= at + 50 {
                    resumed_at = Some(now);
                    ctl.send(Control::Run).unwrap();
                }
            }
            _ => {}
        })
        .await;
    assert_eq!(end.expect("the held pocket runs"), StreamEnd::Completed);
    assert!(events
        .iter()
        .any(|e| matches!(e, LinkEvent::Status(s) if s.state == DeviceState::Running)));
    let (held_at, resumed_at) = (held_at.expect("held"), resumed_at.unwrap());
    let pos = positions(&m);
    let still: Vec<P3> = pos
        .iter()
        .filter(|p| p.0 > held_at && p.0 <= resumed_at)
        .map(|p| p.1)
        .collect();
    assert!(still.len() >= 40, "{} SYNCs while held", still.len());
    assert!(
        still.windows(2).all(|w| w[0] == w[1]),
        "the set-point stands while held"
    );
    let demand: Vec<P3> = pos.iter().map(|p| p.1).collect();
    // this run starts where the drives stopped (their 0x6064, whole counts)
    let stopped = P3::new(
        (last.x * SIGN[0] * COUNTS).round() / (SIGN[0] * COUNTS),
        (last.y * SIGN[1] * COUNTS).round() / (SIGN[1] * COUNTS),
        (last.z * SIGN[2] * COUNTS).round() / (SIGN[2] * COUNTS),
    );
    let path = pieces(&tp, stopped);
    let (d, at) = worst_distance(&path, demand.iter().copied());
    assert!(
        d <= 1e-3,
        "held run: a set-point is {d:.6} mm off the path at {at:?}"
    );
    check_limits("held run", &demand);
    assert_eq!(acked(&events).last(), Some(&(program.len() - 1)));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn each_injected_fault_stops_the_job_with_the_drives_reason_and_the_link_runs_the_next_after_unlock(
) {
    let mut table = settings();
    table["heartbeat_timeout_ms"] = 400.into();
    let mut m = Machine::start_with(table).await;
    // two depth passes: long enough for a silent node to be noticed before the end
    let job = m.program(&pocket_of_depth(2.0));
    let next = m.program(&square(5.0));
    let cases: Vec<(u8, DriveFault, Vec<&str>, Option<u32>)> = vec![
        (
            2,
            DriveFault::FollowingError { after_syncs: 300 },
            vec!["node 2 (axis y)", "EMCY 0x8611", "following error"],
            Some(0x8611),
        ),
        (
            3,
            DriveFault::Fault {
                after_syncs: 400,
                code: 0x2310,
            },
            vec!["node 3 (axis z)", "0x2310", "over-current"],
            Some(0x2310),
        ),
        (
            1,
            DriveFault::LoseSync { after_syncs: 250 },
            vec!["node 1 (axis x)", "0x8700", "SYNC"],
            Some(0x8700),
        ),
        (
            2,
            DriveFault::SdoAbort {
                index: 0x6060,
                sub: 0,
                code: 0x0609_0030,
            },
            vec!["node 2 (axis y)", "0x6060", "0x06090030", "invalid value"],
            Some(0x0609_0030),
        ),
        (
            3,
            DriveFault::Silent { after_syncs: 100 },
            vec!["node 3 (axis z)", "silent", "heartbeat"],
            None,
        ),
    ];
    for (node, fault, words, code) in cases {
        let what = format!("{fault:?} on node {node}");
        assert!(m.sim().drives.inject(node, fault.clone()));
        m.sim().drives.clear_traces();
        let (end, events) = m.stream(&job, 0, |_, _, _| {}).await;
        let Err(LinkError::Alarm { code: got, text }) = end else {
            panic!("{what}: the job should stop with an alarm, got {end:?}");
        };
        for w in &words {
            assert!(text.contains(w), "{what}: \"{text}\" does not say {w}");
        }
        assert_eq!(got, code, "{what}: {text}");
        // the state reached the caller typed
        let typed = events.iter().any(|e| match (e, &fault) {
            (LinkEvent::Status(s), DriveFault::Silent { .. }) => s.state == DeviceState::Offline,
            (LinkEvent::Status(s), _) => {
                matches!(&s.state, DeviceState::Alarm { code: Some(c), .. } if Some(*c) == code)
            }
            _ => false,
        });
        assert!(typed, "{what}: no typed state among {events:?}");
        // stopped: no drive is left following set-points, and nothing moves any more
        for n in 1..=3u8 {
            let state = m.sim().drives.with_drive(n, |d| d.power_state()).unwrap();
            assert_ne!(
                state,
                machlink_protocols::canopen::cia402::PowerState::OperationEnabled,
                "{what}: node {n} still enabled"
            );
        }
        let before = m.sim().drives.trace(1).len();
        tokio::time::sleep(Duration::from_millis(50)).await;
        assert_eq!(
            m.sim().drives.trace(1).len(),
            before,
            "{what}: set-points after the stop"
        );
        // a drive left in fault refuses the next program until the operator unlocks
        let in_fault = (1..=3u8).any(|n| {
            m.sim().drives.with_drive(n, |d| d.power_state()).unwrap()
                == machlink_protocols::canopen::cia402::PowerState::Fault
        });
        if in_fault {
            let (end, _) = m.stream(&next, 0, |_, _, _| {}).await;
            let Err(LinkError::Alarm { text, .. }) = end else {
                panic!(
                    "{what}: a drive in fault must refuse the next job until unlock, got {end:?}"
                );
            };
            assert!(
                text.contains("unlock"),
                "{what}: \"{text}\" does not say unlock"
            );
        }
        // after the operator's unlock the same link runs the next program
        m.link
            .operate(&machlink_protocols::link::Operation::Unlock)
            .await
            .unwrap_or_else(|e| panic!("{what}: unlock: {e}"));
        let (end, events) = m.stream(&next, 0, |_, _, _| {}).await;
        assert_eq!(
            end.unwrap_or_else(|e| panic!("after {what}: {e}")),
            StreamEnd::Completed
        );
        assert_eq!(
            acked(&events).last(),
            Some(&(next.len() - 1)),
            "after {what}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancelled_pocket_stops_on_the_path_disables_the_drives_and_resumes_after_the_last_acknowledged_move(
) {
    let mut m = Machine::start_with(settings()).await;
    let tp = pocket_path();
    let program = m.program(&tp);
    let half = program.len() / 2;
    let mut sent = false;
    let (end, events) = m
        .stream(&program, 0, |ev, ctl, _| {
            if matches!(ev, LinkEvent::Acked { unit } if *unit >= half) && !sent {
                sent = true;
                ctl.send(Control::Cancel).unwrap();
            }
        })
        .await;
    let Ok(StreamEnd::Cancelled { acked: done }) = end else {
        panic!("the job should end cancelled, got {end:?}");
    };
    assert!(
        done > half && done < program.len(),
        "{done} of {}",
        program.len()
    );
    assert_eq!(acked(&events).last(), Some(&(done - 1)));
    // braked on the path within the limits, then disabled (switched on)
    let pos = positions(&m);
    let demand: Vec<P3> = pos.iter().map(|p| p.1).collect();
    let (d, at) = worst_distance(&pieces(&tp, P3::default()), demand.iter().copied());
    assert!(d <= 1e-3, "a set-point is {d:.6} mm off the path at {at:?}");
    check_limits("cancelled run", &demand);
    for n in 1..=3u8 {
        let state = m.sim().drives.with_drive(n, |d| d.power_state()).unwrap();
        assert_eq!(
            state,
            machlink_protocols::canopen::cia402::PowerState::SwitchedOn,
            "node {n}"
        );
    }
    // resumed after the last acknowledged move: the rest of the program from where the
    // axes stood
    let (end, events) = m.stream(&program, done, |_, _, _| {}).await;
    assert_eq!(end.expect("the rest runs"), StreamEnd::Completed);
    let a = acked(&events);
    assert_eq!(a.first().copied().map(|u| u >= done), Some(true), "{a:?}");
    assert_eq!(a.last(), Some(&(program.len() - 1)));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cyclic_synchronous_position_paced_by_the_clock_follows_the_path_holds_and_resumes() {
    // real time, 4 times as fast: the clock thread sends every cycle's frames itself
    let mut table = settings();
    table["mode"] = "csp".into();
    table["transport"] = "memory".into();
    table["lockstep"] = false.into();
    table["time_scale"] = 4.0.into();
    let mut m = Machine::start_with(table).await;
    let mut tp = square(12.0);
    tp.push(Move::Arc {
        to: P3::new(6.0, 6.0, 0.0),
        center: offset_core::Point::new(3.0, 3.0),
        ccw: true,
        feed: 1500.0,
    });
    let program = m.program(&tp);
    let (mut hold_sent, mut held_at, mut resumed) = (false, None::<u64>, false);
    let (end, events) = m
        .stream(&program, 0, |ev, ctl, sim| match ev {
            LinkEvent::Acked { unit } if *unit >= 1 && !hold_sent => {
                hold_sent = true;
                ctl.send(Control::Hold).unwrap();
            }
            LinkEvent::Status(s) if s.state == DeviceState::Held && !resumed => {
                let now = sim.drives.with_drive(1, |d| d.syncs()).unwrap();
                if now >= *held_at.get_or_insert(now) + 50 {
                    resumed = true;
                    ctl.send(Control::Run).unwrap();
                }
            }
            _ => {}
        })
        .await;
    assert_eq!(end.expect("the square runs in CSP"), StreamEnd::Completed);
    assert!(resumed, "held and resumed");
    assert_eq!(acked(&events).last(), Some(&(program.len() - 1)));
    // the drives moved only because their 0x607A set-points came mapped by RPDO
    let pos = positions(&m);
    let demand: Vec<P3> = pos.iter().map(|p| p.1).collect();
    assert!(
        demand
            .iter()
            .any(|p| p.dist(P3::new(12.0, 12.0, 0.0)) < 0.01),
        "reaches the far corner"
    );
    let (d, at) = worst_distance(&pieces(&tp, P3::default()), demand.iter().copied());
    assert!(d <= 1e-3, "a set-point is {d:.6} mm off the path at {at:?}");
    check_limits("csp", &demand);
    check_limits(
        "csp positions",
        &pos.iter().map(|p| p.2).collect::<Vec<_>>(),
    );
}

#[tokio::test]
async fn nmt_commands_from_the_link_move_every_drive_between_states() {
    use machlink_protocols::canopen::master::{Axis, CanopenLink, CanopenOptions};
    use machlink_protocols::canopen::nmt::{NmtCommand, NmtState};
    use machlink_protocols::canopen::trajectory::AxisLimits;
    use machlink_protocols::canopen::MemoryBus;
    use machlink_sim::canopen::SimDrives;
    let bus = MemoryBus::new();
    let drives = SimDrives::spawn(&bus, &[4, 5], 1.0);
    let limits = AxisLimits {
        velocity: 10.0,
        acceleration: 100.0,
        jerk: 1000.0,
    };
    let axes = [(0, 4u8), (1, 5u8)]
        .map(|(axis, node)| Axis {
            axis,
            node,
            counts_per_mm: 1000.0,
            sign: 1.0,
            limits,
        })
        .to_vec();
    let mut link = CanopenLink::new(Box::new(bus.attach()), CanopenOptions::new(axes));
    let states = |d: &SimDrives| [4u8, 5].map(|n| d.with_drive(n, |d| d.nmt_state()).unwrap());
    for (cmd, want) in [
        (NmtCommand::Start, NmtState::Operational),
        (NmtCommand::Stop, NmtState::Stopped),
        (NmtCommand::PreOperational, NmtState::PreOperational),
        (NmtCommand::Start, NmtState::Operational),
        (NmtCommand::ResetCommunication, NmtState::PreOperational),
        (NmtCommand::Start, NmtState::Operational),
        (NmtCommand::ResetNode, NmtState::PreOperational),
    ] {
        link.nmt(cmd).await.unwrap();
        // the drives take the frames in their own tasks
        for _ in 0..200 {
            if states(&drives) == [want; 2] {
                break;
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        assert_eq!(states(&drives), [want; 2], "after {cmd:?}");
    }
}
