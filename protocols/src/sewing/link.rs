//! `SewingLink`: streams a stitch program to a pattern sewing machine over the framed, acknowledged pattern transfer protocol.
//!
//! The host is the only one who asks: every request is a frame with a fresh sequence number,
//! answered by the machine with an ACK (or a refusal) carrying the same number. A request
//! that is not answered within the timeout, or answered with a NAK, is sent again with the
//! *same* number, so the machine recognises a repeat and answers it again without acting on
//! it twice. The pattern goes up in chunks that each name the index of their first record,
//! and the whole pattern carries a CRC-32 the machine checks before it will sew; START names
//! both the record to start at and that CRC. Progress is the machine's stitch counter,
//! read with STATUS.

use super::wire::{self, req, Decoded, Decoder, Frame, Info, SewingState, Status};
use super::{pattern_crc, StitchRecord};
use crate::link::{
    Control, DeviceState, Handed, Link, LinkError, LinkEvent, MachineStatus, OperatorReason,
    Reattach, SendJournal, StreamEnd,
};
use futures::future::BoxFuture;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

/// Anything a link can talk over: a serial port, a pty, a TCP stream, a test pipe.
pub trait SerialIo: AsyncRead + AsyncWrite + Send + Unpin {}
impl<T: AsyncRead + AsyncWrite + Send + Unpin> SerialIo for T {}

/// Timing of the link (real time).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SewingTiming {
    /// How long to wait for an answer before sending a request again.
    pub reply_timeout: Duration,
    /// How often one request is tried before the link gives up.
    pub attempts: u32,
    /// How often the machine's status is read while it sews.
    pub poll: Duration,
    /// Silence on the line after which a half-received frame is dropped.
    pub idle_gap: Duration,
}

impl Default for SewingTiming {
    fn default() -> Self {
        SewingTiming {
            reply_timeout: Duration::from_millis(150),
            attempts: 40,
            poll: Duration::from_millis(50),
            idle_gap: Duration::from_millis(40),
        }
    }
}

/// What the machine said to a request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reply {
    /// Done; the data after the echoed request type.
    Ack(Vec<u8>),
    Refused {
        code: u8,
        text: String,
    },
}

/// A connection to one pattern sewing machine.
pub struct SewingLink {
    io: Box<dyn SerialIo>,
    decoder: Decoder,
    seq: u8,
    timing: SewingTiming,
    /// How many requests had to be sent again (timeouts and NAKs), for tests and logs.
    pub retransmissions: u64,
    /// Where the next START is journaled before it goes out (see `attach.rs`).
    pub(super) journal: Option<Box<dyn SendJournal>>,
    /// The next stream follows the machine where it is (set when `reattach` found it sewing).
    pub(super) follow: bool,
}

impl SewingLink {
    pub fn new(io: impl SerialIo + 'static, timing: SewingTiming) -> Self {
        SewingLink {
            io: Box::new(io),
            decoder: Decoder::default(),
            seq: 0,
            timing,
            retransmissions: 0,
            journal: None,
            follow: false,
        }
    }

    /// Opens a serial port (or pty) at `baud`.
    pub fn open(port: &str, baud: u32, timing: SewingTiming) -> Result<Self, LinkError> {
        Ok(SewingLink::new(crate::serial::open(port, baud)?, timing))
    }

