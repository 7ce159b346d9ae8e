//! The motion-block register map: header registers, ring slots, and the block layout.
//!
//! All addresses are 0-based holding-register offsets from the device's base address (the
//! Modbus PDU address, not the "40001" catalogue number). See docs/modbus.md.

use serde::{Deserialize, Serialize};
use std::fmt;

/// The map version this crate speaks (header register 0).
pub const MAP_VERSION: u16 = 1;
/// Registers per motion block in the ring.
pub const BLOCK_REGISTERS: u16 = 16;
/// Registers before the ring starts (the header, with reserved room).
pub const HEADER_REGISTERS: u16 = 32;
/// Registers the link reads each poll (version .. actual Z).
pub const STATUS_REGISTERS: u16 = 16;
/// The most registers one FC16 write may carry (Modbus application protocol, 6.12).
pub const MAX_WRITE_REGISTERS: u16 = 123;
/// The most registers one FC3 read may return.
pub const MAX_READ_REGISTERS: u16 = 125;

/// Header register offsets (from the base address).
pub mod reg {
    /// Map version (read-only), 1 for this layout.
    pub const VERSION: u16 = 0;
    /// Ring capacity in blocks (read-only).
    pub const CAPACITY: u16 = 1;
    /// Registers per block (read-only), 16.
    pub const BLOCK_SIZE: u16 = 2;
    /// State word (read-only): 0 idle, 1 running, 2 hold, 3 fault.
    pub const STATE: u16 = 3;
    /// Fault code (read-only), 0 when there is none.
    pub const FAULT: u16 = 4;
    /// Command register (write): see `Command`. Reads back 0 once the device acted on it.
    pub const COMMAND: u16 = 5;
    /// Host's write sequence, 32-bit (write both registers in one request).
    pub const WRITE_SEQ: u16 = 6;
    /// Device's consumed sequence, 32-bit (read-only): the last block it finished.
    pub const CONSUMED_SEQ: u16 = 8;
    /// Actual position X, Y, Z: signed 32-bit µm each (read-only).
    pub const POS_X: u16 = 10;
    pub const POS_Y: u16 = 12;
    pub const POS_Z: u16 = 14;
    /// First register of ring slot 0.
    pub const RING: u16 = super::HEADER_REGISTERS;
}

/// Register offsets inside one block.
pub mod block_reg {
    /// The block's sequence number, 32-bit (the unit index + 1).
    pub const SEQ: u16 = 0;
    /// Move type (`BlockKind`).
    pub const KIND: u16 = 2;
    /// Reserved, written 0.
    pub const RESERVED: u16 = 3;
    /// Target X, Y, Z: signed 32-bit µm.
    pub const X: u16 = 4;
    pub const Y: u16 = 6;
    pub const Z: u16 = 8;
    /// Feed, unsigned 32-bit, mm/min × 1000 (0: the machine's rapid rate); a dwell's time in ms.
    pub const FEED: u16 = 10;
    /// Arc centre relative to the block's start point, signed 32-bit µm.
    pub const I: u16 = 12;
    pub const J: u16 = 14;
}

/// Which half of a 32-bit value goes in the lower register address. Devices differ.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WordOrder {
    /// High word at the lower address (Modicon convention, the default).
    #[default]
    HighFirst,
    /// Low word at the lower address ("word swapped").
    LowFirst,
}

impl WordOrder {
    /// Splits `v` into the two registers in address order.
    pub fn split(self, v: u32) -> [u16; 2] {
        let (hi, lo) = ((v >> 16) as u16, v as u16);
        match self {
            WordOrder::HighFirst => [hi, lo],
            WordOrder::LowFirst => [lo, hi],
        }
    }
    /// Joins two registers (in address order) into a 32-bit value.
    pub fn join(self, r: [u16; 2]) -> u32 {
        let (hi, lo) = match self {
            WordOrder::HighFirst => (r[0], r[1]),
            WordOrder::LowFirst => (r[1], r[0]),
        };
        ((hi as u32) << 16) | lo as u32
    }
    /// Reads the 32-bit value at `regs[at..at + 2]`; registers a short reply lacks read as 0
    /// (what a device sends is never trusted to be as long as asked).
    pub fn get(self, regs: &[u16], at: u16) -> u32 {
        let at = at as usize;
        let r = |i: usize| regs.get(i).copied().unwrap_or(0);
        self.join([r(at), r(at + 1)])
    }
    /// Writes `v` at `regs[at..at + 2]`.
    pub fn put(self, regs: &mut [u16], at: u16, v: u32) {
        let at = at as usize;
        regs[at..at + 2].copy_from_slice(&self.split(v));
    }
}

