//! CANopen master benchmarks (docs/BENCHMARKS.md, "CANopen master"):
//! 1. set-points per second the master sustains in lockstep with three simulated drives on
//!    the in-memory bus, against what the bus could carry at 1 Mbit/s and 500 kbit/s (every
//!    frame counted in bits, stuffing included), and the planner alone;
//! 2. SYNC period jitter of the master at 1, 2 and 4 ms periods over CANOPEN_JITTER_SECS
//!    (60 by default) each, against a tokio interval at 1 ms measured in the same run, with
//!    the CPU time of the SYNC clock's thread (`canopen-sync`, from
//!    /proc/self/task/TID/schedstat) and of the whole process over the same stretch; and,
//!    before each period, a bare sleeping thread at the same period (the platform's own
//!    wake-up lateness: what any clock on this machine gets without spinning).
//!
//! `cargo bench -p machlink-sim --bench canopen_bench` (`CANOPEN_PERIODS_MS=2` for one
//! period)

use machlink_protocols::canopen::master::{
    realtime_priority, sleep_until, tight_timer_slack, Axis, CanopenLink, CanopenOptions, Pace,
};
use machlink_protocols::canopen::trajectory::{AxisLimits, Limits, Planner};
use machlink_protocols::canopen::MemoryBus;
use machlink_protocols::{Control, Link, StreamEnd};
use machlink_sim::canopen::SimDrives;
use offset_core::{Move, Point, P3};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};

const LIMITS: AxisLimits = AxisLimits {
    velocity: 150.0,
    acceleration: 2000.0,
    jerk: 50_000.0,
};

fn axes() -> Vec<Axis> {
    (0..3)
        .map(|i| Axis {
            axis: i,
            node: i as u8 + 1,
            counts_per_mm: 10_000.0,
            sign: 1.0,
            limits: LIMITS,
        })
        .collect()
}

/// A serpentine of 100 mm lines joined by half circles, `rows` rows, at 6000 mm/min.
fn serpentine(rows: usize) -> Vec<Move> {
    let mut m = vec![Move::Rapid {
        to: P3::new(0.0, 0.0, 1.0),
    }];
    for r in 0..rows {
        let y = r as f64 * 4.0;
        let x1 = if r % 2 == 0 { 100.0 } else { 0.0 };
        m.push(Move::Linear {
            to: P3::new(x1, y, 1.0),
            feed: 6000.0,
        });
        m.push(Move::Arc {
            to: P3::new(x1, y + 4.0, 1.0),
            center: Point::new(x1, y + 2.0),
            ccw: r % 2 == 0,
            feed: 6000.0,
        });
    }
    m
}

fn options(pace: Pace, log: Arc<Mutex<Vec<Instant>>>) -> CanopenOptions {
    options_at(pace, log, Duration::from_millis(1))
}

