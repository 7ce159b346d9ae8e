//! A simulated motion-block device behind a tokio-modbus server on TCP or on a pty (RTU):
//! it serves the register map, executes blocks at machine speed, records what it executed,
//! and injects faults on request (docs/modbus.md).

pub mod cli;

use futures::future::BoxFuture;
use machlink_protocols::modbus::map::{
    fault, reg, BlockKind, Command, Layout, ModbusState, MotionBlock, WordOrder, BLOCK_REGISTERS,
    MAP_VERSION, MAX_READ_REGISTERS, MAX_WRITE_REGISTERS,
};
use offset_core::{Point, P3};
use serde::Serialize;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context as TaskContext, Poll};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Notify;
use tokio::task::JoinHandle;
use tokio::time::Instant;
use tokio_modbus::server::Service;
use tokio_modbus::{ExceptionCode, Request, Response, SlaveRequest};

/// Faults the device injects, by request number (1-based, counted over every request it
/// receives on any connection) or by block sequence.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Faults {
    /// Requests that are carried out but whose reply is never sent.
    pub drop_replies: Vec<u64>,
    /// Requests that are carried out and answered `late_by` later.
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
    /// Pace every exchange as a serial line at this baud would (10 bits per byte, plus the
    /// 3.5-character silence that ends each RTU frame).
    pub line_baud: Option<u32>,
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
}

struct Device {
    /// The whole map, from the base address.
    regs: Vec<u16>,
    trace: Vec<Executed>,
    events: Vec<TraceEvent>,
    /// Bumped by stop and fault: a block in motion under an older epoch is abandoned.
    epoch: u64,
}