impl std::str::FromStr for WordOrder {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "high-first" => Ok(WordOrder::HighFirst),
            "low-first" => Ok(WordOrder::LowFirst),
            _ => Err(format!(
                "word order {s:?} is neither \"high-first\" nor \"low-first\""
            )),
        }
    }
}

/// The move type register of a block.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[repr(u16)]
pub enum BlockKind {
    Rapid = 1,
    Linear = 2,
    ArcCw = 3,
    ArcCcw = 4,
    Dwell = 5,
    /// The program's last block: the device goes idle once it is executed.
    End = 6,
    /// A tool change: the device holds at it (before finishing it) until the operator has
    /// loaded tool `feed` and resumes; no motion (its target repeats the last target).
    ToolChange = 7,
}

impl BlockKind {
    pub fn from_register(v: u16) -> Option<BlockKind> {
        Some(match v {
            1 => BlockKind::Rapid,
            2 => BlockKind::Linear,
            3 => BlockKind::ArcCw,
            4 => BlockKind::ArcCcw,
            5 => BlockKind::Dwell,
            6 => BlockKind::End,
            7 => BlockKind::ToolChange,
            _ => return None,
        })
    }
    pub fn name(self) -> &'static str {
        match self {
            BlockKind::Rapid => "rapid",
            BlockKind::Linear => "linear",
            BlockKind::ArcCw => "arc cw",
            BlockKind::ArcCcw => "arc ccw",
            BlockKind::Dwell => "dwell",
            BlockKind::End => "end",
            BlockKind::ToolChange => "tool",
        }
    }
}

/// One motion block as the device stores it: integer micrometres, feed in mm/min × 1000.
/// Its sequence number is not part of it: block `i` of a program travels as sequence `i + 1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct MotionBlock {
    pub kind: BlockKind,
    /// Target position, µm (absolute, work frame). Dwell and end blocks repeat the last target.
    pub target: [i32; 3],
    /// mm/min × 1000 for moves (0 for rapids: the machine's rapid rate); ms for a dwell;
    /// the tool's number for a tool change.
    pub feed: u32,
    /// Arc centre relative to the start point, µm (I, J); zero for other kinds.
    pub center: [i32; 2],
}

impl MotionBlock {
    /// The block's registers with sequence number `seq`, in address order.
    pub fn encode(&self, seq: u32, order: WordOrder) -> [u16; BLOCK_REGISTERS as usize] {
        let mut r = [0u16; BLOCK_REGISTERS as usize];
        order.put(&mut r, block_reg::SEQ, seq);
        r[block_reg::KIND as usize] = self.kind as u16;
        order.put(&mut r, block_reg::X, self.target[0] as u32);
        order.put(&mut r, block_reg::Y, self.target[1] as u32);
        order.put(&mut r, block_reg::Z, self.target[2] as u32);
        order.put(&mut r, block_reg::FEED, self.feed);
        order.put(&mut r, block_reg::I, self.center[0] as u32);
        order.put(&mut r, block_reg::J, self.center[1] as u32);
        r
    }

    /// Reads a block back from its registers: (sequence, block), or the unknown kind value.
    pub fn decode(r: &[u16], order: WordOrder) -> Result<(u32, MotionBlock), u16> {
        let kind_reg = r.get(block_reg::KIND as usize).copied().unwrap_or(0);
        let kind = BlockKind::from_register(kind_reg).ok_or(kind_reg)?;
        let i = |at| order.get(r, at) as i32;
        Ok((
            order.get(r, block_reg::SEQ),
            MotionBlock {
                kind,
                target: [i(block_reg::X), i(block_reg::Y), i(block_reg::Z)],
                feed: order.get(r, block_reg::FEED),
                center: [i(block_reg::I), i(block_reg::J)],
            },
        ))
    }

    /// Target in mm.
    pub fn target_mm(&self) -> [f64; 3] {
        self.target.map(|v| v as f64 / 1000.0)
    }
}

