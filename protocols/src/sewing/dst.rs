//! Tajima DST: the 512-byte header and 3-byte balanced-ternary stitch records, written and read.
//!
//! Layout (checked against public readers and writers, e.g. pyembroidery):
//! - Header, 512 bytes: `LA:` label (16 chars, space padded), `ST:` record count (7),
//!   `CO:` colour changes (3), `+X:` `-X:` `+Y:` `-Y:` extents in 0.1 mm (5 each, as positive
//!   numbers), `AX:` `AY:` end position relative to the start (sign + 5), `MX:` `MY:` (multi-
//!   design offset, `+    0`), `PD:` (`******`), each field ending in CR; then 0x1A and spaces
//!   up to byte 512.
//! - Records, 3 bytes each, relative moves of -121..=121 per axis in 0.1 mm, Y up, as sums of
//!   balanced-ternary digits: byte 0 holds ±1 (x: bits 0/1, y: bits 7/6) and ±9 (x: bits 2/3,
//!   y: bits 5/4); byte 1 holds ±3 (x: bits 0/1, y: bits 7/6) and ±27 (x: bits 2/3, y: bits
//!   5/4); byte 2 holds ±81 (x: bits 2/3, y: bits 5/4), bits 0 and 1 always set, bit 7 = jump,
//!   bits 7+6 = colour change / stop (`xx xx C3`), `00 00 F3` = end.
//! - A trim is written as three zero-length jumps (`00 00 83` ×3); the reader turns each run
//!   of three zero jumps back into a trim. Stops are written as colour changes (DST has one
//!   code for both).
//! - `ST` counts the records after the header, the end record excluded; the extents span
//!   every frame position of the pattern (stitches and jumps) and the start point (0, 0).

use super::{RecordLimits, SewingError, StitchKind, StitchRecord};

pub const HEADER_LEN: usize = 512;
/// The largest move of one record on each axis, 0.1 mm.
pub const MAX_STEP: i32 = 121;

const X_BITS: [(usize, u8, u8, i32); 5] = [
    // (byte, + bit, - bit, weight)
    (2, 2, 3, 81),
    (1, 2, 3, 27),
    (0, 2, 3, 9),
    (1, 0, 1, 3),
    (0, 0, 1, 1),
];
const Y_BITS: [(usize, u8, u8, i32); 5] = [
    (2, 5, 4, 81),
    (1, 5, 4, 27),
    (0, 5, 4, 9),
    (1, 7, 6, 3),
    (0, 7, 6, 1),
];

/// Encodes a relative move of a stitch (`jump` false) or jump (`jump` true) record.
/// Returns None when a step exceeds ±121.
pub fn encode_move(dx: i32, dy: i32, jump: bool) -> Option<[u8; 3]> {
    if dx.abs() > MAX_STEP || dy.abs() > MAX_STEP {
        return None;
    }
    let mut b = [0u8, 0u8, 0b0000_0011];
    if jump {
        b[2] |= 0x80;
    }
    for (mut v, table) in [(dx, &X_BITS), (dy, &Y_BITS)] {
        for &(byte, plus, minus, w) in table.iter() {
            // the balanced-ternary digit of weight w: v in (-w·1.5, w·1.5] after the larger digits
            let half = w / 2; // 81 → 40, 27 → 13, 9 → 4, 3 → 1, 1 → 0
            if v > half {
                b[byte] |= 1 << plus;
                v -= w;
            } else if v < -half {
                b[byte] |= 1 << minus;
                v += w;
            }
        }
        debug_assert_eq!(v, 0);
    }
    Some(b)
}

/// Decodes the relative move of a record.
pub fn decode_move(b: [u8; 3]) -> (i32, i32) {
    let sum = |table: &[(usize, u8, u8, i32); 5]| {
        table.iter().fold(0, |acc, &(byte, plus, minus, w)| {
            let mut a = acc;
            if b[byte] & (1 << plus) != 0 {
                a += w;
            }
            if b[byte] & (1 << minus) != 0 {
                a -= w;
            }
            a
        })
    };
    (sum(&X_BITS), sum(&Y_BITS))
}

const COLOR: [u8; 3] = [0, 0, 0xC3];
const END: [u8; 3] = [0, 0, 0xF3];
const ZERO_JUMP: [u8; 3] = [0, 0, 0x83];
/// How many zero-length jumps stand for one trim.
pub const TRIM_JUMPS: usize = 3;

/// The header fields of a DST file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DstHeader {
    pub label: String,
    pub records: u32,
    pub color_changes: u32,
    pub plus_x: i32,
    pub minus_x: i32,
    pub plus_y: i32,
    pub minus_y: i32,
    pub ax: i32,
    pub ay: i32,
}

/// A DST file read back: its header and its records (absolute, 0.1 mm).
#[derive(Clone, Debug, PartialEq)]
pub struct DstPattern {
    pub header: DstHeader,
    pub records: Vec<StitchRecord>,
}

