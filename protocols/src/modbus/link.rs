//! `ModbusLink`: streams motion blocks into a device's ring over Modbus TCP or RTU, with
//! timeouts, reconnects with backoff, and a resynchronisation that never loses or repeats a block.

use super::map::{
    exception_name, fault_name, reg, Command, Layout, ModbusState, MotionBlock, Status, WordOrder,
    BLOCK_REGISTERS, MAP_VERSION, MAX_READ_REGISTERS, MAX_WRITE_REGISTERS, STATUS_REGISTERS,
};
use crate::link::{
    Control, DeviceState, Handed, Link, LinkError, LinkEvent, MachineStatus, Reattach, SendJournal,
    StreamEnd,
};
use futures::future::BoxFuture;
use serde::{Deserialize, Serialize};
use std::borrow::Cow;
use std::time::{Duration, Instant};
use tokio::io::AsyncReadExt;
use tokio::sync::{mpsc, watch};
use tokio_modbus::client::{Client, Context};
use tokio_modbus::{Request, Response, Slave};
use tokio_serial::SerialPort;

/// Parity of an RTU line.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Parity {
    #[default]
    None,
    Even,
    Odd,
}

/// How the link reaches the device.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "transport", rename_all = "snake_case")]
pub enum Transport {
    /// Modbus TCP to `host:port`.
    Tcp { host: String, port: u16 },
    /// Modbus RTU on a serial port (8 data bits, 1 stop bit).
    Rtu {
        path: String,
        baud: u32,
        parity: Parity,
    },
}

impl std::fmt::Display for Transport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Transport::Tcp { host, port } => write!(f, "{host}:{port}"),
            Transport::Rtu { path, .. } => write!(f, "{path}"),
        }
    }
}

/// Everything the link needs to know about one device.
#[derive(Clone, Debug, PartialEq)]
pub struct ModbusSettings {
    pub transport: Transport,
    /// Unit id (RTU slave address; on TCP usually 1 or 255).
    pub unit_id: u8,
    /// Address of header register 0.
    pub base_address: u16,
    /// Which half of 32-bit values comes first.
    pub word_order: WordOrder,
    /// The most registers per FC16 write (1..=123; many drives take 10 or 12).
    pub max_write_registers: u16,
    /// How long one request may wait for its reply.
    pub timeout: Duration,
    /// How often the header is read while waiting for room in the ring.
    pub poll_interval: Duration,
    /// First wait before retrying after a failure; doubles each time up to `backoff_max`.
    pub backoff_initial: Duration,
    pub backoff_max: Duration,
    /// Failed attempts in a row before the stream gives up.
    pub max_retries: u32,
    /// RTU only: after a timeout, the line must be silent this long before the next request,
    /// so that a late reply is not taken for the next one (RTU has no transaction id).
    pub rtu_quiet: Duration,
}

impl ModbusSettings {
    fn with(transport: Transport) -> Self {
        ModbusSettings {
            transport,
            unit_id: 1,
            base_address: 0,
            word_order: WordOrder::HighFirst,
            max_write_registers: MAX_WRITE_REGISTERS,
            timeout: Duration::from_millis(500),
            poll_interval: Duration::from_millis(20),
            backoff_initial: Duration::from_millis(50),
            backoff_max: Duration::from_secs(2),
            max_retries: 8,
            rtu_quiet: Duration::from_millis(500),
        }
    }
    /// Defaults for a Modbus TCP device.
    pub fn tcp(host: impl Into<String>, port: u16) -> Self {
        Self::with(Transport::Tcp {
            host: host.into(),
            port,
        })
    }
    /// Defaults for a Modbus RTU device (no parity).
    pub fn rtu(path: impl Into<String>, baud: u32) -> Self {
        Self::with(Transport::Rtu {
            path: path.into(),
            baud,
            parity: Parity::None,
        })
    }
    /// Checks the settings, naming the first wrong one.
    pub fn validate(&self) -> Result<(), ModbusError> {
        let bad = |m: String| Err(ModbusError::Settings(m));
        if !(1..=MAX_WRITE_REGISTERS).contains(&self.max_write_registers) {
            return bad(format!(
                "max_write_registers is {}, but must be between 1 and {MAX_WRITE_REGISTERS}",
                self.max_write_registers
            ));
        }
        if self.timeout.is_zero() {
            return bad("timeout must be above zero".into());
        }
        if self.unit_id == 0 {
            return bad("unit id 0 is the broadcast address, which never answers".into());
        }
        if let Transport::Rtu { baud: 0, .. } = self.transport {
            return bad("baud must be above zero".into());
        }
        Ok(())
    }
}

