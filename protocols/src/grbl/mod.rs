//! The GRBL link: streams G-code to a GRBL 1.1 controller with character counting.
//!
//! GRBL acknowledges each line with `ok` or `error:N` once it has planned (or rejected) it,
//! and holds unparsed bytes in a small receive buffer (128 bytes) that silently drops bytes
//! when it overflows. The link therefore keeps the sum of the lengths of unacknowledged
//! lines (newline included) within that buffer: "character counting". Real-time bytes
//! (`?` `!` `~` 0x18 and the overrides) bypass the buffer on the controller and are sent
//! out of band here too. Status is polled with `?` at most five times a second.

mod attach;
pub mod codes;
pub mod kind;
pub mod reply;
pub mod resume;

use crate::link::{
    Control, DeviceState, Handed, Link, LinkError, LinkEvent, MachineStatus, Operation,
    OperatorReason, Overrides, Reattach, SendJournal, StreamEnd,
};
use crate::program::Units;
use codes::{describe_alarm, describe_error};
use futures::future::BoxFuture;
use reply::{classify, parse_opt, Reply, StatusReport};
use std::collections::VecDeque;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

/// Real-time command bytes of GRBL 1.1.
pub mod realtime {
    pub const STATUS: u8 = b'?';
    pub const FEED_HOLD: u8 = b'!';
    pub const CYCLE_START: u8 = b'~';
    pub const SOFT_RESET: u8 = 0x18;
    /// Feed override: back to 100 %.
    pub const FEED_OV_RESET: u8 = 0x90;
    pub const FEED_OV_PLUS_10: u8 = 0x91;
    pub const FEED_OV_MINUS_10: u8 = 0x92;
    pub const FEED_OV_PLUS_1: u8 = 0x93;
    pub const FEED_OV_MINUS_1: u8 = 0x94;
    /// Rapid override: 100 %, 50 %, 25 %.
    pub const RAPID_OV_RESET: u8 = 0x95;
    pub const RAPID_OV_MEDIUM: u8 = 0x96;
    pub const RAPID_OV_LOW: u8 = 0x97;
    /// Spindle override: back to 100 %, ±10 %, ±1 %.
    pub const SPINDLE_OV_RESET: u8 = 0x99;
    pub const SPINDLE_OV_PLUS_10: u8 = 0x9A;
    pub const SPINDLE_OV_MINUS_10: u8 = 0x9B;
    pub const SPINDLE_OV_PLUS_1: u8 = 0x9C;
    pub const SPINDLE_OV_MINUS_1: u8 = 0x9D;
    /// Cancels a jog in progress.
    pub const JOG_CANCEL: u8 = 0x85;
    /// Whether `b` is acted on by GRBL the moment it arrives, wherever it is in a line.
    pub fn is_realtime(b: u8) -> bool {
        matches!(b, b'?' | b'!' | b'~' | 0x18) || b >= 0x80
    }
}

/// The slowest status poll GRBL's docs recommend not to exceed: 5 Hz.
pub const MIN_STATUS_INTERVAL: Duration = Duration::from_millis(200);
/// How long a controller may leave status requests unanswered before the link reports it
/// as not answering (five status polls: GRBL answers `?` within milliseconds, whatever it
/// is doing). It gives up after `GrblOptions::ack_timeout`.
pub const NOT_ANSWERING_AFTER: Duration = Duration::from_secs(1);
/// The receive buffer assumed when `$I` does not report one (GRBL 1.1 on an ATmega328p).
pub const DEFAULT_WINDOW: usize = 128;

/// How to talk to a GRBL controller.
#[derive(Clone, Debug, PartialEq)]
pub struct GrblOptions {
    /// Serial speed (GRBL 1.1 ships at 115200).
    pub baud: u32,
    /// Run the whole program once in check mode (`$C`) before the real run, so a bad line
    /// is found before anything moves.
    pub check_first: bool,
    /// Time between `?` status polls; never less than 200 ms (5 Hz).
    pub status_interval: Duration,
    /// How long the controller may stay silent (no reply of any kind, status polls
    /// included) before the link gives up.
    pub ack_timeout: Duration,
    /// How long to wait for the start-up banner and `$I` when connecting or resetting.
    pub connect_timeout: Duration,
    /// How a resume brings the machine back to where the program goes on.
    pub resume: resume::ResumeOptions,
}

