//! Serial ports: open a controller's port (USB-serial or a pty) as an async byte stream.

use crate::link::LinkError;
use tokio_serial::{SerialPortBuilderExt, SerialStream};

/// Opens `port` at `baud`, 8N1, no flow control; the error names the port.
pub fn open(port: &str, baud: u32) -> Result<SerialStream, LinkError> {
    tokio_serial::new(port, baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .parity(tokio_serial::Parity::None)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None)
        .open_native_async()
        .map_err(|e| LinkError::Open {
            port: port.to_string(),
            source: std::io::Error::from(e),
        })
}
