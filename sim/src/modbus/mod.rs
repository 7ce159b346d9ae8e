//! A simulated motion-block device serving the register map of docs/modbus.md on Modbus TCP
//! or RTU (a pty, or any byte stream): it executes blocks at machine speed, records what it
//! executed, and injects faults on request. Frames come from `machlink_protocols::modbus::frame`,
//! the module the link uses too.

pub mod cli;
mod serve;

use machlink_protocols::modbus::frame::{
    exception, Request, Response, MAX_READ, MAX_READ_WRITE_WRITE,
};
use machlink_protocols::modbus::map::{
    fault, reg, BlockKind, Command, Layout, ModbusState, MotionBlock, WordOrder, BLOCK_REGISTERS,
    MAP_VERSION, MAX_WRITE_REGISTERS,
};
use offset_core::{Point, P3};
use serde::Serialize;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::TcpListener;
use tokio::sync::Notify;
use tokio::task::JoinHandle;
use tokio::time::Instant;

/// Faults the device injects, by request number (1-based, counted over every request it
/// receives on any connection) or by block sequence.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Faults {
    /// Requests that are carried out but whose reply is never sent.
    pub drop_replies: Vec<u64>,
    /// Requests that are carried out and answered late: the reply's last byte leaves
    /// `late_by` after the request's first byte arrived (RTU), or the reply is sent
    /// `late_by` after the request arrived (TCP).
    pub late_replies: Vec<u64>,
    pub late_by: Duration,
    /// Requests answered with this exception code and not carried out.
    pub exceptions: Vec<(u64, u8)>,
    /// TCP: the request is carried out and the connection closed instead of the reply.
    /// RTU: the device goes deaf for `silence` (the request is lost), as if the cable were pulled.
    pub disconnects: Vec<u64>,
    pub silence: Duration,
    /// The device faults with this code when it first reaches this block sequence (the block
    /// is not executed; after a clear fault and a resume it runs normally).
    pub fault_at_block: Option<(u32, u16)>,
    /// `(seq, silence)`: once block `seq` has executed, the device holds (as at a hold
    /// command: the next block waits) and its communication hangs for `silence`: every
    /// request meanwhile is lost, neither carried out nor answered. Afterwards it answers
    /// again, still holding with block `seq` consumed, until a resume command.
    pub silent_after_block: Option<(u32, Duration)>,
}

/// How the simulated device is built.
#[derive(Clone, Debug, PartialEq)]
pub struct SimConfig {
    pub unit_id: u8,
    pub base_address: u16,
    /// Ring capacity in blocks.
    pub capacity: u16,
    pub word_order: WordOrder,
    /// Simulated seconds per wall second; 0 or infinity executes blocks at once.
    pub time_scale: f64,
    /// Rapid rate, mm/min.
    pub rapid_feed: f64,
    /// Acceleration and deceleration of every block, mm/s² (each block starts and ends at rest).
    pub acceleration: f64,
    /// Pace every exchange as a serial line at this baud would (10 bits per byte, and the
    /// 3.5-character silence between frames). On RTU the device models the line: a request
    /// takes its bytes' time from when it arrives (or from 3.5 characters after the last
    /// frame, if later), the reply starts 3.5 characters after the request ends and is
    /// delivered when its last byte would have arrived.
    pub line_baud: Option<u32>,
    /// Answer FC23 (read/write in one request); false answers it Illegal Function, as
    /// devices that only know FC3, FC6 and FC16 do.
    pub read_write: bool,
    pub faults: Faults,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            unit_id: 1,
            base_address: 0,
            capacity: 64,
            word_order: WordOrder::HighFirst,
            time_scale: 1.0,
            rapid_feed: 5000.0,
            acceleration: 500.0,
            line_baud: None,
            read_write: true,
            faults: Faults::default(),
        }
    }
}

/// One executed block, as the trace records it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Executed {
    pub seq: u32,
    pub block: MotionBlock,
}

/// What the device did, as its event trace (and `--trace FILE`) records it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum TraceEvent {
    /// A block's sequence number was written into its ring slot (the block sent to the
    /// device), with the device's consumed sequence at that moment: `seq <= consumed` is
    /// a block sent again after it had run.
    Written { seq: u32, consumed: u32 },
    /// A block executed to its end.
    Executed { seq: u32, block: MotionBlock },
    /// A sync command set the consumed sequence to `at` (a job starts there).
    Synced { at: u32 },
    /// The device reached tool block `seq` and holds there, unfinished, for the operator to
    /// load tool `tool` (docs/modbus.md, rule 10a).
    ToolStop { seq: u32, tool: u32 },
}