    /// Sends one request and waits for its answer, sending it again (same sequence number)
    /// on a NAK or a timeout.
    pub async fn request(&mut self, kind: u8, payload: Vec<u8>) -> Result<Reply, LinkError> {
        self.seq = self.seq.wrapping_add(1);
        let seq = self.seq;
        let bytes = Frame::new(seq, kind, payload).encode();
        let mut buf = [0u8; 512];
        for attempt in 0..self.timing.attempts {
            if attempt > 0 {
                self.retransmissions += 1;
            }
            self.io.write_all(&bytes).await?;
            self.io.flush().await?;
            let deadline = Instant::now() + self.timing.reply_timeout;
            'wait: loop {
                while let Some(d) = self.decoder.next_frame() {
                    match d {
                        Decoded::Frame(f) if f.seq == seq => match f.kind {
                            wire::reply::ACK if f.payload.first() == Some(&kind) => {
                                return Ok(Reply::Ack(f.payload[1..].to_vec()))
                            }
                            wire::reply::REFUSED
                                if f.payload.first() == Some(&kind) && f.payload.len() >= 2 =>
                            {
                                return Ok(Reply::Refused {
                                    code: f.payload[1],
                                    text: String::from_utf8_lossy(&f.payload[2..]).into_owned(),
                                })
                            }
                            wire::reply::NAK => break 'wait,
                            _ => {}
                        },
                        // stale answers to earlier attempts, or noise
                        _ => {}
                    }
                }
                let now = Instant::now();
                if now >= deadline {
                    break;
                }
                let wait = (deadline - now).min(self.timing.idle_gap);
                match tokio::time::timeout(wait, self.io.read(&mut buf)).await {
                    Ok(Ok(0)) => {
                        return Err(LinkError::Io(std::io::Error::new(
                            std::io::ErrorKind::UnexpectedEof,
                            "the machine closed the line",
                        )))
                    }
                    Ok(Ok(n)) => self.decoder.push(&buf[..n]),
                    Ok(Err(e)) => return Err(e.into()),
                    Err(_) => self.decoder.resync_on_idle(),
                }
            }
        }
        Err(LinkError::Timeout(
            self.timing.reply_timeout * self.timing.attempts,
        ))
    }

    /// A request that must be acknowledged: a refusal becomes an error.
    async fn must(&mut self, kind: u8, payload: Vec<u8>, what: &str) -> Result<Vec<u8>, LinkError> {
        match self.request(kind, payload).await? {
            Reply::Ack(d) => Ok(d),
            Reply::Refused { code, text } => Err(LinkError::Protocol(format!(
                "the machine refused {what} (code {code}): {text}"
            ))),
        }
    }

    /// The machine's description (sewing area, longest stitch, speed).
    pub async fn info(&mut self) -> Result<Info, LinkError> {
        let d = self.must(req::INFO, vec![], "the info request").await?;
        Info::decode(&d)
            .ok_or_else(|| LinkError::Protocol(format!("the info reply is {} bytes", d.len())))
    }

    /// The machine's status.
    pub async fn status(&mut self) -> Result<Status, LinkError> {
        let d = self.must(req::STATUS, vec![], "the status request").await?;
        Status::decode(&d)
            .ok_or_else(|| LinkError::Protocol("the status reply is malformed".into()))
    }

    /// Uploads a pattern in acknowledged chunks and has the machine verify it.
    pub async fn upload(&mut self, records: &[StitchRecord]) -> Result<(), LinkError> {
        let crc = pattern_crc(records);
        let mut p = (records.len() as u32).to_le_bytes().to_vec();
        p.extend_from_slice(&crc.to_le_bytes());
        self.must(req::LOAD_BEGIN, p, "the upload").await?;
        // chunks shrink when the line is noisy (a long frame is more likely to be hit) and
        // grow back while it is clean
        let mut size = wire::CHUNK_RECORDS;
        let mut clean = 0;
        let mut offset = 0usize;
        while offset < records.len() {
            let chunk = &records[offset..(offset + size).min(records.len())];
            let mut p = (offset as u32).to_le_bytes().to_vec();
            p.extend_from_slice(&(chunk.len() as u16).to_le_bytes());
            for r in chunk {
                p.extend_from_slice(&r.to_wire());
            }
            let before = self.retransmissions;
            self.must(req::LOAD_CHUNK, p, &format!("the chunk at record {offset}"))
                .await?;
            offset += chunk.len();
            if self.retransmissions > before {
                size = (size / 2).max(4);
                clean = 0;
            } else {
                clean += 1;
                if clean >= 8 {
                    size = (size * 2).min(wire::CHUNK_RECORDS);
                    clean = 0;
                }
            }
        }
        self.must(req::LOAD_END, vec![], "the pattern").await?;
        Ok(())
    }

    async fn start(&mut self, at: usize, crc: u32) -> Result<(), LinkError> {
        let mut p = (at as u32).to_le_bytes().to_vec();
        p.extend_from_slice(&crc.to_le_bytes());
        self.must(req::START, p, &format!("to start at record {at}"))
            .await
            .map(|_| ())
    }

    /// Uploads `records` (unless the machine holds them already) and sews them from record
    /// `from` on.
    pub async fn sew(
        &mut self,
        records: &[StitchRecord],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        mut control: watch::Receiver<Control>,
    ) -> Result<StreamEnd, LinkError> {
        let info = self.info().await?;
        check_pattern(records, &info)?;
        let len = records.len();
        let crc = pattern_crc(records);
        let mut st = self.status().await?;
        let same = st.pattern_len as usize == len && st.pattern_crc == crc;
        // the machine keeps its counter through stops and power loss: when a resumed job
        // (from > 0) finds the machine further on than our journal (we missed its last
        // acknowledgements), trust the machine. A job from 0 always sews the whole pattern,
        // even when the machine just sewed the same one (the next pocket of a batch).
        let mut done = if same && from > 0 {
            from.max(st.counter as usize)
        } else {
            from
        };
        if done > from {
            let _ = events.send(LinkEvent::Acked { unit: done - 1 });
        }
        if done >= len {
            return Ok(StreamEnd::Completed);
        }
        // a machine still sewing this pattern (the daemon restarted, the line came back) is
        // followed where it is, never started again
        let sewing = same && (from > 0 || std::mem::take(&mut self.follow)) && st.state.is_sewing();
        if sewing {
            if *control.borrow_and_update() == Control::Hold && st.state == SewingState::Sewing {
                self.must(req::STOP, vec![], "to hold").await?;
            }
        } else {
            if !same || st.state == SewingState::NoPattern {
                self.upload(records).await?;
            }
            // an operator's hold before the start waits here
            loop {
                let c = *control.borrow_and_update();
                match c {
                    Control::Run => break,
                    Control::Cancel => return Ok(StreamEnd::Cancelled { acked: done }),
                    Control::Hold => {
                        if control.changed().await.is_err() {
                            return Ok(StreamEnd::Cancelled { acked: done });
                        }
                    }
                }
            }
            self.journal_start(done, len)?;
            self.start(done, crc).await?;
            self.journal_started(len)?;
        }
        let mut last_state: Option<SewingState> = None;
        let mut held = sewing && st.state != SewingState::Sewing;
        let mut control_open = true;
        loop {
            tokio::select! {
                ch = control.changed(), if control_open => {
                    if ch.is_err() {
                        control_open = false;
                        continue;
                    }
                    let c = *control.borrow_and_update();
                    match c {
                        Control::Cancel => {
                            self.must(req::ABORT, vec![], "to stop").await?;
                            let st = self.status().await?;
                            done = done.max(st.counter as usize);
                            return Ok(StreamEnd::Cancelled { acked: done });
                        }
                        Control::Hold => {
                            held = true;
                            self.must(req::STOP, vec![], "to hold").await?;
                        }
                        Control::Run => {
                            // a machine that is sewing takes RESUME as a no-op
                            held = false;
                            self.must(req::RESUME, vec![], "to resume").await?;
                        }
                    }
                }
                _ = tokio::time::sleep(self.timing.poll) => {
                    st = self.status().await?;
                    let counter = st.counter as usize;
                    if st.pattern_crc == crc && counter > done && counter <= len {
                        done = counter;
                        let _ = events.send(LinkEvent::Acked { unit: done - 1 });
                    }
                    if last_state != Some(st.state) {
                        let _ = events.send(LinkEvent::Status(st.to_status()));
                        if st.state == SewingState::ThreadBreak {
                            let _ = events.send(LinkEvent::Message(format!(
                                "thread break at stitch {counter}: rethread the needle, then resume the job"
                            )));
                        }
                    }
                    last_state = Some(st.state);
                    match st.state {
                        SewingState::Done if done >= len => return Ok(StreamEnd::Completed),
                        SewingState::NoPattern => {
                            // power loss: the pattern is gone, the counter is kept
                            let _ = events.send(LinkEvent::Message(format!(
                                "the machine lost its pattern (power loss?) at stitch {counter}; uploading it again"
                            )));
                            self.upload(records).await?;
                            if held {
                                // stay held: the operator resumes
                                last_state = Some(SewingState::Held);
                                self.start(done, crc).await?;
                                self.must(req::STOP, vec![], "to hold").await?;
                            } else {
                                self.start(done, crc).await?;
                            }
                        }
                        SewingState::Ready | SewingState::Done => {
                            return Err(LinkError::Protocol(format!(
                                "the machine stopped sewing at stitch {counter} of {len} without being asked"
                            )))
                        }
                        _ => {}
                    }
                }
            }
        }
    }
}