impl Default for GrblOptions {
    fn default() -> Self {
        GrblOptions {
            baud: 115_200,
            check_first: false,
            status_interval: MIN_STATUS_INTERVAL,
            ack_timeout: Duration::from_secs(20),
            connect_timeout: Duration::from_secs(5),
            resume: resume::ResumeOptions::default(),
        }
    }
}

type Incoming = Result<String, std::io::Error>;

/// A connection to one GRBL controller.
pub struct GrblLink {
    writer: Box<dyn AsyncWrite + Unpin + Send>,
    lines: mpsc::Receiver<Incoming>,
    reader: tokio::task::JoinHandle<()>,
    opts: GrblOptions,
    window: usize,
    planner_blocks: Option<usize>,
    wco: Option<[f64; 3]>,
    banner: String,
    /// The controller greeted with its banner when the port was opened: it had just
    /// restarted (an Arduino resets when its port opens), and holds nothing of earlier jobs.
    restarted: bool,
    /// `$I` has been read (it waits while the controller is busy with an earlier job).
    info_read: bool,
    /// Where the next stream records, before the bytes leave, how far it handed lines over.
    journal: Option<Box<dyn SendJournal>>,
    /// The operator's overrides, and what the controller was last set to.
    overrides: Option<watch::Receiver<Overrides>>,
    device_overrides: Overrides,
}

impl Drop for GrblLink {
    fn drop(&mut self) {
        self.reader.abort();
    }
}

/// How one pass over the program ended.
enum PassEnd {
    Done,
    Cancelled { acked: usize },
}

/// Lines the reader may hold that the link has not taken yet; past that the reader waits
/// (and the flood guard of the transport cuts off a device that keeps sending).
const PENDING_LINES: usize = 4096;

/// Reads the controller's lines: each bounded in length and made printable
/// (`crate::untrusted`), so no reply can grow a buffer without end or put a control
/// character in a log.
async fn read_lines<R: AsyncRead + Unpin>(mut r: R, tx: mpsc::Sender<Incoming>) {
    let mut buf = [0u8; 1024];
    let mut splitter = crate::untrusted::LineSplitter::new(crate::untrusted::MAX_LINE);
    loop {
        match r.read(&mut buf).await {
            Ok(0) => return,
            Ok(n) => {
                let mut lines = Vec::new();
                let pushed = splitter.push(&buf[..n], |l| lines.push(l));
                for l in lines {
                    if tx.send(Ok(l)).await.is_err() {
                        return;
                    }
                }
                if let Err(e) = pushed {
                    let _ = tx.send(Err(std::io::Error::other(e))).await;
                    return;
                }
            }
            Err(e) => {
                let _ = tx.send(Err(e)).await;
                return;
            }
        }
    }
}

impl GrblLink {
    /// Opens the serial port, waits for GRBL's banner (sending a soft reset when none
    /// comes) and asks `$I` for the receive buffer size.
    pub async fn open(port: &str, opts: GrblOptions) -> Result<GrblLink, LinkError> {
        let stream = crate::serial::open(port, opts.baud)?;
        // what the controller said to an earlier connection is not for this one
        let _ = tokio_serial::SerialPort::clear(stream.get_ref(), tokio_serial::ClearBuffer::Input);
        Self::from_stream(stream, opts).await
    }

