//! What a device sends is untrusted: lines are bounded in length, text is stripped of control
//! characters before it reaches a log, an event or a terminal, and a device that floods its
//! link is cut off with an error that says so.
//!
//! Pure pieces (no I/O, time handed in) so each is tested alone: [`printable`], [`LineSplitter`],
//! [`FloodGuard`]; and [`Guarded`], an `AsyncRead + AsyncWrite` wrapper that applies the flood
//! guard to any transport (every serial port the links open goes through it).

use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::time::Instant;

/// The longest line a line-based device (GRBL) may send, in bytes, line end excluded. GRBL's
/// longest reports (`$I`, `[GC:…]`, a full status report) are under 200 bytes.
pub const MAX_LINE: usize = 1024;

/// The most bytes a device may send within [`FLOOD_WINDOW`]: about 10 times what a serial
/// line at 921600 baud can carry, so only a broken or hostile device reaches it.
pub const FLOOD_BYTES: usize = 1 << 20;
/// The window the flood guard counts bytes in.
pub const FLOOD_WINDOW: Duration = Duration::from_secs(1);

/// The most characters of device text kept for a message.
pub const MAX_TEXT: usize = 512;

/// Device text made safe for a log line, an event or a terminal: control characters (C0, DEL,
/// C1), bidirectional and other invisible formatting characters are dropped (a tab becomes a
/// space), and the text is cut to `max` characters with `…` at the end.
pub fn printable(text: &str, max: usize) -> String {
    let mut out = String::with_capacity(text.len().min(max * 4));
    let mut kept = 0usize;
    for c in text.chars() {
        let c = match c {
            '\t' => ' ',
            c if c.is_control() || is_invisible_format(c) => continue,
            c => c,
        };
        if kept == max {
            out.push('…');
            return out;
        }
        out.push(c);
        kept += 1;
    }
    out
}

/// Unicode format characters that change how the text around them is shown (bidirectional
/// overrides and isolates, zero-width characters, the BOM).
fn is_invisible_format(c: char) -> bool {
    matches!(c,
        '\u{00AD}' | '\u{061C}' | '\u{180E}'
        | '\u{200B}'..='\u{200F}'
        | '\u{202A}'..='\u{202E}'
        | '\u{2060}'..='\u{2069}'
        | '\u{FEFF}'
        | '\u{FFF9}'..='\u{FFFB}')
}

/// Bytes as printable text: invalid UTF-8 becomes U+FFFD, then [`printable`].
pub fn printable_bytes(bytes: &[u8], max: usize) -> String {
    printable(&String::from_utf8_lossy(bytes), max)
}

/// A line longer than the splitter takes.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("the device sent a line longer than {max} bytes (it begins `{start}`): cut off")]
pub struct Overlong {
    pub max: usize,
    /// The line's first characters, printable.
    pub start: String,
}

/// Splits a byte stream into lines at `\n` or `\r`, dropping empty lines; each line is
/// decoded lossily and made [`printable`]. A line longer than its bound is an error: the
/// device is cut off rather than buffered without end.
#[derive(Debug)]
pub struct LineSplitter {
    max: usize,
    buf: Vec<u8>,
}

impl LineSplitter {
    pub fn new(max: usize) -> LineSplitter {
        LineSplitter {
            max,
            buf: Vec::new(),
        }
    }

    /// Takes `bytes` and hands each complete line to `line`; stops at the first overlong line.
    pub fn push(&mut self, bytes: &[u8], mut line: impl FnMut(String)) -> Result<(), Overlong> {
        for &b in bytes {
            if b == b'\n' || b == b'\r' {
                if !self.buf.is_empty() {
                    line(printable_bytes(&self.buf, self.max));
                    self.buf.clear();
                }
            } else if self.buf.len() >= self.max {
                let start = printable_bytes(&self.buf[..self.buf.len().min(40)], 40);
                self.buf.clear();
                return Err(Overlong {
                    max: self.max,
                    start,
                });
            } else {
                self.buf.push(b);
            }
        }
        Ok(())
    }

    /// Bytes of the line not yet ended.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }
}

/// The error of a device that sent more than its budget.
pub fn flood_error(bytes: usize, window: Duration) -> io::Error {
    io::Error::other(format!(
        "the device sent more than {bytes} bytes within {window:?}: cut off as flooding"
    ))
}

