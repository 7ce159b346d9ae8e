//! Modbus frames: the requests and replies the register map uses (FC3, FC6, FC16, FC23 and exceptions) in their RTU and TCP envelopes, encoded and decoded without I/O by both the link and the simulated device.
//!
//! A PDU is the function code and its data (Modbus application protocol 1.1b3, section 6).
//! RTU wraps it as `unit | PDU | CRC-16 (low byte first)`; TCP as the 7-byte MBAP header
//! `transaction id | 0 | length | unit` before it. Reply matching lives here too: a reply
//! answers a request only if its function, and its echoed address and count or its
//! register count, agree ([`Request::check_reply`]).

/// Function codes.
pub mod function {
    pub const READ_HOLDING: u8 = 0x03;
    pub const WRITE_SINGLE: u8 = 0x06;
    pub const WRITE_MULTIPLE: u8 = 0x10;
    pub const READ_WRITE: u8 = 0x17;
    /// Set in a reply's function code when it carries an exception.
    pub const EXCEPTION: u8 = 0x80;
}

/// Exception codes the map uses (Modbus application protocol, section 7).
pub mod exception {
    pub const ILLEGAL_FUNCTION: u8 = 0x01;
    pub const ILLEGAL_ADDRESS: u8 = 0x02;
    pub const ILLEGAL_VALUE: u8 = 0x03;
    pub const DEVICE_FAILURE: u8 = 0x04;
    pub const ACKNOWLEDGE: u8 = 0x05;
    pub const DEVICE_BUSY: u8 = 0x06;
    /// TCP only: a gateway found no device behind the unit id.
    pub const GATEWAY_TARGET: u8 = 0x0B;
}

/// The most registers one FC3 read returns.
pub const MAX_READ: u16 = 125;
/// The most registers one FC16 write carries.
pub const MAX_WRITE: u16 = 123;
/// The most registers the write half of an FC23 carries.
pub const MAX_READ_WRITE_WRITE: u16 = 121;
/// The longest RTU frame (address, 253-byte PDU, CRC).
pub const MAX_RTU_FRAME: usize = 256;

/// A request, as the link sends it and the device decodes it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Request {
    /// FC3: read `count` holding registers from `addr`.
    Read { addr: u16, count: u16 },
    /// FC6: write one register.
    WriteSingle { addr: u16, value: u16 },
    /// FC16: write `words` from `addr`.
    Write { addr: u16, words: Vec<u16> },
    /// FC23: write `words` from `write_addr`, then read `read_count` from `read_addr`, in one
    /// exchange (the write happens first).
    ReadWrite {
        read_addr: u16,
        read_count: u16,
        write_addr: u16,
        words: Vec<u16>,
    },
    /// Any other function, kept as its code and data: a device answers Illegal Function.
    Other { function: u8, data: Vec<u8> },
}

/// A reply.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Response {
    Read(Vec<u16>),
    WriteSingle {
        addr: u16,
        value: u16,
    },
    Write {
        addr: u16,
        count: u16,
    },
    ReadWrite(Vec<u16>),
    /// The request's function code (without the 0x80 bit) and the exception code.
    Exception {
        function: u8,
        code: u8,
    },
}

/// Why bytes are not a frame.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    #[error("the frame is {0} bytes, too short for its function")]
    Short(usize),
    #[error("function 0x{0:02X} is not one this map uses")]
    UnknownFunction(u8),
    #[error("the byte count {count} does not match {what}")]
    ByteCount { count: usize, what: String },
    #[error("the CRC reads 0x{got:04X}, the frame's bytes give 0x{want:04X}")]
    Crc { got: u16, want: u16 },
    #[error("the MBAP header names protocol {0}, not Modbus (0)")]
    Protocol(u16),
    #[error("the MBAP length {0} is out of range")]
    Length(usize),
}

fn be16(b: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([b[at], b[at + 1]])
}

fn push_words(out: &mut Vec<u8>, words: &[u16]) {
    for w in words {
        out.extend_from_slice(&w.to_be_bytes());
    }
}

