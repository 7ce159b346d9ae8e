//! Network management and the small broadcast services: NMT commands, heartbeat (node
//! states), SYNC, and EMCY (a drive's error code and what it means in CiA 301 / CiA 402).

use super::frame::CanFrame;
use std::fmt;

/// COB-ID of NMT commands.
pub const NMT_COB: u16 = 0x000;
/// COB-ID of SYNC.
pub const SYNC_COB: u16 = 0x080;

/// An NMT command from the master.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NmtCommand {
    Start,
    Stop,
    PreOperational,
    ResetNode,
    ResetCommunication,
}

impl NmtCommand {
    pub fn code(self) -> u8 {
        match self {
            NmtCommand::Start => 0x01,
            NmtCommand::Stop => 0x02,
            NmtCommand::PreOperational => 0x80,
            NmtCommand::ResetNode => 0x81,
            NmtCommand::ResetCommunication => 0x82,
        }
    }
    pub fn from_code(c: u8) -> Option<NmtCommand> {
        Some(match c {
            0x01 => NmtCommand::Start,
            0x02 => NmtCommand::Stop,
            0x80 => NmtCommand::PreOperational,
            0x81 => NmtCommand::ResetNode,
            0x82 => NmtCommand::ResetCommunication,
            _ => return None,
        })
    }
    /// The command for node `node` (0: every node).
    pub fn frame(self, node: u8) -> CanFrame {
        CanFrame::cob(NMT_COB, &[self.code(), node])
    }
    /// The command and its node (0: all) of an NMT frame.
    pub fn parse(f: &CanFrame) -> Option<(NmtCommand, u8)> {
        match (f.cob_id()?, f.data()) {
            (NMT_COB, [c, node]) => Some((NmtCommand::from_code(*c)?, *node)),
            _ => None,
        }
    }
}

/// A node's NMT state as its heartbeat reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NmtState {
    BootUp,
    Stopped,
    Operational,
    PreOperational,
}

impl NmtState {
    pub fn code(self) -> u8 {
        match self {
            NmtState::BootUp => 0x00,
            NmtState::Stopped => 0x04,
            NmtState::Operational => 0x05,
            NmtState::PreOperational => 0x7F,
        }
    }
    pub fn from_code(c: u8) -> Option<NmtState> {
        Some(match c & 0x7F {
            0x00 => NmtState::BootUp,
            0x04 => NmtState::Stopped,
            0x05 => NmtState::Operational,
            0x7F => NmtState::PreOperational,
            _ => return None,
        })
    }
}

impl fmt::Display for NmtState {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(match self {
            NmtState::BootUp => "boot-up",
            NmtState::Stopped => "stopped",
            NmtState::Operational => "operational",
            NmtState::PreOperational => "pre-operational",
        })
    }
}

/// COB-ID of node `n`'s heartbeat.
pub fn heartbeat_cob(node: u8) -> u16 {
    0x700 + node as u16
}

/// Node `node`'s heartbeat (or boot-up message) in state `state`.
pub fn heartbeat_frame(node: u8, state: NmtState) -> CanFrame {
    CanFrame::cob(heartbeat_cob(node), &[state.code()])
}

/// The node and state of a heartbeat frame.
pub fn parse_heartbeat(f: &CanFrame) -> Option<(u8, NmtState)> {
    let cob = f.cob_id()?;
    match (cob, f.data()) {
        (0x701..=0x77F, [s]) => Some(((cob - 0x700) as u8, NmtState::from_code(*s)?)),
        _ => None,
    }
}

/// A SYNC (no counter).
pub fn sync_frame() -> CanFrame {
    CanFrame::cob(SYNC_COB, &[])
}

/// Whether `f` is a SYNC (with or without the 1-byte counter).
pub fn is_sync(f: &CanFrame) -> bool {
    f.cob_id() == Some(SYNC_COB) && f.len() <= 1
}

/// An emergency message from a node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Emcy {
    pub node: u8,
    /// The error code (CiA 301 classes, CiA 402 drive codes; 0x0000: error reset).
    pub code: u16,
    /// The node's error register (0x1001).
    pub register: u8,
    /// Manufacturer-specific bytes.
    pub vendor: [u8; 5],
}

impl Emcy {
    pub fn cob(node: u8) -> u16 {
        0x080 + node as u16
    }
    pub fn frame(&self) -> CanFrame {
        let c = self.code.to_le_bytes();
        let v = self.vendor;
        CanFrame::cob(
            Emcy::cob(self.node),
            &[c[0], c[1], self.register, v[0], v[1], v[2], v[3], v[4]],
        )
    }
    pub fn parse(f: &CanFrame) -> Option<Emcy> {
        let cob = f.cob_id()?;
        if !(0x081..=0x0FF).contains(&cob) || f.len() != 8 {
            return None;
        }
        let d = f.data();
        Some(Emcy {
            node: (cob - 0x080) as u8,
            code: u16::from_le_bytes([d[0], d[1]]),
            register: d[2],
            vendor: [d[3], d[4], d[5], d[6], d[7]],
        })
    }
    /// What the code means.
    pub fn meaning(&self) -> &'static str {
        emcy_meaning(self.code)
    }
}