fn options_at(pace: Pace, log: Arc<Mutex<Vec<Instant>>>, period: Duration) -> CanopenOptions {
    let mut o = CanopenOptions::new(axes());
    o.period = period;
    o.pace = pace;
    o.heartbeat_timeout = Duration::from_secs(2);
    o.report_timeout = Duration::from_secs(2);
    o.sync_log = Some(log);
    o
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// (p50, p99, max) of |interval − period| in µs.
fn jitter(instants: &[Instant], period: Duration) -> (f64, f64, f64, usize) {
    let mut d: Vec<f64> = instants
        .windows(2)
        .map(|w| ((w[1] - w[0]).as_secs_f64() - period.as_secs_f64()).abs() * 1e6)
        .collect();
    d.sort_by(|a, b| a.partial_cmp(b).unwrap());
    (
        percentile(&d, 0.5),
        percentile(&d, 0.99),
        *d.last().unwrap(),
        d.len(),
    )
}

async fn throughput() {
    let moves = serpentine(60);
    // the planner alone
    let mut limits = Limits::default();
    for i in 0..3 {
        limits.axes[i] = Some(LIMITS);
    }
    let t0 = Instant::now();
    let mut planner = Planner::new(&moves, P3::default(), &limits, 0.001).unwrap();
    let mut cycles = 0u64;
    while planner.next_cycle().is_some() {
        cycles += 1;
    }
    let plan = t0.elapsed();
    println!(
        "planner alone: {cycles} cycles ({:.1} s of motion at 1 ms) in {:.3} s: {:.0} cycles/s, {:.0} set-points/s",
        cycles as f64 / 1000.0,
        plan.as_secs_f64(),
        cycles as f64 / plan.as_secs_f64(),
        3.0 * cycles as f64 / plan.as_secs_f64()
    );

    // the master in lockstep with three simulated drives
    let bus = MemoryBus::new();
    let _drives = SimDrives::spawn(&bus, &[1, 2, 3], 1.0);
    let log = Arc::new(Mutex::new(Vec::new()));
    let mut link = CanopenLink::new(Box::new(bus.attach()), options(Pace::Lockstep, log.clone()));
    let (tx, _rx) = mpsc::unbounded_channel();
    let (_ctl, ctl_rx) = watch::channel(Control::Run);
    let before = bus.stats();
    let end = link
        .stream(&moves, 0, tx, ctl_rx)
        .await
        .expect("the serpentine runs");
    assert_eq!(end, StreamEnd::Completed);
    let after = bus.stats();
    let syncs = log.lock().unwrap().clone();
    let n = syncs.len() as f64;
    let wall = (*syncs.last().unwrap() - syncs[0]).as_secs_f64();
    let bits = (after.bits - before.bits) as f64;
    let frames = (after.frames - before.frames) as f64;
    let per_cycle = bits / n;
    println!(
        "master in lockstep, 3 drives, in-memory bus: {} SYNCs in {wall:.2} s: {:.0} cycles/s, {:.0} set-points/s",
        syncs.len(),
        n / wall,
        3.0 * n / wall
    );
    println!(
        "bus: {frames:.0} frames, {bits:.0} bits, {:.2} frames and {per_cycle:.1} bits per cycle (SYNC, 3 RPDO, 3 TPDO, heartbeats, start-up SDO)",
        frames / n
    );
    for rate in [1_000_000.0, 500_000.0] {
        let cycles = rate / per_cycle;
        println!(
            "bus capacity at {:.0} kbit/s: {:.0} cycles/s = {:.0} set-points/s (shortest period {:.0} µs); the master sustains {:.1} × that",
            rate / 1000.0,
            cycles,
            3.0 * cycles,
            1e6 / cycles,
            (n / wall) / cycles
        );
    }
}

/// The CPU time the thread named `name` of this process has had, from its schedstat (ns).
fn thread_cpu(name: &str) -> Option<Duration> {
    for t in std::fs::read_dir("/proc/self/task").ok()?.flatten() {
        let comm = std::fs::read_to_string(t.path().join("comm")).unwrap_or_default();
        if comm.trim() == name {
            let st = std::fs::read_to_string(t.path().join("schedstat")).ok()?;
            let ns: u64 = st.split_whitespace().next()?.parse().ok()?;
            return Some(Duration::from_nanos(ns));
        }
    }
    None
}

/// The CPU time of every thread of this process now alive, from their schedstat.
fn process_cpu() -> Duration {
    let mut ns = 0u64;
    for t in std::fs::read_dir("/proc/self/task")
        .into_iter()
        .flatten()
        .flatten()
    {
        let st = std::fs::read_to_string(t.path().join("schedstat")).unwrap_or_default();
        ns += st
            .split_whitespace()
            .next()
            .and_then(|x| x.parse::<u64>().ok())
            .unwrap_or(0);
    }
    Duration::from_nanos(ns)
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .unwrap_or_default()
        .split_whitespace()
        .take(3)
        .collect::<Vec<_>>()
        .join(" ")
}

async fn anchor_jitter(secs: u64) {
    let period = Duration::from_millis(1);
    // anchor: a tokio interval at 1 ms, same process, same load
    let anchor_secs = (secs / 4).max(5);
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
    let mut t = Vec::with_capacity(anchor_secs as usize * 1000 + 10);
    let until = Instant::now() + Duration::from_secs(anchor_secs);
    while Instant::now() < until {
        tick.tick().await;
        t.push(Instant::now());
    }
    let (p50, p99, max, n) = jitter(&t, period);
    println!(
        "anchor: tokio::time::interval at 1 ms for {anchor_secs} s ({n} ticks): |jitter| p50 {p50:.1} µs, p99 {p99:.1} µs, max {max:.1} µs"
    );
}

/// The second anchor: what a sleeping thread gets from this machine. A thread with the SYNC
/// clock's settings and its sleep (SCHED_FIFO where allowed, timer slack 1 ns, an absolute
/// `clock_nanosleep`: the master's own functions) sleeps to each deadline of `period` and
/// does nothing else: its jitter is what
/// the clock would show without spinning, and its lateness (woken − deadline) is the spin a
/// clock needs to be on time; the p99 lateness as a share of the period is what that spin
/// costs in CPU.
fn sleep_anchor(secs: u64, period: Duration) {
    let n = (Duration::from_secs(secs).as_nanos() / period.as_nanos()) as u32;
    let (realtime, woke, mut late) = std::thread::spawn(move || {
        let realtime = realtime_priority();
        tight_timer_slack();
        let start = Instant::now();
        let (mut woke, mut late) = (Vec::with_capacity(n as usize), Vec::new());
        for k in 1..=n {
            let deadline = start + period * k;
            sleep_until(deadline);
            let now = Instant::now();
            woke.push(now);
            late.push(now.saturating_duration_since(deadline).as_secs_f64() * 1e6);
        }
        (realtime, woke, late)
    })
    .join()
    .expect("the sleeping anchor's thread ran");
    let (p50, p99, max, periods) = jitter(&woke, period);
    late.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let late_p99 = percentile(&late, 0.99);
    println!(
        "anchor: a bare thread (SCHED_FIFO: {}) sleeping by clock_nanosleep to each {} ms deadline for {secs} s ({periods} periods): |jitter| p50 {p50:.1} µs, p99 {p99:.1} µs, max {max:.1} µs; woken late by p50 {:.1} µs, p99 {late_p99:.1} µs, max {:.1} µs (a spin covering the p99 lateness: {:.1} % of a core); load average {}",
        if realtime { "yes" } else { "refused" },
        period.as_millis(),
        percentile(&late, 0.5),
        late.last().unwrap(),
        late_p99 / (period.as_secs_f64() * 1e6) * 100.0,
        load_average()
    );
}

async fn sync_jitter(secs: u64, period: Duration) {
    let bus = MemoryBus::new();
    let _drives = SimDrives::spawn(&bus, &[1, 2, 3], 1.0);
    let log = Arc::new(Mutex::new(Vec::new()));
    let opts = options_at(Pace::RealTime { scale: 1.0 }, log.clone(), period);
    let mut link = CanopenLink::new(Box::new(bus.attach()), opts);
    let (tx, _rx) = mpsc::unbounded_channel();
    let (ctl, ctl_rx) = watch::channel(Control::Run);
    // long enough to outlast the measurement; cancelled when it is over
    let moves = serpentine(400);
    let load_before = load_average();
    let stop = {
        let log = log.clone();
        async move {
            // the CPU counters from the first SYNC to the end of the measured stretch
            let mut first: Option<(Instant, Duration, Duration)> = None;
            loop {
                tokio::time::sleep(Duration::from_millis(100)).await;
                let (len, first_at, last_at) = {
                    let l = log.lock().unwrap();
                    (l.len(), l.first().copied(), l.last().copied())
                };
                if first.is_none() && len > 0 {
                    if let Some(c) = thread_cpu("canopen-sync") {
                        first = Some((Instant::now(), c, process_cpu()));
                    }
                }
                if let (Some(a), Some(b)) = (first_at, last_at) {
                    if len > 1 && b - a >= Duration::from_secs(secs) {
                        break;
                    }
                }
            }
            let clock = thread_cpu("canopen-sync");
            let all = process_cpu();
            let _ = ctl.send(Control::Cancel);
            first.zip(clock).map(|((t0, c0, p0), c1)| {
                let wall = t0.elapsed().as_secs_f64();
                (
                    (c1 - c0).as_secs_f64() / wall,
                    (all.saturating_sub(p0)).as_secs_f64() / wall,
                )
            })
        }
    };
    let (end, cpu) = tokio::join!(link.stream(&moves, 0, tx, ctl_rx), stop);
    end.expect("the serpentine runs until cancelled");
    let syncs = log.lock().unwrap().clone();
    let (p50, p99, max, n) = jitter(&syncs, period);
    let ms = period.as_millis();
    println!(
        "master SYNC at {ms} ms for {secs} s ({n} periods, 3 simulated drives): |jitter| p50 {p50:.1} µs, p99 {p99:.1} µs, max {max:.1} µs; load average {load_before} before, {} after",
        load_average()
    );
    match cpu {
        Some((clock, all)) => println!(
            "CPU at {ms} ms: SYNC clock thread {:.1} % of one core; every thread of the process (session, drives, clock) {:.1} %",
            clock * 100.0,
            all * 100.0
        ),
        None => println!("CPU at {ms} ms: the SYNC clock thread was not found"),
    }
}

fn main() {
    let secs: u64 = std::env::var("CANOPEN_JITTER_SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        throughput().await;
        anchor_jitter(secs).await;
        let periods: Vec<u64> = std::env::var("CANOPEN_PERIODS_MS")
            .ok()
            .map(|v| v.split(',').filter_map(|p| p.trim().parse().ok()).collect())
            .unwrap_or_else(|| vec![1, 2, 4]);
        for ms in periods {
            sleep_anchor((secs / 4).max(5), Duration::from_millis(ms));
            sync_jitter(secs, Duration::from_millis(ms)).await;
        }
    });
}
