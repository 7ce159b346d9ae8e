//! The `modbus-tcp` and `modbus-rtu` machine kinds: a PLC or servo drive taking motion blocks
//! into a ring buffer of holding registers (docs/modbus.md). Both share the ring's settings.

use super::link::{ModbusLink, ModbusSettings, Parity, Transport};
use super::map::{MotionBlock, WordOrder};
use super::post::{post_blocks, ModbusPost};
use crate::kind::{started, Joined, MachineKind, OpenLink};
use crate::link::{Link, LinkError};
use crate::post::{PostError, PostFor};
use crate::program::Units;
use crate::serial::{check_port, default_baud, warn_missing_port};
use futures::future::BoxFuture;
use offset_core::Toolpath;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::Duration;

/// The keys every Modbus machine takes, whatever carries its requests.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RingSettings {
    /// Unit id (TCP: 1 unless a gateway routes by it; RTU: the slave address, 1 to 247).
    #[serde(default = "default_unit")]
    pub unit: u8,
    /// Address of header register 0.
    #[serde(default)]
    pub base_address: u16,
    /// "high-first" (default) or "low-first" for 32-bit values.
    #[serde(default)]
    pub word_order: WordOrder,
    /// The most registers per write (1 to 123; many drives take 10 or 12).
    #[serde(default = "default_max_write")]
    pub max_write_registers: u16,
    /// Commit and read the header in one FC23 request when the device answers it.
    #[serde(default = "default_read_write")]
    pub read_write: bool,
    /// How long one request may wait for its reply, ms.
    #[serde(default = "default_timeout")]
    pub timeout_ms: u64,
    /// How often the device is polled while the ring is full, ms.
    #[serde(default = "default_poll")]
    pub poll_ms: u64,
    /// Failed attempts in a row (with backoff) before the job fails.
    #[serde(default = "default_retries")]
    pub retries: u32,
    /// How long the device may answer nothing at all mid-job before the job pauses with its
    /// last acknowledged block and the link reconnects, s (2 to 3600); without it, after
    /// `retries` unanswered attempts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub silent_timeout_s: Option<f64>,
}

impl Default for RingSettings {
    fn default() -> Self {
        RingSettings {
            unit: default_unit(),
            base_address: 0,
            word_order: WordOrder::default(),
            max_write_registers: default_max_write(),
            read_write: default_read_write(),
            timeout_ms: default_timeout(),
            poll_ms: default_poll(),
            retries: default_retries(),
            silent_timeout_s: None,
        }
    }
}

/// `link = "modbus-tcp"`'s own keys.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TcpAddress {
    /// The device's host name or address.
    pub host: String,
    #[serde(default = "default_tcp_port")]
    pub port: u16,
}

/// `link = "modbus-rtu"`'s own keys.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RtuLine {
    /// The serial port, e.g. /dev/ttyUSB0.
    pub port: String,
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// "none" (default), "even" or "odd".
    #[serde(default)]
    pub parity: Parity,
    /// After a timeout, how long the line must be silent before the next request, ms.
    #[serde(default = "default_timeout")]
    pub quiet_ms: u64,
}

fn default_unit() -> u8 {
    1
}
fn default_max_write() -> u16 {
    123
}
fn default_read_write() -> bool {
    true
}
fn default_timeout() -> u64 {
    500
}
fn default_poll() -> u64 {
    20
}
fn default_retries() -> u32 {
    8
}
fn default_tcp_port() -> u16 {
    502
}

impl RingSettings {
    /// The link's settings over `transport`.
    pub fn settings(&self, transport: Transport) -> ModbusSettings {
        let mut s = match &transport {
            Transport::Tcp { host, port } => ModbusSettings::tcp(host.clone(), *port),
            Transport::Rtu { path, baud, .. } => ModbusSettings::rtu(path.clone(), *baud),
        };
        s.transport = transport;
        s.unit_id = self.unit;
        s.base_address = self.base_address;
        s.word_order = self.word_order;
        s.max_write_registers = self.max_write_registers;
        s.read_write = self.read_write;
        s.timeout = Duration::from_millis(self.timeout_ms);
        s.poll_interval = Duration::from_millis(self.poll_ms);
        s.max_retries = self.retries;
        s.silent_timeout = self.silent_timeout_s.map(Duration::from_secs_f64);
        s
    }

    /// Checks the keys that are the ring's own (the link's settings check the rest).
    pub fn check(&self) -> Result<(), String> {
        match self.silent_timeout_s {
            Some(t) => crate::grbl::kind::check_silent_timeout(t),
            None => Ok(()),
        }
    }
}

/// The post every Modbus machine runs.
pub fn modbus_posts() -> Vec<PostFor<MotionBlock>> {
    vec![Arc::new(ModbusPost)]
}

/// A G-code file for a Modbus machine: its moves as motion blocks.
pub fn gcode_file_blocks(moves: &Toolpath) -> Option<Result<Vec<MotionBlock>, PostError>> {
    Some(post_blocks(moves).map_err(|e| PostError::new("modbus", e)))
}

