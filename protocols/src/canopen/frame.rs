//! The CAN frame: an identifier (11 or 29 bits), up to 8 data bytes, and its length on the wire.

use std::fmt;

/// Why a frame could not be made.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    #[error("CAN identifier {id:#x} does not fit {bits} bits")]
    IdTooLarge { id: u32, bits: u8 },
    #[error("a classic CAN frame carries at most 8 data bytes, not {0}")]
    TooLong(usize),
}

/// One classic CAN 2.0 frame.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct CanFrame {
    id: u32,
    extended: bool,
    rtr: bool,
    len: u8,
    data: [u8; 8],
}

impl CanFrame {
    /// A data frame with an 11-bit identifier (every CANopen COB-ID machlink uses).
    pub fn new(id: u16, data: &[u8]) -> Result<CanFrame, FrameError> {
        CanFrame::with_id(id as u32, false, data)
    }

    /// A data frame with an 11-bit (`extended` false) or 29-bit identifier.
    pub fn with_id(id: u32, extended: bool, data: &[u8]) -> Result<CanFrame, FrameError> {
        let bits = if extended { 29 } else { 11 };
        if id >> bits != 0 {
            return Err(FrameError::IdTooLarge { id, bits });
        }
        if data.len() > 8 {
            return Err(FrameError::TooLong(data.len()));
        }
        let mut d = [0u8; 8];
        d[..data.len()].copy_from_slice(data);
        Ok(CanFrame {
            id,
            extended,
            rtr: false,
            len: data.len() as u8,
            data: d,
        })
    }

    /// A remote frame (request) of length code `len` (0 to 8).
    pub fn remote(id: u32, extended: bool, len: u8) -> Result<CanFrame, FrameError> {
        let mut f = CanFrame::with_id(id, extended, &[])?;
        if len > 8 {
            return Err(FrameError::TooLong(len as usize));
        }
        f.rtr = true;
        f.len = len;
        Ok(f)
    }

    /// A standard frame from a COB-ID and a payload known to fit (at most 8 bytes, 11 bits).
    pub(crate) fn cob(id: u16, data: &[u8]) -> CanFrame {
        debug_assert!(id < 0x800 && data.len() <= 8);
        let n = data.len().min(8);
        let mut d = [0u8; 8];
        d[..n].copy_from_slice(&data[..n]);
        CanFrame {
            id: (id & 0x7FF) as u32,
            extended: false,
            rtr: false,
            len: n as u8,
            data: d,
        }
    }

    pub fn id(&self) -> u32 {
        self.id
    }
    pub fn is_extended(&self) -> bool {
        self.extended
    }
    pub fn is_remote(&self) -> bool {
        self.rtr
    }
    /// The data bytes (empty for a remote frame).
    pub fn data(&self) -> &[u8] {
        if self.rtr {
            &[]
        } else {
            &self.data[..self.len as usize]
        }
    }
    /// The data length code.
    pub fn len(&self) -> usize {
        self.len as usize
    }
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The 11-bit COB-ID of a standard data frame; None for extended or remote frames,
    /// which CANopen does not use.
    pub fn cob_id(&self) -> Option<u16> {
        (!self.extended && !self.rtr).then_some(self.id as u16)
    }

    /// Bits this frame occupies on the bus, stuff bits included (computed exactly from its
    /// contents), plus the 3-bit interframe space: what a bus load is counted in.
    pub fn bits_on_wire(&self) -> u32 {
        let mut bits: Vec<bool> = Vec::with_capacity(160);
        let push = |bits: &mut Vec<bool>, v: u32, n: u32| {
            for i in (0..n).rev() {
                bits.push((v >> i) & 1 == 1);
            }
        };
        bits.push(false); // SOF
        if self.extended {
            push(&mut bits, self.id >> 18, 11);
            bits.push(true); // SRR
            bits.push(true); // IDE
            push(&mut bits, self.id & 0x3FFFF, 18);
            bits.push(self.rtr);
            bits.push(false); // r1
            bits.push(false); // r0
        } else {
            push(&mut bits, self.id, 11);
            bits.push(self.rtr);
            bits.push(false); // IDE
            bits.push(false); // r0
        }
        push(&mut bits, self.len as u32, 4);
        for b in self.data() {
            push(&mut bits, *b as u32, 8);
        }
        let crc = crc15(&bits);
        push(&mut bits, crc as u32, 15);
        let mut stuffed = 0;
        let (mut run, mut last) = (0, None);
        for &b in &bits {
            if Some(b) == last {
                run += 1;
            } else {
                last = Some(b);
                run = 1;
            }
            if run == 5 {
                stuffed += 1;
                last = Some(!b);
                run = 1;
            }
        }
        // CRC delimiter, ACK slot, ACK delimiter, 7 EOF, 3 interframe space
        bits.len() as u32 + stuffed + 1 + 2 + 7 + 3
    }
}

/// CAN's CRC-15 (polynomial 0x4599) over the bits from SOF to the end of the data.
fn crc15(bits: &[bool]) -> u16 {
    let mut crc: u16 = 0;
    for &b in bits {
        let next = b ^ ((crc >> 14) & 1 == 1);
        crc = (crc << 1) & 0x7FFF;
        if next {
            crc ^= 0x4599;
        }
    }
    crc
}

impl fmt::Debug for CanFrame {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        fmt::Display::fmt(self, f)
    }
}

impl fmt::Display for CanFrame {
    /// As candump writes it: `181#0A00000000000000`, `R` for a remote frame.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        if self.extended {
            write!(f, "{:08X}#", self.id)?;
        } else {
            write!(f, "{:03X}#", self.id)?;
        }
        if self.rtr {
            return write!(f, "R{}", self.len);
        }
        for b in self.data() {
            write!(f, "{b:02X}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_lengths_fall_between_the_unstuffed_and_worst_case_bounds() {
        // standard frame, n data bytes: 47 + 8n unstuffed bits (44 + 8n + 3 IFS),
        // at most (34 + 8n - 1) / 4 stuff bits
        for n in 0..=8usize {
            for pattern in [0x00u8, 0xFF, 0x55, 0x0F] {
                let f = CanFrame::new(0x000, &vec![pattern; n]).unwrap();
                let bits = f.bits_on_wire();
                let base = 47 + 8 * n as u32;
                let worst = base + (34 + 8 * n as u32 - 1) / 4;
                assert!(
                    bits >= base && bits <= worst,
                    "{n} bytes of {pattern:#x}: {bits}"
                );
            }
        }
        // all-zero standard frame with no data: identifier 0 gives the longest run
        assert!(CanFrame::new(0, &[]).unwrap().bits_on_wire() > 47);
        let ext = CanFrame::with_id(0x1234_5678 & 0x1FFF_FFFF, true, &[1, 2]).unwrap();
        assert!(ext.bits_on_wire() >= 67 + 16);
    }

    #[test]
    fn identifiers_and_lengths_are_checked() {
        assert!(CanFrame::new(0x800, &[]).is_err());
        assert!(CanFrame::with_id(0x2000_0000, true, &[]).is_err());
        assert!(CanFrame::new(0x181, &[0; 9]).is_err());
        let f = CanFrame::new(0x181, &[0xA, 0]).unwrap();
        assert_eq!(f.to_string(), "181#0A00");
        assert_eq!(f.cob_id(), Some(0x181));
    }
}
