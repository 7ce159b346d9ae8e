//! SLCAN (Lawicel ASCII), the line protocol of USB-CAN adapters: one codec for both ends —
//! the host that opens an adapter (machlink's master) and the adapter itself (the simulator).
//!
//! Host to adapter: `Sn` bit rate (S0 10k … S8 1M), `O` open, `L` listen only, `C` close,
//! `tiiildd…` (11-bit id, length digit, data in hex) and `Tiiiiiiiildd…` (29-bit) to transmit,
//! `riiil` / `Riiiiiiiil` remote frames; each line ends with CR. The adapter answers CR (OK),
//! `z`/`Z` CR (frame queued, some adapters) or BEL (error), and reports received frames as the
//! same `t`/`T`/`r`/`R` lines, optionally followed by a 4-digit timestamp. Lines that are none
//! of these are noise and ignored; a line longer than [`MAX_LINE`] is dropped whole.

use super::bus::{BusError, CanBus, FrameSink};
use super::frame::CanFrame;
use futures::future::BoxFuture;
use std::collections::VecDeque;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadHalf, WriteHalf};

/// The longest line kept (the longest valid one, `T` + 8 + 1 + 16 + a 4-digit timestamp, is 30).
pub const MAX_LINE: usize = 40;

/// One line of SLCAN, from either end.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SlcanLine {
    /// A frame: to transmit (host to adapter) or received (adapter to host).
    Frame(CanFrame),
    /// An empty line ended by CR: the adapter's OK.
    Ok,
    /// BEL: the adapter's error.
    Error,
    /// `z` or `Z`: a frame was queued for transmission.
    Queued,
    /// `O`: open the channel.
    Open,
    /// `L`: open listening only.
    ListenOnly,
    /// `C`: close the channel.
    Close,
    /// `Sn`: the bit rate, in bit/s.
    Bitrate(u32),
    /// Anything else (a version query, noise), as text.
    Other(String),
}

/// Bit rates by their `Sn` digit.
const BITRATES: [u32; 9] = [
    10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000,
];

/// The `Sn` digit of a bit rate (750 kbit/s is taken as S7 too, as python-can does).
pub fn bitrate_code(bitrate: u32) -> Option<u8> {
    if bitrate == 750_000 {
        return Some(7);
    }
    BITRATES.iter().position(|&b| b == bitrate).map(|i| i as u8)
}

/// Splits a byte stream into lines: CR ends a line, BEL is an error line of its own, LF is
/// ignored, and a line longer than [`MAX_LINE`] is dropped up to its end.
#[derive(Debug, Default)]
pub struct LineDecoder {
    buf: Vec<u8>,
    overlong: bool,
    /// Lines dropped as too long.
    pub dropped: u64,
}

impl LineDecoder {
    pub fn new() -> LineDecoder {
        LineDecoder::default()
    }

    /// Takes `bytes` and appends every line they complete to `out`.
    pub fn push(&mut self, bytes: &[u8], out: &mut Vec<SlcanLine>) {
        for &b in bytes {
            match b {
                b'\r' => {
                    if self.overlong {
                        self.overlong = false;
                        self.dropped += 1;
                    } else {
                        out.push(parse_line(&self.buf));
                    }
                    self.buf.clear();
                }
                0x07 => {
                    if !self.buf.is_empty() || self.overlong {
                        self.dropped += 1;
                    }
                    self.buf.clear();
                    self.overlong = false;
                    out.push(SlcanLine::Error);
                }
                b'\n' => {}
                _ if self.overlong => {}
                _ if self.buf.len() >= MAX_LINE => {
                    self.overlong = true;
                    self.buf.clear();
                }
                _ => self.buf.push(b),
            }
        }
    }
}

fn hex(bytes: &[u8]) -> Option<u32> {
    if bytes.is_empty() || bytes.len() > 8 {
        return None;
    }
    let mut v = 0u32;
    for &b in bytes {
        v = (v << 4) | (b as char).to_digit(16)?;
    }
    Some(v)
}

