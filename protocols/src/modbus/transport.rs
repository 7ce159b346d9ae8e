//! The byte streams a Modbus link runs on: opening TCP and serial ports, RTU or TCP framing over any stream, one exchange at a time, late and stale replies told apart from the answer and drained.
//!
//! TCP tells replies apart by their transaction id. RTU has none, so after a request timed
//! out its reply is *owed*: it may still come, and it would look like the answer to the
//! next request of the same shape. Before the next request the wire therefore settles the
//! line: it discards whatever arrives until the line has been quiet for the quiet time,
//! then (given a [`Barrier`]) reads a few header registers with a register count that no
//! owed request has, discarding every frame until that read's own reply. A device answers
//! in the order it was asked, so once that reply is in, nothing owed can come any more.

use super::frame::{self, FrameError, Request, Response, Side};
use std::io;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

/// Anything a link can talk over: a serial port, a pty, a TCP stream, a test cable.
pub trait ByteStream: AsyncRead + AsyncWrite + Send + Unpin {}
impl<T: AsyncRead + AsyncWrite + Send + Unpin> ByteStream for T {}

/// How frames are delimited on the stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Framing {
    /// MBAP header with a transaction id.
    Tcp,
    /// Unit, PDU, CRC, with 3.5 characters of silence between frames at `baud`.
    Rtu { baud: u32 },
}

impl Framing {
    /// The silence between RTU frames (3.5 characters of 10 bits); zero on TCP.
    pub fn t35(self) -> Duration {
        match self {
            Framing::Tcp => Duration::ZERO,
            Framing::Rtu { baud } => Duration::from_secs_f64(35.0 / baud.max(1) as f64),
        }
    }
}

/// Parity of an RTU line.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Parity {
    #[default]
    None,
    Even,
    Odd,
}

/// Where a device is, for a transport that opens its own stream.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Endpoint {
    /// Modbus TCP to `host:port`.
    Tcp { host: String, port: u16 },
    /// Modbus RTU on a serial port (8 data bits, 1 stop bit).
    Serial {
        path: String,
        baud: u32,
        parity: Parity,
    },
}

impl Endpoint {
    pub fn framing(&self) -> Framing {
        match self {
            Endpoint::Tcp { .. } => Framing::Tcp,
            Endpoint::Serial { baud, .. } => Framing::Rtu { baud: *baud },
        }
    }

    /// Opens the stream: a TCP connection (within `timeout`, Nagle off) or the serial port.
    pub async fn open(&self, timeout: Duration) -> io::Result<Box<dyn ByteStream>> {
        match self {
            Endpoint::Tcp { host, port } => {
                let stream = tokio::time::timeout(
                    timeout,
                    tokio::net::TcpStream::connect((host.as_str(), *port)),
                )
                .await
                .map_err(|_| io::Error::from(io::ErrorKind::TimedOut))??;
                stream.set_nodelay(true)?;
                Ok(Box::new(stream))
            }
            Endpoint::Serial { path, baud, parity } => {
                Ok(Box::new(open_serial(path, *baud, *parity)?))
            }
        }
    }
}

/// Opens a serial port for RTU: 8 data bits, 1 stop bit, the given parity, no flow control,
/// with whatever the port had buffered thrown away.
pub fn open_serial(
    path: &str,
    baud: u32,
    parity: Parity,
) -> std::io::Result<tokio_serial::SerialStream> {
    use tokio_serial::{SerialPort, SerialPortBuilderExt};
    let port = tokio_serial::new(path, baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None)
        .parity(match parity {
            Parity::None => tokio_serial::Parity::None,
            Parity::Even => tokio_serial::Parity::Even,
            Parity::Odd => tokio_serial::Parity::Odd,
        })
        .open_native_async()?;
    port.clear(tokio_serial::ClearBuffer::All)?;
    Ok(port)
}

/// A read the wire may send to close an episode of late replies: `addr` and a register
/// count from `counts` that differs from every owed read's (docs/modbus.md: the header's
/// 32 registers at the base address).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Barrier {
    pub addr: u16,
    pub counts: (u16, u16),
}

