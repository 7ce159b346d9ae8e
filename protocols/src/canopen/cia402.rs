//! The CiA 402 drive: its power state machine as the statusword (0x6041) shows it and the
//! controlword (0x6040) drives it — one table for the master and the simulated drive — and
//! its modes of operation.

use serde::{Deserialize, Serialize};
use std::fmt;

/// The power state of a drive.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PowerState {
    NotReadyToSwitchOn,
    SwitchOnDisabled,
    ReadyToSwitchOn,
    SwitchedOn,
    OperationEnabled,
    QuickStopActive,
    FaultReactionActive,
    Fault,
}

/// Statusword bit 12 in interpolated position mode: interpolation is active.
pub const SW_IP_ACTIVE: u16 = 1 << 12;
/// Statusword bit 13 in the position modes: following error.
pub const SW_FOLLOWING_ERROR: u16 = 1 << 13;
/// Statusword bit 9: remote (the controlword is obeyed).
pub const SW_REMOTE: u16 = 1 << 9;
/// Controlword bit 4 in interpolated position mode: enable interpolation.
pub const CW_ENABLE_IP: u16 = 1 << 4;
/// Controlword bit 8: halt.
pub const CW_HALT: u16 = 1 << 8;

impl PowerState {
    /// The state the statusword shows (bits 0–3, 5, 6); None for a pattern CiA 402 does not
    /// define.
    pub fn from_statusword(sw: u16) -> Option<PowerState> {
        use PowerState::*;
        Some(if sw & 0x4F == 0x00 {
            NotReadyToSwitchOn
        } else if sw & 0x4F == 0x40 {
            SwitchOnDisabled
        } else if sw & 0x6F == 0x21 {
            ReadyToSwitchOn
        } else if sw & 0x6F == 0x23 {
            SwitchedOn
        } else if sw & 0x6F == 0x27 {
            OperationEnabled
        } else if sw & 0x6F == 0x07 {
            QuickStopActive
        } else if sw & 0x4F == 0x0F {
            FaultReactionActive
        } else if sw & 0x4F == 0x08 {
            Fault
        } else {
            return None;
        })
    }

    /// The statusword bits 0–6 a drive in this state shows (voltage enabled, bit 4, in the
    /// states that have power).
    pub fn statusword(self) -> u16 {
        use PowerState::*;
        match self {
            NotReadyToSwitchOn => 0x00,
            SwitchOnDisabled => 0x40,
            ReadyToSwitchOn => 0x21 | 0x10,
            SwitchedOn => 0x23 | 0x10,
            OperationEnabled => 0x27 | 0x10,
            QuickStopActive => 0x07 | 0x10,
            FaultReactionActive => 0x0F | 0x10,
            Fault => 0x08,
        }
    }

    /// The state a drive goes to on `cmd` (CiA 402 transitions 2–12, 15, 16); None: the
    /// command does nothing in this state.
    pub fn on(self, cmd: Command) -> Option<PowerState> {
        use Command as C;
        use PowerState::*;
        Some(match (self, cmd) {
            (SwitchOnDisabled, C::Shutdown) => ReadyToSwitchOn,
            (ReadyToSwitchOn, C::SwitchOn) => SwitchedOn,
            (ReadyToSwitchOn, C::EnableOperation) => OperationEnabled,
            (ReadyToSwitchOn, C::DisableVoltage | C::QuickStop) => SwitchOnDisabled,
            (SwitchedOn, C::EnableOperation) => OperationEnabled,
            (SwitchedOn, C::Shutdown) => ReadyToSwitchOn,
            (SwitchedOn, C::DisableVoltage | C::QuickStop) => SwitchOnDisabled,
            (OperationEnabled, C::SwitchOn) => SwitchedOn,
            (OperationEnabled, C::Shutdown) => ReadyToSwitchOn,
            (OperationEnabled, C::DisableVoltage) => SwitchOnDisabled,
            (OperationEnabled, C::QuickStop) => QuickStopActive,
            (QuickStopActive, C::EnableOperation) => OperationEnabled,
            (QuickStopActive, C::DisableVoltage) => SwitchOnDisabled,
            (Fault, C::FaultReset) => SwitchOnDisabled,
            _ => return None,
        })
    }

    /// The command that moves a drive in this state one step toward operation enabled; None
    /// when it is there, or must get there by itself (not ready, fault reaction).
    pub fn toward_enabled(self) -> Option<Command> {
        use PowerState::*;
        match self {
            Fault => Some(Command::FaultReset),
            SwitchOnDisabled => Some(Command::Shutdown),
            ReadyToSwitchOn => Some(Command::SwitchOn),
            SwitchedOn | QuickStopActive => Some(Command::EnableOperation),
            OperationEnabled | NotReadyToSwitchOn | FaultReactionActive => None,
        }
    }
}