fn parse_frame(line: &[u8]) -> Option<CanFrame> {
    let (extended, remote) = match line.first()? {
        b't' => (false, false),
        b'T' => (true, false),
        b'r' => (false, true),
        b'R' => (true, true),
        _ => return None,
    };
    let id_len = if extended { 8 } else { 3 };
    let id = hex(line.get(1..1 + id_len)?)?;
    let len_at = 1 + id_len;
    let len = (*line.get(len_at)? as char).to_digit(10)? as usize;
    if len > 8 {
        return None;
    }
    let data_hex = if remote { 0 } else { 2 * len };
    let rest = line.get(len_at + 1..)?;
    // the data, then nothing or a 4-digit timestamp
    if rest.len() != data_hex && rest.len() != data_hex + 4 {
        return None;
    }
    hex(&rest[data_hex..]).or((rest.len() == data_hex).then_some(0))?;
    if remote {
        return CanFrame::remote(id, extended, len as u8).ok();
    }
    let mut data = [0u8; 8];
    for (i, d) in data.iter_mut().enumerate().take(len) {
        *d = hex(&rest[2 * i..2 * i + 2])? as u8;
    }
    CanFrame::with_id(id, extended, &data[..len]).ok()
}

/// Reads one line (without its CR).
pub fn parse_line(line: &[u8]) -> SlcanLine {
    if let Some(f) = parse_frame(line) {
        return SlcanLine::Frame(f);
    }
    match line {
        [] => SlcanLine::Ok,
        [b'z'] | [b'Z'] => SlcanLine::Queued,
        [b'O'] => SlcanLine::Open,
        [b'L'] => SlcanLine::ListenOnly,
        [b'C'] => SlcanLine::Close,
        [b'S', d] if (b'0'..=b'8').contains(d) => SlcanLine::Bitrate(BITRATES[(d - b'0') as usize]),
        _ => SlcanLine::Other(String::from_utf8_lossy(line).into_owned()),
    }
}

/// Appends `frame` as a line (`t…`/`T…`/`r…`/`R…` and CR).
pub fn encode_frame(frame: &CanFrame, out: &mut Vec<u8>) {
    use std::io::Write;
    let tag = match (frame.is_extended(), frame.is_remote()) {
        (false, false) => 't',
        (true, false) => 'T',
        (false, true) => 'r',
        (true, true) => 'R',
    };
    if frame.is_extended() {
        let _ = write!(out, "{tag}{:08X}{}", frame.id(), frame.len());
    } else {
        let _ = write!(out, "{tag}{:03X}{}", frame.id(), frame.len());
    }
    for b in frame.data() {
        let _ = write!(out, "{b:02X}");
    }
    out.push(b'\r');
}

/// The line of a host command: `Sn`, `O`, `L`, `C` (a frame goes through [`encode_frame`]).
pub fn encode_line(line: &SlcanLine, out: &mut Vec<u8>) {
    match line {
        SlcanLine::Frame(f) => return encode_frame(f, out),
        SlcanLine::Ok => {}
        SlcanLine::Error => {
            out.push(0x07);
            return;
        }
        SlcanLine::Queued => out.push(b'z'),
        SlcanLine::Open => out.push(b'O'),
        SlcanLine::ListenOnly => out.push(b'L'),
        SlcanLine::Close => out.push(b'C'),
        SlcanLine::Bitrate(b) => {
            out.push(b'S');
            out.push(b'0' + bitrate_code(*b).unwrap_or(6));
        }
        SlcanLine::Other(t) => out.extend_from_slice(t.as_bytes()),
    }
    out.push(b'\r');
}

/// How long the adapter may take to answer a command.
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(1);

/// A CAN bus through an SLCAN adapter on a byte stream (a serial port or a pty).
pub struct SlcanBus<S> {
    port: String,
    reader: ReadHalf<S>,
    writer: WriteHalf<S>,
    decoder: LineDecoder,
    lines: Vec<SlcanLine>,
    frames: VecDeque<CanFrame>,
    out: Vec<u8>,
    clock: Option<std::fs::File>,
}

