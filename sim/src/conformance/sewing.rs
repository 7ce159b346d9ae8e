//! The pattern sewing machine's state table (docs/sewing-link.md): every request in every state, with the reply and the next state a machine must give, and a driver that checks one cell on a machine over the pattern transfer protocol.

use machlink_protocols::sewing::wire::{
    refusal, reply, req, Decoded, Decoder, Frame, SewingState, Status,
};
use machlink_protocols::sewing::{pattern_crc, StitchKind, StitchRecord};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

/// The machine under test must break its thread when it is about to sew this record of the
/// test pattern (the one state the protocol cannot bring about by itself).
pub const THREAD_BREAK_AT: u32 = 2;
/// Records in the test pattern: 0.5 mm stitches in rows, long enough to keep a machine
/// sewing through a test.
pub const PATTERN_RECORDS: usize = 2000;
/// Records in each chunk the driver sends.
const CHUNK: usize = 8;
/// Where the driver starts sewing (after the thread break).
const START_AT: u32 = 10;

/// The states of the table's columns. `Loading` is NoPattern after LOAD_BEGIN (STATUS shows
/// state 0 for both).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Column {
    NoPattern,
    Loading,
    Ready,
    Sewing,
    Held,
    ThreadBreak,
    Done,
}

pub const COLUMNS: [Column; 7] = [
    Column::NoPattern,
    Column::Loading,
    Column::Ready,
    Column::Sewing,
    Column::Held,
    Column::ThreadBreak,
    Column::Done,
];

impl Column {
    fn state(self) -> SewingState {
        match self {
            Column::NoPattern | Column::Loading => SewingState::NoPattern,
            Column::Ready => SewingState::Ready,
            Column::Sewing => SewingState::Sewing,
            Column::Held => SewingState::Held,
            Column::ThreadBreak => SewingState::ThreadBreak,
            Column::Done => SewingState::Done,
        }
    }
    fn name(self) -> &'static str {
        match self {
            Column::NoPattern => "NoPattern (0)",
            Column::Loading => "Loading (0)",
            Column::Ready => "Ready (1)",
            Column::Sewing => "Sewing (2)",
            Column::Held => "Held (3)",
            Column::ThreadBreak => "ThreadBreak (4)",
            Column::Done => "Done (5)",
        }
    }
}

/// The requests of the table's rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ask {
    Info,
    Status,
    LoadBegin,
    ChunkNext,
    ChunkRepeat,
    ChunkGap,
    LoadEnd,
    LoadEndBadCrc,
    Start,
    StartOtherCrc,
    StartPastEnd,
    StartAtEnd,
    Stop,
    Resume,
    Abort,
    UnknownType,
    BadCrc,
    StoppedShort,
    Repeat,
}

pub const ASKS: [Ask; 19] = [
    Ask::Info,
    Ask::Status,
    Ask::LoadBegin,
    Ask::ChunkNext,
    Ask::ChunkRepeat,
    Ask::ChunkGap,
    Ask::LoadEnd,
    Ask::LoadEndBadCrc,
    Ask::Start,
    Ask::StartOtherCrc,
    Ask::StartPastEnd,
    Ask::StartAtEnd,
    Ask::Stop,
    Ask::Resume,
    Ask::Abort,
    Ask::UnknownType,
    Ask::BadCrc,
    Ask::StoppedShort,
    Ask::Repeat,
];

impl Ask {
    /// The row's heading in the document.
    pub fn text(self) -> &'static str {
        match self {
            Ask::Info => "INFO",
            Ask::Status => "STATUS",
            Ask::LoadBegin => "LOAD_BEGIN",
            Ask::ChunkNext => "LOAD_CHUNK at offset = records loaded",
            Ask::ChunkRepeat => "LOAD_CHUNK of records already loaded (v2)",
            Ask::ChunkGap => "LOAD_CHUNK at offset > records loaded",
            Ask::LoadEnd => "LOAD_END, all records there, CRC and records good",
            Ask::LoadEndBadCrc => "LOAD_END, the pattern CRC does not match",
            Ask::Start => "START at k < length, the pattern's CRC",
            Ask::StartOtherCrc => "START naming another CRC",
            Ask::StartPastEnd => "START at k > length",
            Ask::StartAtEnd => "START at k = length",
            Ask::Stop => "STOP",
            Ask::Resume => "RESUME",
            Ask::Abort => "ABORT",
            Ask::UnknownType => "any other request type",
            Ask::BadCrc => "a frame with a bad CRC",
            Ask::StoppedShort => "a frame whose bytes stop short of its length (v2)",
            Ask::Repeat => "the last request again (same seq and type)",
        }
    }
}