/// Why an exchange failed.
#[derive(Debug, thiserror::Error)]
pub enum WireError {
    #[error("no reply within {0:?}")]
    Timeout(Duration),
    #[error("the stream closed")]
    Closed,
    #[error("{0}")]
    Io(#[from] io::Error),
    #[error("a damaged reply: {0}")]
    Garbled(#[from] FrameError),
    #[error("every register count for the settling read is owed to an earlier request")]
    NoBarrier,
}

/// What became of each reply frame the wire received, for tests and diagnostics.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReplyFate {
    /// Taken as the answer to the `request`-th request this wire sent (1-based).
    Taken { request: u64 },
    /// Discarded: a late reply to an earlier request, or another unit's.
    Stale,
    /// Discarded unread while the line settled after a timeout.
    Drained,
}

/// What the wire did, for benchmarks and logs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WireCounters {
    pub requests: u64,
    pub replies: u64,
    /// Frames discarded as late replies to earlier requests (or replies of other units).
    pub stale: u64,
    /// Bytes discarded while settling the line after a timeout.
    pub drained: u64,
    /// Settling reads sent.
    pub barriers: u64,
}

/// One stream with its framing: sends a request and returns its reply.
pub struct Wire {
    io: Box<dyn ByteStream>,
    framing: Framing,
    unit: u8,
    quiet: Duration,
    barrier: Option<Barrier>,
    buf: Vec<u8>,
    transaction: u16,
    /// RTU: requests that timed out (or got a damaged reply) since the line last settled.
    owed: Vec<Request>,
    /// RTU: when bytes last arrived, for the silence before the next request.
    last_rx: Option<Instant>,
    counters: WireCounters,
    log: Option<Vec<ReplyFate>>,
}

impl Wire {
    /// A wire on `io`. `quiet` is how long the line must be silent before a request after a
    /// timeout (at least 3.5 characters on RTU).
    pub fn new(
        io: Box<dyn ByteStream>,
        framing: Framing,
        unit: u8,
        quiet: Duration,
        barrier: Option<Barrier>,
    ) -> Wire {
        Wire {
            io,
            framing,
            unit,
            quiet: quiet.max(framing.t35()),
            barrier,
            buf: Vec::new(),
            transaction: 0,
            owed: Vec::new(),
            last_rx: None,
            counters: WireCounters::default(),
            log: None,
        }
    }

    pub fn framing(&self) -> Framing {
        self.framing
    }
    pub fn counters(&self) -> WireCounters {
        self.counters
    }
    /// Starts recording the fate of every reply frame (see [`Wire::replies`]).
    pub fn record_replies(&mut self) {
        self.log.get_or_insert_with(Vec::new);
    }
    /// The fate of every reply frame received since recording started, in arrival order.
    pub fn replies(&self) -> &[ReplyFate] {
        self.log.as_deref().unwrap_or(&[])
    }
    /// Whether replies to earlier requests may still arrive (RTU after a timeout).
    pub fn owes(&self) -> bool {
        !self.owed.is_empty()
    }

    /// Sends `req` and waits up to `timeout` for its reply (an exception reply included).
    pub async fn exchange(
        &mut self,
        req: &Request,
        timeout: Duration,
    ) -> Result<Response, WireError> {
        if self.owed.is_empty() {
            self.send(req).await?;
            return self.await_reply(req, timeout).await;
        }
        // A read whose count no owed read has settles the line by itself.
        if self.is_barrier(req) {
            self.drain().await?;
            self.counters.barriers += 1;
            self.send(req).await?;
            let r = self.await_reply(req, timeout).await?;
            self.owed.clear();
            return Ok(r);
        }
        self.settle(timeout).await?;
        self.send(req).await?;
        self.await_reply(req, timeout).await
    }

    /// Register counts of the owed reads.
    fn owed_reads(&self) -> Vec<u16> {
        self.owed
            .iter()
            .filter_map(|r| match r {
                Request::Read { count, .. } => Some(*count),
                _ => None,
            })
            .collect()
    }