impl fmt::Display for Emcy {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(f, "EMCY 0x{:04X} ({})", self.code, self.meaning())
    }
}

/// The meaning of an EMCY error code: CiA 402's drive codes where it names one, else the
/// CiA 301 class.
pub fn emcy_meaning(code: u16) -> &'static str {
    match code {
        0x0000 => "error reset or no error",
        0x1000 => "generic error",
        0x2310 => "continuous over-current",
        0x2320 => "short circuit or earth leakage",
        0x3210 => "DC link over-voltage",
        0x3220 => "DC link under-voltage",
        0x4210 => "excess temperature of the device",
        0x4310 => "excess temperature of the drive",
        0x5441 => "safe torque off (enable input inactive)",
        0x7121 => "motor blocked",
        0x7305 => "incremental sensor 1 fault",
        0x8110 => "CAN overrun (objects lost)",
        0x8120 => "CAN in error passive mode",
        0x8130 => "life guard or heartbeat error",
        0x8140 => "recovered from bus off",
        0x8210 => "PDO not processed due to length error",
        0x8220 => "PDO length exceeded",
        0x8250 => "RPDO timeout",
        0x8400 => "velocity speed controller",
        0x8500 => "position controller",
        0x8611 => "following error",
        0x8612 => "reference limit",
        0x8700 => "sync controller (SYNC missing or late)",
        0xFF00..=0xFFFF => "device-specific error",
        c => match c & 0xF000 {
            0x2000 => "current",
            0x3000 => "voltage",
            0x4000 => "temperature",
            0x5000 => "device hardware",
            0x6000 => "device software",
            0x7000 => "additional modules",
            0x8000 => "monitoring",
            0x9000 => "external error",
            0xF000 => "additional functions",
            _ => "generic error",
        },
    }
}

/// What a standard COB-ID carries, by the CiA 301 predefined connection set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cob {
    Nmt,
    Sync,
    Emcy(u8),
    /// Transmit PDO `n` (1–4) of a node.
    Tpdo(u8, u8),
    /// Receive PDO `n` (1–4) of a node.
    Rpdo(u8, u8),
    /// SDO response from a node.
    SdoResponse(u8),
    /// SDO request to a node.
    SdoRequest(u8),
    Heartbeat(u8),
    Other(u16),
}

/// Classifies a COB-ID.
pub fn classify(cob: u16) -> Cob {
    let node = (cob & 0x7F) as u8;
    match cob {
        0x000 => Cob::Nmt,
        0x080 => Cob::Sync,
        0x081..=0x0FF => Cob::Emcy(node),
        0x181..=0x1FF => Cob::Tpdo(1, node),
        0x201..=0x27F => Cob::Rpdo(1, node),
        0x281..=0x2FF => Cob::Tpdo(2, node),
        0x301..=0x37F => Cob::Rpdo(2, node),
        0x381..=0x3FF => Cob::Tpdo(3, node),
        0x401..=0x47F => Cob::Rpdo(3, node),
        0x481..=0x4FF => Cob::Tpdo(4, node),
        0x501..=0x57F => Cob::Rpdo(4, node),
        0x581..=0x5FF => Cob::SdoResponse(node),
        0x601..=0x67F => Cob::SdoRequest(node),
        0x701..=0x77F => Cob::Heartbeat(node),
        c => Cob::Other(c),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nmt_heartbeat_and_emcy_frames_read_back() {
        let f = NmtCommand::ResetCommunication.frame(3);
        assert_eq!(f.to_string(), "000#8203");
        assert_eq!(
            NmtCommand::parse(&f),
            Some((NmtCommand::ResetCommunication, 3))
        );
        let h = heartbeat_frame(2, NmtState::PreOperational);
        assert_eq!(h.to_string(), "702#7F");
        assert_eq!(parse_heartbeat(&h), Some((2, NmtState::PreOperational)));
        let e = Emcy {
            node: 2,
            code: 0x8611,
            register: 0x21,
            vendor: [0; 5],
        };
        assert_eq!(e.frame().to_string(), "082#1186210000000000");
        assert_eq!(Emcy::parse(&e.frame()), Some(e));
        assert_eq!(e.to_string(), "EMCY 0x8611 (following error)");
        assert_eq!(emcy_meaning(0x2399), "current");
        assert_eq!(classify(0x182), Cob::Tpdo(1, 2));
        assert!(is_sync(&sync_frame()));
    }
}