fn words_of(b: &[u8]) -> Vec<u16> {
    b.chunks_exact(2).map(|c| be16(c, 0)).collect()
}

impl Request {
    pub fn function(&self) -> u8 {
        match self {
            Request::Read { .. } => function::READ_HOLDING,
            Request::WriteSingle { .. } => function::WRITE_SINGLE,
            Request::Write { .. } => function::WRITE_MULTIPLE,
            Request::ReadWrite { .. } => function::READ_WRITE,
            Request::Other { function, .. } => *function,
        }
    }

    /// The request's PDU.
    pub fn pdu(&self) -> Vec<u8> {
        let mut b = vec![self.function()];
        match self {
            Request::Read { addr, count } => {
                b.extend_from_slice(&addr.to_be_bytes());
                b.extend_from_slice(&count.to_be_bytes());
            }
            Request::WriteSingle { addr, value } => {
                b.extend_from_slice(&addr.to_be_bytes());
                b.extend_from_slice(&value.to_be_bytes());
            }
            Request::Write { addr, words } => {
                b.extend_from_slice(&addr.to_be_bytes());
                b.extend_from_slice(&(words.len() as u16).to_be_bytes());
                b.push((words.len() * 2) as u8);
                push_words(&mut b, words);
            }
            Request::ReadWrite {
                read_addr,
                read_count,
                write_addr,
                words,
            } => {
                b.extend_from_slice(&read_addr.to_be_bytes());
                b.extend_from_slice(&read_count.to_be_bytes());
                b.extend_from_slice(&write_addr.to_be_bytes());
                b.extend_from_slice(&(words.len() as u16).to_be_bytes());
                b.push((words.len() * 2) as u8);
                push_words(&mut b, words);
            }
            Request::Other { data, .. } => b.extend_from_slice(data),
        }
        b
    }

    /// Decodes a request PDU (the device's side). Quantities are not range-checked here:
    /// that is the device's to answer with Illegal Data Value.
    pub fn from_pdu(p: &[u8]) -> Result<Request, FrameError> {
        let short = || FrameError::Short(p.len());
        let f = *p.first().ok_or_else(short)?;
        let need = |n: usize| if p.len() < n { Err(short()) } else { Ok(()) };
        Ok(match f {
            function::READ_HOLDING => {
                need(5)?;
                Request::Read {
                    addr: be16(p, 1),
                    count: be16(p, 3),
                }
            }
            function::WRITE_SINGLE => {
                need(5)?;
                Request::WriteSingle {
                    addr: be16(p, 1),
                    value: be16(p, 3),
                }
            }
            function::WRITE_MULTIPLE => {
                need(6)?;
                let count = be16(p, 3) as usize;
                let bytes = p[5] as usize;
                if bytes != count * 2 || p.len() != 6 + bytes {
                    return Err(FrameError::ByteCount {
                        count: bytes,
                        what: format!("{count} registers in a {}-byte PDU", p.len()),
                    });
                }
                Request::Write {
                    addr: be16(p, 1),
                    words: words_of(&p[6..]),
                }
            }
            function::READ_WRITE => {
                need(10)?;
                let count = be16(p, 7) as usize;
                let bytes = p[9] as usize;
                if bytes != count * 2 || p.len() != 10 + bytes {
                    return Err(FrameError::ByteCount {
                        count: bytes,
                        what: format!("{count} registers in a {}-byte PDU", p.len()),
                    });
                }
                Request::ReadWrite {
                    read_addr: be16(p, 1),
                    read_count: be16(p, 3),
                    write_addr: be16(p, 5),
                    words: words_of(&p[10..]),
                }
            }
            other => Request::Other {
                function: other,
                data: p[1..].to_vec(),
            },
        })
    }