    /// Same as `open` over any byte stream (a pty, a TCP bridge, a test double).
    pub async fn from_stream<S>(io: S, opts: GrblOptions) -> Result<GrblLink, LinkError>
    where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        let (r, w) = tokio::io::split(io);
        let (tx, rx) = mpsc::channel(PENDING_LINES);
        let reader = tokio::spawn(read_lines(r, tx));
        let mut link = GrblLink {
            writer: Box::new(w),
            lines: rx,
            reader,
            opts,
            window: DEFAULT_WINDOW,
            planner_blocks: None,
            wco: None,
            banner: String::new(),
            restarted: false,
            info_read: false,
            journal: None,
            overrides: None,
            device_overrides: Overrides::default(),
        };
        link.connect().await?;
        Ok(link)
    }

    /// The controller's receive buffer in bytes: the most unacknowledged bytes in flight.
    pub fn window(&self) -> usize {
        self.window
    }

    /// The planner size `$I` reported, if it did.
    pub fn planner_blocks(&self) -> Option<usize> {
        self.planner_blocks
    }

    /// The banner the controller last greeted with, e.g. `Grbl 1.1h ['$' for help]`.
    pub fn banner(&self) -> &str {
        &self.banner
    }

    /// Greets the controller without disturbing it: a status request first (a controller
    /// still running an earlier job answers it and goes on), the banner of one that has just
    /// restarted, and a soft reset only when neither comes. `$I` is read once it is idle.
    async fn connect(&mut self) -> Result<(), LinkError> {
        let total = self.opts.connect_timeout;
        let first = (total / 4).min(Duration::from_secs(1));
        let start = Instant::now();
        self.write(&[realtime::STATUS]).await?;
        let mut busy = false;
        let mut answered = false;
        while let Some(line) = self.next_line(start + first).await? {
            match classify(&line) {
                Reply::Banner(b) => {
                    self.banner = b;
                    self.restarted = true;
                    answered = true;
                    break;
                }
                Reply::Status(s) => {
                    if s.wco.is_some() {
                        self.wco = s.wco;
                    }
                    busy = matches!(s.state.as_str(), "Run" | "Hold" | "Jog" | "Home" | "Door");
                    answered = true;
                    break;
                }
                _ => {}
            }
        }
        if !answered {
            self.write(&[realtime::SOFT_RESET]).await?;
            if !self.wait_banner(start + total).await? {
                return Err(LinkError::Protocol(format!(
                    "no GRBL start-up banner within {total:?}, even after a soft reset"
                )));
            }
            self.restarted = true;
        }
        if !busy {
            self.read_info().await?;
        }
        Ok(())
    }

    /// Reads the receive buffer and planner sizes from `$I` (only while the controller is
    /// idle: its receive buffer may hold an earlier job's lines until then).
    async fn read_info(&mut self) -> Result<(), LinkError> {
        if self.info_read {
            return Ok(());
        }
        let info = self.send_setting("$I").await?;
        if let Some((blocks, rx)) = info.lines().find_map(parse_opt) {
            if rx < 2 {
                return Err(LinkError::Protocol(format!(
                    "$I reports a receive buffer of {rx} bytes, too small to stream"
                )));
            }
            self.window = rx;
            self.planner_blocks = Some(blocks);
        }
        self.info_read = true;
        Ok(())
    }

    /// Whether the controller greeted this connection with its banner (it had restarted).
    pub fn restarted(&self) -> bool {
        self.restarted
    }

    async fn write(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        self.writer.write_all(bytes).await?;
        self.writer.flush().await?;
        Ok(())
    }

    /// The next line from the controller, or None at `deadline`.
    async fn next_line(&mut self, deadline: Instant) -> Result<Option<String>, LinkError> {
        match tokio::time::timeout_at(deadline, self.lines.recv()).await {
            Err(_) => Ok(None),
            Ok(item) => take(item).map(Some),
        }
    }

    /// Waits for the start-up banner until `deadline`; false when it did not come.
    async fn wait_banner(&mut self, deadline: Instant) -> Result<bool, LinkError> {
        while let Some(line) = self.next_line(deadline).await? {
            if let Reply::Banner(b) = classify(&line) {
                self.banner = b;
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Sends a system line (`$x=…`, `$X`, `$C`, `$$`, `$I`, …) or a single G-code line and
    /// waits for its `ok`; returns what the controller printed before the `ok`, one line
    /// per line. Never counted in the streaming window (call it between streams).
    pub async fn send_setting(&mut self, line: &str) -> Result<String, LinkError> {
        check_line(line, 0, usize::MAX)?;
        let mut out = line.as_bytes().to_vec();
        out.push(b'\n');
        self.write(&out).await?;
        let mut printed: Vec<String> = Vec::new();
        let deadline = Instant::now() + self.opts.ack_timeout;
        loop {
            let Some(reply) = self.next_line(deadline).await? else {
                return Err(LinkError::Timeout(self.opts.ack_timeout));
            };
            match classify(&reply) {
                Reply::Ok => return Ok(printed.join("\n")),
                Reply::Error(code) => {
                    return Err(LinkError::Rejected {
                        unit: 0,
                        text: line.to_string(),
                        reason: describe_error(code),
                    })
                }
                Reply::Alarm(code) => {
                    return Err(LinkError::Alarm {
                        code: Some(code as u32),
                        text: format!("{} while sending {line}", describe_alarm(code)),
                    })
                }
                Reply::Status(s) => {
                    if s.wco.is_some() {
                        self.wco = s.wco;
                    }
                }
                Reply::Banner(b) => {
                    self.banner = b.clone();
                    printed.push(b);
                }
                Reply::Bracket(t) | Reply::Other(t) => printed.push(t),
            }
        }
    }

    /// Asks for one status report and waits for it.
    pub async fn query_status(&mut self) -> Result<StatusReport, LinkError> {
        self.write(&[realtime::STATUS]).await?;
        let deadline = Instant::now() + self.opts.ack_timeout;
        loop {
            let Some(line) = self.next_line(deadline).await? else {
                return Err(LinkError::Timeout(self.opts.ack_timeout));
            };
            if let Reply::Status(s) = classify(&line) {
                if s.wco.is_some() {
                    self.wco = s.wco;
                }
                return Ok(s);
            }
        }
    }

    /// Sends one real-time byte (feed overrides 0x90–0x9D, `!`, `~`, …) out of band.
    pub async fn send_realtime(&mut self, byte: u8) -> Result<(), LinkError> {
        if !realtime::is_realtime(byte) {
            return Err(LinkError::Protocol(format!(
                "0x{byte:02x} is not a GRBL real-time command"
            )));
        }
        self.write(&[byte]).await
    }

    /// Empties the controller: a feed hold first when it may be moving (so the reset
    /// does not cost position), then a soft reset, which drops everything buffered and
    /// planned; waits for the banner.
    async fn recover(&mut self, hold_first: bool) -> Result<(), LinkError> {
        let deadline = Instant::now() + self.opts.connect_timeout;
        if hold_first {
            self.write(&[realtime::FEED_HOLD]).await?;
            'settle: loop {
                self.write(&[realtime::STATUS]).await?;
                let poll_end = (Instant::now() + Duration::from_millis(100)).min(deadline);
                while let Some(line) = self.next_line(poll_end).await? {
                    if let Reply::Status(s) = classify(&line) {
                        let settled = match s.state.as_str() {
                            "Hold" => s.substate != Some(1),
                            "Run" | "Jog" | "Home" => false,
                            _ => true,
                        };
                        if settled {
                            break 'settle;
                        }
                    }
                }
                if Instant::now() >= deadline {
                    break;
                }
            }
        }
        self.write(&[realtime::SOFT_RESET]).await?;
        // a reset sets the overrides back to 100 %
        self.device_overrides = Overrides::default();
        if !self
            .wait_banner(Instant::now() + self.opts.connect_timeout)
            .await?
        {
            return Err(LinkError::Timeout(self.opts.connect_timeout));
        }
        Ok(())
    }

    /// Leaves check mode if the controller is still in it (after a reset in check mode).
    async fn leave_check_mode(&mut self) -> Result<(), LinkError> {
        if self.query_status().await?.state == "Check" {
            self.send_setting("$C").await?;
            self.wait_banner(Instant::now() + self.opts.connect_timeout)
                .await?;
        }
        Ok(())
    }

    async fn stream_gcode(
        &mut self,
        units: Units<'_, String>,
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        mut control: watch::Receiver<Control>,
    ) -> Result<StreamEnd, LinkError> {
        self.read_info().await?;
        // the program is read a page at a time here and while it streams: a file of
        // millions of lines costs the link a page or two of memory, not its length
        for (i, l) in units.iter(0..units.len()).enumerate() {
            check_line(&l?, i, self.window)?;
        }
        let from = from.min(units.len());
        // a program that goes on after a stop first brings the machine back to where it
        // left off (docs/grbl.md, "Resume"); the resume lines carry the comment `(resume)`
        let back = resume::reposition(units, from, &self.opts.resume).map_err(|e| {
            LinkError::Rejected {
                unit: from,
                text: units.get(from).unwrap_or_default(),
                reason: e,
            }
        })?;
        let preamble: Vec<String> = back
            .lines
            .iter()
            .map(|(l, _)| format!("{l} (resume)"))
            .collect();
        for p in &preamble {
            check_line(p, from, self.window)?;
        }
        let lines = &Lines {
            units,
            rewrite: back.rewrite.clone(),
        };
        if self.opts.check_first && from < lines.len() {
            self.send_setting("$C").await?;
            for p in &preamble {
                self.send_setting(p).await?;
            }
            let _ = events.send(LinkEvent::Message(
                "checking the program in GRBL's check mode ($C) before running it".into(),
            ));
            match self
                .run_pass(lines, from, &events, &mut control, true)
                .await
            {
                Ok(PassEnd::Done) => {
                    self.send_setting("$C").await?;
                    self.wait_banner(Instant::now() + self.opts.connect_timeout)
                        .await?;
                }
                Ok(PassEnd::Cancelled { .. }) => {
                    self.leave_check_mode().await?;
                    return Ok(StreamEnd::Cancelled { acked: from });
                }
                Err(e) => {
                    if let Err(e2) = self.leave_check_mode().await {
                        tracing::warn!("could not leave check mode after a failed check: {e2}");
                    }
                    return Err(match e {
                        LinkError::Rejected { unit, text, reason } => LinkError::Rejected {
                            unit,
                            text,
                            reason: format!("{reason}; found in check mode, nothing moved"),
                        },
                        other => other,
                    });
                }
            }
        }
        if !preamble.is_empty() {
            let _ = events.send(LinkEvent::Message(format!(
                "resuming at line {}: {}",
                from + 1,
                back.lines
                    .iter()
                    .map(|(_, why)| why.as_str())
                    .collect::<Vec<_>>()
                    .join("; ")
            )));
        }
        for p in &preamble {
            self.send_setting(p).await?;
        }
        match self
            .run_pass(lines, from, &events, &mut control, false)
            .await?
        {
            PassEnd::Done => Ok(StreamEnd::Completed),
            PassEnd::Cancelled { acked } => Ok(StreamEnd::Cancelled { acked }),
        }
    }

    /// Streams `lines[from..]` with character counting until every line is acknowledged
    /// and (outside check mode) the machine reports Idle with an empty planner.
    async fn run_pass(
        &mut self,
        lines: &Lines<'_>,
        from: usize,
        events: &mpsc::UnboundedSender<LinkEvent>,
        control: &mut watch::Receiver<Control>,
        check: bool,
    ) -> Result<PassEnd, LinkError> {
        let mut overrides = if check { None } else { self.overrides.take() };
        let r = self
            .run_pass_with(lines, from, events, control, check, &mut overrides)
            .await;
        if overrides.is_some() {
            self.overrides = overrides;
        }
        r
    }

    /// Records in the journal that the controller holds lines `..upto` (after a reset
    /// dropped the rest); a journal that fails is only logged here, as the stream is over.
    fn journal_reset(&mut self, upto: usize) {
        if let Some(j) = self.journal.as_mut() {
            if let Err(e) = j.sent(upto) {
                tracing::warn!("cannot journal that the controller holds {upto} lines: {e}");
            }
        }
    }

    async fn run_pass_with(
        &mut self,
        lines: &Lines<'_>,
        from: usize,
        events: &mpsc::UnboundedSender<LinkEvent>,
        control: &mut watch::Receiver<Control>,
        check: bool,
        overrides: &mut Option<watch::Receiver<Overrides>>,
    ) -> Result<PassEnd, LinkError> {
        let n = lines.len();
        let mut next = from;
        // the last program stop (M0, M1) before this pass, which may name the tool to load
        let last_stop = lines.last_stop_before(from)?;
        // the program stops this pass sent, in order (a program holds few)
        let mut sent_stops: Vec<String> = Vec::new();
        let mut inflight: VecDeque<(usize, usize)> = VecDeque::new();
        let mut used = 0usize;
        let mut held = false;
        let mut machine_paused = false;
        // the machine's own pauses this pass has seen end: the next one is at the program
        // stop after as many stops from `from`
        let mut stops_passed = 0usize;
        // Until when after a cycle start a report of Hold is stale: the answer to a poll
        // sent before the `~`, one made in the same turn of the controller's loop as it
        // (GRBL reports before it starts the cycle), or an automatic report on its way.
        // Taken as a new pause, such a report held the job again at the stop it had just
        // left while the machine ran on, and the daemon's answer, a feed hold, stopped it
        // there with the job paused for a tool already loaded. A hold that lasts past this
        // (a `~` the controller lost, or a program stop right after the last) is a pause.
        let stale_hold_grace = 2 * self.opts.status_interval.max(MIN_STATUS_INTERVAL);
        let mut stale_holds_until: Option<Instant> = None;
        let mut control_open = true;
        let mut idle_seen = 0u32;
        let mut poll = tokio::time::interval(self.opts.status_interval.max(MIN_STATUS_INTERVAL));
        poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        // when the status poll in flight was sent
        let mut poll_out: Option<Instant> = None;
        let mut last_heard = Instant::now();
        // what the controller last reported, for the status while it says nothing
        let mut last_status = MachineStatus::default();
        // one early poll when the last line is answered; after that the 5 Hz tick
        let mut final_poll_sent = false;

        let initial = *control.borrow_and_update();
        match initial {
            Control::Cancel => return Ok(PassEnd::Cancelled { acked: from }),
            Control::Hold => {
                self.write(&[realtime::FEED_HOLD]).await?;
                held = true;
            }
            Control::Run => {}
        }
        let mut overrides_open = overrides.is_some();
        if let Some(o) = overrides.as_mut() {
            let want = *o.borrow_and_update();
            self.set_overrides(want).await?;
        }

        loop {
            let acked_now = next - inflight.len();
            let mut out = Vec::new();
            while next < n {
                let line = lines.get(next)?;
                let len = line.len() + 1;
                if used + len > self.window {
                    break;
                }
                if is_program_stop(&line) {
                    sent_stops.push(line.clone());
                }
                out.extend_from_slice(line.as_bytes());
                out.push(b'\n');
                inflight.push_back((next, len));
                used += len;
                next += 1;
            }
            if !out.is_empty() {
                // the journal knows before the bytes leave, and after: a restart finds in it
                // exactly which lines the controller may hold
                if !check {
                    if let Some(j) = self.journal.as_mut() {
                        j.sending(acked_now, next).map_err(LinkError::Journal)?;
                    }
                }
                self.write(&out).await?;
                if !check {
                    if let Some(j) = self.journal.as_mut() {
                        j.sent(next).map_err(LinkError::Journal)?;
                    }
                }
            }
            let all_acked = next == n && inflight.is_empty();
            if all_acked && check {
                return Ok(PassEnd::Done);
            }
            if all_acked && poll_out.is_none() && !final_poll_sent {
                self.write(&[realtime::STATUS]).await?;
                poll_out = Some(Instant::now());
                final_poll_sent = true;
            }
            let acked_count = next - inflight.len();
            tokio::select! {
                item = self.lines.recv() => {
                    let line = take(item)?;
                    last_heard = Instant::now();
                    match classify(&line) {
                        Reply::Ok => {
                            let Some((unit, len)) = inflight.pop_front() else {
                                tracing::warn!("GRBL sent an ok with no line outstanding");
                                continue;
                            };
                            used -= len;
                            if !check {
                                let _ = events.send(LinkEvent::Acked { unit });
                            }
                        }
                        Reply::Error(code) => {
                            let Some(&(unit, _)) = inflight.front() else {
                                return Err(LinkError::Protocol(format!(
                                    "GRBL sent error:{code} with no line outstanding"
                                )));
                            };
                            if let Err(e) = self.recover(true).await {
                                tracing::warn!("could not empty the controller after error:{code}: {e}");
                            }
                            if !check {
                                self.journal_reset(acked_count);
                            }
                            return Err(LinkError::Rejected {
                                unit,
                                text: lines.text(unit),
                                reason: describe_error(code),
                            });
                        }
                        Reply::Alarm(code) => {
                            let k = inflight.front().map(|u| u.0).unwrap_or(acked_count.saturating_sub(1));
                            if let Err(e) = self.recover(false).await {
                                tracing::warn!("could not reset the controller after ALARM:{code}: {e}");
                            }
                            if !check {
                                self.journal_reset(acked_count);
                            }
                            let text = lines.text(k);
                            return Err(LinkError::Alarm {
                                code: Some(code as u32),
                                text: format!(
                                    "{} while running line {}: {text}",
                                    describe_alarm(code),
                                    k + 1
                                ),
                            });
                        }
                        Reply::Status(s) => {
                            // any report that comes after the last ok was made after it
                            // (the controller's bytes arrive in order)
                            poll_out = None;
                            let confirms = next == n && inflight.is_empty();
                            if s.wco.is_some() {
                                self.wco = s.wco;
                            }
                            let mut status = s.to_status(self.wco);
                            if status.state == DeviceState::Held
                                && stale_holds_until.is_some_and(|t| Instant::now() < t)
                            {
                                continue;
                            }
                            // (once it paused itself it waits for the operator, whether or
                            // not the daemon holds it too)
                            if status.state == DeviceState::Held && (!held || machine_paused) {
                                // a hold nobody here asked for: M0/M1 or the machine's button;
                                // the program stop it holds at may name the tool to load: the
                                // first one this pass sent that it has not passed yet (the lines
                                // after it may be sent already), else the last one sent
                                let reason = sent_stops
                                    .get(stops_passed)
                                    .or(sent_stops.last())
                                    .or(last_stop.as_ref())
                                    .and_then(|l| crate::gcode::tool_to_load(l))
                                    .map_or(OperatorReason::ProgramStop, |(number, name)| {
                                        OperatorReason::LoadTool { number, name }
                                    });
                                status.state = DeviceState::NeedsOperator { reason };
                                if !machine_paused {
                                    machine_paused = true;
                                    let _ = events.send(LinkEvent::Message(
                                        "the machine paused itself (program stop or its own hold button); resume to go on".into(),
                                    ));
                                }
                            } else if status.state != DeviceState::Held {
                                if machine_paused {
                                    stops_passed += 1;
                                }
                                machine_paused = false;
                            }
                            last_status = status.clone();
                            let _ = events.send(LinkEvent::Status(status));
                            if confirms && s.state == "Idle" {
                                let planner_empty = match (s.buffer, self.planner_blocks) {
                                    (Some((free, _)), Some(total)) => free as usize >= total,
                                    _ => false,
                                };
                                idle_seen += 1;
                                if planner_empty || idle_seen >= 2 {
                                    return Ok(PassEnd::Done);
                                }
                            } else {
                                idle_seen = 0;
                            }
                        }
                        Reply::Banner(b) => {
                            return Err(LinkError::Protocol(format!(
                                "the controller reset itself ({b}) with {} of {} lines acknowledged",
                                acked_count,
                                n
                            )));
                        }
                        Reply::Bracket(m) => {
                            if m.starts_with("[MSG:") {
                                let _ = events.send(LinkEvent::Message(m));
                            }
                        }
                        Reply::Other(_) => {}
                    }
                }
                _ = poll.tick() => {
                    let stale = poll_out.is_some_and(|t| t.elapsed() > Duration::from_secs(2));
                    if poll_out.is_none() || stale {
                        self.write(&[realtime::STATUS]).await?;
                        poll_out = Some(Instant::now());
                    }
                    let silent = last_heard.elapsed();
                    if silent >= NOT_ANSWERING_AFTER && !check {
                        let _ = events.send(LinkEvent::Status(MachineStatus::not_answering(
                            &last_status,
                            silent,
                        )));
                    }
                }
                changed = control.changed(), if control_open => {
                    if changed.is_err() {
                        control_open = false;
                        continue;
                    }
                    let c = *control.borrow_and_update();
                    match c {
                        Control::Hold => {
                            self.write(&[realtime::FEED_HOLD]).await?;
                            held = true;
                        }
                        Control::Run => {
                            if held || machine_paused {
                                self.write(&[realtime::CYCLE_START]).await?;
                                stale_holds_until = Some(Instant::now() + stale_hold_grace);
                                held = false;
                                if machine_paused {
                                    stops_passed += 1;
                                }
                                machine_paused = false;
                            }
                        }
                        Control::Cancel => {
                            self.recover(true).await?;
                            if !check {
                                self.journal_reset(acked_count);
                            }
                            return Ok(PassEnd::Cancelled { acked: acked_count });
                        }
                    }
                }
                changed = async {
                    match overrides.as_mut() {
                        Some(o) => o.changed().await,
                        None => std::future::pending().await,
                    }
                }, if overrides_open => {
                    if changed.is_err() {
                        overrides_open = false;
                        continue;
                    }
                    if let Some(o) = overrides.as_mut() {
                        let want = *o.borrow_and_update();
                        self.set_overrides(want).await?;
                    }
                }
                _ = tokio::time::sleep_until(last_heard + self.opts.ack_timeout) => {
                    return Err(LinkError::Timeout(self.opts.ack_timeout));
                }
            }
        }
    }
}

fn take(item: Option<Incoming>) -> Result<String, LinkError> {
    match item {
        Some(Ok(line)) => Ok(line),
        Some(Err(e)) => Err(LinkError::Io(e)),
        None => Err(LinkError::Io(std::io::Error::new(
            std::io::ErrorKind::UnexpectedEof,
            "the controller closed the connection",
        ))),
    }
}

/// A line GRBL can take: ASCII, no line breaks, no real-time characters, short enough.
fn check_line(line: &str, index: usize, window: usize) -> Result<(), LinkError> {
    let bad = |why: String| LinkError::Rejected {
        unit: index,
        text: line.to_string(),
        reason: why,
    };
    if let Some(b) = line
        .bytes()
        .find(|&b| realtime::is_realtime(b) || b == b'\n' || b == b'\r')
    {
        return Err(bad(format!(
            "line {} holds byte 0x{b:02x}, which GRBL would act on as a real-time command or line end",
            index + 1
        )));
    }
    if line.len() + 1 > window {
        return Err(bad(format!(
            "line {} is {} bytes, longer than the controller's {window}-byte receive buffer",
            index + 1,
            line.len() + 1
        )));
    }
    Ok(())
}

/// The words of a G-code line (letter upper-cased, value as written), comments skipped.
fn words(line: &str) -> Vec<(char, String)> {
    let mut out = Vec::new();
    let mut chars = line.chars().peekable();
    let mut in_paren = false;
    while let Some(c) = chars.next() {
        if in_paren {
            in_paren = c != ')';
            continue;
        }
        match c {
            '(' => in_paren = true,
            ';' => break,
            c if c.is_ascii_alphabetic() => {
                let mut v = String::new();
                while let Some(&d) = chars.peek() {
                    if d.is_ascii_digit() || d == '.' || d == '-' || d == '+' {
                        v.push(d);
                        chars.next();
                    } else if d == ' ' {
                        chars.next();
                    } else {
                        break;
                    }
                }
                out.push((c.to_ascii_uppercase(), v));
            }
            _ => {}
        }
    }
    out
}

/// The lines a stream sends: the program's, with the one a resume rewrites.
struct Lines<'a> {
    units: Units<'a, String>,
    rewrite: Option<(usize, String)>,
}