/// Why talking to a Modbus device failed.
#[derive(Debug, thiserror::Error)]
pub enum ModbusError {
    #[error("cannot connect to {target}: {source}")]
    Connect {
        target: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{target} did not answer the {what} within {after:?}")]
    Timeout {
        target: String,
        what: String,
        after: Duration,
    },
    #[error("{target}: the {what} failed: {source}")]
    Transport {
        target: String,
        what: String,
        #[source]
        source: tokio_modbus::Error,
    },
    #[error("{target} answered the {what} with a reply that does not match it: {detail}")]
    BadReply {
        target: String,
        what: String,
        detail: String,
    },
    #[error("{target} answered the {what} with exception 0x{code:02X} {}", exception_name(*code))]
    Exception {
        target: String,
        what: String,
        code: u8,
    },
    #[error("{target} faulted with code 0x{code:04X} ({}) at block {block}{detail}", fault_name(*code))]
    DeviceFault {
        target: String,
        code: u16,
        block: u32,
        detail: String,
    },
    #[error("{target}: {message}")]
    Protocol { target: String, message: String },
    #[error("the Modbus settings are wrong: {0}")]
    Settings(String),
    #[error("gave up on {target} after {attempts} failed attempts in a row; the last: {last}")]
    GaveUp {
        target: String,
        attempts: u32,
        last: Box<ModbusError>,
    },
}

impl ModbusError {
    /// Whether trying again (after a reconnect, unless `keeps_connection`) may succeed.
    pub fn is_retryable(&self) -> bool {
        match self {
            ModbusError::Connect { .. }
            | ModbusError::Timeout { .. }
            | ModbusError::Transport { .. }
            | ModbusError::BadReply { .. } => true,
            // Acknowledge and Server Device Busy ask the client to come back later.
            ModbusError::Exception { code, .. } => matches!(code, 0x05 | 0x06),
            _ => false,
        }
    }
    fn keeps_connection(&self) -> bool {
        matches!(self, ModbusError::Exception { .. })
    }
}

impl From<ModbusError> for LinkError {
    fn from(e: ModbusError) -> Self {
        match e {
            ModbusError::Connect { target, source } => LinkError::Open {
                port: target,
                source,
            },
            ModbusError::DeviceFault { code, .. } => LinkError::Alarm {
                code: Some(code as u32),
                text: e.to_string(),
            },
            ModbusError::GaveUp { .. } | ModbusError::Timeout { .. } => LinkError::Io(
                std::io::Error::new(std::io::ErrorKind::TimedOut, e.to_string()),
            ),
            other => LinkError::Protocol(other.to_string()),
        }
    }
}

/// Where a stream stands, as the host knows it.
#[derive(Debug)]
struct Progress {
    /// Every block up to this sequence is in the ring with verified contents.
    written: u32,
    /// The write sequence the device last confirmed.
    committed: u32,
    /// Highest sequence a write may have touched (partially, if it failed).
    touched: u32,
    /// The consumed sequence last reported as acknowledged.
    acked: u32,
    started: bool,
    synced: bool,
    last_state: Option<u16>,
    last_status: Option<Instant>,
}

/// A link to a motion-block device over Modbus TCP or RTU.
pub struct ModbusLink {
    s: ModbusSettings,
    ctx: Option<Context>,
    /// The previous connection ended in a timeout: drain late replies before the next request.
    drain: bool,
    layout: Layout,
    target: String,
    /// Requests sent, reconnects made: for benchmarks and logs.
    pub requests: u64,
    pub reconnects: u64,
    /// Where the sync that hands the device a program is journaled first (see `attach.rs`).
    pub(super) journal: Option<Box<dyn SendJournal>>,
}

impl ModbusLink {
    /// A link that connects on first use.
    pub fn new(settings: ModbusSettings) -> Result<Self, ModbusError> {
        settings.validate()?;
        let target = format!(
            "Modbus device {} unit {}",
            settings.transport, settings.unit_id
        );
        Ok(ModbusLink {
            layout: Layout {
                base: settings.base_address,
                capacity: 0,
            },
            s: settings,
            ctx: None,
            drain: false,
            target,
            requests: 0,
            reconnects: 0,
            journal: None,
        })
    }