/// Why a Modbus machine cannot run move `m` of a G-code file: a program stop (`M0`, `M1`),
/// for which its ring has no block (docs/modbus.md: the device holds by itself only at a
/// tool change), so it would not stop there.
pub fn gcode_file_refuses(m: &offset_core::toolpath::Move) -> Option<String> {
    matches!(m, offset_core::toolpath::Move::Stop).then(|| {
        "a program stop (M0, M1) has no block in a Modbus ring (docs/modbus.md), so the device would not stop there; take the stop out or run the file on a CANopen machine".to_string()
    })
}

/// Opens a Modbus link with `settings`; it connects on its first request.
pub fn open_ring(settings: ModbusSettings) -> OpenLink<MotionBlock> {
    Box::pin(async move {
        let link = ModbusLink::new(settings).map_err(LinkError::from)?;
        Ok(Box::new(link) as Box<dyn Link<MotionBlock>>)
    })
}

/// What carries a Modbus machine's requests (TCP or an RTU line), with its own keys.
pub trait RingTransport:
    Serialize + serde::de::DeserializeOwned + Clone + std::fmt::Debug + Send + Sync + 'static
{
    /// The `link = "…"` of machines on this transport.
    const LINK: &'static str;
    const ABOUT: &'static str;
    /// The link's settings with `ring`'s.
    fn settings(&self, ring: &RingSettings) -> ModbusSettings;
    /// Checks the transport's own keys.
    fn check(&self) -> Result<(), String>;
    /// Warns at start-up of what is missing (a serial port).
    fn warn_missing(&self, _machine: &str) {}
}

impl RingTransport for TcpAddress {
    const LINK: &'static str = "modbus-tcp";
    const ABOUT: &'static str =
        "a PLC or drive taking motion blocks into a ring buffer over Modbus TCP";
    fn settings(&self, ring: &RingSettings) -> ModbusSettings {
        ring.settings(Transport::Tcp {
            host: self.host.clone(),
            port: self.port,
        })
    }
    fn check(&self) -> Result<(), String> {
        if self.host.trim().is_empty() {
            return Err("host must not be empty".into());
        }
        Ok(())
    }
}

impl RingTransport for RtuLine {
    const LINK: &'static str = "modbus-rtu";
    const ABOUT: &'static str =
        "a PLC or drive taking motion blocks into a ring buffer over Modbus RTU on a serial line";
    fn settings(&self, ring: &RingSettings) -> ModbusSettings {
        let mut m = ring.settings(Transport::Rtu {
            path: self.port.clone(),
            baud: self.baud,
            parity: self.parity,
        });
        m.rtu_quiet = Duration::from_millis(self.quiet_ms);
        m
    }
    fn check(&self) -> Result<(), String> {
        check_port(&self.port, self.baud)
    }
    fn warn_missing(&self, machine: &str) {
        warn_missing_port(machine, &self.port);
    }
}

/// A Modbus machine kind on transport `T`.
pub struct ModbusKind<T>(std::marker::PhantomData<T>);

impl<T> Default for ModbusKind<T> {
    fn default() -> Self {
        ModbusKind(std::marker::PhantomData)
    }
}

/// `link = "modbus-tcp"`.
pub type ModbusTcpKind = ModbusKind<TcpAddress>;
/// `link = "modbus-rtu"`.
pub type ModbusRtuKind = ModbusKind<RtuLine>;

impl<T: RingTransport> MachineKind for ModbusKind<T> {
    type Settings = Joined<T, RingSettings>;
    type Unit = MotionBlock;
    type Device = ();

    fn link(&self) -> &'static str {
        T::LINK
    }
    fn about(&self) -> &'static str {
        T::ABOUT
    }
    fn keys(&self) -> Vec<&'static str> {
        Joined::<T, RingSettings>::keys()
    }
    fn posts(&self) -> Vec<PostFor<MotionBlock>> {
        modbus_posts()
    }
    fn estimate(&self, _s: &Self::Settings, blocks: Units<'_, MotionBlock>) -> Option<f64> {
        Some(crate::estimate::blocks_seconds(
            &blocks.to_vec().ok()?,
            crate::estimate::RAPID,
        ))
    }
    fn check(&self, s: &Self::Settings) -> Result<(), String> {
        s.own.check()?;
        s.common.check()?;
        s.own
            .settings(&s.common)
            .validate()
            .map_err(|e| e.to_string())
    }
    fn gcode_units(
        &self,
        _lines: &[String],
        moves: &Toolpath,
    ) -> Option<Result<Vec<MotionBlock>, PostError>> {
        gcode_file_blocks(moves)
    }
    fn gcode_runs_as_moves(&self) -> bool {
        true
    }
    fn gcode_move_refused(&self, m: &offset_core::toolpath::Move) -> Option<String> {
        gcode_file_refuses(m)
    }
    fn start(&self, machine: &str, s: &Self::Settings) -> BoxFuture<'static, std::io::Result<()>> {
        s.own.warn_missing(machine);
        started(())
    }
    fn open(&self, _machine: &str, s: &Self::Settings, _device: &()) -> OpenLink<MotionBlock> {
        open_ring(s.own.settings(&s.common))
    }
}
