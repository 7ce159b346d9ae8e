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

use super::wire::{self, refusal, req, Decoded, Decoder, Frame, Info, SewingState, Status};
use super::{pattern_crc, StitchKind, StitchRecord};
use crate::link::{
    Control, DeviceState, Handed, Link, LinkError, LinkEvent, MachineStatus, OperatorReason,
    Reattach, SendJournal, StreamEnd,
};
use futures::future::BoxFuture;
use std::collections::VecDeque;
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
    /// The upload window the machine reported (INFO), once asked.
    window: Option<u8>,
    /// The machine speaks protocol version 2 (its INFO has a window byte): chunks are
    /// placed by their offset alone, so they may be sent again in other sizes.
    version2: bool,
    /// The most chunk frames this link keeps in flight.
    max_window: u8,
    /// How many requests had to be sent again (timeouts and NAKs), for tests and logs.
    pub retransmissions: u64,
    /// Where the next START is journaled before it goes out (see `attach.rs`).
    pub(super) journal: Option<Box<dyn SendJournal>>,
    /// The next stream follows the machine where it is (set when `reattach` found it sewing).
    pub(super) follow: bool,
}

/// A LOAD_CHUNK frame in flight.
#[derive(Clone, Copy, Debug)]
struct InFlight {
    seq: u8,
    offset: usize,
    count: usize,
}

impl SewingLink {
    pub fn new(io: impl SerialIo + 'static, timing: SewingTiming) -> Self {
        SewingLink {
            io: Box::new(io),
            decoder: Decoder::default(),
            seq: 0,
            timing,
            window: None,
            version2: false,
            max_window: wire::HOST_WINDOW,
            retransmissions: 0,
            journal: None,
            follow: false,
        }
    }

    /// Opens a serial port (or pty) at `baud`.
    pub fn open(port: &str, baud: u32, timing: SewingTiming) -> Result<Self, LinkError> {
        Ok(SewingLink::new(crate::serial::open(port, baud)?, timing))
    }

    /// Keeps at most `frames` chunk frames in flight, whatever the machine allows (1: stop
    /// and wait, as with a machine of protocol version 1).
    pub fn with_max_window(mut self, frames: u8) -> Self {
        self.max_window = frames.max(1);
        self
    }

    /// The upload window in use: the smaller of the machine's (INFO) and this link's; 1
    /// until INFO was asked.
    pub fn window(&self) -> u8 {
        self.window.unwrap_or(1).min(self.max_window)
    }

    fn next_seq(&mut self) -> u8 {
        self.seq = self.seq.wrapping_add(1);
        self.seq
    }

    async fn send(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        self.io.write_all(bytes).await?;
        self.io.flush().await?;
        Ok(())
    }

    /// The next frame from the machine (or a damaged one), or `None` once `deadline` passed.
    /// A partial frame is dropped when the line has been quiet for the idle gap, and counts
    /// as a damaged frame.
    async fn next_reply(&mut self, deadline: Instant) -> Result<Option<Decoded>, LinkError> {
        let mut buf = [0u8; 512];
        loop {
            if let Some(d) = self.decoder.next_frame() {
                return Ok(Some(d));
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
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
                Err(_) => {
                    if let Some(seq) = self.decoder.resync_on_idle() {
                        return Ok(Some(Decoded::Corrupt { seq }));
                    }
                }
            }
        }
    }