    pub fn settings(&self) -> &ModbusSettings {
        &self.s
    }

    async fn connect(&mut self) -> Result<(), ModbusError> {
        let slave = Slave(self.s.unit_id);
        let target = self.target.clone();
        let conn_err = |source| ModbusError::Connect {
            target: target.clone(),
            source,
        };
        let ctx = match &self.s.transport {
            Transport::Tcp { host, port } => {
                let stream = tokio::time::timeout(
                    self.s.timeout,
                    tokio::net::TcpStream::connect((host.as_str(), *port)),
                )
                .await
                .map_err(|_| conn_err(std::io::ErrorKind::TimedOut.into()))?
                .map_err(conn_err)?;
                stream.set_nodelay(true).map_err(conn_err)?;
                tokio_modbus::client::tcp::attach_slave(stream, slave)
            }
            Transport::Rtu { path, baud, parity } => {
                use tokio_serial::SerialPortBuilderExt;
                let mut port = tokio_serial::new(path, *baud)
                    .data_bits(tokio_serial::DataBits::Eight)
                    .stop_bits(tokio_serial::StopBits::One)
                    .parity(match parity {
                        Parity::None => tokio_serial::Parity::None,
                        Parity::Even => tokio_serial::Parity::Even,
                        Parity::Odd => tokio_serial::Parity::Odd,
                    })
                    .open_native_async()
                    .map_err(|e| conn_err(e.into()))?;
                if self.drain {
                    drain_until_quiet(&mut port, self.s.rtu_quiet).await;
                }
                port.clear(tokio_serial::ClearBuffer::All)
                    .map_err(|e| conn_err(e.into()))?;
                tokio_modbus::client::rtu::attach_slave(port, slave)
            }
        };
        self.drain = false;
        self.ctx = Some(ctx);
        self.reconnects += 1;
        Ok(())
    }

    /// Sends one request with the timeout, checks the reply matches it, and drops the
    /// connection after anything but a clean reply or an exception.
    async fn exchange(&mut self, req: Request<'static>) -> Result<Response, ModbusError> {
        if self.ctx.is_none() {
            self.connect().await?;
        }
        let what = self.describe(&req);
        let Some(ctx) = self.ctx.as_mut() else {
            unreachable!("connect() either sets the context or fails")
        };
        self.requests += 1;
        let result = tokio::time::timeout(self.s.timeout, ctx.call(req.clone())).await;
        let fail = |this: &mut Self, e: ModbusError| {
            this.ctx = None;
            this.drain = true;
            Err(e)
        };
        match result {
            Err(_) => {
                let e = ModbusError::Timeout {
                    target: self.target.clone(),
                    what,
                    after: self.s.timeout,
                };
                fail(self, e)
            }
            Ok(Err(source)) => {
                let e = ModbusError::Transport {
                    target: self.target.clone(),
                    what,
                    source,
                };
                fail(self, e)
            }
            Ok(Ok(Err(code))) => Err(ModbusError::Exception {
                target: self.target.clone(),
                what,
                code: code.into(),
            }),
            Ok(Ok(Ok(resp))) => match reply_mismatch(&req, &resp) {
                None => Ok(resp),
                Some(detail) => {
                    let e = ModbusError::BadReply {
                        target: self.target.clone(),
                        what,
                        detail,
                    };
                    fail(self, e)
                }
            },
        }
    }