/// Writes `records` (absolute, 0.1 mm, each within ±121 of the one before) as a DST file.
pub fn write(records: &[StitchRecord], label: &str) -> Result<Vec<u8>, SewingError> {
    let mut body: Vec<u8> = Vec::with_capacity(records.len() * 3 + 3);
    let (mut cx, mut cy) = (0i32, 0i32);
    let (mut minx, mut maxx, mut miny, mut maxy) = (0, 0, 0, 0);
    let (mut count, mut colors) = (0u32, 0u32);
    for (i, r) in records.iter().enumerate() {
        match r.kind {
            StitchKind::Stitch | StitchKind::Jump => {
                let (dx, dy) = (r.x as i64 - cx as i64, r.y as i64 - cy as i64);
                let too_long = || SewingError::StitchTooLong {
                    index: i,
                    x: r.x,
                    y: r.y,
                    len: ((dx * dx + dy * dy) as f64).sqrt().round() as i64,
                    max: MAX_STEP as i64,
                };
                if dx.abs() > MAX_STEP as i64 || dy.abs() > MAX_STEP as i64 {
                    return Err(too_long());
                }
                let b = encode_move(dx as i32, dy as i32, r.kind == StitchKind::Jump)
                    .ok_or_else(too_long)?;
                body.extend_from_slice(&b);
                count += 1;
                (cx, cy) = (r.x, r.y);
                minx = minx.min(cx);
                maxx = maxx.max(cx);
                miny = miny.min(cy);
                maxy = maxy.max(cy);
            }
            StitchKind::Trim => {
                for _ in 0..TRIM_JUMPS {
                    body.extend_from_slice(&ZERO_JUMP);
                }
                count += TRIM_JUMPS as u32;
            }
            StitchKind::ColorChange | StitchKind::Stop => {
                body.extend_from_slice(&COLOR);
                count += 1;
                colors += 1;
            }
        }
    }
    body.extend_from_slice(&END);
    let header = DstHeader {
        label: label.to_string(),
        records: count,
        color_changes: colors,
        plus_x: maxx,
        minus_x: -minx,
        plus_y: maxy,
        minus_y: -miny,
        ax: cx,
        ay: cy,
    };
    let mut out = header_bytes(&header);
    out.extend_from_slice(&body);
    Ok(out)
}

/// Writes records that may make longer steps than a DST record: they are first split as the
/// post splits jumps (a stitch too long is still an error).
pub fn write_toolpath(tp: &offset_core::Toolpath, label: &str) -> Result<Vec<u8>, SewingError> {
    write(&super::records(tp, RecordLimits::DST)?, label)
}

fn signed5(v: i32) -> String {
    format!("{}{:5}", if v < 0 { '-' } else { '+' }, v.unsigned_abs())
}

fn header_bytes(h: &DstHeader) -> Vec<u8> {
    // the label: printable ASCII only, 16 characters
    let label: String = h
        .label
        .chars()
        .map(|c| {
            if c.is_ascii_graphic() || c == ' ' {
                c
            } else {
                '_'
            }
        })
        .take(16)
        .collect();
    let mut s = String::new();
    s.push_str(&format!("LA:{label:<16}\r"));
    s.push_str(&format!("ST:{:7}\r", h.records.min(9_999_999)));
    s.push_str(&format!("CO:{:3}\r", h.color_changes.min(999)));
    s.push_str(&format!("+X:{:5}\r", h.plus_x.clamp(0, 99_999)));
    s.push_str(&format!("-X:{:5}\r", h.minus_x.clamp(0, 99_999)));
    s.push_str(&format!("+Y:{:5}\r", h.plus_y.clamp(0, 99_999)));
    s.push_str(&format!("-Y:{:5}\r", h.minus_y.clamp(0, 99_999)));
    s.push_str(&format!("AX:{}\r", signed5(h.ax.clamp(-99_999, 99_999))));
    s.push_str(&format!("AY:{}\r", signed5(h.ay.clamp(-99_999, 99_999))));
    s.push_str(&format!("MX:{}\r", signed5(0)));
    s.push_str(&format!("MY:{}\r", signed5(0)));
    s.push_str("PD:******\r");
    let mut b = s.into_bytes();
    b.push(0x1A);
    b.resize(HEADER_LEN, b' ');
    b
}

