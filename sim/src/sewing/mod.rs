//! A simulated pattern sewing machine that speaks the pattern transfer protocol, sews in simulated time, injects faults and records every needle drop.
//!
//! It validates an uploaded pattern (count, CRC-32, every record inside the sewing area and no
//! step longer than its longest stitch) before it will sew, sews one record per stitch cycle
//! at the set stitches per minute (sped up by the time scale), and answers STATUS with its
//! stitch counter. Faults on request: bytes corrupted or dropped in both directions, a thread
//! break before a given stitch (the machine waits for RESUME), and a power loss before a given
//! stitch (the pattern is lost and must be uploaded again; the stitch counter is kept, as in
//! the machine's non-volatile memory). Colour changes and stops are passed over (a
//! single-needle pattern sewer).

pub mod cli;
pub mod pty;

use machlink_protocols::sewing::wire::{
    refusal, reply, req, Decoded, Decoder, Frame, Info, SewingState, Status,
};
use machlink_protocols::sewing::{pattern_crc, StitchKind, StitchRecord};
use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

/// How the simulated machine is built and which faults it injects.
#[derive(Clone, Debug, PartialEq)]
pub struct SewingSimConfig {
    /// Stitches per minute.
    pub spm: u32,
    /// Simulated time runs this many times faster than real time.
    pub time_scale: f64,
    /// Probability per byte, in each direction, that the byte is lost (half the cases) or has
    /// one bit flipped (the other half).
    pub noise: f64,
    /// Seed of the noise.
    pub seed: u64,
    /// The thread breaks when the machine is about to sew these records (once each).
    pub thread_break_at: Vec<u32>,
    /// The power fails when the machine is about to sew these records (once each).
    pub power_loss_at: Vec<u32>,
    /// `(n, silence)`: once `n` records are sewn the machine holds (as on HOLD) and its
    /// controller hangs for `silence`: every byte that arrives meanwhile is lost and
    /// nothing is answered, STATUS included. Afterwards it answers again, still held at
    /// stitch `n`, until RESUME.
    pub silent_after: Option<(u32, Duration)>,
    /// The sewing area, 0.1 mm: min x, min y, max x, max y.
    pub area: [i32; 4],
    /// The longest step of one record, 0.1 mm.
    pub max_stitch: u16,
    /// Pace the line both ways at this baud rate (10 bits a byte); `None`: as fast as the
    /// pty or stream carries bytes.
    pub baud: Option<u32>,
    /// The upload window INFO reports (protocol version 2: chunks acknowledged with the
    /// records loaded, repeats of loaded chunks acknowledged again, a NAK for a frame whose
    /// bytes stop short). `None` is a machine of protocol version 1: no window byte in INFO
    /// (the host sends one chunk at a time), none of those.
    pub window: Option<u8>,
}

impl Default for SewingSimConfig {
    fn default() -> Self {
        SewingSimConfig {
            spm: 2500,
            time_scale: 1.0,
            noise: 0.0,
            seed: 1,
            thread_break_at: vec![],
            power_loss_at: vec![],
            silent_after: None,
            area: [-1500, -1000, 1500, 1000],
            max_stitch: 127,
            baud: None,
            window: Some(4),
        }
    }
}

/// One needle drop: the record's index in the pattern and where the needle went in, 0.1 mm.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct NeedleDrop {
    pub index: u32,
    pub x: i32,
    pub y: i32,
}

/// One line of the machine's trace (`--trace FILE`): a record it executed, or an event.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum TraceLine {
    /// A record executed (stitch, jump, trim, …): its index in the pattern and the frame's
    /// position after it, 0.1 mm.
    Record {
        index: u32,
        kind: StitchKind,
        x: i32,
        y: i32,
    },
    /// "thread break at 150", "start at 0", "upload begun (612 records)", …
    Note { text: String },
}

