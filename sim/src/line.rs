//! Serial-line timing for simulators: ten bits a byte at the baud rate, RTU's 3.5-character silence, and paced in-memory cables that run in real time or in tokio's paused time.
//!
//! A test that runs under `#[tokio::test(start_paused = true)]` on a [`cable`] gets a line
//! whose every byte takes exactly its time on the simulated clock: durations measured with
//! `tokio::time::Instant` are then the line's time, deterministic and independent of the
//! machine the test runs on.

use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, DuplexStream};
use tokio::time::Instant;

/// Bytes buffered in each direction of an in-memory line (a UART driver's buffer).
const BUFFER: usize = 64 * 1024;
/// Bytes a pump moves per step: the delivery granularity (1.4 ms at 115200 baud).
const STEP: usize = 16;
/// A pump that wakes up this much late still counts the line as busy, so that timer
/// granularity does not slow the line below its baud rate.
const SLACK: Duration = Duration::from_millis(2);

/// Time of one character (start bit, 8 data bits, stop bit) at `baud`.
pub fn char_time(baud: u32) -> Duration {
    Duration::from_secs_f64(10.0 / baud.max(1) as f64)
}

/// Time of `n` characters at `baud`.
pub fn chars(baud: u32, n: f64) -> Duration {
    Duration::from_secs_f64(n * 10.0 / baud.max(1) as f64)
}

/// The silence that ends a Modbus RTU frame: 3.5 characters.
pub fn t35(baud: u32) -> Duration {
    chars(baud, 3.5)
}

/// Whether tokio's clock is paused (a `start_paused` test): time then moves only when every
/// task waits, so a thread that sleeps does not move it.
pub fn clock_is_paused() -> bool {
    let before = Instant::now();
    std::thread::sleep(Duration::from_micros(100));
    Instant::now() == before
}

/// Sleeps until `due` to within a few tens of microseconds. tokio's timers tick in whole
/// milliseconds, which at 115200 baud is 11 characters; so in real time the last stretch
/// is slept on the thread (blocking it for at most 1.5 ms). In paused time (`paused`) the
/// timer alone is exact.
pub async fn sleep_until_precise(due: Instant, paused: bool) {
    const COARSE: Duration = Duration::from_micros(1500);
    if paused {
        tokio::time::sleep_until(due).await;
        return;
    }
    if let Some(early) = due.checked_sub(COARSE) {
        if early > Instant::now() {
            tokio::time::sleep_until(early).await;
        }
    }
    let now = Instant::now();
    if due > now {
        std::thread::sleep(due - now);
    }
}

/// Puts a serial line of `baud` in front of `inner`: bytes written to the returned stream
/// reach `inner` no faster than the line carries them, and bytes from `inner` reach the
/// reader likewise. Spawns two pump tasks on the current runtime.
pub fn paced<S>(inner: S, baud: u32) -> DuplexStream
where
    S: AsyncRead + AsyncWrite + Send + 'static,
{
    let (outer, mine) = tokio::io::duplex(BUFFER);
    let (mine_r, mine_w) = tokio::io::split(mine);
    let (in_r, in_w) = tokio::io::split(inner);
    let byte = char_time(baud);
    tokio::spawn(pump(in_r, mine_w, byte));
    tokio::spawn(pump(mine_r, in_w, byte));
    outer
}

/// An in-memory null-modem cable: (host end, device end), paced at `baud` both ways when
/// given, instant otherwise.
pub fn cable(baud: Option<u32>) -> (DuplexStream, DuplexStream) {
    let (a, b) = tokio::io::duplex(BUFFER);
    match baud {
        Some(baud) => (paced(a, baud), b),
        None => (a, b),
    }
}

/// Which way bytes went through a [`Tap`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// Written by the side holding the tap (the host).
    Sent,
    /// Read by it.
    Received,
}

/// Bytes that went through a [`Tap`], when (tokio's clock) and which way.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Tapped {
    pub at: Instant,
    pub direction: Direction,
    pub bytes: Vec<u8>,
}

/// A stream that records every byte written to and read from it: the transcripts of the
/// protocol documents' example sessions. It can also damage one write on its way out.
pub struct Tap<S> {
    inner: S,
    log: std::sync::Arc<std::sync::Mutex<Vec<Tapped>>>,
    writes: usize,
    /// (write number from 1, byte index, bits to flip)
    flip: Option<(usize, usize, u8)>,
}