    /// Why `r` cannot be the reply to this request, if it cannot: the function must agree,
    /// a write's echo must name the same address and count (or value), a read must return
    /// the registers asked for. An exception to this request's function always matches.
    pub fn check_reply(&self, r: &Response) -> Result<(), String> {
        let bad = |what: String| Err(what);
        match (self, r) {
            (_, Response::Exception { function, .. }) if *function == self.function() => Ok(()),
            (Request::Read { count, .. }, Response::Read(v))
            | (
                Request::ReadWrite {
                    read_count: count, ..
                },
                Response::ReadWrite(v),
            ) => {
                if v.len() == *count as usize {
                    Ok(())
                } else {
                    bad(format!("{} registers instead of {count}", v.len()))
                }
            }
            (Request::Write { addr, words }, Response::Write { addr: a, count }) => {
                if a == addr && *count as usize == words.len() {
                    Ok(())
                } else {
                    bad(format!("it confirms {count} registers at {a}"))
                }
            }
            (Request::WriteSingle { addr, value }, Response::WriteSingle { addr: a, value: v }) => {
                if a == addr && v == value {
                    Ok(())
                } else {
                    bad(format!("it confirms {v} at {a}"))
                }
            }
            (_, other) => bad(format!("a reply of function 0x{:02X}", other.function())),
        }
    }
}

impl Response {
    /// The function code on the wire (with 0x80 for an exception).
    pub fn function(&self) -> u8 {
        match self {
            Response::Read(_) => function::READ_HOLDING,
            Response::WriteSingle { .. } => function::WRITE_SINGLE,
            Response::Write { .. } => function::WRITE_MULTIPLE,
            Response::ReadWrite(_) => function::READ_WRITE,
            Response::Exception { function, .. } => function | function::EXCEPTION,
        }
    }

    pub fn pdu(&self) -> Vec<u8> {
        let mut b = vec![self.function()];
        match self {
            Response::Read(v) | Response::ReadWrite(v) => {
                b.push((v.len() * 2) as u8);
                push_words(&mut b, v);
            }
            Response::WriteSingle { addr, value: n } | Response::Write { addr, count: n } => {
                b.extend_from_slice(&addr.to_be_bytes());
                b.extend_from_slice(&n.to_be_bytes());
            }
            Response::Exception { code, .. } => b.push(*code),
        }
        b
    }

    /// Decodes a reply PDU (the link's side).
    pub fn from_pdu(p: &[u8]) -> Result<Response, FrameError> {
        let short = || FrameError::Short(p.len());
        let f = *p.first().ok_or_else(short)?;
        if f & function::EXCEPTION != 0 {
            return Ok(Response::Exception {
                function: f & !function::EXCEPTION,
                code: *p.get(1).ok_or_else(short)?,
            });
        }
        let need = |n: usize| if p.len() < n { Err(short()) } else { Ok(()) };
        Ok(match f {
            function::READ_HOLDING | function::READ_WRITE => {
                need(2)?;
                let bytes = p[1] as usize;
                if !bytes.is_multiple_of(2) || p.len() != 2 + bytes {
                    return Err(FrameError::ByteCount {
                        count: bytes,
                        what: format!("a {}-byte PDU of registers", p.len()),
                    });
                }
                let v = words_of(&p[2..]);
                if f == function::READ_HOLDING {
                    Response::Read(v)
                } else {
                    Response::ReadWrite(v)
                }
            }
            function::WRITE_SINGLE => {
                need(5)?;
                Response::WriteSingle {
                    addr: be16(p, 1),
                    value: be16(p, 3),
                }
            }
            function::WRITE_MULTIPLE => {
                need(5)?;
                Response::Write {
                    addr: be16(p, 1),
                    count: be16(p, 3),
                }
            }
            other => return Err(FrameError::UnknownFunction(other)),
        })
    }
}

/// Which end of the line reads a frame: RTU lengths depend on it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// The device reads requests.
    Request,
    /// The link reads replies.
    Reply,
}