/// What the machine did, for tests to read: every needle drop and every notable event.
#[derive(Clone, Debug, Default)]
pub struct SewingTrace {
    pub drops: Vec<NeedleDrop>,
    /// Every record executed and every event, in order (what `--trace FILE` writes).
    pub lines: Vec<TraceLine>,
    /// e.g. "thread break at 150", "power loss at 300", "pattern verified (612 records)".
    pub events: Vec<String>,
    /// Frames that arrived corrupted (and were NAKed) and repeats recognised by their
    /// sequence number (answered again, not applied).
    pub corrupt_frames: u64,
    pub duplicates: u64,
}

/// The trace shared between the running machine and whoever reads it.
pub type Trace = Arc<Mutex<SewingTrace>>;

/// A small deterministic generator for the noise (xorshift64*).
struct Noise {
    state: u64,
    p: f64,
}

impl Noise {
    fn new(seed: u64, p: f64) -> Self {
        Noise {
            state: seed.max(1).wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1,
            p,
        }
    }
    fn next_f64(&mut self) -> f64 {
        self.state ^= self.state >> 12;
        self.state ^= self.state << 25;
        self.state ^= self.state >> 27;
        let v = self.state.wrapping_mul(0x2545_F491_4F6C_DD1D);
        (v >> 11) as f64 / (1u64 << 53) as f64
    }
    /// The bytes as the line delivers them.
    fn apply(&mut self, bytes: &[u8]) -> Vec<u8> {
        if self.p <= 0.0 {
            return bytes.to_vec();
        }
        let mut out = Vec::with_capacity(bytes.len());
        for &b in bytes {
            let r = self.next_f64();
            if r < self.p / 2.0 {
                continue; // lost
            }
            if r < self.p {
                let bit = (self.next_f64() * 8.0) as u32 % 8;
                out.push(b ^ (1 << bit));
            } else {
                out.push(b);
            }
        }
        out
    }
}

struct Loading {
    total: u32,
    crc: u32,
    records: Vec<StitchRecord>,
}

/// The machine's memory and mechanics.
struct Machine {
    cfg: SewingSimConfig,
    trace: Trace,
    state: SewingState,
    pattern: Vec<StitchRecord>,
    loading: Option<Loading>,
    /// kept through a power loss (non-volatile)
    counter: u32,
    pattern_len: u32,
    pattern_crc: u32,
    x: i32,
    y: i32,
    needle_down: bool,
    thread_break: bool,
    /// held at a colour-change or stop record (rule 9a), until RESUME or START
    operator_stop: bool,
    /// the last request applied and the answer it got: (seq, type, reply frame bytes)
    last: Option<(u8, u8, Vec<u8>)>,
    breaks: BTreeSet<u32>,
    power_losses: BTreeSet<u32>,
    /// Hung (`SewingSimConfig::silent_after`) until then.
    silent_until: Option<Instant>,
}

impl Machine {
    fn new(cfg: SewingSimConfig, trace: Trace) -> Self {
        let breaks = cfg.thread_break_at.iter().copied().collect();
        let power_losses = cfg.power_loss_at.iter().copied().collect();
        Machine {
            cfg,
            trace,
            state: SewingState::NoPattern,
            pattern: vec![],
            loading: None,
            counter: 0,
            pattern_len: 0,
            pattern_crc: 0,
            x: 0,
            y: 0,
            needle_down: false,
            thread_break: false,
            operator_stop: false,
            last: None,
            breaks,
            power_losses,
            silent_until: None,
        }
    }

    fn info(&self) -> Info {
        let [min_x, min_y, max_x, max_y] = self.cfg.area;
        Info {
            min_x,
            min_y,
            max_x,
            max_y,
            max_stitch: self.cfg.max_stitch,
            spm: self.cfg.spm.min(u16::MAX as u32) as u16,
            window: self.cfg.window,
        }
    }

