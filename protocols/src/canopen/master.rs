//! The CANopen master session: start-up (NMT, SDO configuration, PDO mapping read back,
//! heartbeat, CiA 402 power-up), then one cycle per SYNC period — the set-points of every
//! axis by RPDO, then the SYNC that applies them — while it watches heartbeats, EMCY and the
//! drives' position reports (TPDO), and obeys hold, resume and cancel.

use super::bus::{BusError, CanBus, FrameSink};
use super::cia402::{Command, Mode, PowerState};
use super::frame::CanFrame;
use super::nmt::{self, classify, Cob, Emcy, NmtCommand, NmtState};
use super::od::{self, Entry};
use super::pdo::{Mapped, Pdo};
use super::sdo::{self, AbortCode, SdoClient, SdoError, SdoStep};
use super::trajectory::{AxisLimits, Limits, Planner};
use crate::link::{Control, DeviceState, Link, LinkError, LinkEvent, MachineStatus, StreamEnd};
use futures::future::BoxFuture;
use offset_core::{Move, P3};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};

/// One axis: which coordinate, on which node, and its scale and limits.
#[derive(Clone, Debug, PartialEq)]
pub struct Axis {
    /// 0 = X, 1 = Y, 2 = Z.
    pub axis: usize,
    pub node: u8,
    /// Position counts per millimetre of travel.
    pub counts_per_mm: f64,
    /// 1, or −1 where the drive counts against the machine's axis.
    pub sign: f64,
    pub limits: AxisLimits,
}

impl Axis {
    fn name(&self) -> char {
        ['x', 'y', 'z'][self.axis.min(2)]
    }
    /// The set-point in counts for a coordinate in mm.
    pub fn counts(&self, mm: f64) -> i32 {
        (self.sign * self.counts_per_mm * mm)
            .round()
            .clamp(i32::MIN as f64, i32::MAX as f64) as i32
    }
    /// The coordinate in mm of a position in counts.
    pub fn mm(&self, counts: i32) -> f64 {
        counts as f64 / (self.sign * self.counts_per_mm)
    }
}

/// How the master paces its cycles.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pace {
    /// One SYNC every period divided by `scale` of wall time (1: real time, what drives need).
    RealTime { scale: f64 },
    /// The next cycle as soon as every drive has reported the last one (simulated drives in
    /// tests and benchmarks: as fast as the bus and the drives go).
    Lockstep,
}

/// Everything the master needs to know.
#[derive(Clone, Debug)]
pub struct CanopenOptions {
    pub axes: Vec<Axis>,
    pub mode: Mode,
    /// The SYNC (interpolation) period.
    pub period: Duration,
    pub pace: Pace,
    /// The heartbeat time written to each drive (0x1017).
    pub heartbeat: Duration,
    /// A drive whose heartbeat is older than this is silent: the job stops.
    pub heartbeat_timeout: Duration,
    /// How long one SDO response may take.
    pub sdo_timeout: Duration,
    /// How long one power state transition may take.
    pub state_timeout: Duration,
    /// How long after a SYNC a drive's position report (TPDO) may come.
    pub report_timeout: Duration,
    /// How long a node may take to answer after a reset.
    pub boot_timeout: Duration,
    /// Written to 0x6065 when set.
    pub following_error_window: Option<u32>,
    /// When set, the instant of every SYNC sent (for the jitter benchmark).
    pub sync_log: Option<Arc<Mutex<Vec<Instant>>>>,
}

impl CanopenOptions {
    /// Options with machlink's defaults for `axes`.
    pub fn new(axes: Vec<Axis>) -> CanopenOptions {
        CanopenOptions {
            axes,
            mode: Mode::InterpolatedPosition,
            period: Duration::from_millis(2),
            pace: Pace::RealTime { scale: 1.0 },
            heartbeat: Duration::from_millis(100),
            heartbeat_timeout: Duration::from_millis(500),
            sdo_timeout: Duration::from_millis(300),
            state_timeout: Duration::from_millis(500),
            report_timeout: Duration::from_millis(200),
            boot_timeout: Duration::from_secs(2),
            following_error_window: None,
            sync_log: None,
        }
    }

    fn limits(&self) -> Limits {
        let mut l = Limits::default();
        for a in &self.axes {
            l.axes[a.axis.min(2)] = Some(a.limits);
        }
        l
    }
}

/// What the master knows of one node.
struct Node {
    axis: Axis,
    sdo: SdoClient,
    rpdo: Pdo,
    tpdo: Pdo,
    /// When its last heartbeat came; None before heartbeats are asked for.
    heard: Option<Instant>,
    nmt: Option<NmtState>,
    /// When it was told to start (heartbeats sent before may still say pre-operational).
    started: Option<Instant>,
    /// Position reports (TPDO) since the stream's first SYNC.
    reports: u64,
    actual: i32,
    following: i32,
}

impl Node {
    fn who(&self) -> String {
        format!("node {} (axis {})", self.axis.node, self.axis.name())
    }
}

/// The set-point, then the position report.
fn rpdo_for(node: u8, mode: Mode) -> Pdo {
    Pdo::rpdo(1, node, vec![Mapped::new(mode.setpoint(), 32)])
}
fn tpdo_for(node: u8) -> Pdo {
    Pdo::tpdo(
        1,
        node,
        vec![
            Mapped::new(od::POSITION_ACTUAL, 32),
            Mapped::new(od::FOLLOWING_ERROR, 32),
        ],
    )
}

fn alarm(code: Option<u32>, text: String) -> LinkError {
    LinkError::Alarm { code, text }
}