impl<S> Tap<S> {
    /// The tapped stream and a handle on its record.
    pub fn new(inner: S) -> (Tap<S>, std::sync::Arc<std::sync::Mutex<Vec<Tapped>>>) {
        let log = std::sync::Arc::default();
        (
            Tap {
                inner,
                log: std::sync::Arc::clone(&log),
                writes: 0,
                flip: None,
            },
            log,
        )
    }
    /// Flips the bits `mask` of byte `at` of the `nth` write (counting from 1), as line
    /// noise would; the record shows the damaged bytes.
    pub fn flipping(mut self, nth: usize, at: usize, mask: u8) -> Self {
        self.flip = Some((nth, at, mask));
        self
    }
    fn record(&self, direction: Direction, bytes: &[u8]) {
        if bytes.is_empty() {
            return;
        }
        if let Ok(mut log) = self.log.lock() {
            log.push(Tapped {
                at: Instant::now(),
                direction,
                bytes: bytes.to_vec(),
            });
        }
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for Tap<S> {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let r = std::pin::Pin::new(&mut self.inner).poll_read(cx, buf);
        if let std::task::Poll::Ready(Ok(())) = r {
            let got = buf.filled()[before..].to_vec();
            self.record(Direction::Received, &got);
        }
        r
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Tap<S> {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        data: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        let mut damaged = None;
        if let Some((nth, at, mask)) = self.flip {
            if self.writes + 1 == nth && at < data.len() {
                let mut d = data.to_vec();
                d[at] ^= mask;
                damaged = Some(d);
            }
        }
        let bytes = damaged.as_deref().unwrap_or(data);
        let r = std::pin::Pin::new(&mut self.inner).poll_write(cx, bytes);
        if let std::task::Poll::Ready(Ok(n)) = r {
            self.writes += 1;
            self.record(Direction::Sent, &bytes[..n]);
        }
        r
    }
    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.inner).poll_flush(cx)
    }
    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

/// Hex bytes, `per_line` a line, each line after the first indented by `indent` spaces.
pub fn hex_lines(bytes: &[u8], per_line: usize, indent: usize) -> String {
    bytes
        .chunks(per_line)
        .map(|c| {
            c.iter()
                .map(|b| format!("{b:02X}"))
                .collect::<Vec<_>>()
                .join(" ")
        })
        .collect::<Vec<_>>()
        .join(&format!("\n{}", " ".repeat(indent)))
}

/// Moves bytes from `from` to `to`, each taking `byte` on the line.
async fn pump<R, W>(mut from: R, mut to: W, byte: Duration)
where
    R: AsyncRead + Unpin,
    W: AsyncWrite + Unpin,
{
    let mut buf = [0u8; STEP];
    let mut free = Instant::now();
    loop {
        let n = match from.read(&mut buf).await {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        let now = Instant::now();
        // A line still busy (or only just free) carries on from where it is; an idle one
        // starts now.
        let start = if free + SLACK < now { now } else { free };
        free = start + byte * n as u32;
        tokio::time::sleep_until(free).await;
        if to.write_all(&buf[..n]).await.is_err() {
            break;
        }
    }
    let _ = to.shutdown().await;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn a_paced_cable_carries_bytes_at_the_baud_rate_both_ways() {
        let (mut host, mut dev) = cable(Some(9600));
        let t = Instant::now();
        host.write_all(&[0x55; 960]).await.unwrap();
        let mut got = vec![0u8; 960];
        dev.read_exact(&mut got).await.unwrap();
        // 960 characters at 960 characters a second (tokio's timers tick in milliseconds)
        let near = |d: Duration, want: Duration| d.abs_diff(want) <= Duration::from_millis(2);
        assert!(
            near(t.elapsed(), Duration::from_secs(1)),
            "{:?}",
            t.elapsed()
        );
        let t = Instant::now();
        dev.write_all(&[0xAA; 96]).await.unwrap();
        let mut got = vec![0u8; 96];
        host.read_exact(&mut got).await.unwrap();
        assert!(
            near(t.elapsed(), Duration::from_millis(100)),
            "{:?}",
            t.elapsed()
        );
        assert_eq!(t35(9600), Duration::from_secs_f64(35.0 / 9600.0));
    }
}
