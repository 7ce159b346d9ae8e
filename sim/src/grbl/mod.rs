//! A simulated GRBL 1.1 controller on a pty: receive buffer that drops on overflow, planner,
//! motion in simulated time, real-time commands, check mode, alarms and fault injection.
//!
//! Three threads share one [`machine::Machine`]: a reader that delivers bytes from the pty
//! (paced like a UART when a baud rate is set), a clock that finishes blocks as simulated
//! time passes, and a writer that paces replies back. The wire is paced in wall time; only
//! motion runs on the simulated clock.

pub mod deviation;
pub mod interp;
pub mod machine;

pub use deviation::max_deviation;
pub use interp::Motion;

use crate::pty::{wait_ready, Pty};
use machine::Machine;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::fs::File;
use std::io::{self, Read, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A fault the simulator injects on purpose.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum GrblFault {
    /// Answer `error:code` to the `line`-th G-code line received (1-based; `$` lines and
    /// empty lines are not counted).
    ErrorAtLine { line: u64, code: u8 },
    /// Raise `ALARM:code` on the `line`-th G-code line received: motion stops, the
    /// planner empties, and everything but status and reset is ignored until a reset.
    AlarmAtLine { line: u64, code: u8 },
    /// Answer the first `line` G-code lines, then hang for `seconds` (wall time), as a
    /// controller whose main loop stopped: no `ok`, no answer to `?` or any real-time
    /// byte, and every byte that arrives meanwhile is lost (the next line, the rest of the
    /// receive buffer, status requests). Blocks already planned run to their end. After
    /// `seconds` it answers again, standing where its last planned block ended.
    SilentAfterLine { line: u64, seconds: f64 },
}

/// How the simulated controller behaves.
#[derive(Clone, Debug, PartialEq)]
pub struct GrblSimConfig {
    /// Simulated seconds per wall second for motion; `f64::INFINITY` finishes every move
    /// the moment it is planned (the planner never fills).
    pub time_scale: f64,
    /// Pace bytes both ways as a UART at this rate would (10 bits per byte).
    pub baud: Option<u32>,
    /// Receive buffer in bytes (GRBL on an ATmega328p: 128).
    pub rx_buffer: usize,
    /// Planner blocks (GRBL on an ATmega328p: 15).
    pub planner_blocks: usize,
    /// Fastest feed, mm/min.
    pub max_feed: f64,
    /// Rapid rate, mm/min.
    pub rapid_feed: f64,
    /// Acceleration, mm/s².
    pub accel: f64,
    pub faults: Vec<GrblFault>,
    /// Homing enabled (`$22=1`): the controller starts locked in alarm until `$H` (or
    /// `$X`), and `$H` runs the cycle to the machine's zero. Off: `$H` is error:5.
    pub homing: bool,
    /// The work offsets of G54 … G59 at power-up (machine position of each work zero), mm.
    pub work_offsets: [[f64; 3]; 6],
    /// Append every line received and every move executed to this file, one JSON object
    /// per line (see [`TraceEvent`]).
    pub trace_file: Option<PathBuf>,
    /// A touch plate whose top is at this machine Z: `G38.2` stops there (None: no plate).
    pub touch_plate_z: Option<f64>,
    /// Takes `M6` as a grblHAL with a manual tool changer does, holding there until cycle
    /// start (as at `M0`; the real controller's `Tool` state and its 0xA3 acknowledge are
    /// not simulated). Off (GRBL 1.1): `M6` is error 20.
    pub m6_holds: bool,
}

/// What the simulated controller did, as its trace (and `--trace FILE`) records it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum TraceEvent {
    /// A line taken from the receive buffer, as it arrived (comments included); `n` counts
    /// the G-code lines from 1 (`$` lines have none).
    Received {
        n: Option<u64>,
        line: String,
    },
    /// A motion line executed to its end (machine coordinates; `feed` as overridden).
    Executed(Executed),
    /// A jog ended (or was cancelled) with the tool here, machine coordinates.
    Jogged {
        to: [f64; 3],
    },
    /// The homing cycle ended at the machine's zero.
    Homed,
    /// `$X` cleared the alarm lock.
    Unlocked,
    /// The cable was pulled (the pty closed) or put back (a new pty at the same path).
    Unplugged,
    Plugged,
}

