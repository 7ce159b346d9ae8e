//! Object dictionary entries machlink reads and writes (CiA 301 communication objects and the
//! CiA 402 drive objects), by index and sub-index, with their names for messages.

use std::fmt;

/// One object dictionary entry: index and sub-index.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Entry {
    pub index: u16,
    pub sub: u8,
}

impl Entry {
    pub const fn new(index: u16, sub: u8) -> Entry {
        Entry { index, sub }
    }
    /// The same index, sub-index `sub`.
    pub const fn at(self, sub: u8) -> Entry {
        Entry::new(self.index, sub)
    }
}

impl fmt::Display for Entry {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(
            f,
            "0x{:04X}:{:02X} ({})",
            self.index,
            self.sub,
            name(self.index)
        )
    }
}

/// 0x1000 device type (u32): the low 16 bits name the device profile.
pub const DEVICE_TYPE: Entry = Entry::new(0x1000, 0);
/// 0x1001 error register (u8).
pub const ERROR_REGISTER: Entry = Entry::new(0x1001, 0);
/// 0x1006 communication cycle period (u32, µs): the SYNC period.
pub const COMM_CYCLE_PERIOD: Entry = Entry::new(0x1006, 0);
/// 0x1008 manufacturer device name (visible string).
pub const DEVICE_NAME: Entry = Entry::new(0x1008, 0);
/// 0x1017 producer heartbeat time (u16, ms).
pub const PRODUCER_HEARTBEAT: Entry = Entry::new(0x1017, 0);
/// 0x1400 RPDO1 communication parameter (sub 1 COB-ID u32, sub 2 transmission type u8).
pub const RPDO1_COMM: u16 = 0x1400;
/// 0x1600 RPDO1 mapping (sub 0 count, sub 1… mapped objects u32).
pub const RPDO1_MAP: u16 = 0x1600;
/// 0x1800 TPDO1 communication parameter.
pub const TPDO1_COMM: u16 = 0x1800;
/// 0x1A00 TPDO1 mapping.
pub const TPDO1_MAP: u16 = 0x1A00;
/// 0x603F error code (u16): the drive's last fault.
pub const ERROR_CODE: Entry = Entry::new(0x603F, 0);
/// 0x6040 controlword (u16).
pub const CONTROLWORD: Entry = Entry::new(0x6040, 0);
/// 0x6041 statusword (u16).
pub const STATUSWORD: Entry = Entry::new(0x6041, 0);
/// 0x6060 modes of operation (i8).
pub const MODES_OF_OPERATION: Entry = Entry::new(0x6060, 0);
/// 0x6061 modes of operation display (i8).
pub const MODES_DISPLAY: Entry = Entry::new(0x6061, 0);
/// 0x605A quick stop option code (i16): machlink writes 2, brake on the quick stop ramp
/// and then go to switch on disabled.
pub const QUICK_STOP_OPTION: Entry = Entry::new(0x605A, 0);
/// The quick stop option code machlink asks for.
pub const QUICK_STOP_THEN_DISABLED: i16 = 2;
/// 0x6064 position actual value (i32, counts).
pub const POSITION_ACTUAL: Entry = Entry::new(0x6064, 0);
/// 0x6065 following error window (u32, counts).
pub const FOLLOWING_ERROR_WINDOW: Entry = Entry::new(0x6065, 0);
/// 0x607A target position (i32, counts): the set-point of cyclic synchronous position.
pub const TARGET_POSITION: Entry = Entry::new(0x607A, 0);
/// 0x60C1:01 interpolation data record, first set-point (i32, counts).
pub const IP_SETPOINT: Entry = Entry::new(0x60C1, 1);
/// 0x60C2:01 interpolation time period, units (u8).
pub const IP_PERIOD_UNITS: Entry = Entry::new(0x60C2, 1);
/// 0x60C2:02 interpolation time period, index (i8: the power of ten of a second, −3 = ms).
pub const IP_PERIOD_INDEX: Entry = Entry::new(0x60C2, 2);
/// 0x60F4 following error actual value (i32, counts).
pub const FOLLOWING_ERROR: Entry = Entry::new(0x60F4, 0);

/// The profile number a CiA 402 drive gives in the low 16 bits of 0x1000.
pub const PROFILE_402: u16 = 402;

/// The object's name, for messages.
pub fn name(index: u16) -> &'static str {
    match index {
        0x1000 => "device type",
        0x1001 => "error register",
        0x1006 => "communication cycle period",
        0x1008 => "device name",
        0x1017 => "producer heartbeat time",
        0x1400..=0x15FF => "RPDO communication parameter",
        0x1600..=0x17FF => "RPDO mapping",
        0x1800..=0x19FF => "TPDO communication parameter",
        0x1A00..=0x1BFF => "TPDO mapping",
        0x603F => "error code",
        0x6040 => "controlword",
        0x6041 => "statusword",
        0x605A => "quick stop option code",
        0x6060 => "modes of operation",
        0x6061 => "modes of operation display",
        0x6064 => "position actual value",
        0x6065 => "following error window",
        0x607A => "target position",
        0x60C1 => "interpolation data record",
        0x60C2 => "interpolation time period",
        0x60F4 => "following error actual value",
        _ => "object",
    }
}