/// Checks a pattern against the machine before anything is sent: every position inside the
/// sewing area, every stitch and jump no longer than the machine's longest.
pub fn check_pattern(records: &[StitchRecord], info: &Info) -> Result<(), LinkError> {
    let (mut cx, mut cy) = (0i64, 0i64);
    for (unit, r) in records.iter().enumerate() {
        let reject = |reason: String| LinkError::Rejected {
            unit,
            text: format!(
                "{:?} at ({:.1}, {:.1}) mm",
                r.kind,
                r.x as f64 / 10.0,
                r.y as f64 / 10.0
            ),
            reason,
        };
        if !info.contains(r.x, r.y) {
            return Err(reject(format!(
                "outside the sewing area ({:.1}, {:.1})–({:.1}, {:.1}) mm",
                info.min_x as f64 / 10.0,
                info.min_y as f64 / 10.0,
                info.max_x as f64 / 10.0,
                info.max_y as f64 / 10.0
            )));
        }
        if r.kind.moves() {
            let (dx, dy) = (r.x as i64 - cx, r.y as i64 - cy);
            let max = info.max_stitch as i64;
            if dx * dx + dy * dy > max * max {
                return Err(reject(format!(
                    "a step of {:.1} mm, longer than the machine's {:.1} mm",
                    ((dx * dx + dy * dy) as f64).sqrt() / 10.0,
                    max as f64 / 10.0
                )));
            }
            (cx, cy) = (r.x as i64, r.y as i64);
        }
    }
    Ok(())
}