impl fmt::Display for MotionBlock {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [x, y, z] = self.target_mm();
        match self.kind {
            BlockKind::Dwell => write!(f, "dwell {} ms", self.feed),
            BlockKind::End => write!(f, "end"),
            BlockKind::ToolChange => write!(f, "tool T{}", self.feed),
            BlockKind::Rapid => write!(f, "rapid X{x:.3} Y{y:.3} Z{z:.3}"),
            BlockKind::Linear => write!(
                f,
                "linear X{x:.3} Y{y:.3} Z{z:.3} F{:.3}",
                self.feed as f64 / 1000.0
            ),
            BlockKind::ArcCw | BlockKind::ArcCcw => write!(
                f,
                "{} X{x:.3} Y{y:.3} Z{z:.3} I{:.3} J{:.3} F{:.3}",
                self.kind.name(),
                self.center[0] as f64 / 1000.0,
                self.center[1] as f64 / 1000.0,
                self.feed as f64 / 1000.0
            ),
        }
    }
}

/// The device's state word.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[repr(u16)]
pub enum ModbusState {
    Idle = 0,
    Running = 1,
    Hold = 2,
    Fault = 3,
}

impl ModbusState {
    pub fn from_register(v: u16) -> Option<ModbusState> {
        Some(match v {
            0 => ModbusState::Idle,
            1 => ModbusState::Running,
            2 => ModbusState::Hold,
            3 => ModbusState::Fault,
            _ => return None,
        })
    }
    pub fn name(self) -> &'static str {
        match self {
            ModbusState::Idle => "Idle",
            ModbusState::Running => "Run",
            ModbusState::Hold => "Hold",
            ModbusState::Fault => "Fault",
        }
    }
}

/// Values of the command register.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[repr(u16)]
pub enum Command {
    /// Idle → running: execute committed blocks in sequence.
    Start = 1,
    /// Running → hold: decelerate and wait, keeping the current block.
    Hold = 2,
    /// Hold → running.
    Resume = 3,
    /// Any → idle: stop moving and drop unexecuted blocks (write sequence := consumed).
    Stop = 4,
    /// Fault → idle, fault code 0.
    ClearFault = 5,
    /// Idle only: consumed sequence := write sequence (start a job at the host's sequence).
    Sync = 6,
}

impl Command {
    pub fn from_register(v: u16) -> Option<Command> {
        Some(match v {
            1 => Command::Start,
            2 => Command::Hold,
            3 => Command::Resume,
            4 => Command::Stop,
            5 => Command::ClearFault,
            6 => Command::Sync,
            _ => return None,
        })
    }
}

/// Fault codes of the map (devices add their own from 0x0100 up).
pub mod fault {
    /// The block in the slot did not carry the expected sequence number.
    pub const SEQUENCE: u16 = 1;
    /// The block's move type register held an unknown value.
    pub const BAD_BLOCK: u16 = 2;
    /// The block's target is outside the machine's travel.
    pub const TRAVEL: u16 = 3;
}

/// A short name for a fault code, for messages.
pub fn fault_name(code: u16) -> &'static str {
    match code {
        fault::SEQUENCE => "block sequence mismatch",
        fault::BAD_BLOCK => "invalid block",
        fault::TRAVEL => "target outside travel",
        0x0100.. => "device-specific fault",
        _ => "unknown fault",
    }
}

/// The standard name of a Modbus exception code.
pub fn exception_name(code: u8) -> &'static str {
    match code {
        0x01 => "Illegal Function",
        0x02 => "Illegal Data Address",
        0x03 => "Illegal Data Value",
        0x04 => "Server Device Failure",
        0x05 => "Acknowledge",
        0x06 => "Server Device Busy",
        0x07 => "Negative Acknowledge",
        0x08 => "Memory Parity Error",
        0x0A => "Gateway Path Unavailable",
        0x0B => "Gateway Target Device Failed to Respond",
        _ => "non-standard exception",
    }
}

/// The header as one status read returns it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Status {
    pub version: u16,
    pub capacity: u16,
    pub block_size: u16,
    /// The raw state word (see `ModbusState::from_register`).
    pub state: u16,
    pub fault: u16,
    pub command: u16,
    pub write_seq: u32,
    pub consumed_seq: u32,
    /// Actual position, µm.
    pub position: [i32; 3],
}

impl Status {
    /// Decodes the first `STATUS_REGISTERS` header registers.
    pub fn decode(r: &[u16], order: WordOrder) -> Status {
        let i = |at| order.get(r, at) as i32;
        let w = |at: u16| r.get(at as usize).copied().unwrap_or(0);
        Status {
            version: w(reg::VERSION),
            capacity: w(reg::CAPACITY),
            block_size: w(reg::BLOCK_SIZE),
            state: w(reg::STATE),
            fault: w(reg::FAULT),
            command: w(reg::COMMAND),
            write_seq: order.get(r, reg::WRITE_SEQ),
            consumed_seq: order.get(r, reg::CONSUMED_SEQ),
            position: [i(reg::POS_X), i(reg::POS_Y), i(reg::POS_Z)],
        }
    }
}

