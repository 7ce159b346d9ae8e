//! Binary DXF: the same groups as ASCII DXF, each a group code and a value typed by the
//! code's range, after the 22-byte sentinel `AutoCAD Binary DXF\r\n\x1a\0`.
//!
//! Written from the DXF reference's description of binary files and its table of group
//! value types: R12 and earlier write a group code as one byte (255 then two bytes,
//! little-endian, for codes above 254), R13 and later always as two bytes; the first
//! group (`0 SECTION`) tells which. Values: strings end with NUL, doubles are 8 bytes,
//! integers 2, 4 or 8 bytes, booleans 1, binary chunks a length byte and that many bytes,
//! all little-endian. Every value becomes the text its ASCII twin would hold (a double's
//! shortest text that reads back to the same bits), so both kinds of file are read by
//! one reader and plan the same program. A group's `line` is the line its code would
//! have in the ASCII twin (two lines per group). Each group consumes at least one byte:
//! the time is linear in the file, and a file cut short is an error naming the offset.

use super::Group;
use crate::io::ImportError;

/// The bytes a binary DXF file starts with.
pub(super) const SENTINEL: &[u8] = b"AutoCAD Binary DXF\r\n\x1a\0";

/// How a group's value is stored, by its code (the DXF reference's table).
enum Value {
    Text,
    Double,
    Int16,
    Int32,
    Int64,
    Bool,
    Chunk,
}

fn value_type(code: i32) -> Value {
    match code {
        10..=59 | 110..=149 | 210..=239 | 460..=469 | 1010..=1059 => Value::Double,
        60..=79 | 170..=179 | 270..=289 | 370..=389 | 400..=409 | 1060..=1070 => Value::Int16,
        90..=99 | 420..=429 | 440..=459 | 1071 => Value::Int32,
        160..=169 => Value::Int64,
        290..=299 => Value::Bool,
        310..=319 | 1004 => Value::Chunk,
        _ => Value::Text,
    }
}

/// The groups of a binary DXF file (`bytes` starts with [`SENTINEL`]), up to `0 EOF`.
pub(super) fn groups(bytes: &[u8], file: &str) -> Result<Vec<Group>, ImportError> {
    let mut at = SENTINEL.len();
    // R13+: the first code (0) takes two bytes, so a NUL follows it; R12: "SECTION" does
    let wide = bytes.get(at + 1) == Some(&0);
    let mut out = Vec::new();
    while at < bytes.len() {
        let code_at = at;
        let code = if wide {
            let b = bytes
                .get(at..at + 2)
                .ok_or_else(|| cut_short(file, at, "a group code"))?;
            at += 2;
            i16::from_le_bytes([b[0], b[1]]) as i32
        } else {
            match bytes[at] {
                255 => {
                    let b = bytes
                        .get(at + 1..at + 3)
                        .ok_or_else(|| cut_short(file, at, "a group code"))?;
                    at += 3;
                    i16::from_le_bytes([b[0], b[1]]) as i32
                }
                c => {
                    at += 1;
                    c as i32
                }
            }
        };
        let what = format!("the value of group {code} (at byte offset {code_at})");
        let value = match value_type(code) {
            Value::Double => {
                let b = take(bytes, &mut at, 8, file, &what)?;
                let v = f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]);
                v.to_string()
            }
            Value::Int16 => {
                let b = take(bytes, &mut at, 2, file, &what)?;
                i16::from_le_bytes([b[0], b[1]]).to_string()
            }
            Value::Int32 => {
                let b = take(bytes, &mut at, 4, file, &what)?;
                i32::from_le_bytes([b[0], b[1], b[2], b[3]]).to_string()
            }
            Value::Int64 => {
                let b = take(bytes, &mut at, 8, file, &what)?;
                i64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]).to_string()
            }
            Value::Bool => take(bytes, &mut at, 1, file, &what)?[0].to_string(),
            Value::Chunk => {
                let n = take(bytes, &mut at, 1, file, &what)?[0] as usize;
                take(bytes, &mut at, n, file, &what)?
                    .iter()
                    .map(|b| format!("{b:02X}"))
                    .collect()
            }
            Value::Text => {
                let rest = bytes.get(at..).unwrap_or_default();
                let n = rest
                    .iter()
                    .position(|&b| b == 0)
                    .ok_or_else(|| cut_short(file, at, &what))?;
                let s = String::from_utf8_lossy(&rest[..n]).trim().to_string();
                at += n + 1;
                s
            }
        };
        let eof = code == 0 && value == "EOF";
        out.push(Group {
            code,
            value,
            line: 2 * out.len() + 1,
        });
        if eof {
            break;
        }
    }
    Ok(out)
}

/// The next `n` bytes at `at`, which moves past them.
fn take<'b>(
    bytes: &'b [u8],
    at: &mut usize,
    n: usize,
    file: &str,
    what: &str,
) -> Result<&'b [u8], ImportError> {
    let b = bytes
        .get(*at..at.saturating_add(n))
        .ok_or_else(|| cut_short(file, *at, what))?;
    *at += n;
    Ok(b)
}

fn cut_short(file: &str, at: usize, what: &str) -> ImportError {
    ImportError::invalid(
        file,
        format!("binary DXF ends inside {what} at byte offset {at}; the file is cut short"),
    )
}