    fn is_barrier(&self, req: &Request) -> bool {
        matches!(req, Request::Read { count, .. } if !self.owed_reads().contains(count))
    }

    /// After a timeout on RTU: drain until quiet, then read past every owed reply.
    async fn settle(&mut self, timeout: Duration) -> Result<(), WireError> {
        self.drain().await?;
        let Some(b) = self.barrier else {
            self.owed.clear();
            return Ok(());
        };
        let taken = self.owed_reads();
        let count = (b.counts.0..=b.counts.1)
            .find(|c| !taken.contains(c))
            .ok_or(WireError::NoBarrier)?;
        let read = Request::Read {
            addr: b.addr,
            count,
        };
        self.counters.barriers += 1;
        self.send(&read).await?;
        self.await_reply(&read, timeout).await?;
        self.owed.clear();
        Ok(())
    }

    /// Discards what arrives until the line has been silent for the quiet time (at most
    /// twenty quiet times in all, so that a chattering line cannot hold the link forever).
    async fn drain(&mut self) -> Result<(), WireError> {
        let give_up = Instant::now() + self.quiet * 20;
        let mut tmp = [0u8; 256];
        let mut result = Ok(());
        while Instant::now() < give_up {
            match tokio::time::timeout(self.quiet, self.io.read(&mut tmp)).await {
                Err(_) => break,
                Ok(Ok(0)) => {
                    result = Err(WireError::Closed);
                    break;
                }
                Ok(Ok(n)) => {
                    self.buf.extend_from_slice(&tmp[..n]);
                    self.last_rx = Some(Instant::now());
                }
                Ok(Err(e)) => {
                    result = Err(e.into());
                    break;
                }
            }
        }
        self.discard_buffer();
        result
    }

    /// Throws away what was received and not asked for, logging the frames in it.
    fn discard_buffer(&mut self) {
        self.counters.drained += self.buf.len() as u64;
        if let Some(log) = &mut self.log {
            let mut at = 0;
            while let Some((Ok(_), n)) = frame::rtu_split(&self.buf[at..], Side::Reply) {
                log.push(ReplyFate::Drained);
                at += n;
            }
        }
        self.buf.clear();
    }

    async fn send(&mut self, req: &Request) -> Result<(), WireError> {
        let pdu = req.pdu();
        let bytes = match self.framing {
            Framing::Tcp => {
                self.transaction = self.transaction.wrapping_add(1);
                frame::tcp_encode(self.transaction, self.unit, &pdu)
            }
            Framing::Rtu { .. } => {
                // Bytes that came unasked (noise, a reply nobody waits for) are not an answer.
                self.discard_buffer();
                self.keep_silence().await;
                frame::rtu_encode(self.unit, &pdu)
            }
        };
        self.counters.requests += 1;
        self.io.write_all(&bytes).await?;
        self.io.flush().await?;
        Ok(())
    }

    /// RTU: a new frame may start only 3.5 characters after the last one ended. Waits of
    /// under a millisecond (above 9600 baud) are slept on the thread, as tokio's timers
    /// tick in whole milliseconds.
    async fn keep_silence(&mut self) {
        let Some(last) = self.last_rx else { return };
        let until = last + self.framing.t35();
        let now = Instant::now();
        if until <= now {
            return;
        }
        let rest = until - now;
        if rest >= Duration::from_millis(1) {
            tokio::time::sleep(rest).await;
        } else {
            std::thread::sleep(rest);
        }
    }