    fn describe(&self, req: &Request<'_>) -> String {
        match req {
            Request::ReadHoldingRegisters(a, n) => {
                format!("read of {}", self.layout.describe(*a, *n))
            }
            Request::WriteMultipleRegisters(a, w) => {
                format!("write of {}", self.layout.describe(*a, w.len() as u16))
            }
            Request::WriteSingleRegister(a, _) => {
                format!("write of {}", self.layout.describe(*a, 1))
            }
            other => format!("{:?}", other.function_code()),
        }
    }

    async fn read(&mut self, addr: u16, count: u16) -> Result<Vec<u16>, ModbusError> {
        match self
            .exchange(Request::ReadHoldingRegisters(addr, count))
            .await?
        {
            Response::ReadHoldingRegisters(v) => Ok(v),
            _ => unreachable!("exchange() checked the reply's function"),
        }
    }

    async fn write(&mut self, addr: u16, words: Vec<u16>) -> Result<(), ModbusError> {
        self.exchange(Request::WriteMultipleRegisters(addr, Cow::Owned(words)))
            .await
            .map(|_| ())
    }

    /// Writes the command register. FC16 rather than FC6: the register reads back 0 once
    /// the device acted, and some devices (pymodbus among them) echo that 0 in an FC6 reply.
    async fn command(&mut self, c: Command) -> Result<(), ModbusError> {
        self.write(self.s.base_address + reg::COMMAND, vec![c as u16])
            .await
    }

    async fn write_seq(&mut self, seq: u32) -> Result<(), ModbusError> {
        let words = self.s.word_order.split(seq).to_vec();
        self.write(self.s.base_address + reg::WRITE_SEQ, words)
            .await
    }

    /// Clears a device fault (command 5): the device goes idle and drops unexecuted blocks,
    /// so a resume from the last acknowledged unit continues the job.
    pub async fn clear_fault(&mut self) -> Result<(), ModbusError> {
        self.command(Command::ClearFault).await
    }

    /// Reads the header and checks that it is the map this link speaks.
    pub async fn read_status(&mut self) -> Result<Status, ModbusError> {
        let r = self.read(self.s.base_address, STATUS_REGISTERS).await?;
        let s = Status::decode(&r, self.s.word_order);
        let proto = |message: String| ModbusError::Protocol {
            target: self.target.clone(),
            message,
        };
        if s.version != MAP_VERSION {
            return Err(proto(format!(
                "holding register {} (map version) reads {}, but this link speaks version {MAP_VERSION}; check the base address",
                self.s.base_address + reg::VERSION,
                s.version
            )));
        }
        if s.block_size != BLOCK_REGISTERS {
            return Err(proto(format!(
                "holding register {} (block size) reads {}, but map version 1 has {BLOCK_REGISTERS}-register blocks",
                self.s.base_address + reg::BLOCK_SIZE,
                s.block_size
            )));
        }
        let layout = Layout {
            base: self.s.base_address,
            capacity: s.capacity,
        };
        if s.capacity == 0 || layout.end() > 0x1_0000 {
            return Err(proto(format!(
                "holding register {} (ring capacity) reads {}, which does not fit the address space above base {}",
                self.s.base_address + reg::CAPACITY,
                s.capacity,
                self.s.base_address
            )));
        }
        if ModbusState::from_register(s.state).is_none() {
            return Err(proto(format!(
                "holding register {} (state word) reads {}, which is no state of the map",
                self.s.base_address + reg::STATE,
                s.state
            )));
        }
        self.layout = layout;
        Ok(s)
    }

