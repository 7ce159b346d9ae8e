//! PDO mapping: which objects a process data frame carries, the SDO writes that configure a
//! PDO (CiA 301's order: invalidate, clear, map, count, transmission type, validate), and the
//! packing of values into its bytes.

use super::frame::CanFrame;
use super::od::Entry;

/// One mapped object: an entry and its length in bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mapped {
    pub entry: Entry,
    pub bits: u8,
}

impl Mapped {
    pub const fn new(entry: Entry, bits: u8) -> Mapped {
        Mapped { entry, bits }
    }
    /// The mapping word written to 0x16xx / 0x1Axx: index, sub-index, bit length.
    pub fn word(&self) -> u32 {
        ((self.entry.index as u32) << 16) | ((self.entry.sub as u32) << 8) | self.bits as u32
    }
    pub fn from_word(w: u32) -> Mapped {
        Mapped::new(Entry::new((w >> 16) as u16, (w >> 8) as u8), w as u8)
    }
}

/// Bit 31 of a PDO COB-ID: the PDO is not valid (off).
pub const COB_INVALID: u32 = 0x8000_0000;
/// Transmission type 1: synchronous, every SYNC.
pub const EVERY_SYNC: u8 = 1;

/// One PDO of one node: its COB-ID, transmission type and mapping.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Pdo {
    /// 0x1400 + n − 1 (RPDO) or 0x1800 + n − 1 (TPDO).
    pub comm_index: u16,
    /// 0x1600 + n − 1 or 0x1A00 + n − 1.
    pub map_index: u16,
    pub cob_id: u16,
    pub transmission: u8,
    pub mapped: Vec<Mapped>,
}

impl Pdo {
    /// Receive PDO `n` (1–4) of `node` at its predefined COB-ID (0x200, 0x300, … + node).
    pub fn rpdo(n: u8, node: u8, mapped: Vec<Mapped>) -> Pdo {
        Pdo {
            comm_index: 0x1400 + n as u16 - 1,
            map_index: 0x1600 + n as u16 - 1,
            cob_id: 0x100 + 0x100 * n as u16 + node as u16,
            transmission: EVERY_SYNC,
            mapped,
        }
    }

    /// Transmit PDO `n` (1–4) of `node` at its predefined COB-ID (0x180, 0x280, … + node),
    /// sent on every SYNC.
    pub fn tpdo(n: u8, node: u8, mapped: Vec<Mapped>) -> Pdo {
        Pdo {
            comm_index: 0x1800 + n as u16 - 1,
            map_index: 0x1A00 + n as u16 - 1,
            cob_id: 0x080 + 0x100 * n as u16 + node as u16,
            transmission: EVERY_SYNC,
            mapped,
        }
    }

    /// Bytes of data the PDO carries.
    pub fn len(&self) -> usize {
        self.mapped
            .iter()
            .map(|m| m.bits as usize)
            .sum::<usize>()
            .div_ceil(8)
    }
    pub fn is_empty(&self) -> bool {
        self.mapped.is_empty()
    }

    /// The SDO writes that configure the PDO, in order.
    pub fn writes(&self) -> Vec<(Entry, Vec<u8>)> {
        let cob = Entry::new(self.comm_index, 1);
        let mut w = vec![
            (
                cob,
                (COB_INVALID | self.cob_id as u32).to_le_bytes().to_vec(),
            ),
            (Entry::new(self.map_index, 0), vec![0]),
        ];
        for (i, m) in self.mapped.iter().enumerate() {
            w.push((
                Entry::new(self.map_index, i as u8 + 1),
                m.word().to_le_bytes().to_vec(),
            ));
        }
        w.push((Entry::new(self.map_index, 0), vec![self.mapped.len() as u8]));
        w.push((Entry::new(self.comm_index, 2), vec![self.transmission]));
        w.push((cob, (self.cob_id as u32).to_le_bytes().to_vec()));
        w
    }

    /// What reading the configuration back must give (the values after [`Pdo::writes`]).
    pub fn expected(&self) -> Vec<(Entry, Vec<u8>)> {
        let mut w = vec![
            (
                Entry::new(self.comm_index, 1),
                (self.cob_id as u32).to_le_bytes().to_vec(),
            ),
            (Entry::new(self.comm_index, 2), vec![self.transmission]),
            (Entry::new(self.map_index, 0), vec![self.mapped.len() as u8]),
        ];
        for (i, m) in self.mapped.iter().enumerate() {
            w.push((
                Entry::new(self.map_index, i as u8 + 1),
                m.word().to_le_bytes().to_vec(),
            ));
        }
        w
    }

    /// The frame carrying `values` (raw, one per mapped object, little-endian bit packing).
    pub fn pack(&self, values: &[u64]) -> CanFrame {
        let mut data = [0u8; 8];
        let mut bit = 0usize;
        for (m, v) in self.mapped.iter().zip(values) {
            for b in 0..m.bits as usize {
                if (v >> b) & 1 == 1 && bit + b < 64 {
                    data[(bit + b) / 8] |= 1 << ((bit + b) % 8);
                }
            }
            bit += m.bits as usize;
        }
        CanFrame::cob(self.cob_id, &data[..self.len().min(8)])
    }

    /// The raw values a frame of this PDO carries; None when it is too short.
    pub fn unpack(&self, data: &[u8]) -> Option<Vec<u64>> {
        if data.len() < self.len() {
            return None;
        }
        let mut out = Vec::with_capacity(self.mapped.len());
        let mut bit = 0usize;
        for m in &self.mapped {
            let mut v = 0u64;
            for b in 0..m.bits as usize {
                let at = bit + b;
                if at >= data.len() * 8 {
                    return None;
                }
                if (data[at / 8] >> (at % 8)) & 1 == 1 {
                    v |= 1 << b;
                }
            }
            out.push(v);
            bit += m.bits as usize;
        }
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::od;

    #[test]
    fn values_pack_and_unpack_through_the_mapping() {
        let p = Pdo::tpdo(
            1,
            2,
            vec![
                Mapped::new(od::POSITION_ACTUAL, 32),
                Mapped::new(od::FOLLOWING_ERROR, 32),
            ],
        );
        assert_eq!(p.cob_id, 0x182);
        let f = p.pack(&[(-5i32) as u32 as u64, 7]);
        assert_eq!(f.to_string(), "182#FBFFFFFF07000000");
        let v = p.unpack(f.data()).unwrap();
        assert_eq!(v[0] as u32 as i32, -5);
        assert_eq!(v[1], 7);
        assert!(p.unpack(&[0; 4]).is_none());
        assert_eq!(Mapped::new(od::IP_SETPOINT, 32).word(), 0x60C1_0120);
        let w = Pdo::rpdo(1, 3, vec![Mapped::new(od::IP_SETPOINT, 32)]).writes();
        assert_eq!(
            w.first().unwrap().1,
            (0x8000_0203u32).to_le_bytes().to_vec()
        );
        assert_eq!(w.last().unwrap().1, (0x0203u32).to_le_bytes().to_vec());
    }
}