fn bus_err(e: BusError) -> LinkError {
    match e {
        BusError::Io(e) => LinkError::Io(e),
        other => LinkError::Protocol(other.to_string()),
    }
}

/// A link to CiA 402 drives on one CAN bus.
pub struct CanopenLink {
    bus: Box<dyn CanBus>,
    opts: CanopenOptions,
    nodes: Vec<Node>,
    events: Option<mpsc::UnboundedSender<LinkEvent>>,
    /// An alarm or offline state went out in this stream.
    stopped_reported: bool,
    /// Heartbeats and EMCY stop what is under way (false while stopping the drives).
    watching: bool,
    /// The operator said `unlock`: the next start-up may reset a drive's fault. A drive
    /// found in fault otherwise refuses the job, as every kind's alarm waits for the
    /// operator.
    unlocked: bool,
}

/// The cycle clock: a thread that sleeps to just before each deadline (an absolute
/// `clock_nanosleep` on CLOCK_MONOTONIC, with its timer slack cut to 1 ns) and spins the last
/// stretch, at most a sixteenth of the period and never more than 150 µs, so it costs at
/// most about 6 % of one core at 2 ms. With a [`FrameSink`] it sends the cycle's frames itself
/// at the deadline — the session hands them over a cycle ahead — so the SYNC leaves on time
/// whatever the async runtime is doing; it then tells the session when they went out.
/// It asks for real-time scheduling (SCHED_FIFO), and runs without where that is refused.
struct Ticker {
    rx: mpsc::UnboundedReceiver<Result<Instant, String>>,
    frames: Option<std::sync::mpsc::Sender<Vec<CanFrame>>>,
    stop: Arc<AtomicBool>,
}

/// The clock wakes this long before each deadline at least and spins the rest.
const SPIN_MIN: Duration = Duration::from_micros(100);

/// How long before each deadline the clock wakes: the machine's own wake-up lateness,
/// learnt as it runs. A wake-up later than the margin allowed widens it to cover that
/// lateness with a quarter to spare, up to [`spin_cap`] of the period; otherwise it narrows
/// by a thousandth a cycle, so it settles where the rare late wake-ups of this machine fall.
/// A bare-metal or real-time kernel keeps it near the minimum. A virtual machine whose idle
/// vCPU wakes a thread later than the cap shows that lateness as jitter rather than paying
/// for it in CPU: the spin is bounded so the clock never takes more than a sixteenth of a
/// core.
struct WakeMargin {
    spin: Duration,
    max: Duration,
}

/// The longest the clock spins before a deadline: a sixteenth of the period, at most 150 µs.
fn spin_cap(interval: Duration) -> Duration {
    (interval / 16).min(Duration::from_micros(150))
}

impl WakeMargin {
    fn new(interval: Duration) -> WakeMargin {
        let max = spin_cap(interval);
        WakeMargin {
            spin: SPIN_MIN.min(max),
            max,
        }
    }

    /// The clock woke `late` after the time it asked for.
    fn woke(&mut self, late: Duration) {
        let floor = SPIN_MIN.min(self.max);
        if late + floor / 4 > self.spin {
            self.spin = (late + late / 4 + floor / 4).min(self.max);
        } else {
            self.spin = (self.spin - self.spin / 1000).max(floor);
        }
    }
}

/// Cuts the calling thread's timer slack to 1 ns (Linux lets a sleeping thread wake up to
/// 50 µs late by default, to batch wake-ups).
pub fn tight_timer_slack() {
    // SAFETY: prctl with PR_SET_TIMERSLACK takes a plain integer.
    unsafe {
        libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0);
    }
}

/// Sleeps until `wake` on CLOCK_MONOTONIC (the clock `Instant` reads), absolute, so a
/// preemption between computing and starting the sleep does not make it later.
pub fn sleep_until(wake: Instant) {
    let now = Instant::now();
    if wake <= now {
        return;
    }
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime and clock_nanosleep with valid pointers.
    unsafe {
        libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts);
        let d = wake - now;
        // (`as i64`: `c_long` is 32 bits on 32-bit Linux, where shop-floor ARM boards run)
        #[allow(clippy::unnecessary_cast)]
        let mut ns = ts.tv_nsec as i64 + d.subsec_nanos() as i64;
        #[allow(clippy::unnecessary_cast)]
        let mut sec = ts.tv_sec as i64 + d.as_secs() as i64;
        if ns >= 1_000_000_000 {
            ns -= 1_000_000_000;
            sec += 1;
        }
        let at = libc::timespec {
            tv_sec: sec as libc::time_t,
            tv_nsec: ns as _,
        };
        while libc::clock_nanosleep(
            libc::CLOCK_MONOTONIC,
            libc::TIMER_ABSTIME,
            &at,
            std::ptr::null_mut(),
        ) == libc::EINTR
        {}
    }
}

/// Asks for SCHED_FIFO for the calling thread; false where that is not allowed.
pub fn realtime_priority() -> bool {
    // SAFETY: plain calls on the current thread with a valid parameter block.
    unsafe {
        let param = libc::sched_param { sched_priority: 20 };
        libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) == 0
    }
}

