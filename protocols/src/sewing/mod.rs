//! Sewing: stitch records in the machine's 0.1 mm units, the DST and JEF files, and the pattern transfer link.
//!
//! A stitch path from the planner (`Move::Stitch`, `Move::Jump`, `Move::Trim`,
//! `Move::ColorChange`, `Move::Stop`, in mm) becomes a list of [`StitchRecord`]s at absolute
//! positions in 0.1 mm units (`post`); files (`dst`, `jef`) and the serial pattern transfer
//! (`wire`, `link`) all work from those records.

mod attach;
pub mod dst;
pub mod jef;
pub mod kind;
pub mod link;
pub mod wire;

pub use kind::{SewingKind, StitchPost};
pub use link::SewingLink;

use offset_core::{Move, Point, Toolpath};
use serde::{Deserialize, Serialize};

/// What a record asks the machine to do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StitchKind {
    /// Move the frame to the position and drop the needle there.
    Stitch,
    /// Move the frame to the position without sewing.
    Jump,
    /// Cut the thread (the position is where the frame already is).
    Trim,
    /// Stop for a thread colour change (the position is where the frame already is).
    ColorChange,
    /// Stop for the operator (the position is where the frame already is).
    Stop,
}

impl StitchKind {
    /// The kind's code on the wire.
    pub fn code(self) -> u8 {
        match self {
            StitchKind::Stitch => 0,
            StitchKind::Jump => 1,
            StitchKind::Trim => 2,
            StitchKind::ColorChange => 3,
            StitchKind::Stop => 4,
        }
    }
    pub fn from_code(c: u8) -> Option<StitchKind> {
        Some(match c {
            0 => StitchKind::Stitch,
            1 => StitchKind::Jump,
            2 => StitchKind::Trim,
            3 => StitchKind::ColorChange,
            4 => StitchKind::Stop,
            _ => return None,
        })
    }
    /// Whether the record moves the frame (stitches and jumps do; the rest stay put).
    pub fn moves(self) -> bool {
        matches!(self, StitchKind::Stitch | StitchKind::Jump)
    }
}

/// One unit of a stitch program: a kind and the absolute frame position after it, in 0.1 mm
/// (Y up, origin where the pattern starts).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct StitchRecord {
    pub kind: StitchKind,
    pub x: i32,
    pub y: i32,
}

impl StitchRecord {
    pub const WIRE_LEN: usize = 9;
    pub fn new(kind: StitchKind, x: i32, y: i32) -> Self {
        StitchRecord { kind, x, y }
    }
    /// The position in mm.
    pub fn mm(&self) -> Point {
        Point::new(self.x as f64 / 10.0, self.y as f64 / 10.0)
    }
    /// The 9 bytes of this record on the wire: kind, x (i32 LE), y (i32 LE).
    pub fn to_wire(&self) -> [u8; 9] {
        let mut b = [0u8; 9];
        b[0] = self.kind.code();
        b[1..5].copy_from_slice(&self.x.to_le_bytes());
        b[5..9].copy_from_slice(&self.y.to_le_bytes());
        b
    }
    pub fn from_wire(b: &[u8]) -> Option<StitchRecord> {
        if b.len() < 9 {
            return None;
        }
        let kind = StitchKind::from_code(b[0])?;
        let x = i32::from_le_bytes([b[1], b[2], b[3], b[4]]);
        let y = i32::from_le_bytes([b[5], b[6], b[7], b[8]]);
        Some(StitchRecord { kind, x, y })
    }
}

/// Why stitches could not be posted, written or read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SewingError {
    #[error("move {index} ({what}) cannot be sewn: a sewing machine only stitches, jumps, trims and stops")]
    NotSewing { index: usize, what: String },
    #[error("move {index} goes to ({x}, {y}) mm, which is not a finite position in range")]
    BadPosition { index: usize, x: f64, y: f64 },
    #[error(
        "stitch {index} to ({:.1}, {:.1}) mm is {:.1} mm long, more than the {:.1} mm the format allows",
        *x as f64 / 10.0, *y as f64 / 10.0, *len as f64 / 10.0, *max as f64 / 10.0
    )]
    StitchTooLong {
        index: usize,
        x: i32,
        y: i32,
        len: i64,
        max: i64,
    },
    #[error("{file}: {message}")]
    BadFile { file: String, message: String },
}

impl SewingError {
    pub fn bad_file(file: &str, message: impl Into<String>) -> Self {
        SewingError::BadFile {
            file: file.to_string(),
            message: message.into(),
        }
    }
}

/// The longest step one record may make, in 0.1 mm: a limit on each axis (DST: 121, JEF:
/// 127) and on the length (the straight-line distance).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RecordLimits {
    pub max_axis: i32,
    pub max_len: i32,
}

impl RecordLimits {
    pub const DST: RecordLimits = RecordLimits {
        max_axis: 121,
        max_len: 121,
    };
    pub const JEF: RecordLimits = RecordLimits {
        max_axis: 127,
        max_len: 127,
    };
    fn fits(&self, dx: i64, dy: i64) -> bool {
        dx.abs() <= self.max_axis as i64
            && dy.abs() <= self.max_axis as i64
            && dx * dx + dy * dy <= (self.max_len as i64).pow(2)
    }
}

/// Rounds a position in mm to the 0.1 mm grid (from the absolute position: nothing drifts).
fn to_units(index: usize, p: Point) -> Result<(i32, i32), SewingError> {
    let (x, y) = ((p.x * 10.0).round(), (p.y * 10.0).round());
    let lim = 1.0e8;
    if !(x.is_finite() && y.is_finite() && x.abs() < lim && y.abs() < lim) {
        return Err(SewingError::BadPosition {
            index,
            x: p.x,
            y: p.y,
        });
    }
    Ok((x as i32, y as i32))
}