/// Where the map sits on one device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    /// Address of header register 0.
    pub base: u16,
    /// Ring capacity, blocks.
    pub capacity: u16,
}

impl Layout {
    /// Ring slot of block sequence `seq` (sequences start at 1).
    pub fn slot(&self, seq: u32) -> u16 {
        // a capacity of 0 (a device that says so) has no slots: everything maps to slot 0
        ((seq.wrapping_sub(1)) % (self.capacity.max(1) as u32)) as u16
    }
    /// Address of the first register of ring slot `slot` (wrapping past the 16-bit address
    /// space, which the link's checks of the map's size refuse before it matters).
    pub fn slot_address(&self, slot: u16) -> u16 {
        self.base
            .wrapping_add(reg::RING)
            .wrapping_add(slot.wrapping_mul(BLOCK_REGISTERS))
    }
    /// One past the last register of the map.
    pub fn end(&self) -> u32 {
        self.base as u32 + reg::RING as u32 + self.capacity as u32 * BLOCK_REGISTERS as u32
    }
    /// Names the registers `addr .. addr + count` in the map's words, for messages.
    pub fn describe(&self, addr: u16, count: u16) -> String {
        let last = addr as u32 + count.max(1) as u32 - 1;
        let range = if count <= 1 {
            format!("holding register {addr}")
        } else {
            format!("holding registers {addr}..={last}")
        };
        let name_of = |a: u32| -> String {
            let Some(off) = a.checked_sub(self.base as u32) else {
                return "below the map".into();
            };
            if off < reg::RING as u32 {
                return match off as u16 {
                    reg::VERSION => "map version",
                    reg::CAPACITY => "ring capacity",
                    reg::BLOCK_SIZE => "block size",
                    reg::STATE => "state word",
                    reg::FAULT => "fault code",
                    reg::COMMAND => "command",
                    6 | 7 => "write sequence",
                    8 | 9 => "consumed sequence",
                    10..=15 => "actual position",
                    _ => "reserved header",
                }
                .into();
            }
            let slot = (off - reg::RING as u32) / BLOCK_REGISTERS as u32;
            if slot >= self.capacity as u32 {
                return "past the ring".into();
            }
            format!("ring slot {slot}")
        };
        let (a, b) = (name_of(addr as u32), name_of(last));
        if a == b {
            format!("{range} ({a})")
        } else {
            format!("{range} ({a} to {b})")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn word_orders_round_trip_and_differ() {
        for order in [WordOrder::HighFirst, WordOrder::LowFirst] {
            for v in [0u32, 1, 0xFFFF, 0x1_0000, 0xDEAD_BEEF, u32::MAX] {
                assert_eq!(order.join(order.split(v)), v);
            }
        }
        assert_eq!(WordOrder::HighFirst.split(0x1234_5678), [0x1234, 0x5678]);
        assert_eq!(WordOrder::LowFirst.split(0x1234_5678), [0x5678, 0x1234]);
    }

    #[test]
    fn blocks_round_trip_with_negative_coordinates() {
        let b = MotionBlock {
            kind: BlockKind::ArcCcw,
            target: [-1, i32::MIN, i32::MAX],
            feed: 800_000,
            center: [-5_000, 7],
        };
        for order in [WordOrder::HighFirst, WordOrder::LowFirst] {
            let r = b.encode(70_000, order);
            assert_eq!(MotionBlock::decode(&r, order), Ok((70_000, b)));
        }
        let mut r = b.encode(1, WordOrder::HighFirst);
        r[block_reg::KIND as usize] = 9;
        assert_eq!(MotionBlock::decode(&r, WordOrder::HighFirst), Err(9));
    }

    #[test]
    fn slots_wrap_and_registers_are_named() {
        let l = Layout {
            base: 100,
            capacity: 8,
        };
        assert_eq!(l.slot(1), 0);
        assert_eq!(l.slot(8), 7);
        assert_eq!(l.slot(9), 0);
        assert_eq!(l.slot_address(1), 100 + 32 + 16);
        assert_eq!(
            l.describe(106, 2),
            "holding registers 106..=107 (write sequence)"
        );
        assert_eq!(
            l.describe(132, 32),
            "holding registers 132..=163 (ring slot 0 to ring slot 1)"
        );
        assert_eq!(l.describe(105, 1), "holding register 105 (command)");
    }
}
