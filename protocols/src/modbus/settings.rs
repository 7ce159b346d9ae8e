//! The settings of a link to one Modbus device (how it is reached, its register map's
//! options, timeouts) and why talking to it failed: shared by the layers below the link
//! (`transport`, `session`, `ring`) and by `link`, which puts them together.

use super::map::{exception_name, fault_name, WordOrder, MAX_WRITE_REGISTERS};
use super::transport::{Framing, Parity};
use crate::link::LinkError;
use serde::{Deserialize, Serialize};
use std::time::Duration;

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
    /// With it, the stream gives up once the device has answered nothing for this long
    /// (however many attempts that took), instead of after `max_retries`.
    pub silent_timeout: Option<Duration>,
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
            silent_timeout: None,
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
    pub(crate) fn target(&self) -> String {
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