    fn status(&self) -> Status {
        Status {
            state: self.state,
            counter: self.counter,
            x: self.x,
            y: self.y,
            thread_break: self.thread_break,
            needle_down: self.needle_down,
            operator_stop: self.operator_stop,
            pattern_len: self.pattern_len,
            pattern_crc: self.pattern_crc,
        }
    }

    fn event(&self, e: String) {
        if let Ok(mut t) = self.trace.lock() {
            t.lines.push(TraceLine::Note { text: e.clone() });
            t.events.push(e);
        }
    }

    /// Answers one decoded frame; returns the reply's bytes.
    fn handle(&mut self, d: Decoded) -> Vec<u8> {
        let f = match d {
            Decoded::Corrupt { seq } => {
                if let Ok(mut t) = self.trace.lock() {
                    t.corrupt_frames += 1;
                }
                return Frame::new(seq, reply::NAK, vec![]).encode();
            }
            Decoded::Frame(f) => f,
        };
        if let Some((seq, kind, bytes)) = &self.last {
            if *seq == f.seq && *kind == f.kind {
                if let Ok(mut t) = self.trace.lock() {
                    t.duplicates += 1;
                }
                return bytes.clone();
            }
        }
        let payload = match self.apply(&f) {
            Ok(mut data) => {
                data.insert(0, f.kind);
                Frame::new(f.seq, reply::ACK, data)
            }
            Err((code, text)) => {
                let mut p = vec![f.kind, code];
                p.extend_from_slice(text.as_bytes());
                Frame::new(f.seq, reply::REFUSED, p)
            }
        };
        let bytes = payload.encode();
        self.last = Some((f.seq, f.kind, bytes.clone()));
        bytes
    }