/// What the device has seen, for tests to check that the faults really happened.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct SimStats {
    pub requests: u64,
    pub connections: u64,
    pub dropped: u64,
    pub late: u64,
    pub exceptions: u64,
    pub disconnects: u64,
    /// Bytes of every request and reply frame on the wire (MBAP or address + CRC included).
    pub wire_bytes: u64,
    /// Frames on the wire (requests and replies): each is followed by 3.5 characters of
    /// silence on RTU, so a line at B baud is busy (wire_bytes + 3.5 × frames) × 10 / B s.
    pub frames: u64,
}

struct Device {
    /// The whole map, from the base address.
    regs: Vec<u16>,
    trace: Vec<Executed>,
    events: Vec<TraceEvent>,
    /// Bumped by stop and fault: a block in motion under an older epoch is abandoned.
    epoch: u64,
    /// The tool block the device has held at: after the resume it finishes it.
    tool_stop: Option<u32>,
}

struct Shared {
    cfg: SimConfig,
    layout: Layout,
    dev: Mutex<Device>,
    wake: Notify,
    stats: Mutex<SimStats>,
    request_no: AtomicU64,
    fault_fired: AtomicBool,
    /// Hung (`Faults::silent_after_block`) until then; set once.
    silent_until: Mutex<Option<Instant>>,
    /// For each reply sent, in the order sent: the number of the request it answers.
    replies: Mutex<Vec<u64>>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Device {
    fn get32(&self, order: WordOrder, at: u16) -> u32 {
        order.get(&self.regs, at)
    }
    fn put32(&mut self, order: WordOrder, at: u16, v: u32) {
        order.put(&mut self.regs, at, v)
    }
    fn state(&self) -> u16 {
        self.regs[reg::STATE as usize]
    }
    fn set_state(&mut self, s: ModbusState) {
        self.regs[reg::STATE as usize] = s as u16;
    }
    fn set_fault(&mut self, code: u16) {
        self.set_state(ModbusState::Fault);
        self.regs[reg::FAULT as usize] = code;
        self.epoch += 1;
    }
}

/// The header registers a write may change, worked on as a whole before any is applied.
#[derive(Clone, Copy, Debug)]
struct Header {
    state: ModbusState,
    fault: u16,
    write: u32,
    consumed: u32,
    /// The block in motion is abandoned.
    abandon: bool,
    /// A sync set the consumed sequence.
    synced: bool,
}

type Reply = Result<Response, u8>;

impl Shared {
    fn new(cfg: SimConfig) -> Arc<Shared> {
        let layout = Layout {
            base: cfg.base_address,
            capacity: cfg.capacity,
        };
        let len = reg::RING as usize + cfg.capacity as usize * BLOCK_REGISTERS as usize;
        let mut regs = vec![0u16; len];
        regs[reg::VERSION as usize] = MAP_VERSION;
        regs[reg::CAPACITY as usize] = cfg.capacity;
        regs[reg::BLOCK_SIZE as usize] = BLOCK_REGISTERS;
        Arc::new(Shared {
            cfg,
            layout,
            dev: Mutex::new(Device {
                regs,
                trace: Vec::new(),
                events: Vec::new(),
                epoch: 0,
                tool_stop: None,
            }),
            wake: Notify::new(),
            stats: Mutex::new(SimStats::default()),
            request_no: AtomicU64::new(0),
            fault_fired: AtomicBool::new(false),
            silent_until: Mutex::new(None),
            replies: Mutex::new(Vec::new()),
        })
    }

    /// Offset of `addr .. addr + n` in the map, or Illegal Data Address.
    fn offset(&self, addr: u16, n: usize) -> Result<usize, u8> {
        let off = (addr as usize)
            .checked_sub(self.cfg.base_address as usize)
            .ok_or(exception::ILLEGAL_ADDRESS)?;
        if off + n > (self.layout.end() - self.cfg.base_address as u32) as usize {
            return Err(exception::ILLEGAL_ADDRESS);
        }
        Ok(off)
    }