    /// Reads the sequence numbers and contents of ring slots for `first..=last` (at most
    /// one ring's worth) and says for each whether it holds that block of `blocks`.
    pub(crate) async fn slots_match(
        &mut self,
        blocks: &[MotionBlock],
        first: u32,
        last: u32,
    ) -> Result<Vec<bool>, ModbusError> {
        let order = self.s.word_order;
        let mut out = Vec::new();
        for (start_seq, regs_run) in self.runs(first, last) {
            let addr = self.layout.slot_address(self.layout.slot(start_seq));
            let mut regs = Vec::with_capacity(regs_run as usize);
            let per_read = MAX_READ_REGISTERS / BLOCK_REGISTERS * BLOCK_REGISTERS;
            let mut off = 0u16;
            while off < regs_run {
                let n = per_read.min(regs_run - off);
                regs.extend(self.read(addr + off, n).await?);
                off += n;
            }
            for (k, chunk) in regs.chunks(BLOCK_REGISTERS as usize).enumerate() {
                let seq = start_seq + k as u32;
                let want = blocks[seq as usize - 1].encode(seq, order);
                out.push(chunk == want);
            }
        }
        Ok(out)
    }

    /// Splits sequences `first..=last` into runs of adjacent ring slots: (first seq, registers).
    fn runs(&self, first: u32, last: u32) -> Vec<(u32, u16)> {
        let mut runs = Vec::new();
        let mut seq = first;
        while seq <= last {
            let slot = self.layout.slot(seq);
            let n = (last - seq + 1).min((self.layout.capacity - slot) as u32);
            runs.push((seq, n as u16 * BLOCK_REGISTERS));
            seq += n;
        }
        runs
    }

    /// Writes blocks `first..=last` into their slots, chunked to `max_write_registers`.
    async fn write_blocks(
        &mut self,
        blocks: &[MotionBlock],
        first: u32,
        last: u32,
    ) -> Result<(), ModbusError> {
        let order = self.s.word_order;
        for (start_seq, regs_run) in self.runs(first, last) {
            let addr = self.layout.slot_address(self.layout.slot(start_seq));
            let n_blocks = regs_run / BLOCK_REGISTERS;
            let mut regs = Vec::with_capacity(regs_run as usize);
            for k in 0..n_blocks as u32 {
                let seq = start_seq + k;
                regs.extend_from_slice(&blocks[seq as usize - 1].encode(seq, order));
            }
            for (i, chunk) in regs.chunks(self.s.max_write_registers as usize).enumerate() {
                let at = addr + (i * self.s.max_write_registers as usize) as u16;
                self.write(at, chunk.to_vec()).await?;
            }
        }
        Ok(())
    }

    /// After a reconnect (or when a stream finds the device busy): reads where the device is
    /// and which slots hold the right blocks, and sets the progress so that only missing
    /// blocks are rewritten and nothing the device accepted is sent again.
    async fn resync(
        &mut self,
        blocks: &[MotionBlock],
        p: &mut Progress,
    ) -> Result<(), ModbusError> {
        let s = self.read_status().await?;
        let total = blocks.len() as u32;
        let target = self.target.clone();
        let proto = |message: String| ModbusError::Protocol { target, message };
        if s.consumed_seq < p.acked {
            return Err(proto(format!(
                "the consumed sequence went back from {} to {} (did the device restart?); the job stops at block {}",
                p.acked, s.consumed_seq, p.acked
            )));
        }
        if s.write_seq != p.committed && s.write_seq != p.written {
            return Err(proto(format!(
                "the write sequence reads {}, but this link last wrote {} (another master on the device?)",
                s.write_seq, p.committed
            )));
        }
        p.committed = s.write_seq;
        let last = p
            .touched
            .max(p.written)
            .min(total)
            .min(s.consumed_seq + s.capacity as u32);
        if last > s.consumed_seq {
            let ok = self.slots_match(blocks, s.consumed_seq + 1, last).await?;
            let mut written = s.consumed_seq;
            for (k, good) in ok.iter().enumerate() {
                let seq = s.consumed_seq + 1 + k as u32;
                if seq <= p.committed && !good {
                    return Err(proto(format!(
                        "ring slot {} does not hold block {seq}, which the device had accepted",
                        self.layout.slot(seq)
                    )));
                }
                if !good {
                    break;
                }
                written = seq;
            }
            p.written = written;
        } else {
            p.written = s.consumed_seq.max(p.committed);
        }
        p.touched = p.written;
        Ok(())
    }

