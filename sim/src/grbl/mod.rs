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

use crate::pty::{wait_ready, Pty, PtyLink};
use machine::Machine;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::fs::File;
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
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
    port: PathBuf,
    link: Option<PtyLink>,
    _pty: Arc<Pty>,
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
    Ok(())
}

impl GrblSim {
    /// Starts a simulated controller on a new pty. Runs on its own threads; it may be
    /// called inside or outside a tokio runtime.
    pub fn spawn_pty(cfg: GrblSimConfig) -> io::Result<GrblSimHandle> {
        Self::spawn_pty_at(cfg, None)
    }

    /// As [`GrblSim::spawn_pty`], with `link` made a symbolic link to the pty (an old link
    /// of that name is replaced; the link goes when the handle is dropped).
    pub fn spawn_pty_at(cfg: GrblSimConfig, link: Option<&Path>) -> io::Result<GrblSimHandle> {
        check_config(&cfg)?;
        let pty = Arc::new(Pty::open()?);
        let port = pty.path.clone();
        let link = PtyLink::optional(&port, link)?;
        let byte_time = cfg.baud.map(|b| Duration::from_secs_f64(10.0 / b as f64));
        let shared = Arc::new(Shared {
            machine: Mutex::new(Machine::new(cfg, Instant::now())),
            wake: Condvar::new(),
            stop: AtomicBool::new(false),
        });
        let (out_tx, out_rx) = mpsc::channel::<Vec<u8>>();
        let (master_r, master_w) = pty.blocking()?;
        let mut threads = Vec::new();

        // the writer: replies back to the client, paced like a UART
        {
            let shared = shared.clone();
            threads.push(std::thread::spawn(move || {
                writer_loop(master_w, out_rx, &shared, byte_time)
            }));
        }
        // the reader: bytes from the client into the controller
        {
            let shared = shared.clone();
            let out_tx = out_tx.clone();
            threads.push(std::thread::spawn(move || {
                reader_loop(master_r, &shared, &out_tx, byte_time)
            }));
        }
        // the clock: finishes blocks as simulated time passes
        {
            let shared = shared.clone();
            threads.push(std::thread::spawn(move || clock_loop(&shared, &out_tx)));
        }
        Ok(GrblSimHandle {
            shared,
            threads,
            port,
            link,
            _pty: pty,
        })
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

fn reader_loop(
    mut master: File,
    shared: &Shared,
    out: &mpsc::Sender<Vec<u8>>,
    byte_time: Option<Duration>,
) {
    let mut buf = [0u8; 512];
    // bytes read from the pty, each with the time its last bit reaches the controller
    let mut wire: VecDeque<(Instant, u8)> = VecDeque::new();
    let mut wire_free = Instant::now();
    while !shared.stop.load(Ordering::Relaxed) {
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
        if wait_ready(&master, false, wait).unwrap_or(false) {
            match master.read(&mut buf) {
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

fn writer_loop(
    mut master: File,
    rx: mpsc::Receiver<Vec<u8>>,
    shared: &Shared,
    byte_time: Option<Duration>,
) {
    let mut free = Instant::now();
    while !shared.stop.load(Ordering::Relaxed) {
        let chunk = match rx.recv_timeout(Duration::from_millis(50)) {
            Ok(c) => c,
            Err(mpsc::RecvTimeoutError::Timeout) => continue,
            Err(mpsc::RecvTimeoutError::Disconnected) => return,
        };
        // the wire was idle until this chunk came (if it had finished the last one)
        free = free.max(Instant::now());
        let mut sent = 0;
        while sent < chunk.len() {
            if shared.stop.load(Ordering::Relaxed) {
                return;
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
            match master.write(&chunk[sent..upto]) {
                Ok(n) => {
                    sent += n;
                    if let Some(bt) = byte_time {
                        free += bt * n as u32;
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                    let _ = wait_ready(&master, true, Duration::from_millis(20));
                }
                Err(_) => std::thread::sleep(Duration::from_millis(20)),
            }
        }
    }
}

impl GrblSimHandle {
    /// The path a client opens (e.g. with `GrblLink::open`): the link if one was asked
    /// for, else the pty.
    pub fn port(&self) -> PathBuf {
        self.link
            .as_ref()
            .map_or_else(|| self.port.clone(), |l| l.path().to_path_buf())
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
    }
}
