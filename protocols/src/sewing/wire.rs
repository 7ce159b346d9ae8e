//! The pattern transfer protocol's frames and messages, shared by the link and the simulated machine (see docs/sewing-link.md).
//!
//! Frame: `7E | len (u16 LE) | seq | type | payload[len] | crc (u16 BE)`, the CRC-16/CCITT-FALSE
//! of everything between the start byte and the CRC. The receiver scans for 0x7E, checks that
//! the length is at most [`MAX_PAYLOAD`] and the CRC matches; on any failure it drops that one
//! start byte and scans on (resynchronisation), so a corrupted or lost byte costs one frame.

use super::crc16_ccitt_false;

pub const SOF: u8 = 0x7E;
/// The largest payload of a frame.
pub const MAX_PAYLOAD: usize = 1024;
/// The most records per upload chunk (9 bytes each): 64 × 9 + 6 = 582 bytes of payload. The
/// link halves its chunks after a chunk had to be sent again (down to 4) and doubles them
/// after 8 clean ones.
pub const CHUNK_RECORDS: usize = 64;
/// The fewest records per chunk the link shrinks to on a noisy line.
pub const MIN_CHUNK_RECORDS: usize = 4;
/// The most LOAD_CHUNK frames the link keeps in flight when the machine allows a window
/// (INFO's window byte); two keep a line busy, more only waste frames behind a damaged one.
pub const HOST_WINDOW: u8 = 2;

/// Host → machine requests.
pub mod req {
    /// → ACK: area min x, min y, max x, max y (i32 LE, 0.1 mm), max stitch (u16 LE, 0.1 mm),
    /// stitches per minute (u16 LE), and from protocol version 2 on the upload window (u8):
    /// how many LOAD_CHUNK frames the machine takes in flight (absent: 1).
    pub const INFO: u8 = 0x01;
    /// total records (u32 LE), pattern CRC-32 (u32 LE): forget any pattern, expect chunks.
    pub const LOAD_BEGIN: u8 = 0x10;
    /// offset (u32 LE, index of the first record), count (u16 LE), count × 9-byte records.
    /// → ACK (version 2: with the records loaded so far, u32 LE).
    pub const LOAD_CHUNK: u8 = 0x11;
    /// check count, CRC and every record (grid, max stitch, area); only then may it sew.
    pub const LOAD_END: u8 = 0x12;
    /// start at (u32 LE record index), pattern CRC-32 (u32 LE): sew from that record on.
    pub const START: u8 = 0x20;
    /// hold after the current stitch.
    pub const STOP: u8 = 0x21;
    /// continue after a hold or a thread break.
    pub const RESUME: u8 = 0x22;
    /// stop sewing and go idle (the pattern stays loaded).
    pub const ABORT: u8 = 0x23;
    /// → ACK: [`super::Status`].
    pub const STATUS: u8 = 0x30;
}

/// Machine → host replies (each carries the sequence number of the request it answers).
pub mod reply {
    /// Done: payload = request type, then the request's data.
    pub const ACK: u8 = 0x06;
    /// A frame arrived corrupted (bad CRC), or (version 2) its bytes stopped coming before
    /// its length was reached: send it again. Its sequence number is the damaged frame's,
    /// not to be trusted.
    pub const NAK: u8 = 0x15;
    /// Well-formed but refused: payload = request type, reason code, UTF-8 text.
    pub const REFUSED: u8 = 0x18;
}

/// Why a machine refused a request.
pub mod refusal {
    pub const BAD_REQUEST: u8 = 1;
    pub const WRONG_OFFSET: u8 = 2;
    pub const PATTERN_INVALID: u8 = 3;
    pub const NO_PATTERN: u8 = 4;
    pub const BUSY: u8 = 5;
}

/// One frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    pub seq: u8,
    pub kind: u8,
    pub payload: Vec<u8>,
}

impl Frame {
    pub fn new(seq: u8, kind: u8, payload: Vec<u8>) -> Self {
        Frame { seq, kind, payload }
    }
    /// The frame's bytes on the line.
    pub fn encode(&self) -> Vec<u8> {
        debug_assert!(self.payload.len() <= MAX_PAYLOAD);
        let mut b = Vec::with_capacity(self.payload.len() + 7);
        b.push(SOF);
        b.extend_from_slice(&(self.payload.len() as u16).to_le_bytes());
        b.push(self.seq);
        b.push(self.kind);
        b.extend_from_slice(&self.payload);
        let crc = crc16_ccitt_false(&b[1..]);
        b.extend_from_slice(&crc.to_be_bytes());
        b
    }
}