    fn observe(
        &self,
        s: &Status,
        blocks: &[MotionBlock],
        p: &mut Progress,
        events: &mpsc::UnboundedSender<LinkEvent>,
    ) -> Result<(), ModbusError> {
        if s.consumed_seq < p.acked {
            return Err(ModbusError::Protocol {
                target: self.target.clone(),
                message: format!(
                    "the consumed sequence went back from {} to {} (did the device restart?)",
                    p.acked, s.consumed_seq
                ),
            });
        }
        if s.consumed_seq > p.acked {
            if s.consumed_seq > p.committed.max(p.written) || s.consumed_seq as usize > blocks.len()
            {
                return Err(ModbusError::Protocol {
                    target: self.target.clone(),
                    message: format!(
                        "the device reports block {} consumed, but only {} were committed",
                        s.consumed_seq, p.committed
                    ),
                });
            }
            p.acked = s.consumed_seq;
            let _ = events.send(LinkEvent::Acked {
                unit: p.acked as usize - 1,
            });
        }
        let due = p
            .last_status
            .is_none_or(|t| t.elapsed() >= Duration::from_millis(200));
        if p.last_state != Some(s.state) || due {
            p.last_state = Some(s.state);
            p.last_status = Some(Instant::now());
            let _ = events.send(LinkEvent::Status(s.to_status()));
        }
        if s.state == ModbusState::Fault as u16 {
            let block = s.consumed_seq + 1;
            let detail = blocks
                .get(block as usize - 1)
                .map(|b| format!(" ({b})"))
                .unwrap_or_default();
            return Err(ModbusError::DeviceFault {
                target: self.target.clone(),
                code: s.fault,
                block,
                detail,
            });
        }
        Ok(())
    }