    async fn await_reply(
        &mut self,
        req: &Request,
        timeout: Duration,
    ) -> Result<Response, WireError> {
        let deadline = Instant::now() + timeout;
        let mut tmp = [0u8; 512];
        loop {
            while let Some(resp) = self.next_reply(req)? {
                if let Some(r) = resp {
                    return Ok(r);
                }
            }
            let read = tokio::time::timeout_at(deadline, self.io.read(&mut tmp)).await;
            match read {
                Err(_) => {
                    if let Framing::Rtu { .. } = self.framing {
                        self.owed.push(req.clone());
                    }
                    return Err(WireError::Timeout(timeout));
                }
                Ok(Ok(0)) => return Err(WireError::Closed),
                Ok(Ok(n)) => {
                    self.buf.extend_from_slice(&tmp[..n]);
                    self.last_rx = Some(Instant::now());
                }
                Ok(Err(e)) => return Err(e.into()),
            }
        }
    }

    /// The next frame in the buffer: `None` when there is none yet, `Some(None)` for a
    /// frame that is not the answer (discarded), `Some(Some(reply))` for the answer.
    fn next_reply(&mut self, req: &Request) -> Result<Option<Option<Response>>, WireError> {
        let (unit, pdu, transaction) = match self.framing {
            Framing::Tcp => match frame::tcp_split(&self.buf) {
                None => return Ok(None),
                Some(Err(e)) => return Err(e.into()),
                Some(Ok((f, n))) => {
                    self.buf.drain(..n);
                    (f.unit, f.pdu, Some(f.transaction))
                }
            },
            Framing::Rtu { .. } => match frame::rtu_split(&self.buf, Side::Reply) {
                None => return Ok(None),
                Some((Err(e), _)) => {
                    // Without a trustworthy length the rest of the buffer cannot be framed.
                    self.counters.drained += self.buf.len() as u64;
                    self.buf.clear();
                    self.owed.push(req.clone());
                    return Err(e.into());
                }
                Some((Ok(f), n)) => {
                    self.buf.drain(..n);
                    (f.unit, f.pdu, None)
                }
            },
        };
        let resp = Response::from_pdu(&pdu);
        let ours = match (&resp, transaction) {
            (Err(_), _) => false,
            (_, Some(t)) => t == self.transaction,
            (Ok(r), None) => {
                // While replies are owed, an exception to a function they share may be one
                // of theirs: they come first, so it is taken as theirs.
                let owed_exception = matches!(r, Response::Exception { function, .. }
                    if self.owed.iter().any(|o| o.function() == *function));
                unit == self.unit && !owed_exception
            }
        };
        let fits = resp.as_ref().map(|r| req.check_reply(r).is_ok());
        match (ours, fits) {
            (true, Ok(true)) => {
                self.counters.replies += 1;
                let request = self.counters.requests;
                if let Some(log) = &mut self.log {
                    log.push(ReplyFate::Taken { request });
                }
                Ok(Some(resp.ok()))
            }
            (true, Err(e)) if transaction.is_some() => Err(e.clone().into()),
            _ => {
                self.counters.stale += 1;
                if let Some(log) = &mut self.log {
                    log.push(ReplyFate::Stale);
                }
                Ok(Some(None))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::DuplexStream;

    fn rtu_wire(io: DuplexStream, barrier: bool) -> Wire {
        let b = barrier.then_some(Barrier {
            addr: 0,
            counts: (16, 32),
        });
        let mut w = Wire::new(
            Box::new(io),
            Framing::Rtu { baud: 19_200 },
            1,
            Duration::from_millis(5),
            b,
        );
        w.record_replies();
        w
    }

    async fn read_request(dev: &mut DuplexStream) -> Request {
        let mut buf = Vec::new();
        let mut tmp = [0u8; 300];
        loop {
            if let Some((f, n)) = frame::rtu_split(&buf, Side::Request) {
                assert_eq!(n, buf.len());
                return Request::from_pdu(&f.unwrap().pdu).unwrap();
            }
            let n = dev.read(&mut tmp).await.unwrap();
            buf.extend_from_slice(&tmp[..n]);
        }
    }

    async fn reply(dev: &mut DuplexStream, r: Response) {
        dev.write_all(&frame::rtu_encode(1, &r.pdu()))
            .await
            .unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn a_late_reply_to_a_read_is_never_taken_for_the_next_read() {
        let (host, mut dev) = tokio::io::duplex(4096);
        let mut w = rtu_wire(host, true);
        let status = Request::Read { addr: 0, count: 16 };
        let device = tokio::spawn(async move {
            // 1: answered 35 ms late (after the 20 ms timeout): consumed = 1
            assert_eq!(
                read_request(&mut dev).await,
                Request::Read { addr: 0, count: 16 }
            );
            tokio::time::sleep(Duration::from_millis(35)).await;
            reply(&mut dev, Response::Read(vec![1; 16])).await;
            // 2: the settling read, with another count; answered at once
            assert_eq!(
                read_request(&mut dev).await,
                Request::Read { addr: 0, count: 17 }
            );
            reply(&mut dev, Response::Read(vec![2; 17])).await;
            // 3: the status read again, answered at once: consumed = 3
            assert_eq!(
                read_request(&mut dev).await,
                Request::Read { addr: 0, count: 16 }
            );
            reply(&mut dev, Response::Read(vec![3; 16])).await;
            dev
        });
        let e = w.exchange(&status, Duration::from_millis(20)).await;
        assert!(matches!(e, Err(WireError::Timeout(_))), "{e:?}");
        // The late reply arrives 15 ms after the timeout: the 5 ms drain is over by then,
        // so only the settling read keeps it from being taken.
        tokio::time::sleep(Duration::from_millis(5)).await;
        let r = w
            .exchange(&status, Duration::from_millis(20))
            .await
            .unwrap();
        assert_eq!(r, Response::Read(vec![3; 16]));
        assert_eq!(
            w.replies(),
            [
                ReplyFate::Stale,
                ReplyFate::Taken { request: 2 },
                ReplyFate::Taken { request: 3 }
            ]
        );
        device.await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn a_late_echo_of_a_write_is_discarded_for_its_address() {
        let (host, mut dev) = tokio::io::duplex(4096);
        let mut w = rtu_wire(host, false);
        let device = tokio::spawn(async move {
            read_request(&mut dev).await;
            tokio::time::sleep(Duration::from_millis(40)).await;
            reply(&mut dev, Response::Write { addr: 32, count: 2 }).await;
            reply(&mut dev, Response::Write { addr: 6, count: 2 }).await;
            dev
        });
        let first = Request::Write {
            addr: 32,
            words: vec![1, 2],
        };
        assert!(w.exchange(&first, Duration::from_millis(20)).await.is_err());
        // no barrier: the drain (5 ms) ends before the late echo; its address gives it away
        let second = Request::Write {
            addr: 6,
            words: vec![0, 9],
        };
        let r = w
            .exchange(&second, Duration::from_millis(50))
            .await
            .unwrap();
        assert_eq!(r, Response::Write { addr: 6, count: 2 });
        assert_eq!(w.counters().stale, 1);
        device.await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn tcp_replies_are_matched_by_transaction() {
        let (host, mut dev) = tokio::io::duplex(4096);
        let mut w = Wire::new(Box::new(host), Framing::Tcp, 1, Duration::ZERO, None);
        let device = tokio::spawn(async move {
            let mut tmp = [0u8; 64];
            let n = dev.read(&mut tmp).await.unwrap();
            let (f, _) = frame::tcp_split(&tmp[..n]).unwrap().unwrap();
            // a stale reply with the previous transaction id, then the answer
            let r = Response::Read(vec![7; 2]).pdu();
            dev.write_all(&frame::tcp_encode(f.transaction.wrapping_sub(1), 1, &r))
                .await
                .unwrap();
            let r = Response::Read(vec![8; 2]).pdu();
            dev.write_all(&frame::tcp_encode(f.transaction, 1, &r))
                .await
                .unwrap();
            dev
        });
        let r = w
            .exchange(&Request::Read { addr: 0, count: 2 }, Duration::from_secs(1))
            .await
            .unwrap();
        assert_eq!(r, Response::Read(vec![8; 2]));
        assert_eq!(w.counters().stale, 1);
        device.await.unwrap();
    }
}