    fn apply(&mut self, f: &Frame) -> Result<Vec<u8>, (u8, String)> {
        let p = &f.payload;
        let u32at = |i: usize| -> Result<u32, (u8, String)> {
            p.get(i..i + 4)
                .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .ok_or((refusal::BAD_REQUEST, "the request is too short".to_string()))
        };
        match f.kind {
            req::INFO => Ok(self.info().encode()),
            req::STATUS => Ok(self.status().encode()),
            req::LOAD_BEGIN => {
                if self.state == SewingState::Sewing {
                    return Err((refusal::BUSY, "the machine is sewing".into()));
                }
                self.loading = Some(Loading {
                    total: u32at(0)?,
                    crc: u32at(4)?,
                    records: vec![],
                });
                self.event(format!("upload begun ({} records)", u32at(0)?));
                self.pattern.clear();
                self.operator_stop = false;
                self.state = SewingState::NoPattern;
                Ok(vec![])
            }
            req::LOAD_CHUNK => {
                let offset = u32at(0)? as usize;
                let count = p
                    .get(4..6)
                    .map(|b| u16::from_le_bytes([b[0], b[1]]) as usize)
                    .ok_or((refusal::BAD_REQUEST, "the chunk has no count".to_string()))?;
                let v2 = self.cfg.window.is_some();
                let l = self
                    .loading
                    .as_mut()
                    .ok_or((refusal::NO_PATTERN, "no upload was begun".to_string()))?;
                let loaded = l.records.len();
                let repeat = v2 && offset < loaded && offset + count <= loaded;
                let wrong_offset = || {
                    (
                        refusal::WRONG_OFFSET,
                        format!(
                            "the chunk starts at record {offset}, but {loaded} records are loaded"
                        ),
                    )
                };
                if !repeat && offset != loaded {
                    return Err(wrong_offset());
                }
                let body = &p[6..];
                if body.len() != count * StitchRecord::WIRE_LEN || offset + count > l.total as usize
                {
                    return Err((refusal::BAD_REQUEST, "the chunk has the wrong size".into()));
                }
                let mut recs = Vec::with_capacity(count);
                for (i, b) in body.chunks(StitchRecord::WIRE_LEN).enumerate() {
                    recs.push(StitchRecord::from_wire(b).ok_or((
                        refusal::BAD_REQUEST,
                        format!("record {} has an unknown kind", offset + i),
                    ))?);
                }
                if !repeat {
                    l.records.extend(recs);
                } else if l.records[offset..offset + count] == recs[..] {
                    // A chunk sent again (its acknowledgement was lost): acknowledged, not loaded.
                    if let Ok(mut t) = self.trace.lock() {
                        t.duplicates += 1;
                    }
                } else {
                    return Err(wrong_offset());
                }
                Ok(if v2 {
                    (l.records.len() as u32).to_le_bytes().to_vec()
                } else {
                    vec![]
                })
            }
            req::LOAD_END => {
                let l = self
                    .loading
                    .take()
                    .ok_or((refusal::NO_PATTERN, "no upload was begun".to_string()))?;
                if l.records.len() != l.total as usize {
                    return Err((
                        refusal::PATTERN_INVALID,
                        format!("{} of {} records arrived", l.records.len(), l.total),
                    ));
                }
                if pattern_crc(&l.records) != l.crc {
                    return Err((
                        refusal::PATTERN_INVALID,
                        "the pattern's CRC does not match its records".into(),
                    ));
                }
                self.validate(&l.records)
                    .map_err(|t| (refusal::PATTERN_INVALID, t))?;
                if l.crc != self.pattern_crc || l.total != self.pattern_len {
                    self.counter = 0;
                }
                self.pattern_len = l.total;
                self.pattern_crc = l.crc;
                self.pattern = l.records;
                self.state = SewingState::Ready;
                self.event(format!("pattern verified ({} records)", self.pattern_len));
                Ok(vec![])
            }
            req::START => {
                let at = u32at(0)?;
                let crc = u32at(4)?;
                if self.pattern.is_empty() || self.state == SewingState::NoPattern {
                    return Err((refusal::NO_PATTERN, "no verified pattern".into()));
                }
                if crc != self.pattern_crc {
                    return Err((
                        refusal::PATTERN_INVALID,
                        "the start names another pattern".into(),
                    ));
                }
                if at > self.pattern_len {
                    return Err((
                        refusal::BAD_REQUEST,
                        format!("record {at} is past the pattern's end"),
                    ));
                }
                if self.state == SewingState::Sewing {
                    return Err((refusal::BUSY, "the machine is sewing".into()));
                }
                self.counter = at;
                if at > 0 {
                    let r = self.pattern[at as usize - 1];
                    (self.x, self.y) = (r.x, r.y);
                } else {
                    (self.x, self.y) = (0, 0);
                }
                self.thread_break = false;
                self.operator_stop = false;
                self.state = SewingState::Sewing;
                self.event(format!("start at {at}"));
                Ok(vec![])
            }
            req::STOP => {
                if self.state == SewingState::Sewing {
                    self.state = SewingState::Held;
                }
                Ok(vec![])
            }
            req::RESUME => {
                if matches!(self.state, SewingState::Held | SewingState::ThreadBreak) {
                    if self.thread_break {
                        self.event(format!("rethreaded, resume at {}", self.counter));
                    }
                    if self.operator_stop {
                        self.event(format!("thread changed, resume at {}", self.counter));
                    }
                    self.thread_break = false;
                    self.operator_stop = false;
                    self.state = SewingState::Sewing;
                }
                Ok(vec![])
            }
            req::ABORT => {
                if matches!(
                    self.state,
                    SewingState::Sewing | SewingState::Held | SewingState::ThreadBreak
                ) {
                    self.state = SewingState::Ready;
                    self.operator_stop = false;
                }
                Ok(vec![])
            }
            other => Err((
                refusal::BAD_REQUEST,
                format!("unknown request type {other:#04x}"),
            )),
        }
    }