impl Default for GrblSimConfig {
    fn default() -> Self {
        GrblSimConfig {
            time_scale: 1.0,
            baud: None,
            rx_buffer: 128,
            planner_blocks: 15,
            max_feed: 5000.0,
            rapid_feed: 5000.0,
            accel: 500.0,
            faults: Vec::new(),
            homing: false,
            work_offsets: [[0.0; 3]; 6],
            trace_file: None,
            touch_plate_z: None,
            m6_holds: false,
        }
    }
}

/// One motion line the simulator executed to its end.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Executed {
    /// 1-based ordinal of the G-code line among those received.
    pub index: u64,
    /// The line as received (spaces and comments removed, upper case).
    pub line: String,
    pub motion: Motion,
    pub from: [f64; 3],
    pub to: [f64; 3],
    /// Absolute XY centre of an arc.
    pub center: Option<[f64; 2]>,
    /// Feed the move ran at, mm/min (the rapid rate for rapids).
    pub feed: f64,
}

struct Shared {
    machine: Mutex<Machine>,
    wake: Condvar,
    stop: AtomicBool,
    /// The pty the wire runs on; None while the cable is out.
    port: Mutex<Option<Plug>>,
    /// Bumped on every unplug and replug, so the wire threads take the new pty.
    generation: AtomicU64,
    /// The path kept pointing at the current pty, when asked for one.
    link: Option<PathBuf>,
}

/// One pty the controller is plugged into.
#[derive(Clone)]
struct Plug {
    pty: Arc<Pty>,
}

impl Plug {
    fn new() -> io::Result<Plug> {
        Ok(Plug {
            pty: Arc::new(Pty::open()?),
        })
    }
    fn file(&self) -> io::Result<File> {
        Ok(File::from(self.pty.master.try_clone()?))
    }
}