/// Turns a stitch path into stitch records within `limits`: jumps longer than a record are
/// split into equal steps (each rounded from its absolute position); a stitch longer than a
/// record is an error naming it. Zero-length jumps are dropped (a trim is written as zero
/// jumps in DST). Comments are skipped; cutting moves are an error.
pub fn records(tp: &Toolpath, limits: RecordLimits) -> Result<Vec<StitchRecord>, SewingError> {
    let mut out: Vec<StitchRecord> = Vec::new();
    let (mut cx, mut cy) = (0i32, 0i32);
    for (index, m) in tp.moves.iter().enumerate() {
        match m {
            Move::Stitch { to } => {
                let (x, y) = to_units(index, *to)?;
                let (dx, dy) = (x as i64 - cx as i64, y as i64 - cy as i64);
                if !limits.fits(dx, dy) {
                    let len = ((dx * dx + dy * dy) as f64).sqrt().round() as i64;
                    return Err(SewingError::StitchTooLong {
                        index,
                        x,
                        y,
                        len,
                        max: limits.max_len as i64,
                    });
                }
                out.push(StitchRecord::new(StitchKind::Stitch, x, y));
                (cx, cy) = (x, y);
            }
            Move::Jump { to } => {
                let (x, y) = to_units(index, *to)?;
                if (x, y) == (cx, cy) {
                    continue;
                }
                let (dx, dy) = (x as f64 - cx as f64, y as f64 - cy as f64);
                let mut n = (dx.abs().max(dy.abs()) / limits.max_axis as f64)
                    .max(dx.hypot(dy) / limits.max_len as f64)
                    .ceil()
                    .max(1.0) as i64;
                loop {
                    let steps: Vec<(i32, i32)> = (1..=n)
                        .map(|i| {
                            let t = i as f64 / n as f64;
                            (
                                (cx as f64 + dx * t).round() as i32,
                                (cy as f64 + dy * t).round() as i32,
                            )
                        })
                        .collect();
                    let mut prev = (cx, cy);
                    let ok = steps.iter().all(|&(sx, sy)| {
                        let f = limits.fits(sx as i64 - prev.0 as i64, sy as i64 - prev.1 as i64);
                        prev = (sx, sy);
                        f
                    });
                    if ok {
                        out.extend(
                            steps
                                .into_iter()
                                .map(|(sx, sy)| StitchRecord::new(StitchKind::Jump, sx, sy)),
                        );
                        break;
                    }
                    n += 1;
                }
                (cx, cy) = (x, y);
            }
            Move::Trim => out.push(StitchRecord::new(StitchKind::Trim, cx, cy)),
            Move::ColorChange => out.push(StitchRecord::new(StitchKind::ColorChange, cx, cy)),
            Move::Stop => out.push(StitchRecord::new(StitchKind::Stop, cx, cy)),
            Move::Comment { .. } => {}
            other => {
                let what = format!("{other:?}");
                let what = what.split([' ', '{']).next().unwrap_or("move").to_string();
                return Err(SewingError::NotSewing { index, what });
            }
        }
    }
    Ok(out)
}

impl crate::program::Unit for StitchRecord {
    fn describe(&self) -> String {
        let p = self.mm();
        format!("{:?} at ({:.1}, {:.1}) mm", self.kind, p.x, p.y)
    }
}

/// The stitch records as a stitch path again (mm), for previews and checks.
pub fn to_toolpath(records: &[StitchRecord]) -> Toolpath {
    let mut tp = Toolpath::new("stitch");
    for r in records {
        tp.push(match r.kind {
            StitchKind::Stitch => Move::Stitch { to: r.mm() },
            StitchKind::Jump => Move::Jump { to: r.mm() },
            StitchKind::Trim => Move::Trim,
            StitchKind::ColorChange => Move::ColorChange,
            StitchKind::Stop => Move::Stop,
        });
    }
    tp
}

/// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor): the frame check
/// of the pattern transfer protocol. check("123456789") = 0x29B1.
pub fn crc16_ccitt_false(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in data {
        crc ^= (b as u16) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// CRC-32/ISO-HDLC (the zlib/Ethernet CRC): the whole pattern's check. check("123456789") =
/// 0xCBF43926.
pub fn crc32(data: &[u8]) -> u32 {
    let mut crc: u32 = 0xFFFF_FFFF;
    for &b in data {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// The pattern CRC of a list of records: CRC-32 over their wire bytes in order.
pub fn pattern_crc(records: &[StitchRecord]) -> u32 {
    let mut bytes = Vec::with_capacity(records.len() * StitchRecord::WIRE_LEN);
    for r in records {
        bytes.extend_from_slice(&r.to_wire());
    }
    crc32(&bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_check_values() {
        assert_eq!(crc16_ccitt_false(b"123456789"), 0x29B1);
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn long_jumps_split_into_equal_records_without_drift() {
        let mut tp = Toolpath::new("t");
        tp.push(Move::Jump {
            to: Point::new(100.0, -33.3),
        });
        tp.push(Move::Stitch {
            to: Point::new(101.0, -33.3),
        });
        let r = records(&tp, RecordLimits::DST).unwrap();
        let jumps: Vec<_> = r.iter().filter(|r| r.kind == StitchKind::Jump).collect();
        assert_eq!(jumps.len(), 9); // 1053 / 121 → 9 steps
        assert_eq!((jumps[8].x, jumps[8].y), (1000, -333));
        let mut err = tp.clone();
        err.push(Move::Stitch {
            to: Point::new(120.0, -33.3),
        });
        let e = records(&err, RecordLimits::DST).unwrap_err();
        assert!(
            e.to_string().starts_with("stitch 2 to (120.0, -33.3)"),
            "{e}"
        );
    }
}