    fn validate(&self, recs: &[StitchRecord]) -> Result<(), String> {
        let info = self.info();
        let (mut cx, mut cy) = (0i64, 0i64);
        let max = info.max_stitch as i64;
        for (i, r) in recs.iter().enumerate() {
            if !info.contains(r.x, r.y) {
                return Err(format!(
                    "record {i} at ({:.1}, {:.1}) mm lies outside the sewing area",
                    r.x as f64 / 10.0,
                    r.y as f64 / 10.0
                ));
            }
            if r.kind.moves() {
                let (dx, dy) = (r.x as i64 - cx, r.y as i64 - cy);
                if dx * dx + dy * dy > max * max {
                    return Err(format!(
                        "record {i} steps {:.1} mm, more than {:.1} mm",
                        ((dx * dx + dy * dy) as f64).sqrt() / 10.0,
                        max as f64 / 10.0
                    ));
                }
                (cx, cy) = (r.x as i64, r.y as i64);
            } else if (r.x as i64, r.y as i64) != (cx, cy) {
                return Err(format!("record {i} ({:?}) moves the frame", r.kind));
            }
        }
        Ok(())
    }

    /// One stitch cycle while sewing.
    fn cycle(&mut self) {
        let i = self.counter;
        if i as usize >= self.pattern.len() {
            self.state = SewingState::Done;
            return;
        }
        if self.power_losses.remove(&i) {
            self.event(format!("power loss at {i}"));
            self.pattern.clear();
            self.loading = None;
            self.last = None;
            self.state = SewingState::NoPattern;
            self.needle_down = false;
            return;
        }
        if self.breaks.remove(&i) {
            self.event(format!("thread break at {i}"));
            self.thread_break = true;
            self.state = SewingState::ThreadBreak;
            return;
        }
        let r = self.pattern[i as usize];
        if let Ok(mut t) = self.trace.lock() {
            let (x, y) = if r.kind.moves() {
                (r.x, r.y)
            } else {
                (self.x, self.y)
            };
            t.lines.push(TraceLine::Record {
                index: i,
                kind: r.kind,
                x,
                y,
            });
        }
        match r.kind {
            StitchKind::Stitch => {
                (self.x, self.y) = (r.x, r.y);
                if let Ok(mut t) = self.trace.lock() {
                    t.drops.push(NeedleDrop {
                        index: i,
                        x: r.x,
                        y: r.y,
                    });
                }
            }
            StitchKind::Jump => (self.x, self.y) = (r.x, r.y),
            StitchKind::Trim => {}
            StitchKind::ColorChange | StitchKind::Stop => {}
        }
        self.counter = i + 1;
        if self.counter as usize == self.pattern.len() {
            self.state = SewingState::Done;
            self.event("done".into());
        } else {
            if matches!(r.kind, StitchKind::ColorChange | StitchKind::Stop) {
                // rule 9a: the operator changes the thread (or does what the stop asks), then
                // RESUME sews on with the next record
                self.event(format!("operator stop at {}", self.counter));
                self.operator_stop = true;
                self.state = SewingState::Held;
            }
            if let Some((n, silence)) = self.cfg.silent_after {
                if n == self.counter {
                    self.cfg.silent_after = None;
                    self.state = SewingState::Held;
                    self.event(format!("hung after {n} records"));
                    self.silent_until = Some(Instant::now() + silence);
                }
            }
        }
    }
}