    /// Sends one request and waits for its answer, sending it again (same sequence number)
    /// on a NAK or a timeout.
    pub async fn request(&mut self, kind: u8, payload: Vec<u8>) -> Result<Reply, LinkError> {
        let seq = self.next_seq();
        let bytes = Frame::new(seq, kind, payload).encode();
        for attempt in 0..self.timing.attempts {
            if attempt > 0 {
                self.retransmissions += 1;
            }
            self.send(&bytes).await?;
            let deadline = Instant::now() + self.timing.reply_timeout;
            while let Some(d) = self.next_reply(deadline).await? {
                // A damaged frame is most likely the answer: ask again at once (the machine
                // knows the repeat by its sequence number and answers it again).
                let Decoded::Frame(f) = d else { break };
                // Answers to other sequence numbers are stale answers to earlier attempts.
                if f.seq != seq {
                    continue;
                }
                match reply_to(&f, kind) {
                    Some(Answer::Nak) => break,
                    Some(Answer::Reply(r)) => return Ok(r),
                    None => {}
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

    /// The machine's description (sewing area, longest stitch, speed, upload window); the
    /// window is agreed here.
    pub async fn info(&mut self) -> Result<Info, LinkError> {
        let d = self.must(req::INFO, vec![], "the info request").await?;
        let info = Info::decode(&d)
            .ok_or_else(|| LinkError::Protocol(format!("the info reply is {} bytes", d.len())))?;
        self.window = Some(info.window());
        self.version2 = info.window.is_some();
        Ok(info)
    }

    /// The machine's status.
    pub async fn status(&mut self) -> Result<Status, LinkError> {
        let d = self.must(req::STATUS, vec![], "the status request").await?;
        Status::decode(&d)
            .ok_or_else(|| LinkError::Protocol("the status reply is malformed".into()))
    }

    /// Uploads a pattern in acknowledged chunks and has the machine verify it (INFO is
    /// asked first if it was not). A machine of protocol version 2 gets a window of chunk
    /// frames (one, if that is its window) that shrink on a noisy line; one of version 1
    /// gets one chunk at a time, each sent again byte for byte until it is acknowledged.
    pub async fn upload(&mut self, records: &[StitchRecord]) -> Result<(), LinkError> {
        if self.window.is_none() {
            self.info().await?;
        }
        let crc = pattern_crc(records);
        let mut p = (records.len() as u32).to_le_bytes().to_vec();
        p.extend_from_slice(&crc.to_le_bytes());
        self.must(req::LOAD_BEGIN, p, "the upload").await?;
        if self.version2 {
            let w = self.window() as usize;
            self.upload_windowed(records, w).await?;
        } else {
            self.upload_stop_and_wait(records).await?;
        }
        self.must(req::LOAD_END, vec![], "the pattern").await?;
        Ok(())
    }

    /// One chunk at a time, each acknowledged before the next (protocol version 1: a
    /// chunk is sent again unchanged, with its sequence number, so that the machine knows a
    /// repeat; chunk sizes change only between chunks).
    async fn upload_stop_and_wait(&mut self, records: &[StitchRecord]) -> Result<(), LinkError> {
        let mut size = ChunkSize::default();
        let mut offset = 0usize;
        while offset < records.len() {
            let chunk = &records[offset..(offset + size.records).min(records.len())];
            let before = self.retransmissions;
            self.must(
                req::LOAD_CHUNK,
                chunk_payload(offset, chunk),
                &format!("the chunk at record {offset}"),
            )
            .await?;
            offset += chunk.len();
            size.after(self.retransmissions > before);
        }
        Ok(())
    }

    /// Up to `window` chunk frames in flight, each with its own sequence number (go-back-N):
    /// the machine acknowledges each chunk with the records it holds, answers a damaged
    /// frame with a NAK and a chunk past the records it holds with REFUSED 2; on either (or
    /// on silence for the reply timeout) the link sends again from the last record the
    /// machine confirmed. A chunk sent twice is acknowledged, never loaded twice: its offset
    /// says where it belongs.
    async fn upload_windowed(
        &mut self,
        records: &[StitchRecord],
        window: usize,
    ) -> Result<(), LinkError> {
        let total = records.len();
        let mut size = ChunkSize::default();
        // Records the machine confirmed, the next record to send, and the furthest sent.
        let (mut acked, mut next, mut sent_to) = (0usize, 0usize, 0usize);
        let mut inflight: VecDeque<InFlight> = VecDeque::new();
        // Sequence numbers of this upload's frames (an ACK's count is good from any of them).
        let mut ours: VecDeque<u8> = VecDeque::new();
        let mut heard = Instant::now();
        let mut silences = 0u32;
        while acked < total {
            if inflight.is_empty() {
                heard = Instant::now();
            }
            while inflight.len() < window && next < total {
                let count = size.records.min(total - next);
                let seq = self.next_seq();
                let payload = chunk_payload(next, &records[next..next + count]);
                let bytes = Frame::new(seq, req::LOAD_CHUNK, payload).encode();
                self.io.write_all(&bytes).await?;
                inflight.push_back(InFlight {
                    seq,
                    offset: next,
                    count,
                });
                ours.push_back(seq);
                if ours.len() > 64 {
                    ours.pop_front();
                }
                next += count;
                sent_to = sent_to.max(next);
            }
            self.io.flush().await?;
            let deadline = heard + self.timing.reply_timeout;
            let d = self.next_reply(deadline).await?;
            let mut go_back = false;
            match d {
                None => {
                    silences += 1;
                    if silences >= self.timing.attempts {
                        return Err(LinkError::Timeout(
                            self.timing.reply_timeout * self.timing.attempts,
                        ));
                    }
                    go_back = true;
                }
                // With one frame in flight, a damaged frame is most likely its answer.
                Some(Decoded::Corrupt { .. }) => go_back = inflight.len() == 1,
                Some(Decoded::Frame(f)) => {
                    let in_flight = inflight.iter().any(|c| c.seq == f.seq);
                    match reply_to(&f, req::LOAD_CHUNK) {
                        Some(Answer::Reply(Reply::Ack(data))) if ours.contains(&f.seq) => {
                            heard = Instant::now();
                            silences = 0;
                            let loaded = match data.get(..4) {
                                Some(b) => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize,
                                None => inflight
                                    .iter()
                                    .find(|c| c.seq == f.seq)
                                    .map_or(0, |c| c.offset + c.count),
                            };
                            if loaded > acked && loaded <= sent_to {
                                acked = loaded;
                                next = next.max(acked);
                                size.after(false);
                            }
                            while inflight
                                .front()
                                .is_some_and(|c| c.offset + c.count <= acked)
                            {
                                inflight.pop_front();
                            }
                        }
                        Some(Answer::Nak) if in_flight => go_back = true,
                        Some(Answer::Reply(Reply::Refused { code, .. }))
                            if in_flight && code == refusal::WRONG_OFFSET =>
                        {
                            go_back = true
                        }
                        Some(Answer::Reply(Reply::Refused { code, text })) if in_flight => {
                            let at = inflight
                                .iter()
                                .find(|c| c.seq == f.seq)
                                .map_or(0, |c| c.offset);
                            return Err(LinkError::Protocol(format!(
                                "the machine refused the chunk at record {at} (code {code}): {text}"
                            )));
                        }
                        _ => {}
                    }
                }
            }
            if go_back {
                self.retransmissions += inflight.len() as u64;
                inflight.clear();
                next = acked;
                size.after(true);
                heard = Instant::now();
            }
        }
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
        let mut resumed = false;
        if sewing {
            let asked = *control.borrow_and_update();
            match asked {
                Control::Hold if st.state == SewingState::Sewing => {
                    self.must(req::STOP, vec![], "to hold").await?;
                }
                // the operator's resume of a job the machine holds (a stop, a thread break
                // rethreaded): the daemon streams with Run only once the operator said so
                Control::Run if st.state != SewingState::Sewing => {
                    self.must(req::RESUME, vec![], "to resume").await?;
                    resumed = true;
                }
                _ => {}
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
        let mut held = sewing && st.state != SewingState::Sewing && !resumed;
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
                        let mut status = st.to_status();
                        if st.state == SewingState::Held && st.operator_stop {
                            let stop = operator_stop(records, counter);
                            status.state = DeviceState::NeedsOperator { reason: stop.clone() };
                            let _ = events.send(LinkEvent::Message(format!(
                                "{stop} at stitch {counter}, then resume the job"
                            )));
                        }
                        let _ = events.send(LinkEvent::Status(status));
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

/// What a reply frame says to a request of type `kind`: `None` when it is no answer to it.
enum Answer {
    Nak,
    Reply(Reply),
}

fn reply_to(f: &Frame, kind: u8) -> Option<Answer> {
    match f.kind {
        wire::reply::ACK if f.payload.first() == Some(&kind) => {
            Some(Answer::Reply(Reply::Ack(f.payload[1..].to_vec())))
        }
        wire::reply::REFUSED if f.payload.first() == Some(&kind) && f.payload.len() >= 2 => {
            Some(Answer::Reply(Reply::Refused {
                code: f.payload[1],
                text: String::from_utf8_lossy(&f.payload[2..]).into_owned(),
            }))
        }
        wire::reply::NAK => Some(Answer::Nak),
        _ => None,
    }
}

/// LOAD_CHUNK's payload: offset, count, records.
fn chunk_payload(offset: usize, chunk: &[StitchRecord]) -> Vec<u8> {
    let mut p = (offset as u32).to_le_bytes().to_vec();
    p.extend_from_slice(&(chunk.len() as u16).to_le_bytes());
    for r in chunk {
        p.extend_from_slice(&r.to_wire());
    }
    p
}

/// Chunks shrink when the line is noisy (a long frame is more likely to be hit) and grow
/// back while it is clean.
struct ChunkSize {
    records: usize,
    clean: u32,
}

impl Default for ChunkSize {
    /// A quarter of the largest: a first chunk that a noisy line still lets through.
    fn default() -> Self {
        ChunkSize {
            records: wire::CHUNK_RECORDS / 4,
            clean: 0,
        }
    }
}

impl ChunkSize {
    /// After a chunk went through (`again`: it or one before it had to be sent again).
    fn after(&mut self, again: bool) {
        if again {
            self.records = (self.records / 2).max(wire::MIN_CHUNK_RECORDS);
            self.clean = 0;
        } else {
            self.clean += 1;
            if self.clean >= 8 {
                self.records = (self.records * 2).min(wire::CHUNK_RECORDS);
                self.clean = 0;
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
                // held at a colour-change or stop record: the operator's turn (the link,
                // which knows the records, names the colour)
                SewingState::Held if self.operator_stop => DeviceState::NeedsOperator {
                    reason: OperatorReason::ProgramStop,
                },
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

/// Why a machine held at an operator stop (rule 9a) waits: the record before `counter` is
/// a colour change (the thread of the next colour, counted from 1) or a stop.
fn operator_stop(records: &[StitchRecord], counter: usize) -> OperatorReason {
    let done = &records[..counter.min(records.len())];
    match done.last().map(|r| r.kind) {
        Some(StitchKind::ColorChange) => OperatorReason::ChangeThread {
            colour: 1 + done
                .iter()
                .filter(|r| r.kind == StitchKind::ColorChange)
                .count() as u32,
        },
        _ => OperatorReason::ProgramStop,
    }
}