struct Shared {
    cfg: SimConfig,
    layout: Layout,
    dev: Mutex<Device>,
    wake: Notify,
    stats: Mutex<SimStats>,
    request_no: AtomicU64,
    fault_fired: AtomicBool,
    silent_until: Mutex<Option<Instant>>,
    line_free_at: Mutex<Instant>,
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
            }),
            wake: Notify::new(),
            stats: Mutex::new(SimStats::default()),
            request_no: AtomicU64::new(0),
            fault_fired: AtomicBool::new(false),
            silent_until: Mutex::new(None),
            line_free_at: Mutex::new(Instant::now()),
        })
    }

    /// Offset of `addr .. addr + n` in the map, or Illegal Data Address.
    fn offset(&self, addr: u16, n: usize) -> Result<usize, ExceptionCode> {
        let off = (addr as usize)
            .checked_sub(self.cfg.base_address as usize)
            .ok_or(ExceptionCode::IllegalDataAddress)?;
        if off + n > (self.layout.end() - self.cfg.base_address as u32) as usize {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        Ok(off)
    }

    /// Carries out one request on the map.
    fn apply(&self, req: &Request<'_>) -> Result<Response, ExceptionCode> {
        match req {
            Request::ReadHoldingRegisters(addr, n) => {
                if !(1..=MAX_READ_REGISTERS).contains(n) {
                    return Err(ExceptionCode::IllegalDataValue);
                }
                let off = self.offset(*addr, *n as usize)?;
                let dev = lock(&self.dev);
                Ok(Response::ReadHoldingRegisters(
                    dev.regs[off..off + *n as usize].to_vec(),
                ))
            }
            Request::WriteSingleRegister(addr, v) => {
                self.write(*addr, &[*v])?;
                Ok(Response::WriteSingleRegister(*addr, *v))
            }
            Request::WriteMultipleRegisters(addr, words) => {
                if words.is_empty() || words.len() > MAX_WRITE_REGISTERS as usize {
                    return Err(ExceptionCode::IllegalDataValue);
                }
                self.write(*addr, words)?;
                Ok(Response::WriteMultipleRegisters(*addr, words.len() as u16))
            }
            _ => Err(ExceptionCode::IllegalFunction),
        }
    }

    fn write(&self, addr: u16, words: &[u16]) -> Result<(), ExceptionCode> {
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
                    return Err(ExceptionCode::IllegalDataValue);
                }
            }
            dev.regs[off..end].copy_from_slice(words);
            // a write that sets a slot's sequence number sends that block
            let block = BLOCK_REGISTERS as usize;
            let first_slot = (off - ring) / block;
            let last_slot = (end - 1 - ring) / block;
            for slot in first_slot..=last_slot {
                let at = ring + slot * block;
                if off <= at && at + 2 <= end {
                    let seq = dev.get32(order, at as u16);
                    dev.events.push(TraceEvent::Written { seq, consumed });
                }
            }
            return Ok(());
        }
        if end > ring {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        for a in off..end {
            match a as u16 {
                reg::COMMAND => {}
                x if x == reg::WRITE_SEQ || x == reg::WRITE_SEQ + 1 => {}
                _ => return Err(ExceptionCode::IllegalDataAddress),
            }
        }
        let w = reg::WRITE_SEQ as usize;
        let touches_seq = off <= w + 1 && end > w;
        if touches_seq && !(off <= w && end >= w + 2) {
            // A 32-bit value must be written whole.
            return Err(ExceptionCode::IllegalDataValue);
        }
        let cmd = (off <= reg::COMMAND as usize && end > reg::COMMAND as usize)
            .then(|| words[reg::COMMAND as usize - off]);
        if touches_seq {
            let new = order.join([words[w - off], words[w + 1 - off]]);
            let consumed = dev.get32(order, reg::CONSUMED_SEQ);
            let current = dev.get32(order, reg::WRITE_SEQ);
            let idle = dev.state() == ModbusState::Idle as u16;
            if new > consumed.saturating_add(self.cfg.capacity as u32) || (!idle && new < current) {
                return Err(ExceptionCode::IllegalDataValue);
            }
            dev.put32(order, reg::WRITE_SEQ, new);
        }
        if let Some(c) = cmd {
            self.command(&mut dev, c)?;
        }
        drop(dev);
        self.wake.notify_one();
        Ok(())
    }

    fn command(&self, dev: &mut Device, c: u16) -> Result<(), ExceptionCode> {
        let order = self.cfg.word_order;
        let state = ModbusState::from_register(dev.state());
        match Command::from_register(c) {
            None if c == 0 => {}
            None => return Err(ExceptionCode::IllegalDataValue),
            Some(Command::Start) => match state {
                Some(ModbusState::Idle) => dev.set_state(ModbusState::Running),
                Some(ModbusState::Fault) => return Err(ExceptionCode::ServerDeviceFailure),
                _ => {}
            },
            Some(Command::Hold) => {
                if state == Some(ModbusState::Running) {
                    dev.set_state(ModbusState::Hold)
                }
            }
            Some(Command::Resume) => {
                if state == Some(ModbusState::Hold) {
                    dev.set_state(ModbusState::Running)
                }
            }
            Some(Command::Stop) => {
                if state != Some(ModbusState::Fault) {
                    dev.set_state(ModbusState::Idle);
                    let consumed = dev.get32(order, reg::CONSUMED_SEQ);
                    dev.put32(order, reg::WRITE_SEQ, consumed);
                    dev.epoch += 1;
                }
            }
            Some(Command::ClearFault) => {
                if state == Some(ModbusState::Fault) {
                    dev.set_state(ModbusState::Idle);
                    dev.regs[reg::FAULT as usize] = 0;
                    let consumed = dev.get32(order, reg::CONSUMED_SEQ);
                    dev.put32(order, reg::WRITE_SEQ, consumed);
                }
            }
            Some(Command::Sync) => {
                if state != Some(ModbusState::Idle) {
                    return Err(ExceptionCode::IllegalDataValue);
                }
                let write = dev.get32(order, reg::WRITE_SEQ);
                dev.put32(order, reg::CONSUMED_SEQ, write);
                dev.events.push(TraceEvent::Synced { at: write });
            }
        }
        Ok(())
    }

    /// Machine time of a block starting at `from`, in seconds.
    fn motion_time(&self, from: [i32; 3], b: &MotionBlock) -> f64 {
        let p = |v: [i32; 3]| P3::new(v[0] as f64 / 1e3, v[1] as f64 / 1e3, v[2] as f64 / 1e3);
        let (a, t) = (p(from), p(b.target));
        let (len, feed) = match b.kind {
            BlockKind::Dwell => return b.feed as f64 / 1000.0,
            BlockKind::End => return 0.0,
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

    /// Wire time of one RTU exchange at the configured baud (request and reply PDUs).
    fn line_time(&self, req_pdu: usize, resp_pdu: usize) -> Option<Duration> {
        let baud = self.cfg.line_baud? as f64;
        // address + PDU + CRC each way, and 3.5 characters of silence after each frame.
        let chars = (req_pdu + 3) as f64 + (resp_pdu + 3) as f64 + 7.0;
        Some(Duration::from_secs_f64(chars * 10.0 / baud))
    }

    async fn pace(
        &self,
        req: &Request<'_>,
        resp: Option<&Result<Response, ExceptionCode>>,
        rtu: bool,
    ) {
        let req_pdu = match req {
            Request::ReadHoldingRegisters(..) | Request::WriteSingleRegister(..) => 5,
            Request::WriteMultipleRegisters(_, w) => 6 + 2 * w.len(),
            _ => 5,
        };
        let resp_pdu = match resp {
            None => 0,
            Some(Err(_)) => 2,
            Some(Ok(Response::ReadHoldingRegisters(v))) => 2 + 2 * v.len(),
            Some(Ok(_)) => 5,
        };
        // RTU: address + CRC; TCP: the 7-byte MBAP header.
        let frame = |pdu: usize| {
            if pdu == 0 {
                0
            } else if rtu {
                pdu + 3
            } else {
                pdu + 7
            }
        };
        lock(&self.stats).wire_bytes += (frame(req_pdu) + frame(resp_pdu)) as u64;
        let Some(t) = self.line_time(req_pdu, resp_pdu) else {
            return;
        };
        let until = {
            let mut free = lock(&self.line_free_at);
            let start = (*free).max(Instant::now());
            *free = start + t;
            *free
        };
        tokio::time::sleep_until(until).await;
    }
}

/// The executor: takes committed blocks in sequence and runs them at machine speed.
async fn execute(shared: Arc<Shared>) {
    let order = shared.cfg.word_order;
    let mut clock = Instant::now();
    let mut since_yield = 0u32;
    loop {
        let next = {
            let mut dev = lock(&shared.dev);
            let consumed = dev.get32(order, reg::CONSUMED_SEQ);
            let write = dev.get32(order, reg::WRITE_SEQ);
            if dev.state() == ModbusState::Running as u16 && consumed < write {
                let seq = consumed + 1;
                let at = reg::RING as usize + shared.layout.slot(seq) as usize * 16;
                match MotionBlock::decode(&dev.regs[at..at + 16], order) {
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
                    Ok((_, block)) => {
                        let from = [
                            dev.get32(order, reg::POS_X) as i32,
                            dev.get32(order, reg::POS_Y) as i32,
                            dev.get32(order, reg::POS_Z) as i32,
                        ];
                        Some((seq, block, dev.epoch, from))
                    }
                }
            } else {
                None
            }
        };
        let Some((seq, block, epoch, from)) = next else {
            shared.wake.notified().await;
            continue;
        };
        if shared.cfg.time_scale > 0.0 && shared.cfg.time_scale.is_finite() {
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
        } else {
            since_yield += 1;
            if since_yield.is_multiple_of(64) {
                tokio::task::yield_now().await;
            }
        }
        let mut dev = lock(&shared.dev);
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
            }
        }
    }
}

