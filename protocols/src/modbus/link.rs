//! `ModbusLink`: streams motion blocks into a device's ring over Modbus TCP or RTU, or over
//! any byte stream handed to it.
//!
//! Three layers, each usable alone: the transport (`transport`: RTU or TCP framing on a
//! stream, late replies told apart), the session (`session`: opening, timeouts, reopening,
//! backoff) and the ring protocol (`ring`: docs/modbus.md's handshake). Their settings and
//! errors are `settings`'s; this module puts them together.

use super::frame::Request;
use super::map::{fault_name, ModbusState, MotionBlock, Status};
use super::map::{HEADER_REGISTERS, STATUS_REGISTERS};
use super::ring::Ring;
use super::session::{Backoff, Dial, Session, SessionTiming};
pub use super::settings::{ModbusError, ModbusSettings, Transport};
pub use super::transport::Parity;
use super::transport::{Barrier, ByteStream, Endpoint, ReplyFate, WireCounters};
use crate::link::{
    Control, DeviceState, Handed, Link, LinkError, LinkEvent, MachineStatus, Reattach, SendJournal,
    StreamEnd,
};
use futures::future::BoxFuture;
use tokio::sync::{mpsc, watch};

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