impl Ticker {
    fn start(interval: Duration, mut sink: Option<Box<dyn FrameSink>>) -> Ticker {
        let (tx, rx) = mpsc::unbounded_channel();
        let (frames_tx, frames_rx) = std::sync::mpsc::channel::<Vec<CanFrame>>();
        let sends = sink.is_some();
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        std::thread::Builder::new()
            .name("canopen-sync".into())
            .spawn(move || {
                let rt = realtime_priority();
                tight_timer_slack();
                tracing::debug!("SYNC clock every {interval:?}, real-time scheduling: {rt}");
                let mut next = Instant::now() + interval;
                let mut margin = WakeMargin::new(interval);
                while !flag.load(Ordering::Relaxed) {
                    let batch = if sends {
                        match frames_rx.recv() {
                            Ok(b) => Some(b),
                            Err(_) => break,
                        }
                    } else {
                        None
                    };
                    let now = Instant::now();
                    if next > now + margin.spin {
                        let wake = next - margin.spin;
                        sleep_until(wake);
                        margin.woke(Instant::now().saturating_duration_since(wake));
                    }
                    while Instant::now() < next {
                        std::hint::spin_loop();
                    }
                    if flag.load(Ordering::Relaxed) {
                        // the session ended meanwhile: no more SYNC
                        break;
                    }
                    let sent = match (&mut sink, batch) {
                        (Some(sink), Some(b)) => sink
                            .send_now(&b)
                            .map(|()| Instant::now())
                            .map_err(|e| format!("the SYNC clock could not send: {e}")),
                        _ => Ok(next),
                    };
                    let failed = sent.is_err();
                    if tx.send(sent).is_err() || failed {
                        break;
                    }
                    next += interval;
                    // after a stall (a suspended machine) start afresh rather than burst
                    let now = Instant::now();
                    if now > next + interval * 50 {
                        next = now + interval;
                    }
                }
                tracing::debug!(
                    "SYNC clock stopped, waking {:?} before each deadline",
                    margin.spin
                );
            })
            .expect("a thread for the SYNC clock");
        Ticker {
            rx,
            frames: sends.then_some(frames_tx),
            stop,
        }
    }
}

impl Drop for Ticker {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

impl CanopenLink {
    /// A link on `bus` with `opts`; nothing is sent until the first stream.
    pub fn new(bus: Box<dyn CanBus>, opts: CanopenOptions) -> CanopenLink {
        let nodes = opts
            .axes
            .iter()
            .map(|a| Node {
                axis: a.clone(),
                sdo: SdoClient::new(),
                rpdo: rpdo_for(a.node, opts.mode),
                tpdo: tpdo_for(a.node),
                heard: None,
                nmt: None,
                started: None,
                reports: 0,
                actual: 0,
                following: 0,
            })
            .collect();
        CanopenLink {
            bus,
            opts,
            nodes,
            events: None,
            stopped_reported: false,
            watching: true,
            unlocked: false,
        }
    }

    fn event(&self, e: LinkEvent) {
        if let Some(tx) = &self.events {
            let _ = tx.send(e);
        }
    }

    fn status(&mut self, state: DeviceState, detail: String, feed: f64) {
        if matches!(state, DeviceState::Alarm { .. } | DeviceState::Offline) {
            self.stopped_reported = true;
        }
        let mut position = [0.0; 3];
        for n in &self.nodes {
            position[n.axis.axis.min(2)] = n.axis.mm(n.actual);
        }
        self.event(LinkEvent::Status(MachineStatus {
            state,
            detail,
            position,
            feed,
        }));
    }

    async fn send(&mut self, f: &CanFrame) -> Result<(), LinkError> {
        self.bus.send(f).await.map_err(bus_err)
    }

    /// Takes one frame: heartbeats, EMCY and position reports update the nodes; an SDO
    /// response is handed back. A drive's EMCY (other than "no error") fails the call.
    fn on_frame(&mut self, f: &CanFrame) -> Result<Option<(usize, [u8; 8])>, LinkError> {
        let Some(cob) = f.cob_id() else {
            return Ok(None);
        };
        let find = |nodes: &[Node], id: u8| nodes.iter().position(|n| n.axis.node == id);
        match classify(cob) {
            Cob::Heartbeat(id) => {
                if let (Some(i), Some((_, state))) =
                    (find(&self.nodes, id), nmt::parse_heartbeat(f))
                {
                    let n = &mut self.nodes[i];
                    if n.heard.is_some() {
                        n.heard = Some(Instant::now());
                    }
                    n.nmt = Some(state);
                }
            }
            Cob::Emcy(id) => {
                if let (Some(i), Some(e)) = (find(&self.nodes, id), Emcy::parse(f)) {
                    if e.code != 0 {
                        let text = format!(
                            "{} reported {} (error register 0x{:02X})",
                            self.nodes[i].who(),
                            e,
                            e.register
                        );
                        self.status(
                            DeviceState::Alarm {
                                code: Some(e.code as u32),
                                text: text.clone(),
                            },
                            format!("EMCY 0x{:04X} from node {id}", e.code),
                            0.0,
                        );
                        return Err(alarm(Some(e.code as u32), text));
                    }
                }
            }
            Cob::Tpdo(1, id) => {
                if let Some(i) = find(&self.nodes, id) {
                    let n = &mut self.nodes[i];
                    if let Some(v) = n.tpdo.unpack(f.data()) {
                        n.actual = v[0] as u32 as i32;
                        n.following = v[1] as u32 as i32;
                        n.reports += 1;
                    }
                }
            }
            Cob::SdoResponse(id) => {
                if let (Some(i), Ok(d)) = (find(&self.nodes, id), <[u8; 8]>::try_from(f.data())) {
                    return Ok(Some((i, d)));
                }
            }
            _ => {}
        }
        Ok(None)
    }