/// The Modbus service of one connection (TCP) or of the line (RTU).
struct DeviceService {
    shared: Arc<Shared>,
    /// TCP: set to close this connection after the current request.
    kill: Option<Arc<AtomicBool>>,
}

impl Service for DeviceService {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = BoxFuture<'static, Result<Option<Response>, ExceptionCode>>;

    fn call(&self, req: SlaveRequest<'static>) -> Self::Future {
        let shared = Arc::clone(&self.shared);
        let kill = self.kill.clone();
        Box::pin(async move {
            let n = shared.request_no.fetch_add(1, Ordering::SeqCst) + 1;
            lock(&shared.stats).requests = n;
            let rtu = kill.is_none();
            if lock(&shared.silent_until).is_some_and(|t| Instant::now() < t) {
                return Ok(None);
            }
            // On TCP, unit 255 means "the device behind this address" (no gateway).
            let for_us = req.slave == shared.cfg.unit_id || (!rtu && req.slave == 255);
            if !for_us {
                return if rtu {
                    Ok(None)
                } else {
                    Err(ExceptionCode::GatewayTargetDevice)
                };
            }
            let faults = &shared.cfg.faults;
            if let Some(&(_, code)) = faults.exceptions.iter().find(|e| e.0 == n) {
                lock(&shared.stats).exceptions += 1;
                let r = Err(ExceptionCode::new(code));
                shared.pace(&req.request, Some(&r), rtu).await;
                return r.map(Some);
            }
            if faults.disconnects.contains(&n) {
                lock(&shared.stats).disconnects += 1;
                match &kill {
                    None => {
                        *lock(&shared.silent_until) = Some(Instant::now() + faults.silence);
                        return Ok(None);
                    }
                    Some(k) => {
                        let r = shared.apply(&req.request);
                        k.store(true, Ordering::SeqCst);
                        return r.map(Some);
                    }
                }
            }
            let r = shared.apply(&req.request);
            if faults.drop_replies.contains(&n) {
                lock(&shared.stats).dropped += 1;
                shared.pace(&req.request, None, rtu).await;
                return Ok(None);
            }
            if faults.late_replies.contains(&n) {
                lock(&shared.stats).late += 1;
                tokio::time::sleep(faults.late_by).await;
            }
            shared.pace(&req.request, Some(&r), rtu).await;
            r.map(Some)
        })
    }
}