/// Runs the machine on `io` until the line closes.
pub async fn run(
    io: impl AsyncRead + AsyncWrite + Unpin,
    cfg: SewingSimConfig,
    trace: Trace,
) -> std::io::Result<()> {
    let period = Duration::from_secs_f64(60.0 / cfg.spm.max(1) as f64 / cfg.time_scale.max(1e-6));
    let idle_gap = Duration::from_millis(20);
    let mut rx_noise = Noise::new(cfg.seed, cfg.noise);
    let mut tx_noise = Noise::new(cfg.seed ^ 0x5555, cfg.noise);
    let mut m = Machine::new(cfg, trace);
    let (mut rd, mut wr) = tokio::io::split(io);
    let mut dec = Decoder::default();
    let mut buf = [0u8; 1024];
    let mut next_cycle = Instant::now();
    let mut last_rx = Instant::now();
    loop {
        let sewing = m.state == SewingState::Sewing;
        let pending = dec.pending() > 0;
        let mut out: Vec<u8> = Vec::new();
        tokio::select! {
            r = rd.read(&mut buf) => {
                let n = r?;
                if n == 0 {
                    return Ok(());
                }
                last_rx = Instant::now();
                if m.silent_until.is_some_and(|t| last_rx < t) {
                    // hung: the bytes are lost
                    continue;
                }
                dec.push(&rx_noise.apply(&buf[..n]));
                while let Some(d) = dec.next_frame() {
                    let was_sewing = m.state == SewingState::Sewing;
                    out.extend(m.handle(d));
                    if !was_sewing && m.state == SewingState::Sewing {
                        next_cycle = Instant::now() + period;
                    }
                }
            }
            _ = tokio::time::sleep_until(next_cycle), if sewing => {
                m.cycle();
                if m.state == SewingState::NoPattern {
                    dec.clear();
                }
                next_cycle += period;
                // never run more than a few cycles behind (a slow test machine)
                let now = Instant::now();
                if next_cycle + period * 4 < now {
                    next_cycle = now;
                }
            }
            _ = tokio::time::sleep_until(last_rx + idle_gap), if pending => {
                let stuck = dec.resync_on_idle();
                while let Some(d) = dec.next_frame() {
                    out.extend(m.handle(d));
                }
                // Version 2: a frame whose bytes stopped short of its length is NAKed.
                if let (Some(seq), Some(_)) = (stuck, m.cfg.window) {
                    if let Ok(mut t) = m.trace.lock() {
                        t.corrupt_frames += 1;
                    }
                    out.extend(Frame::new(seq, reply::NAK, vec![]).encode());
                }
                last_rx = Instant::now();
            }
        }
        if !out.is_empty() {
            wr.write_all(&tx_noise.apply(&out)).await?;
            wr.flush().await?;
        }
    }
}

/// A machine running on a fresh pty: the path a host opens, and the trace.
pub struct SewingSim {
    /// The pty's path (a symbolic link's target when one was asked for).
    pub path: String,
    pub trace: Trace,
    pub task: tokio::task::JoinHandle<std::io::Result<()>>,
    /// The symbolic link to the pty, when one was asked for; removed on drop.
    pub link: Option<crate::pty::PtyLink>,
}

impl Drop for SewingSim {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Starts a machine on a new pty inside the current tokio runtime.
pub fn spawn_on_pty(cfg: SewingSimConfig) -> std::io::Result<SewingSim> {
    spawn_on_pty_at(cfg, None)
}

/// As [`spawn_on_pty`], with `link` made a symbolic link to the pty (an old link of that
/// name is replaced).
pub fn spawn_on_pty_at(
    cfg: SewingSimConfig,
    link: Option<&std::path::Path>,
) -> std::io::Result<SewingSim> {
    let port = crate::pty::PtyPort::open()?;
    let path = port.slave_path.clone();
    let link = crate::pty::PtyLink::optional(std::path::Path::new(&path), link)?;
    let trace: Trace = Arc::default();
    let task = spawn_on(port, cfg, trace.clone());
    Ok(SewingSim {
        path,
        trace,
        task,
        link,
    })
}

/// Starts a machine on any byte stream (an in-memory [`crate::line::cable`] in tests),
/// behind a line paced at `cfg.baud` when one is set.
pub fn spawn_on<S>(
    io: S,
    cfg: SewingSimConfig,
    trace: Trace,
) -> tokio::task::JoinHandle<std::io::Result<()>>
where
    S: AsyncRead + AsyncWrite + Send + 'static,
{
    match cfg.baud {
        Some(baud) => {
            let line = crate::line::paced(io, baud);
            tokio::spawn(run(line, cfg, trace))
        }
        None => tokio::spawn(run(Box::pin(io), cfg, trace)),
    }
}