/// Counts the bytes a device sends per window; over the budget the device is flooding.
#[derive(Clone, Debug)]
pub struct FloodGuard {
    budget: usize,
    window: Duration,
    start: Option<Instant>,
    seen: usize,
}

impl FloodGuard {
    pub fn new(budget: usize, window: Duration) -> FloodGuard {
        FloodGuard {
            budget,
            window,
            start: None,
            seen: 0,
        }
    }

    /// Notes `n` bytes received at `now`; an error once a window holds more than the budget.
    pub fn note(&mut self, n: usize, now: Instant) -> io::Result<()> {
        match self.start {
            Some(s) if now.duration_since(s) < self.window => {}
            _ => {
                self.start = Some(now);
                self.seen = 0;
            }
        }
        self.seen = self.seen.saturating_add(n);
        if self.seen > self.budget {
            return Err(flood_error(self.budget, self.window));
        }
        Ok(())
    }
}

impl Default for FloodGuard {
    fn default() -> Self {
        FloodGuard::new(FLOOD_BYTES, FLOOD_WINDOW)
    }
}

/// A transport whose reads pass a [`FloodGuard`]: once the device floods, every read fails
/// with the flood error (the link reports it and is opened afresh for the next job).
pub struct Guarded<S> {
    inner: S,
    guard: FloodGuard,
    failed: bool,
}

impl<S> Guarded<S> {
    pub fn new(inner: S) -> Guarded<S> {
        Guarded::with_guard(inner, FloodGuard::default())
    }
    pub fn with_guard(inner: S, guard: FloodGuard) -> Guarded<S> {
        Guarded {
            inner,
            guard,
            failed: false,
        }
    }
    pub fn get_ref(&self) -> &S {
        &self.inner
    }
    pub fn get_mut(&mut self) -> &mut S {
        &mut self.inner
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for Guarded<S> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        if self.failed {
            return Poll::Ready(Err(flood_error(self.guard.budget, self.guard.window)));
        }
        let before = buf.filled().len();
        let this = &mut *self;
        match Pin::new(&mut this.inner).poll_read(cx, buf) {
            Poll::Ready(Ok(())) => {
                let n = buf.filled().len() - before;
                if let Err(e) = this.guard.note(n, Instant::now()) {
                    this.failed = true;
                    return Poll::Ready(Err(e));
                }
                Poll::Ready(Ok(()))
            }
            other => other,
        }
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Guarded<S> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write(cx, buf)
    }
    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }
    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn control_and_invisible_characters_never_reach_the_operator() {
        assert_eq!(
            printable("ok\x1b[2J\x07\u{202E}gnp.exe\u{9b}", 100),
            "ok[2Jgnp.exe"
        );
        assert_eq!(printable("a\tb", 100), "a b");
        assert_eq!(printable("abcdef", 3), "abc…");
        assert_eq!(printable_bytes(b"\xff\xfeok", 10), "\u{FFFD}\u{FFFD}ok");
    }

    #[test]
    fn lines_are_split_and_an_overlong_one_cuts_the_device_off() {
        let mut s = LineSplitter::new(8);
        let mut got = Vec::new();
        s.push(b"ok\r\n\nerror:2\nALA", |l| got.push(l)).unwrap();
        s.push(b"RM:1\n", |l| got.push(l)).unwrap();
        assert_eq!(got, ["ok", "error:2", "ALARM:1"]);
        let e = s.push(b"0123456789\n", |l| got.push(l)).unwrap_err();
        assert_eq!(e.max, 8);
        assert!(e.to_string().contains("longer than 8 bytes"), "{e}");
    }

    #[test]
    fn the_flood_guard_counts_per_window() {
        let t0 = Instant::now();
        let mut g = FloodGuard::new(100, Duration::from_secs(1));
        g.note(60, t0).unwrap();
        g.note(40, t0 + Duration::from_millis(500)).unwrap();
        // a new window starts the count again
        g.note(90, t0 + Duration::from_millis(1001)).unwrap();
        let e = g.note(11, t0 + Duration::from_millis(1500)).unwrap_err();
        assert!(e.to_string().contains("cut off as flooding"), "{e}");
    }
}