    /// Fails naming the first node whose heartbeat is overdue, or that left operational
    /// while `operational` is expected.
    fn check_nodes(&mut self, operational: bool) -> Result<(), LinkError> {
        if !self.watching {
            return Ok(());
        }
        let now = Instant::now();
        for n in &self.nodes {
            if let Some(t) = n.heard {
                let quiet = now.saturating_duration_since(t);
                if quiet > self.opts.heartbeat_timeout {
                    let text = format!(
                        "{} is silent: no heartbeat for {} ms (timeout {} ms)",
                        n.who(),
                        quiet.as_millis(),
                        self.opts.heartbeat_timeout.as_millis()
                    );
                    self.status(
                        DeviceState::Offline,
                        format!("node {} silent", n.axis.node),
                        0.0,
                    );
                    return Err(alarm(None, text));
                }
            }
            let settled = n
                .started
                .is_some_and(|t| now.saturating_duration_since(t) > self.opts.heartbeat_timeout);
            if operational {
                // heartbeats sent before the start may still be on their way
                let left = |s: &NmtState| *s != NmtState::Operational && settled;
                if let Some(s) = n.nmt.filter(left) {
                    return Err(alarm(
                        None,
                        format!("{} left operational: its heartbeat says {s}", n.who()),
                    ));
                }
            }
        }
        Ok(())
    }

    /// One SDO transfer with node `i`: upload (`write` None) or download.
    async fn sdo(
        &mut self,
        i: usize,
        entry: Entry,
        write: Option<&[u8]>,
    ) -> Result<Vec<u8>, LinkError> {
        self.sdo_within(i, entry, write, self.opts.sdo_timeout)
            .await
    }

    async fn sdo_within(
        &mut self,
        i: usize,
        entry: Entry,
        write: Option<&[u8]>,
        timeout: Duration,
    ) -> Result<Vec<u8>, LinkError> {
        let node = self.nodes[i].axis.node;
        let first = match write {
            Some(d) => self.nodes[i].sdo.download(entry.index, entry.sub, d),
            None => self.nodes[i].sdo.upload(entry.index, entry.sub),
        };
        let access = if write.is_some() {
            "download"
        } else {
            "upload"
        };
        self.send(&CanFrame::cob(sdo::request_cob(node), &first))
            .await?;
        let mut deadline = tokio::time::Instant::now() + timeout;
        loop {
            let f = match tokio::time::timeout_at(deadline, self.bus.recv()).await {
                Ok(r) => r.map_err(bus_err)?,
                Err(_) => {
                    let abort = self.nodes[i].sdo.cancel(AbortCode::TIMEOUT);
                    let _ = self
                        .send(&CanFrame::cob(sdo::request_cob(node), &abort))
                        .await;
                    return Err(LinkError::Protocol(format!(
                        "{} did not answer the SDO {access} of {entry} within {} ms",
                        self.nodes[i].who(),
                        timeout.as_millis()
                    )));
                }
            };
            self.check_nodes(false)?;
            let got = match self.on_frame(&f) {
                Ok(got) => got,
                Err(e) if self.watching => return Err(e),
                Err(_) => None,
            };
            let Some((j, data)) = got else {
                continue;
            };
            if j != i {
                continue;
            }
            match self.nodes[i].sdo.on_response(&data) {
                Ok(SdoStep::Send(r)) => {
                    self.send(&CanFrame::cob(sdo::request_cob(node), &r))
                        .await?;
                    deadline = tokio::time::Instant::now() + timeout;
                }
                Ok(SdoStep::Done(v)) => return Ok(v),
                Err(e) => {
                    let who = self.nodes[i].who();
                    return Err(match e {
                        SdoError::Aborted { code, .. } => alarm(Some(code.0), format!("{who} {e}")),
                        SdoError::Protocol { .. } => LinkError::Protocol(format!("{who} {e}")),
                    });
                }
            }
        }
    }

    async fn write(&mut self, i: usize, entry: Entry, data: &[u8]) -> Result<(), LinkError> {
        self.sdo(i, entry, Some(data)).await.map(|_| ())
    }

    async fn read_u32(&mut self, i: usize, entry: Entry) -> Result<u32, LinkError> {
        let v = self.sdo(i, entry, None).await?;
        let mut b = [0u8; 4];
        for (k, x) in v.iter().take(4).enumerate() {
            b[k] = *x;
        }
        Ok(u32::from_le_bytes(b))
    }

    async fn statusword(&mut self, i: usize) -> Result<u16, LinkError> {
        Ok(self.read_u32(i, od::STATUSWORD).await? as u16)
    }

    /// Collects frames (boot-ups) for `d`.
    async fn listen(&mut self, d: Duration) -> Result<(), LinkError> {
        let until = tokio::time::Instant::now() + d;
        while let Ok(r) = tokio::time::timeout_at(until, self.bus.recv()).await {
            let f = r.map_err(bus_err)?;
            // an EMCY of an old fault does not stop a start-up that resets it
            let _ = self.on_frame(&f);
        }
        Ok(())
    }

    /// Start-up: reset communication, check and configure every node, start them, and
    /// bring every drive to operation enabled. Returns the drives' position, mm.
    async fn start_up(&mut self) -> Result<P3, LinkError> {
        for n in &mut self.nodes {
            n.heard = None;
            n.nmt = None;
            n.started = None;
            n.sdo = SdoClient::new();
        }
        let ids: Vec<u8> = self.nodes.iter().map(|n| n.axis.node).collect();
        // a drive a crashed master left enabled is disabled before its PDOs are reset
        self.all_controlword_within(Command::Shutdown.controlword(), Duration::from_millis(50))
            .await;
        for id in &ids {
            self.send(&NmtCommand::ResetCommunication.frame(*id))
                .await?;
        }
        self.listen(Duration::from_millis(20)).await?;
        for i in 0..self.nodes.len() {
            self.configure(i).await?;
        }
        for id in &ids {
            self.send(&NmtCommand::Start.frame(*id)).await?;
        }
        let now = Instant::now();
        for n in &mut self.nodes {
            n.started = Some(now);
            // what the heartbeat said before the start (boot-up) is no news
            n.nmt = None;
        }
        for i in 0..self.nodes.len() {
            self.power_up(i).await?;
        }
        // the operator's unlock served this start-up; a later fault waits for another
        self.unlocked = false;
        let mut start = P3::default();
        for i in 0..self.nodes.len() {
            let counts = self.read_u32(i, od::POSITION_ACTUAL).await? as i32;
            let n = &mut self.nodes[i];
            n.actual = counts;
            let mm = n.axis.mm(counts);
            match n.axis.axis {
                0 => start.x = mm,
                1 => start.y = mm,
                _ => start.z = mm,
            }
        }
        Ok(start)
    }