    fn read(&self, addr: u16, n: u16) -> Result<Vec<u16>, u8> {
        if !(1..=MAX_READ).contains(&n) {
            return Err(exception::ILLEGAL_VALUE);
        }
        let off = self.offset(addr, n as usize)?;
        Ok(lock(&self.dev).regs[off..off + n as usize].to_vec())
    }

    /// Carries out one request on the map: the reply, or the exception code.
    fn apply(&self, req: &Request) -> Reply {
        match req {
            Request::Read { addr, count } => self.read(*addr, *count).map(Response::Read),
            Request::WriteSingle { addr, value } => {
                self.write(*addr, &[*value])?;
                Ok(Response::WriteSingle {
                    addr: *addr,
                    value: *value,
                })
            }
            Request::Write { addr, words } => {
                if words.is_empty() || words.len() > MAX_WRITE_REGISTERS as usize {
                    return Err(exception::ILLEGAL_VALUE);
                }
                self.write(*addr, words)?;
                Ok(Response::Write {
                    addr: *addr,
                    count: words.len() as u16,
                })
            }
            Request::ReadWrite {
                read_addr,
                read_count,
                write_addr,
                words,
            } if self.cfg.read_write => {
                if words.is_empty()
                    || words.len() > MAX_READ_WRITE_WRITE as usize
                    || !(1..=MAX_READ).contains(read_count)
                {
                    return Err(exception::ILLEGAL_VALUE);
                }
                self.offset(*read_addr, *read_count as usize)?;
                // The write first, then the read (application protocol 6.17).
                self.write(*write_addr, words)?;
                self.read(*read_addr, *read_count).map(Response::ReadWrite)
            }
            _ => Err(exception::ILLEGAL_FUNCTION),
        }
    }

    /// Writes `words` at `addr`: all of them or, with an exception, none.
    fn write(&self, addr: u16, words: &[u16]) -> Result<(), u8> {
        let off = self.offset(addr, words.len())?;
        let end = off + words.len();
        let order = self.cfg.word_order;
        let mut dev = lock(&self.dev);
        let ring = reg::RING as usize;
        if off >= ring {
            // Slots of committed blocks not yet executed are the device's: refuse to touch them.
            let consumed = dev.get32(order, reg::CONSUMED_SEQ);
            let write = dev.get32(order, reg::WRITE_SEQ);
            let cap = self.cfg.capacity as u32;
            for seq in consumed + 1..=write.min(consumed + cap) {
                let s = ring + self.layout.slot(seq) as usize * BLOCK_REGISTERS as usize;
                if off < s + BLOCK_REGISTERS as usize && s < end {
                    return Err(exception::ILLEGAL_VALUE);
                }
            }
            dev.regs[off..end].copy_from_slice(words);
            // a write that sets a slot's sequence number sends that block
            let block = BLOCK_REGISTERS as usize;
            for slot in (off - ring) / block..=(end - 1 - ring) / block {
                let at = ring + slot * block;
                if off <= at && at + 2 <= end {
                    let seq = dev.get32(order, at as u16);
                    dev.events.push(TraceEvent::Written { seq, consumed });
                }
            }
            return Ok(());
        }
        // Only the command and the write sequence may be written, and not together with
        // anything past the header.
        if end > ring
            || (off..end).any(|a| !(reg::COMMAND..reg::CONSUMED_SEQ).contains(&(a as u16)))
        {
            return Err(exception::ILLEGAL_ADDRESS);
        }
        let w = reg::WRITE_SEQ as usize;
        let touches_seq = off <= w + 1 && end > w;
        if touches_seq && !(off <= w && end >= w + 2) {
            // A 32-bit value must be written whole.
            return Err(exception::ILLEGAL_VALUE);
        }
        let mut h = Header {
            state: ModbusState::from_register(dev.state()).unwrap_or(ModbusState::Fault),
            fault: dev.regs[reg::FAULT as usize],
            write: dev.get32(order, reg::WRITE_SEQ),
            consumed: dev.get32(order, reg::CONSUMED_SEQ),
            abandon: false,
            synced: false,
        };
        // The write sequence first, then the command.
        if touches_seq {
            let new = order.join([words[w - off], words[w + 1 - off]]);
            let back = h.state != ModbusState::Idle && new < h.write;
            if new > h.consumed.saturating_add(self.cfg.capacity as u32) || back {
                return Err(exception::ILLEGAL_VALUE);
            }
            h.write = new;
        }
        if off <= reg::COMMAND as usize {
            command(&mut h, words[reg::COMMAND as usize - off])?;
        }
        dev.set_state(h.state);
        dev.regs[reg::FAULT as usize] = h.fault;
        dev.put32(order, reg::WRITE_SEQ, h.write);
        if h.synced {
            dev.events.push(TraceEvent::Synced { at: h.consumed });
        }
        if h.synced || h.abandon {
            // a new job, or this one stopped: a tool block holds again when it comes
            dev.tool_stop = None;
        }
        dev.put32(order, reg::CONSUMED_SEQ, h.consumed);
        if h.abandon {
            dev.epoch += 1;
        }
        if self.instant() {
            self.run_instantly(&mut dev);
        }
        drop(dev);
        self.wake.notify_one();
        Ok(())
    }