/// What the decoder found.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Decoded {
    Frame(Frame),
    /// A frame-shaped run of bytes whose CRC did not match; `seq` is what its sequence byte
    /// said (not to be trusted).
    Corrupt {
        seq: u8,
    },
}

/// Reassembles frames from a byte stream, resynchronising after noise.
#[derive(Default, Debug)]
pub struct Decoder {
    buf: Vec<u8>,
    /// Frames found by `resync_on_idle`, handed out by `next` first.
    ready: std::collections::VecDeque<Decoded>,
}

impl Decoder {
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }
    /// The next complete frame (or corrupt frame), or None until more bytes arrive.
    pub fn next_frame(&mut self) -> Option<Decoded> {
        if let Some(d) = self.ready.pop_front() {
            return Some(d);
        }
        self.scan()
    }
    fn scan(&mut self) -> Option<Decoded> {
        loop {
            let start = match self.buf.iter().position(|&b| b == SOF) {
                Some(i) => i,
                None => {
                    self.buf.clear();
                    return None;
                }
            };
            self.buf.drain(..start);
            if self.buf.len() < 5 {
                return None;
            }
            let len = u16::from_le_bytes([self.buf[1], self.buf[2]]) as usize;
            if len > MAX_PAYLOAD {
                self.buf.drain(..1);
                continue;
            }
            let total = len + 7;
            if self.buf.len() < total {
                return None;
            }
            let crc = u16::from_be_bytes([self.buf[total - 2], self.buf[total - 1]]);
            if crc16_ccitt_false(&self.buf[1..total - 2]) != crc {
                let seq = self.buf[3];
                self.buf.drain(..1);
                return Some(Decoded::Corrupt { seq });
            }
            let f = Frame {
                seq: self.buf[3],
                kind: self.buf[4],
                payload: self.buf[5..total - 2].to_vec(),
            };
            self.buf.drain(..total);
            return Some(Decoded::Frame(f));
        }
    }
    /// The line went quiet with a partial frame pending. Senders write whole frames, so
    /// nothing pending can still complete: its length was corrupted or a byte was lost. Drop
    /// start bytes one by one, keeping any whole frame that was stuck behind the bad one,
    /// until the buffer is empty.
    ///
    /// Returns the sequence byte of the frame that timed out (not to be trusted), when there
    /// was one: a machine answers it with a NAK.
    pub fn resync_on_idle(&mut self) -> Option<u8> {
        let stuck = (self.buf.first() == Some(&SOF)).then(|| self.buf.get(3).copied().unwrap_or(0));
        while !self.buf.is_empty() {
            self.buf.drain(..1);
            while let Some(d) = self.scan() {
                self.ready.push_back(d);
            }
        }
        stuck
    }
    pub fn clear(&mut self) {
        self.buf.clear();
        self.ready.clear();
    }
    pub fn pending(&self) -> usize {
        self.buf.len()
    }
}

/// The machine's state, as the status reply reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SewingState {
    /// No verified pattern (after power-up or while loading).
    NoPattern = 0,
    /// A verified pattern, not sewing.
    Ready = 1,
    Sewing = 2,
    /// Held on request; RESUME continues.
    Held = 3,
    /// The thread broke: the machine waits for the operator; RESUME continues at the same stitch.
    ThreadBreak = 4,
    /// The pattern is sewn to its end.
    Done = 5,
}

impl SewingState {
    pub fn from_code(c: u8) -> Option<SewingState> {
        Some(match c {
            0 => SewingState::NoPattern,
            1 => SewingState::Ready,
            2 => SewingState::Sewing,
            3 => SewingState::Held,
            4 => SewingState::ThreadBreak,
            5 => SewingState::Done,
            _ => return None,
        })
    }
    pub fn name(self) -> &'static str {
        match self {
            SewingState::NoPattern => "NoPattern",
            SewingState::Ready => "Ready",
            SewingState::Sewing => "Sewing",
            SewingState::Held => "Held",
            SewingState::ThreadBreak => "ThreadBreak",
            SewingState::Done => "Done",
        }
    }
}