    /// Checks the device type, writes the mode, the period, the PDOs (read back) and the
    /// heartbeat of node `i`.
    async fn configure(&mut self, i: usize) -> Result<(), LinkError> {
        // the node may still be booting after the reset: ask again until boot_timeout
        let until = Instant::now() + self.opts.boot_timeout;
        let device_type = loop {
            match self.read_u32(i, od::DEVICE_TYPE).await {
                Ok(v) => break v,
                Err(LinkError::Protocol(m))
                    if m.contains("did not answer") && Instant::now() < until => {}
                Err(e) => return Err(e),
            }
        };
        let who = self.nodes[i].who();
        if device_type as u16 != od::PROFILE_402 {
            return Err(alarm(
                None,
                format!(
                    "{who} is not a CiA 402 drive: its device type 0x1000 is 0x{device_type:08X} (profile {})",
                    device_type as u16
                ),
            ));
        }
        let mode = self.opts.mode;
        self.write(i, od::MODES_OF_OPERATION, &[mode.code() as u8])
            .await?;
        let ms = self.opts.period.as_millis().clamp(1, 255) as u8;
        self.write(i, od::IP_PERIOD_UNITS, &[ms]).await?;
        self.write(i, od::IP_PERIOD_INDEX, &[(-3i8) as u8]).await?;
        let us = self.opts.period.as_micros() as u32;
        match self
            .write(i, od::COMM_CYCLE_PERIOD, &us.to_le_bytes())
            .await
        {
            // 0x1006 is optional on a SYNC consumer
            Err(LinkError::Alarm { code: Some(c), .. }) if c == AbortCode::NO_OBJECT.0 => {}
            r => r?,
        }
        match self
            .write(
                i,
                od::QUICK_STOP_OPTION,
                &od::QUICK_STOP_THEN_DISABLED.to_le_bytes(),
            )
            .await
        {
            // 0x605A is optional: a drive without it keeps its own quick stop reaction
            Err(LinkError::Alarm { code: Some(c), .. }) if c == AbortCode::NO_OBJECT.0 => {}
            r => r?,
        }
        if let Some(w) = self.opts.following_error_window {
            self.write(i, od::FOLLOWING_ERROR_WINDOW, &w.to_le_bytes())
                .await?;
        }
        for pdo in [self.nodes[i].rpdo.clone(), self.nodes[i].tpdo.clone()] {
            for (entry, data) in pdo.writes() {
                self.write(i, entry, &data).await?;
            }
            for (entry, want) in pdo.expected() {
                let got = self.sdo(i, entry, None).await?;
                let as_int = |b: &[u8]| b.iter().rev().fold(0u64, |v, x| (v << 8) | *x as u64);
                if as_int(&got) != as_int(&want) {
                    return Err(alarm(
                        None,
                        format!(
                            "{who} reads back {entry} as {got:02X?} after machlink wrote {want:02X?}: the PDO mapping did not take"
                        ),
                    ));
                }
            }
        }
        let hb = self.opts.heartbeat.as_millis().clamp(1, u16::MAX as u128) as u16;
        self.write(i, od::PRODUCER_HEARTBEAT, &hb.to_le_bytes())
            .await?;
        self.nodes[i].heard = Some(Instant::now());
        Ok(())
    }

    /// Drives node `i` through the power state machine to operation enabled, one transition
    /// at a time, each within `state_timeout`.
    async fn power_up(&mut self, i: usize) -> Result<(), LinkError> {
        let mode = self.opts.mode;
        let mut sw = self.statusword(i).await?;
        for _ in 0..8 {
            let state = PowerState::from_statusword(sw);
            if state == Some(PowerState::Fault) && !self.unlocked {
                return Err(alarm(
                    None,
                    format!(
                        "{} is in fault from before this job (statusword 0x{sw:04X}): clear its cause, then `machlink unlock` the machine",
                        self.nodes[i].who()
                    ),
                ));
            }
            let Some(cmd) = state.and_then(|s| s.toward_enabled()) else {
                if state == Some(PowerState::OperationEnabled) {
                    let shown = self.sdo(i, od::MODES_DISPLAY, None).await?;
                    let shown = shown.first().map(|b| *b as i8);
                    if shown != Some(mode.code()) {
                        return Err(alarm(
                            None,
                            format!(
                                "{} shows mode {:?} in 0x6061 after machlink asked for {mode}",
                                self.nodes[i].who(),
                                shown
                            ),
                        ));
                    }
                    return Ok(());
                }
                sw = self.wait_state(i, sw, None).await?;
                continue;
            };
            let word = match cmd {
                Command::EnableOperation => mode.enable_word(),
                Command::FaultReset => {
                    // a reset is a rising edge of bit 7
                    self.write(i, od::CONTROLWORD, &0u16.to_le_bytes()).await?;
                    cmd.controlword()
                }
                _ => cmd.controlword(),
            };
            self.write(i, od::CONTROLWORD, &word.to_le_bytes()).await?;
            let want = state.and_then(|s| s.on(cmd));
            sw = self.wait_state(i, sw, want).await?;
        }
        Err(alarm(
            None,
            format!(
                "{} did not reach operation enabled (statusword 0x{sw:04X})",
                self.nodes[i].who()
            ),
        ))
    }