/// A TCP stream that fails its next write once `kill` is set: how the device hangs up.
#[derive(Debug)]
struct HangUp {
    inner: TcpStream,
    kill: Arc<AtomicBool>,
}

impl AsyncRead for HangUp {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut TaskContext<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_read(cx, buf)
    }
}

impl AsyncWrite for HangUp {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut TaskContext<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        if self.kill.load(Ordering::SeqCst) {
            return Poll::Ready(Err(std::io::ErrorKind::BrokenPipe.into()));
        }
        Pin::new(&mut self.inner).poll_write(cx, buf)
    }
    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut TaskContext<'_>) -> Poll<std::io::Result<()>> {
        if self.kill.load(Ordering::SeqCst) {
            return Poll::Ready(Err(std::io::ErrorKind::BrokenPipe.into()));
        }
        Pin::new(&mut self.inner).poll_flush(cx)
    }
    fn poll_shutdown(
        mut self: Pin<&mut Self>,
        cx: &mut TaskContext<'_>,
    ) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

/// A running simulated device; dropping it stops it.
pub struct ModbusSim {
    shared: Arc<Shared>,
    tasks: Vec<JoinHandle<()>>,
    addr: Option<SocketAddr>,
    port: Option<PathBuf>,
    link: Option<PathBuf>,
    /// The pty's slave end, held open so the master never sees a hang-up between clients.
    _slave: Option<tokio_serial::SerialStream>,
}

impl ModbusSim {
    /// Serves the device on TCP at `bind` (port 0: any free port; see `addr()`).
    pub async fn spawn_tcp(cfg: SimConfig, bind: SocketAddr) -> std::io::Result<ModbusSim> {
        let shared = Shared::new(cfg);
        let listener = TcpListener::bind(bind).await?;
        let addr = listener.local_addr()?;
        let server = tokio_modbus::server::tcp::Server::new(listener);
        let sh = Arc::clone(&shared);
        let on_connected = move |stream: TcpStream, _peer: SocketAddr| {
            let shared = Arc::clone(&sh);
            async move {
                stream.set_nodelay(true)?;
                lock(&shared.stats).connections += 1;
                let kill = Arc::new(AtomicBool::new(false));
                let service = DeviceService {
                    shared,
                    kill: Some(Arc::clone(&kill)),
                };
                Ok(Some((
                    service,
                    HangUp {
                        inner: stream,
                        kill,
                    },
                )))
            }
        };
        let serve = tokio::spawn(async move {
            if let Err(e) = server.serve(&on_connected, |_e| {}).await {
                tracing::warn!("Modbus TCP device stopped: {e}");
            }
        });
        let exec = tokio::spawn(execute(Arc::clone(&shared)));
        Ok(ModbusSim {
            shared,
            tasks: vec![serve, exec],
            addr: Some(addr),
            port: None,
            link: None,
            _slave: None,
        })
    }

    /// Serves the device as an RTU slave on a new pseudo-terminal; clients open `port()`.
    /// With `link`, a symlink of that name points at the pty (replaced if it exists).
    pub async fn spawn_pty(cfg: SimConfig, link: Option<&Path>) -> std::io::Result<ModbusSim> {
        use tokio_serial::SerialPort;
        let shared = Shared::new(cfg);
        let (master, slave) = tokio_serial::SerialStream::pair().map_err(std::io::Error::from)?;
        let name = slave
            .name()
            .ok_or_else(|| std::io::Error::other("the pty has no name"))?;
        let port = PathBuf::from(name);
        if let Some(l) = link {
            let _ = std::fs::remove_file(l);
            std::os::unix::fs::symlink(&port, l)?;
        }
        lock(&shared.stats).connections = 1;
        let service = DeviceService {
            shared: Arc::clone(&shared),
            kill: None,
        };
        let serve = tokio::spawn(async move {
            let server = tokio_modbus::server::rtu::Server::new(master);
            if let Err(e) = server.serve_forever(service).await {
                tracing::warn!("Modbus RTU device stopped: {e}");
            }
        });
        let exec = tokio::spawn(execute(Arc::clone(&shared)));
        Ok(ModbusSim {
            shared,
            tasks: vec![serve, exec],
            addr: None,
            link: link.map(Path::to_path_buf),
            port: Some(port),
            _slave: Some(slave),
        })
    }

    /// The TCP address (TCP devices only).
    pub fn addr(&self) -> SocketAddr {
        self.addr
            .expect("addr() is for a device spawned with spawn_tcp")
    }
    /// The pty path clients open (RTU devices only): the symlink if one was asked for.
    pub fn port(&self) -> &Path {
        self.link
            .as_deref()
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
        if let Some(l) = &self.link {
            let _ = std::fs::remove_file(l);
        }
    }
}