/// The PDU length of the frame whose PDU starts with `head`, when its first bytes tell it:
/// `None` until enough bytes are there, `Some(Err(function))` for a function whose length
/// this map does not know (an RTU device then frames by the line's silence).
pub fn pdu_len(head: &[u8], side: Side) -> Option<Result<usize, u8>> {
    let f = *head.first()?;
    let at = |i: usize| head.get(i).copied();
    if side == Side::Reply && f & function::EXCEPTION != 0 {
        return Some(Ok(2));
    }
    Some(Ok(match (side, f) {
        (Side::Request, function::READ_HOLDING | function::WRITE_SINGLE) => 5,
        (Side::Request, function::WRITE_MULTIPLE) => 6 + at(5)? as usize,
        (Side::Request, function::READ_WRITE) => 10 + at(9)? as usize,
        (Side::Reply, function::READ_HOLDING | function::READ_WRITE) => 2 + at(1)? as usize,
        (Side::Reply, function::WRITE_SINGLE | function::WRITE_MULTIPLE) => 5,
        (_, other) => return Some(Err(other)),
    }))
}

/// CRC-16/MODBUS (reflected polynomial 0xA001, initial 0xFFFF), sent low byte first.
pub fn crc16(data: &[u8]) -> u16 {
    let mut crc = 0xFFFFu16;
    for &b in data {
        crc ^= b as u16;
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xA001
            } else {
                crc >> 1
            };
        }
    }
    crc
}

/// An RTU frame: unit, PDU, CRC.
pub fn rtu_encode(unit: u8, pdu: &[u8]) -> Vec<u8> {
    let mut b = Vec::with_capacity(pdu.len() + 3);
    b.push(unit);
    b.extend_from_slice(pdu);
    let crc = crc16(&b);
    b.extend_from_slice(&crc.to_le_bytes());
    b
}

/// One RTU frame split off the front of a receive buffer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RtuFrame {
    pub unit: u8,
    pub pdu: Vec<u8>,
}

/// Splits the frame at the front of `buf`: `None` while it is incomplete, else the frame
/// (or why it is not one) and the bytes it took. A frame whose function this map does not
/// know takes the whole buffer (RTU frames such a frame by the line's silence).
pub fn rtu_split(buf: &[u8], side: Side) -> Option<(Result<RtuFrame, FrameError>, usize)> {
    if buf.len() < 2 {
        return None;
    }
    let n = match pdu_len(&buf[1..], side)? {
        Ok(n) => n + 3,
        Err(f) => return Some((Err(FrameError::UnknownFunction(f)), buf.len())),
    };
    if buf.len() < n {
        return None;
    }
    let got = u16::from_le_bytes([buf[n - 2], buf[n - 1]]);
    let want = crc16(&buf[..n - 2]);
    if got != want {
        return Some((Err(FrameError::Crc { got, want }), n));
    }
    Some((
        Ok(RtuFrame {
            unit: buf[0],
            pdu: buf[1..n - 2].to_vec(),
        }),
        n,
    ))
}

/// Bytes an RTU frame of `pdu_len` takes on the line.
pub fn rtu_len(pdu_len: usize) -> usize {
    pdu_len + 3
}

/// A Modbus TCP frame: MBAP header and PDU.
pub fn tcp_encode(transaction: u16, unit: u8, pdu: &[u8]) -> Vec<u8> {
    let mut b = Vec::with_capacity(pdu.len() + 7);
    b.extend_from_slice(&transaction.to_be_bytes());
    b.extend_from_slice(&0u16.to_be_bytes());
    b.extend_from_slice(&((pdu.len() + 1) as u16).to_be_bytes());
    b.push(unit);
    b.extend_from_slice(pdu);
    b
}

/// One TCP frame split off the front of a receive buffer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TcpFrame {
    pub transaction: u16,
    pub unit: u8,
    pub pdu: Vec<u8>,
}