    /// Polls the statusword until the state is `want` (or, with None, changes), at most
    /// `state_timeout`.
    async fn wait_state(
        &mut self,
        i: usize,
        from: u16,
        want: Option<PowerState>,
    ) -> Result<u16, LinkError> {
        let until = Instant::now() + self.opts.state_timeout;
        let from_state = PowerState::from_statusword(from);
        loop {
            let sw = self.statusword(i).await?;
            let s = PowerState::from_statusword(sw);
            let arrived = match want {
                Some(w) => s == Some(w),
                None => s != from_state,
            };
            if arrived {
                return Ok(sw);
            }
            if Instant::now() >= until {
                let to = want
                    .map(|w| w.to_string())
                    .unwrap_or_else(|| "another state".into());
                let now = s
                    .map(|s| s.to_string())
                    .unwrap_or_else(|| "an undefined state".into());
                return Err(alarm(
                    None,
                    format!(
                        "{} did not go to {to} within {} ms: it is in {now} (statusword 0x{sw:04X})",
                        self.nodes[i].who(),
                        self.opts.state_timeout.as_millis()
                    ),
                ));
            }
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
    }

    /// Sends NMT command `cmd` to every axis's node (start, stop, pre-operational, reset
    /// node, reset communication), outside a stream.
    pub async fn nmt(&mut self, cmd: NmtCommand) -> Result<(), LinkError> {
        let ids: Vec<u8> = self.nodes.iter().map(|n| n.axis.node).collect();
        for id in ids {
            self.send(&cmd.frame(id)).await?;
        }
        Ok(())
    }

    /// Writes `word` to every drive's controlword, best effort (after a fault or a cancel).
    async fn all_controlword(&mut self, word: u16) {
        let t = self.opts.sdo_timeout.min(Duration::from_millis(100));
        self.all_controlword_within(word, t).await
    }

    async fn all_controlword_within(&mut self, word: u16, t: Duration) {
        self.watching = false;
        for i in 0..self.nodes.len() {
            let _ = self
                .sdo_within(i, od::CONTROLWORD, Some(&word.to_le_bytes()), t)
                .await;
        }
        self.watching = true;
    }

    /// After a failed start-up: every drive that answers is shut down (operation disabled)
    /// and every node goes back to pre-operational, so none waits for set-points.
    async fn disable_after_failed_start(&mut self) {
        self.all_controlword(Command::Shutdown.controlword()).await;
        let ids: Vec<u8> = self.nodes.iter().map(|n| n.axis.node).collect();
        for id in ids {
            let _ = self.send(&NmtCommand::PreOperational.frame(id)).await;
        }
    }

    /// The set-point frames of one cycle.
    fn setpoints(&self, p: P3, out: &mut Vec<CanFrame>) {
        out.clear();
        for n in &self.nodes {
            let mm = [p.x, p.y, p.z][n.axis.axis.min(2)];
            let counts = n.axis.counts(mm);
            out.push(n.rpdo.pack(&[counts as u32 as u64]));
        }
    }

    async fn run(
        &mut self,
        units: &[Move],
        from: usize,
        control: &mut watch::Receiver<Control>,
    ) -> Result<StreamEnd, LinkError> {
        if *control.borrow() == Control::Cancel {
            return Ok(StreamEnd::Cancelled { acked: from });
        }
        let start = match self.start_up().await {
            Ok(start) => start,
            Err(e) => {
                self.disable_after_failed_start().await;
                return Err(e);
            }
        };
        let period = self.opts.period.as_secs_f64();
        let mut planner = Planner::new(&units[from..], start, &self.opts.limits(), period)
            .map_err(|e| LinkError::Rejected {
                unit: from,
                text: units
                    .get(from)
                    .map(|m| format!("{m:?}"))
                    .unwrap_or_default(),
                reason: e.to_string(),
            })?;
        for n in &mut self.nodes {
            n.reports = 0;
        }
        self.status(
            DeviceState::Running,
            format!(
                "{} every {} ms",
                self.opts.mode,
                self.opts.period.as_millis()
            ),
            0.0,
        );
        let result = self.cycles(&mut planner, units.len(), from, control).await;
        match &result {
            Ok(_) => {
                // motion is over: disable operation (switched on), no more SYNC
                self.all_controlword(Command::SwitchOn.controlword()).await;
                self.status(DeviceState::Idle, "switched on".into(), 0.0);
            }
            Err(_) => {
                // stop every drive that still follows
                self.all_controlword(Command::QuickStop.controlword()).await;
            }
        }
        result
    }

    async fn cycles(
        &mut self,
        planner: &mut Planner,
        total: usize,
        from: usize,
        control: &mut watch::Receiver<Control>,
    ) -> Result<StreamEnd, LinkError> {
        let lockstep = self.opts.pace == Pace::Lockstep;
        let interval = match self.opts.pace {
            Pace::RealTime { scale } => self.opts.period.div_f64(scale.max(1e-6)),
            Pace::Lockstep => self.opts.period,
        };
        let mut ticker = match self.opts.pace {
            Pace::RealTime { .. } => Some(Ticker::start(interval, self.bus.frame_sink())),
            Pace::Lockstep => None,
        };
        // the clock thread gets the frames of about 10 ms of cycles ahead, so a session that
        // is late by less than that (a busy machine) never delays a SYNC; hold and cancel
        // take effect that much later
        let lead = (Duration::from_millis(10).as_secs_f64() / interval.as_secs_f64())
            .ceil()
            .clamp(2.0, 16.0) as usize;
        let mut inflight: std::collections::VecDeque<Option<super::trajectory::Cycle>> =
            Default::default();
        let sync = nmt::sync_frame();
        let mut frames = Vec::with_capacity(self.nodes.len() + 1);
        let mut sent_at: std::collections::VecDeque<Instant> = Default::default();
        let mut first_unreported = 0u64;
        let mut pending: std::collections::VecDeque<(u64, usize)> = Default::default();
        let mut acked = 0usize;
        let mut cycle = 0u64;
        let mut next = planner.next_cycle();
        let mut last = planner.position();
        let mut planned_last = last;
        let mut held_reported = false;
        // at an operator stop (a tool change, a program stop): whether it was reported, and
        // whether the operator's hold has come since (the run after it releases the stop)
        let mut operator_reported = false;
        let mut operator_held = false;
        let mut settling = 0u32;
        let mut cancelling = false;
        let mut last_status = Instant::now();
        let sync_log = self.opts.sync_log.clone();
        let relative_total = total - from;
        let clock_sends = ticker.as_ref().is_some_and(|t| t.frames.is_some());
        loop {
            // the set-points of a cycle, then the SYNC that applies them
            if clock_sends {
                // the clock thread sends them at their cycle's moment
                while inflight.len() < lead {
                    self.setpoints(next.map_or(planned_last, |c| c.position), &mut frames);
                    frames.push(sync);
                    if let Some(tx) = ticker.as_ref().and_then(|t| t.frames.as_ref()) {
                        let _ = tx.send(frames.clone());
                    }
                    inflight.push_back(next);
                    if let Some(c) = next {
                        planned_last = c.position;
                    }
                    next = if cancelling && held_reported {
                        None
                    } else {
                        planner.next_cycle()
                    };
                }
            } else {
                self.setpoints(next.map_or(last, |c| c.position), &mut frames);
                frames.push(sync);
            }
            let mut sent_now: Option<Instant> = None;
            // wait for the cycle's moment, handling frames meanwhile
            // lockstep: the next cycle once every drive has reported, or after one period
            let lockstep_until = tokio::time::Instant::now() + self.opts.period;
            loop {
                if lockstep
                    && (self.nodes.iter().all(|n| n.reports >= cycle)
                        || tokio::time::Instant::now() >= lockstep_until)
                {
                    if planner.is_at_rest() && (cancelling || *control.borrow() == Control::Hold) {
                        // nothing moves: do not spin
                        tokio::time::sleep(Duration::from_micros(500)).await;
                    }
                    break;
                }
                let wait = if lockstep {
                    lockstep_until.saturating_duration_since(tokio::time::Instant::now())
                } else {
                    self.opts.report_timeout.min(self.opts.heartbeat_timeout)
                };
                let tick = async {
                    match ticker.as_mut() {
                        Some(t) => t.rx.recv().await,
                        None => std::future::pending().await,
                    }
                };
                tokio::select! {
                    biased;
                    t = tick => {
                        match t {
                            Some(Ok(at)) => sent_now = Some(at),
                            Some(Err(e)) => return Err(LinkError::Protocol(e)),
                            None => return Err(LinkError::Protocol("the SYNC clock stopped".into())),
                        }
                        break;
                    }
                    f = tokio::time::timeout(wait, self.bus.recv()) => {
                        if let Ok(f) = f {
                            let f = f.map_err(bus_err)?;
                            self.on_frame(&f)?;
                        }
                    }
                }
                self.check_nodes(true)?;
            }
            let this = if clock_sends {
                inflight.pop_front().flatten()
            } else {
                for f in &frames {
                    self.bus.send(f).await.map_err(bus_err)?;
                }
                next
            };
            let now = match (clock_sends, sent_now) {
                (true, Some(at)) => at,
                _ => Instant::now(),
            };
            if let Some(log) = &sync_log {
                log.lock().unwrap().push(now);
            }
            sent_at.push_back(now);
            cycle += 1;
            if let Some(c) = this {
                pending.push_back((cycle, c.passed));
                last = c.position;
            }
            // drives' reports: acknowledge what every drive has taken
            let reported = self.nodes.iter().map(|n| n.reports).min().unwrap_or(cycle);
            while sent_at.len() > 1 && first_unreported < reported {
                sent_at.pop_front();
                first_unreported += 1;
            }
            if let Some(t) = sent_at.front() {
                if reported < cycle && now.saturating_duration_since(*t) > self.opts.report_timeout
                {
                    let late = self
                        .nodes
                        .iter()
                        .find(|n| n.reports == reported)
                        .map(|n| n.who())
                        .unwrap_or_default();
                    return Err(alarm(
                        None,
                        format!(
                            "{late} did not report its position for SYNC {} within {} ms",
                            reported + 1,
                            self.opts.report_timeout.as_millis()
                        ),
                    ));
                }
            }
            while let Some(&(c, passed)) = pending.front() {
                if c > reported {
                    break;
                }
                pending.pop_front();
                if passed > acked {
                    acked = passed;
                    self.event(LinkEvent::Acked {
                        unit: from + acked - 1,
                    });
                }
            }
            self.check_nodes(true)?;
            // the operator
            let ctl = *control.borrow_and_update();
            match ctl {
                Control::Run if !cancelling => {
                    planner.set_hold(false);
                    if held_reported {
                        held_reported = false;
                        self.status(DeviceState::Running, "resumed".into(), 0.0);
                    }
                }
                Control::Hold if !cancelling => planner.set_hold(true),
                Control::Cancel => {
                    cancelling = true;
                    planner.set_hold(true);
                }
                _ => {}
            }
            // an operator stop: the path stands at rest and says why; the daemon pauses the
            // job, and only the operator's resume after that (a hold, then run) goes on
            let waiting = planner.operator_stop().cloned();
            if let Some(reason) = waiting.filter(|_| !cancelling) {
                let standing_now = this.is_none_or(|c| c.speed == 0.0);
                if !operator_reported && standing_now {
                    operator_reported = true;
                    operator_held = false;
                    self.status(
                        DeviceState::NeedsOperator {
                            reason: reason.clone(),
                        },
                        format!("{reason} at unit {}", from + acked),
                        0.0,
                    );
                }
                if ctl == Control::Hold {
                    operator_held = true;
                } else if ctl == Control::Run && operator_held && operator_reported {
                    planner.release();
                    operator_reported = false;
                    operator_held = false;
                    self.status(DeviceState::Running, "resumed".into(), 0.0);
                }
            }
            let standing = |c: &Option<super::trajectory::Cycle>| c.is_none_or(|c| c.speed == 0.0);
            if planner.is_at_rest()
                && (ctl == Control::Hold || cancelling)
                && (cancelling || planner.operator_stop().is_none())
                && !held_reported
                && standing(&this)
                && standing(&next)
                && inflight.iter().all(standing)
            {
                held_reported = true;
                if !cancelling {
                    self.status(DeviceState::Held, "held on the path".into(), 0.0);
                }
            }
            // cancelled and at rest: no more set-points; done once the drives have
            // reported the last ones
            if cancelling
                && held_reported
                && pending.is_empty()
                && inflight.iter().all(Option::is_none)
            {
                return Ok(StreamEnd::Cancelled {
                    acked: from + acked,
                });
            }
            if this.is_none()
                && next.is_none()
                && inflight.iter().all(Option::is_none)
                && pending.is_empty()
                && acked >= relative_total
            {
                // finished moving: every drive within a micrometre of its last set-point
                // (or, for a drive that never gets there, after half a second)
                settling += 1;
                let settled = self.nodes.iter().all(|n| {
                    (n.following.unsigned_abs() as f64) <= (n.axis.counts_per_mm * 1e-3).max(1.0)
                });
                if settled || settling as f64 * self.opts.period.as_secs_f64() > 0.5 {
                    return Ok(StreamEnd::Completed);
                }
            }
            if last_status.elapsed() > Duration::from_millis(100) {
                last_status = Instant::now();
                let state =
                    if let Some(reason) = planner.operator_stop().filter(|_| operator_reported) {
                        DeviceState::NeedsOperator {
                            reason: reason.clone(),
                        }
                    } else if held_reported {
                        DeviceState::Held
                    } else {
                        DeviceState::Running
                    };
                let feed = this.map(|c| c.speed * 60.0).unwrap_or(0.0);
                self.status(state, format!("SYNC {cycle}"), feed);
            }
            if !clock_sends {
                next = if cancelling && held_reported {
                    None
                } else {
                    planner.next_cycle()
                };
            }
        }
    }
}

impl Link<Move> for CanopenLink {
    fn stream<'a>(
        &'a mut self,
        units: &'a [Move],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        mut control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        Box::pin(async move {
            self.events = Some(events);
            self.stopped_reported = false;
            let r = self.run(units, from.min(units.len()), &mut control).await;
            if let Err(LinkError::Alarm { code, text }) = &r {
                if !self.stopped_reported {
                    // a stop found in start-up (an SDO abort, a power-up timeout): typed too
                    let state = DeviceState::Alarm {
                        code: *code,
                        text: text.clone(),
                    };
                    self.status(state, "start-up stopped".into(), 0.0);
                }
            }
            self.events = None;
            r
        })
    }

    fn operate<'a>(
        &'a mut self,
        op: &'a crate::link::Operation,
    ) -> BoxFuture<'a, Result<String, LinkError>> {
        Box::pin(async move {
            match op {
                crate::link::Operation::Unlock => {
                    self.unlocked = true;
                    Ok("unlocked: a drive still in fault is reset (fault reset, 0x6040 bit 7) when the next job enables it".into())
                }
                other => Err(LinkError::unsupported(
                    &other.name(),
                    "a CANopen machine takes only unlock between jobs",
                )),
            }
        })
    }
}