/// The status reply: 22 bytes after the request type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Status {
    pub state: SewingState,
    /// Records completed: the index of the next record to sew. Kept through a power loss.
    pub counter: u32,
    /// Frame position, 0.1 mm.
    pub x: i32,
    pub y: i32,
    pub thread_break: bool,
    pub needle_down: bool,
    /// Held at a colour-change or stop record of the pattern: the machine waits for the
    /// operator (a thread to change) and RESUME sews on (flag bit 2).
    pub operator_stop: bool,
    /// Length and CRC-32 of the loaded (or last) pattern; 0 when none was ever loaded.
    pub pattern_len: u32,
    pub pattern_crc: u32,
}

impl Status {
    pub fn encode(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(22);
        b.push(self.state as u8);
        b.extend_from_slice(&self.counter.to_le_bytes());
        b.extend_from_slice(&self.x.to_le_bytes());
        b.extend_from_slice(&self.y.to_le_bytes());
        b.push(
            self.thread_break as u8
                | (self.needle_down as u8) << 1
                | (self.operator_stop as u8) << 2,
        );
        b.extend_from_slice(&self.pattern_len.to_le_bytes());
        b.extend_from_slice(&self.pattern_crc.to_le_bytes());
        b
    }
    pub fn decode(b: &[u8]) -> Option<Status> {
        if b.len() < 22 {
            return None;
        }
        let u32at = |i: usize| u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
        Some(Status {
            state: SewingState::from_code(b[0])?,
            counter: u32at(1),
            x: u32at(5) as i32,
            y: u32at(9) as i32,
            thread_break: b[13] & 1 != 0,
            needle_down: b[13] & 2 != 0,
            operator_stop: b[13] & 4 != 0,
            pattern_len: u32at(14),
            pattern_crc: u32at(18),
        })
    }
}

/// The machine's description, as the info reply reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Info {
    /// Sewing area, 0.1 mm.
    pub min_x: i32,
    pub min_y: i32,
    pub max_x: i32,
    pub max_y: i32,
    /// The longest stitch or jump one record may make, 0.1 mm.
    pub max_stitch: u16,
    pub spm: u16,
    /// How many LOAD_CHUNK frames the machine takes in flight; `None` for a machine of
    /// protocol version 1, whose INFO has no window byte (it takes one).
    pub window: Option<u8>,
}

impl Info {
    pub fn encode(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(21);
        for v in [self.min_x, self.min_y, self.max_x, self.max_y] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b.extend_from_slice(&self.max_stitch.to_le_bytes());
        b.extend_from_slice(&self.spm.to_le_bytes());
        if let Some(w) = self.window {
            b.push(w);
        }
        b
    }
    /// The frames the machine takes in flight (1 when it does not say, or says 0).
    pub fn window(&self) -> u8 {
        self.window.unwrap_or(1).max(1)
    }
    pub fn decode(b: &[u8]) -> Option<Info> {
        if b.len() < 20 {
            return None;
        }
        let i32at = |i: usize| i32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
        Some(Info {
            min_x: i32at(0),
            min_y: i32at(4),
            max_x: i32at(8),
            max_y: i32at(12),
            max_stitch: u16::from_le_bytes([b[16], b[17]]),
            spm: u16::from_le_bytes([b[18], b[19]]),
            window: b.get(20).copied(),
        })
    }
    pub fn contains(&self, x: i32, y: i32) -> bool {
        x >= self.min_x && x <= self.max_x && y >= self.min_y && y <= self.max_y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_survive_noise_before_and_between_them() {
        let a = Frame::new(7, req::STATUS, vec![]);
        let b = Frame::new(8, req::LOAD_CHUNK, vec![SOF, 1, 2, 3, SOF]);
        let mut line = vec![0x00, SOF, 0xFF, SOF];
        line.extend(a.encode());
        let mut bad = b.encode();
        bad[6] ^= 0x10;
        line.extend(bad);
        line.extend(b.encode());
        let mut d = Decoder::default();
        let mut got = vec![];
        for byte in line {
            d.push(&[byte]);
            while let Some(x) = d.next_frame() {
                got.push(x);
            }
        }
        // the noise `7E 7E 00` reads as a 126-byte frame: only the line going quiet unblocks it
        assert!(d.pending() > 0);
        assert!(
            d.resync_on_idle().is_some(),
            "the stuck frame is named for a NAK"
        );
        while let Some(x) = d.next_frame() {
            got.push(x);
        }
        assert_eq!(d.pending(), 0);
        let frames: Vec<Frame> = got
            .into_iter()
            .filter_map(|x| match x {
                Decoded::Frame(f) => Some(f),
                Decoded::Corrupt { .. } => None,
            })
            .collect();
        assert_eq!(frames, vec![a, b]);
    }
}