/// Writes SLCAN lines to a serial port from the SYNC clock's thread (a duplicate of the
/// port's descriptor; the port is non-blocking, so a full buffer is waited out here).
pub struct SlcanSink {
    file: std::fs::File,
    buf: Vec<u8>,
}

impl FrameSink for SlcanSink {
    fn send_now(&mut self, frames: &[CanFrame]) -> std::io::Result<()> {
        use std::io::Write;
        self.buf.clear();
        for f in frames {
            encode_frame(f, &mut self.buf);
        }
        let mut at = 0;
        let give_up = std::time::Instant::now() + Duration::from_secs(1);
        while at < self.buf.len() {
            match self.file.write(&self.buf[at..]) {
                Ok(n) => at += n,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    if std::time::Instant::now() > give_up {
                        return Err(e);
                    }
                    std::thread::sleep(Duration::from_micros(50));
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }
}

impl<S: AsyncRead + AsyncWrite + Send + 'static> SlcanBus<S> {
    /// Closes the channel (in case an earlier program left it open), sets the bit rate and
    /// opens it; the adapter must answer OK to `Sn` and `O`.
    pub async fn open(stream: S, port: &str, bitrate: u32) -> Result<SlcanBus<S>, BusError> {
        let (reader, writer) = tokio::io::split(stream);
        let mut bus = SlcanBus {
            port: port.to_string(),
            reader,
            writer,
            decoder: LineDecoder::new(),
            lines: Vec::new(),
            frames: VecDeque::new(),
            out: Vec::new(),
            clock: None,
        };
        // closing a closed channel is an error on some adapters: its answer does not matter
        bus.command(SlcanLine::Close).await?;
        let _ = bus.reply(Duration::from_millis(200)).await;
        for cmd in [SlcanLine::Bitrate(bitrate), SlcanLine::Open] {
            let what = match &cmd {
                SlcanLine::Bitrate(b) => format!(
                    "the bit rate {b} bit/s (S{})",
                    bitrate_code(*b).unwrap_or(6)
                ),
                _ => "opening the channel (O)".to_string(),
            };
            bus.command(cmd).await?;
            match bus.reply(REPLY_TIMEOUT).await {
                Some(true) => {}
                Some(false) => {
                    return Err(BusError::Adapter {
                        port: port.to_string(),
                        what: format!("refused {what}"),
                    })
                }
                None => {
                    return Err(BusError::Adapter {
                        port: port.to_string(),
                        what: format!("did not answer {what} within {REPLY_TIMEOUT:?}"),
                    })
                }
            }
        }
        bus.frames.clear();
        Ok(bus)
    }

    async fn command(&mut self, line: SlcanLine) -> Result<(), BusError> {
        self.out.clear();
        encode_line(&line, &mut self.out);
        self.writer.write_all(&self.out).await?;
        self.writer.flush().await?;
        Ok(())
    }

    /// Waits for OK (true) or BEL (false); frames meanwhile are kept.
    async fn reply(&mut self, timeout: Duration) -> Option<bool> {
        let deadline = tokio::time::Instant::now() + timeout;
        let mut tmp = [0u8; 256];
        loop {
            for line in self.lines.drain(..) {
                match line {
                    SlcanLine::Ok => return Some(true),
                    SlcanLine::Error => return Some(false),
                    SlcanLine::Frame(f) => self.frames.push_back(f),
                    _ => {}
                }
            }
            let n = tokio::time::timeout_at(deadline, self.reader.read(&mut tmp))
                .await
                .ok()?
                .ok()?;
            if n == 0 {
                return None;
            }
            self.decoder.push(&tmp[..n], &mut self.lines);
        }
    }

    /// The same bus, with `file` (the port opened again, or its descriptor duplicated) as the
    /// SYNC clock's writer.
    pub fn with_clock_writer(mut self, file: std::fs::File) -> SlcanBus<S> {
        self.clock = Some(file);
        self
    }

    /// Closes the channel (`C`); the adapter's answer is not awaited.
    pub async fn close(&mut self) -> Result<(), BusError> {
        self.command(SlcanLine::Close).await
    }
}

impl<S: AsyncRead + AsyncWrite + Send + 'static> CanBus for SlcanBus<S> {
    fn send<'a>(&'a mut self, frame: &'a CanFrame) -> BoxFuture<'a, Result<(), BusError>> {
        Box::pin(async move {
            self.out.clear();
            encode_frame(frame, &mut self.out);
            self.writer.write_all(&self.out).await?;
            Ok(())
        })
    }