#[cfg(test)]
mod clock_tests {
    use super::*;

    #[test]
    fn the_wake_margin_covers_late_wake_ups_up_to_its_cap_and_settles_back() {
        let us = Duration::from_micros;
        let mut m = WakeMargin::new(us(2000));
        assert_eq!(m.spin, SPIN_MIN);
        m.woke(us(10));
        assert_eq!(m.spin, SPIN_MIN, "an on-time wake-up keeps the minimum");
        m.woke(us(100));
        assert!(
            m.spin >= us(125),
            "a wake-up 100 µs late is covered: {:?}",
            m.spin
        );
        m.woke(us(5000));
        assert_eq!(m.spin, us(125), "never more than a sixteenth of the period");
        for _ in 0..10_000 {
            m.woke(us(20));
        }
        assert_eq!(
            m.spin, SPIN_MIN,
            "on-time wake-ups bring it back to the minimum"
        );
        let mut long = WakeMargin::new(us(8000));
        long.woke(us(5000));
        assert_eq!(long.spin, us(150), "never more than 150 µs");
        let mut short = WakeMargin::new(us(1000));
        short.woke(us(400));
        assert_eq!(
            short.spin,
            us(62) + Duration::from_nanos(500),
            "a sixteenth of 1 ms"
        );
    }
}