    /// One round: read the header, obey the operator, then commit, fill the ring, start, or wait.
    async fn step(
        &mut self,
        blocks: &[MotionBlock],
        from: u32,
        p: &mut Progress,
        events: &mpsc::UnboundedSender<LinkEvent>,
        control: &mut watch::Receiver<Control>,
    ) -> Result<Option<StreamEnd>, ModbusError> {
        let total = blocks.len() as u32;
        let s = self.read_status().await?;
        if !p.synced {
            if s.state == ModbusState::Idle as u16 {
                // A new job: the device's consumed sequence becomes `from`.
                self.journal_sync(from, total)?;
                self.write_seq(from).await?;
                self.command(Command::Sync).await?;
                let s = self.read_status().await?;
                if s.consumed_seq != from || s.write_seq != from {
                    return Err(ModbusError::Protocol {
                        target: self.target.clone(),
                        message: format!(
                            "after the sync command the device reports consumed {} and write {}, not {from}",
                            s.consumed_seq, s.write_seq
                        ),
                    });
                }
                (p.written, p.committed, p.touched, p.acked) = (from, from, from, from);
                self.journal_synced(total)?;
            } else if s.state == ModbusState::Fault as u16 {
                return Err(ModbusError::Protocol {
                    target: self.target.clone(),
                    message: format!(
                        "the device is in fault 0x{:04X} ({}) from before this job; clear it at the machine (command register {} = 5) and resume",
                        s.fault,
                        fault_name(s.fault),
                        self.s.base_address + reg::COMMAND
                    ),
                });
            } else {
                // Still running this program from an earlier stream: take over where it is.
                if s.consumed_seq < from || s.write_seq > total {
                    return Err(ModbusError::Protocol {
                        target: self.target.clone(),
                        message: format!(
                            "the device is busy (state {}) with blocks {}..{} of another program; stop it first",
                            ModbusState::from_register(s.state).map_or("?", |d| d.name()),
                            s.consumed_seq,
                            s.write_seq
                        ),
                    });
                }
                (p.committed, p.written, p.touched, p.acked) =
                    (s.write_seq, s.write_seq, s.write_seq, from);
                self.resync(blocks, p).await?;
                p.started = true;
            }
            p.synced = true;
            return Ok(None);
        }
        self.observe(&s, blocks, p, events)?;
        let state = ModbusState::from_register(s.state);
        if matches!(state, Some(ModbusState::Running | ModbusState::Hold)) {
            p.started = true;
        }
        let want = *control.borrow_and_update();
        match want {
            Control::Cancel => {
                self.command(Command::Stop).await?;
                let s = self.read_status().await?;
                self.observe(&s, blocks, p, events)?;
                return Ok(Some(StreamEnd::Cancelled {
                    acked: p.acked as usize,
                }));
            }
            Control::Hold if state == Some(ModbusState::Running) => {
                self.command(Command::Hold).await?
            }
            Control::Run if state == Some(ModbusState::Hold) => {
                self.command(Command::Resume).await?
            }
            _ => {}
        }
        if s.consumed_seq >= total && state == Some(ModbusState::Idle) {
            return Ok(Some(StreamEnd::Completed));
        }
        if s.write_seq != p.committed {
            return Err(ModbusError::Protocol {
                target: self.target.clone(),
                message: format!(
                    "the write sequence changed from {} to {} behind this link's back (stopped at the machine?)",
                    p.committed, s.write_seq
                ),
            });
        }
        if p.started && state == Some(ModbusState::Idle) {
            return Err(ModbusError::Protocol {
                target: self.target.clone(),
                message: format!(
                    "the device went idle after block {} of {total} (stopped at the machine?)",
                    s.consumed_seq
                ),
            });
        }
        let mut worked = false;
        let in_ring = p.written - s.consumed_seq;
        let room = (s.capacity as u32).saturating_sub(in_ring);
        if p.written < total && room > 0 {
            let batch = room.min((s.capacity as u32 / 2).max(1));
            let last = (p.written + batch).min(total);
            p.touched = p.touched.max(last);
            self.write_blocks(blocks, p.written + 1, last).await?;
            p.written = last;
            worked = true;
        }
        if p.written > p.committed {
            self.write_seq(p.written).await?;
            p.committed = p.written;
            worked = true;
        }
        if !p.started && p.committed > s.consumed_seq && state == Some(ModbusState::Idle) {
            self.command(Command::Start).await?;
            p.started = true;
            worked = true;
        }
        if !worked {
            // Wake early for the operator; a dropped control sender just leaves the poll.
            let operator = async {
                if control.changed().await.is_err() {
                    std::future::pending::<()>().await
                }
            };
            tokio::select! {
                _ = tokio::time::sleep(self.s.poll_interval) => {}
                _ = operator => {}
            }
        }
        Ok(None)
    }