    /// Machine time of a block starting at `from`, in seconds.
    fn motion_time(&self, from: [i32; 3], b: &MotionBlock) -> f64 {
        let p = |v: [i32; 3]| P3::new(v[0] as f64 / 1e3, v[1] as f64 / 1e3, v[2] as f64 / 1e3);
        let (a, t) = (p(from), p(b.target));
        let (len, feed) = match b.kind {
            BlockKind::Dwell => return b.feed as f64 / 1000.0,
            BlockKind::End | BlockKind::ToolChange => return 0.0,
            BlockKind::Rapid => (a.dist(t), self.cfg.rapid_feed),
            BlockKind::Linear => (a.dist(t), b.feed as f64 / 1000.0),
            BlockKind::ArcCw | BlockKind::ArcCcw => {
                let c = Point::new(
                    a.x + b.center[0] as f64 / 1e3,
                    a.y + b.center[1] as f64 / 1e3,
                );
                let ccw = b.kind == BlockKind::ArcCcw;
                let xy = offset_core::toolpath::arc_segment(a.xy(), t.xy(), c, ccw).length();
                (xy.hypot(t.z - a.z), b.feed as f64 / 1000.0)
            }
        };
        let v = (feed / 60.0).max(1e-3);
        let acc = self.cfg.acceleration.max(1e-3);
        if len >= v * v / acc {
            len / v + v / acc
        } else {
            2.0 * (len / acc).sqrt()
        }
    }
}

/// The command register's effect on the header (docs/modbus.md, the state table): commands
/// outside their states change nothing; start in fault and sync outside idle are refused.
fn command(h: &mut Header, c: u16) -> Result<(), u8> {
    use ModbusState::*;
    match (Command::from_register(c), h.state) {
        (None, _) if c == 0 => {}
        (None, _) => return Err(exception::ILLEGAL_VALUE),
        (Some(Command::Start), Idle) => h.state = Running,
        (Some(Command::Start), Fault) => return Err(exception::DEVICE_FAILURE),
        (Some(Command::Hold), Running) => h.state = Hold,
        (Some(Command::Resume), Hold) => h.state = Running,
        (Some(Command::Stop), Idle | Running | Hold) => {
            h.state = Idle;
            h.write = h.consumed;
            h.abandon = true;
        }
        (Some(Command::ClearFault), Fault) => {
            h.state = Idle;
            h.fault = 0;
            h.write = h.consumed;
        }
        (Some(Command::Sync), Idle) => {
            h.consumed = h.write;
            h.synced = true;
        }
        (Some(Command::Sync), _) => return Err(exception::ILLEGAL_VALUE),
        _ => {}
    }
    Ok(())
}

/// The block the device executes next: (sequence, block, epoch, start position), or `None`
/// (not running, nothing committed, or a fault raised here).
fn next_block(shared: &Shared, dev: &mut Device) -> Option<(u32, MotionBlock, u64, [i32; 3])> {
    let order = shared.cfg.word_order;
    let consumed = dev.get32(order, reg::CONSUMED_SEQ);
    let write = dev.get32(order, reg::WRITE_SEQ);
    if dev.state() != ModbusState::Running as u16 || consumed >= write {
        return None;
    }
    let seq = consumed + 1;
    let at = reg::RING as usize + shared.layout.slot(seq) as usize * BLOCK_REGISTERS as usize;
    match MotionBlock::decode(&dev.regs[at..at + BLOCK_REGISTERS as usize], order) {
        Err(_) => {
            dev.set_fault(fault::BAD_BLOCK);
            None
        }
        Ok((s, _)) if s != seq => {
            dev.set_fault(fault::SEQUENCE);
            None
        }
        Ok(_)
            if shared.cfg.faults.fault_at_block.is_some_and(|f| f.0 == seq)
                && !shared.fault_fired.swap(true, Ordering::SeqCst) =>
        {
            let code = shared.cfg.faults.fault_at_block.map_or(0, |f| f.1);
            dev.set_fault(code);
            None
        }
        Ok((_, block)) if block.kind == BlockKind::ToolChange && dev.tool_stop != Some(seq) => {
            // a tool change: hold here, the block unfinished, until the operator resumes
            dev.tool_stop = Some(seq);
            dev.set_state(ModbusState::Hold);
            dev.events.push(TraceEvent::ToolStop {
                seq,
                tool: block.feed,
            });
            None
        }
        Ok((_, block)) => {
            let from = [
                dev.get32(order, reg::POS_X) as i32,
                dev.get32(order, reg::POS_Y) as i32,
                dev.get32(order, reg::POS_Z) as i32,
            ];
            Some((seq, block, dev.epoch, from))
        }
    }
}

/// Completes block `seq` unless it was abandoned (stop, fault) meanwhile.
fn finish_block(shared: &Shared, dev: &mut Device, seq: u32, block: MotionBlock, epoch: u64) {
    let order = shared.cfg.word_order;
    let still_running =
        dev.state() == ModbusState::Running as u16 || dev.state() == ModbusState::Hold as u16;
    if dev.epoch == epoch && still_running && dev.get32(order, reg::CONSUMED_SEQ) == seq - 1 {
        dev.put32(order, reg::POS_X, block.target[0] as u32);
        dev.put32(order, reg::POS_Y, block.target[1] as u32);
        dev.put32(order, reg::POS_Z, block.target[2] as u32);
        dev.put32(order, reg::CONSUMED_SEQ, seq);
        dev.trace.push(Executed { seq, block });
        dev.events.push(TraceEvent::Executed { seq, block });
        if block.kind == BlockKind::End {
            dev.set_state(ModbusState::Idle);
        } else if let Some((at, silence)) = shared.cfg.faults.silent_after_block {
            let mut until = lock(&shared.silent_until);
            if at == seq && until.is_none() {
                dev.set_state(ModbusState::Hold);
                *until = Some(Instant::now() + silence);
            }
        }
    }
}

impl Shared {
    /// Whether the device's communication hangs now (`Faults::silent_after_block`).
    fn silent(&self) -> bool {
        lock(&self.silent_until).is_some_and(|t| Instant::now() < t)
    }