impl Shared {
    /// The current pty's master end (and its generation), or None while unplugged.
    fn wire(&self) -> Option<(u64, File)> {
        let g = self.generation.load(Ordering::SeqCst);
        let port = self.port.lock().unwrap_or_else(|p| p.into_inner());
        port.as_ref().and_then(|p| p.file().ok()).map(|f| (g, f))
    }
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Machine> {
        // a panicking simulator thread must not hide the trace from the test that reads it
        self.machine.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The simulated GRBL controller.
pub struct GrblSim;

/// A running simulated controller; dropping it stops it.
pub struct GrblSimHandle {
    shared: Arc<Shared>,
    threads: Vec<JoinHandle<()>>,
}

fn check_config(cfg: &GrblSimConfig) -> io::Result<()> {
    let bad = |what: String| Err(io::Error::new(io::ErrorKind::InvalidInput, what));
    if cfg.time_scale.is_nan() || cfg.time_scale <= 0.0 {
        return bad(format!(
            "time scale {} must be above 0 (simulated seconds per wall second)",
            cfg.time_scale
        ));
    }
    if cfg.rx_buffer < 2 || cfg.planner_blocks < 1 {
        return bad("the receive buffer needs 2 bytes and the planner 1 block at least".into());
    }
    if cfg.baud == Some(0) {
        return bad("a baud rate of 0 cannot carry bytes".into());
    }
    for (name, v) in [
        ("max feed", cfg.max_feed),
        ("rapid feed", cfg.rapid_feed),
        ("acceleration", cfg.accel),
    ] {
        if v.is_nan() || v <= 0.0 || v.is_infinite() {
            return bad(format!("{name} {v} must be a positive number"));
        }
    }
    if cfg.work_offsets.iter().flatten().any(|v| !v.is_finite()) {
        return bad("work offsets must be numbers".into());
    }
    for f in &cfg.faults {
        if let GrblFault::SilentAfterLine { seconds, .. } = f {
            if !(seconds.is_finite() && *seconds >= 0.0) {
                return bad(format!(
                    "a silence of {seconds} s must be a number of seconds, 0 or more"
                ));
            }
        }
    }
    Ok(())
}

impl GrblSim {
    /// Starts a simulated controller on a new pty. Runs on its own threads; it may be
    /// called inside or outside a tokio runtime.
    pub fn spawn_pty(cfg: GrblSimConfig) -> io::Result<GrblSimHandle> {
        Self::spawn(cfg, None)
    }

    /// Starts a simulated controller on a new pty and keeps `link` a symbolic link to it
    /// (replacing an old link), also across an unplug and replug: the path a machine's
    /// `port` names, as `/dev/ttyUSB0` names a real controller.
    pub fn spawn_linked(cfg: GrblSimConfig, link: &std::path::Path) -> io::Result<GrblSimHandle> {
        Self::spawn(cfg, Some(link.to_path_buf()))
    }

    fn spawn(cfg: GrblSimConfig, link: Option<PathBuf>) -> io::Result<GrblSimHandle> {
        check_config(&cfg)?;
        let plug = Plug::new()?;
        if let Some(l) = &link {
            crate::pty::symlink_replacing(&plug.pty.path, l)?;
        }
        let byte_time = cfg.baud.map(|b| Duration::from_secs_f64(10.0 / b as f64));
        let trace_file = cfg.trace_file.clone();
        let trace = match &trace_file {
            Some(p) => Some(
                std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(p)
                    .map_err(|e| {
                        io::Error::new(
                            e.kind(),
                            format!("cannot open the trace file {}: {e}", p.display()),
                        )
                    })?,
            ),
            None => None,
        };
        let shared = Arc::new(Shared {
            machine: Mutex::new(Machine::new(cfg, Instant::now())),
            wake: Condvar::new(),
            stop: AtomicBool::new(false),
            port: Mutex::new(Some(plug)),
            generation: AtomicU64::new(0),
            link,
        });
        let (out_tx, out_rx) = mpsc::channel::<Vec<u8>>();
        let mut threads = Vec::new();

        // the writer: replies back to the client, paced like a UART
        {
            let shared = shared.clone();
            threads.push(std::thread::spawn(move || {
                writer_loop(out_rx, &shared, byte_time)
            }));
        }
        // the reader: bytes from the client into the controller
        {
            let shared = shared.clone();
            let out_tx = out_tx.clone();
            threads.push(std::thread::spawn(move || {
                reader_loop(&shared, &out_tx, byte_time)
            }));
        }
        // the clock: finishes blocks as simulated time passes
        {
            let shared = shared.clone();
            threads.push(std::thread::spawn(move || clock_loop(&shared, &out_tx)));
        }
        // the trace file, appended as things happen
        if let Some(file) = trace {
            let shared = shared.clone();
            threads.push(std::thread::spawn(move || trace_loop(file, &shared)));
        }
        Ok(GrblSimHandle { shared, threads })
    }
}

/// Appends the trace's new events to `file` every 20 ms, one JSON object per line.
fn trace_loop(mut file: File, shared: &Shared) {
    let mut written = 0usize;
    loop {
        let stop = shared.stop.load(Ordering::Relaxed);
        let new: Vec<TraceEvent> = {
            let m = shared.lock();
            m.events[written..].to_vec()
        };
        written += new.len();
        let mut buf = Vec::new();
        for e in &new {
            if let Ok(mut l) = serde_json::to_vec(e) {
                l.push(b'\n');
                buf.extend(l);
            }
        }
        if !buf.is_empty() && (file.write_all(&buf).is_err() || file.flush().is_err()) {
            return;
        }
        if stop {
            return;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A simulated controller served on a byte stream by a tokio task instead of threads (no
/// UART pacing): in a `start_paused` test its motion runs on tokio's simulated clock, so a
/// session replays the same to the byte every time.
pub struct GrblTask {
    machine: Arc<Mutex<Machine>>,
    task: tokio::task::JoinHandle<()>,
}

impl GrblSim {
    /// Serves a simulated controller on `io` from a tokio task (see [`GrblTask`]).
    pub fn spawn_on<S>(io: S, cfg: GrblSimConfig) -> io::Result<GrblTask>
    where
        S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Send + 'static,
    {
        check_config(&cfg)?;
        // The machine counts std time; map tokio's (perhaps paused) clock onto it.
        let (t0, s0) = (tokio::time::Instant::now(), Instant::now());
        let clock = move || s0 + (tokio::time::Instant::now() - t0);
        let machine = Arc::new(Mutex::new(Machine::new(cfg, clock())));
        let m = Arc::clone(&machine);
        let task = tokio::spawn(async move {
            use tokio::io::{AsyncReadExt, AsyncWriteExt};
            let (mut rd, mut wr) = tokio::io::split(io);
            let mut buf = [0u8; 512];
            loop {
                let (out, wait) = {
                    let mut m = m.lock().unwrap_or_else(|p| p.into_inner());
                    m.process(clock());
                    (m.take_output(), m.next_event())
                };
                if !out.is_empty() && wr.write_all(&out).await.is_err() {
                    return;
                }
                let wait = wait.unwrap_or(Duration::from_secs(3600));
                tokio::select! {
                    r = rd.read(&mut buf) => {
                        let Ok(n) = r else { return };
                        if n == 0 {
                            return;
                        }
                        let mut m = m.lock().unwrap_or_else(|p| p.into_inner());
                        for &b in &buf[..n] {
                            m.receive(b, clock());
                        }
                    }
                    _ = tokio::time::sleep(wait.max(Duration::from_micros(100))) => {}
                }
            }
        });
        Ok(GrblTask { machine, task })
    }
}

impl GrblTask {
    /// Every motion line executed to its end, in order.
    pub fn trace(&self) -> Vec<Executed> {
        self.machine
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .trace
            .clone()
    }
}

impl Drop for GrblTask {
    fn drop(&mut self) {
        self.task.abort();
    }
}

fn flush(m: &mut Machine, out: &mpsc::Sender<Vec<u8>>) {
    let bytes = m.take_output();
    if !bytes.is_empty() {
        let _ = out.send(bytes);
    }
}

fn reader_loop(shared: &Shared, out: &mpsc::Sender<Vec<u8>>, byte_time: Option<Duration>) {
    let mut buf = [0u8; 512];
    // bytes read from the pty, each with the time its last bit reaches the controller
    let mut wire: VecDeque<(Instant, u8)> = VecDeque::new();
    let mut wire_free = Instant::now();
    let mut master: Option<(u64, File)> = None;
    while !shared.stop.load(Ordering::Relaxed) {
        let g = shared.generation.load(Ordering::SeqCst);
        if master.as_ref().is_none_or(|(mg, _)| *mg != g) {
            // unplugged or replugged: bytes on the old wire never arrive
            master = shared.wire();
            wire.clear();
        }
        let Some((_, file)) = master.as_mut() else {
            std::thread::sleep(Duration::from_millis(10));
            continue;
        };
        let wait = match wire.front() {
            Some(&(due, _)) => due
                .saturating_duration_since(Instant::now())
                .min(Duration::from_millis(20)),
            None => Duration::from_millis(20),
        };
        // poll() counts in milliseconds: wait out shorter UART gaps by sleeping
        let wait = if wait < Duration::from_millis(1) {
            std::thread::sleep(wait);
            Duration::ZERO
        } else {
            wait
        };
        if wait_ready(&*file, false, wait).unwrap_or(false) {
            match file.read(&mut buf) {
                Ok(n) if n > 0 => {
                    let now = Instant::now();
                    for &b in &buf[..n] {
                        let due = match byte_time {
                            Some(bt) => {
                                wire_free = wire_free.max(now) + bt;
                                wire_free
                            }
                            None => now,
                        };
                        wire.push_back((due, b));
                    }
                }
                Ok(_) => {}
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
                Err(_) => std::thread::sleep(Duration::from_millis(20)),
            }
        }
        let now = Instant::now();
        if wire.front().is_some_and(|&(due, _)| due <= now) {
            let mut m = shared.lock();
            while let Some(&(due, b)) = wire.front() {
                if due > now {
                    break;
                }
                wire.pop_front();
                m.receive(b, now);
            }
            m.process(now);
            flush(&mut m, out);
            drop(m);
            shared.wake.notify_all();
        }
    }
}

fn clock_loop(shared: &Shared, out: &mpsc::Sender<Vec<u8>>) {
    let mut m = shared.lock();
    while !shared.stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        m.process(now);
        flush(&mut m, out);
        let wait = m
            .next_event()
            .unwrap_or(Duration::from_millis(50))
            .clamp(Duration::from_micros(100), Duration::from_millis(50));
        m = match shared.wake.wait_timeout(m, wait) {
            Ok((g, _)) => g,
            Err(p) => p.into_inner().0,
        };
    }
}

fn writer_loop(rx: mpsc::Receiver<Vec<u8>>, shared: &Shared, byte_time: Option<Duration>) {
    let mut free = Instant::now();
    let mut master: Option<(u64, File)> = None;
    while !shared.stop.load(Ordering::Relaxed) {
        let chunk = match rx.recv_timeout(Duration::from_millis(50)) {
            Ok(c) => c,
            Err(mpsc::RecvTimeoutError::Timeout) => {
                if master
                    .as_ref()
                    .is_some_and(|(g, _)| *g != shared.generation.load(Ordering::SeqCst))
                {
                    master = None;
                }
                continue;
            }
            Err(mpsc::RecvTimeoutError::Disconnected) => return,
        };
        let g = shared.generation.load(Ordering::SeqCst);
        if master.as_ref().is_none_or(|(mg, _)| *mg != g) {
            master = shared.wire();
        }
        // with the cable out, what the controller says is lost
        let Some((_, file)) = master.as_mut() else {
            continue;
        };
        // the wire was idle until this chunk came (if it had finished the last one)
        free = free.max(Instant::now());
        let mut sent = 0;
        while sent < chunk.len() {
            if shared.stop.load(Ordering::Relaxed) || shared.generation.load(Ordering::SeqCst) != g
            {
                break;
            }
            // bytes whose last bit has left the UART by now
            let upto = match byte_time {
                None => chunk.len(),
                Some(bt) => {
                    let now = Instant::now();
                    let done = if now > free {
                        (now - free).as_secs_f64() / bt.as_secs_f64()
                    } else {
                        0.0
                    };
                    let k = (sent + done as usize).min(chunk.len());
                    if k == sent {
                        std::thread::sleep((free + bt).saturating_duration_since(now));
                        continue;
                    }
                    k
                }
            };
            match file.write(&chunk[sent..upto]) {
                Ok(n) => {
                    sent += n;
                    if let Some(bt) = byte_time {
                        free += bt * n as u32;
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                    let _ = wait_ready(&*file, true, Duration::from_millis(20));
                }
                Err(_) => std::thread::sleep(Duration::from_millis(20)),
            }
        }
    }
}

impl GrblSimHandle {
    /// The path a client opens (e.g. with `GrblLink::open`): the symbolic link when it was
    /// spawned with one, else the current pty.
    pub fn port(&self) -> PathBuf {
        if let Some(l) = &self.shared.link {
            return l.clone();
        }
        let port = self.shared.port.lock().unwrap_or_else(|p| p.into_inner());
        port.as_ref()
            .map(|p| p.pty.path.clone())
            .unwrap_or_else(|| PathBuf::from("/dev/null/unplugged"))
    }
    /// Pulls the cable: the pty closes (a client reading it gets end of file or an I/O
    /// error), the symbolic link (if any) is removed, and what either side sends is lost.
    /// The controller goes on with what it has, as a controller with its own power does.
    pub fn unplug(&self) {
        let old = self
            .shared
            .port
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take();
        self.shared.generation.fetch_add(1, Ordering::SeqCst);
        if let Some(l) = &self.shared.link {
            let _ = std::fs::remove_file(l);
        }
        drop(old);
        self.shared.lock().events.push(TraceEvent::Unplugged);
    }
    /// Puts the cable back: a new pty, and the symbolic link pointing at it.
    pub fn replug(&self) -> io::Result<()> {
        let plug = Plug::new()?;
        if let Some(l) = &self.shared.link {
            crate::pty::symlink_replacing(&plug.pty.path, l)?;
        }
        *self.shared.port.lock().unwrap_or_else(|p| p.into_inner()) = Some(plug);
        self.shared.generation.fetch_add(1, Ordering::SeqCst);
        self.shared.lock().events.push(TraceEvent::Plugged);
        Ok(())
    }
    /// Everything the trace records, in order.
    pub fn events(&self) -> Vec<TraceEvent> {
        self.shared.lock().events.clone()
    }
    /// Where the tool is, machine coordinates.
    pub fn position(&self) -> [f64; 3] {
        self.shared.lock().position()
    }
    /// Every motion line executed to its end, in order.
    pub fn trace(&self) -> Vec<Executed> {
        self.shared.lock().trace.clone()
    }
    /// G-code lines received (`$` lines and empty lines not counted).
    pub fn received_lines(&self) -> u64 {
        self.shared.lock().received
    }
    /// Bytes dropped because the receive buffer was full.
    pub fn rx_overflows(&self) -> u64 {
        self.shared.lock().overflows
    }
    /// Simulated time the machine spent moving or dwelling.
    pub fn sim_time(&self) -> Duration {
        Duration::from_secs_f64(self.shared.lock().motion_time.max(0.0))
    }
    /// Stops the simulator and waits for its threads.
    pub fn shutdown(self) {}
}

impl Drop for GrblSimHandle {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        self.shared.wake.notify_all();
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
        if let Some(l) = &self.shared.link {
            let _ = std::fs::remove_file(l);
        }
    }
}