/// What a machine answers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Answer {
    Ack,
    Refused(u8),
    Nak,
    /// The reply it gave the first time, byte for byte, and nothing applied.
    Stored,
}

/// One cell of this table.
pub type Cell = super::Cell<Answer, Column>;
use super::cell_of;

/// The table: what a machine does on `ask` in `column`.
pub fn cell(ask: Ask, column: Column) -> Cell {
    use Answer::*;
    use Column as C;
    let no_pattern = matches!(column, C::NoPattern | C::Loading);
    match ask {
        Ask::Info | Ask::Status => cell_of(Ack, None),
        Ask::LoadBegin if column == C::Sewing => cell_of(Refused(refusal::BUSY), None),
        Ask::LoadBegin => cell_of(Ack, Some(C::Loading)),
        Ask::ChunkNext | Ask::ChunkRepeat if column == C::Loading => cell_of(Ack, None),
        Ask::ChunkGap if column == C::Loading => cell_of(Refused(refusal::WRONG_OFFSET), None),
        Ask::LoadEnd if column == C::Loading => cell_of(Ack, Some(C::Ready)),
        Ask::LoadEndBadCrc if column == C::Loading => {
            cell_of(Refused(refusal::PATTERN_INVALID), Some(C::NoPattern))
        }
        Ask::ChunkNext | Ask::ChunkRepeat | Ask::ChunkGap | Ask::LoadEnd | Ask::LoadEndBadCrc => {
            cell_of(Refused(refusal::NO_PATTERN), None)
        }
        Ask::Start | Ask::StartOtherCrc | Ask::StartPastEnd | Ask::StartAtEnd if no_pattern => {
            cell_of(Refused(refusal::NO_PATTERN), None)
        }
        Ask::StartOtherCrc => cell_of(Refused(refusal::PATTERN_INVALID), None),
        Ask::StartPastEnd => cell_of(Refused(refusal::BAD_REQUEST), None),
        Ask::Start | Ask::StartAtEnd if column == C::Sewing => {
            cell_of(Refused(refusal::BUSY), None)
        }
        Ask::Start => cell_of(Ack, Some(C::Sewing)),
        Ask::StartAtEnd => cell_of(Ack, Some(C::Done)),
        Ask::Stop if column == C::Sewing => cell_of(Ack, Some(C::Held)),
        Ask::Resume if matches!(column, C::Held | C::ThreadBreak) => cell_of(Ack, Some(C::Sewing)),
        Ask::Abort if matches!(column, C::Sewing | C::Held | C::ThreadBreak) => {
            cell_of(Ack, Some(C::Ready))
        }
        Ask::Stop | Ask::Resume | Ask::Abort => cell_of(Ack, None),
        Ask::UnknownType => cell_of(Refused(refusal::BAD_REQUEST), None),
        Ask::BadCrc | Ask::StoppedShort => cell_of(Nak, None),
        Ask::Repeat => cell_of(Stored, None),
    }
}

fn cell_text(c: Cell) -> String {
    let answer = match c.answer {
        Answer::Ack => "ACK".to_string(),
        Answer::Refused(code) => format!("REFUSED {code}"),
        Answer::Nak => "NAK".to_string(),
        Answer::Stored => "first reply again".to_string(),
    };
    match c.next {
        Some(Column::Done) => format!("{answer} → Done (at its next stitch cycle)"),
        Some(n) => format!("{answer} → {}", n.name().split(' ').next().unwrap_or("")),
        None => answer,
    }
}