    /// Streams `blocks` from unit `from` on (unit `i` travels as sequence `i + 1`).
    pub async fn stream_blocks(
        &mut self,
        blocks: &[MotionBlock],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        mut control: watch::Receiver<Control>,
    ) -> Result<StreamEnd, ModbusError> {
        if blocks.len() >= u32::MAX as usize {
            return Err(ModbusError::Settings(format!(
                "a program of {} blocks does not fit 32-bit sequence numbers",
                blocks.len()
            )));
        }
        let from = from.min(blocks.len()) as u32;
        let mut p = Progress {
            written: from,
            committed: from,
            touched: from,
            acked: from,
            started: false,
            synced: false,
            last_state: None,
            last_status: None,
        };
        let mut failures = 0u32;
        let mut resync = false;
        loop {
            let r = if resync {
                self.resync(blocks, &mut p).await.map(|()| None)
            } else {
                self.step(blocks, from, &mut p, &events, &mut control).await
            };
            match r {
                Ok(Some(end)) => return Ok(end),
                Ok(None) => {
                    failures = 0;
                    resync = false;
                }
                Err(e) if e.is_retryable() => {
                    failures += 1;
                    if failures > self.s.max_retries {
                        return Err(ModbusError::GaveUp {
                            target: self.target.clone(),
                            attempts: failures,
                            last: Box::new(e),
                        });
                    }
                    if !e.keeps_connection() {
                        // Before the sync the device holds nothing of ours: redo the sync.
                        resync = p.synced;
                    }
                    let _ = events.send(LinkEvent::Message(format!("retrying: {e}")));
                    let wait = self
                        .s
                        .backoff_initial
                        .saturating_mul(1 << (failures - 1).min(16))
                        .min(self.s.backoff_max);
                    tokio::time::sleep(wait).await;
                }
                Err(e) => return Err(e),
            }
        }
    }
}

impl Link<MotionBlock> for ModbusLink {
    fn stream<'a>(
        &'a mut self,
        blocks: &'a [MotionBlock],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        Box::pin(async move {
            self.stream_blocks(blocks, from, events, control)
                .await
                .map_err(LinkError::from)
        })
    }
    fn inquire(&mut self) -> BoxFuture<'_, Result<MachineStatus, LinkError>> {
        Box::pin(async move { Ok(self.read_status().await?.to_status()) })
    }
    fn reattach<'a>(
        &'a mut self,
        blocks: &'a [MotionBlock],
        handed: Handed,
        _events: mpsc::UnboundedSender<LinkEvent>,
        _control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<Reattach, LinkError>> {
        Box::pin(async move { self.where_is(blocks, handed).await.map_err(LinkError::from) })
    }
    fn keep_journal(&mut self, journal: Box<dyn SendJournal>) {
        self.journal = Some(journal);
    }
}

impl Status {
    /// The header as the link's `MachineStatus`.
    pub fn to_status(&self) -> MachineStatus {
        let known = ModbusState::from_register(self.state);
        MachineStatus {
            state: match known {
                Some(ModbusState::Idle) => DeviceState::Idle,
                Some(ModbusState::Running) => DeviceState::Running,
                Some(ModbusState::Hold) => DeviceState::Held,
                Some(ModbusState::Fault) => DeviceState::Alarm {
                    code: Some(self.fault as u32),
                    text: fault_name(self.fault).to_string(),
                },
                None => DeviceState::Unknown,
            },
            detail: known.map_or_else(|| format!("state {}", self.state), |k| k.name().into()),
            position: self.position.map(|v| v as f64 / 1000.0),
            feed: 0.0,
        }
    }
}

/// Reads and drops whatever arrives until the line has been silent for `quiet` (at most
/// ten quiet periods in all, so a chattering line cannot hold the link forever).
async fn drain_until_quiet(port: &mut tokio_serial::SerialStream, quiet: Duration) {
    let mut buf = [0u8; 256];
    let give_up = Instant::now() + quiet * 10;
    while Instant::now() < give_up {
        match tokio::time::timeout(quiet, port.read(&mut buf)).await {
            Ok(Ok(n)) if n > 0 => continue,
            _ => break,
        }
    }
}

/// Why `resp` cannot be the reply to `req`, if it cannot.
fn reply_mismatch(req: &Request<'_>, resp: &Response) -> Option<String> {
    match (req, resp) {
        (Request::ReadHoldingRegisters(_, n), Response::ReadHoldingRegisters(v)) => {
            (v.len() != *n as usize).then(|| format!("{} registers instead of {n}", v.len()))
        }
        (Request::WriteMultipleRegisters(a, w), Response::WriteMultipleRegisters(a2, n2)) => {
            (*a != *a2 || w.len() != *n2 as usize)
                .then(|| format!("it confirms {n2} registers at {a2}"))
        }
        (Request::WriteSingleRegister(a, v), Response::WriteSingleRegister(a2, v2)) => {
            (a != a2 || v != v2).then(|| format!("it confirms {v2} at {a2}"))
        }
        _ => Some(format!("{resp:?}")),
    }
}
