//! Janome JEF: a little-endian header, thread tables and 2-byte stitch records, written and read.
//!
//! Layout (checked against public readers and writers, e.g. pyembroidery):
//! - Header, 116 bytes (0x74), all integers i32 little-endian: the offset of the stitch data
//!   (0x74 + 8 × threads), flags (0x14), the date and time as 14 ASCII digits
//!   (`YYYYMMDDhhmmss`) and two zero bytes, the number of threads, the number of stitch data
//!   points (stitch 1, jump or colour change 2, end 1), the hoop code (0 = 110×110, 1 = 50×50,
//!   2 = 140×200, 3 = 126×110, 4 = 200×200), the design's half-extents from its centre (left,
//!   top, right, bottom, 0.1 mm), then for four hoops the distances from the design's edges to
//!   the hoop's edges (or −1 ×4 where it does not fit).
//! - Thread colours (i32 index into the Janome palette per thread), then thread types (0x0D
//!   per thread).
//! - Records: a stitch is two signed bytes dx, dy (−127..=127, 0.1 mm, Y up); `80 02 dx dy` is
//!   a jump, `80 01 dx dy` a colour change, `80 10` the end.
//! - A trim is written as a zero-length jump `80 02 00 00`, and read back as one; stops are
//!   written as colour changes.

use super::{RecordLimits, SewingError, StitchKind, StitchRecord};

const HEADER_LEN: usize = 0x74;
pub const MAX_STEP: i32 = 127;

/// Settings of one JEF file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct JefOptions {
    /// `YYYYMMDDhhmmss`, written as is (14 digits).
    pub date: String,
}

impl Default for JefOptions {
    fn default() -> Self {
        JefOptions {
            date: "20000101000000".into(),
        }
    }
}

/// Writes `records` (absolute, 0.1 mm, each within ±127 of the one before) as a JEF file.
pub fn write(records: &[StitchRecord], opts: &JefOptions) -> Result<Vec<u8>, SewingError> {
    let mut body = Vec::with_capacity(records.len() * 2 + 2);
    let (mut cx, mut cy) = (0i32, 0i32);
    let (mut minx, mut maxx, mut miny, mut maxy) = (0, 0, 0, 0);
    let mut points: i32 = 1;
    let mut threads: i32 = 1;
    for (i, r) in records.iter().enumerate() {
        let (dx, dy) = if r.kind.moves() {
            (r.x as i64 - cx as i64, r.y as i64 - cy as i64)
        } else {
            (0, 0)
        };
        if dx.abs() > MAX_STEP as i64 || dy.abs() > MAX_STEP as i64 {
            return Err(SewingError::StitchTooLong {
                index: i,
                x: r.x,
                y: r.y,
                len: ((dx * dx + dy * dy) as f64).sqrt().round() as i64,
                max: MAX_STEP as i64,
            });
        }
        let (bx, by) = (dx as i8 as u8, dy as i8 as u8);
        match r.kind {
            StitchKind::Stitch => {
                body.extend_from_slice(&[bx, by]);
                points += 1;
            }
            StitchKind::Jump => {
                if dx == 0 && dy == 0 {
                    // a zero jump means a trim in this file; the post never makes one
                    continue;
                }
                body.extend_from_slice(&[0x80, 0x02, bx, by]);
                points += 2;
            }
            StitchKind::Trim => {
                body.extend_from_slice(&[0x80, 0x02, 0, 0]);
                points += 2;
            }
            StitchKind::ColorChange | StitchKind::Stop => {
                body.extend_from_slice(&[0x80, 0x01, 0, 0]);
                points += 2;
                threads += 1;
            }
        }
        if r.kind.moves() {
            (cx, cy) = (r.x, r.y);
            minx = minx.min(cx);
            maxx = maxx.max(cx);
            miny = miny.min(cy);
            maxy = maxy.max(cy);
        }
    }
    body.extend_from_slice(&[0x80, 0x10]);

    let date: Vec<u8> = opts
        .date
        .bytes()
        .chain(std::iter::repeat(b'0'))
        .take(14)
        .collect();
    let (w, h) = (maxx - minx, maxy - miny);
    let (hw, hh) = ((w + 1) / 2, (h + 1) / 2);
    let mut out = Vec::with_capacity(HEADER_LEN + threads as usize * 8 + body.len());
    let int = |out: &mut Vec<u8>, v: i32| out.extend_from_slice(&v.to_le_bytes());
    int(&mut out, HEADER_LEN as i32 + threads * 8);
    int(&mut out, 0x14);
    out.extend_from_slice(&date);
    out.extend_from_slice(&[0, 0]);
    int(&mut out, threads);
    int(&mut out, points);
    int(&mut out, hoop_code(w, h));
    for v in [hw, hh, hw, hh] {
        int(&mut out, v);
    }
    // the hoops' half sizes: 110×110, 50×50, 140×200, and the 140×200 again as "custom"
    for (hx, hy) in [(550, 550), (250, 250), (700, 1000), (700, 1000)] {
        let (ex, ey) = (hx - hw, hy - hh);
        let e = if ex >= 0 && ey >= 0 {
            [ex, ey, ex, ey]
        } else {
            [-1; 4]
        };
        for v in e {
            int(&mut out, v);
        }
    }
    debug_assert_eq!(out.len(), HEADER_LEN);
    for t in 0..threads {
        int(&mut out, t % 78 + 1);
    }
    for _ in 0..threads {
        int(&mut out, 0x0D);
    }
    out.extend_from_slice(&body);
    Ok(out)
}