impl fmt::Display for PowerState {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        use PowerState::*;
        f.write_str(match self {
            NotReadyToSwitchOn => "not ready to switch on",
            SwitchOnDisabled => "switch on disabled",
            ReadyToSwitchOn => "ready to switch on",
            SwitchedOn => "switched on",
            OperationEnabled => "operation enabled",
            QuickStopActive => "quick stop active",
            FaultReactionActive => "fault reaction active",
            Fault => "fault",
        })
    }
}

/// A controlword command (bits 0–3 and 7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    Shutdown,
    /// Also "disable operation" from operation enabled.
    SwitchOn,
    DisableVoltage,
    QuickStop,
    EnableOperation,
    /// Bit 7 (a rising edge resets a fault).
    FaultReset,
}

impl Command {
    /// The controlword (bits 0–3, 7).
    pub fn controlword(self) -> u16 {
        match self {
            Command::Shutdown => 0x0006,
            Command::SwitchOn => 0x0007,
            Command::DisableVoltage => 0x0000,
            Command::QuickStop => 0x0002,
            Command::EnableOperation => 0x000F,
            Command::FaultReset => 0x0080,
        }
    }

    /// The command a controlword gives; `previous` is the last controlword, for the rising
    /// edge of fault reset.
    pub fn from_controlword(cw: u16, previous: u16) -> Option<Command> {
        if cw & 0x80 != 0 && previous & 0x80 == 0 {
            return Some(Command::FaultReset);
        }
        if cw & 0x80 != 0 {
            return None;
        }
        Some(if cw & 0x02 == 0 {
            Command::DisableVoltage
        } else if cw & 0x04 == 0 {
            Command::QuickStop
        } else if cw & 0x01 == 0 {
            Command::Shutdown
        } else if cw & 0x08 == 0 {
            Command::SwitchOn
        } else {
            Command::EnableOperation
        })
    }
}

impl fmt::Display for Command {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(match self {
            Command::Shutdown => "shutdown",
            Command::SwitchOn => "switch on",
            Command::DisableVoltage => "disable voltage",
            Command::QuickStop => "quick stop",
            Command::EnableOperation => "enable operation",
            Command::FaultReset => "fault reset",
        })
    }
}

/// How set-points reach the drives.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Mode {
    /// Interpolated position (0x6060 = 7): set-points to 0x60C1:01.
    #[default]
    #[serde(rename = "ip")]
    InterpolatedPosition,
    /// Cyclic synchronous position (0x6060 = 8): set-points to 0x607A.
    #[serde(rename = "csp")]
    CyclicSynchronousPosition,
}

impl Mode {
    /// The value of 0x6060.
    pub fn code(self) -> i8 {
        match self {
            Mode::InterpolatedPosition => 7,
            Mode::CyclicSynchronousPosition => 8,
        }
    }
    pub fn from_code(c: i8) -> Option<Mode> {
        match c {
            7 => Some(Mode::InterpolatedPosition),
            8 => Some(Mode::CyclicSynchronousPosition),
            _ => None,
        }
    }
    /// The object the set-point goes to.
    pub fn setpoint(self) -> super::od::Entry {
        match self {
            Mode::InterpolatedPosition => super::od::IP_SETPOINT,
            Mode::CyclicSynchronousPosition => super::od::TARGET_POSITION,
        }
    }
    /// The controlword that enables operation in this mode (IP also sets bit 4).
    pub fn enable_word(self) -> u16 {
        match self {
            Mode::InterpolatedPosition => Command::EnableOperation.controlword() | CW_ENABLE_IP,
            Mode::CyclicSynchronousPosition => Command::EnableOperation.controlword(),
        }
    }
}

impl fmt::Display for Mode {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(match self {
            Mode::InterpolatedPosition => "interpolated position (7)",
            Mode::CyclicSynchronousPosition => "cyclic synchronous position (8)",
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_state_reads_back_from_its_statusword_and_the_enable_path_arrives() {
        use PowerState::*;
        for s in [
            NotReadyToSwitchOn,
            SwitchOnDisabled,
            ReadyToSwitchOn,
            SwitchedOn,
            OperationEnabled,
            QuickStopActive,
            FaultReactionActive,
            Fault,
        ] {
            assert_eq!(
                PowerState::from_statusword(s.statusword() | 0x0200),
                Some(s)
            );
        }
        for start in [
            Fault,
            SwitchOnDisabled,
            ReadyToSwitchOn,
            SwitchedOn,
            QuickStopActive,
        ] {
            let mut s = start;
            let mut prev = 0;
            for _ in 0..5 {
                let Some(cmd) = s.toward_enabled() else { break };
                let cw = cmd.controlword();
                assert_eq!(Command::from_controlword(cw, prev), Some(cmd));
                s = s.on(cmd).unwrap();
                prev = cw;
            }
            assert_eq!(s, OperationEnabled, "from {start}");
        }
        // a held fault-reset bit is no second reset
        assert_eq!(Command::from_controlword(0x80, 0x80), None);
    }
}