impl Link<StitchRecord> for SewingLink {
    fn stream<'a>(
        &'a mut self,
        records: &'a [StitchRecord],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        Box::pin(self.sew(records, from, events, control))
    }
    fn inquire(&mut self) -> BoxFuture<'_, Result<MachineStatus, LinkError>> {
        Box::pin(async move { Ok(self.status().await?.to_status()) })
    }
    fn reattach<'a>(
        &'a mut self,
        records: &'a [StitchRecord],
        handed: Handed,
        _events: mpsc::UnboundedSender<LinkEvent>,
        _control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<Reattach, LinkError>> {
        Box::pin(self.where_is(records, handed))
    }
    fn keep_journal(&mut self, journal: Box<dyn SendJournal>) {
        self.journal = Some(journal);
    }
}

impl Status {
    /// The status reply as the link's `MachineStatus`.
    pub fn to_status(&self) -> MachineStatus {
        MachineStatus {
            state: match self.state {
                SewingState::NoPattern | SewingState::Ready | SewingState::Done => {
                    DeviceState::Idle
                }
                SewingState::Sewing => DeviceState::Running,
                SewingState::Held => DeviceState::Held,
                SewingState::ThreadBreak => DeviceState::NeedsOperator {
                    reason: OperatorReason::ThreadBreak,
                },
            },
            detail: self.state.name().to_string(),
            position: [self.x as f64 / 10.0, self.y as f64 / 10.0, 0.0],
            feed: 0.0,
        }
    }
}
