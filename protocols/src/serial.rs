//! Serial ports: open a controller's port (USB-serial or a pty) as an async byte stream, and
//! the settings every serial kind shares (`port`, `baud`): their default, their check and the
//! warning for a port that is not there yet. GRBL, sewing, Modbus RTU and SLCAN CANopen all
//! take them from here.

use crate::link::LinkError;
use crate::untrusted::Guarded;
use tokio_serial::{SerialPortBuilderExt, SerialStream};

/// 115200 baud, GRBL 1.1's default (and most USB-serial controllers').
pub fn default_baud() -> u32 {
    115_200
}

/// Warns of a serial port that is not there (yet): its jobs fail until it is.
pub fn warn_missing_port(machine: &str, port: &str) {
    if !std::path::Path::new(port).exists() {
        tracing::warn!(
            "machine `{machine}`: the port {port} does not exist (yet); its jobs fail until it does"
        );
    }
}

/// Checks a serial port setting and its speed.
pub fn check_port(port: &str, baud: u32) -> Result<(), String> {
    if port.trim().is_empty() {
        return Err("port must not be empty".into());
    }
    if baud == 0 {
        return Err("baud must be above 0".into());
    }
    Ok(())
}

/// Opens `port` at `baud`, 8N1, no flow control; the error names the port, and says
/// `PortBusy` when another program (or a link closed a moment ago) holds it. Reads pass the
/// flood guard of `crate::untrusted`: a device that floods the line is cut off.
pub fn open(port: &str, baud: u32) -> Result<Guarded<SerialStream>, LinkError> {
    tokio_serial::new(port, baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .parity(tokio_serial::Parity::None)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None)
        .open_native_async()
        .map(Guarded::new)
        .map_err(|e| open_error(port, std::io::Error::from(e)))
}

/// The error of a failed open. serialport takes an exclusive lock (TIOCEXCL) and reports a
/// held one as "Resource busy" or as a text naming the lock, not always as an error kind.
pub fn open_error(port: &str, source: std::io::Error) -> LinkError {
    let text = source.to_string().to_ascii_lowercase();
    if source.kind() == std::io::ErrorKind::ResourceBusy
        || text.contains("lock")
        || text.contains("busy")
    {
        LinkError::PortBusy {
            port: port.to_string(),
        }
    } else {
        LinkError::Open {
            port: port.to_string(),
            source,
        }
    }
}