/// Splits the frame at the front of `buf`: `None` while it is incomplete; an error means
/// the stream cannot be framed any more (close it).
pub fn tcp_split(buf: &[u8]) -> Option<Result<(TcpFrame, usize), FrameError>> {
    if buf.len() < 7 {
        return None;
    }
    let protocol = be16(buf, 2);
    if protocol != 0 {
        return Some(Err(FrameError::Protocol(protocol)));
    }
    let len = be16(buf, 4) as usize;
    if !(2..=254).contains(&len) {
        return Some(Err(FrameError::Length(len)));
    }
    let n = 6 + len;
    if buf.len() < n {
        return None;
    }
    Some(Ok((
        TcpFrame {
            transaction: be16(buf, 0),
            unit: buf[6],
            pdu: buf[7..n].to_vec(),
        },
        n,
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_crc_is_modbus_and_goes_low_byte_first() {
        // Read 2 registers from 0 on unit 1: the textbook frame 01 03 00 00 00 02 C4 0B.
        let f = rtu_encode(1, &Request::Read { addr: 0, count: 2 }.pdu());
        assert_eq!(f, [0x01, 0x03, 0x00, 0x00, 0x00, 0x02, 0xC4, 0x0B]);
        assert_eq!(crc16(b"123456789"), 0x4B37);
    }

    #[test]
    fn requests_and_replies_round_trip_through_both_envelopes() {
        let reqs = [
            Request::Read { addr: 7, count: 16 },
            Request::WriteSingle {
                addr: 5,
                value: 0xBEEF,
            },
            Request::Write {
                addr: 32,
                words: (0..123).collect(),
            },
            Request::ReadWrite {
                read_addr: 0,
                read_count: 16,
                write_addr: 5,
                words: vec![1, 0, 64],
            },
        ];
        for r in &reqs {
            let bytes = rtu_encode(9, &r.pdu());
            let (f, n) = rtu_split(&bytes, Side::Request).unwrap();
            assert_eq!(n, bytes.len());
            let f = f.unwrap();
            assert_eq!((f.unit, Request::from_pdu(&f.pdu).unwrap()), (9, r.clone()));
            let tcp = tcp_encode(0x1234, 1, &r.pdu());
            let (t, n) = tcp_split(&tcp).unwrap().unwrap();
            assert_eq!((t.transaction, n), (0x1234, tcp.len()));
            assert_eq!(Request::from_pdu(&t.pdu).unwrap(), r.clone());
        }
        let resps = [
            Response::Read(vec![1, 2, 3]),
            Response::ReadWrite(vec![9; 16]),
            Response::Write {
                addr: 32,
                count: 123,
            },
            Response::WriteSingle { addr: 5, value: 0 },
            Response::Exception {
                function: 0x10,
                code: 0x02,
            },
        ];
        for r in &resps {
            let bytes = rtu_encode(9, &r.pdu());
            // a reply arrives in two pieces: incomplete, then whole
            assert_eq!(rtu_split(&bytes[..bytes.len() - 1], Side::Reply), None);
            let (f, _) = rtu_split(&bytes, Side::Reply).unwrap();
            assert_eq!(Response::from_pdu(&f.unwrap().pdu).unwrap(), r.clone());
        }
    }

    #[test]
    fn a_reply_matches_only_its_own_request() {
        let read = Request::Read { addr: 0, count: 16 };
        assert!(read.check_reply(&Response::Read(vec![0; 16])).is_ok());
        assert!(read.check_reply(&Response::Read(vec![0; 17])).is_err());
        assert!(read.check_reply(&Response::ReadWrite(vec![0; 16])).is_err());
        let write = Request::Write {
            addr: 6,
            words: vec![0, 5],
        };
        assert!(write
            .check_reply(&Response::Write { addr: 6, count: 2 })
            .is_ok());
        assert!(write
            .check_reply(&Response::Write { addr: 5, count: 2 })
            .is_err());
        assert!(write
            .check_reply(&Response::Exception {
                function: 0x10,
                code: 6
            })
            .is_ok());
        assert!(write
            .check_reply(&Response::Exception {
                function: 0x03,
                code: 6
            })
            .is_err());
    }

    #[test]
    fn a_damaged_rtu_frame_is_told_apart() {
        let mut bytes = rtu_encode(1, &Response::Read(vec![1, 2]).pdu());
        bytes[4] ^= 0x01;
        let (f, n) = rtu_split(&bytes, Side::Reply).unwrap();
        assert!(matches!(f, Err(FrameError::Crc { .. })));
        assert_eq!(n, bytes.len());
        let (f, n) = rtu_split(&[1, 0x2B, 0, 0, 0], Side::Request).unwrap();
        assert_eq!((f, n), (Err(FrameError::UnknownFunction(0x2B)), 5));
    }
}
