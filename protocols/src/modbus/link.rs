//! `ModbusLink`: streams motion blocks into a device's ring over Modbus TCP or RTU, or over
//! any byte stream handed to it.
//!
//! Three layers, each usable alone: the transport (`transport`: RTU or TCP framing on a
//! stream, late replies told apart), the session (`session`: opening, timeouts, reopening,
//! backoff) and the ring protocol (`ring`: docs/modbus.md's handshake). This module holds
//! their settings and errors and puts them together.

use super::frame::Request;
use super::map::{exception_name, fault_name, ModbusState, MotionBlock, Status, WordOrder};
use super::map::{HEADER_REGISTERS, MAX_WRITE_REGISTERS, STATUS_REGISTERS};
use super::ring::Ring;
use super::session::{Backoff, Dial, Session, SessionTiming};
pub use super::transport::Parity;
use super::transport::{Barrier, ByteStream, Endpoint, Framing, ReplyFate, WireCounters};
use crate::link::{
    Control, DeviceState, Handed, Link, LinkError, LinkEvent, MachineStatus, Reattach, SendJournal,
    StreamEnd,
};
use futures::future::BoxFuture;
use serde::{Deserialize, Serialize};
use std::time::Duration;
use tokio::sync::{mpsc, watch};

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

impl Transport {
    /// The framing this transport speaks.
    pub fn framing(&self) -> Framing {
        match self {
            Transport::Tcp { .. } => Framing::Tcp,
            Transport::Rtu { baud, .. } => Framing::Rtu { baud: *baud },
        }
    }
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
    /// Commit the write sequence and read the header in one FC23 request when the device
    /// answers FC23 (a device that answers Illegal Function gets FC16 + FC3 from then on).
    pub read_write: bool,
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
    /// so that a late reply is not taken for the next one (RTU has no transaction id). Never
    /// less than 3.5 characters.
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
            read_write: true,
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
    fn target(&self) -> String {
        format!("Modbus device {} unit {}", self.transport, self.unit_id)
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
        source: std::io::Error,
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
    /// Whether the device still holds what it held before the failure in a known way (an
    /// exception: the request was not carried out), so no resynchronisation is needed.
    pub fn keeps_connection(&self) -> bool {
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

/// A link to a motion-block device over Modbus TCP or RTU.
pub struct ModbusLink {
    s: ModbusSettings,
    pub(super) session: Session,
    pub(super) ring: Ring,
}

impl ModbusLink {
    /// A link that opens its transport (`settings.transport`) on first use, and again after
    /// a failure.
    pub fn new(settings: ModbusSettings) -> Result<Self, ModbusError> {
        let dial = Dial::Open(match &settings.transport {
            Transport::Tcp { host, port } => Endpoint::Tcp {
                host: host.clone(),
                port: *port,
            },
            Transport::Rtu { path, baud, parity } => Endpoint::Serial {
                path: path.clone(),
                baud: *baud,
                parity: *parity,
            },
        });
        Self::with_dial(settings, dial)
    }

    /// A link on a stream that is already open (a serial port, a TCP stream, a test cable),
    /// framed as `settings.transport` says (TCP, or RTU at its baud rate; its path only
    /// names the device in messages). The stream is never reopened: once it closes, every
    /// request fails.
    pub fn from_stream(
        io: impl ByteStream + 'static,
        settings: ModbusSettings,
    ) -> Result<Self, ModbusError> {
        let framing = settings.transport.framing();
        Self::with_dial(settings, Dial::Given(Some(Box::new(io)), framing))
    }

    fn with_dial(settings: ModbusSettings, dial: Dial) -> Result<Self, ModbusError> {
        settings.validate()?;
        // After a timeout on RTU the header is read with a count no owed request has.
        let barrier = Barrier {
            addr: settings.base_address,
            counts: (STATUS_REGISTERS, HEADER_REGISTERS),
        };
        let session = Session::new(
            dial,
            settings.unit_id,
            SessionTiming {
                timeout: settings.timeout,
                quiet: settings.rtu_quiet,
            },
            Some(barrier),
            settings.target(),
        );
        let ring = Ring::new(&settings);
        Ok(ModbusLink {
            s: settings,
            session,
            ring,
        })
    }

    pub fn settings(&self) -> &ModbusSettings {
        &self.s
    }
    /// Requests sent so far.
    pub fn requests(&self) -> u64 {
        self.session.counters().requests
    }
    /// How often the transport was opened (the first time included).
    pub fn reconnects(&self) -> u64 {
        self.session.opens()
    }
    /// What the transport did: requests, replies, stale replies discarded, bytes drained.
    pub fn wire_counters(&self) -> WireCounters {
        self.session.counters()
    }
    /// Records the fate of every reply frame from now on, for tests that check that no late
    /// reply was ever taken for another request's answer.
    pub fn record_replies(&mut self) {
        self.session.record_replies();
    }
    /// Every reply frame's fate since `record_replies`, requests numbered from 1.
    pub fn replies(&self) -> Vec<ReplyFate> {
        self.session.replies()
    }
    /// Whether the device answered FC23 (read/write in one request): `None` until tried.
    pub fn uses_read_write(&self) -> Option<bool> {
        self.ring.uses_read_write()
    }

    /// Clears a device fault (command 5): the device goes idle and drops unexecuted blocks,
    /// so a resume from the last acknowledged unit continues the job.
    pub async fn clear_fault(&mut self) -> Result<(), ModbusError> {
        self.ring.clear_fault(&mut self.session).await
    }

    /// Reads the header and checks that it is the map this link speaks.
    pub async fn read_status(&mut self) -> Result<Status, ModbusError> {
        self.ring.read_status(&mut self.session).await
    }

    /// Sends one request as it is (for tools and conformance tests); an exception reply
    /// is `ModbusError::Exception`.
    pub async fn call(&mut self, req: &Request) -> Result<super::frame::Response, ModbusError> {
        let what = self.ring.describe(req);
        self.session.call(req, &what).await
    }

    /// Streams `blocks` from unit `from` on (unit `i` travels as sequence `i + 1`).
    pub async fn stream_blocks(
        &mut self,
        blocks: &[MotionBlock],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> Result<StreamEnd, ModbusError> {
        let backoff = Backoff::new(
            self.s.backoff_initial,
            self.s.backoff_max,
            self.s.max_retries,
        );
        self.ring
            .stream(&mut self.session, backoff, blocks, from, events, control)
            .await
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
        self.ring.journal = Some(journal);
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