/// The state table as docs/sewing-link.md carries it.
pub fn markdown_table() -> String {
    super::markdown(
        "request \\ state",
        &ASKS,
        &COLUMNS,
        |a| a.text().to_string(),
        |c| c.name().to_string(),
        |a, c| cell_text(cell(a, c)),
    )
}

/// The test pattern: a serpentine of 0.5 mm stitches inside any reasonable sewing area.
pub fn test_pattern() -> Vec<StitchRecord> {
    (0..PATTERN_RECORDS as i32)
        .map(|i| {
            let (row, col) = (i / 100, i % 100);
            let x = if row % 2 == 0 { col * 5 } else { 495 - col * 5 };
            StitchRecord::new(StitchKind::Stitch, x, row * 10)
        })
        .collect()
}

/// A frame-level client: sends frames, reads replies.
struct Raw<S> {
    io: S,
    dec: Decoder,
    seq: u8,
}

impl<S: AsyncRead + AsyncWrite + Unpin> Raw<S> {
    fn next_seq(&mut self) -> u8 {
        self.seq = self.seq.wrapping_add(1);
        self.seq
    }
    async fn send(&mut self, bytes: &[u8]) -> Result<(), String> {
        self.io
            .write_all(bytes)
            .await
            .map_err(|e| format!("writing: {e}"))?;
        self.io.flush().await.map_err(|e| format!("writing: {e}"))
    }
    /// The next frame from the machine, within two seconds.
    async fn reply(&mut self) -> Result<Frame, String> {
        let deadline = Instant::now() + Duration::from_secs(2);
        let mut buf = [0u8; 512];
        loop {
            if let Some(d) = self.dec.next_frame() {
                match d {
                    Decoded::Frame(f) => return Ok(f),
                    Decoded::Corrupt { .. } => return Err("a damaged reply".into()),
                }
            }
            let n = tokio::time::timeout_at(deadline, self.io.read(&mut buf))
                .await
                .map_err(|_| "no reply within 2 s".to_string())?
                .map_err(|e| format!("reading: {e}"))?;
            if n == 0 {
                return Err("the machine closed the line".into());
            }
            self.dec.push(&buf[..n]);
        }
    }
    /// Sends a request and returns its reply frame (checked to carry the request's seq).
    async fn ask(&mut self, kind: u8, payload: Vec<u8>) -> Result<Frame, String> {
        let seq = self.next_seq();
        self.send(&Frame::new(seq, kind, payload).encode()).await?;
        let f = self.reply().await?;
        if f.seq != seq {
            return Err(format!(
                "the reply carries seq {}, the request {seq}",
                f.seq
            ));
        }
        Ok(f)
    }
    async fn must(&mut self, kind: u8, payload: Vec<u8>) -> Result<Vec<u8>, String> {
        let f = self.ask(kind, payload).await?;
        if f.kind != reply::ACK || f.payload.first() != Some(&kind) {
            return Err(format!("setting up: request 0x{kind:02X} got {:?}", f));
        }
        Ok(f.payload[1..].to_vec())
    }
    async fn status(&mut self) -> Result<Status, String> {
        let d = self.must(req::STATUS, vec![]).await?;
        Status::decode(&d).ok_or_else(|| "a malformed STATUS reply".to_string())
    }
    async fn wait_for(&mut self, state: SewingState) -> Result<Status, String> {
        for _ in 0..400 {
            let s = self.status().await?;
            if s.state == state {
                return Ok(s);
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        Err(format!("the machine never reached {}", state.name()))
    }
    async fn begin(&mut self, records: &[StitchRecord], crc: u32) -> Result<(), String> {
        let mut p = (records.len() as u32).to_le_bytes().to_vec();
        p.extend_from_slice(&crc.to_le_bytes());
        self.must(req::LOAD_BEGIN, p).await.map(|_| ())
    }
    async fn chunks(&mut self, records: &[StitchRecord], from: usize) -> Result<(), String> {
        for at in (from..records.len()).step_by(CHUNK) {
            let end = (at + CHUNK).min(records.len());
            self.must(req::LOAD_CHUNK, chunk(at, &records[at..end]))
                .await?;
        }
        Ok(())
    }
    async fn start(&mut self, at: u32, crc: u32) -> Result<(), String> {
        self.must(req::START, start(at, crc)).await.map(|_| ())
    }
}

fn chunk(offset: usize, records: &[StitchRecord]) -> Vec<u8> {
    let mut p = (offset as u32).to_le_bytes().to_vec();
    p.extend_from_slice(&(records.len() as u16).to_le_bytes());
    for r in records {
        p.extend_from_slice(&r.to_wire());
    }
    p
}

fn start(at: u32, crc: u32) -> Vec<u8> {
    let mut p = at.to_le_bytes().to_vec();
    p.extend_from_slice(&crc.to_le_bytes());
    p
}

/// Takes a fresh machine (just powered up, thread to break before record
/// [`THREAD_BREAK_AT`]) on `io` to `column`, sends `ask`, and checks the answer, the state
/// after it and STATUS's counter and pattern against the table.
pub async fn check<S>(io: S, column: Column, ask: Ask) -> Result<(), String>
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    let want = cell(ask, column);
    let mut m = Raw {
        io,
        dec: Decoder::default(),
        seq: 0,
    };
    let pattern = test_pattern();
    let crc = pattern_crc(&pattern);
    let len = pattern.len() as u32;
    // Bring the machine to the column's state.
    let fresh = m.status().await?;
    if fresh.state != SewingState::NoPattern || fresh.pattern_len != 0 {
        return Err("the machine is not fresh (no pattern ever loaded)".into());
    }
    if column != Column::NoPattern {
        m.begin(&pattern, crc).await?;
        m.chunks(&pattern[..CHUNK], 0).await?;
        if column != Column::Loading {
            m.chunks(&pattern, CHUNK).await?;
            m.must(req::LOAD_END, vec![]).await?;
        }
    }
    match column {
        Column::Sewing | Column::Held => {
            m.start(START_AT, crc).await?;
            if column == Column::Held {
                m.must(req::STOP, vec![]).await?;
                m.wait_for(SewingState::Held).await?;
            }
        }
        Column::ThreadBreak => {
            m.start(0, crc).await?;
            m.wait_for(SewingState::ThreadBreak).await?;
        }
        Column::Done => {
            m.start(len - 2, crc).await?;
            m.wait_for(SewingState::Done).await?;
        }
        _ => {}
    }
    // What some rows need beyond the state: every record loaded, or a wrong pattern CRC.
    if column == Column::Loading {
        match ask {
            Ask::LoadEnd => m.chunks(&pattern, CHUNK).await?,
            Ask::LoadEndBadCrc => {
                m.begin(&pattern, crc ^ 1).await?;
                m.chunks(&pattern, 0).await?;
            }
            _ => {}
        }
    }
    let before = m.status().await?;
    if before.state != column.state() {
        return Err(format!(
            "setting up reached {}, not {}",
            before.state.name(),
            column.state().name()
        ));
    }
    let kind_sent;
    let got = match ask {
        Ask::BadCrc => {
            let seq = m.next_seq();
            let mut bytes = Frame::new(seq, req::STATUS, vec![]).encode();
            let n = bytes.len();
            bytes[n - 1] ^= 0x5A;
            m.send(&bytes).await?;
            kind_sent = req::STATUS;
            m.reply().await?
        }
        Ask::StoppedShort => {
            let seq = m.next_seq();
            let bytes = Frame::new(seq, req::LOAD_CHUNK, chunk(0, &pattern[..CHUNK])).encode();
            m.send(&bytes[..bytes.len() - 3]).await?;
            kind_sent = req::LOAD_CHUNK;
            m.reply().await?
        }
        Ask::Repeat => {
            let seq = m.next_seq();
            let bytes = Frame::new(seq, req::STATUS, vec![]).encode();
            m.send(&bytes).await?;
            let first = m.reply().await?;
            tokio::time::sleep(Duration::from_millis(60)).await;
            m.send(&bytes).await?;
            let again = m.reply().await?;
            if again != first {
                return Err(format!(
                    "the repeat got {again:?}, the first time {first:?}"
                ));
            }
            kind_sent = req::STATUS;
            first
        }
        _ => {
            let (kind, payload) = match ask {
                Ask::Info => (req::INFO, vec![]),
                Ask::Status => (req::STATUS, vec![]),
                Ask::LoadBegin => {
                    let mut p = (len).to_le_bytes().to_vec();
                    p.extend_from_slice(&crc.to_le_bytes());
                    (req::LOAD_BEGIN, p)
                }
                Ask::ChunkNext => (req::LOAD_CHUNK, chunk(CHUNK, &pattern[CHUNK..2 * CHUNK])),
                Ask::ChunkRepeat => (req::LOAD_CHUNK, chunk(0, &pattern[..CHUNK])),
                Ask::ChunkGap => (
                    req::LOAD_CHUNK,
                    chunk(2 * CHUNK, &pattern[2 * CHUNK..3 * CHUNK]),
                ),
                Ask::LoadEnd | Ask::LoadEndBadCrc => (req::LOAD_END, vec![]),
                Ask::Start => (req::START, start(START_AT, crc)),
                Ask::StartOtherCrc => (req::START, start(START_AT, crc ^ 1)),
                Ask::StartPastEnd => (req::START, start(len + 1, crc)),
                Ask::StartAtEnd => (req::START, start(len, crc)),
                Ask::Stop => (req::STOP, vec![]),
                Ask::Resume => (req::RESUME, vec![]),
                Ask::Abort => (req::ABORT, vec![]),
                Ask::UnknownType => (0x7F, vec![]),
                Ask::BadCrc | Ask::StoppedShort | Ask::Repeat => unreachable!("sent above"),
            };
            kind_sent = kind;
            m.ask(kind, payload).await?
        }
    };
    let answered = match (got.kind, got.payload.first()) {
        (reply::ACK, Some(&k)) if k == kind_sent => Answer::Ack,
        (reply::REFUSED, Some(&k)) if k == kind_sent && got.payload.len() >= 2 => {
            Answer::Refused(got.payload[1])
        }
        (reply::NAK, _) => Answer::Nak,
        _ => return Err(format!("an answer the protocol does not have: {got:?}")),
    };
    let expected = match want.answer {
        Answer::Stored => Answer::Ack,
        a => a,
    };
    if answered != expected {
        return Err(format!("{answered:?}, where {} is due", cell_text(want)));
    }
    let mut after = m.status().await?;
    let next = want.next.unwrap_or(column);
    if next == Column::Done {
        after = m.wait_for(SewingState::Done).await?;
    }
    if after.state != next.state() {
        return Err(format!(
            "STATUS shows {} afterwards, where {} is due",
            after.state.name(),
            next.state().name()
        ));
    }
    // What STATUS says of the pattern changes only with a verified LOAD_END.
    let (plen, pcrc) = if want.next == Some(Column::Ready) && ask == Ask::LoadEnd {
        (len, crc)
    } else {
        (before.pattern_len, before.pattern_crc)
    };
    if (after.pattern_len, after.pattern_crc) != (plen, pcrc) {
        return Err(format!(
            "STATUS names pattern ({}, {:08X}) afterwards, where ({plen}, {pcrc:08X}) is due",
            after.pattern_len, after.pattern_crc
        ));
    }
    // The counter: START sets it to where sewing starts; nothing else takes it back.
    let from = match (ask, want.answer) {
        (Ask::Start, Answer::Ack) => START_AT,
        (Ask::StartAtEnd, Answer::Ack) => len,
        _ => before.counter,
    };
    // It moves on only while the machine sews (before the request or after it).
    let moving = column == Column::Sewing || next == Column::Sewing;
    if after.counter < from || (!moving && after.counter != from) {
        return Err(format!(
            "the stitch counter reads {} afterwards, where {from} is due",
            after.counter
        ));
    }
    Ok(())
}