    fn recv(&mut self) -> BoxFuture<'_, Result<CanFrame, BusError>> {
        Box::pin(async move {
            let mut tmp = [0u8; 512];
            loop {
                if let Some(f) = self.frames.pop_front() {
                    return Ok(f);
                }
                let n = self.reader.read(&mut tmp).await?;
                if n == 0 {
                    return Err(BusError::Closed);
                }
                self.decoder.push(&tmp[..n], &mut self.lines);
                let mut refused = false;
                for line in self.lines.drain(..) {
                    match line {
                        SlcanLine::Frame(f) => self.frames.push_back(f),
                        SlcanLine::Error => refused = true,
                        _ => {}
                    }
                }
                if refused {
                    return Err(BusError::Adapter {
                        port: self.port.clone(),
                        what: "refused a frame (BEL): its queue is full or the bus is off".into(),
                    });
                }
            }
        })
    }

    fn frame_sink(&mut self) -> Option<Box<dyn FrameSink>> {
        let file = self.clock.as_ref()?.try_clone().ok()?;
        Some(Box::new(SlcanSink {
            file,
            buf: Vec::new(),
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(bytes: &[u8]) -> Vec<SlcanLine> {
        let mut d = LineDecoder::new();
        let mut out = Vec::new();
        d.push(bytes, &mut out);
        out
    }

    #[test]
    fn frames_round_trip_through_their_lines() {
        for f in [
            CanFrame::new(0x080, &[]).unwrap(),
            CanFrame::new(0x601, &[0x40, 0x00, 0x10, 0, 0, 0, 0, 0]).unwrap(),
            CanFrame::with_id(0x1ABC_DEF0, true, &[0xFF]).unwrap(),
            CanFrame::remote(0x701, false, 1).unwrap(),
            CanFrame::remote(0x1000_0000, true, 8).unwrap(),
        ] {
            let mut out = Vec::new();
            encode_frame(&f, &mut out);
            assert_eq!(lines(&out), vec![SlcanLine::Frame(f)], "{f}");
        }
        let mut out = Vec::new();
        encode_frame(&CanFrame::new(0x181, &[0x0A, 0xFF]).unwrap(), &mut out);
        assert_eq!(out, b"t18120AFF\r");
    }

    #[test]
    fn replies_commands_noise_and_timestamps_are_told_apart() {
        let got = lines(b"\r\x07z\rS8\rO\rC\rV1013\rt0801\rt0801123456\rt0800\rhello\n\r");
        assert_eq!(
            got,
            vec![
                SlcanLine::Ok,
                SlcanLine::Error,
                SlcanLine::Queued,
                SlcanLine::Bitrate(1_000_000),
                SlcanLine::Open,
                SlcanLine::Close,
                SlcanLine::Other("V1013".into()),
                SlcanLine::Other("t0801".into()),
                SlcanLine::Frame(CanFrame::new(0x080, &[0x12]).unwrap()),
                SlcanLine::Frame(CanFrame::new(0x080, &[]).unwrap()),
                SlcanLine::Other("hello".into()),
            ]
        );
    }

    #[test]
    fn an_overlong_line_is_dropped_whole_and_the_next_one_read() {
        let mut bytes = vec![b't'; 100];
        bytes.extend_from_slice(b"\rt0800\r");
        let mut d = LineDecoder::new();
        let mut out = Vec::new();
        d.push(&bytes, &mut out);
        assert_eq!(
            out,
            vec![SlcanLine::Frame(CanFrame::new(0x080, &[]).unwrap())]
        );
        assert_eq!(d.dropped, 1);
    }
}