/// Reads a DST file (`file` names it in errors).
pub fn read(bytes: &[u8], file: &str) -> Result<DstPattern, SewingError> {
    if bytes.len() < HEADER_LEN {
        return Err(SewingError::bad_file(
            file,
            format!(
                "a DST file starts with a {HEADER_LEN}-byte header, but the file has only {} bytes",
                bytes.len()
            ),
        ));
    }
    let header = parse_header(&bytes[..HEADER_LEN], file)?;
    let body = &bytes[HEADER_LEN..];
    let mut records = Vec::new();
    let (mut cx, mut cy) = (0i32, 0i32);
    let mut zero_jumps = 0usize;
    let mut ended = false;
    for (k, c) in body.chunks(3).enumerate() {
        let offset = HEADER_LEN + 3 * k;
        if c.len() < 3 {
            return Err(SewingError::bad_file(
                file,
                format!("the record at byte {offset} is cut short"),
            ));
        }
        let b = [c[0], c[1], c[2]];
        if b[2] & 0b11 != 0b11 {
            return Err(SewingError::bad_file(
                file,
                format!(
                    "the record at byte {offset} ({:02X} {:02X} {:02X}) lacks the two set low bits of a DST record",
                    b[0], b[1], b[2]
                ),
            ));
        }
        let flush = |zero_jumps: &mut usize, records: &mut Vec<StitchRecord>, cx, cy| {
            for _ in 0..*zero_jumps / TRIM_JUMPS {
                records.push(StitchRecord::new(StitchKind::Trim, cx, cy));
            }
            for _ in 0..*zero_jumps % TRIM_JUMPS {
                records.push(StitchRecord::new(StitchKind::Jump, cx, cy));
            }
            *zero_jumps = 0;
        };
        if b[2] & 0xF3 == 0xF3 {
            flush(&mut zero_jumps, &mut records, cx, cy);
            ended = true;
            break;
        }
        if b[2] & 0xC3 == 0xC3 {
            flush(&mut zero_jumps, &mut records, cx, cy);
            records.push(StitchRecord::new(StitchKind::ColorChange, cx, cy));
            continue;
        }
        let (dx, dy) = decode_move(b);
        let jump = b[2] & 0x80 != 0;
        if jump && dx == 0 && dy == 0 {
            zero_jumps += 1;
            continue;
        }
        flush(&mut zero_jumps, &mut records, cx, cy);
        cx += dx;
        cy += dy;
        let kind = if jump {
            StitchKind::Jump
        } else {
            StitchKind::Stitch
        };
        records.push(StitchRecord::new(kind, cx, cy));
    }
    if !ended {
        return Err(SewingError::bad_file(
            file,
            "the stitch records end without the end record 00 00 F3",
        ));
    }
    Ok(DstPattern { header, records })
}

/// Reads a DST file's stitch records (absolute, 0.1 mm), for previews.
pub fn read_dst(bytes: &[u8], file: &str) -> Result<Vec<StitchRecord>, SewingError> {
    Ok(read(bytes, file)?.records)
}

fn parse_header(h: &[u8], file: &str) -> Result<DstHeader, SewingError> {
    let end = h.iter().position(|&b| b == 0x1A).unwrap_or(h.len());
    let text = String::from_utf8_lossy(&h[..end]);
    let mut fields: Vec<(String, String)> = Vec::new();
    for f in text.split('\r') {
        if f.len() >= 3 && f.as_bytes()[2] == b':' {
            fields.push((f[..2].to_string(), f[3..].to_string()));
        }
    }
    let get = |name: &str| {
        fields
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.clone())
    };
    let num = |name: &str| -> Result<i32, SewingError> {
        let v = get(name).ok_or_else(|| {
            SewingError::bad_file(file, format!("the DST header has no {name}: field"))
        })?;
        let t: String = v.chars().filter(|c| !c.is_whitespace()).collect();
        t.trim_start_matches('+').parse::<i32>().map_err(|_| {
            SewingError::bad_file(
                file,
                format!("the DST header field {name}: holds {v:?}, not a number"),
            )
        })
    };
    let label = get("LA").ok_or_else(|| {
        SewingError::bad_file(file, "not a DST file: the header does not start with LA:")
    })?;
    Ok(DstHeader {
        label: label.trim_end().to_string(),
        records: num("ST")?.max(0) as u32,
        color_changes: num("CO")?.max(0) as u32,
        plus_x: num("+X")?,
        minus_x: num("-X")?,
        plus_y: num("+Y")?,
        minus_y: num("-Y")?,
        ax: num("AX")?,
        ay: num("AY")?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn digits_land_on_the_documented_bits() {
        assert_eq!(encode_move(1, 0, false), Some([0x01, 0x00, 0x03]));
        assert_eq!(encode_move(0, 1, false), Some([0x80, 0x00, 0x03]));
        assert_eq!(encode_move(-81, 0, false), Some([0x00, 0x00, 0x0B]));
        assert_eq!(encode_move(0, 81, true), Some([0x00, 0x00, 0xA3]));
        // 121 = 81 + 27 + 9 + 3 + 1
        assert_eq!(encode_move(121, 0, false), Some([0x05, 0x05, 0x07]));
        assert_eq!(encode_move(122, 0, false), None);
    }
}