    /// An infinitely fast machine (time scale 0 or infinite) executes what was committed
    /// before it answers the write that committed it.
    fn instant(&self) -> bool {
        !(self.cfg.time_scale > 0.0 && self.cfg.time_scale.is_finite())
    }
    fn run_instantly(&self, dev: &mut Device) {
        while let Some((seq, block, epoch, _)) = next_block(self, dev) {
            finish_block(self, dev, seq, block, epoch);
        }
    }
}

/// The executor of a machine with a time scale: takes committed blocks in sequence and
/// runs them at machine speed.
async fn execute(shared: Arc<Shared>) {
    if shared.instant() {
        return;
    }
    let mut clock = Instant::now();
    loop {
        let next = next_block(&shared, &mut lock(&shared.dev));
        let Some((seq, block, epoch, from)) = next else {
            shared.wake.notified().await;
            continue;
        };
        let t = shared.motion_time(from, &block) / shared.cfg.time_scale;
        clock = clock.max(Instant::now()) + Duration::from_secs_f64(t);
        // Sleep only when a millisecond or more is due: the average pace stays exact.
        loop {
            let (state, ep) = {
                let dev = lock(&shared.dev);
                (dev.state(), dev.epoch)
            };
            if ep != epoch {
                break;
            }
            let now = Instant::now();
            if state == ModbusState::Hold as u16 {
                tokio::time::sleep(Duration::from_millis(2)).await;
                clock += Instant::now() - now;
                continue;
            }
            if clock <= now + Duration::from_millis(1) {
                break;
            }
            tokio::time::sleep((clock - now).min(Duration::from_millis(5))).await;
        }
        finish_block(&shared, &mut lock(&shared.dev), seq, block, epoch);
    }
}

/// A running simulated device; dropping it stops it.
pub struct ModbusSim {
    shared: Arc<Shared>,
    tasks: Vec<JoinHandle<()>>,
    addr: Option<SocketAddr>,
    port: Option<PathBuf>,
    link: Option<crate::pty::PtyLink>,
}

impl ModbusSim {
    fn start(cfg: SimConfig) -> (Arc<Shared>, JoinHandle<()>) {
        let shared = Shared::new(cfg);
        let exec = tokio::spawn(execute(Arc::clone(&shared)));
        (shared, exec)
    }