impl Lines<'_> {
    fn len(&self) -> usize {
        self.units.len()
    }
    fn get(&self, i: usize) -> Result<String, LinkError> {
        match &self.rewrite {
            Some((k, l)) if *k == i => Ok(l.clone()),
            _ => Ok(self.units.get(i)?),
        }
    }
    /// Line `i` for a message; empty when it cannot be read.
    fn text(&self, i: usize) -> String {
        self.get(i).unwrap_or_default()
    }
    /// The last program stop among the lines before `from`.
    fn last_stop_before(&self, from: usize) -> Result<Option<String>, LinkError> {
        let mut last = None;
        for i in 0..from.min(self.len()) {
            let l = self.get(i)?;
            if is_program_stop(&l) {
                last = Some(l);
            }
        }
        Ok(last)
    }
}

/// A program stop the controller holds at (M0, M1; docs/grbl.md), or a tool change a
/// controller that takes M6 holds at (`T1 M6`).
fn is_program_stop(line: &str) -> bool {
    line.starts_with("M0") || line.starts_with("M1") || crate::gcode::tool_change_of(line).is_some()
}

impl Link<String> for GrblLink {
    fn stream<'a>(
        &'a mut self,
        lines: &'a [String],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        Box::pin(self.stream_gcode(lines.into(), from, events, control))
    }
    fn stream_units<'a>(
        &'a mut self,
        units: Units<'a, String>,
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        Box::pin(self.stream_gcode(units, from, events, control))
    }
    fn inquire(&mut self) -> BoxFuture<'_, Result<MachineStatus, LinkError>> {
        Box::pin(async move {
            let s = self.query_status().await?;
            Ok(s.to_status(self.wco))
        })
    }
    fn reattach<'a>(
        &'a mut self,
        lines: &'a [String],
        handed: Handed,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<Reattach, LinkError>> {
        Box::pin(self.follow(lines.into(), handed, events, control))
    }
    fn reattach_units<'a>(
        &'a mut self,
        units: Units<'a, String>,
        handed: Handed,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<Reattach, LinkError>> {
        Box::pin(self.follow(units, handed, events, control))
    }
    fn operate<'a>(&'a mut self, op: &'a Operation) -> BoxFuture<'a, Result<String, LinkError>> {
        Box::pin(self.operator(op))
    }
    fn follow_overrides(&mut self, overrides: watch::Receiver<Overrides>) -> Result<(), LinkError> {
        self.overrides = Some(overrides);
        Ok(())
    }
    fn keep_journal(&mut self, journal: Box<dyn SendJournal>) {
        self.journal = Some(journal);
    }
}

#[cfg(test)]
mod tests;