fn hoop_code(w: i32, h: i32) -> i32 {
    if w < 500 && h < 500 {
        1
    } else if w < 1260 && h < 1100 {
        3
    } else if w < 1400 && h < 2000 {
        2
    } else if w < 2000 && h < 2000 {
        4
    } else {
        0
    }
}

/// Writes a stitch path as a JEF file (jumps split to JEF's ±12.7 mm records).
pub fn write_toolpath(
    tp: &offset_core::Toolpath,
    opts: &JefOptions,
) -> Result<Vec<u8>, SewingError> {
    write(&super::records(tp, RecordLimits::JEF)?, opts)
}

/// Reads a JEF file's stitch records (absolute, 0.1 mm); `file` names it in errors.
pub fn read(bytes: &[u8], file: &str) -> Result<Vec<StitchRecord>, SewingError> {
    let int = |at: usize| -> Result<i32, SewingError> {
        bytes
            .get(at..at + 4)
            .map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| {
                SewingError::bad_file(file, format!("the JEF header is cut short at byte {at}"))
            })
    };
    let start = int(0)?;
    let threads = int(24)?;
    if threads < 0 || start < HEADER_LEN as i32 || start as usize > bytes.len() {
        return Err(SewingError::bad_file(
            file,
            format!("not a JEF file: the stitch data offset {start} lies outside the file"),
        ));
    }
    let mut at = start as usize;
    let mut out = Vec::new();
    let (mut cx, mut cy) = (0i32, 0i32);
    loop {
        let b = bytes.get(at..at + 2).ok_or_else(|| {
            SewingError::bad_file(
                file,
                format!("the stitch data ends at byte {at} without the end record 80 10"),
            )
        })?;
        if b[0] != 0x80 {
            cx += b[0] as i8 as i32;
            cy += b[1] as i8 as i32;
            out.push(StitchRecord::new(StitchKind::Stitch, cx, cy));
            at += 2;
            continue;
        }
        let ctl = b[1];
        if ctl == 0x10 {
            break;
        }
        let d = bytes.get(at + 2..at + 4).ok_or_else(|| {
            SewingError::bad_file(file, format!("the command at byte {at} is cut short"))
        })?;
        let (dx, dy) = (d[0] as i8 as i32, d[1] as i8 as i32);
        match ctl {
            0x01 => out.push(StitchRecord::new(StitchKind::ColorChange, cx, cy)),
            0x02 | 0x04 if dx == 0 && dy == 0 => {
                out.push(StitchRecord::new(StitchKind::Trim, cx, cy))
            }
            0x02 | 0x04 => {
                cx += dx;
                cy += dy;
                out.push(StitchRecord::new(StitchKind::Jump, cx, cy));
            }
            other => {
                return Err(SewingError::bad_file(
                    file,
                    format!("unknown JEF command 80 {other:02X} at byte {at}"),
                ))
            }
        }
        at += 4;
    }
    Ok(out)
}