    /// Serves the device on TCP at `bind` (port 0: any free port; see `addr()`).
    pub async fn spawn_tcp(cfg: SimConfig, bind: SocketAddr) -> std::io::Result<ModbusSim> {
        let listener = TcpListener::bind(bind).await?;
        let addr = listener.local_addr()?;
        let (shared, exec) = Self::start(cfg);
        let serve = tokio::spawn(serve::tcp(listener, Arc::clone(&shared)));
        Ok(ModbusSim {
            shared,
            tasks: vec![serve, exec],
            addr: Some(addr),
            port: None,
            link: None,
        })
    }

    /// Serves the device as an RTU slave on a new pseudo-terminal; clients open `port()`.
    /// With `link`, a symlink of that name points at the pty (replaced if it exists).
    pub async fn spawn_pty(cfg: SimConfig, link: Option<&Path>) -> std::io::Result<ModbusSim> {
        let pty = crate::pty::PtyPort::open()?;
        let port = PathBuf::from(&pty.slave_path);
        let link = crate::pty::PtyLink::optional(&port, link)?;
        let mut sim = Self::spawn_rtu_on(cfg, pty);
        sim.port = Some(port);
        sim.link = link;
        Ok(sim)
    }

    /// Serves the device as an RTU slave on any byte stream (an in-memory
    /// [`crate::line::cable`] in tests; the device models the line at `cfg.line_baud`).
    pub fn spawn_rtu_on<S>(cfg: SimConfig, io: S) -> ModbusSim
    where
        S: AsyncRead + AsyncWrite + Send + Unpin + 'static,
    {
        let (shared, exec) = Self::start(cfg);
        lock(&shared.stats).connections = 1;
        let serve = tokio::spawn(serve::rtu(io, Arc::clone(&shared)));
        ModbusSim {
            shared,
            tasks: vec![serve, exec],
            addr: None,
            port: None,
            link: None,
        }
    }

    /// The TCP address (TCP devices only).
    pub fn addr(&self) -> SocketAddr {
        self.addr
            .expect("addr() is for a device spawned with spawn_tcp")
    }
    /// The pty path clients open (RTU devices on a pty only): the symlink if one was asked for.
    pub fn port(&self) -> &Path {
        self.link
            .as_ref()
            .map(|l| l.path())
            .or(self.port.as_deref())
            .expect("port() is for a device spawned with spawn_pty")
    }
    /// The blocks executed so far, in execution order.
    pub fn trace(&self) -> Vec<Executed> {
        lock(&self.shared.dev).trace.clone()
    }
    /// The events from number `from` on (writes of blocks, executions, syncs), in order.
    pub fn events_from(&self, from: usize) -> Vec<TraceEvent> {
        let dev = lock(&self.shared.dev);
        dev.events
            .get(from..)
            .map(<[_]>::to_vec)
            .unwrap_or_default()
    }
    pub fn stats(&self) -> SimStats {
        *lock(&self.shared.stats)
    }
    /// For every reply the device sent, in the order sent, the number of the request it
    /// answered (requests count from 1): what a test compares with the link's own account.
    pub fn replies(&self) -> Vec<u64> {
        lock(&self.shared.replies).clone()
    }
    /// State word, fault code, consumed and write sequence as the registers hold them.
    pub fn registers(&self) -> (u16, u16, u32, u32) {
        let dev = lock(&self.shared.dev);
        let o = self.shared.cfg.word_order;
        (
            dev.state(),
            dev.regs[reg::FAULT as usize],
            dev.get32(o, reg::CONSUMED_SEQ),
            dev.get32(o, reg::WRITE_SEQ),
        )
    }
}

impl Drop for ModbusSim {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}
