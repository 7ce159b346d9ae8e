//! The adapter a CAN bus is reached through, as a machine table names it:
//! `socketcan:IFACE` (a Linux CAN interface) or `slcan:PORT[@BITRATE]` (a Lawicel USB-CAN
//! adapter on a serial port), and opening it as a [`CanBus`].

use super::bus::CanBus;
use std::fmt;
use std::str::FromStr;

/// Where the bus is: `socketcan:IFACE` or `slcan:PORT[@BITRATE]`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BusSpec {
    /// A Linux CAN interface (can0, vcan0), its bit rate set with `ip link`.
    SocketCan { interface: String },
    /// A Lawicel (SLCAN) USB-CAN adapter on a serial port, opened at `bitrate` bit/s.
    Slcan { port: String, bitrate: u32 },
}

/// 500 kbit/s, where `slcan:PORT` names none.
pub const DEFAULT_BITRATE: u32 = 500_000;

impl FromStr for BusSpec {
    type Err = String;
    fn from_str(s: &str) -> Result<BusSpec, String> {
        if let Some(iface) = s.strip_prefix("socketcan:") {
            if iface.is_empty() || iface.len() > 15 || iface.contains(['/', ' ']) {
                return Err(format!(
                    "bus \"{s}\": \"{iface}\" is not a network interface name (e.g. can0)"
                ));
            }
            return Ok(BusSpec::SocketCan {
                interface: iface.to_string(),
            });
        }
        if let Some(rest) = s.strip_prefix("slcan:") {
            let (port, bitrate) = match rest.rsplit_once('@') {
                Some((p, b)) => {
                    let rate: u32 = b
                        .parse()
                        .map_err(|_| format!("bus \"{s}\": bit rate \"{b}\" is not a number"))?;
                    (p, rate)
                }
                None => (rest, DEFAULT_BITRATE),
            };
            if port.is_empty() {
                return Err(format!("bus \"{s}\" names no serial port"));
            }
            if super::slcan::bitrate_code(bitrate).is_none() {
                return Err(format!(
                    "bus \"{s}\": an SLCAN adapter runs at 10000, 20000, 50000, 100000, 125000, \
                     250000, 500000, 800000 or 1000000 bit/s, not {bitrate}"
                ));
            }
            return Ok(BusSpec::Slcan {
                port: port.to_string(),
                bitrate,
            });
        }
        Err(format!(
            "bus \"{s}\" is neither \"socketcan:IFACE\" (e.g. socketcan:can0) nor \
             \"slcan:PORT[@BITRATE]\" (e.g. slcan:/dev/ttyACM0@500000)"
        ))
    }
}

impl fmt::Display for BusSpec {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        match self {
            BusSpec::SocketCan { interface } => write!(f, "socketcan:{interface}"),
            BusSpec::Slcan { port, bitrate } => write!(f, "slcan:{port}@{bitrate}"),
        }
    }
}

/// Opens the bus `spec` names.
pub async fn open(spec: &BusSpec) -> Result<Box<dyn CanBus>, crate::link::LinkError> {
    match spec {
        BusSpec::SocketCan { interface } => {
            let bus = super::socketcan::SocketCanBus::open(interface).map_err(|source| {
                crate::link::LinkError::Open {
                    port: spec.to_string(),
                    source,
                }
            })?;
            Ok(Box::new(bus))
        }
        BusSpec::Slcan { port, bitrate } => Ok(Box::new(open_slcan(port, *bitrate).await?)),
    }
}

/// Opens an SLCAN adapter on serial port `port` at CAN bit rate `bitrate`, with a clock
/// writer on the same port.
pub async fn open_slcan(
    port: &str,
    bitrate: u32,
) -> Result<
    super::slcan::SlcanBus<crate::untrusted::Guarded<tokio_serial::SerialStream>>,
    crate::link::LinkError,
> {
    use std::os::fd::{AsRawFd, BorrowedFd};
    let stream = crate::serial::open(port, 115_200)?;
    // SAFETY: the fd is the open serial port's, borrowed only to duplicate it.
    let writer = unsafe { BorrowedFd::borrow_raw(stream.get_ref().as_raw_fd()) }
        .try_clone_to_owned()
        .map_err(crate::link::LinkError::Io)?;
    let bus = super::slcan::SlcanBus::open(stream, port, bitrate)
        .await
        .map_err(|e| crate::link::LinkError::Protocol(e.to_string()))?;
    Ok(bus.with_clock_writer(std::fs::File::from(writer)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bus_settings_parse_and_name_what_is_wrong() {
        assert_eq!(
            "socketcan:can0".parse::<BusSpec>().unwrap(),
            BusSpec::SocketCan {
                interface: "can0".into()
            }
        );
        assert_eq!(
            "slcan:/dev/ttyACM0@1000000".parse::<BusSpec>().unwrap(),
            BusSpec::Slcan {
                port: "/dev/ttyACM0".into(),
                bitrate: 1_000_000
            }
        );
        assert_eq!(
            "slcan:/dev/ttyACM0".parse::<BusSpec>().unwrap().to_string(),
            "slcan:/dev/ttyACM0@500000"
        );
        let e = "slcan:/dev/ttyACM0@300000".parse::<BusSpec>().unwrap_err();
        assert!(e.contains("300000"), "{e}");
        assert!("can0".parse::<BusSpec>().is_err());
        assert!("socketcan:".parse::<BusSpec>().is_err());
    }
}
